//! Tests of the world's recordings: what an independent reader (the `mcap` crate's) finds in one,
//! the Foxglove messages decoding as drawn, a kill part way, and the stepping thread never waiting.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use spidar_msg::HandSample;
use spidar_world::host::Stepper;

use crate::cdr::{self, Field};
use crate::foxglove::{FrameTransforms, SceneUpdate};
use crate::reader::{self, Ending};
use crate::world::*;

pub(crate) fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spidar-world-record-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// The user's hands in front of the virtual human, the left one jabbing now and then.
pub(crate) fn sample(k: u64, t_s: f64) -> HandSample {
    let mut s = HandSample { tick: k, t_s, ..Default::default() };
    let jab = ((k % 300) as f64 / 300.0 * std::f64::consts::TAU).sin().max(0.0);
    s.hands[0].pos_world_m = DVec3::new(-0.15, 0.0, -0.45 * jab);
    s.hands[1].pos_world_m = DVec3::new(0.15, 0.0, 0.0);
    for h in &mut s.hands {
        h.valid = true;
    }
    s
}

/// The rig's status the tests' world gets: a known tick count.
pub(crate) fn rig_status(k: u64) -> spidar_msg::RigStatus {
    spidar_msg::RigStatus {
        tick: 3 * k,
        state: spidar_msg::RigState::Active,
        rate_hz: 1000.0,
        lateness_p99_s: 5e-5,
        faults: k / 100,
        tensions_n: [[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]],
        ..Default::default()
    }
}

/// Steps `scene` `steps` times with a recorder on `path` (the default rig's geometry and a known
/// status); returns the look's shape and label counts and the report.
pub(crate) fn record_scene(scene: &str, path: &Path, steps: u64) -> (usize, usize, WorldRecordingReport) {
    let scene = spidar_world::load(scene).unwrap();
    let look = scene.look();
    let info = WorldInfo {
        scene: "test".into(),
        name: "boxing".into(),
        clock: "virtual".into(),
        ..Default::default()
    };
    let (rec, obs) = WorldRecording::start(path, &info, &look).unwrap();
    let mut st = Stepper::new(scene);
    st.add_observer(Box::new(obs));
    let dt = st.step_s();
    let geometry = spidar_rt::status::rig_info(&spidar_rt::rig::Rig::default_rig());
    for k in 0..steps {
        let t = dt * (k + 1) as f64;
        st.step(t, &[sample(k, t)], Some(&geometry), Some(&rig_status(k)));
        if k % 64 == 63 {
            // The writer thread keeps up (the queue holds QUEUE_STEPS): no step is dropped here.
            while rec.dropped() == 0 && !queue_has_room(&rec) {
                std::thread::yield_now();
            }
        }
    }
    (look.shapes.len(), look.labels.len(), rec.finish())
}

fn queue_has_room(rec: &WorldRecording) -> bool {
    rec.queued() < QUEUE_STEPS / 2
}

#[test]
fn the_mcap_crates_reader_lists_the_world_channels_and_schemas_and_the_drawing_decodes() {
    let p = temp("boxing.world.mcap");
    let (shapes, labels, rep) = record_scene("boxing", &p, 600);
    assert_eq!((rep.steps, rep.dropped, rep.write_failed, rep.error.clone()), (600, 0, 0, None), "{rep}");
    let bytes = std::fs::read(&p).unwrap();
    let (summary, topics) = crate::tests::mcap_topics(&bytes);
    let want = |t: &str, s: &str| (t.to_string(), s.to_string(), "ros2msg".to_string(), "cdr".to_string());
    assert_eq!(
        topics,
        vec![
            want(TOPIC_BOXER, "spidar/Boxer"),
            want(TOPIC_CROWD, "spidar/Crowd"),
            want(TOPIC_WORLD_EVENT, "spidar/WorldEvent"),
            want(TOPIC_GAZE, "spidar/Gaze"),
            want(TOPIC_GAZE_DRAWN, "foxglove_msgs/msg/SceneUpdate"),
            want(TOPIC_LABELS, "foxglove_msgs/msg/SceneUpdate"),
            want(TOPIC_SCENE, "foxglove_msgs/msg/SceneUpdate"),
            want(TOPIC_SKELETONS, "foxglove_msgs/msg/SceneUpdate"),
            want(TOPIC_STEP, "spidar/WorldStep"),
            want(TOPIC_TF, "foxglove_msgs/msg/FrameTransforms"),
            want(TOPIC_VIEW, "spidar/ViewFrame"),
        ]
    );
    assert!(summary.chunk_indexes.iter().all(|c| c.compression == "zstd"));
    // No chunk of schemas and channels alone (its index would start the recording in 1970).
    let stats = summary.stats.as_ref().expect("statistics");
    assert!(summary.chunk_indexes.iter().all(|c| c.message_start_time >= stats.message_start_time));
    assert!(stats.message_start_time > 1_000_000_000 * 1_600_000_000, "a start after 2020");
    // Every message, streamed by the mcap crate.
    let mut per_topic = BTreeMap::<String, u64>::new();
    let (mut first_scene, mut first_labels, mut last_tf) = (None, None, None);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        *per_topic.entry(m.channel.topic.clone()).or_default() += 1;
        match m.channel.topic.as_str() {
            TOPIC_SCENE if first_scene.is_none() => first_scene = Some(m.data.into_owned()),
            TOPIC_LABELS if first_labels.is_none() => first_labels = Some(m.data.into_owned()),
            TOPIC_TF => last_tf = Some(m.data.into_owned()),
            _ => {}
        }
    }
    for t in [TOPIC_STEP, TOPIC_TF, TOPIC_BOXER, TOPIC_GAZE] {
        assert_eq!(per_topic[t], 600, "{t}: one per step");
    }
    assert_eq!(per_topic[TOPIC_GAZE_DRAWN], per_topic[TOPIC_VIEW], "the gaze's arrow at the view's rate");
    assert!(!per_topic.contains_key(TOPIC_CROWD), "no crowd in boxing");
    assert!(per_topic[TOPIC_WORLD_EVENT] >= 3, "the first behaviours at least: {per_topic:?}");
    // Every body has its frame, and the first scene update draws every one in its frame.
    let tf: FrameTransforms = cdr::decode(&last_tf.unwrap()).unwrap();
    assert_eq!(
        tf.transforms.len(),
        2 + shapes + labels,
        "the world under its z-up root, the link frame, every moving shape, every label's frame"
    );
    assert!(tf.transforms.iter().any(|t| t.child_frame_id == "virtual_human/head"), "{:?}", tf.transforms);
    assert_eq!(
        (tf.transforms[0].parent_frame_id.as_str(), tf.transforms[0].child_frame_id.as_str()),
        (Z_UP_FRAME, WORLD_FRAME)
    );
    assert!(tf.transforms[1..].iter().all(|t| t.parent_frame_id == WORLD_FRAME));
    let q = &tf.transforms[3].rotation;
    assert!(((q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1.0).abs() < 1e-5, "a unit quaternion");
    let scene: SceneUpdate = cdr::decode(&first_scene.unwrap()).unwrap();
    assert_eq!(scene.entities.len(), shapes, "every shape");
    let label_update: SceneUpdate = cdr::decode(&first_labels.unwrap()).unwrap();
    assert_eq!(label_update.entities.len(), labels, "every behaviour label");
    for e in &scene.entities[..shapes] {
        assert!(e.frame_locked && tf.transforms.iter().any(|t| t.child_frame_id == e.frame_id), "{}", e.id);
        assert!(!(e.spheres.is_empty() && e.cylinders.is_empty() && e.cubes.is_empty()), "{} is drawn", e.id);
    }
    // The Foxglove schemas name their nested types the ROS 2 way.
    let s = cdr::schema_text::<SceneUpdate>();
    assert!(s.starts_with(
        "foxglove_msgs/SceneEntityDeletion[] deletions\nfoxglove_msgs/SceneEntity[] entities\n"
    ));
    for t in [
        "foxglove_msgs/SceneEntity",
        "foxglove_msgs/CylinderPrimitive",
        "geometry_msgs/Pose",
        "builtin_interfaces/Time",
    ] {
        assert_eq!(s.matches(&format!("MSG: {t}\n")).count(), 1, "{t}");
    }
    assert!(s.contains("\nuint8 type\n"), "the raw identifier is named as the schema names it");
    // spidar's own reader and summary agree.
    let w = summarize(&p).unwrap();
    assert_eq!((w.steps, w.recording.ending.clone()), (600, Some(Ending::Complete)));
    assert_eq!(w.recording.meta("role"), "world");
    assert!(w.boxer.is_some());
}

/// The virtual human's gaze on `/world/gaze` is what the scene had at each step, read back
/// exactly (the same bout stepped again without a recorder: the boxing world is deterministic);
/// it turns to the jabbing fist; the CSV export has it; `/world/gaze/drawn` is an arrow from the
/// eyes along the gaze, as long as the distance to the point looked at.
#[test]
fn the_virtual_humans_gaze_is_recorded_step_by_step_and_read_back() {
    struct Gazes(std::sync::Arc<std::sync::Mutex<Vec<GazeMsg>>>);
    impl spidar_world::Observer for Gazes {
        fn after_step(&mut self, s: &spidar_world::StepView<'_>) {
            let d = s.scene.decisions().unwrap();
            self.0.lock().unwrap().push(GazeMsg::of(s.t_s, &d.gaze));
        }
    }
    let p = temp("gaze.world.mcap");
    let (_, _, rep) = record_scene("boxing", &p, 900);
    assert_eq!((rep.steps, rep.dropped), (900, 0), "{rep}");
    let truth = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let mut st = Stepper::new(spidar_world::load("boxing").unwrap());
    st.add_observer(Box::new(Gazes(truth.clone())));
    let geometry = spidar_rt::status::rig_info(&spidar_rt::rig::Rig::default_rig());
    for k in 0..900 {
        let t = st.step_s() * (k + 1) as f64;
        st.step(t, &[sample(k, t)], Some(&geometry), Some(&rig_status(k)));
    }
    let (mut read, mut arrows) = (Vec::new(), Vec::new());
    reader::read(&p, |_, m| {
        let reader::Msg::Other { channel, data, .. } = m else { return Ok(reader::Flow::Continue) };
        match channel.topic.as_str() {
            TOPIC_GAZE => match decode(&channel.topic, &channel.schema, data) {
                Some(Ok(WorldMsg::Gaze(g))) => read.push(g),
                other => panic!("{other:?}"),
            },
            TOPIC_GAZE_DRAWN => arrows.push(cdr::decode::<SceneUpdate>(data).unwrap()),
            _ => {}
        }
        Ok(reader::Flow::Continue)
    })
    .unwrap();
    let truth = truth.lock().unwrap();
    assert_eq!(read.len(), 900);
    assert_eq!(read, *truth, "every step's gaze, exactly");
    let attended = read.iter().filter(|g| g.attended == 1).count();
    assert!(attended > 20, "the left fist's jabs are attended: {attended} steps");
    assert!(read.iter().all(|g| (g.dir.length() - 1.0).abs() < 1e-9));
    // The arrows: at the view's rate, each from the eyes of a recorded step, along its gaze.
    assert!(arrows.len() >= 900 / 6 - 1, "{} arrows", arrows.len());
    for u in &arrows {
        let e = &u.entities[0];
        let a = &e.arrows[0];
        let eye = DVec3::new(a.pose.position.x, a.pose.position.y, a.pose.position.z);
        let g = read
            .iter()
            .find(|g| (g.eye_m - eye).length() < 1e-12)
            .expect("an arrow from a recorded step's eyes");
        let q = glam::DQuat::from_xyzw(
            a.pose.orientation.x,
            a.pose.orientation.y,
            a.pose.orientation.z,
            a.pose.orientation.w,
        );
        assert!((q * DVec3::X - g.dir).length() < 1e-9, "along the gaze");
        assert!((a.shaft_length + a.head_length - (g.at_m - g.eye_m).length()).abs() < 1e-9);
        assert_eq!(e.frame_id, WORLD_FRAME);
    }
    let w = summarize(&p).unwrap();
    assert_eq!(
        (w.gaze_steps, w.gaze_attended_steps),
        (900, read.iter().filter(|g| g.attended > 0).count() as u64)
    );
    assert!(w.to_string().contains("its gaze"), "{w}");
    let dir = temp("gaze-csv");
    let rep = crate::export::export_world_csv(&p, &dir).unwrap();
    let csv = std::fs::read_to_string(dir.join("world_gaze.csv")).unwrap();
    assert_eq!(csv.lines().count(), 901, "a header and a row per step: {:?}", rep.files);
}

#[test]
fn a_crowd_recording_carries_every_characters_state_and_frame() {
    let p = temp("crowd.world.mcap");
    let (_, _, rep) = record_scene("crowd", &p, 200);
    assert_eq!(rep.steps, 200, "{rep}");
    // As many as the shipped crowd scene holds (its look says how many).
    let n =
        spidar_world::load("crowd").unwrap().look().crowd.expect("the crowd scene has a crowd").characters;
    assert!(n >= 2, "{n} characters");
    let w = summarize(&p).unwrap();
    assert_eq!(w.characters, n);
    assert!(w.events >= n as u64, "every character's first state is an event: {}", w.events);
    let mut crowd = 0;
    let mut figures = 0;
    let joints = spidar_world::load("crowd").unwrap().look().crowd.unwrap().joints.len();
    reader::read(&p, |_, m| {
        if let reader::Msg::Other { channel, data, .. } = m {
            if channel.topic == TOPIC_TF {
                let tf: FrameTransforms = cdr::decode(data).unwrap();
                assert_eq!(tf.transforms.len(), n + 2, "the z-up root, the link frame and one per character");
            }
            if channel.topic == TOPIC_SKELETONS {
                // Each character's drawn figure, in its body frame (origin at the centre of mass,
                // 0.75 m above the floor): every bone a segment, standing on the floor.
                let u: SceneUpdate = cdr::decode(data).unwrap();
                for e in u.entities.iter().filter(|e| e.frame_id.starts_with("character/")) {
                    let pts = &e.lines[0].points;
                    assert_eq!(pts.len(), 2 * (joints - 1), "{}: one segment per bone", e.id);
                    let lo = pts.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
                    let hi = pts.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
                    assert!((-0.75..-0.6).contains(&lo), "{}: its ankles are {lo} m from its centre", e.id);
                    assert!((0.55..0.8).contains(&hi), "{}: its head is {hi} m above its centre", e.id);
                    figures += 1;
                }
            }
            if let Some(Ok(WorldMsg::Crowd(c))) = decode(&channel.topic, &channel.schema, data) {
                assert_eq!(c.states.len(), n);
                crowd += 1;
            }
        }
        Ok(reader::Flow::Continue)
    })
    .unwrap();
    assert_eq!(crowd, 200);
    assert!(figures >= 30 * n, "figures at display rate: {figures}");
}

#[test]
fn the_stepping_thread_drops_and_counts_a_step_when_every_buffer_is_queued() {
    let p = temp("full.world.mcap");
    let scene = spidar_world::load("walls").unwrap();
    let look = scene.look();
    let (rec, obs) = WorldRecording::start(&p, &WorldInfo::default(), &look).unwrap();
    // Take every free buffer away, as a writer stuck on the disk would keep them.
    let mut held = Vec::new();
    while let Ok(b) = obs.free.try_recv() {
        held.push(b);
    }
    assert_eq!(held.len(), QUEUE_STEPS);
    let mut st = Stepper::new(scene);
    st.add_observer(Box::new(obs));
    for k in 0..5u64 {
        let t = 0.003 * (k + 1) as f64;
        st.step(t, &[sample(k, t)], None, None);
    }
    assert_eq!(rec.dropped(), 5, "each step found no buffer: dropped, counted, never waited for");
    let r = rec.finish();
    assert_eq!((r.steps, r.dropped), (0, 5), "{r}");
    let meta = summarize(&p).unwrap().recording.end_meta.unwrap();
    assert_eq!(meta["steps_dropped"], "5");
}

/// A crowd's recording, whose figures the writer draws from the states the stepping thread copied,
/// keeps what the stepping thread used to draw itself: every `/world/view` frame is the frame
/// written with its figures at that step (bit for bit), and every skeleton drawn (at display rate
/// and when a character's state changes) is that step's figure. Over pushes that topple
/// characters (their state changes are events).
#[test]
fn a_crowd_recording_keeps_the_figures_of_each_step() {
    use spidar_world::view::FrameMaker;
    use spidar_world::{Observer, Scene, StepView};
    let p = temp("crowd-figures.world.mcap");
    let mut scene = spidar_world::crowd::CrowdScene::builtin().unwrap();
    let look = scene.look();
    let info = WorldInfo { start_unix_ns: Some(0), ..Default::default() };
    let (rec, mut obs) = WorldRecording::start(&p, &info, &look).unwrap();
    let mut reference = FrameMaker::new(&look);
    let l = *reference.layout();
    // Each step's frame written with its figures, by its log time; and whether it was a view frame.
    let mut want = std::collections::HashMap::<u64, (Vec<f32>, bool)>::new();
    let mut next_view = f64::NEG_INFINITY;
    let n = scene.crowd.len();
    for k in 0..1500u64 {
        if k % 150 == 40 {
            let i = (k / 150) as usize % n;
            let b = scene.crowd.body_space(i);
            scene.crowd.add_impulse_at(i, b.r_m + DVec3::Y * 0.5, DVec3::X * 150.0);
        }
        let t = 0.003 * (k + 1) as f64;
        let s = sample(k, t);
        let m = scene.step(t, std::slice::from_ref(&s));
        let v = StepView {
            t_s: t,
            scene: &scene,
            samples: std::slice::from_ref(&s),
            model: &m,
            rig_info: None,
            rig_status: None,
        };
        obs.after_step(&v);
        reference.observe(&v, true);
        let view = t >= next_view;
        if view {
            next_view = t + VIEW_EVERY_S;
        }
        let mut f = vec![0.0; l.max_words];
        let words = reference.write(&mut f, &v, view, true);
        f.truncate(words);
        want.insert((t * 1e9).round() as u64, (f, view));
        // The writer keeps up (fewer steps queued than figure buffers): no step is dropped here.
        while rec.queued() > 32 {
            std::thread::yield_now();
        }
    }
    let rep = rec.finish();
    assert_eq!((rep.steps, rep.dropped), (1500, 0), "{rep}");
    let crowd_look = look.crowd.as_ref().unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let (mut views, mut skeletons, mut changes) = (0, 0, 0);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let Some((frame, view)) = want.get(&m.log_time) else { continue };
        match m.channel.topic.as_str() {
            TOPIC_VIEW => {
                let v: ViewFrameMsg = cdr::decode(&m.data).unwrap();
                assert!(view, "a view frame at a step that had none");
                let bits = |f: &[f32]| f.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&v.frame), bits(frame), "the view frame at {} ns", m.log_time);
                views += 1;
            }
            TOPIC_SKELETONS => {
                let u: SceneUpdate = cdr::decode(&m.data).unwrap();
                assert_eq!(u.entities.len(), n, "every character in every message");
                for e in u.entities.iter().filter(|e| e.id.starts_with("character/")) {
                    let i: usize = e.id["character/".len()..].parse().unwrap();
                    let c = &frame[l.characters_at + i * l.character_floats..][..l.character_floats];
                    let drawn = skeleton(crowd_look, c, e.lines[0].color);
                    assert_eq!(e.lines[0].points, drawn.points, "{} at {} ns", e.id, m.log_time);
                    skeletons += 1;
                }
            }
            TOPIC_WORLD_EVENT => {
                let ev: WorldEventMsg = cdr::decode(&m.data).unwrap();
                changes += usize::from(ev.kind == EVENT_CHARACTER);
            }
            _ => {}
        }
    }
    assert!(views >= 250, "{views} view frames compared");
    assert!(skeletons >= 250 * n, "{skeletons} skeletons compared");
    assert!(changes > 2 * n, "{changes} character state changes: the pushes toppled no one");
}

/// Steps that draw a crowd's figures when every buffer of figure states is still with the writer
/// are dropped and counted, never waited for.
#[test]
fn a_crowd_step_without_a_free_figure_buffer_is_dropped_and_counted() {
    let p = temp("no-figures.world.mcap");
    let scene = spidar_world::load("crowd").unwrap();
    let look = scene.look();
    let (rec, obs) = WorldRecording::start(&p, &WorldInfo::default(), &look).unwrap();
    let mut held = Vec::new();
    while let Ok(b) = obs.figures_free.try_recv() {
        held.push(b);
    }
    assert_eq!(held.len(), FIGURE_BUFFERS);
    let mut st = Stepper::new(scene);
    st.add_observer(Box::new(obs));
    for k in 0..5u64 {
        let t = 0.003 * (k + 1) as f64;
        st.step(t, &[sample(k, t)], None, None);
    }
    // The first step draws the skeletons; no step was kept, so each next one does too.
    assert_eq!(rec.dropped(), 5);
    let r = rec.finish();
    assert_eq!((r.steps, r.dropped), (0, 5), "{r}");
}

/// Run by `a_killed_world_leaves_a_recording_read_up_to_its_last_chunk` as its own child
/// process (skipped otherwise): a boxing world recording until killed.
#[test]
#[ignore = "the child process of the kill test"]
fn child_records_a_world_until_killed() {
    let Ok(path) = std::env::var("SPIDAR_WORLD_RECORD_CHILD") else { return };
    let scene = spidar_world::load("boxing").unwrap();
    let look = scene.look();
    let (rec, obs) = WorldRecording::start(Path::new(&path), &WorldInfo::default(), &look).unwrap();
    let mut st = Stepper::new(scene);
    st.add_observer(Box::new(obs));
    // Ends by itself if nobody kills it (about 100 s).
    for k in 0..100_000u64 {
        let t = 0.003 * (k + 1) as f64;
        st.step(t, &[sample(k, t)], None, None);
        std::thread::sleep(std::time::Duration::from_micros(500));
    }
    rec.finish();
}

#[test]
fn a_killed_world_leaves_a_recording_read_up_to_its_last_chunk() {
    let path = temp("killed.world.mcap");
    let _ = std::fs::remove_file(&path);
    let mut child = spidar_testkit::spawn_test_child(
        "world_tests::child_records_a_world_until_killed",
        "SPIDAR_WORLD_RECORD_CHILD",
        Path::new(&path),
    );
    // Wait until two or more chunks are on disk, then SIGKILL.
    spidar_testkit::kill_once_written(
        &mut child,
        Path::new(&path),
        400_000,
        std::time::Duration::from_secs(100),
    );
    let mut steps = Vec::new();
    let rec = reader::read(&path, |_, m| {
        if let reader::Msg::Other { channel, data, .. } = m {
            if let Some(Ok(WorldMsg::Step(s))) = decode(&channel.topic, &channel.schema, data) {
                steps.push(s.step);
            }
        }
        Ok(reader::Flow::Continue)
    })
    .unwrap();
    assert!(matches!(rec.ending, Some(Ending::CutShort { .. })), "{:?}", rec.ending);
    assert!(rec.end_meta.is_none(), "the world never ended normally");
    assert!(steps.len() > 300, "{} steps read", steps.len());
    assert_eq!(steps.first(), Some(&1));
    assert!(steps.windows(2).all(|w| w[1] == w[0] + 1), "consecutive steps, none lost in the file");
    let w = summarize(&path).unwrap();
    assert_eq!(w.steps, steps.len() as u64);
    assert!(w.to_string().contains("cut short"), "{w}");
}

#[test]
fn docs_list_every_world_schema_as_implemented() {
    let docs = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/recording.md")).unwrap();
    for (name, text) in [
        ("spidar/WorldStep", cdr::schema_text::<WorldStep>()),
        ("spidar/Boxer", cdr::schema_text::<BoxerMsg>()),
        ("spidar/Gaze", cdr::schema_text::<GazeMsg>()),
        ("spidar/Crowd", cdr::schema_text::<CrowdMsg>()),
        ("spidar/WorldEvent", cdr::schema_text::<WorldEventMsg>()),
        ("spidar/ViewFrame", cdr::schema_text::<ViewFrameMsg>()),
    ] {
        if std::env::var("SPIDAR_PRINT_SCHEMAS").is_ok() {
            println!("### `{name}`\n\n```\n{text}```\n");
            continue;
        }
        assert!(
            docs.contains(&text),
            "docs/recording.md does not list the schema of {name} as written:\n{text}"
        );
    }
    let _ = BoxerMsg::ros_type();
}
