//! The rig's screen: the optional `display` section of the rig file (where the physical screen
//! hangs in the rig frame, how far apart the viewer's eyes are, which stereo format the screen
//! takes), checked once into a plain [`Display`].
//!
//! Why it exists: the live view's user's-eye camera draws through this rectangle from the rig
//! file's `eye_m` (a generalised, off-axis perspective projection), so a point of the rig frame is
//! drawn where the ray from the eye to it crosses the screen: life-size and where the grips are.
//! Its checks live here, apart from `rig.rs`'s, and every refusal names the field.
//!
//! What it must never do: accept a rectangle that cannot be a screen (NaN, degenerate, not a
//! rectangle, the eye behind it): the picture would be silently wrong. Nothing here runs in the
//! tick.

use glam::{DQuat, DVec3, EulerRot};
use serde::{Deserialize, Serialize};

/// The `display` section of a rig file (versioned with the rig file: part of version 1).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DisplayFile {
    /// Where the screen's picture is, in the rig frame: its corners, or its centre, size and
    /// orientation.
    pub screen: ScreenFile,
    /// Distance between the viewer's eyes, for stereo (m); the eyes sit on either side of the
    /// rig file's `eye_m` along the screen's horizontal. Optional: 0.063 m (an adult's average).
    #[serde(default = "default_eye_separation")]
    pub eye_separation_m: f64,
    /// What the screen takes: `Mono`, `SideBySide` or `TopBottom` (frame packing of a 3D
    /// projector or monitor: left eye left or on top), `Anaglyph` (red left, cyan right).
    /// Optional: `Mono`. The page's `?stereo=` overrides it.
    #[serde(default)]
    pub stereo: Stereo,
}

fn default_eye_separation() -> f64 {
    DEFAULT_EYE_SEPARATION_M
}

/// An adult's average interpupillary distance (m).
pub const DEFAULT_EYE_SEPARATION_M: f64 = 0.063;

/// The screen's rectangle (the lit picture, not the bezel), rig frame, metres.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum ScreenFile {
    /// Three corners as seen from the eye: lower left, lower right, upper left.
    Corners { lower_left_m: [f64; 3], lower_right_m: [f64; 3], upper_left_m: [f64; 3] },
    /// Centre, width and height, and the turn from a screen facing +z (toward the user, upright):
    /// yaw about y, then pitch about the turned x, then roll about the turned z (degrees).
    Centre { centre_m: [f64; 3], size_m: [f64; 2], yaw_deg: f64, pitch_deg: f64, roll_deg: f64 },
}

/// Stereo output of the user's-eye view.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
pub enum Stereo {
    #[default]
    Mono,
    SideBySide,
    TopBottom,
    Anaglyph,
}

impl Stereo {
    /// The wire code (`spidar_msg::DisplayInfo::stereo`) and the page's name.
    pub fn code(self) -> u8 {
        match self {
            Stereo::Mono => 0,
            Stereo::SideBySide => 1,
            Stereo::TopBottom => 2,
            Stereo::Anaglyph => 3,
        }
    }
}

/// A checked screen placement (rig frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Display {
    pub lower_left_m: DVec3,
    /// Unit vectors along the screen's width (to the right) and height (up), seen from the eye.
    pub right: DVec3,
    pub up: DVec3,
    pub width_m: f64,
    pub height_m: f64,
    pub eye_separation_m: f64,
    pub stereo: Stereo,
}

impl Display {
    pub fn lower_right_m(&self) -> DVec3 {
        self.lower_left_m + self.right * self.width_m
    }
    pub fn upper_left_m(&self) -> DVec3 {
        self.lower_left_m + self.up * self.height_m
    }
    pub fn centre_m(&self) -> DVec3 {
        self.lower_left_m + 0.5 * (self.right * self.width_m + self.up * self.height_m)
    }
    /// The screen's normal, toward the viewer.
    pub fn normal(&self) -> DVec3 {
        self.right.cross(self.up)
    }

    /// Where the ray from `eye_m` to `p_m` crosses the screen's plane, as (u, v) in metres from the
    /// lower-left corner along the width and the height; `None` when the point is not beyond the
    /// eye toward the screen (the ray never reaches the plane).
    pub fn crossing(&self, eye_m: DVec3, p_m: DVec3) -> Option<(f64, f64)> {
        let n = self.normal();
        let d = p_m - eye_m;
        let dn = d.dot(n);
        if dn >= 0.0 {
            return None;
        }
        let s = (self.lower_left_m - eye_m).dot(n) / dn;
        let x = eye_m + d * s - self.lower_left_m;
        Some((x.dot(self.right), x.dot(self.up)))
    }

    /// The eyes (left, right) for a viewer at `eye_m`: half the separation to either side along
    /// the screen's horizontal.
    pub fn eyes(&self, eye_m: DVec3) -> [DVec3; 2] {
        let h = self.right * (0.5 * self.eye_separation_m);
        [eye_m - h, eye_m + h]
    }

    /// A display from three corners (no checks: see [`validate`]).
    pub fn from_corners(ll: DVec3, lr: DVec3, ul: DVec3, eye_separation_m: f64, stereo: Stereo) -> Display {
        let (w, h) = (lr - ll, ul - ll);
        Display {
            lower_left_m: ll,
            right: w.normalize_or_zero(),
            up: h.normalize_or_zero(),
            width_m: w.length(),
            height_m: h.length(),
            eye_separation_m,
            stereo,
        }
    }
}

/// Smallest and largest screen side accepted (m): a phone is not a rig's screen, and nothing
/// larger than a room is.
pub const SIDE_RANGE_M: (f64, f64) = (0.05, 20.0);
/// How far a screen's corner angle may be from 90 degrees: corners measured by hand are within a
/// fraction of a degree; more means a corner was mistyped.
pub const RIGHT_ANGLE_TOLERANCE_DEG: f64 = 2.0;
/// The eye must be at least this far in front of the screen's plane (m).
pub const MIN_EYE_DISTANCE_M: f64 = 0.05;

/// A refusal: the field (below `display.`) and why.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// Dotted field path, e.g. `display.screen.upper_left_m`.
    pub field: String,
    /// The key to locate in the text (`upper_left_m`).
    pub key: &'static str,
    pub message: String,
}

fn refuse(field: &str, key: &'static str, message: String) -> Refusal {
    Refusal { field: format!("display.{field}"), key, message }
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Checks the section against the viewer's eye point (`eye_m`, rig frame) and builds the plain
/// display.
pub fn validate(f: &DisplayFile, eye_m: DVec3) -> Result<Display, Refusal> {
    let sep = f.eye_separation_m;
    if !(sep.is_finite() && (0.0..=0.1).contains(&sep)) {
        return Err(refuse(
            "eye_separation_m",
            "eye_separation_m",
            format!("{sep} m: must be 0 .. 0.1 m (an adult's eyes are about 0.063 m apart)"),
        ));
    }
    let d = match &f.screen {
        ScreenFile::Corners { lower_left_m, lower_right_m, upper_left_m } => {
            for (key, v) in [
                ("lower_left_m", lower_left_m),
                ("lower_right_m", lower_right_m),
                ("upper_left_m", upper_left_m),
            ] {
                if !finite3(v) || v.iter().any(|x| x.abs() > 20.0) {
                    return Err(refuse(
                        &format!("screen.{key}"),
                        key,
                        format!("{v:?}: every coordinate must be a finite number of metres within 20 m of the rig origin"),
                    ));
                }
            }
            let (ll, lr, ul) = (
                DVec3::from_array(*lower_left_m),
                DVec3::from_array(*lower_right_m),
                DVec3::from_array(*upper_left_m),
            );
            Display::from_corners(ll, lr, ul, sep, f.stereo)
        }
        ScreenFile::Centre { centre_m, size_m, yaw_deg, pitch_deg, roll_deg } => {
            if !finite3(centre_m) || centre_m.iter().any(|x| x.abs() > 20.0) {
                return Err(refuse(
                    "screen.centre_m",
                    "centre_m",
                    format!("{centre_m:?}: must be a finite point within 20 m of the rig origin"),
                ));
            }
            if !size_m.iter().all(|s| s.is_finite()) {
                return Err(refuse("screen.size_m", "size_m", format!("{size_m:?}: must be finite")));
            }
            for (key, v) in [("yaw_deg", yaw_deg), ("pitch_deg", pitch_deg), ("roll_deg", roll_deg)] {
                if !(v.is_finite() && v.abs() <= 360.0) {
                    return Err(refuse(
                        &format!("screen.{key}"),
                        key,
                        format!("{v}: must be a finite angle within +-360 degrees"),
                    ));
                }
            }
            let q = DQuat::from_euler(
                EulerRot::YXZ,
                yaw_deg.to_radians(),
                pitch_deg.to_radians(),
                roll_deg.to_radians(),
            );
            let (right, up) = (q * DVec3::X, q * DVec3::Y);
            let c = DVec3::from_array(*centre_m);
            let ll = c - 0.5 * (right * size_m[0] + up * size_m[1]);
            Display::from_corners(ll, ll + right * size_m[0], ll + up * size_m[1], sep, f.stereo)
        }
    };
    let (wkey, hkey, wfield, hfield) = match f.screen {
        ScreenFile::Corners { .. } => {
            ("lower_right_m", "upper_left_m", "screen.lower_right_m", "screen.upper_left_m")
        }
        ScreenFile::Centre { .. } => ("size_m", "size_m", "screen.size_m", "screen.size_m"),
    };
    for (key, field, side, what) in [(wkey, wfield, d.width_m, "width"), (hkey, hfield, d.height_m, "height")]
    {
        if !(SIDE_RANGE_M.0..=SIDE_RANGE_M.1).contains(&side) {
            return Err(refuse(
                field,
                key,
                format!(
                    "the screen's {what} would be {side:.3} m: a screen is {} .. {} m a side (a degenerate rectangle: \
                     check the corners)",
                    SIDE_RANGE_M.0, SIDE_RANGE_M.1
                ),
            ));
        }
    }
    let angle = d.right.dot(d.up).clamp(-1.0, 1.0).acos().to_degrees();
    if (angle - 90.0).abs() > RIGHT_ANGLE_TOLERANCE_DEG {
        return Err(refuse(
            hfield,
            hkey,
            format!(
                "the corners do not make a rectangle: the angle at the lower-left corner is {angle:.1} degrees, \
                 not 90 (+-{RIGHT_ANGLE_TOLERANCE_DEG}); measure the corners again"
            ),
        ));
    }
    // Square the up axis onto the right one (a hand-measured corner is off by a fraction of a
    // degree): the projection needs an orthonormal frame.
    let n = d.right.cross(d.up).normalize();
    let d = Display { up: n.cross(d.right).normalize(), ..d };
    let dist = (eye_m - d.lower_left_m).dot(d.normal());
    if !(dist.is_finite() && dist >= MIN_EYE_DISTANCE_M) {
        let side = if dist < 0.0 { "behind the screen (on its far side)" } else { "on the screen's plane" };
        return Err(refuse(
            "screen",
            "screen",
            format!(
                "the eye (eye_m {eye_m:?}) is {side}, {dist:.3} m from it: the eye must be in front, at least \
                 {MIN_EYE_DISTANCE_M} m; give the corners as seen from the eye (lower left, lower right, upper left), \
                 or fix eye_m"
            ),
        ));
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corners(ll: [f64; 3], lr: [f64; 3], ul: [f64; 3]) -> DisplayFile {
        DisplayFile {
            screen: ScreenFile::Corners { lower_left_m: ll, lower_right_m: lr, upper_left_m: ul },
            eye_separation_m: 0.063,
            stereo: Stereo::Mono,
        }
    }

    const EYE: DVec3 = DVec3::new(0.0, 0.35, 0.4);

    #[test]
    fn a_point_on_the_screen_crosses_at_itself_and_a_far_point_along_its_ray() {
        let d = validate(&corners([-1.0, -0.5, -1.2], [1.0, -0.5, -1.2], [-1.0, 1.0, -1.2]), EYE).unwrap();
        assert!((d.width_m - 2.0).abs() < 1e-12 && (d.height_m - 1.5).abs() < 1e-12);
        let (u, v) = d.crossing(EYE, DVec3::new(0.3, 0.2, -1.2)).unwrap();
        assert!((u - 1.3).abs() < 1e-12 && (v - 0.7).abs() < 1e-12, "{u} {v}");
        // Twice as far from the eye as the screen: the crossing is halfway.
        let far = EYE + (DVec3::new(0.3, 0.2, -1.2) - EYE) * 2.0;
        let (u2, v2) = d.crossing(EYE, far).unwrap();
        assert!((u2 - u).abs() < 1e-12 && (v2 - v).abs() < 1e-12);
        // A point behind the eye never reaches the screen.
        assert!(d.crossing(EYE, EYE + DVec3::Z).is_none());
    }

    #[test]
    fn centre_form_equals_the_corners_it_stands_for() {
        let f = DisplayFile {
            screen: ScreenFile::Centre {
                centre_m: [0.2, 0.3, -1.1],
                size_m: [1.6, 0.9],
                yaw_deg: 20.0,
                pitch_deg: -10.0,
                roll_deg: 0.0,
            },
            eye_separation_m: 0.06,
            stereo: Stereo::SideBySide,
        };
        let d = validate(&f, EYE).unwrap();
        assert!((d.centre_m() - DVec3::new(0.2, 0.3, -1.1)).length() < 1e-12);
        assert!((d.width_m - 1.6).abs() < 1e-12 && (d.height_m - 0.9).abs() < 1e-12);
        // Yawed 20 degrees about y: the width runs along (cos 20, 0, -sin 20).
        let a = 20f64.to_radians();
        assert!((d.right - DVec3::new(a.cos(), 0.0, -a.sin())).length() < 1e-12);
        let c = corners(d.lower_left_m.to_array(), d.lower_right_m().to_array(), d.upper_left_m().to_array());
        let d2 =
            validate(&DisplayFile { eye_separation_m: 0.06, stereo: Stereo::SideBySide, ..c }, EYE).unwrap();
        assert!((d2.lower_left_m - d.lower_left_m).length() < 1e-12);
        assert!((d2.up - d.up).length() < 1e-12);
    }

    #[test]
    fn the_eyes_sit_on_the_screens_horizontal() {
        let d = validate(&corners([-1.0, -0.5, -1.2], [1.0, -0.5, -0.8], [-1.0, 1.0, -1.2]), EYE).unwrap();
        let [l, r] = d.eyes(EYE);
        assert!(((r - l).length() - 0.063).abs() < 1e-12);
        assert!((r - l).normalize().dot(d.right) > 1.0 - 1e-12);
        assert!(((l + r) * 0.5 - EYE).length() < 1e-12);
    }

    fn refused(f: DisplayFile, field: &str, why: &str) {
        let e = validate(&f, EYE).unwrap_err();
        assert_eq!(e.field, field, "{e:?}");
        assert!(e.message.contains(why), "{e:?}");
    }

    #[test]
    fn a_screen_that_cannot_be_right_is_refused_naming_the_field() {
        // NaN.
        refused(
            corners([f64::NAN, 0.0, -1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, -1.0]),
            "display.screen.lower_left_m",
            "finite",
        );
        // Degenerate: two corners on one point.
        refused(
            corners([-1.0, 0.0, -1.0], [-1.0, 0.0, -1.0], [-1.0, 1.0, -1.0]),
            "display.screen.lower_right_m",
            "degenerate",
        );
        refused(
            corners([-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [-1.0, 0.001, -1.0]),
            "display.screen.upper_left_m",
            "degenerate",
        );
        // Not a rectangle (a parallelogram leaning 10 degrees).
        let lean = 1.0 * 10f64.to_radians().tan();
        refused(
            corners([-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [-1.0 + lean, 1.0, -1.0]),
            "display.screen.upper_left_m",
            "rectangle",
        );
        // The eye behind the screen: the corners given mirrored (as seen from behind).
        refused(
            corners([1.0, 0.0, -1.0], [-1.0, 0.0, -1.0], [1.0, 1.0, -1.0]),
            "display.screen",
            "behind the screen",
        );
        // A screen behind the user, facing away.
        refused(corners([-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [-1.0, 1.0, 1.0]), "display.screen", "behind");
        // Eye separation.
        let mut f = corners([-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, -1.0]);
        f.eye_separation_m = f64::NAN;
        refused(f.clone(), "display.eye_separation_m", "0 .. 0.1");
        f.eye_separation_m = 0.5;
        refused(f, "display.eye_separation_m", "0 .. 0.1");
        // Centre form: a zero size, a NaN angle.
        let centre = |size: [f64; 2], yaw: f64| DisplayFile {
            screen: ScreenFile::Centre {
                centre_m: [0.0, 0.0, -1.0],
                size_m: size,
                yaw_deg: yaw,
                pitch_deg: 0.0,
                roll_deg: 0.0,
            },
            eye_separation_m: 0.063,
            stereo: Stereo::Mono,
        };
        refused(centre([0.0, 1.0], 0.0), "display.screen.size_m", "degenerate");
        refused(centre([1.0, 1.0], f64::NAN), "display.screen.yaw_deg", "finite");
        // Turned half round: it faces away from the eye.
        refused(centre([1.0, 1.0], 180.0), "display.screen", "behind");
    }
}
