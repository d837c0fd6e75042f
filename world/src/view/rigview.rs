//! What the view shows of the rig beyond its strings: each hand's force-feasible workspace (the
//! cells where the force limit can be rendered in every direction, computed once per rig
//! geometry) and which strings come within a distance of the other hand's strings or of a
//! forearm (per frame, from the hands shown).
//!
//! Both are `spidar rig map`'s computations (`spidar_msg::strings`, which the map uses too): the
//! exact capacity margin of the four-string zonotope, the same answer the loop's tension allocator
//! gives, and the segment distances, with the near distance and forearm capsule the rig sends
//! (its rig file's `near_strings`). Computed on the view's broadcasting thread, never the world's
//! stepping thread or the rig's 1 kHz tick.
//!
//! Must never: draw a cell as feasible where the map says the limit is not met, or leave a near
//! string unmarked in a frame whose hands put it near.

use glam::DVec3;
use spidar_msg::strings::{capacity, segment_distance, Forearm, Grid};
use spidar_msg::{RigInfo, HANDS, STRINGS};

pub use spidar_msg::strings::DEFAULT_NEAR_M;

use super::frame::{GLOBALS_AT, HANDS_AT, HAND_FLOATS};

/// Spacing of the workspace cells sent to the page, m (8 cm: a few thousand cells per hand).
pub const WORKSPACE_STEP_M: f64 = 0.08;
/// Bit of string `s` of hand `h` in the frame header's flags (word 3): near another hand's string.
pub const fn near_string_bit(h: usize, s: usize) -> u32 {
    1 << (h * STRINGS + s)
}
/// Bit of string `s` of hand `h` in the flags: near a forearm.
pub const fn near_forearm_bit(h: usize, s: usize) -> u32 {
    1 << (8 + h * STRINGS + s)
}

/// One hand's feasible cells: a grid over its anchors' box and the indices (x fastest) of the
/// cells whose capacity margin reaches the force limit.
#[derive(Clone, Debug, PartialEq)]
pub struct Workspace {
    pub grid: Grid,
    pub cells: Vec<u32>,
}

/// The feasible workspace of hand `h` of `info` (the link's frame; the capacity is the same in
/// any frame the anchors and the grip share).
pub fn workspace(info: &RigInfo, h: usize, step_m: f64) -> Workspace {
    let a = info.anchors_m[h];
    let lo = a.iter().fold(DVec3::splat(f64::INFINITY), |m, p| m.min(*p));
    let hi = a.iter().fold(DVec3::splat(f64::NEG_INFINITY), |m, p| m.max(*p));
    let grid = Grid::covering(lo, hi, step_m);
    let (min_n, max_n, limit) = (info.tension_min_n[h], info.tension_max_n[h], info.force_limit_n[h]);
    let cells = grid
        .points()
        .filter(|(_, p)| capacity(&a, *p, min_n, max_n).margin_n >= limit)
        .map(|(i, _)| i as u32)
        .collect();
    Workspace { grid, cells }
}

/// Which strings are near (the flags' bits): each string of a shown hand against the other
/// hand's strings (a hand's own strings meet at its grip, so they are not compared) and against
/// the forearm capsule of every shown hand. `anchors` and `grips` in one frame.
pub fn near_mask(
    anchors: &[[DVec3; STRINGS]; HANDS],
    grips: [Option<DVec3>; HANDS],
    near_m: f64,
    forearm: &Forearm,
) -> u32 {
    let mut mask = 0;
    for h in 0..HANDS {
        let Some(g) = grips[h] else { continue };
        for s in 0..STRINGS {
            let a = anchors[h][s];
            let other = 1 - h;
            if let Some(go) = grips[other] {
                if anchors[other].iter().any(|b| segment_distance(g, a, go, *b).0 < near_m) {
                    mask |= near_string_bit(h, s);
                }
            }
            let arm_near = (0..HANDS)
                .filter_map(|f| grips[f].map(|p| forearm.axis(f, p)))
                .any(|(w, e)| segment_distance(g, a, w, e).0 - forearm.radius_m < near_m);
            if arm_near {
                mask |= near_forearm_bit(h, s);
            }
        }
    }
    mask
}

/// The rig as the broadcaster knows it, for marking the near strings of each frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearStrings {
    /// Anchors in the scene frame (the frames' hands are in it).
    pub anchors_m: [[DVec3; STRINGS]; HANDS],
    pub near_m: f64,
    pub forearm: Forearm,
}

impl NearStrings {
    /// With the near distance and forearm the rig sent (`info.clearance`).
    pub fn new(info: &RigInfo, offset: DVec3) -> NearStrings {
        NearStrings {
            anchors_m: info.anchors_m.map(|h| h.map(|a| a + offset)),
            near_m: info.clearance.distance_m,
            forearm: info.clearance.forearm,
        }
    }

    /// Sets the near strings' bits in the header of `frame` (its little-endian bytes), from the
    /// hands it shows.
    pub fn mark(&self, frame: &mut [u8]) {
        let word =
            |i: usize| frame.get(4 * i..4 * i + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        let float = |i: usize| word(i).map(f32::from_bits).unwrap_or(f32::NAN) as f64;
        let valid = float(GLOBALS_AT + 3);
        if !valid.is_finite() || frame.len() < 4 * (HANDS_AT + HANDS * HAND_FLOATS) {
            return;
        }
        let grips: [Option<DVec3>; HANDS] = std::array::from_fn(|h| {
            let o = HANDS_AT + h * HAND_FLOATS;
            ((valid as u32 >> h) & 1 == 1).then(|| DVec3::new(float(o), float(o + 1), float(o + 2)))
        });
        let mask = near_mask(&self.anchors_m, grips, self.near_m, &self.forearm);
        let flags = word(3).unwrap_or(0) & !0xffff | mask;
        frame[12..16].copy_from_slice(&flags.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped rig file's geometry as the rig sends it (world frame).
    fn info() -> RigInfo {
        spidar_rt::status::rig_info(&spidar_rt::Rig::default_rig())
    }

    #[test]
    fn two_crossing_strings_are_near_and_the_rest_are_not() {
        // Hand 0's grip at (-0.5, 0, 0), its string 0 along +x to (0.5, 0, 0); hand 1's grip at
        // (0, 0.005, -0.5), its string 0 along +z: they cross 5 mm apart. Every other anchor is far
        // off, away from both.
        let mut anchors = [[DVec3::new(-5.0, -5.0, -5.0); 4]; 2];
        anchors[0] = [
            DVec3::new(0.5, 0.0, 0.0),
            DVec3::new(-3.0, 3.0, 0.0),
            DVec3::new(-3.0, -3.0, 0.0),
            DVec3::new(-3.0, 0.0, 3.0),
        ];
        anchors[1] = [
            DVec3::new(0.0, 0.005, 0.5),
            DVec3::new(0.0, 3.0, -3.0),
            DVec3::new(0.0, -3.0, -3.0),
            DVec3::new(3.0, 0.0, -3.0),
        ];
        let grips = [Some(DVec3::new(-0.5, 0.0, 0.0)), Some(DVec3::new(0.0, 0.005, -0.5))];
        // No forearm in the way: a capsule of no length far behind.
        let arm = Forearm { toward_elbow: DVec3::Y, wrist_m: 10.0, elbow_m: 10.0, radius_m: 0.0 };
        let m = near_mask(&anchors, grips, 0.01, &arm);
        assert_eq!(m, near_string_bit(0, 0) | near_string_bit(1, 0), "{m:#x}");
        // 4 mm: the 5 mm crossing is no longer near.
        assert_eq!(near_mask(&anchors, grips, 0.004, &arm), 0);
        // A hand not shown has no strings to be near.
        assert_eq!(near_mask(&anchors, [grips[0], None], 0.01, &arm), 0);
        // A forearm along hand 0's string 1 marks that string, and only as near a forearm.
        let along = Forearm {
            toward_elbow: DVec3::new(-3.0, 3.0, 0.0) - grips[0].unwrap(),
            wrist_m: 0.1,
            elbow_m: 0.3,
            radius_m: 0.04,
        };
        let m = near_mask(&anchors, [grips[0], None], 0.01, &along);
        assert_eq!(m, near_forearm_bit(0, 1), "{m:#x}");
    }

    #[test]
    fn the_shipped_rigs_back_strings_cross_near_the_homes_and_part_when_the_hands_do() {
        // The shipped rig is nearly mirror-symmetric: with both grips at home each hand's back
        // strings (1 upper, 3 lower) cross the other hand's within a millimetre (the upper pair
        // 18 cm above the homes, `spidar rig map`).
        let info = info();
        let arm = Forearm::default();
        let (up, low) = (info.anchors_m[0][1], info.anchors_m[1][1]);
        let d = segment_distance(info.home_m[0], up, info.home_m[1], low).0;
        assert!(d < 0.001, "{d}");
        let home = info.home_m.map(Some);
        let back =
            near_string_bit(0, 1) | near_string_bit(0, 3) | near_string_bit(1, 1) | near_string_bit(1, 3);
        assert_eq!(near_mask(&info.anchors_m, home, DEFAULT_NEAR_M, &arm) & 0xff, back);
        // The right grip 10 cm further right, 10 cm up: the strings part, none is near.
        let apart = [home[0], Some(info.home_m[1] + DVec3::new(0.1, 0.1, 0.0))];
        let m = near_mask(&info.anchors_m, apart, DEFAULT_NEAR_M, &arm) & 0xff;
        assert_eq!(m, 0, "{m:#x}");
    }

    #[test]
    fn the_marked_frame_carries_the_mask_and_the_workspace_is_the_maps() {
        let info = info();
        let near = NearStrings::new(&info, DVec3::ZERO);
        let mut words = [0f32; HANDS_AT + HANDS * HAND_FLOATS];
        words[3] = f32::from_bits(1 << 20);
        words[GLOBALS_AT + 3] = 3.0;
        for h in 0..HANDS {
            let p = info.home_m[h];
            words[HANDS_AT + h * HAND_FLOATS..][..3].copy_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
        }
        let mut bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        near.mark(&mut bytes);
        let flags = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]);
        let back =
            near_string_bit(0, 1) | near_string_bit(0, 3) | near_string_bit(1, 1) | near_string_bit(1, 3);
        assert_eq!(flags & 0xff, back);
        assert_eq!(flags & (1 << 20), 1 << 20, "other flags are kept");
        // The near distance is the rig's (its file's `near_strings`): at 0 nothing is near.
        let mut touching_only = info;
        touching_only.clearance.distance_m = 0.0;
        NearStrings::new(&touching_only, DVec3::ZERO).mark(&mut bytes);
        assert_eq!(bytes[12] as u32, 0, "the back strings do not touch");
        // The workspace: the feasible cells are those where the map's exact margin meets the limit.
        let w = workspace(&info, 0, WORKSPACE_STEP_M);
        assert!(
            !w.cells.is_empty() && w.cells.len() < w.grid.len() / 2,
            "{} of {}",
            w.cells.len(),
            w.grid.len()
        );
        // Where the boxing scene's head target is (43 cm forward, 18 cm up of the rig origin: about
        // 10 N in every direction) the limit holds.
        let head = info.home_m[0] + DVec3::new(0.15, 0.18, -0.43);
        let head_cell =
            w.grid.points().min_by(|a, b| (a.1 - head).length().total_cmp(&(b.1 - head).length()));
        assert!(w.cells.contains(&(head_cell.unwrap().0 as u32)), "the head target's cell is feasible");
        for (i, p) in w.grid.points() {
            let (lo, hi, limit) = (info.tension_min_n[0], info.tension_max_n[0], info.force_limit_n[0]);
            let m = capacity(&info.anchors_m[0], p, lo, hi).margin_n;
            assert_eq!(w.cells.binary_search(&(i as u32)).is_ok(), m >= limit);
        }
    }
}
