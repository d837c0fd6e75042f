//! Writing a fitted (or homed) geometry into the rig file, atomically and keeping its comments.
//!
//! Why it exists: the rig file is hand-written and commented; the operator's notes in it must
//! survive calibration, and a crash or full disk must never leave a half-written file that the
//! next `spidar run` would read.
//!
//! How: only the numbers change, in place. For each string the tool finds its entry (the tuple
//! holding its `channel:`), replaces the values of `anchor_m`, `metres_per_count` and
//! `length_at_zero_m` (inserting the last after `metres_per_count` if absent), and updates or
//! appends the `calibration` record; every other byte stays as it was. The new text is parsed and
//! validated as a rig and must read back the values written, then it replaces the file as
//! [`crate::safefile`] does: exclusively created temporary file, mode and owner kept, a symlink's
//! target updated, the previous version kept as `<name>.<UTC time>.bak`.
//!
//! What it must never do: write a file that does not load, or write over a rig file that changed
//! on disk since it was read.

use std::path::Path;

use spidar_rt::Rig;

use crate::model::HandGeometry;
use crate::safefile::Replaced;
use crate::CalibError;

/// What goes into the `calibration` record (empty strings leave a field as it was).
#[derive(Clone, Debug, Default)]
pub struct Stamp {
    pub homed_utc: String,
    pub fitted_utc: String,
    pub fit_residual_rms_m: Option<f64>,
    pub session: String,
}

/// The text with `//` comments blanked and string contents masked (same byte offsets), so that
/// searches for keys and brackets see only RON structure.
pub(crate) fn code_mask(text: &str) -> Vec<u8> {
    let mut out = text.as_bytes().to_vec();
    let b = text.as_bytes();
    let mut i = 0;
    let mut in_str = false;
    while i < b.len() {
        if in_str {
            if b[i] == b'\\' {
                out[i] = b'_';
                if i + 1 < b.len() {
                    out[i + 1] = b'_';
                }
                i += 2;
                continue;
            }
            if b[i] == b'"' {
                in_str = false;
            } else {
                out[i] = b'_';
            }
        } else if b[i] == b'"' {
            in_str = true;
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                out[i] = b' ';
                i += 1;
            }
            continue;
        }
        i += 1;
    }
    out
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// Byte offsets of `key:` (as a whole identifier) in `mask[from..to]`.
pub(crate) fn find_keys(mask: &[u8], key: &str, from: usize, to: usize) -> Vec<usize> {
    let k = key.as_bytes();
    let mut hits = Vec::new();
    let mut i = from;
    while i + k.len() <= to {
        if &mask[i..i + k.len()] == k && (i == 0 || !is_ident(mask[i - 1])) {
            let mut j = i + k.len();
            while j < to && mask[j].is_ascii_whitespace() {
                j += 1;
            }
            if j < to && mask[j] == b':' && (i + k.len() >= mask.len() || !is_ident(mask[i + k.len()])) {
                hits.push(i);
            }
        }
        i += 1;
    }
    hits
}

/// The value after `key:` at `at`: (start, end) bytes of the value, up to the `,` or closing
/// bracket that ends it (a parenthesised value is taken whole).
pub(crate) fn value_span(mask: &[u8], at: usize, to: usize) -> Option<(usize, usize)> {
    let mut i = at;
    while i < to && mask[i] != b':' {
        i += 1;
    }
    i += 1;
    while i < to && mask[i].is_ascii_whitespace() {
        i += 1;
    }
    let start = i;
    let mut depth = 0i32;
    while i < to {
        match mask[i] {
            b'(' | b'[' => depth += 1,
            b')' | b']' if depth == 0 => break,
            b')' | b']' => depth -= 1,
            b',' if depth == 0 => break,
            _ => {}
        }
        i += 1;
    }
    let mut end = i;
    while end > start && mask[end - 1].is_ascii_whitespace() {
        end -= 1;
    }
    (end > start).then_some((start, end))
}

/// The tuple `( ... )` enclosing byte `at`.
fn enclosing_tuple(mask: &[u8], at: usize) -> Option<(usize, usize)> {
    let mut depth = 0i32;
    let mut i = at;
    let start = loop {
        if i == 0 {
            return None;
        }
        i -= 1;
        match mask[i] {
            b')' => depth += 1,
            b'(' if depth == 0 => break i,
            b'(' => depth -= 1,
            _ => {}
        }
    };
    let mut depth = 0i32;
    for (j, &c) in mask.iter().enumerate().skip(start) {
        match c {
            b'(' => depth += 1,
            b')' => {
                depth -= 1;
                if depth == 0 {
                    return Some((start, j));
                }
            }
            _ => {}
        }
    }
    None
}

fn fmt_m(v: f64) -> String {
    // Micrometres: far below what a fit determines, and round-trips within 5e-7 m.
    format!("{v:.6}")
}

/// The rig file text with new geometry for the hands given and the calibration record updated.
pub fn updated_rig_text(
    text: &str,
    origin: &str,
    geometry: &[Option<HandGeometry>; 2],
    stamp: &Stamp,
) -> Result<String, CalibError> {
    let bad = |message: String| CalibError::RigFile { file: origin.to_string(), message };
    let mask = code_mask(text);
    let mut edits: Vec<(usize, usize, String)> = Vec::new();
    let channels = find_keys(&mask, "channel", 0, mask.len());
    if channels.len() != 8 {
        return Err(bad(format!(
            "expected 8 string entries (each with `channel:`), found {}",
            channels.len()
        )));
    }
    for (h, g) in geometry.iter().enumerate() {
        let Some(g) = g else { continue };
        for s in 0..4 {
            let (t0, t1) = enclosing_tuple(&mask, channels[4 * h + s]).ok_or_else(|| {
                bad(format!("hands[{h}].strings[{s}]: cannot find the entry's parentheses"))
            })?;
            let one = |key: &str| -> Result<(usize, usize), CalibError> {
                let hits = find_keys(&mask, key, t0, t1);
                if hits.len() != 1 {
                    return Err(bad(format!(
                        "hands[{h}].strings[{s}]: expected one `{key}:`, found {}",
                        hits.len()
                    )));
                }
                value_span(&mask, hits[0], t1)
                    .ok_or_else(|| bad(format!("hands[{h}].strings[{s}].{key}: no value")))
            };
            let a = g.anchors_m[s];
            let (x0, x1) = one("anchor_m")?;
            edits.push((x0, x1, format!("({}, {}, {})", fmt_m(a.x), fmt_m(a.y), fmt_m(a.z))));
            let (m0, m1) = one("metres_per_count")?;
            edits.push((m0, m1, format!("{:.12e}", g.metres_per_count[s])));
            let zero = format!("Some({})", fmt_m(g.length_at_zero_m[s]));
            match find_keys(&mask, "length_at_zero_m", t0, t1).len() {
                0 => edits.push((m1, m1, format!(", length_at_zero_m: {zero}"))),
                _ => {
                    let (z0, z1) = one("length_at_zero_m")?;
                    edits.push((z0, z1, zero));
                }
            }
        }
    }
    // The calibration record.
    let cal = find_keys(&mask, "calibration", 0, mask.len());
    let rms = stamp.fit_residual_rms_m.map(|v| format!("{v:.3e}"));
    if let Some(&at) = cal.first() {
        let (c0, c1) =
            value_span(&mask, at, mask.len()).ok_or_else(|| bad("calibration: no value".into()))?;
        for (key, val) in [
            ("homed_utc", (!stamp.homed_utc.is_empty()).then(|| format!("{:?}", stamp.homed_utc))),
            ("fitted_utc", (!stamp.fitted_utc.is_empty()).then(|| format!("{:?}", stamp.fitted_utc))),
            ("fit_residual_rms_m", rms.clone()),
            ("session", (!stamp.session.is_empty()).then(|| format!("{:?}", stamp.session))),
        ] {
            let Some(val) = val else { continue };
            match find_keys(&mask, key, c0, c1).first() {
                Some(&k) => {
                    let (v0, v1) = value_span(&mask, k, c1)
                        .ok_or_else(|| bad(format!("calibration.{key}: no value")))?;
                    edits.push((v0, v1, val));
                }
                None => {
                    // Insert right after the record's opening parenthesis.
                    edits.push((c0 + 1, c0 + 1, format!("{key}: {val}, ")));
                }
            }
        }
    } else {
        let close =
            mask.iter().rposition(|&c| c == b')').ok_or_else(|| bad("no closing parenthesis".into()))?;
        let before = mask[..close].iter().rposition(|c| !c.is_ascii_whitespace()).unwrap_or(0);
        let comma = if matches!(mask[before], b',' | b'(') { "" } else { "," };
        let q = |s: &str| format!("{s:?}");
        let block = format!(
            "{comma}\n    // Written by `spidar calib`: when the counters were last homed and the geometry last fitted.\n    \
             calibration: (\n        \
             // Last `spidar calib home --write`, UTC; empty: never.\n        homed_utc: {},\n        \
             // Last `spidar calib fit --write`, UTC; empty: never.\n        fitted_utc: {},\n        \
             // RMS string-length residual of that fit.\n        fit_residual_rms_m: {},\n        \
             // The session file it was fitted from.\n        session: {},\n    ),\n",
            q(&stamp.homed_utc),
            q(&stamp.fitted_utc),
            rms.unwrap_or_else(|| "0.0".into()),
            q(&stamp.session)
        );
        edits.push((before + 1, close, block));
    }
    edits.sort_by_key(|e| std::cmp::Reverse(e.0));
    let mut out = text.to_string();
    for (a, b, s) in edits {
        out.replace_range(a..b, &s);
    }
    // The result must load as a rig and read back what was written.
    let rig = Rig::from_str(&out, origin)
        .map_err(|e| bad(format!("the updated text does not load ({e}); the file was not changed")))?;
    for (h, g) in geometry.iter().enumerate() {
        let Some(g) = g else { continue };
        let hr = &rig.hands[h];
        let z = hr.length_at_zero_m.ok_or_else(|| bad("length_at_zero_m did not read back".into()))?;
        for (s, zs) in z.iter().enumerate() {
            let ok = hr.anchors_m[s].distance(g.anchors_m[s]) < 1e-6
                && (zs - g.length_at_zero_m[s]).abs() < 1e-6
                && (hr.metres_per_count[s] / g.metres_per_count[s] - 1.0).abs() < 1e-10;
            if !ok {
                return Err(bad(format!(
                    "hands[{h}].strings[{s}] did not read back as written; the file was not changed"
                )));
            }
        }
    }
    Ok(out)
}

/// Updates the rig file at `path` with new geometry and stamp (see [`crate::safefile`]: a
/// symlinked rig file has its target updated, mode and owner are kept, the previous version stays
/// as a dated backup). Fails without touching the file if it changed on disk since `read_text`
/// was read.
pub fn update_rig_file(
    path: &Path,
    read_text: &str,
    geometry: &[Option<HandGeometry>; 2],
    stamp: &Stamp,
) -> Result<Replaced, CalibError> {
    let new = updated_rig_text(read_text, &path.display().to_string(), geometry, stamp)?;
    let now = crate::read_text(path, "cannot re-read the rig file")?;
    if now != read_text {
        return Err(CalibError::RigFile {
            file: path.display().to_string(),
            message: "changed on disk while calibrating; nothing was written: run the command again".into(),
        });
    }
    crate::safefile::replace(path, &new, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use spidar_rt::rig::DEFAULT_RIG_RON;

    fn geometry(shift: f64) -> HandGeometry {
        let rig = Rig::default_rig();
        let hr = &rig.hands[1];
        HandGeometry {
            anchors_m: hr.anchors_m.map(|a| a + DVec3::new(shift, -shift, 0.5 * shift)),
            length_at_zero_m: [1.1, 2.2, 3.3, 4.4],
            metres_per_count: hr.metres_per_count.map(|m| m * 1.0987654321),
        }
    }

    #[test]
    fn update_changes_only_the_numbers_and_keeps_every_comment() {
        let g = geometry(0.0123456);
        let stamp = Stamp {
            fitted_utc: "2025-01-02T03:04:05Z".into(),
            fit_residual_rms_m: Some(2e-5),
            ..Stamp::default()
        };
        let out = updated_rig_text(DEFAULT_RIG_RON, "rig.ron", &[None, Some(g)], &stamp).unwrap();
        let rig = Rig::from_str(&out, "rig.ron").unwrap();
        assert_eq!(rig.hands[0], Rig::default_rig().hands[0], "hand 0 untouched");
        assert!(rig.hands[1].anchors_m[2].distance(g.anchors_m[2]) < 1e-6);
        assert_eq!(rig.hands[1].length_at_zero_m, Some([1.1, 2.2, 3.3, 4.4]));
        for line in DEFAULT_RIG_RON.lines().filter(|l| l.trim_start().starts_with("//")) {
            assert!(out.contains(line), "comment lost: {line}");
        }
        let file: spidar_rt::rig::RigFile =
            spidar_config::parse_kind(&out, "rig.ron", spidar_config::FileKind::Rig).unwrap();
        let cal = file.calibration;
        assert_eq!(cal.fitted_utc, "2025-01-02T03:04:05Z");
        assert_eq!(cal.fit_residual_rms_m, 2e-5);
        // A second update edits the record in place rather than adding another.
        let again = updated_rig_text(
            &out,
            "rig.ron",
            &[Some(g), None],
            &Stamp { homed_utc: "x".into(), ..Stamp::default() },
        )
        .unwrap();
        assert_eq!(again.matches("calibration:").count(), 1);
        let file: spidar_rt::rig::RigFile =
            spidar_config::parse_kind(&again, "rig.ron", spidar_config::FileKind::Rig).unwrap();
        assert_eq!(file.calibration.homed_utc, "x");
    }

    #[test]
    fn a_geometry_that_would_not_load_is_refused_and_nothing_is_written() {
        let mut g = geometry(0.0);
        g.anchors_m = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, 1.0, 0.0)];
        let e =
            updated_rig_text(DEFAULT_RIG_RON, "rig.ron", &[Some(g), None], &Stamp::default()).unwrap_err();
        assert!(e.to_string().contains("not changed"), "{e}");
    }

    #[test]
    fn file_update_is_atomic_and_keeps_a_backup() {
        let dir = std::env::temp_dir().join(format!("spidar-calib-rigfile-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rig.ron");
        std::fs::write(&path, DEFAULT_RIG_RON).unwrap();
        let bak = update_rig_file(&path, DEFAULT_RIG_RON, &[Some(geometry(0.01)), None], &Stamp::default())
            .unwrap()
            .backup
            .unwrap();
        assert_eq!(std::fs::read_to_string(&bak).unwrap(), DEFAULT_RIG_RON);
        let new = std::fs::read_to_string(&path).unwrap();
        assert!(Rig::from_str(&new, "x").unwrap().hands[0].length_at_zero_m.is_some());
        // No temporary file is left behind.
        let left: Vec<_> =
            std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
        assert_eq!(left.len(), 2, "{left:?}");
        // A file changed behind our back is not overwritten.
        let e = update_rig_file(&path, DEFAULT_RIG_RON, &[Some(geometry(0.02)), None], &Stamp::default())
            .unwrap_err();
        assert!(e.to_string().contains("changed on disk"), "{e}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), new);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
