//! The text messages of the view: the scene description (once per connection), the rig (when it
//! is known or changes) and the status (a few times a second). Built on the view's own threads.

use glam::{DQuat, DVec3};
use serde::Serialize;
use serde_json::{json, Value};
use spidar_msg::{RigInfo, RigState, RigStatus};
use spidar_sim::collide::Shape;

use super::frame::{Layout, GLOBALS_AT, HANDS_AT, HAND_FLOATS, PROXY_FLOATS, STAMP_AT, TENSIONS_AT};
use crate::look::{Look, LookShape, CONTACT_FLOATS, GAZE_FLOATS, MAX_CONTACTS, SHAPE_FLOATS};

fn v3(v: DVec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn colour(c: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

#[derive(Serialize)]
struct ShapeJson {
    name: String,
    kind: &'static str,
    radius_m: f64,
    half_length_m: f64,
    half_extents_m: [f64; 3],
    colour: String,
    proxy: Option<[u16; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pos_m: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    quat: Option<[f64; 4]>,
}

fn shape_json(s: &LookShape, at: Option<(DVec3, DQuat)>) -> ShapeJson {
    let (kind, radius_m, half_length_m, half_extents_m) = match s.shape {
        Shape::Sphere { radius_m } => ("sphere", radius_m, 0.0, [0.0; 3]),
        Shape::Capsule { half_length_m, radius_m } => ("capsule", radius_m, half_length_m, [0.0; 3]),
        Shape::Box { half_extents_m } => ("box", 0.0, 0.0, v3(half_extents_m)),
        Shape::Plane => ("plane", 0.0, 0.0, [0.0; 3]),
    };
    ShapeJson {
        name: s.name.clone(),
        kind,
        radius_m,
        half_length_m,
        half_extents_m,
        colour: colour(s.colour),
        proxy: s.proxy.map(|p| [p.body, p.part]),
        pos_m: at.map(|a| v3(a.0)),
        quat: at.map(|a| [a.1.x, a.1.y, a.1.z, a.1.w]),
    }
}

/// The scene description: what the page builds its scene graph from, and the frame layout.
pub fn scene(name: &str, look: &Look, layout: &Layout, frame_hz: f64) -> String {
    let crowd = look.crowd.as_ref().map(|c| {
        json!({
            "characters": c.characters,
            "joints": c.joints.iter().map(|j| json!({
                "name": j.name, "parent": j.parent, "offset_m": v3(j.offset_m)
            })).collect::<Vec<_>>(),
            "states": c.states,
            "colours": c.colours.iter().map(|c| colour(*c)).collect::<Vec<_>>(),
            "proxy_body_is_character": c.proxy_body_is_character,
        })
    });
    json!({
        "type": "scene",
        "version": 1,
        "name": name,
        "frame_hz": frame_hz,
        "layout": {
            "id": layout.id,
            "stamp_at": STAMP_AT,
            "globals_at": GLOBALS_AT,
            "hands_at": HANDS_AT,
            "hand_floats": HAND_FLOATS,
            "tensions_at": TENSIONS_AT,
            "shapes_at": layout.shapes_at,
            "shape_floats": SHAPE_FLOATS,
            "shape_force_at": layout.shape_force_at,
            "labels_at": layout.labels_at,
            "characters_at": layout.characters_at,
            "character_floats": layout.character_floats,
            "proxies_at": layout.proxies_at,
            "proxy_floats": PROXY_FLOATS,
            "gaze_at": layout.gaze_at,
            "gaze_floats": GAZE_FLOATS,
            "contacts_at": layout.contacts_at,
            "contact_floats": CONTACT_FLOATS,
            "max_contacts": MAX_CONTACTS,
        },
        "link_offset_m": v3(look.link_offset_m),
        "focus_m": v3(look.focus_m),
        "shapes": look.shapes.iter().map(|s| shape_json(s, None)).collect::<Vec<_>>(),
        "statics": look.statics.iter().map(|(s, p, q)| shape_json(s, Some((*p, *q)))).collect::<Vec<_>>(),
        "labels": look.labels.iter().map(|l| json!({"name": l.name, "shape": l.shape, "states": l.states})).collect::<Vec<_>>(),
        "counters": look.counters,
        "crowd": crowd,
        "humanoids": look.humanoids.iter().map(|h| json!({
            "name": h.name,
            "colour": colour(h.colour),
            "skin": colour(h.skin),
            "forward": v3(h.forward),
            "segments": h.segments.iter().map(|s| json!({"shape": s.shape, "part": s.part, "side": s.side})).collect::<Vec<_>>(),
            "joints": h.joints.iter().map(|j| json!({
                "name": j.name, "parent_shape": j.parent_shape, "child_shape": j.child_shape,
                "at_parent_m": v3(j.at_parent_m), "at_child_m": v3(j.at_child_m),
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "eyes": look.eyes.iter().map(|e| json!({"name": e.name, "eye_m": v3(e.eye_m), "focus_m": v3(e.focus_m)})).collect::<Vec<_>>(),
        "gaze": look.gazes.iter().map(|g| json!({"name": g.name, "head_shape": g.head_shape})).collect::<Vec<_>>(),
    })
    .to_string()
}

/// The rig's geometry in the scene frame, with each hand's force-feasible workspace (cells of a
/// grid, see [`super::rigview`]) and what makes a string near (the flags of the frames).
pub fn rig(info: &RigInfo, offset: DVec3) -> String {
    use super::rigview::{workspace, WORKSPACE_STEP_M};
    let workspaces: Vec<Value> = (0..info.anchors_m.len())
        .map(|h| {
            let w = workspace(info, h, WORKSPACE_STEP_M);
            json!({
                "origin_m": v3(w.grid.origin_m + offset),
                "step_m": w.grid.step_m,
                "n": w.grid.n,
                "cells": w.cells,
            })
        })
        .collect();
    let arm = info.clearance.forearm;
    let anchors: Vec<Vec<[f64; 3]>> =
        info.anchors_m.iter().map(|h| h.iter().map(|a| v3(*a + offset)).collect()).collect();
    json!({
        "type": "rig",
        "period_s": info.period_s,
        "anchors_m": anchors,
        "home_m": info.home_m.iter().map(|h| v3(*h + offset)).collect::<Vec<_>>(),
        "tension_min_n": info.tension_min_n,
        "tension_max_n": info.tension_max_n,
        "force_limit_n": info.force_limit_n,
        "grip_radius_m": info.grip_radius_m,
        "eye_m": v3(info.eye_m + offset),
        "display": display(&info.display, offset),
        "workspace": workspaces,
        "strings_near_m": info.clearance.distance_m,
        "forearm": {
            "toward_elbow": v3(arm.toward_elbow),
            "wrist_m": arm.wrist_m,
            "elbow_m": arm.elbow_m,
            "radius_m": arm.radius_m,
        },
    })
    .to_string()
}

/// The rig's screen in the scene frame (null: none), for the page's off-axis camera.
fn display(d: &spidar_msg::DisplayInfo, offset: DVec3) -> Value {
    if !d.present {
        return Value::Null;
    }
    let stereo = match d.stereo {
        1 => "side-by-side",
        2 => "top-bottom",
        3 => "anaglyph",
        _ => "mono",
    };
    json!({
        "lower_left_m": v3(d.lower_left_m + offset),
        "lower_right_m": v3(d.lower_right_m + offset),
        "upper_left_m": v3(d.upper_left_m + offset),
        "eye_separation_m": d.eye_separation_m,
        "stereo": stereo,
    })
}

pub fn rig_state_name(s: RigState) -> &'static str {
    match s {
        RigState::Unconfigured => "unconfigured",
        RigState::Inactive => "inactive",
        RigState::Active => "active",
        RigState::Faulted => "faulted",
        RigState::Stopping => "stopping",
    }
}

/// What the status message says, as the stepping thread left it.
#[derive(Clone, Copy, Debug, Default)]
pub struct StatusData {
    pub t_s: f64,
    pub steps: u64,
    pub step_rate_hz: f64,
    pub rig: Option<RigStatus>,
    /// World time the rig status was first seen at its tick (for its age).
    pub rig_seen_t_s: f64,
    /// World time of the newest hand sample (NaN: none yet).
    pub sample_t_s: f64,
    pub counters: [f64; crate::look::MAX_COUNTERS],
    pub ended: bool,
}

/// The status message.
pub fn status(
    d: &StatusData,
    counter_names: &[String],
    viewers: usize,
    published: u64,
    skipped: u64,
    ages: (Option<super::AgeSummary>, Option<super::AgeSummary>),
) -> String {
    let finite = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let age = |a: Option<super::AgeSummary>| {
        a.map(|a| {
            json!({
                "frames": a.frames, "total": a.total, "p50_ms": a.p50_ms, "p99_ms": a.p99_ms, "max_ms": a.max_ms,
                "hand_lag_p50_ms": a.hand_lag_p50_ms, "hand_lag_p99_ms": a.hand_lag_p99_ms,
                "draw_p50_ms": a.draw_p50_ms, "draw_p99_ms": a.draw_p99_ms,
                "arrive_p50_ms": finite(a.arrive_p50_ms), "arrive_p99_ms": finite(a.arrive_p99_ms),
                "wait_p50_ms": finite(a.wait_p50_ms), "wait_p99_ms": finite(a.wait_p99_ms),
                "hand_err_p50_mm": finite(a.hand_err_p50_mm), "hand_err_p99_mm": finite(a.hand_err_p99_mm),
                "hand_err_max_mm": finite(a.hand_err_max_mm),
                "hand_still_err_p50_mm": finite(a.hand_still_err_p50_mm),
                "hand_still_err_p99_mm": finite(a.hand_still_err_p99_mm),
                "hand_still_err_max_mm": finite(a.hand_still_err_max_mm),
                "step": a.step, "tick": a.tick,
            })
        })
    };
    let rig = d.rig.map(|r| {
        let f: Vec<[f64; 3]> = r.force_n.iter().map(|f| v3(*f)).collect();
        let fa: Vec<f64> = r.force_n.iter().map(|f| f.length()).collect();
        json!({
            "state": rig_state_name(r.state),
            "tick": r.tick,
            "rate_hz": r.rate_hz,
            "lateness_p99_s": r.lateness_p99_s,
            "force_n": f,
            "force_abs_n": fa,
            "tensions_n": r.tensions_n,
            "faults": r.faults,
            "device_errors": r.device_errors,
            "stale_ticks": r.stale_ticks,
            "clamped_ticks": r.clamped_ticks,
            "misses": r.misses,
            "age_s": d.t_s - d.rig_seen_t_s,
        })
    });
    let sample_age = d.t_s - d.sample_t_s;
    let link = if d.sample_t_s.is_nan() {
        "no hand samples yet"
    } else if sample_age > 0.1 {
        "stale: no hand samples"
    } else {
        "up"
    };
    let counters: Vec<Value> =
        counter_names.iter().zip(d.counters.iter()).map(|(n, v)| json!({"name": n, "value": v})).collect();
    json!({
        "type": "status",
        "t_s": d.t_s,
        "steps": d.steps,
        "step_rate_hz": d.step_rate_hz,
        "ended": d.ended,
        "rig": rig,
        "link": {"state": link, "sample_age_s": if d.sample_t_s.is_nan() { Value::Null } else { json!(sample_age) }},
        "counters": counters,
        "viewers": viewers,
        "frames": {"published": published, "skipped": skipped},
        "picture_age": {"screen": age(ages.0), "headset": age(ages.1)},
    })
    .to_string()
}
