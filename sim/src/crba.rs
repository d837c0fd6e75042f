//! Composite-rigid-body algorithm: the joint-space inertia matrix `M(q)`.
//!
//! Used to verify ABA (`M qdd + C = tau`) and by controllers that need the mass matrix, e.g. to
//! compute a task-space inertia. Pass 1 is `state::kinematics`.
//!
//! Must never: allocate (the output is the caller's; the composite inertias reuse `ws.ia`).

use crate::model::Model;
use crate::spatial::SVec;
use crate::state::Workspace;

/// Writes `M` (row-major, `nv x nv`) into `m_out` at the state `kinematics` was last run for.
pub fn crba(model: &Model, ws: &mut Workspace, m_out: &mut [f64]) {
    let nv = model.nv;
    m_out[..nv * nv].fill(0.0);
    for (i, b) in model.bodies.iter().enumerate() {
        ws.ia[i] = b.inertia;
    }
    for i in (0..model.bodies.len()).rev() {
        if let Some(p) = model.bodies[i].parent {
            let ic = ws.ia[i].to_parent(&ws.xup[i]);
            ws.ia[p] += ic;
        }
    }
    for i in 0..model.bodies.len() {
        let bi = &model.bodies[i];
        for k in 0..bi.nv() {
            let mut f: SVec = ws.ia[i].mul_motion(ws.jm[i].s[k]);
            let row = bi.v_at + k;
            for l in 0..bi.nv() {
                m_out[row * nv + bi.v_at + l] = ws.jm[i].s[l].dot(f);
            }
            let mut j = i;
            while let Some(p) = model.bodies[j].parent {
                f = ws.xup[j].inv_apply_force(f);
                j = p;
                let bj = &model.bodies[j];
                for l in 0..bj.nv() {
                    let val = ws.jm[j].s[l].dot(f);
                    m_out[row * nv + bj.v_at + l] = val;
                    m_out[(bj.v_at + l) * nv + row] = val;
                }
            }
        }
    }
}
