//! The virtual human's landed blows as the user's hands feel them, on the path `spidar run`
//! takes (the scripted user boxing through the simulated rig, the rt-loop and the boxing world;
//! `spidar eval blows` measures the same): every blow the world reports is felt on both hands
//! along the blow, its burst at least half its planned amplitude (or the rig's limit), its
//! energy within the bound, the rig's force limit never exceeded.

use spidar_lab::eval_blows::eval_blows;
use spidar_rt::blow::BlowParams;

#[test]
fn the_virtual_humans_landed_blows_are_felt_at_the_users_hands() {
    let r = eval_blows(20.0, 3, |_| {}).unwrap();
    eprintln!("{r}");
    let n = r.blows.len() as u64;
    assert!(n >= 3, "the active virtual human landed only {n} blows in 20 s");
    // Every blow reached both hands (counted by the loop the tick its force first got there).
    assert_eq!(r.blows_felt, [n, n], "blows felt by the loop, of {n} landed");
    let p = BlowParams::default();
    for b in &r.blows {
        let want = p.burst_amplitude_n(b.speed_m_per_s).min(r.force_limit_n);
        assert!(
            b.blow_peak_n >= 0.5 * want && b.blow_peak_n > 0.1,
            "blow {} at {:.1} m/s felt at most {:.2} N at the hands (its burst alone: {want:.2} N)",
            b.seq,
            b.speed_m_per_s,
            b.blow_peak_n
        );
        assert!(b.blow_impulse_n_s > 0.0, "blow {}: impulse along it {} N s", b.seq, b.blow_impulse_n_s);
        // Both hands, one tick's misjudgement of the hand's motion each.
        assert!(b.burst_energy_j <= 2.0 * p.burst_budget_j + 0.002, "blow {}: {} J", b.seq, b.burst_energy_j);
    }
    assert!(
        r.max_force_n <= r.force_limit_n + 1e-9,
        "{} N above the rig's {} N",
        r.max_force_n,
        r.force_limit_n
    );
}
