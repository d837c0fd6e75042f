//! The rig model: the geometry and electrical constants of a SPIDAR-H, loaded from a RON rig file
//! (`configs/rig-spidar-h.ron`) and validated once into plain parameters.
//!
//! This is the only place where raw device units (counts, volts) meet SI units: metres per count
//! and volts per newton, each with the sign of its channel's winding. Nothing here runs in the
//! tick; the tick uses the plain `Rig` built from it.

use std::path::Path;

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::bounds;
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
    /// Keys whose physical bounds (`bounds.rs`) this file may exceed, e.g. `["tension_max_n"]`;
    /// every override in effect is shown in the run summary. Optional: none when left out.
    #[serde(default)]
    pub overrides: Vec<String>,
    /// Per kind of board: what a string's command is, its real range and scale
    /// ([`crate::boards`]). Optional: every part has a default.
    #[serde(default)]
    pub boards: crate::boards::BoardsFile,
    /// The user's eye point (rig frame, m), for the live view's first-person camera; absent: the
    /// built-in [`DEFAULT_EYE_M`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eye_m: Option<[f64; 3]>,
    /// The rig's screen, for the live view's off-axis user's-eye camera ([`crate::display`]);
    /// absent: the view's camera is a plain perspective from `eye_m`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub display: Option<crate::display::DisplayFile>,
}

/// Where a standing user's eyes are when the file does not say (rig frame, m): 0.35 m above the
/// rig origin (1.45 m above the floor with the default `rig_to_world`), 0.4 m behind the grips'
/// home points.
pub const DEFAULT_EYE_M: [f64; 3] = [0.0, 0.35, 0.4];

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
    /// Stiffest contact rendered on this hand; stiffer proxies are softened to it. At most
    /// `2 grip_damping_n_s_per_m / (3 period_s)`, the stability bound (`bounds.rs`).
    pub stiffness_limit_n_per_m: f64,
    /// Lower estimate of the physical damping the user's arm and the string drive give this grip.
    /// Optional: 8 N s/m when left out.
    #[serde(default = "default_grip_damping")]
    pub grip_damping_n_s_per_m: f64,
}

fn default_grip_damping() -> f64 {
    8.0
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
    /// Ticks in a row without a usable reply (late, missing or corrupt) that fault the rig; each
    /// shorter run holds the last output and is counted. Optional: 5 when left out.
    #[serde(default = "default_reply_fault_ticks")]
    pub reply_fault_ticks: u32,
    /// A string length further than this from where the hand's last pose and velocity predict it
    /// (per tick since the last accepted reply) marks the reply corrupt: held and counted.
    /// Optional: 2 mm when left out.
    #[serde(default = "default_reply_jump_m")]
    pub reply_jump_m: f64,
    /// After homing was lost (a fault during homing, a reopened device) the rig homes itself when
    /// every string stays within this length for `rehome_still_s`. Optional: 3 mm when left out.
    #[serde(default = "default_rehome_still_m")]
    pub rehome_still_m: f64,
    /// See `rehome_still_m`. Optional: 1 s when left out.
    #[serde(default = "default_rehome_still_s")]
    pub rehome_still_s: f64,
    /// After the device reports a disconnect, try to reopen it this often (each attempt bounded
    /// to half a tick); 0 = never (restart spidar). Optional: 0.2 s when left out.
    #[serde(default = "default_device_reopen_s")]
    pub device_reopen_s: f64,
}

fn default_device_reopen_s() -> f64 {
    0.2
}
fn default_reply_fault_ticks() -> u32 {
    5
}
fn default_reply_jump_m() -> f64 {
    0.002
}
fn default_rehome_still_m() -> f64 {
    0.003
}
fn default_rehome_still_s() -> f64 {
    1.0
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
    /// The physical bounds this rig file overrides (shown in the run summary).
    pub overrides: Vec<String>,
    /// What the boards' commands mean and their ranges ([`crate::boards`]).
    pub boards: crate::boards::BoardScales,
    /// The user's eye point (rig frame).
    pub eye_m: DVec3,
    /// The rig's screen (rig frame), if the file places one.
    pub display: Option<crate::display::Display>,
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
    pub grip_damping_n_s_per_m: f64,
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
        Rig::load_with_overrides(path, &[])
    }

    /// Loads and validates a rig file with more overrides than it lists itself (a command line's
    /// `--override KEY`); they are checked and shown like the file's own.
    pub fn load_with_overrides(path: &Path, extra: &[String]) -> Result<Rig, ConfigError> {
        let (mut file, text) = config::load_file_kind::<RigFile>(path, config::FileKind::Rig)?;
        file.overrides.extend(extra.iter().cloned());
        Rig::validate(file, &text, &path.display().to_string())
    }

    /// The compiled-in default rig.
    pub fn default_rig() -> Rig {
        Rig::from_str(DEFAULT_RIG_RON, DEFAULT_RIG_NAME).expect("the built-in rig file is valid (tested)")
    }

    pub fn from_str(text: &str, origin: &str) -> Result<Rig, ConfigError> {
        Rig::from_str_with_overrides(text, origin, &[])
    }

    /// [`Rig::from_str`] with more overrides (see [`Rig::load_with_overrides`]).
    pub fn from_str_with_overrides(text: &str, origin: &str, extra: &[String]) -> Result<Rig, ConfigError> {
        let mut file = config::parse_kind::<RigFile>(text, origin, config::FileKind::Rig)?;
        file.overrides.extend(extra.iter().cloned());
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
        let eye = f.eye_m.unwrap_or(DEFAULT_EYE_M);
        if !eye.iter().all(|v| v.is_finite() && v.abs() < 10.0) {
            return Err(bad(
                "eye_m".into(),
                "eye_m",
                0,
                "must be finite, within 10 m of the rig origin".into(),
            ));
        }
        let display = match &f.display {
            Some(d) => Some(
                crate::display::validate(d, DVec3::from_array(eye))
                    .map_err(|r| bad(r.field, r.key, 0, r.message))?,
            ),
            None => None,
        };
        for (i, o) in f.overrides.iter().enumerate() {
            if !bounds::OVERRIDABLE.contains(&o.as_str()) {
                return Err(bad(
                    format!("overrides[{i}]"),
                    "overrides",
                    0,
                    format!(
                        "\"{o}\" is not a bound that can be overridden; known: {}",
                        bounds::OVERRIDABLE.join(", ")
                    ),
                ));
            }
        }
        let overridden = |key: &str| f.overrides.iter().any(|o| o == key);
        // A physical bound: `v` must lie in `b` unless the file overrides `key`. Hard limits
        // (finite, sign) are checked by the caller first and are never overridable.
        let phys = |b: &bounds::Bound, key: &str, v: f64, field: String, occ: usize| {
            if b.holds(v) || overridden(key) {
                return Ok(());
            }
            Err(bad(
                field,
                key,
                occ,
                format!(
                    "{v}: outside the safe range {} .. {} because {}; fix the value, or list \"{key}\" in \
                     overrides to accept it (the run summary will show it)",
                    b.lo, b.hi, b.why
                ),
            ))
        };
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
            phys(&bounds::TENSION_MIN_N, "tension_min_n", hf.tension_min_n, field("tension_min_n"), h)?;
            if !(fin(hf.tension_max_n) && hf.tension_max_n >= 2.0 * hf.tension_min_n) {
                return Err(bad(
                    field("tension_max_n"),
                    "tension_max_n",
                    h,
                    format!(
                        "{} N: must be at least twice tension_min_n ({} N), or no force is left to render",
                        hf.tension_max_n, hf.tension_min_n
                    ),
                ));
            }
            phys(&bounds::TENSION_MAX_N, "tension_max_n", hf.tension_max_n, field("tension_max_n"), h)?;
            if !(fin(hf.force_limit_n) && hf.force_limit_n > 0.0) {
                return Err(bad(
                    field("force_limit_n"),
                    "force_limit_n",
                    h,
                    format!("{} N: must be a positive number of newtons", hf.force_limit_n),
                ));
            }
            if !(fin(hf.grip_radius_m) && hf.grip_radius_m > 0.0) {
                return Err(bad(
                    field("grip_radius_m"),
                    "grip_radius_m",
                    h,
                    format!("{} m: must be a positive number of metres", hf.grip_radius_m),
                ));
            }
            phys(&bounds::GRIP_RADIUS_M, "grip_radius_m", hf.grip_radius_m, field("grip_radius_m"), h)?;
            if !(fin(hf.grip_damping_n_s_per_m) && hf.grip_damping_n_s_per_m > 0.0) {
                return Err(bad(
                    field("grip_damping_n_s_per_m"),
                    "grip_damping_n_s_per_m",
                    h,
                    format!("{}: must be a positive number", hf.grip_damping_n_s_per_m),
                ));
            }
            phys(
                &bounds::GRIP_DAMPING_N_S_PER_M,
                "grip_damping_n_s_per_m",
                hf.grip_damping_n_s_per_m,
                field("grip_damping_n_s_per_m"),
                h,
            )?;
            if !(fin(hf.stiffness_limit_n_per_m) && hf.stiffness_limit_n_per_m > 0.0) {
                return Err(bad(
                    field("stiffness_limit_n_per_m"),
                    "stiffness_limit_n_per_m",
                    h,
                    format!("{}: must be a positive number", hf.stiffness_limit_n_per_m),
                ));
            }
            let k_max = bounds::stiffness_limit_n_per_m(hf.grip_damping_n_s_per_m, f.period_s);
            if hf.stiffness_limit_n_per_m > k_max && !overridden("stiffness_limit_n_per_m") {
                return Err(bad(
                    field("stiffness_limit_n_per_m"),
                    "stiffness_limit_n_per_m",
                    h,
                    format!(
                        "{} N/m: above {k_max:.0} N/m, the stiffest contact that stays stable at this rig's \
                         period ({} s) on a grip damped by {} N s/m: K_max = 2 b / (3 T) (one tick of delay \
                         plus the hold act as negative damping 1.5 K T; see docs/safety.md). Lower it, or \
                         list \"stiffness_limit_n_per_m\" in overrides",
                        hf.stiffness_limit_n_per_m, f.period_s, hf.grip_damping_n_s_per_m
                    ),
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
                if !(fin(sf.metres_per_count) && sf.metres_per_count != 0.0) {
                    return Err(bad(
                        sfield("metres_per_count"),
                        "metres_per_count",
                        occ,
                        format!("{}: must be finite and non-zero", sf.metres_per_count),
                    ));
                }
                let key = "metres_per_count";
                phys(&bounds::METRES_PER_COUNT, key, sf.metres_per_count.abs(), sfield(key), occ)?;
                if !(fin(sf.volts_per_newton) && sf.volts_per_newton != 0.0) {
                    return Err(bad(
                        sfield("volts_per_newton"),
                        "volts_per_newton",
                        occ,
                        format!("{}: must be finite and non-zero", sf.volts_per_newton),
                    ));
                }
                let key = "volts_per_newton";
                phys(&bounds::VOLTS_PER_NEWTON, key, sf.volts_per_newton.abs(), sfield(key), occ)?;
                if let Some(l) = sf.length_at_zero_m {
                    if !l.is_finite() {
                        return Err(bad(
                            sfield("length_at_zero_m"),
                            "length_at_zero_m",
                            zeros_seen,
                            "must be finite".into(),
                        ));
                    }
                    let key = "length_at_zero_m";
                    phys(&bounds::LENGTH_AT_ZERO_M, key, l, sfield(key), zeros_seen)?;
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
            let home = DVec3::from_array(hf.home_m);
            let inside = bounds::inside_margin(&anchors, home);
            if inside < bounds::HOME_INSIDE_MARGIN && !overridden("home_m") {
                return Err(bad(
                    field("home_m"),
                    "home_m",
                    h,
                    format!(
                        "({}, {}, {}) is not inside this hand's frame (the tetrahedron of its four anchors, \
                         with a margin of {:.0} % of its size): there the strings cannot hold zero net force, \
                         so neither the safe output nor homing works. Move the home point inside the frame, \
                         or list \"home_m\" in overrides",
                        hf.home_m[0],
                        hf.home_m[1],
                        hf.home_m[2],
                        bounds::HOME_INSIDE_MARGIN * 100.0
                    ),
                ));
            }
            // What the strings can produce at home: the largest force over 26 directions that the
            // allocator renders within the tension range.
            let capacity = bounds::force_capacity_n(&anchors, home, hf.tension_min_n, hf.tension_max_n);
            if hf.force_limit_n > capacity && !overridden("force_limit_n") {
                return Err(bad(
                    field("force_limit_n"),
                    "force_limit_n",
                    h,
                    format!(
                        "{} N: the strings can produce at most {capacity:.1} N at the home point with tensions \
                         {} .. {} N, so this limit can never bind and hides a typo; lower it (the lab clipped \
                         at 4 N), or list \"force_limit_n\" in overrides",
                        hf.force_limit_n, hf.tension_min_n, hf.tension_max_n
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
                home_m: home,
                grip_radius_m: hf.grip_radius_m,
                stiffness_limit_n_per_m: hf.stiffness_limit_n_per_m,
                grip_damping_n_s_per_m: hf.grip_damping_n_s_per_m,
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
        // Hard ranges: outside them the rule itself breaks (a fade of 0 or -0.0 never fades).
        let hard: [(&str, f64, f64, f64); 8] = [
            ("device_reopen_s", s.device_reopen_s, 0.0, 60.0),
            ("ramp_in_s", s.ramp_in_s, 0.0, 10.0),
            ("ramp_out_s", s.ramp_out_s, 0.0, 10.0),
            ("contact_stale_after_s", s.contact_stale_after_s, f.period_s, 1.0),
            ("contact_fade_s", s.contact_fade_s, f.period_s, 5.0),
            ("residual_fault_m", s.residual_fault_m, 1e-5, 1.0),
            ("reply_jump_m", s.reply_jump_m, 1e-5, 1.0),
            ("rehome_still_s", s.rehome_still_s, f.period_s, 60.0),
        ];
        for (key, v, lo, hi) in hard {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(bad(format!("safety.{key}"), key, 0, format!("{v}: must be in {lo} .. {hi}")));
            }
        }
        let sf = |k: &str| format!("safety.{k}");
        phys(&bounds::RAMP_S, "ramp_in_s", s.ramp_in_s, sf("ramp_in_s"), 0)?;
        phys(&bounds::RAMP_S, "ramp_out_s", s.ramp_out_s, sf("ramp_out_s"), 0)?;
        phys(&bounds::CONTACT_FADE_S, "contact_fade_s", s.contact_fade_s, sf("contact_fade_s"), 0)?;
        phys(&bounds::RESIDUAL_FAULT_M, "residual_fault_m", s.residual_fault_m, sf("residual_fault_m"), 0)?;
        phys(&bounds::REPLY_JUMP_M, "reply_jump_m", s.reply_jump_m, sf("reply_jump_m"), 0)?;
        let counts: [(&str, u32, &bounds::Bound); 3] = [
            ("residual_fault_ticks", s.residual_fault_ticks, &bounds::RESIDUAL_FAULT_TICKS),
            ("reply_fault_ticks", s.reply_fault_ticks, &bounds::REPLY_FAULT_TICKS),
            ("fault_recovery_ticks", s.fault_recovery_ticks, &bounds::FAULT_RECOVERY_TICKS),
        ];
        for (key, v, b) in counts {
            let never_recover = key == "fault_recovery_ticks" && v == 0;
            if v == 0 && !never_recover {
                return Err(bad(sf(key), key, 0, "0: must be at least 1".into()));
            }
            if !never_recover {
                phys(b, key, v as f64, sf(key), 0)?;
            }
        }
        // Stillness must be judged well above the encoder's resolution (10 counts of the
        // coarsest string), or the noise alone would keep the rig from homing itself.
        let coarsest = hands.iter().flat_map(|h| h.metres_per_count).fold(0.0_f64, |a, m| a.max(m.abs()));
        if !(s.rehome_still_m.is_finite() && s.rehome_still_m >= 10.0 * coarsest) {
            return Err(bad(
                sf("rehome_still_m"),
                "rehome_still_m",
                0,
                format!(
                    "{} m: must be at least 10 encoder counts ({:.2e} m), or encoder noise alone keeps the rig \
                     from homing itself",
                    s.rehome_still_m,
                    10.0 * coarsest
                ),
            ));
        }
        phys(&bounds::REHOME_STILL_M, "rehome_still", s.rehome_still_m, sf("rehome_still_m"), 0)?;
        phys(&bounds::REHOME_STILL_S, "rehome_still", s.rehome_still_s, sf("rehome_still_s"), 0)?;
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
            overrides: f.overrides,
            boards,
            eye_m: DVec3::from_array(eye),
            display,
        })
    }

    /// Refuses a board whose command range clips the tensions this rig asks for (checked at start,
    /// once the board is known), unless the rig file overrides `board_range`. `volts_max` is the
    /// board's range in volts of the host scale.
    pub fn check_board_range(&self, board: &str, volts_max: f64) -> Result<(), String> {
        let clipped = bounds::check_board_range(
            [self.hands[0].tension_max_n, self.hands[1].tension_max_n],
            [self.hands[0].volts_per_newton, self.hands[1].volts_per_newton],
            volts_max,
        );
        if clipped.is_empty() || self.overrides.iter().any(|o| o == "board_range") {
            return Ok(());
        }
        Err(format!(
            "tension_max_n is beyond the DA range of {board} on {} strings (first: {}): the board would clip \
             those commands, so the rig would not render what it computes; lower tension_max_n or check \
             volts_per_newton in the rig file, or list \"board_range\" in its overrides",
            clipped.len(),
            clipped[0]
        ))
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

    /// The default rig file with the first `replace` changed to `by`: must be refused on `field`,
    /// located at the changed line, with a reason containing `why`.
    fn refused(replace: &str, by: &str, field: &str, why: &str) -> ConfigError {
        let text = with(replace, by);
        let e = Rig::from_str(&text, "rig.ron").unwrap_err();
        assert_eq!(e.field, field, "{e}");
        let line = text.lines().position(|l| l.contains(by.trim_end_matches(','))).unwrap() + 1;
        assert_eq!(e.line, line, "{e}");
        assert!(e.column > 0);
        assert!(e.message.contains(why), "{e}");
        assert!(e.to_string().starts_with(&format!("rig.ron:{line}:")), "{e}");
        e
    }

    // One test per dangerous value an operator could write (issue 17's list), each refused with
    // its reason.
    macro_rules! refuses {
        ($name:ident, $replace:expr, $by:expr, $field:expr, $why:expr) => {
            #[test]
            fn $name() {
                refused($replace, $by, $field, $why);
            }
        };
    }
    refuses!(
        refuses_tension_max_beyond_the_motors,
        "tension_max_n: 20.0",
        "tension_max_n: 1e6",
        "hands[0].tension_max_n",
        "motors"
    );
    refuses!(
        refuses_a_force_limit_the_strings_cannot_produce,
        "force_limit_n: 4.0",
        "force_limit_n: 400.0",
        "hands[0].force_limit_n",
        "strings can produce at most"
    );
    refuses!(
        refuses_a_zero_force_limit,
        "force_limit_n: 4.0",
        "force_limit_n: 0.0",
        "hands[0].force_limit_n",
        "positive"
    );
    refuses!(
        refuses_a_stiffness_beyond_the_stability_bound,
        "stiffness_limit_n_per_m: 5000.0",
        "stiffness_limit_n_per_m: 1e9",
        "hands[0].stiffness_limit_n_per_m",
        "K_max = 2 b / (3 T)"
    );
    refuses!(
        refuses_a_minimum_tension_that_pulls_in_the_safe_output,
        "tension_min_n: 1.0",
        "tension_min_n: 9.0",
        "hands[0].tension_min_n",
        "safe output"
    );
    refuses!(
        refuses_a_zero_minimum_tension,
        "tension_min_n: 1.0",
        "tension_min_n: 0.0",
        "hands[0].tension_min_n",
        "taut"
    );
    refuses!(
        refuses_a_ramp_in_of_zero,
        "ramp_in_s: 0.5",
        "ramp_in_s: 0.0",
        "safety.ramp_in_s",
        "step of full force"
    );
    refuses!(
        refuses_a_ramp_out_of_zero,
        "ramp_out_s: 0.3",
        "ramp_out_s: 0.0",
        "safety.ramp_out_s",
        "step of full force"
    );
    refuses!(
        refuses_a_residual_check_switched_off,
        "residual_fault_ticks: 20",
        "residual_fault_ticks: 4294967295",
        "safety.residual_fault_ticks",
        "switches the pose check off"
    );
    refuses!(
        refuses_recovery_after_a_single_good_tick,
        "fault_recovery_ticks: 30",
        "fault_recovery_ticks: 1",
        "safety.fault_recovery_ticks",
        "at least 10 times"
    );
    refuses!(
        refuses_holding_the_output_for_long,
        "reply_fault_ticks: 5",
        "reply_fault_ticks: 1000",
        "safety.reply_fault_ticks",
        "20 ms"
    );
    refuses!(
        refuses_metres_per_count_of_1e_300,
        "metres_per_count: 2.924062107079e-5",
        "metres_per_count: 1e-300",
        "hands[0].strings[0].metres_per_count",
        "pulley"
    );
    refuses!(
        refuses_volts_per_newton_of_1000,
        "volts_per_newton: 0.2",
        "volts_per_newton: 1000.0",
        "hands[0].strings[0].volts_per_newton",
        "amplifiers"
    );
    refuses!(
        refuses_a_home_point_15_m_outside_the_frame,
        "home_m: (-0.15, 0.0, 0.0)",
        "home_m: (15.0, 0.0, 0.0)",
        "hands[0].home_m",
        "not inside this hand's frame"
    );
    refuses!(
        refuses_a_negative_length_at_zero,
        "volts_per_newton: 0.2)",
        "volts_per_newton: 0.2, length_at_zero_m: Some(-1.0))",
        "hands[0].strings[0].length_at_zero_m",
        "never negative"
    );
    refuses!(
        refuses_a_contact_fade_of_minus_zero,
        "contact_fade_s: 0.1",
        "contact_fade_s: -0.0",
        "safety.contact_fade_s",
        "must be in"
    );
    refuses!(
        refuses_a_stillness_tolerance_below_the_encoder_noise,
        "rehome_still_m: 0.003",
        "rehome_still_m: 0.0001",
        "safety.rehome_still_m",
        "encoder"
    );

    #[test]
    fn an_override_accepts_a_value_beyond_its_bound_and_is_kept_for_the_summary() {
        let text = with("tension_max_n: 20.0", "tension_max_n: 30.0");
        assert!(Rig::from_str(&text, "r").is_err());
        let text = text.replace("overrides: [],", "overrides: [\"tension_max_n\"],");
        let rig = Rig::from_str(&text, "r").unwrap();
        assert_eq!(rig.hands[0].tension_max_n, 30.0);
        assert_eq!(rig.overrides, vec!["tension_max_n".to_string()]);
        // Hard limits are never overridable.
        let text = text.replace("contact_fade_s: 0.1", "contact_fade_s: -0.0");
        let text = text.replace(
            "overrides: [\"tension_max_n\"],",
            "overrides: [\"tension_max_n\", \"contact_fade_s\"],",
        );
        assert_eq!(Rig::from_str(&text, "r").unwrap_err().field, "safety.contact_fade_s");
        // An unknown override name is an error that lists the known ones.
        let text = DEFAULT_RIG_RON.replace("overrides: [],", "overrides: [\"everything\"],");
        let e = Rig::from_str(&text, "r").unwrap_err();
        assert!(e.field == "overrides[0]" && e.message.contains("tension_max_n"), "{e}");
    }

    #[test]
    fn the_default_rig_is_inside_every_bound_with_room() {
        let rig = Rig::default_rig();
        assert!(rig.overrides.is_empty());
        for h in &rig.hands {
            let cap = bounds::force_capacity_n(&h.anchors_m, h.home_m, h.tension_min_n, h.tension_max_n);
            assert!(cap > 2.0 * h.force_limit_n, "capacity {cap} N");
            let inside = bounds::inside_margin(&h.anchors_m, h.home_m);
            assert!(inside > 2.0 * bounds::HOME_INSIDE_MARGIN, "{inside}");
            let k_max = bounds::stiffness_limit_n_per_m(h.grip_damping_n_s_per_m, rig.period_s);
            assert!(h.stiffness_limit_n_per_m <= k_max, "{k_max}");
        }
    }

    #[test]
    fn the_board_range_is_refused_unless_overridden() {
        let rig = Rig::default_rig();
        assert!(rig.check_board_range("B", 4.0).is_ok(), "20 N x 0.2 V/N = 4 V fits");
        let e = rig.check_board_range("UART B1M", 3.3).unwrap_err();
        assert!(e.contains("UART B1M") && e.contains("8 strings") && e.contains("board_range"), "{e}");
        let mut over = rig.clone();
        over.overrides.push("board_range".into());
        assert!(over.check_board_range("UART B1M", 3.3).is_ok());
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
