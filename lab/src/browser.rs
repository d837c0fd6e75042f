//! A real browser for the view's benchmarks: Debian's chromium started headless on a page of the
//! live view (software WebGL, as the browser tests run it), and stopped when dropped.
//!
//! Why here and not through the tests' puppeteer: a benchmark needs nothing from the page but that
//! it draws; the page reports what it drew over its own WebSocket (`docs/view.md`).
//!
//! Must never: leave a browser running (the process group is killed on drop) or pick a browser
//! silently: a missing one is an error that says how to install it.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

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
    /// Opens `url` in a new headless chromium with a `width` x `height` window.
    pub fn open(url: &str, width: u32, height: u32) -> anyhow::Result<Browser> {
        let exe = chromium()?;
        let profile = std::env::temp_dir().join(format!(
            "spidar-bench-chromium-{}-{}",
            std::process::id(),
            spidar_link::private_dir::random_u64()
        ));
        std::fs::create_dir_all(&profile).context("making the browser's profile folder")?;
        use std::os::unix::process::CommandExt;
        let child = Command::new(&exe)
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
}

impl Drop for Browser {
    fn drop(&mut self) {
        // The browser's whole process group (its renderer and GPU processes), by its own id.
        let pgid = self.child.id() as libc::pid_t;
        // SAFETY: signals the process group this struct started (setpgid by `process_group(0)`).
        unsafe { libc::kill(-pgid, libc::SIGTERM) };
        let until = std::time::Instant::now() + std::time::Duration::from_secs(3);
        while std::time::Instant::now() < until {
            if let Ok(Some(_)) = self.child.try_wait() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        // SAFETY: as above.
        unsafe { libc::kill(-pgid, libc::SIGKILL) };
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}
