//! Calibration on the simulated rig whose true geometry is wrong on purpose (anchors off by 2.5-5 cm,
//! metres per count off by 8-10 %, counters starting anywhere, 0.5 count encoder noise on top of
//! quantisation): record, fit, verify against the truth.

// Indexing hands 0..2 and strings 0..4 in parallel arrays reads plainer than zipped iterators here.
#![allow(clippy::needless_range_loop)]
use glam::DVec3;
use spidar_calib::fit::{fit_hand, observations, FitOptions, Observability, Observation};
use spidar_calib::jig::JigFile;
use spidar_calib::model::{align, HandGeometry};
use spidar_calib::record::{Plan, RecordOptions, Recorder, SimOperator};
use spidar_calib::session::SessionFile;
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_calib::verify::verify;
use spidar_calib::CalibError;
use spidar_rt::Rig;

fn jig() -> JigFile {
    JigFile::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/jig-spidar-h.ron")))
        .unwrap()
}

fn truth_opts() -> SimTruthOptions {
    SimTruthOptions { seed: 7, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 0.5 }
}

fn record(jig: Option<JigFile>, free: usize, opts: &SimTruthOptions) -> (SessionFile, [HandGeometry; 2]) {
    let rig = Rig::default_rig();
    let truth = truth_geometry(&rig, opts);
    let dev = sim_rig(&rig, &truth, opts.noise_counts, opts.seed).unwrap();
    let mut rec = Recorder::new(dev, &rig, RecordOptions::default()).unwrap();
    let mut op = SimOperator::new(false);
    let plan = Plan { hands: vec![0, 1], jig, free_per_hand: free, free_half_extent_m: DVec3::splat(0.3) };
    let session = rec.record_plan(&mut op, &plan, "sim").unwrap();
    (session, truth)
}

#[test]
fn the_truth_really_differs_from_the_configured_rig() {
    let rig = Rig::default_rig();
    let truth = truth_geometry(&rig, &truth_opts());
    for h in 0..2 {
        for i in 0..4 {
            let d = truth[h].anchors_m[i].distance(rig.hands[h].anchors_m[i]);
            assert!((0.025..=0.05).contains(&d), "anchor moved {d} m");
            let r = truth[h].metres_per_count[i] / rig.hands[h].metres_per_count[i];
            assert!((0.08..=0.10 + 1e-12).contains(&(r - 1.0).abs()), "mpc ratio {r}");
        }
    }
}

#[test]
fn jig_and_free_poses_fit_anchors_within_a_millimetre_and_check_points_within_a_millimetre() {
    let rig = Rig::default_rig();
    let opts = truth_opts();
    let (session, truth) = record(Some(jig()), 40, &opts);
    let mut fitted = [truth[0]; 2];
    for h in 0..2 {
        let obs = observations(&session, h);
        assert_eq!(obs.iter().filter(|o| o.known_m.is_some()).count(), 8);
        assert_eq!(obs.len(), 1 + 8 + 40);
        let fit = fit_hand(h, &rig.hands[h], &obs, &FitOptions::default()).unwrap();
        println!("{fit}");
        assert_eq!(fit.gauge_dof, 0);
        assert_eq!(fit.rank, fit.n_params, "jig points leave nothing unobservable");
        assert!(fit.is_trustworthy());
        for i in 0..4 {
            let err = fit.geometry.anchors_m[i].distance(truth[h].anchors_m[i]);
            assert!(err < 1e-3, "hand {h} anchor {i}: {:.3} mm from the truth", err * 1e3);
            let rel = fit.geometry.metres_per_count[i] / truth[h].metres_per_count[i] - 1.0;
            assert!(rel.abs() < 1e-3, "hand {h} mpc {i}: {rel:e}");
            // The reported uncertainty is honest: the error is within 4 standard deviations.
            let std = fit.anchor_std_m[i].length();
            assert!(err < 4.0 * std + 50e-6, "anchor {i}: error {err:e} vs std {std:e}");
        }
        fitted[h] = fit.geometry;
    }
    // Verification on the same simulated rig, at check points the fit never saw.
    let dev = sim_rig(&rig, &truth, opts.noise_counts, opts.seed + 1).unwrap();
    let mut rec = Recorder::new(dev, &rig, RecordOptions::default()).unwrap();
    let mut op = SimOperator::new(false);
    let report = verify(&mut rec, &mut op, &rig, &fitted, &jig(), &[0, 1]).unwrap();
    println!("{report}");
    assert_eq!(report.checks.len(), 8);
    assert!(report.max_error_m() < 1e-3, "check-point error {:.3} mm", report.max_error_m() * 1e3);
    // With the configured (taped) geometry homed at the home point the same points are centimetres off.
    let homed: [HandGeometry; 2] = std::array::from_fn(|h| {
        let home = session.poses_of(h).next().unwrap();
        HandGeometry::homed(&rig.hands[h], &home.counts, rig.hands[h].home_m)
    });
    let before = verify(&mut rec, &mut op, &rig, &homed, &jig(), &[0, 1]).unwrap();
    assert!(before.max_error_m() > 10e-3, "uncalibrated error only {:.3} mm", before.max_error_m() * 1e3);
}

#[test]
fn free_poses_alone_fit_the_shape_and_name_the_unobservable_frame_and_scale() {
    let rig = Rig::default_rig();
    let opts = truth_opts();
    let (session, truth) = record(None, 60, &opts);
    for h in 0..2 {
        let obs = observations(&session, h);
        let fit = fit_hand(h, &rig.hands[h], &obs, &FitOptions::default()).unwrap();
        println!("{fit}");
        // Exactly the 7 gauge directions are unobservable, and the report says which.
        assert_eq!(fit.gauge_dof, 7);
        assert_eq!(fit.rank, fit.n_params - 7, "only the frame and scale are unobservable");
        let note = fit.gauge_note.as_deref().unwrap();
        assert!(note.contains("3 translations, 3 rotations") && note.contains("scale"), "{note}");
        assert!(fit
            .params
            .iter()
            .filter(|p| p.name.starts_with("anchor"))
            .all(|p| p.status == Observability::Gauge));
        // What is observable is right: the anchors' shape up to a similarity, and the ratios of the
        // metres per count.
        let aligned = align(&fit.geometry.anchors_m, &truth[h].anchors_m, true);
        for i in 0..4 {
            let err = aligned[i].distance(truth[h].anchors_m[i]);
            assert!(err < 1e-3, "hand {h} anchor {i}: shape error {:.3} mm", err * 1e3);
        }
        let ratio: Vec<f64> =
            (0..4).map(|i| fit.geometry.metres_per_count[i] / truth[h].metres_per_count[i]).collect();
        for r in &ratio {
            assert!((r / ratio[0] - 1.0).abs() < 1e-3, "{ratio:?}");
        }
    }
}

#[test]
fn free_poses_with_known_metres_per_count_leave_only_the_rigid_frame_unobservable() {
    let rig = Rig::default_rig();
    let opts = SimTruthOptions { mpc_error: 0.0, ..truth_opts() };
    let (session, truth) = record(None, 60, &opts);
    let obs = observations(&session, 0);
    let fit = fit_hand(
        0,
        &rig.hands[0],
        &obs,
        &FitOptions { fit_metres_per_count: false, ..FitOptions::default() },
    )
    .unwrap();
    assert_eq!(fit.gauge_dof, 6);
    assert_eq!(fit.rank, fit.n_params - 6, "only the rigid frame is unobservable");
    let aligned = align(&fit.geometry.anchors_m, &truth[0].anchors_m, false);
    for i in 0..4 {
        assert!(aligned[i].distance(truth[0].anchors_m[i]) < 1e-3);
    }
}

// ---------------------------------------------------------------------------------------------
// Degenerate data: a clear error, never a silent bad result.

fn jig_session() -> (SessionFile, [HandGeometry; 2]) {
    record(Some(jig()), 40, &truth_opts())
}

#[test]
fn too_few_poses_say_how_many_more_are_needed() {
    let rig = Rig::default_rig();
    let (session, _) = record(None, 8, &truth_opts());
    let obs = observations(&session, 0);
    let e = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CalibError::Degenerate { hand: 0, .. }));
    assert!(msg.contains("too few poses") && msg.contains("more free poses"), "{msg}");
}

#[test]
fn two_identical_poses_are_refused_by_the_recorder_and_by_the_fit() {
    let rig = Rig::default_rig();
    let (session, _) = jig_session();
    let mut obs = observations(&session, 1);
    let mut copy = obs[20].clone();
    copy.label = "copy".into();
    copy.counts[0] += 0.3; // within noise of the original
    obs.push(copy);
    let msg = fit_hand(1, &rig.hands[1], &obs, &FitOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("same point") && msg.contains("copy"), "{msg}");

    // The recorder refuses a pose on top of an earlier one and says so.
    let opts = truth_opts();
    let truth = truth_geometry(&rig, &opts);
    let mut rec =
        Recorder::new(sim_rig(&rig, &truth, 0.5, 1).unwrap(), &rig, RecordOptions::default()).unwrap();
    let mut op = SimOperator::new(false);
    let req = spidar_calib::record::Request::Free { index: 0, of: 2, suggest_m: DVec3::new(-0.2, 0.1, 0.05) };
    let first = rec.record_pose(&mut op, 0, &req, &[]).unwrap().unwrap();
    let second = rec.record_pose(&mut op, 0, &req, std::slice::from_ref(&first)).unwrap();
    assert!(second.is_none());
    assert!(rec.warnings()[0].contains("adds no information"), "{:?}", rec.warnings());
}

#[test]
fn poses_all_in_one_plane_are_refused_with_the_plane_named() {
    let rig = Rig::default_rig();
    let truth = truth_geometry(&rig, &truth_opts());
    // Lengths of exact poses on the plane z = 0.05 through the true geometry.
    let obs: Vec<Observation> = (0..40)
        .map(|k| {
            let p = DVec3::new(
                -0.15 + 0.3 * ((k % 7) as f64 / 6.0 - 0.5),
                0.3 * ((k / 7) as f64 / 5.0 - 0.5),
                0.05,
            );
            let g = &truth[0];
            Observation {
                label: format!("p{k}"),
                counts: std::array::from_fn(|i| {
                    ((g.anchors_m[i].distance(p) - g.length_at_zero_m[i]) / g.metres_per_count[i]).floor()
                }),
                known_m: None,
                hint_m: (k == 0).then_some(p),
            }
        })
        .collect();
    let msg = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("one plane") && msg.contains("normal"), "{msg}");
}

#[test]
fn a_string_slack_in_a_few_poses_is_down_weighted_and_named_and_in_many_is_an_error() {
    let rig = Rig::default_rig();
    let (session, truth) = jig_session();
    let clean = observations(&session, 0);
    // String 2 sagged by 5 mm (it reads that much long) in 3 jig poses.
    let mpc = truth[0].metres_per_count[2];
    let mut obs = clean.clone();
    for k in [2, 4, 7] {
        obs[k].counts[2] += 5e-3 / mpc;
    }
    let fit = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap();
    for k in [2, 4, 7] {
        assert!(
            fit.outliers.iter().any(|o| o.0 == k && o.1 == 2),
            "pose {k} not flagged: {:?}",
            fit.outliers
        );
    }
    for i in 0..4 {
        assert!(
            fit.geometry.anchors_m[i].distance(truth[0].anchors_m[i]) < 1e-3,
            "robust fit still within 1 mm"
        );
    }
    assert!(fit.advice.iter().any(|a| a.contains("re-record")), "{:?}", fit.advice);
    // Slack in six of the eight jig poses: the string is not to be trusted at all.
    let mut obs = clean;
    for k in 1..=6 {
        obs[k].counts[2] += 5e-3 / mpc;
    }
    let e = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap_err();
    assert!(matches!(e, CalibError::InconsistentString { hand: 0, string: 2, .. }), "{e}");
    assert!(e.to_string().contains("slack"), "{e}");
}

#[test]
fn the_session_round_trips_through_its_file() {
    let (session, _) = record(Some(jig()), 10, &truth_opts());
    let path = std::env::temp_dir().join(format!("spidar-calib-session-{}.ron", std::process::id()));
    session.save(&path).unwrap();
    let back = SessionFile::load(&path).unwrap();
    assert_eq!(back, session);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn two_jig_points_leave_a_rotation_unobservable_and_the_fit_says_so() {
    let rig = Rig::default_rig();
    let (session, _) = jig_session();
    // Keep the home pose, two jig points and the free poses: a rotation about the line through the
    // two points changes no length.
    let obs: Vec<Observation> = observations(&session, 0)
        .into_iter()
        .enumerate()
        .filter(|(k, o)| o.known_m.is_none() || *k <= 2)
        .map(|(_, o)| o)
        .collect();
    assert_eq!(obs.iter().filter(|o| o.known_m.is_some()).count(), 2);
    let e = fit_hand(0, &rig.hands[0], &obs, &FitOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CalibError::Degenerate { .. }), "{msg}");
    assert!(msg.contains("rank deficient") && msg.contains("at least 4"), "{msg}");
}

#[test]
fn a_stop_signal_during_recording_aborts_at_the_next_exchange() {
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::sync::Arc;
    let rig = Rig::default_rig();
    let opts = truth_opts();
    let truth = truth_geometry(&rig, &opts);
    let dev = sim_rig(&rig, &truth, opts.noise_counts, opts.seed).unwrap();
    let stop = Arc::new(AtomicU32::new(0));
    let mut rec =
        Recorder::new(dev, &rig, RecordOptions { stop: Some(stop.clone()), ..RecordOptions::default() })
            .unwrap();
    let mut op = SimOperator::new(false);
    let plan = Plan { hands: vec![0], jig: None, free_per_hand: 3, free_half_extent_m: DVec3::splat(0.2) };
    stop.fetch_add(1, Ordering::SeqCst);
    match rec.record_plan(&mut op, &plan, "sim") {
        Err(CalibError::Aborted(why)) => assert!(why.contains("a stop signal"), "{why}"),
        other => panic!("expected an abort, got {:?}", other.map(|s| s.poses.len())),
    }
    // As `spidar calib`: the outputs are switched off after the abort.
    assert!(!rec.finish().unwrap().is_active());
}
