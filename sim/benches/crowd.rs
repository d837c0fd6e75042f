//! Crowd of keyframe characters, for 1,000 to 20,000 characters, on one thread and on all of
//! rayon's threads, in one run:
//!
//! - `crowd_step`: one 3 ms step as the world runs it (AI, controllers and feet, contacts with the
//!   floor and each other, integration). The project's goal is 5,000 characters per 3 ms step on
//!   one core and 10,000 on this 2-core machine, at a cost per character at 20,000 within 20 % of
//!   that at 1,000 (criterion's throughput: elements per second).
//! - `crowd_drawn_figures`: every character's drawn figure (its pose interpolated from the keyframe
//!   set and stood on its feet, and its joints placed in the world): what a view frame or a
//!   recorded skeleton asks for, at display rate (a 60 Hz view: once every 5.6 steps).
//!
//! `cargo bench -p spidar-sim --bench crowd`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use rayon::prelude::*;
use spidar_sim::character::drawn::world_joints;
use spidar_sim::character::skeleton::MAX_JOINTS;

mod common;

const SIZES: [usize; 4] = [1000, 5000, 10_000, 20_000];

fn bench(cr: &mut Criterion) {
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let all = rayon::ThreadPoolBuilder::new().build().unwrap();
    let pools = [("1 thread", &one), ("all threads", &all)];
    for n in SIZES {
        // The same crowd alternately on one thread and on all: the machine's other load falls on
        // both alike.
        let mut crowds: Vec<_> =
            pools.iter().map(|(_, pool)| pool.install(|| common::wandering_crowd(n))).collect();
        let mut g = cr.benchmark_group("crowd_step");
        g.sample_size(20);
        g.throughput(Throughput::Elements(n as u64));
        for ((name, pool), c) in pools.iter().zip(crowds.iter_mut()) {
            let id = BenchmarkId::new(format!("{name} ({})", pool.current_num_threads()), n);
            g.bench_function(id, |b| pool.install(|| b.iter(|| c.step())));
        }
        g.finish();
        let mut g = cr.benchmark_group("crowd_drawn_figures");
        g.sample_size(20);
        g.throughput(Throughput::Elements(n as u64));
        for ((name, pool), c) in pools.iter().zip(crowds.iter()) {
            let id = BenchmarkId::new(format!("{name} ({})", pool.current_num_threads()), n);
            g.bench_function(id, |b| {
                pool.install(|| {
                    b.iter(|| {
                        (0..n)
                            .into_par_iter()
                            .with_min_len(64)
                            .map(|i| {
                                let mut j = [DVec3::ZERO; MAX_JOINTS];
                                world_joints(c, i, &mut j);
                                j[MAX_JOINTS - 1].y
                            })
                            .sum::<f64>()
                    })
                })
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
