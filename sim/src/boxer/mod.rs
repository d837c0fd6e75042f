//! The virtual boxer of seed 000: the boxing world (avatar and virtual human), the avatar driven
//! by the user's hands, and the virtual human's motion control and cognitive model.
//!
//! Why a module of its own: the engine (`step`, `Predictor`) knows nothing of boxing; this is
//! where the paper's application lives: the avatar's hands pulled to the user's hands by
//! spring-dampers (section 3.4), the reaching springs (appendix, [`reach`]), and the cognitive
//! model that predicts on a copy of the state and picks avoid / block / attack ([`mind`]).
//!
//! Force feedback (sections 3.4, 3.12), the paper's coupling: the avatar's fists are bodies of
//! this world and collide with the virtual human here, so the virtual human receives the
//! avatar's contact, a block stops the avatar's fist, and the prediction runs the same contacts.
//! The user feels the contact force acting on the avatar's hands: every step reports it per
//! hand as a local model ([`HandContact`]: force, normal, the contact's stiffness in series with
//! the coupling spring, and the user's hand position it was computed for), which the rt-loop
//! renders at 1 kHz with the user's motion, clipped to what the rig can push.
//!
//! Must never: feed the coupling spring back to the user (it is the avatar's dynamics, not a
//! contact), or allocate in a step after construction.

pub mod config;
pub mod mind;
pub mod perceive;
pub mod reach;
pub mod spar;
pub mod stance;

use glam::{DMat3, DVec3};
use spidar_msg::{Blow, HandContact, ProxyShape};

use crate::aba::aba;
use crate::collide::Shape;
use crate::contact::contacts;
use crate::desc::boxing_scene;
use crate::model::{Model, Part, Side};
use crate::passive::passive_forces;
use crate::state::{kinematics, State, Workspace};
use crate::step::integrate;
use crate::SimError;

pub use config::{load_boxer, parse_boxer, BOXER_RON};
pub use mind::{Behaviour, BodyBehaviour, ContactClass, Mind, MindParams, Priority};
pub use perceive::{Perception, Seen, Skill, SkillLevel};
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
    /// The coupling's force is limited to this (N): the avatar's arm pushes no harder than an
    /// arm does, however far past a block or a part the user's real hand goes (the rig cannot
    /// stop it).
    pub coupling_max_n: f64,
    /// The avatar's joint springs and dampers as a fraction of the fighter's in body-upper.ron:
    /// the paper gives the avatar softer joints so its hands nearly reach the user's hands.
    pub avatar_joint_scale: f64,
    /// Contacts on the avatar's other parts reach both hands times this (the lab's 0.1).
    pub damage_attenuation: f64,
    /// Reaching spring stiffness (N/m) and damping (N s/m) for a hand / forearm, and for the
    /// head / chest (heavier, held by the stiff waist).
    pub reach_arm_k_n_per_m: f64,
    pub reach_arm_d_n_s_per_m: f64,
    pub reach_body_k_n_per_m: f64,
    pub reach_body_d_n_s_per_m: f64,
    /// The virtual human's cognitive model on (active) or off (passive, section 4.2).
    pub active: bool,
    /// The cognitive model's tunables, with the skill in use (`mind.skill`).
    pub mind: MindParams,
    /// Every level of skill of the boxer file, by [`SkillLevel::index`].
    pub skills: [Skill; 3],
    /// Seed of the attack generator (target and duration).
    pub seed: u64,
}

impl Default for BoxerParams {
    /// The built-in `configs/boxer.ron` (a test checks it loads).
    fn default() -> Self {
        parse_boxer(BOXER_RON, "configs/boxer.ron (built in)")
            .expect("the built-in boxer file is valid (tested)")
    }
}

impl BoxerParams {
    /// These parameters at another level of skill (the file's `skills`).
    pub fn with_skill(mut self, level: SkillLevel) -> BoxerParams {
        self.mind.skill = self.skills[level.index()];
        self
    }

    /// These parameters with the paper's perfect perception (no delay, no error, a full view)
    /// and no counters or forced avoidances: for tests of the decision mechanics alone.
    pub fn with_perfect_perception(mut self) -> BoxerParams {
        self.mind.skill = Skill::perfect(self.mind.skill.level, self.mind.skill.block_speed_m_per_s);
        self
    }

    /// The level of skill in use.
    pub fn skill(&self) -> SkillLevel {
        self.mind.skill.level
    }
}

/// Where the user's hand pulls the avatar's hand (simulation frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandTarget {
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
}

/// What one step did, for the scene and the tests. Contacts are those of the state the step
/// ended in: what the world holds until the next step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepReport {
    /// Force of the coupling spring on each avatar hand (never fed back).
    pub coupling_force_n: [DVec3; 2],
    /// Per avatar hand: its contact as the local model the rt-loop renders (the user's hand
    /// position `at_m` in the rt-loop's world frame, without `user_offset_m`); zero when the hand
    /// touches nothing or is not tracked.
    pub hand_contacts: [HandContact; 2],
    /// Sum of the contact forces on the avatar's other parts.
    pub damage_force_n: DVec3,
    /// Per avatar hand: it touches the virtual human's head, its chest, one of its hands or
    /// forearms (a block).
    pub head_hit: [bool; 2],
    pub chest_hit: [bool; 2],
    pub blocked: [bool; 2],
    /// The virtual human's hand touches the avatar's head or chest.
    pub avatar_hit: bool,
    /// Sum of the contact forces of the virtual human's hands on the avatar's head and chest (a
    /// part of `damage_force_n`: the blow's, which the rt-loop renders from `blow`).
    pub blow_force_n: DVec3,
    /// The newest blow the virtual human landed on the avatar (its `seq` changes with each new
    /// one; `in_contact` while its fist is still on the avatar).
    pub blow: Blow,
}

impl StepReport {
    /// An avatar hand touches the virtual human's head or chest.
    pub fn vh_hit(&self) -> bool {
        self.head_hit.iter().chain(&self.chest_hit).any(|&x| x)
    }
}

/// The boxing world: both bodies, stepped at the scene's 3 ms.
pub struct BoxingWorld {
    /// The world model; the prediction runs the same one (the avatar's fists collide in both).
    pub model: Model,
    pub state: State,
    pub ws: Workspace,
    pub params: BoxerParams,
    pub avatar: Parts,
    pub vh: Parts,
    pub mind: Mind,
    pub last: StepReport,
    /// Per avatar hand, per shape of the model: the penalty stiffness of the pair the hand's
    /// shape forms with it (N/m; 0 for none).
    hand_pair_k: [Vec<f64>; 2],
    /// Per avatar hand: the running estimate of how its contact force grows with the user's hand.
    stiffness: [StiffnessEstimate; 2],
    /// The state whose kinematics and contacts `ws` holds (its contact forces are already in
    /// `ws.f_ext`), so a step never computes them twice and never uses stale ones.
    kin_state: State,
    prepared: bool,
    /// The newest landed blow, and when a fist of the virtual human last touched the avatar's
    /// head or chest.
    blow: Blow,
    blow_touch_s: f64,
}

/// A touch of the virtual human's fist on the avatar's head or chest that begins at least this
/// long after the last one is a new blow (the hit counters' rule: a chattering contact is one).
pub const BLOW_GAP_S: f64 = mind::HIT_GAP_S;

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
        let hand_pair_k = avatar.hand.map(|hand| {
            let mut k = vec![0.0; model.shapes.len()];
            for p in &model.pairs {
                let (a, b) = (p.a as usize, p.b as usize);
                if model.shapes[a].body == Some(hand) {
                    k[b] = p.k_n_per_m;
                } else if model.shapes[b].body == Some(hand) {
                    k[a] = p.k_n_per_m;
                }
            }
            k
        });
        let state = State::new(&model);
        let ws = Workspace::new(&model);
        let mind = Mind::new(&model, &params, &vh, &avatar);
        let mut w = BoxingWorld {
            kin_state: state.clone(),
            model,
            state,
            ws,
            params,
            avatar,
            vh,
            mind,
            last: StepReport::default(),
            hand_pair_k,
            stiffness: [StiffnessEstimate::default(); 2],
            prepared: false,
            blow: Blow::default(),
            blow_touch_s: f64::NEG_INFINITY,
        };
        w.begin_step();
        Ok(w)
    }

    pub fn dt_s(&self) -> f64 {
        self.model.dt_s
    }

    /// Kinematics and contacts of the current state (their forces into the workspace), unless
    /// the workspace already holds them; [`BoxingWorld::step`] leaves them ready, so this only
    /// works after the state was changed from outside.
    pub fn begin_step(&mut self) {
        if self.prepared && same_bits(&self.kin_state, &self.state) {
            return;
        }
        self.ws.f_ext.fill(crate::spatial::SVec::ZERO);
        kinematics(&self.model, &self.state, &mut self.ws);
        contacts(&self.model, &mut self.ws);
        self.kin_state.copy_from(&self.state);
        self.prepared = true;
    }

    /// One 3 ms step with the avatar's hands pulled toward `targets` (None: that hand is not
    /// tracked and only its joints hold it). The report's contacts are those of the new state.
    pub fn step(&mut self, targets: &[Option<HandTarget>; 2]) -> StepReport {
        self.begin_step();
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
        }
        // The virtual human thinks (prediction on a copy) and acts (its reaches).
        self.mind.think(m, &self.state, &self.ws, targets, &self.params);
        self.mind.act(m, &mut self.ws, self.state.t_s);
        // The contacts of this state are already in the workspace (`begin_step`).
        passive_forces(m, &self.state, &mut self.ws);
        aba(m, &self.state, &mut self.ws);
        integrate(m, &mut self.state, &mut self.ws);
        self.prepared = false;
        self.begin_step();
        self.report_contacts(targets, &mut rep);
        self.mind.after_step(&rep, self.state.t_s);
        self.last = rep;
        rep
    }

    /// Fills the contact part of `rep` from the workspace's contacts (the new state's).
    fn report_contacts(&mut self, targets: &[Option<HandTarget>; 2], rep: &mut StepReport) {
        let m = &self.model;
        let (av, vh) = (&self.avatar, &self.vh);
        let avatar_bodies = m.articulations[AVATAR].bodies.clone();
        // Per hand: the summed force, the stiffness-weighted normal, the summed stiffness and the
        // power the touched bodies put in.
        let mut sums = [(DVec3::ZERO, DVec3::ZERO, 0.0f64, 0.0f64); 2];
        // The fastest touch of a virtual human's fist on the avatar's head or chest: (relative
        // speed, point, relative velocity, striking hand's side).
        let mut strike: Option<(f64, DVec3, DVec3, usize)> = None;
        for c in &self.ws.contacts {
            let (Some(a), Some(b)) = (c.body_a.map(usize::from), c.body_b.map(usize::from)) else {
                continue;
            };
            // Seen from each side: (body, its force, the normal toward it, the other body, the
            // other body's shape).
            for (me, f, n, other, other_shape) in
                [(a, c.force_n, c.normal, b, c.shape_b), (b, -c.force_n, -c.normal, a, c.shape_a)]
            {
                if let Some(h) = av.hand.iter().position(|&x| x == me) {
                    let k = self.hand_pair_k[h][other_shape as usize];
                    sums[h].0 += f;
                    sums[h].1 += n * k;
                    sums[h].2 += k;
                    let x = &self.ws.x0[other];
                    let v_other = self.ws.point_velocity(other, x.e * (c.point_m - x.r));
                    sums[h].3 += f.dot(v_other);
                    rep.head_hit[h] |= other == vh.head;
                    rep.chest_hit[h] |= other == vh.chest;
                    rep.blocked[h] |= vh.hand.contains(&other) || vh.forearm.contains(&other);
                } else if avatar_bodies.contains(&me) {
                    rep.damage_force_n += f;
                    let side = vh.hand.iter().position(|&x| x == other);
                    if let (true, Some(side)) = (me == av.head || me == av.chest, side) {
                        rep.avatar_hit = true;
                        rep.blow_force_n += f;
                        let (xo, xm) = (&self.ws.x0[other], &self.ws.x0[me]);
                        let v_rel = self.ws.point_velocity(other, xo.e * (c.point_m - xo.r))
                            - self.ws.point_velocity(me, xm.e * (c.point_m - xm.r));
                        let speed = v_rel.length();
                        if speed.is_finite() && strike.is_none_or(|s| speed > s.0) {
                            strike = Some((speed, c.point_m, v_rel, side));
                        }
                    }
                }
            }
        }
        let p = &self.params;
        let kc = p.coupling_k_n_per_m;
        for h in 0..2 {
            let (f, nk, k, source) = sums[h];
            let Some(t) = targets[h] else { continue };
            if f == DVec3::ZERO || !f.is_finite() {
                continue;
            }
            // How the force grows as the user's hand goes in: measured from the world's own
            // response (the touched body and the avatar give as well as the springs), never more
            // than the contact spring in series with the coupling spring, and nothing while the
            // coupling pulls at its limit (a deeper hand then pulls no harder).
            let hand = self.avatar.hand[h];
            let x = self.ws.point_world(hand, m.bodies[hand].com_m);
            let saturated = ((t.pos_m - x) * kc).length() >= p.coupling_max_n;
            let normal = nk.normalize_or(f.normalize_or_zero());
            let at = t.pos_m - p.user_offset_m;
            let series = if k > 0.0 { kc * k / (kc + k) } else { 0.0 };
            let est = self.stiffness[h].update(at, f, normal);
            rep.hand_contacts[h] = HandContact {
                force_n: f,
                normal,
                k_n_per_m: if saturated { 0.0 } else { est.clamp(0.0, series) },
                at_m: at,
                source_w: if source.is_finite() { source } else { 0.0 },
            };
        }
        for h in 0..2 {
            if !rep.hand_contacts[h].touching() {
                self.stiffness[h] = StiffnessEstimate::default();
            }
        }
        self.report_blow(strike, rep);
    }

    /// The blow part of `rep`: a touch of the virtual human's fist on the avatar's head or chest
    /// (`strike`: its relative speed, point, relative velocity and side) that begins
    /// [`BLOW_GAP_S`] after the last one is a new blow, measured at this first touching step:
    /// its direction and speed are the fist's relative to the struck part, its momentum the
    /// striking hand and forearm's mass times that speed.
    fn report_blow(&mut self, strike: Option<(f64, DVec3, DVec3, usize)>, rep: &mut StepReport) {
        let t = self.state.t_s;
        match strike {
            Some((speed, point_m, v_rel, side)) => {
                if t - self.blow_touch_s > BLOW_GAP_S {
                    let m = &self.model;
                    let mass = m.bodies[self.vh.hand[side]].mass_kg + m.bodies[self.vh.forearm[side]].mass_kg;
                    self.blow = Blow {
                        seq: self.blow.seq + 1,
                        point_m,
                        dir: v_rel.normalize_or_zero(),
                        speed_m_per_s: speed,
                        momentum_n_s: mass * speed,
                        in_contact: true,
                    };
                }
                self.blow_touch_s = t;
            }
            None => self.blow.in_contact = false,
        }
        rep.blow = self.blow;
    }

    /// World position of a body's centre of mass (after `begin_step` or `step`).
    pub fn com(&self, body: usize) -> DVec3 {
        self.ws.com_world(&self.model, body)
    }
}

/// How fast an avatar hand's contact force grows as the user's hand goes in, from the world's own
/// response: a least-squares slope of the force change over the user's hand's motion along the
/// normal, step by step, weighted toward the last [`StiffnessEstimate::WINDOW_STEPS`] steps.
/// The first steps of a contact (an impact, which says nothing of the slope) give none.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StiffnessEstimate {
    last: Option<(DVec3, DVec3)>,
    sxy: f64,
    sxx: f64,
    steps: u32,
}

impl StiffnessEstimate {
    /// Steps the estimate mostly remembers (30 ms at 3 ms).
    pub const WINDOW_STEPS: f64 = 10.0;
    /// Motion below this over the window (m, rms per step) says nothing of the slope.
    const MIN_MOTION_M: f64 = 1e-5;

    /// Adds this step's user hand position `at_m` and force `f_n` (normal `n`); returns the slope
    /// (N/m), 0 while it knows too little.
    pub fn update(&mut self, at_m: DVec3, f_n: DVec3, n: DVec3) -> f64 {
        if let Some((at0, f0)) = self.last {
            // In: against the normal.
            let dx = (at0 - at_m).dot(n);
            let df = (f_n - f0).dot(n);
            let a = 1.0 / Self::WINDOW_STEPS;
            self.sxy += a * (dx * df - self.sxy);
            self.sxx += a * (dx * dx - self.sxx);
            self.steps += 1;
        }
        self.last = Some((at_m, f_n));
        let enough = self.steps as f64 >= Self::WINDOW_STEPS && self.sxx > Self::MIN_MOTION_M.powi(2);
        if enough && (self.sxy / self.sxx).is_finite() {
            self.sxy / self.sxx
        } else {
            0.0
        }
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
        f.clamp_length_max(p.coupling_max_n)
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
