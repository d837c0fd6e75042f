//! Recordings and live sessions read as Foxglove reads them, with Foxglove's own published
//! libraries in node (`tests/foxglove/`: @mcap/core, @foxglove/ws-protocol,
//! @foxglove/rosmsg2-serialization, @foxglove/schemas).
//!
//! One session serves both tests: a boxing world process (`spidar-hil-world`, the world of
//! `spidar run`) that records and serves Foxglove live at once, a virtual-clock rig in lockstep
//! with it (recorded too), and a Foxglove WebSocket client subscribed to every channel while it
//! runs. Node and the npm packages are needed: without them the tests say SKIPPED and pass,
//! unless `SPIDAR_BROWSER_TESTS=required` (set by `.ci/run`). They never leave a process behind:
//! the world is ended (SIGTERM) and waited for, node ends when the server closes.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use serde_json::Value;
use spidar_link::PrivateDir;
use spidar_record::writer::{EndInfo, Recorder, SessionInfo};
use spidar_runtime::session::{load_scripts, sim_device, SimOptions, VirtualRun};

use super::link::{WorldProcess, WAIT};
use super::rig;

/// True when node and the packages are here; false (after a loud message) when skipped.
fn foxglove_here(test: &str) -> bool {
    spidar_testkit::node::can_run(test, spidar_testkit::node::foxglove_missing(), "The Foxglove checks")
}

/// What the shared session left: its files (kept in `_dir`) and the live client's summary.
struct Session {
    _dir: PrivateDir,
    world_mcap: PathBuf,
    rig_mcap: PathBuf,
    live: Value,
}

fn last_json(out: &str) -> Value {
    let line =
        out.lines().rev().find(|l| l.starts_with('{')).unwrap_or_else(|| panic!("no JSON from node: {out}"));
    serde_json::from_str(line).unwrap()
}

/// Runs the session once for every test of this file.
fn session() -> &'static Session {
    static S: OnceLock<Session> = OnceLock::new();
    S.get_or_init(|| {
        let dir = PrivateDir::for_process().unwrap();
        let world_mcap = dir.join("bout.world.mcap");
        let rig_mcap = dir.join("bout.mcap");
        let sock = format!("unix:{}", dir.join("fox.sock").display());
        let mut world = WorldProcess::start(&[
            "--scene",
            "boxing",
            "--lockstep",
            "--listen",
            &sock,
            "--foxglove",
            "127.0.0.1:0",
            "--record",
            world_mcap.to_str().unwrap(),
        ]);
        assert!(world.wait_for_line("Foxglove live at"), "{:?}", world.said.lock().unwrap());
        let url = world
            .said
            .lock()
            .unwrap()
            .iter()
            .find_map(|l| l.split_whitespace().find(|w| w.starts_with("ws://")).map(str::to_string))
            .unwrap();
        // The client subscribes to every channel before the rig connects.
        let mut node = Command::new("node")
            .args(["live.mjs", &url, world_mcap.to_str().unwrap()])
            .current_dir(spidar_testkit::node::foxglove_dir())
            .stdout(Stdio::piped())
            .spawn()
            .expect("starting node");
        let mut out = BufReader::new(node.stdout.take().unwrap());
        let mut first = String::new();
        out.read_line(&mut first).unwrap();
        assert!(first.contains("\"subscribed\":11"), "{first}");
        // A rig in lockstep with the world, recorded as `spidar run --record` does.
        let r = rig();
        let dev = sim_device(&r, load_scripts("box", &r, 1).unwrap(), &SimOptions::default()).unwrap();
        let mut v = VirtualRun::with_world_process(dev, &r, &world.at, None, WAIT).unwrap();
        let mut rec = Recorder::create(&rig_mcap, &SessionInfo::default()).unwrap();
        v.home_and_activate();
        for _ in 0..3000 {
            let t = v.tick();
            rec.write_tick(&t);
        }
        rec.finish(&EndInfo::default());
        drop(v); // the rig says goodbye
                 // The world ends (SIGTERM, as Ctrl-C): its recording is finished, its clients closed.
        unsafe { libc::kill(world.child.id() as i32, libc::SIGTERM) };
        assert!(world.child.wait().unwrap().success(), "{:?}", world.said.lock().unwrap());
        let mut rest = String::new();
        std::io::Read::read_to_string(&mut out, &mut rest).unwrap();
        assert!(node.wait().unwrap().success(), "{rest}");
        Session { _dir: dir, world_mcap, rig_mcap, live: last_json(&rest) }
    })
}

/// Runs `node recording.mjs FILE` and returns its summary.
fn read_recording(path: &std::path::Path) -> Value {
    let o = Command::new("node")
        .args(["recording.mjs", path.to_str().unwrap(), "40"])
        .current_dir(spidar_testkit::node::foxglove_dir())
        .output()
        .expect("starting node");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}{}", String::from_utf8_lossy(&o.stderr));
    last_json(&out)
}

#[test]
fn foxglove_client_receives_live_what_the_recording_holds_and_decodes_it() {
    if !foxglove_here("foxglove_client_receives_live_what_the_recording_holds_and_decodes_it") {
        return;
    }
    let s = &session().live;
    // Every channel of the recording, with its schema, in the recording's encodings.
    assert_eq!(s["channels"].as_array().unwrap().len(), spidar_record::world::channels().len(), "{s}");
    for c in s["channels"].as_array().unwrap() {
        assert_eq!(
            (c["encoding"].as_str(), c["schemaEncoding"].as_str()),
            (Some("cdr"), Some("ros2msg")),
            "{c}"
        );
    }
    assert_eq!(s["schemasDiffer"], serde_json::json!([]), "the live schemas are the recording's");
    assert_eq!(s["decodeErrors"], serde_json::json!([]), "every message decodes");
    let (received, matched) = (s["received"].as_u64().unwrap(), s["matched"].as_u64().unwrap());
    // 3000 ticks: 1000 steps, each a step, transforms and the boxer's decisions at least (the
    // first few may pass before the server has taken the subscriptions).
    assert!(received > 2500, "{s}");
    assert_eq!(matched, received, "each message received equals the recording's of its topic and time: {s}");
    assert_eq!(matched, s["recordedFromFirst"].as_u64().unwrap(), "and nothing recorded was missed: {s}");
    for t in [
        "/world/tf",
        "/world/scene",
        "/world/labels",
        "/world/boxer",
        "/world/gaze",
        "/world/gaze/drawn",
        "/world/view",
    ] {
        assert!(s["perTopic"][t].as_u64().unwrap_or(0) > 0, "{t}: {s}");
    }
}

#[test]
fn foxglove_reads_the_sessions_time_range_and_the_whole_scene_after_any_seek() {
    if !foxglove_here("foxglove_reads_the_sessions_time_range_and_the_whole_scene_after_any_seek") {
        return;
    }
    let s = session();
    for (path, world) in [(&s.world_mcap, true), (&s.rig_mcap, false)] {
        let r = read_recording(path);
        assert_eq!(r["problems"], serde_json::json!([]), "{}: {r}", path.display());
        // The range starts at the first message, which is the session's start (not 1970).
        assert_eq!(r["startNs"], r["firstMessageNs"], "{r}");
        let from_session = r["startNs"].as_f64().unwrap() - r["sessionStartNs"].as_f64().unwrap();
        assert!((0.0..0.01e9).contains(&from_session), "{r}");
        let d = r["durationS"].as_f64().unwrap();
        assert!((2.9..3.1).contains(&d), "3 s of rig time: {d} s ({r})");
        if world {
            assert_eq!(r["seeks"], 40, "{r}");
            assert_eq!(r["entities"]["/world/scene"], 19, "every body of the boxing world: {r}");
            assert_eq!(r["entities"]["/world/labels"], 3, "{r}");
            for ty in [
                "foxglove_msgs/ModelPrimitive",
                "foxglove_msgs/TriangleListPrimitive",
                "foxglove_msgs/SceneEntity",
            ] {
                assert_eq!(r["fieldLists"][ty], "released", "{ty}: {r}");
            }
        }
    }
}

#[test]
fn foxglove_client_receives_the_rigs_channels_live_as_its_recording_holds_them() {
    if !foxglove_here("foxglove_client_receives_the_rigs_channels_live_as_its_recording_holds_them") {
        return;
    }
    use spidar_runtime::session::{run_live, LiveOptions, WorldChoice};
    let dir = PrivateDir::for_process().unwrap();
    let rig_mcap = dir.join("live-rig.mcap");
    let r = rig();
    let rec = Recorder::create(&rig_mcap, &SessionInfo::default()).unwrap();
    // `spidar run --record FILE --foxglove ADDR`: the rig's recorder thread writes the file and
    // serves its channels (here on any free port).
    let (recorder, url) = spidar_runtime::recording::recorder_thread(Some(rec), Some("127.0.0.1:0")).unwrap();
    let url = url.unwrap();
    let mut node = Command::new("node")
        .args(["live.mjs", &url, rig_mcap.to_str().unwrap()])
        .current_dir(spidar_testkit::node::foxglove_dir())
        .stdout(Stdio::piped())
        .spawn()
        .expect("starting node");
    let mut out = BufReader::new(node.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    assert!(first.contains("\"subscribed\":4"), "{first}");
    let dev = sim_device(&r, load_scripts("tour", &r, 1).unwrap(), &SimOptions::default()).unwrap();
    let opts = LiveOptions {
        seconds: Some(2.0),
        rt: spidar_rt::rt_thread::RtOptions { fifo_priority: None, lock_memory: false, ..Default::default() },
        spin_ns: 0,
        status_every: None,
        stop: spidar_runtime::signals::Stop::detached(),
        scene_name: "walls".into(),
        script_name: "tour".into(),
        connect_timeout: WAIT,
        world_priority: None,
        supervisor: None,
        recorder,
    };
    let world = WorldChoice::Thread(spidar_world::host::Stepper::new(Box::new(
        spidar_world::walls::WallsScene::builtin(),
    )));
    let summary = run_live(dev, &r, world, opts).unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut out, &mut rest).unwrap();
    assert!(node.wait().unwrap().success(), "{rest}");
    let s = last_json(&rest);
    assert_eq!(s["schemasDiffer"], serde_json::json!([]), "{s}");
    assert_eq!(s["decodeErrors"], serde_json::json!([]), "{s}");
    let (received, matched) = (s["received"].as_u64().unwrap(), s["matched"].as_u64().unwrap());
    assert!(received > 2 * summary.counters.ticks, "a tick and a sample every tick: {s}");
    assert_eq!(matched, received, "{s}");
    assert_eq!(matched, s["recordedFromFirst"].as_u64().unwrap(), "nothing recorded was missed: {s}");
}
