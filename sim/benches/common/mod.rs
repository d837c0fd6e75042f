//! The crowd the crowd bench and the `crowd_cpu` example measure: `n` characters of the built-in
//! crowd scene (its body, controller, keyframe set and floor) on a 2 m grid, wandering over it,
//! after 1 s of warm-up.

use spidar_sim::character::ai::Goal;
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::scene::builtin_crowd;

pub fn wandering_crowd(n: usize) -> Crowd {
    let mut c = builtin_crowd().unwrap().empty_like();
    let side = (n as f64).sqrt().ceil() as usize;
    let half = side as f64;
    c.wander = Some([-half, -half, half, half]);
    c.wander_speed_m_per_s = 0.8;
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
