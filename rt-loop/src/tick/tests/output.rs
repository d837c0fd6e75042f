//! Tests of the tick core's output phases (`tick/output.rs`): rendering, the safety counters,
//! the avatar contact's energy reserve, allocation and the impulses sent back to the world.
//! Each asserts what the rig does tick by tick; none may depend on timing.

use super::*;

/// After a run of held ticks the energy reserve books the hand's motion over them against the
/// held output (what the strings applied), not against the force commanded two ticks before
/// the run.
#[test]
fn motion_over_held_ticks_is_booked_against_the_held_output() {
    let mut c = core();
    home_and_activate(&mut c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let at_w = c.rig().rig_to_world.point(home[0]);
    let contact = |seq: u64, f: f64| {
        let mut m = ContactModel { seq, ..Default::default() };
        m.hand_contacts[0] = spidar_msg::HandContact {
            force_n: DVec3::Z * f,
            normal: DVec3::Z,
            k_n_per_m: 0.0,
            at_m: at_w,
            source_w: 0.0,
        };
        m
    };
    let mut out = Output::default();
    let still = counts_at(&c, home);
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(contact(1, 1.0)), &still, Ok(()));
    }
    let (_, before) = tick_io(&mut c, &mut out, Some(contact(1, 1.0)), &still, Ok(()));
    let (_, last) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &still, Ok(()));
    let (f_before, f_held) = (before.hands[0].output_n, last.hands[0].output_n);
    assert!(f_held.length() > 2.0 * f_before.length(), "{f_before} {f_held}");
    let reserve0 = last.hands[0].reserve_j;
    for _ in 0..3 {
        let (_, r) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &still, Err(TIMEOUT));
        assert!(r.hands[0].held);
    }
    // The hand went 1 mm into the held force over the held ticks.
    let d = -f_held.normalize() * 0.001;
    let moved = counts_at(&c, [home[0] + d, home[1]]);
    let (_, r) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &moved, Ok(()));
    assert!(!r.hands[0].held && r.hands[0].valid);
    let booked = r.hands[0].reserve_j - reserve0;
    let want = -f_held.dot(d);
    assert!((booked - want).abs() < 0.1 * want, "booked {booked} J, the held force did {want} J");
}

/// The energy the world's bodies put into an avatar-hand contact (its power times the time
/// since the last model) goes into that hand's reserve; a gap in the models counts for at
/// most 10 ms (a world that was gone does not credit its absence).
#[test]
fn the_worlds_energy_into_a_contact_is_credited_over_the_time_between_models() {
    let mut c = core();
    home_and_activate(&mut c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let at_w = c.rig().rig_to_world.point(home[0]);
    let contact = |seq: u64, source_w: f64| {
        let mut m = ContactModel { seq, ..Default::default() };
        m.hand_contacts[0] = spidar_msg::HandContact {
            force_n: DVec3::Z,
            normal: DVec3::Z,
            k_n_per_m: 0.0,
            at_m: at_w,
            source_w,
        };
        m
    };
    let mut out = Output::default();
    let still = counts_at(&c, home);
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(contact(1, 0.0)), &still, Ok(()));
    }
    let reserve = |r: &TickRecord| r.hands[0].reserve_j;
    let (_, r0) = tick_io(&mut c, &mut out, Some(contact(1, 0.0)), &still, Ok(()));
    // A model every tick (1 ms apart) at 2 W: 2 mJ each.
    let (_, r1) = tick_io(&mut c, &mut out, Some(contact(2, 2.0)), &still, Ok(()));
    assert!((reserve(&r1) - reserve(&r0) - 0.002).abs() < 1e-9, "{} -> {}", reserve(&r0), reserve(&r1));
    // Two ticks without a model, then one: 3 ms at 2 W.
    tick_io(&mut c, &mut out, None, &still, Ok(()));
    tick_io(&mut c, &mut out, None, &still, Ok(()));
    let (_, r2) = tick_io(&mut c, &mut out, Some(contact(3, 2.0)), &still, Ok(()));
    assert!((reserve(&r2) - reserve(&r1) - 0.006).abs() < 1e-9, "{} -> {}", reserve(&r1), reserve(&r2));
    // 20 ticks without a model (late, not yet stale: still engaged), then one: 21 ms, of
    // which 10 count.
    for _ in 0..20 {
        tick_io(&mut c, &mut out, None, &still, Ok(()));
    }
    let (_, r3) = tick_io(&mut c, &mut out, Some(contact(4, 2.0)), &still, Ok(()));
    assert!((reserve(&r3) - reserve(&r2) - 0.02).abs() < 1e-9, "{} -> {}", reserve(&r2), reserve(&r3));
}

/// An avatar-hand contact's force is rendered as the world gives it (its direction, not only
/// its size); a hand that moves with it while the reserve is empty has it scaled down, and
/// every such tick is counted.
#[test]
fn an_avatar_hand_contact_is_rendered_as_given_and_each_passivity_limited_tick_counted() {
    let mut c = core();
    home_and_activate(&mut c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let f = DVec3::new(0.0, 0.5, 1.5);
    let xf = c.rig().rig_to_world;
    let contact = |p_rig: DVec3| {
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.hand_contacts[0] = spidar_msg::HandContact {
            force_n: f,
            normal: f.normalize(),
            k_n_per_m: 0.0,
            at_m: xf.point(p_rig),
            source_w: 0.0,
        };
        m
    };
    let mut out = Output::default();
    let still = counts_at(&c, home);
    let mut r = TickRecord::default();
    for _ in 0..600 {
        r = tick_io(&mut c, &mut out, Some(contact(home[0])), &still, Ok(())).1;
    }
    // World and rig axes agree here.
    assert!((r.hands[0].commanded_n - f).length() < 1e-9, "{:?}", r.hands[0]);
    assert!(!r.hands[0].passivity_limited);
    let before = c.counters().passivity_limited;
    // The hand goes along the force at 0.5 m/s: the force would give it energy it never put in.
    let mut limited = 0;
    for i in 1..=40 {
        let p = home[0] + f.normalize() * (0.0005 * i as f64);
        let counts = counts_at(&c, [p, home[1]]);
        let (_, r) = tick_io(&mut c, &mut out, Some(contact(p)), &counts, Ok(()));
        if r.hands[0].passivity_limited {
            limited += 1;
            assert!(r.hands[0].commanded_n.length() < f.length());
            assert!(r.hands[0].commanded_n.dot(f) >= 0.0, "scaled along its own direction");
        }
    }
    assert!(limited > 20, "{limited}");
    assert_eq!(c.counters().passivity_limited, [before[0] + limited, before[1]]);
}

/// A proxy touched with no force (zero stiffness and damping: a trigger volume) is a contact
/// that renders nothing: the impulses sent back are zero, never NaN (0 / 0 in the applied share).
#[test]
fn a_contact_with_no_force_sends_zero_impulses_not_nan() {
    use spidar_msg::{Proxy, ProxyId, ProxyShape};
    let mut c = core();
    home_and_activate(&mut c);
    let home = c.rig().rig_to_world.point(c.rig().hands[0].home_m);
    let mut m = ContactModel { seq: 1, ..Default::default() };
    m.push(Proxy {
        id: ProxyId { body: 3, part: 0 },
        shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
        k_n_per_m: 0.0,
        d_n_s_per_m: 0.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 0b01,
    });
    for _ in 0..600 {
        tick_with(&mut c, Some(m));
    }
    let (s, rec) = tick_with(&mut c, Some(m));
    assert_eq!(rec.hands[0].contacts, 1, "touching: {:?}", rec.hands[0]);
    assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO);
    assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
}

#[test]
fn contact_impulse_is_the_rendered_force_with_the_gain_but_without_the_clamp() {
    use spidar_msg::{Proxy, ProxyId, ProxyShape};
    let mut c = core();
    home_and_activate(&mut c);
    // Hand 0 sits at home (counts stay zero); a wall 1 cm in front of its centre, 3 cm deep
    // into the 4 cm fist: 2000 N/m x 0.03 m = 60 N, far above the 4 N clamp.
    let xf = c.rig().rig_to_world;
    let home = xf.point(c.rig().hands[0].home_m);
    let mut m = ContactModel { seq: 1, ..Default::default() };
    m.push(Proxy {
        id: ProxyId { body: 3, part: 0 },
        shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
        k_n_per_m: 2000.0,
        d_n_s_per_m: 0.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 0b01,
    });
    let dt = c.rig().period_s;
    let limit = c.rig().hands[0].force_limit_n;
    // While ramping in (gain about 0.2, still 12 N), then at full gain.
    run(&mut c, 100, Ok(()));
    for _ in 0..2 {
        let (s, rec) = tick_with(&mut c, Some(m));
        assert!(rec.gain > 0.0 && rec.hands[0].clamped, "{rec:?}");
        let contact = s.proxy_contact_impulse_n_s[0];
        let want = -DVec3::Z * 60.0 * rec.gain * dt;
        assert!((contact - want).length() < 1e-12, "{contact} vs {want}");
        let applied = s.proxy_impulse_n_s[0].length() / dt;
        assert!(applied <= limit + 1e-9 && applied > 0.9 * limit, "{applied} N applied");
        assert!(s.proxy_contact_impulse_n_s[1..].iter().all(|i| *i == DVec3::ZERO));
        // Keep the model fresh to full gain (a model that faded out would ramp back in).
        for _ in 0..600 {
            tick_with(&mut c, Some(m));
        }
    }
    // The model goes stale and fades: the contact fades with it, to exactly zero.
    let fade = c.rig().safety.contact_stale_after_s + c.rig().safety.contact_fade_s;
    let mut last = f64::INFINITY;
    for _ in 0..(fade / dt).round() as usize + 1 {
        let (s, rec) = tick_with(&mut c, None);
        let contact = s.proxy_contact_impulse_n_s[0].length() / dt;
        assert!((contact - 60.0 * rec.gain).abs() < 1e-9 && contact <= last, "{contact} N");
        last = contact;
    }
    let (s, _) = tick_with(&mut c, None);
    assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
    assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO);
}

#[test]
fn the_scenes_extra_force_is_rendered_as_given_and_every_safety_counter_counts_its_ticks() {
    use spidar_msg::{Proxy, ProxyId, ProxyShape};
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let zero = [0i64; MAX_CHANNELS];
    let extra = |f: DVec3| {
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.extra_force_n = [f, DVec3::ZERO];
        m
    };
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(extra(DVec3::ZERO)), &zero, Ok(()));
    }
    let base = *c.counters();
    // The scene's extra force, as given (world and rig axes agree here).
    let (_, r) = tick_io(&mut c, &mut out, Some(extra(DVec3::new(0.0, 1.0, -2.0))), &zero, Ok(()));
    assert!((r.hands[0].commanded_n - DVec3::new(0.0, 1.0, -2.0)).length() < 1e-12, "{r:?}");
    assert!((r.hands[0].output_n - DVec3::new(0.0, 1.0, -2.0)).length() < 1e-9);
    // 7 ticks above the 4 N limit: clamped 7 times, on hand 0 only.
    for _ in 0..7 {
        tick_io(&mut c, &mut out, Some(extra(DVec3::X * 10.0)), &zero, Ok(()));
    }
    // 3 ticks of a NaN force: replaced by zero, counted.
    for _ in 0..3 {
        let (_, r) = tick_io(&mut c, &mut out, Some(extra(DVec3::NAN)), &zero, Ok(()));
        assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
    }
    // 5 ticks against a proxy stiffer than the limit, 1 mm deep.
    let home = c.rig().rig_to_world.point(c.rig().hands[1].home_m);
    let mut stiff = ContactModel { seq: 2, ..Default::default() };
    stiff.push(Proxy {
        id: ProxyId { body: 1, part: 0 },
        shape: ProxyShape::Plane { point_m: home - DVec3::Y * 0.039, normal: DVec3::Y },
        k_n_per_m: 1e6,
        d_n_s_per_m: 0.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 0b10,
    });
    for _ in 0..5 {
        let (_, r) = tick_io(&mut c, &mut out, Some(stiff), &zero, Ok(()));
        assert!((r.hands[1].commanded_n.y - 4.0).abs() < 1e-9, "5000 N/m x 1 mm = 5 N, clamped to 4");
    }
    // 100 ticks with no new model: the ticks past contact_stale_after_s are stale.
    let (mut stale, mut clamped_fading) = (0, 0);
    for _ in 0..100 {
        let (_, r) = tick_io(&mut c, &mut out, None, &zero, Ok(()));
        stale += (r.contact_age_s > c.rig().safety.contact_stale_after_s) as u64;
        clamped_fading += r.hands[1].clamped as u64;
    }
    assert!((60..=71).contains(&stale), "{stale}");
    // The stiff contact goes on (fading) while the model ages: clamped while above 4 N.
    assert!((30..60).contains(&clamped_fading), "{clamped_fading}");
    let k = c.counters();
    assert_eq!(k.clamped, [base.clamped[0] + 7, base.clamped[1] + 5 + clamped_fading]);
    assert_eq!(k.non_finite, base.non_finite + 3);
    assert_eq!(k.stiffness_limited, [base.stiffness_limited[0], base.stiffness_limited[1] + 5 + 100]);
    assert_eq!(k.stale, base.stale + stale);
    assert_eq!(k.active_ticks, base.active_ticks + 1 + 7 + 3 + 5 + 100);
    assert_eq!(k.infeasible, base.infeasible);
    assert_eq!(k.fallback, base.fallback);
    assert_eq!(k.models, base.models + 1 + 7 + 3 + 5);
}

#[test]
fn a_grip_outside_its_frame_is_counted_as_fallback_every_tick() {
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    // Hand 1 walks 1 mm per tick down to 1.5 m below the rig origin, out of its tetrahedron
    // (zero net force is then infeasible: the box-QP fallback chooses the tensions).
    let mut fallback = 0;
    let mut infeasible = 0;
    for k in 0..1500 {
        let p = [home[0], home[1] - DVec3::Y * (k as f64 * 1e-3)];
        let counts = counts_at(&c, p);
        let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
        assert!(!r.hands[1].held, "walking is not a jump");
        fallback += (r.hands[1].method == Method::Fallback) as u64;
        infeasible += (r.hands[1].method == Method::Scaled) as u64;
    }
    assert!(fallback > 100, "{fallback}");
    assert_eq!(c.counters().fallback, [0, fallback]);
    assert_eq!(c.counters().infeasible, [0, infeasible]);
}

#[test]
fn nothing_is_rendered_while_inactive_and_a_contact_pushing_nothing_gives_back_nothing() {
    let mut c = core();
    c.command(Command::Home);
    let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
    run(&mut c, settle + 1, Ok(()));
    let m = pressing_wall(&c);
    assert_eq!(c.contact_model(), None);
    let mut out = Output::default();
    let zero = [0i64; MAX_CHANNELS];
    let (s, r) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
    assert_eq!(c.contact_model().map(|m| m.seq), Some(1), "the newest model is kept");
    assert_eq!((r.hands[0].rendered_n, r.hands[0].contacts), (DVec3::ZERO, 0), "inactive: no rendering");
    assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
    // Active, the fist 1 cm inside a heavily damped plane but leaving it at 1 m/s: the damper
    // cancels the spring (a penalty contact never pulls), so the force and impulses are zero,
    // not NaN.
    use spidar_msg::{Proxy, ProxyId, ProxyShape};
    c.command(Command::Activate);
    let home = c.rig().hands[0].home_m;
    let world = c.rig().rig_to_world.point(home);
    let mut damped = ContactModel { seq: 2, ..Default::default() };
    damped.push(Proxy {
        id: ProxyId { body: 3, part: 0 },
        shape: ProxyShape::Plane { point_m: world - DVec3::Z * 0.03, normal: DVec3::Z },
        k_n_per_m: 2000.0,
        d_n_s_per_m: 5000.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 0b01,
    });
    for k in 0..9 {
        let p = [home + DVec3::Z * (k as f64 * 1e-3), c.rig().hands[1].home_m];
        let counts = counts_at(&c, p);
        let (s, r) = tick_io(&mut c, &mut out, Some(damped), &counts, Ok(()));
        if k > 4 {
            assert_eq!(r.hands[0].contacts, 1, "tick {k}");
            assert_eq!(r.hands[0].rendered_n, DVec3::ZERO, "tick {k}");
            assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO, "tick {k}: {:?}", s.proxy_impulse_n_s[0]);
            assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
        }
    }
}

#[test]
fn a_force_beyond_what_the_strings_can_render_there_is_counted_as_infeasible() {
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    // Hand 0 walks 0.3 m to its outer side (-x), where the strings give about 2 N outward.
    let mut m = ContactModel { seq: 1, ..Default::default() };
    m.extra_force_n = [DVec3::X * -4.0, DVec3::ZERO];
    let mut scaled = 0;
    for k in 0..=300 {
        let p = [home[0] - DVec3::X * (k as f64 * 1e-3), home[1]];
        let counts = counts_at(&c, p);
        let (_, r) = tick_io(&mut c, &mut out, Some(m), &counts, Ok(()));
        scaled += (r.hands[0].method == Method::Scaled) as u64;
        if k == 300 {
            assert_eq!(r.hands[0].method, Method::Scaled);
            assert!(r.hands[0].output_n.length() < 3.9 && r.hands[0].scale < 1.0, "{:?}", r.hands[0]);
        }
    }
    assert!(scaled > 10);
    assert_eq!(c.counters().infeasible, [scaled, 0]);
}

#[test]
fn a_grip_outside_its_frame_never_produces_more_than_the_force_limit() {
    // The audit's case: fallback ticks (not even zero force feasible) while the scene asks for
    // the full 4 N; the box QP's closest force was up to 4.07 N before the produced-force limit.
    let mut c = core();
    home_and_activate(&mut c);
    let mut out = Output::default();
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let limit = c.rig().hands[1].force_limit_n;
    let (mut fallback, mut limited, mut worst) = (0, 0, 0.0_f64);
    // Hand 1 walks 1 mm per tick down to 1.5 m below its home, asked 6 N (clamped to 4 N) in a
    // direction that turns on a sphere (golden-angle spiral), so every side is asked for.
    for k in 0..1500 {
        let z = 1.0 - 2.0 * ((k % 300) as f64 + 0.5) / 300.0;
        let phi = k as f64 * 2.399_963;
        let r = (1.0 - z * z).sqrt();
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.extra_force_n = [DVec3::ZERO, DVec3::new(r * phi.cos(), z, r * phi.sin()) * 6.0];
        let p = [home[0], home[1] - DVec3::Y * (k as f64 * 1e-3)];
        let before = c.counters().produced_limited[1];
        let counts = counts_at(&c, p);
        let (_, rec) = tick_io(&mut c, &mut out, Some(m), &counts, Ok(()));
        let h = &rec.hands[1];
        assert!(!h.held);
        fallback += (h.method == Method::Fallback) as u64;
        let f = h.output_n.length();
        worst = worst.max(f);
        assert!(f <= limit + 1e-9, "tick {k}: produced {f} N above the {limit} N limit: {h:?}");
        assert!(h.tensions_n.iter().all(|&t| (1.0..=20.0).contains(&t)), "{h:?}");
        if c.counters().produced_limited[1] > before {
            limited += 1;
            assert_eq!(h.method, Method::Fallback, "only the fallback can produce more than it was asked");
            assert!((f - limit).abs() < 1e-9, "scaled onto the limit: {f}");
        }
    }
    assert!(fallback > 300, "{fallback}");
    assert!(limited > 20, "the case must exercise the limit: {limited} of {fallback} fallback ticks");
    assert_eq!(c.counters().produced_limited, [0, limited]);
    assert_eq!(c.counters().produced_unmet, [0, 0]);
    assert!(worst > 3.9, "{worst}");
}
