//! Engine benchmarks on the two-boxer scene at dt = 3 ms, for comparison with the figures the
//! engine issue quotes for this machine: MuJoCo 4.0 `mj_step` ~18 us without contacts and
//! 41-54 us while fists land; 0.3 s prediction (copy + 100 steps) 3.5-4.5 ms; Pinocchio ABA for
//! one 26-DOF boxer ~7 us. Run: `cargo bench -p spidar-sim --bench step`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use glam::DVec3;
use spidar_sim::aba::aba;
use spidar_sim::contact::contacts;
use spidar_sim::desc::{build_scene, builtin_body, SCENE_BOXING_RON};
use spidar_sim::passive::passive_forces;
use spidar_sim::state::kinematics;
use spidar_sim::{boxing_scene, forward, integrate, step, Model, Part, Predictor, Side, State, Workspace};

/// The boxer's right fist driven at the avatar's guard, as in the engine tests.
fn punch(m: &Model, ws: &mut Workspace) {
    let fist = m.find_part(1, Part::Hand, Side::Right).unwrap();
    let head = m.find_part(0, Part::Hand, Side::Left).unwrap();
    let to = ws.com_world(m, head) - ws.com_world(m, fist);
    let f = to.normalize() * (2000.0 * to.length()).min(600.0);
    let pf = ws.com_world(m, fist);
    ws.add_force_at(fist, pf, f);
    let elbow = m.find_part(1, Part::Forearm, Side::Right).unwrap();
    let shoulder = m.find_part(1, Part::UpperArm, Side::Right).unwrap();
    ws.tau[m.bodies[elbow].v_at] -= 150.0;
    ws.tau[m.bodies[shoulder].v_at] += 80.0;
}

/// A state in the middle of a punch landing, with fist-head contacts.
fn landing_state(m: &Model) -> State {
    let mut s = State::new(m);
    let mut ws = Workspace::new(m);
    loop {
        kinematics(m, &s, &mut ws);
        punch(m, &mut ws);
        forward(m, &s, &mut ws);
        let n = ws.contacts.len();
        integrate(m, &mut s, &mut ws);
        if n > 0 && s.steps > 10 {
            // A few steps into the contact.
            for _ in 0..3 {
                kinematics(m, &s, &mut ws);
                punch(m, &mut ws);
                step(m, &mut s, &mut ws);
            }
            return s;
        }
        assert!(s.steps < 1000, "the punch never lands");
    }
}

fn benches(c: &mut Criterion) {
    let m = boxing_scene().unwrap();
    let mut ws = Workspace::new(&m);
    let mut s = State::new(&m);
    for _ in 0..300 {
        step(&m, &mut s, &mut ws);
    }
    let guard = s.clone();
    c.bench_function("step/two_boxers_guard_no_contacts", |b| {
        b.iter_batched_ref(|| guard.clone(), |st| step(&m, st, &mut ws), BatchSize::SmallInput)
    });
    let landing = landing_state(&m);
    c.bench_function("step/two_boxers_fist_landing", |b| {
        b.iter_batched_ref(
            || landing.clone(),
            |st| {
                kinematics(&m, st, &mut ws);
                punch(&m, &mut ws);
                step(&m, st, &mut ws);
                assert!(!ws.contacts.is_empty());
            },
            BatchSize::SmallInput,
        )
    });
    let mut pred = Predictor::new(&m);
    for (name, steps) in
        [("predict/0.3s_copy_plus_100_steps", 100), ("predict/0.5s_copy_plus_167_steps", 167)]
    {
        c.bench_function(name, |b| {
            b.iter(|| {
                pred.run(&m, &landing, steps, |m, _, ws| {
                    // The controller works from the previous step's kinematics, as a real one does.
                    punch(m, ws);
                    true
                })
            })
        });
    }
    // The step's phases on the landing state, each alone (what a predicted step spends where):
    // kinematics, contacts (broad and narrow phase, penalty forces), joint springs and limits,
    // ABA, integration. Each runs on the workspace the previous phases left, as in `step`.
    kinematics(&m, &landing, &mut ws);
    punch(&m, &mut ws);
    let f_ext = ws.f_ext.clone();
    c.bench_function("phase/kinematics", |b| b.iter(|| kinematics(&m, &landing, &mut ws)));
    c.bench_function("phase/contacts", |b| {
        b.iter(|| {
            ws.f_ext.copy_from_slice(&f_ext);
            contacts(&m, &mut ws)
        })
    });
    assert!(!ws.contacts.is_empty(), "phase/contacts must measure a state with contacts");
    c.bench_function("phase/passive", |b| b.iter(|| passive_forces(&m, &landing, &mut ws)));
    c.bench_function("phase/aba", |b| b.iter(|| aba(&m, &landing, &mut ws)));
    c.bench_function("phase/integrate", |b| {
        b.iter_batched_ref(|| landing.clone(), |st| integrate(&m, st, &mut ws), BatchSize::SmallInput)
    });
    // ABA alone for one 26-DOF boxer (kinematics + passive forces + ABA), as Pinocchio's ABA.
    let one = build_scene(
        &SCENE_BOXING_RON.replace(
            "(name: \"avatar\", body: \"body-upper.ron\", pos_m: (0.0, 0.0, 0.0), yaw_deg: 0.0),",
            "",
        ),
        "one boxer",
        builtin_body,
    )
    .unwrap();
    assert_eq!(one.nv, 26);
    let mut ws1 = Workspace::new(&one);
    let mut s1 = State::new(&one);
    for (i, v) in s1.v.iter_mut().enumerate() {
        *v = (i as f64 * 0.37).sin();
    }
    ws1.f_ext[3].lin = DVec3::X;
    c.bench_function("aba/one_boxer_26dof", |b| {
        b.iter(|| {
            kinematics(&one, &s1, &mut ws1);
            passive_forces(&one, &s1, &mut ws1);
            aba(&one, &s1, &mut ws1);
        })
    });
}

/// The narrow phase per shape pair, overlapping cases.
fn collide_pairs(c: &mut Criterion) {
    use glam::{DMat3, DQuat};
    use spidar_sim::collide::{collide, Hit, Shape, ShapePose, MAX_HITS};
    let at = |x: f64, y: f64, z: f64| ShapePose { pos_m: DVec3::new(x, y, z), rot: DMat3::IDENTITY };
    let along_x = |y: f64| ShapePose {
        pos_m: DVec3::new(0.0, y, 0.0),
        rot: DMat3::from_rotation_z(std::f64::consts::FRAC_PI_2),
    };
    let tilt = ShapePose {
        pos_m: DVec3::new(0.1, 0.6, 0.0),
        rot: DMat3::from_quat(DQuat::from_xyzw(0.1, 0.2, 0.3, 0.9).normalize()),
    };
    let sphere = Shape::Sphere { radius_m: 0.5 };
    let capsule = Shape::Capsule { half_length_m: 1.0, radius_m: 0.3 };
    let cube = Shape::Box { half_extents_m: DVec3::splat(0.5) };
    let cases = [
        ("sphere-sphere", sphere, at(0.0, 0.0, 0.0), sphere, at(0.3, 0.7, 0.1)),
        ("sphere-capsule", sphere, at(0.2, 0.0, 0.0), capsule, tilt),
        ("capsule-capsule", capsule, along_x(0.5), capsule, tilt),
        ("sphere-box", sphere, at(0.2, 1.0, 0.0), cube, tilt),
        ("capsule-box", capsule, along_x(1.2), cube, tilt),
        ("box-box", cube, at(0.0, 1.3, 0.0), cube, tilt),
        ("box-plane", cube, at(0.0, 0.45, 0.0), Shape::Plane, at(0.0, 0.0, 0.0)),
    ];
    let mut out = [Hit { point_m: DVec3::ZERO, normal: DVec3::Y, depth_m: 0.0 }; MAX_HITS];
    for (name, a, pa, b, pb) in cases {
        c.bench_function(&format!("collide/{name}"), |bch| bch.iter(|| collide(&a, &pa, &b, &pb, &mut out)));
    }
}

criterion_group!(name = g; config = Criterion::default().sample_size(30); targets = benches, collide_pairs);
criterion_main!(g);
