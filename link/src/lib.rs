//! The rig-world link: how hand samples reach the world and contact models reach the rig.
//!
//! The rig's loop talks to a [`RigLink`]: once per tick it takes the newest contact model
//! ([`RigLink::poll`]) and sends the tick's hand sample, and every few ticks a [`RigStatus`].
//! Two implementations:
//! - [`channel`]: bounded channels to a world thread in the same process (the virtual clock, the
//!   hardware-in-the-loop tests, bit-identical runs);
//! - [`rig::SocketRigLink`]: datagrams to a world process, over a Unix socket on one host or UDP
//!   to another host, with a handshake, liveness and counters for everything odd that arrives.
//!
//! The world's end of a socket link is [`world::WorldLink`]. Messages travel in the wire form of
//! `spidar_msg::wire`; sockets live in private directories ([`private_dir`]).
//!
//! On the rig's side nothing here blocks, allocates or locks once set up: sends and receives are
//! non-blocking system calls on fixed buffers, counters are atomics.

pub mod channel;
pub mod private_dir;
pub mod rig;
pub mod shim;
pub mod sock;
pub mod world;

use std::net::{SocketAddr, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, AtomicU32, AtomicU64, AtomicU8, AtomicUsize, Ordering};

use spidar_msg::handshake::RefuseCode;
use spidar_msg::{ContactModel, HandSample, RigStatus};

pub use private_dir::PrivateDir;

/// Errors of the link (set-up and handshake; the tick only counts).
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error(
        "'{0}' is not a link address: use unix:PATH (a world on this machine) or udp://HOST:PORT \
         (udp://:PORT means 127.0.0.1)"
    )]
    BadAddress(String),
    #[error("{what} {path} {why}")]
    Unsafe { what: &'static str, path: PathBuf, why: String },
    #[error("{op} {at}: {source}")]
    Io {
        op: &'static str,
        at: String,
        #[source]
        source: std::io::Error,
    },
    #[error("socket path {0} is empty or too long (at most 107 bytes): choose a shorter path")]
    PathTooLong(PathBuf),
    #[error(
        "no world answered at {addr} within {waited_s:.1} s: is `spidar world` running and listening there? \
         (it prints its address when it starts)"
    )]
    NoWorld { addr: String, waited_s: f64 },
    #[error("the world at {addr} refused this rig: {reason}")]
    Refused { addr: String, code: RefuseCode, reason: String },
    #[error(
        "the world at {addr} speaks link protocol {world}, this rig speaks {rig}: run the same spidar \
         version on both sides"
    )]
    Version { addr: String, world: u16, rig: u16 },
}

impl LinkError {
    pub(crate) fn io(
        op: &'static str,
        at: &(impl std::fmt::Debug + ?Sized),
        source: std::io::Error,
    ) -> LinkError {
        LinkError::Io { op, at: format!("{at:?}"), source }
    }
}

/// Where a world listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// A Unix datagram socket on this host.
    Unix(PathBuf),
    /// UDP, for a world on another host (or this one).
    Udp(SocketAddr),
}

impl Endpoint {
    /// `unix:PATH`, `udp://HOST:PORT` (a name is resolved now), `udp://:PORT` (127.0.0.1).
    pub fn parse(s: &str) -> Result<Endpoint, LinkError> {
        let bad = || LinkError::BadAddress(s.to_string());
        if let Some(p) = s.strip_prefix("unix:") {
            if p.is_empty() {
                return Err(bad());
            }
            return Ok(Endpoint::Unix(PathBuf::from(p)));
        }
        let rest = s.strip_prefix("udp://").ok_or_else(bad)?;
        let hostport = if rest.starts_with(':') { format!("127.0.0.1{rest}") } else { rest.to_string() };
        let addr = hostport.to_socket_addrs().map_err(|_| bad())?.next().ok_or_else(bad)?;
        Ok(Endpoint::Udp(addr))
    }

    pub fn unix(path: &Path) -> Endpoint {
        Endpoint::Unix(path.to_path_buf())
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Endpoint::Unix(p) => write!(f, "unix:{}", p.display()),
            Endpoint::Udp(a) => write!(f, "udp://{a}"),
        }
    }
}

impl std::str::FromStr for Endpoint {
    type Err = LinkError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Endpoint::parse(s)
    }
}

/// What became of a sample handed to the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sent {
    /// On its way.
    Queued,
    /// The way was full (the world is not draining): dropped.
    Dropped,
    /// No world to send to (not connected yet, refused, or gone).
    NoPeer,
}

/// The rig's end of the link, used from the tick: nothing here may block, allocate or lock.
pub trait RigLink: Send {
    /// Receives what arrived since the last call and does the link's housekeeping (handshake,
    /// liveness); returns the newest contact model that arrived, if any.
    fn poll(&mut self, now_s: f64) -> Option<ContactModel>;
    /// Sends this tick's hand sample.
    fn send_sample(&mut self, s: &HandSample) -> Sent;
    /// Sends a status summary (a few tens of times a second).
    fn send_status(&mut self, s: &RigStatus);
    /// The rig is stopping: tell the world (best effort).
    fn close(&mut self) {}
    /// The link's counters, when it keeps any beyond the rig's own.
    fn stats(&self) -> Option<&LinkStats> {
        None
    }
}

/// Where a socket link stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum LinkState {
    /// Saying hello; no world has answered yet.
    Connecting = 0,
    /// A world answered and sends models.
    Connected = 1,
    /// The world went silent (killed, crashed, hung, network lost) or said goodbye; hellos go
    /// out again so a new world can take over.
    Lost = 2,
    /// The world refused this rig (see the mailbox for why); hellos go out again, slowly.
    Refused = 3,
}

impl LinkState {
    pub fn from_u8(b: u8) -> LinkState {
        match b {
            1 => LinkState::Connected,
            2 => LinkState::Lost,
            3 => LinkState::Refused,
            _ => LinkState::Connecting,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            LinkState::Connecting => "connecting",
            LinkState::Connected => "connected",
            LinkState::Lost => "world lost",
            LinkState::Refused => "refused",
        }
    }
}

/// Counters of a rig's socket link: written by the tick, read by anyone (atomics, relaxed).
#[derive(Default)]
pub struct LinkStats {
    state: AtomicU8,
    /// Handshakes completed (the first and every reconnection).
    pub connects: AtomicU64,
    /// Worlds seen (a new `world_session`: a restarted or replaced world).
    pub worlds: AtomicU64,
    /// Times the world went silent or said goodbye while connected.
    pub lost: AtomicU64,
    /// Hellos handed to the kernel (not those that found nobody or a full way).
    pub hellos: AtomicU64,
    pub models: AtomicU64,
    pub samples_sent: AtomicU64,
    /// Samples dropped because the way was full.
    pub samples_dropped: AtomicU64,
    /// Sends that found nobody at the world's address.
    pub sends_unanswered: AtomicU64,
    pub statuses_sent: AtomicU64,
    /// Datagrams that did not decode (short, long, bad magic, unknown kind, bad values).
    pub malformed: AtomicU64,
    /// Datagrams of another protocol version (`peer_version` says which).
    pub wrong_version: AtomicU64,
    pub peer_version: AtomicU32,
    /// Datagrams from an address other than the world's.
    pub foreign: AtomicU64,
    /// Valid datagrams that make no sense now (a model before the handshake, a sample, ...).
    pub unexpected: AtomicU64,
    /// Models dropped for a stamp that is not a number, or older than the newest one taken.
    pub bad_stamps: AtomicU64,
    pub out_of_order: AtomicU64,
    /// Models stamped in the rig's future, taken as stamped now.
    pub future_stamps: AtomicU64,
    pub refusals: AtomicU64,
    /// Goodbyes received from the world.
    pub byes: AtomicU64,
    /// The newest handshake answer (a Welcome or a Refuse datagram), for the control side.
    pub handshake: Mailbox,
}

impl LinkStats {
    pub fn state(&self) -> LinkState {
        LinkState::from_u8(self.state.load(Ordering::Relaxed))
    }
    pub(crate) fn set_state(&self, s: LinkState) {
        self.state.store(s as u8, Ordering::Relaxed);
    }
    pub fn get(c: &AtomicU64) -> u64 {
        c.load(Ordering::Relaxed)
    }
    pub(crate) fn add(c: &AtomicU64) {
        c.fetch_add(1, Ordering::Relaxed);
    }

    /// Every counter by name, for a machine-readable summary (`spidar run --json`).
    pub fn counts(&self) -> [(&'static str, u64); 17] {
        let g = |c: &AtomicU64| c.load(Ordering::Relaxed);
        [
            ("connects", g(&self.connects)),
            ("worlds", g(&self.worlds)),
            ("lost", g(&self.lost)),
            ("hellos", g(&self.hellos)),
            ("models", g(&self.models)),
            ("samples_sent", g(&self.samples_sent)),
            ("samples_dropped", g(&self.samples_dropped)),
            ("sends_unanswered", g(&self.sends_unanswered)),
            ("statuses_sent", g(&self.statuses_sent)),
            ("malformed", g(&self.malformed)),
            ("wrong_version", g(&self.wrong_version)),
            ("foreign", g(&self.foreign)),
            ("unexpected", g(&self.unexpected)),
            ("bad_stamps", g(&self.bad_stamps) + g(&self.out_of_order)),
            ("future_stamps", g(&self.future_stamps)),
            ("refusals", g(&self.refusals)),
            ("byes", g(&self.byes)),
        ]
    }

    /// A one-line summary for the end of a run.
    pub fn summary(&self) -> String {
        let g = |c: &AtomicU64| c.load(Ordering::Relaxed);
        format!(
            "{} models received, {} samples sent ({} dropped, {} unanswered), {} connects, {} worlds, lost {} times; \
             odd datagrams: {} malformed, {} wrong version, {} foreign, {} unexpected, {} bad or old stamps, {} future stamps",
            g(&self.models),
            g(&self.samples_sent),
            g(&self.samples_dropped),
            g(&self.sends_unanswered),
            g(&self.connects),
            g(&self.worlds),
            g(&self.lost),
            g(&self.malformed),
            g(&self.wrong_version),
            g(&self.foreign),
            g(&self.unexpected),
            g(&self.bad_stamps) + g(&self.out_of_order),
            g(&self.future_stamps),
        )
    }
}

/// Room for one handshake datagram.
pub const MAILBOX_BYTES: usize = 256;

/// A single-writer, many-reader slot for a small datagram, without locks (a sequence lock over
/// atomics): the tick writes, the control side reads and retries if it raced a write.
pub struct Mailbox {
    seq: AtomicU64,
    len: AtomicUsize,
    bytes: [AtomicU8; MAILBOX_BYTES],
}

impl Default for Mailbox {
    fn default() -> Self {
        Mailbox {
            seq: AtomicU64::new(0),
            len: AtomicUsize::new(0),
            bytes: [const { AtomicU8::new(0) }; MAILBOX_BYTES],
        }
    }
}

impl Mailbox {
    /// Stores `d` (cut to the slot's size). One writer only.
    pub fn write(&self, d: &[u8]) {
        self.seq.fetch_add(1, Ordering::Relaxed);
        fence(Ordering::Release);
        let n = d.len().min(MAILBOX_BYTES);
        for (slot, b) in self.bytes.iter().zip(&d[..n]) {
            slot.store(*b, Ordering::Relaxed);
        }
        self.len.store(n, Ordering::Relaxed);
        self.seq.fetch_add(1, Ordering::Release);
    }

    /// The newest datagram stored and how many writes there have been, or None if none yet (or
    /// a writer kept racing the read).
    pub fn read(&self) -> Option<(u64, Vec<u8>)> {
        for _ in 0..1000 {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 == 0 {
                return None;
            }
            if s1 % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let n = self.len.load(Ordering::Relaxed);
            let v: Vec<u8> = self.bytes[..n].iter().map(|b| b.load(Ordering::Relaxed)).collect();
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return Some((s1 / 2, v));
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_parse_and_print() {
        assert_eq!(Endpoint::parse("unix:/run/x.sock").unwrap(), Endpoint::Unix("/run/x.sock".into()));
        assert_eq!(Endpoint::parse("udp://:7700").unwrap(), Endpoint::Udp("127.0.0.1:7700".parse().unwrap()));
        assert_eq!(Endpoint::parse("udp://10.0.0.2:7700").unwrap().to_string(), "udp://10.0.0.2:7700");
        for bad in ["", "unix:", "tcp://x:1", "udp://nohost", "/run/x.sock"] {
            let e = Endpoint::parse(bad).unwrap_err().to_string();
            assert!(e.contains("unix:PATH") && e.contains("udp://HOST:PORT"), "{bad}: {e}");
        }
    }

    #[test]
    fn the_mailbox_keeps_the_newest_datagram() {
        let m = Mailbox::default();
        assert!(m.read().is_none());
        m.write(b"first");
        m.write(b"second");
        assert_eq!(m.read(), Some((2, b"second".to_vec())));
        m.write(&[7u8; 300]);
        assert_eq!(m.read().unwrap().1.len(), MAILBOX_BYTES);
    }
}
