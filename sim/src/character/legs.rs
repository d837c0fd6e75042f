//! The drawn legs stand on the controller's feet: after the keyframe interpolation gives the pose
//! (section 5), the hips and knees are turned so each ankle is where the controller's foot is
//! (two-bone inverse kinematics), and the pelvis is lowered when a foot is farther than the straight
//! leg reaches. The keyframes still decide the style (how the knee points, the arms, the trunk); the
//! feet decide where the legs end, so a planted foot stays where it was put while the body moves
//! over it, and a swinging foot lifts.
//!
//! Also forward kinematics of the skeleton ([`joint_positions`]), for tools, tests and viewers.
//!
//! Must never: allocate, or return a non-unit rotation.

use glam::{Quat, Vec3};

use super::skeleton::{Joint, SkeletonPose, MAX_JOINTS};

/// The two legs of a skeleton: hip, knee and ankle joints (each the parent of the next), the
/// segment lengths, and the joints from the root to each hip.
#[derive(Clone, Debug, PartialEq)]
pub struct Legs {
    pub hip: [usize; 2],
    pub knee: [usize; 2],
    pub ankle: [usize; 2],
    pub thigh_m: [f32; 2],
    pub shin_m: [f32; 2],
    /// Height of the ankle joint above the sole (m): the target is this far above the foot.
    pub ankle_height_m: f32,
    /// Joints from the root to each hip's parent, root first.
    chain: [[u8; MAX_JOINTS]; 2],
    chain_len: [u8; 2],
    /// Each hip's offset from its parent, in single precision; and whether both hips hang from
    /// the same joint (then its frame is computed once).
    hip_off: [Vec3; 2],
    same_parent: bool,
    /// The root joint's rest offset, single precision.
    root_off: Vec3,
}

/// Lowest the pelvis goes for the feet to reach the floor (m).
const PELVIS_DROP_MAX_M: f32 = 0.25;

impl Legs {
    /// The legs ending at the ankles `ankle` (left, right). Knees are the ankles' parents, hips the
    /// knees'. Errors name what is wrong.
    pub fn new(joints: &[Joint], ankle: [usize; 2], ankle_height_m: f32) -> Result<Legs, String> {
        let mut legs = Legs {
            hip: [0; 2],
            knee: [0; 2],
            ankle,
            thigh_m: [0.0; 2],
            shin_m: [0.0; 2],
            ankle_height_m,
            chain: [[0; MAX_JOINTS]; 2],
            chain_len: [0; 2],
            hip_off: [Vec3::ZERO; 2],
            same_parent: false,
            root_off: joints[0].offset_m.as_vec3(),
        };
        for k in 0..2 {
            let a = ankle[k];
            let knee =
                joints[a].parent.ok_or_else(|| format!("ankle {:?} has no parent (knee)", joints[a].name))?;
            let hip = joints[knee]
                .parent
                .ok_or_else(|| format!("knee {:?} has no parent (hip)", joints[knee].name))?;
            let hip_parent =
                joints[hip].parent.ok_or_else(|| format!("hip {:?} cannot be the root", joints[hip].name))?;
            for (name, o) in
                [(&joints[knee].name, joints[knee].offset_m), (&joints[a].name, joints[a].offset_m)]
            {
                if o.x.abs() > 1e-6 || o.z.abs() > 1e-6 || !(o.y < 0.0) {
                    return Err(format!(
                        "{name:?} must hang straight below its parent at rest (offset (0, -length, 0)), got {o}"
                    ));
                }
            }
            legs.hip[k] = hip;
            legs.knee[k] = knee;
            legs.hip_off[k] = joints[hip].offset_m.as_vec3();
            legs.thigh_m[k] = -joints[knee].offset_m.y as f32;
            legs.shin_m[k] = -joints[a].offset_m.y as f32;
            // The chain root .. hip parent.
            let mut up = [0u8; MAX_JOINTS];
            let mut n = 0;
            let mut j = Some(hip_parent);
            while let Some(i) = j {
                up[n] = i as u8;
                n += 1;
                j = joints[i].parent;
            }
            for (t, &i) in up[..n].iter().rev().enumerate() {
                legs.chain[k][t] = i;
            }
            legs.chain_len[k] = n as u8;
        }
        if legs.ankle[0] == legs.ankle[1] || legs.hip[0] == legs.hip[1] {
            return Err("the two legs must be different joints".into());
        }
        legs.same_parent = joints[legs.hip[0]].parent == joints[legs.hip[1]].parent;
        Ok(legs)
    }

    /// Position and rotation of the frame of hip `k`'s parent in `S_r`.
    #[inline]
    fn hip_parent_frame(&self, joints: &[Joint], pose: &SkeletonPose, k: usize) -> (Vec3, Quat) {
        if self.chain_len[k] == 1 {
            // The hips hang from the root (the usual skeleton): its offset and rotation.
            return (self.root_off + pose.root_m, pose.rot[0]);
        }
        let (mut p, mut r) = (Vec3::ZERO, Quat::IDENTITY);
        for &i in &self.chain[k][..self.chain_len[k] as usize] {
            let i = i as usize;
            let off = joints[i].offset_m.as_vec3() + if i == 0 { pose.root_m } else { Vec3::ZERO };
            p += r * off;
            r *= pose.rot[i];
        }
        (p, r)
    }

    /// Turns the legs of `pose` toward ankle targets (`S_r`), leg `k` by `weight[k]` in [0, 1]
    /// (0 leaves the keyframe's leg). `up` is the world's up in `S_r`: the pelvis is lowered along
    /// it when a weighted target is beyond the straight leg. `floor_m`: how far below the origin of
    /// `S_r` the floor is, along `up`; a leg only partly on its target (the hand-over between the feet
    /// and the keyframes) is kept from going through it.
    pub fn reach(
        &self,
        joints: &[Joint],
        pose: &mut SkeletonPose,
        target: [Vec3; 2],
        weight: [f32; 2],
        up: Vec3,
        floor_m: f32,
    ) {
        if weight[0] <= 0.0 && weight[1] <= 0.0 {
            return;
        }
        let mut frame = [(Vec3::ZERO, Quat::IDENTITY); 2];
        let mut hip = [Vec3::ZERO; 2];
        let mut drop = 0.0f32;
        for k in 0..2 {
            frame[k] =
                if k == 1 && self.same_parent { frame[0] } else { self.hip_parent_frame(joints, pose, k) };
            hip[k] = frame[k].0 + frame[k].1 * self.hip_off[k];
            if weight[k] <= 0.0 {
                continue;
            }
            // Lower the hip along `up` until the target is within reach: |r + up d| = L.
            let reach = (self.thigh_m[k] + self.shin_m[k]) * 0.999;
            let r = target[k] - hip[k];
            let ru = r.dot(up);
            let c = r.length_squared() - reach * reach;
            if c > 0.0 {
                let disc = ru * ru - c;
                let d = if disc >= 0.0 { -ru - disc.sqrt() } else { -ru };
                drop = drop.max(d * weight[k]);
            }
        }
        let drop = drop.clamp(0.0, PELVIS_DROP_MAX_M);
        if drop > 0.0 {
            pose.root_m -= up * drop;
            for k in 0..2 {
                frame[k].0 -= up * drop;
                hip[k] -= up * drop;
            }
        }
        for k in 0..2 {
            let w = weight[k].min(1.0);
            if w <= 0.0 {
                continue;
            }
            let (a, b) = (self.thigh_m[k], self.shin_m[k]);
            let to = target[k] - hip[k];
            let len = to.length();
            if !(len > 1e-6) {
                continue;
            }
            let d = len.clamp((a - b).abs() + 1e-4, a + b - 1e-4);
            // The knee's bend from straight: pi minus the triangle's angle at the knee.
            let cos_knee = ((a * a + b * b - d * d) / (2.0 * a * b)).clamp(-1.0, 1.0);
            // Half-angle of the bend: cos(bend / 2) = sin(knee / 2), sin(bend / 2) = cos(knee / 2).
            let (s2, c2) = (((1.0 - cos_knee) * 0.5).sqrt(), ((1.0 + cos_knee) * 0.5).sqrt());
            let knee = Quat::from_xyzw(c2, 0.0, 0.0, s2);
            // With that bend the ankle is, in the hip's frame, at (0, -a - b cos(bend), -b sin(bend)),
            // which is `d` from the hip; in S_r, turned by the hip's rotation.
            // sin(bend) = 2 sin(bend / 2) cos(bend / 2).
            let (cos_bend, sin_bend) = (-cos_knee, 2.0 * c2 * s2);
            let hip_rot = frame[k].1 * pose.rot[self.hip[k]];
            let now = hip_rot * Vec3::new(0.0, -a - b * cos_bend, -b * sin_bend);
            // The shortest rotation from `now` to `to` (both of length `d`, `len`): the
            // normalised (u x v, 1 + u . v) of the unit vectors.
            let (u, v) = (now * (1.0 / d), to * (1.0 / len));
            let dot = u.dot(v);
            if dot < -0.999 {
                // Pointing the other way: no use turning a leg half a turn.
                continue;
            }
            let swing = Quat::from_vec4(u.cross(v).extend(1.0 + dot)).normalize();
            // Unit quaternions multiply to a unit quaternion (to rounding; the next step starts
            // again from the keyframes).
            let hip_local = frame[k].1.conjugate() * swing * hip_rot;
            pose.rot[self.hip[k]] = nlerp(pose.rot[self.hip[k]], hip_local, w);
            pose.rot[self.knee[k]] = nlerp(pose.rot[self.knee[k]], knee, w);
        }
        if weight[0] < 1.0 || weight[1] < 1.0 {
            // Blended legs end between the feet and the keyframe's legs, with the pelvis lowered
            // for the feet: lift the figure if that puts an ankle through the floor.
            let mut lowest = f32::INFINITY;
            for k in 0..2 {
                let (_, r_parent) = frame[k];
                let hip_rot = r_parent * pose.rot[self.hip[k]];
                let knee_pos = hip[k] + hip_rot * joints[self.knee[k]].offset_m.as_vec3();
                let ankle =
                    knee_pos + hip_rot * pose.rot[self.knee[k]] * joints[self.ankle[k]].offset_m.as_vec3();
                lowest = lowest.min(ankle.dot(up));
            }
            let below = -floor_m - lowest;
            if below > 0.0 {
                pose.root_m += up * below;
            }
        }
    }
}

/// Positions of the first `joints.len()` joints of `pose` in `S_r` (m).
pub fn joint_positions(joints: &[Joint], pose: &SkeletonPose, out: &mut [Vec3; MAX_JOINTS]) {
    let mut rot = [Quat::IDENTITY; MAX_JOINTS];
    for (i, j) in joints.iter().enumerate().take(MAX_JOINTS) {
        let off = j.offset_m.as_vec3();
        match j.parent {
            None => {
                out[i] = off + pose.root_m;
                rot[i] = pose.rot[i];
            }
            Some(p) => {
                out[i] = out[p] + rot[p] * off;
                rot[i] = rot[p] * pose.rot[i];
            }
        }
    }
}

#[inline]
fn nlerp(a: Quat, b: Quat, w: f32) -> Quat {
    if w >= 1.0 {
        return b;
    }
    let b = if a.dot(b) < 0.0 { -b } else { b };
    (a * (1.0 - w) + b * w).normalize()
}
