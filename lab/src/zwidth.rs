//! `spidar bench zwidth`: the range of wall stiffness and damping the rig renders passively (its
//! Z-width), measured on the simulated rig through the real loop.
//!
//! One bout: the simulated rig (motors, strings, encoder quantisation) on the virtual clock,
//! driven by the rt-loop as `spidar run` drives it (kinematics from the counts, the velocity
//! filter, penalty rendering of a plane proxy sent as a world sends it every 3 ms, the force
//! limit, the tension allocation, the one-tick delay and the zero-order hold). A simulated hand
//! (a mass held by an arm spring and damper, [`HandModel`]) rests on the wall's surface; then its
//! arm target steps into the wall so that it presses with about [`HandModel::press_n`]. After a
//! settling time the bout is judged on its last second (docs/zwidth.md):
//!
//! - sustained oscillation: the penetration's peak-to-peak over the last half second is above
//!   [`OSC_PP_M`] and no smaller than [`NO_DECAY`] times that of the half second before;
//! - energy: the wall put more than [`ENERGY_J`] into the hand over the last second, beyond
//!   what its ideal spring gave back (`integral F.v dt + K/2 (p_end^2 - p_start^2)`).
//!
//! Either makes the wall not passive at that (K, B). The sweep runs a grid of (K, B) per axis,
//! position and loop rate and puts the Colgate-Schenkel bound `b > K T / 2 + |B|` beside it,
//! with `b` the hand's damping: the simulated rig has no friction of its own, so the damping at
//! the grip is the hand's.
//!
//! Must never: judge a bout from anything but the simulated rig's ground truth, hide the rig's
//! stiffness limit (the bench lifts it to measure the renderer itself, and says so), or use the
//! wall clock (a bout is deterministic).

use anyhow::Context;
use glam::DVec3;
use spidar_device::sim::{Script, SimRig, SimRigParams};
use spidar_link::channel;
use spidar_msg::{ContactModel, Proxy, ProxyId, ProxyShape};
use spidar_rt::{Command, Endpoints, Lifecycle, Rig, RtLoop, VirtualClock};

/// Peak-to-peak penetration (m) over the last half second above which a bout oscillates.
pub const OSC_PP_M: f64 = 0.2e-3;
/// An oscillation that shrank to less than this share of the half second before is decaying.
pub const NO_DECAY: f64 = 0.8;
/// Energy (J) the wall may put into the hand over the last second beyond its spring's.
pub const ENERGY_J: f64 = 0.5e-3;
/// The hand the bench presses with (left): its home and reach are the rig map's.
pub const HAND: usize = 0;
/// The wall's model is sent this often, as the world sends its models.
pub const MODEL_EVERY_S: f64 = 0.003;

/// The person's hand on the grip: a mass held toward a target by the arm's spring and damper.
///
/// Defaults: a relaxed grip, the light and lightly damped end of measured human hand and arm
/// endpoint impedance (docs/zwidth.md): 0.7 kg, 300 N/m, 8 N s/m (the rig file's
/// `grip_damping_n_s_per_m`), pressing with 2 N.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandModel {
    pub mass_kg: f64,
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    /// The arm's target steps `press_n / k_n_per_m` into the wall.
    pub press_n: f64,
}

impl Default for HandModel {
    fn default() -> Self {
        HandModel { mass_kg: 0.7, k_n_per_m: 300.0, d_n_s_per_m: 8.0, press_n: 2.0 }
    }
}

/// Where a bout presses: the hand's home or off its centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Place {
    Home,
    /// 10 cm further out, up and forward than home (toward where the rig map's margin falls).
    OffCentre,
}

impl Place {
    pub const ALL: [Place; 2] = [Place::Home, Place::OffCentre];

    /// The grip's centre at the start of the bout (rig frame).
    pub fn position_m(self, rig: &Rig) -> DVec3 {
        let home = rig.hands[HAND].home_m;
        match self {
            Place::Home => home,
            // Hand 0 is the left hand: out is -x.
            Place::OffCentre => home + DVec3::new(-0.10, 0.10, -0.10),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Place::Home => "home",
            Place::OffCentre => "off-centre",
        }
    }
}

/// The axis a bout presses along, and the way the hand presses (as the shipped scenes have it:
/// toward the middle into a side wall, down on a table, forward into a front wall).
pub const AXES: [(&str, DVec3); 3] =
    [("x", DVec3::new(1.0, 0.0, 0.0)), ("y", DVec3::new(0.0, -1.0, 0.0)), ("z", DVec3::new(0.0, 0.0, -1.0))];

/// One bout's set-up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bout {
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    /// Index into [`AXES`].
    pub axis: usize,
    pub place: Place,
    /// The loop's period (the simulated rig's exchanges follow it).
    pub period_s: f64,
    pub hand: HandModel,
    /// Seconds from the press to the end; the last second is judged (at least 2).
    pub seconds: f64,
    /// First-order lag of the motors (0: ideal, as `spidar run`'s simulated rig by default).
    pub motor_time_constant_s: f64,
}

impl Bout {
    /// A 3 s bout at 1 kHz at home, along x, with the default hand and ideal motors.
    pub fn new(k_n_per_m: f64, d_n_s_per_m: f64) -> Bout {
        Bout {
            k_n_per_m,
            d_n_s_per_m,
            axis: 0,
            place: Place::Home,
            period_s: 0.001,
            hand: HandModel::default(),
            seconds: 3.0,
            motor_time_constant_s: 0.0,
        }
    }
}

/// What a bout measured.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BoutResult {
    /// Penetration peak-to-peak (m) over the last half second and the half second before it.
    pub pp_last_m: f64,
    pub pp_before_m: f64,
    /// Energy (J) the wall put into the hand over the last second beyond its ideal spring's.
    pub energy_j: f64,
    /// Mean penetration (m) over the last half second.
    pub depth_m: f64,
    /// Largest force the strings produced on the hand after the press (N).
    pub peak_force_n: f64,
    /// Ticks whose force was clamped to the limit or scaled back as infeasible.
    pub clamped: u64,
    pub infeasible: u64,
}

impl BoutResult {
    pub fn oscillates(&self) -> bool {
        self.pp_last_m > OSC_PP_M && self.pp_last_m >= NO_DECAY * self.pp_before_m
    }
    pub fn active(&self) -> bool {
        self.energy_j > ENERGY_J
    }
    pub fn passive(&self) -> bool {
        !self.oscillates() && !self.active()
    }
}

/// The rig of a bout: the file's, homed (counter zeros from the homes), at the bout's rate, with
/// the stiffness limit lifted so the renderer meets the wall's stiffness as asked.
fn bout_rig(rig: &Rig, b: &Bout) -> Rig {
    let mut r = rig.clone();
    r.period_s = b.period_s;
    for h in r.hands.iter_mut() {
        let home = h.home_m;
        h.length_at_zero_m = Some(std::array::from_fn(|i| (h.anchors_m[i] - home).length()));
        h.stiffness_limit_n_per_m = f64::MAX;
    }
    r
}

fn sim_rig(rig: &Rig, b: &Bout, start_m: DVec3) -> anyhow::Result<SimRig> {
    let mut p = SimRigParams::with_defaults(rig.sim_hands());
    p.period_s = rig.period_s;
    p.motor_time_constant_s = b.motor_time_constant_s;
    let hp = &mut p.hands[HAND];
    hp.start_m = start_m;
    hp.mass_kg = b.hand.mass_kg;
    hp.arm_k_n_per_m = b.hand.k_n_per_m;
    hp.arm_d_n_s_per_m = b.hand.d_n_s_per_m;
    let scripts = [0, 1].map(|h| Script::hold(p.hands[h].start_m));
    SimRig::new(p, scripts).context("building the simulated rig for a Z-width bout")
}

/// The wall: a plane touching the grip's sphere at `start_m`, solid on the side the hand presses
/// toward, for hand [`HAND`] only (world frame, as a scene sends it).
fn wall_model(rig: &Rig, b: &Bout, start_m: DVec3, seq: u64, stamp_s: f64) -> ContactModel {
    let press = AXES[b.axis].1;
    let surface = start_m + press * rig.hands[HAND].grip_radius_m;
    let mut m = ContactModel { seq, stamp_s, ..Default::default() };
    m.push(Proxy {
        id: ProxyId { body: 1, part: 0 },
        shape: ProxyShape::Plane {
            point_m: rig.rig_to_world.point(surface),
            normal: rig.rig_to_world.vector(-press),
        },
        k_n_per_m: b.k_n_per_m,
        d_n_s_per_m: b.d_n_s_per_m,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 1 << HAND,
    });
    m
}

/// Peak-to-peak of a series.
fn peak_to_peak(xs: &[f64]) -> f64 {
    let (lo, hi) = xs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| (l.min(*x), h.max(*x)));
    if xs.is_empty() {
        0.0
    } else {
        hi - lo
    }
}

/// Runs one bout and measures it (deterministic: the virtual clock, no noise).
pub fn run_bout(rig: &Rig, b: &Bout) -> anyhow::Result<BoutResult> {
    anyhow::ensure!(
        b.seconds >= 2.0,
        "a Z-width bout needs at least 2 s after the press (got {})",
        b.seconds
    );
    let rig = bout_rig(rig, b);
    let start = b.place.position_m(&rig);
    let (link, world) = channel::pair();
    let ep = Endpoints { link: Some(Box::new(link)), ..Endpoints::default() };
    let mut rt = RtLoop::new(sim_rig(&rig, b, start)?, VirtualClock::new(), &rig, ep)?;
    rt.configure().map_err(|e| anyhow::anyhow!("opening the simulated rig: {e}"))?;
    rt.command(Command::Activate);
    let period = rig.period_s;
    let ramp_ticks = ((rig.safety.ramp_in_s + 0.1) / period).ceil() as u64;
    let bout_ticks = (b.seconds / period).round() as u64;
    let press = AXES[b.axis].1;
    let mut depth = Vec::with_capacity(bout_ticks as usize);
    let judge_from = bout_ticks.saturating_sub((1.0 / period).round() as u64);
    let (mut energy, mut depth_at_judge, mut peak) = (0.0, 0.0, 0.0_f64);
    let (mut next_model_s, mut seq) = (0.0, 0);
    let before = *rt.core().counters();
    for tick in 0..ramp_ticks + bout_ticks {
        let now_s = rt.clock().now_s();
        if now_s >= next_model_s {
            seq += 1;
            // The next tick takes it (as a world's model, stamped when it was made).
            let _ = world.models.try_send(wall_model(&rig, b, start, seq, now_s));
            next_model_s += MODEL_EVERY_S;
            while world.samples.try_recv().is_ok() {}
        }
        if tick == ramp_ticks {
            anyhow::ensure!(
                rt.state() == Lifecycle::Active,
                "the loop is {:?}, not active, before the press",
                rt.state()
            );
            rt.device_mut().set_push(HAND, press * (b.hand.press_n / b.hand.k_n_per_m));
        }
        rt.tick();
        if tick < ramp_ticks {
            continue;
        }
        let t = &rt.device().truth().hands[HAND];
        // Penetration of the fist's sphere into the wall, along the press.
        let p = (t.pos_m - start).dot(press);
        let k = tick - ramp_ticks;
        if k == judge_from {
            depth_at_judge = p.max(0.0);
        }
        if k >= judge_from {
            energy += t.string_force_n.dot(t.vel_m_per_s) * period;
        }
        peak = peak.max(t.string_force_n.length());
        depth.push(p);
    }
    let half = (0.5 / period).round() as usize;
    let n = depth.len();
    let last = &depth[n - half..];
    let end = depth[n - 1].max(0.0);
    energy += 0.5 * b.k_n_per_m * (end * end - depth_at_judge * depth_at_judge);
    let c = rt.core().counters();
    Ok(BoutResult {
        pp_last_m: peak_to_peak(last),
        pp_before_m: peak_to_peak(&depth[n - 2 * half..n - half]),
        energy_j: energy,
        depth_m: last.iter().sum::<f64>() / last.len() as f64,
        peak_force_n: peak,
        clamped: c.clamped[HAND] - before.clamped[HAND],
        infeasible: c.infeasible[HAND] - before.infeasible[HAND],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    // The boundary at 1 kHz, at home along x, B = 0, with the default hand (b = 8 N s/m) lies
    // between 5,000 and 10,000 N/m (`spidar bench zwidth`).

    #[test]
    fn a_wall_just_inside_the_boundary_is_passive_at_1_khz() {
        let rig = Rig::default_rig();
        let r = run_bout(&rig, &Bout::new(4000.0, 0.0)).unwrap();
        assert!(r.passive(), "{r:?}");
        assert!(r.pp_last_m < 0.05e-3 && r.energy_j.abs() < 0.1e-3, "{r:?}");
        // It holds the hand: the press (about 2 N) over K.
        assert!((r.depth_m * 4000.0 - 2.0).abs() < 0.3, "{r:?}");
    }

    #[test]
    fn a_wall_well_outside_the_boundary_oscillates_and_gives_the_hand_energy_at_1_khz() {
        let rig = Rig::default_rig();
        let r = run_bout(&rig, &Bout::new(15_000.0, 0.0)).unwrap();
        assert!(r.oscillates() && r.active() && !r.passive(), "{r:?}");
        // Negative damping eats the hand's own: a soft wall with B = -5 N s/m is not passive either.
        let r = run_bout(&rig, &Bout::new(2000.0, -5.0)).unwrap();
        assert!(!r.passive(), "{r:?}");
    }

    #[test]
    fn bouts_are_deterministic() {
        let rig = Rig::default_rig();
        let b = Bout { axis: 2, place: Place::OffCentre, period_s: 0.002, ..Bout::new(3000.0, 5.0) };
        assert_eq!(run_bout(&rig, &b).unwrap(), run_bout(&rig, &b).unwrap());
    }
}
