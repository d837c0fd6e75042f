//! Joint kinds and their kinematics: the joint transform `X_J(q)`, the motion subspace `S(q)` and
//! the velocity-product term `c_J = S-dot qd`, plus how each kind integrates its position.
//!
//! Coordinates (what a body's slice of `q` and `v` holds):
//! - `Free`: q = [x, y, z, qx, qy, qz, qw] (origin in the parent frame, orientation), v = [w, v]:
//!   angular velocity in the body frame, velocity of the body origin in the parent frame. The
//!   linear part is in the fixed frame so that a force-free body's coordinates do not change and
//!   equal and opposite contact forces conserve linear momentum to rounding: S = [1 0; 0 R^T].
//! - `Ball`: q = [qx, qy, qz, qw], v = angular velocity relative to the parent in the child frame.
//! - `Universal { axis1, axis2 }`: q = [a1, a2]; the child is rotated by `a1` about `axis1` then by
//!   `a2` about `axis2` (both unit axes in the joint frame at zero).
//! - `Revolute { axis }`: q = [angle].
//! - `Fixed`: no coordinates.
//!
//! Must never: allocate or panic; quaternions are renormalised when integrated.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::spatial::{quat_exp, SVec, Xform};

/// Most velocity coordinates one joint has (a free joint).
pub const MAX_JOINT_DOF: usize = 6;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum JointKind {
    Free,
    Ball,
    Universal { axis1: DVec3, axis2: DVec3 },
    Revolute { axis: DVec3 },
    Fixed,
}

impl JointKind {
    /// Number of position coordinates.
    pub fn nq(&self) -> usize {
        match self {
            JointKind::Free => 7,
            JointKind::Ball => 4,
            JointKind::Universal { .. } => 2,
            JointKind::Revolute { .. } => 1,
            JointKind::Fixed => 0,
        }
    }

    /// Number of velocity coordinates (degrees of freedom).
    pub fn nv(&self) -> usize {
        match self {
            JointKind::Free => 6,
            JointKind::Ball => 3,
            JointKind::Universal { .. } => 2,
            JointKind::Revolute { .. } => 1,
            JointKind::Fixed => 0,
        }
    }

    /// The identity configuration written into `q`.
    pub fn zero(&self, q: &mut [f64]) {
        q.fill(0.0);
        match self {
            JointKind::Free => q[6] = 1.0,
            JointKind::Ball => q[3] = 1.0,
            _ => {}
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            JointKind::Free => "free",
            JointKind::Ball => "ball",
            JointKind::Universal { .. } => "universal",
            JointKind::Revolute { .. } => "revolute",
            JointKind::Fixed => "fixed",
        }
    }
}

/// A quaternion stored as [x, y, z, w] in a coordinate slice.
#[inline]
pub fn read_quat(q: &[f64]) -> DQuat {
    DQuat::from_xyzw(q[0], q[1], q[2], q[3])
}

#[inline]
pub fn write_quat(q: &mut [f64], r: DQuat) {
    q[0] = r.x;
    q[1] = r.y;
    q[2] = r.z;
    q[3] = r.w;
}

/// What the dynamics passes need of a joint at one configuration.
#[derive(Clone, Copy, Debug, Default)]
pub struct JointMotion {
    /// Joint transform from the joint's parent-side frame to the child body frame.
    pub xj: Xform,
    /// Motion subspace columns in child coordinates; only the first `nv` are used.
    pub s: [SVec; MAX_JOINT_DOF],
    /// Joint velocity `S qd`.
    pub vj: SVec,
    /// Velocity-product term `S-dot qd`.
    pub cj: SVec,
}

/// Computes the joint's transform, subspace and velocity terms at `q`, `qd`.
#[inline]
pub fn joint_motion(kind: &JointKind, q: &[f64], qd: &[f64]) -> JointMotion {
    let mut m = JointMotion::default();
    match *kind {
        JointKind::Free => {
            let p = DVec3::new(q[0], q[1], q[2]);
            m.xj = Xform::from_pose(p, read_quat(&q[3..7]));
            let rt = m.xj.e;
            for i in 0..3 {
                m.s[i] = SVec::unit(i);
                m.s[3 + i] = SVec::new(DVec3::ZERO, rt.col(i));
            }
            let w = DVec3::new(qd[0], qd[1], qd[2]);
            let v_child = rt * DVec3::new(qd[3], qd[4], qd[5]);
            m.vj = SVec::new(w, v_child);
            // d/dt (R^T v) = -w x (R^T v) for the fixed-frame velocity v.
            m.cj = SVec::new(DVec3::ZERO, -w.cross(v_child));
        }
        JointKind::Ball => {
            m.xj = Xform::from_pose(DVec3::ZERO, read_quat(q));
            for i in 0..3 {
                m.s[i] = SVec::unit(i);
            }
            m.vj = SVec::new(DVec3::new(qd[0], qd[1], qd[2]), DVec3::ZERO);
        }
        JointKind::Universal { axis1, axis2 } => {
            let r1 = DQuat::from_axis_angle(axis1, q[0]);
            let r2 = DQuat::from_axis_angle(axis2, q[1]);
            m.xj = Xform::from_pose(DVec3::ZERO, r1 * r2);
            // The first axis seen from the child frame: R2^T a1.
            let a1c = r2.inverse() * axis1;
            m.s[0] = SVec::new(a1c, DVec3::ZERO);
            m.s[1] = SVec::new(axis2, DVec3::ZERO);
            m.vj = SVec::new(a1c * qd[0] + axis2 * qd[1], DVec3::ZERO);
            // d/dt (R2^T a1) = -(a2 qd2) x (R2^T a1).
            m.cj = SVec::new((a1c * qd[0]).cross(axis2 * qd[1]), DVec3::ZERO);
        }
        JointKind::Revolute { axis } => {
            m.xj = Xform::from_pose(DVec3::ZERO, DQuat::from_axis_angle(axis, q[0]));
            m.s[0] = SVec::new(axis, DVec3::ZERO);
            m.vj = SVec::new(axis * qd[0], DVec3::ZERO);
        }
        JointKind::Fixed => {}
    }
    m
}

/// Advances the joint's position coordinates by `h` seconds at velocity `qd` (semi-implicit
/// Euler: `qd` is the already-updated velocity).
#[inline]
pub fn integrate_position(kind: &JointKind, q: &mut [f64], qd: &[f64], h: f64) {
    match kind {
        JointKind::Free => {
            let r = read_quat(&q[3..7]);
            q[0] += qd[3] * h;
            q[1] += qd[4] * h;
            q[2] += qd[5] * h;
            let w = DVec3::new(qd[0], qd[1], qd[2]);
            write_quat(&mut q[3..7], (r * quat_exp(w * h)).normalize());
        }
        JointKind::Ball => {
            let r = read_quat(q);
            let w = DVec3::new(qd[0], qd[1], qd[2]);
            write_quat(q, (r * quat_exp(w * h)).normalize());
        }
        JointKind::Universal { .. } => {
            q[0] += qd[0] * h;
            q[1] += qd[1] * h;
        }
        JointKind::Revolute { .. } => q[0] += qd[0] * h,
        JointKind::Fixed => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// S qd equals the numerical derivative of the joint transform (universal joint, the only kind
    /// whose subspace depends on q), and c_J equals the numerical derivative of S qd.
    #[test]
    fn universal_subspace_and_bias_match_finite_differences() {
        let kind = JointKind::Universal { axis1: DVec3::X, axis2: DVec3::Y };
        let q = [0.4, -0.7];
        let qd = [1.3, -0.6];
        let h = 1e-6;
        let m0 = joint_motion(&kind, &q, &qd);
        let q1 = [q[0] + qd[0] * h, q[1] + qd[1] * h];
        let m1 = joint_motion(&kind, &q1, &qd);
        // Relative rotation over h, in the old child coordinates: E0 E1^T = R0^T R1 ~ I + [w h]x.
        let d = m0.xj.e * m1.xj.e.transpose();
        let w =
            DVec3::new(d.y_axis.z - d.z_axis.y, d.z_axis.x - d.x_axis.z, d.x_axis.y - d.y_axis.x) * 0.5 / h;
        assert!((w - m0.vj.ang).length() < 1e-5, "w {w} vs vj {}", m0.vj.ang);
        // c_J: derivative of the coordinate vector S qd with qd held constant.
        let dvj = (m1.vj.ang - m0.vj.ang) / h;
        assert!((dvj - m0.cj.ang).length() < 1e-4, "{dvj} vs {}", m0.cj.ang);
    }

    #[test]
    fn quaternion_integration_stays_unit_and_turns_at_the_right_rate() {
        let kind = JointKind::Ball;
        let mut q = [0.0, 0.0, 0.0, 1.0];
        let w = [0.0, 2.0, 0.0];
        for _ in 0..1000 {
            integrate_position(&kind, &mut q, &w, 0.001);
        }
        let r = read_quat(&q);
        assert!((r.length() - 1.0).abs() < 1e-12);
        let (axis, angle) = r.to_axis_angle();
        assert!((angle - 2.0).abs() < 1e-9 && (axis - DVec3::Y).length() < 1e-9);
    }
}
