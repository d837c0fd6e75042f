//! Featherstone's articulated-body algorithm: joint accelerations from joint forces in O(n).
//!
//! Solves `(M + diag(armature)) qdd = tau - C(q, v) + J^T f_ext` over a forest of joint trees,
//! where `armature` carries the implicit joint spring/damper terms (see `passive.rs`). Passes 2
//! and 3 of RBDA table 7.1; pass 1 is `state::kinematics`.
//!
//! Must never: allocate or panic. A joint whose `D` block is not positive definite (which a
//! valid model cannot produce) yields zero acceleration for that joint rather than NaN.

use glam::{DMat3, DVec3};

use crate::joint::{JointKind, MAX_JOINT_DOF};
use crate::model::Model;
use crate::spatial::{SInertia, SVec};
use crate::state::{State, Workspace};

/// Computes `ws.qdd` from `ws.tau + ws.tau_passive`, `ws.armature`, `ws.f_ext` and gravity.
/// Requires `kinematics` to have run for `state`.
pub fn aba(model: &Model, _state: &State, ws: &mut Workspace) {
    let n = model.bodies.len();
    // Articulated inertias and bias forces start as the rigid ones.
    for (i, b) in model.bodies.iter().enumerate() {
        let v = ws.vel[i];
        let fe = ws.x0[i].apply_force(ws.f_ext[i]);
        ws.ia[i] = b.inertia;
        ws.pa[i] = v.cross_force(b.inertia.mul_motion(v)) - fe;
    }
    // Backward: fold each body's articulated inertia into its parent.
    for i in (0..n).rev() {
        let b = &model.bodies[i];
        if matches!(b.joint, JointKind::Ball) {
            ball_backward(model, ws, i);
            continue;
        }
        let nd = b.nv();
        let ia = ws.ia[i];
        let mut u = [SVec::ZERO; MAX_JOINT_DOF];
        let mut d = [[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF];
        let mut uu = [0.0; MAX_JOINT_DOF];
        for k in 0..nd {
            u[k] = ia.mul_motion(ws.jm[i].s[k]);
        }
        for r in 0..nd {
            for c in 0..nd {
                d[r][c] = ws.jm[i].s[r].dot(u[c]);
            }
            d[r][r] += ws.armature[b.v_at + r];
            uu[r] = ws.tau[b.v_at + r] + ws.tau_passive[b.v_at + r] - ws.jm[i].s[r].dot(ws.pa[i]);
        }
        let dinv = invert_spd(&d, nd);
        ws.u[i] = u;
        ws.dinv[i] = dinv;
        ws.uu[i] = uu;
        if let Some(p) = b.parent {
            // W = U D^-1, then Ia = IA - W U^T and pa = pA + Ia c + W u: nd outer products.
            let mut ia_a = ia;
            let mut pa = ws.pa[i];
            for k in 0..nd {
                let mut w = SVec::ZERO;
                for c in 0..nd {
                    w += u[c] * dinv[c][k];
                }
                ia_a.sub_outer(w, u[k]);
                pa += w * uu[k];
            }
            pa += ia_a.mul_motion(ws.cbias[i]);
            let xup = ws.xup[i];
            ws.ia[p] += ia_a.to_parent(&xup);
            ws.pa[p] += xup.inv_apply_force(pa);
        }
    }
    // Forward: accelerations from the root out. The world accelerates upward at -g, which puts
    // gravity into every body without computing gravity forces.
    let a_world = SVec::new(glam::DVec3::ZERO, -model.gravity_m_per_s2);
    for (i, b) in model.bodies.iter().enumerate() {
        let nd = b.nv();
        let a_parent = match b.parent {
            Some(p) => ws.acc[p],
            None => a_world,
        };
        let mut a = ws.xup[i].apply_motion(a_parent) + ws.cbias[i];
        let mut rhs = [0.0; MAX_JOINT_DOF];
        for r in 0..nd {
            rhs[r] = ws.uu[i][r] - ws.u[i][r].dot(a);
        }
        for r in 0..nd {
            let mut s = 0.0;
            for c in 0..nd {
                s += ws.dinv[i][r][c] * rhs[c];
            }
            ws.qdd[b.v_at + r] = s;
            a += ws.jm[i].s[r] * s;
        }
        ws.acc[i] = a;
    }
}

/// The backward step for a ball joint, whose subspace is `[1 0]^T`: the same algebra as the
/// general path with `U = (a, b^T)` and `D = a + diag(armature)`, done with 3x3 blocks (a third of
/// the work of the general path; ball joints are most of the upper body).
fn ball_backward(model: &Model, ws: &mut Workspace, i: usize) {
    let b = &model.bodies[i];
    let ia = ws.ia[i];
    let va = b.v_at;
    let arm = DVec3::new(ws.armature[va], ws.armature[va + 1], ws.armature[va + 2]);
    let d = ia.a + DMat3::from_diagonal(arm);
    let dinv = if d.determinant() > 0.0 { d.inverse() } else { DMat3::ZERO };
    let bt = ia.b.transpose();
    let tau = DVec3::new(ws.tau[va], ws.tau[va + 1], ws.tau[va + 2])
        + DVec3::new(ws.tau_passive[va], ws.tau_passive[va + 1], ws.tau_passive[va + 2]);
    let uu = tau - ws.pa[i].ang;
    let mut u = [SVec::ZERO; MAX_JOINT_DOF];
    let mut dinv6 = [[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF];
    for k in 0..3 {
        u[k] = SVec::new(ia.a.col(k), bt.col(k));
        for r in 0..3 {
            dinv6[r][k] = dinv.col(k)[r];
        }
    }
    ws.u[i] = u;
    ws.dinv[i] = dinv6;
    ws.uu[i] = [uu.x, uu.y, uu.z, 0.0, 0.0, 0.0];
    if let Some(p) = b.parent {
        // W = U D^-1 = (a D^-1, b^T D^-1); Ia = IA - W U^T; pa = pA + Ia c + W u.
        let wa = ia.a * dinv;
        let wl = bt * dinv;
        let ia_a = SInertia { a: ia.a - wa * ia.a, b: ia.b - wa * ia.b, c: ia.c - wl * ia.b };
        let pa = ws.pa[i] + SVec::new(wa * uu, wl * uu) + ia_a.mul_motion(ws.cbias[i]);
        let xup = ws.xup[i];
        ws.ia[p] += ia_a.to_parent(&xup);
        ws.pa[p] += xup.inv_apply_force(pa);
    }
}

/// Inverse of a symmetric positive-definite `n x n` block (n <= 6) by Cholesky; zeros if the
/// block is not positive definite.
pub(crate) fn invert_spd(
    d: &[[f64; MAX_JOINT_DOF]; MAX_JOINT_DOF],
    n: usize,
) -> [[f64; MAX_JOINT_DOF]; MAX_JOINT_DOF] {
    let mut inv = [[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF];
    if n == 1 {
        if d[0][0] > 0.0 {
            inv[0][0] = 1.0 / d[0][0];
        }
        return inv;
    }
    // L L^T = D
    let mut l = [[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF];
    for j in 0..n {
        let mut s = d[j][j];
        for k in 0..j {
            s -= l[j][k] * l[j][k];
        }
        if !(s > 0.0) {
            return [[0.0; MAX_JOINT_DOF]; MAX_JOINT_DOF];
        }
        let ljj = s.sqrt();
        l[j][j] = ljj;
        for i in (j + 1)..n {
            let mut s = d[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / ljj;
        }
    }
    // Solve L L^T x = e_c for each column c.
    for c in 0..n {
        let mut y = [0.0; MAX_JOINT_DOF];
        for i in 0..n {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i][k] * y[k];
            }
            y[i] = s / l[i][i];
        }
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in (i + 1)..n {
                s -= l[k][i] * inv[k][c];
            }
            inv[i][c] = s / l[i][i];
        }
    }
    inv
}
