//! The socket link end to end on this host: handshakes, refusals that name both sides, models and
//! samples both ways, liveness, and every kind of odd datagram counted and dropped.
//!
//! Times given to the rig's end are a test clock (seconds), so liveness is checked without
//! waiting; only the world's "rig lost" uses the wall clock, with a short limit.

use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Duration;

use spidar_link::rig::{hello, RigLinkOptions, SocketRigLink};
use spidar_link::world::{Arrived, WorldEvent, WorldLink, WorldOffer};
use spidar_link::{Endpoint, LinkError, LinkState, LinkStats, PrivateDir, RigLink, Sent};
use spidar_msg::handshake::{RefuseCode, Welcome};
use spidar_msg::wire::{self, MAX_DATAGRAM};
use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus, HANDS, MAX_PROXIES, STRINGS};

const WAIT: Duration = Duration::from_secs(5);

fn offer(scene: &str) -> WorldOffer {
    WorldOffer { scene: scene.into(), step_s: 0.003, rig_lost_after: Duration::from_millis(300) }
}

fn rig_info() -> RigInfo {
    RigInfo { period_s: 0.001, ..Default::default() }
}

fn rig_for(world: &Endpoint, dir: &Path, scene: &str) -> SocketRigLink {
    SocketRigLink::open(
        world,
        Some(&dir.join("rig.sock")),
        hello(77, rig_info(), scene),
        RigLinkOptions::default(),
    )
    .unwrap()
}

/// Drains the world's end until something happens (a hello answered, a rig gone).
fn serve_handshake(world: &mut WorldLink) -> Vec<WorldEvent> {
    let mut events = Vec::new();
    let mut samples = Vec::new();
    for _ in 0..500 {
        world.wait(Duration::from_millis(10));
        world.drain(&mut samples, &mut events);
        if !events.is_empty() {
            break;
        }
    }
    events
}

/// Connects `rig` to `world` (the world answering on another thread). Returns the welcome.
fn connect(
    rig: &mut SocketRigLink,
    world: WorldLink,
) -> (Result<Welcome, LinkError>, WorldLink, Vec<WorldEvent>) {
    let h = std::thread::spawn(move || {
        let mut world = world;
        let ev = serve_handshake(&mut world);
        (world, ev)
    });
    let r = rig.connect(WAIT, 0.0);
    let (world, ev) = h.join().unwrap();
    (r, world, ev)
}

fn drain_until(world: &mut WorldLink, n: usize) -> (Vec<Arrived>, Vec<WorldEvent>) {
    let (mut s, mut e) = (Vec::new(), Vec::new());
    for _ in 0..500 {
        world.wait(Duration::from_millis(10));
        world.drain(&mut s, &mut e);
        if s.len() >= n {
            break;
        }
    }
    (s, e)
}

fn poll_until(rig: &mut SocketRigLink, now_s: f64) -> Option<ContactModel> {
    for _ in 0..500 {
        if let Some(m) = rig.poll(now_s) {
            return Some(m);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    None
}

fn models_both_ways(world_at: Endpoint, dir: &Path) {
    let world = WorldLink::bind(&world_at, offer("walls")).unwrap();
    let listening = world.listening().clone();
    let mut rig = rig_for(&listening, dir, "walls");
    let (w, mut world, ev) = connect(&mut rig, world);
    let w = w.unwrap();
    assert_eq!(w.scene.as_str(), "walls");
    assert_eq!(w.world_session, world.world_session());
    assert!(matches!(&ev[..], [WorldEvent::Connected { session: 77, again: false, .. }]), "{ev:?}");
    assert_eq!(world.peer().unwrap().info, rig_info(), "the rig's geometry reached the world");

    for tick in 0..5 {
        let s = HandSample { tick, t_s: 0.001 * tick as f64, ..Default::default() };
        assert_eq!(rig.send_sample(&s), Sent::Queued);
    }
    rig.send_status(&RigStatus { tick: 4, rate_hz: 1000.0, ..Default::default() });
    let (got, _) = drain_until(&mut world, 5);
    assert_eq!(got.iter().map(|a| a.sample.tick).collect::<Vec<_>>(), [0, 1, 2, 3, 4]);
    assert!(got.windows(2).all(|w| w[0].arrived_ns <= w[1].arrived_ns), "arrival times in order");
    let mut e = Vec::new();
    for seq in 1..=3 {
        assert!(world.send_model(&ContactModel { seq, stamp_s: 0.004, ..Default::default() }, &mut e));
    }
    let m = poll_until(&mut rig, 0.005).expect("a model arrives");
    // All three were queued by the time the first was read, or the rest follow: the newest wins.
    let newest = if m.seq == 3 { m } else { poll_until(&mut rig, 0.005).map_or(m, |n| n) };
    assert!(newest.seq >= m.seq);
    assert_eq!(world.peer().unwrap().status.map(|s| s.rate_hz), Some(1000.0));
    assert_eq!(LinkStats::get(&rig.stats().unwrap().malformed), 0);
    assert_eq!(world.stats().samples_lost, 0);
}

#[test]
fn a_rig_and_a_world_shake_hands_and_exchange_over_a_unix_socket() {
    let d = PrivateDir::for_process().unwrap();
    models_both_ways(Endpoint::unix(&d.join("world.sock")), d.path());
}

#[test]
fn the_same_exchange_runs_over_udp_on_localhost() {
    let d = PrivateDir::for_process().unwrap();
    models_both_ways(Endpoint::parse("udp://:0").unwrap(), d.path());
}

#[test]
fn a_rig_asking_for_another_scene_is_refused_with_both_named() {
    let d = PrivateDir::for_process().unwrap();
    let world = WorldLink::bind(&Endpoint::unix(&d.join("w.sock")), offer("walls")).unwrap();
    let mut rig = rig_for(world.listening(), d.path(), "crowd");
    let (r, _world, ev) = connect(&mut rig, world);
    let e = r.unwrap_err();
    let LinkError::Refused { code, ref reason, .. } = e else { panic!("{e}") };
    assert_eq!(code, RefuseCode::Scene);
    assert!(reason.contains("'walls'") && reason.contains("'crowd'"), "{reason}");
    assert!(matches!(&ev[..], [WorldEvent::Refused { .. }]), "{ev:?}");
    assert_eq!(rig.state(), LinkState::Refused);
    assert_eq!(
        rig.send_sample(&HandSample::default()),
        Sent::NoPeer,
        "nothing is sent to a world that refused"
    );
}

/// A fake world: a plain socket at the world's address that speaks the wire format by hand.
struct FakeWorld {
    sock: UnixDatagram,
    rig_path: std::path::PathBuf,
}

impl FakeWorld {
    fn at(dir: &Path) -> (FakeWorld, Endpoint) {
        let p = dir.join("fake.sock");
        let sock = UnixDatagram::bind(&p).unwrap();
        sock.set_read_timeout(Some(WAIT)).unwrap();
        (FakeWorld { sock, rig_path: dir.join("rig.sock") }, Endpoint::unix(&p))
    }
    fn recv(&self) -> wire::Message {
        let mut b = vec![0u8; MAX_DATAGRAM];
        let n = self.sock.recv(&mut b).unwrap();
        wire::decode(&b[..n]).unwrap().1
    }
    fn send_raw(&self, d: &[u8]) {
        self.sock.send_to(d, &self.rig_path).unwrap();
    }
    fn send<M: wire::Wire>(&self, m: &M) {
        let mut b = vec![0u8; MAX_DATAGRAM];
        let n = wire::encode(m, 1, &mut b).unwrap();
        self.send_raw(&b[..n]);
    }
    fn welcome(&self, world_session: u64) {
        self.send(&Welcome {
            rig_session: 77,
            world_session,
            hands: HANDS as u8,
            strings: STRINGS as u8,
            max_proxies: MAX_PROXIES as u8,
            step_s: 0.003,
            scene: Default::default(),
        });
    }
}

#[test]
fn a_world_of_another_protocol_version_is_named_with_both_versions() {
    let d = PrivateDir::for_process().unwrap();
    let (fake, at) = FakeWorld::at(d.path());
    let mut rig = rig_for(&at, d.path(), "");
    let h = std::thread::spawn(move || {
        assert!(matches!(fake.recv(), wire::Message::Hello(_)));
        let mut b = vec![0u8; MAX_DATAGRAM];
        let n = wire::encode(&spidar_msg::handshake::Bye { session: 1 }, 1, &mut b).unwrap();
        b[4..6].copy_from_slice(&7u16.to_le_bytes()); // protocol 7
        fake.send_raw(&b[..n]);
    });
    let e = rig.connect(WAIT, 0.0).unwrap_err();
    h.join().unwrap();
    assert!(matches!(e, LinkError::Version { world: 7, rig: wire::PROTOCOL_VERSION, .. }), "{e}");
    let text = e.to_string();
    let ours = format!("this rig speaks {}", wire::PROTOCOL_VERSION);
    assert!(text.contains("protocol 7") && text.contains(&ours), "{text}");
}

#[test]
fn a_world_learns_a_rig_of_another_version_and_answers_in_its_own() {
    let d = PrivateDir::for_process().unwrap();
    let mut world = WorldLink::bind(&Endpoint::unix(&d.join("w.sock")), offer("walls")).unwrap();
    let rig = UnixDatagram::bind(d.join("old-rig.sock")).unwrap();
    rig.set_read_timeout(Some(WAIT)).unwrap();
    let mut b = vec![0u8; MAX_DATAGRAM];
    let n = wire::encode(&hello(5, rig_info(), ""), 1, &mut b).unwrap();
    // A version other than ours (an older rig).
    let theirs = wire::PROTOCOL_VERSION - 1;
    b[4..6].copy_from_slice(&theirs.to_le_bytes());
    rig.send_to(&b[..n], d.join("w.sock")).unwrap();
    let ev = serve_handshake(&mut world);
    assert!(matches!(&ev[..], [WorldEvent::WrongVersion { theirs: t, .. }] if *t == theirs), "{ev:?}");
    let n = rig.recv(&mut b).unwrap();
    assert_eq!(wire::header(&b[..n]).unwrap().version, wire::PROTOCOL_VERSION);
    assert!(world.peer().is_none());
}

#[test]
fn odd_datagrams_from_a_world_are_counted_and_change_nothing() {
    let d = PrivateDir::for_process().unwrap();
    let (fake, at) = FakeWorld::at(d.path());
    let mut rig = rig_for(&at, d.path(), "");
    let _ = rig.poll(0.0); // hello
    assert!(matches!(fake.recv(), wire::Message::Hello(_)));
    // A model before the welcome is unexpected.
    fake.send(&ContactModel { seq: 1, stamp_s: 0.0, ..Default::default() });
    fake.welcome(9);
    std::thread::sleep(Duration::from_millis(20));
    assert!(rig.poll(0.01).is_none());
    assert_eq!(rig.state(), LinkState::Connected);
    let st = rig.shared_stats();
    assert_eq!(LinkStats::get(&st.unexpected), 1);

    let good = {
        let mut b = vec![0u8; MAX_DATAGRAM];
        let n =
            wire::encode(&ContactModel { seq: 2, stamp_s: 0.01, ..Default::default() }, 2, &mut b).unwrap();
        b.truncate(n);
        b
    };
    fake.send_raw(&good[..good.len() - 1]); // truncated
    fake.send_raw(&good[..10]); // shorter than a header
    let mut long = good.clone();
    long.push(0);
    fake.send_raw(&long);
    let mut magic = good.clone();
    magic[0] = b'X';
    fake.send_raw(&magic);
    let mut kind = good.clone();
    kind[6] = 42;
    fake.send_raw(&kind);
    let mut version = good.clone();
    let other = wire::PROTOCOL_VERSION + 1;
    version[4..6].copy_from_slice(&other.to_le_bytes());
    fake.send_raw(&version);
    fake.send(&ContactModel { seq: 3, stamp_s: f64::NAN, ..Default::default() }); // no time
    fake.send(&HandSample::default()); // a sample, to the rig
                                       // A stranger on the same host sends a perfectly good model.
    let stranger = UnixDatagram::bind(d.join("stranger.sock")).unwrap();
    stranger.send_to(&good, d.join("rig.sock")).unwrap();
    std::thread::sleep(Duration::from_millis(20));
    assert!(rig.poll(0.02).is_none(), "nothing odd becomes a model");
    assert_eq!(LinkStats::get(&st.malformed), 5, "truncated, short, long, magic, kind");
    assert_eq!(LinkStats::get(&st.wrong_version), 1);
    assert_eq!(st.peer_version.load(Ordering::Relaxed), u32::from(other));
    assert_eq!(LinkStats::get(&st.bad_stamps), 1);
    assert_eq!(LinkStats::get(&st.unexpected), 2);
    assert_eq!(LinkStats::get(&st.foreign), 1);

    // Stamps: in the future -> now; older than the newest taken -> dropped.
    fake.send(&ContactModel { seq: 4, stamp_s: 1e300, ..Default::default() });
    let m = poll_until(&mut rig, 0.03).unwrap();
    assert_eq!((m.seq, m.stamp_s), (4, 0.03));
    assert_eq!(LinkStats::get(&st.future_stamps), 1);
    fake.send(&ContactModel { seq: 5, stamp_s: 0.029, ..Default::default() });
    std::thread::sleep(Duration::from_millis(20));
    assert!(rig.poll(0.031).is_none());
    assert_eq!(LinkStats::get(&st.out_of_order), 1);
    assert_eq!(rig.state(), LinkState::Connected, "odd datagrams do not disconnect");
}

#[test]
fn a_silent_world_is_lost_and_a_new_one_at_the_same_address_takes_over() {
    let d = PrivateDir::for_process().unwrap();
    let (fake, at) = FakeWorld::at(d.path());
    let mut rig = rig_for(&at, d.path(), "");
    let _ = rig.poll(0.0);
    assert!(matches!(fake.recv(), wire::Message::Hello(_)));
    fake.welcome(1);
    fake.send(&ContactModel { seq: 1, stamp_s: 0.0, ..Default::default() });
    assert!(poll_until(&mut rig, 0.001).is_some());
    let st = rig.shared_stats();
    // Quiet for less than the limit: still connected; past it: lost, and hellos go out again.
    assert!(rig.poll(0.2).is_none());
    assert_eq!(rig.state(), LinkState::Connected);
    let hellos = LinkStats::get(&st.hellos);
    assert!(rig.poll(0.3).is_none());
    assert_eq!(rig.state(), LinkState::Lost);
    assert_eq!(st.state(), LinkState::Lost);
    assert_eq!(LinkStats::get(&st.lost), 1);
    assert_eq!(LinkStats::get(&st.hellos), hellos + 1);
    assert!(matches!(fake.recv(), wire::Message::Hello(_)));
    let _ = rig.poll(0.35);
    assert_eq!(LinkStats::get(&st.hellos), hellos + 1, "one hello per 100 ms");

    // The world process is gone; another starts at the same path.
    drop(fake);
    std::fs::remove_file(d.join("fake.sock")).unwrap(); // as a new world replaces a stale socket
    let (fake2, _) = FakeWorld::at(d.path());
    let _ = rig.poll(0.41);
    assert!(matches!(fake2.recv(), wire::Message::Hello(_)));
    fake2.welcome(2);
    fake2.send(&ContactModel { seq: 1, stamp_s: 0.40, ..Default::default() });
    let m = poll_until(&mut rig, 0.42).expect("the new world's model is taken");
    assert_eq!(m.seq, 1, "a new world's sequence starts again and is accepted");
    assert_eq!(rig.state(), LinkState::Connected);
    assert_eq!(LinkStats::get(&st.worlds), 2);
    assert_eq!(LinkStats::get(&st.connects), 2);
}

#[test]
fn a_killed_world_process_is_noticed_at_the_first_send() {
    let d = PrivateDir::for_process().unwrap();
    let (fake, at) = FakeWorld::at(d.path());
    let mut rig = rig_for(&at, d.path(), "");
    let _ = rig.poll(0.0);
    let _ = fake.recv();
    fake.welcome(1);
    std::thread::sleep(Duration::from_millis(20));
    let _ = rig.poll(0.001);
    assert_eq!(rig.state(), LinkState::Connected);
    drop(fake); // the socket closes (its file stays, as after kill -9)
    assert_eq!(rig.send_sample(&HandSample::default()), Sent::NoPeer);
    assert_eq!(rig.state(), LinkState::Lost);
}

#[test]
fn a_world_pauses_when_its_rig_leaves_or_goes_silent_and_refuses_a_second_rig() {
    let d = PrivateDir::for_process().unwrap();
    let world = WorldLink::bind(&Endpoint::unix(&d.join("w.sock")), offer("walls")).unwrap();
    let mut rig = rig_for(world.listening(), d.path(), "");
    let (r, mut world, _) = connect(&mut rig, world);
    r.unwrap();
    // Samples with a gap: ticks 0, 1, 4 -> two lost.
    for tick in [0u64, 1, 4] {
        rig.send_sample(&HandSample { tick, ..Default::default() });
    }
    let (s, _) = drain_until(&mut world, 3);
    assert_eq!(s.len(), 3);
    assert_eq!(world.stats().samples_lost, 2);

    // A second rig is refused while the first is served.
    let mut other = SocketRigLink::open(
        world.listening(),
        Some(&d.join("rig2.sock")),
        hello(78, rig_info(), ""),
        RigLinkOptions::default(),
    )
    .unwrap();
    let h = std::thread::spawn(move || other.connect(Duration::from_secs(5), 0.0).map(|_| ()));
    let ev = serve_handshake(&mut world);
    let e = h.join().unwrap().unwrap_err();
    assert!(matches!(e, LinkError::Refused { code: RefuseCode::Busy, .. }), "{e}");
    assert!(ev.iter().any(|e| matches!(e, WorldEvent::Refused { .. })), "{ev:?}");
    assert_eq!(world.peer().map(|p| p.session), Some(77));

    // The rig stops: goodbye, and the world pauses.
    rig.close();
    let ev = serve_handshake(&mut world);
    assert!(matches!(&ev[..], [WorldEvent::Left { .. }]), "{ev:?}");
    assert!(world.peer().is_none());

    // It comes back (same session: a reconnection), then goes silent: lost after the limit.
    let _ = rig.poll(10.0);
    let ev = serve_handshake(&mut world);
    assert!(matches!(&ev[..], [WorldEvent::Connected { again: true, .. }]), "{ev:?}");
    std::thread::sleep(Duration::from_millis(400));
    let (mut s, mut ev) = (Vec::new(), Vec::new());
    world.drain(&mut s, &mut ev);
    assert!(matches!(&ev[..], [WorldEvent::Lost { .. }]), "{ev:?}");
    assert!(world.peer().is_none());
}

#[test]
fn a_planted_symlink_or_a_live_socket_is_never_taken_over() {
    let d = PrivateDir::for_process().unwrap();
    let target = d.join("elsewhere");
    std::fs::write(&target, b"precious").unwrap();
    std::os::unix::fs::symlink(&target, d.join("w.sock")).unwrap();
    let e = WorldLink::bind(&Endpoint::unix(&d.join("w.sock")), offer("walls")).err().unwrap().to_string();
    assert!(e.contains("symbolic link"), "{e}");
    assert_eq!(std::fs::read(&target).unwrap(), b"precious");
    let _live = WorldLink::bind(&Endpoint::unix(&d.join("live.sock")), offer("walls")).unwrap();
    let e = WorldLink::bind(&Endpoint::unix(&d.join("live.sock")), offer("walls")).err().unwrap().to_string();
    assert!(e.contains("in use by another process"), "{e}");
    // A stale one (its process gone) is replaced.
    drop(UnixDatagram::bind(d.join("stale.sock")).unwrap());
    assert!(WorldLink::bind(&Endpoint::unix(&d.join("stale.sock")), offer("walls")).is_ok());
    // A socket in a directory others can write to is refused, on either side.
    let shared = d.join("shared");
    std::fs::create_dir(&shared).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o777)).unwrap();
    let e =
        WorldLink::bind(&Endpoint::unix(&shared.join("w.sock")), offer("walls")).err().unwrap().to_string();
    assert!(e.contains("written by group or others"), "{e}");
    let e = SocketRigLink::open(
        &Endpoint::unix(&shared.join("w.sock")),
        Some(&d.join("rig.sock")),
        hello(1, rig_info(), ""),
        RigLinkOptions::default(),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("written by group or others"), "{e}");
}

#[test]
fn a_model_is_stamped_with_the_rigs_time_however_long_the_world_held_the_sample() {
    use spidar_link::sock::realtime_ns;
    use spidar_link::world::rig_time_now;
    use std::time::Instant;
    let d = PrivateDir::for_process().unwrap();
    let world = WorldLink::bind(&Endpoint::unix(&d.join("w.sock")), offer("walls")).unwrap();
    let mut rig = rig_for(world.listening(), d.path(), "");
    let (r, mut world, _) = connect(&mut rig, world);
    r.unwrap();
    // The rig's clock reads 7.0 s as it sends (a clock of its own: not the world's).
    let rig_t0 = 7.0;
    let sent = Instant::now();
    rig.send_sample(&HandSample { tick: 7000, t_s: rig_t0, ..Default::default() });
    // The world is slow to drain: 50 ms.
    std::thread::sleep(Duration::from_millis(50));
    let (s, _) = drain_until(&mut world, 1);
    let stamp = rig_time_now(s[0].sample.t_s, s[0].arrived_ns, realtime_ns());
    let mut e = Vec::new();
    world.send_model(&ContactModel { seq: 1, stamp_s: stamp, ..Default::default() }, &mut e);
    let m = poll_until(&mut rig, rig_t0 + sent.elapsed().as_secs_f64()).expect("the model");
    let rig_now = rig_t0 + sent.elapsed().as_secs_f64();
    // The stamp counts the time the world held the sample ...
    assert!(m.stamp_s - rig_t0 >= 0.050, "stamped {} s after the sample", m.stamp_s - rig_t0);
    // ... and is never in the rig's future: the age the rig sees is real and small.
    let age = rig_now - m.stamp_s;
    assert!(age >= 0.0, "a model from the future: age {age}");
    assert_eq!(LinkStats::get(&rig.stats().unwrap().future_stamps), 0);
}

/// A world of two seats (`spidar world --scene spar`): two rigs each take a seat, a third is
/// refused naming both, each rig's samples come tagged with its seat and each gets its own
/// models; a rig that leaves frees its seat for the next.
#[test]
fn a_world_of_two_seats_serves_two_rigs_apart_and_refuses_a_third() {
    let world =
        WorldLink::bind_seats(&Endpoint::Udp("127.0.0.1:0".parse().unwrap()), offer("spar"), 2).unwrap();
    let at = world.listening().clone();
    let open = |session: u64| {
        SocketRigLink::open(&at, None, hello(session, rig_info(), ""), RigLinkOptions::default()).unwrap()
    };
    let (mut a, mut b, mut c) = (open(1), open(2), open(3));
    let (r, world, ev) = connect(&mut a, world);
    r.unwrap();
    assert!(matches!(&ev[..], [WorldEvent::Connected { session: 1, seat: 0, .. }]), "{ev:?}");
    let (r, world, ev) = connect(&mut b, world);
    r.unwrap();
    assert!(matches!(&ev[..], [WorldEvent::Connected { session: 2, seat: 1, .. }]), "{ev:?}");
    let (r, mut world, ev) = connect(&mut c, world);
    let e = r.unwrap_err().to_string();
    assert!(matches!(&ev[..], [WorldEvent::Refused { .. }]), "{ev:?}");
    assert!(e.contains("serves the rigs at udp://127.0.0.1:") && e.contains(" and "), "{e}");

    for tick in 0..3 {
        a.send_sample(&HandSample { tick, ..Default::default() });
        b.send_sample(&HandSample { tick: 100 + tick, ..Default::default() });
    }
    let (got, _) = drain_until(&mut world, 6);
    let of = |seat: usize| got.iter().filter(|g| g.seat == seat).map(|g| g.sample.tick).collect::<Vec<_>>();
    assert_eq!((of(0), of(1)), (vec![0, 1, 2], vec![100, 101, 102]));
    assert_eq!(world.stats().samples_lost, 0, "each seat's ticks are counted apart");
    let mut e = Vec::new();
    assert!(world.send_model_to(0, &ContactModel { seq: 10, stamp_s: 0.001, ..Default::default() }, &mut e));
    assert!(world.send_model_to(1, &ContactModel { seq: 20, stamp_s: 0.001, ..Default::default() }, &mut e));
    assert_eq!(poll_until(&mut a, 0.002).map(|m| m.seq), Some(10));
    assert_eq!(poll_until(&mut b, 0.002).map(|m| m.seq), Some(20));

    a.close();
    let ev = serve_handshake(&mut world);
    assert!(matches!(&ev[..], [WorldEvent::Left { seat: 0, .. }]), "{ev:?}");
    assert!(world.peer_at(0).is_none() && world.peer_at(1).is_some());
    let (r, _world, ev) = connect(&mut c, world);
    r.unwrap();
    assert!(matches!(&ev[..], [WorldEvent::Connected { session: 3, seat: 0, .. }]), "{ev:?}");
}
