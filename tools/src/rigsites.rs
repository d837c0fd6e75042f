//! Where the shipped scenes ask the hands to push, for `spidar rig map`: the walls scene's walls
//! and balls (the point of each nearest the hand's home, where its fist first touches it) and the
//! boxing scene's targets (the virtual human's head, chest and gloves in its guard: the aim points
//! of the scripted user, `spidar_runtime::scripts::aim_points_rig`). All in the rig frame.
//!
//! Must never: invent a contact the scene does not have (each site is read from the scene's own
//! file or body), or leave a scene the user named out silently (an unknown name is an error).

use std::path::Path;

use glam::DVec3;
use spidar_calib::rigmap::Site;
use spidar_rt::Rig;
use spidar_world::walls::{SceneFile, DEFAULT_SCENE_NAME, DEFAULT_SCENE_RON};

const TAKES: &str =
    "--scenes takes boxing, walls, a boxer file or a walls scene file (comma separated), or none";

/// The sites of the scenes named (`boxing`, `walls`, or a boxer or walls scene file).
pub fn scene_sites(rig: &Rig, scenes: &[String]) -> anyhow::Result<Vec<Site>> {
    let mut out = Vec::new();
    for name in scenes.iter().map(|s| s.trim()).filter(|s| !s.is_empty() && *s != "none") {
        match name {
            "boxing" => out.extend(boxing_sites(rig, &spidar_sim::boxer::BoxerParams::default(), "boxing")?),
            "walls" => {
                let file = spidar_config::parse_kind(
                    DEFAULT_SCENE_RON,
                    DEFAULT_SCENE_NAME,
                    spidar_config::FileKind::WallsScene,
                )?;
                out.extend(walls_sites(rig, &file, "walls"));
            }
            path => {
                let p = Path::new(path);
                if !p.is_file() {
                    anyhow::bail!("unknown scene '{path}' (and no such file): {TAKES}");
                }
                let (_, text) = spidar_config::load_file::<serde::de::IgnoredAny>(p)?;
                match spidar_config::peek_kind(&text, path)? {
                    spidar_config::FileKind::Boxer => {
                        out.extend(boxing_sites(rig, &spidar_sim::boxer::load_boxer(p)?, path)?)
                    }
                    spidar_config::FileKind::WallsScene => {
                        // Validated as the scene itself loads it, then read for its shapes.
                        spidar_world::walls::WallsScene::load(p)?;
                        let (file, _) = spidar_config::load_file_kind::<SceneFile>(
                            p,
                            spidar_config::FileKind::WallsScene,
                        )?;
                        out.extend(walls_sites(rig, &file, path));
                    }
                    other => anyhow::bail!(
                        "{path}: this is {}, not a boxing or walls scene: {TAKES}",
                        other.what()
                    ),
                }
            }
        }
    }
    Ok(out)
}

/// Per hand, the grip's centre where it first touches each plane and ball: the shape's point
/// nearest the home, moved out by the grip's radius (rig frame).
fn walls_sites(rig: &Rig, file: &SceneFile, scene: &str) -> Vec<Site> {
    let mut out = Vec::new();
    for (h, hr) in rig.hands.iter().enumerate() {
        let home_w = rig.rig_to_world.point(hr.home_m);
        let r = hr.grip_radius_m;
        for p in &file.planes {
            let n = DVec3::from_array(p.normal).normalize();
            let at = home_w - n * n.dot(home_w - DVec3::from_array(p.point_m)) + n * r;
            out.push(Site {
                label: format!("{scene}: {}", p.label),
                hand: h,
                point_m: rig.rig_to_world.point_to_rig(at),
            });
        }
        for s in &file.spheres {
            let c = DVec3::from_array(s.centre_m);
            let at = c + (home_w - c).normalize_or(DVec3::Y) * (s.radius_m + r);
            out.push(Site {
                label: format!("{scene}: {}", s.label),
                hand: h,
                point_m: rig.rig_to_world.point_to_rig(at),
            });
        }
    }
    out
}

/// Per hand, the virtual human's head, chest and gloves in its guard (the scripted user's aims).
fn boxing_sites(
    rig: &Rig,
    params: &spidar_sim::boxer::BoxerParams,
    scene: &str,
) -> anyhow::Result<Vec<Site>> {
    const NAMES: [&str; 6] = ["head", "chest", "left glove", "right glove", "left chest", "right chest"];
    let aims = spidar_runtime::scripts::aim_points_rig(rig, params)?;
    Ok((0..rig.hands.len())
        .flat_map(|h| {
            aims.iter().zip(NAMES).take(4).map(move |(p, n)| Site {
                label: format!("{scene}: {n}"),
                hand: h,
                point_m: *p,
            })
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_walls_sites_lie_on_the_walls_the_grip_radius_out() {
        let rig = Rig::default_rig();
        let sites = scene_sites(&rig, &["walls".into()]).unwrap();
        // Two planes and a ball per hand.
        assert_eq!(sites.len(), 2 * 3, "{sites:?}");
        for s in &sites {
            let hr = &rig.hands[s.hand];
            let w = rig.rig_to_world.point(s.point_m);
            match s.label.as_str() {
                "walls: front wall" => assert!((w.z - (-0.30 + hr.grip_radius_m)).abs() < 1e-9, "{w}"),
                "walls: table" => assert!((w.y - (0.90 + hr.grip_radius_m)).abs() < 1e-9, "{w}"),
                "walls: ball" => {
                    let d = (w - DVec3::new(0.0, 1.35, -0.12)).length();
                    assert!((d - (0.08 + hr.grip_radius_m)).abs() < 1e-9, "{d}");
                }
                other => panic!("unexpected site {other}"),
            }
        }
        assert!(scene_sites(&rig, &["nowhere".into()]).unwrap_err().to_string().contains("--scenes takes"));
    }
}
