"""The wire format of the Python client against the link's specification (docs/link.md) and
the bytes the Rust side pins (msg/src/wire_tests.rs): a datagram written here is the datagram
the Rust side writes, and everything the Rust side refuses is refused here, naming what."""

import math
import struct

import pytest

from spidar import wire
from spidar.wire import WireError


def test_a_goodbye_is_the_byte_string_the_link_document_pins():
    d = wire.encode(wire.Bye(0x0123456789ABCDEF), 42)
    assert d.hex(" ") == (
        "53 50 44 52 06 00 04 00 08 00 00 00 2a 00 00 00 00 00 00 00 ef cd ab 89 67 45 23 01"
    )


def test_every_kind_has_the_payload_length_of_the_link_document():
    assert {wire.KIND_NAMES[k]: wire.payload_len(k) for k in wire.KIND_NAMES} == {
        "Hello": 549, "Welcome": 91, "Refuse": 169, "Bye": 8, "HandSample": 938, "ContactModel": 1946,
        "RigStatus": 185,
    }
    assert wire.encode(wire.HandSample(), 1)[:12].hex(" ") == f"53 50 44 52 {wire.PROTOCOL_VERSION:02x} 00 05 00 aa 03 00 00"


def _sample():
    s = wire.HandSample(tick=7, t_s=0.007, model_seq=3)
    s.hands[1] = wire.HandState((0.1, 1.2, -0.3), (1.0, -2.0, 0.5), (0.0, 0.0, 3.5), True)
    s.proxy_impulse_n_s[2] = (1e-3, -2e-3, math.inf)
    s.proxy_contact_impulse_n_s[15] = (0.5, 0.25, -0.125)
    return s


def _model():
    return wire.ContactModel(
        seq=9,
        stamp_s=1.5,
        proxies=[
            wire.Proxy(wire.Plane((0, 1.1, -0.3), (0, 0, 1)), 2000.0, 5.0, body=0, part=1),
            wire.Proxy(wire.Sphere((0.1, 1.2, -0.2), 0.08), 1000.0, 5.0, (0.0, 0.1, 0.0), 0b01, 1, 0),
            wire.Proxy(wire.Capsule((0, 1, 0), (0, 1.2, 0), 0.05), 500.0, 1.0, hand_mask=0b10, body=2, part=3),
        ],
        hand_contacts=[wire.HandContact((0, 0, 2.0), (0, 0, 1), 800.0, (0.1, 1.0, -0.2), 0.3), wire.HandContact()],
        extra_force_n=[(0.5, 0.0, 0.0), (0.0, -1.0, 0.0)],
        blow=wire.Blow(3, (0.0, 1.5, -0.1), (0.0, 0.0, 1.0), 4.5, 4.1, True),
    )


@pytest.mark.parametrize(
    "message",
    [
        _sample(),
        _model(),
        wire.Hello(rig_session=5, scene="walls", rig=wire.RigInfo(period_s=0.001, eye_m=(0, 1.6, 0.1))),
        wire.Hello(
            rig_session=6,
            rig=wire.RigInfo(
                eye_m=(0, 1.6, 0.1),
                display=wire.DisplayInfo(True, (-0.8, 0.5, -1.0), (0.8, 0.5, -1.0), (-0.8, 1.4, -1.0), 0.064, 1),
                clearance=wire.StringClearance(0.02, (-0.2, -0.5, 0.9), 0.07, 0.3, 0.05),
            ),
        ),
        wire.Welcome(1, 2, 2, 4, 16, 0.003, "python wall"),
        wire.Refuse(3, wire.REFUSE_SCENE, "this world runs scene 'a', the rig asked for 'b'"),
        wire.Bye(11),
        wire.RigStatus(tick=16, t_s=0.016, state="active", rate_hz=1000.0, faults=1, misses=2),
    ],
    ids=lambda m: type(m).__name__,
)
def test_every_message_reads_back_as_written(message):
    h, back = wire.decode(wire.encode(message, 77))
    assert h.seq == 77 and h.version == wire.PROTOCOL_VERSION
    assert back == message


def test_nan_travels_unchanged_for_the_rig_to_deal_with():
    m = wire.ContactModel(stamp_s=math.nan, proxies=[wire.Proxy(wire.Sphere((math.nan, 0, 0), 0.1), math.inf)])
    _, back = wire.decode(wire.encode(m, 1))
    assert math.isnan(back.stamp_s) and math.isnan(back.proxies[0].shape.centre_m[0])
    assert back.proxies[0].k_n_per_m == math.inf


def _corrupt(d, at, value):
    b = bytearray(d)
    b[at] = value
    return bytes(b)


@pytest.mark.parametrize(
    "datagram, says",
    [
        (b"SPDR", "shorter than the 20-byte header"),
        (_corrupt(wire.encode(wire.Bye(1), 1), 0, ord("X")), "bad magic"),
        (wire.encode(wire.Bye(1), 1)[:-1], "truncated"),
        (wire.encode(wire.Bye(1), 1) + b"\0", "too long"),
        (_corrupt(wire.encode(wire.Bye(1), 1), 6, 99), "unknown message kind 99"),
        (_corrupt(wire.encode(wire.Bye(1), 1), 7, 1), "flags"),
        (_corrupt(wire.encode(wire.Bye(1), 1), 8, 9), "announced as 9 bytes"),
        (_corrupt(wire.encode(_sample(), 1), 20 + 16 + 72, 2), "bool"),
        (_corrupt(wire.encode(_model(), 1), 20 + 16 + 16 * 102, 17), "proxy count"),
        (_corrupt(wire.encode(_model(), 1), 20 + 16 + 4, 7), "proxy shape tag"),
        (_corrupt(wire.encode(_model(), 1), 20 + 16 + 5 + 6 * 8 + 7, 0x40), "unused numbers not zero"),
        (_corrupt(wire.encode(wire.Welcome(scene="ab"), 1), 20 + 27 + 3, ord("c")), "text"),
        (_corrupt(wire.encode(wire.RigStatus(), 1), 20 + 16, 9), "rig state"),
    ],
)
def test_a_malformed_datagram_is_refused_naming_what_is_wrong(datagram, says):
    with pytest.raises(WireError, match=says):
        wire.decode(datagram)


def test_another_protocol_version_is_named_with_both_versions():
    d = wire.encode(wire.Bye(1), 1, version=2)
    with pytest.raises(WireError) as e:
        wire.decode(d)
    assert e.value.version == 2
    assert f"the peer speaks link protocol 2, this side speaks {wire.PROTOCOL_VERSION}" in str(e.value)


def test_text_is_cut_at_a_character_boundary():
    w = wire.Welcome(scene="é" * 40)  # 80 bytes of UTF-8: 32 characters fit in 64 bytes
    _, back = wire.decode(wire.encode(w, 1))
    assert back.scene == "é" * 32


def test_too_many_proxies_is_an_error_of_the_caller_not_a_bad_datagram():
    m = wire.ContactModel(proxies=[wire.Proxy(wire.Sphere((0, 0, 0), 0.1), 1.0)] * 17)
    with pytest.raises(ValueError, match="at most 16 proxies"):
        wire.encode(m, 1)


def test_the_header_is_little_endian_with_the_sequence_number_last():
    d = wire.encode(wire.Bye(0), 0x0102030405060708)
    assert struct.unpack_from("<Q", d, 12)[0] == 0x0102030405060708
