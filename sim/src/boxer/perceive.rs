//! What the virtual human sees of the avatar: a model of a person's vision between the world and
//! the cognitive model (seed 000 section 5's next step: "a model of visual attention and gaze").
//!
//! Every step the true state is written into a history. The mind reads the avatar from that
//! history, never from the world directly:
//!
//! - **Delay.** A fist is seen as it was `delay_s` ago (visual processing and the decision to
//!   move: people react to what they see in roughly 0.15-0.3 s).
//! - **Gaze and attention.** The head's eyes point along [`Perception::gaze_dir`], which turns at
//!   most `gaze_deg_per_s` toward the most threatening avatar fist (the one closing fastest on the
//!   head or chest; when none closes, the nearer one).
//! - **Attention dwells.** Once on a fist that threatened, attention stays with it until
//!   `attention_dwell_s` after that fist last threatened (a person cannot move attention at once
//!   from one thing to the next: the attentional dwell time); until then the other fist neither
//!   draws the gaze nor is seen with attention: even in the central field it is seen as the
//!   periphery sees it, later and less accurately. So a feint that drew the eyes leaves the other
//!   hand seen late while it comes.
//! - **Field of view.** A fist within `central_deg` of the gaze (the cone's full angle) is seen
//!   after `delay_s`; one in the periphery, within `fov_deg`, `periphery_delay_s` later and with
//!   `periphery_noise` times the error; one outside the field of view is not seen: the last
//!   sight of it is kept.
//! - **Acceleration.** The prediction extrapolates a fist with `accel_seen` of its seen
//!   acceleration (1: all of it, as the paper's model did), so a person's poor judgement of a
//!   brief motion's speeding up, slowing down and bending is part of what is seen.
//! - **Error.** Each prediction starts from the seen fist moved by a position error (`noise_m`
//!   per axis, standard deviation) and its speed scaled by a speed error (`speed_noise`, a Weber
//!   fraction), drawn from the mind's seeded generator: deterministic for a seed.
//!
//! The virtual human's own body is felt (proprioception), not seen: it is always the true state.
//!
//! Must never: allocate after construction (the history is sized for the longest delay), or let
//! the mind see a fist sooner than `delay_s` after it moved.

use glam::DVec3;
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::{HandTarget, Parts, AVATAR};
use crate::model::Model;
use crate::state::{State, Workspace};

/// A level of skill: how the virtual human perceives and decides (`skills` in the boxer file).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SkillLevel {
    Novice,
    Amateur,
    Pro,
}

impl SkillLevel {
    pub const ALL: [SkillLevel; 3] = [SkillLevel::Novice, SkillLevel::Amateur, SkillLevel::Pro];

    pub fn name(self) -> &'static str {
        match self {
            SkillLevel::Novice => "novice",
            SkillLevel::Amateur => "amateur",
            SkillLevel::Pro => "pro",
        }
    }

    /// The level named `name`; an error lists the levels there are.
    pub fn parse(name: &str) -> Result<SkillLevel, String> {
        SkillLevel::ALL.into_iter().find(|l| l.name() == name).ok_or_else(|| {
            format!("unknown skill level '{name}': use one of novice, amateur, pro (see configs/boxer.ron)")
        })
    }

    pub fn index(self) -> usize {
        self as usize
    }
}

impl std::fmt::Display for SkillLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One level's perception and decision parameters (`configs/boxer.ron` documents each).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Skill {
    pub level: SkillLevel,
    /// Perception: delay of the central field (s), the periphery's extra delay (s), the full
    /// angles of the central field and of the field of view (degrees), the gaze's turning speed
    /// (deg/s), the position error (m, per axis) and the speed error (fraction) in the central
    /// field, and how many times larger both are in the periphery.
    pub delay_s: f64,
    pub periphery_delay_s: f64,
    pub central_deg: f64,
    pub fov_deg: f64,
    pub gaze_deg_per_s: f64,
    pub noise_m: f64,
    pub speed_noise: f64,
    pub periphery_noise: f64,
    /// Decisions: the mean speed of a block (m/s); the chance that a defence that kept the fist
    /// off is followed by a counter, and how soon after it ends one may start (s); the chance that
    /// a predicted head contact is answered by moving the body as well as a block (Fig. 5).
    pub block_speed_m_per_s: f64,
    pub counter_chance: f64,
    pub counter_within_s: f64,
    pub avoid_chance: f64,
    /// After a defence ends, no new one starts for this long (s): the psychological refractory
    /// period, why a feint that drew a defence opens the guard for the punch that follows.
    pub refractory_s: f64,
    /// After a defence that the fist never met (a feint drew it, or the punch fell short or
    /// was slipped), no new one starts for this long instead (s): the guard is out of place and
    /// attention on the hand that drew it, so the punch that follows a feint is answered late.
    pub feint_recovery_s: f64,
    /// Attention stays with a fist this long after it last threatened (s): the other fist is
    /// seen without attention until then.
    pub attention_dwell_s: f64,
    /// How much of a fist's seen acceleration (its speeding up, slowing down and bending) the
    /// prediction uses, 0 to 1: people judge a briefly seen motion's acceleration poorly and
    /// extrapolate it mostly at its speed, so a feint's slowing is missed and a hook's bend seen
    /// late (docs/boxing.md section 4.1).
    pub accel_seen: f64,
}

impl Skill {
    /// The paper's virtual human (2006): it sees the true state at once, everywhere, exactly.
    /// For tests of the decision mechanics that should not depend on perception.
    pub fn perfect(level: SkillLevel, block_speed_m_per_s: f64) -> Skill {
        Skill {
            level,
            delay_s: 0.0,
            periphery_delay_s: 0.0,
            central_deg: 360.0,
            fov_deg: 360.0,
            gaze_deg_per_s: 1.0e6,
            noise_m: 0.0,
            speed_noise: 0.0,
            periphery_noise: 1.0,
            block_speed_m_per_s,
            counter_chance: 0.0,
            counter_within_s: 0.0,
            avoid_chance: 0.0,
            refractory_s: 0.0,
            feint_recovery_s: 0.0,
            attention_dwell_s: 0.0,
            accel_seen: 1.0,
        }
    }

    /// The longest a fist can be seen late (s).
    pub fn longest_delay_s(&self) -> f64 {
        self.delay_s + self.periphery_delay_s
    }
}

/// How one avatar fist is seen now.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Seen {
    /// Where the fist's centre was seen and how fast it moved (world), and the user's hand that
    /// pulled it then (the coupling's target), as of `age_s` ago.
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
    pub target: Option<HandTarget>,
    pub age_s: f64,
    /// Angle between the gaze and the fist now (degrees).
    pub eccentricity_deg: f64,
    /// In the central field; in the field of view at all.
    pub central: bool,
    pub in_view: bool,
}

/// The vision model: the history of what there was to see, the gaze, and what is seen.
pub struct Perception {
    pub skill: Skill,
    dt_s: f64,
    /// Coordinates of the avatar in `State::q` and `State::v`.
    q_range: std::ops::Range<usize>,
    v_range: std::ops::Range<usize>,
    /// Ring buffers, `cap` entries: the avatar's q and v, the fists (pos, vel) and the targets.
    cap: usize,
    newest: usize,
    len: usize,
    hist_q: Vec<f64>,
    hist_v: Vec<f64>,
    hist_fist: Vec<[(DVec3, DVec3); 2]>,
    hist_target: Vec<[Option<HandTarget>; 2]>,
    /// Per fist: how many steps old the sight of it is (held while it is out of view).
    lag: [usize; 2],
    /// Per fist: 0 out of view, 1 in the periphery, 2 in the central field; steps since then.
    class: [u8; 2],
    since: [usize; 2],
    /// Where the eyes point (unit, world) and from where (the head's centre).
    pub gaze_dir: DVec3,
    pub eye_m: DVec3,
    /// The fist attention is on (0 or 1), if any threatens or did within the dwell.
    pub attended: Option<usize>,
    /// Steps attention still dwells on the attended fist, which no longer threatens.
    dwell_left: usize,
    pub seen: [Seen; 2],
    av: Parts,
    vh: Parts,
}

impl Perception {
    pub fn new(model: &Model, skill: Skill, vh: &Parts, av: &Parts) -> Perception {
        let bodies = model.articulations[AVATAR].bodies.clone();
        let q0 = bodies.clone().map(|b| model.bodies[b].q_at).min().unwrap_or(0);
        let q1 = bodies.clone().map(|b| model.bodies[b].q_at + model.bodies[b].nq()).max().unwrap_or(0);
        let v0 = bodies.clone().map(|b| model.bodies[b].v_at).min().unwrap_or(0);
        let v1 = bodies.map(|b| model.bodies[b].v_at + model.bodies[b].nv()).max().unwrap_or(0);
        let mut p = Perception {
            skill,
            dt_s: model.dt_s,
            q_range: q0..q1,
            v_range: v0..v1,
            cap: 0,
            newest: 0,
            len: 0,
            hist_q: Vec::new(),
            hist_v: Vec::new(),
            hist_fist: Vec::new(),
            hist_target: Vec::new(),
            lag: [0; 2],
            class: [2; 2],
            since: [usize::MAX / 2; 2],
            gaze_dir: DVec3::Z,
            eye_m: DVec3::ZERO,
            attended: None,
            dwell_left: 0,
            seen: [Seen::default(); 2],
            av: *av,
            vh: *vh,
        };
        p.set_skill(skill);
        p
    }

    /// Changes the skill; the history is resized (allocates: call between bouts, not in a step).
    pub fn set_skill(&mut self, skill: Skill) {
        self.skill = skill;
        // A sight held out of view may be up to a second old.
        let longest = skill.longest_delay_s().max(1.0);
        self.cap = (longest / self.dt_s).ceil() as usize + 2;
        let (nq, nv) = (self.q_range.len(), self.v_range.len());
        self.hist_q = vec![0.0; self.cap * nq];
        self.hist_v = vec![0.0; self.cap * nv];
        self.hist_fist = vec![[(DVec3::ZERO, DVec3::ZERO); 2]; self.cap];
        self.hist_target = vec![[None; 2]; self.cap];
        self.len = 0;
        self.newest = 0;
        self.lag = [0; 2];
        self.class = [2; 2];
        self.since = [usize::MAX / 2; 2];
        self.attended = None;
        self.dwell_left = 0;
    }

    /// Steps of the central field's delay.
    fn delay_steps(&self, central: bool) -> usize {
        let d = if central { self.skill.delay_s } else { self.skill.longest_delay_s() };
        (d / self.dt_s).round() as usize
    }

    /// The history entry `lag` steps old (clamped to the oldest kept).
    fn index(&self, lag: usize) -> usize {
        let lag = lag.min(self.len.saturating_sub(1));
        (self.newest + self.cap - lag) % self.cap
    }

    /// Records the world's present (`ws` holds the kinematics of `state`) and the user's hands,
    /// moves the gaze and decides what is seen of each fist.
    pub fn observe(
        &mut self,
        model: &Model,
        state: &State,
        ws: &Workspace,
        targets: &[Option<HandTarget>; 2],
    ) {
        self.newest = if self.len == 0 { 0 } else { (self.newest + 1) % self.cap };
        self.len = (self.len + 1).min(self.cap);
        let (nq, nv) = (self.q_range.len(), self.v_range.len());
        let i = self.newest;
        self.hist_q[i * nq..(i + 1) * nq].copy_from_slice(&state.q[self.q_range.clone()]);
        self.hist_v[i * nv..(i + 1) * nv].copy_from_slice(&state.v[self.v_range.clone()]);
        self.hist_fist[i] =
            self.av.hand.map(|h| (ws.com_world(model, h), ws.point_velocity(h, model.bodies[h].com_m)));
        self.hist_target[i] = *targets;
        self.eye_m = ws.com_world(model, self.vh.head);
        let chest = ws.com_world(model, self.vh.chest);
        // Attention: the fist seen closing fastest on the head or chest; the nearer if none closes.
        let mut best = (f64::NEG_INFINITY, None);
        let mut threat = [f64::NEG_INFINITY; 2];
        for h in 0..2 {
            let (p, v) = self.hist_fist[self.index(self.lag[h])][h];
            let closing = [self.eye_m, chest]
                .iter()
                .map(|&b| v.dot((b - p).normalize_or_zero()))
                .fold(f64::NEG_INFINITY, f64::max);
            let near = -(p - self.eye_m).length();
            threat[h] = if closing > 0.5 { 10.0 + closing } else { near };
            if threat[h] > best.0 {
                best = (threat[h], Some(h));
            }
        }
        // The eyes follow a fist seen closing; otherwise they rest on the avatar's upper chest,
        // between its head and chest, as a boxer's do. Attention stays with the fist it is on
        // while that one threatens and for the dwell after; only then may it move.
        let threatening = best.0 >= 10.0;
        let dwell = (self.skill.attention_dwell_s / self.dt_s).round() as usize;
        match self.attended {
            Some(h) if threat[h] >= 10.0 => self.dwell_left = dwell,
            Some(_) if self.dwell_left > 0 => self.dwell_left -= 1,
            _ => {
                self.attended = if threatening { best.1 } else { None };
                self.dwell_left = dwell;
            }
        }
        let look_at = match self.attended {
            Some(h) => self.hist_fist[self.index(self.lag[h])][h].0,
            None => (ws.com_world(model, self.av.head) + ws.com_world(model, self.av.chest)) * 0.5,
        };
        let want = (look_at - self.eye_m).normalize_or(self.gaze_dir);
        self.gaze_dir = turn_toward(self.gaze_dir, want, self.skill.gaze_deg_per_s.to_radians() * self.dt_s);
        // What is seen of each fist: where it is on the retina now decides how late.
        for h in 0..2 {
            let (now, _) = self.hist_fist[i][h];
            let ecc =
                self.gaze_dir.angle_between((now - self.eye_m).normalize_or(self.gaze_dir)).to_degrees();
            // Attention on the other fist: this one is seen as the periphery sees it.
            let central = ecc <= 0.5 * self.skill.central_deg && self.attended.is_none_or(|a| a == h);
            let in_view = ecc <= 0.5 * self.skill.fov_deg;
            // Sights since the fist came into its present part of the view are `want` late;
            // until the first of them arrives, the older sight goes on ageing (a periphery's sight
            // at most as late as the periphery's delay).
            let class = u8::from(in_view) + u8::from(central);
            if class != self.class[h] {
                self.class[h] = class;
                self.since[h] = 0;
            } else {
                self.since[h] = self.since[h].saturating_add(1);
            }
            let want = self.delay_steps(central);
            let was_seen = self.lag[h] < self.cap - 1;
            self.lag[h] = if in_view && self.since[h] >= want {
                want
            } else if in_view && was_seen {
                (self.lag[h] + 1).min(self.delay_steps(false).max(want))
            } else {
                (self.lag[h] + 1).min(self.cap - 1)
            };
            let k = self.index(self.lag[h]);
            let (pos, vel) = self.hist_fist[k][h];
            self.seen[h] = Seen {
                pos_m: pos,
                vel_m_per_s: vel,
                target: self.hist_target[k][h],
                age_s: self.lag[h].min(self.len - 1) as f64 * self.dt_s,
                eccentricity_deg: ecc,
                central,
                in_view,
            };
        }
    }

    /// The state the mind predicts from: the true state with the avatar as it was seen (the
    /// attended fist's sight, or the fresher of the two). Copies into `out` without allocating.
    pub fn perceived_state(&self, state: &State, out: &mut State) {
        out.copy_from(state);
        if self.len == 0 {
            return;
        }
        let lag = match self.attended {
            Some(h) => self.lag[h],
            None => self.lag[0].min(self.lag[1]),
        };
        let k = self.index(lag);
        let (nq, nv) = (self.q_range.len(), self.v_range.len());
        out.q[self.q_range.clone()].copy_from_slice(&self.hist_q[k * nq..(k + 1) * nq]);
        out.v[self.v_range.clone()].copy_from_slice(&self.hist_v[k * nv..(k + 1) * nv]);
    }

    /// The user's hands as seen, each moved by a fresh error from `rng` (deterministic for its
    /// seed): the prediction's start.
    pub fn perceived_targets(&self, rng: &mut Pcg64Mcg) -> [Option<HandTarget>; 2] {
        let s = self.skill;
        let mut out = [None; 2];
        for h in 0..2 {
            let seen = &self.seen[h];
            let Some(t) = seen.target else { continue };
            let f = if seen.central { 1.0 } else { s.periphery_noise };
            let off = DVec3::new(gauss(rng), gauss(rng), gauss(rng)) * (s.noise_m * f);
            let scale = (1.0 + gauss(rng) * s.speed_noise * f).max(0.0);
            out[h] = Some(HandTarget { pos_m: t.pos_m + off, vel_m_per_s: t.vel_m_per_s * scale });
        }
        out
    }

    /// The user's hands as seen (no error): for the mind's estimate of their acceleration.
    pub fn seen_targets(&self) -> [Option<HandTarget>; 2] {
        self.seen.map(|s| s.target)
    }
}

/// A unit vector turned from `from` toward `to` by at most `max_rad`.
fn turn_toward(from: DVec3, to: DVec3, max_rad: f64) -> DVec3 {
    let angle = from.angle_between(to);
    if !(angle > max_rad) {
        return to;
    }
    let axis = from.cross(to).normalize_or(DVec3::Y);
    glam::DQuat::from_axis_angle(axis, max_rad) * from
}

/// A standard normal draw (Box-Muller).
fn gauss(rng: &mut Pcg64Mcg) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gaze_turns_at_most_its_speed() {
        let d = turn_toward(DVec3::Z, DVec3::X, 0.1);
        assert!((d.angle_between(DVec3::Z) - 0.1).abs() < 1e-12);
        assert_eq!(
            turn_toward(DVec3::Z, DVec3::new(0.0, 0.01, 1.0).normalize(), 0.1),
            DVec3::new(0.0, 0.01, 1.0).normalize()
        );
    }

    #[test]
    fn skill_levels_parse_by_name_only() {
        assert_eq!(SkillLevel::parse("pro"), Ok(SkillLevel::Pro));
        let e = SkillLevel::parse("champion").unwrap_err();
        assert!(e.contains("champion") && e.contains("novice, amateur, pro"), "{e}");
    }
}
