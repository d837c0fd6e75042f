//! `spidar bench view`: what the live view costs the world's step, with no viewer and with three,
//! in alternating blocks of one run, and how fast the viewers get their frames.
//!
//! The world thread here is the scene thread's loop (3 ms on the real clock), fed by the simulated
//! rig and the rt-loop ticked on the virtual clock in step with it (the user's path: the `box`
//! script's punches reach the virtual human through the loop's proxies). Each step is timed from
//! the scene's step through the observers' calls. Blocks cycle: view off (no observer), view on
//! with no viewer, view on with `viewers` WebSocket clients reading every frame.
//!
//! Where it runs is part of what it measures: by default (with two CPUs or more) the world thread
//! has a CPU of its own and the browsers, their drivers and the bench's other threads run on the
//! rest, as on a rig whose display's browser draws on other cores or another machine
//! ([`crate::cpus::Placement`]). Each step's thread CPU time and whether the thread was preempted
//! while stepping are kept beside its wall time, to tell a step slowed on its CPU from one taken
//! off it.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use spidar_rt::telemetry::{DurationHist, Percentiles};
use spidar_rt::{Clock, MonotonicClock, Rig};
use spidar_world::crowd::CrowdScene;
use spidar_world::view::{View, ViewOptions};
use spidar_world::{Observer, Scene, StepView};

use spidar_rt::status::rig_info;
use spidar_runtime::session::{load_scripts, sim_device, SimOptions, VirtualRun};

/// A crowd scene of `n` characters: the built-in one, spread over an area that holds them.
pub fn crowd_of(n: usize) -> anyhow::Result<CrowdScene> {
    use spidar_sim::character::keyframe::KEYFRAMES_HUMANOID_RON;
    use spidar_sim::character::scene::{build_crowd, BODY_CHARACTER_RON, SCENE_CROWD_RON};
    // The built-in scene with `n` characters on a square area 1.2 m apart in front of the user,
    // its near edge where the built-in scene has it.
    let side = ((n as f64).sqrt().ceil() * 1.2 + 1.2).max(4.8);
    let field = |key: &str| -> anyhow::Result<(usize, usize)> {
        let at = SCENE_CROWD_RON.find(key).ok_or_else(|| anyhow::anyhow!("no {key} in the crowd scene"))?;
        let end = at + SCENE_CROWD_RON[at..].find(',').unwrap_or(0);
        let end = if key == "area_m:" { at + SCENE_CROWD_RON[at..].find(')').unwrap_or(0) + 1 } else { end };
        Ok((at, end))
    };
    let (area_at, area_end) = field("area_m:")?;
    let near: f64 = SCENE_CROWD_RON[area_at..area_end - 1]
        .rsplit(',')
        .next()
        .and_then(|v| v.trim().parse().ok())
        .ok_or_else(|| anyhow::anyhow!("the crowd scene's area_m is not four numbers"))?;
    let (count_at, count_end) = field("count:")?;
    let area = format!("area_m: ({:.1}, {:.1}, {:.1}, {near})", -side / 2.0, near - side, side / 2.0);
    let mut text = SCENE_CROWD_RON.to_string();
    // The later field first: the earlier one's offsets stay valid.
    let mut edits = [(area_at, area_end, area), (count_at, count_end, format!("count: {n}"))];
    edits.sort_by_key(|e| std::cmp::Reverse(e.0));
    for (a, b, with) in edits {
        text.replace_range(a..b, &with);
    }
    let crowd = build_crowd(&text, &format!("the built-in crowd with {n} characters"), |name| {
        let t = if name == "body-character.ron" { BODY_CHARACTER_RON } else { KEYFRAMES_HUMANOID_RON };
        Ok((t.to_string(), name.to_string()))
    })?;
    Ok(CrowdScene::new(crowd, &format!("crowd of {n} keyframe characters")))
}

pub struct ViewBenchOptions {
    /// `boxing`, `boxing-passive` or `crowd`.
    pub scene: String,
    /// Characters of the crowd scene.
    pub characters: usize,
    pub seconds_per_block: f64,
    /// Rounds of the three blocks.
    pub rounds: u32,
    pub viewers: usize,
    /// Step the world under SCHED_FIFO at this priority (the viewers stay at normal priority).
    pub fifo: Option<u8>,
    /// The viewers' block has one real browser (headless chromium drawing the page from the user's
    /// eye) instead of WebSocket clients.
    pub browser: bool,
    /// A block with a headless chromium drawing the page in an immersive session of an emulated
    /// headset (`crate::browser::Headset`: node, puppeteer-core and iwer from tests/browser).
    pub headset: bool,
    /// More of the browsers' page query (`shading=standard&aa=1`, say).
    pub page: String,
    /// The view's most frames a second (None: its default, a frame after every step).
    pub frame_hz: Option<f64>,
    /// The world thread's CPU, and the CPUs of the browsers and the bench's other threads.
    pub world_cpu: crate::cpus::CpuChoice,
    pub browser_cpus: crate::cpus::CpuChoice,
}

/// What a block has watching the world.
#[derive(Clone, Copy)]
enum Block {
    Off,
    NoViewer,
    Viewers(usize),
    Browser,
    Headset,
}

impl Block {
    fn name(&self) -> String {
        match self {
            Block::Off => "view off".into(),
            Block::NoViewer => "view, no viewer".into(),
            Block::Viewers(n) => format!("view, {n} viewers"),
            Block::Browser => "view, a screen".into(),
            Block::Headset => "view, a headset".into(),
        }
    }
}

/// A block's browser, if it has one.
enum Page {
    None,
    // Held for its drop, which stops the browser.
    #[allow(dead_code)]
    Screen(crate::browser::Browser),
    Headset(crate::browser::Headset),
}

impl Page {
    /// Whether the page is drawing as the block wants (a headset: in its session).
    fn ready(&mut self) -> anyhow::Result<bool> {
        match self {
            Page::Headset(h) => h.presenting(),
            Page::None | Page::Screen(_) => Ok(true),
        }
    }
}

#[derive(Default)]
pub struct Phase {
    pub step: DurationHist,
    /// The scene's step alone (without the observers' calls), and the observers' calls.
    pub scene: DurationHist,
    pub observer: DurationHist,
    /// The world thread's CPU time over the whole step (what it ran, not what it waited).
    pub cpu: DurationHist,
    /// Steps during which the world thread was switched out while it could run (preempted).
    pub preempted: u64,
    /// Steps that started more than one step late.
    pub late: u64,
    /// Frames the viewers read, and the seconds they were connected (summed over viewers).
    pub frames_read: u64,
    pub viewer_seconds: f64,
    pub min_viewer_hz: f64,
    /// A browser's picture ages per block (p50, p99 ms).
    pub ages: Vec<(f64, f64)>,
}

pub struct ViewBenchReport {
    pub scene: String,
    pub frame_bytes: u64,
    pub phases: Vec<(String, Phase)>,
    pub load: String,
    pub rt: String,
    pub placement: crate::cpus::Placement,
}

type Spawn = (String, Arc<AtomicBool>, Arc<AtomicU64>, Arc<AtomicU64>);

/// One viewer: a WebSocket client that reads every message until told to stop.
fn viewer(
    url: String,
    stop: Arc<AtomicBool>,
    frames: Arc<AtomicU64>,
    bytes: Arc<AtomicU64>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let addr = url.trim_start_matches("ws://").to_string();
        let Ok(stream) = std::net::TcpStream::connect(&addr) else { return };
        let Ok((mut ws, _)) = tungstenite::client(format!("{url}/"), stream) else { return };
        let _ = ws.get_mut().set_read_timeout(Some(Duration::from_millis(100)));
        while !stop.load(Ordering::Relaxed) {
            match ws.read() {
                Ok(tungstenite::Message::Binary(b)) => {
                    frames.fetch_add(1, Ordering::Relaxed);
                    bytes.store(b.len() as u64, Ordering::Relaxed);
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
                Err(_) => break,
            }
        }
    })
}

impl Phase {
    /// A viewer read `frames` in `secs`.
    fn viewer_read(&mut self, frames: u64, secs: f64) {
        self.frames_read += frames;
        self.viewer_seconds += secs;
        let hz = frames as f64 / secs;
        self.min_viewer_hz = if self.min_viewer_hz == 0.0 { hz } else { self.min_viewer_hz.min(hz) };
    }
}

/// The world a block steps: the rig on the virtual clock, the scene, and the view when it watches.
struct World<'a> {
    v: &'a mut VirtualRun<spidar_device::sim::SimRig>,
    scene: &'a mut dyn Scene,
    info: &'a spidar_msg::RigInfo,
    observer: Option<&'a mut dyn Observer>,
}

impl World<'_> {
    /// One world step after the rig's ticks of its span, not timed (while a browser starts).
    fn step_unmeasured(self, samples: &mut Vec<spidar_msg::HandSample>, ticks_per_step: u64) {
        let World { v, scene, info, observer } = self;
        for _ in 0..ticks_per_step {
            v.rt.tick();
        }
        for _ in v.far.telemetry.try_iter() {}
        samples.clear();
        samples.extend(v.far.samples.try_iter());
        let t = v.clock.now_ns() as f64 * 1e-9;
        let m = scene.step(t, samples);
        if let Some(o) = observer {
            let sv = StepView {
                t_s: t,
                scene: &*scene,
                samples,
                model: &m,
                rig_info: Some(info),
                rig_status: None,
            };
            o.after_step(&sv);
        }
        let _ = v.far.models.try_send(m);
    }

    /// `steps` world steps paced by `clock` at the scene's rate, each after the rig's ticks of its
    /// span, timed into `phase` (the whole step, the scene's part, the observer's part).
    fn step_block(
        self,
        clock: &mut MonotonicClock,
        samples: &mut Vec<spidar_msg::HandSample>,
        phase: &mut Phase,
        steps: u64,
        ticks_per_step: u64,
    ) {
        let World { v, scene, info, mut observer } = self;
        let step_ns = (scene.step_s() * 1e9).round() as u64;
        let mut deadline = clock.now_ns();
        for _ in 0..steps {
            let wake = clock.sleep_until(deadline);
            if wake > deadline + step_ns {
                phase.late += 1;
            }
            for _ in 0..ticks_per_step {
                v.rt.tick();
            }
            for _ in v.far.telemetry.try_iter() {}
            samples.clear();
            samples.extend(v.far.samples.try_iter());
            let t = v.clock.now_ns() as f64 * 1e-9;
            // The CPU clock and the switch count are read outside the wall-clock stamps.
            let switches = crate::cpus::thread_involuntary_switches();
            let c0 = crate::cpus::thread_cpu_ns();
            let t0 = Instant::now();
            let m = scene.step(t, samples);
            let t1 = Instant::now();
            if let Some(o) = observer.as_mut() {
                let sv = StepView {
                    t_s: t,
                    scene: &*scene,
                    samples,
                    model: &m,
                    rig_info: Some(info),
                    rig_status: None,
                };
                o.after_step(&sv);
            }
            let t2 = Instant::now();
            let c2 = crate::cpus::thread_cpu_ns();
            if crate::cpus::thread_involuntary_switches() > switches {
                phase.preempted += 1;
            }
            let _ = v.far.models.try_send(m);
            phase.cpu.record(c2.saturating_sub(c0) as f64 * 1e-9);
            phase.step.record((t2 - t0).as_secs_f64());
            phase.scene.record((t1 - t0).as_secs_f64());
            phase.observer.record((t2 - t1).as_secs_f64());
            deadline += step_ns;
            if clock.now_ns() > deadline + 10 * step_ns {
                deadline = clock.now_ns();
            }
        }
    }
}

pub fn bench_view(rig: &Rig, o: &ViewBenchOptions) -> anyhow::Result<ViewBenchReport> {
    let (mut scene, script): (Box<dyn Scene>, &str) = match o.scene.as_str() {
        "boxing" | "boxing-passive" => (spidar_world::load(&o.scene)?, "box"),
        "crowd" => (Box::new(crowd_of(o.characters)?), "spar"),
        other => {
            anyhow::bail!("unknown scene '{other}' for the view bench: use boxing, boxing-passive or crowd")
        }
    };
    let allowed = crate::cpus::allowed_cpus();
    let placement = crate::cpus::Placement::resolve(&o.world_cpu, &o.browser_cpus, &allowed)
        .map_err(|e| anyhow::anyhow!(e))?;
    // The view's threads and the viewers' spawner are started on the others' CPUs (threads inherit
    // their creator's), then this thread, the world's, moves to its own.
    let others = placement.others.clone().unwrap_or_default();
    crate::cpus::pin_current_thread(&others).context("moving the bench to --browser-cpus")?;
    let scripts = load_scripts(script, rig, 1)?;
    let dev = sim_device(rig, scripts, &SimOptions::default())?;
    let mut v = VirtualRun::new(dev, rig, None)?;
    v.home_and_activate();
    let look = scene.look();
    let mut view = View::start(
        scene.name(),
        &look,
        &ViewOptions {
            addr: ([127, 0, 0, 1], 0).into(),
            frame_hz: o.frame_hz.unwrap_or(ViewOptions::default().frame_hz),
            world_step_s: scene.step_s(),
            ..Default::default()
        },
    )
    .context("starting the view")?;
    let handle = view.counters_handle();
    let info = rig_info(rig);
    // Viewers are started by a thread of normal priority: threads inherit their creator's policy.
    let (spawn_tx, spawn_rx) = std::sync::mpsc::channel::<Spawn>();
    let (joined_tx, joined_rx) = std::sync::mpsc::channel();
    let spawner = std::thread::spawn(move || {
        for (url, stop, frames, bytes) in spawn_rx {
            let _ = joined_tx.send(viewer(url, stop, frames, bytes));
        }
    });
    let world_cpus = placement.world.map_or(allowed.clone(), |w| vec![w]);
    crate::cpus::pin_current_thread(&world_cpus).context("pinning the world thread to --world-cpu")?;
    let rt = match o.fifo {
        Some(p) => spidar_rt::rt_thread::setup_current_thread(&spidar_rt::rt_thread::RtOptions {
            fifo_priority: Some(p),
            lock_memory: false,
            prefault_stack_bytes: 0,
            cpu: None,
        })
        .to_string(),
        None => "normal priority".to_string(),
    };
    let ticks_per_step = (scene.step_s() / rig.period_s).round().max(1.0) as u64;
    let mut blocks = vec![Block::Off, Block::NoViewer];
    if o.browser {
        blocks.push(Block::Browser);
    } else if o.viewers > 0 || !o.headset {
        blocks.push(Block::Viewers(o.viewers));
    }
    if o.headset {
        blocks.push(Block::Headset);
    }
    let mut phases: Vec<(String, Phase)> = blocks.iter().map(|b| (b.name(), Phase::default())).collect();
    let mut clock = MonotonicClock::new();
    let mut samples = Vec::with_capacity(64);
    let bytes = Arc::new(AtomicU64::new(0));
    let steps_per_block = (o.seconds_per_block / scene.step_s()).round().max(1.0) as u64;
    for _ in 0..o.rounds {
        for (block, (_, phase)) in blocks.iter().zip(phases.iter_mut()) {
            let stop = Arc::new(AtomicBool::new(false));
            let (want, clients) = match *block {
                Block::Off | Block::NoViewer => (0, 0),
                Block::Viewers(n) => (n, n),
                Block::Browser | Block::Headset => (1, 0),
            };
            let counts: Vec<Arc<AtomicU64>> = (0..clients).map(|_| Arc::new(AtomicU64::new(0))).collect();
            // A real browser draws the page (its frames drawn, from the ages it reports).
            let url = handle.url();
            let mut page = match block {
                Block::Browser => Page::Screen(crate::browser::Browser::open(
                    &format!("{url}/?camera=eye&{}", o.page),
                    960,
                    540,
                    &others,
                )?),
                Block::Headset => {
                    Page::Headset(crate::browser::Headset::open(url, &o.page, 960, 540, &others)?)
                }
                _ => Page::None,
            };
            for c in &counts {
                spawn_tx.send((handle.ws_url().to_string(), stop.clone(), c.clone(), bytes.clone()))?;
            }
            let threads: Vec<_> = counts.iter().filter_map(|_| joined_rx.recv().ok()).collect();
            let browser = !matches!(page, Page::None);
            let until = Instant::now() + Duration::from_secs(if browser { 90 } else { 5 });
            loop {
                let connected = handle.counters().viewers.load(Ordering::Relaxed) == want;
                if connected && page.ready()? {
                    break;
                }
                if Instant::now() > until {
                    anyhow::bail!("{}: the page was not drawing after 90 s", block.name());
                }
                // The world steps on while a browser starts (its page needs frames to draw).
                if browser {
                    let world =
                        World { v: &mut v, scene: &mut *scene, info: &info, observer: Some(&mut view) };
                    world.step_unmeasured(&mut samples, ticks_per_step);
                    std::thread::sleep(Duration::from_millis(3));
                } else {
                    std::thread::sleep(Duration::from_millis(10));
                }
            }
            handle.clear_picture_ages();
            let started = Instant::now();
            let at_start: Vec<u64> = counts.iter().map(|c| c.load(Ordering::Relaxed)).collect();
            let observer: Option<&mut dyn Observer> =
                if matches!(block, Block::Off) { None } else { Some(&mut view) };
            let world = World { v: &mut v, scene: &mut *scene, info: &info, observer };
            world.step_block(&mut clock, &mut samples, phase, steps_per_block, ticks_per_step);
            let secs = started.elapsed().as_secs_f64();
            for (c, s) in counts.iter().zip(at_start) {
                phase.viewer_read(c.load(Ordering::Relaxed) - s, secs);
            }
            if browser {
                let (screen, headset) = handle.picture_ages().summaries();
                let drew = if matches!(block, Block::Headset) { headset } else { screen };
                if let Some(a) = drew {
                    phase.frames_read += a.frames as u64;
                    phase.viewer_seconds += secs;
                    let hz = a.frames as f64 / secs;
                    phase.min_viewer_hz =
                        if phase.min_viewer_hz == 0.0 { hz } else { phase.min_viewer_hz.min(hz) };
                    phase.ages.push((a.p50_ms, a.p99_ms));
                }
            }
            drop(page);
            stop.store(true, Ordering::Relaxed);
            for t in threads {
                let _ = t.join();
            }
        }
    }
    drop(spawn_tx);
    let _ = spawner.join();
    let load = std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default();
    Ok(ViewBenchReport {
        scene: scene.name().to_string(),
        frame_bytes: bytes.load(Ordering::Relaxed),
        phases,
        load,
        rt,
        placement,
    })
}

fn row(p: &Percentiles) -> String {
    use spidar_rt::telemetry::fmt_dur;
    format!(
        "{:>9} {:>9} {:>9} {:>9}",
        fmt_dur(p.p50_s),
        fmt_dur(p.p99_s),
        fmt_dur(p.p999_s),
        fmt_dur(p.max_s)
    )
}

impl std::fmt::Display for ViewBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "spidar bench view: scene {}, world step = scene step + observers, blocks alternating (load average {})", self.scene, self.load)?;
        writeln!(f, "  world thread: {}; {}", self.rt, self.placement)?;
        writeln!(
            f,
            "  {:<18} {:>7} {:>9} {:>9} {:>9} {:>9} {:>6}   scene p99   observer p99    cpu p99  preempted   frames/s per viewer",
            "", "steps", "p50", "p99", "p99.9", "max", "late"
        )?;
        for (name, p) in &self.phases {
            if !p.ages.is_empty() {
                let worst = p.ages.iter().fold((0.0f64, 0.0f64), |a, b| (a.0.max(b.0), a.1.max(b.1)));
                writeln!(f, "  {name}: picture age per block, worst p50 {:.1} ms, worst p99 {:.1} ms (frames drawn a second as 'frames/s')", worst.0, worst.1)?;
            }
            let rate = if p.viewer_seconds > 0.0 {
                format!(
                    "{:.1} (min {:.1}), {} kB a frame",
                    p.frames_read as f64 / p.viewer_seconds,
                    p.min_viewer_hz,
                    self.frame_bytes / 1000
                )
            } else {
                "-".into()
            };
            writeln!(
                f,
                "  {name:<18} {:>7} {} {:>6}   {:>9}   {:>12}  {:>9}  {:>9}   {rate}",
                p.step.len(),
                row(&p.step.percentiles()),
                p.late,
                spidar_rt::telemetry::fmt_dur(p.scene.percentiles().p99_s),
                spidar_rt::telemetry::fmt_dur(p.observer.percentiles().p99_s),
                spidar_rt::telemetry::fmt_dur(p.cpu.percentiles().p99_s),
                p.preempted,
            )?;
        }
        Ok(())
    }
}
