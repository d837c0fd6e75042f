//! `spidar eval poses`: contact sheets of the keyframe characters (seed 002) as they are drawn: a
//! walk and a stop, a stagger, a fall to each side, and a stand-up, each a row of frames of the
//! skeleton the world computes drawn over the rigid body it belongs to, written as SVG. Next to the
//! pictures it prints the measures the tests check on the same motions (how far any joint leaves
//! the body's shape, joints below the floor, the largest joint jump in one step, how far a planted
//! foot's drawn ankle slides).
//!
//! The characters are those of the built-in crowd scene (its body, controller and keyframe set),
//! run through the user's path (`crate::crowd_run`: the simulated rig, the rt-loop, the crowd
//! scene), pushed by a simulated hand; the frames are the poses the scene publishes.
//!
//! Must never: draw a pose the world did not compute.

use std::fmt;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use plotters::prelude::*;
use spidar_rt::Rig;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::drawn::{world_joints, FigureStats};
use spidar_sim::character::scene::builtin_crowd;
use spidar_sim::character::skeleton::MAX_JOINTS;
use spidar_sim::collide::Shape;

use crate::crowd_run::{first_touch, shove_scripts, CrowdRun, Shove, SETTLED_S};

/// The horizontal axis of a sheet's pictures: the world's z (toward the user) or x (to the user's
/// right).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    WorldZ,
    WorldX,
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

/// A push through the user's path: a hand shoves the character at `height_m` above the floor,
/// toward its centre line, `depth_m` past where it first touches the body in `push_s`, starting
/// 6 cm short of it at the motion's time `at_s`.
#[derive(Clone, Copy, Debug)]
struct HandPush {
    at_s: f64,
    height_m: f64,
    depth_m: f64,
    push_s: f64,
}

/// Where a pushed character stands (world x, z, m): on the rig's centre line, its near side about
/// 0.3 m in front of the rig's origin (farther when it shows the user its side, the wider one).
fn stand_point(heading_rad: f64) -> (f64, f64) {
    (0.0, -0.42 - 0.08 * heading_rad.sin().abs())
}

/// Runs one motion through the user's path (simulated rig, rt-loop, crowd scene: `crowd_run`): a
/// character of the crowd scene at `at` (world x, z) with `heading_rad` and `goal`, pushed by a hand
/// if `push` says so; frames every `every_s` from the motion's time `from_s` (0: the rig has
/// settled) for `frames` frames.
#[allow(clippy::too_many_arguments)]
fn record(
    name: &'static str,
    title: &str,
    view: View,
    (at, heading_rad): ((f64, f64), f64),
    goal: Goal,
    push: Option<HandPush>,
    (from_s, every_s, frames): (f64, f64, usize),
) -> anyhow::Result<Sheet> {
    let rig = Rig::default_rig();
    let mut c = builtin_crowd()?.empty_like();
    c.add(at.0, at.1, heading_rad, goal);
    let shove = match push {
        Some(p) => {
            let b = c.body_space(0);
            let floor_y = b.r_m.y - 0.75;
            // The hand pushes away from the user, through the body's centre line at the height,
            // from 6 cm short of where it first touches the body.
            let into = -DVec3::Z;
            let centre = DVec3::new(b.r_m.x, floor_y + p.height_m, b.r_m.z);
            let touch = first_touch(&c, centre - into * 0.6, into)
                .ok_or_else(|| anyhow::anyhow!("{name}: the hand's line misses the body"))?;
            let (near, point) = (touch - into * 0.06, touch);
            let start_s = SETTLED_S + p.at_s - 0.6;
            Some(Shove {
                start_s,
                reach_s: 0.6,
                near: rig.rig_to_world.point_to_rig(near),
                to: rig.rig_to_world.point_to_rig(point + into * p.depth_m),
                push_s: p.push_s,
            })
        }
        None => None,
    };
    let mut run = CrowdRun::new(&rig, c, shove_scripts(&rig, shove.as_ref()))?;
    let mut stats = FigureStats::default();
    let mut out = Vec::new();
    let end = from_s + every_s * frames as f64;
    loop {
        let t = run.step()? - SETTLED_S;
        if t > end + 1e-9 {
            break;
        }
        let c = run.crowd();
        let dt = c.world.dt_s;
        if t >= from_s - 1e-9 {
            stats.add(c, 0, 0.0);
        }
        let slot = ((t - from_s) / every_s).round();
        if slot >= 0.0
            && (t - from_s - slot * every_s).abs() <= 0.5 * dt
            && (slot as usize) < frames
            && out.len() == slot as usize
        {
            out.push(frame(c, t));
        }
    }
    if run.faults() != 0 {
        anyhow::bail!("the rig faulted {} times while recording {name}: the sheet is void", run.faults());
    }
    let title = match push {
        Some(_) => format!("{title}; the hand gave {:.0} N s", run.scene.impulse_sum_n_s),
        None => title.to_string(),
    };
    Ok(Sheet { name, title, view, frames: out, stats })
}

/// The motions of the contact sheets, each through the user's path: the pushes are a hand's.
pub fn sheets() -> anyhow::Result<Vec<Sheet>> {
    use std::f64::consts::{FRAC_PI_2, PI};
    let push = |at_s: f64, height_m: f64, depth_m: f64, push_s: f64| {
        Some(HandPush { at_s, height_m, depth_m, push_s })
    };
    // Facing the user (its front at +z), its back to the user, its left or right side to the user.
    let (front, back, left, right) = (0.0, PI, FRAC_PI_2, -FRAC_PI_2);
    let placed = |h: f64| (stand_point(h), h);
    // A walk across in front of the user, from the left to the right, and a stop.
    let walk = Goal::WalkTo { point_m: DVec3::new(1.2, 0.0, -1.2), speed_m_per_s: 0.9 };
    Ok(vec![
        record(
            "walk",
            "walking 2.4 m across in front of the user and stopping (side view)",
            View::WorldX,
            ((-1.2, -1.2), FRAC_PI_2), // facing +x, the way it walks
            walk,
            None,
            (0.2, 0.3, 16),
        )?,
        record(
            "stagger",
            "a hand's push at the shoulders from behind: staggers forward and recovers (side view)",
            View::WorldZ,
            placed(back),
            Goal::Stand,
            push(0.3, 1.05, 0.06, 0.3),
            (0.2, 0.15, 16),
        )?,
        record(
            "fall-forward",
            "a hand's shove at the trunk from behind: falls on its face (side view)",
            View::WorldZ,
            placed(back),
            Goal::Stand,
            push(0.3, 0.85, 0.25, 0.5),
            (0.2, 0.12, 16),
        )?,
        record(
            "fall-backward",
            "a hand's shove at the shoulders from the front: falls on its back (side view)",
            View::WorldZ,
            placed(front),
            Goal::Stand,
            push(0.3, 1.05, 0.25, 0.5),
            (0.2, 0.12, 16),
        )?,
        record(
            "fall-left",
            "a hand's shove at the shoulders from its right: falls to its left and rolls over (front view)",
            View::WorldZ,
            placed(left),
            Goal::Stand,
            push(0.3, 1.05, 0.25, 0.5),
            (0.2, 0.15, 16),
        )?,
        record(
            "fall-right",
            "a hand's shove at the shoulders from its left: falls to its right and rolls over (back view)",
            View::WorldZ,
            placed(right),
            Goal::Stand,
            push(0.3, 1.05, 0.25, 0.5),
            (0.2, 0.15, 16),
        )?,
        record(
            "stand-up",
            "after a hand's shove from behind: on its face, stops, stands up and settles (side view)",
            View::WorldZ,
            placed(back),
            Goal::Stand,
            push(0.3, 0.85, 0.25, 0.5),
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
        View::WorldZ => p.z,
        View::WorldX => p.x,
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
    Ok(PosesReport {
        path: "the user's path, as `spidar run --scene crowd --virtual`: the crowd scene behind the simulated rig and the \
               rt-loop, the pushes a simulated hand's",
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every sheet, run through the simulated rig, the rt-loop and the crowd scene with a hand's
    /// pushes, shows what its title says (the walk and the stagger keep their feet, every shove
    /// topples the character, the stand-up ends upright), and the drawn figure stays on the body
    /// within the bounds the character tests hold the crowd stepper to.
    #[test]
    fn the_contact_sheets_show_their_motions_through_the_rig() {
        let sheets = sheets().unwrap();
        assert_eq!(sheets.len(), 7);
        for s in &sheets {
            assert_eq!(s.frames.len(), 16, "{}", s.name);
            eprintln!("{}: {}", s.name, s.title);
            let fell = s.frames.iter().any(|f| f.policy != Policy::Balance);
            let expect_fall = s.name.starts_with("fall") || s.name == "stand-up";
            assert_eq!(
                fell,
                expect_fall,
                "{}: {:?}",
                s.name,
                s.frames.iter().map(|f| f.policy).collect::<Vec<_>>()
            );
            let st = &s.stats;
            assert!(st.trunk_outside_m < 0.06, "{}: {st:?}", s.name);
            assert!(st.lying_outside_m < 0.09, "{}: {st:?}", s.name);
            assert!(st.below_floor_m < 0.02, "{}: {st:?}", s.name);
            assert!(st.max_jump_m < 0.07, "{}: {st:?}", s.name);
            assert!(st.max_slide_m < 0.05, "{}: {st:?}", s.name);
        }
        let up = sheets.iter().find(|s| s.name == "stand-up").unwrap();
        assert_eq!(up.frames.last().unwrap().policy, Policy::Balance, "it never stood up again");
        // The walk lifts its feet visibly.
        assert!(sheets[0].stats.max_lift_m > 0.05, "{:?}", sheets[0].stats);
    }
}
