//! `spidar run`'s options in two stages, as ripgrep does: clap parses the raw arguments
//! ([`RunArgs`], [`RigArgs`]), then [`RunPlan::check`] turns them into the plan, a plain struct
//! of checked choices (the rig loaded, the device chosen, where the world runs, which clock),
//! refusing with an error a person can act on every option that does not apply to the run it is
//! given for. `run.rs` runs the plan.
//!
//! Must never: open a device, start a thread or a process, or write a file: checking is free of
//! effects, so a refused command line leaves nothing behind.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::bail;
use spidar_link::Endpoint;
use spidar_rt::rt_thread::{self, RtOptions};
use spidar_rt::Rig;

use crate::hardware::{DeviceKind, HardwareArgs, HardwareChoice};
use crate::rigpath::RigSource;
use crate::session;
use crate::world_process::ViewArgs;

/// Longest `spidar run` or `spidar emulate` (a week): a number that would run for ever is a typo.
pub const MAX_RUN_S: f64 = 7.0 * 24.0 * 3600.0;
/// Longest benchmark or evaluation phase, and the longest wait for a world.
pub const MAX_BENCH_S: f64 = 3600.0;

/// A number of seconds in (0, `max`].
pub fn seconds_upto(s: &str, max: f64) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= max {
        Ok(v)
    } else {
        Err(format!("must be more than 0 and at most {max} s"))
    }
}
/// Seconds of a run, at most a week.
pub fn run_seconds(s: &str) -> Result<f64, String> {
    seconds_upto(s, MAX_RUN_S)
}
/// Seconds of a benchmark phase or a wait, at most an hour.
pub fn bench_seconds(s: &str) -> Result<f64, String> {
    seconds_upto(s, MAX_BENCH_S)
}
/// Encoder noise: 0 to 1000 counts.
pub fn noise_counts(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number of counts"))?;
    if v.is_finite() && (0.0..=1000.0).contains(&v) {
        Ok(v)
    } else {
        Err("must be between 0 and 1000 counts".into())
    }
}

/// The rig and the loop thread's scheduling, shared by `spidar run` and the benchmarks.
#[derive(clap::Args, Clone, Debug)]
pub struct RigArgs {
    /// Rig file (RON). Default: yours (~/.config/spidar/rig.ron, made by `spidar calib home`) if
    /// it exists, else the built-in configs/rig-spidar-h.ron.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Do not ask for SCHED_FIFO and locked memory.
    #[arg(long)]
    pub no_rt: bool,
    /// SCHED_FIFO priority for the loop thread.
    #[arg(long, default_value_t = 80, value_parser = clap::value_parser!(u8).range(1..=99))]
    pub priority: u8,
    /// Pin the loop thread to this CPU.
    #[arg(long)]
    pub cpu: Option<usize>,
    /// Accept a rig value beyond its physical bound (a key of the rig file's `overrides`, e.g.
    /// board_range); repeatable. The summary shows every override in effect.
    #[arg(long = "override", value_name = "KEY")]
    pub overrides: Vec<String>,
    /// Sleep to this many microseconds before each deadline, then busy-wait: hides the kernel's
    /// wake-up latency at the cost of that much CPU per millisecond.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=900))]
    pub spin_us: u64,
}

impl RigArgs {
    /// Loads the rig file these arguments name (yours, or the built-in one).
    pub fn load(&self) -> anyhow::Result<Rig> {
        crate::rigpath::load_rig(self.rig.as_deref(), &self.overrides)
    }

    /// The loop thread's set-up; refuses a CPU this machine does not have.
    pub fn rt_options(&self) -> anyhow::Result<RtOptions> {
        if let Some(cpu) = self.cpu {
            rt_thread::check_cpu(cpu).map_err(|e| anyhow::anyhow!("--cpu {cpu}: {e}"))?;
        }
        Ok(if self.no_rt {
            RtOptions { fifo_priority: None, lock_memory: false, cpu: self.cpu, ..RtOptions::default() }
        } else {
            RtOptions { fifo_priority: Some(self.priority), cpu: self.cpu, ..RtOptions::default() }
        })
    }
}

/// `spidar run`'s arguments as parsed, before any check.
#[derive(clap::Args, Clone, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub rig: RigArgs,
    /// Which device drives the rig.
    #[arg(long, value_enum, default_value = "sim")]
    pub device: DeviceKind,
    #[command(flatten)]
    pub hw: HardwareArgs,
    /// Scene behind the loop: `boxing` (a virtual human who predicts your punches and blocks,
    /// dodges or hits back; the default), `boxing-passive` (the same body with its mind off),
    /// `crowd` (keyframe characters to push, who stagger, step, fall and get up), `walls` (the rig
    /// check), or a boxer, crowd scene or walls scene file of any name (it says what it is: see
    /// configs/ and docs/formats.md). With --world ADDR: the scene that world must run (default:
    /// whatever it runs).
    #[arg(long)]
    pub scene: Option<String>,
    /// The virtual human's level of skill (boxing scenes): novice, amateur or pro, each a set of
    /// perception and decision parameters of its boxer file. Default: the file's own (the
    /// built-in file's is a good amateur). With --world ADDR: give it to `spidar world` instead.
    #[arg(long)]
    pub skill: Option<String>,
    /// Where the world runs: `child` (a `spidar world` process started here and restarted if it
    /// dies; the default), `thread` (inside this process), or the address of a world already
    /// running: unix:PATH, udp://HOST:PORT (`spidar world` prints its address).
    #[arg(long, default_value = "child")]
    pub world: String,
    /// How many times a child world that dies is restarted (at most 100).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=100))]
    pub world_restarts: u32,
    /// How long to wait for the world's first answer, in seconds (at most 3600).
    #[arg(long, default_value_t = 30.0, value_parser = bench_seconds)]
    pub world_timeout_s: f64,
    /// Step the world (child or thread) with SCHED_FIFO at this priority, below the loop's
    /// (--priority): keeps the contact model fresh on a busy machine. Default: normal scheduler.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=98))]
    pub world_priority: Option<u8>,
    /// The simulated user's hands (--device sim only): box (straights, hooks, uppercuts and
    /// feints at the virtual human), crowd (pushes at the crowd's front row), hold, circle, spar,
    /// tour (for `walls`), or a script file of any name (see configs/script-example.ron).
    /// Default: crowd for `--scene crowd` or a .ron file whose name contains "crowd", box
    /// otherwise (the name decides the script; the file's `kind` decides the scene).
    #[arg(long)]
    pub script: Option<String>,
    /// Stop after this many seconds, at most a week (default: run until Ctrl-C, SIGTERM or SIGHUP).
    #[arg(long, value_parser = run_seconds)]
    pub seconds: Option<f64>,
    /// Seed of the simulated rig and of random scripts (--device sim only); the same seed gives
    /// the same run on the virtual clock.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Encoder noise of the simulated rig, standard deviation in counts, 0 to 1000 (--device sim
    /// only).
    #[arg(long, default_value_t = 0.0, value_parser = noise_counts)]
    pub noise_counts: f64,
    /// Simulate string sag when a tension drops below 0.3 N (--device sim only).
    #[arg(long)]
    pub slack: bool,
    /// Run on the virtual clock, as fast as the machine computes (needs --seconds; the world
    /// runs in this process).
    #[arg(long = "virtual")]
    pub virtual_clock: bool,
    /// No live status line.
    #[arg(long, short)]
    pub quiet: bool,
    /// The live view of the world (served by the world: the child process or the thread).
    #[command(flatten)]
    pub view: ViewArgs,
    /// Record the session into this MCAP file (zstd chunks): every tick, every hand sample and
    /// contact model, the events, and the files that made the session. See docs/recording.md.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Print the summary as JSON, for scripts.
    #[arg(long)]
    pub json: bool,
}

/// Where the world of a run steps.
#[derive(Clone, Debug, PartialEq)]
pub enum WorldPlan {
    /// A thread of the rig's process (on the virtual clock: stepped in the loop's thread).
    Thread,
    /// A `spidar world` child process, restarted this many times if it dies.
    Child { restarts: u32 },
    /// A world already running at this address (on the virtual clock it answers in lockstep).
    Connect(Endpoint),
}

/// Which clock the loop runs on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Clock {
    /// The real clock, until a stop signal or for this many seconds.
    Real { seconds: Option<f64> },
    /// The virtual clock, for this many seconds of rig time, as fast as the machine computes.
    Virtual { seconds: f64 },
}

/// The simulated rig's settings (used when no board is chosen).
#[derive(Clone, Debug, PartialEq)]
pub struct SimPlan {
    /// The simulated user's hands: a built-in script's name or a script file.
    pub script: String,
    pub seed: u64,
    pub noise_counts: f64,
    pub slack: bool,
}

/// A checked `spidar run`: every choice made, every option known to apply.
#[derive(Debug)]
pub struct RunPlan {
    pub rig: Rig,
    /// Which rig file it is (named in the summary and the recording).
    pub rig_source: RigSource,
    pub rt: RtOptions,
    /// Sleep to this long before each deadline and spin the rest (0: pure sleep).
    pub spin_ns: u64,
    /// The real boards; `None`: the simulated rig with `sim`.
    pub hardware: Option<HardwareChoice>,
    pub sim: SimPlan,
    /// The device as the command line named it (for the recording's session information).
    pub device_kind: DeviceKind,
    /// The scene argument (`boxing` when left out).
    pub scene: String,
    /// What --scene said, for a world already running (it must run that scene).
    pub scene_asked: Option<String>,
    /// What --skill said (the world's scene is loaded at that level).
    pub skill: Option<String>,
    pub world: WorldPlan,
    pub world_timeout: Duration,
    pub world_priority: Option<u8>,
    pub clock: Clock,
    pub quiet: bool,
    pub json: bool,
    pub view: ViewArgs,
    pub record: Option<PathBuf>,
}

impl RunPlan {
    /// Checks `a` into a plan: options that do not apply to this run are refused first (naming
    /// what they apply to; `given(id)` tells an option the person gave from one left at its
    /// default), then the rig file is loaded and the device, the CPU and the world's address are
    /// checked.
    pub fn check(a: RunArgs, given: &dyn Fn(&str) -> bool) -> anyhow::Result<RunPlan> {
        check_device_options(&a, given)?;
        check_world_options(&a, given)?;
        let rig = a.rig.load()?;
        let hardware = a.hw.choice(a.device, &rig)?;
        let world = match (a.virtual_clock, a.world.as_str()) {
            (true, "child" | "thread") | (false, "thread") => WorldPlan::Thread,
            (false, "child") => WorldPlan::Child { restarts: a.world_restarts },
            (_, addr) => WorldPlan::Connect(
                Endpoint::parse(addr)
                    .map_err(|e| anyhow::anyhow!("--world: {e}; or use child (the default) or thread"))?,
            ),
        };
        let clock = match (a.virtual_clock, a.seconds) {
            (true, Some(seconds)) => Clock::Virtual { seconds },
            (true, None) => bail!("--virtual needs --seconds: how much rig time to run"),
            (false, seconds) => Clock::Real { seconds },
        };
        let scene = a.scene.clone().unwrap_or_else(|| "boxing".into());
        let script = a.script.clone().unwrap_or_else(|| session::default_script(&scene).to_string());
        Ok(RunPlan {
            rt: a.rig.rt_options()?,
            spin_ns: a.rig.spin_us * 1000,
            rig_source: RigSource::resolve(a.rig.rig.as_deref()),
            rig,
            hardware,
            sim: SimPlan { script, seed: a.seed, noise_counts: a.noise_counts, slack: a.slack },
            device_kind: a.device,
            scene,
            scene_asked: a.scene,
            skill: a.skill,
            world,
            world_timeout: Duration::from_secs_f64(a.world_timeout_s),
            world_priority: a.world_priority,
            clock,
            quiet: a.quiet,
            json: a.json,
            view: a.view,
            record: a.record,
        })
    }
}

/// Options of real boards refused on the simulated rig, and the simulated rig's on real boards.
fn check_device_options(a: &RunArgs, given: &dyn Fn(&str) -> bool) -> anyhow::Result<()> {
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
        return Ok(());
    }
    for (id, flag) in
        [("script", "--script"), ("seed", "--seed"), ("noise_counts", "--noise-counts"), ("slack", "--slack")]
    {
        if given(id) {
            bail!(
                "{flag} applies to the simulated rig only (--device sim): on real boards the hands are a person's; \
                 leave it out"
            );
        }
    }
    if a.device != DeviceKind::Uart && given("port") {
        bail!("--port applies to --device uart only: USB boards are found by their USB id (pick one with --switch)");
    }
    if a.device == DeviceKind::Uart && given("switch") {
        bail!("--switch picks one of several USB boards: it does not apply to --device uart (use --port)");
    }
    Ok(())
}

/// Options of the clock, the loop's scheduling and the world that do not go with the world or
/// the clock chosen.
fn check_world_options(a: &RunArgs, given: &dyn Fn(&str) -> bool) -> anyhow::Result<()> {
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
                if a.skill.is_some() {
                    bail!(
                        "--skill sets the level of a world this rig starts: give a running world its level with                          `spidar world --skill LEVEL`"
                    );
                }
                if given("world_restarts") {
                    bail!(
                        "--world-restarts applies to --world child only: a world already running is not restarted \
                         by this rig"
                    );
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        run: RunArgs,
    }

    /// Checks `spidar run ARGS`, taking an option as given when it is on the command line.
    fn check(args: &[&str]) -> anyhow::Result<RunPlan> {
        let a = Cli::try_parse_from(std::iter::once("run").chain(args.iter().copied())).unwrap().run;
        let said: Vec<String> =
            args.iter().filter_map(|s| s.strip_prefix("--")).map(|s| s.replace('-', "_")).collect();
        RunPlan::check(a, &|id: &str| said.iter().any(|s| s == id))
    }

    #[test]
    fn the_defaults_plan_a_simulated_boxing_run_with_a_child_world_on_the_real_clock() {
        let p = check(&["--rig", "../configs/rig-spidar-h.ron"]).unwrap();
        assert!(p.hardware.is_none());
        assert_eq!((p.scene.as_str(), p.sim.script.as_str()), ("boxing", "box"));
        assert_eq!(p.world, WorldPlan::Child { restarts: 3 });
        assert_eq!(p.clock, Clock::Real { seconds: None });
        assert_eq!(p.rt.fifo_priority, Some(80));
        assert_eq!(p.world_timeout, Duration::from_secs(30));
    }

    #[test]
    fn the_virtual_clock_runs_the_world_on_a_thread_for_the_seconds_given() {
        let p = check(&[
            "--rig",
            "../configs/rig-spidar-h.ron",
            "--virtual",
            "--seconds",
            "2",
            "--scene",
            "crowd",
        ])
        .unwrap();
        assert_eq!((p.world, p.clock), (WorldPlan::Thread, Clock::Virtual { seconds: 2.0 }));
        assert_eq!(p.sim.script, "crowd", "a crowd scene's own script");
        let p = check(&[
            "--rig",
            "../configs/rig-spidar-h.ron",
            "--virtual",
            "--seconds",
            "2",
            "--world",
            "unix:/x",
        ])
        .unwrap();
        assert!(matches!(p.world, WorldPlan::Connect(_)), "a listening world answers in lockstep");
        let p = check(&["--rig", "../configs/rig-spidar-h.ron", "--world", "udp://127.0.0.1:9"]).unwrap();
        assert!(matches!(p.world, WorldPlan::Connect(_)));
    }

    #[test]
    fn options_that_do_not_apply_are_refused_before_anything_is_loaded() {
        // The rig file does not exist: the option is refused first.
        for (args, says) in [
            (&["--port", "/dev/ttyUSB0"][..], "--port applies to real boards"),
            (&["--virtual"], "--virtual needs --seconds"),
            (&["--virtual", "--seconds", "1", "--world", "child"], "leave out --world child"),
            (
                &["--virtual", "--seconds", "1", "--foxglove", ":8765"],
                "--foxglove is served by the world process",
            ),
            (
                &["--world", "thread", "--world-timeout-s", "5"],
                "--world-timeout-s applies to a world process",
            ),
            (
                &["--world", "unix:/x", "--world-priority", "5"],
                "--world-priority applies to a world this rig starts",
            ),
            (&["--world-priority", "90"], "must be below the loop's --priority 80"),
            (&["--device", "usb-sh4", "--slack"], "--slack applies to the simulated rig only"),
        ] {
            let mut all = vec!["--rig", "/nonexistent/rig.ron"];
            all.extend_from_slice(args);
            let e = check(&all).unwrap_err().to_string();
            assert!(e.contains(says), "{args:?}: {e}");
        }
        let e = check(&["--rig", "/nonexistent/rig.ron"]).unwrap_err();
        assert!(format!("{e:?}").contains("/nonexistent/rig.ron"), "{e:?}");
        let e =
            check(&["--rig", "../configs/rig-spidar-h.ron", "--world", "tcp://x"]).unwrap_err().to_string();
        assert!(e.starts_with("--world:") && e.contains("child (the default) or thread"), "{e}");
    }
}
