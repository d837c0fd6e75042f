//! The live view: a web page that draws the world in 3D (three.js), served by the world.
//!
//! [`View`] is an [`Observer`]: after a step it copies what a frame needs into a preallocated
//! mailbox, at display rate and only while someone watches, and flags it for the view's threads.
//! Those threads do everything else: an HTTP server (`tiny_http`) serves the page and the
//! descriptions; a WebSocket listener (`tungstenite`, on the next port) accepts viewers, one
//! thread each; a broadcaster polls the mailbox (every 2 ms), turns it into binary frames (60 Hz)
//! and status messages (4 Hz) and leaves the newest of each in every viewer's slot. A viewer that
//! cannot take its frames for a while is dropped, never waited for.
//!
//! Must never: block, allocate or format on the stepping thread (the observer `try_lock`s the
//! mailbox and skips a frame when the broadcaster is copying it).

mod fed;
mod frame;
pub mod json;
mod maker;
mod server;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use spidar_msg::RigInfo;
use std::sync::mpsc::SyncSender;

pub use fed::FedView;
pub use frame::{Layout, MAGIC};
pub use json::StatusData;
pub use maker::FrameMaker;

use crate::look::Look;
use crate::{Observer, StepView};

/// The view's page, its bundle of three.js and the page code, embedded so a build needs no npm.
pub const INDEX_HTML: &str = include_str!("../../../web/index.html");
pub const BUNDLE_JS: &str = include_str!("../../../web/dist/spidar-view.js");

/// Errors a user can cause when starting the view.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("the view cannot listen on {addr}: {source} (choose another address with --view ADDR:PORT, or switch the view off with --no-view)")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("the view address '{0}' is not an address: give HOST:PORT (e.g. 127.0.0.1:8080), a port, or http://HOST:PORT")]
    Address(String),
    #[error("starting the view's threads: {0}")]
    Thread(std::io::Error),
    #[error("the scene description to serve does not read: {0}")]
    Description(String),
}

/// Parses `--view`'s value: `HOST:PORT`, `http://HOST:PORT[/]`, `:PORT` or `PORT` (the last two
/// on 127.0.0.1).
pub fn parse_addr(s: &str) -> Result<SocketAddr, ViewError> {
    let t = s.trim().trim_start_matches("http://").trim_end_matches('/');
    let t = t.strip_prefix(':').unwrap_or(t);
    if let Ok(port) = t.parse::<u16>() {
        return Ok(SocketAddr::from(([127, 0, 0, 1], port)));
    }
    let t = t.replace("localhost", "127.0.0.1");
    t.parse().map_err(|_| ViewError::Address(s.to_string()))
}

/// How the view runs.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Where the page is served; frames are on the next port (or any free port when this is 0).
    pub addr: SocketAddr,
    /// Frames per second of loop-clock time while someone watches.
    pub frame_hz: f64,
    /// Status messages per second.
    pub status_hz: f64,
    /// Most viewers at once (each one is a thread).
    pub max_viewers: usize,
    /// A viewer whose socket takes no data for this long is dropped.
    pub write_timeout: Duration,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            frame_hz: 60.0,
            status_hz: 4.0,
            max_viewers: 8,
            write_timeout: Duration::from_secs(2),
        }
    }
}

/// Counters of a view, readable from any thread.
#[derive(Debug, Default)]
pub struct ViewCounters {
    /// Frames the observer wrote into the mailbox.
    pub frames_published: AtomicU64,
    /// Frames the observer skipped because the broadcaster held the mailbox.
    pub frames_skipped: AtomicU64,
    /// Frames the broadcaster handed to viewers (one per viewer), and frames a viewer's slot
    /// replaced before it was sent (the viewer was slower than the frame rate).
    pub frames_queued: AtomicU64,
    pub frames_replaced: AtomicU64,
    /// Binary frames written to sockets.
    pub frames_sent: AtomicU64,
    pub viewers: AtomicUsize,
    pub viewers_total: AtomicU64,
    /// Viewers dropped because their socket took no data within the write timeout.
    pub viewers_dropped: AtomicU64,
    /// Viewers refused because `max_viewers` were connected.
    pub viewers_refused: AtomicU64,
}

/// The mailbox between the stepping thread (or a replay) and the broadcaster.
struct Mailbox {
    frame: Vec<f32>,
    frame_words: usize,
    frame_fresh: bool,
    status: StatusData,
    status_fresh: bool,
    rig: Option<RigInfo>,
    rig_fresh: bool,
    /// A replay's playback state (JSON, `type` `playback`), handed on as it is.
    playback: Option<String>,
}

impl Mailbox {
    fn new(words: usize) -> Mailbox {
        Mailbox {
            frame: vec![0.0; words],
            frame_words: 0,
            frame_fresh: false,
            status: StatusData { sample_t_s: f64::NAN, ..Default::default() },
            status_fresh: false,
            rig: None,
            rig_fresh: false,
            playback: None,
        }
    }
}

struct Shared {
    mailbox: Mutex<Mailbox>,
    /// Set after the observer wrote the mailbox; the broadcaster polls it (a wake-up from the
    /// stepping thread would be a system call, and the woken thread could preempt the step).
    fresh: AtomicBool,
    counters: ViewCounters,
    /// Set when the view stops; `done` once the broadcaster has handed out the last status.
    stop: AtomicBool,
    done: AtomicBool,
    /// Where the viewers' text messages go (a replay's controls); the live view takes none.
    commands: Option<SyncSender<String>>,
}

impl Shared {
    fn new(words: usize, commands: Option<SyncSender<String>>) -> Arc<Shared> {
        Arc::new(Shared {
            mailbox: Mutex::new(Mailbox::new(words)),
            fresh: AtomicBool::new(false),
            counters: ViewCounters::default(),
            stop: AtomicBool::new(false),
            done: AtomicBool::new(false),
            commands,
        })
    }

    /// Ends the view: the last status says the world ended; the threads send it and stop.
    fn stop(&self, server: Option<server::Server>) {
        if let Ok(mut mb) = self.mailbox.lock() {
            mb.status.ended = true;
            mb.status_fresh = true;
        }
        self.fresh.store(true, Ordering::Release);
        self.stop.store(true, Ordering::Relaxed);
        if let Some(s) = server {
            s.stop();
        }
    }
}

/// The live view, as an observer of the world's steps.
pub struct View {
    shared: Arc<Shared>,
    server: Option<server::Server>,
    maker: FrameMaker,
    frame_every_s: f64,
    status_every_s: f64,
    next_frame_t_s: f64,
    next_status_t_s: f64,
    next_counters_t_s: f64,
    urls: (String, String),
}

impl View {
    /// Starts the view's servers for a scene that looks like `look`.
    pub fn start(scene_name: &str, look: &Look, opts: &ViewOptions) -> Result<View, ViewError> {
        let maker = FrameMaker::new(look);
        let layout = *maker.layout();
        let shared = Shared::new(layout.max_words, None);
        let description = json::scene(scene_name, look, &layout, opts.frame_hz);
        let server = server::Server::start(
            opts,
            shared.clone(),
            description,
            look.counters.clone(),
            look.link_offset_m,
        )?;
        let urls = (format!("http://{}", server.http_addr), format!("ws://{}", server.ws_addr));
        Ok(View {
            shared,
            server: Some(server),
            maker,
            frame_every_s: 1.0 / opts.frame_hz.max(1.0),
            status_every_s: 1.0 / opts.status_hz.max(0.1),
            next_frame_t_s: f64::NEG_INFINITY,
            next_status_t_s: f64::NEG_INFINITY,
            next_counters_t_s: f64::NEG_INFINITY,
            urls,
        })
    }

    /// The page's address (`http://HOST:PORT`).
    pub fn url(&self) -> &str {
        &self.urls.0
    }

    /// The frames' address (`ws://HOST:PORT`).
    pub fn ws_url(&self) -> &str {
        &self.urls.1
    }

    pub fn counters(&self) -> &ViewCounters {
        &self.shared.counters
    }

    /// A handle to the counters that outlives the view being moved into a host.
    pub fn counters_handle(&self) -> ViewHandle {
        ViewHandle { shared: self.shared.clone(), urls: self.urls.clone() }
    }

    /// Writes the frame (when one is due) and the status into the mailbox, if the broadcaster is
    /// not copying it right now. The scene poses every time: its counters feed the status.
    fn publish(&mut self, step: &StepView<'_>, frame_due: bool) {
        let Ok(mut guard) = self.shared.mailbox.try_lock() else {
            self.shared.counters.frames_skipped.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let mb = &mut *guard;
        // Unwatched, the scene poses (for the status's counters) once a second: posing a big
        // crowd costs tens of microseconds.
        let counters_due = step.t_s >= self.next_counters_t_s;
        if frame_due || (!mb.frame_fresh && counters_due) {
            // (A frame that waits to be sent is kept whole.)
            self.next_counters_t_s = step.t_s + 1.0;
            let words = self.maker.write(&mut mb.frame, step, frame_due);
            if frame_due {
                mb.frame_words = words;
                mb.frame_fresh = true;
                self.shared.counters.frames_published.fetch_add(1, Ordering::Relaxed);
            }
        }
        mb.status = *self.maker.status();
        mb.status_fresh = true;
        if let Some(info) = step.rig_info {
            if mb.rig != Some(*info) {
                mb.rig = Some(*info);
                mb.rig_fresh = true;
            }
        }
        drop(guard);
        self.shared.fresh.store(true, Ordering::Release);
    }
}

impl Observer for View {
    fn after_step(&mut self, step: &StepView<'_>) {
        let t = step.t_s;
        let watched = self.shared.counters.viewers.load(Ordering::Relaxed) > 0;
        self.maker.observe(step, watched);
        let frame_due = watched && t >= self.next_frame_t_s;
        let status_due = t >= self.next_status_t_s;
        if frame_due || status_due {
            self.publish(step, frame_due);
            if frame_due {
                self.next_frame_t_s = t + self.frame_every_s;
            }
            if status_due {
                self.next_status_t_s = t + self.status_every_s;
            }
        }
    }
}

impl Drop for View {
    fn drop(&mut self) {
        self.shared.stop(self.server.take());
    }
}

/// The view's counters and addresses, kept by whoever started the view after the [`View`] itself
/// moved into the host that steps the world.
#[derive(Clone)]
pub struct ViewHandle {
    shared: Arc<Shared>,
    urls: (String, String),
}

impl ViewHandle {
    pub fn counters(&self) -> &ViewCounters {
        &self.shared.counters
    }
    pub fn url(&self) -> &str {
        &self.urls.0
    }
    pub fn ws_url(&self) -> &str {
        &self.urls.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use spidar_msg::{ContactModel, HandState, HANDS};

    #[test]
    fn view_addresses_default_to_the_loopback_host() {
        let a = |s: &str| parse_addr(s).unwrap().to_string();
        assert_eq!(a("8080"), "127.0.0.1:8080");
        assert_eq!(a(":9000"), "127.0.0.1:9000");
        assert_eq!(a("http://localhost:8080/"), "127.0.0.1:8080");
        assert_eq!(a("0.0.0.0:8080"), "0.0.0.0:8080");
        let e = parse_addr("here").unwrap_err().to_string();
        assert!(e.contains("HOST:PORT"), "{e}");
    }

    #[test]
    fn a_frame_carries_the_scene_poses_at_the_layout_offsets() {
        let scene = crate::boxing::BoxingScene::new(Default::default()).unwrap();
        let look = crate::Scene::look(&scene);
        let l = Layout::of(&look, 7);
        let mut buf = vec![f32::NAN; l.max_words];
        let hands =
            [HandState { pos_m: DVec3::new(0.1, 1.1, 0.0), valid: true, ..Default::default() }; HANDS];
        let model = ContactModel::default();
        let common = frame::Common {
            seq: 3,
            t_s: 1.5,
            hands: &hands,
            tensions_n: None,
            model: &model,
            offset: look.link_offset_m,
        };
        frame::write_common(&mut buf, &l, &common);
        let mut counters = [0.0; crate::look::MAX_COUNTERS];
        let mut contacts = 0;
        crate::Scene::pose(&scene, &mut l.poses(&mut buf, &mut counters, &mut contacts));
        assert_eq!((buf[0].to_bits(), buf[1].to_bits(), buf[2].to_bits()), (MAGIC, 7, 3));
        assert_eq!(buf[frame::GLOBALS_AT], 1.5);
        // Hands are moved into the scene frame.
        let h = &buf[frame::HANDS_AT..frame::HANDS_AT + 3];
        assert!((h[1] as f64 - (1.1 + look.link_offset_m.y)).abs() < 1e-6);
        // Every shape is at its pose in the world, with a unit rotation.
        for (k, p) in scene.world.ws.shape_pose.iter().enumerate() {
            let s = &buf[l.shapes_at + 7 * k..l.shapes_at + 7 * k + 7];
            let d = DVec3::new(s[0] as f64, s[1] as f64, s[2] as f64) - p.pos_m;
            assert!(d.length() < 1e-5, "shape {k}");
            let n: f32 = s[3..7].iter().map(|x| x * x).sum();
            assert!((n - 1.0).abs() < 1e-5, "shape {k}");
        }
        // Nothing written past the scene's sections but the proxies (all empty here).
        assert!(buf[l.proxies_at..l.contacts_at].iter().all(|x| *x == 0.0));
        assert!(buf[l.contacts_at..].iter().all(|x| x.is_nan()));
    }
}
