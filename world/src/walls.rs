//! The rig-check scene: stiff planes and balls, as contact proxies, sent every step.
//!
//! Used after assembling a rig: press each grip into each wall and feel k x depth, squeeze the
//! ball from both sides. The ball may move (sinusoidally) so the rt-loop's extrapolation of moving
//! proxies is exercised. The scenery is immovable: the impulses the hands apply to it only tell
//! the status which shapes are being touched.

use std::path::Path;

use glam::DVec3;
use serde::Deserialize;
use spidar_config::{self as config, ConfigError};
use spidar_msg::{ContactModel, HandSample, Proxy, ProxyId, ProxyShape};

use crate::Scene;

pub const DEFAULT_SCENE_RON: &str = include_str!("../../configs/scene-walls.ron");
pub const DEFAULT_SCENE_NAME: &str = "configs/scene-walls.ron (built in)";

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Format version; must be 1.
    pub version: u32,
    /// Free text.
    pub name: String,
    /// Time between contact models.
    pub step_s: f64,
    pub planes: Vec<PlaneFile>,
    pub spheres: Vec<SphereFile>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlaneFile {
    pub label: String,
    /// A point on the plane (world frame).
    pub point_m: [f64; 3],
    /// Outward normal: the solid is on the other side.
    pub normal: [f64; 3],
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SphereFile {
    pub label: String,
    pub centre_m: [f64; 3],
    pub radius_m: f64,
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    /// Sinusoidal motion of the centre.
    #[serde(default)]
    pub motion: Option<MotionFile>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MotionFile {
    pub amplitude_m: [f64; 3],
    pub period_s: f64,
}

/// The walls scene.
pub struct WallsScene {
    name: String,
    step_s: f64,
    file: SceneFile,
    seq: u64,
    /// Which proxies the hands touched in the newest sample.
    touched: Vec<bool>,
}

impl WallsScene {
    pub fn builtin() -> WallsScene {
        WallsScene::from_str(DEFAULT_SCENE_RON, DEFAULT_SCENE_NAME).expect("built-in scene is valid (tested)")
    }

    pub fn load(path: &Path) -> Result<WallsScene, ConfigError> {
        let (file, text) = config::load_file_kind::<SceneFile>(path, config::FileKind::WallsScene)?;
        WallsScene::validate(file, &text, &path.display().to_string())
    }

    pub fn from_str(text: &str, origin: &str) -> Result<WallsScene, ConfigError> {
        let file = config::parse_kind::<SceneFile>(text, origin, config::FileKind::WallsScene)?;
        WallsScene::validate(file, text, origin)
    }

    fn validate(file: SceneFile, text: &str, origin: &str) -> Result<WallsScene, ConfigError> {
        let bad = |field: String, key: &str, occ: usize, msg: &str| {
            config::invalid(text, origin, &field, key, occ, msg.into())
        };
        if file.version != 1 {
            return Err(bad("version".into(), "version", 0, "this build reads scene files of version 1"));
        }
        if !(file.step_s.is_finite() && (0.0005..=0.1).contains(&file.step_s)) {
            return Err(bad("step_s".into(), "step_s", 0, "must be within 0.5 .. 100 ms"));
        }
        if file.planes.len() + file.spheres.len() > spidar_msg::MAX_PROXIES {
            return Err(bad(
                "planes".into(),
                "planes",
                0,
                "too many shapes: a contact model carries at most 16 proxies",
            ));
        }
        let gains_ok = |k: f64, d: f64| k.is_finite() && k >= 0.0 && d.is_finite() && d >= 0.0;
        for (i, p) in file.planes.iter().enumerate() {
            let n = DVec3::from_array(p.normal);
            if !(n.is_finite() && n.length() > 1e-6) {
                return Err(bad(format!("planes[{i}].normal"), "normal", i, "must be a non-zero direction"));
            }
            if !p.point_m.iter().all(|v| v.is_finite()) {
                return Err(bad(format!("planes[{i}].point_m"), "point_m", i, "must be finite"));
            }
            if !gains_ok(p.k_n_per_m, p.d_n_s_per_m) {
                return Err(bad(
                    format!("planes[{i}].k_n_per_m"),
                    "k_n_per_m",
                    i,
                    "gains must be finite and >= 0",
                ));
            }
        }
        let np = file.planes.len();
        for (i, s) in file.spheres.iter().enumerate() {
            if !(s.radius_m.is_finite() && s.radius_m > 0.0 && s.centre_m.iter().all(|v| v.is_finite())) {
                return Err(bad(
                    format!("spheres[{i}].radius_m"),
                    "radius_m",
                    i,
                    "must be a positive radius at a finite centre",
                ));
            }
            if !gains_ok(s.k_n_per_m, s.d_n_s_per_m) {
                return Err(bad(
                    format!("spheres[{i}].k_n_per_m"),
                    "k_n_per_m",
                    np + i,
                    "gains must be finite and >= 0",
                ));
            }
            if let Some(m) = &s.motion {
                if !(m.period_s.is_finite()
                    && m.period_s > 0.0
                    && m.amplitude_m.iter().all(|v| v.is_finite()))
                {
                    return Err(bad(
                        format!("spheres[{i}].motion"),
                        "period_s",
                        i,
                        "motion needs a positive period and a finite amplitude",
                    ));
                }
            }
        }
        let n = file.planes.len() + file.spheres.len();
        Ok(WallsScene { name: file.name.clone(), step_s: file.step_s, file, seq: 0, touched: vec![false; n] })
    }

    /// The model at time `t_s` (positions and velocities of moving balls at that time).
    pub fn model_at(&self, t_s: f64, seq: u64) -> ContactModel {
        let mut m = ContactModel { seq, stamp_s: t_s, ..Default::default() };
        for (i, p) in self.file.planes.iter().enumerate() {
            m.push(Proxy {
                id: ProxyId { body: 0, part: i as u16 },
                shape: ProxyShape::Plane {
                    point_m: DVec3::from_array(p.point_m),
                    normal: DVec3::from_array(p.normal).normalize(),
                },
                k_n_per_m: p.k_n_per_m,
                d_n_s_per_m: p.d_n_s_per_m,
                vel_m_per_s: DVec3::ZERO,
                hand_mask: Proxy::BOTH_HANDS,
            });
        }
        for (i, s) in self.file.spheres.iter().enumerate() {
            let (mut c, mut v) = (DVec3::from_array(s.centre_m), DVec3::ZERO);
            if let Some(mo) = &s.motion {
                let w = std::f64::consts::TAU / mo.period_s;
                let a = DVec3::from_array(mo.amplitude_m);
                c += a * (w * t_s).sin();
                v = a * w * (w * t_s).cos();
            }
            m.push(Proxy {
                id: ProxyId { body: 1, part: i as u16 },
                shape: ProxyShape::Sphere { centre_m: c, radius_m: s.radius_m },
                k_n_per_m: s.k_n_per_m,
                d_n_s_per_m: s.d_n_s_per_m,
                vel_m_per_s: v,
                hand_mask: Proxy::BOTH_HANDS,
            });
        }
        m
    }

    fn label(&self, i: usize) -> &str {
        let np = self.file.planes.len();
        if i < np {
            &self.file.planes[i].label
        } else {
            &self.file.spheres[i - np].label
        }
    }
}

impl Scene for WallsScene {
    fn name(&self) -> &str {
        &self.name
    }

    fn step_s(&self) -> f64 {
        self.step_s
    }

    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        if let Some(last) = samples.last() {
            for (t, imp) in self.touched.iter_mut().zip(last.proxy_impulse_n_s.iter()) {
                *t = imp.length_squared() > 0.0;
            }
        }
        self.seq += 1;
        self.model_at(t_s, self.seq)
    }

    fn status(&self) -> String {
        let touching: Vec<&str> =
            (0..self.touched.len()).filter(|&i| self.touched[i]).map(|i| self.label(i)).collect();
        if touching.is_empty() {
            "touching nothing".into()
        } else {
            format!("touching {}", touching.join(", "))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scene_has_two_walls_and_a_moving_ball() {
        let s = WallsScene::builtin();
        let m = s.model_at(1.0, 1);
        assert_eq!(m.proxies().len(), 3);
        match m.proxies()[2].shape {
            ProxyShape::Sphere { centre_m, .. } => assert!((centre_m.y - (1.35 + 0.03)).abs() < 1e-9),
            _ => panic!("ball expected"),
        }
        assert!(m.proxies()[2].vel_m_per_s.y.abs() < 1e-9, "at the top of its travel the ball is still");
    }

    #[test]
    fn bad_plane_normal_names_the_field() {
        let text = DEFAULT_SCENE_RON.replacen("normal: (0.0, 0.0, 1.0)", "normal: (0.0, 0.0, 0.0)", 1);
        let e = WallsScene::from_str(&text, "s.ron").err().unwrap();
        assert_eq!(e.field, "planes[0].normal");
        assert!(e.line > 0);
    }
}
