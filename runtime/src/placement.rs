//! `spidar place`: placing the rig's screen in a minute. The live view's page shows numbered
//! targets on the screen (`?place=1`); the person holds the right grip's centre on each in turn,
//! the ball touching the screen, until it is taken; spidar fits the screen's rectangle to where
//! the rig measured the grip (`spidar_calib::display`) and writes it into the user's rig file as
//! calibration does.
//!
//! A target is taken when the grip has stayed within [`STILL_M`] for [`STILL_S`] at least
//! [`APART_M`] from the last one taken: the median of that still stretch is the grip's place.
//! Runs on `spidar run`'s path: the session's rig loop measures, its telemetry is read here.
//!
//! Must never: take a place from a hand whose pose is not valid, or write the rig file itself
//! (the caller writes what [`place_screen`] returns, through `spidar_calib::display`).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::bail;
use glam::DVec3;
use spidar_calib::display::{fit_screen, Placement, TARGETS};
use spidar_device::sim::{Script, Segment};
use spidar_device::Device;
use spidar_rt::telemetry::TickRecord;
use spidar_rt::Rig;

use crate::session::{LiveOptions, LiveSession, WorldChoice};

/// Still: every sample of the last [`STILL_S`] within this of their median (m).
pub const STILL_M: f64 = 0.003;
pub const STILL_S: f64 = 1.0;
/// A new target is at least this far from the last one taken (m).
pub const APART_M: f64 = 0.10;
/// The hand that places: the right one.
pub const HAND: usize = 1;

/// Finds where a grip was held still, one place per target.
#[derive(Default)]
pub struct Holds {
    window: VecDeque<(f64, DVec3)>,
    pub taken: Vec<DVec3>,
    /// The last place taken, or where the grip starts (its home: not a target).
    last: Option<DVec3>,
}

impl Holds {
    /// Holds of a grip that starts at `home_m` (held there while the rig homes: not a target).
    pub fn starting_at(home_m: DVec3) -> Holds {
        Holds { last: Some(home_m), ..Default::default() }
    }

    /// Takes one tick's grip position (`t_s` loop time); returns a place when one was just taken.
    pub fn push(&mut self, t_s: f64, pos_m: DVec3, valid: bool) -> Option<DVec3> {
        if !valid {
            self.window.clear();
            return None;
        }
        self.window.push_back((t_s, pos_m));
        while self.window.front().is_some_and(|(t, _)| t_s - t > STILL_S) {
            self.window.pop_front();
        }
        let span = self.window.back()?.0 - self.window.front()?.0;
        if span < STILL_S * 0.98 {
            return None;
        }
        let median = |k: usize| {
            let mut v: Vec<f64> = self.window.iter().map(|(_, p)| p[k]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let m = DVec3::new(median(0), median(1), median(2));
        if self.window.iter().any(|(_, p)| p.distance(m) > STILL_M) {
            return None;
        }
        if self.last.is_some_and(|l| l.distance(m) < APART_M) {
            return None;
        }
        self.taken.push(m);
        self.last = Some(m);
        self.window.clear();
        Some(m)
    }
}

/// The simulated rig's person placing `truth` (rig frame): the right grip's centre reached to each
/// target, the ball touching the screen, and held there 1.8 s (aimed `aim_off_m[k]` beside the
/// target: a person who saw the grip land beside it aims again), the left held at home.
pub fn scripted_person(rig: &Rig, truth: &spidar_rt::display::Display, aim_off_m: [DVec3; 5]) -> [Script; 2] {
    let r = rig.hands[HAND].grip_radius_m;
    let mut segments = Vec::new();
    for (k, &(a, b)) in TARGETS.iter().enumerate() {
        let p = target_grip_m(truth, (a, b), r) + aim_off_m[k];
        segments.push(Segment::Reach { to_m: p.to_array(), duration_s: 1.0 });
        segments.push(Segment::Hold { at_m: p.to_array(), for_s: 1.8 });
    }
    segments.push(Segment::Reach { to_m: rig.hands[HAND].home_m.to_array(), duration_s: 1.0 });
    [
        Script::hold(rig.hands[1 - HAND].home_m).with_start_hold(1.0),
        Script::from_segments(segments, false).with_start_hold(1.0),
    ]
}

/// Where a grip's centre is when held on target (a, b) of `d`, the ball touching the screen.
pub fn target_grip_m(d: &spidar_rt::display::Display, (a, b): (f64, f64), grip_radius_m: f64) -> DVec3 {
    d.lower_left_m + d.right * a * d.width_m + d.up * b * d.height_m + d.normal() * grip_radius_m
}

/// A world to show the targets in: an empty scene (nothing to touch while placing) stepped on a
/// thread of this process, with the live view at `view` (None: no view).
pub fn placement_world(view: Option<std::net::SocketAddr>) -> anyhow::Result<(WorldChoice, Option<String>)> {
    use spidar_world::Scene;
    let empty = spidar_world::walls::WallsScene::from_str(
        "(kind: \"walls-scene\", version: 1, name: \"placing the screen\", step_s: 0.003, planes: [], spheres: [])",
        "the placement's empty scene",
    )?;
    let look = empty.look();
    let name = empty.name().to_string();
    let mut stepper = spidar_world::host::Stepper::new(Box::new(empty));
    let mut url = None;
    if let Some(addr) = view {
        let v = spidar_world::view::View::start(
            &name,
            &look,
            &spidar_world::view::ViewOptions { addr, ..Default::default() },
        )?;
        url = Some(format!("{}/?place=1&camera=eye", v.url()));
        stepper.add_observer(Box::new(v));
    }
    Ok((WorldChoice::Thread(stepper), url))
}

/// The session's options while placing: no status line, the rig loop at normal priority unless
/// `rt` says otherwise.
pub fn placement_options(rt: spidar_rt::rt_thread::RtOptions) -> LiveOptions {
    LiveOptions {
        seconds: None,
        rt,
        spin_ns: 0,
        status_every: None,
        stop: crate::signals::Stop::detached(),
        scene_name: "placing the screen".into(),
        script_name: "placing the screen".into(),
        connect_timeout: Duration::from_secs(30),
        world_priority: None,
        supervisor: None,
        recorder: None,
    }
}

/// A screen in front of the user for the simulated rig's person to place when the rig file has
/// none: 1.6 x 1.0 m, 0.9 m ahead of the rig's origin, upright, facing the user.
pub fn demo_screen(rig: &Rig) -> anyhow::Result<spidar_rt::display::Display> {
    use spidar_rt::display::{validate, DisplayFile, ScreenFile};
    let f = DisplayFile {
        screen: ScreenFile::Centre {
            centre_m: [0.0, 0.0, -0.9],
            size_m: [1.6, 1.0],
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
        },
        eye_separation_m: spidar_rt::display::DEFAULT_EYE_SEPARATION_M,
        stereo: Default::default(),
    };
    validate(&f, rig.eye_m).map_err(|r| anyhow::anyhow!("{}: {}", r.field, r.message))
}

/// Runs a session on `dev` until the grip was held at every target (or `timeout`), then fits the
/// screen. `say` gets what to tell the person.
pub fn place_screen<D: Device + 'static>(
    dev: D,
    rig: &Rig,
    world: WorldChoice,
    opts: &LiveOptions,
    timeout: Duration,
    say: &mut dyn FnMut(String),
) -> anyhow::Result<Placement> {
    let mut s = LiveSession::start(dev, rig, world, opts)?;
    let mut holds = Holds::starting_at(rig.hands[HAND].home_m);
    say(format!(
        "hold the right grip's centre on target 1 of {} (the ball touching the screen) until it is taken",
        TARGETS.len()
    ));
    let until = Instant::now() + timeout;
    let mut lines = Vec::new();
    while holds.taken.len() < TARGETS.len() && Instant::now() < until {
        let mut took = Vec::new();
        let alive = s.poll(
            &mut |r: &TickRecord| {
                let h = &r.hands[HAND];
                if let Some(p) = holds.push(r.t_s, h.pos_rig_m, h.valid) {
                    took.push(p);
                }
            },
            &mut |l| lines.push(l),
        );
        for l in lines.drain(..) {
            say(l);
        }
        for p in took {
            let k = holds.taken.len();
            say(format!("target {k} taken at ({:.3}, {:.3}, {:.3}) m", p.x, p.y, p.z));
            if k < TARGETS.len() {
                say(format!("now target {}", k + 1));
            }
        }
        if !alive {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    s.request_stop();
    while s.poll(&mut |_| {}, &mut |_| {}) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let _ = s.finish(0, &mut |_| {});
    if holds.taken.len() < TARGETS.len() {
        bail!(
            "{} of {} targets taken before the time ran out: hold the grip still on each target for {STILL_S} s",
            holds.taken.len(),
            TARGETS.len()
        );
    }
    let (sep, stereo) =
        rig.display.map_or((spidar_rt::display::DEFAULT_EYE_SEPARATION_M, Default::default()), |d| {
            (d.eye_separation_m, d.stereo)
        });
    Ok(fit_screen(&TARGETS, &holds.taken, rig.hands[HAND].grip_radius_m, rig.eye_m, sep, stereo)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_place_is_taken_after_a_still_second_and_not_twice() {
        let mut h = Holds::default();
        let mut taken = Vec::new();
        for k in 0..4000 {
            let t = k as f64 * 0.001;
            // Moving for 0.5 s, still (with 1 mm of noise) for 1.5 s, moving, still elsewhere.
            let p = match t {
                t if t < 0.5 => DVec3::new(t, 0.0, 0.0),
                t if t < 2.0 => DVec3::new(0.5, 0.001 * (k % 2) as f64, 0.0),
                t if t < 2.5 => DVec3::new(0.5 + (t - 2.0), 0.0, 0.0),
                _ => DVec3::new(1.0, 0.0, 0.0),
            };
            if let Some(p) = h.push(t, p, true) {
                taken.push((t, p));
            }
        }
        assert_eq!(taken.len(), 2, "{taken:?}");
        assert!((taken[0].1.x - 0.5).abs() < 1e-9 && taken[0].0 > 1.49 && taken[0].0 < 1.6);
        assert!((taken[1].1.x - 1.0).abs() < 1e-9);
        // An invalid pose takes nothing.
        let mut h = Holds::default();
        assert!((0..3000).all(|k| h.push(k as f64 * 0.001, DVec3::ZERO, false).is_none()));
        // Still at home is not a target.
        let mut h = Holds::starting_at(DVec3::ZERO);
        assert!((0..3000).all(|k| h.push(k as f64 * 0.001, DVec3::ZERO, true).is_none()));
    }
}
