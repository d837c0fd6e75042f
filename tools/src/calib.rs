//! `spidar calib`: home, record, fit and verify the string geometry of a rig (see
//! `spidar-calib`). Arguments are checked here; the work is in the calib crate, and the loop that
//! holds the strings meanwhile is `spidar_runtime::calibration`'s.
//!
//! The rig file: `--rig`, else the user's own (`rigpath`), created from the built-in template by
//! the first `calib home`; the shipped template itself is never written. Every summary names the
//! rig file in use and every hint carries the same `--rig` (and device options).
//!
//! `--device sim` (the default) is the simulated rig, its grips moved by a scripted operator, with
//! the rt-loop on the virtual clock. Its true geometry is the built-in rig file perturbed by
//! `--seed` (anchors off by centimetres, metres per count by up to 10 %, counters starting
//! anywhere), whatever `--rig` says, so that home, record, fit --write and verify all run against
//! the same simulated hardware while the rig file is being corrected. `--device uart|usb-simple|
//! usb-sh4` opens the boards as `spidar run` does, runs the loop on its real-time thread under the
//! same supervisor process, and asks a person at the console to move the grips
//! (`ConsoleOperator`: Enter, s, q).
//!
//! Whatever ends a command (done, q, a lost board, Ctrl-C / SIGTERM / SIGHUP, an error) the loop
//! ends with its switch-off, and `record` has saved every kept pose: `record --resume` continues.
//! If the process dies, the supervisor writes zero to the boards.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context};
use clap::{Args, Subcommand, ValueEnum};
use glam::DVec3;
use spidar_calib::console::ConsoleOperator;
use spidar_calib::fit::{fit_hand, observations, FitOptions};
use spidar_calib::jig::JigFile;
use spidar_calib::model::HandGeometry;
use spidar_calib::quality::QualityOptions;
use spidar_calib::record::{Operator, Plan, RecordOptions, Recorder, Request, SimOperator};
use spidar_calib::rigfile::{update_rig_file, Stamp};
use spidar_calib::session::{PoseKind, SessionFile};
use spidar_calib::sim::SimTruthOptions;
use spidar_calib::CalibError;
use spidar_rt::rt_thread::RtOptions;
use spidar_rt::Rig;

use spidar_runtime::calibration::{self, CalibLoop};
use spidar_runtime::hardware::{DeviceKind, HardwareArgs};
use spidar_runtime::rigpath::{self, shell_quote, RigSource};
use spidar_runtime::signals::Stop;
use spidar_runtime::supervisor;

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq, Debug)]
pub enum Hands {
    Both,
    Left,
    Right,
}

impl Hands {
    fn list(self) -> Vec<usize> {
        match self {
            Hands::Both => vec![0, 1],
            Hands::Left => vec![0],
            Hands::Right => vec![1],
        }
    }
}

#[derive(Args, Clone, Debug)]
pub struct DeviceArgs {
    /// Rig file (RON) to calibrate. Default: yours ($XDG_CONFIG_HOME/spidar/rig.ron or
    /// ~/.config/spidar/rig.ron), created from the built-in template by the first `calib home`.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Which device to record from: the simulated rig (a scripted hand moves the grips) or the
    /// real boards (you move the grips and answer at the console: Enter, s, q).
    #[arg(long, value_enum, default_value = "sim")]
    pub device: DeviceKind,
    #[command(flatten)]
    pub hw: HardwareArgs,
    /// Simulated rig: seed of its true geometry and of its encoder noise.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Simulated rig: each true anchor is 0.5 .. 1 times this far from the built-in rig's.
    #[arg(long, default_value_t = 0.05)]
    pub sim_anchor_error_m: f64,
    /// Simulated rig: each true metres per count differs from the built-in rig's by 0.8 .. 1 times this fraction.
    #[arg(long, default_value_t = 0.10)]
    pub sim_mpc_error: f64,
    /// Simulated rig: encoder noise, standard deviation in counts (plus quantisation).
    #[arg(long, default_value_t = 0.5)]
    pub noise_counts: f64,
    /// Give up on a pose whose grip does not keep still this long (it is asked again).
    #[arg(long, default_value_t = 30.0)]
    pub pose_timeout_s: f64,
    /// The board counts as lost after this long without a good reply (late or bad replies before
    /// that are retried and counted).
    #[arg(long, default_value_t = 2.0)]
    pub lost_after_s: f64,
    /// Simulated rig: print every request and progress line (a console operator always sees them).
    #[arg(long, short)]
    pub verbose: bool,
    /// Boards: run the loop with the normal scheduler (no SCHED_FIFO, memory not locked), as
    /// `spidar run --no-rt`.
    #[arg(long)]
    pub no_rt: bool,
}

impl DeviceArgs {
    /// The simulated rig's options as the command line defaults them (what a hint may leave out).
    fn sim_defaults() -> DeviceArgs {
        #[derive(clap::Parser)]
        struct Only {
            #[command(flatten)]
            dev: DeviceArgs,
        }
        <Only as clap::Parser>::parse_from(["spidar"]).dev
    }
}

#[derive(Subcommand, Debug)]
pub enum CalibCmd {
    /// Place the rig's screen: open the page it prints full screen on that screen, hold the right
    /// grip's centre on each numbered target (the ball touching the screen) until it is taken;
    /// --write stores the screen in the rig file (docs/display.md). On the simulated rig a scripted
    /// person places the rig file's screen (or one 0.9 m ahead).
    Screen {
        #[command(flatten)]
        dev: DeviceArgs,
        /// Where the page with the targets is served (HOST:PORT).
        #[arg(long, default_value = "127.0.0.1:8080")]
        view: String,
        /// Write the screen into the rig file (atomically, the previous version kept as a dated backup).
        #[arg(long)]
        write: bool,
    },
    /// Hold each grip at its home point and preset the lengths at counter zero from the
    /// configured anchors (what `spidar run` does at start); --write stores them and the time.
    /// The first one creates your rig file from the built-in template.
    Home {
        #[command(flatten)]
        dev: DeviceArgs,
        #[arg(long, value_enum, default_value = "both")]
        hands: Hands,
        /// Write the lengths into the rig file (atomically, the previous version kept as a dated backup).
        #[arg(long)]
        write: bool,
    },
    /// Guided recording: home pose, jig points, free poses; the session file is saved after every pose.
    Record {
        #[command(flatten)]
        dev: DeviceArgs,
        #[arg(long, value_enum, default_value = "both", conflicts_with = "resume")]
        hands: Hands,
        /// Jig file with known points (fit_points are recorded). Without it: free poses only.
        #[arg(long, conflicts_with = "resume")]
        jig: Option<PathBuf>,
        /// Free poses per hand (without a jig the fit needs at least 17).
        #[arg(long, default_value_t = 40, conflicts_with = "resume")]
        free: usize,
        /// Half size of the box around each home point that free-pose suggestions fill.
        #[arg(long, default_value_t = 0.3, conflicts_with = "resume")]
        free_half_extent_m: f64,
        /// Session file to write (an existing one is kept as a dated backup, unless --resume).
        #[arg(long, default_value = "calib-session.ron")]
        out: PathBuf,
        /// Continue the session in --out where it stopped (its plan: hands, jig, free poses).
        #[arg(long)]
        resume: bool,
    },
    /// Fit the geometry to a session; report, plots, optionally write the rig file.
    Fit {
        /// Rig file with the configured geometry (start values; written with --write). Default:
        /// yours (see `calib home`).
        #[arg(long)]
        rig: Option<PathBuf>,
        #[arg(long, default_value = "calib-session.ron")]
        session: PathBuf,
        /// Keep the configured metres per count instead of fitting them.
        #[arg(long)]
        fixed_mpc: bool,
        /// Folder for the SVG plots (default: <session>.plots).
        #[arg(long)]
        plots: Option<PathBuf>,
        /// The residual may be this many times the noise measured at rest before the data count
        /// as bad (then the cause is looked for and the fit is not written without --force).
        #[arg(long, default_value_t = 3.0)]
        max_noise_ratio: f64,
        /// How well the grip sits on a jig point (standard deviation per axis), part of the
        /// reported uncertainty.
        #[arg(long, default_value_t = 0.005e-3)]
        jig_tolerance_m: f64,
        /// Write the fitted geometry into the rig file (atomically, the previous version kept as
        /// a dated backup).
        #[arg(long)]
        write: bool,
        /// Write even if the data are bad, some parameter is weakly determined or the frame is
        /// not observable.
        #[arg(long)]
        force: bool,
    },
    /// Put the grips on the jig's check points and report the position error with the rig file's geometry.
    Verify {
        #[command(flatten)]
        dev: DeviceArgs,
        #[arg(long, value_enum, default_value = "both")]
        hands: Hands,
        #[arg(long, default_value = "configs/jig-spidar-h.ron")]
        jig: PathBuf,
        /// Fail (exit status 1) when any check point is off by more than this (0 .. 0.1 m).
        #[arg(long, default_value_t = 0.001)]
        max_error_m: f64,
    },
}

/// A number option in `lo ..= hi`, or a clear error.
fn check_range(name: &str, v: f64, lo: f64, hi: f64) -> anyhow::Result<()> {
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        bail!("{name} must be a number in {lo} .. {hi} (got {v})");
    }
    Ok(())
}

fn check_device_args(d: &DeviceArgs) -> anyhow::Result<()> {
    check_range("--sim-anchor-error-m", d.sim_anchor_error_m, 0.0, 0.5)?;
    check_range("--sim-mpc-error", d.sim_mpc_error, 0.0, 0.49)?;
    check_range("--noise-counts", d.noise_counts, 0.0, 100.0)?;
    check_range("--pose-timeout-s", d.pose_timeout_s, 3.0, 3600.0)?;
    check_range("--lost-after-s", d.lost_after_s, 0.01, 600.0)?;
    Ok(())
}

/// The simulated rig's truth the options ask for (see the module doc).
fn sim_truth(d: &DeviceArgs) -> SimTruthOptions {
    SimTruthOptions {
        seed: d.seed,
        anchor_error_m: d.sim_anchor_error_m,
        mpc_error: d.sim_mpc_error,
        noise_counts: d.noise_counts,
    }
}

/// The loop's thread: SCHED_FIFO 80 with memory locked (as `spidar run`), or `--no-rt`.
fn rt_options(d: &DeviceArgs) -> RtOptions {
    if d.no_rt {
        RtOptions { fifo_priority: None, lock_memory: false, ..RtOptions::default() }
    } else {
        RtOptions::default()
    }
}

/// Recording options from the command line.
fn record_options(d: &DeviceArgs) -> RecordOptions {
    RecordOptions { timeout_s: d.pose_timeout_s, lost_after_s: d.lost_after_s, ..RecordOptions::default() }
}

/// The stop signals (SIGINT, SIGTERM, SIGHUP), and under a supervisor also the ones it received.
fn stop_signals() -> anyhow::Result<Stop> {
    let stop = Stop::install()?;
    Ok(match supervisor::attached() {
        Some(page) => stop.with_forwarded(&page.stops),
        None => stop,
    })
}

/// Starts the loop on the device `--device` names and runs `body` with a recorder on it and the
/// operator it needs (the simulated user on the simulated rig, the person at the console on
/// boards); then ends the loop (its switch-off), also when `body` failed, the operator aborted,
/// a stop signal came or the board was lost. Returns what `body` made and the loop's line.
fn with_recorder<T>(
    d: &DeviceArgs,
    rig: &Rig,
    what: &str,
    rig_line: &str,
    body: impl FnOnce(&mut Recorder<'_, CalibLoop>, &mut dyn Operator<CalibLoop>, &str) -> Result<T, CalibError>,
) -> anyhow::Result<(T, String, String)> {
    let stop = stop_signals()?;
    let (lp, name) = calibration::start_loop(d.device, &d.hw, &sim_truth(d), rig, &rt_options(d), &stop)?;
    eprintln!("spidar calib {what}: {name}; {rig_line}");
    let live = matches!(lp, CalibLoop::Live(_));
    let mut rec = Recorder::new(lp, rig, record_options(d))?;
    let check = stop.clone();
    rec.set_stop(Arc::new(move || check.requested()));
    let mut op: Box<dyn Operator<CalibLoop>> = if live {
        let mut op = ConsoleOperator::stdio(rig)?;
        op.introduce();
        Box::new(op)
    } else {
        Box::new(SimOperator::new(d.verbose))
    };
    let r = body(&mut rec, &mut *op, &name);
    let off = rec.switch_off();
    let mut stats = format!("loop: {}", rec.loop_stats());
    let lp = rec.finish();
    if let Ok(lp) = &lp {
        if let Some(c) = lp.counters() {
            stats += &format!(
                "; the loop counted {} late or bad replies, {} count jumps, {} faults",
                c.late_replies,
                c.count_jumps[0] + c.count_jumps[1],
                c.faults
            );
        }
        if let Some(rep) = lp.report() {
            stats += &format!("; its thread: {rep}");
        }
    }
    match (r, off) {
        (Ok(t), Ok(())) => Ok((t, name, stats)),
        (Ok(_), Err(e)) => Err(anyhow::Error::new(e).context("switching the outputs off")),
        (Err(e), off) => {
            eprintln!("{stats}");
            let note = match off {
                Ok(()) => "outputs switched off".to_string(),
                Err(o) => format!("switching the outputs off failed ({o}): power the amplifiers down"),
            };
            Err(anyhow::Error::new(e).context(note))
        }
    }
}

/// The device options of a hint (empty for the simulated rig with its defaults).
fn device_hint(d: &DeviceArgs) -> String {
    let mut s = String::new();
    match d.device {
        // Every option that makes the simulated rig what it is: a hint without one of them
        // would verify against another simulated rig.
        DeviceKind::Sim => {
            let d0 = DeviceArgs::sim_defaults();
            if d.seed != d0.seed {
                s += &format!(" --seed {}", d.seed);
            }
            if d.sim_anchor_error_m != d0.sim_anchor_error_m {
                s += &format!(" --sim-anchor-error-m {}", d.sim_anchor_error_m);
            }
            if d.sim_mpc_error != d0.sim_mpc_error {
                s += &format!(" --sim-mpc-error {}", d.sim_mpc_error);
            }
            if d.noise_counts != d0.noise_counts {
                s += &format!(" --noise-counts {}", d.noise_counts);
            }
        }
        DeviceKind::Uart => s += " --device uart",
        DeviceKind::UsbSimple => s += " --device usb-simple",
        DeviceKind::UsbSh4 => s += " --device usb-sh4",
    }
    if d.device != DeviceKind::Sim {
        if let Some(p) = &d.hw.port {
            s += &format!(" --port {}", shell_quote(Path::new(p)));
        }
        if let Some(sw) = d.hw.switch {
            s += &format!(" --switch {sw}");
        }
        if let Some(v) = d.hw.digits_per_volt {
            s += &format!(" --digits-per-volt {v}");
        }
        if d.hw.reply_timeout_us != 800 {
            s += &format!(" --reply-timeout-us {}", d.hw.reply_timeout_us);
        }
        if d.no_rt {
            s += " --no-rt";
        }
    }
    s
}

/// `--rig <file>` for a hint (empty when there is no file: the built-in template).
fn rig_hint(src: &RigSource) -> String {
    src.path().map_or(String::new(), |p| format!(" --rig {}", shell_quote(p)))
}

/// Runs a calibration command; the exit status (0, or the supervisor's when it had to write
/// zero to the boards: 3).
pub fn run(cmd: CalibCmd) -> anyhow::Result<u8> {
    // On boards the same supervisor as `spidar run` watches this process: in the supervisor the
    // command ends here, with the status it gives.
    if let CalibCmd::Home { dev: d, .. }
    | CalibCmd::Screen { dev: d, .. }
    | CalibCmd::Record { dev: d, .. }
    | CalibCmd::Verify { dev: d, .. } = &cmd
    {
        check_device_args(d)?;
        if let Some(code) = calibration::supervise_boards(d.device, &d.hw, d.rig.as_deref(), &rt_options(d))?
        {
            return Ok(code);
        }
    }
    match cmd {
        CalibCmd::Home { dev, hands, write } => home(&dev, hands, write),
        CalibCmd::Screen { dev, view, write } => screen(&dev, &view, write),
        CalibCmd::Record { dev, hands, jig, free, free_half_extent_m, out, resume } => {
            record(&dev, hands, jig, free, free_half_extent_m, &out, resume)
        }
        CalibCmd::Fit { rig, session, fixed_mpc, plots, max_noise_ratio, jig_tolerance_m, write, force } => {
            check_range("--max-noise-ratio", max_noise_ratio, 1.0, 1e6)?;
            check_range("--jig-tolerance-m", jig_tolerance_m, 0.0, 0.01)?;
            let opts = FitOptions {
                fit_metres_per_count: !fixed_mpc,
                jig_tolerance_m,
                quality: QualityOptions { max_noise_ratio, ..QualityOptions::default() },
                ..FitOptions::default()
            };
            fit(rig.as_deref(), &session, &opts, plots, write, force)
        }
        CalibCmd::Verify { dev, hands, jig, max_error_m } => verify(&dev, hands, &jig, max_error_m),
    }
    .map(|()| 0)
}

fn screen(d: &DeviceArgs, view: &str, write: bool) -> anyhow::Result<()> {
    use spidar_runtime::placement::{
        demo_screen, place_screen, scripted_person, PlaceOptions, PlacementView,
    };
    check_device_args(d)?;
    let src = rigpath::calibration_target(d.rig.as_deref(), true)?;
    let (rig, text) = src.load()?;
    let stop = stop_signals()?;
    // The calibration session's loop: on boards on its real-time thread under the supervisor; on
    // the simulated rig (the rig file's truth, a scripted person) on the virtual clock.
    let (lp, name) = match d.hw.choice(d.device, &rig)? {
        None => {
            let truth = match rig.display {
                Some(t) => t,
                None => demo_screen(&rig)?,
            };
            let scripts = scripted_person(&rig, &truth, [DVec3::ZERO; 5]);
            let dev = spidar_runtime::session::sim_device(&rig, scripts, &Default::default())?;
            let lp = spidar_calib::ticks::VirtualLoop::start(dev, &rig, false)?;
            (CalibLoop::Sim(lp), "the simulated rig (a scripted person places the screen)".to_string())
        }
        Some(_) => calibration::start_loop(d.device, &d.hw, &sim_truth(d), &rig, &rt_options(d), &stop)?,
    };
    let page = PlacementView::start(&rig, spidar_world::view::parse_addr(view)?)?;
    eprintln!(
        "spidar calib screen: {name}; rig file {}; open {} full screen on the rig's screen",
        src.describe(),
        page.url
    );
    let check = stop.clone();
    let opts = PlaceOptions {
        timeout_s: 600.0,
        lost_after_s: d.lost_after_s,
        stop: Some(Arc::new(move || check.requested())),
    };
    let placed = place_screen(lp, &rig, &opts, &mut |l: String| eprintln!("{l}"))?;
    drop(page);
    if let Some(c) = placed.source.counters() {
        eprintln!(
            "the loop counted {} late or bad replies, {} count jumps, {} faults",
            c.late_replies,
            c.count_jumps[0] + c.count_jumps[1],
            c.faults
        );
    }
    let p = placed.placement;
    let dsp = &p.display;
    println!(
        "screen: {:.3} x {:.3} m, lower left ({:.4}, {:.4}, {:.4}) m, facing ({:.3}, {:.3}, {:.3}); targets off the fit: rms {:.1} mm, worst {:.1} mm",
        dsp.width_m, dsp.height_m, dsp.lower_left_m.x, dsp.lower_left_m.y, dsp.lower_left_m.z,
        dsp.normal().x, dsp.normal().y, dsp.normal().z, p.rms_m * 1e3, p.worst_m * 1e3
    );
    let path = src.path().context("placing the screen needs a rig file")?;
    if write {
        let note =
            format!("Placed by `spidar calib screen` (targets off the fit: rms {:.1} mm).", p.rms_m * 1e3);
        let r = spidar_calib::display::update_display(path, &text, dsp, &note)?;
        println!(
            "wrote the screen into {}{}",
            r.target.display(),
            r.backup.map(|b| format!(" (previous: {})", b.display())).unwrap_or_default()
        );
    } else {
        println!("not written: run again with --write to store it in {}", shell_quote(path));
    }
    Ok(())
}

fn home(d: &DeviceArgs, hands: Hands, write: bool) -> anyhow::Result<()> {
    let src = rigpath::calibration_target(d.rig.as_deref(), true)?;
    let (rig, text) = src.load()?;
    let rig_line = format!("rig file {}", src.describe());
    let (geometry, _, stats) =
        with_recorder(d, &rig, "home", &rig_line, |rec, op, _| home_hands(rec, op, &rig, hands))?;
    eprintln!("{stats}");
    let path = src.path().context("homing needs a rig file")?;
    if write {
        let stamp = Stamp { homed_utc: spidar_calib::utc_now(), ..Stamp::default() };
        let w = update_rig_file(path, &text, &geometry, &stamp)?;
        println!("wrote {}{}", w.target.display(), backup_note(&w.backup));
        println!("next: spidar calib verify{}{}", rig_hint(&src), device_hint(d));
    } else {
        println!(
            "(not written: add --write to store these lengths in {}: spidar calib home{}{} --write)",
            path.display(),
            rig_hint(&src),
            device_hint(d)
        );
    }
    Ok(())
}

fn backup_note(b: &Option<PathBuf>) -> String {
    b.as_ref().map_or(String::new(), |b| format!(" (previous version kept as {})", b.display()))
}

fn home_hands(
    rec: &mut Recorder<'_, CalibLoop>,
    op: &mut dyn Operator<CalibLoop>,
    rig: &Rig,
    hands: Hands,
) -> Result<[Option<HandGeometry>; 2], CalibError> {
    let mut geometry = [None, None];
    for h in hands.list() {
        let home = rig.hands[h].home_m;
        let (counts, _) = rec.record_at(op, h, &Request::Home { at_m: home })?;
        let g = HandGeometry::homed(&rig.hands[h], &counts, home);
        println!(
            "hand {h} ({}): counts {:?} at the home point -> length_at_zero_m {:.6?}",
            rig.hands[h].label,
            counts.map(|c| c.round() as i64),
            g.length_at_zero_m
        );
        geometry[h] = Some(g);
    }
    Ok(geometry)
}

/// The plan of a new session, checked (pose counts the fit needs, hands, box).
fn new_plan(hands: Hands, jig: Option<&Path>, free: usize, half: f64) -> anyhow::Result<Plan> {
    check_range("--free-half-extent-m", half, 0.05, 1.0)?;
    let jig = jig.map(JigFile::load).transpose()?;
    let plan = Plan { hands: hands.list(), jig, free_per_hand: free, free_half_extent_m: DVec3::splat(half) };
    plan.check()?;
    Ok(plan)
}

/// The plan of a session to resume, with its jig file (which must still hold the points recorded).
fn resumed_plan(session: &SessionFile, out: &Path) -> anyhow::Result<Plan> {
    let Some(p) = &session.plan else {
        bail!("{}: a version 1 session has no plan and cannot be resumed: record a new one", out.display())
    };
    let jig = match &p.jig_file {
        Some(f) => {
            let jig = JigFile::load(Path::new(f)).with_context(|| format!("the session's jig file {f}"))?;
            for pose in &session.poses {
                if let PoseKind::Jig { label, at_m } = &pose.kind {
                    let same = jig
                        .fit_points
                        .iter()
                        .any(|q| q.hand == pose.hand && &q.label == label && q.at_m == *at_m);
                    if !same {
                        bail!(
                            "the jig file {f} no longer has point {label} of hand {} at {at_m:?} as recorded: \
                             restore it, or record a new session",
                            pose.hand
                        );
                    }
                }
            }
            Some(jig)
        }
        None => None,
    };
    let plan = Plan {
        hands: p.hands.clone(),
        jig,
        free_per_hand: p.free_per_hand,
        free_half_extent_m: DVec3::splat(p.free_half_extent_m),
    };
    plan.check()?;
    Ok(plan)
}

fn record(
    d: &DeviceArgs,
    hands: Hands,
    jig: Option<PathBuf>,
    free: usize,
    half: f64,
    out: &Path,
    resume: bool,
) -> anyhow::Result<()> {
    let src = RigSource::resolve(d.rig.as_deref());
    let (rig, _) = src.load()?;
    // Everything that can be checked is checked before the first pose.
    spidar_calib::safefile::check_writable(out)?;
    let (mut session, plan) = if resume {
        let session = SessionFile::load(out)
            .with_context(|| format!("resuming {} (start a new session without --resume)", out.display()))?;
        if session.complete {
            bail!(
                "{} is complete already: fit it with spidar calib fit{} --session {}",
                out.display(),
                rig_hint(&src),
                shell_quote(out)
            );
        }
        if session.rig_name != rig.name {
            bail!(
                "{} was recorded with the rig '{}', the rig file {} is '{}': give the same --rig",
                out.display(),
                session.rig_name,
                src.describe(),
                rig.name
            );
        }
        let plan = resumed_plan(&session, out)?;
        (session, plan)
    } else {
        let plan = new_plan(hands, jig.as_deref(), free, half)?;
        if let Some(b) = spidar_calib::safefile::keep_dated_copy(out)? {
            eprintln!("{} exists: kept as {}", out.display(), b.display());
        }
        let rig_file = src.path().map_or("(built in)".to_string(), |p| p.display().to_string());
        let sp = plan.session_plan(jig.as_ref().map(|j| j.display().to_string()));
        (SessionFile::new(&rig.name, &rig_file, "", sp), plan)
    };
    let rig_line = format!("rig file {}; session {}", src.describe(), out.display());
    let t0 = std::time::Instant::now();
    let before = session.poses.len();
    let mut save = |s: &SessionFile| s.save(out);
    let session_ref = &mut session;
    let result = with_recorder(d, &rig, "record", &rig_line, |rec, op, name| {
        if session_ref.device.is_empty() {
            session_ref.device = name.to_string();
        }
        rec.record_plan(op, &plan, session_ref, &mut save).map(|_| rec.warnings().to_vec())
    });
    let resume_hint = format!(
        "spidar calib record{}{} --out {} --resume",
        rig_hint(&src),
        device_hint(d),
        shell_quote(out)
    );
    let (warnings, _, stats) = match result {
        Ok(w) => w,
        Err(e) => {
            let total: usize = plan.hands.iter().map(|&h| session.poses_of(h).count()).sum();
            eprintln!(
                "{} poses kept in {} ({} this time); continue with: {resume_hint}",
                total,
                out.display(),
                total - before
            );
            return Err(e);
        }
    };
    session.complete = true;
    session.save(out)?;
    for h in &plan.hands {
        println!("hand {h}: {} poses recorded", session.poses_of(*h).count());
    }
    for w in &warnings {
        println!("warning: {w}");
    }
    println!("{stats}");
    println!("saved {} ({:.1} s); rig file {}", out.display(), t0.elapsed().as_secs_f64(), src.describe());
    println!("next: spidar calib fit{} --session {} --write", rig_hint(&src), shell_quote(out));
    Ok(())
}

fn fit(
    rig: Option<&Path>,
    session_path: &Path,
    opts: &FitOptions,
    plots: Option<PathBuf>,
    write: bool,
    force: bool,
) -> anyhow::Result<()> {
    let src = if write { rigpath::calibration_target(rig, true)? } else { RigSource::resolve(rig) };
    let (rig, text) = src.load()?;
    let session = SessionFile::load(session_path)?;
    println!("spidar calib fit: session {}; rig file {}", session_path.display(), src.describe());
    if session.rig_name != rig.name {
        eprintln!(
            "warning: the session was recorded with the rig '{}', this rig file is '{}'",
            session.rig_name, rig.name
        );
    }
    if !session.complete {
        println!(
            "note: the session is incomplete ({} poses); fitting what is there (continue it with spidar calib \
             record{} --out {} --resume)",
            session.poses.len(),
            rig_hint(&src),
            shell_quote(session_path)
        );
    }
    let plots = plots.unwrap_or_else(|| {
        let mut p = session_path.as_os_str().to_owned();
        p.push(".plots");
        PathBuf::from(p)
    });
    let mut geometry = [None, None];
    let mut refusals: Vec<String> = Vec::new();
    let mut rms = 0.0f64;
    for (h, slot) in geometry.iter_mut().enumerate() {
        let obs = observations(&session, h);
        if obs.is_empty() {
            continue;
        }
        let t0 = std::time::Instant::now();
        let fit = fit_hand(h, &rig.hands[h], &obs, opts)?;
        let dt = t0.elapsed();
        print!("{fit}");
        println!("  fit took {:.0} ms", dt.as_secs_f64() * 1e3);
        let files = spidar_calib::plot::write_plots(&fit, &plots)?;
        for f in files {
            println!("  plot: {}", f.display());
        }
        refusals.extend(fit.quality_lines());
        // (Weak parameters through bad data follow from the data: the quality line says what to do.)
        let weak = fit.params.iter().any(|p| p.status == spidar_calib::fit::Observability::Weak);
        if weak && fit.quality.clean() {
            refusals.push(format!(
                "hand {h}: some parameter is weakly determined (marked WEAK): record more poses"
            ));
        }
        if fit.gauge_dof > 0 {
            refusals
                .push(format!("hand {h}: the rig frame is not observable from free poses alone: add a jig"));
        }
        rms = rms.max(fit.rms_m);
        *slot = Some(fit.geometry);
    }
    if geometry.iter().all(Option::is_none) {
        bail!("the session {} has no poses", session_path.display());
    }
    let fitted: [Option<[glam::DVec3; 4]>; 2] =
        std::array::from_fn(|h| geometry[h].as_ref().map(|g| g.anchors_m));
    println!("{}", spidar_calib::rigmap_plot::fit_change(&rig, &fitted));
    let Some(path) = src.path().filter(|_| write) else {
        println!(
            "(rig file not changed: add --write to store the fitted geometry: spidar calib fit{} --session {} --write)",
            rig_hint(&src),
            shell_quote(session_path)
        );
        return Ok(());
    };
    if !refusals.is_empty() && !force {
        bail!(
            "not written to {}:\n  {}\nrecord again as said, or add --force to write anyway",
            path.display(),
            refusals.join("\n  ")
        );
    }
    let stamp = Stamp {
        fitted_utc: spidar_calib::utc_now(),
        fit_residual_rms_m: Some(rms),
        session: session_path.display().to_string(),
        ..Stamp::default()
    };
    let w = update_rig_file(path, &text, &geometry, &stamp)?;
    println!("wrote the fitted geometry into {}{}", w.target.display(), backup_note(&w.backup));
    println!("next: spidar calib verify{}", rig_hint(&src));
    Ok(())
}

fn verify(d: &DeviceArgs, hands: Hands, jig: &Path, max_error_m: f64) -> anyhow::Result<()> {
    check_range("--max-error-m", max_error_m, 1e-6, 0.1)?;
    let src = RigSource::resolve(d.rig.as_deref());
    let (rig, _) = src.load()?;
    let jig = JigFile::load(jig)?;
    let geometry: [Option<HandGeometry>; 2] = std::array::from_fn(|h| HandGeometry::from_rig(&rig.hands[h]));
    let geometry = match geometry {
        [Some(a), Some(b)] => [a, b],
        _ => bail!(
            "the rig file {} has no length_at_zero_m: run `spidar calib home{} --write` or `spidar calib fit{} --write` first",
            src.describe(),
            rig_hint(&src),
            rig_hint(&src)
        ),
    };
    let rig_line = format!("rig file {}", src.describe());
    let list = hands.list();
    let (report, _, stats) = with_recorder(d, &rig, "verify", &rig_line, |rec, op, _| {
        spidar_calib::verify::verify(rec, op, &rig, &geometry, &jig, &list)
    })?;
    println!("{report}");
    eprintln!("{stats}");
    println!("rig file {}", src.describe());
    if report.max_error_m() > max_error_m {
        bail!(
            "a check point is off by {:.3} mm (limit {:.3} mm): calibrate (spidar calib record{}{} --jig ..., then \
             spidar calib fit{} --write) and verify again",
            report.max_error_m() * 1e3,
            max_error_m * 1e3,
            rig_hint(&src),
            device_hint(d),
            rig_hint(&src)
        );
    }
    Ok(())
}
