//! What a scene's minds decided, as plain data for recordings: the virtual human's behaviour per
//! hand and body, its latest prediction and its reach targets, its counters, and its gaze.
//!
//! Copied on the stepping thread after a step ([`crate::Scene::decisions`]): plain `Copy` data, no
//! allocation.

use glam::DVec3;

/// A hand's behaviour code: 0 standby (guard), 1 attack, 2 block.
pub const HAND_BEHAVIOURS: [&str; 3] = ["standby", "attack", "block"];
/// The body's behaviour code: 0 standby, 1 avoidance.
pub const BODY_BEHAVIOURS: [&str; 2] = ["standby", "avoidance"];
/// What a predicted contact means (the class code): 0 none, 1 the user's attack lands, 2 the
/// virtual human's attack lands, 3 the virtual human blocked, 4 the user blocked, 5 other.
pub const CONTACT_CLASSES: [&str; 6] =
    ["none", "user_attack", "boxer_attack", "boxer_blocked", "user_blocked", "other"];

/// One running reach (a part pulled to a target over a minimum-jerk trajectory).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReachTarget {
    /// The reach is running.
    pub active: bool,
    /// The model body that moves.
    pub body: u16,
    /// Target point (scene frame, m).
    pub target_m: DVec3,
    /// Scene time it started, and its duration (s).
    pub start_s: f64,
    pub duration_s: f64,
}

/// The contact that decided the latest prediction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Prediction {
    /// See [`CONTACT_CLASSES`] (0: no prediction yet).
    pub class: u8,
    /// The virtual human's body and the avatar's body predicted to touch.
    pub vh_body: u16,
    pub av_body: u16,
    /// Predicted contact point (scene frame) and scene time.
    pub point_m: DVec3,
    pub at_s: f64,
}

/// Where the virtual human looks (its vision model's gaze, `spidar_sim::boxer::Perception`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Gaze {
    /// The eyes (the head's centre) and the unit direction they point (scene frame).
    pub eye_m: DVec3,
    pub dir: DVec3,
    /// The point looked at: along `dir`, as far as what attention is on (the attended fist as
    /// seen, or the avatar's upper chest when no fist threatens).
    pub at_m: DVec3,
    /// The avatar's fist attention is on: 0 none, 1 left, 2 right.
    pub attended: u8,
}

/// The virtual human's state of mind after a step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Decisions {
    /// The cognitive model is on (an active virtual human).
    pub active: bool,
    /// [left, right], see [`HAND_BEHAVIOURS`].
    pub hands: [u8; 2],
    /// See [`BODY_BEHAVIOURS`].
    pub body: u8,
    /// Hands [left, right], then the body.
    pub reaches: [ReachTarget; 3],
    pub prediction: Prediction,
    /// Counters since the scene started.
    pub predictions: u64,
    pub attacks: u64,
    pub avoidances: u64,
    pub blocks: u64,
    /// The user's hands on the virtual human's head or chest; its hands on the avatar's.
    pub hits_taken: u64,
    pub hits_given: u64,
    /// Wall time of the latest prediction (s).
    pub last_predict_s: f64,
    /// Where it looks.
    pub gaze: Gaze,
}
