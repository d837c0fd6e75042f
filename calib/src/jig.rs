//! Jig files: known grip positions (a jig board with pegs, a surveyed frame) at which the fit
//! anchors the rig frame and its scale, and check points that verification uses.
//!
//! A jig file is RON with `deny_unknown_fields` and a `version`; a bad file names its line and
//! column. It never holds fitted values, only what was measured on the jig.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::CalibError;

pub const JIG_FILE_VERSION: u32 = 1;

/// One known point.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JigPoint {
    /// Name shown to the operator, e.g. "A1 (front lower left)".
    pub label: String,
    /// Which hand's grip goes there: 0 left, 1 right.
    pub hand: usize,
    /// Where the grip centre is when on this point (rig frame).
    pub at_m: [f64; 3],
}

impl JigPoint {
    pub fn at(&self) -> DVec3 {
        DVec3::from_array(self.at_m)
    }
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JigFile {
    /// File format version; must be 1.
    pub version: u32,
    /// Free text naming the jig and how it is placed.
    pub name: String,
    /// Points the fit uses as known positions.
    pub fit_points: Vec<JigPoint>,
    /// Points only verification uses (never fitted to, so they test the fit honestly).
    pub check_points: Vec<JigPoint>,
}

impl JigFile {
    pub fn load(path: &Path) -> Result<JigFile, CalibError> {
        let text = crate::read_text(path, "cannot read the jig file")?;
        JigFile::from_str(&text, &path.display().to_string())
    }

    pub fn from_str(text: &str, origin: &str) -> Result<JigFile, CalibError> {
        let f: JigFile = crate::parse_ron_kind(text, origin, spidar_config::FileKind::Jig)?;
        let bad = |message: String| CalibError::BadFile { file: origin.to_string(), message };
        if f.version != JIG_FILE_VERSION {
            return Err(bad(format!(
                "version {}: this build reads jig files of version {JIG_FILE_VERSION}",
                f.version
            )));
        }
        for (list, pts) in [("fit_points", &f.fit_points), ("check_points", &f.check_points)] {
            for (i, p) in pts.iter().enumerate() {
                if p.hand > 1 {
                    return Err(bad(format!("{list}[{i}] ({}): hand {} (must be 0 or 1)", p.label, p.hand)));
                }
                if !p.at_m.iter().all(|v| v.is_finite() && v.abs() < 5.0) {
                    return Err(bad(format!(
                        "{list}[{i}] ({}): at_m must be finite and within 5 m",
                        p.label
                    )));
                }
            }
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_jig_file_loads() {
        let f = JigFile::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/jig-spidar-h.ron")))
            .unwrap();
        for hand in 0..2 {
            assert_eq!(f.fit_points.iter().filter(|p| p.hand == hand).count(), 8);
            assert!(f.check_points.iter().filter(|p| p.hand == hand).count() >= 4);
        }
    }

    #[test]
    fn bad_jig_file_names_line_and_column() {
        let e = JigFile::from_str(
            "(kind: \"jig\", version: 1, name: \"x\", fit_points: [], check_points: [], extra: 1)",
            "j.ron",
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("j.ron:1:"), "{e}");
    }
}
