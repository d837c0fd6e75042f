//! Crowd of keyframe characters: one 3 ms step (AI, controllers, contacts with the floor and each
//! other, integration, and every character's pose interpolated from the keyframe set) per
//! iteration, on one core. DESIGN.md section 8 asks for more than 5,000 characters per step in 3 ms.
//!
//! `cargo bench -p spidar-sim --bench crowd`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::CharacterParams;
use spidar_sim::collide::{Pose, Shape};
use spidar_sim::desc::{parse_body, ContactDesc, Gain};

const BODY: &str = include_str!("../../configs/body-character.ron");

/// `n` characters on a square at 2 m spacing, each wandering to random points, after 1 s of
/// simulated warm-up so they are walking (and some bump into each other).
fn crowd(n: usize) -> Crowd {
    let body = CrowdBody::from_file(&parse_body(BODY, "body").unwrap(), "body").unwrap();
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
        let (x, z) = ((i % side) as f64 * 2.0 - half, (i / side) as f64 * 2.0 - half);
        let h = c.random() * std::f64::consts::TAU;
        c.add(x, z, h, Goal::Stand);
    }
    for _ in 0..333 {
        c.step();
    }
    c
}

fn bench(cr: &mut Criterion) {
    let mut g = cr.benchmark_group("crowd_step_and_pose");
    g.sample_size(20);
    for n in [1000usize, 5000, 10000] {
        let mut c = crowd(n);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| b.iter(|| c.step()));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
