//! Grip position from the four string lengths of one SPIDAR-H hand, and the string directions
//! that the tension allocator needs.
//!
//! Why it exists: every 1 kHz tick turns encoder lengths into the grip position (closed form seed
//! from `docs/reference.md` section 2, then damped Gauss-Newton over all four strings) and
//! reports the least-squares residual as a free health signal (slack string, encoder slip, wrong
//! anchor).
//!
//! What it must never do: allocate, lock, format, or panic. Everything here is fixed-size `f64`
//! arithmetic on `glam` values; bad input (NaN, infinity, negative lengths) gives a `GripSolution` with
//! `valid == false` instead of a panic, and degenerate geometry (grip on an anchor) degrades to a
//! zero direction rather than a division by zero.

use core::fmt;

use glam::{DMat3, DVec3};

/// Gauss-Newton damping `s` in `(J^T J + s I) dx = J^T (l_meas - l_calc)`.
///
/// `J` has unit rows, so `J^T J` is dimensionless with trace 4; inside the SPIDAR-H and desktop
/// tetrahedra its smallest eigenvalue is 0.5 .. 1.3. Damping does not move the fixed point (at
/// the least-squares optimum `J^T r = 0` whatever `s` is); it only leaves a fraction
/// `s / (eig + s)` (~2e-3 here) of the linearised error after each step, invisible after the
/// closed-form seed, and bounds the step when `J^T J` is near singular (grip close to an anchor
/// or a degenerate pose). That is the lab's value and there is no reason to differ.
pub const GN_DAMPING: f64 = 1e-3;

/// Smallest accepted anchor "flatness" ratio `6 V / L^3`, with `V` the volume of the anchor
/// tetrahedron and `L` its longest edge (0.707 for a regular tetrahedron, about its thickness
/// over its size for a flat one). Below 1 % the closed-form 3x3 is badly conditioned and the rig
/// could not render force across that plane anyway, so such anchors are a configuration error.
pub const MIN_ANCHOR_SHAPE: f64 = 1e-2;

/// Distances below this (metres) count as "grip on the anchor": the direction is undefined there.
const MIN_DIST_M: f64 = 1e-9;

/// Why a set of anchors cannot be used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum KinematicsError {
    /// An anchor coordinate is NaN or infinite.
    NonFiniteAnchor {
        /// Index (0..4) of the first bad anchor.
        index: usize,
    },
    /// The anchors are (nearly) coplanar or coincide: `6 V / L^3` below [`MIN_ANCHOR_SHAPE`].
    Coplanar {
        /// The measured ratio `6 V / L^3`.
        shape: f64,
    },
}

impl fmt::Display for KinematicsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KinematicsError::NonFiniteAnchor { index } => {
                write!(f, "anchor {index} has a NaN or infinite coordinate: fix anchor_m in the rig file")
            }
            KinematicsError::Coplanar { shape } => write!(
                f,
                "the four anchors are (nearly) coplanar or coincide (6V/L^3 = {shape:.3e}, need >= \
                 {MIN_ANCHOR_SHAPE:.0e}): the grip position cannot be computed; check anchor_m in the rig \
                 file (the motors must not lie in one plane)"
            ),
        }
    }
}

impl std::error::Error for KinematicsError {}

/// Result of one position solve.
#[derive(Clone, Copy, Debug)]
pub struct GripSolution {
    /// Grip position in the rig frame, metres. NaN when `valid` is false, so that any accidental
    /// use trips a NaN guard instead of silently rendering at a made-up point.
    pub pos_m: DVec3,
    /// RMS over the four strings of `|p - a_i| - l_i` after the solve, metres. A few count-lengths
    /// for a healthy rig; millimetres or more means a slack string, slip or wrong geometry.
    /// `f64::INFINITY` when `valid` is false, so a `residual > limit` check also trips.
    pub residual_m: f64,
    /// False when an input length was NaN, infinite or negative, or the result was not finite.
    pub valid: bool,
}

impl GripSolution {
    const INVALID: GripSolution = GripSolution { pos_m: DVec3::NAN, residual_m: f64::INFINITY, valid: false };
}

/// Anchor geometry of one hand with the closed-form inverse precomputed.
#[derive(Clone, Debug)]
pub struct Kinematics {
    anchors_m: [DVec3; 4],
    /// Anchor centroid. The closed form works in coordinates relative to it so that the squared
    /// norms it subtracts are small and lose no precision in a rig far from its frame's origin.
    centroid_m: DVec3,
    /// Inverse of the matrix whose rows are `2 (b_{i+1} - b_i)`, `b_i = a_i - centroid`.
    m_inv: DMat3,
    /// `|b_{i+1}|^2 - |b_i|^2` for i = 0, 1, 2: the geometry-only part of the right-hand side.
    k: DVec3,
}

impl Kinematics {
    /// Precomputes the closed form for these anchors (rig frame, metres).
    ///
    /// Fails when an anchor is not finite or the anchors are (nearly) coplanar, which the closed
    /// form cannot invert; see [`MIN_ANCHOR_SHAPE`].
    pub fn new(anchors_m: [DVec3; 4]) -> Result<Kinematics, KinematicsError> {
        if let Some(index) = anchors_m.iter().position(|a| !a.is_finite()) {
            return Err(KinematicsError::NonFiniteAnchor { index });
        }
        let [a0, a1, a2, a3] = anchors_m;
        let six_vol = (a1 - a0).cross(a2 - a0).dot(a3 - a0).abs();
        let mut longest = 0.0_f64;
        for i in 0..4 {
            for j in (i + 1)..4 {
                longest = longest.max(anchors_m[i].distance(anchors_m[j]));
            }
        }
        let shape = if longest > 0.0 { six_vol / (longest * longest * longest) } else { 0.0 };
        // A NaN ratio (possible only with absurd magnitudes) is rejected too.
        if shape.is_nan() || shape < MIN_ANCHOR_SHAPE {
            return Err(KinematicsError::Coplanar { shape });
        }
        let centroid_m = (a0 + a1 + a2 + a3) * 0.25;
        let b = anchors_m.map(|a| a - centroid_m);
        let m = DMat3::from_cols(2.0 * (b[1] - b[0]), 2.0 * (b[2] - b[1]), 2.0 * (b[3] - b[2])).transpose();
        let m_inv = m.inverse();
        let k = DVec3::new(
            b[1].length_squared() - b[0].length_squared(),
            b[2].length_squared() - b[1].length_squared(),
            b[3].length_squared() - b[2].length_squared(),
        );
        if !m_inv.is_finite() {
            return Err(KinematicsError::Coplanar { shape });
        }
        Ok(Kinematics { anchors_m, centroid_m, m_inv, k })
    }

    /// The anchors this geometry was built from (rig frame, metres).
    pub fn anchors(&self) -> &[DVec3; 4] {
        &self.anchors_m
    }

    /// String lengths `|a_i - p|` for a grip at `p`.
    pub fn lengths(&self, p: DVec3) -> [f64; 4] {
        self.anchors_m.map(|a| a.distance(p))
    }

    /// Closed-form position: subtract consecutive sphere equations `|p - a_i|^2 = l_i^2` and
    /// solve the three linear equations with the precomputed inverse. Exact for consistent
    /// lengths, but it uses only three of the four differences, so with noisy lengths it is a
    /// seed, not the estimate. Non-finite in, non-finite out (no panic).
    pub fn closed_form(&self, lengths_m: &[f64; 4]) -> DVec3 {
        let [l0, l1, l2, l3] = lengths_m.map(|l| l * l);
        // 2 (b_{i+1} - b_i) . q = l_i^2 - l_{i+1}^2 + |b_{i+1}|^2 - |b_i|^2, with q = p - centroid.
        let rhs = DVec3::new(l0 - l1, l1 - l2, l2 - l3) + self.k;
        self.centroid_m + self.m_inv * rhs
    }

    /// Closed-form seed, then `iterations` damped Gauss-Newton steps over all four strings
    /// (2 per tick is plenty: the seed is already exact up to length noise).
    ///
    /// Negative, NaN or infinite lengths give `valid == false` (a negative length is an encoder or
    /// homing fault, never a geometry). A step that would produce a non-finite position is
    /// skipped, so a finite seed always yields a finite pose.
    pub fn solve(&self, lengths_m: &[f64; 4], iterations: u32) -> GripSolution {
        // `!(l >= 0)` also catches NaN; `is_finite` catches +inf.
        if lengths_m.iter().any(|&l| !(l >= 0.0 && l.is_finite())) {
            return GripSolution::INVALID;
        }
        let mut p = self.closed_form(lengths_m);
        if !p.is_finite() {
            return GripSolution::INVALID;
        }
        for _ in 0..iterations {
            let mut jtj = DMat3::from_diagonal(DVec3::splat(GN_DAMPING));
            let mut jtr = DVec3::ZERO;
            for (a, &l) in self.anchors_m.iter().zip(lengths_m) {
                let d = p - *a;
                let dist = d.length();
                if dist > MIN_DIST_M {
                    // Row of J: d(|p - a|)/dp, the unit vector from the anchor to the grip.
                    let u = d / dist;
                    jtj += outer(u, u);
                    jtr += u * (l - dist);
                }
            }
            let dx = jtj.inverse() * jtr;
            let next = p + dx;
            if !next.is_finite() {
                break;
            }
            p = next;
        }
        let mut sum_sq = 0.0;
        for (a, &l) in self.anchors_m.iter().zip(lengths_m) {
            let r = a.distance(p) - l;
            sum_sq += r * r;
        }
        let residual_m = (sum_sq * 0.25).sqrt();
        if !(p.is_finite() && residual_m.is_finite()) {
            return GripSolution::INVALID;
        }
        GripSolution { pos_m: p, residual_m, valid: true }
    }

    /// Unit vectors from a grip at `p` toward each anchor: the direction in which each string's
    /// tension pulls the grip. A grip on an anchor gives a zero vector for that string (no defined
    /// direction; the allocator then holds it at minimum tension); a non-finite `p` gives NaN
    /// vectors, which the allocator treats as unknown directions.
    pub fn directions(&self, p: DVec3) -> [DVec3; 4] {
        self.anchors_m.map(|a| {
            let d = a - p;
            let dist = d.length();
            if dist > MIN_DIST_M {
                d / dist
            } else if dist.is_nan() {
                DVec3::NAN
            } else {
                DVec3::ZERO
            }
        })
    }
}

/// `u v^T`.
#[inline]
fn outer(u: DVec3, v: DVec3) -> DMat3 {
    DMat3::from_cols(u * v.x, u * v.y, u * v.z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Metres of string per encoder count on the human-scale rig (reference section 1).
    const COUNT_M: f64 = 2.924062107079e-5;
    const SEED: u64 = 0x5919_da11;

    /// Deterministic runs (fixed seed, nothing written to disk); set PROPTEST_RNG_SEED to explore.
    fn cfg(cases: u32) -> ProptestConfig {
        spidar_testkit::proptest_config(SEED, cases)
    }

    fn spidar_h() -> [[DVec3; 4]; 2] {
        [
            [
                DVec3::new(-1.75, 2.00, 1.12),
                DVec3::new(1.65, 2.17, -1.34),
                DVec3::new(-1.65, -0.90, -1.44),
                DVec3::new(1.65, -0.99, 0.50),
            ],
            [
                DVec3::new(1.58, 2.00, 1.12),
                DVec3::new(-1.65, 2.18, -1.34),
                DVec3::new(1.65, -0.98, -1.44),
                DVec3::new(-1.65, -0.98, 0.50),
            ],
        ]
    }

    fn desktop_cube() -> [DVec3; 4] {
        let h = 0.265;
        [DVec3::new(h, h, h), DVec3::new(-h, h, -h), DVec3::new(h, -h, -h), DVec3::new(-h, -h, h)]
    }

    /// Point with barycentric weights `w` (normalised here) in the anchor tetrahedron.
    fn bary(anchors: &[DVec3; 4], w: [f64; 4]) -> DVec3 {
        let s: f64 = w.iter().sum();
        anchors.iter().zip(w).fold(DVec3::ZERO, |acc, (a, wi)| acc + *a * (wi / s))
    }

    /// A random anchor set that `new` accepts comfortably, or the two real ones.
    fn anchor_sets() -> impl Strategy<Value = [DVec3; 4]> {
        let coord = -2.5f64..2.5;
        let v = (coord.clone(), coord.clone(), coord).prop_map(|(x, y, z)| DVec3::new(x, y, z));
        let random = [v.clone(), v.clone(), v.clone(), v]
            .prop_filter("well-shaped tetrahedron", |a| Kinematics::new(*a).is_ok_and(|_| shape(a) > 0.1));
        prop_oneof![
            1 => Just(spidar_h()[0]),
            1 => Just(spidar_h()[1]),
            1 => Just(desktop_cube()),
            3 => random,
        ]
    }

    fn shape(a: &[DVec3; 4]) -> f64 {
        let v = (a[1] - a[0]).cross(a[2] - a[0]).dot(a[3] - a[0]).abs();
        let mut l = 0.0f64;
        for i in 0..4 {
            for j in 0..4 {
                l = l.max(a[i].distance(a[j]));
            }
        }
        v / (l * l * l)
    }

    /// Barycentric weights that keep the point at least 5 % (of each weight) inside every face.
    fn inner_weights() -> impl Strategy<Value = [f64; 4]> {
        [0.05f64..1.0, 0.05f64..1.0, 0.05f64..1.0, 0.05f64..1.0]
    }

    #[test]
    fn real_rig_and_desktop_anchors_are_accepted() {
        for a in spidar_h().into_iter().chain([desktop_cube()]) {
            let k = Kinematics::new(a).expect("real anchors must be accepted");
            assert_eq!(k.anchors(), &a);
        }
    }

    #[test]
    fn coplanar_coincident_and_nonfinite_anchors_are_rejected() {
        let flat = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, 1.0, 1e-3)];
        assert!(matches!(Kinematics::new(flat), Err(KinematicsError::Coplanar { .. })));
        let exactly_flat = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(0.3, 0.7, 0.0)];
        assert!(matches!(Kinematics::new(exactly_flat), Err(KinematicsError::Coplanar { .. })));
        let same = [DVec3::ONE; 4];
        assert!(matches!(Kinematics::new(same), Err(KinematicsError::Coplanar { .. })));
        let mut nan = desktop_cube();
        nan[2].y = f64::NAN;
        assert_eq!(Kinematics::new(nan).unwrap_err(), KinematicsError::NonFiniteAnchor { index: 2 });
        let mut inf = desktop_cube();
        inf[3].x = f64::INFINITY;
        assert_eq!(Kinematics::new(inf).unwrap_err(), KinematicsError::NonFiniteAnchor { index: 3 });
        // The message tells the user what to do.
        let msg = Kinematics::new(flat).unwrap_err().to_string();
        assert!(msg.contains("anchor_m"), "{msg}");
    }

    #[test]
    fn bad_lengths_give_invalid_pose_without_panic() {
        let k = Kinematics::new(spidar_h()[0]).unwrap();
        let good = k.lengths(DVec3::new(0.1, 0.2, -0.1));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.5] {
            for i in 0..4 {
                let mut l = good;
                l[i] = bad;
                for it in [0, 2, 50] {
                    let pose = k.solve(&l, it);
                    assert!(!pose.valid);
                    assert!(pose.pos_m.is_nan());
                    assert_eq!(pose.residual_m, f64::INFINITY);
                }
            }
        }
        // Absurd but finite lengths: either a finite pose or an invalid one, never a panic.
        for l in [[1e300; 4], [0.0; 4], [1e-300, 1e300, 0.0, 5.0]] {
            let pose = k.solve(&l, 2);
            assert!(!pose.valid || (pose.pos_m.is_finite() && pose.residual_m.is_finite()));
        }
    }

    #[test]
    fn directions_are_unit_toward_the_anchors_and_safe_on_an_anchor() {
        let a = spidar_h()[1];
        let k = Kinematics::new(a).unwrap();
        let p = DVec3::new(0.2, 0.3, -0.1);
        for (u, ai) in k.directions(p).iter().zip(&a) {
            assert!((u.length() - 1.0).abs() < 1e-15);
            assert!(u.dot((*ai - p).normalize()) > 1.0 - 1e-15);
        }
        let on = k.directions(a[2]);
        assert_eq!(on[2], DVec3::ZERO);
        assert!(on.iter().all(|u| u.is_finite()));
        assert!(k.directions(DVec3::NAN).iter().all(|u| u.is_nan()));
    }

    #[test]
    fn one_centimetre_error_on_one_string_raises_the_residual() {
        for a in spidar_h().into_iter().chain([desktop_cube()]) {
            let k = Kinematics::new(a).unwrap();
            let centre = bary(&a, [1.0; 4]);
            let scale = a[0].distance(centre);
            for p in [centre, centre + DVec3::new(0.1, -0.1, 0.05) * scale] {
                let exact = k.lengths(p);
                let clean = k.solve(&exact, 2).residual_m;
                assert!(clean < 1e-9, "{clean}");
                for i in 0..4 {
                    let mut l = exact;
                    l[i] += 0.01;
                    let pose = k.solve(&l, 2);
                    // A 1 cm slip leaves a residual of millimetres, 100x above quantisation noise.
                    assert!(pose.valid && pose.residual_m > 1e-3, "string {i}: {}", pose.residual_m);
                }
            }
        }
    }

    #[test]
    fn gauss_newton_moves_the_seed_to_the_least_squares_optimum() {
        // A 5 mm error on one string: the seed (three differences) and the least-squares pose
        // differ by millimetres; the solve must land on the optimum, where J^T r = 0, and its
        // residual must be the optimum's, below the seed's.
        let a = spidar_h()[0];
        let k = Kinematics::new(a).unwrap();
        let p = DVec3::new(-0.15, 0.1, 0.05);
        for i in 0..4 {
            let mut l = k.lengths(p);
            l[i] += 0.005;
            let seed = k.closed_form(&l);
            let pose = k.solve(&l, 2);
            let rms = |x: DVec3| {
                (k.lengths(x).iter().zip(&l).map(|(c, m)| (c - m).powi(2)).sum::<f64>() * 0.25).sqrt()
            };
            assert!((pose.residual_m - rms(pose.pos_m)).abs() < 1e-15, "the residual is the RMS at the pose");
            assert!(
                pose.residual_m < rms(seed) - 1e-6,
                "string {i}: {} vs seed {}",
                pose.residual_m,
                rms(seed)
            );
            // At the optimum the gradient vanishes: J^T r = 0.
            let grad = a.iter().zip(&l).fold(DVec3::ZERO, |g, (ai, li)| {
                let d = pose.pos_m - *ai;
                g + d.normalize() * (d.length() - li)
            });
            assert!(grad.length() < 1e-6, "string {i}: gradient {grad}");
            // With no iteration the pose is the seed.
            assert_eq!(k.solve(&l, 0).pos_m, seed);
        }
    }

    proptest! {
        #![proptest_config(cfg(2000))]

        #[test]
        fn closed_form_is_exact_with_exact_lengths(a in anchor_sets(), w in inner_weights()) {
            let k = Kinematics::new(a).unwrap();
            let p = bary(&a, w);
            let q = k.closed_form(&k.lengths(p));
            prop_assert!(q.distance(p) < 1e-12, "{} vs {}", q, p);
        }

        #[test]
        fn round_trip_recovers_the_position(a in anchor_sets(), w in inner_weights()) {
            let k = Kinematics::new(a).unwrap();
            let p = bary(&a, w);
            let pose = k.solve(&k.lengths(p), 2);
            prop_assert!(pose.valid);
            prop_assert!(pose.pos_m.distance(p) < 1e-12, "{} vs {}", pose.pos_m, p);
            prop_assert!(pose.residual_m < 1e-12);
        }

        #[test]
        fn quantised_lengths_give_sub_count_error(w in inner_weights(), hand in 0usize..2) {
            let a = spidar_h()[hand];
            let k = Kinematics::new(a).unwrap();
            let p = bary(&a, w);
            let l = k.lengths(p).map(|l| (l / COUNT_M).round() * COUNT_M);
            let pose = k.solve(&l, 2);
            prop_assert!(pose.valid);
            // Each length is off by at most half a count, so the least-squares error can reach
            // |J^+ d| for the worst sign pattern d of +-half a count: compute that bound here.
            let u = a.map(|ai| (p - ai).normalize());
            let jtj = u.iter().fold(DMat3::ZERO, |m, ui| m + outer(*ui, *ui));
            let mut bound = 0.0f64;
            for signs in 0..16 {
                let jtd = (0..4).fold(DVec3::ZERO, |acc, i| {
                    acc + u[i] * if signs & (1 << i) != 0 { 0.5 * COUNT_M } else { -0.5 * COUNT_M }
                });
                bound = bound.max((jtj.inverse() * jtd).length());
            }
            let err = pose.pos_m.distance(p);
            prop_assert!(err <= bound * 1.001 + 1e-12, "error {} > bound {}", err, bound);
            // On this rig that is about one count-length (1.2 at worst near the faces).
            prop_assert!(err < 1.25 * COUNT_M, "error {} counts", err / COUNT_M);
            prop_assert!(pose.residual_m < COUNT_M);
            // Gauss-Newton over four strings is at least as good as the three-difference seed.
            let seed = k.closed_form(&l);
            let resid = |x: DVec3| k.lengths(x).iter().zip(&l).map(|(c, m)| (c - m).powi(2)).sum::<f64>();
            prop_assert!(resid(pose.pos_m) <= resid(seed) * (1.0 + 1e-9) + 1e-24);
        }

        #[test]
        fn solve_converges_to_the_least_squares_optimum(
            w in inner_weights(),
            noise in [-3e-3f64..3e-3, -3e-3f64..3e-3, -3e-3f64..3e-3, -3e-3f64..3e-3],
        ) {
            // With inconsistent lengths (up to 3 mm, a slipping string) 2 steps already sit at the
            // optimum to well under a count-length: more steps change nothing that matters.
            let a = spidar_h()[0];
            let k = Kinematics::new(a).unwrap();
            let p = bary(&a, w);
            let mut l = k.lengths(p);
            for (li, n) in l.iter_mut().zip(noise) {
                *li += n;
            }
            let two = k.solve(&l, 2);
            let many = k.solve(&l, 20);
            prop_assert!(two.pos_m.distance(many.pos_m) < 1e-6, "{}", two.pos_m.distance(many.pos_m));
            prop_assert!((two.residual_m - many.residual_m).abs() < 1e-9);
        }
    }
}
