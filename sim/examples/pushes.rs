//! Pushes one standing keyframe character of the crowd scene and prints what it does: the policies
//! it went through, the steps it took, how far it leaned, moved and turned, and the largest energy
//! it had above what the push and gravity gave it. For tuning the controller by hand:
//! `cargo run --release -p spidar-sim --example pushes -- [impulse_n_s height_m dir_deg offset_m]`
//! (no arguments: a sweep over strengths, heights and directions).

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::{body_energy_j, Policy};
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::drawn::FigureStats;
use spidar_sim::character::scene::builtin_crowd;

fn one() -> Crowd {
    let c = builtin_crowd().unwrap();
    let mut one = Crowd::new(c.body.clone(), c.world, c.params, c.set.clone());
    one.statics = c.statics.clone();
    one.add(0.0, 0.0, 0.0, Goal::Stand);
    one
}

fn push(j: f64, h: f64, dir_deg: f64, offset: f64, verbose: bool) -> String {
    let mut c = one();
    for _ in 0..200 {
        c.step();
    }
    let b0 = c.body_space(0);
    let p = &c.params.controller.clone();
    let (m, g) = (c.body.mass_kg, 9.81);
    let e_before = body_energy_j(p, m, g, &b0, 0.0);
    let d = DVec3::new(dir_deg.to_radians().sin(), 0.0, dir_deg.to_radians().cos());
    let side = DVec3::Y.cross(d).normalize();
    let at = DVec3::new(b0.r_m.x, h, b0.r_m.z) - d * 0.13 + side * offset;
    c.add_impulse_at(0, at, d * j);
    c.step();
    let b1 = c.body_space(0);
    let e_push = body_energy_j(p, m, g, &b1, 0.0);
    let mut seen = vec![Policy::Balance];
    let (mut max_tilt, mut worst_excess, mut vmax) = (0.0f64, f64::NEG_INFINITY, 0.0f64);
    let mut fall_dir = None;
    let (mut e_prev, mut drive_work, mut other_work) = (e_push, 0.0, 0.0);
    let mut fig = FigureStats::default();
    for k in 0..(10.0 / 0.003) as usize {
        let bb = c.body_space(0);
        c.step();
        let dv = c.chars[0].drive;
        let pw = dv.force_n.dot(bb.r_dot_m_per_s + bb.w_world.cross(dv.at_m - bb.r_m))
            + dv.torque_n_m.dot(bb.w_world);
        let b = c.body_space(0);
        fig.add(&c, 0, 0.0);
        let e = body_energy_j(p, m, g, &b, 0.0);
        drive_work += pw * 0.003;
        other_work += (e - e_prev) - pw * 0.003;
        e_prev = e;
        if verbose && k % 20 == 0 {
            println!("   drive work {drive_work:7.2} J, other {other_work:7.2} J, P {pw:8.1} W");
        }
        worst_excess = worst_excess.max(e - e_push);
        max_tilt = max_tilt.max(b.tilt());
        vmax = vmax.max(b.r_dot_m_per_s.length());
        let pol = c.chars[0].control.policy;
        if pol == Policy::Fall && fall_dir.is_none() {
            let lean = DVec3::new(b.e_yr.x, 0.0, b.e_yr.z).normalize();
            fall_dir = Some(lean.dot(d));
        }
        if *seen.last().unwrap() != pol {
            seen.push(pol);
        }
        if verbose && k % 20 == 0 {
            let f = c.chars[0].control.feet;
            println!(
                "t {:5.2} {:8} tilt {:5.1} thx {:6.1} thz {:6.1} com ({:5.2} {:4.2} {:5.2}) v {:4.2} feet ({:5.2},{:5.2}){} ({:5.2},{:5.2}){} steps {} drop {}",
                k as f64 * 0.003,
                pol.name(),
                b.tilt().to_degrees(),
                b.theta_x.to_degrees(),
                b.theta_z.to_degrees(),
                b.r_m.x,
                b.r_m.y,
                b.r_m.z,
                b.r_dot_m_per_s.length(),
                f.foot[0].pos_m.x,
                f.foot[0].pos_m.z,
                if f.foot[0].planted() { " " } else { "*" },
                f.foot[1].pos_m.x,
                f.foot[1].pos_m.z,
                if f.foot[1].planted() { " " } else { "*" },
                f.steps,
                c.chars[0].drive.dropped,
            );
        }
    }
    let b = c.body_space(0);
    let moved = b.r_m - b0.r_m;
    format!(
        "J {j:5.1} h {h:4.2} dir {dir_deg:5.0} off {offset:5.2}: {:?} tilt {:5.1} steps {:2} moved {:5.2} along {:5.2} turn {:6.1} deg vmax {:4.2} fall-dir {:5.2} E push {:6.1} J excess {:6.2} J (E before {:.1})\n    figure: trunk out {:.3} lying out {:.3} ({} at {:.2} s) any {:.3} below floor {:.3} ({} at {:.2} s) jump {:.3} ({} at {:.3} s) slide {:.3} lift {:.3}",
        seen.iter().map(|p| p.name()).collect::<Vec<_>>(),
        max_tilt.to_degrees(),
        c.chars[0].control.feet.steps,
        moved.length(),
        moved.dot(d),
        (b.theta_y() - b0.theta_y()).to_degrees(),
        vmax,
        fall_dir.unwrap_or(f64::NAN),
        e_push - e_before,
        worst_excess,
        e_before,
        fig.trunk_outside_m,
        fig.lying_outside_m,
        c.set.joints[fig.worst_lying_at.1].name,
        fig.worst_lying_at.0 as f64 * 0.003,
        fig.any_outside_m,
        fig.below_floor_m,
        c.set.joints[fig.lowest_at.1].name,
        fig.lowest_at.0 as f64 * 0.003,
        fig.max_jump_m,
        c.set.joints[fig.jump_at.1].name,
        fig.jump_at.0 as f64 * 0.003,
        fig.max_slide_m,
        fig.max_lift_m,
    )
}

/// The crowd scene on its own for `seconds`: every fall, with who and where.
fn scene(seconds: f64) {
    let mut c = builtin_crowd().unwrap();
    let mut last: Vec<Policy> = c.chars.iter().map(|ch| ch.control.policy).collect();
    let track: Option<usize> = std::env::var("TRACK").ok().map(|s| s.parse().unwrap());
    for k in 0..(seconds / 0.003) as usize {
        c.step();
        if let (Some(i), 0) = (track, k % 20) {
            let b = c.body_space(i);
            let f = c.chars[i].control.feet;
            let d = c.chars[i].drive;
            println!(
                "  t {:5.2} #{i} {:8} tilt {:5.1} thx {:5.1} thz {:5.1} com ({:5.2},{:5.2}) v ({:5.2},{:5.2}) yaw {:6.1} feet ({:5.2},{:5.2}){} ({:5.2},{:5.2}){} F ({:6.1},{:6.1}) drop {} goal {:?}",
                k as f64 * 0.003, c.chars[i].control.policy.name(), b.tilt().to_degrees(), b.theta_x.to_degrees(), b.theta_z.to_degrees(),
                b.r_m.x, b.r_m.z, b.r_dot_m_per_s.x, b.r_dot_m_per_s.z, b.theta_y().to_degrees(),
                f.foot[0].pos_m.x, f.foot[0].pos_m.z, if f.foot[0].planted() { " " } else { "*" },
                f.foot[1].pos_m.x, f.foot[1].pos_m.z, if f.foot[1].planted() { " " } else { "*" },
                d.force_n.x, d.force_n.z, d.dropped, c.chars[i].goal
            );
        }
        for (i, was) in last.iter_mut().enumerate() {
            let p = c.chars[i].control.policy;
            if p != *was {
                let b = c.body_space(i);
                println!(
                    "t {:6.2} char {i} {} -> {} at ({:5.2}, {:5.2}) v {:4.2} goal {:?} near pairs {} points {}",
                    k as f64 * 0.003,
                    was.name(),
                    p.name(),
                    b.r_m.x,
                    b.r_m.z,
                    b.r_dot_m_per_s.length(),
                    c.chars[i].goal,
                    c.stats.near_pairs,
                    c.stats.pair_points
                );
                *was = p;
            }
        }
    }
}

/// One character walking to a point `dist` ahead at `speed`, printed every 60 ms.
fn walk(dist: f64, speed: f64) {
    let mut c = builtin_crowd().unwrap().empty_like();
    let ang = std::env::var("ANG").map_or(0.0, |s| s.parse::<f64>().unwrap()).to_radians();
    c.add(
        0.0,
        0.0,
        0.0,
        Goal::WalkTo { point_m: DVec3::new(dist * ang.sin(), 0.0, dist * ang.cos()), speed_m_per_s: speed },
    );
    for k in 0..(8.0 / 0.003) as usize {
        c.step();
        if k % 20 == 0 {
            let b = c.body_space(0);
            let f = c.chars[0].control.feet;
            println!(
                "t {:5.2} {:8} tilt {:5.1} thx {:6.1} com z {:5.2} v {:5.2} feet z ({:5.2}{}) ({:5.2}{}) x ({:5.2},{:5.2}) steps {} drop {}",
                k as f64 * 0.003,
                c.chars[0].control.policy.name(),
                b.tilt().to_degrees(),
                b.theta_x.to_degrees(),
                b.r_m.z,
                b.r_dot_m_per_s.z,
                f.foot[0].pos_m.z,
                if f.foot[0].planted() { " " } else { "*" },
                f.foot[1].pos_m.z,
                if f.foot[1].planted() { " " } else { "*" },
                f.foot[0].pos_m.x,
                f.foot[1].pos_m.x,
                f.steps,
                c.chars[0].drive.dropped
            );
        }
    }
}

fn main() {
    if std::env::args().nth(1).as_deref() == Some("walk") {
        let a: Vec<f64> = std::env::args().skip(2).map(|s| s.parse().unwrap()).collect();
        walk(a.first().copied().unwrap_or(3.0), a.get(1).copied().unwrap_or(0.6));
        return;
    }
    if std::env::args().nth(1).as_deref() == Some("scene") {
        scene(std::env::args().nth(2).map_or(20.0, |s| s.parse().unwrap()));
        return;
    }
    let a: Vec<f64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    if a.len() >= 2 {
        println!(
            "{}",
            push(a[0], a[1], a.get(2).copied().unwrap_or(0.0), a.get(3).copied().unwrap_or(0.0), true)
        );
        return;
    }
    for h in [0.75, 1.2] {
        for dir in [0.0, 90.0, 180.0, -135.0] {
            for j in [15.0, 30.0, 60.0, 100.0] {
                println!("{}", push(j, h, dir, 0.0, false));
            }
        }
    }
    for j in [10.0, 20.0, 30.0] {
        println!("{}", push(j, 1.1, 0.0, 0.15, false));
    }
}
