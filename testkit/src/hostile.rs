//! A world that sends the rig what a broken or hostile scene could: absurd proxies (NaN and
//! infinite stiffnesses, huge velocities, NaN extra forces) or absurd local models of the avatar's
//! hands (NaN, infinite and huge forces, normals, stiffnesses and positions). The rig's safety
//! chain must keep every force on the hands finite and within its limit whatever comes.
//!
//! Must never: send something a real scene could not (every value is a plain `f64` a bug could
//! produce), or vary between runs with the same seed.

use glam::DVec3;
use spidar_msg::{ContactModel, HandContact, HandSample, Proxy, ProxyId, ProxyShape};
use spidar_world::Scene;

/// What a [`HostileScene`] sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Hostility {
    /// A proxy at each hand with a random or absurd stiffness, damping and velocity, and NaN or
    /// huge extra forces every seventh step.
    Proxies,
    /// The avatar hands' local models with NaN, infinite and huge forces, normals, stiffnesses,
    /// positions and source powers, in turn.
    HandContacts,
}

/// A 3 ms scene sending the rig hostile contact models.
pub struct HostileScene {
    what: Hostility,
    seq: u64,
    rng: u64,
}

impl HostileScene {
    /// A scene of `what`, its randomness seeded with `seed` (not 0).
    pub fn new(what: Hostility, seed: u64) -> HostileScene {
        assert!(seed != 0, "xorshift needs a seed other than 0");
        HostileScene { what, seq: 0, rng: seed }
    }

    fn next(&mut self) -> f64 {
        // xorshift: deterministic, no dependency.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        (self.rng >> 11) as f64 / (1u64 << 53) as f64
    }

    fn proxies(&mut self, m: &mut ContactModel, s: &HandSample) {
        for h in 0..2 {
            let p = s.hands[h].pos_world_m;
            let k = match self.seq % 5 {
                0 => f64::NAN,
                1 => f64::INFINITY,
                _ => 10f64.powf(2.0 + 8.0 * self.next()),
            };
            let dir =
                DVec3::new(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5).normalize_or(DVec3::Y);
            m.push(Proxy {
                id: ProxyId { body: 9, part: h as u16 },
                shape: ProxyShape::Sphere { centre_m: p + dir * 0.05, radius_m: 0.03 },
                k_n_per_m: k,
                d_n_s_per_m: 1e3 * self.next(),
                vel_m_per_s: DVec3::new(self.next(), -self.next(), 50.0 * (self.next() - 0.5)),
                hand_mask: Proxy::BOTH_HANDS,
            });
        }
        if self.seq.is_multiple_of(7) {
            m.extra_force_n = [DVec3::new(f64::NAN, 1.0, 0.0), DVec3::splat(1e9)];
        }
    }

    fn hand_contacts(&self, m: &mut ContactModel, s: &HandSample) {
        let bad = [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300, -1e9];
        for h in 0..2 {
            let x = bad[(self.seq as usize + h) % bad.len()];
            let at = s.hands[h].pos_world_m;
            m.hand_contacts[h] = match self.seq % 4 {
                0 => HandContact {
                    force_n: DVec3::new(x, 1.0, 0.0),
                    normal: DVec3::Y,
                    k_n_per_m: 1e3,
                    at_m: at,
                    source_w: 0.0,
                },
                1 => HandContact {
                    force_n: DVec3::Y * 1e6,
                    normal: DVec3::splat(x),
                    k_n_per_m: x,
                    at_m: at,
                    source_w: x,
                },
                2 => HandContact {
                    force_n: DVec3::Y,
                    normal: DVec3::Y,
                    k_n_per_m: 1e12,
                    at_m: DVec3::splat(x),
                    source_w: 1e9,
                },
                _ => HandContact {
                    force_n: DVec3::Y * 3.0,
                    normal: -DVec3::Y,
                    k_n_per_m: 1e4,
                    at_m: at + DVec3::Y,
                    source_w: -x,
                },
            };
        }
    }
}

impl Scene for HostileScene {
    fn name(&self) -> &str {
        match self.what {
            Hostility::Proxies => "hostile",
            Hostility::HandContacts => "hostile local models",
        }
    }
    fn step_s(&self) -> f64 {
        0.003
    }
    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        self.seq += 1;
        let mut m = ContactModel { seq: self.seq, stamp_s: t_s, ..Default::default() };
        let Some(s) = samples.last() else { return m };
        match self.what {
            Hostility::Proxies => self.proxies(&mut m, s),
            Hostility::HandContacts => self.hand_contacts(&mut m, s),
        }
        m
    }
}
