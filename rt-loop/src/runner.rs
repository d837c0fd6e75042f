//! The loop around a [`TickCore`]: wait for the absolute deadline, take commands and the newest
//! contact model, exchange with the device, compute, publish the hand sample and the telemetry.
//!
//! The world is reached through a [`RigLink`] (`spidar-link`): bounded channels to a world
//! thread in this process, or datagrams to a world process. Either way the loop only polls it and
//! hands it the tick's sample (and every `STATUS_EVERY` ticks a status): it never blocks, never
//! allocates. The control side's channels are bounded and used only with `try_send`/`try_recv`
//! here; the other side must *poll* too (never block in `recv` on a channel this loop sends to):
//! crossbeam wakes a blocked receiver through a mutex, and this loop must take no lock. The
//! consumers in `spidar` poll at a few milliseconds.
//!
//! A model stamped in the loop's future is taken as stamped now, whatever link it came by: a
//! wrong stamp must never keep a model fresh past the staleness fade.
//!
//! A sample the link cannot take (the world is not draining: a full socket queue or channel) is
//! not the end of its impulses: they are carried into the next sample of the same model, or sent
//! on their own first when the model changed, so the world gets every impulse the rig applied
//! while it stalled. Only what still cannot go is counted lost.
//!
//! Deadlines advance by exactly one period; if the loop falls more than `MAX_BEHIND` periods
//! behind (the machine stalled), the deadline is re-based on now and the skipped periods are
//! counted as misses, rather than running a burst of catch-up ticks into the user's hand.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use spidar_device::{Device, DeviceError, ErrorKind, Input, Output};
use spidar_link::{channel, RigLink, Sent};
use spidar_msg::{ContactModel, HandSample, RigStatus};

use crate::clock::Clock;
use crate::rig::Rig;
use crate::status::{StatusWindow, STATUS_EVERY};
use crate::telemetry::{CommandLog, TickRecord};
use crate::tick::{Command, Event, Lifecycle, TickCore};

const MAX_BEHIND: u64 = 10;
/// Ticks at minimum tension after the ramp-out, before the device is switched off.
const STOP_HOLD_TICKS: u32 = 20;
/// Exchanges tried when priming the counters at start before a late or corrupt reply fails it.
pub const PRIME_TRIES: u32 = 10;

/// What the loop shares without a lock or a system call with whoever watches it: a heartbeat it
/// writes every tick (a supervising process reads it to tell a running loop from a dead or hung
/// one) and a flag that stops it at once. Plain atomics in a `#[repr(C)]` struct, so it can live
/// in memory shared with another process.
#[repr(C)]
#[derive(Debug, Default)]
pub struct Lifeline {
    /// 0 before the first tick; then the ticks done so far; [`Lifeline::DONE`] once the loop has
    /// ended with the device switched off.
    pub beat: AtomicU64,
    /// Non-zero: stop at the next tick without the ramp-out: outputs zeroed, device switched off
    /// (the second stop signal).
    pub halt: AtomicU32,
}

impl Lifeline {
    /// The beat of a loop that has ended with its device switched off.
    pub const DONE: u64 = u64::MAX;

    /// Asks the loop to stop at once with its outputs zeroed.
    pub fn halt(&self) {
        self.halt.store(1, Ordering::SeqCst);
    }

    /// The loop has ended and switched its device off.
    pub fn done(&self) -> bool {
        self.beat.load(Ordering::Acquire) == Self::DONE
    }
}

/// The loop's ends of its channels and its link to the world. Any of them may be absent.
#[derive(Default)]
pub struct Endpoints {
    pub commands: Option<Receiver<Command>>,
    pub events: Option<Sender<Event>>,
    /// The world: a channel link from [`Endpoints::pair`], or a socket link put in its place.
    pub link: Option<Box<dyn RigLink>>,
    pub telemetry: Option<Sender<TickRecord>>,
    /// The heartbeat and the halt flag (leaked or in a shared page: it outlives the loop).
    pub lifeline: Option<&'static Lifeline>,
}

/// Bounded channel capacities used by [`Endpoints::pair`] (the link's are in `spidar_link::channel`).
pub const COMMAND_CAPACITY: usize = 16;
pub const EVENT_CAPACITY: usize = 64;
pub const TELEMETRY_CAPACITY: usize = 4096;

/// The far ends of the channels, for the control side, an in-process world and the telemetry
/// consumer. With a socket link in place of the channel link, `models`, `samples` and `status`
/// lead nowhere.
pub struct FarEnds {
    pub commands: Sender<Command>,
    pub events: Receiver<Event>,
    pub models: Sender<ContactModel>,
    pub samples: Receiver<HandSample>,
    pub status: Receiver<RigStatus>,
    pub telemetry: Receiver<TickRecord>,
}

impl Endpoints {
    /// Creates every channel with the default capacities; the world is an in-process channel link.
    pub fn pair() -> (Endpoints, FarEnds) {
        use crossbeam_channel::bounded;
        let (ct, cr) = bounded(COMMAND_CAPACITY);
        let (et, er) = bounded(EVENT_CAPACITY);
        let (tt, tr) = bounded(TELEMETRY_CAPACITY);
        let (link, world) = channel::pair();
        (
            Endpoints {
                commands: Some(cr),
                events: Some(et),
                link: Some(Box::new(link)),
                telemetry: Some(tt),
                lifeline: None,
            },
            FarEnds {
                commands: ct,
                events: er,
                models: world.models,
                samples: world.samples,
                status: world.status,
                telemetry: tr,
            },
        )
    }
}

/// Sends `s`, with the impulses of an earlier sample the link could not take (`carry`).
fn send_with_carry(
    link: &mut dyn RigLink,
    mut s: HandSample,
    carry: &mut Option<HandSample>,
    c: &mut crate::tick::Counters,
) {
    if let Some(old) = carry.take() {
        if old.model_seq == s.model_seq {
            for (a, b) in s.proxy_impulse_n_s.iter_mut().zip(old.proxy_impulse_n_s.iter()) {
                *a += *b;
            }
            for (a, b) in s.proxy_contact_impulse_n_s.iter_mut().zip(old.proxy_contact_impulse_n_s.iter()) {
                *a += *b;
            }
        } else if link.send_sample(&old) != Sent::Queued {
            c.impulses_lost += 1; // of another model, and still no way through
        }
    }
    match link.send_sample(&s) {
        Sent::Queued => {}
        Sent::Dropped => {
            c.samples_dropped += 1;
            *carry = Some(s);
        }
        Sent::NoPeer => {
            if s.proxy_impulse_n_s
                .iter()
                .chain(s.proxy_contact_impulse_n_s.iter())
                .any(|i| *i != glam::DVec3::ZERO)
            {
                c.impulses_lost += 1;
            }
        }
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
    /// Commands applied since the last tick, for its record.
    pending_commands: CommandLog,
    /// The device was reopened in this tick (for its record).
    reopened_now: bool,
    /// Ticks between reopen attempts (0: never) and until the next one.
    reopen_every: u32,
    reopen_wait: u32,
    reopen_budget: Duration,
    status: StatusWindow,
    /// A sample the link could not take, waiting to go with the next one.
    carry: Option<HandSample>,
    /// Ticks done, for the heartbeat.
    beats: u64,
    /// Stopped at once by the lifeline's halt flag (no ramp-out).
    halted: bool,
    /// What the switch-off at the end said, if it failed (the zero may not have reached the boards).
    off_error: Option<DeviceError>,
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
            pending_commands: CommandLog::default(),
            reopened_now: false,
            reopen_every: (rig.safety.device_reopen_s / rig.period_s).round() as u32,
            reopen_wait: 0,
            // Half a tick: the attempt, the compute and the sleep must all fit in the period.
            reopen_budget: Duration::from_secs_f64(rig.period_s * 0.5),
            status: StatusWindow::default(),
            carry: None,
            beats: 0,
            halted: false,
            off_error: None,
        })
    }

    /// Unconfigured -> Inactive: opens and powers the device, reads the counters once, and sets the
    /// first deadline one period from now. Not real-time; call before the first tick.
    pub fn configure(&mut self) -> Result<(), DeviceError> {
        self.dev.open()?;
        self.configure_opened()
    }

    /// As [`RtLoop::configure`] for a device opened already (boards opened with detailed errors:
    /// opening them again would enumerate them twice).
    pub fn configure_opened(&mut self) -> Result<(), DeviceError> {
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
    /// The loop was stopped at once by the lifeline's halt flag: outputs zeroed, no ramp-out.
    pub fn halted(&self) -> bool {
        self.halted
    }
    /// The device's error when the loop switched it off at its end (None: it said it did).
    pub fn off_error(&self) -> Option<DeviceError> {
        self.off_error
    }
    /// Makes this the calibration's loop (`TickCore::calibrate`): Inactive for good, strings at
    /// minimum tension, counts checked step by step. Before the first tick.
    pub fn calibrate(&mut self) {
        self.core.calibrate();
    }
    /// Gives the loop a heartbeat and halt flag (before it runs; `Endpoints::lifeline` does the same).
    pub fn set_lifeline(&mut self, lifeline: &'static Lifeline) {
        self.ep.lifeline = Some(lifeline);
    }
    /// Applies a command directly (tests and single-threaded drivers; the channel does the same).
    pub fn command(&mut self, c: Command) {
        if c == Command::Stop {
            self.stopping = true;
        }
        self.pending_commands.push(c);
        self.core.command(c);
    }

    /// One tick: sleep to the deadline, then read, compute, write. Returns false once the loop
    /// has stopped. Never allocates, locks or panics.
    pub fn tick(&mut self) -> bool {
        if self.finished || !self.configured {
            return false;
        }
        if self.ep.lifeline.is_some_and(|l| l.halt.load(Ordering::Relaxed) != 0) {
            self.halt();
            return false;
        }
        let wake = self.clock.sleep_until(self.deadline_ns);
        let lateness_ns = wake.saturating_sub(self.deadline_ns);

        while let Some(c) = self.ep.commands.as_ref().and_then(|r| r.try_recv().ok()) {
            self.command(c);
        }
        let now_s = wake as f64 * 1e-9;
        // The model as the core takes it (restamped), for the record.
        let mut taken = None;
        if let Some(mut m) = self.ep.link.as_mut().and_then(|l| l.poll(now_s)) {
            if m.stamp_s > now_s {
                m.stamp_s = now_s;
            }
            self.core.set_contact_model(m);
            taken = Some(m);
        }
        self.reopened_now = false;

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

        // The record is built in place (`last`) and copied once, into the telemetry channel.
        self.last = TickRecord::default();
        let mut sample = HandSample::default();
        let t_compute = Instant::now();
        self.core.step(now_s, io, &self.inp, &mut self.out, &mut sample, &mut self.last);
        let compute_s = t_compute.elapsed().as_secs_f64();

        let rec = &mut self.last;
        rec.lateness_s = lateness_ns as f64 * 1e-9;
        rec.compute_s = compute_s;
        rec.io_s = io_s;
        // What went in and came out, so a recording can re-run the core (see telemetry).
        rec.commands = self.pending_commands.take();
        rec.model = taken;
        rec.reopened = self.reopened_now;
        rec.io_error = io.err().map(|e| e.kind());
        rec.input = self.inp;
        rec.output = self.out;
        rec.sample = sample;
        if lateness_ns > self.period_ns {
            self.core.counters_mut().misses += 1;
        }
        self.status.add(rec);
        if let Some(link) = self.ep.link.as_mut() {
            let c = self.core.counters_mut();
            send_with_carry(&mut **link, sample, &mut self.carry, c);
            if rec.tick.is_multiple_of(STATUS_EVERY) {
                let st = self.status.status(rec, self.core.counters(), self.stopping, self.core.rig());
                link.send_status(&st);
            }
        }
        if self.stopping && self.core.is_quiet() {
            self.stop_hold += 1;
            if self.stop_hold >= STOP_HOLD_TICKS {
                // Strings have been at minimum tension with zero net force; now switch off.
                self.off_error = self.dev.deactivate().err();
                self.finished = true;
                if let Some(link) = self.ep.link.as_mut() {
                    link.close();
                }
                self.last.events.push(Event::Stopped);
            }
        }
        while let Some(e) = self.core.pop_event() {
            self.core_event(e);
            self.last.events.push(e);
        }
        if let Some(tx) = self.ep.telemetry.as_ref() {
            if let Err(TrySendError::Full(_)) = tx.try_send(self.last) {
                self.core.counters_mut().telemetry_dropped += 1;
            }
        }
        // `Stopped` goes out after the last record, so whoever waits for it has every record.
        if self.finished {
            self.core_event(Event::Stopped);
        }

        self.beat();

        self.deadline_ns += self.period_ns;
        let now = if self.clock.is_virtual() { wake } else { self.clock.now_ns() };
        if now > self.deadline_ns + MAX_BEHIND * self.period_ns {
            let skipped = (now - self.deadline_ns) / self.period_ns;
            self.core.counters_mut().misses += skipped;
            self.deadline_ns += skipped * self.period_ns;
        }
        !self.finished
    }

    /// Writes the heartbeat: the ticks done, or `DONE` once the device is off. One atomic store.
    fn beat(&mut self) {
        self.beats += 1;
        if let Some(l) = self.ep.lifeline {
            l.beat.store(if self.finished { Lifeline::DONE } else { self.beats }, Ordering::Release);
        }
    }

    /// Stops at once: zero output, device off, the world told goodbye (the second stop signal).
    fn halt(&mut self) {
        self.out = Output::default();
        self.off_error = self.dev.deactivate().err();
        self.finished = true;
        self.halted = true;
        if let Some(link) = self.ep.link.as_mut() {
            link.close();
        }
        self.core_event(Event::Stopped);
        self.beat();
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
                self.reopened_now = true;
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

    /// The link to the world (to inspect or wait on it between ticks).
    pub fn link(&self) -> Option<&dyn RigLink> {
        self.ep.link.as_deref()
    }

    /// Puts another link to the world in place (between ticks; a benchmark switching worlds) and
    /// returns the one it replaces.
    pub fn replace_link(&mut self, link: Option<Box<dyn RigLink>>) -> Option<Box<dyn RigLink>> {
        self.carry = None;
        std::mem::replace(&mut self.ep.link, link)
    }

    /// Gives the device back (after the loop finished), e.g. to inspect a simulated rig.
    pub fn into_device(self) -> D {
        self.dev
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// A link whose way is full for the first `full` sends; it keeps what got through.
    struct Narrow {
        full: u32,
        got: Vec<HandSample>,
    }
    impl RigLink for Narrow {
        fn poll(&mut self, _: f64) -> Option<ContactModel> {
            None
        }
        fn send_sample(&mut self, s: &HandSample) -> Sent {
            if self.full > 0 {
                self.full -= 1;
                return Sent::Dropped;
            }
            self.got.push(*s);
            Sent::Queued
        }
        fn send_status(&mut self, _: &RigStatus) {}
    }

    fn sample(tick: u64, model_seq: u64, x: f64) -> HandSample {
        let mut s = HandSample { tick, model_seq, ..Default::default() };
        s.proxy_impulse_n_s[1] = DVec3::X * x;
        s.proxy_contact_impulse_n_s[2] = DVec3::Y * x;
        s
    }

    /// A board that keeps what it was last told.
    struct Recorder {
        info: spidar_device::DeviceInfo,
        last: Output,
        active: bool,
        deactivations: u32,
    }
    impl Default for Recorder {
        fn default() -> Self {
            let info = spidar_device::DeviceInfo {
                board: Default::default(),
                identity: Default::default(),
                channels: 8,
                volts_min: -10.0,
                volts_max: 10.0,
            };
            Recorder { info, last: Output::default(), active: false, deactivations: 0 }
        }
    }
    impl Device for Recorder {
        fn open(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn activate(&mut self) -> Result<(), DeviceError> {
            self.active = true;
            Ok(())
        }
        fn deactivate(&mut self) -> Result<(), DeviceError> {
            self.active = false;
            self.deactivations += 1;
            self.last = Output::default();
            Ok(())
        }
        fn exchange(&mut self, out: &Output, _: &mut Input) -> Result<(), DeviceError> {
            self.last = *out;
            Ok(())
        }
        fn info(&self) -> &spidar_device::DeviceInfo {
            &self.info
        }
    }

    #[test]
    fn the_heartbeat_counts_ticks_and_the_halt_flag_zeroes_the_outputs_at_once() {
        let lifeline: &'static Lifeline = Box::leak(Box::default());
        let rig = Rig::default_rig();
        let ep = Endpoints { lifeline: Some(lifeline), ..Endpoints::default() };
        let mut rt = RtLoop::new(Recorder::default(), crate::VirtualClock::new(), &rig, ep).unwrap();
        rt.configure().unwrap();
        assert_eq!(lifeline.beat.load(Ordering::SeqCst), 0, "no beat before the first tick");
        for _ in 0..50 {
            assert!(rt.tick());
        }
        assert_eq!(lifeline.beat.load(Ordering::SeqCst), 50);
        // Inactive: the strings are held at minimum tension.
        assert!(rt.device().last.volts.iter().any(|v| *v > 0.1), "{:?}", rt.device().last);
        lifeline.halt();
        assert!(!rt.tick(), "the halted loop ends on its next tick");
        assert!(rt.is_finished() && rt.halted());
        assert_eq!(rt.device().last, Output::default());
        assert!(!rt.device().active && rt.device().deactivations == 1);
        assert!(lifeline.done());
        assert!(!rt.tick());
    }

    #[test]
    fn a_clean_stop_ends_the_heartbeat_with_done_after_the_device_is_off() {
        let lifeline: &'static Lifeline = Box::leak(Box::default());
        let rig = Rig::default_rig();
        let mut rt =
            RtLoop::new(Recorder::default(), crate::VirtualClock::new(), &rig, Endpoints::default()).unwrap();
        rt.set_lifeline(lifeline);
        rt.configure().unwrap();
        rt.command(Command::Stop);
        let mut ticks = 0;
        while rt.tick() {
            ticks += 1;
            assert!(ticks < 100_000, "the stop never ended");
            assert!(!lifeline.done(), "not done while the device is on");
            assert!(rt.device().active);
        }
        assert!(ticks >= STOP_HOLD_TICKS - 1 && !rt.halted());
        assert!(lifeline.done() && !rt.device().active);
    }

    #[test]
    fn impulses_of_samples_the_link_could_not_take_go_with_the_next_one() {
        let mut link = Narrow { full: 3, got: Vec::new() };
        let (mut carry, mut c) = (None, crate::tick::Counters::default());
        for tick in 0..5 {
            send_with_carry(&mut link, sample(tick, 7, 1.0), &mut carry, &mut c);
        }
        // Ticks 0-2 did not fit; tick 3 carried their impulses, tick 4 its own.
        assert_eq!(link.got.iter().map(|s| s.tick).collect::<Vec<_>>(), [3, 4]);
        assert_eq!(link.got[0].proxy_impulse_n_s[1], DVec3::X * 4.0);
        assert_eq!(link.got[0].proxy_contact_impulse_n_s[2], DVec3::Y * 4.0);
        assert_eq!(link.got[1].proxy_impulse_n_s[1], DVec3::X);
        assert_eq!((c.samples_dropped, c.impulses_lost), (3, 0));

        // The model changes while a sample waits: the old one goes first, on its own.
        let mut link = Narrow { full: 1, got: Vec::new() };
        let (mut carry, mut c) = (None, crate::tick::Counters::default());
        send_with_carry(&mut link, sample(0, 7, 1.0), &mut carry, &mut c);
        send_with_carry(&mut link, sample(1, 8, 2.0), &mut carry, &mut c);
        assert_eq!(link.got.iter().map(|s| (s.tick, s.model_seq)).collect::<Vec<_>>(), [(0, 7), (1, 8)]);
        assert_eq!(link.got[1].proxy_impulse_n_s[1], DVec3::X * 2.0);
        assert_eq!(c.impulses_lost, 0);

        // ... unless the way is still full: then that one is counted lost.
        let mut link = Narrow { full: 2, got: Vec::new() };
        let (mut carry, mut c) = (None, crate::tick::Counters::default());
        send_with_carry(&mut link, sample(0, 7, 1.0), &mut carry, &mut c);
        send_with_carry(&mut link, sample(1, 8, 2.0), &mut carry, &mut c);
        assert_eq!(link.got.iter().map(|s| s.tick).collect::<Vec<_>>(), [1]);
        assert_eq!(c.impulses_lost, 1);
    }
}
