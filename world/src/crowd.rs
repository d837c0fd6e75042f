//! The crowd scene (`spidar run --scene crowd`): keyframe characters of seed 002 walking about in
//! front of the user, who can push them with the SPIDAR-H hands.
//!
//! Every step it applies the impulses the rt-loop gave each proxy (the reaction of the force on the
//! hands, at the proxy surface point nearest the hand) to the character the proxy stands for,
//! steps the crowd to the loop time, and publishes the trunk capsules and heads of the characters
//! nearest the hands as proxies, so the hands feel the characters and the characters feel the hands
//! with the same momentum.
//!
//! Must never: apply an impulse computed against a contact model it no longer knows, or run more
//! than a few catch-up steps in one call (a stalled thread must not burst).

use spidar_sim::impulse::{centre, nearest_on_surface, touching_hand};
use std::path::Path;

use glam::DVec3;
use spidar_msg::{ContactModel, HandSample, Proxy, ProxyId, ProxyShape, MAX_PROXIES};
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::scene::{builtin_crowd, load_crowd};
use spidar_sim::collide::Shape;

use crate::Scene;

/// Penalty gains of the character proxies the hands render against (as the rig-check walls).
pub const PROXY_K_N_PER_M: f64 = 1500.0;
pub const PROXY_D_N_S_PER_M: f64 = 5.0;
/// Characters whose centre of mass is farther than this from every hand get no proxies (m).
pub const PROXY_RANGE_M: f64 = 1.2;
/// Contact models remembered, so late impulses still find the proxies they were computed on.
const KEEP_MODELS: usize = 8;
/// Most crowd steps one call runs to catch up with the loop clock.
const MAX_CATCH_UP: usize = 10;

pub struct CrowdScene {
    pub crowd: Crowd,
    name: String,
    seq: u64,
    sent: [ContactModel; KEEP_MODELS],
    t0_s: Option<f64>,
    hands: [Option<DVec3>; 2],
    /// Total impulse the hands gave the characters (N s), for the status line and tests.
    pub impulse_total_n_s: DVec3,
    /// Impulses dropped because their contact model was too old.
    pub impulses_unmatched: u64,
}

impl CrowdScene {
    pub fn new(crowd: Crowd, name: &str) -> CrowdScene {
        CrowdScene {
            crowd,
            name: name.to_string(),
            seq: 0,
            sent: [ContactModel::default(); KEEP_MODELS],
            t0_s: None,
            hands: [None; 2],
            impulse_total_n_s: DVec3::ZERO,
            impulses_unmatched: 0,
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
            self.hands[h] = hs.valid.then_some(hs.pos_m);
        }
        if s.model_seq == 0 || s.proxy_impulse_n_s.iter().all(|i| *i == DVec3::ZERO) {
            return;
        }
        let Some(m) = self.sent.iter().find(|m| m.seq == s.model_seq) else {
            self.impulses_unmatched += 1;
            return;
        };
        for (p, imp) in m.proxies().iter().zip(s.proxy_impulse_n_s.iter()) {
            let i = p.id.body as usize;
            if *imp == DVec3::ZERO || i >= self.crowd.len() {
                continue;
            }
            let at = touching_hand(&p.shape, s)
                .map_or_else(|| centre(&p.shape), |h| nearest_on_surface(&p.shape, s.hands[h].pos_m));
            self.crowd.add_impulse_at(i, at, *imp);
            self.impulse_total_n_s += *imp;
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
            n += 1;
        }
        if self.crowd.time_s + 0.5 * dt <= t_s - t0 {
            // Too far behind: drop the backlog rather than burst.
            self.t0_s = Some(t_s - self.crowd.time_s);
        }
        self.model(t_s)
    }

    fn status(&self) -> String {
        let fallen = self
            .crowd
            .chars
            .iter()
            .filter(|c| c.control.policy != spidar_sim::character::controller::Policy::Balance)
            .count();
        format!(
            "{} characters, {} down, pushed {:.1} N s",
            self.crowd.len(),
            fallen,
            self.impulse_total_n_s.length()
        )
    }

    fn look(&self) -> crate::look::Look {
        crate::looks::crowd::look(self)
    }

    fn pose(&self, out: &mut crate::look::Poses<'_>) {
        crate::looks::crowd::pose(self, out)
    }
}
