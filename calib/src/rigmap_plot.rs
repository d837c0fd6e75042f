//! The rig map as a person reads it: the report text (`spidar rig map`), its headline (after a
//! calibration fit) and SVG slices of each hand's capacity margin.
//!
//! SVG through `plotters` without its font features (see `plot.rs`). What it must never do:
//! draw or print a figure the [`RigMap`] does not hold, or hide where the limit is not met.

use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;
use plotters::prelude::*;

use crate::rigmap::{map_rig, HandMap, Interference, MapOptions, RigMap};
use crate::CalibError;
use spidar_rt::Rig;

/// Colours of the margin classes: zero force impossible, below the limit, the limit up to twice
/// it, beyond.
const CLASS_COLOURS: [RGBColor; 4] =
    [RGBColor(190, 190, 190), RGBColor(244, 165, 130), RGBColor(166, 219, 160), RGBColor(27, 120, 55)];

/// Half-width of each slice drawn around the hand's home, m.
const SLICE_HALF_M: f64 = 1.0;

fn class_of(margin_n: f64, limit_n: f64) -> usize {
    if margin_n < 0.0 {
        0
    } else if margin_n < limit_n {
        1
    } else if margin_n < 2.0 * limit_n {
        2
    } else {
        3
    }
}

fn v3(p: DVec3) -> String {
    format!("({:.2}, {:.2}, {:.2})", p.x, p.y, p.z)
}

/// One line: how much of the frame and of the reach meets the limit, per hand (`spidar calib`
/// prints it after a fit, `spidar rig map` first).
pub fn headline(map: &RigMap) -> String {
    let per_hand: Vec<String> = map
        .hands
        .iter()
        .map(|h| {
            format!(
                "{} {:.0} % of its frame, {:.0} % of its reach, {:.1} N at home",
                h.label,
                h.frame_fraction() * 100.0,
                h.reach_fraction() * 100.0,
                h.home.margin_n
            )
        })
        .collect();
    let limit = map.hands.first().map_or(0.0, |h| h.force_limit_n);
    format!("force limit ({limit} N) renderable in every direction: {}", per_hand.join("; "))
}

/// What a fit did to the rig (`spidar calib fit`): the map's headline for the configured
/// anchors, then for `fitted` (per hand; None keeps the configured ones), on the default grid.
pub fn fit_change(rig: &Rig, fitted: &[Option<[DVec3; 4]>; 2]) -> String {
    let options = MapOptions::default();
    let before = map_rig(rig, &options);
    let mut after_rig = rig.clone();
    for (hr, f) in after_rig.hands.iter_mut().zip(fitted) {
        if let Some(a) = f {
            hr.anchors_m = *a;
        }
    }
    let after = map_rig(&after_rig, &options);
    format!(
        "rig map (spidar rig map), configured anchors: {}\nrig map, fitted anchors:                      {}",
        headline(&before),
        headline(&after)
    )
}

/// The full report of `spidar rig map`.
pub fn report(map: &RigMap, rig_name: &str) -> String {
    let o = &map.options;
    let mut s = format!("spidar rig map: {rig_name}\n");
    let _ = writeln!(
        s,
        "  grid         {:.0} mm over each hand's anchor box; reach = {:.2} m around its home",
        o.step_m * 1e3,
        o.reach_m
    );
    let _ = writeln!(s, "  headline     {}", headline(map));
    for h in &map.hands {
        hand_report(&mut s, h, map);
    }
    sites_report(&mut s, map);
    s
}

fn hand_report(s: &mut String, h: &HandMap, map: &RigMap) {
    let _ = writeln!(
        s,
        "  {:<12} tensions {} .. {} N, force limit {} N",
        h.label, h.tension_n.0, h.tension_n.1, h.force_limit_n
    );
    let _ = writeln!(
        s,
        "    frame      {:.2} m^3 (anchor tetrahedron); zero force possible in {:.2} m^3; limit met in {:.2} m^3 \
         ({:.0} %)",
        h.frame_volume_m3,
        h.closure_volume_m3,
        h.feasible_volume_m3,
        h.frame_fraction() * 100.0
    );
    let _ = writeln!(
        s,
        "    reach      limit met in {:.0} % of {:.3} m^3",
        h.reach_fraction() * 100.0,
        h.reach_volume_m3
    );
    let met = if h.home.margin_n >= h.force_limit_n { "met" } else { "NOT met" };
    let _ = writeln!(
        s,
        "    home       {}: {:.2} N in every direction, weakest along {} (limit {met})",
        v3(h.home_m),
        h.home.margin_n,
        v3(h.home.weakest)
    );
    let f = &map.options.forearm;
    let what = format!(
        "forearm (capsule {:.0} .. {:.0} mm from the grip, radius {:.0} mm)",
        f.wrist_m * 1e3,
        f.elbow_m * 1e3,
        f.radius_m * 1e3
    );
    interference_report(s, "forearm", &what, &h.forearm);
    let what = format!(
        "other hand's strings (its grip at home; clearance {:.0} mm)",
        map.options.string_clearance_m * 1e3
    );
    interference_report(s, "strings", &what, &h.strings);
}

fn interference_report(s: &mut String, label: &str, what: &str, i: &Interference) {
    let mins: Vec<String> = i.min_clearance_m.iter().map(|c| format!("{:.0}", c * 1e3)).collect();
    let home: Vec<String> = i.at_home_m.iter().map(|c| format!("{:.0}", c * 1e3)).collect();
    let _ = writeln!(
        s,
        "    {label:<10} {what}: closest per string {} mm over the reach, {} mm at home; touching at {} of {} \
         positions",
        mins.join("/"),
        home.join("/"),
        i.touching_positions,
        i.positions
    );
    for t in i.worst.iter().flatten() {
        let _ = writeln!(
            s,
            "               string {}: {:.0} mm in with the grip at {}, at {}",
            t.string,
            -t.clearance_m * 1e3,
            v3(t.grip_m),
            v3(t.at_m)
        );
    }
}

fn sites_report(s: &mut String, map: &RigMap) {
    if map.sites.is_empty() {
        return;
    }
    let _ = writeln!(s, "  sites        capacity margin at the homes and the scenes' contacts (exact):");
    for m in &map.sites {
        let h = &map.hands[m.site.hand];
        let _ = writeln!(
            s,
            "    {:<6} {:<34} {}: {:>6.2} N in every direction, {:+.2} N against the limit ({})",
            h.label,
            m.site.label,
            v3(m.site.point_m),
            m.capacity.margin_n,
            m.capacity.margin_n - h.force_limit_n,
            if m.limit_met { "met" } else { "NOT met" }
        );
    }
}

/// The map for other tools (`spidar rig map --json`): per hand its grid, the capacity margin and
/// the feasible flag per cell, the string clearances; the sites with their margins.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MapJson {
    pub kind: &'static str,
    pub version: u32,
    pub rig: String,
    pub step_m: f64,
    pub reach_m: f64,
    pub string_clearance_m: f64,
    pub forearm: ForearmJson,
    pub hands: Vec<HandJson>,
    pub sites: Vec<SiteJson>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ForearmJson {
    pub toward_elbow: [f64; 3],
    pub wrist_m: f64,
    pub elbow_m: f64,
    pub radius_m: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct HandJson {
    pub label: String,
    pub force_limit_n: f64,
    pub tension_n: [f64; 2],
    pub anchors_m: [[f64; 3]; 4],
    pub home_m: [f64; 3],
    /// Centre of cell (0, 0, 0), spacing and cell counts; cells in x-fastest order.
    pub grid_origin_m: [f64; 3],
    pub grid_step_m: f64,
    pub grid_n: [usize; 3],
    /// Capacity margin per cell, N (to 0.01 N).
    pub margin_n: Vec<f64>,
    /// The force limit met per cell (margin >= limit).
    pub feasible: Vec<bool>,
    pub feasible_volume_m3: f64,
    pub frame_fraction: f64,
    pub reach_fraction: f64,
    pub forearm: InterferenceJson,
    pub strings: InterferenceJson,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct InterferenceJson {
    /// Per string: its smallest clearance over the reach, and at home, m.
    pub min_clearance_m: [f64; 4],
    pub at_home_m: [f64; 4],
    pub touching_positions: usize,
    pub positions: usize,
    /// The tightest touch per string: grip position, point on the string, clearance.
    pub worst: Vec<TouchJson>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct TouchJson {
    pub string: usize,
    pub grip_m: [f64; 3],
    pub at_m: [f64; 3],
    pub clearance_m: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct SiteJson {
    pub hand: usize,
    pub label: String,
    pub point_m: [f64; 3],
    pub margin_n: f64,
    pub weakest: [f64; 3],
    pub limit_met: bool,
}

fn interference_json(i: &Interference) -> InterferenceJson {
    InterferenceJson {
        min_clearance_m: i.min_clearance_m,
        at_home_m: i.at_home_m,
        touching_positions: i.touching_positions,
        positions: i.positions,
        worst: i
            .worst
            .iter()
            .flatten()
            .map(|t| TouchJson {
                string: t.string,
                grip_m: t.grip_m.to_array(),
                at_m: t.at_m.to_array(),
                clearance_m: t.clearance_m,
            })
            .collect(),
    }
}

/// [`MapJson`] of `map`.
pub fn to_json(map: &RigMap, rig_name: &str) -> MapJson {
    let o = &map.options;
    let hands = map
        .hands
        .iter()
        .map(|h| HandJson {
            label: h.label.clone(),
            force_limit_n: h.force_limit_n,
            tension_n: [h.tension_n.0, h.tension_n.1],
            anchors_m: h.anchors_m.map(|a| a.to_array()),
            home_m: h.home_m.to_array(),
            grid_origin_m: h.grid.origin_m.to_array(),
            grid_step_m: h.grid.step_m,
            grid_n: h.grid.n,
            margin_n: h.margin_n.iter().map(|m| (m * 100.0).round() / 100.0).collect(),
            feasible: h.margin_n.iter().map(|m| *m >= h.force_limit_n).collect(),
            feasible_volume_m3: h.feasible_volume_m3,
            frame_fraction: h.frame_fraction(),
            reach_fraction: h.reach_fraction(),
            forearm: interference_json(&h.forearm),
            strings: interference_json(&h.strings),
        })
        .collect();
    let sites = map
        .sites
        .iter()
        .map(|m| SiteJson {
            hand: m.site.hand,
            label: m.site.label.clone(),
            point_m: m.site.point_m.to_array(),
            margin_n: m.capacity.margin_n,
            weakest: m.capacity.weakest.to_array(),
            limit_met: m.limit_met,
        })
        .collect();
    MapJson {
        kind: "rig-map",
        version: 1,
        rig: rig_name.to_string(),
        step_m: o.step_m,
        reach_m: o.reach_m,
        string_clearance_m: o.string_clearance_m,
        forearm: ForearmJson {
            toward_elbow: o.forearm.toward_elbow.to_array(),
            wrist_m: o.forearm.wrist_m,
            elbow_m: o.forearm.elbow_m,
            radius_m: o.forearm.radius_m,
        },
        hands,
        sites,
    }
}

fn plot_err(file: &Path) -> impl Fn(String) -> CalibError + '_ {
    move |message| CalibError::Plot { file: file.display().to_string(), message }
}

/// A slice through a hand's map: the horizontal plane through its home (`vertical` false: x
/// across, z up the page) or the vertical one (x across, y up).
struct Slice<'a> {
    h: &'a HandMap,
    vertical: bool,
}

impl Slice<'_> {
    /// Runs of cells of one class along x, per row: `(x0, x1, v0, v1, class)`.
    fn runs(&self) -> Vec<(f64, f64, f64, f64, usize)> {
        let g = &self.h.grid;
        let f = (self.h.home_m - g.origin_m) / g.step_m;
        let fixed = if self.vertical { f.z } else { f.y }
            .round()
            .clamp(0.0, (g.n[if self.vertical { 2 } else { 1 }] - 1) as f64) as usize;
        let rows = if self.vertical { g.n[1] } else { g.n[2] };
        let half = 0.5 * g.step_m;
        let mut out = Vec::new();
        for r in 0..rows {
            let idx = |i: usize| if self.vertical { g.index(i, r, fixed) } else { g.index(i, fixed, r) };
            let p = g.point(0, if self.vertical { r } else { fixed }, if self.vertical { fixed } else { r });
            let v = if self.vertical { p.y } else { p.z };
            let mut start = 0;
            for i in 1..=g.n[0] {
                let c = class_of(self.h.margin_n[idx(start)], self.h.force_limit_n);
                if i == g.n[0] || class_of(self.h.margin_n[idx(i)], self.h.force_limit_n) != c {
                    let x0 = g.point(start, 0, 0).x - half;
                    let x1 = g.point(i - 1, 0, 0).x + half;
                    out.push((x0, x1, v - half, v + half, c));
                    start = i;
                }
            }
        }
        out
    }
}

/// Two slices per hand (horizontal and vertical through its home), classes of the capacity
/// margin coloured, the homes and the reach marked.
pub fn slices_svg(map: &RigMap, path: &Path) -> Result<(), CalibError> {
    let err = plot_err(path);
    let root = SVGBackend::new(path, (1000, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let limit = map.hands.first().map_or(0.0, |h| h.force_limit_n);
    let title = format!(
        "capacity margin (force renderable in every direction): grey none, orange < {limit} N, light green {limit} .. {} N, green > {} N",
        2.0 * limit,
        2.0 * limit
    );
    let (top, body) = root.split_vertically(40);
    top.titled(&title, ("sans-serif", 15)).map_err(|e| err(e.to_string()))?;
    let areas = body.split_evenly((map.hands.len(), 2));
    for (k, area) in areas.iter().enumerate() {
        let h = &map.hands[k / 2];
        let slice = Slice { h, vertical: k % 2 == 1 };
        let (cx, cv) = (h.home_m.x, if slice.vertical { h.home_m.y } else { h.home_m.z });
        let caption = if slice.vertical {
            format!("{}: vertical slice z = {:.2} m", h.label, h.home_m.z)
        } else {
            format!("{}: horizontal slice y = {:.2} m", h.label, h.home_m.y)
        };
        let mut chart = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 15))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(
                (cx - SLICE_HALF_M)..(cx + SLICE_HALF_M),
                (cv - SLICE_HALF_M)..(cv + SLICE_HALF_M),
            )
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("x (m)")
            .y_desc(if slice.vertical { "y (m)" } else { "z (m)" })
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let clip = |a: f64, c: f64| a.clamp(c - SLICE_HALF_M, c + SLICE_HALF_M);
        let cells = slice.runs().into_iter().filter(|r| r.1 > cx - SLICE_HALF_M && r.0 < cx + SLICE_HALF_M);
        chart
            .draw_series(cells.filter(|r| r.3 > cv - SLICE_HALF_M && r.2 < cv + SLICE_HALF_M).map(
                |(x0, x1, v0, v1, c)| {
                    Rectangle::new(
                        [(clip(x0, cx), clip(v0, cv)), (clip(x1, cx), clip(v1, cv))],
                        CLASS_COLOURS[c].filled(),
                    )
                },
            ))
            .map_err(|e| err(e.to_string()))?;
        let r = map.options.reach_m;
        let circle = (0..=72).map(|i| {
            let a = std::f64::consts::TAU * i as f64 / 72.0;
            (cx + r * a.cos(), cv + r * a.sin())
        });
        chart.draw_series(LineSeries::new(circle, BLACK.stroke_width(1))).map_err(|e| err(e.to_string()))?;
        for (j, other) in map.hands.iter().enumerate() {
            let p = (other.home_m.x, if slice.vertical { other.home_m.y } else { other.home_m.z });
            let style = if j == k / 2 { BLACK.filled() } else { BLACK.stroke_width(1) };
            chart.draw_series(std::iter::once(Circle::new(p, 4, style))).map_err(|e| err(e.to_string()))?;
        }
        // This hand's scene contacts, projected onto the slice: a cross, red where the limit is
        // not met there, with its label.
        for m in map.sites.iter().filter(|m| m.site.hand == k / 2 && m.site.label != "home") {
            let q = m.site.point_m;
            let p = (q.x, if slice.vertical { q.y } else { q.z });
            let colour = if m.limit_met { BLACK } else { RED };
            let style = colour.stroke_width(2);
            chart.draw_series(std::iter::once(Cross::new(p, 6, style))).map_err(|e| err(e.to_string()))?;
            let text =
                Text::new(format!("{} {:.1} N", m.site.label, m.capacity.margin_n), p, ("sans-serif", 11));
            chart.draw_series(std::iter::once(text)).map_err(|e| err(e.to_string()))?;
        }
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fit_that_moves_anchors_shows_what_it_did_to_the_map() {
        let rig = Rig::default_rig();
        let same = fit_change(&rig, &[Some(rig.hands[0].anchors_m), None]);
        let (before, after) = same.split_once('\n').unwrap();
        assert_eq!(before.split_once(": ").unwrap().1, after.split_once(": ").unwrap().1.trim_start());
        // The left hand's lower anchors 0.4 m higher: less of its frame can be pushed with the limit.
        let mut moved = rig.hands[0].anchors_m;
        moved[2].y += 0.4;
        moved[3].y += 0.4;
        let changed = fit_change(&rig, &[Some(moved), None]);
        let (before, after) = changed.split_once('\n').unwrap();
        let left = |line: &str| line.split("left ").nth(1).unwrap().split(';').next().unwrap().to_string();
        assert_ne!(left(before), left(after), "{changed}");
        let right = |line: &str| line.split("right ").nth(1).unwrap().to_string();
        assert_eq!(right(before), right(after));
    }

    #[test]
    fn the_slices_cover_every_cell_once_and_the_report_says_each_hands_figures() {
        let rig = Rig::default_rig();
        let map = map_rig(&rig, &MapOptions { step_m: 0.1, ..MapOptions::default() });
        for h in &map.hands {
            for vertical in [false, true] {
                let runs = Slice { h, vertical }.runs();
                let width: f64 = runs.iter().map(|r| r.1 - r.0).sum();
                let rows = if vertical { h.grid.n[1] } else { h.grid.n[2] };
                assert!((width - rows as f64 * h.grid.n[0] as f64 * h.grid.step_m).abs() < 1e-9);
            }
        }
        let text = report(&map, &rig.name);
        for h in &map.hands {
            assert!(text.contains(&format!("{:.2} N in every direction", h.home.margin_n)), "{text}");
        }
        assert!(headline(&map).contains("% of its reach"));
        let dir = std::env::temp_dir().join(format!("spidar-rigmap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let svg = dir.join("map.svg");
        slices_svg(&map, &svg).unwrap();
        let body = std::fs::read_to_string(&svg).unwrap();
        assert!(body.contains("<rect") && body.contains("vertical slice"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
