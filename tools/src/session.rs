//! A session: a device, the rt-loop, a scene and the telemetry consumer wired together.
//!
//! Two ways to run one:
//! - [`run_live`]: the real clock; the loop on its own real-time thread, the scene on another,
//!   telemetry and the status line on the calling thread. This is `spidar run`.
//! - [`VirtualRun`]: the virtual clock; loop ticks and scene steps interleaved on the calling
//!   thread in a fixed order, so a run is bit-identical for a seed. Hardware-in-the-loop tests and
//!   `spidar run --virtual` use it.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use spidar_device::sim::{builtin_script, Script, ScriptFile, SimRig, SimRigParams, BUILTIN_SCRIPTS};
use spidar_device::Device;
use spidar_msg::HandSample;
use spidar_rt::rt_thread::{self, RtOptions, RtReport};
use spidar_rt::telemetry::{fmt_dur, Stats, TickRecord};
use spidar_rt::{
    Clock, Command, Counters, Endpoints, Event, FarEnds, Lifecycle, MonotonicClock, Rig, RtLoop, VirtualClock,
};

use crate::scene_thread::{self, SceneCounters};
use spidar_world::Scene;

/// How long the simulated user holds the grips still at their home points before a script
/// starts, as an operator does while the rig homes (`spidar_rt::tick::HOMING_SETTLE_S` plus margin).
pub const HOLD_AT_HOME_S: f64 = 0.3;

/// The simulated user's scripts by built-in name or RON file, each starting with a hold at home.
pub fn load_scripts(name_or_path: &str, rig: &Rig, seed: u64) -> anyhow::Result<[Script; 2]> {
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    let scripts = if name_or_path == "box" {
        // Jabs and hooks at the boxing scene's virtual human (tools/src/scripts.rs).
        crate::scripts::boxing_scripts(rig, &Default::default(), seed, 2000, None)?
    } else if let Some(s) = builtin_script(name_or_path, home, seed) {
        s
    } else if name_or_path.ends_with(".ron") {
        let path = std::path::Path::new(name_or_path);
        ScriptFile::load(path).with_context(|| format!("loading the script file {name_or_path}"))?.hands
    } else {
        bail!(
            "unknown script '{name_or_path}': use box, one of {} or a script file (.ron)",
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

/// Loop and scene interleaved on the virtual clock, on the calling thread.
pub struct VirtualRun<D: Device> {
    pub rt: RtLoop<D, VirtualClock>,
    pub far: FarEnds,
    pub scene: Option<Box<dyn Scene>>,
    pub clock: VirtualClock,
    pub stats: Stats,
    /// The newest hand sample the loop sent (for inspection).
    pub last_sample: Option<HandSample>,
    scene_step_ns: u64,
    next_scene_ns: u64,
    samples: Vec<HandSample>,
}

impl<D: Device> VirtualRun<D> {
    /// Configures the device (Inactive). Does not home or activate.
    pub fn new(dev: D, rig: &Rig, scene: Option<Box<dyn Scene>>) -> anyhow::Result<VirtualRun<D>> {
        let clock = VirtualClock::new();
        let (mut ep, far) = Endpoints::pair();
        ep.telemetry = None; // records are read directly, tick by tick
        ep.events = None;
        let mut rt = RtLoop::new(dev, clock.clone(), rig, ep)?;
        rt.configure().map_err(|e| anyhow::anyhow!("opening the device: {e}"))?;
        let scene_step_ns = scene.as_ref().map_or(3_000_000, |s| (s.step_s() * 1e9).round() as u64);
        Ok(VirtualRun {
            rt,
            far,
            scene,
            clock,
            stats: Stats::new(),
            last_sample: None,
            scene_step_ns,
            next_scene_ns: 0,
            samples: Vec::with_capacity(64),
        })
    }

    /// Homes (grips at their home points) and activates, as `spidar run` does.
    pub fn home_and_activate(&mut self) {
        self.rt.command(Command::Home);
        self.rt.command(Command::Activate);
    }

    /// One loop tick, then a scene step if one is due. Returns the tick's record.
    pub fn tick(&mut self) -> TickRecord {
        self.rt.tick();
        let rec = *self.rt.last_record();
        self.stats.add(&rec);
        let now = self.clock.now_ns();
        let scene_due = self.scene.is_some() && now >= self.next_scene_ns;
        if scene_due || self.scene.is_none() {
            self.samples.clear();
            self.samples.extend(self.far.samples.try_iter());
            if let Some(s) = self.samples.last() {
                self.last_sample = Some(*s);
            }
        }
        if let (true, Some(scene)) = (scene_due, self.scene.as_mut()) {
            let m = scene.step(now as f64 * 1e-9, &self.samples);
            let _ = self.far.models.try_send(m);
            self.next_scene_ns = now + self.scene_step_ns;
        }
        rec
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
}

/// What a live run reports at the end.
#[derive(Debug)]
pub struct Summary {
    pub device: String,
    pub scene: String,
    pub script: String,
    pub wall_s: f64,
    pub rt: RtReport,
    pub stats: Stats,
    pub counters: Counters,
    pub scene_steps: u64,
    pub scene_late: u64,
    pub models_dropped: u64,
    /// The scene's own status at the end (`Scene::status`).
    pub scene_status: String,
    pub final_state: Lifecycle,
    pub faults_seen: Vec<String>,
    pub clean_stop: bool,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        let s = &self.stats;
        let lat = s.lateness.percentiles();
        let comp = s.compute.percentiles();
        let io = s.io.percentiles();
        writeln!(
            f,
            "spidar run: {:.2} s on {}, scene {}, script {}",
            self.wall_s, self.device, self.scene, self.script
        )?;
        writeln!(f, "  real time    {}", self.rt)?;
        for w in &self.rt.warnings {
            writeln!(f, "  warning      {w}")?;
        }
        writeln!(f, "  ticks        {} ({:.1} Hz), {} active", c.ticks, s.rate_hz(), c.active_ticks)?;
        writeln!(f, "  lateness     {lat}")?;
        writeln!(f, "  misses       {} ticks woke > 1 ms late", c.misses)?;
        writeln!(f, "  compute      {comp}  (per tick, both hands, excluding device I/O)")?;
        writeln!(f, "  device I/O   {io}")?;
        writeln!(f, "  max force    left {:.2} N, right {:.2} N", s.max_force_n[0], s.max_force_n[1])?;
        writeln!(
            f,
            "  tensions     {:.2} .. {:.2} N commanded",
            if s.min_tension_n.is_finite() { s.min_tension_n } else { 0.0 },
            s.max_tension_n
        )?;
        writeln!(
            f,
            "  safety       clamped {}/{}, infeasible {}/{}, fallback {}/{}, stiffness-limited {}/{} (left/right ticks)",
            c.clamped[0],
            c.clamped[1],
            c.infeasible[0],
            c.infeasible[1],
            c.fallback[0],
            c.fallback[1],
            c.stiffness_limited[0],
            c.stiffness_limited[1]
        )?;
        writeln!(
            f,
            "               stale-model ticks {}, non-finite forces {}, faults {}, device errors {}",
            c.stale, c.non_finite, c.faults, c.device_errors
        )?;
        for fault in &self.faults_seen {
            writeln!(f, "  fault        {fault}")?;
        }
        writeln!(
            f,
            "  scene        {} steps ({} late), {} models received, {} dropped",
            self.scene_steps, self.scene_late, c.models, self.models_dropped
        )?;
        if !self.scene_status.is_empty() {
            writeln!(f, "               {}", self.scene_status)?;
        }
        writeln!(
            f,
            "  dropped      telemetry {}, samples {}, events {}",
            c.telemetry_dropped, c.samples_dropped, c.events_dropped
        )?;
        write!(
            f,
            "  end          {} ({})",
            self.final_state.name(),
            if self.clean_stop {
                "forces ramped out, strings at minimum tension, device off"
            } else {
                "NOT a clean stop"
            }
        )
    }
}

/// What `run_live` needs.
pub struct LiveOptions {
    pub seconds: Option<f64>,
    pub rt: RtOptions,
    /// Sleep to this long before each deadline and spin the rest (0: pure sleep).
    pub spin_ns: u64,
    /// Print the status line (to stderr) every this often; None: quiet.
    pub status_every: Option<Duration>,
    pub stop: Arc<AtomicBool>,
    pub scene_name: String,
    pub script_name: String,
    /// Watch the scene thread's steps (the live view); they get the rig's geometry and status.
    pub observers: Vec<Box<dyn spidar_world::Observer>>,
}

/// Runs a session on the real clock until `seconds` pass or `stop` is set (Ctrl-C), then stops
/// cleanly: force ramps out, strings hold minimum tension, the device is switched off.
pub fn run_live<D: Device + 'static>(
    dev: D,
    rig: &Rig,
    scene: Box<dyn Scene>,
    opts: LiveOptions,
) -> anyhow::Result<Summary> {
    let device_name = format!("{} ({})", dev.info().board, dev.info().identity);
    let clock = MonotonicClock::new();
    let (ep, far) = Endpoints::pair();
    let mut rt = RtLoop::new(dev, clock.with_spin(opts.spin_ns), rig, ep)?;
    rt.configure().map_err(|e| anyhow::anyhow!("opening the device: {e}"))?;

    let scene_stop = Arc::new(AtomicBool::new(false));
    let scene_counters = Arc::new(SceneCounters::default());
    let FarEnds { commands, events, models, samples, telemetry } = far;
    // The viewers' rig status comes from the telemetry read below (the world's link will carry it).
    let mut rig_feed = None;
    let mut observers = scene_thread::Observers::default();
    if !opts.observers.is_empty() {
        let (feed, rx) = crate::rig_view::RigStatusFeed::new(rig);
        rig_feed = Some(feed);
        observers = scene_thread::Observers {
            list: opts.observers,
            rig_info: Some(crate::rig_view::rig_info(rig)),
            rig_status: Some(rx),
        };
    }
    let scene_handle = scene_thread::spawn(
        scene,
        clock,
        samples,
        models,
        scene_stop.clone(),
        scene_counters.clone(),
        observers,
    )
    .context("starting the scene thread")?;

    let rt_opts = opts.rt.clone();
    let rt_handle = std::thread::Builder::new()
        .name("spidar-rt".into())
        .spawn(move || {
            let report = rt_thread::setup_current_thread(&rt_opts);
            rt.run();
            (report, rt)
        })
        .context("starting the real-time thread")?;

    // The grips start at their home points on the simulated rig; a real rig's operator holds them
    // there before starting (see README).
    let _ = commands.try_send(Command::Home);
    let _ = commands.try_send(Command::Activate);

    let start = Instant::now();
    let mut stats = Stats::new();
    let mut last_status = Instant::now();
    let mut stop_sent = false;
    let mut faults_seen = Vec::new();
    let mut stopped = false;
    let mut stop_deadline = None;
    let status_every = opts.status_every;
    let mut printed_status = false;
    loop {
        // Poll (never block on) the loop's channels: see spidar_rt::runner.
        for r in telemetry.try_iter() {
            stats.add(&r);
            if let Some(f) = rig_feed.as_mut() {
                f.add(&r);
            }
        }
        for e in events.try_iter() {
            match e {
                Event::Fault(why) => faults_seen.push(format!("{why}")),
                Event::Refused { command, why } => faults_seen.push(format!("{command:?} refused: {why}")),
                Event::DeviceReopened => {
                    faults_seen.push("device reopened after a disconnect: home again".into())
                }
                Event::Stopped => stopped = true,
                _ => {}
            }
        }
        if stopped || rt_handle.is_finished() {
            break;
        }
        let elapsed = start.elapsed().as_secs_f64();
        let time_up = opts.seconds.is_some_and(|s| elapsed >= s);
        if !stop_sent && (time_up || opts.stop.load(Ordering::Relaxed)) {
            let _ = commands.try_send(Command::Stop);
            stop_sent = true;
            if let Some(f) = rig_feed.as_mut() {
                f.stopping();
            }
            stop_deadline = Some(Instant::now() + Duration::from_secs(5));
        }
        if stop_deadline.is_some_and(|d| Instant::now() > d) {
            bail!("the real-time loop did not stop within 5 s of the stop command");
        }
        if let Some(every) = status_every {
            if last_status.elapsed() >= every {
                last_status = Instant::now();
                let mut line =
                    status_line(&stats, faults_seen.len(), scene_counters.steps.load(Ordering::Relaxed));
                if let Ok(st) = scene_counters.status.lock() {
                    if !st.is_empty() {
                        line.push_str("  | ");
                        line.push_str(&st);
                    }
                }
                let mut err = std::io::stderr().lock();
                let _ = write!(err, "\r{line}\x1b[K");
                let _ = err.flush();
                printed_status = true;
                stats.reset_window();
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    if printed_status {
        eprintln!();
    }
    let (report, rt) = rt_handle.join().map_err(|_| anyhow::anyhow!("the real-time thread panicked"))?;
    for r in telemetry.try_iter() {
        stats.add(&r);
    }
    scene_stop.store(true, Ordering::Relaxed);
    let scene = scene_handle.join().map_err(|_| anyhow::anyhow!("the scene thread panicked"))?;
    Ok(Summary {
        scene_status: scene.status(),
        device: device_name,
        scene: opts.scene_name,
        script: opts.script_name,
        wall_s: start.elapsed().as_secs_f64(),
        rt: report,
        stats,
        counters: *rt.core().counters(),
        scene_steps: scene_counters.steps.load(Ordering::Relaxed),
        scene_late: scene_counters.late_steps.load(Ordering::Relaxed),
        models_dropped: scene_counters.models_dropped.load(Ordering::Relaxed),
        final_state: rt.state(),
        faults_seen,
        clean_stop: rt.is_finished(),
    })
}

/// The live status line: state, rate, lateness p99 over the window, forces, safety counts.
pub fn status_line(stats: &Stats, faults: usize, scene_steps: u64) -> String {
    let w = &stats.window;
    let Some(last) = w.last else { return "waiting for the first tick".into() };
    let p = w.lateness.percentiles();
    let f = |h: usize| last.hands[h].output_n.length();
    let fault = last.fault.map(|f| format!(" ({f})")).unwrap_or_default();
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
