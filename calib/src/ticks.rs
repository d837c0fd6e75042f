//! The rt-loop as calibration reads it: one tick record after another from the loop that holds
//! the strings (`TickCore::calibrate`: Inactive for good, every string at minimum tension with
//! zero net force), each hand's counts taken only from the ticks the loop's own rules let
//! through, and a lasting loss of the board or a stop request turned into an error that ends the
//! session cleanly.
//!
//! Why it exists: calibration lasts minutes with a person's hands on the grips. It must run under
//! the same safety as `spidar run`: the same loop, the same rules for late, corrupt and garbled
//! replies (a count that steps further than a grip moves in a tick is rejected by the loop, not
//! here), the same switch-off at the end, and on real boards the same supervisor. So this module
//! only reads what the loop did: a tick whose exchange failed, whose rig was faulted, or whose
//! hand the loop held (its counts rejected) gives that hand no sample; the rest give the counts
//! the loop read. The loop runs where the caller put it: on this thread on the virtual clock
//! ([`VirtualLoop`]: the simulated rig, tests), or on its real-time thread on the real clock
//! (`spidar-runtime`'s calibration session: real boards and the board emulator).
//!
//! What it must never do: drive a device itself (no output here but the loop's), or keep a
//! session going on a board that is gone: a disconnect, or no good reply for `lost_after_s`, ends
//! it (what was recorded is kept by the caller).

use std::sync::Arc;

use spidar_device::sim::SimRig;
use spidar_device::{Device, ErrorKind};
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Command, Counters, Lifecycle, Rig, RtLoop, VirtualClock};

use crate::CalibError;

/// Polled every tick: `true` asks the session to stop (the loop ends, what was recorded kept).
pub type StopCheck = Arc<dyn Fn() -> bool + Send + Sync>;

/// Where the tick records come from: a calibrating rt-loop.
pub trait TickSource {
    /// The next tick's record, in order. Blocks until it comes (on the real clock up to a
    /// period; on the virtual clock this runs the tick). An error: the loop is gone.
    fn next_record(&mut self) -> Result<TickRecord, CalibError>;
    /// Ends the loop as `spidar run` ends it: strings at minimum tension for a few ticks, then
    /// the device off (zero on every channel). An error: the zero may not have reached the boards.
    /// Idempotent.
    fn finish(&mut self) -> Result<(), CalibError>;
}

/// A source whose device is the simulated rig, so the simulated user can move its grips
/// (`record::SimOperator`); None for boards, whose grips a person moves.
pub trait SimulatedRig {
    fn sim_rig(&mut self) -> Option<&mut SimRig>;
}

/// What one tick gave calibration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sample {
    /// Per hand: the counts of its four strings, or None when the tick's exchange failed, the
    /// rig was faulted, or the loop held the hand (its counts rejected).
    pub hands: [Option<[i64; 4]>; 2],
}

/// What the loop's records showed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoopStats {
    /// Tick records read.
    pub ticks: u64,
    /// Ticks whose exchange failed (a late, lost or corrupt reply): no sample.
    pub late_or_bad: u64,
    /// Hand-ticks the loop held for a count step (a garbled count): no sample of that hand.
    pub count_jumps: u64,
    /// Ticks the rig was faulted (a run of bad replies or count steps): no sample.
    pub faulted: u64,
    /// Longest run of ticks without a sample of either hand.
    pub longest_outage_ticks: u64,
    /// Records the loop could not hand over (the reader lagged): gaps in the tick numbers.
    pub missed: u64,
}

impl std::fmt::Display for LoopStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ticks, {} late or bad replies left out (longest outage {} ticks), {} counts the loop rejected for a \
             jump, {} ticks faulted, {} records missed",
            self.ticks, self.late_or_bad, self.longest_outage_ticks, self.count_jumps, self.faulted, self.missed
        )
    }
}

/// The loop's records as samples, with the board-lost and stop rules.
pub struct Ticks<S: TickSource> {
    source: S,
    channels: [[usize; 4]; 2],
    period_s: f64,
    lost_after_ticks: u64,
    failed_in_a_row: u64,
    outage: u64,
    last_tick: Option<u64>,
    stop: Option<StopCheck>,
    stats: LoopStats,
}

impl<S: TickSource> Ticks<S> {
    /// Reads `source`'s records for `rig`; the board counts as lost after `lost_after_s` without
    /// a good exchange.
    pub fn new(source: S, rig: &Rig, lost_after_s: f64) -> Ticks<S> {
        Ticks {
            source,
            channels: [rig.hands[0].channels, rig.hands[1].channels],
            period_s: rig.period_s,
            lost_after_ticks: (lost_after_s / rig.period_s).ceil().max(1.0) as u64,
            failed_in_a_row: 0,
            outage: 0,
            last_tick: None,
            stop: None,
            stats: LoopStats::default(),
        }
    }

    /// Polls `stop` every tick from now on.
    pub fn set_stop(&mut self, stop: StopCheck) {
        self.stop = Some(stop);
    }

    pub fn source_mut(&mut self) -> &mut S {
        &mut self.source
    }

    pub fn stats(&self) -> LoopStats {
        self.stats
    }

    /// True once a stop was asked for.
    pub fn stop_requested(&self) -> bool {
        self.stop.as_ref().is_some_and(|s| s())
    }

    /// The next tick's sample. Errors: a stop request, a lost board (disconnected, or no good
    /// exchange for `lost_after_s`), the loop gone.
    pub fn tick(&mut self) -> Result<Sample, CalibError> {
        if self.stop_requested() {
            return Err(CalibError::Interrupted("a stop signal (Ctrl-C, SIGTERM or SIGHUP)".into()));
        }
        let r = self.source.next_record()?;
        self.stats.ticks += 1;
        if let Some(last) = self.last_tick {
            self.stats.missed += r.tick.saturating_sub(last + 1);
        }
        self.last_tick = Some(r.tick);
        let sample = self.sample_of(&r);
        if sample.hands.iter().all(Option::is_none) {
            self.outage += 1;
            self.stats.longest_outage_ticks = self.stats.longest_outage_ticks.max(self.outage);
        } else {
            self.outage = 0;
        }
        match r.io_error {
            Some(ErrorKind::Disconnected) => Err(CalibError::BoardLost(
                "the device disconnected: the board is gone (unplugged, powered down, or the emulator stopped), and \
                 its counters restart when it comes back"
                    .into(),
            )),
            Some(kind) => {
                self.failed_in_a_row += 1;
                if self.failed_in_a_row >= self.lost_after_ticks {
                    return Err(CalibError::BoardLost(format!(
                        "no good reply for {} ticks ({:.1} s; last: {kind:?}): check the cable and the board's power",
                        self.failed_in_a_row,
                        self.failed_in_a_row as f64 * self.period_s
                    )));
                }
                Ok(sample)
            }
            None => {
                self.failed_in_a_row = 0;
                Ok(sample)
            }
        }
    }

    /// What `r` gives each hand, counted into the stats.
    fn sample_of(&mut self, r: &TickRecord) -> Sample {
        if r.io_error.is_some() {
            self.stats.late_or_bad += 1;
            return Sample::default();
        }
        if r.state == Lifecycle::Faulted {
            self.stats.faulted += 1;
            return Sample::default();
        }
        let mut s = Sample::default();
        for (h, slot) in s.hands.iter_mut().enumerate() {
            if r.hands[h].held {
                self.stats.count_jumps += 1;
            } else {
                *slot = Some(self.channels[h].map(|ch| r.input.counts[ch]));
            }
        }
        s
    }

    /// Ends the loop (strings at minimum tension, then the device off) and hands the source back.
    pub fn finish(mut self) -> Result<S, CalibError> {
        self.source.finish()?;
        Ok(self.source)
    }

    /// Ends the loop and keeps the source (after an error, to report it with the samples' stats).
    pub fn switch_off(&mut self) -> Result<(), CalibError> {
        self.source.finish()
    }
}

/// The calibrating loop on the caller's thread and the virtual clock: each record is one tick run
/// now, back to back. For the simulated rig (its time is its exchange count) and for a device
/// whose replies pace it (the board emulator advancing one period per command); the same tick
/// core, rules and switch-off as the real-time loop.
pub struct VirtualLoop<D: Device> {
    rt: RtLoop<D, VirtualClock>,
}

impl<D: Device> VirtualLoop<D> {
    /// Opens `dev` (unless `opened`: boards opened already with detailed errors), makes the loop
    /// calibration's and configures it: from its first tick every string at minimum tension.
    pub fn start(dev: D, rig: &Rig, opened: bool) -> Result<VirtualLoop<D>, CalibError> {
        let mut rt = RtLoop::new(dev, VirtualClock::new(), rig, spidar_rt::Endpoints::default())
            .map_err(|e| CalibError::Recording(format!("the rig cannot run its loop: {e}")))?;
        rt.calibrate();
        if opened {
            rt.configure_opened()?;
        } else {
            rt.configure()?;
        }
        Ok(VirtualLoop { rt })
    }

    /// The device (between ticks: the simulated user's hand is moved through it).
    pub fn device_mut(&mut self) -> &mut D {
        self.rt.device_mut()
    }

    /// What the loop counted.
    pub fn counters(&self) -> &Counters {
        self.rt.core().counters()
    }

    /// The device back (after `finish`), e.g. to inspect a simulated rig.
    pub fn into_device(self) -> D {
        self.rt.into_device()
    }
}

impl<D: Device> TickSource for VirtualLoop<D> {
    fn next_record(&mut self) -> Result<TickRecord, CalibError> {
        if self.rt.is_finished() {
            return Err(CalibError::Recording("the rig's loop has stopped".into()));
        }
        self.rt.tick();
        Ok(*self.rt.last_record())
    }

    fn finish(&mut self) -> Result<(), CalibError> {
        if !self.rt.is_finished() {
            self.rt.command(Command::Stop);
            while self.rt.tick() {}
        }
        match self.rt.off_error() {
            None => Ok(()),
            Some(e) => Err(e.into()),
        }
    }
}

impl SimulatedRig for VirtualLoop<SimRig> {
    fn sim_rig(&mut self) -> Option<&mut SimRig> {
        Some(self.device_mut())
    }
}
