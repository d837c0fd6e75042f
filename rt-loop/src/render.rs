//! Penalty rendering at 1 kHz against the local contact proxies of the latest `ContactModel`.
//!
//! The hand is a sphere (the fist). Each proxy is first moved by its velocity times the model's
//! age, so a proxy that is moving when the sim last spoke keeps moving between sim steps. The
//! force is a spring on the penetration depth plus a damper on the approach speed, never pulling
//! (a penalty contact only pushes). The reaction impulse of every contact is accumulated per proxy
//! so the scene can apply it to the body it belongs to. Allocation-free; never panics; works in
//! the world frame, like the messages.

use glam::DVec3;
use spidar_msg::{ContactModel, ProxyShape, MAX_PROXIES};

/// Outcome of rendering one hand against one model.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rendered {
    pub force_n: DVec3,
    pub contacts: u8,
    /// True when some proxy was stiffer than the hand's stiffness limit and was softened.
    pub stiffness_limited: bool,
}

/// Signed distance from `p` to the proxy surface (negative inside) and the outward unit normal.
pub fn distance(shape: &ProxyShape, p: DVec3) -> (f64, DVec3) {
    match *shape {
        ProxyShape::Plane { point_m, normal } => {
            let n = normal.normalize_or(DVec3::Y);
            ((p - point_m).dot(n), n)
        }
        ProxyShape::Sphere { centre_m, radius_m } => {
            let d = p - centre_m;
            let len = d.length();
            (len - radius_m, if len > 1e-12 { d / len } else { DVec3::Y })
        }
        ProxyShape::Capsule { a_m, b_m, radius_m } => {
            let ab = b_m - a_m;
            let len2 = ab.length_squared();
            let t = if len2 > 1e-24 { ((p - a_m).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let d = p - (a_m + ab * t);
            let len = d.length();
            (len - radius_m, if len > 1e-12 { d / len } else { DVec3::Y })
        }
    }
}

/// Renders the force on one hand (sphere at `pos_m`, radius `radius_m`, velocity `vel_m_per_s`)
/// against every proxy of `model` that this hand may touch, extrapolated by `age_s`. Adds the
/// reaction impulse (`-force * dt_s`) of each contact into `impulses`, as rendered: the caller
/// scales it by the loop's gain for the virtual contact, and by the part of the force the hand
/// really received for the applied impulse.
#[allow(clippy::too_many_arguments)]
pub fn render_hand(
    hand: usize,
    pos_m: DVec3,
    vel_m_per_s: DVec3,
    radius_m: f64,
    stiffness_limit_n_per_m: f64,
    model: &ContactModel,
    age_s: f64,
    dt_s: f64,
    impulses: &mut [DVec3; MAX_PROXIES],
) -> Rendered {
    let mut out = Rendered::default();
    for (i, proxy) in model.proxies().iter().enumerate() {
        if !proxy.touches(hand) {
            continue;
        }
        let shape = proxy.extrapolated(age_s);
        let (dist, n) = distance(&shape, pos_m);
        let depth = radius_m - dist;
        // Written so that a NaN depth also counts as "no contact".
        if depth.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        let mut k = proxy.k_n_per_m;
        if k > stiffness_limit_n_per_m {
            k = stiffness_limit_n_per_m;
            out.stiffness_limited = true;
        }
        let approach = -(vel_m_per_s - proxy.vel_m_per_s).dot(n);
        let fn_n = (k * depth + proxy.d_n_s_per_m * approach).max(0.0);
        let f = n * fn_n;
        if !f.is_finite() {
            continue; // a NaN proxy contributes nothing; the safety phase guards the total too
        }
        out.force_n += f;
        out.contacts = out.contacts.saturating_add(1);
        if let Some(slot) = impulses.get_mut(i) {
            *slot -= f * dt_s;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use spidar_msg::{Proxy, ProxyId};

    fn model(shape: ProxyShape, k: f64, d: f64, vel: DVec3) -> ContactModel {
        let mut m = ContactModel::default();
        m.push(Proxy {
            id: ProxyId { body: 1, part: 2 },
            shape,
            k_n_per_m: k,
            d_n_s_per_m: d,
            vel_m_per_s: vel,
            hand_mask: Proxy::BOTH_HANDS,
        });
        m
    }

    #[test]
    fn plane_force_is_k_times_depth_along_the_normal() {
        let m = model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Z }, 2000.0, 0.0, DVec3::ZERO);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::new(0.0, 0.0, 0.03), DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n - DVec3::Z * 20.0).length() < 1e-9, "{}", r.force_n);
        assert!((imp[0] + DVec3::Z * 0.02).length() < 1e-12);
    }

    #[test]
    fn no_force_when_apart_and_no_pull_when_leaving_fast() {
        let m = model(ProxyShape::Sphere { centre_m: DVec3::ZERO, radius_m: 0.1 }, 1000.0, 50.0, DVec3::ZERO);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::X * 0.2, DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert_eq!(r.force_n, DVec3::ZERO);
        // Barely touching while moving away quickly: damping would pull; it must not.
        let r = render_hand(0, DVec3::X * 0.139, DVec3::X * 2.0, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert_eq!(r.force_n, DVec3::ZERO);
    }

    #[test]
    fn moving_proxy_is_extrapolated_by_its_age() {
        // A sphere moving +x at 1 m/s, stamped 20 ms ago at x = 0: now at x = 0.02.
        let m = model(ProxyShape::Sphere { centre_m: DVec3::ZERO, radius_m: 0.1 }, 1000.0, 0.0, DVec3::X);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let p = DVec3::X * 0.15; // 0.13 from the moved centre -> depth 0.01
        let r = render_hand(1, p, DVec3::X, 0.04, 1e4, &m, 0.02, 0.001, &mut imp);
        assert!((r.force_n.x - 10.0).abs() < 1e-9, "{}", r.force_n);
    }

    #[test]
    fn capsule_pushes_away_from_its_axis() {
        let m = model(
            ProxyShape::Capsule { a_m: DVec3::ZERO, b_m: DVec3::Y, radius_m: 0.05 },
            1000.0,
            0.0,
            DVec3::ZERO,
        );
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::new(0.0, 0.5, 0.08), DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n - DVec3::Z * 10.0).length() < 1e-9);
        // Beyond the end cap the normal points from the end point.
        let r = render_hand(0, DVec3::new(0.0, 1.08, 0.0), DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n - DVec3::Y * 10.0).length() < 1e-9);
    }

    #[test]
    fn stiffness_is_limited_and_reported() {
        let m = model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Y }, 1e6, 0.0, DVec3::ZERO);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::Y * 0.039, DVec3::ZERO, 0.04, 5000.0, &m, 0.0, 0.001, &mut imp);
        assert!(r.stiffness_limited);
        assert!((r.force_n.y - 5.0).abs() < 1e-9);
    }

    #[test]
    fn damping_acts_on_the_approach_speed_relative_to_the_proxy() {
        // A plane moving +z at 1 m/s, the fist 1 cm inside it.
        let m = model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Z }, 1000.0, 20.0, DVec3::Z);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let at = DVec3::Z * 0.03;
        // Moving with the plane: no relative motion, spring only (10 N).
        let r = render_hand(0, at, DVec3::Z, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n.z - 10.0).abs() < 1e-9, "{}", r.force_n);
        // At rest: the plane approaches at 1 m/s, the damper adds 20 N.
        let r = render_hand(0, at, DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n.z - 30.0).abs() < 1e-9, "{}", r.force_n);
        // Leaving at 0.25 m/s relative: the damper takes 5 N off.
        let r = render_hand(0, at, DVec3::Z * 1.25, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert!((r.force_n.z - 5.0).abs() < 1e-9, "{}", r.force_n);
    }

    #[test]
    fn a_proxy_at_the_stiffness_limit_is_not_reported_as_limited() {
        let m = model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Y }, 5000.0, 0.0, DVec3::ZERO);
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::Y * 0.039, DVec3::ZERO, 0.04, 5000.0, &m, 0.0, 0.001, &mut imp);
        assert!(!r.stiffness_limited);
        assert_eq!(r.contacts, 1);
        assert!((r.force_n.y - 5.0).abs() < 1e-9);
    }

    #[test]
    fn impulses_accumulate_per_proxy_and_a_nan_proxy_adds_nothing() {
        let mut m =
            model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Y }, 1000.0, 0.0, DVec3::ZERO);
        m.push(Proxy {
            id: ProxyId { body: 1, part: 3 },
            shape: ProxyShape::Sphere { centre_m: DVec3::new(0.0, f64::NAN, 0.0), radius_m: 0.1 },
            k_n_per_m: 1000.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: Proxy::BOTH_HANDS,
        });
        m.push(Proxy {
            id: ProxyId { body: 1, part: 4 },
            shape: ProxyShape::Sphere { centre_m: DVec3::new(0.0, 0.05, 0.0), radius_m: 0.02 },
            k_n_per_m: 1000.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: Proxy::BOTH_HANDS,
        });
        let mut imp = [DVec3::ONE; MAX_PROXIES];
        // Fist at y = 0.02: 2 cm into the plane (20 N up); 1 cm from the sphere's centre-line, 5 cm
        // into it along -y (3 cm + 2 cm - 0.03 = depth 0.03: 30 N down).
        let r = render_hand(0, DVec3::Y * 0.02, DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert_eq!(r.contacts, 2);
        assert!((r.force_n.y - (20.0 - 30.0)).abs() < 1e-9, "{}", r.force_n);
        assert!((imp[0] - (DVec3::ONE - DVec3::Y * 0.02)).length() < 1e-12, "{}", imp[0]);
        assert_eq!(imp[1], DVec3::ONE, "the NaN proxy got nothing");
        assert!((imp[2] - (DVec3::ONE + DVec3::Y * 0.03)).length() < 1e-12, "{}", imp[2]);
        assert_eq!(imp[3], DVec3::ONE);
    }

    #[test]
    fn distance_to_each_shape_is_signed_and_normal_unit() {
        let (d, n) = distance(&ProxyShape::Plane { point_m: DVec3::Y, normal: DVec3::Y * 3.0 }, DVec3::ZERO);
        assert!((d + 1.0).abs() < 1e-12 && (n - DVec3::Y).length() < 1e-12);
        let (d, n) = distance(&ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::ZERO }, DVec3::Y);
        assert!((d - 1.0).abs() < 1e-12 && n == DVec3::Y, "a zero normal falls back to +y");
        let (d, n) =
            distance(&ProxyShape::Sphere { centre_m: DVec3::X, radius_m: 0.5 }, DVec3::new(1.0, 0.0, 2.0));
        assert!((d - 1.5).abs() < 1e-12 && (n - DVec3::Z).length() < 1e-12);
        let (_, n) = distance(&ProxyShape::Sphere { centre_m: DVec3::X, radius_m: 0.5 }, DVec3::X);
        assert_eq!(n, DVec3::Y, "at the centre the normal falls back to +y");
        let cap = ProxyShape::Capsule { a_m: DVec3::ZERO, b_m: DVec3::X * 2.0, radius_m: 0.1 };
        let (d, n) = distance(&cap, DVec3::new(1.5, -0.6, 0.0));
        assert!((d - 0.5).abs() < 1e-12 && (n + DVec3::Y).length() < 1e-12);
        let (d, n) = distance(&cap, DVec3::new(-1.0, 0.0, 0.0));
        assert!((d - 0.9).abs() < 1e-12 && (n + DVec3::X).length() < 1e-12, "before the first end cap");
        // Away from the origin: the axis parameter is measured from the first end.
        let off = ProxyShape::Capsule {
            a_m: DVec3::new(1.0, 2.0, 3.0),
            b_m: DVec3::new(3.0, 2.0, 3.0),
            radius_m: 0.1,
        };
        let (d, n) = distance(&off, DVec3::new(1.5, 2.0, 3.6));
        assert!((d - 0.5).abs() < 1e-12 && (n - DVec3::Z).length() < 1e-12, "{d} {n}");
        let (d, n) = distance(&off, DVec3::new(3.4, 2.0, 3.0));
        assert!((d - 0.3).abs() < 1e-12 && (n - DVec3::X).length() < 1e-12, "beyond the second end: {d} {n}");
        let dot = ProxyShape::Capsule { a_m: DVec3::ONE, b_m: DVec3::ONE, radius_m: 0.1 };
        let (d, _) = distance(&dot, DVec3::new(1.0, 2.0, 1.0));
        assert!((d - 0.9).abs() < 1e-12, "a zero-length capsule is a sphere");
    }

    #[test]
    fn hand_mask_is_respected() {
        let mut m =
            model(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Y }, 1e3, 0.0, DVec3::ZERO);
        m.proxies[0].hand_mask = 0b10;
        let mut imp = [DVec3::ZERO; MAX_PROXIES];
        let r = render_hand(0, DVec3::ZERO, DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert_eq!(r.contacts, 0);
        let r = render_hand(1, DVec3::ZERO, DVec3::ZERO, 0.04, 1e4, &m, 0.0, 0.001, &mut imp);
        assert_eq!(r.contacts, 1);
    }
}
