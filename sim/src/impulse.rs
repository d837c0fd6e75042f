//! Impulses from the rt-loop, given back to the sim bodies they were applied to.
//!
//! The rt-loop renders the hands' force at 1 kHz against proxies the sim published, and returns
//! with every `HandSample` the impulse it applied to each proxy. Applying the same impulse,
//! opposite to the hands' force, to the body that proxy stands for keeps momentum consistent
//! between the user's hands and the world (DESIGN.md section 1). (The sample also carries the
//! virtual contact's own, unclamped impulse, for scenes with a simulated hand between the user
//! and the world: the boxing scene.)
//!
//! Proxy ids name a body as `ProxyId { body: articulation index, part: link index within it }`.
//!
//! Must never: allocate, or apply an impulse to a body a proxy id does not name.

use glam::DVec3;
use spidar_msg::{ContactModel, HandSample, ProxyId, ProxyShape};

use crate::model::Model;
use crate::state::Workspace;

/// The proxy id of a body.
pub fn proxy_id(model: &Model, body: usize) -> ProxyId {
    let art = model.bodies[body].articulation;
    ProxyId { body: art as u16, part: (body - model.articulations[art].bodies.start) as u16 }
}

/// The body a proxy id names, if it exists in this model.
pub fn body_of(model: &Model, id: ProxyId) -> Option<usize> {
    let art = model.articulations.get(id.body as usize)?;
    let b = art.bodies.start + id.part as usize;
    (b < art.bodies.end).then_some(b)
}

/// Applies the impulses of `sample` (computed against `sent`, the contact model with
/// `sample.model_seq`) to the bodies for the next step. The point of application is the
/// proxy surface point nearest to the closer valid hand. Returns the total impulse applied.
pub fn apply_hand_impulses(
    model: &Model,
    ws: &mut Workspace,
    sent: &ContactModel,
    sample: &HandSample,
) -> DVec3 {
    if sample.model_seq != sent.seq || sent.seq == 0 {
        return DVec3::ZERO;
    }
    let mut total = DVec3::ZERO;
    for (p, imp) in sent.proxies().iter().zip(sample.proxy_impulse_n_s.iter()) {
        if *imp == DVec3::ZERO {
            continue;
        }
        let Some(body) = body_of(model, p.id) else { continue };
        let point = match touching_hand(&p.shape, sample) {
            Some(h) => nearest_on_surface(&p.shape, sample.hands[h].pos_world_m),
            None => centre(&p.shape),
        };
        ws.add_impulse_at(body, point, *imp, model.dt_s);
        total += *imp;
    }
    total
}

/// The valid hand of `sample` nearest the surface of `shape`: the one whose contact with that
/// proxy the impulse came from (on a tie, the first).
pub fn touching_hand(shape: &ProxyShape, sample: &HandSample) -> Option<usize> {
    let d = |h: usize| dist(shape, sample.hands[h].pos_world_m);
    (0..sample.hands.len()).filter(|&h| sample.hands[h].valid).min_by(|&a, &b| d(a).total_cmp(&d(b)))
}

/// The centre of a proxy shape.
pub fn centre(s: &ProxyShape) -> DVec3 {
    match *s {
        ProxyShape::Plane { point_m, .. } => point_m,
        ProxyShape::Sphere { centre_m, .. } => centre_m,
        ProxyShape::Capsule { a_m, b_m, .. } => (a_m + b_m) * 0.5,
    }
}

/// Distance from `p` to the shape's surface.
pub fn dist(s: &ProxyShape, p: DVec3) -> f64 {
    (nearest_on_surface(s, p) - p).length()
}

/// Nearest point of the shape's surface to `p`.
pub fn nearest_on_surface(s: &ProxyShape, p: DVec3) -> DVec3 {
    let on_sphere = |c: DVec3, r: f64| {
        let d = p - c;
        let l = d.length();
        if l > 1e-12 {
            c + d * (r / l)
        } else {
            c + DVec3::Y * r
        }
    };
    match *s {
        ProxyShape::Plane { point_m, normal } => p - normal * (p - point_m).dot(normal),
        ProxyShape::Sphere { centre_m, radius_m } => on_sphere(centre_m, radius_m),
        ProxyShape::Capsule { a_m, b_m, radius_m } => {
            let ab = b_m - a_m;
            let t = if ab.length_squared() > 0.0 {
                ((p - a_m).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            on_sphere(a_m + ab * t, radius_m)
        }
    }
}
