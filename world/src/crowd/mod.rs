//! The crowd scene (`spidar run --scene crowd`): keyframe characters of seed 002 in front of the
//! user, a front row keeping their spots within reach of the hands and more wandering behind, whom
//! the user can push with the SPIDAR-H hands.
//!
//! Every step it applies the contacts of the hands with the characters (as the rt-loop rendered them
//! against the proxies it was sent, at the proxy surface point nearest the hand) to the character
//! each proxy stands for, steps the crowd to the loop time, and publishes the trunk capsules and
//! heads of the characters nearest the hands as proxies.
//!
//! Which impulse: the character receives the whole virtual contact (`proxy_contact_impulse_n_s`),
//! not only the part the rig could display (`proxy_impulse_n_s`, at most 4 N a hand on the
//! SPIDAR-H): a person pushing a 40 kg character pushes with their arm, and the rig shows them as
//! much of the contact's reaction as its motors can. With the displayed part alone no push could
//! ever topple a character (4 N for a second moves 40 kg by 0.1 m/s). Both are counted: `given`
//! (what the characters got) and `felt` (what the hands got). The boxing scene does the same for the
//! same reason, through its avatar's hands.
//!
//! Must never: apply an impulse computed against a contact model it no longer knows, or run more
//! than a few catch-up steps in one call (a stalled thread must not burst).

use spidar_sim::impulse::{centre, nearest_on_surface, touching_hand};
use std::path::Path;

use glam::DVec3;
use spidar_msg::{ContactModel, HandSample, Proxy, ProxyId, ProxyShape, MAX_PROXIES};
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::scene::{builtin_crowd, load_crowd};
use spidar_sim::collide::Shape;

use crate::Scene;

mod look;

/// Penalty gains of the character proxies the hands render against: the rig's stiffest contact
/// (the renderer softens anything stiffer to it), and the damping of a hand pressing into a body.
pub const PROXY_K_N_PER_M: f64 = 5000.0;
pub const PROXY_D_N_S_PER_M: f64 = 100.0;
/// Characters whose centre of mass is farther than this from every hand get no proxies (m).
pub const PROXY_RANGE_M: f64 = 1.2;
/// Contact models remembered, so late impulses still find the proxies they were computed on.
const KEEP_MODELS: usize = 8;
/// Most crowd steps one call runs to catch up with the loop clock.
const MAX_CATCH_UP: usize = 10;
/// A character touched again after this long without contact starts a new push (s).
const PUSH_GAP_S: f64 = 0.5;
/// Impulse below which a touch is not counted as a push (N s).
const PUSH_MIN_N_S: f64 = 0.5;

/// What happened to the characters so far (for the status line, the summary and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CrowdCounts {
    /// Pushes (contact episodes above [`PUSH_MIN_N_S`]) and distinct characters pushed.
    pub pushes: u64,
    pub characters_pushed: u64,
    /// Times a character started to fall, and stood up again.
    pub falls: u64,
    pub stand_ups: u64,
    /// The largest single push (N s).
    pub largest_push_n_s: f64,
}

pub struct CrowdScene {
    pub crowd: Crowd,
    name: String,
    seq: u64,
    sent: [ContactModel; KEEP_MODELS],
    t0_s: Option<f64>,
    hands: [Option<DVec3>; 2],
    /// Total impulse the hands' contacts gave the characters (N s), and the total the rig applied
    /// to the hands (N s): the second is the first as far as the rig could display it.
    pub impulse_total_n_s: DVec3,
    pub felt_total_n_s: DVec3,
    /// Sum of the magnitudes of the per-step impulses the characters got (N s).
    pub impulse_sum_n_s: f64,
    pub felt_sum_n_s: f64,
    /// Impulses dropped because their contact model was too old.
    pub impulses_unmatched: u64,
    pub counts: CrowdCounts,
    /// Per character: loop time of its last contact (s), the impulse of the push in progress
    /// (N s), whether it was ever pushed, and its policy at the last step.
    last_touch_s: Vec<f64>,
    push_n_s: Vec<f64>,
    pushed: Vec<bool>,
    policy: Vec<Policy>,
}

impl CrowdScene {
    pub fn new(crowd: Crowd, name: &str) -> CrowdScene {
        let n = crowd.len();
        let policy = crowd.chars.iter().map(|c| c.control.policy).collect();
        CrowdScene {
            crowd,
            name: name.to_string(),
            seq: 0,
            sent: [ContactModel::default(); KEEP_MODELS],
            t0_s: None,
            hands: [None; 2],
            impulse_total_n_s: DVec3::ZERO,
            felt_total_n_s: DVec3::ZERO,
            impulse_sum_n_s: 0.0,
            felt_sum_n_s: 0.0,
            impulses_unmatched: 0,
            counts: CrowdCounts::default(),
            last_touch_s: vec![f64::NEG_INFINITY; n],
            push_n_s: vec![0.0; n],
            pushed: vec![false; n],
            policy,
        }
    }

    pub fn builtin() -> anyhow::Result<CrowdScene> {
        Ok(CrowdScene::new(builtin_crowd()?, "crowd of keyframe characters"))
    }

    pub fn load(path: &Path) -> anyhow::Result<CrowdScene> {
        Ok(CrowdScene::new(load_crowd(path)?, &path.display().to_string()))
    }

    fn apply(&mut self, s: &HandSample) {
        for (h, hs) in s.hands.iter().enumerate() {
            self.hands[h] = hs.valid.then_some(hs.pos_world_m);
        }
        if s.model_seq == 0 || s.proxy_impulse_n_s.iter().all(|i| *i == DVec3::ZERO) {
            return;
        }
        let Some(m) = self.sent.iter().find(|m| m.seq == s.model_seq) else {
            self.impulses_unmatched += 1;
            return;
        };
        let m = *m;
        for ((p, imp), felt) in
            m.proxies().iter().zip(s.proxy_contact_impulse_n_s.iter()).zip(&s.proxy_impulse_n_s)
        {
            let i = p.id.body as usize;
            self.felt_total_n_s += *felt;
            self.felt_sum_n_s += felt.length();
            if *imp == DVec3::ZERO || i >= self.crowd.len() {
                continue;
            }
            let at = touching_hand(&p.shape, s)
                .map_or_else(|| centre(&p.shape), |h| nearest_on_surface(&p.shape, s.hands[h].pos_world_m));
            self.crowd.add_impulse_at(i, at, *imp);
            self.impulse_total_n_s += *imp;
            self.impulse_sum_n_s += imp.length();
            // A push: contact after a gap, counted once it has given enough.
            if s.t_s - self.last_touch_s[i] > PUSH_GAP_S {
                self.push_n_s[i] = 0.0;
            }
            let before = self.push_n_s[i];
            self.push_n_s[i] += imp.length();
            self.counts.largest_push_n_s = self.counts.largest_push_n_s.max(self.push_n_s[i]);
            if before < PUSH_MIN_N_S && self.push_n_s[i] >= PUSH_MIN_N_S {
                self.counts.pushes += 1;
                if !self.pushed[i] {
                    self.pushed[i] = true;
                    self.counts.characters_pushed += 1;
                }
            }
            self.last_touch_s[i] = s.t_s;
        }
    }

    /// Counts falls and stand-ups from the characters' policies after a step.
    fn count_policies(&mut self) {
        for (i, c) in self.crowd.chars.iter().enumerate() {
            let (was, now) = (self.policy[i], c.control.policy);
            if was == now {
                continue;
            }
            if was == Policy::Balance && now == Policy::Fall {
                self.counts.falls += 1;
            }
            if was == Policy::StandUp && now == Policy::Balance {
                self.counts.stand_ups += 1;
            }
            self.policy[i] = now;
        }
    }

    /// The contact model at loop time `t_s`: the characters nearest the hands.
    pub fn model(&mut self, t_s: f64) -> ContactModel {
        self.seq += 1;
        let mut m = ContactModel { seq: self.seq, stamp_s: t_s, ..Default::default() };
        let mut near: [(f64, usize); MAX_PROXIES] = [(f64::INFINITY, 0); MAX_PROXIES];
        let mut count = 0;
        for i in 0..self.crowd.len() {
            let c = self.crowd.bodies[i].pos_m;
            let d = self.hands.iter().flatten().map(|h| (*h - c).length()).fold(f64::INFINITY, f64::min);
            if d > PROXY_RANGE_M {
                continue;
            }
            // Keep the nearest few (insertion into a short sorted list).
            let mut at = count.min(MAX_PROXIES);
            while at > 0 && near[at - 1].0 > d {
                if at < MAX_PROXIES {
                    near[at] = near[at - 1];
                }
                at -= 1;
            }
            if at < MAX_PROXIES {
                near[at] = (d, i);
                count = (count + 1).min(MAX_PROXIES);
            }
        }
        'chars: for &(_, i) in &near[..count] {
            for k in 0..self.crowd.body.shapes.len() {
                let (shape, pose) = self.crowd.shape_world(i, k);
                let ps = match shape {
                    Shape::Sphere { radius_m } => ProxyShape::Sphere { centre_m: pose.pos_m, radius_m },
                    Shape::Capsule { half_length_m, radius_m } => {
                        let a = pose.rot.y_axis * half_length_m;
                        ProxyShape::Capsule { a_m: pose.pos_m - a, b_m: pose.pos_m + a, radius_m }
                    }
                    // The feet are out of the hands' reach; boxes have no proxy shape.
                    Shape::Box { .. } | Shape::Plane => continue,
                };
                let p = Proxy {
                    id: ProxyId { body: i as u16, part: k as u16 },
                    shape: ps,
                    k_n_per_m: PROXY_K_N_PER_M,
                    d_n_s_per_m: PROXY_D_N_S_PER_M,
                    vel_m_per_s: self.crowd.point_velocity(i, pose.pos_m),
                    hand_mask: Proxy::BOTH_HANDS,
                };
                if !m.push(p) {
                    break 'chars;
                }
            }
        }
        self.sent[(self.seq as usize) % KEEP_MODELS] = m;
        m
    }
}

impl Scene for CrowdScene {
    fn name(&self) -> &str {
        &self.name
    }

    fn step_s(&self) -> f64 {
        self.crowd.world.dt_s
    }

    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        for s in samples {
            self.apply(s);
        }
        let t0 = *self.t0_s.get_or_insert(t_s);
        let dt = self.crowd.world.dt_s;
        let mut n = 0;
        while self.crowd.time_s + 0.5 * dt <= t_s - t0 && n < MAX_CATCH_UP {
            self.crowd.step();
            self.count_policies();
            n += 1;
        }
        if self.crowd.time_s + 0.5 * dt <= t_s - t0 {
            // Too far behind: drop the backlog rather than burst.
            self.t0_s = Some(t_s - self.crowd.time_s);
        }
        self.model(t_s)
    }

    fn status(&self) -> String {
        let fallen = self.crowd.chars.iter().filter(|c| c.control.policy != Policy::Balance).count();
        let c = &self.counts;
        format!(
            "{} characters, {} down | {} pushes on {} characters (largest {:.1} N s), given {:.1} N s, felt {:.1} N s | {} falls, {} stood up",
            self.crowd.len(),
            fallen,
            c.pushes,
            c.characters_pushed,
            c.largest_push_n_s,
            self.impulse_sum_n_s,
            self.felt_sum_n_s,
            c.falls,
            c.stand_ups
        )
    }

    fn look(&self) -> crate::look::Look {
        look::look(self)
    }

    fn pose(&self, out: &mut crate::look::Poses<'_>) {
        look::pose(self, out)
    }

    fn figure_states(&self, out: &mut [spidar_sim::character::drawn::FigureState]) {
        spidar_sim::character::drawn::figure_states(&self.crowd, out)
    }
}
