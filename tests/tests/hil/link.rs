//! The rig and the world as two OS processes: the world is `spidar-hil-world` (this package's
//! build of `spidar world`, the same library code), the rig is this test.
//!
//! On the virtual clock the world steps in lockstep with the rig (`--lockstep`), so a run through
//! the link is compared bit for bit with the same run in one process, and a `kill -9` lands at a
//! known tick. On the real clock the rig runs as `spidar run` does (`LiveSession`: a child world
//! started, watched and restarted by the session, or a world connected over UDP); those tests
//! check only what holds whatever the machine's load (forces, clamps, counts, who said what),
//! never how fast.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use spidar_link::{Endpoint, LinkState, LinkStats, PrivateDir};
use spidar_rt::rt_thread::RtOptions;
use spidar_rt::telemetry::TickRecord;
use spidar_runtime::child_world::ChildWorldSpec;
use spidar_runtime::session::{LiveOptions, LiveSession, WorldChoice};
use spidar_runtime::signals::Stop;

use super::*;

const WORLD_BIN: &str = env!("CARGO_BIN_EXE_spidar-hil-world");
/// Generous: a loaded 2-core machine may take seconds to start a process.
pub(super) const WAIT: Duration = Duration::from_secs(30);

/// A world process of this test.
pub(super) struct WorldProcess {
    pub(super) child: Child,
    pub(super) at: Endpoint,
    pub(super) said: Arc<Mutex<Vec<String>>>,
}

impl WorldProcess {
    /// Starts `spidar-hil-world` with `args` and waits for the line that says where it listens.
    pub(super) fn start(args: &[&str]) -> WorldProcess {
        let mut child = Command::new(WORLD_BIN)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting the world process");
        let said = Arc::new(Mutex::new(Vec::new()));
        let err = child.stderr.take().unwrap();
        let s = said.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                s.lock().unwrap().push(l);
            }
        });
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
        let addr = first.trim().rsplit(' ').next().unwrap_or("").to_string();
        let at = Endpoint::parse(&addr)
            .unwrap_or_else(|e| panic!("the world said {first:?} ({e}); stderr: {:?}", said.lock().unwrap()));
        WorldProcess { child, at, said }
    }

    /// kill -9.
    fn kill9(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// Waits (up to `WAIT`) until the world has said something containing `what`.
    pub(super) fn wait_for_line(&self, what: &str) -> bool {
        let until = Instant::now() + WAIT;
        while Instant::now() < until {
            if self.said.lock().unwrap().iter().any(|l| l.contains(what)) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }
}

impl Drop for WorldProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The front wall of `front_wall`, as a scene file the world process loads.
fn wall_file(dir: &Path, k_n_per_m: f64) -> PathBuf {
    let p = dir.join("front-wall.ron");
    std::fs::write(&p, front_wall_text(k_n_per_m, 5.0)).unwrap();
    p
}

/// Both hands (or the left only) pressing the front wall 1.5 cm past first contact.
fn pressing(both: bool) -> SimRig {
    let r = rig();
    let home = [r.hands[0].home_m, r.hands[1].home_m];
    let press = |h: usize| reach_and_hold(DVec3::new(home[h].x, 0.0, WALL_Z_M + 0.04 - 0.015));
    let scripts = [press(0), if both { press(1) } else { Script::hold(home[1]) }].map(|s| {
        let hold = s.start_hold_s.max(HOLD_AT_HOME_S);
        s.with_start_hold(hold)
    });
    sim_device(&r, scripts, &SimOptions::default()).unwrap()
}

fn lockstep_world(scene: &Path, listen: &str) -> WorldProcess {
    WorldProcess::start(&[
        "--scene",
        scene.to_str().unwrap(),
        "--listen",
        listen,
        "--lockstep",
        // The rig may pause between ticks as long as it likes: it is never taken as gone.
        "--rig-lost-s",
        "3600",
    ])
}

/// What a tick did to the user's hands (not its wall-clock timings).
fn same_tick(a: &TickRecord, b: &TickRecord) -> bool {
    a.tick == b.tick
        && a.t_s == b.t_s
        && a.gain == b.gain
        && a.contact_age_s == b.contact_age_s
        && a.state == b.state
        && a.hands.iter().zip(b.hands.iter()).all(|(x, y)| {
            x.pos_rig_m == y.pos_rig_m
                && x.commanded_n == y.commanded_n
                && x.tensions_n == y.tensions_n
                && x.contacts == y.contacts
        })
}

fn wall_through_a_world_process_is_bit_identical(listen: &str) {
    let dir = PrivateDir::for_process().unwrap();
    let file = wall_file(dir.path(), 2000.0);
    let listen = listen.replace("DIR", dir.path().to_str().unwrap());
    let world = lockstep_world(&file, &listen);
    let r = rig();
    let mut local = VirtualRun::new(pressing(false), &r, Some(Box::new(front_wall(2000.0, 5.0)))).unwrap();
    let mut remote = VirtualRun::with_world_process(pressing(false), &r, &world.at, None, WAIT).unwrap();
    local.home_and_activate();
    remote.home_and_activate();
    for i in 0..4000 {
        let (a, b) = (local.tick(), remote.tick());
        assert!(same_tick(&a, &b), "tick {i} differs:\n in process {a:?}\n two processes {b:?}");
    }
    let f = remote.rt.last_record().hands[0].commanded_n.length();
    assert!(f > 2.0, "the hand presses the wall through the link: {f} N");
    let felt = [truth(&local).hands[0].string_force_n, truth(&remote).hands[0].string_force_n];
    assert!((felt[0] - felt[1]).length() <= 0.05 * felt[0].length(), "{felt:?}");
    assert_eq!(remote.lockstep_timeouts(), 0);
    let st = remote.link_stats().unwrap();
    assert!(LinkStats::get(&st.models) > 1300, "{}", st.summary());
    assert_eq!(LinkStats::get(&st.malformed) + LinkStats::get(&st.foreign), 0, "{}", st.summary());
}

#[test]
fn the_wall_through_a_world_process_on_a_unix_socket_is_the_in_process_wall_bit_for_bit() {
    wall_through_a_world_process_is_bit_identical("unix:DIR/world.sock");
}

#[test]
fn the_wall_through_a_world_process_over_udp_on_localhost_is_the_in_process_wall_bit_for_bit() {
    wall_through_a_world_process_is_bit_identical("udp://127.0.0.1:0");
}

#[test]
fn kill_9_of_the_world_fades_force_to_zero_and_a_new_world_restores_it_without_homing() {
    let dir = PrivateDir::for_process().unwrap();
    let file = wall_file(dir.path(), 2000.0);
    let listen = format!("unix:{}", dir.join("world.sock").display());
    let mut world = lockstep_world(&file, &listen);
    let r = rig();
    let limit = [r.hands[0].force_limit_n, r.hands[1].force_limit_n];
    let mut v = VirtualRun::with_world_process(pressing(true), &r, &world.at, None, WAIT).unwrap();
    v.home_and_activate();
    v.run_ticks(3000);
    let before: Vec<f64> = v.rt.last_record().hands.iter().map(|h| h.commanded_n.length()).collect();
    assert!(before.iter().all(|f| *f > 2.0), "both hands press the wall: {before:?}");

    world.kill9();
    let (stale, fade) = (r.safety.contact_stale_after_s, r.safety.contact_fade_s);
    let limit_ticks = ((stale + fade) / r.period_s).ceil() as usize + 4;
    let mut prev = before.clone();
    let mut zero_at = None;
    let check = |rec: &TickRecord| {
        assert_eq!(rec.state, Lifecycle::Active, "the rig stays active");
        for (h, hr) in rec.hands.iter().enumerate() {
            assert!(hr.commanded_n.length() <= limit[h] + 1e-9, "above the clamp: {}", hr.commanded_n);
            let t = &r.hands[h];
            assert!(
                hr.tensions_n.iter().all(|x| *x >= t.tension_min_n - 1e-9 && *x <= t.tension_max_n + 1e-9),
                "tension out of range: {:?}",
                hr.tensions_n
            );
        }
    };
    for i in 0..limit_ticks + 300 {
        let rec = v.tick();
        check(&rec);
        let f: Vec<f64> = rec.hands.iter().map(|h| h.commanded_n.length()).collect();
        for h in 0..2 {
            assert!(
                f[h] <= prev[h] + 0.2,
                "tick {i}: hand {h} force rose from {} to {} while fading",
                prev[h],
                f[h]
            );
        }
        if rec.contact_age_s >= stale + fade {
            assert!(f.iter().all(|x| *x == 0.0), "tick {i}: the faded model still pushes: {f:?}");
        }
        if zero_at.is_none() && f.iter().all(|x| *x == 0.0) {
            zero_at = Some(i);
        }
        prev = f;
    }
    let zero_at = zero_at.expect("force never reached zero");
    assert!(zero_at <= limit_ticks, "zero after {zero_at} ticks, the fade allows {limit_ticks}");
    let st = v.link_stats().unwrap();
    assert_eq!(st.state(), LinkState::Lost);
    assert!(v.rt.core().is_homed());
    assert!(v.counters().stale > 0);
    let faults = v.counters().faults;

    // A new world at the same address: the rig's hellos find it; force ramps back, no homing.
    let _world2 = lockstep_world(&file, &listen);
    let ramp_ticks = (r.safety.ramp_in_s / r.period_s).round() as usize;
    let mut back_at = None;
    let mut first_push = None;
    let mut gain = 0.0;
    for i in 0..ramp_ticks + 1500 {
        let rec = v.tick();
        check(&rec);
        // No step: the force's gain rises no faster than the activation ramp.
        assert!(rec.gain - gain <= 1.0 / ramp_ticks as f64 + 1e-9, "tick {i}: gain {gain} -> {}", rec.gain);
        gain = rec.gain;
        let f: Vec<f64> = rec.hands.iter().map(|h| h.commanded_n.length()).collect();
        if first_push.is_none() && f.iter().any(|x| *x > 0.0) {
            first_push = Some(f.iter().cloned().fold(0.0, f64::max));
        }
        if back_at.is_none() && (0..2).all(|h| f[h] > 0.9 * before[h]) {
            back_at = Some(i);
        }
    }
    // The hand sank into the wall while nothing resisted (the arm pushes 1.5 cm past contact:
    // 30 N rendered), so 90 % of the old force returns early in the ramp, but from near zero.
    assert!(back_at.is_some(), "force came back");
    let first = first_push.unwrap();
    assert!(first < 0.2, "the first force after the restart is {first} N: a step, not a ramp");
    assert_eq!(LinkStats::get(&st.worlds), 2, "{}", st.summary());
    assert_eq!(st.state(), LinkState::Connected);
    assert!(v.rt.core().is_homed(), "still homed");
    assert_eq!(v.counters().faults, faults, "the world's death is no fault of the rig");
}

/// A world that speaks the wire format by hand and sends the rig everything a broken or hostile
/// world could: for every sample, a burst of odd datagrams and one model, some of them absurd.
fn hostile_world(
    dir: PathBuf,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<[u64; 6]> {
    use spidar_msg::handshake::Welcome;
    use spidar_msg::wire::{self, Message, MAX_DATAGRAM};
    use spidar_msg::{Proxy, ProxyId, ProxyShape, HANDS, MAX_PROXIES, STRINGS};
    use std::os::unix::net::UnixDatagram;
    let sock = UnixDatagram::bind(dir.join("world.sock")).unwrap();
    let stranger = UnixDatagram::bind(dir.join("stranger.sock")).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    std::thread::spawn(move || {
        let _ = dir;
        let mut rig_path = PathBuf::new();
        let mut buf = vec![0u8; MAX_DATAGRAM + 1];
        let mut out = vec![0u8; MAX_DATAGRAM];
        // malformed, wrong version, foreign, NaN stamp, future stamp, models
        let mut sent = [0u64; 6];
        let mut seq = 0u64;
        let mut k = 0u64;
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            let Ok((n, from)) = sock.recv_from(&mut buf) else { continue };
            let (h, m) = wire::decode(&buf[..n]).unwrap();
            // The rig's socket is in a private directory of its own: answer where it speaks from.
            rig_path = from.as_pathname().map(Path::to_path_buf).unwrap_or(rig_path);
            match m {
                Message::Hello(hello) => {
                    let w = Welcome {
                        rig_session: hello.rig_session,
                        world_session: 5,
                        hands: HANDS as u8,
                        strings: STRINGS as u8,
                        max_proxies: MAX_PROXIES as u8,
                        step_s: 0.003,
                        scene: Default::default(),
                    };
                    let n = wire::encode(&w, h.seq, &mut out).unwrap();
                    sock.send_to(&out[..n], &rig_path).unwrap();
                }
                Message::Sample(s) => {
                    k += 1;
                    seq += 1;
                    let mut m = spidar_msg::ContactModel { seq, stamp_s: s.t_s, ..Default::default() };
                    for hand in 0..2 {
                        let p = s.hands[hand].pos_world_m;
                        m.push(Proxy {
                            id: ProxyId { body: 1, part: hand as u16 },
                            shape: ProxyShape::Sphere {
                                centre_m: p + DVec3::new(0.0, 0.0, -0.05),
                                radius_m: 0.03,
                            },
                            k_n_per_m: match k % 4 {
                                0 => f64::NAN,
                                1 => 1e12,
                                2 => f64::INFINITY,
                                _ => 3000.0,
                            },
                            d_n_s_per_m: if k.is_multiple_of(5) { f64::NAN } else { 1e6 },
                            vel_m_per_s: DVec3::new(
                                0.0,
                                0.0,
                                if k.is_multiple_of(7) { f64::INFINITY } else { 40.0 },
                            ),
                            hand_mask: Proxy::BOTH_HANDS,
                        });
                    }
                    if k.is_multiple_of(9) {
                        m.extra_force_n = [DVec3::splat(f64::NAN), DVec3::splat(1e9)];
                    }
                    let len = wire::encode(&m, seq, &mut out).unwrap();
                    let d = out[..len].to_vec();
                    let send = |b: &[u8]| sock.send_to(b, &rig_path).unwrap();
                    match k % 6 {
                        0 => {
                            send(&d[..len - 7]); // truncated
                            send(&d[..3]); // not even a header
                            let mut x = d.clone();
                            x[0] ^= 0xff; // bad magic
                            send(&x);
                            let mut x = d.clone();
                            x[6] = 200; // unknown kind
                            send(&x);
                            let mut x = d.clone();
                            x.extend_from_slice(&[0; 5]); // too long
                            send(&x);
                            sent[0] += 5;
                        }
                        1 => {
                            let mut x = d.clone();
                            x[4] = 9; // another protocol version
                            send(&x);
                            sent[1] += 1;
                        }
                        2 => {
                            stranger.send_to(&d, &rig_path).unwrap(); // someone else on the host
                            sent[2] += 1;
                        }
                        3 => {
                            let mut nan = m;
                            nan.stamp_s = f64::NAN;
                            let n = wire::encode(&nan, seq, &mut out).unwrap();
                            send(&out[..n]);
                            sent[3] += 1;
                        }
                        4 => {
                            let mut future = m;
                            future.stamp_s = s.t_s + 1e6;
                            let n = wire::encode(&future, seq, &mut out).unwrap();
                            send(&out[..n]);
                            sent[4] += 1;
                        }
                        _ => {}
                    }
                    send(&d);
                    sent[5] += 1;
                }
                _ => {}
            }
        }
        sent
    })
}

#[test]
fn a_world_sending_malformed_datagrams_and_hostile_models_changes_nothing_beyond_the_clamps() {
    let dir = PrivateDir::for_process().unwrap();
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let world = hostile_world(dir.path().to_path_buf(), stop.clone());
    let r = rig();
    let scripts = load_scripts("spar", &r, 5).unwrap();
    let dev = sim_device(&r, scripts, &SimOptions::default()).unwrap();
    let mut v = VirtualRun::with_world_process(dev, &r, &Endpoint::unix(&dir.join("world.sock")), None, WAIT)
        .unwrap();
    v.home_and_activate();
    let mut clamped = 0;
    for i in 0..6000 {
        let rec = v.tick();
        assert!(rec.state == Lifecycle::Active || i < 200 && rec.state == Lifecycle::Inactive, "{rec:?}");
        for (h, hr) in rec.hands.iter().enumerate() {
            let t = &r.hands[h];
            assert!(
                hr.commanded_n.is_finite() && hr.commanded_n.length() <= t.force_limit_n + 1e-9,
                "{}",
                hr.commanded_n
            );
            assert!(hr.output_n.length() <= t.force_limit_n + 1e-9);
            assert!(hr
                .tensions_n
                .iter()
                .all(|x| x.is_finite() && *x >= t.tension_min_n - 1e-9 && *x <= t.tension_max_n + 1e-9));
            clamped += hr.clamped as u32;
        }
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let sent = world.join().unwrap();
    v.run_ticks(50); // take what is still queued
    let st = v.link_stats().unwrap();
    let g = |c: &std::sync::atomic::AtomicU64| LinkStats::get(c);
    assert_eq!(g(&st.malformed), sent[0], "{}", st.summary());
    assert_eq!(g(&st.wrong_version), sent[1]);
    assert_eq!(g(&st.foreign), sent[2]);
    assert_eq!(g(&st.bad_stamps), sent[3]);
    assert_eq!(g(&st.future_stamps), sent[4]);
    assert!(sent.iter().all(|n| *n > 50), "each kind was sent: {sent:?}");
    let c = v.counters();
    assert!(clamped > 100, "the hostile models needed the clamp");
    assert!(c.non_finite > 0 && c.stiffness_limited.iter().sum::<u64>() > 0, "{c:?}");
    assert_eq!(c.faults, 0, "nothing the world sends faults the rig");
}

// ---------------------------------------------------------------------------------------------
// The real clock, as `spidar run` runs: a child world, restarts, UDP.

fn live_options(scene: &str) -> LiveOptions {
    LiveOptions {
        seconds: None,
        // Tests must not take the machine's real-time priority from others.
        rt: RtOptions { fifo_priority: None, lock_memory: false, ..RtOptions::default() },
        spin_ns: 0,
        status_every: None,
        stop: Stop::detached(),
        scene_name: scene.into(),
        script_name: "press".into(),
        connect_timeout: WAIT,
        world_priority: None,
        supervisor: None,
        recorder: None,
    }
}

/// Polls `s` until `f` says so for a record (every record goes through it) or `WAIT` passes.
fn pump<D: spidar_device::Device + 'static>(
    s: &mut LiveSession<D>,
    said: &mut Vec<String>,
    mut f: impl FnMut(&TickRecord) -> bool,
) -> bool {
    let until = Instant::now() + WAIT;
    let mut done = false;
    while !done && Instant::now() < until {
        let running = s.poll(&mut |rec| done |= f(rec), &mut |l| said.push(l));
        assert!(running, "the loop stopped; the world said {said:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
    done
}

fn both_press(rec: &TickRecord) -> bool {
    rec.hands.iter().all(|h| h.commanded_n.length() > 2.0)
}

#[test]
fn spidar_run_restarts_a_killed_child_world_and_force_returns_without_homing() {
    let dir = PrivateDir::for_process().unwrap();
    let file = wall_file(dir.path(), 2000.0);
    let r = rig();
    let spec = ChildWorldSpec {
        program: WORLD_BIN.into(),
        prefix: Vec::new(),
        scene: file.to_str().unwrap().into(),
        restarts: 2,
        extra: Vec::new(),
    };
    let mut s = LiveSession::start(pressing(true), &r, WorldChoice::Child(spec), &live_options("front wall"))
        .unwrap();
    let (stale, fade) = (r.safety.contact_stale_after_s, r.safety.contact_fade_s);
    let mut said = Vec::new();
    let mut bad = Vec::new();
    let mut active_seen = false;
    let mut check = |rec: &TickRecord| {
        active_seen |= rec.state == Lifecycle::Active;
        if active_seen && rec.state != Lifecycle::Active {
            bad.push(format!("left Active (no homing may happen): {rec:?}"));
        }
        for (h, hr) in rec.hands.iter().enumerate() {
            let t = &r.hands[h];
            if hr.commanded_n.length() > t.force_limit_n + 1e-9 {
                bad.push(format!("above the clamp: {rec:?}"));
            }
            if hr.tensions_n.iter().any(|x| *x < t.tension_min_n - 1e-9 || *x > t.tension_max_n + 1e-9) {
                bad.push(format!("tension out of range: {rec:?}"));
            }
        }
        if rec.contact_age_s >= stale + fade && rec.hands.iter().any(|h| h.commanded_n != DVec3::ZERO) {
            bad.push(format!("a faded model still pushes: {rec:?}"));
        }
    };
    // Both hands press the wall through the world process, for 200 ticks in a row.
    let mut steady = 0;
    let pressed = pump(&mut s, &mut said, |rec| {
        check(rec);
        steady = if both_press(rec) { steady + 1 } else { 0 };
        steady >= 200
    });
    assert!(pressed, "both hands pressing through the child world; it said {said:?}");
    let pid = s.world_pid().expect("a child world");
    // SAFETY: kill on our child's pid: kill -9 of the world.
    assert_eq!(unsafe { libc::kill(pid as i32, libc::SIGKILL) }, 0);
    // The force fades (to zero if the new world takes longer than the fade: that depends on the
    // machine; the lockstep test above pins it); the session restarts the world; force comes
    // back, with no homing.
    let (mut faded, mut back) = (false, 0);
    let restored = pump(&mut s, &mut said, |rec| {
        check(rec);
        faded |= rec.gain < 1.0 && rec.contact_age_s > stale;
        back = if faded && both_press(rec) { back + 1 } else { 0 };
        back >= 200
    });
    assert!(faded, "the force faded after the kill; the world said {said:?}");
    assert!(restored, "force came back with the restarted world; it said {said:?}");
    assert_eq!(s.world_starts(), 2);
    assert!(
        said.iter()
            .any(|l| l.contains("was killed (signal 9, SIGKILL)") && l.contains("restarting it (1 of 2")),
        "{said:?}"
    );
    assert!(said.iter().any(|l| l.contains("world lost")), "{said:?}");
    s.request_stop();
    while s.poll(&mut |_| {}, &mut |l| said.push(l)) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let sum = s.finish(0, &mut |l| said.push(l)).unwrap();
    assert!(bad.is_empty(), "{} bad ticks, first: {:?}", bad.len(), bad.first());
    assert!(sum.clean_stop, "{sum}");
    assert_eq!(sum.counters.faults, 0, "{sum}");
    assert!(sum.world.contains("starts 2"), "{}", sum.world);
}

#[test]
fn spidar_run_feels_the_wall_of_a_world_over_udp_and_the_world_pauses_when_the_rig_stops() {
    let dir = PrivateDir::for_process().unwrap();
    let file = wall_file(dir.path(), 2000.0);
    let world = WorldProcess::start(&["--scene", file.to_str().unwrap(), "--listen", "udp://127.0.0.1:0"]);
    assert!(matches!(world.at, Endpoint::Udp(a) if a.ip().is_loopback()));
    let r = rig();
    // The same press on the virtual clock in one process: the force the link must reproduce.
    let mut local = VirtualRun::new(pressing(false), &r, Some(Box::new(front_wall(2000.0, 5.0)))).unwrap();
    local.home_and_activate();
    local.run_ticks(4000);
    let want = local.rt.last_record().hands[0].commanded_n.length();
    assert!(want > 2.0);

    let scene = Some(file.to_str().unwrap().to_string());
    let mut s = LiveSession::start(
        pressing(false),
        &r,
        WorldChoice::Connect { at: world.at.clone(), scene },
        &live_options("front wall"),
    )
    .unwrap();
    let mut said = Vec::new();
    let mut forces = Vec::new();
    let start = Instant::now();
    // 4 s of rig time (the plant advances one period per tick), then the last second's median.
    while forces.len() < 4000 && start.elapsed() < 3 * WAIT {
        assert!(s.poll(&mut |rec| forces.push(rec.hands[0].commanded_n.length()), &mut |l| said.push(l)));
        std::thread::sleep(Duration::from_millis(5));
    }
    s.request_stop();
    while s.poll(&mut |_| {}, &mut |l| said.push(l)) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let sum = s.finish(0, &mut |l| said.push(l)).unwrap();
    assert!(forces.len() >= 4000, "{} ticks", forces.len());
    let mut last: Vec<f64> = forces[3000..4000].to_vec();
    last.sort_by(f64::total_cmp);
    let median = last[500];
    assert!((median - want).abs() < 0.05 * want, "over UDP {median} N, in one process {want} N");
    assert!(sum.clean_stop && sum.counters.faults == 0, "{sum}");
    assert!(sum.link.as_deref().is_some_and(|l| l.contains("0 malformed")), "{:?}", sum.link);
    // The rig said goodbye: the world pauses its scene and says so.
    assert!(
        world.wait_for_line("stopped: scene paused, waiting for a rig"),
        "{:?}",
        world.said.lock().unwrap()
    );
}

#[test]
fn a_child_world_ends_when_the_rig_that_started_it_is_gone() {
    // PR_SET_PDEATHSIG fires when the thread that started the child ends: a thread stands in for
    // a rig process killed with kill -9 (which cannot be done to this test process).
    let dir = PrivateDir::for_process().unwrap();
    let at = Endpoint::unix(&dir.join("world.sock"));
    let spec = ChildWorldSpec {
        program: WORLD_BIN.into(),
        prefix: Vec::new(),
        scene: "walls".into(),
        restarts: 0,
        extra: Vec::new(),
    };
    let pid = std::thread::spawn(move || {
        let child = spidar_runtime::child_world::ChildWorld::start(spec, &at).unwrap();
        let pid = child.pid().unwrap();
        std::mem::forget(child); // no clean stop: the "rig" just vanishes
        pid
    })
    .join()
    .unwrap();
    let until = Instant::now() + WAIT;
    let mut status = 0;
    let mut ended = false;
    while Instant::now() < until && !ended {
        // SAFETY: waitpid on our own child, without blocking.
        ended = unsafe { libc::waitpid(pid as i32, &mut status, libc::WNOHANG) } == pid as i32;
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(ended, "the world outlived the rig that started it");
    // A clean exit if its signal handler was in place yet, else the signal's default action.
    let clean = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    let termed = libc::WIFSIGNALED(status) && libc::WTERMSIG(status) == libc::SIGTERM;
    assert!(clean || termed, "it ended on SIGTERM: status {status:#x}");
}
