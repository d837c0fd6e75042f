//! Telemetry: one plain record per tick, sent by the tick through a bounded channel with
//! `try_send` (dropped and counted when the consumer lags), and the statistics a non-real-time
//! thread builds from them: rate, lateness and compute-time percentiles, misses, forces.
//!
//! A record holds everything that went into the tick core from outside (device input, commands,
//! the contact model taken, a reopen) and everything that came out (volts, the hand sample,
//! forces, lifecycle, events), so a recording of the records can re-run the core bit for bit.
//!
//! Only [`TickRecord`] is touched by the tick: plain `Copy` data, no allocation. [`Stats`]
//! allocates (histograms) and lives on the consumer's thread.

use glam::DVec3;
use hdrhistogram::Histogram;
use spidar_device::{ErrorKind, Input, Output};
use spidar_msg::{ContactModel, HandSample};

use crate::control::{Command, Event, FaultReason, Lifecycle};
use crate::tension::Method;

/// One hand in one tick (rig frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandRecord {
    /// Grip position in the rig frame; `HandState::pos_world_m` is the same point in the world.
    pub pos_rig_m: DVec3,
    pub vel_rig_m_per_s: DVec3,
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
    /// A proxy stiffer than the hand's limit was softened.
    pub stiffness_limited: bool,
    /// The asked force was not finite and was replaced by zero.
    pub non_finite: bool,
    /// Energy reserve of the avatar-hand contact (J) and whether the command was scaled down
    /// to stay within it this tick (`local.rs`).
    pub reserve_j: f64,
    pub passivity_limited: bool,
    /// The landed blow's share of `output_n` (its push and burst as asked, scaled as the safety
    /// phase and the allocation scaled the whole force; `blow.rs`).
    pub blow_n: DVec3,
    /// This hand's output was held from the last tick (late, missing or rejected reply, or a
    /// pose above the residual limit): every other field repeats that tick's.
    pub held: bool,
}

impl Default for HandRecord {
    fn default() -> Self {
        HandRecord {
            pos_rig_m: DVec3::ZERO,
            vel_rig_m_per_s: DVec3::ZERO,
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
            stiffness_limited: false,
            non_finite: false,
            reserve_j: 0.0,
            passivity_limited: false,
            blow_n: DVec3::ZERO,
            held: false,
        }
    }
}

/// A few items of one tick kept in order in a fixed array; more are counted in `lost`, not kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmallLog<T: Copy, const N: usize> {
    items: [Option<T>; N],
    len: u8,
    lost: u8,
}

impl<T: Copy, const N: usize> Default for SmallLog<T, N> {
    fn default() -> Self {
        SmallLog { items: [None; N], len: 0, lost: 0 }
    }
}

impl<T: Copy, const N: usize> SmallLog<T, N> {
    /// Appends `x`, or counts it as lost when full.
    pub fn push(&mut self, x: T) {
        match self.items.get_mut(self.len as usize) {
            Some(slot) => {
                *slot = Some(x);
                self.len += 1;
            }
            None => self.lost = self.lost.saturating_add(1),
        }
    }
    pub fn iter(&self) -> impl Iterator<Item = T> + '_ {
        self.items.iter().take(self.len as usize).flatten().copied()
    }
    pub fn len(&self) -> usize {
        self.len as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Items that did not fit.
    pub fn lost(&self) -> u8 {
        self.lost
    }
    /// Takes the items out, leaving the log empty.
    pub fn take(&mut self) -> Self {
        std::mem::take(self)
    }
    /// Restores a lost count (decoding a recording).
    pub fn set_lost(&mut self, lost: u8) {
        self.lost = lost;
    }
}

/// Commands kept per tick in a record.
pub const RECORD_COMMANDS: usize = 8;
/// Events kept per tick in a record.
pub const RECORD_EVENTS: usize = 8;
pub type CommandLog = SmallLog<Command, RECORD_COMMANDS>;
pub type EventLog = SmallLog<Event, RECORD_EVENTS>;

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
    // What went into the core from outside, in the order the loop gives it (commands, the model,
    // a reopen, then the step with the device's input):
    /// Commands the core received since the previous tick, in order.
    pub commands: CommandLog,
    /// The contact model the core took just before this step (None: it kept the one it had).
    pub model: Option<ContactModel>,
    /// The device was reopened after a disconnect just before this step.
    pub reopened: bool,
    /// Kind of the device exchange's error this tick (None: the exchange succeeded).
    pub io_error: Option<ErrorKind>,
    /// What the device read (counters, status), as given to the core.
    pub input: Input,
    // What came out:
    /// DA volts computed by this tick (written at the next exchange).
    pub output: Output,
    /// The sample sent to the world this tick.
    pub sample: HandSample,
    /// What the core and the loop reported during this tick, in order.
    pub events: EventLog,
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
    /// Adds every value of `other` (benchmarks that pool blocks).
    pub fn merge(&mut self, other: &DurationHist) {
        let _ = self.h.add(&other.h);
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
    fn small_log_keeps_order_and_counts_what_does_not_fit() {
        let mut l: SmallLog<u32, 3> = SmallLog::default();
        for i in 0..5 {
            l.push(i);
        }
        assert_eq!(l.iter().collect::<Vec<_>>(), vec![0, 1, 2]);
        assert_eq!((l.len(), l.lost()), (3, 2));
        let taken = l.take();
        assert!(l.is_empty() && l.lost() == 0);
        assert_eq!(taken.len(), 3);
    }

    #[test]
    fn durations_format_with_sensible_units() {
        assert_eq!(fmt_dur(850e-9), "850 ns");
        assert_eq!(fmt_dur(12.34e-6), "12.3 us");
        assert_eq!(fmt_dur(2.5e-3), "2.50 ms");
    }
}
