//! Tests of the tick core's lifecycle (`tick/lifecycle.rs`): activation, faults and their
//! recovery, commands, homing and re-homing, events and counters. Each asserts what the rig
//! does tick by tick; none may depend on timing.

use super::*;

#[test]
fn activation_is_refused_until_homed() {
    let mut c = core();
    c.command(Command::Activate);
    assert_eq!(c.state(), Lifecycle::Inactive);
    assert!(matches!(c.pop_event(), Some(Event::Refused { command: Command::Activate, .. })));
    c.command(Command::Home);
    c.command(Command::Activate); // waits for homing instead of being refused
    assert_eq!(c.state(), Lifecycle::Inactive);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle, Ok(()));
    assert_eq!(c.state(), Lifecycle::Inactive, "homing waits for the strings to settle");
    run(&mut c, 1, Ok(()));
    assert_eq!(c.pop_event(), Some(Event::Homed));
    assert_eq!(c.state(), Lifecycle::Active);
}

#[test]
fn inactive_output_is_zero_net_force_at_minimum_tension() {
    let mut c = core();
    c.command(Command::Home);
    let (_, rec) = run(&mut c, 3, Ok(()));
    for h in &rec.hands {
        assert!(h.output_n.length() < 1e-9, "{}", h.output_n);
        let min = h.tensions_n.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!((min - 1.0).abs() < 1e-9, "{:?}", h.tensions_n);
    }
}

#[test]
fn a_run_of_late_replies_faults_and_a_transient_fault_recovers_to_active() {
    let mut c = core();
    home_and_activate(&mut c);
    run(&mut c, 600, Ok(()));
    assert_eq!(c.ramp_gain(), 1.0);
    let n = reply_limit(&c);
    run(&mut c, n - 1, Err(TIMEOUT));
    assert_eq!(c.state(), Lifecycle::Active, "a short run is held, not a fault");
    let (out, rec) = run(&mut c, 1, Err(TIMEOUT));
    assert_eq!(c.state(), Lifecycle::Faulted);
    assert_eq!(c.fault(), Some(FaultReason::Device(ErrorKind::Timeout)));
    assert_eq!(rec.gain, 0.0);
    assert!(rec.hands.iter().all(|h| !h.held), "a fault is never held");
    assert!(out.volts[..8].iter().all(|v| *v >= 0.2 - 1e-12), "strings stay taut: {:?}", out.volts);
    let need = c.rig().safety.fault_recovery_ticks as usize;
    assert!((10..100).contains(&need), "recovery takes tens of ticks: {need}");
    run(&mut c, need - 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Faulted);
    run(&mut c, 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active);
    assert!(c.ramp_gain() < 0.01, "force ramps in again after the fault");
    let k = c.counters();
    assert_eq!((k.faults, k.device_errors, k.late_replies), (1, n as u64, n as u64 - 1));
    assert_eq!(k.held, [n as u64 - 1; 2]);
}

#[test]
fn disconnect_is_not_transient() {
    let mut c = core();
    c.command(Command::Home);
    run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
    run(&mut c, 1000, Ok(()));
    assert_eq!(c.state(), Lifecycle::Faulted);
    c.command(Command::ClearFault);
    assert_eq!(c.state(), Lifecycle::Inactive);
}

#[test]
fn deactivate_ramps_out_then_goes_inactive() {
    let mut c = core();
    home_and_activate(&mut c);
    run(&mut c, 600, Ok(()));
    c.command(Command::Deactivate);
    let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
    run(&mut c, ramp_out - 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active);
    run(&mut c, 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Inactive);
    assert!(c.is_quiet());
}

#[test]
fn a_reopened_device_clears_the_fault_to_inactive_and_unhomed_then_rehomes_when_held_still() {
    let mut c = core();
    home_and_activate(&mut c);
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    assert_eq!(c.fault(), Some(FaultReason::Device(ErrorKind::Timeout)));
    while c.pop_event().is_some() {}
    run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
    assert_eq!(c.pop_event(), Some(Event::Fault(FaultReason::Device(ErrorKind::Disconnected))));
    run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
    run(&mut c, 10, Err(TIMEOUT));
    assert_eq!(c.pop_event(), None, "reported once");
    assert_eq!(
        c.fault(),
        Some(FaultReason::Device(ErrorKind::Disconnected)),
        "a disconnect outranks a timeout"
    );
    assert_eq!(c.counters().faults, 1, "one fault, its reason upgraded");
    c.device_reopened();
    while c.pop_event().is_some() {}
    let need = c.rig().safety.fault_recovery_ticks as usize;
    run(&mut c, need, Ok(()));
    assert_eq!(c.state(), Lifecycle::Inactive, "never straight back to Active after a reopen");
    assert!(!c.is_homed(), "the counters may have restarted: home again");
    assert!(c.is_awaiting_home());
    assert!(std::iter::from_fn(|| c.pop_event()).any(|e| e == Event::HomeNeeded), "the operator is told");
    c.command(Command::Activate);
    assert_eq!(c.state(), Lifecycle::Inactive);
    assert_eq!(c.counters().reopens, 1);
    // The grips are held still (the counts do not move): after rehome_still_s the rig homes
    // itself, and since it was active before the disconnect, it activates again.
    // (The window opened on the tick the fault cleared.)
    let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
    let (_, rec) = run(&mut c, still - 2, Ok(()));
    assert!(!c.is_homing() && c.counters().rehomes == 0);
    assert!(rec.awaiting_home, "the status can say what to do");
    let (_, rec) = run(&mut c, 1, Ok(()));
    assert!(!rec.awaiting_home);
    assert!(c.is_homing() && !c.is_awaiting_home());
    assert_eq!(c.counters().rehomes, 1);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    assert!(c.is_homed());
    assert_eq!(c.state(), Lifecycle::Active);
}

#[test]
fn a_fault_during_homing_lets_the_rig_home_again_without_a_restart() {
    let mut c = core();
    c.command(Command::Home);
    c.command(Command::Activate);
    run(&mut c, 20, Ok(()));
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    assert_eq!(c.state(), Lifecycle::Faulted);
    assert!(!c.is_homing() && c.is_awaiting_home());
    let need = c.rig().safety.fault_recovery_ticks as usize;
    run(&mut c, need, Ok(()));
    assert_eq!(c.state(), Lifecycle::Inactive);
    // The grips are moving (the operator walked away): no homing while they move.
    let mut out = Output::default();
    let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
    let mut counts = [0i64; MAX_CHANNELS];
    for i in 0..3 * still {
        counts[6] = ((i / 50) % 2) as i64 * 200; // 6 mm back and forth every 50 ms
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
    }
    assert_eq!(c.counters().rehomes, 0, "a moving grip is never taken for a held one");
    // Encoder noise of a few counts does not count as motion.
    for i in 0..still + 1 {
        counts[6] = 200 + [0, 3, -2, 1][i % 4];
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
    }
    assert_eq!(c.counters().rehomes, 1);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active, "the Activate that was waiting for homing is kept");
}

#[test]
fn garbled_replies_neither_stop_nor_fake_the_stillness_that_rehomes() {
    let mut c = core();
    c.command(Command::Home);
    run(&mut c, 20, Ok(()));
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    let need = c.rig().safety.fault_recovery_ticks as usize;
    run(&mut c, need, Ok(()));
    assert!(c.is_awaiting_home());
    // Grips held still, but every 20th reply has a count 4096 off.
    let mut out = Output::default();
    let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
    let mut ticks = 0;
    while c.counters().rehomes == 0 {
        let mut counts = [0i64; MAX_CHANNELS];
        if ticks % 20 == 7 {
            counts[ticks % 8] = 4096;
        }
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
        ticks += 1;
        assert!(ticks < 2 * still, "the garbled replies kept the rig from homing");
    }
    assert!(ticks >= still, "{ticks}");
    assert!(c.counters().count_jumps.iter().sum::<u64>() > 0);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    assert!(c.is_homed());
    assert_eq!(c.hands[0].zero_m, Some(c.rig().hands[0].home_offsets([0; 4], c.rig().hands[0].home_m)));
}

#[test]
fn home_sent_while_faulted_homes_as_soon_as_the_fault_clears() {
    let mut c = core();
    c.command(Command::Home);
    run(&mut c, 20, Ok(()));
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    c.command(Command::Home);
    assert!(!std::iter::from_fn(|| c.pop_event()).any(|e| matches!(e, Event::Refused { .. })));
    let need = c.rig().safety.fault_recovery_ticks as usize;
    run(&mut c, need, Ok(()));
    assert_eq!(c.state(), Lifecycle::Inactive);
    assert!(c.is_homing() && !c.is_awaiting_home());
    assert_eq!(c.counters().rehomes, 0, "asked for, not automatic");
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    assert!(c.is_homed());
    assert_eq!(c.state(), Lifecycle::Inactive, "no Activate was asked");
}

#[test]
fn homing_takes_steady_counts_wherever_they_are() {
    // Counters far from zero (a board that was never reset) and a grip that trembles by 20
    // counts (0.6 mm) from one reply to the next: that is steady, homing goes ahead.
    let mut c = core();
    c.command(Command::Home);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    let mut out = Output::default();
    let mut counts = [0i64; MAX_CHANNELS];
    for (ch, n) in counts.iter_mut().enumerate() {
        *n = 100_000 + 1_000 * ch as i64;
    }
    for _ in 0..settle {
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
    }
    counts[5] += 20;
    tick_io(&mut c, &mut out, None, &counts, Ok(()));
    assert!(c.is_homed(), "a tremor is not a jump");
    assert_eq!(c.counters().count_jumps, [0, 0]);
    let h1: [i64; 4] = std::array::from_fn(|s| counts[c.rig().hands[1].channels[s]]);
    assert_eq!(c.hands[1].zero_m, Some(c.rig().hands[1].home_offsets(h1, c.rig().hands[1].home_m)));
}

#[test]
fn the_rehoming_window_counts_only_good_replies_of_an_inactive_rig() {
    // Ticks until the rig re-homes itself after a fault during homing, with `spoil` applied
    // on the first ticks after the fault cleared.
    fn ticks_to_rehome(spoil: usize, err: Option<DeviceError>) -> usize {
        let mut c = core();
        c.command(Command::Home);
        run(&mut c, 20, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive);
        let mut ticks = 0;
        if let Some(e) = err {
            run(&mut c, spoil, Err(e));
            ticks += spoil;
        }
        while c.counters().rehomes == 0 {
            run(&mut c, 1, Ok(()));
            ticks += 1;
            assert!(ticks < 5000);
        }
        ticks
    }
    let clean = ticks_to_rehome(0, None);
    // Held ticks (no reply) are not still ticks: they add to the wait.
    assert_eq!(ticks_to_rehome(4, Some(TIMEOUT)), clean + 4);
    // A faulted rig does not home by itself, however still the grips.
    let text = crate::rig::DEFAULT_RIG_RON.replace("fault_recovery_ticks: 30", "fault_recovery_ticks: 0");
    let mut c = TickCore::new(&Rig::from_str(&text, "t").unwrap()).unwrap();
    c.command(Command::Home);
    run(&mut c, 20, Ok(()));
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    run(&mut c, 3000, Ok(()));
    assert!(c.is_awaiting_home() && c.state() == Lifecycle::Faulted);
    assert_eq!(c.counters().rehomes, 0);
    assert!(!c.is_homing());
}

#[test]
fn homing_settles_on_good_replies_only() {
    let mut c = core();
    c.command(Command::Home);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle - 2, Ok(()));
    run(&mut c, 3, Err(TIMEOUT)); // held, not a fault: the settle clock waits
    assert_eq!(c.state(), Lifecycle::Inactive);
    run(&mut c, 2, Ok(()));
    assert!(c.is_homing(), "a held tick is not a settled one");
    run(&mut c, 1, Ok(()));
    assert!(c.is_homed());
}

#[test]
fn homing_waits_for_two_replies_that_agree() {
    let mut c = core();
    c.command(Command::Home);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle, Ok(()));
    let mut out = Output::default();
    let mut counts = [0i64; MAX_CHANNELS];
    counts[3] = 4096; // a corrupt reply on the very tick homing takes the counts
    tick_io(&mut c, &mut out, None, &counts, Ok(()));
    assert!(c.is_homing() && c.counters().count_jumps == [1, 0]);
    tick_io(&mut c, &mut out, None, &[0; MAX_CHANNELS], Ok(()));
    assert!(c.is_homing(), "the good reply disagrees with the corrupt one before it");
    tick_io(&mut c, &mut out, None, &[0; MAX_CHANNELS], Ok(()));
    assert!(c.is_homed());
    assert_eq!(c.hands[0].zero_m, Some(c.rig().hands[0].home_offsets([0; 4], c.rig().hands[0].home_m)));
}

#[test]
fn a_fault_while_inactive_or_ramping_out_never_resumes_active() {
    for ramping_out in [false, true] {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        c.command(if ramping_out { Command::Stop } else { Command::Deactivate });
        if !ramping_out {
            run(&mut c, 400, Ok(()));
            assert_eq!(c.state(), Lifecycle::Inactive);
        } else {
            run(&mut c, 50, Ok(()));
            assert_eq!(c.state(), Lifecycle::Active, "still ramping out");
        }
        let (n, need) = (reply_limit(&c), c.rig().safety.fault_recovery_ticks as usize);
        run(&mut c, n, Err(DeviceError::Corrupt { what: "test" }));
        assert_eq!(c.state(), Lifecycle::Faulted);
        run(&mut c, need + 5, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive, "ramping out: {ramping_out}");
        assert_eq!(c.ramp_gain(), 0.0);
    }
}

#[test]
fn activate_during_a_ramp_out_ramps_back_in() {
    let mut c = core();
    home_and_activate(&mut c);
    run(&mut c, 600, Ok(()));
    c.command(Command::Deactivate);
    run(&mut c, 100, Ok(()));
    let low = c.ramp_gain();
    assert!(low < 1.0 && low > 0.0);
    c.command(Command::Activate);
    let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
    run(&mut c, ramp_out, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active);
    assert!(c.ramp_gain() > low, "{} after {low}", c.ramp_gain());
}

#[test]
fn fault_recovery_ticks_zero_never_recovers() {
    let text = crate::rig::DEFAULT_RIG_RON.replace("fault_recovery_ticks: 30", "fault_recovery_ticks: 0");
    let mut c = TickCore::new(&Rig::from_str(&text, "t").unwrap()).unwrap();
    home_and_activate(&mut c);
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    run(&mut c, 5000, Ok(()));
    assert_eq!(c.state(), Lifecycle::Faulted);
    c.command(Command::ClearFault);
    assert_eq!(c.state(), Lifecycle::Inactive);
}

#[test]
fn names_and_reasons_say_what_they_are() {
    let names = [Lifecycle::Unconfigured, Lifecycle::Inactive, Lifecycle::Active, Lifecycle::Faulted]
        .map(Lifecycle::name);
    assert_eq!(names, ["unconfigured", "inactive", "active", "faulted"]);
    let says = |f: FaultReason| f.to_string();
    assert_eq!(says(FaultReason::Device(ErrorKind::Timeout)), "device error (Timeout)");
    assert!(says(FaultReason::PoseInvalid { hand: 1 }).starts_with("hand 1: pose"));
    assert!(says(FaultReason::Residual { hand: 0 }).contains("slack string"));
    assert!(says(FaultReason::CountJump { hand: 1 }).starts_with("hand 1: counts jumped"));
}

#[test]
fn events_beyond_the_queue_are_dropped_and_counted() {
    let mut c = core();
    for _ in 0..20 {
        c.command(Command::Activate); // refused: not homed
    }
    assert_eq!(c.counters().events_dropped, 4);
    assert_eq!(std::iter::from_fn(|| c.pop_event()).count(), 16);
}

#[test]
fn quiet_only_when_not_active_and_the_force_has_ramped_out() {
    let mut c = core();
    assert!(c.is_quiet());
    c.command(Command::Home);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    assert!(c.is_homed() && c.is_quiet());
    c.command(Command::Activate);
    assert!(!c.is_quiet(), "active, though the ramp has not risen yet");
    run(&mut c, 600, Ok(()));
    assert!(!c.is_quiet(), "active");
    c.command(Command::Stop);
    run(&mut c, 100, Ok(()));
    assert!(!c.is_quiet(), "still ramping out");
    let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
    run(&mut c, ramp_out, Ok(()));
    assert!(c.is_quiet());
    // A fault is quiet at once (the ramp is cut).
    let mut c = core();
    home_and_activate(&mut c);
    run(&mut c, 600, Ok(()));
    let n = reply_limit(&c);
    run(&mut c, n, Err(TIMEOUT));
    assert!(c.is_quiet());
}

#[test]
fn the_loop_counts_into_the_cores_counters() {
    let mut c = core();
    c.counters_mut().misses += 2;
    c.counters_mut().samples_dropped += 1;
    assert_eq!((c.counters().misses, c.counters().samples_dropped), (2, 1));
}

#[test]
fn recovery_needs_good_exchanges_in_a_row() {
    let mut c = core();
    home_and_activate(&mut c);
    let need = c.rig().safety.fault_recovery_ticks as usize;
    let n = reply_limit(&c);
    run(&mut c, n, Err(DeviceError::Timeout { waited_us: 1 }));
    for _ in 0..3 {
        run(&mut c, need - 1, Ok(()));
        run(&mut c, 1, Err(DeviceError::Corrupt { what: "test" }));
    }
    assert_eq!(c.state(), Lifecycle::Faulted, "a flaky link must not count its good ticks across errors");
    run(&mut c, need, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active);
    assert_eq!(c.counters().faults, 1);
}
