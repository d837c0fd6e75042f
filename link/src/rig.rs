//! The rig's end of a socket link to a world process (Unix datagram or UDP).
//!
//! Connecting: the rig sends `Hello` (its session, sizes, the scene it asks for, its geometry)
//! every `hello_every_s` until the world answers `Welcome` or `Refuse`. [`SocketRigLink::connect`]
//! does that before the loop starts, so a refusal or a version mismatch is an error the user
//! reads at once; the tick keeps doing it afterwards, so a world that is restarted, replaced or
//! started late is picked up without the rig doing anything else.
//!
//! Liveness: a world that sends nothing for `lost_after_s` (killed, crashed, hung, network down)
//! or says `Bye` is lost: the rig's own staleness fade has already taken the force to zero by
//! then, the state says "world lost", samples stop and hellos go out again (a world that was only
//! slow answers with a model or a welcome and is back). A send that finds nobody at a Unix
//! address (the world process is gone) declares it lost at once.
//!
//! What the tick gets is checked here: only datagrams from the world's address, of this
//! protocol, that decode; a model's stamp must be a number, not older than the newest model
//! taken (UDP may reorder), and not in the rig's future (taken as stamped now, so a wrong clock
//! can never keep a model fresh). Everything else is dropped and counted in [`LinkStats`].
//! Never blocks, allocates or locks after [`SocketRigLink::open`].

use std::sync::Arc;
use std::time::{Duration, Instant};

use spidar_msg::handshake::{Bye, Hello, Name, Welcome};
use spidar_msg::wire::{self, Message, WireError, MAX_DATAGRAM, PROTOCOL_VERSION};
use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus, HANDS, MAX_PROXIES, STRINGS};

use crate::sock::{is_full, is_gone, RawAddr, Sock, Waiter};
use crate::{Endpoint, LinkError, LinkState, LinkStats, RigLink, Sent};

/// Timing of the rig's side.
#[derive(Clone, Debug)]
pub struct RigLinkOptions {
    /// A hello every this often while not connected (ten times slower after a refusal).
    pub hello_every_s: f64,
    /// The world is lost after this long without a datagram from it.
    pub lost_after_s: f64,
    /// Most datagrams read in one poll (bounds the tick's time when flooded).
    pub max_per_poll: usize,
}

impl Default for RigLinkOptions {
    fn default() -> Self {
        RigLinkOptions { hello_every_s: 0.1, lost_after_s: 0.25, max_per_poll: 64 }
    }
}

/// The rig's end of a datagram link.
pub struct SocketRigLink {
    sock: Sock,
    world: RawAddr,
    world_name: String,
    hello: [u8; MAX_DATAGRAM],
    hello_len: usize,
    rx: [u8; MAX_DATAGRAM + 1],
    tx: [u8; MAX_DATAGRAM],
    seq: u64,
    session: u64,
    wanted_scene: Name,
    state: LinkState,
    world_session: u64,
    last_heard_s: f64,
    last_hello_s: f64,
    newest_stamp_s: f64,
    opts: RigLinkOptions,
    stats: Arc<LinkStats>,
}

/// Builds the hello a rig sends: its geometry, the sizes, the scene it asks for (empty: any).
pub fn hello(rig_session: u64, rig: RigInfo, scene: &str) -> Hello {
    Hello {
        rig_session,
        hands: HANDS as u8,
        strings: STRINGS as u8,
        max_proxies: MAX_PROXIES as u8,
        scene: Name::new(scene),
        rig,
    }
}

impl SocketRigLink {
    /// Opens the rig's socket for a world at `world`: for a Unix world, bound at `own_path` (in
    /// a private directory: the world answers there); for UDP, on an ephemeral port of the
    /// local address that reaches the world (127.0.0.1 for a local one).
    pub fn open(
        world: &Endpoint,
        own_path: Option<&std::path::Path>,
        hello: Hello,
        opts: RigLinkOptions,
    ) -> Result<SocketRigLink, LinkError> {
        let (sock, addr) = match world {
            Endpoint::Unix(p) => {
                let own = own_path.ok_or_else(|| {
                    LinkError::BadAddress("a Unix world needs a socket path for the rig".into())
                })?;
                if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                    crate::private_dir::check_socket_dir(dir)?;
                }
                (Sock::bind_unix(own)?, RawAddr::unix(p)?)
            }
            Endpoint::Udp(a) => {
                use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr};
                let local: SocketAddr = match (a.ip().is_loopback(), a.is_ipv4()) {
                    (true, true) => (Ipv4Addr::LOCALHOST, 0).into(),
                    (true, false) => (Ipv6Addr::LOCALHOST, 0).into(),
                    (false, true) => (Ipv4Addr::UNSPECIFIED, 0).into(),
                    (false, false) => (Ipv6Addr::UNSPECIFIED, 0).into(),
                };
                (Sock::bind_udp(local)?, RawAddr::inet(*a))
            }
        };
        let mut link = SocketRigLink {
            sock,
            world: addr,
            world_name: world.to_string(),
            hello: [0; MAX_DATAGRAM],
            hello_len: 0,
            rx: [0; MAX_DATAGRAM + 1],
            tx: [0; MAX_DATAGRAM],
            seq: 0,
            session: hello.rig_session,
            wanted_scene: hello.scene,
            state: LinkState::Connecting,
            world_session: 0,
            last_heard_s: f64::NEG_INFINITY,
            last_hello_s: f64::NEG_INFINITY,
            newest_stamp_s: f64::NEG_INFINITY,
            opts,
            stats: Arc::new(LinkStats::default()),
        };
        link.hello_len =
            wire::encode(&hello, 0, &mut link.hello).map_err(|e| LinkError::BadAddress(e.to_string()))?;
        Ok(link)
    }

    /// The shared counters (for the status line and the summary).
    pub fn shared_stats(&self) -> Arc<LinkStats> {
        self.stats.clone()
    }

    pub fn state(&self) -> LinkState {
        self.state
    }

    /// A second handle on the socket that can wait for a datagram (lockstep runs).
    pub fn waiter(&self) -> std::io::Result<Waiter> {
        self.sock.try_clone_waiter()
    }

    /// Says hello until the world answers, for at most `timeout` (not real-time: before the
    /// loop starts). `rig_now_s` is the rig clock now (hellos are paced by the wall clock here, a
    /// virtual rig clock may stand still). A refusal or a version mismatch is an error that names
    /// both sides.
    pub fn connect(&mut self, timeout: Duration, rig_now_s: f64) -> Result<Welcome, LinkError> {
        let start = Instant::now();
        let version_before = LinkStats::get(&self.stats.wrong_version);
        let refusals_before = LinkStats::get(&self.stats.refusals);
        let mut last_hello: Option<Instant> = None;
        loop {
            if self.state != LinkState::Connected
                && last_hello.is_none_or(|t| t.elapsed() >= Duration::from_millis(50))
            {
                self.send_hello(rig_now_s);
                last_hello = Some(Instant::now());
            }
            let _ = self.poll(rig_now_s);
            match self.state {
                LinkState::Connected => {
                    let (_, d) = self.stats.handshake.read().unwrap_or_default();
                    if let Ok((_, Message::Welcome(w))) = wire::decode(&d) {
                        return Ok(w);
                    }
                }
                LinkState::Refused if LinkStats::get(&self.stats.refusals) > refusals_before => {
                    return Err(self.refusal());
                }
                _ => {}
            }
            if LinkStats::get(&self.stats.wrong_version) > version_before {
                return Err(LinkError::Version {
                    addr: self.world_name.clone(),
                    world: self.stats.peer_version.load(std::sync::atomic::Ordering::Relaxed) as u16,
                    rig: PROTOCOL_VERSION,
                });
            }
            let waited = start.elapsed();
            if waited >= timeout {
                return Err(LinkError::NoWorld {
                    addr: self.world_name.clone(),
                    waited_s: waited.as_secs_f64(),
                });
            }
            self.sock.wait((timeout - waited).min(Duration::from_millis(20)));
        }
    }

    /// The newest refusal as an error (or a generic one).
    pub fn refusal(&self) -> LinkError {
        let (_, d) = self.stats.handshake.read().unwrap_or_default();
        match wire::decode(&d) {
            Ok((_, Message::Refuse(r))) => {
                LinkError::Refused { addr: self.world_name.clone(), code: r.code, reason: r.reason.as_str().to_string() }
            }
            // A welcome this side refused.
            Ok((_, Message::Welcome(w))) if !shape_matches(&w) => LinkError::Refused {
                addr: self.world_name.clone(),
                code: spidar_msg::handshake::RefuseCode::Shape,
                reason: format!(
                    "the world has {} hands, {} strings and {} proxies per model, this rig {HANDS}, {STRINGS} and \
                     {MAX_PROXIES}: build both from the same spidar source",
                    w.hands, w.strings, w.max_proxies
                ),
            },
            Ok((_, Message::Welcome(w))) => LinkError::Refused {
                addr: self.world_name.clone(),
                code: spidar_msg::handshake::RefuseCode::Scene,
                reason: format!(
                    "it runs scene '{}', this rig asked for '{}' (start the world with --scene {} or leave --scene out)",
                    w.scene, self.wanted_scene, self.wanted_scene
                ),
            },
            _ => LinkError::Refused {
                addr: self.world_name.clone(),
                code: spidar_msg::handshake::RefuseCode::Other,
                reason: "no reason given".into(),
            },
        }
    }

    fn send_raw(&mut self, len: usize, hello: bool) -> std::io::Result<()> {
        let d = if hello { &self.hello[..len] } else { &self.tx[..len] };
        self.sock.send_to(d, &self.world)
    }

    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn send_hello(&mut self, now_s: f64) {
        self.last_hello_s = now_s;
        let seq = self.next_seq();
        // The hello was encoded once; only its sequence number changes.
        self.hello[12..20].copy_from_slice(&seq.to_le_bytes());
        match self.send_raw(self.hello_len, true) {
            Ok(()) => LinkStats::add(&self.stats.hellos),
            Err(e) if is_gone(&e) => LinkStats::add(&self.stats.sends_unanswered),
            Err(_) => {}
        }
    }

    fn set_state(&mut self, s: LinkState) {
        self.state = s;
        self.stats.set_state(s);
    }

    fn lose_world(&mut self) {
        if self.state == LinkState::Connected {
            LinkStats::add(&self.stats.lost);
            self.set_state(LinkState::Lost);
        }
    }

    fn on_welcome(&mut self, w: &Welcome, n: usize, now_s: f64) {
        if w.rig_session != self.session {
            LinkStats::add(&self.stats.unexpected);
            return;
        }
        self.stats.handshake.write(&self.rx[..n]);
        if !shape_matches(w) || (!self.wanted_scene.is_empty() && w.scene != self.wanted_scene) {
            // A world that should have refused: refuse it here (the mailbox holds its welcome).
            LinkStats::add(&self.stats.refusals);
            self.set_state(LinkState::Refused);
            return;
        }
        if w.world_session != self.world_session {
            self.world_session = w.world_session;
            LinkStats::add(&self.stats.worlds);
        }
        LinkStats::add(&self.stats.connects);
        self.last_heard_s = now_s;
        self.set_state(LinkState::Connected);
    }

    /// Checks a model's stamp against the rig clock; None drops it (counted).
    fn accept(&mut self, mut m: ContactModel, now_s: f64) -> Option<ContactModel> {
        if m.stamp_s.is_nan() {
            LinkStats::add(&self.stats.bad_stamps);
            return None;
        }
        if m.stamp_s > now_s {
            LinkStats::add(&self.stats.future_stamps);
            m.stamp_s = now_s;
        }
        if m.stamp_s < self.newest_stamp_s {
            LinkStats::add(&self.stats.out_of_order);
            return None;
        }
        self.newest_stamp_s = m.stamp_s;
        Some(m)
    }
}

fn shape_matches(w: &Welcome) -> bool {
    w.hands as usize == HANDS && w.strings as usize == STRINGS && w.max_proxies as usize == MAX_PROXIES
}

impl RigLink for SocketRigLink {
    fn poll(&mut self, now_s: f64) -> Option<ContactModel> {
        let mut newest = None;
        for _ in 0..self.opts.max_per_poll {
            let r = match self.sock.recv(&mut self.rx) {
                Ok(r) => r,
                Err(_) => break, // WouldBlock: nothing more queued (other errors: try next tick)
            };
            if !r.from.same(&self.world) {
                LinkStats::add(&self.stats.foreign);
                continue;
            }
            let n = r.len.min(self.rx.len());
            let decoded =
                if r.truncated { Err(WireError::Short { got: 0 }) } else { wire::decode(&self.rx[..n]) };
            match decoded {
                Err(WireError::Version { got, .. }) => {
                    LinkStats::add(&self.stats.wrong_version);
                    self.stats.peer_version.store(got as u32, std::sync::atomic::Ordering::Relaxed);
                }
                Err(_) => LinkStats::add(&self.stats.malformed),
                Ok((_, Message::Welcome(w))) => self.on_welcome(&w, n, now_s),
                Ok((_, Message::Refuse(f))) if f.rig_session == self.session => {
                    self.stats.handshake.write(&self.rx[..n]);
                    LinkStats::add(&self.stats.refusals);
                    if self.state == LinkState::Connected {
                        LinkStats::add(&self.stats.lost);
                    }
                    self.set_state(LinkState::Refused);
                }
                Ok((_, Message::Bye(_))) if matches!(self.state, LinkState::Connected | LinkState::Lost) => {
                    LinkStats::add(&self.stats.byes);
                    self.lose_world();
                }
                Ok((_, Message::Model(m)))
                    if matches!(self.state, LinkState::Connected | LinkState::Lost) =>
                {
                    self.last_heard_s = now_s;
                    if self.state == LinkState::Lost {
                        // The same world, back from a stall (a new one would have welcomed us).
                        LinkStats::add(&self.stats.connects);
                        self.set_state(LinkState::Connected);
                    }
                    LinkStats::add(&self.stats.models);
                    if let Some(m) = self.accept(m, now_s) {
                        newest = Some(m);
                    }
                }
                Ok(_) => LinkStats::add(&self.stats.unexpected),
            }
        }
        if self.state == LinkState::Connected && now_s - self.last_heard_s > self.opts.lost_after_s {
            self.lose_world();
        }
        if self.state != LinkState::Connected {
            let every = if self.state == LinkState::Refused { 10.0 } else { 1.0 } * self.opts.hello_every_s;
            if now_s - self.last_hello_s >= every {
                self.send_hello(now_s);
            }
        }
        newest
    }

    fn send_sample(&mut self, s: &HandSample) -> Sent {
        // Only to a world that welcomed this rig and is heard from: a lost one (or a new one at
        // its address) gets hellos, not a flood of samples it would drop.
        if self.state != LinkState::Connected {
            return Sent::NoPeer;
        }
        let seq = self.next_seq();
        let Ok(n) = wire::encode(s, seq, &mut self.tx) else { return Sent::Dropped };
        match self.send_raw(n, false) {
            Ok(()) => {
                LinkStats::add(&self.stats.samples_sent);
                Sent::Queued
            }
            Err(e) if is_full(&e) => {
                LinkStats::add(&self.stats.samples_dropped);
                Sent::Dropped
            }
            Err(e) => {
                if is_gone(&e) {
                    LinkStats::add(&self.stats.sends_unanswered);
                    self.lose_world();
                }
                Sent::NoPeer
            }
        }
    }

    fn send_status(&mut self, s: &RigStatus) {
        if self.state != LinkState::Connected {
            return;
        }
        let seq = self.next_seq();
        if let Ok(n) = wire::encode(s, seq, &mut self.tx) {
            if self.send_raw(n, false).is_ok() {
                LinkStats::add(&self.stats.statuses_sent);
            }
        }
    }

    fn close(&mut self) {
        if matches!(self.state, LinkState::Connected | LinkState::Lost) {
            let seq = self.next_seq();
            if let Ok(n) = wire::encode(&Bye { session: self.session }, seq, &mut self.tx) {
                let _ = self.send_raw(n, false);
            }
            // Polled again, the link says hello first (the world paused when it got the bye).
            self.set_state(LinkState::Lost);
        }
    }

    fn stats(&self) -> Option<&LinkStats> {
        Some(&self.stats)
    }
}
