//! The crowd scene file (`configs/scene-crowd.ron`): the world, the character body and keyframe
//! set it uses, the characters' settings, scenery, and where the crowd stands and wanders.
//!
//! Must never: accept a file it cannot build faithfully; every error names the file, line, column
//! and field and says what to change.

use std::path::Path;

use glam::{DMat3, DVec3};
use serde::Deserialize;
use spidar_config as config;

use super::ai::Goal;
use super::crowd::{Crowd, CrowdBody, CrowdWorld};
use super::keyframe::{KeyframeSet, KEYFRAMES_HUMANOID_RON};
use super::CharacterParams;
use crate::collide::Pose;
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

fn err(text: &str, origin: &str, field: &str, key: &str, msg: String) -> SimError {
    SimError::Config(config::invalid(text, origin, field, key, 0, msg))
}

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

/// Builds a crowd from scene text; `resolve` gives (text, origin) of a named file.
pub fn build_crowd(
    text: &str,
    origin: &str,
    mut resolve: impl FnMut(&str) -> Result<(String, String), SimError>,
) -> Result<Crowd, SimError> {
    let f: CrowdSceneFile = config::parse_kind(text, origin, config::FileKind::CrowdScene)?;
    config::check_version(text, origin, f.version, 1)?;
    if !(f.dt_s > 0.0 && f.dt_s <= 0.01) {
        return Err(err(text, origin, "dt_s", "dt_s", format!("must be in (0, 0.01] s, got {}", f.dt_s)));
    }
    if !(f.contact.friction >= 0.0 && f.contact.slip_m_per_s > 0.0) {
        return Err(err(
            text,
            origin,
            "contact",
            "contact",
            "friction must be >= 0 and slip_m_per_s > 0".into(),
        ));
    }
    f.character
        .controller
        .check()
        .map_err(|(field, m)| err(text, origin, &format!("character.controller.{field}"), field, m))?;
    let a = f.crowd.area_m;
    if !(a[2] > a[0] && a[3] > a[1]) {
        return Err(err(
            text,
            origin,
            "crowd.area_m",
            "area_m",
            "needs min x < max x and min z < max z".into(),
        ));
    }
    let (btext, borigin) = resolve(&f.body)?;
    let body = CrowdBody::from_file(&parse_body(&btext, &borigin)?, &borigin)?;
    let (ktext, korigin) = resolve(&f.keyframes)?;
    let set = KeyframeSet::parse(&ktext, &korigin)?;
    if set.behaviours.len() < 2 {
        return Err(err(
            text,
            origin,
            "keyframes",
            "keyframes",
            format!("{korigin}: the character AI needs two behaviours (walking and falling, standing up)"),
        ));
    }
    let world = CrowdWorld::new(f.dt_s, f.gravity_m_per_s2, &f.contact, body.mass_kg);
    let mut c = Crowd::new(body, world, f.character, set);
    for s in &f.statics {
        let shape = s.shape.to_shape();
        let rot = DMat3::from_quat(quat_exp(s.rot_deg * (std::f64::consts::PI / 180.0)));
        c.statics.push((shape, Pose { pos_m: s.pos_m, rot }));
    }
    c.seed(f.crowd.seed);
    c.wander = Some(a);
    c.wander_speed_m_per_s = f.crowd.walk_speed_m_per_s;
    // Start on a grid over the area, 1.2 m apart at least, facing random ways.
    let cols = ((a[2] - a[0]) / 1.2).floor().max(1.0) as usize;
    let rows = ((a[3] - a[1]) / 1.2).floor().max(1.0) as usize;
    if f.crowd.count > cols * rows {
        return Err(err(
            text,
            origin,
            "crowd.count",
            "count",
            format!(
                "{} characters do not fit in the area 1.2 m apart (at most {}); enlarge area_m",
                f.crowd.count,
                cols * rows
            ),
        ));
    }
    for i in 0..f.crowd.count {
        let x = a[0] + 0.6 + (i % cols) as f64 * 1.2;
        let z = a[1] + 0.6 + (i / cols) as f64 * 1.2;
        let h = c.random() * std::f64::consts::TAU;
        c.add(x, z, h, Goal::Stand);
    }
    Ok(c)
}
