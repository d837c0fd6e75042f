//! The boxing scene's look: the avatar and the virtual human as their collision shapes (blue and
//! red, gloves darker), the virtual human's behaviour per hand and body (Fig. 5) as labels, the
//! contacts between the two bodies, and the bout's counters.

use glam::DVec3;
use spidar_sim::boxer::{Behaviour, BodyBehaviour, AVATAR, BOXER};
use spidar_sim::impulse::proxy_id;

use super::BoxingScene;
use crate::look::{quat, DrawnContact, Look, LookLabel, LookShape, Poses};

const AVATAR_COLOUR: [u8; 3] = [70, 120, 215];
const AVATAR_GLOVE: [u8; 3] = [30, 60, 150];
const VH_COLOUR: [u8; 3] = [205, 70, 55];
const VH_GLOVE: [u8; 3] = [140, 25, 20];
const FLOOR_COLOUR: [u8; 3] = [120, 120, 115];

/// The counters the heads-up display shows, in the order [`pose`] writes them.
pub(crate) const COUNTERS: [&str; 6] =
    ["hits taken", "hits given", "attacks", "avoidances", "blocks", "predictions"];

pub(crate) fn look(scene: &BoxingScene) -> Look {
    let w = &scene.world;
    let m = &w.model;
    // Every model shape, statics included, so a look index is a model shape index.
    let shapes = m
        .shapes
        .iter()
        .map(|s| {
            let (actor, colour, glove, proxy) = match s.body {
                Some(b) if m.bodies[b].articulation == BOXER => {
                    ("virtual human", VH_COLOUR, VH_GLOVE, Some(proxy_id(m, b)))
                }
                Some(b) if m.bodies[b].articulation == AVATAR => {
                    ("avatar", AVATAR_COLOUR, AVATAR_GLOVE, None)
                }
                Some(_) => ("body", AVATAR_COLOUR, AVATAR_COLOUR, None),
                None => ("scenery", FLOOR_COLOUR, FLOOR_COLOUR, None),
            };
            let is_glove = s.body.is_some_and(|b| w.avatar.hand.contains(&b) || w.vh.hand.contains(&b));
            LookShape {
                // The model names shapes `actor.part`.
                name: format!("{actor}/{}", s.name.rsplit('.').next().unwrap_or(&s.name)),
                shape: s.shape,
                colour: if is_glove { glove } else { colour },
                proxy,
            }
        })
        .collect();
    let shape_of = |body: usize| m.shapes.iter().position(|s| s.body == Some(body)).unwrap_or(0);
    let hand_states = vec!["guard".to_string(), "attack".into(), "block".into()];
    let labels = vec![
        LookLabel { name: "left hand".into(), shape: shape_of(w.vh.hand[0]), states: hand_states.clone() },
        LookLabel { name: "right hand".into(), shape: shape_of(w.vh.hand[1]), states: hand_states },
        LookLabel {
            name: "body".into(),
            shape: shape_of(w.vh.head),
            states: vec!["guard".into(), "avoid".into()],
        },
    ];
    Look {
        shapes,
        statics: Vec::new(),
        labels,
        counters: COUNTERS.iter().map(|c| c.to_string()).collect(),
        crowd: None,
        link_offset_m: w.params.user_offset_m,
        focus_m: w.com(w.vh.head) - DVec3::new(0.0, 0.1, 0.0),
    }
}

pub(crate) fn pose(scene: &BoxingScene, out: &mut Poses<'_>) {
    let w = &scene.world;
    for (k, p) in w.ws.shape_pose.iter().enumerate() {
        out.shape(k, p.pos_m, quat(&p.rot));
    }
    for c in &w.ws.contacts {
        // Contacts between bodies (the floor is out of reach of these bodies anyway).
        if c.body_a.is_none() || c.body_b.is_none() {
            continue;
        }
        let f = c.force_n.length();
        out.shape_force(c.shape_a as usize, f);
        out.shape_force(c.shape_b as usize, f);
        out.contact(DrawnContact { point_m: c.point_m, force_n: c.force_n });
    }
    let mind = &w.mind;
    for h in 0..2 {
        out.label(
            h,
            match mind.hands[h] {
                Behaviour::Standby => 0,
                Behaviour::Attack => 1,
                Behaviour::Block => 2,
            },
        );
    }
    out.label(2, usize::from(mind.body == BodyBehaviour::Avoidance));
    let counts =
        [mind.hits_taken, mind.hits_given, mind.attacks, mind.avoidances, mind.blocks, mind.predictions];
    for (i, v) in counts.iter().enumerate() {
        out.counter(i, *v as f64);
    }
}
