//! The drawn figure measured against the simulated body: where each joint of the pose a viewer
//! draws is in the world, how far it is outside the body's collision shapes, whether it is below the
//! floor, how far it jumps in one step, and how far a drawn foot slides while its foot is planted.
//! The character tests and `spidar eval poses` use these; the live view draws the same joints.
//!
//! Must never: change a character; these only read.

use glam::{DMat3, DVec3, Vec3};

use super::crowd::{Crowd, CrowdBody, PARALLEL_MIN};
use super::keyframe::{Pose, MAX_JOINTS};
use super::legs::joint_positions;
use crate::collide::Shape;

/// World positions of the joints of character `i` as drawn: its pose ([`Crowd::pose`], in `S_r`)
/// placed at the body's centre of mass and orientation. Returns how many joints the skeleton has.
pub fn world_joints(c: &Crowd, i: usize, out: &mut [DVec3; MAX_JOINTS]) -> usize {
    let mut pose = Pose::default();
    c.pose(i, &mut pose);
    world_joints_of(c, i, &pose, out)
}

/// [`world_joints`] of a pose already computed.
pub fn world_joints_of(c: &Crowd, i: usize, pose: &Pose, out: &mut [DVec3; MAX_JOINTS]) -> usize {
    let n = c.set.joints.len().min(MAX_JOINTS);
    let mut local = [Vec3::ZERO; MAX_JOINTS];
    joint_positions(&c.set.joints, pose, &mut local);
    let s = &c.bodies[i];
    let r = DMat3::from_quat(s.rot);
    let com = s.pos_m + r * c.body.com_m;
    for k in 0..n {
        out[k] = com + r * local[k].as_dvec3();
    }
    n
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
