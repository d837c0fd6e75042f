//! The harness of the kill tests: a child process writes a file (a recording) until it is killed
//! with SIGKILL, mid-write, once the file holds enough. What is left must still read.
//!
//! Must never: kill before the file has grown past the size asked (the test would prove nothing),
//! or wait for ever (a child that ends by itself or writes too little fails the test).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Starts this test binary again as a child that runs only the ignored test `test` (its full
/// path, e.g. `record::child_records_a_live_session_until_killed`), with `env` set to `value` so
/// the test knows it is the child (it returns at once otherwise). Its output is dropped.
pub fn spawn_test_child(test: &str, env: &str, value: &Path) -> Child {
    Command::new(std::env::current_exe().expect("the test binary"))
        .args(["--exact", test, "--ignored", "--nocapture"])
        .env(env, value)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start the test binary as a child")
}

/// Waits until `path` holds more than `bytes` bytes, then kills `child` with SIGKILL (no clean-up
/// of any kind) and reaps it. Panics, saying why, when the child ends by itself first or the file
/// has not grown that far within `within`.
pub fn kill_once_written(child: &mut Child, path: &Path, bytes: u64, within: Duration) {
    let deadline = Instant::now() + within;
    loop {
        let len = std::fs::metadata(path).map_or(0, |m| m.len());
        if len > bytes {
            break;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the writing child ended by itself ({status}) at {len} bytes");
        }
        assert!(Instant::now() < deadline, "the writing child wrote only {len} bytes in {within:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().expect("SIGKILL the child"); // SIGKILL: no clean-up of any kind
    child.wait().expect("reap the child");
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;

    fn temp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("spidar-testkit-{}-{name}", std::process::id()))
    }

    /// The child of the test below (skipped otherwise): appends 1 KiB to the file every 2 ms
    /// for up to a minute, from this one process (no helper process that could outlive a kill).
    #[test]
    #[ignore = "the child process of the kill test"]
    fn child_writes_until_killed() {
        use std::io::Write;
        let Some(path) = std::env::var_os("SPIDAR_TESTKIT_CHILD") else { return };
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path).unwrap();
        for _ in 0..30_000 {
            f.write_all(&[0u8; 1024]).unwrap();
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    #[test]
    fn the_child_is_killed_only_once_the_file_has_grown() {
        let path = temp("grows");
        let _ = std::fs::remove_file(&path);
        let mut child =
            spawn_test_child("kill::tests::child_writes_until_killed", "SPIDAR_TESTKIT_CHILD", &path);
        kill_once_written(&mut child, &path, 64 * 1024, Duration::from_secs(60));
        let len = std::fs::metadata(&path).unwrap().len();
        assert!(len > 64 * 1024, "{len}");
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(std::fs::metadata(&path).unwrap().len(), len, "nothing writes after the kill");
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    #[should_panic(expected = "ended by itself")]
    fn a_child_that_ends_by_itself_fails_the_test() {
        let path = temp("never");
        let mut child = Command::new("true").spawn().unwrap();
        kill_once_written(&mut child, &path, 1, Duration::from_secs(30));
    }
}
