use glam::DVec3;
use spidar_calib::fit::{fit_hand, observations, FitOptions};
use spidar_calib::jig::JigFile;
use spidar_calib::record::{Plan, RecordOptions, Recorder, SimOperator};
use spidar_calib::session::SessionFile;
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_rt::Rig;

fn jig() -> JigFile {
    JigFile::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/jig-spidar-h.ron")))
        .unwrap()
}
fn record(
    jig: Option<JigFile>,
    free: usize,
    opts: &SimTruthOptions,
) -> (SessionFile, [spidar_calib::HandGeometry; 2]) {
    let rig = Rig::default_rig();
    let truth = truth_geometry(&rig, opts);
    let dev = sim_rig(&rig, &truth, opts.noise_counts, opts.seed).unwrap();
    let range: f64 = std::env::var("RANGE").ok().and_then(|v| v.parse().ok()).unwrap_or(0.5e-3);
    let mut rec =
        Recorder::new(dev, &rig, RecordOptions { still_range_m: range, ..RecordOptions::default() }).unwrap();
    let mut op = SimOperator::new(false);
    let plan = Plan { hands: vec![0], jig, free_per_hand: free, free_half_extent_m: DVec3::splat(0.3) };
    (rec.record_session(&mut op, &plan, "sim").unwrap(), truth)
}

fn show(name: &str, obs: &[spidar_calib::fit::Observation], truth: &[spidar_calib::HandGeometry; 2]) {
    let rig = Rig::default_rig();
    let t = std::time::Instant::now();
    match fit_hand(0, &rig.hands[0], obs, &FitOptions::default()) {
        Ok(f) => {
            let err: Vec<String> = (0..4)
                .map(|i| format!("{:.3}", f.geometry.anchors_m[i].distance(truth[0].anchors_m[i]) * 1e3))
                .collect();
            println!(
                "== {name}: {:?} rms {:.4} mm, anchor err mm {:?} trust {}",
                t.elapsed(),
                f.rms_m * 1e3,
                err,
                f.is_trustworthy()
            );
            println!(
                "   ratio {:.2} dof {} after {:.2} findings {:?}",
                f.quality.ratio, f.quality.dof, f.quality.ratio_after, f.quality.findings
            );
            for l in f.quality_lines() {
                println!("   {l}");
            }
        }
        Err(e) => println!("== {name}: ERR {e}"),
    }
}

#[test]
fn explore() {
    for noise in [0.0, 0.5, 3.0] {
        let opts = SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: noise };
        let (session, truth) = record(Some(jig()), 40, &opts);
        show(&format!("clean noise {noise}"), &observations(&session, 0), &truth);
        let (session, truth) = record(None, 60, &opts);
        show(&format!("clean free-only noise {noise}"), &observations(&session, 0), &truth);
    }
    let opts = SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 0.5 };
    let (session, truth) = record(Some(jig()), 40, &opts);
    let clean = observations(&session, 0);
    for (d, s, at) in [(5e-3, 2usize, 25), (1e-3, 1, 25), (1e-3, 3, 12), (-1e-3, 0, 40), (0.2e-3, 2, 30)] {
        let mut obs = clean.clone();
        let mpc = truth[0].metres_per_count[s];
        for k in at..obs.len() {
            obs[k].counts[s] += d / mpc;
        }
        show(&format!("slip {d} string {s} at {at}"), &obs, &truth);
    }
    for (c, s) in [(0.18e-3, 3usize), (0.018e-3, 1), (-0.18e-3, 0)] {
        let mut obs = clean.clone();
        let mpc = truth[0].metres_per_count[s];
        for k in 0..obs.len() {
            obs[k].counts[s] += k as f64 * c / mpc;
        }
        show(&format!("creep {c} string {s}"), &obs, &truth);
    }
    for (k, s, d) in [(30usize, 1usize, 1e-3), (4, 2, 1e-3)] {
        let mut obs = clean.clone();
        obs[k].counts[s] += d / truth[0].metres_per_count[s];
        show(&format!("outlier pose {k} string {s}"), &obs, &truth);
    }
}

#[test]
fn jig_mc() {
    use rand::{Rng, SeedableRng};
    let rig = Rig::default_rig();
    let opts = SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 0.5 };
    let (session, _truth) = record(Some(jig()), 40, &opts);
    let clean = observations(&session, 0);
    let fo = FitOptions { jig_tolerance_m: 0.0, ..FitOptions::default() };
    let base = fit_hand(0, &rig.hands[0], &clean, &fo).unwrap();
    let with = fit_hand(0, &rig.hands[0], &clean, &FitOptions::default()).unwrap();
    println!("std without {:?}\nstd with {:?}", base.anchor_std_m, with.anchor_std_m);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    let mut acc = [glam::DVec3::ZERO; 4];
    let trials = 30;
    for _ in 0..trials {
        let mut obs = clean.clone();
        for o in obs.iter_mut() {
            if let Some(p) = o.known_m.as_mut() {
                let z: DVec3 = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ) * (3.0f64).sqrt()
                    * 0.03e-3;
                *p += z;
            }
        }
        let f = fit_hand(0, &rig.hands[0], &obs, &fo).unwrap();
        for i in 0..4 {
            let d = f.geometry.anchors_m[i] - base.geometry.anchors_m[i];
            acc[i] += d * d;
        }
    }
    for i in 0..4 {
        println!("MC std anchor {i}: {:?}", (acc[i] / trials as f64).to_array().map(|v| v.sqrt() * 1e3));
    }
}

#[test]
fn jig_truth_offsets() {
    let opts = SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 0.5 };
    let (session, truth) = record(Some(jig()), 40, &opts);
    for o in observations(&session, 0) {
        if let Some(k) = o.known_m {
            let (p, _) = truth[0].position(&o.counts).unwrap();
            println!("{}: offset um {:?}", o.label, ((p - k) * 1e6).to_array().map(|v| v.round()));
        }
    }
}

#[test]
fn noise3() {
    let rig = Rig::default_rig();
    for free in [40, 80] {
        let opts = SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 3.0 };
        let r = Rig::default_rig();
        let truth = truth_geometry(&r, &opts);
        let dev = sim_rig(&r, &truth, opts.noise_counts, opts.seed).unwrap();
        let mut rec = Recorder::new(dev, &r, RecordOptions::default()).unwrap();
        let plan = Plan {
            hands: vec![0, 1],
            jig: Some(jig()),
            free_per_hand: free,
            free_half_extent_m: DVec3::splat(0.3),
        };
        let session = rec.record_session(&mut SimOperator::new(false), &plan, "sim").unwrap();
        for h in 0..2 {
            let f = fit_hand(h, &rig.hands[h], &observations(&session, h), &FitOptions::default()).unwrap();
            let f0 = fit_hand(
                h,
                &rig.hands[h],
                &observations(&session, h),
                &FitOptions { jig_tolerance_m: 0.0, ..FitOptions::default() },
            )
            .unwrap();
            for i in 0..4 {
                println!(
                    "free {free} hand {h} anchor {i}: err {:.3} mm std {:.3} (noise only {:.3})",
                    f.geometry.anchors_m[i].distance(truth[h].anchors_m[i]) * 1e3,
                    f.anchor_std_m[i].length() * 1e3,
                    f0.anchor_std_m[i].length() * 1e3
                );
            }
        }
    }
}
