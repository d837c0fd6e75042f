//! The boxing scene (seed 000): the physics world of `spidar_sim::boxer` behind the rt-loop.
//!
//! Every 3 ms step: the user's hands (newest sample, world frame of the rt-loop) plus the boxer's
//! `user_offset_m` become the targets the coupling springs pull the avatar's hands to; the world
//! steps (the avatar's fists collide with the virtual human, who thinks and reaches); and the
//! scene sends the contact on each avatar hand as a local model (`HandContact`, in the rt-loop's
//! frame), which the rt-loop renders at 1 kHz and clips to what the rig can push, with the
//! newest blow the virtual human landed on the avatar (`Blow`: the loop renders a push along it
//! and a burst at impact on both hands) and the avatar's other damage (contacts on its other
//! parts, attenuated) as the extra force on both hands.
//! No proxies: the user touches the virtual human only through the avatar's hands.
//!
//! The virtual human's decisions (behaviour per hand and body, the deciding prediction, hits)
//! are data on `world.mind` and `world.last` for the status line, the recorder and the viewer.
//!
//! Must never: send the coupling spring to the user.

use spidar_msg::{ContactModel, HandSample, HANDS};
use spidar_sim::boxer::{BoxerParams, BoxingWorld, HandTarget};

use crate::Scene;

pub(crate) mod look;

pub struct BoxingScene {
    pub world: BoxingWorld,
    seq: u64,
    targets: [Option<HandTarget>; HANDS],
    /// Wall time of each world step (ns), the newest last; read by `spidar eval` and the status.
    pub last_step_ns: u64,
}

impl BoxingScene {
    pub fn new(params: BoxerParams) -> anyhow::Result<BoxingScene> {
        let world = BoxingWorld::new(params)?;
        Ok(BoxingScene { world, seq: 0, targets: [None; HANDS], last_step_ns: 0 })
    }

    /// The `seq` of the newest model sent.
    pub fn seq(&self) -> u64 {
        self.seq
    }

    /// The model of the world's newest state: the avatar hands' contacts (the report's, in the
    /// rt-loop's frame already), the newest blow the virtual human landed (the loop renders it on
    /// both hands, `spidar_rt::blow`), and the avatar's other damage (contacts on its parts that
    /// are not a landed blow), attenuated, on both hands.
    fn model_at(&mut self, t_s: f64) -> ContactModel {
        self.seq += 1;
        let w = &self.world;
        let damage = (w.last.damage_force_n - w.last.blow_force_n) * w.params.damage_attenuation;
        ContactModel {
            seq: self.seq,
            stamp_s: t_s,
            hand_contacts: w.last.hand_contacts,
            extra_force_n: [damage; HANDS],
            blow: w.last.blow,
            ..Default::default()
        }
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
            gaze: self.gaze(),
        }
    }

    /// Where the virtual human looks: its eyes, the direction its gaze has turned to, and the
    /// point on that line as far away as what its attention is on (the attended fist as it was
    /// seen, else the avatar's upper chest, where a boxer's eyes rest).
    pub fn gaze(&self) -> crate::decisions::Gaze {
        let w = &self.world;
        let p = &w.mind.perception;
        let looked_at = match p.attended {
            Some(h) => p.seen[h].pos_m,
            None => (w.com(w.avatar.head) + w.com(w.avatar.chest)) * 0.5,
        };
        // The eyes are the head's centre now (the vision model took it at the step's start).
        let eye_m = w.com(w.vh.head);
        let dir = p.gaze_dir.normalize_or(glam::DVec3::NEG_Z);
        crate::decisions::Gaze {
            eye_m,
            dir,
            at_m: eye_m + dir * (looked_at - eye_m).length(),
            attended: p.attended.map_or(0, |h| h as u8 + 1),
        }
    }

    /// The virtual human's behaviours (body and each hand), the newest decision (the Table I class
    /// of the deciding predicted contact and the part it names), and its counters.
    pub fn status_text(&self) -> String {
        let w = &self.world;
        let m = &w.mind;
        let b = |x: spidar_sim::boxer::Behaviour| format!("{x:?}").to_lowercase();
        let part = |body: usize| {
            let p = &w.vh;
            if body == p.head {
                "head"
            } else if body == p.chest {
                "chest"
            } else if p.hand.contains(&body) {
                "hand"
            } else if p.forearm.contains(&body) || p.upper_arm.contains(&body) {
                "arm"
            } else {
                "body"
            }
        };
        let decision = m
            .last_decision
            .map_or("none".to_string(), |d| format!("{} on its {}", d.class.name(), part(d.vh_body)));
        format!(
            "{} {} body {} hands {}/{} | decided: {decision} | attacks {} (counters {}, given up {}) avoid {} block {} ended {} | hits taken {} given {} | predictions {} last {:.2} ms",
            m.skill().level,
            if m.active { "active" } else { "passive" },
            format!("{:?}", m.body).to_lowercase(),
            b(m.hands[0]),
            b(m.hands[1]),
            m.attacks,
            m.counters,
            m.attacks_abandoned,
            m.avoidances,
            m.blocks,
            m.defences_ended,
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
        // The newest sample is where the user's hands are: the avatar's hands are pulled there.
        if let Some(s) = samples.last() {
            let off = self.world.params.user_offset_m;
            for h in 0..HANDS {
                let hs = s.hands[h];
                self.targets[h] = hs
                    .valid
                    .then_some(HandTarget { pos_m: hs.pos_world_m + off, vel_m_per_s: hs.vel_world_m_per_s });
            }
        }
        self.world.step(&self.targets);
        let m = self.model_at(t_s);
        self.last_step_ns = started.elapsed().as_nanos() as u64;
        m
    }

    fn status(&self) -> String {
        self.status_text()
    }

    fn look(&self) -> crate::look::Look {
        look::look(self)
    }

    fn pose(&self, out: &mut crate::look::Poses<'_>) {
        look::pose(self, out)
    }

    fn decisions(&self) -> Option<crate::decisions::Decisions> {
        Some(self.decisions())
    }
}
