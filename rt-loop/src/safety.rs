//! The safety phase: what stands between a rendered force and the user's hand.
//!
//! In order: a NaN/inf guard (a non-finite force becomes zero), the staleness fade (a contact model
//! older than its limit fades linearly to zero; no model at all is zero), the ramp (force rises
//! from zero after activation or after a fault clears and falls to zero before stopping), and last
//! the per-hand force clamp, so nothing upstream can exceed the rig's limit. Every intervention is
//! reported to the caller, which counts it. Allocation-free; never panics.

use glam::DVec3;

/// Gain in [0, 1] for a contact model of age `age_s` (None: no model yet).
pub fn staleness_gain(age_s: Option<f64>, stale_after_s: f64, fade_s: f64) -> f64 {
    match age_s {
        None => 0.0,
        Some(a) if a.is_nan() => 0.0,
        Some(a) if a <= stale_after_s => 1.0,
        Some(a) if fade_s > 0.0 => (1.0 - (a - stale_after_s) / fade_s).clamp(0.0, 1.0),
        Some(_) => 0.0,
    }
}

/// A linear ramp of the force gain between 0 and 1.
#[derive(Clone, Copy, Debug)]
pub struct Ramp {
    gain: f64,
    up_per_tick: f64,
    down_per_tick: f64,
    rising: bool,
}

impl Ramp {
    pub fn new(ramp_in_s: f64, ramp_out_s: f64, dt_s: f64) -> Ramp {
        let step = |t: f64| if t > 0.0 { dt_s / t } else { 1.0 };
        Ramp { gain: 0.0, up_per_tick: step(ramp_in_s), down_per_tick: step(ramp_out_s), rising: false }
    }
    /// Start rising from the current gain.
    pub fn rise(&mut self) {
        self.rising = true;
    }
    /// Start falling from the current gain.
    pub fn fall(&mut self) {
        self.rising = false;
    }
    /// Drop to zero at once (faults).
    pub fn cut(&mut self) {
        self.rising = false;
        self.gain = 0.0;
    }
    /// Advances one tick and returns the gain to apply this tick.
    pub fn step(&mut self) -> f64 {
        // Snap within a rounding error of the ends, so N steps of 1/N reach them exactly.
        const SNAP: f64 = 1e-9;
        self.gain = if self.rising {
            let g = self.gain + self.up_per_tick;
            if g > 1.0 - SNAP {
                1.0
            } else {
                g
            }
        } else {
            let g = self.gain - self.down_per_tick;
            if g < SNAP {
                0.0
            } else {
                g
            }
        };
        self.gain
    }
    pub fn gain(&self) -> f64 {
        self.gain
    }
    pub fn is_rising(&self) -> bool {
        self.rising
    }
}

/// Once the contact model was lost while active (its force faded all the way to zero), force
/// comes back no faster than the activation ramp when models arrive again: a world that
/// reconnects, is restarted or replaced never steps force into the user's hand. A model that is
/// merely late (fading, not gone) returns at once, as before.
#[derive(Clone, Copy, Debug)]
pub struct ReturnRamp {
    limit: f64,
    per_tick: f64,
    lost: bool,
}

impl ReturnRamp {
    pub fn new(ramp_in_s: f64, dt_s: f64) -> ReturnRamp {
        ReturnRamp { limit: 1.0, per_tick: if ramp_in_s > 0.0 { dt_s / ramp_in_s } else { 1.0 }, lost: false }
    }

    /// The staleness gain to apply this tick, given the fade's (`stale_gain`); `active_with_model`:
    /// the rig is active and has had a model (one that faded to zero is then a lost one).
    pub fn step(&mut self, stale_gain: f64, active_with_model: bool) -> f64 {
        if active_with_model && stale_gain == 0.0 {
            self.lost = true;
        }
        if !self.lost {
            return stale_gain;
        }
        if stale_gain == 0.0 {
            self.limit = 0.0;
            return 0.0;
        }
        self.limit = (self.limit + self.per_tick).min(1.0);
        if self.limit > 1.0 - 1e-9 {
            self.limit = 1.0;
            self.lost = false;
        }
        stale_gain.min(self.limit)
    }
}

/// What the safety phase did to one hand's force this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Guarded {
    pub force_n: DVec3,
    pub non_finite: bool,
    pub clamped: bool,
}

/// NaN guard, gains, then the clamp to `limit_n` (scaling along the force's own direction).
pub fn guard(force_n: DVec3, gain: f64, limit_n: f64) -> Guarded {
    let mut out = Guarded::default();
    let mut f = force_n;
    if !f.is_finite() {
        out.non_finite = true;
        f = DVec3::ZERO;
    }
    let g = if gain.is_finite() { gain.clamp(0.0, 1.0) } else { 0.0 };
    f *= g;
    let mag = f.length();
    if mag > limit_n {
        out.clamped = true;
        f *= limit_n / mag;
    }
    out.force_n = f;
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn staleness_fades_linearly_after_the_limit() {
        assert_eq!(staleness_gain(None, 0.03, 0.1), 0.0);
        assert_eq!(staleness_gain(Some(0.02), 0.03, 0.1), 1.0);
        assert!((staleness_gain(Some(0.08), 0.03, 0.1) - 0.5).abs() < 1e-12);
        assert_eq!(staleness_gain(Some(0.5), 0.03, 0.1), 0.0);
        assert_eq!(staleness_gain(Some(0.031), 0.03, 0.0), 0.0);
        assert_eq!(staleness_gain(Some(f64::NAN), 0.03, 0.1), 0.0);
    }

    #[test]
    fn force_returns_over_the_ramp_after_the_model_was_lost_and_at_once_after_a_short_fade() {
        let mut r = ReturnRamp::new(0.5, 0.001);
        // Not active: a missing model is no loss (start-up).
        assert_eq!(r.step(0.0, false), 0.0);
        assert_eq!(r.step(1.0, true), 1.0);
        // Late, fading, back: no ramp.
        assert_eq!(r.step(0.4, true), 0.4);
        assert_eq!(r.step(1.0, true), 1.0);
        // Gone (zero while active), back: 500 ticks to full, never above the fade's gain.
        assert_eq!(r.step(0.0, true), 0.0);
        assert_eq!(r.step(0.0, true), 0.0);
        let mut n = 1;
        let mut prev = r.step(1.0, true);
        assert!((prev - 0.002).abs() < 1e-12);
        while prev < 1.0 {
            let g = r.step(1.0, true);
            assert!(g > prev && g - prev < 0.0021 && n < 500, "tick {n}: {prev} -> {g}");
            prev = g;
            n += 1;
        }
        assert_eq!(n, 500);
        assert_eq!(r.step(0.3, true), 0.3, "after the ramp, the fade alone again");
        // The return is over once at full: a model missing while the rig is not active (no
        // loss, as at start-up) then comes back at once, not over another ramp.
        assert_eq!(r.step(0.0, false), 0.0);
        assert_eq!(r.step(1.0, true), 1.0, "the return ended when it reached full force");
    }

    #[test]
    fn ramp_takes_the_configured_number_of_ticks() {
        let mut r = Ramp::new(0.5, 0.3, 0.001);
        r.rise();
        // (Bounded: a ramp that never ends fails here instead of hanging the test.)
        let mut n = 0;
        while r.step() < 1.0 && n < 10_000 {
            n += 1;
        }
        assert_eq!(n + 1, 500);
        r.fall();
        let mut n = 0;
        while r.step() > 0.0 && n < 10_000 {
            n += 1;
        }
        assert_eq!(n + 1, 300);
    }

    #[test]
    fn staleness_boundaries_are_exact() {
        // At the limit itself the model is still fresh; just past it the fade has begun.
        assert_eq!(staleness_gain(Some(0.03), 0.03, 0.1), 1.0);
        let g = staleness_gain(Some(0.031), 0.03, 0.1);
        assert!((g - 0.99).abs() < 1e-9, "{g}");
        assert_eq!(staleness_gain(Some(0.13), 0.03, 0.1), 0.0);
        // A model from the future (clock skew) is fresh, not amplified.
        assert_eq!(staleness_gain(Some(-0.5), 0.03, 0.1), 1.0);
        // A zero or negative fade (refused by the rig file) drops force at once, never keeps it.
        assert_eq!(staleness_gain(Some(0.01), 0.03, 0.0), 1.0, "a fresh model is full whatever the fade");
        assert_eq!(staleness_gain(Some(0.0300001), 0.03, 0.0), 0.0);
        assert_eq!(staleness_gain(Some(0.0300001), 0.03, -0.0), 0.0);
        assert_eq!(staleness_gain(Some(0.0300001), 0.03, -1.0), 0.0);
    }

    #[test]
    fn every_ramp_time_takes_its_number_of_ticks_and_ends_exactly_at_its_ends() {
        // Steps of dt / t rarely sum to exactly 1: the snap must land the ends on the right tick.
        for ms in 50..=1000 {
            let t = ms as f64 * 1e-3;
            let want = ms;
            let mut r = Ramp::new(t, t, 0.001);
            r.rise();
            let mut n = 1;
            while r.step() < 1.0 {
                n += 1;
                assert!(r.gain() < 1.0 && n <= want, "ramp {ms} ms rose for {n} ticks");
            }
            assert_eq!((n, r.gain()), (want, 1.0), "ramp in {ms} ms");
            r.fall();
            let mut n = 1;
            while r.step() > 0.0 {
                n += 1;
                assert!(n <= want, "ramp {ms} ms fell for {n} ticks");
            }
            assert_eq!((n, r.gain()), (want, 0.0), "ramp out {ms} ms");
        }
    }

    #[test]
    fn ramp_rises_falls_and_cuts_from_where_it_is() {
        let mut r = Ramp::new(0.01, 0.02, 0.001);
        assert_eq!((r.gain(), r.is_rising()), (0.0, false));
        assert_eq!(r.step(), 0.0, "idle at zero");
        r.rise();
        assert!(r.is_rising());
        assert!((r.step() - 0.1).abs() < 1e-12);
        assert!((r.step() - 0.2).abs() < 1e-12);
        r.fall();
        assert!(!r.is_rising());
        assert!((r.step() - 0.15).abs() < 1e-12, "falls at its own rate from where it was");
        r.rise();
        for _ in 0..20 {
            r.step();
        }
        assert_eq!(r.gain(), 1.0, "never beyond full");
        r.cut();
        assert_eq!((r.gain(), r.is_rising()), (0.0, false));
        assert_eq!(r.step(), 0.0);
        // A zero ramp time (refused by the rig file) is a step, not a division by zero.
        let mut z = Ramp::new(0.0, 0.0, 0.001);
        z.rise();
        assert_eq!(z.step(), 1.0);
    }

    #[test]
    fn guard_reports_what_it_did() {
        let g = guard(DVec3::new(3.0, 4.0, 0.0), 1.0, 10.0);
        assert_eq!(g, Guarded { force_n: DVec3::new(3.0, 4.0, 0.0), non_finite: false, clamped: false });
        let g = guard(DVec3::new(3.0, 4.0, 0.0), 0.5, 10.0);
        assert_eq!(g.force_n, DVec3::new(1.5, 2.0, 0.0), "the gain scales");
        let g = guard(DVec3::new(30.0, 40.0, 0.0), 1.0, 10.0);
        assert!(g.clamped && (g.force_n - DVec3::new(6.0, 8.0, 0.0)).length() < 1e-12);
        let g = guard(DVec3::new(6.0, 8.0, 0.0), 1.0, 10.0);
        assert!(!g.clamped, "exactly at the limit is not clamped");
        let g = guard(DVec3::new(f64::NAN, 1.0, 0.0), 1.0, 10.0);
        assert!(g.non_finite && g.force_n == DVec3::ZERO);
        assert_eq!(guard(DVec3::X, f64::NAN, 10.0).force_n, DVec3::ZERO, "a NaN gain is zero");
        assert_eq!(guard(DVec3::X, 7.0, 10.0).force_n, DVec3::X, "a gain above 1 is 1");
        assert_eq!(guard(DVec3::X, -1.0, 10.0).force_n, DVec3::ZERO);
        // A zero limit (refused by the rig file) still gives zero, never NaN.
        assert_eq!(guard(DVec3::ZERO, 1.0, 0.0).force_n, DVec3::ZERO);
        assert_eq!(guard(DVec3::X, 1.0, 0.0).force_n, DVec3::ZERO);
    }

    proptest! {
        #[test]
        fn clamp_holds_for_any_input(x in proptest::num::f64::ANY, y in proptest::num::f64::ANY,
                                     z in proptest::num::f64::ANY, gain in proptest::num::f64::ANY,
                                     limit in 0.0f64..50.0) {
            let g = guard(DVec3::new(x, y, z), gain, limit);
            prop_assert!(g.force_n.is_finite());
            prop_assert!(g.force_n.length() <= limit * (1.0 + 1e-12));
        }

        #[test]
        fn clamp_keeps_direction(x in -1e3f64..1e3, y in -1e3f64..1e3, z in -1e3f64..1e3) {
            let f = DVec3::new(x, y, z);
            let g = guard(f, 1.0, 4.0);
            prop_assume!(f.length() > 1e-6);
            prop_assert!(g.force_n.cross(f).length() <= 1e-9 * f.length());
            prop_assert!(g.force_n.dot(f) >= 0.0);
        }
    }
}
