//! The boxing scene (seed 000): the physics world of `spidar_sim::boxer` behind the rt-loop.
//!
//! Every 3 ms step: the user's hands (newest sample, world frame of the rt-loop) plus the boxer's
//! `user_offset_m` become the avatar's hand targets; the impulses of the virtual contacts the
//! rt-loop rendered against the proxies of the last models (`proxy_contact_impulse_n_s`: the
//! full penalty force, not limited by the rig's force clamp) are given to the virtual human's
//! parts they name, and their reaction to the avatar's hands; the world steps (the virtual human
//! thinks and reaches); and
//! the scene publishes proxies of the virtual human's parts near the user's hands, in the
//! rt-loop's frame, with the avatar's damage (contacts on its other parts, attenuated) as the
//! extra force on both hands.
//!
//! Must never: send the coupling spring to the user, or publish a proxy without the id of the body
//! it stands for (the impulse would be lost).

use glam::DVec3;
use spidar_msg::{ContactModel, HandSample, Proxy, HANDS};
use spidar_sim::boxer::{proxy_shape, BoxerParams, BoxingWorld, HandTarget, BOXER};
use spidar_sim::impulse::{body_of, dist, nearest_on_surface, proxy_id, touching_hand};

use crate::Scene;

/// Contact models kept to match the impulses of late samples (a sample names its model's seq).
const KEPT_MODELS: usize = 8;

pub struct BoxingScene {
    pub world: BoxingWorld,
    seq: u64,
    sent: [ContactModel; KEPT_MODELS],
    targets: [Option<HandTarget>; HANDS],
    /// Newest user hand positions (rt-loop frame), for attributing impulses to hands.
    user_hands: [Option<DVec3>; HANDS],
    /// Wall time of each world step (ns), the newest last; read by `spidar eval` and the status.
    pub last_step_ns: u64,
}

impl BoxingScene {
    pub fn new(params: BoxerParams) -> anyhow::Result<BoxingScene> {
        let world = BoxingWorld::new(params)?;
        Ok(BoxingScene {
            world,
            seq: 0,
            sent: [ContactModel::default(); KEPT_MODELS],
            targets: [None; HANDS],
            user_hands: [None; HANDS],
            last_step_ns: 0,
        })
    }

    /// Applies the virtual contact impulses of one sample to the world.
    ///
    /// The contact is between the avatar's hand and the virtual human, both simulated (seed 000,
    /// section 3.4): the virtual human receives the whole contact, as rendered at 1 kHz with the
    /// loop's ramp and stale-model fade, so a punch moves it as hard as it lands in the world.
    /// The user's hand feels the same contact only up to the rig's force limit; the difference is
    /// carried by the avatar's hand (it gets the reaction) and its coupling spring, not lost. The
    /// applied impulse (`proxy_impulse_n_s`, at most 4 N worth) would make every punch a push.
    fn take_impulses(&mut self, s: &HandSample) {
        if s.model_seq == 0 {
            return;
        }
        let Some(m) = self.sent.iter().find(|m| m.seq == s.model_seq) else { return };
        let m = *m;
        let off = self.world.params.user_offset_m;
        for (p, imp) in m.proxies().iter().zip(s.proxy_contact_impulse_n_s.iter()) {
            if *imp == DVec3::ZERO {
                continue;
            }
            let Some(body) = body_of(&self.world.model, p.id) else { continue };
            // The hand that touched it: the valid one nearer the proxy's surface.
            let Some(hand) = touching_hand(&p.shape, s) else { continue };
            let point = nearest_on_surface(&p.shape, s.hands[hand].pos_m) + off;
            self.world.apply_user_impulse(hand, body, point, *imp);
        }
    }

    /// The proxies of the virtual human's parts near the user's hands, in the rt-loop's frame.
    fn model_at(&mut self, t_s: f64) -> ContactModel {
        self.seq += 1;
        let w = &self.world;
        let p = &w.params;
        let mut cm = ContactModel { seq: self.seq, stamp_s: t_s, ..Default::default() };
        for (k, s) in w.model.shapes.iter().enumerate() {
            let Some(body) = s.body else { continue };
            if w.model.bodies[body].articulation != BOXER {
                continue;
            }
            let pose = w.ws.shape_pose[k];
            let Some(shape) = proxy_shape(&s.shape, pose.pos_m - p.user_offset_m, pose.rot) else { continue };
            let near = self.user_hands.iter().flatten().any(|&h| dist(&shape, h) < p.proxy_range_m);
            if !near {
                continue;
            }
            let com_b = w.model.bodies[body].com_m;
            let vel = w.ws.point_velocity(body, com_b)
                + w.ws.angular_velocity(body).cross(pose.pos_m - w.ws.point_world(body, com_b));
            let ok = cm.push(Proxy {
                id: proxy_id(&w.model, body),
                shape,
                k_n_per_m: p.proxy_k_n_per_m,
                d_n_s_per_m: p.proxy_d_n_s_per_m,
                vel_m_per_s: vel,
                hand_mask: Proxy::BOTH_HANDS,
            });
            if !ok {
                break;
            }
        }
        let damage = w.last.damage_force_n * p.damage_attenuation;
        cm.extra_force_n = [damage; HANDS];
        self.sent[(self.seq as usize) % KEPT_MODELS] = cm;
        cm
    }

    /// The virtual human's behaviours, reaches, latest prediction and counters.
    pub fn decisions(&self) -> crate::decisions::Decisions {
        use crate::decisions::{Decisions, Prediction, ReachTarget};
        use spidar_sim::boxer::{Behaviour, BodyBehaviour, ContactClass};
        let m = &self.world.mind;
        let hand = |b: Behaviour| match b {
            Behaviour::Standby => 0,
            Behaviour::Attack => 1,
            Behaviour::Block => 2,
        };
        let mut reaches = [ReachTarget::default(); 3];
        for (out, r) in reaches.iter_mut().zip(m.reaches.iter()) {
            if let Some(r) = r {
                *out = ReachTarget {
                    active: true,
                    body: r.body as u16,
                    target_m: r.target_m,
                    start_s: r.start_s,
                    duration_s: r.duration_s,
                };
            }
        }
        let prediction = m.last_decision.map_or(Prediction::default(), |d| Prediction {
            class: match d.class {
                ContactClass::AvatarAttack => 1,
                ContactClass::BoxerAttack => 2,
                ContactClass::BoxerBlocked => 3,
                ContactClass::AvatarBlocked => 4,
                ContactClass::Other => 5,
            },
            vh_body: d.vh_body as u16,
            av_body: d.av_body as u16,
            point_m: d.point_m,
            at_s: d.at_s,
        });
        Decisions {
            active: m.active,
            hands: [hand(m.hands[0]), hand(m.hands[1])],
            body: u8::from(m.body == BodyBehaviour::Avoidance),
            reaches,
            prediction,
            predictions: m.predictions,
            attacks: m.attacks,
            avoidances: m.avoidances,
            blocks: m.blocks,
            hits_taken: m.hits_taken,
            hits_given: m.hits_given,
            last_predict_s: m.last_predict_ns as f64 * 1e-9,
        }
    }

    pub fn status_text(&self) -> String {
        let m = &self.world.mind;
        let b = |x: spidar_sim::boxer::Behaviour| format!("{x:?}").to_lowercase();
        format!(
            "{} body {:?} hands {}/{} | attacks {} avoid {} block {} | hits taken {} given {} | predictions {} last {:.2} ms",
            if m.active { "active" } else { "passive" },
            m.body,
            b(m.hands[0]),
            b(m.hands[1]),
            m.attacks,
            m.avoidances,
            m.blocks,
            m.hits_taken,
            m.hits_given,
            m.predictions,
            m.last_predict_ns as f64 * 1e-6,
        )
    }
}

impl Scene for BoxingScene {
    fn name(&self) -> &str {
        "boxing"
    }

    fn step_s(&self) -> f64 {
        self.world.dt_s()
    }

    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        let started = std::time::Instant::now();
        self.world.begin_step();
        for s in samples {
            self.take_impulses(s);
        }
        if let Some(s) = samples.last() {
            let off = self.world.params.user_offset_m;
            for h in 0..HANDS {
                let hs = s.hands[h];
                self.user_hands[h] = hs.valid.then_some(hs.pos_m);
                self.targets[h] =
                    hs.valid.then_some(HandTarget { pos_m: hs.pos_m + off, vel_m_per_s: hs.vel_m_per_s });
            }
        }
        self.world.step(&self.targets);
        // The proxies need the kinematics of the new state.
        self.world.begin_step();
        let m = self.model_at(t_s);
        self.last_step_ns = started.elapsed().as_nanos() as u64;
        m
    }

    fn status(&self) -> String {
        self.status_text()
    }

    fn look(&self) -> crate::look::Look {
        crate::looks::boxing::look(self)
    }

    fn pose(&self, out: &mut crate::look::Poses<'_>) {
        crate::looks::boxing::pose(self, out)
    }

    fn decisions(&self) -> Option<crate::decisions::Decisions> {
        Some(self.decisions())
    }
}
