//! The drawn figure measured against the simulated body: where each joint of the pose a viewer
//! draws is in the world, how far it is outside the body's collision shapes, whether it is below the
//! floor, how far it jumps in one step, and how far a drawn foot slides while its foot is planted.
//! The character tests and `spidar eval poses` use these; the live view draws the same joints.
//!
//! A figure takes some 0.3 us a character to compute, too long for the world's stepping thread in
//! a big crowd. So a viewer or a recorder copies each character's [`FigureState`] there (the few
//! numbers a figure depends on that change from step to step, a copy of a few hundred bytes) and
//! computes the figures on its own thread with [`Figures`] (what never changes), while the crowd
//! steps on: the same joints, bit for bit, as [`world_joints`] gives at the step copied.
//!
//! Must never: change a character; these only read.

use glam::{DMat3, DQuat, DVec3, Vec3};

use super::controller::{ControllerState, Ground};
use super::crowd::{Crowd, CrowdBody, StartPose, PARALLEL_MIN};
use super::feet::{Feet, Foot};
use super::keyframe::KeyframeSet;
use super::legs::joint_positions;
use super::params::ControllerParams;
use super::skeleton::{Joint, SkeletonPose, MAX_JOINTS};
use super::{Character, Correspondence};
use crate::collide::Shape;

/// World positions of the joints of character `i` as drawn: its pose ([`Crowd::pose`], in `S_r`)
/// placed at the body's centre of mass and orientation. Returns how many joints the skeleton has.
pub fn world_joints(c: &Crowd, i: usize, out: &mut [DVec3; MAX_JOINTS]) -> usize {
    let mut pose = SkeletonPose::default();
    c.pose(i, &mut pose);
    world_joints_of(c, i, &pose, out)
}

/// [`world_joints`] of a pose already computed.
pub fn world_joints_of(c: &Crowd, i: usize, pose: &SkeletonPose, out: &mut [DVec3; MAX_JOINTS]) -> usize {
    let s = &c.bodies[i];
    place(&c.set.joints, pose, s.pos_m, s.rot, c.body.com_m, out)
}

/// The joints of `pose` (in `S_r`) placed on a body at `pos_m`, `rot` whose centre of mass is at
/// `com_m` in its own frame. Returns how many joints the skeleton has.
fn place(
    joints: &[Joint],
    pose: &SkeletonPose,
    pos_m: DVec3,
    rot: DQuat,
    com_m: DVec3,
    out: &mut [DVec3; MAX_JOINTS],
) -> usize {
    let n = joints.len().min(MAX_JOINTS);
    let mut local = [Vec3::ZERO; MAX_JOINTS];
    joint_positions(joints, pose, &mut local);
    let r = DMat3::from_quat(rot);
    let com = pos_m + r * com_m;
    for k in 0..n {
        out[k] = com + r * local[k].as_dvec3();
    }
    n
}

/// What character `i`'s drawn figure depends on that changes from step to step, copied after a
/// step ([`FigureState::of`], under 256 bytes): the body's pose after the step and at its start, and the
/// parts of the correspondence, the feet and the floor that [`Character::pose`] reads.
/// [`Figures::world_joints`] turns it into the figure [`world_joints`] gives at that step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FigureState {
    /// The body's pose after the step (where the figure is placed).
    pub pos_m: DVec3,
    pub rot: DQuat,
    /// The body at the step's start (where the pose is computed from).
    pub start: StartPose,
    pub anim: Correspondence,
    /// Each foot's place on the floor and its swing (time into it, length; 0: planted).
    pub foot_m: [DVec3; 2],
    pub swing_s: [[f64; 2]; 2],
    /// How much the drawn legs stand on the feet.
    pub grip: f32,
    /// The floor under it as the step's contacts saw it: normal force (N) and height (m).
    pub ground_n: f64,
    pub ground_y_m: f64,
}

// What a viewer copies per character on the stepping thread: kept small.
const _: () = assert!(std::mem::size_of::<FigureState>() <= 256);

impl FigureState {
    /// Character `i`'s state as it is drawn now.
    #[inline]
    pub fn of(c: &Crowd, i: usize) -> FigureState {
        let (b, ch) = (&c.bodies[i], &c.chars[i]);
        let feet = &ch.control.feet;
        let foot = |k: usize| &feet.foot[k];
        FigureState {
            pos_m: b.pos_m,
            rot: b.rot,
            start: c.starts[i],
            anim: ch.anim,
            foot_m: [foot(0).pos_m, foot(1).pos_m],
            swing_s: [[foot(0).swing_s, foot(0).swing_s_total], [foot(1).swing_s, foot(1).swing_s_total]],
            grip: feet.grip,
            ground_n: ch.ground.normal_n,
            ground_y_m: ch.ground.point_m.y,
        }
    }

    /// The character as far as the drawn pose reads it (the rest left at its default).
    fn character(&self) -> Character {
        let foot = |k: usize| Foot {
            pos_m: self.foot_m[k],
            swing_s: self.swing_s[k][0],
            swing_s_total: self.swing_s[k][1],
            ..Foot::default()
        };
        Character {
            anim: self.anim,
            control: ControllerState {
                feet: Feet { foot: [foot(0), foot(1)], grip: self.grip, ..Feet::default() },
                ..ControllerState::default()
            },
            ground: Ground { normal_n: self.ground_n, point_m: DVec3::new(0.0, self.ground_y_m, 0.0) },
            ..Character::default()
        }
    }
}

/// Every character's [`FigureState`] (as many as `out` holds), in `out`.
pub fn figure_states(c: &Crowd, out: &mut [FigureState]) {
    for (i, s) in out.iter_mut().take(c.len()).enumerate() {
        *s = FigureState::of(c, i);
    }
}

/// What every drawn figure of a crowd depends on that never changes: the keyframe set (skeleton,
/// keys, legs), the controller's step height, the body's centre of mass. Made once
/// ([`Figures::of`]) for the thread that turns [`FigureState`]s into figures.
#[derive(Clone, Debug)]
pub struct Figures {
    set: KeyframeSet,
    controller: ControllerParams,
    com_m: DVec3,
}

impl Figures {
    pub fn of(c: &Crowd) -> Figures {
        Figures { set: c.set.clone(), controller: c.params.controller, com_m: c.body.com_m }
    }

    /// Joints of the skeleton.
    pub fn joints(&self) -> usize {
        self.set.joints.len().min(MAX_JOINTS)
    }

    /// The world positions of the joints of the figure of `s` (as [`world_joints`] gives them at
    /// the step `s` was copied after). Returns how many joints the skeleton has.
    pub fn world_joints(&self, s: &FigureState, out: &mut [DVec3; MAX_JOINTS]) -> usize {
        let mut pose = SkeletonPose::default();
        s.character().pose(&s.start.space(), &self.set, &self.controller, &mut pose);
        place(&self.set.joints, &pose, s.pos_m, s.rot, self.com_m, out)
    }
}

/// Every character's drawn figure in the world ([`world_joints`]), handed to `f(i, joints, slot)`
/// with character `i`'s share of `out` (`per` items each; as many characters as `out` holds): on
/// all of rayon's threads for crowds of [`PARALLEL_MIN`] or more, like the step. What a viewer or
/// a recorder asks for, at its own rate (a step computes no poses).
pub fn for_each_figure<T: Send>(
    c: &Crowd,
    out: &mut [T],
    per: usize,
    f: impl Fn(usize, &[DVec3], &mut [T]) + Sync,
) {
    if per == 0 {
        return;
    }
    let n = c.len().min(out.len() / per);
    let one = |i: usize, slot: &mut [T]| {
        let mut j = [DVec3::ZERO; MAX_JOINTS];
        let k = world_joints(c, i, &mut j);
        f(i, &j[..k], slot);
    };
    let out = &mut out[..n * per];
    if n >= PARALLEL_MIN && rayon::current_num_threads() > 1 {
        use rayon::prelude::*;
        out.par_chunks_mut(per).enumerate().with_min_len(64).for_each(|(i, s)| one(i, s));
    } else {
        for (i, s) in out.chunks_mut(per).enumerate() {
            one(i, s);
        }
    }
}

/// How far `p` (world) is outside every collision shape of character `i`'s body (0 inside one).
pub fn outside_body(body: &CrowdBody, c: &Crowd, i: usize, p: DVec3) -> f64 {
    let s = &c.bodies[i];
    let r = DMat3::from_quat(s.rot);
    let mut best = f64::INFINITY;
    for (shape, local, _) in &body.shapes {
        let centre = s.pos_m + r * local.pos_m;
        let rot = r * local.rot;
        let q = rot.transpose() * (p - centre);
        let d = match *shape {
            Shape::Sphere { radius_m } => q.length() - radius_m,
            Shape::Capsule { half_length_m, radius_m } => {
                let y = q.y.clamp(-half_length_m, half_length_m);
                (q - DVec3::new(0.0, y, 0.0)).length() - radius_m
            }
            Shape::Box { half_extents_m } => (q.abs() - half_extents_m).max(DVec3::ZERO).length(),
            Shape::Plane => continue,
        };
        best = best.min(d);
    }
    best.max(0.0)
}

/// Running measures of one character's drawn figure over a motion (feed it after every step).
#[derive(Clone, Debug, Default)]
pub struct FigureStats {
    /// Worst distance outside the body's shapes (m), over the trunk joints (all but the arms' and
    /// legs' last two), over every joint while lying or standing up, and over every joint always.
    pub trunk_outside_m: f64,
    pub lying_outside_m: f64,
    pub any_outside_m: f64,
    /// Lowest any joint went below the floor (m, positive below).
    pub below_floor_m: f64,
    /// Largest move of one joint in one step (m).
    pub max_jump_m: f64,
    /// Largest slide of a drawn ankle over one stance of its foot (m).
    pub max_slide_m: f64,
    /// Highest a drawn ankle rose above its standing height while its foot swung (m).
    pub max_lift_m: f64,
    /// Steps measured.
    pub steps: usize,
    /// Where the worst lying distance and the lowest joint were: (step, joint index).
    pub worst_lying_at: (usize, usize),
    pub jump_at: (usize, usize),
    pub lowest_at: (usize, usize),
    prev: Option<[DVec3; MAX_JOINTS]>,
    stance_start: [Option<DVec3>; 2],
    stance_ankle: [DVec3; 2],
}

/// Joints whose names end like these are limbs' ends (hands, elbows, knees, ankles): they may
/// reach out of the body while it stands and steps; the others are the trunk.
fn is_limb(name: &str) -> bool {
    ["_hand", "_elbow", "_knee", "_ankle"].iter().any(|e| name.ends_with(e))
}

impl FigureStats {
    /// Measures character `i` of `c` now. `floor_y`: the floor's height.
    pub fn add(&mut self, c: &Crowd, i: usize, floor_y: f64) {
        let mut j = [DVec3::ZERO; MAX_JOINTS];
        let n = world_joints(c, i, &mut j);
        let b = c.body_space(i);
        let policy = c.chars[i].control.policy;
        let lying = b.tilt() > 75f64.to_radians() || policy == super::controller::Policy::StandUp;
        for k in 0..n {
            let out = outside_body(&c.body, c, i, j[k]);
            self.any_outside_m = self.any_outside_m.max(out);
            if !is_limb(&c.set.joints[k].name) {
                self.trunk_outside_m = self.trunk_outside_m.max(out);
            }
            if lying && out > self.lying_outside_m {
                self.lying_outside_m = out;
                self.worst_lying_at = (self.steps, k);
            }
            if floor_y - j[k].y > self.below_floor_m {
                self.below_floor_m = floor_y - j[k].y;
                self.lowest_at = (self.steps, k);
            }
        }
        if let Some(prev) = &self.prev {
            for k in 0..n {
                let d = (j[k] - prev[k]).length();
                if d > self.max_jump_m {
                    self.max_jump_m = d;
                    self.jump_at = (self.steps, k);
                }
            }
        }
        self.prev = Some(j);
        // Feet: a planted foot's drawn ankle must stay where it was when the foot landed.
        if let (Some(legs), feet) = (&c.set.legs, &c.chars[i].control.feet) {
            for k in 0..2 {
                let ankle = j[legs.ankle[k]];
                let f = &feet.foot[k];
                let held = feet.placed
                    && f.planted()
                    && !f.dragged
                    && super::legs_weight(b.e_yr.y) * feet.grip >= 1.0;
                if held {
                    let start = *self.stance_start[k].get_or_insert(ankle);
                    self.max_slide_m = self.max_slide_m.max((ankle - start).length());
                    self.stance_ankle[k] = ankle;
                } else {
                    self.stance_start[k] = None;
                    if feet.placed && !f.planted() {
                        let rise = ankle.y - (floor_y + legs.ankle_height_m as f64);
                        self.max_lift_m = self.max_lift_m.max(rise);
                    }
                }
            }
        }
        self.steps += 1;
    }
}
