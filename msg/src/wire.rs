//! The wire encoding of every message that crosses the rig-world link (`docs/link.md`).
//!
//! One message per datagram: a 20-byte header, then the message's fixed-size payload. Everything
//! is little-endian; `f64` travels as its IEEE-754 bits (NaN and infinities pass unchanged: what
//! to do with them is the receiver's business, and the rig's safety phase handles them).
//!
//! ```text
//! offset size field
//!  0      4   magic "SPDR"
//!  4      2   protocol version (PROTOCOL_VERSION)
//!  6      1   kind (Kind)
//!  7      1   flags, 0
//!  8      4   payload length in bytes (u32), fixed per kind
//! 12      8   sequence number (u64): per sender, +1 for every datagram it sends
//! 20      -   payload
//! ```
//!
//! Encoding writes into the caller's buffer and never allocates; decoding reads a datagram into a
//! value and answers every malformed case with a [`WireError`], never a panic. Each message lists
//! its fields in order in one `Field` impl below; the round-trip tests compare every field, so a
//! field added to a message and forgotten here fails them. Change the layout: bump
//! [`PROTOCOL_VERSION`], update `docs/link.md`.

use glam::DVec3;

use crate::handshake::{Bye, Hello, Refuse, RefuseCode, Text, Welcome};
use crate::strings::{Forearm, StringClearance};
use crate::{
    Blow, ContactModel, DisplayInfo, HandContact, HandSample, HandState, Proxy, ProxyId, ProxyShape, RigInfo,
    RigState, RigStatus, HANDS, MAX_PROXIES, STRINGS,
};

pub const MAGIC: [u8; 4] = *b"SPDR";
/// Raised whenever any message's layout changes; both ends must speak the same one.
pub const PROTOCOL_VERSION: u16 = 6;
pub const HEADER_LEN: usize = 20;

/// What a datagram carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Kind {
    Hello = 1,
    Welcome = 2,
    Refuse = 3,
    Bye = 4,
    Sample = 5,
    Model = 6,
    Status = 7,
}

impl Kind {
    pub const ALL: [Kind; 7] =
        [Kind::Hello, Kind::Welcome, Kind::Refuse, Kind::Bye, Kind::Sample, Kind::Model, Kind::Status];

    pub fn from_u8(b: u8) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| *k as u8 == b)
    }

    /// Payload bytes of this kind.
    pub const fn payload_len(self) -> usize {
        match self {
            Kind::Hello => Hello::SIZE,
            Kind::Welcome => Welcome::SIZE,
            Kind::Refuse => Refuse::SIZE,
            Kind::Bye => Bye::SIZE,
            Kind::Sample => HandSample::SIZE,
            Kind::Model => ContactModel::SIZE,
            Kind::Status => RigStatus::SIZE,
        }
    }
}

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// The longest datagram of this protocol: a receive buffer this big holds any valid one (and
/// one byte more tells a too-long datagram from a valid one).
pub const MAX_DATAGRAM: usize = HEADER_LEN
    + max(
        max(max(Hello::SIZE, Welcome::SIZE), max(Refuse::SIZE, Bye::SIZE)),
        max(max(HandSample::SIZE, ContactModel::SIZE), RigStatus::SIZE),
    );

/// Everything that can be wrong with a datagram (or a buffer to encode into). Plain data: making
/// one never allocates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("datagram of {got} bytes is shorter than the {HEADER_LEN}-byte header")]
    Short { got: usize },
    #[error("not a spidar link datagram (bad magic)")]
    BadMagic,
    #[error("the peer speaks link protocol {got}, this side speaks {ours}: run the same spidar version on both sides")]
    Version { got: u16, ours: u16 },
    #[error("unknown message kind {0}")]
    UnknownKind(u8),
    #[error("header flags {0:#04x} set (must be 0)")]
    Flags(u8),
    #[error("{kind:?} payload announced as {got} bytes, this protocol's is {want}")]
    Length { kind: Kind, got: usize, want: usize },
    #[error("{kind:?} datagram truncated: {got} bytes, {want} expected")]
    Truncated { kind: Kind, got: usize, want: usize },
    #[error("{kind:?} datagram too long: {got} bytes, {want} expected")]
    Long { kind: Kind, got: usize, want: usize },
    #[error("invalid {what} in a {kind:?} message")]
    BadValue { kind: Kind, what: &'static str },
    #[error("a {need}-byte buffer is needed to encode, {have} given")]
    BufferTooSmall { need: usize, have: usize },
}

/// The header of a datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    pub version: u16,
    pub kind: Kind,
    pub len: u32,
    pub seq: u64,
}

/// A decoded datagram. Plain data on the stack (the rig decodes without allocating), so the
/// large model is not boxed.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    Hello(Hello),
    Welcome(Welcome),
    Refuse(Refuse),
    Bye(Bye),
    Sample(HandSample),
    Model(ContactModel),
    Status(RigStatus),
}

impl Message {
    pub fn kind(&self) -> Kind {
        match self {
            Message::Hello(_) => Kind::Hello,
            Message::Welcome(_) => Kind::Welcome,
            Message::Refuse(_) => Kind::Refuse,
            Message::Bye(_) => Kind::Bye,
            Message::Sample(_) => Kind::Sample,
            Message::Model(_) => Kind::Model,
            Message::Status(_) => Kind::Status,
        }
    }
}

/// A message that travels alone in a datagram.
pub trait Wire: Field {
    const KIND: Kind;
}

impl Wire for Hello {
    const KIND: Kind = Kind::Hello;
}
impl Wire for Welcome {
    const KIND: Kind = Kind::Welcome;
}
impl Wire for Refuse {
    const KIND: Kind = Kind::Refuse;
}
impl Wire for Bye {
    const KIND: Kind = Kind::Bye;
}
impl Wire for HandSample {
    const KIND: Kind = Kind::Sample;
}
impl Wire for ContactModel {
    const KIND: Kind = Kind::Model;
}
impl Wire for RigStatus {
    const KIND: Kind = Kind::Status;
}

/// Encodes `m` with sequence number `seq` into the front of `buf`; returns the datagram's length.
/// Never allocates.
pub fn encode<M: Wire>(m: &M, seq: u64, buf: &mut [u8]) -> Result<usize, WireError> {
    let need = HEADER_LEN + M::SIZE;
    let Some(out) = buf.get_mut(..need) else {
        return Err(WireError::BufferTooSmall { need, have: buf.len() });
    };
    let mut w = Put { buf: out, at: 0 };
    w.bytes(&MAGIC);
    w.bytes(&PROTOCOL_VERSION.to_le_bytes());
    w.bytes(&[M::KIND as u8, 0]);
    w.bytes(&(M::SIZE as u32).to_le_bytes());
    w.bytes(&seq.to_le_bytes());
    m.put(&mut w);
    Ok(need)
}

/// Reads and checks a datagram's header: the magic, the version, the kind, the flags and that
/// the announced length is this protocol's length for the kind. Does not look at the payload.
pub fn header(d: &[u8]) -> Result<Header, WireError> {
    if d.len() < HEADER_LEN {
        return Err(WireError::Short { got: d.len() });
    }
    let mut r = Get { buf: d, at: 0, kind: Kind::Hello, err: None };
    if r.array::<4>() != MAGIC {
        return Err(WireError::BadMagic);
    }
    let version = u16::from_le_bytes(r.array());
    if version != PROTOCOL_VERSION {
        return Err(WireError::Version { got: version, ours: PROTOCOL_VERSION });
    }
    let [k, flags] = r.array::<2>();
    let kind = Kind::from_u8(k).ok_or(WireError::UnknownKind(k))?;
    if flags != 0 {
        return Err(WireError::Flags(flags));
    }
    let len = u32::from_le_bytes(r.array());
    let seq = u64::from_le_bytes(r.array());
    let want = kind.payload_len();
    if len as usize != want {
        return Err(WireError::Length { kind, got: len as usize, want });
    }
    Ok(Header { version, kind, len, seq })
}

/// Decodes one datagram. Never panics, whatever the bytes.
pub fn decode(d: &[u8]) -> Result<(Header, Message), WireError> {
    let h = header(d)?;
    let want = HEADER_LEN + h.len as usize;
    if d.len() < want {
        return Err(WireError::Truncated { kind: h.kind, got: d.len(), want });
    }
    if d.len() > want {
        return Err(WireError::Long { kind: h.kind, got: d.len(), want });
    }
    let mut r = Get { buf: &d[HEADER_LEN..], at: 0, kind: h.kind, err: None };
    let m = match h.kind {
        Kind::Hello => Message::Hello(Hello::get(&mut r)),
        Kind::Welcome => Message::Welcome(Welcome::get(&mut r)),
        Kind::Refuse => Message::Refuse(Refuse::get(&mut r)),
        Kind::Bye => Message::Bye(Bye::get(&mut r)),
        Kind::Sample => Message::Sample(HandSample::get(&mut r)),
        Kind::Model => Message::Model(ContactModel::get(&mut r)),
        Kind::Status => Message::Status(RigStatus::get(&mut r)),
    };
    match r.err {
        Some(e) => Err(e),
        None => Ok((h, m)),
    }
}

/// Writes fields in order. The buffer was sized from `Field::SIZE`, so writes always fit; one
/// that did not would be dropped (and caught by the size tests), never a panic.
pub struct Put<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Put<'_> {
    fn bytes(&mut self, b: &[u8]) {
        if let Some(d) = self.buf.get_mut(self.at..self.at + b.len()) {
            d.copy_from_slice(b);
        }
        self.at += b.len();
    }
}

/// Reads fields in order. A value that cannot be right (an unknown enum tag, a bool that is not
/// 0 or 1, text that is not UTF-8) is recorded as the decode's error and read as a filler, so
/// reading goes on without branching at every field.
pub struct Get<'a> {
    buf: &'a [u8],
    at: usize,
    kind: Kind,
    err: Option<WireError>,
}

impl Get<'_> {
    fn array<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        if let Some(s) = self.buf.get(self.at..self.at + N) {
            a.copy_from_slice(s);
        }
        self.at += N;
        a
    }
    fn bad(&mut self, what: &'static str) {
        self.err.get_or_insert(WireError::BadValue { kind: self.kind, what });
    }
}

/// A value with a fixed-size wire form.
pub trait Field: Sized {
    /// Bytes on the wire.
    const SIZE: usize;
    fn put(&self, w: &mut Put<'_>);
    fn get(r: &mut Get<'_>) -> Self;
}

macro_rules! le_field {
    ($($t:ty),*) => {$(
        impl Field for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            fn put(&self, w: &mut Put<'_>) {
                w.bytes(&self.to_le_bytes());
            }
            fn get(r: &mut Get<'_>) -> Self {
                <$t>::from_le_bytes(r.array())
            }
        }
    )*};
}
le_field!(u8, u16, u64, f64);

impl Field for bool {
    const SIZE: usize = 1;
    fn put(&self, w: &mut Put<'_>) {
        w.bytes(&[*self as u8]);
    }
    fn get(r: &mut Get<'_>) -> Self {
        match r.array::<1>()[0] {
            0 => false,
            1 => true,
            _ => {
                r.bad("bool (not 0 or 1)");
                false
            }
        }
    }
}

impl Field for DVec3 {
    const SIZE: usize = 24;
    fn put(&self, w: &mut Put<'_>) {
        self.x.put(w);
        self.y.put(w);
        self.z.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        DVec3::new(f64::get(r), f64::get(r), f64::get(r))
    }
}

impl<T: Field, const N: usize> Field for [T; N] {
    const SIZE: usize = T::SIZE * N;
    fn put(&self, w: &mut Put<'_>) {
        for x in self {
            x.put(w);
        }
    }
    fn get(r: &mut Get<'_>) -> Self {
        std::array::from_fn(|_| T::get(r))
    }
}

impl<const N: usize> Field for Text<N> {
    const SIZE: usize = N;
    fn put(&self, w: &mut Put<'_>) {
        w.bytes(self.raw());
    }
    fn get(r: &mut Get<'_>) -> Self {
        let raw = r.array::<N>();
        Text::from_raw(&raw).unwrap_or_else(|| {
            r.bad("text (not zero-padded UTF-8)");
            Text::default()
        })
    }
}

impl Field for ProxyId {
    const SIZE: usize = 4;
    fn put(&self, w: &mut Put<'_>) {
        self.body.put(w);
        self.part.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        ProxyId { body: u16::get(r), part: u16::get(r) }
    }
}

/// Tag byte, then seven f64 slots; a shape with fewer numbers leaves the rest zero.
impl Field for ProxyShape {
    const SIZE: usize = 1 + 7 * 8;
    fn put(&self, w: &mut Put<'_>) {
        let (tag, n): (u8, [f64; 7]) = match *self {
            ProxyShape::Plane { point_m: p, normal: n } => (0, [p.x, p.y, p.z, n.x, n.y, n.z, 0.0]),
            ProxyShape::Sphere { centre_m: c, radius_m } => (1, [c.x, c.y, c.z, radius_m, 0.0, 0.0, 0.0]),
            ProxyShape::Capsule { a_m: a, b_m: b, radius_m } => (2, [a.x, a.y, a.z, b.x, b.y, b.z, radius_m]),
        };
        tag.put(w);
        n.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        let tag = u8::get(r);
        let n = <[f64; 7]>::get(r);
        let v = |i: usize| DVec3::new(n[i], n[i + 1], n[i + 2]);
        let unused_zero = |from: usize| n[from..].iter().all(|x| x.to_bits() == 0);
        match tag {
            0 if unused_zero(6) => ProxyShape::Plane { point_m: v(0), normal: v(3) },
            1 if unused_zero(4) => ProxyShape::Sphere { centre_m: v(0), radius_m: n[3] },
            2 => ProxyShape::Capsule { a_m: v(0), b_m: v(3), radius_m: n[6] },
            _ => {
                r.bad(if tag <= 1 { "proxy shape (unused numbers not zero)" } else { "proxy shape tag" });
                ProxyShape::Sphere { centre_m: DVec3::ZERO, radius_m: 0.0 }
            }
        }
    }
}

impl Field for Proxy {
    const SIZE: usize = ProxyId::SIZE + ProxyShape::SIZE + 8 + 8 + DVec3::SIZE + 1;
    fn put(&self, w: &mut Put<'_>) {
        self.id.put(w);
        self.shape.put(w);
        self.k_n_per_m.put(w);
        self.d_n_s_per_m.put(w);
        self.vel_m_per_s.put(w);
        self.hand_mask.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        Proxy {
            id: ProxyId::get(r),
            shape: ProxyShape::get(r),
            k_n_per_m: f64::get(r),
            d_n_s_per_m: f64::get(r),
            vel_m_per_s: DVec3::get(r),
            hand_mask: u8::get(r),
        }
    }
}

impl Field for HandContact {
    const SIZE: usize = 3 * DVec3::SIZE + 8 + 8;
    fn put(&self, w: &mut Put<'_>) {
        self.force_n.put(w);
        self.normal.put(w);
        self.k_n_per_m.put(w);
        self.at_m.put(w);
        self.source_w.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        HandContact {
            force_n: DVec3::get(r),
            normal: DVec3::get(r),
            k_n_per_m: f64::get(r),
            at_m: DVec3::get(r),
            source_w: f64::get(r),
        }
    }
}

impl Field for Blow {
    const SIZE: usize = 8 + 2 * DVec3::SIZE + 8 + 8 + 1;
    fn put(&self, w: &mut Put<'_>) {
        self.seq.put(w);
        self.point_m.put(w);
        self.dir.put(w);
        self.speed_m_per_s.put(w);
        self.momentum_n_s.put(w);
        self.in_contact.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        Blow {
            seq: u64::get(r),
            point_m: DVec3::get(r),
            dir: DVec3::get(r),
            speed_m_per_s: f64::get(r),
            momentum_n_s: f64::get(r),
            in_contact: bool::get(r),
        }
    }
}

/// All `MAX_PROXIES` slots travel, used or not: the datagram has one size.
impl Field for ContactModel {
    const SIZE: usize = 8
        + 8
        + <[Proxy; MAX_PROXIES]>::SIZE
        + 1
        + <[HandContact; HANDS]>::SIZE
        + <[DVec3; HANDS]>::SIZE
        + Blow::SIZE;
    fn put(&self, w: &mut Put<'_>) {
        self.seq.put(w);
        self.stamp_s.put(w);
        self.proxies.put(w);
        self.proxy_count.put(w);
        self.hand_contacts.put(w);
        self.extra_force_n.put(w);
        self.blow.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        let m = ContactModel {
            seq: u64::get(r),
            stamp_s: f64::get(r),
            proxies: Field::get(r),
            proxy_count: u8::get(r),
            hand_contacts: Field::get(r),
            extra_force_n: Field::get(r),
            blow: Field::get(r),
        };
        if m.proxy_count as usize > MAX_PROXIES {
            r.bad("proxy count (above MAX_PROXIES)");
        }
        m
    }
}

impl Field for HandState {
    const SIZE: usize = 3 * DVec3::SIZE + 1;
    fn put(&self, w: &mut Put<'_>) {
        self.pos_world_m.put(w);
        self.vel_world_m_per_s.put(w);
        self.force_n.put(w);
        self.valid.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        HandState {
            pos_world_m: DVec3::get(r),
            vel_world_m_per_s: DVec3::get(r),
            force_n: DVec3::get(r),
            valid: bool::get(r),
        }
    }
}

impl Field for HandSample {
    const SIZE: usize = 8 + 8 + <[HandState; HANDS]>::SIZE + 8 + 2 * <[DVec3; MAX_PROXIES]>::SIZE;
    fn put(&self, w: &mut Put<'_>) {
        self.tick.put(w);
        self.t_s.put(w);
        self.hands.put(w);
        self.model_seq.put(w);
        self.proxy_impulse_n_s.put(w);
        self.proxy_contact_impulse_n_s.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        HandSample {
            tick: u64::get(r),
            t_s: f64::get(r),
            hands: Field::get(r),
            model_seq: u64::get(r),
            proxy_impulse_n_s: Field::get(r),
            proxy_contact_impulse_n_s: Field::get(r),
        }
    }
}

impl Field for StringClearance {
    const SIZE: usize = 8 + DVec3::SIZE + 3 * 8;
    fn put(&self, w: &mut Put<'_>) {
        self.distance_m.put(w);
        self.forearm.toward_elbow.put(w);
        self.forearm.wrist_m.put(w);
        self.forearm.elbow_m.put(w);
        self.forearm.radius_m.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        StringClearance {
            distance_m: f64::get(r),
            forearm: Forearm {
                toward_elbow: Field::get(r),
                wrist_m: f64::get(r),
                elbow_m: f64::get(r),
                radius_m: f64::get(r),
            },
        }
    }
}

impl Field for DisplayInfo {
    const SIZE: usize = 1 + 3 * DVec3::SIZE + 8 + 1;
    fn put(&self, w: &mut Put<'_>) {
        self.present.put(w);
        self.lower_left_m.put(w);
        self.lower_right_m.put(w);
        self.upper_left_m.put(w);
        self.eye_separation_m.put(w);
        self.stereo.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        DisplayInfo {
            present: bool::get(r),
            lower_left_m: Field::get(r),
            lower_right_m: Field::get(r),
            upper_left_m: Field::get(r),
            eye_separation_m: f64::get(r),
            stereo: u8::get(r),
        }
    }
}

impl Field for RigInfo {
    const SIZE: usize = 8
        + <[[DVec3; STRINGS]; HANDS]>::SIZE
        + <[DVec3; HANDS]>::SIZE
        + 4 * 8 * HANDS
        + DVec3::SIZE
        + DisplayInfo::SIZE
        + StringClearance::SIZE;
    fn put(&self, w: &mut Put<'_>) {
        self.period_s.put(w);
        self.anchors_m.put(w);
        self.home_m.put(w);
        self.tension_min_n.put(w);
        self.tension_max_n.put(w);
        self.force_limit_n.put(w);
        self.grip_radius_m.put(w);
        self.eye_m.put(w);
        self.display.put(w);
        self.clearance.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        RigInfo {
            period_s: f64::get(r),
            anchors_m: Field::get(r),
            home_m: Field::get(r),
            tension_min_n: Field::get(r),
            tension_max_n: Field::get(r),
            force_limit_n: Field::get(r),
            grip_radius_m: Field::get(r),
            eye_m: Field::get(r),
            display: Field::get(r),
            clearance: Field::get(r),
        }
    }
}

impl Field for RigState {
    const SIZE: usize = 1;
    fn put(&self, w: &mut Put<'_>) {
        (*self as u8).put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        match u8::get(r) {
            0 => RigState::Unconfigured,
            1 => RigState::Inactive,
            2 => RigState::Active,
            3 => RigState::Faulted,
            4 => RigState::Stopping,
            _ => {
                r.bad("rig state");
                RigState::Unconfigured
            }
        }
    }
}

impl Field for RigStatus {
    const SIZE: usize = 8 + 8 + 1 + 8 + 8 + <[DVec3; HANDS]>::SIZE + <[[f64; STRINGS]; HANDS]>::SIZE + 5 * 8;
    fn put(&self, w: &mut Put<'_>) {
        self.tick.put(w);
        self.t_s.put(w);
        self.state.put(w);
        self.rate_hz.put(w);
        self.lateness_p99_s.put(w);
        self.force_n.put(w);
        self.tensions_n.put(w);
        self.faults.put(w);
        self.device_errors.put(w);
        self.stale_ticks.put(w);
        self.clamped_ticks.put(w);
        self.misses.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        RigStatus {
            tick: u64::get(r),
            t_s: f64::get(r),
            state: RigState::get(r),
            rate_hz: f64::get(r),
            lateness_p99_s: f64::get(r),
            force_n: Field::get(r),
            tensions_n: Field::get(r),
            faults: u64::get(r),
            device_errors: u64::get(r),
            stale_ticks: u64::get(r),
            clamped_ticks: u64::get(r),
            misses: u64::get(r),
        }
    }
}

impl Field for Hello {
    const SIZE: usize = 8 + 3 + crate::handshake::Name::CAPACITY + RigInfo::SIZE;
    fn put(&self, w: &mut Put<'_>) {
        self.rig_session.put(w);
        self.hands.put(w);
        self.strings.put(w);
        self.max_proxies.put(w);
        self.scene.put(w);
        self.rig.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        Hello {
            rig_session: u64::get(r),
            hands: u8::get(r),
            strings: u8::get(r),
            max_proxies: u8::get(r),
            scene: Field::get(r),
            rig: RigInfo::get(r),
        }
    }
}

impl Field for Welcome {
    const SIZE: usize = 8 + 8 + 3 + 8 + crate::handshake::Name::CAPACITY;
    fn put(&self, w: &mut Put<'_>) {
        self.rig_session.put(w);
        self.world_session.put(w);
        self.hands.put(w);
        self.strings.put(w);
        self.max_proxies.put(w);
        self.step_s.put(w);
        self.scene.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        Welcome {
            rig_session: u64::get(r),
            world_session: u64::get(r),
            hands: u8::get(r),
            strings: u8::get(r),
            max_proxies: u8::get(r),
            step_s: f64::get(r),
            scene: Field::get(r),
        }
    }
}

impl Field for Refuse {
    const SIZE: usize = 8 + 1 + crate::handshake::Reason::CAPACITY;
    fn put(&self, w: &mut Put<'_>) {
        self.rig_session.put(w);
        (self.code as u8).put(w);
        self.reason.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        let rig_session = u64::get(r);
        let code = RefuseCode::from_u8(u8::get(r)).unwrap_or_else(|| {
            r.bad("refusal code");
            RefuseCode::Other
        });
        Refuse { rig_session, code, reason: Field::get(r) }
    }
}

impl Field for Bye {
    const SIZE: usize = 8;
    fn put(&self, w: &mut Put<'_>) {
        self.session.put(w);
    }
    fn get(r: &mut Get<'_>) -> Self {
        Bye { session: u64::get(r) }
    }
}

#[cfg(test)]
#[path = "wire_tests.rs"]
mod tests;
