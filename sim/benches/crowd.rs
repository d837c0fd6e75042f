//! Crowd of keyframe characters: one 3 ms step (AI, controllers, contacts with the floor and each
//! other, integration, and every character's pose interpolated from the keyframe set) per
//! iteration, on one core. DESIGN.md section 8 asks for more than 5,000 characters per step in 3 ms.
//!
//! `cargo bench -p spidar-sim --bench crowd`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

mod common;

fn bench(cr: &mut Criterion) {
    let mut g = cr.benchmark_group("crowd_step_and_pose");
    g.sample_size(20);
    for n in [1000usize, 5000, 10000] {
        let mut c = common::wandering_crowd(n);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| b.iter(|| c.step()));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
