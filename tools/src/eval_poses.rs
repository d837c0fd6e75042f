//! `spidar eval poses`: contact sheets of the keyframe characters (seed 002) as they are drawn: a
//! walk and a stop, a stagger, a fall to each side, and a stand-up, each a row of frames of the
//! skeleton the world computes drawn over the rigid body it belongs to, written as SVG. Next to the
//! pictures it prints the measures the tests check on the same motions (how far any joint leaves
//! the body's shape, joints below the floor, the largest joint jump in one step, how far a planted
//! foot's drawn ankle slides).
//!
//! The characters are those of the built-in crowd scene (its body, controller and keyframe set),
//! stepped by the crowd stepper the scene runs; the frames are the poses the scene publishes.
//!
//! Must never: draw a pose the world did not compute.

use std::fmt;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use plotters::prelude::*;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::drawn::{world_joints, FigureStats};
use spidar_sim::character::keyframe::MAX_JOINTS;
use spidar_sim::character::scene::builtin_crowd;
use spidar_sim::collide::Shape;

/// Which way a sheet looks at the character: from its side (its front to the right) or from its
/// front (its left to the right).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    Side,
    Front,
}

/// One drawn moment.
#[derive(Clone, Debug)]
pub struct Frame {
    pub t_s: f64,
    pub policy: Policy,
    /// Joint positions (world) and each joint's parent.
    pub joints: Vec<(DVec3, Option<usize>)>,
    /// The body's collision shapes in the world.
    pub shapes: Vec<(Shape, DVec3, DMat3)>,
    /// The controller's feet: position and whether planted.
    pub feet: Option<[(DVec3, bool); 2]>,
}

/// A motion and the frames drawn of it.
#[derive(Clone, Debug)]
pub struct Sheet {
    pub name: &'static str,
    pub title: String,
    pub view: View,
    pub frames: Vec<Frame>,
    pub stats: FigureStats,
}

fn frame(c: &Crowd, t_s: f64) -> Frame {
    let mut j = [DVec3::ZERO; MAX_JOINTS];
    let n = world_joints(c, 0, &mut j);
    let joints = (0..n).map(|k| (j[k], c.set.joints[k].parent)).collect();
    let shapes = (0..c.body.shapes.len())
        .map(|k| {
            let (s, p) = c.shape_world(0, k);
            (s, p.pos_m, p.rot)
        })
        .collect();
    let f = &c.chars[0].control.feet;
    let feet = f.placed.then(|| [0, 1].map(|k| (f.foot[k].pos_m, f.foot[k].planted())));
    Frame { t_s, policy: c.chars[0].control.policy, joints, shapes, feet }
}

/// Runs one motion: `setup` places the character and may push it at `push_at_s`; frames every
/// `every_s` from `from_s` for `frames` frames.
fn record(
    name: &'static str,
    title: &str,
    view: View,
    goal: Goal,
    push: Option<(f64, DVec3, DVec3)>,
    (from_s, every_s, frames): (f64, f64, usize),
) -> anyhow::Result<Sheet> {
    let mut c = builtin_crowd()?.empty_like();
    c.add(0.0, 0.0, 0.0, goal);
    let dt = c.world.dt_s;
    let mut stats = FigureStats::default();
    let mut out = Vec::new();
    let end = from_s + every_s * frames as f64;
    let mut k = 0usize;
    let mut pushed = false;
    loop {
        let t = k as f64 * dt;
        if t > end + 1e-9 {
            break;
        }
        if let (Some((at_s, height_m, impulse)), false) = (push, pushed) {
            if t >= at_s {
                let b = c.body_space(0);
                let dir = impulse.normalize();
                // On the body's surface facing the push, at the given height above the floor.
                let point = DVec3::new(b.r_m.x, height_m.x, b.r_m.z) - dir * 0.13;
                c.add_impulse_at(0, point, impulse);
                pushed = true;
            }
        }
        c.step();
        k += 1;
        let t = k as f64 * dt;
        if t >= from_s - 1e-9 {
            stats.add(&c, 0, 0.0);
        }
        let slot = ((t - from_s) / every_s).round();
        if slot >= 0.0 && (t - from_s - slot * every_s).abs() < 0.5 * dt && (slot as usize) < frames {
            out.push(frame(&c, t));
        }
    }
    Ok(Sheet { name, title: title.to_string(), view, frames: out, stats })
}

/// The motions of the contact sheets.
pub fn sheets() -> anyhow::Result<Vec<Sheet>> {
    let push = |at_s: f64, h_m: f64, dir: DVec3, n_s: f64| Some((at_s, DVec3::new(h_m, 0.0, 0.0), dir * n_s));
    let walk = Goal::WalkTo { point_m: DVec3::new(0.0, 0.0, 2.4), speed_m_per_s: 0.9 };
    Ok(vec![
        record("walk", "walking 2.4 m and stopping (side view)", View::Side, walk, None, (0.2, 0.3, 16))?,
        record(
            "stagger",
            "a 20 N s push at the shoulders from behind: staggers forward and recovers (side view)",
            View::Side,
            Goal::Stand,
            push(0.3, 1.2, DVec3::Z, 20.0),
            (0.2, 0.15, 16),
        )?,
        record(
            "fall-forward",
            "a 100 N s shove at the trunk from behind: falls on its face (side view)",
            View::Side,
            Goal::Stand,
            push(0.3, 0.75, DVec3::Z, 100.0),
            (0.2, 0.12, 16),
        )?,
        record(
            "fall-backward",
            "a 90 N s shove at the shoulders from the front: sits down and falls on its back (side view)",
            View::Side,
            Goal::Stand,
            push(0.3, 1.2, -DVec3::Z, 90.0),
            (0.2, 0.12, 16),
        )?,
        record(
            "fall-left",
            "a 90 N s shove at the shoulders from its right: falls to its left and rolls over (front view)",
            View::Front,
            Goal::Stand,
            push(0.3, 1.2, DVec3::X, 90.0),
            (0.2, 0.15, 16),
        )?,
        record(
            "fall-right",
            "a 90 N s shove at the shoulders from its left: falls to its right and rolls over (front view)",
            View::Front,
            Goal::Stand,
            push(0.3, 1.2, -DVec3::X, 90.0),
            (0.2, 0.15, 16),
        )?,
        record(
            "stand-up",
            "after falling on its face: stops, stands up and settles (side view)",
            View::Side,
            Goal::Stand,
            push(0.3, 0.75, DVec3::Z, 100.0),
            (2.0, 0.2, 16),
        )?,
    ])
}

/// Window of one panel in the view's plane (m): width, and height from the floor.
const PANEL_W_M: f64 = 2.0;
const PANEL_H_M: f64 = 1.9;
const PANEL_PX: (u32, u32) = (150, 160);
const COLUMNS: usize = 8;

fn horizontal(view: View, p: DVec3) -> f64 {
    match view {
        View::Side => p.z,
        View::Front => p.x,
    }
}

fn draw_err(path: &Path) -> impl Fn(String) -> anyhow::Error + '_ {
    move |m| anyhow::anyhow!("drawing {}: {m}", path.display())
}

/// The outline (in the view's plane) of a collision shape.
fn outline(view: View, s: &Shape, pos: DVec3, rot: DMat3) -> Vec<(f64, f64)> {
    let pr = |p: DVec3| (horizontal(view, p), p.y);
    let circle = |c: (f64, f64), r: f64, from: f64, to: f64, n: usize| -> Vec<(f64, f64)> {
        (0..=n)
            .map(|i| from + (to - from) * i as f64 / n as f64)
            .map(|a| (c.0 + r * a.cos(), c.1 + r * a.sin()))
            .collect()
    };
    match *s {
        Shape::Sphere { radius_m } => circle(pr(pos), radius_m, 0.0, std::f64::consts::TAU, 24),
        Shape::Capsule { half_length_m, radius_m } => {
            // An orthographic capsule is a 2-D capsule of the same radius.
            let (a, b) = (pr(pos - rot.y_axis * half_length_m), pr(pos + rot.y_axis * half_length_m));
            let ang = (b.1 - a.1).atan2(b.0 - a.0);
            let half = std::f64::consts::FRAC_PI_2;
            let mut pts = circle(b, radius_m, ang - half, ang + half, 10);
            pts.extend(circle(a, radius_m, ang + half, ang + 3.0 * half, 10));
            pts
        }
        Shape::Box { half_extents_m: e } => {
            let mut pts: Vec<(f64, f64)> = (0..8)
                .map(|i| {
                    let s = DVec3::new(
                        if i & 1 == 0 { -1.0 } else { 1.0 },
                        if i & 2 == 0 { -1.0 } else { 1.0 },
                        if i & 4 == 0 { -1.0 } else { 1.0 },
                    );
                    pr(pos + rot * (s * e))
                })
                .collect();
            hull(&mut pts)
        }
        Shape::Plane => Vec::new(),
    }
}

/// Convex hull of 2-D points (monotone chain).
fn hull(p: &mut [(f64, f64)]) -> Vec<(f64, f64)> {
    p.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let cross =
        |o: (f64, f64), a: (f64, f64), b: (f64, f64)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    let mut h: Vec<(f64, f64)> = Vec::new();
    for pass in 0..2 {
        let start = h.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for &q in iter {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], q) <= 0.0 {
                h.pop();
            }
            h.push(q);
        }
        h.pop();
    }
    h
}

/// Writes one contact sheet as SVG.
pub fn write_svg(sheet: &Sheet, path: &Path) -> anyhow::Result<()> {
    let err = draw_err(path);
    let rows = sheet.frames.len().div_ceil(COLUMNS);
    let size = (PANEL_PX.0 * COLUMNS as u32, PANEL_PX.1 * rows as u32 + 28);
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    root.draw(&Text::new(sheet.title.clone(), (8, 6), ("sans-serif", 15))).map_err(|e| err(e.to_string()))?;
    let grid = root.margin(26, 0, 0, 0).split_evenly((rows, COLUMNS));
    let body_fill = RGBColor(205, 215, 230);
    let bone = RGBColor(200, 40, 40);
    for (f, panel) in sheet.frames.iter().zip(grid.iter()) {
        // Centre on the body horizontally; the floor marks show where it went.
        let centre =
            f.shapes.iter().map(|s| horizontal(sheet.view, s.1)).sum::<f64>() / f.shapes.len().max(1) as f64;
        let x0 = centre - PANEL_W_M / 2.0;
        let chart = ChartBuilder::on(panel)
            .margin(4)
            .build_cartesian_2d(x0..x0 + PANEL_W_M, -0.15..PANEL_H_M - 0.15)
            .map_err(|e| err(e.to_string()))?;
        let area = chart.plotting_area();
        area.draw(&PathElement::new(vec![(x0, 0.0), (x0 + PANEL_W_M, 0.0)], BLACK.stroke_width(1)))
            .map_err(|e| err(e.to_string()))?;
        let first = (x0 / 0.5).ceil() as i64;
        for m in first..first + 5 {
            let x = m as f64 * 0.5;
            area.draw(&PathElement::new(vec![(x, 0.0), (x, -0.06)], BLACK.stroke_width(1)))
                .map_err(|e| err(e.to_string()))?;
        }
        for (s, pos, rot) in &f.shapes {
            let pts = outline(sheet.view, s, *pos, *rot);
            if pts.len() > 2 {
                area.draw(&Polygon::new(pts.clone(), body_fill.mix(0.6).filled()))
                    .map_err(|e| err(e.to_string()))?;
                let mut closed = pts;
                closed.push(closed[0]);
                area.draw(&PathElement::new(closed, RGBColor(120, 135, 160).stroke_width(1)))
                    .map_err(|e| err(e.to_string()))?;
            }
        }
        for &(p, parent) in &f.joints {
            if let Some(q) = parent {
                let q = f.joints[q].0;
                area.draw(&PathElement::new(
                    vec![(horizontal(sheet.view, q), q.y), (horizontal(sheet.view, p), p.y)],
                    bone.stroke_width(2),
                ))
                .map_err(|e| err(e.to_string()))?;
            }
            area.draw(&Circle::new((horizontal(sheet.view, p), p.y), 2, bone.filled()))
                .map_err(|e| err(e.to_string()))?;
        }
        if let Some(feet) = f.feet {
            for (p, planted) in feet {
                let style = if planted { BLACK.filled() } else { BLACK.stroke_width(1) };
                area.draw(&Circle::new((horizontal(sheet.view, p), 0.0), 3, style))
                    .map_err(|e| err(e.to_string()))?;
            }
        }
        panel
            .draw(&Text::new(format!("{:.2} s {}", f.t_s, f.policy.name()), (4, 2), ("sans-serif", 11)))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

/// What one sheet's motion measured (m): see [`FigureStats`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct PoseRow {
    pub motion: &'static str,
    pub file: PathBuf,
    pub trunk_outside_m: f64,
    pub lying_outside_m: f64,
    pub any_outside_m: f64,
    pub below_floor_m: f64,
    pub max_jump_m: f64,
    pub max_slide_m: f64,
    pub max_lift_m: f64,
}

/// Every sheet written and what it measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PosesReport {
    pub path: &'static str,
    pub rows: Vec<PoseRow>,
}

impl fmt::Display for PosesReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "drawn figure against the rigid body ({}), worst over each motion:", self.path)?;
        writeln!(
            f,
            "{:<14} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}   file",
            "motion", "trunk", "lying", "any", "below", "jump", "slide", "lift"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "{:<14} {:>7.1}cm {:>7.1}cm {:>7.1}cm {:>7.1}cm {:>7.1}cm {:>7.1}cm {:>7.1}cm   {}",
                r.motion,
                r.trunk_outside_m * 100.0,
                r.lying_outside_m * 100.0,
                r.any_outside_m * 100.0,
                r.below_floor_m * 100.0,
                r.max_jump_m * 100.0,
                r.max_slide_m * 100.0,
                r.max_lift_m * 100.0,
                r.file.display()
            )?;
        }
        write!(
            f,
            "(trunk: joints other than hands, elbows, knees, ankles outside the body's shapes; lying: any joint while lying or \
             standing up; any: any joint at any time, arms reaching out included; below: under the floor; jump: largest move \
             of a joint in one 3 ms step; slide: a drawn ankle's drift while its foot is planted; lift: highest swing)"
        )
    }
}

/// Writes every sheet into `dir` (created if needed) and returns what it wrote and measured.
pub fn eval_poses(dir: &Path) -> anyhow::Result<PosesReport> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("creating {}: {e}", dir.display()))?;
    let mut rows = Vec::new();
    for s in sheets()? {
        let file: PathBuf = dir.join(format!("{}.svg", s.name));
        write_svg(&s, &file)?;
        let st = &s.stats;
        rows.push(PoseRow {
            motion: s.name,
            file,
            trunk_outside_m: st.trunk_outside_m,
            lying_outside_m: st.lying_outside_m,
            any_outside_m: st.any_outside_m,
            below_floor_m: st.below_floor_m,
            max_jump_m: st.max_jump_m,
            max_slide_m: st.max_slide_m,
            max_lift_m: st.max_lift_m,
        });
    }
    Ok(PosesReport { path: "crowd stepper, the crowd scene's settings; no rig or rt-loop", rows })
}
