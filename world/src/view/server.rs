//! The view's threads: the page over HTTP (`tiny_http`), viewers over WebSocket (`tungstenite`,
//! one thread each, on the port after the page's), and the broadcaster between the observer (its
//! queued frames and its mailbox) and the viewers.
//!
//! The broadcaster is the one thread that finishes frames: it takes the newest queued frame,
//! computes its drawn figures (a crowd's, from the states copied with it), turns it into bytes
//! once for all viewers and hands the buffer back. Every viewer has a slot holding the newest
//! frame and the newest text of each kind; the broadcaster overwrites it (a slow viewer gets fewer
//! frames, never a queue), the viewer's thread sends it. A viewer's socket has a write timeout: a
//! viewer that takes no data for that long is dropped and counted. Nothing here ever holds the
//! mailbox for longer than a copy.

use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use glam::DVec3;
use spidar_sim::character::drawn::FigureState;
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Bytes, Message, WebSocket};

use super::rigview::NearStrings;
use super::{json, FrameFinisher, FrameSenderEnds, Shared, ViewError, ViewOptions, BUNDLE_JS, INDEX_HTML};

/// What the threads serve of a scene: its description (the `scene` message), the names of its
/// counters, the link's offset in its frame, and the frames queued for the viewers with what
/// finishes them.
pub(super) struct Scene {
    pub description: String,
    pub counter_names: Vec<String>,
    pub offset: DVec3,
    pub frames: FrameSenderEnds,
    pub finisher: FrameFinisher,
}

/// The newest text messages, for viewers that connect later and for `/status.json`.
#[derive(Default)]
struct Latest {
    scene: String,
    /// The newest frame: a viewer that connects sees it at once (a paused replay sends no other).
    frame: Option<Bytes>,
    rig: Option<String>,
    status: Option<String>,
    playback: Option<String>,
}

#[derive(Default)]
struct Slot {
    frame: Option<Bytes>,
    rig: Option<String>,
    status: Option<String>,
    playback: Option<String>,
}

struct Viewer {
    slot: Mutex<Slot>,
    wake: Condvar,
    gone: AtomicBool,
}

type Viewers = Arc<Mutex<Vec<Arc<Viewer>>>>;

/// How often the broadcaster looks at the mailbox.
const POLL: Duration = Duration::from_millis(1);

pub(super) struct Server {
    pub http_addr: SocketAddr,
    pub ws_addr: SocketAddr,
    threads: Vec<JoinHandle<()>>,
}

fn bind(addr: SocketAddr) -> Result<TcpListener, ViewError> {
    TcpListener::bind(addr).map_err(|source| ViewError::Bind { addr, source })
}

impl Server {
    pub fn start(opts: &ViewOptions, shared: Arc<Shared>, scene: Scene) -> Result<Server, ViewError> {
        let mut http_listener = bind(opts.addr)?;
        let http_addr = http_listener.local_addr().map_err(ViewError::Thread)?;
        // The WebSocket on the next port when a port was asked for; when any port was (0), any
        // port too: the HTTP port's neighbour may be another program's ephemeral port (seen: a
        // test's view failing to bind on a loaded CI machine). The page learns the port either way.
        let ws_want = match opts.addr.port() {
            0 => SocketAddr::new(http_addr.ip(), 0),
            _ => SocketAddr::new(
                http_addr.ip(),
                http_addr
                    .port()
                    .checked_add(1)
                    .ok_or_else(|| ViewError::Address(format!("{http_addr} (no port after it)")))?,
            ),
        };
        let mut ws_listener = bind(ws_want)?;
        let ws_addr = ws_listener.local_addr().map_err(ViewError::Thread)?;
        // With TLS the public ports are TLS fronts relaying to plain servers on loopback ports.
        let mut fronts = Vec::new();
        if let Some(id) = &opts.tls {
            for public in [&mut http_listener, &mut ws_listener] {
                let inner = bind(SocketAddr::from(([127, 0, 0, 1], 0)))?;
                let inner_addr = inner.local_addr().map_err(ViewError::Thread)?;
                fronts.push((std::mem::replace(public, inner), inner_addr, id.clone()));
            }
        }
        ws_listener.set_nonblocking(true).map_err(ViewError::Thread)?;
        let http = tiny_http::Server::from_listener(http_listener, None)
            .map_err(|e| ViewError::Thread(std::io::Error::other(e.to_string())))?;
        let index = INDEX_HTML.replace("{{WS_PORT}}", &ws_addr.port().to_string());
        let Scene { description, counter_names, offset, frames, finisher } = scene;
        let latest = Arc::new(Mutex::new(Latest { scene: description, ..Default::default() }));
        let viewers: Viewers = Arc::new(Mutex::new(Vec::new()));
        let spawn = |name: &str, f: Box<dyn FnOnce() + Send>| {
            std::thread::Builder::new().name(name.into()).spawn(f).map_err(ViewError::Thread)
        };
        let mut threads = Vec::new();
        for (listener, backend, id) in fronts {
            let shared = shared.clone();
            threads.push(spawn(
                "spidar-view-tls-front",
                Box::new(move || super::tls::front(listener, backend, id, shared)),
            )?);
        }
        {
            let (shared, latest) = (shared.clone(), latest.clone());
            threads
                .push(spawn("spidar-view-http", Box::new(move || serve_http(http, index, shared, latest)))?);
        }
        {
            let (shared, latest, viewers, opts) =
                (shared.clone(), latest.clone(), viewers.clone(), opts.clone());
            threads.push(spawn(
                "spidar-view-accept",
                Box::new(move || accept_viewers(ws_listener, shared, latest, viewers, opts)),
            )?);
        }
        {
            let status_every = Duration::from_secs_f64(1.0 / opts.status_hz.max(0.1));
            let texts = Texts { counter_names, offset, status_every };
            threads.push(spawn(
                "spidar-view-frames",
                Box::new(move || broadcast(shared, latest, viewers, frames, finisher, texts)),
            )?);
        }
        Ok(Server { http_addr, ws_addr, threads })
    }

    /// Waits for the threads (the stop flag is set): the broadcaster sends the last status first.
    pub fn stop(self) {
        for t in self.threads {
            let _ = t.join();
        }
    }
}

fn serve_http(http: tiny_http::Server, index: String, shared: Arc<Shared>, latest: Arc<Mutex<Latest>>) {
    let header = |k: &str, v: &str| tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()).ok();
    while !shared.stop.load(Ordering::Relaxed) {
        let req = match http.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(_) => break,
        };
        let path = req.url().split('?').next().unwrap_or("").to_string();
        let (body, kind) = match path.as_str() {
            "/" | "/index.html" => (index.clone(), "text/html; charset=utf-8"),
            "/spidar-view.js" => (BUNDLE_JS.to_string(), "text/javascript; charset=utf-8"),
            "/scene.json" => (latest.lock().map(|l| l.scene.clone()).unwrap_or_default(), "application/json"),
            "/status.json" => (
                latest.lock().ok().and_then(|l| l.status.clone()).unwrap_or_else(|| "null".into()),
                "application/json",
            ),
            "/rig.json" => (
                latest.lock().ok().and_then(|l| l.rig.clone()).unwrap_or_else(|| "null".into()),
                "application/json",
            ),
            "/playback.json" => (
                latest.lock().ok().and_then(|l| l.playback.clone()).unwrap_or_else(|| "null".into()),
                "application/json",
            ),
            // A benchmark's measured window starts here: the reports so far are forgotten.
            "/clear-ages" => {
                if let Ok(mut a) = shared.ages.lock() {
                    a.clear();
                }
                let _ = req.respond(tiny_http::Response::empty(204));
                continue;
            }
            "/favicon.ico" => {
                let _ = req.respond(tiny_http::Response::empty(204));
                continue;
            }
            _ => {
                let _ = req.respond(tiny_http::Response::from_string("not found").with_status_code(404));
                continue;
            }
        };
        let mut resp = tiny_http::Response::from_string(body);
        // Cross-origin isolated (the page loads nothing from elsewhere): the page may then share
        // memory with the worker that receives its frames (web/src/connection.js).
        let isolated = [
            header("Cross-Origin-Opener-Policy", "same-origin"),
            header("Cross-Origin-Embedder-Policy", "require-corp"),
            header("Cross-Origin-Resource-Policy", "same-origin"),
        ];
        let headers = [header("Content-Type", kind), header("Cache-Control", "no-store")];
        for h in headers.into_iter().chain(isolated).flatten() {
            resp.add_header(h);
        }
        let _ = req.respond(resp);
    }
}

fn accept_viewers(
    listener: TcpListener,
    shared: Arc<Shared>,
    latest: Arc<Mutex<Latest>>,
    viewers: Viewers,
    opts: super::ViewOptions,
) {
    while !shared.stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                let (shared, latest, viewers, opts) =
                    (shared.clone(), latest.clone(), viewers.clone(), opts.clone());
                let started = std::thread::Builder::new()
                    .name("spidar-view-viewer".into())
                    .spawn(move || serve_viewer(stream, shared, latest, viewers, &opts));
                if started.is_err() {
                    // Out of threads: the connection is dropped with the closure.
                    continue;
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

/// Whether an error means the socket took no data within its timeout (a stalled viewer).
fn timed_out(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(io) if matches!(io.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut))
}

fn serve_viewer(
    stream: TcpStream,
    shared: Arc<Shared>,
    latest: Arc<Mutex<Latest>>,
    viewers: Viewers,
    opts: &super::ViewOptions,
) {
    let c = &shared.counters;
    let setup = stream
        .set_nonblocking(false)
        .and_then(|_| stream.set_nodelay(true))
        .and_then(|_| stream.set_read_timeout(Some(Duration::from_secs(2))))
        .and_then(|_| stream.set_write_timeout(Some(opts.write_timeout)));
    if setup.is_err() {
        return;
    }
    // Each message goes out as it is sent (no batching behind the frame rate).
    let cfg = WebSocketConfig::default().write_buffer_size(0);
    let Ok(mut ws) = tungstenite::accept_with_config(stream, Some(cfg)) else { return };
    let me = Arc::new(Viewer {
        slot: Mutex::new(Slot::default()),
        wake: Condvar::new(),
        gone: AtomicBool::new(false),
    });
    {
        let Ok(mut list) = viewers.lock() else { return };
        if list.len() >= opts.max_viewers {
            c.viewers_refused.fetch_add(1, Ordering::Relaxed);
            let _ = ws.close(None);
            let _ = ws.flush();
            return;
        }
        list.push(me.clone());
        c.viewers.fetch_add(1, Ordering::Relaxed);
        c.viewers_total.fetch_add(1, Ordering::Relaxed);
    }
    let dropped = run_viewer(&mut ws, &me, &shared, &latest);
    if dropped {
        c.viewers_dropped.fetch_add(1, Ordering::Relaxed);
    }
    me.gone.store(true, Ordering::Relaxed);
    if let Ok(mut list) = viewers.lock() {
        list.retain(|v| !Arc::ptr_eq(v, &me));
    }
    c.viewers.fetch_sub(1, Ordering::Relaxed);
}

/// Sends the viewer its slot until it leaves, the view stops, or its socket stalls (returns true).
fn run_viewer(ws: &mut WebSocket<TcpStream>, me: &Viewer, shared: &Shared, latest: &Mutex<Latest>) -> bool {
    let (first, frame): (Vec<String>, _) = match latest.lock() {
        Ok(l) => (
            [Some(l.scene.clone()), l.rig.clone(), l.status.clone(), l.playback.clone()]
                .into_iter()
                .flatten()
                .collect(),
            l.frame.clone(),
        ),
        Err(_) => return false,
    };
    for t in first {
        if let Err(e) = ws.send(Message::text(t)) {
            return timed_out(&e);
        }
    }
    if let Some(f) = frame {
        if let Err(e) = ws.send(Message::Binary(f)) {
            return timed_out(&e);
        }
        shared.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
    }
    loop {
        let stopping = shared.done.load(Ordering::Relaxed);
        let slot = {
            let Ok(mut s) = me.slot.lock() else { return false };
            if s.frame.is_none() && s.rig.is_none() && s.status.is_none() && s.playback.is_none() && !stopping
            {
                // Not long: the viewer's messages are read in between.
                s = match me.wake.wait_timeout(s, Duration::from_millis(50)) {
                    Ok((s, _)) => s,
                    Err(_) => return false,
                };
            }
            std::mem::take(&mut *s)
        };
        let texts = [slot.rig, slot.status, slot.playback].into_iter().flatten();
        for t in texts {
            if let Err(e) = ws.send(Message::text(t)) {
                return timed_out(&e);
            }
        }
        if let Some(f) = slot.frame {
            if let Err(e) = ws.send(Message::Binary(f)) {
                return timed_out(&e);
            }
            shared.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
        }
        // Reads only drain what the viewer sent: never wait on it. Non-blocking for the drain (a
        // read timeout would not do: the kernel rounds it up to whole scheduler ticks, 4-8 ms
        // here, during which the newest frame would wait in the slot), blocking again for writes.
        if ws.get_mut().set_nonblocking(true).is_err() {
            return false;
        }
        let drained = drain(ws, shared);
        if ws.get_mut().set_nonblocking(false).is_err() {
            return false;
        }
        match drained {
            Drained::Closed => {
                let _ = ws.flush();
                return false;
            }
            Drained::Failed => return false,
            Drained::Empty => {}
        }
        if stopping {
            let _ = ws.close(None);
            let _ = ws.flush();
            return false;
        }
    }
}

/// How draining a viewer's messages ended.
enum Drained {
    Empty,
    Closed,
    Failed,
}

/// Reads every message the viewer has sent so far (its socket non-blocking): pictures drawn go to
/// the ages, other texts to the replay's controls.
fn drain(ws: &mut WebSocket<TcpStream>, shared: &Shared) -> Drained {
    loop {
        match ws.read() {
            Ok(Message::Close(_)) => return Drained::Closed,
            Ok(Message::Text(t)) => {
                // A picture drawn, with its age; else a replay's controls (a full queue drops
                // the command: the page resends).
                if let Some(d) = super::Drawn::parse(t.as_str()) {
                    if let Ok(mut a) = shared.ages.lock() {
                        a.record(&d);
                    }
                } else if let Some(c) = &shared.commands {
                    let _ = c.try_send(t.as_str().to_string());
                }
            }
            Ok(_) => continue,
            Err(e) if timed_out(&e) => return Drained::Empty,
            Err(_) => return Drained::Failed,
        }
    }
}

/// How the broadcaster writes the text messages.
struct Texts {
    counter_names: Vec<String>,
    offset: DVec3,
    status_every: Duration,
}

/// The newest queued frame, finished (its figures drawn) and as bytes; every buffer goes back to
/// the free ones (older frames queued behind it are skipped and counted).
/// With the rig known (`near`), the frame's header marks its near strings.
fn newest_frame(
    frames: &FrameSenderEnds,
    finisher: &FrameFinisher,
    shared: &Shared,
    near: Option<&NearStrings>,
) -> Option<Bytes> {
    let mut newest = None;
    while let Ok(b) = frames.full.try_recv() {
        if let Some(old) = newest.replace(b) {
            shared.counters.frames_skipped.fetch_add(1, Ordering::Relaxed);
            let _ = frames.free.try_send(old);
        }
    }
    let b = newest?;
    let mut bytes = Vec::new();
    let states: &[FigureState] = if b.figures_pending { &b.states } else { &[] };
    finisher.to_bytes(&b.words[..b.len], states, &mut bytes);
    let _ = frames.free.try_send(b);
    if let Some(n) = near {
        n.mark(&mut bytes);
    }
    Some(Bytes::from(bytes))
}

fn broadcast(
    shared: Arc<Shared>,
    latest: Arc<Mutex<Latest>>,
    viewers: Viewers,
    frames: FrameSenderEnds,
    finisher: FrameFinisher,
    texts: Texts,
) {
    // However this thread ends, the viewers' threads are told to close and leave.
    struct Done<'a>(&'a Shared);
    impl Drop for Done<'_> {
        fn drop(&mut self) {
            self.0.done.store(true, Ordering::Relaxed);
        }
    }
    let _done = Done(&shared);
    let c = &shared.counters;
    let Texts { counter_names, offset, status_every } = texts;
    let mut near: Option<NearStrings> = None;
    let mut last_status = Instant::now() - status_every;
    loop {
        // Poll: the stepping thread never wakes anyone.
        let until = Instant::now() + Duration::from_millis(250);
        while !shared.fresh.load(Ordering::Acquire)
            && !shared.stop.load(Ordering::Relaxed)
            && Instant::now() < until
        {
            std::thread::sleep(POLL);
        }
        shared.fresh.store(false, Ordering::Relaxed);
        // Outside the mailbox's lock: computing a crowd's figures takes a while.
        let frame = newest_frame(&frames, &finisher, &shared, near.as_ref());
        let (status, rig, playback, stopping) = {
            let Ok(mut mb) = shared.mailbox.lock() else { return };
            let status = mb.status_fresh.then_some(mb.status);
            mb.status_fresh = false;
            let rig = if mb.rig_fresh { mb.rig } else { None };
            mb.rig_fresh = false;
            (status, rig, mb.playback.take(), shared.stop.load(Ordering::Relaxed))
        };
        let viewer_count = c.viewers.load(Ordering::Relaxed);
        if let Some(r) = &rig {
            near = Some(NearStrings::new(r, offset));
        }
        // Once per rig geometry: the workspace cells take a few milliseconds.
        let rig_json = rig.map(|r| json::rig(&r, offset));
        let status_json =
            status.filter(|s| s.ended || stopping || last_status.elapsed() >= status_every).map(|s| {
                last_status = Instant::now();
                let ages = shared.ages.lock().map(|a| a.summaries()).unwrap_or_default();
                json::status(
                    &s,
                    &counter_names,
                    viewer_count,
                    c.frames_published.load(Ordering::Relaxed),
                    c.frames_skipped.load(Ordering::Relaxed),
                    ages,
                )
            });
        if let Ok(mut l) = latest.lock() {
            if let Some(r) = &rig_json {
                l.rig = Some(r.clone());
            }
            if let Some(s) = &status_json {
                l.status = Some(s.clone());
            }
            if let Some(p) = &playback {
                l.playback = Some(p.clone());
            }
            if let Some(f) = &frame {
                l.frame = Some(f.clone());
            }
        }
        let list: Vec<Arc<Viewer>> = viewers.lock().map(|l| l.clone()).unwrap_or_default();
        for v in list.iter().filter(|v| !v.gone.load(Ordering::Relaxed)) {
            let Ok(mut s) = v.slot.lock() else { continue };
            if let Some(f) = &frame {
                if s.frame.replace(f.clone()).is_some() {
                    c.frames_replaced.fetch_add(1, Ordering::Relaxed);
                }
                c.frames_queued.fetch_add(1, Ordering::Relaxed);
            }
            if let Some(r) = &rig_json {
                s.rig = Some(r.clone());
            }
            if let Some(st) = &status_json {
                s.status = Some(st.clone());
            }
            if let Some(p) = &playback {
                s.playback = Some(p.clone());
            }
            drop(s);
            v.wake.notify_one();
        }
        if stopping {
            // The viewers' threads send what their slots hold, close and leave.
            shared.done.store(true, Ordering::Relaxed);
            for v in &list {
                v.wake.notify_one();
            }
            return;
        }
    }
}
