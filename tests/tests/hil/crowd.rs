//! The crowd scene behind the whole haptic stack: a hand pushing a keyframe character.

use glam::DVec3;
use spidar_device::sim::Script;
use spidar_rt::Clock;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::Crowd;
use spidar_tools::session::SimOptions;
use spidar_world::crowd::CrowdScene;
use spidar_world::Scene;

use super::{reach_and_hold, rig, session, truth};

/// The left hand reaches 2 cm into the chest of a character standing in front of it. The hand
/// feels the character (force toward the user, at the rig's clamp), the character receives the
/// reaction as impulses (equal to the hand's force times the tick, summed), and it gives way by
/// stepping back without falling. The scene is driven here every tick so the test keeps it.
#[test]
fn a_hand_push_reaches_the_character_and_its_reaction_reaches_the_hand() {
    let r = rig();
    let home = [r.hands[0].home_m, r.hands[1].home_m];
    // Rig frame: 0.2 m below the rig origin is 0.9 m above the floor, 0.15 m above the centre of mass.
    let press = DVec3::new(home[0].x, -0.2, -0.30);
    let mut v = session([reach_and_hold(press), Script::hold(home[1])], None, &SimOptions::default());
    // The built-in crowd scene's world and characters, with just one character in it.
    let base = spidar_sim::character::scene::builtin_crowd().unwrap();
    let mut crowd = Crowd::new(base.body.clone(), base.world, base.params, base.set.clone());
    crowd.statics = base.statics.clone();
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
    // The push reaches the character, with the same momentum the hand lost.
    let given = scene.impulse_total_n_s;
    assert!(given.z < -1.0, "impulse given to the character {given}");
    assert!(
        (given + hand_impulse).length() < 1e-6 * hand_impulse.length().max(1.0),
        "{given} vs {hand_impulse}"
    );
    assert_eq!(scene.impulses_unmatched, 0);
    // It gives way in the push's direction and keeps its feet.
    assert!(end.r_m.z - start.z < -0.02, "moved {}", end.r_m - start);
    assert_eq!(scene.crowd.chars[0].control.policy, Policy::Balance);
    assert_eq!(v.counters().faults, 0);
}
