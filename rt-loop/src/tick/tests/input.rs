//! Tests of the tick core's input phase (`tick/input.rs`): late and corrupt replies, count
//! jumps judged against the hand's motion, the pose residual, and which hand is held. Each
//! asserts what the rig does tick by tick; none may depend on timing.

use super::*;

#[test]
fn a_late_reply_burst_shorter_than_the_limit_keeps_force_while_a_longer_one_faults() {
    let mut c = core();
    home_and_activate(&mut c);
    let m = pressing_wall(&c);
    let mut out = Output::default();
    let zero = [0i64; MAX_CHANNELS];
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
    }
    let (s0, r0) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
    let pressing = out;
    assert!(r0.hands[0].commanded_n.length() > 3.9, "{r0:?}");
    let n = reply_limit(&c);
    for i in 0..n - 1 {
        let (s, r) = tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
        assert_eq!(r.state, Lifecycle::Active, "burst tick {i}");
        assert_eq!(out, pressing, "the last output is held, to the volt");
        assert!(r.hands.iter().all(|h| h.held));
        assert_eq!(r.hands[0].commanded_n, r0.hands[0].commanded_n);
        assert_eq!(s.proxy_impulse_n_s, s0.proxy_impulse_n_s, "the held force is the applied one");
        assert_eq!(s.proxy_contact_impulse_n_s, s0.proxy_contact_impulse_n_s);
        assert!(s0.proxy_contact_impulse_n_s[0].length() > 0.0);
        assert_eq!(s.hands, s0.hands);
    }
    let (_, r) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
    assert!(r.state == Lifecycle::Active && !r.hands[0].held && r.hands[0].commanded_n.length() > 3.9);
    assert_eq!(c.counters().late_replies, n as u64 - 1);
    assert_eq!(c.counters().faults, 0);
    // One more than the limit: faulted on the n-th, safe at once.
    for _ in 0..n - 1 {
        tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
    }
    assert_eq!(c.state(), Lifecycle::Active);
    let (_, r) = tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
    assert_eq!(r.state, Lifecycle::Faulted);
    assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
    assert!(r.hands[0].output_n.length() < 1e-9);
    assert_ne!(out, pressing);
    let k = c.counters();
    assert_eq!((k.faults, k.late_replies, k.device_errors), (1, 2 * n as u64 - 2, 2 * n as u64 - 1));
}

/// After a late reply the count step's tolerance covers two periods of the hand's motion, and
/// the string's own predicted motion over one period (not over two, or four): a corrupt count
/// just beyond that is rejected on the tick it arrives, one just within it is taken.
#[test]
fn after_a_late_reply_a_count_just_beyond_the_fast_hands_tolerance_is_rejected() {
    let dt = 0.001;
    let v = DVec3::new(2.0, 0.0, 0.0); // a fast punch: 2 mm per tick
                                       // The string that moves most per tick, and how much.
    let probe = core();
    let hr = probe.rig().hands[0].clone();
    let home = hr.home_m;
    let len = |p: DVec3, s: usize| (hr.anchors_m[s] - p).length();
    let (s_max, m) = (0..4)
        .map(|s| (s, (len(home + v * dt, s) - len(home, s)).abs()))
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    assert!(m > 0.001, "{m}");
    let jump = probe.rig().safety.reply_jump_m;
    // Run a hand at constant speed, one late reply, then a reply off by `err_m` on s_max.
    let taken = |err_m: f64| {
        let mut c = core();
        home_and_activate(&mut c);
        let other = c.rig().hands[1].home_m;
        let mut out = Output::default();
        for i in 0..100 {
            let counts = counts_at(&c, [home + v * (dt * i as f64), other]);
            tick_io(&mut c, &mut out, None, &counts, Ok(()));
        }
        let counts = counts_at(&c, [home + v * (dt * 100.0), other]);
        tick_io(&mut c, &mut out, None, &counts, Err(TIMEOUT));
        let p = home + v * (dt * 101.0);
        let mut counts = counts_at(&c, [p, other]);
        counts[hr.channels[s_max]] += (err_m / hr.metres_per_count[s_max]).round() as i64;
        let jumps = c.counters().count_jumps[0];
        let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
        assert_eq!(r.state, Lifecycle::Active);
        (c.counters().count_jumps[0] == jumps, r.hands[0].held)
    };
    // Two periods of reply jump, plus one period of the string's motion (m), plus half a
    // period more: beyond; half a period less: within.
    assert_eq!(taken(2.0 * jump + 1.5 * m), (false, true), "rejected, held");
    assert_eq!(taken(2.0 * jump + 0.5 * m), (true, false), "taken");
}

#[test]
fn a_corrupt_count_is_rejected_on_the_tick_it_arrives_and_a_run_of_them_faults() {
    let mut c = core();
    home_and_activate(&mut c);
    let m = pressing_wall(&c);
    let mut out = Output::default();
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    // The hands move at 1 m/s along x: each tick's counts follow them.
    let at = |k: usize| home.map(|h| h + DVec3::X * (k as f64 * 1e-3));
    let k = std::cell::Cell::new(0);
    let step = |c: &mut TickCore, out: &mut Output, corrupt: Option<(usize, i64)>| {
        let mut counts = counts_at(c, at(k.get()));
        if let Some((ch, by)) = corrupt {
            counts[ch] += by;
        }
        k.set(k.get() + 1);
        tick_io(c, out, Some(m), &counts, Ok(())).1
    };
    for _ in 0..700 {
        step(&mut c, &mut out, None);
    }
    let before = step(&mut c, &mut out, None);
    let held_out = out;
    assert!(!before.hands[0].held);
    // A reply with 4096 counts (12 cm) too many on hand 0's string 2: rejected at once.
    let r = step(&mut c, &mut out, Some((2, 4096)));
    assert!(r.hands[0].held && !r.hands[1].held, "only the hand with the bad count is held");
    assert_eq!(r.hands[0].pos_rig_m, before.hands[0].pos_rig_m);
    assert_eq!(out.volts[..4], held_out.volts[..4]);
    assert_eq!(c.counters().count_jumps, [1, 0]);
    // The next good reply is accepted, from where the hand really is now.
    let r = step(&mut c, &mut out, None);
    assert!(!r.hands[0].held);
    assert!((r.hands[0].pos_rig_m - at(k.get() - 1)[0]).length() < 1e-4, "{}", r.hands[0].pos_rig_m);
    assert!(
        (r.hands[0].vel_rig_m_per_s.x - 1.0).abs() < 0.05,
        "velocity over the skipped tick: {}",
        r.hands[0].vel_rig_m_per_s
    );
    // Small corruptions too: 200 counts (6 mm) on hand 1.
    let r = step(&mut c, &mut out, Some((5, -200)));
    assert!(r.hands[1].held && !r.hands[0].held);
    assert_eq!(c.counters().count_jumps, [1, 1]);
    assert_eq!(c.counters().faults, 0);
    // Counts that stay away (an encoder that slipped, a board that keeps garbling) fault.
    let n = reply_limit(&c);
    for _ in 0..n - 1 {
        assert_eq!(step(&mut c, &mut out, Some((0, 3000))).state, Lifecycle::Active);
    }
    let r = step(&mut c, &mut out, Some((0, 3000)));
    assert_eq!(r.fault, Some(FaultReason::CountJump { hand: 0 }));
    assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
    assert_eq!(c.counters().count_jumps, [1 + n as u64, 1]);
    assert_eq!(c.counters().held, [1 + n as u64 - 1, 1]);
}

#[test]
fn a_tick_that_woke_late_is_judged_by_the_time_that_passed_not_as_a_jump() {
    let mut c = core();
    home_and_activate(&mut c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let (mut out, mut rec, mut s) = (Output::default(), TickRecord::default(), HandSample::default());
    // The hands move at 1 m/s along x; on the real clock.
    let mut t = c.counters.ticks as f64 * 0.001;
    let mut x = 0.0;
    let mut tick = |c: &mut TickCore, dt: f64| {
        t += dt;
        x += dt; // 1 m/s
        let inp = Input { counts: counts_at(c, home.map(|h| h + DVec3::X * x)), status: 0 };
        c.step(t, Ok(()), &inp, &mut out, &mut s, &mut rec);
        rec
    };
    for _ in 0..300 {
        tick(&mut c, 0.001);
    }
    // The loop wakes 6 ms late: the hands moved 6 mm, three times the per-tick tolerance.
    let r = tick(&mut c, 0.006);
    assert!(!r.hands[0].held && !r.hands[1].held, "{:?}", c.counters());
    assert_eq!(c.counters().count_jumps, [0, 0]);
    assert!(
        (r.hands[0].vel_rig_m_per_s.x - 1.0).abs() < 0.05,
        "velocity over the late tick: {}",
        r.hands[0].vel_rig_m_per_s
    );
}

#[test]
fn a_fast_steady_hand_is_never_taken_for_a_jump_and_its_volts_are_its_tensions() {
    let mut c = core();
    home_and_activate(&mut c);
    let m = pressing_wall(&c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let mut out = Output::default();
    // Both hands speed up at 30 m/s^2 to 3 m/s (3 mm per tick, beyond reply_jump_m alone),
    // then sweep on: the prediction from their velocity keeps every reply.
    let along = |k: usize| {
        let t = k as f64 * 1e-3;
        if t < 0.1 {
            15.0 * t * t
        } else {
            0.15 + 3.0 * (t - 0.1)
        }
    };
    for k in 0..200 {
        let p = home.map(|h| h + DVec3::new(0.0, 1.0, -1.0).normalize() * along(k));
        let counts = counts_at(&c, p);
        let (_, r) = tick_io(&mut c, &mut out, Some(m), &counts, Ok(()));
        for (h, hr) in c.rig().hands.iter().enumerate() {
            for s in 0..4 {
                let want = r.hands[h].tensions_n[s] * hr.volts_per_newton[s];
                assert_eq!(out.volts[hr.channels[s]], want, "the volts written are the tensions'");
            }
        }
    }
    assert_eq!(c.counters().count_jumps, [0, 0]);
    assert_eq!(c.counters().held, [0, 0]);
}

#[test]
fn a_pose_above_the_residual_limit_is_held_and_a_run_of_them_faults() {
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let zero = [0i64; MAX_CHANNELS];
    for _ in 0..10 {
        tick_io(&mut c, &mut out, None, &zero, Ok(()));
    }
    // String 1 of hand 0 creeps 0.2 mm per tick (a slipping encoder): slow enough for the jump
    // check, inconsistent with the other three.
    let mpc = c.rig().hands[0].metres_per_count[1];
    let limit = c.rig().safety.residual_fault_ticks;
    let mut held = 0;
    let mut fault_at = None;
    for i in 1..400 {
        let mut counts = zero;
        counts[1] = (i as f64 * 0.2e-3 / mpc).round() as i64;
        let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
        if r.state == Lifecycle::Faulted {
            fault_at = Some(r.fault);
            break;
        }
        held += r.hands[0].held as u64;
    }
    assert_eq!(fault_at, Some(Some(FaultReason::Residual { hand: 0 })));
    assert_eq!(held, u64::from(limit) - 1, "each tick above the limit before the fault is held");
    assert_eq!(c.counters().residual_high[0], u64::from(limit));
    assert_eq!(c.counters().held, [u64::from(limit) - 1, 0]);
    assert_eq!(c.counters().count_jumps, [0, 0]);
}

#[test]
fn a_faulted_rig_is_never_held_and_its_safe_output_comes_from_the_last_good_pose() {
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let away = [home[0] + DVec3::new(0.1, 0.2, 0.0), home[1]];
    let counts = counts_at(&c, away);
    for _ in 0..3 {
        let h0 = counts_at(&c, home);
        tick_io(&mut c, &mut out, None, &h0, Ok(()));
    }
    // Walk hand 0 to `away` slowly, then a reply that makes a length negative: no pose.
    for k in 1..=200 {
        let p = [home[0] + (away[0] - home[0]) * (k as f64 / 200.0), home[1]];
        let cp = counts_at(&c, p);
        tick_io(&mut c, &mut out, None, &cp, Ok(()));
    }
    let _ = counts;
    c.command(Command::Home); // refused while active: nothing changes
    let mut bad = counts_at(&c, away);
    bad[0] = -1_000_000_000;
    // Without a velocity history the jump check cannot judge it; the kinematics refuse it.
    for h in c.hands.iter_mut() {
        h.vel.reset();
    }
    let (_, r) = tick_io(&mut c, &mut out, None, &bad, Ok(()));
    assert_eq!(r.fault, Some(FaultReason::PoseInvalid { hand: 0 }));
    let h = &r.hands[0];
    assert!(!h.held && !h.valid);
    assert!(h.tensions_n.iter().all(|t| t.is_finite() && *t >= 1.0 - 1e-9 && *t <= 20.0), "{h:?}");
    assert!(h.output_n.length() < 1e-9, "zero net force at the last good pose: {}", h.output_n);
    // Those tensions balance at `away` (where the grip is), not at home.
    let dirs = c.hands[0].kin.directions(away[0]);
    let net: DVec3 = (0..4).map(|s| dirs[s] * h.tensions_n[s]).sum();
    assert!(net.length() < 1e-3, "{net}");
}
