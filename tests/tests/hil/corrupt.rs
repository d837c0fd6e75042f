//! Corrupt counts (item 4 of issue 17): UART replies carry no checksum, so a garbled reply can
//! change a count by up to 4096 (12 cm of string) without the driver noticing. The loop must
//! reject such a reply on the tick it arrives, from the redundancy it has: the count step against
//! the hand's own motion, and the four strings' residual.

use super::*;

/// The simulated rig with a fraction of its replies garbled the way a UART board's reply without
/// checksum is garbled: one count of the reply changed by 1 .. 4096 either way, silently (the
/// exchange reports success). Deterministic for its seed.
type Garbling = spidar_testkit::Garbling<SimRig>;

/// Random sparring against the rig-check scene; `rate` of the replies garbled.
fn sparring_garbled(seed: u64, rate: f64) -> VirtualRun<Garbling> {
    let r = rig();
    let scripts = load_scripts("spar", &r, seed).unwrap();
    let sim = sim_device(&r, scripts, &SimOptions { seed, encoder_noise_counts: 0.7, ..Default::default() })
        .unwrap();
    let dev = Garbling::new(sim, rate, 1, seed ^ 0x9e37_79b9_7f4a_7c15);
    let mut v = VirtualRun::new(dev, &r, Some(Box::new(WallsScene::builtin()))).unwrap();
    v.home_and_activate();
    v
}

/// What garbling changed over a run, against a shadow tick core fed the same plant's replies
/// ungarbled (see `measure`).
#[derive(Debug, Default)]
struct Damage {
    /// Largest distance of a pose the loop used (not held) to the shadow's.
    pose_err_m: f64,
    /// Largest commanded force difference on a tick the loop used its own pose, and on a held one.
    force_err_used_n: f64,
    force_err_held_n: f64,
    /// Largest tick-to-tick change of the shadow's commanded force (what one held tick can miss).
    shadow_step_n: f64,
    /// Ticks whose force differs from the shadow's by more than 0.5 N.
    over_half_newton: u64,
    /// Garbled replies, those the loop used (its hand not held), and the largest count error used.
    garbled: u64,
    used_garbled: u64,
    used_max_counts: i64,
    counters: Counters,
}

/// Runs `ticks` of sparring with `rate` of the replies garbled, beside a shadow tick core that
/// gets the same plant's replies ungarbled, the same contact models and the same times: what the
/// garbling changed is exactly the difference of the two.
fn measure(seed: u64, rate: f64, ticks: usize) -> Damage {
    let r = rig();
    let mut v = sparring_garbled(seed, rate);
    let mut shadow = TickCore::new(&r).unwrap();
    shadow.observe_counts(&v.rt.device().clean);
    shadow.command(Command::Home);
    shadow.command(Command::Activate);
    let (mut out, mut sample, mut rec) = Default::default();
    let mut d = Damage::default();
    let mut prev = [DVec3::ZERO; 2];
    let mut seq = u64::MAX;
    for _ in 0..ticks {
        let rb = v.tick();
        if let Some(m) = v.rt.core().contact_model() {
            if m.seq != seq {
                seq = m.seq;
                shadow.set_contact_model(*m);
            }
        }
        let clean = v.rt.device().clean;
        shadow.step(rb.t_s, Ok(()), &clean, &mut out, &mut sample, &mut rec);
        let rc: &TickRecord = &rec;
        if let Some((ch, by)) = v.rt.device().last {
            d.garbled += 1;
            if rb.hands[ch / 4].valid && !rb.hands[ch / 4].held {
                d.used_garbled += 1;
                d.used_max_counts = d.used_max_counts.max(by.abs());
            }
        }
        for (h, prev) in prev.iter_mut().enumerate() {
            let err = (rb.hands[h].commanded_n - rc.hands[h].commanded_n).length();
            if rb.hands[h].held {
                d.force_err_held_n = d.force_err_held_n.max(err);
            } else {
                d.force_err_used_n = d.force_err_used_n.max(err);
                if rb.hands[h].valid {
                    d.pose_err_m = d.pose_err_m.max(rb.hands[h].pos_rig_m.distance(rc.hands[h].pos_rig_m));
                }
            }
            d.over_half_newton += (err > 0.5) as u64;
            d.shadow_step_n = d.shadow_step_n.max((rc.hands[h].commanded_n - *prev).length());
            *prev = rc.hands[h].commanded_n;
        }
    }
    d.counters = *v.counters();
    d
}

use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Counters, TickCore};

#[test]
fn with_5_percent_of_replies_garbled_no_wrong_count_drives_the_force() {
    let r = rig();
    let d = measure(11, 0.05, 200_000);
    eprintln!("{d:?}");
    let c = &d.counters;
    let mpc = r.hands[0].metres_per_count[0];
    let tau = r.safety.reply_jump_m;
    assert_eq!(c.faults, 0, "isolated garbled replies are not faults");
    assert!(d.garbled > 9_000, "{} garbled", d.garbled);
    assert!(c.count_jumps[0] + c.count_jumps[1] >= d.garbled - d.used_garbled, "every rejection counted");
    assert_eq!(c.held, c.count_jumps, "each rejected reply held its hand's output for that tick");
    // A garbled reply is used only when its error is within the jump tolerance of the hand's
    // predicted motion (a few percent of them, all small): never the centimetres of a bad count.
    // The tolerance is tau plus one tick of the string's own motion (at most 3 mm at the 3 m/s
    // of a sparring punch), and the prediction itself may miss by up to about tau when the fist
    // stops on a stiff wall: a used error stays below 2 tau + 3 mm.
    let bound = 2.0 * tau + 3e-3;
    assert!(d.used_garbled < d.garbled / 20, "{} of {} used", d.used_garbled, d.garbled);
    assert!((d.used_max_counts as f64) * mpc <= bound, "a {} count error was used", d.used_max_counts);
    assert!(d.pose_err_m <= bound, "pose error {} m", d.pose_err_m);
    // The bound on the force: a used reply moves the force by at most what its pose error makes
    // of the stiffest contact (here far less: 0.5 N); a held tick misses at most one tick of the
    // uncorrupted force's own change.
    assert!(d.force_err_used_n < 0.5, "{} N on a used tick", d.force_err_used_n);
    assert!(d.force_err_held_n <= d.shadow_step_n + 1e-9);
    assert!(d.over_half_newton < 40, "{} hand-ticks off by more than 0.5 N", d.over_half_newton);
}

#[test]
fn garbled_replies_a_fault_during_homing_and_the_rehoming_allocate_nothing() {
    let r = rig();
    let mut v = sparring_garbled(5, 0.05);
    v.run_ticks(1000);
    let (before, _) = super::forbidden_allocs();
    let home = [r.hands[0].home_m, r.hands[1].home_m];
    for i in 0..8_000u32 {
        match i {
            0 => v.rt.command(Command::Deactivate),
            1 => (0..2).for_each(|h| v.rt.device_mut().inner.set_script(h, reach_and_hold(home[h]))),
            1_500 => {
                v.rt.command(Command::Home);
                v.rt.command(Command::Activate);
            }
            // A run of timeouts while homing: the homing is lost and redone once the grips rest.
            1_520 => {
                v.rt.device_mut()
                    .inner
                    .fail_next(r.safety.reply_fault_ticks, DeviceError::Timeout { waited_us: 1 })
            }
            _ => {}
        }
        super::no_alloc(|| v.tick());
    }
    let (after, first) = super::forbidden_allocs();
    assert_eq!(after - before, 0, "the tick allocated (first: {first} bytes)");
    let c = v.counters();
    assert!(c.rehomes == 1 && c.count_jumps.iter().sum::<u64>() > 100 && c.faults == 1, "{c:?}");
    assert_eq!(v.rt.state(), Lifecycle::Active);
}
