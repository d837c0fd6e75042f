//! Two people box each other as processes (docs/spar.md): `spidar world --scene spar` and two
//! `spidar run --world ADDR` on simulated rigs with the `box` script's users (each its own seed),
//! over a Unix socket and over UDP on this host. Each rig's hands feel the other's body (force on
//! both rigs' hands, models received), the world says who joined and who boxes whom, and punches
//! land. The waits are generous bounds for a loaded machine; the runs use the normal scheduler.

use std::io::{BufRead, BufReader, Read};
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

fn bout(listen: &str) {
    let mut world = Command::new(BIN)
        .args(["world", "--scene", "spar", "--listen", listen])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(world.stdout.take().unwrap()).read_line(&mut first).unwrap();
    let at = first.trim().rsplit(' ').next().unwrap().to_string();
    assert!(first.contains("scene spar (two seats) listening on"), "{first}");
    let rig = |seed: &str, seconds: &str| {
        Command::new(BIN)
            .args(["run", "--world", &at, "--script", "box", "--no-rt", "--seed", seed, "--seconds", seconds])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let a = rig("1", "9");
    std::thread::sleep(Duration::from_millis(500));
    let b = rig("2", "7");
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(world.id() as i32, libc::SIGINT) };
    let mut world_err = String::new();
    world.stderr.take().unwrap().read_to_string(&mut world_err).unwrap();
    assert!(world.wait().unwrap().success(), "{world_err}");
    for (name, o) in [("seat 0", &a), ("seat 1", &b)] {
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
