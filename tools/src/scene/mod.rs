//! The scene side of the channel: whatever produces contact models for the rt-loop at the
//! simulation's rate (3 ms) and consumes the hand samples it sends back.
//!
//! The built-in rig-check scene ([`walls`]) is the template the physics simulation follows: it
//! receives every `HandSample` (positions, velocities, and the impulses the rt-loop applied to
//! each proxy), steps, and sends one `ContactModel` stamped with the loop-clock time it is valid at.
//! A scene runs on its own thread on the real clock ([`spawn`]) or interleaved with the loop on
//! the virtual clock (`session::run_virtual`).

pub mod boxing;
pub mod crowd;
pub mod walls;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use spidar_msg::{ContactModel, HandSample};
use spidar_rt::{Clock, MonotonicClock};

pub trait Scene: Send {
    fn name(&self) -> &str;
    /// Time between two steps.
    fn step_s(&self) -> f64;
    /// Advances the scene to loop-clock time `t_s`, given the samples received since the last
    /// step (oldest first), and returns the contact model valid at `t_s`.
    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel;
    /// A short live status for the status line.
    fn status(&self) -> String {
        String::new()
    }
}

/// Counters of a scene thread.
#[derive(Default)]
pub struct SceneCounters {
    pub steps: AtomicU64,
    pub models_dropped: AtomicU64,
    /// Steps that started more than one step period late.
    pub late_steps: AtomicU64,
    /// The scene's own status (`Scene::status`), refreshed every 100 steps for the status line;
    /// the scene thread only `try_lock`s it, so a slow reader never holds a step up.
    pub status: std::sync::Mutex<String>,
}

/// Runs `scene` on its own thread every `step_s` on `clock` (shared epoch with the loop) until
/// `stop` is set. It polls the sample channel (never blocks on it: see `spidar_rt::runner`).
pub fn spawn(
    mut scene: Box<dyn Scene>,
    mut clock: MonotonicClock,
    samples: Receiver<HandSample>,
    models: Sender<ContactModel>,
    stop: Arc<AtomicBool>,
    counters: Arc<SceneCounters>,
) -> std::io::Result<JoinHandle<Box<dyn Scene>>> {
    std::thread::Builder::new().name("spidar-scene".into()).spawn(move || {
        let step_ns = (scene.step_s() * 1e9).round() as u64;
        let mut buf: Vec<HandSample> = Vec::with_capacity(256);
        let mut deadline = clock.now_ns();
        let mut since_status = 100u32;
        while !stop.load(Ordering::Relaxed) {
            let wake = clock.sleep_until(deadline);
            if wake > deadline + step_ns {
                counters.late_steps.fetch_add(1, Ordering::Relaxed);
            }
            buf.clear();
            buf.extend(samples.try_iter());
            let m = scene.step(wake as f64 * 1e-9, &buf);
            if let Err(TrySendError::Full(_)) = models.try_send(m) {
                counters.models_dropped.fetch_add(1, Ordering::Relaxed);
            }
            counters.steps.fetch_add(1, Ordering::Relaxed);
            since_status += 1;
            if since_status >= 100 {
                if let Ok(mut st) = counters.status.try_lock() {
                    *st = scene.status();
                    since_status = 0;
                }
            }
            deadline += step_ns;
            if clock.now_ns() > deadline + 10 * step_ns {
                deadline = clock.now_ns(); // stalled: do not run a burst of catch-up steps
            }
        }
        scene
    })
}

/// Builds a scene by name or RON file path.
pub fn load(name_or_path: &str) -> anyhow::Result<Box<dyn Scene>> {
    match name_or_path {
        "walls" => Ok(Box::new(walls::WallsScene::builtin())),
        "crowd" => Ok(Box::new(crowd::CrowdScene::builtin()?)),
        "boxing" => Ok(Box::new(boxing::BoxingScene::new(Default::default())?)),
        "boxing-passive" => Ok(Box::new(boxing::BoxingScene::new(spidar_sim::boxer::BoxerParams {
            active: false,
            ..Default::default()
        })?)),
        // A boxer file (configs/boxer.ron): the boxing scene with those parameters.
        p if p.ends_with("boxer.ron") => {
            let params = spidar_sim::boxer::load_boxer(std::path::Path::new(p))?;
            Ok(Box::new(boxing::BoxingScene::new(params)?))
        }
        // A crowd scene file (configs/scene-crowd.ron and copies of it).
        p if p.ends_with(".ron") && file_name(p).contains("crowd") => {
            Ok(Box::new(crowd::CrowdScene::load(std::path::Path::new(p))?))
        }
        p if p.ends_with(".ron") => Ok(Box::new(walls::WallsScene::load(std::path::Path::new(p))?)),
        other => anyhow::bail!(
            "unknown scene '{other}': use 'boxing', 'boxing-passive', 'walls', 'crowd', a boxer file (*boxer.ron), a crowd scene file (*crowd*.ron) or a walls scene file (.ron) like configs/scene-walls.ron"
        ),
    }
}

fn file_name(p: &str) -> String {
    std::path::Path::new(p).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default()
}
