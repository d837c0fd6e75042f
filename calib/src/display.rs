//! Placing the rig's screen: the page shows targets at known fractions of the screen, the person
//! holds a grip's centre on each (the ball touching the screen), and this fits the screen's
//! rectangle in the rig frame to where the rig measured the grip, then writes it into the rig
//! file's `display` section the way calibration writes the geometry (atomically, comments kept,
//! the result loading and reading back).
//!
//! The fit: a grip centre at target (a, b) (fractions of the width and height from the lower-left
//! corner) is `ll + a w + b h + r n`, `w` and `h` the screen's sides, `n` its unit normal toward
//! the viewer, `r` the grip's radius. Linear least squares in `ll + r n`, `w`, `h` (nine unknowns,
//! three equations a target), then the plane moved back by `r` along the fitted normal.
//!
//! What it must never do: write a placement that is not a screen: too few or collinear targets,
//! a target held off the others' plane (the residual says which), sides that are not a rectangle,
//! or a screen the eye is behind are refused with the reason; so is a file that changed on disk.

use std::path::Path;

use glam::DVec3;
use spidar_rt::display::{validate, Display, DisplayFile, ScreenFile, Stereo, RIGHT_ANGLE_TOLERANCE_DEG};
use spidar_rt::Rig;

use crate::safefile::Replaced;
use crate::CalibError;

/// Where the page shows the targets: fractions of the screen's width and height from its
/// lower-left corner, in the order the person visits them.
pub const TARGETS: [(f64, f64); 5] = [(0.15, 0.15), (0.85, 0.15), (0.85, 0.85), (0.15, 0.85), (0.5, 0.5)];

/// The largest distance (m) of a held grip from the fitted rectangle: a grip held still on its
/// target is within a millimetre or two; more means it was not on the target or not on the screen.
pub const MAX_RESIDUAL_M: f64 = 0.008;

/// A fitted screen and how well the targets agree with it.
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub display: Display,
    /// RMS and largest distance of a grip centre from where the fitted screen puts its target.
    pub rms_m: f64,
    pub worst_m: f64,
    pub worst_target: usize,
    /// Where the grip was at each target (rig frame), and where the fitted screen puts each
    /// target's grip centre.
    pub grips_m: [DVec3; 5],
    pub fitted_m: [DVec3; 5],
}

fn refuse(message: String) -> CalibError {
    CalibError::BadFile { file: "the screen's placement".into(), message }
}

/// Solves the 3x3 system `a x = b` (Cramer), None when singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.abs() < 1e-12 {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        *xk = det(m) / d;
    }
    Some(x)
}

/// Least squares `p = c + a w + b h` over the targets' fractions (a, b) and grips p: the three
/// coordinates share one 3x3 normal matrix. None when the targets lie on a line.
fn fit_affine(targets: &[(f64, f64)], grips_m: &[DVec3]) -> Option<(DVec3, DVec3, DVec3)> {
    // Normal equations of p = c + a w + b h, the same 3x3 matrix for every coordinate.
    let mut m = [[0.0; 3]; 3];
    let mut rhs = [[0.0; 3]; 3];
    for (&(a, b), p) in targets.iter().zip(grips_m) {
        let row = [1.0, a, b];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            for (k, pk) in p.to_array().iter().enumerate() {
                rhs[k][i] += row[i] * pk;
            }
        }
    }
    let mut sol = [[0.0; 3]; 3];
    for k in 0..3 {
        let x = solve3(m, rhs[k])?;
        for i in 0..3 {
            sol[i][k] = x[i];
        }
    }
    Some((DVec3::from_array(sol[0]), DVec3::from_array(sol[1]), DVec3::from_array(sol[2])))
}

/// Fits the screen to grip centres `grips_m` (rig frame) held at `targets` (fractions), for a grip
/// of radius `grip_radius_m`, seen from `eye_m`; checked as a rig file's screen would be.
pub fn fit_screen(
    targets: &[(f64, f64)],
    grips_m: &[DVec3],
    grip_radius_m: f64,
    eye_m: DVec3,
    eye_separation_m: f64,
    stereo: Stereo,
) -> Result<Placement, CalibError> {
    if targets.len() != grips_m.len() || targets.len() < 3 || targets.len() > TARGETS.len() {
        return Err(refuse(format!(
            "{} targets held: at least 3 (the page shows {}) are needed to place a screen",
            grips_m.len(),
            TARGETS.len()
        )));
    }
    let (c, w, h) = fit_affine(targets, grips_m)
        .ok_or_else(|| refuse("the targets held lie on one line: they cannot place a screen".into()))?;
    let n = w.cross(h).normalize_or_zero();
    if n == DVec3::ZERO {
        return Err(refuse("the targets held do not span a rectangle".into()));
    }
    let mut worst = (0.0_f64, 0usize);
    let mut sq = 0.0;
    for (i, (&(a, b), p)) in targets.iter().zip(grips_m).enumerate() {
        let e = (c + w * a + h * b - *p).length();
        sq += e * e;
        if e > worst.0 {
            worst = (e, i);
        }
    }
    let rms = (sq / targets.len() as f64).sqrt();
    if worst.0 > MAX_RESIDUAL_M {
        // Which target is off: the one the others, fitted without it, miss by most.
        if targets.len() >= 4 {
            for i in 0..targets.len() {
                let (t, g): (Vec<_>, Vec<_>) =
                    targets.iter().zip(grips_m).enumerate().filter(|(k, _)| *k != i).map(|(_, x)| x).unzip();
                if let Some((c2, w2, h2)) = fit_affine(&t, &g) {
                    let (a, b) = targets[i];
                    let e = (c2 + w2 * a + h2 * b - grips_m[i]).length();
                    if i == 0 || e > worst.0 {
                        worst = (e, i);
                    }
                }
            }
        }
        return Err(refuse(format!(
            "target {} was held {:.1} mm from where the others put it (a target may be {:.0} mm off): hold the grip's centre \
             on each target, the ball touching the screen, and keep it still until it is taken",
            worst.1 + 1,
            worst.0 * 1e3,
            MAX_RESIDUAL_M * 1e3
        )));
    }
    let angle = w.normalize().dot(h.normalize()).clamp(-1.0, 1.0).acos().to_degrees();
    if (angle - 90.0).abs() > RIGHT_ANGLE_TOLERANCE_DEG {
        return Err(refuse(format!(
            "the targets make a corner of {angle:.1} degrees, not a rectangle's 90: was the page full screen on \
             that screen, and were the targets visited in their order?"
        )));
    }
    let ll = c - n * grip_radius_m;
    let file = DisplayFile {
        screen: ScreenFile::Corners {
            lower_left_m: ll.to_array(),
            lower_right_m: (ll + w).to_array(),
            upper_left_m: (ll + h).to_array(),
        },
        eye_separation_m,
        stereo,
    };
    let display = validate(&file, eye_m).map_err(|r| refuse(format!("{}: {}", r.field, r.message)))?;
    let mut g = [DVec3::ZERO; 5];
    let mut fitted = [DVec3::ZERO; 5];
    for (i, (&(a, b), p)) in targets.iter().zip(grips_m).enumerate() {
        g[i] = *p;
        fitted[i] = c + w * a + h * b;
    }
    Ok(Placement {
        display,
        rms_m: rms,
        worst_m: worst.0,
        worst_target: worst.1,
        grips_m: g,
        fitted_m: fitted,
    })
}

fn stereo_name(s: Stereo) -> &'static str {
    match s {
        Stereo::Mono => "Mono",
        Stereo::SideBySide => "SideBySide",
        Stereo::TopBottom => "TopBottom",
        Stereo::Anaglyph => "Anaglyph",
    }
}

/// The rig file's text with its `display` section set to `d` (replaced, or added at the end),
/// every other byte kept; it must load and read back the screen written.
pub fn updated_display_text(text: &str, origin: &str, d: &Display, note: &str) -> Result<String, CalibError> {
    let bad = |message: String| CalibError::RigFile { file: origin.to_string(), message };
    let p = |v: DVec3| format!("({:.6}, {:.6}, {:.6})", v.x, v.y, v.z);
    let section = format!(
        "Some((\n        // {note}\n        screen: Corners(lower_left_m: {}, lower_right_m: {}, upper_left_m: {}),\n        \
         // The viewer's eyes' separation (m).\n        eye_separation_m: {},\n        \
         // What the screen takes: Mono, SideBySide, TopBottom or Anaglyph.\n        stereo: {},\n    ))",
        p(d.lower_left_m),
        p(d.lower_right_m()),
        p(d.upper_left_m()),
        d.eye_separation_m,
        stereo_name(d.stereo)
    );
    let mask = crate::rigfile::code_mask(text);
    let out = match crate::rigfile::find_keys(&mask, "display", 0, mask.len()).first() {
        Some(&at) => {
            let (v0, v1) = crate::rigfile::value_span(&mask, at, mask.len())
                .ok_or_else(|| bad("display: no value".into()))?;
            let mut out = text.to_string();
            out.replace_range(v0..v1, &section);
            out
        }
        None => {
            let close =
                mask.iter().rposition(|&c| c == b')').ok_or_else(|| bad("no closing parenthesis".into()))?;
            let before = mask[..close].iter().rposition(|c| !c.is_ascii_whitespace()).unwrap_or(0);
            let comma = if matches!(mask[before], b',' | b'(') { "" } else { "," };
            let mut out = text.to_string();
            out.replace_range(
                before + 1..close,
                &format!(
                    "{comma}\n    // The rig's screen (docs/display.md): where its picture is in the rig frame.\n    display: {section},\n"
                ),
            );
            out
        }
    };
    let rig = Rig::from_str(&out, origin)
        .map_err(|e| bad(format!("the updated text does not load ({e}); the file was not changed")))?;
    let back =
        rig.display.ok_or_else(|| bad("the screen did not read back; the file was not changed".into()))?;
    if (back.lower_left_m - d.lower_left_m).length() > 1e-5
        || (back.lower_right_m() - d.lower_right_m()).length() > 1e-5
        || (back.upper_left_m() - d.upper_left_m()).length() > 1e-5
    {
        return Err(bad("the screen did not read back as written; the file was not changed".into()));
    }
    Ok(out)
}

/// Writes the screen into the rig file at `path` (see [`crate::safefile`]); refuses if the file
/// changed on disk since `read_text` was read.
pub fn update_display(path: &Path, read_text: &str, d: &Display, note: &str) -> Result<Replaced, CalibError> {
    let new = updated_display_text(read_text, &path.display().to_string(), d, note)?;
    let now = crate::read_text(path, "cannot re-read the rig file")?;
    if now != read_text {
        return Err(CalibError::RigFile {
            file: path.display().to_string(),
            message: "changed on disk while placing the screen; nothing was written: run the command again"
                .into(),
        });
    }
    crate::safefile::replace(path, &new, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use spidar_rt::rig::DEFAULT_RIG_RON;

    fn truth() -> Display {
        let f = DisplayFile {
            screen: ScreenFile::Centre {
                centre_m: [0.1, 0.0, -0.9],
                size_m: [1.8, 1.2],
                yaw_deg: 10.0,
                pitch_deg: -6.0,
                roll_deg: 2.0,
            },
            eye_separation_m: 0.063,
            stereo: Stereo::Mono,
        };
        validate(&f, DVec3::new(0.0, 0.35, 0.4)).unwrap()
    }

    fn held(d: &Display, r: f64) -> Vec<DVec3> {
        TARGETS
            .iter()
            .map(|&(a, b)| d.lower_left_m + d.right * a * d.width_m + d.up * b * d.height_m + d.normal() * r)
            .collect()
    }

    #[test]
    fn exact_grips_give_back_the_screen() {
        let t = truth();
        let p = fit_screen(&TARGETS, &held(&t, 0.04), 0.04, DVec3::new(0.0, 0.35, 0.4), 0.063, Stereo::Mono)
            .unwrap();
        let d = p.display;
        for (a, b) in [
            (d.lower_left_m, t.lower_left_m),
            (d.lower_right_m(), t.lower_right_m()),
            (d.upper_left_m(), t.upper_left_m()),
        ] {
            assert!((a - b).length() < 1e-9, "{a} vs {b}");
        }
        assert!(p.rms_m < 1e-9);
    }

    #[test]
    fn a_bad_placement_is_refused_saying_why() {
        let t = truth();
        let eye = DVec3::new(0.0, 0.35, 0.4);
        let mut g = held(&t, 0.04);
        // Target 3 held 3 cm off the screen.
        g[2] += t.normal() * 0.03;
        let e = fit_screen(&TARGETS, &g, 0.04, eye, 0.063, Stereo::Mono).unwrap_err().to_string();
        assert!(e.contains("target 3 was held"), "{e}");
        // On one line.
        let line: Vec<(f64, f64)> = vec![(0.1, 0.1), (0.5, 0.5), (0.9, 0.9)];
        let e =
            fit_screen(&line, &held(&t, 0.04)[..3], 0.04, eye, 0.063, Stereo::Mono).unwrap_err().to_string();
        assert!(e.contains("one line"), "{e}");
        // The targets visited in the wrong order: the right side and the left swapped.
        let g = held(&t, 0.04);
        let swapped = vec![g[1], g[0], g[3], g[2], g[4]];
        assert!(fit_screen(&TARGETS, &swapped, 0.04, eye, 0.063, Stereo::Mono).is_err());
    }

    #[test]
    fn the_screen_is_written_into_the_rig_file_and_reads_back() {
        let t = truth();
        let text = updated_display_text(DEFAULT_RIG_RON, "rig.ron", &t, "placed by a test").unwrap();
        let rig = Rig::from_str(&text, "rig.ron").unwrap();
        assert!((rig.display.unwrap().lower_left_m - t.lower_left_m).length() < 1e-5);
        // Every comment of the template is still there, and placing again replaces the section.
        for l in DEFAULT_RIG_RON.lines().filter(|l| l.trim_start().starts_with("//")) {
            assert!(text.contains(l), "lost: {l}");
        }
        let mut moved = t;
        moved.lower_left_m += DVec3::new(0.01, 0.0, 0.0);
        let again = updated_display_text(&text, "rig.ron", &moved, "placed again").unwrap();
        assert_eq!(again.matches("display:").count(), 1);
        let rig = Rig::from_str(&again, "rig.ron").unwrap();
        assert!((rig.display.unwrap().lower_left_m - moved.lower_left_m).length() < 1e-5);
    }
}
