//! The crowd scene behind the whole haptic stack: hands pushing keyframe characters through the
//! simulated rig and the rt-loop (the path `spidar run --scene crowd` takes), with the scene
//! stepped here on the virtual clock so the test can read its counters.

use glam::DVec3;
use spidar_device::sim::Script;
use spidar_rt::Clock;
use spidar_runtime::session::{load_scripts, SimOptions};
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_world::crowd::CrowdScene;
use spidar_world::Scene;

use super::{reach_and_hold, rig, session, truth};

/// The left hand reaches 2 cm into the chest of a character standing in front of it. The hand
/// feels the character (force toward the user, at the rig's clamp), the character receives the
/// hand's whole contact as impulses (the rig's share of it is what the hand felt), and it gives way
/// by stepping back without falling.
#[test]
fn a_hand_push_reaches_the_character_and_its_reaction_reaches_the_hand() {
    let r = rig();
    let home = [r.hands[0].home_m, r.hands[1].home_m];
    // Rig frame: 0.2 m below the rig origin is 0.9 m above the floor, 0.15 m above the centre of mass.
    let press = DVec3::new(home[0].x, -0.2, -0.30);
    let mut v = session([reach_and_hold(press), Script::hold(home[1])], None, &SimOptions::default());
    // The built-in crowd scene's world and characters, with just one character in it.
    let mut crowd = spidar_sim::character::scene::builtin_crowd().unwrap().empty_like();
    // Facing the user (+z), its chest surface 0.32 m in front of the rig origin.
    crowd.add(home[0].x, -0.42, 0.0, Goal::Stand);
    let mut scene = CrowdScene::new(crowd, "one character");
    let start = scene.crowd.body_space(0).r_m;
    let (mut hand_impulse, mut peak_felt) = (DVec3::ZERO, 0.0f64);
    let mut last_tick = None;
    for _ in 0..4000 {
        v.tick();
        let Some(s) = v.last_sample else { continue };
        if last_tick == Some(s.tick) {
            continue;
        }
        last_tick = Some(s.tick);
        if s.model_seq != 0 && s.proxy_impulse_n_s.iter().any(|i| *i != DVec3::ZERO) {
            hand_impulse += (s.hands[0].force_n + s.hands[1].force_n) * r.period_s;
        }
        peak_felt = peak_felt.max(truth(&v).hands[0].string_force_n.z);
        let m = scene.step(v.clock.now_ns() as f64 * 1e-9, &[s]);
        let _ = v.far.models.try_send(m);
    }
    let end = scene.crowd.body_space(0);
    // The reaction reaches the hand: the strings pull it back toward the user (+z), up to the clamp.
    assert!(peak_felt > 0.5 * r.hands[0].force_limit_n, "the hand felt at most {peak_felt} N");
    // The push reaches the character: the whole contact, of which the hand felt the rig's share.
    let (given, felt) = (scene.impulse_total_n_s, scene.felt_total_n_s);
    assert!(given.z < -1.0, "impulse given to the character {given}");
    assert!(
        (felt + hand_impulse).length() < 1e-6 * hand_impulse.length().max(1.0),
        "{felt} vs {hand_impulse}"
    );
    assert!(given.length() >= felt.length() - 1e-9, "the character got less than the hand felt");
    assert_eq!(scene.impulses_unmatched, 0);
    // It gives way in the push's direction and keeps its feet.
    assert!(end.r_m.z - start.z < -0.02, "moved {}", end.r_m - start);
    assert_eq!(scene.crowd.chars[0].control.policy, Policy::Balance);
    assert!(scene.crowd.chars[0].control.feet.steps >= 1, "it did not step back");
    assert_eq!(v.counters().faults, 0);
}

/// `spidar run --scene crowd` with its default script (the simulated user reaches into the front
/// row: pushes, an off-centre push, a shove) for 20 s: several characters are pushed, one falls and
/// stands up again, and the pushing hand feels every push.
#[test]
fn the_crowd_scene_with_its_default_script_pushes_topples_and_raises_characters() {
    let r = rig();
    let scripts = load_scripts(spidar_runtime::session::default_script("crowd"), &r, 1).unwrap();
    let mut v = session(scripts, None, &SimOptions::default());
    let mut scene = CrowdScene::builtin().unwrap();
    let mut last_tick = None;
    // Per push (in order of the scene's count): the strongest force either hand felt within half
    // a second of its start.
    let mut pushes: Vec<(f64, f64)> = Vec::new();
    for _ in 0..20_000 {
        let rec = v.tick();
        let felt = rec.hands[0].output_n.length().max(rec.hands[1].output_n.length());
        for p in pushes.iter_mut().filter(|p| rec.t_s - p.0 < 0.5) {
            p.1 = p.1.max(felt);
        }
        let Some(s) = v.last_sample else { continue };
        if last_tick == Some(s.tick) {
            continue;
        }
        last_tick = Some(s.tick);
        let before = scene.counts.pushes;
        let m = scene.step(v.clock.now_ns() as f64 * 1e-9, &[s]);
        let _ = v.far.models.try_send(m);
        for _ in before..scene.counts.pushes {
            pushes.push((rec.t_s - 0.1, felt));
        }
    }
    let c = scene.counts;
    assert!(c.characters_pushed >= 2 && c.pushes >= 4, "{}", scene.status());
    assert!(c.falls >= 1 && c.stand_ups >= 1, "{}", scene.status());
    for (i, (t, felt)) in pushes.iter().enumerate() {
        assert!(*felt > 1.0, "push {i} at {t:.2} s: the hands felt at most {felt:.2} N");
    }
    // The characters got the contacts; the hands felt them as far as the rig renders force.
    assert!(scene.impulse_sum_n_s > 10.0 * scene.felt_sum_n_s, "{}", scene.status());
    assert_eq!(scene.impulses_unmatched, 0);
    assert_eq!(v.counters().faults, 0);
}
