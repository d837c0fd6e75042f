//! A recording session saved as RON after every pose, so that no pose is lost (Ctrl-C, a lost
//! board, a closed terminal) and a fit can be redone later (other options, a newer build) without
//! touching the rig again.
//!
//! It holds only what was measured (averaged counts, their spread, what the operator was asked
//! for) and what was planned (hands, jig, number of free poses, so that `spidar calib record
//! --resume` continues it), never fitted values. The format is documented with a commented example
//! in `docs/calibration.md`.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::CalibError;

/// The version this build writes. Version 1 (no plan, written only when complete) is still read.
pub const SESSION_FILE_VERSION: u32 = 2;

/// What a recorded pose was.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub enum PoseKind {
    /// The grip at the rig's home point (the first pose of each hand): seeds the lengths at zero.
    /// Fitted as a free pose, because a home point held by eye is not a jig.
    Home { at_m: [f64; 3] },
    /// The grip on a jig point: a known position.
    Jig { label: String, at_m: [f64; 3] },
    /// Anywhere in the workspace: the position is an unknown of the fit.
    Free,
}

/// One recorded pose.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PoseRecord {
    /// 0 left, 1 right.
    pub hand: usize,
    pub kind: PoseKind,
    /// Counts of the hand's four strings averaged while the grip was still.
    pub counts: [f64; 4],
    /// Standard deviation of each string's counts over the average (the noise at rest).
    pub counts_std: [f64; 4],
    /// Samples averaged.
    pub samples: u32,
}

/// What `spidar calib record` was asked to record; `--resume` continues it.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SessionPlan {
    /// Hands in recording order (0 left, 1 right).
    pub hands: Vec<usize>,
    /// The jig file whose `fit_points` are recorded; `None`: free poses only.
    pub jig_file: Option<String>,
    /// Free poses per hand.
    pub free_per_hand: usize,
    /// Half size of the box around each home point that free-pose suggestions fill.
    pub free_half_extent_m: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SessionFile {
    /// File format version: 2 (1 is still read).
    pub version: u32,
    /// Name of the rig file's rig at recording time.
    pub rig_name: String,
    /// The rig file recording used (for the hints; `fit` takes `--rig`).
    #[serde(default)]
    pub rig_file: String,
    /// Device the counts came from.
    pub device: String,
    /// When the session was started (UTC).
    #[serde(default)]
    pub started_utc: String,
    /// When the last pose was saved (UTC).
    pub recorded_utc: String,
    /// What was asked for (absent in version 1).
    #[serde(default)]
    pub plan: Option<SessionPlan>,
    /// Every pose of the plan was recorded.
    #[serde(default)]
    pub complete: bool,
    pub poses: Vec<PoseRecord>,
}

/// Free poses per hand a session may ask for.
pub const MAX_FREE_PER_HAND: usize = 1000;

impl SessionPlan {
    /// Refuses hands other than 0 and 1, repeated hands, and pose counts or box sizes out of range.
    pub fn check(&self) -> Result<(), String> {
        if self.hands.is_empty() {
            return Err("no hand to record".into());
        }
        for (k, &h) in self.hands.iter().enumerate() {
            if h > 1 {
                return Err(format!("hand {h} (must be 0 left or 1 right)"));
            }
            if self.hands[..k].contains(&h) {
                return Err(format!("hand {h} is listed twice"));
            }
        }
        if self.free_per_hand > MAX_FREE_PER_HAND {
            return Err(format!("{} free poses per hand: at most {MAX_FREE_PER_HAND}", self.free_per_hand));
        }
        if !(self.free_half_extent_m.is_finite() && (0.05..=1.0).contains(&self.free_half_extent_m)) {
            return Err(format!(
                "free-pose box half size {} m: must be 0.05 .. 1 m",
                self.free_half_extent_m
            ));
        }
        Ok(())
    }
}

impl SessionFile {
    /// An empty session of `plan`.
    pub fn new(rig_name: &str, rig_file: &str, device: &str, plan: SessionPlan) -> SessionFile {
        let now = crate::utc_now();
        SessionFile {
            version: SESSION_FILE_VERSION,
            rig_name: rig_name.to_string(),
            rig_file: rig_file.to_string(),
            device: device.to_string(),
            started_utc: now.clone(),
            recorded_utc: now,
            plan: Some(plan),
            complete: false,
            poses: Vec::new(),
        }
    }

    pub fn load(path: &Path) -> Result<SessionFile, CalibError> {
        let text = crate::read_text(path, "cannot read the session file")?;
        SessionFile::from_str(&text, &path.display().to_string())
    }

    /// Parses and checks a session: every value a fit or a resume relies on is in range, and an
    /// error names the line and column of the offending field.
    pub fn from_str(text: &str, origin: &str) -> Result<SessionFile, CalibError> {
        // Sessions written before files said their kind (versions 1 and 2 as first written) have
        // no `kind` entry and are read as they are; a session that names a kind must name this one.
        let mut f: SessionFile = match spidar_config::find_kind(text) {
            Ok(None) => crate::parse_ron(text, origin)?,
            _ => crate::parse_ron_kind(text, origin, spidar_config::FileKind::CalibrationSession)?,
        };
        let invalid = |field: String, key: &str, occurrence: usize, message: String| {
            CalibError::Config(spidar_config::invalid(text, origin, &field, key, occurrence, message))
        };
        if !(1..=SESSION_FILE_VERSION).contains(&f.version) {
            return Err(invalid(
                "version".into(),
                "version",
                0,
                format!("version {}: this build reads session files of version 1 and 2", f.version),
            ));
        }
        if f.version == 1 {
            // Version 1 was written once, at the end of a complete recording.
            f.complete = true;
        }
        if let Some(p) = &f.plan {
            p.check().map_err(|m| invalid("plan".into(), "plan", 0, m))?;
        }
        for (k, p) in f.poses.iter().enumerate() {
            let field = |name: &str| format!("poses[{k}].{name}");
            if p.hand > 1 {
                return Err(invalid(
                    field("hand"),
                    "hand",
                    k,
                    format!("hand {} (must be 0 left or 1 right): the file was edited or is corrupt", p.hand),
                ));
            }
            if !p.counts.iter().all(|c| c.is_finite() && c.abs() < 1e15) {
                return Err(invalid(
                    field("counts"),
                    "counts",
                    k,
                    "every count must be a finite number".into(),
                ));
            }
            if !p.counts_std.iter().all(|c| c.is_finite() && *c >= 0.0) {
                return Err(invalid(
                    field("counts_std"),
                    "counts_std",
                    k,
                    "every spread must be a finite number >= 0".into(),
                ));
            }
            if p.samples == 0 {
                return Err(invalid(field("samples"), "samples", k, "at least 1 sample".into()));
            }
            let at = match &p.kind {
                PoseKind::Home { at_m } | PoseKind::Jig { at_m, .. } => Some(at_m),
                PoseKind::Free => None,
            };
            if let Some(at) = at {
                if !at.iter().all(|v| v.is_finite() && v.abs() < 5.0) {
                    let occurrence =
                        f.poses[..k].iter().filter(|q| !matches!(q.kind, PoseKind::Free)).count();
                    return Err(invalid(
                        field("kind.at_m"),
                        "at_m",
                        occurrence,
                        "must be finite and within 5 m".into(),
                    ));
                }
            }
        }
        Ok(f)
    }

    /// The session as RON, with a header saying what it is.
    pub fn to_text(&self, path: &Path) -> Result<String, CalibError> {
        let pretty = ron::ser::PrettyConfig::new().depth_limit(3);
        let body = ron::ser::to_string_pretty(self, pretty)
            .map_err(|e| CalibError::BadFile { file: path.display().to_string(), message: e.to_string() })?;
        let body = spidar_config::with_kind(&body, spidar_config::FileKind::CalibrationSession);
        let rig = if self.rig_file.is_empty() || self.rig_file.starts_with('(') {
            String::new()
        } else {
            format!(" --rig {}", self.rig_file)
        };
        Ok(format!(
            "// spidar calib session: averaged encoder counts per pose, as recorded (format: docs/calibration.md).\n\
             // Refit with `spidar calib fit{rig} --session {}`; continue an incomplete one with\n\
             // `spidar calib record{rig} --out {} --resume` (and the device options it was recorded with).\n{body}\n",
            path.display(),
            path.display()
        ))
    }

    /// Writes the session atomically (a crash leaves the previous save or this one).
    pub fn save(&self, path: &Path) -> Result<(), CalibError> {
        crate::safefile::replace(path, &self.to_text(path)?, false).map(|_| ())
    }

    pub fn poses_of(&self, hand: usize) -> impl Iterator<Item = &PoseRecord> {
        self.poses.iter().filter(move |p| p.hand == hand)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn text(hand: usize) -> String {
        format!(
            "(version: 2, rig_name: \"r\", device: \"d\", recorded_utc: \"t\", poses: [\n\
             (hand: 0, kind: Free, counts: (1.0, 2.0, 3.0, 4.0), counts_std: (0.5, 0.5, 0.5, 0.5), samples: 500),\n\
             (hand: {hand}, kind: Free, counts: (1.0, 2.0, 3.0, 4.0), counts_std: (0.5, 0.5, 0.5, 0.5), samples: 500),\n\
             ])"
        )
    }

    #[test]
    fn a_version_1_session_still_loads_as_complete_without_a_plan() {
        let v1 = text(1).replacen("version: 2", "version: 1", 1);
        let f = SessionFile::from_str(&v1, "s.ron").unwrap();
        assert!(f.complete && f.plan.is_none() && f.poses.len() == 2);
    }

    #[test]
    fn a_file_that_never_ends_is_refused_not_read_forever() {
        let e = SessionFile::load(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(e.starts_with("/dev/zero: cannot read the session file: larger than 4 MiB"), "{e}");
    }

    #[test]
    fn a_pose_of_hand_5_is_refused_at_its_line() {
        SessionFile::from_str(&text(1), "s.ron").unwrap();
        let e = SessionFile::from_str(&text(5), "s.ron").unwrap_err().to_string();
        assert!(e.starts_with("s.ron:3:2: poses[1].hand: hand 5"), "{e}");
    }

    #[test]
    fn non_finite_counts_and_empty_averages_are_refused() {
        let e = SessionFile::from_str(&text(1).replacen("2.0", "inf", 1), "s.ron").unwrap_err().to_string();
        assert!(e.contains("poses[0].counts"), "{e}");
        let e = SessionFile::from_str(&text(1).replacen("samples: 500", "samples: 0", 1), "s.ron")
            .unwrap_err()
            .to_string();
        assert!(e.contains("poses[0].samples"), "{e}");
        let e = SessionFile::from_str(&text(1).replacen("version: 2", "version: 3", 1), "s.ron")
            .unwrap_err()
            .to_string();
        assert!(e.contains("version 3"), "{e}");
    }

    #[test]
    fn a_plan_with_an_impossible_hand_or_count_is_refused() {
        let with_plan = |plan: &str| text(1).replacen("poses:", &format!("plan: Some({plan}), poses:"), 1);
        let ok = "(hands: [0, 1], jig_file: None, free_per_hand: 40, free_half_extent_m: 0.3)";
        SessionFile::from_str(&with_plan(ok), "s.ron").unwrap();
        for (bad, why) in [
            (ok.replace("[0, 1]", "[0, 2]"), "hand 2"),
            (ok.replace("[0, 1]", "[1, 1]"), "twice"),
            (ok.replace("40", "100000"), "at most"),
            (ok.replace("0.3", "NaN"), "half size"),
        ] {
            let e = SessionFile::from_str(&with_plan(&bad), "s.ron").unwrap_err().to_string();
            assert!(e.contains("plan") && e.contains(why), "{e}");
        }
    }

    #[test]
    fn a_session_says_its_kind_and_one_of_another_kind_is_refused() {
        // Written before kinds: read as it is, at version 1 and 2.
        let old = SessionFile::from_str(&text(1), "s.ron").unwrap();
        SessionFile::from_str(&text(1).replacen("version: 2", "version: 1", 1), "s.ron").unwrap();
        // Written now: the kind is the first entry, and the file reads back.
        let written = old.to_text(Path::new("s.ron")).unwrap();
        assert!(written.contains("kind: \"calibration-session\""), "{written}");
        assert_eq!(SessionFile::from_str(&written, "s.ron").unwrap().poses.len(), old.poses.len());
        // A file that says it is something else is refused where it says so.
        let rig = text(1).replacen("(version", "(kind: \"rig\", version", 1);
        let e = SessionFile::from_str(&rig, "s.ron").unwrap_err().to_string();
        assert!(e.contains("kind \"rig\"") && e.contains("check the path"), "{e}");
    }
}
