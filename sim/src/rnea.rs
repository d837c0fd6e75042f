//! Recursive Newton-Euler inverse dynamics: the joint forces that produce given accelerations.
//!
//! `tau = M(q) qdd + C(q, v) - J^T f_ext`, gravity included. Used to verify ABA and by
//! controllers that want gravity or bias compensation. Pass 1 is `state::kinematics`.
//!
//! Must never: allocate (the output and scratch are the caller's and the workspace's).

use crate::model::Model;
use crate::spatial::SVec;
use crate::state::Workspace;

/// Writes into `tau` (`nv` long) the joint forces that give accelerations `qdd` at the state
/// `kinematics` was last run for. Uses `ws.f_ext` and overwrites `ws.acc` and `ws.pa`.
pub fn rnea(model: &Model, ws: &mut Workspace, qdd: &[f64], tau: &mut [f64]) {
    let a_world = SVec::new(glam::DVec3::ZERO, -model.gravity_m_per_s2);
    for (i, b) in model.bodies.iter().enumerate() {
        let a_parent = match b.parent {
            Some(p) => ws.acc[p],
            None => a_world,
        };
        let mut a = ws.xup[i].apply_motion(a_parent) + ws.cbias[i];
        for k in 0..b.nv() {
            a += ws.jm[i].s[k] * qdd[b.v_at + k];
        }
        ws.acc[i] = a;
        let v = ws.vel[i];
        ws.pa[i] = b.inertia.mul_motion(a) + v.cross_force(b.inertia.mul_motion(v))
            - ws.x0[i].apply_force(ws.f_ext[i]);
    }
    for i in (0..model.bodies.len()).rev() {
        let b = &model.bodies[i];
        let f = ws.pa[i];
        for k in 0..b.nv() {
            tau[b.v_at + k] = ws.jm[i].s[k].dot(f);
        }
        if let Some(p) = b.parent {
            let fp = ws.xup[i].inv_apply_force(f);
            ws.pa[p] += fp;
        }
    }
}
