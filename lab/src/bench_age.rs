//! `spidar bench view --age`: how late the drawn picture is, on `spidar run`'s path with a real
//! browser: the simulated rig, the rt-loop at 1 kHz on the real clock, the child world process
//! serving the live view, and headless chromium drawing the page from the user's eye. The page reports the age of every frame it
//! draws, from the rig tick whose hand sample it shows to its drawing (`docs/view.md`), and the
//! world keeps the last thousand in its status; this reads them there at the end.
//!
//! With `--headset` the page is drawn in an immersive session of an emulated headset
//! ([`crate::browser::Headset`]) and the ages are the headset's pictures'.
//!
//! Must never: report a figure it did not measure (no browser, no report: an error saying why).

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::Deserialize;
use spidar_rt::rt_thread::RtOptions;
use spidar_rt::Rig;
use spidar_runtime::child_world::ChildWorldSpec;
use spidar_runtime::session::{load_scripts, sim_device, LiveOptions, LiveSession, SimOptions, WorldChoice};

use crate::browser::{Browser, Headset};

/// The browser drawing the page, held for its drop (which stops it).
enum Page {
    Screen(Browser),
    Headset(Headset),
}

impl Page {
    fn cpu_s(&self) -> f64 {
        match self {
            Page::Screen(b) => b.cpu_s(),
            Page::Headset(h) => h.cpu_s(),
        }
    }
}

pub struct AgeBenchOptions {
    pub scene: String,
    /// Seconds of drawing measured (after the page's first report).
    pub seconds: f64,
    /// The browser window's size (px).
    pub width: u32,
    pub height: u32,
    /// The world process to start (None: this executable's `spidar world`).
    pub world: Option<ChildWorldSpec>,
    /// The page in an immersive session of an emulated headset ([`crate::browser::Headset`]); the
    /// headset's pictures' ages.
    pub headset: bool,
    /// More of the page's query (`shading=standard&aa=1`, say).
    pub page: String,
}

/// The ages of one kind of page, as the world's status has them.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct Ages {
    pub frames: usize,
    pub total: u64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    pub hand_lag_p50_ms: f64,
    pub hand_lag_p99_ms: f64,
    pub draw_p50_ms: f64,
    pub draw_p99_ms: f64,
    /// The tick to the frame's arrival at the page, the arrival to its drawing (None: the page
    /// did not say).
    #[serde(default)]
    pub arrive_p50_ms: Option<f64>,
    #[serde(default)]
    pub arrive_p99_ms: Option<f64>,
    #[serde(default)]
    pub wait_p50_ms: Option<f64>,
    #[serde(default)]
    pub wait_p99_ms: Option<f64>,
    /// The grips' distance from the measured hands when shown (mm): as drawn (a headset
    /// extrapolates them) and as the newest frame had them (None: the page did not say).
    #[serde(default)]
    pub hand_err_p50_mm: Option<f64>,
    #[serde(default)]
    pub hand_err_p99_mm: Option<f64>,
    #[serde(default)]
    pub hand_err_max_mm: Option<f64>,
    #[serde(default)]
    pub hand_still_err_p50_mm: Option<f64>,
    #[serde(default)]
    pub hand_still_err_p99_mm: Option<f64>,
    #[serde(default)]
    pub hand_still_err_max_mm: Option<f64>,
}

pub struct AgeReport {
    pub scene: String,
    pub page: &'static str,
    pub ages: Ages,
    pub seconds: f64,
    pub load: [String; 2],
    /// The browser's CPU time over the measured seconds, and the pictures it reported drawing then.
    pub browser_cpu_s: f64,
    pub pictures: u64,
}

/// `GET path` from the view at `url` (`http://HOST:PORT`): the body.
pub fn http_get(url: &str, path: &str) -> anyhow::Result<String> {
    let host = url.trim_start_matches("http://");
    let mut c =
        std::net::TcpStream::connect(host).with_context(|| format!("connecting to the view at {url}"))?;
    c.set_read_timeout(Some(Duration::from_secs(5)))?;
    write!(c, "GET {path} HTTP/1.0\r\nHost: {host}\r\nConnection: close\r\n\r\n")?;
    let mut text = String::new();
    c.read_to_string(&mut text)?;
    let (_, body) = text.split_once("\r\n\r\n").context("the view answered no HTTP")?;
    Ok(body.to_string())
}

fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

/// The ages of `kind` (`screen` or `headset`) in the view's status, if any were reported.
fn ages_in(url: &str, kind: &str) -> anyhow::Result<Option<Ages>> {
    let s: serde_json::Value = serde_json::from_str(&http_get(url, "/status.json")?)?;
    let a = &s["picture_age"][kind];
    Ok(if a.is_null() { None } else { Some(serde_json::from_value(a.clone())?) })
}

pub fn bench_age(rig: &Rig, o: &AgeBenchOptions) -> anyhow::Result<AgeReport> {
    crate::browser::chromium()?;
    let script = spidar_runtime::session::default_script(&o.scene);
    let dev = sim_device(rig, load_scripts(script, rig, 1)?, &SimOptions::default())?;
    let mut spec = match &o.world {
        Some(s) => s.clone(),
        None => ChildWorldSpec::this_executable(&o.scene, 0)?,
    };
    spec.extra.extend(["--view".into(), "127.0.0.1:0".into()]);
    let opts = LiveOptions {
        seconds: None,
        rt: RtOptions::default(),
        spin_ns: 0,
        status_every: None,
        stop: spidar_runtime::signals::Stop::detached(),
        scene_name: o.scene.clone(),
        script_name: script.into(),
        connect_timeout: Duration::from_secs(60),
        world_priority: None,
        supervisor: None,
        recorder: None,
    };
    let mut s = LiveSession::start(dev, rig, WorldChoice::Child(spec), &opts)?;
    let mut url = None;
    let mut said = Vec::new();
    let mut poll = |s: &mut LiveSession<_>, url: &mut Option<String>| {
        s.poll(&mut |_| {}, &mut |l: String| {
            if let Some(at) = l.split("live view at ").nth(1) {
                *url = at.split(' ').next().map(str::to_string);
            }
            said.push(l);
        })
    };
    let until = Instant::now() + Duration::from_secs(60);
    while url.is_none() && Instant::now() < until {
        if !poll(&mut s, &mut url) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let Some(url) = url else {
        s.request_stop();
        bail!("the world process printed no view address")
    };
    let (kind, page) = if o.headset { ("headset", "headset") } else { ("screen", "screen") };
    let mut browser = if o.headset {
        Page::Headset(Headset::open(&url, &o.page, o.width, o.height, &[])?)
    } else {
        Page::Screen(Browser::open(&format!("{url}/?camera=eye&{}", o.page), o.width, o.height, &[])?)
    };
    let load_start = load();
    // The page draws and reports; then the window of reports is what this run drew.
    let until = Instant::now() + Duration::from_secs(90);
    let mut first = None;
    while Instant::now() < until {
        poll(&mut s, &mut Some(String::new()));
        if let Page::Headset(h) = &mut browser {
            // A driver that gave up says why.
            if let Err(e) = h.presenting() {
                drop(browser);
                s.request_stop();
                return Err(e);
            }
        }
        if ages_in(&url, kind)?.is_some_and(|a| a.total > 0) {
            first = Some(Instant::now());
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    if first.is_none() {
        drop(browser);
        s.request_stop();
        bail!("the browser drew nothing the world heard of in 90 s");
    }
    // The measured window starts now: the pictures drawn while the page started are forgotten.
    http_get(&url, "/clear-ages")?;
    let (cpu0, total0) = (browser.cpu_s(), ages_in(&url, kind)?.map(|a| a.total).unwrap_or(0));
    let until = Instant::now() + Duration::from_secs_f64(o.seconds);
    while Instant::now() < until {
        poll(&mut s, &mut Some(String::new()));
        std::thread::sleep(Duration::from_millis(20));
    }
    let ages = ages_in(&url, kind)?.unwrap_or_default();
    let (browser_cpu_s, pictures) = (browser.cpu_s() - cpu0, ages.total - total0);
    drop(browser);
    s.request_stop();
    while poll(&mut s, &mut Some(String::new())) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = s.finish(0, &mut |_| {});
    Ok(AgeReport {
        scene: o.scene.clone(),
        page,
        ages,
        seconds: o.seconds,
        load: [load_start, load()],
        browser_cpu_s,
        pictures,
    })
}

impl std::fmt::Display for AgeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = &self.ages;
        writeln!(
            f,
            "spidar bench view --age: scene {}, spidar run's path (simulated rig, rt-loop at 1 kHz, child world \
             process, headless chromium drawing the {} page), {:.0} s; load average {} at the start, {} at the end",
            self.scene, self.page, self.seconds, self.load[0], self.load[1]
        )?;
        writeln!(
            f,
            "  picture age (rig tick of the hand sample shown -> the browser frame that draws it), the last {} frames \
             drawn: p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms",
            a.frames, a.p50_ms, a.p99_ms, a.max_ms
        )?;
        let ms = |x: Option<f64>| x.map(|v| format!("{v:.1} ms")).unwrap_or_else(|| "not reported".into());
        writeln!(
            f,
            "  of which the way to the page (world, link, broadcaster, socket): p50 {}, p99 {}",
            ms(a.arrive_p50_ms),
            ms(a.arrive_p99_ms)
        )?;
        writeln!(
            f,
            "  of which the wait for the browser's next frame: p50 {}, p99 {}",
            ms(a.wait_p50_ms),
            ms(a.wait_p99_ms)
        )?;
        writeln!(
            f,
            "  of which the page's own drawing (software WebGL here): p50 {:.1} ms, p99 {:.1} ms",
            a.draw_p50_ms, a.draw_p99_ms
        )?;
        writeln!(
            f,
            "  drawn hands behind their tick (the age less how far ahead the page extrapolated them): p50 {:.1} ms, p99 {:.1} ms",
            a.hand_lag_p50_ms, a.hand_lag_p99_ms
        )?;
        if let (Some(p50), Some(p99), Some(max)) = (a.hand_err_p50_mm, a.hand_err_p99_mm, a.hand_err_max_mm) {
            let mm = |x: Option<f64>| x.map_or("-".into(), |v| format!("{v:.1}"));
            writeln!(
                f,
                "  drawn grips from the measured hands when shown: p50 {p50:.1} mm, p99 {p99:.1} mm, max {max:.1} mm \
                 (not extrapolated, the newest frame's: p50 {} mm, p99 {} mm, max {} mm)",
                mm(a.hand_still_err_p50_mm),
                mm(a.hand_still_err_p99_mm),
                mm(a.hand_still_err_max_mm),
            )?;
        }
        write!(
            f,
            "  the browser's CPU time (all its processes): {:.1} ms a picture ({} new frames drawn in {:.0} s, {:.1} a second; \
             counts work, not waiting, so it changes little with the machine's load)",
            1e3 * self.browser_cpu_s / self.pictures.max(1) as f64,
            self.pictures,
            self.seconds,
            self.pictures as f64 / self.seconds
        )
    }
}
