//! The strings' geometry both sides of the link compute with: what forces four strings can render
//! on a grip (the capacity margin of their force zonotope, and whether one force can be
//! rendered), the distance between two strings (segments), the user's forearm as a capsule, what
//! counts as a string near another or the forearm ([`StringClearance`], carried in
//! [`crate::RigInfo`]), and a grid of cells over a box.
//!
//! Why here: the rig map (`spidar-calib`, on the rig's side) and the live view (`spidar-world`)
//! both need these from the rig's geometry, and this crate is the one both sides import (the
//! world must not depend on the rt-loop or the calibration; docs/architecture.md). Only `glam`.
//!
//! Method. With tensions in `[min, max]` the forces four strings can make on a grip form the
//! zonotope `Z = { sum t_i u_i }` (`u_i` the unit directions toward the anchors): centre
//! `c = (min + max) / 2 sum u_i`, generators `h u_i` with `h = (max - min) / 2`. Its facets are
//! normal to `u_i x u_j` (six pairs), and its support along a unit `n` is
//! `n . c + h sum_k |n . u_k|`. So, exactly and in closed form:
//! - a force `F` can be rendered exactly iff `|n . (F - c)| <= h sum_k |n . u_k|` for the six
//!   normals: the same question the loop's allocator (`spidar_rt::tension`) answers with `Exact`;
//! - the capacity margin (the radius of the largest ball of forces around zero inside `Z`) is
//!   the smallest `h sum_k |n . u_k| - |n . c|` over the six normals; negative where not even zero
//!   net force is possible (the allocator's fallback: the grip outside its anchor tetrahedron).
//!
//! Must never: disagree with the allocator about what can be rendered (tested at random points
//! in `spidar-calib`), or be called in the 1 kHz tick (nothing here is needed there).

use glam::DVec3;

/// Tensions' image: centre and half-width of the zonotope of forces at one grip position.
#[derive(Clone, Copy, Debug)]
struct Zonotope {
    u: [DVec3; 4],
    centre: DVec3,
    half: f64,
}

impl Zonotope {
    fn at(anchors: &[DVec3; 4], p: DVec3, min_n: f64, max_n: f64) -> Zonotope {
        let u = anchors.map(|a| (a - p).normalize_or_zero());
        Zonotope {
            u,
            centre: (u[0] + u[1] + u[2] + u[3]) * (0.5 * (min_n + max_n)),
            half: 0.5 * (max_n - min_n),
        }
    }

    /// The facet normals (unit), one per pair of non-parallel strings.
    fn normals(&self) -> impl Iterator<Item = DVec3> + '_ {
        const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
        PAIRS.iter().filter_map(|&(i, j)| {
            let n = self.u[i].cross(self.u[j]);
            (n.length_squared() > 1e-20).then(|| n.normalize())
        })
    }

    /// Half-width of the zonotope along `n` (about its centre).
    fn reach(&self, n: DVec3) -> f64 {
        self.half * self.u.iter().map(|u| n.dot(*u).abs()).sum::<f64>()
    }
}

/// The capacity at one grip position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capacity {
    /// The largest force that can be rendered in every direction, N; negative where not even
    /// zero net force can be (its size then says how far outside).
    pub margin_n: f64,
    /// The direction (unit) in which the strings give least: the margin is reached along it.
    pub weakest: DVec3,
}

/// The capacity margin of a grip at `p` pulled toward `anchors` with tensions in `[min_n, max_n]`.
pub fn capacity(anchors: &[DVec3; 4], p: DVec3, min_n: f64, max_n: f64) -> Capacity {
    let z = Zonotope::at(anchors, p, min_n, max_n);
    let mut best = Capacity { margin_n: f64::NEG_INFINITY, weakest: DVec3::ZERO };
    let mut first = true;
    for n in z.normals() {
        let nc = n.dot(z.centre);
        let m = z.reach(n) - nc.abs();
        if first || m < best.margin_n {
            // The face nearest to zero lies on the side the centre is not.
            let weakest = if nc > 0.0 { -n } else { n };
            best = Capacity { margin_n: m, weakest };
            first = false;
        }
    }
    best
}

/// True iff the strings can render `force_n` exactly on a grip at `p` (the allocator's `Exact`).
pub fn renders(anchors: &[DVec3; 4], p: DVec3, min_n: f64, max_n: f64, force_n: DVec3) -> bool {
    let z = Zonotope::at(anchors, p, min_n, max_n);
    let mut any = false;
    for n in z.normals() {
        any = true;
        if n.dot(force_n - z.centre).abs() > z.reach(n) {
            return false;
        }
    }
    any
}

/// Closest distance between segments `p0 p1` and `q0 q1`, and the closest point on the first.
pub fn segment_distance(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> (f64, DVec3) {
    let (d1, d2, r) = (p1 - p0, q1 - q0, p0 - q0);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    let tiny = 1e-18;
    let (s, t) = if a <= tiny && e <= tiny {
        (0.0, 0.0)
    } else if a <= tiny {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(r);
        if e <= tiny {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let mut s = if denom > tiny * a * e { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    let (cp, cq) = (p0 + d1 * s, q0 + d2 * t);
    ((cp - cq).length(), cp)
}

/// The user's forearm as a capsule hanging off the grip: its axis runs from `wrist_m` to
/// `elbow_m` along `toward_elbow` (the left hand's; the right hand's is mirrored in x), radius
/// `radius_m`. Defaults: approximate adult figures (forearm about 0.27 m from wrist to elbow,
/// about 0.29 m round at its thickest), a guard posture (elbow below and behind the fist, toward
/// the user, who stands on +z looking toward -z, slightly outward); set them for the user.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Forearm {
    pub toward_elbow: DVec3,
    /// Distance from the grip's centre to the wrist (the capsule's start), m.
    pub wrist_m: f64,
    /// Distance from the grip's centre to the elbow (the capsule's end), m.
    pub elbow_m: f64,
    pub radius_m: f64,
}

impl Default for Forearm {
    fn default() -> Forearm {
        Forearm { toward_elbow: DVec3::new(-0.25, -0.55, 0.8), wrist_m: 0.08, elbow_m: 0.35, radius_m: 0.045 }
    }
}

impl Forearm {
    /// The capsule's axis for hand `hand` (0 left, 1 right) with the grip at `p`.
    pub fn axis(&self, hand: usize, p: DVec3) -> (DVec3, DVec3) {
        let mut d = self.toward_elbow.normalize_or_zero();
        if hand == 1 {
            d.x = -d.x;
        }
        (p + d * self.wrist_m, p + d * self.elbow_m)
    }
}

/// When a string counts as near: closer than `distance_m` to another hand's string, or to the
/// forearm capsule's surface. The live view marks such strings; `spidar rig map` counts strings
/// closer than it to each other as touching. From the rig file's `near_strings` (optional; these
/// defaults when left out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StringClearance {
    pub distance_m: f64,
    pub forearm: Forearm,
}

/// Strings within 1 cm: two strings' own thickness (about 1 mm each) and a margin for the
/// geometry's error after a calibration.
pub const DEFAULT_NEAR_M: f64 = 0.01;

impl Default for StringClearance {
    fn default() -> StringClearance {
        StringClearance { distance_m: DEFAULT_NEAR_M, forearm: Forearm::default() }
    }
}

/// A regular grid of cell centres over a box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Centre of cell (0, 0, 0).
    pub origin_m: DVec3,
    pub step_m: f64,
    pub n: [usize; 3],
}

impl Grid {
    /// Cells of `step_m` covering the box `lo .. hi`.
    pub fn covering(lo: DVec3, hi: DVec3, step_m: f64) -> Grid {
        let count = |a: f64, b: f64| (((b - a) / step_m).ceil().max(1.0)) as usize;
        let n = [count(lo.x, hi.x), count(lo.y, hi.y), count(lo.z, hi.z)];
        Grid { origin_m: lo + DVec3::splat(0.5 * step_m), step_m, n }
    }

    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Cell centre `(i, j, k)`.
    pub fn point(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin_m + DVec3::new(i as f64, j as f64, k as f64) * self.step_m
    }

    /// Index of `(i, j, k)` in a field over this grid (x fastest).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.n[0] * (j + self.n[1] * k)
    }

    /// Every cell centre with its index.
    pub fn points(&self) -> impl Iterator<Item = (usize, DVec3)> + '_ {
        (0..self.n[2]).flat_map(move |k| {
            (0..self.n[1])
                .flat_map(move |j| (0..self.n[0]).map(move |i| (self.index(i, j, k), self.point(i, j, k))))
        })
    }

    pub fn cell_volume_m3(&self) -> f64 {
        self.step_m.powi(3)
    }
}
