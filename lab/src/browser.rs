//! A real browser for the view's benchmarks: Debian's chromium started headless on a page of the
//! live view (software WebGL, as the browser tests run it), and stopped when dropped.
//!
//! Why here and not through the tests' puppeteer: a benchmark needs nothing from the page but that
//! it draws; the page reports what it drew over its own WebSocket (`docs/view.md`).
//!
//! A headset session ([`Headset`]) needs a WebXR runtime, which headless chromium has not: there
//! the page is driven by `tests/browser/bench-headset.mjs` (node, puppeteer-core and the `iwer`
//! headset emulation the browser tests use), which opens it with the emulated headset and enters
//! an immersive session. The page itself is the one users get: nothing in it is for benchmarks.
//!
//! Must never: leave a browser running (the process group is killed on drop) or pick a browser
//! silently: a missing one, or a missing node or npm package, is an error that says how to
//! install it (never a figure measured without the headset).

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

/// The browser to start: `$SPIDAR_CHROMIUM`, else `/usr/bin/chromium`, else `chromium` on PATH.
pub fn chromium() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os("SPIDAR_CHROMIUM") {
        return Ok(PathBuf::from(p));
    }
    let debian = PathBuf::from("/usr/bin/chromium");
    if debian.exists() {
        return Ok(debian);
    }
    if let Some(p) = std::env::var_os("PATH")
        .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("chromium")).find(|p| p.exists()))
    {
        return Ok(p);
    }
    bail!("no chromium to measure with: install it (apt-get install chromium) or set SPIDAR_CHROMIUM to a Chromium-based browser")
}

/// A headless chromium showing one page.
pub struct Browser {
    child: Child,
    profile: PathBuf,
}

impl Browser {
    /// Opens `url` in a new headless chromium with a `width` x `height` window, its processes on
    /// `cpus` (empty: any).
    pub fn open(url: &str, width: u32, height: u32, cpus: &[usize]) -> anyhow::Result<Browser> {
        let exe = chromium()?;
        let profile = std::env::temp_dir().join(format!(
            "spidar-bench-chromium-{}-{}",
            std::process::id(),
            spidar_link::private_dir::random_u64()
        ));
        std::fs::create_dir_all(&profile).context("making the browser's profile folder")?;
        use std::os::unix::process::CommandExt;
        let mut cmd = Command::new(&exe);
        crate::cpus::run_on(&mut cmd, cpus);
        let child = cmd
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-background-timer-throttling",
                "--disable-renderer-backgrounding",
                "--disable-backgrounding-occluded-windows",
                &format!("--window-size={width},{height}"),
                &format!("--user-data-dir={}", profile.display()),
                url,
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .with_context(|| format!("starting {}", exe.display()))?;
        Ok(Browser { child, profile })
    }

    /// The CPU time its processes have used so far (s).
    pub fn cpu_s(&self) -> f64 {
        group_cpu_s(self.child.id())
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = stop_group(&mut self.child, libc::SIGTERM);
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}

/// The CPU time (user and system, s) the processes of process group `pgid` have used so far (the
/// living ones: a browser's processes live as long as it does).
pub fn group_cpu_s(pgid: u32) -> f64 {
    // SAFETY: sysconf has no preconditions.
    let tick = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    let Ok(dir) = std::fs::read_dir("/proc") else { return 0.0 };
    let mut ticks = 0u64;
    for e in dir.flatten() {
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else { continue };
        // After the name's closing parenthesis: state, ppid, pgrp, ... utime (12th), stime (13th).
        let Some(at) = stat.rfind(')') else { continue };
        let f: Vec<&str> = stat[at + 1..].split_whitespace().collect();
        if f.len() > 12 && f[2].parse::<u32>() == Ok(pgid) {
            ticks += f[11].parse::<u64>().unwrap_or(0) + f[12].parse::<u64>().unwrap_or(0);
        }
    }
    ticks as f64 / tick
}

/// Stops `child`'s process group (started with `process_group(0)`: the child and all it started
/// in its group): `first`, up to 3 s to go, then SIGKILL; and reaps the child. True when it ended
/// by itself with success within the 3 s.
fn stop_group(child: &mut Child, first: libc::c_int) -> bool {
    let pgid = child.id() as libc::pid_t;
    // SAFETY: signals the process group this module started (setpgid by `process_group(0)`).
    unsafe { libc::kill(-pgid, first) };
    let until = Instant::now() + Duration::from_secs(3);
    let mut ended = None;
    while Instant::now() < until {
        if let Ok(Some(s)) = child.try_wait() {
            ended = Some(s.success());
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: as above.
    unsafe { libc::kill(-pgid, libc::SIGKILL) };
    let _ = child.wait();
    ended == Some(true)
}

/// The folder of the browser tests' node scripts and packages: `$SPIDAR_BROWSER_TESTS`, else
/// `tests/browser` of the source tree this was built from, else of the current folder.
pub fn browser_tests_dir() -> PathBuf {
    if let Some(p) = std::env::var_os("SPIDAR_BROWSER_TESTS") {
        return PathBuf::from(p);
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/browser");
    if built.join("package.json").exists() {
        return built;
    }
    PathBuf::from("tests/browser")
}

/// Node to run the headset driver with: `$SPIDAR_NODE`, else `node` on PATH.
fn node() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os("SPIDAR_NODE") {
        return Ok(PathBuf::from(p));
    }
    std::env::var_os("PATH")
        .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("node")).find(|p| p.exists()))
        .ok_or_else(|| {
            anyhow::anyhow!("no node to drive the headset with: install Node.js (apt-get install nodejs npm) or set SPIDAR_NODE")
        })
}

/// The headset driver's script in `dir`, with its packages (puppeteer-core, iwer) installed there,
/// or an error saying how to get them.
fn headset_driver(dir: &Path) -> anyhow::Result<PathBuf> {
    let script = dir.join("bench-headset.mjs");
    if !script.exists() {
        bail!(
            "no headset driver at {}: run from the spidar source tree or set SPIDAR_BROWSER_TESTS to its tests/browser",
            script.display()
        );
    }
    for package in ["iwer/build/iwer.min.js", "puppeteer-core/package.json"] {
        if !dir.join("node_modules").join(package).exists() {
            bail!(
                "the headset driver's packages are not installed (no node_modules/{package} in {}): run `npm ci` there",
                dir.display()
            );
        }
    }
    Ok(script)
}

/// A headless chromium showing one page in an immersive session of an emulated headset (see the
/// module's doc): started by [`Headset::open`], ready once [`Headset::presenting`] says so.
pub struct Headset {
    node: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    chromium: Option<libc::pid_t>,
    presenting: bool,
}

impl Headset {
    /// Opens `url` (the view's `http://HOST:PORT`) with the page's `query` in a `width` x `height`
    /// window with an emulated headset, and has the page enter a session (the world must be sending
    /// frames meanwhile). The driver and its browser run on `cpus` (empty: any).
    pub fn open(url: &str, query: &str, width: u32, height: u32, cpus: &[usize]) -> anyhow::Result<Headset> {
        let exe = chromium()?;
        let dir = browser_tests_dir();
        let script = headset_driver(&dir)?;
        let node = node()?;
        use std::os::unix::process::CommandExt;
        let mut cmd = Command::new(&node);
        crate::cpus::run_on(&mut cmd, cpus);
        let mut child = cmd
            .arg(&script)
            .args([url, &width.to_string(), &height.to_string(), query])
            .current_dir(&dir)
            .env("SPIDAR_CHROMIUM", &exe)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .with_context(|| format!("starting {} {}", node.display(), script.display()))?;
        let stdout = child.stdout.take().context("the headset driver's output")?;
        let (tx, lines) = std::sync::mpsc::channel();
        let on = cpus.to_vec();
        std::thread::spawn(move || {
            // With the browser, not on the CPU of the thread that opened it (a bench's world).
            let _ = crate::cpus::pin_current_thread(&on);
            for l in std::io::BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        let stdin = child.stdin.take();
        Ok(Headset { node: child, stdin, lines, chromium: None, presenting: false })
    }

    /// Whether the page draws in the session yet; an error when the driver gave up or ended.
    pub fn presenting(&mut self) -> anyhow::Result<bool> {
        loop {
            match self.lines.try_recv() {
                Ok(l) if l == "PRESENTING" => self.presenting = true,
                Ok(l) if l.starts_with("CHROMIUM ") => self.chromium = l[9..].trim().parse().ok(),
                Ok(l) if l.starts_with("FAILED ") => bail!("the emulated headset: {}", &l[7..]),
                Ok(_) => {}
                Err(TryRecvError::Empty) => return Ok(self.presenting),
                Err(TryRecvError::Disconnected) => {
                    bail!("the headset driver ended before the page entered a session")
                }
            }
        }
    }

    /// The CPU time its browser's processes have used so far (s; 0 before it started).
    pub fn cpu_s(&self) -> f64 {
        self.chromium.map(|p| group_cpu_s(p as u32)).unwrap_or(0.0)
    }
}

impl Drop for Headset {
    fn drop(&mut self) {
        // Its stdin's end tells the driver to close the browser; it has 3 s.
        drop(self.stdin.take());
        let closed = stop_group(&mut self.node, 0);
        // Puppeteer starts chromium in a process group of its own: stopped by its id unless the
        // driver closed it.
        if let (false, Some(pid)) = (closed, self.chromium) {
            // SAFETY: the group of the browser this driver started and reported.
            unsafe { libc::kill(-pid, libc::SIGKILL) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without the driver or its packages the headset is refused, saying what to do.
    #[test]
    fn a_headset_without_its_driver_or_packages_is_refused_saying_how_to_install_them() {
        let dir = std::env::temp_dir().join(format!("spidar-headset-driver-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("node_modules/puppeteer-core")).unwrap();
        let e = headset_driver(&dir).unwrap_err().to_string();
        assert!(e.contains("bench-headset.mjs") && e.contains("SPIDAR_BROWSER_TESTS"), "{e}");
        std::fs::write(dir.join("bench-headset.mjs"), "").unwrap();
        std::fs::write(dir.join("node_modules/puppeteer-core/package.json"), "{}").unwrap();
        let e = headset_driver(&dir).unwrap_err().to_string();
        assert!(e.contains("node_modules/iwer") && e.contains("npm ci"), "{e}");
        std::fs::create_dir_all(dir.join("node_modules/iwer/build")).unwrap();
        std::fs::write(dir.join("node_modules/iwer/build/iwer.min.js"), "").unwrap();
        assert_eq!(headset_driver(&dir).unwrap(), dir.join("bench-headset.mjs"));
        // The source tree's own driver is found.
        assert!(
            browser_tests_dir().join("bench-headset.mjs").exists()
                || std::env::var_os("SPIDAR_BROWSER_TESTS").is_some()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
