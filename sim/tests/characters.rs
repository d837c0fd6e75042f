//! Tests of the keyframe characters (seed 002): balance, stepping, falls and standing up on the crowd
//! stepper and in the general engine (bounded by a person's feet, never adding energy);
//! the drawn figure against the body; the keyframe set's interpolation; determinism for any number
//! of threads; the loaders' errors.

mod alloc_count;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::{body_energy_j, Policy};
use spidar_sim::character::crowd::Crowd;
use spidar_sim::character::drawn::{self, FigureStats};
use spidar_sim::character::keyframe::{KeyframeSet, QPoint, KEYFRAMES_HUMANOID_RON};
use spidar_sim::character::scene::{build_crowd, builtin_crowd, BODY_CHARACTER_RON, SCENE_CROWD_RON};
use spidar_sim::character::skeleton::SkeletonPose;
use spidar_sim::desc::{build_scene, parse_body};
use spidar_sim::state::kinematics;
use spidar_sim::{step, State, Workspace};

const DT: f64 = 0.003;

/// One crowd with the built-in crowd scene's body, settings, keyframes and floor, and no one in it.
fn crowd() -> Crowd {
    builtin_crowd().unwrap().empty_like()
}

/// 30 characters on a 6 x 5 grid, wandering in a 6 m square, seeded with `seed`; the random
/// source (same seed) that placed them, for the pushes that follow.
fn wandering_crowd(seed: u64) -> (Crowd, Pcg64) {
    let mut c = crowd();
    c.seed(seed);
    c.wander = Some([-3.0, -3.0, 3.0, 3.0]);
    let mut rng = Pcg64::seed_from_u64(seed);
    for i in 0..30 {
        c.add(
            (i % 6) as f64 * 1.1 - 3.0,
            (i / 6) as f64 * 1.1 - 3.0,
            rng.random_range(-3.0..3.0),
            Goal::Stand,
        );
    }
    (c, rng)
}

fn steps(c: &mut Crowd, seconds: f64) {
    for _ in 0..(seconds / DT).round() as usize {
        c.step();
    }
}

/// A character standing at the origin facing +z, settled for half a second.
fn standing() -> Crowd {
    let mut c = crowd();
    c.add(0.0, 0.0, 0.0, Goal::Stand);
    steps(&mut c, 0.5);
    c
}

/// Horizontal unit vector at `deg` from +z toward +x.
fn dir(deg: f64) -> DVec3 {
    let a = deg.to_radians();
    DVec3::new(a.sin(), 0.0, a.cos())
}

/// Pushes character 0 with `impulse_n_s` along `d` at `height_m` above the floor, on the surface of
/// its trunk facing the push, `offset_m` to the side of its centre line.
fn push(c: &mut Crowd, impulse_n_s: f64, height_m: f64, d: DVec3, offset_m: f64) {
    let b = c.body_space(0);
    let side = DVec3::Y.cross(d).normalize();
    let at = DVec3::new(b.r_m.x, height_m, b.r_m.z) - d * 0.13 + side * offset_m;
    c.add_impulse_at(0, at, d * impulse_n_s);
}

/// What a push did, watched for `seconds`.
struct Watch {
    /// Policies visited, without repeats.
    policies: Vec<Policy>,
    /// Direction of the lean (horizontal) when the fall began.
    fall_lean: Option<DVec3>,
    /// How the body lay when it stopped (`Down`): its left axis's height.
    down_side: Option<f64>,
    /// Where the first step landed, from where that foot was.
    first_step: Option<DVec3>,
    steps: u64,
    /// Feet lifted to step before the fall began.
    steps_before_fall: Option<u64>,
}

fn watch(c: &mut Crowd, seconds: f64) -> Watch {
    let mut w = Watch {
        policies: vec![c.chars[0].control.policy],
        fall_lean: None,
        down_side: None,
        first_step: None,
        steps: 0,
        steps_before_fall: None,
    };
    let feet0 = c.chars[0].control.feet;
    for _ in 0..(seconds / DT).round() as usize {
        c.step();
        let ch = &c.chars[0];
        let p = ch.control.policy;
        let b = c.body_space(0);
        if p == Policy::Fall && w.fall_lean.is_none() {
            w.fall_lean = Some(DVec3::new(b.e_yr.x, 0.0, b.e_yr.z).normalize());
            w.steps_before_fall = Some(ch.control.feet.lifts);
        }
        if p == Policy::Down && w.down_side.is_none() {
            w.down_side = Some(b.e_xr.y);
        }
        let f = &ch.control.feet;
        if w.first_step.is_none() && f.steps > 0 {
            // The foot that landed: the one that moved.
            let moved = [0, 1].map(|k| f.foot[k].pos_m - feet0.foot[k].pos_m);
            let k = if moved[0].length() >= moved[1].length() { 0 } else { 1 };
            w.first_step = Some(moved[k]);
        }
        if *w.policies.last().unwrap() != p {
            w.policies.push(p);
        }
    }
    w.steps = c.chars[0].control.feet.steps;
    w
}

fn upright_and_still(c: &Crowd) -> bool {
    let b = c.body_space(0);
    b.tilt() < 3f64.to_radians() && b.r_dot_m_per_s.length() < 0.03
}

const HEIGHTS: [(&str, f64); 2] = [("trunk", 0.75), ("shoulders", 1.2)];
const DIRECTIONS: [f64; 6] = [0.0, 180.0, 90.0, -90.0, 45.0, -135.0];

#[test]
fn standing_still_is_stable_for_60_s() {
    let mut c = crowd();
    c.add(1.0, -2.0, 0.4, Goal::Stand);
    let start = c.body_space(0);
    let w = watch(&mut c, 60.0);
    let b = c.body_space(0);
    assert_eq!(w.policies, vec![Policy::Balance]);
    assert!(b.tilt() < 1e-3, "tilt {}", b.tilt());
    assert!((b.r_m - start.r_m).length() < 0.01, "drifted {}", (b.r_m - start.r_m).length());
    assert!((b.theta_y() - 0.4).abs() < 1e-3, "heading {}", b.theta_y());
    assert!(b.r_dot_m_per_s.length() < 1e-3);
    assert_eq!(w.steps, 0, "it should not step while nothing pushes it");
}

/// Small pushes at the trunk and at the shoulders, from six directions: the character steps, the
/// first step lands in the push's direction, it never falls, and it ends upright and still.
#[test]
fn a_small_push_is_recovered_by_stepping_in_its_direction() {
    for (place, h) in HEIGHTS {
        for deg in DIRECTIONS {
            let d = dir(deg);
            let mut c = standing();
            let before = c.body_space(0).r_m;
            push(&mut c, 15.0, h, d, 0.0);
            let w = watch(&mut c, 6.0);
            let what = format!("15 N s at the {place} toward {deg} deg");
            assert_eq!(w.policies, vec![Policy::Balance], "{what}: it must not fall");
            let first = w.first_step.unwrap_or_else(|| panic!("{what}: it did not step"));
            assert!(first.dot(d) > 0.05, "{what}: first step {first} not along the push");
            let moved = c.body_space(0).r_m - before;
            assert!(moved.dot(d) > 0.05, "{what}: moved {moved}");
            assert!((moved - d * moved.dot(d)).length() < 0.1, "{what}: moved off the push's line {moved}");
            assert!(upright_and_still(&c), "{what}: not recovered");
        }
    }
}

/// Shoves the bounded feet cannot catch, at the trunk and at the shoulders, from six directions:
/// the character falls the way it was pushed, stops, stands up and is upright again.
#[test]
fn a_shove_the_feet_cannot_catch_makes_it_fall_the_way_it_was_pushed_and_stand_up() {
    for (place, h, impulse) in [("trunk", 0.75, 100.0), ("shoulders", 1.2, 70.0)] {
        for deg in DIRECTIONS {
            let d = dir(deg);
            let mut c = standing();
            push(&mut c, impulse, h, d, 0.0);
            let w = watch(&mut c, 14.0);
            let what = format!("{impulse} N s at the {place} toward {deg} deg");
            assert_eq!(
                w.policies,
                vec![Policy::Balance, Policy::Fall, Policy::Down, Policy::StandUp, Policy::Balance],
                "{what}"
            );
            let lean = w.fall_lean.unwrap();
            assert!(lean.dot(d) > 0.8, "{what}: fell toward {lean}");
            // The feet tried: a step or two, no more (a person's steps are not fast enough).
            let tried = w.steps_before_fall.unwrap();
            assert!((1..=3).contains(&tried), "{what}: {tried} steps tried before the fall");
            assert!(upright_and_still(&c), "{what}: not standing at the end");
        }
    }
}

/// Over a sweep of pushes (strengths from a nudge to a shove, heights from the feet to the head,
/// eight directions, on and off the centre line), the body's kinetic energy never exceeds what the
/// push gave it plus what gravity gives it by lowering its centre of mass: the controller adds none.
#[test]
fn the_controller_never_adds_energy_after_a_push() {
    let mut rng = Pcg64::seed_from_u64(19);
    let mut worst: f64 = f64::NEG_INFINITY;
    for k in 0..48 {
        let impulse = [8.0, 20.0, 40.0, 70.0, 110.0, 150.0][k % 6];
        let h = rng.random_range(0.2..1.4);
        let d = dir(k as f64 * 45.0 + rng.random_range(-10.0..10.0));
        let offset = rng.random_range(-0.12..0.12);
        let mut c = standing();
        push(&mut c, impulse, h, d, offset);
        c.step();
        let p = c.params.controller;
        let (m, g) = (c.body.mass_kg, 9.81);
        let b0 = c.body_space(0);
        let e0 = body_energy_j(&p, m, g, &b0, 0.0);
        for _ in 0..(10.0 / DT) as usize {
            c.step();
            let b = c.body_space(0);
            let ke = body_energy_j(&p, m, g, &b, 0.0) - m * g * b.r_m.y;
            // KE(t) <= KE(push) + m g (h(push) - h(t)), i.e. E(t) <= E(push).
            let bound = e0 - m * g * b.r_m.y;
            worst = worst.max(ke - bound);
        }
    }
    // The contact's springiness and the integration's rounding: a fraction of a joule.
    assert!(worst < 0.5, "kinetic energy exceeded the push's plus gravity's by {worst} J");
}

/// Pushes beside the centre line turn the body about the vertical by an angle proportional to
/// their angular impulse, one way for each side; the feet follow with a step (a pivot on the other).
#[test]
fn an_off_centre_push_turns_the_body_in_proportion_to_its_angular_impulse() {
    let mut ratio = Vec::new();
    for (impulse, offset) in [(8.0, 0.15), (16.0, 0.15), (16.0, -0.15), (12.0, 0.08)] {
        let mut c = standing();
        let y0 = c.body_space(0).theta_y();
        push(&mut c, impulse, 1.1, DVec3::Z, offset);
        let w = watch(&mut c, 6.0);
        assert_eq!(w.policies, vec![Policy::Balance]);
        let b = c.body_space(0);
        let turn = b.theta_y() - y0;
        // Angular impulse about the vertical: (r x J).y with r = offset to the side (+x for an
        // offset > 0 pushing +z): -offset J.
        let l = -offset * impulse;
        ratio.push(turn / l);
        assert!(w.steps >= 1, "no step after a turn");
        // Standing square to the new heading: the line between the feet is across it.
        let f = c.chars[0].control.feet;
        let across = (f.foot[0].pos_m - f.foot[1].pos_m).normalize();
        assert!(
            across.dot(b.heading.e_zc).abs() < 0.35,
            "feet {across} not across heading {:?}",
            b.heading.e_zc
        );
    }
    let (lo, hi) = ratio.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| (a.min(*r), b.max(*r)));
    assert!(lo > 0.0, "turned the wrong way: {ratio:?}");
    assert!(hi / lo < 1.25, "turn per angular impulse varies: {ratio:?} rad per N m s");
    // Big enough to see: 16 N s at 15 cm turns it by more than 10 degrees.
    assert!(ratio[1] * 0.15 * 16.0 > 10f64.to_radians(), "{ratio:?}");
}

/// A character shoved sideways lands on its side and rolls onto its face or its back (its convex
/// sides, section 6.1), where it can stand up.
#[test]
fn sideways_falls_roll_onto_the_face_or_back() {
    for deg in [90.0, -90.0] {
        let mut c = standing();
        push(&mut c, 90.0, 1.2, dir(deg), 0.0);
        let w = watch(&mut c, 14.0);
        let side = w.down_side.expect("it fell and stopped");
        assert!(side.abs() < 0.35, "push toward {deg}: lies on its side (left axis height {side})");
        assert!(w.policies.contains(&Policy::StandUp) && *w.policies.last().unwrap() == Policy::Balance);
    }
}

/// The front-back lean given to the keyframe space stays continuous through falls in every
/// direction (near lying on the side it used to flip between the front and the back fall).
#[test]
fn the_lean_angles_stay_continuous_through_every_fall() {
    // Straight to each side (where the body lands exactly on its side) and in between.
    for (deg, offset) in (0..8).flat_map(|k| [(k as f64 * 45.0, 0.0), (k as f64 * 45.0 + 10.0, 0.03)]) {
        let mut c = standing();
        push(&mut c, 100.0, 1.2, dir(deg), offset);
        let mut prev: Option<(f64, f64)> = None;
        let mut worst: f64 = 0.0;
        for _ in 0..(6.0 / DT) as usize {
            c.step();
            let b = c.body_space(0);
            let q = c.chars[0].anim.q(&b, &c.set);
            if let Some((x, z)) = prev {
                worst = worst.max((q.theta_x - x).abs()).max((q.theta_z - z).abs());
            }
            prev = Some((q.theta_x, q.theta_z));
        }
        // A fall turns the body at most a few rad/s: a few hundredths of a radian per 3 ms step.
        assert!(worst < 0.06, "push toward {deg} deg: a lean jumped {worst} rad in one step");
    }
}

/// The drawn figure over pushes from every direction and height (and a walk): the trunk's joints
/// stay within a few centimetres of the body's shapes always, every joint does while lying or
/// standing up, nothing goes below the floor, no joint jumps, and a planted foot's drawn ankle stays
/// put while the other swings and lifts visibly.
#[test]
fn the_drawn_figure_stays_on_the_body() {
    let mut runs: Vec<(String, FigureStats)> = Vec::new();
    for h in [0.3, 0.75, 1.2] {
        for deg in (0..8).map(|k| k as f64 * 45.0) {
            for impulse in [20.0, 100.0] {
                let mut c = standing();
                push(&mut c, impulse, h, dir(deg), 0.02);
                let mut f = FigureStats::default();
                for _ in 0..(10.0 / DT) as usize {
                    c.step();
                    f.add(&c, 0, 0.0);
                }
                runs.push((format!("{impulse} N s at {h} m toward {deg} deg"), f));
            }
        }
    }
    let mut c = crowd();
    c.add(0.0, 0.0, 0.0, Goal::WalkTo { point_m: DVec3::new(1.0, 0.0, 3.0), speed_m_per_s: 0.9 });
    let mut f = FigureStats::default();
    for _ in 0..(8.0 / DT) as usize {
        c.step();
        f.add(&c, 0, 0.0);
    }
    runs.push(("walking 3 m".into(), f));
    for (what, f) in &runs {
        assert!(f.trunk_outside_m < 0.06, "{what}: a trunk joint {:.3} m off the body", f.trunk_outside_m);
        assert!(f.lying_outside_m < 0.09, "{what}: lying, a joint {:.3} m off the body", f.lying_outside_m);
        assert!(f.below_floor_m < 0.02, "{what}: a joint {:.3} m below the floor", f.below_floor_m);
        // Kicked at the shins, the body turns at ten radians a second: its far joints move a few
        // centimetres per step by that alone.
        assert!(f.max_jump_m < 0.07, "{what}: a joint jumped {:.3} m in one step", f.max_jump_m);
        assert!(f.max_slide_m < 0.05, "{what}: a planted foot slid {:.3} m", f.max_slide_m);
    }
    let walk = &runs.last().unwrap().1;
    assert!(walk.max_lift_m > 0.05, "the swinging foot lifts only {:.3} m", walk.max_lift_m);
    assert!(walk.max_slide_m < 0.01, "walking, a planted foot slid {:.3} m", walk.max_slide_m);
}

/// A character's [`drawn::FigureState`], copied after a step and turned into its figure a few steps
/// later (as a viewer's thread does while the crowd steps on), gives the joints `world_joints` gave
/// at the step copied, bit for bit: over a wandering crowd pushed over and over, through every
/// control state, behaviour blends, swinging feet, the legs handing over to the keyframes and
/// leans past the polar poses' start (each of which is checked to have been met).
#[test]
fn a_copied_figure_state_draws_the_figure_of_its_step() {
    use spidar_sim::character::drawn::{world_joints, FigureState, Figures};
    use spidar_sim::character::skeleton::MAX_JOINTS;
    let (mut c, mut rng) = wandering_crowd(4);
    let figures = Figures::of(&c);
    let n = figures.joints();
    let mut seen_policies = Vec::new();
    let (mut blends, mut swings, mut handovers, mut polar, mut moved) = (0, 0, 0, 0, 0);
    // Copies made 4 steps ago: (states, the joints world_joints gave then).
    type Copy = (Vec<FigureState>, Vec<[glam::DVec3; MAX_JOINTS]>);
    let mut pending: std::collections::VecDeque<Copy> = Default::default();
    for k in 0..(14.0 / DT) as usize {
        if k % 60 == 30 {
            let i = rng.random_range(0..c.len());
            let b = c.body_space(i);
            let d = DVec3::new(rng.random_range(-1.0..1.0), 0.0, rng.random_range(-1.0..1.0)).normalize();
            c.add_impulse_at(i, b.r_m + DVec3::Y * rng.random_range(0.0..0.6), d * 110.0);
        }
        c.step();
        if k % 5 != 0 {
            continue;
        }
        if pending.len() == 4 {
            let (states, then) = pending.pop_front().unwrap();
            for (i, (s, want)) in states.iter().zip(&then).enumerate() {
                let mut got = [DVec3::ZERO; MAX_JOINTS];
                assert_eq!(figures.world_joints(s, &mut got), n);
                for j in 0..n {
                    assert_eq!(
                        [got[j].x.to_bits(), got[j].y.to_bits(), got[j].z.to_bits()],
                        [want[j].x.to_bits(), want[j].y.to_bits(), want[j].z.to_bits()],
                        "character {i} joint {j}, copied 20 steps before step {k}"
                    );
                }
                let mut now = [DVec3::ZERO; MAX_JOINTS];
                world_joints(&c, i, &mut now);
                moved += usize::from(now[..n] != want[..n]);
            }
        }
        let mut states = Vec::new();
        let mut then = Vec::new();
        for i in 0..c.len() {
            states.push(FigureState::of(&c, i));
            let mut j = [DVec3::ZERO; MAX_JOINTS];
            assert_eq!(world_joints(&c, i, &mut j), n);
            then.push(j);
            let ch = &c.chars[i];
            if !seen_policies.contains(&ch.control.policy) {
                seen_policies.push(ch.control.policy);
            }
            blends += usize::from(ch.anim.blend < 1.0 && ch.anim.from_behaviour != ch.anim.behaviour);
            swings += usize::from(ch.control.feet.foot.iter().any(|f| !f.planted()));
            handovers += usize::from(ch.control.feet.grip > 0.0 && ch.control.feet.grip < 1.0);
            polar += usize::from(c.starts[i].space().e_yr.y < 0.52f64.cos());
        }
        pending.push_back((states, then));
    }
    assert_eq!(seen_policies.len(), 4, "control states met: {seen_policies:?}");
    for (what, count) in [
        ("behaviour blends", blends),
        ("swinging feet", swings),
        ("leg handovers", handovers),
        ("polar leans", polar),
    ] {
        assert!(count > 0, "no {what} met");
    }
    assert!(moved > 0, "the figures never moved between a copy and its drawing");
}

/// The drawn figures of a wandering crowd pushed over and over (every joint of every character,
/// every tenth step) are pinned: a change to anything a figure is computed from changes this.
#[test]
fn the_drawn_figures_of_a_pushed_crowd_are_pinned() {
    use spidar_sim::character::drawn::world_joints;
    use spidar_sim::character::skeleton::MAX_JOINTS;
    let (mut c, mut rng) = wandering_crowd(7);
    let mut h = spidar_msg::digest::Digest::new();
    let mut falls = 0;
    for k in 0..(10.0 / DT) as usize {
        if k % 60 == 30 {
            let i = rng.random_range(0..c.len());
            let b = c.body_space(i);
            let d = DVec3::new(rng.random_range(-1.0..1.0), 0.0, rng.random_range(-1.0..1.0)).normalize();
            c.add_impulse_at(i, b.r_m + DVec3::Y * rng.random_range(0.0..0.6), d * 110.0);
        }
        c.step();
        falls += c.chars.iter().filter(|ch| ch.control.policy == Policy::Fall).count();
        if k % 10 == 0 {
            for i in 0..c.len() {
                let mut j = [DVec3::ZERO; MAX_JOINTS];
                let n = world_joints(&c, i, &mut j);
                for p in &j[..n] {
                    h.vec3(*p);
                }
            }
        }
    }
    assert!(falls > 0, "the pushes should topple someone");
    let h = h.value();
    assert_eq!(h, 0x2247_5b35_6b54_6e2b, "figure digest changed: {h:#018x}");
}

/// Walking to a point and stopping: it arrives without overshooting, stands still with its feet
/// side by side under it, and shows the standing pose (not a frozen stride).
#[test]
fn a_stop_settles_into_the_standing_pose() {
    let mut c = crowd();
    let to = DVec3::new(0.5, 0.0, 2.5);
    c.add(0.0, 0.0, 0.0, Goal::WalkTo { point_m: to, speed_m_per_s: 0.9 });
    let mut beyond: f64 = 0.0;
    for _ in 0..(9.0 / DT) as usize {
        c.step();
        let b = c.body_space(0);
        let along = (to - DVec3::ZERO).normalize();
        beyond = beyond.max((b.r_m - to).dot(along));
    }
    let b = c.body_space(0);
    assert!(beyond < 0.1, "overshot the target by {beyond} m");
    assert!(DVec3::new(b.r_m.x - to.x, 0.0, b.r_m.z - to.z).length() < 0.15, "stopped at {}", b.r_m);
    assert!(upright_and_still(&c));
    let f = c.chars[0].control.feet;
    let apart = f.foot[0].pos_m - f.foot[1].pos_m;
    let (side, front) = (apart.dot(b.heading.e_xc), apart.dot(b.heading.e_zc));
    assert!(
        front.abs() < 0.07 && (0.08..0.26).contains(&side),
        "feet {side} m apart across, {front} m along"
    );
    // The walk cycle is at a standing phase: the drawn arms hang as in the standing keyframe.
    let mut rest = SkeletonPose::default();
    c.set.pose(&QPoint::default(), &mut rest);
    let arms: Vec<usize> = c
        .set
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| j.name.contains("shoulder"))
        .map(|(i, _)| i)
        .collect();
    for j in arms {
        let err = c.pose_of(0).rot[j].angle_between(rest.rot[j]);
        assert!(
            err < 3f32.to_radians(),
            "{} is {} deg from standing",
            c.set.joints[j].name,
            err.to_degrees()
        );
    }
}

/// The crowd stepper and the general engine give the same motion for one character, pushed.
#[test]
fn crowd_stepper_and_engine_agree_for_one_character() {
    let scene = "(kind: \"body-scene\", version: 1, dt_s: 0.003, gravity_m_per_s2: (0.0, -9.81, 0.0), \
        contact: (stiffness: Abs(4e5), damping: Abs(4000.0), friction: 0.0, slip_m_per_s: 0.01), \
        joint_limit: (stiffness_n_m_per_rad: 300.0, damping_n_m_s_per_rad: 5.0), \
        statics: [(name: \"floor\", shape: Plane)], actors: [(name: \"c\", body: \"c.ron\", pos_m: (0.0, 0.0, 0.0))])";
    let m = build_scene(scene, "test", |_| Ok((BODY_CHARACTER_RON.to_string(), "c.ron".into()))).unwrap();
    let (mut s, mut ws) = (State::new(&m), Workspace::new(&m));
    let mut ch = spidar_sim::character::Character::default();
    let mut c = crowd();
    c.add(0.0, 0.0, 0.0, Goal::Stand);
    let params = c.params;
    let set = c.set.clone();
    let mut worst: f64 = 0.0;
    let mut seen = vec![Policy::Balance];
    for k in 0..3000 {
        kinematics(&m, &s, &mut ws);
        let eb = ch.drive_engine(&m, &mut ws, 0, &params, &set);
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
fn the_shipped_set_has_the_papers_shape() {
    let set = KeyframeSet::builtin();
    // Section 6.1: twelve one-dimensional animations in two behaviours.
    assert_eq!(set.animations, 12);
    assert_eq!(set.behaviours, vec!["walking and falling", "standing up"]);
    assert!(set.keys.len() >= 48, "{} keyframes", set.keys.len());
    // Its quaternions are stored so that posing needs no sign tests (a speed matter only).
    assert_eq!(set.aligned_planes(), (4, 4));
    // Standing-up keyframes are all on the (Theta_z = 0, D_x = 0, D_z = 0) line (section 6.1).
    for k in set.keys.iter().filter(|k| k.at.behaviour == 1) {
        assert!(k.at.theta_z == 0.0 && k.at.d_x == 0.0 && k.at.d_z == 0.0, "{:?}", k.at);
    }
    assert!(set.legs.is_some(), "the set names the legs that stand on the feet");
}

#[test]
fn the_interpolated_pose_equals_the_keyframe_at_each_keyframe() {
    let set = KeyframeSet::builtin();
    let n = set.joints.len();
    let mut out = SkeletonPose::default();
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
    let mut q = QPoint::default();
    let mut anim = spidar_sim::character::Correspondence { blend: 1.0, ..Default::default() };
    let (mut prev, mut cur) = (SkeletonPose::default(), SkeletonPose::default());
    set.pose(&q, &mut prev);
    let (mut worst, mut total) = (0.0f64, 0.0);
    let mut wraps = 0;
    for step in 0..200_000 {
        // Leans move at up to 3 rad/s, phases at up to 2 cycles/s (faster than any character).
        q.theta_x = (q.theta_x + rng.random_range(-3.0..3.0) * DT).clamp(-3.1, 3.1);
        q.theta_z = (q.theta_z + rng.random_range(-3.0..3.0) * DT).clamp(-1.55, 1.55);
        let (dx, dz) = (q.d_x + rng.random_range(0.0..2.0) * DT, q.d_z + rng.random_range(-1.0..2.0) * DT);
        wraps += (!(0.0..1.0).contains(&dz) || dx >= 1.0) as u32;
        q.d_x = spidar_sim::character::periodic(dx);
        q.d_z = spidar_sim::character::periodic(dz);
        let behaviour = if (step / 5000) % 2 == 1 { 1 } else { 0 };
        if behaviour != anim.behaviour {
            anim.from_behaviour = anim.behaviour;
            anim.behaviour = behaviour;
            anim.blend = 0.0;
        }
        anim.blend = (anim.blend + DT / set.behaviour_blend_s).min(1.0);
        q.behaviour = anim.behaviour;
        set.pose_blended(&q, anim.from_behaviour, anim.blend, &mut cur);
        let d = cur.max_angle_to(&prev, n);
        worst = worst.max(d);
        total += d;
        prev = cur;
    }
    assert!(wraps > 100, "the path must cross the phase wrap often ({wraps})");
    assert!(total > 10.0, "the path must actually animate (total {total} rad)");
    assert!(worst < 4f64.to_radians(), "a joint turned {} deg in one step", worst.to_degrees());
}

#[test]
fn the_pose_wraps_smoothly_at_the_walk_phase_boundary() {
    let set = KeyframeSet::builtin();
    let n = set.joints.len();
    let (mut a, mut b) = (SkeletonPose::default(), SkeletonPose::default());
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

// ---- determinism ----

/// A crowd large enough to step on several threads, wandering and bumping, with pushes.
fn busy_crowd(seed: u64, n: usize, seconds: f64) -> (u64, usize) {
    let mut c = crowd();
    c.seed(seed);
    let side = (n as f64).sqrt().ceil() as usize;
    let half = side as f64 * 0.55;
    c.wander = Some([-half, -half, half, half]);
    let mut rng = Pcg64::seed_from_u64(seed);
    for i in 0..n {
        // 1.1 m apart: neighbours touch as they wander.
        c.add(
            (i % side) as f64 * 1.1 - half,
            (i / side) as f64 * 1.1 - half,
            rng.random_range(-3.0..3.0),
            Goal::Stand,
        );
    }
    let mut falls = 0;
    for k in 0..(seconds / DT) as usize {
        if k % 100 == 50 {
            let i = rng.random_range(0..c.len());
            let b = c.body_space(i);
            let d = DVec3::new(rng.random_range(-1.0..1.0), 0.0, rng.random_range(-1.0..1.0)).normalize();
            c.add_impulse_at(i, b.r_m + DVec3::Y * rng.random_range(0.0..0.6), d * 110.0);
        }
        c.step();
        falls += c.chars.iter().filter(|ch| ch.control.policy == Policy::Fall).count();
    }
    (c.digest(), falls)
}

/// A wandering crowd with random pushes: the same seed gives the same motion, bit for bit, and
/// its digest is pinned.
#[test]
fn the_same_seed_gives_the_same_crowd_motion() {
    let (a, falls) = busy_crowd(2, 30, 9.0);
    assert_eq!(a, busy_crowd(2, 30, 9.0).0);
    assert_ne!(a, busy_crowd(3, 30, 9.0).0);
    assert!(falls > 0, "the pushes should topple someone");
    // Pinned: a change of any result of the step changes this.
    assert_eq!(a, 0xb4f3_c26a_014a_8f3e, "digest changed: {a:#018x}");
}

/// The crowd step on all cores gives the same bits as on one, for 1, 2 and 4 threads (with
/// contacts between characters, pushes and falls).
#[test]
fn the_crowd_step_is_bit_identical_for_1_2_and_4_threads() {
    let n = 1000;
    let digests: Vec<(usize, u64, usize)> = [1usize, 2, 4]
        .iter()
        .map(|&threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let (d, falls) = pool.install(|| busy_crowd(5, n, 2.0));
            (threads, d, falls)
        })
        .collect();
    assert!(digests[0].2 > 0, "the pushes should topple someone");
    for (threads, d, _) in &digests {
        assert_eq!(*d, digests[0].1, "{threads} threads differ from 1");
    }
}

// ---- the crowd scene file ----

#[test]
fn the_shipped_crowd_scene_loads_from_disk_and_walks() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/scene-crowd.ron");
    let mut c = spidar_sim::character::scene::load_crowd(std::path::Path::new(path)).unwrap();
    assert_eq!(c.len(), 10);
    let stations = c.chars.iter().filter(|ch| matches!(ch.goal, Goal::Station { .. })).count();
    assert_eq!(stations, 2, "the front row");
    let start: Vec<DVec3> = (0..c.len()).map(|i| c.body_space(i).r_m).collect();
    let mut falls = 0;
    let mut walked = vec![0.0; c.len()];
    let mut last = start.clone();
    for k in 0..(20.0 / DT) as usize {
        c.step();
        falls += c.chars.iter().filter(|ch| ch.control.policy == Policy::Fall).count();
        if k % 100 == 0 {
            for i in 0..c.len() {
                let p = c.body_space(i).r_m;
                walked[i] += (p - last[i]).length();
                last[i] = p;
            }
        }
    }
    assert_eq!(falls, 0, "nobody falls by walking about");
    for (i, s) in start.iter().enumerate() {
        let b = c.body_space(i);
        assert!(b.r_m.is_finite());
        let moved = (b.r_m - *s).length();
        if matches!(c.chars[i].goal, Goal::Station { .. }) {
            assert!(moved < 0.05, "station {i} left its spot by {moved} m");
        } else {
            assert!(walked[i] > 2.0, "character {i} walked only {} m", walked[i]);
            let a = [-2.4, -4.2, 2.4, -1.4];
            assert!(
                b.r_m.x > a[0] - 1.0 && b.r_m.x < a[2] + 1.0 && b.r_m.z > a[1] - 1.0 && b.r_m.z < a[3] + 1.0
            );
        }
    }
}

/// After the first step a crowd step (AI, controllers, contacts, grid, integration) allocates
/// nothing, even while the crowd spreads out and characters fall; nor do the drawn figures a viewer
/// asks for between steps.
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
            if k % 6 == 0 {
                let mut figures = [[DVec3::ZERO; 3]; 25];
                drawn::for_each_figure(&c, &mut figures, 1, |_, joints, slot| {
                    slot[0] = [joints[0], joints[3], joints[15]]
                });
                std::hint::black_box(&figures);
            }
        }
    });
    assert_eq!(n, 0, "{n} allocations in 2000 crowd steps");
    assert!(alloc_count::count(|| drop(vec![1u8; 10])) > 0);
}

// ---- loader errors: every count, size and area bounded, located ----

/// `text` with the first `from` replaced by `to`, and the error it gives: it must name `origin`,
/// the line of the replaced text and `field`.
fn located<T: std::fmt::Debug>(
    base: &str,
    from: &str,
    to: &str,
    field: &str,
    parse: impl Fn(&str) -> Result<T, spidar_sim::SimError>,
) -> String {
    assert!(base.contains(from), "{from:?} is not in the file");
    let text = base.replacen(from, to, 1);
    let e = parse(&text).expect_err(&format!("{to:?} must be refused")).to_string();
    let line = base[..base.find(from).unwrap()].matches('\n').count() + 1;
    assert!(e.starts_with(&format!("f.ron:{line}:")), "{to:?}: {e}");
    assert!(e.contains(field), "{to:?}: {e} does not name {field}");
    e
}

#[test]
fn bad_crowd_scene_values_are_located_and_explained() {
    let scene = |t: &str| {
        build_crowd(t, "f.ron", |name| {
            Ok(match name {
                "body-character.ron" => (BODY_CHARACTER_RON.to_string(), "b.ron".into()),
                _ => (KEYFRAMES_HUMANOID_RON.to_string(), "k.ron".into()),
            })
        })
    };
    for (from, to, field) in [
        ("count: 8,", "count: 18446744073709551615,", "crowd.count"),
        ("count: 8,", "count: 5000,", "crowd.count"),
        ("area_m: (-2.4, -4.2, 2.4, -1.4),", "area_m: (-2.4, -4.2, NaN, -1.4),", "crowd.area_m"),
        ("area_m: (-2.4, -4.2, 2.4, -1.4),", "area_m: (-1e300, -4.2, 1e300, -1.4),", "crowd.area_m"),
        ("area_m: (-2.4, -4.2, 2.4, -1.4),", "area_m: (-2.4, -4.2, inf, -1.4),", "crowd.area_m"),
        ("walk_speed_m_per_s: 0.6,", "walk_speed_m_per_s: -1.0,", "walk_speed_m_per_s"),
        ("dt_s: 0.003,", "dt_s: NaN,", "dt_s"),
        ("gravity_m_per_s2: (0.0, -9.81, 0.0),", "gravity_m_per_s2: (0.0, inf, 0.0),", "gravity_m_per_s2"),
        ("stiffness: Abs(400000.0),", "stiffness: Abs(NaN),", "contact.stiffness"),
        ("floor_friction: 0.8,", "floor_friction: inf,", "character.controller.floor_friction"),
        ("step_front_max_m: 0.6,", "step_front_max_m: 0.0,", "character.controller.step_front_max_m"),
        ("arrive_m: 0.05,", "arrive_m: NaN,", "character.ai.arrive_m"),
        (
            "(at_m: (-0.32, -0.62), heading_deg: 0.0),",
            "(at_m: (NaN, -0.62), heading_deg: 0.0),",
            "crowd.stations[0]",
        ),
    ] {
        located(SCENE_CROWD_RON, from, to, field, scene);
    }
    // A crowd of stations only is fine; one of nothing is not.
    let only_stations = SCENE_CROWD_RON.replacen("count: 8,", "count: 0,", 1);
    assert_eq!(scene(&only_stations).unwrap().len(), 2);
    let start = SCENE_CROWD_RON.find("        stations: [").unwrap();
    let end = start + SCENE_CROWD_RON[start..].find("        ],\n").unwrap() + "        ],\n".len();
    let no_stations = format!("{}{}", &SCENE_CROWD_RON[..start], &SCENE_CROWD_RON[end..]);
    let e = located(&no_stations, "count: 8,", "count: 0,", "crowd.count", scene);
    assert!(e.contains("1 to"), "{e}");
}

#[test]
fn bad_body_values_are_located_and_explained() {
    let body = |t: &str| parse_body(t, "f.ron");
    let inertia = "inertia_kg_m2: (10.0, 10.0, 10.0)";
    for (from, to, field) in [
        (inertia, "inertia_kg_m2: (10.0, NaN, 10.0)", "mass"),
        (inertia, "inertia_kg_m2: (10.0, 10.0, inf)", "mass"),
        ("mass_kg: 40.0", "mass_kg: 1e300", "mass"),
        ("centre_m: (0.0, 0.0, 0.0)", "centre_m: (0.0, NaN, 0.0)", "mass"),
        ("Sphere(radius_m: 0.12)", "Sphere(radius_m: NaN)", "shape"),
        ("Box(size_m: (0.16, 0.06, 0.10))", "Box(size_m: (0.16, NaN, 0.10))", "shape"),
        (
            "Capsule(half_length_m: 0.33, radius_m: 0.13)",
            "Capsule(half_length_m: 1e9, radius_m: 0.13)",
            "shape",
        ),
        ("anchor_m: (0.0, 0.75, 0.0)", "anchor_m: (0.0, inf, 0.0)", "anchor_m"),
        ("gain_dt_s: 0.003,", "gain_dt_s: NaN,", "gain_dt_s"),
    ] {
        located(BODY_CHARACTER_RON, from, to, field, body);
    }
}

#[test]
fn bad_keyframe_values_are_located_and_explained() {
    let set = |t: &str| KeyframeSet::parse(t, "f.ron");
    let k = KEYFRAMES_HUMANOID_RON;
    for (from, to, field) in [
        ("stride_front_m: 0.9,", "stride_front_m: NaN,", "stride_front_m"),
        ("stride_front_m: 0.9,", "stride_front_m: 1e300,", "stride_front_m"),
        ("behaviour_blend_s: 0.3,", "behaviour_blend_s: inf,", "behaviour_blend_s"),
        ("offset_m: (0.0, 0.38, 0.0)", "offset_m: (0.0, NaN, 0.0)", "skeleton[2].offset_m"),
        ("(name: \"neck\"", "(name: \"spine\"", "skeleton[2].name"),
        ("line: (theta_x_deg: 25.0)", "line: (theta_x_deg: NaN)", "animations[1].line"),
        ("(at: 0.125, pose:", "(at: NaN, pose:", "animations[0].keys[1].at"),
        ("ankle_height_m: 0.04", "ankle_height_m: -1.0", "legs.ankle_height_m"),
        ("ankles: (\"l_ankle\", \"r_ankle\")", "ankles: (\"l_ankle\", \"r_foot\")", "legs.ankles"),
        ("line: (theta_x_deg: 25.0)", "line: (theta_x_deg: 25.0, theta_z_deg: 10.0)", "front plane"),
        ("\"l_knee\": (", "\"l_knee2\": (", "no joint \"l_knee2\""),
    ] {
        located(k, from, to, field, set);
    }
    // No keyframes at all, and an animation without keys.
    let start = k.find("    animations: [").unwrap();
    let empty = format!("{}    animations: [],\n)\n", &k[..start]);
    let e = KeyframeSet::parse(&empty, "f.ron").unwrap_err().to_string();
    assert!(e.starts_with("f.ron:") && e.contains("animations"), "{e}");
    let first = k.find("            keys: [\n").unwrap() + "            keys: [\n".len();
    let end = first + k[first..].find("            ],\n").unwrap();
    let no_keys = format!("{}{}", &k[..first], &k[end..]);
    let e = KeyframeSet::parse(&no_keys, "f.ron").unwrap_err().to_string();
    assert!(e.starts_with("f.ron:") && e.contains("animations[0].keys") && e.contains("1 to"), "{e}");
}
