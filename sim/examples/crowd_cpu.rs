//! Steps a wandering crowd and prints the wall time per step, for measuring with `perf stat` (CPU
//! time, which a shared machine's other load does not inflate):
//! `cargo run --release -p spidar-sim --example crowd_cpu -- 5000 1000`

use std::time::Instant;

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::CharacterParams;
use spidar_sim::collide::{Pose, Shape};
use spidar_sim::desc::{parse_body, ContactDesc, Gain};

fn main() {
    let args: Vec<usize> =
        std::env::args().skip(1).map(|a| a.parse().expect("numbers: characters steps")).collect();
    let (n, steps) = (args.first().copied().unwrap_or(5000), args.get(1).copied().unwrap_or(1000));
    let body = CrowdBody::from_file(
        &parse_body(include_str!("../../configs/body-character.ron"), "body").unwrap(),
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
    let t0 = Instant::now();
    for _ in 0..steps {
        c.step();
    }
    let per = t0.elapsed().as_secs_f64() / steps as f64;
    println!(
        "{n} characters, {steps} steps after 1 s warm-up: {:.3} ms wall per step ({:.0} ns per character); \
         near pairs {} contact points {}",
        per * 1e3,
        per * 1e9 / n as f64,
        c.stats.near_pairs,
        c.stats.pair_points
    );
}
