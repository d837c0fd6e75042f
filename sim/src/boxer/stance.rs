//! The virtual human's stance: where its legs hold its waist. The body model is an upper body
//! whose free root (the waist) a base spring holds at a home pose; that spring stands for the
//! legs. A reach is a force inside the body (it pushes a part and pulls the body's centre of mass
//! the other way), so no reach can keep the base spring from bringing the whole body back to its
//! home: after a lean back or a punch that lifted it, the body would spring back toward a fist
//! that is still out. A boxer moves his feet instead: while a fist comes or a defence is under
//! way the stance follows the waist wherever that does not bring it toward a fist, and steps back
//! to its place only once no fist comes.
//!
//! The model's home pose is never changed (the prediction shares the model): a stance away from
//! the place is the base spring's force toward the stance minus its force toward the place, a
//! constant force on the root, `K (home - place)` (the spring is linear in position).
//!
//! Must never: allocate, or pull the waist toward a fist while following.

use glam::{DMat3, DVec3};

use crate::model::Model;
use crate::state::Workspace;

/// Where the base spring of the virtual human's waist holds it (world frame, the root's origin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stance {
    /// The waist's place in the scene: the model's home pose of the root.
    pub place_m: DVec3,
    /// Where the stance holds the waist now.
    pub home_m: DVec3,
    /// The base spring's linear stiffness in world axes (N/m).
    k: DMat3,
    root: usize,
}

impl Stance {
    /// The stance of the articulation whose free root is `root`, at its place.
    pub fn new(model: &Model, root: usize) -> Stance {
        let b = &model.bodies[root];
        let q = &model.q_default[b.q_at..b.q_at + 3];
        let place_m = b.x_tree.point_to_parent(DVec3::new(q[0], q[1], q[2]));
        // The spring acts on the root's position in the actor frame (the free joint's parent).
        let e = b.x_tree.e;
        let ka = DMat3::from_diagonal(DVec3::new(b.stiffness[3], b.stiffness[4], b.stiffness[5]));
        Stance { place_m, home_m: place_m, k: e.transpose() * ka * e, root }
    }

    /// The waist's position now (world; `ws` holds the kinematics).
    pub fn waist_m(&self, ws: &Workspace) -> DVec3 {
        ws.point_world(self.root, DVec3::ZERO)
    }

    /// Adds the force that moves the base spring's anchor from the place to `home_m`, and while
    /// `brace` the legs' bracing: a stiffer spring toward the home and a damper, (N/m, N s/m).
    pub fn apply(&self, ws: &mut Workspace, home_m: DVec3, brace: Option<(f64, f64)>) {
        let mut f = self.k * (home_m - self.place_m);
        if let Some((k, d)) = brace {
            let v = ws.point_velocity(self.root, DVec3::ZERO);
            f += (home_m - self.waist_m(ws)) * k - v * d;
        }
        if f != DVec3::ZERO && f.is_finite() {
            let at = self.waist_m(ws);
            ws.add_force_at(self.root, at, f);
        }
    }

    /// While a fist comes: the stance follows the waist at `waist_m` wherever staying would pull
    /// the body toward a fist. `toward_fists` are unit directions from the virtual human's parts
    /// to the avatar's fists; the spring's pull (home minus waist) keeps no component along any
    /// of them. At most `max_m` from the place (a step).
    pub fn follow(&mut self, waist_m: DVec3, toward_fists: &[DVec3], max_m: f64) {
        let pull = not_toward(self.home_m - waist_m, toward_fists);
        let home = self.place_m + (waist_m + pull - self.place_m).clamp_length_max(max_m);
        if home.is_finite() {
            self.home_m = home;
        }
    }

    /// Where the stance is `ahead_s` seconds on while it steps back to its place at `speed`.
    pub fn returning(&self, ahead_s: f64, speed_m_per_s: f64) -> DVec3 {
        let e = self.place_m - self.home_m;
        self.home_m + e.clamp_length_max(speed_m_per_s * ahead_s.max(0.0))
    }

    /// Steps back toward the place for `dt_s` at `speed`.
    pub fn step_back(&mut self, dt_s: f64, speed_m_per_s: f64) {
        self.home_m = self.returning(dt_s, speed_m_per_s);
    }
}

/// What is left of a spring's pull `pull` once nothing of it points along any of `toward` (unit
/// directions to the fists): its largest part in every half-space "not toward this fist", by
/// alternating projections (a few passes settle two to four directions; whatever they leave
/// pointing toward one is let go of).
pub fn not_toward(mut pull: DVec3, toward: &[DVec3]) -> DVec3 {
    for _ in 0..4 {
        for u in toward {
            let along = pull.dot(*u);
            if along > 0.0 {
                pull -= *u * along;
            }
        }
    }
    if toward.iter().any(|u| pull.dot(*u) > 1e-9) {
        DVec3::ZERO
    } else {
        pull
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic spread of unit directions.
    fn dirs(n: usize, seed: f64) -> Vec<DVec3> {
        (0..n)
            .map(|k| {
                let a = seed + k as f64 * 2.399;
                DVec3::new(a.cos() * (0.7 * a).sin(), (1.3 * a).cos(), a.sin() * (0.7 * a).cos()).normalize()
            })
            .collect()
    }

    #[test]
    fn what_is_left_of_a_pull_points_toward_no_fist() {
        for case in 0..200 {
            let toward = dirs(1 + case % 4, case as f64 * 0.37);
            let pull = dirs(1, case as f64 * 1.91 + 5.0)[0] * 0.05;
            let left = not_toward(pull, &toward);
            for u in &toward {
                assert!(left.dot(*u) <= 1e-9, "case {case}: {left} points toward {u}");
            }
            assert!(left.length() <= pull.length() + 1e-12, "case {case}: the pull grew");
            if toward.iter().all(|u| pull.dot(*u) <= 0.0) {
                assert_eq!(left, pull, "case {case}: a pull away from every fist is kept whole");
            }
        }
        // A single fist straight ahead (+z): a pull forward and up keeps only its upward part.
        let left = not_toward(DVec3::new(0.0, 0.02, 0.05), &[DVec3::Z]);
        assert!((left - DVec3::new(0.0, 0.02, 0.0)).length() < 1e-12, "{left}");
    }

    #[test]
    fn the_stance_follows_the_waist_only_where_staying_would_pull_toward_a_fist() {
        let mut s = Stance { place_m: DVec3::ZERO, home_m: DVec3::ZERO, k: DMat3::IDENTITY, root: 0 };
        // The fist ahead (+z) and below: the waist pushed back (-z) and up.
        let toward = [DVec3::new(0.0, -0.5, 1.0).normalize()];
        let waist = DVec3::new(0.0, 0.04, -0.06);
        s.follow(waist, &toward, 0.15);
        assert!((s.home_m - waist).dot(toward[0]) <= 1e-12, "the stance still pulls toward the fist");
        assert!(s.home_m.z < -0.05 && s.home_m.y > 0.0, "it followed the waist back: {}", s.home_m);
        // Pushed toward the fist: the stance stays where it was and pulls the waist back.
        let before = s.home_m;
        s.follow(before + toward[0] * 0.03, &toward, 0.15);
        assert_eq!(s.home_m, before);
        // Never further than a step from its place.
        s.follow(DVec3::new(0.0, 0.0, -0.5), &toward, 0.15);
        assert!((s.home_m - s.place_m).length() <= 0.15 + 1e-12, "{}", s.home_m);
        // Back to its place at the given speed.
        let from = s.home_m;
        s.step_back(0.1, 0.2);
        assert!(((from - s.home_m).length() - 0.02).abs() < 1e-12);
        for _ in 0..100 {
            s.step_back(0.1, 0.2);
        }
        assert_eq!(s.home_m, s.place_m);
    }
}
