//! The looks of the built-in scenes ([`crate::look`]): which shapes, colours, labels and counters
//! each one shows, and how it writes its poses. Kept out of the scenes' own files, which change
//! for other reasons; each scene's `Scene::look`/`Scene::pose` call into here.

pub(crate) mod boxing;
pub(crate) mod crowd;

use glam::{DMat3, DQuat};

/// A rotation matrix as a unit quaternion (tolerant of rounding in the matrix).
#[inline]
pub(crate) fn quat(m: &DMat3) -> DQuat {
    DQuat::from_mat3(m).normalize()
}
