//! What a rig can do where (`spidar rig map`): per hand, over a grid of its frame, the largest
//! force the strings can render in every direction (the capacity margin) against the hand's
//! force limit; the volume where the limit is met; where the home lies in it; and where strings
//! come close to the other hand's strings or to the user's forearm.
//!
//! Why it exists: the loop clamps every force to `force_limit_n` and counts, after the fact, the
//! ticks it could not render. An operator setting up or changing a rig needs to know beforehand
//! where in the frame each hand can be pushed with the full limit, and where a string runs through
//! the user's arm.
//!
//! Method: the exact capacity margin of each hand's four-string force zonotope, and segment
//! distances between strings and to the forearm capsule, both from `spidar_msg::strings` (shared
//! with the live view, which must not depend on this crate); see that module for the maths.
//!
//! Interference: strings are segments from the grip to their anchors. The two hands' strings
//! are checked against each other (one hand moved over its reach, the other at home); each
//! hand's strings against a forearm capsule from the wrist toward the elbow ([`Forearm`]).
//!
//! Must never: disagree with the allocator about what can be rendered (tested at random points),
//! or be called in the 1 kHz tick (it allocates).

use glam::DVec3;
use spidar_rt::rig::HandRig;
use spidar_rt::Rig;

pub use spidar_msg::strings::{capacity, renders, segment_distance, Capacity, Forearm, Grid};

/// What to map, and how finely.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapOptions {
    /// Grid spacing, m.
    pub step_m: f64,
    /// Radius around each home that counts as the hand's reach (interference is checked there,
    /// and the limit's coverage is given for it too), m.
    pub reach_m: f64,
    pub forearm: Forearm,
    /// Strings closer than this to each other count as touching (two strings' own thickness and
    /// a margin), m.
    pub string_clearance_m: f64,
}

impl Default for MapOptions {
    fn default() -> MapOptions {
        MapOptions { step_m: 0.05, reach_m: 0.4, forearm: Forearm::default(), string_clearance_m: 0.01 }
    }
}

/// A place where a string comes too close: the grip position that does it, the string, the
/// distance and the point on the string.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Touch {
    pub grip_m: DVec3,
    pub string: usize,
    /// Clearance left (negative: into the forearm, or closer than the clearance), m.
    pub clearance_m: f64,
    pub at_m: DVec3,
}

/// Interference of one hand's strings over its reach.
#[derive(Clone, Debug, PartialEq)]
pub struct Interference {
    /// Grid positions checked (within reach of the home).
    pub positions: usize,
    /// Per string: the smallest clearance over the reach, m (forearm: surface distance; strings:
    /// distance less the clearance).
    pub min_clearance_m: [f64; 4],
    /// Positions where some string touches, and the tightest example per string (if any).
    pub touching_positions: usize,
    pub worst: [Option<Touch>; 4],
    /// Clearance of each string at the home position, m.
    pub at_home_m: [f64; 4],
}

/// The map of one hand.
#[derive(Clone, Debug, PartialEq)]
pub struct HandMap {
    pub hand: usize,
    pub label: String,
    pub force_limit_n: f64,
    pub tension_n: (f64, f64),
    pub anchors_m: [DVec3; 4],
    pub home_m: DVec3,
    pub grid: Grid,
    /// Capacity margin per grid cell, N (`grid.index` order).
    pub margin_n: Vec<f64>,
    /// Volume of the anchor tetrahedron (the frame), m^3.
    pub frame_volume_m3: f64,
    /// Volume where zero net force is possible (wrench-closure), m^3.
    pub closure_volume_m3: f64,
    /// Volume where the force limit can be rendered in every direction (wrench-feasible), m^3.
    pub feasible_volume_m3: f64,
    /// Volume of the reach ball around home, and the part of it where the limit is met, m^3.
    pub reach_volume_m3: f64,
    pub reach_feasible_m3: f64,
    /// The capacity at home.
    pub home: Capacity,
    pub forearm: Interference,
    /// This hand's strings against the other hand's (at its home), over this hand's reach.
    pub strings: Interference,
}

impl HandMap {
    /// Share of the frame (the anchor tetrahedron) where the limit is met.
    pub fn frame_fraction(&self) -> f64 {
        if self.frame_volume_m3 > 0.0 {
            self.feasible_volume_m3 / self.frame_volume_m3
        } else {
            0.0
        }
    }

    /// Share of the reach ball where the limit is met.
    pub fn reach_fraction(&self) -> f64 {
        if self.reach_volume_m3 > 0.0 {
            self.reach_feasible_m3 / self.reach_volume_m3
        } else {
            0.0
        }
    }

    /// The margin at the grid cell nearest `p` (None outside the grid).
    pub fn margin_near(&self, p: DVec3) -> Option<f64> {
        let g = &self.grid;
        let f = (p - g.origin_m) / g.step_m;
        let idx = |v: f64, n: usize| {
            let r = v.round();
            (r >= 0.0 && (r as usize) < n).then_some(r as usize)
        };
        Some(self.margin_n[g.index(idx(f.x, g.n[0])?, idx(f.y, g.n[1])?, idx(f.z, g.n[2])?)])
    }
}

/// A place a hand is asked to push at: a home, or a scene's contact (the point of a wall, ball or
/// the virtual human's head nearest the hand's home), rig frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Site {
    /// What it is (`home`, `walls: front wall`, `boxing: boxer/head`).
    pub label: String,
    pub hand: usize,
    pub point_m: DVec3,
}

/// A site and the capacity there, computed exactly (not read off the grid).
#[derive(Clone, Debug, PartialEq)]
pub struct SiteMargin {
    pub site: Site,
    pub capacity: Capacity,
    /// The force limit can be rendered there in every direction.
    pub limit_met: bool,
}

/// The map of a rig: both hands.
#[derive(Clone, Debug, PartialEq)]
pub struct RigMap {
    pub hands: Vec<HandMap>,
    pub options: MapOptions,
    /// The homes and the scenes' contacts given to [`RigMap::with_sites`], with their margins.
    pub sites: Vec<SiteMargin>,
}

impl RigMap {
    /// Adds each hand's home and `sites` (rig frame) with the capacity margin at each.
    pub fn with_sites(mut self, sites: &[Site]) -> RigMap {
        let homes = self.hands.iter().map(|h| Site { label: "home".into(), hand: h.hand, point_m: h.home_m });
        let all: Vec<Site> = homes.chain(sites.iter().cloned()).collect();
        self.sites = all
            .into_iter()
            .filter_map(|site| {
                let h = self.hands.get(site.hand)?;
                let capacity = capacity(&h.anchors_m, site.point_m, h.tension_n.0, h.tension_n.1);
                Some(SiteMargin { limit_met: capacity.margin_n >= h.force_limit_n, capacity, site })
            })
            .collect();
        self
    }
}

/// Maps every hand of `rig`.
pub fn map_rig(rig: &Rig, options: &MapOptions) -> RigMap {
    let hands = (0..rig.hands.len()).map(|h| map_hand(rig, h, options)).collect();
    RigMap { hands, options: *options, sites: Vec::new() }
}

fn map_hand(rig: &Rig, h: usize, o: &MapOptions) -> HandMap {
    let hr = &rig.hands[h];
    let a = hr.anchors_m;
    let lo = a.iter().fold(DVec3::splat(f64::INFINITY), |m, p| m.min(*p));
    let hi = a.iter().fold(DVec3::splat(f64::NEG_INFINITY), |m, p| m.max(*p));
    let grid = Grid::covering(lo, hi, o.step_m);
    let (min_n, max_n) = (hr.tension_min_n, hr.tension_max_n);
    let mut margin_n = vec![0.0; grid.len()];
    let (mut closure, mut feasible, mut reach, mut reach_ok) = (0usize, 0usize, 0usize, 0usize);
    for (idx, p) in grid.points() {
        let m = capacity(&a, p, min_n, max_n).margin_n;
        margin_n[idx] = m;
        closure += (m >= 0.0) as usize;
        feasible += (m >= hr.force_limit_n) as usize;
        if (p - hr.home_m).length() <= o.reach_m {
            reach += 1;
            reach_ok += (m >= hr.force_limit_n) as usize;
        }
    }
    let cell = grid.cell_volume_m3();
    let frame_volume_m3 = ((a[1] - a[0]).cross(a[2] - a[0]).dot(a[3] - a[0]) / 6.0).abs();
    let other = &rig.hands[1 - h];
    HandMap {
        hand: h,
        label: hr.label.clone(),
        force_limit_n: hr.force_limit_n,
        tension_n: (min_n, max_n),
        anchors_m: a,
        home_m: hr.home_m,
        grid,
        margin_n,
        frame_volume_m3,
        closure_volume_m3: closure as f64 * cell,
        feasible_volume_m3: feasible as f64 * cell,
        reach_volume_m3: reach as f64 * cell,
        reach_feasible_m3: reach_ok as f64 * cell,
        home: capacity(&a, hr.home_m, min_n, max_n),
        forearm: interference(hr, o, |p, s| forearm_clearance(hr, h, &o.forearm, p, s)),
        strings: interference(hr, o, |p, s| strings_clearance(hr, other, p, s, o.string_clearance_m)),
    }
}

/// Clearance of string `s` of a grip at `p` from the forearm capsule, and the closest point.
fn forearm_clearance(hr: &HandRig, hand: usize, f: &Forearm, p: DVec3, s: usize) -> (f64, DVec3) {
    let (w, e) = f.axis(hand, p);
    let (d, at) = segment_distance(p, hr.anchors_m[s], w, e);
    (d - f.radius_m, at)
}

/// Clearance of string `s` of a grip at `p` from the other hand's strings (grip at its home).
fn strings_clearance(hr: &HandRig, other: &HandRig, p: DVec3, s: usize, clearance_m: f64) -> (f64, DVec3) {
    let mut best = (f64::INFINITY, p);
    for &b in &other.anchors_m {
        let (d, at) = segment_distance(p, hr.anchors_m[s], other.home_m, b);
        if d - clearance_m < best.0 {
            best = (d - clearance_m, at);
        }
    }
    best
}

/// Runs `clearance(p, string)` over the grid cells within reach of the hand's home (and at home).
fn interference(
    hr: &HandRig,
    o: &MapOptions,
    clearance: impl Fn(DVec3, usize) -> (f64, DVec3),
) -> Interference {
    let r = o.reach_m;
    let grid = Grid::covering(hr.home_m - DVec3::splat(r), hr.home_m + DVec3::splat(r), o.step_m);
    let mut out = Interference {
        positions: 0,
        min_clearance_m: [f64::INFINITY; 4],
        touching_positions: 0,
        worst: [None; 4],
        at_home_m: std::array::from_fn(|s| clearance(hr.home_m, s).0),
    };
    for (_, p) in grid.points().filter(|(_, p)| (*p - hr.home_m).length() <= r) {
        out.positions += 1;
        let mut touching = false;
        for s in 0..4 {
            let (c, at) = clearance(p, s);
            touching |= c <= 0.0;
            if c < out.min_clearance_m[s] {
                out.min_clearance_m[s] = c;
                if c <= 0.0 {
                    out.worst[s] = Some(Touch { grip_m: p, string: s, clearance_m: c, at_m: at });
                }
            }
        }
        out.touching_positions += touching as usize;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use spidar_rt::tension::{Allocator, Method, TensionLimits};

    /// Springhead's desktop preset: anchors on alternate corners of a cube (a regular tetrahedron).
    fn cube(h: f64) -> [DVec3; 4] {
        [DVec3::new(h, h, h), DVec3::new(-h, h, -h), DVec3::new(h, -h, -h), DVec3::new(-h, -h, h)]
    }

    #[test]
    fn the_capacity_at_the_centre_of_a_regular_frame_is_the_closed_form() {
        // At the centre of a regular tetrahedron the strings point to its corners: sum u = 0, so
        // the forces are centred on zero. The unit normal n of u0 x u1 is perpendicular to u0 and
        // u1, and |n . u2| = |n . u3| = sqrt(2/3) (e.g. n = (-1, 0, 1) / sqrt 2 for the cube's
        // corners). Every face is (max - min) / 2 x 2 sqrt(2/3) from zero: the capacity is
        // (max - min) sqrt(2/3).
        let (min, max) = (0.5, 20.0);
        let want = (max - min) * (2.0_f64 / 3.0).sqrt();
        let c = capacity(&cube(0.265), DVec3::ZERO, min, max);
        assert!((c.margin_n / want - 1.0).abs() < 0.01, "{} vs {want}", c.margin_n);
        // The map over a grid whose cell centre is the frame's centre says the same.
        let mut rig = Rig::default_rig();
        rig.hands[0].anchors_m = cube(0.265);
        rig.hands[0].home_m = DVec3::ZERO;
        rig.hands[0].tension_min_n = min;
        rig.hands[0].tension_max_n = max;
        // 11 cells across the cube: the middle one's centre is the frame's centre.
        let m = map_hand(&rig, 0, &MapOptions { step_m: 0.53 / 11.0, reach_m: 0.1, ..MapOptions::default() });
        let at_centre = m.margin_near(DVec3::ZERO).unwrap();
        assert!((at_centre / want - 1.0).abs() < 0.01, "{at_centre} vs {want}");
        assert!((m.home.margin_n / want - 1.0).abs() < 0.01);
        // And the allocator, asked a force far beyond reach in 3,200 directions, renders no less
        // than that in any and just that in the weakest.
        let u = cube(0.265).map(|a| a.normalize());
        let mut least = f64::INFINITY;
        for i in 0..40 {
            for j in 0..80 {
                let th = std::f64::consts::PI * (i as f64 + 0.5) / 40.0;
                let ph = std::f64::consts::TAU * j as f64 / 80.0;
                let d = DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
                let al = Allocator::new(TensionLimits { min_n: min, max_n: max }).allocate(&u, d * 500.0);
                least = least.min(al.force_n.length());
            }
        }
        assert!(least >= want * (1.0 - 1e-9) && least < want * 1.01, "{least} vs {want}");
    }

    #[test]
    fn the_maps_feasibility_agrees_with_the_allocator_at_1000_random_points() {
        let rig = Rig::default_rig();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(27);
        let (mut limit_met, mut closure_only, mut outside, mut exact) = (0, 0, 0, 0);
        for k in 0..1000 {
            let hr = &rig.hands[k % 2];
            let (min_n, max_n, limit) = (hr.tension_min_n, hr.tension_max_n, hr.force_limit_n);
            // Points over the whole frame and beyond (below it the hand is outside).
            let p = DVec3::new(
                rng.random_range(-1.8..1.8),
                rng.random_range(-1.2..2.2),
                rng.random_range(-1.5..1.2),
            );
            let u = hr.anchors_m.map(|a| (a - p).normalize());
            let mut al = Allocator::new(TensionLimits { min_n, max_n });
            let c = capacity(&hr.anchors_m, p, min_n, max_n);
            // Zero force: possible iff the margin is not negative (else the allocator's fallback).
            if c.margin_n.abs() > 1e-6 {
                assert_eq!(al.allocate(&u, DVec3::ZERO).method != Method::Fallback, c.margin_n > 0.0, "{p}");
            }
            // The limit along the weakest direction: exact iff the map says the limit is met.
            if (c.margin_n - limit).abs() > 1e-6 {
                let met = al.allocate(&u, c.weakest * limit).method == Method::Exact;
                assert_eq!(met, c.margin_n > limit, "{p}: margin {}", c.margin_n);
            }
            // And any force: the map's membership is the allocator's Exact (off the boundary).
            for _ in 0..5 {
                let f = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ) * rng.random_range(0.0..30.0);
                let yes = renders(&hr.anchors_m, p, min_n, max_n, f);
                let near = renders(&hr.anchors_m, p, min_n, max_n, f * 1.000_001)
                    != renders(&hr.anchors_m, p, min_n, max_n, f * 0.999_999);
                if !near {
                    assert_eq!(al.allocate(&u, f).method == Method::Exact, yes, "{p} {f}");
                    exact += yes as usize;
                }
            }
            match c.margin_n {
                m if m >= limit => limit_met += 1,
                m if m >= 0.0 => closure_only += 1,
                _ => outside += 1,
            }
        }
        // The sample covers every case.
        assert!(
            limit_met > 50 && closure_only > 50 && outside > 50 && exact > 500,
            "{limit_met} {closure_only} {outside} {exact}"
        );
    }

    #[test]
    fn two_strings_crossing_at_a_known_point_are_found_there() {
        // The left hand's string 0 runs along x through (0, 0, 0); the right hand's string 0
        // along z through (0, 0.03, 0): 3 cm apart at the crossing, at (0, 0, 0) on the first.
        let (d, at) = segment_distance(
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 0.03, -1.0),
            DVec3::new(0.0, 0.03, 1.0),
        );
        assert!((d - 0.03).abs() < 1e-12 && at.length() < 1e-12, "{d} {at}");
        // A rig built so: hand 0's grip at (-0.5, 0, 0) with an anchor at (0.5, 0, 0); hand 1 at home
        // (0, 0.005, -0.5) with an anchor at (0, 0.005, 0.5). The strings cross 5 mm apart, within a
        // 1 cm clearance: a touch at the crossing.
        let mut rig = Rig::default_rig();
        rig.hands[0].home_m = DVec3::new(-0.5, 0.0, 0.0);
        rig.hands[0].anchors_m[0] = DVec3::new(0.5, 0.0, 0.0);
        rig.hands[1].home_m = DVec3::new(0.0, 0.005, -0.5);
        rig.hands[1].anchors_m[0] = DVec3::new(0.0, 0.005, 0.5);
        let (c, at) = strings_clearance(&rig.hands[0], &rig.hands[1], rig.hands[0].home_m, 0, 0.01);
        assert!((c - (0.005 - 0.01)).abs() < 1e-12, "{c}");
        assert!((at - DVec3::ZERO).length() < 1e-9, "{at}");
        let o = MapOptions { step_m: 0.05, reach_m: 0.1, ..MapOptions::default() };
        let m = map_hand(&rig, 0, &o);
        assert!((m.strings.at_home_m[0] + 0.005).abs() < 1e-12);
        // Over the reach (grid cells around home, not home itself) the string still touches, near
        // the crossing.
        let worst = m.strings.worst[0].expect("the crossing touches");
        assert!(worst.clearance_m <= 0.0 && worst.at_m.length() < 0.1, "{worst:?}");
        assert!(m.strings.min_clearance_m[0] == worst.clearance_m);
        assert!(m.strings.touching_positions > 0);
    }

    #[test]
    fn a_string_along_the_forearm_touches_it_and_one_away_from_it_does_not() {
        let mut rig = Rig::default_rig();
        let f = Forearm::default();
        let home = rig.hands[0].home_m;
        let (w, e) = f.axis(0, home);
        // String 2 runs out along the forearm's axis, string 0 straight up.
        rig.hands[0].anchors_m[2] = home + (e - w).normalize() * 2.0;
        rig.hands[0].anchors_m[0] = home + DVec3::Y * 2.0;
        let hr = &rig.hands[0];
        let (c2, _) = forearm_clearance(hr, 0, &f, home, 2);
        assert!((c2 + f.radius_m).abs() < 1e-9, "{c2}");
        let (c0, _) = forearm_clearance(hr, 0, &f, home, 0);
        assert!(c0 > 0.0, "{c0}");
    }
}
