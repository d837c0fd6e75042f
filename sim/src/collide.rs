//! Narrow-phase collision: contact points between two posed primitive shapes.
//!
//! The articulated-body solver needs, for every pair of shapes the broad phase lets through, a small
//! set of contact points with a normal and a penetration depth. This module is that geometry and
//! nothing else: no bodies, no masses, no state. It runs thousands of times per 3 ms physics step,
//! so it must never allocate (output goes into a fixed `[Hit; MAX_HITS]`), never use trigonometry,
//! and never panic or produce NaN: degenerate input (zero radius, zero-length capsule, coincident
//! centres, identical boxes, even NaN or negative sizes, which are read as zero) still yields finite
//! hits with unit normals, or no hits. Hits whose own numbers are not finite (e.g. from a NaN pose)
//! are dropped rather than reported.
//!
//! Conventions: the normal of every hit points from `b` toward `a` (moving `a` along `+normal`
//! separates the pair), `depth_m > 0` for every reported hit, and `point_m` is the midpoint between
//! the two surfaces along the normal. Pairs are handled in one canonical order (sphere < capsule <
//! box < plane, and a deterministic order between two shapes of the same kind); the other order is
//! the same computation with negated normals, so `collide(b, a)` mirrors `collide(a, b)` exactly.
//!
//! Where a degenerate configuration leaves the normal undefined (coincident sphere centres, a point
//! on a capsule axis) a deterministic fallback is used: world `±y` for two points (the sign follows
//! the canonical order, so the two argument orders still mirror), a fixed perpendicular of the
//! capsule axis when an axis is involved.
//!
//! Exact: sphere/capsule pairs (closest points), sphere-box, all plane pairs, and the capsule-box
//! and box-box separating-axis depths. Approximate: (1) in capsule-box and box-box an edge-cross
//! axis is used only if its overlap is at least 5% below the best face axis (stable face manifolds),
//! so a depth can be up to 5% longer than the true minimum; (2) box-box contact points are the
//! vertices inside the other box and the edge/face crossing points, each with its depth measured to
//! the other box's supporting plane along the normal, the deepest `MAX_HITS` kept, so the deepest
//! point may be shallower than the axis overlap; an edge-edge axis gives one point (closest points of
//! the two edges) with the axis overlap as depth; (3) parallel capsules (within ~0.57°) report the
//! two ends of their overlap rather than the exact contact interval.

// `!(x <= y)` is used on purpose: it is true for NaN, which must take the "no contact" path.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use glam::{DMat3, DVec3};

/// A collision shape in its body's frame (shape-local frame given by `ShapePose` below).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    Sphere {
        radius_m: f64,
    },
    /// Segment from -half_length_m to +half_length_m along the shape's local y axis, swept by radius_m.
    Capsule {
        half_length_m: f64,
        radius_m: f64,
    },
    /// Centred box.
    Box {
        half_extents_m: DVec3,
    },
    /// Half-space below the plane through the local origin with normal local +y (solid at y < 0).
    Plane,
}

/// World pose of a shape: x_world = pos_m + rot * x_local. `rot` is a proper rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapePose {
    pub pos_m: DVec3,
    pub rot: DMat3,
}

impl ShapePose {
    pub const IDENTITY: ShapePose = ShapePose { pos_m: DVec3::ZERO, rot: DMat3::IDENTITY };

    pub fn new(pos_m: DVec3, rot: DMat3) -> Self {
        ShapePose { pos_m, rot }
    }

    /// Pure translation.
    pub fn at(pos_m: DVec3) -> Self {
        ShapePose { pos_m, rot: DMat3::IDENTITY }
    }

    #[inline]
    fn world_point(&self, local: DVec3) -> DVec3 {
        self.pos_m + self.rot * local
    }

    #[inline]
    fn local_point(&self, world: DVec3) -> DVec3 {
        tmul(&self.rot, world - self.pos_m)
    }
}

/// One contact point between shape `a` and shape `b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Midpoint between the two surfaces along the normal (world).
    pub point_m: DVec3,
    /// Unit normal pointing from b toward a: pushing a along +normal separates them.
    pub normal: DVec3,
    /// Penetration depth, > 0 when overlapping.
    pub depth_m: f64,
}

impl Hit {
    pub const ZERO: Hit = Hit { point_m: DVec3::ZERO, normal: DVec3::Y, depth_m: 0.0 };
}

pub const MAX_HITS: usize = 8;

/// Below this length (m) a vector has no usable direction.
const TINY_M: f64 = 1e-12;
/// `1 - cos²` of the angle between two capsule axes below which they are treated as parallel
/// (about 0.57°): the overlap is then reported as two hits at its ends.
const PARALLEL_SIN2: f64 = 1e-4;
/// Cross-product axes shorter than this (sine of the angle between the edges) are skipped in the
/// separating-axis tests: near-parallel edges are covered by the face axes.
const EDGE_AXIS_MIN_SIN: f64 = 1e-6;
/// An edge-edge axis replaces the best face axis only if its overlap is clearly smaller; face
/// contacts give better manifolds, so near-ties go to the face.
const EDGE_AXIS_REL: f64 = 0.95;
/// Slack (relative to the box size) for "on the boundary counts as inside" when clipping.
const CLIP_SLACK: f64 = 1e-10;

/// Bounded output cursor: drops non-positive depths, non-finite hits and overflow.
struct Sink<'a> {
    out: &'a mut [Hit; MAX_HITS],
    n: usize,
}

impl Sink<'_> {
    #[inline]
    fn push(&mut self, point_m: DVec3, normal: DVec3, depth_m: f64) {
        if self.n < MAX_HITS
            && depth_m > 0.0
            && depth_m.is_finite()
            && point_m.is_finite()
            && normal.is_finite()
        {
            self.out[self.n] = Hit { point_m, normal, depth_m };
            self.n += 1;
        }
    }
}

/// Fixed-capacity output, no allocation: returns the number of hits written into `out`.
pub fn collide(a: &Shape, pa: &ShapePose, b: &Shape, pb: &ShapePose, out: &mut [Hit; MAX_HITS]) -> usize {
    let swap = match rank(a).cmp(&rank(b)) {
        core::cmp::Ordering::Greater => true,
        core::cmp::Ordering::Less => false,
        core::cmp::Ordering::Equal => key_greater(a, pa, b, pb),
    };
    if swap {
        let n = collide_ordered(b, pb, a, pa, out);
        for h in out.iter_mut().take(n) {
            h.normal = -h.normal;
        }
        n
    } else {
        collide_ordered(a, pa, b, pb, out)
    }
}

/// Conservative bounding-sphere radius of a shape about its local origin (f64::INFINITY for Plane).
pub fn bounding_radius(s: &Shape) -> f64 {
    match *s {
        Shape::Sphere { radius_m } => size(radius_m),
        Shape::Capsule { half_length_m, radius_m } => size(half_length_m) + size(radius_m),
        Shape::Box { half_extents_m } => size3(half_extents_m).length(),
        Shape::Plane => f64::INFINITY,
    }
}

fn rank(s: &Shape) -> u8 {
    match s {
        Shape::Sphere { .. } => 0,
        Shape::Capsule { .. } => 1,
        Shape::Box { .. } => 2,
        Shape::Plane => 3,
    }
}

/// Total order on (pose, shape) used to pick one evaluation order for two shapes of the same kind.
fn key_greater(a: &Shape, pa: &ShapePose, b: &Shape, pb: &ShapePose) -> bool {
    let ka = sort_key(a, pa);
    let kb = sort_key(b, pb);
    for (x, y) in ka.iter().zip(kb.iter()) {
        match x.total_cmp(y) {
            core::cmp::Ordering::Greater => return true,
            core::cmp::Ordering::Less => return false,
            core::cmp::Ordering::Equal => {}
        }
    }
    false
}

fn sort_key(s: &Shape, p: &ShapePose) -> [f64; 15] {
    let (s0, s1, s2) = match *s {
        Shape::Sphere { radius_m } => (radius_m, 0.0, 0.0),
        Shape::Capsule { half_length_m, radius_m } => (half_length_m, radius_m, 0.0),
        Shape::Box { half_extents_m: h } => (h.x, h.y, h.z),
        Shape::Plane => (0.0, 0.0, 0.0),
    };
    let (x, y, z, r) = (p.rot.x_axis, p.rot.y_axis, p.rot.z_axis, p.pos_m);
    [r.x, r.y, r.z, x.x, x.y, x.z, y.x, y.y, y.z, z.x, z.y, z.z, s0, s1, s2]
}

/// `a` has rank <= `b`'s rank.
fn collide_ordered(a: &Shape, pa: &ShapePose, b: &Shape, pb: &ShapePose, out: &mut [Hit; MAX_HITS]) -> usize {
    let mut sink = Sink { out, n: 0 };
    match (*a, *b) {
        (Shape::Sphere { radius_m: ra }, Shape::Sphere { radius_m: rb }) => {
            let (ra, rb) = (size(ra), size(rb));
            let (ca, cb) = (pa.pos_m, pb.pos_m);
            if (ca - cb).length_squared() < (ra + rb) * (ra + rb) {
                let (p, n, d) = core_contact(ca, ra, cb, rb, DVec3::Y);
                sink.push(p, n, d);
            }
        }
        (Shape::Sphere { radius_m: ra }, Shape::Capsule { half_length_m: hb, radius_m: rb }) => {
            let (ra, hb, rb) = (size(ra), size(hb), size(rb));
            let axis = pb.rot.y_axis;
            let q = closest_on_segment(pb.pos_m, axis, hb, pa.pos_m);
            if (pa.pos_m - q).length_squared() < (ra + rb) * (ra + rb) {
                let (p, n, d) = core_contact(pa.pos_m, ra, q, rb, axis.any_orthonormal_vector());
                sink.push(p, n, d);
            }
        }
        (Shape::Sphere { radius_m: ra }, Shape::Box { half_extents_m: hb }) => {
            sphere_box(&mut sink, pa.pos_m, size(ra), pb, size3(hb));
        }
        (Shape::Sphere { radius_m: ra }, Shape::Plane) => {
            let n = plane_normal(pb);
            point_plane(&mut sink, pa.pos_m, size(ra), n, pb.pos_m);
        }
        (
            Shape::Capsule { half_length_m: ha, radius_m: ra },
            Shape::Capsule { half_length_m: hb, radius_m: rb },
        ) => {
            let seg_a = Seg { c: pa.pos_m, u: pa.rot.y_axis, h: size(ha) };
            let seg_b = Seg { c: pb.pos_m, u: pb.rot.y_axis, h: size(hb) };
            capsule_capsule(&mut sink, seg_a, size(ra), seg_b, size(rb));
        }
        (Shape::Capsule { half_length_m: ha, radius_m: ra }, Shape::Box { half_extents_m: hb }) => {
            capsule_box(&mut sink, pa, size(ha), size(ra), pb, size3(hb));
        }
        (Shape::Capsule { half_length_m: ha, radius_m: ra }, Shape::Plane) => {
            let (ha, ra) = (size(ha), size(ra));
            let n = plane_normal(pb);
            let axis = pa.rot.y_axis * ha;
            point_plane(&mut sink, pa.pos_m - axis, ra, n, pb.pos_m);
            if ha > 0.0 {
                point_plane(&mut sink, pa.pos_m + axis, ra, n, pb.pos_m);
            }
        }
        (Shape::Box { half_extents_m: ha }, Shape::Box { half_extents_m: hb }) => {
            box_box(&mut sink, pa, size3(ha), pb, size3(hb));
        }
        (Shape::Box { half_extents_m: ha }, Shape::Plane) => {
            box_plane(&mut sink, pa, size3(ha), pb);
        }
        // Plane-plane, and (unreachable) orders with rank(a) > rank(b).
        _ => {}
    }
    sink.n
}

// ---------------------------------------------------------------------------------------------
// Small helpers

/// Sizes are read as non-negative; NaN and negative become 0.
#[inline]
fn size(x: f64) -> f64 {
    if x > 0.0 {
        x
    } else {
        0.0
    }
}

#[inline]
fn size3(v: DVec3) -> DVec3 {
    DVec3::new(size(v.x), size(v.y), size(v.z))
}

/// `x` clamped to `[lo, hi]`; unlike `f64::clamp` never panics (NaN passes through).
#[inline]
fn clampf(x: f64, lo: f64, hi: f64) -> f64 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

#[inline]
fn clamp3(p: DVec3, h: DVec3) -> DVec3 {
    DVec3::new(clampf(p.x, -h.x, h.x), clampf(p.y, -h.y, h.y), clampf(p.z, -h.z, h.z))
}

/// `m^T * v`.
#[inline]
fn tmul(m: &DMat3, v: DVec3) -> DVec3 {
    DVec3::new(m.x_axis.dot(v), m.y_axis.dot(v), m.z_axis.dot(v))
}

#[inline]
fn sign_of(x: f64) -> f64 {
    if x < 0.0 {
        -1.0
    } else {
        1.0
    }
}

#[inline]
fn unit_axis(i: usize) -> DVec3 {
    match i {
        0 => DVec3::X,
        1 => DVec3::Y,
        _ => DVec3::Z,
    }
}

/// The unit normal of a plane shape at pose `p` (its local +y; +y if that has no length).
pub fn plane_normal(p: &ShapePose) -> DVec3 {
    let n = p.rot.y_axis;
    let len = n.length();
    if len > TINY_M {
        n / len
    } else {
        DVec3::Y
    }
}

/// Contact between two "cores" (points) inflated by radii: returns (point, normal b->a, depth).
#[inline]
fn core_contact(pa: DVec3, ra: f64, pb: DVec3, rb: f64, fallback: DVec3) -> (DVec3, DVec3, f64) {
    let d = pa - pb;
    let len = d.length();
    let n = if len > TINY_M { d / len } else { fallback };
    let depth = ra + rb - len;
    ((pa - n * ra + pb + n * rb) * 0.5, n, depth)
}

/// A point inflated by `r` against the half-space below the plane through `p0` with unit normal `n`.
#[inline]
fn point_plane(sink: &mut Sink, c: DVec3, r: f64, n: DVec3, p0: DVec3) {
    let height = n.dot(c - p0);
    sink.push(c - n * (0.5 * (r + height)), n, r - height);
}

/// Segment `c + s u`, `s` in `[-h, h]`, `u` unit.
#[derive(Clone, Copy, Debug)]
struct Seg {
    c: DVec3,
    u: DVec3,
    h: f64,
}

impl Seg {
    #[inline]
    fn at(&self, s: f64) -> DVec3 {
        self.c + self.u * s
    }
}

#[inline]
fn closest_on_segment(c: DVec3, u: DVec3, h: f64, p: DVec3) -> DVec3 {
    c + u * clampf((p - c).dot(u), -h, h)
}

/// Parameters (s, t) of a closest pair of points between two segments (Ericson, RTCD 5.1.9),
/// robust for parallel and zero-length segments.
fn closest_segments(a: Seg, b: Seg) -> (f64, f64) {
    let w = a.c - b.c;
    let bb = a.u.dot(b.u);
    let d = a.u.dot(w);
    let e = b.u.dot(w);
    let denom = 1.0 - bb * bb;
    let mut s = if denom > 1e-12 { clampf((bb * e - d) / denom, -a.h, a.h) } else { 0.0 };
    let mut t = e + bb * s;
    if t < -b.h {
        t = -b.h;
        s = clampf(bb * t - d, -a.h, a.h);
    } else if t > b.h {
        t = b.h;
        s = clampf(bb * t - d, -a.h, a.h);
    }
    (s, t)
}

// ---------------------------------------------------------------------------------------------
// Pairs

fn capsule_capsule(sink: &mut Sink, a: Seg, ra: f64, b: Seg, rb: f64) {
    let fallback = a.u.any_orthonormal_vector();
    let rsum = ra + rb;
    let cos = a.u.dot(b.u);
    if 1.0 - cos * cos < PARALLEL_SIN2 {
        // Parallel: the overlap of b's projection onto a's axis, reported at both ends.
        let sc = (b.c - a.c).dot(a.u);
        let ext = b.h * cos.abs();
        let lo = (sc - ext).max(-a.h);
        let hi = (sc + ext).min(a.h);
        if lo <= hi {
            let mut ends = [lo, hi];
            let n_ends = if hi - lo > 1e-9 * (1.0 + a.h) {
                2
            } else {
                ends[0] = 0.5 * (lo + hi);
                1
            };
            let mut deepest = f64::NEG_INFINITY;
            for &s in ends.iter().take(n_ends) {
                let p = a.at(s);
                let q = closest_on_segment(b.c, b.u, b.h, p);
                let (pt, n, d) = core_contact(p, ra, q, rb, fallback);
                deepest = deepest.max(d);
                sink.push(pt, n, d);
            }
            // Slightly crossing "parallel" segments can be closest between the ends.
            let (s, t) = closest_segments(a, b);
            let (pt, n, d) = core_contact(a.at(s), ra, b.at(t), rb, fallback);
            if d > deepest + 1e-9 * (1.0 + rsum) {
                sink.push(pt, n, d);
            }
            return;
        }
    }
    let (s, t) = closest_segments(a, b);
    let (pa, pb) = (a.at(s), b.at(t));
    if (pa - pb).length_squared() < rsum * rsum {
        let (pt, n, d) = core_contact(pa, ra, pb, rb, fallback);
        sink.push(pt, n, d);
    }
}

fn sphere_box(sink: &mut Sink, c: DVec3, r: f64, pb: &ShapePose, h: DVec3) {
    let p = pb.local_point(c);
    let q = clamp3(p, h);
    let diff = p - q;
    let d2 = diff.length_squared();
    if !(d2 < r * r || d2 <= TINY_M * TINY_M) {
        return;
    }
    let dist = d2.sqrt();
    let (n_local, depth, q_surf) = if dist > TINY_M {
        (diff / dist, r - dist, q)
    } else {
        // Centre inside (or on) the box: leave through the nearest face.
        let gap = h - p.abs();
        let i = if gap.x <= gap.y && gap.x <= gap.z {
            0
        } else if gap.y <= gap.z {
            1
        } else {
            2
        };
        let sign = sign_of(p[i]);
        let mut q_surf = p;
        q_surf[i] = sign * h[i];
        (unit_axis(i) * sign, r + gap[i], q_surf)
    };
    let n = pb.rot * n_local;
    let box_surf = pb.world_point(q_surf);
    sink.push((c - n * r + box_surf) * 0.5, n, depth);
}

/// Parameter range `[s_lo, s_hi]` on the segment `c + s d`, `s` in `[-hl, hl]`, of the points
/// closest to the box `|x| <= h` (a range when the segment runs parallel to the closest feature).
/// The squared distance is convex and piecewise quadratic in `s`; its derivative is piecewise linear
/// and non-decreasing with breaks where a coordinate crosses a face plane, so the minimisers are
/// found exactly (derivatives within `slack` of zero count as zero).
fn closest_params_segment_box(c: DVec3, d: DVec3, hl: f64, h: DVec3, slack: f64) -> (f64, f64) {
    let mut ts = [0.0f64; 8];
    ts[0] = -hl;
    ts[1] = hl;
    let mut m = 2;
    for i in 0..3 {
        if d[i].abs() > 1e-15 {
            for bound in [-h[i], h[i]] {
                let t = (bound - c[i]) / d[i];
                if t > -hl && t < hl && m < ts.len() {
                    ts[m] = t;
                    m += 1;
                }
            }
        }
    }
    // Insertion sort (m <= 8).
    for k in 1..m {
        let mut j = k;
        while j > 0 && ts[j - 1] > ts[j] {
            ts.swap(j - 1, j);
            j -= 1;
        }
    }
    let mut gs = [0.0f64; 8];
    for k in 0..m {
        let p = c + d * ts[k];
        gs[k] = (p - clamp3(p, h)).dot(d);
    }
    // First s with g(s) >= -slack, last s with g(s) <= slack.
    let mut lo = ts[m - 1];
    for k in 0..m {
        if gs[k] >= -slack {
            lo = if k == 0 { ts[0] } else { crossing(ts[k - 1], gs[k - 1], ts[k], gs[k], -slack) };
            break;
        }
    }
    let mut hi = ts[0];
    for k in (0..m).rev() {
        if gs[k] <= slack {
            hi = if k == m - 1 { ts[k] } else { crossing(ts[k], gs[k], ts[k + 1], gs[k + 1], slack) };
            break;
        }
    }
    if hi < lo {
        let mid = 0.5 * (lo + hi);
        (mid, mid)
    } else {
        (lo, hi)
    }
}

/// Where the line through (t0, g0), (t1, g1) reaches `level` (g0 <= level <= g1 or the reverse).
#[inline]
fn crossing(t0: f64, g0: f64, t1: f64, g1: f64, level: f64) -> f64 {
    let span = g1 - g0;
    if span.abs() > 0.0 {
        t0 + (t1 - t0) * clampf((level - g0) / span, 0.0, 1.0)
    } else {
        t0
    }
}

/// Hits for a capsule core `c + s d` against face `sign * e_i` of the box `|x| <= h` (box-local):
/// the segment is clipped to the face's extent and both ends of the clipped part are reported.
/// Returns false when nothing of the segment lies over the face.
#[allow(clippy::too_many_arguments)]
fn capsule_face_hits(
    sink: &mut Sink,
    pb: &ShapePose,
    c: DVec3,
    d: DVec3,
    hl: f64,
    r: f64,
    h: DVec3,
    i: usize,
    sign: f64,
    core_inside: bool,
) -> bool {
    let mut lo = -hl;
    let mut hi = hl;
    for j in 0..3 {
        if j == i {
            continue;
        }
        let lim = h[j] + CLIP_SLACK * (1.0 + h[j]);
        if d[j].abs() < 1e-15 {
            if !(c[j].abs() <= lim) {
                return false;
            }
        } else {
            let t1 = (-lim - c[j]) / d[j];
            let t2 = (lim - c[j]) / d[j];
            lo = lo.max(t1.min(t2));
            hi = hi.min(t1.max(t2));
        }
    }
    if !(lo <= hi) {
        return false;
    }
    let n_local = unit_axis(i) * sign;
    let n = pb.rot * n_local;
    let mut push_at = |s: f64| {
        let p = c + d * s;
        let height = sign * p[i] - h[i];
        let mut q = p;
        q[i] = sign * h[i];
        let mid = (p - n_local * r + q) * 0.5;
        sink.push(pb.world_point(mid), n, r - height);
        r - height
    };
    let deepest =
        if hi - lo > 1e-9 * (1.0 + hl) { push_at(lo).max(push_at(hi)) } else { push_at(0.5 * (lo + hi)) };
    if core_inside {
        // The face axis's overlap counts the whole segment: if its deepest end lies beyond the face
        // (the segment leaves through a side), report that end too so the deepest hit is the
        // separating depth.
        let end = if sign * d[i] > 0.0 { -hl } else { hl };
        let p = c + d * end;
        if r - (sign * p[i] - h[i]) > deepest + 1e-9 * (1.0 + hl) {
            push_at(end);
        }
    }
    true
}

fn capsule_box(sink: &mut Sink, pa: &ShapePose, hl: f64, r: f64, pb: &ShapePose, h: DVec3) {
    let c = pb.local_point(pa.pos_m);
    let d = tmul(&pb.rot, pa.rot.y_axis);
    let scale = 1.0 + h.max_element() + hl;
    let (s_lo, s_hi) = closest_params_segment_box(c, d, hl, h, 1e-12 * scale);
    let s = 0.5 * (s_lo + s_hi);
    let p = c + d * s;
    let q = clamp3(p, h);
    let diff = p - q;
    let d2 = diff.length_squared();
    let core_tol = TINY_M * scale;
    if d2 > core_tol * core_tol {
        // The core is outside the box: closest points.
        if !(d2 < r * r) {
            return;
        }
        let dist = d2.sqrt();
        let n_local = diff / dist;
        let off = diff.abs();
        let face_tol = 1e-9 * scale;
        let outside = (off.x > face_tol) as u8 + (off.y > face_tol) as u8 + (off.z > face_tol) as u8;
        if outside == 1 {
            let i = if off.x >= off.y && off.x >= off.z {
                0
            } else if off.y >= off.z {
                1
            } else {
                2
            };
            if capsule_face_hits(sink, pb, c, d, hl, r, h, i, sign_of(diff[i]), false) {
                return;
            }
        }
        if s_hi - s_lo > 1e-9 * scale {
            // Parallel to the closest edge: both ends of the closest stretch.
            for s in [s_lo, s_hi] {
                let p = c + d * s;
                let q = clamp3(p, h);
                let (mid, n_local, depth) = core_contact(p, r, q, 0.0, n_local);
                sink.push(pb.world_point(mid), pb.rot * n_local, depth);
            }
        } else {
            let mid = (p - n_local * r + q) * 0.5;
            sink.push(pb.world_point(mid), pb.rot * n_local, r - dist);
        }
        return;
    }

    // The core segment meets the box: separating axes of segment vs box (3 faces, 3 edge crosses).
    let mut best = f64::INFINITY;
    let mut best_face = 1usize;
    for i in 0..3 {
        let ov = h[i] + hl * d[i].abs() - c[i].abs();
        if ov < best {
            best = ov;
            best_face = i;
        }
    }
    let face_best = best;
    let mut best_edge: Option<(usize, DVec3)> = None;
    for k in 0..3 {
        let l = d.cross(unit_axis(k));
        let len = l.length();
        if !(len > EDGE_AXIS_MIN_SIN) {
            continue;
        }
        let l = l / len;
        let ov = h.dot(l.abs()) - c.dot(l).abs();
        if ov < best && ov < EDGE_AXIS_REL * face_best - TINY_M {
            best = ov;
            best_edge = Some((k, l));
        }
    }
    let depth = best + r;
    match best_edge {
        None => {
            let sign = sign_of(c[best_face]);
            if !capsule_face_hits(sink, pb, c, d, hl, r, h, best_face, sign, true) {
                let n_local = unit_axis(best_face) * sign;
                sink.push(pb.world_point(p), pb.rot * n_local, depth);
            }
        }
        Some((k, l)) => {
            let n_local = if c.dot(l) < 0.0 { -l } else { l };
            // Box edge along e_k furthest along +n (toward the capsule).
            let mut corner = DVec3::ZERO;
            for j in 0..3 {
                if j != k {
                    corner[j] = sign_of(n_local[j]) * h[j];
                }
            }
            let seg = Seg { c, u: d, h: hl };
            let edge = Seg { c: corner, u: unit_axis(k), h: h[k] };
            let (s, t) = closest_segments(seg, edge);
            let mid = (seg.at(s) - n_local * r + edge.at(t)) * 0.5;
            sink.push(pb.world_point(mid), pb.rot * n_local, depth);
        }
    }
}

/// Parameter range `[t0, t1]` within `[0, 1]` of the segment `p0 -> p1` inside the box `|x| <= h`.
fn clip_segment_box(p0: DVec3, p1: DVec3, h: DVec3) -> Option<(f64, f64)> {
    let d = p1 - p0;
    let mut lo = 0.0f64;
    let mut hi = 1.0f64;
    for i in 0..3 {
        let lim = h[i] + CLIP_SLACK * (1.0 + h[i]);
        if d[i].abs() < 1e-15 {
            if !(p0[i].abs() <= lim) {
                return None;
            }
        } else {
            let t1 = (-lim - p0[i]) / d[i];
            let t2 = (lim - p0[i]) / d[i];
            lo = lo.max(t1.min(t2));
            hi = hi.min(t1.max(t2));
            if !(lo <= hi) {
                return None;
            }
        }
    }
    Some((lo, hi))
}

/// The 8 vertices of the box `|x| <= h`; bit k of the index set means +h along axis k.
fn box_vertices(h: DVec3) -> [DVec3; 8] {
    let mut v = [DVec3::ZERO; 8];
    for (i, p) in v.iter_mut().enumerate() {
        let s = |k: usize| if i & (1 << k) != 0 { 1.0 } else { -1.0 };
        *p = DVec3::new(s(0) * h.x, s(1) * h.y, s(2) * h.z);
    }
    v
}

/// The 12 edges as pairs of vertex indices (see `box_vertices`).
const BOX_EDGES: [(usize, usize); 12] =
    [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)];

/// Contact candidates of box `p` (vertices `v` in the output frame, `v_other` the same vertices in
/// the other box's frame, whose half extents are `h_other`): its vertices inside the other box and
/// the points where its edges cross the other box's faces. `depth_of` gives (point, depth).
fn box_candidates(
    cand: &mut Candidates,
    v: &[DVec3; 8],
    v_other: &[DVec3; 8],
    h_other: DVec3,
    depth_of: impl Fn(DVec3) -> (DVec3, f64),
) {
    for (p, q) in v.iter().zip(v_other.iter()) {
        if inside_box(*q, h_other) {
            let (x, d) = depth_of(*p);
            cand.add(x, d);
        }
    }
    for (i, j) in BOX_EDGES {
        if let Some((t0, t1)) = clip_segment_box(v_other[i], v_other[j], h_other) {
            for (par, interior) in [(t0, t0 > 0.0), (t1, t1 < 1.0)] {
                if interior {
                    let (x, d) = depth_of(v[i].lerp(v[j], par));
                    cand.add(x, d);
                }
            }
        }
    }
}

#[inline]
fn inside_box(p: DVec3, h: DVec3) -> bool {
    let slack = CLIP_SLACK * (1.0 + h.max_element());
    p.x.abs() <= h.x + slack && p.y.abs() <= h.y + slack && p.z.abs() <= h.z + slack
}

/// Candidate contact points (box-box), deduplicated, capacity for every clipped edge end.
struct Candidates {
    p: [DVec3; 48],
    d: [f64; 48],
    n: usize,
    tol2: f64,
}

impl Candidates {
    fn add(&mut self, p: DVec3, d: f64) {
        if !(d > 0.0) || self.n >= self.p.len() {
            return;
        }
        for k in 0..self.n {
            if (self.p[k] - p).length_squared() <= self.tol2 {
                if d > self.d[k] {
                    self.d[k] = d;
                }
                return;
            }
        }
        self.p[self.n] = p;
        self.d[self.n] = d;
        self.n += 1;
    }
}

fn box_box(sink: &mut Sink, pa: &ShapePose, ha: DVec3, pb: &ShapePose, hb: DVec3) {
    // Everything in A's frame: A centred at the origin with identity axes.
    let rot = pa.rot.transpose() * pb.rot;
    let t = pa.local_point(pb.pos_m);
    let bx = [rot.x_axis, rot.y_axis, rot.z_axis];
    let proj_a = |l: DVec3| ha.dot(l.abs());
    let proj_b = |l: DVec3| hb.x * bx[0].dot(l).abs() + hb.y * bx[1].dot(l).abs() + hb.z * bx[2].dot(l).abs();
    let overlap = |l: DVec3| proj_a(l) + proj_b(l) - t.dot(l).abs();

    let mut best = f64::INFINITY;
    let mut best_l = DVec3::Y;
    for l in [DVec3::X, DVec3::Y, DVec3::Z, bx[0], bx[1], bx[2]] {
        let ov = overlap(l);
        if ov <= 0.0 {
            return;
        }
        if ov < best {
            best = ov;
            best_l = l;
        }
    }
    let face_best = best;
    let mut best_edge: Option<(usize, usize)> = None;
    for i in 0..3 {
        for (j, bj) in bx.iter().enumerate() {
            let l = unit_axis(i).cross(*bj);
            let len = l.length();
            if !(len > EDGE_AXIS_MIN_SIN) {
                continue;
            }
            let l = l / len;
            let ov = overlap(l);
            if ov <= 0.0 {
                return;
            }
            if ov < best && ov < EDGE_AXIS_REL * face_best - TINY_M {
                best = ov;
                best_l = l;
                best_edge = Some((i, j));
            }
        }
    }
    if !(best > 0.0 && best.is_finite()) {
        return;
    }
    // From B toward A (A is at the origin).
    let n = if t.dot(best_l) > 0.0 { -best_l } else { best_l };
    let n_world = pa.rot * n;

    if let Some((i, j)) = best_edge {
        // A's edge along e_i deepest toward B (support in -n), B's edge along b_j toward A (+n).
        let mut ca = DVec3::ZERO;
        for k in 0..3 {
            if k != i {
                ca[k] = -sign_of(n[k]) * ha[k];
            }
        }
        let mut cb = t;
        for (m, bm) in bx.iter().enumerate() {
            if m != j {
                cb += *bm * (sign_of(bm.dot(n)) * hb[m]);
            }
        }
        let ea = Seg { c: ca, u: unit_axis(i), h: ha[i] };
        let eb = Seg { c: cb, u: bx[j], h: hb[j] };
        let (s, u) = closest_segments(ea, eb);
        sink.push(pa.world_point((ea.at(s) + eb.at(u)) * 0.5), n_world, best);
        return;
    }

    // Face axis: the vertices of each box inside the other, and the points where the edges of each
    // cross the faces of the other (the clipped ends of its edges).
    let max_b = n.dot(t) + proj_b(n);
    let min_a = -proj_a(n);
    let scale = 1.0 + ha.max_element().max(hb.max_element());
    let mut cand =
        Candidates { p: [DVec3::ZERO; 48], d: [0.0; 48], n: 0, tol2: (1e-6 * scale) * (1e-6 * scale) };
    let va = box_vertices(ha);
    let va_in_b = va.map(|p| tmul(&rot, p - t));
    let vb = box_vertices(hb).map(|q| t + rot * q);
    box_candidates(&mut cand, &va, &va_in_b, hb, |x| {
        let depth = max_b - n.dot(x);
        (x + n * (0.5 * depth), depth)
    });
    box_candidates(&mut cand, &vb, &vb, ha, |w| {
        let depth = n.dot(w) - min_a;
        (w - n * (0.5 * depth), depth)
    });
    if cand.n == 0 {
        // Numerically nothing inside: the middle of the overlap slab, between the centres.
        let base = t * 0.5;
        let point = base + n * (0.5 * (min_a + max_b) - n.dot(base));
        sink.push(pa.world_point(point), n_world, best);
        return;
    }
    // The deepest MAX_HITS candidates, deepest first.
    for _ in 0..MAX_HITS {
        let mut pick = None;
        let mut pick_d = 0.0;
        for (k, &d) in cand.d.iter().enumerate().take(cand.n) {
            if d > pick_d {
                pick = Some(k);
                pick_d = d;
            }
        }
        let Some(k) = pick else { break };
        cand.d[k] = f64::NEG_INFINITY;
        sink.push(pa.world_point(cand.p[k]), n_world, pick_d.min(best));
    }
}

fn box_plane(sink: &mut Sink, pa: &ShapePose, h: DVec3, pp: &ShapePose) {
    box_plane_n(sink, pa, h, plane_normal(pp), pp.pos_m);
}

/// `collide(box, pa, plane, pp, out)` for a plane whose `plane_normal(pp)` the caller already has:
/// the same hits, bit for bit. The crowd stepper calls this for every character's feet on the
/// floor every step, where the normal's normalisation (a division) was most of the cost.
pub fn box_on_plane(
    half_extents_m: DVec3,
    pa: &ShapePose,
    normal: DVec3,
    plane_m: DVec3,
    out: &mut [Hit; MAX_HITS],
) -> usize {
    let mut sink = Sink { out, n: 0 };
    box_plane_n(&mut sink, pa, size3(half_extents_m), normal, plane_m);
    sink.n
}

#[inline]
fn box_plane_n(sink: &mut Sink, pa: &ShapePose, h: DVec3, n: DVec3, plane_m: DVec3) {
    if h.x > 0.0 && h.y > 0.0 && h.z > 0.0 {
        // The usual box: the eight corners in the order of the general loop below, unrolled, and
        // a corner above the plane (which the sink would drop) skipped before its point is made.
        for ix in [-1.0, 1.0] {
            for iy in [-1.0, 1.0] {
                for iz in [-1.0, 1.0] {
                    let v = pa.world_point(DVec3::new(ix * h.x, iy * h.y, iz * h.z));
                    let height = n.dot(v - plane_m);
                    if height < 0.0 {
                        sink.push(v - n * (0.5 * height), n, -height);
                    }
                }
            }
        }
        return;
    }
    // Zero extents give coincident vertices: visit each distinct vertex once.
    let signs = |x: f64| if x > 0.0 { [-1.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
    let count = |x: f64| if x > 0.0 { 2 } else { 1 };
    let (sx, sy, sz) = (signs(h.x), signs(h.y), signs(h.z));
    for &ix in sx.iter().take(count(h.x)) {
        for &iy in sy.iter().take(count(h.y)) {
            for &iz in sz.iter().take(count(h.z)) {
                let v = pa.world_point(DVec3::new(ix * h.x, iy * h.y, iz * h.z));
                let height = n.dot(v - plane_m);
                sink.push(v - n * (0.5 * height), n, -height);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;
    use proptest::prelude::*;

    const EPS: f64 = 1e-9;

    fn hits(a: &Shape, pa: &ShapePose, b: &Shape, pb: &ShapePose) -> Vec<Hit> {
        let mut out = [Hit::ZERO; MAX_HITS];
        let n = collide(a, pa, b, pb, &mut out);
        assert!(n <= MAX_HITS);
        out[..n].to_vec()
    }

    #[test]
    fn box_on_plane_gives_the_same_hits_as_collide() {
        let mut touching = 0;
        let tilted =
            ShapePose::new(DVec3::new(0.3, -0.2, 0.1), DMat3::from_quat(DQuat::from_rotation_z(0.2)));
        for (k, pose) in [
            ShapePose::at(DVec3::new(2.0, 0.24, -1.0)),
            ShapePose::new(
                DVec3::new(0.1, 0.2, 0.0),
                DMat3::from_quat(DQuat::from_euler(glam::EulerRot::XYZ, 0.3, 0.5, 0.2)),
            ),
            ShapePose::at(DVec3::new(0.0, 2.0, 0.0)),
        ]
        .iter()
        .enumerate()
        {
            for half in [DVec3::new(0.5, 0.25, 0.3), DVec3::new(0.5, 0.0, 0.3)] {
                for plane in [ShapePose::IDENTITY, tilted] {
                    let want = hits(&cuboid(half.x, half.y, half.z), pose, &Shape::Plane, &plane);
                    let mut out = [Hit::ZERO; MAX_HITS];
                    let n = box_on_plane(half, pose, plane_normal(&plane), plane.pos_m, &mut out);
                    assert_eq!(out[..n].to_vec(), want, "case {k}");
                    touching += (n > 0) as usize;
                }
            }
        }
        // Some cases touch (the comparison is of real hits); the one 2 m up does not.
        assert!(touching >= 2, "only {touching} cases touch");
    }

    fn sphere(r: f64) -> Shape {
        Shape::Sphere { radius_m: r }
    }
    fn capsule(h: f64, r: f64) -> Shape {
        Shape::Capsule { half_length_m: h, radius_m: r }
    }
    fn cuboid(x: f64, y: f64, z: f64) -> Shape {
        Shape::Box { half_extents_m: DVec3::new(x, y, z) }
    }
    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }
    fn at(x: f64, y: f64, z: f64) -> ShapePose {
        ShapePose::at(v(x, y, z))
    }
    /// Local y (a capsule's axis) along world x.
    fn along_x(x: f64, y: f64, z: f64) -> ShapePose {
        ShapePose::new(v(x, y, z), DMat3::from_rotation_z(-core::f64::consts::FRAC_PI_2))
    }
    /// Local y along world z.
    fn along_z(x: f64, y: f64, z: f64) -> ShapePose {
        ShapePose::new(v(x, y, z), DMat3::from_rotation_x(core::f64::consts::FRAC_PI_2))
    }

    #[track_caller]
    fn close(a: f64, b: f64) {
        assert!((a - b).abs() < EPS, "{a} != {b}");
    }
    #[track_caller]
    fn close3(a: DVec3, b: DVec3) {
        assert!((a - b).length() < EPS, "{a} != {b}");
    }
    #[track_caller]
    fn one(h: &[Hit], point: DVec3, normal: DVec3, depth: f64) {
        assert_eq!(h.len(), 1, "{h:?}");
        close3(h[0].point_m, point);
        close3(h[0].normal, normal);
        close(h[0].depth_m, depth);
    }
    /// The hits, whatever their order, are exactly the given (point, depth) with one normal.
    #[track_caller]
    fn set(h: &[Hit], normal: DVec3, expected: &[(DVec3, f64)]) {
        assert_eq!(h.len(), expected.len(), "{h:?}");
        for &(p, d) in expected {
            let found = h.iter().find(|x| (x.point_m - p).length() < 1e-7);
            let Some(x) = found else { panic!("no hit at {p} in {h:?}") };
            close(x.depth_m, d);
            close3(x.normal, normal);
        }
    }

    // ---- sphere ----

    #[test]
    fn sphere_sphere_analytic() {
        let h = hits(&sphere(1.0), &at(0.0, 0.0, 0.0), &sphere(1.0), &at(1.5, 0.0, 0.0));
        one(&h, v(0.75, 0.0, 0.0), v(-1.0, 0.0, 0.0), 0.5);
        // Different radii: surfaces at x=0.4 (a) and x=0.5 (b) -> midpoint 0.45.
        let h = hits(&sphere(0.4), &at(0.0, 0.0, 0.0), &sphere(0.5), &at(0.0, 0.0, 0.8));
        one(&h, v(0.0, 0.0, 0.35), v(0.0, 0.0, -1.0), 0.1);
        assert!(hits(&sphere(1.0), &at(0.0, 0.0, 0.0), &sphere(1.0), &at(2.0, 0.0, 0.0)).is_empty());
        assert!(hits(&sphere(1.0), &at(0.0, 0.0, 0.0), &sphere(1.0), &at(2.5, 0.0, 0.0)).is_empty());
    }

    #[test]
    fn sphere_sphere_coincident_uses_plus_or_minus_y() {
        let h = hits(&sphere(0.3), &at(1.0, 2.0, 3.0), &sphere(0.2), &at(1.0, 2.0, 3.0));
        assert_eq!(h.len(), 1);
        let n = h[0].normal;
        assert!(n == DVec3::Y || n == -DVec3::Y, "{n}");
        // Midpoint between a's surface (c - 0.3 n) and b's (c + 0.2 n).
        one(&h, v(1.0, 2.0, 3.0) - n * 0.05, n, 0.5);
        // The other order mirrors it.
        let g = hits(&sphere(0.2), &at(1.0, 2.0, 3.0), &sphere(0.3), &at(1.0, 2.0, 3.0));
        one(&g, h[0].point_m, -n, 0.5);
    }

    #[test]
    fn sphere_capsule_side_and_end() {
        // Vertical capsule (segment y in [-1, 1], radius 0.5); sphere beside it.
        let h = hits(&sphere(0.7), &at(1.0, 0.5, 0.0), &capsule(1.0, 0.5), &at(0.0, 0.0, 0.0));
        one(&h, v(0.4, 0.5, 0.0), DVec3::X, 0.2);
        // Above the top end.
        let h = hits(&sphere(0.5), &at(0.0, 1.8, 0.0), &capsule(1.0, 0.5), &at(0.0, 0.0, 0.0));
        one(&h, v(0.0, 1.4, 0.0), DVec3::Y, 0.2);
        // Swapped order: normal from the sphere toward the capsule.
        let h = hits(&capsule(1.0, 0.5), &at(0.0, 0.0, 0.0), &sphere(0.7), &at(1.0, 0.5, 0.0));
        one(&h, v(0.4, 0.5, 0.0), -DVec3::X, 0.2);
        // Centre on the axis: a fixed perpendicular of the axis.
        let h = hits(&sphere(0.1), &at(0.0, 0.3, 0.0), &capsule(1.0, 0.5), &at(0.0, 0.0, 0.0));
        assert_eq!(h.len(), 1);
        close(h[0].normal.length(), 1.0);
        close(h[0].normal.y, 0.0);
        close(h[0].depth_m, 0.6);
        assert!(hits(&sphere(0.5), &at(0.0, 2.1, 0.0), &capsule(1.0, 0.5), &ShapePose::IDENTITY).is_empty());
    }

    #[test]
    fn sphere_box_face_edge_corner_inside() {
        let b = cuboid(1.0, 1.0, 1.0);
        let o = ShapePose::IDENTITY;
        let h = hits(&sphere(1.0), &at(1.5, 0.0, 0.0), &b, &o);
        one(&h, v(0.75, 0.0, 0.0), DVec3::X, 0.5);
        // Edge (x = y = 1): distance 0.2 * sqrt 2.
        let d = 0.2 * 2f64.sqrt();
        let n = v(1.0, 1.0, 0.0).normalize();
        let h = hits(&sphere(0.5), &at(1.2, 1.2, 0.3), &b, &o);
        one(&h, v(1.0, 1.0, 0.3) + n * (0.5 * (d - 0.5)), n, 0.5 - d);
        // Corner.
        let d = 0.1 * 3f64.sqrt();
        let n = v(1.0, 1.0, 1.0).normalize();
        let h = hits(&sphere(0.3), &at(1.1, 1.1, 1.1), &b, &o);
        one(&h, v(1.0, 1.0, 1.0) + n * (0.5 * (d - 0.3)), n, 0.3 - d);
        // Centre inside, nearest face +x at 0.2: depth r + 0.2.
        let h = hits(&sphere(0.1), &at(0.8, 0.1, -0.3), &b, &o);
        one(&h, v(0.85, 0.1, -0.3), DVec3::X, 0.3);
        // Rotated, translated box: 45 degrees about z, sphere straight above.
        let pb = ShapePose::new(v(2.0, 0.0, 0.0), DMat3::from_rotation_z(core::f64::consts::FRAC_PI_4));
        let top = 2f64.sqrt(); // top corner edge of the rotated box
        let h = hits(&sphere(0.5), &at(2.0, top + 0.4, 0.0), &b, &pb);
        one(&h, v(2.0, top - 0.05, 0.0), DVec3::Y, 0.1);
        // Zero-size box at the sphere centre.
        let h = hits(&sphere(0.5), &at(0.0, 0.0, 0.0), &cuboid(0.0, 0.0, 0.0), &o);
        assert_eq!(h.len(), 1);
        close(h[0].depth_m, 0.5);
    }

    // ---- capsule ----

    #[test]
    fn capsule_capsule_crossing() {
        let h =
            hits(&capsule(1.0, 0.5), &along_x(0.0, 0.8, 0.0), &capsule(1.0, 0.5), &along_z(0.0, 0.0, 0.0));
        one(&h, v(0.0, 0.4, 0.0), DVec3::Y, 0.2);
        // Off-centre crossing, radii differ: closest points (0.3, 0.7, 0.2) and (0.3, 0, 0.2).
        let h =
            hits(&capsule(1.0, 0.4), &along_x(0.0, 0.7, 0.2), &capsule(1.0, 0.4), &along_z(0.3, 0.0, 0.0));
        one(&h, v(0.3, 0.35, 0.2), DVec3::Y, 0.1);
        // End to end, collinear along x, gap 0.1 between the segment ends.
        let h =
            hits(&capsule(1.0, 0.1), &along_x(2.1, 0.0, 0.0), &capsule(1.0, 0.1), &along_x(0.0, 0.0, 0.0));
        one(&h, v(1.05, 0.0, 0.0), DVec3::X, 0.1);
        assert!(hits(
            &capsule(1.0, 0.5),
            &along_x(0.0, 1.0, 0.0),
            &capsule(1.0, 0.5),
            &along_z(0.0, 0.0, 0.0)
        )
        .is_empty());
    }

    #[test]
    fn parallel_capsules_give_two_hits_at_the_overlap_ends() {
        // a lies on b, both along x; b is shifted so the overlap is x in [0.5, 1].
        let h =
            hits(&capsule(1.0, 0.5), &along_x(0.0, 0.9, 0.0), &capsule(1.0, 0.5), &along_x(1.5, 0.0, 0.0));
        set(&h, DVec3::Y, &[(v(0.5, 0.45, 0.0), 0.1), (v(1.0, 0.45, 0.0), 0.1)]);
        // Full overlap, antiparallel axes, different lengths.
        let flip = ShapePose::new(v(0.0, 0.0, 0.0), DMat3::from_rotation_z(core::f64::consts::FRAC_PI_2));
        let h = hits(&capsule(0.5, 0.3), &along_x(0.2, 0.0, 0.5), &capsule(2.0, 0.3), &flip);
        set(&h, DVec3::Z, &[(v(-0.3, 0.0, 0.25), 0.1), (v(0.7, 0.0, 0.25), 0.1)]);
        // Nearly parallel (1e-4 rad) still gives two hits.
        let tilt =
            ShapePose::new(v(0.0, 0.9, 0.0), DMat3::from_rotation_z(-core::f64::consts::FRAC_PI_2 + 1e-4));
        let h = hits(&capsule(1.0, 0.5), &tilt, &capsule(1.0, 0.5), &along_x(0.0, 0.0, 0.0));
        assert_eq!(h.len(), 2, "{h:?}");
        // Collinear, overlapping cores (coincident axes): finite normal perpendicular to the axis.
        let h =
            hits(&capsule(1.0, 0.2), &along_x(0.5, 0.0, 0.0), &capsule(1.0, 0.2), &along_x(0.0, 0.0, 0.0));
        assert_eq!(h.len(), 2);
        for x in &h {
            close(x.normal.length(), 1.0);
            close(x.normal.x, 0.0);
            close(x.depth_m, 0.4);
        }
    }

    #[test]
    fn capsule_box_standing_lying_edge_and_penetrating() {
        let b = cuboid(1.0, 1.0, 1.0);
        let o = ShapePose::IDENTITY;
        // Standing on the top face: bottom end core at y = 1.3.
        let h = hits(&capsule(1.0, 0.5), &at(0.0, 2.3, 0.0), &b, &o);
        one(&h, v(0.0, 0.9, 0.0), DVec3::Y, 0.2);
        // Lying on the top face: two hits at the segment ends.
        let h = hits(&capsule(0.5, 0.5), &along_x(0.2, 1.4, 0.3), &b, &o);
        set(&h, DVec3::Y, &[(v(-0.3, 0.95, 0.3), 0.1), (v(0.7, 0.95, 0.3), 0.1)]);
        // Long capsule across the face: the hits are where it leaves the face (x = +-1).
        let h = hits(&capsule(3.0, 0.5), &along_x(0.0, 1.4, 0.0), &b, &o);
        set(&h, DVec3::Y, &[(v(-1.0, 0.95, 0.0), 0.1), (v(1.0, 0.95, 0.0), 0.1)]);
        // Tilted so one end lifts clear: a single hit at the low end.
        let tilt =
            ShapePose::new(v(0.0, 1.6, 0.0), DMat3::from_rotation_z(-core::f64::consts::FRAC_PI_2 + 0.5));
        let h = hits(&capsule(0.5, 0.5), &tilt, &b, &o);
        assert_eq!(h.len(), 1, "{h:?}");
        close3(h[0].normal, DVec3::Y);
        let low = 1.6 - 0.5 * 0.5f64.sin();
        close(h[0].depth_m, 0.5 - (low - 1.0));
        // Across the top edge x = y = 1 (capsule along z).
        let d = 0.3 * 2f64.sqrt();
        let n = v(1.0, 1.0, 0.0).normalize();
        // The capsule runs along the edge: both ends of the edge (z = +-1) are hits.
        let h = hits(&capsule(2.0, 0.5), &along_z(1.3, 1.3, 0.0), &b, &o);
        let e = |z: f64| (v(1.0, 1.0, z) + n * (0.5 * (d - 0.5)), 0.5 - d);
        set(&h, n, &[e(-1.0), e(1.0)]);
        // Across the edge at an angle: one hit.
        let skew = ShapePose::new(v(1.3, 1.3, 0.0), DMat3::from_rotation_z(core::f64::consts::FRAC_PI_4));
        let h = hits(&capsule(2.0, 0.5), &skew, &b, &o);
        one(&h, v(1.0, 1.0, 0.0) + n * (0.5 * (d - 0.5)), n, 0.5 - d);
        // Core inside the box just under the top face: the face axis, two hits, depth r + 0.1.
        let h = hits(&capsule(0.5, 0.2), &along_x(0.0, 0.9, 0.0), &b, &o);
        set(&h, DVec3::Y, &[(v(-0.5, 0.85, 0.0), 0.3), (v(0.5, 0.85, 0.0), 0.3)]);
        // Core piercing an edge region diagonally: the edge-cross axis (1, 1, 0)/sqrt 2.
        let diag = ShapePose::new(v(0.95, 0.95, 0.0), DMat3::from_rotation_z(core::f64::consts::FRAC_PI_4));
        let h = hits(&capsule(0.3, 0.1), &diag, &b, &o);
        assert_eq!(h.len(), 1, "{h:?}");
        close3(h[0].normal, n);
        close(h[0].depth_m, 0.1 + (2f64.sqrt() - 0.95 * 2f64.sqrt()));
        // Swapped order.
        let h = hits(&b, &o, &capsule(0.5, 0.5), &along_x(0.2, 1.4, 0.3));
        set(&h, -DVec3::Y, &[(v(-0.3, 0.95, 0.3), 0.1), (v(0.7, 0.95, 0.3), 0.1)]);
        assert!(hits(&capsule(0.5, 0.5), &along_x(0.0, 1.5, 0.0), &b, &o).is_empty());
    }

    #[test]
    fn capsule_lying_on_rotated_box_face_gives_two_hits() {
        // Box rotated about y by 30 degrees; capsule lies along the box's local x on its top face.
        let r = DMat3::from_rotation_y(0.5);
        let pb = ShapePose::new(v(1.0, -1.0, 2.0), r);
        let pa = ShapePose::new(
            pb.pos_m + r * v(0.1, 0.5 + 0.3 - 0.05, 0.0),
            r * DMat3::from_rotation_z(core::f64::consts::FRAC_PI_2),
        );
        let h = hits(&capsule(0.4, 0.3), &pa, &cuboid(1.0, 0.5, 0.7), &pb);
        let e1 = pb.pos_m + r * v(0.5, 0.5 - 0.025, 0.0);
        let e2 = pb.pos_m + r * v(-0.3, 0.5 - 0.025, 0.0);
        set(&h, DVec3::Y, &[(e1, 0.05), (e2, 0.05)]);
    }

    // ---- box ----

    #[test]
    fn box_box_stacked_gives_the_four_corners() {
        let h =
            hits(&cuboid(0.5, 0.5, 0.5), &at(0.2, 1.4, 0.1), &cuboid(1.0, 1.0, 1.0), &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (v(0.2 + x, 0.95, 0.1 + z), 0.1);
        set(&h, DVec3::Y, &[c(-0.5, -0.5), c(-0.5, 0.5), c(0.5, -0.5), c(0.5, 0.5)]);
        // Same-size boxes stacked exactly (vertices on the other's side faces).
        let h =
            hits(&cuboid(1.0, 1.0, 1.0), &at(0.0, 1.95, 0.0), &cuboid(1.0, 1.0, 1.0), &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (v(x, 0.975, z), 0.05);
        set(&h, DVec3::Y, &[c(-1.0, -1.0), c(-1.0, 1.0), c(1.0, -1.0), c(1.0, 1.0)]);
        // The small box underneath: B's top corners inside A; normal from B (below) up to A.
        let h = hits(&cuboid(1.0, 1.0, 1.0), &at(0.0, 0.0, 0.0), &cuboid(0.5, 0.5, 0.5), &at(0.2, -1.4, 0.1));
        let c = |x: f64, z: f64| (v(0.2 + x, -0.95, 0.1 + z), 0.1);
        set(&h, DVec3::Y, &[c(-0.5, -0.5), c(-0.5, 0.5), c(0.5, -0.5), c(0.5, 0.5)]);
    }

    #[test]
    fn box_box_crossed_bars_use_the_edge_crossings() {
        // No vertex of either bar is inside the other: the contact square is x, z in [-0.5, 0.5].
        let h =
            hits(&cuboid(2.0, 0.5, 0.5), &at(0.0, 1.4, 0.0), &cuboid(0.5, 1.0, 2.0), &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (v(x, 0.95, z), 0.1);
        set(&h, DVec3::Y, &[c(-0.5, -0.5), c(-0.5, 0.5), c(0.5, -0.5), c(0.5, 0.5)]);
    }

    #[test]
    fn box_box_overhanging_and_rotated_on_top() {
        // Half overhanging: contact rectangle x in [0.5, 1], z in [-0.5, 0.5].
        let h =
            hits(&cuboid(0.5, 0.5, 0.5), &at(1.0, 1.4, 0.0), &cuboid(1.0, 1.0, 1.0), &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (v(x, 0.95, z), 0.1);
        set(&h, DVec3::Y, &[c(0.5, -0.5), c(0.5, 0.5), c(1.0, -0.5), c(1.0, 0.5)]);
        // Same-size square rotated 45 degrees about y on top: the contact is an octagon.
        let pa = ShapePose::new(v(0.0, 1.9, 0.0), DMat3::from_rotation_y(core::f64::consts::FRAC_PI_4));
        let h = hits(&cuboid(1.0, 1.0, 1.0), &pa, &cuboid(1.0, 1.0, 1.0), &ShapePose::IDENTITY);
        assert_eq!(h.len(), 8, "{h:?}");
        let k = 2f64.sqrt() - 1.0;
        for x in &h {
            close3(x.normal, DVec3::Y);
            close(x.depth_m, 0.1);
            close(x.point_m.y, 0.95);
            let (px, pz) = (x.point_m.x.abs(), x.point_m.z.abs());
            assert!(
                (close_to(px, 1.0) && close_to(pz, k)) || (close_to(px, k) && close_to(pz, 1.0)),
                "{x:?}"
            );
        }
    }

    fn close_to(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn box_box_edge_on_edge() {
        // A: cube rotated 45 degrees about z (lowest edge along z); B: rotated 45 degrees about x (top
        // edge along x). The edges cross at x = z = 0 with 0.1 overlap along y.
        let s2 = 2f64.sqrt();
        let pa =
            ShapePose::new(v(0.0, 2.0 * s2 - 0.1, 0.0), DMat3::from_rotation_z(core::f64::consts::FRAC_PI_4));
        let pb = ShapePose::new(DVec3::ZERO, DMat3::from_rotation_x(core::f64::consts::FRAC_PI_4));
        let h = hits(&cuboid(1.0, 1.0, 1.0), &pa, &cuboid(1.0, 1.0, 1.0), &pb);
        one(&h, v(0.0, s2 - 0.05, 0.0), DVec3::Y, 0.1);
    }

    #[test]
    fn identical_boxes_are_finite() {
        let b = cuboid(0.5, 0.2, 0.3);
        let p = ShapePose::new(v(1.0, 2.0, 3.0), DMat3::from_rotation_y(0.3));
        let h = hits(&b, &p, &b, &p);
        assert!(!h.is_empty());
        for x in &h {
            assert!(x.point_m.is_finite() && x.depth_m > 0.0);
            close(x.normal.length(), 1.0);
            close(x.depth_m, 0.4); // smallest full overlap: 2 * 0.2 along the box's y
        }
    }

    // ---- plane ----

    #[test]
    fn plane_sphere_and_capsule() {
        let g = ShapePose::IDENTITY;
        let h = hits(&sphere(0.5), &at(1.0, 0.4, 2.0), &Shape::Plane, &g);
        one(&h, v(1.0, -0.05, 2.0), DVec3::Y, 0.1);
        // Below the surface entirely: depth r + distance below.
        let h = hits(&sphere(0.5), &at(0.0, -1.0, 0.0), &Shape::Plane, &g);
        one(&h, v(0.0, -0.75, 0.0), DVec3::Y, 1.5);
        // Capsule lying on the ground: both ends.
        let h = hits(&capsule(1.0, 0.3), &along_x(0.0, 0.25, 0.5), &Shape::Plane, &g);
        set(&h, DVec3::Y, &[(v(-1.0, -0.025, 0.5), 0.05), (v(1.0, -0.025, 0.5), 0.05)]);
        // Standing: only the lower end.
        let h = hits(&capsule(1.0, 0.3), &at(0.0, 1.25, 0.0), &Shape::Plane, &g);
        one(&h, v(0.0, -0.025, 0.0), DVec3::Y, 0.05);
        // Plane first: normal from the shape toward the plane.
        let h = hits(&Shape::Plane, &g, &sphere(0.5), &at(1.0, 0.4, 2.0));
        one(&h, v(1.0, -0.05, 2.0), -DVec3::Y, 0.1);
        // Tilted plane through (0, 1, 0) with normal (1, 1, 0)/sqrt 2.
        let n = v(1.0, 1.0, 0.0).normalize();
        let tilted = ShapePose::new(v(0.0, 1.0, 0.0), DMat3::from_rotation_z(-core::f64::consts::FRAC_PI_4));
        let c = v(0.0, 1.0, 0.0) + n * 0.4;
        let h = hits(&sphere(0.5), &ShapePose::at(c), &Shape::Plane, &tilted);
        one(&h, c - n * 0.45, n, 0.1);
        assert!(hits(&sphere(0.5), &at(0.0, 0.5, 0.0), &Shape::Plane, &g).is_empty());
    }

    #[test]
    fn box_resting_on_plane_gives_its_four_bottom_corners() {
        let h = hits(&cuboid(0.5, 0.25, 0.3), &at(2.0, 0.24, -1.0), &Shape::Plane, &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (v(2.0 + x, -0.005, -1.0 + z), 0.01);
        set(&h, DVec3::Y, &[c(-0.5, -0.3), c(-0.5, 0.3), c(0.5, -0.3), c(0.5, 0.3)]);
        // Rotated about the vertical: still four, at the rotated corners.
        let r = DMat3::from_rotation_y(0.7);
        let pa = ShapePose::new(v(0.0, 0.24, 0.0), r);
        let h = hits(&cuboid(0.5, 0.25, 0.3), &pa, &Shape::Plane, &ShapePose::IDENTITY);
        let c = |x: f64, z: f64| (r * v(x, 0.0, z) + v(0.0, -0.005, 0.0), 0.01);
        set(&h, DVec3::Y, &[c(-0.5, -0.3), c(-0.5, 0.3), c(0.5, -0.3), c(0.5, 0.3)]);
        // Fully sunk: all eight vertices.
        assert_eq!(
            hits(&cuboid(0.5, 0.25, 0.3), &at(0.0, -2.0, 0.0), &Shape::Plane, &ShapePose::IDENTITY).len(),
            8
        );
        // Balanced on one edge (45 degrees about z): two hits.
        let pa = ShapePose::new(
            v(0.0, 0.5 * 2f64.sqrt() - 0.01, 0.0),
            DMat3::from_rotation_z(core::f64::consts::FRAC_PI_4),
        );
        assert_eq!(hits(&cuboid(0.5, 0.5, 0.5), &pa, &Shape::Plane, &ShapePose::IDENTITY).len(), 2);
        // A flat (zero-height) box: four distinct corners, not eight.
        assert_eq!(
            hits(&cuboid(0.5, 0.0, 0.3), &at(0.0, -0.1, 0.0), &Shape::Plane, &ShapePose::IDENTITY).len(),
            4
        );
    }

    #[test]
    fn plane_plane_is_empty() {
        assert!(hits(&Shape::Plane, &ShapePose::IDENTITY, &Shape::Plane, &at(0.0, 1.0, 0.0)).is_empty());
    }

    #[test]
    fn bounding_radii() {
        assert_eq!(bounding_radius(&sphere(0.5)), 0.5);
        assert_eq!(bounding_radius(&capsule(1.0, 0.5)), 1.5);
        close(bounding_radius(&cuboid(1.0, 2.0, 2.0)), 3.0);
        assert_eq!(bounding_radius(&Shape::Plane), f64::INFINITY);
        assert_eq!(bounding_radius(&sphere(-1.0)), 0.0);
        assert_eq!(bounding_radius(&sphere(f64::NAN)), 0.0);
    }

    #[test]
    fn out_of_contract_nan_pose_gives_no_hits() {
        let p = at(f64::NAN, 0.0, 0.0);
        for s in [sphere(1.0), capsule(1.0, 1.0), cuboid(1.0, 1.0, 1.0), Shape::Plane] {
            for t in [sphere(1.0), capsule(1.0, 1.0), cuboid(1.0, 1.0, 1.0), Shape::Plane] {
                assert!(hits(&s, &p, &t, &ShapePose::IDENTITY).is_empty());
            }
        }
    }

    // ---- properties ----

    fn any_rot() -> impl Strategy<Value = DMat3> {
        (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64).prop_map(|(x, y, z, w)| {
            let q = DQuat::from_xyzw(x, y, z, w);
            if q.length() < 1e-3 {
                DMat3::IDENTITY
            } else {
                DMat3::from_quat(q.normalize())
            }
        })
    }

    fn any_pose() -> impl Strategy<Value = ShapePose> {
        (-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64, any_rot())
            .prop_map(|(x, y, z, r)| ShapePose::new(v(x, y, z), r))
    }

    fn solid() -> impl Strategy<Value = Shape> {
        prop_oneof![
            (0.05..1.5f64).prop_map(sphere),
            (0.0..1.5f64, 0.05..1.0f64).prop_map(|(h, r)| capsule(h, r)),
            (0.05..1.5f64, 0.05..1.5f64, 0.05..1.5f64).prop_map(|(x, y, z)| cuboid(x, y, z)),
        ]
    }

    fn any_shape() -> impl Strategy<Value = Shape> {
        prop_oneof![4 => solid(), 1 => Just(Shape::Plane)]
    }

    fn degenerate_len() -> impl Strategy<Value = f64> {
        prop_oneof![Just(0.0), Just(1e-300), Just(1e-13), Just(-0.5), Just(f64::NAN), Just(1.0), 0.0..2.0f64,]
    }

    fn degenerate_shape() -> impl Strategy<Value = Shape> {
        prop_oneof![
            degenerate_len().prop_map(sphere),
            (degenerate_len(), degenerate_len()).prop_map(|(h, r)| capsule(h, r)),
            (degenerate_len(), degenerate_len(), degenerate_len()).prop_map(|(x, y, z)| cuboid(x, y, z)),
            Just(Shape::Plane),
        ]
    }

    fn degenerate_pose() -> impl Strategy<Value = ShapePose> {
        let coord = prop_oneof![Just(0.0), Just(0.5), Just(1.0), -2.0..2.0f64];
        let rot = prop_oneof![
            Just(DMat3::IDENTITY),
            Just(DMat3::from_rotation_z(core::f64::consts::FRAC_PI_2)),
            Just(DMat3::from_rotation_x(core::f64::consts::FRAC_PI_2)),
            any_rot(),
        ];
        (coord.clone(), coord.clone(), coord, rot).prop_map(|(x, y, z, r)| ShapePose::new(v(x, y, z), r))
    }

    fn deepest(h: &[Hit]) -> Hit {
        *h.iter().max_by(|a, b| a.depth_m.total_cmp(&b.depth_m)).unwrap()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        #[test]
        fn swapping_the_shapes_negates_the_normals(a in any_shape(), pa in any_pose(), b in any_shape(), pb in any_pose()) {
            let ab = hits(&a, &pa, &b, &pb);
            let ba = hits(&b, &pb, &a, &pa);
            prop_assert_eq!(ab.len(), ba.len());
            for (x, y) in ab.iter().zip(ba.iter()) {
                prop_assert!((x.point_m - y.point_m).length() < 1e-12);
                prop_assert!((x.normal + y.normal).length() < 1e-12);
                prop_assert!((x.depth_m - y.depth_m).abs() < 1e-12);
            }
        }

        #[test]
        fn degenerate_input_gives_finite_hits_with_unit_normals(
            a in degenerate_shape(), pa in degenerate_pose(), b in degenerate_shape(), pb in degenerate_pose()
        ) {
            for (s, ps, t, pt) in [(a, pa, b, pb), (b, pb, a, pa), (a, pa, a, pa)] {
                for x in hits(&s, &ps, &t, &pt) {
                    prop_assert!(x.point_m.is_finite() && x.normal.is_finite() && x.depth_m.is_finite(), "{:?}", x);
                    prop_assert!(x.depth_m > 0.0);
                    prop_assert!((x.normal.length() - 1.0).abs() < 1e-9, "{:?}", x);
                }
            }
        }

        #[test]
        fn shapes_beyond_their_bounding_spheres_do_not_touch(
            a in solid(), pa in any_pose(), b in solid(), rb in any_rot(),
            dir in (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64), margin in 1e-6..1.0f64
        ) {
            let dir = DVec3::from(dir).try_normalize().unwrap_or(DVec3::X);
            let gap = bounding_radius(&a) + bounding_radius(&b) + margin;
            let pb = ShapePose::new(pa.pos_m + dir * gap, rb);
            prop_assert!(hits(&a, &pa, &b, &pb).is_empty());
            prop_assert!(hits(&b, &pb, &a, &pa).is_empty());
        }

        /// For every pair but box-box the deepest hit is the exact penetration along its normal:
        /// moving `a` out by a hair more separates the shapes, a little less does not.
        #[test]
        fn the_deepest_hit_is_the_separating_translation(a in solid(), pa in any_pose(), b in any_shape(), pb in any_pose()) {
            if matches!((a, b), (Shape::Box { .. }, Shape::Box { .. })) {
                return Ok(());
            }
            // Pull b halfway toward a so that most cases touch.
            let pb = ShapePose::new((pa.pos_m + pb.pos_m) * 0.5, pb.rot);
            let h = hits(&a, &pa, &b, &pb);
            if h.is_empty() {
                return Ok(());
            }
            let top = deepest(&h);
            let out = ShapePose::new(pa.pos_m + top.normal * (top.depth_m + 1e-7), pa.rot);
            let after = hits(&a, &out, &b, &pb);
            prop_assert!(after.iter().all(|x| x.depth_m < 1e-9), "{:?} then {:?}", top, after);
            if top.depth_m > 1e-5 {
                // Capsule-box prefers a face axis to an edge axis less than 5% better (see
                // EDGE_AXIS_REL), so its depth may be up to 5% long; everything else is exact.
                let capsule_box = matches!((a, b), (Shape::Capsule { .. }, Shape::Box { .. }) | (Shape::Box { .. }, Shape::Capsule { .. }));
                let f = if capsule_box { 0.94 } else { 0.99 };
                let part = ShapePose::new(pa.pos_m + top.normal * (top.depth_m * f), pa.rot);
                let still = hits(&a, &part, &b, &pb);
                prop_assert!(!still.is_empty(), "{:?}", top);
                prop_assert!(deepest(&still).depth_m <= (1.0 - f) * top.depth_m + 1e-9, "{:?} then {:?}", top, still);
            }
        }

        /// Box-box: moving `a` out along the normal by the reported depth leaves at most the
        /// depth missed by the manifold, never more overlap than before, and a full SAT push separates.
        #[test]
        fn box_box_normal_separates(
            ha in (0.05..1.5f64, 0.05..1.5f64, 0.05..1.5f64), pa in any_pose(),
            hb in (0.05..1.5f64, 0.05..1.5f64, 0.05..1.5f64), pb in any_pose()
        ) {
            let (a, b) = (cuboid(ha.0, ha.1, ha.2), cuboid(hb.0, hb.1, hb.2));
            let pb = ShapePose::new((pa.pos_m + pb.pos_m) * 0.5, pb.rot);
            let h = hits(&a, &pa, &b, &pb);
            if h.is_empty() {
                return Ok(());
            }
            let top = deepest(&h);
            for x in &h {
                prop_assert!((x.normal - top.normal).length() < 1e-12);
            }
            // All hits share the minimum-overlap axis; its overlap bounds every depth.
            let sep = bounding_radius(&a) + bounding_radius(&b);
            let mut lo = top.depth_m;
            let mut hi = 2.0 * sep;
            // Bisect for the translation along the normal that just separates: it must be >= depth.
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                let p = ShapePose::new(pa.pos_m + top.normal * mid, pa.rot);
                if hits(&a, &p, &b, &pb).is_empty() { hi = mid } else { lo = mid }
            }
            prop_assert!(hi >= top.depth_m - 1e-9);
        }

        /// Capsule-capsule against brute force: the deepest hit matches the sampled core distance.
        #[test]
        fn capsule_capsule_matches_brute_force(
            ha in 0.0..1.5f64, ra in 0.05..1.0f64, pa in any_pose(),
            hb in 0.0..1.5f64, rb in 0.05..1.0f64, pb in any_pose()
        ) {
            let (ua, ub) = (pa.rot.y_axis, pb.rot.y_axis);
            let mut best = f64::INFINITY;
            let n = 400;
            for i in 0..=n {
                let p = pa.pos_m + ua * (ha * (2.0 * i as f64 / n as f64 - 1.0));
                let q = closest_on_segment(pb.pos_m, ub, hb, p);
                best = best.min((p - q).length());
            }
            let h = hits(&capsule(ha, ra), &pa, &capsule(hb, rb), &pb);
            let expect = ra + rb - best;
            if expect > 1e-3 {
                prop_assert!(!h.is_empty());
                let d = deepest(&h).depth_m;
                // Sampling overestimates the distance by at most (step/2)^2-ish; allow the step.
                prop_assert!(d >= expect - 1e-9 && d <= expect + 2.0 * ha / n as f64 + 1e-9, "{} vs {}", d, expect);
            } else if expect < -1e-3 {
                prop_assert!(h.is_empty());
            }
        }
    }
}
