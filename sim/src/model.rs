//! The immutable `Model`: bodies in a forest of joint trees, their inertias, joint springs and
//! limits, collision shapes and the contact pairs that may touch, all resolved to absolute
//! SI values when the model is built (see `desc` for the RON description it is built from).
//!
//! Must never: change after it is built. A `Model` is shared read-only by the world step and by
//! any number of prediction workspaces.

use std::ops::Range;

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::collide::{bounding_radius, Shape, ShapePose};
use crate::joint::{JointKind, MAX_JOINT_DOF};
use crate::spatial::{SInertia, Xform};

/// What part of a human body a solid is; the virtual human classifies contacts by it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
pub enum Part {
    Waist,
    Chest,
    Head,
    UpperArm,
    Forearm,
    Hand,
    /// A single-rigid-body character's body.
    Torso,
    #[default]
    Other,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
pub enum Side {
    Left,
    Right,
    #[default]
    Centre,
}

/// One solid and the joint that connects it to its parent (or to the world).
#[derive(Clone, Debug)]
pub struct Body {
    pub name: String,
    pub part: Part,
    pub side: Side,
    /// Parent body index (always lower than this body's), `None` for a root jointed to the world.
    pub parent: Option<usize>,
    pub articulation: usize,
    pub joint: JointKind,
    /// From the parent body frame (or world) to the joint frame at zero joint motion.
    pub x_tree: Xform,
    pub inertia: SInertia,
    pub mass_kg: f64,
    /// Centre of mass in the body frame.
    pub com_m: DVec3,
    /// Inverse rotational inertia about the centre of mass, body frame.
    pub inv_i_com: DMat3,
    /// First index of this joint's coordinates in `State::q` and `State::v`.
    pub q_at: usize,
    pub v_at: usize,
    /// Joint spring (N m/rad, or N/m for a free joint's translation) per velocity coordinate.
    pub stiffness: [f64; MAX_JOINT_DOF],
    /// Joint damper (N m s/rad or N s/m) per velocity coordinate.
    pub damping: [f64; MAX_JOINT_DOF],
    /// Joint limits per velocity coordinate (radians), for ball, universal and revolute joints.
    /// A ball joint's limits apply to the components of its rotation vector from the joint zero.
    pub limits: Option<[(f64, f64); 3]>,
}

impl Body {
    pub fn nq(&self) -> usize {
        self.joint.nq()
    }
    pub fn nv(&self) -> usize {
        self.joint.nv()
    }
}

/// A collision shape placed on a body (or fixed in the world when `body` is `None`).
#[derive(Clone, Debug)]
pub struct ShapeInst {
    pub name: String,
    pub body: Option<usize>,
    pub shape: Shape,
    /// Pose in the body frame (in the world frame for static shapes).
    pub local: ShapePose,
    /// Collision filtering: two shapes may touch when each one's group meets the other's mask.
    pub group: u32,
    pub mask: u32,
    pub bound_m: f64,
}

/// One named instance of a body description in the scene: a contiguous range of bodies.
#[derive(Clone, Debug)]
pub struct Articulation {
    pub name: String,
    /// The description it was built from (e.g. "upper-body").
    pub kind: String,
    pub bodies: Range<usize>,
    pub mass_kg: f64,
    /// The root is held up against gravity at the articulation's centre of mass.
    pub carries_weight: bool,
}

/// A pair of shapes that may touch, with its penalty gains resolved.
#[derive(Clone, Copy, Debug)]
pub struct ShapePair {
    pub a: u16,
    pub b: u16,
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    pub friction: f64,
    /// Reduced mass of the two bodies' segments (one body's mass against scenery), which `Rate`
    /// contact gains are scaled by.
    pub m_red_kg: f64,
}

/// Penalty contact settings resolved for the model.
#[derive(Clone, Copy, Debug)]
pub struct ContactParams {
    /// Coulomb friction is regularised below this slip speed so it is smooth and stable; see
    /// `contact.rs` for how it is also bounded by the step's stability limit.
    pub slip_m_per_s: f64,
}

/// Joint-limit penalty gains (applied implicitly like the joint springs).
#[derive(Clone, Copy, Debug)]
pub struct LimitParams {
    pub k_n_m_per_rad: f64,
    pub d_n_m_s_per_rad: f64,
}

/// Everything about the simulated world that does not change while it runs.
#[derive(Clone, Debug)]
pub struct Model {
    pub dt_s: f64,
    pub gravity_m_per_s2: DVec3,
    /// Bodies in topological order (parent before child).
    pub bodies: Vec<Body>,
    pub nq: usize,
    pub nv: usize,
    /// The default pose: targets of the joint springs, home of free bases, and the initial state.
    pub q_default: Vec<f64>,
    pub shapes: Vec<ShapeInst>,
    pub pairs: Vec<ShapePair>,
    pub articulations: Vec<Articulation>,
    pub contact: ContactParams,
    pub limit: LimitParams,
    /// Joint springs, dampers and limits enter the step implicitly (the default; see
    /// `passive.rs`). False makes them explicit, only to measure why they are not.
    pub implicit_joint_springs: bool,
}

impl Model {
    pub fn body_index(&self, articulation: &str, body: &str) -> Option<usize> {
        let a = self.articulations.iter().find(|a| a.name == articulation)?;
        a.bodies.clone().find(|&i| self.bodies[i].name == body)
    }

    pub fn articulation_index(&self, name: &str) -> Option<usize> {
        self.articulations.iter().position(|a| a.name == name)
    }

    /// The bodies of one articulation with a given part and side.
    pub fn find_part(&self, articulation: usize, part: Part, side: Side) -> Option<usize> {
        self.articulations[articulation]
            .bodies
            .clone()
            .find(|&i| self.bodies[i].part == part && self.bodies[i].side == side)
    }

    /// Lists the shape pairs that can touch: filtered by group and mask; shapes of the same
    /// articulation never touch (the upper-body models do not self-collide); static shapes do not
    /// touch each other.
    pub(crate) fn build_pairs(&mut self, gains: impl Fn(f64) -> (f64, f64, f64)) {
        let mut pairs = Vec::new();
        for i in 0..self.shapes.len() {
            for j in (i + 1)..self.shapes.len() {
                let (a, b) = (&self.shapes[i], &self.shapes[j]);
                if a.group & b.mask == 0 || b.group & a.mask == 0 {
                    continue;
                }
                let same = match (a.body, b.body) {
                    (None, None) => true,
                    (Some(x), Some(y)) => self.bodies[x].articulation == self.bodies[y].articulation,
                    _ => false,
                };
                if same || matches!((a.shape, b.shape), (Shape::Plane, Shape::Plane)) {
                    continue;
                }
                let m_red_kg = self.reduced_mass(a.body, b.body);
                let (k, d, mu) = gains(m_red_kg);
                pairs.push(ShapePair {
                    a: i as u16,
                    b: j as u16,
                    k_n_per_m: k,
                    d_n_s_per_m: d,
                    friction: mu,
                    m_red_kg,
                });
            }
        }
        self.pairs = pairs;
    }

    /// Reduced mass of two bodies' segments; scenery (`None`) is immovable.
    pub fn reduced_mass(&self, a: Option<usize>, b: Option<usize>) -> f64 {
        match (a.map(|i| self.bodies[i].mass_kg), b.map(|i| self.bodies[i].mass_kg)) {
            (Some(x), Some(y)) => x * y / (x + y),
            (Some(x), None) | (None, Some(x)) => x,
            (None, None) => 1.0,
        }
    }

    /// Total mass of the articulation a body belongs to.
    pub fn articulation_mass(&self, body: usize) -> f64 {
        self.articulations[self.bodies[body].articulation].mass_kg
    }
}

/// Placement of a shape in the world given its body's world transform (`x0`: world -> body).
#[inline]
pub fn place(local: &ShapePose, x0: &Xform) -> ShapePose {
    let rot_body = x0.e.transpose();
    ShapePose { pos_m: x0.r + rot_body * local.pos_m, rot: rot_body * local.rot }
}

/// Solid ellipsoid inertia about its centre, full sizes along x, y, z.
pub fn ellipsoid_inertia(mass_kg: f64, size_m: DVec3) -> DMat3 {
    let (a, b, c) = (size_m.x * 0.5, size_m.y * 0.5, size_m.z * 0.5);
    DMat3::from_diagonal(DVec3::new(b * b + c * c, a * a + c * c, a * a + b * b) * (mass_kg / 5.0))
}

/// Solid box inertia about its centre, full sizes along x, y, z.
pub fn box_inertia(mass_kg: f64, size_m: DVec3) -> DMat3 {
    let s = size_m * size_m;
    DMat3::from_diagonal(DVec3::new(s.y + s.z, s.x + s.z, s.x + s.y) * (mass_kg / 12.0))
}

pub(crate) fn shape_bound(s: &Shape) -> f64 {
    bounding_radius(s)
}
