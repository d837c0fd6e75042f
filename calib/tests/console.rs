//! The console operator driven like a person at a keyboard: the recorder runs on its own thread
//! against the simulated rig; this thread reads the prompts, moves the simulated hand to the
//! point each prompt names, and then types Enter, `s` or `q`.

use std::io::{BufReader, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use glam::DVec3;
use spidar_calib::console::ConsoleOperator;
use spidar_calib::jig::JigFile;
use spidar_calib::record::{Plan, RecordOptions, Recorder};
use spidar_calib::session::{PoseKind, SessionFile};
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_calib::CalibError;
use spidar_device::sim::{Script, Segment, SimRig};
use spidar_device::{Device, DeviceError, DeviceInfo, Input, Output};
use spidar_rt::Rig;

/// The simulated rig shared with the test thread, which moves its hand between key presses.
struct Shared(Arc<Mutex<SimRig>>, DeviceInfo);

impl Device for Shared {
    fn open(&mut self) -> Result<(), DeviceError> {
        self.0.lock().unwrap().open()
    }
    fn activate(&mut self) -> Result<(), DeviceError> {
        self.0.lock().unwrap().activate()
    }
    fn deactivate(&mut self) -> Result<(), DeviceError> {
        self.0.lock().unwrap().deactivate()
    }
    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        self.0.lock().unwrap().exchange(out, inp)
    }
    fn info(&self) -> &DeviceInfo {
        &self.1
    }
}

/// Keys typed by the test: a pipe from a channel, as stdin is a pipe from the keyboard.
struct Keyboard {
    rx: Receiver<Vec<u8>>,
    pending: Vec<u8>,
}

impl Read for Keyboard {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.pending.is_empty() {
            match self.rx.recv() {
                Ok(b) => self.pending = b,
                Err(_) => return Ok(0),
            }
        }
        let n = buf.len().min(self.pending.len());
        buf[..n].copy_from_slice(&self.pending[..n]);
        self.pending.drain(..n);
        Ok(n)
    }
}

/// The screen: complete lines go to the test thread.
struct Screen {
    tx: Sender<String>,
    partial: String,
}

impl Write for Screen {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.partial.push_str(&String::from_utf8_lossy(buf));
        while let Some(i) = self.partial.find('\n') {
            let line: String = self.partial.drain(..=i).collect();
            let _ = self.tx.send(line.trim_end().to_string());
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[derive(Clone, Copy, Debug)]
enum Key {
    /// Move the hand to the requested point, then Enter.
    Move,
    Skip,
    Quit,
    /// Close the keyboard (Ctrl-D, or the terminal going away).
    Close,
    /// A stop signal (Ctrl-C, SIGTERM, SIGHUP): the flag `spidar calib` gives the recorder's
    /// link is raised.
    Signal,
}

struct Outcome {
    result: Result<SessionFile, CalibError>,
    screen: Vec<String>,
    rig: Arc<Mutex<SimRig>>,
    keys_used: usize,
}

/// The point in the last "(x, y, z) m" of a line.
fn point_in(line: &str) -> DVec3 {
    let (a, b) = (line.rfind('(').unwrap(), line.rfind(')').unwrap());
    let v: Vec<f64> = line[a + 1..b].split(',').map(|s| s.trim().parse().unwrap()).collect();
    DVec3::new(v[0], v[1], v[2])
}

fn two_jig_points() -> JigFile {
    let mut jig = JigFile::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/jig-spidar-h.ron"
    )))
    .unwrap();
    jig.fit_points.retain(|p| p.hand == 0);
    jig.fit_points.truncate(2);
    assert_eq!(jig.fit_points.len(), 2);
    jig
}

fn drive(free: usize, keys: &[Key]) -> Outcome {
    let rig = Rig::default_rig();
    let opts = SimTruthOptions { seed: 3, anchor_error_m: 0.03, mpc_error: 0.05, noise_counts: 0.5 };
    let truth = truth_geometry(&rig, &opts);
    let shared = Arc::new(Mutex::new(sim_rig(&rig, &truth, opts.noise_counts, opts.seed).unwrap()));
    let (key_tx, key_rx) = mpsc::channel::<Vec<u8>>();
    let (screen_tx, screen_rx) = mpsc::channel::<String>();
    let info = shared.lock().unwrap().info().clone();
    let dev = Shared(shared.clone(), info);
    let stop = Arc::new(AtomicBool::new(false));
    let worker_stop = stop.clone();
    let plan = Plan {
        hands: vec![0],
        jig: Some(two_jig_points()),
        free_per_hand: free,
        free_half_extent_m: DVec3::splat(0.25),
    };
    let worker = std::thread::spawn(move || {
        let keyboard = BufReader::new(Keyboard { rx: key_rx, pending: Vec::new() });
        let screen = Box::new(Screen { tx: screen_tx, partial: String::new() });
        let mut op = ConsoleOperator::new(keyboard, screen, &rig).unwrap();
        op.introduce();
        let mut rec = Recorder::on_virtual_loop(dev, &rig, RecordOptions::default(), false).unwrap();
        rec.set_stop(Arc::new(move || worker_stop.load(Ordering::SeqCst)));
        let r = rec.record_session(&mut op, &plan, "simulated rig behind a console");
        // As `spidar calib record`: outputs off when the recording ends, whichever way.
        if r.is_ok() {
            rec.finish().unwrap();
        }
        r
    });
    let mut screen = Vec::new();
    let mut asked_at = DVec3::ZERO;
    let mut used = 0;
    let mut key_tx = Some(key_tx);
    // Lines stop when the worker ends (its screen is dropped).
    while let Ok(line) = screen_rx.recv_timeout(Duration::from_secs(120)) {
        if line.starts_with("> hand") {
            asked_at = point_in(&line);
        }
        let prompt = line.trim_start().starts_with("press Enter") || line.contains("cannot be skipped");
        screen.push(line);
        if !prompt {
            continue;
        }
        let key = keys.get(used).copied().unwrap_or(Key::Close);
        used += 1;
        let Some(tx) = key_tx.as_ref() else { continue };
        match key {
            Key::Move => {
                let script = Script::from_segments(
                    vec![
                        Segment::Reach { to_m: asked_at.to_array(), duration_s: 1.0 },
                        Segment::Hold { at_m: asked_at.to_array(), for_s: 1e6 },
                    ],
                    false,
                );
                shared.lock().unwrap().try_set_script(0, script).unwrap();
                tx.send(b"\n".to_vec()).unwrap();
            }
            Key::Skip => tx.send(b"s\n".to_vec()).unwrap(),
            Key::Quit => tx.send(b"q\n".to_vec()).unwrap(),
            Key::Close => key_tx = None,
            Key::Signal => stop.store(true, Ordering::SeqCst),
        }
    }
    // A worker still waiting for a key ends (input closed) rather than hanging the test.
    drop(key_tx);
    let result = worker.join().unwrap();
    Outcome { result, screen, rig: shared, keys_used: used }
}

#[test]
fn console_recording_of_home_two_jig_points_and_two_free_poses_completes() {
    use Key::Move;
    // home, 2 jig points, 2 free poses, back home at the end.
    let o = drive(2, &[Move, Move, Move, Move, Move, Move]);
    let session = o.result.unwrap_or_else(|e| panic!("{e}\n{}", o.screen.join("\n")));
    assert_eq!(o.keys_used, 6, "{}", o.screen.join("\n"));
    let kinds: Vec<&str> = session
        .poses
        .iter()
        .map(|p| match p.kind {
            PoseKind::Home { .. } => "home",
            PoseKind::Jig { .. } => "jig",
            PoseKind::Free => "free",
        })
        .collect();
    assert_eq!(kinds, ["home", "jig", "jig", "free", "free"], "{}", o.screen.join("\n"));
    // The operator saw where, in rig-frame metres, and what was recorded.
    assert!(o.screen.iter().any(|l| l.starts_with("> hand 0 (") && l.contains("home point (")));
    assert_eq!(o.screen.iter().filter(|l| l.contains("recorded:")).count(), 5);
    assert!(!o.rig.lock().unwrap().is_active(), "outputs left on after recording");
}

#[test]
fn console_keeps_exchanging_at_minimum_tension_while_waiting_for_a_key() {
    // The loop ticks while the test thread takes its time: the rig's plant time runs on and the
    // strings pull as the loop holds them while inactive (at least the minimum tension, zero net
    // force), not zero (the last tick before the abort's switch-off).
    let o = drive(0, &[Key::Quit]);
    assert!(matches!(o.result, Err(CalibError::Aborted(_))));
    let rig = o.rig.lock().unwrap();
    assert!(rig.truth().t_s > 0.0, "no exchange while waiting for the key");
    let hr = &Rig::default_rig().hands[0];
    let t = rig.truth().hands[0].tension_n;
    assert!(t.iter().all(|&t| t > 0.8 * hr.tension_min_n && t < hr.tension_max_n), "string tensions {t:?} N");
    assert!(t.iter().any(|&t| t < 1.2 * hr.tension_min_n), "no string at the minimum: {t:?} N");
}

#[test]
fn console_q_aborts_with_the_device_deactivated() {
    use Key::{Move, Quit};
    let o = drive(2, &[Move, Quit]);
    match &o.result {
        Err(CalibError::Aborted(why)) => assert!(why.contains("(q)"), "{why}"),
        other => panic!("expected an abort, got {:?}", other.as_ref().map(|s| s.poses.len())),
    }
    assert!(!o.rig.lock().unwrap().is_active(), "q must switch the outputs off");
    assert!(o.screen.iter().any(|l| l.starts_with("aborting: stopped by the operator")));
}

#[test]
fn a_stop_signal_while_waiting_aborts_with_the_device_deactivated() {
    let o = drive(2, &[Key::Move, Key::Signal]);
    match &o.result {
        Err(CalibError::Interrupted(why)) => assert!(why.contains("a stop signal"), "{why}"),
        other => panic!("expected an interruption, got {:?}", other.as_ref().map(|s| s.poses.len())),
    }
    assert!(!o.rig.lock().unwrap().is_active(), "a stop signal must switch the outputs off");
    assert!(o.screen.iter().any(|l| l.starts_with("stopping: ")), "{}", o.screen.join("\n"));
}

#[test]
fn console_closed_input_aborts_with_the_device_deactivated() {
    let o = drive(2, &[Key::Move, Key::Close]);
    match &o.result {
        Err(CalibError::Aborted(why)) => assert!(why.contains("input closed"), "{why}"),
        other => panic!("expected an abort, got {:?}", other.as_ref().map(|s| s.poses.len())),
    }
    assert!(!o.rig.lock().unwrap().is_active());
}

#[test]
fn console_s_skips_a_free_pose_and_the_next_suggestion_replaces_it() {
    use Key::{Move, Skip};
    // home, jig, jig, free (skipped), free, free, back home.
    let o = drive(2, &[Move, Move, Move, Skip, Move, Move, Move]);
    let session = o.result.unwrap_or_else(|e| panic!("{e}\n{}", o.screen.join("\n")));
    assert_eq!(session.poses.iter().filter(|p| matches!(p.kind, PoseKind::Free)).count(), 2);
    assert_eq!(o.screen.iter().filter(|l| l.trim() == "skipped").count(), 1);
    assert_eq!(o.keys_used, 7, "{}", o.screen.join("\n"));
}

#[test]
fn console_s_does_not_skip_the_home_pose() {
    use Key::{Move, Skip};
    let o = drive(0, &[Skip, Move, Move, Move, Move]);
    let session = o.result.unwrap_or_else(|e| panic!("{e}\n{}", o.screen.join("\n")));
    assert!(matches!(session.poses[0].kind, PoseKind::Home { .. }));
    assert!(o.screen.iter().any(|l| l.contains("cannot be skipped")));
}
