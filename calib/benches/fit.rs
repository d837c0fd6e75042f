//! Time of one hand's geometry fit from 100 poses (home, 8 jig points, 91 free poses) recorded on
//! the simulated rig with a wrong-on-purpose truth, with 0.5 and with 3 counts of encoder noise
//! (the data-quality check included). Budget (DESIGN.md section 8): < 1 s.
//! `cargo bench -p spidar-calib --bench fit`

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use spidar_calib::fit::{fit_hand, observations, FitOptions, Observation};
use spidar_calib::jig::JigFile;
use spidar_calib::record::{Plan, RecordOptions, Recorder, SimOperator};
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_rt::Rig;

fn session(rig: &Rig, noise_counts: f64) -> Vec<Observation> {
    let opts = SimTruthOptions { noise_counts, ..SimTruthOptions::default() };
    let truth = truth_geometry(rig, &opts);
    let jig = JigFile::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/jig-spidar-h.ron"
    )))
    .unwrap();
    let mut rec = Recorder::on_virtual_loop(
        sim_rig(rig, &truth, opts.noise_counts, opts.seed).unwrap(),
        rig,
        RecordOptions::default(),
        false,
    )
    .unwrap();
    let plan =
        Plan { hands: vec![0], jig: Some(jig), free_per_hand: 91, free_half_extent_m: DVec3::splat(0.3) };
    let session = rec.record_session(&mut SimOperator::new(false), &plan, "sim").unwrap();
    let obs = observations(&session, 0);
    assert_eq!(obs.len(), 100);
    // What the benchmark times is a fit that succeeds on clean data.
    let fit = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap();
    assert!(fit.is_trustworthy(), "{fit}");
    obs
}

fn bench_fit(c: &mut Criterion) {
    let rig = Rig::default_rig();
    let mut g = c.benchmark_group("calib");
    g.sample_size(20);
    for (name, noise) in [("fit_hand_100_poses", 0.5), ("fit_hand_100_poses_3_counts_noise", 3.0)] {
        let obs = session(&rig, noise);
        g.bench_function(name, |b| {
            b.iter(|| fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench_fit);
criterion_main!(benches);
