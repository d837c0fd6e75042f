//! The geometry fit of one hand: Levenberg-Marquardt over anchors, lengths and metres per count
//! (and the unknown free poses), made robust by iteratively reweighted least squares with a Huber
//! loss, followed by an observability analysis from the SVD of the Jacobian.
//!
//! Why it exists: everything the rig renders depends on this geometry, and a least-squares fit
//! over many poses is how cable robots get it to sub-millimetre accuracy.
//!
//! What it must never do: return a geometry the data do not determine without saying so. Too few
//! poses, duplicate poses, poses in one plane and strings that disagree with the rest are errors;
//! a Jacobian rank below what the frame choice explains is an error naming the parameters involved;
//! weakly determined parameters are marked and the report says what data would help.
//!
//! # Model
//! For pose k and string i: `|a_i - p_k| = L_i + m_i (c_ki - c_ref_i)`, with `a_i` the anchor,
//! `p_k` the grip position (known on a jig point, unknown otherwise), `c_ki` the averaged counts,
//! `c_ref` the counts of the first (home) pose, `L_i` the string length at that reference and
//! `m_i = m0_i (1 + s_i)` the metres per count (fitted as the relative change `s_i` so every
//! parameter is of order metres). Counts are taken relative to the reference so that `L_i` and
//! `s_i` are not correlated through an arbitrary counter start; the rig file's length at counter
//! zero is `L_i - m_i c_ref_i`.
//!
//! # Gauge freedom
//! String lengths do not change when the anchors and all free poses move together rigidly, and
//! with metres per count fitted they do not change either when everything (anchors, poses,
//! lengths, metres per count) is scaled by one factor. So:
//! - with jig points (at least three not in a line), the jig fixes the frame and the scale: no
//!   gauge freedom is left, and the SVD check below proves it;
//! - with free poses only, 6 (rigid) or 7 (with scale) directions are unobservable. They are fixed
//!   explicitly by "inner constraints" on the anchors, added as heavily weighted residual rows:
//!   the fitted anchors' centroid equals the configured one (3 rows), the fitted anchors are not
//!   rotated against the configured ones (`sum b_i x (a_i - a_cfg_i) = 0` with `b_i` the configured
//!   anchors about their centroid: the least-squares best alignment, 3 rows) and, when metres per
//!   count are fitted, not scaled either (`sum b_i . (a_i - a_cfg_i) = 0`, 1 row). The constraints
//!   touch only the gauge directions, so they do not change the fit to the data; they decide in
//!   which frame it is expressed, and the report says so.

use glam::DVec3;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};
use spidar_rt::rig::HandRig;

use crate::model::HandGeometry;
use crate::quality::{self, Quality, QualityOptions};
use crate::session::{PoseKind, PoseRecord, SessionFile};
use crate::CalibError;

/// Weight of the gauge rows against data rows (whose Jacobian entries are of order 1).
const GAUGE_WEIGHT: f64 = 1e4;
/// Singular values below this fraction of the largest count as zero (exact null directions come
/// out near 1e-15; the weakest real direction of a usable data set is far above 1e-9).
const NULL_TOL: f64 = 1e-9;
/// Smallest residual scale assumed (0.1 um): keeps weights finite on exact synthetic data.
const SIGMA_FLOOR_M: f64 = 1e-7;
/// Condition number above which the data are called degenerate even without an exact null space.
const MAX_CONDITION: f64 = 1e8;

/// Fit settings.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// Fit metres per count (4 more unknowns); otherwise keep the configured values.
    pub fit_metres_per_count: bool,
    /// Huber threshold in robust standard deviations.
    pub huber_k: f64,
    /// A residual beyond this many robust standard deviations (and beyond `outlier_floor_m`) is an outlier.
    pub outlier_sigmas: f64,
    pub outlier_floor_m: f64,
    /// A string with outliers in at least this fraction of poses (and at least `slack_min_poses`)
    /// is slack or slipping: an error, not something to fit through.
    pub slack_fraction: f64,
    pub slack_min_poses: usize,
    /// Two poses closer than this in string length (RMS over the four strings) are duplicates: error.
    pub duplicate_m: f64,
    /// Poses whose smallest spread about their best plane is below this are planar: error.
    pub min_depth_spread_m: f64,
    /// An anchor or length whose standard deviation exceeds this is marked weak (1 mm: the accuracy
    /// `spidar calib verify` asks for).
    pub weak_std_m: f64,
    /// How well the grip sits on a jig point (standard deviation per axis): the jig's machining,
    /// play, and how far the holding tension pushes the grip (on the simulated rig's stiffly held
    /// grip: about 5 um). Part of the reported uncertainty: the anchors, metres away, are fixed
    /// through a jig a few decimetres wide, so this is amplified about a hundredfold.
    pub jig_tolerance_m: f64,
    /// The residual against the noise measured at rest, and the causes looked for when it is above.
    pub quality: QualityOptions,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            fit_metres_per_count: true,
            huber_k: 1.345,
            outlier_sigmas: 6.0,
            outlier_floor_m: 0.3e-3,
            slack_fraction: 0.08,
            slack_min_poses: 4,
            duplicate_m: 2e-3,
            min_depth_spread_m: 0.03,
            weak_std_m: 1.0e-3,
            jig_tolerance_m: 0.005e-3,
            quality: QualityOptions::default(),
        }
    }
}

impl FitOptions {
    /// Refuses non-finite and out-of-range settings, naming the setting and its range.
    pub fn check(&self) -> Result<(), CalibError> {
        let range = |name: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(CalibError::Options(format!("fit option {name} must be {lo} .. {hi} (got {v})")))
            }
        };
        range("huber_k", self.huber_k, 0.1, 100.0)?;
        range("outlier_sigmas", self.outlier_sigmas, 1.0, 1000.0)?;
        range("outlier_floor_m", self.outlier_floor_m, 0.0, 0.1)?;
        range("slack_fraction", self.slack_fraction, 0.0, 1.0)?;
        range("duplicate_m", self.duplicate_m, 0.0, 0.5)?;
        range("min_depth_spread_m", self.min_depth_spread_m, 0.0, 1.0)?;
        range("weak_std_m", self.weak_std_m, 1e-9, 1.0)?;
        range("jig_tolerance_m", self.jig_tolerance_m, 0.0, 0.01)?;
        if self.slack_min_poses == 0 {
            return Err(CalibError::Options("fit option slack_min_poses must be at least 1".into()));
        }
        self.quality.check().map_err(|m| CalibError::Options(format!("data quality: {m}")))
    }
}

/// One pose as the fit sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    pub label: String,
    pub counts: [f64; 4],
    /// A jig point: the position is known.
    pub known_m: Option<DVec3>,
    /// Roughly where it was (the home point): seeds the lengths when there is no jig point.
    pub hint_m: Option<DVec3>,
    /// Standard deviation of each averaged count from the noise measured while the grip was still
    /// (counts; quantisation included).
    pub noise_counts: [f64; 4],
}

/// Standard deviation of the average of a pose's counts: the scatter measured while the grip was
/// held still over the number of samples, plus what quantisation leaves when that scatter is too
/// small to dither the counter (a steady count is off by up to one count: 1/sqrt(12)).
pub fn averaged_noise_counts(p: &PoseRecord) -> [f64; 4] {
    let n = f64::from(p.samples.max(1));
    p.counts_std.map(|s| {
        let q = (1.0 - 2.0 * s).max(0.0);
        (s * s / n + q * q / 12.0).sqrt()
    })
}

/// The observations of one hand in a session, in recording order.
pub fn observations(session: &SessionFile, hand: usize) -> Vec<Observation> {
    let mut free = 0;
    session
        .poses_of(hand)
        .map(|p| {
            let noise_counts = averaged_noise_counts(p);
            match &p.kind {
                PoseKind::Home { at_m } => Observation {
                    label: "home".into(),
                    counts: p.counts,
                    known_m: None,
                    hint_m: Some(DVec3::from_array(*at_m)),
                    noise_counts,
                },
                PoseKind::Jig { label, at_m } => Observation {
                    label: format!("jig {label}"),
                    counts: p.counts,
                    known_m: Some(DVec3::from_array(*at_m)),
                    hint_m: None,
                    noise_counts,
                },
                PoseKind::Free => {
                    free += 1;
                    Observation {
                        label: format!("free {free}"),
                        counts: p.counts,
                        known_m: None,
                        hint_m: None,
                        noise_counts,
                    }
                }
            }
        })
        .collect()
}

/// How well the data determine a parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Observability {
    /// Determined by the data to within the weak threshold.
    Observed,
    /// Determined, but its standard deviation exceeds the threshold: more data would help.
    Weak,
    /// Not determined by the data; its value follows from the frame choice (gauge constraints).
    Gauge,
}

#[derive(Clone, Debug)]
pub struct ParamReport {
    pub name: String,
    pub value: f64,
    pub configured: f64,
    pub std: f64,
    pub unit: &'static str,
    pub status: Observability,
}

/// Result of fitting one hand.
#[derive(Clone, Debug)]
pub struct HandFit {
    pub hand: usize,
    pub configured: HandGeometry,
    pub geometry: HandGeometry,
    pub anchor_std_m: [DVec3; 4],
    pub params: Vec<ParamReport>,
    pub labels: Vec<String>,
    /// Fitted (free) or known (jig) grip positions.
    pub poses_m: Vec<DVec3>,
    /// Per pose and string: measured minus modelled length, metres.
    pub residuals_m: Vec<[f64; 4]>,
    /// Final robust weights (1 = full weight).
    pub weights: Vec<[f64; 4]>,
    pub rms_m: f64,
    pub robust_sigma_m: f64,
    /// (pose, RMS over its strings).
    pub worst_pose: (usize, f64),
    /// (pose, string, residual) beyond the outlier limit.
    pub outliers: Vec<(usize, usize, f64)>,
    pub n_jig: usize,
    pub n_free: usize,
    pub n_params: usize,
    pub rank: usize,
    /// Directions fixed by the gauge constraints (0, 6 or 7) and what they are.
    pub gauge_dof: usize,
    pub gauge_note: Option<String>,
    /// Largest over smallest non-null singular value of the (scaled) Jacobian.
    pub condition: f64,
    pub advice: Vec<String>,
    /// The residual against the noise measured at rest, and what the data show when it is above.
    pub quality: Quality,
    pub lm_evaluations: usize,
    pub irls_rounds: usize,
}

/// The geometry unknowns (the LM's parameters): 12 anchor coordinates, 4 lengths at the
/// reference pose, 4 relative metres-per-count changes. Free poses are not LM parameters: they are
/// solved per pose inside each evaluation (variable projection, see [`Problem`]).
struct Layout {
    fit_mpc: bool,
    /// Which observations are free poses (unknown position).
    free: Vec<bool>,
    /// Geometry parameters.
    n: usize,
}

impl Layout {
    const L: usize = 12;
    const S: usize = 16;
    fn new(obs: &[Observation], fit_mpc: bool) -> Layout {
        Layout {
            fit_mpc,
            free: obs.iter().map(|o| o.known_m.is_none()).collect(),
            n: if fit_mpc { 20 } else { 16 },
        }
    }
    fn n_free(&self) -> usize {
        self.free.iter().filter(|f| **f).count()
    }
    /// All unknowns, the free poses' coordinates included.
    fn n_all(&self) -> usize {
        self.n + 3 * self.n_free()
    }
}

struct Gauge {
    a_cfg: [DVec3; 4],
    b: [DVec3; 4],
    r: f64,
    scale: bool,
}

impl Gauge {
    /// The frame of free poses alone: the configured anchors' centroid, orientation and (with
    /// metres per count fitted) scale.
    fn configured(hr: &HandRig, scale: bool) -> Gauge {
        let cen = hr.anchors_m.iter().copied().sum::<DVec3>() / 4.0;
        let b = hr.anchors_m.map(|a| a - cen);
        let r = (b.iter().map(|v| v.length_squared()).sum::<f64>() / 4.0).sqrt();
        Gauge { a_cfg: hr.anchors_m, b, r, scale }
    }
    fn rows(&self) -> usize {
        if self.scale {
            7
        } else {
            6
        }
    }
}

/// Variable projection: for given geometry every free pose is the least-squares point of its
/// four (weighted) lengths, solved by Gauss-Newton in `set_params`; the LM sees residuals as a
/// function of the geometry alone, and a Jacobian with each pose's directions projected out
/// (Kaufman's form: `(I - J_p J_p^+) J_g` per pose). Same optimum as fitting everything jointly,
/// at the cost of a 20-parameter problem instead of one with 3 more per pose.
struct Problem<'a> {
    obs: &'a [Observation],
    /// Counts relative to the reference pose.
    dc: Vec<[f64; 4]>,
    mpc0: [f64; 4],
    sqrt_w: Vec<[f64; 4]>,
    layout: &'a Layout,
    gauge: Option<&'a Gauge>,
    x: DVector<f64>,
    /// Current pose of every observation (jig: the known point; free: solved for `x`).
    poses: Vec<DVec3>,
}

impl Problem<'_> {
    fn anchor(&self, i: usize) -> DVec3 {
        DVec3::new(self.x[3 * i], self.x[3 * i + 1], self.x[3 * i + 2])
    }
    fn mpc(&self, i: usize) -> f64 {
        if self.layout.fit_mpc {
            self.mpc0[i] * (1.0 + self.x[Layout::S + i])
        } else {
            self.mpc0[i]
        }
    }
    fn pose(&self, k: usize) -> DVec3 {
        self.poses[k]
    }
    fn m(&self) -> usize {
        4 * self.obs.len() + self.gauge.map_or(0, Gauge::rows)
    }
    /// Solves every free pose for the current geometry, from its previous value.
    fn solve_poses(&mut self) {
        let anchors: [DVec3; 4] = std::array::from_fn(|i| self.anchor(i));
        let mpc: [f64; 4] = std::array::from_fn(|i| self.mpc(i));
        for k in 0..self.obs.len() {
            if !self.layout.free[k] {
                continue;
            }
            let l: [f64; 4] = std::array::from_fn(|i| self.x[Layout::L + i] + mpc[i] * self.dc[k][i]);
            let w = self.sqrt_w[k].map(|v| v * v);
            let mut p = self.poses[k];
            for _ in 0..30 {
                let mut jtj = glam::DMat3::ZERO;
                let mut jtr = DVec3::ZERO;
                for i in 0..4 {
                    let d = anchors[i] - p;
                    let dist = d.length().max(1e-9);
                    let u = d / dist;
                    // r = l - |a - p|, dr/dp = u
                    jtj += glam::DMat3::from_cols(u * u.x, u * u.y, u * u.z) * w[i];
                    jtr += u * (w[i] * (l[i] - dist));
                }
                let step = -(jtj.inverse() * jtr);
                if !step.is_finite() {
                    break;
                }
                p += step;
                if step.length() < 1e-13 {
                    break;
                }
            }
            self.poses[k] = p;
        }
    }
    /// Unweighted residuals: measured minus modelled length.
    fn raw_residuals(&self) -> Vec<[f64; 4]> {
        (0..self.obs.len())
            .map(|k| {
                let p = self.pose(k);
                std::array::from_fn(|i| {
                    (self.x[Layout::L + i] + self.mpc(i) * self.dc[k][i]) - self.anchor(i).distance(p)
                })
            })
            .collect()
    }
    /// Jacobian of the weighted data rows with respect to the geometry, each free pose's
    /// directions projected out (no gauge rows).
    fn data_jacobian(&self) -> DMatrix<f64> {
        let mut j = self.geometry_columns(&self.sqrt_w);
        self.project_poses(&mut j, &self.sqrt_w);
        j
    }
    /// Jacobian of the data rows (each row times `sqrt_w`) with respect to the geometry, before
    /// the free poses are projected out.
    fn geometry_columns(&self, sqrt_w: &[[f64; 4]]) -> DMatrix<f64> {
        let n = self.layout.n;
        let mut j = DMatrix::zeros(4 * self.obs.len(), n);
        for (k, wk) in sqrt_w.iter().enumerate() {
            let p = self.pose(k);
            for (i, &w) in wk.iter().enumerate() {
                let row = 4 * k + i;
                let d = self.anchor(i) - p;
                let u = d / d.length().max(1e-9);
                // r = L + m dc - |a - p|
                for c in 0..3 {
                    j[(row, 3 * i + c)] = -w * u[c];
                }
                j[(row, Layout::L + i)] = w;
                if self.layout.fit_mpc {
                    j[(row, Layout::S + i)] = w * self.mpc0[i] * self.dc[k][i];
                }
            }
        }
        j
    }
    /// Projects every free pose's directions out of the columns of `j` (rows weighted by
    /// `sqrt_w`): `J -= J_p (J_p^T J_p)^-1 J_p^T J` over each free pose's 4 rows. What is left of a
    /// column is what no re-solved grip position can absorb.
    fn project_poses(&self, j: &mut DMatrix<f64>, sqrt_w: &[[f64; 4]]) {
        for k in 0..self.obs.len() {
            if !self.layout.free[k] {
                continue;
            }
            let p = self.pose(k);
            let jp: [DVec3; 4] = std::array::from_fn(|i| {
                let d = self.anchor(i) - p;
                d / d.length().max(1e-9) * sqrt_w[k][i]
            });
            let jtj = jp
                .iter()
                .fold(glam::DMat3::ZERO, |m, u| m + glam::DMat3::from_cols(*u * u.x, *u * u.y, *u * u.z));
            let inv = jtj.inverse();
            for col in 0..j.ncols() {
                let jtg = (0..4).fold(DVec3::ZERO, |acc, i| acc + jp[i] * j[(4 * k + i, col)]);
                let c = inv * jtg;
                for i in 0..4 {
                    j[(4 * k + i, col)] -= jp[i].dot(c);
                }
            }
        }
    }
    fn gauge_residuals(&self, g: &Gauge) -> Vec<f64> {
        let d: [DVec3; 4] = std::array::from_fn(|i| self.anchor(i) - g.a_cfg[i]);
        let t = d.iter().copied().sum::<DVec3>() / 4.0;
        let rot = (0..4).map(|i| g.b[i].cross(d[i])).sum::<DVec3>() / (4.0 * g.r);
        let mut v = vec![t.x, t.y, t.z, rot.x, rot.y, rot.z];
        if g.scale {
            v.push((0..4).map(|i| g.b[i].dot(d[i])).sum::<f64>() / (4.0 * g.r));
        }
        v.iter_mut().for_each(|x| *x *= GAUGE_WEIGHT);
        v
    }
    fn gauge_jacobian(&self, g: &Gauge) -> DMatrix<f64> {
        let mut j = DMatrix::zeros(g.rows(), self.layout.n);
        for i in 0..4 {
            let b = g.b[i] / (4.0 * g.r);
            for c in 0..3 {
                j[(c, 3 * i + c)] = 0.25;
            }
            // d(b x d)/dd = [b]x
            let bx = [[0.0, -b.z, b.y], [b.z, 0.0, -b.x], [-b.y, b.x, 0.0]];
            for (r, row) in bx.iter().enumerate() {
                for c in 0..3 {
                    j[(3 + r, 3 * i + c)] = row[c];
                }
            }
            if g.scale {
                for c in 0..3 {
                    j[(6, 3 * i + c)] = b[c];
                }
            }
        }
        j * GAUGE_WEIGHT
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
        self.solve_poses();
    }
    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        let mut r = DVector::zeros(self.m());
        for (k, rk) in self.raw_residuals().iter().enumerate() {
            for i in 0..4 {
                r[4 * k + i] = self.sqrt_w[k][i] * rk[i];
            }
        }
        if let Some(g) = self.gauge {
            for (q, v) in self.gauge_residuals(g).into_iter().enumerate() {
                r[4 * self.obs.len() + q] = v;
            }
        }
        r.iter().all(|v| v.is_finite()).then_some(r)
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let jd = self.data_jacobian();
        let j = match self.gauge {
            Some(g) => {
                let mut j = DMatrix::zeros(self.m(), self.layout.n);
                j.rows_mut(0, jd.nrows()).copy_from(&jd);
                j.rows_mut(jd.nrows(), g.rows()).copy_from(&self.gauge_jacobian(g));
                j
            }
            None => jd,
        };
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

fn param_name(col: usize) -> String {
    const XYZ: [&str; 3] = ["x", "y", "z"];
    if col < 12 {
        format!("anchor[{}].{}", col / 3, XYZ[col % 3])
    } else if col < 16 {
        format!("length[{}]", col - 12)
    } else {
        format!("metres_per_count[{}]", col - 16)
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The residuals of the fit against the noise measured at rest (see [`crate::quality`]).
fn judge_quality(problem: &Problem<'_>, residuals: &[[f64; 4]], opts: &FitOptions) -> Quality {
    let obs = problem.obs;
    let n = obs.len();
    let noise_m: Vec<[f64; 4]> = obs
        .iter()
        .map(|o| {
            std::array::from_fn(|i| {
                (o.noise_counts[i] * problem.mpc0[i].abs())
                    .hypot(opts.quality.model_floor_m)
                    .max(SIGMA_FLOOR_M)
            })
        })
        .collect();
    let whiten: Vec<[f64; 4]> = noise_m.iter().map(|s| s.map(|v| 1.0 / v)).collect();
    let p = problem.layout.n;
    let mut geometry = problem.geometry_columns(&whiten);
    if let Some(g) = problem.gauge {
        // Only the directions the frame choice leaves free. (Along the scale direction the
        // residual's own derivative is the residual: scaling everything scales it. Leaving that
        // direction in would explain any residual away.)
        let jg = problem.gauge_jacobian(g);
        if let Some(inv) = (&jg * jg.transpose()).try_inverse() {
            geometry = &geometry * (DMatrix::identity(p, p) - jg.transpose() * inv * &jg);
        }
    }
    // Geometry, residual and one column per reading side by side, so the free poses are
    // projected out of all of them at once (every cause the quality check tests is a sum of
    // reading columns).
    let (c_res, c_single) = (p, p + 1);
    let mut m = DMatrix::zeros(4 * n, c_single + 4 * n);
    m.columns_mut(0, p).copy_from(&geometry);
    let mut singles_raw = vec![0.0; 4 * n];
    for k in 0..n {
        for i in 0..4 {
            let (row, w) = (4 * k + i, whiten[k][i]);
            m[(row, c_res)] = residuals[k][i] * w;
            m[(row, c_single + i * n + k)] = w;
            singles_raw[i * n + k] = w * w;
        }
    }
    problem.project_poses(&mut m, &whiten);
    let noise_rms_m = (noise_m.iter().flatten().map(|v| v * v).sum::<f64>() / (4 * n) as f64).sqrt();
    quality::analyse(
        quality::Design {
            geometry: m.columns(0, p).into_owned(),
            residual: m.column(c_res).into_owned(),
            singles: m.columns(c_single, 4 * n).into_owned(),
            singles_raw,
            n,
            rows_dof: 4 * n - 3 * problem.layout.n_free(),
            noise_rms_m,
        },
        &opts.quality,
    )
}

/// Fits one hand's geometry to its observations. `hr` gives the configured geometry (start values
/// and, for free poses only, the frame).
///
/// The phases, each a function below, in order: the observations checked (finite, enough of
/// them, no duplicates) -> start values (lengths from a jig point or the home pose) -> the poses'
/// spread checked (not in one plane) -> Levenberg-Marquardt inside Huber reweighting -> data
/// quality and outliers (a string that disagrees in many poses is an error) -> observability (a
/// rank deficiency is an error naming the parameters) -> covariance -> the report's parameters,
/// frame note and advice.
pub fn fit_hand(
    hand: usize,
    hr: &HandRig,
    obs: &[Observation],
    opts: &FitOptions,
) -> Result<HandFit, CalibError> {
    opts.check()?;
    if hand > 1 {
        return Err(CalibError::Options(format!("hand {hand}: must be 0 (left) or 1 (right)")));
    }
    let size = check_observations(hand, hr, obs, opts)?;
    let start = start_values(hand, hr, obs)?;
    check_spread(hand, obs, &start.positions_m, opts)?;
    let fit_mpc = opts.fit_metres_per_count;
    let layout = Layout::new(obs, fit_mpc);
    let gauge = (size.n_jig == 0).then(|| Gauge::configured(hr, fit_mpc));
    let labels: Vec<String> = obs.iter().map(|o| o.label.clone()).collect();
    let solved = solve(hand, hr, obs, &start, &layout, gauge.as_ref(), opts)?;
    let problem = &solved.problem;

    let residuals = problem.raw_residuals();
    let quality = judge_quality(problem, &residuals, opts);
    let weights: Vec<[f64; 4]> = problem.sqrt_w.iter().map(|w| w.map(|v| v * v)).collect();
    let all: Vec<f64> = residuals.iter().flatten().copied().collect();
    let rms_m = (all.iter().map(|v| v * v).sum::<f64>() / all.len() as f64).sqrt();
    let (outliers, limit) = find_outliers(&residuals, solved.sigma, opts);
    // (Unless the data-quality check found what it is: then its verdict names it more precisely.)
    if quality.findings.is_empty() {
        check_strings(hand, obs.len(), &outliers, limit, opts)?;
    }
    let worst_pose = residuals
        .iter()
        .enumerate()
        .map(|(k, r)| (k, (r.iter().map(|v| v * v).sum::<f64>() / 4.0).sqrt()))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();

    let seen = observability(hand, problem, &layout, gauge.as_ref(), &size)?;
    let cov = covariance(hand, problem, &seen.jd, gauge.as_ref(), &size, &residuals, &weights, opts)?;
    let std = |col: usize| cov[(col, col)].max(0.0).sqrt();

    let mpc: [f64; 4] = std::array::from_fn(|i| problem.mpc(i));
    let geometry = HandGeometry {
        anchors_m: std::array::from_fn(|i| problem.anchor(i)),
        length_at_zero_m: std::array::from_fn(|i| problem.x[Layout::L + i] - mpc[i] * start.c_ref[i]),
        metres_per_count: mpc,
    };
    let configured = start.geometry;
    let params = param_reports(hr, problem, &geometry, &cov, start.c_ref, size.gauge_dof, opts);
    let anchor_std_m = std::array::from_fn(|i| DVec3::new(std(3 * i), std(3 * i + 1), std(3 * i + 2)));
    let poses_m: Vec<DVec3> = (0..obs.len()).map(|k| problem.pose(k)).collect();
    let gauge_note = (size.gauge_dof > 0).then(|| gauge_note(fit_mpc));
    let advice = advice(&params, &seen, &size, &outliers, &labels, &quality, fit_mpc);

    Ok(HandFit {
        hand,
        configured,
        geometry,
        anchor_std_m,
        params,
        labels,
        poses_m,
        residuals_m: residuals,
        weights,
        rms_m,
        robust_sigma_m: solved.sigma,
        worst_pose,
        outliers,
        n_jig: size.n_jig,
        n_free: size.n_free,
        n_params: layout.n_all(),
        rank: seen.rank,
        gauge_dof: size.gauge_dof,
        gauge_note,
        condition: seen.condition,
        advice,
        quality,
        lm_evaluations: solved.evaluations,
        irls_rounds: solved.rounds,
    })
}

/// How many poses of each kind, and what the frame choice fixes.
struct Size {
    n_jig: usize,
    n_free: usize,
    /// Directions fixed by the gauge constraints: 0 with jig points, else 6 (7 with the scale).
    gauge_dof: usize,
    /// Equations (4 per pose).
    m: usize,
}

/// The first phase: every number finite, at least 8 equations beyond the unknowns (so the noise
/// and outliers can be seen), and no two poses the same point.
fn check_observations(
    hand: usize,
    hr: &HandRig,
    obs: &[Observation],
    opts: &FitOptions,
) -> Result<Size, CalibError> {
    let degenerate = |message: String| CalibError::Degenerate { hand, message };
    if let Some(k) = obs.iter().position(|o| {
        !(o.counts.iter().all(|c| c.is_finite())
            && o.noise_counts.iter().all(|c| c.is_finite() && *c >= 0.0)
            && o.known_m.is_none_or(|p| p.is_finite()))
    }) {
        return Err(degenerate(format!(
            "pose {k} ({}) holds a number that is not finite: record it again",
            obs[k].label
        )));
    }
    if obs.is_empty() {
        return Err(degenerate("no poses recorded for this hand: run `spidar calib record` for it".into()));
    }
    let mpc0 = hr.metres_per_count;
    let n_jig = obs.iter().filter(|o| o.known_m.is_some()).count();
    let n_free = obs.len() - n_jig;
    let fit_mpc = opts.fit_metres_per_count;
    let gauge_dof = if n_jig == 0 { 6 + usize::from(fit_mpc) } else { 0 };
    let n_params = 16 + if fit_mpc { 4 } else { 0 } + 3 * n_free;
    let m = 4 * obs.len();
    let needed = n_params - gauge_dof + 8;
    if m < needed {
        let short = needed - m;
        return Err(degenerate(format!(
            "too few poses: {} ({n_jig} jig, {n_free} free) give {m} equations for {} unknowns{}; each free pose \
             adds 1 equation net and each jig point 4: record at least {short} more free poses or {} more jig points",
            obs.len(),
            n_params - gauge_dof,
            if gauge_dof > 0 { format!(" (after the {gauge_dof} fixed by the frame choice)") } else { String::new() },
            short.div_ceil(4)
        )));
    }
    // Duplicates: the same four lengths twice.
    for a in 0..obs.len() {
        for b in (a + 1)..obs.len() {
            let d2: f64 = (0..4).map(|i| ((obs[a].counts[i] - obs[b].counts[i]) * mpc0[i]).powi(2)).sum();
            let d = (d2 / 4.0).sqrt();
            if d < opts.duplicate_m {
                return Err(degenerate(format!(
                    "poses {a} ({}) and {b} ({}) are the same point (string lengths within {:.2} mm RMS): the second \
                     adds no information; remove one from the session or record a different point",
                    obs[a].label,
                    obs[b].label,
                    d * 1e3
                )));
            }
        }
    }
    Ok(Size { n_jig, n_free, gauge_dof, m })
}

/// Where the fit starts.
struct Start {
    /// Counts of the reference (first) pose, and every pose's counts relative to them.
    c_ref: [f64; 4],
    dc: Vec<[f64; 4]>,
    /// String lengths at the reference pose.
    l_ref: [f64; 4],
    /// The configured geometry with those lengths.
    geometry: HandGeometry,
    /// Every pose's position: the jig point, or solved with the start geometry.
    positions_m: Vec<DVec3>,
}

/// Start values: configured anchors and metres per count, lengths from a jig point, else the
/// home hint, else the rig's own lengths at zero.
fn start_values(hand: usize, hr: &HandRig, obs: &[Observation]) -> Result<Start, CalibError> {
    let degenerate = |message: String| CalibError::Degenerate { hand, message };
    let mpc0 = hr.metres_per_count;
    let c_ref = obs[0].counts;
    let dc: Vec<[f64; 4]> = obs.iter().map(|o| std::array::from_fn(|i| o.counts[i] - c_ref[i])).collect();
    let l_ref: [f64; 4] = if let Some((k, p)) =
        obs.iter().enumerate().find_map(|(k, o)| o.known_m.map(|p| (k, p)))
    {
        std::array::from_fn(|i| (hr.anchors_m[i] - p).length() - mpc0[i] * dc[k][i])
    } else if let Some(p) = obs[0].hint_m {
        std::array::from_fn(|i| (hr.anchors_m[i] - p).length())
    } else if let Some(z) = hr.length_at_zero_m {
        std::array::from_fn(|i| z[i] + mpc0[i] * c_ref[i])
    } else {
        return Err(degenerate(
            "nothing fixes the string lengths to start from: no jig point, no home pose, and the rig is not homed; \
             record the home pose first (spidar calib record does) or home the rig"
                .into(),
        ));
    };
    let geometry = HandGeometry {
        anchors_m: hr.anchors_m,
        length_at_zero_m: std::array::from_fn(|i| l_ref[i] - mpc0[i] * c_ref[i]),
        metres_per_count: mpc0,
    };
    let positions_m: Vec<DVec3> = obs
        .iter()
        .map(|o| match o.known_m {
            Some(p) => Ok(p),
            None => geometry.position(&o.counts).map(|(p, _)| p).ok_or_else(|| {
                degenerate(format!("pose {} gives invalid lengths with the configured geometry", o.label))
            }),
        })
        .collect::<Result<_, _>>()?;
    Ok(Start { c_ref, dc, l_ref, geometry, positions_m })
}

/// All poses in one plane (or a line): the anchors' distances from it are not determined.
fn check_spread(
    hand: usize,
    obs: &[Observation],
    positions_m: &[DVec3],
    opts: &FitOptions,
) -> Result<(), CalibError> {
    let n = positions_m.len() as f64;
    let c = positions_m.iter().copied().sum::<DVec3>() / n;
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for p in positions_m {
        let d = nalgebra::Vector3::new(p.x - c.x, p.y - c.y, p.z - c.z);
        cov += d * d.transpose() / n;
    }
    let eig = cov.symmetric_eigen();
    let (imin, lmin) =
        eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).map(|(i, v)| (i, *v)).unwrap();
    let spread = lmin.max(0.0).sqrt();
    if spread < opts.min_depth_spread_m {
        let nv = eig.eigenvectors.column(imin);
        return Err(CalibError::Degenerate {
            hand,
            message: format!(
                "all {} poses lie in one plane (RMS {:.1} mm off it, normal ({:+.2}, {:+.2}, {:+.2})): the anchors' \
                 distances from that plane cannot be told apart; add poses at least 10 cm in front of and behind it \
                 (need an RMS spread of {:.0} mm)",
                obs.len(),
                spread * 1e3,
                nv[0],
                nv[1],
                nv[2],
                opts.min_depth_spread_m * 1e3
            ),
        });
    }
    Ok(())
}

/// The solved problem and how the solve went.
struct Solved<'a> {
    problem: Problem<'a>,
    /// Robust scale (MAD) of the last round's residuals.
    sigma: f64,
    evaluations: usize,
    rounds: usize,
}

/// IRLS around LM: Huber weights from the robust scale of the last fit's residuals, until
/// reweighting no longer moves the geometry (at most 10 rounds).
fn solve<'a>(
    hand: usize,
    hr: &HandRig,
    obs: &'a [Observation],
    start: &Start,
    layout: &'a Layout,
    gauge: Option<&'a Gauge>,
    opts: &FitOptions,
) -> Result<Solved<'a>, CalibError> {
    let mut x = DVector::zeros(layout.n);
    for i in 0..4 {
        for c in 0..3 {
            x[3 * i + c] = hr.anchors_m[i][c];
        }
        x[Layout::L + i] = start.l_ref[i];
    }
    let mut problem = Problem {
        obs,
        dc: start.dc.clone(),
        mpc0: hr.metres_per_count,
        sqrt_w: vec![[1.0; 4]; obs.len()],
        layout,
        gauge,
        x,
        poses: start.positions_m.clone(),
    };
    problem.solve_poses();
    let lm = LevenbergMarquardt::new().with_patience(200);
    let mut evaluations = 0;
    let mut rounds = 0;
    let mut sigma = 0.0;
    for round in 0..10 {
        rounds = round + 1;
        let before = problem.x.clone();
        let (p, report) = lm.minimize(problem);
        problem = p;
        // Converged when reweighting no longer moves the geometry (0.01 um).
        let moved = (&problem.x - &before).amax();
        evaluations += report.number_of_evaluations;
        if !report.termination.was_successful() {
            return Err(CalibError::NoConvergence { hand, why: format!("{:?}", report.termination) });
        }
        let r = problem.raw_residuals();
        // Robust scale (MAD). Averaged noisy counts resolve far below one count (the noise
        // dithers the quantiser), so no count-sized floor: only a tiny one against exact data.
        sigma = (1.4826 * median(r.iter().flatten().map(|v| v.abs()).collect())).max(SIGMA_FLOOR_M);
        let k = opts.huber_k * sigma;
        let new_w: Vec<[f64; 4]> =
            r.iter().map(|rk| rk.map(|v| if v.abs() <= k { 1.0 } else { (k / v.abs()).sqrt() })).collect();
        let change = new_w
            .iter()
            .zip(&problem.sqrt_w)
            .flat_map(|(a, b)| (0..4).map(move |i| (a[i] - b[i]).abs()))
            .fold(0.0, f64::max);
        problem.sqrt_w = new_w;
        if round > 0 && (change < 1e-3 || moved < 1e-8) {
            break;
        }
    }
    Ok(Solved { problem, sigma, evaluations, rounds })
}

/// Readings beyond `outlier_sigmas` robust standard deviations (and the floor): (pose, string,
/// residual), and the limit.
fn find_outliers(residuals: &[[f64; 4]], sigma: f64, opts: &FitOptions) -> (Vec<(usize, usize, f64)>, f64) {
    let limit = (opts.outlier_sigmas * sigma).max(opts.outlier_floor_m);
    let mut outliers = Vec::new();
    for (k, rk) in residuals.iter().enumerate() {
        for (i, &r) in rk.iter().enumerate() {
            if r.abs() > limit {
                outliers.push((k, i, r));
            }
        }
    }
    (outliers, limit)
}

/// A string that disagrees in many poses is slack or slipping: not something to fit through.
fn check_strings(
    hand: usize,
    poses: usize,
    outliers: &[(usize, usize, f64)],
    limit: f64,
    opts: &FitOptions,
) -> Result<(), CalibError> {
    for i in 0..4 {
        let bad: Vec<&(usize, usize, f64)> = outliers.iter().filter(|o| o.1 == i).collect();
        if bad.len() >= opts.slack_min_poses.max((opts.slack_fraction * poses as f64).ceil() as usize) {
            let worst = bad.iter().max_by(|a, b| a.2.abs().total_cmp(&b.2.abs())).unwrap();
            return Err(CalibError::InconsistentString {
                hand,
                string: i,
                bad: bad.len(),
                total: poses,
                limit_mm: limit * 1e3,
                worst_mm: worst.2 * 1e3,
                worst_pose: worst.0,
            });
        }
    }
    Ok(())
}

/// What the data determine: the weighted data Jacobian, its rank and condition, and the least
/// determined direction (a row of `v_t`).
struct Seen {
    jd: DMatrix<f64>,
    v_t: DMatrix<f64>,
    smallest: usize,
    rank: usize,
    condition: f64,
}

/// Observability: SVD of the weighted data Jacobian with the gauge rows appended (scaled like
/// the data rows). The gauge rows pin exactly the gauge directions, so what is still (nearly)
/// singular is a real lack of information. (Without them the scale direction is not exactly
/// null: scaling everything scales the residuals too.) A rank deficiency, or a condition above
/// `MAX_CONDITION`, is an error naming the parameters involved.
fn observability(
    hand: usize,
    problem: &Problem<'_>,
    layout: &Layout,
    gauge: Option<&Gauge>,
    size: &Size,
) -> Result<Seen, CalibError> {
    let jd = problem.data_jacobian();
    let jn = jd.norm() / (jd.ncols() as f64).sqrt();
    let j_obs = match gauge {
        Some(g) => {
            let jg = problem.gauge_jacobian(g) * (jn / GAUGE_WEIGHT);
            let mut j = DMatrix::zeros(jd.nrows() + jg.nrows(), jd.ncols());
            j.rows_mut(0, jd.nrows()).copy_from(&jd);
            j.rows_mut(jd.nrows(), jg.nrows()).copy_from(&jg);
            j
        }
        None => jd.clone(),
    };
    let svd = j_obs.svd(false, true);
    let v_t = svd.v_t.expect("requested");
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let smax = svd.singular_values[order[0]];
    let null: Vec<usize> =
        order.iter().copied().filter(|&q| svd.singular_values[q] < NULL_TOL * smax).collect();
    // Rank over all unknowns: each free pose is determined by its own 4 strings (3 of them span
    // space inside the anchor tetrahedron), so a deficiency can only be in the geometry.
    let gauge_dof = size.gauge_dof;
    let rank = layout.n_all() - null.len() - gauge_dof;
    let smallest = order.iter().copied().rfind(|q| !null.contains(q)).unwrap_or(order[0]);
    let condition = smax / svd.singular_values[smallest];
    if null.is_empty() && condition <= MAX_CONDITION {
        return Ok(Seen { jd, v_t, smallest, rank, condition });
    }
    // Component of each parameter in the (extra) null space.
    let null_part = |col: usize| null.iter().map(|&q| v_t[(q, col)].powi(2)).sum::<f64>().sqrt();
    let mut cols: Vec<usize> = (0..layout.n).collect();
    let weak_dir = |col: usize| if !null.is_empty() { null_part(col) } else { v_t[(smallest, col)].abs() };
    cols.sort_by(|&a, &b| weak_dir(b).total_cmp(&weak_dir(a)));
    let names: Vec<String> =
        cols.iter().take(6).filter(|&&c| weak_dir(c) > 0.05).map(|&c| param_name(c)).collect();
    let jig_hint = if (1..4).contains(&size.n_jig) {
        " With jig points, use at least 4 not in one plane (or none: free poses alone)."
    } else {
        ""
    };
    Err(CalibError::Degenerate {
        hand,
        message: format!(
            "the data do not determine the geometry: {} ({} of {} directions unobservable{}, condition {:.1e}); \
             involved: {}. Spread the poses through the whole workspace, in all three directions.{jig_hint}",
            if !null.is_empty() { "rank deficient" } else { "nearly rank deficient" },
            null.len().max(1),
            layout.n_all() - gauge_dof,
            if gauge_dof > 0 { format!(" beyond the {gauge_dof} of the frame") } else { String::new() },
            condition,
            names.join(", ")
        ),
    })
}

/// Covariance of the geometry in the chosen gauge: sigma^2 (J^T J + G^T G)^-1, plus what the jig
/// points' tolerance propagates into it (the residuals cannot show that: the anchors absorb part
/// of a displaced jig point).
#[allow(clippy::too_many_arguments)]
fn covariance(
    hand: usize,
    problem: &Problem<'_>,
    jd: &DMatrix<f64>,
    gauge: Option<&Gauge>,
    size: &Size,
    residuals: &[[f64; 4]],
    weights: &[[f64; 4]],
    opts: &FitOptions,
) -> Result<DMatrix<f64>, CalibError> {
    let mut normal = jd.transpose() * jd;
    if let Some(g) = gauge {
        let jg = problem.gauge_jacobian(g);
        normal += jg.transpose() * jg;
    }
    let redundancy = (size.m + size.gauge_dof) as f64 - problem.layout.n_all() as f64;
    let wsum: f64 =
        residuals.iter().zip(weights).flat_map(|(r, w)| (0..4).map(move |i| w[i] * r[i] * r[i])).sum();
    let s2 = (wsum / redundancy.max(1.0)).max(SIGMA_FLOOR_M * SIGMA_FLOOR_M);
    let inv = normal.clone().cholesky().map(|c| c.inverse()).ok_or_else(|| CalibError::Degenerate {
        hand,
        message: "the normal equations are singular although the rank check passed: report this".into(),
    })?;
    let mut cov = &inv * s2;
    if size.n_jig > 0 && opts.jig_tolerance_m > 0.0 {
        // A jig point is known to within its tolerance (and the holding tension moves the grip
        // on it a little).
        let obs = problem.obs;
        let mut jp = DMatrix::zeros(jd.nrows(), 3 * size.n_jig);
        let mut col = 0;
        for k in (0..obs.len()).filter(|&k| obs[k].known_m.is_some()) {
            let p = problem.pose(k);
            for i in 0..4 {
                let u = (problem.anchor(i) - p).normalize_or_zero() * problem.sqrt_w[k][i];
                for c in 0..3 {
                    jp[(4 * k + i, col + c)] = u[c];
                }
            }
            col += 3;
        }
        let a = &inv * (jd.transpose() * jp);
        cov += (&a * a.transpose()) * opts.jig_tolerance_m.powi(2);
    }
    Ok(cov)
}

/// Every parameter's estimate, configured value, standard deviation and observability.
fn param_reports(
    hr: &HandRig,
    problem: &Problem<'_>,
    geometry: &HandGeometry,
    cov: &DMatrix<f64>,
    c_ref: [f64; 4],
    gauge_dof: usize,
    opts: &FitOptions,
) -> Vec<ParamReport> {
    let std = |col: usize| cov[(col, col)].max(0.0).sqrt();
    let (x, mpc0, fit_mpc) = (&problem.x, hr.metres_per_count, problem.layout.fit_mpc);
    // In the free-pose gauge every anchor moves with the frame, and with the scale free the
    // lengths and metres per count scale with it (exactly: see the module doc).
    let in_gauge = |col: usize| gauge_dof > 0 && (col < 12 || gauge_dof == 7);
    let status = |col: usize, std: f64, weak: f64| {
        if in_gauge(col) {
            Observability::Gauge
        } else if std > weak {
            Observability::Weak
        } else {
            Observability::Observed
        }
    };
    let mut params = Vec::new();
    for col in 0..12 {
        let s = std(col);
        params.push(ParamReport {
            name: param_name(col),
            value: x[col],
            configured: hr.anchors_m[col / 3][col % 3],
            std: s,
            unit: "m",
            status: status(col, s, opts.weak_std_m),
        });
    }
    for i in 0..4 {
        // length at counter zero = L - m0 (1 + s) c_ref: propagate the covariance of (L, s).
        let cl = Layout::L + i;
        let mut var = cov[(cl, cl)];
        if fit_mpc {
            let cs = Layout::S + i;
            let g = -mpc0[i] * c_ref[i];
            var += g * g * cov[(cs, cs)] + 2.0 * g * cov[(cl, cs)];
        }
        let s = var.max(0.0).sqrt();
        params.push(ParamReport {
            name: format!("length_at_zero[{i}]"),
            value: geometry.length_at_zero_m[i],
            configured: hr.length_at_zero_m.map_or(f64::NAN, |z| z[i]),
            std: s,
            unit: "m",
            // The length at the reference pose is what the data see; judge observability on it.
            status: status(cl, std(cl), opts.weak_std_m),
        });
    }
    if fit_mpc {
        for (i, &m0) in mpc0.iter().enumerate() {
            let col = Layout::S + i;
            let s = std(col) * m0.abs();
            params.push(ParamReport {
                name: format!("metres_per_count[{i}]"),
                value: geometry.metres_per_count[i],
                configured: m0,
                std: s,
                unit: "m/count",
                status: status(col, std(col), 1e-4),
            });
        }
    }
    params
}

/// What free poses alone leave unobservable, and how it was fixed.
fn gauge_note(fit_mpc: bool) -> String {
    format!(
        "from free poses alone the rig frame (3 translations, 3 rotations){} cannot be observed: lengths do not \
         change when the whole rig moves{}. It was fixed to the configured anchors (same centroid, no rotation{} \
         against them), so the anchors' absolute positions carry the configured anchors' common error; their \
         shape, the lengths and the {} are determined. Add at least 4 jig points (not in one plane) to observe it.",
        if fit_mpc { " and its scale" } else { "" },
        if fit_mpc { " or grows with the metres per count" } else { "" },
        if fit_mpc { ", no scaling" } else { "" },
        if fit_mpc { "ratios of the metres per count" } else { "metres per count as configured" }
    )
}

/// What data would help.
fn advice(
    params: &[ParamReport],
    seen: &Seen,
    size: &Size,
    outliers: &[(usize, usize, f64)],
    labels: &[String],
    quality: &Quality,
    fit_mpc: bool,
) -> Vec<String> {
    let mut advice = Vec::new();
    let weak: Vec<&ParamReport> = params.iter().filter(|p| p.status == Observability::Weak).collect();
    if !weak.is_empty() {
        let (v_t, smallest) = (&seen.v_t, seen.smallest);
        let mut cols: Vec<usize> = (0..if fit_mpc { 20 } else { 16 }).collect();
        cols.sort_by(|&a, &b| v_t[(smallest, b)].abs().total_cmp(&v_t[(smallest, a)].abs()));
        advice.push(format!(
            "weakly determined: {}; the least determined combination involves {}: spread the poses wider (closer to \
             and farther from those anchors) and add more of them",
            weak.iter().map(|p| p.name.as_str()).collect::<Vec<_>>().join(", "),
            cols.iter().take(3).map(|&c| param_name(c)).collect::<Vec<_>>().join(", ")
        ));
    }
    if size.gauge_dof > 0 {
        advice.push("add at least 4 jig points (not in one plane) to fix the rig frame and scale".into());
    }
    if !outliers.is_empty() {
        let mut poses: Vec<usize> = outliers.iter().map(|o| o.0).collect();
        poses.dedup();
        advice.push(format!(
            "re-record pose(s) {} (outliers were down-weighted; a moved grip or a briefly slack string)",
            poses.iter().map(|k| format!("{k} ({})", labels[*k])).collect::<Vec<_>>().join(", ")
        ));
    }
    if !quality.clean() {
        advice.push(
            "the data are not clean (see data quality above): weak parameters and outliers may follow from that; \
             fix the data first"
                .into(),
        );
    }
    if advice.is_empty() {
        advice.push("nothing: every parameter is determined to within the threshold".into());
    }
    advice
}

impl HandFit {
    /// True when no parameter is weakly determined and the residual is at the level of the noise
    /// measured at rest (outliers alone do not count when the residual is: they were down-weighted
    /// and are listed in the report).
    pub fn is_trustworthy(&self) -> bool {
        self.params.iter().all(|p| p.status != Observability::Weak) && self.quality.clean()
    }
}

impl HandFit {
    /// What the data-quality check found, one line each with what to re-record; empty when the
    /// residual is at the level of the noise.
    pub fn quality_lines(&self) -> Vec<String> {
        if self.quality.clean() {
            return Vec::new();
        }
        let mut lines = self.quality.describe(self.hand, &self.labels);
        if lines.is_empty() {
            lines.push(format!(
                "unexplained: hand {} has a residual {:.0} times the noise measured at rest and no single slip, \
                 creep or outlier pose explains it: check the rig file's channels and signs and the jig's \
                 coordinates, then record hand {} again",
                self.hand, self.quality.ratio, self.hand
            ));
        }
        lines
    }
}

impl std::fmt::Display for HandFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "hand {}: {} poses ({} jig, {} free), {} unknowns, Jacobian rank {} (+{} fixed by the frame choice), \
             condition {:.2e}",
            self.hand,
            self.labels.len(),
            self.n_jig,
            self.n_free,
            self.n_params,
            self.rank,
            self.gauge_dof,
            self.condition
        )?;
        writeln!(
            f,
            "  residual RMS {:.4} mm, robust sigma {:.4} mm, worst pose {} ({}) {:.4} mm RMS; {} outlier(s); LM \
             {} evaluations in {} IRLS round(s)",
            self.rms_m * 1e3,
            self.robust_sigma_m * 1e3,
            self.worst_pose.0,
            self.labels[self.worst_pose.0],
            self.worst_pose.1 * 1e3,
            self.outliers.len(),
            self.lm_evaluations,
            self.irls_rounds
        )?;
        let q = &self.quality;
        writeln!(
            f,
            "  data quality: residual {:.1} times the noise measured at rest ({:.4} mm RMS per averaged length; limit \
             {:.1} times){}",
            q.ratio,
            q.noise_rms_m * 1e3,
            q.max_noise_ratio,
            if q.clean() {
                ": the model explains the data".to_string()
            } else if q.findings.is_empty() {
                ": NOT explained by noise, no single cause found".to_string()
            } else {
                format!(": NOT noise; {} cause(s) found, {:.1} times the noise without them", q.findings.len(), q.ratio_after)
            }
        )?;
        for line in self.quality_lines() {
            writeln!(f, "  {line}")?;
        }
        for (k, i, r) in &self.outliers {
            writeln!(f, "  outlier: pose {k} ({}) string {i}: {:+.3} mm", self.labels[*k], r * 1e3)?;
        }
        writeln!(
            f,
            "  {:<22} {:>16} {:>16} {:>12} {:>12}  status",
            "parameter", "fitted", "configured", "change", "std dev"
        )?;
        for p in &self.params {
            let (scale, unit) = if p.unit == "m" { (1.0, "m") } else { (1.0, "") };
            let change = if p.configured.is_finite() {
                if p.unit == "m" {
                    format!("{:+.2} mm", (p.value - p.configured) * 1e3)
                } else {
                    format!("{:+.3} %", (p.value / p.configured - 1.0) * 100.0)
                }
            } else {
                "-".into()
            };
            let std = if p.unit == "m" {
                format!("{:.3} mm", p.std * 1e3)
            } else {
                format!("{:.2e} ({:.3} %)", p.std, p.std / p.value.abs() * 100.0)
            };
            let value = if p.unit == "m" {
                format!("{:.5} {unit}", p.value * scale)
            } else {
                format!("{:.6e}", p.value)
            };
            let conf = if !p.configured.is_finite() {
                "-".into()
            } else if p.unit == "m" {
                format!("{:.5} m", p.configured)
            } else {
                format!("{:.6e}", p.configured)
            };
            let status = match p.status {
                Observability::Observed => "observed",
                Observability::Weak => "WEAK",
                Observability::Gauge => "frame (not observable)",
            };
            writeln!(f, "  {:<22} {:>16} {:>16} {:>12} {:>12}  {status}", p.name, value, conf, change, std)?;
        }
        if let Some(n) = &self.gauge_note {
            writeln!(f, "  note: {n}")?;
        }
        for a in &self.advice {
            writeln!(f, "  more data would help: {a}")?;
        }
        Ok(())
    }
}
