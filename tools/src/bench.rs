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

use crate::session::{load_scripts, sim_device, SimOptions};
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
