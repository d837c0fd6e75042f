//! Tests of the keyframe characters (seed 002): balance, pushes, falls and standing up on the crowd
//! stepper and in the general engine; the keyframe set's interpolation; determinism.

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::CharacterParams;
use spidar_sim::desc::{build_scene, parse_body, ContactDesc, Gain};
use spidar_sim::state::kinematics;
use spidar_sim::{step, State, Workspace};

const BODY: &str = include_str!("../../configs/body-character.ron");

fn contact() -> ContactDesc {
    ContactDesc { stiffness: Gain::Abs(4e5), damping: Gain::Abs(4000.0), friction: 0.0, slip_m_per_s: 0.01 }
}

fn crowd() -> Crowd {
    let body = CrowdBody::from_file(&parse_body(BODY, "body-character.ron").unwrap(), "body").unwrap();
    let world = CrowdWorld::new(0.003, DVec3::new(0.0, -9.81, 0.0), &contact(), body.mass_kg);
    let mut c = Crowd::new(body, world, CharacterParams::default(), KeyframeSet::builtin());
    c.statics.push((spidar_sim::collide::Shape::Plane, spidar_sim::collide::Pose::IDENTITY));
    c
}

fn steps(c: &mut Crowd, seconds: f64) {
    for _ in 0..(seconds / 0.003).round() as usize {
        c.step();
    }
}

/// Runs `seconds` and returns the policies visited in order (without repeats).
fn run_policies(c: &mut Crowd, i: usize, seconds: f64) -> Vec<Policy> {
    let mut seen = vec![c.chars[i].control.policy];
    for _ in 0..(seconds / 0.003).round() as usize {
        c.step();
        let p = c.chars[i].control.policy;
        if *seen.last().unwrap() != p {
            seen.push(p);
        }
    }
    seen
}

fn upright(c: &Crowd, i: usize) -> bool {
    c.body_space(i).tilt() < 2f64.to_radians()
}

#[test]
fn standing_still_is_stable_for_60_s() {
    let mut c = crowd();
    c.add(1.0, -2.0, 0.4, Goal::Stand);
    let start = c.body_space(0);
    let seen = run_policies(&mut c, 0, 60.0);
    let b = c.body_space(0);
    assert_eq!(seen, vec![Policy::Balance]);
    assert!(b.tilt() < 1e-3, "tilt {}", b.tilt());
    let moved = (b.r_m - start.r_m).length();
    assert!(moved < 0.01, "drifted {moved} m");
    assert!((b.theta_y - 0.4).abs() < 1e-3, "heading {}", b.theta_y);
    assert!(b.r_dot_m_per_s.length() < 1e-3);
}

/// A push at chest height, too small to topple it, is taken by moving the feet: the character
/// travels in the push's direction (its walk phase advances: it steps), then stands again.
#[test]
fn a_small_push_is_recovered_by_stepping_in_its_direction() {
    for dir in [DVec3::Z, DVec3::X, DVec3::new(-0.6, 0.0, -0.8)] {
        let mut c = crowd();
        c.add(0.0, 0.0, 0.0, Goal::Stand);
        steps(&mut c, 0.5);
        let before = c.body_space(0);
        let chest = before.r_m + DVec3::new(0.0, 0.3, 0.0);
        c.add_impulse_at(0, chest, dir * 25.0);
        let seen = run_policies(&mut c, 0, 5.0);
        let after = c.body_space(0);
        let moved = after.r_m - before.r_m;
        assert_eq!(seen, vec![Policy::Balance], "push {dir}: it must not fall");
        assert!(moved.dot(dir) > 0.2, "push {dir}: moved {moved}");
        assert!((moved - dir * moved.dot(dir)).length() < 0.02, "push {dir}: moved sideways {moved}");
        let stepped = c.chars[0].anim.d_front_m.abs() + c.chars[0].anim.d_side_m.abs();
        assert!(stepped > 0.2, "push {dir}: walked {stepped} m along its own axes");
        assert!(upright(&c, 0) && after.r_dot_m_per_s.length() < 0.02, "push {dir}: not recovered");
    }
}

/// A push beside the centre line turns the body about the vertical (it pivots), and the character
/// keeps standing, facing its new way.
#[test]
fn an_off_centre_push_turns_the_body() {
    let mut turns = Vec::new();
    for offset_m in [0.2, -0.2] {
        let mut c = crowd();
        c.add(0.0, 0.0, 0.0, Goal::Stand);
        steps(&mut c, 0.5);
        let b = c.body_space(0);
        c.add_impulse_at(0, b.r_m + DVec3::new(offset_m, 0.3, 0.0), DVec3::Z * 25.0);
        let seen = run_policies(&mut c, 0, 5.0);
        assert_eq!(seen, vec![Policy::Balance]);
        let after = c.body_space(0);
        assert!(upright(&c, 0) && after.theta_y_dot.abs() < 0.01);
        turns.push(after.theta_y);
    }
    // Pushed forward on its left (+x) side, it turns to its right (negative heading), and back.
    assert!(turns[0] < -3f64.to_radians() && turns[1] > 3f64.to_radians(), "turns {turns:?}");
}

/// A hard push at head height topples it: it falls, brakes to a stop lying down, and stands up
/// again through the standing-up behaviour of the keyframe set.
#[test]
fn a_large_push_makes_it_fall_brake_stop_and_stand_up() {
    for (dir, lying) in [(DVec3::Z, 1.0), (-DVec3::Z, -1.0)] {
        let mut c = crowd();
        c.add(0.0, 0.0, 0.0, Goal::Stand);
        steps(&mut c, 0.5);
        let b = c.body_space(0);
        c.add_impulse_at(0, b.r_m + DVec3::new(0.0, 0.6, 0.0), dir * 90.0);
        let mut seen = vec![Policy::Balance];
        let (mut lowest, mut stand_up_shown) = (f64::INFINITY, false);
        let mut down_speed = None;
        for _ in 0..(12.0 / 0.003) as usize {
            c.step();
            let p = c.chars[0].control.policy;
            let b = c.body_space(0);
            lowest = lowest.min(b.r_m.y);
            if p == Policy::Down && down_speed.is_none() {
                down_speed = Some(b.r_dot_m_per_s.length());
                assert!(b.theta_x * lying > 1.3, "lying on the {} side: theta_x {}", lying, b.theta_x);
            }
            stand_up_shown |= c.chars[0].anim.behaviour == 1;
            if *seen.last().unwrap() != p {
                seen.push(p);
            }
        }
        assert_eq!(seen, vec![Policy::Balance, Policy::Fall, Policy::Down, Policy::StandUp, Policy::Balance]);
        assert!(lowest < 0.3, "it never reached the floor (centre of mass {lowest} m)");
        assert!(down_speed.unwrap() < 0.08, "not braked: {down_speed:?}");
        assert!(stand_up_shown && upright(&c, 0));
    }
}

/// The crowd stepper and the general engine give the same motion for one character, pushed.
#[test]
fn crowd_stepper_and_engine_agree_for_one_character() {
    let scene = "(version: 1, dt_s: 0.003, gravity_m_per_s2: (0.0, -9.81, 0.0), \
        contact: (stiffness: Abs(4e5), damping: Abs(4000.0), friction: 0.0, slip_m_per_s: 0.01), \
        joint_limit: (stiffness_n_m_per_rad: 300.0, damping_n_m_s_per_rad: 5.0), \
        statics: [(name: \"floor\", shape: Plane)], actors: [(name: \"c\", body: \"c.ron\", pos_m: (0.0, 0.0, 0.0))])";
    let m = build_scene(scene, "test", |_| Ok((BODY.to_string(), "c.ron".into()))).unwrap();
    let (mut s, mut ws) = (State::new(&m), Workspace::new(&m));
    let mut ch = spidar_sim::character::Character::default();
    let mut c = crowd();
    c.add(0.0, 0.0, 0.0, Goal::Stand);
    let params = CharacterParams::default();
    let mut worst: f64 = 0.0;
    let mut seen = vec![Policy::Balance];
    for k in 0..2500 {
        kinematics(&m, &s, &mut ws);
        let eb = ch.drive_engine(&m, &mut ws, 0, &params, 0.3);
        let cb = c.body_space(0);
        worst = worst.max((eb.r_m - cb.r_m).length()).max((eb.theta_x - cb.theta_x).abs());
        if k == 200 {
            // An off-centre push at the head: it falls, so all the policies are compared.
            let p = eb.r_m + DVec3::new(0.1, 0.6, 0.0);
            ws.add_impulse_at(0, p, DVec3::new(10.0, 0.0, 90.0), m.dt_s);
            c.add_impulse_at(0, p, DVec3::new(10.0, 0.0, 90.0));
        }
        step(&m, &mut s, &mut ws);
        c.step();
        assert_eq!(ch.control.policy, c.chars[0].control.policy, "step {k}");
        if *seen.last().unwrap() != ch.control.policy {
            seen.push(ch.control.policy);
        }
    }
    assert!(worst < 1e-6, "the two paths differ by {worst}");
    assert_eq!(seen, vec![Policy::Balance, Policy::Fall, Policy::Down, Policy::StandUp, Policy::Balance]);
}
