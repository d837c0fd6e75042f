//! Property tests of every decoder in the device layer: random and truncated bytes never panic,
//! every frame the protocol does not allow is rejected, and every accepted frame is exactly what
//! the matching encoder writes (so nothing malformed slips through as data).

use proptest::prelude::*;

use crate::frame::{FrameError, Unwrap};
use crate::uart::protocol::{self as up, BoardInfo, BoardParser, CurrentReply, HostCommand, ReplyLayout};
use crate::usb::protocol as usbp;

fn any_board() -> impl Strategy<Value = BoardInfo> {
    (0u8..8, 1u8..=7).prop_map(|(id, m)| BoardInfo::of_model(id, m).unwrap())
}

fn any_layout() -> impl Strategy<Value = ReplyLayout> {
    prop::sample::select(ReplyLayout::ALL.to_vec())
}

fn bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>(), 0..max)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn info_reply_accepts_only_well_formed_boards(id in 0u8..8, b in bytes(16)) {
        match up::decode_info_reply(id, &b) {
            Ok(info) => {
                prop_assert_eq!(b.len(), up::INFO_REPLY_LEN);
                prop_assert_eq!(b[0], up::header(up::cmd::BOARD_INFO, id));
                prop_assert!(info.is_present());
                let mut again = [0u8; up::INFO_REPLY_LEN];
                up::encode_info_reply(&info, &mut again);
                prop_assert_eq!(&again[..], &b[..]);
            }
            Err(FrameError::Short { .. } | FrameError::Long { .. }) => prop_assert_ne!(b.len(), up::INFO_REPLY_LEN),
            Err(FrameError::Header { got, .. }) => prop_assert_eq!(got, b[0]),
            Err(FrameError::NotABoard) => prop_assert!(b.len() == up::INFO_REPLY_LEN),
            Err(e) => prop_assert!(false, "unexpected {:?}", e),
        }
    }

    #[test]
    fn current_reply_accepts_only_its_exact_length_and_header(
        board in any_board(),
        layout in any_layout(),
        b in bytes(60),
    ) {
        let len = board.current_reply_len(layout);
        match up::decode_current_reply(&board, layout, &b) {
            Ok(r) => {
                prop_assert_eq!(b.len(), len);
                prop_assert_eq!(b[0], up::header(up::cmd::CURRENT, board.id));
                let mut again = [0u8; 64];
                let n = up::encode_current_reply(&board, layout, &r, &mut again).unwrap();
                prop_assert_eq!(&again[..n], &b[..]);
            }
            Err(_) => prop_assert!(b.len() != len || b[0] != up::header(up::cmd::CURRENT, board.id)),
        }
    }

    #[test]
    fn truncated_or_misaddressed_current_replies_are_rejected(
        board in any_board(),
        layout in any_layout(),
        pos in proptest::array::uniform8(any::<i16>()),
        cut in 0usize..49,
        wrong in any::<u8>(),
    ) {
        let r = CurrentReply { positions: pos, velocities: pos, sensors: pos };
        let mut buf = [0u8; 64];
        let n = up::encode_current_reply(&board, layout, &r, &mut buf).unwrap();
        prop_assert!(up::decode_current_reply(&board, layout, &buf[..n]).is_ok());
        let cut = cut.min(n - 1);
        let is_short =
            matches!(up::decode_current_reply(&board, layout, &buf[..cut]), Err(FrameError::Short { .. }));
        prop_assert!(is_short);
        if wrong != buf[0] {
            buf[0] = wrong;
            let is_header =
                matches!(up::decode_current_reply(&board, layout, &buf[..n]), Err(FrameError::Header { .. }));
            prop_assert!(is_header);
        }
    }

    #[test]
    fn boards_parser_never_panics_and_takes_only_its_own_commands_and_length_tables(
        me in any_board(),
        stream in bytes(600),
    ) {
        let mut p = BoardParser::new(&me);
        for &x in &stream {
            let step = p.push(x);
            if let Some(c) = step.reply_to {
                prop_assert!(usize::from(c) < up::COMMANDS);
            }
            match step.done {
                Some(HostCommand::SetCommandLengths { board, lengths }) => {
                    prop_assert_eq!(p.table(board), lengths);
                }
                Some(HostCommand::BoardInfo { board } | HostCommand::Current { board, .. } | HostCommand::Other { board, .. }) => {
                    prop_assert_eq!(board, me.id);
                }
                None => {}
            }
        }
    }

    #[test]
    fn counter_extension_never_panics_and_rejects_only_impossible_steps(
        raws in proptest::collection::vec(any::<i64>(), 1..50),
        max_step in 0i64..70_000,
    ) {
        let mut w16 = Unwrap::<16>::new();
        let mut w24 = Unwrap::<24>::new();
        for r in raws {
            let before = w16.value();
            match w16.update(r, max_step) {
                Ok(v) => prop_assert!((v - before).abs() <= max_step.max(1 << 15) ),
                Err(FrameError::Jump { counts }) => {
                    prop_assert!(counts as i64 > max_step);
                    prop_assert_eq!(w16.value(), before);
                }
                Err(e) => prop_assert!(false, "unexpected {:?}", e),
            }
            let _ = w24.update(r, max_step);
        }
    }

    #[test]
    fn simple_counters_accept_exactly_32_bytes(b in bytes(70)) {
        match usbp::simple_decode_counters(&b) {
            Ok(r) => {
                prop_assert_eq!(b.len(), usbp::SIMPLE_LEN);
                let mut again = [0u8; usbp::SIMPLE_LEN];
                usbp::simple_encode_counters(&r, &mut again);
                // Bytes 25..31 are padding the board may fill as it likes: not data.
                prop_assert_eq!(&again[..25], &b[..25]);
            }
            Err(_) => prop_assert_ne!(b.len(), usbp::SIMPLE_LEN),
        }
    }

    #[test]
    fn simple_commands_decode_only_known_opcodes(b in bytes(40), op in prop::sample::select(vec![0x51u8, 0x52, 0xA2, 0x00, 0xFF])) {
        let mut b = b;
        if !b.is_empty() {
            b[0] = op;
        }
        if let Ok(c) = usbp::simple_decode_command(&b) {
            prop_assert_eq!(b.len(), usbp::SIMPLE_LEN);
            let ok = match c {
                usbp::SimpleCommand::Reset { .. } | usbp::SimpleCommand::ClearCounters => b[0] == 0xA2,
                usbp::SimpleCommand::SetDa(_) => b[0] == 0x52,
                usbp::SimpleCommand::RequestCounters => b[0] == 0x51,
            };
            prop_assert!(ok);
        }
    }

    #[test]
    fn sh4_packets_accept_exactly_512_bytes(b in bytes(600), cut in 0usize..512) {
        match usbp::sh4_decode_in(&b) {
            Ok(r) => {
                prop_assert_eq!(b.len(), usbp::SH4_LEN);
                let mut again = [0u8; usbp::SH4_LEN];
                usbp::sh4_encode_in(&r, &mut again);
                prop_assert_eq!(&again[..54], &b[..54]);
            }
            Err(_) => prop_assert_ne!(b.len(), usbp::SH4_LEN),
        }
        if let Ok(da) = usbp::sh4_decode_out(&b) {
            prop_assert_eq!(&b[..2], &[0x01, 0x0E]);
            let mut again = [0u8; usbp::SH4_LEN];
            usbp::sh4_encode_out(&da, &mut again);
            prop_assert_eq!(&again[..18], &b[..18]);
        }
        // A whole valid packet cut short is rejected.
        let mut full = [0u8; usbp::SH4_LEN];
        usbp::sh4_encode_out(&[1; usbp::CHANNELS], &mut full);
        prop_assert!(usbp::sh4_decode_out(&full[..cut]).is_err());
        prop_assert!(usbp::sh4_decode_in(&full[..cut]).is_err());
    }
}
