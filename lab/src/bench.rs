//! `spidar bench rt`: the tick loop and a bare absolute-sleep loop, side by side in one run.
//!
//! Both run on the same real-time thread, in alternating blocks, so that they see the same
//! machine: the bare loop (sleep to the deadline, note the lateness, nothing else) is the floor the
//! operating system gives; the tick loop (the simulated rig, the rig-check scene stepped inline
//! every 3 ms, the full tick) should be no worse. DESIGN.md section 8: p99.9 no worse than the
//! bare loop's, no tick more than 1 ms late.

use spidar_rt::rt_thread::{self, RtOptions, RtReport};
use spidar_rt::telemetry::{DurationHist, Percentiles};
use spidar_rt::{Clock, Command, Endpoints, MonotonicClock, Rig, RtLoop};

use spidar_runtime::session::{load_scripts, sim_device, SimOptions};
use spidar_world::{walls::WallsScene, Scene};

pub struct RtBenchOptions {
    /// Total seconds for each loop.
    pub seconds_each: f64,
    /// Number of alternations.
    pub blocks: u32,
    pub rt: RtOptions,
    /// Sleep to this long before each deadline and spin the rest, in both loops (0: pure sleep).
    pub spin_ns: u64,
}

pub struct LoopResult {
    pub lateness: Percentiles,
    pub over_100us: u64,
    pub over_500us: u64,
    pub over_1ms: u64,
    pub cycles: u64,
}

pub struct RtBenchReport {
    pub rt: RtReport,
    pub bare: LoopResult,
    pub tick: LoopResult,
    pub compute: Percentiles,
    pub io: Percentiles,
}

fn result(h: &DurationHist) -> LoopResult {
    LoopResult {
        lateness: h.percentiles(),
        over_100us: h.count_above(100e-6),
        over_500us: h.count_above(500e-6),
        over_1ms: h.count_above(1e-3),
        cycles: h.len(),
    }
}

pub fn bench_rt(rig: &Rig, opts: &RtBenchOptions) -> anyhow::Result<RtBenchReport> {
    let scripts = load_scripts("tour", rig, 1)?;
    let dev = sim_device(rig, scripts, &SimOptions::default())?;
    let rig = rig.clone();
    let rt_opts = opts.rt.clone();
    let blocks = opts.blocks.max(1);
    let spin_ns = opts.spin_ns;
    let per_block = ((opts.seconds_each / blocks as f64) / rig.period_s).round().max(1.0) as u64;
    let handle = std::thread::Builder::new().name("spidar-bench-rt".into()).spawn(
        move || -> anyhow::Result<RtBenchReport> {
            let report = rt_thread::setup_current_thread(&rt_opts);
            let mut clock = MonotonicClock::new().with_spin(spin_ns);
            let (ep, far) = Endpoints::pair();
            let mut rt = RtLoop::new(dev, clock, &rig, ep)?;
            rt.configure().map_err(|e| anyhow::anyhow!("opening the simulated rig: {e}"))?;
            rt.command(Command::Home);
            rt.command(Command::Activate);
            let mut scene = WallsScene::builtin();
            let scene_every = (scene.step_s() / rig.period_s).round().max(1.0) as u64;
            let period_ns = (rig.period_s * 1e9).round() as u64;
            let (mut bare, mut tick, mut compute, mut io) = (
                DurationHist::default(),
                DurationHist::default(),
                DurationHist::default(),
                DurationHist::default(),
            );
            let mut samples = Vec::with_capacity(64);
            for _ in 0..blocks {
                let mut deadline = clock.now_ns() + period_ns;
                for _ in 0..per_block {
                    let wake = clock.sleep_until(deadline);
                    bare.record(wake.saturating_sub(deadline) as f64 * 1e-9);
                    deadline += period_ns;
                }
                rt.resync();
                for k in 0..per_block {
                    rt.tick();
                    let r = rt.last_record();
                    tick.record(r.lateness_s);
                    compute.record(r.compute_s);
                    io.record(r.io_s);
                    for _ in far.telemetry.try_iter() {}
                    if k % scene_every == 0 {
                        samples.clear();
                        samples.extend(far.samples.try_iter());
                        let _ = far.models.try_send(scene.step(clock.now_ns() as f64 * 1e-9, &samples));
                    }
                }
            }
            rt.command(Command::Stop);
            while rt.tick() {}
            Ok(RtBenchReport {
                rt: report,
                bare: result(&bare),
                tick: result(&tick),
                compute: compute.percentiles(),
                io: io.percentiles(),
            })
        },
    )?;
    handle.join().map_err(|_| anyhow::anyhow!("the benchmark thread panicked"))?
}

impl std::fmt::Display for RtBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "spidar bench rt: wake-up lateness at 1 kHz, both loops in alternating blocks on one thread"
        )?;
        writeln!(f, "  real time   {}", self.rt)?;
        for w in &self.rt.warnings {
            writeln!(f, "  warning     {w}")?;
        }
        for (name, r) in [("bare sleep", &self.bare), ("tick loop", &self.tick)] {
            writeln!(
                f,
                "  {name:<11} {} cycles: {}; > 100 us {}, > 500 us {}, > 1 ms {}",
                r.cycles, r.lateness, r.over_100us, r.over_500us, r.over_1ms
            )?;
        }
        writeln!(f, "  tick compute {} (both hands, excluding device I/O)", self.compute)?;
        write!(f, "  sim-rig I/O  {}", self.io)
    }
}

// ---------------------------------------------------------------------------------------------
// `spidar bench link`

/// What `spidar bench link` runs.
pub struct LinkBenchOptions {
    /// Seconds of the loop with each kind of world.
    pub seconds_each: f64,
    /// Alternations between the world as a process and as a thread.
    pub blocks: u32,
    pub rt: RtOptions,
    /// The scene of both worlds.
    pub scene: String,
    /// Samples echoed for the round-trip figures, per transport.
    pub echoes: u64,
    /// How to start a world process (`spidar world` from this executable).
    pub world: spidar_runtime::child_world::ChildWorldSpec,
    /// SCHED_FIFO priority of both worlds (None: the normal scheduler).
    pub world_priority: Option<u8>,
}

/// Latency of one transport.
pub struct EchoResult {
    pub transport: String,
    pub round_trip: Percentiles,
    pub one_way: Percentiles,
    pub unanswered: u64,
}

/// The loop with one kind of world.
pub struct WorldBlock {
    pub lateness: LoopResult,
    /// Age of the contact model each active tick used.
    pub model_age: Percentiles,
    pub models: u64,
    pub stale_ticks: u64,
}

pub struct LinkBenchReport {
    pub rt: RtReport,
    pub world_priority: Option<u8>,
    pub scene: String,
    pub step_s: f64,
    pub echo: Vec<EchoResult>,
    pub process: WorldBlock,
    pub thread: WorldBlock,
}

/// Round trips at 1 kHz through an echo world process at `at`: send a sample on the deadline,
/// wait for its echo (up to 0.9 ms), record; the echo carries the rig-to-world trip as the
/// world's kernel stamped the sample's arrival.
fn echo_round_trips(
    rig: &Rig,
    spec: &spidar_runtime::child_world::ChildWorldSpec,
    at: &spidar_link::Endpoint,
    dir: &spidar_link::PrivateDir,
    n: u64,
) -> anyhow::Result<EchoResult> {
    use spidar_link::RigLink;
    let mut spec = spec.clone();
    spec.extra.push("--echo".into());
    let mut clock = MonotonicClock::new();
    let (mut child, mut link, _) = spidar_runtime::session::start_child_world_at(
        rig,
        spec,
        at,
        dir,
        &clock,
        std::time::Duration::from_secs(30),
    )?;
    let waiter = link.waiter()?;
    let (mut rtt, mut one_way) = (DurationHist::default(), DurationHist::default());
    let mut unanswered = 0;
    let period_ns = 1_000_000;
    let mut deadline = clock.now_ns() + period_ns;
    for k in 1..=n {
        clock.sleep_until(deadline);
        deadline += period_ns;
        let sent_ns = clock.now_ns();
        let now_s = sent_ns as f64 * 1e-9;
        let _ = link.poll(now_s); // late echoes of earlier samples
        link.send_sample(&spidar_runtime::world_process::echo_sample(k, now_s));
        let mut answered = false;
        loop {
            let left = (sent_ns + 900_000).saturating_sub(clock.now_ns());
            if left == 0 || !waiter.wait(std::time::Duration::from_nanos(left)) {
                break;
            }
            if let Some(m) = link.poll(clock.now_ns() as f64 * 1e-9) {
                if m.seq == k {
                    rtt.record((clock.now_ns() - sent_ns) as f64 * 1e-9);
                    one_way.record(m.extra_force_n[0].x);
                    answered = true;
                    break;
                }
            }
        }
        unanswered += !answered as u64;
    }
    link.close();
    child.stop(std::time::Duration::from_secs(2), &mut |_| {});
    Ok(EchoResult {
        transport: match at {
            spidar_link::Endpoint::Unix(_) => "Unix datagram socket".into(),
            spidar_link::Endpoint::Udp(a) => format!("UDP on {}", a.ip()),
        },
        round_trip: rtt.percentiles(),
        one_way: one_way.percentiles(),
        unanswered,
    })
}

/// `spidar bench link`: the link's round trip and one-way latency at 1 kHz (Unix socket and UDP
/// on localhost, through an echo world process), then the rig's wake-up lateness and the model
/// age at the rig with the world as a process and as a thread, in alternating blocks on one
/// real-time thread: `spidar run`'s path (simulated rig, rt-loop, the same world code).
pub fn bench_link(rig: &Rig, opts: &LinkBenchOptions) -> anyhow::Result<LinkBenchReport> {
    use spidar_link::{channel, PrivateDir};
    let script = if opts.scene.starts_with("boxing") { "box" } else { "tour" };
    let scripts = load_scripts(script, rig, 1)?;
    let dev = sim_device(rig, scripts, &SimOptions::default())?;
    // The thread's scene is built here, where the world thread will run.
    let scene = spidar_world::load(&opts.scene)?;
    let rig = rig.clone();
    let rt_opts = opts.rt.clone();
    let blocks = opts.blocks.max(1);
    let per_block = ((opts.seconds_each / blocks as f64) / rig.period_s).round().max(1.0) as u64;
    let world_spec = opts.world.clone();
    let echoes = opts.echoes;
    let world_priority = opts.world_priority;
    let scene_name = opts.scene.clone();
    // Everything runs on one thread set up for real time; the worlds it starts (process and
    // thread) run with the normal scheduler.
    let handle = std::thread::Builder::new().name("spidar-bench-link".into()).spawn(
        move || -> anyhow::Result<LinkBenchReport> {
            let report = rt_thread::setup_current_thread(&rt_opts);
            let dir = PrivateDir::for_process()?;
            let echo = if echoes > 0 { echo_both(&rig, &world_spec, &dir, echoes)? } else { Vec::new() };

            let clock = MonotonicClock::new();
            let mut spec = world_spec.clone();
            spec.scene = scene_name.clone();
            if let Some(p) = world_priority {
                spec.extra.extend(["--priority".into(), p.to_string().into()]);
            }
            let (mut child, plink, welcome) = spidar_runtime::session::start_child_world(
                &rig,
                spec,
                &dir,
                &clock,
                std::time::Duration::from_secs(60),
            )?;
            let (ep, _far) = Endpoints::pair();
            let mut rt = RtLoop::new(dev, clock, &rig, ep)?;
            rt.configure().map_err(|e| anyhow::anyhow!("opening the simulated rig: {e}"))?;
            rt.command(Command::Home);
            rt.command(Command::Activate);
            let mut process_link: Option<Box<dyn spidar_link::RigLink>> = Some(Box::new(plink));
            let mut stepper = Some(spidar_world::host::Stepper::new(scene));
            let info = spidar_rt::status::rig_info(&rig);
            let (mut late, mut age) = (
                [DurationHist::default(), DurationHist::default()],
                [DurationHist::default(), DurationHist::default()],
            );
            let mut models = [0u64; 2];
            let mut stale = [0u64; 2];
            const PROCESS: usize = 0;
            const THREAD: usize = 1;
            for b in 0..blocks {
                let order = if b % 2 == 0 { [PROCESS, THREAD] } else { [THREAD, PROCESS] };
                for mode in order {
                    let mut thread = None;
                    if mode == PROCESS {
                        // The link was closed at the end of its last block: it says hello again.
                        rt.replace_link(process_link.take());
                    } else {
                        let (rig_end, world_end) = channel::pair();
                        let scene = stepper.take().expect("the thread's scene");
                        thread = Some(spawn_scene_thread(scene, clock, world_end, info, world_priority)?);
                        rt.replace_link(Some(Box::new(rig_end)));
                    }
                    let (m, s) = measure_block(&mut rt, per_block, &mut late[mode], &mut age[mode]);
                    models[mode] += m;
                    stale[mode] += s;
                    let link = rt.replace_link(None);
                    if let Some((h, stop)) = thread {
                        stop.store(true, std::sync::atomic::Ordering::Relaxed);
                        stepper = Some(h.join().map_err(|_| anyhow::anyhow!("the scene thread panicked"))?);
                    } else if let Some(mut l) = link {
                        l.close(); // the world pauses until the next process block
                        process_link = Some(l);
                    }
                }
            }
            rt.command(Command::Stop);
            while rt.tick() {}
            child.stop(std::time::Duration::from_secs(3), &mut |_| {});
            let block = |m: usize| WorldBlock {
                lateness: result(&late[m]),
                model_age: age[m].percentiles(),
                models: models[m],
                stale_ticks: stale[m],
            };
            Ok(LinkBenchReport {
                rt: report,
                world_priority,
                scene: format!("{} ({})", scene_name, welcome.scene),
                step_s: welcome.step_s,
                echo,
                process: block(PROCESS),
                thread: block(THREAD),
            })
        },
    )?;
    handle.join().map_err(|_| anyhow::anyhow!("the benchmark thread panicked"))?
}

/// The round trips through an echo world on a Unix socket, then on UDP on localhost.
fn echo_both(
    rig: &Rig,
    world: &spidar_runtime::child_world::ChildWorldSpec,
    dir: &spidar_link::PrivateDir,
    echoes: u64,
) -> anyhow::Result<Vec<EchoResult>> {
    use spidar_link::Endpoint;
    let unix = echo_round_trips(rig, world, &Endpoint::unix(&dir.join("echo.sock")), dir, echoes)?;
    let port = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?.port();
    let udp = echo_round_trips(rig, world, &Endpoint::Udp(([127, 0, 0, 1], port).into()), dir, echoes)?;
    Ok(vec![unix, udp])
}

/// A world thread stepping `scene` behind the channel's world end, with its stop flag.
type SceneThread =
    (std::thread::JoinHandle<spidar_world::host::Stepper>, std::sync::Arc<std::sync::atomic::AtomicBool>);

fn spawn_scene_thread(
    scene: spidar_world::host::Stepper,
    clock: MonotonicClock,
    world_end: spidar_link::channel::ChannelWorldEnd,
    info: spidar_msg::RigInfo,
    world_priority: Option<u8>,
) -> anyhow::Result<SceneThread> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let counters = std::sync::Arc::new(spidar_runtime::scene_thread::SceneCounters::default());
    let h = spidar_runtime::scene_thread::spawn(
        scene,
        clock,
        world_end,
        info,
        stop.clone(),
        counters,
        world_priority,
    )?;
    Ok((h, stop))
}

/// One block of the loop with the world connected: 300 ticks to settle (the world connects again
/// and its models are fresh), then `ticks` measured into `late` and `age`. Returns the models
/// received and the stale ticks during the measured ticks.
fn measure_block<D: spidar_device::Device, C: spidar_rt::Clock>(
    rt: &mut RtLoop<D, C>,
    ticks: u64,
    late: &mut DurationHist,
    age: &mut DurationHist,
) -> (u64, u64) {
    for _ in 0..300 {
        rt.tick();
    }
    rt.resync();
    let (m0, s0) = (rt.core().counters().models, rt.core().counters().stale);
    for _ in 0..ticks {
        rt.tick();
        let r = rt.last_record();
        late.record(r.lateness_s);
        if r.state == spidar_rt::Lifecycle::Active && r.contact_age_s.is_finite() {
            age.record(r.contact_age_s.max(0.0));
        }
    }
    (rt.core().counters().models - m0, rt.core().counters().stale - s0)
}

impl std::fmt::Display for LinkBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "spidar bench link: spidar run's path (simulated rig, rt-loop, world {}), at 1 kHz",
            self.scene
        )?;
        writeln!(
            f,
            "  worlds      {}",
            self.world_priority.map_or("normal scheduler".to_string(), |p| format!("SCHED_FIFO {p}"))
        )?;
        writeln!(f, "  real time   {}", self.rt)?;
        for w in &self.rt.warnings {
            writeln!(f, "  warning     {w}")?;
        }
        for e in &self.echo {
            writeln!(
                f,
                "  {}: round trip {} ({} samples, {} unanswered within 0.9 ms)",
                e.transport, e.round_trip, e.round_trip.count, e.unanswered
            )?;
            writeln!(f, "      one way rig -> world {}", e.one_way)?;
        }
        for (name, b) in [("world as a process", &self.process), ("world as a thread ", &self.thread)] {
            writeln!(
                f,
                "  {name}: lateness {}; > 500 us {}, > 1 ms {} of {} ticks",
                b.lateness.lateness, b.lateness.over_500us, b.lateness.over_1ms, b.lateness.cycles
            )?;
            writeln!(
                f,
                "      model age at the rig {}; {} models, {} stale ticks",
                b.model_age, b.models, b.stale_ticks
            )?;
        }
        write!(
            f,
            "  goal: model age p99 <= one world step ({:.1} ms) + 1 ms = {:.1} ms",
            self.step_s * 1e3,
            self.step_s * 1e3 + 1.0
        )
    }
}
