//! A recording session saved as RON, so that a fit can be redone later (other options, a newer
//! build) without touching the rig again.
//!
//! It holds only what was measured (averaged counts, their spread, what the operator was asked
//! for), never fitted values.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::CalibError;

pub const SESSION_FILE_VERSION: u32 = 1;

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
    /// Standard deviation of each string's counts over the average.
    pub counts_std: [f64; 4],
    /// Samples averaged.
    pub samples: u32,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SessionFile {
    /// File format version; must be 1.
    pub version: u32,
    /// Name of the rig file's rig at recording time.
    pub rig_name: String,
    /// Device the counts came from.
    pub device: String,
    /// When recording finished (UTC).
    pub recorded_utc: String,
    pub poses: Vec<PoseRecord>,
}

impl SessionFile {
    pub fn load(path: &Path) -> Result<SessionFile, CalibError> {
        let text = crate::read_text(path, "cannot read the session file")?;
        let f: SessionFile = crate::parse_ron_kind(
            &text,
            &path.display().to_string(),
            spidar_config::FileKind::CalibrationSession,
        )?;
        if f.version != SESSION_FILE_VERSION {
            return Err(CalibError::BadFile {
                file: path.display().to_string(),
                message: format!(
                    "version {}: this build reads sessions of version {SESSION_FILE_VERSION}",
                    f.version
                ),
            });
        }
        Ok(f)
    }

    /// Writes the session (temp file then rename, so a crash leaves the old file or the new one).
    pub fn save(&self, path: &Path) -> Result<(), CalibError> {
        let pretty = ron::ser::PrettyConfig::new().depth_limit(3);
        let body = ron::ser::to_string_pretty(self, pretty)
            .map_err(|e| CalibError::BadFile { file: path.display().to_string(), message: e.to_string() })?;
        let body = spidar_config::with_kind(&body, spidar_config::FileKind::CalibrationSession);
        let text = format!(
            "// spidar calib session: averaged encoder counts per pose, as recorded. Refit with\n\
             // `spidar calib fit --session {}`.\n{body}\n",
            path.display()
        );
        crate::rigfile::write_atomically(path, &text, false)
    }

    pub fn poses_of(&self, hand: usize) -> impl Iterator<Item = &PoseRecord> {
        self.poses.iter().filter(move |p| p.hand == hand)
    }
}
