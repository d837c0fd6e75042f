//! Runs a checked [`RunPlan`] (`spidar run`): on real boards under a supervisor process, then the
//! world where the plan puts it, the recording, the device, the session on its clock, and the
//! summary. Each step is its own function, in the order a run takes them.
//!
//! Must never: open a device before everything that can fail without one has been set up (a
//! recording path that cannot be written stops the run before a board moves), or return before
//! the session has ended the way the rig's safety rules say.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::bail;
use spidar_device::Device;
use spidar_record::world::{WorldRecorder, WorldRecording};
use spidar_rt::telemetry::fmt_dur;
use spidar_world::host::Stepper;

use crate::child_world::ChildWorldSpec;
use crate::plan::{Clock, RunPlan, WorldPlan};
use crate::recording;
use crate::session::{self, LiveOptions, SimOptions, VirtualOptions, VirtualWorld, WorldChoice};
use crate::signals::Stop;
use crate::supervisor::{self, Shared};
use crate::{errln, hardware, outln, report, world_process};

/// Runs `plan`; the exit status (0 unless a supervisor took the boards over).
pub fn run(plan: RunPlan) -> anyhow::Result<u8> {
    // A certificate that does not read is refused before the rig starts (the world reads it again).
    if let (Some(t), false) = (&plan.view.view_tls, plan.view.no_view) {
        spidar_world::view::TlsIdentity::from_arg(t)?;
    }
    // Real boards hold their last command if this process dies: a supervisor watches over it.
    let supervised = supervisor::attached();
    if let (Some(choice), None) = (&plan.hardware, supervised) {
        let stop = Stop::install()?;
        let choice = choice.clone();
        return supervisor::supervise(&stop, plan.rt.fifo_priority, &mut |page| {
            hardware::open_for_takeover(&choice, page)
        });
    }
    let stop = match supervised {
        Some(page) => Stop::install()?.with_forwarded(&page.stops),
        None => Stop::install()?,
    };
    let (mut world, scene_name) = start_world(&plan)?;
    let mut records = start_recording(&plan, &mut world)?;
    let (dev, script_name) = open_device(&plan, &scene_name, supervised)?;
    let device = format!("{} ({})", dev.info().board, dev.info().identity);
    let names = Names { device, scene: scene_name, script: script_name };
    match plan.clock {
        Clock::Virtual { seconds } => {
            run_virtual(&plan, dev, world, &mut records, names, seconds, stop, supervised)
        }
        Clock::Real { seconds } => run_live(&plan, dev, world, records, names, seconds, stop, supervised),
    }
}

/// What the summary calls the device, the scene and the script.
struct Names {
    device: String,
    scene: String,
    script: String,
}

/// The world: its scene loaded here for a thread (the virtual clock's too) with its live view,
/// or the arguments of a child process, or the address of a world already running. Returns the
/// scene's name for the summary.
fn start_world(plan: &RunPlan) -> anyhow::Result<(WorldChoice, String)> {
    let scene_arg = &plan.scene;
    // The world's scene is loaded where the world runs: here for the virtual clock and a thread,
    // in the world process otherwise (the rig process stays small).
    Ok(match &plan.world {
        WorldPlan::Thread => {
            let scene = spidar_world::load_with_skill(scene_arg, plan.skill.as_deref())?;
            let name = match &plan.skill {
                Some(skill) => format!("{scene_arg} ({}, skill {skill})", scene.name()),
                None => format!("{scene_arg} ({})", scene.name()),
            };
            // The live view runs on the real clock only.
            let view = if matches!(plan.clock, Clock::Virtual { .. }) {
                if plan.view.view.is_some() {
                    errln!("spidar: no live view with --virtual (it runs faster than real time)");
                }
                None
            } else {
                world_process::start_view(&plan.view, &*scene)?
            };
            let mut stepper = Stepper::new(scene);
            if let Some(v) = view {
                stepper.add_observer(Box::new(v));
            }
            (WorldChoice::Thread(stepper), name)
        }
        WorldPlan::Child { restarts } => {
            let mut spec = ChildWorldSpec::this_executable(scene_arg, *restarts)?;
            if let Some(p) = plan.world_priority {
                spec.extra.extend(["--priority".into(), p.to_string().into()]);
            }
            spec.extra.extend(plan.view.child_args());
            if let Some(skill) = &plan.skill {
                // Checked here, so a wrong level is refused before the child starts.
                spidar_sim::boxer::SkillLevel::parse(skill).map_err(|e| anyhow::anyhow!("--skill: {e}"))?;
                spec.extra.extend(["--skill".into(), skill.into()]);
            }
            let name = match &plan.skill {
                Some(skill) => format!("{scene_arg} (skill {skill})"),
                None => scene_arg.clone(),
            };
            (WorldChoice::Child(spec), name)
        }
        WorldPlan::Connect(at) => {
            if plan.view.view.is_some() || plan.view.no_view {
                errln!("spidar: the world at {at} serves its own live view (spidar world --view/--no-view)");
            }
            let name = plan.scene_asked.clone().unwrap_or_else(|| "as the world runs it".into());
            (WorldChoice::Connect { at: at.clone(), scene: plan.scene_asked.clone() }, name)
        }
    })
}

/// What `--record` writes: the rig's recording, and the world's share wherever the world runs.
#[derive(Default)]
struct Records {
    rig: Option<spidar_record::writer::Recorder>,
    /// The world's recording when the world is a thread of this process.
    world: Option<WorldRecording>,
    /// On the virtual clock the world's recorder observes the stepped scene directly.
    world_observer: Option<WorldRecorder>,
    /// The file a child world process writes.
    child_world_file: Option<PathBuf>,
}

/// Creates the recordings before the device opens (a path that cannot be written stops the run
/// here): the rig's FILE.mcap, and FILE.world.mcap next to it, written by the world wherever it
/// runs on the rig recording's time line.
fn start_recording(plan: &RunPlan, world: &mut WorldChoice) -> anyhow::Result<Records> {
    let mut r = Records::default();
    let Some(path) = &plan.record else { return Ok(r) };
    let virtual_clock = matches!(plan.clock, Clock::Virtual { .. });
    let info = recording::session_info(
        plan.rig_source.path(),
        &plan.scene,
        &plan.sim.script,
        &format!("{:?}", plan.device_kind),
        plan.sim.seed,
        virtual_clock,
    )?;
    let rig = recording::create(path, &info)?;
    let start_ns = Some(rig.start_unix_ns());
    r.rig = Some(rig);
    let wpath = spidar_record::world::world_path(path);
    match world {
        WorldChoice::Thread(stepper) => {
            let (rec, obs) =
                recording::start_world_recording(&wpath, &plan.scene, stepper.scene(), virtual_clock, start_ns)?;
            r.world = Some(rec);
            if virtual_clock {
                r.world_observer = Some(obs);
            } else {
                stepper.add_observer(Box::new(obs));
            }
        }
        WorldChoice::Child(spec) => {
            r.child_world_file = Some(wpath.clone());
            spec.extra.extend(["--record".into(), wpath.into_os_string()]);
            if let Some(ns) = start_ns {
                spec.extra.extend(["--record-start-unix-ns".into(), ns.to_string().into()]);
            }
        }
        WorldChoice::Connect { at, .. } => errln!(
            "spidar: the world at {at} is not recorded here; record it where it runs (spidar world --record FILE.mcap)"
        ),
    }
    Ok(r)
}

/// Opens the simulated rig with its script, or the real boards (checked against the rig file).
/// Returns the device and the script's name for the summary.
fn open_device(
    plan: &RunPlan,
    scene_name: &str,
    supervised: Option<&'static Shared>,
) -> anyhow::Result<(Box<dyn Device>, String)> {
    let rig = &plan.rig;
    let Some(choice) = &plan.hardware else {
        let s = &plan.sim;
        let scripts = session::load_scripts(&s.script, rig, s.seed)?;
        let sim_opts = SimOptions {
            seed: s.seed,
            encoder_noise_counts: s.noise_counts,
            slack: s.slack,
            ..Default::default()
        };
        errln!(
            "spidar: rig '{}' on the simulated SPIDAR-H (seed {}), scene {scene_name}, script {}",
            rig.name,
            s.seed,
            s.script
        );
        return Ok((Box::new(session::sim_device(rig, scripts, &sim_opts)?), s.script.clone()));
    };
    let dev = hardware::open_hardware_for(choice, supervised)?;
    let watched = match supervised {
        Some(_) => {
            format!("; supervisor pid {} watches this rig process (pid {})", parent_pid(), std::process::id())
        }
        None => String::new(),
    };
    errln!(
        "spidar: rig '{}' on {} ({}), scene {scene_name}{watched}",
        rig.name,
        dev.info().board,
        dev.info().identity
    );
    hardware::check_rig_against(rig, dev.info())?;
    errln!("hold each grip at its home point: the rig homes as it starts");
    Ok((dev, "none (a person's hands on real boards)".to_string()))
}

/// The session on the virtual clock, the world stepped in this thread; prints the summary.
#[allow(clippy::too_many_arguments)]
fn run_virtual(
    plan: &RunPlan,
    dev: Box<dyn Device>,
    world: WorldChoice,
    records: &mut Records,
    names: Names,
    seconds: f64,
    stop: Stop,
    supervised: Option<&'static Shared>,
) -> anyhow::Result<u8> {
    let world = match world {
        WorldChoice::Thread(stepper) => VirtualWorld::Scene(stepper.into_scene()),
        WorldChoice::Connect { at, scene } => {
            VirtualWorld::Process { at, scene, timeout: plan.world_timeout }
        }
        WorldChoice::Child(_) => bail!("--virtual runs no child world"),
    };
    let options = VirtualOptions {
        seconds,
        stop,
        progress: !plan.quiet,
        device: names.device,
        scene_name: names.scene,
        script_name: names.script,
        supervisor: supervised,
        recorder: records.rig.take(),
        observers: records.world_observer.take().into_iter().map(|o| Box::new(o) as _).collect(),
    };
    let (mut summary, link) = session::run_virtual_with(dev, &plan.rig, world, options)?;
    summary.rig_file = plan.rig_source.describe();
    let world_rec = records.world.take().map(|r| r.finish());
    let mut out = summary.summary(world_rec.as_ref());
    if let Some(l) = &link {
        let counts: serde_json::Map<String, serde_json::Value> =
            l.counts().iter().map(|(k, n)| (k.to_string(), serde_json::Value::from(*n))).collect();
        out.row("link", l.summary(), "link", counts);
    }
    print_summary(plan, &out);
    report::check_outcome(summary.final_state, &summary.counters, &summary.faults_seen)?;
    Ok(0)
}

/// The session on the real clock; prints the summary and what the recordings kept.
#[allow(clippy::too_many_arguments)]
fn run_live(
    plan: &RunPlan,
    dev: Box<dyn Device>,
    world: WorldChoice,
    mut records: Records,
    names: Names,
    seconds: Option<f64>,
    stop: Stop,
    supervised: Option<&'static Shared>,
) -> anyhow::Result<u8> {
    let options = LiveOptions {
        seconds,
        rt: plan.rt.clone(),
        spin_ns: plan.spin_ns,
        status_every: (!plan.quiet).then_some(Duration::from_millis(500)),
        stop,
        scene_name: names.scene,
        script_name: names.script,
        connect_timeout: plan.world_timeout,
        world_priority: plan.world_priority,
        supervisor: supervised,
        recorder: recording::recorder_thread(records.rig.take(), plan.view.foxglove.as_deref())?.0,
    };
    let mut summary = session::run_live(dev, &plan.rig, world, options)?;
    summary.rig_file = plan.rig_source.describe();
    let recording = summary.recording.clone();
    // The scene thread has stopped: the world's recording ends with its last step. A child world
    // process wrote its own: what it kept is read back from its file.
    let world_rec = match (records.world.take(), &records.child_world_file) {
        (Some(r), _) => Some(r.finish()),
        (None, Some(p)) => spidar_record::world::report_of(p)
            .map_err(|e| errln!("spidar: the world's recording {} does not read: {e}", p.display()))
            .ok(),
        (None, None) => None,
    };
    print_summary(plan, &summary.summary(recording.as_ref(), world_rec.as_ref()));
    if summary.counters.misses > 0 {
        errln!(
            "note: {} ticks woke more than 1 ms late (worst {}); see `spidar bench rt` for this machine's floor",
            summary.counters.misses,
            fmt_dur(summary.stats.lateness.percentiles().max_s)
        );
    }
    if !summary.clean_stop {
        bail!("the loop did not stop cleanly");
    }
    report::check_outcome(summary.final_state, &summary.counters, &summary.faults_seen)?;
    Ok(0)
}

/// The summary as text, or as JSON with `--json`.
fn print_summary(plan: &RunPlan, summary: &spidar_rt::summary::Summary) {
    if plan.json {
        outln!("{:#}", summary.json());
    } else {
        outln!("{summary}");
    }
}

fn parent_pid() -> u32 {
    // SAFETY: getppid cannot fail.
    unsafe { libc::getppid() as u32 }
}
