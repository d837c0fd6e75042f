//! `spidar`: run a SPIDAR-H (real or simulated) with a scene behind it, and benchmark the loop.
//! Arguments are parsed here and checked into parameters; the work is in the library.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use spidar_device::Device;
use spidar_rt::rt_thread::{self, RtOptions};
use spidar_rt::telemetry::fmt_dur;
use spidar_rt::Rig;
use spidar_tools::bench::{bench_link, bench_rt, LinkBenchOptions, RtBenchOptions};
use spidar_tools::child_world::ChildWorldSpec;
use spidar_tools::hardware::{self, DeviceKind, HardwareArgs};
use spidar_tools::report;
use spidar_tools::session::{
    self, load_scripts, sim_device, LiveOptions, SimOptions, VirtualRun, WorldChoice,
};
use spidar_tools::signals::Stop;
use spidar_tools::world_process::WorldArgs;

#[derive(Parser)]
#[command(name = "spidar", version, about = "Real-time haptics for a two-hand SPIDAR-H string rig")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the 1 kHz haptic loop on a rig with a world behind it (Ctrl-C stops cleanly). The
    /// world runs as a child process unless --world says otherwise.
    Run(RunArgs),
    /// Run a world: a scene behind the rig-world link, waiting for a rig (`spidar run --world
    /// ADDR`), on this host or another.
    World(WorldArgs),
    /// Calibrate the string geometry: home, record, fit, verify (simulated rig by default).
    Calib {
        #[command(subcommand)]
        what: spidar_tools::calib::CalibCmd,
    },
    /// Serve the UART board protocol on a pseudo-terminal, backed by the simulated rig.
    Emulate(EmulateArgs),
    /// List serial ports and USB devices, what each is and whether it can be opened.
    Devices {
        /// Ask each serial port that opens for UART boards (sends the enumeration bytes).
        #[arg(long)]
        probe: bool,
        /// Also check this port (ptys, e.g. the emulator's link, are not listed by the OS).
        #[arg(long)]
        port: Vec<String>,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchCmd,
    },
    /// Evaluations against the papers: `reactions` (seed 000: timing during a bout and the
    /// reaction experiment), `impacts` (seed 002: impact-force estimation), `poses` (seed 002:
    /// contact sheets of the characters as drawn).
    Eval {
        #[command(subcommand)]
        what: EvalCmd,
        /// Print the results as JSON, for scripts.
        #[arg(long, global = true)]
        json: bool,
    },
    /// Print what a recording (`run --record`) holds; with --verify, re-run the rt-loop from its
    /// recorded inputs and check every output bit for bit.
    Replay(spidar_tools::recording::ReplayArgs),
    /// Write one CSV file per channel of a recording, each with a header line.
    Export(spidar_tools::recording::ExportArgs),
    /// Plot a recording as SVG: force per hand, tensions per string, lateness, events and hits.
    Plot(spidar_tools::recording::PlotArgs),
}

#[derive(Subcommand)]
enum EvalCmd {
    /// Seed 002 section 6.2: an automated estimator guesses impact forces from the keyframe
    /// characters' motion; prints accuracy, mean and std per parameter next to the paper's Table 1.
    Impacts {
        /// Scored hits (the paper: 6 subjects x 20).
        #[arg(long, default_value_t = 120)]
        trials: usize,
        /// Practice hits per parameter combination (54 combinations) for the estimator.
        #[arg(long, default_value_t = 4)]
        practice: usize,
        /// Seed of the random nuisance (heading, drift, exact strength and height).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// rig: hands push the character through the simulated rig, the rt-loop and the crowd
        /// scene (the user's path); stepper: a force on the crowd stepper's character (the paper's
        /// heights, down to the feet).
        #[arg(long, value_enum, default_value = "rig")]
        path: spidar_tools::eval_impacts::ImpactPath,
    },
    /// Seed 002: contact sheets (SVG) of the keyframe characters as drawn over their rigid bodies
    /// (a walk, a stagger, a fall each way, a stand-up), with the pose-against-body measures.
    Poses {
        /// Folder the sheets are written to.
        #[arg(long, default_value = "docs/poses")]
        out: PathBuf,
    },
    /// On the path of `spidar run` (simulated rig, rt-loop, boxing world, virtual clock): sim step
    /// and prediction cost during a bout, what punches of every kind did to an active and a
    /// passive virtual human, then the section 4.3 experiment: straights at four targets, an
    /// observer guesses each from the virtual human's motion.
    Reactions {
        /// Straights per target and mode (active, passive).
        #[arg(long, default_value_t = 24)]
        trials: usize,
        /// Punches of the punch experiment (each thrown at an active and a passive virtual
        /// human); 0 skips it.
        #[arg(long, default_value_t = 400)]
        punches: usize,
        /// Seed of the jabs (aim, hand, speed) and of the bout.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Length of the timed bout (s of rig time, virtual clock); 0 skips it.
        #[arg(long, default_value_t = 60.0)]
        bout_seconds: f64,
    },
}

#[derive(clap::Args)]
struct EmulateArgs {
    /// Rig file (RON) whose geometry the simulated rig has. Default: the built-in one.
    #[arg(long)]
    rig: Option<PathBuf>,
    /// The boards on the link, by model, ids 0, 1, ... in order (B1M, B1F, B2M, B2F, B3M, B3F, B5M).
    #[arg(long, default_value = "B1M,B1M")]
    boards: String,
    /// The boards' firmware generation: 2021 (since 2021-08: forces in the reply) or 2020
    /// (2020-01 to 2021-08: currents in the reply).
    #[arg(long, default_value_t = 2021, value_parser = clap::value_parser!(u32).range(2020..=2021))]
    firmware: u32,
    /// Path of the link to the pty (a symlink that survives `disconnect`/`reconnect`). Default:
    /// `uart` in a directory private to you ($XDG_RUNTIME_DIR/spidar, or /tmp/spidar-<uid>).
    #[arg(long)]
    link: Option<PathBuf>,
    /// The simulated user's hands: hold, circle, spar, tour, or a script file (.ron).
    #[arg(long, default_value = "tour")]
    script: String,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Encoder noise of the simulated rig, standard deviation in counts.
    #[arg(long, default_value_t = 0.0)]
    noise_counts: f64,
    /// Experiments only: zero the motors when no command came for this long. The real boards
    /// have no watchdog (they hold their last command), so by default neither do these.
    #[arg(long)]
    watchdog_ms: Option<u64>,
    /// Advance the rig one period per servo tick received instead of with the wall clock.
    #[arg(long)]
    per_tick: bool,
    /// Stop after this many seconds (default: until Ctrl-C or `quit` on stdin).
    #[arg(long)]
    seconds: Option<f64>,
    /// Serve at normal priority instead of SCHED_FIFO 70.
    #[arg(long)]
    no_rt: bool,
}

#[derive(clap::Args)]
struct RigArgs {
    /// Rig file (RON). Default: yours (~/.config/spidar/rig.ron, made by `spidar calib home`) if
    /// it exists, else the built-in configs/rig-spidar-h.ron.
    #[arg(long)]
    rig: Option<PathBuf>,
    /// Do not ask for SCHED_FIFO and locked memory.
    #[arg(long)]
    no_rt: bool,
    /// SCHED_FIFO priority for the loop thread.
    #[arg(long, default_value_t = 80, value_parser = clap::value_parser!(u8).range(1..=99))]
    priority: u8,
    /// Pin the loop thread to this CPU.
    #[arg(long)]
    cpu: Option<usize>,
    /// Accept a rig value beyond its physical bound (a key of the rig file's `overrides`, e.g.
    /// board_range); repeatable. The summary shows every override in effect.
    #[arg(long = "override", value_name = "KEY")]
    overrides: Vec<String>,
    /// Sleep to this many microseconds before each deadline, then busy-wait: hides the kernel's
    /// wake-up latency at the cost of that much CPU per millisecond.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=900))]
    spin_us: u64,
}

#[derive(clap::Args)]
struct RunArgs {
    #[command(flatten)]
    rig: RigArgs,
    /// Which device drives the rig.
    #[arg(long, value_enum, default_value = "sim")]
    device: DeviceKind,
    #[command(flatten)]
    hw: HardwareArgs,
    /// Scene behind the loop: `boxing` (the reactive virtual human, seed 000; the default),
    /// `boxing-passive` (its cognitive model off), a boxer file like configs/boxer.ron, `crowd`
    /// (keyframe characters to push, seed 002) or a crowd scene file (*crowd*.ron), `walls` (the
    /// rig check) or a walls scene file (.ron). With --world ADDR: the scene that world must run
    /// (default: whatever it runs).
    #[arg(long)]
    scene: Option<String>,
    /// Where the world runs: `child` (a `spidar world` process started here and restarted if it
    /// dies; the default), `thread` (inside this process), or the address of a world already
    /// running: unix:PATH, udp://HOST:PORT (`spidar world` prints its address).
    #[arg(long, default_value = "child")]
    world: String,
    /// How many times a child world that dies is restarted.
    #[arg(long, default_value_t = 3)]
    world_restarts: u32,
    /// How long to wait for the world's first answer, in seconds.
    #[arg(long, default_value_t = 30.0)]
    world_timeout_s: f64,
    /// Step the world (child or thread) with SCHED_FIFO at this priority, below the loop's
    /// (--priority): keeps the contact model fresh on a busy machine. Default: normal scheduler.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=98))]
    world_priority: Option<u8>,
    /// The simulated user's hands: box (straights, hooks, uppercuts and feints at the virtual
    /// human), crowd (pushes at the crowd's front row), hold, circle, spar, tour (for `walls`), or a
    /// script file (.ron).
    /// Default: the scene's own (crowd for a crowd scene, box otherwise).
    #[arg(long)]
    script: Option<String>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Seed of the simulated rig and of random scripts; the same seed gives the same run on the
    /// virtual clock.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Encoder noise of the simulated rig, standard deviation in counts.
    #[arg(long, default_value_t = 0.0)]
    noise_counts: f64,
    /// Simulate string sag when a tension drops below 0.3 N.
    #[arg(long)]
    slack: bool,
    /// Run on the virtual clock, as fast as the machine computes (needs --seconds).
    #[arg(long = "virtual")]
    virtual_clock: bool,
    /// No live status line.
    #[arg(long, short)]
    quiet: bool,
    /// The live view of the world (served by the world: the child process or the thread).
    #[command(flatten)]
    view: spidar_tools::world_process::ViewArgs,
    /// Record the session into this MCAP file (zstd chunks): every tick, every hand sample and
    /// contact model, the events, and the files that made the session. See docs/recording.md.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Print the summary as JSON, for scripts.
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
enum BenchCmd {
    /// The world step's time with the live view off, on without viewers and on with viewers
    /// reading every frame, in alternating blocks; and the viewers' frame rate.
    View {
        /// Rig file (RON). Default: the built-in configs/rig-spidar-h.ron.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// `boxing` (the box script), `boxing-passive` (no predictions: the step's time is steady)
        /// or `crowd` (the spar script).
        #[arg(long, default_value = "boxing")]
        scene: String,
        /// Characters in the crowd scene.
        #[arg(long, default_value_t = 1000)]
        characters: usize,
        /// Seconds of each block.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Rounds of the three blocks.
        #[arg(long, default_value_t = 5)]
        rounds: u32,
        /// Viewers in the viewers' blocks.
        #[arg(long, default_value_t = 3)]
        viewers: usize,
        /// Step the world under SCHED_FIFO at this priority (the viewers stay at normal priority).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=99))]
        fifo: Option<u8>,
    },
    /// Lateness of the tick loop next to a bare absolute-sleep loop, in one run.
    Rt {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds for each of the two loops.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Alternations between the two loops.
        #[arg(long, default_value_t = 10)]
        blocks: u32,
    },
    /// Wake-up lateness of live sessions with and without --record (alternating blocks), and the
    /// recording's size per hour.
    Record {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds of session for each arm.
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Alternations between the two arms.
        #[arg(long, default_value_t = 6)]
        blocks: u32,
        #[arg(long, default_value = "boxing")]
        scene: String,
        #[arg(long, default_value = "box")]
        script: String,
    },
    /// The rig-world link at 1 kHz: round trip and one-way latency through a world process (Unix
    /// socket and UDP on localhost), then the rig's wake-up lateness and the model age at the
    /// rig with the world as a process and as a thread, alternating in one run.
    Link {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds of the loop with each kind of world.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Alternations between the two kinds of world.
        #[arg(long, default_value_t = 10)]
        blocks: u32,
        /// The scene of both worlds.
        #[arg(long, default_value = "boxing")]
        scene: String,
        /// Samples echoed per transport for the round-trip figures (at 1 kHz).
        #[arg(long, default_value_t = 5000)]
        echoes: u64,
        /// SCHED_FIFO priority of both worlds (default: the normal scheduler).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=98))]
        world_priority: Option<u8>,
    },
    /// Round trip of one exchange over a pty to the board emulator, then the 1 kHz loop through it.
    Uart {
        #[command(flatten)]
        rig: RigArgs,
        /// Back-to-back exchanges for the round-trip figures.
        #[arg(long, default_value_t = 20_000)]
        exchanges: u64,
        /// Seconds of the 1 kHz loop through the link.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Deadline of one exchange, in microseconds.
        #[arg(long, default_value_t = 800)]
        reply_timeout_us: u64,
    },
}

fn load_rig(args: &RigArgs) -> anyhow::Result<Rig> {
    spidar_tools::rigpath::load_rig(args.rig.as_deref(), &args.overrides)
}

fn rt_options(args: &RigArgs) -> anyhow::Result<RtOptions> {
    if let Some(cpu) = args.cpu {
        rt_thread::check_cpu(cpu).map_err(|e| anyhow::anyhow!("--cpu {cpu}: {e}"))?;
    }
    Ok(if args.no_rt {
        RtOptions { fifo_priority: None, lock_memory: false, cpu: args.cpu, ..RtOptions::default() }
    } else {
        RtOptions { fifo_priority: Some(args.priority), cpu: args.cpu, ..RtOptions::default() }
    })
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Cmd::Run(a) => run(a),
        Cmd::World(a) => {
            let stop = Stop::install()?;
            spidar_tools::world_process::run_world(&a, &stop).map(|_| ())
        }
        Cmd::Calib { what } => spidar_tools::calib::run(what),
        Cmd::Emulate(a) => emulate(a),
        Cmd::Replay(a) => spidar_tools::recording::replay(&a),
        Cmd::Export(a) => spidar_tools::recording::export(&a),
        Cmd::Plot(a) => spidar_tools::recording::plot(&a),
        Cmd::Eval { what: EvalCmd::Reactions { trials, punches, seed, bout_seconds }, json } => {
            use spidar_tools::eval;
            if !json {
                println!("measured on {}\n", eval::PATH);
            }
            let mut bout = None;
            if bout_seconds > 0.0 {
                eprintln!("timing a {bout_seconds} s bout on the simulated rig (virtual clock) ...");
                let b = eval::bout_timing(bout_seconds, seed)?;
                if !json {
                    println!("bout of {} s (box script, active virtual human), per 3 ms step:", b.seconds);
                    println!("  world step   {}", b.step);
                    println!("  prediction   {}", b.prediction);
                    println!("  step+predict {}", b.step_with_prediction);
                    let [med, p99, max] = b.prediction_steps;
                    println!(
                        "  pred. steps  median {med}, p99 {p99}, max {max} of {} ahead",
                        b.horizon_steps
                    );
                    println!("  rt misses    {}", b.misses);
                    println!("  scene        {}\n", b.status);
                }
                bout = Some(b);
            }
            let mut punch_report = None;
            if punches > 0 {
                eprintln!("throwing {punches} punches at an active and a passive virtual human ...");
                let p = eval::punch_report(punches, seed)?;
                if !json {
                    println!("{p}\n");
                }
                punch_report = Some(p);
            }
            let r = eval::reactions(trials, seed, |done, total| {
                if done % 16 == 0 || done == total {
                    eprint!("\rjabs {done}/{total}\x1b[K");
                }
            })?;
            eprintln!();
            if json {
                let j = serde_json::json!({
                    "command": "eval reactions",
                    "path": eval::PATH,
                    "bout": bout,
                    "punches": punch_report,
                    "reactions": r,
                });
                println!("{j:#}");
            } else {
                println!("{r}");
            }
            Ok(())
        }
        Cmd::Eval { what: EvalCmd::Poses { out }, json } => {
            let report = spidar_tools::eval_poses::eval_poses(&out)?;
            if json {
                println!("{:#}", serde_json::json!({ "command": "eval poses", "report": report }));
            } else {
                println!("{report}");
            }
            Ok(())
        }
        Cmd::Devices { probe, port } => {
            print!("{}", hardware::devices_report(&port, probe));
            Ok(())
        }
        Cmd::Bench { what: BenchCmd::Uart { rig, exchanges, seconds, reply_timeout_us } } => {
            if !(seconds.is_finite() && seconds > 0.0) {
                bail!("--seconds must be a positive number");
            }
            let r = load_rig(&rig)?;
            let scripts = load_scripts("hold", &r, 1)?;
            eprintln!("{exchanges} round trips, then {seconds} s of the 1 kHz loop through the emulator ...");
            let rep = hardware::bench_uart(
                &r,
                scripts,
                exchanges,
                seconds,
                &rt_options(&rig)?,
                Duration::from_micros(reply_timeout_us),
            )?;
            println!("{rep}");
            Ok(())
        }
        Cmd::Eval { what: EvalCmd::Impacts { trials, practice, seed, path }, json } => {
            use spidar_tools::eval_impacts::{eval_impacts, ImpactOptions};
            if trials == 0 || practice == 0 {
                bail!("--trials and --practice must be at least 1");
            }
            let o = ImpactOptions {
                trials,
                practice_per_combo: practice,
                seed,
                path,
                ..ImpactOptions::default()
            };
            let report = eval_impacts(&o, |done, total| {
                if done % 50 == 0 || done == total {
                    eprint!("\r  simulated {done}/{total} hits");
                }
            })?;
            eprintln!();
            if json {
                println!("{:#}", serde_json::json!({ "command": "eval impacts", "report": report }));
            } else {
                println!("{report}");
            }
            Ok(())
        }
        Cmd::Bench { what: BenchCmd::Record { rig, seconds, blocks, scene, script } } => {
            if !(seconds.is_finite() && seconds > 0.0) {
                bail!("--seconds must be a positive number");
            }
            let r = load_rig(&rig)?;
            eprintln!("{blocks} blocks of live sessions each way, {seconds} s per arm ...");
            let rep = spidar_tools::bench_record::bench_record(
                &r,
                &spidar_tools::bench_record::RecordBenchOptions {
                    seconds_each: seconds,
                    blocks,
                    rt: rt_options(&rig)?,
                    scene,
                    script,
                    dir: std::env::temp_dir().join(format!("spidar-bench-record-{}", std::process::id())),
                },
            )?;
            println!("{rep}");
            Ok(())
        }
        Cmd::Bench { what: BenchCmd::Link { rig, seconds, blocks, scene, echoes, world_priority } } => {
            if !(seconds.is_finite() && seconds > 0.0) {
                bail!("--seconds must be a positive number");
            }
            let r = load_rig(&rig)?;
            eprintln!(
                "{echoes} round trips per transport, then {seconds} s of the loop with each kind of world in {blocks} blocks ..."
            );
            let rep = bench_link(
                &r,
                &LinkBenchOptions {
                    seconds_each: seconds,
                    blocks,
                    rt: rt_options(&rig)?,
                    scene,
                    echoes,
                    world: ChildWorldSpec {
                        extra: vec!["--no-view".into()],
                        ..ChildWorldSpec::this_executable("walls", 0)?
                    },
                    world_priority,
                },
            )?;
            println!("{rep}");
            Ok(())
        }
        Cmd::Bench { what: BenchCmd::View { rig, scene, characters, seconds, rounds, viewers, fifo } } => {
            use spidar_tools::bench_view::{bench_view, ViewBenchOptions};
            if !(seconds.is_finite() && seconds > 0.0) || rounds == 0 {
                bail!("--seconds must be a positive number and --rounds at least 1");
            }
            let r = match &rig {
                Some(p) => Rig::load(p)?,
                None => Rig::default_rig(),
            };
            eprintln!(
                "{rounds} rounds of three {seconds} s blocks (view off, no viewer, {viewers} viewers) ..."
            );
            let o = ViewBenchOptions { scene, characters, seconds_per_block: seconds, rounds, viewers, fifo };
            println!("{}", bench_view(&r, &o)?);
            Ok(())
        }
        Cmd::Bench { what: BenchCmd::Rt { rig, seconds, blocks } } => {
            if !(seconds.is_finite() && seconds > 0.0) {
                bail!("--seconds must be a positive number");
            }
            let r = load_rig(&rig)?;
            eprintln!("running each loop for {seconds} s in {blocks} blocks ...");
            let rep = bench_rt(
                &r,
                &RtBenchOptions {
                    seconds_each: seconds,
                    blocks,
                    rt: rt_options(&rig)?,
                    spin_ns: rig.spin_us * 1000,
                },
            )?;
            println!("{rep}");
            Ok(())
        }
    }
}

fn emulate(a: EmulateArgs) -> anyhow::Result<()> {
    let rig = match &a.rig {
        Some(p) => Rig::load(p)?,
        None => Rig::default_rig(),
    };
    if !(a.noise_counts.is_finite() && a.noise_counts >= 0.0) {
        bail!("--noise-counts must be >= 0");
    }
    let models =
        spidar_device::emulator::parse_models(&a.boards).map_err(|e| anyhow::anyhow!("--boards: {e}"))?;
    let scripts = load_scripts(&a.script, &rig, a.seed)?;
    let plant = if a.per_tick {
        spidar_device::emulator::PlantClock::PerTick
    } else {
        spidar_device::emulator::PlantClock::RealTime
    };
    let layout = if a.firmware == 2020 {
        spidar_device::uart::protocol::ReplyLayout::Currents
    } else {
        spidar_device::uart::protocol::ReplyLayout::Forces
    };
    let link = match a.link.clone() {
        Some(l) => l,
        None => hardware::default_link()?,
    };
    let opts = hardware::EmulateOptions {
        link,
        emulator: spidar_device::emulator::EmulatorOptions {
            watchdog: a.watchdog_ms.map(Duration::from_millis),
            fifo_priority: (!a.no_rt).then_some(70),
            ..hardware::emulator_options(&rig, models, layout, plant)
        },
        sim: SimOptions { seed: a.seed, encoder_noise_counts: a.noise_counts, ..Default::default() },
    };
    let emu = hardware::start_emulator(&rig, scripts, &opts)?;
    println!(
        "spidar emulate: boards {} ({}) on {} (link {}), rig '{}', script {}, watchdog {}",
        a.boards,
        layout.firmware(),
        emu.pty_path().map_or("?".into(), |p| p.display().to_string()),
        emu.link().display(),
        rig.name,
        a.script,
        a.watchdog_ms.map_or("none (as the real boards)".to_string(), |w| format!("{w} ms (experiment)"))
    );
    println!(
        "run the stack against it: spidar run --device uart   (--port {} is the default)",
        emu.link().display()
    );
    if !a.no_rt && !emu.control().fifo() {
        // The thread sets its policy as it starts; give it a moment before reporting.
        std::thread::sleep(Duration::from_millis(50));
    }
    println!(
        "serving thread: {}",
        if emu.control().fifo() {
            "SCHED_FIFO 70"
        } else {
            "normal priority (SCHED_FIFO not permitted or not asked)"
        }
    );
    println!("{}", hardware::EMULATE_HELP);
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("installing the Ctrl-C handler")?;
    }
    hardware::run_emulator(emu, stop, a.seconds)
}

fn run(a: RunArgs) -> anyhow::Result<()> {
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s > 0.0) {
            bail!("--seconds must be a positive number of seconds");
        }
    }
    if !(a.noise_counts.is_finite() && a.noise_counts >= 0.0) {
        bail!("--noise-counts must be >= 0");
    }
    if !(a.world_timeout_s.is_finite() && a.world_timeout_s > 0.0) {
        bail!("--world-timeout-s must be a positive number of seconds");
    }
    let rig = load_rig(&a.rig)?;
    // The rig file the run loads (yours when no --rig is given): named in the summary and the record.
    let rig_src = spidar_tools::rigpath::RigSource::resolve(a.rig.rig.as_deref());
    if let Some(p) = a.world_priority {
        if !a.rig.no_rt && p >= a.rig.priority {
            bail!("--world-priority {p} must be below the loop's --priority {}", a.rig.priority);
        }
    }
    let scene_arg = a.scene.clone().unwrap_or_else(|| "boxing".into());
    // The world's scene is loaded where the world runs: here for the virtual clock and a thread,
    // in the world process otherwise (the rig process stays small).
    let (mut world, scene_name) = match (a.virtual_clock, a.world.as_str()) {
        (true, "child" | "thread") | (false, "thread") => {
            let scene = spidar_world::load(&scene_arg)?;
            let name = format!("{scene_arg} ({})", scene.name());
            // The live view runs on the real clock only.
            let view = if a.virtual_clock {
                if a.view.view.is_some() {
                    eprintln!("spidar: no live view with --virtual (it runs faster than real time)");
                }
                None
            } else {
                spidar_tools::world_process::start_view(&a.view, &*scene)?
            };
            let mut stepper = spidar_world::host::Stepper::new(scene);
            if let Some(v) = view {
                stepper.add_observer(Box::new(v));
            }
            (WorldChoice::Thread(stepper), name)
        }
        (true, other) => bail!("--virtual runs the world in this process: leave out --world {other}"),
        (false, "child") => {
            let mut spec = ChildWorldSpec::this_executable(&scene_arg, a.world_restarts)?;
            if let Some(p) = a.world_priority {
                spec.extra.extend(["--priority".into(), p.to_string().into()]);
            }
            spec.extra.extend(a.view.child_args());
            (WorldChoice::Child(spec), scene_arg.clone())
        }
        (false, addr) => {
            if a.view.view.is_some() || a.view.no_view {
                eprintln!(
                    "spidar: the world at {addr} serves its own live view (spidar world --view/--no-view)"
                );
            }
            let at = spidar_link::Endpoint::parse(addr)
                .map_err(|e| anyhow::anyhow!("--world: {e}; or use child (the default) or thread"))?;
            let name = a.scene.clone().unwrap_or_else(|| "as the world runs it".into());
            (WorldChoice::Connect { at, scene: a.scene.clone() }, name)
        }
    };
    let script = a.script.clone().unwrap_or_else(|| session::default_script(&scene_arg).to_string());
    let scripts = load_scripts(&script, &rig, a.seed)?;
    let sim_opts = SimOptions {
        seed: a.seed,
        encoder_noise_counts: a.noise_counts,
        slack: a.slack,
        ..Default::default()
    };
    // Created before the device opens: a path that cannot be written stops the run here.
    let mut recorder = match &a.record {
        Some(path) => {
            let info = spidar_tools::recording::session_info(
                rig_src.path(),
                &scene_arg,
                &script,
                &format!("{:?}", a.device),
                a.seed,
                a.virtual_clock,
            )?;
            Some(spidar_tools::recording::create(path, &info)?)
        }
        None => None,
    };
    // The world's share: FILE.world.mcap next to FILE.mcap, written by the world wherever it
    // runs (this process or the child), on the rig recording's time line.
    let mut world_recording = None;
    let mut world_observer = None;
    if let Some(path) = &a.record {
        let wpath = spidar_record::world::world_path(path);
        let start_ns = recorder.as_ref().map(|r| r.start_unix_ns());
        match &mut world {
            WorldChoice::Thread(stepper) => {
                let (rec, obs) = spidar_tools::recording::start_world_recording(
                    &wpath,
                    &scene_arg,
                    stepper.scene(),
                    a.virtual_clock,
                    start_ns,
                )?;
                world_recording = Some(rec);
                if a.virtual_clock {
                    world_observer = Some(obs);
                } else {
                    stepper.add_observer(Box::new(obs));
                }
            }
            WorldChoice::Child(spec) => {
                spec.extra.extend(["--record".into(), wpath.into_os_string()]);
                if let Some(ns) = start_ns {
                    spec.extra.extend(["--record-start-unix-ns".into(), ns.to_string().into()]);
                }
            }
            WorldChoice::Connect { at, .. } => eprintln!(
                "spidar: the world at {at} is not recorded here; record it where it runs (spidar world --record FILE.mcap)"
            ),
        }
    }
    let dev: Box<dyn Device> = match a.hw.choice(a.device, &rig)? {
        None => {
            eprintln!(
                "spidar: rig '{}' on the simulated SPIDAR-H (seed {}), scene {}, script {}",
                rig.name, a.seed, scene_name, script
            );
            Box::new(sim_device(&rig, scripts, &sim_opts)?)
        }
        Some(choice) => {
            let dev = hardware::open_hardware(&choice)?;
            eprintln!(
                "spidar: rig '{}' on {} ({}), scene {}",
                rig.name,
                dev.info().board,
                dev.info().identity,
                scene_name
            );
            hardware::check_rig_against(&rig, dev.info())?;
            eprintln!("hold each grip at its home point: the rig homes as it starts");
            dev
        }
    };

    if a.virtual_clock {
        let Some(seconds) = a.seconds else { bail!("--virtual needs --seconds") };
        let WorldChoice::Thread(stepper) = world else {
            unreachable!("--virtual runs the world in this process")
        };
        let mut v = VirtualRun::new(dev, &rig, Some(stepper.into_scene()))?;
        if let Some(o) = world_observer.take() {
            v.observers.push(Box::new(o));
        }
        v.home_and_activate();
        let ticks = (seconds / rig.period_s).round() as u64;
        let t0 = std::time::Instant::now();
        for _ in 0..ticks {
            let r = v.tick();
            if let Some(rec) = recorder.as_mut() {
                rec.write_tick(&r);
            }
        }
        v.rt.command(spidar_rt::Command::Stop);
        loop {
            let more = v.rt.tick();
            if let Some(rec) = recorder.as_mut() {
                rec.write_tick(v.rt.last_record());
            }
            if !more {
                break;
            }
        }
        let wall = t0.elapsed().as_secs_f64();
        let c = *v.counters();
        let recording = recorder.map(|r| {
            r.finish(&spidar_record::writer::EndInfo {
                ticks: c.ticks,
                telemetry_dropped: 0,
                final_state: v.rt.state().name().into(),
                clean_stop: v.rt.is_finished(),
                faults: c.faults,
            })
        });
        let world_rec = world_recording.take().map(|r| r.finish());
        let status = v.scene.as_ref().map(|s| s.status()).unwrap_or_default();
        if a.json {
            let j = report::virtual_json(&report::VirtualRunReport {
                ticks: c.ticks,
                rig_seconds: seconds,
                wall_s: wall,
                stats: &v.stats,
                counters: &c,
                scene_status: &status,
                end: v.rt.state(),
                recording: recording.as_ref(),
                rig_file: &rig_src.describe(),
            });
            println!("{j:#}");
        } else {
            println!(
                "spidar run --virtual: {} ticks ({seconds} s of rig time) in {:.2} s wall ({:.0}x real time)",
                c.ticks,
                wall,
                seconds / wall
            );
            println!("  rig file     {}", rig_src.describe());
            println!("  compute      {}", v.stats.compute.percentiles());
            if !status.is_empty() {
                println!("  scene        {status}");
            }
            println!(
                "  max force    left {:.2} N, right {:.2} N",
                v.stats.max_force_n[0], v.stats.max_force_n[1]
            );
            println!(
                "  safety       clamped {}/{}, infeasible {}/{}, fallback {}/{}, faults {}",
                c.clamped[0],
                c.clamped[1],
                c.infeasible[0],
                c.infeasible[1],
                c.fallback[0],
                c.fallback[1],
                c.faults
            );
            if let Some(r) = &recording {
                println!("  recording    {r}");
            }
            if let Some(r) = &world_rec {
                println!("  world rec.   {r}");
            }
            println!("  end          {}", v.rt.state().name());
        }
        return report::check_outcome(v.rt.state(), &c, &[]);
    }

    let stop = Stop::install()?;
    let summary = session::run_live(
        dev,
        &rig,
        world,
        LiveOptions {
            seconds: a.seconds,
            rt: rt_options(&a.rig)?,
            spin_ns: a.rig.spin_us * 1000,
            status_every: (!a.quiet).then_some(Duration::from_millis(500)),
            stop,
            scene_name,
            script_name: script.clone(),
            connect_timeout: Duration::from_secs_f64(a.world_timeout_s),
            world_priority: a.world_priority,
            recorder: match recorder {
                Some(r) => Some(spidar_record::writer::RecorderThread::spawn(r)?),
                None => None,
            },
        },
    )?;
    let mut summary = summary;
    summary.rig_file = rig_src.describe();
    let recording = summary.recording.clone();
    // The scene thread has stopped: the world's recording ends with its last step.
    let world_rec = world_recording.take().map(|r| r.finish());
    if a.json {
        println!("{:#}", report::run_json(&summary, recording.as_ref()));
    } else {
        println!("{summary}");
        if let Some(r) = &recording {
            println!("  recording    {r}");
        }
        if let Some(r) = &world_rec {
            println!("  world rec.   {r}");
        }
    }
    let lat = summary.stats.lateness.percentiles();
    if summary.counters.misses > 0 {
        eprintln!(
            "note: {} ticks woke more than 1 ms late (worst {}); see `spidar bench rt` for this machine's floor",
            summary.counters.misses,
            fmt_dur(lat.max_s)
        );
    }
    if !summary.clean_stop {
        bail!("the loop did not stop cleanly");
    }
    report::check_outcome(summary.final_state, &summary.counters, &summary.faults_seen)
}
