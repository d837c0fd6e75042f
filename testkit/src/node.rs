//! Whether a test that drives node (the browser tests through puppeteer-core and Debian's
//! chromium, the Foxglove tests through Foxglove's own libraries) can run on this machine, and the
//! loud skip when it cannot: a missing browser must not pass quietly where it matters, so
//! `SPIDAR_BROWSER_TESTS=required` (set by `.ci/run`) turns the skip into a failure.
//!
//! Must never: report a test as run that was skipped, or skip silently.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A folder of the repository (`tests/browser`, `tests/foxglove`), from any crate of the workspace.
pub fn repo_dir(relative: &str) -> PathBuf {
    // This crate sits one level below the workspace root, as every crate does.
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(relative)
}

/// `tests/browser`: the browser tests' scripts and their npm packages.
pub fn browser_dir() -> PathBuf {
    repo_dir("tests/browser")
}

/// `tests/foxglove`: the Foxglove tests' scripts and their npm packages.
pub fn foxglove_dir() -> PathBuf {
    repo_dir("tests/foxglove")
}

/// Why a browser test cannot run (None: it can): Debian's chromium (or `SPIDAR_CHROMIUM`), node
/// on PATH and `npm ci` done in tests/browser.
pub fn browser_missing() -> Option<String> {
    let chromium = std::env::var("SPIDAR_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    if !Path::new(&chromium).exists() {
        return Some(format!("no chromium at {chromium} (apt-get install chromium, or set SPIDAR_CHROMIUM)"));
    }
    node_missing(&browser_dir(), "puppeteer-core")
}

/// Why a Foxglove test cannot run (None: it can): node on PATH and `npm ci` done in tests/foxglove.
pub fn foxglove_missing() -> Option<String> {
    node_missing(&foxglove_dir(), "@mcap/core")
}

fn node_missing(dir: &Path, package: &str) -> Option<String> {
    if Command::new("node").arg("--version").output().map(|o| !o.status.success()).unwrap_or(true) {
        return Some("no node on PATH".into());
    }
    if !dir.join("node_modules").join(package).exists() {
        return Some(format!("no {package}: run npm ci in {}", dir.display()));
    }
    None
}

/// True when `test` can run (`missing` is None); otherwise a loud message naming what did not run
/// (`what`) and false, or a panic when `SPIDAR_BROWSER_TESTS=required`.
pub fn can_run(test: &str, missing: Option<String>, what: &str) -> bool {
    let Some(why) = missing else { return true };
    if std::env::var("SPIDAR_BROWSER_TESTS").as_deref() == Ok("required") {
        panic!("{test}: cannot run: {why} (SPIDAR_BROWSER_TESTS=required)");
    }
    eprintln!("\n*** SKIPPED {test}: {why}. {what} did not run. ***\n");
    false
}
