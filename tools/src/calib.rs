//! `spidar calib`: home, record, fit and verify the string geometry of a rig (see
//! `spidar-calib`). Arguments are checked here; the work is in the calib crate.
//!
//! `--device sim` (the default) is the simulated rig, its grips moved by a scripted operator. Its
//! true geometry is the built-in rig file perturbed by `--seed` (anchors off by centimetres,
//! metres per count by up to 10 %, counters starting anywhere), whatever `--rig` says, so that
//! home, record, fit --write and verify all run against the same simulated hardware while the rig
//! file is being corrected. `--device uart|usb-simple|usb-sh4` opens the boards as `spidar run`
//! does (`hardware::open_hardware`) and asks a person at the console to move the grips
//! (`ConsoleOperator`: Enter, s, q); the outputs are switched off however the command ends.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::{Args, Subcommand, ValueEnum};
use glam::DVec3;
use spidar_calib::console::ConsoleOperator;
use spidar_calib::fit::{fit_hand, observations, FitOptions};
use spidar_calib::jig::JigFile;
use spidar_calib::model::HandGeometry;
use spidar_calib::record::{Operator, Plan, RecordOptions, Recorder, Request, SimOperator};
use spidar_calib::rigfile::{update_rig_file, Stamp};
use spidar_calib::session::SessionFile;
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_device::sim::SimRig;
use spidar_device::Device;
use spidar_rt::Rig;

use crate::hardware::{self, DeviceKind, HardwareArgs};
use crate::signals::Stop;

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
    /// Rig file (RON) whose geometry is calibrated (and written with --write).
    #[arg(long, default_value = "configs/rig-spidar-h.ron")]
    pub rig: PathBuf,
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
    /// Simulated rig: print every request and progress line (a console operator always sees them).
    #[arg(long, short)]
    pub verbose: bool,
}

#[derive(Subcommand, Debug)]
pub enum CalibCmd {
    /// Hold each grip at its home point and preset the lengths at counter zero from the
    /// configured anchors (what `spidar run` does at start); --write stores them and the time.
    Home {
        #[command(flatten)]
        dev: DeviceArgs,
        #[arg(long, value_enum, default_value = "both")]
        hands: Hands,
        /// Write the lengths into the rig file (atomically, old file kept as <file>.bak).
        #[arg(long)]
        write: bool,
    },
    /// Guided recording: home pose, jig points, free poses; saves a session file.
    Record {
        #[command(flatten)]
        dev: DeviceArgs,
        #[arg(long, value_enum, default_value = "both")]
        hands: Hands,
        /// Jig file with known points (fit_points are recorded). Without it: free poses only.
        #[arg(long)]
        jig: Option<PathBuf>,
        /// Free poses per hand.
        #[arg(long, default_value_t = 40)]
        free: usize,
        /// Half size of the box around each home point that free-pose suggestions fill.
        #[arg(long, default_value_t = 0.3)]
        free_half_extent_m: f64,
        /// Session file to write.
        #[arg(long, default_value = "calib-session.ron")]
        out: PathBuf,
    },
    /// Fit the geometry to a session; report, plots, optionally write the rig file.
    Fit {
        /// Rig file with the configured geometry (start values; written with --write).
        #[arg(long, default_value = "configs/rig-spidar-h.ron")]
        rig: PathBuf,
        #[arg(long, default_value = "calib-session.ron")]
        session: PathBuf,
        /// Keep the configured metres per count instead of fitting them.
        #[arg(long)]
        fixed_mpc: bool,
        /// Folder for the SVG plots (default: <session>.plots).
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Write the fitted geometry into the rig file (atomically, old file kept as <file>.bak).
        #[arg(long)]
        write: bool,
        /// Write even if some parameter is weakly determined or the frame is not observable.
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
        /// Fail (exit status 1) when any check point is off by more than this.
        #[arg(long, default_value_t = 0.001)]
        max_error_m: f64,
    },
}

fn check_device_args(d: &DeviceArgs) -> anyhow::Result<()> {
    if !(d.sim_anchor_error_m.is_finite() && (0.0..=0.5).contains(&d.sim_anchor_error_m)) {
        bail!("--sim-anchor-error-m must be in 0 .. 0.5 m");
    }
    if !(d.sim_mpc_error.is_finite() && (0.0..0.5).contains(&d.sim_mpc_error)) {
        bail!("--sim-mpc-error must be in 0 .. 0.5");
    }
    if !(d.noise_counts.is_finite() && d.noise_counts >= 0.0) {
        bail!("--noise-counts must be >= 0");
    }
    Ok(())
}

fn load_rig(path: &Path) -> anyhow::Result<(Rig, String)> {
    let text = spidar_config::read_capped(path, spidar_config::MAX_FILE_BYTES)
        .with_context(|| format!("reading the rig file {} (give one with --rig)", path.display()))?;
    let rig = Rig::from_str(&text, &path.display().to_string())?;
    Ok((rig, text))
}

/// The simulated device: the built-in rig perturbed by the seed (see the module doc).
fn sim_device(d: &DeviceArgs, rig: &Rig) -> anyhow::Result<(SimRig, String)> {
    check_device_args(d)?;
    let base = Rig::default_rig();
    let opts = SimTruthOptions {
        seed: d.seed,
        anchor_error_m: d.sim_anchor_error_m,
        mpc_error: d.sim_mpc_error,
        noise_counts: d.noise_counts,
    };
    let truth = truth_geometry(&base, &opts);
    let dev = sim_rig(rig, &truth, d.noise_counts, d.seed)?;
    let name = format!(
        "simulated SPIDAR-H (seed {}, anchors off by up to {:.0} mm, metres per count by up to {:.0} %, noise {} counts)",
        d.seed,
        d.sim_anchor_error_m * 1e3,
        d.sim_mpc_error * 100.0,
        d.noise_counts
    );
    Ok((dev, name))
}

/// The device a calibration command drives, opened.
enum Opened {
    /// The simulated rig, its grips moved by the [`SimOperator`].
    Sim(Box<SimRig>),
    /// Real boards, its grips moved by a person at the console.
    Board(Box<dyn Device>),
}

/// Opens the device `--device` names, with the same options and messages as `spidar run`.
fn open_device(d: &DeviceArgs, rig: &Rig) -> anyhow::Result<(Opened, String)> {
    match d.hw.choice(d.device, rig)? {
        None => {
            let (dev, name) = sim_device(d, rig)?;
            Ok((Opened::Sim(Box::new(dev)), name))
        }
        Some(choice) => {
            let dev = hardware::open_hardware(&choice)?;
            let name = format!("{} ({})", dev.info().board, dev.info().identity);
            hardware::check_rig_against(rig, dev.info())?;
            Ok((Opened::Board(dev), name))
        }
    }
}

/// Recording on a board is paced by the wall clock (one exchange per tick period), which also
/// keeps the strings at minimum tension (the boards hold their last command: no watchdog).
/// A stop signal (SIGINT, SIGTERM, SIGHUP) aborts either kind with the outputs switched off.
fn board_record_options() -> anyhow::Result<RecordOptions> {
    Ok(RecordOptions { pace: true, ..sim_record_options()? })
}

/// The simulated rig's recording: unpaced, stopped by a stop signal like a board's.
fn sim_record_options() -> anyhow::Result<RecordOptions> {
    Ok(RecordOptions { stop: Some(Stop::install()?.counter()), ..RecordOptions::default() })
}

/// The person at the console, told how it works.
fn console_operator(rig: &Rig) -> anyhow::Result<ConsoleOperator> {
    let mut op = ConsoleOperator::stdio(rig)?.with_stop(Stop::install()?.counter());
    op.introduce();
    Ok(op)
}

/// Runs `body` on an activated recorder and switches the outputs off afterwards, also when
/// `body` failed or the operator aborted.
fn with_recorder<D: Device, O: Operator<D>, T>(
    mut rec: Recorder<'_, D>,
    op: &mut O,
    body: impl FnOnce(&mut Recorder<'_, D>, &mut O) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let r = body(&mut rec, op);
    let off = rec.finish();
    let t = r?;
    off.context("switching the outputs off")?;
    Ok(t)
}

pub fn run(cmd: CalibCmd) -> anyhow::Result<()> {
    match cmd {
        CalibCmd::Home { dev, hands, write } => home(&dev, hands, write),
        CalibCmd::Record { dev, hands, jig, free, free_half_extent_m, out } => {
            record(&dev, hands, jig, free, free_half_extent_m, &out)
        }
        CalibCmd::Fit { rig, session, fixed_mpc, plots, write, force } => {
            fit(&rig, &session, fixed_mpc, plots, write, force)
        }
        CalibCmd::Verify { dev, hands, jig, max_error_m } => verify(&dev, hands, &jig, max_error_m),
    }
}

fn home(d: &DeviceArgs, hands: Hands, write: bool) -> anyhow::Result<()> {
    let (rig, text) = load_rig(&d.rig)?;
    let (dev, name) = open_device(d, &rig)?;
    eprintln!("spidar calib home: {name}");
    let geometry = match dev {
        Opened::Sim(dev) => with_recorder(
            Recorder::new(*dev, &rig, sim_record_options()?)?,
            &mut SimOperator::new(d.verbose),
            |rec, op| home_hands(rec, op, &rig, hands),
        )?,
        Opened::Board(dev) => with_recorder(
            Recorder::opened(dev, &rig, board_record_options()?)?,
            &mut console_operator(&rig)?,
            |rec, op| home_hands(rec, op, &rig, hands),
        )?,
    };
    if write {
        let stamp = Stamp { homed_utc: spidar_calib::utc_now(), ..Stamp::default() };
        let bak = update_rig_file(&d.rig, &text, &geometry, &stamp)?;
        println!("wrote {} (previous file kept as {})", d.rig.display(), bak.display());
    } else {
        println!("(not written: add --write to store these lengths in {})", d.rig.display());
    }
    Ok(())
}

fn home_hands<D: Device, O: Operator<D>>(
    rec: &mut Recorder<'_, D>,
    op: &mut O,
    rig: &Rig,
    hands: Hands,
) -> anyhow::Result<[Option<HandGeometry>; 2]> {
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

fn record(
    d: &DeviceArgs,
    hands: Hands,
    jig: Option<PathBuf>,
    free: usize,
    half: f64,
    out: &Path,
) -> anyhow::Result<()> {
    if !(half.is_finite() && (0.05..=1.0).contains(&half)) {
        bail!("--free-half-extent-m must be in 0.05 .. 1 m");
    }
    let (rig, _) = load_rig(&d.rig)?;
    let jig = jig.map(|p| JigFile::load(&p)).transpose()?;
    let plan = Plan { hands: hands.list(), jig, free_per_hand: free, free_half_extent_m: DVec3::splat(half) };
    let (dev, name) = open_device(d, &rig)?;
    eprintln!("spidar calib record: {name}");
    let t0 = std::time::Instant::now();
    let (session, warnings) = match dev {
        Opened::Sim(dev) => with_recorder(
            Recorder::new(*dev, &rig, sim_record_options()?)?,
            &mut SimOperator::new(d.verbose),
            |rec, op| {
                let session = rec.record_plan(op, &plan, &name)?;
                Ok((session, rec.warnings().to_vec()))
            },
        )?,
        Opened::Board(dev) => with_recorder(
            Recorder::opened(dev, &rig, board_record_options()?)?,
            &mut console_operator(&rig)?,
            |rec, op| {
                let session = rec.record_plan(op, &plan, &name)?;
                Ok((session, rec.warnings().to_vec()))
            },
        )?,
    };
    session.save(out)?;
    for h in hands.list() {
        println!("hand {h}: {} poses recorded", session.poses_of(h).count());
    }
    for w in &warnings {
        println!("warning: {w}");
    }
    println!(
        "saved {} ({:.1} s); next: spidar calib fit --session {}",
        out.display(),
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

fn fit(
    rig_path: &Path,
    session_path: &Path,
    fixed_mpc: bool,
    plots: Option<PathBuf>,
    write: bool,
    force: bool,
) -> anyhow::Result<()> {
    let (rig, text) = load_rig(rig_path)?;
    let session = SessionFile::load(session_path)?;
    let plots = plots.unwrap_or_else(|| {
        let mut p = session_path.as_os_str().to_owned();
        p.push(".plots");
        PathBuf::from(p)
    });
    let opts = FitOptions { fit_metres_per_count: !fixed_mpc, ..FitOptions::default() };
    let mut geometry = [None, None];
    let mut trustworthy = true;
    let mut rms = 0.0f64;
    for (h, slot) in geometry.iter_mut().enumerate() {
        let obs = observations(&session, h);
        if obs.is_empty() {
            continue;
        }
        let t0 = std::time::Instant::now();
        let fit = fit_hand(h, &rig.hands[h], &obs, &opts)?;
        let dt = t0.elapsed();
        print!("{fit}");
        println!("  fit took {:.0} ms", dt.as_secs_f64() * 1e3);
        let files = spidar_calib::plot::write_plots(&fit, &plots)?;
        for f in files {
            println!("  plot: {}", f.display());
        }
        trustworthy &= fit.is_trustworthy() && fit.gauge_dof == 0;
        rms = rms.max(fit.rms_m);
        *slot = Some(fit.geometry);
    }
    if geometry.iter().all(Option::is_none) {
        bail!("the session {} has no poses", session_path.display());
    }
    if write {
        if !trustworthy && !force {
            bail!(
                "not written: some parameter is weakly determined or the frame is not observable (see above); \
                 record more data as advised, or add --force to write anyway"
            );
        }
        let stamp = Stamp {
            fitted_utc: spidar_calib::utc_now(),
            fit_residual_rms_m: Some(rms),
            session: session_path.display().to_string(),
            ..Stamp::default()
        };
        let bak = update_rig_file(rig_path, &text, &geometry, &stamp)?;
        println!(
            "wrote the fitted geometry into {} (previous file kept as {})",
            rig_path.display(),
            bak.display()
        );
    } else {
        println!(
            "(rig file not changed: add --write to store the fitted geometry in {})",
            rig_path.display()
        );
    }
    Ok(())
}

fn verify(d: &DeviceArgs, hands: Hands, jig: &Path, max_error_m: f64) -> anyhow::Result<()> {
    let (rig, _) = load_rig(&d.rig)?;
    let jig = JigFile::load(jig)?;
    let geometry: [Option<HandGeometry>; 2] = std::array::from_fn(|h| HandGeometry::from_rig(&rig.hands[h]));
    let geometry = match geometry {
        [Some(a), Some(b)] => [a, b],
        _ => bail!(
            "the rig file {} has no length_at_zero_m: run `spidar calib home --write` or `spidar calib fit --write` first",
            d.rig.display()
        ),
    };
    let (dev, name) = open_device(d, &rig)?;
    eprintln!("spidar calib verify: {name}");
    let report = match dev {
        Opened::Sim(dev) => with_recorder(
            Recorder::new(*dev, &rig, sim_record_options()?)?,
            &mut SimOperator::new(d.verbose),
            |rec, op| Ok(spidar_calib::verify::verify(rec, op, &rig, &geometry, &jig, &hands.list())?),
        )?,
        Opened::Board(dev) => with_recorder(
            Recorder::opened(dev, &rig, board_record_options()?)?,
            &mut console_operator(&rig)?,
            |rec, op| Ok(spidar_calib::verify::verify(rec, op, &rig, &geometry, &jig, &hands.list())?),
        )?,
    };
    println!("{report}");
    if report.max_error_m() > max_error_m {
        bail!(
            "a check point is off by {:.3} mm (limit {:.3} mm): calibrate (spidar calib record, fit --write) and verify again",
            report.max_error_m() * 1e3,
            max_error_m * 1e3
        );
    }
    Ok(())
}
