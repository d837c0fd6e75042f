//! The live view: the world hosted by `spidar run`'s scene thread with the view as its observer,
//! watched by Debian's chromium through puppeteer-core (`tests/browser/`), and by raw WebSocket
//! clients.
//!
//! The browser tests need node, chromium and `npm ci` in `tests/browser`; without them they say so
//! loudly and pass, unless `SPIDAR_BROWSER_TESTS=required` (set by `.ci/run`), which makes a
//! missing browser a failure.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use glam::{DQuat, DVec3};
use serde_json::{json, Value};
use spidar_link::channel::ChannelWorldEnd;
use spidar_msg::{ContactModel, HandSample, HandState, RigState, RigStatus};
use spidar_rt::status::rig_info;
use spidar_rt::{Clock, MonotonicClock};
use spidar_sim::character::controller::Policy;
use spidar_sim::character::keyframe::Pose as SkeletonPose;
use spidar_tools::scene_thread::{self, SceneCounters};
use spidar_world::boxing::BoxingScene;
use spidar_world::crowd::CrowdScene;
use spidar_world::host::Stepper;
use spidar_world::view::{View, ViewHandle, ViewOptions};
use spidar_world::{Observer, Scene, StepView};

use super::{forbidden_allocs, no_alloc, rig};

// ---------------------------------------------------------------------------------------------
// A world hosted as `spidar run` hosts it, with the test's hands, pushes and a pause.

#[derive(Default)]
struct Ctl {
    /// Stop stepping the world (it stays where it is; the host's steps, samples, frames and the
    /// records go on).
    hold: AtomicBool,
    /// Loop-clock time (bits of an f64; 0: none) the scripted punch starts at.
    punch_at: AtomicU64,
    /// A character to push over at the next step.
    push: Mutex<Option<usize>>,
}

/// What the world was after one step.
#[derive(Clone)]
struct Rec {
    t: f64,
    /// Boxing: every shape's pose. Crowd: every character's body pose.
    parts: Vec<(DVec3, DQuat)>,
    /// Crowd: every character's skeleton pose and policy.
    skeletons: Vec<(SkeletonPose, Policy)>,
    counters: Vec<f64>,
}

/// The scene behind the view, recording itself after every step and obeying the test.
struct Hosted<S> {
    inner: S,
    record: fn(&S, f64) -> Rec,
    act: fn(&mut S, &Ctl),
    ctl: Arc<Ctl>,
    log: Arc<Mutex<Vec<Rec>>>,
    last: ContactModel,
}

impl<S: Scene> Scene for Hosted<S> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn step_s(&self) -> f64 {
        self.inner.step_s()
    }
    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        if !self.ctl.hold.load(Ordering::Relaxed) {
            (self.act)(&mut self.inner, &self.ctl);
            self.last = self.inner.step(t_s, samples);
        }
        let r = (self.record)(&self.inner, t_s);
        self.log.lock().unwrap().push(r);
        self.last
    }
    fn look(&self) -> spidar_world::look::Look {
        self.inner.look()
    }
    fn pose(&self, out: &mut spidar_world::look::Poses<'_>) {
        self.inner.pose(out)
    }
}

fn record_boxing(s: &BoxingScene, t: f64) -> Rec {
    let w = &s.world;
    let m = &w.mind;
    Rec {
        t,
        parts: w.ws.shape_pose.iter().map(|p| (p.pos_m, DQuat::from_mat3(&p.rot).normalize())).collect(),
        skeletons: Vec::new(),
        counters: [m.hits_taken, m.hits_given, m.attacks, m.avoidances, m.blocks, m.predictions]
            .iter()
            .map(|c| *c as f64)
            .collect(),
    }
}

fn record_crowd(s: &CrowdScene, t: f64) -> Rec {
    let c = &s.crowd;
    let down = c.chars.iter().filter(|ch| ch.control.policy != Policy::Balance).count();
    Rec {
        t,
        parts: c.bodies.iter().map(|b| (b.pos_m, b.rot)).collect(),
        skeletons: (0..c.len()).map(|i| (c.poses[i], c.chars[i].control.policy)).collect(),
        counters: vec![c.len() as f64, down as f64, s.impulse_total_n_s.length()],
    }
}

/// A push that tips a character over: 200 N s backward at its chest (it falls on its back,
/// the way its narrow feet let it fall most easily).
fn push_crowd(s: &mut CrowdScene, ctl: &Ctl) {
    if let Some(i) = ctl.push.lock().unwrap().take() {
        let b = s.crowd.body_space(i);
        let front = b.heading.to_world(0.0, 1.0);
        s.crowd.add_impulse_at(i, b.r_m + DVec3::Y * 0.45, front * -200.0);
    }
}

/// The test's known rig status, as the rig would send it.
fn known_rig_status() -> RigStatus {
    RigStatus {
        tick: 1,
        t_s: 0.0,
        state: RigState::Active,
        rate_hz: 999.8,
        lateness_p99_s: 57.3e-6,
        force_n: [DVec3::new(0.0, 0.0, -1.5), DVec3::new(0.6, 0.8, 0.0)],
        tensions_n: [[1.0, 2.0, 3.0, 20.0], [1.0, 1.0, 5.0, 9.0]],
        faults: 3,
        device_errors: 1,
        stale_ticks: 2,
        clamped_ticks: 7,
        misses: 4,
    }
}

struct Hosting {
    stop: Arc<AtomicBool>,
    scene: Option<JoinHandle<Stepper>>,
    feeder: Option<JoinHandle<()>>,
    counters: Arc<SceneCounters>,
    view: ViewHandle,
    ctl: Arc<Ctl>,
    log: Arc<Mutex<Vec<Rec>>>,
    clock: MonotonicClock,
    look: spidar_world::look::Look,
    _status: Sender<RigStatus>,
    _models: Receiver<ContactModel>,
}

impl Drop for Hosting {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(f) = self.feeder.take() {
            let _ = f.join();
        }
        if let Some(s) = self.scene.take() {
            let _ = s.join();
        }
    }
}

/// The user's hands: both at home, the right one jabbing at `target` (link frame) from `punch_at`.
fn hands_at(t: f64, punch_at: f64, target: DVec3) -> [HandState; 2] {
    let r = rig();
    let w = r.rig_to_world;
    let home = [w.point(r.hands[0].home_m), w.point(r.hands[1].home_m)];
    let mut h = home.map(|p| HandState { pos_m: p, valid: true, ..Default::default() });
    let (out_s, hold_s) = (0.2, 0.3);
    let s = t - punch_at;
    if punch_at > 0.0 && s > 0.0 && s < out_s + hold_s + out_s {
        // Minimum jerk out, hold, and back.
        let (from, to, tau) = if s < out_s {
            (home[1], target, s / out_s)
        } else if s < out_s + hold_s {
            (target, target, 0.0)
        } else {
            (target, home[1], (s - out_s - hold_s) / out_s)
        };
        let p = 10.0 * tau.powi(3) - 15.0 * tau.powi(4) + 6.0 * tau.powi(5);
        let v = (30.0 * tau.powi(2) - 60.0 * tau.powi(3) + 30.0 * tau.powi(4)) / out_s;
        h[1].pos_m = from + (to - from) * p;
        h[1].vel_m_per_s = (to - from) * v;
    }
    h
}

fn host<S: Scene + 'static>(
    inner: S,
    record: fn(&S, f64) -> Rec,
    act: fn(&mut S, &Ctl),
    target: DVec3,
    opts: &ViewOptions,
) -> Hosting {
    let look = inner.look();
    let ctl = Arc::new(Ctl::default());
    let log = Arc::new(Mutex::new(Vec::new()));
    let hosted =
        Hosted { inner, record, act, ctl: ctl.clone(), log: log.clone(), last: ContactModel::default() };
    let view = View::start(hosted.name(), &look, opts).expect("starting the view");
    let handle = view.counters_handle();
    let (status_tx, status_rx) = crossbeam_channel::bounded(4);
    status_tx.send(known_rig_status()).unwrap();
    let (samples_tx, samples_rx) = crossbeam_channel::bounded(256);
    let (models_tx, models_rx) = crossbeam_channel::bounded(1);
    let clock = MonotonicClock::new();
    let stop = Arc::new(AtomicBool::new(false));
    let counters = Arc::new(SceneCounters::default());
    let mut stepper = Stepper::new(Box::new(hosted));
    stepper.add_observer(Box::new(view));
    // The world as `spidar run --world thread` hosts it.
    let scene = scene_thread::spawn(
        stepper,
        clock,
        ChannelWorldEnd { models: models_tx, samples: samples_rx, status: status_rx },
        rig_info(&rig()),
        stop.clone(),
        counters.clone(),
        None,
    )
    .unwrap();
    // The user's hands at 1 kHz on the scene's clock.
    let feeder = {
        let (stop, ctl) = (stop.clone(), ctl.clone());
        std::thread::spawn(move || {
            let mut tick = 0;
            while !stop.load(Ordering::Relaxed) {
                let t = clock.now_ns() as f64 * 1e-9;
                let punch_at = f64::from_bits(ctl.punch_at.load(Ordering::Relaxed));
                let s =
                    HandSample { tick, t_s: t, hands: hands_at(t, punch_at, target), ..Default::default() };
                let _ = samples_tx.try_send(s);
                tick += 1;
                std::thread::sleep(Duration::from_millis(1));
            }
        })
    };
    Hosting {
        stop,
        scene: Some(scene),
        feeder: Some(feeder),
        counters,
        view: handle,
        ctl,
        log,
        clock,
        look,
        _status: status_tx,
        _models: models_rx,
    }
}

fn boxing_world(opts: &ViewOptions) -> Hosting {
    let scene = BoxingScene::new(Default::default()).unwrap();
    // The right jab aims at the virtual human's head, in the rt-loop's frame.
    let target = scene.world.com(scene.world.vh.head) - scene.world.params.user_offset_m;
    host(scene, record_boxing, |_, _| {}, target, opts)
}

fn crowd_world(opts: &ViewOptions) -> Hosting {
    host(CrowdScene::builtin().unwrap(), record_crowd, push_crowd, DVec3::ZERO, opts)
}

/// The view's tests run one at a time: browsers and big frames would load the machine under the
/// other view tests' worlds.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn any_port() -> ViewOptions {
    ViewOptions { addr: ([127, 0, 0, 1], 0).into(), ..Default::default() }
}

// ---------------------------------------------------------------------------------------------
// What the browser asks.

impl Hosting {
    fn now(&self) -> f64 {
        self.clock.now_ns() as f64 * 1e-9
    }

    /// The record of the step at loop time `t` (a frame's time is its step's, in f32).
    fn at(&self, t: f64) -> Rec {
        let log = self.log.lock().unwrap();
        let r =
            log.iter().min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs())).expect("no step recorded");
        assert!((r.t - t).abs() < 1e-5 * t.max(1.0), "no step at t = {t} (nearest {})", r.t);
        r.clone()
    }

    fn latest(&self) -> Rec {
        self.log.lock().unwrap().last().cloned().expect("no step recorded")
    }

    fn answer(&self, q: &Value) -> Value {
        let f = |v: &Value| v.as_f64().unwrap();
        let close = |a: DVec3, b: &[Value], what: &str| {
            let d = (a - DVec3::new(f(&b[0]), f(&b[1]), f(&b[2]))).length();
            assert!(d < 1e-4, "{what}: the frame is {d} m from the world");
        };
        let same_rot = |a: DQuat, b: &[Value], what: &str| {
            let q = DQuat::from_xyzw(f(&b[0]), f(&b[1]), f(&b[2]), f(&b[3]));
            assert!(a.dot(q).abs() > 1.0 - 1e-5, "{what}: the frame's rotation {q} is not the world's {a}");
        };
        match q["ask"].as_str().unwrap() {
            "check_shapes" => {
                let rec = self.at(f(&q["t"]));
                let shapes = q["shapes"].as_object().unwrap();
                for (name, v) in shapes {
                    let k =
                        self.look.shapes.iter().position(|s| &s.name == name).expect("a shape of the look");
                    let v = v.as_array().unwrap();
                    close(rec.parts[k].0, &v[0..3], name);
                    same_rot(rec.parts[k].1, &v[3..7], name);
                }
                json!({"ok": shapes.len()})
            }
            "check_characters" => {
                let rec = self.at(f(&q["t"]));
                let states = &self.look.crowd.as_ref().unwrap().states;
                for (i, c) in q["characters"].as_array().unwrap().iter().enumerate() {
                    let c = c.as_array().unwrap();
                    let what = format!("character {i}");
                    close(rec.parts[i].0, &c[0..3], &what);
                    same_rot(rec.parts[i].1, &c[3..7], &what);
                    let (pose, policy) = &rec.skeletons[i];
                    close(pose.root_m.as_dvec3(), &c[7..10], &what);
                    assert_eq!(states[c[10].as_u64().unwrap() as usize], policy.name(), "{what}'s state");
                    for j in 0..self.look.crowd.as_ref().unwrap().joints.len() {
                        same_rot(
                            pose.rot[j].as_dquat(),
                            &c[12 + 4 * j..16 + 4 * j],
                            &format!("{what} joint {j}"),
                        );
                    }
                }
                json!({"ok": true})
            }
            "punch" => {
                // The world is held with the fist out (0.45 s after the punch starts), so a slow
                // browser still shows the virtual human's reaction.
                let at = self.now() + 0.05;
                self.ctl.punch_at.store(at.to_bits(), Ordering::Relaxed);
                while self.latest().t < at + 0.45 {
                    std::thread::sleep(Duration::from_millis(2));
                }
                self.ctl.hold.store(true, Ordering::Relaxed);
                json!({"t_punch": at})
            }
            "push" => {
                // Pushed (again every 3 s while it stands), and held still once it is down.
                let i = q["i"].as_u64().unwrap() as usize;
                let until = Instant::now() + Duration::from_secs(15);
                let mut next_push = Instant::now();
                loop {
                    if Instant::now() >= next_push {
                        *self.ctl.push.lock().unwrap() = Some(i);
                        next_push += Duration::from_secs(3);
                    }
                    let r = self.latest();
                    if r.skeletons[i].1 == Policy::Down {
                        self.ctl.hold.store(true, Ordering::Relaxed);
                        return json!({"t_down": self.latest().t});
                    }
                    if Instant::now() > until {
                        return json!({"error": format!("character {i} did not fall: {:?}", r.skeletons[i].1)});
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            "hold" => {
                self.ctl.hold.store(true, Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(300));
                json!({"ok": true})
            }
            "check_hud" => {
                let hud = q["hud"].as_object().unwrap();
                let text = |k: &str| {
                    hud.get(k).and_then(|v| v.as_str()).unwrap_or_else(|| panic!("no {k} in the HUD"))
                };
                let r = known_rig_status();
                let want = [
                    ("rig_state", "active".to_string()),
                    ("rate_hz", format!("{:.1}", r.rate_hz)),
                    ("lateness_p99", format!("{:.1} us", r.lateness_p99_s * 1e6)),
                    ("force_l", format!("{:.2}", r.force_n[0].length())),
                    ("force_r", format!("{:.2}", r.force_n[1].length())),
                    ("faults", r.faults.to_string()),
                    ("device_errors", r.device_errors.to_string()),
                    ("stale_ticks", r.stale_ticks.to_string()),
                    ("misses", r.misses.to_string()),
                    ("link", "up".to_string()),
                ];
                for (k, v) in want {
                    assert_eq!(text(k), v, "the HUD's {k} in the {} browser", q["browser"]);
                }
                let world = self.latest();
                for (name, v) in self.look.counters.iter().zip(world.counters.iter()) {
                    let shown = if v.fract() == 0.0 { format!("{}", *v as i64) } else { format!("{v:.1}") };
                    assert_eq!(
                        text(&format!("counter:{name}")),
                        shown,
                        "the HUD's {name} in the {} browser",
                        q["browser"]
                    );
                }
                json!({"ok": true})
            }
            other => json!({"error": format!("unknown question {other}")}),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Running the browser.

fn browser_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("browser")
}

/// Whether node, chromium and the test folder's packages are here; if not, why.
fn browser_missing() -> Option<String> {
    let chromium = std::env::var("SPIDAR_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    if !std::path::Path::new(&chromium).exists() {
        return Some(format!("no chromium at {chromium} (apt-get install chromium, or set SPIDAR_CHROMIUM)"));
    }
    if Command::new("node").arg("--version").output().map(|o| !o.status.success()).unwrap_or(true) {
        return Some("no node on PATH".into());
    }
    if !browser_dir().join("node_modules/puppeteer-core").exists() {
        return Some(format!("no puppeteer-core: run npm ci in {}", browser_dir().display()));
    }
    None
}

/// True when the browser tests can run; false (after a loud message) when they are skipped.
fn browser_here(test: &str) -> bool {
    let Some(why) = browser_missing() else { return true };
    if std::env::var("SPIDAR_BROWSER_TESTS").as_deref() == Ok("required") {
        panic!("{test}: the browser test cannot run: {why} (SPIDAR_BROWSER_TESTS=required)");
    }
    eprintln!("\n*** SKIPPED {test}: {why}. The view's browser tests did not run. ***\n");
    false
}

/// Runs `node view.mjs ARGS`, answering its questions with `answer`; panics with its output
/// unless it ends with `RESULT ok`.
fn node(args: &[&str], mut answer: impl FnMut(&Value) -> Value) {
    let mut child = Command::new("node")
        .arg("view.mjs")
        .args(args)
        .current_dir(browser_dir())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("starting node");
    let mut stdin = child.stdin.take().unwrap();
    let out = BufReader::new(child.stdout.take().unwrap());
    let mut transcript = String::new();
    let mut result = None;
    for line in out.lines() {
        let line = line.unwrap();
        transcript.push_str(&line);
        transcript.push('\n');
        if let Some(q) = line.strip_prefix("ASK ") {
            let q: Value = serde_json::from_str(q).unwrap();
            let a = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| answer(&q)));
            let reply = match &a {
                Ok(v) => v.clone(),
                Err(e) => {
                    json!({"error": e.downcast_ref::<String>().cloned().unwrap_or_else(|| "a check failed".into())})
                }
            };
            writeln!(stdin, "{reply}").unwrap();
            stdin.flush().unwrap();
            if let Err(e) = a {
                let _ = child.wait();
                eprintln!("{transcript}");
                std::panic::resume_unwind(e);
            }
        } else if let Some(r) = line.strip_prefix("RESULT ") {
            result = Some(r.to_string());
        }
    }
    let status = child.wait().unwrap();
    eprintln!("{transcript}");
    assert!(status.success() && result.as_deref() == Some("ok"), "the browser test failed: {result:?}");
}

/// Boxing in a browser: the virtual human drawn where the world has it, moved by a scripted punch,
/// the HUD's numbers the world's, a second browser showing the same.
#[test]
fn view_boxing_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("view_boxing_in_a_browser") {
        return;
    }
    let w = boxing_world(&any_port());
    node(&["boxing", w.view.url()], |q| w.answer(q));
    assert_eq!(w.view.counters().viewers_total.load(Ordering::Relaxed), 2);
}

/// The crowd in a browser: a walking character's drawn pose changes, a pushed one is drawn down.
#[test]
fn view_crowd_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("view_crowd_in_a_browser") {
        return;
    }
    let w = crowd_world(&any_port());
    node(&["crowd", w.view.url()], |q| w.answer(q));
}

// ---------------------------------------------------------------------------------------------
// Without a browser.

/// A WebSocket viewer on the view's frames port; `read` says whether it reads.
fn viewer(url: &str, read: bool, frames: Arc<AtomicU64>, stop: Arc<AtomicBool>) -> JoinHandle<()> {
    let url = url.to_string();
    std::thread::spawn(move || {
        let addr = url.trim_start_matches("ws://").to_string();
        let stream = std::net::TcpStream::connect(&addr).unwrap();
        let (mut ws, _) = tungstenite::client(format!("{url}/"), stream).unwrap();
        while !stop.load(Ordering::Relaxed) {
            if !read {
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
            match ws.read() {
                Ok(tungstenite::Message::Binary(_)) => {
                    frames.fetch_add(1, Ordering::Relaxed);
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
    })
}

/// A viewer that never reads: the world steps on (no more late steps than without it, every step
/// taken), the viewer that reads gets its frames all along, and the stalled one is dropped.
#[test]
fn view_a_viewer_that_never_reads_does_not_slow_the_world() {
    let _one = one_at_a_time();
    // Big frames (400 characters, 90 kB) fill the stalled socket's buffers within seconds.
    let crowd = spidar_tools::bench_view::crowd_of(400).unwrap();
    // The default write timeout (2 s): a world that waited for the stalled viewer would lose
    // about half of phase B's steps.
    let opts = any_port();
    let w = host(crowd, record_crowd, |_, _| {}, DVec3::ZERO, &opts);
    let c = w.view.counters();
    let steps = |w: &Hosting| w.counters.steps.load(Ordering::Relaxed);
    let late = |w: &Hosting| w.counters.late_steps.load(Ordering::Relaxed);
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(AtomicU64::new(0));
    let reader = viewer(w.view.ws_url(), true, frames.clone(), stop.clone());
    let published = || c.frames_published.load(Ordering::Relaxed);
    let mark = |w: &Hosting| (Instant::now(), steps(w), late(w), frames.load(Ordering::Relaxed), published());
    // A: one viewer reading, 3 s.
    std::thread::sleep(Duration::from_millis(500));
    let a0 = mark(&w);
    std::thread::sleep(Duration::from_secs(3));
    let a1 = mark(&w);
    // B: and one that never reads, until the view drops it, and a second more.
    let stalled = viewer(w.view.ws_url(), false, Arc::new(AtomicU64::new(0)), stop.clone());
    let until = Instant::now() + Duration::from_secs(30);
    while c.viewers_dropped.load(Ordering::Relaxed) == 0 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_secs(1));
    let b1 = mark(&w);
    stop.store(true, Ordering::Relaxed);
    let _ = (reader.join(), stalled.join());
    let phase = |p: (Instant, u64, u64, u64, u64), q: (Instant, u64, u64, u64, u64)| {
        let secs = (q.0 - p.0).as_secs_f64();
        (secs, q.1 - p.1, q.2 - p.2, q.3 - p.3, q.4 - p.4)
    };
    let (sa, steps_a, late_a, frames_a, pub_a) = phase(a0, a1);
    let (sb, steps_b, late_b, frames_b, pub_b) = phase(a1, b1);
    eprintln!(
        "A (one reader, {sa:.1} s): {steps_a} steps, {late_a} late, {pub_a} frames published, {frames_a} read; \
         B (and a stalled viewer, {sb:.1} s): {steps_b} steps, {late_b} late, {pub_b} frames published, {frames_b} read; dropped {}",
        c.viewers_dropped.load(Ordering::Relaxed)
    );
    assert_eq!(c.viewers_dropped.load(Ordering::Relaxed), 1, "the stalled viewer is dropped");
    // A world that waited for the stalled viewer would lose its steps while the socket was full
    // (the scene thread does not catch up more than 10 steps) and publish no frames.
    let (rate_a, rate_b) = (steps_a as f64 * 0.003 / sa, steps_b as f64 * 0.003 / sb);
    assert!(
        rate_b >= rate_a - 0.2,
        "steps taken: {rate_b:.2} of the 3 ms steps with the stalled viewer, {rate_a:.2} without"
    );
    // Late steps follow the machine's load (this thread is not real time, and the stalled viewer's
    // socket takes megabytes of copying before it fills): only a gross change fails.
    let late_rate_a = late_a as f64 / steps_a as f64;
    assert!(
        late_b as f64 <= (2.0 * late_rate_a + 0.15) * steps_b as f64 + 20.0,
        "late steps with the stalled viewer: {late_b} of {steps_b}, without: {late_a} of {steps_a}"
    );
    assert!(
        pub_b as f64 >= 20.0 * sb && frames_b as f64 >= 10.0 * sb,
        "frames published {pub_b} and read {frames_b} in {sb:.1} s"
    );
}

/// The observer's call after a step allocates nothing, with viewers connected and frames flowing.
#[test]
fn view_observer_allocates_nothing_per_step() {
    let _one = one_at_a_time();
    let mut scene = BoxingScene::new(Default::default()).unwrap();
    let look = scene.look();
    let mut view = View::start("boxing", &look, &any_port()).unwrap();
    let handle = view.counters_handle();
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(AtomicU64::new(0));
    let reader = viewer(view.ws_url(), true, frames.clone(), stop.clone());
    while handle.counters().viewers.load(Ordering::Relaxed) == 0 {
        std::thread::sleep(Duration::from_millis(10));
    }
    let info = rig_info(&rig());
    let status = known_rig_status();
    let mut sample = HandSample { hands: hands_at(0.0, 0.0, DVec3::ZERO), ..Default::default() };
    let mut run = |n: usize, guarded: bool| {
        for i in 0..n {
            let t = i as f64 * 0.003;
            sample.t_s = t;
            let m = scene.step(t, std::slice::from_ref(&sample));
            let v = StepView {
                t_s: t,
                scene: &scene,
                samples: std::slice::from_ref(&sample),
                model: &m,
                rig_info: Some(&info),
                rig_status: Some(&status),
            };
            if guarded {
                no_alloc(|| view.after_step(&v));
            } else {
                view.after_step(&v);
            }
        }
    };
    run(100, false);
    let (before, _) = forbidden_allocs();
    run(1000, true);
    assert_eq!(forbidden_allocs().0, before, "the observer allocated");
    assert!(handle.counters().frames_published.load(Ordering::Relaxed) >= 150, "frames were written");
    stop.store(true, Ordering::Relaxed);
    drop(view);
    let _ = reader.join();
}

/// The README's pictures (`docs/img/`), taken by the same harness from `spidar run`'s path: the
/// simulated rig, the rt-loop, the scene thread and the view.
/// `cargo test -p spidar-tests --test hil view_screenshots -- --ignored`
#[test]
#[ignore = "writes docs/img: run by hand"]
fn view_screenshots_for_the_readme() {
    use spidar_rt::rt_thread::RtOptions;
    use spidar_tools::session::{load_scripts, run_live, sim_device, LiveOptions, SimOptions, WorldChoice};
    use spidar_tools::signals::Stop;
    if !browser_here("view_screenshots_for_the_readme") {
        return;
    }
    let _one = one_at_a_time();
    let img = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/img");
    for (scene_name, script, shots) in [
        ("boxing", "box", vec![("eye", "boxing-eye.png", "4"), ("orbit", "boxing-side.png", "3")]),
        ("crowd", "spar", vec![("orbit", "crowd.png", "5")]),
    ] {
        let r = rig();
        let scene = spidar_world::load(scene_name).unwrap();
        let view = View::start(scene.name(), &scene.look(), &any_port()).unwrap();
        let url = view.url().to_string();
        let dev = sim_device(&r, load_scripts(script, &r, 1).unwrap(), &SimOptions::default()).unwrap();
        let stop = Stop::detached();
        let opts = LiveOptions {
            seconds: Some(30.0),
            rt: RtOptions { fifo_priority: None, lock_memory: false, ..RtOptions::default() },
            spin_ns: 0,
            status_every: None,
            stop: stop.clone(),
            scene_name: scene_name.into(),
            script_name: script.into(),
            connect_timeout: Duration::from_secs(10),
            world_priority: None,
            recorder: None,
        };
        // The world on a thread of `spidar run`, with the view as its observer.
        let mut stepper = Stepper::new(scene);
        stepper.add_observer(Box::new(view));
        let run =
            std::thread::spawn(move || run_live(dev, &r, WorldChoice::Thread(stepper), opts).map(|_| ()));
        for (camera, file, wait) in shots {
            let path = img.join(file);
            node(
                &["screenshot", &url, camera, path.to_str().unwrap(), wait],
                |_| json!({"error": "no questions"}),
            );
        }
        stop.request();
        run.join().unwrap().unwrap();
    }
}
