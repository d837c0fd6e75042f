//! Crowd of keyframe characters: one 3 ms step (AI, controllers and feet, contacts with the floor
//! and each other, integration, and every character's pose interpolated from the keyframe set and
//! stood on its feet) per iteration, for 1,000 to 20,000 characters, on one thread and on all of
//! rayon's threads, in one run. The project's goal is more than 5,000 characters per 3 ms step
//! on one core and 10,000 on this 2-core machine, at a cost per character at 20,000 within
//! 20 % of that at 1,000 (criterion's throughput: elements per second).
//!
//! `cargo bench -p spidar-sim --bench crowd`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

mod common;

const SIZES: [usize; 4] = [1000, 5000, 10_000, 20_000];

fn bench(cr: &mut Criterion) {
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let all = rayon::ThreadPoolBuilder::new().build().unwrap();
    let mut g = cr.benchmark_group("crowd_step_and_pose");
    g.sample_size(20);
    for n in SIZES {
        g.throughput(Throughput::Elements(n as u64));
        // The same crowd alternately on one thread and on all: the machine's other load falls on
        // both alike.
        for (name, pool) in [("1 thread", &one), ("all threads", &all)] {
            let mut c = pool.install(|| common::wandering_crowd(n));
            let id = BenchmarkId::new(format!("{name} ({})", pool.current_num_threads()), n);
            g.bench_function(id, |b| pool.install(|| b.iter(|| c.step())));
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
