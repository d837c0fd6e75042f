//! `State` (what is integrated and what a prediction copies) and `Workspace` (everything derived
//! from it, plus scratch), and the kinematics pass that fills the workspace from a state.
//!
//! Must never: allocate after `Workspace::new` (every buffer is sized from the model there), or
//! keep anything in the workspace that a prediction would need from the state.

use glam::{DMat3, DVec3};

use crate::collide::{ShapePose, MAX_HITS};
use crate::joint::{joint_motion, JointMotion, MAX_JOINT_DOF};
use crate::model::{place, Model};
use crate::spatial::{SInertia, SVec, Xform};

/// Contacts one step keeps; more are counted in `Workspace::contacts_dropped` and not applied.
pub const MAX_CONTACTS: usize = 512;

/// The integration state. Copying it into another workspace and stepping is a prediction.
#[derive(Clone, Debug, PartialEq)]
pub struct State {
    /// Seconds of simulated time.
    pub t_s: f64,
    /// Steps taken.
    pub steps: u64,
    /// Joint positions, `Model::nq` long (see `joint.rs` for each kind's layout).
    pub q: Vec<f64>,
    /// Joint velocities, `Model::nv` long.
    pub v: Vec<f64>,
}

impl State {
    /// The model's default pose, at rest.
    pub fn new(model: &Model) -> State {
        State { t_s: 0.0, steps: 0, q: model.q_default.clone(), v: vec![0.0; model.nv] }
    }

    /// Copies `other` into `self` without allocating (both come from the same model).
    pub fn copy_from(&mut self, other: &State) {
        self.t_s = other.t_s;
        self.steps = other.steps;
        self.q.copy_from_slice(&other.q);
        self.v.copy_from_slice(&other.v);
    }

    /// A digest of the exact bits of the state, for determinism tests.
    pub fn digest(&self) -> u64 {
        let mut d = spidar_msg::digest::Digest::new();
        d.u64(self.steps).f64(self.t_s);
        for x in self.q.iter().chain(self.v.iter()) {
            d.f64(*x);
        }
        d.value()
    }
}

/// One contact found in a step, with the force it produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Shape indices in `Model::shapes`.
    pub shape_a: u16,
    pub shape_b: u16,
    /// Body indices (`None`: static scenery).
    pub body_a: Option<u16>,
    pub body_b: Option<u16>,
    /// World contact point (midway between the surfaces).
    pub point_m: DVec3,
    /// Unit normal pointing from b toward a.
    pub normal: DVec3,
    pub depth_m: f64,
    /// Force on a (world); b receives the opposite.
    pub force_n: DVec3,
}

/// Derived quantities and scratch for stepping one state. One per thread.
#[derive(Clone, Debug)]
pub struct Workspace {
    /// Per body: joint motion, transform from the parent (or world), from the world.
    pub(crate) jm: Vec<JointMotion>,
    pub(crate) xup: Vec<Xform>,
    /// World -> body transforms (`x0[i].r` is the body origin in the world).
    pub x0: Vec<Xform>,
    /// Spatial velocity of each body in its own coordinates.
    pub vel: Vec<SVec>,
    pub(crate) cbias: Vec<SVec>,
    pub(crate) ia: Vec<SInertia>,
    pub(crate) pa: Vec<SVec>,
    /// Spatial acceleration of each body in its own coordinates (after `forward`).
    pub acc: Vec<SVec>,
    pub(crate) u: Vec<[SVec; MAX_JOINT_DOF]>,
    pub(crate) dinv: Vec<[[f64; MAX_JOINT_DOF]; MAX_JOINT_DOF]>,
    pub(crate) uu: Vec<[f64; MAX_JOINT_DOF]>,
    /// External spatial forces on each body, world coordinates about the world origin. Callers
    /// add to it before a step (`add_force_at`); the step clears it.
    pub f_ext: Vec<SVec>,
    /// Generalised forces applied by controllers (`nv` long); cleared by the step.
    pub tau: Vec<f64>,
    /// Joint springs, dampers and limits of the last step (`nv`).
    pub tau_passive: Vec<f64>,
    /// The implicit terms `h d + h^2 k` added to the joint-space inertia diagonal (`nv`).
    pub(crate) armature: Vec<f64>,
    /// Joint accelerations of the last step (`nv`).
    pub qdd: Vec<f64>,
    /// World pose of every shape (after `forward`).
    pub shape_pose: Vec<ShapePose>,
    /// The contacts of the last step.
    pub contacts: Vec<Contact>,
    /// Contact records beyond `MAX_CONTACTS` (their forces are still applied), counted since
    /// the workspace was made.
    pub contacts_dropped: u64,
    /// Contact points whose configured gains exceeded the stability bound at their effective
    /// mass and were softened to it, counted since the workspace was made.
    pub contacts_softened: u64,
    pub(crate) hits: [crate::collide::Hit; MAX_HITS],
}

impl Workspace {
    pub fn new(model: &Model) -> Workspace {
        let n = model.bodies.len();
        Workspace {
            jm: vec![JointMotion::default(); n],
            xup: vec![Xform::IDENTITY; n],
            x0: vec![Xform::IDENTITY; n],
            vel: vec![SVec::ZERO; n],
            cbias: vec![SVec::ZERO; n],
            ia: vec![SInertia::ZERO; n],
            pa: vec![SVec::ZERO; n],
            acc: vec![SVec::ZERO; n],
            u: vec![[SVec::ZERO; MAX_JOINT_DOF]; n],
            dinv: vec![[[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF]; n],
            uu: vec![[0.0; MAX_JOINT_DOF]; n],
            f_ext: vec![SVec::ZERO; n],
            tau: vec![0.0; model.nv],
            tau_passive: vec![0.0; model.nv],
            armature: vec![0.0; model.nv],
            qdd: vec![0.0; model.nv],
            shape_pose: model.shapes.iter().map(|s| s.local).collect(),
            contacts: Vec::with_capacity(MAX_CONTACTS),
            contacts_dropped: 0,
            contacts_softened: 0,
            hits: [crate::collide::Hit { point_m: DVec3::ZERO, normal: DVec3::Y, depth_m: 0.0 }; MAX_HITS],
        }
    }

    /// Adds a force (world, N) acting at a world point on `body` for the next step.
    #[inline]
    pub fn add_force_at(&mut self, body: usize, point_m: DVec3, force_n: DVec3) {
        self.f_ext[body] += SVec::new(point_m.cross(force_n), force_n);
    }

    /// Adds a pure torque (world, N m) on `body` for the next step.
    #[inline]
    pub fn add_torque(&mut self, body: usize, torque_n_m: DVec3) {
        self.f_ext[body].ang += torque_n_m;
    }

    /// Applies an impulse (N s) at a world point over the next step of `dt_s`, so the momentum
    /// given is exactly the impulse.
    #[inline]
    pub fn add_impulse_at(&mut self, body: usize, point_m: DVec3, impulse_n_s: DVec3, dt_s: f64) {
        self.add_force_at(body, point_m, impulse_n_s / dt_s);
    }

    /// World position of a point given in a body's frame (valid after `forward`/`kinematics`).
    #[inline]
    pub fn point_world(&self, body: usize, p_body: DVec3) -> DVec3 {
        self.x0[body].point_to_parent(p_body)
    }

    /// World velocity of a point given in a body's frame.
    #[inline]
    pub fn point_velocity(&self, body: usize, p_body: DVec3) -> DVec3 {
        let v = self.vel[body];
        self.x0[body].e.transpose() * (v.lin + v.ang.cross(p_body))
    }

    /// Angular velocity of a body in world coordinates.
    #[inline]
    pub fn angular_velocity(&self, body: usize) -> DVec3 {
        self.x0[body].e.transpose() * self.vel[body].ang
    }

    /// Centre of mass of a body in the world.
    pub fn com_world(&self, model: &Model, body: usize) -> DVec3 {
        self.point_world(body, model.bodies[body].com_m)
    }
}

/// Pass 1 of every algorithm: joint motions, transforms, velocities and velocity-product terms,
/// and the world pose of every shape.
pub fn kinematics(model: &Model, state: &State, ws: &mut Workspace) {
    for (i, b) in model.bodies.iter().enumerate() {
        let q = &state.q[b.q_at..b.q_at + b.nq()];
        let qd = &state.v[b.v_at..b.v_at + b.nv()];
        let jm = joint_motion(&b.joint, q, qd);
        // A child's tree transform is a pure translation (`desc.rs`): the product by its identity
        // rotation is then left out, which changes no bit (glam sums the products in order, and the
        // ones left out are by exact zeros and ones).
        let xup = if b.x_tree.e == DMat3::IDENTITY {
            Xform { e: jm.xj.e, r: b.x_tree.r + jm.xj.r }
        } else {
            jm.xj.compose(&b.x_tree)
        };
        let (x0, v) = match b.parent {
            Some(p) => (xup.compose(&ws.x0[p]), xup.apply_motion(ws.vel[p]) + jm.vj),
            None => (xup, jm.vj),
        };
        ws.cbias[i] = jm.cj + v.cross_motion(jm.vj);
        ws.jm[i] = jm;
        ws.xup[i] = xup;
        ws.x0[i] = x0;
        ws.vel[i] = v;
    }
    for (k, s) in model.shapes.iter().enumerate() {
        if let Some(b) = s.body {
            ws.shape_pose[k] = if s.local.rot == DMat3::IDENTITY {
                // `place` without its product by the identity (the same bits, as above).
                let x0 = &ws.x0[b];
                let rot_body = x0.e.transpose();
                ShapePose { pos_m: x0.r + rot_body * s.local.pos_m, rot: rot_body }
            } else {
                place(&s.local, &ws.x0[b])
            };
        }
    }
}
