//! The live view: a web page that draws the world in 3D (three.js), served by the world.
//!
//! [`View`] is an [`Observer`]: after a step, at display rate and only while someone watches, it
//! writes what a frame needs into a preallocated frame buffer taken from a small pool (a crowd's
//! drawn figures only as the states they are computed from) and queues it for the view's threads;
//! the status goes into a mailbox. Those threads do everything else: an HTTP server (`tiny_http`)
//! serves the page and the descriptions; a WebSocket listener (`tungstenite`, on the next port)
//! accepts viewers, one thread each; one broadcaster, shared by all viewers, polls the queue and
//! the mailbox (every 2 ms), computes the figures and turns the newest frame into a binary message
//! (60 Hz), the status into a text message (4 Hz), and leaves the newest of each in every
//! viewer's slot. A viewer that cannot take its frames for a while is dropped, never waited for.
//!
//! Must never: block, allocate or format on the stepping thread (the observer skips a frame, and
//! counts it, when every frame buffer is still with the broadcaster, and `try_lock`s the
//! mailbox).

mod age;
mod fed;
mod frame;
pub mod json;
mod maker;
pub mod rigview;
mod server;
mod tls;
pub use tls::TlsIdentity;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, Sender};
use spidar_msg::RigInfo;
use spidar_sim::character::drawn::FigureState;

pub use age::{AgeSummary, Drawn, PictureAges};
pub use fed::FedView;
pub use frame::{Layout, GLOBALS_AT, HANDS_AT, HAND_FLOATS, MAGIC, TENSIONS_AT};
pub use json::StatusData;
pub use maker::{FrameFinisher, FrameMaker};

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
    #[error("the view's HTTPS: {0}")]
    Tls(String),
}

/// Parses `--view`'s value: `HOST:PORT`, `http://HOST:PORT[/]`, `:PORT` or `PORT` (the last two
/// on 127.0.0.1).
pub fn parse_addr(s: &str) -> Result<SocketAddr, ViewError> {
    let t = s.trim().trim_start_matches("http://").trim_start_matches("https://").trim_end_matches('/');
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
    /// The most frames a second of loop-clock time while someone watches. A frame goes out after
    /// every world step (each brings the rig's newest hand sample) up to this rate, so the newest
    /// frame a page can draw is at most a step old ([`frame_hz_for`]).
    pub frame_hz: f64,
    /// Large frames (a big crowd's) go out less often than `frame_hz`, keeping each viewer's
    /// stream under this many bytes a second, but never less often than [`MIN_FRAME_HZ`].
    pub frame_bytes_per_s: f64,
    /// The world's step (s), when known (0: not known): a frame goes out at most once a step, so
    /// the page is told the rate frames arrive at, at most one a step ([`arriving_frame_hz`]).
    pub world_step_s: f64,
    /// Status messages per second.
    pub status_hz: f64,
    /// Most viewers at once (each one is a thread).
    pub max_viewers: usize,
    /// A viewer whose socket takes no data for this long is dropped.
    pub write_timeout: Duration,
    /// Serve the page over HTTPS and the frames over secure WebSockets with this certificate
    /// (None: plain HTTP and WebSockets).
    pub tls: Option<TlsIdentity>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            frame_hz: 1000.0,
            frame_bytes_per_s: 4e6,
            world_step_s: 0.0,
            status_hz: 4.0,
            max_viewers: 8,
            write_timeout: Duration::from_secs(2),
            tls: None,
        }
    }
}

/// Frames a second a view sends at the least while someone watches (a display's rate).
pub const MIN_FRAME_HZ: f64 = 60.0;

/// The frame rate of a view whose frames (without contacts) are `frame_bytes` long: `frame_hz`,
/// less when that would send more than `frame_bytes_per_s`, but not under [`MIN_FRAME_HZ`] (unless
/// `frame_hz` itself is).
pub fn frame_hz_for(opts: &ViewOptions, frame_bytes: usize) -> f64 {
    let by_bytes = (opts.frame_bytes_per_s / frame_bytes.max(1) as f64).max(MIN_FRAME_HZ);
    opts.frame_hz.min(by_bytes).max(1.0)
}

/// The frames a second a page receives from a view sending `frame_hz` after world steps of
/// `world_step_s` (0: not known): at most one a step (a frame after every 3 ms step is 333 a second,
/// not the 1000 a view may send at most). The headset's page interpolates over this interval.
pub fn arriving_frame_hz(frame_hz: f64, world_step_s: f64) -> f64 {
    if world_step_s > 0.0 && world_step_s.is_finite() {
        frame_hz.min(1.0 / world_step_s)
    } else {
        frame_hz
    }
}

/// Counters of a view, readable from any thread.
#[derive(Debug, Default)]
pub struct ViewCounters {
    /// Frames the observer queued for the broadcaster.
    pub frames_published: AtomicU64,
    /// Frames skipped: due while every frame buffer was still with the broadcaster (the observer
    /// never waits for it), or queued behind a newer one (the broadcaster sends the newest).
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

/// Frame buffers between the stepping thread (or a replay) and the broadcaster: one being written,
/// one queued, one being finished and sent.
const FRAME_BUFFERS: usize = 3;

/// A frame on its way to the viewers: its words and, for a crowd, the states its figures are
/// computed from (the broadcaster writes their joints, [`FrameFinisher`]).
struct FrameBuf {
    words: Vec<f32>,
    len: usize,
    states: Vec<FigureState>,
    /// Whether `states` are this frame's (to be drawn into it).
    figures_pending: bool,
}

/// The two queues of the frame buffers (lock-free, allocation-free): the writer's ends (the
/// observer, or a replay's host) and the broadcaster's. The writer may take back a frame still
/// queued (`queued`): the newest frame replaces one the broadcaster has not taken yet.
struct FrameWriterEnds {
    free: Receiver<FrameBuf>,
    full: Sender<FrameBuf>,
    queued: Receiver<FrameBuf>,
}

struct FrameSenderEnds {
    full: Receiver<FrameBuf>,
    free: Sender<FrameBuf>,
}

impl FrameWriterEnds {
    /// A buffer to write a frame into: a free one, or else the oldest frame still queued (it is
    /// skipped, counted); `None` while the broadcaster holds every buffer.
    fn take(&self, counters: &ViewCounters) -> Option<FrameBuf> {
        self.free.try_recv().ok().or_else(|| {
            let b = self.queued.try_recv().ok()?;
            counters.frames_skipped.fetch_add(1, Ordering::Relaxed);
            Some(b)
        })
    }
}

/// [`FRAME_BUFFERS`] buffers of `words` words (they grow as needed for a replay's frames) and
/// `states` figure states each, all free.
fn frame_buffers(words: usize, states: usize) -> (FrameWriterEnds, FrameSenderEnds) {
    let (free_tx, free_rx) = bounded(FRAME_BUFFERS);
    let (full_tx, full_rx) = bounded(FRAME_BUFFERS);
    for _ in 0..FRAME_BUFFERS {
        let b = FrameBuf {
            words: vec![0.0; words],
            len: 0,
            states: vec![FigureState::default(); states],
            figures_pending: false,
        };
        let _ = free_tx.try_send(b);
    }
    let writer = FrameWriterEnds { free: free_rx, full: full_tx, queued: full_rx.clone() };
    (writer, FrameSenderEnds { full: full_rx, free: free_tx })
}

/// The mailbox between the stepping thread (or a replay) and the broadcaster.
struct Mailbox {
    status: StatusData,
    status_fresh: bool,
    rig: Option<RigInfo>,
    rig_fresh: bool,
    /// A replay's playback state (JSON, `type` `playback`), handed on as it is.
    playback: Option<String>,
}

impl Mailbox {
    fn new() -> Mailbox {
        Mailbox {
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
    /// Set after the observer queued a frame or wrote the mailbox; the broadcaster polls it (a
    /// wake-up from the stepping thread would be a system call, and the woken thread could
    /// preempt the step).
    fresh: AtomicBool,
    counters: ViewCounters,
    /// Set when the view stops; `done` once the broadcaster has handed out the last status.
    stop: AtomicBool,
    done: AtomicBool,
    /// Where the viewers' text messages go (a replay's controls); the live view takes none.
    commands: Option<SyncSender<String>>,
    /// The pictures' ages the pages report (their `drawn` messages); viewers' threads write it.
    ages: Mutex<PictureAges>,
}

impl Shared {
    fn new(commands: Option<SyncSender<String>>) -> Arc<Shared> {
        Arc::new(Shared {
            mailbox: Mutex::new(Mailbox::new()),
            fresh: AtomicBool::new(false),
            counters: ViewCounters::default(),
            stop: AtomicBool::new(false),
            done: AtomicBool::new(false),
            commands,
            ages: Mutex::new(PictureAges::default()),
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
    frames: FrameWriterEnds,
    /// Where the scene poses when only its counters are wanted (no one watches).
    scratch: Vec<f32>,
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
        let maker = FrameMaker::new(look).with_wall_clock();
        let layout = *maker.layout();
        let finisher = FrameFinisher::new(look);
        let (frames, sender) = frame_buffers(layout.max_words, finisher.states());
        let shared = Shared::new(None);
        let frame_hz = frame_hz_for(opts, 4 * layout.contacts_at);
        let description =
            json::scene(scene_name, look, &layout, arriving_frame_hz(frame_hz, opts.world_step_s));
        let server = server::Server::start(
            opts,
            shared.clone(),
            server::Scene {
                description,
                counter_names: look.counters.clone(),
                offset: look.link_offset_m,
                frames: sender,
                finisher,
            },
        )?;
        let (http, ws) = if opts.tls.is_some() { ("https", "wss") } else { ("http", "ws") };
        let urls = (format!("{http}://{}", server.http_addr), format!("{ws}://{}", server.ws_addr));
        Ok(View {
            shared,
            server: Some(server),
            maker,
            frames,
            scratch: vec![0.0; layout.max_words],
            frame_every_s: 1.0 / frame_hz,
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

    /// Frames a second of loop-clock time while someone watches ([`frame_hz_for`]).
    pub fn frame_hz(&self) -> f64 {
        1.0 / self.frame_every_s
    }

    /// A handle to the counters that outlives the view being moved into a host.
    pub fn counters_handle(&self) -> ViewHandle {
        ViewHandle { shared: self.shared.clone(), urls: self.urls.clone() }
    }

    /// Queues the frame, when one is due and a frame buffer is free (the scene poses into it and
    /// copies its figures' states), and writes the status into the mailbox, if the broadcaster is
    /// not copying it right now. The scene's pose refreshes the counters the status shows.
    fn publish(&mut self, step: &StepView<'_>, frame_due: bool) {
        let c = &self.shared.counters;
        if frame_due {
            match self.frames.take(c) {
                Some(mut b) => {
                    self.next_counters_t_s = step.t_s + 1.0;
                    b.len = self.maker.write(&mut b.words, step, true, false);
                    step.scene.figure_states(&mut b.states);
                    b.figures_pending = !b.states.is_empty();
                    // Never full: it has room for every buffer.
                    if self.frames.full.try_send(b).is_ok() {
                        c.frames_published.fetch_add(1, Ordering::Relaxed);
                    }
                }
                // Every buffer is with the broadcaster: this frame is skipped.
                None => {
                    c.frames_skipped.fetch_add(1, Ordering::Relaxed);
                }
            }
        } else if step.t_s >= self.next_counters_t_s {
            // Unwatched, the scene poses (for the status's counters) once a second, without its
            // figures.
            self.next_counters_t_s = step.t_s + 1.0;
            self.maker.write(&mut self.scratch, step, false, false);
        }
        let Ok(mut mb) = self.shared.mailbox.try_lock() else {
            self.shared.fresh.store(true, Ordering::Release);
            return;
        };
        mb.status = *self.maker.status();
        mb.status_fresh = true;
        if let Some(info) = step.rig_info {
            if mb.rig != Some(*info) {
                mb.rig = Some(*info);
                mb.rig_fresh = true;
            }
        }
        drop(mb);
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
                self.next_frame_t_s = next_due(self.next_frame_t_s, t, self.frame_every_s);
            }
            if status_due {
                self.next_status_t_s = t + self.status_every_s;
            }
        }
    }
}

/// When the frame after one due at `due` (sent at `t`) is due: one period on, so the rate holds
/// on average over steps that do not divide it (at 60 Hz over 3 ms steps: 18, 15, 18 ms ... apart,
/// not 18 every time); one period after `t` when that is already past (after a pause, or a period
/// shorter than a step: every step).
fn next_due(due: f64, t: f64, every: f64) -> f64 {
    let next = due + every;
    if next > t {
        next
    } else {
        t + every
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
    /// The pictures' ages the pages reported so far (see [`PictureAges`]).
    pub fn picture_ages(&self) -> PictureAges {
        self.shared.ages.lock().map(|a| a.clone()).unwrap_or_default()
    }
    /// Forgets the ages reported so far.
    pub fn clear_picture_ages(&self) {
        if let Ok(mut a) = self.shared.ages.lock() {
            a.clear();
        }
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

    /// Frames go out after every step when the period is shorter than a step; at 60 Hz over 3 ms
    /// steps they average 60 a second (18 and 15 ms apart), not one every 18 ms (55.6 Hz); after a
    /// pause the next is one period on, not a burst.
    #[test]
    fn frames_are_due_every_step_or_at_the_rate_on_average() {
        let steps = |every: f64| {
            let (mut due, mut sent) = (f64::NEG_INFINITY, Vec::new());
            for k in 0..2000 {
                let t = k as f64 * 0.003;
                if t >= due {
                    sent.push(t);
                    due = next_due(due, t, every);
                }
            }
            sent
        };
        assert_eq!(steps(1.0 / 1000.0).len(), 2000, "every step");
        let s = steps(1.0 / 60.0);
        let hz = (s.len() - 1) as f64 / (s[s.len() - 1] - s[0]);
        assert!((hz - 60.0).abs() < 0.2, "{hz} frames a second");
        assert!(s.windows(2).all(|w| w[1] - w[0] < 0.0181), "no gap over a step past the period");
        assert_eq!(next_due(1.0, 5.0, 0.1), 5.1, "after a pause: one period on");
    }

    #[test]
    fn big_frames_go_out_less_often_but_at_a_display_rate() {
        let o = ViewOptions::default();
        assert_eq!(frame_hz_for(&o, 1000), o.frame_hz, "a boxing frame: every step");
        assert_eq!(frame_hz_for(&o, 40_000), 100.0, "4 MB/s of 40 kB frames");
        assert_eq!(frame_hz_for(&o, 300_000), MIN_FRAME_HZ, "never under 60 a second");
        assert_eq!(frame_hz_for(&ViewOptions { frame_hz: 30.0, ..o }, 300_000), 30.0, "unless asked");
    }

    #[test]
    fn the_page_is_told_the_rate_frames_arrive_at_at_most_one_a_step() {
        assert!(
            (arriving_frame_hz(1000.0, 0.003) - 1000.0 / 3.0).abs() < 1e-9,
            "a frame after every 3 ms step"
        );
        assert_eq!(arriving_frame_hz(60.0, 0.003), 60.0, "fewer than one a step: as sent");
        assert_eq!(arriving_frame_hz(1000.0, 0.0), 1000.0, "the step not known: as sent");
        assert_eq!(arriving_frame_hz(1000.0, f64::NAN), 1000.0);
    }

    #[test]
    fn a_frame_carries_the_scene_poses_at_the_layout_offsets() {
        let scene = crate::boxing::BoxingScene::new(Default::default()).unwrap();
        let look = crate::Scene::look(&scene);
        let l = Layout::of(&look, 7);
        let mut buf = vec![f32::NAN; l.max_words];
        let hands =
            [HandState { pos_world_m: DVec3::new(0.1, 1.1, 0.0), valid: true, ..Default::default() }; HANDS];
        let model = ContactModel::default();
        let common = frame::Common {
            seq: 3,
            step: 41,
            tick: 123,
            tick_wall_ms: 1.5e12,
            t_s: 1.5,
            hands: &hands,
            tensions_n: None,
            model: &model,
            offset: look.link_offset_m,
        };
        frame::write_common(&mut buf, &l, &common);
        let mut counters = [0.0; crate::look::MAX_COUNTERS];
        let mut contacts = 0;
        crate::Scene::pose(&scene, &mut l.poses(&mut buf, &mut counters, &mut contacts, true));
        assert_eq!((buf[0].to_bits(), buf[1].to_bits(), buf[2].to_bits()), (MAGIC, 7, 3));
        let word = |k: usize| buf[frame::STAMP_AT + k].to_bits() as u64;
        assert_eq!((word(0) | word(1) << 32, word(2) | word(3) << 32), (41, 123), "the step and tick");
        assert_eq!(f64::from_bits(word(4) | word(5) << 32), 1.5e12, "the tick's wall-clock time");
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
        // Nothing written past the scene's sections but the proxies (all empty here) and the
        // virtual human's gaze: from its head, a unit direction, a point on that line.
        assert!(buf[l.proxies_at..l.gaze_at].iter().all(|x| *x == 0.0));
        assert_eq!((l.gazes, l.contacts_at - l.gaze_at), (1, crate::look::GAZE_FLOATS));
        let g: Vec<DVec3> = buf[l.gaze_at..l.contacts_at]
            .chunks(3)
            .map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64))
            .collect();
        assert!((g[0] - scene.world.com(scene.world.vh.head)).length() < 1e-5, "the eyes: {g:?}");
        assert!((g[1].length() - 1.0).abs() < 1e-6 && ((g[2] - g[0]).normalize() - g[1]).length() < 1e-5);
        assert!(buf[l.contacts_at..].iter().all(|x| x.is_nan()));
        // Nothing to finish: a viewer gets the words as written.
        let mut bytes = Vec::new();
        FrameFinisher::new(&look).to_bytes(&buf, &[], &mut bytes);
        assert_eq!(bytes, buf.iter().flat_map(|w| w.to_le_bytes()).collect::<Vec<u8>>());
    }

    /// A crowd's frame written on the stepping thread without its figures, with the figures'
    /// states copied, and finished a few steps later (as the broadcaster and the recorder's writer
    /// do, while the crowd steps on) is the frame written with its figures at that step, bit for
    /// bit: in place (the recorder) and as the bytes a viewer gets (the broadcaster). Over pushes
    /// that topple characters, so fallen and standing-up figures are among those compared.
    #[test]
    fn a_crowd_frame_finished_later_is_the_frame_written_with_its_figures() {
        use crate::Scene;
        use spidar_msg::HandSample;
        use spidar_sim::character::controller::Policy;
        use spidar_sim::character::drawn::FigureState;
        let mut scene = crate::crowd::CrowdScene::builtin().unwrap();
        let look = scene.look();
        let (mut now, mut later) = (FrameMaker::new(&look), FrameMaker::new(&look));
        let finisher = FrameFinisher::new(&look);
        let l = *now.layout();
        let n = scene.crowd.len();
        assert_eq!(finisher.states(), n);
        let sample = HandSample {
            hands: [HandState { valid: true, ..Default::default() }; HANDS],
            ..Default::default()
        };
        // (step, frame without its figures, its figures' states, frame with its figures)
        type Made = (usize, Vec<f32>, Vec<FigureState>, Vec<f32>);
        let mut pending: Vec<Made> = Vec::new();
        let (mut compared, mut fallen, mut moved) = (0, 0, 0);
        for k in 0..4000usize {
            if k % 400 == 10 {
                let i = (k / 400) % n;
                let b = scene.crowd.body_space(i);
                scene.crowd.add_impulse_at(i, b.r_m + DVec3::Y * 0.5, DVec3::X * 150.0);
            }
            let t = k as f64 * 0.003;
            let m = scene.step(t, std::slice::from_ref(&sample));
            let step = StepView {
                t_s: t,
                scene: &scene,
                samples: std::slice::from_ref(&sample),
                model: &m,
                rig_info: None,
                rig_status: None,
            };
            now.observe(&step, true);
            later.observe(&step, true);
            // Frames made three steps ago, finished now.
            for (made, mut frame, states, want) in pending.extract_if(.., |p| p.0 + 3 == k) {
                let mut bytes = Vec::new();
                finisher.to_bytes(&frame, &states, &mut bytes);
                let want_bytes: Vec<u8> = want.iter().flat_map(|w| w.to_le_bytes()).collect();
                assert!(
                    bytes == want_bytes,
                    "step {made}: the bytes sent differ from the frame with its figures"
                );
                let unfinished = frame.clone();
                finisher.finish(&mut frame, &states);
                let bits = |f: &[f32]| f.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&frame), bits(&want), "step {made}: the frame finished in place differs");
                moved += usize::from(bits(&unfinished) != bits(&want));
                compared += 1;
            }
            if k % 6 == 0 {
                let mut a = vec![0.0; l.max_words];
                let words = now.write(&mut a, &step, true, true);
                let mut b = vec![0.0; l.max_words];
                assert_eq!(later.write(&mut b, &step, true, false), words);
                let mut states = vec![FigureState::default(); n];
                scene.figure_states(&mut states);
                fallen += scene.crowd.chars.iter().filter(|c| c.control.policy != Policy::Balance).count();
                a.truncate(words);
                b.truncate(words);
                pending.push((k, b, states, a));
            }
        }
        assert!(compared > 600, "{compared} frames compared");
        assert!(fallen > 0, "no character was down or falling in a frame compared");
        assert_eq!(moved, compared, "a frame without its figures must differ from one with them");
    }
}
