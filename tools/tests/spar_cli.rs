//! Two people box each other as processes (docs/spar.md): `spidar world --scene spar` and two
//! `spidar run --world ADDR` on simulated rigs with the `box` script's users (each its own seed),
//! over a Unix socket and over UDP on this host. Each rig's hands feel the other's body (force on
//! both rigs' hands, models received), the world says who joined and who boxes whom, and punches
//! land. Each rig's felt force is measured at its simulated grip: the test rebuilds the rig's
//! simulated plant from its recording, drives it with the recorded volts, checks it reads every
//! recorded encoder count, and compares the force its strings put on the grip with the contact
//! force the loop asked. The waits are generous bounds for a loaded machine; the runs use the
//! normal scheduler.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_spidar");

/// The first number after `key` in `text`.
fn number_after(text: &str, key: &str) -> Option<f64> {
    let rest = &text[text.find(key)? + key.len()..];
    let s: String =
        rest.trim_start().chars().take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-').collect();
    s.parse().ok()
}

/// A `spidar world --scene spar` process: where it listens, and its stderr as it comes.
struct World {
    child: std::process::Child,
    at: String,
    err: std::sync::mpsc::Receiver<String>,
    said: String,
}

impl World {
    fn start(listen: &str, extra: &[&str]) -> World {
        let mut child = Command::new(BIN)
            .args(["world", "--scene", "spar", "--listen", listen])
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
        assert!(first.contains("scene spar (two seats) listening on"), "{first}");
        let at = first.trim().rsplit(' ').next().unwrap().to_string();
        let (tx, err) = std::sync::mpsc::channel();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        World { child, at, err, said: String::new() }
    }

    /// The first line of stderr with `needle` in it (waiting up to a minute).
    fn line_with(&mut self, needle: &str) -> String {
        loop {
            let l = self
                .err
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("the world never said '{needle}': {}", self.said));
            self.said.push_str(&l);
            self.said.push('\n');
            if l.contains(needle) {
                return l;
            }
        }
    }

    /// Stops it (SIGINT) and returns all it said on stderr.
    fn stop(mut self) -> String {
        // SAFETY: kill(2) on our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        let ok = self.child.wait().unwrap().success();
        while let Ok(l) = self.err.recv_timeout(Duration::from_secs(10)) {
            self.said.push_str(&l);
            self.said.push('\n');
        }
        assert!(ok, "{}", self.said);
        self.said
    }
}

/// A simulated rig with the `box` script's user (its own seed) at the world `at`.
fn rig(at: &str, seed: &str, seconds: &str, extra: &[&str]) -> std::process::Child {
    rig_with("box", at, seed, seconds, extra)
}

/// A simulated rig whose user follows `script` at the world `at`.
fn rig_with(script: &str, at: &str, seed: &str, seconds: &str, extra: &[&str]) -> std::process::Child {
    Command::new(BIN)
        .args(["run", "--world", at, "--script", script, "--no-rt", "--seed", seed, "--seconds", seconds])
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Each rig ended well, boxed in the spar scene, received models and felt the other's body.
fn check_rigs(a: &std::process::Output, b: &std::process::Output) {
    for (name, o) in [("seat 0", a), ("seat 1", b)] {
        let out = String::from_utf8_lossy(&o.stdout);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: {out}\n{err}");
        assert!(out.contains("scene spar"), "{name}: {out}");
        let models = number_after(&out, "link").unwrap_or(0.0);
        assert!(models > 1000.0, "{name} received {models} models: {out}");
        let left = number_after(&out, "max force    left").unwrap();
        let right = number_after(&out, "N, right").unwrap();
        // The box script punches with either hand: each rig felt the other's body or guard.
        assert!(left.max(right) > 0.5, "{name} felt nothing: {out}");
    }
}

/// The default rig file's force limit per hand (configs/rig-spidar-h.ron, `force_limit_n`).
const FORCE_LIMIT_N: f64 = 4.0;

/// The simulated rig of a `spidar run` recording, rebuilt from what the recording says (its rig
/// file, script and seed; `spidar run`'s simulated rig has ideal motors, no encoder noise, no
/// slack) and driven exchange by exchange as the loop drove it (`RtLoop::configure`: open,
/// activate, one exchange with zero volts; then at every tick the volts the tick before
/// computed). Every encoder count it samples must be the one recorded, which proves it is the
/// same plant on the same trajectory. Returns the ticks in order and, for each, the force the
/// strings put on each grip while its volts were applied (the period after the next exchange:
/// `sum t_i u_i` at the simulated grip, `Truth::string_force_n`); None past a gap in the
/// recording or for the last tick.
fn grip_forces(
    path: &std::path::Path,
) -> (Vec<spidar_rt::telemetry::TickRecord>, Vec<Option<[glam::DVec3; 2]>>) {
    use spidar_device::{Device, Input, Output};
    use spidar_record::reader::{read, Flow, Msg};
    let mut ticks = Vec::new();
    let rec = read(path, |_, m| {
        if let Msg::Tick(t) = m {
            ticks.push(*t);
        }
        Ok(Flow::Continue)
    })
    .unwrap();
    let rig =
        spidar_rt::Rig::from_str(&rec.rig_text().expect("the rig file attached"), "the recording").unwrap();
    let seed: u64 = rec.meta("seed").parse().unwrap();
    let scripts = spidar_runtime::session::load_scripts(rec.meta("script"), &rig, seed).unwrap();
    let opts = spidar_runtime::session::SimOptions { seed, ..Default::default() };
    let mut sim = spidar_runtime::session::sim_device(&rig, scripts, &opts).unwrap();
    let mut inp = Input::default();
    sim.open().unwrap();
    sim.activate().unwrap();
    sim.exchange(&Output::default(), &mut inp).unwrap();
    let mut felt = vec![None; ticks.len()];
    let mut out = Output::default();
    for (k, t) in ticks.iter().enumerate() {
        if k > 0 && t.tick != ticks[k - 1].tick + 1 {
            eprintln!(
                "{}: a gap after tick {}: the grip is replayed up to it",
                path.display(),
                ticks[k - 1].tick
            );
            break;
        }
        sim.exchange(&out, &mut inp).unwrap();
        assert_eq!(inp, t.input, "{}: tick {}: the replayed rig read other counts", path.display(), t.tick);
        if k > 0 {
            let h = &sim.truth().hands;
            felt[k - 1] = Some([h[0].string_force_n, h[1].string_force_n]);
        }
        out = t.output;
    }
    (ticks, felt)
}

/// Why a touching hand-tick was not compared (the exclusion rule, in the order it is applied).
const EXCLUDED: [&str; 8] =
    ["faded", "blow", "reserve", "stiffness", "held", "not exact", "below 0.05 N", "not replayed"];

/// Below this the asked force is a graze, compared in newtons (see `felt_at_the_grip`).
const GRAZE_N: f64 = 0.5;

/// How the force felt at a rig's simulated grips compared with the contact force its loop asked,
/// over a bout.
#[derive(Debug, Default)]
struct Felt {
    /// Hand-ticks active, tracked and touching.
    touching: u64,
    /// Of those, not compared, by the first reason that holds (`EXCLUDED`).
    excluded: [u64; 8],
    /// Compared in newtons: a graze (asked 0.05-0.5 N), and the worst difference there (N).
    grazes: u64,
    graze_worst_n: f64,
    /// Compared, renderable as asked (within the limit), and the worst relative error there.
    as_asked: u64,
    as_asked_worst: f64,
    /// Compared, above the limit but otherwise renderable: felt against the asked force clamped
    /// to the limit along its own direction.
    clamped: u64,
    clamped_worst: f64,
    /// The largest difference between the grip's force and what the allocation said its
    /// tensions pull (`output_n`), over the compared hand-ticks (N).
    grip_vs_output_n: f64,
    /// Per hand, the longest time the force at the grip stayed above 0.5 N on end (s).
    held_s: [f64; 2],
}

/// Per tick of a rig's recording: the force the simulated strings put on the grip while the
/// tick's volts were applied (`grip_forces`) against the contact force the loop asked
/// (`rendered_n`, its local model of the avatar-hand contact), where the rig can render it:
/// active at full gain (not fading a stale model), the hand tracked and touching, no blow in it,
/// not scaled by the energy reserve, not stiffness-limited, not held, exactly allocatable,
/// above 0.05 N. Above the limit, against the asked force clamped to it. The motors are ideal
/// (`spidar run`'s simulated rig), so there is no settling to wait for: the tension commanded is
/// the tension pulled for the whole period. What remains is the hold: the strings pull along
/// the directions of the pose the encoders read up to 2 ms before (the pose the tick computed
/// from, then a period for the board to apply it), and a fist at punch speed (2-6 m/s) moves
/// 4-11 mm meanwhile, turning the pull of strings that carry 15-30 N together by up to about
/// 0.1 N whatever the force asked: 3 % of the 4 N limit, more than 5 % of a graze. A graze
/// (asked below 0.5 N) is compared in newtons.
fn felt_at_the_grip(path: &std::path::Path) -> Felt {
    use spidar_rt::tension::Method;
    let (ticks, grip) = grip_forces(path);
    let mut f = Felt::default();
    let mut run = [0u32; 2];
    for (t, g) in ticks.iter().zip(&grip) {
        for (hi, h) in t.hands.iter().enumerate() {
            let high = g.is_some_and(|g| g[hi].length() > GRAZE_N);
            run[hi] = if high { run[hi] + 1 } else { 0 };
            f.held_s[hi] = f.held_s[hi].max(f64::from(run[hi]) * 1e-3);
            if h.contacts == 0 || !h.valid || t.gain == 0.0 {
                continue;
            }
            f.touching += 1;
            let asked = h.rendered_n.length();
            let why = [
                t.gain != 1.0,
                h.blow_n != glam::DVec3::ZERO,
                h.passivity_limited,
                h.stiffness_limited,
                h.held,
                h.method != Method::Exact,
                asked <= 0.05,
                g.is_none(),
            ];
            if let Some(k) = why.iter().position(|&w| w) {
                f.excluded[k] += 1;
                continue;
            }
            let at_grip = g.unwrap()[hi];
            let want = h.rendered_n * (FORCE_LIMIT_N / asked).min(1.0);
            let err = (at_grip - want).length() / want.length();
            f.grip_vs_output_n = f.grip_vs_output_n.max((at_grip - h.output_n).length());
            if want.length() < GRAZE_N {
                f.grazes += 1;
                f.graze_worst_n = f.graze_worst_n.max((at_grip - want).length());
            } else if h.clamped {
                f.clamped += 1;
                f.clamped_worst = f.clamped_worst.max(err);
            } else {
                f.as_asked += 1;
                f.as_asked_worst = f.as_asked_worst.max(err);
            }
        }
    }
    f
}

/// A bout through `listen`: two rigs (recording their ticks) and the world, as processes.
fn bout(listen: &str) {
    let dir = std::env::temp_dir().join(format!(
        "spidar-spar-bout-{}-{}",
        std::process::id(),
        listen.starts_with("udp") as u8
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let (r0, r1) = (dir.join("seat0.mcap"), dir.join("seat1.mcap"));
    let world = World::start(listen, &["--no-view"]);
    let a = rig(&world.at, "1", "9", &["--record", r0.to_str().unwrap()]);
    std::thread::sleep(Duration::from_millis(500));
    let b = rig(&world.at, "2", "7", &["--record", r1.to_str().unwrap()]);
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    std::thread::sleep(Duration::from_millis(300));
    let world_err = world.stop();
    check_rigs(&a, &b);
    assert!(
        world_err.contains("seat 0: the rig at") && world_err.contains("joined, boxing a standing opponent")
    );
    assert!(
        world_err.contains("seat 1: the rig at") && world_err.contains("joined, boxing the person at seat 0")
    );
    // Seat 1's rig ends first and says goodbye ("stopped"); a world too loaded to keep up may
    // report it lost instead (seen once, at a load average of 16 with the tests in parallel:
    // "lost (silent for 0.01 s)", the goodbye not taken; not investigated further).
    let seat1_left = world_err.lines().any(|l| {
        l.contains("seat 1: the rig at")
            && (l.contains(" stopped; ") || l.contains(" lost (silent for "))
            && l.contains("seat 0 boxes a standing opponent")
    });
    assert!(seat1_left, "{world_err}");
    // The last status: "seat 0: WHO (N hits landed, M blocked) | seat 1: ...".
    let seat = |s: &str| &world_err[world_err.rfind(&format!("seat {s}: a standing opponent (")).unwrap()..];
    let hits = number_after(seat("0"), "(").unwrap() + number_after(seat("1"), "(").unwrap();
    let blocked = number_after(seat("0"), "landed,").unwrap() + number_after(seat("1"), "landed,").unwrap();
    assert!(hits >= 1.0, "no punch landed: {world_err}");
    assert!(blocked >= 1.0, "no punch was blocked: {world_err}");
    // Each user's hand feels the other's blocks and blows: the force at the simulated grip is
    // within 5 % of the contact force asked where the rig can render it, of the asked force
    // clamped to 4 N where it is above the limit. Most punches are far above 4 N.
    for (name, path) in [("seat 0", &r0), ("seat 1", &r1)] {
        let f = felt_at_the_grip(path);
        let pct = |n: u64| 100.0 * n as f64 / f.touching.max(1) as f64;
        let excluded: Vec<String> = EXCLUDED
            .iter()
            .zip(f.excluded)
            .filter(|(_, n)| *n > 0)
            .map(|(why, n)| format!("{why} {n} ({:.1} %)", pct(n)))
            .collect();
        eprintln!(
            "{listen} {name}: {} touching hand-ticks; at the grip against asked on {} ({:.1} %), worst {:.2} %; \
             against asked clamped to 4 N on {} ({:.1} %), worst {:.2} %; grazes (asked < 0.5 N) {} ({:.1} %), \
             worst {:.3} N; grip vs allocation within {:.4} N; excluded: {}",
            f.touching,
            f.as_asked,
            pct(f.as_asked),
            100.0 * f.as_asked_worst,
            f.clamped,
            pct(f.clamped),
            100.0 * f.clamped_worst,
            f.grazes,
            pct(f.grazes),
            f.graze_worst_n,
            f.grip_vs_output_n,
            excluded.join(", ")
        );
        // Below the limit is rare and depends on the bout's timing (0-17 hand-ticks a bout).
        assert!(f.as_asked + f.clamped >= 100, "{name}: too few hand-ticks to compare: {f:?}");
        assert!(
            f.as_asked_worst <= 0.05 && f.clamped_worst <= 0.05 && f.graze_worst_n <= 0.05,
            "{name}: felt at the grip off the asked force: {f:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_rigs_spar_through_one_world_over_a_unix_socket() {
    let dir = std::env::temp_dir().join(format!("spidar-spar-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o700)).unwrap();
    bout(&format!("unix:{}", dir.join("world.sock").display()));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_rigs_spar_through_one_world_over_udp() {
    bout("udp://127.0.0.1:0");
}

/// Two users clinch, as processes over UDP (each rig's user follows the lab's clinch script
/// file: both hands push into the other's chest for 1.5 s, twice): every hand holds the contact
/// (the force at its simulated grip above 0.5 N for 0.5 s on end at least), and the force at the
/// grip is within 5 % of the contact the loop asked where the rig can render it.
#[test]
fn two_rigs_clinch_through_one_world_over_udp() {
    let dir = std::env::temp_dir().join(format!("spidar-spar-clinch-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let script = dir.join("clinch.ron");
    let text = spidar_lab::spar::clinch_script_file(&spidar_rt::Rig::default_rig(), 1.5, 2).unwrap();
    std::fs::write(&script, text).unwrap();
    let (r0, r1) = (dir.join("seat0.mcap"), dir.join("seat1.mcap"));
    let world = World::start("udp://127.0.0.1:0", &["--no-view"]);
    let s = script.to_str().unwrap();
    let a = rig_with(s, &world.at, "1", "8", &["--record", r0.to_str().unwrap()]);
    std::thread::sleep(Duration::from_millis(300));
    let b = rig_with(s, &world.at, "2", "8", &["--record", r1.to_str().unwrap()]);
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    world.stop();
    check_rigs(&a, &b);
    for (name, path) in [("seat 0", &r0), ("seat 1", &r1)] {
        let f = felt_at_the_grip(path);
        eprintln!("clinch {name}: {f:?}");
        assert!(f.held_s.iter().all(|&s| s >= 0.5), "{name}: a hand held no contact: {f:?}");
        assert!(f.as_asked + f.clamped >= 100, "{name}: too few hand-ticks to compare: {f:?}");
        assert!(
            f.as_asked_worst <= 0.05 && f.clamped_worst <= 0.05 && f.graze_worst_n <= 0.05,
            "{name}: felt at the grip off the asked force: {f:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// True when node, chromium and `npm ci` in tests/browser are here; else says so loudly and
/// returns false, unless `SPIDAR_BROWSER_TESTS=required`, which makes it a failure.
fn browser_here(test: &str) -> bool {
    spidar_testkit::node::can_run(
        test,
        spidar_testkit::node::browser_missing(),
        "The spar view's browser test",
    )
}

/// The live view of a bout over UDP, watched by chromium (tests/browser/spar.mjs): both bodies
/// drawn where the world's frames put them, following the rigs (seat 0's gloves near its user's
/// hands, both seats' gloves moving as their users punch), each seat's eye looking at the other.
#[test]
fn the_live_view_shows_both_seats_from_either_persons_eye() {
    if !browser_here("the_live_view_shows_both_seats_from_either_persons_eye") {
        return;
    }
    let mut world = World::start("udp://127.0.0.1:0", &["--view", "127.0.0.1:0"]);
    let line = world.line_with("live view at ");
    let url = word_after(&line, "live view at ");
    let a = rig(&world.at, "1", "90", &[]);
    std::thread::sleep(Duration::from_millis(500));
    let b = rig(&world.at, "2", "90", &[]);
    world.line_with("joined, boxing the person at seat 0");
    let node = Command::new("node")
        .args(["spar.mjs", &url])
        .current_dir(spidar_testkit::node::browser_dir())
        .stdin(Stdio::null())
        .output()
        .expect("starting node");
    let out = String::from_utf8_lossy(&node.stdout).into_owned();
    for mut r in [a, b] {
        // SAFETY: kill(2) on our own child.
        unsafe { libc::kill(r.id() as i32, libc::SIGINT) };
        r.wait().unwrap();
    }
    world.stop();
    assert!(
        out.contains("RESULT ok"),
        "the browser test failed:\n{out}\n{}",
        String::from_utf8_lossy(&node.stderr)
    );
}

/// The word after `key` in `text`.
fn word_after(text: &str, key: &str) -> String {
    text[text.find(key).unwrap() + key.len()..].split_whitespace().next().unwrap().to_string()
}

/// A bout recorded by the world (`spidar world --scene spar --record`) and by each rig (`spidar
/// run --record` with `--world` at the spar world), read back: the world's file describes both
/// seats' bodies, its frames move both (their gloves and heads where two people box: seat 1 in
/// front), carry contacts between them and the hits; each rig's file holds its own ticks and the
/// models it received.
#[test]
fn a_bout_is_recorded_by_the_world_and_by_each_rig() {
    use spidar_record::play::ViewTrack;
    let dir = std::env::temp_dir().join(format!("spidar-spar-rec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (w, r0, r1) = (dir.join("bout.world.mcap"), dir.join("seat0.mcap"), dir.join("seat1.mcap"));
    let world = World::start("udp://127.0.0.1:0", &["--no-view", "--record", w.to_str().unwrap()]);
    let a = rig(&world.at, "1", "8", &["--record", r0.to_str().unwrap()]);
    std::thread::sleep(Duration::from_millis(500));
    let b = rig(&world.at, "2", "7", &["--record", r1.to_str().unwrap()]);
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let said = world.stop();
    check_rigs(&a, &b);
    assert!(said.contains("spidar world: recording"), "{said}");

    let track = ViewTrack::open(&w).unwrap();
    let desc: serde_json::Value = serde_json::from_str(&track.description).unwrap();
    assert_eq!(desc["name"], "spar");
    let names: Vec<&str> =
        desc["humanoids"].as_array().unwrap().iter().map(|h| h["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["seat 0", "seat 1"]);
    let shape = |name: &str| {
        desc["shapes"]
            .as_array()
            .unwrap()
            .iter()
            .position(|s| s["name"] == name)
            .unwrap_or_else(|| panic!("no {name}"))
    };
    let l = &desc["layout"];
    let at = |k: &str| l[k].as_u64().unwrap() as usize;
    let pos = |f: &[f32], k: usize| {
        let o = at("shapes_at") + k * at("shape_floats");
        glam::DVec3::new(f[o] as f64, f[o + 1] as f64, f[o + 2] as f64)
    };
    // A seat's solid of one part (the first, for hands the left).
    let part = |seat: usize, part: &str| {
        let h = &desc["humanoids"][seat];
        h["segments"].as_array().unwrap().iter().find(|s| s["part"] == part).unwrap()["shape"]
            .as_u64()
            .unwrap() as usize
    };
    let waists = [part(0, "waist"), part(1, "waist")];
    assert_eq!(waists, [shape("seat 0/waist"), shape("seat 1/waist")]);
    let gloves: Vec<usize> = desc["shapes"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .filter(|(_, s)| s["name"].as_str().unwrap().contains("hand"))
        .map(|(k, _)| k)
        .collect();
    assert_eq!(gloves.len(), 4, "two gloves per seat: {gloves:?}");
    let (mut first, mut moved, mut contacts, mut forced) = (None::<Vec<f32>>, [0.0f64; 4], 0usize, 0.0f32);
    let n = 60;
    for i in 0..=n {
        let t = track.first_t_s + (track.last_t_s - track.first_t_s) * i as f64 / n as f64;
        let f = track.frame_at(t).unwrap();
        let w = &f.frame;
        assert!(pos(w, waists[1]).z < pos(w, waists[0]).z - 0.5, "seat 1 stands in front of seat 0 at {t} s");
        let f0 = first.get_or_insert_with(|| w.clone());
        for (g, m) in gloves.iter().zip(moved.iter_mut()) {
            *m = m.max((pos(w, *g) - pos(f0, *g)).length());
        }
        contacts += w.len().saturating_sub(at("contacts_at")) / at("contact_floats");
        for g in &gloves {
            forced = forced.max(w[at("shape_force_at") + g]);
        }
    }
    assert!(moved.iter().all(|&m| m > 0.05), "every glove moved in the recording: {moved:?} m");
    assert!(contacts > 0 && forced > 0.5, "contacts recorded: {contacts}, most force on a glove {forced} N");
    let last = track.frame_at(track.last_t_s).unwrap();
    assert!(last.counters[0] + last.counters[1] >= 1.0, "hits recorded: {:?}", &last.counters[..2]);

    for (name, path, out) in [("seat 0", &r0, &a), ("seat 1", &r1, &b)] {
        let s = spidar_record::summary::summarize(path).unwrap();
        let models = number_after(&String::from_utf8_lossy(&out.stdout), "link").unwrap();
        assert!(s.active_ticks > 3000, "{name}: {} active ticks recorded", s.active_ticks);
        // The recording holds the models the loop took, each tick the newest that had arrived:
        // a loaded world that falls behind sends models in bursts, and the older of a burst is
        // superseded within the millisecond (87 % taken at a load average of 15); a loaded loop
        // also skips deadlines (5959 ticks in 8.49 s at 16), and the recorder may drop whole
        // ticks (counted as missing). Hence three quarters of the models received, of the share
        // of the milliseconds that had a recorded tick, and never more than were received.
        let r = &s.recording;
        let due = ((r.ticks + r.missing_ticks) as f64).max(r.last_t_s / 1e-3).max(1.0);
        let kept = r.ticks as f64 / due;
        assert!(
            s.models as f64 > 0.75 * models * kept && s.models as f64 <= models,
            "{name}: {} of {models} models recorded, {} of {due} ticks",
            s.models,
            r.ticks
        );
        assert!(s.hits[0] + s.hits[1] >= 1, "{name}: no contact onset recorded");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// True when node and `npm ci` in tests/foxglove are here; else says so loudly and returns false,
/// unless `SPIDAR_BROWSER_TESTS=required`, which makes it a failure.
fn foxglove_here(test: &str) -> bool {
    spidar_testkit::node::can_run(
        test,
        spidar_testkit::node::foxglove_missing(),
        "The spar world's Foxglove check",
    )
}

/// The spar world's channels live to Foxglove (`spidar world --scene spar --foxglove`), as its
/// recording holds them: a Foxglove WebSocket client (tests/foxglove/live.mjs, Foxglove's own
/// libraries) subscribed before the rigs join receives the world's channels while two rigs box,
/// every message decodes and equals the recording's of its topic and time, and nothing recorded
/// after it subscribed is missed.
#[test]
fn the_spar_world_serves_its_channels_live_to_foxglove() {
    if !foxglove_here("the_spar_world_serves_its_channels_live_to_foxglove") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("spidar-spar-fox-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let w = dir.join("bout.world.mcap");
    let mut world = World::start(
        "udp://127.0.0.1:0",
        &["--no-view", "--foxglove", "127.0.0.1:0", "--record", w.to_str().unwrap()],
    );
    let line = world.line_with("Foxglove live at");
    let url = line.split_whitespace().find(|x| x.starts_with("ws://")).unwrap().to_string();
    let mut node = Command::new("node")
        .args(["live.mjs", &url, w.to_str().unwrap()])
        .current_dir(spidar_testkit::node::foxglove_dir())
        .stdout(Stdio::piped())
        .spawn()
        .expect("starting node");
    let mut out = BufReader::new(node.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    assert!(first.contains("\"subscribed\":"), "{first}");
    let a = rig(&world.at, "1", "5", &[]);
    std::thread::sleep(Duration::from_millis(300));
    let b = rig(&world.at, "2", "4", &[]);
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let said = world.stop();
    check_rigs(&a, &b);
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut out, &mut rest).unwrap();
    assert!(node.wait().unwrap().success(), "{rest}");
    let line = rest.lines().rev().find(|l| l.starts_with('{')).unwrap_or_else(|| panic!("no JSON: {rest}"));
    let s: serde_json::Value = serde_json::from_str(line).unwrap();
    eprintln!("{first}{s}");
    assert!(said.contains("Foxglove: 1 clients"), "{said}");
    assert_eq!(s["schemasDiffer"], serde_json::json!([]), "the live schemas are the recording's");
    assert_eq!(s["decodeErrors"], serde_json::json!([]), "every message decodes");
    let (received, matched) = (s["received"].as_u64().unwrap(), s["matched"].as_u64().unwrap());
    // 4-5 s of bout at a step every 3 ms: a thousand steps and more.
    assert!(received > 1000, "{s}");
    assert_eq!(matched, received, "each message received equals the recording's of its topic and time: {s}");
    assert_eq!(matched, s["recordedFromFirst"].as_u64().unwrap(), "and nothing recorded was missed: {s}");
    for t in ["/world/tf", "/world/scene", "/world/view"] {
        assert!(s["perTopic"][t].as_u64().unwrap_or(0) > 0, "{t}: {s}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
