//! Physics-driven keyframe characters (seed 002): each character is one rigid body kept upright by
//! an inverted-pendulum controller, and its visible pose is interpolated from a multidimensional
//! keyframe set at the point of the keyframe space its body state maps to.
//!
//! - [`space`]: the rigid-body space (r, theta and their rates, section 4.1);
//! - [`controller`]: equations 1-5, the bounds, the Fig. 3 state machine (section 4.2);
//! - [`ai`]: goals of attitude and locomotion and the behaviour B (sections 3, 6.1);
//! - [`keyframe`]: the keyframe space Q, keyframe sets in RON and interpolation (section 5);
//! - [`crowd`]: a dedicated stepper for thousands of characters with a grid broad phase.
//!
//! [`Character`] holds everything one character carries between steps; it is driven either inside
//! the general engine ([`Character::drive_engine`], the body is an articulation of a `Model`) or
//! by the crowd stepper. Both use the same controller, AI and animation code, and the crowd stepper
//! uses the engine's collision and penalty law, so one character moves the same in both (tested).
//!
//! Must never: allocate per step, or touch a body that is not the character's.

pub mod ai;
pub mod controller;
pub mod crowd;
pub mod drawn;
pub mod feet;
pub mod keyframe;
pub mod legs;
pub mod params;
pub mod scene;
pub mod skeleton;
pub mod space;

use glam::{DQuat, DVec3};
use serde::Deserialize;

use crate::model::Model;
use crate::state::Workspace;
use ai::{AiParams, Goal};
use controller::{ControllerState, Drive, Ground};
use keyframe::{KeyframeSet, Lean, QPoint};
use params::{ControllerParams, TiltCosines};
use skeleton::SkeletonPose;
use space::BodySpace;

/// All settings of a kind of character.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct CharacterParams {
    pub controller: ControllerParams,
    pub ai: AiParams,
}

/// Where a character is in the keyframe space and how it got there (section 5.2).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Correspondence {
    /// Total travelled distance to the front and to the side along the body's own axes (m): the
    /// integrals of equations 6 and 7.
    pub d_front_m: f64,
    pub d_side_m: f64,
    /// Behaviour being shown, the one it is blending from, and how far the blend is (0..1).
    pub behaviour: u8,
    pub from_behaviour: u8,
    pub blend: f64,
}

/// Below this speed (m/s) a standing character's walk phase glides to the nearest standing phase
/// of the cycle (0 or a half), so a stop ends in the standing pose rather than mid-stride.
pub const SETTLE_SPEED_M_PER_S: f64 = 0.1;
/// How fast the phase glides there (cycles per second).
const SETTLE_CYCLES_PER_S: f64 = 1.0;
/// Within this angle of lying on its side (rad) the front-back lean fades out of the point of Q:
/// there the heading frame's front-back lean turns over (section 5.2's identity map would jump
/// between the front and the back fall poses).
const SIDE_FADE_RAD: f64 = 0.44;

impl Correspondence {
    /// Advances eqs 6, 7 by one step with the body's horizontal velocity, and the behaviour blend.
    /// `settle`: the body stands (slow and balanced): the phases glide to a standing phase.
    #[inline]
    pub fn advance(
        &mut self,
        b: &BodySpace,
        behaviour: u8,
        blend_s: f64,
        dt_s: f64,
        settle: Option<(f64, f64)>,
    ) {
        let (vs, vf) = b.velocity_sc();
        self.d_front_m += vf * dt_s;
        self.d_side_m += vs * dt_s;
        if let Some((stride_front_m, stride_side_m)) = settle {
            let glide = |d: &mut f64, stride: f64| {
                let half = 0.5 * stride;
                let target = (*d / half).round() * half;
                let max = SETTLE_CYCLES_PER_S * stride * dt_s;
                *d += (target - *d).clamp(-max, max);
            };
            glide(&mut self.d_front_m, stride_front_m);
            glide(&mut self.d_side_m, stride_side_m);
        }
        if behaviour != self.behaviour {
            self.from_behaviour = self.behaviour;
            self.behaviour = behaviour;
            // Starting from the point the previous blend had reached keeps the pose continuous.
            self.blend = 1.0 - self.blend.min(1.0);
        }
        self.blend = (self.blend + dt_s / blend_s).min(1.0);
    }

    /// The point of Q: leans by the identity map, except that the front-back lean fades out near
    /// lying on the side (where it is undefined) and stays within [-90, 90] deg (the set's reach);
    /// phases by equations 8 and 9 with the strides.
    #[inline]
    pub fn q(&self, b: &BodySpace, set: &KeyframeSet) -> QPoint {
        QPoint {
            theta_x: lean_front_continuous(b),
            theta_z: b.theta_z,
            d_x: periodic(self.d_side_m / set.stride_side_m),
            d_z: periodic(self.d_front_m / set.stride_front_m),
            behaviour: self.behaviour,
        }
    }

    /// The pose to show (in `S_r`), from the keyframes alone: at the point of Q, and for large
    /// leans by the lean's direction ([`KeyframeSet::pose_polar`]), with the behaviour blend.
    #[inline]
    pub fn pose(&self, b: &BodySpace, set: &KeyframeSet, out: &mut SkeletonPose) {
        let q = self.q(b, set);
        let polar = polar_lean(b);
        pose_at(set, &q, q.behaviour, polar.as_ref(), out);
        if self.blend >= 1.0 || self.from_behaviour == self.behaviour {
            return;
        }
        let mut other = SkeletonPose::default();
        pose_at(set, &q, self.from_behaviour, polar.as_ref(), &mut other);
        let (w, n) = (self.blend as f32, set.posed);
        for j in 0..n {
            out.rot[j] = nlerp(other.rot[j], out.rot[j], w);
        }
        out.root_m = other.root_m * (1.0 - w) + out.root_m * w;
    }
}

/// Leans (from the vertical) over which the pose moves from the point of Q to the lean's direction
/// (rad): the planes' poses compose for walking and staggering, but two falls do not compose.
const POLAR_FROM_RAD: f64 = 0.52;
const POLAR_FULL_RAD: f64 = 0.79;

/// The lean by direction and how much its pose counts (0 below [`POLAR_FROM_RAD`]).
#[inline]
fn polar_lean(b: &BodySpace) -> Option<(Lean, f32)> {
    let cy = b.e_yr.y;
    if cy > POLAR_FROM_RAD.cos() {
        return None;
    }
    let tau = cy.clamp(-1.0, 1.0).acos();
    let m = ((tau - POLAR_FROM_RAD) / (POLAR_FULL_RAD - POLAR_FROM_RAD)).clamp(0.0, 1.0);
    let (sf, sz) = (b.e_yr.dot(b.heading.e_zc), b.e_yr.dot(b.heading.e_xc));
    let h2 = sf * sf + sz * sz;
    let front_share = if h2 > 1e-18 { sf * sf / h2 } else { 1.0 };
    let lean = Lean {
        front_rad: tau.copysign(sf),
        side_rad: tau.min(std::f64::consts::FRAC_PI_2).copysign(sz),
        front_share,
    };
    Some((lean, (m * m * (3.0 - 2.0 * m)) as f32))
}

/// The pose of one behaviour at `q`, moved toward the lean's direction by its weight.
#[inline]
fn pose_at(
    set: &KeyframeSet,
    q: &QPoint,
    behaviour: u8,
    polar: Option<&(Lean, f32)>,
    out: &mut SkeletonPose,
) {
    set.pose(&QPoint { behaviour, ..*q }, out);
    let Some((lean, m)) = polar else { return };
    let mut p = SkeletonPose::default();
    set.pose_polar(lean, q.d_x, q.d_z, behaviour, &mut p);
    if *m >= 1.0 {
        *out = p;
        return;
    }
    for j in 0..set.posed {
        out.rot[j] = nlerp(out.rot[j], p.rot[j], *m);
    }
    out.root_m = out.root_m * (1.0 - m) + p.root_m * *m;
}

#[inline]
fn nlerp(a: glam::Quat, b: glam::Quat, w: f32) -> glam::Quat {
    let b = if a.dot(b) < 0.0 { -b } else { b };
    (a * (1.0 - w) + b * w).normalize()
}

/// The front-back lean as the keyframe space sees it: `atan2(e_yr . e_zc, max(e_yr . e_yc, 0))`
/// (so within [-90, 90] deg), faded to 0 as the body comes within [`SIDE_FADE_RAD`] of lying on its
/// side. Continuous for every orientation but the head-down ones the body's round top avoids.
#[inline]
pub fn lean_front_continuous(b: &BodySpace) -> f64 {
    // Upright enough, it is the rigid-body space's own theta_x (one atan2 saved per character).
    if b.e_yr.y >= SIDE_FADE_RAD.sin() {
        return b.theta_x;
    }
    let sf = b.e_yr.dot(b.heading.e_zc);
    let up = b.e_yr.y.max(0.0);
    let th = sf.atan2(up);
    let h = (sf * sf + up * up).sqrt();
    let w = (h / SIDE_FADE_RAD.sin()).min(1.0);
    th * w * w * (3.0 - 2.0 * w)
}

/// Equation 8: p(x) = x - floor(x), in [0, 1).
#[inline]
pub fn periodic(x: f64) -> f64 {
    let p = x - x.floor();
    if p >= 1.0 {
        0.0
    } else {
        p
    }
}

/// One character's state between steps (besides its rigid body's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Character {
    pub goal: Goal,
    pub control: ControllerState,
    pub anim: Correspondence,
    /// The floor under it as the last step's contacts saw it.
    pub ground: Ground,
    /// The last drive applied (for tools and tests).
    pub drive: Drive,
}

impl Default for Character {
    fn default() -> Self {
        Character {
            goal: Goal::Stand,
            control: ControllerState::default(),
            anim: Correspondence { blend: 1.0, ..Correspondence::default() },
            ground: Ground::default(),
            drive: Drive::default(),
        }
    }
}

impl Character {
    /// AI, controller and correspondence for one step: returns the drive to apply.
    #[inline]
    pub fn think(
        &mut self,
        p: &CharacterParams,
        mass_kg: f64,
        g: f64,
        dt_s: f64,
        set: &KeyframeSet,
        b: &BodySpace,
    ) -> Drive {
        self.think_with(p, &p.controller.tilt_cosines(), mass_kg, g, dt_s, set, b)
    }

    /// [`Character::think`] with the controller's threshold cosines given (a crowd computes them
    /// once per step).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn think_with(
        &mut self,
        p: &CharacterParams,
        cos: &TiltCosines,
        mass_kg: f64,
        g: f64,
        dt_s: f64,
        set: &KeyframeSet,
        b: &BodySpace,
    ) -> Drive {
        let (targets, behaviour) = ai::decide(&p.ai, &self.goal, b, self.control.policy);
        let d = self.control.control_with(&p.controller, cos, mass_kg, g, dt_s, b, &self.ground, &targets);
        let (vs, vf) = b.velocity_sc();
        let standing = self.control.policy == controller::Policy::Balance
            && vs * vs + vf * vf < SETTLE_SPEED_M_PER_S * SETTLE_SPEED_M_PER_S
            && targets.velocity_m_per_s.length_squared() < 1e-4;
        let strides = (set.stride_front_m, set.stride_side_m);
        self.anim.advance(b, behaviour, set.behaviour_blend_s, dt_s, standing.then_some(strides));
        self.drive = d;
        d
    }

    /// The drawn pose (in `S_r`): the keyframe set at the point of Q the body maps to, with the legs
    /// turned onto the feet the controller stands on (while upright; a fall hands the legs back to
    /// the keyframes by the time the body leans [`LEGS_FREE_DEG`]).
    pub fn pose(
        &self,
        b: &BodySpace,
        set: &KeyframeSet,
        p: &params::ControllerParams,
        out: &mut SkeletonPose,
    ) {
        self.anim.pose(b, set, out);
        let (Some(legs), true) = (&set.legs, self.control.feet.grip > 0.0) else { return };
        let w = legs_weight(b.e_yr.y) * self.control.feet.grip;
        if w <= 0.0 {
            return;
        }
        let to_body = |v: DVec3| DVec3::new(v.dot(b.e_xr), v.dot(b.e_yr), v.dot(b.e_zr)).as_vec3();
        let target = |k: usize| {
            let f = &self.control.feet.foot[k];
            let lift = f.lift_m(p.step_height_m);
            to_body(f.pos_m + DVec3::Y * (legs.ankle_height_m as f64 + lift) - b.r_m)
        };
        let up = to_body(DVec3::Y);
        let floor_y = if self.ground.normal_n > 0.0 {
            self.ground.point_m.y
        } else {
            self.control.feet.foot[0].pos_m.y
        };
        legs.reach(&set.joints, out, [target(0), target(1)], [w, w], up, (b.r_m.y - floor_y) as f32);
    }

    /// Drives a character whose body is `body` of an engine model: reads the floor contacts of the
    /// last step from `ws.contacts`, and adds the controller's force and torque to `ws` for the next
    /// `step`. Floor contacts are those with static shapes whose normal points up.
    pub fn drive_engine(
        &mut self,
        model: &Model,
        ws: &mut Workspace,
        body: usize,
        p: &CharacterParams,
        set: &KeyframeSet,
    ) -> BodySpace {
        let mut ground = Ground::default();
        let mut moment = DVec3::ZERO;
        for c in &ws.contacts {
            let (n, up) = match (c.body_a, c.body_b) {
                (Some(a), None) if a as usize == body => (c.force_n, c.normal),
                (None, Some(b)) if b as usize == body => (-c.force_n, -c.normal),
                _ => continue,
            };
            if up.y < 0.7 {
                continue;
            }
            let fn_ = n.dot(up).max(0.0);
            ground.normal_n += fn_;
            moment += c.point_m * fn_;
        }
        if ground.normal_n > 0.0 {
            ground.point_m = moment / ground.normal_n;
        }
        self.ground = ground;
        let b = body_space_engine(model, ws, body);
        let g = -model.gravity_m_per_s2.y;
        let d = self.think(p, model.bodies[body].mass_kg, g, model.dt_s, set, &b);
        ws.add_force_at(body, d.at_m, d.force_n);
        ws.add_torque(body, d.torque_n_m);
        b
    }
}

/// The body leans (deg) below which the drawn legs stand fully on the feet, and above which the
/// keyframes alone pose them (a fall lifts the feet off the floor).
pub const LEGS_ON_FEET_DEG: f64 = 20.0;
pub const LEGS_FREE_DEG: f64 = 40.0;

/// How much the drawn legs follow the feet at a lean whose cosine is `cos_tilt`: 1 upright, 0 past
/// [`LEGS_FREE_DEG`], smooth between.
#[inline]
pub fn legs_weight(cos_tilt: f64) -> f32 {
    let (on, free) = (LEGS_ON_FEET_DEG.to_radians().cos(), LEGS_FREE_DEG.to_radians().cos());
    let w = ((cos_tilt - free) / (on - free)).clamp(0.0, 1.0);
    (w * w * (3.0 - 2.0 * w)) as f32
}

/// The rigid-body space of an engine body (after `kinematics`/`step`).
pub fn body_space_engine(model: &Model, ws: &Workspace, body: usize) -> BodySpace {
    let rot = DQuat::from_mat3(&ws.x0[body].e.transpose());
    let com = ws.com_world(model, body);
    let v = ws.point_velocity(body, model.bodies[body].com_m);
    BodySpace::new(rot, com, v, ws.angular_velocity(body))
}
