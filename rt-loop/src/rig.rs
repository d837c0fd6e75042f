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
use crate::config::{self, At, Checker, ConfigError};
use spidar_msg::strings::StringClearance;

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
    /// When a string counts as near another hand's string or the user's forearm (the live view
    /// marks it; `spidar rig map` reports where it happens); absent: the defaults of
    /// [`NearStringsFile`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near_strings: Option<NearStringsFile>,
}

/// The rig file's `near_strings`: every field optional, defaults those of
/// `spidar_msg::strings::StringClearance` (1 cm; an adult forearm in a guard posture).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NearStringsFile {
    /// A string closer than this to another hand's string or to the forearm's surface is near.
    #[serde(default = "near_default_distance")]
    pub distance_m: f64,
    /// The forearm capsule: from the grip toward the elbow, the left hand's (rig frame; the right
    /// hand's is mirrored in x), need not be a unit vector.
    #[serde(default = "near_default_toward_elbow")]
    pub forearm_toward_elbow: [f64; 3],
    /// From the grip's centre to the wrist (the capsule's start), m.
    #[serde(default = "near_default_wrist")]
    pub forearm_wrist_m: f64,
    /// From the grip's centre to the elbow (the capsule's end), m.
    #[serde(default = "near_default_elbow")]
    pub forearm_elbow_m: f64,
    /// The forearm's radius, m.
    #[serde(default = "near_default_radius")]
    pub forearm_radius_m: f64,
}

fn near_default_distance() -> f64 {
    StringClearance::default().distance_m
}
fn near_default_toward_elbow() -> [f64; 3] {
    StringClearance::default().forearm.toward_elbow.to_array()
}
fn near_default_wrist() -> f64 {
    StringClearance::default().forearm.wrist_m
}
fn near_default_elbow() -> f64 {
    StringClearance::default().forearm.elbow_m
}
fn near_default_radius() -> f64 {
    StringClearance::default().forearm.radius_m
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
    /// When a string counts as near another hand's string or the forearm (rig frame).
    pub near_strings: StringClearance,
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

/// The volts the rig's strings need at their highest tension.
pub fn volts_needed(hands: &[HandRig]) -> f64 {
    hands
        .iter()
        .flat_map(|h| h.volts_per_newton.iter().map(move |v| h.tension_max_n * v.abs()))
        .fold(0.0, f64::max)
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

    /// Checks every value and builds the plain parameters: each section of the file by its own
    /// function below, every check through the one located [`Checker`] with its bound's reason.
    pub fn validate(f: RigFile, text: &str, origin: &str) -> Result<Rig, ConfigError> {
        let c = Checker::new(text, origin).with_overrides(&f.overrides);
        check_header(&c, &f)?;
        let eye = f.eye_m.unwrap_or(DEFAULT_EYE_M);
        c.finite_within(&At::key("eye_m"), &eye, bounds::EYE_M, "m of the rig origin")?;
        let display = match &f.display {
            Some(d) => Some(
                crate::display::validate(d, DVec3::from_array(eye))
                    .map_err(|r| c.error(&At::new(r.field, r.key, 0), r.message))?,
            ),
            None => None,
        };
        c.count(&At::key("hands"), f.hands.len(), 2, 2, "hands (a SPIDAR-H has two)")?;
        let mut seen = Seen { channels: [false; spidar_device::MAX_CHANNELS], zeros: 0 };
        let left = check_hand(&c, 0, &f.hands[0], f.period_s, &mut seen)?;
        let right = check_hand(&c, 1, &f.hands[1], f.period_s, &mut seen)?;
        let hands = [left, right];
        let rig_to_world = check_transform(&c, &f.rig_to_world)?;
        check_safety(&c, &f.safety, f.period_s, &hands)?;
        check_estimation(&c, &f.estimation, f.period_s)?;
        let boards = crate::boards::validate(&f.boards, volts_needed(&hands), &c)?;
        let near_strings = check_near_strings(&c, f.near_strings.as_ref())?;
        Ok(Rig {
            name: f.name,
            period_s: f.period_s,
            hands,
            rig_to_world,
            safety: f.safety,
            estimation: f.estimation,
            overrides: f.overrides,
            boards,
            eye_m: DVec3::from_array(eye),
            display,
            near_strings,
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

// ---------------------------------------------------------------------------------------------
// The rig file's checks, one function per section (called by `Rig::validate`).

/// What earlier hands used, for checks across hands: channels taken, and how many
/// `length_at_zero_m` entries came before (an optional key: it locates the n-th one in the text).
struct Seen {
    channels: [bool; spidar_device::MAX_CHANNELS],
    zeros: usize,
}

/// The version, the overrides' names and the tick period.
/// The file's `near_strings` (the defaults when absent): a distance and a forearm that make sense.
fn check_near_strings(c: &Checker, f: Option<&NearStringsFile>) -> Result<StringClearance, ConfigError> {
    let Some(f) = f else { return Ok(StringClearance::default()) };
    let at = |key: &'static str| At::new(format!("near_strings.{key}"), key, 0);
    let distance_m = c.within(&at("distance_m"), f.distance_m, &bounds::NEAR_STRINGS_M)?;
    let toward = at("forearm_toward_elbow");
    c.finite_within(&toward, &f.forearm_toward_elbow, 10.0, "")?;
    let toward_elbow = DVec3::from_array(f.forearm_toward_elbow);
    c.ensure(toward_elbow.length() > 1e-3, &toward, || {
        format!(
            "{:?}: must be a direction (not zero), from the grip toward the elbow",
            f.forearm_toward_elbow
        )
    })?;
    let wrist_m = c.within(&at("forearm_wrist_m"), f.forearm_wrist_m, &bounds::FOREARM_WRIST_M)?;
    let elbow_m = c.within(&at("forearm_elbow_m"), f.forearm_elbow_m, &bounds::FOREARM_ELBOW_M)?;
    c.ensure(elbow_m > wrist_m, &at("forearm_elbow_m"), || {
        format!("{elbow_m} m: the elbow must be further from the grip than the wrist ({wrist_m} m)")
    })?;
    let radius_m = c.within(&at("forearm_radius_m"), f.forearm_radius_m, &bounds::FOREARM_RADIUS_M)?;
    let forearm = spidar_msg::strings::Forearm { toward_elbow, wrist_m, elbow_m, radius_m };
    Ok(StringClearance { distance_m, forearm })
}

fn check_header(c: &Checker, f: &RigFile) -> Result<(), ConfigError> {
    c.ensure(f.version == RIG_FILE_VERSION, &At::key("version"), || {
        format!("this build reads rig files of version {RIG_FILE_VERSION}, the file says {}", f.version)
    })?;
    for (i, o) in f.overrides.iter().enumerate() {
        c.ensure(
            bounds::OVERRIDABLE.contains(&o.as_str()),
            &At::new(format!("overrides[{i}]"), "overrides", 0),
            || {
                format!(
                    "\"{o}\" is not a bound that can be overridden; known: {}",
                    bounds::OVERRIDABLE.join(", ")
                )
            },
        )?;
    }
    c.within(&At::key("period_s"), f.period_s, &bounds::PERIOD_S)?;
    Ok(())
}

/// One hand: its force and tension limits, its grip, its four strings and where its home point
/// sits in their frame.
fn check_hand(
    c: &Checker,
    h: usize,
    hf: &HandFile,
    period_s: f64,
    seen: &mut Seen,
) -> Result<HandRig, ConfigError> {
    let at = |key: &'static str| At::new(format!("hands[{h}].{key}"), key, h);
    let min_n = c.positive(&at("tension_min_n"), hf.tension_min_n, "N", "so strings stay taut")?;
    c.within(&at("tension_min_n"), min_n, &bounds::TENSION_MIN_N)?;
    let max_n = hf.tension_max_n;
    c.ensure(max_n.is_finite() && max_n >= 2.0 * min_n, &at("tension_max_n"), || {
        format!("{max_n} N: must be at least twice tension_min_n ({min_n} N), or no force is left to render")
    })?;
    c.within(&at("tension_max_n"), max_n, &bounds::TENSION_MAX_N)?;
    c.positive(&at("force_limit_n"), hf.force_limit_n, "N", "the force is scaled down to it")?;
    c.positive(&at("grip_radius_m"), hf.grip_radius_m, "m", "the hand's sphere has a size")?;
    c.within(&at("grip_radius_m"), hf.grip_radius_m, &bounds::GRIP_RADIUS_M)?;
    let b = c.positive(&at("grip_damping_n_s_per_m"), hf.grip_damping_n_s_per_m, "N s/m", "an arm damps")?;
    c.within(&at("grip_damping_n_s_per_m"), b, &bounds::GRIP_DAMPING_N_S_PER_M)?;
    let k = c.positive(&at("stiffness_limit_n_per_m"), hf.stiffness_limit_n_per_m, "N/m", "a stiffness")?;
    let k_max = bounds::stiffness_limit_n_per_m(b, period_s);
    c.ensure(k <= k_max || c.overridden("stiffness_limit_n_per_m"), &at("stiffness_limit_n_per_m"), || {
        format!(
            "{k} N/m: above {k_max:.0} N/m, the stiffest contact that stays stable at this rig's period \
             ({period_s} s) on a grip damped by {b} N s/m: K_max = 2 b / (3 T) (one tick of delay plus the hold \
             act as negative damping 1.5 K T; see docs/safety.md). Lower it, or list \"stiffness_limit_n_per_m\" \
             in overrides"
        )
    })?;
    c.finite_within(&at("home_m"), &hf.home_m, bounds::COORDINATE_M, "m")?;
    c.count(&at("strings"), hf.strings.len(), 4, 4, "strings (each hand has four)")?;
    let mut hand = HandRig {
        label: hf.label.clone(),
        channels: [0; 4],
        anchors_m: [DVec3::ZERO; 4],
        metres_per_count: [0.0; 4],
        length_at_zero_m: None,
        volts_per_newton: [0.0; 4],
        tension_min_n: min_n,
        tension_max_n: max_n,
        force_limit_n: hf.force_limit_n,
        home_m: DVec3::from_array(hf.home_m),
        grip_radius_m: hf.grip_radius_m,
        stiffness_limit_n_per_m: k,
        grip_damping_n_s_per_m: b,
    };
    let mut zeros = [None; 4];
    for (s, sf) in hf.strings.iter().enumerate() {
        zeros[s] = check_string(c, h, s, sf, &mut hand, seen)?;
    }
    hand.length_at_zero_m =
        match zeros.iter().flatten().count() {
            0 => None,
            4 => Some(zeros.map(|z| z.unwrap_or(0.0))),
            _ => return Err(c.error(
                &at("strings"),
                "length_at_zero_m is given for some strings of this hand but not all: give all four or none \
                 (then home the rig)",
            )),
        };
    check_hand_geometry(c, h, hf, &hand)?;
    Ok(hand)
}

/// One string: its own channel, an anchor in reach of the frame's centre, the counter and DA
/// scales. Fills string `s` of `hand`; returns its length at counter zero when the file gives it.
fn check_string(
    c: &Checker,
    h: usize,
    s: usize,
    sf: &StringFile,
    hand: &mut HandRig,
    seen: &mut Seen,
) -> Result<Option<f64>, ConfigError> {
    let at = |key: &'static str, occ: usize| At::new(format!("hands[{h}].strings[{s}].{key}"), key, occ);
    let occ = h * 4 + s;
    let max = spidar_device::MAX_CHANNELS;
    let taken = sf.channel < max && seen.channels[sf.channel];
    c.ensure(sf.channel < max && !taken, &at("channel", occ), || {
        let what = if taken { "used twice" } else { "out of range" };
        format!("channel {} is {what}: each string needs its own channel below {max}", sf.channel)
    })?;
    seen.channels[sf.channel] = true;
    c.finite_within(&at("anchor_m", occ), &sf.anchor_m, bounds::COORDINATE_M, "m")?;
    let anchor = DVec3::from_array(sf.anchor_m);
    c.within(&at("anchor_m", occ), anchor.length(), &bounds::ANCHOR_FROM_CENTRE_M)?;
    let non_zero = |v: f64| v.is_finite() && v != 0.0;
    let mpc = sf.metres_per_count;
    c.ensure(non_zero(mpc), &at("metres_per_count", occ), || format!("{mpc}: must be finite and non-zero"))?;
    c.within(&at("metres_per_count", occ), mpc.abs(), &bounds::METRES_PER_COUNT)?;
    let vpn = sf.volts_per_newton;
    c.ensure(non_zero(vpn), &at("volts_per_newton", occ), || format!("{vpn}: must be finite and non-zero"))?;
    c.within(&at("volts_per_newton", occ), vpn.abs(), &bounds::VOLTS_PER_NEWTON)?;
    let zero = match sf.length_at_zero_m {
        None => None,
        Some(l) => {
            let at = at("length_at_zero_m", seen.zeros);
            seen.zeros += 1;
            c.finite(&at, l)?;
            Some(c.within(&at, l, &bounds::LENGTH_AT_ZERO_M)?)
        }
    };
    hand.channels[s] = sf.channel;
    hand.anchors_m[s] = anchor;
    hand.metres_per_count[s] = mpc;
    hand.volts_per_newton[s] = vpn;
    Ok(zero)
}

/// The hand's frame as a whole: anchors that span space, a home point inside them, and a force
/// limit the strings can reach there.
fn check_hand_geometry(c: &Checker, h: usize, hf: &HandFile, hand: &HandRig) -> Result<(), ConfigError> {
    let at = |key: &'static str| At::new(format!("hands[{h}].{key}"), key, h);
    let a = &hand.anchors_m;
    // The closed-form kinematics need the anchors to span space.
    let vol = ((a[1] - a[0]).cross(a[2] - a[0]).dot(a[3] - a[0]) / 6.0).abs();
    c.ensure(vol >= 1e-3, &at("strings"), || {
        format!(
            "the four anchors are (nearly) coplanar (tetrahedron volume {vol:.2e} m^3): check anchor_m; position \
             cannot be computed"
        )
    })?;
    let inside = bounds::inside_margin(a, hand.home_m);
    c.ensure(inside >= bounds::HOME_INSIDE_MARGIN || c.overridden("home_m"), &at("home_m"), || {
        let [x, y, z] = hf.home_m;
        format!(
            "({x}, {y}, {z}) is not inside this hand's frame (the tetrahedron of its four anchors, with a margin \
             of {:.0} % of its size): there the strings cannot hold zero net force, so neither the safe output \
             nor homing works. Move the home point inside the frame, or list \"home_m\" in overrides",
            bounds::HOME_INSIDE_MARGIN * 100.0
        )
    })?;
    // What the strings can produce at home: the largest force over 26 directions that the
    // allocator renders within the tension range.
    let (min_n, max_n) = (hand.tension_min_n, hand.tension_max_n);
    let capacity = bounds::force_capacity_n(a, hand.home_m, min_n, max_n);
    c.ensure(hand.force_limit_n <= capacity || c.overridden("force_limit_n"), &at("force_limit_n"), || {
        format!(
            "{} N: the strings can produce at most {capacity:.1} N at the home point with tensions {min_n} .. \
             {max_n} N, so this limit can never bind and hides a typo; lower it (the lab clipped at 4 N), or list \
             \"force_limit_n\" in overrides",
            hand.force_limit_n
        )
    })
}

/// The rig-to-world transform: a unit quaternion and a finite translation.
fn check_transform(c: &Checker, t: &TransformFile) -> Result<RigToWorld, ConfigError> {
    let [w, x, y, z] = t.rotation_wxyz;
    let q = DQuat::from_xyzw(x, y, z, w);
    let at = At::new("rig_to_world.rotation_wxyz", "rotation_wxyz", 0);
    c.ensure(q.is_finite() && (q.length() - 1.0).abs() < 1e-6, &at, || {
        format!("({w}, {x}, {y}, {z}) is not a unit quaternion (length {})", q.length())
    })?;
    let at = At::new("rig_to_world.translation_m", "translation_m", 0);
    c.finite_within(&at, &t.translation_m, f64::MAX, "m")?;
    Ok(RigToWorld { rotation: q, translation_m: DVec3::from_array(t.translation_m) })
}

/// The safety section: ramps, the stale model's fade, the pose and reply checks, recovery and
/// rehoming. `hands` are the checked hands (the stillness tolerance depends on their encoders).
fn check_safety(c: &Checker, s: &SafetyFile, period_s: f64, hands: &[HandRig; 2]) -> Result<(), ConfigError> {
    let at = |key: &'static str| At::new(format!("safety.{key}"), key, 0);
    c.within(&at("device_reopen_s"), s.device_reopen_s, &bounds::DEVICE_REOPEN_S)?;
    c.within(&at("ramp_in_s"), s.ramp_in_s, &bounds::RAMP_HARD_S)?;
    c.within(&at("ramp_in_s"), s.ramp_in_s, &bounds::RAMP_IN_S)?;
    c.within(&at("ramp_out_s"), s.ramp_out_s, &bounds::RAMP_HARD_S)?;
    c.within(&at("ramp_out_s"), s.ramp_out_s, &bounds::RAMP_OUT_S)?;
    let stale = &at("contact_stale_after_s");
    c.within(stale, s.contact_stale_after_s, &bounds::contact_stale_after_s_hard(period_s))?;
    c.within(stale, s.contact_stale_after_s, &bounds::CONTACT_STALE_AFTER_S)?;
    c.within(&at("contact_fade_s"), s.contact_fade_s, &bounds::contact_fade_s_hard(period_s))?;
    c.within(&at("contact_fade_s"), s.contact_fade_s, &bounds::CONTACT_FADE_S)?;
    c.within(stale, s.contact_stale_after_s + s.contact_fade_s, &bounds::CONTACT_FELT_S)?;
    c.within(&at("residual_fault_m"), s.residual_fault_m, &bounds::RESIDUAL_HARD_M)?;
    c.within(&at("residual_fault_m"), s.residual_fault_m, &bounds::RESIDUAL_FAULT_M)?;
    c.within(&at("reply_jump_m"), s.reply_jump_m, &bounds::REPLY_JUMP_HARD_M)?;
    c.within(&at("reply_jump_m"), s.reply_jump_m, &bounds::REPLY_JUMP_M)?;
    let counts = [
        ("residual_fault_ticks", s.residual_fault_ticks, &bounds::RESIDUAL_FAULT_TICKS),
        ("reply_fault_ticks", s.reply_fault_ticks, &bounds::REPLY_FAULT_TICKS),
        ("fault_recovery_ticks", s.fault_recovery_ticks, &bounds::FAULT_RECOVERY_TICKS),
    ];
    for (key, v, b) in counts {
        // 0 recovery ticks means "never recover", always allowed.
        if key == "fault_recovery_ticks" && v == 0 {
            continue;
        }
        c.ensure(v != 0, &at(key), || "0: must be at least 1".into())?;
        c.within(&at(key), f64::from(v), b)?;
    }
    // Stillness must be judged well above the encoder's resolution (10 counts of the coarsest
    // string), or the noise alone would keep the rig from homing itself.
    let coarsest = hands.iter().flat_map(|h| h.metres_per_count).fold(0.0_f64, |a, m| a.max(m.abs()));
    let still_m = s.rehome_still_m;
    c.ensure(still_m.is_finite() && still_m >= 10.0 * coarsest, &at("rehome_still_m"), || {
        format!(
            "{still_m} m: must be at least 10 encoder counts ({:.2e} m), or encoder noise alone keeps the rig \
             from homing itself",
            10.0 * coarsest
        )
    })?;
    c.within(&at("rehome_still_m"), still_m, &bounds::REHOME_STILL_M)?;
    c.within(&at("rehome_still_s"), s.rehome_still_s, &bounds::rehome_still_s_hard(period_s))?;
    c.within(&at("rehome_still_s"), s.rehome_still_s, &bounds::REHOME_STILL_S)?;
    Ok(())
}

/// The estimation section: solver iterations and the velocity filter against the tick rate.
fn check_estimation(c: &Checker, e: &EstimationFile, period_s: f64) -> Result<(), ConfigError> {
    let at = |key: &'static str| At::new(format!("estimation.{key}"), key, 0);
    let iterations = f64::from(e.gauss_newton_iterations);
    c.within(&at("gauss_newton_iterations"), iterations, &bounds::GAUSS_NEWTON_ITERATIONS)?;
    let cutoff = &at("velocity_cutoff_hz");
    let hz = c.positive(cutoff, e.velocity_cutoff_hz, "Hz", "a filter's cut-off")?;
    let nyquist = 0.5 / period_s;
    c.ensure(hz < nyquist, cutoff, || {
        format!(
            "{hz} Hz: must be below {nyquist} Hz, half the tick rate (Nyquist): a sampled filter cannot pass or \
             stop anything above it"
        )
    })?;
    c.within(cutoff, hz, &bounds::velocity_cutoff_hz(period_s))?;
    Ok(())
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

    /// Why `edits` (each: the first `replace` changed to `by`) applied to the default rig file must
    /// be refused: on `field`, located on the line of the first edit, with a reason containing `why`.
    struct Dangerous {
        edits: &'static [(&'static str, &'static str)],
        field: &'static str,
        why: &'static str,
    }

    macro_rules! danger {
        ($field:expr, $why:expr, $(($replace:expr, $by:expr)),+) => {
            Dangerous { edits: &[$(($replace, $by)),+], field: $field, why: $why }
        };
    }

    /// What a bad edit did instead of being refused as it should, or `None` when it was.
    fn not_refused(d: &Dangerous) -> Option<String> {
        let mut text = DEFAULT_RIG_RON.to_string();
        for (replace, by) in d.edits {
            assert!(text.contains(replace), "{replace}");
            text = text.replacen(replace, by, 1);
        }
        let by = d.edits[0].1;
        let line = text.lines().position(|l| l.contains(by.trim_end_matches(','))).unwrap() + 1;
        match Rig::from_str(&text, "rig.ron") {
            Ok(_) => Some(format!("{by}: accepted")),
            Err(e) if e.field != d.field || e.line != line || e.column == 0 => {
                Some(format!("{by}: refused elsewhere, want {} on line {line}: {e}", d.field))
            }
            Err(e)
                if !e.message.contains(d.why) || !e.to_string().starts_with(&format!("rig.ron:{line}:")) =>
            {
                Some(format!("{by}: refused without the reason \"{}\": {e}", d.why))
            }
            Err(_) => None,
        }
    }

    /// Every kind of dangerous value an operator could write (issue 17's list and issue 26's audit:
    /// beyond the motors, zero, -0.0, NaN, a unit slip, a check switched off, a model felt for
    /// seconds, an anchor in the next room, a filter at the Nyquist frequency), each refused on its
    /// field with its reason. Before issue 26, 25 of the first 30 were refused.
    const DANGEROUS: [Dangerous; 41] = [
        danger!("hands[0].tension_max_n", "motors", ("tension_max_n: 20.0", "tension_max_n: 1e6")),
        danger!(
            "hands[0].force_limit_n",
            "strings can produce at most",
            ("force_limit_n: 4.0", "force_limit_n: 400.0")
        ),
        danger!("hands[0].force_limit_n", "positive", ("force_limit_n: 4.0", "force_limit_n: 0.0")),
        danger!(
            "hands[0].stiffness_limit_n_per_m",
            "K_max = 2 b / (3 T)",
            ("stiffness_limit_n_per_m: 5000.0", "stiffness_limit_n_per_m: 1e9")
        ),
        danger!("hands[0].tension_min_n", "safe output", ("tension_min_n: 1.0", "tension_min_n: 9.0")),
        danger!("hands[0].tension_min_n", "taut", ("tension_min_n: 1.0", "tension_min_n: 0.0")),
        danger!("safety.ramp_in_s", "step of full force", ("ramp_in_s: 0.5", "ramp_in_s: 0.0")),
        danger!("safety.ramp_out_s", "step of full force", ("ramp_out_s: 0.3", "ramp_out_s: 0.0")),
        danger!(
            "safety.residual_fault_ticks",
            "switches the pose check off",
            ("residual_fault_ticks: 20", "residual_fault_ticks: 4294967295")
        ),
        danger!(
            "safety.fault_recovery_ticks",
            "at least 10 times",
            ("fault_recovery_ticks: 30", "fault_recovery_ticks: 1")
        ),
        danger!("safety.reply_fault_ticks", "20 ms", ("reply_fault_ticks: 5", "reply_fault_ticks: 1000")),
        danger!(
            "hands[0].strings[0].metres_per_count",
            "pulley",
            ("metres_per_count: 2.924062107079e-5", "metres_per_count: 1e-300")
        ),
        danger!(
            "hands[0].strings[0].volts_per_newton",
            "amplifiers",
            ("volts_per_newton: 0.2", "volts_per_newton: 1000.0")
        ),
        danger!(
            "hands[0].home_m",
            "not inside this hand's frame",
            ("home_m: (-0.15, 0.0, 0.0)", "home_m: (15.0, 0.0, 0.0)")
        ),
        danger!(
            "hands[0].strings[0].length_at_zero_m",
            "never negative",
            ("volts_per_newton: 0.2)", "volts_per_newton: 0.2, length_at_zero_m: Some(-1.0))")
        ),
        danger!("safety.contact_fade_s", "must be in", ("contact_fade_s: 0.1", "contact_fade_s: -0.0")),
        danger!("safety.rehome_still_m", "encoder", ("rehome_still_m: 0.003", "rehome_still_m: 0.0001")),
        danger!("hands[0].force_limit_n", "positive", ("force_limit_n: 4.0", "force_limit_n: NaN")),
        danger!("hands[0].grip_radius_m", "fist", ("grip_radius_m: 0.04", "grip_radius_m: 5.0")),
        danger!(
            "hands[0].grip_damping_n_s_per_m",
            "buzz",
            ("grip_damping_n_s_per_m: 8.0", "grip_damping_n_s_per_m: 1000.0")
        ),
        danger!(
            "safety.residual_fault_m",
            "centimetres off",
            ("residual_fault_m: 0.002", "residual_fault_m: 1.0")
        ),
        danger!("safety.reply_jump_m", "corrupt counts", ("reply_jump_m: 0.002", "reply_jump_m: 1.0")),
        danger!("safety.rehome_still_s", "one tick", ("rehome_still_s: 1.0", "rehome_still_s: 0.0")),
        danger!("period_s", "10 kHz", ("period_s: 0.001", "period_s: 1.0")),
        danger!("safety.device_reopen_s", "never reopens", ("device_reopen_s: 0.2", "device_reopen_s: -1.0")),
        danger!(
            "hands[0].strings[0].metres_per_count",
            "non-zero",
            ("metres_per_count: 2.924062107079e-5", "metres_per_count: 0.0")
        ),
        // Issue 26's audit: the five values that were accepted.
        danger!(
            "safety.contact_stale_after_s",
            "a tenth of a second",
            ("contact_stale_after_s: 0.03", "contact_stale_after_s: 1.0")
        ),
        danger!(
            "safety.contact_stale_after_s",
            "a second old",
            ("contact_stale_after_s: 0.03", "contact_stale_after_s: 1.0"),
            ("contact_fade_s: 0.1", "contact_fade_s: 5.0"),
            ("overrides: [],", "overrides: [\"contact_stale_after_s\", \"contact_fade_s\"],")
        ),
        danger!(
            "hands[0].strings[0].anchor_m",
            "unit slip",
            ("anchor_m: (-1.75, 2.00, 1.12)", "anchor_m: (-19.0, 2.00, 1.12)")
        ),
        danger!(
            "estimation.velocity_cutoff_hz",
            "count steps",
            ("velocity_cutoff_hz: 60.0", "velocity_cutoff_hz: 499.0")
        ),
        danger!(
            "estimation.velocity_cutoff_hz",
            "Nyquist",
            ("velocity_cutoff_hz: 60.0", "velocity_cutoff_hz: 500.0")
        ),
        // And their neighbours.
        danger!(
            "hands[0].strings[0].anchor_m",
            "no room for a hand",
            ("anchor_m: (-1.75, 2.00, 1.12)", "anchor_m: (0.0, 0.0, 0.0)")
        ),
        danger!(
            "estimation.velocity_cutoff_hz",
            "lags",
            ("velocity_cutoff_hz: 60.0", "velocity_cutoff_hz: 0.1")
        ),
        danger!(
            "estimation.gauss_newton_iterations",
            "at least one iteration",
            ("gauss_newton_iterations: 2", "gauss_newton_iterations: 0")
        ),
        danger!("eye_m", "within 10 m", ("eye_m: Some((0.0, 0.35, 0.4))", "eye_m: Some((0.0, 1000.0, 0.4))")),
        danger!(
            "near_strings.distance_m",
            "marks only strings that touch",
            ("distance_m: 0.01", "distance_m: -0.01")
        ),
        danger!(
            "near_strings.distance_m",
            "marks only strings that touch",
            ("distance_m: 0.01", "distance_m: NaN")
        ),
        danger!(
            "near_strings.forearm_radius_m",
            "3 .. 6 cm",
            ("forearm_radius_m: 0.045", "forearm_radius_m: -0.045")
        ),
        danger!(
            "near_strings.forearm_elbow_m",
            "further from the grip",
            ("forearm_elbow_m: 0.35", "forearm_elbow_m: 0.06")
        ),
        danger!(
            "near_strings.forearm_toward_elbow",
            "not zero",
            ("forearm_toward_elbow: (-0.25, -0.55, 0.8)", "forearm_toward_elbow: (0.0, 0.0, 0.0)")
        ),
        danger!(
            "rig_to_world.rotation_wxyz",
            "unit quaternion",
            ("rotation_wxyz: (1.0, 0.0, 0.0, 0.0)", "rotation_wxyz: (2.0, 0.0, 0.0, 0.0)")
        ),
    ];

    #[test]
    fn every_dangerous_value_of_the_audit_is_refused_with_its_reason() {
        let failures: Vec<String> = DANGEROUS.iter().filter_map(not_refused).collect();
        assert!(
            failures.is_empty(),
            "{} of {} refused:\n{}",
            DANGEROUS.len() - failures.len(),
            DANGEROUS.len(),
            failures.join("\n")
        );
    }

    #[test]
    fn no_number_of_the_rig_file_accepts_nan_an_infinity_or_1e300() {
        // Every floating-point value of the default file, as written there.
        let numbers = [
            "period_s: 0.001",
            "tension_min_n: 1.0",
            "tension_max_n: 20.0",
            "force_limit_n: 4.0",
            "grip_radius_m: 0.04",
            "stiffness_limit_n_per_m: 5000.0",
            "grip_damping_n_s_per_m: 8.0",
            "metres_per_count: 2.924062107079e-5",
            "volts_per_newton: 0.2",
            "ramp_in_s: 0.5",
            "ramp_out_s: 0.3",
            "contact_stale_after_s: 0.03",
            "contact_fade_s: 0.1",
            "residual_fault_m: 0.002",
            "reply_jump_m: 0.002",
            "rehome_still_m: 0.003",
            "rehome_still_s: 1.0",
            "device_reopen_s: 0.2",
            "velocity_cutoff_hz: 60.0",
            "digits_per_volt: 415.0",
            "limit_v: 4.0",
        ];
        let mut accepted = Vec::new();
        for n in numbers {
            let key = n.split(':').next().unwrap();
            for v in ["NaN", "inf", "-inf", "1e300", "-1e300"] {
                let by = format!("{key}: {v}");
                let e = match Rig::from_str(&with(n, &by), "rig.ron") {
                    Ok(_) => {
                        accepted.push(by);
                        continue;
                    }
                    Err(e) => e,
                };
                assert!(e.field.ends_with(key), "{by}: refused on {}: {e}", e.field);
            }
        }
        assert!(accepted.is_empty(), "accepted: {accepted:?}");
    }

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

    /// The `boards:` section as the rig file reads it (`boards.rs`).
    mod boards_section {
        use super::*;
        use crate::boards::UartCounts;

        /// The default rig file without its `boards:` section.
        fn without_section() -> String {
            let start = DEFAULT_RIG_RON.find("    // The boards' commands").unwrap();
            let end = DEFAULT_RIG_RON[start..].find("\n    ),\n").unwrap() + start + "\n    ),\n".len();
            format!("{}{}", &DEFAULT_RIG_RON[..start], &DEFAULT_RIG_RON[end..])
        }

        #[test]
        fn the_default_rig_file_says_each_boards_command_range() {
            let b = Rig::default_rig().boards;
            assert_eq!(b.usb_digits_per_volt, 415.0);
            assert_eq!(b.usb_limit_v, 4.0);
            assert!((b.uart_pwm_full_scale_v() - 4.0).abs() < 1e-12);
            assert!((b.uart_current_full_scale_v() - 4.0).abs() < 1e-12);
            assert_eq!(b.uart_pwm_digits_per_volt, 256.0);
            assert_eq!(b.uart_counts_per_rev(), 1024);
        }

        #[test]
        fn left_out_the_da_limit_is_what_the_rig_needs_and_uart_takes_the_lab_scale() {
            let text = without_section();
            assert!(!text.contains("boards:"));
            let rig = Rig::from_str(&text, "test").unwrap();
            let b = rig.boards;
            // 20 N x 0.2 V/N: not the 10 V the DA could give.
            assert!((b.usb_limit_v - 4.0).abs() < 1e-12);
            assert_eq!(b.usb_limit_v, volts_needed(&rig.hands));
            // The lab host driver's scale: full PWM duty at 0.825 V, full current target at 3.3 V.
            assert!((b.uart_pwm_full_scale_v() - 0.825).abs() < 1e-12);
            assert!((b.uart_current_full_scale_v() - 4095.0 * 3.3 / 4096.0).abs() < 1e-12);
            assert_eq!(b.uart_counts, UartCounts::MagnetAngle);
        }

        #[test]
        fn bad_values_are_located_and_encoder_counts_are_read() {
            let bad = DEFAULT_RIG_RON.replacen(
                "uart_pwm_duty: (full_scale_v: 4.0)",
                "uart_pwm_duty: (full_scale_v: -1.0)",
                1,
            );
            let e = Rig::from_str(&bad, "test.ron").unwrap_err().to_string();
            assert!(e.contains("boards.uart_pwm_duty.full_scale_v") && e.contains("test.ron:"), "{e}");
            let big = DEFAULT_RIG_RON.replacen("limit_v: 4.0", "limit_v: 100.0", 1);
            let e = Rig::from_str(&big, "test.ron").unwrap_err().to_string();
            assert!(e.contains("boards.usb_da.limit_v") && e.contains("78.96"), "{e}");
            let enc = DEFAULT_RIG_RON.replacen(
                "uart_counts: MagnetAngle",
                "uart_counts: Encoder(counts_per_rev: 2000)",
                1,
            );
            assert_eq!(Rig::from_str(&enc, "test").unwrap().boards.uart_counts_per_rev(), 2000);
            let unknown =
                DEFAULT_RIG_RON.replacen("uart_counts: MagnetAngle", "uart_counts: MagnetAngle, dac: 1", 1);
            let e = Rig::from_str(&unknown, "test").unwrap_err().to_string();
            assert!(e.contains("dac"), "{e}");
        }
    }

    #[test]
    fn near_strings_are_optional_and_so_is_each_of_their_fields() {
        // The shipped file states the defaults.
        assert_eq!(Rig::default_rig().near_strings, StringClearance::default());
        let start = DEFAULT_RIG_RON.find("    near_strings: Some((").unwrap();
        let end = start + DEFAULT_RIG_RON[start..].find(")),\n").unwrap() + 4;
        let with =
            |section: &str| format!("{}{section}{}", &DEFAULT_RIG_RON[..start], &DEFAULT_RIG_RON[end..]);
        assert_eq!(Rig::from_str(&with(""), "rig.ron").unwrap().near_strings, StringClearance::default());
        let r = Rig::from_str(
            &with("    near_strings: Some((distance_m: 0.03, forearm_radius_m: 0.06)),\n"),
            "rig.ron",
        )
        .unwrap();
        let mut want = StringClearance { distance_m: 0.03, ..Default::default() };
        want.forearm.radius_m = 0.06;
        assert_eq!(r.near_strings, want);
        // A field it does not know is refused, named.
        let e =
            Rig::from_str(&with("    near_strings: Some((distance_mm: 10.0)),\n"), "rig.ron").unwrap_err();
        assert!(e.to_string().contains("distance_mm"), "{e}");
    }
}
