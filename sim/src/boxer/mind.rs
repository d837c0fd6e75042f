//! The virtual human's cognitive model (seed 000, sections 3.5 and 3.7-3.10): when an avatar
//! hand comes at any part of it fast enough, copy the world state into a prediction workspace and
//! run it ahead with the user's hands extrapolated and its own reaches continuing; classify the
//! predicted contacts by Table I; the highest-priority, earliest one drives the behaviour state
//! machines of Fig. 5 (hands: standby / attack / block; body: standby / avoidance), whose actions
//! (Table II) are reaching motions: a block by Fig. 7, avoidance by the geometry of Fig. 6 (the
//! chest leaning only as far as the waist allows), attacks at the avatar's head or chest with a
//! seeded random target and duration. `docs/boxing.md` describes the model as built.
//!
//! A defence (block, and avoidance when needed) answers one avatar hand. While it is under way
//! the other hand stands by and no attack starts or continues (Fig. 5); every prediction during
//! it asks what would happen if the virtual human stood by now: while that still finds the fist
//! on its head or chest the defence goes on (aimed at the newest prediction), and it ends, the
//! body returning to its guard, as soon as it does not (a feint, a punch that has gone by).
//!
//! Passive mode (section 4.2) switches all of it off: the body then only yields to contacts.
//!
//! Must never: read the world's workspace after the step begins to change it, allocate once built
//! (the predictor is sized at construction), let two hands attack at once, or attack during a
//! defence.

use std::time::Instant;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::perceive::{Perception, Skill};
use super::reach::Reach;
use super::stance::{not_toward, Stance};
use super::{coupling_force, BoxerParams, HandTarget, Parts, StepReport, AVATAR, BOXER};
use crate::model::{Model, Part};
use crate::state::{State, Workspace};
use crate::step::Predictor;

/// Contacts of one kind closer together than this are one hit (s).
pub const HIT_GAP_S: f64 = 0.1;

/// Table I: what a predicted contact between a virtual-human part and an avatar part means.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactClass {
    /// 1. (head, hand), (chest, hand): the avatar's attack lands.
    AvatarAttack,
    /// 2. (hand, head), (hand, chest): the virtual human's attack lands.
    BoxerAttack,
    /// 3. (hand, hand), (arm, hand): the virtual human blocked.
    BoxerBlocked,
    /// 4. (hand, arm): the avatar blocked.
    AvatarBlocked,
    /// 5. Any other pair.
    Other,
}

/// Table I priorities, ordered: `High > Middle > Low`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Priority {
    Low,
    Middle,
    High,
}

impl ContactClass {
    /// Classifies a contact by the virtual human's part and the avatar's part.
    pub fn of(vh: Part, av: Part) -> ContactClass {
        use Part::*;
        let arm = |p| matches!(p, Forearm | UpperArm);
        match (vh, av) {
            (Head | Chest, Hand) => ContactClass::AvatarAttack,
            (Hand, Head | Chest) => ContactClass::BoxerAttack,
            (Hand, Hand) => ContactClass::BoxerBlocked,
            (p, Hand) if arm(p) => ContactClass::BoxerBlocked,
            (Hand, p) if arm(p) => ContactClass::AvatarBlocked,
            _ => ContactClass::Other,
        }
    }

    pub fn priority(self) -> Priority {
        match self {
            ContactClass::AvatarAttack | ContactClass::BoxerAttack => Priority::High,
            ContactClass::BoxerBlocked | ContactClass::AvatarBlocked => Priority::Middle,
            ContactClass::Other => Priority::Low,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ContactClass::AvatarAttack => "avatar's attack",
            ContactClass::BoxerAttack => "own attack",
            ContactClass::BoxerBlocked => "own block",
            ContactClass::AvatarBlocked => "avatar's block",
            ContactClass::Other => "other",
        }
    }
}

/// A hand's behaviour (Fig. 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Behaviour {
    Standby,
    Attack,
    Block,
}

/// The body's (head and chest) behaviour (Fig. 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BodyBehaviour {
    Standby,
    Avoidance,
}

/// The contact that decided a prediction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decision {
    pub class: ContactClass,
    pub vh_body: usize,
    pub av_body: usize,
    /// Predicted contact point (world) and when, in simulated time.
    pub point_m: DVec3,
    pub at_s: f64,
    /// The avatar hand's centre when the prediction started (A in Figs. 6 and 7), when an
    /// avatar hand is involved.
    pub hand_start_m: DVec3,
    /// The avatar hand's centre at the contact in the prediction.
    pub hand_at_contact_m: DVec3,
    /// The virtual human's hand (0 or 1) whose glove or arm this avatar hand met earlier in the
    /// same prediction: the punch gets to the part by pushing through that guard.
    pub through_guard: Option<usize>,
}

/// The defence under way: which avatar hand it answers and which part it keeps unhit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Defence {
    /// 0 or 1: the avatar hand whose punch it answers.
    pub av_hand: usize,
    /// The virtual human's head or chest.
    pub part: usize,
    /// The blocking hand (0 or 1), if a block is part of it.
    pub blocking: Option<usize>,
    /// The body moves too (avoidance, or the trunk's lean for the chest).
    pub avoiding: bool,
    /// Simulated time it began.
    pub since_s: f64,
    /// Hits taken when it began (a defence that ends with no more kept the fist off).
    pub hits_before: u64,
    /// The fist it answers has touched the virtual human (a block met it, or it landed). A
    /// defence that ends untouched and unmet (`met`) was drawn for nothing (a feint, a punch
    /// that fell short): the feint's recovery follows ([`Skill::feint_recovery_s`]).
    pub touched: bool,
    /// Where the part was when the defence began, and whether the fist (as seen) has since come
    /// within [`MET_M`] of it: a punch slipped goes through where the part was, a feint stops
    /// short of it. A defence the fist met (touched or came there) was no feint's.
    pub part_from_m: DVec3,
    pub met: bool,
}

/// A fist seen within this of where the defended part was when the defence began met the
/// defence (m): the head's capsule (9 cm) and the fist (4 cm) touch at 0.13. A feint stops
/// 10-20 cm before the part's surface, 0.22-0.32 m from its centre.
pub const MET_M: f64 = 0.15;

/// Tunables of the cognitive model (`mind` in `configs/boxer.ron`, which documents each).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MindParams {
    /// An avatar hand closing on any part of the virtual human faster than this triggers a
    /// prediction.
    pub trigger_m_per_s: f64,
    /// While an avatar hand closes on it faster than this, the body does not go back to its
    /// guard (toward the fist) and no attack starts.
    pub approach_m_per_s: f64,
    /// How far ahead a prediction runs.
    pub horizon_s: f64,
    /// After a middle-priority contact, keep predicting this long for a high one.
    pub middle_grace_s: f64,
    /// Do not start another prediction sooner than this after one.
    pub predict_every_s: f64,
    /// A user's hand slowing down at more than this (m/s^2) is extrapolated to where it stops,
    /// not along a straight line at its speed.
    pub decel_m_per_s2: f64,
    /// Avoidance: P' extends AP by this factor; R lies this far from the trajectory (Q), on the
    /// ray from Q through B.
    pub avoid_extend: f64,
    pub avoid_clearance_m: f64,
    /// Avoidance: the cost of moving the part down or up relative to sideways (see
    /// [`avoid_target`]).
    pub avoid_duck_cost: f64,
    /// Avoidance reaches finish this fraction of the predicted time to contact (the linear
    /// extrapolation of an accelerating fist predicts the contact late).
    pub avoid_time_fraction: f64,
    /// The body moves as well as the block when the predicted contact is this close (s), or
    /// when no hand can block in time.
    pub avoid_lead_s: f64,
    /// The trunk leans back from a punch at the chest by pulling the head back this far (m),
    /// about what the waist's range allows.
    pub lean_m: f64,
    /// Block reaches finish this fraction of the time to contact.
    pub block_time_fraction: f64,
    /// Attack decision probability per step while both hands stand by (the lab's 0.004).
    pub attack_per_step: f64,
    /// Attack reach duration range (s).
    pub attack_s: (f64, f64),
    /// The attack's target point is the centre of the avatar's head or chest moved by a random
    /// offset up to this far in each axis (section 4.4.3: the target position is set randomly).
    pub attack_scatter_m: f64,
    /// A finished attack is held this long before the hand returns to standby.
    pub hold_s: f64,
    /// After a defence the body goes back to its guard in a reach this long (s).
    pub return_s: f64,
    /// An avatar fist closer than this to the head's or the chest's centre, or touching the
    /// virtual human, is out at it: the body holds and braces as while a fist comes (m).
    pub fist_near_m: f64,
    /// The stance ([`Stance`]) follows the waist at most this far from its place (m), and steps
    /// back to it at this speed once no fist comes or is near (m/s).
    pub stance_step_max_m: f64,
    pub stance_return_m_per_s: f64,
    /// While it guards, the legs brace: a spring toward the stance (N/m) and a damper (N s/m).
    pub brace_k_n_per_m: f64,
    pub brace_d_n_s_per_m: f64,
    /// The level of skill: its perception and decision parameters.
    pub skill: Skill,
}

impl Default for MindParams {
    /// The values of the built-in `configs/boxer.ron`.
    fn default() -> Self {
        BoxerParams::default().mind
    }
}

/// The cognitive model and the reaches it commands.
pub struct Mind {
    pub params: MindParams,
    pub active: bool,
    pub hands: [Behaviour; 2],
    pub body: BodyBehaviour,
    /// Current reaches: hands [left, right], then the body (head or chest).
    pub reaches: [Option<Reach>; 3],
    pub defence: Option<Defence>,
    pub predictor: Predictor,
    /// The contact that decided the newest prediction (None: it found none).
    pub last_decision: Option<Decision>,
    /// Counters: predictions run, their last and total wall time (ns), behaviours entered,
    /// defences ended because the newest prediction no longer found the contact.
    pub predictions: u64,
    pub last_predict_ns: u64,
    pub predict_ns_total: u64,
    /// Predictions whose predicted world came apart (a velocity no longer finite) and that
    /// stopped there (see [`Mind::predict_with`]).
    pub predictions_blown_up: u64,
    pub avoidances: u64,
    pub blocks: u64,
    pub attacks: u64,
    pub defences_ended: u64,
    /// Defences that ended with the fist never having met them (a feint drew them, or the punch
    /// fell short: [`Defence::met`]); each is followed by the feint's recovery.
    pub defences_aborted: u64,
    /// Hits taken (the avatar's fist on head or chest) and given (its hand on the avatar's).
    pub hits_taken: u64,
    pub hits_given: u64,
    /// Attacks given up because a prediction found them blocked (Table I classes 3 and 4 with
    /// no hit of its own after), and attacks started as counters after a defence.
    pub attacks_abandoned: u64,
    pub counters: u64,
    /// What it sees of the avatar ([`Perception`]): the gaze, attention and each fist's sight.
    pub perception: Perception,
    /// A counter may start until this simulated time (a defence kept the fist off).
    counter_until_s: f64,
    /// No new defence starts before this simulated time (the refractory period after one).
    refractory_until_s: f64,
    /// The state its predictions start from (the avatar as seen); taken while one runs.
    perceived: Option<State>,
    /// The generator of the sight's errors (apart from the attacks' so either can change alone).
    sight_rng: Pcg64Mcg,
    /// Simulated time of the last step with the avatar's fist on the head or chest, and with its
    /// hand on the avatar's.
    last_hit_s: f64,
    last_hitting_s: f64,
    next_predict_s: f64,
    /// Per user hand: the velocity of the previous step and a smoothed acceleration, for the
    /// extrapolation.
    prev_vel: [Option<DVec3>; 2],
    pub hand_acc_m_per_s2: [DVec3; 2],
    /// Where its legs hold its waist ([`Stance`]): it follows the waist while a fist comes or a
    /// defence is under way, and steps back to its place once none does.
    pub stance: Stance,
    /// The legs brace (`brace_k_n_per_m`, `brace_d_n_s_per_m`): while a fist comes or is near,
    /// or a defence is under way.
    pub braced: bool,
    vh: Parts,
    av: Parts,
    rng: Pcg64Mcg,
}

/// Time constant of the smoothing of the user's hand acceleration (s).
const ACC_SMOOTH_S: f64 = 0.006;

impl Mind {
    pub fn new(model: &Model, p: &BoxerParams, vh: &Parts, av: &Parts) -> Mind {
        Mind {
            params: p.mind,
            active: p.active,
            hands: [Behaviour::Standby; 2],
            body: BodyBehaviour::Standby,
            reaches: [None; 3],
            defence: None,
            predictor: Predictor::new(model),
            last_decision: None,
            predictions: 0,
            last_predict_ns: 0,
            predict_ns_total: 0,
            predictions_blown_up: 0,
            avoidances: 0,
            blocks: 0,
            attacks: 0,
            defences_ended: 0,
            defences_aborted: 0,
            hits_taken: 0,
            hits_given: 0,
            attacks_abandoned: 0,
            counters: 0,
            perception: Perception::new(model, p.mind.skill, vh, av),
            counter_until_s: f64::NEG_INFINITY,
            refractory_until_s: f64::NEG_INFINITY,
            perceived: Some(State::new(model)),
            sight_rng: Pcg64Mcg::seed_from_u64(p.seed ^ 0x005e_ed0f_5197),
            last_hit_s: f64::NEG_INFINITY,
            last_hitting_s: f64::NEG_INFINITY,
            next_predict_s: 0.0,
            prev_vel: [None; 2],
            hand_acc_m_per_s2: [DVec3::ZERO; 2],
            stance: Stance::new(model, vh.waist),
            braced: false,
            vh: *vh,
            av: *av,
            rng: Pcg64Mcg::seed_from_u64(p.seed),
        }
    }

    /// Is an avatar hand closing on any part of the virtual human (head, chest, hands, arms)
    /// faster than the trigger speed (section 3.7)? At any angle: a hook closes on the head from
    /// the side.
    pub fn triggered(&self, model: &Model, ws: &Workspace) -> bool {
        self.closing_faster_than(model, ws, self.params.trigger_m_per_s)
    }

    /// Is an avatar hand closing on any part of the virtual human faster than `speed_m_per_s`,
    /// as it sees the fists ([`Perception`]; its own parts as they are)?
    pub fn closing_faster_than(&self, model: &Model, ws: &Workspace, speed_m_per_s: f64) -> bool {
        self.fists_closing(model, ws, &self.seen_fists(), speed_m_per_s)
    }

    /// The avatar's fists (centre, velocity) as it sees them now ([`Perception`]).
    pub fn seen_fists(&self) -> [(DVec3, DVec3); 2] {
        self.perception.seen.map(|s| (s.pos_m, s.vel_m_per_s))
    }

    /// The avatar's fists (centre, velocity) as they are, seen or not. Only ever used to keep the
    /// body's own motion from going toward them ([`Mind::fist_in_flight`]), never to decide or
    /// aim a defence.
    pub fn true_fists(&self, model: &Model, ws: &Workspace) -> [(DVec3, DVec3); 2] {
        self.av.hand.map(|h| (ws.com_world(model, h), ws.point_velocity(h, model.bodies[h].com_m)))
    }

    /// Is a fist out at the virtual human as it truly is: closing on any part faster than
    /// `approach_m_per_s`, or near its head or chest ([`Mind::fist_at`])? A person does not
    /// avoid what it has not seen yet, but neither does it walk into a punch on its way back to
    /// its guard: while a fist is in flight the body's own motion (the way back to its guard, the
    /// stance stepping back, a hold letting go) waits, whether the fist is seen yet or not. This
    /// stops motion and never starts a defence: the reaction still waits for the sight.
    pub fn fist_in_flight(&self, model: &Model, ws: &Workspace) -> bool {
        let fists = self.true_fists(model, ws);
        self.fists_closing(model, ws, &fists, self.params.approach_m_per_s)
            || self.fists_near(model, ws, &fists, self.params.fist_near_m)
    }

    /// Is one of `fists` (centre, velocity) closing on any part of the virtual human faster than
    /// `speed_m_per_s`?
    fn fists_closing(
        &self,
        model: &Model,
        ws: &Workspace,
        fists: &[(DVec3, DVec3); 2],
        speed_m_per_s: f64,
    ) -> bool {
        let vh = &self.vh;
        let parts = [vh.head, vh.chest, vh.hand[0], vh.hand[1], vh.forearm[0], vh.forearm[1]];
        fists.iter().any(|&(p, v)| {
            parts.iter().any(|&b| {
                let to = ws.com_world(model, b) - p;
                let d = to.length();
                let closing = (v - ws.point_velocity(b, model.bodies[b].com_m)).dot(to / d);
                d > 1e-6 && closing > speed_m_per_s
            })
        })
    }

    /// Is an avatar fist out at the virtual human: within `m` of its head's or chest's centre,
    /// where they are or where going back to its guard would take them (the waist back at its
    /// place, the head at the guard its reach left from), or touching any part of it (pressing
    /// on a block, say)? `ws` holds the state's contacts.
    pub fn fist_at(&self, model: &Model, ws: &Workspace, m: f64) -> bool {
        // The fists as it sees them; a touch it feels at once.
        self.fists_near(model, ws, &self.seen_fists(), m)
    }

    /// Is one of `fists` within `m` of the head's or chest's centre (where they are or where
    /// going back to guard would take them), or is an avatar fist touching the virtual human?
    fn fists_near(&self, model: &Model, ws: &Workspace, fists: &[(DVec3, DVec3); 2], m: f64) -> bool {
        let (head, chest) = (ws.com_world(model, self.vh.head), ws.com_world(model, self.vh.chest));
        let back = self.stance.place_m - self.stance.waist_m(ws);
        let head_guard = self.reaches[2].map_or(head + back, |r| r.home_m);
        let parts = [head, chest, head_guard, chest + back];
        let near = fists.iter().any(|&(p, _)| parts.iter().any(|&b| (b - p).length() < m));
        let fist = |b: Option<u16>| b.is_some_and(|b| self.av.hand.contains(&(b as usize)));
        let boxer = |b: Option<u16>| b.is_some_and(|b| model.bodies[b as usize].articulation == BOXER);
        near || ws
            .contacts
            .iter()
            .any(|c| (fist(c.body_a) && boxer(c.body_b)) || (fist(c.body_b) && boxer(c.body_a)))
    }

    /// Runs a prediction from `state` with the user's hands at `targets` extrapolated and the
    /// current reaches continuing; returns the deciding contact (highest priority, earliest),
    /// following Table I's stopping rules.
    pub fn predict(
        &mut self,
        model: &Model,
        state: &State,
        targets: &[Option<HandTarget>; 2],
        bp: &BoxerParams,
    ) -> Option<Decision> {
        let reaches = self.reaches;
        self.predict_with(model, state, targets, bp, &reaches, false)
    }

    /// [`Mind::predict`] with `reaches` instead of the current ones, and the stance stepping
    /// back to its place from the start (`stance_returning`) instead of staying where it is.
    pub fn predict_with(
        &mut self,
        model: &Model,
        state: &State,
        targets: &[Option<HandTarget>; 2],
        bp: &BoxerParams,
        reaches: &[Option<Reach>; 3],
        stance_returning: bool,
    ) -> Option<Decision> {
        let started = Instant::now();
        let steps = (self.params.horizon_s / model.dt_s).ceil() as usize;
        let grace = (self.params.middle_grace_s / model.dt_s).ceil() as usize;
        let t0 = state.t_s;
        let (av, vh) = (self.av, self.vh);
        // A person uses little of a briefly seen motion's acceleration (the skill's `accel_seen`).
        let acc = self.hand_acc_m_per_s2.map(|a| a * self.params.skill.accel_seen);
        let mut best: Option<Decision> = None;
        let mut middle_at: Option<usize> = None;
        let mut hand_start = [DVec3::ZERO; 2];
        let mut n = 0usize;
        // Pairs already touching when the prediction starts (guards resting on each other, a
        // fist held against a block) are the present, not a prediction: skip them. Fixed
        // capacity; more are simply not skipped.
        let mut present = [(usize::MAX, usize::MAX); 16];
        let mut n_present = 0;
        let decel = self.params.decel_m_per_s2;
        let stance = self.stance;
        let brace = (self.braced && !stance_returning).then_some(self.brace());
        let stance_speed = self.params.stance_return_m_per_s;
        let mut blown_up = false;
        // Per avatar hand, the virtual human's hand whose glove or arm it met first.
        let mut met_guard: [Option<usize>; 2] = [None; 2];
        self.predictor.run(model, state, steps, |m, s, ws| {
            if n == 1 {
                for c in &ws.contacts {
                    if let (Some(a), Some(b)) = (c.body_a, c.body_b) {
                        if n_present < present.len() {
                            present[n_present] = (a as usize, b as usize);
                            n_present += 1;
                        }
                    }
                }
            }
            if n == 0 {
                for h in 0..2 {
                    hand_start[h] = ws.com_world(m, av.hand[h]);
                }
            }
            // Contacts of the previous predicted step, classified by Table I.
            for c in &ws.contacts {
                let (Some(a), Some(b)) = (c.body_a, c.body_b) else { continue };
                let (a, b) = (a as usize, b as usize);
                if n == 1 || present[..n_present].contains(&(a, b)) {
                    continue;
                }
                let (vb, ab) = match (m.bodies[a].articulation, m.bodies[b].articulation) {
                    (BOXER, AVATAR) => (a, b),
                    (AVATAR, BOXER) => (b, a),
                    _ => continue,
                };
                let class = ContactClass::of(m.bodies[vb].part, m.bodies[ab].part);
                let hand = av.hand.iter().position(|&h| h == ab);
                if class == ContactClass::BoxerBlocked {
                    let guard = (0..2).find(|&g| [vh.hand[g], vh.forearm[g], vh.upper_arm[g]].contains(&vb));
                    if let (Some(h), Some(g)) = (hand, guard) {
                        met_guard[h] = met_guard[h].or(Some(g));
                    }
                }
                if outranks(class, &best) {
                    offer(
                        &mut best,
                        &mut middle_at,
                        n,
                        Decision {
                            class,
                            vh_body: vb,
                            av_body: ab,
                            point_m: c.point_m,
                            at_s: s.t_s,
                            hand_start_m: hand.map_or(DVec3::ZERO, |h| hand_start[h]),
                            hand_at_contact_m: ws.com_world(m, ab),
                            through_guard: hand.and_then(|h| met_guard[h]),
                        },
                    );
                }
            }
            match best.map(|d| d.class.priority()) {
                Some(Priority::High) => return false,
                Some(Priority::Middle) if middle_at.is_some_and(|k| n >= k + grace) => return false,
                _ => {}
            }
            // A predicted world that has come apart (a velocity no longer finite: the start
            // pressed parts centimetres into each other, or a blow set a body spinning) finds no
            // contact from here on: ABA spreads a non-finite value to its whole articulation, the
            // shapes' poses follow, and `collide` drops every hit that is not finite. So the
            // decision is already the one the horizon would give; stop rather than step on.
            if !s.v.iter().all(|v| v.is_finite()) {
                blown_up = true;
                return false;
            }
            // Nothing more can happen once nothing moves: both fists (and the user's hands they
            // follow) at rest and every reach done. Stopping there keeps the longest predictions,
            // which find nothing, within the budget.
            let settled = !stance_returning
                || (stance.returning(s.t_s - t0, stance_speed) - stance.place_m).length() < 1e-3;
            let body_still = [vh.head, vh.chest]
                .iter()
                .all(|&b| ws.point_velocity(b, m.bodies[b].com_m).length() < QUIET_BODY_M_PER_S);
            if best.is_none()
                && n >= QUIET_MIN_STEPS
                && settled
                && body_still
                && still(m, ws, s, &av, targets, reaches, acc, decel, t0)
            {
                return false;
            }
            let dt_ahead = s.t_s - t0;
            for (h, t) in targets.iter().enumerate() {
                if let Some(t) = t {
                    let ext = extrapolate(t, acc[h], dt_ahead, decel);
                    let f = coupling_force(m, ws, av.hand[h], &ext, bp);
                    let c = ws.com_world(m, av.hand[h]);
                    ws.add_force_at(av.hand[h], c, f);
                }
            }
            for r in reaches.iter().flatten() {
                r.apply(m, ws, s.t_s);
            }
            let home =
                if stance_returning { stance.returning(dt_ahead, stance_speed) } else { stance.home_m };
            stance.apply(ws, home, brace);
            n += 1;
            true
        });
        self.predictions += 1;
        self.predictions_blown_up += blown_up as u64;
        self.last_predict_ns = started.elapsed().as_nanos() as u64;
        self.predict_ns_total += self.last_predict_ns;
        best
    }

    /// Section 3.9: behaviour from the deciding contact, and the reaches of Table II. Only the
    /// avatar's attack (Table I class 1) changes behaviour; the other classes are recorded.
    pub fn decide(&mut self, model: &Model, ws: &Workspace, now_s: f64, d: &Decision, bp: &BoxerParams) {
        self.last_decision = Some(*d);
        if d.class != ContactClass::AvatarAttack {
            return;
        }
        let Some(av_hand) = self.av.hand.iter().position(|&h| h == d.av_body) else { return };
        let part = if d.vh_body == self.vh.head { self.vh.head } else { self.vh.chest };
        let left = (d.at_s - now_s).max(0.06);
        let (a, p) = (d.hand_start_m, d.hand_at_contact_m);
        let prev = self.defence;
        let mut def = Defence {
            av_hand,
            part,
            blocking: None,
            avoiding: false,
            since_s: now_s,
            hits_before: self.hits_taken,
            touched: false,
            part_from_m: ws.com_world(model, part),
            met: false,
        };
        if let Some(prev) = prev {
            def.since_s = prev.since_s;
            def.hits_before = prev.hits_before;
            def.touched = prev.touched;
            def.part_from_m = prev.part_from_m;
            def.met = prev.met;
        }

        // Block (Fig. 7): a hand goes to the fist's path, to the point where the fist will be
        // when the hand is there first (the prediction's line from A to the contact, walked at
        // its mean speed): of those points a hand gets to in time, the one it moves least for.
        // A punch predicted to get to the part by pushing through a glove or arm already in its
        // way is met by that guard held firm where it is (a boxer tightens the guard that is
        // hit; it does not drop the other glove to the part behind it).
        let (dur, block, block_in_time) = match d.through_guard {
            Some(g) => (0.05, Some((g, ws.com_world(model, self.vh.hand[g]))), true),
            None => self.block_target(model, ws, a, p, left),
        };
        // The body moves too when the contact is close (a fist can glance off a block) or no
        // hand can block in time. The head slips by Fig. 6; the chest cannot move that far and
        // leans only as far as the waist allows, away from the fist.
        // Fig. 5 moves the body as well as a hand; how often it does so when a block alone would
        // do is the skill's (`avoid_chance`), drawn once when a defence begins.
        let chosen = prev.is_none() && self.rng.random::<f64>() < self.params.skill.avoid_chance;
        def.avoiding =
            !block_in_time || left <= self.params.avoid_lead_s || chosen || prev.is_some_and(|p| p.avoiding);
        if let Some((h, target)) = block {
            def.blocking = Some(h);
            // A block under way that already goes there in time is kept (a fresh reach starts
            // from rest).
            let running = self.reaches[h].filter(|r| self.hands[h] == Behaviour::Block && !r.done(now_s));
            let on_time = |r: &Reach| {
                (r.target_m - target).length() < 0.03 && r.start_s + r.duration_s <= now_s + dur + 0.01
            };
            if !running.is_some_and(|r| on_time(&r)) {
                self.reaches[h] = Some(Reach::start(
                    model,
                    ws,
                    self.vh.hand[h],
                    target,
                    now_s,
                    dur,
                    bp.reach_arm_k_n_per_m,
                    bp.reach_arm_d_n_s_per_m,
                ));
            }
            if self.hands[h] != Behaviour::Block {
                self.blocks += 1;
            }
            self.hands[h] = Behaviour::Block;
            // Fig. 5: the other hand stands by; an attack by it stops.
            let o = 1 - h;
            if self.hands[o] != Behaviour::Standby {
                self.hands[o] = Behaviour::Standby;
                self.reaches[o] = None;
            }
        }
        if def.avoiding {
            // The body moves by its head, the top of the chain: a dodge slips the head, a lean
            // pulls it back and the trunk with it. (A reach on the chest would swing the head
            // about it, toward a hook.)
            let head = self.vh.head;
            let b = ws.com_world(model, head);
            // A dodge under way is kept while its target still clears the newly predicted path:
            // restarting it would throw away the motion already gained (a fresh reach starts from
            // rest) and, for a punch aimed dead at the part, could flip the side.
            let keep = match self.reaches[2] {
                Some(r) if self.body == BodyBehaviour::Avoidance && part == head => {
                    let p_ext = a + (p - a) * self.params.avoid_extend;
                    (r.target_m - nearest_on_segment(a, p_ext, r.target_m)).length()
                        >= 0.8 * self.params.avoid_clearance_m
                }
                Some(r) if self.body == BodyBehaviour::Avoidance => r.target_m.z < r.home_m.z,
                _ => false,
            };
            if !keep {
                // A dodge re-aimed, or one from a body on its way back, keeps its guard as home.
                let home = self.reaches[2].map_or(b, |r| r.home_m);
                // The head slips by Fig. 6, from where it is now (a dodge from an earlier punch
                // may have taken it aside). The chest cannot slip that far: the trunk leans back
                // from its guard, away from the fist, as far as the waist lets it.
                let r = if part == self.vh.chest {
                    let away = DVec3::new(b.x - a.x, 0.0, b.z - a.z).normalize_or(DVec3::NEG_Z);
                    // Mostly back (the virtual human faces +z).
                    let dir = DVec3::new(away.x * 0.5, 0.0, -1.0).normalize();
                    // From where the head is now (a punch may have lifted the body, or a dodge
                    // taken it aside) it goes neither toward the avatar nor toward the fist.
                    let mut r = home + dir * self.params.lean_m;
                    r.z = r.z.min(b.z);
                    let to_fist = (a - b).normalize_or_zero();
                    r - to_fist * (r - b).dot(to_fist).max(0.0)
                } else {
                    avoid_target(a, p, b, &self.params)
                };
                // Nor toward the other fist, seen or as it is: a dodge of one punch must not take
                // the head into the next (a combination's second fist is often on its way before
                // it is seen).
                let o = 1 - av_hand;
                let (seen, truly) = (self.seen_fists(), self.true_fists(model, ws));
                let toward = [seen[o].0, truly[o].0].map(|f| (f - b).normalize_or_zero());
                let r = b + not_toward(r - b, &toward);
                let dur = (left * self.params.avoid_time_fraction).max(0.06);
                let mut reach = Reach::start(
                    model,
                    ws,
                    head,
                    r,
                    now_s,
                    dur,
                    bp.reach_body_k_n_per_m,
                    bp.reach_body_d_n_s_per_m,
                );
                reach.home_m = home;
                self.reaches[2] = Some(reach);
            }
            if self.body != BodyBehaviour::Avoidance {
                self.avoidances += 1;
            }
            self.body = BodyBehaviour::Avoidance;
        }
        self.defence = Some(def);
    }

    /// The block against a fist going from `a` to `p` in `left` seconds: (the reach's duration,
    /// the hand and its target, whether it gets there in time). Candidates are points of AP the
    /// fist passes at a time t up to the block's end before the contact; a hand gets to one in
    /// time when its distance is at most `block_speed_m_per_s` times the reach, which ends at
    /// `block_time_fraction` of t. Of the points a hand gets to in time, the least motion; if
    /// none, the point it comes nearest to being on time for.
    fn block_target(
        &self,
        model: &Model,
        ws: &Workspace,
        a: DVec3,
        p: DVec3,
        left: f64,
    ) -> (f64, Option<(usize, DVec3)>, bool) {
        const N: usize = 12;
        let f = self.params.block_time_fraction;
        let v = self.params.skill.block_speed_m_per_s;
        // (hand, target, duration, distance, distance over what it can cover)
        let mut best: Option<(usize, DVec3, f64, f64, f64)> = None;
        for h in 0..2 {
            let hb = ws.com_world(model, self.vh.hand[h]);
            for k in 1..=N {
                let t = left * f * k as f64 / N as f64;
                let x = a + (p - a) * (t / left);
                let dur = (f * t).max(0.03);
                let dist = (x - hb).length();
                let ratio = dist / (v * dur);
                let better = match best {
                    None => true,
                    Some((_, _, _, bd, br)) => {
                        if ratio <= 1.0 {
                            br > 1.0 || dist < bd
                        } else {
                            br > 1.0 && ratio < br
                        }
                    }
                };
                if better {
                    best = Some((h, x, dur, dist, ratio));
                }
            }
        }
        match best {
            Some((h, x, dur, _, ratio)) => (dur, Some((h, x)), ratio <= 1.0),
            None => (0.05, None, false),
        }
    }

    /// Ends the defence under way: the blocking hand returns to its guard (its joints' springs
    /// take it there), the body in an unhurried reach back to where the dodge left from.
    fn end_defence(&mut self, model: &Model, ws: &Workspace, now_s: f64, bp: &BoxerParams) {
        let Some(def) = self.defence.take() else {
            return;
        };
        self.defences_ended += 1;
        // A defence the fist never met leaves the guard out of place and attention on the hand
        // that drew it: the next one waits longer (the feint's recovery).
        let met = def.touched || def.met;
        let wait = if met {
            self.params.skill.refractory_s
        } else {
            self.defences_aborted += 1;
            self.params.skill.feint_recovery_s.max(self.params.skill.refractory_s)
        };
        self.refractory_until_s = now_s + wait;
        // A defence that kept the fist off (blocked or made it miss) opens a counter, by chance;
        // one a feint drew kept nothing off (the fist never came) and opens none.
        if met
            && self.hits_taken == def.hits_before
            && self.rng.random::<f64>() < self.params.skill.counter_chance
        {
            self.counter_until_s = now_s + self.params.skill.counter_within_s;
        }
        for h in 0..2 {
            if self.hands[h] == Behaviour::Block {
                self.hands[h] = Behaviour::Standby;
                self.reaches[h] = None;
            }
        }
        // The body, dodged or held where it stopped on its way back, goes back to its guard.
        self.body = BodyBehaviour::Standby;
        if let Some(r) = self.reaches[2] {
            self.reaches[2] = Some(self.return_reach(model, ws, &r, now_s, bp));
        }
    }

    /// An unhurried reach of the part `r` moves back to where it left its guard from.
    fn return_reach(&self, model: &Model, ws: &Workspace, r: &Reach, now_s: f64, bp: &BoxerParams) -> Reach {
        let mut back = Reach::start(
            model,
            ws,
            r.body,
            r.home_m,
            now_s,
            self.params.return_s,
            bp.reach_body_k_n_per_m,
            bp.reach_body_d_n_s_per_m,
        );
        back.home_m = r.home_m;
        back.tracking()
    }

    /// Called before the world step: trigger, predict, decide, start attacks, end finished reaches.
    pub fn think(
        &mut self,
        model: &Model,
        state: &State,
        ws: &Workspace,
        targets: &[Option<HandTarget>; 2],
        bp: &BoxerParams,
    ) {
        let now = state.t_s;
        // What it sees now: the avatar as it was a perception delay ago.
        self.perception.observe(model, state, ws, targets);
        let seen = self.perception.seen_targets();
        // The fist a defence answers, seen where the part was when it began: the defence met it.
        if let Some(d) = self.defence.as_mut() {
            d.met |= (self.perception.seen[d.av_hand].pos_m - d.part_from_m).length() < MET_M;
        }
        // The user's hands' acceleration as seen, smoothed (for the extrapolation).
        let k = (model.dt_s / ACC_SMOOTH_S).min(1.0);
        for h in 0..2 {
            let v = seen[h].map(|t| t.vel_m_per_s);
            if let (Some(v), Some(pv)) = (v, self.prev_vel[h]) {
                let a = (v - pv) / model.dt_s;
                if a.is_finite() {
                    self.hand_acc_m_per_s2[h] += (a - self.hand_acc_m_per_s2[h]) * k;
                }
            } else {
                self.hand_acc_m_per_s2[h] = DVec3::ZERO;
            }
            self.prev_vel[h] = v;
        }
        // A finished attack is held a little, then the hand returns to standby; the body's
        // way back to its guard is let go of once done (its joints hold it there).
        for h in 0..2 {
            if let Some(r) = self.reaches[h] {
                if self.hands[h] == Behaviour::Attack && now > r.start_s + r.duration_s + self.params.hold_s {
                    self.reaches[h] = None;
                    self.hands[h] = Behaviour::Standby;
                }
            }
        }
        if self.body == BodyBehaviour::Standby && self.reaches[2].is_some_and(|r| r.done(now)) {
            self.reaches[2] = None;
        }
        if !self.active {
            return;
        }
        let defending = self.defence.is_some();
        let closing = self.triggered(model, ws);
        // A fist coming at it, even slowly: the body does not go back toward it, nor does an
        // attack start.
        let approaching = self.closing_faster_than(model, ws, self.params.approach_m_per_s);
        // A fist out at its head or chest, or touching it, coming or not: the body does not go
        // back toward it.
        // And a fist in flight, seen yet or not: the body's own motion waits (it does not go back
        // to its guard into a punch it has not seen yet).
        let guarding =
            approaching || self.fist_at(model, ws, self.params.fist_near_m) || self.fist_in_flight(model, ws);
        let attacking = self.hands.contains(&Behaviour::Attack);
        if now >= self.next_predict_s && (defending || closing || attacking) {
            self.next_predict_s = now + self.params.predict_every_s;
            // During a defence: what if the virtual human stood by now (its defence's reaches
            // gone, the body and the blocking hand left to their joints)? Otherwise as the paper
            // says: its current reaches continue.
            let mut reaches = self.reaches;
            if let Some(d) = self.defence {
                if let Some(h) = d.blocking {
                    reaches[h] = None;
                }
                reaches[2] = None;
            }
            // From what it has seen, not from the world as it is.
            let seen_targets = self.perception.perceived_targets(&mut self.sight_rng);
            let d = match self.perceived.take() {
                Some(mut from) => {
                    self.perception.perceived_state(state, &mut from);
                    let d =
                        self.predict_with(model, &from, &seen_targets, bp, &reaches, self.defence.is_some());
                    self.perceived = Some(from);
                    d
                }
                None => None,
            };
            // The newest prediction finds the other fist first: the defence under way answered
            // the one fist and ends; the answer to the other is a new one, which waits the
            // refractory period (the psychological refractory period: a second response waits
            // for the first), or the feint's recovery when the fist it answered never met it.
            if let (Some(def), Some(d)) = (self.defence, d) {
                let other =
                    self.av.hand.iter().position(|&h| h == d.av_body).is_some_and(|h| h != def.av_hand);
                if d.class == ContactClass::AvatarAttack && other {
                    self.end_defence(model, ws, now, bp);
                }
            }
            let defending = self.defence.is_some();
            match d {
                // A new defence waits out the refractory period after the last one.
                Some(d)
                    if d.class == ContactClass::AvatarAttack
                        && (defending || now >= self.refractory_until_s) =>
                {
                    self.decide(model, ws, now, &d, bp)
                }
                Some(d) if d.class == ContactClass::AvatarAttack => self.last_decision = Some(d),
                Some(d) if self.abandons(&d) => {
                    self.last_decision = Some(d);
                    let h = self.vh.hand.iter().position(|&b| b == d.vh_body).unwrap_or(0);
                    self.hands[h] = Behaviour::Standby;
                    self.reaches[h] = None;
                    self.attacks_abandoned += 1;
                }
                other => {
                    self.last_decision = other;
                    // The newest prediction no longer finds the fist on the head or chest: the
                    // defence ends, and the body goes back to its guard once no fist is closing
                    // on it any more (it does not step back into a punch on its way).
                    if !defending || !closing {
                        self.end_defence(model, ws, now, bp);
                    }
                }
            }
        }
        // While a fist comes at it or is out near it and it is not avoiding, the body holds still
        // where it is: it neither goes back to its guard after a defence (that would be toward
        // the fist) nor sways there on its joints; the head, its most mobile part, is held if
        // nothing else is. Once no fist comes and none is near, it goes back to its guard.
        if self.body == BodyBehaviour::Standby {
            let held = self.reaches[2].is_some_and(|r| is_hold(&r));
            if guarding && !held {
                let home = self.reaches[2].map(|r| r.home_m);
                self.reaches[2] = Some(hold_here(model, ws, self.vh.head, home, now, bp));
            } else if !guarding && held && self.defence.is_none() {
                self.reaches[2] = self.reaches[2].and_then(|r| {
                    ((r.home_m - r.target_m).length() > 0.01)
                        .then(|| self.return_reach(model, ws, &r, now, bp))
                });
            }
        }
        self.place_stance(model, ws, guarding);
        self.stop_a_dodge_into_a_fist(model, ws, now, bp);
        // Attack: one hand at a time, only while both stand by, no defence is under way and no
        // fist is closing on it.
        let idle =
            self.hands.iter().all(|&b| b == Behaviour::Standby) && self.defence.is_none() && !approaching;
        // A counter: right after a defence that kept the fist off, if the skill chose one.
        let counter = idle && now <= self.counter_until_s;
        if counter {
            self.counter_until_s = f64::NEG_INFINITY;
            self.counters += 1;
        }
        if idle && (counter || self.rng.random::<f64>() < self.params.attack_per_step) {
            let h = if self.rng.random::<f64>() < 0.7 { 1 } else { 0 };
            let hand = self.vh.hand[h];
            let hp = ws.com_world(model, hand);
            let (head, chest) = (ws.com_world(model, self.av.head), ws.com_world(model, self.av.chest));
            // Nearer target favoured (section 4.4.3): weight by the other one's distance.
            let (dh, dc) = ((head - hp).length(), (chest - hp).length());
            let centre = if self.rng.random::<f64>() < dc / (dh + dc) { head } else { chest };
            let sc = self.params.attack_scatter_m;
            let mut off = [0.0; 3];
            for o in &mut off {
                *o = if sc > 0.0 { self.rng.random_range(-sc..sc) } else { 0.0 };
            }
            let target = centre + DVec3::from_array(off);
            let (lo, hi) = self.params.attack_s;
            let dur = self.rng.random_range(lo..hi);
            self.reaches[h] = Some(Reach::start(
                model,
                ws,
                hand,
                target,
                now,
                dur,
                bp.reach_arm_k_n_per_m,
                bp.reach_arm_d_n_s_per_m,
            ));
            self.hands[h] = Behaviour::Attack;
            self.attacks += 1;
        }
    }

    /// Moves the stance ([`Stance`]) and lets a hold go of what pulls toward a fist. While a
    /// fist comes at it or is near, or a defence is under way, the stance follows the waist
    /// wherever staying would pull the body toward one of the avatar's fists (seen from the head
    /// and from the chest), and a hold ([`is_hold`]) follows the head the same way: both resist
    /// being moved toward a fist and yield to being moved away. Otherwise the stance steps back
    /// to its place.
    fn place_stance(&mut self, model: &Model, ws: &Workspace, guarding: bool) {
        self.braced = guarding || self.defence.is_some();
        if self.braced {
            // Toward each fist as seen and as it is (the body's own motion goes toward neither).
            let (seen, truly) = (self.seen_fists(), self.true_fists(model, ws));
            let mut toward = [DVec3::ZERO; 8];
            for (k, (part, at)) in [self.vh.head, self.vh.chest]
                .into_iter()
                .flat_map(|p| [seen[0].0, seen[1].0, truly[0].0, truly[1].0].map(|at| (p, at)))
                .enumerate()
            {
                toward[k] = (at - ws.com_world(model, part)).normalize_or_zero();
            }
            let waist = self.stance.waist_m(ws);
            self.stance.follow(waist, &toward, self.params.stance_step_max_m);
            if let Some(r) = self.reaches[2].as_mut().filter(|r| is_hold(r)) {
                let at = ws.point_world(r.body, r.point_body_m);
                let target = at + not_toward(r.target_m - at, &toward);
                if target.is_finite() {
                    r.target_m = target;
                }
            }
        } else {
            self.stance.step_back(model.dt_s, self.params.stance_return_m_per_s);
        }
    }

    /// A dodge (or lean: both are reaches of the head) under way stops where it is, held there,
    /// once the head moves toward a fist that has started toward it (as it truly is: this only
    /// keeps the body's own motion out of a punch, as [`Mind::fist_in_flight`] does). A dodge is
    /// aimed away from the fist it answers and, when it starts, away from the other one too; but a
    /// combination's next fist may leave its guard while the head is still on its way, and from
    /// where it comes the rest of that way can lead into it (issue 15's 2 cm bound: the second or
    /// third punch of a combination met a head dodging the one before 2.2-3.7 cm toward it). The
    /// hold keeps the dodge's home, so the way back to the guard after the defence is as before.
    /// Only the head's motion is checked: checking the chest's as well stopped leans that pulled
    /// the chest down, partly toward a low fist, and let a straight reach the chest.
    fn stop_a_dodge_into_a_fist(&mut self, model: &Model, ws: &Workspace, now: f64, bp: &BoxerParams) {
        if self.body != BodyBehaviour::Avoidance {
            return;
        }
        let Some(r) = self.reaches[2].filter(|r| !is_hold(r)) else { return };
        let (at, v) = (ws.point_world(r.body, r.point_body_m), ws.point_velocity(r.body, r.point_body_m));
        let into = self.true_fists(model, ws).iter().any(|&(fist, fist_v)| {
            let to = (fist - at).normalize_or_zero();
            -fist_v.dot(to) > STARTED_M_PER_S && v.dot(to) > STARTED_M_PER_S
        });
        if into {
            self.reaches[2] = Some(hold_here(model, ws, r.body, Some(r.home_m), now, bp));
        }
    }

    /// The legs' bracing spring and damper (N/m, N s/m).
    fn brace(&self) -> (f64, f64) {
        (self.params.brace_k_n_per_m, self.params.brace_d_n_s_per_m)
    }

    /// Applies the current reaches and the stance for this step.
    pub fn act(&self, model: &Model, ws: &mut Workspace, now_s: f64) {
        for r in self.reaches.iter().flatten() {
            r.apply(model, ws, now_s);
        }
        self.stance.apply(ws, self.stance.home_m, self.braced.then_some(self.brace()));
    }

    /// Counts hits after the world step at `t_s`: a hit is a contact of the kind that begins at
    /// least [`HIT_GAP_S`] after the previous one, so a punch whose contact chatters (a penalty
    /// contact may touch, bounce and touch again within a few steps) counts once.
    pub fn after_step(&mut self, rep: &StepReport, t_s: f64) {
        if let Some(d) = self.defence.as_mut() {
            let h = d.av_hand;
            d.touched |= rep.head_hit[h] || rep.chest_hit[h] || rep.blocked[h];
        }
        if rep.vh_hit() {
            if t_s - self.last_hit_s > HIT_GAP_S {
                self.hits_taken += 1;
            }
            self.last_hit_s = t_s;
        }
        if rep.avatar_hit {
            if t_s - self.last_hitting_s > HIT_GAP_S {
                self.hits_given += 1;
            }
            self.last_hitting_s = t_s;
        }
    }

    /// Does this prediction give up the attack under way: its attacking hand's contact is a block
    /// (Table I class 3 or 4) and no hit of its own came after it within the middle grace?
    fn abandons(&self, d: &Decision) -> bool {
        matches!(d.class, ContactClass::BoxerBlocked | ContactClass::AvatarBlocked)
            && self.vh.hand.iter().zip(self.hands).any(|(&b, beh)| b == d.vh_body && beh == Behaviour::Attack)
    }

    /// The level of skill in use.
    pub fn skill(&self) -> Skill {
        self.params.skill
    }

    /// Number of hands attacking now (never more than one).
    pub fn attacking(&self) -> usize {
        self.hands.iter().filter(|&&b| b == Behaviour::Attack).count()
    }
}

/// A prediction runs at least this many steps before it may stop for want of motion.
const QUIET_MIN_STEPS: usize = 10;
/// Below this speed a fist or a hand is at rest (m/s), and the head and the chest (m/s).
const QUIET_M_PER_S: f64 = 0.2;
const QUIET_BODY_M_PER_S: f64 = 0.02;

/// In a prediction: both avatar fists and the user's hands they follow (extrapolated) at rest,
/// and every reach done (holds excepted: they keep a part still).
#[allow(clippy::too_many_arguments)]
fn still(
    m: &Model,
    ws: &Workspace,
    s: &State,
    av: &Parts,
    targets: &[Option<HandTarget>; 2],
    reaches: &[Option<Reach>; 3],
    acc: [DVec3; 2],
    decel: f64,
    t0: f64,
) -> bool {
    let fists = av.hand.iter().all(|&h| ws.point_velocity(h, m.bodies[h].com_m).length() < QUIET_M_PER_S);
    let hands = targets.iter().enumerate().all(|(h, t)| {
        t.is_none_or(|t| extrapolate(&t, acc[h], s.t_s - t0, decel).vel_m_per_s.length() < QUIET_M_PER_S)
    });
    let reaching = reaches.iter().flatten().any(|r| !is_hold(r) && !r.done(s.t_s));
    fists && hands && !reaching
}

/// A hold ([`is_hold`]) of `body` where it is now, with `home` (default: here) as where its way
/// back to the guard goes once it is let go.
fn hold_here(
    model: &Model,
    ws: &Workspace,
    body: usize,
    home: Option<DVec3>,
    now: f64,
    bp: &BoxerParams,
) -> Reach {
    let here = ws.com_world(model, body);
    let mut hold =
        Reach::start(model, ws, body, here, now, 0.05, bp.reach_body_k_n_per_m, bp.reach_body_d_n_s_per_m);
    hold.home_m = home.unwrap_or(here);
    hold.duration_s = f64::INFINITY;
    hold
}

/// A reach that holds its part where it is while a fist is about (it never ends).
fn is_hold(r: &Reach) -> bool {
    r.duration_s.is_infinite()
}

/// A hand speeding up is expected to reach at most this many times its present speed (the peak
/// of a minimum-jerk punch is 2.4 times its speed a fifth of the way out).
pub const SPEED_UP_MAX: f64 = 2.5;

/// A fist closing on the body, or the body moving toward a fist, faster than this has started
/// to (m/s): the threshold of [`Mind::stop_a_dodge_into_a_fist`], above the sway of a fist held at
/// its guard and of a body at rest.
pub const STARTED_M_PER_S: f64 = 0.05;
/// The extrapolated path turns at most this far (rad), on a radius of at least this (m).
pub const TURN_MAX_RAD: f64 = std::f64::consts::FRAC_PI_2;
pub const RADIUS_MIN_M: f64 = 0.15;

/// Where a user's hand at `t` (smoothed acceleration `acc`) is expected `ahead` seconds on
/// (section 3.7 extrapolates linearly; this keeps what the present motion says of the next
/// fraction of a second):
/// - along its path, its speed changes at the acceleration it has along it: a hand slowing down
///   at more than `decel_m_per_s2` stops where that brings it to rest (a feint stops short), a
///   hand speeding up goes on speeding up to at most [`SPEED_UP_MAX`] times its speed (a punch's
///   first moments are slow, and a line at that speed would see its contact late);
/// - the path bends as it bends now (the acceleration across the velocity over the speed
///   squared), on an arc of at least [`RADIUS_MIN_M`] radius, for at most [`TURN_MAX_RAD`], then
///   goes straight on: hooks and uppercuts curve into their target.
pub fn extrapolate(t: &HandTarget, acc: DVec3, ahead: f64, decel_m_per_s2: f64) -> HandTarget {
    let speed = t.vel_m_per_s.length();
    let linear = HandTarget { pos_m: t.pos_m + t.vel_m_per_s * ahead, vel_m_per_s: t.vel_m_per_s };
    if !(speed > 1e-6 && acc.is_finite() && ahead > 0.0) {
        return if speed > 1e-6 { linear } else { *t };
    }
    let u = t.vel_m_per_s / speed;
    let a = acc.dot(u);
    // Speed changes at `a` for `tt` (until it stops, or reaches the cap), then holds.
    let (a, tt) = if a < -decel_m_per_s2 {
        (a, ahead.min(speed / -a))
    } else if a > 0.0 {
        (a, ahead.min(speed * (SPEED_UP_MAX - 1.0) / a))
    } else {
        (0.0, 0.0)
    };
    let v_end = speed + a * tt;
    let arc = speed * tt + 0.5 * a * tt * tt + v_end * (ahead - tt);
    // The bend: curvature from the acceleration across the velocity.
    let across = acc - u * acc.dot(u);
    let kappa = (across.length() / (speed * speed)).min(1.0 / RADIUS_MIN_M);
    if !(kappa > 1e-9) {
        return HandTarget { pos_m: t.pos_m + u * arc, vel_m_per_s: u * v_end };
    }
    let n = across.normalize();
    let turn = arc * kappa;
    let th = turn.min(TURN_MAX_RAD);
    let r = 1.0 / kappa;
    let (s, c) = th.sin_cos();
    let dir = u * c + n * s;
    let pos = t.pos_m + (u * s + n * (1.0 - c)) * r + dir * ((turn - th) * r);
    HandTarget { pos_m: pos, vel_m_per_s: dir * v_end }
}

/// A contact of `class` replaces the best so far only with a strictly higher priority, so among
/// equals the earliest stands (section 3.8: "the highest and earliest contact decides").
fn outranks(class: ContactClass, best: &Option<Decision>) -> bool {
    best.is_none_or(|d| class.priority() > d.class.priority())
}

/// Takes `d` as the best contact at predicted step `n`; the first middle-priority one starts the
/// grace during which the prediction goes on looking for a high one.
fn offer(best: &mut Option<Decision>, middle_at: &mut Option<usize>, n: usize, d: Decision) {
    if d.class.priority() == Priority::Middle && middle_at.is_none() {
        *middle_at = Some(n);
    }
    *best = Some(d);
}

/// The avoidance target of Fig. 6. A is the avatar's hand when the prediction started, P its
/// predicted centre at the contact, B the centre of the part to move. The hand's path AP' is AP
/// extended by `avoid_extend`; Q is its point nearest B. The paper puts R on the ray from Q
/// through B at a set distance from Q (`avoid_clearance_m`): that is the point of the circle of
/// that radius around the path (in the plane across it at Q) nearest to B. Here "nearest" weighs
/// a vertical move `avoid_duck_cost` times a horizontal one, because the waist lets the upper
/// body slip sideways far more easily than duck (measured: asked for 0.2 m, the head slips
/// 0.18-0.22 m sideways but ducks 0.10 m); with a cost of 1 this is exactly the paper's R. A
/// point toward the avatar (+z) keeps B's depth instead, and a part already clear of the path
/// stays. Nor does it come toward the fist where it is now (A): that component is dropped.
/// A punch aimed dead at B leaves a tie: the part slips away from the side the punch comes from.
pub fn avoid_target(a: DVec3, p: DVec3, b: DVec3, mp: &MindParams) -> DVec3 {
    let p_ext = a + (p - a) * mp.avoid_extend;
    let q = nearest_on_segment(a, p_ext, b);
    let c = mp.avoid_clearance_m;
    if (b - q).length() >= c {
        return b;
    }
    let path = (p_ext - a).normalize_or(DVec3::NEG_Z);
    let e1 = DVec3::Y.cross(path).normalize_or(DVec3::X);
    let e2 = path.cross(e1);
    // On a tie, away from the side the punch comes from: e1 pointing the way B lies from A
    // across the virtual human's front (x), tried first.
    let e1 = if e1.x * (b.x - a.x) >= 0.0 { e1 } else { -e1 };
    let to_fist = (a - b).normalize_or_zero();
    let cost = |r: DVec3| {
        let d = r - b;
        d.x * d.x + d.z * d.z + mp.avoid_duck_cost * d.y * d.y
    };
    const N: usize = 72;
    let mut best = (f64::INFINITY, b);
    for k in 0..N {
        let th = k as f64 * std::f64::consts::TAU / N as f64;
        let mut r = q + (e1 * th.cos() + e2 * th.sin()) * c;
        // Never toward the avatar: such a point keeps B's depth instead; never toward the fist.
        r.z = r.z.min(b.z);
        r -= to_fist * (r - b).dot(to_fist).max(0.0);
        let e = cost(r);
        // Strictly better only: on a tie the earlier angle (from +e1) stays.
        if e < best.0 - 1e-12 {
            best = (e, r);
        }
    }
    best.1
}

/// Nearest point to `p` on the segment `a`..`b`.
pub fn nearest_on_segment(a: DVec3, b: DVec3, p: DVec3) -> DVec3 {
    let ab = b - a;
    let l2 = ab.length_squared();
    if l2 <= 0.0 {
        return a;
    }
    a + ab * ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_table_one_class_gets_its_priority() {
        use Part::*;
        let cases = [
            (Head, Hand, ContactClass::AvatarAttack, Priority::High),
            (Chest, Hand, ContactClass::AvatarAttack, Priority::High),
            (Hand, Head, ContactClass::BoxerAttack, Priority::High),
            (Hand, Chest, ContactClass::BoxerAttack, Priority::High),
            (Hand, Hand, ContactClass::BoxerBlocked, Priority::Middle),
            (Forearm, Hand, ContactClass::BoxerBlocked, Priority::Middle),
            (UpperArm, Hand, ContactClass::BoxerBlocked, Priority::Middle),
            (Hand, Forearm, ContactClass::AvatarBlocked, Priority::Middle),
            (Hand, UpperArm, ContactClass::AvatarBlocked, Priority::Middle),
            (Forearm, Forearm, ContactClass::Other, Priority::Low),
            (Head, Head, ContactClass::Other, Priority::Low),
            (Waist, Hand, ContactClass::Other, Priority::Low),
        ];
        for (vh, av, class, prio) in cases {
            assert_eq!(ContactClass::of(vh, av), class, "({vh:?}, {av:?})");
            assert_eq!(class.priority(), prio, "{class:?}");
        }
        assert!(Priority::High > Priority::Middle && Priority::Middle > Priority::Low);
    }

    fn mind_params(duck: f64) -> MindParams {
        MindParams {
            avoid_extend: 1.5,
            avoid_clearance_m: 0.2,
            avoid_duck_cost: duck,
            ..MindParams::default()
        }
    }

    #[test]
    fn avoidance_with_equal_costs_is_the_papers_fig_6() {
        // A punch along -z passing 5 cm beside and 3 cm under B: Q is abreast of B on the path,
        // R on the ray QB at the clearance.
        let (a, p) = (DVec3::new(0.05, 1.47, 0.0), DVec3::new(0.05, 1.47, -0.8));
        let b = DVec3::new(0.0, 1.5, -0.85);
        let r = avoid_target(a, p, b, &mind_params(1.0));
        let q = DVec3::new(0.05, 1.47, -0.85);
        let want = q + (b - q).normalize() * 0.2;
        assert!((r - want).length() < 0.01, "{r} vs the paper's {want}");
    }

    #[test]
    fn avoidance_prefers_a_slip_to_a_duck_and_never_comes_forward() {
        let mp = mind_params(4.0);
        // A punch passing 5 cm over B: ducking 15 cm costs more than slipping 19 cm sideways.
        let (a, p) = (DVec3::new(0.0, 1.55, 0.0), DVec3::new(0.0, 1.55, -0.8));
        let b = DVec3::new(0.0, 1.5, -0.85);
        let r = avoid_target(a, p, b, &mp);
        assert!((r - b).x.abs() > 0.15 && (r - b).y.abs() < 0.1, "slip expected, got {:?}", r - b);
        // Dead at B from the left (x < 0): the part slips to the right, clear of the path.
        let a = DVec3::new(-0.1, 1.5, 0.0);
        let r = avoid_target(a, b, b, &mp);
        assert!(r.x > b.x + 0.1, "{:?}", r - b);
        let q = nearest_on_segment(a, a + (b - a) * 1.5, r);
        assert!((r - q).length() > 0.19);
        // Never toward the avatar (who is at +z), whatever the geometry.
        for k in 0..50 {
            let th = k as f64 * 0.37;
            let a = b + DVec3::new(th.cos() * 0.3, th.sin() * 0.3, 0.6);
            assert!(avoid_target(a, b, b, &mp).z <= b.z);
        }
        // Already clear of the path: stay.
        let a = DVec3::new(0.4, 1.5, 0.0);
        let p = DVec3::new(0.4, 1.5, -0.8);
        assert_eq!(avoid_target(a, p, b, &mp), b);
    }

    #[test]
    fn avoidance_never_comes_toward_the_fist() {
        let mp = mind_params(1.0);
        let b = DVec3::new(0.0, 1.5, -0.85);
        // Fists coming from every side at and around the head, from where they are now.
        for k in 0..40 {
            let th = k as f64 * 0.41;
            let a = b + DVec3::new(th.cos() * 0.3, th.sin() * 0.15, 0.2 + 0.1 * th.sin());
            let r = avoid_target(a, b + (b - a) * 0.1, b, &mp);
            assert!((r - b).dot((a - b).normalize()) <= 1e-9, "fist at {a}: R {r}");
        }
    }

    fn hand(pos: DVec3, vel: DVec3) -> HandTarget {
        HandTarget { pos_m: pos, vel_m_per_s: vel }
    }

    #[test]
    fn a_steady_hand_is_extrapolated_on_a_straight_line() {
        let t = hand(DVec3::new(0.1, 1.4, -0.3), DVec3::new(0.0, 0.0, -3.0));
        for ahead in [0.0, 0.05, 0.3] {
            let e = extrapolate(&t, DVec3::ZERO, ahead, 5.0);
            assert!((e.pos_m - (t.pos_m + t.vel_m_per_s * ahead)).length() < 1e-12);
            assert_eq!(e.vel_m_per_s, t.vel_m_per_s);
        }
        // A hand at rest stays.
        assert_eq!(extrapolate(&hand(DVec3::ONE, DVec3::ZERO), DVec3::X, 0.2, 5.0).pos_m, DVec3::ONE);
    }

    #[test]
    fn a_slowing_hand_stops_where_its_deceleration_brings_it_to_rest() {
        // 3 m/s slowing at 30 m/s^2: stops after 0.1 s, 0.15 m on.
        let t = hand(DVec3::ZERO, DVec3::new(0.0, 0.0, -3.0));
        let acc = DVec3::new(0.0, 0.0, 30.0);
        for ahead in [0.1, 0.2, 0.5] {
            let e = extrapolate(&t, acc, ahead, 5.0);
            assert!((e.pos_m - DVec3::new(0.0, 0.0, -0.15)).length() < 1e-9, "{ahead}: {}", e.pos_m);
            assert!(e.vel_m_per_s.length() < 1e-9);
        }
        // Under the threshold it is not believed: a straight line.
        let e = extrapolate(&t, DVec3::new(0.0, 0.0, 4.0), 0.1, 5.0);
        assert!((e.pos_m.z + 0.3).abs() < 1e-9);
    }

    #[test]
    fn a_hand_speeding_up_is_expected_to_reach_at_most_its_cap() {
        // 1 m/s speeding up at 100 m/s^2: capped at 2.5 m/s after 15 ms.
        let t = hand(DVec3::ZERO, DVec3::new(0.0, 0.0, -1.0));
        let e = extrapolate(&t, DVec3::new(0.0, 0.0, -100.0), 0.2, 5.0);
        let t_cap = 1.5 / 100.0;
        let want = 1.0 * t_cap + 0.5 * 100.0 * t_cap * t_cap + 2.5 * (0.2 - t_cap);
        assert!((e.pos_m.z + want).abs() < 1e-9, "{} vs {want}", e.pos_m.z);
        assert!((e.vel_m_per_s.length() - SPEED_UP_MAX).abs() < 1e-9);
    }

    #[test]
    fn a_curving_hand_is_extrapolated_along_its_arc_with_limits() {
        // 2 m/s along -z bending toward +x at 20 m/s^2: radius v^2 / a = 0.2 m.
        let t = hand(DVec3::ZERO, DVec3::new(0.0, 0.0, -2.0));
        let acc = DVec3::new(20.0, 0.0, 0.0);
        // A quarter turn takes pi/2 x 0.2 m = 0.314 m, 0.157 s.
        let e = extrapolate(&t, acc, 0.157_079_632_679_489_66, 5.0);
        assert!((e.pos_m - DVec3::new(0.2, 0.0, -0.2)).length() < 1e-6, "{}", e.pos_m);
        // Then straight on, turned by no more than a quarter.
        let e = extrapolate(&t, acc, 0.3, 5.0);
        assert!(e.vel_m_per_s.normalize().dot(DVec3::X) > 1.0 - 1e-9, "{}", e.vel_m_per_s);
        assert!((e.pos_m.z + 0.2).abs() < 1e-6 && e.pos_m.x > 0.2);
        // A sharper bend than 0.15 m radius is taken as 0.15 m.
        let e = extrapolate(&t, DVec3::new(400.0, 0.0, 0.0), 0.5, 5.0);
        assert!((e.pos_m.z + RADIUS_MIN_M).abs() < 1e-6, "{}", e.pos_m);
    }

    #[test]
    fn nearest_point_is_clamped_to_the_segment() {
        let (a, b) = (DVec3::ZERO, DVec3::X);
        assert_eq!(nearest_on_segment(a, b, DVec3::new(0.5, 1.0, 0.0)), DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(nearest_on_segment(a, b, DVec3::new(-2.0, 1.0, 0.0)), a);
        assert_eq!(nearest_on_segment(a, b, DVec3::new(3.0, 0.0, 0.0)), b);
    }
}
