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
use spidar_runtime::scene_thread::{self, SceneCounters};
use spidar_sim::character::controller::Policy;
use spidar_sim::character::drawn::world_joints;
use spidar_sim::character::skeleton::MAX_JOINTS;
use spidar_world::boxing::BoxingScene;
use spidar_world::crowd::CrowdScene;
use spidar_world::host::Stepper;
use spidar_world::look::{CHARACTER_HEAD_FLOATS, CHARACTER_STATE, JOINT_FLOATS};
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
    /// The right fist's jab: from its home point at loop-clock time `.0` to `.1` (link frame) in
    /// 0.2 s, and held there until cleared.
    jab: Mutex<Option<(f64, DVec3)>>,
}

/// What the world was after one step.
#[derive(Clone)]
struct Rec {
    t: f64,
    /// Boxing: every shape's pose. Crowd: every character's body pose.
    parts: Vec<(DVec3, DQuat)>,
    /// Crowd: every character's drawn figure (its joints in the world, as
    /// `spidar_sim::character::drawn::world_joints` gives them) and policy.
    skeletons: Vec<(Vec<DVec3>, Policy)>,
    counters: Vec<f64>,
    /// Boxing: each articulated body's joints in the world (actor, joint, where the simulation has
    /// it: the child solid's origin).
    body_joints: Vec<(&'static str, String, DVec3)>,
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
    fn figure_states(&self, out: &mut [spidar_sim::character::drawn::FigureState]) {
        self.inner.figure_states(out)
    }
}

fn record_boxing(s: &BoxingScene, t: f64) -> Rec {
    let w = &s.world;
    let m = &w.mind;
    Rec {
        t,
        parts: w.ws.shape_pose.iter().map(|p| (p.pos_m, DQuat::from_mat3(&p.rot).normalize())).collect(),
        skeletons: Vec::new(),
        body_joints: [(spidar_sim::boxer::BOXER, "virtual human"), (spidar_sim::boxer::AVATAR, "avatar")]
            .into_iter()
            .flat_map(|(a, name)| {
                w.model.articulations[a]
                    .bodies
                    .clone()
                    .filter(|&b| w.model.bodies[b].parent.is_some())
                    .map(move |b| (name, w.model.bodies[b].name.clone(), w.ws.point_world(b, DVec3::ZERO)))
            })
            .collect(),
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
        skeletons: (0..c.len())
            .map(|i| {
                let mut j = [DVec3::ZERO; MAX_JOINTS];
                let n = world_joints(c, i, &mut j);
                (j[..n].to_vec(), c.chars[i].control.policy)
            })
            .collect(),
        counters: vec![c.len() as f64, down as f64, s.impulse_total_n_s.length()],
        body_joints: Vec::new(),
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
    let mut h = home.map(|p| HandState { pos_world_m: p, valid: true, ..Default::default() });
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
        h[1].pos_world_m = from + (to - from) * p;
        h[1].vel_world_m_per_s = (to - from) * v;
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
                let mut s =
                    HandSample { tick, t_s: t, hands: hands_at(t, punch_at, target), ..Default::default() };
                if let Some((at, to)) = *ctl.jab.lock().unwrap() {
                    s.hands[1] = jab(s.hands[1].pos_world_m, t - at, to);
                }
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
        view: handle,
        ctl,
        log,
        clock,
        look,
        _status: status_tx,
        _models: models_rx,
    }
}

/// A hand from `home` to `to` in 0.2 s (minimum jerk), `s` seconds after it started, then held.
fn jab(home: DVec3, s: f64, to: DVec3) -> HandState {
    let tau = (s / 0.2).clamp(0.0, 1.0);
    let p = 10.0 * tau.powi(3) - 15.0 * tau.powi(4) + 6.0 * tau.powi(5);
    let v = (30.0 * tau.powi(2) - 60.0 * tau.powi(3) + 30.0 * tau.powi(4)) / 0.2;
    HandState {
        pos_world_m: home + (to - home) * p,
        vel_world_m_per_s: (to - home) * v,
        valid: true,
        ..Default::default()
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

pub(super) fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

pub(super) fn any_port() -> ViewOptions {
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

    /// Holds the world still; gives the loop time of a step taken after the hold (every status
    /// from then on shows the held world's numbers).
    fn hold(&self) -> f64 {
        self.ctl.hold.store(true, Ordering::Relaxed);
        // The step under way may have read the flag before: two more steps.
        let n = self.log.lock().unwrap().len();
        while self.log.lock().unwrap().len() < n + 2 {
            std::thread::sleep(Duration::from_millis(2));
        }
        self.latest().t
    }

    fn latest(&self) -> Rec {
        self.log.lock().unwrap().last().cloned().expect("no step recorded")
    }

    /// The page's question `q` answered (a check of what it drew against the world, or an
    /// action on the world), each kind by its own method.
    fn answer(&self, q: &Value) -> Value {
        match q["ask"].as_str().unwrap() {
            "check_shapes" => self.check_shapes(q),
            "check_characters" => self.check_characters(q),
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
            "push" => self.push_until_down(q["i"].as_u64().unwrap() as usize),
            "hold" => json!({"t_hold": self.hold()}),
            "check_person_joints" => {
                let f = |v: &Value| v.as_f64().unwrap();
                // Every joint of the body drawn as a person, as each of its two pieces draws it,
                // within 1 cm of where the simulation has it at the frame's step.
                let rec = self.at(f(&q["t"]));
                let name = q["name"].as_str().unwrap();
                let drawn = q["joints"].as_object().unwrap();
                let mut worst: f64 = 0.0;
                let mut n = 0;
                for (actor, joint, truth) in rec.body_joints.iter().filter(|j| j.0 == name) {
                    let d = drawn.get(joint).unwrap_or_else(|| panic!("{actor}: joint {joint} is not drawn"));
                    for side in ["parent", "child"] {
                        let p = d[side]
                            .as_array()
                            .unwrap_or_else(|| panic!("{actor}'s {joint}: no {side} piece"));
                        let e = (DVec3::new(f(&p[0]), f(&p[1]), f(&p[2])) - *truth).length();
                        assert!(
                            e < 0.01,
                            "{actor}'s {joint} as its {side} piece draws it is {e} m from the simulation's"
                        );
                        worst = worst.max(e);
                        n += 1;
                    }
                }
                assert!(n >= 16, "{name}: {n} joint ends compared");
                json!({"worst_m": worst, "ends": n})
            }
            "jab" => {
                // The right fist jabs at the virtual human's head (hit) or out to the right, clear
                // of every body (miss), and stays there.
                let head = self.look.shapes.iter().position(|s| s.name == "virtual human/head").unwrap();
                let head_m = self.latest().parts[head].0 - self.look.link_offset_m;
                let r = rig();
                let home = r.rig_to_world.point(r.hands[1].home_m);
                let to =
                    if q["hit"].as_bool().unwrap() { head_m } else { home + DVec3::new(0.35, 0.05, 0.0) };
                let at = self.now();
                *self.ctl.jab.lock().unwrap() = Some((at, to));
                json!({"t_out": at + 0.2})
            }
            "release" => {
                *self.ctl.jab.lock().unwrap() = None;
                json!({"ok": true})
            }
            "check_hud" => self.check_hud(q),
            other => json!({"error": format!("unknown question {other}")}),
        }
    }

    /// Every shape the page drew at time `t` is where the world had it.
    fn check_shapes(&self, q: &Value) -> Value {
        let rec = self.at(num(&q["t"]));
        let shapes = q["shapes"].as_object().unwrap();
        for (name, v) in shapes {
            let k = self.look.shapes.iter().position(|s| &s.name == name).expect("a shape of the look");
            let v = v.as_array().unwrap();
            close(rec.parts[k].0, &v[0..3], name);
            same_rot(rec.parts[k].1, &v[3..7], name);
        }
        json!({"ok": shapes.len()})
    }

    /// Every character the page drew at time `t` is where the world had it, in its state, with
    /// the world's drawn figure joint by joint.
    fn check_characters(&self, q: &Value) -> Value {
        let rec = self.at(num(&q["t"]));
        let states = &self.look.crowd.as_ref().unwrap().states;
        for (i, c) in q["characters"].as_array().unwrap().iter().enumerate() {
            let c = c.as_array().unwrap();
            let what = format!("character {i}");
            close(rec.parts[i].0, &c[0..3], &what);
            same_rot(rec.parts[i].1, &c[3..7], &what);
            let (joints, policy) = &rec.skeletons[i];
            assert_eq!(
                states[c[CHARACTER_STATE].as_u64().unwrap() as usize],
                policy.name(),
                "{what}'s state"
            );
            assert_eq!(joints.len(), self.look.crowd.as_ref().unwrap().joints.len());
            assert_eq!(c.len(), CHARACTER_HEAD_FLOATS + JOINT_FLOATS * joints.len(), "{what}'s numbers");
            for (j, p) in joints.iter().enumerate() {
                let o = CHARACTER_HEAD_FLOATS + JOINT_FLOATS * j;
                close(*p, &c[o..o + 3], &format!("{what} joint {j}"));
            }
        }
        json!({"ok": true})
    }

    /// Character `i` pushed (again every 3 s while it stands), and the world held still once it
    /// is down.
    fn push_until_down(&self, i: usize) -> Value {
        let until = Instant::now() + Duration::from_secs(15);
        let mut next_push = Instant::now();
        loop {
            if Instant::now() >= next_push {
                *self.ctl.push.lock().unwrap() = Some(i);
                next_push += Duration::from_secs(3);
            }
            let r = self.latest();
            if r.skeletons[i].1 == Policy::Down {
                return json!({"t_down": self.hold()});
            }
            if Instant::now() > until {
                return json!({"error": format!("character {i} did not fall: {:?}", r.skeletons[i].1)});
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The page's HUD shows the rig's status and the world's counters as they are.
    fn check_hud(&self, q: &Value) -> Value {
        let hud = q["hud"].as_object().unwrap();
        let text =
            |k: &str| hud.get(k).and_then(|v| v.as_str()).unwrap_or_else(|| panic!("no {k} in the HUD"));
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
}

/// A number of the page's answer.
fn num(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The page's position `b` (three numbers) is the world's `a`, to 0.1 mm.
fn close(a: DVec3, b: &[Value], what: &str) {
    let d = (a - DVec3::new(num(&b[0]), num(&b[1]), num(&b[2]))).length();
    assert!(d < 1e-4, "{what}: the frame is {d} m from the world");
}

/// The page's rotation `b` (x, y, z, w) is the world's `a`.
fn same_rot(a: DQuat, b: &[Value], what: &str) {
    let q = DQuat::from_xyzw(num(&b[0]), num(&b[1]), num(&b[2]), num(&b[3]));
    assert!(a.dot(q).abs() > 1.0 - 1e-5, "{what}: the frame's rotation {q} is not the world's {a}");
}

// ---------------------------------------------------------------------------------------------
// Running the browser.

/// True when the browser tests can run; false (after a loud message) when they are skipped.
pub(super) fn browser_here(test: &str) -> bool {
    spidar_testkit::node::can_run(test, spidar_testkit::node::browser_missing(), "The view's browser tests")
}

/// Runs `node view.mjs ARGS`, answering its questions with `answer`; panics with its output
/// unless it ends with `RESULT ok`.
pub(super) fn node(args: &[&str], answer: impl FnMut(&Value) -> Value) {
    node_script("view.mjs", args, answer)
}

/// Runs `node SCRIPT ARGS` in `tests/browser` (see [`node`]).
pub(super) fn node_script(script: &str, args: &[&str], mut answer: impl FnMut(&Value) -> Value) {
    let mut child = Command::new("node")
        .arg(script)
        .args(args)
        .current_dir(spidar_testkit::node::browser_dir())
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

/// A hit as a flash on the part hit: a scripted jab that lands on the virtual human (the avatar's
/// glove, which follows the user's hand, on its head: the world's own contact) lights the part it
/// lands on in the page; one that misses lights nothing.
#[test]
fn view_a_hit_flashes_the_part_hit_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("view_a_hit_flashes_the_part_hit_in_a_browser") {
        return;
    }
    // A passive virtual human: it neither dodges nor blocks the jab.
    let scene =
        BoxingScene::new(spidar_sim::boxer::BoxerParams { active: false, ..Default::default() }).unwrap();
    let w = host(scene, record_boxing, |_, _| {}, DVec3::ZERO, &any_port());
    node(&["flash", w.view.url()], |q| w.answer(q));
}

/// The virtual human and the avatar drawn as people: every joint of each, as both pieces that meet
/// there draw it, within 1 cm of the simulated body's, before and after a punch moves them; the
/// collision shapes come back with the toggle.
#[test]
fn view_people_move_joint_for_joint_with_the_simulated_bodies_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("view_people_move_joint_for_joint_with_the_simulated_bodies_in_a_browser") {
        return;
    }
    let w = boxing_world(&any_port());
    node_script("display.mjs", &["people", w.view.url()], |q| w.answer(q));
}

/// The crowd drawn as people: every piece of every character's person meets the drawn figure's
/// joints within 1 cm (standing, walking, and with one pushed down), the pushed one's person lies
/// on the floor (every piece under 0.5 m and none deeper in it than a limb is thick; from the side,
/// all below a level eye at 0.55 m), and the toggle draws the figures' bones instead.
#[test]
fn display_crowd_drawn_as_people_joint_for_joint_and_lying_when_down() {
    let _one = one_at_a_time();
    if !browser_here("display_crowd_drawn_as_people_joint_for_joint_and_lying_when_down") {
        return;
    }
    let w = crowd_world(&any_port());
    node_script("display.mjs", &["crowd", w.view.url()], |q| w.answer(q));
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

/// A certificate and key for 127.0.0.1 made for a test, in a folder of its own (removed by the
/// caller), and the certificate's DER.
pub(super) fn test_certificate(name: &str) -> (PathBuf, PathBuf, PathBuf, Vec<u8>) {
    let dir = std::env::temp_dir().join(format!("spidar-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let c = rcgen::generate_simple_self_signed(vec!["127.0.0.1".into(), "localhost".into()]).unwrap();
    let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&cert, c.cert.pem()).unwrap();
    std::fs::write(&key, c.signing_key.serialize_pem()).unwrap();
    (dir, cert, key, c.cert.der().to_vec())
}

/// The view over HTTPS (`--view-tls`): a TLS client that trusts the view's certificate gets the
/// page (its request sent with the handshake's last flight, as a browser may), the status, and
/// over a secure WebSocket the scene and frames; a client that does not trust it gets nothing;
/// certificate files that do not read are refused naming the file and saying what to do.
#[test]
fn view_over_https_serves_the_page_and_frames_and_refuses_a_bad_certificate() {
    use rustls::pki_types::{CertificateDer, ServerName};
    use spidar_world::view::TlsIdentity;
    use std::io::Read;
    use std::net::TcpStream;
    let _one = one_at_a_time();
    let (dir, cert, key, der) = test_certificate("view-tls");
    let id = TlsIdentity::from_pem_files(&cert, &key).unwrap();
    let w = boxing_world(&ViewOptions { tls: Some(id), ..any_port() });
    assert!(
        w.view.url().starts_with("https://") && w.view.ws_url().starts_with("wss://"),
        "{}",
        w.view.url()
    );
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let client = |trusted: bool| {
        let mut roots = rustls::RootCertStore::empty();
        if trusted {
            roots.add(CertificateDer::from(der.clone())).unwrap();
        }
        Arc::new(
            rustls::ClientConfig::builder_with_provider(provider.clone())
                .with_safe_default_protocol_versions()
                .unwrap()
                .with_root_certificates(roots)
                .with_no_client_auth(),
        )
    };
    let connect = |url: &str, cfg: Arc<rustls::ClientConfig>| {
        let addr = url.split("://").nth(1).unwrap().trim_end_matches('/');
        let tcp = TcpStream::connect(addr).unwrap();
        tcp.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let conn = rustls::ClientConnection::new(cfg, ServerName::try_from("127.0.0.1").unwrap()).unwrap();
        rustls::StreamOwned::new(conn, tcp)
    };
    let get = |path: &str, cfg: Arc<rustls::ClientConfig>| -> std::io::Result<String> {
        let mut s = connect(w.view.url(), cfg);
        // Queued before the handshake: it leaves in one write with the client's Finished, so the
        // server's last handshake read brings the request too.
        write!(s.conn.writer(), "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")?;
        while s.conn.is_handshaking() || s.conn.wants_write() {
            s.conn.complete_io(&mut s.sock)?;
        }
        let mut text = String::new();
        s.read_to_string(&mut text)?;
        Ok(text)
    };
    let page = get("/", client(true)).unwrap();
    let ws_port = w.view.ws_url().rsplit(':').next().unwrap().trim_end_matches('/').to_string();
    assert!(page.starts_with("HTTP/1.") && page.contains(" 200 "), "{page}");
    assert!(page.contains(&format!("content=\"{ws_port}\"")), "the page names the frames' port {ws_port}");
    let status = get("/scene.json", client(true)).unwrap();
    assert!(status.contains("\"type\":\"scene\""), "{status}");
    assert!(get("/", client(false)).is_err(), "a client that does not trust the certificate gets no page");
    // The frames over TLS.
    let stream = connect(w.view.ws_url(), client(true));
    let (mut ws, _) = tungstenite::client(format!("ws://127.0.0.1:{ws_port}/"), stream).unwrap();
    let mut scene = false;
    let mut frames = 0;
    let until = Instant::now() + Duration::from_secs(20);
    while frames < 3 && Instant::now() < until {
        match ws.read().unwrap() {
            tungstenite::Message::Text(t) if t.as_str().contains("\"type\":\"scene\"") => scene = true,
            tungstenite::Message::Binary(_) => frames += 1,
            _ => {}
        }
    }
    assert!(scene && frames == 3, "over wss: the scene ({scene}) and frames ({frames})");
    drop(ws);
    // Files that do not read.
    let missing = dir.join("missing.pem");
    let e = TlsIdentity::from_pem_files(&missing, &key).unwrap_err().to_string();
    assert!(e.contains("missing.pem") && e.contains("docs/display.md"), "{e}");
    let e = TlsIdentity::from_pem_files(&key, &key).unwrap_err().to_string();
    assert!(e.contains("key.pem") && e.contains("no CERTIFICATE"), "{e}");
    let e = TlsIdentity::from_arg("only-one.pem").unwrap_err().to_string();
    assert!(e.contains("CERT.pem,KEY.pem"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

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

/// Steps `scene` `n` times (3 ms apart, both hands resting at the origin, the test rig's
/// geometry and a known status) and shows each step to `observe`, as the stepper shows its
/// observers.
fn step_observed<S: Scene>(scene: &mut S, n: usize, mut observe: impl FnMut(&StepView)) {
    let info = rig_info(&rig());
    let status = known_rig_status();
    let mut sample = HandSample { hands: hands_at(0.0, 0.0, DVec3::ZERO), ..Default::default() };
    for i in 0..n {
        let t = i as f64 * 0.003;
        sample.t_s = t;
        let m = scene.step(t, std::slice::from_ref(&sample));
        observe(&StepView {
            t_s: t,
            scene: &*scene,
            samples: std::slice::from_ref(&sample),
            model: &m,
            rig_info: Some(&info),
            rig_status: Some(&status),
        });
    }
}

/// A viewer that never reads does not hold the world back: with it connected (and never dropped:
/// the write timeout is an hour), the world takes 4,000 steps whose frames (about 65 MB) are far
/// more than its socket can buffer, every frame is published, and the viewer that reads gets its
/// frames all along. A world that waited for the stalled viewer would block inside a step once its
/// socket filled. Judged by counts; the only clock is a ten-minute bound that turns such a block
/// into a failure instead of a hang.
#[test]
fn view_a_viewer_that_never_reads_does_not_slow_the_world() {
    let _one = one_at_a_time();
    // Big frames (400 characters, about 90 kB each).
    let mut scene = spidar_lab::bench_view::crowd_of(400).unwrap();
    let look = scene.look();
    let opts = ViewOptions { write_timeout: Duration::from_secs(3600), ..any_port() };
    let mut view = View::start("crowd", &look, &opts).unwrap();
    let frame_hz = view.frame_hz();
    let handle = view.counters_handle();
    let stop = Arc::new(AtomicBool::new(false));
    let (read, stalled_read) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let reader = viewer(view.ws_url(), true, read.clone(), stop.clone());
    let stalled = viewer(view.ws_url(), false, stalled_read, stop.clone());
    let c = handle.counters();
    let mut waited = 0;
    while c.viewers.load(Ordering::Relaxed) < 2 {
        std::thread::sleep(Duration::from_millis(10));
        waited += 1;
        assert!(waited < 6000, "the two viewers never connected");
    }
    const STEPS: usize = 4000;
    let (done_tx, done_rx) = crossbeam_channel::bounded(1);
    let stepping = std::thread::spawn(move || {
        step_observed(&mut scene, STEPS, |v| view.after_step(v));
        let _ = done_tx.send(());
        view
    });
    assert!(
        done_rx.recv_timeout(Duration::from_secs(600)).is_ok(),
        "the world did not finish {STEPS} steps with a stalled viewer connected: it waits for viewers"
    );
    let view = stepping.join().unwrap();
    let c = handle.counters();
    let offered = c.frames_published.load(Ordering::Relaxed) + c.frames_skipped.load(Ordering::Relaxed);
    // A frame is due at the first step at or past each period: frames this big at 60 a second.
    assert_eq!(frame_hz, spidar_world::view::MIN_FRAME_HZ, "frames of 90 kB go out at the least rate");
    let due = (STEPS as f64 * 0.003 * frame_hz) as u64;
    assert!(offered + 1 >= due, "{offered} frames offered in {STEPS} steps, {due} due");
    assert_eq!(
        c.viewers_dropped.load(Ordering::Relaxed),
        0,
        "the stalled viewer stayed connected throughout"
    );
    assert_eq!(c.viewers.load(Ordering::Relaxed), 2);
    // The reading viewer gets frames while the stalled one holds its socket full.
    let mut waited = 0;
    while read.load(Ordering::Relaxed) < 10 {
        std::thread::sleep(Duration::from_millis(10));
        waited += 1;
        assert!(waited < 6000, "the reading viewer got {} frames", read.load(Ordering::Relaxed));
    }
    stop.store(true, Ordering::Relaxed);
    drop(view);
    let _ = (reader.join(), stalled.join());
}

/// The frames a viewer gets of a crowd, whose figures the view's broadcaster draws from the states
/// the stepping thread copied while the crowd steps on, are the frames the view used to write on
/// the stepping thread, figures and all (`FrameMaker::write` with `figures_now`, on all of rayon's
/// threads for these 300 characters), at the same step: every received frame equals that frame,
/// bit for bit, over pushes that topple characters. Each frame is drawn three steps or more after
/// its step; the test waits for it (by counts) before the next one is due.
#[test]
fn view_frames_drawn_off_the_stepping_thread_are_the_frames_of_their_step() {
    use spidar_world::view::FrameMaker;
    let _one = one_at_a_time();
    let mut scene = spidar_lab::bench_view::crowd_of(300).unwrap();
    let look = scene.look();
    let mut view = View::start("crowd", &look, &any_port()).unwrap();
    let handle = view.counters_handle();
    let (got_tx, got_rx) = crossbeam_channel::unbounded::<Vec<u8>>();
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let (url, stop) = (view.ws_url().to_string(), stop.clone());
        std::thread::spawn(move || {
            let stream = std::net::TcpStream::connect(url.trim_start_matches("ws://")).unwrap();
            let (mut ws, _) = tungstenite::client(format!("{url}/"), stream).unwrap();
            let _ = ws.get_mut().set_read_timeout(Some(Duration::from_millis(100)));
            while !stop.load(Ordering::Relaxed) {
                match ws.read() {
                    Ok(tungstenite::Message::Binary(b)) => {
                        let _ = got_tx.send(b.to_vec());
                    }
                    Ok(_) | Err(tungstenite::Error::Io(_)) => {}
                    Err(_) => break,
                }
            }
        })
    };
    let c = handle.counters();
    let mut waited = 0;
    while c.viewers.load(Ordering::Relaxed) == 0 {
        std::thread::sleep(Duration::from_millis(10));
        waited += 1;
        assert!(waited < 6000, "the viewer never connected");
    }
    let mut reference = FrameMaker::new(&look);
    let l = *reference.layout();
    let mut buf = vec![0.0f32; l.max_words];
    // The frame published last: its sequence number, bytes, characters not balancing, and the
    // step it is checked at.
    let mut last: Option<(u32, Vec<u8>, usize, usize)> = None;
    let (mut published, mut compared, mut most_down) = (0, 0, 0);
    let info = rig_info(&rig());
    let status = known_rig_status();
    let mut sample = HandSample { hands: hands_at(0.0, 0.0, DVec3::ZERO), ..Default::default() };
    for k in 0..900 {
        if k % 100 == 20 {
            // A push that topples one of the characters.
            let i = (k / 100) * 31 % scene.crowd.len();
            let b = scene.crowd.body_space(i);
            scene.crowd.add_impulse_at(i, b.r_m + DVec3::Y * 0.5, DVec3::X * 150.0);
        }
        let t = k as f64 * 0.003;
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
        view.after_step(&v);
        reference.observe(&v, true);
        let p = c.frames_published.load(Ordering::Relaxed);
        if p > published {
            published = p;
            let words = reference.write(&mut buf, &v, true, true);
            let bytes: Vec<u8> = buf[..words].iter().flat_map(|w| w.to_le_bytes()).collect();
            let seq = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
            let down = (0..l.characters)
                .filter(|i| buf[l.characters_at + i * l.character_floats + CHARACTER_STATE] != 0.0)
                .count();
            last = Some((seq, bytes, down, k + 3));
        }
        if let Some((seq, want, down, at)) = last.take_if(|x| x.3 == k) {
            // The viewer gets it before the next frame is due (the test waits, by counts).
            let got = got_rx.recv_timeout(Duration::from_secs(60)).expect("the frame reached the viewer");
            assert_eq!(u32::from_le_bytes(got[8..12].try_into().unwrap()), seq, "the frame published last");
            // The live view stamps its frames with the tick's wall-clock time (the reference, like
            // a recording, does not): within a minute of now, and otherwise the same frame.
            let wall_ms = f64::from_le_bytes(got[32..40].try_into().unwrap());
            let now_ms =
                std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_secs_f64()
                    * 1e3;
            assert!(
                (now_ms - wall_ms).abs() < 60e3,
                "the tick's wall-clock time {wall_ms} ms, now {now_ms} ms"
            );
            let mut want = want;
            want[32..40].copy_from_slice(&got[32..40]);
            // The live view also marks the strings near each other or a forearm in the flags'
            // low 16 bits (from the rig's hands, `rigview`); the reference writer does not.
            want[12..14].copy_from_slice(&got[12..14]);
            assert!(got == want, "frame {seq} (step {}, {down} characters not balancing) differs", at - 3);
            compared += 1;
            most_down = most_down.max(down);
        }
    }
    assert!(compared >= 140, "{compared} frames compared");
    assert!(most_down > 0, "no frame compared had a character off balance");
    assert_eq!(c.frames_skipped.load(Ordering::Relaxed), 0);
    stop.store(true, Ordering::Relaxed);
    drop(view);
    let _ = reader.join();
}

/// The observer's call after a step allocates nothing, with viewers connected and frames flowing.
#[test]
fn view_observer_allocates_nothing_per_step() {
    let _one = one_at_a_time();
    observer_allocates_nothing(BoxingScene::new(Default::default()).unwrap(), "boxing");
    // The crowd's frames carry its figures' states, copied while the frame is written.
    observer_allocates_nothing(CrowdScene::builtin().unwrap(), "crowd");
}

fn observer_allocates_nothing<S: Scene>(mut scene: S, name: &str) {
    let look = scene.look();
    let mut view = View::start(name, &look, &any_port()).unwrap();
    let handle = view.counters_handle();
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(AtomicU64::new(0));
    let reader = viewer(view.ws_url(), true, frames.clone(), stop.clone());
    while handle.counters().viewers.load(Ordering::Relaxed) == 0 {
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut run = |n: usize, guarded: bool| {
        step_observed(&mut scene, n, |v| {
            if guarded {
                no_alloc(|| view.after_step(v));
            } else {
                view.after_step(v);
            }
        })
    };
    run(100, false);
    let (before, _) = forbidden_allocs();
    run(1000, true);
    let (after, first) = forbidden_allocs();
    assert_eq!(after - before, 0, "the {name} observer allocated (first: {first} bytes)");
    assert!(handle.counters().frames_published.load(Ordering::Relaxed) >= 150, "{name}: frames were written");
    stop.store(true, Ordering::Relaxed);
    drop(view);
    let _ = reader.join();
}

/// The world's recorder after a step allocates nothing either: it makes the live view's frame (for
/// `spidar replay`) with the view's own code, into buffers taken from its pool, and a crowd's
/// figure states into buffers of its second pool.
#[test]
fn world_recorder_allocates_nothing_per_step() {
    recorder_allocates_nothing(BoxingScene::new(Default::default()).unwrap(), "boxing");
    recorder_allocates_nothing(CrowdScene::builtin().unwrap(), "crowd");
}

fn recorder_allocates_nothing<S: Scene>(mut scene: S, name: &str) {
    let look = scene.look();
    let path =
        std::env::temp_dir().join(format!("spidar-hil-alloc-{}-{name}.world.mcap", std::process::id()));
    let info = spidar_record::world::WorldInfo { name: name.into(), ..Default::default() };
    let (rec, mut obs) = spidar_record::world::WorldRecording::start(&path, &info, &look).unwrap();
    step_observed(&mut scene, 100, |v| obs.after_step(v));
    let (before, _) = forbidden_allocs();
    step_observed(&mut scene, 300, |v| no_alloc(|| obs.after_step(v)));
    let (after, first) = forbidden_allocs();
    assert_eq!(after - before, 0, "the {name} recorder allocated (first: {first} bytes)");
    let r = rec.finish();
    assert!(r.steps + r.dropped == 400 && r.error.is_none(), "{name}: {r}");
    assert!(r.steps > 0, "{name}: {r}");
    let _ = std::fs::remove_file(&path);
}

// ---------------------------------------------------------------------------------------------
// `spidar run`'s path: the view served by its child world process.

/// `spidar run --scene SCENE --script SCRIPT --view 127.0.0.1:0` on the simulated rig: the
/// rt-loop, and the child world process (this package's `spidar world`) started, watched and
/// linked by the session as `spidar run` does, with the view option passed through. The session
/// is polled on its own thread until `stop`.
pub(super) struct RunPath {
    /// The view's address, as the world printed it.
    pub(super) url: String,
    stop: spidar_runtime::signals::Stop,
    run: Option<JoinHandle<spidar_runtime::summary::SessionSummary>>,
    pub(super) said: Arc<Mutex<Vec<String>>>,
}

impl RunPath {
    pub(super) fn start(scene: &str, script: &str) -> RunPath {
        RunPath::start_on(scene, script, rig())
    }

    /// The same on a rig of the test's (a rig file with a screen, say).
    pub(super) fn start_on(scene: &str, script: &str, r: spidar_rt::Rig) -> RunPath {
        RunPath::start_with(scene, script, r, &[])
    }

    /// The same with more arguments for the world's view (`--view-tls CERT,KEY`, say).
    pub(super) fn start_with(scene: &str, script: &str, r: spidar_rt::Rig, view_args: &[String]) -> RunPath {
        use spidar_rt::rt_thread::RtOptions;
        use spidar_runtime::child_world::ChildWorldSpec;
        use spidar_runtime::session::{
            load_scripts, sim_device, LiveOptions, LiveSession, SimOptions, WorldChoice,
        };
        let stop = spidar_runtime::signals::Stop::detached();
        let said = Arc::new(Mutex::new(Vec::<String>::new()));
        let (url_tx, url_rx) = crossbeam_channel::bounded(1);
        let opts = LiveOptions {
            seconds: None,
            rt: RtOptions { fifo_priority: None, lock_memory: false, ..RtOptions::default() },
            spin_ns: 0,
            status_every: None,
            stop: stop.clone(),
            scene_name: scene.into(),
            script_name: script.into(),
            connect_timeout: Duration::from_secs(60),
            world_priority: None,
            recorder: None,
            supervisor: None,
        };
        let spec = ChildWorldSpec {
            program: env!("CARGO_BIN_EXE_spidar-hil-world").into(),
            prefix: Vec::new(),
            scene: scene.into(),
            restarts: 0,
            extra: ["--view".into(), "127.0.0.1:0".into()]
                .into_iter()
                .chain(view_args.iter().map(std::ffi::OsString::from))
                .collect(),
        };
        let (st, sd, script) = (stop.clone(), said.clone(), script.to_string());
        let run = std::thread::spawn(move || {
            let dev = sim_device(&r, load_scripts(&script, &r, 1).unwrap(), &SimOptions::default()).unwrap();
            let mut s = LiveSession::start(dev, &r, WorldChoice::Child(spec), &opts).unwrap();
            let mut url_tx = Some(url_tx);
            let mut say = |l: String| {
                // "live view at http://127.0.0.1:PORT (frames on ws://...)"
                if let Some(at) = l.split("live view at ").nth(1) {
                    if let Some(tx) = url_tx.take() {
                        let _ = tx.send(at.split(' ').next().unwrap_or("").to_string());
                    }
                }
                sd.lock().unwrap().push(l);
            };
            while s.poll(&mut |_| {}, &mut say) {
                if st.requested() {
                    s.request_stop();
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            s.finish(st.count(), &mut say).unwrap()
        });
        let url = url_rx.recv_timeout(Duration::from_secs(90)).unwrap_or_else(|_| {
            stop.request();
            panic!("the world process printed no view address; it said {:?}", said.lock().unwrap())
        });
        RunPath { url, stop, run: Some(run), said }
    }

    /// Stops the run (the rig stops, the world process ends) and gives its summary.
    pub(super) fn finish(mut self) -> spidar_runtime::summary::SessionSummary {
        self.stop.request();
        self.run.take().unwrap().join().expect("the session")
    }

    /// `GET path` from the world process's view server: the JSON it answers.
    pub(super) fn get(&self, path: &str) -> Value {
        use std::io::Read;
        let host = self.url.trim_start_matches("http://");
        let mut c = std::net::TcpStream::connect(host).unwrap();
        write!(c, "GET {path} HTTP/1.0\r\nHost: {host}\r\nConnection: close\r\n\r\n").unwrap();
        let mut text = String::new();
        c.read_to_string(&mut text).unwrap();
        let (head, body) = text.split_once("\r\n\r\n").expect("an HTTP answer");
        assert!(head.starts_with("HTTP/1.") && head.contains(" 200 "), "GET {path}: {head}");
        serde_json::from_str(body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
    }

    fn answer(&self, q: &Value) -> Value {
        match q["ask"].as_str().unwrap() {
            "check_live" => {
                let hud = q["hud"].as_object().unwrap();
                let text = |k: &str| hud.get(k).and_then(|v| v.as_str()).unwrap_or("(missing)").to_string();
                let mut world = self.get("/status.json");
                // A real-clock rig on a loaded 2-core machine may fault for a moment (a late
                // reply) and recover by itself after its recovery ticks: wait for that, and let
                // the HUD, read before, show the fault the world showed.
                let first_state = world["rig"]["state"].clone();
                let until = std::time::Instant::now() + std::time::Duration::from_secs(20);
                while world["rig"]["state"] == "faulted" && std::time::Instant::now() < until {
                    std::thread::sleep(std::time::Duration::from_millis(100));
                    world = self.get("/status.json");
                }
                assert_eq!(world["rig"]["state"], "active", "the world's status: {world}");
                assert_eq!(world["link"]["state"], "up", "the world's status: {world}");
                let hud_state = text("rig_state");
                assert!(
                    hud_state == "active" || (hud_state == "faulted" && first_state == "faulted"),
                    "the HUD's rig state {hud_state}; the world said {first_state}, then {}",
                    world["rig"]["state"]
                );
                assert_eq!(
                    text("link"),
                    "up",
                    "the HUD's world link; the world says {}",
                    world["link"]["state"]
                );
                assert!(text("scene").ends_with("boxing"), "the HUD's scene: {}", text("scene"));
                assert_eq!(world["viewers"], 1, "the world counts the browser");
                assert_eq!(text("viewers"), "1", "the HUD's viewers");
                let (page, steps) = (q["page_steps"].as_u64().unwrap(), world["steps"].as_u64().unwrap());
                assert!(steps >= page && page > 0, "the world's steps ({steps}) and the page's ({page})");
                let scene = self.get("/scene.json");
                assert_eq!(scene["name"], "boxing");
                json!({"ok": true})
            }
            other => json!({"error": format!("unknown question {other}")}),
        }
    }
}

impl Drop for RunPath {
    fn drop(&mut self) {
        self.stop.request();
        if let Some(r) = self.run.take() {
            let _ = r.join();
        }
    }
}

/// The page as a user opens it: `spidar run --view` passes the address to its child world
/// process, which serves the view there and prints where; a browser opened at that address
/// draws the virtual human, the grips and a HUD that agrees with the world's `/status.json`.
#[test]
fn view_served_by_spidar_runs_child_world_process() {
    let _one = one_at_a_time();
    if !browser_here("view_served_by_spidar_runs_child_world_process") {
        return;
    }
    let run = RunPath::start("boxing", "box");
    assert!(run.url.starts_with("http://127.0.0.1:") && !run.url.ends_with(":0"), "printed {}", run.url);
    // Boxing steps every 3 ms and a frame goes out after each step: the page is told 333 a second
    // (the headset interpolates over that interval), not the view's most, 1,000.
    let hz = run.get("/scene.json")["frame_hz"].as_f64().unwrap();
    assert!((hz - 1000.0 / 3.0).abs() < 0.01, "the scene message says {hz} frames a second");
    node(&["live", &run.url], |q| run.answer(q));
    // (Faults are not checked: this rig loop runs at normal priority, and a loaded machine makes
    // its replies late; the HUD shows whatever the rig reports.)
    let said = run.said.clone();
    let sum = run.finish();
    assert!(sum.clean_stop, "{sum}; the world said {:?}", said.lock().unwrap());
}

/// The README's pictures (`docs/img/`), taken by the same harness from `spidar run`'s path: the
/// simulated rig, the rt-loop and the child world process serving the view.
/// `cargo test -p spidar-tests --test hil view_screenshots -- --ignored`
#[test]
#[ignore = "writes docs/img: run by hand"]
fn view_screenshots_for_the_readme() {
    if !browser_here("view_screenshots_for_the_readme") {
        return;
    }
    let _one = one_at_a_time();
    let img = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/img");
    for (scene_name, script, shots) in [
        ("boxing", "box", vec![("eye", "boxing-eye.png", "4"), ("orbit", "boxing-side.png", "3")]),
        ("crowd", "spar", vec![("orbit", "crowd.png", "5")]),
    ] {
        let run = RunPath::start(scene_name, script);
        for (camera, file, wait) in shots {
            let path = img.join(file);
            node(
                &["screenshot", &run.url, camera, path.to_str().unwrap(), wait],
                |_| json!({"error": "no questions"}),
            );
        }
        let sum = run.finish();
        assert!(sum.clean_stop, "{sum}");
    }
}
