//! The character AI (seed 002, section 3): what each character wants. It sets the controller's
//! goal of attitude and locomotion (stand, walk to a point, walk with a velocity, turn) and the
//! behaviour dimension B of the keyframe space, and decides when a fallen character may stand up:
//! not when it fell sideways or is still sliding (section 6.1), since the standing-up keyframes
//! only cover the front-back line of Q.
//!
//! Must never: allocate, or command anything the controller's bounds do not already limit.

use glam::DVec3;
use serde::Deserialize;

use super::controller::{Policy, Targets};
use super::space::BodySpace;

/// What a character is trying to do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Goal {
    /// Stand where it is; keep whatever heading a push gave it.
    Stand,
    /// Stand and face a heading (rad).
    Face { heading_rad: f64 },
    /// Walk to a point at a speed, facing where it goes, and stand there.
    WalkTo { point_m: DVec3, speed_m_per_s: f64 },
    /// Walk with a world velocity, facing along it.
    Walk { velocity_m_per_s: DVec3 },
    /// Keep a spot: stand at a point facing a heading (rad); pushed away, step back there (facing
    /// the same way, stepping backward or sideways as needed) at up to a speed.
    Station { point_m: DVec3, heading_rad: f64, speed_m_per_s: f64 },
}

/// The AI's settings.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AiParams {
    /// A fallen character lying more than this far on its side does not stand up (deg).
    pub side_fall_max_deg: f64,
    /// A fallen character sliding faster than this does not stand up yet (m/s).
    pub slide_max_m_per_s: f64,
    /// Within this distance of a walk target the character stops (m).
    pub arrive_m: f64,
    /// Deceleration the approach to a walk target plans with (m/s^2): the speed asked for is what
    /// stops the character at the target braking this hard.
    pub slow_down_m_per_s2: f64,
}

impl Default for AiParams {
    fn default() -> Self {
        AiParams { side_fall_max_deg: 25.0, slide_max_m_per_s: 0.15, arrive_m: 0.1, slow_down_m_per_s2: 0.8 }
    }
}

impl AiParams {
    /// Checks the settings: an error gives the field and what to do.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let ok = |v: f64, lo: f64, hi: f64| v >= lo && v <= hi;
        if !ok(self.side_fall_max_deg, 0.0, 90.0) {
            return Err((
                "side_fall_max_deg",
                format!("must be in [0, 90] deg, got {}", self.side_fall_max_deg),
            ));
        }
        if !ok(self.slide_max_m_per_s, 0.0, 100.0) {
            return Err((
                "slide_max_m_per_s",
                format!("must be in [0, 100] m/s, got {}", self.slide_max_m_per_s),
            ));
        }
        if !ok(self.arrive_m, 0.01, 100.0) {
            return Err(("arrive_m", format!("must be in [0.01, 100] m, got {}", self.arrive_m)));
        }
        if !ok(self.slow_down_m_per_s2, 0.05, 100.0) {
            return Err((
                "slow_down_m_per_s2",
                format!("must be in [0.05, 100] m/s^2, got {}", self.slow_down_m_per_s2),
            ));
        }
        Ok(())
    }

    /// The speed toward a target `dist_m` away that stops there: braking at `slow_down_m_per_s2`
    /// from where the character will be after the velocity loop's lag (`lag_s`) at `speed_now`.
    #[inline]
    pub fn approach_speed(&self, dist_m: f64, speed_now: f64, lag_s: f64, max: f64) -> f64 {
        let left = (dist_m - self.arrive_m - speed_now * lag_s).max(0.0);
        (2.0 * self.slow_down_m_per_s2 * left).sqrt().min(max)
    }
}

/// Time the controller's velocity loop lags the speed it is asked for (s): 1 / its gain.
const VELOCITY_LAG_S: f64 = 0.5;

/// The behaviour dimension B of the keyframe set (its index in the set's `behaviours`).
pub const B_WALK_AND_FALL: u8 = 0;
pub const B_STAND_UP: u8 = 1;

/// The AI's decision for one step: controller targets and the behaviour to show.
pub fn decide(p: &AiParams, goal: &Goal, b: &BodySpace, policy: Policy) -> (Targets, u8) {
    let mut t = Targets::default();
    match *goal {
        Goal::Stand => {}
        Goal::Face { heading_rad } => t.heading = Some(super::space::Heading::from_angle(heading_rad).e_zc),
        Goal::WalkTo { point_m, speed_m_per_s } => {
            let mut d = point_m - b.r_m;
            d.y = 0.0;
            let dist = d.length();
            if dist > p.arrive_m {
                let v_now = b.r_dot_m_per_s.dot(d / dist).max(0.0);
                let speed = p.approach_speed(dist, v_now, VELOCITY_LAG_S, speed_m_per_s);
                t.velocity_m_per_s = d * (speed / dist);
                t.heading = Some(d);
            }
        }
        Goal::Station { point_m, heading_rad, speed_m_per_s } => {
            t.heading = Some(super::space::Heading::from_angle(heading_rad).e_zc);
            let mut d = point_m - b.r_m;
            d.y = 0.0;
            let dist = d.length();
            if dist > p.arrive_m {
                let v_now = b.r_dot_m_per_s.dot(d / dist).max(0.0);
                let speed = p.approach_speed(dist, v_now, VELOCITY_LAG_S, speed_m_per_s);
                t.velocity_m_per_s = d * (speed / dist);
            }
        }
        Goal::Walk { velocity_m_per_s } => {
            t.velocity_m_per_s = DVec3::new(velocity_m_per_s.x, 0.0, velocity_m_per_s.z);
            if t.velocity_m_per_s.length_squared() > 1e-6 {
                t.heading = Some(t.velocity_m_per_s);
            }
        }
    }
    let (vs, vf) = b.velocity_sc();
    let sliding = (vs * vs + vf * vf).sqrt() > p.slide_max_m_per_s;
    // Sliding only matters before rising: while standing up the centre of mass moves by itself.
    t.may_stand_up =
        b.theta_z.abs() < p.side_fall_max_deg.to_radians() && (policy == Policy::StandUp || !sliding);
    let behaviour = if policy == Policy::StandUp { B_STAND_UP } else { B_WALK_AND_FALL };
    (t, behaviour)
}
