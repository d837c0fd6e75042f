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
    /// Distance over which the approach to a walk target slows down (m).
    pub slow_down_m: f64,
}

impl Default for AiParams {
    fn default() -> Self {
        AiParams { side_fall_max_deg: 25.0, slide_max_m_per_s: 0.15, arrive_m: 0.1, slow_down_m: 0.6 }
    }
}

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
                let speed = speed_m_per_s * (dist / p.slow_down_m.max(1e-3)).min(1.0);
                t.velocity_m_per_s = d * (speed / dist);
                t.heading = Some(d);
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
