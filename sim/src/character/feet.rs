//! The character's two feet on the floor: where the controller may put the centre of pressure,
//! and the steps that move it (steps bounded like a person's, after seed 002 section 4.2).
//!
//! The paper bounds the centre-of-pressure torque by "a reachable range for the legs". Here the
//! range is where the feet really are: each planted foot supports the centre of pressure within
//! `foot_support_m` of its centre, two planted feet everything between them (the convex hull of
//! the two disks). When the balance needs the centre of pressure outside that region, or a planted
//! foot is left beyond the legs' reach, the character steps: one foot lifts and swings to a new
//! place, which bounds
//! - how far a foot lands from the other (`step_front_max_m`, `step_back_max_m`,
//!   `step_side_max_m`, and never crossing the other foot: `step_width_min_m`),
//! - how often it can step (`swing_min_s` in the air, `stance_min_s` on the ground between steps),
//! - how fast the foot moves (`foot_speed_max_m_per_s`, averaged over the swing).
//!
//! These are the numbers of a person; they decide which pushes a character can catch by stepping
//! and which make it fall. The feet are also what the drawn skeleton stands on (the legs are
//! turned so the ankles are where these feet are; `super::legs`), so a planted foot does not slide.
//!
//! Must never: allocate, move a planted foot, or move a swinging foot faster than the bound.

use glam::DVec3;

use super::params::ControllerParams;

/// One foot: planted where it is, or swinging from `from_m` to `to_m`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Foot {
    /// Where the foot is on the floor now (world; y is the floor's height under it) (m).
    pub pos_m: DVec3,
    /// Where the swing started and where it lands (world) (m).
    pub from_m: DVec3,
    pub to_m: DVec3,
    /// Time into the swing and its length (s); `swing_s_total == 0`: planted.
    pub swing_s: f64,
    pub swing_s_total: f64,
    /// Planted but dragged along the floor since it landed (the legs could not hold it).
    pub dragged: bool,
}

impl Foot {
    #[inline]
    pub fn planted(&self) -> bool {
        self.swing_s_total == 0.0
    }

    /// Progress of the swing in [0, 1] (1 when planted).
    #[inline]
    pub fn progress(&self) -> f64 {
        if self.planted() {
            1.0
        } else {
            (self.swing_s / self.swing_s_total).min(1.0)
        }
    }

    /// Height of the foot above the floor for drawing (m): a parabola over the swing.
    #[inline]
    pub fn lift_m(&self, step_height_m: f64) -> f64 {
        if self.planted() {
            0.0
        } else {
            let s = self.progress();
            4.0 * step_height_m * s * (1.0 - s)
        }
    }
}

/// Both feet. Foot 0 is the left (the character's `+x` side), foot 1 the right.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Feet {
    pub foot: [Foot; 2],
    /// Whether the feet are on the floor under the body at all (not while fallen).
    pub placed: bool,
    /// Time since the last foot landed (s).
    pub since_land_s: f64,
    /// Steps taken so far (landed), and feet lifted.
    pub steps: u64,
    pub lifts: u64,
    /// How much the drawn legs stand on these feet, in [0, 1]: rises to 1 after the feet are
    /// placed and falls to 0 after they are released, over [`GRIP_S`], so the legs never jump
    /// between the feet and the keyframes.
    pub grip: f32,
}

/// Time the drawn legs take to hand over between the feet and the keyframes (s).
pub const GRIP_S: f64 = 0.2;

/// Which way a foot lies from the body's centre line: +1 left, -1 right.
#[inline]
pub fn side_sign(k: usize) -> f64 {
    if k == 0 {
        1.0
    } else {
        -1.0
    }
}

/// The support region: the planted feet, as a segment `a..b` (a point when `a == b`) widened by
/// `radius_m`. `None`: no foot on the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Support {
    pub a_m: DVec3,
    pub b_m: DVec3,
    pub radius_m: f64,
}

impl Support {
    /// Signed horizontal distance of `p` from the region's edge: positive outside, negative inside
    /// (how deep).
    #[inline]
    pub fn signed_distance(&self, p: DVec3) -> f64 {
        let ab = DVec3::new(self.b_m.x - self.a_m.x, 0.0, self.b_m.z - self.a_m.z);
        let ap = DVec3::new(p.x - self.a_m.x, 0.0, p.z - self.a_m.z);
        let len2 = ab.length_squared();
        let t = if len2 > 1e-12 { (ap.dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
        (ap - ab * t).length() - self.radius_m
    }

    /// The point of the region nearest `p` (horizontally; y of `p` kept) and how far `p` is
    /// outside it (0 inside).
    #[inline]
    pub fn project(&self, p: DVec3) -> (DVec3, f64) {
        let ab = DVec3::new(self.b_m.x - self.a_m.x, 0.0, self.b_m.z - self.a_m.z);
        let ap = DVec3::new(p.x - self.a_m.x, 0.0, p.z - self.a_m.z);
        let len2 = ab.length_squared();
        let t = if len2 > 1e-12 { (ap.dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
        let q = DVec3::new(self.a_m.x + ab.x * t, p.y, self.a_m.z + ab.z * t);
        let off = DVec3::new(p.x - q.x, 0.0, p.z - q.z);
        let d = off.length();
        if d <= self.radius_m {
            (p, 0.0)
        } else {
            (q + off * (self.radius_m / d), d - self.radius_m)
        }
    }
}

impl Feet {
    /// Puts both feet on the floor at `floor_y`, beside `base_m` across the heading's side axis.
    pub fn place(&mut self, p: &ControllerParams, base_m: DVec3, e_side: DVec3, floor_y: f64) {
        for k in 0..2 {
            let mut at = base_m + e_side * (side_sign(k) * p.hip_half_width_m);
            at.y = floor_y;
            self.foot[k] =
                Foot { pos_m: at, from_m: at, to_m: at, swing_s: 0.0, swing_s_total: 0.0, dragged: false };
        }
        self.placed = true;
        self.since_land_s = 0.0;
    }

    /// Lifts both feet off the floor (the character fell).
    pub fn release(&mut self) {
        self.placed = false;
    }

    /// Moves the legs' grip toward the feet (placed) or away (released) for a step of `dt_s`.
    #[inline]
    pub fn update_grip(&mut self, dt_s: f64) {
        let d = (dt_s / GRIP_S) as f32;
        self.grip = if self.placed { (self.grip + d).min(1.0) } else { (self.grip - d).max(0.0) };
    }

    /// The index of the swinging foot, if one is.
    #[inline]
    pub fn swinging(&self) -> Option<usize> {
        (0..2).find(|&k| !self.foot[k].planted())
    }

    /// A planted foot left farther than the legs reach from the body's base is dragged along the
    /// floor after it (it slides, held at the legs' reach). Returns whether a foot slid.
    pub fn drag(&mut self, p: &ControllerParams, base_m: DVec3) -> bool {
        let mut slid = false;
        for f in self.foot.iter_mut().filter(|f| f.planted()) {
            let d = horizontal(f.pos_m - base_m);
            let len = d.length();
            if len > p.leg_reach_m {
                let to = f.pos_m - d * (1.0 - p.leg_reach_m / len);
                f.pos_m = to;
                f.from_m = to;
                f.to_m = to;
                f.dragged = true;
                slid = true;
            }
        }
        slid
    }

    /// The planted feet carry the body; the support is their region.
    pub fn support(&self, p: &ControllerParams) -> Option<Support> {
        if !self.placed {
            return None;
        }
        let (l, r) = (self.foot[0].planted(), self.foot[1].planted());
        let (a, b) = match (l, r) {
            (true, true) => (self.foot[0].pos_m, self.foot[1].pos_m),
            (true, false) => (self.foot[0].pos_m, self.foot[0].pos_m),
            (false, true) => (self.foot[1].pos_m, self.foot[1].pos_m),
            (false, false) => return None,
        };
        Some(Support { a_m: a, b_m: b, radius_m: p.foot_support_m })
    }

    /// Advances a swing by `dt_s`: the landing point follows `target` (if given) no faster than
    /// the foot may move, the foot moves along a minimum-jerk path, and lands at the end.
    pub fn advance(&mut self, p: &ControllerParams, dt_s: f64, retarget: Option<DVec3>) {
        self.since_land_s += dt_s;
        let Some(k) = self.swinging() else { return };
        let f = &mut self.foot[k];
        f.swing_s += dt_s;
        let s = f.progress();
        if let (Some(t), true) = (retarget, s < 0.6) {
            let d = horizontal(t - f.to_m);
            let max = p.foot_speed_max_m_per_s * dt_s;
            let len = d.length();
            f.to_m += if len > max { d * (max / len) } else { d };
        }
        if s >= 1.0 {
            f.pos_m = f.to_m;
            f.from_m = f.to_m;
            f.swing_s = 0.0;
            f.swing_s_total = 0.0;
            f.dragged = false;
            self.since_land_s = 0.0;
            self.steps += 1;
        } else {
            let m = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
            f.pos_m = f.from_m + (f.to_m - f.from_m) * m;
        }
    }

    /// Where foot `k` may land, nearest `want`: within the step bounds from the other foot
    /// (`front`/`side` axes of the heading), on its own side of it.
    pub fn reachable(
        &self,
        p: &ControllerParams,
        k: usize,
        want: DVec3,
        e_side: DVec3,
        e_front: DVec3,
    ) -> DVec3 {
        let stance = self.foot[1 - k].pos_m;
        let d = want - stance;
        let (mut side, mut front) = (d.dot(e_side), d.dot(e_front));
        let sgn = side_sign(k);
        side = (side * sgn).clamp(p.step_width_min_m, p.step_side_max_m) * sgn;
        front = front.clamp(-p.step_back_max_m, p.step_front_max_m);
        let mut at = stance + e_side * side + e_front * front;
        at.y = stance.y;
        at
    }

    /// Starts a swing of foot `k` to `to_m`; its length follows the bounds (never shorter than
    /// `swing_min_s`, never faster than `foot_speed_max_m_per_s` on average).
    pub fn lift(&mut self, p: &ControllerParams, k: usize, to_m: DVec3, slow: bool) {
        let f = &mut self.foot[k];
        let dist = horizontal(to_m - f.pos_m).length();
        let speed = if slow { p.foot_speed_max_m_per_s * 0.5 } else { p.foot_speed_max_m_per_s };
        let t = (dist / speed).max(if slow { p.swing_min_s * 1.4 } else { p.swing_min_s });
        f.from_m = f.pos_m;
        f.to_m = to_m;
        f.swing_s = 0.0;
        f.swing_s_total = t;
        f.dragged = false;
        self.lifts += 1;
    }
}

#[inline]
pub fn horizontal(v: DVec3) -> DVec3 {
    DVec3::new(v.x, 0.0, v.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn support_projects_onto_the_hull_of_two_disks() {
        let s = Support { a_m: DVec3::new(-0.1, 0.0, 0.0), b_m: DVec3::new(0.1, 0.0, 0.0), radius_m: 0.05 };
        assert_eq!(s.project(DVec3::new(0.05, 0.0, 0.02)).1, 0.0);
        let (q, out) = s.project(DVec3::new(0.0, 0.0, 0.25));
        assert!((q - DVec3::new(0.0, 0.0, 0.05)).length() < 1e-12 && (out - 0.2).abs() < 1e-12);
        let (q, out) = s.project(DVec3::new(0.4, 0.0, 0.0));
        assert!((q - DVec3::new(0.15, 0.0, 0.0)).length() < 1e-12 && (out - 0.25).abs() < 1e-12);
    }

    #[test]
    fn a_swing_lands_where_aimed_within_the_speed_bound() {
        let p = ControllerParams::default();
        let mut f = Feet::default();
        f.place(&p, DVec3::ZERO, DVec3::X, 0.0);
        let to = f.reachable(&p, 1, DVec3::new(0.0, 0.0, 2.0), DVec3::X, DVec3::Z);
        assert!((to.z - f.foot[0].pos_m.z - p.step_front_max_m).abs() < 1e-12, "{to}");
        f.lift(&p, 1, to, false);
        let mut last = f.foot[1].pos_m;
        let mut fastest: f64 = 0.0;
        let dt = 0.003;
        while f.swinging().is_some() {
            f.advance(&p, dt, None);
            fastest = fastest.max((f.foot[1].pos_m - last).length() / dt);
            last = f.foot[1].pos_m;
        }
        assert_eq!(f.foot[1].pos_m, to);
        assert_eq!(f.steps, 1);
        // Minimum jerk peaks at 1.875 times the mean speed.
        assert!(fastest <= 1.9 * p.foot_speed_max_m_per_s, "{fastest}");
    }
}
