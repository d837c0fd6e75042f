//! The in-process scene thread: a scene stepped every `step_s` on the loop's own clock, fed by
//! and feeding the rt-loop's channels.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus};
use spidar_rt::{Clock, MonotonicClock};
use spidar_world::{Observer, Scene, StepView};

/// What watches the scene thread's steps (the live view), and what it is told of the rig.
#[derive(Default)]
pub struct Observers {
    pub list: Vec<Box<dyn Observer>>,
    pub rig_info: Option<RigInfo>,
    /// The rig's status, fed from the session's telemetry (the newest is kept).
    pub rig_status: Option<Receiver<RigStatus>>,
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
    mut observers: Observers,
) -> std::io::Result<JoinHandle<Box<dyn Scene>>> {
    std::thread::Builder::new().name("spidar-scene".into()).spawn(move || {
        let step_ns = (scene.step_s() * 1e9).round() as u64;
        let mut buf: Vec<HandSample> = Vec::with_capacity(256);
        let mut deadline = clock.now_ns();
        let mut since_status = 100u32;
        let mut rig_status: Option<RigStatus> = None;
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
            if !observers.list.is_empty() {
                if let Some(rx) = &observers.rig_status {
                    rig_status = rx.try_iter().last().or(rig_status);
                }
                let view = StepView {
                    t_s: wake as f64 * 1e-9,
                    scene: &*scene,
                    samples: &buf,
                    model: &m,
                    rig_info: observers.rig_info.as_ref(),
                    rig_status: rig_status.as_ref(),
                };
                for o in observers.list.iter_mut() {
                    o.after_step(&view);
                }
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
