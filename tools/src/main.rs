//! `spidar`: run a SPIDAR-H (real or simulated) with a scene behind it, and benchmark the loop.
//! Arguments are parsed here and checked into parameters; the work is in the library.
//!
//! Exit status: 0 done; 1 an error, or a session that ended faulted or never became active; 2 a
//! command line that cannot be used; 3 the rig process died or hung on real boards and its
//! supervisor wrote zero to them; 4 the supervisor could not (use the emergency stop).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

mod calib;

use anyhow::bail;
use clap::parser::ValueSource;
use clap::{ArgMatches, CommandFactory, FromArgMatches, Parser, Subcommand};
use spidar_device::Device;
use spidar_lab::bench::{bench_link, bench_rt, LinkBenchOptions, RtBenchOptions};
use spidar_rt::rt_thread::{self, RtOptions};
use spidar_rt::telemetry::fmt_dur;
use spidar_rt::Rig;
use spidar_runtime::child_world::ChildWorldSpec;
use spidar_runtime::hardware::{self, DeviceKind, HardwareArgs};
use spidar_runtime::report;
use spidar_runtime::session::{
    self, load_scripts, sim_device, LiveOptions, SimOptions, VirtualOptions, WorldChoice,
};
use spidar_runtime::signals::Stop;
use spidar_runtime::world_process::WorldArgs;
use spidar_runtime::{errln, outln, supervisor, term};

/// Longest `spidar run` or `spidar emulate` (a week): a number that would run for ever is a typo.
const MAX_RUN_S: f64 = 7.0 * 24.0 * 3600.0;
/// Longest benchmark or evaluation phase.
const MAX_BENCH_S: f64 = 3600.0;

/// A number of seconds in (0, `max`].
fn seconds_upto(s: &str, max: f64) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= max {
        Ok(v)
    } else {
        Err(format!("must be more than 0 and at most {max} s"))
    }
}
fn run_seconds(s: &str) -> Result<f64, String> {
    seconds_upto(s, MAX_RUN_S)
}
fn bench_seconds(s: &str) -> Result<f64, String> {
    seconds_upto(s, MAX_BENCH_S)
}
/// 0 (skip) or a number of seconds up to an hour.
fn bout_seconds(s: &str) -> Result<f64, String> {
    if s.trim().parse::<f64>().is_ok_and(|v| v == 0.0) {
        return Ok(0.0);
    }
    seconds_upto(s, MAX_BENCH_S)
}
/// Encoder noise: 0 to 1000 counts.
fn noise_counts(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number of counts"))?;
    if v.is_finite() && (0.0..=1000.0).contains(&v) {
        Ok(v)
    } else {
        Err("must be between 0 and 1000 counts".into())
    }
}

#[derive(Parser)]
#[command(name = "spidar", version, about = "Real-time haptics for a two-hand SPIDAR-H string rig")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the 1 kHz haptic loop on a rig with a world behind it. Ctrl-C, SIGTERM or SIGHUP stop
    /// cleanly (force ramps out, strings at minimum tension, boards off, summary); a second one
    /// stops at once with the outputs zeroed. The world runs as a child process unless --world
    /// says otherwise. On real boards a supervisor process writes zero to them if the rig process
    /// dies or hangs.
    Run(RunArgs),
    /// Run a world: a scene behind the rig-world link, waiting for a rig (`spidar run --world
    /// ADDR`), on this host or another.
    World(WorldArgs),
    /// Calibrate the string geometry: home, record, fit, verify (simulated rig by default).
    Calib {
        #[command(subcommand)]
        what: crate::calib::CalibCmd,
    },
    /// Serve the UART board protocol on a pseudo-terminal, backed by the simulated rig (Ctrl-C,
    /// SIGTERM or SIGHUP print the final status and remove the link).
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
    /// Evaluations: `reactions` (the virtual boxer's timing during a bout, and how readable its
    /// reactions to jabs are), `impacts` (how well impact forces can be told from the keyframe
    /// characters' motion), `poses` (contact sheets of the characters as drawn).
    Eval {
        #[command(subcommand)]
        what: EvalCmd,
        /// Print the results as JSON, for scripts.
        #[arg(long, global = true)]
        json: bool,
    },
    /// Play a recording (`run --record`) into the live view (the page gets a playback bar: play,
    /// pause, seek, speed) and print what it holds; with --verify, re-run the rt-loop from its
    /// recorded inputs and check every output bit for bit.
    Replay(spidar_runtime::replay::ReplayArgs),
    /// Write one CSV file per channel of a recording, each with a header line.
    Export(spidar_runtime::replay::ExportArgs),
    /// Plot a recording as SVG: force per hand, tensions per string, lateness, events and hits.
    Plot(spidar_runtime::replay::PlotArgs),
}

#[derive(Subcommand)]
enum EvalCmd {
    /// Keyframe characters are hit with random strengths, heights and directions; an automated
    /// estimator that practised on other hits guesses each hit's parameters from the character's
    /// motion alone. Prints accuracy, mean and standard deviation per parameter, next to the
    /// figures people reached in the published study this repeats.
    Impacts {
        /// Scored hits.
        #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u64).range(1..=100_000))]
        trials: u64,
        /// Practice hits per parameter combination (54 combinations) for the estimator.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=1000))]
        practice: u64,
        /// Seed of the random nuisance (heading, drift, exact strength and height).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// rig: hands push the character through the simulated rig, the rt-loop and the crowd
        /// scene (the user's path); stepper: a force on the crowd stepper's character (at heights
        /// down to the feet).
        #[arg(long, value_enum, default_value = "rig")]
        path: spidar_lab::eval_impacts::ImpactPath,
    },
    /// Contact sheets (SVG) of the keyframe characters as drawn over their rigid bodies
    /// (a walk, a stagger, a fall each way, a stand-up), with the pose-against-body measures.
    Poses {
        /// Folder the sheets are written to.
        #[arg(long, default_value = "docs/poses")]
        out: PathBuf,
    },
    /// On the path of `spidar run` (simulated rig, rt-loop, boxing world, virtual clock): sim step
    /// and prediction cost during a bout, what punches of every kind did to an active and a
    /// passive virtual human, then the reaction experiment: straights at four targets, an
    /// observer guesses each target from the virtual human's motion alone, with its cognitive
    /// model on and off.
    Reactions {
        /// Straights per target and mode (active, passive).
        #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u64).range(1..=10_000))]
        trials: u64,
        /// Punches of the punch experiment (each thrown at an active and a passive virtual
        /// human), at most 100000; 0 skips it.
        #[arg(long, default_value_t = 400, value_parser = clap::value_parser!(u64).range(0..=100_000))]
        punches: u64,
        /// Seed of the jabs (aim, hand, speed) and of the bout.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Length of the timed bout (s of rig time, virtual clock; at most 3600); 0 skips it.
        #[arg(long, default_value_t = 60.0, value_parser = bout_seconds)]
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
    /// Encoder noise of the simulated rig, standard deviation in counts (0 to 1000).
    #[arg(long, default_value_t = 0.0, value_parser = noise_counts)]
    noise_counts: f64,
    /// Experiments only: zero the motors when no command came for this long. The real boards
    /// have no watchdog (they hold their last command), so by default neither do these.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    watchdog_ms: Option<u64>,
    /// Advance the rig one period per servo tick received instead of with the wall clock.
    #[arg(long)]
    per_tick: bool,
    /// Stop after this many seconds, at most a week (default: until Ctrl-C, SIGTERM, SIGHUP or
    /// `quit` on stdin).
    #[arg(long, value_parser = run_seconds)]
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
    /// Scene behind the loop: `boxing` (a virtual human who predicts your punches and blocks,
    /// dodges or hits back; the default), `boxing-passive` (the same body with its mind off),
    /// `crowd` (keyframe characters to push, who stagger, step, fall and get up), `walls` (the rig
    /// check), or a boxer, crowd scene or walls scene file of any name (it says what it is: see
    /// configs/ and docs/formats.md). With --world ADDR: the scene that world must run (default:
    /// whatever it runs).
    #[arg(long)]
    scene: Option<String>,
    /// Where the world runs: `child` (a `spidar world` process started here and restarted if it
    /// dies; the default), `thread` (inside this process), or the address of a world already
    /// running: unix:PATH, udp://HOST:PORT (`spidar world` prints its address).
    #[arg(long, default_value = "child")]
    world: String,
    /// How many times a child world that dies is restarted (at most 100).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=100))]
    world_restarts: u32,
    /// How long to wait for the world's first answer, in seconds (at most 3600).
    #[arg(long, default_value_t = 30.0, value_parser = bench_seconds)]
    world_timeout_s: f64,
    /// Step the world (child or thread) with SCHED_FIFO at this priority, below the loop's
    /// (--priority): keeps the contact model fresh on a busy machine. Default: normal scheduler.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=98))]
    world_priority: Option<u8>,
    /// The simulated user's hands (--device sim only): box (straights, hooks, uppercuts and
    /// feints at the virtual human), crowd (pushes at the crowd's front row), hold, circle, spar,
    /// tour (for `walls`), or a script file of any name (see configs/script-example.ron).
    /// Default: the scene's own (crowd for a crowd scene, box otherwise).
    #[arg(long)]
    script: Option<String>,
    /// Stop after this many seconds, at most a week (default: run until Ctrl-C, SIGTERM or SIGHUP).
    #[arg(long, value_parser = run_seconds)]
    seconds: Option<f64>,
    /// Seed of the simulated rig and of random scripts (--device sim only); the same seed gives
    /// the same run on the virtual clock.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Encoder noise of the simulated rig, standard deviation in counts, 0 to 1000 (--device sim
    /// only).
    #[arg(long, default_value_t = 0.0, value_parser = noise_counts)]
    noise_counts: f64,
    /// Simulate string sag when a tension drops below 0.3 N (--device sim only).
    #[arg(long)]
    slack: bool,
    /// Run on the virtual clock, as fast as the machine computes (needs --seconds; the world
    /// runs in this process).
    #[arg(long = "virtual")]
    virtual_clock: bool,
    /// No live status line.
    #[arg(long, short)]
    quiet: bool,
    /// The live view of the world (served by the world: the child process or the thread).
    #[command(flatten)]
    view: spidar_runtime::world_process::ViewArgs,
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
        /// Characters in the crowd scene (at most 100000).
        #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(0..=100_000))]
        characters: u32,
        /// Seconds of each block (at most 3600).
        #[arg(long, default_value_t = 2.0, value_parser = bench_seconds)]
        seconds: f64,
        /// Rounds of the three blocks.
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
        rounds: u32,
        /// Viewers in the viewers' blocks (at most 64).
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=64))]
        viewers: u32,
        /// Step the world under SCHED_FIFO at this priority (the viewers stay at normal priority).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=99))]
        fifo: Option<u8>,
    },
    /// Lateness of the tick loop next to a bare absolute-sleep loop, in one run.
    Rt {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds for each of the two loops (at most 3600).
        #[arg(long, default_value_t = 10.0, value_parser = bench_seconds)]
        seconds: f64,
        /// Alternations between the two loops.
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=1000))]
        blocks: u32,
    },
    /// Wake-up lateness of live sessions with and without --record (alternating blocks), and the
    /// recording's size per hour.
    Record {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds of session for each arm (at most 3600).
        #[arg(long, default_value_t = 60.0, value_parser = bench_seconds)]
        seconds: f64,
        /// Alternations between the two arms.
        #[arg(long, default_value_t = 6, value_parser = clap::value_parser!(u32).range(1..=1000))]
        blocks: u32,
        #[arg(long, default_value = "boxing")]
        scene: String,
        #[arg(long, default_value = "box")]
        script: String,
    },
    /// Playing a recording into the view (`spidar replay`): the time to open it and to seek to
    /// random times, and the frame rate it serves to WebSocket viewers at 1x.
    Replay {
        /// The recording (FILE.mcap with FILE.world.mcap next to it, or FILE.world.mcap).
        file: PathBuf,
        /// Seeks to random times.
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..=100_000))]
        seeks: u64,
        /// WebSocket viewers reading every frame (at most 64).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=64))]
        viewers: u64,
        /// Seconds of playing to them (at most 3600).
        #[arg(long, default_value_t = 10.0, value_parser = bench_seconds)]
        seconds: f64,
    },
    /// The rig-world link at 1 kHz: round trip and one-way latency through a world process (Unix
    /// socket and UDP on localhost), then the rig's wake-up lateness and the model age at the
    /// rig with the world as a process and as a thread, alternating in one run.
    Link {
        #[command(flatten)]
        rig: RigArgs,
        /// Seconds of the loop with each kind of world (at most 3600).
        #[arg(long, default_value_t = 10.0, value_parser = bench_seconds)]
        seconds: f64,
        /// Alternations between the two kinds of world.
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=1000))]
        blocks: u32,
        /// The scene of both worlds.
        #[arg(long, default_value = "boxing")]
        scene: String,
        /// Samples echoed per transport for the round-trip figures (at 1 kHz); 0 skips them.
        #[arg(long, default_value_t = 5000, value_parser = clap::value_parser!(u64).range(0..=10_000_000))]
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
        #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
        exchanges: u64,
        /// Seconds of the 1 kHz loop through the link (at most 3600).
        #[arg(long, default_value_t = 10.0, value_parser = bench_seconds)]
        seconds: f64,
        /// Deadline of one exchange, in microseconds.
        #[arg(long, default_value_t = 800, value_parser = clap::value_parser!(u64).range(50..=100_000))]
        reply_timeout_us: u64,
    },
}

fn load_rig(args: &RigArgs) -> anyhow::Result<Rig> {
    spidar_runtime::rigpath::load_rig(args.rig.as_deref(), &args.overrides)
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

fn main() -> ExitCode {
    // A rig process started by its supervisor finds the shared page before any thread starts.
    if let Err(e) = supervisor::attach_from_env() {
        errln!("Error: {e:?}");
        return ExitCode::FAILURE;
    }
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    match dispatch(cli, &matches) {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            errln!("Error: {e:?}");
            ExitCode::FAILURE
        }
    }
}

/// Runs a command; the exit status (0 unless a supervisor took the boards over).
fn dispatch(cli: Cli, matches: &ArgMatches) -> anyhow::Result<u8> {
    match cli.command {
        Cmd::Run(a) => run(a, matches.subcommand_matches("run").unwrap_or(matches)),
        Cmd::World(a) => {
            let stop = Stop::install()?;
            spidar_runtime::world_process::run_world(&a, &stop).map(|_| 0)
        }
        Cmd::Calib { what } => crate::calib::run(what),
        Cmd::Emulate(a) => emulate(a).map(|_| 0),
        Cmd::Replay(a) => spidar_runtime::replay::replay(&a).map(|_| 0),
        Cmd::Export(a) => spidar_runtime::replay::export(&a).map(|_| 0),
        Cmd::Plot(a) => spidar_runtime::replay::plot(&a).map(|_| 0),
        Cmd::Eval { what: EvalCmd::Reactions { trials, punches, seed, bout_seconds }, json } => {
            use spidar_lab::eval;
            let stop = Stop::install()?;
            if !json {
                outln!("measured on {}\n", eval::PATH);
            }
            let mut bout = None;
            if bout_seconds > 0.0 {
                errln!("timing a {bout_seconds} s bout on the simulated rig (virtual clock) ...");
                let b = eval::bout_timing(bout_seconds, seed)?;
                if !json {
                    outln!("bout of {} s (box script, active virtual human), per 3 ms step:", b.seconds);
                    outln!("  world step   {}", b.step);
                    outln!("  prediction   {}", b.prediction);
                    outln!("  step+predict {}", b.step_with_prediction);
                    let [med, p99, max] = b.prediction_steps;
                    outln!("  pred. steps  median {med}, p99 {p99}, max {max} of {} ahead", b.horizon_steps);
                    outln!("  rt misses    {}", b.misses);
                    outln!("  scene        {}\n", b.status);
                }
                bout = Some(b);
            }
            let mut punch_report = None;
            if punches > 0 {
                errln!("throwing {punches} punches at an active and a passive virtual human ...");
                let p = eval::punch_report(punches as usize, seed, |done, total| {
                    stopped_eval(&stop, done, total, "punches");
                    if done % 16 == 0 || done == total {
                        term::progress(&format!("punches {done}/{total}"));
                    }
                })?;
                term::progress_done();
                if !json {
                    outln!("{p}\n");
                }
                punch_report = Some(p);
            }
            let r = eval::reactions(trials as usize, seed, |done, total| {
                stopped_eval(&stop, done, total, "straights");
                if done % 16 == 0 || done == total {
                    term::progress(&format!("straights {done}/{total}"));
                }
            })?;
            term::progress_done();
            if json {
                let j = serde_json::json!({
                    "command": "eval reactions",
                    "path": eval::PATH,
                    "bout": bout,
                    "punches": punch_report,
                    "reactions": r,
                });
                outln!("{j:#}");
            } else {
                outln!("{r}");
            }
            Ok(0)
        }
        Cmd::Eval { what: EvalCmd::Poses { out }, json } => {
            let report = spidar_lab::eval_poses::eval_poses(&out)?;
            if json {
                outln!("{:#}", serde_json::json!({ "command": "eval poses", "report": report }));
            } else {
                outln!("{report}");
            }
            Ok(0)
        }
        Cmd::Devices { probe, port } => {
            outln!("{}", hardware::devices_report(&port, probe).trim_end());
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::Uart { rig, exchanges, seconds, reply_timeout_us } } => {
            let r = load_rig(&rig)?;
            let scripts = load_scripts("hold", &r, 1)?;
            errln!("{exchanges} round trips, then {seconds} s of the 1 kHz loop through the emulator ...");
            let rep = hardware::bench_uart(
                &r,
                scripts,
                exchanges,
                seconds,
                &rt_options(&rig)?,
                Duration::from_micros(reply_timeout_us),
            )?;
            outln!("{rep}");
            Ok(0)
        }
        Cmd::Eval { what: EvalCmd::Impacts { trials, practice, seed, path }, json } => {
            use spidar_lab::eval_impacts::{eval_impacts, ImpactOptions};
            let o = ImpactOptions {
                trials: trials as usize,
                practice_per_combo: practice as usize,
                seed,
                path,
                ..ImpactOptions::default()
            };
            let stop = Stop::install()?;
            let report = eval_impacts(&o, |done, total| {
                stopped_eval(&stop, done, total, "hits");
                if done % 50 == 0 || done == total {
                    term::progress(&format!("  simulated {done}/{total} hits"));
                }
            })?;
            term::progress_done();
            if json {
                outln!("{:#}", serde_json::json!({ "command": "eval impacts", "report": report }));
            } else {
                outln!("{report}");
            }
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::Record { rig, seconds, blocks, scene, script } } => {
            let r = load_rig(&rig)?;
            errln!("{blocks} blocks of live sessions each way, {seconds} s per arm ...");
            let rep = spidar_lab::bench_record::bench_record(
                &r,
                &spidar_lab::bench_record::RecordBenchOptions {
                    seconds_each: seconds,
                    blocks,
                    rt: rt_options(&rig)?,
                    scene,
                    script,
                    dir: std::env::temp_dir().join(format!("spidar-bench-record-{}", std::process::id())),
                },
            )?;
            outln!("{rep}");
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::Replay { file, seeks, viewers, seconds } } => {
            use spidar_lab::bench_replay::{bench_replay, ReplayBenchOptions};
            errln!(
                "opening {}, {seeks} seeks, then {seconds} s of playing to {viewers} viewer(s) ...",
                file.display()
            );
            let o = ReplayBenchOptions { file, seeks: seeks as usize, viewers: viewers as usize, seconds };
            outln!("{}", bench_replay(&o)?);
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::Link { rig, seconds, blocks, scene, echoes, world_priority } } => {
            let r = load_rig(&rig)?;
            errln!(
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
            outln!("{rep}");
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::View { rig, scene, characters, seconds, rounds, viewers, fifo } } => {
            use spidar_lab::bench_view::{bench_view, ViewBenchOptions};
            let (characters, viewers) = (characters as usize, viewers as usize);
            let r = match &rig {
                Some(p) => Rig::load(p)?,
                None => Rig::default_rig(),
            };
            errln!(
                "{rounds} rounds of three {seconds} s blocks (view off, no viewer, {viewers} viewers) ..."
            );
            let o = ViewBenchOptions { scene, characters, seconds_per_block: seconds, rounds, viewers, fifo };
            outln!("{}", bench_view(&r, &o)?);
            Ok(0)
        }
        Cmd::Bench { what: BenchCmd::Rt { rig, seconds, blocks } } => {
            let r = load_rig(&rig)?;
            errln!("running each loop for {seconds} s in {blocks} blocks ...");
            let rep = bench_rt(
                &r,
                &RtBenchOptions {
                    seconds_each: seconds,
                    blocks,
                    rt: rt_options(&rig)?,
                    spin_ns: rig.spin_us * 1000,
                },
            )?;
            outln!("{rep}");
            Ok(0)
        }
    }
}

fn emulate(a: EmulateArgs) -> anyhow::Result<()> {
    let rig = match &a.rig {
        Some(p) => Rig::load(p)?,
        None => Rig::default_rig(),
    };
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
    // Signals end the emulator cleanly (status, link removed) from here on.
    let stop = Stop::install()?;
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
    outln!(
        "spidar emulate: boards {} ({}) on {} (link {}), rig '{}', script {}, watchdog {}",
        a.boards,
        layout.firmware(),
        emu.pty_path().map_or("?".into(), |p| p.display().to_string()),
        emu.link().display(),
        rig.name,
        a.script,
        a.watchdog_ms.map_or("none (as the real boards)".to_string(), |w| format!("{w} ms (experiment)"))
    );
    outln!(
        "run the stack against it: spidar run --device uart   (--port {} is the default)",
        emu.link().display()
    );
    if !a.no_rt && !emu.control().fifo() {
        // The thread sets its policy as it starts; give it a moment before reporting.
        std::thread::sleep(Duration::from_millis(50));
    }
    outln!(
        "serving thread: {}",
        if emu.control().fifo() {
            "SCHED_FIFO 70"
        } else {
            "normal priority (SCHED_FIFO not permitted or not asked)"
        }
    );
    outln!("{}", hardware::EMULATE_HELP);
    hardware::run_emulator(emu, &stop, a.seconds)
}

/// The option `id` was given on the command line (not left at its default).
fn given(m: &ArgMatches, id: &str) -> bool {
    m.try_get_raw(id).is_ok_and(|v| v.is_some()) && m.value_source(id) == Some(ValueSource::CommandLine)
}

/// Refuses options that do not apply to this run, naming what they apply to.
fn check_run_options(a: &RunArgs, m: &ArgMatches) -> anyhow::Result<()> {
    let given = |id: &str| given(m, id);
    if a.device == DeviceKind::Sim {
        for (id, flag) in [
            ("port", "--port"),
            ("switch", "--switch"),
            ("digits_per_volt", "--digits-per-volt"),
            ("reply_timeout_us", "--reply-timeout-us"),
        ] {
            if given(id) {
                bail!(
                    "{flag} applies to real boards, not to the simulated rig: leave it out, or choose the board \
                     with --device uart, usb-simple or usb-sh4"
                );
            }
        }
    } else {
        for (id, flag) in [
            ("script", "--script"),
            ("seed", "--seed"),
            ("noise_counts", "--noise-counts"),
            ("slack", "--slack"),
        ] {
            if given(id) {
                bail!(
                    "{flag} applies to the simulated rig only (--device sim): on real boards the hands are a \
                     person's; leave it out"
                );
            }
        }
        if a.device != DeviceKind::Uart && given("port") {
            bail!("--port applies to --device uart only: USB boards are found by their USB id (pick one with --switch)");
        }
        if a.device == DeviceKind::Uart && given("switch") {
            bail!(
                "--switch picks one of several USB boards: it does not apply to --device uart (use --port)"
            );
        }
    }
    if a.virtual_clock {
        if a.seconds.is_none() {
            bail!("--virtual needs --seconds: how much rig time to run");
        }
        for (id, flag) in [
            ("priority", "--priority"),
            ("no_rt", "--no-rt"),
            ("cpu", "--cpu"),
            ("spin_us", "--spin-us"),
            ("world_priority", "--world-priority"),
            ("world_restarts", "--world-restarts"),
            ("world_timeout_s", "--world-timeout-s"),
        ] {
            let to_a_world_process =
                id == "world_timeout_s" && !matches!(a.world.as_str(), "child" | "thread");
            if given(id) && !to_a_world_process {
                bail!(
                    "{flag} does not apply to --virtual: the loop and the world run on the virtual clock in this \
                     process, as fast as the machine computes; leave it out"
                );
            }
        }
        if a.world == "child" && given("world") {
            bail!(
                "--virtual runs the world in this process (or in one already listening, --world ADDR, which then \
                 answers in lockstep): leave out --world child"
            );
        }
    } else {
        match a.world.as_str() {
            "child" => {}
            "thread" => {
                for (id, flag) in
                    [("world_restarts", "--world-restarts"), ("world_timeout_s", "--world-timeout-s")]
                {
                    if given(id) {
                        bail!("{flag} applies to a world process; --world thread runs the world in this process");
                    }
                }
            }
            _ => {
                if given("world_restarts") {
                    bail!("--world-restarts applies to --world child only: a world already running is not restarted by this rig");
                }
                if given("world_priority") {
                    bail!(
                        "--world-priority applies to a world this rig starts: give a running world its priority with \
                         `spidar world --priority`"
                    );
                }
            }
        }
    }
    if a.view.foxglove.is_some() && (a.virtual_clock || a.world != "child") {
        bail!(
            "--foxglove is served by the world process this rig starts (--world child, the default, on the real \
             clock); a world already running serves it itself: spidar world --foxglove ADDR"
        );
    }
    if a.rig.no_rt && given("priority") {
        bail!("--priority is the loop's SCHED_FIFO priority, which --no-rt turns off: leave one of them out");
    }
    if let Some(p) = a.world_priority {
        if !a.rig.no_rt && p >= a.rig.priority {
            bail!("--world-priority {p} must be below the loop's --priority {}", a.rig.priority);
        }
    }
    Ok(())
}

/// An evaluation runs on the simulated rig and the virtual clock (no device, no file written
/// until the end): a stop signal ends it after the trial in progress, saying how far it got,
/// with the status a shell gives to an interrupted command (130).
fn stopped_eval(stop: &Stop, done: usize, total: usize, what: &str) {
    if stop.requested() {
        term::progress_done();
        errln!("stopped by a signal after {done} of {total} {what}: no report (nothing else to stop: no device was used)");
        std::process::exit(130);
    }
}

fn run(a: RunArgs, m: &ArgMatches) -> anyhow::Result<u8> {
    check_run_options(&a, m)?;
    let rig = load_rig(&a.rig)?;
    // The rig file the run loads (yours when no --rig is given): named in the summary and the record.
    let rig_src = spidar_runtime::rigpath::RigSource::resolve(a.rig.rig.as_deref());
    let choice = a.hw.choice(a.device, &rig)?;
    // Real boards hold their last command if this process dies: a supervisor watches over it.
    let supervised = supervisor::attached();
    if let (Some(choice), None) = (&choice, supervised) {
        let stop = Stop::install()?;
        let choice = choice.clone();
        let fifo = rt_options(&a.rig)?.fifo_priority;
        return supervisor::supervise(&stop, fifo, &mut |page| hardware::open_for_takeover(&choice, page));
    }
    let stop = match supervised {
        Some(page) => Stop::install()?.with_forwarded(&page.stops),
        None => Stop::install()?,
    };
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
                    errln!("spidar: no live view with --virtual (it runs faster than real time)");
                }
                None
            } else {
                spidar_runtime::world_process::start_view(&a.view, &*scene)?
            };
            let mut stepper = spidar_world::host::Stepper::new(scene);
            if let Some(v) = view {
                stepper.add_observer(Box::new(v));
            }
            (WorldChoice::Thread(stepper), name)
        }
        (false, "child") => {
            let mut spec = ChildWorldSpec::this_executable(&scene_arg, a.world_restarts)?;
            if let Some(p) = a.world_priority {
                spec.extra.extend(["--priority".into(), p.to_string().into()]);
            }
            spec.extra.extend(a.view.child_args());
            (WorldChoice::Child(spec), scene_arg.clone())
        }
        (_, addr) => {
            if a.view.view.is_some() || a.view.no_view {
                errln!(
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
    // Created before the device opens: a path that cannot be written stops the run here.
    let mut recorder = match &a.record {
        Some(path) => {
            let info = spidar_runtime::recording::session_info(
                rig_src.path(),
                &scene_arg,
                &script,
                &format!("{:?}", a.device),
                a.seed,
                a.virtual_clock,
            )?;
            Some(spidar_runtime::recording::create(path, &info)?)
        }
        None => None,
    };
    // The world's share: FILE.world.mcap next to FILE.mcap, written by the world wherever it
    // runs (this process or the child), on the rig recording's time line.
    let mut world_recording = None;
    let mut world_observer = None;
    let mut child_world_file = None;
    if let Some(path) = &a.record {
        let wpath = spidar_record::world::world_path(path);
        let start_ns = recorder.as_ref().map(|r| r.start_unix_ns());
        match &mut world {
            WorldChoice::Thread(stepper) => {
                let (rec, obs) = spidar_runtime::recording::start_world_recording(
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
                child_world_file = Some(wpath.clone());
                spec.extra.extend(["--record".into(), wpath.into_os_string()]);
                if let Some(ns) = start_ns {
                    spec.extra.extend(["--record-start-unix-ns".into(), ns.to_string().into()]);
                }
            }
            WorldChoice::Connect { at, .. } => errln!(
                "spidar: the world at {at} is not recorded here; record it where it runs (spidar world --record FILE.mcap)"
            ),
        }
    }
    let (dev, script_name): (Box<dyn Device>, String) = match choice {
        None => {
            let scripts = load_scripts(&script, &rig, a.seed)?;
            let sim_opts = SimOptions {
                seed: a.seed,
                encoder_noise_counts: a.noise_counts,
                slack: a.slack,
                ..Default::default()
            };
            errln!(
                "spidar: rig '{}' on the simulated SPIDAR-H (seed {}), scene {}, script {}",
                rig.name,
                a.seed,
                scene_name,
                script
            );
            (Box::new(sim_device(&rig, scripts, &sim_opts)?), script.clone())
        }
        Some(choice) => {
            let dev = hardware::open_hardware_for(&choice, supervised)?;
            errln!(
                "spidar: rig '{}' on {} ({}), scene {}{}",
                rig.name,
                dev.info().board,
                dev.info().identity,
                scene_name,
                if supervised.is_some() {
                    format!(
                        "; supervisor pid {} watches this rig process (pid {})",
                        parent_pid(),
                        std::process::id()
                    )
                } else {
                    String::new()
                }
            );
            hardware::check_rig_against(&rig, dev.info())?;
            errln!("hold each grip at its home point: the rig homes as it starts");
            (dev, "none (a person's hands on real boards)".to_string())
        }
    };
    let device = format!("{} ({})", dev.info().board, dev.info().identity);

    if a.virtual_clock {
        let Some(seconds) = a.seconds else { bail!("--virtual needs --seconds") };
        let world = match world {
            WorldChoice::Thread(stepper) => session::VirtualWorld::Scene(stepper.into_scene()),
            WorldChoice::Connect { at, scene } => session::VirtualWorld::Process {
                at,
                scene,
                timeout: Duration::from_secs_f64(a.world_timeout_s),
            },
            WorldChoice::Child(_) => unreachable!("--virtual runs no child world"),
        };
        let (mut summary, link) = session::run_virtual_with(
            dev,
            &rig,
            world,
            VirtualOptions {
                seconds,
                stop,
                progress: !a.quiet,
                device,
                scene_name,
                script_name,
                supervisor: supervised,
                recorder: recorder.take(),
                observers: world_observer.take().into_iter().map(|o| Box::new(o) as _).collect(),
            },
        )?;
        summary.rig_file = rig_src.describe();
        let world_rec = world_recording.take().map(|r| r.finish());
        if a.json {
            let mut j = report::virtual_json(&summary, world_rec.as_ref());
            if let Some(l) = &link {
                j["link"] =
                    l.counts().iter().map(|(k, n)| (k.to_string(), serde_json::Value::from(*n))).collect();
            }
            outln!("{j:#}");
        } else {
            outln!("{summary}");
            if let Some(r) = &world_rec {
                outln!("  world rec.   {r}");
            }
            if let Some(l) = &link {
                outln!("  link         {}", l.summary());
            }
        }
        report::check_outcome(summary.final_state, &summary.counters, &summary.faults_seen)?;
        return Ok(0);
    }

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
            script_name,
            connect_timeout: Duration::from_secs_f64(a.world_timeout_s),
            world_priority: a.world_priority,
            supervisor: supervised,
            recorder: spidar_runtime::recording::recorder_thread(recorder, a.view.foxglove.as_deref())?.0,
        },
    )?;
    let mut summary = summary;
    summary.rig_file = rig_src.describe();
    let recording = summary.recording.clone();
    // The scene thread has stopped: the world's recording ends with its last step. A child world
    // process wrote its own: what it kept is read back from its file.
    let world_rec = match (world_recording.take(), &child_world_file) {
        (Some(r), _) => Some(r.finish()),
        (None, Some(p)) => match spidar_record::world::report_of(p) {
            Ok(r) => Some(r),
            Err(e) => {
                errln!("spidar: the world's recording {} does not read: {e}", p.display());
                None
            }
        },
        (None, None) => None,
    };
    if a.json {
        outln!("{:#}", report::run_json(&summary, recording.as_ref(), world_rec.as_ref()));
    } else {
        outln!("{summary}");
        if let Some(r) = &recording {
            outln!("  recording    {r}");
        }
        if let Some(r) = &world_rec {
            outln!("  world rec.   {r}");
        }
    }
    let lat = summary.stats.lateness.percentiles();
    if summary.counters.misses > 0 {
        errln!(
            "note: {} ticks woke more than 1 ms late (worst {}); see `spidar bench rt` for this machine's floor",
            summary.counters.misses,
            fmt_dur(lat.max_s)
        );
    }
    if !summary.clean_stop {
        bail!("the loop did not stop cleanly");
    }
    report::check_outcome(summary.final_state, &summary.counters, &summary.faults_seen)?;
    Ok(0)
}

fn parent_pid() -> u32 {
    // SAFETY: getppid cannot fail.
    unsafe { libc::getppid() as u32 }
}
