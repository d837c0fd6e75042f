//! A blow the virtual human lands on the avatar, as the user's hands feel it (the boxing scene;
//! `docs/boxing.md` section 6 gives the numbers and the measurement).
//!
//! The world reports each landed blow in the contact model (`Blow`: its direction, impact speed
//! and momentum, a sequence number). Every hand of the rig feels it in two parts, both along the
//! blow's direction (the whole avatar was struck, and the user holds the rig with both hands):
//!
//! - **the push**: from impact, a force that grows with the blow's momentum (`push_n_per_n_s`
//!   times it, at most `push_max_n`: F0) and dies away over `push_s` as
//!   `F0 exp(-t / push_decay_s) (1 - t / push_s)`, so its impulse (about 0.03 s times F0 with the
//!   defaults) grows with the blow whatever the contact's length. It is paid from an energy
//!   reserve as the avatar-hand contacts are (`local::Passivity`): credited at impact with the
//!   blow's kinetic energy scaled as its force is (`push_energy_share`), filled by the hand moving
//!   against the push, drained by the hand moving with it, and the push is scaled down along its
//!   direction when the work it would do on the hand over the tick exceeds what is left.
//! - **the burst**: at impact, an open-loop decaying sinusoid (event-based haptics)
//!   `A sin(2 pi f t) exp(-t / tau)` for `burst_s`, its amplitude A growing with the impact speed
//!   (`burst_n_per_m_per_s` times it, at most `burst_max_n`). `burst_s` is a whole number of
//!   periods, so it ends at zero. Its energy is bounded: the work it does on the hand over one
//!   blow is booked tick by tick and the burst is cut (scaled down, then zero) when the work of
//!   the next tick would exceed `burst_budget_j`: at most the budget plus one tick's
//!   misjudgement of the hand's motion. Its impulse is at most `A tau` (the envelope's integral).
//!
//! Both parts are added to the rendered force before the safety phase, so they pass through the
//! same gain (the ramp and the stale-model fade: a stale model fades them to zero), the same
//! force clamp and the same allocation as every other force.
//!
//! Must never: allocate, panic, or start a burst twice for the same blow.

use glam::DVec3;
use spidar_msg::Blow;

use crate::local::Passivity;

/// How a blow is rendered. The defaults are what `spidar run` uses (`docs/boxing.md` section 6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlowParams {
    /// Push per unit of the blow's momentum (N per N s), its largest size (N), its decay time
    /// constant and its length (s).
    pub push_n_per_n_s: f64,
    pub push_max_n: f64,
    pub push_decay_s: f64,
    pub push_s: f64,
    /// Share of the blow's kinetic energy credited to the push's reserve at impact.
    pub push_energy_share: f64,
    /// Burst amplitude per unit of impact speed (N per m/s) and its largest amplitude (N).
    pub burst_n_per_m_per_s: f64,
    pub burst_max_n: f64,
    /// Burst frequency (Hz), decay time constant (s) and length (s).
    pub burst_hz: f64,
    pub burst_decay_s: f64,
    pub burst_s: f64,
    /// Most work the burst of one blow may do on one hand (J).
    pub burst_budget_j: f64,
}

impl Default for BlowParams {
    fn default() -> Self {
        BlowParams {
            push_n_per_n_s: 0.6,
            push_max_n: 2.5,
            push_decay_s: 0.04,
            push_s: 0.15,
            push_energy_share: 0.01,
            burst_n_per_m_per_s: 2.0,
            burst_max_n: 3.0,
            burst_hz: 50.0,
            burst_decay_s: 0.015,
            burst_s: 0.06,
            burst_budget_j: 0.025,
        }
    }
}

impl BlowParams {
    /// The burst's amplitude for an impact at `speed_m_per_s` (0 for anything not finite).
    pub fn burst_amplitude_n(&self, speed_m_per_s: f64) -> f64 {
        let a = (self.burst_n_per_m_per_s * speed_m_per_s).clamp(0.0, self.burst_max_n);
        if a.is_finite() {
            a
        } else {
            0.0
        }
    }

    /// The push's size for a blow of `momentum_n_s` (0 for anything not finite).
    pub fn push_n(&self, momentum_n_s: f64) -> f64 {
        let f = (self.push_n_per_n_s * momentum_n_s).clamp(0.0, self.push_max_n);
        if f.is_finite() {
            f
        } else {
            0.0
        }
    }

    /// The push's size `t_s` after impact for a start size `f0_n` (0 outside its length).
    pub fn push_at(&self, f0_n: f64, t_s: f64) -> f64 {
        if !(0.0..self.push_s).contains(&t_s) {
            return 0.0;
        }
        f0_n * (-t_s / self.push_decay_s).exp() * (1.0 - t_s / self.push_s)
    }

    /// The burst's signed size `t_s` after impact for amplitude `a_n` (0 outside its length).
    pub fn burst_at(&self, a_n: f64, t_s: f64) -> f64 {
        if !(0.0..self.burst_s).contains(&t_s) {
            return 0.0;
        }
        a_n * (std::f64::consts::TAU * self.burst_hz * t_s).sin() * (-t_s / self.burst_decay_s).exp()
    }
}

/// A blow's force on one hand this tick (the frame the caller gave the direction in).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlowForce {
    pub push_n: DVec3,
    pub burst_n: DVec3,
    /// The push was scaled down by its reserve this tick.
    pub push_limited: bool,
    /// The burst was cut by its energy budget this tick.
    pub burst_cut: bool,
}

impl BlowForce {
    pub fn total_n(&self) -> DVec3 {
        self.push_n + self.burst_n
    }
}

/// One hand's rendering of the newest blow: which blow, how far into its burst, its reserve.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlowFeel {
    seq: u64,
    /// Time since the blow arrived (s); the burst runs while it is below `burst_s`.
    since_s: f64,
    burst_amp_n: f64,
    push_size_n: f64,
    /// Work the burst did on the hand this blow (J).
    burst_work_j: f64,
    /// Whether any of this blow's force reached the hand yet.
    felt: bool,
    reserve: Passivity,
    /// The burst's force commanded on the last tick (same frame as the direction).
    last_burst_n: DVec3,
}

/// What one tick of [`BlowFeel::tick`] reports for the counters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlowTick {
    pub force: BlowForce,
    /// This is the first tick any of this blow's force reached the hand.
    pub newly_felt: bool,
    /// Work the burst did on the hand over the last tick (J; positive: given to the hand).
    pub burst_work_j: f64,
}

impl BlowFeel {
    /// The blow being rendered (0: none yet).
    pub fn seq(&self) -> u64 {
        self.seq
    }

    /// Work the current blow's burst has done on the hand (J).
    pub fn burst_work_j(&self) -> f64 {
        self.burst_work_j
    }

    /// Takes a new blow (a `seq` other than the one being rendered, not 0): its burst starts,
    /// its push's reserve is credited with its kinetic energy times the share. The same blow
    /// again changes nothing.
    pub fn start(&mut self, b: &Blow, p: &BlowParams) {
        if b.seq == 0 || b.seq == self.seq {
            return;
        }
        *self = BlowFeel {
            seq: b.seq,
            since_s: 0.0,
            burst_amp_n: p.burst_amplitude_n(b.speed_m_per_s),
            push_size_n: p.push_n(b.momentum_n_s),
            reserve: self.reserve,
            ..BlowFeel::default()
        };
        // The reserve is emptied by `observe` outside a push: a new blow starts from its own energy.
        self.reserve.observe(None, false);
        self.reserve.credit(0.5 * b.momentum_n_s * b.speed_m_per_s * p.push_energy_share);
    }

    /// One tick of the blow on a hand at `pos_m` moving at `vel_m_per_s` (None: no trusted pose;
    /// nothing is rendered, the burst's time goes on). `dir` is the blow's unit direction in the
    /// hand's frame, `gain` the tick's
    /// ramp times staleness (what the safety phase will scale the force by; the budget and the
    /// reserve judge the force the hand will get).
    #[allow(clippy::too_many_arguments)]
    pub fn tick(
        &mut self,
        p: &BlowParams,
        pos_m: Option<DVec3>,
        vel_m_per_s: DVec3,
        dir: DVec3,
        gain: f64,
        dt_s: f64,
    ) -> BlowTick {
        let mut out = BlowTick::default();
        // The burst's work over the last tick, at the measured velocity.
        if pos_m.is_some() {
            let w = self.last_burst_n.dot(vel_m_per_s) * dt_s;
            if w.is_finite() {
                out.burst_work_j = w;
                self.burst_work_j += w;
            }
        }
        let t = self.since_s;
        let pushing = self.seq != 0 && t < p.push_s;
        self.reserve.observe(pos_m, pushing);
        self.since_s += dt_s;
        self.last_burst_n = DVec3::ZERO;
        let dir = dir.normalize_or_zero();
        let (Some(_), true) = (pos_m, gain > 0.0 && gain.is_finite() && self.seq != 0) else {
            self.reserve.commanded(DVec3::ZERO);
            return out;
        };
        if pushing {
            let want = dir * p.push_at(self.push_size_n, t);
            let (f, limited) = self.reserve.limit(want * gain, vel_m_per_s, dt_s, true);
            out.force.push_n = f / gain;
            out.force.push_limited = limited;
        }
        self.reserve.commanded(out.force.push_n * gain);
        let burst = dir * p.burst_at(self.burst_amp_n, t);
        let work = (burst * gain).dot(vel_m_per_s) * dt_s;
        let left = (p.burst_budget_j - self.burst_work_j.max(0.0)).max(0.0);
        out.force.burst_n = if work > left {
            out.force.burst_cut = true;
            burst * (left / work)
        } else {
            burst
        };
        if !out.force.burst_n.is_finite() {
            out.force.burst_n = DVec3::ZERO;
        }
        self.last_burst_n = out.force.burst_n * gain;
        if !self.felt && out.force.total_n() != DVec3::ZERO {
            self.felt = true;
            out.newly_felt = true;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blow(seq: u64, speed: f64) -> Blow {
        Blow {
            seq,
            dir: DVec3::Z,
            speed_m_per_s: speed,
            momentum_n_s: 1.6 * speed,
            in_contact: true,
            ..Default::default()
        }
    }

    /// Peak |force|, peak burst, the burst's work and the ticks newly felt over a whole blow on a
    /// hand moving at `vel`.
    fn run(p: &BlowParams, b: &Blow, vel: DVec3, gain: f64) -> (f64, f64, f64, u32) {
        let mut f = BlowFeel::default();
        f.start(b, p);
        let (mut peak, mut burst_peak, mut work, mut felt) = (0.0f64, 0.0f64, 0.0, 0);
        let mut pos = DVec3::ZERO;
        for _ in 0..200 {
            let t = f.tick(p, Some(pos), vel, b.dir, gain, 0.001);
            peak = peak.max((t.force.total_n() * gain).length());
            burst_peak = burst_peak.max(t.force.burst_n.length());
            work += t.burst_work_j;
            felt += t.newly_felt as u32;
            pos += vel * 0.001;
        }
        (peak, burst_peak, work, felt)
    }

    #[test]
    fn the_bursts_peak_grows_with_the_impact_speed_and_stops_at_its_largest() {
        let p = BlowParams::default();
        let mut last = 0.0;
        for speed in [0.1, 0.25, 0.5, 0.75, 1.0, 1.25] {
            let (_, burst, _, felt) = run(&p, &blow(1, speed), DVec3::ZERO, 1.0);
            assert!(burst > last + 0.05, "{speed} m/s: burst peak {burst} N not above {last} N");
            assert_eq!(felt, 1, "felt once");
            last = burst;
        }
        let (_, burst, _, _) = run(&p, &blow(1, 50.0), DVec3::ZERO, 1.0);
        assert!(burst <= p.burst_max_n + 1e-12, "{burst}");
        // The push grows with the momentum too.
        assert!(p.push_n(2.0) < p.push_n(4.0) && p.push_n(1e9) == p.push_max_n);
    }

    #[test]
    fn the_burst_ends_at_zero_and_its_work_on_a_moving_hand_stays_within_the_budget() {
        let p = BlowParams::default();
        assert!(p.burst_at(3.0, p.burst_s - 1e-9).abs() < 1e-3, "ends at zero");
        assert_eq!(p.burst_at(3.0, p.burst_s), 0.0);
        // The hand moving at 3 m/s along the blow, the hardest blow: without the budget the burst
        // would do more than it allows on the positive half-waves.
        let b = blow(1, 20.0);
        let mut f = BlowFeel::default();
        f.start(&b, &p);
        let mut pos = DVec3::ZERO;
        let (mut work, mut cut) = (0.0, false);
        for _ in 0..100 {
            // The hand follows the force's sign (worst case: it moves with every half-wave).
            let t0 = f.since_s;
            let v = DVec3::Z * 3.0 * p.burst_at(1.0, t0).signum();
            let t = f.tick(&p, Some(pos), v, b.dir, 1.0, 0.001);
            work += t.burst_work_j;
            cut |= t.force.burst_cut;
            pos += v * 0.001;
        }
        // The last tick's work is booked on the next one.
        work += f.tick(&p, Some(pos), DVec3::ZERO, b.dir, 1.0, 0.001).burst_work_j;
        assert!(cut, "the budget had to cut this burst");
        assert!(
            work <= p.burst_budget_j + 1e-9,
            "burst work {work} J above the budget {} J",
            p.burst_budget_j
        );
        assert!(work > 0.5 * p.burst_budget_j, "{work}");
    }

    #[test]
    fn the_push_gives_a_hand_moving_with_it_no_more_than_its_reserve() {
        let p = BlowParams::default();
        let b = blow(1, 2.0);
        let credit = 0.5 * b.momentum_n_s * b.speed_m_per_s * p.push_energy_share;
        let mut f = BlowFeel::default();
        f.start(&b, &p);
        let v = DVec3::Z * 2.0;
        let mut pos = DVec3::ZERO;
        let (mut work, mut limited) = (0.0, false);
        for _ in 0..500 {
            let t = f.tick(&p, Some(pos), v, b.dir, 1.0, 0.001);
            work += t.force.push_n.dot(v) * 0.001;
            limited |= t.force.push_limited;
            pos += v * 0.001;
        }
        assert!(limited);
        assert!(work <= credit + 0.01, "push work {work} J, reserve {credit} J");
        // A hand held still feels the whole push: its start size, dying away, over its length,
        // its impulse growing with the blow's momentum.
        let impulse = |momentum: f64| {
            let b = Blow { momentum_n_s: momentum, ..b };
            let mut f = BlowFeel::default();
            f.start(&b, &p);
            let first = f.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, 1.0, 0.001).force.push_n;
            assert!((first - DVec3::Z * p.push_n(momentum)).length() < 1e-12, "{first}");
            let mut sum = first.z * 0.001;
            for i in 1..200 {
                let t = f.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, 1.0, 0.001);
                assert!(i < 150 || t.force.push_n == DVec3::ZERO, "no push after its length");
                sum += t.force.push_n.z * 0.001;
            }
            sum
        };
        let (weak, strong) = (impulse(1.0), impulse(3.0));
        assert!(strong > 2.5 * weak && weak > 0.02 * p.push_n(1.0), "{weak} {strong} N s");
    }

    #[test]
    fn the_same_blow_never_starts_twice_and_no_pose_or_no_gain_renders_nothing() {
        let p = BlowParams::default();
        let b = blow(4, 5.0);
        let mut f = BlowFeel::default();
        f.start(&b, &p);
        for _ in 0..10 {
            f.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, 1.0, 0.001);
        }
        let since = f.since_s;
        f.start(&b, &p);
        assert_eq!(f.since_s, since, "the same seq again is the same blow");
        let mut g = BlowFeel::default();
        g.start(&b, &p);
        assert_eq!(g.tick(&p, None, DVec3::ZERO, b.dir, 1.0, 0.001).force, BlowForce::default());
        assert_eq!(g.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, 0.0, 0.001).force, BlowForce::default());
        assert_eq!(
            g.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, f64::NAN, 0.001).force,
            BlowForce::default()
        );
        let mut h = BlowFeel::default();
        h.start(&Blow { seq: 0, ..b }, &p);
        assert_eq!(h.seq(), 0, "seq 0 is no blow");
        let nan = Blow { seq: 9, speed_m_per_s: f64::NAN, momentum_n_s: f64::INFINITY, ..b };
        h.start(&nan, &p);
        let t = h.tick(&p, Some(DVec3::ZERO), DVec3::ZERO, b.dir, 1.0, 0.001);
        assert!(t.force.total_n().is_finite());
    }
}
