"""The link's wire format: every byte a Python world reads from or writes to the rig.

Why it exists: a world in Python speaks the same datagrams as the Rust world
(``msg/src/wire.rs``, described in ``docs/link.md``): a 20-byte header, then a fixed-size
payload per kind, little-endian, ``f64`` as IEEE-754 bits. This module is the only place that
knows the layout, so a change of the protocol (or a shim that delays or drops datagrams) touches
one file.

What it must never do: accept a datagram the Rust side would refuse. Decoding checks the magic,
the version (read first, so another version is always named), the kind, the flags, the
length, and every value that can be wrong (bools, enum tags, text, the proxy count, unused shape
numbers), and raises :class:`WireError` naming what is wrong; it never returns half a message.
Encoding writes exactly what the Rust side writes, NaN included: what to do with a NaN is the
rig's business (its safety phase drops it and counts it).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple, Union

MAGIC = b"SPDR"
#: Raised on the Rust side whenever a message's layout changes; both ends must speak the same.
PROTOCOL_VERSION = 6
HEADER_LEN = 20
HANDS = 2
STRINGS = 4
MAX_PROXIES = 16
NAME_BYTES = 64
REASON_BYTES = 160

KIND_HELLO = 1
KIND_WELCOME = 2
KIND_REFUSE = 3
KIND_BYE = 4
KIND_SAMPLE = 5
KIND_MODEL = 6
KIND_STATUS = 7

KIND_NAMES = {
    KIND_HELLO: "Hello",
    KIND_WELCOME: "Welcome",
    KIND_REFUSE: "Refuse",
    KIND_BYE: "Bye",
    KIND_SAMPLE: "HandSample",
    KIND_MODEL: "ContactModel",
    KIND_STATUS: "RigStatus",
}

#: Refusal codes (``Refuse.code``).
REFUSE_OTHER = 0
REFUSE_SHAPE = 1
REFUSE_SCENE = 2
REFUSE_BUSY = 3
REFUSE_RIG = 4

#: Rig states (``RigStatus.state``).
RIG_STATES = ("unconfigured", "inactive", "active", "faulted", "stopping")

Vec3 = Tuple[float, float, float]
ZERO: Vec3 = (0.0, 0.0, 0.0)

_HEADER = struct.Struct("<4sHBBIQ")
_HAND_STATE = struct.Struct("<9dB")  # pos, vel, force, valid
_VEC16 = struct.Struct("<48d")
_PROXY = struct.Struct("<HHB7d2d3dB")
_HAND_CONTACT = struct.Struct("<3d3dd3dd")
_BLOW = struct.Struct("<Q3d3dddB")
_RIG_INFO = struct.Struct("<d24d6d2d2d2d2d3d")
_DISPLAY = struct.Struct("<B3d3d3ddB")  # present, lower left, lower right, upper left, eye separation, stereo
_CLEARANCE = struct.Struct("<d3dddd")  # near distance, forearm toward elbow, wrist, elbow, radius
_STATUS = struct.Struct("<QdBdd6d8d5Q")


class WireError(ValueError):
    """A datagram that is not a valid message of this protocol, and why."""

    def __init__(self, what: str, version: Optional[int] = None):
        super().__init__(what)
        #: The peer's protocol version when that is what is wrong (None otherwise).
        self.version = version


# ---------------------------------------------------------------------------------------------
# Messages (world frame, metres, seconds on the rig's clock; see docs/link.md).


@dataclass
class HandState:
    """One hand as the rig measured it on one tick (world frame)."""

    pos_m: Vec3 = ZERO
    vel_m_per_s: Vec3 = ZERO
    #: Force the rig commanded on the user's hand this tick, after safety.
    force_n: Vec3 = ZERO
    #: False when the pose is not trustworthy (not homed, faulted, residual too large).
    valid: bool = False


@dataclass
class HandSample:
    """What the rig sends every tick."""

    tick: int = 0
    #: The rig's clock at the encoder read (s).
    t_s: float = 0.0
    hands: List[HandState] = field(default_factory=lambda: [HandState(), HandState()])
    #: ``seq`` of the model the impulses below were computed against (0: none).
    model_seq: int = 0
    #: Impulse on each proxy of that model this tick (N s, per proxy index, both hands summed):
    #: the reaction of what the user's hands really received through it, after the rig's ramp,
    #: fade, clamp and tension allocation. Apply it to the body the proxy stands for.
    proxy_impulse_n_s: List[Vec3] = field(default_factory=lambda: [ZERO] * MAX_PROXIES)
    #: Impulse of the virtual contact itself, before the rig's clamp and allocation (N s).
    proxy_contact_impulse_n_s: List[Vec3] = field(default_factory=lambda: [ZERO] * MAX_PROXIES)


@dataclass
class Plane:
    """Half-space bounded by the plane through ``point_m`` with outward ``normal``; the solid is
    on the side opposite the normal."""

    point_m: Vec3
    normal: Vec3


@dataclass
class Sphere:
    """Solid ball."""

    centre_m: Vec3
    radius_m: float


@dataclass
class Capsule:
    """Solid capsule: the segment ``a_m``..``b_m`` swept by ``radius_m``."""

    a_m: Vec3
    b_m: Vec3
    radius_m: float


Shape = Union[Plane, Sphere, Capsule]

BOTH_HANDS = 0b11


@dataclass
class Proxy:
    """A contact proxy: a shape, its penalty gains, its velocity (the rig moves the shape by
    ``vel * age`` before using it) and which hands may touch it (bit 0: left, bit 1: right)."""

    shape: Shape
    k_n_per_m: float
    d_n_s_per_m: float = 0.0
    vel_m_per_s: Vec3 = ZERO
    hand_mask: int = BOTH_HANDS
    #: Which body and part the proxy stands for (free for a Python world's own use).
    body: int = 0
    part: int = 0


@dataclass
class HandContact:
    """A contact on one hand as a local model the rig carries along between steps:
    ``force_n + k_n_per_m (n.u)^2 ((at_m - x).u) u``, u the force's direction (docs/link.md).
    All zero: no contact."""

    force_n: Vec3 = ZERO
    normal: Vec3 = ZERO
    k_n_per_m: float = 0.0
    at_m: Vec3 = ZERO
    source_w: float = 0.0


@dataclass
class Blow:
    """A blow landed on the avatar (boxing): the rig renders a push along ``dir`` growing with
    ``momentum_n_s`` while ``in_contact``, and a short decaying burst at impact growing with
    ``speed_m_per_s``. ``seq`` tells a new blow from the same one sent again; 0: no blow yet."""

    seq: int = 0
    point_m: Vec3 = ZERO
    #: Unit direction of the blow (world frame).
    dir: Vec3 = ZERO
    speed_m_per_s: float = 0.0
    momentum_n_s: float = 0.0
    in_contact: bool = False


@dataclass
class ContactModel:
    """What a world sends every step."""

    seq: int = 0
    #: The rig's clock when the geometry is valid (s).
    stamp_s: float = 0.0
    proxies: List[Proxy] = field(default_factory=list)
    hand_contacts: List[HandContact] = field(default_factory=lambda: [HandContact(), HandContact()])
    #: Extra force per hand, added after rendering and held until the next model (world frame).
    extra_force_n: List[Vec3] = field(default_factory=lambda: [ZERO, ZERO])
    #: The newest blow landed on the avatar (a world without one leaves it zero).
    blow: Blow = field(default_factory=Blow)


@dataclass
class RigInfo:
    """The rig's period and geometry (world frame), sent in its hello."""

    period_s: float = 0.001
    anchors_m: List[List[Vec3]] = field(default_factory=lambda: [[ZERO] * STRINGS for _ in range(HANDS)])
    home_m: List[Vec3] = field(default_factory=lambda: [ZERO, ZERO])
    tension_min_n: List[float] = field(default_factory=lambda: [0.0, 0.0])
    tension_max_n: List[float] = field(default_factory=lambda: [0.0, 0.0])
    force_limit_n: List[float] = field(default_factory=lambda: [0.0, 0.0])
    grip_radius_m: List[float] = field(default_factory=lambda: [0.0, 0.0])
    eye_m: Vec3 = ZERO
    #: The rig's screen, if its rig file places one.
    display: "DisplayInfo" = field(default_factory=lambda: DisplayInfo())
    #: When a string counts as near another hand's string or the user's forearm (the rig file's
    #: ``near_strings``).
    clearance: "StringClearance" = field(default_factory=lambda: StringClearance())


@dataclass
class StringClearance:
    """A string closer than ``distance_m`` to another hand's string or to the forearm capsule's
    surface is near. The capsule runs from ``wrist_m`` to ``elbow_m`` from the grip along
    ``toward_elbow`` (the left hand's, world frame; the right hand's mirrored in x)."""

    distance_m: float = 0.01
    toward_elbow: Vec3 = (-0.25, -0.55, 0.8)
    wrist_m: float = 0.08
    elbow_m: float = 0.35
    radius_m: float = 0.045


#: The stereo formats of a rig's screen, by their number on the wire.
STEREO = ("mono", "side-by-side", "top-bottom", "anaglyph")


@dataclass
class DisplayInfo:
    """The rig's screen (world frame): the rectangle the user's-eye view is drawn through from
    ``RigInfo.eye_m``, the eyes' separation and the stereo format (an index into ``STEREO``)."""

    #: False: the rig file places no screen (the rest is zero).
    present: bool = False
    lower_left_m: Vec3 = ZERO
    lower_right_m: Vec3 = ZERO
    upper_left_m: Vec3 = ZERO
    eye_separation_m: float = 0.0
    stereo: int = 0


@dataclass
class RigStatus:
    """The rig's health, every 16 ticks."""

    tick: int = 0
    t_s: float = 0.0
    state: str = "unconfigured"
    rate_hz: float = 0.0
    lateness_p99_s: float = 0.0
    force_n: List[Vec3] = field(default_factory=lambda: [ZERO, ZERO])
    tensions_n: List[List[float]] = field(default_factory=lambda: [[0.0] * STRINGS for _ in range(HANDS)])
    faults: int = 0
    device_errors: int = 0
    stale_ticks: int = 0
    clamped_ticks: int = 0
    misses: int = 0


@dataclass
class Hello:
    rig_session: int = 0
    hands: int = HANDS
    strings: int = STRINGS
    max_proxies: int = MAX_PROXIES
    #: The scene the rig insists on ("": any).
    scene: str = ""
    rig: RigInfo = field(default_factory=RigInfo)


@dataclass
class Welcome:
    rig_session: int = 0
    world_session: int = 0
    hands: int = HANDS
    strings: int = STRINGS
    max_proxies: int = MAX_PROXIES
    step_s: float = 0.003
    scene: str = ""


@dataclass
class Refuse:
    rig_session: int = 0
    code: int = REFUSE_OTHER
    reason: str = ""


@dataclass
class Bye:
    #: The sender's session.
    session: int = 0


Message = Union[Hello, Welcome, Refuse, Bye, HandSample, ContactModel, RigStatus]

_SIZES = {
    KIND_HELLO: 8 + 3 + NAME_BYTES + _RIG_INFO.size + _DISPLAY.size + _CLEARANCE.size,
    KIND_WELCOME: 8 + 8 + 3 + 8 + NAME_BYTES,
    KIND_REFUSE: 8 + 1 + REASON_BYTES,
    KIND_BYE: 8,
    KIND_SAMPLE: 8 + 8 + HANDS * _HAND_STATE.size + 8 + 2 * _VEC16.size,
    KIND_MODEL: 8 + 8 + MAX_PROXIES * _PROXY.size + 1 + HANDS * _HAND_CONTACT.size + HANDS * 24 + _BLOW.size,
    KIND_STATUS: _STATUS.size,
}

#: The longest datagram of this protocol.
MAX_DATAGRAM = HEADER_LEN + max(_SIZES.values())


def payload_len(kind: int) -> int:
    """Payload bytes of a message kind."""
    return _SIZES[kind]


# ---------------------------------------------------------------------------------------------
# Encoding.


def _text(s: str, n: int) -> bytes:
    """UTF-8, cut at a character boundary to fit ``n`` bytes, zero-padded (as the Rust side)."""
    s = s.split("\0", 1)[0]
    b = s.encode("utf-8")
    while len(b) > n:
        s = s[:-1]
        b = s.encode("utf-8")
    return b + bytes(n - len(b))


def _vec(v: Sequence[float]) -> Vec3:
    x, y, z = v
    return (float(x), float(y), float(z))


def _proxy_bytes(p: Proxy) -> bytes:
    s = p.shape
    if isinstance(s, Plane):
        tag, nums = 0, (*_vec(s.point_m), *_vec(s.normal), 0.0)
    elif isinstance(s, Sphere):
        tag, nums = 1, (*_vec(s.centre_m), float(s.radius_m), 0.0, 0.0, 0.0)
    elif isinstance(s, Capsule):
        tag, nums = 2, (*_vec(s.a_m), *_vec(s.b_m), float(s.radius_m))
    else:
        raise TypeError(f"a proxy's shape is a Plane, Sphere or Capsule, not {type(s).__name__}")
    return _PROXY.pack(
        int(p.body) & 0xFFFF,
        int(p.part) & 0xFFFF,
        tag,
        *nums,
        float(p.k_n_per_m),
        float(p.d_n_s_per_m),
        *_vec(p.vel_m_per_s),
        int(p.hand_mask) & 0xFF,
    )


_EMPTY_PROXY = bytes(_PROXY.size)


def _payload(m: Message) -> Tuple[int, bytes]:
    if isinstance(m, ContactModel):
        if len(m.proxies) > MAX_PROXIES:
            raise ValueError(f"a contact model carries at most {MAX_PROXIES} proxies, {len(m.proxies)} given")
        proxies = b"".join(_proxy_bytes(p) for p in m.proxies) + _EMPTY_PROXY * (MAX_PROXIES - len(m.proxies))
        contacts = b"".join(
            _HAND_CONTACT.pack(*_vec(c.force_n), *_vec(c.normal), float(c.k_n_per_m), *_vec(c.at_m), float(c.source_w))
            for c in m.hand_contacts
        )
        extra = b"".join(struct.pack("<3d", *_vec(f)) for f in m.extra_force_n)
        b = m.blow
        blow = _BLOW.pack(
            b.seq, *_vec(b.point_m), *_vec(b.dir), float(b.speed_m_per_s), float(b.momentum_n_s), int(bool(b.in_contact))
        )
        return KIND_MODEL, (
            struct.pack("<Qd", m.seq, float(m.stamp_s)) + proxies + bytes([len(m.proxies)]) + contacts + extra + blow
        )
    if isinstance(m, Welcome):
        return KIND_WELCOME, (
            struct.pack("<QQBBBd", m.rig_session, m.world_session, m.hands, m.strings, m.max_proxies, m.step_s)
            + _text(m.scene, NAME_BYTES)
        )
    if isinstance(m, Refuse):
        return KIND_REFUSE, struct.pack("<QB", m.rig_session, m.code) + _text(m.reason, REASON_BYTES)
    if isinstance(m, Bye):
        return KIND_BYE, struct.pack("<Q", m.session)
    if isinstance(m, HandSample):
        hands = b"".join(
            _HAND_STATE.pack(*_vec(h.pos_m), *_vec(h.vel_m_per_s), *_vec(h.force_n), int(bool(h.valid)))
            for h in m.hands
        )
        flat = lambda vs: _VEC16.pack(*(x for v in vs for x in _vec(v)))  # noqa: E731
        return KIND_SAMPLE, (
            struct.pack("<Qd", m.tick, m.t_s)
            + hands
            + struct.pack("<Q", m.model_seq)
            + flat(m.proxy_impulse_n_s)
            + flat(m.proxy_contact_impulse_n_s)
        )
    if isinstance(m, Hello):
        r = m.rig
        info = _RIG_INFO.pack(
            r.period_s,
            *(x for hand in r.anchors_m for a in hand for x in _vec(a)),
            *(x for h in r.home_m for x in _vec(h)),
            *r.tension_min_n,
            *r.tension_max_n,
            *r.force_limit_n,
            *r.grip_radius_m,
            *_vec(r.eye_m),
        )
        d = r.display
        info += _DISPLAY.pack(
            int(bool(d.present)),
            *_vec(d.lower_left_m),
            *_vec(d.lower_right_m),
            *_vec(d.upper_left_m),
            d.eye_separation_m,
            d.stereo,
        )
        c = r.clearance
        info += _CLEARANCE.pack(c.distance_m, *_vec(c.toward_elbow), c.wrist_m, c.elbow_m, c.radius_m)
        return KIND_HELLO, (
            struct.pack("<QBBB", m.rig_session, m.hands, m.strings, m.max_proxies) + _text(m.scene, NAME_BYTES) + info
        )
    if isinstance(m, RigStatus):
        return KIND_STATUS, _STATUS.pack(
            m.tick,
            m.t_s,
            RIG_STATES.index(m.state),
            m.rate_hz,
            m.lateness_p99_s,
            *(x for f in m.force_n for x in _vec(f)),
            *(x for t in m.tensions_n for x in t),
            m.faults,
            m.device_errors,
            m.stale_ticks,
            m.clamped_ticks,
            m.misses,
        )
    raise TypeError(f"not a link message: {type(m).__name__}")


def encode(m: Message, seq: int, version: int = PROTOCOL_VERSION) -> bytes:
    """One datagram: the header (``seq``: the sender's count of datagrams, +1 each) and the
    message. ``version`` is for tests of a mismatch; leave it alone otherwise."""
    kind, body = _payload(m)
    assert len(body) == _SIZES[kind], (kind, len(body))
    return _HEADER.pack(MAGIC, version, kind, 0, len(body), seq) + body


# ---------------------------------------------------------------------------------------------
# Decoding.


@dataclass
class Header:
    version: int
    kind: int
    length: int
    seq: int


def header(d: bytes) -> Header:
    """Reads and checks a datagram's header (not its payload)."""
    if len(d) < HEADER_LEN:
        raise WireError(f"datagram of {len(d)} bytes is shorter than the {HEADER_LEN}-byte header")
    magic, version, kind, flags, length, seq = _HEADER.unpack_from(d)
    if magic != MAGIC:
        raise WireError("not a spidar link datagram (bad magic)")
    if version != PROTOCOL_VERSION:
        raise WireError(
            f"the peer speaks link protocol {version}, this side speaks {PROTOCOL_VERSION}: "
            "run the same spidar version on both sides",
            version=version,
        )
    if kind not in _SIZES:
        raise WireError(f"unknown message kind {kind}")
    if flags != 0:
        raise WireError(f"header flags {flags:#04x} set (must be 0)")
    if length != _SIZES[kind]:
        raise WireError(f"{KIND_NAMES[kind]} payload announced as {length} bytes, this protocol's is {_SIZES[kind]}")
    return Header(version, kind, length, seq)


def _read_text(raw: bytes, kind: int) -> str:
    end = raw.find(b"\0")
    end = len(raw) if end < 0 else end
    if any(raw[end:]):
        raise WireError(f"invalid text (not zero-padded UTF-8) in a {KIND_NAMES[kind]} message")
    try:
        return raw[:end].decode("utf-8")
    except UnicodeDecodeError:
        raise WireError(f"invalid text (not zero-padded UTF-8) in a {KIND_NAMES[kind]} message") from None


def _bool(b: int, kind: int) -> bool:
    if b not in (0, 1):
        raise WireError(f"invalid bool (not 0 or 1) in a {KIND_NAMES[kind]} message")
    return b == 1


def _triples(xs: Sequence[float]) -> List[Vec3]:
    return [(xs[i], xs[i + 1], xs[i + 2]) for i in range(0, len(xs), 3)]


def _decode_proxy(buf: bytes, at: int) -> Proxy:
    v = _PROXY.unpack_from(buf, at)
    body, part, tag, n = v[0], v[1], v[2], v[3:10]
    k, d, vel, mask = v[10], v[11], (v[12], v[13], v[14]), v[15]
    zero = lambda i: all(struct.pack("<d", x) == bytes(8) for x in n[i:])  # noqa: E731
    if tag == 0 and zero(6):
        shape: Shape = Plane((n[0], n[1], n[2]), (n[3], n[4], n[5]))
    elif tag == 1 and zero(4):
        shape = Sphere((n[0], n[1], n[2]), n[3])
    elif tag == 2:
        shape = Capsule((n[0], n[1], n[2]), (n[3], n[4], n[5]), n[6])
    else:
        what = "proxy shape (unused numbers not zero)" if tag <= 1 else "proxy shape tag"
        raise WireError(f"invalid {what} in a ContactModel message")
    return Proxy(shape, k, d, vel, mask, body, part)


def decode(d: bytes) -> Tuple[Header, Message]:
    """Decodes one datagram; raises :class:`WireError` for anything the Rust side refuses."""
    h = header(d)
    want = HEADER_LEN + h.length
    if len(d) < want:
        raise WireError(f"{KIND_NAMES[h.kind]} datagram truncated: {len(d)} bytes, {want} expected")
    if len(d) > want:
        raise WireError(f"{KIND_NAMES[h.kind]} datagram too long: {len(d)} bytes, {want} expected")
    p = memoryview(d)[HEADER_LEN:].tobytes()
    k = h.kind
    if k == KIND_SAMPLE:
        tick, t_s = struct.unpack_from("<Qd", p, 0)
        hands = []
        for i in range(HANDS):
            v = _HAND_STATE.unpack_from(p, 16 + i * _HAND_STATE.size)
            hands.append(HandState((v[0], v[1], v[2]), (v[3], v[4], v[5]), (v[6], v[7], v[8]), _bool(v[9], k)))
        at = 16 + HANDS * _HAND_STATE.size
        (model_seq,) = struct.unpack_from("<Q", p, at)
        imp = _triples(_VEC16.unpack_from(p, at + 8))
        contact = _triples(_VEC16.unpack_from(p, at + 8 + _VEC16.size))
        return h, HandSample(tick, t_s, hands, model_seq, imp, contact)
    if k == KIND_HELLO:
        session, hands_n, strings, max_proxies = struct.unpack_from("<QBBB", p, 0)
        scene = _read_text(p[11 : 11 + NAME_BYTES], k)
        v = _RIG_INFO.unpack_from(p, 11 + NAME_BYTES)
        anchors = _triples(v[1:25])
        info = RigInfo(
            period_s=v[0],
            anchors_m=[anchors[0:4], anchors[4:8]],
            home_m=_triples(v[25:31]),
            tension_min_n=list(v[31:33]),
            tension_max_n=list(v[33:35]),
            force_limit_n=list(v[35:37]),
            grip_radius_m=list(v[37:39]),
            eye_m=(v[39], v[40], v[41]),
        )
        d = _DISPLAY.unpack_from(p, 11 + NAME_BYTES + _RIG_INFO.size)
        info.display = DisplayInfo(_bool(d[0], k), (d[1], d[2], d[3]), (d[4], d[5], d[6]), (d[7], d[8], d[9]), d[10], d[11])
        c = _CLEARANCE.unpack_from(p, 11 + NAME_BYTES + _RIG_INFO.size + _DISPLAY.size)
        info.clearance = StringClearance(c[0], (c[1], c[2], c[3]), c[4], c[5], c[6])
        return h, Hello(session, hands_n, strings, max_proxies, scene, info)
    if k == KIND_STATUS:
        v = _STATUS.unpack_from(p, 0)
        if v[2] >= len(RIG_STATES):
            raise WireError("invalid rig state in a RigStatus message")
        return h, RigStatus(
            v[0], v[1], RIG_STATES[v[2]], v[3], v[4], _triples(v[5:11]), [list(v[11:15]), list(v[15:19])], *v[19:24]
        )
    if k == KIND_BYE:
        return h, Bye(struct.unpack_from("<Q", p, 0)[0])
    if k == KIND_MODEL:
        seq, stamp = struct.unpack_from("<Qd", p, 0)
        count = p[16 + MAX_PROXIES * _PROXY.size]
        if count > MAX_PROXIES:
            raise WireError("invalid proxy count (above MAX_PROXIES) in a ContactModel message")
        all_proxies = [_decode_proxy(p, 16 + i * _PROXY.size) for i in range(MAX_PROXIES)]
        at = 16 + MAX_PROXIES * _PROXY.size + 1
        contacts = []
        for i in range(HANDS):
            v = _HAND_CONTACT.unpack_from(p, at + i * _HAND_CONTACT.size)
            contacts.append(HandContact((v[0], v[1], v[2]), (v[3], v[4], v[5]), v[6], (v[7], v[8], v[9]), v[10]))
        extra = _triples(struct.unpack_from("<6d", p, at + HANDS * _HAND_CONTACT.size))
        v = _BLOW.unpack_from(p, at + HANDS * _HAND_CONTACT.size + HANDS * 24)
        blow = Blow(v[0], (v[1], v[2], v[3]), (v[4], v[5], v[6]), v[7], v[8], _bool(v[9], k))
        return h, ContactModel(seq, stamp, all_proxies[:count], contacts, extra, blow)
    if k == KIND_WELCOME:
        rs, ws, hands_n, strings, max_proxies, step_s = struct.unpack_from("<QQBBBd", p, 0)
        return h, Welcome(rs, ws, hands_n, strings, max_proxies, step_s, _read_text(p[27 : 27 + NAME_BYTES], k))
    if k == KIND_REFUSE:
        rs, code = struct.unpack_from("<QB", p, 0)
        if code > REFUSE_RIG:
            raise WireError("invalid refusal code in a Refuse message")
        return h, Refuse(rs, code, _read_text(p[9 : 9 + REASON_BYTES], k))
    raise WireError(f"unknown message kind {k}")  # unreachable: header() checked the kind


def finite(v: Sequence[float]) -> bool:
    """True when every number of ``v`` is finite."""
    return all(math.isfinite(x) for x in v)
