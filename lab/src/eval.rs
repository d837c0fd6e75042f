//! `spidar eval reactions`: the boxing paper's evaluations, automated, on the path `spidar run`
//! uses: the scripted user's hands in the simulated rig, the rt-loop (kinematics, rendering of
//! the avatar hands' contacts, safety, tension allocation), and the boxing world behind it,
//! in-process on the virtual clock (one tick, then a world step every 3 ms, as [`Bout`] runs).
//!
//! - The cost of the world step and of the prediction during a bout (the paper's Table III),
//!   per step: steps without a prediction, predictions alone, and the whole steps that ran one.
//! - What the punches did ([`punch_outcomes`]): a box script of straights, hooks and uppercuts
//!   with both hands at 2-7 m/s, at the head and the chest, single and in combinations, with
//!   feints; per punch whether it landed, was blocked, started an avoidance, how soon the virtual
//!   human reacted, and how far its head and chest moved toward the fist.
//! - The reaction experiment of section 4.3 (Table IV): the scripted user throws straights at
//!   four targets of the virtual human; an observer that sees only the virtual human's motion
//!   guesses the target. The observer ([`Person`]) stands for a participant of the study page:
//!   one clip seen once from the user's eye, no answer ever given to learn from, the motion on
//!   the picture read with what everyone knows of blows and defences. A leave-one-out classifier
//!   trained on each condition's own labelled trials is printed beside it (it learns any
//!   consistent motion, which no participant can). The virtual human's own attacks are off so
//!   every reaction answers the punch.
//!
//! Must never: be used as a timed test (wall-clock numbers are printed, not asserted).

use std::fmt;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use spidar_device::sim::{Script, SimRig};
use spidar_msg::{ContactModel, HandSample};
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Clock, Rig};
use spidar_sim::boxer::{Behaviour, BodyBehaviour, BoxerParams, Mind, SkillLevel};

use spidar_runtime::scripts::{
    aim_points_now, box_plan, Aim, BoxPlan, PlanOptions, Punch, PunchKind, SeeingUser, UserGuard,
};
use spidar_runtime::session::{sim_device, SimOptions, VirtualRun, HOLD_AT_HOME_S};
use spidar_world::boxing::BoxingScene;
use spidar_world::Scene;

/// What every evaluation here says it measured.
pub const PATH: &str =
    "the path of `spidar run`: scripted user -> simulated rig -> rt-loop -> boxing world, \
                        in-process on the virtual clock (1 ms ticks, a world step every 3 ms)";

/// Median and 99th percentile of a set of durations (ns), in ms.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Spread {
    pub n: usize,
    pub median_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

impl Spread {
    pub fn of(ns: Vec<u64>) -> Spread {
        if ns.is_empty() {
            return Spread::default();
        }
        let n = ns.len();
        let [median, p99, max] = quantiles(ns).map(|x| x as f64 * 1e-6);
        Spread { n, median_ms: median, p99_ms: p99, max_ms: max }
    }
}

/// Median, 99th percentile and maximum (nearest rank); zeros when empty.
fn quantiles(mut v: Vec<u64>) -> [u64; 3] {
    v.sort_unstable();
    let at = |q: f64| v.get(((v.len().max(1) - 1) as f64 * q).round() as usize).copied().unwrap_or(0);
    [at(0.5), at(0.99), at(1.0)]
}

impl fmt::Display for Spread {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "median {:.3} ms, p99 {:.3} ms, max {:.3} ms ({} samples)",
            self.median_ms, self.p99_ms, self.max_ms, self.n
        )
    }
}

/// The boxing scene behind the rt-loop on the simulated rig, driven tick by tick on the virtual
/// clock: the path of `spidar run`, with the scene kept typed so its world can be read after
/// every step.
pub struct Bout {
    pub v: VirtualRun<SimRig>,
    pub scene: BoxingScene,
    samples: Vec<HandSample>,
    /// The samples the last world step consumed, and the records of their ticks.
    pub consumed: Vec<HandSample>,
    pub consumed_recs: Vec<TickRecord>,
    recs: Vec<TickRecord>,
    /// The last models sent, newest last (a sample names the one it rendered by `seq`).
    sent: std::collections::VecDeque<ContactModel>,
    next_step_ns: u64,
    /// The scripted user in closed loop ([`Bout::seeing`]), and the rig it maps what it sees to.
    pub user: Option<SeeingUser>,
    rig: Rig,
}

/// Models a [`Bout`] keeps for looking up by `seq`.
const KEPT_MODELS: usize = 8;

impl Bout {
    /// Homed and activated, the user's hands following `scripts` after they hold the grips at
    /// home while the rig homes.
    pub fn new(params: BoxerParams, scripts: [Script; 2], seed: u64) -> anyhow::Result<Bout> {
        let rig = Rig::default_rig();
        let scripts = scripts.map(|s| {
            let hold = s.start_hold_s.max(HOLD_AT_HOME_S);
            s.with_start_hold(hold)
        });
        let dev = sim_device(&rig, scripts, &SimOptions { seed, ..Default::default() })?;
        let mut v = VirtualRun::new(dev, &rig, None)?;
        v.home_and_activate();
        Ok(Bout {
            v,
            scene: BoxingScene::new(params)?,
            samples: Vec::with_capacity(16),
            consumed: Vec::with_capacity(16),
            consumed_recs: Vec::with_capacity(16),
            recs: Vec::with_capacity(16),
            sent: std::collections::VecDeque::with_capacity(KEPT_MODELS + 1),
            next_step_ns: 0,
            user: None,
            rig,
        })
    }

    /// [`Bout::new`] with the user throwing `plan`'s punches in closed loop: each aimed, as it
    /// starts, at the part where the user saw it ([`SeeingUser`]), the way a person at the rig
    /// aims at the picture, not at where the part stood in its guard.
    pub fn seeing(params: BoxerParams, plan: &BoxPlan, seed: u64) -> anyhow::Result<Bout> {
        let user = SeeingUser::new(plan);
        let mut b = Bout::new(params, user.holding_scripts(), seed)?;
        b.user = Some(user);
        Ok(b)
    }

    /// One tick, then a world step if one is due (true): `consumed` then holds its samples.
    pub fn tick(&mut self) -> (TickRecord, bool) {
        if let Some(u) = self.user.as_mut() {
            let now = self.v.rt.device().truth().t_s - HOLD_AT_HOME_S;
            // A plan's scripts are valid by construction; a bad one is a bug here.
            while let Some((_, hand, script)) = u.due(now, self.rig.period_s).expect("a punch's script") {
                self.v.rt.device_mut().try_set_script(hand, script).expect("a punch's script");
            }
        }
        self.v.rt.tick();
        let rec = *self.v.rt.last_record();
        self.v.stats.add(&rec);
        self.recs.push(rec);
        self.samples.extend(self.v.far.samples.try_iter());
        let now = self.v.clock.now_ns();
        if now >= self.next_step_ns {
            let m = self.scene.step(now as f64 * 1e-9, &self.samples);
            let _ = self.v.far.models.try_send(m);
            if self.sent.len() == KEPT_MODELS {
                self.sent.pop_front();
            }
            self.sent.push_back(m);
            self.next_step_ns = now + (self.scene.step_s() * 1e9).round() as u64;
            self.consumed.clear();
            self.consumed.append(&mut self.samples);
            self.consumed_recs.clear();
            self.consumed_recs.append(&mut self.recs);
            let t = self.script_t_s();
            if let Some(u) = self.user.as_mut() {
                u.see(t, aim_points_now(&self.scene.world, &self.rig));
            }
            return (rec, true);
        }
        (rec, false)
    }

    /// One of the last models sent, by its `seq`.
    pub fn model(&self, seq: u64) -> Option<&ContactModel> {
        self.sent.iter().find(|m| m.seq == seq)
    }

    /// Time on the scripts' clock (their start hold excluded).
    pub fn script_t_s(&self) -> f64 {
        self.v.rt.device().truth().t_s - HOLD_AT_HOME_S
    }
}

/// What a timed bout measured.
#[derive(serde::Serialize)]
pub struct BoutTiming {
    pub seconds: f64,
    /// World steps without a prediction in them.
    pub step: Spread,
    /// Predictions alone.
    pub prediction: Spread,
    /// World steps with a prediction in them, whole (the sim thread's worst 3 ms).
    pub step_with_prediction: Spread,
    /// Steps each prediction ran (median, p99, max) and the horizon's steps: Table I's stopping
    /// rules end most predictions early, and the longest ones make the tail.
    pub prediction_steps: [u64; 3],
    /// Predictions by the steps they ran: 1-25, 26-50, 51-100, 101 to one short of the horizon,
    /// the whole horizon (the longest, which find nothing and make the time's tail).
    pub prediction_steps_histogram: [u64; 5],
    /// A prediction's time over the steps it ran (us; median, p99): the cost of one predicted
    /// step, which does not depend on how far the stopping rules let a prediction go.
    pub per_predicted_step_us: [f64; 2],
    /// Predictions stopped because their predicted world came apart (a velocity not finite).
    pub blown_up: u64,
    pub horizon_steps: u64,
    pub misses: u64,
    pub status: String,
}

impl fmt::Display for BoutTiming {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        writeln!(f, "bout of {} s (box script, active virtual human), per 3 ms step:", self.seconds)?;
        writeln!(f, "  world step   {}", self.step)?;
        writeln!(f, "  prediction   {}", self.prediction)?;
        writeln!(f, "  step+predict {}", self.step_with_prediction)?;
        let [med, p99, max] = self.prediction_steps;
        writeln!(f, "  pred. steps  median {med}, p99 {p99}, max {max} of {} ahead", self.horizon_steps)?;
        let [a, b, c, d, e] = self.prediction_steps_histogram;
        let h = self.horizon_steps;
        writeln!(
            f,
            "  pred. steps  1-25: {a}, 26-50: {b}, 51-100: {c}, 101-{}: {d}, {h}: {e}",
            h.saturating_sub(1)
        )?;
        let [step_med, step_p99] = self.per_predicted_step_us;
        writeln!(f, "  per pred. step median {step_med:.1} us, p99 {step_p99:.1} us")?;
        writeln!(f, "  pred. blown up {} (stopped once a velocity was not finite)", self.blown_up)?;
        writeln!(f, "  rt misses    {}", self.misses)?;
        write!(f, "  scene        {}", self.status)
    }
}

/// A bout of `seconds` of the `box` script against an active virtual human, timed per step.
pub fn bout_timing(seconds: f64, seed: u64) -> anyhow::Result<BoutTiming> {
    let rig = Rig::default_rig();
    let params = BoxerParams::default();
    let opts = PlanOptions { punches: (seconds as usize).max(1), ..Default::default() };
    let plan = box_plan(&rig, &params, seed, &opts)?;
    let mut b = Bout::seeing(params, &plan, seed)?;
    let (mut steps, mut preds, mut predicting) = (Vec::new(), Vec::new(), Vec::new());
    let mut pred_steps = Vec::new();
    let ticks = (seconds / rig.period_s).round() as u64;
    for _ in 0..ticks {
        let before = b.scene.world.mind.predictions;
        if !b.tick().1 {
            continue;
        }
        if b.scene.world.mind.predictions > before {
            preds.push(b.scene.world.mind.last_predict_ns);
            predicting.push(b.scene.last_step_ns);
            // The predictor's copy started from the state before this step.
            let w = &b.scene.world;
            pred_steps.push((w.mind.predictor.state.steps + 1).saturating_sub(w.state.steps));
        } else {
            steps.push(b.scene.last_step_ns);
        }
    }
    let horizon_steps = (b.scene.world.mind.params.horizon_s / b.scene.world.dt_s()).ceil() as u64;
    let mut histogram = [0u64; 5];
    for &n in &pred_steps {
        let bin = match n {
            n if n >= horizon_steps => 4,
            101.. => 3,
            51.. => 2,
            26.. => 1,
            _ => 0,
        };
        histogram[bin] += 1;
    }
    // Per predicted step, in tenths of a microsecond so the quantiles keep a decimal.
    let per_step = preds.iter().zip(&pred_steps).map(|(&ns, &n)| ns / (100 * n.max(1))).collect();
    let [step_med, step_p99, _] = quantiles(per_step).map(|x| x as f64 * 0.1);
    Ok(BoutTiming {
        seconds,
        step: Spread::of(steps),
        prediction: Spread::of(preds),
        step_with_prediction: Spread::of(predicting),
        prediction_steps: quantiles(pred_steps),
        prediction_steps_histogram: histogram,
        per_predicted_step_us: [step_med, step_p99],
        blown_up: b.scene.world.mind.predictions_blown_up,
        horizon_steps,
        misses: b.v.counters().misses,
        status: b.scene.status_text(),
    })
}

// ---------------------------------------------------------------------------------------------
// What the punches did.

/// Motion of the virtual human's parts smaller than this is not a reaction (m).
pub const SEEN_M: f64 = 0.01;
/// A punch's window runs this long after its hand is back at the guard (s).
const WINDOW_TAIL_S: f64 = 0.1;

/// What one punch did, as the world and the rig saw it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PunchOutcome {
    pub punch: Punch,
    /// The user's hand's highest speed during the punch (the rig's estimate, m/s).
    pub peak_m_per_s: f64,
    /// The avatar's fist of the punching hand touched the virtual human's head, its chest, one of
    /// its hands or forearms.
    pub head: bool,
    pub chest: bool,
    pub blocked: bool,
    /// The virtual human's body went into avoidance during the punch, and a hand into a block.
    pub avoidance: bool,
    pub block: bool,
    /// The punch started with the virtual human standing by (nothing under way).
    pub from_rest: bool,
    /// From the punch's start to the first motion of the virtual human's head, chest or hands
    /// over 1 cm once a defence is under way (s); and whether that came before the fist
    /// touched it.
    pub reaction_s: Option<f64>,
    pub reacted_before_contact: bool,
    /// The farthest the head or chest moved toward the punching fist during the punch and the
    /// tail of its window, and while the fist was on its way out (m).
    pub toward_fist_m: f64,
    pub toward_fist_out_m: f64,
    /// Where the farthest motion toward the fist while it came out happened: which part, when
    /// (s after the punch's start) and what the virtual human was doing then.
    pub toward_fist_out_at: Option<TowardFist>,
    /// A block met the fist: the force the user's hand felt on the first tick that rendered that
    /// contact and the contact force the world had then (N), when it met it (s after the punch's
    /// start), and whether the fist then got to the part it was aimed at.
    pub block_felt_n: Option<(f64, f64)>,
    pub block_at_s: f64,
    pub landed_after_block: bool,
    /// How far the part it was aimed at (the head, or the chest for chest aims) was from where
    /// it stood at the bout's start when the punch started (m). The closed-loop user aims where it
    /// saw the part ([`SeeingUser`]), so this is how far the body had moved from its guard, not an
    /// aiming error (the open-loop script aimed at the guard, where a moved body was not).
    pub part_off_m: f64,
}

/// The moment of a punch's farthest motion of the head or chest toward the fist.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TowardFist {
    /// "head" or "chest".
    pub part: &'static str,
    /// Seconds after the punch's start.
    pub at_s: f64,
    /// What moved the body then (see [`body_motion`]), and the hands' behaviours.
    pub body: &'static str,
    pub hands: [&'static str; 2],
}

/// What moves the virtual human's body: "avoiding" (a dodge or lean), "held" (held still while
/// a fist comes), "returning" (its way back to its guard) or "free" (only its joints).
pub fn body_motion(m: &Mind) -> &'static str {
    match (m.body, m.reaches[2]) {
        (BodyBehaviour::Avoidance, _) => "avoiding",
        (_, Some(r)) if r.duration_s.is_infinite() => "held",
        (_, Some(_)) => "returning",
        (_, None) => "free",
    }
}

fn behaviour_name(b: Behaviour) -> &'static str {
    match b {
        Behaviour::Standby => "standby",
        Behaviour::Attack => "attack",
        Behaviour::Block => "block",
    }
}

impl PunchOutcome {
    /// A block met the fist on its way out and the user's hand felt it on the first tick that
    /// rendered it: at least half of the contact force, or of the rig's limit `limit_n`.
    pub fn block_felt(&self, limit_n: f64) -> bool {
        self.block_felt_n.is_some_and(|(felt, contact)| felt >= 0.5 * contact.min(limit_n))
    }

    /// The punch and its farthest motion toward the fist while it came out, in words.
    pub fn toward_fist_description(&self) -> String {
        let p = &self.punch;
        let hand = ["left", "right"][p.hand];
        let mut s = format!(
            "{} {} {hand} at the {} at {:.2} s{}{}: {:.3} m",
            p.kind.name(),
            if p.feint { "feint" } else { "punch" },
            p.aim.name(),
            p.start_s,
            if p.in_combo > 0 {
                format!(", number {} of a combination", p.in_combo + 1)
            } else {
                String::new()
            },
            format_args!(" ({:.1} m/s)", self.peak_m_per_s),
            self.toward_fist_out_m
        );
        if let Some(t) = self.toward_fist_out_at {
            s += &format!(
                " by the {} {:.3} s after the start (of {:.3} out), body {}, hands {}/{}",
                t.part, t.at_s, p.out_s, t.body, t.hands[0], t.hands[1]
            );
        }
        s
    }

    /// A block met the fist while it was still on its way out.
    pub fn blocked_on_the_way_out(&self) -> bool {
        self.block_felt_n.is_some() && self.block_at_s <= self.punch.out_s
    }

    /// Landed on the part it was aimed at (the head or the chest, or either for other aims).
    pub fn landed(&self) -> bool {
        match self.punch.aim {
            Aim::Head => self.head,
            Aim::Chest | Aim::LeftChest | Aim::RightChest => self.chest,
            _ => self.head || self.chest,
        }
    }
}

/// A whole bout's punches and what it counted on the way.
#[derive(serde::Serialize)]
pub struct BoutOutcome {
    pub active: bool,
    pub punches: Vec<PunchOutcome>,
    /// World steps with an attack under way while a defence was.
    pub attack_during_defence_steps: u64,
    pub steps: u64,
    pub status: String,
    pub passivity_limited: [u64; 2],
    pub clamped: [u64; 2],
    /// The virtual human's level of skill.
    pub skill: &'static str,
    /// Its attacks: all started, those that were counters, those given up because a prediction
    /// found them blocked; and when each started (s, scripts' clock).
    pub attacks: u64,
    pub counters: u64,
    pub abandoned: u64,
    pub attack_starts_s: Vec<f64>,
}

/// The state of the virtual human and the avatar after one world step.
#[derive(Clone, Copy, Debug)]
struct Frame {
    t_s: f64,
    body: BodyBehaviour,
    motion: &'static str,
    hands: [Behaviour; 2],
    vh: [DVec3; 4],
    fist: [DVec3; 2],
    head: [bool; 2],
    chest: [bool; 2],
    blocked: [bool; 2],
    /// Per hand: the contact force of the previous step's model, and the force the user's hand
    /// felt on the first tick that rendered it.
    contact_n: [DVec3; 2],
    felt_n: [f64; 2],
    /// Per hand: the highest speed of the ticks since the previous step.
    speed: [f64; 2],
}

/// Runs `plan` through a [`Bout`] against a virtual human with `params` and reports every punch.
pub fn punch_outcomes(params: BoxerParams, plan: &BoxPlan, seed: u64) -> anyhow::Result<BoutOutcome> {
    punch_outcomes_with(params, plan, seed, &mut |_| {})
}

/// [`punch_outcomes`], calling `progress` with the number of punches over (first with 0), so a
/// caller can show progress or stop between punches.
fn punch_outcomes_with(
    params: BoxerParams,
    plan: &BoxPlan,
    seed: u64,
    progress: &mut dyn FnMut(usize),
) -> anyhow::Result<BoutOutcome> {
    let active = params.active;
    let mut ends: Vec<f64> = plan.punches.iter().map(|p| p.end_s()).collect();
    ends.sort_by(f64::total_cmp);
    let mut over = 0;
    progress(over);
    let mut b = Bout::seeing(params, plan, seed)?;
    let end_s = plan.punches.iter().map(|p| p.end_s()).fold(0.0, f64::max) + 0.5;
    let mut frames: Vec<Frame> = Vec::with_capacity((end_s / 0.003) as usize + 16);
    let mut bad = 0;
    let mut attack_starts_s = Vec::new();
    let mut was_attacking = false;
    let mut prev_contact = [DVec3::ZERO; 2];
    let mut prev_seq = 0;
    while b.script_t_s() < end_s {
        if !b.tick().1 {
            continue;
        }
        if ends.get(over).is_some_and(|&e| e <= b.script_t_s()) {
            while ends.get(over).is_some_and(|&e| e <= b.script_t_s()) {
                over += 1;
            }
            progress(over);
        }
        let w = &b.scene.world;
        let m = &w.mind;
        let defending = m.body == BodyBehaviour::Avoidance || m.hands.contains(&Behaviour::Block);
        if defending && m.hands.contains(&Behaviour::Attack) {
            bad += 1;
        }
        let attacking = m.hands.contains(&Behaviour::Attack);
        if attacking && !was_attacking {
            attack_starts_s.push(b.script_t_s());
        }
        was_attacking = attacking;
        let r = &w.last;
        // The force felt on the first tick that rendered the previous step's model.
        let first = b.consumed.iter().find(|s| s.model_seq == prev_seq);
        let felt = [0, 1].map(|h| first.map_or(0.0, |s| s.hands[h].force_n.length()));
        let speed = [0, 1]
            .map(|h| b.consumed.iter().map(|s| s.hands[h].vel_world_m_per_s.length()).fold(0.0, f64::max));
        let vh = w.vh;
        frames.push(Frame {
            t_s: b.script_t_s(),
            body: m.body,
            motion: body_motion(m),
            hands: m.hands,
            vh: [w.com(vh.head), w.com(vh.chest), w.com(vh.hand[0]), w.com(vh.hand[1])],
            fist: [w.com(w.avatar.hand[0]), w.com(w.avatar.hand[1])],
            head: r.head_hit,
            chest: r.chest_hit,
            blocked: r.blocked,
            contact_n: prev_contact,
            felt_n: felt,
            speed,
        });
        prev_contact = [r.hand_contacts[0].force_n, r.hand_contacts[1].force_n];
        prev_seq = b.scene.seq();
    }
    let guard = frames.first().map_or([DVec3::ZERO; 4], |f| f.vh);
    let punches = plan.punches.iter().map(|p| outcome(p, &frames, &guard)).collect();
    let c = b.v.counters();
    let m = &b.scene.world.mind;
    let (skill, attacks, counters, abandoned) =
        (m.skill().level.name(), m.attacks, m.counters, m.attacks_abandoned);
    Ok(BoutOutcome {
        skill,
        attacks,
        counters,
        abandoned,
        attack_starts_s,
        active,
        punches,
        attack_during_defence_steps: bad,
        steps: frames.len() as u64,
        status: b.scene.status_text(),
        passivity_limited: c.passivity_limited,
        clamped: c.clamped,
    })
}

fn outcome(p: &Punch, frames: &[Frame], guard: &[DVec3; 4]) -> PunchOutcome {
    let h = p.hand;
    let (t0, t1) = (p.start_s, p.end_s() + WINDOW_TAIL_S);
    let i0 = frames.partition_point(|f| f.t_s < t0);
    let i1 = frames.partition_point(|f| f.t_s < t1);
    let win = &frames[i0.min(frames.len())..i1.min(frames.len())];
    let mut o = PunchOutcome {
        punch: *p,
        peak_m_per_s: 0.0,
        head: false,
        chest: false,
        blocked: false,
        avoidance: false,
        block: false,
        from_rest: false,
        reaction_s: None,
        reacted_before_contact: false,
        toward_fist_m: 0.0,
        toward_fist_out_m: 0.0,
        toward_fist_out_at: None,
        block_felt_n: None,
        block_at_s: 0.0,
        landed_after_block: false,
        part_off_m: 0.0,
    };
    let Some(first) = win.first() else { return o };
    let part = usize::from(p.aim != Aim::Head);
    o.part_off_m = (first.vh[part] - guard[part]).length();
    o.from_rest = first.body == BodyBehaviour::Standby && first.hands == [Behaviour::Standby; 2];
    let start = first.vh;
    let mut reference = [start[0], start[1]];
    let mut touched = false;
    let mut responding = false;
    for (k, f) in win.iter().enumerate() {
        o.peak_m_per_s = o.peak_m_per_s.max(f.speed[h]);
        let contact = f.head[h] || f.chest[h] || f.blocked[h];
        // A reaction is the response's motion: counted once a defence is under way (a motion
        // before it, its own attack or a way back to its guard, is not a reaction to this punch).
        responding |= f.body == BodyBehaviour::Avoidance || f.hands.contains(&Behaviour::Block);
        if responding && o.reaction_s.is_none() && (0..4).any(|i| (f.vh[i] - start[i]).length() > SEEN_M) {
            o.reaction_s = Some(f.t_s - t0);
            o.reacted_before_contact = !touched && !contact;
        }
        touched |= contact;
        o.head |= f.head[h];
        o.chest |= f.chest[h];
        o.avoidance |= f.body == BodyBehaviour::Avoidance && first.body != BodyBehaviour::Avoidance;
        o.block |= f.hands.contains(&Behaviour::Block) && !first.hands.contains(&Behaviour::Block);
        if f.blocked[h] && !o.blocked {
            o.blocked = true;
            o.block_at_s = f.t_s - t0;
            // The model of this step reaches the loop for the ticks the next step consumes.
            if let Some(next) = win.get(k + 1) {
                o.block_felt_n = Some((next.felt_n[h], next.contact_n[h].length()));
            }
        } else if o.blocked && (f.head[h] || f.chest[h]) {
            o.landed_after_block = true;
        }
        // Head and chest toward the fist: their motion since the punch started, along the
        // direction from where they are now to where the fist is now. Its own attack leans the
        // trunk into the punch it throws: that is not a reaction, so attacks are left out (the
        // motion counts from where the part was when the attack ended).
        if f.hands.contains(&Behaviour::Attack) {
            reference = [f.vh[0], f.vh[1]];
            continue;
        }
        for (i, r) in reference.iter().enumerate() {
            let to_fist = (f.fist[h] - f.vh[i]).normalize_or_zero();
            let toward = (f.vh[i] - *r).dot(to_fist);
            o.toward_fist_m = o.toward_fist_m.max(toward);
            if f.t_s <= p.start_s + p.out_s && toward > o.toward_fist_out_m {
                o.toward_fist_out_m = toward;
                o.toward_fist_out_at = Some(TowardFist {
                    part: ["head", "chest"][i],
                    at_s: f.t_s - t0,
                    body: f.motion,
                    hands: f.hands.map(behaviour_name),
                });
            }
        }
    }
    o
}

/// Speed bins of the report (m/s): the user's hand's peak speed as the rig measured it (the
/// simulated arm follows the script's path with some lag, so it is not the planned speed).
pub const SPEED_BINS: [(f64, f64); 3] = [(0.0, 3.5), (3.5, 5.0), (5.0, f64::INFINITY)];

/// The speed bin of a punch.
pub fn speed_bin(o: &PunchOutcome) -> (f64, f64) {
    SPEED_BINS
        .into_iter()
        .find(|&(lo, hi)| o.peak_m_per_s >= lo && o.peak_m_per_s < hi)
        .unwrap_or(SPEED_BINS[0])
}

/// Rates over a set of punches.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rates {
    pub n: usize,
    pub head: f64,
    pub chest: f64,
    pub landed: f64,
    pub blocked: f64,
    pub avoidance: f64,
    pub peak_m_per_s: f64,
}

impl Rates {
    pub fn of<'a>(it: impl Iterator<Item = &'a PunchOutcome>) -> Rates {
        let mut r = Rates::default();
        for o in it {
            r.n += 1;
            r.head += o.head as u8 as f64;
            r.chest += o.chest as u8 as f64;
            r.landed += o.landed() as u8 as f64;
            r.blocked += o.blocked as u8 as f64;
            r.avoidance += o.avoidance as u8 as f64;
            r.peak_m_per_s += o.peak_m_per_s;
        }
        if r.n > 0 {
            let n = r.n as f64;
            for x in [
                &mut r.head,
                &mut r.chest,
                &mut r.landed,
                &mut r.blocked,
                &mut r.avoidance,
                &mut r.peak_m_per_s,
            ] {
                *x /= n;
            }
        }
        r
    }
}

impl BoutOutcome {
    /// Landed share of the punches (not feints) selected by `sel`, and how many there were.
    pub fn landed_of(&self, sel: impl Fn(&PunchOutcome) -> bool) -> (f64, usize) {
        let v: Vec<&PunchOutcome> = self.punches.iter().filter(|o| !o.punch.feint && sel(o)).collect();
        (v.iter().filter(|o| o.landed()).count() as f64 / v.len().max(1) as f64, v.len())
    }

    /// Punches (not feints) thrown within [`FEINT_PAIR_S`] after a feint ended its way out.
    pub fn after_feint(&self, o: &PunchOutcome) -> bool {
        !o.punch.feint
            && self.punches.iter().any(|f| {
                let out = f.punch.start_s + f.punch.out_s;
                f.punch.feint && f.punch.start_s < o.punch.start_s && o.punch.start_s - out <= FEINT_PAIR_S
            })
    }

    /// Feint pairs: the landed share of punches thrown within 0.5 s after a feint, and what the
    /// same punches (each paired with the punches of its kind and aim thrown with no feint
    /// before) landed without one; and how many there were.
    pub fn feint_pairs(&self) -> (f64, f64, usize) {
        let after: Vec<&PunchOutcome> = self.punches.iter().filter(|o| self.after_feint(o)).collect();
        let mut without = 0.0;
        for o in &after {
            let (rate, _) = self.landed_of(|x| {
                x.punch.kind == o.punch.kind && x.punch.aim == o.punch.aim && !self.after_feint(x)
            });
            without += rate;
        }
        let n = after.len();
        let with = after.iter().filter(|o| o.landed()).count() as f64 / n.max(1) as f64;
        (with, without / n.max(1) as f64, n)
    }

    /// Feint pairs against the same place in a combination: the punches thrown within 0.5 s
    /// after a feint, and the punches of the same kind, aim and place in a combination thrown
    /// after a real punch instead (no feint within 0.5 s before). The part a script aims at is
    /// often away from its guard in a combination (the body stepped back or slipped and holds
    /// there while fists are out), which the comparison with all punches mixes in.
    pub fn feint_pairs_same_place(&self) -> PairComparison {
        let after: Vec<&PunchOutcome> = self.punches.iter().filter(|o| self.after_feint(o)).collect();
        let like = |o: &PunchOutcome, x: &PunchOutcome| {
            !x.punch.feint
                && x.punch.in_combo == o.punch.in_combo
                && x.punch.kind == o.punch.kind
                && x.punch.aim == o.punch.aim
                && !self.after_feint(x)
        };
        let without: Vec<&PunchOutcome> =
            self.punches.iter().filter(|x| after.iter().any(|o| like(o, x))).collect();
        PairComparison::of(&after, &without)
    }

    /// Landed share of the punches (not feints) by how far the part aimed at was from its place
    /// when they started: under 5 cm, 5-10 cm, over 10 cm (share, number).
    pub fn landed_by_part_off(&self) -> [(f64, usize); 3] {
        [(0.0, 0.05), (0.05, 0.10), (0.10, f64::INFINITY)]
            .map(|(lo, hi)| self.landed_of(|o| o.part_off_m >= lo && o.part_off_m < hi))
    }

    /// Blocks that met a fist, and how many of them a counter followed within 1 s.
    pub fn counters_after_blocks(&self) -> (usize, usize) {
        let blocks: Vec<f64> = self
            .punches
            .iter()
            .filter(|o| o.blocked && !o.landed())
            .map(|o| o.punch.start_s + o.block_at_s)
            .collect();
        let countered =
            blocks.iter().filter(|&&t| self.attack_starts_s.iter().any(|&a| a > t && a <= t + 1.0)).count();
        (blocks.len(), countered)
    }

    /// Rates of the punches (not feints) aimed at `aim`.
    pub fn at(&self, aim: Aim) -> Rates {
        Rates::of(self.punches.iter().filter(|o| !o.punch.feint && o.punch.aim == aim))
    }

    pub fn feints(&self) -> Rates {
        Rates::of(self.punches.iter().filter(|o| o.punch.feint))
    }

    /// Median reaction time of punches thrown at a virtual human at rest (s).
    pub fn reaction_median_s(&self) -> Option<f64> {
        let mut v: Vec<f64> = self
            .punches
            .iter()
            .filter(|o| !o.punch.feint && o.from_rest)
            .filter_map(|o| o.reaction_s)
            .collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    }

    /// The farthest the head or chest moved toward a fist: over whole punches, and while the
    /// fists were on their way out.
    pub fn toward_fist_max_m(&self) -> (f64, f64) {
        let max = |f: fn(&PunchOutcome) -> f64| self.punches.iter().map(f).fold(0.0, f64::max);
        (max(|o| o.toward_fist_m), max(|o| o.toward_fist_out_m))
    }
}

/// Two sets of punches compared by their landed shares: the difference with a 95 % interval
/// (normal approximation of two independent proportions: rough at these counts).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PairComparison {
    pub with_landed: usize,
    pub with_n: usize,
    pub without_landed: usize,
    pub without_n: usize,
}

impl PairComparison {
    pub fn of(with: &[&PunchOutcome], without: &[&PunchOutcome]) -> PairComparison {
        let landed = |v: &[&PunchOutcome]| v.iter().filter(|o| o.landed()).count();
        PairComparison {
            with_landed: landed(with),
            with_n: with.len(),
            without_landed: landed(without),
            without_n: without.len(),
        }
    }

    /// The landed shares (with, without), their difference and its 95 % half-width.
    pub fn shares(&self) -> (f64, f64, f64, f64) {
        let p = |l: usize, n: usize| l as f64 / n.max(1) as f64;
        let (a, b) = (p(self.with_landed, self.with_n), p(self.without_landed, self.without_n));
        let var = a * (1.0 - a) / self.with_n.max(1) as f64 + b * (1.0 - b) / self.without_n.max(1) as f64;
        (a, b, a - b, 1.96 * var.sqrt())
    }
}

impl fmt::Display for PairComparison {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (a, b, d, hw) = self.shares();
        write!(
            f,
            "{:.1} % ({} of {}) vs {:.1} % ({} of {}): difference {:+.1} points, 95 % interval {:+.1} to {:+.1}",
            100.0 * a,
            self.with_landed,
            self.with_n,
            100.0 * b,
            self.without_landed,
            self.without_n,
            100.0 * d,
            100.0 * (d - hw),
            100.0 * (d + hw)
        )
    }
}

/// A punch thrown this soon after a feint's way out is a feint pair's (s).
pub const FEINT_PAIR_S: f64 = 0.5;

/// The box script of the punch experiment: every kind, head and chest, both hands, 2-7 m/s,
/// single and in combinations, a fifth feints.
pub fn punch_plan(punches: usize, seed: u64) -> anyhow::Result<BoxPlan> {
    let rig = Rig::default_rig();
    box_plan(&rig, &BoxerParams::default(), seed, &PlanOptions { punches, ..Default::default() })
}

/// The feint-pair script: punches thrown only in combinations of 2-3, this share of them feints,
/// so a punch follows a feint within [`FEINT_PAIR_S`] often enough to compare (the `box`
/// script's 400 punches hold only about 17 such pairs). Half as many punches as the main plan.
/// Its combinations go high-low (head then chest, or chest then head), as a boxer feints at one
/// level to hit the other, after a feint or a real punch alike, so the pairs compare the two.
pub fn feint_pair_plan(punches: usize, seed: u64) -> anyhow::Result<BoxPlan> {
    let rig = Rig::default_rig();
    let opts =
        PlanOptions { punches, combo_share: 1.0, feint_share: 0.3, high_low: true, ..Default::default() };
    box_plan(&rig, &BoxerParams::default(), seed ^ 0xfe17, &opts)
}

/// The punch experiment: the same plan against an active and a passive virtual human.
#[derive(serde::Serialize)]
pub struct PunchReport {
    pub active: BoutOutcome,
    pub passive: BoutOutcome,
    /// The same punches at the other levels of skill (novice, pro).
    pub other_skills: Vec<BoutOutcome>,
    /// The feint-pair script ([`feint_pair_plan`]) at the default skill.
    pub feint_pairs: BoutOutcome,
}

/// `progress(done, total)` is called as punches end (`total` counts each punch four times:
/// thrown at the active and the passive virtual human, at novice and at pro; and the feint-pair
/// script's punches once). The five bouts are independent and run on as many threads as the
/// machine has cores (each bout is deterministic; only the order of the progress calls varies).
pub fn punch_report(
    punches: usize,
    seed: u64,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<PunchReport> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let plan = punch_plan(punches, seed)?;
    let pairs_plan = feint_pair_plan(punches.div_ceil(2), seed)?;
    let n = plan.punches.len();
    let total = 4 * n + pairs_plan.punches.len();
    let jobs: Vec<(BoxerParams, &BoxPlan)> = vec![
        (BoxerParams::default(), &plan),
        (BoxerParams { active: false, ..Default::default() }, &plan),
        (BoxerParams::default().with_skill(SkillLevel::Novice), &plan),
        (BoxerParams::default().with_skill(SkillLevel::Pro), &plan),
        (BoxerParams::default(), &pairs_plan),
    ];
    // Punches over per bout, summed for the caller's progress from this thread.
    let over: Vec<AtomicUsize> = jobs.iter().map(|_| AtomicUsize::new(0)).collect();
    let results = std::thread::scope(|sc| {
        let bouts = sc.spawn(|| {
            jobs.par_iter()
                .zip(&over)
                .map(|((params, plan), over)| {
                    let params = BoxerParams { seed, ..params.clone() };
                    punch_outcomes_with(params, plan, seed, &mut |k| over.store(k, Ordering::Relaxed))
                })
                .collect::<Vec<_>>()
        });
        let mut last = usize::MAX;
        while !bouts.is_finished() {
            let done = over.iter().map(|o| o.load(Ordering::Relaxed)).sum();
            if done != last {
                progress(done, total);
                last = done;
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        bouts.join().expect("a punch bout panicked")
    });
    progress(total, total);
    let [active, passive, novice, pro, feint_pairs]: [BoutOutcome; 5] = results
        .into_iter()
        .collect::<anyhow::Result<Vec<_>>>()?
        .try_into()
        .map_err(|_| anyhow::anyhow!("five bouts"))?;
    Ok(PunchReport { active, passive, other_skills: vec![novice, pro], feint_pairs })
}

impl fmt::Display for PunchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (a, p) = (&self.active, &self.passive);
        let n_feints = a.punches.iter().filter(|o| o.punch.feint).count();
        writeln!(
            f,
            "punches (path: {PATH}): {} thrown, {} of them feints; landed on the part aimed at, active | passive",
            a.punches.len(),
            n_feints
        )?;
        writeln!(
            f,
            "  {:<10} {:<10} {:>5} {:>8} {:>15} {:>15}",
            "kind", "peak m/s", "n", "mean", "head", "chest"
        )?;
        for kind in PunchKind::ALL {
            for (lo, hi) in SPEED_BINS {
                let sel =
                    |o: &&PunchOutcome| !o.punch.feint && o.punch.kind == kind && speed_bin(o) == (lo, hi);
                let rate = |b: &BoutOutcome, aim: Aim| {
                    Rates::of(b.punches.iter().filter(sel).filter(|o| o.punch.aim == aim))
                };
                let (ah, ph, ac, pc) =
                    (rate(a, Aim::Head), rate(p, Aim::Head), rate(a, Aim::Chest), rate(p, Aim::Chest));
                writeln!(
                    f,
                    "  {:<10} {:<10} {:>5} {:>8.1} {:>6.2} | {:<6.2} {:>6.2} | {:<6.2}",
                    kind.name(),
                    match (lo, hi) {
                        (l, _) if l <= 0.0 => format!("< {hi:.1}"),
                        (_, h) if h.is_infinite() => format!(">= {lo:.1}"),
                        _ => format!("{lo:.1}-{hi:.1}"),
                    },
                    ah.n + ac.n,
                    (ah.peak_m_per_s * ah.n as f64 + ac.peak_m_per_s * ac.n as f64)
                        / (ah.n + ac.n).max(1) as f64,
                    ah.head,
                    ph.head,
                    ac.chest,
                    pc.chest
                )?;
            }
        }
        let (ah, ph, ac, pc) = (a.at(Aim::Head), p.at(Aim::Head), a.at(Aim::Chest), p.at(Aim::Chest));
        writeln!(
            f,
            "  all punches: head {:.2} | {:.2} ({} punches), chest {:.2} | {:.2} ({} punches)",
            ah.head, ph.head, ah.n, ac.chest, pc.chest, ac.n
        )?;
        let single = |b: &BoutOutcome, c: bool| {
            Rates::of(b.punches.iter().filter(|o| !o.punch.feint && (o.punch.in_combo > 0) == c))
        };
        writeln!(
            f,
            "  single punches landed {:.2} | {:.2}, in combinations {:.2} | {:.2}",
            single(a, false).landed,
            single(p, false).landed,
            single(a, true).landed,
            single(p, true).landed
        )?;
        let fe = a.feints();
        writeln!(f, "  feints: {} started an avoidance ({:.2}), active", fe.n, fe.avoidance)?;
        let react: Vec<f64> =
            a.punches.iter().filter(|o| !o.punch.feint && o.from_rest).filter_map(|o| o.reaction_s).collect();
        writeln!(
            f,
            "  reaction (first motion over 1 cm from the punch's start, punches at a virtual human at rest): median {} ({} punches)",
            a.reaction_median_s().map_or("-".into(), |s| format!("{s:.3} s")),
            react.len()
        )?;
        let ((aw, ao), (pw, po)) = (a.toward_fist_max_m(), p.toward_fist_max_m());
        let over = |b: &BoutOutcome| b.punches.iter().filter(|o| o.toward_fist_out_m > 0.02).count();
        let bound =
            if over(a) == 0 { "the issue's 2 cm bound holds" } else { "the issue's 2 cm bound is NOT met" };
        writeln!(
            f,
            "  head or chest toward the fist while it came out: at most {ao:.3} m, over 2 cm in {} of {} punches (active: {bound}); \
             at most {po:.3} m, over 2 cm in {} (passive); over the whole punch at most {aw:.3} / {pw:.3} m",
            over(a),
            a.punches.len(),
            over(p)
        )?;
        for o in a.punches.iter().filter(|o| o.toward_fist_out_m > 0.02) {
            writeln!(f, "    over 2 cm (active): {}", o.toward_fist_description())?;
        }
        let blocks: Vec<&PunchOutcome> = a.punches.iter().filter(|o| o.block_felt_n.is_some()).collect();
        let felt = blocks.iter().filter(|o| o.block_felt(4.0)).count();
        let through = blocks.iter().filter(|o| o.landed_after_block).count();
        let out = blocks.iter().filter(|o| o.blocked_on_the_way_out()).count();
        let out_felt = blocks.iter().filter(|o| o.blocked_on_the_way_out() && o.block_felt(4.0)).count();
        writeln!(
            f,
            "  blocks that met the fist: {} ({out} on its way out); felt on their first tick (at least half of the contact or of \
             4 N): {felt} ({out_felt} of those on the way out); the fist got through after: {through}",
            blocks.len(),
        )?;
        writeln!(f, "  landed on the part aimed at, {} (default) skill, active:", a.skill)?;
        writeln!(f, "    {:<10} {:>14} {:>14} {:>14}", "kind", "head", "chest", "both")?;
        for kind in PunchKind::ALL {
            let cell = |aim: Option<Aim>| {
                let (r, n) = a.landed_of(|o| o.punch.kind == kind && aim.is_none_or(|x| o.punch.aim == x));
                format!("{:>5.1} % ({n:>3})", 100.0 * r)
            };
            writeln!(
                f,
                "    {:<10} {:>14} {:>14} {:>14}",
                kind.name(),
                cell(Some(Aim::Head)),
                cell(Some(Aim::Chest)),
                cell(None)
            )?;
        }
        let (all, n_all) = a.landed_of(|_| true);
        writeln!(
            f,
            "    overall {:.1} % of {n_all} punches (professional boxers land about 20-40 %)",
            100.0 * all
        )?;
        let mut by_skill = vec![(a.skill, all)];
        by_skill.extend(self.other_skills.iter().map(|b| (b.skill, b.landed_of(|_| true).0)));
        by_skill.sort_by_key(|(name, _)| SkillLevel::parse(name).map_or(9, |l| l.index()));
        let rows: Vec<String> = by_skill.iter().map(|(s, r)| format!("{s} {:.1} %", 100.0 * r)).collect();
        let reactions: Vec<String> = std::iter::once(a)
            .chain(&self.other_skills)
            .map(|b| {
                format!("{} {}", b.skill, b.reaction_median_s().map_or("-".into(), |s| format!("{s:.3} s")))
            })
            .collect();
        writeln!(
            f,
            "  landed by skill: {}; reaction median by skill: {}",
            rows.join(", "),
            reactions.join(", ")
        )?;
        let (with, without, pairs) = a.feint_pairs();
        let feints: Vec<&PunchOutcome> = a.punches.iter().filter(|o| o.punch.feint).collect();
        let share = |pick: fn(&PunchOutcome) -> bool| {
            feints.iter().filter(|o| pick(o)).count() as f64 / feints.len().max(1) as f64
        };
        writeln!(
            f,
            "  feints: {} drew the start of a defence {:.2} (a block {:.2}, an avoidance {:.2}); punches within {FEINT_PAIR_S} s after a feint landed {:.1} %, the same punches without one {:.1} % ({pairs} pairs)",
            feints.len(),
            share(|o| o.block || o.avoidance),
            share(|o| o.block),
            share(|o| o.avoidance),
            100.0 * with,
            100.0 * without
        )?;
        let (with, without, pairs) = self.feint_pairs.feint_pairs();
        writeln!(
            f,
            "  feint pairs ({} punches in combinations of 2-3, {} of them feints, {} skill): punches within {FEINT_PAIR_S} s after a feint landed {:.1} %, the same punches without one {:.1} % ({pairs} pairs)",
            self.feint_pairs.punches.len(),
            self.feint_pairs.punches.iter().filter(|o| o.punch.feint).count(),
            self.feint_pairs.skill,
            100.0 * with,
            100.0 * without
        )?;
        writeln!(
            f,
            "    the same pairs against the same place in a combination after a real punch (kind, aim and place matched): after a feint {}",
            self.feint_pairs.feint_pairs_same_place()
        )?;
        let off = |b: &BoutOutcome| {
            let [n, m, far] = b.landed_by_part_off();
            format!(
                "under 5 cm {:.0} % ({}), 5-10 cm {:.0} % ({}), over 10 cm {:.0} % ({})",
                100.0 * n.0,
                n.1,
                100.0 * m.0,
                m.1,
                100.0 * far.0,
                far.1
            )
        };
        writeln!(
            f,
            "  landed by how far the part aimed at was from its place when the punch started (the user aims where it saw the part, 0.15 s before the punch): main script {}; feint-pair script {}",
            off(a),
            off(&self.feint_pairs)
        )?;
        let (blocked, countered) = a.counters_after_blocks();
        writeln!(
            f,
            "  its attacks: {} ({} counters, {} given up when a prediction found them blocked); blocked punches followed by its attack within 1 s: {countered} of {blocked} ({:.2})",
            a.attacks,
            a.counters,
            a.abandoned,
            countered as f64 / blocked.max(1) as f64
        )?;
        writeln!(
            f,
            "  steps with an attack under way during a defence: {} of {}",
            a.attack_during_defence_steps, a.steps
        )?;
        write!(
            f,
            "  rig: passivity-limited ticks {}/{}, clamped {}/{} (left/right, active bout)\n  virtual human: {}",
            a.passivity_limited[0], a.passivity_limited[1], a.clamped[0], a.clamped[1], a.status
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Section 4.3.

/// The four targets of Table IV, as the virtual human's parts.
pub const TARGETS: [&str; 4] = ["left hand", "right hand", "left chest", "right chest"];
const TARGET_AIMS: [Aim; 4] = [Aim::LeftHand, Aim::RightHand, Aim::LeftChest, Aim::RightChest];

/// Seconds after the punch's start at which the classifier samples the virtual human's motion.
const WATCH_AT_S: [f64; 5] = [0.15, 0.3, 0.45, 0.6, 0.75];
/// The clip a person sees runs this long after the punch starts (as the study's clips).
const CLIP_AFTER_S: f64 = 0.9;
/// A glove's seen motion is read as covering a chest side when it brings the glove nearer that
/// side (on the picture) by at least this share of the motion.
const COVER_SHARE: f64 = 0.5;

/// The bout of one Table IV trial on the product path: one straight at `target` (3-5 m/s, a
/// hand drawn from `seed`), the virtual human's own attacks off; with the punch it throws.
/// Shared by [`trial`] and `spidar study reactions`' clips.
pub fn trial_bout(active: bool, target: usize, seed: u64) -> anyhow::Result<(Bout, Punch)> {
    let rig = Rig::default_rig();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let params = BoxerParams { active, seed, ..Default::default() };
    let opts = PlanOptions {
        punches: 1,
        kinds: vec![PunchKind::Straight],
        aims: vec![TARGET_AIMS[target]],
        hands: vec![rng.random_range(0..2usize)],
        feint_share: 0.0,
        combo_share: 0.0,
        speed_m_per_s: (3.0, 5.0),
        pause_s: (0.5, 0.6),
        high_low: false,
        // From the avatar's own guard, as before the box script's user boxed from the chin
        // (docs/boxing.md 5.3 has both).
        guard: UserGuard::Home,
    };
    let plan = box_plan(&rig, &params, seed, &opts)?;
    let mut b = Bout::new(params, plan.scripts, seed)?;
    b.scene.world.mind.params.attack_per_step = 0.0;
    let p = plan.punches[0];
    Ok((b, p))
}

/// What one trial showed: the classifier's features, the a-priori observer's answer, and the
/// mind's counters (predictions, their total ns, avoidances, blocks).
struct Trial {
    features: Vec<f64>,
    seen: usize,
    counters: [u64; 4],
    /// The first defence of the clip, if any: (the blocking hand, the body moved too).
    defence: Option<(Option<usize>, bool)>,
}

/// The four parts of Table IV in the world now: the gloves and the two sides of the chest (the
/// points the script aims at, carried by the chest as it moves).
fn parts_now(b: &Bout, chest_sides: &[DVec3; 2]) -> [DVec3; 4] {
    let w = &b.scene.world;
    [
        w.com(w.vh.hand[0]),
        w.com(w.vh.hand[1]),
        w.ws.point_world(w.vh.chest, chest_sides[0]),
        w.ws.point_world(w.vh.chest, chest_sides[1]),
    ]
}

/// A chest side's point (the script's aim: 7 cm to the side, 3 cm down from the chest's centre)
/// in the chest's own frame. The virtual human faces +z; its left is +x.
fn chest_side_in_body(b: &Bout, side: f64) -> DVec3 {
    let w = &b.scene.world;
    let c = w.vh.chest;
    let o = w.ws.point_world(c, DVec3::ZERO);
    let axes = [DVec3::X, DVec3::Y, DVec3::Z].map(|a| w.ws.point_world(c, a) - o);
    let d = w.com(c) + DVec3::new(0.07 * side, -0.03, 0.0) - o;
    DVec3::new(axes[0].dot(d), axes[1].dot(d), axes[2].dot(d))
}

fn trial(active: bool, target: usize, seed: u64) -> anyhow::Result<Trial> {
    let (mut b, p) = trial_bout(active, target, seed)?;
    while b.script_t_s() < p.start_s {
        b.tick();
    }
    let vh = b.scene.world.vh;
    let watched = [vh.head, vh.chest, vh.hand[0], vh.hand[1], vh.forearm[0], vh.forearm[1]];
    let rest: Vec<DVec3> = watched.iter().map(|&x| b.scene.world.com(x)).collect();
    let sides = [chest_side_in_body(&b, 1.0), chest_side_in_body(&b, -1.0)];
    // The user's eye: the avatar's head, where the study page's camera is.
    let eye = b.scene.world.com(b.scene.world.avatar.head);
    let mut person = Person::new(eye, parts_now(&b, &sides));
    let mut features = Vec::with_capacity(WATCH_AT_S.len() * watched.len() * 3);
    let mut watch = WATCH_AT_S.iter().peekable();
    let mut defence = None;
    while b.script_t_s() < p.start_s + CLIP_AFTER_S {
        if b.tick().1 {
            person.watch(parts_now(&b, &sides));
            if defence.is_none() {
                defence = b.scene.world.mind.defence.map(|d| (d.blocking, d.avoiding));
            }
        }
        if watch.peek().is_some_and(|&&at| b.script_t_s() >= p.start_s + at) {
            watch.next();
            for (i, &x) in watched.iter().enumerate() {
                let d = b.scene.world.com(x) - rest[i];
                let d = if d.length() < SEEN_M { DVec3::ZERO } else { d };
                features.extend_from_slice(&d.to_array());
            }
        }
    }
    let m = &b.scene.world.mind;
    let guess = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0x9e37_79b9).random_range(0..4usize);
    Ok(Trial {
        features,
        seen: person.answer().unwrap_or(guess),
        counters: [m.predictions, m.predict_ns_total, m.avoidances, m.blocks],
        defence,
    })
}

/// The observer that stands for a person at the study page: sees one clip once, from the user's
/// eye, with no answer ever given to learn from, and reads it with what everyone knows of
/// blows and defences (docs/boxing.md, "Table IV"):
/// - it sees the four parts of the answers (the gloves, the chest's sides) move on the picture,
///   in perspective from the eye: motion along the line of sight (toward or away from the eye)
///   changes a part's size on the picture by a few per cent and is not counted; motion under
///   [`SEEN_M`] on the picture (at the body's distance) is not seen;
/// - its eye goes to the largest seen motion of the clip;
/// - a glove whose largest motion takes it over a side of the chest on the picture (nearer it by
///   at least [`COVER_SHARE`] of the motion) is covering that side: that side was attacked;
/// - any other motion is the attacked part itself: jolted by the blow or taken away from it;
/// - nothing seen: no answer (the caller guesses at random, as a person must).
struct Person {
    eye: DVec3,
    /// The parts' distance from the eye at rest: the picture's scale (m on the picture are m
    /// across the line of sight at the body).
    scale_m: f64,
    rest: [DVec3; 4],
    /// Per part: its largest seen motion and where every part was then.
    peak: [(f64, [DVec3; 4]); 4],
}

impl Person {
    fn new(eye: DVec3, rest: [DVec3; 4]) -> Person {
        let scale_m = rest.iter().map(|p| (*p - eye).length()).sum::<f64>() / 4.0;
        Person { eye, scale_m, rest, peak: [(0.0, rest); 4] }
    }

    /// Where `p` is on the picture: its direction from the eye (perspective), at the body's
    /// distance. Motion along the line of sight does not move a point on it.
    fn on_picture(&self, p: DVec3) -> DVec3 {
        (p - self.eye).normalize_or(DVec3::Z) * self.scale_m
    }

    /// Up on the picture at the body: the world's up, less its part along the line of sight.
    fn up_on_picture(&self) -> DVec3 {
        let centre = self.rest.iter().sum::<DVec3>() / 4.0;
        let sight = (centre - self.eye).normalize_or(DVec3::Z);
        (DVec3::Y - sight * sight.y).normalize_or(DVec3::Y)
    }

    fn watch(&mut self, now: [DVec3; 4]) {
        for i in 0..4 {
            let seen = (self.on_picture(now[i]) - self.on_picture(self.rest[i])).length();
            if seen > self.peak[i].0 {
                self.peak[i] = (seen, now);
            }
        }
    }

    /// The part read as attacked (an index of [`TARGETS`]), or `None` when nothing was seen.
    fn answer(&self) -> Option<usize> {
        let (i, &(seen, then)) = self.peak.iter().enumerate().max_by(|a, b| a.1 .0.total_cmp(&b.1 .0))?;
        if seen < SEEN_M {
            return None;
        }
        if i < 2 {
            let apart =
                |at: &[DVec3; 4], side: usize| (self.on_picture(at[side]) - self.on_picture(at[i])).length();
            // A glove dropped over the body: down more than across, to the chest sides' height
            // or lower. It covers the side it is nearer to.
            let up = self.up_on_picture();
            let moved = self.on_picture(then[i]) - self.on_picture(self.rest[i]);
            let down = -moved.dot(up);
            let across = (moved + up * down).length();
            let low =
                [2, 3].iter().all(|&s| (self.on_picture(then[i]) - self.on_picture(then[s])).dot(up) <= 0.0);
            if down > across && low {
                return Some(if apart(&then, 2) <= apart(&then, 3) { 2 } else { 3 });
            }
            // A glove brought nearer a side of the chest on the picture by most of its motion.
            let (side, gain) = [2, 3]
                .map(|s| (s, apart(&self.rest, s) - apart(&then, s)))
                .into_iter()
                .max_by(|a, b| a.1.total_cmp(&b.1))?;
            if gain >= COVER_SHARE * seen {
                return Some(side);
            }
        }
        Some(i)
    }
}

/// The experiment's result for one mode.
#[derive(serde::Serialize)]
pub struct Confusion {
    /// counts[target][answer]
    pub counts: [[usize; 4]; 4],
}

impl Confusion {
    pub fn rate(&self, target: usize, answer: usize) -> f64 {
        let n: usize = self.counts[target].iter().sum();
        if n == 0 {
            0.0
        } else {
            self.counts[target][answer] as f64 / n as f64
        }
    }

    pub fn total(&self) -> f64 {
        let n: usize = self.counts.iter().flatten().sum();
        let right: usize = (0..4).map(|i| self.counts[i][i]).sum();
        right as f64 / n.max(1) as f64
    }
}

/// Leave-one-out nearest centroid: each trial is guessed from the others' mean motions.
fn observe(samples: &[(usize, Vec<f64>)]) -> Confusion {
    let mut counts = [[0usize; 4]; 4];
    for (i, (truth, x)) in samples.iter().enumerate() {
        let mut best = (f64::INFINITY, 0);
        for c in 0..4 {
            let others: Vec<&Vec<f64>> = samples
                .iter()
                .enumerate()
                .filter(|(j, (t, _))| *j != i && *t == c)
                .map(|(_, (_, f))| f)
                .collect();
            if others.is_empty() {
                continue;
            }
            let d: f64 = (0..x.len())
                .map(|k| {
                    let mean = others.iter().map(|f| f[k]).sum::<f64>() / others.len() as f64;
                    (x[k] - mean).powi(2)
                })
                .sum();
            if d < best.0 {
                best = (d, c);
            }
        }
        counts[*truth][best.1] += 1;
    }
    Confusion { counts }
}

#[derive(serde::Serialize)]
pub struct Reactions {
    pub trials: usize,
    /// The a-priori observer's answers ([`Person`]: a person at the study page).
    pub active: Confusion,
    pub passive: Confusion,
    /// The leave-one-out classifier's, trained on each condition's own labelled trials.
    pub active_classifier: Confusion,
    pub passive_classifier: Confusion,
    pub prediction: Spread,
    pub avoidances: u64,
    pub blocks: u64,
    /// What the active virtual human did per target (its first defence of each clip):
    /// [target][no defence, blocked with its left hand, with its right hand, moved its body].
    pub defences: [[usize; 4]; 4],
}

/// Runs the section 4.3 experiment: `trials` straights per target, active and passive.
pub fn reactions(
    trials: usize,
    seed: u64,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<Reactions> {
    let total = 2 * 4 * trials;
    let mut done = 0;
    let mut preds = Vec::new();
    let (mut avoidances, mut blocks) = (0, 0);
    let mut defences = [[0usize; 4]; 4];
    let mut modes = Vec::new();
    for active in [true, false] {
        let mut samples = Vec::with_capacity(4 * trials);
        let mut seen = Confusion { counts: [[0; 4]; 4] };
        for (target, row) in defences.iter_mut().enumerate() {
            for n in 0..trials {
                let s = seed.wrapping_mul(1_000_003) ^ ((target * 100_000 + n) as u64);
                let t = trial(active, target, s)?;
                let [predictions, ns, avoid, block] = t.counters;
                if active && predictions > 0 {
                    preds.push(ns / predictions);
                    avoidances += avoid;
                    blocks += block;
                }
                if active {
                    match t.defence {
                        None => row[0] += 1,
                        Some((hand, moved)) => {
                            if let Some(h) = hand {
                                row[1 + h] += 1;
                            }
                            if moved {
                                row[3] += 1;
                            }
                        }
                    }
                }
                seen.counts[target][t.seen] += 1;
                samples.push((target, t.features));
                done += 1;
                progress(done, total);
            }
        }
        modes.push((seen, observe(&samples)));
    }
    let empty = || (Confusion { counts: [[0; 4]; 4] }, Confusion { counts: [[0; 4]; 4] });
    let (passive, passive_classifier) = modes.pop().unwrap_or_else(empty);
    let (active, active_classifier) = modes.pop().unwrap_or_else(empty);
    Ok(Reactions {
        trials,
        active,
        passive,
        active_classifier,
        passive_classifier,
        prediction: Spread::of(preds),
        avoidances,
        blocks,
        defences,
    })
}

/// Table IV of the paper, for printing next to ours: [active, passive][target][answer].
pub const PAPER: [[[f64; 4]; 4]; 2] = [
    [[0.88, 0.08, 0.08, 0.0], [0.20, 0.71, 0.0, 0.08], [0.08, 0.0, 0.79, 0.17], [0.0, 0.0, 0.13, 0.88]],
    [[0.63, 0.13, 0.25, 0.0], [0.42, 0.42, 0.08, 0.08], [0.25, 0.42, 0.17, 0.17], [0.13, 0.63, 0.13, 0.13]],
];

impl fmt::Display for Reactions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "reaction experiment: {} straights per target and mode", self.trials)?;
        writeln!(f, "  path: {PATH}")?;
        writeln!(
            f,
            "  observer: a person at the study page: each clip seen once from the user's eye, no answer given to learn from; \
             the gloves' and chest sides' motion across the line of sight (under 1 cm not seen); the largest motion read as \
             the part attacked, or, when it is a glove going to cover a side of the chest, as that side (docs/boxing.md)"
        )?;
        for (m, (name, c, paper_total)) in
            [("active", &self.active, 0.80), ("passive", &self.passive, 0.33)].into_iter().enumerate()
        {
            writeln!(f, "\n{name} reactions: observer's answer (ours | paper)")?;
            write!(f, "  {:<12}", "target")?;
            for a in TARGETS {
                write!(f, " {a:>17}")?;
            }
            writeln!(f)?;
            for t in 0..4 {
                write!(f, "  {:<12}", TARGETS[t])?;
                for (a, paper) in PAPER[m][t].iter().enumerate() {
                    write!(f, "      {:.2} | {:.2}", c.rate(t, a), paper)?;
                }
                writeln!(f)?;
            }
            writeln!(f, "  total correct rate {:.2} (paper {paper_total:.2})", c.total())?;
        }
        writeln!(
            f,
            "\nactive minus passive: {:+.2} (paper {:+.2}; the issue asks at least +0.25)",
            self.active.total() - self.passive.total(),
            0.80 - 0.33
        )?;
        writeln!(
            f,
            "a classifier trained on each condition's own labelled trials (leave-one-out nearest centroid over head, chest, \
             hand and forearm displacements at 0.15-0.75 s; it learns any consistent motion, which no participant can): \
             active {:.2}, passive {:.2}",
            self.active_classifier.total(),
            self.passive_classifier.total()
        )?;
        writeln!(f, "\nwhat the active virtual human did (its first defence per clip; a block and a body motion can be one defence)")?;
        writeln!(
            f,
            "  {:<12} {:>11} {:>17} {:>18} {:>11}",
            "target", "no defence", "left glove blocks", "right glove blocks", "body moved"
        )?;
        for (t, row) in self.defences.iter().enumerate() {
            writeln!(f, "  {:<12} {:>11} {:>17} {:>18} {:>11}", TARGETS[t], row[0], row[1], row[2], row[3])?;
        }
        write!(
            f,
            "\nactive trials: {} avoidances, {} blocks; prediction per trial {}",
            self.avoidances, self.blocks, self.prediction
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parts at rest as in the guard, seen from an eye 1.5 m in front (+z) at head height.
    fn person() -> Person {
        let rest = [
            DVec3::new(0.10, 1.30, 0.30),
            DVec3::new(-0.10, 1.30, 0.30),
            DVec3::new(0.07, 1.17, 0.05),
            DVec3::new(-0.07, 1.17, 0.05),
        ];
        Person::new(DVec3::new(0.0, 1.55, 1.6), rest)
    }

    fn moved(p: &Person, part: usize, d: DVec3) -> [DVec3; 4] {
        let mut at = p.rest;
        at[part] += d;
        at
    }

    #[test]
    fn the_person_reads_a_jolt_as_the_part_hit_and_a_covering_glove_as_the_side_covered() {
        // The left glove knocked aside (across the line of sight): the left glove.
        let mut p = person();
        p.watch(moved(&p, 0, DVec3::new(0.06, 0.02, 0.0)));
        assert_eq!(p.answer(), Some(0));
        // The right glove brought in front of the right side of the chest (onto the line of
        // sight to it, 20 cm before it): the right chest.
        let mut p = person();
        let sight = p.rest[3] - p.eye;
        let cover = p.rest[3] - sight * (0.20 / sight.z.abs());
        p.watch(moved(&p, 1, cover - p.rest[1]));
        assert_eq!(p.answer(), Some(3));
        // The chest's left side pushed aside more than anything else: the left chest.
        let mut p = person();
        p.watch(moved(&p, 2, DVec3::new(0.03, 0.0, 0.0)));
        assert_eq!(p.answer(), Some(2));
    }

    #[test]
    fn the_person_reads_a_glove_dropped_over_the_body_as_the_side_it_covers() {
        // The left glove dropped 16 cm on the picture, to below the chest sides: the left chest.
        let mut p = person();
        p.watch(moved(&p, 0, DVec3::new(-0.02, -0.16, 0.0)));
        assert_eq!(p.answer(), Some(2));
        // The right glove knocked up 5 cm (a punch at it): the right hand.
        let mut p = person();
        p.watch(moved(&p, 1, DVec3::new(0.0, 0.05, 0.0)));
        assert_eq!(p.answer(), Some(1));
    }

    /// Table IV on the product path, 4 straights per target and mode (seed 0): the passive body,
    /// only pushed, shows a glove hit right and names a hand for every chest attack; the active
    /// virtual human defends in most clips of every target.
    #[test]
    fn passive_motion_names_a_hand_for_chest_attacks_and_the_active_defends() {
        let r = reactions(4, 0, |_, _| {}).unwrap();
        let chest_read = |c: &Confusion| c.counts[2][2] + c.counts[3][3];
        assert_eq!(chest_read(&r.passive), 0, "passive chest attacks read as hands: {:?}", r.passive.counts);
        let hands_read = |c: &Confusion| c.counts[0][0] + c.counts[1][1];
        assert!(hands_read(&r.passive) >= 6, "passive: a glove hit is seen: {:?}", r.passive.counts);
        assert!(r.defences.iter().all(|row| row[0] <= 2), "the active defends: {:?}", r.defences);
    }

    /// Table IV on the eval's own seed and size (`spidar eval reactions --seed 0`, 24 straights per
    /// target and mode): the active reactions are read right at least 0.25 more often than the
    /// passive ones, as the issue asks (docs/boxing.md 5.3: +0.28 here; seeds 1-4 give +0.29,
    /// +0.28, +0.26, +0.22). Deterministic: the seed fixes every trial.
    #[test]
    fn active_reactions_are_read_right_a_quarter_more_often_than_passive_ones() {
        let r = reactions(24, 0, |_, _| {}).unwrap();
        let (a, p) = (r.active.total(), r.passive.total());
        assert!(a - p >= 0.25, "active {a:.2}, passive {p:.2}: {:?}", r.active.counts);
        // The hand attacks too, which the guard held firm made legible (0.46 and 0.38 before).
        let hands = (r.active.rate(0, 0) + r.active.rate(1, 1)) / 2.0;
        assert!(hands >= 0.7, "active hand attacks read right {hands:.2}: {:?}", r.active.counts);
    }

    #[test]
    fn the_person_misses_motion_along_the_line_of_sight_and_under_a_centimetre() {
        let mut p = person();
        // 8 cm straight away from the eye: the same point on the picture.
        let away = (p.rest[0] - p.eye).normalize() * 0.08;
        p.watch(moved(&p, 0, away));
        // 8 mm across it.
        p.watch(moved(&p, 1, DVec3::new(0.008, 0.0, 0.0)));
        assert_eq!(p.answer(), None, "nothing seen: the caller guesses");
        // The largest seen motion counts, not the largest motion.
        p.watch(moved(&p, 2, DVec3::new(0.0, 0.015, 0.0)));
        assert_eq!(p.answer(), Some(2));
    }
}
