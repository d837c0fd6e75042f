//! The geometry of one hand that calibration measures: anchors, string length at counter zero and
//! metres per count, and the one equation that ties them to the counts,
//! `|anchor_i - grip| = length_at_zero_m_i + metres_per_count_i * counts_i`.
//!
//! It must never guess: a rig that was never homed has no length at zero, and that is an `Option`
//! here, not a made-up number.

use glam::DVec3;
use spidar_rt::rig::HandRig;

/// One hand's string geometry (rig frame, metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandGeometry {
    pub anchors_m: [DVec3; 4],
    pub length_at_zero_m: [f64; 4],
    pub metres_per_count: [f64; 4],
}

impl HandGeometry {
    /// The configured geometry of a hand, if it has lengths at zero (homed or calibrated).
    pub fn from_rig(hr: &HandRig) -> Option<HandGeometry> {
        Some(HandGeometry {
            anchors_m: hr.anchors_m,
            length_at_zero_m: hr.length_at_zero_m?,
            metres_per_count: hr.metres_per_count,
        })
    }

    /// The configured anchors and metres per count, with the lengths at zero that make the grip
    /// read `at_m` for these counts (what homing does).
    pub fn homed(hr: &HandRig, counts: &[f64; 4], at_m: DVec3) -> HandGeometry {
        let mut l0 = [0.0; 4];
        for i in 0..4 {
            l0[i] = (hr.anchors_m[i] - at_m).length() - counts[i] * hr.metres_per_count[i];
        }
        HandGeometry { anchors_m: hr.anchors_m, length_at_zero_m: l0, metres_per_count: hr.metres_per_count }
    }

    /// String lengths for (averaged) counts.
    pub fn lengths(&self, counts: &[f64; 4]) -> [f64; 4] {
        std::array::from_fn(|i| self.length_at_zero_m[i] + self.metres_per_count[i] * counts[i])
    }

    /// Grip position for these counts and the RMS string residual there (the rt-loop's solver,
    /// iterated to convergence). `None` if the anchors are unusable or the lengths invalid.
    pub fn position(&self, counts: &[f64; 4]) -> Option<(DVec3, f64)> {
        let k = spidar_rt::kinematics::Kinematics::new(self.anchors_m).ok()?;
        let pose = k.solve(&self.lengths(counts), 20);
        pose.valid.then_some((pose.pos_m, pose.residual_m))
    }
}

/// Best rigid (or, with `scale`, similarity) transform mapping `from` onto `to` in the
/// least-squares sense (Umeyama 1991), applied to `from`. Used to compare a geometry fitted in an
/// unobservable frame with the truth, and to report how far the fit moved the anchor set as a whole.
pub fn align(from: &[DVec3], to: &[DVec3], scale: bool) -> Vec<DVec3> {
    use nalgebra::{Matrix3, Vector3};
    let n = from.len() as f64;
    let cf = from.iter().copied().sum::<DVec3>() / n;
    let ct = to.iter().copied().sum::<DVec3>() / n;
    let v = |p: DVec3| Vector3::new(p.x, p.y, p.z);
    let mut cov = Matrix3::zeros();
    let mut var_from = 0.0;
    for (f, t) in from.iter().zip(to) {
        cov += v(*t - ct) * v(*f - cf).transpose();
        var_from += (*f - cf).length_squared();
    }
    cov /= n;
    var_from /= n;
    let svd = cov.svd(true, true);
    let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * vt;
    let s = if scale { (svd.singular_values.component_mul(&d.diagonal())).sum() / var_from } else { 1.0 };
    from.iter()
        .map(|f| {
            let q = r * v(*f - cf) * s;
            ct + DVec3::new(q.x, q.y, q.z)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn align_recovers_a_rotated_scaled_shifted_copy() {
        let pts =
            [DVec3::new(1.0, 2.0, 0.5), DVec3::new(-1.5, 2.1, -1.3), DVec3::new(-1.6, -0.9, -1.4), DVec3::X];
        let q = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.1, -0.2, 0.3);
        let moved: Vec<DVec3> = pts.iter().map(|p| q * *p * 1.1 + DVec3::new(0.3, -0.2, 0.1)).collect();
        let back = align(&moved, &pts, true);
        for (b, p) in back.iter().zip(&pts) {
            assert!(b.distance(*p) < 1e-12, "{b} {p}");
        }
        // Rigid only: the 10 % scale remains, so the copy does not land on the points.
        let rigid = align(&moved, &pts, false);
        assert!(rigid.iter().zip(&pts).any(|(b, p)| b.distance(*p) > 0.05));
    }
}
