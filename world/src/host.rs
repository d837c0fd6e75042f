//! Hosting a scene: what every host of a scene does at each step ([`Stepper`]), and the world
//! process's loop around a socket link ([`serve`]).
//!
//! The [`Stepper`] feeds a scene the rig's samples, puts the model it returns on the rig's clock
//! and calls every [`Observer`] after the step. A scene's own time never jumps back: when a rig
//! connects again (or a new rig, whose clock starts at zero), the scene continues from where it
//! paused, and the stepper shifts times between the rig's clock and the scene's by a fixed
//! offset. The first rig a scene meets has offset zero, so the thread and virtual-clock hosts see
//! exactly the rig's times (bit-identical runs).
//!
//! [`serve`] is the world process: wait for a rig, then step every `step_s` on the world's own
//! clock, draining every sample queued since the last step at its start; the step's time is the
//! rig's clock now, estimated from the newest sample and the kernel's record of when it arrived
//! (`spidar_link::world::rig_time_now`). A rig that leaves or goes silent pauses the scene until
//! a rig connects. With `lockstep` the world instead steps exactly when a virtual-clock rig's
//! samples say a step is due (the same rule as the in-process virtual run), so a run through
//! two processes is bit-identical to one in a single process.

use std::time::{Duration, Instant};

use spidar_link::sock::realtime_ns;
use spidar_link::world::{rig_time_now, Arrived, WorldEvent, WorldLink, WorldStats};
use spidar_msg::wire::PROTOCOL_VERSION;
use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus};

use crate::{Observer, Scene, StepView};

/// A scene, its observers, and the scene's time against the rig's.
pub struct Stepper {
    scene: Box<dyn Scene>,
    observers: Vec<Box<dyn Observer>>,
    /// Scene time = rig time + offset.
    offset_s: f64,
    last_scene_t_s: Option<f64>,
    shifted: Vec<HandSample>,
    steps: u64,
}

impl Stepper {
    pub fn new(scene: Box<dyn Scene>) -> Stepper {
        Stepper {
            scene,
            observers: Vec::new(),
            offset_s: 0.0,
            last_scene_t_s: None,
            shifted: Vec::with_capacity(64),
            steps: 0,
        }
    }

    pub fn add_observer(&mut self, o: Box<dyn Observer>) {
        self.observers.push(o);
    }

    pub fn scene(&self) -> &dyn Scene {
        &*self.scene
    }

    pub fn into_scene(self) -> Box<dyn Scene> {
        self.scene
    }

    pub fn step_s(&self) -> f64 {
        self.scene.step_s()
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// A rig (re)connects and its clock reads `rig_t_s`: the scene continues one step after its
    /// last one (or, for the first rig, at the rig's own time).
    pub fn resume(&mut self, rig_t_s: f64) {
        self.offset_s = match self.last_scene_t_s {
            Some(t) => t + self.scene.step_s() - rig_t_s,
            None => 0.0,
        };
    }

    /// One step at rig time `rig_t_s` with the rig's samples since the last step (rig times);
    /// returns the model stamped on the rig's clock.
    pub fn step(
        &mut self,
        rig_t_s: f64,
        samples: &[HandSample],
        rig_info: Option<&RigInfo>,
        rig_status: Option<&RigStatus>,
    ) -> ContactModel {
        let t_s = rig_t_s + self.offset_s;
        let samples: &[HandSample] = if self.offset_s == 0.0 {
            samples
        } else {
            self.shifted.clear();
            self.shifted.extend(samples.iter().map(|s| HandSample { t_s: s.t_s + self.offset_s, ..*s }));
            &self.shifted
        };
        let model = self.scene.step(t_s, samples);
        self.steps += 1;
        self.last_scene_t_s = Some(t_s);
        for o in self.observers.iter_mut() {
            o.after_step(&StepView {
                t_s,
                scene: &*self.scene,
                samples,
                model: &model,
                rig_info,
                rig_status,
            });
        }
        ContactModel { stamp_s: model.stamp_s - self.offset_s, ..model }
    }
}

/// How the world process steps.
#[derive(Clone, Debug, Default)]
pub struct ServeOptions {
    /// Step when the rig's samples say a step is due (virtual-clock rigs), not on this clock.
    pub lockstep: bool,
}

/// What a world process did.
#[derive(Clone, Debug, Default)]
pub struct ServeReport {
    pub steps: u64,
    /// Steps that started more than one step period late.
    pub late_steps: u64,
    /// Times the scene paused because its rig left or went silent.
    pub pauses: u64,
    pub link: WorldStats,
    /// Longest step (scene and observers), seconds.
    pub max_step_s: f64,
}

impl std::fmt::Display for ServeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l = &self.link;
        write!(
            f,
            "{} steps ({} late, longest {:.2} ms), {} rig connections, paused {} times; samples {} received, {} ticks \
             missing, {} out of order; models {} sent, {} dropped; odd datagrams: {} malformed, {} wrong version, {} foreign, \
             {} unexpected; {} refusals",
            self.steps,
            self.late_steps,
            self.max_step_s * 1e3,
            l.connections,
            self.pauses,
            l.samples,
            l.samples_lost,
            l.samples_out_of_order,
            l.models_sent,
            l.models_dropped,
            l.malformed,
            l.wrong_version,
            l.foreign,
            l.unexpected,
            l.refusals
        )
    }
}

/// What a world says about an event on its link.
pub fn describe(e: &WorldEvent) -> String {
    match e {
        WorldEvent::Connected { rig, session, again: false, .. } => {
            format!("rig connected from {rig} (session {session:016x}): scene running")
        }
        WorldEvent::Connected { rig, again: true, .. } => format!("rig at {rig} connected again: scene running"),
        WorldEvent::Refused { rig, reason } => format!("refused a rig at {rig}: {reason}"),
        WorldEvent::WrongVersion { rig, theirs } => format!(
            "a rig at {rig} speaks link protocol {theirs}, this world speaks {PROTOCOL_VERSION}: refused (run the \
             same spidar version on both sides)"
        ),
        WorldEvent::Left { rig, .. } => format!("rig at {rig} stopped: scene paused, waiting for a rig"),
        WorldEvent::Lost { rig, silent_s, .. } => {
            format!("rig at {rig} lost (silent for {silent_s:.2} s): scene paused, waiting for a rig")
        }
    }
}

/// Runs the world process's loop until `stop()` says so; `say` gets one line per event.
pub fn serve(
    stepper: &mut Stepper,
    link: &mut WorldLink,
    opts: &ServeOptions,
    stop: &dyn Fn() -> bool,
    say: &mut dyn FnMut(&str),
) -> ServeReport {
    let mut rep = ServeReport::default();
    let step = Duration::from_secs_f64(stepper.step_s());
    let step_ns = step.as_nanos() as u64;
    let mut arrived: Vec<Arrived> = Vec::with_capacity(256);
    let mut events = Vec::new();
    let mut samples: Vec<HandSample> = Vec::with_capacity(256);
    // Real time: the next step's deadline and the newest sample's time and arrival.
    let mut deadline: Option<Instant> = None;
    let mut anchor: Option<(f64, i64)> = None;
    // Lockstep: the rig time (ns) at which the next step is due.
    let mut next_due_ns = 0u64;
    let mut resume = true;
    let mut report = |events: &mut Vec<WorldEvent>, rep: &mut ServeReport| {
        for e in events.drain(..) {
            if matches!(e, WorldEvent::Left { .. } | WorldEvent::Lost { .. }) {
                rep.pauses += 1;
            }
            say(&describe(&e));
        }
    };
    while !stop() {
        if link.peer().is_none() {
            // Paused: wait for a rig.
            (deadline, anchor, next_due_ns, resume) = (None, None, 0, true);
            arrived.clear();
            samples.clear();
            link.wait(Duration::from_millis(50));
            link.drain(&mut arrived, &mut events);
            report(&mut events, &mut rep);
            continue;
        }
        if opts.lockstep {
            link.wait(Duration::from_millis(50));
        } else {
            let d = *deadline.get_or_insert_with(Instant::now);
            if let Some(wait) = d.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        link.drain(&mut arrived, &mut events);
        report(&mut events, &mut rep);
        if link.peer().is_none() {
            continue;
        }
        let info = link.peer().map(|p| p.info);
        let status = link.peer().and_then(|p| p.status);
        if opts.lockstep {
            for a in arrived.drain(..) {
                samples.push(a.sample);
                let now_ns = (a.sample.t_s * 1e9).round() as u64;
                if resume {
                    stepper.resume(a.sample.t_s);
                    resume = false;
                }
                if now_ns >= next_due_ns {
                    let t0 = Instant::now();
                    let m = stepper.step(a.sample.t_s, &samples, info.as_ref(), status.as_ref());
                    rep.max_step_s = rep.max_step_s.max(t0.elapsed().as_secs_f64());
                    samples.clear();
                    link.send_model(&m, &mut events);
                    rep.steps += 1;
                    next_due_ns = now_ns + step_ns;
                }
            }
            report(&mut events, &mut rep);
            continue;
        }
        let d = deadline.get_or_insert_with(Instant::now);
        *d += step;
        let late = Instant::now().saturating_duration_since(*d);
        if late > Duration::ZERO {
            rep.late_steps += 1; // started after the next step's deadline
            if late > 10 * step {
                *d = Instant::now(); // stalled: no burst of catch-up steps
            }
        }
        if let Some(a) = arrived.last() {
            anchor = Some((a.sample.t_s, a.arrived_ns));
        }
        let Some((t_s, at_ns)) = anchor else { continue }; // no sample yet: nothing to step against
        let rig_t = rig_time_now(t_s, at_ns, realtime_ns());
        if resume {
            stepper.resume(rig_t);
            resume = false;
        }
        samples.clear();
        samples.extend(arrived.drain(..).map(|a| a.sample));
        let t0 = Instant::now();
        let m = stepper.step(rig_t, &samples, info.as_ref(), status.as_ref());
        rep.max_step_s = rep.max_step_s.max(t0.elapsed().as_secs_f64());
        link.send_model(&m, &mut events);
        report(&mut events, &mut rep);
        rep.steps += 1;
    }
    link.close();
    rep.link = *link.stats();
    rep
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::Ordering;

    type Seen = std::sync::Arc<std::sync::Mutex<Vec<(f64, Vec<f64>)>>>;

    /// A scene that records the times it is given.
    struct Clockwork {
        seen: Seen,
    }
    impl Scene for Clockwork {
        fn name(&self) -> &str {
            "clockwork"
        }
        fn step_s(&self) -> f64 {
            0.003
        }
        fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
            self.seen.lock().unwrap().push((t_s, samples.iter().map(|s| s.t_s).collect()));
            ContactModel { stamp_s: t_s, ..Default::default() }
        }
    }

    struct Count(std::sync::Arc<std::sync::atomic::AtomicU64>);
    impl Observer for Count {
        fn after_step(&mut self, s: &StepView<'_>) {
            assert_eq!(s.model.stamp_s, s.t_s, "observers see the scene's own times");
            self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }

    fn sample(t_s: f64) -> HandSample {
        HandSample { t_s, ..Default::default() }
    }

    /// What an observer of the world process saw.
    #[derive(Default)]
    struct Seen2 {
        steps: u64,
        info: Option<RigInfo>,
        status_ticks: Vec<u64>,
    }
    struct Watch(std::sync::Arc<std::sync::Mutex<Seen2>>);
    impl Observer for Watch {
        fn after_step(&mut self, s: &StepView<'_>) {
            let mut w = self.0.lock().unwrap();
            w.steps += 1;
            w.info = s.rig_info.copied();
            if let Some(st) = s.rig_status {
                w.status_ticks.push(st.tick);
            }
        }
    }

    #[test]
    fn the_world_process_shows_its_observers_every_step_with_the_rigs_geometry_and_status() {
        use spidar_link::rig::{hello, RigLinkOptions, SocketRigLink};
        use spidar_link::world::WorldOffer;
        use spidar_link::{Endpoint, PrivateDir, RigLink};
        let d = PrivateDir::for_process().unwrap();
        let at = Endpoint::unix(&d.join("w.sock"));
        let offer =
            WorldOffer { scene: "clock".into(), step_s: 0.003, rig_lost_after: Duration::from_secs(60) };
        let mut link = WorldLink::bind(&at, offer).unwrap();
        let seen = std::sync::Arc::new(std::sync::Mutex::new(Seen2::default()));
        let mut stepper = Stepper::new(Box::new(Clockwork { seen: Seen::default() }));
        stepper.add_observer(Box::new(Watch(seen.clone())));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let s = stop.clone();
        let world = std::thread::spawn(move || {
            serve(
                &mut stepper,
                &mut link,
                &ServeOptions { lockstep: true },
                &|| s.load(Ordering::Relaxed),
                &mut |_| {},
            )
        });
        let info =
            RigInfo { period_s: 0.001, home_m: [glam::DVec3::X, glam::DVec3::Y], ..Default::default() };
        let mut rig = SocketRigLink::open(
            &at,
            Some(&d.join("rig.sock")),
            hello(3, info, ""),
            RigLinkOptions::default(),
        )
        .unwrap();
        rig.connect(Duration::from_secs(10), 0.0).unwrap();
        let until = std::time::Instant::now() + Duration::from_secs(20);
        for tick in 0..300u64 {
            let t_s = 0.001 * (tick + 1) as f64;
            if tick % 16 == 0 {
                rig.send_status(&RigStatus { tick, t_s, ..Default::default() });
            }
            rig.send_sample(&HandSample { tick, t_s, ..Default::default() });
            // Lockstep: every third sample makes a step; its model comes back before the next.
            while tick % 3 == 0 && rig.poll(t_s).is_none() && std::time::Instant::now() < until {
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        stop.store(true, Ordering::Relaxed);
        let rep = world.join().unwrap();
        let w = seen.lock().unwrap();
        assert_eq!((w.steps, rep.steps), (100, 100));
        assert_eq!(w.info, Some(info), "the rig's geometry from its hello");
        assert!(
            !w.status_ticks.is_empty() && w.status_ticks.windows(2).all(|p| p[0] <= p[1]),
            "{:?}",
            w.status_ticks
        );
        assert_eq!(
            *w.status_ticks.last().unwrap(),
            288,
            "the newest status the rig sent before the last step"
        );
    }

    #[test]
    fn the_first_rig_shares_the_scene_clock_and_a_later_one_continues_it() {
        let seen = Seen::default();
        let mut st = Stepper::new(Box::new(Clockwork { seen: seen.clone() }));
        let n = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        st.add_observer(Box::new(Count(n.clone())));
        st.resume(5.0);
        let m = st.step(5.0, &[sample(4.999)], None, None);
        assert_eq!(m.stamp_s, 5.0, "first rig: scene time is rig time");
        st.step(5.003, &[], None, None);
        // A new rig, its clock at 0.2 s: the scene goes on at 5.006, the model on the rig's clock.
        st.resume(0.2);
        let m = st.step(0.2, &[sample(0.199)], None, None);
        assert!((m.stamp_s - 0.2).abs() < 1e-12, "{}", m.stamp_s);
        let m = st.step(0.203, &[], None, None);
        assert!((m.stamp_s - 0.203).abs() < 1e-12);
        let seen = seen.lock().unwrap();
        let times: Vec<f64> = seen.iter().map(|s| s.0).collect();
        assert!(times.windows(2).all(|w| (w[1] - w[0] - 0.003).abs() < 1e-9), "{times:?}");
        assert!((seen[2].1[0] - 5.005).abs() < 1e-9, "samples shifted with the rig: {:?}", seen[2].1);
        assert_eq!(n.load(std::sync::atomic::Ordering::Relaxed), 4, "observers after every step");
    }
}
