//! The rigid-body space R = {r, theta, r-dot, theta-dot} of a single-rigid-body character (seed 002,
//! section 4.1): where its centre of mass is, how far it leans and which way it faces.
//!
//! Frames: `S_r` is the body frame (`e_yr` up the trunk, `e_zr` the character's front). `S_c` is the
//! heading frame: `e_yc` is the world up and `e_xc`, `e_zc` lie in the floor, turned by the body's
//! heading `theta_y` (the twist of the body's orientation about the world vertical, so the rest of
//! the orientation is a pure lean). The world `e_z` is the reference of the heading.
//!
//! The paper writes `sin theta_x = e_yr . e_xc` and `sin theta_z = e_yr . e_zc`, but its equations of
//! motion (3, 5) pair `theta_x` with travel along `e_zc` and its keyframe set puts the front-back
//! fall in the `theta_z = 0` plane with `theta_x` in [-pi, pi]. Those only fit `theta_x` being the
//! lean toward the front (`sin theta_x = e_yr . e_zc`, extended to [-pi, pi] with `e_yr . e_yc` so a
//! character lying face down is at +pi/2 and face up at -pi/2) and `theta_z` the lean to the side
//! (`sin theta_z = e_yr . e_xc`, in [-pi/2, pi/2]). That is what is used here.
//!
//! Must never: allocate, or produce NaN for any unit orientation (the upside-down heading falls back
//! to the world frame).

use glam::{DQuat, DVec3};

/// The heading frame `S_c` (rotation about the world vertical by `theta_y`).
///
/// Kept as its two axes; the angle is computed only where asked for ([`Heading::theta_y`]): the
/// controller works with the axes, and an `atan2` per character per step was a tenth of a crowd
/// step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Heading {
    pub e_xc: DVec3,
    pub e_zc: DVec3,
}

impl Heading {
    pub fn from_angle(theta_y: f64) -> Heading {
        let (s, c) = theta_y.sin_cos();
        // Rotation about +y by theta_y: z -> (sin, 0, cos), x -> (cos, 0, -sin).
        Heading { e_xc: DVec3::new(c, 0.0, -s), e_zc: DVec3::new(s, 0.0, c) }
    }

    /// Heading angle `theta_y` (rad), in [-pi, pi]: 0 faces world +z, positive turns toward +x.
    #[inline]
    pub fn theta_y(&self) -> f64 {
        self.e_zc.x.atan2(self.e_zc.z)
    }

    /// Angle (rad, in [-pi, pi]) from this heading to the horizontal direction `dir` (any
    /// length), positive toward `+e_xc`: `theta_y(dir) - theta_y` wrapped, with one `atan2`.
    #[inline]
    pub fn angle_to(&self, dir: DVec3) -> f64 {
        dir.dot(self.e_xc).atan2(dir.dot(self.e_zc))
    }

    /// The twist of `rot` about the world vertical.
    pub fn of(rot: DQuat) -> Heading {
        let n = (rot.y * rot.y + rot.w * rot.w).sqrt();
        if n < 1e-9 {
            return Heading::from_angle(0.0);
        }
        // Half-angle cosine and sine of the twist give the axes without more trigonometry.
        let (c, s) = (rot.w / n, rot.y / n);
        let (sin, cos) = (2.0 * s * c, c * c - s * s);
        Heading { e_xc: DVec3::new(cos, 0.0, -sin), e_zc: DVec3::new(sin, 0.0, cos) }
    }

    /// World horizontal vector from heading-frame components (x: side, z: front).
    #[inline]
    pub fn to_world(&self, side: f64, front: f64) -> DVec3 {
        self.e_xc * side + self.e_zc * front
    }
}

/// A point of the rigid-body space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodySpace {
    /// Centre of mass in the world (m).
    pub r_m: DVec3,
    /// Centre-of-mass velocity in the world (m/s).
    pub r_dot_m_per_s: DVec3,
    /// Lean toward the front, [-pi, pi] (rad).
    pub theta_x: f64,
    /// Lean toward the side `+e_xc`, [-pi/2, pi/2] (rad).
    pub theta_z: f64,
    /// Sine and cosine of `theta_x` and `theta_z`, from the trunk axis (the controller's pendulum
    /// needs them; taking them from the vectors saves a `sin_cos` per lean).
    pub sin_cos_x: (f64, f64),
    pub sin_cos_z: (f64, f64),
    /// Rates of the three angles (rad/s): `theta_x`, `theta_z` from the angular velocity about
    /// `e_xc` and `-e_zc`, `theta_y` about the vertical.
    pub theta_x_dot: f64,
    pub theta_y_dot: f64,
    pub theta_z_dot: f64,
    pub heading: Heading,
    /// The body's axes in the world: `e_yr` up the trunk, `e_xr` its left, `e_zr` its front.
    pub e_yr: DVec3,
    pub e_xr: DVec3,
    pub e_zr: DVec3,
    /// Angular velocity (world, rad/s).
    pub w_world: DVec3,
}

impl BodySpace {
    /// From the body's pose (`rot`: body -> world), its centre of mass, the world velocity of the
    /// centre of mass and the world angular velocity.
    pub fn new(rot: DQuat, com_m: DVec3, com_vel_m_per_s: DVec3, w_world: DVec3) -> BodySpace {
        let heading = Heading::of(rot);
        let e_yr = rot * DVec3::Y;
        let (sx, sz, cy) = (e_yr.dot(heading.e_zc), e_yr.dot(heading.e_xc), e_yr.y);
        // theta_x = atan2(sx, cy): its sine and cosine are sx and cy over their length.
        let hx = (sx * sx + cy * cy).sqrt();
        let sin_cos_x = if hx > 0.0 { (sx / hx, cy / hx) } else { (0.0, 1.0) };
        // theta_z = asin(sz): its cosine is the other leg, never negative.
        let sz = sz.clamp(-1.0, 1.0);
        BodySpace {
            r_m: com_m,
            r_dot_m_per_s: com_vel_m_per_s,
            theta_x: sx.atan2(cy),
            theta_z: sz.asin(),
            sin_cos_x,
            sin_cos_z: (sz, (1.0 - sz * sz).max(0.0).sqrt()),
            // Rotation about +e_xc moves e_yr toward +e_zc; about -e_zc toward +e_xc.
            theta_x_dot: w_world.dot(heading.e_xc),
            theta_y_dot: w_world.y,
            theta_z_dot: -w_world.dot(heading.e_zc),
            heading,
            e_yr,
            e_xr: rot * DVec3::X,
            e_zr: rot * DVec3::Z,
            w_world,
        }
    }

    /// Horizontal velocity in the heading frame: (side, front).
    #[inline]
    pub fn velocity_sc(&self) -> (f64, f64) {
        (self.r_dot_m_per_s.dot(self.heading.e_xc), self.r_dot_m_per_s.dot(self.heading.e_zc))
    }

    /// Heading `theta_y` (rad), in [-pi, pi].
    #[inline]
    pub fn theta_y(&self) -> f64 {
        self.heading.theta_y()
    }

    /// Angle of the trunk from the vertical (rad), in [0, pi].
    #[inline]
    pub fn tilt(&self) -> f64 {
        self.e_yr.y.clamp(-1.0, 1.0).acos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }

    #[test]
    fn leans_and_heading_follow_the_definitions() {
        // Turned 0.7 rad, then leaning 0.3 rad to the front: theta_x 0.3, theta_z 0, heading 0.7.
        let yaw = DQuat::from_rotation_y(0.7);
        let b = BodySpace::new(yaw * DQuat::from_rotation_x(0.3), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        close(b.theta_x, 0.3);
        close(b.theta_z, 0.0);
        close(b.theta_y(), 0.7);
        close(b.sin_cos_x.0, 0.3f64.sin());
        close(b.sin_cos_x.1, 0.3f64.cos());
        // Lying face down (head toward the front) is +pi/2, face up -pi/2.
        let b = BodySpace::new(
            yaw * DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2),
            DVec3::ZERO,
            DVec3::ZERO,
            DVec3::ZERO,
        );
        close(b.theta_x, std::f64::consts::FRAC_PI_2);
        close(b.theta_y(), 0.7);
        // Leaning toward +x_c: rotation about -z.
        let b = BodySpace::new(yaw * DQuat::from_rotation_z(-0.4), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        close(b.theta_z, 0.4);
        close(b.theta_x, 0.0);
        close(b.sin_cos_z.0, 0.4f64.sin());
        close(b.sin_cos_z.1, 0.4f64.cos());
        // The angle to a direction is the wrapped difference of headings.
        close(
            Heading::from_angle(3.0).angle_to(Heading::from_angle(-3.0).e_zc * 2.0),
            std::f64::consts::TAU - 6.0,
        );
        // Rates: spinning about e_xc raises theta_x.
        let h = Heading::from_angle(0.7);
        let b = BodySpace::new(yaw, DVec3::ZERO, DVec3::ZERO, h.e_xc * 2.0 - h.e_zc * 3.0 + DVec3::Y);
        close(b.theta_x_dot, 2.0);
        close(b.theta_z_dot, 3.0);
        close(b.theta_y_dot, 1.0);
    }

    #[test]
    fn upside_down_is_finite() {
        let b = BodySpace::new(
            DQuat::from_rotation_x(std::f64::consts::PI),
            DVec3::ZERO,
            DVec3::ZERO,
            DVec3::ZERO,
        );
        assert!(b.theta_x.is_finite() && b.theta_y().is_finite() && b.theta_z.is_finite());
    }
}
