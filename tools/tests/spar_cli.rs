//! Two people box each other as processes (docs/spar.md): `spidar world --scene spar` and two
//! `spidar run --world ADDR` on simulated rigs with the `box` script's users (each its own seed),
//! over a Unix socket and over UDP on this host. Each rig's hands feel the other's body (force on
//! both rigs' hands, models received), the world says who joined and who boxes whom, and punches
//! land. The waits are generous bounds for a loaded machine; the runs use the normal scheduler.

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
    Command::new(BIN)
        .args(["run", "--world", at, "--script", "box", "--no-rt", "--seed", seed, "--seconds", seconds])
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

fn bout(listen: &str) {
    let world = World::start(listen, &["--no-view"]);
    let a = rig(&world.at, "1", "9", &[]);
    std::thread::sleep(Duration::from_millis(500));
    let b = rig(&world.at, "2", "7", &[]);
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
    assert!(
        world_err.contains("seat 1: the rig at")
            && world_err.contains("stopped; seat 0 boxes a standing opponent"),
        "{world_err}"
    );
    let hits0 = number_after(&world_err, "seat 0: a standing opponent (").unwrap();
    let hits1 = number_after(&world_err, "seat 1: a standing opponent (").unwrap();
    assert!(hits0 + hits1 >= 1.0, "no punch landed: {world_err}");
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

fn browser_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/browser")
}

/// True when node, chromium and `npm ci` in tests/browser are here; else says so loudly and
/// returns false, unless `SPIDAR_BROWSER_TESTS=required`, which makes it a failure.
fn browser_here(test: &str) -> bool {
    let chromium = std::env::var("SPIDAR_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    let why = if !std::path::Path::new(&chromium).exists() {
        format!("no chromium at {chromium} (apt-get install chromium, or set SPIDAR_CHROMIUM)")
    } else if Command::new("node").arg("--version").output().map(|o| !o.status.success()).unwrap_or(true) {
        "no node on PATH".into()
    } else if !browser_dir().join("node_modules/puppeteer-core").exists() {
        format!("no puppeteer-core: run npm ci in {}", browser_dir().display())
    } else {
        return true;
    };
    if std::env::var("SPIDAR_BROWSER_TESTS").as_deref() == Ok("required") {
        panic!("{test}: the browser test cannot run: {why} (SPIDAR_BROWSER_TESTS=required)");
    }
    eprintln!("\n*** SKIPPED {test}: {why}. The spar view's browser test did not run. ***\n");
    false
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
    let a = rig(&world.at, "1", "40", &[]);
    std::thread::sleep(Duration::from_millis(500));
    let b = rig(&world.at, "2", "40", &[]);
    world.line_with("joined, boxing the person at seat 0");
    let node = Command::new("node")
        .args(["spar.mjs", &url])
        .current_dir(browser_dir())
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
