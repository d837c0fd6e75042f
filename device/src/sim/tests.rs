//! Behaviour of the simulated rig and its scripts, checked against hand-computed numbers.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use glam::DVec3;
use proptest::prelude::*;

use super::script::tour;
use super::*;
use crate::{Device, DeviceError, Input, Output};

// Counts allocations made on the current thread while `COUNTING` is set, so a test can prove
// `exchange` does not allocate. Other threads and other times pass straight through.
struct CountingAlloc;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = COUNTING.try_with(|c| {
            if c.get() {
                let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
            }
        });
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = COUNTING.try_with(|c| {
            if c.get() {
                let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
            }
        });
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

pub(crate) fn allocations_during(f: impl FnOnce()) -> u64 {
    ALLOCS.with(|a| a.set(0));
    COUNTING.with(|c| c.set(true));
    f();
    COUNTING.with(|c| c.set(false));
    ALLOCS.with(|a| a.get())
}

/// Hand 0 on channels 0-3 with anchors on alternate corners of a 2 m cube around the origin
/// (Springhead's HISpidar4 layout, scaled), hand 1 the same shifted on channels 4-7.
fn cube_params() -> SimRigParams {
    let corners = [
        DVec3::new(1., 1., 1.),
        DVec3::new(-1., 1., -1.),
        DVec3::new(1., -1., -1.),
        DVec3::new(-1., -1., 1.),
    ];
    let hand = |h: usize, shift: DVec3| {
        let strings = core::array::from_fn(|i| {
            let anchor_m = corners[i] + shift;
            SimString {
                anchor_m,
                channel: 4 * h + i,
                metres_per_count: 2.5e-5,
                length_at_zero_m: (anchor_m - shift).length(),
                volts_per_newton: 0.2,
                tension_max_n: 20.0,
            }
        });
        SimHandParams::new(strings, shift)
    };
    SimRigParams::with_defaults([hand(0, DVec3::ZERO), hand(1, DVec3::new(0.0, 0.0, 3.0))])
}

fn holds(p: &SimRigParams) -> [Script; 2] {
    [Script::hold(p.hands[0].start_m), Script::hold(p.hands[1].start_m)]
}

fn opened(params: SimRigParams, scripts: [Script; 2]) -> SimRig {
    let mut rig = SimRig::new(params, scripts).expect("valid rig");
    rig.open().unwrap();
    rig
}

fn run(rig: &mut SimRig, out: &Output, n: usize) -> Input {
    let mut inp = Input::default();
    for _ in 0..n {
        rig.exchange(out, &mut inp).unwrap();
    }
    inp
}

fn volts_for(rig: &SimRig, hand: usize, tensions_n: [f64; 4]) -> Output {
    let mut out = Output::default();
    for (s, t) in rig.params().hands[hand].strings.iter().zip(tensions_n) {
        out.volts[s.channel] = t * s.volts_per_newton;
    }
    out
}

fn length_from_counts(s: &SimString, counts: i64) -> f64 {
    s.length_at_zero_m + counts as f64 * s.metres_per_count
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// Length -> counts -> length lands within one count below the true length (floor), for
    /// both signs of metres_per_count.
    #[test]
    fn counts_round_trip(x in -0.6f64..0.6, y in -0.6f64..0.6, z in -0.6f64..0.6, flip in any::<bool>()) {
        let mut p = cube_params();
        p.hands[0].start_m = DVec3::new(x, y, z);
        if flip {
            for s in &mut p.hands[0].strings {
                s.metres_per_count = -s.metres_per_count;
            }
        }
        let mut rig = opened(p.clone(), holds(&p));
        let inp = run(&mut rig, &Output::default(), 1);
        for (i, s) in p.hands[0].strings.iter().enumerate() {
            let true_len = (s.anchor_m - p.hands[0].start_m).length();
            let raw = (true_len - s.length_at_zero_m) / s.metres_per_count;
            prop_assert_eq!(inp.counts[s.channel], raw.floor() as i64);
            let err_counts = (true_len - length_from_counts(s, inp.counts[s.channel])) / s.metres_per_count;
            prop_assert!((0.0..1.0 + 1e-9).contains(&err_counts), "string {i}: {err_counts} counts off");
        }
    }
}

#[test]
fn exchange_before_open_is_wrong_state() {
    let p = cube_params();
    let mut rig = SimRig::new(p.clone(), holds(&p)).unwrap();
    let err = rig.exchange(&Output::default(), &mut Input::default()).unwrap_err();
    assert!(matches!(err, DeviceError::WrongState { .. }), "{err:?}");
    assert!(rig.activate().is_err());
    assert_eq!(rig.truth().t_s, 0.0, "a refused exchange must not advance the plant");
}

#[test]
fn info_describes_the_rig() {
    let mut p = cube_params();
    p.seed = 42;
    p.hands[1].strings[3].channel = 11;
    let rig = opened(p.clone(), holds(&p));
    let info = rig.info();
    assert_eq!(info.board.as_str(), "simulated SPIDAR-H");
    assert_eq!(info.identity.as_str(), "sim seed 42");
    assert_eq!(info.channels, 12);
    assert_eq!((info.volts_min, info.volts_max), (-10.0, 10.0));
}

#[test]
fn hold_script_settles_at_target_with_zero_volts() {
    let mut p = cube_params();
    let target = DVec3::new(0.1, -0.05, 0.2);
    p.hands[0].start_m = DVec3::new(-0.2, 0.1, 0.0);
    let scripts = [Script::hold(target), Script::hold(p.hands[1].start_m)];
    let mut rig = opened(p, scripts);
    rig.activate().unwrap();
    let inp = run(&mut rig, &Output::default(), 3000);
    let h = rig.truth().hands[0];
    assert!((h.pos_m - target).length() < 1e-5, "pos {} target {target}", h.pos_m);
    assert!(h.vel_m_per_s.length() < 1e-4);
    assert_eq!(h.tension_n, [0.0; 4]);
    assert_eq!(inp.status & STATUS_ACTIVE, STATUS_ACTIVE);
    assert!((rig.truth().t_s - 3.0).abs() < 1e-12);
}

#[test]
fn constant_tension_balances_the_arm_spring() {
    let p = cube_params();
    let mut rig = opened(p.clone(), holds(&p));
    rig.activate().unwrap();
    let t = 10.0;
    let out = volts_for(&rig, 0, [t, 0.0, 0.0, 0.0]);
    run(&mut rig, &out, 5000);
    let h = rig.truth().hands[0];
    let x0 = p.hands[0].start_m;
    let anchor = p.hands[0].strings[0].anchor_m;
    let u = (anchor - h.pos_m).normalize();
    // Equilibrium: k (x0 - x) + t u(x) = 0, so x - x0 = t u / k: 5 cm toward the anchor.
    let expected = x0 + u * (t / p.hands[0].arm_k_n_per_m);
    assert!((h.pos_m - expected).length() < 1e-6, "pos {} expected {expected}", h.pos_m);
    assert!(((h.pos_m - x0).length() - 0.05).abs() < 1e-6);
    assert!((h.pos_m - x0).dot(anchor - x0) > 0.0, "moved away from the pulling string");
    assert!((h.string_force_n - u * t).length() < 1e-9);
    assert!((h.string_force_n + h.arm_force_n).length() < 1e-6, "forces do not balance");
    assert_eq!(h.tension_n, [t, 0.0, 0.0, 0.0]);
    // Hand 1 got no command and stays put.
    assert!((rig.truth().hands[1].pos_m - p.hands[1].start_m).length() < 1e-12);
}

#[test]
fn tension_is_clamped_to_the_motor_and_board_limits() {
    let mut p = cube_params();
    p.hands[0].strings[2].tension_max_n = 100.0;
    p.hands[0].strings[3].volts_per_newton = -0.2;
    let mut rig = opened(p.clone(), holds(&p));
    rig.activate().unwrap();
    let mut out = Output::default();
    out.volts[0] = 6.0; // 30 N asked, motor max 20 N
    out.volts[1] = -3.0; // strings cannot push
    out.volts[2] = 15.0; // board clips to 10 V = 50 N (motor allows 100 N)
    out.volts[3] = -2.0; // reversed winding: 10 N
    run(&mut rig, &out, 1);
    assert_eq!(rig.truth().hands[0].tension_n, [20.0, 0.0, 50.0, 10.0]);
    out.volts = [f64::NAN; crate::MAX_CHANNELS];
    run(&mut rig, &out, 1);
    assert_eq!(rig.truth().hands[0].tension_n, [0.0; 4], "NaN volts must read as 0");
    out.volts = [f64::INFINITY; crate::MAX_CHANNELS];
    run(&mut rig, &out, 1);
    assert_eq!(rig.truth().hands[0].tension_n, [20.0, 20.0, 50.0, 0.0]);
}

#[test]
fn outputs_are_zero_unless_active() {
    let p = cube_params();
    let mut rig = opened(p.clone(), holds(&p));
    let out = volts_for(&rig, 0, [5.0; 4]);
    let inp = run(&mut rig, &out, 10);
    assert_eq!(rig.truth().hands[0].tension_n, [0.0; 4]);
    assert_eq!(inp.status & STATUS_ACTIVE, 0);
    rig.activate().unwrap();
    run(&mut rig, &out, 1);
    assert_eq!(rig.truth().hands[0].tension_n, [5.0; 4]);
    rig.deactivate().unwrap();
    run(&mut rig, &out, 1);
    assert_eq!(rig.truth().hands[0].tension_n, [0.0; 4]);
}

#[test]
fn motor_lag_reaches_63_percent_after_one_time_constant() {
    let mut p = cube_params();
    p.motor_time_constant_s = 0.05;
    let mut rig = opened(p.clone(), holds(&p));
    rig.activate().unwrap();
    let out = volts_for(&rig, 0, [10.0, 10.0, 10.0, 10.0]);
    run(&mut rig, &out, 50);
    let expected = 10.0 * (1.0 - (-1.0f64).exp());
    for t in rig.truth().hands[0].tension_n {
        assert!((t - expected).abs() < 1e-9, "{t} vs {expected}");
    }
    run(&mut rig, &out, 450);
    for t in rig.truth().hands[0].tension_n {
        assert!((t - 10.0).abs() < 1e-3);
    }
}

fn noisy_params(seed: u64) -> SimRigParams {
    let mut p = cube_params();
    p.seed = seed;
    p.encoder_noise_counts = 2.0;
    p.slack_tension_n = 1.0;
    p.slack_length_m = 0.002;
    p.motor_time_constant_s = 0.003;
    p
}

/// Runs a rig with noise, slack, lag and sparring scripts under a varying command and returns
/// every counter reading and the final truth.
fn busy_run(seed: u64, ticks: usize) -> (Vec<Input>, Truth) {
    let p = noisy_params(seed);
    let scripts = builtin_script("spar", [p.hands[0].start_m, p.hands[1].start_m], 7).unwrap();
    let mut rig = opened(p, scripts);
    rig.activate().unwrap();
    let mut inputs = Vec::with_capacity(ticks);
    let mut inp = Input::default();
    for k in 0..ticks {
        let mut out = Output::default();
        for (c, v) in out.volts.iter_mut().enumerate().take(8) {
            *v = 0.2 + 0.8 * ((k as f64) * 0.01 + c as f64).sin().abs();
        }
        rig.exchange(&out, &mut inp).unwrap();
        inputs.push(inp);
    }
    (inputs, *rig.truth())
}

#[test]
fn same_seed_is_bit_identical_and_seed_changes_noise() {
    let (a_inp, a_truth) = busy_run(1, 2000);
    let (b_inp, b_truth) = busy_run(1, 2000);
    assert_eq!(a_inp, b_inp);
    // Bit-identical, not just close: compare the raw bits of the position.
    for h in 0..2 {
        assert_eq!(
            a_truth.hands[h].pos_m.to_array().map(f64::to_bits),
            b_truth.hands[h].pos_m.to_array().map(f64::to_bits)
        );
    }
    assert_eq!(a_truth, b_truth);
    let (c_inp, c_truth) = busy_run(2, 2000);
    assert_ne!(a_inp, c_inp, "a different seed must change the encoder noise");
    // The seed only drives the noise: the plant itself is the same.
    assert_eq!(a_truth.hands[0].pos_m, c_truth.hands[0].pos_m);
}

#[test]
fn encoder_noise_has_the_configured_spread() {
    let mut p = cube_params();
    p.encoder_noise_counts = 3.0;
    let mut rig = opened(p.clone(), holds(&p));
    let s = p.hands[0].strings[0];
    let raw = ((s.anchor_m - p.hands[0].start_m).length() - s.length_at_zero_m) / s.metres_per_count;
    let n = 20_000;
    let mut inp = Input::default();
    let (mut sum, mut sum2) = (0.0, 0.0);
    for _ in 0..n {
        rig.exchange(&Output::default(), &mut inp).unwrap();
        let e = inp.counts[s.channel] as f64 - raw;
        sum += e;
        sum2 += e * e;
    }
    let mean = sum / n as f64;
    let sd = (sum2 / n as f64 - mean * mean).sqrt();
    // floor() takes half a count off on average and adds 1/12 count^2 of variance.
    assert!((mean + 0.5).abs() < 0.1, "mean {mean}");
    assert!((sd - (9.0f64 + 1.0 / 12.0).sqrt()).abs() < 0.1, "sd {sd}");
}

#[test]
fn slack_strings_read_longer() {
    let mut p = cube_params();
    p.slack_tension_n = 2.0;
    p.slack_length_m = 0.01;
    let mut rig = opened(p.clone(), holds(&p));
    let s = p.hands[0].strings[0];
    let counts_at = |tension_n: f64, rig: &mut SimRig| {
        rig.activate().unwrap();
        let out = volts_for(rig, 0, [tension_n; 4]);
        // The tension set now is seen by the next exchange's sampling.
        let _ = run(rig, &out, 1);
        let inp = run(rig, &out, 1);
        (inp.counts[s.channel], (s.anchor_m - rig.truth().hands[0].pos_m).length())
    };
    let (c0, l0) = counts_at(0.0, &mut rig);
    assert!((length_from_counts(&s, c0) - (l0 + 0.01)).abs() < 2.0 * s.metres_per_count);
    let (c1, _) = counts_at(1.0, &mut rig);
    let l1 = length_from_counts(&s, c1);
    // Half the slack tension: half the slack length (the hand has barely moved: 4 equal
    // tensions nearly cancel at the centre of the cube).
    let true_l1 = (s.anchor_m - rig.truth().hands[0].pos_m).length();
    assert!((l1 - (true_l1 + 0.005)).abs() < 1e-4, "{l1} vs {true_l1}");
    let (c2, _) = counts_at(3.0, &mut rig);
    let true_l2 = (s.anchor_m - rig.truth().hands[0].pos_m).length();
    assert!((length_from_counts(&s, c2) - true_l2).abs() < 1e-4, "taut string must read its true length");
}

#[test]
fn fail_next_fails_n_times_holding_the_last_command_then_recovers() {
    let p = cube_params();
    let mut rig = opened(p.clone(), holds(&p));
    rig.activate().unwrap();
    let out = volts_for(&rig, 0, [5.0; 4]);
    run(&mut rig, &out, 5);
    let error = DeviceError::Timeout { waited_us: 900 };
    rig.fail_next(3, error);
    let mut inp = Input { counts: [123; crate::MAX_CHANNELS], status: 77 };
    let lower = volts_for(&rig, 0, [2.0; 4]);
    for k in 0..3 {
        assert_eq!(rig.exchange(&lower, &mut inp), Err(error), "exchange {k}");
        assert_eq!(rig.truth().hands[0].tension_n, [5.0; 4], "no watchdog: the last command is held");
        assert_eq!(inp.counts[0], 123, "a failed exchange must not write the input");
    }
    assert!((rig.truth().t_s - 0.008).abs() < 1e-12, "the plant keeps running through faults");
    rig.exchange(&lower, &mut inp).unwrap();
    assert_eq!(rig.truth().hands[0].tension_n, [2.0; 4]);
    assert_eq!(inp.status, STATUS_ACTIVE);
}

#[test]
fn exchange_does_not_allocate() {
    let p = noisy_params(3);
    let home = [p.hands[0].start_m, p.hands[1].start_m];
    let mut scripts = builtin_script("spar", home, 1).unwrap();
    let samples = (0..100)
        .map(|i| TrajectorySample { t_s: i as f64 * 0.01, pos_m: DVec3::new(0.001 * i as f64, 0.0, 0.0) })
        .collect();
    scripts[1] = Script::from_segments(
        vec![
            Segment::recorded("mem", samples).unwrap(),
            Segment::Circle {
                centre_m: home[1].to_array(),
                radius_m: 0.1,
                normal: [0., 0., 1.],
                period_s: 1.0,
                turns: 1.0,
            },
            Segment::Jab { to_m: [0.0, 0.1, 2.8], out_s: 0.2, back_s: 0.3 },
        ],
        true,
    );
    let mut rig = opened(p, scripts);
    rig.activate().unwrap();
    let out = volts_for(&rig, 0, [3.0; 4]);
    let mut inp = Input::default();
    rig.fail_next(2, DeviceError::Corrupt { what: "test" });
    let n = allocations_during(|| {
        for _ in 0..5000 {
            let _ = rig.exchange(&out, &mut inp);
        }
    });
    assert_eq!(n, 0);
}

#[test]
fn set_script_starts_now_from_the_current_target() {
    let p = cube_params();
    let mut rig = opened(p.clone(), holds(&p));
    run(&mut rig, &Output::default(), 500);
    let to = DVec3::new(0.0, 0.2, 0.0);
    rig.set_script(
        0,
        Script::from_segments(vec![Segment::Reach { to_m: to.to_array(), duration_s: 1.0 }], false),
    );
    assert_eq!(rig.truth().hands[0].target_m, p.hands[0].start_m);
    run(&mut rig, &Output::default(), 500);
    // Half-way through the reach: min-jerk is at half the distance.
    assert!((rig.truth().hands[0].target_m - to * 0.5).length() < 1e-9);
    run(&mut rig, &Output::default(), 1500);
    assert!((rig.truth().hands[0].pos_m - to).length() < 1e-5);
    assert!(rig.try_set_script(2, Script::hold(DVec3::ZERO)).is_err());
}

#[test]
fn push_offsets_the_arm_target() {
    let p = cube_params();
    let mut rig = opened(p.clone(), holds(&p));
    let push = DVec3::new(0.0, 0.0, -0.05);
    rig.set_push(1, push);
    run(&mut rig, &Output::default(), 3000);
    assert!((rig.truth().hands[1].pos_m - (p.hands[1].start_m + push)).length() < 1e-5);
    assert_eq!(rig.truth().hands[1].target_m, p.hands[1].start_m + push);
}

#[test]
fn invalid_parameters_are_named() {
    let p = cube_params();
    let check = |p: SimRigParams, needle: &str| {
        let err = SimRig::new(p, holds(&cube_params())).expect_err("must be rejected").to_string();
        assert!(err.contains(needle), "`{err}` does not mention `{needle}`");
    };
    let mut q = p.clone();
    q.hands[1].strings[2].channel = 1;
    check(q, "hands[1].strings[2].channel");
    let mut q = p.clone();
    q.hands[0].mass_kg = 0.0;
    check(q, "hands[0].mass_kg");
    let mut q = p.clone();
    q.hands[0].strings[1].metres_per_count = 0.0;
    check(q, "hands[0].strings[1].metres_per_count");
    let mut q = p.clone();
    q.hands[1].strings[0].volts_per_newton = f64::NAN;
    check(q, "volts_per_newton");
    let mut q = p.clone();
    q.period_s = 0.0;
    check(q, "period_s");
    let mut q = p.clone();
    q.substeps = 0;
    check(q, "substeps");
    let mut q = p.clone();
    q.hands[0].strings[0].channel = crate::MAX_CHANNELS;
    check(q, "out of range");
    let mut q = p.clone();
    q.hands[0].start_m = DVec3::new(f64::INFINITY, 0.0, 0.0);
    check(q, "start_m");
    let bad_script = Script::from_segments(vec![Segment::Reach { to_m: [0.0; 3], duration_s: -1.0 }], false);
    let err = SimRig::new(p.clone(), [bad_script, Script::hold(DVec3::ZERO)]).unwrap_err().to_string();
    assert!(err.contains("hand 0") && err.contains("duration_s"), "{err}");
    let empty_repeat = Script::from_segments(vec![Segment::Hold { at_m: [0.0; 3], for_s: 0.0 }], true);
    assert!(SimRig::new(p, [empty_repeat, Script::hold(DVec3::ZERO)]).is_err());
}

#[test]
fn lab_rig_homes_at_the_origin() {
    let p = SimRigParams::lab([DVec3::ZERO, DVec3::ZERO]);
    let mut rig = opened(p.clone(), holds(&p));
    let inp = run(&mut rig, &Output::default(), 1);
    // Counters zero at the origin: within one count of 0 (floor of a rounding error).
    assert!(inp.counts[..8].iter().all(|c| (-1..=0).contains(c)), "{:?}", inp.counts);
    assert_eq!(rig.info().channels, 8);
}

// ---------------------------------------------------------------- scripts

/// Checks that a script's velocity is the derivative of its position wherever the position is
/// smooth (steps of the target velocity are allowed where documented: skip those instants).
fn check_velocity_consistent(script: &Script, start: DVec3, until_s: f64) {
    let mut cur = ScriptCursor::new(start);
    let dt = 1e-4;
    let mut prev = cur.target(script, 0.0);
    let mut t = dt;
    while t < until_s {
        let now = cur.target(script, t);
        let fd = (now.pos_m - prev.pos_m) / dt;
        let mid = (now.vel_m_per_s + prev.vel_m_per_s) * 0.5;
        let tol = 1e-3 + 0.01 * mid.length();
        let jump = (now.vel_m_per_s - prev.vel_m_per_s).length() > 0.05;
        assert!(jump || (fd - mid).length() < tol, "t = {t}: finite difference {fd} vs velocity {mid}");
        prev = now;
        t += dt;
    }
}

#[test]
fn min_jerk_reach_ends_at_the_point_with_zero_velocity() {
    let start = DVec3::new(0.1, 0.0, 0.0);
    let to = DVec3::new(0.1, 0.3, -0.4);
    let script = Script::from_segments(vec![Segment::Reach { to_m: to.to_array(), duration_s: 0.8 }], false);
    let end = script.target_at(start, 0.8);
    assert!((end.pos_m - to).length() < 1e-12);
    assert_eq!(end.vel_m_per_s, DVec3::ZERO);
    let mid = script.target_at(start, 0.4);
    assert!((mid.pos_m - (start + to) * 0.5).length() < 1e-12);
    // Peak min-jerk speed is 15/8 of the mean speed.
    assert!((mid.vel_m_per_s.length() - 1.875 * 0.5 / 0.8).abs() < 1e-12);
    let begin = script.target_at(start, 0.0);
    assert_eq!((begin.pos_m, begin.vel_m_per_s), (start, DVec3::ZERO));
    // Non-repeating: stays at the end.
    assert_eq!(script.target_at(start, 5.0).pos_m, to);
    assert_eq!(script.duration_s(start), Some(0.8));
    check_velocity_consistent(&script, start, 1.0);
}

#[test]
fn jab_goes_out_and_comes_back() {
    let start = DVec3::new(0.0, 0.1, 0.0);
    let to = DVec3::new(0.0, 0.2, -0.4);
    let script =
        Script::from_segments(vec![Segment::Jab { to_m: to.to_array(), out_s: 0.2, back_s: 0.4 }], true);
    assert!((script.target_at(start, 0.2).pos_m - to).length() < 1e-12);
    assert!((script.target_at(start, 0.6).pos_m - start).length() < 1e-12);
    // Repeating: the second jab is the first one again.
    assert!((script.target_at(start, 0.8).pos_m - to).length() < 1e-12);
    check_velocity_consistent(&script, start, 1.3);
}

#[test]
fn circle_approaches_then_turns_at_its_radius() {
    let centre = DVec3::new(0.0, 0.1, -0.1);
    let script = builtin_script("circle", [centre, DVec3::ZERO], 0).unwrap()[0].clone();
    // From its centre the circle starts at +x, after a period/4 = 0.5 s approach.
    let start_pt = script.target_at(centre, 0.5);
    assert!((start_pt.pos_m - (centre + DVec3::new(0.1, 0.0, 0.0))).length() < 1e-12);
    let mut cur = ScriptCursor::new(centre);
    let mut t = 0.5;
    while t < 6.0 {
        let tg = cur.target(&script, t);
        let r = tg.pos_m - centre;
        assert!((r.length() - 0.1).abs() < 1e-9, "t = {t}: radius {}", r.length());
        assert!(r.z.abs() < 1e-12, "must stay in the frontal plane");
        assert!((tg.vel_m_per_s.length() - 0.1 * std::f64::consts::TAU / 2.0).abs() < 1e-9);
        t += 0.01;
    }
    // Counter-clockwise about +z: a quarter turn after the start it is at +y.
    assert!((script.target_at(centre, 1.0).pos_m - (centre + DVec3::new(0.0, 0.1, 0.0))).length() < 1e-9);
    check_velocity_consistent(&script, centre, 5.0);
}

#[test]
fn spar_stays_in_its_box_and_is_deterministic() {
    let centre = DVec3::new(0.1, 0.0, -0.05);
    let half = DVec3::new(0.2, 0.2, 0.25);
    let spar = |seed| {
        Script::from_segments(
            vec![Segment::Spar {
                seed,
                centre_m: centre.to_array(),
                half_extent_m: half.to_array(),
                for_s: 30.0,
            }],
            false,
        )
    };
    let trace = |seed| {
        let s = spar(seed);
        let mut cur = ScriptCursor::new(centre);
        (0..30_000).map(|k| cur.target(&s, k as f64 * 1e-3)).collect::<Vec<_>>()
    };
    let a = trace(5);
    let (mut min_z, mut max_speed) = (f64::MAX, 0.0f64);
    for (k, tg) in a.iter().enumerate() {
        let d = (tg.pos_m - centre).abs();
        assert!(d.cmple(half + 1e-12).all(), "t = {} ms: {} outside the box", k, tg.pos_m);
        min_z = min_z.min(tg.pos_m.z);
        max_speed = max_speed.max(tg.vel_m_per_s.length());
    }
    // There were jabs: fast moves reaching the front half of the box.
    assert!(min_z < centre.z - 0.6 * half.z, "no jab reached the front: min z {min_z}");
    assert!(max_speed > 1.0, "no fast move: {max_speed} m/s");
    assert_eq!(a, trace(5));
    assert_ne!(a, trace(6));
    // A fresh evaluation far into the segment agrees with the cursor that walked there.
    assert_eq!(spar(5).target_at(centre, 12.345), ScriptCursor::new(centre).target(&spar(5), 12.345));
    check_velocity_consistent(&spar(5), centre, 10.0);
}

#[test]
fn segments_chain_from_where_the_previous_ended() {
    let start = DVec3::ZERO;
    let script = Script::from_segments(
        vec![
            Segment::Hold { at_m: [0.0, 0.1, 0.0], for_s: 0.5 },
            Segment::Reach { to_m: [0.2, 0.1, 0.0], duration_s: 1.0 },
            Segment::Jab { to_m: [0.2, 0.1, -0.3], out_s: 0.2, back_s: 0.3 },
        ],
        true,
    );
    assert_eq!(script.target_at(start, 0.25).pos_m, DVec3::new(0.0, 0.1, 0.0));
    assert!((script.target_at(start, 1.0).pos_m - DVec3::new(0.1, 0.1, 0.0)).length() < 1e-12);
    assert!((script.target_at(start, 1.7).pos_m - DVec3::new(0.2, 0.1, -0.3)).length() < 1e-12);
    // Second pass starts with the hold again, at t = 2.0.
    assert_eq!(script.target_at(start, 2.1).pos_m, DVec3::new(0.0, 0.1, 0.0));
    // A cursor that goes back in time replays from the start.
    let mut cur = ScriptCursor::new(start);
    let late = cur.target(&script, 7.3);
    let early = cur.target(&script, 1.0);
    assert_eq!(late, script.target_at(start, 7.3));
    assert_eq!(early, script.target_at(start, 1.0));
}

#[test]
fn recorded_trajectory_interpolates_linearly() {
    let csv = "t_s,x_m,y_m,z_m\n0.0,0,0,0\n1.0,1,0,0\n# comment\n\n3.0,1,2,0\n";
    let seg = Segment::recorded_from_csv("walk.csv", csv).unwrap();
    let script = Script::from_segments(vec![seg, Segment::Hold { at_m: [5.0, 5.0, 5.0], for_s: 1.0 }], false);
    let tg = script.target_at(DVec3::ZERO, 0.25);
    assert!((tg.pos_m - DVec3::new(0.25, 0.0, 0.0)).length() < 1e-12);
    assert!((tg.vel_m_per_s - DVec3::X).length() < 1e-12);
    let tg = script.target_at(DVec3::ZERO, 2.0);
    assert!((tg.pos_m - DVec3::new(1.0, 1.0, 0.0)).length() < 1e-12);
    assert_eq!(script.target_at(DVec3::ZERO, 3.5).pos_m, DVec3::splat(5.0));
    assert_eq!(script.duration_s(DVec3::ZERO), Some(4.0));
}

#[test]
fn trajectory_errors_name_the_file_and_line() {
    let err =
        |text: &str| Segment::recorded_from_csv("rec.csv", text).expect_err("must be rejected").to_string();
    let e = err("t_s,x_m,y_m,z_m\n0,0,0,0\n0.1,0,0,0\n0.2,0,zero,0\n");
    assert!(e.contains("rec.csv") && e.contains("line 4") && e.contains("y_m"), "{e}");
    let e = err("t_s,x_m,y_m,z_m\n0,0,0,0\n0,1,0,0\n");
    assert!(e.contains("line 3") && e.contains("increase"), "{e}");
    let e = err("t_s,x_m,y_m,z_m\n0,0,0\n");
    assert!(e.contains("line 2") && e.contains("columns"), "{e}");
    let e = err("time,x,y,z\n0,0,0,0\n");
    assert!(e.contains("line 1") && e.contains("t_s,x_m,y_m,z_m"), "{e}");
    let e = err("t_s,x_m,y_m,z_m\n");
    assert!(e.contains("no samples"), "{e}");
    let e = Segment::recorded("mem", vec![TrajectorySample { t_s: -1.0, pos_m: DVec3::ZERO }])
        .unwrap_err()
        .to_string();
    assert!(e.contains("mem") && e.contains("negative"), "{e}");

    let dir = std::env::temp_dir().join(format!("spidar-sim-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("bad.csv"), "t_s,x_m,y_m,z_m\n0,0,0,0\n1,0,0\n").unwrap();
    std::fs::write(dir.join("good.csv"), "t_s,x_m,y_m,z_m\n0,0,0,0\n1,0.1,0,0\n").unwrap();
    let mut script = Script::from_segments(vec![Segment::Trajectory { file: "bad.csv".into() }], false);
    let e = script.prepare(&dir, "test").unwrap_err().to_string();
    assert!(e.contains("bad.csv") && e.contains("line 3"), "{e}");
    let mut script = Script::from_segments(vec![Segment::Trajectory { file: "missing.csv".into() }], false);
    let e = script.prepare(&dir, "test").unwrap_err().to_string();
    assert!(e.contains("missing.csv"), "{e}");
    // Script files resolve trajectories next to themselves.
    let text = r#"(kind: "script", version: 1, hands: (
        (segments: [Trajectory(file: "good.csv")]),
        (segments: [Hold(at_m: (0.0, 0.0, 0.0), for_s: 1.0)], repeat: true),
    ))"#;
    std::fs::write(dir.join("s.ron"), text).unwrap();
    let file = ScriptFile::load(&dir.join("s.ron")).unwrap();
    assert!(matches!(&file.hands[0].segments[0], Segment::Recorded(r) if r.samples().len() == 2));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn script_files_parse_and_report_positions() {
    let text = r#"(
    kind: "script", version: 1,
    hands: (
        (segments: [
            Hold(at_m: (0.0, 0.1, 0.0), for_s: 0.5),
            Reach(to_m: (0.1, 0.1, -0.2), duration_s: 1.0),
            Jab(to_m: (0.1, 0.2, -0.4), out_s: 0.2, back_s: 0.3),
            Circle(centre_m: (0.0, 0.1, 0.0), radius_m: 0.1, normal: (0.0, 0.0, 1.0), period_s: 2.0, turns: 1.5),
            Spar(seed: 3, centre_m: (0.0, 0.0, 0.0), half_extent_m: (0.2, 0.2, 0.25), for_s: 10.0),
        ], repeat: true),
        (segments: []),
    ),
)"#;
    let f = ScriptFile::from_str(text, "scripts.ron").unwrap();
    assert_eq!(f.hands[0].segments.len(), 5);
    assert!(f.hands[0].repeat && !f.hands[1].repeat);

    let bad_field = text.replace("out_s: 0.2", "out_time: 0.2");
    let e = ScriptFile::from_str(&bad_field, "scripts.ron").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, SimRigError::Parse { line: 7, .. }), "{msg}");
    assert!(msg.starts_with("scripts.ron:7:") && msg.contains("out_time"), "{msg}");

    let e = ScriptFile::from_str(&text.replace("(0.0, 0.1, 0.0)", "[0.0, 0.1, 0.0]"), "p.ron").unwrap_err();
    assert!(e.to_string().contains("(x, y, z)") && matches!(e, SimRigError::Parse { line: 5, .. }), "{e}");
    let e = ScriptFile::from_str(&text.replace("version: 1", "version: 9"), "x.ron").unwrap_err().to_string();
    assert!(e.contains("version") && e.contains('9'), "{e}");
    // A file of another kind is named as such, at its kind entry.
    let e = ScriptFile::from_str(&text.replace("\"script\"", "\"rig\""), "x.ron").unwrap_err().to_string();
    assert!(
        e.starts_with("x.ron:2:5:") && e.contains("a rig file") && e.contains("not a script file"),
        "{e}"
    );
    let e = ScriptFile::from_str(&text.replace("radius_m: 0.1", "radius_m: -0.1"), "x.ron")
        .unwrap_err()
        .to_string();
    assert!(e.contains("hand 0") && e.contains("segment 3") && e.contains("radius_m"), "{e}");
}

#[test]
fn builtin_scripts_exist_and_tour_presses_past_the_surfaces() {
    let home = [DVec3::new(-0.2, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0)];
    for name in BUILTIN_SCRIPTS {
        let s = builtin_script(name, home, 1).unwrap();
        for (i, script) in s.iter().enumerate() {
            script.validate(&format!("{name} {i}")).unwrap();
        }
    }
    assert!(builtin_script("nope", home, 1).is_none());
    assert_eq!(builtin_script("hold", home, 1).unwrap()[1].target_at(home[1], 9.0).pos_m, home[1]);

    let [h0, h1] = builtin_script("tour", home, 0).unwrap();
    let r = tour::REACH_S;
    let (p, rest) = (tour::PRESS_S, tour::REST_S);
    // Timeline: rest, reach, press, reach back, rest, reach, press, reach back, rest, ...
    let front_t = rest + r + p / 2.0;
    let floor_t = 2.0 * rest + 3.0 * r + p + p / 2.0;
    let sphere_t = 3.0 * rest + 5.0 * r + 2.0 * p + p / 2.0;
    for (h, s) in [&h0, &h1].into_iter().enumerate() {
        assert_eq!(
            s.target_at(home[h], front_t).pos_m,
            DVec3::new(home[h].x, home[h].y, tour::FRONT_TARGET_Z_M)
        );
        assert_eq!(
            s.target_at(home[h], floor_t).pos_m,
            DVec3::new(home[h].x, tour::FLOOR_TARGET_Y_M, tour::FLOOR_TARGET_Z_M)
        );
    }
    // Both hands squeeze the ball from opposite sides, 1.5 cm past first contact of a 4 cm fist.
    let ball = DVec3::from(tour::BALL_CENTRE_M);
    let (a, b) = (h0.target_at(home[0], sphere_t).pos_m, h1.target_at(home[1], sphere_t).pos_m);
    assert!(a.x < ball.x && b.x > ball.x, "{a} {b}");
    for p in [a, b] {
        let depth = (0.08 + 0.04) - (p - ball).length();
        assert!((depth - 0.015).abs() < 1e-12, "{depth}");
    }
    // Both hands' passes last the same, so they stay in step when repeating.
    let pass = |s: &Script| Script::from_segments(s.segments.clone(), false).duration_s(DVec3::ZERO).unwrap();
    assert_eq!(pass(&h0), pass(&h1));
    // And it starts over from home.
    assert_eq!(h0.target_at(home[0], pass(&h0) + 0.1).pos_m, home[0]);
}

#[test]
fn simulated_hand_follows_sparring() {
    let p = SimRigParams::lab([DVec3::new(-0.2, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0)]);
    let home = [p.hands[0].start_m, p.hands[1].start_m];
    let scripts = builtin_script("spar", home, 9).unwrap();
    let mut rig = opened(p, scripts);
    let (mut worst, mut min_z) = (0.0f64, f64::MAX);
    let mut inp = Input::default();
    for _ in 0..20_000 {
        rig.exchange(&Output::default(), &mut inp).unwrap();
        for h in rig.truth().hands {
            assert!(h.pos_m.is_finite());
            worst = worst.max((h.pos_m - h.target_m).length());
            min_z = min_z.min(h.pos_m.z);
        }
    }
    // A 1 kg hand on a 200 N/m, 20 N s/m arm (natural period 0.44 s) lags 0.15 s jabs by
    // some centimetres, and yet the jabs do get out.
    assert!(worst < 0.25, "hand strayed {worst} m from its target");
    assert!(min_z < -0.12, "no jab got out: min z {min_z}");
}

#[test]
fn simulated_hand_presses_to_the_tour_targets() {
    let p = SimRigParams::lab([DVec3::new(-0.2, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0)]);
    let home = [p.hands[0].start_m, p.hands[1].start_m];
    let scripts = builtin_script("tour", home, 0).unwrap();
    let mut rig = opened(p, scripts);
    // End of the front press: rest + reach + press.
    let ticks = ((tour::REST_S + tour::REACH_S + tour::PRESS_S) * 1000.0) as usize - 1;
    run(&mut rig, &Output::default(), ticks);
    for h in 0..2 {
        let pos = rig.truth().hands[h].pos_m;
        assert!((pos.z - tour::FRONT_TARGET_Z_M).abs() < 1e-3, "hand {h} at {pos}");
    }
}
