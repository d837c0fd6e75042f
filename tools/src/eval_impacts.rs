//! `spidar eval impacts`: the impact-force estimation experiment of seed 002 (section 6.2), with an
//! automated estimator in place of the six human subjects.
//!
//! Protocol: a standing character is hit once by a horizontal force `F` at height `h` above the
//! floor, at the point of its trunk's surface `theta_pos` around its front, pointing into the body
//! turned by `theta_dir` from the inward direction (Fig. 9): `theta_pos`, `theta_dir` in
//! {-45, 0, 45} deg, `h` in {0, 0.5, 1.0} m, `|F|` strong or weak. The estimator sees only the
//! generated motion (the body's transform and the skeleton pose over time, as drawn, in the frame
//! of the character's heading before the hit) and guesses the four parameters. As in Table 1, the
//! direction is scored as the absolute direction `theta_dir + theta_pos`, distances are normalised by
//! each parameter's choice interval, and accuracy is the share of exact answers.
//!
//! The estimator: features of the motion (travel direction and distance, initial lean against
//! the travel, turn, whether and how it fell, peak speed, how the keyframe pose moved), and a
//! nearest-neighbour vote over a *separate* set of practice hits (other random seeds), the way
//! the subjects knew from experience what pushes look like. Every hit, practice and trial, has
//! random nuisance: the character's heading, a small drift when hit, the exact strength (+-15%),
//! height (+-5 cm) and hit time, so the answer is never a lookup of an identical run.
//!
//! Must never: let the estimator read the force, the controller's state or anything else that is
//! not drawn on the screen.

use std::collections::BTreeSet;
use std::fmt;

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::scene::builtin_crowd;
use spidar_sim::SimError;

const POS_DEG: [f64; 3] = [-45.0, 0.0, 45.0];
const H_M: [f64; 3] = [0.0, 0.5, 1.0];
/// Impulses of the two strengths (N s), given over `PUSH_S`.
const WEAK_N_S: f64 = 30.0;
const STRONG_N_S: f64 = 75.0;
const PUSH_S: f64 = 0.1;
/// Radius of the trunk's surface where the force is applied (m).
const SURFACE_M: f64 = 0.2;
/// Seconds of motion watched after the hit.
const WATCH_S: f64 = 6.0;

/// One impact: the four parameters of Fig. 9.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impact {
    pub pos_deg: f64,
    pub dir_deg: f64,
    pub h_m: f64,
    pub strong: bool,
}

impl Impact {
    pub fn all() -> Vec<Impact> {
        let mut v = Vec::new();
        for &pos_deg in &POS_DEG {
            for &dir_deg in &POS_DEG {
                for &h_m in &H_M {
                    for strong in [false, true] {
                        v.push(Impact { pos_deg, dir_deg, h_m, strong });
                    }
                }
            }
        }
        v
    }
}

#[derive(Clone, Debug)]
pub struct ImpactOptions {
    /// Trials scored (the paper: 6 subjects x 20).
    pub trials: usize,
    /// Practice hits per parameter combination for the estimator.
    pub practice_per_combo: usize,
    pub seed: u64,
    /// Neighbours in the vote.
    pub k: usize,
}

impl Default for ImpactOptions {
    fn default() -> Self {
        ImpactOptions { trials: 120, practice_per_combo: 4, seed: 1, k: 5 }
    }
}

/// What the estimator extracts from a watched motion.
#[derive(Clone, Copy, Debug)]
struct Features {
    v: [f64; 9],
    /// A qualitative label of the motion, for counting distinct patterns.
    pattern: (i8, i8, i8, i8),
}

/// Simulates one hit and returns the features of the motion as drawn.
fn watch(imp: &Impact, rng: &mut Crowd) -> Result<Features, SimError> {
    // Nuisance, drawn from the scoring run's own generator (passed in as a crowd for its splitmix).
    let heading = rng.random() * std::f64::consts::TAU;
    let drift = DVec3::new(rng.random() - 0.5, 0.0, rng.random() - 0.5) * 0.1;
    let strength = (if imp.strong { STRONG_N_S } else { WEAK_N_S }) * (0.85 + 0.3 * rng.random());
    let h = imp.h_m + (rng.random() - 0.5) * 0.1;
    let wait_s = 0.3 + 0.3 * rng.random();

    // One character with the crowd scene's own settings, body and keyframes.
    let c = builtin_crowd()?;
    let mut one = Crowd::new(c.body.clone(), c.world, c.params, c.set.clone());
    one.statics = c.statics.clone();
    one.add(0.0, 0.0, heading, Goal::Walk { velocity_m_per_s: drift });
    let dt_s = one.world.dt_s;
    let steps = |s: f64| (s / dt_s).round() as usize;
    for _ in 0..steps(wait_s) {
        one.step();
    }
    one.chars[0].goal = Goal::Stand;
    // The frame the viewer judges in: the character's heading when hit.
    let b0 = one.body_space(0);
    let (ex, ez) = (b0.heading.e_xc, b0.heading.e_zc);
    let local = |v: DVec3| (v.dot(ex), v.dot(ez));
    let ang = (imp.pos_deg).to_radians();
    let dir = (imp.pos_deg + imp.dir_deg).to_radians();
    let floor_y = b0.r_m.y - 0.75;
    let point = b0.r_m + (ex * ang.sin() + ez * ang.cos()) * SURFACE_M + DVec3::Y * (floor_y + h - b0.r_m.y);
    let force = -(ex * dir.sin() + ez * dir.cos()) * (strength / PUSH_S);
    // What is drawn: body transform and skeleton pose, every 30 ms.
    let mut lean_early = (0.0f64, 0.0f64);
    let (mut fell, mut peak_speed) = (false, 0.0f64);
    let mut pose_travel = 0.0;
    let mut prev_pose = one.poses[0];
    let mut turn_early = 0.0;
    let (mut disp_1s, mut pos_prev) = ((0.0, 0.0), one.bodies[0].pos_m);
    let mut lying_side = 0i8;
    for k in 0..steps(WATCH_S) {
        if k < steps(PUSH_S) {
            one.add_force_at(0, point, force);
        }
        one.step();
        if k % 10 != 9 {
            continue;
        }
        let t = (k + 1) as f64 * one.world.dt_s;
        // Only drawn quantities: the body's transform and its pose.
        let s = one.bodies[0];
        let up = s.rot * DVec3::Y;
        let speed = (s.pos_m - pos_prev).length() / (10.0 * one.world.dt_s);
        pos_prev = s.pos_m;
        peak_speed = peak_speed.max(speed);
        if up.y < 0.5 && !fell {
            fell = true;
            let (sx, sz) = local(up);
            lying_side = if sz.abs() > sx.abs() {
                if sz > 0.0 {
                    1
                } else {
                    2
                }
            } else if sx > 0.0 {
                3
            } else {
                4
            };
        }
        if t <= 0.25 {
            let (lx, lz) = local(up);
            lean_early = (lx, lz);
            let fwd = s.rot * DVec3::Z;
            turn_early = local(fwd).0;
        }
        if (t - 1.0).abs() < 0.016 {
            disp_1s = local(s.pos_m - b0.r_m);
        }
        pose_travel += one.poses[0].max_angle_to(&prev_pose, one.set.joints.len());
        prev_pose = one.poses[0];
    }
    let s = one.bodies[0];
    let (dx, dz) = local(s.pos_m - b0.r_m);
    let fwd = s.rot * DVec3::Z;
    let (fx, fz) = local(fwd);
    let turn = fx.atan2(fz);
    let dist = (dx * dx + dz * dz).sqrt();
    let travel_dir = (-dx).atan2(-dz); // 0: pushed straight back (a hit on the front)
                                       // Lean in the first 0.25 s against the early travel: positive when the top leads.
    let (ux, uz) = disp_1s;
    let ul = (ux * ux + uz * uz).sqrt().max(1e-6);
    let lead = (lean_early.0 * ux + lean_early.1 * uz) / ul;
    let v = [
        travel_dir.sin() * 2.0,
        travel_dir.cos(),
        dist.min(3.0),
        lead * 4.0,
        turn * 2.0,
        turn_early * 4.0,
        if fell { 2.0 } else { 0.0 },
        peak_speed,
        (pose_travel / 20.0).min(3.0),
    ];
    let octant = ((travel_dir.to_degrees() + 202.5).rem_euclid(360.0) / 45.0) as i8;
    let turned = if turn > 0.1 {
        1
    } else if turn < -0.1 {
        -1
    } else {
        0
    };
    let leaned = if lead > 0.05 {
        1
    } else if lead < -0.05 {
        -1
    } else {
        0
    };
    Ok(Features {
        v,
        pattern: (if fell { lying_side } else { 0 }, if dist > 0.15 { octant } else { -1 }, turned, leaned),
    })
}

/// Per-parameter scores.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Score {
    pub accuracy: f64,
    pub mean: f64,
    pub std: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ImpactReport {
    pub trials: usize,
    pub practice: usize,
    /// theta_pos, theta_dir + theta_pos, h, |F|.
    pub scores: [Score; 4],
    pub patterns: usize,
    pub falls: usize,
}

/// The paper's Table 1: accuracy, mean, standard deviation for the four parameters.
pub const TABLE_1: [(f64, f64, f64); 4] =
    [(0.73, 0.017, 0.545), (0.78, -0.099, 0.488), (0.54, -0.008, 0.766), (0.88, 0.041, 0.350)];

/// Runs the protocol; `progress` is called after each simulated hit with (done, total).
pub fn eval_impacts(
    o: &ImpactOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<ImpactReport, SimError> {
    let combos = Impact::all();
    // Two independent generators: practice and trials never share nuisance.
    let mut practice_rng = builtin_crowd()?;
    practice_rng.seed(o.seed.wrapping_mul(2).wrapping_add(1));
    let mut trial_rng = builtin_crowd()?;
    trial_rng.seed(o.seed.wrapping_mul(2).wrapping_add(2));
    let total = combos.len() * o.practice_per_combo + o.trials;
    let mut done = 0;
    let mut practice: Vec<(Features, Impact)> = Vec::new();
    for _ in 0..o.practice_per_combo {
        for imp in &combos {
            practice.push((watch(imp, &mut practice_rng)?, *imp));
            done += 1;
            progress(done, total);
        }
    }
    // Scale each feature by its spread over the practice set.
    let mut scale = [0.0; 9];
    for (f, sc) in scale.iter_mut().enumerate() {
        let m = practice.iter().map(|p| p.0.v[f]).sum::<f64>() / practice.len() as f64;
        let var = practice.iter().map(|p| (p.0.v[f] - m).powi(2)).sum::<f64>() / practice.len() as f64;
        *sc = 1.0 / var.sqrt().max(1e-6);
    }
    let mut errs: [Vec<f64>; 4] = Default::default();
    let mut patterns = BTreeSet::new();
    let mut falls = 0;
    for _ in 0..o.trials {
        let pick = (trial_rng.random() * combos.len() as f64) as usize % combos.len();
        let truth = combos[pick];
        let f = watch(&truth, &mut trial_rng)?;
        done += 1;
        progress(done, total);
        falls += (f.v[6] > 0.0) as usize;
        let mut near: Vec<(f64, &Impact)> = practice
            .iter()
            .map(|(p, imp)| ((0..9).map(|k| ((p.v[k] - f.v[k]) * scale[k]).powi(2)).sum::<f64>(), imp))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let near = &near[..o.k.min(near.len())];
        // Each parameter by its own vote among the neighbours (ties: the nearest's).
        let vote = |get: &dyn Fn(&Impact) -> f64| -> f64 {
            let mut best = (0usize, get(near[0].1));
            for (_, imp) in near {
                let v = get(imp);
                let c = near.iter().filter(|(_, o)| (get(o) - v).abs() < 1e-9).count();
                if c > best.0 {
                    best = (c, v);
                }
            }
            best.1
        };
        let g_pos = vote(&|i| i.pos_deg);
        let g_abs = vote(&|i| i.pos_deg + i.dir_deg);
        let g_h = vote(&|i| i.h_m);
        let g_f = vote(&|i| i.strong as u8 as f64);
        errs[0].push((g_pos - truth.pos_deg) / 45.0);
        errs[1].push((g_abs - (truth.pos_deg + truth.dir_deg)) / 45.0);
        errs[2].push((g_h - truth.h_m) / 0.5);
        errs[3].push(g_f - truth.strong as u8 as f64);
        patterns.insert(f.pattern);
    }
    // Distinct patterns over the practice hits too: every hit the set generated counts.
    for (p, _) in &practice {
        patterns.insert(p.pattern);
    }
    let score = |e: &Vec<f64>| {
        let n = e.len().max(1) as f64;
        let mean = e.iter().sum::<f64>() / n;
        let var = e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        Score { accuracy: e.iter().filter(|x| x.abs() < 1e-9).count() as f64 / n, mean, std: var.sqrt() }
    };
    Ok(ImpactReport {
        trials: o.trials,
        practice: practice.len(),
        scores: [score(&errs[0]), score(&errs[1]), score(&errs[2]), score(&errs[3])],
        patterns: patterns.len(),
        falls,
    })
}

impl fmt::Display for ImpactReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "impact-force estimation (seed 002, section 6.2): {} scored hits, estimator practised on {} other hits",
            self.trials, self.practice
        )?;
        writeln!(f, "{:<22} {:>28}   {:>28}", "", "this run", "paper (Table 1, 6 subjects)")?;
        writeln!(
            f,
            "{:<22} {:>8} {:>9} {:>9}   {:>8} {:>9} {:>9}",
            "parameter", "accuracy", "mean", "std", "accuracy", "mean", "std"
        )?;
        let names = ["theta_pos", "theta_dir + theta_pos", "h", "|F|"];
        for (i, name) in names.iter().enumerate() {
            let s = self.scores[i];
            let (pa, pm, ps) = TABLE_1[i];
            writeln!(
                f,
                "{:<22} {:>8.2} {:>9.3} {:>9.3}   {:>8.2} {:>9.3} {:>9.3}",
                name, s.accuracy, s.mean, s.std, pa, pm, ps
            )?;
        }
        writeln!(f, "(mean and std of the signed error in units of each parameter's choice interval: 45 deg, 0.5 m, strong/weak)")?;
        write!(
            f,
            "distinct motion patterns (fall side x travel octant x turn x initial lean): {} (paper: about 30); scored hits that fell: {}",
            self.patterns, self.falls
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The motion carries the push: guessing from it beats chance by far on the strength
    /// (chance 0.5) and the absolute direction (five choices, chance 0.2), and the same seed gives
    /// the same table.
    #[test]
    fn the_estimator_reads_the_push_from_the_motion() {
        let o = ImpactOptions { trials: 40, practice_per_combo: 2, seed: 9, k: 5 };
        let r = eval_impacts(&o, |_, _| {}).unwrap();
        assert!(r.scores[3].accuracy > 0.8, "{r}");
        assert!(r.scores[1].accuracy > 0.6, "{r}");
        assert!(r.patterns > 10, "{r}");
        let again = eval_impacts(&o, |_, _| {}).unwrap();
        assert_eq!(format!("{r}"), format!("{again}"));
    }
}
