//! A keyframe character's skeleton and its pose: the joints (names, parents, rest offsets) and one
//! pose of them. Apart from the keyframe set and the legs so that both read them without
//! importing each other.
//!
//! Must never: hold more than [`MAX_JOINTS`] joints (poses are fixed-capacity so posing allocates
//! nothing).

use glam::{DVec3, Quat, Vec3};

/// Most joints a skeleton may have.
pub const MAX_JOINTS: usize = 16;

/// One joint of a skeleton.
#[derive(Clone, Debug)]
pub struct Joint {
    pub name: String,
    pub parent: Option<usize>,
    pub offset_m: DVec3,
}

/// A skeleton pose in the body frame `S_r`: each joint's rotation relative to its parent (at rest
/// all joint frames are aligned with `S_r`), and the root joint's offset from its rest position.
/// Single precision: a pose is for display (the physics is all f64), and f32 quaternions blend
/// four at a time in SIMD registers, which is what makes posing thousands of characters cheap.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkeletonPose {
    pub rot: [Quat; MAX_JOINTS],
    pub root_m: Vec3,
}

impl Default for SkeletonPose {
    fn default() -> Self {
        SkeletonPose { rot: [Quat::IDENTITY; MAX_JOINTS], root_m: Vec3::ZERO }
    }
}

impl SkeletonPose {
    /// Largest rotation angle between two poses over the first `n` joints (rad), from the chord
    /// `|a - b| = 2 sin(angle / 4)` (well conditioned for nearly equal rotations, unlike acos).
    pub fn max_angle_to(&self, o: &SkeletonPose, n: usize) -> f64 {
        (0..n)
            .map(|j| {
                let (a, b) = (self.rot[j].as_dquat(), o.rot[j].as_dquat());
                let b = if a.dot(b) < 0.0 { -b } else { b };
                let chord = (a - b).length();
                4.0 * (0.5 * chord).min(1.0).asin()
            })
            .fold(0.0, f64::max)
    }
}
