//! Spatial (6-D) vector algebra in Featherstone's Plücker notation, on glam f64 types.
//!
//! Why it exists: every dynamics algorithm in this crate (ABA, RNEA, CRBA) is written in terms of
//! spatial motion vectors, force vectors, Plücker transforms and 6x6 inertias. Each is stored as
//! 3-D blocks rather than a dense 6x6 so the arithmetic skips the known zeros.
//!
//! Conventions (Featherstone, *Rigid Body Dynamics Algorithms*, ch. 2):
//! - a motion vector is `(w, v)`: angular velocity and the velocity of the body point that is at
//!   the frame's origin; a force vector is `(n, f)`: moment about the origin and force.
//! - `Xform { e, r }` is the transform from frame A to frame B, where `e` rotates A coordinates into
//!   B coordinates and `r` is B's origin in A coordinates: `X = [E 0; -E rx E]`.
//!
//! Must never: allocate or branch on data (these run in the inner loop of every step).

use glam::{DMat3, DQuat, DVec3};
use std::ops::{Add, AddAssign, Mul, Neg, Sub, SubAssign};

/// The 3x3 cross-product matrix: `skew(a) * b == a.cross(b)`.
#[inline]
pub fn skew(a: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, a.z, -a.y), DVec3::new(-a.z, 0.0, a.x), DVec3::new(a.y, -a.x, 0.0))
}

/// A spatial motion or force vector; which one it is follows from how it is used.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SVec {
    /// Angular part (w for motion, n for force).
    pub ang: DVec3,
    /// Linear part (v for motion, f for force).
    pub lin: DVec3,
}

impl SVec {
    pub const ZERO: SVec = SVec { ang: DVec3::ZERO, lin: DVec3::ZERO };

    #[inline]
    pub const fn new(ang: DVec3, lin: DVec3) -> Self {
        SVec { ang, lin }
    }

    /// Scalar product of a motion and a force vector (power).
    #[inline]
    pub fn dot(self, o: SVec) -> f64 {
        self.ang.dot(o.ang) + self.lin.dot(o.lin)
    }

    /// Motion cross motion: `self x m` (crm).
    #[inline]
    pub fn cross_motion(self, m: SVec) -> SVec {
        SVec { ang: self.ang.cross(m.ang), lin: self.ang.cross(m.lin) + self.lin.cross(m.ang) }
    }

    /// Motion cross force: `self x* f` (crf).
    #[inline]
    pub fn cross_force(self, f: SVec) -> SVec {
        SVec { ang: self.ang.cross(f.ang) + self.lin.cross(f.lin), lin: self.ang.cross(f.lin) }
    }

    /// Component `i` (0..3 angular, 3..6 linear).
    #[inline]
    pub fn get(&self, i: usize) -> f64 {
        if i < 3 {
            self.ang[i]
        } else {
            self.lin[i - 3]
        }
    }

    /// Unit vector along component `i`.
    #[inline]
    pub fn unit(i: usize) -> SVec {
        let mut s = SVec::ZERO;
        if i < 3 {
            s.ang[i] = 1.0;
        } else {
            s.lin[i - 3] = 1.0;
        }
        s
    }

    pub fn is_finite(&self) -> bool {
        self.ang.is_finite() && self.lin.is_finite()
    }
}

impl Add for SVec {
    type Output = SVec;
    #[inline]
    fn add(self, o: SVec) -> SVec {
        SVec { ang: self.ang + o.ang, lin: self.lin + o.lin }
    }
}
impl Sub for SVec {
    type Output = SVec;
    #[inline]
    fn sub(self, o: SVec) -> SVec {
        SVec { ang: self.ang - o.ang, lin: self.lin - o.lin }
    }
}
impl Neg for SVec {
    type Output = SVec;
    #[inline]
    fn neg(self) -> SVec {
        SVec { ang: -self.ang, lin: -self.lin }
    }
}
impl Mul<f64> for SVec {
    type Output = SVec;
    #[inline]
    fn mul(self, s: f64) -> SVec {
        SVec { ang: self.ang * s, lin: self.lin * s }
    }
}
impl AddAssign for SVec {
    #[inline]
    fn add_assign(&mut self, o: SVec) {
        self.ang += o.ang;
        self.lin += o.lin;
    }
}
impl SubAssign for SVec {
    #[inline]
    fn sub_assign(&mut self, o: SVec) {
        self.ang -= o.ang;
        self.lin -= o.lin;
    }
}

/// Plücker transform from frame A to frame B (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Xform {
    /// Rotation taking A coordinates to B coordinates.
    pub e: DMat3,
    /// B's origin in A coordinates.
    pub r: DVec3,
}

impl Default for Xform {
    fn default() -> Self {
        Xform::IDENTITY
    }
}

impl Xform {
    pub const IDENTITY: Xform = Xform { e: DMat3::IDENTITY, r: DVec3::ZERO };

    /// Frame B is frame A rotated by `q` (B's axes expressed in A are the columns of `q`'s matrix)
    /// and moved to `origin` (in A).
    #[inline]
    pub fn from_pose(origin: DVec3, q: DQuat) -> Xform {
        Xform { e: DMat3::from_quat(q).transpose(), r: origin }
    }

    /// Pure translation: B's origin at `r` in A, same orientation.
    #[inline]
    pub fn translation(r: DVec3) -> Xform {
        Xform { e: DMat3::IDENTITY, r }
    }

    /// Motion vector in A coordinates -> B coordinates.
    #[inline]
    pub fn apply_motion(&self, m: SVec) -> SVec {
        SVec { ang: self.e * m.ang, lin: self.e * (m.lin - self.r.cross(m.ang)) }
    }

    /// Force vector in A coordinates -> B coordinates.
    #[inline]
    pub fn apply_force(&self, f: SVec) -> SVec {
        SVec { ang: self.e * (f.ang - self.r.cross(f.lin)), lin: self.e * f.lin }
    }

    /// Motion vector in B coordinates -> A coordinates (`X^-1 m`).
    #[inline]
    pub fn inv_apply_motion(&self, m: SVec) -> SVec {
        let ang = self.e.transpose() * m.ang;
        SVec { ang, lin: self.e.transpose() * m.lin + self.r.cross(ang) }
    }

    /// Force vector in B coordinates -> A coordinates (`X^T f`).
    #[inline]
    pub fn inv_apply_force(&self, f: SVec) -> SVec {
        let lin = self.e.transpose() * f.lin;
        SVec { ang: self.e.transpose() * f.ang + self.r.cross(lin), lin }
    }

    /// `self * a`: first `a` (A -> B), then `self` (B -> C), giving A -> C.
    #[inline]
    pub fn compose(&self, a: &Xform) -> Xform {
        Xform { e: self.e * a.e, r: a.r + a.e.transpose() * self.r }
    }

    /// The inverse transform (B -> A).
    #[inline]
    pub fn inverse(&self) -> Xform {
        Xform { e: self.e.transpose(), r: -(self.e * self.r) }
    }

    /// A point given in B coordinates, expressed in A coordinates.
    #[inline]
    pub fn point_to_parent(&self, p: DVec3) -> DVec3 {
        self.r + self.e.transpose() * p
    }
}

/// A symmetric spatial inertia (rigid-body or articulated) as 3x3 blocks:
/// `I = [a b; b^T c]`, so `I (w, v) = (a w + b v, b^T w + c v)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SInertia {
    pub a: DMat3,
    pub b: DMat3,
    pub c: DMat3,
}

impl Default for SInertia {
    fn default() -> Self {
        SInertia::ZERO
    }
}

impl SInertia {
    pub const ZERO: SInertia = SInertia { a: DMat3::ZERO, b: DMat3::ZERO, c: DMat3::ZERO };

    /// Rigid body of `mass_kg` with its centre of mass at `com_m` and rotational inertia `i_com`
    /// about the centre of mass, all in the body frame.
    pub fn rigid(mass_kg: f64, com_m: DVec3, i_com: DMat3) -> SInertia {
        let cx = skew(com_m);
        SInertia {
            a: i_com - mass_kg * cx * cx,
            b: mass_kg * cx,
            c: DMat3::from_diagonal(DVec3::splat(mass_kg)),
        }
    }

    /// `I m` for a motion vector `m`, giving a force vector.
    #[inline]
    pub fn mul_motion(&self, m: SVec) -> SVec {
        SVec { ang: self.a * m.ang + self.b * m.lin, lin: self.b.transpose() * m.ang + self.c * m.lin }
    }

    /// `X^T I X`: this inertia, given in B coordinates, expressed in A coordinates.
    #[inline]
    pub fn to_parent(&self, x: &Xform) -> SInertia {
        let et = x.e.transpose();
        let a1 = et * self.a * x.e;
        let b1 = et * self.b * x.e;
        let c1 = et * self.c * x.e;
        let r = x.r;
        let b1t = b1.transpose();
        let rx_c1 = skew_mul(r, &c1);
        SInertia { a: a1 - mul_skew(&b1, r) + skew_mul(r, &b1t) - mul_skew(&rx_c1, r), b: b1 + rx_c1, c: c1 }
    }

    /// `self -= x y^T` by blocks (callers keep the total symmetric, e.g. `sum_k (U D^-1)_k U_k^T`).
    #[inline]
    pub fn sub_outer(&mut self, x: SVec, y: SVec) {
        self.a -= outer(x.ang, y.ang);
        self.b -= outer(x.ang, y.lin);
        self.c -= outer(x.lin, y.lin);
    }
}

impl Add for SInertia {
    type Output = SInertia;
    #[inline]
    fn add(self, o: SInertia) -> SInertia {
        SInertia { a: self.a + o.a, b: self.b + o.b, c: self.c + o.c }
    }
}
impl AddAssign for SInertia {
    #[inline]
    fn add_assign(&mut self, o: SInertia) {
        self.a += o.a;
        self.b += o.b;
        self.c += o.c;
    }
}

/// `m * skew(r)` without the products by the skew matrix's zeros. glam's product sums the three
/// column terms in order; dropping a term that is `x * 0 = ±0` leaves every nonzero sum's bits
/// unchanged, so this is `m * skew(r)` to the bit (up to the sign of an exact zero).
#[inline]
fn mul_skew(m: &DMat3, r: DVec3) -> DMat3 {
    let (x, y, z) = (m.x_axis, m.y_axis, m.z_axis);
    // skew(r) columns: (0, rz, -ry), (-rz, 0, rx), (ry, -rx, 0).
    DMat3::from_cols(y * r.z + z * (-r.y), x * (-r.z) + z * r.x, x * r.y + y * (-r.x))
}

/// `skew(r) * m` without the products by the skew matrix's zeros (same argument as `mul_skew`).
#[inline]
fn skew_mul(r: DVec3, m: &DMat3) -> DMat3 {
    let col =
        |c: DVec3| DVec3::new((-r.z) * c.y + r.y * c.z, r.z * c.x + (-r.x) * c.z, (-r.y) * c.x + r.x * c.y);
    DMat3::from_cols(col(m.x_axis), col(m.y_axis), col(m.z_axis))
}

/// `x y^T`.
#[inline]
pub fn outer(x: DVec3, y: DVec3) -> DMat3 {
    DMat3::from_cols(x * y.x, x * y.y, x * y.z)
}

/// Rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion.
#[inline]
pub fn quat_log(q: DQuat) -> DVec3 {
    let q = if q.w < 0.0 { -q } else { q };
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    if s < 1e-12 {
        return v * 2.0;
    }
    let angle = 2.0 * s.atan2(q.w);
    v * (angle / s)
}

/// Unit quaternion of a rotation vector.
#[inline]
pub fn quat_exp(rv: DVec3) -> DQuat {
    let angle = rv.length();
    if angle < 1e-12 {
        return DQuat::from_xyzw(rv.x * 0.5, rv.y * 0.5, rv.z * 0.5, 1.0).normalize();
    }
    DQuat::from_axis_angle(rv / angle, angle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn v3() -> impl Strategy<Value = DVec3> {
        (-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64).prop_map(|(x, y, z)| DVec3::new(x, y, z))
    }
    fn quat() -> impl Strategy<Value = DQuat> {
        (v3(), 0.0..3.1f64).prop_map(|(a, t)| {
            let a = if a.length() < 1e-3 { DVec3::X } else { a.normalize() };
            DQuat::from_axis_angle(a, t)
        })
    }
    fn svec() -> impl Strategy<Value = SVec> {
        (v3(), v3()).prop_map(|(a, l)| SVec::new(a, l))
    }
    fn close(a: SVec, b: SVec) -> bool {
        (a - b).ang.length() < 1e-9 && (a - b).lin.length() < 1e-9
    }

    proptest! {
        /// Power is frame-invariant: (X m) . (X^-T f) == m . f.
        #[test]
        fn power_is_invariant_under_transforms(q in quat(), r in v3(), m in svec(), f in svec()) {
            let x = Xform::from_pose(r, q);
            let p0 = m.dot(f);
            let p1 = x.apply_motion(m).dot(x.apply_force(f));
            prop_assert!((p0 - p1).abs() < 1e-9);
        }

        #[test]
        fn inverse_and_compose_agree(q1 in quat(), r1 in v3(), q2 in quat(), r2 in v3(), m in svec(), f in svec()) {
            let a = Xform::from_pose(r1, q1);
            let b = Xform::from_pose(r2, q2);
            prop_assert!(close(a.inv_apply_motion(a.apply_motion(m)), m));
            prop_assert!(close(a.inv_apply_force(a.apply_force(f)), f));
            prop_assert!(close(a.inverse().apply_motion(m), a.inv_apply_motion(m)));
            prop_assert!(close(b.compose(&a).apply_motion(m), b.apply_motion(a.apply_motion(m))));
            prop_assert!(close(b.compose(&a).apply_force(f), b.apply_force(a.apply_force(f))));
        }

        /// X^T I X computed by blocks equals transforming the force I (X m) back.
        #[test]
        fn inertia_transform_matches_definition(q in quat(), r in v3(), c in v3(), m in svec(), mass in 0.1..10.0f64) {
            let i = SInertia::rigid(mass, c * 0.3, DMat3::from_diagonal(DVec3::new(0.1, 0.2, 0.3)));
            let x = Xform::from_pose(r, q);
            let direct = x.inv_apply_force(i.mul_motion(x.apply_motion(m)));
            prop_assert!(close(i.to_parent(&x).mul_motion(m), direct));
        }

        /// The rigid-body inertia gives the kinetic energy 1/2 m |v_c|^2 + 1/2 w.Ic w.
        #[test]
        fn rigid_inertia_energy(c in v3(), m in svec(), mass in 0.1..10.0f64) {
            let ic = DMat3::from_diagonal(DVec3::new(0.1, 0.2, 0.3));
            let i = SInertia::rigid(mass, c, ic);
            let vc = m.lin + m.ang.cross(c);
            let e = 0.5 * mass * vc.length_squared() + 0.5 * m.ang.dot(ic * m.ang);
            prop_assert!((0.5 * m.dot(i.mul_motion(m)) - e).abs() < 1e-9 * (1.0 + e));
        }

        #[test]
        fn quat_log_exp_round_trip(q in quat()) {
            let back = quat_exp(quat_log(q));
            prop_assert!(back.dot(q).abs() > 1.0 - 1e-12);
        }
    }

    /// The skew products drop only products by zero: they equal glam's full products to the bit.
    #[test]
    fn skew_products_are_the_full_products_to_the_bit() {
        let m = DMat3::from_cols(
            DVec3::new(0.31, -1.7, 2.9),
            DVec3::new(1.1e-3, 0.77, -0.4),
            DVec3::new(-5.5, 0.123, 3.3e2),
        );
        let r = DVec3::new(0.137, -0.291, 0.0833);
        assert_eq!(mul_skew(&m, r), m * skew(r));
        assert_eq!(skew_mul(r, &m), skew(r) * m);
    }

    #[test]
    fn cross_products_match_their_duality() {
        // (v x m) . f == -m . (v x* f)
        let v = SVec::new(DVec3::new(0.3, -1.0, 2.0), DVec3::new(1.0, 0.5, -0.2));
        let m = SVec::new(DVec3::new(-0.7, 0.1, 0.4), DVec3::new(0.2, 2.0, 1.0));
        let f = SVec::new(DVec3::new(1.1, -0.3, 0.9), DVec3::new(-2.0, 0.4, 0.6));
        assert!((v.cross_motion(m).dot(f) + m.dot(v.cross_force(f))).abs() < 1e-12);
    }
}
