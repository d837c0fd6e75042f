//! Reaching motions (seed 000, appendix): a spring-damper between a part of the virtual human and
//! a target point whose natural length shrinks along the minimum-jerk profile, so the part moves
//! with the bell-shaped speed of human reaching while the joints' own springs and the body's
//! dynamics shape the motion. The equal and opposite force is applied at the body's centre of
//! mass, so the reaching force is internal: it bends the body, it does not push it around.
//!
//! Must never: allocate, or leave a non-finite force in the workspace (a degenerate reach, part
//! already at the target, applies nothing).

use glam::DVec3;

use crate::model::Model;
use crate::state::Workspace;

/// Minimum-jerk progress s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, tau clamped to [0, 1].
pub fn min_jerk(tau: f64) -> f64 {
    let t = tau.clamp(0.0, 1.0);
    t * t * t * (10.0 + t * (-15.0 + 6.0 * t))
}

/// d s / d tau of [`min_jerk`] (0 outside [0, 1]).
pub fn min_jerk_rate(tau: f64) -> f64 {
    if !(0.0..=1.0).contains(&tau) {
        return 0.0;
    }
    30.0 * tau * tau * (1.0 - tau) * (1.0 - tau)
}

/// One reaching motion of one body toward a fixed world point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// The moving body (hand, forearm, head or chest).
    pub body: usize,
    /// The point of the body the spring pulls, in the body's frame (its centre of mass).
    pub point_body_m: DVec3,
    /// Target point (world).
    pub target_m: DVec3,
    /// Where the point was when the motion this reach belongs to began (world): a dodge that is
    /// re-aimed keeps the place it left from.
    pub home_m: DVec3,
    /// Simulated time the reach started.
    pub start_s: f64,
    pub duration_s: f64,
    /// Distance from the part to the target at the start: the spring's initial natural length.
    pub l0_m: f64,
    /// Where the point was when this reach started (world).
    pub from_m: DVec3,
    /// The spring pulls the point toward where the straight path from `from_m` has got to
    /// (minimum-jerk in time), in every direction ([`Reach::tracking`]); otherwise it is the
    /// paper's spring along the line to the target, whose natural length shrinks.
    pub track: bool,
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
}

impl Reach {
    /// A reach of `body` to `target_m` starting now (`ws` holds the current kinematics).
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        model: &Model,
        ws: &Workspace,
        body: usize,
        target_m: DVec3,
        now_s: f64,
        duration_s: f64,
        k_n_per_m: f64,
        d_n_s_per_m: f64,
    ) -> Reach {
        let point_body_m = model.bodies[body].com_m;
        let home_m = ws.point_world(body, point_body_m);
        let l0_m = (target_m - home_m).length();
        Reach {
            body,
            point_body_m,
            target_m,
            home_m,
            start_s: now_s,
            duration_s: duration_s.max(1e-3),
            l0_m,
            from_m: home_m,
            track: false,
            k_n_per_m,
            d_n_s_per_m,
        }
    }

    /// The same reach, tracking its straight path: the paper's spring acts only along the line
    /// to the target, so whatever else pulls on the body (its joints' springs after a dodge)
    /// swings the part freely around the target, at any speed; tracking holds it on the path at
    /// the minimum-jerk pace.
    pub fn tracking(self) -> Reach {
        Reach { track: true, ..self }
    }

    pub fn tau(&self, t_s: f64) -> f64 {
        (t_s - self.start_s) / self.duration_s
    }

    /// The spring's natural length: l0 (1 - s(tau)), shrinking to zero (docs/reference.md section 6: the
    /// paper prints the growing form; the lab code shrinks).
    pub fn natural_length_m(&self, t_s: f64) -> f64 {
        self.l0_m * (1.0 - min_jerk(self.tau(t_s)))
    }

    /// True once the natural length has shrunk to zero (the spring then holds the part there).
    pub fn done(&self, t_s: f64) -> bool {
        self.tau(t_s) >= 1.0
    }

    /// Adds the reaching force to `body` and the opposite force at the centre of mass of the
    /// articulation (applied to its root body there). Returns the force on the part.
    pub fn apply(&self, model: &Model, ws: &mut Workspace, t_s: f64) -> DVec3 {
        let p = ws.point_world(self.body, self.point_body_m);
        if self.track {
            let tau = self.tau(t_s);
            let path = self.target_m - self.from_m;
            let at = self.from_m + path * min_jerk(tau);
            let rate = path * (min_jerk_rate(tau) / self.duration_s);
            let v = ws.point_velocity(self.body, self.point_body_m);
            let f = (at - p) * self.k_n_per_m + (rate - v) * self.d_n_s_per_m;
            if !f.is_finite() {
                return DVec3::ZERO;
            }
            return self.push(model, ws, p, f);
        }
        let d = self.target_m - p;
        let dist = d.length();
        if !(dist > 1e-9) {
            return DVec3::ZERO;
        }
        let u = d / dist;
        let l = self.natural_length_m(t_s);
        let l_rate = -self.l0_m * min_jerk_rate(self.tau(t_s)) / self.duration_s;
        // Extension and its rate: the target is fixed, so d|d|/dt = -v . u.
        let v = ws.point_velocity(self.body, self.point_body_m);
        let ext = dist - l;
        let ext_rate = -v.dot(u) - l_rate;
        let f = u * (self.k_n_per_m * ext + self.d_n_s_per_m * ext_rate);
        if !f.is_finite() {
            return DVec3::ZERO;
        }
        self.push(model, ws, p, f)
    }

    /// Adds `f` at the point `p` of the body and the opposite force at the articulation's centre
    /// of mass; returns `f`.
    fn push(&self, model: &Model, ws: &mut Workspace, p: DVec3, f: DVec3) -> DVec3 {
        ws.add_force_at(self.body, p, f);
        let art = model.bodies[self.body].articulation;
        let root = model.articulations[art].bodies.start;
        let com = articulation_com(model, ws, art);
        ws.add_force_at(root, com, -f);
        f
    }
}

/// Centre of mass of one articulation (world; `ws` holds its kinematics).
pub fn articulation_com(model: &Model, ws: &Workspace, articulation: usize) -> DVec3 {
    let a = &model.articulations[articulation];
    let mut sum = DVec3::ZERO;
    for b in a.bodies.clone() {
        sum += ws.com_world(model, b) * model.bodies[b].mass_kg;
    }
    sum / a.mass_kg
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn min_jerk_runs_from_zero_to_one_with_zero_end_speeds() {
        assert_eq!(min_jerk(0.0), 0.0);
        assert!((min_jerk(1.0) - 1.0).abs() < 1e-12);
        assert!((min_jerk(0.5) - 0.5).abs() < 1e-12);
        assert_eq!(min_jerk_rate(0.0), 0.0);
        assert_eq!(min_jerk_rate(1.0), 0.0);
        assert!((min_jerk_rate(0.5) - 1.875).abs() < 1e-12);
        // The rate is the derivative of the profile.
        let h = 1e-6;
        for tau in [0.1, 0.3, 0.7, 0.9] {
            let num = (min_jerk(tau + h) - min_jerk(tau - h)) / (2.0 * h);
            assert!((num - min_jerk_rate(tau)).abs() < 1e-6);
        }
    }
}
