//! `spidar replay` into the view: a boxing bout recorded as `spidar run --virtual --record` records
//! it (the simulated rig, the rt-loop, the world and its recorder), played into the live view's
//! page in chromium (`tests/browser/view.mjs replay`) and to raw WebSocket viewers.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::Duration;

use glam::{DQuat, DVec3};
use serde_json::{json, Value};
use spidar_record::foxglove::FrameTransforms;
use spidar_record::reader::{self, Flow, Msg};
use spidar_record::world::{world_path, ViewFrameMsg, WorldStep, TOPIC_STEP, TOPIC_TF, TOPIC_VIEW};
use spidar_runtime::replay_view::{Replay, ReplayOptions};
use spidar_world::view::{ViewHandle, ViewOptions};

use super::view::{any_port, browser_here, node, one_at_a_time};
use super::*;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spidar-hil-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// `spidar run --virtual --seconds SECONDS --record PATH` on the boxing scene with the box script:
/// the rig's file at `path`, the world's next to it. Returns the world's file.
fn record_boxing(path: &Path, seconds: f64) -> PathBuf {
    let r = rig();
    let dev = sim_device(&r, load_scripts("box", &r, 1).unwrap(), &SimOptions::default()).unwrap();
    let info = spidar_runtime::recording::session_info(None, "boxing", "box", "Sim", 1, true).unwrap();
    let recorder = spidar_runtime::recording::create(path, &info).unwrap();
    let scene = spidar_world::load("boxing").unwrap();
    let wpath = world_path(path);
    let (wrec, obs) = spidar_runtime::recording::start_world_recording(
        &wpath,
        "boxing",
        &*scene,
        true,
        Some(recorder.start_unix_ns()),
    )
    .unwrap();
    let opts = spidar_runtime::session::VirtualOptions {
        seconds,
        stop: spidar_runtime::signals::Stop::detached(),
        progress: false,
        device: "Sim".into(),
        scene_name: "boxing".into(),
        script_name: "box".into(),
        supervisor: None,
        recorder: Some(recorder),
        observers: vec![Box::new(obs)],
    };
    let sum = spidar_runtime::session::run_virtual(dev, &r, scene, opts).unwrap();
    assert!(sum.counters.active_ticks > 1000, "{sum}");
    let w = wrec.finish();
    assert_eq!((w.dropped, w.write_failed, w.error.clone()), (0, 0, None), "{w}");
    wpath
}

/// A 10 s bout, recorded once for the tests here.
fn bout() -> &'static Recorded {
    static B: OnceLock<Recorded> = OnceLock::new();
    B.get_or_init(|| Recorded::read(&record_boxing(&temp("bout.mcap"), 10.0)))
}

/// What a world recording says, read front to back by the plain reader: the virtual human's head
/// at every step (`/world/tf`), and the time of every view frame (`/world/view`).
struct Recorded {
    world: PathBuf,
    head: Vec<(f64, DVec3, DQuat)>,
    frames: Vec<f64>,
}

impl Recorded {
    fn read(world: &Path) -> Recorded {
        let (mut head, mut frames, mut t) = (Vec::new(), Vec::new(), 0.0);
        reader::read(world, |_, m| {
            if let Msg::Other { channel, data, .. } = m {
                match channel.topic.as_str() {
                    TOPIC_STEP => t = spidar_record::cdr::decode::<WorldStep>(data).unwrap().t_s,
                    TOPIC_TF => {
                        let tf: FrameTransforms = spidar_record::cdr::decode(data).unwrap();
                        let h =
                            tf.transforms.iter().find(|x| x.child_frame_id == "virtual_human/head").unwrap();
                        let (p, q) = (&h.translation, &h.rotation);
                        head.push((t, DVec3::new(p.x, p.y, p.z), DQuat::from_xyzw(q.x, q.y, q.z, q.w)));
                    }
                    TOPIC_VIEW => frames.push(spidar_record::cdr::decode::<ViewFrameMsg>(data).unwrap().t_s),
                    _ => {}
                }
            }
            Ok(Flow::Continue)
        })
        .unwrap();
        assert!(head.len() > 500 && frames.len() > 100, "{} steps, {} frames", head.len(), frames.len());
        Recorded { world: world.to_path_buf(), head, frames }
    }

    /// The page's head pose `v` (position, quaternion) at frame time `t` is the recording's.
    fn check_head(&self, t: f64, v: &[Value]) {
        let f = |i: usize| v[i].as_f64().unwrap();
        let &(ts, p, q) =
            self.head.iter().min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs())).unwrap();
        assert!((ts - t).abs() < 1e-5 * t.max(1.0), "no recorded step at t = {t} (nearest {ts})");
        let d = (p - DVec3::new(f(0), f(1), f(2))).length();
        assert!(d < 1e-4, "the head is drawn {d} m from where the recording has it at t = {t}");
        let dq = DQuat::from_xyzw(f(3), f(4), f(5), f(6));
        assert!(q.dot(dq).abs() > 1.0 - 1e-5, "the head's rotation {dq} is not the recording's {q}");
    }

    fn answer(&self, q: &Value) -> Value {
        let f = |k: &str| q[k].as_f64().unwrap();
        match q["ask"].as_str().unwrap() {
            "check_pose" => {
                self.check_head(f("t"), q["head"].as_array().unwrap());
                json!({"ok": true})
            }
            "check_seek" => {
                // The frame shown is the recording's last frame at or before the time asked.
                let asked = f("asked");
                let want = self.frames.iter().rev().find(|t| **t <= asked).copied().unwrap_or(self.frames[0]);
                assert_eq!(
                    f("t") as f32,
                    want as f32,
                    "after a seek to {asked} s the page shows t = {}",
                    f("t")
                );
                self.check_head(f("t"), q["head"].as_array().unwrap());
                json!({"ok": true, "frame_t": want})
            }
            other => json!({"error": format!("unknown question {other}")}),
        }
    }
}

/// A replay served on its own thread, as `spidar replay` serves it.
struct Serving {
    url: String,
    ws: String,
    handle: ViewHandle,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Serving {
    fn start(world: &Path, view: ViewOptions) -> Serving {
        Serving::with(world, &ReplayOptions { view, from_s: None, speed: 1.0, play: false })
    }

    fn with(world: &Path, o: &ReplayOptions) -> Serving {
        let r = Replay::start(world, o).unwrap();
        let (url, ws, handle) = (r.url().to_string(), r.ws_url().to_string(), r.handle());
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let thread = std::thread::spawn(move || r.run(&|| s.load(Ordering::Relaxed)).unwrap());
        Serving { url, ws, handle, stop, thread: Some(thread) }
    }
}

impl Drop for Serving {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A recorded bout played into the view in chromium: frames arrive, the virtual human is drawn
/// where the recording has it, pause stops the time, a seek jumps there, and 2x plays twice as fast
/// by the replay's own clock; a second browser sees the same.
#[test]
fn replay_a_recorded_bout_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("replay_a_recorded_bout_in_a_browser") {
        return;
    }
    let rec = bout();
    let s = Serving::start(&rec.world, any_port());
    node(&["replay", &s.url], |q| rec.answer(q));
    assert!(s.handle.counters().frames_sent.load(Ordering::Relaxed) > 100);
}

/// A WebSocket viewer of a replay: counts its frames and keeps the newest playback message. Sends
/// what is put into `send`.
struct RawViewer {
    frames: Arc<AtomicU64>,
    last_playback: Arc<std::sync::Mutex<Option<Value>>>,
    send: crossbeam_channel::Sender<String>,
    thread: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
}

impl RawViewer {
    fn connect(ws_url: &str) -> RawViewer {
        let (frames, last_playback) = (Arc::new(AtomicU64::new(0)), Arc::new(std::sync::Mutex::new(None)));
        let stop = Arc::new(AtomicBool::new(false));
        let (send, rx) = crossbeam_channel::unbounded::<String>();
        let addr = ws_url.trim_start_matches("ws://").to_string();
        let stream = std::net::TcpStream::connect(&addr).unwrap();
        let (mut ws, _) = tungstenite::client(format!("{ws_url}/"), stream).unwrap();
        ws.get_mut().set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        let (f, p, st) = (frames.clone(), last_playback.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            while !st.load(Ordering::Relaxed) {
                for c in rx.try_iter() {
                    let _ = ws.send(tungstenite::Message::text(c));
                }
                match ws.read() {
                    Ok(tungstenite::Message::Binary(_)) => {
                        f.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(tungstenite::Message::Text(t)) => {
                        let v: Value = serde_json::from_str(t.as_str()).unwrap();
                        if v["type"] == "playback" {
                            *p.lock().unwrap() = Some(v);
                        }
                    }
                    Ok(_) => {}
                    Err(tungstenite::Error::Io(e))
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) => {}
                    Err(_) => break,
                }
            }
        });
        RawViewer { frames, last_playback, send, thread: Some(thread), stop }
    }

    fn playback(&self) -> Option<Value> {
        self.last_playback.lock().unwrap().clone()
    }

    /// Waits (up to a minute, a bound against hanging, not a measure) until `ok` holds.
    fn until(&self, what: &str, ok: impl Fn(&RawViewer) -> bool) {
        for _ in 0..6000 {
            if ok(self) {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        panic!("never: {what}; last playback {:?}", self.playback());
    }
}

impl Drop for RawViewer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A recording cut short (the session killed) plays up to where it ends and says so; three viewers
/// get its frames, and one viewer's commands move everyone's playback. (A viewer that stops
/// reading is dropped by the same server code as the live view's.)
#[test]
fn replay_of_a_recording_cut_short_plays_to_its_end_to_every_viewer() {
    let rec = bout();
    let cut = temp("cut.world.mcap");
    let bytes = std::fs::read(&rec.world).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let truth = Recorded::read(&cut);
    let s = Serving::start(&cut, any_port());
    let viewers: Vec<RawViewer> = (0..3).map(|_| RawViewer::connect(&s.ws)).collect();
    for v in &viewers {
        v.until("a playback message", |v| v.playback().is_some());
    }
    let p = viewers[0].playback().unwrap();
    let last = *truth.frames.last().unwrap();
    assert_eq!(p["complete"], false);
    assert!(p["ends"].as_str().unwrap().contains("cut short"), "{p}");
    assert_eq!(p["last_s"].as_f64(), Some(last), "it plays to the last frame of the last whole chunk");
    assert!(last < rec.frames.last().unwrap() - 2.0, "the cut took seconds off: {last}");
    // One viewer plays at 4x; everyone's playback moves to the end.
    viewers[1].send.send(json!({"cmd": "speed", "x": 4}).to_string()).unwrap();
    viewers[1].send.send(json!({"cmd": "play"}).to_string()).unwrap();
    for v in &viewers {
        v.until("the end of the recording", |v| {
            v.playback().is_some_and(|p| p["at_end"] == true && p["playing"] == false && p["speed"] == 4.0)
        });
        // (About 55 frames a second of recording, a sixth of a second each at 4x: most reach it.)
        assert!(v.frames.load(Ordering::Relaxed) > 10, "{} frames", v.frames.load(Ordering::Relaxed));
    }
    let p = viewers[2].playback().unwrap();
    assert_eq!((p["t_s"].as_f64(), p["frame_t_s"].as_f64()), (Some(last), Some(last)));
    assert_eq!(s.handle.counters().viewers.load(Ordering::Relaxed), 3);
}

/// The README's picture of a replay (`docs/img/replay.png`), taken by the same harness: the bout
/// playing from 3 s, with the playback bar.
/// `cargo test -p spidar-tests --test hil replay_screenshot_for_the_readme -- --ignored`
#[test]
#[ignore = "writes docs/img: run by hand"]
fn replay_screenshot_for_the_readme() {
    if !browser_here("replay_screenshot_for_the_readme") {
        return;
    }
    let _one = one_at_a_time();
    let img = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/img/replay.png");
    let o = ReplayOptions { view: any_port(), from_s: Some(3.0), speed: 1.0, play: true };
    let s = Serving::with(&bout().world, &o);
    node(&["screenshot", &s.url, "orbit", img.to_str().unwrap(), "2"], |_| json!({"error": "no questions"}));
}

/// A measurement (docs/view.md): the frames one and three browsers each receive per second from a
/// replay of the bout playing at 1x.
/// `cargo test -p spidar-tests --test hil replay_frame_rate_to_browsers -- --ignored --nocapture`
#[test]
#[ignore = "a measurement: run by hand"]
fn replay_frame_rate_to_browsers() {
    if !browser_here("replay_frame_rate_to_browsers") {
        return;
    }
    let _one = one_at_a_time();
    for n in ["1", "3"] {
        let s = Serving::start(&bout().world, any_port());
        node(&["rate", &s.url, n, "6"], |_| json!({"error": "no questions"}));
    }
}

/// `GET path` from a view server at `url`: the JSON it answers.
fn http_json(url: &str, path: &str) -> Value {
    use std::io::{Read, Write};
    let host = url.trim_start_matches("http://");
    let mut c = std::net::TcpStream::connect(host).unwrap();
    // A bound against hanging, not a measure.
    c.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(c, "GET {path} HTTP/1.0\r\nHost: {host}\r\nConnection: close\r\n\r\n").unwrap();
    let mut text = String::new();
    c.read_to_string(&mut text).unwrap();
    let (_, body) = text.split_once("\r\n\r\n").expect("an HTTP answer");
    serde_json::from_str(body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
}

/// A replay's frames mark the near strings as the live view's do (docs/view.md): the broadcaster
/// marks each frame from the hands it shows and the recorded rig geometry (a recording keeps no
/// `near_strings`: the defaults, which the shipped rig file states). Every frame's flags are the
/// near mask of its own grips, and the bout has frames with strings marked.
#[test]
fn replay_frames_mark_the_near_strings_of_the_hands_they_show() {
    use spidar_world::view::rigview::{near_mask, NearStrings};
    use spidar_world::view::{GLOBALS_AT, HANDS_AT, HAND_FLOATS};
    let rec = bout();
    let s =
        Serving::with(&rec.world, &ReplayOptions { view: any_port(), from_s: None, speed: 1.0, play: true });
    let o = &http_json(&s.url, "/scene.json")["link_offset_m"];
    let offset = DVec3::new(o[0].as_f64().unwrap(), o[1].as_f64().unwrap(), o[2].as_f64().unwrap());
    let near = NearStrings::new(&spidar_rt::status::rig_info(&rig()), offset);
    let stream = std::net::TcpStream::connect(s.ws.trim_start_matches("ws://")).unwrap();
    // Bounds against hanging (the handshake's too), not measures.
    stream.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let (mut ws, _) = tungstenite::client(format!("{}/", s.ws), stream).unwrap();
    ws.get_mut().set_read_timeout(Some(Duration::from_millis(200))).unwrap();
    let (mut frames, mut marked) = (0, 0);
    let until = std::time::Instant::now() + Duration::from_secs(60);
    while frames < 300 && std::time::Instant::now() < until {
        let b = match ws.read() {
            Ok(tungstenite::Message::Binary(b)) => b,
            Ok(_) => continue,
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
            {
                continue
            }
            Err(e) => panic!("the replay's socket: {e}"),
        };
        let word = |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let float = |i: usize| f32::from_bits(word(i)) as f64;
        let valid = float(GLOBALS_AT + 3) as u32;
        let grips: [Option<DVec3>; 2] = std::array::from_fn(|h| {
            let at = HANDS_AT + h * HAND_FLOATS;
            ((valid >> h) & 1 == 1).then(|| DVec3::new(float(at), float(at + 1), float(at + 2)))
        });
        let mask = near_mask(&near.anchors_m, grips, near.near_m, &near.forearm);
        assert_eq!(word(3) & 0xffff, mask, "frame {frames}: grips {grips:?}");
        frames += 1;
        marked += (mask != 0) as usize;
    }
    // (Any number: each frame is checked; a loaded machine sends fewer.)
    assert!(frames >= 30, "{frames} frames in a minute");
    assert!(marked > 0, "no frame of {frames} had a string near another or a forearm");
    eprintln!("{marked} of {frames} replayed frames have near strings marked");
}
