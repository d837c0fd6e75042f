//! The rig model: the geometry and electrical constants of a SPIDAR-H, loaded from a RON rig file
//! (`configs/rig-spidar-h.ron`) and validated once into plain parameters.
//!
//! This is the only place where raw device units (counts, volts) meet SI units: metres per count
//! and volts per newton, each with the sign of its channel's winding. Nothing here runs in the
//! tick; the tick uses the plain `Rig` built from it.

use std::path::Path;

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::config::{self, ConfigError};

/// Rig file format version this build reads.
pub const RIG_FILE_VERSION: u32 = 1;

/// The default rig file, compiled in so `spidar run` works from any directory.
pub const DEFAULT_RIG_RON: &str = include_str!("../../configs/rig-spidar-h.ron");
pub const DEFAULT_RIG_NAME: &str = "configs/rig-spidar-h.ron (built in)";

// ---------------------------------------------------------------------------------------------
// File format (what a person edits). Every field is documented in the default rig file too.

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// File format version; must be 1.
    pub version: u32,
    /// Free text naming the rig.
    pub name: String,
    /// Tick period of the haptic loop.
    pub period_s: f64,
    /// The two 4-string units: hand 0 is the user's left hand, hand 1 the right.
    pub hands: Vec<HandFile>,
    /// Maps rig coordinates to world coordinates.
    pub rig_to_world: TransformFile,
    pub safety: SafetyFile,
    pub estimation: EstimationFile,
    /// When the counters were last homed and the geometry last fitted; written by `spidar calib`,
    /// absent in a rig file that was never calibrated.
    #[serde(default)]
    pub calibration: CalibrationFile,
    /// Per kind of board: what a string's command is, its real range and scale
    /// ([`crate::boards`]). Optional: every part has a default.
    #[serde(default)]
    pub boards: crate::boards::BoardsFile,
}

/// The calibration record of a rig file (informational: the geometry itself is in `hands`).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Last `spidar calib home --write`, UTC (RFC 3339); empty: never.
    #[serde(default)]
    pub homed_utc: String,
    /// Last `spidar calib fit --write`, UTC (RFC 3339); empty: never.
    #[serde(default)]
    pub fitted_utc: String,
    /// RMS string-length residual of that fit.
    #[serde(default)]
    pub fit_residual_rms_m: f64,
    /// The session file it was fitted from.
    #[serde(default)]
    pub session: String,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HandFile {
    /// Free text, e.g. "left".
    pub label: String,
    /// The four strings of this hand.
    pub strings: Vec<StringFile>,
    /// Lowest tension a string may be commanded while the rig is on; keeps strings taut.
    pub tension_min_n: f64,
    /// Highest tension a string may be commanded (motor limit).
    pub tension_max_n: f64,
    /// Largest force rendered on this hand; larger forces are scaled down along their direction.
    pub force_limit_n: f64,
    /// Where the grip is held for homing (rig frame).
    pub home_m: [f64; 3],
    /// Radius of the sphere that stands for the hand in contact rendering.
    pub grip_radius_m: f64,
    /// Stiffest contact rendered on this hand; stiffer proxies are softened to it.
    pub stiffness_limit_n_per_m: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StringFile {
    /// DA and counter channel of this string's motor on the board.
    pub channel: usize,
    /// Where the string leaves the frame (rig frame).
    pub anchor_m: [f64; 3],
    /// String length change per encoder count; negative if the counter runs backwards.
    pub metres_per_count: f64,
    /// String length when the counter reads zero; absent until the rig is homed or calibrated.
    #[serde(default)]
    pub length_at_zero_m: Option<f64>,
    /// DA volts per newton of string tension; negative if the motor winds the other way.
    pub volts_per_newton: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TransformFile {
    /// Rotation from rig to world as a unit quaternion (w, x, y, z).
    pub rotation_wxyz: [f64; 4],
    /// World position of the rig origin.
    pub translation_m: [f64; 3],
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SafetyFile {
    /// Force ramps from zero to full over this time after activation and after a fault clears.
    pub ramp_in_s: f64,
    /// On stop, force ramps to zero over this time before the strings go to minimum tension.
    pub ramp_out_s: f64,
    /// A contact model older than this is stale: its force starts fading.
    pub contact_stale_after_s: f64,
    /// Time for a stale model's force to fade from full to zero.
    pub contact_fade_s: f64,
    /// Kinematic residual (RMS over the 4 strings) above which the pose is not trusted and the hand faults.
    pub residual_fault_m: f64,
    /// Ticks in a row with a bad residual before the fault (a single noisy tick is tolerated).
    pub residual_fault_ticks: u32,
    /// Good exchanges in a row after a transient device fault before recovering; 0 = never.
    pub fault_recovery_ticks: u32,
    /// After the device reports a disconnect, try to reopen it this often (each attempt bounded
    /// to half a tick); 0 = never (restart spidar). Optional: 0.2 s when left out.
    #[serde(default = "default_device_reopen_s")]
    pub device_reopen_s: f64,
}

fn default_device_reopen_s() -> f64 {
    0.2
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct EstimationFile {
    /// Gauss-Newton iterations per tick after the closed-form seed.
    pub gauss_newton_iterations: u32,
    /// Cut-off of the velocity estimator's low-pass filter.
    pub velocity_cutoff_hz: f64,
}

// ---------------------------------------------------------------------------------------------
// Validated parameters (what the code uses).

#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub name: String,
    pub period_s: f64,
    pub hands: [HandRig; 2],
    pub rig_to_world: RigToWorld,
    pub safety: SafetyFile,
    pub estimation: EstimationFile,
    /// What the boards' commands mean and their ranges ([`crate::boards`]).
    pub boards: crate::boards::BoardScales,
}

#[derive(Clone, Debug, PartialEq)]
pub struct HandRig {
    pub label: String,
    pub channels: [usize; 4],
    pub anchors_m: [DVec3; 4],
    pub metres_per_count: [f64; 4],
    pub length_at_zero_m: Option<[f64; 4]>,
    pub volts_per_newton: [f64; 4],
    pub tension_min_n: f64,
    pub tension_max_n: f64,
    pub force_limit_n: f64,
    pub home_m: DVec3,
    pub grip_radius_m: f64,
    pub stiffness_limit_n_per_m: f64,
}

impl HandRig {
    /// Counter zero lengths that make the grip read `at_m` for these counts (homing).
    pub fn home_offsets(&self, counts: [i64; 4], at_m: DVec3) -> [f64; 4] {
        let mut out = [0.0; 4];
        for i in 0..4 {
            out[i] = (self.anchors_m[i] - at_m).length() - counts[i] as f64 * self.metres_per_count[i];
        }
        out
    }
}

/// Rigid transform from the rig frame to the world frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigToWorld {
    pub rotation: DQuat,
    pub translation_m: DVec3,
}

impl RigToWorld {
    pub fn point(&self, p_rig: DVec3) -> DVec3 {
        self.rotation * p_rig + self.translation_m
    }
    pub fn vector(&self, v_rig: DVec3) -> DVec3 {
        self.rotation * v_rig
    }
    pub fn point_to_rig(&self, p_world: DVec3) -> DVec3 {
        self.rotation.inverse() * (p_world - self.translation_m)
    }
    pub fn vector_to_rig(&self, v_world: DVec3) -> DVec3 {
        self.rotation.inverse() * v_world
    }
}

impl Rig {
    /// Loads and validates a rig file.
    pub fn load(path: &Path) -> Result<Rig, ConfigError> {
        let (file, text) = config::load_file_kind::<RigFile>(path, config::FileKind::Rig)?;
        Rig::validate(file, &text, &path.display().to_string())
    }

    /// The compiled-in default rig.
    pub fn default_rig() -> Rig {
        Rig::from_str(DEFAULT_RIG_RON, DEFAULT_RIG_NAME).expect("the built-in rig file is valid (tested)")
    }

    pub fn from_str(text: &str, origin: &str) -> Result<Rig, ConfigError> {
        let file = config::parse_kind::<RigFile>(text, origin, config::FileKind::Rig)?;
        Rig::validate(file, text, origin)
    }

    /// Checks every value and builds the plain parameters.
    pub fn validate(f: RigFile, text: &str, origin: &str) -> Result<Rig, ConfigError> {
        let bad = |field: String, key: &str, occ: usize, msg: String| {
            config::invalid(text, origin, &field, key, occ, msg)
        };
        if f.version != RIG_FILE_VERSION {
            return Err(bad(
                "version".into(),
                "version",
                0,
                format!(
                    "this build reads rig files of version {RIG_FILE_VERSION}, the file says {}",
                    f.version
                ),
            ));
        }
        if !(f.period_s.is_finite() && (1e-4..=1e-2).contains(&f.period_s)) {
            return Err(bad(
                "period_s".into(),
                "period_s",
                0,
                format!("{} s is outside 0.1 .. 10 ms", f.period_s),
            ));
        }
        if f.hands.len() != 2 {
            return Err(bad(
                "hands".into(),
                "hands",
                0,
                format!("a SPIDAR-H has two hands; the file lists {}", f.hands.len()),
            ));
        }
        let mut channels_seen = [false; spidar_device::MAX_CHANNELS];
        // How many length_at_zero_m fields came before: locates a bad one in the text.
        let mut zeros_seen = 0;
        let mut hands = Vec::with_capacity(2);
        for (h, hf) in f.hands.iter().enumerate() {
            let field = |name: &str| format!("hands[{h}].{name}");
            let fin = |v: f64| v.is_finite();
            if !(fin(hf.tension_min_n) && hf.tension_min_n > 0.0) {
                return Err(bad(
                    field("tension_min_n"),
                    "tension_min_n",
                    h,
                    format!("{} N: must be > 0 so strings stay taut", hf.tension_min_n),
                ));
            }
            if !(fin(hf.tension_max_n) && hf.tension_max_n > hf.tension_min_n) {
                return Err(bad(
                    field("tension_max_n"),
                    "tension_max_n",
                    h,
                    format!("{} N: must be above tension_min_n ({} N)", hf.tension_max_n, hf.tension_min_n),
                ));
            }
            if !(fin(hf.force_limit_n)
                && hf.force_limit_n >= 0.0
                && hf.force_limit_n <= 4.0 * hf.tension_max_n)
            {
                return Err(bad(
                    field("force_limit_n"),
                    "force_limit_n",
                    h,
                    format!("{} N: must be between 0 and 4 x tension_max_n", hf.force_limit_n),
                ));
            }
            if !(fin(hf.grip_radius_m) && (0.0..0.3).contains(&hf.grip_radius_m)) {
                return Err(bad(
                    field("grip_radius_m"),
                    "grip_radius_m",
                    h,
                    format!("{} m: must be in 0 .. 0.3 m", hf.grip_radius_m),
                ));
            }
            if !(fin(hf.stiffness_limit_n_per_m) && hf.stiffness_limit_n_per_m > 0.0) {
                return Err(bad(
                    field("stiffness_limit_n_per_m"),
                    "stiffness_limit_n_per_m",
                    h,
                    format!("{}: must be a positive number", hf.stiffness_limit_n_per_m),
                ));
            }
            if !hf.home_m.iter().all(|v| v.is_finite()) {
                return Err(bad(field("home_m"), "home_m", h, "must be three finite numbers".into()));
            }
            if hf.strings.len() != 4 {
                return Err(bad(
                    field("strings"),
                    "strings",
                    h,
                    format!("each hand has four strings; this one lists {}", hf.strings.len()),
                ));
            }
            let mut anchors = [DVec3::ZERO; 4];
            let mut mpc = [0.0; 4];
            let mut vpn = [0.0; 4];
            let mut chans = [0; 4];
            let mut zero = [0.0; 4];
            let mut zero_count = 0;
            for (s, sf) in hf.strings.iter().enumerate() {
                let occ = h * 4 + s;
                let sfield = |name: &str| format!("hands[{h}].strings[{s}].{name}");
                if sf.channel >= spidar_device::MAX_CHANNELS || channels_seen[sf.channel] {
                    return Err(bad(
                        sfield("channel"),
                        "channel",
                        occ,
                        format!(
                            "channel {} is {}: each string needs its own channel below {}",
                            sf.channel,
                            if sf.channel >= spidar_device::MAX_CHANNELS {
                                "out of range"
                            } else {
                                "used twice"
                            },
                            spidar_device::MAX_CHANNELS
                        ),
                    ));
                }
                channels_seen[sf.channel] = true;
                if !sf.anchor_m.iter().all(|v| v.is_finite() && v.abs() < 20.0) {
                    return Err(bad(
                        sfield("anchor_m"),
                        "anchor_m",
                        occ,
                        "must be three finite numbers within 20 m".into(),
                    ));
                }
                if !(fin(sf.metres_per_count)
                    && sf.metres_per_count != 0.0
                    && sf.metres_per_count.abs() < 1e-2)
                {
                    return Err(bad(
                        sfield("metres_per_count"),
                        "metres_per_count",
                        occ,
                        format!("{}: must be non-zero and below 1 cm per count", sf.metres_per_count),
                    ));
                }
                if !(fin(sf.volts_per_newton) && sf.volts_per_newton != 0.0) {
                    return Err(bad(
                        sfield("volts_per_newton"),
                        "volts_per_newton",
                        occ,
                        format!("{}: must be finite and non-zero", sf.volts_per_newton),
                    ));
                }
                if let Some(l) = sf.length_at_zero_m {
                    if !l.is_finite() {
                        return Err(bad(
                            sfield("length_at_zero_m"),
                            "length_at_zero_m",
                            zeros_seen,
                            "must be finite".into(),
                        ));
                    }
                    zero[s] = l;
                    zero_count += 1;
                    zeros_seen += 1;
                }
                anchors[s] = DVec3::from_array(sf.anchor_m);
                mpc[s] = sf.metres_per_count;
                vpn[s] = sf.volts_per_newton;
                chans[s] = sf.channel;
            }
            if zero_count != 0 && zero_count != 4 {
                return Err(bad(
                    field("strings"),
                    "strings",
                    h,
                    "length_at_zero_m is given for some strings of this hand but not all: give all four or none \
                     (then home the rig)"
                        .into(),
                ));
            }
            // The closed-form kinematics need the anchors to span space.
            let vol =
                (anchors[1] - anchors[0]).cross(anchors[2] - anchors[0]).dot(anchors[3] - anchors[0]) / 6.0;
            if vol.abs() < 1e-3 {
                return Err(bad(
                    field("strings"),
                    "strings",
                    h,
                    format!(
                        "the four anchors are (nearly) coplanar (tetrahedron volume {:.2e} m^3): \
                         check anchor_m; position cannot be computed",
                        vol.abs()
                    ),
                ));
            }
            hands.push(HandRig {
                label: hf.label.clone(),
                channels: chans,
                anchors_m: anchors,
                metres_per_count: mpc,
                length_at_zero_m: (zero_count == 4).then_some(zero),
                volts_per_newton: vpn,
                tension_min_n: hf.tension_min_n,
                tension_max_n: hf.tension_max_n,
                force_limit_n: hf.force_limit_n,
                home_m: DVec3::from_array(hf.home_m),
                grip_radius_m: hf.grip_radius_m,
                stiffness_limit_n_per_m: hf.stiffness_limit_n_per_m,
            });
        }
        let [w, x, y, z] = f.rig_to_world.rotation_wxyz;
        let q = DQuat::from_xyzw(x, y, z, w);
        if !(q.is_finite() && (q.length() - 1.0).abs() < 1e-6) {
            return Err(bad(
                "rig_to_world.rotation_wxyz".into(),
                "rotation_wxyz",
                0,
                format!("({w}, {x}, {y}, {z}) is not a unit quaternion (length {})", q.length()),
            ));
        }
        if !f.rig_to_world.translation_m.iter().all(|v| v.is_finite()) {
            return Err(bad(
                "rig_to_world.translation_m".into(),
                "translation_m",
                0,
                "must be finite".into(),
            ));
        }
        let s = &f.safety;
        let checks: [(&str, f64, f64, f64); 6] = [
            ("device_reopen_s", s.device_reopen_s, 0.0, 60.0),
            ("ramp_in_s", s.ramp_in_s, 0.0, 10.0),
            ("ramp_out_s", s.ramp_out_s, 0.0, 10.0),
            ("contact_stale_after_s", s.contact_stale_after_s, f.period_s, 1.0),
            ("contact_fade_s", s.contact_fade_s, 0.0, 5.0),
            ("residual_fault_m", s.residual_fault_m, 1e-5, 1.0),
        ];
        for (key, v, lo, hi) in checks {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(bad(format!("safety.{key}"), key, 0, format!("{v}: must be in {lo} .. {hi}")));
            }
        }
        let e = &f.estimation;
        if !(1..=10).contains(&e.gauss_newton_iterations) {
            return Err(bad(
                "estimation.gauss_newton_iterations".into(),
                "gauss_newton_iterations",
                0,
                format!("{}: must be 1 .. 10", e.gauss_newton_iterations),
            ));
        }
        let nyquist = 0.5 / f.period_s;
        if !(e.velocity_cutoff_hz.is_finite() && e.velocity_cutoff_hz > 0.0 && e.velocity_cutoff_hz < nyquist)
        {
            return Err(bad(
                "estimation.velocity_cutoff_hz".into(),
                "velocity_cutoff_hz",
                0,
                format!("{} Hz: must be in 0 .. {nyquist} Hz (half the tick rate)", e.velocity_cutoff_hz),
            ));
        }
        let boards = crate::boards::validate(&f.boards, &hands, |field, key, msg| bad(field, key, 0, msg))?;
        let hands: [HandRig; 2] = hands.try_into().expect("two hands");
        Ok(Rig {
            name: f.name,
            period_s: f.period_s,
            hands,
            rig_to_world: RigToWorld {
                rotation: q,
                translation_m: DVec3::from_array(f.rig_to_world.translation_m),
            },
            safety: f.safety,
            estimation: f.estimation,
            boards,
        })
    }

    /// Number of device channels the rig uses (highest channel + 1).
    pub fn channels(&self) -> usize {
        self.hands.iter().flat_map(|h| h.channels).max().map_or(0, |c| c + 1)
    }

    /// The simulated rig's plant parameters for this rig as its truth: the same geometry, counters
    /// zeroed with the grips at their home points (unless the file gives the zero lengths), motors
    /// limited to the tension maximum, grips starting at home, default arm.
    pub fn sim_hands(&self) -> [spidar_device::sim::SimHandParams; 2] {
        use spidar_device::sim::{SimHandParams, SimString};
        std::array::from_fn(|h| {
            let hr = &self.hands[h];
            let strings = std::array::from_fn(|s| SimString {
                anchor_m: hr.anchors_m[s],
                channel: hr.channels[s],
                metres_per_count: hr.metres_per_count[s],
                length_at_zero_m: match hr.length_at_zero_m {
                    Some(z) => z[s],
                    None => (hr.anchors_m[s] - hr.home_m).length(),
                },
                volts_per_newton: hr.volts_per_newton[s],
                tension_max_n: hr.tension_max_n,
            });
            SimHandParams::new(strings, hr.home_m)
        })
    }

    /// True when every string knows its length at counter zero.
    pub fn is_homed(&self) -> bool {
        self.hands.iter().all(|h| h.length_at_zero_m.is_some())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rig_loads_and_matches_the_reference_anchors() {
        let rig = Rig::default_rig();
        assert_eq!(rig.hands[0].anchors_m[0], DVec3::new(-1.75, 2.00, 1.12));
        assert_eq!(rig.hands[1].anchors_m[3], DVec3::new(-1.65, -0.98, 0.50));
        assert_eq!(rig.channels(), 8);
        assert_eq!(rig.period_s, 0.001);
    }

    fn with(replace: &str, by: &str) -> String {
        assert!(DEFAULT_RIG_RON.contains(replace), "{replace}");
        DEFAULT_RIG_RON.replacen(replace, by, 1)
    }

    #[test]
    fn bad_tension_range_names_file_line_and_field() {
        let text = with("tension_max_n: 20.0", "tension_max_n: 0.5");
        let e = Rig::from_str(&text, "rig.ron").unwrap_err();
        assert_eq!(e.field, "hands[0].tension_max_n");
        let line = text.lines().position(|l| l.contains("tension_max_n: 0.5")).unwrap() + 1;
        assert_eq!(e.line, line);
        assert!(e.to_string().contains("rig.ron:"));
    }

    #[test]
    fn duplicate_channel_is_rejected() {
        let text = with("channel: 1,", "channel: 0,");
        let e = Rig::from_str(&text, "rig.ron").unwrap_err();
        assert_eq!(e.field, "hands[0].strings[1].channel");
        assert!(e.message.contains("used twice"), "{}", e.message);
    }

    #[test]
    fn unknown_field_is_rejected_with_its_name() {
        let text = with("grip_radius_m:", "grip_radius_mm: 1.0, grip_radius_m:");
        let e = Rig::from_str(&text, "rig.ron").unwrap_err();
        assert_eq!(e.field, "grip_radius_mm");
        assert!(e.line > 0);
    }

    #[test]
    fn coplanar_anchors_are_rejected() {
        let mut f: RigFile = config::parse_kind(DEFAULT_RIG_RON, "x", config::FileKind::Rig).unwrap();
        for s in f.hands[1].strings.iter_mut() {
            s.anchor_m[2] = 0.5;
        }
        let e = Rig::validate(f, DEFAULT_RIG_RON, "x").unwrap_err();
        assert_eq!(e.field, "hands[1].strings");
        assert!(e.message.contains("coplanar"));
    }

    #[test]
    fn wrong_version_is_rejected() {
        let e = Rig::from_str(&with("version: 1", "version: 7"), "r").unwrap_err();
        assert_eq!(e.field, "version");
    }

    #[test]
    fn homing_offsets_make_the_home_point_read_back() {
        let rig = Rig::default_rig();
        let h = &rig.hands[0];
        let counts = [1234, -5678, 42, 0];
        let off = h.home_offsets(counts, h.home_m);
        for i in 0..4 {
            let l = off[i] + counts[i] as f64 * h.metres_per_count[i];
            assert!((l - (h.anchors_m[i] - h.home_m).length()).abs() < 1e-12);
        }
    }

    #[test]
    fn rig_to_world_round_trips() {
        let t =
            RigToWorld { rotation: DQuat::from_rotation_y(0.3), translation_m: DVec3::new(0.0, 1.1, 0.2) };
        let p = DVec3::new(0.3, -0.2, 0.5);
        assert!((t.point_to_rig(t.point(p)) - p).length() < 1e-12);
    }
}
