//! The tick's compute cost (both hands, no device I/O) and each of its phases: the phases as
//! the tick runs them (`TickCore::run_phase`, both hands, on an active rig pressing a wall) and
//! the modules' functions alone. Budget (DESIGN.md section 8): the whole tick under 2 us on this
//! machine.
//!
//! `cargo bench -p spidar-rt --bench tick`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use spidar_device::{Input, Output};
use spidar_msg::{ContactModel, HandSample, Proxy, ProxyId, ProxyShape, MAX_PROXIES};
use spidar_rt::kinematics::Kinematics;
use spidar_rt::render::render_hand;
use spidar_rt::telemetry::TickRecord;
use spidar_rt::tension::{Allocator, TensionLimits};
use spidar_rt::tick::{Phase, HOMING_SETTLE_S};
use spidar_rt::{Command, Lifecycle, Rig, TickCore};

/// Counts that put each grip at `pos` for a rig homed with counts 0 at the home points.
fn counts_at(rig: &Rig, pos: [DVec3; 2]) -> Input {
    let mut inp = Input::default();
    for (h, hr) in rig.hands.iter().enumerate() {
        for s in 0..4 {
            let l = (hr.anchors_m[s] - pos[h]).length() - (hr.anchors_m[s] - hr.home_m).length();
            inp.counts[hr.channels[s]] = (l / hr.metres_per_count[s]).round() as i64;
        }
    }
    inp
}

/// The rig-check scene's proxies (world frame): front wall, table, ball.
fn scene_model(stamp_s: f64) -> ContactModel {
    let mut m = ContactModel { seq: 1, stamp_s, ..Default::default() };
    let proxy = |part, shape, k| Proxy {
        id: ProxyId { body: 0, part },
        shape,
        k_n_per_m: k,
        d_n_s_per_m: 5.0,
        vel_m_per_s: DVec3::new(0.0, 0.01, 0.0),
        hand_mask: Proxy::BOTH_HANDS,
    };
    m.push(proxy(0, ProxyShape::Plane { point_m: DVec3::new(0.0, 1.1, -0.30), normal: DVec3::Z }, 2000.0));
    m.push(proxy(1, ProxyShape::Plane { point_m: DVec3::new(0.0, 0.9, 0.0), normal: DVec3::Y }, 2000.0));
    m.push(proxy(2, ProxyShape::Sphere { centre_m: DVec3::new(0.0, 1.35, -0.12), radius_m: 0.08 }, 1000.0));
    m
}

fn active_core(rig: &Rig) -> TickCore {
    let mut core = TickCore::new(rig).unwrap();
    let home = counts_at(rig, [rig.hands[0].home_m, rig.hands[1].home_m]);
    let (mut out, mut s, mut rec) = (Output::default(), HandSample::default(), TickRecord::default());
    core.command(Command::Home);
    core.command(Command::Activate);
    for _ in 0..((HOMING_SETTLE_S + rig.safety.ramp_in_s) / rig.period_s) as usize + 2 {
        core.step(0.0, Ok(()), &home, &mut out, &mut s, &mut rec);
    }
    assert_eq!(core.state(), Lifecycle::Active);
    core
}

fn bench(c: &mut Criterion) {
    let rig = Rig::default_rig();
    // Both hands pressing 1.4 mm into the front wall: rendering, a contact and full allocation.
    let press = [DVec3::new(-0.15, 0.0, -0.2614), DVec3::new(0.15, 0.0, -0.2614)];
    let inp = counts_at(&rig, press);

    let mut core = active_core(&rig);
    let (mut out, mut s, mut rec) = (Output::default(), HandSample::default(), TickRecord::default());
    core.set_contact_model(scene_model(0.0));
    c.bench_function("tick/both_hands_in_contact", |b| {
        b.iter(|| {
            core.step(0.001, Ok(()), black_box(&inp), &mut out, &mut s, &mut rec);
            black_box(&out);
        })
    });
    assert!(rec.hands[0].contacts > 0, "the benchmark must render a contact");

    // The tick's phases one by one, both hands, from the state the whole tick above left: an
    // active rig, a fresh model, both grips 1.4 mm into the wall.
    core.step(0.001, Ok(()), &inp, &mut out, &mut s, &mut rec);
    for (name, phase) in [
        ("step_phase/read_kinematics_velocity", Phase::Read),
        ("step_phase/render", Phase::Render),
        ("step_phase/safety", Phase::Safety),
        ("step_phase/allocate", Phase::Allocate),
    ] {
        c.bench_function(name, |b| b.iter(|| black_box(core.run_phase(phase, 0.001, black_box(&inp)))));
    }
    assert_eq!(core.state(), Lifecycle::Active, "the phases must run on an active rig");
    assert!(core.run_phase(Phase::Render, 0.001, &inp) > 0.0, "the wall pushes back along +z");

    let free = counts_at(&rig, [rig.hands[0].home_m, rig.hands[1].home_m]);
    c.bench_function("tick/both_hands_free", |b| {
        b.iter(|| {
            core.step(0.001, Ok(()), black_box(&free), &mut out, &mut s, &mut rec);
            black_box(&out);
        })
    });

    // What the loop does around the core for the record (runner.rs): a fresh record built in
    // place, the device input and output, the sample and the model copied in, the send.
    let (tx, rx) = crossbeam_channel::bounded::<TickRecord>(4096);
    let mut last = TickRecord::default();
    let model = Some(scene_model(0.0));
    c.bench_function("loop/tick_record_filled_and_sent", |b| {
        b.iter(|| {
            last = TickRecord::default();
            last.input = black_box(inp);
            last.output = black_box(out);
            last.sample = black_box(s);
            last.model = black_box(model);
            let _ = tx.try_send(last);
            black_box(&last);
            black_box(rx.try_recv().ok());
        })
    });

    let kin = Kinematics::new(rig.hands[0].anchors_m).unwrap();
    let lengths = kin.lengths(press[0] + DVec3::new(1e-5, -2e-5, 3e-5));
    c.bench_function("phase/kinematics_solve_2_iterations", |b| {
        b.iter(|| black_box(kin.solve(black_box(&lengths), 2)))
    });

    let world = rig.rig_to_world.point(press[0]);
    let model = scene_model(0.0);
    c.bench_function("phase/render_hand_3_proxies", |b| {
        b.iter(|| {
            let mut imp = [DVec3::ZERO; MAX_PROXIES];
            black_box(render_hand(
                0,
                black_box(world),
                DVec3::ZERO,
                0.04,
                5000.0,
                &model,
                0.002,
                0.001,
                &mut imp,
            ))
        })
    });

    let mut alloc = Allocator::new(TensionLimits { min_n: 1.0, max_n: 20.0 });
    let dirs = kin.directions(press[0]);
    c.bench_function("phase/allocate_exact", |b| {
        b.iter(|| black_box(alloc.allocate(black_box(&dirs), black_box(DVec3::new(0.0, 0.0, 2.7)))))
    });
    c.bench_function("phase/allocate_scaled", |b| {
        b.iter(|| black_box(alloc.allocate(black_box(&dirs), black_box(DVec3::new(30.0, -40.0, 20.0)))))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
