//! A live Foxglove server: a session's channels served over the Foxglove WebSocket protocol
//! (`foxglove.websocket.v1`), so Foxglove or Lichtblick connect to a running world (or rig) and
//! see what its recording will hold, as it happens.
//!
//! The protocol, as this server speaks it: the client opens a WebSocket asking for the
//! subprotocol `foxglove.websocket.v1`; the server sends a `serverInfo` text message, then an
//! `advertise` message listing every channel (id, topic, `cdr` encoding, schema name, schema text
//! in `ros2msg`). The client sends `subscribe` (`{"op":"subscribe","subscriptions":[{"id":S,
//! "channelId":C}]}`) and `unsubscribe` (`{"op":"unsubscribe","subscriptionIds":[S]}`); for
//! each subscribed message the server sends a binary frame: opcode 1, the subscription id (u32
//! LE), the message's time (u64 LE, Unix ns), the message bytes. A client that subscribes is sent
//! the newest message of the channel at once (a 3D panel then has the whole scene, which is
//! re-sent only once a second).
//!
//! This module knows nothing of the messages: a [`Publisher`] is handed encoded messages (by the
//! recorder's thread, `spidar_record::channel::Tap`) with their channel's index. Threads, no async
//! runtime, as the live view: one accepting connections, one per client.
//!
//! What it must never do: make a publisher wait. Publishing copies the bytes once into shared
//! memory and queues a handle per subscribed client (a bounded queue: a client that falls behind
//! loses messages, counted); a client's thread writes with a timeout, and a client that takes no
//! data for that long is dropped and counted. The world's step never sees any of it.

use std::collections::{HashMap, VecDeque};
use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use serde_json::{json, Value};
use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Bytes, Message, WebSocket};

/// The subprotocol of the Foxglove WebSocket protocol, version 1.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// Messages queued for one client before its newest ones are dropped.
pub const CLIENT_QUEUE: usize = 4096;

/// One channel as advertised.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FoxgloveChannel {
    pub topic: String,
    /// Message encoding (`cdr`).
    pub encoding: String,
    pub schema_name: String,
    pub schema: String,
    /// Schema encoding (`ros2msg`).
    pub schema_encoding: String,
}

/// Errors of starting the server.
#[derive(Debug, thiserror::Error)]
pub enum FoxgloveError {
    #[error("cannot serve Foxglove at {addr}: {source} (choose another port, e.g. --foxglove 127.0.0.1:0 for any)")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("'{0}' is not an address to serve Foxglove at: use HOST:PORT or :PORT (e.g. 127.0.0.1:8765)")]
    Address(String),
    #[error("starting the Foxglove server's threads: {0}")]
    Thread(std::io::Error),
}

/// Parses `HOST:PORT`, `:PORT` (127.0.0.1) or `ws://HOST:PORT`.
pub fn parse_addr(s: &str) -> Result<SocketAddr, FoxgloveError> {
    let t = s.trim().trim_start_matches("ws://").trim_end_matches('/');
    let t = if t.starts_with(':') { format!("127.0.0.1{t}") } else { t.to_string() };
    use std::net::ToSocketAddrs;
    t.to_socket_addrs().ok().and_then(|mut a| a.next()).ok_or_else(|| FoxgloveError::Address(s.into()))
}

/// Counts of the server.
#[derive(Debug, Default)]
pub struct FoxgloveCounters {
    /// Clients connected now, and in all.
    pub clients: AtomicU64,
    pub clients_total: AtomicU64,
    /// Clients dropped because their socket took no data for the write timeout.
    pub clients_dropped: AtomicU64,
    /// Connections refused (no foxglove subprotocol asked for).
    pub refused: AtomicU64,
    pub messages_published: AtomicU64,
    pub messages_sent: AtomicU64,
    /// Messages a client's full queue did not take.
    pub messages_dropped: AtomicU64,
}

struct Client {
    queue: Mutex<VecDeque<Bytes>>,
    wake: Condvar,
    /// channel index -> subscription id.
    subs: Mutex<HashMap<usize, u32>>,
    gone: AtomicBool,
}

struct Inner {
    channels: Vec<FoxgloveChannel>,
    clients: Mutex<Vec<Arc<Client>>>,
    /// The newest message of each channel (time, bytes), for a client that subscribes later.
    latest: Mutex<Vec<Option<(u64, Bytes)>>>,
    counters: FoxgloveCounters,
    stop: AtomicBool,
    write_timeout: Duration,
    name: String,
    /// The client threads, joined when the server stops (so a client gets what was queued).
    threads: Mutex<Vec<std::thread::JoinHandle<()>>>,
}

/// The handle that publishes messages; cheap to clone, never waits.
#[derive(Clone)]
pub struct Publisher {
    inner: Arc<Inner>,
}

/// A frame for subscription `sub`: opcode 1, the id, the time, the message.
fn frame(sub: u32, log_ns: u64, data: &[u8]) -> Bytes {
    let mut b = Vec::with_capacity(13 + data.len());
    b.push(1u8);
    b.extend_from_slice(&sub.to_le_bytes());
    b.extend_from_slice(&log_ns.to_le_bytes());
    b.extend_from_slice(data);
    Bytes::from(b)
}

impl Publisher {
    /// Channel `ch`'s next message at `log_ns` (Unix ns). Never waits for a client.
    pub fn publish(&self, ch: usize, log_ns: u64, data: &[u8]) {
        let i = &self.inner;
        if ch >= i.channels.len() {
            return;
        }
        i.counters.messages_published.fetch_add(1, Ordering::Relaxed);
        let Ok(clients) = i.clients.lock() else { return };
        let subscribed: Vec<(Arc<Client>, u32)> = clients
            .iter()
            .filter_map(|c| c.subs.lock().ok().and_then(|s| s.get(&ch).copied()).map(|sub| (c.clone(), sub)))
            .collect();
        drop(clients);
        if let Ok(mut l) = i.latest.lock() {
            l[ch] = Some((log_ns, Bytes::copy_from_slice(data)));
        }
        for (c, sub) in subscribed {
            let Ok(mut q) = c.queue.lock() else { continue };
            if q.len() >= CLIENT_QUEUE {
                i.counters.messages_dropped.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            q.push_back(frame(sub, log_ns, data));
            c.wake.notify_one();
        }
    }

    pub fn counters(&self) -> &FoxgloveCounters {
        &self.inner.counters
    }
}

/// The running server: its address, its publisher, its threads.
pub struct FoxgloveServer {
    addr: SocketAddr,
    publisher: Publisher,
    accept: Option<JoinHandle<()>>,
}

impl FoxgloveServer {
    /// Listens at `addr` (port 0: any free port) and advertises `channels` (their index is the
    /// channel given to [`Publisher::publish`]). `name` is the server's name shown to clients.
    pub fn start(
        addr: SocketAddr,
        name: &str,
        channels: Vec<FoxgloveChannel>,
        write_timeout: Duration,
    ) -> Result<FoxgloveServer, FoxgloveError> {
        let listener = TcpListener::bind(addr).map_err(|source| FoxgloveError::Bind { addr, source })?;
        let addr = listener.local_addr().map_err(FoxgloveError::Thread)?;
        listener.set_nonblocking(true).map_err(FoxgloveError::Thread)?;
        let inner = Arc::new(Inner {
            latest: Mutex::new(vec![None; channels.len()]),
            channels,
            clients: Mutex::new(Vec::new()),
            counters: FoxgloveCounters::default(),
            stop: AtomicBool::new(false),
            write_timeout,
            name: name.into(),
            threads: Mutex::new(Vec::new()),
        });
        let i = inner.clone();
        let accept = std::thread::Builder::new()
            .name("spidar-foxglove-accept".into())
            .spawn(move || accept_clients(listener, i))
            .map_err(FoxgloveError::Thread)?;
        Ok(FoxgloveServer { addr, publisher: Publisher { inner }, accept: Some(accept) })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The address a Foxglove client opens (`ws://HOST:PORT`).
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    pub fn publisher(&self) -> Publisher {
        self.publisher.clone()
    }

    /// [`Publisher::publish`] through the server itself.
    pub fn publish(&self, ch: usize, log_ns: u64, data: &[u8]) {
        self.publisher.publish(ch, log_ns, data);
    }

    pub fn counters(&self) -> &FoxgloveCounters {
        &self.publisher.inner.counters
    }

    /// Stops accepting and closes every client.
    pub fn stop(&mut self) {
        self.publisher.inner.stop.store(true, Ordering::Relaxed);
        if let Ok(cs) = self.publisher.inner.clients.lock() {
            for c in cs.iter() {
                c.wake.notify_all();
            }
        }
        if let Some(h) = self.accept.take() {
            let _ = h.join();
        }
        // Each client sends what is queued and closes; a stalled one gives up after the
        // write timeout.
        let threads =
            self.publisher.inner.threads.lock().map(|mut t| std::mem::take(&mut *t)).unwrap_or_default();
        for h in threads {
            let _ = h.join();
        }
    }
}

impl Drop for FoxgloveServer {
    fn drop(&mut self) {
        self.stop();
    }
}

fn accept_clients(listener: TcpListener, inner: Arc<Inner>) {
    while !inner.stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                let i = inner.clone();
                let spawned = std::thread::Builder::new()
                    .name("spidar-foxglove-client".into())
                    .spawn(move || serve_client(stream, i));
                if let (Ok(h), Ok(mut threads)) = (spawned, inner.threads.lock()) {
                    threads.retain(|t| !t.is_finished());
                    threads.push(h);
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

fn timed_out(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(io) if matches!(io.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut))
}

// The handshake callback's error type is tungstenite's own response.
#[allow(clippy::result_large_err)]
fn serve_client(stream: TcpStream, inner: Arc<Inner>) {
    let setup = stream
        .set_nonblocking(false)
        .and_then(|_| stream.set_nodelay(true))
        .and_then(|_| stream.set_read_timeout(Some(Duration::from_secs(2))))
        .and_then(|_| stream.set_write_timeout(Some(inner.write_timeout)));
    if setup.is_err() {
        return;
    }
    let mut asked = false;
    let answer = |req: &Request, mut resp: Response| -> Result<Response, ErrorResponse> {
        let offered = req.headers().get_all("Sec-WebSocket-Protocol");
        if offered
            .iter()
            .filter_map(|v| v.to_str().ok())
            .any(|v| v.split(',').any(|p| p.trim() == SUBPROTOCOL))
        {
            resp.headers_mut().insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().expect("a valid header"));
            asked = true;
        }
        Ok(resp)
    };
    let cfg = WebSocketConfig::default().write_buffer_size(0);
    let Ok(mut ws) = tungstenite::accept_hdr_with_config(stream, answer, Some(cfg)) else { return };
    let c = &inner.counters;
    if !asked {
        c.refused.fetch_add(1, Ordering::Relaxed);
        let _ = ws.close(None);
        let _ = ws.flush();
        return;
    }
    let me = Arc::new(Client {
        queue: Mutex::new(VecDeque::new()),
        wake: Condvar::new(),
        subs: Mutex::new(HashMap::new()),
        gone: AtomicBool::new(false),
    });
    if let Ok(mut l) = inner.clients.lock() {
        l.push(me.clone());
    }
    c.clients.fetch_add(1, Ordering::Relaxed);
    c.clients_total.fetch_add(1, Ordering::Relaxed);
    if run_client(&mut ws, &me, &inner) {
        c.clients_dropped.fetch_add(1, Ordering::Relaxed);
    }
    me.gone.store(true, Ordering::Relaxed);
    if let Ok(mut l) = inner.clients.lock() {
        l.retain(|x| !Arc::ptr_eq(x, &me));
    }
    c.clients.fetch_sub(1, Ordering::Relaxed);
}

/// The server's first two messages: who it is, and every channel.
fn hello(inner: &Inner) -> [String; 2] {
    let info = json!({
        "op": "serverInfo",
        "name": inner.name,
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": {},
        "sessionId": format!("{:x}", std::process::id()),
    });
    let channels: Vec<Value> = inner
        .channels
        .iter()
        .enumerate()
        .map(|(i, ch)| {
            json!({
                "id": i as u32 + 1,
                "topic": ch.topic,
                "encoding": ch.encoding,
                "schemaName": ch.schema_name,
                "schema": ch.schema,
                "schemaEncoding": ch.schema_encoding,
            })
        })
        .collect();
    [info.to_string(), json!({ "op": "advertise", "channels": channels }).to_string()]
}

/// Serves one client until it leaves, the server stops, or its socket stalls (returns true).
fn run_client(ws: &mut WebSocket<TcpStream>, me: &Client, inner: &Inner) -> bool {
    for t in hello(inner) {
        if let Err(e) = ws.send(Message::text(t)) {
            return timed_out(&e);
        }
    }
    // Reads only take the client's requests: never wait on them.
    if ws.get_mut().set_read_timeout(Some(Duration::from_millis(1))).is_err() {
        return false;
    }
    loop {
        if inner.stop.load(Ordering::Relaxed) {
            // What was published before the end reaches the client before the close: a client
            // that kept up must hold everything the recording holds (each send is bounded by
            // the write timeout, so a stalled client cannot hold the end up for long).
            let rest: Vec<Bytes> = me.queue.lock().map(|mut q| q.drain(..).collect()).unwrap_or_default();
            for b in rest {
                if ws.send(Message::Binary(b)).is_err() {
                    return false;
                }
                inner.counters.messages_sent.fetch_add(1, Ordering::Relaxed);
            }
            let _ = ws.close(None);
            let _ = ws.flush();
            return false;
        }
        loop {
            match ws.read() {
                Ok(Message::Text(t)) => on_request(t.as_str(), me, inner),
                Ok(Message::Close(_)) => return false,
                Ok(_) => {}
                Err(e) if timed_out(&e) => break,
                Err(_) => return false,
            }
        }
        let batch: Vec<Bytes> = {
            let Ok(mut q) = me.queue.lock() else { return false };
            if q.is_empty() {
                q = match me.wake.wait_timeout(q, Duration::from_millis(20)) {
                    Ok((q, _)) => q,
                    Err(_) => return false,
                };
            }
            q.drain(..).collect()
        };
        for b in batch {
            match ws.send(Message::Binary(b)) {
                Ok(()) => {
                    inner.counters.messages_sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => return timed_out(&e),
            }
        }
    }
}

/// A client's `subscribe` or `unsubscribe`; anything else is ignored.
fn on_request(text: &str, me: &Client, inner: &Inner) {
    let Ok(v) = serde_json::from_str::<Value>(text) else { return };
    match v["op"].as_str() {
        Some("subscribe") => {
            for s in v["subscriptions"].as_array().into_iter().flatten() {
                let (Some(sub), Some(ch)) = (s["id"].as_u64(), s["channelId"].as_u64()) else { continue };
                let Some(ch) = (ch as usize).checked_sub(1).filter(|c| *c < inner.channels.len()) else {
                    continue;
                };
                if let Ok(mut subs) = me.subs.lock() {
                    subs.insert(ch, sub as u32);
                }
                // The channel's newest message at once.
                let latest = inner.latest.lock().ok().and_then(|l| l[ch].clone());
                if let (Some((t, data)), Ok(mut q)) = (latest, me.queue.lock()) {
                    q.push_back(frame(sub as u32, t, &data));
                }
            }
        }
        Some("unsubscribe") => {
            for id in v["subscriptionIds"].as_array().into_iter().flatten().filter_map(Value::as_u64) {
                if let Ok(mut subs) = me.subs.lock() {
                    subs.retain(|_, s| *s as u64 != id);
                }
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tungstenite::client::IntoClientRequest;

    fn channel(topic: &str) -> FoxgloveChannel {
        FoxgloveChannel {
            topic: topic.into(),
            encoding: "cdr".into(),
            schema_name: "spidar/Test".into(),
            schema: "uint8[] data".into(),
            schema_encoding: "ros2msg".into(),
        }
    }

    fn connect(addr: SocketAddr, subprotocol: bool) -> WebSocket<TcpStream> {
        let mut req = format!("ws://{addr}").into_client_request().unwrap();
        if subprotocol {
            req.headers_mut().insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
        }
        let stream = TcpStream::connect(addr).unwrap();
        let (ws, resp) = tungstenite::client(req, stream).unwrap();
        if subprotocol {
            assert_eq!(resp.headers().get("Sec-WebSocket-Protocol").unwrap(), SUBPROTOCOL);
        }
        ws
    }

    /// Reads the server's two text messages and subscribes to channel 1 as subscription 7.
    fn subscribe(ws: &mut WebSocket<TcpStream>) -> Value {
        let info: Value = serde_json::from_str(ws.read().unwrap().to_text().unwrap()).unwrap();
        assert_eq!(info["op"], "serverInfo");
        let adv: Value = serde_json::from_str(ws.read().unwrap().to_text().unwrap()).unwrap();
        ws.send(Message::text(r#"{"op":"subscribe","subscriptions":[{"id":7,"channelId":1}]}"#)).unwrap();
        adv
    }

    fn wait_until(what: &str, f: impl Fn() -> bool) {
        let until = std::time::Instant::now() + Duration::from_secs(30);
        while !f() {
            assert!(std::time::Instant::now() < until, "waited too long for {what}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    #[test]
    fn a_client_that_stops_reading_is_dropped_and_the_others_get_everything() {
        let mut server = FoxgloveServer::start(
            "127.0.0.1:0".parse().unwrap(),
            "test",
            vec![channel("/a"), channel("/b")],
            Duration::from_millis(200),
        )
        .unwrap();
        let addr = server.addr();
        let mut stalled = connect(addr, true);
        let adv = subscribe(&mut stalled);
        assert_eq!(adv["channels"][1]["topic"], "/b");
        assert_eq!(adv["channels"][0]["schemaEncoding"], "ros2msg");
        let mut reader = connect(addr, true);
        subscribe(&mut reader);
        let p = server.publisher();
        wait_until("both subscriptions", || {
            p.inner.clients.lock().unwrap().iter().all(|c| c.subs.lock().unwrap().contains_key(&0))
                && p.counters().clients.load(Ordering::Relaxed) == 2
        });
        const N: u64 = 2000;
        let got = std::thread::spawn(move || {
            let mut n = 0u64;
            while n < N {
                let Message::Binary(b) = reader.read().unwrap() else { continue };
                assert_eq!(b[0], 1, "a message frame");
                assert_eq!(u32::from_le_bytes(b[1..5].try_into().unwrap()), 7, "the subscription");
                assert_eq!(
                    u64::from_le_bytes(b[5..13].try_into().unwrap()),
                    1000 + n,
                    "in order, with its time"
                );
                assert_eq!(b.len(), 13 + 16 * 1024);
                n += 1;
            }
            (n, reader)
        });
        // 32 MB: far more than the stalled client's socket buffers hold.
        let data = vec![0xabu8; 16 * 1024];
        for i in 0..N {
            p.publish(0, 1000 + i, &data);
            p.publish(1, 1000 + i, &data); // nobody subscribed: not sent
        }
        let (n, reader) = got.join().unwrap();
        assert_eq!(n, N, "the reading client got every message");
        wait_until("the stalled client's drop", || p.counters().clients_dropped.load(Ordering::Relaxed) == 1);
        assert_eq!(p.counters().clients.load(Ordering::Relaxed), 1);
        assert_eq!(p.counters().messages_published.load(Ordering::Relaxed), 2 * N);
        drop((stalled, reader));
        server.stop();
    }

    #[test]
    fn a_server_that_stops_sends_what_it_queued_before_it_closes() {
        let mut server = FoxgloveServer::start(
            "127.0.0.1:0".parse().unwrap(),
            "test",
            vec![channel("/a")],
            Duration::from_secs(20),
        )
        .unwrap();
        let mut ws = connect(server.addr(), true);
        subscribe(&mut ws);
        let p = server.publisher();
        wait_until("the subscription", || {
            p.inner.clients.lock().unwrap().iter().all(|c| c.subs.lock().unwrap().contains_key(&0))
        });
        // The client does not read yet: its socket fills, the server's sender waits on it in the
        // middle of a batch, and messages stay queued behind. Publish until some are.
        let data = vec![0x5au8; 64 * 1024];
        let queued =
            || p.inner.clients.lock().unwrap().iter().map(|c| c.queue.lock().unwrap().len()).sum::<usize>();
        let mut n = 0u64;
        let sent = || p.counters().messages_sent.load(Ordering::Relaxed);
        while sent() == 0 || queued() < 256 {
            p.publish(0, n, &data);
            n += 1;
            assert!(n < CLIENT_QUEUE as u64, "the socket never filled");
        }
        // The world ends with messages queued; the client reads from now on.
        let go = Arc::new(AtomicBool::new(false));
        let reader = {
            let go = go.clone();
            std::thread::spawn(move || {
                while !go.load(Ordering::Relaxed) {
                    std::thread::yield_now();
                }
                let mut got = Vec::new();
                loop {
                    match ws.read() {
                        Ok(Message::Binary(b)) => got.push(u64::from_le_bytes(b[5..13].try_into().unwrap())),
                        Ok(Message::Close(_)) | Err(_) => break,
                        Ok(_) => {}
                    }
                }
                got
            })
        };
        p.inner.stop.store(true, Ordering::Relaxed);
        go.store(true, Ordering::Relaxed);
        server.stop();
        let got = reader.join().unwrap();
        assert_eq!(got, (0..n).collect::<Vec<_>>(), "every message published before the end, in order");
    }

    #[test]
    fn a_client_without_the_foxglove_subprotocol_is_refused_and_a_late_one_gets_the_newest_message() {
        let mut server = FoxgloveServer::start(
            "127.0.0.1:0".parse().unwrap(),
            "test",
            vec![channel("/a")],
            Duration::from_secs(1),
        )
        .unwrap();
        let mut plain = connect(server.addr(), false);
        assert!(matches!(plain.read(), Ok(Message::Close(_)) | Err(_)));
        wait_until("the refusal", || server.counters().refused.load(Ordering::Relaxed) == 1);
        server.publish(0, 5, b"old");
        server.publish(0, 9, b"newest");
        let mut late = connect(server.addr(), true);
        subscribe(&mut late);
        let b = loop {
            if let Message::Binary(b) = late.read().unwrap() {
                break b;
            }
        };
        assert_eq!(u64::from_le_bytes(b[5..13].try_into().unwrap()), 9);
        assert_eq!(&b[13..], b"newest");
        server.stop();
    }
}
