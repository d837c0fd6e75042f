//! The calibration loop (`TickCore::calibrate`): Inactive for good and unhomed, strings at
//! minimum tension with zero net force, every hand's counts checked step by step against the last
//! reply taken, so that `spidar calib` reads only counts the loop's rules let through.

use super::*;

fn calibrating() -> TickCore {
    let mut c = core();
    c.calibrate();
    c
}

/// One calibration tick with these counts.
fn tick_counts(c: &mut TickCore, out: &mut Output, counts: &[i64; MAX_CHANNELS]) -> TickRecord {
    tick_io(c, out, None, counts, Ok(())).1
}

#[test]
fn calibrating_refuses_home_and_activate_and_holds_the_strings_at_minimum_tension() {
    let mut c = calibrating();
    c.command(Command::Home);
    c.command(Command::Activate);
    let refused: Vec<Command> = std::iter::from_fn(|| c.pop_event())
        .filter_map(|e| match e {
            Event::Refused { command, .. } => Some(command),
            _ => None,
        })
        .collect();
    assert_eq!(refused, [Command::Home, Command::Activate]);
    let (out, rec) = run(&mut c, 500, Ok(()));
    assert_eq!((rec.state, c.is_homed(), c.is_homing()), (Lifecycle::Inactive, false, false));
    for (h, hr) in c.rig().hands.iter().enumerate() {
        let t = rec.hands[h].tensions_n;
        assert!(t.iter().all(|&t| t >= hr.tension_min_n - 1e-9), "hand {h}: {t:?}");
        assert!(t.iter().any(|&t| (t - hr.tension_min_n).abs() < 1e-9), "hand {h}: {t:?}");
        assert!(rec.hands[h].output_n.length() < 1e-9, "zero net force at home");
        for (s, &ch) in hr.channels.iter().enumerate() {
            assert_eq!(out.volts[ch], t[s] * hr.volts_per_newton[s]);
        }
    }
    // Held still at home for longer than `rehome_still_s`: still no homing.
    run(&mut c, 5_000, Ok(()));
    assert!(!c.is_homed() && c.counters().rehomes == 0);
}

#[test]
fn calibrating_a_garbled_count_is_rejected_and_held_and_a_step_that_stays_faults_then_is_taken() {
    let mut c = calibrating();
    let mut out = Output::default();
    let ch = c.rig().hands[1].channels[2];
    // 2 mm of string in counts on that channel (about 69 on the built-in rig).
    let jump = (c.rig().safety.reply_jump_m / c.rig().hands[1].metres_per_count[2].abs()).floor() as i64;
    let mut counts = [5_000i64; MAX_CHANNELS];
    // A grip moved by hand: one count a tick, never rejected.
    for _ in 0..200 {
        counts[ch] += 1;
        let r = tick_counts(&mut c, &mut out, &counts);
        assert!(!r.hands[1].held && r.state == Lifecycle::Inactive);
    }
    assert_eq!(c.counters().count_jumps, [0, 0]);
    // A garbled reply: 4000 counts off on one string of hand 1 (12 cm), then a good one again.
    let mut garbled = counts;
    garbled[ch] += 4_000;
    let r = tick_counts(&mut c, &mut out, &garbled);
    assert!(r.hands[1].held && !r.hands[0].held, "only the hand with the bad count is held");
    let r = tick_counts(&mut c, &mut out, &counts);
    assert!(!r.hands[1].held);
    assert_eq!(c.counters().count_jumps, [0, 1]);
    // After a late reply the allowance grows with the ticks since the last reply taken.
    run(&mut c, 1, Err(TIMEOUT));
    counts[ch] += 2 * jump - 1;
    assert!(!tick_counts(&mut c, &mut out, &counts).hands[1].held);
    // A real step (a string that slipped on its pulley) stays: a run of rejections faults ...
    counts[ch] += 10 * jump;
    let n = reply_limit(&c);
    for _ in 0..n - 1 {
        let r = tick_counts(&mut c, &mut out, &counts);
        assert!(r.hands[1].held && r.state == Lifecycle::Inactive);
    }
    let r = tick_counts(&mut c, &mut out, &counts);
    assert_eq!((r.state, r.fault), (Lifecycle::Faulted, Some(FaultReason::CountJump { hand: 1 })));
    // ... which clears by itself, and the step is taken from then on: still calibrating.
    let recover = c.rig().safety.fault_recovery_ticks as usize;
    for _ in 0..recover {
        tick_counts(&mut c, &mut out, &counts);
    }
    let r = tick_counts(&mut c, &mut out, &counts);
    assert_eq!((r.state, r.hands[1].held), (Lifecycle::Inactive, false));
    assert!(!c.is_homed() && c.is_calibrating());
    assert_eq!(c.counters().count_jumps, [0, 1 + n as u64]);
}

#[test]
fn without_calibrating_an_unhomed_hand_takes_its_counts_as_they_come() {
    // What the calibration mode adds: an ordinary inactive rig's unhomed hands are not checked.
    let mut c = core();
    let mut out = Output::default();
    let mut counts = [5_000i64; MAX_CHANNELS];
    tick_counts(&mut c, &mut out, &counts);
    counts[c.rig().hands[0].channels[0]] += 4_000;
    assert!(!tick_counts(&mut c, &mut out, &counts).hands[0].held);
    assert_eq!(c.counters().count_jumps, [0, 0]);
}
