//! The boxing scene's look: the avatar and the virtual human as their collision shapes (blue and
//! red, gloves darker), the virtual human's behaviour per hand and body (Fig. 5) as labels, the
//! contacts between the two bodies, the bout's counters, and where the virtual human looks (its
//! gaze: the page turns its eyes there).

use glam::DVec3;
use spidar_sim::boxer::{Behaviour, BodyBehaviour, AVATAR, BOXER};
use spidar_sim::impulse::proxy_id;

use super::BoxingScene;
use crate::look::{
    quat, DrawnContact, Look, LookBodyJoint, LookGaze, LookHumanoid, LookLabel, LookSegment, LookShape, Poses,
};

pub(crate) const AVATAR_COLOUR: [u8; 3] = [70, 120, 215];
pub(crate) const AVATAR_GLOVE: [u8; 3] = [30, 60, 150];
pub(crate) const VH_COLOUR: [u8; 3] = [205, 70, 55];
pub(crate) const VH_GLOVE: [u8; 3] = [140, 25, 20];
pub(crate) const FLOOR_COLOUR: [u8; 3] = [120, 120, 115];
const SKIN: [u8; 3] = [224, 172, 138];

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
        humanoids: vec![
            humanoid(m, BOXER, "virtual human", VH_COLOUR),
            humanoid(m, AVATAR, "avatar", AVATAR_COLOUR),
        ],
        eyes: Vec::new(),
        gazes: vec![LookGaze { name: "virtual human".into(), head_shape: shape_of(w.vh.head) }],
    }
}

/// An articulated upper body as a person: each body's (first) shape a segment, each joint where
/// the model puts it: at the child body's origin, which sits at `x_tree`'s translation in its
/// parent's frame (both moved into the shapes' own frames).
pub(crate) fn humanoid(
    m: &spidar_sim::model::Model,
    articulation: usize,
    name: &str,
    colour: [u8; 3],
) -> LookHumanoid {
    use spidar_sim::model::{Part, Side};
    let shape_of = |body: usize| m.shapes.iter().position(|s| s.body == Some(body));
    // A point of a body's frame in its shape's frame.
    let in_shape = |k: usize, p_body: DVec3| {
        let l = &m.shapes[k].local;
        l.rot.transpose() * (p_body - l.pos_m)
    };
    let bodies = m.articulations[articulation].bodies.clone();
    let segments = bodies
        .clone()
        .filter_map(|b| {
            let part = match m.bodies[b].part {
                Part::Waist => "waist",
                Part::Chest => "chest",
                Part::Head => "head",
                Part::UpperArm => "upper_arm",
                Part::Forearm => "forearm",
                Part::Hand => "hand",
                _ => return None,
            };
            let side = match m.bodies[b].side {
                Side::Left => -1,
                Side::Right => 1,
                Side::Centre => 0,
            };
            Some(LookSegment { shape: shape_of(b)?, part: part.into(), side })
        })
        .collect();
    let joints = bodies
        .filter_map(|b| {
            let body = &m.bodies[b];
            let p = body.parent?;
            let (ps, cs) = (shape_of(p)?, shape_of(b)?);
            Some(LookBodyJoint {
                name: body.name.clone(),
                parent_shape: ps,
                child_shape: cs,
                at_parent_m: in_shape(ps, body.x_tree.r),
                at_child_m: in_shape(cs, DVec3::ZERO),
            })
        })
        .collect();
    LookHumanoid { name: name.into(), segments, joints, colour, skin: SKIN, forward: DVec3::NEG_Z }
}

/// Every shape's pose and the contacts between bodies (the parts touching flash): the boxing and
/// the spar scenes' bodies are drawn alike.
pub(crate) fn pose_shapes_and_contacts(ws: &spidar_sim::Workspace, out: &mut Poses<'_>) {
    for (k, p) in ws.shape_pose.iter().enumerate() {
        out.shape(k, p.pos_m, quat(&p.rot));
    }
    for c in &ws.contacts {
        // Contacts between bodies (the floor is out of reach of these bodies anyway).
        if c.body_a.is_none() || c.body_b.is_none() {
            continue;
        }
        let f = c.force_n.length();
        out.shape_force(c.shape_a as usize, f);
        out.shape_force(c.shape_b as usize, f);
        out.contact(DrawnContact { point_m: c.point_m, force_n: c.force_n });
    }
}

pub(crate) fn pose(scene: &BoxingScene, out: &mut Poses<'_>) {
    let w = &scene.world;
    pose_shapes_and_contacts(&w.ws, out);
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
    let g = scene.gaze();
    out.gaze(0, g.eye_m, g.dir, g.at_m);
    let counts =
        [mind.hits_taken, mind.hits_given, mind.attacks, mind.avoidances, mind.blocks, mind.predictions];
    for (i, v) in counts.iter().enumerate() {
        out.counter(i, *v as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::look::GAZE_FLOATS;
    use crate::Scene;
    use spidar_msg::{HandSample, HandState};

    /// The joints the look puts on the segments, carried by the shapes' poses, are where the
    /// simulation has them (the child body's origin), from either side, while the bodies move.
    #[test]
    fn the_humanoids_joints_ride_on_the_shapes_to_the_simulated_joints() {
        let mut scene = BoxingScene::new(Default::default()).unwrap();
        let look = scene.look();
        assert_eq!(look.humanoids.len(), 2);
        for h in &look.humanoids {
            assert_eq!(h.segments.len(), 9, "{}: nine solids", h.name);
            assert_eq!(h.joints.len(), 8, "{}: eight joints below the base", h.name);
        }
        let mut hands = [HandState { valid: true, ..Default::default() }; 2];
        let mut worst: f64 = 0.0;
        for k in 0..600 {
            // The user's right hand jabs out and back, so the avatar's arm moves.
            let s = (k as f64 * 0.02).sin().abs();
            hands[1].pos_world_m = DVec3::new(0.15, 1.4, -0.3 - 0.3 * s);
            hands[0].pos_world_m = DVec3::new(-0.15, 1.4, -0.3);
            let sample = HandSample { hands, t_s: k as f64 * 0.003, ..Default::default() };
            scene.step(k as f64 * 0.003, std::slice::from_ref(&sample));
            let w = &scene.world;
            for h in &look.humanoids {
                for j in &h.joints {
                    let body = w.model.shapes[j.child_shape].body.unwrap();
                    let truth = w.ws.point_world(body, DVec3::ZERO);
                    for (shape, at) in [(j.parent_shape, j.at_parent_m), (j.child_shape, j.at_child_m)] {
                        let p = &w.ws.shape_pose[shape];
                        worst = worst.max((p.pos_m + p.rot * at - truth).length());
                    }
                }
            }
        }
        assert!(worst < 1e-6, "a joint carried by a shape is {worst} m from the simulation's");
    }

    /// One step of [`gaze_bout`]: the fist attended (if any), and the published gaze's point
    /// looked at: its distance to the attended fist as seen, the angle between the published
    /// direction and that fist (degrees), its distance to the avatar's upper chest.
    struct GazeStep {
        k: usize,
        attended: Option<usize>,
        to_fist_m: f64,
        fist_deg: f64,
        to_chest_m: f64,
    }

    /// A bout of 2.7 s read through the view's frames: the user's hands at rest for 1.2 s, then
    /// the right one jabs out and back at the virtual human's head (its own attacks off, so
    /// every motion of the avatar's fists is the user's); with the eyes turning at
    /// `gaze_deg_per_s` (the default skill's when `None`).
    fn gaze_bout(gaze_deg_per_s: Option<f64>) -> Vec<GazeStep> {
        use crate::view::{json, Layout};
        let mut scene = BoxingScene::new(Default::default()).unwrap();
        scene.world.mind.params.attack_per_step = 0.0;
        if let Some(r) = gaze_deg_per_s {
            scene.world.mind.perception.skill.gaze_deg_per_s = r;
        }
        let look = scene.look();
        let layout = Layout::for_look(&look);
        let desc: serde_json::Value =
            serde_json::from_str(&json::scene("boxing", &look, &layout, 60.0)).unwrap();
        let head_shape = desc["gaze"][0]["head_shape"].as_u64().unwrap() as usize;
        assert_eq!(scene.world.model.shapes[head_shape].body, Some(scene.world.vh.head));
        assert_eq!(desc["layout"]["gaze_at"].as_u64(), Some(layout.gaze_at as u64));
        let mut buf = vec![0.0f32; layout.max_words];
        let mut counters = [0.0; 8];
        let mut hands = [HandState { valid: true, ..Default::default() }; 2];
        let mut out = Vec::new();
        for k in 0..900 {
            let s = if k < 400 { 0.0 } else { ((k - 400) as f64 * 0.012).sin().abs() };
            hands[1].pos_world_m = DVec3::new(0.15, 1.45, -0.3 - 0.35 * s);
            hands[0].pos_world_m = DVec3::new(-0.15, 1.4, -0.3);
            let sample = HandSample { hands, t_s: k as f64 * 0.003, ..Default::default() };
            scene.step(k as f64 * 0.003, std::slice::from_ref(&sample));
            let mut contacts = 0;
            scene.pose(&mut layout.poses(&mut buf, &mut counters, &mut contacts, true));
            let g = &buf[layout.gaze_at..layout.gaze_at + GAZE_FLOATS];
            let v = |i: usize| DVec3::new(g[i] as f64, g[i + 1] as f64, g[i + 2] as f64);
            let (eye, dir, at) = (v(0), v(3), v(6));
            let w = &scene.world;
            let p = &w.mind.perception;
            assert!((eye - w.com(w.vh.head)).length() < 1e-4, "the eyes are in the head");
            assert!((dir.length() - 1.0).abs() < 1e-5 && ((at - eye).normalize() - dir).length() < 1e-4);
            let fist = p.seen[p.attended.unwrap_or(1)].pos_m;
            out.push(GazeStep {
                k,
                attended: p.attended,
                to_fist_m: (at - fist).length(),
                fist_deg: dir.angle_between(fist - eye).to_degrees(),
                to_chest_m: (at - (w.com(w.avatar.head) + w.com(w.avatar.chest)) * 0.5).length(),
            });
        }
        out
    }

    /// The frame's gaze is the virtual human's vision model's: from its head, onto the user's
    /// fist it perceives closing on it (the right one, which jabs), where the fist was seen (its
    /// perception delay late); at rest on the avatar's upper chest. With eyes that turn at once,
    /// the published point is the seen fist itself.
    #[test]
    fn the_published_gaze_follows_the_perceived_threatening_fist() {
        // The avatar's hands settle onto the user's from where they start in the first 0.9 s.
        let steps = gaze_bout(Some(1.0e6));
        let (rest, jab) = (&steps[300..400], &steps[400..]);
        assert!(rest.iter().all(|s| s.attended.is_none() && s.to_chest_m < 0.01), "at rest: the upper chest");
        let attended: Vec<&GazeStep> = jab.iter().filter(|s| s.attended.is_some()).collect();
        assert!(attended.len() > 30, "the jab is seen closing: {} steps", attended.len());
        for s in &attended {
            assert_eq!(s.attended, Some(1), "step {}: the jabbing (right) fist is attended", s.k);
            // The seen fist moves between the vision model's step and the frame: under a step's.
            assert!(s.to_fist_m < 0.02, "step {}: {} m off the fist as seen", s.k, s.to_fist_m);
        }
    }

    /// With the default skill's eyes (turning at 400 degrees a second) the published gaze
    /// turns onto the attended fist: over every spell of attention of 60 ms or more (24 degrees
    /// of turn) the angle to it shrinks by at least 10 degrees (the fist moves too).
    #[test]
    fn the_published_gaze_turns_onto_the_fist_at_the_skills_rate() {
        let steps = gaze_bout(None);
        let mut spells = 0;
        for spell in steps[400..].split(|s| s.attended.is_none()).filter(|s| s.len() >= 20) {
            spells += 1;
            let (first, last) = (spell[0].fist_deg, spell[spell.len() - 1].fist_deg);
            assert!(
                last < first - 10.0,
                "step {}: the angle went from {first} to {last} degrees",
                spell[0].k
            );
        }
        assert!(spells >= 2, "each jab is attended: {spells} spells");
    }
}
