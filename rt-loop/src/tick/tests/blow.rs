//! Tests of a landed blow through the whole tick (`blow.rs` in the output phases): felt on both
//! hands along the blow, its burst decaying and ending, the same blow never started twice,
//! the safety clamp holding over push plus burst, a stale model fading it to zero, counted.

use super::*;
use crate::blow::BlowParams;
use spidar_msg::Blow;

/// A model carrying blow `seq` along +z (world), hard: 6 m/s, 10 N s.
fn with_blow(seq: u64, in_contact: bool) -> ContactModel {
    let blow =
        Blow { seq, dir: DVec3::Z, speed_m_per_s: 6.0, momentum_n_s: 10.0, in_contact, ..Default::default() };
    ContactModel { seq: 1, blow, ..Default::default() }
}

#[test]
fn a_landed_blow_is_felt_on_both_hands_along_it_within_the_clamp_once_and_counted() {
    let mut c = core();
    home_and_activate(&mut c);
    let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
    let still = counts_at(&c, home);
    let mut out = Output::default();
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(with_blow(0, false)), &still, Ok(()));
    }
    assert_eq!(c.counters().blows_felt, [0, 0]);
    let dir = c.rig().rig_to_world.vector_to_rig(DVec3::Z);
    let limit = c.rig().hands[0].force_limit_n;
    let p = BlowParams::default();
    // The hand held still: each tick feels the push plus the burst along the blow, up to the
    // rig's limit; the same blow arriving again changes nothing.
    let (f0, a) = (p.push_n(10.0), p.burst_amplitude_n(6.0));
    let (mut clamped, mut swung_back) = (0, false);
    for i in 0..200 {
        let (_, r) = tick_io(&mut c, &mut out, Some(with_blow(1, i < 5)), &still, Ok(()));
        let t = i as f64 * 0.001;
        let want = p.push_at(f0, t) + p.burst_at(a, t);
        for h in 0..2 {
            let f = r.hands[h].output_n;
            assert!(f.length() <= limit + 1e-9, "tick {i}: {f} N over the rig's {limit} N");
            assert!((f - dir * f.dot(dir)).length() < 1e-9, "along the blow: {f}");
            assert!((r.hands[h].blow_n - f).length() < 1e-9, "the record's blow share is all of it");
            if want.abs() <= limit {
                assert!((f.dot(dir) - want).abs() < 1e-6, "tick {i} hand {h}: {f} N, want {want} N");
            } else {
                assert!((f.length() - limit).abs() < 1e-9 && f.dot(dir) * want > 0.0, "{f}");
                clamped += 1;
            }
        }
        swung_back |= p.burst_at(a, t) < -0.5;
    }
    assert!(
        clamped > 0 && swung_back,
        "the hardest blow reaches the clamp ({clamped} ticks), its burst swings back"
    );
    let k = *c.counters();
    assert_eq!(k.blows_felt, [1, 1]);
    assert_eq!(k.clamped[0] + k.clamped[1], clamped);
    // A new blow is felt again (its burst starts at zero: felt from its second tick).
    for _ in 0..3 {
        tick_io(&mut c, &mut out, Some(with_blow(2, false)), &still, Ok(()));
    }
    assert_eq!(c.counters().blows_felt, [2, 2]);
}

#[test]
fn a_stale_model_fades_a_blow_to_zero_and_an_inactive_rig_feels_none() {
    let mut c = core();
    home_and_activate(&mut c);
    let still = counts_at(&c, [c.rig().hands[0].home_m, c.rig().hands[1].home_m]);
    let mut out = Output::default();
    for _ in 0..600 {
        tick_io(&mut c, &mut out, Some(with_blow(0, false)), &still, Ok(()));
    }
    // The blow arrives with its fist on, then the world goes silent.
    let (_, r) = tick_io(&mut c, &mut out, Some(with_blow(1, true)), &still, Ok(()));
    assert!(r.hands[0].output_n.length() > 2.0, "{:?}", r.hands[0]);
    let s = c.rig().safety.clone();
    let fade_ticks = ((s.contact_stale_after_s + s.contact_fade_s) / c.rig().period_s).round() as usize;
    let p = BlowParams::default();
    let most = p.push_max_n + p.burst_max_n;
    let mut faded = 0;
    for _ in 0..fade_ticks + 2 {
        let (_, r) = tick_io(&mut c, &mut out, None, &still, Ok(()));
        let f = r.hands[0].output_n.length();
        assert!(f <= r.gain * most + 1e-9, "fading: {f} N at gain {}", r.gain);
        faded += u32::from(r.gain < 1.0);
    }
    assert!(faded > 10);
    let (_, r) = tick_io(&mut c, &mut out, None, &still, Ok(()));
    assert!(
        r.hands[0].output_n.length() < 1e-9,
        "a stale model's blow fades to nothing: {}",
        r.hands[0].output_n
    );
    assert!(r.hands[1].output_n.length() < 1e-9);
    // Inactive: a new blow is not felt and not counted.
    let felt = c.counters().blows_felt;
    c.command(Command::Deactivate);
    run(&mut c, 1000, Ok(()));
    let (_, r) = tick_io(&mut c, &mut out, Some(with_blow(2, true)), &still, Ok(()));
    assert!(r.hands[0].output_n.length() < 1e-9);
    assert_eq!(c.counters().blows_felt, felt);
}
