//! The crowd stepper: thousands of single-rigid-body characters stepped per 3 ms step (the
//! project's goals: 5,000 on one core, 10,000 on two). Their drawn poses are computed only when
//! someone draws them ([`Crowd::pose`]), at the drawer's rate: nothing in a step depends on them.
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
use super::keyframe::KeyframeSet;
use super::params::TiltCosines;
use super::skeleton::SkeletonPose;
use super::space::BodySpace;
use super::{Character, CharacterParams};
use crate::collide::{bounding_radius, box_on_plane, collide, plane_normal, Hit, Shape, ShapePose, MAX_HITS};
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

/// Where a character's body was at the start of a step, as far as its drawn pose needs it: its
/// rigid-body space there ([`StartPose::space`]) without the velocities, which no pose reads.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StartPose {
    /// Body -> world rotation.
    pub rot: DQuat,
    /// Centre of mass in the world (m).
    pub r_m: DVec3,
}

impl StartPose {
    /// The rigid-body space at the start of the step, its velocities zero.
    #[inline]
    pub fn space(&self) -> BodySpace {
        BodySpace::new(self.rot, self.r_m, DVec3::ZERO, DVec3::ZERO)
    }
}

/// The shared description of every crowd character's body.
#[derive(Clone, Debug)]
pub struct CrowdBody {
    pub mass_kg: f64,
    /// Centre of mass in the body frame.
    pub com_m: DVec3,
    pub i_com: DMat3,
    pub inv_i_com: DMat3,
    /// The inverse inertia when it is the same about every axis (the paper's 10 I): then the
    /// world inverse inertia is that scalar in every orientation, and no matrix is turned.
    pub inv_i_iso: Option<f64>,
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
            inv_i_iso: (i_com == DMat3::from_diagonal(DVec3::splat(i_com.x_axis.x)))
                .then(|| 1.0 / i_com.x_axis.x),
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

/// What the rest of the step needs to know of a character once its own part is done: read by
/// the pair contacts of its neighbours (so kept apart from what they write) and by integration.
#[derive(Clone, Copy, Debug)]
struct Kin {
    /// Body origin, velocity (world) and rotation matrix (body -> world).
    pos_m: DVec3,
    vel_m_per_s: DVec3,
    rotm: DMat3,
    /// Angular velocity (world), world inverse inertia and centre of mass.
    w_world: DVec3,
    inv_i_world: DMat3,
    com_world: DVec3,
    /// The box in the world axes around all of the body's shapes (centre, half extents).
    box_c: DVec3,
    box_e: DVec3,
}

impl Default for Kin {
    fn default() -> Kin {
        Kin {
            pos_m: DVec3::ZERO,
            vel_m_per_s: DVec3::ZERO,
            rotm: DMat3::IDENTITY,
            w_world: DVec3::ZERO,
            inv_i_world: DMat3::IDENTITY,
            com_world: DVec3::ZERO,
            box_c: DVec3::ZERO,
            box_e: DVec3::ZERO,
        }
    }
}

/// Per character, what a step adds up: force (world) and torque about the centre of mass (world)
/// for this step, the floor's push for the next, and counts for the statistics.
#[derive(Clone, Copy, Debug, Default)]
struct Acc {
    force: DVec3,
    torque: DVec3,
    ground_moment: DVec3,
    ground_n: f64,
    scenery_points: u32,
    near: u32,
    pair_points: u32,
}

/// Shared, read-only inputs of the per-character phase.
struct Shared<'a> {
    body: &'a CrowdBody,
    world: &'a CrowdWorld,
    params: &'a CharacterParams,
    set: &'a KeyframeSet,
    statics: &'a [(Shape, ShapePose)],
    static_normal: &'a [DVec3],
    local_box_m: (DVec3, DVec3),
    cos: TiltCosines,
    wander: Option<[f64; 4]>,
    wander_speed_m_per_s: f64,
    seed: u64,
    steps: u64,
}

/// Crowds at least this large step on all of rayon's threads; smaller ones on the calling thread
/// (a handful of characters is cheaper than a hand-over, and rayon's job queue allocates now and
/// then when called from outside its pool). The results are the same bits either way.
pub const PARALLEL_MIN: usize = 256;
/// Characters per parallel task.
const CHUNK: usize = 64;

/// A crowd: bodies, characters, and the scratch of the step.
///
/// A step has three phases: every character's own part (AI, controller, scenery contacts), in
/// parallel over characters; the grid (on the calling thread); the contacts between characters
/// and integration, in parallel over characters (each sums the forces of its own pairs, in a fixed
/// order, computing each pair's contact the same way from both sides, so the two get exactly
/// opposite forces, then moves its body: the pairs read only the caches of the step's start).
/// Nothing a character computes depends on the order characters are visited, so any number of
/// threads gives the same bits (tested with 1, 2 and 4).
#[derive(Clone, Debug)]
pub struct Crowd {
    pub body: CrowdBody,
    pub world: CrowdWorld,
    pub params: CharacterParams,
    pub set: KeyframeSet,
    pub statics: Vec<(Shape, ShapePose)>,
    pub bodies: Vec<BodyState>,
    pub chars: Vec<Character>,
    /// Each character's body at the start of the last step (what its drawn pose, [`Crowd::pose`],
    /// is computed from).
    pub starts: Vec<StartPose>,
    pub time_s: f64,
    pub steps: u64,
    pub stats: CrowdStats,
    /// Pick new walk targets in this rectangle (min x, min z, max x, max z) when one is reached;
    /// `None`: goals stay as set. Only characters standing or walking to a point wander.
    pub wander: Option<[f64; 4]>,
    pub wander_speed_m_per_s: f64,
    rng: u64,
    kin: Vec<Kin>,
    acc: Vec<Acc>,
    /// Each character's position at the step's start, packed for the grid.
    pos: Vec<DVec3>,
    // Uniform grid on the floor (x, z), rebuilt every step: each character's cell, the start of
    // each cell's run in `cell_items`, the characters in cell order and their positions (so the
    // neighbour search reads positions in cell order, packed).
    cell_of: Vec<u32>,
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    cell_pos: Vec<DVec3>,
    grid: Grid,
    /// `plane_normal` of each static shape (unused for non-planes), refreshed every step.
    static_normal: Vec<DVec3>,
}

/// The grid's geometry for the current step.
#[derive(Clone, Copy, Debug, Default)]
struct Grid {
    lo_x: f64,
    lo_z: f64,
    cell_m: f64,
    nx: usize,
    nz: usize,
}

impl Grid {
    #[inline]
    fn cell(&self, p: DVec3) -> (usize, usize) {
        if !p.is_finite() {
            // A broken state goes to cell 0 and meets only what is there.
            return (0, 0);
        }
        let cx = (((p.x - self.lo_x) / self.cell_m).max(0.0) as usize).min(self.nx - 1);
        let cz = (((p.z - self.lo_z) / self.cell_m).max(0.0) as usize).min(self.nz - 1);
        (cx, cz)
    }
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
            starts: Vec::new(),
            time_s: 0.0,
            steps: 0,
            stats: CrowdStats::default(),
            wander: None,
            wander_speed_m_per_s: 1.0,
            rng: 0x9e37_79b9_7f4a_7c15,
            kin: Vec::new(),
            acc: Vec::new(),
            pos: Vec::new(),
            cell_of: Vec::new(),
            cell_start: Vec::new(),
            cell_items: Vec::new(),
            cell_pos: Vec::new(),
            grid: Grid::default(),
            static_normal: Vec::new(),
        }
    }

    /// A crowd with the same body, world, settings, keyframes and scenery, and no characters (for
    /// tools and tests that study one character of a scene).
    pub fn empty_like(&self) -> Crowd {
        let mut c = Crowd::new(self.body.clone(), self.world, self.params, self.set.clone());
        c.statics = self.statics.clone();
        c
    }

    /// Seeds the crowd's own random numbers (wander targets, and [`Crowd::random`]).
    pub fn seed(&mut self, seed: u64) {
        self.rng = seed ^ 0x9e37_79b9_7f4a_7c15;
    }

    /// A uniform number in [0, 1) (splitmix64) from the crowd's sequence (for placing characters;
    /// the step itself draws per character, see `wander_unit`).
    pub fn random(&mut self) -> f64 {
        self.rng = self.rng.wrapping_add(0x9e37_79b9_7f4a_7c15);
        unit(mix(self.rng))
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
        let b = self.body_space(self.bodies.len() - 1);
        self.starts.push(StartPose { rot, r_m: b.r_m });
        self.kin.push(Kin::default());
        self.acc.push(Acc::default());
        self.pos.push(DVec3::ZERO);
        self.cell_of.push(0);
        self.cell_items.push(0);
        self.cell_pos.push(DVec3::ZERO);
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
        body_space_of(&self.body, &self.bodies[i])
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
        self.acc[i].force += force_n;
        self.acc[i].torque += (point_m - c).cross(force_n);
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

    /// The drawn pose of character `i` as of the last step, in its body frame `S_r` (origin at the
    /// centre of mass; joints and parents in `set.joints`): the keyframe set at the point of Q its
    /// state at the start of that step maps to, the legs stood on its feet. Nothing in a step
    /// depends on a pose, so a step computes none: whoever draws (the view, the recorder, the
    /// tools) asks for the poses it draws, at its own rate, and gets exactly the pose the step
    /// would have computed.
    #[inline]
    pub fn pose(&self, i: usize, out: &mut SkeletonPose) {
        *out = SkeletonPose::default();
        self.chars[i].pose(&self.starts[i].space(), &self.set, &self.params.controller, out);
    }

    /// [`Crowd::pose`], returned.
    pub fn pose_of(&self, i: usize) -> SkeletonPose {
        let mut p = SkeletonPose::default();
        self.pose(i, &mut p);
        p
    }

    /// One step: AI and controllers, contacts, integration (no poses: see [`Crowd::pose`]).
    pub fn step(&mut self) {
        let parallel = self.len() >= PARALLEL_MIN && rayon::current_num_threads() > 1;
        let (lo, hi) = self.per_character(parallel);
        self.build_grid(lo, hi);
        let [scenery_points, near, pair_points] = self.pairs_and_integration(parallel);
        // Each pair was met from both sides.
        self.stats = CrowdStats { near_pairs: near / 2, pair_points: pair_points / 2, scenery_points };
        self.time_s += self.world.dt_s;
        self.steps += 1;
    }

    /// Everything that concerns one character alone, done while its data is in cache: AI and
    /// controller (on the floor contacts of the last step, like the engine) and contacts with the
    /// scenery. Returns the box (min, max) around the finite positions, for the grid.
    // The phases stay separate functions so a profile shows each one.
    #[inline(never)]
    fn per_character(&mut self, parallel: bool) -> (DVec3, DVec3) {
        // Scenery is a handful of shapes: this grows only when scenery is added.
        self.static_normal.clear();
        self.static_normal.extend(self.statics.iter().map(|(_, p)| plane_normal(p)));
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (shape, local, _) in &self.body.shapes {
            let e = aabb_half_m(shape, &local.rot);
            lo = lo.min(local.pos_m - e);
            hi = hi.max(local.pos_m + e);
        }
        let sh = Shared {
            body: &self.body,
            world: &self.world,
            params: &self.params,
            set: &self.set,
            statics: &self.statics,
            static_normal: &self.static_normal,
            local_box_m: ((lo + hi) * 0.5, (hi - lo) * 0.5),
            cos: self.params.controller.tilt_cosines(),
            wander: self.wander,
            wander_speed_m_per_s: self.wander_speed_m_per_s,
            seed: self.rng,
            steps: self.steps,
        };
        let bodies = &self.bodies;
        // Minima and maxima are exact in any order: the box is the same bits on any threads.
        const EMPTY: (DVec3, DVec3) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        let join = |a: (DVec3, DVec3), b: (DVec3, DVec3)| (a.0.min(b.0), a.1.max(b.1));
        let run = |base: usize,
                   chars: &mut [Character],
                   starts: &mut [StartPose],
                   kin: &mut [Kin],
                   acc: &mut [Acc],
                   pos: &mut [DVec3]| {
            let mut bx = EMPTY;
            for k in 0..chars.len() {
                let s = &bodies[base + k];
                one_character(&sh, base + k, s, &mut chars[k], &mut starts[k], &mut kin[k], &mut acc[k]);
                pos[k] = s.pos_m;
                // A body with a non-finite position (a broken state) goes to cell 0 and does not
                // size the grid.
                if s.pos_m.is_finite() {
                    bx = join(bx, (s.pos_m, s.pos_m));
                }
            }
            bx
        };
        if parallel {
            use rayon::prelude::*;
            self.chars
                .par_chunks_mut(CHUNK)
                .zip(self.starts.par_chunks_mut(CHUNK))
                .zip(self.kin.par_chunks_mut(CHUNK))
                .zip(self.acc.par_chunks_mut(CHUNK))
                .zip(self.pos.par_chunks_mut(CHUNK))
                .enumerate()
                .map(|(c, ((((ch, sp), ki), ac), po))| run(c * CHUNK, ch, sp, ki, ac, po))
                .reduce(|| EMPTY, join)
        } else {
            run(0, &mut self.chars, &mut self.starts, &mut self.kin, &mut self.acc, &mut self.pos)
        }
    }

    /// Every character sums the contacts of the pairs it is in (its own and the eight neighbouring
    /// cells, neighbours in a fixed order), then integrates (the engine's semi-implicit Euler for a
    /// free joint): its pairs read only the caches of the step's start, never a body, so each
    /// character moves as soon as its own sum is done. Returns the counts of scenery points, near
    /// pairs and pair points (each pair counted from both sides).
    #[inline(never)]
    fn pairs_and_integration(&mut self, parallel: bool) -> [usize; 3] {
        let ctx = PairCtx {
            body: &self.body,
            world: &self.world,
            kin: &self.kin,
            grid: self.grid,
            cell_start: &self.cell_start,
            cell_items: &self.cell_items,
            cell_pos: &self.cell_pos,
            cell_of: &self.cell_of,
        };
        let run = |base: usize, acc: &mut [Acc], bodies: &mut [BodyState]| {
            let mut counts = [0usize; 3];
            for (k, (a, s)) in acc.iter_mut().zip(bodies.iter_mut()).enumerate() {
                let i = base + k;
                ctx.gather(i, a);
                counts[0] += a.scenery_points as usize;
                counts[1] += a.near as usize;
                counts[2] += a.pair_points as usize;
                integrate(ctx.body, &ctx.world.gravity_m_per_s2, ctx.world.dt_s, s, a, &ctx.kin[i]);
            }
            counts
        };
        if parallel {
            use rayon::prelude::*;
            self.acc
                .par_chunks_mut(CHUNK)
                .zip(self.bodies.par_chunks_mut(CHUNK))
                .enumerate()
                .map(|(c, (a, b))| run(c * CHUNK, a, b))
                .reduce(|| [0; 3], |x, y| [x[0] + y[0], x[1] + y[1], x[2] + y[2]])
        } else {
            run(0, &mut self.acc, &mut self.bodies)
        }
    }

    /// Cell size: two bounding radii, so touching characters are in the same or adjacent cells.
    fn cell_size(&self) -> f64 {
        2.0 * self.body.bound_m
    }

    /// The grid over the box `lo`..`hi` around the characters' positions.
    #[inline(never)]
    fn build_grid(&mut self, mut lo: DVec3, mut hi: DVec3) {
        let n = self.len();
        if n == 0 {
            return;
        }
        if !lo.is_finite() {
            (lo, hi) = (DVec3::ZERO, DVec3::ZERO);
        }
        // The grid's buffer is sized once (about two cells per character); when the crowd spreads
        // wider, the cells grow instead of the buffer, so stepping never allocates and the grid
        // costs the same per character at any size. Larger cells only test more pairs; they never
        // miss one.
        if self.cell_start.len() < 2 * n + 2 {
            self.cell_start.resize((2 * n).clamp(16, 1 << 24) + 1, 0);
        }
        let mut cs = self.cell_size();
        let (nx, nz);
        loop {
            // Sizes compared as floats: a huge spread must not overflow the product.
            let fx = ((hi.x - lo.x) / cs).floor() + 1.0;
            let fz = ((hi.z - lo.z) / cs).floor() + 1.0;
            if fx * fz < self.cell_start.len() as f64 {
                (nx, nz) = (fx as usize, fz as usize);
                break;
            }
            cs *= 1.5;
        }
        self.grid = Grid { lo_x: lo.x, lo_z: lo.z, cell_m: cs, nx, nz };
        let cells = nx * nz;
        self.cell_start[..cells + 1].fill(0);
        for i in 0..n {
            let (cx, cz) = self.grid.cell(self.pos[i]);
            let c = (cz * nx + cx) as u32;
            self.cell_of[i] = c;
            self.cell_start[c as usize + 1] += 1;
        }
        for c in 0..cells {
            self.cell_start[c + 1] += self.cell_start[c];
        }
        // Counting sort, stable: each cell's characters in index order.
        for i in 0..n {
            let c = self.cell_of[i] as usize;
            let at = self.cell_start[c] as usize;
            self.cell_items[at] = i as u32;
            self.cell_pos[at] = self.pos[i];
            self.cell_start[c] += 1;
        }
        // Restore the starts (each was advanced by its count).
        for c in (1..=cells).rev() {
            self.cell_start[c] = self.cell_start[c - 1];
        }
        self.cell_start[0] = 0;
    }

    /// A digest of the exact bits of every body and character, for determinism tests.
    pub fn digest(&self) -> u64 {
        let mut d = spidar_msg::digest::Digest::new();
        d.f64(self.steps as f64);
        for (s, c) in self.bodies.iter().zip(&self.chars) {
            d.vec3(s.pos_m).vec3(s.w_body).vec3(s.vel_m_per_s);
            for x in s.rot.to_array() {
                d.f64(x);
            }
            d.f64(c.anim.d_front_m).f64(c.anim.d_side_m).f64(c.control.policy as u8 as f64);
        }
        d.value()
    }
}

/// The rigid-body space of a crowd body.
#[inline]
fn body_space_of(body: &CrowdBody, s: &BodyState) -> BodySpace {
    let w = s.rot * s.w_body;
    let c = s.rot * body.com_m;
    BodySpace::new(s.rot, s.pos_m + c, s.vel_m_per_s + w.cross(c), w)
}

/// splitmix64's output function.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) from 53 random bits.
#[inline]
fn unit(z: u64) -> f64 {
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// The `k`-th random number of character `i` at step `step`: a function of the crowd's seed and
/// these alone, so it does not depend on which thread or in which order characters are stepped.
#[inline]
fn wander_unit(seed: u64, i: usize, step: u64, k: u64) -> f64 {
    let z = seed
        ^ mix((i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ step.rotate_left(32))
        ^ k.wrapping_mul(0xd1b5_4a32_d192_ed03);
    unit(mix(z))
}

/// The engine's semi-implicit Euler for a free joint: one character's body over one step under
/// what it added up (then cleared for the next step).
#[inline]
fn integrate(body: &CrowdBody, g: &DVec3, h: f64, s: &mut BodyState, a: &mut Acc, k: &Kin) {
    let f = a.force + *g * body.mass_kg;
    let r = k.rotm;
    let t_body = r.transpose() * a.torque;
    let iw = body.i_com * s.w_body;
    let w_dot = body.inv_i_com * (t_body - s.w_body.cross(iw));
    // The body origin's acceleration: the centre of mass's minus the rotation terms.
    let c = r * body.com_m;
    let w = k.w_world;
    let a_origin = f / body.mass_kg - (r * w_dot).cross(c) - w.cross(w.cross(c));
    s.w_body += w_dot * h;
    s.vel_m_per_s += a_origin * h;
    s.pos_m += s.vel_m_per_s * h;
    s.rot = (s.rot * quat_exp(s.w_body * h)).normalize();
    a.force = DVec3::ZERO;
    a.torque = DVec3::ZERO;
}

/// One character's own part of a step (see [`Crowd::per_character`]).
#[allow(clippy::too_many_arguments)]
#[inline]
fn one_character(
    sh: &Shared<'_>,
    i: usize,
    s: &BodyState,
    ch: &mut Character,
    start: &mut StartPose,
    kin: &mut Kin,
    acc: &mut Acc,
) {
    let h = sh.world.dt_s;
    let g = -sh.world.gravity_m_per_s2.y;
    let b = body_space_of(sh.body, s);
    *start = StartPose { rot: s.rot, r_m: b.r_m };
    if let Some(area) = sh.wander {
        let pick = match ch.goal {
            Goal::WalkTo { point_m, .. } => {
                let d = DVec3::new(point_m.x - b.r_m.x, 0.0, point_m.z - b.r_m.z).length();
                d < sh.params.ai.arrive_m * 2.0
            }
            Goal::Stand => true,
            _ => false,
        };
        if pick {
            let x = area[0] + (area[2] - area[0]) * wander_unit(sh.seed, i, sh.steps, 0);
            let z = area[1] + (area[3] - area[1]) * wander_unit(sh.seed, i, sh.steps, 1);
            ch.goal = Goal::WalkTo { point_m: DVec3::new(x, 0.0, z), speed_m_per_s: sh.wander_speed_m_per_s };
        }
    }
    ch.ground = if acc.ground_n > 0.0 {
        Ground { normal_n: acc.ground_n, point_m: acc.ground_moment / acc.ground_n }
    } else {
        Ground::default()
    };
    let d = ch.think_with(sh.params, &sh.cos, sh.body.mass_kg, g, h, sh.set, &b);
    acc.force += d.force_n;
    acc.torque += (d.at_m - b.r_m).cross(d.force_n) + d.torque_n_m;
    acc.ground_n = 0.0;
    acc.ground_moment = DVec3::ZERO;
    acc.near = 0;
    acc.pair_points = 0;
    // The per-step caches (the state is fixed until integration).
    let r = DMat3::from_quat(s.rot);
    kin.pos_m = s.pos_m;
    kin.vel_m_per_s = s.vel_m_per_s;
    kin.rotm = r;
    kin.w_world = r * s.w_body;
    kin.inv_i_world = match sh.body.inv_i_iso {
        Some(k) => DMat3::from_diagonal(DVec3::splat(k)),
        None => r * sh.body.inv_i_com * r.transpose(),
    };
    kin.com_world = b.r_m;
    // The body-frame box turned into the world holds the turned shapes.
    let (c, e) = sh.local_box_m;
    kin.box_c = s.pos_m + r * c;
    kin.box_e = r.x_axis.abs() * e.x + r.y_axis.abs() * e.y + r.z_axis.abs() * e.z;
    scenery_contacts(sh, kin, acc);
}

/// Contacts of one character with the scenery (its caches filled).
#[inline]
fn scenery_contacts(sh: &Shared<'_>, k: &Kin, acc: &mut Acc) {
    let h = sh.world.dt_s;
    let inv_mass_kg = 1.0 / sh.body.mass_kg;
    let mut hits = [Hit::ZERO; MAX_HITS];
    let mut points = 0;
    for (shape, local, bound) in &sh.body.shapes {
        let pos_m = k.pos_m + k.rotm * local.pos_m;
        let mut rot = None;
        for ((ss, sp), &normal) in sh.statics.iter().zip(sh.static_normal) {
            let far = match ss {
                Shape::Plane => (pos_m - sp.pos_m).dot(sp.rot.y_axis) > *bound,
                _ => (pos_m - sp.pos_m).length_squared() > (bound + bounding_radius(ss)).powi(2),
            };
            if far {
                continue;
            }
            let pose = ShapePose { pos_m, rot: *rot.get_or_insert_with(|| k.rotm * local.rot) };
            let nh = match (shape, ss) {
                (Shape::Box { half_extents_m }, Shape::Plane) => {
                    box_on_plane(*half_extents_m, &pose, normal, sp.pos_m, &mut hits)
                }
                _ => collide(shape, &pose, ss, sp, &mut hits),
            };
            if nh == 0 {
                continue;
            }
            let share = 1.0 / nh as f64;
            for hit in hits.iter().take(nh) {
                let arm = hit.point_m - k.com_world;
                let w = arm.cross(hit.normal);
                let inv_m = inv_mass_kg + w.dot(k.inv_i_world * w);
                let vrel = k.vel_m_per_s + k.w_world.cross(hit.point_m - k.pos_m);
                let (f, _) = penalty_force(&sh.world.scenery, hit, inv_m, share, h, vrel);
                acc.force += f;
                acc.torque += arm.cross(f);
                if hit.normal.y >= 0.7 {
                    let fn_ = f.dot(hit.normal).max(0.0);
                    acc.ground_n += fn_;
                    acc.ground_moment += hit.point_m * fn_;
                }
                points += 1;
            }
        }
    }
    acc.scenery_points = points;
}

/// What the pair contacts read: every character's caches and the grid.
struct PairCtx<'a> {
    body: &'a CrowdBody,
    world: &'a CrowdWorld,
    kin: &'a [Kin],
    grid: Grid,
    cell_start: &'a [u32],
    cell_items: &'a [u32],
    cell_pos: &'a [DVec3],
    cell_of: &'a [u32],
}

impl PairCtx<'_> {
    /// Adds to `a` the contacts of character `i` with every character near it.
    #[inline]
    fn gather(&self, i: usize, a: &mut Acc) {
        let g = &self.grid;
        let reach = (2.0 * self.body.bound_m).powi(2);
        let c = self.cell_of[i] as usize;
        let (cx, cz) = ((c % g.nx) as isize, (c / g.nx) as isize);
        let pi = self.kin[i].pos_m;
        for oz in -1..=1isize {
            let z = cz + oz;
            if z < 0 || z >= g.nz as isize {
                continue;
            }
            for ox in -1..=1isize {
                let x = cx + ox;
                if x < 0 || x >= g.nx as isize {
                    continue;
                }
                let cell = z as usize * g.nx + x as usize;
                let run = self.cell_start[cell] as usize..self.cell_start[cell + 1] as usize;
                for (&j, &pj) in self.cell_items[run.clone()].iter().zip(&self.cell_pos[run]) {
                    let j = j as usize;
                    if j == i || (pi - pj).length_squared() > reach {
                        continue;
                    }
                    a.near += 1;
                    // Bounding spheres reach from the feet to the head; upright neighbours' boxes
                    // in the world axes are far narrower, and bodies whose boxes are apart have
                    // no shapes that touch.
                    let (ki, kj) = (&self.kin[i], &self.kin[j]);
                    let gap = (ki.box_c - kj.box_c).abs() - ki.box_e - kj.box_e;
                    if gap.max_element() > AABB_MARGIN_M {
                        continue;
                    }
                    // The pair is computed from its lower index, whichever side asks, so both get
                    // exactly opposite forces.
                    let (lo, hi) = (i.min(j), i.max(j));
                    let sign = if i == lo { 1.0 } else { -1.0 };
                    self.pair(lo, hi, |point, f| {
                        let f = f * sign;
                        a.force += f;
                        a.torque += (point - ki.com_world).cross(f);
                        a.pair_points += 1;
                    });
                }
            }
        }
    }

    /// Inverse effective mass of character `i` at world `p` along `n` (the engine's formula, in
    /// world coordinates).
    #[inline]
    fn inv_mass_along(&self, i: usize, p: DVec3, n: DVec3) -> f64 {
        let k = &self.kin[i];
        let w = (p - k.com_world).cross(n);
        1.0 / self.body.mass_kg + w.dot(k.inv_i_world * w)
    }

    #[inline]
    fn vel_at(&self, i: usize, p: DVec3) -> DVec3 {
        let k = &self.kin[i];
        k.vel_m_per_s + k.w_world.cross(p - k.pos_m)
    }

    /// The contacts between characters `i < j`: calls `apply(point, force on i)` for each.
    fn pair(&self, i: usize, j: usize, mut apply: impl FnMut(DVec3, DVec3)) {
        let h = self.world.dt_s;
        let ns = self.body.shapes.len();
        let (ki, kj) = (&self.kin[i], &self.kin[j]);
        let mut hits = [Hit::ZERO; MAX_HITS];
        for ka in 0..ns {
            let (sa, la, ra) = self.body.shapes[ka];
            let pa_m = ki.pos_m + ki.rotm * la.pos_m;
            // Most shapes of a near pair are nowhere near the other body at all.
            let reach_j = ra + self.body.bound_m;
            if (pa_m - kj.pos_m).length_squared() > reach_j * reach_j {
                continue;
            }
            let pa = ShapePose { pos_m: pa_m, rot: ki.rotm * la.rot };
            for kb in 0..ns {
                let (sb, lb, rb) = self.body.shapes[kb];
                let pb_m = kj.pos_m + kj.rotm * lb.pos_m;
                if (pa.pos_m - pb_m).length_squared() > (ra + rb) * (ra + rb) {
                    continue;
                }
                let pb = ShapePose { pos_m: pb_m, rot: kj.rotm * lb.rot };
                // Shapes whose boxes in the world axes are apart have no hit.
                let gap = (pa.pos_m - pb.pos_m).abs() - aabb_half_m(&sa, &pa.rot) - aabb_half_m(&sb, &pb.rot);
                if gap.max_element() > AABB_MARGIN_M {
                    continue;
                }
                let nh = collide(&sa, &pa, &sb, &pb, &mut hits);
                if nh == 0 {
                    continue;
                }
                let share = 1.0 / nh as f64;
                for hit in hits.iter().take(nh) {
                    let inv_m = self.inv_mass_along(i, hit.point_m, hit.normal)
                        + self.inv_mass_along(j, hit.point_m, hit.normal);
                    let vrel = self.vel_at(i, hit.point_m) - self.vel_at(j, hit.point_m);
                    let (f, _) = penalty_force(&self.world.pair, hit, inv_m, share, h, vrel);
                    apply(hit.point_m, f);
                }
            }
        }
    }
}
