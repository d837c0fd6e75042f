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
