//! A session: a device, the rt-loop, a world and the telemetry consumer wired together.
//!
//! Two ways to run one:
//! - [`LiveSession`] ([`run_live`] around it): the real clock; the loop on its own real-time
//!   thread; the world in a child process (`spidar world`, the default), in a world process
//!   already running (`--world ADDR`), or on a thread of this process (`--world thread`);
//!   telemetry, the world's health and the status line on the calling thread. This is
//!   `spidar run`.
//! - [`VirtualRun`]: the virtual clock; loop ticks and world steps interleaved on the calling
//!   thread in a fixed order, so a run is bit-identical for a seed. Hardware-in-the-loop tests and
//!   `spidar run --virtual` use it, with the scene in this process, or
//!   ([`VirtualRun::with_world_process`]) in a world process stepping in lockstep.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use crossbeam_channel::{Receiver, Sender};
use spidar_device::sim::{builtin_script, Script, ScriptFile, SimRig, SimRigParams, BUILTIN_SCRIPTS};
use spidar_device::Device;
use spidar_link::channel::ChannelWorldEnd;
use spidar_link::rig::{hello, RigLinkOptions, SocketRigLink};
use spidar_link::sock::Waiter;
use spidar_link::{Endpoint, LinkError, LinkState, LinkStats, PrivateDir};
use spidar_msg::handshake::Welcome;
use spidar_msg::{HandSample, RigInfo};
use spidar_rt::rt_thread::{self, RtOptions, RtReport};
use spidar_rt::status::rig_info;
use spidar_rt::telemetry::{fmt_dur, Stats, TickRecord};
use spidar_rt::{
    Clock, Command, Counters, Endpoints, Event, FarEnds, Lifecycle, Lifeline, MonotonicClock, Rig, RtLoop,
    VirtualClock,
};
use spidar_world::host::Stepper;
use spidar_world::{Observer, Scene, StepView};

use crate::child_world::{ChildWorld, ChildWorldSpec};
use crate::scene_thread::{self, SceneCounters};
use crate::signals::Stop;
use crate::summary::{FaultTally, SessionSummary, VirtualSummary};
use crate::supervisor::Shared;
use crate::term::StatusOut;

/// How long the simulated user holds the grips still at their home points before a script
/// starts, as an operator does while the rig homes (`spidar_rt::tick::HOMING_SETTLE_S` plus margin).
pub const HOLD_AT_HOME_S: f64 = 0.3;

/// The simulated user's script a scene gets when none is named: pushes at the front row for a
/// crowd scene (`crowd` or a `*crowd*.ron` file), straights, hooks, uppercuts and feints (`box`) for the others.
pub fn default_script(scene: &str) -> &'static str {
    let file =
        std::path::Path::new(scene).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
    if scene == "crowd" || (scene.ends_with(".ron") && file.contains("crowd")) {
        "crowd"
    } else {
        "box"
    }
}

/// The simulated user's scripts by built-in name or RON file, each starting with a hold at home.
pub fn load_scripts(name_or_path: &str, rig: &Rig, seed: u64) -> anyhow::Result<[Script; 2]> {
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    let scripts = if name_or_path == "box" {
        // Straights, hooks, uppercuts and feints at the boxing scene's virtual human (runtime/src/scripts.rs).
        crate::scripts::boxing_scripts(rig, &Default::default(), seed, 2000, None)?
    } else if name_or_path == "crowd" {
        // Pushes and shoves at the crowd scene's front row (runtime/src/scripts.rs).
        crate::scripts::crowd_scripts(rig, seed)?
    } else if let Some(s) = builtin_script(name_or_path, home, seed) {
        s
    } else if std::path::Path::new(name_or_path).is_file() {
        // A script file of any name: it says it is one (`kind: "script"`).
        let path = std::path::Path::new(name_or_path);
        ScriptFile::load(path).with_context(|| format!("loading the script file {name_or_path}"))?.hands
    } else {
        bail!(
            "unknown script '{name_or_path}' (and no such file): use box, crowd, one of {} or a script file \
             (see configs/script-example.ron)",
            BUILTIN_SCRIPTS.join(", ")
        )
    };
    Ok(scripts.map(|s| {
        let hold = s.start_hold_s.max(HOLD_AT_HOME_S);
        s.with_start_hold(hold)
    }))
}

/// Options of the simulated rig that a user may want to change from the command line.
#[derive(Clone, Debug)]
pub struct SimOptions {
    pub seed: u64,
    pub encoder_noise_counts: f64,
    pub slack: bool,
    /// First-order lag of the motors' tension (0: ideal motors).
    pub motor_time_constant_s: f64,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions { seed: 1, encoder_noise_counts: 0.0, slack: false, motor_time_constant_s: 0.0 }
    }
}

/// The simulated rig whose truth is `rig`, with the user's hands following `scripts`.
pub fn sim_device(rig: &Rig, scripts: [Script; 2], opts: &SimOptions) -> anyhow::Result<SimRig> {
    let mut p = SimRigParams::with_defaults(rig.sim_hands());
    p.period_s = rig.period_s;
    p.seed = opts.seed;
    p.encoder_noise_counts = opts.encoder_noise_counts;
    p.motor_time_constant_s = opts.motor_time_constant_s;
    if opts.slack {
        // A string below 0.3 N sags; the encoder then reads up to 5 mm too long.
        p.slack_tension_n = 0.3;
        p.slack_length_m = 0.005;
    }
    SimRig::new(p, scripts).context("building the simulated rig")
}

/// The rig's link timing for `rig`: the world is lost once its last model has faded out.
pub fn link_options(rig: &Rig) -> RigLinkOptions {
    RigLinkOptions {
        lost_after_s: (rig.safety.contact_stale_after_s + rig.safety.contact_fade_s).max(0.25),
        ..Default::default()
    }
}

/// Opens a socket link to the world at `at` and shakes hands, for at most `timeout` (not
/// real-time: before the loop starts). The rig's own Unix socket goes into `dir`. `scene`: the
/// scene to insist on (None: whatever the world runs). `rig_now_s`: the rig's clock now.
pub fn connect_world(
    rig: &Rig,
    at: &Endpoint,
    dir: &PrivateDir,
    scene: Option<&str>,
    rig_now_s: f64,
    timeout: Duration,
) -> Result<(SocketRigLink, Welcome), LinkError> {
    let own = dir.join("rig.sock");
    let h = hello(spidar_link::private_dir::random_u64(), rig_info(rig), scene.unwrap_or(""));
    let mut link = SocketRigLink::open(at, Some(&own), h, link_options(rig))?;
    let w = link.connect(timeout, rig_now_s)?;
    Ok((link, w))
}

/// A world process stepping in lockstep with a virtual run: after each tick that should get an
/// answer (a hello the world received, a sample that makes a step due), the run waits for the
/// world's datagram before the next tick, so the next tick takes it exactly as the in-process
/// scene's model would be taken.
struct Lockstep {
    waiter: Waiter,
    stats: Arc<LinkStats>,
    /// hellos, unanswered sends, samples sent, connects: as of the last tick.
    seen: [u64; 4],
    step_ns: u64,
    next_ns: u64,
    timeout: Duration,
    timeouts: u64,
}

impl Lockstep {
    fn after_tick(&mut self, now_ns: u64) {
        let s = &self.stats;
        let now = [
            LinkStats::get(&s.hellos),
            LinkStats::get(&s.sends_unanswered),
            LinkStats::get(&s.samples_sent),
            LinkStats::get(&s.connects),
        ];
        if now[3] != self.seen[3] {
            self.next_ns = 0; // a world starts its schedule at each connection
        }
        // A hello that reached a socket is answered (welcome or refusal).
        let mut expect = now[0] != self.seen[0];
        // A world answers samples only once it has welcomed the rig (a lost link still sends).
        if now[2] != self.seen[2] && s.state() == LinkState::Connected && now_ns >= self.next_ns {
            self.next_ns = now_ns + self.step_ns;
            expect = true;
        }
        self.seen = now;
        if expect && !self.waiter.wait(self.timeout) {
            self.timeouts += 1;
        }
    }
}

/// Loop and world interleaved on the virtual clock, on the calling thread.
pub struct VirtualRun<D: Device> {
    pub rt: RtLoop<D, VirtualClock>,
    pub far: FarEnds,
    /// The scene stepped in this process (None: none, or a world process).
    pub scene: Option<Box<dyn Scene>>,
    pub clock: VirtualClock,
    pub stats: Stats,
    /// The newest hand sample the loop sent (for inspection; in-process worlds only).
    pub last_sample: Option<HandSample>,
    /// Called after every step of the in-process scene.
    pub observers: Vec<Box<dyn Observer>>,
    rig_info: RigInfo,
    scene_step_ns: u64,
    next_scene_ns: u64,
    samples: Vec<HandSample>,
    lockstep: Option<Lockstep>,
    _dir: Option<PrivateDir>,
}

impl<D: Device> VirtualRun<D> {
    /// Configures the device (Inactive). Does not home or activate.
    pub fn new(dev: D, rig: &Rig, scene: Option<Box<dyn Scene>>) -> anyhow::Result<VirtualRun<D>> {
        let scene_step_ns = scene.as_ref().map_or(3_000_000, |s| (s.step_s() * 1e9).round() as u64);
        Self::build(dev, rig, scene, None, scene_step_ns, None)
    }

    /// The world in its own process at `at`, started with `--lockstep` (`spidar world
    /// --lockstep`): connects now (waiting at most `timeout`), then waits for the world's answer
    /// whenever one is due, so the run is the same as with the scene in this process.
    pub fn with_world_process(
        dev: D,
        rig: &Rig,
        at: &Endpoint,
        scene: Option<&str>,
        timeout: Duration,
    ) -> anyhow::Result<VirtualRun<D>> {
        let dir = PrivateDir::for_process()?;
        let (link, w) = connect_world(rig, at, &dir, scene, 0.0, timeout)?;
        let step_ns = (w.step_s * 1e9).round() as u64;
        let stats = link.shared_stats();
        let lockstep = Lockstep {
            waiter: link.waiter().context("waiting on the link")?,
            seen: [
                LinkStats::get(&stats.hellos),
                LinkStats::get(&stats.sends_unanswered),
                0,
                LinkStats::get(&stats.connects),
            ],
            stats,
            step_ns,
            next_ns: 0,
            timeout: timeout.max(Duration::from_secs(1)),
            timeouts: 0,
        };
        let mut v = Self::build(dev, rig, None, Some(Box::new(link)), step_ns, Some(lockstep))?;
        v._dir = Some(dir);
        Ok(v)
    }

    fn build(
        dev: D,
        rig: &Rig,
        scene: Option<Box<dyn Scene>>,
        link: Option<Box<dyn spidar_link::RigLink>>,
        scene_step_ns: u64,
        lockstep: Option<Lockstep>,
    ) -> anyhow::Result<VirtualRun<D>> {
        let clock = VirtualClock::new();
        let (mut ep, far) = Endpoints::pair();
        ep.telemetry = None; // records are read directly, tick by tick
        ep.events = None;
        if link.is_some() {
            ep.link = link;
        }
        let mut rt = RtLoop::new(dev, clock.clone(), rig, ep)?;
        rt.configure().map_err(|e| anyhow::anyhow!("opening the device: {e}"))?;
        Ok(VirtualRun {
            rt,
            far,
            scene,
            clock,
            stats: Stats::new(),
            last_sample: None,
            observers: Vec::new(),
            rig_info: rig_info(rig),
            scene_step_ns,
            next_scene_ns: 0,
            samples: Vec::with_capacity(64),
            lockstep,
            _dir: None,
        })
    }

    /// Homes (grips at their home points) and activates, as `spidar run` does.
    pub fn home_and_activate(&mut self) {
        self.rt.command(Command::Home);
        self.rt.command(Command::Activate);
    }

    /// One loop tick, then a world step if one is due. Returns the tick's record.
    pub fn tick(&mut self) -> TickRecord {
        self.rt.tick();
        let rec = *self.rt.last_record();
        self.stats.add(&rec);
        self.after_tick();
        rec
    }

    /// The world's side of a tick (for callers that run `rt.tick()` themselves): the in-process
    /// scene steps if a step is due, or a world process is given time to answer.
    pub fn after_tick(&mut self) {
        let now = self.clock.now_ns();
        if let Some(l) = self.lockstep.as_mut() {
            l.after_tick(now);
            return;
        }
        let scene_due = self.scene.is_some() && now >= self.next_scene_ns;
        if scene_due || self.scene.is_none() {
            self.samples.clear();
            self.samples.extend(self.far.samples.try_iter());
            if let Some(s) = self.samples.last() {
                self.last_sample = Some(*s);
            }
        }
        if let (true, Some(scene)) = (scene_due, self.scene.as_mut()) {
            let t_s = now as f64 * 1e-9;
            let m = scene.step(t_s, &self.samples);
            if !self.observers.is_empty() {
                let status = self.far.status.try_iter().last();
                for o in self.observers.iter_mut() {
                    o.after_step(&StepView {
                        t_s,
                        scene: &**scene,
                        samples: &self.samples,
                        model: &m,
                        rig_info: Some(&self.rig_info),
                        rig_status: status.as_ref(),
                    });
                }
            }
            let _ = self.far.models.try_send(m);
            self.next_scene_ns = now + self.scene_step_ns;
        }
    }

    pub fn run_ticks(&mut self, n: u64) {
        for _ in 0..n {
            self.tick();
        }
    }

    /// Stops the scene from sending models (as if the simulation hung).
    pub fn stop_scene(&mut self) -> Option<Box<dyn Scene>> {
        self.scene.take()
    }

    pub fn counters(&self) -> &Counters {
        self.rt.core().counters()
    }

    /// The socket link's counters (a world process), if any.
    pub fn link_stats(&self) -> Option<Arc<LinkStats>> {
        self.lockstep.as_ref().map(|l| l.stats.clone())
    }

    /// Lockstep answers that did not come in time (a world process only).
    pub fn lockstep_timeouts(&self) -> u64 {
        self.lockstep.as_ref().map_or(0, |l| l.timeouts)
    }
}

/// What `spidar run --virtual` needs.
pub struct VirtualOptions {
    /// Rig time to run (s).
    pub seconds: f64,
    pub stop: Stop,
    /// Show the status line (to stderr) while running.
    pub progress: bool,
    pub device: String,
    pub scene_name: String,
    pub script_name: String,
    /// The page shared with a supervising process (real boards), if any.
    pub supervisor: Option<&'static Shared>,
    /// Records every tick, the ramp-out included (`spidar run --virtual --record`).
    pub recorder: Option<spidar_record::writer::Recorder>,
    /// Watch the world's steps (the world's recording, `FILE.world.mcap`).
    pub observers: Vec<Box<dyn Observer>>,
}

/// The world of a virtual run.
pub enum VirtualWorld {
    /// Stepped in this process, interleaved with the loop.
    Scene(Box<dyn Scene>),
    /// A world process already listening at `at` (`spidar run --virtual --world ADDR`: a
    /// `spidar world --lockstep` or a world of one's own, such as a Python one), answered in
    /// lockstep; `scene`: the scene to insist on. Waits at most `timeout` for its welcome.
    Process { at: Endpoint, scene: Option<String>, timeout: Duration },
}

/// `spidar run --virtual`: the loop and the scene interleaved on the virtual clock for `seconds` of
/// rig time, as fast as the machine computes; a stop signal ramps out early (a second one stops
/// at once with the outputs zeroed). The device is switched off at the end either way.
pub fn run_virtual<D: Device>(
    dev: D,
    rig: &Rig,
    scene: Box<dyn Scene>,
    opts: VirtualOptions,
) -> anyhow::Result<VirtualSummary> {
    run_virtual_with(dev, rig, VirtualWorld::Scene(scene), opts).map(|(s, _)| s)
}

/// [`run_virtual`] with its world in this process or in a world process; with a world process,
/// also the link's counters at the end.
pub fn run_virtual_with<D: Device>(
    dev: D,
    rig: &Rig,
    world: VirtualWorld,
    mut opts: VirtualOptions,
) -> anyhow::Result<(VirtualSummary, Option<Arc<LinkStats>>)> {
    let mut v = match world {
        VirtualWorld::Scene(scene) => VirtualRun::new(dev, rig, Some(scene))?,
        VirtualWorld::Process { at, scene, timeout } => {
            VirtualRun::with_world_process(dev, rig, &at, scene.as_deref(), timeout)?
        }
    };
    v.observers.append(&mut opts.observers);
    let mut recorder = opts.recorder.take();
    let lifeline: &'static Lifeline = match opts.supervisor {
        Some(s) => &s.lifeline,
        None => Box::leak(Box::default()),
    };
    v.rt.set_lifeline(lifeline);
    if let Some(s) = opts.supervisor {
        s.set_driving();
    }
    v.home_and_activate();
    let ticks = (opts.seconds / rig.period_s).round() as u64;
    // The ramp-out is a fraction of a second of rig time; this only guards against a loop that
    // never quiets.
    let stop_limit = (10.0 / rig.period_s) as u64;
    let mut out = StatusOut::new(Duration::from_millis(500));
    let mut faults = FaultTally::default();
    let (mut n, mut stopping_at) = (0u64, None);
    let mut was_faulted = false;
    let mut states = StateLines::default();
    let t0 = Instant::now();
    loop {
        if stopping_at.is_none() && (n >= ticks || opts.stop.requested()) {
            let time_up = n >= ticks;
            if !time_up {
                out.say(stopping_words(false));
            }
            v.rt.command(Command::Stop);
            stopping_at = Some(n);
        }
        let overdue = stopping_at.is_some_and(|at| n - at > stop_limit);
        if (opts.stop.urgent() || overdue) && lifeline.halt.load(Ordering::Relaxed) == 0 {
            out.say(HALT_WORDS);
            lifeline.halt();
        }
        if !v.rt.tick() {
            break;
        }
        let rec = *v.rt.last_record();
        if let Some(w) = recorder.as_mut() {
            w.write_tick(&rec);
        }
        v.stats.add(&rec);
        v.after_tick();
        states.see(&rec);
        for line in states.lines.drain(..) {
            out.say(&line);
        }
        let faulted = rec.state == Lifecycle::Faulted;
        if faulted && !was_faulted {
            if let Some(r) = rec.fault {
                faults.push(r.to_string());
            }
        }
        was_faulted = faulted;
        n += 1;
        if opts.progress && n % 64 == 0 && out.due() {
            let line = status_line(&v.stats, faults.total() as usize, v.counters().models);
            out.status(&line);
            v.stats.reset_window();
        }
    }
    out.finish();
    let wall_s = t0.elapsed().as_secs_f64();
    let c = *v.counters();
    let recording = recorder.map(|w| {
        w.finish(&spidar_record::writer::EndInfo {
            ticks: c.ticks,
            telemetry_dropped: 0,
            final_state: v.rt.state().name().into(),
            clean_stop: v.rt.is_finished(),
            faults: c.faults,
        })
    });
    let summary = VirtualSummary {
        device: opts.device,
        scene: opts.scene_name,
        script: opts.script_name,
        rig_file: String::new(),
        seconds: opts.seconds,
        wall_s,
        period_s: rig.period_s,
        counters: *v.counters(),
        scene_status: v.scene.as_ref().map_or_else(|| "stepped by the world process".into(), |s| s.status()),
        final_state: v.rt.state(),
        faults_seen: faults,
        clean_stop: v.rt.is_finished(),
        halted: v.rt.halted(),
        signals: opts.stop.count(),
        stats: std::mem::replace(&mut v.stats, Stats::new()),
        recording,
    };
    Ok((summary, v.link_stats()))
}

/// A line for each change of the rig's state, so a log (and an operator) sees when the rig
/// became active, faulted or inactive.
#[derive(Default)]
struct StateLines {
    last: Option<Lifecycle>,
    lines: Vec<String>,
}

impl StateLines {
    fn see(&mut self, r: &TickRecord) {
        if self.last == Some(r.state) {
            return;
        }
        self.last = Some(r.state);
        let line = match r.state {
            Lifecycle::Unconfigured => return,
            Lifecycle::Inactive => "rig: inactive (strings at minimum tension)".to_string(),
            Lifecycle::Active => "rig: active (force ramps in)".to_string(),
            Lifecycle::Faulted => format!(
                "rig: FAULTED ({}): force fades out, strings at minimum tension",
                r.fault.map_or("no reason kept".to_string(), |f| f.to_string())
            ),
        };
        self.lines.push(line);
    }
}

/// What the operator is told when the clean stop begins.
fn stopping_words(time_up: bool) -> &'static str {
    if time_up {
        "stopping (time up): force ramps out, then the device is switched off"
    } else {
        "stopping: force ramps out, then the device is switched off (a second Ctrl-C stops at once)"
    }
}

const HALT_WORDS: &str = "stopping at once: zero on every channel, device off";

/// Where the world of a live run is.
pub enum WorldChoice {
    /// A thread of the rig's process, stepping this scene (with its observers: the live view).
    Thread(Stepper),
    /// A world process started (and restarted) by the session, on a Unix socket in a private
    /// directory.
    Child(ChildWorldSpec),
    /// A world process already running at this address; `scene`: the scene to insist on.
    Connect { at: Endpoint, scene: Option<String> },
}

/// What `run_live` needs.
pub struct LiveOptions {
    pub seconds: Option<f64>,
    pub rt: RtOptions,
    /// Sleep to this long before each deadline and spin the rest (0: pure sleep).
    pub spin_ns: u64,
    /// Print the status line (to stderr) every this often; None: quiet.
    pub status_every: Option<Duration>,
    pub stop: Stop,
    pub scene_name: String,
    pub script_name: String,
    /// How long to wait for the world's first answer.
    pub connect_timeout: Duration,
    /// SCHED_FIFO priority of a thread world (a child world gets its own `--priority`).
    pub world_priority: Option<u8>,
    /// The page shared with a supervising process (`spidar run` on real boards), if any.
    pub supervisor: Option<&'static Shared>,
    /// Records every tick (`spidar run --record`): `run_live` feeds it the telemetry.
    pub recorder: Option<spidar_record::writer::RecorderThread>,
}

/// One per session: its size does not matter.
#[allow(clippy::large_enum_variant)]
enum LiveWorld {
    Thread {
        handle: Option<JoinHandle<Stepper>>,
        stop: Arc<AtomicBool>,
        counters: Arc<SceneCounters>,
    },
    Process {
        stats: Arc<LinkStats>,
        at: Endpoint,
        scene: String,
        child: Option<ChildWorld>,
        last_state: LinkState,
        _dir: PrivateDir,
    },
}

type RtHandle<D> = JoinHandle<(RtReport, RtLoop<D, MonotonicClock>)>;

/// A live run under way: poll it until it ends, then `finish` it.
pub struct LiveSession<D: Device + 'static> {
    rt_handle: Option<RtHandle<D>>,
    commands: Sender<Command>,
    events: Receiver<Event>,
    telemetry: Receiver<TickRecord>,
    world: LiveWorld,
    lifeline: &'static Lifeline,
    pub stats: Stats,
    pub faults_seen: FaultTally,
    start: Instant,
    stop_deadline: Option<Instant>,
    stopped: bool,
    device: String,
    scene_name: String,
    script_name: String,
}

/// Starts a world process listening in `dir` and connects to it, retrying while it starts
/// (loading a scene takes a moment); an early exit is an error with what it said.
pub fn start_child_world(
    rig: &Rig,
    spec: ChildWorldSpec,
    dir: &PrivateDir,
    clock: &MonotonicClock,
    timeout: Duration,
) -> anyhow::Result<(ChildWorld, SocketRigLink, Welcome)> {
    start_child_world_at(rig, spec, &Endpoint::unix(&dir.join("world.sock")), dir, clock, timeout)
}

/// The same at any address (a UDP one for benchmarks).
pub fn start_child_world_at(
    rig: &Rig,
    spec: ChildWorldSpec,
    at: &Endpoint,
    dir: &PrivateDir,
    clock: &MonotonicClock,
    timeout: Duration,
) -> anyhow::Result<(ChildWorld, SocketRigLink, Welcome)> {
    let at = at.clone();
    let mut child = ChildWorld::start(spec, &at)?;
    let until = Instant::now() + timeout;
    let mut said = Vec::new();
    loop {
        let try_for = until.saturating_duration_since(Instant::now()).min(Duration::from_millis(200));
        match connect_world(rig, &at, dir, None, clock.now_ns() as f64 * 1e-9, try_for) {
            Ok((link, w)) => {
                // What the world said as it started (where its live view is) goes to the
                // session's next `poll`, with the world's later lines.
                child.hold_lines(said);
                return Ok((child, link, w));
            }
            Err(LinkError::NoWorld { .. }) if Instant::now() < until => {}
            // Not there yet: the socket file does not exist or nobody listens on it.
            Err(LinkError::Io { .. }) if Instant::now() < until => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => return Err(e).context("connecting to the world process"),
        }
        if let Some(how) = child.try_exit(&mut |l| said.push(l)) {
            bail!("the world process {how} before it answered: {}", said.join(" | "));
        }
        child.read_lines(&mut |l| said.push(l));
    }
}

impl<D: Device + 'static> LiveSession<D> {
    /// Opens the device, starts or connects to the world, starts the loop, homes and activates.
    pub fn start(
        dev: D,
        rig: &Rig,
        world: WorldChoice,
        opts: &LiveOptions,
    ) -> anyhow::Result<LiveSession<D>> {
        let device = format!("{} ({})", dev.info().board, dev.info().identity);
        let clock = MonotonicClock::new();
        let (mut ep, far) = Endpoints::pair();
        let FarEnds { commands, events, models, samples, status, telemetry } = far;
        let live_world = match world {
            WorldChoice::Thread(stepper) => {
                let stop = Arc::new(AtomicBool::new(false));
                let counters = Arc::new(SceneCounters::default());
                let handle = scene_thread::spawn(
                    stepper,
                    clock,
                    ChannelWorldEnd { models, samples, status },
                    rig_info(rig),
                    stop.clone(),
                    counters.clone(),
                    opts.world_priority,
                )
                .context("starting the scene thread")?;
                LiveWorld::Thread { handle: Some(handle), stop, counters }
            }
            WorldChoice::Child(spec) => {
                let dir =
                    PrivateDir::for_process().context("making a private directory for the world's socket")?;
                let (child, link, w) = start_child_world(rig, spec, &dir, &clock, opts.connect_timeout)?;
                let stats = link.shared_stats();
                ep.link = Some(Box::new(link));
                LiveWorld::Process {
                    stats,
                    at: Endpoint::unix(&dir.join("world.sock")),
                    scene: w.scene.as_str().to_string(),
                    child: Some(child),
                    last_state: LinkState::Connected,
                    _dir: dir,
                }
            }
            WorldChoice::Connect { at, scene } => {
                let dir =
                    PrivateDir::for_process().context("making a private directory for the rig's socket")?;
                let (link, w) = connect_world(
                    rig,
                    &at,
                    &dir,
                    scene.as_deref(),
                    clock.now_ns() as f64 * 1e-9,
                    opts.connect_timeout,
                )?;
                let stats = link.shared_stats();
                ep.link = Some(Box::new(link));
                LiveWorld::Process {
                    stats,
                    at,
                    scene: w.scene.as_str().to_string(),
                    child: None,
                    last_state: LinkState::Connected,
                    _dir: dir,
                }
            }
        };
        // The heartbeat and halt flag: in the supervisor's page, or this process's own (one
        // small leak per session, so the loop can hold a plain `&'static`).
        let lifeline: &'static Lifeline = match opts.supervisor {
            Some(s) => &s.lifeline,
            None => Box::leak(Box::default()),
        };
        ep.lifeline = Some(lifeline);
        let mut rt = RtLoop::new(dev, clock.with_spin(opts.spin_ns), rig, ep)?;
        rt.configure().map_err(|e| anyhow::anyhow!("opening the device: {e}"))?;
        if let Some(s) = opts.supervisor {
            s.set_driving();
        }
        let rt_opts = opts.rt.clone();
        let rt_handle = std::thread::Builder::new()
            .name("spidar-rt".into())
            .spawn(move || {
                let report = rt_thread::setup_current_thread(&rt_opts);
                rt.run();
                (report, rt)
            })
            .context("starting the real-time thread")?;
        // The grips start at their home points on the simulated rig; a real rig's operator holds
        // them there before starting (see docs/guide.md).
        let _ = commands.try_send(Command::Home);
        let _ = commands.try_send(Command::Activate);
        Ok(LiveSession {
            rt_handle: Some(rt_handle),
            commands,
            events,
            telemetry,
            world: live_world,
            lifeline,
            stats: Stats::new(),
            faults_seen: FaultTally::default(),
            start: Instant::now(),
            stop_deadline: None,
            stopped: false,
            device,
            scene_name: opts.scene_name.clone(),
            script_name: opts.script_name.clone(),
        })
    }

    /// Takes the loop's telemetry (each record to `each`) and events, and watches the world
    /// (restarting a child world that ended; `say` gets what is worth a line). Never blocks.
    /// False once the loop has stopped.
    pub fn poll(&mut self, each: &mut dyn FnMut(&TickRecord), say: &mut dyn FnMut(String)) -> bool {
        for r in self.telemetry.try_iter() {
            self.stats.add(&r);
            each(&r);
        }
        for e in self.events.try_iter() {
            match e {
                Event::Fault(why) => self.faults_seen.push(format!("{why}")),
                Event::Refused { command, why } => {
                    self.faults_seen.push(format!("{command:?} refused: {why}"))
                }
                Event::DeviceReopened => {
                    self.faults_seen.push("device reopened after a disconnect: home again".into())
                }
                Event::HomeNeeded => self.faults_seen.push(
                    "homing lost: hold both grips still at their home points (the rig homes itself) or send Home"
                        .into(),
                ),
                Event::Stopped => self.stopped = true,
                _ => {}
            }
        }
        if let LiveWorld::Process { stats, child, last_state, .. } = &mut self.world {
            if let Some(c) = child.as_mut() {
                if self.stop_deadline.is_none() {
                    c.check(say);
                } else {
                    c.read_lines(say);
                }
            }
            let state = stats.state();
            // Once stopping, the rig says goodbye itself: nothing to announce.
            if state != *last_state && self.stop_deadline.is_none() {
                match state {
                    LinkState::Lost => say(
                        "world lost: its force fades to zero, the strings hold minimum tension, the rig stays homed; \
                         waiting for a world"
                            .into(),
                    ),
                    LinkState::Connected => say("world connected: force ramps back in".into()),
                    LinkState::Refused => {
                        let why = stats.handshake.read().and_then(|(_, d)| match spidar_msg::wire::decode(&d) {
                            Ok((_, spidar_msg::wire::Message::Refuse(r))) => Some(r.reason.as_str().to_string()),
                            _ => None,
                        });
                        say(format!("the world refused this rig: {}", why.unwrap_or_else(|| "no reason given".into())))
                    }
                    LinkState::Connecting => {}
                }
                *last_state = state;
            }
        }
        !(self.stopped || self.rt_handle.as_ref().is_none_or(|h| h.is_finished()))
    }

    /// Asks the loop to ramp out and stop.
    pub fn request_stop(&mut self) {
        if self.stop_deadline.is_none() {
            let _ = self.commands.try_send(Command::Stop);
            self.stop_deadline = Some(Instant::now() + Duration::from_secs(5));
        }
    }

    /// Stops the loop at its next tick without the ramp-out: outputs zeroed, device off (a
    /// second stop signal).
    pub fn halt(&mut self) {
        self.lifeline.halt();
        self.stop_deadline.get_or_insert_with(|| Instant::now() + Duration::from_secs(5));
    }

    /// A stop was asked for.
    pub fn stop_requested(&self) -> bool {
        self.stop_deadline.is_some()
    }

    /// The halt was asked for.
    pub fn halt_requested(&self) -> bool {
        self.lifeline.halt.load(Ordering::Relaxed) != 0
    }

    /// The stop was asked for more than 5 s ago and the loop still runs.
    pub fn stop_overdue(&self) -> bool {
        self.stop_deadline.is_some_and(|d| Instant::now() > d)
    }

    pub fn elapsed_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// The world process's id (a child world).
    pub fn world_pid(&self) -> Option<u32> {
        match &self.world {
            LiveWorld::Process { child: Some(c), .. } => c.pid(),
            _ => None,
        }
    }

    /// The world process's starts so far (a child world).
    pub fn world_starts(&self) -> u32 {
        match &self.world {
            LiveWorld::Process { child: Some(c), .. } => c.starts,
            _ => 0,
        }
    }

    pub fn link_stats(&self) -> Option<&LinkStats> {
        match &self.world {
            LiveWorld::Process { stats, .. } => Some(stats),
            LiveWorld::Thread { .. } => None,
        }
    }

    /// The status line: the loop's state, rate, lateness, forces, and the world's.
    pub fn status_line(&mut self) -> String {
        let faults = self.faults_seen.total() as usize;
        let (steps, world, scene) = match &self.world {
            LiveWorld::Thread { counters, .. } => (
                counters.steps.load(Ordering::Relaxed),
                String::new(),
                counters.status.lock().map(|s| s.clone()).unwrap_or_default(),
            ),
            LiveWorld::Process { stats, child, .. } => {
                let state = stats.state();
                let world = match state {
                    LinkState::Connected => String::new(),
                    LinkState::Lost => "  WORLD LOST".into(),
                    s => format!("  world {}", s.name()),
                };
                let (steps, scene) = child.as_ref().and_then(|c| c.status.clone()).unwrap_or_default();
                let steps = if child.is_some() { steps } else { LinkStats::get(&stats.models) };
                (steps, world, scene)
            }
        };
        let mut line = status_line(&self.stats, faults, steps);
        line.push_str(&world);
        if !scene.is_empty() {
            line.push_str("  | ");
            line.push_str(&scene);
        }
        line
    }

    /// Waits for the loop to end (after a stop), ends the world, and reports. `signals`: the stop
    /// signals that ended it, for the summary.
    pub fn finish(mut self, signals: u32, say: &mut dyn FnMut(String)) -> anyhow::Result<SessionSummary> {
        let handle = self.rt_handle.take().context("the loop was already finished")?;
        let (report, rt) = handle.join().map_err(|_| anyhow::anyhow!("the real-time thread panicked"))?;
        for r in self.telemetry.try_iter() {
            self.stats.add(&r);
        }
        let c = *rt.core().counters();
        let (scene_steps, scene_late, models_dropped, scene_status, world, link, world_report) =
            match &mut self.world {
                LiveWorld::Thread { handle, stop, counters } => {
                    stop.store(true, Ordering::Relaxed);
                    let stepper = handle
                        .take()
                        .context("the scene thread")?
                        .join()
                        .map_err(|_| anyhow::anyhow!("the scene thread panicked"))?;
                    (
                        counters.steps.load(Ordering::Relaxed),
                        Some(counters.late_steps.load(Ordering::Relaxed)),
                        counters.models_dropped.load(Ordering::Relaxed),
                        stepper.scene().status(),
                        "a thread of this process".to_string(),
                        None,
                        None,
                    )
                }
                LiveWorld::Process { stats, at, scene, child, .. } => {
                    let mut world = format!("process at {at}, scene {scene}");
                    let (mut steps, mut status, mut report) =
                        (LinkStats::get(&stats.models), String::new(), None);
                    if let Some(ch) = child.as_mut() {
                        // The rig said goodbye as it stopped; now end the world and keep its last words.
                        ch.stop(Duration::from_secs(3), say);
                        if let Some((n, s)) = ch.status.clone() {
                            (steps, status) = (n, s);
                        }
                        report = ch.report.clone();
                        world.push_str(&format!(
                            " (a child of this process, pid {}; starts {}{})",
                            ch.last_pid,
                            ch.starts,
                            if ch.exits.is_empty() {
                                String::new()
                            } else {
                                format!(": it {}", ch.exits.join(", then "))
                            }
                        ));
                    }
                    (steps, None, 0, status, world, Some(stats.summary()), report)
                }
            };
        Ok(SessionSummary {
            scene_status,
            device: self.device.clone(),
            scene: self.scene_name.clone(),
            script: self.script_name.clone(),
            wall_s: self.start.elapsed().as_secs_f64(),
            rt: report,
            stats: std::mem::replace(&mut self.stats, Stats::new()),
            counters: c,
            scene_steps,
            scene_late,
            models_dropped,
            world,
            link,
            world_report,
            final_state: rt.state(),
            faults_seen: std::mem::take(&mut self.faults_seen),
            clean_stop: rt.is_finished(),
            halted: rt.halted(),
            signals,
            recording: None,
            overrides: Vec::new(),
            rig_file: String::new(),
        })
    }
}

/// Runs a session on the real clock until `seconds` pass or a stop is requested (a signal), then
/// stops cleanly: force ramps out, strings hold minimum tension, the device is switched off, the
/// world ends. A second signal stops at once with the outputs zeroed.
pub fn run_live<D: Device + 'static>(
    dev: D,
    rig: &Rig,
    world: WorldChoice,
    mut opts: LiveOptions,
) -> anyhow::Result<SessionSummary> {
    let mut s = LiveSession::start(dev, rig, world, &opts)?;
    let mut recorder = opts.recorder.take();
    let mut out = StatusOut::new(opts.status_every.unwrap_or(Duration::from_millis(500)));
    let said = std::cell::RefCell::new(Vec::new());
    let mut say = |line: String| said.borrow_mut().push(line);
    let states = std::cell::RefCell::new(StateLines::default());
    let mut each = |r: &TickRecord| {
        states.borrow_mut().see(r);
        if let Some(rec) = recorder.as_mut() {
            rec.push(r);
        }
    };
    let tell = |out: &mut StatusOut| {
        for line in states.borrow_mut().lines.drain(..) {
            out.say(&line);
        }
        for line in said.borrow_mut().drain(..) {
            out.say(&format!("world: {line}"));
        }
    };
    loop {
        let running = s.poll(&mut each, &mut say);
        tell(&mut out);
        if !running {
            break;
        }
        let time_up = opts.seconds.is_some_and(|t| s.elapsed_s() >= t);
        if (time_up || opts.stop.requested()) && !s.stop_requested() {
            out.say(stopping_words(time_up));
            s.request_stop();
        }
        if opts.stop.urgent() && !s.halt_requested() {
            out.say(HALT_WORDS);
            s.halt();
        }
        if s.stop_overdue() {
            bail!("the real-time loop did not stop within 5 s of the stop command");
        }
        if opts.status_every.is_some() && out.due() {
            let line = s.status_line();
            out.status(&line);
            s.stats.reset_window();
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    // The loop's last records (sent before its `Stopped`) may still be queued.
    s.poll(&mut each, &mut say);
    tell(&mut out);
    out.finish();
    let summary = s.finish(opts.stop.count(), &mut say);
    tell(&mut out);
    let mut summary = summary?;
    summary.overrides = rig.overrides.clone();
    if let Some(r) = recorder {
        let to_file = r.records_to_file();
        let rep = r.finish(&crate::recording::end_info(&summary))?;
        if to_file {
            summary.recording = Some(rep);
        }
    }
    Ok(summary)
}

/// The live status line: state, rate, lateness p99 over the window, forces, safety counts.
pub fn status_line(stats: &Stats, faults: usize, scene_steps: u64) -> String {
    let w = &stats.window;
    let Some(last) = w.last else { return "waiting for the first tick".into() };
    let p = w.lateness.percentiles();
    let f = |h: usize| last.hands[h].output_n.length();
    let mut fault = last.fault.map(|f| format!(" ({f})")).unwrap_or_default();
    if last.awaiting_home {
        fault.push_str(" (hold both grips still at home to re-home)");
    }
    format!(
        "t {:6.1} s  {}{}  {:6.1} Hz  late p99 {:>8}  force L {:4.1} N R {:4.1} N (max {:4.1}/{:4.1})  gain {:.2}  faults {}  scene steps {}",
        last.t_s,
        last.state.name(),
        fault,
        w.rate_hz(),
        fmt_dur(p.p99_s),
        f(0),
        f(1),
        w.max_force_n[0],
        w.max_force_n[1],
        last.gain,
        faults,
        scene_steps
    )
}
