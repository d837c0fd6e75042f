//! Penalty contacts: find the touching shape pairs, turn each penetration into a force
//! (spring-damper on depth along the normal, regularised Coulomb friction along the surface),
//! apply it to both bodies, and keep a record of it for the virtual human to classify.
//!
//! Stability: the penalty is explicit, so a contact's gains must satisfy `K h^2 / m < 4` at its
//! effective mass `m` along the normal, which for a point away from the centre of mass is far
//! below the body's mass (0.43 kg at the end of a 3 kg bar). A pair touching at `n` points shares
//! its gains among them, so a box landing flat is no stiffer than one landing on a corner; and
//! each point's share is bounded by `K <= m / (n h^2)`, `D <= m / (2 n h)` with `m` the effective
//! mass of the two rigid bodies at that point (a lower bound of the articulated one). Softened
//! points are counted in `Workspace::contacts_softened`.
//! Friction is viscous below the slip speed `s`; that viscosity `mu f_n / s` is kept below
//! `m / h` (`m` the contact's effective mass) by raising `s` where needed, so sticking never
//! oscillates.
//!
//! Must never: allocate (the contact list has a fixed capacity and counts the records it drops;
//! their forces are still applied), pull
//! two bodies together, or apply a force to static scenery.

use glam::DVec3;

use crate::collide::{collide, Hit, Shape};
use crate::model::{Model, ShapePair};
use crate::state::{Contact, Workspace, MAX_CONTACTS};

/// Finds contacts for the current shape poses (`kinematics` must have run) and adds their
/// forces to `ws.f_ext`. Returns how many contacts were found.
pub fn contacts(model: &Model, ws: &mut Workspace) -> usize {
    ws.contacts.clear();
    let h = model.dt_s;
    for pair in &model.pairs {
        let (ia, ib) = (pair.a as usize, pair.b as usize);
        let (sa, sb) = (&model.shapes[ia], &model.shapes[ib]);
        let (pa, pb) = (&ws.shape_pose[ia], &ws.shape_pose[ib]);
        // Broad phase: bounding spheres, or the other shape's distance from a plane.
        let far = match (&sa.shape, &sb.shape) {
            (Shape::Plane, _) => (pb.pos_m - pa.pos_m).dot(pa.rot.y_axis) > sb.bound_m,
            (_, Shape::Plane) => (pa.pos_m - pb.pos_m).dot(pb.rot.y_axis) > sa.bound_m,
            _ => (pa.pos_m - pb.pos_m).length_squared() > (sa.bound_m + sb.bound_m).powi(2),
        };
        if far {
            continue;
        }
        let (pa, pb) = (*pa, *pb);
        let n = collide(&sa.shape, &pa, &sb.shape, &pb, &mut ws.hits);
        if n == 0 {
            continue;
        }
        let share = 1.0 / n as f64;
        for h_i in 0..n {
            let hit = ws.hits[h_i];
            let inv_m = sa.body.map_or(0.0, |b| inv_mass_along(model, ws, b, hit.point_m, hit.normal))
                + sb.body.map_or(0.0, |b| inv_mass_along(model, ws, b, hit.point_m, hit.normal));
            let va = sa.body.map_or(DVec3::ZERO, |b| point_velocity_world(ws, b, hit.point_m));
            let vb = sb.body.map_or(DVec3::ZERO, |b| point_velocity_world(ws, b, hit.point_m));
            let (force, softened) = penalty_force(&Penalty::of(pair, model), &hit, inv_m, share, h, va - vb);
            ws.contacts_softened += softened as u64;
            if let Some(b) = sa.body {
                ws.add_force_at(b, hit.point_m, force);
            }
            if let Some(b) = sb.body {
                ws.add_force_at(b, hit.point_m, -force);
            }
            if ws.contacts.len() < MAX_CONTACTS {
                ws.contacts.push(Contact {
                    shape_a: pair.a,
                    shape_b: pair.b,
                    body_a: sa.body.map(|b| b as u16),
                    body_b: sb.body.map(|b| b as u16),
                    point_m: hit.point_m,
                    normal: hit.normal,
                    depth_m: hit.depth_m,
                    force_n: force,
                });
            } else {
                ws.contacts_dropped += 1;
            }
        }
    }
    ws.contacts.len()
}

/// The gains of one touching pair: what the penalty law needs besides the geometry.
#[derive(Clone, Copy, Debug)]
pub struct Penalty {
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    pub friction: f64,
    /// The model's minimum slip speed.
    pub slip_m_per_s: f64,
}

impl Penalty {
    #[inline]
    pub fn of(pair: &ShapePair, model: &Model) -> Penalty {
        Penalty {
            k_n_per_m: pair.k_n_per_m,
            d_n_s_per_m: pair.d_n_s_per_m,
            friction: pair.friction,
            slip_m_per_s: model.contact.slip_m_per_s,
        }
    }
}

/// The penalty law for one contact point, shared by the engine and the crowd stepper
/// (`character::crowd`) so both give the same force: `inv_m` is the summed inverse effective mass
/// of the two bodies along the normal, `share` is `1 / points` of this pair, `h` the step and
/// `vrel` the velocity of a's point relative to b's. Returns the force on a and whether the gains
/// were softened to the stability bound.
#[inline]
pub fn penalty_force(p: &Penalty, hit: &Hit, inv_m: f64, share: f64, h: f64, vrel: DVec3) -> (DVec3, bool) {
    let (mut ks, mut ds) = (p.k_n_per_m * share, p.d_n_s_per_m * share);
    let mut softened = false;
    // The bounds are `k_max = m_eff share / h^2` and `d_max = 0.5 m_eff share / h`, three divisions
    // per contact point (most of the crowd's contact cost). Compared by products with a margin of
    // 1e-9 (far above the few ulps the two forms differ by), a gain clearly inside its bound needs
    // neither; only a point near or past a bound takes the divisions, so no result changes. NaN
    // compares false and takes the divisions too.
    let hh = h * h;
    let margin = share * (1.0 - 1e-9);
    let inside = inv_m > 0.0 && ks * inv_m * hh <= margin && ds * inv_m * (2.0 * h) <= margin;
    if !inside {
        let m_eff = 1.0 / inv_m;
        let (k_max, d_max) = (m_eff * share / hh, 0.5 * m_eff * share / h);
        if ks > k_max || ds > d_max {
            ks = ks.min(k_max);
            ds = ds.min(d_max);
            softened = true;
        }
    }
    let vn = vrel.dot(hit.normal);
    let fn_ = (ks * hit.depth_m - ds * vn).max(0.0);
    let vt = vrel - hit.normal * vn;
    let mu_fn = p.friction * fn_;
    let vt_len = vt.length();
    let ft = if vt_len > 0.0 {
        // Without friction (the characters' floor: their legs make the friction) the ratio is
        // that zero itself (0 / x for x > 0, sign included): skipping two divisions changes no bit.
        let ratio = if mu_fn == 0.0 {
            mu_fn
        } else {
            let slip = p.slip_m_per_s.max(mu_fn * h / (1.0 / inv_m));
            mu_fn / vt_len.max(slip)
        };
        -vt * ratio
    } else {
        DVec3::ZERO
    };
    (hit.normal * fn_ + ft, softened)
}

/// Inverse of the effective mass of a free rigid body pushed at world point `p` along `n`.
#[inline]
pub fn inv_mass_along(model: &Model, ws: &Workspace, body: usize, p: DVec3, n: DVec3) -> f64 {
    let b = &model.bodies[body];
    let x = &ws.x0[body];
    let r = x.e * (p - x.r) - b.com_m;
    let w = r.cross(x.e * n);
    1.0 / b.mass_kg + w.dot(b.inv_i_com * w)
}

/// World velocity of the body point currently at world position `p`.
#[inline]
fn point_velocity_world(ws: &Workspace, body: usize, p: DVec3) -> DVec3 {
    let x = &ws.x0[body];
    let v = ws.vel[body];
    let p_body = x.e * (p - x.r);
    x.e.transpose() * (v.lin + v.ang.cross(p_body))
}
