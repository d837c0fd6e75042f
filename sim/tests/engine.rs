//! Physics tests of the engine: each proves one property against an analytic answer or an
//! independent algorithm, on small models built here and on the shipped boxing scene.
#![allow(clippy::needless_range_loop)]

use glam::{DMat3, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use spidar_sim::crba::crba;
use spidar_sim::desc::{build_scene, builtin_body, SCENE_BOXING_RON};
use spidar_sim::joint::{write_quat, JointKind};
use spidar_sim::rnea::rnea;
use spidar_sim::state::kinematics;
use spidar_sim::step::{angular_momentum, kinetic_energy, linear_momentum, potential_energy};
use spidar_sim::{boxing_scene, forward, integrate, step, Model, Part, Predictor, Side, State, Workspace};

mod alloc_count;

/// A scene with the given header fields, statics and one body file (named "b.ron").
fn scene(dt_s: f64, gravity: f64, contact: &str, statics: &str, actors: &str, body: &str) -> Model {
    let text = format!(
        "(kind: \"body-scene\", version: 1, dt_s: {dt_s}, gravity_m_per_s2: (0.0, {gravity}, 0.0), contact: {contact}, \
         joint_limit: (stiffness_n_m_per_rad: 300.0, damping_n_m_s_per_rad: 5.0), \
         statics: [{statics}], actors: [{actors}])"
    );
    let body = body.to_string();
    build_scene(&text, "test-scene", |name| {
        if name == "b.ron" {
            Ok((body.clone(), "b.ron".into()))
        } else {
            builtin_body(name)
        }
    })
    .unwrap_or_else(|e| panic!("{e}"))
}

const NO_CONTACT: &str = "(stiffness: Abs(1e5), damping: Abs(0.0), friction: 0.0, slip_m_per_s: 0.01)";
const FLOOR: &str = "(name: \"floor\", shape: Plane)";

/// One free rigid body with the given mass description and shapes.
fn free_body(mass: &str, shapes: &str) -> String {
    format!(
        "(kind: \"body\", version: 1, name: \"thing\", source: \"test\", gain_dt_s: 0.003, links: [(name: \"thing\", parent: None, \
         joint: (kind: Free, anchor_m: (0.0, 0.0, 0.0), stiffness: Abs(0.0), damping: Abs(0.0)), \
         mass: {mass}, shapes: [{shapes}])])"
    )
}

fn actor(name: &str, x: f64, y: f64, z: f64) -> String {
    format!("(name: \"{name}\", body: \"b.ron\", pos_m: ({x}, {y}, {z}))")
}

/// Sets a free root's angular velocity (body frame) and linear velocity (actor frame).
fn set_free_velocity(m: &Model, s: &mut State, body: usize, w_body: DVec3, v_body: DVec3) {
    let va = m.bodies[body].v_at;
    s.v[va..va + 3].copy_from_slice(&w_body.to_array());
    s.v[va + 3..va + 6].copy_from_slice(&v_body.to_array());
}

fn random_state(m: &Model, rng: &mut Pcg64) -> State {
    let mut s = State::new(m);
    for b in &m.bodies {
        let q = &mut s.q[b.q_at..b.q_at + b.nq()];
        match b.joint {
            JointKind::Free => {
                for x in &mut q[..3] {
                    *x += rng.random_range(-0.2..0.2);
                }
                let axis = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
                write_quat(
                    &mut q[3..7],
                    DQuat::from_axis_angle(axis.normalize(), rng.random_range(-2.0..2.0)),
                );
            }
            JointKind::Ball => {
                let axis = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
                write_quat(q, DQuat::from_axis_angle(axis.normalize(), rng.random_range(-2.0..2.0)));
            }
            _ => q.iter_mut().for_each(|x| *x = rng.random_range(-2.0..2.0)),
        }
    }
    s.v.iter_mut().for_each(|x| *x = rng.random_range(-3.0..3.0));
    s
}

/// A chain exercising every joint kind: free root, ball, universal, revolute, fixed.
const CHAIN: &str = r#"(kind: "body", version: 1, name: "chain", source: "test", gain_dt_s: 0.003, links: [
    (name: "root", parent: None, joint: (kind: Free, anchor_m: (0.0, 1.0, 0.0), stiffness: Abs(50.0), damping: Abs(2.0),
        linear_stiffness: Some(Abs(300.0)), linear_damping: Some(Abs(10.0))),
     mass: Box(mass_kg: 3.0, size_m: (0.3, 0.2, 0.1), centre_m: (0.01, 0.02, -0.03))),
    (name: "a", parent: Some("root"), joint: (kind: Ball, anchor_m: (0.1, 0.2, 0.0), default_deg: [10.0, 20.0, -5.0],
        stiffness: Abs(20.0), damping: Abs(1.0), limits_deg: Some([(-30.0, 30.0), (-40.0, 40.0), (-50.0, 50.0)])),
     mass: Ellipsoid(mass_kg: 1.0, size_m: (0.1, 0.3, 0.12), centre_m: (0.0, 0.15, 0.02))),
    (name: "b", parent: Some("a"), joint: (kind: Universal(axis1: (1.0, 0.0, 0.0), axis2: (0.0, 0.6, 0.8)),
        anchor_m: (0.0, 0.3, 0.0), stiffness: Abs(5.0), damping: Abs(0.5)),
     mass: Explicit(mass_kg: 0.7, centre_m: (0.02, 0.1, 0.0), inertia_kg_m2: (0.003, 0.001, 0.004))),
    (name: "c", parent: Some("b"), joint: (kind: Revolute(axis: (0.0, 0.0, 1.0)), anchor_m: (0.0, 0.2, 0.05),
        stiffness: Abs(3.0), damping: Abs(0.1), limits_deg: Some([(-20.0, 20.0)])),
     mass: Box(mass_kg: 0.4, size_m: (0.05, 0.2, 0.05), centre_m: (0.0, 0.1, 0.0))),
    (name: "d", parent: Some("c"), joint: (kind: Fixed, anchor_m: (0.0, 0.2, 0.0), stiffness: Abs(0.0), damping: Abs(0.0)),
     mass: Box(mass_kg: 0.2, size_m: (0.05, 0.05, 0.05), centre_m: (0.0, 0.02, 0.0))),
    (name: "e", parent: Some("a"), joint: (kind: Revolute(axis: (0.0, 1.0, 0.0)), anchor_m: (0.05, 0.1, 0.0),
        stiffness: Abs(1.0), damping: Abs(0.0)),
     mass: Box(mass_kg: 0.3, size_m: (0.2, 0.02, 0.05), centre_m: (0.1, 0.0, 0.0))),
])"#;

/// ABA's accelerations satisfy the equation of motion built independently by RNEA (bias forces)
/// and CRBA (mass matrix), including the implicit joint terms, at random states with random
/// joint forces and external forces, on every joint kind and on the boxing scene.
#[test]
fn aba_agrees_with_rnea_and_crba_at_random_states() {
    let chain = scene(0.003, -9.81, NO_CONTACT, "", &actor("c", 0.1, 0.0, -0.2), CHAIN);
    let boxers = boxing_scene().unwrap();
    let mut rng = Pcg64::seed_from_u64(7);
    for m in [&chain, &boxers] {
        let mut ws = Workspace::new(m);
        let nv = m.nv;
        let mut mm = vec![0.0; nv * nv];
        let mut bias = vec![0.0; nv];
        let mut tau_id = vec![0.0; nv];
        for _ in 0..50 {
            let s = random_state(m, &mut rng);
            let tau: Vec<f64> = (0..nv).map(|_| rng.random_range(-5.0..5.0)).collect();
            let fext: Vec<(usize, DVec3, DVec3)> = (0..3)
                .map(|_| {
                    let b = rng.random_range(0..m.bodies.len());
                    let p = DVec3::new(rng.random(), rng.random(), rng.random());
                    let f = DVec3::new(rng.random(), rng.random(), rng.random()) * 20.0 - 10.0;
                    (b, p, f)
                })
                .collect();
            for &(b, p, f) in &fext {
                ws.add_force_at(b, p, f);
            }
            ws.tau.copy_from_slice(&tau);
            forward(m, &s, &mut ws);
            let qdd = ws.qdd.clone();
            // The contacts of this random (interpenetrating) state are external forces too: rnea
            // and the rhs see the same ws.f_ext that ABA saw.
            let applied: Vec<f64> = (0..nv).map(|k| tau[k] + ws.tau_passive[k]).collect();
            let armature = spidar_sim::step::armature(&ws).to_vec();
            rnea(m, &mut ws, &qdd, &mut tau_id);
            let zeros = vec![0.0; nv];
            rnea(m, &mut ws, &zeros, &mut bias);
            crba(m, &mut ws, &mut mm);
            for r in 0..nv {
                let scale = 1.0 + applied[r].abs();
                let via_rnea = tau_id[r] + armature[r] * qdd[r];
                assert!(
                    (via_rnea - applied[r]).abs() < 1e-8 * scale,
                    "rnea row {r}: {via_rnea} vs {}",
                    applied[r]
                );
                let mq: f64 = (0..nv).map(|c| mm[r * nv + c] * qdd[c]).sum();
                let via_crba = mq + bias[r] + armature[r] * qdd[r];
                assert!(
                    (via_crba - applied[r]).abs() < 1e-8 * scale,
                    "crba row {r}: {via_crba} vs {}",
                    applied[r]
                );
                for c in 0..nv {
                    assert!((mm[r * nv + c] - mm[c * nv + r]).abs() < 1e-10, "M symmetric");
                }
            }
            ws.f_ext.iter_mut().for_each(|f| *f = Default::default());
        }
    }
}

/// Runs a force-free asymmetric body for 10 s from the given spin; returns the worst relative
/// drift of angular momentum and of energy, checking linear momentum is exact all along.
fn free_spin_drift(dt_s: f64, w_body: DVec3) -> (f64, f64) {
    let body =
        free_body("Explicit(mass_kg: 2.0, centre_m: (0.0, 0.0, 0.0), inertia_kg_m2: (0.02, 0.05, 0.08))", "");
    let m = scene(dt_s, 0.0, NO_CONTACT, "", &actor("b", 0.0, 0.0, 0.0), &body);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    set_free_velocity(&m, &mut s, 0, w_body, DVec3::new(0.3, -0.2, 0.1));
    kinematics(&m, &s, &mut ws);
    let (p0, l0, e0) = (linear_momentum(&m, &ws), angular_momentum(&m, &ws), kinetic_energy(&m, &ws));
    let mut worst = (0.0f64, 0.0f64);
    for _ in 0..(10.0 / dt_s) as usize {
        step(&m, &mut s, &mut ws);
        kinematics(&m, &s, &mut ws);
        assert!((linear_momentum(&m, &ws) - p0).length() < 1e-12, "linear momentum changed");
        worst.0 = worst.0.max((angular_momentum(&m, &ws) - l0).length() / l0.length());
        worst.1 = worst.1.max((kinetic_energy(&m, &ws) - e0).abs() / e0);
    }
    worst
}

/// Without gravity, damping or contacts, a free body keeps its linear momentum exactly; spinning
/// about a principal axis it keeps angular momentum and energy to rounding; tumbling about the
/// unstable intermediate axis (the hardest case) the semi-implicit step's gyroscopic error stays
/// within 3 % over 10 s at 3 ms and shrinks in proportion to the step.
#[test]
fn free_body_conserves_momentum_and_energy() {
    let (l, e) = free_spin_drift(0.003, DVec3::new(0.0, 0.0, 3.0));
    assert!(l < 1e-9 && e < 1e-9, "principal spin: angular momentum drift {l:.2e}, energy drift {e:.2e}");
    let tumble = DVec3::new(0.05, 3.0, 0.2);
    let (l3, e3) = free_spin_drift(0.003, tumble);
    let (l1, e1) = free_spin_drift(0.001, tumble);
    assert!(
        l3 < 0.03 && e3 < 0.03,
        "tumbling at 3 ms: angular momentum drift {l3:.2e}, energy drift {e3:.2e}"
    );
    assert!(
        l1 < l3 / 2.5 && e1 < e3 / 2.5,
        "drift does not shrink with the step: 3 ms {l3:.2e} {e3:.2e}, 1 ms {l1:.2e} {e1:.2e}"
    );
}

/// A compound pendulum's small-amplitude period is 2 pi sqrt(I_pivot / (m g d)).
#[test]
fn pendulum_period_matches_analytic() {
    // A 1 kg, 0.6 m x 0.04 m x 0.04 m bar pivoting about z at one end, hanging down.
    let body = r#"(kind: "body", version: 1, name: "pendulum", source: "test", gain_dt_s: 0.003, links: [
        (name: "bar", parent: None, joint: (kind: Revolute(axis: (0.0, 0.0, 1.0)), anchor_m: (0.0, 2.0, 0.0),
            default_deg: [5.0], stiffness: Abs(0.0), damping: Abs(0.0)),
         mass: Box(mass_kg: 1.0, size_m: (0.04, 0.6, 0.04), centre_m: (0.0, -0.3, 0.0)))])"#;
    let m = scene(0.003, -9.81, NO_CONTACT, "", &actor("p", 0.0, 0.0, 0.0), body);
    let (mass, d, g) = (1.0, 0.3, 9.81);
    let i_pivot = mass * (0.6f64.powi(2) + 0.04f64.powi(2)) / 12.0 + mass * d * d;
    let analytic = 2.0 * std::f64::consts::PI * (i_pivot / (mass * g * d)).sqrt();
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    // Time the upward zero crossings of the angle (linear interpolation between steps).
    let mut crossings = Vec::new();
    let mut prev = s.q[0];
    while crossings.len() < 6 {
        step(&m, &mut s, &mut ws);
        if prev < 0.0 && s.q[0] >= 0.0 {
            crossings.push(s.t_s - m.dt_s * s.q[0] / (s.q[0] - prev));
        }
        prev = s.q[0];
    }
    let period = (crossings[5] - crossings[0]) / 5.0;
    // Small-amplitude correction for 5 degrees: T = T0 (1 + a^2/16).
    let expected = analytic * (1.0 + (5f64.to_radians()).powi(2) / 16.0);
    assert!((period - expected).abs() / expected < 2e-3, "period {period:.5} s, analytic {expected:.5} s");
}

/// A two-link arm with joint springs, held out sideways under gravity, settles where each
/// spring's torque balances gravity's (checked with RNEA's gravity torques, not the step).
#[test]
fn sprung_chain_settles_to_static_equilibrium() {
    let body = r#"(kind: "body", version: 1, name: "arm", source: "test", gain_dt_s: 0.003, links: [
        (name: "upper", parent: None, joint: (kind: Revolute(axis: (0.0, 0.0, 1.0)), anchor_m: (0.0, 1.5, 0.0),
            default_deg: [90.0], stiffness: Abs(40.0), damping: Abs(3.0)),
         mass: Box(mass_kg: 2.0, size_m: (0.05, 0.3, 0.05), centre_m: (0.0, -0.15, 0.0))),
        (name: "lower", parent: Some("upper"), joint: (kind: Ball, anchor_m: (0.0, -0.3, 0.0),
            default_deg: [0.0, 0.0, 20.0], stiffness: Abs(15.0), damping: Abs(1.0)),
         mass: Box(mass_kg: 1.0, size_m: (0.05, 0.25, 0.05), centre_m: (0.0, -0.125, 0.0)))])"#;
    let m = scene(0.003, -9.81, NO_CONTACT, "", &actor("a", 0.0, 0.0, 0.0), body);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..4000 {
        step(&m, &mut s, &mut ws);
    }
    assert!(s.v.iter().all(|v| v.abs() < 1e-6), "still moving: {:?}", s.v);
    // Static equilibrium: the spring torques equal the gravity torques RNEA gives at rest.
    kinematics(&m, &s, &mut ws);
    spidar_sim::passive::passive_forces(&m, &s, &mut ws);
    let mut g = vec![0.0; m.nv];
    rnea(&m, &mut ws, &vec![0.0; m.nv], &mut g);
    let sag = (s.q[0] - m.q_default[0]).abs();
    assert!(sag > 0.05, "gravity should bend the arm visibly (sag {sag} rad)");
    for k in 0..m.nv {
        assert!(
            (ws.tau_passive[k] - g[k]).abs() < 1e-5,
            "dof {k}: spring {} vs gravity {}",
            ws.tau_passive[k],
            g[k]
        );
    }
}

/// A body dropped on the floor comes to rest at the penetration m g / k; a box landing flat
/// shares the pair's stiffness among its corners and rests at the same depth.
#[test]
fn dropped_body_rests_at_mg_over_k() {
    // Gains within the stability bound at every contact point (see contact.rs).
    let contact = "(stiffness: Abs(4e4), damping: Abs(50.0), friction: 0.5, slip_m_per_s: 0.01)";
    for (shape, bottom) in [
        ("(name: \"s\", shape: Sphere(radius_m: 0.1))", 0.1),
        ("(name: \"b\", shape: Box(size_m: (0.3, 0.1, 0.2)))", 0.05),
        (
            "(name: \"c\", shape: Capsule(half_length_m: 0.2, radius_m: 0.05), rot_deg: (0.0, 0.0, 90.0))",
            0.05,
        ),
    ] {
        let body = free_body("Box(mass_kg: 3.0, size_m: (0.2, 0.2, 0.2), centre_m: (0.0, 0.0, 0.0))", shape);
        let m = scene(0.003, -9.81, contact, FLOOR, &actor("b", 0.0, 0.5, 0.0), &body);
        let mut s = State::new(&m);
        let mut ws = Workspace::new(&m);
        for _ in 0..3000 {
            step(&m, &mut s, &mut ws);
        }
        kinematics(&m, &s, &mut ws);
        let depth = bottom - ws.x0[0].r.y;
        let expected = 3.0 * 9.81 / 4e4;
        assert!(
            (depth - expected).abs() < 0.01 * expected,
            "{shape}: depth {depth:.3e} vs m g / k {expected:.3e}"
        );
        // Vertically at rest (a lying capsule may still roll: nothing resists rolling).
        assert!(s.v[4].abs() < 1e-6, "{shape}: still bouncing {:?}", s.v);
        assert_eq!(ws.contacts_softened, 0);
    }
}

/// Gains beyond the explicit penalty's stability bound at a contact's effective mass (a bar
/// landing on its ends: 0.43 kg at each end of a 3 kg bar) are softened to the bound and counted,
/// and the bar lies still on the floor instead of blowing up.
#[test]
fn too_stiff_contact_gains_are_softened_not_unstable() {
    let contact = "(stiffness: Abs(2e6), damping: Abs(4000.0), friction: 0.5, slip_m_per_s: 0.01)";
    let body = free_body(
        "Box(mass_kg: 3.0, size_m: (0.2, 0.2, 0.2), centre_m: (0.0, 0.0, 0.0))",
        "(name: \"c\", shape: Capsule(half_length_m: 0.2, radius_m: 0.05), rot_deg: (0.0, 0.0, 90.0))",
    );
    let m = scene(0.003, -9.81, contact, FLOOR, &actor("b", 0.0, 0.3, 0.0), &body);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..3000 {
        step(&m, &mut s, &mut ws);
    }
    kinematics(&m, &s, &mut ws);
    assert!(ws.contacts_softened > 0, "the gains were not softened");
    assert!(s.v.iter().all(|v| v.abs() < 0.2), "not lying still: {:?}", s.v);
    let y = ws.x0[0].r.y;
    assert!((0.04..0.05).contains(&y), "resting height {y}");
}

/// Two bodies colliding off-centre, with friction: the contact forces are equal and opposite
/// at the same point, so total linear and angular momentum are conserved through the impact.
#[test]
fn colliding_bodies_conserve_total_momentum() {
    let contact = "(stiffness: Abs(5e4), damping: Abs(20.0), friction: 0.8, slip_m_per_s: 0.01)";
    let body = free_body(
        "Box(mass_kg: 1.5, size_m: (0.2, 0.25, 0.3), centre_m: (0.0, 0.0, 0.0))",
        "(name: \"s\", shape: Capsule(half_length_m: 0.1, radius_m: 0.08)), (name: \"k\", shape: Box(size_m: (0.1, 0.1, 0.1)), pos_m: (0.1, 0.0, 0.0))",
    );
    let actors = format!("{}, {}", actor("a", -0.5, 1.0, 0.0), actor("b", 0.5, 1.05, 0.03));
    let m = scene(0.003, 0.0, contact, "", &actors, &body);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    set_free_velocity(&m, &mut s, 0, DVec3::new(0.0, 1.0, 2.0), DVec3::new(2.0, 0.1, 0.0));
    set_free_velocity(&m, &mut s, 1, DVec3::new(1.0, 0.0, 0.0), DVec3::new(-1.5, 0.0, 0.2));
    kinematics(&m, &s, &mut ws);
    let (p0, l0) = (linear_momentum(&m, &ws), angular_momentum(&m, &ws));
    let mut touched = 0;
    for _ in 0..400 {
        forward(&m, &s, &mut ws);
        touched += ws.contacts.len();
        integrate(&m, &mut s, &mut ws);
        kinematics(&m, &s, &mut ws);
        assert!((linear_momentum(&m, &ws) - p0).length() < 1e-9 * (1.0 + p0.length()));
        // Angular momentum is conserved by the forces; the integrator's gyroscopic error is small.
        assert!((angular_momentum(&m, &ws) - l0).length() < 0.02 * l0.length());
    }
    assert!(touched > 0, "the bodies never touched");
    // And they bounced: body a no longer moves toward b.
    assert!(s.v[3..6].iter().zip([1.0, 0.0, 0.0]).map(|(v, d)| v * d).sum::<f64>() < 1.0);
}

/// Measured justification of the integrator: the boxing scene with the lab's gains diverges at
/// 3 ms when joint springs and dampers are explicit, and is at rest when they are implicit.
#[test]
fn implicit_joint_springs_are_stable_where_explicit_ones_are_not() {
    let mut m = boxing_scene().unwrap();
    let run = |m: &Model| {
        let mut s = State::new(m);
        let mut ws = Workspace::new(m);
        // A small disturbance: a tap on each hand.
        for side in [Side::Left, Side::Right] {
            let h = m.find_part(1, Part::Hand, side).unwrap();
            ws.add_force_at(h, ws.com_world(m, h), DVec3::new(0.0, 0.0, 10.0));
        }
        let mut peak = 0.0f64;
        for _ in 0..1000 {
            step(m, &mut s, &mut ws);
            let v = s.v.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            peak = peak.max(if v.is_finite() { v } else { f64::INFINITY });
        }
        (peak, s.v.iter().fold(0.0f64, |a, v| a.max(v.abs())))
    };
    let (_, end_implicit) = run(&m);
    m.implicit_joint_springs = false;
    let (peak_explicit, _) = run(&m);
    assert!(end_implicit < 1e-3, "implicit: still moving at {end_implicit} after 3 s");
    assert!(peak_explicit > 1e3, "explicit springs should blow up at 3 ms (peak {peak_explicit})");
}

fn com_positions(m: &Model, ws: &Workspace) -> Vec<DVec3> {
    (0..m.bodies.len()).map(|i| ws.com_world(m, i)).collect()
}

/// Left alone, both boxers hold their guard for 60 s of simulated time: every segment stays
/// where it settled in the first second, and nothing moves at the end.
#[test]
fn boxers_hold_guard_for_60_s() {
    let m = boxing_scene().unwrap();
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..333 {
        step(&m, &mut s, &mut ws);
    }
    let settled = com_positions(&m, &ws);
    // The guard is the designed one: fists in front of the chin, above the shoulders.
    for art in 0..2 {
        for side in [Side::Left, Side::Right] {
            let hand = settled[m.find_part(art, Part::Hand, side).unwrap()];
            let head = settled[m.find_part(art, Part::Head, Side::Centre).unwrap()];
            assert!(
                (hand.y - head.y).abs() < 0.25 && (hand.x - head.x).abs() < 0.15,
                "fist {hand} head {head}"
            );
        }
    }
    let mut worst = 0.0f64;
    for _ in 0..20_000 {
        step(&m, &mut s, &mut ws);
        for (i, p) in com_positions(&m, &ws).iter().enumerate() {
            worst = worst.max((*p - settled[i]).length());
        }
    }
    assert!(worst < 0.005, "a segment drifted {worst} m from its guard position");
    assert!(s.v.iter().all(|v| v.abs() < 1e-4), "still moving after 60 s");
    assert!(ws.contacts.is_empty(), "the boxers touch each other in guard");
}

/// Drives one boxer's fist at the other's guard, the fist in front of it (at 0.95 m apart an arm
/// of 0.64 m reaches the guard, not the head, without leaning in): a pull at the fist plus
/// extension torques at the elbow and shoulder, which the stiff, heavily damped guard of the
/// lab's gains needs (measured: a 600 N pull alone leaves the fist 18 cm short of the guard).
fn punch(m: &Model, ws: &mut Workspace, attacker: usize, target: usize, side: Side) {
    let fist = m.find_part(attacker, Part::Hand, side).unwrap();
    // Facing each other, the attacker's right fist is in line with the target's left.
    let other = if side == Side::Right { Side::Left } else { Side::Right };
    let guard = m.find_part(target, Part::Hand, other).unwrap();
    let to = ws.com_world(m, guard) - ws.com_world(m, fist);
    let f = to.normalize() * (2000.0 * to.length()).min(600.0)
        - ws.point_velocity(fist, m.bodies[fist].com_m) * 8.0;
    let p = ws.com_world(m, fist);
    ws.add_force_at(fist, p, f);
    let elbow = m.find_part(attacker, Part::Forearm, side).unwrap();
    let shoulder = m.find_part(attacker, Part::UpperArm, side).unwrap();
    ws.tau[m.bodies[elbow].v_at] -= 150.0;
    ws.tau[m.bodies[shoulder].v_at] += 80.0;
}

/// A scripted punch lands on the other boxer's guard: the contact is recorded with the right
/// parts, the guard is knocked back, and both return to their guard afterwards.
#[test]
fn scripted_punch_lands_and_both_react_and_recover() {
    let m = boxing_scene().unwrap();
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..333 {
        step(&m, &mut s, &mut ws);
    }
    let guard = com_positions(&m, &ws);
    let (avatar, boxer) = (0, 1);
    let head = m.find_part(avatar, Part::Hand, Side::Left).unwrap();
    let fist = m.find_part(boxer, Part::Hand, Side::Right).unwrap();
    let mut landed = None;
    let mut head_moved = 0.0f64;
    let mut max_force = 0.0f64;
    for k in 0..200 {
        kinematics(&m, &s, &mut ws);
        // Keep pushing for 0.12 s after the fist lands, then let go.
        if landed.is_none_or(|l| k < l + 40) {
            punch(&m, &mut ws, boxer, avatar, Side::Right);
        }
        forward(&m, &s, &mut ws);
        for c in &ws.contacts {
            let bodies = [c.body_a.map(|b| b as usize), c.body_b.map(|b| b as usize)];
            if bodies.contains(&Some(head)) && bodies.contains(&Some(fist)) {
                landed.get_or_insert(k);
                max_force = max_force.max(c.force_n.length());
            }
        }
        integrate(&m, &mut s, &mut ws);
        head_moved = head_moved.max((ws.com_world(&m, head) - guard[head]).length());
    }
    let landed = landed.expect("the punch never reached the guard");
    assert!(landed < 100, "the punch took {landed} steps to land");
    assert!(max_force > 20.0, "the hit was too soft: {max_force} N");
    assert!(head_moved > 0.01, "the guard did not react ({head_moved} m)");
    // Released, both bodies come back to their guard.
    for _ in 0..1000 {
        step(&m, &mut s, &mut ws);
    }
    let back = com_positions(&m, &ws);
    for i in 0..m.bodies.len() {
        assert!(
            (back[i] - guard[i]).length() < 0.01,
            "{} did not recover: {}",
            m.bodies[i].name,
            back[i] - guard[i]
        );
    }
}

/// A scripted 10 s bout (punches both ways, alternating hands) is bit-for-bit repeatable, and
/// its digest is pinned: any change to the engine's arithmetic shows up here.
#[test]
fn scripted_bout_digest_is_pinned() {
    fn bout() -> (u64, usize) {
        let m = boxing_scene().unwrap();
        let mut s = State::new(&m);
        let mut ws = Workspace::new(&m);
        let mut contacts = 0;
        for k in 0..3334 {
            kinematics(&m, &s, &mut ws);
            // Every second someone throws a 0.4 s punch.
            let phase = k % 333;
            if phase < 133 {
                let round = k / 333;
                let (att, tgt) = if round % 2 == 0 { (1, 0) } else { (0, 1) };
                let side = if (round / 2) % 2 == 0 { Side::Right } else { Side::Left };
                punch(&m, &mut ws, att, tgt, side);
            }
            forward(&m, &s, &mut ws);
            contacts += ws.contacts.len();
            integrate(&m, &mut s, &mut ws);
        }
        (s.digest(), contacts)
    }
    let (a, contacts) = bout();
    assert_eq!(bout().0, a, "two identical bouts differ");
    assert!(contacts > 100, "the bout had too few contacts ({contacts})");
    // The boxing scene's virtual human stands 0.80 m in front since issue 15 (0.95 before, with
    // 0x251d_2784_5129_9e08; that distance still gives it, so the arithmetic is unchanged).
    assert_eq!(a, 0x5f68_ae77_4ce9_641a, "digest changed: {a:#018x}");
}

/// After the first step neither a world step nor a prediction (copy + 100 steps) allocates.
#[test]
fn step_and_prediction_do_not_allocate() {
    let m = boxing_scene().unwrap();
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    let mut pred = Predictor::new(&m);
    step(&m, &mut s, &mut ws);
    pred.run(&m, &s, 1, |_, _, _| true);
    let n = alloc_count::count(|| {
        for _ in 0..100 {
            kinematics(&m, &s, &mut ws);
            punch(&m, &mut ws, 1, 0, Side::Right);
            step(&m, &mut s, &mut ws);
        }
        pred.run(&m, &s, 100, |m, _, ws| {
            ws.add_force_at(0, DVec3::ZERO, DVec3::X);
            let _ = m;
            true
        });
    });
    assert_eq!(n, 0, "{n} allocations in 100 steps and a 100-step prediction");
    // The allocation counter works (guards against a test that cannot fail).
    assert!(alloc_count::count(|| drop(vec![1u8; 10])) > 0);
}

/// A prediction from a copied state is exactly the world's own future.
#[test]
fn prediction_equals_the_world_future() {
    let m = boxing_scene().unwrap();
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    let mut pred = Predictor::new(&m);
    for _ in 0..50 {
        step(&m, &mut s, &mut ws);
    }
    pred.run(&m, &s, 100, |m, st, ws| {
        kinematics(m, st, ws);
        punch(m, ws, 0, 1, Side::Left);
        true
    });
    for _ in 0..100 {
        kinematics(&m, &s, &mut ws);
        punch(&m, &mut ws, 0, 1, Side::Left);
        step(&m, &mut s, &mut ws);
    }
    assert_eq!(pred.state, s);
}

/// The shipped scene loads from its files on disk and matches the built-in copy; the energy of
/// the boxers at rest is what their pose says.
#[test]
fn shipped_scene_loads_from_disk() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/scene-boxing.ron");
    let m = spidar_sim::load_scene(&dir).unwrap();
    assert_eq!(m.nv, 52, "two 26-DOF bodies");
    assert_eq!(m.bodies.len(), 18, "two 9-solid bodies");
    assert_eq!(m.q_default, boxing_scene().unwrap().q_default);
    assert!(SCENE_BOXING_RON.contains("version: 1"));
    let mut ws = Workspace::new(&m);
    kinematics(&m, &State::new(&m), &mut ws);
    assert!(potential_energy(&m, &ws) > 0.0);
    let _ = DMat3::IDENTITY;
}

/// Impulses the rt-loop applied to a proxy reach the body the proxy names, in full.
#[test]
fn hand_impulses_reach_the_named_body() {
    use spidar_msg::{ContactModel, HandSample, Proxy, ProxyShape};
    use spidar_sim::impulse::{apply_hand_impulses, body_of, proxy_id};
    let body = free_body(
        "Box(mass_kg: 2.0, size_m: (0.2, 0.2, 0.2), centre_m: (0.0, 0.0, 0.0))",
        "(name: \"s\", shape: Sphere(radius_m: 0.1))",
    );
    let actors = format!("{}, {}", actor("a", 0.0, 1.0, -0.5), actor("b", 1.0, 1.0, -0.5));
    let m = scene(0.003, 0.0, NO_CONTACT, "", &actors, &body);
    let id = proxy_id(&m, 1);
    assert_eq!(body_of(&m, id), Some(1));
    let mut sent = ContactModel { seq: 4, ..Default::default() };
    sent.push(Proxy {
        id,
        shape: ProxyShape::Sphere { centre_m: DVec3::new(1.0, 1.0, -0.5), radius_m: 0.1 },
        k_n_per_m: 1000.0,
        d_n_s_per_m: 0.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: Proxy::BOTH_HANDS,
    });
    let mut sample = HandSample { model_seq: 4, ..Default::default() };
    sample.hands[0].valid = true;
    sample.hands[0].pos_world_m = DVec3::new(1.0, 1.0, -0.35);
    sample.proxy_impulse_n_s[0] = DVec3::new(0.0, 0.0, -0.02);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    // Three rt-loop ticks per sim step.
    for _ in 0..3 {
        apply_hand_impulses(&m, &mut ws, &sent, &sample);
    }
    step(&m, &mut s, &mut ws);
    kinematics(&m, &s, &mut ws);
    let p = linear_momentum(&m, &ws);
    assert!((p - DVec3::new(0.0, 0.0, -0.06)).length() < 1e-12, "momentum {p}");
    // Applied at the front of the sphere, on the line through its centre: no spin.
    assert!(ws.angular_velocity(1).length() < 1e-9);
    // A stale model's impulses are not applied.
    sample.model_seq = 3;
    assert_eq!(apply_hand_impulses(&m, &mut ws, &sent, &sample), DVec3::ZERO);
}

/// The single-rigid-body character of the keyframe paper comes from the same description
/// language: dropped a little above the floor, it lands on its narrow feet and stands, its
/// weight carried by the floor at the depth m g / k.
#[test]
fn single_body_character_stands_on_the_floor() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/body-character.ron"))
        .unwrap();
    let contact = "(stiffness: Abs(4e5), damping: Abs(4000.0), friction: 0.8, slip_m_per_s: 0.01)";
    let m = scene(0.003, -9.81, contact, FLOOR, &actor("c", 0.0, 0.01, 0.0), &text);
    assert_eq!((m.bodies.len(), m.nv, m.shapes.len()), (1, 6, 5));
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..1000 {
        step(&m, &mut s, &mut ws);
    }
    kinematics(&m, &s, &mut ws);
    let up = ws.x0[0].e.transpose() * DVec3::Y;
    assert!(up.y > 0.9999, "the character tipped: up = {up}");
    // Feet bottom is 0.75 m below the centre of mass.
    let depth = 0.75 - ws.x0[0].r.y;
    let expected = 40.0 * 9.81 / 4e5;
    assert!((depth - expected).abs() < 0.02 * expected, "depth {depth:.3e}, m g / k {expected:.3e}");
    assert!(ws.contacts.iter().all(|c| m.shapes[c.shape_b as usize].name.ends_with("feet")));
}

/// A joint pushed past its limit stops there: it settles where the limit's spring (300 N m/rad
/// in these scenes) balances the push, and the limit damper does not hold it when pushed back.
#[test]
fn joint_stops_at_its_limit() {
    let body = r#"(kind: "body", version: 1, name: "bar", source: "test", gain_dt_s: 0.003, links: [
        (name: "bar", parent: None, joint: (kind: Revolute(axis: (0.0, 0.0, 1.0)), anchor_m: (0.0, 1.0, 0.0),
            stiffness: Abs(0.0), damping: Abs(0.5), limits_deg: Some([(-20.0, 20.0)])),
         mass: Box(mass_kg: 1.0, size_m: (0.04, 0.4, 0.04), centre_m: (0.0, -0.2, 0.0)))])"#;
    let m = scene(0.003, 0.0, NO_CONTACT, "", &actor("b", 0.0, 0.0, 0.0), body);
    let mut s = State::new(&m);
    let mut ws = Workspace::new(&m);
    for _ in 0..3000 {
        ws.tau[0] = 10.0;
        step(&m, &mut s, &mut ws);
    }
    let expected = 20f64.to_radians() + 10.0 / 300.0;
    assert!((s.q[0] - expected).abs() < 1e-4, "angle {} vs {}", s.q[0], expected);
    // Pushed back, it leaves the limit and swings freely to the other one.
    for _ in 0..3000 {
        ws.tau[0] = -10.0;
        step(&m, &mut s, &mut ws);
    }
    assert!((s.q[0] + expected).abs() < 1e-4, "angle {} vs {}", s.q[0], -expected);
}
