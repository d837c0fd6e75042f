//! `spidar eval`: the boxing paper's evaluations, automated.
//!
//! - The cost of the world step and of the prediction during a bout on the simulated rig (the
//!   paper's Table III), measured per step on the virtual clock: steps without a prediction,
//!   predictions alone, and the whole steps that ran one (what the sim thread's 3 ms must hold).
//! - The reaction experiment of section 4.3 (Table IV): the scripted user jabs each of four
//!   targets of the virtual human many times; an observer that sees only the virtual human's
//!   motion guesses the target. The observer is a leave-one-out nearest-centroid classifier over
//!   the displacements of the virtual human's head, chest, hands and forearms, blind to motions
//!   under 1 cm (what a person watching would miss). The experiment runs the world without the
//!   rig, the avatar's fists colliding in the simulation as in the lab's (see
//!   `BoxerParams::avatar_hands_collide`), and the virtual human's own attacks switched off so
//!   every reaction answers the jab.
//!
//! Must never: be used as a timed test (wall-clock numbers are printed, not asserted).

use std::fmt;

use anyhow::Context;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use spidar_msg::HandSample;
use spidar_rt::{Clock, Rig};
use spidar_sim::boxer::{min_jerk, BoxerParams, BoxingWorld, HandTarget};

use crate::scripts::boxing_scripts;
use crate::session::{sim_device, SimOptions, VirtualRun, HOLD_AT_HOME_S};
use spidar_world::boxing::BoxingScene;
use spidar_world::Scene;

/// Median and 99th percentile of a set of durations (ns), in ms.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Spread {
    pub n: usize,
    pub median_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

impl Spread {
    pub fn of(ns: Vec<u64>) -> Spread {
        if ns.is_empty() {
            return Spread::default();
        }
        let n = ns.len();
        let [median, p99, max] = quantiles(ns).map(|x| x as f64 * 1e-6);
        Spread { n, median_ms: median, p99_ms: p99, max_ms: max }
    }
}

/// Median, 99th percentile and maximum (nearest rank); zeros when empty.
fn quantiles(mut v: Vec<u64>) -> [u64; 3] {
    v.sort_unstable();
    let at = |q: f64| v.get(((v.len().max(1) - 1) as f64 * q).round() as usize).copied().unwrap_or(0);
    [at(0.5), at(0.99), at(1.0)]
}

impl fmt::Display for Spread {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "median {:.3} ms, p99 {:.3} ms, max {:.3} ms ({} samples)",
            self.median_ms, self.p99_ms, self.max_ms, self.n
        )
    }
}

/// What a timed bout measured.
#[derive(serde::Serialize)]
pub struct BoutTiming {
    pub seconds: f64,
    /// World steps without a prediction in them.
    pub step: Spread,
    /// Predictions alone.
    pub prediction: Spread,
    /// World steps with a prediction in them, whole (the sim thread's worst 3 ms).
    pub step_with_prediction: Spread,
    /// Steps each prediction ran (median, p99, max) and the horizon's steps: Table I's stopping
    /// rules end most predictions early, and the longest ones make the tail.
    pub prediction_steps: [u64; 3],
    pub horizon_steps: u64,
    pub misses: u64,
    pub status: String,
}

/// A bout of `seconds` on the simulated rig, virtual clock, the `box` script, active virtual human.
pub fn bout_timing(seconds: f64, seed: u64) -> anyhow::Result<BoutTiming> {
    let rig = Rig::default_rig();
    let params = BoxerParams::default();
    let scripts = boxing_scripts(&rig, &params, seed, (seconds as usize).max(1), None)?.map(|s| {
        let hold = s.start_hold_s.max(HOLD_AT_HOME_S);
        s.with_start_hold(hold)
    });
    let dev = sim_device(&rig, scripts, &SimOptions { seed, ..Default::default() })?;
    let mut v = VirtualRun::new(dev, &rig, None)?;
    v.home_and_activate();
    let mut scene = BoxingScene::new(params)?;
    let mut samples: Vec<HandSample> = Vec::with_capacity(16);
    let (mut steps, mut preds, mut predicting) = (Vec::new(), Vec::new(), Vec::new());
    let mut pred_steps = Vec::new();
    let mut next_ns = 0u64;
    let ticks = (seconds / rig.period_s).round() as u64;
    for _ in 0..ticks {
        v.rt.tick();
        samples.extend(v.far.samples.try_iter());
        let now = v.clock.now_ns();
        if now >= next_ns {
            let before = scene.world.mind.predictions;
            let m = scene.step(now as f64 * 1e-9, &samples);
            let _ = v.far.models.try_send(m);
            samples.clear();
            next_ns = now + (scene.step_s() * 1e9).round() as u64;
            if scene.world.mind.predictions > before {
                preds.push(scene.world.mind.last_predict_ns);
                predicting.push(scene.last_step_ns);
                // The predictor's copy started from the state before this step.
                let w = &scene.world;
                pred_steps.push((w.mind.predictor.state.steps + 1).saturating_sub(w.state.steps));
            } else {
                steps.push(scene.last_step_ns);
            }
        }
    }
    Ok(BoutTiming {
        seconds,
        step: Spread::of(steps),
        prediction: Spread::of(preds),
        step_with_prediction: Spread::of(predicting),
        prediction_steps: quantiles(pred_steps),
        horizon_steps: (scene.world.mind.params.horizon_s / scene.world.dt_s()).ceil() as u64,
        misses: v.counters().misses,
        status: scene.status_text(),
    })
}

/// The four targets of Table IV, as the virtual human's parts.
pub const TARGETS: [&str; 4] = ["left hand", "right hand", "left chest", "right chest"];

/// Seconds of the virtual human's motion the observer sees, and when it samples it.
const WATCH_AT_S: [f64; 5] = [0.15, 0.3, 0.45, 0.6, 0.75];
/// Motions smaller than this are not seen.
const SEEN_M: f64 = 0.01;

/// One jab at `target` and the virtual human's motion it caused (the observer's features).
fn trial(active: bool, target: usize, seed: u64) -> anyhow::Result<(Vec<f64>, BoxingWorld)> {
    let params = BoxerParams { active, seed, avatar_hands_collide: true, ..Default::default() };
    let mut w = BoxingWorld::new(params).context("building the boxing world")?;
    w.mind.params.attack_per_step = 0.0;
    for _ in 0..300 {
        w.begin_step();
        w.step(&[None, None]);
    }
    w.begin_step();
    let vh = w.vh;
    let watched = [vh.head, vh.chest, vh.hand[0], vh.hand[1], vh.forearm[0], vh.forearm[1]];
    let rest: Vec<DVec3> = watched.iter().map(|&b| w.com(b)).collect();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    // The virtual human faces +z: its left is world +x.
    let aim = match target {
        0 => w.com(vh.hand[0]),
        1 => w.com(vh.hand[1]),
        2 => w.com(vh.chest) + DVec3::new(0.08, 0.0, 0.1),
        _ => w.com(vh.chest) + DVec3::new(-0.08, 0.0, 0.1),
    };
    let noise = DVec3::new(rng.random_range(-0.02..0.02), rng.random_range(-0.02..0.02), 0.0);
    let to = aim + noise + DVec3::new(0.0, 0.0, -0.05);
    let hand = rng.random_range(0..2usize);
    let guard = [w.com(w.avatar.hand[0]), w.com(w.avatar.hand[1])];
    let (out_s, back_s) = (rng.random_range(0.2..0.3), 0.35);
    let dt = w.dt_s();
    let mut features = Vec::with_capacity(WATCH_AT_S.len() * watched.len() * 3);
    let mut next = 0;
    let mut k = 0usize;
    while next < WATCH_AT_S.len() {
        let t = k as f64 * dt;
        let (pos, vel) = if t < out_s {
            let tau = t / out_s;
            let rate = spidar_sim::boxer::reach::min_jerk_rate(tau) / out_s;
            (guard[hand] + (to - guard[hand]) * min_jerk(tau), (to - guard[hand]) * rate)
        } else {
            let tau = ((t - out_s) / back_s).min(1.0);
            let rate = spidar_sim::boxer::reach::min_jerk_rate(tau) / back_s;
            (to + (guard[hand] - to) * min_jerk(tau), (guard[hand] - to) * rate)
        };
        let mut targets = [0, 1].map(|h| Some(HandTarget { pos_m: guard[h], vel_m_per_s: DVec3::ZERO }));
        targets[hand] = Some(HandTarget { pos_m: pos, vel_m_per_s: vel });
        w.step(&targets);
        w.begin_step();
        k += 1;
        if (k as f64 * dt) >= WATCH_AT_S[next] {
            for (i, &b) in watched.iter().enumerate() {
                let d = w.com(b) - rest[i];
                let d = if d.length() < SEEN_M { DVec3::ZERO } else { d };
                features.extend_from_slice(&d.to_array());
            }
            next += 1;
        }
    }
    Ok((features, w))
}

/// The experiment's result for one mode.
#[derive(serde::Serialize)]
pub struct Confusion {
    /// counts[target][answer]
    pub counts: [[usize; 4]; 4],
}

impl Confusion {
    pub fn rate(&self, target: usize, answer: usize) -> f64 {
        let n: usize = self.counts[target].iter().sum();
        if n == 0 {
            0.0
        } else {
            self.counts[target][answer] as f64 / n as f64
        }
    }

    pub fn total(&self) -> f64 {
        let n: usize = self.counts.iter().flatten().sum();
        let right: usize = (0..4).map(|i| self.counts[i][i]).sum();
        right as f64 / n.max(1) as f64
    }
}

/// Leave-one-out nearest centroid: each trial is guessed from the others' mean motions.
fn observe(samples: &[(usize, Vec<f64>)]) -> Confusion {
    let mut counts = [[0usize; 4]; 4];
    for (i, (truth, x)) in samples.iter().enumerate() {
        let mut best = (f64::INFINITY, 0);
        for c in 0..4 {
            let others: Vec<&Vec<f64>> = samples
                .iter()
                .enumerate()
                .filter(|(j, (t, _))| *j != i && *t == c)
                .map(|(_, (_, f))| f)
                .collect();
            if others.is_empty() {
                continue;
            }
            let d: f64 = (0..x.len())
                .map(|k| {
                    let mean = others.iter().map(|f| f[k]).sum::<f64>() / others.len() as f64;
                    (x[k] - mean).powi(2)
                })
                .sum();
            if d < best.0 {
                best = (d, c);
            }
        }
        counts[*truth][best.1] += 1;
    }
    Confusion { counts }
}

#[derive(serde::Serialize)]
pub struct Reactions {
    pub trials: usize,
    pub active: Confusion,
    pub passive: Confusion,
    pub prediction: Spread,
    pub avoidances: u64,
    pub blocks: u64,
}

/// Runs the section 4.3 experiment: `trials` jabs per target, active and passive.
pub fn reactions(
    trials: usize,
    seed: u64,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<Reactions> {
    let total = 2 * 4 * trials;
    let mut done = 0;
    let mut preds = Vec::new();
    let (mut avoidances, mut blocks) = (0, 0);
    let mut modes = Vec::new();
    for active in [true, false] {
        let mut samples = Vec::with_capacity(4 * trials);
        for target in 0..4 {
            for n in 0..trials {
                let s = seed.wrapping_mul(1_000_003) ^ ((target * 100_000 + n) as u64);
                let (f, w) = trial(active, target, s)?;
                if active && w.mind.predictions > 0 {
                    preds.push(w.mind.predict_ns_total / w.mind.predictions);
                    avoidances += w.mind.avoidances;
                    blocks += w.mind.blocks;
                }
                samples.push((target, f));
                done += 1;
                progress(done, total);
            }
        }
        modes.push(observe(&samples));
    }
    let passive = modes.pop().unwrap_or(Confusion { counts: [[0; 4]; 4] });
    let active = modes.pop().unwrap_or(Confusion { counts: [[0; 4]; 4] });
    Ok(Reactions { trials, active, passive, prediction: Spread::of(preds), avoidances, blocks })
}

/// Table IV of the paper, for printing next to ours: [active, passive][target][answer].
const PAPER: [[[f64; 4]; 4]; 2] = [
    [[0.88, 0.08, 0.08, 0.0], [0.20, 0.71, 0.0, 0.08], [0.08, 0.0, 0.79, 0.17], [0.0, 0.0, 0.13, 0.88]],
    [[0.63, 0.13, 0.25, 0.0], [0.42, 0.42, 0.08, 0.08], [0.25, 0.42, 0.17, 0.17], [0.13, 0.63, 0.13, 0.13]],
];

impl fmt::Display for Reactions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "reaction experiment: {} jabs per target and mode", self.trials)?;
        for (m, (name, c, paper_total)) in
            [("active", &self.active, 0.80), ("passive", &self.passive, 0.33)].into_iter().enumerate()
        {
            writeln!(f, "\n{name} reactions: observer's answer (ours | paper)")?;
            write!(f, "  {:<12}", "target")?;
            for a in TARGETS {
                write!(f, " {a:>17}")?;
            }
            writeln!(f)?;
            for t in 0..4 {
                write!(f, "  {:<12}", TARGETS[t])?;
                for (a, paper) in PAPER[m][t].iter().enumerate() {
                    write!(f, "      {:.2} | {:.2}", c.rate(t, a), paper)?;
                }
                writeln!(f)?;
            }
            writeln!(f, "  total correct rate {:.2} (paper {paper_total:.2})", c.total())?;
        }
        write!(
            f,
            "\nactive trials: {} avoidances, {} blocks; prediction per trial {}",
            self.avoidances, self.blocks, self.prediction
        )
    }
}
