//! The virtual boxer of seed 000: the boxing world (avatar and virtual human), the avatar driven
//! by the user's hands, and the virtual human's motion control and cognitive model.
//!
//! Why a module of its own: the engine (`step`, `Predictor`) knows nothing of boxing; this is
//! where the paper's application lives: the avatar's hands pulled to the user's hands by
//! spring-dampers (section 3.4), the reaching springs (appendix, [`reach`]), and the cognitive
//! model that predicts on a copy of the state and picks avoid / block / attack ([`mind`]).
//!
//! Force feedback (sections 3.4, 3.12): the user's hands touch the virtual human through the
//! rt-loop's 1 kHz rendering against proxies of the virtual human's parts; the impulses of those
//! virtual contacts (before the rig's force clamp: the user feels them only as far as the rig can
//! show them) come back and are given to those parts here, and their reaction to the avatar's
//! hands. So the avatar's hand shapes must not also collide with the virtual human in the world
//! simulation (that would count each contact twice): those pairs are removed from the world
//! model. The prediction model keeps them: there is no rt-loop inside a prediction.
//!
//! Must never: feed the coupling spring back to the user (it is the avatar's dynamics, not a
//! contact), or allocate in a step after construction.

pub mod config;
pub mod mind;
pub mod reach;

use glam::{DMat3, DVec3};
use spidar_msg::ProxyShape;

use crate::collide::Shape;

use crate::desc::boxing_scene;
use crate::model::{Model, Part, Side};
use crate::state::{kinematics, State, Workspace};
use crate::step::{forward, forward_dynamics, integrate};
use crate::SimError;

pub use config::{load_boxer, parse_boxer, BOXER_RON};
pub use mind::{Behaviour, BodyBehaviour, ContactClass, Mind, MindParams, Priority};
pub use reach::{min_jerk, Reach};

/// Index of the avatar and of the virtual human in the boxing scene.
pub const AVATAR: usize = 0;
pub const BOXER: usize = 1;

/// The bodies of one upper body, by part; arrays are [left, right].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parts {
    pub waist: usize,
    pub chest: usize,
    pub head: usize,
    pub upper_arm: [usize; 2],
    pub forearm: [usize; 2],
    pub hand: [usize; 2],
}

impl Parts {
    fn find(model: &Model, art: usize) -> Result<Parts, SimError> {
        let f = |part, side| {
            model.find_part(art, part, side).ok_or_else(|| {
                SimError::Build(format!(
                    "the boxing scene's actor {art} has no {part:?} ({side:?}): the boxer needs the 9-solid upper body"
                ))
            })
        };
        Ok(Parts {
            waist: f(Part::Waist, Side::Centre)?,
            chest: f(Part::Chest, Side::Centre)?,
            head: f(Part::Head, Side::Centre)?,
            upper_arm: [f(Part::UpperArm, Side::Left)?, f(Part::UpperArm, Side::Right)?],
            forearm: [f(Part::Forearm, Side::Left)?, f(Part::Forearm, Side::Right)?],
            hand: [f(Part::Hand, Side::Left)?, f(Part::Hand, Side::Right)?],
        })
    }
}

/// Parameters of the boxing world. Defaults are the values the tests and `spidar run` use.
#[derive(Clone, Debug, PartialEq)]
pub struct BoxerParams {
    /// Added to a user's hand (world frame of the rt-loop) to place the avatar's hand target in the
    /// simulation. The lab used SPIDAR position + (0, 1.4, -0.3) m; our rig file already adds
    /// (0, 1.10, 0), so this is the rest: it brings the user's home grips to the avatar's guard.
    pub user_offset_m: DVec3,
    /// Coupling spring from the user's hand to the avatar's hand (N/m) and its damper (N s/m).
    pub coupling_k_n_per_m: f64,
    pub coupling_d_n_s_per_m: f64,
    /// The avatar's joint springs and dampers as a fraction of the fighter's in body-upper.ron:
    /// the paper gives the avatar softer joints so its hands nearly reach the user's hands.
    pub avatar_joint_scale: f64,
    /// Contacts on the avatar's other parts reach both hands times this (the lab's 0.1).
    pub damage_attenuation: f64,
    /// Penalty gains of the proxies the rt-loop renders (the rig softens above its own limit).
    pub proxy_k_n_per_m: f64,
    pub proxy_d_n_s_per_m: f64,
    /// Only parts of the virtual human closer than this to a hand (surface to grip centre) are
    /// published as proxies.
    pub proxy_range_m: f64,
    /// Reaching spring stiffness (N/m) and damping (N s/m) for a hand / forearm, and for the
    /// head / chest (heavier, held by the stiff waist).
    pub reach_arm_k_n_per_m: f64,
    pub reach_arm_d_n_s_per_m: f64,
    pub reach_body_k_n_per_m: f64,
    pub reach_body_d_n_s_per_m: f64,
    /// The virtual human's cognitive model on (active) or off (passive, section 4.2).
    pub active: bool,
    /// Radius of the sphere that stands for the user's fist (the rig file's `grip_radius_m`):
    /// the prediction tests the extrapolated hands with it against the virtual human's parts,
    /// as the rt-loop will render them.
    pub grip_radius_m: f64,
    /// The cognitive model's tunables.
    pub mind: MindParams,
    /// Seed of the attack generator (target and duration).
    pub seed: u64,
    /// Let the avatar's hands collide with the virtual human in the world simulation. Only for
    /// running the world without a rig (`spidar eval reactions`, as in the lab's simulation):
    /// behind the rt-loop these contacts come from its rendering and would count twice.
    pub avatar_hands_collide: bool,
}

impl Default for BoxerParams {
    /// The built-in `configs/boxer.ron` (a test checks it loads).
    fn default() -> Self {
        parse_boxer(BOXER_RON, "configs/boxer.ron (built in)")
            .expect("the built-in boxer file is valid (tested)")
    }
}

/// Where the user's hand pulls the avatar's hand (simulation frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandTarget {
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
}

/// What one step did, for the scene and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepReport {
    /// Force of the coupling spring on each avatar hand (never fed back).
    pub coupling_force_n: [DVec3; 2],
    /// Contact force on each avatar hand from the rt-loop's contacts with the virtual human (the
    /// reaction of the impulses it reported), averaged over the step.
    pub hand_contact_force_n: [DVec3; 2],
    /// Sum of the contact forces on the avatar's other parts (world simulation).
    pub damage_force_n: DVec3,
    /// The user's hands touched the virtual human's head or chest this step.
    pub vh_hit: bool,
    /// The virtual human's hand touched the avatar's head or chest this step.
    pub avatar_hit: bool,
}

/// The boxing world: both bodies, stepped at the scene's 3 ms.
pub struct BoxingWorld {
    /// The world model: avatar hands do not collide with the virtual human (see module doc).
    pub model: Model,
    /// The prediction model: every pair, so predicted punches land.
    pub predict_model: Model,
    pub state: State,
    pub ws: Workspace,
    pub params: BoxerParams,
    pub avatar: Parts,
    pub vh: Parts,
    pub mind: Mind,
    pub last: StepReport,
    /// Impulses from the user's hands gathered for the coming step, per avatar hand.
    pending_hand_impulse_n_s: [DVec3; 2],
    pending_vh_hit: bool,
    /// The state whose kinematics `ws` holds (copied by `begin_step`), so `step` can skip a
    /// second kinematics pass of the same state and still never use stale kinematics.
    kin_state: State,
}

impl BoxingWorld {
    pub fn new(params: BoxerParams) -> Result<BoxingWorld, SimError> {
        let mut model = boxing_scene()?;
        if model.articulations.len() < 2 {
            return Err(SimError::Build("the boxing scene needs two actors: avatar, then boxer".into()));
        }
        let avatar = Parts::find(&model, AVATAR)?;
        let vh = Parts::find(&model, BOXER)?;
        let s = params.avatar_joint_scale;
        if !(s > 0.0 && s <= 1.0) {
            return Err(SimError::Build(format!("avatar_joint_scale {s} must be in (0, 1]")));
        }
        // Softer avatar joints (not the root: its base spring holds the body at home).
        for b in model.articulations[AVATAR].bodies.clone().skip(1) {
            for k in model.bodies[b].stiffness.iter_mut() {
                *k *= s;
            }
            for d in model.bodies[b].damping.iter_mut() {
                *d *= s;
            }
        }
        let predict_model = model.clone();
        let vh_bodies = model.articulations[BOXER].bodies.clone();
        let shapes = &model.shapes;
        let is_avatar_hand = |k: u16| shapes[k as usize].body.is_some_and(|b| avatar.hand.contains(&b));
        let is_vh = |k: u16| shapes[k as usize].body.is_some_and(|b| vh_bodies.contains(&b));
        let keep: Vec<bool> = model
            .pairs
            .iter()
            .map(|p| !((is_avatar_hand(p.a) && is_vh(p.b)) || (is_avatar_hand(p.b) && is_vh(p.a))))
            .collect();
        if !params.avatar_hands_collide {
            let mut it = keep.iter();
            model.pairs.retain(|_| *it.next().unwrap_or(&true));
        }
        let state = State::new(&model);
        let mut ws = Workspace::new(&model);
        kinematics(&model, &state, &mut ws);
        let mind = Mind::new(&predict_model, &params, &vh, &avatar);
        Ok(BoxingWorld {
            kin_state: state.clone(),
            model,
            predict_model,
            state,
            ws,
            params,
            avatar,
            vh,
            mind,
            last: StepReport::default(),
            pending_hand_impulse_n_s: [DVec3::ZERO; 2],
            pending_vh_hit: false,
        })
    }

    pub fn dt_s(&self) -> f64 {
        self.model.dt_s
    }

    /// Kinematics of the current state; call before [`BoxingWorld::apply_user_impulse`].
    pub fn begin_step(&mut self) {
        kinematics(&self.model, &self.state, &mut self.ws);
        self.kin_state.copy_from(&self.state);
    }

    /// The impulse of a virtual contact the rt-loop rendered between user hand `hand` and
    /// virtual-human body `body` at `point_m` (simulation frame), not limited by the rig's force
    /// clamp: given to that body now, and its reaction to the avatar's hand, which carries the
    /// contact the user's hand feels only up to the rig's limit (the lab's avatar hand collided
    /// in the simulation the same way).
    pub fn apply_user_impulse(&mut self, hand: usize, body: usize, point_m: DVec3, impulse_n_s: DVec3) {
        if !impulse_n_s.is_finite() || !self.model.articulations[BOXER].bodies.contains(&body) {
            return;
        }
        let dt = self.model.dt_s;
        self.ws.add_impulse_at(body, point_m, impulse_n_s, dt);
        let h = self.avatar.hand[hand.min(1)];
        let c = self.ws.com_world(&self.model, h);
        self.ws.add_impulse_at(h, c, -impulse_n_s, dt);
        self.pending_hand_impulse_n_s[hand.min(1)] += impulse_n_s;
        if body == self.vh.head || body == self.vh.chest {
            self.pending_vh_hit = true;
        }
    }

    /// One 3 ms step with the avatar's hands pulled toward `targets` (None: that hand is not
    /// tracked and only its joints hold it).
    pub fn step(&mut self, targets: &[Option<HandTarget>; 2]) -> StepReport {
        let m = &self.model;
        let mut rep = StepReport::default();
        for (h, t) in targets.iter().enumerate() {
            if let Some(t) = t {
                let f = coupling_force(m, &self.ws, self.avatar.hand[h], t, &self.params);
                let b = self.avatar.hand[h];
                let c = self.ws.com_world(m, b);
                self.ws.add_force_at(b, c, f);
                rep.coupling_force_n[h] = f;
            }
            rep.hand_contact_force_n[h] = -self.pending_hand_impulse_n_s[h] / m.dt_s;
        }
        rep.vh_hit = self.pending_vh_hit;
        self.pending_hand_impulse_n_s = [DVec3::ZERO; 2];
        self.pending_vh_hit = false;
        // The virtual human thinks (prediction on a copy) and acts (its reaches).
        self.mind.think(&self.predict_model, &self.state, &self.ws, targets, &self.params);
        self.mind.act(m, &mut self.ws, self.state.t_s);
        // `begin_step` normally ran the kinematics of this very state: then only the dynamics
        // remain (the same bits either way; the full pass when the state changed since).
        if same_bits(&self.kin_state, &self.state) {
            forward_dynamics(m, &self.state, &mut self.ws);
        } else {
            forward(m, &self.state, &mut self.ws);
        }
        let avatar_bodies = m.articulations[AVATAR].bodies.clone();
        for c in &self.ws.contacts {
            for (b, f, other) in [(c.body_a, c.force_n, c.body_b), (c.body_b, -c.force_n, c.body_a)] {
                let Some(b) = b.map(|b| b as usize) else { continue };
                if avatar_bodies.contains(&b) && !self.avatar.hand.contains(&b) {
                    rep.damage_force_n += f;
                    let o = other.map(|o| o as usize);
                    if (b == self.avatar.head || b == self.avatar.chest)
                        && o.is_some_and(|o| self.vh.hand.contains(&o))
                    {
                        rep.avatar_hit = true;
                    }
                }
            }
        }
        integrate(m, &mut self.state, &mut self.ws);
        self.mind.after_step(&rep, self.state.t_s);
        self.last = rep;
        rep
    }

    /// World position of a body's centre of mass (after `begin_step` or `step`).
    pub fn com(&self, body: usize) -> DVec3 {
        self.ws.com_world(&self.model, body)
    }
}

/// The two states are the same to the bit (so their kinematics are).
fn same_bits(a: &State, b: &State) -> bool {
    let eq =
        |x: &[f64], y: &[f64]| x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits());
    a.steps == b.steps && a.t_s.to_bits() == b.t_s.to_bits() && eq(&a.q, &b.q) && eq(&a.v, &b.v)
}

/// The coupling spring-damper on an avatar hand toward the user's hand.
pub fn coupling_force(model: &Model, ws: &Workspace, hand: usize, t: &HandTarget, p: &BoxerParams) -> DVec3 {
    let com = model.bodies[hand].com_m;
    let x = ws.point_world(hand, com);
    let v = ws.point_velocity(hand, com);
    let f = (t.pos_m - x) * p.coupling_k_n_per_m + (t.vel_m_per_s - v) * p.coupling_d_n_s_per_m;
    if f.is_finite() {
        f
    } else {
        DVec3::ZERO
    }
}

/// A proxy for a collision shape at a world pose: spheres and capsules as they are, a box as the
/// capsule along its longest axis with the radius of its thinnest half extent (the chest).
pub fn proxy_shape(s: &Shape, pos: DVec3, rot: DMat3) -> Option<ProxyShape> {
    match *s {
        Shape::Sphere { radius_m } => Some(ProxyShape::Sphere { centre_m: pos, radius_m }),
        Shape::Capsule { half_length_m, radius_m } => {
            let ax = rot * DVec3::Y * half_length_m;
            Some(ProxyShape::Capsule { a_m: pos - ax, b_m: pos + ax, radius_m })
        }
        Shape::Box { half_extents_m: e } => {
            let (axis, long) = if e.x >= e.y && e.x >= e.z {
                (DVec3::X, e.x)
            } else if e.y >= e.z {
                (DVec3::Y, e.y)
            } else {
                (DVec3::Z, e.z)
            };
            let r = e.min_element();
            let ax = rot * axis * (long - r).max(0.0);
            Some(ProxyShape::Capsule { a_m: pos - ax, b_m: pos + ax, radius_m: r })
        }
        Shape::Plane => None,
    }
}
