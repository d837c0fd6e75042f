//! The crowd stepper: thousands of single-rigid-body characters stepped and posed per 3 ms step on
//! one core (DESIGN.md section 8: more than 5,000).
//!
//! Why not the general engine: `Model::build_pairs` lists every pair of shapes (O(n^2) for n
//! characters) and the articulated-body machinery is general. Here every body is one free rigid
//! body of the same description, so the step is specialised: a uniform grid on the floor finds the
//! characters that may touch (O(n)), and each body integrates in closed form. It is the same
//! physics as the engine: the same narrow phase (`collide::collide`), the same penalty law
//! (`contact::penalty_force`, with the stability bound at the contact's effective mass), the same
//! semi-implicit Euler with the same free-joint coordinates (angular velocity in the body frame,
//! linear velocity in the world), and the same controller, AI and animation as
//! `Character::drive_engine`. One character in both gives the same motion (tested: within 1e-6 m
//! over 7.5 s of standing, a push, a fall and standing up; the two differ only in rounding).
//!
//! What it leaves out: articulations, joint springs, contact records (only per-character floor
//! summaries are kept), collision groups. Static scenery is a short list of shapes checked against
//! every character (a floor and a few walls; not thousands of obstacles).
//!
//! Must never: allocate after the first step (the grid's buffers grow once), or apply a force to a
//! character from a pair it is not in.

use glam::{DMat3, DQuat, DVec3};

use super::ai::Goal;
use super::controller::Ground;
use super::keyframe::{KeyframeSet, Pose};
use super::space::BodySpace;
use super::{Character, CharacterParams};
use crate::collide::{
    bounding_radius, box_on_plane, collide, plane_normal, Hit, Pose as ShapePose, Shape, MAX_HITS,
};
use crate::contact::{penalty_force, Penalty};
use crate::desc::{BodyFile, ContactDesc, MassDesc};
use crate::spatial::quat_exp;
use crate::SimError;

/// Boxes in the world axes are compared with this much slack (m), far above the rounding of the
/// narrow phase, so a pair they keep apart cannot have a hit of positive depth.
const AABB_MARGIN_M: f64 = 1e-6;

/// Half extents (m) of the box in the world axes around a shape turned by `rot`; a plane has none.
#[inline]
fn aabb_half_m(s: &Shape, rot: &DMat3) -> DVec3 {
    match *s {
        Shape::Sphere { radius_m } => DVec3::splat(radius_m.max(0.0)),
        Shape::Capsule { half_length_m, radius_m } => {
            rot.y_axis.abs() * half_length_m.max(0.0) + DVec3::splat(radius_m.max(0.0))
        }
        Shape::Box { half_extents_m: e } => {
            let e = e.max(DVec3::ZERO);
            rot.x_axis.abs() * e.x + rot.y_axis.abs() * e.y + rot.z_axis.abs() * e.z
        }
        Shape::Plane => DVec3::splat(f64::INFINITY),
    }
}

/// The rigid body of one crowd character: the free-joint coordinates of the engine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyState {
    /// Body origin in the world (m).
    pub pos_m: DVec3,
    /// Body -> world rotation.
    pub rot: DQuat,
    /// Angular velocity in the body frame (rad/s).
    pub w_body: DVec3,
    /// Velocity of the body origin in the world (m/s).
    pub vel_m_per_s: DVec3,
}

/// The shared description of every crowd character's body.
#[derive(Clone, Debug)]
pub struct CrowdBody {
    pub mass_kg: f64,
    /// Centre of mass in the body frame.
    pub com_m: DVec3,
    pub i_com: DMat3,
    pub inv_i_com: DMat3,
    /// Shapes with their pose in the body frame and bounding radius.
    pub shapes: Vec<(Shape, ShapePose, f64)>,
    /// Radius about the body origin that holds every shape.
    pub bound_m: f64,
    /// Height of the body origin above the floor when standing (the root joint's anchor).
    pub stand_height_m: f64,
}

impl CrowdBody {
    /// From a body file of one free link (like `configs/body-character.ron`).
    pub fn from_file(f: &BodyFile, origin: &str) -> Result<CrowdBody, SimError> {
        if f.links.len() != 1 || !matches!(f.links[0].joint.kind, crate::joint::JointKind::Free) {
            return Err(SimError::Build(format!(
                "{origin}: a crowd character must be one link with a Free joint (got {} links)",
                f.links.len()
            )));
        }
        let l = &f.links[0];
        let (mass_kg, com_m, i_com) = match l.mass {
            MassDesc::Explicit { mass_kg, centre_m, inertia_kg_m2 } => {
                (mass_kg, centre_m, DMat3::from_diagonal(inertia_kg_m2))
            }
            MassDesc::Box { mass_kg, size_m, centre_m } => {
                (mass_kg, centre_m, crate::model::box_inertia(mass_kg, size_m))
            }
            MassDesc::Ellipsoid { mass_kg, size_m, centre_m } => {
                (mass_kg, centre_m, crate::model::ellipsoid_inertia(mass_kg, size_m))
            }
        };
        let mut shapes = Vec::new();
        let mut bound_m: f64 = 0.0;
        for s in &l.shapes {
            let shape = match s.shape {
                crate::desc::ShapeDesc::Sphere { radius_m } => Shape::Sphere { radius_m },
                crate::desc::ShapeDesc::Capsule { half_length_m, radius_m } => {
                    Shape::Capsule { half_length_m, radius_m }
                }
                crate::desc::ShapeDesc::Box { size_m } => Shape::Box { half_extents_m: size_m * 0.5 },
                crate::desc::ShapeDesc::Plane => {
                    return Err(SimError::Build(format!("{origin}: a character cannot carry a plane")))
                }
            };
            let rot = DMat3::from_quat(quat_exp(s.rot_deg * (std::f64::consts::PI / 180.0)));
            let r = bounding_radius(&shape);
            bound_m = bound_m.max(s.pos_m.length() + r);
            shapes.push((shape, ShapePose { pos_m: s.pos_m, rot }, r));
        }
        Ok(CrowdBody {
            mass_kg,
            com_m,
            i_com,
            inv_i_com: i_com.inverse(),
            shapes,
            bound_m,
            stand_height_m: l.joint.anchor_m.y,
        })
    }
}

/// Contact and world settings of a crowd.
#[derive(Clone, Copy, Debug)]
pub struct CrowdWorld {
    pub dt_s: f64,
    pub gravity_m_per_s2: DVec3,
    /// Penalty gains between a character and scenery, and between two characters.
    pub scenery: Penalty,
    pub pair: Penalty,
}

impl CrowdWorld {
    /// Gains resolved as the engine's scene builder does (rates with the pair's reduced mass).
    pub fn new(dt_s: f64, gravity_m_per_s2: DVec3, contact: &ContactDesc, mass_kg: f64) -> CrowdWorld {
        let gains = |m_red_kg: f64| Penalty {
            k_n_per_m: contact.stiffness.stiffness(m_red_kg, dt_s),
            d_n_s_per_m: contact.damping.damping(m_red_kg, dt_s),
            friction: contact.friction,
            slip_m_per_s: contact.slip_m_per_s,
        };
        CrowdWorld { dt_s, gravity_m_per_s2, scenery: gains(mass_kg), pair: gains(mass_kg * 0.5) }
    }
}

/// Counters of the last step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CrowdStats {
    /// Character pairs whose bounding spheres overlapped.
    pub near_pairs: usize,
    /// Contact points between characters, and with scenery.
    pub pair_points: usize,
    pub scenery_points: usize,
}

/// A crowd: bodies, characters and their poses, and the scratch of the step.
#[derive(Clone, Debug)]
pub struct Crowd {
    pub body: CrowdBody,
    pub world: CrowdWorld,
    pub params: CharacterParams,
    pub set: KeyframeSet,
    pub statics: Vec<(Shape, ShapePose)>,
    pub bodies: Vec<BodyState>,
    pub chars: Vec<Character>,
    /// Pose of each character (in its body frame), from the last step.
    pub poses: Vec<Pose>,
    /// Rigid-body space of each character at the start of the last step.
    pub spaces: Vec<BodySpace>,
    pub time_s: f64,
    pub steps: u64,
    pub stats: CrowdStats,
    /// Pick new walk targets in this rectangle (min x, min z, max x, max z) when one is reached;
    /// `None`: goals stay as set.
    pub wander: Option<[f64; 4]>,
    pub wander_speed_m_per_s: f64,
    rng: u64,
    // Per-step accumulators: force (world) and torque about the centre of mass (world).
    force: Vec<DVec3>,
    torque: Vec<DVec3>,
    ground_moment: Vec<DVec3>,
    ground_n: Vec<f64>,
    // Uniform grid on the floor (x, z), rebuilt every step.
    cell_of: Vec<u32>,
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    cell_pos: Vec<DVec3>,
    grid_dims: (usize, usize),
    // Per character for the current step: rotation matrix, world angular velocity, world inverse
    // inertia and centre of mass. Shape poses are not stored: computing one from `rotm` where it is
    // needed (the scenery pass and near pairs) is cheaper than writing and reading them back for
    // every character (a few hundred bytes each, megabytes per step).
    rotm: Vec<DMat3>,
    w_world: Vec<DVec3>,
    inv_i_world: Vec<DMat3>,
    com_world: Vec<DVec3>,
    hits: [Hit; MAX_HITS],
    /// `plane_normal` of each static shape (unused for non-planes), refreshed every step.
    static_normal: Vec<DVec3>,
    /// The box around all of the body's shapes in the body frame (centre, half extents), refreshed
    /// every step, and each character's box in the world axes around it (centre, half extents).
    local_box_m: (DVec3, DVec3),
    box_c: Vec<DVec3>,
    box_e: Vec<DVec3>,
}

impl Crowd {
    pub fn new(body: CrowdBody, world: CrowdWorld, params: CharacterParams, set: KeyframeSet) -> Crowd {
        Crowd {
            body,
            world,
            params,
            set,
            statics: Vec::new(),
            bodies: Vec::new(),
            chars: Vec::new(),
            poses: Vec::new(),
            spaces: Vec::new(),
            time_s: 0.0,
            steps: 0,
            stats: CrowdStats::default(),
            wander: None,
            wander_speed_m_per_s: 1.0,
            rng: 0x9e37_79b9_7f4a_7c15,
            force: Vec::new(),
            torque: Vec::new(),
            ground_moment: Vec::new(),
            ground_n: Vec::new(),
            cell_of: Vec::new(),
            cell_start: Vec::new(),
            cell_items: Vec::new(),
            cell_pos: Vec::new(),
            grid_dims: (1, 1),
            rotm: Vec::new(),
            w_world: Vec::new(),
            inv_i_world: Vec::new(),
            com_world: Vec::new(),
            hits: [Hit::ZERO; MAX_HITS],
            static_normal: Vec::new(),
            local_box_m: (DVec3::ZERO, DVec3::ZERO),
            box_c: Vec::new(),
            box_e: Vec::new(),
        }
    }

    /// Seeds the crowd's own random numbers (wander targets).
    pub fn seed(&mut self, seed: u64) {
        self.rng = seed ^ 0x9e37_79b9_7f4a_7c15;
    }

    /// A uniform number in [0, 1) (splitmix64): the crowd's only randomness, so a seed fixes it.
    pub fn random(&mut self) -> f64 {
        self.rng = self.rng.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Adds a character standing on the floor at `(x, z)` facing `heading_rad`; returns its index.
    pub fn add(&mut self, x: f64, z: f64, heading_rad: f64, goal: Goal) -> usize {
        let rot = DQuat::from_rotation_y(heading_rad);
        self.bodies.push(BodyState {
            pos_m: DVec3::new(x, self.body.stand_height_m, z),
            rot,
            w_body: DVec3::ZERO,
            vel_m_per_s: DVec3::ZERO,
        });
        self.chars.push(Character { goal, ..Character::default() });
        self.poses.push(Pose::default());
        let b = self.body_space(self.bodies.len() - 1);
        self.spaces.push(b);
        self.force.push(DVec3::ZERO);
        self.torque.push(DVec3::ZERO);
        self.ground_moment.push(DVec3::ZERO);
        self.ground_n.push(0.0);
        self.cell_of.push(0);
        self.cell_items.push(0);
        self.cell_pos.push(DVec3::ZERO);
        self.rotm.push(DMat3::IDENTITY);
        self.w_world.push(DVec3::ZERO);
        self.inv_i_world.push(DMat3::IDENTITY);
        self.com_world.push(DVec3::ZERO);
        self.box_c.push(DVec3::ZERO);
        self.box_e.push(DVec3::ZERO);
        self.bodies.len() - 1
    }

    pub fn len(&self) -> usize {
        self.bodies.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bodies.is_empty()
    }

    /// The rigid-body space of character `i` now.
    pub fn body_space(&self, i: usize) -> BodySpace {
        let s = &self.bodies[i];
        let w = s.rot * s.w_body;
        let c = s.rot * self.body.com_m;
        BodySpace::new(s.rot, s.pos_m + c, s.vel_m_per_s + w.cross(c), w)
    }

    /// World pose of shape `k` of character `i`.
    #[inline]
    pub fn shape_world(&self, i: usize, k: usize) -> (Shape, ShapePose) {
        let (shape, local, _) = self.body.shapes[k];
        let s = &self.bodies[i];
        let r = DMat3::from_quat(s.rot);
        (shape, ShapePose { pos_m: s.pos_m + r * local.pos_m, rot: r * local.rot })
    }

    /// Adds a force (world, N) at a world point on character `i` for the next step.
    #[inline]
    pub fn add_force_at(&mut self, i: usize, point_m: DVec3, force_n: DVec3) {
        let c = self.bodies[i].pos_m + self.bodies[i].rot * self.body.com_m;
        self.force[i] += force_n;
        self.torque[i] += (point_m - c).cross(force_n);
    }

    /// Adds an impulse (N s) at a world point, given over the next step.
    #[inline]
    pub fn add_impulse_at(&mut self, i: usize, point_m: DVec3, impulse_n_s: DVec3) {
        self.add_force_at(i, point_m, impulse_n_s / self.world.dt_s);
    }

    /// Velocity (world) of the body point of character `i` now at world `p`.
    #[inline]
    pub fn point_velocity(&self, i: usize, p: DVec3) -> DVec3 {
        let s = &self.bodies[i];
        s.vel_m_per_s + (s.rot * s.w_body).cross(p - s.pos_m)
    }

    /// One step: AI and controllers, contacts, integration, then every character's pose.
    pub fn step(&mut self) {
        self.stats = CrowdStats::default();
        self.per_character();
        self.build_grid();
        self.pair_contacts();
        self.integrate_all();
    }

    /// Everything that concerns one character alone, done while its data is in cache: AI and
    /// controller (on the floor contacts of the last step, like the engine), contacts with the
    /// scenery, and its pose at the point of Q its state at the start of the step maps to.
    // The phases stay separate functions so a profile shows each one.
    #[inline(never)]
    fn per_character(&mut self) {
        let h = self.world.dt_s;
        let g = -self.world.gravity_m_per_s2.y;
        let blend_s = self.set.behaviour_blend_s;
        let cos = self.params.controller.tilt_cosines();
        // Scenery is a handful of shapes: this grows only when scenery is added.
        self.static_normal.clear();
        self.static_normal.extend(self.statics.iter().map(|(_, p)| plane_normal(p)));
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (shape, local, _) in &self.body.shapes {
            let e = aabb_half_m(shape, &local.rot);
            lo = lo.min(local.pos_m - e);
            hi = hi.max(local.pos_m + e);
        }
        self.local_box_m = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        for i in 0..self.len() {
            let b = self.body_space(i);
            self.spaces[i] = b;
            if let Some(area) = self.wander {
                self.wander_goal(i, area);
            }
            let ch = &mut self.chars[i];
            ch.ground = if self.ground_n[i] > 0.0 {
                Ground { normal_n: self.ground_n[i], point_m: self.ground_moment[i] / self.ground_n[i] }
            } else {
                Ground::default()
            };
            let d = ch.think_with(&self.params, &cos, self.body.mass_kg, g, h, blend_s, &b);
            self.force[i] += d.force_n;
            self.torque[i] += (d.at_m - b.r_m).cross(d.force_n) + d.torque_n_m;
            self.ground_n[i] = 0.0;
            self.ground_moment[i] = DVec3::ZERO;
            self.cache(i, &b);
            self.scenery_contacts(i);
            self.chars[i].anim.pose(&b, &self.set, &mut self.poses[i]);
        }
    }

    /// The engine's semi-implicit Euler for a free joint.
    #[inline(never)]
    fn integrate_all(&mut self) {
        let h = self.world.dt_s;
        for i in 0..self.len() {
            let s = &mut self.bodies[i];
            let f = self.force[i] + self.world.gravity_m_per_s2 * self.body.mass_kg;
            let r = self.rotm[i];
            let t_body = r.transpose() * self.torque[i];
            let iw = self.body.i_com * s.w_body;
            let w_dot = self.body.inv_i_com * (t_body - s.w_body.cross(iw));
            // The body origin's acceleration: the centre of mass's minus the rotation terms.
            let c = r * self.body.com_m;
            let w = self.w_world[i];
            let a_origin = f / self.body.mass_kg - (r * w_dot).cross(c) - w.cross(w.cross(c));
            s.w_body += w_dot * h;
            s.vel_m_per_s += a_origin * h;
            s.pos_m += s.vel_m_per_s * h;
            s.rot = (s.rot * quat_exp(s.w_body * h)).normalize();
            self.force[i] = DVec3::ZERO;
            self.torque[i] = DVec3::ZERO;
        }
        self.time_s += h;
        self.steps += 1;
    }

    /// Fills the per-step caches of character `i` (its state is fixed until integration).
    #[inline]
    fn cache(&mut self, i: usize, b: &BodySpace) {
        let s = &self.bodies[i];
        let r = DMat3::from_quat(s.rot);
        self.rotm[i] = r;
        self.w_world[i] = r * s.w_body;
        self.inv_i_world[i] = r * self.body.inv_i_com * r.transpose();
        self.com_world[i] = b.r_m;
        // The body-frame box turned into the world holds the turned shapes.
        let (c, e) = self.local_box_m;
        self.box_c[i] = s.pos_m + r * c;
        self.box_e[i] = r.x_axis.abs() * e.x + r.y_axis.abs() * e.y + r.z_axis.abs() * e.z;
    }

    fn wander_goal(&mut self, i: usize, area: [f64; 4]) {
        let s = &self.spaces[i];
        let pick = match self.chars[i].goal {
            Goal::WalkTo { point_m, .. } => {
                let d = DVec3::new(point_m.x - s.r_m.x, 0.0, point_m.z - s.r_m.z).length();
                d < self.params.ai.arrive_m * 2.0
            }
            _ => true,
        };
        if pick {
            let x = area[0] + (area[2] - area[0]) * self.random();
            let z = area[1] + (area[3] - area[1]) * self.random();
            self.chars[i].goal =
                Goal::WalkTo { point_m: DVec3::new(x, 0.0, z), speed_m_per_s: self.wander_speed_m_per_s };
        }
    }

    #[inline]
    fn apply_hit(&mut self, i: usize, hit: &Hit, force: DVec3) {
        self.force[i] += force;
        self.torque[i] += (hit.point_m - self.com_world[i]).cross(force);
    }

    /// Inverse effective mass of character `i` at world `p` along `n` (the engine's formula, in
    /// world coordinates).
    #[inline]
    fn inv_mass_along(&self, i: usize, p: DVec3, n: DVec3) -> f64 {
        let w = (p - self.com_world[i]).cross(n);
        1.0 / self.body.mass_kg + w.dot(self.inv_i_world[i] * w)
    }

    #[inline]
    fn vel_at(&self, i: usize, p: DVec3) -> DVec3 {
        self.bodies[i].vel_m_per_s + self.w_world[i].cross(p - self.bodies[i].pos_m)
    }

    /// Contacts of character `i` with the scenery (its caches must be filled).
    // Borrows the shapes, the scenery and the hit buffer in place: copying them per character (a
    // few hundred bytes each) cost more than the narrow phase itself.
    #[inline]
    fn scenery_contacts(&mut self, i: usize) {
        let h = self.world.dt_s;
        let inv_mass_kg = 1.0 / self.body.mass_kg;
        let (com, inv_i, w_world) = (self.com_world[i], self.inv_i_world[i], self.w_world[i]);
        let (pos, vel) = (self.bodies[i].pos_m, self.bodies[i].vel_m_per_s);
        let (mut force, mut torque) = (self.force[i], self.torque[i]);
        let (mut ground_n, mut ground_moment) = (self.ground_n[i], self.ground_moment[i]);
        let mut points = 0;
        let r = self.rotm[i];
        for (shape, local, bound) in &self.body.shapes {
            let pos_m = pos + r * local.pos_m;
            let mut rot = None;
            for ((ss, sp), &normal) in self.statics.iter().zip(&self.static_normal) {
                let far = match ss {
                    Shape::Plane => (pos_m - sp.pos_m).dot(sp.rot.y_axis) > *bound,
                    _ => (pos_m - sp.pos_m).length_squared() > (bound + bounding_radius(ss)).powi(2),
                };
                if far {
                    continue;
                }
                let pose = ShapePose { pos_m, rot: *rot.get_or_insert_with(|| r * local.rot) };
                let nh = match (shape, ss) {
                    (Shape::Box { half_extents_m }, Shape::Plane) => {
                        box_on_plane(*half_extents_m, &pose, normal, sp.pos_m, &mut self.hits)
                    }
                    _ => collide(shape, &pose, ss, sp, &mut self.hits),
                };
                if nh == 0 {
                    continue;
                }
                let share = 1.0 / nh as f64;
                for hit in self.hits.iter().take(nh) {
                    // `inv_mass_along`, `vel_at` and `apply_hit` on the values held above.
                    let arm = hit.point_m - com;
                    let w = arm.cross(hit.normal);
                    let inv_m = inv_mass_kg + w.dot(inv_i * w);
                    let vrel = vel + w_world.cross(hit.point_m - pos);
                    let (f, _) = penalty_force(&self.world.scenery, hit, inv_m, share, h, vrel);
                    force += f;
                    torque += arm.cross(f);
                    if hit.normal.y >= 0.7 {
                        let fn_ = f.dot(hit.normal).max(0.0);
                        ground_n += fn_;
                        ground_moment += hit.point_m * fn_;
                    }
                    points += 1;
                }
            }
        }
        self.force[i] = force;
        self.torque[i] = torque;
        self.ground_n[i] = ground_n;
        self.ground_moment[i] = ground_moment;
        self.stats.scenery_points += points;
    }

    /// Cell size: two bounding radii, so touching characters are in the same or adjacent cells.
    fn cell_size(&self) -> f64 {
        2.0 * self.body.bound_m
    }

    #[inline(never)]
    fn build_grid(&mut self) {
        let n = self.len();
        if n == 0 {
            return;
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        // A body with a non-finite position (a broken state) goes to cell 0 and does not size the grid.
        for s in self.bodies.iter().filter(|s| s.pos_m.is_finite()) {
            lo = lo.min(s.pos_m);
            hi = hi.max(s.pos_m);
        }
        // The grid's buffer is sized once (at least four cells per character); when the crowd
        // spreads wider, the cells grow instead of the buffer, so stepping never allocates. Larger
        // cells only test more pairs; they never miss one.
        if self.cell_start.is_empty() {
            let cs = self.cell_size();
            let cells = (((hi.x - lo.x) / cs) as usize + 1) * (((hi.z - lo.z) / cs) as usize + 1);
            self.cell_start.resize(cells.clamp(4 * n, 1 << 22) + 1, 0);
        }
        let mut cs = self.cell_size();
        let (mut nx, mut nz);
        loop {
            nx = (((hi.x - lo.x) / cs) as usize).saturating_add(1);
            nz = (((hi.z - lo.z) / cs) as usize).saturating_add(1);
            if nx.saturating_mul(nz) < self.cell_start.len() {
                break;
            }
            cs *= 1.5;
        }
        let cells = nx * nz;
        self.cell_start[..cells + 1].fill(0);
        for i in 0..n {
            let p = self.bodies[i].pos_m;
            let cx = (((p.x - lo.x) / cs) as usize).min(nx - 1);
            let cz = (((p.z - lo.z) / cs) as usize).min(nz - 1);
            let c = (cz * nx + cx) as u32;
            self.cell_of[i] = c;
            self.cell_start[c as usize + 1] += 1;
        }
        for c in 0..cells {
            self.cell_start[c + 1] += self.cell_start[c];
        }
        // Counting sort: each start is advanced while its items are placed, then moved back.
        for i in 0..n {
            let c = self.cell_of[i] as usize;
            let at = self.cell_start[c] as usize;
            self.cell_items[at] = i as u32;
            self.cell_start[c] += 1;
        }
        // Restore the starts (each was advanced by its count).
        for c in (1..=cells).rev() {
            self.cell_start[c] = self.cell_start[c - 1];
        }
        self.cell_start[0] = 0;
        for k in 0..n {
            self.cell_pos[k] = self.bodies[self.cell_items[k] as usize].pos_m;
        }
        self.grid_dims = (nx, nz);
    }

    /// Visits every pair of characters in the same or adjacent cells once: each cell against
    /// itself and its four "forward" neighbours, on positions stored in cell order (sequential).
    #[inline(never)]
    fn pair_contacts(&mut self) {
        let (nx, nz) = self.grid_dims;
        let reach = (2.0 * self.body.bound_m).powi(2);
        const FORWARD: [(isize, isize); 4] = [(1, 0), (-1, 1), (0, 1), (1, 1)];
        for cz in 0..nz {
            for cx in 0..nx {
                let cell = cz * nx + cx;
                let (a, b) = (self.cell_start[cell] as usize, self.cell_start[cell + 1] as usize);
                for k in a..b {
                    let pk = self.cell_pos[k];
                    for k2 in k + 1..b {
                        if (pk - self.cell_pos[k2]).length_squared() <= reach {
                            self.near(k, k2);
                        }
                    }
                    for (ox, oz) in FORWARD {
                        let (x, z) = (cx as isize + ox, cz as isize + oz);
                        if x < 0 || x >= nx as isize || z >= nz as isize {
                            continue;
                        }
                        let other = z as usize * nx + x as usize;
                        let (a2, b2) = (self.cell_start[other] as usize, self.cell_start[other + 1] as usize);
                        for k2 in a2..b2 {
                            if (pk - self.cell_pos[k2]).length_squared() <= reach {
                                self.near(k, k2);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Two grid items whose bodies are near: contacts, lower character index first.
    #[inline]
    fn near(&mut self, k: usize, k2: usize) {
        let (i, j) = (self.cell_items[k] as usize, self.cell_items[k2] as usize);
        self.stats.near_pairs += 1;
        // Bounding spheres reach from the feet to the head; upright neighbours' boxes in the world
        // axes are far narrower, and bodies whose boxes are apart have no shapes that touch.
        let gap = (self.box_c[i] - self.box_c[j]).abs() - self.box_e[i] - self.box_e[j];
        if gap.max_element() > AABB_MARGIN_M {
            return;
        }
        self.pair(i.min(j), i.max(j));
    }

    fn pair(&mut self, i: usize, j: usize) {
        let h = self.world.dt_s;
        let ns = self.body.shapes.len();
        let (ri, rj) = (self.rotm[i], self.rotm[j]);
        let (pos_i, pos_j) = (self.bodies[i].pos_m, self.bodies[j].pos_m);
        for ka in 0..ns {
            let (sa, la, ra) = self.body.shapes[ka];
            let pa_m = pos_i + ri * la.pos_m;
            // Most shapes of a near pair are nowhere near the other body at all.
            let reach_j = ra + self.body.bound_m;
            if (pa_m - pos_j).length_squared() > reach_j * reach_j {
                continue;
            }
            let pa = ShapePose { pos_m: pa_m, rot: ri * la.rot };
            for kb in 0..ns {
                let (sb, lb, rb) = self.body.shapes[kb];
                let pb_m = pos_j + rj * lb.pos_m;
                if (pa.pos_m - pb_m).length_squared() > (ra + rb) * (ra + rb) {
                    continue;
                }
                let pb = ShapePose { pos_m: pb_m, rot: rj * lb.rot };
                // Bounding spheres of the trunk's capsules overlap for upright neighbours a body
                // apart; their boxes in the world axes mostly do not, and shapes whose boxes are
                // apart have no hit, so skipping `collide` for them changes nothing.
                let gap = (pa.pos_m - pb.pos_m).abs() - aabb_half_m(&sa, &pa.rot) - aabb_half_m(&sb, &pb.rot);
                if gap.max_element() > AABB_MARGIN_M {
                    continue;
                }
                let nh = collide(&sa, &pa, &sb, &pb, &mut self.hits);
                if nh == 0 {
                    continue;
                }
                let share = 1.0 / nh as f64;
                for hi in 0..nh {
                    let hit = &{ self.hits[hi] };
                    let inv_m = self.inv_mass_along(i, hit.point_m, hit.normal)
                        + self.inv_mass_along(j, hit.point_m, hit.normal);
                    let vrel = self.vel_at(i, hit.point_m) - self.vel_at(j, hit.point_m);
                    let (f, _) = penalty_force(&self.world.pair, hit, inv_m, share, h, vrel);
                    self.apply_hit(i, hit, f);
                    self.apply_hit(j, hit, -f);
                    self.stats.pair_points += 1;
                }
            }
        }
    }

    /// A digest of the exact bits of every body and character, for determinism tests.
    pub fn digest(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |x: f64| {
            for b in x.to_bits().to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        eat(self.steps as f64);
        for (s, c) in self.bodies.iter().zip(&self.chars) {
            for v in [s.pos_m, s.w_body, s.vel_m_per_s] {
                eat(v.x);
                eat(v.y);
                eat(v.z);
            }
            for x in s.rot.to_array() {
                eat(x);
            }
            eat(c.anim.d_front_m);
            eat(c.anim.d_side_m);
            eat(c.control.policy as u8 as f64);
        }
        h
    }
}
