//! The crowd scene behind the whole haptic stack on the virtual clock, for the evaluations of the
//! keyframe characters (`spidar eval impacts`, `spidar eval poses`): the simulated rig (strings,
//! encoders, the user's arms following scripts), the rt-loop rendering the characters' proxies and
//! the crowd scene giving each character the hands' contacts, the path `spidar run --scene crowd
//! --virtual` takes. The scene is stepped here (as the HIL tests do) so the caller can read its
//! characters after every step.
//!
//! Must never: give a character anything but what the rt-loop rendered.

use glam::DVec3;
use spidar_device::sim::{Script, Segment, SimRig};
use spidar_rt::{Clock as _, Rig};
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::drawn::outside_body;
use spidar_world::crowd::CrowdScene;
use spidar_world::Scene as _;

use spidar_runtime::session::{sim_device, SimOptions, VirtualRun, HOLD_AT_HOME_S};

/// The loop time (s) from which a motion is watched: the rig has homed and its force ramped in.
pub const SETTLED_S: f64 = HOLD_AT_HOME_S + 0.7;

/// One hand's move through a character: from home to `near` (just outside the body) in `reach_s`,
/// starting at loop time `start_s`, then through to `to` in `push_s`, then home in 0.6 s.
#[derive(Clone, Copy, Debug)]
pub struct Shove {
    pub start_s: f64,
    pub reach_s: f64,
    pub near: DVec3,
    pub to: DVec3,
    pub push_s: f64,
}

impl Shove {
    /// The loop time (s) at which the hand starts through the body.
    pub fn push_start_s(&self) -> f64 {
        self.start_s + self.reach_s
    }
}

/// The hands' scripts (rig frame): both hold their grips at home, and the one nearer the shove's
/// start (by `near.x`) makes it.
pub fn shove_scripts(rig: &Rig, shove: Option<&Shove>) -> [Script; 2] {
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    let mut scripts = [Script::hold(home[0]), Script::hold(home[1])];
    if let Some(s) = shove {
        let hand = usize::from(s.near.x >= 0.0);
        let hold = |at: DVec3, for_s: f64| Segment::Hold { at_m: at.to_array(), for_s };
        scripts[hand] = Script::from_segments(
            vec![
                hold(home[hand], (s.start_s - HOLD_AT_HOME_S).max(0.0)),
                Segment::Reach { to_m: s.near.to_array(), duration_s: s.reach_s },
                Segment::Reach { to_m: s.to.to_array(), duration_s: s.push_s },
                Segment::Reach { to_m: home[hand].to_array(), duration_s: 0.6 },
                hold(home[hand], 1e6),
            ],
            false,
        );
    }
    // The user holds the grips at home while the rig homes, as `spidar run` arranges.
    scripts.map(|s| s.with_start_hold(HOLD_AT_HOME_S))
}

/// The crowd scene `crowd` behind the simulated rig and the rt-loop, the hands following `scripts`.
pub struct CrowdRun {
    v: VirtualRun<SimRig>,
    pub scene: CrowdScene,
    last_tick: Option<u64>,
}

impl CrowdRun {
    /// Builds the rig, homes and activates it as `spidar run` does.
    pub fn new(rig: &Rig, crowd: Crowd, scripts: [Script; 2]) -> anyhow::Result<CrowdRun> {
        let dev = sim_device(rig, scripts, &SimOptions::default())?;
        let mut v = VirtualRun::new(dev, rig, None)?;
        v.home_and_activate();
        Ok(CrowdRun { v, scene: CrowdScene::new(crowd, "evaluation"), last_tick: None })
    }

    /// Runs loop ticks until the scene has taken one more step on the newest hand sample and its
    /// contact model has gone back to the loop; returns the loop time of that step (s).
    pub fn step(&mut self) -> anyhow::Result<f64> {
        for _ in 0..1000 {
            self.v.tick();
            let Some(s) = self.v.last_sample else { continue };
            if self.last_tick == Some(s.tick) {
                continue;
            }
            self.last_tick = Some(s.tick);
            let t_s = self.v.clock.now_ns() as f64 * 1e-9;
            let m = self.scene.step(t_s, &[s]);
            let _ = self.v.far.models.try_send(m);
            return Ok(t_s);
        }
        anyhow::bail!("the rt-loop sent the world no hand sample in 1,000 ticks ({} faults)", self.faults())
    }

    /// The crowd as the scene has stepped it.
    pub fn crowd(&self) -> &Crowd {
        &self.scene.crowd
    }

    /// Faults the rt-loop counted (a run with any is not the path a person meets).
    pub fn faults(&self) -> u64 {
        self.v.counters().faults
    }
}

/// Radius of the simulated fist (m).
pub const FIST_M: f64 = 0.04;

/// Where a fist moving from `from` along the unit direction `into` first touches character 0's
/// body (its centre then, world frame), searched over 1.5 m in 2 mm steps; None if it passes by.
pub fn first_touch(c: &Crowd, from: DVec3, into: DVec3) -> Option<DVec3> {
    (0..750).map(|k| from + into * (k as f64 * 0.002)).find(|p| outside_body(&c.body, c, 0, *p) <= FIST_M)
}
