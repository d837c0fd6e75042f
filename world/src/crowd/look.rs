//! The crowd scene's look: every character as its drawn figure (the 16-joint humanoid of its
//! keyframe set, posed as the world interpolates it and stood on its feet: the figure that lies on
//! the body, `spidar_sim::character::drawn`), tinted by its control state (balance, fall, down,
//! stand up).

use std::sync::Arc;

use glam::DVec3;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::drawn::{for_each_figure, Figures};

use super::CrowdScene;
use crate::look::{put_character, quat, Look, LookCrowd, LookJoint, LookShape, Poses};

const POLICIES: [Policy; 4] = [Policy::Balance, Policy::Fall, Policy::Down, Policy::StandUp];
const STATE_COLOURS: [[u8; 3]; 4] = [[80, 165, 95], [235, 160, 35], [200, 55, 55], [80, 135, 225]];

/// The counters the heads-up display shows, in the order [`pose`] writes them.
pub(crate) const COUNTERS: [&str; 3] = ["characters", "not balancing", "pushed (N s)"];

pub(crate) fn look(scene: &CrowdScene) -> Look {
    let c = &scene.crowd;
    let joints = c
        .set
        .joints
        .iter()
        .map(|j| LookJoint { name: j.name.clone(), parent: j.parent, offset_m: j.offset_m })
        .collect();
    let statics = c
        .statics
        .iter()
        .enumerate()
        .map(|(i, (shape, p))| {
            let s = LookShape {
                name: format!("scenery/{i}"),
                shape: *shape,
                colour: [120, 120, 115],
                proxy: None,
            };
            (s, p.pos_m, quat(&p.rot))
        })
        .collect();
    Look {
        shapes: Vec::new(),
        statics,
        labels: Vec::new(),
        counters: COUNTERS.iter().map(|c| c.to_string()).collect(),
        crowd: Some(LookCrowd {
            characters: c.len(),
            joints,
            states: POLICIES.iter().map(|p| p.name().to_string()).collect(),
            colours: STATE_COLOURS.to_vec(),
            proxy_body_is_character: true,
            figures: Some(Arc::new(Figures::of(c))),
        }),
        link_offset_m: DVec3::ZERO,
        focus_m: DVec3::new(0.0, 1.0, -2.0),
        humanoids: Vec::new(),
        eyes: Vec::new(),
        gazes: Vec::new(),
    }
}

pub(crate) fn pose(scene: &CrowdScene, out: &mut Poses<'_>) {
    let c = &scene.crowd;
    let not_balancing = c.chars.iter().filter(|ch| ch.control.policy != Policy::Balance).count();
    let character = |i: usize, joints: &[DVec3], slot: &mut [f32]| {
        let policy = c.chars[i].control.policy;
        let state = POLICIES.iter().position(|p| *p == policy).unwrap_or(0);
        let b = &c.bodies[i];
        put_character(slot, b.pos_m, b.rot, joints, state, 0.0);
    };
    let now = out.figures_now();
    let (slots, per) = out.characters_mut();
    if now {
        // The figures are computed here, at the view's (or recorder's) rate: a step computes none.
        for_each_figure(c, slots, per, character);
    } else if per > 0 {
        // Bodies only: the view's (or recorder's) thread adds the figures (`Scene::figure_states`).
        for (i, slot) in slots.chunks_exact_mut(per).take(c.len()).enumerate() {
            character(i, &[], slot);
        }
    }
    out.counter(0, c.len() as f64);
    out.counter(1, not_balancing as f64);
    out.counter(2, scene.impulse_total_n_s.length());
}
