//! The world as a child process of `spidar run`: started from this same executable
//! (`spidar world`), watched, restarted a bounded number of times, and ended with the rig.
//!
//! The child gets its own process group (a Ctrl-C in the terminal goes to the rig, which ramps
//! out and then ends the world), dies with its parent (`PR_SET_PDEATHSIG`: a rig killed by
//! `kill -9` leaves no world behind), and runs with the normal scheduler, below the rig's
//! real-time loop. Its stderr comes back through a pipe: `@status` lines feed the rig's status
//! line, the rest is shown as `world: ...`.

use std::ffi::OsString;
use std::io::BufRead;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use crossbeam_channel::{unbounded, Receiver, Sender};
use spidar_link::Endpoint;

use crate::signals::describe_exit;

/// Marks a status line on a child world's stderr (written by `world_process`, read here).
pub const STATUS_PREFIX: &str = "@status ";
/// Marks the final report line on a child world's stderr.
pub const REPORT_PREFIX: &str = "@report ";

/// How to start a world process.
#[derive(Clone, Debug)]
pub struct ChildWorldSpec {
    /// The program, and the arguments before the world's own (`spidar world`: this executable
    /// and `world`).
    pub program: PathBuf,
    pub prefix: Vec<OsString>,
    /// The `--scene` argument.
    pub scene: String,
    /// Restarts allowed after the first start.
    pub restarts: u32,
    /// More arguments for the world.
    pub extra: Vec<OsString>,
}

impl ChildWorldSpec {
    /// `spidar world` from the running executable.
    pub fn this_executable(scene: &str, restarts: u32) -> anyhow::Result<ChildWorldSpec> {
        let program =
            std::env::current_exe().context("finding this executable to start the world process")?;
        Ok(ChildWorldSpec {
            program,
            prefix: vec!["world".into()],
            scene: scene.into(),
            restarts,
            extra: Vec::new(),
        })
    }
}

/// A watched world process.
pub struct ChildWorld {
    spec: ChildWorldSpec,
    listen: Endpoint,
    child: Option<Child>,
    reader: Option<JoinHandle<()>>,
    lines_tx: Sender<String>,
    lines: Receiver<String>,
    /// Times started (the first start included).
    pub starts: u32,
    /// The process id of the newest world started.
    pub last_pid: u32,
    /// The newest `@status` line: steps and the scene's status.
    pub status: Option<(u64, String)>,
    /// The final report of the last world that ended cleanly.
    pub report: Option<String>,
    /// How each world that ended on its own ended.
    pub exits: Vec<String>,
    gave_up: bool,
    /// Lines already read (while the world started), given to `show` at the next read.
    held: Vec<String>,
}

impl ChildWorld {
    /// Starts a world listening at `listen` (a Unix socket in a private directory, for
    /// `spidar run`).
    pub fn start(spec: ChildWorldSpec, listen: &Endpoint) -> anyhow::Result<ChildWorld> {
        let (lines_tx, lines) = unbounded();
        let mut w = ChildWorld {
            spec,
            listen: listen.clone(),
            child: None,
            reader: None,
            lines_tx,
            lines,
            starts: 0,
            last_pid: 0,
            status: None,
            report: None,
            exits: Vec::new(),
            gave_up: false,
            held: Vec::new(),
        };
        w.spawn()?;
        Ok(w)
    }

    fn spawn(&mut self) -> anyhow::Result<()> {
        let mut cmd = Command::new(&self.spec.program);
        cmd.args(&self.spec.prefix)
            .arg("--scene")
            .arg(&self.spec.scene)
            .arg("--listen")
            .arg(self.listen.to_string())
            .arg("--report-status")
            .args(&self.spec.extra)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let parent = std::process::id();
        // SAFETY: only async-signal-safe calls (setpgid, prctl, getppid, sched_setscheduler)
        // between fork and exec, and no allocation.
        unsafe {
            cmd.pre_exec(move || {
                libc::setpgid(0, 0);
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                if libc::getppid() as u32 != parent {
                    return Err(std::io::Error::from_raw_os_error(libc::ESRCH)); // the rig already ended
                }
                let normal = libc::sched_param { sched_priority: 0 };
                libc::sched_setscheduler(0, libc::SCHED_OTHER, &normal);
                Ok(())
            });
        }
        let mut child = cmd
            .spawn()
            .with_context(|| format!("starting the world process {}", self.spec.program.display()))?;
        let stderr = child.stderr.take().context("the world's stderr")?;
        let tx = self.lines_tx.clone();
        self.reader = Some(
            std::thread::Builder::new()
                .name("spidar-world-err".into())
                .spawn(move || {
                    for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                        if tx.send(line).is_err() {
                            break;
                        }
                    }
                })
                .context("starting the world's output reader")?,
        );
        self.last_pid = child.id();
        self.child = Some(child);
        self.starts += 1;
        Ok(())
    }

    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(|c| c.id())
    }

    /// Restarts left.
    pub fn restarts_left(&self) -> u32 {
        (self.spec.restarts + 1).saturating_sub(self.starts)
    }

    pub fn gave_up(&self) -> bool {
        self.gave_up
    }

    /// Sorts the world's new output lines: `@status` and `@report` are kept, the rest go to `show`.
    pub fn read_lines(&mut self, show: &mut dyn FnMut(String)) {
        for line in self.held.drain(..) {
            show(line);
        }
        for line in self.lines.try_iter() {
            if let Some(rest) = line.strip_prefix(STATUS_PREFIX) {
                let (steps, text) = rest.split_once('\t').unwrap_or((rest, ""));
                self.status = Some((steps.parse().unwrap_or(0), text.to_string()));
            } else if let Some(rest) = line.strip_prefix(REPORT_PREFIX) {
                self.report = Some(rest.to_string());
            } else {
                show(line.strip_prefix("spidar world: ").unwrap_or(&line).to_string());
            }
        }
    }

    /// Lines read elsewhere (already sorted by `read_lines`), to go to `show` at the next read.
    pub fn hold_lines(&mut self, lines: Vec<String>) {
        self.held.extend(lines);
    }

    /// If the world has ended: how (kept in `exits`), after its last lines went to `show`.
    pub fn try_exit(&mut self, show: &mut dyn FnMut(String)) -> Option<String> {
        let c = self.child.as_mut()?;
        let Ok(Some(status)) = c.try_wait() else { return None };
        self.child = None;
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        self.read_lines(show);
        let how = describe_exit(status);
        self.exits.push(how.clone());
        Some(how)
    }

    /// Has the world ended? Then restart it while restarts are left. Says what it did.
    pub fn check(&mut self, show: &mut dyn FnMut(String)) {
        self.read_lines(show);
        let Some(how) = self.try_exit(show) else { return };
        if self.restarts_left() == 0 {
            self.gave_up = true;
            show(format!(
                "world process {how}; restarted {} times already, giving up: the rig stays safe with no force (Ctrl-C ends the run)",
                self.spec.restarts
            ));
            return;
        }
        match self.spawn() {
            Ok(()) => show(format!(
                "world process {how}; restarting it ({} of {} restarts)",
                self.starts - 1,
                self.spec.restarts
            )),
            Err(e) => {
                self.gave_up = true;
                show(format!("world process {how}; restarting it failed: {e:#}"));
            }
        }
    }

    /// Ends the world: SIGTERM, up to `grace` to finish, then SIGKILL. Keeps its last lines.
    pub fn stop(&mut self, grace: Duration, show: &mut dyn FnMut(String)) {
        if let Some(mut c) = self.child.take() {
            // SAFETY: kill with a pid we started and have not reaped.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
            let until = Instant::now() + grace;
            while c.try_wait().ok().flatten().is_none() && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(10));
            }
            if c.try_wait().ok().flatten().is_none() {
                let _ = c.kill();
                let _ = c.wait();
            }
            if let Some(r) = self.reader.take() {
                let _ = r.join();
            }
        }
        self.read_lines(show);
    }
}

impl Drop for ChildWorld {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(2), &mut |_| {});
    }
}
