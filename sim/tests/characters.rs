//! Tests of the keyframe characters (seed 002): balance, pushes, falls and standing up on the crowd
//! stepper and in the general engine; the keyframe set's interpolation; determinism.

mod alloc_count;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::keyframe::{Pose, QPoint};
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
    assert!((b.theta_y() - 0.4).abs() < 1e-3, "heading {}", b.theta_y());
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
        turns.push(after.theta_y());
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
    let scene = "(kind: \"body-scene\", version: 1, dt_s: 0.003, gravity_m_per_s2: (0.0, -9.81, 0.0), \
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

// ---- the keyframe set ----

#[test]
fn the_shipped_set_is_the_papers_evaluation_set() {
    let set = KeyframeSet::builtin();
    assert_eq!(set.animations, 12);
    assert_eq!(set.keys.len(), 57);
    assert_eq!(set.behaviours, vec!["walking and falling", "standing up"]);
    // Its quaternions are stored so that posing needs no sign tests (a speed matter only).
    assert_eq!(set.aligned_planes(), (4, 4));
    // Standing-up keyframes are all on the (Theta_z = 0, D_x = 0, D_z = 0) line (section 6.1).
    for k in set.keys.iter().filter(|k| k.at.behaviour == 1) {
        assert!(k.at.theta_z == 0.0 && k.at.d_x == 0.0 && k.at.d_z == 0.0, "{:?}", k.at);
    }
}

#[test]
fn the_interpolated_pose_equals_the_keyframe_at_each_keyframe() {
    let set = KeyframeSet::builtin();
    let n = set.joints.len();
    let mut out = Pose::default();
    for k in &set.keys {
        set.pose(&k.at, &mut out);
        let err = out.max_angle_to(&k.pose, n);
        // Poses are single precision: a few 1e-7 rad of rounding.
        assert!(err < 2e-6, "{:?}: {err} rad off", k.at);
        assert!((out.root_m - k.pose.root_m).length() < 1e-6);
    }
}

/// A random path through Q (leans, both walk phases wrapping past 1, behaviour switches blended in
/// time as a character does) never makes a joint turn by more than a bounded amount per step.
#[test]
fn the_pose_changes_continuously_along_a_long_random_path() {
    let set = KeyframeSet::builtin();
    let n = set.joints.len();
    let mut rng = Pcg64::seed_from_u64(7);
    let dt = 0.003;
    let mut q = QPoint::default();
    let mut anim = spidar_sim::character::Correspondence { blend: 1.0, ..Default::default() };
    let (mut prev, mut cur) = (Pose::default(), Pose::default());
    set.pose(&q, &mut prev);
    let (mut worst, mut total) = (0.0f64, 0.0);
    let mut wraps = 0;
    for step in 0..200_000 {
        // Leans move at up to 3 rad/s, phases at up to 2 cycles/s (faster than any character).
        q.theta_x = (q.theta_x + rng.random_range(-3.0..3.0) * dt).clamp(-3.1, 3.1);
        q.theta_z = (q.theta_z + rng.random_range(-3.0..3.0) * dt).clamp(-1.55, 1.55);
        let (dx, dz) = (q.d_x + rng.random_range(0.0..2.0) * dt, q.d_z + rng.random_range(-1.0..2.0) * dt);
        wraps += (!(0.0..1.0).contains(&dz) || dx >= 1.0) as u32;
        q.d_x = spidar_sim::character::periodic(dx);
        q.d_z = spidar_sim::character::periodic(dz);
        let behaviour = if (step / 5000) % 2 == 1 { 1 } else { 0 };
        if behaviour != anim.behaviour {
            anim.from_behaviour = anim.behaviour;
            anim.behaviour = behaviour;
            anim.blend = 0.0;
        }
        anim.blend = (anim.blend + dt / set.behaviour_blend_s).min(1.0);
        q.behaviour = anim.behaviour;
        set.pose_blended(&q, anim.from_behaviour, anim.blend, &mut cur);
        let d = cur.max_angle_to(&prev, n);
        worst = worst.max(d);
        total += d;
        prev = cur;
    }
    assert!(wraps > 100, "the path must cross the phase wrap often ({wraps})");
    assert!(total > 10.0, "the path must actually animate (total {total} rad)");
    // The steepest part of the set (40 deg of arm between fall keyframes 15 deg of lean apart, and
    // a 0.3 s behaviour blend) moves a joint by at most a few degrees per 3 ms step at these rates.
    assert!(worst < 4f64.to_radians(), "a joint turned {} deg in one step", worst.to_degrees());
}

#[test]
fn the_pose_wraps_smoothly_at_the_walk_phase_boundary() {
    let set = KeyframeSet::builtin();
    let n = set.joints.len();
    let (mut a, mut b) = (Pose::default(), Pose::default());
    for theta_x in [0.0, 0.3, 0.52, -0.52, 0.7] {
        for theta_z in [0.0, 0.2, -0.43] {
            let q = QPoint { theta_x, theta_z, d_x: 0.3, ..QPoint::default() };
            set.pose(&QPoint { d_z: 1.0 - 1e-9, ..q }, &mut a);
            set.pose(&QPoint { d_z: 0.0, ..q }, &mut b);
            assert!(a.max_angle_to(&b, n) < 2e-6, "front phase wrap at {theta_x} {theta_z}");
            set.pose(&QPoint { d_x: 1.0 - 1e-9, d_z: 0.4, ..q }, &mut a);
            set.pose(&QPoint { d_x: 0.0, d_z: 0.4, ..q }, &mut b);
            assert!(a.max_angle_to(&b, n) < 2e-6, "side phase wrap at {theta_x} {theta_z}");
        }
    }
}

#[test]
fn a_keyframe_off_the_planes_is_located_and_explained() {
    let text = spidar_sim::character::keyframe::KEYFRAMES_HUMANOID_RON.replacen(
        "line: (theta_x_deg: 30.0)",
        "line: (theta_x_deg: 30.0, theta_z_deg: 10.0)",
        1,
    );
    let e = KeyframeSet::parse(&text, "k.ron").unwrap_err().to_string();
    assert!(e.starts_with("k.ron:") && e.contains("front plane"), "{e}");
    let text = spidar_sim::character::keyframe::KEYFRAMES_HUMANOID_RON.replacen(
        "\"l_knee\": (",
        "\"l_knee2\": (",
        1,
    );
    let e = KeyframeSet::parse(&text, "k.ron").unwrap_err().to_string();
    assert!(e.contains("no joint \"l_knee2\""), "{e}");
}

// ---- determinism ----

/// A wandering crowd with random pushes: the same seed gives the same motion, bit for bit, and
/// its digest is pinned.
#[test]
fn the_same_seed_gives_the_same_crowd_motion() {
    fn run(seed: u64) -> (u64, usize) {
        let mut c = crowd();
        c.seed(seed);
        c.wander = Some([-4.0, -4.0, 4.0, 4.0]);
        let mut rng = Pcg64::seed_from_u64(seed);
        for i in 0..30 {
            c.add(
                (i % 6) as f64 * 1.3 - 3.0,
                (i / 6) as f64 * 1.3 - 3.0,
                rng.random_range(-3.0..3.0),
                Goal::Stand,
            );
        }
        let mut falls = 0;
        for k in 0..3000 {
            if k % 100 == 50 {
                let i = rng.random_range(0..c.len());
                let b = c.body_space(i);
                let dir = DVec3::new(rng.random_range(-1.0..1.0), 0.0, rng.random_range(-1.0..1.0));
                c.add_impulse_at(i, b.r_m + DVec3::Y * rng.random_range(0.0..0.6), dir.normalize() * 110.0);
            }
            c.step();
            falls += c.chars.iter().filter(|ch| ch.control.policy == Policy::Fall).count();
        }
        (c.digest(), falls)
    }
    let (a, falls) = run(2);
    assert_eq!(a, run(2).0);
    assert_ne!(a, run(3).0);
    assert!(falls > 0, "the pushes should topple someone");
    // Re-pinned when the controller took its heading error and lean sines from vectors instead
    // of angles (the same quantities, rounded differently); every behaviour test passed unchanged.
    assert_eq!(a, 0x282b_c409_eafc_79d7, "digest changed: {a:#018x}");
}

// ---- the crowd scene file ----

#[test]
fn the_shipped_crowd_scene_loads_from_disk_and_walks() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/scene-crowd.ron");
    let mut c = spidar_sim::character::scene::load_crowd(std::path::Path::new(path)).unwrap();
    assert_eq!(c.len(), 8);
    let start: Vec<DVec3> = (0..c.len()).map(|i| c.body_space(i).r_m).collect();
    steps(&mut c, 20.0);
    for (i, s) in start.iter().enumerate() {
        let b = c.body_space(i);
        assert!(b.r_m.is_finite());
        assert!((b.r_m - *s).length() > 0.3, "character {i} did not walk");
        let a = [-2.4, -4.0, 2.4, -0.5];
        assert!(b.r_m.x > a[0] - 1.0 && b.r_m.x < a[2] + 1.0 && b.r_m.z > a[1] - 1.0 && b.r_m.z < a[3] + 1.0);
    }
}

#[test]
fn a_bad_controller_setting_in_the_crowd_scene_is_located() {
    use spidar_sim::character::scene::{build_crowd, SCENE_CROWD_RON};
    let text = SCENE_CROWD_RON.replacen("fall_angle_deg: 35.0", "fall_angle_deg: 95.0", 1);
    let e = build_crowd(&text, "s.ron", |_| unreachable!()).unwrap_err().to_string();
    let line = text.lines().position(|l| l.contains("fall_angle_deg: 95.0")).unwrap() + 1;
    assert!(e.starts_with(&format!("s.ron:{line}:")), "{e}");
    assert!(e.contains("character.controller.fall_angle_deg") && e.contains("between"), "{e}");
}

/// After the first step a crowd step (AI, controllers, contacts, grid, integration, posing)
/// allocates nothing, even while the crowd spreads out and characters fall.
#[test]
fn crowd_steps_do_not_allocate() {
    let mut c = crowd();
    c.wander = Some([-3.0, -3.0, 3.0, 3.0]);
    for i in 0..25 {
        c.add((i % 5) as f64 * 1.5 - 3.0, (i / 5) as f64 * 1.5 - 3.0, i as f64, Goal::Stand);
    }
    c.step();
    c.wander = Some([-30.0, -30.0, 30.0, 30.0]);
    let n = alloc_count::count(|| {
        for k in 0..2000 {
            if k % 100 == 0 {
                let b = c.body_space(k / 100);
                c.add_impulse_at(k / 100, b.r_m + DVec3::Y * 0.6, DVec3::X * 100.0);
            }
            c.step();
        }
    });
    assert_eq!(n, 0, "{n} allocations in 2000 crowd steps");
    assert!(alloc_count::count(|| drop(vec![1u8; 10])) > 0);
}
