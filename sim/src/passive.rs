//! Joint springs and dampers toward the default pose, joint limits, and the base spring of free
//! roots: the passive generalised forces, and the implicit terms that make them stable.
//!
//! Integration choice (measured in `tests::implicit_joint_springs_are_stable_where_explicit_ones_are_not`):
//! human-joint gains on light segments (a 0.6 kg hand on a 2-DOF wrist) have natural
//! frequencies whose `w dt` exceeds 2 at dt = 3 ms, where semi-implicit Euler with explicit
//! springs diverges. Because every joint spring and damper is diagonal in joint coordinates, the
//! linearly implicit step `(M + h D + h^2 K) qdd = tau(q, v) - C` is exact to first order and
//! costs nothing: `h d + h^2 k` is added to the diagonal of each joint's `D` block inside ABA (the
//! same place an armature inertia goes). It is unconditionally stable for the springs and
//! dampers, and leaves the dynamics of undamped, unsprung joints untouched.
//!
//! Must never: allocate; produce NaN for any finite state.

use glam::DVec3;

use crate::joint::{read_quat, JointKind};
use crate::model::Model;
use crate::spatial::quat_log;
use crate::state::{State, Workspace};

/// Fills `ws.tau_passive` and `ws.armature` for the state, and adds the weight support of
/// articulations whose base carries their weight to `ws.f_ext` (needs `kinematics`).
pub fn passive_forces(model: &Model, state: &State, ws: &mut Workspace) {
    for art in &model.articulations {
        if !art.carries_weight {
            continue;
        }
        // Lift the whole weight at the current centre of mass, applied to the root: this cancels
        // gravity's force and its moment about the base without changing any joint's load.
        let mut mc = DVec3::ZERO;
        for i in art.bodies.clone() {
            mc += ws.com_world(model, i) * model.bodies[i].mass_kg;
        }
        let com = mc / art.mass_kg;
        ws.add_force_at(art.bodies.start, com, -model.gravity_m_per_s2 * art.mass_kg);
    }
    let h = model.dt_s;
    let lim = model.limit;
    let q0 = &model.q_default;
    for b in &model.bodies {
        let (qa, va) = (b.q_at, b.v_at);
        let nv = b.nv();
        let v = &state.v[va..va + nv];
        // Error from the default pose per velocity coordinate, and the joint "angles" for limits.
        let mut err = [0.0; 6];
        let mut angle = [0.0; 3];
        match b.joint {
            JointKind::Free => {
                let p = DVec3::new(state.q[qa], state.q[qa + 1], state.q[qa + 2]);
                let p0 = DVec3::new(q0[qa], q0[qa + 1], q0[qa + 2]);
                let r = read_quat(&state.q[qa + 3..qa + 7]);
                let r0 = read_quat(&q0[qa + 3..qa + 7]);
                let er = quat_log(r0.inverse() * r);
                // Translation error in the parent frame, like the free joint's linear velocity.
                let ep = p - p0;
                err = [er.x, er.y, er.z, ep.x, ep.y, ep.z];
            }
            JointKind::Ball => {
                let r = read_quat(&state.q[qa..qa + 4]);
                let r0 = read_quat(&q0[qa..qa + 4]);
                let e = quat_log(r0.inverse() * r);
                err[..3].copy_from_slice(&e.to_array());
                angle = quat_log(r).to_array();
            }
            JointKind::Universal { .. } | JointKind::Revolute { .. } => {
                for k in 0..nv {
                    err[k] = state.q[qa + k] - q0[qa + k];
                    angle[k] = state.q[qa + k];
                }
            }
            JointKind::Fixed => {}
        }
        for k in 0..nv {
            let (ks, ds) = (b.stiffness[k], b.damping[k]);
            let mut tau = -ks * err[k] - ds * v[k];
            let mut arm = h * ds + h * h * ks;
            if let Some(limits) = &b.limits {
                if k < 3 {
                    let (lo, hi) = limits[k];
                    // One-sided spring beyond the limit; the damper only resists going further out,
                    // so a joint leaving its limit is not held there.
                    let over = if angle[k] > hi {
                        angle[k] - hi
                    } else if angle[k] < lo {
                        angle[k] - lo
                    } else {
                        0.0
                    };
                    if over != 0.0 {
                        tau -= lim.k_n_m_per_rad * over;
                        arm += h * h * lim.k_n_m_per_rad;
                        if over * v[k] > 0.0 {
                            tau -= lim.d_n_m_s_per_rad * v[k];
                            arm += h * lim.d_n_m_s_per_rad;
                        }
                    }
                }
            }
            ws.tau_passive[va + k] = tau;
            ws.armature[va + k] = if model.implicit_joint_springs { arm } else { 0.0 };
        }
    }
}
