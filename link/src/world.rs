//! The world's end of a socket link: listen, take one rig at a time (or one per seat, for a
//! scene of several people: [`WorldLink::bind_seats`]), drain its samples, send it contact
//! models. Not real-time (the world process may allocate and block); it just must not
//! lose a sample it could have had.
//!
//! - A rig is served after a valid `Hello`: same protocol version, same sizes, a usable period,
//!   and the scene this world runs (or none asked for). Anything else is answered with `Refuse`
//!   naming both sides; a rig of another protocol version gets a `Refuse` in this version, so
//!   its header tells it which one this world speaks.
//! - While every seat is taken, hellos from other addresses are refused (busy), and any other
//!   datagram not from a served rig is dropped and counted. A rig takes the first free seat; a
//!   rig saying hello again from its address keeps its seat.
//! - [`WorldLink::drain`] reads every queued datagram (the world calls it at the start of each
//!   step, so no sample is lost to a slow step); samples lost on the way show as gaps in their
//!   tick numbers and are counted. Each sample comes with its kernel arrival time, from which
//!   [`rig_time_now`] puts the world's steps on the rig's clock.
//! - A rig that says `Bye`, sends nothing for `rig_lost_after`, or whose socket is gone, is lost:
//!   the world pauses until a rig connects.

use std::time::{Duration, Instant};

use spidar_msg::handshake::{Bye, Hello, Name, Reason, Refuse, RefuseCode, Welcome};
use spidar_msg::wire::{self, Message, WireError, MAX_DATAGRAM, PROTOCOL_VERSION};
use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus, HANDS, MAX_PROXIES, STRINGS};

use crate::sock::{is_full, is_gone, realtime_ns, RawAddr, Sock};
use crate::{Endpoint, LinkError};

/// What a world offers a rig.
#[derive(Clone, Debug)]
pub struct WorldOffer {
    /// The scene's name as rigs ask for it (the `--scene` argument).
    pub scene: String,
    pub step_s: f64,
    /// A rig is lost after this long without a datagram from it.
    pub rig_lost_after: Duration,
}

/// The rig being served.
#[derive(Clone, Debug)]
pub struct RigPeer {
    pub addr: RawAddr,
    pub session: u64,
    pub info: RigInfo,
    /// The newest status it sent.
    pub status: Option<RigStatus>,
    last_heard: Instant,
    last_seq: u64,
    last_tick: Option<u64>,
}

/// Counts of the world's end.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WorldStats {
    /// Rigs served (connections, reconnections included).
    pub connections: u64,
    pub samples: u64,
    /// Samples that never arrived (gaps in their tick numbers).
    pub samples_lost: u64,
    /// Samples that arrived twice or after a newer one (dropped).
    pub samples_out_of_order: u64,
    pub statuses: u64,
    pub models_sent: u64,
    /// Models dropped because the rig's queue was full.
    pub models_dropped: u64,
    pub malformed: u64,
    pub wrong_version: u64,
    /// Datagrams from an address other than the rig's.
    pub foreign: u64,
    /// Valid datagrams that make no sense here (a model, a welcome, ...).
    pub unexpected: u64,
    pub refusals: u64,
}

/// A sample and the CLOCK_REALTIME nanoseconds of its arrival.
#[derive(Clone, Copy, Debug)]
pub struct Arrived {
    pub sample: HandSample,
    pub arrived_ns: i64,
    /// The seat of the rig that sent it (0 for a world of one seat).
    pub seat: usize,
}

/// What happened on the link, for the world to say.
#[derive(Clone, Debug, PartialEq)]
pub enum WorldEvent {
    /// A rig is served; `again` when it is the same rig session as before (it had lost us).
    Connected {
        rig: String,
        session: u64,
        again: bool,
        /// The seat it took (0 for a world of one seat).
        seat: usize,
    },
    Refused {
        rig: String,
        reason: String,
    },
    WrongVersion {
        rig: String,
        theirs: u16,
    },
    /// The rig said goodbye.
    Left {
        rig: String,
        seat: usize,
    },
    /// The rig went silent (or its socket is gone).
    Lost {
        rig: String,
        silent_s: f64,
        seat: usize,
    },
}

/// The rig's clock now, from the newest sample: its time plus how long ago it arrived (both
/// CLOCK_REALTIME). Short of the rig's true time by the sample's trip (tens of microseconds),
/// so a model stamped with it looks that much older to the rig, never younger.
pub fn rig_time_now(sample_t_s: f64, arrived_ns: i64, now_ns: i64) -> f64 {
    let since = now_ns.saturating_sub(arrived_ns).clamp(0, 10_000_000_000);
    sample_t_s + since as f64 * 1e-9
}

pub struct WorldLink {
    sock: Sock,
    offer: WorldOffer,
    world_session: u64,
    /// The rig served at each seat.
    peers: Vec<Option<RigPeer>>,
    /// The last session served at each seat, to tell a reconnection from a new rig.
    last_session: Vec<Option<u64>>,
    /// Say each refusal reason once per rig, not at every hello.
    last_refusal: Option<(u64, String)>,
    last_wrong_version: Option<u16>,
    rx: Vec<u8>,
    tx: Vec<u8>,
    seq: u64,
    stats: WorldStats,
    listening: Endpoint,
}

impl WorldLink {
    /// Listens at `listen` (UDP port 0: any free port; [`WorldLink::listening`] says which).
    pub fn bind(listen: &Endpoint, offer: WorldOffer) -> Result<WorldLink, LinkError> {
        Self::bind_seats(listen, offer, 1)
    }

    /// Listens at `listen` for up to `seats` rigs at once (at least one), each served as if it
    /// were alone: its own handshake, liveness, sample counts and models.
    pub fn bind_seats(listen: &Endpoint, offer: WorldOffer, seats: usize) -> Result<WorldLink, LinkError> {
        let seats = seats.max(1);
        let sock = match listen {
            Endpoint::Unix(p) => Sock::bind_unix(p)?,
            Endpoint::Udp(a) => Sock::bind_udp(*a)?,
        };
        sock.enable_timestamps().map_err(|e| LinkError::io("asking for arrival times on", listen, e))?;
        // A few seconds of samples, so a world that stalls loses none (best effort).
        sock.grow_receive_buffer(8 << 20);
        let listening = match (listen, sock.local_udp()) {
            (Endpoint::Udp(_), Some(a)) => Endpoint::Udp(a),
            _ => listen.clone(),
        };
        Ok(WorldLink {
            sock,
            offer,
            world_session: crate::private_dir::random_u64(),
            peers: vec![None; seats],
            last_session: vec![None; seats],
            last_refusal: None,
            last_wrong_version: None,
            rx: vec![0; MAX_DATAGRAM + 1],
            tx: vec![0; MAX_DATAGRAM],
            seq: 0,
            stats: WorldStats::default(),
            listening,
        })
    }

    /// The address rigs connect to.
    pub fn listening(&self) -> &Endpoint {
        &self.listening
    }

    /// The rig at the first seat (the only one of a world of one seat).
    pub fn peer(&self) -> Option<&RigPeer> {
        self.peers[0].as_ref()
    }

    /// The rig at `seat`, if one is served there.
    pub fn peer_at(&self, seat: usize) -> Option<&RigPeer> {
        self.peers.get(seat).and_then(|p| p.as_ref())
    }

    pub fn seats(&self) -> usize {
        self.peers.len()
    }

    /// The seat of the rig at `from`, if it is served.
    fn seat_of(&self, from: &RawAddr) -> Option<usize> {
        self.peers.iter().position(|p| p.as_ref().is_some_and(|p| p.addr.same(from)))
    }

    pub fn stats(&self) -> &WorldStats {
        &self.stats
    }

    pub fn world_session(&self) -> u64 {
        self.world_session
    }

    /// Waits until a datagram is queued or `timeout` passes.
    pub fn wait(&self, timeout: Duration) -> bool {
        self.sock.wait(timeout)
    }

    fn send<M: wire::Wire>(&mut self, m: &M, to: &RawAddr) -> std::io::Result<()> {
        self.seq += 1;
        let n = wire::encode(m, self.seq, &mut self.tx).map_err(std::io::Error::other)?;
        self.sock.send_to(&self.tx[..n], to)
    }

    fn refuse(
        &mut self,
        to: &RawAddr,
        session: u64,
        code: RefuseCode,
        reason: String,
        events: &mut Vec<WorldEvent>,
    ) {
        self.stats.refusals += 1;
        let _ = self.send(&Refuse { rig_session: session, code, reason: Reason::new(&reason) }, to);
        let key = (session, reason.clone());
        if self.last_refusal.as_ref() != Some(&key) {
            events.push(WorldEvent::Refused { rig: to.describe(), reason });
            self.last_refusal = Some(key);
        }
    }

    /// Why this world cannot serve `h`, if it cannot.
    fn check_hello(&self, h: &Hello) -> Option<(RefuseCode, String)> {
        if (h.hands as usize, h.strings as usize, h.max_proxies as usize) != (HANDS, STRINGS, MAX_PROXIES) {
            return Some((
                RefuseCode::Shape,
                format!(
                    "the rig has {} hands, {} strings and {} proxies per model, this world {HANDS}, {STRINGS} and \
                     {MAX_PROXIES}: build both from the same spidar source",
                    h.hands, h.strings, h.max_proxies
                ),
            ));
        }
        if !h.scene.is_empty() && h.scene != Name::new(&self.offer.scene) {
            return Some((
                RefuseCode::Scene,
                format!(
                    "this world runs scene '{}', the rig asked for '{}' (start a world with --scene {} or leave \
                     --scene out of the rig's command)",
                    self.offer.scene, h.scene, h.scene
                ),
            ));
        }
        let p = h.rig.period_s;
        if !(p.is_finite() && p > 0.0 && p <= 0.1) {
            return Some((RefuseCode::Rig, format!("the rig's period {p} s is not between 0 and 0.1 s")));
        }
        None
    }

    fn on_hello(&mut self, h: Hello, from: RawAddr, events: &mut Vec<WorldEvent>) {
        let Some(seat) = self.seat_of(&from).or_else(|| self.peers.iter().position(|p| p.is_none())) else {
            let served: Vec<String> = self.peers.iter().flatten().map(|p| p.addr.describe()).collect();
            let reason = format!(
                "this world serves the rig{} at {}: stop {} or start another world",
                if served.len() > 1 { "s" } else { "" },
                served.join(" and "),
                if served.len() > 1 { "one of them" } else { "that rig" },
            );
            return self.refuse(&from, h.rig_session, RefuseCode::Busy, reason, events);
        };
        if let Some((code, reason)) = self.check_hello(&h) {
            self.peers[seat] = None;
            return self.refuse(&from, h.rig_session, code, reason, events);
        }
        let welcome = Welcome {
            rig_session: h.rig_session,
            world_session: self.world_session,
            hands: HANDS as u8,
            strings: STRINGS as u8,
            max_proxies: MAX_PROXIES as u8,
            step_s: self.offer.step_s,
            scene: Name::new(&self.offer.scene),
        };
        let _ = self.send(&welcome, &from);
        let again = self.last_session[seat] == Some(h.rig_session);
        let same_peer = self.peers[seat].as_ref().is_some_and(|p| p.session == h.rig_session);
        self.stats.connections += 1;
        self.last_session[seat] = Some(h.rig_session);
        self.last_refusal = None;
        let (last_seq, last_tick, status) = match (&self.peers[seat], same_peer) {
            (Some(p), true) => (p.last_seq, p.last_tick, p.status),
            _ => (0, None, None),
        };
        self.peers[seat] = Some(RigPeer {
            addr: from,
            session: h.rig_session,
            info: h.rig,
            status,
            last_heard: Instant::now(),
            last_seq,
            last_tick,
        });
        events.push(WorldEvent::Connected { rig: from.describe(), session: h.rig_session, again, seat });
    }

    /// Reads every queued datagram: samples of the served rig go to `samples` (in order, with
    /// their arrival times), what happened to `events`. Then checks that the rig is alive.
    pub fn drain(&mut self, samples: &mut Vec<Arrived>, events: &mut Vec<WorldEvent>) {
        while let Ok(r) = self.sock.recv(&mut self.rx) {
            let arrived_ns = r.arrived_ns.unwrap_or_else(realtime_ns);
            let seat = self.seat_of(&r.from);
            let n = r.len.min(self.rx.len());
            let decoded =
                if r.truncated { Err(WireError::Short { got: 0 }) } else { wire::decode(&self.rx[..n]) };
            match decoded {
                Ok((_, Message::Hello(h))) => self.on_hello(h, r.from, events),
                Err(WireError::Version { got, .. }) => {
                    self.stats.wrong_version += 1;
                    // Answer in this version: its header tells the rig which one this world speaks.
                    let reason = format!("this world speaks link protocol {PROTOCOL_VERSION}, the rig {got}");
                    let _ = self.send(
                        &Refuse { rig_session: 0, code: RefuseCode::Other, reason: Reason::new(&reason) },
                        &r.from,
                    );
                    if self.last_wrong_version != Some(got) {
                        self.last_wrong_version = Some(got);
                        events.push(WorldEvent::WrongVersion { rig: r.from.describe(), theirs: got });
                    }
                }
                _ if seat.is_none() => self.stats.foreign += 1,
                Err(_) => self.stats.malformed += 1,
                Ok((h, Message::Sample(s))) => {
                    let Some(seat) = seat else { continue };
                    let Some(p) = self.peers[seat].as_mut() else { continue };
                    p.last_heard = Instant::now();
                    if h.seq <= p.last_seq || p.last_tick.is_some_and(|t| s.tick <= t) {
                        self.stats.samples_out_of_order += 1;
                        continue;
                    }
                    if let Some(t) = p.last_tick {
                        self.stats.samples_lost += s.tick - t - 1;
                    }
                    p.last_seq = h.seq;
                    p.last_tick = Some(s.tick);
                    self.stats.samples += 1;
                    samples.push(Arrived { sample: s, arrived_ns, seat });
                }
                Ok((_, Message::Status(st))) => {
                    if let Some(p) = seat.and_then(|i| self.peers[i].as_mut()) {
                        p.last_heard = Instant::now();
                        p.status = Some(st);
                        self.stats.statuses += 1;
                    }
                }
                Ok((_, Message::Bye(b))) => {
                    let i = seat.unwrap_or(0);
                    match self.peers[i].take() {
                        Some(p) if p.session == b.session => {
                            events.push(WorldEvent::Left { rig: p.addr.describe(), seat: i })
                        }
                        other => {
                            self.peers[i] = other;
                            self.stats.unexpected += 1;
                        }
                    }
                }
                Ok(_) => self.stats.unexpected += 1,
            }
        }
        for (seat, slot) in self.peers.iter_mut().enumerate() {
            let Some(p) = slot else { continue };
            let silent = p.last_heard.elapsed();
            if silent > self.offer.rig_lost_after {
                events.push(WorldEvent::Lost {
                    rig: p.addr.describe(),
                    silent_s: silent.as_secs_f64(),
                    seat,
                });
                *slot = None;
            }
        }
    }

    /// Sends a model to the served rig; false if there is none or it could not take it.
    pub fn send_model(&mut self, m: &ContactModel, events: &mut Vec<WorldEvent>) -> bool {
        self.send_model_to(0, m, events)
    }

    /// Sends a model to the rig at `seat`; false if there is none or it could not take it.
    pub fn send_model_to(&mut self, seat: usize, m: &ContactModel, events: &mut Vec<WorldEvent>) -> bool {
        let Some(to) = self.peer_at(seat).map(|p| p.addr) else { return false };
        match self.send(m, &to) {
            Ok(()) => {
                self.stats.models_sent += 1;
                true
            }
            Err(e) if is_full(&e) => {
                self.stats.models_dropped += 1;
                false
            }
            Err(e) => {
                if is_gone(&e) {
                    // The rig's socket is gone: its process ended.
                    let silent_s =
                        self.peers[seat].take().map_or(0.0, |p| p.last_heard.elapsed().as_secs_f64());
                    events.push(WorldEvent::Lost { rig: to.describe(), silent_s, seat });
                }
                false
            }
        }
    }

    /// Says goodbye to the served rigs (the world is ending).
    pub fn close(&mut self) {
        for seat in 0..self.peers.len() {
            if let Some(p) = self.peers[seat].take() {
                let _ = self.send(&Bye { session: self.world_session }, &p.addr);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rig_time_is_the_newest_sample_plus_the_time_since_it_arrived() {
        assert_eq!(rig_time_now(2.5, 1_000_000_000, 1_004_000_000), 2.5 + 0.004);
        // A clock that stepped back never makes the rig's time go backwards, nor far ahead.
        assert_eq!(rig_time_now(2.5, 1_000_000_000, 999_000_000), 2.5);
        assert_eq!(rig_time_now(2.5, 0, i64::MAX), 12.5);
    }
}
