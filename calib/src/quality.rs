//! Data quality of a fit: the residuals against the noise measured while the grip was held still,
//! and, when they are well above it, the cause the data show.
//!
//! Why it exists: a fit through bad data looks like any other fit. A string that slipped on its
//! pulley midway, or creeps a little with every pose, gives anchors millimetres off while the
//! Levenberg-Marquardt fit converges happily and, with enough poses, even reports a small
//! uncertainty. What gives it away is the residual: at every pose the recorder measured how much
//! each averaged count scatters while the grip was still, so the fit knows what residual the noise
//! alone explains. A residual well above that is not noise, and its pattern over the recording
//! order names the cause:
//! - a *slip*: one string's residual steps at one pose and stays (the string slipped on its pulley,
//!   so every later count has another zero);
//! - a *creep*: one string's residual drifts with the pose number, from the first pose or from
//!   a later one on (the string stretches or slips a little at each pose, once it started);
//! - an *outlier*: one pose disagrees (the grip moved while it was averaged, a string was briefly
//!   slack, the wrong jig point).
//!
//! How: the residuals and the fit's Jacobian are whitened by the per-pose noise, each free pose's
//! three directions are projected out (a free grip position absorbs any error along them), and so
//! are the geometry's directions (the fit absorbs those too): what is left is the part of the
//! data the model cannot explain, chi-square distributed with `dof` degrees of freedom if the data
//! are only noise. Each candidate cause is a column (a step in string i at pose k, a ramp in string
//! i from pose k on, one reading) projected the same way; the one that explains most of what is left is taken
//! (a linearised likelihood-ratio test), and the search repeats on the rest until the residual
//! is down to the noise or nothing explains enough.
//!
//! What it must never do: call a clean fit bad (with 3 counts of encoder noise the ratio stays
//! near 1), or name a cause the data do not single out (a free pose's four strings share one
//! residual direction, so an outlier there names the pose, not a string).

use nalgebra::{DMatrix, DVector};

/// A cause after the first must explain at least this share of the residual above the noise.
const MIN_SHARE: f64 = 0.01;

/// Thresholds of the data-quality check (the fit options carry one).
#[derive(Clone, Debug, PartialEq)]
pub struct QualityOptions {
    /// The residual is "well above the noise" when its RMS, in units of the noise measured at
    /// rest, exceeds this (clean data give about 1).
    pub max_noise_ratio: f64,
    /// A cause is named only when it explains the residual at least this many standard deviations
    /// better than no cause (a linearised likelihood-ratio test: sqrt of the chi-square drop).
    pub min_sigmas: f64,
    /// Causes looked for at most.
    pub max_causes: usize,
    /// Added in quadrature to the noise of every averaged length: what the model cannot be
    /// expected to explain even on a perfect rig (grip play, string elasticity), metres.
    pub model_floor_m: f64,
}

impl Default for QualityOptions {
    fn default() -> Self {
        QualityOptions { max_noise_ratio: 3.0, min_sigmas: 8.0, max_causes: 3, model_floor_m: 0.0 }
    }
}

impl QualityOptions {
    /// Refuses non-finite or out-of-range thresholds.
    pub fn check(&self) -> Result<(), String> {
        if !(self.max_noise_ratio.is_finite() && self.max_noise_ratio >= 1.0) {
            return Err(format!("max_noise_ratio must be a number >= 1 (got {})", self.max_noise_ratio));
        }
        if !(self.min_sigmas.is_finite() && self.min_sigmas >= 3.0) {
            return Err(format!("min_sigmas must be a number >= 3 (got {})", self.min_sigmas));
        }
        if !(1..=10).contains(&self.max_causes) {
            return Err(format!("max_causes must be 1 .. 10 (got {})", self.max_causes));
        }
        if !(self.model_floor_m.is_finite() && (0.0..=0.01).contains(&self.model_floor_m)) {
            return Err(format!("model_floor_m must be 0 .. 0.01 m (got {})", self.model_floor_m));
        }
        Ok(())
    }
}

/// What the data show. `string` is `None` when the data do not single out one string (a reading
/// of a free pose: its four strings share one residual direction).
#[derive(Clone, Debug, PartialEq)]
pub enum Cause {
    /// From pose `at` on, `string` reads `size_m` longer than before (it slipped on its pulley).
    Slip { string: Option<usize>, at: usize, size_m: f64 },
    /// `string` reads `size_m` longer in poses `from..=to` only (slack for a while, or it slipped
    /// and slipped back).
    Burst { string: Option<usize>, from: usize, to: usize, size_m: f64 },
    /// `string` reads `per_pose_m` longer with every pose from pose `from` on, in recording order.
    Creep { string: Option<usize>, from: usize, per_pose_m: f64 },
    /// Pose `pose` disagrees with the rest by `size_m` (on `string` when the data single it out).
    Outlier { pose: usize, string: Option<usize>, size_m: f64 },
}

/// One cause found, with how strongly the data show it.
#[derive(Clone, Debug, PartialEq)]
pub struct Finding {
    pub cause: Cause,
    /// Size over its standard deviation (sqrt of the chi-square drop it gives).
    pub sigmas: f64,
    /// Share of the residual above the noise that it explains (0 .. 1).
    pub explained: f64,
}

/// The data-quality verdict of one hand's fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Quality {
    /// RMS over poses and strings of the noise of the averaged lengths, measured at rest.
    pub noise_rms_m: f64,
    /// RMS of the residual in units of that noise (sqrt of chi-square per degree of freedom).
    pub ratio: f64,
    /// Degrees of freedom left by the model (readings minus free-pose and geometry unknowns).
    pub dof: usize,
    /// The same ratio once the causes found are taken out.
    pub ratio_after: f64,
    pub findings: Vec<Finding>,
    /// The threshold it was judged with.
    pub max_noise_ratio: f64,
}

impl Quality {
    /// The residual is at the noise level: the model explains the data.
    pub fn clean(&self) -> bool {
        self.ratio <= self.max_noise_ratio
    }

    /// One line per finding, with the pose labels, and what to do about it.
    pub fn describe(&self, hand: usize, labels: &[String]) -> Vec<String> {
        let pose = |k: usize| format!("pose {k} ({})", labels.get(k).map_or("?", String::as_str));
        let which = |s: &Option<usize>| match s {
            Some(s) => format!("string {s}"),
            None => "one string (the data do not single out which)".to_string(),
        };
        let mut lines = Vec::new();
        for f in &self.findings {
            let strength = format!("{:.0} sigma, {:.0} % of the excess", f.sigmas, f.explained * 100.0);
            lines.push(match &f.cause {
                Cause::Slip { string, at, size_m } => format!(
                    "slip: hand {hand} {} reads {:+.2} mm from {} on, compared with the poses before ({strength}): \
                     it slipped on its pulley (or its counter jumped) between {} and {}, so the poses before and \
                     after do not share a counter zero. Check the string's knot and winding, then record hand \
                     {hand} again",
                    which(string),
                    size_m * 1e3,
                    pose(*at),
                    pose(at - 1),
                    pose(*at)
                ),
                Cause::Burst { string, from, to, size_m } => format!(
                    "slack: hand {hand} {} reads {:+.2} mm off in {} to {} only ({strength}): it was slack or \
                     caught for a while. Check its tension and path, then record those {} poses again",
                    which(string),
                    size_m * 1e3,
                    pose(*from),
                    pose(*to),
                    to - from + 1
                ),
                Cause::Creep { string, from, per_pose_m } => format!(
                    "creep: hand {hand} {} reads {:+.3} mm more with every pose {} ({strength}): the string \
                     stretches or slips slowly on its pulley. Tension or replace it, then record hand {hand} again",
                    which(string),
                    per_pose_m * 1e3,
                    if *from == 0 {
                        "in recording order".to_string()
                    } else {
                        format!("from {} on, in recording order", pose(*from))
                    }
                ),
                Cause::Outlier { pose: k, string, size_m } => format!(
                    "outlier: {} disagrees with the other poses by {:.2} mm on {} ({strength}): the grip moved while \
                     it was averaged, a string was briefly slack, or the wrong jig point was used. Record that pose \
                     again",
                    pose(*k),
                    size_m.abs() * 1e3,
                    which(string)
                ),
            });
        }
        lines
    }
}

/// The whitened problem around the fit: every row is one reading divided by its noise, and every
/// column has each free pose's directions projected out already.
pub(crate) struct Design {
    /// Geometry Jacobian.
    pub geometry: DMatrix<f64>,
    /// Residuals (measured minus modelled length).
    pub residual: DVector<f64>,
    /// One column per reading, string by string: column `i * n + k` is string i at pose k.
    pub singles: DMatrix<f64>,
    /// Size (squared) of each reading's column before any projection.
    pub singles_raw: Vec<f64>,
    /// Poses.
    pub n: usize,
    /// Readings minus free-pose unknowns.
    pub rows_dof: usize,
    pub noise_rms_m: f64,
}

/// A candidate cause in one string's readings: off in poses `from..=to`, or growing by the same
/// amount with every pose from pose `from` on (a creep that starts there; 0: from the first).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shape {
    Boxed { from: usize, to: usize },
    Ramp { from: usize },
}

/// Judges the residual against the noise and looks for its causes.
pub(crate) fn analyse(d: Design, opts: &QualityOptions) -> Quality {
    let Design { geometry, mut residual, mut singles, singles_raw, n, rows_dof, noise_rms_m } = d;
    // Orthonormal basis of what the geometry can absorb.
    let svd = geometry.svd(true, false);
    let u = svd.u.expect("requested");
    let smax = svd.singular_values.max();
    let keep: Vec<usize> =
        (0..svd.singular_values.len()).filter(|&q| svd.singular_values[q] > 1e-9 * smax).collect();
    let basis = u.select_columns(&keep);
    residual -= &basis * (basis.transpose() * &residual);
    singles -= &basis * (basis.transpose() * &singles);
    let dof = rows_dof.saturating_sub(keep.len()).max(1);
    let chi2 = residual.norm_squared();
    let ratio = (chi2 / dof as f64).sqrt();
    let mut findings = Vec::new();
    let mut left = chi2;
    while (left / dof.saturating_sub(findings.len()).max(1) as f64).sqrt() > opts.max_noise_ratio
        && findings.len() < opts.max_causes
    {
        let scores = Scores::new(&singles, &singles_raw, &residual, n);
        let Some((string, shape, drop)) = scores.best() else { break };
        // Too weak, or (after the first) a crumb: what the linearisation leaves of a large cause.
        if drop.sqrt() < opts.min_sigmas || (!findings.is_empty() && drop < MIN_SHARE * (chi2 - dof as f64)) {
            break;
        }
        let c = scores.column(string, shape);
        let n2 = c.norm_squared();
        let size = c.dot(&residual) / n2;
        // The string is named when the data prefer it clearly (by the same margin a cause needs)
        // over the same pattern on any other string: never at a free pose's single reading, whose
        // four strings share one residual direction.
        let rival = (0..4).filter(|&j| j != string).map(|j| scores.drop(j, shape)).fold(0.0, f64::max);
        let named = (drop - rival >= opts.min_sigmas * opts.min_sigmas).then_some(string);
        let cause = match shape {
            Shape::Ramp { from } => Cause::Creep { string: named, from, per_pose_m: size },
            Shape::Boxed { from, to } if from == to => {
                Cause::Outlier { pose: from, string: named, size_m: size }
            }
            Shape::Boxed { from, to } if to == n - 1 => Cause::Slip { string: named, at: from, size_m: size },
            Shape::Boxed { from, to } => Cause::Burst { string: named, from, to, size_m: size },
        };
        let excess = (chi2 - dof as f64).max(drop);
        findings.push(Finding { cause, sigmas: drop.sqrt(), explained: (drop / excess).min(1.0) });
        // Take it out of what is left (and out of every other candidate).
        let unit = &c / n2.sqrt();
        residual -= &unit * unit.dot(&residual);
        singles -= &unit * (unit.transpose() * &singles);
        left = residual.norm_squared();
    }
    let ratio_after = (left / dof.saturating_sub(findings.len()).max(1) as f64).sqrt();
    Quality { noise_rms_m, ratio, dof, ratio_after, findings, max_noise_ratio: opts.max_noise_ratio }
}

/// The chi-square drop of every candidate on what is left. A box of readings `from..=to` of one
/// string is a difference of two prefix sums of its reading columns, so its dot products come from
/// the prefix sums' Gram matrix: every box of every string costs one small matrix product. A ramp
/// from pose f is the sum of the steps after it (`sum over k > f of (k - f) reading_k`), built
/// from the prefix sums from the last pose back.
struct Scores {
    n: usize,
    /// Per string: prefix sums of its reading columns (column k: readings 0..k).
    prefix: Vec<DMatrix<f64>>,
    /// Per string: prefix' dot products with the residual, Gram matrix, raw sizes.
    dot_r: Vec<DVector<f64>>,
    gram: Vec<DMatrix<f64>>,
    raw: Vec<Vec<f64>>,
    /// Per string: the ramp columns (column f: the ramp from pose f), their dot products with
    /// the residual, squared sizes, and raw sizes.
    ramps: Vec<DMatrix<f64>>,
    ramp_dot: Vec<Vec<f64>>,
    ramp_n2: Vec<Vec<f64>>,
    ramp_raw: Vec<Vec<f64>>,
}

impl Scores {
    fn new(singles: &DMatrix<f64>, singles_raw: &[f64], r: &DVector<f64>, n: usize) -> Scores {
        let mut s = Scores {
            n,
            prefix: Vec::new(),
            dot_r: Vec::new(),
            gram: Vec::new(),
            raw: Vec::new(),
            ramps: Vec::new(),
            ramp_dot: Vec::new(),
            ramp_n2: Vec::new(),
            ramp_raw: Vec::new(),
        };
        for i in 0..4 {
            let mut p = DMatrix::zeros(singles.nrows(), n + 1);
            let mut rr = vec![0.0; n + 1];
            for k in 0..n {
                let next = p.column(k) + singles.column(i * n + k);
                p.set_column(k + 1, &next);
                rr[k + 1] = rr[k] + singles_raw[i * n + k];
            }
            // ramp(f) = ramp(f + 1) + (readings f+1 .. n-1), ramp(n - 1) = 0.
            let mut q = DMatrix::zeros(singles.nrows(), n);
            let mut q_raw = vec![0.0; n];
            for f in (0..n.saturating_sub(1)).rev() {
                let next = q.column(f + 1) + (p.column(n) - p.column(f + 1));
                q.set_column(f, &next);
                q_raw[f] = (f + 1..n).map(|k| ((k - f) as f64).powi(2) * singles_raw[i * n + k]).sum();
            }
            s.ramp_dot.push((0..n).map(|f| q.column(f).dot(r)).collect());
            s.ramp_n2.push((0..n).map(|f| q.column(f).norm_squared()).collect());
            s.ramp_raw.push(q_raw);
            s.ramps.push(q);
            s.dot_r.push(p.transpose() * r);
            s.gram.push(p.transpose() * &p);
            s.prefix.push(p);
            s.raw.push(rr);
        }
        s
    }

    /// Boxes worth testing: every run of poses except the whole session (a constant, which the
    /// lengths absorb) and runs from pose 0 (the same as the run after them, sign reversed), but
    /// with pose 0 alone (whose complement, poses 1 to the end, is left out instead).
    fn boxes(n: usize) -> impl Iterator<Item = (usize, usize)> {
        (0..n).flat_map(move |from| (from..n).map(move |to| (from, to))).filter(move |&(from, to)| {
            (from > 0 || to == 0) && !(from == 1 && to == n - 1) && !(from == 0 && to == n - 1)
        })
    }

    /// Ramps worth testing: from every pose that leaves at least two poses after it (a ramp from
    /// the last but one is the last pose alone: a box already).
    fn ramp_starts(n: usize) -> std::ops::Range<usize> {
        0..n.saturating_sub(2)
    }

    fn drop(&self, i: usize, shape: Shape) -> f64 {
        let (dot, n2, raw) = match shape {
            Shape::Ramp { from } => (self.ramp_dot[i][from], self.ramp_n2[i][from], self.ramp_raw[i][from]),
            Shape::Boxed { from, to } => {
                let (a, b) = (from, to + 1);
                let g = &self.gram[i];
                (
                    self.dot_r[i][b] - self.dot_r[i][a],
                    g[(b, b)] + g[(a, a)] - 2.0 * g[(a, b)],
                    self.raw[i][b] - self.raw[i][a],
                )
            }
        };
        // A cause the geometry (or a cause already taken) absorbs entirely cannot be seen.
        if n2 <= 1e-9 * raw {
            return 0.0;
        }
        dot * dot / n2
    }

    /// The candidate with the largest drop: (string, shape, drop).
    fn best(&self) -> Option<(usize, Shape, f64)> {
        let mut best: Option<(usize, Shape, f64)> = None;
        for i in 0..4 {
            let shapes = Scores::boxes(self.n)
                .map(|(from, to)| Shape::Boxed { from, to })
                .chain(Scores::ramp_starts(self.n).map(|from| Shape::Ramp { from }));
            for shape in shapes {
                let d = self.drop(i, shape);
                if best.is_none_or(|b| d > b.2) {
                    best = Some((i, shape, d));
                }
            }
        }
        best
    }

    /// The projected column of a candidate.
    fn column(&self, i: usize, shape: Shape) -> DVector<f64> {
        match shape {
            Shape::Ramp { from } => self.ramps[i].column(from).clone_owned(),
            Shape::Boxed { from, to } => self.prefix[i].column(to + 1) - self.prefix[i].column(from),
        }
    }
}
