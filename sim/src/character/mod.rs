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
pub mod feet;
pub mod keyframe;
pub mod scene;
pub mod space;

use glam::{DQuat, DVec3};
use serde::Deserialize;

use crate::model::Model;
use crate::state::Workspace;
use ai::{AiParams, Goal};
use controller::{ControllerParams, ControllerState, Drive, Ground, TiltCosines};
use keyframe::{KeyframeSet, Pose, QPoint};
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

impl Correspondence {
    /// Advances eqs 6, 7 by one step with the body's horizontal velocity, and the behaviour blend.
    #[inline]
    pub fn advance(&mut self, b: &BodySpace, behaviour: u8, blend_s: f64, dt_s: f64) {
        let (vs, vf) = b.velocity_sc();
        self.d_front_m += vf * dt_s;
        self.d_side_m += vs * dt_s;
        if behaviour != self.behaviour {
            self.from_behaviour = self.behaviour;
            self.behaviour = behaviour;
            // Starting from the point the previous blend had reached keeps the pose continuous.
            self.blend = 1.0 - self.blend.min(1.0);
        }
        self.blend = (self.blend + dt_s / blend_s).min(1.0);
    }

    /// The point of Q: leans identically, phases by equations 8 and 9 with the strides.
    #[inline]
    pub fn q(&self, b: &BodySpace, set: &KeyframeSet) -> QPoint {
        QPoint {
            theta_x: b.theta_x,
            theta_z: b.theta_z,
            d_x: periodic(self.d_side_m / set.stride_side_m),
            d_z: periodic(self.d_front_m / set.stride_front_m),
            behaviour: self.behaviour,
        }
    }

    /// The pose to show (in `S_r`).
    #[inline]
    pub fn pose(&self, b: &BodySpace, set: &KeyframeSet, out: &mut Pose) {
        set.pose_blended(&self.q(b, set), self.from_behaviour, self.blend, out);
    }
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
        blend_s: f64,
        b: &BodySpace,
    ) -> Drive {
        self.think_with(p, &p.controller.tilt_cosines(), mass_kg, g, dt_s, blend_s, b)
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
        blend_s: f64,
        b: &BodySpace,
    ) -> Drive {
        let (targets, behaviour) = ai::decide(&p.ai, &self.goal, b, self.control.policy);
        let d = self.control.control_with(&p.controller, cos, mass_kg, g, dt_s, b, &self.ground, &targets);
        self.anim.advance(b, behaviour, blend_s, dt_s);
        self.drive = d;
        d
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
        blend_s: f64,
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
        let d = self.think(p, model.bodies[body].mass_kg, g, model.dt_s, blend_s, &b);
        ws.add_force_at(body, d.at_m, d.force_n);
        ws.add_torque(body, d.torque_n_m);
        b
    }
}

/// The rigid-body space of an engine body (after `kinematics`/`step`).
pub fn body_space_engine(model: &Model, ws: &Workspace, body: usize) -> BodySpace {
    let rot = DQuat::from_mat3(&ws.x0[body].e.transpose());
    let com = ws.com_world(model, body);
    let v = ws.point_velocity(body, model.bodies[body].com_m);
    BodySpace::new(rot, com, v, ws.angular_velocity(body))
}
