//! The loop around a [`TickCore`]: wait for the absolute deadline, take commands and the newest
//! contact model, exchange with the device, compute, publish the hand sample and the telemetry.
//!
//! Channels are bounded and used only with `try_send`/`try_recv` on this side, so the tick never
//! blocks and never allocates. The other side must *poll* too (never block in `recv` on a
//! channel this loop sends to): crossbeam wakes a blocked receiver through a mutex, and this loop
//! must take no lock. The consumers in `spidar` poll at a few milliseconds.
//!
//! Deadlines advance by exactly one period; if the loop falls more than `MAX_BEHIND` periods
//! behind (the machine stalled), the deadline is re-based on now and the skipped periods are
//! counted as misses, rather than running a burst of catch-up ticks into the user's hand.

use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use spidar_device::{Device, DeviceError, ErrorKind, Input, Output};
use spidar_msg::{ContactModel, HandSample};

use crate::clock::Clock;
use crate::rig::Rig;
use crate::telemetry::TickRecord;
use crate::tick::{Command, Event, Lifecycle, TickCore};

const MAX_BEHIND: u64 = 10;
/// Ticks at minimum tension after the ramp-out, before the device is switched off.
const STOP_HOLD_TICKS: u32 = 20;
/// Exchanges tried when priming the counters at start before a late or corrupt reply fails it.
pub const PRIME_TRIES: u32 = 10;

/// The loop's ends of its channels. Any of them may be absent.
#[derive(Default)]
pub struct Endpoints {
    pub commands: Option<Receiver<Command>>,
    pub events: Option<Sender<Event>>,
    pub models: Option<Receiver<ContactModel>>,
    pub samples: Option<Sender<HandSample>>,
    pub telemetry: Option<Sender<TickRecord>>,
}

/// Bounded channel capacities used by [`Endpoints::pair`].
pub const COMMAND_CAPACITY: usize = 16;
pub const EVENT_CAPACITY: usize = 64;
pub const MODEL_CAPACITY: usize = 8;
pub const SAMPLE_CAPACITY: usize = 64;
pub const TELEMETRY_CAPACITY: usize = 4096;

/// The far ends of the channels, for the control side, the scene and the telemetry consumer.
pub struct FarEnds {
    pub commands: Sender<Command>,
    pub events: Receiver<Event>,
    pub models: Sender<ContactModel>,
    pub samples: Receiver<HandSample>,
    pub telemetry: Receiver<TickRecord>,
}

impl Endpoints {
    /// Creates every channel with the default capacities.
    pub fn pair() -> (Endpoints, FarEnds) {
        use crossbeam_channel::bounded;
        let (ct, cr) = bounded(COMMAND_CAPACITY);
        let (et, er) = bounded(EVENT_CAPACITY);
        let (mt, mr) = bounded(MODEL_CAPACITY);
        let (st, sr) = bounded(SAMPLE_CAPACITY);
        let (tt, tr) = bounded(TELEMETRY_CAPACITY);
        (
            Endpoints {
                commands: Some(cr),
                events: Some(et),
                models: Some(mr),
                samples: Some(st),
                telemetry: Some(tt),
            },
            FarEnds { commands: ct, events: er, models: mt, samples: sr, telemetry: tr },
        )
    }
}

/// A device, a clock and a tick core, run as a loop.
pub struct RtLoop<D: Device, C: Clock> {
    dev: D,
    clock: C,
    core: TickCore,
    ep: Endpoints,
    out: Output,
    inp: Input,
    period_ns: u64,
    deadline_ns: u64,
    configured: bool,
    stopping: bool,
    stop_hold: u32,
    finished: bool,
    last: TickRecord,
    /// The device reported a disconnect and has not been reopened yet.
    disconnected: bool,
    /// Ticks between reopen attempts (0: never) and until the next one.
    reopen_every: u32,
    reopen_wait: u32,
    reopen_budget: Duration,
}

impl<D: Device, C: Clock> RtLoop<D, C> {
    pub fn new(dev: D, clock: C, rig: &Rig, ep: Endpoints) -> Result<RtLoop<D, C>, crate::RtError> {
        let core = TickCore::new(rig)?;
        let period_ns = (rig.period_s * 1e9).round() as u64;
        Ok(RtLoop {
            dev,
            clock,
            core,
            ep,
            out: Output::default(),
            inp: Input::default(),
            period_ns,
            deadline_ns: 0,
            configured: false,
            stopping: false,
            stop_hold: 0,
            finished: false,
            last: TickRecord::default(),
            disconnected: false,
            reopen_every: (rig.safety.device_reopen_s / rig.period_s).round() as u32,
            reopen_wait: 0,
            // Half a tick: the attempt, the compute and the sleep must all fit in the period.
            reopen_budget: Duration::from_secs_f64(rig.period_s * 0.5),
        })
    }

    /// Unconfigured -> Inactive: opens and powers the device, reads the counters once, and sets the
    /// first deadline one period from now. Not real-time; call before the first tick.
    pub fn configure(&mut self) -> Result<(), DeviceError> {
        self.dev.open()?;
        self.dev.activate()?;
        // Prime with zero output and one read so the first tick starts from real counts. A late
        // or garbled reply is no reason to give up here either: a few more tries.
        self.out = Output::default();
        let mut tries = 1;
        while let Err(e) = self.dev.exchange(&self.out, &mut self.inp) {
            if !matches!(e.kind(), ErrorKind::Timeout | ErrorKind::Corrupt) || tries >= PRIME_TRIES {
                return Err(e);
            }
            tries += 1;
        }
        self.core.observe_counts(&self.inp);
        self.configured = true;
        self.deadline_ns = self.clock.now_ns() + self.period_ns;
        Ok(())
    }

    pub fn state(&self) -> Lifecycle {
        if self.configured {
            self.core.state()
        } else {
            Lifecycle::Unconfigured
        }
    }
    pub fn core(&self) -> &TickCore {
        &self.core
    }
    pub fn device(&self) -> &D {
        &self.dev
    }
    pub fn device_mut(&mut self) -> &mut D {
        &mut self.dev
    }
    pub fn clock(&self) -> &C {
        &self.clock
    }
    /// The record of the last tick.
    pub fn last_record(&self) -> &TickRecord {
        &self.last
    }
    pub fn is_finished(&self) -> bool {
        self.finished
    }
    /// Applies a command directly (tests and single-threaded drivers; the channel does the same).
    pub fn command(&mut self, c: Command) {
        if c == Command::Stop {
            self.stopping = true;
        }
        self.core.command(c);
    }

    /// One tick: sleep to the deadline, then read, compute, write. Returns false once the loop
    /// has stopped. Never allocates, locks or panics.
    pub fn tick(&mut self) -> bool {
        if self.finished || !self.configured {
            return false;
        }
        let wake = self.clock.sleep_until(self.deadline_ns);
        let lateness_ns = wake.saturating_sub(self.deadline_ns);

        while let Some(c) = self.ep.commands.as_ref().and_then(|r| r.try_recv().ok()) {
            self.command(c);
        }
        let mut newest = None;
        while let Some(m) = self.ep.models.as_ref().and_then(|r| r.try_recv().ok()) {
            newest = Some(m);
        }
        if let Some(m) = newest {
            self.core.set_contact_model(m);
        }

        let t_io = Instant::now();
        let io = if self.disconnected {
            self.try_reopen()
        } else {
            let r = self.dev.exchange(&self.out, &mut self.inp);
            if r.is_err_and(|e| e.kind() == ErrorKind::Disconnected) {
                self.disconnected = true;
                self.reopen_wait = self.reopen_every;
            }
            r
        };
        let io_s = t_io.elapsed().as_secs_f64();

        let t_compute = Instant::now();
        let mut sample = HandSample::default();
        let mut rec = TickRecord::default();
        self.core.step(wake as f64 * 1e-9, io, &self.inp, &mut self.out, &mut sample, &mut rec);
        let compute_s = t_compute.elapsed().as_secs_f64();

        rec.lateness_s = lateness_ns as f64 * 1e-9;
        rec.compute_s = compute_s;
        rec.io_s = io_s;
        if lateness_ns > self.period_ns {
            self.core.counters_mut().misses += 1;
        }
        if let Some(tx) = self.ep.samples.as_ref() {
            if let Err(TrySendError::Full(_)) = tx.try_send(sample) {
                self.core.counters_mut().samples_dropped += 1;
            }
        }
        if let Some(tx) = self.ep.telemetry.as_ref() {
            if let Err(TrySendError::Full(_)) = tx.try_send(rec) {
                self.core.counters_mut().telemetry_dropped += 1;
            }
        }
        self.last = rec;

        if self.stopping && self.core.is_quiet() {
            self.stop_hold += 1;
            if self.stop_hold >= STOP_HOLD_TICKS {
                // Strings have been at minimum tension with zero net force; now switch off.
                let _ = self.dev.deactivate();
                self.finished = true;
                self.core_event(Event::Stopped);
            }
        }
        while let Some(e) = self.core.pop_event() {
            self.core_event(e);
        }

        self.deadline_ns += self.period_ns;
        let now = if self.clock.is_virtual() { wake } else { self.clock.now_ns() };
        if now > self.deadline_ns + MAX_BEHIND * self.period_ns {
            let skipped = (now - self.deadline_ns) / self.period_ns;
            self.core.counters_mut().misses += skipped;
            self.deadline_ns += skipped * self.period_ns;
        }
        !self.finished
    }

    /// While disconnected: every `reopen_every` ticks, one bounded reopen attempt instead of the
    /// exchange. The tick itself still counts as failed (nothing was read); the next one exchanges.
    fn try_reopen(&mut self) -> Result<(), DeviceError> {
        const WAITING: DeviceError = DeviceError::Disconnected { what: "waiting to reopen the device" };
        if self.reopen_every == 0 {
            return Err(WAITING);
        }
        if self.reopen_wait > 0 {
            self.reopen_wait -= 1;
            return Err(WAITING);
        }
        self.reopen_wait = self.reopen_every;
        self.core.counters_mut().reopen_attempts += 1;
        match self.dev.reopen(self.reopen_budget) {
            Ok(()) => {
                self.disconnected = false;
                self.core.device_reopened();
                Err(DeviceError::Disconnected { what: "device reopened: exchanging from the next tick" })
            }
            Err(e) => Err(e),
        }
    }

    fn core_event(&mut self, e: Event) {
        if let Some(tx) = self.ep.events.as_ref() {
            if tx.try_send(e).is_err() {
                self.core.counters_mut().events_dropped += 1;
            }
        }
    }

    /// Sets the next deadline one period from now (after the caller paused the loop on purpose,
    /// e.g. a benchmark alternating with another loop), so the pause is not counted as misses.
    pub fn resync(&mut self) {
        self.deadline_ns = self.clock.now_ns() + self.period_ns;
    }

    /// Ticks until stopped.
    pub fn run(&mut self) {
        while self.tick() {}
    }

    /// Gives the device back (after the loop finished), e.g. to inspect a simulated rig.
    pub fn into_device(self) -> D {
        self.dev
    }
}
