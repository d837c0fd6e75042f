//! Prints, for every keyframe of the crowd scene's set, how far its joints are outside the body's
//! shapes and below the floor with the body lying (or leaning) at the keyframe's lean on the floor:
//! a check for the animator that a falling or lying pose is drawn on the body.
//! `cargo run --release -p spidar-sim --example keyframes`

use glam::{DMat3, DQuat, DVec3, Vec3};
use spidar_sim::character::legs::joint_positions;
use spidar_sim::character::scene::builtin_crowd;
use spidar_sim::character::skeleton::MAX_JOINTS;
use spidar_sim::collide::Shape;

fn main() {
    let c = builtin_crowd().unwrap();
    let set = &c.set;
    for k in &set.keys {
        let (tx, tz) = (k.at.theta_x, k.at.theta_z);
        let rot = DQuat::from_rotation_x(tx) * DQuat::from_rotation_z(-tz);
        let r = DMat3::from_quat(rot);
        let up = r.transpose() * DVec3::Y;
        // Lowest point of the body along `up` (S_r): where the floor touches it.
        let mut floor = f64::INFINITY;
        for (shape, local, _) in &c.body.shapes {
            let lo = match *shape {
                Shape::Sphere { radius_m } => local.pos_m.dot(up) - radius_m,
                Shape::Capsule { half_length_m, radius_m } => {
                    let a = local.rot.y_axis * half_length_m;
                    (local.pos_m + a).dot(up).min((local.pos_m - a).dot(up)) - radius_m
                }
                Shape::Box { half_extents_m: e } => {
                    let mut m = f64::INFINITY;
                    for i in 0..8 {
                        let s = DVec3::new(
                            if i & 1 == 0 { -1.0 } else { 1.0 },
                            if i & 2 == 0 { -1.0 } else { 1.0 },
                            if i & 4 == 0 { -1.0 } else { 1.0 },
                        );
                        m = m.min((local.pos_m + local.rot * (s * e)).dot(up));
                    }
                    m
                }
                Shape::Plane => continue,
            };
            floor = floor.min(lo);
        }
        let mut p = [Vec3::ZERO; MAX_JOINTS];
        joint_positions(&set.joints, &k.pose, &mut p);
        let (mut worst_out, mut out_j, mut worst_below, mut below_j) = (0.0f64, "", 0.0f64, "");
        for (j, joint) in set.joints.iter().enumerate() {
            let q = p[j].as_dvec3();
            let mut d = f64::INFINITY;
            for (shape, local, _) in &c.body.shapes {
                let l = local.rot.transpose() * (q - local.pos_m);
                d = d.min(match *shape {
                    Shape::Sphere { radius_m } => l.length() - radius_m,
                    Shape::Capsule { half_length_m, radius_m } => {
                        (l - DVec3::new(0.0, l.y.clamp(-half_length_m, half_length_m), 0.0)).length()
                            - radius_m
                    }
                    Shape::Box { half_extents_m } => (l.abs() - half_extents_m).max(DVec3::ZERO).length(),
                    Shape::Plane => continue,
                });
            }
            if d > worst_out {
                (worst_out, out_j) = (d, &joint.name);
            }
            let below = floor - q.dot(up);
            if below > worst_below {
                (worst_below, below_j) = (below, &joint.name);
            }
        }
        println!(
            "B {} thx {:6.1} thz {:6.1} dx {:.2} dz {:.3}: outside {:5.1} cm ({out_j}), below floor {:5.1} cm ({below_j})",
            k.at.behaviour,
            tx.to_degrees(),
            tz.to_degrees(),
            k.at.d_x,
            k.at.d_z,
            worst_out * 100.0,
            worst_below * 100.0
        );
    }
}
