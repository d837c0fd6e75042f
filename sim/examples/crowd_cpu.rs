//! Steps a wandering crowd and prints the wall time per step, for measuring with `perf stat` (CPU
//! time, which a shared machine's other load does not inflate) and under `taskset`/`chrt`:
//! `cargo run --release -p spidar-sim --example crowd_cpu -- 5000 1000 [threads] [draw_every]`
//! (threads: rayon's, default all; draw_every: also compute every character's drawn figure after
//! every that many steps, as a view does (6 for 60 Hz), default never).

use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;
use spidar_sim::character::drawn::world_joints;
use spidar_sim::character::skeleton::MAX_JOINTS;

#[path = "../benches/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<usize> =
        std::env::args().skip(1).map(|a| a.parse().expect("numbers: characters steps [threads]")).collect();
    let (n, steps) = (args.first().copied().unwrap_or(5000), args.get(1).copied().unwrap_or(1000));
    let draw_every = args.get(3).copied().unwrap_or(0);
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(&t) = args.get(2) {
        pool = pool.num_threads(t);
    }
    let pool = pool.build().expect("a thread pool");
    pool.install(|| {
        let mut c = common::wandering_crowd(n);
        let t0 = Instant::now();
        let mut drawn = 0.0;
        for k in 0..steps {
            c.step();
            if draw_every > 0 && k % draw_every == 0 {
                drawn += (0..n)
                    .into_par_iter()
                    .with_min_len(64)
                    .map(|i| {
                        let mut j = [DVec3::ZERO; MAX_JOINTS];
                        world_joints(&c, i, &mut j);
                        j[MAX_JOINTS - 1].y
                    })
                    .sum::<f64>();
            }
        }
        std::hint::black_box(drawn);
        let per = t0.elapsed().as_secs_f64() / steps as f64;
        println!(
            "{n} characters on {} threads, {steps} steps after 1 s warm-up{}: {:.3} ms wall per step ({:.0} ns per character); \
             near pairs {} contact points {}",
            pool.current_num_threads(),
            if draw_every > 0 { format!(", drawn figures every {draw_every} steps") } else { String::new() },
            per * 1e3,
            per * 1e9 / n as f64,
            c.stats.near_pairs,
            c.stats.pair_points
        );
    });
}
