//! `spidar eval impacts`: the impact-force estimation experiment of seed 002 (section 6.2), with an
//! automated estimator in place of the six human subjects.
//!
//! Protocol: a standing character is hit once by a horizontal force `F` at height `h` above the
//! floor, at the point of its trunk's surface `theta_pos` around its front, pointing into the body
//! turned by `theta_dir` from the inward direction (Fig. 9): `theta_pos`, `theta_dir` in
//! {-45, 0, 45} deg, `h` in {0, 0.5, 1.0} m, `|F|` strong or weak.
//!
//! Two paths ([`ImpactPath`]): by default the hits go the user's way, a simulated hand pushing the
//! character through the simulated rig, the rt-loop and the crowd scene, as `spidar run --scene
//! crowd --virtual` runs them (heights on the trunk: 0.5, 0.8, 1.1 m; strength by how far
//! the hand pushes through); `--path stepper` hits the crowd stepper's character with a force, the
//! paper's protocol to the letter. The estimator sees only the
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
use spidar_rt::Rig;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::scene::builtin_crowd;
use spidar_sim::character::skeleton::SkeletonPose;

use crate::crowd_run::{first_touch, shove_scripts, CrowdRun, Shove, SETTLED_S};

const POS_DEG: [f64; 3] = [-45.0, 0.0, 45.0];
/// Impulses of the two strengths on the crowd stepper (N s), given over `PUSH_S`: a weak hit the
/// character catches by stepping, a strong one its feet cannot catch.
const WEAK_N_S: f64 = 20.0;
const STRONG_N_S: f64 = 80.0;
const PUSH_S: f64 = 0.1;
/// Through the rig, the two strengths are how far the hand pushes past where it first touches the
/// body (m): a push of a few centimetres, or a shove following through like the crowd script's.
const WEAK_DEPTH_M: f64 = 0.04;
const STRONG_DEPTH_M: f64 = 0.30;
/// How long the hand takes to reach the hit's start (s).
const REACH_S: f64 = 0.8;
/// Through the rig, where the character stands: on the rig's centre line, its chest about 0.3 m
/// in front of the rig's origin (world z, m).
const CHARACTER_Z_M: f64 = -0.42;
/// How far from the body's centre line the hit's line passes through the point at `theta_pos`
/// (m): on the stepper the force is applied there, at the trunk's surface; through the rig the
/// hand's line passes through a point inside the trunk, so that every direction of the hit meets
/// the body (the trunk is two capsules 0.13 m thick, 0.21 m to each side), and the push starts
/// where the fist first touches the body on that line.
const SURFACE_M: f64 = 0.2;
const AIM_M: f64 = 0.06;
/// Seconds of motion watched after the hit.
const WATCH_S: f64 = 6.0;

/// Which path the hits take.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
pub enum ImpactPath {
    /// The user's path (`spidar run --scene crowd --virtual`): a simulated hand pushes the
    /// character through the simulated rig, the rt-loop and the crowd scene.
    Rig,
    /// The crowd stepper alone, the character hit by a force on its body (a push anywhere,
    /// heights down to the feet, which the rig's hands cannot reach).
    Stepper,
}

impl ImpactPath {
    /// The three heights `h` of the hit above the floor (m): the paper's on the stepper (0.5 m
    /// apart, the lowest at the feet); through the rig three on the trunk's straight part (0.42 to
    /// 1.08 m; the hands reach down to the frame's lower anchors, 0.1-0.2 m above the floor, but
    /// a hand's push at the feet or through the narrow top of the head glances off): the thighs,
    /// the hips, the shoulders.
    pub fn heights_m(self) -> [f64; 3] {
        match self {
            ImpactPath::Rig => [0.5, 0.8, 1.1],
            ImpactPath::Stepper => [0.0, 0.5, 1.0],
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            ImpactPath::Rig => {
                "the user's path (as `spidar run --scene crowd --virtual`): a simulated hand pushes the crowd scene's \
                 character through the simulated rig, the rt-loop (its proxy contacts) and the crowd scene"
            }
            ImpactPath::Stepper => {
                "the crowd stepper (spidar-sim) alone, the crowd scene's character hit by a force on its body; \
                 no rig, rt-loop or world"
            }
        }
    }
}

/// One impact: the four parameters of Fig. 9.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impact {
    pub pos_deg: f64,
    pub dir_deg: f64,
    pub h_m: f64,
    pub strong: bool,
}

impl Impact {
    pub fn all(path: ImpactPath) -> Vec<Impact> {
        let mut v = Vec::new();
        for &pos_deg in &POS_DEG {
            for &dir_deg in &POS_DEG {
                for h_m in path.heights_m() {
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
    pub path: ImpactPath,
}

impl Default for ImpactOptions {
    fn default() -> Self {
        ImpactOptions { trials: 120, practice_per_combo: 4, seed: 1, k: 5, path: ImpactPath::Rig }
    }
}

/// What the estimator extracts from a watched motion.
#[derive(Clone, Copy, Debug)]
struct Features {
    v: [f64; 9],
    /// A qualitative label of the motion, for counting distinct patterns.
    pattern: (i8, i8, i8, i8),
}

/// What the estimator extracts from the motion as it is drawn, step by step from the hit on: only
/// the body's transform and its keyframe pose, in the frame of the character's heading when hit.
struct Watcher {
    ex: DVec3,
    ez: DVec3,
    r0: DVec3,
    dt_s: f64,
    k: usize,
    lean_early: (f64, f64),
    fell: bool,
    peak_speed: f64,
    pose_travel: f64,
    prev_pose: SkeletonPose,
    turn_early: f64,
    disp_1s: (f64, f64),
    pos_prev: DVec3,
    lying_side: i8,
}

impl Watcher {
    /// Starts watching character 0 of `c` now (the hit's start).
    fn new(c: &Crowd) -> Watcher {
        let b0 = c.body_space(0);
        Watcher {
            ex: b0.heading.e_xc,
            ez: b0.heading.e_zc,
            r0: b0.r_m,
            dt_s: c.world.dt_s,
            k: 0,
            lean_early: (0.0, 0.0),
            fell: false,
            peak_speed: 0.0,
            pose_travel: 0.0,
            prev_pose: c.pose_of(0),
            turn_early: 0.0,
            disp_1s: (0.0, 0.0),
            pos_prev: c.bodies[0].pos_m,
            lying_side: 0,
        }
    }

    fn local(&self, v: DVec3) -> (f64, f64) {
        (v.dot(self.ex), v.dot(self.ez))
    }

    /// After each crowd step: what is drawn, every 10 steps (30 ms).
    fn observe(&mut self, c: &Crowd) {
        let k = self.k;
        self.k += 1;
        if k % 10 != 9 {
            return;
        }
        let t = (k + 1) as f64 * self.dt_s;
        let s = c.bodies[0];
        let up = s.rot * DVec3::Y;
        let speed = (s.pos_m - self.pos_prev).length() / (10.0 * self.dt_s);
        self.pos_prev = s.pos_m;
        self.peak_speed = self.peak_speed.max(speed);
        if up.y < 0.5 && !self.fell {
            self.fell = true;
            let (sx, sz) = self.local(up);
            self.lying_side = if sz.abs() > sx.abs() {
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
            self.lean_early = self.local(up);
            self.turn_early = self.local(s.rot * DVec3::Z).0;
        }
        if (t - 1.0).abs() < 0.016 {
            self.disp_1s = self.local(s.pos_m - self.r0);
        }
        let pose = c.pose_of(0);
        self.pose_travel += pose.max_angle_to(&self.prev_pose, c.set.joints.len());
        self.prev_pose = pose;
    }

    fn features(&self, c: &Crowd) -> Features {
        let s = c.bodies[0];
        let (dx, dz) = self.local(s.pos_m - self.r0);
        let (fx, fz) = self.local(s.rot * DVec3::Z);
        let turn = fx.atan2(fz);
        let dist = (dx * dx + dz * dz).sqrt();
        let travel_dir = (-dx).atan2(-dz); // 0: pushed straight back (a hit on the front)
                                           // Lean in the first 0.25 s against the early travel: positive when the top leads.
        let (ux, uz) = self.disp_1s;
        let ul = (ux * ux + uz * uz).sqrt().max(1e-6);
        let lead = (self.lean_early.0 * ux + self.lean_early.1 * uz) / ul;
        let fell = self.fell;
        let v = [
            travel_dir.sin() * 2.0,
            travel_dir.cos(),
            dist.min(3.0),
            lead * 4.0,
            turn * 2.0,
            self.turn_early * 4.0,
            if fell { 2.0 } else { 0.0 },
            self.peak_speed,
            (self.pose_travel / 20.0).min(3.0),
        ];
        let octant = ((travel_dir.to_degrees() + 202.5).rem_euclid(360.0) / 45.0) as i8;
        let sign = |x: f64, dead: f64| -> i8 {
            if x > dead {
                1
            } else if x < -dead {
                -1
            } else {
                0
            }
        };
        Features {
            v,
            pattern: (
                if fell { self.lying_side } else { 0 },
                if dist > 0.15 { octant } else { -1 },
                sign(turn, 0.1),
                sign(lead, 0.05),
            ),
        }
    }
}

/// Where the hit lands and which way it points, world frame: the point of the trunk's surface
/// (`radius_m` from the centre line) at `theta_pos` around the front of `b0`'s heading, `h` above
/// the floor, and the unit direction into the body turned by `theta_dir`.
fn hit_line(
    imp: &Impact,
    b0: &spidar_sim::character::space::BodySpace,
    floor_y: f64,
    h: f64,
    radius_m: f64,
) -> (DVec3, DVec3) {
    let (ex, ez) = (b0.heading.e_xc, b0.heading.e_zc);
    let ang = imp.pos_deg.to_radians();
    let dir = (imp.pos_deg + imp.dir_deg).to_radians();
    let point = b0.r_m + (ex * ang.sin() + ez * ang.cos()) * radius_m + DVec3::Y * (floor_y + h - b0.r_m.y);
    (point, -(ex * dir.sin() + ez * dir.cos()))
}

/// One hit on the crowd stepper: a force on the body. Returns the features of the motion as drawn
/// and the impulse the character got (N s).
fn hit_by_force(imp: &Impact, rng: &mut Crowd) -> anyhow::Result<(Features, f64)> {
    // Nuisance, drawn from the scoring run's own generator (passed in as a crowd for its splitmix).
    let heading = rng.random() * std::f64::consts::TAU;
    let drift = DVec3::new(rng.random() - 0.5, 0.0, rng.random() - 0.5) * 0.1;
    let strength = (if imp.strong { STRONG_N_S } else { WEAK_N_S }) * (0.85 + 0.3 * rng.random());
    let h = imp.h_m + (rng.random() - 0.5) * 0.1;
    let wait_s = 0.3 + 0.3 * rng.random();

    // One character with the crowd scene's own settings, body and keyframes.
    let mut one = builtin_crowd()?.empty_like();
    one.add(0.0, 0.0, heading, Goal::Walk { velocity_m_per_s: drift });
    let dt_s = one.world.dt_s;
    let steps = |s: f64| (s / dt_s).round() as usize;
    for _ in 0..steps(wait_s) {
        one.step();
    }
    one.chars[0].goal = Goal::Stand;
    let b0 = one.body_space(0);
    let (point, into) = hit_line(imp, &b0, b0.r_m.y - 0.75, h, SURFACE_M);
    let force = into * (strength / PUSH_S);
    let mut w = Watcher::new(&one);
    for k in 0..steps(WATCH_S) {
        if k < steps(PUSH_S) {
            one.add_force_at(0, point, force);
        }
        one.step();
        w.observe(&one);
    }
    Ok((w.features(&one), strength))
}

/// One hit through the user's path, as `spidar run --scene crowd --virtual` runs it: the simulated
/// rig (its strings, encoders and the user's arm following a script), the rt-loop rendering the
/// character's proxies, and the crowd scene (the world) giving the character the hand's contact.
/// One character of the crowd scene stands facing the user in front of the rig; a hand reaches to
/// 6 cm short of the body on the hit's line and pushes along it, past where it first touches by
/// `WEAK_DEPTH_M` (weak) or `STRONG_DEPTH_M` (strong). Returns the features of the motion as drawn
/// (watched from the push's start) and the impulse the character got (N s).
fn hit_by_hand(imp: &Impact, rng: &mut Crowd, rig: &Rig) -> anyhow::Result<(Features, f64)> {
    // Nuisance: the heading (roughly facing the user), the depth of the push, height and timing.
    let heading = (rng.random() - 0.5) * 20f64.to_radians();
    let depth = (if imp.strong { STRONG_DEPTH_M } else { WEAK_DEPTH_M }) * (0.85 + 0.3 * rng.random());
    let h = imp.h_m + (rng.random() - 0.5) * 0.1;
    let wait_s = 0.3 * rng.random();

    let mut one = builtin_crowd()?.empty_like();
    one.add(0.0, CHARACTER_Z_M, heading, Goal::Stand);
    let b0 = one.body_space(0);
    let (point, into) = hit_line(imp, &b0, b0.r_m.y - 0.75, h, AIM_M);
    let touch = first_touch(&one, point - into * 0.5, into)
        .ok_or_else(|| anyhow::anyhow!("the hit's line misses the body ({imp:?})"))?;
    let shove = Shove {
        start_s: SETTLED_S + wait_s,
        reach_s: REACH_S,
        near: rig.rig_to_world.point_to_rig(touch - into * 0.06),
        to: rig.rig_to_world.point_to_rig(touch + into * depth),
        push_s: if imp.strong { 0.5 } else { 0.4 },
    };
    let mut run = CrowdRun::new(rig, one, shove_scripts(rig, Some(&shove)))?;
    let end_s = shove.push_start_s() + WATCH_S;
    let mut w: Option<Watcher> = None;
    loop {
        let t_s = run.step()?;
        if t_s >= end_s {
            break;
        }
        match w.as_mut() {
            Some(w) => w.observe(run.crowd()),
            None if t_s >= shove.push_start_s() => w = Some(Watcher::new(run.crowd())),
            None => {}
        }
    }
    if run.faults() != 0 {
        anyhow::bail!(
            "the rig faulted {} times during a hit ({imp:?}): the evaluation is void",
            run.faults()
        );
    }
    let w = w.ok_or_else(|| anyhow::anyhow!("the hit never started"))?;
    Ok((w.features(run.crowd()), run.scene.impulse_sum_n_s))
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
    /// Scored hits that fell, by strength (weak, strong) and by height (the path's three), each with
    /// how many there were: (fell, of).
    pub falls_by_strength: [(usize, usize); 2],
    pub falls_by_height: [(usize, usize); 3],
    /// The path the hits took, and its three heights (m).
    pub path: ImpactPath,
    pub heights_m: [f64; 3],
    /// The impulse the scored hits gave the character (N s), weak and strong: (mean, least, most).
    pub impulse_n_s: [(f64, f64, f64); 2],
}

/// The paper's Table 1: accuracy, mean, standard deviation for the four parameters.
pub const TABLE_1: [(f64, f64, f64); 4] =
    [(0.73, 0.017, 0.545), (0.78, -0.099, 0.488), (0.54, -0.008, 0.766), (0.88, 0.041, 0.350)];

/// Runs the protocol; `progress` is called after each simulated hit with (done, total).
pub fn eval_impacts(
    o: &ImpactOptions,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<ImpactReport> {
    let combos = Impact::all(o.path);
    let rig = Rig::default_rig();
    let watch = |imp: &Impact, rng: &mut Crowd| match o.path {
        ImpactPath::Rig => hit_by_hand(imp, rng, &rig),
        ImpactPath::Stepper => hit_by_force(imp, rng),
    };
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
            practice.push((watch(imp, &mut practice_rng)?.0, *imp));
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
    let mut falls_by_strength = [(0, 0); 2];
    let mut falls_by_height = [(0, 0); 3];
    let mut impulses: [Vec<f64>; 2] = Default::default();
    let heights = o.path.heights_m();
    for _ in 0..o.trials {
        let pick = (trial_rng.random() * combos.len() as f64) as usize % combos.len();
        let truth = combos[pick];
        let (f, given) = watch(&truth, &mut trial_rng)?;
        impulses[truth.strong as usize].push(given);
        done += 1;
        progress(done, total);
        let fell = f.v[6] > 0.0;
        falls += fell as usize;
        let fs = &mut falls_by_strength[truth.strong as usize];
        *fs = (fs.0 + fell as usize, fs.1 + 1);
        let hk = heights.iter().position(|h| (*h - truth.h_m).abs() < 1e-9).unwrap_or(0);
        falls_by_height[hk] = (falls_by_height[hk].0 + fell as usize, falls_by_height[hk].1 + 1);
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
        errs[2].push((g_h - truth.h_m) / (heights[1] - heights[0]));
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
        falls_by_strength,
        falls_by_height,
        path: o.path,
        heights_m: heights,
        impulse_n_s: impulses.map(|v| {
            let n = v.len().max(1) as f64;
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(0.0, f64::max);
            (v.iter().sum::<f64>() / n, if v.is_empty() { 0.0 } else { lo }, hi)
        }),
    })
}

impl fmt::Display for ImpactReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "impact-force estimation (seed 002, section 6.2): {} scored hits, estimator practised on {} other hits",
            self.trials, self.practice
        )?;
        writeln!(f, "path measured: {}", self.path.describe())?;
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
        writeln!(f, "(mean and std of the signed error in units of each parameter's choice interval: 45 deg, {:.2} m, strong/weak)", self.heights_m[1] - self.heights_m[0])?;
        writeln!(
            f,
            "distinct motion patterns (fall side x travel octant x turn x initial lean): {} (paper: about 30)",
            self.patterns
        )?;
        let [w, s] = self.falls_by_strength;
        let [h0, h1, h2] = self.falls_by_height;
        let [h_0, h_1, h_2] = self.heights_m;
        let [iw, is] = self.impulse_n_s;
        writeln!(
            f,
            "impulse the scored hits gave the character: weak {:.1} N s (range {:.1}-{:.1}), strong {:.1} N s (range {:.1}-{:.1})",
            iw.0, iw.1, iw.2, is.0, is.1, is.2
        )?;
        write!(
            f,
            "scored hits that fell: {} of {} (weak: {} of {}, strong: {} of {}; at h {h_0} m: {} of {}, {h_1} m: {} of {}, {h_2} m: {} of {})",
            self.falls, self.trials, w.0, w.1, s.0, s.1, h0.0, h0.1, h1.0, h1.1, h2.0, h2.1
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
        let o = ImpactOptions { trials: 40, practice_per_combo: 2, seed: 9, k: 5, path: ImpactPath::Stepper };
        let r = eval_impacts(&o, |_, _| {}).unwrap();
        assert!(r.scores[3].accuracy > 0.8, "{r}");
        assert!(r.scores[1].accuracy > 0.6, "{r}");
        assert!(r.patterns > 10, "{r}");
        let again = eval_impacts(&o, |_, _| {}).unwrap();
        assert_eq!(format!("{r}"), format!("{again}"));
    }

    /// Through the user's path (simulated rig, rt-loop, crowd scene): a shove through the chest
    /// topples the character, a push of a few centimetres at the hips does not, and the shove gives
    /// it several times the impulse.
    #[test]
    fn hits_by_hand_through_the_rig_reach_the_character() {
        let rig = Rig::default_rig();
        let mut rng = builtin_crowd().unwrap();
        rng.seed(3);
        let shove = Impact { pos_deg: 0.0, dir_deg: 0.0, h_m: 1.1, strong: true };
        let push = Impact { pos_deg: 45.0, dir_deg: -45.0, h_m: 0.8, strong: false };
        let (fs, is) = hit_by_hand(&shove, &mut rng, &rig).unwrap();
        let (fp, ip) = hit_by_hand(&push, &mut rng, &rig).unwrap();
        assert!(fs.v[6] > 0.0, "the shove ({is:.1} N s) did not topple it: {:?}", fs.v);
        assert!(fp.v[6] == 0.0, "the push ({ip:.1} N s) toppled it: {:?}", fp.v);
        assert!(ip > 1.0 && is > 2.0 * ip, "impulses: push {ip:.1} N s, shove {is:.1} N s");
        // Pushed from the front, it travels away from the user (travel direction near 0).
        assert!(fs.v[1] > 0.7, "{:?}", fs.v);
    }
}
