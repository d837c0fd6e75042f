//! `spidar calib screen`: placing the rig's screen in a minute. The live view's page shows
//! numbered targets on the screen (`?place=1`); the person holds the right grip's centre on each
//! in turn, the ball touching the screen, until it is taken; spidar fits the screen's rectangle to
//! where the grip was (`spidar_calib::display`) and writes it into the user's rig file as
//! calibration does.
//!
//! Runs on the calibration session's path (`crate::calibration`): the calibrating rt-loop holds
//! the strings (every string at minimum tension with zero net force, the loop's limits, its rules
//! for late, corrupt and garbled replies, its fault and fade, its switch-off), on boards on its
//! real-time thread under the supervisor; this module only reads its tick records through
//! `spidar_calib::ticks` (a lost board or a stop signal ends the placement, the loop switched off).
//! The calibrating loop is never homed, so placement homes as `spidar run` does, by itself: the
//! grips held still at their home points for [`STILL_S`] give the right hand's lengths at counter
//! zero (`HandGeometry::homed`), and from then on each tick's counts give the grip's place.
//!
//! A target is taken when the grip has stayed within [`STILL_M`] for [`STILL_S`] at least
//! [`APART_M`] from the last one taken: the median of that still stretch is the grip's place.
//!
//! Must never: drive a device itself (outputs are the loop's alone), take a place from a tick the
//! loop did not take (late, bad, jumped or faulted: no sample), or write the rig file itself (the
//! caller writes what [`place_screen`] returns, through `spidar_calib::display`).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{bail, Context};
use glam::DVec3;
use spidar_calib::display::{fit_screen, Placement, TARGETS};
use spidar_calib::model::HandGeometry;
use spidar_calib::ticks::{LoopStats, StopCheck, TickSource, Ticks};
use spidar_device::sim::{Script, Segment};
use spidar_rt::kinematics::Kinematics;
use spidar_rt::Rig;

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

/// The simulated rig's person placing `truth` (rig frame): both grips held still at home while
/// placement homes ([`STILL_S`] and a half), then the right grip's centre reached calmly to each
/// target, the ball touching the screen, and held there 1.8 s (aimed `aim_off_m[k]` beside the target: a
/// person who saw the grip land beside it aims again), the left held at home.
pub fn scripted_person(rig: &Rig, truth: &spidar_rt::display::Display, aim_off_m: [DVec3; 5]) -> [Script; 2] {
    let r = rig.hands[HAND].grip_radius_m;
    let mut segments = Vec::new();
    let home = rig.hands[HAND].home_m;
    let mut from = home;
    // A calm reach, as calibration's simulated user moves (under 1 m/s): the calibrating loop
    // takes a string that steps further than `reply_jump_m` in a tick for a garbled count.
    let reach = |from: DVec3, to: DVec3| Segment::Reach {
        to_m: to.to_array(),
        duration_s: 0.3 + 2.0 * from.distance(to),
    };
    for (k, &(a, b)) in TARGETS.iter().enumerate() {
        let p = target_grip_m(truth, (a, b), r) + aim_off_m[k];
        segments.push(reach(from, p));
        segments.push(Segment::Hold { at_m: p.to_array(), for_s: 1.8 });
        from = p;
    }
    segments.push(reach(from, home));
    [
        Script::hold(rig.hands[1 - HAND].home_m).with_start_hold(1.0),
        Script::from_segments(segments, false).with_start_hold(STILL_S * 1.5),
    ]
}

/// Where a grip's centre is when held on target (a, b) of `d`, the ball touching the screen.
pub fn target_grip_m(d: &spidar_rt::display::Display, (a, b): (f64, f64), grip_radius_m: f64) -> DVec3 {
    d.lower_left_m + d.right * a * d.width_m + d.up * b * d.height_m + d.normal() * grip_radius_m
}

/// The page with the targets: an empty scene (nothing to touch while placing) stepped on a thread
/// of this process, serving the live view. It only shows the targets: the grips are the
/// calibrating loop's, which has no world.
pub struct PlacementView {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    /// The page to open full screen on the rig's screen.
    pub url: String,
}

impl PlacementView {
    /// Serves the view at `addr` for `rig` (its screen and eye, if the rig file has them).
    pub fn start(rig: &Rig, addr: std::net::SocketAddr) -> anyhow::Result<PlacementView> {
        use spidar_world::Scene;
        let empty = spidar_world::walls::WallsScene::from_str(
            "(kind: \"walls-scene\", version: 1, name: \"placing the screen\", step_s: 0.003, planes: [], spheres: [])",
            "the placement's empty scene",
        )?;
        let look = empty.look();
        let name = empty.name().to_string();
        let mut stepper = spidar_world::host::Stepper::new(Box::new(empty));
        let v = spidar_world::view::View::start(
            &name,
            &look,
            &spidar_world::view::ViewOptions { addr, ..Default::default() },
        )?;
        let url = format!("{}/?place=1&camera=eye", v.url());
        stepper.add_observer(Box::new(v));
        let info = spidar_rt::status::rig_info(rig);
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let step = Duration::from_secs_f64(stepper.step_s());
        let handle = std::thread::Builder::new()
            .name("spidar-place-view".into())
            .spawn(move || {
                let start = std::time::Instant::now();
                while !stopped.load(Ordering::Relaxed) {
                    stepper.step(start.elapsed().as_secs_f64(), &[], Some(&info), None);
                    std::thread::sleep(step);
                }
            })
            .context("starting the placement page's thread")?;
        Ok(PlacementView { stop, handle: Some(handle), url })
    }
}

impl Drop for PlacementView {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
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

/// Homing while placing: the right grip's counts held still for [`STILL_S`] (every string within
/// [`STILL_M`] of its median) at its home point.
struct StillCounts {
    window: VecDeque<[f64; 4]>,
    len: usize,
    pushed: u64,
    tolerance_counts: [f64; 4],
}

impl StillCounts {
    fn new(rig: &Rig) -> StillCounts {
        let hr = &rig.hands[HAND];
        let len = (STILL_S / rig.period_s).round().max(1.0) as usize;
        StillCounts {
            window: VecDeque::with_capacity(len + 1),
            len,
            pushed: 0,
            tolerance_counts: std::array::from_fn(|i| STILL_M / hr.metres_per_count[i].abs()),
        }
    }

    /// Takes one tick's counts; the median counts once the last [`STILL_S`] were still.
    fn push(&mut self, counts: [f64; 4]) -> Option<[f64; 4]> {
        self.window.push_back(counts);
        if self.window.len() > self.len {
            self.window.pop_front();
        }
        self.pushed += 1;
        // Judged every 50 ticks once full: the medians sort the window.
        if self.window.len() < self.len || !self.pushed.is_multiple_of(50) {
            return None;
        }
        let median: [f64; 4] = std::array::from_fn(|i| {
            let mut v: Vec<f64> = self.window.iter().map(|c| c[i]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        });
        let still =
            self.window.iter().all(|c| (0..4).all(|i| (c[i] - median[i]).abs() <= self.tolerance_counts[i]));
        still.then_some(median)
    }
}

/// How a placement runs.
#[derive(Clone)]
pub struct PlaceOptions {
    /// Give up when the targets were not all taken within this long of the loop's time.
    pub timeout_s: f64,
    /// The board counts as lost after this long without a good reply.
    pub lost_after_s: f64,
    /// Polled every tick: a stop signal ends the placement (the loop switched off).
    pub stop: Option<StopCheck>,
}

impl Default for PlaceOptions {
    fn default() -> Self {
        PlaceOptions { timeout_s: 600.0, lost_after_s: 2.0, stop: None }
    }
}

/// What a placement found, and what the calibrating loop showed meanwhile.
pub struct Placed<S> {
    pub placement: Placement,
    /// The loop's records as placement read them (ticks, replies left out, faulted ticks).
    pub stats: LoopStats,
    /// The loop, ended (its counters).
    pub source: S,
}

/// Places the screen on `source`, a calibrating loop already running (`crate::calibration`): homes
/// the right grip, takes a place at every target, ends the loop (its switch-off, also after an
/// error or a stop), then fits the screen. `say` gets what to tell the person.
pub fn place_screen<S: TickSource>(
    source: S,
    rig: &Rig,
    opts: &PlaceOptions,
    say: &mut dyn FnMut(String),
) -> anyhow::Result<Placed<S>> {
    let mut ticks = Ticks::new(source, rig, opts.lost_after_s);
    if let Some(stop) = &opts.stop {
        ticks.set_stop(stop.clone());
    }
    let held = hold_targets(&mut ticks, rig, opts.timeout_s, say);
    let off = ticks.switch_off();
    let stats = ticks.stats();
    say(format!("loop: {stats}"));
    let taken = match (held, off) {
        (Ok(t), Ok(())) => t,
        (Ok(_), Err(e)) => return Err(anyhow::Error::new(e).context("switching the outputs off")),
        (Err(e), Ok(())) => return Err(e.context("outputs switched off")),
        (Err(e), Err(o)) => {
            return Err(
                e.context(format!("switching the outputs off failed ({o}): power the amplifiers down"))
            )
        }
    };
    let source = ticks.finish()?;
    let (sep, stereo) =
        rig.display.map_or((spidar_rt::display::DEFAULT_EYE_SEPARATION_M, Default::default()), |d| {
            (d.eye_separation_m, d.stereo)
        });
    let placement = fit_screen(&TARGETS, &taken, rig.hands[HAND].grip_radius_m, rig.eye_m, sep, stereo)?;
    Ok(Placed { placement, stats, source })
}

/// Reads the loop until the grip was held at every target (or `timeout_s` of ticks): the places.
fn hold_targets<S: TickSource>(
    ticks: &mut Ticks<S>,
    rig: &Rig,
    timeout_s: f64,
    say: &mut dyn FnMut(String),
) -> anyhow::Result<Vec<DVec3>> {
    let hr = &rig.hands[HAND];
    let kin = Kinematics::new(hr.anchors_m).context("the right hand's anchors")?;
    let mut home = StillCounts::new(rig);
    let mut geometry: Option<HandGeometry> = None;
    let mut holds = Holds::starting_at(hr.home_m);
    say(format!("hold the right grip still at its home point for {STILL_S} s: placement homes it"));
    let max_ticks = (timeout_s / rig.period_s).ceil() as u64;
    for n in 0..max_ticks {
        // A tick the loop did not take (late, bad, jumped, faulted) gives no sample: left out.
        let Some(counts) = ticks.tick()?.hands[HAND] else { continue };
        let counts = counts.map(|c| c as f64);
        let Some(g) = &geometry else {
            if let Some(median) = home.push(counts) {
                geometry = Some(HandGeometry::homed(hr, &median, hr.home_m));
                say(format!(
                    "homed; hold the right grip's centre on target 1 of {} (the ball touching the screen) until it is taken",
                    TARGETS.len()
                ));
            }
            continue;
        };
        let pose = kin.solve(&g.lengths(&counts), 20);
        if let Some(p) = holds.push(n as f64 * rig.period_s, pose.pos_m, pose.valid) {
            let k = holds.taken.len();
            say(format!("target {k} taken at ({:.3}, {:.3}, {:.3}) m", p.x, p.y, p.z));
            if k == TARGETS.len() {
                return Ok(holds.taken);
            }
            say(format!("now target {}", k + 1));
        }
    }
    match geometry {
        None => bail!(
            "the right grip was never still at its home point for {STILL_S} s within {timeout_s:.0} s: hold it there first"
        ),
        Some(_) => bail!(
            "{} of {} targets taken before the time ran out: hold the grip still on each target for {STILL_S} s",
            holds.taken.len(),
            TARGETS.len()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn homing_waits_for_a_still_second_and_gives_its_median_counts() {
        let rig = Rig::default_rig();
        let mut home = StillCounts::new(&rig);
        let per_tick = 1e-3 / rig.hands[HAND].metres_per_count[0].abs(); // 1 m/s in counts a tick
                                                                         // Moving: never still.
        assert!((0..3000).all(|k| home.push([k as f64 * per_tick, 0.0, 0.0, 0.0]).is_none()));
        // Then still, with one count of noise: homed within a second and a block of 50 ticks.
        let base = 3000.0 * per_tick;
        let got = (0..1100).find_map(|k| home.push([base + (k % 2) as f64, 7.0, -3.0, 0.0]).map(|m| (k, m)));
        let (k, m) = got.expect("homed");
        assert!((999..1050).contains(&k), "homed after {k} ticks");
        assert!((m[0] - base).abs() <= 1.0 && m[1] == 7.0 && m[2] == -3.0, "{m:?}");
    }

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
