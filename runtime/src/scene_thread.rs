//! The world as a thread of the rig's process: a scene stepped every `step_s` on the loop's own
//! clock, fed by and feeding the loop's channel link, with the normal scheduler or a SCHED_FIFO
//! priority below the loop's. (`spidar run --world thread`; the default is a world process, see `session`.)

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::TrySendError;
use spidar_link::channel::ChannelWorldEnd;
use spidar_msg::{HandSample, RigInfo};
use spidar_rt::{Clock, MonotonicClock};
use spidar_world::host::Stepper;

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

/// Runs the stepper's scene on its own thread every `step_s` on `clock` (shared epoch with the
/// loop) until `stop` is set, calling its observers after every step. It polls the channels
/// (never blocks on them: see `spidar_link::channel`).
pub fn spawn(
    mut stepper: Stepper,
    mut clock: MonotonicClock,
    world: ChannelWorldEnd,
    rig_info: RigInfo,
    stop: Arc<AtomicBool>,
    counters: Arc<SceneCounters>,
    priority: Option<u8>,
) -> std::io::Result<JoinHandle<Stepper>> {
    std::thread::Builder::new().name("spidar-scene".into()).spawn(move || {
        // Below the rig's loop, whatever thread started this one (threads inherit the policy).
        setup_world_thread(priority);
        let step_ns = (stepper.step_s() * 1e9).round() as u64;
        let mut buf: Vec<HandSample> = Vec::with_capacity(256);
        let mut status = None;
        let mut deadline = clock.now_ns();
        let mut since_status = 100u32;
        while !stop.load(Ordering::Relaxed) {
            let wake = clock.sleep_until(deadline);
            if wake > deadline + step_ns {
                counters.late_steps.fetch_add(1, Ordering::Relaxed);
            }
            buf.clear();
            buf.extend(world.samples.try_iter());
            if let Some(s) = world.newest_status() {
                status = Some(s);
            }
            let m = stepper.step(wake as f64 * 1e-9, &buf, Some(&rig_info), status.as_ref());
            if let Err(TrySendError::Full(_)) = world.models.try_send(m) {
                counters.models_dropped.fetch_add(1, Ordering::Relaxed);
            }
            counters.steps.fetch_add(1, Ordering::Relaxed);
            since_status += 1;
            if since_status >= 100 {
                if let Ok(mut st) = counters.status.try_lock() {
                    *st = stepper.scene().status();
                    since_status = 0;
                }
            }
            deadline += step_ns;
            if clock.now_ns() > deadline + 10 * step_ns {
                deadline = clock.now_ns(); // stalled: do not run a burst of catch-up steps
            }
        }
        stepper
    })
}

/// Sets the calling world thread's scheduling: SCHED_FIFO at `priority`, or the normal scheduler
/// (threads inherit their creator's policy: a world started from the rig's loop must not keep it).
pub fn setup_world_thread(priority: Option<u8>) -> spidar_rt::rt_thread::RtReport {
    match priority {
        Some(p) => spidar_rt::rt_thread::setup_current_thread(&spidar_rt::rt_thread::RtOptions {
            fifo_priority: Some(p),
            lock_memory: false,
            prefault_stack_bytes: 0,
            cpu: None,
        }),
        None => {
            let normal = libc::sched_param { sched_priority: 0 };
            // SAFETY: sets the calling thread's policy; a valid sched_param.
            unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &normal) };
            spidar_rt::rt_thread::RtReport { policy: "SCHED_OTHER (normal)".into(), ..Default::default() }
        }
    }
}
