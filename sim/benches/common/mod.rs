//! The crowd the crowd bench and the `crowd_cpu` example measure: `n` characters on a 2 m grid,
//! wandering over it, after 1 s of warm-up.

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::CharacterParams;
use spidar_sim::collide::{Pose, Shape};
use spidar_sim::desc::{parse_body, ContactDesc, Gain};

pub fn wandering_crowd(n: usize) -> Crowd {
    let body = CrowdBody::from_file(
        &parse_body(include_str!("../../../configs/body-character.ron"), "body").unwrap(),
        "body",
    )
    .unwrap();
    let contact = ContactDesc {
        stiffness: Gain::Abs(4e5),
        damping: Gain::Abs(4000.0),
        friction: 0.0,
        slip_m_per_s: 0.01,
    };
    let world = CrowdWorld::new(0.003, DVec3::new(0.0, -9.81, 0.0), &contact, body.mass_kg);
    let mut c = Crowd::new(body, world, CharacterParams::default(), KeyframeSet::builtin());
    c.statics.push((Shape::Plane, Pose::IDENTITY));
    let side = (n as f64).sqrt().ceil() as usize;
    let half = side as f64;
    c.wander = Some([-half, -half, half, half]);
    c.seed(1);
    for i in 0..n {
        let h = c.random() * std::f64::consts::TAU;
        c.add((i % side) as f64 * 2.0 - half, (i / side) as f64 * 2.0 - half, h, Goal::Stand);
    }
    for _ in 0..333 {
        c.step();
    }
    c
}
