//! The calibration session: `spidar calib` as a client of the same rt-loop `spidar run` uses.
//! The loop, calibrating (`TickCore::calibrate`: Inactive for good, every string at minimum
//! tension with zero net force, the loop's rules for late, corrupt and garbled replies), drives
//! the device; calibration reads its tick records (`spidar_calib::ticks`).
//!
//! Two ways, as for a run:
//! - real boards (and the board emulator): [`LiveLoop`], the loop on its real-time thread on the
//!   real clock, its records through the telemetry channel, and the same supervisor process as
//!   `spidar run` watching it ([`supervise_boards`]): if the calibration process dies or hangs
//!   while its loop drives the boards, the supervisor writes zero to them;
//! - the simulated rig: `spidar_calib::ticks::VirtualLoop`, the same loop on the calling thread on
//!   the virtual clock (the simulated rig's time is its exchange count; a session takes seconds).
//!
//! What it must never do: drive a device outside the loop, or return from `finish` before the
//! loop has switched the device off (or the second stop signal halted it, zero on every channel).

use std::collections::VecDeque;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use crossbeam_channel::{Receiver, Sender, TryRecvError};
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_calib::ticks::{SimulatedRig, TickSource, VirtualLoop};
use spidar_calib::CalibError;
use spidar_device::sim::SimRig;
use spidar_device::{Device, DeviceError};
use spidar_rt::rt_thread::{self, RtOptions, RtReport};
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Command, Counters, Endpoints, Lifeline, MonotonicClock, Rig, RtLoop};

use crate::hardware::{self, DeviceKind, HardwareArgs};
use crate::rigpath::RigSource;
use crate::signals::Stop;
use crate::supervisor::{self, Shared};

/// How long the loop may take to end after it was told to (it needs about 20 ticks).
const STOP_WITHIN: Duration = Duration::from_secs(5);

type Handle = JoinHandle<(RtReport, RtLoop<Box<dyn Device>, MonotonicClock>)>;

/// The calibrating loop on its real-time thread, on the real clock.
pub struct LiveLoop {
    handle: Option<Handle>,
    commands: Sender<Command>,
    telemetry: Receiver<TickRecord>,
    pending: VecDeque<TickRecord>,
    lifeline: &'static Lifeline,
    stop: Stop,
    /// Once the loop has ended: what its thread obtained, what it counted, its switch-off.
    report: Option<RtReport>,
    counters: Option<Counters>,
    off_error: Option<DeviceError>,
}

impl LiveLoop {
    /// Starts the loop on `dev` (opened already): calibrating, configured (strings at minimum
    /// tension from its first tick), on a thread set up as `rt` asks. A second stop signal in
    /// `stop` halts it at once (zero on every channel). Under a supervisor (`page`) the loop's
    /// heartbeat is the page's and the boards count as driven from here on.
    pub fn start(
        dev: Box<dyn Device>,
        rig: &Rig,
        rt: &RtOptions,
        stop: Stop,
        page: Option<&'static Shared>,
    ) -> anyhow::Result<LiveLoop> {
        let (mut ep, far) = Endpoints::pair();
        // No world, no events: calibration reads the records.
        ep.link = None;
        ep.events = None;
        let lifeline: &'static Lifeline = match page {
            Some(s) => &s.lifeline,
            None => Box::leak(Box::default()),
        };
        ep.lifeline = Some(lifeline);
        let mut rt_loop = RtLoop::new(dev, MonotonicClock::new(), rig, ep)?;
        rt_loop.calibrate();
        rt_loop.configure_opened().map_err(|e| anyhow::anyhow!("starting the loop on the device: {e}"))?;
        if let Some(s) = page {
            s.set_driving();
        }
        let opts = rt.clone();
        let handle = std::thread::Builder::new()
            .name("spidar-rt".into())
            .spawn(move || {
                let report = rt_thread::setup_current_thread(&opts);
                rt_loop.run();
                (report, rt_loop)
            })
            .context("starting the real-time thread")?;
        Ok(LiveLoop {
            handle: Some(handle),
            commands: far.commands,
            telemetry: far.telemetry,
            pending: VecDeque::new(),
            lifeline,
            stop,
            report: None,
            counters: None,
            off_error: None,
        })
    }

    /// What the loop's thread obtained (SCHED_FIFO, memory locked, ...), once it has ended.
    pub fn report(&self) -> Option<&RtReport> {
        self.report.as_ref()
    }

    /// What the loop counted, once it has ended.
    pub fn counters(&self) -> Option<&Counters> {
        self.counters.as_ref()
    }

    /// The second stop signal: the loop stops at its next tick with zero on every channel.
    fn halt_if_urgent(&self) {
        if self.stop.urgent() {
            self.lifeline.halt();
        }
    }

    fn running(&self) -> bool {
        self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }

    /// Joins the ended loop's thread and keeps what it said.
    fn join(&mut self) -> Result<(), CalibError> {
        let Some(h) = self.handle.take() else { return Ok(()) };
        let (report, rt) =
            h.join().map_err(|_| CalibError::Recording("the real-time thread panicked".into()))?;
        self.report = Some(report);
        self.counters = Some(*rt.core().counters());
        self.off_error = rt.off_error();
        Ok(())
    }
}

impl TickSource for LiveLoop {
    fn next_record(&mut self) -> Result<TickRecord, CalibError> {
        loop {
            if let Some(r) = self.pending.pop_front() {
                return Ok(r);
            }
            // Never a blocking receive: the loop must not take a lock to wake this thread.
            match self.telemetry.try_recv() {
                Ok(r) => {
                    self.pending.push_back(r);
                    self.pending.extend(self.telemetry.try_iter());
                    continue;
                }
                Err(TryRecvError::Disconnected) => {}
                Err(TryRecvError::Empty) if self.running() => {
                    self.halt_if_urgent();
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                Err(TryRecvError::Empty) => {}
            }
            self.join()?;
            return Err(CalibError::Recording(
                "the rig's loop has stopped (halted by a second stop signal, or its device failed)".into(),
            ));
        }
    }

    fn finish(&mut self) -> Result<(), CalibError> {
        if self.handle.is_some() {
            let _ = self.commands.try_send(Command::Stop);
            let until = Instant::now() + STOP_WITHIN;
            while self.running() {
                self.halt_if_urgent();
                // The records keep coming until the end: keep the channel from filling.
                let _ = self.telemetry.try_iter().count();
                if Instant::now() > until {
                    self.lifeline.halt();
                    if Instant::now() > until + STOP_WITHIN {
                        return Err(CalibError::Recording(
                            "the rig's loop did not stop within 10 s: power the amplifiers down".into(),
                        ));
                    }
                }
                std::thread::sleep(Duration::from_millis(2));
            }
            self.join()?;
        }
        match self.off_error {
            None => Ok(()),
            Some(e) => Err(e.into()),
        }
    }
}

impl Drop for LiveLoop {
    /// Whatever ended the session (an error, a panic in the caller), the loop ends with its
    /// switch-off.
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

/// The loop a calibration command reads.
#[allow(clippy::large_enum_variant)]
pub enum CalibLoop {
    /// The simulated rig, on this thread's virtual clock; its grips moved by the simulated user.
    Sim(VirtualLoop<SimRig>),
    /// Boards (or the board emulator) on the real-time loop; a person moves the grips.
    Live(LiveLoop),
}

impl CalibLoop {
    /// What the loop's thread obtained (real-time loop only, once it has ended).
    pub fn report(&self) -> Option<&RtReport> {
        match self {
            CalibLoop::Sim(_) => None,
            CalibLoop::Live(l) => l.report(),
        }
    }

    /// What the loop counted (the real-time loop's once it has ended).
    pub fn counters(&self) -> Option<Counters> {
        match self {
            CalibLoop::Sim(v) => Some(*v.counters()),
            CalibLoop::Live(l) => l.counters().copied(),
        }
    }
}

impl TickSource for CalibLoop {
    fn next_record(&mut self) -> Result<TickRecord, CalibError> {
        match self {
            CalibLoop::Sim(v) => v.next_record(),
            CalibLoop::Live(l) => l.next_record(),
        }
    }
    fn finish(&mut self) -> Result<(), CalibError> {
        match self {
            CalibLoop::Sim(v) => v.finish(),
            CalibLoop::Live(l) => l.finish(),
        }
    }
}

impl SimulatedRig for CalibLoop {
    fn sim_rig(&mut self) -> Option<&mut SimRig> {
        match self {
            CalibLoop::Sim(v) => v.sim_rig(),
            CalibLoop::Live(_) => None,
        }
    }
}

/// The simulated rig a calibration command runs on: the built-in rig perturbed as `truth` says
/// (whatever the rig file says, so that every command of a calibration meets the same rig).
pub fn sim_device(rig: &Rig, truth: &SimTruthOptions) -> anyhow::Result<(SimRig, String)> {
    let geometry = truth_geometry(&Rig::default_rig(), truth);
    let dev = sim_rig(rig, &geometry, truth.noise_counts, truth.seed)?;
    let name = format!(
        "simulated SPIDAR-H (seed {}, anchors off by up to {:.0} mm, metres per count by up to {:.0} %, noise {} counts)",
        truth.seed,
        truth.anchor_error_m * 1e3,
        truth.mpc_error * 100.0,
        truth.noise_counts
    );
    Ok((dev, name))
}

/// Opens the device `kind` names (with the same options and messages as `spidar run`) and starts
/// calibration's loop on it: on the virtual clock for the simulated rig, on the real-time thread
/// for boards (under the supervisor's `page` when there is one). Returns the loop and the
/// device's name.
pub fn start_loop(
    kind: DeviceKind,
    hw: &HardwareArgs,
    truth: &SimTruthOptions,
    rig: &Rig,
    rt: &RtOptions,
    stop: &Stop,
) -> anyhow::Result<(CalibLoop, String)> {
    match hw.choice(kind, rig)? {
        None => {
            let (dev, name) = sim_device(rig, truth)?;
            Ok((CalibLoop::Sim(VirtualLoop::start(dev, rig, false)?), name))
        }
        Some(choice) => {
            let page = supervisor::attached();
            let dev = hardware::open_hardware_for(&choice, page)?;
            let mut name = format!("{} ({})", dev.info().board, dev.info().identity);
            hardware::check_rig_against(rig, dev.info())?;
            if page.is_some() {
                // SAFETY: getppid has no preconditions.
                let parent = unsafe { libc::getppid() };
                name.push_str(&format!(
                    "; supervisor pid {parent} watches this calibration process (pid {})",
                    std::process::id()
                ));
            }
            Ok((CalibLoop::Live(LiveLoop::start(dev, rig, rt, stop.clone(), page)?), name))
        }
    }
}

/// On real boards, a calibration process runs under the same supervisor as `spidar run`: called
/// first thing, this process becomes the supervisor, starts the calibration process from the same
/// executable and arguments, watches it, and returns the exit status to give
/// (`Some`; 3 when it had to write zero to the boards). `None`: carry on (the simulated rig, or
/// this process is the supervised one).
pub fn supervise_boards(
    kind: DeviceKind,
    hw: &HardwareArgs,
    rig_file: Option<&std::path::Path>,
    rt: &RtOptions,
) -> anyhow::Result<Option<u8>> {
    if kind == DeviceKind::Sim || supervisor::attached().is_some() {
        return Ok(None);
    }
    // The boards' scales come from the rig file; the user's may not exist yet (the first `calib
    // home` creates it, in the supervised process): the template has the same boards section.
    let (rig, _) = RigSource::resolve(rig_file).load()?;
    let Some(choice) = hw.choice(kind, &rig)? else { return Ok(None) };
    let stop = Stop::install()?;
    let code = supervisor::supervise(&stop, rt.fifo_priority, &mut |page| {
        hardware::open_for_takeover(&choice, page)
    })?;
    Ok(Some(code))
}
