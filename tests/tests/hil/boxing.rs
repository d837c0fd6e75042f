//! The boxing scene (seed 000) behind the rt-loop on the simulated rig: force feedback is the
//! contact on the avatar's hands, never the coupling spring, and a whole bout runs clean.

use super::*;
use spidar_rt::Clock;
use spidar_sim::boxer::BoxerParams;
use spidar_tools::scene::boxing::{boxing_scripts, BoxingScene};

/// A loop and a boxing scene driven tick by tick (the scene is kept typed so the test can read
/// the world after each step). The scripts jab `target` (0 head, 1 chest, 2/3 the hands).
struct Bout {
    v: VirtualRun<SimRig>,
    scene: BoxingScene,
    samples: Vec<HandSample>,
    /// The samples the last scene step consumed.
    consumed: Vec<HandSample>,
    next_step_ns: u64,
}

impl Bout {
    fn new(params: BoxerParams, seed: u64, punches: usize, target: Option<usize>) -> Bout {
        let rig = rig();
        let scripts = boxing_scripts(&rig, &params, seed, punches, target).unwrap();
        let v = session(scripts, None, &SimOptions { seed, ..Default::default() });
        Bout {
            v,
            scene: BoxingScene::new(params).unwrap(),
            samples: Vec::new(),
            consumed: Vec::new(),
            next_step_ns: 0,
        }
    }

    /// One tick, then a scene step if one is due (true); `consumed` then holds its samples.
    fn tick(&mut self) -> (spidar_rt::telemetry::TickRecord, bool) {
        self.v.rt.tick();
        let rec = *self.v.rt.last_record();
        self.v.stats.add(&rec);
        self.samples.extend(self.v.far.samples.try_iter());
        let now = self.v.clock.now_ns();
        if now >= self.next_step_ns {
            let m = self.scene.step(now as f64 * 1e-9, &self.samples);
            let _ = self.v.far.models.try_send(m);
            self.next_step_ns = now + 3_000_000;
            self.consumed.clear();
            self.consumed.append(&mut self.samples);
            return (rec, true);
        }
        (rec, false)
    }
}

#[test]
fn feedback_force_is_the_contact_on_the_avatar_hand_never_the_coupling_spring() {
    // Passive virtual human, the user jabbing its head: contacts only through the rt-loop.
    let params = BoxerParams { active: false, ..Default::default() };
    let mut b = Bout::new(params, 7, 12, Some(0));
    let (mut contact_steps, mut free_steps, mut max_spring_free, mut max_err) = (0, 0, 0.0f64, 0.0f64);
    let mut max_contact = 0.0f64;
    for _ in 0..15_000 {
        let (_, stepped) = b.tick();
        if !stepped {
            continue;
        }
        let rep = b.scene.world.last;
        let samples = &b.consumed;
        if samples.is_empty() || rep.damage_force_n.length() > 0.0 {
            continue;
        }
        for h in 0..2 {
            // The force the rig put on the user's hand over the step vs the contact force the
            // avatar's hand received in the same step.
            let felt: DVec3 = samples.iter().map(|s| s.hands[h].force_n).sum::<DVec3>() / 3.0;
            let contact = rep.hand_contact_force_n[h];
            if contact.length() > 0.5 {
                contact_steps += 1;
                max_contact = max_contact.max(contact.length());
                max_err = max_err.max((felt - contact).length() / contact.length());
            } else if contact == DVec3::ZERO {
                free_steps += 1;
                // Out of contact the user feels nothing, whatever the spring pulls.
                assert!(
                    felt.length() < 1e-9,
                    "felt {felt} N with no contact (spring {} N)",
                    rep.coupling_force_n[h]
                );
                max_spring_free = max_spring_free.max(rep.coupling_force_n[h].length());
            }
        }
    }
    assert!(contact_steps > 50, "the jabs should land on the head: {contact_steps} contact steps");
    assert!(free_steps > 1000);
    assert!(max_spring_free > 5.0, "the coupling spring did work out of contact: {max_spring_free} N");
    assert!(max_contact > 1.0, "contacts were felt: {max_contact} N");
    // Rendering tolerance: a step averages 3 ticks, and the rig's tension allocation scales a
    // force it cannot render (the impulse is scaled the same way).
    assert!(max_err < 0.05, "felt force differs from the avatar hand's contact by {:.1} %", max_err * 100.0);
}

#[test]
fn a_full_bout_runs_with_no_deadline_miss_and_no_string_out_of_range() {
    let r = rig();
    let mut b = Bout::new(BoxerParams::default(), 1, 60, None);
    let mut out_of_range = 0;
    for _ in 0..60_000 {
        let (rec, _) = b.tick();
        assert_ne!(rec.state, Lifecycle::Faulted, "tick {}: {:?}", rec.tick, rec.fault);
        for (h, hr) in rec.hands.iter().enumerate() {
            for t in hr.tensions_n {
                if !(t >= r.hands[h].tension_min_n - 1e-9 && t <= r.hands[h].tension_max_n + 1e-9) {
                    out_of_range += 1;
                }
            }
            assert!(hr.output_n.length() <= r.hands[h].force_limit_n + 1e-9);
        }
    }
    assert_eq!(out_of_range, 0);
    assert_eq!(b.v.counters().misses, 0, "no deadline missed on the virtual clock");
    let m = &b.scene.world.mind;
    assert!(m.hits_taken > 0, "the user landed nothing: {}", b.scene.status_text());
    assert!(m.predictions > 0 && m.avoidances + m.blocks > 0, "{}", b.scene.status_text());
}

#[test]
fn a_boxing_bout_is_bit_identical_for_a_seed() {
    let digest = |seed: u64| {
        let mut b = Bout::new(BoxerParams { seed, ..Default::default() }, seed, 10, None);
        for _ in 0..8_000 {
            b.tick();
        }
        (b.scene.world.state.digest(), b.scene.world.mind.predictions)
    };
    let (a, preds) = digest(5);
    assert!(preds > 0, "the bout should make the virtual human predict");
    assert_eq!(a, digest(5).0);
    assert_ne!(a, digest(6).0);
}

/// The head's path (centre of mass, world) at every scene step of `ticks` ticks of a passive bout.
fn head_path(punches: usize, ticks: usize) -> Vec<DVec3> {
    let params = BoxerParams { active: false, ..Default::default() };
    let mut b = Bout::new(params, 7, punches, Some(0));
    let mut path = Vec::new();
    for _ in 0..ticks {
        if b.tick().1 {
            path.push(b.scene.world.com(b.scene.world.vh.head));
        }
    }
    path
}

#[test]
fn the_users_jabs_move_a_passive_virtual_humans_head() {
    // The same bout with and without jabs: the head's largest departure from where it would have
    // been is what the punches did (the virtual human also settles and sways on its own).
    let ticks = 12_000;
    let still = head_path(0, ticks);
    let jabbed = head_path(12, ticks);
    let moved = still.iter().zip(&jabbed).map(|(a, b)| (*a - *b).length()).fold(0.0, f64::max);
    eprintln!("head moved {:.1} mm by the jabs", moved * 1e3);
}
