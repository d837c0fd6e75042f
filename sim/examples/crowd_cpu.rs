//! Steps a wandering crowd and prints the wall time per step, for measuring with `perf stat` (CPU
//! time, which a shared machine's other load does not inflate) and under `taskset`/`chrt`:
//! `cargo run --release -p spidar-sim --example crowd_cpu -- 5000 1000 [threads]`
//! (threads: rayon's; default all).

use std::time::Instant;

#[path = "../benches/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<usize> =
        std::env::args().skip(1).map(|a| a.parse().expect("numbers: characters steps [threads]")).collect();
    let (n, steps) = (args.first().copied().unwrap_or(5000), args.get(1).copied().unwrap_or(1000));
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(&t) = args.get(2) {
        pool = pool.num_threads(t);
    }
    let pool = pool.build().expect("a thread pool");
    pool.install(|| {
        let mut c = common::wandering_crowd(n);
        let t0 = Instant::now();
        for _ in 0..steps {
            c.step();
        }
        let per = t0.elapsed().as_secs_f64() / steps as f64;
        println!(
            "{n} characters on {} threads, {steps} steps after 1 s warm-up: {:.3} ms wall per step ({:.0} ns per character); \
             near pairs {} contact points {}",
            pool.current_num_threads(),
            per * 1e3,
            per * 1e9 / n as f64,
            c.stats.near_pairs,
            c.stats.pair_points
        );
    });
}
