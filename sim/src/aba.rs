//! Featherstone's articulated-body algorithm: joint accelerations from joint forces in O(n).
//!
//! Solves `(M + diag(armature)) qdd = tau - C(q, v) + J^T f_ext` over a forest of joint trees,
//! where `armature` carries the implicit joint spring/damper terms (see `passive.rs`). Passes 2
//! and 3 of RBDA table 7.1; pass 1 is `state::kinematics`.
//!
//! Must never: allocate or panic. A joint whose `D` block is not positive definite (which a
//! valid model cannot produce) yields zero acceleration for that joint rather than NaN.

use glam::{DMat3, DVec3};

use crate::joint::JointKind;
use crate::model::Model;
use crate::spatial::{SInertia, SVec};
use crate::state::{State, Workspace};

/// Computes `ws.qdd` from `ws.tau + ws.tau_passive`, `ws.armature`, `ws.f_ext` and gravity.
/// Requires `kinematics` to have run for `state`.
///
/// Each joint kind runs its own instance of the passes (`backward::<N, SUB>`, `forward::<N, SUB>`
/// with `N` its degrees of freedom and `SUB` the shape of its subspace): with the sizes known at
/// compile time the small loops unroll, the 6x6 scratch blocks shrink to `N x N`, and products
/// with the subspace skip its known zeros. The arithmetic and its order are otherwise those of
/// one general `nv`-sized pass, so results are bit-for-bit the same (the pinned digests check it).
pub fn aba(model: &Model, _state: &State, ws: &mut Workspace) {
    let n = model.bodies.len();
    // Articulated inertias and bias forces start as the rigid ones.
    for (i, b) in model.bodies.iter().enumerate() {
        let v = ws.vel[i];
        let pv = v.cross_force(b.inertia.mul_motion(v));
        ws.ia[i] = b.inertia;
        // Most bodies have no external force: subtracting its transform (exact zeros) would
        // change no bit, so it is left out.
        ws.pa[i] = if ws.f_ext[i] == SVec::ZERO { pv } else { pv - ws.x0[i].apply_force(ws.f_ext[i]) };
    }
    // Backward: fold each body's articulated inertia into its parent.
    for i in (0..n).rev() {
        match model.bodies[i].joint {
            JointKind::Ball => ball_backward(model, ws, i),
            JointKind::Free => backward::<6, FREE>(model, ws, i),
            JointKind::Universal { .. } => backward::<2, ANGULAR>(model, ws, i),
            JointKind::Revolute { .. } => backward::<1, ANGULAR>(model, ws, i),
            JointKind::Fixed => backward::<0, GENERAL>(model, ws, i),
        }
    }
    // Forward: accelerations from the root out. The world accelerates upward at -g, which puts
    // gravity into every body without computing gravity forces.
    let a_world = SVec::new(glam::DVec3::ZERO, -model.gravity_m_per_s2);
    for i in 0..n {
        match model.bodies[i].joint {
            JointKind::Ball => forward::<3, ANGULAR>(model, ws, i, a_world),
            JointKind::Free => forward::<6, FREE>(model, ws, i, a_world),
            JointKind::Universal { .. } => forward::<2, ANGULAR>(model, ws, i, a_world),
            JointKind::Revolute { .. } => forward::<1, ANGULAR>(model, ws, i, a_world),
            JointKind::Fixed => forward::<0, GENERAL>(model, ws, i, a_world),
        }
    }
}

/// Subspace shapes the passes are specialised for. `GENERAL`: any `S`. `ANGULAR`: every column is
/// `(s, 0)` (ball, universal, revolute). `FREE`: the free joint's `S = [1 0; 0 R^T]` as
/// `joint_motion` lays it out (columns 0-2 unit angular, 3-5 `(0, R^T e_k)`).
///
/// The specialised products leave out only terms that are products by an exact 0 (or by 1), and
/// glam sums a product's terms in order, so each equals the general product to the bit (up to
/// the sign of an exact zero, which no later operation here turns into a different value).
const GENERAL: u8 = 0;
const ANGULAR: u8 = 1;
const FREE: u8 = 2;

/// `I s` for column `k` of a subspace of shape `SUB`.
#[inline(always)]
fn inertia_times_s<const SUB: u8>(ia: &SInertia, s: SVec, k: usize) -> SVec {
    match SUB {
        ANGULAR => SVec::new(ia.a * s.ang, ia.b.transpose() * s.ang),
        FREE if k < 3 => SVec::new(ia.a.col(k), ia.b.row(k)),
        FREE => SVec::new(ia.b * s.lin, ia.c * s.lin),
        _ => ia.mul_motion(s),
    }
}

/// `s . x` for column `k` of a subspace of shape `SUB`.
#[inline(always)]
fn s_dot<const SUB: u8>(s: SVec, k: usize, x: SVec) -> f64 {
    match SUB {
        ANGULAR => s.ang.dot(x.ang),
        FREE if k < 3 => x.ang[k],
        FREE => s.lin.dot(x.lin),
        _ => s.dot(x),
    }
}

/// `a += s q` for column `k` of a subspace of shape `SUB`.
#[inline(always)]
fn add_s_times<const SUB: u8>(a: &mut SVec, s: SVec, k: usize, q: f64) {
    match SUB {
        ANGULAR => a.ang += s.ang * q,
        FREE if k < 3 => a.ang[k] += q,
        FREE => a.lin += s.lin * q,
        _ => *a += s * q,
    }
}

/// The backward step for a joint of `N` degrees of freedom (the body's `nv`) whose subspace has
/// the shape `SUB`.
#[inline]
fn backward<const N: usize, const SUB: u8>(model: &Model, ws: &mut Workspace, i: usize) {
    let b = &model.bodies[i];
    let va = b.v_at;
    let ia = ws.ia[i];
    let s: [SVec; N] = std::array::from_fn(|k| ws.jm[i].s[k]);
    let (tau, tau_p, arm) = (&ws.tau[va..va + N], &ws.tau_passive[va..va + N], &ws.armature[va..va + N]);
    let mut u = [SVec::ZERO; N];
    let mut d = [[0.0; N]; N];
    let mut uu = [0.0; N];
    for k in 0..N {
        u[k] = inertia_times_s::<SUB>(&ia, s[k], k);
    }
    for r in 0..N {
        for c in 0..N {
            d[r][c] = s_dot::<SUB>(s[r], r, u[c]);
        }
        d[r][r] += arm[r];
        uu[r] = tau[r] + tau_p[r] - s_dot::<SUB>(s[r], r, ws.pa[i]);
    }
    let dinv = invert_spd_n::<N>(&d);
    ws.u[i][..N].copy_from_slice(&u);
    for r in 0..N {
        ws.dinv[i][r][..N].copy_from_slice(&dinv[r]);
    }
    ws.uu[i][..N].copy_from_slice(&uu);
    if let Some(p) = b.parent {
        // W = U D^-1, then Ia = IA - W U^T and pa = pA + Ia c + W u: N outer products.
        let mut ia_a = ia;
        let mut pa = ws.pa[i];
        for k in 0..N {
            let mut w = SVec::ZERO;
            for c in 0..N {
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

/// The forward step for a joint of `N` degrees of freedom and subspace shape `SUB`: its
/// accelerations and the body's.
#[inline]
fn forward<const N: usize, const SUB: u8>(model: &Model, ws: &mut Workspace, i: usize, a_world: SVec) {
    let b = &model.bodies[i];
    let a_parent = match b.parent {
        Some(p) => ws.acc[p],
        None => a_world,
    };
    let mut a = ws.xup[i].apply_motion(a_parent) + ws.cbias[i];
    let (u, dinv, uu) = (&ws.u[i], &ws.dinv[i], &ws.uu[i]);
    let mut rhs = [0.0; N];
    for r in 0..N {
        rhs[r] = uu[r] - u[r].dot(a);
    }
    let qdd = &mut ws.qdd[b.v_at..b.v_at + N];
    for r in 0..N {
        let mut s = 0.0;
        for c in 0..N {
            s += dinv[r][c] * rhs[c];
        }
        qdd[r] = s;
        add_s_times::<SUB>(&mut a, ws.jm[i].s[r], r, s);
    }
    ws.acc[i] = a;
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
    // Only the first 3 entries of each block are read (by `forward::<3>`).
    for k in 0..3 {
        ws.u[i][k] = SVec::new(ia.a.col(k), bt.col(k));
        for r in 0..3 {
            ws.dinv[i][r][k] = dinv.col(k)[r];
        }
    }
    ws.uu[i][..3].copy_from_slice(&[uu.x, uu.y, uu.z]);
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

/// Inverse of a symmetric positive-definite `N x N` block by Cholesky; zeros if the block is
/// not positive definite.
#[inline]
pub(crate) fn invert_spd_n<const N: usize>(d: &[[f64; N]; N]) -> [[f64; N]; N] {
    let mut inv = [[0.0; N]; N];
    if N == 1 {
        if d[0][0] > 0.0 {
            inv[0][0] = 1.0 / d[0][0];
        }
        return inv;
    }
    // L L^T = D
    let mut l = [[0.0; N]; N];
    for j in 0..N {
        let mut s = d[j][j];
        for k in 0..j {
            s -= l[j][k] * l[j][k];
        }
        if !(s > 0.0) {
            return [[0.0; N]; N];
        }
        let ljj = s.sqrt();
        l[j][j] = ljj;
        for i in (j + 1)..N {
            let mut s = d[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / ljj;
        }
    }
    // Solve L L^T x = e_c for each column c.
    for c in 0..N {
        let mut y = [0.0; N];
        for i in 0..N {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i][k] * y[k];
            }
            y[i] = s / l[i][i];
        }
        for i in (0..N).rev() {
            let mut s = y[i];
            for k in (i + 1)..N {
                s -= l[k][i] * inv[k][c];
            }
            inv[i][c] = s / l[i][i];
        }
    }
    inv
}
