//! Round trips of random messages (every field compared), every malformed case, and a pinned
//! datagram (the one shown in docs/link.md).

use super::*;
use crate::handshake::{Name, Reason};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Random messages. Every struct literal below names every field: a field added to a message
// stops this file compiling until it gets a generator, and then the round trip fails until the
// field is encoded.

fn num() -> impl Strategy<Value = f64> {
    any::<f64>().prop_filter("NaN never equals itself (NaN bits are tested apart)", |x| !x.is_nan())
}

fn v3() -> impl Strategy<Value = DVec3> {
    (num(), num(), num()).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

fn shape() -> impl Strategy<Value = ProxyShape> {
    prop_oneof![
        (v3(), v3()).prop_map(|(point_m, normal)| ProxyShape::Plane { point_m, normal }),
        (v3(), num()).prop_map(|(centre_m, radius_m)| ProxyShape::Sphere { centre_m, radius_m }),
        (v3(), v3(), num()).prop_map(|(a_m, b_m, radius_m)| ProxyShape::Capsule { a_m, b_m, radius_m }),
    ]
}

fn proxy() -> impl Strategy<Value = Proxy> {
    (any::<u16>(), any::<u16>(), shape(), num(), num(), v3(), any::<u8>()).prop_map(
        |(body, part, shape, k_n_per_m, d_n_s_per_m, vel_m_per_s, hand_mask)| Proxy {
            id: ProxyId { body, part },
            shape,
            k_n_per_m,
            d_n_s_per_m,
            vel_m_per_s,
            hand_mask,
        },
    )
}

fn arr<T: std::fmt::Debug, const N: usize>(s: impl Strategy<Value = T>) -> impl Strategy<Value = [T; N]> {
    prop::collection::vec(s, N).prop_map(|v| v.try_into().expect("N elements"))
}

fn hand_contact() -> impl Strategy<Value = HandContact> {
    (v3(), v3(), num(), v3(), num()).prop_map(|(force_n, normal, k_n_per_m, at_m, source_w)| HandContact {
        force_n,
        normal,
        k_n_per_m,
        at_m,
        source_w,
    })
}

fn blow() -> impl Strategy<Value = Blow> {
    (any::<u64>(), v3(), v3(), num(), num(), any::<bool>()).prop_map(
        |(seq, point_m, dir, speed_m_per_s, momentum_n_s, in_contact)| Blow {
            seq,
            point_m,
            dir,
            speed_m_per_s,
            momentum_n_s,
            in_contact,
        },
    )
}

fn model() -> impl Strategy<Value = ContactModel> {
    (
        any::<u64>(),
        num(),
        arr::<_, MAX_PROXIES>(proxy()),
        0..=MAX_PROXIES as u8,
        arr::<_, HANDS>(hand_contact()),
        arr::<_, HANDS>(v3()),
        blow(),
    )
        .prop_map(|(seq, stamp_s, proxies, proxy_count, hand_contacts, extra_force_n, blow)| {
            ContactModel { seq, stamp_s, proxies, proxy_count, hand_contacts, extra_force_n, blow }
        })
}

fn hand_state() -> impl Strategy<Value = HandState> {
    (v3(), v3(), v3(), any::<bool>()).prop_map(|(pos_world_m, vel_world_m_per_s, force_n, valid)| HandState {
        pos_world_m,
        vel_world_m_per_s,
        force_n,
        valid,
    })
}

fn sample() -> impl Strategy<Value = HandSample> {
    (
        any::<u64>(),
        num(),
        arr::<_, HANDS>(hand_state()),
        any::<u64>(),
        arr::<_, MAX_PROXIES>(v3()),
        arr::<_, MAX_PROXIES>(v3()),
    )
        .prop_map(|(tick, t_s, hands, model_seq, proxy_impulse_n_s, proxy_contact_impulse_n_s)| {
            HandSample { tick, t_s, hands, model_seq, proxy_impulse_n_s, proxy_contact_impulse_n_s }
        })
}

fn rig_info() -> impl Strategy<Value = RigInfo> {
    (
        (num(), arr::<_, HANDS>(arr::<_, STRINGS>(v3())), arr::<_, HANDS>(v3())),
        (arr::<_, HANDS>(num()), arr::<_, HANDS>(num()), arr::<_, HANDS>(num())),
        (arr::<_, HANDS>(num()), v3()),
        (any::<bool>(), v3(), v3(), v3(), num(), any::<u8>()),
        (num(), v3(), num(), num(), num()),
    )
        .prop_map(
            |(
                (period_s, anchors_m, home_m),
                (tension_min_n, tension_max_n, force_limit_n),
                (grip_radius_m, eye_m),
                (present, lower_left_m, lower_right_m, upper_left_m, eye_separation_m, stereo),
                (distance_m, toward_elbow, wrist_m, elbow_m, radius_m),
            )| {
                RigInfo {
                    period_s,
                    anchors_m,
                    home_m,
                    tension_min_n,
                    tension_max_n,
                    force_limit_n,
                    grip_radius_m,
                    eye_m,
                    display: DisplayInfo {
                        present,
                        lower_left_m,
                        lower_right_m,
                        upper_left_m,
                        eye_separation_m,
                        stereo,
                    },
                    clearance: StringClearance {
                        distance_m,
                        forearm: Forearm { toward_elbow, wrist_m, elbow_m, radius_m },
                    },
                }
            },
        )
}

fn rig_state() -> impl Strategy<Value = RigState> {
    prop_oneof![
        Just(RigState::Unconfigured),
        Just(RigState::Inactive),
        Just(RigState::Active),
        Just(RigState::Faulted),
        Just(RigState::Stopping),
    ]
}

fn status() -> impl Strategy<Value = RigStatus> {
    (
        (any::<u64>(), num(), rig_state(), num(), num()),
        arr::<_, HANDS>(v3()),
        arr::<_, HANDS>(arr::<_, STRINGS>(num())),
        arr::<_, 5>(any::<u64>()),
    )
        .prop_map(|((tick, t_s, state, rate_hz, lateness_p99_s), force_n, tensions_n, c)| RigStatus {
            tick,
            t_s,
            state,
            rate_hz,
            lateness_p99_s,
            force_n,
            tensions_n,
            faults: c[0],
            device_errors: c[1],
            stale_ticks: c[2],
            clamped_ticks: c[3],
            misses: c[4],
        })
}

fn text<const N: usize>() -> impl Strategy<Value = Text<N>> {
    ".{0,80}".prop_map(|s: String| Text::new(&s))
}

fn hello() -> impl Strategy<Value = Hello> {
    (any::<u64>(), any::<[u8; 3]>(), text::<64>(), rig_info()).prop_map(|(rig_session, n, scene, rig)| {
        Hello { rig_session, hands: n[0], strings: n[1], max_proxies: n[2], scene, rig }
    })
}

fn welcome() -> impl Strategy<Value = Welcome> {
    (any::<u64>(), any::<u64>(), any::<[u8; 3]>(), num(), text::<64>()).prop_map(
        |(rig_session, world_session, n, step_s, scene)| Welcome {
            rig_session,
            world_session,
            hands: n[0],
            strings: n[1],
            max_proxies: n[2],
            step_s,
            scene,
        },
    )
}

fn refuse() -> impl Strategy<Value = Refuse> {
    (any::<u64>(), 0u8..=4, text::<160>()).prop_map(|(rig_session, code, reason)| Refuse {
        rig_session,
        code: RefuseCode::from_u8(code).unwrap(),
        reason,
    })
}

fn message() -> impl Strategy<Value = Message> {
    prop_oneof![
        hello().prop_map(Message::Hello),
        welcome().prop_map(Message::Welcome),
        refuse().prop_map(Message::Refuse),
        any::<u64>().prop_map(|session| Message::Bye(Bye { session })),
        sample().prop_map(Message::Sample),
        model().prop_map(Message::Model),
        status().prop_map(Message::Status),
    ]
}

fn encode_any(m: &Message, seq: u64, buf: &mut [u8]) -> Result<usize, WireError> {
    match m {
        Message::Hello(x) => encode(x, seq, buf),
        Message::Welcome(x) => encode(x, seq, buf),
        Message::Refuse(x) => encode(x, seq, buf),
        Message::Bye(x) => encode(x, seq, buf),
        Message::Sample(x) => encode(x, seq, buf),
        Message::Model(x) => encode(x, seq, buf),
        Message::Status(x) => encode(x, seq, buf),
    }
}

fn encoded(m: &Message, seq: u64) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_DATAGRAM];
    let n = encode_any(m, seq, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn every_message_survives_a_round_trip_field_for_field(m in message(), seq in any::<u64>()) {
        let d = encoded(&m, seq);
        prop_assert_eq!(d.len(), HEADER_LEN + m.kind().payload_len());
        let (h, back) = decode(&d).unwrap();
        prop_assert_eq!(h, Header { version: PROTOCOL_VERSION, kind: m.kind(), len: m.kind().payload_len() as u32, seq });
        prop_assert_eq!(back, m);
    }

    #[test]
    fn decoding_never_panics_on_any_bytes(d in prop::collection::vec(any::<u8>(), 0..2 * MAX_DATAGRAM)) {
        let _ = decode(&d);
    }

    #[test]
    fn a_valid_datagram_cut_or_padded_is_refused(m in message(), cut in 1usize..64, extra in 1usize..64) {
        let d = encoded(&m, 1);
        let want = d.len();
        let short = &d[..want.saturating_sub(cut).max(HEADER_LEN)];
        if short.len() < want {
            prop_assert_eq!(decode(short).unwrap_err(), WireError::Truncated { kind: m.kind(), got: short.len(), want });
        }
        let mut long = d.clone();
        long.extend(std::iter::repeat_n(0u8, extra));
        prop_assert_eq!(decode(&long).unwrap_err(), WireError::Long { kind: m.kind(), got: want + extra, want });
    }

    #[test]
    fn a_flipped_byte_never_panics_and_header_damage_is_named(m in message(), at in 0usize..MAX_DATAGRAM, bit in 0u8..8) {
        let mut d = encoded(&m, 7);
        let at = at % d.len();
        d[at] ^= 1 << bit;
        match decode(&d) {
            Err(WireError::BadMagic) => prop_assert!(at < 4),
            Err(WireError::Version { ours, .. }) => prop_assert!((4..6).contains(&at) && ours == PROTOCOL_VERSION),
            Err(WireError::UnknownKind(_)) | Err(WireError::Flags(_)) | Err(WireError::Length { .. }) => prop_assert!((6..12).contains(&at)),
            Err(WireError::BadValue { .. }) => prop_assert!(at >= HEADER_LEN),
            Err(e) => prop_assert!(false, "unexpected {e:?}"),
            Ok((h, back)) => {
                // A bit of the sequence number or of a payload number: the datagram reads, and
                // what it reads as encodes back to exactly these bytes.
                prop_assert!(at >= 12);
                prop_assert_eq!(encoded(&back, h.seq), d);
            }
        }
    }
}

#[test]
fn sizes_follow_the_layout() {
    // What each payload holds, in bytes (docs/link.md lists the same).
    assert_eq!(ProxyShape::SIZE, 57);
    assert_eq!(Proxy::SIZE, 102);
    assert_eq!(HandContact::SIZE, 88);
    assert_eq!(Blow::SIZE, 73);
    assert_eq!(ContactModel::SIZE, 8 + 8 + 16 * 102 + 1 + 2 * 88 + 48 + 73);
    assert_eq!(HandSample::SIZE, 8 + 8 + 2 * 73 + 8 + 2 * 16 * 24);
    assert_eq!(RigInfo::SIZE, 336 + 82 + 56);
    assert_eq!(RigStatus::SIZE, 185);
    assert_eq!(Hello::SIZE, 411 + 82 + 56);
    assert_eq!(Welcome::SIZE, 91);
    assert_eq!(Refuse::SIZE, 169);
    assert_eq!(Bye::SIZE, 8);
    assert_eq!(MAX_DATAGRAM, HEADER_LEN + ContactModel::SIZE);
}

#[test]
fn put_writes_exactly_the_announced_size_for_every_kind() {
    let msgs = [
        Message::Hello(Hello::default()),
        Message::Welcome(Welcome::default()),
        Message::Refuse(Refuse::default()),
        Message::Bye(Bye::default()),
        Message::Sample(HandSample::default()),
        Message::Model(ContactModel::default()),
        Message::Status(RigStatus::default()),
    ];
    for m in msgs {
        // A Put over a buffer far larger than the size: its position after put() is what it wrote.
        let mut big = vec![0u8; 4 * MAX_DATAGRAM];
        let mut w = Put { buf: &mut big, at: 0 };
        match &m {
            Message::Hello(x) => x.put(&mut w),
            Message::Welcome(x) => x.put(&mut w),
            Message::Refuse(x) => x.put(&mut w),
            Message::Bye(x) => x.put(&mut w),
            Message::Sample(x) => x.put(&mut w),
            Message::Model(x) => x.put(&mut w),
            Message::Status(x) => x.put(&mut w),
        }
        assert_eq!(w.at, m.kind().payload_len(), "{:?}", m.kind());
    }
}

/// The in-memory sizes of the messages, pinned: a field added to one of them changes its size
/// and fails here with the reminder, even if a test generator was given a default for it.
#[test]
fn a_message_struct_that_grows_must_grow_its_wire_form_too() {
    use std::mem::size_of;
    let pinned = [
        ("HandSample", size_of::<HandSample>(), 952),
        ("ContactModel", size_of::<ContactModel>(), 2120),
        ("Blow", size_of::<Blow>(), 80),
        ("HandContact", size_of::<HandContact>(), 88),
        ("Proxy", size_of::<Proxy>(), 112),
        ("RigInfo", size_of::<RigInfo>(), 480),
        ("RigStatus", size_of::<RigStatus>(), 192),
        ("Hello", size_of::<Hello>(), 560),
        ("Welcome", size_of::<Welcome>(), 96),
    ];
    for (name, now, was) in pinned {
        assert_eq!(
            now, was,
            "{name} changed size ({was} -> {now} bytes): encode the new field in msg/src/wire.rs, raise \
             PROTOCOL_VERSION, update docs/link.md, then this number"
        );
    }
}

#[test]
fn non_finite_numbers_travel_bit_for_bit() {
    let mut m = ContactModel { stamp_s: f64::NAN, ..Default::default() };
    m.proxies[0].k_n_per_m = f64::INFINITY;
    m.proxies[0].d_n_s_per_m = f64::from_bits(0x7ff8_dead_beef_0001); // a NaN with a payload
    m.extra_force_n[1] = DVec3::new(f64::NEG_INFINITY, -0.0, f64::NAN);
    m.proxy_count = 1;
    let d = encoded(&Message::Model(m), 3);
    let Message::Model(b) = decode(&d).unwrap().1 else { panic!("kind changed") };
    assert_eq!(b.stamp_s.to_bits(), f64::NAN.to_bits());
    assert_eq!(b.proxies[0].k_n_per_m, f64::INFINITY);
    assert_eq!(b.proxies[0].d_n_s_per_m.to_bits(), 0x7ff8_dead_beef_0001);
    assert_eq!(b.extra_force_n[1].x, f64::NEG_INFINITY);
    assert_eq!(b.extra_force_n[1].y.to_bits(), (-0.0f64).to_bits());
    assert!(b.extra_force_n[1].z.is_nan());
}

fn bye_datagram() -> Vec<u8> {
    encoded(&Message::Bye(Bye { session: 0x0123_4567_89ab_cdef }), 42)
}

#[test]
fn every_malformed_header_is_named() {
    let good = bye_datagram();
    assert_eq!(decode(&good[..HEADER_LEN - 1]), Err(WireError::Short { got: HEADER_LEN - 1 }));
    assert_eq!(decode(&[]), Err(WireError::Short { got: 0 }));
    let with = |at: usize, b: u8| {
        let mut d = good.clone();
        d[at] = b;
        decode(&d)
    };
    assert_eq!(with(0, b'X'), Err(WireError::BadMagic));
    assert_eq!(with(4, 1), Err(WireError::Version { got: 1, ours: PROTOCOL_VERSION }));
    assert_eq!(with(5, 1), Err(WireError::Version { got: 256 + PROTOCOL_VERSION, ours: PROTOCOL_VERSION }));
    assert_eq!(with(6, 0), Err(WireError::UnknownKind(0)));
    assert_eq!(with(6, 99), Err(WireError::UnknownKind(99)));
    assert_eq!(with(7, 1), Err(WireError::Flags(1)));
    assert_eq!(with(8, 9), Err(WireError::Length { kind: Kind::Bye, got: 9, want: 8 }));
    assert_eq!(with(11, 1), Err(WireError::Length { kind: Kind::Bye, got: (1 << 24) + 8, want: 8 }));
    // A valid header of another kind on a Bye's payload: too short for that kind.
    assert_eq!(
        {
            let mut d = good.clone();
            d[6] = Kind::Model as u8;
            d[8..12].copy_from_slice(&(ContactModel::SIZE as u32).to_le_bytes());
            decode(&d)
        },
        Err(WireError::Truncated {
            kind: Kind::Model,
            got: good.len(),
            want: HEADER_LEN + ContactModel::SIZE
        })
    );
    // The version is read before the kind, so a peer of another version is named even when its
    // kinds differ from ours.
    let mut d = good.clone();
    d[4] = 9;
    d[6] = 200;
    assert_eq!(header(&d), Err(WireError::Version { got: 9, ours: PROTOCOL_VERSION }));
}

#[test]
fn every_malformed_payload_value_is_named() {
    let bad = |m: &Message, at: usize, b: u8| {
        let mut d = encoded(m, 1);
        d[HEADER_LEN + at] = b;
        match decode(&d) {
            Err(WireError::BadValue { what, .. }) => what,
            other => panic!("{other:?}"),
        }
    };
    let model = Message::Model(ContactModel::default());
    // Proxy 0's shape tag sits after its 4-byte id.
    let tag_at = 8 + 8 + 4;
    assert_eq!(bad(&model, tag_at, 3), "proxy shape tag");
    // A sphere (tag 1) with a non-zero unused slot.
    assert_eq!(bad(&model, tag_at + 1 + 5 * 8 + 7, 0x40), "proxy shape (unused numbers not zero)");
    let count_at = 8 + 8 + MAX_PROXIES * Proxy::SIZE;
    assert_eq!(bad(&model, count_at, MAX_PROXIES as u8 + 1), "proxy count (above MAX_PROXIES)");
    let sample = Message::Sample(HandSample::default());
    let valid_at = 8 + 8 + 72;
    assert_eq!(bad(&sample, valid_at, 2), "bool (not 0 or 1)");
    let status = Message::Status(RigStatus::default());
    assert_eq!(bad(&status, 16, 5), "rig state");
    let welcome = Message::Welcome(Welcome { scene: Text::new("walls"), ..Default::default() });
    let scene_at = 8 + 8 + 3 + 8;
    assert_eq!(bad(&welcome, scene_at, 0xff), "text (not zero-padded UTF-8)");
    assert_eq!(bad(&welcome, scene_at + 10, b'x'), "text (not zero-padded UTF-8)");
    let refuse = Message::Refuse(Refuse::default());
    assert_eq!(bad(&refuse, 8, 77), "refusal code");
}

#[test]
fn encoding_needs_a_big_enough_buffer_and_allocates_nothing_else() {
    let mut small = [0u8; 27];
    assert_eq!(
        encode(&Bye { session: 1 }, 0, &mut small),
        Err(WireError::BufferTooSmall { need: 28, have: 27 })
    );
    let mut exact = [0u8; 28];
    assert_eq!(encode(&Bye { session: 1 }, 0, &mut exact), Ok(28));
}

/// The datagram shown in docs/link.md, byte for byte.
#[test]
fn the_documented_bye_datagram_is_what_encode_writes() {
    let hex: String = bye_datagram().iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ");
    assert_eq!(hex, "53 50 44 52 06 00 04 00 08 00 00 00 2a 00 00 00 00 00 00 00 ef cd ab 89 67 45 23 01");
}

#[test]
fn names_are_cut_to_fit_and_read_back() {
    let long = "x".repeat(100);
    let w = Welcome { scene: Name::new(&long), ..Default::default() };
    assert_eq!(w.scene.as_str().len(), 64);
    let r = Refuse {
        reason: Reason::new("the world runs 'walls', the rig asked for 'crowd'"),
        ..Default::default()
    };
    let d = encoded(&Message::Refuse(r), 0);
    assert_eq!(decode(&d).unwrap().1, Message::Refuse(r));
}
