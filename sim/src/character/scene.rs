//! The crowd scene file (`configs/scene-crowd.ron`): the world, the character body and keyframe
//! set it uses, the characters' settings, scenery, and where the crowd stands and wanders.
//!
//! Must never: accept a file it cannot build faithfully; every error names the file, line, column
//! and field and says what to change.

use std::path::Path;

use glam::{DMat3, DVec3};
use serde::Deserialize;
use spidar_config::{self as config, At, Bound, Checker};

use super::ai::Goal;
use super::crowd::{Crowd, CrowdBody, CrowdWorld};
use super::keyframe::{KeyframeSet, KEYFRAMES_HUMANOID_RON};
use super::CharacterParams;
use crate::collide::ShapePose;
use crate::desc::{parse_body, ContactDesc, ShapeFile};
use crate::spatial::quat_exp;
use crate::SimError;

pub const SCENE_CROWD_RON: &str = include_str!("../../../configs/scene-crowd.ron");
pub const BODY_CHARACTER_RON: &str = include_str!("../../../configs/body-character.ron");

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrowdLayout {
    pub count: usize,
    /// Rectangle the characters start in and wander to: (min x, min z, max x, max z), world (m).
    pub area_m: [f64; 4],
    pub walk_speed_m_per_s: f64,
    pub seed: u64,
    /// Characters that keep a spot instead of wandering (the front row a user reaches): where
    /// each stands (x, z) and which way it faces (deg, 0 facing +z); pushed away, they step back.
    #[serde(default)]
    pub stations: Vec<StationFile>,
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationFile {
    pub at_m: (f64, f64),
    pub heading_deg: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrowdSceneFile {
    pub version: u32,
    pub dt_s: f64,
    pub gravity_m_per_s2: DVec3,
    pub body: String,
    pub keyframes: String,
    pub contact: ContactDesc,
    pub character: CharacterParams,
    #[serde(default)]
    pub statics: Vec<ShapeFile>,
    pub crowd: CrowdLayout,
}

/// Most characters a crowd scene may have (wanderers and stations): far more than a 3 ms step
/// holds, and small enough that the buffers of the step stay reasonable.
pub const CROWD_MAX: usize = 1_000_000;
/// Largest coordinate of the crowd's area and stations (m).
pub const AREA_MAX_M: f64 = 1e5;
/// The spacing of the starting grid (m).
const START_SPACING_M: f64 = 1.2;

/// The built-in crowd scene.
pub fn builtin_crowd() -> Result<Crowd, SimError> {
    build_crowd(SCENE_CROWD_RON, "configs/scene-crowd.ron (built in)", |name| match name {
        "body-character.ron" => {
            Ok((BODY_CHARACTER_RON.to_string(), "configs/body-character.ron (built in)".into()))
        }
        "keyframes-humanoid.ron" => {
            Ok((KEYFRAMES_HUMANOID_RON.to_string(), "configs/keyframes-humanoid.ron (built in)".into()))
        }
        other => Err(SimError::Io { path: other.into(), message: "not a built-in file".into() }),
    })
}

/// Loads a crowd scene file and the body and keyframe files it names (relative to it).
pub fn load_crowd(path: &Path) -> Result<Crowd, SimError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SimError::Io { path: path.display().to_string(), message: e.to_string() })?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_else(|| ".".into());
    build_crowd(&text, &path.display().to_string(), |name| {
        let p = dir.join(name);
        let t = std::fs::read_to_string(&p)
            .map_err(|e| SimError::Io { path: p.display().to_string(), message: e.to_string() })?;
        Ok((t, p.display().to_string()))
    })
}

/// Builds a crowd from scene text; `resolve` gives (text, origin) of a named file. The file is
/// checked part by part (the world, the crowd's layout), then the body and keyframe set it names
/// are read, then the crowd is placed.
pub fn build_crowd(
    text: &str,
    origin: &str,
    mut resolve: impl FnMut(&str) -> Result<(String, String), SimError>,
) -> Result<Crowd, SimError> {
    let f: CrowdSceneFile = config::parse_kind(text, origin, config::FileKind::CrowdScene)?;
    let c = Checker::new(text, origin);
    c.version(f.version, 2)?;
    check_world(&c, &f)?;
    let cols = check_layout(&c, &f.crowd)?;
    let (btext, borigin) = resolve(&f.body)?;
    let body = CrowdBody::from_file(&parse_body(&btext, &borigin)?, &borigin)?;
    let (ktext, korigin) = resolve(&f.keyframes)?;
    let set = KeyframeSet::parse(&ktext, &korigin)?;
    c.ensure(set.behaviours.len() >= 2, &At::key("keyframes"), || {
        format!("{korigin}: the character AI needs two behaviours (walking and falling, standing up)")
    })?;
    Ok(place_crowd(f, body, set, cols))
}

/// The crowd's step.
const CROWD_DT_S: Bound = Bound::hard(
    "dt_s",
    0.0,
    0.01,
    "s",
    "the characters' controllers and contacts are tuned for steps of a few ms",
);
/// How fast the crowd wanders.
const WALK_SPEED_M_PER_S: Bound = Bound::hard("walk_speed_m_per_s", 0.0, 10.0, "m/s", "nobody walks faster");

/// The world: the step, gravity, the contacts, the characters' controller and AI settings and the
/// scenery.
fn check_world(c: &Checker, f: &CrowdSceneFile) -> Result<(), SimError> {
    c.positive(&At::key("dt_s"), f.dt_s, "s", "the world steps forward")?;
    c.within(&At::key("dt_s"), f.dt_s, &CROWD_DT_S)?;
    let g = f.gravity_m_per_s2;
    c.ensure(g.is_finite() && g.length() <= 1000.0 && g.y < 0.0, &At::key("gravity_m_per_s2"), || {
        format!("must be finite, pointing down (y < 0) and within 1000 m/s^2, got {g}")
    })?;
    let located =
        |part: &str, (key, m): (&'static str, String)| c.error(&At::new(format!("{part}.{key}"), key, 0), m);
    f.contact.check().map_err(|e| located("contact", e))?;
    f.character.controller.check().map_err(|e| located("character.controller", e))?;
    f.character.ai.check().map_err(|e| located("character.ai", e))?;
    for (i, s) in f.statics.iter().enumerate() {
        s.check().map_err(|m| c.error(&At::new(format!("statics[{i}].shape"), "shape", i), m))?;
    }
    Ok(())
}

/// Where the crowd stands: an area, a number of characters that fits in it on the starting
/// grid, a walking speed, and the stations. Returns the grid's columns.
fn check_layout(c: &Checker, l: &CrowdLayout) -> Result<usize, SimError> {
    let a = l.area_m;
    c.ensure(
        a.iter().all(|v| v.abs() <= AREA_MAX_M) && a[2] > a[0] && a[3] > a[1],
        &At::new("crowd.area_m", "area_m", 0),
        || {
            format!(
                "needs finite corners within {AREA_MAX_M} m with min x < max x and min z < max z, got {a:?}"
            )
        },
    )?;
    let count = At::new("crowd.count", "count", 0);
    let n_total = l.count.saturating_add(l.stations.len());
    c.count(&count, n_total, 1, CROWD_MAX, "characters (count plus stations)")?;
    let speed = At::new("crowd.walk_speed_m_per_s", "walk_speed_m_per_s", 0);
    c.positive(&speed, l.walk_speed_m_per_s, "m/s", "the crowd walks")?;
    c.within(&speed, l.walk_speed_m_per_s, &WALK_SPEED_M_PER_S)?;
    for (i, st) in l.stations.iter().enumerate() {
        let (x, z) = st.at_m;
        let ok = x.abs() <= AREA_MAX_M && z.abs() <= AREA_MAX_M && st.heading_deg.is_finite();
        c.ensure(ok, &At::new(format!("crowd.stations[{i}]"), "at_m", i), || {
            format!("position (within {AREA_MAX_M} m) and heading must be finite numbers")
        })?;
    }
    // Start on a grid over the area, START_SPACING_M apart at least (sizes compared as floats: a
    // huge area must not overflow the product).
    let cols = ((a[2] - a[0]) / START_SPACING_M).floor().max(1.0);
    let rows = ((a[3] - a[1]) / START_SPACING_M).floor().max(1.0);
    c.ensure(l.count as f64 <= cols * rows, &count, || {
        format!(
            "{} characters do not fit in the area {START_SPACING_M} m apart (at most {}); enlarge area_m",
            l.count,
            cols * rows
        )
    })?;
    Ok(cols as usize)
}

/// The crowd, placed: its scenery, the stations' characters, then the wanderers on the starting
/// grid of `cols` columns, each facing a random way.
fn place_crowd(f: CrowdSceneFile, body: CrowdBody, set: KeyframeSet, cols: usize) -> Crowd {
    let world = CrowdWorld::new(f.dt_s, f.gravity_m_per_s2, &f.contact, body.mass_kg);
    let mut c = Crowd::new(body, world, f.character, set);
    for s in &f.statics {
        let shape = s.shape.to_shape();
        let rot = DMat3::from_quat(quat_exp(s.rot_deg * (std::f64::consts::PI / 180.0)));
        c.statics.push((shape, ShapePose { pos_m: s.pos_m, rot }));
    }
    let a = f.crowd.area_m;
    c.seed(f.crowd.seed);
    c.wander = Some(a);
    c.wander_speed_m_per_s = f.crowd.walk_speed_m_per_s;
    for st in &f.crowd.stations {
        let heading_rad = st.heading_deg.to_radians();
        let point_m = DVec3::new(st.at_m.0, 0.0, st.at_m.1);
        let speed_m_per_s = f.crowd.walk_speed_m_per_s;
        c.add(st.at_m.0, st.at_m.1, heading_rad, Goal::Station { point_m, heading_rad, speed_m_per_s });
    }
    for i in 0..f.crowd.count {
        let x = a[0] + 0.5 * START_SPACING_M + (i % cols) as f64 * START_SPACING_M;
        let z = a[1] + 0.5 * START_SPACING_M + (i / cols) as f64 * START_SPACING_M;
        let h = c.random() * std::f64::consts::TAU;
        c.add(x, z, h, Goal::Stand);
    }
    c
}
