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
mod rigsites;

use clap::parser::ValueSource;
use clap::{ArgMatches, CommandFactory, FromArgMatches, Parser, Subcommand};
use spidar_lab::bench::{bench_link, bench_rt, LinkBenchOptions, RtBenchOptions};
use spidar_rt::Rig;
use spidar_runtime::child_world::ChildWorldSpec;
use spidar_runtime::hardware;
use spidar_runtime::plan::{
    bench_seconds, noise_counts, run_seconds, seconds_upto, RigArgs, RunArgs, RunPlan, MAX_BENCH_S,
};
use spidar_runtime::session::{load_scripts, SimOptions};
use spidar_runtime::signals::Stop;
use spidar_runtime::world_process::WorldArgs;
use spidar_runtime::{errln, outln, supervisor, term};

/// 0 (skip) or a number of seconds up to an hour.
fn bout_seconds(s: &str) -> Result<f64, String> {
    if s.trim().parse::<f64>().is_ok_and(|v| v == 0.0) {
        return Ok(0.0);
    }
    seconds_upto(s, MAX_BENCH_S)
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
    /// reactions to jabs are), `blows` (what the user's hands feel of the virtual human's blows), `impacts` (how well impact forces can be told from the keyframe
    /// characters' motion), `poses` (contact sheets of the characters as drawn).
    Eval {
        #[command(subcommand)]
        what: EvalCmd,
        /// Print the results as JSON, for scripts.
        #[arg(long, global = true)]
        json: bool,
    },
    /// Studies with people: `reactions` (a page shows each participant the virtual human's
    /// reactions to straights, the avatar hidden, and asks which part was attacked; the answers go
    /// to a CSV file and the confusion matrix is printed beside the published one: docs/study.md).
    Study {
        #[command(subcommand)]
        what: StudyCmd,
    },
    /// Play a recording (`run --record`) into the live view (the page gets a playback bar: play,
    /// pause, seek, speed) and print what it holds; with --verify, re-run the rt-loop from its
    /// recorded inputs and check every output bit for bit.
    Replay(spidar_runtime::replay::ReplayArgs),
    /// Write one CSV file per channel of a recording, each with a header line.
    Export(spidar_runtime::replay::ExportArgs),
    /// Plot a recording as SVG: force per hand, tensions per string, lateness, events and hits.
    Plot(spidar_runtime::replay::PlotArgs),
    /// What a rig can do where: `map` (each hand's force capacity over its frame against the
    /// force limit, the volume where the limit holds, strings near the forearm or each other).
    Rig {
        #[command(subcommand)]
        what: RigCmd,
    },
}

#[derive(Subcommand)]
enum RigCmd {
    /// Map a rig file: over a grid of each hand's frame, the largest force the strings render in
    /// every direction (the capacity margin) against the force limit; the volume where the limit
    /// holds, in the frame and within reach of home; the capacity at home; the strings' clearance
    /// from a forearm capsule (grip toward the elbow) and from the other hand's strings. Writes
    /// SVG slices with --svg.
    Map(RigMapArgs),
}

#[derive(clap::Args)]
struct RigMapArgs {
    /// Rig file (RON). Default: yours (~/.config/spidar/rig.ron) if it exists, else the built-in
    /// configs/rig-spidar-h.ron.
    #[arg(long)]
    rig: Option<PathBuf>,
    /// Write the slices (horizontal and vertical through each home) to this SVG file.
    #[arg(long)]
    svg: Option<PathBuf>,
    /// Grid spacing, millimetres.
    #[arg(long, default_value_t = 50.0)]
    step_mm: f64,
    /// Radius around each home checked for interference and reported as the hand's reach, m.
    #[arg(long, default_value_t = 0.4)]
    reach_m: f64,
    /// Forearm capsule: from the grip toward the elbow, the left hand's direction (the right's
    /// is mirrored in x), as x,y,z in the rig frame. Default: the rig file's `near_strings`.
    #[arg(long, value_delimiter = ',', num_args = 3)]
    forearm_dir: Option<Vec<f64>>,
    /// Forearm capsule: distance from the grip's centre to the wrist and to the elbow, m.
    /// Default: the rig file's `near_strings`.
    #[arg(long, value_delimiter = ',', num_args = 2)]
    forearm_span_m: Option<Vec<f64>>,
    /// Forearm capsule radius, m. Default: the rig file's `near_strings`.
    #[arg(long)]
    forearm_radius_m: Option<f64>,
    /// Strings of the two hands closer than this count as touching, mm. Default: the rig file's
    /// `near_strings.distance_m`.
    #[arg(long)]
    string_clearance_mm: Option<f64>,
    /// Scenes whose contacts are marked and given their margin: boxing (the virtual human's head,
    /// chest and gloves), walls (its walls and ball), a boxer or walls scene file; `none`.
    #[arg(long, value_delimiter = ',', default_values_t = ["boxing".to_string(), "walls".to_string()])]
    scenes: Vec<String>,
    /// Write the map as JSON to this file (grid, margin and feasible flag per cell, string
    /// clearances, the sites' margins), for other tools.
    #[arg(long)]
    json: Option<PathBuf>,
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
    /// On the path of `spidar run`: the virtual human's landed blows and what the user's hands
    /// feel of each (peak force and impulse by impact speed, the bursts' energy, the clamp).
    Blows {
        /// Length of the bout (s of rig time, virtual clock; at most 3600).
        #[arg(long, default_value_t = 60.0, value_parser = bout_seconds)]
        seconds: f64,
        /// Seed of the user's punches and of the bout.
        #[arg(long, default_value_t = 0)]
        seed: u64,
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

#[derive(Subcommand)]
enum StudyCmd {
    /// Makes the clips on the path of `spidar run` (straights at the virtual human's left and
    /// right hand and chest, active and passive), serves the study page (docs/study.md), writes
    /// each answer to --out as it is given, and prints the confusion matrix of every answer in
    /// the file beside the published matrix when it stops (Ctrl-C, or --participants).
    Reactions(spidar_lab::study_page::StudyArgs),
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
    /// Path of the symlink to the pty (it survives `disconnect`/`reconnect`). Default: `uart` in
    /// a directory private to you ($XDG_RUNTIME_DIR/spidar, or /tmp/spidar-<uid>). `--link` is
    /// the older name of this option.
    #[arg(long, alias = "link")]
    symlink: Option<PathBuf>,
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
        /// Instead: how late the drawn picture is, on `spidar run`'s path with headless chromium
        /// drawing the page for --seconds (p50/p99 of the age, rig tick to browser frame).
        #[arg(long)]
        age: bool,
        /// The viewers' block has one headless chromium drawing the page instead of WebSocket clients.
        #[arg(long, conflicts_with = "age")]
        browser: bool,
        /// A block (with --age: the page) with headless chromium in an immersive session of an
        /// emulated headset, driven by node, puppeteer-core and iwer from tests/browser (`npm ci`
        /// there first).
        #[arg(long)]
        headset: bool,
        /// More of the query of the page the browser opens, e.g. `shading=standard&aa=1` (a GPU's
        /// look on a software renderer: docs/view.md).
        #[arg(long, default_value = "")]
        page: String,
        /// With --age: the browser window's size, WIDTHxHEIGHT (px).
        #[arg(long, default_value = "960x540", requires = "age")]
        size: String,
        /// The view's most frames a second (default: a frame after every world step), to compare
        /// the world step's cost at another rate, e.g. 60.
        #[arg(long, conflicts_with = "age", value_parser = bench_frame_hz)]
        frame_hz: Option<f64>,
        /// The CPU the world thread steps on: a number, `any` (not pinned) or `auto` (with two
        /// CPUs or more the last one, as a rig gives the world a core of its own; else any).
        #[arg(long, default_value = "auto", conflicts_with = "age")]
        world_cpu: spidar_lab::cpus::CpuChoice,
        /// The CPUs of the browsers, their drivers and the bench's other threads, e.g. `0` or
        /// `0,2-3`: `any`, or `auto` (the CPUs other than the world's).
        #[arg(long, default_value = "auto", conflicts_with = "age")]
        browser_cpus: spidar_lab::cpus::CpuChoice,
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
    /// Two rigs sparring through one world over a bad network (`--scene spar`, docs/spar.md):
    /// simulated rigs with scripted users on the virtual clock, a delay/jitter/loss shim each way,
    /// at 0, 50, 100 and 200 ms round trip; the felt-force error and the energy given to each
    /// hand against what the design allows.
    Spar {
        /// Seconds of each bout (at most 3600).
        #[arg(long, default_value_t = 20.0, value_parser = bench_seconds)]
        seconds: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
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
    /// The wall stiffness and damping the rig renders passively (its Z-width): a simulated hand
    /// pressing a plane wall on the simulated rig through the loop, on the virtual clock, over a
    /// grid of K and B per axis, place and loop rate; the shipped scenes' contacts checked
    /// (docs/zwidth.md).
    Zwidth {
        /// Rig file (RON). Default: yours (~/.config/spidar/rig.ron) if it exists, else the
        /// built-in configs/rig-spidar-h.ron.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Write the plot (SVG) here.
        #[arg(long)]
        svg: Option<PathBuf>,
        /// Stiffnesses of the grid, log-spaced from 100 to 20,000 N/m (the sweep's resolution).
        #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u32).range(2..=200))]
        k_steps: u32,
        /// Dampings of the grid, evenly from -5 to 20 N s/m.
        #[arg(long, default_value_t = 6, value_parser = clap::value_parser!(u32).range(2..=200))]
        b_steps: u32,
        /// Loop rates (Hz), comma-separated.
        #[arg(long, default_value = "1000,500", value_delimiter = ',')]
        rates: Vec<f64>,
        /// Seconds of each bout after the press (at least 2; the last 1 s is judged).
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
        /// The hand: mass (kg), arm stiffness (N/m), arm damping (N s/m).
        #[arg(long, default_value_t = 0.7)]
        hand_mass: f64,
        #[arg(long, default_value_t = 300.0)]
        hand_k: f64,
        #[arg(long, default_value_t = 8.0)]
        hand_d: f64,
        /// First-order lag of the simulated motors (ms; 0: ideal, as spidar run's default).
        #[arg(long, default_value_t = 0.0)]
        motor_lag_ms: f64,
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
        Cmd::Devices { probe, port } => {
            outln!("{}", hardware::devices_report(&port, probe).trim_end());
            Ok(0)
        }
        Cmd::Eval { what, json } => eval(what, json).map(|_| 0),
        Cmd::Study { what: StudyCmd::Reactions(a) } => {
            let stop = Stop::install()?;
            let t = spidar_lab::study_page::study_reactions(&a, &|| stop.requested(), |m| errln!("{m}"))?;
            outln!("{t}");
            Ok(0)
        }
        Cmd::Bench { what } => bench(what).map(|_| 0),
        Cmd::Rig { what: RigCmd::Map(a) } => rig_map(&a).map(|_| 0),
    }
}

/// `spidar rig map`: the map's report on stdout, its slices as SVG.
fn rig_map(a: &RigMapArgs) -> anyhow::Result<()> {
    use spidar_calib::rigmap::{map_rig, Forearm, MapOptions};
    use spidar_calib::rigmap_plot::{report, slices_svg};
    let in_range = |name: &str, v: f64, lo: f64, hi: f64| {
        if v.is_finite() && (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(anyhow::anyhow!("{name} {v}: must be within {lo} .. {hi}"))
        }
    };
    let rig = spidar_runtime::rigpath::load_rig(a.rig.as_deref(), &[])?;
    // The rig file's `near_strings`, each part overridden by its option.
    let near = rig.near_strings;
    let dir =
        a.forearm_dir.as_ref().map_or(near.forearm.toward_elbow, |d| glam::DVec3::new(d[0], d[1], d[2]));
    if !dir.is_finite() || dir.length() < 1e-6 {
        anyhow::bail!("--forearm-dir {dir}: give a direction (three numbers, not all zero)");
    }
    let (wrist, elbow) =
        a.forearm_span_m.as_ref().map_or((near.forearm.wrist_m, near.forearm.elbow_m), |s| (s[0], s[1]));
    in_range("--forearm-span-m (wrist)", wrist, 0.0, 1.0)?;
    in_range("--forearm-span-m (elbow)", elbow, wrist, 2.0)?;
    let clearance_mm = a.string_clearance_mm.unwrap_or(near.distance_m * 1e3);
    let options = MapOptions {
        step_m: in_range("--step-mm", a.step_mm, 5.0, 500.0)? * 1e-3,
        reach_m: in_range("--reach-m", a.reach_m, 0.05, 2.0)?,
        forearm: Forearm {
            toward_elbow: dir,
            wrist_m: wrist,
            elbow_m: elbow,
            radius_m: in_range(
                "--forearm-radius-m",
                a.forearm_radius_m.unwrap_or(near.forearm.radius_m),
                0.0,
                0.2,
            )?,
        },
        string_clearance_m: in_range("--string-clearance-mm", clearance_mm, 0.0, 200.0)? * 1e-3,
    };
    let sites = rigsites::scene_sites(&rig, &a.scenes)?;
    let map = map_rig(&rig, &options).with_sites(&sites);
    outln!("{}", report(&map, &rig.name).trim_end());
    if let Some(svg) = &a.svg {
        slices_svg(&map, svg)?;
        outln!("  slices       {}", svg.display());
    }
    if let Some(path) = &a.json {
        let text = serde_json::to_string(&spidar_calib::rigmap_plot::to_json(&map, &rig.name))?;
        std::fs::write(path, text).map_err(|e| {
            anyhow::anyhow!("{}: {e}: check the folder exists and is writable", path.display())
        })?;
        outln!("  json         {}", path.display());
    }
    Ok(())
}

/// `spidar eval`: each evaluation, its progress on stderr and its report as text or JSON.
fn eval(what: EvalCmd, json: bool) -> anyhow::Result<()> {
    let report = match what {
        EvalCmd::Reactions { trials, punches, seed, bout_seconds } => {
            return eval_reactions(trials, punches, seed, bout_seconds, json);
        }
        EvalCmd::Blows { seconds, seed } => {
            let stop = Stop::install()?;
            let report = spidar_lab::eval_blows::eval_blows(seconds, seed, |t| {
                stopped_eval(&stop, t as usize, seconds as usize, "seconds");
                term::progress(&format!("  boxed {t:.0}/{seconds:.0} s"));
            })?;
            term::progress_done();
            (serde_json::json!({ "command": "eval blows", "report": report }), report.to_string())
        }
        EvalCmd::Poses { out } => {
            let report = spidar_lab::eval_poses::eval_poses(&out)?;
            (serde_json::json!({ "command": "eval poses", "report": report }), report.to_string())
        }
        EvalCmd::Impacts { trials, practice, seed, path } => {
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
            (serde_json::json!({ "command": "eval impacts", "report": report }), report.to_string())
        }
    };
    if json {
        outln!("{:#}", report.0);
    } else {
        outln!("{}", report.1);
    }
    Ok(())
}

/// `spidar eval reactions`: the timed bout, the punches and the reaction experiment, each
/// skippable, printed as each ends (or all at once as JSON).
fn eval_reactions(trials: u64, punches: u64, seed: u64, bout_seconds: f64, json: bool) -> anyhow::Result<()> {
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
            outln!("{b}\n");
        }
        bout = Some(b);
    }
    let mut punch_report = None;
    if punches > 0 {
        errln!("throwing {punches} punches at an active and a passive virtual human ...");
        let p = eval::punch_report(punches as usize, seed, |done, total| {
            stopped_eval(&stop, done, total, "punches");
            term::progress(&format!("punches {done}/{total}"));
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
    Ok(())
}

/// `spidar bench`: each benchmark with what it is about to do on stderr, its report on stdout.
fn bench(what: BenchCmd) -> anyhow::Result<()> {
    let report = match what {
        BenchCmd::Uart { rig, exchanges, seconds, reply_timeout_us } => {
            let r = rig.load()?;
            let scripts = load_scripts("hold", &r, 1)?;
            errln!("{exchanges} round trips, then {seconds} s of the 1 kHz loop through the emulator ...");
            let timeout = Duration::from_micros(reply_timeout_us);
            hardware::bench_uart(&r, scripts, exchanges, seconds, &rig.rt_options()?, timeout)?.to_string()
        }
        BenchCmd::Record { rig, seconds, blocks, scene, script } => {
            use spidar_lab::bench_record::{bench_record, RecordBenchOptions};
            let r = rig.load()?;
            errln!("{blocks} blocks of live sessions each way, {seconds} s per arm ...");
            let dir = std::env::temp_dir().join(format!("spidar-bench-record-{}", std::process::id()));
            let o = RecordBenchOptions {
                seconds_each: seconds,
                blocks,
                rt: rig.rt_options()?,
                scene,
                script,
                dir,
            };
            bench_record(&r, &o)?.to_string()
        }
        BenchCmd::Replay { file, seeks, viewers, seconds } => {
            use spidar_lab::bench_replay::{bench_replay, ReplayBenchOptions};
            errln!(
                "opening {}, {seeks} seeks, then {seconds} s of playing to {viewers} viewer(s) ...",
                file.display()
            );
            let o = ReplayBenchOptions { file, seeks: seeks as usize, viewers: viewers as usize, seconds };
            bench_replay(&o)?.to_string()
        }
        BenchCmd::Spar { seconds, seed } => {
            errln!("seven spar bouts of {seconds} s on the virtual clock ...");
            spidar_lab::spar::spar_table(seconds, seed)?.to_string()
        }
        BenchCmd::Link { rig, seconds, blocks, scene, echoes, world_priority } => {
            let r = rig.load()?;
            errln!(
                "{echoes} round trips per transport, then {seconds} s of the loop with each kind of world in {blocks} \
                 blocks ..."
            );
            let world = ChildWorldSpec {
                extra: vec!["--no-view".into()],
                ..ChildWorldSpec::this_executable("walls", 0)?
            };
            let rt = rig.rt_options()?;
            let o =
                LinkBenchOptions { seconds_each: seconds, blocks, rt, scene, echoes, world, world_priority };
            bench_link(&r, &o)?.to_string()
        }
        BenchCmd::View {
            rig,
            scene,
            characters,
            seconds,
            rounds,
            viewers,
            fifo,
            age,
            size,
            browser,
            headset,
            page,
            frame_hz,
            world_cpu,
            browser_cpus,
        } => {
            use spidar_lab::bench_view::{bench_view, ViewBenchOptions};
            let (characters, viewers) = (characters as usize, viewers as usize);
            let r = match &rig {
                Some(p) => Rig::load(p)?,
                None => Rig::default_rig(),
            };
            if age {
                use spidar_lab::bench_age::{bench_age, AgeBenchOptions};
                errln!("drawing the live view in headless chromium for {seconds} s on spidar run's path ...");
                let (width, height) = size
                    .split_once('x')
                    .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
                    .filter(|(w, h): &(u32, u32)| (64..=8192).contains(w) && (64..=8192).contains(h))
                    .ok_or_else(|| {
                        anyhow::anyhow!("--size {size}: give WIDTHxHEIGHT in pixels, e.g. 960x540")
                    })?;
                let o = AgeBenchOptions { scene, seconds, width, height, world: None, headset, page };
                bench_age(&r, &o)?.to_string()
            } else {
                errln!(
                    "{rounds} rounds of {seconds} s blocks (view off, no viewer, {}{}) ...",
                    if browser { "a screen browser".to_string() } else { format!("{viewers} viewers") },
                    if headset { ", a headset" } else { "" }
                );
                let o = ViewBenchOptions {
                    scene,
                    characters,
                    seconds_per_block: seconds,
                    rounds,
                    viewers,
                    fifo,
                    browser,
                    headset,
                    page,
                    frame_hz,
                    world_cpu,
                    browser_cpus,
                };
                bench_view(&r, &o)?.to_string()
            }
        }
        BenchCmd::Zwidth {
            rig,
            svg,
            k_steps,
            b_steps,
            rates,
            seconds,
            hand_mass,
            hand_k,
            hand_d,
            motor_lag_ms,
        } => {
            use spidar_lab::zwidth::HandModel;
            use spidar_lab::zwidth_sweep::{sweep, SweepOptions};
            let r = spidar_runtime::rigpath::load_rig(rig.as_deref(), &[])?;
            for (name, v, lo, hi) in [
                ("--seconds", seconds, 2.0, 600.0),
                ("--hand-mass", hand_mass, 0.05, 20.0),
                ("--hand-k", hand_k, 1.0, 1e5),
                ("--hand-d", hand_d, 0.0, 1e3),
                ("--motor-lag-ms", motor_lag_ms, 0.0, 100.0),
            ] {
                if !(v.is_finite() && (lo..=hi).contains(&v)) {
                    anyhow::bail!("{name} {v}: give a number from {lo} to {hi}");
                }
            }
            let o = SweepOptions {
                k_steps: k_steps as usize,
                b_steps: b_steps as usize,
                rates_hz: rates,
                seconds,
                hand: HandModel {
                    mass_kg: hand_mass,
                    k_n_per_m: hand_k,
                    d_n_s_per_m: hand_d,
                    ..HandModel::default()
                },
                motor_time_constant_s: motor_lag_ms * 1e-3,
                ..SweepOptions::default()
            };
            errln!(
                "{} x {} walls x 6 cases at {:?} Hz on the virtual clock, then the shipped scenes' contacts ...",
                o.k_steps,
                o.b_steps,
                o.rates_hz
            );
            let report = sweep(&r, &o)?;
            if let Some(path) = &svg {
                spidar_lab::zwidth_plot::zwidth_svg(&report, path)?;
                errln!("wrote {}", path.display());
            }
            report.to_string()
        }
        BenchCmd::Rt { rig, seconds, blocks } => {
            let r = rig.load()?;
            errln!("running each loop for {seconds} s in {blocks} blocks ...");
            let o = RtBenchOptions {
                seconds_each: seconds,
                blocks,
                rt: rig.rt_options()?,
                spin_ns: rig.spin_us * 1000,
            };
            bench_rt(&r, &o)?.to_string()
        }
    };
    outln!("{report}");
    Ok(())
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
    let symlink = match a.symlink.clone() {
        Some(l) => l,
        None => hardware::default_symlink()?,
    };
    // Signals end the emulator cleanly (status, symlink removed) from here on.
    let stop = Stop::install()?;
    let opts = hardware::EmulateOptions {
        symlink,
        emulator: spidar_device::emulator::EmulatorOptions {
            watchdog: a.watchdog_ms.map(Duration::from_millis),
            fifo_priority: (!a.no_rt).then_some(70),
            ..hardware::emulator_options(&rig, models, layout, plant)
        },
        sim: SimOptions { seed: a.seed, encoder_noise_counts: a.noise_counts, ..Default::default() },
    };
    let emu = hardware::start_emulator(&rig, scripts, &opts)?;
    outln!(
        "spidar emulate: boards {} ({}) on {} (symlink {}), rig '{}', script {}, watchdog {}",
        a.boards,
        layout.firmware(),
        emu.pty_path().map_or("?".into(), |p| p.display().to_string()),
        emu.symlink().display(),
        rig.name,
        a.script,
        a.watchdog_ms.map_or("none (as the real boards)".to_string(), |w| format!("{w} ms (experiment)"))
    );
    outln!(
        "run the stack against it: spidar run --device uart   (--port {} is the default)",
        emu.symlink().display()
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

/// `spidar run`: the arguments checked into a plan (`given` tells an option the person gave from
/// one left at its default), then run.
fn run(a: RunArgs, m: &ArgMatches) -> anyhow::Result<u8> {
    let given = |id: &str| {
        m.try_get_raw(id).is_ok_and(|v| v.is_some()) && m.value_source(id) == Some(ValueSource::CommandLine)
    };
    spidar_runtime::run::run(RunPlan::check(a, &given)?)
}

/// `bench view --frame-hz`: 1 to 1000 frames a second.
fn bench_frame_hz(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number of frames a second"))?;
    if v.is_finite() && (1.0..=1000.0).contains(&v) {
        Ok(v)
    } else {
        Err("must be between 1 and 1000 frames a second".into())
    }
}
