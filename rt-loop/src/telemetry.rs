//! Telemetry: one plain record per tick, sent by the tick through a bounded channel with
//! `try_send` (dropped and counted when the consumer lags), and the statistics a non-real-time
//! thread builds from them: rate, lateness and compute-time percentiles, misses, forces.
//!
//! Only [`TickRecord`] is touched by the tick. [`Stats`] allocates (histograms) and lives on the
//! consumer's thread.

use glam::DVec3;
use hdrhistogram::Histogram;

use crate::tension::Method;
use crate::tick::{FaultReason, Lifecycle};

/// One hand in one tick (rig frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandRecord {
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
    pub residual_m: f64,
    pub valid: bool,
    /// Force asked by rendering (plus the scene's extra force), before safety.
    pub rendered_n: DVec3,
    /// Force after the safety phase (gains, clamp).
    pub commanded_n: DVec3,
    /// Force the allocated tensions produce.
    pub output_n: DVec3,
    pub tensions_n: [f64; 4],
    /// Fraction of the commanded force the strings could render along its direction.
    pub scale: f64,
    pub method: Method,
    pub contacts: u8,
    pub clamped: bool,
    /// This hand's output was held from the last tick (late, missing or rejected reply, or a
    /// pose above the residual limit): every other field repeats that tick's.
    pub held: bool,
}

impl Default for HandRecord {
    fn default() -> Self {
        HandRecord {
            pos_m: DVec3::ZERO,
            vel_m_per_s: DVec3::ZERO,
            residual_m: 0.0,
            valid: false,
            rendered_n: DVec3::ZERO,
            commanded_n: DVec3::ZERO,
            output_n: DVec3::ZERO,
            tensions_n: [0.0; 4],
            scale: 1.0,
            method: Method::Exact,
            contacts: 0,
            clamped: false,
            held: false,
        }
    }
}

/// Everything about one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TickRecord {
    pub tick: u64,
    /// Loop-clock time of the tick's deadline wake-up.
    pub t_s: f64,
    /// Wake-up time minus deadline.
    pub lateness_s: f64,
    /// Time spent computing the tick (kinematics to volts), excluding the device exchange.
    pub compute_s: f64,
    /// Time spent in the device exchange.
    pub io_s: f64,
    pub state: Lifecycle,
    pub fault: Option<FaultReason>,
    /// Overall force gain applied (ramp x staleness; 0 when not active).
    pub gain: f64,
    /// Age of the contact model used (infinite: none).
    pub contact_age_s: f64,
    pub hands: [HandRecord; 2],
    /// Homing was lost (a fault during homing, a reopened device): the rig waits for both grips
    /// to be held still at their home points, or for the Home command.
    pub awaiting_home: bool,
}

/// Percentiles of a distribution, in seconds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Percentiles {
    pub count: u64,
    pub p50_s: f64,
    pub p99_s: f64,
    pub p999_s: f64,
    pub max_s: f64,
}

impl std::fmt::Display for Percentiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "p50 {} p99 {} p99.9 {} max {}",
            fmt_dur(self.p50_s),
            fmt_dur(self.p99_s),
            fmt_dur(self.p999_s),
            fmt_dur(self.max_s)
        )
    }
}

/// Human-readable duration: ns, us or ms.
pub fn fmt_dur(s: f64) -> String {
    if !s.is_finite() {
        "-".into()
    } else if s < 1e-6 {
        format!("{:.0} ns", s * 1e9)
    } else if s < 1e-3 {
        format!("{:.1} us", s * 1e6)
    } else {
        format!("{:.2} ms", s * 1e3)
    }
}

/// A histogram of durations with nanosecond resolution up to 10 s.
#[derive(Clone, Debug)]
pub struct DurationHist {
    h: Histogram<u64>,
}

impl Default for DurationHist {
    fn default() -> Self {
        DurationHist { h: Histogram::new_with_bounds(1, 10_000_000_000, 3).expect("valid bounds") }
    }
}

impl DurationHist {
    pub fn record(&mut self, s: f64) {
        let ns = if s.is_finite() { (s * 1e9).round().clamp(1.0, 1e10) as u64 } else { 10_000_000_000 };
        self.h.saturating_record(ns);
    }
    pub fn percentiles(&self) -> Percentiles {
        let q = |p: f64| self.h.value_at_quantile(p) as f64 * 1e-9;
        Percentiles {
            count: self.h.len(),
            p50_s: q(0.5),
            p99_s: q(0.99),
            p999_s: q(0.999),
            max_s: self.h.max() as f64 * 1e-9,
        }
    }
    pub fn len(&self) -> u64 {
        self.h.len()
    }
    pub fn is_empty(&self) -> bool {
        self.h.is_empty()
    }
    /// Records above `s`.
    pub fn count_above(&self, s: f64) -> u64 {
        let ns = (s * 1e9) as u64;
        self.h.iter_recorded().filter(|v| v.value_iterated_to() > ns).map(|v| v.count_at_value()).sum()
    }
    pub fn clear(&mut self) {
        self.h.reset();
    }
}

/// Ticks per second of loop-clock time for `records` ticks between `first_t_s` and `last_t_s`.
fn rate_hz(records: u64, first_t_s: Option<f64>, last_t_s: f64) -> f64 {
    match first_t_s {
        Some(t0) if last_t_s > t0 => records.saturating_sub(1) as f64 / (last_t_s - t0),
        _ => 0.0,
    }
}

/// Statistics over the records a consumer has seen (whole run and a live window).
#[derive(Clone, Debug, Default)]
pub struct Stats {
    pub records: u64,
    pub first_t_s: Option<f64>,
    pub last_t_s: f64,
    pub lateness: DurationHist,
    pub compute: DurationHist,
    pub io: DurationHist,
    /// Ticks that woke more than one period late.
    pub late_over_1ms: u64,
    pub max_force_n: [f64; 2],
    pub max_tension_n: f64,
    /// Lowest tension commanded on any string.
    pub min_tension_n: f64,
    pub window: Window,
}

/// The live window: reset by whoever prints it.
#[derive(Clone, Debug, Default)]
pub struct Window {
    pub records: u64,
    pub first_t_s: Option<f64>,
    pub last_t_s: f64,
    pub lateness: DurationHist,
    pub last: Option<TickRecord>,
    pub max_force_n: [f64; 2],
}

impl Window {
    /// Ticks per second of loop-clock time over the window.
    pub fn rate_hz(&self) -> f64 {
        rate_hz(self.records, self.first_t_s, self.last_t_s)
    }
}

impl Stats {
    pub fn new() -> Stats {
        Stats { min_tension_n: f64::INFINITY, ..Default::default() }
    }

    pub fn add(&mut self, r: &TickRecord) {
        self.records += 1;
        self.first_t_s.get_or_insert(r.t_s);
        self.last_t_s = r.t_s;
        self.lateness.record(r.lateness_s.max(0.0));
        self.compute.record(r.compute_s);
        self.io.record(r.io_s);
        if r.lateness_s > 1e-3 {
            self.late_over_1ms += 1;
        }
        let w = &mut self.window;
        w.records += 1;
        w.first_t_s.get_or_insert(r.t_s);
        w.last_t_s = r.t_s;
        w.lateness.record(r.lateness_s.max(0.0));
        w.last = Some(*r);
        for (i, h) in r.hands.iter().enumerate() {
            let f = h.output_n.length();
            self.max_force_n[i] = self.max_force_n[i].max(f);
            w.max_force_n[i] = w.max_force_n[i].max(f);
            for t in h.tensions_n {
                self.max_tension_n = self.max_tension_n.max(t);
                self.min_tension_n = self.min_tension_n.min(t);
            }
        }
    }

    /// Ticks per second of loop-clock time over the whole run.
    pub fn rate_hz(&self) -> f64 {
        rate_hz(self.records, self.first_t_s, self.last_t_s)
    }

    pub fn reset_window(&mut self) {
        self.window = Window::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_and_misses_are_counted() {
        let mut s = Stats::new();
        for i in 0..1000u64 {
            let r = TickRecord {
                tick: i,
                t_s: i as f64 * 1e-3,
                lateness_s: if i == 500 { 2e-3 } else { 10e-6 },
                compute_s: 1e-6,
                ..Default::default()
            };
            s.add(&r);
        }
        let p = s.lateness.percentiles();
        assert!((p.p50_s - 10e-6).abs() < 1e-7, "{p:?}");
        assert!((p.max_s - 2e-3).abs() < 1e-5);
        assert_eq!(s.late_over_1ms, 1);
        assert_eq!(s.lateness.count_above(1e-3), 1);
        assert!((s.rate_hz() - 1000.0).abs() < 1e-6);
    }

    #[test]
    fn durations_format_with_sensible_units() {
        assert_eq!(fmt_dur(850e-9), "850 ns");
        assert_eq!(fmt_dur(12.34e-6), "12.3 us");
        assert_eq!(fmt_dur(2.5e-3), "2.50 ms");
    }
}
