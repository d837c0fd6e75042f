//! The virtual boxer's costs on the sim thread (issue 6: "sim step and prediction cost during a
//! bout"), dt = 3 ms, active virtual human, the world as `spidar run` builds it:
//!
//! - `boxer/step_guard`: one `BoxingWorld` step, both avatar hands held at guard, nothing
//!   triggers a prediction and the virtual human does not attack.
//! - `boxer/predict_jab`: one prediction as the mind runs it, from a state captured mid-jab with
//!   the user's hand coming at the head at 2-3 m/s (the mind's current reaches continuing).
//! - `boxer/predict_longest_in_jab`: of every prediction the mind could run during that jab, the
//!   one that ran the most steps (the stopping rules of Table I decide how far each goes).
//! - `boxer/bout_step`: the mean cost of a world step over whole 0.6 s jab cycles (a jab out in
//!   0.25 s and back every 200 steps, alternating hands, spontaneous attacks on): what the sim
//!   thread pays per 3 ms, predictions included.
//!
//! The set-up prints what each case measures (speeds, steps a prediction ran, predictions per
//! cycle). `cargo bench -p spidar-sim --bench boxer`; for steadier numbers build with
//! `--no-run` and run `chrt -f 50 taskset -c 1 target/release/deps/boxer-* --bench`.
//!
//! Must never assert a time: the assertions check that each case measures what it says (no
//! prediction at guard, a repeatable prediction, predictions in the bout), not how fast it is.

use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use spidar_sim::boxer::reach::min_jerk_rate;
use spidar_sim::boxer::{min_jerk, BoxerParams, BoxingWorld, HandTarget, Reach};
use spidar_sim::State;

/// Steps of one jab cycle in the bout: 0.6 s at 3 ms.
const CYCLE_STEPS: usize = 200;
/// The jab goes out in this long, then comes back in the same time.
const JAB_OUT_S: f64 = 0.25;

/// A world after 0.9 s of settling in its guard, spontaneous attacks off (as the tests do).
fn settled() -> BoxingWorld {
    let mut w = BoxingWorld::new(BoxerParams::default()).unwrap();
    w.mind.params.attack_per_step = 0.0;
    for _ in 0..300 {
        w.begin_step();
        w.step(&[None, None]);
    }
    w.begin_step();
    w
}

/// Both avatar hands' targets at their current positions (the guard), at rest.
fn guard_of(w: &BoxingWorld) -> [DVec3; 2] {
    [w.com(w.avatar.hand[0]), w.com(w.avatar.hand[1])]
}

/// The user's hands `k` steps into a jab cycle: `hand` out from its guard to `to` in
/// `JAB_OUT_S` and back along the minimum-jerk profile, the other held at guard.
fn jab_targets(guard: [DVec3; 2], hand: usize, to: DVec3, k: usize, dt_s: f64) -> [Option<HandTarget>; 2] {
    let t = k as f64 * dt_s;
    let (a, b, tau) = if t < JAB_OUT_S {
        (guard[hand], to, t / JAB_OUT_S)
    } else {
        (to, guard[hand], ((t - JAB_OUT_S) / JAB_OUT_S).min(1.0))
    };
    let mut out = [0, 1].map(|h| Some(HandTarget { pos_m: guard[h], vel_m_per_s: DVec3::ZERO }));
    out[hand] = Some(HandTarget {
        pos_m: a + (b - a) * min_jerk(tau),
        vel_m_per_s: (b - a) * (min_jerk_rate(tau) / JAB_OUT_S),
    });
    out
}

/// A state the mind predicts from, with the user's hands it extrapolates and the virtual human's
/// reaches it continues (the prediction depends on all three).
struct Captured {
    state: State,
    reaches: [Option<Reach>; 3],
    /// The mind's estimate of the user's hands' acceleration (the extrapolation uses it).
    acc: [DVec3; 2],
    targets: [Option<HandTarget>; 2],
    speed_m_per_s: f64,
    steps_run: u64,
}

/// Drives one jab at the head through an active world; at every step where the mind's trigger
/// holds, runs the prediction the mind would run from there. Returns the first such state with
/// the hand at 2-3 m/s and the one whose prediction ran the most steps, and the world (for its
/// models and parameters).
fn jab_predictions() -> (BoxingWorld, Captured, Captured) {
    let mut w = settled();
    let guard = guard_of(&w);
    let to = w.com(w.vh.head) + DVec3::new(0.0, 0.0, 0.05);
    let dt = w.dt_s();
    let (mut at_speed, mut longest): (Option<Captured>, Option<Captured>) = (None, None);
    for k in 0..CYCLE_STEPS {
        let targets = jab_targets(guard, 0, to, k, dt);
        if w.mind.triggered(&w.model, &w.ws) {
            let (st, tg, bp) = (&w.state, &targets, &w.params);
            w.mind.predict(&w.model, st, tg, bp);
            let c = Captured {
                state: w.state.clone(),
                reaches: w.mind.reaches,
                acc: w.mind.hand_acc_m_per_s2,
                targets,
                speed_m_per_s: targets[0].map_or(0.0, |t| t.vel_m_per_s.length()),
                // The predictor's copy advanced exactly as many steps as the prediction ran.
                steps_run: w.mind.predictor.state.steps - w.state.steps,
            };
            if at_speed.is_none() && (2.0..=3.0).contains(&c.speed_m_per_s) && k as f64 * dt < JAB_OUT_S {
                at_speed = Some(Captured { state: c.state.clone(), ..c });
            }
            if longest.as_ref().is_none_or(|l| c.steps_run > l.steps_run) {
                longest = Some(c);
            }
        }
        w.step(&targets);
        w.begin_step();
    }
    let at_speed = at_speed.expect("the jab never reached 2-3 m/s toward the head while triggering");
    let longest = longest.expect("the jab never triggered a prediction");
    (w, at_speed, longest)
}

fn bench_step_guard(c: &mut Criterion) {
    let mut w = settled();
    let guard = guard_of(&w);
    let targets = guard.map(|p| Some(HandTarget { pos_m: p, vel_m_per_s: DVec3::ZERO }));
    let before = w.mind.predictions;
    c.bench_function("boxer/step_guard", |b| {
        b.iter(|| {
            w.step(&targets);
            w.begin_step();
        })
    });
    assert_eq!(w.mind.predictions, before, "a hand held at guard must not trigger a prediction");
}

fn bench_predict(c: &mut Criterion) {
    let (mut w, jab, longest) = jab_predictions();
    let horizon = (w.mind.params.horizon_s / w.dt_s()).ceil() as u64;
    for (name, cap) in [("boxer/predict_jab", &jab), ("boxer/predict_longest_in_jab", &longest)] {
        w.mind.reaches = cap.reaches;
        w.mind.hand_acc_m_per_s2 = cap.acc;
        let d = w.mind.predict(&w.model, &cap.state, &cap.targets, &w.params);
        let ran = w.mind.predictor.state.steps - cap.state.steps;
        assert_eq!(ran, cap.steps_run, "{name}: the prediction is not repeatable from the captured state");
        eprintln!(
            "{name}: hand target at {:.2} m/s, the prediction ran {} of {horizon} steps ({:.0} ms ahead), decided {}",
            cap.speed_m_per_s,
            cap.steps_run,
            cap.steps_run as f64 * w.dt_s() * 1e3,
            d.map_or("nothing".to_string(), |d| format!(
                "{:?} on {} at +{:.0} ms",
                d.class,
                w.model.bodies[d.vh_body].name,
                (d.at_s - cap.state.t_s) * 1e3
            )),
        );
        c.bench_function(name, |b| b.iter(|| w.mind.predict(&w.model, &cap.state, &cap.targets, &w.params)));
    }
}

fn bench_bout_step(c: &mut Criterion) {
    let mut w = settled();
    // Spontaneous attacks on, as in a bout (the lab's rate).
    w.mind.params.attack_per_step = BoxerParams::default().mind.attack_per_step;
    let guard = guard_of(&w);
    let head = w.com(w.vh.head) + DVec3::new(0.0, 0.0, 0.05);
    let dt = w.dt_s();
    let peak = (head - guard[0]).length() * 1.875 / JAB_OUT_S;
    let mut k = 0usize;
    let cycle = |w: &mut BoxingWorld, k: &mut usize| {
        for _ in 0..CYCLE_STEPS {
            let targets = jab_targets(guard, (*k / CYCLE_STEPS) % 2, head, *k % CYCLE_STEPS, dt);
            w.step(&targets);
            w.begin_step();
            *k += 1;
        }
    };
    // Warm-up: two cycles, one per hand.
    cycle(&mut w, &mut k);
    cycle(&mut w, &mut k);
    let (p0, k0) = (w.mind.predictions, k);
    c.bench_function("boxer/bout_step", |b| {
        // Whole cycles only, so every sample holds the same mix of guard and predicting steps;
        // the time returned is per step.
        b.iter_custom(|iters| {
            let started = Instant::now();
            for _ in 0..iters {
                cycle(&mut w, &mut k);
            }
            started.elapsed() / CYCLE_STEPS as u32
        })
    });
    if k == k0 {
        return; // skipped by a name filter on the command line
    }
    let cycles = ((k - k0) / CYCLE_STEPS) as f64;
    eprintln!(
        "boxer/bout_step: jabs peak {peak:.1} m/s; {:.1} predictions per 0.6 s cycle over {cycles} cycles; \
         {} avoidances, {} blocks, {} attacks",
        (w.mind.predictions - p0) as f64 / cycles,
        w.mind.avoidances,
        w.mind.blocks,
        w.mind.attacks
    );
    assert!(w.mind.predictions > p0, "the bout's jabs must trigger predictions");
}

criterion_group!(
    name = g;
    config = Criterion::default().sample_size(30);
    targets = bench_step_guard, bench_predict, bench_bout_step
);
criterion_main!(g);
