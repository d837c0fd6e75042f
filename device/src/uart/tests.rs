//! The UART protocol byte by byte against reference/boards.md section 3, and the driver against
//! the emulator's boards in-process (a fake transport that plays the boards' side).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::DVec3;

use super::protocol::*;
use super::*;
use crate::emulator::{Boards, EmulatorOptions, PlantClock};
use crate::sim::{Script, SimRig, SimRigParams};
use crate::Device;

#[test]
fn header_packs_board_id_in_bits_0_to_2_and_command_in_bits_3_to_7() {
    assert_eq!(header(cmd::CURRENT, 0), 0x30);
    assert_eq!(header(cmd::CURRENT, 1), 0x31);
    assert_eq!(header(cmd::BOARD_INFO, 7), 0x0F);
    assert_eq!(split_header(0x31), (cmd::CURRENT, 1));
}

#[test]
fn enumeration_request_is_40_zeros_the_info_header_and_26_zeros() {
    let mut buf = [0xEEu8; 80];
    let n = encode_info_request(3, &mut buf);
    assert_eq!(n, 67);
    assert!(buf[..40].iter().all(|&b| b == 0));
    assert_eq!(buf[40], (1 << 3) | 3);
    assert!(buf[41..67].iter().all(|&b| b == 0));
}

#[test]
fn board_info_reply_decodes_and_the_presence_rule_holds() {
    let b = decode_info_reply(2, &[0x0A, 5, 12, 4, 4, 0, 0]).unwrap();
    assert_eq!((b.id, b.model, b.n_motor, b.n_current), (2, 5, 4, 4));
    assert_eq!(b.model_name(), "B3M");
    // Wrong header, model 0, no motors, a short reply: all rejected.
    assert!(matches!(decode_info_reply(1, &[0x0A, 5, 12, 4, 4, 0, 0]), Err(FrameError::Header { .. })));
    assert_eq!(decode_info_reply(2, &[0x0A, 0, 12, 4, 0, 0, 0]), Err(FrameError::NotABoard));
    assert_eq!(decode_info_reply(2, &[0x0A, 1, 12, 0, 0, 0, 0]), Err(FrameError::NotABoard));
    assert!(matches!(decode_info_reply(2, &[0x0A, 1, 12, 4]), Err(FrameError::Short { need: 7, got: 4 })));
}

#[test]
fn set_command_lengths_is_header_12_lengths_and_5_zeros() {
    let b = BoardInfo::of_model(1, 1).unwrap(); // B1M at id 1
    let mut buf = [0xEEu8; SET_CMD_LEN_REQUEST_LEN];
    assert_eq!(encode_set_command_lengths(&b, &mut buf), 18);
    assert_eq!(buf[0], (2 << 3) | 1);
    assert_eq!(&buf[1..13], &[0, 1, 13, 0, 0, 0, 9, 0, 0, 0, 0, 0]);
    assert_eq!(&buf[13..], &[0; 5]);
}

#[test]
fn reply_lengths_are_17_for_a_4_motor_m_board_and_25_for_b3m() {
    let m = BoardInfo::of_model(0, 1).unwrap();
    let b3m = BoardInfo::of_model(0, 5).unwrap();
    assert_eq!((m.current_cmd_len(), m.current_reply_len()), (9, 17));
    assert_eq!(b3m.current_reply_len(), 25);
    // Padding: max(5, reply - cmd + 20).
    assert_eq!(m.current_padding(), 28);
    assert_eq!(b3m.current_padding(), 36);
}

#[test]
fn current_command_is_header_then_little_endian_i16_then_padding() {
    let b = BoardInfo::of_model(0, 1).unwrap();
    let mut buf = [0xEEu8; 64];
    let n = encode_current(&b, &[1, -1, 4095, -4095], &mut buf).unwrap();
    assert_eq!(n, 9 + 28);
    assert_eq!(&buf[..9], &[0x30, 0x01, 0x00, 0xFF, 0xFF, 0xFF, 0x0F, 0x01, 0xF0]);
    assert!(buf[9..n].iter().all(|&b| b == 0));
    assert_eq!(buf[n], 0xEE, "nothing written past the frame");
}

#[test]
fn volts_become_4096_per_3v3_clamped_to_4095() {
    assert_eq!(volts_to_current(1.0, DEFAULT_DIGITS_PER_VOLT), 1241);
    assert_eq!(volts_to_current(3.3, DEFAULT_DIGITS_PER_VOLT), 4095);
    assert_eq!(volts_to_current(-100.0, DEFAULT_DIGITS_PER_VOLT), -4095);
    assert_eq!(volts_to_current(f64::NAN, DEFAULT_DIGITS_PER_VOLT), 0);
}

#[test]
fn current_reply_decodes_positions_velocities_and_currents() {
    let b3m = BoardInfo::of_model(1, 5).unwrap();
    let mut bytes = vec![0x31];
    for v in [100i16, -2, 32767, -32768, 1, 2, 3, 4, 10, 20, 30, 40] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let r = decode_current_reply(&b3m, &bytes).unwrap();
    assert_eq!(r.positions, [100, -2, 32767, -32768]);
    assert_eq!(r.velocities, [1, 2, 3, 4]);
    assert_eq!(r.currents, [10, 20, 30, 40]);
    let mut again = [0u8; 25];
    encode_current_reply(&b3m, &r, &mut again).unwrap();
    assert_eq!(&again[..], &bytes[..]);
    bytes[0] = 0x30;
    assert!(matches!(decode_current_reply(&b3m, &bytes), Err(FrameError::Header { want: 0x31, got: 0x30 })));
    assert!(decode_current_reply(&b3m, &bytes[..24]).is_err());
}

#[test]
fn sixteen_bit_counters_extend_across_the_wrap_both_ways() {
    let mut w = crate::frame::Unwrap::<16>::new();
    assert_eq!(w.update(32000, 4096).unwrap(), 32000);
    assert_eq!(w.update(-32000i16 as i64, 4096).unwrap(), 33536); // wrapped forward
    assert_eq!(w.update(32000, 4096).unwrap(), 32000); // and back
    assert_eq!(w.update(-100, 4096), Err(FrameError::Jump { counts: 32100 }));
    assert_eq!(w.value(), 32000, "a rejected step changes nothing");
    let mut w24 = crate::frame::Unwrap::<24>::new();
    assert_eq!(w24.update(0x7F_FFFF, 10).unwrap(), 0x7F_FFFF);
    assert_eq!(w24.update(0x80_0000, 10).unwrap(), 0x80_0000);
}

#[test]
fn the_boards_parser_skips_padding_and_takes_each_command_by_its_length() {
    let b = BoardInfo::of_model(0, 1).unwrap();
    let mut p = BoardParser::new([Some(b), None, None, None, None, None, None, None]);
    let mut buf = [0u8; 64];
    let n = encode_current(&b, &[5, 6, 7, 8], &mut buf).unwrap();
    let cmds: Vec<HostCommand> = buf[..n].iter().filter_map(|&x| p.push(x)).collect();
    assert_eq!(cmds, vec![HostCommand::Current { board: 0, currents: [5, 6, 7, 8] }]);
    // A command for an absent board is no board's.
    assert_eq!(p.push(header(cmd::BOARD_INFO, 3)), None);
    assert_eq!(p.push(header(cmd::BOARD_INFO, 0)), Some(HostCommand::BoardInfo { board: 0 }));
}

// ---------------------------------------------------------------------------------------------
// The driver against the emulator's boards, in-process.

/// A byte link straight into `Boards` (no pty): what the host writes is fed to the boards at
/// once, their replies wait in a queue. `corrupt_next` flips the next reply's first byte.
struct Loopback {
    boards: Arc<Mutex<Boards>>,
    rx: VecDeque<u8>,
    out: Vec<u8>,
    ticks: Vec<(usize, usize)>,
    corrupt_next: Arc<Mutex<bool>>,
}

impl ByteLink for Loopback {
    fn write_all(&mut self, bytes: &[u8], _deadline: Instant) -> Result<(), DeviceError> {
        self.out.clear();
        self.ticks.clear();
        self.boards.lock().unwrap().feed(bytes, Instant::now(), &mut self.out, &mut self.ticks);
        let mut c = self.corrupt_next.lock().unwrap();
        if *c && !self.out.is_empty() {
            self.out[0] ^= 0xFF;
            *c = false;
        }
        self.rx.extend(self.out.iter());
        Ok(())
    }
    fn read_exact(&mut self, buf: &mut [u8], _deadline: Instant) -> Result<(), DeviceError> {
        if self.rx.len() < buf.len() {
            self.rx.clear();
            return Err(DeviceError::Timeout { waited_us: 0 });
        }
        for b in buf.iter_mut() {
            *b = self.rx.pop_front().unwrap_or(0);
        }
        Ok(())
    }
    fn clear_input(&mut self) -> Result<(), DeviceError> {
        self.rx.clear();
        Ok(())
    }
}

struct LoopConnector {
    boards: Arc<Mutex<Boards>>,
    corrupt_next: Arc<Mutex<bool>>,
}

impl Connector for LoopConnector {
    type Link = Loopback;
    fn connect(&mut self) -> Result<Loopback, DeviceError> {
        Ok(Loopback {
            boards: self.boards.clone(),
            rx: VecDeque::with_capacity(1024),
            out: Vec::with_capacity(1024),
            ticks: Vec::with_capacity(16),
            corrupt_next: self.corrupt_next.clone(),
        })
    }
    fn describe(&self) -> &str {
        "loopback"
    }
}

fn lab_rig() -> SimRig {
    let p = SimRigParams::lab([DVec3::new(-0.15, 0.0, 0.0), DVec3::new(0.15, 0.0, 0.0)]);
    let holds = [Script::hold(p.hands[0].start_m), Script::hold(p.hands[1].start_m)];
    SimRig::new(p, holds).unwrap()
}

fn driver(models: Vec<u8>) -> (UartDevice<LoopConnector>, Arc<Mutex<Boards>>, Arc<Mutex<bool>>) {
    let opts = EmulatorOptions { models, plant: PlantClock::PerTick, ..Default::default() };
    let boards = Arc::new(Mutex::new(Boards::new(lab_rig(), opts).unwrap()));
    let corrupt = Arc::new(Mutex::new(false));
    let conn = LoopConnector { boards: boards.clone(), corrupt_next: corrupt.clone() };
    (UartDevice::new(conn, UartOptions::default()), boards, corrupt)
}

#[test]
fn driver_enumerates_the_boards_and_numbers_channels_in_board_order() {
    let (mut d, _, _) = driver(vec![1, 5]);
    d.open().unwrap();
    assert_eq!(d.boards().len(), 2);
    assert_eq!(d.boards()[1].model_name(), "B3M");
    assert_eq!(d.info().channels, 8);
    assert_eq!(d.info().board.as_str(), "UART B1M#0+B3M#1");
    assert!((d.info().volts_max - 3.3).abs() < 0.01);
}

#[test]
fn driver_reads_the_same_counts_and_drives_the_same_tensions_as_the_rig_in_process() {
    let (mut d, boards, _) = driver(vec![1, 1]);
    let mut reference = lab_rig();
    d.open().unwrap();
    d.activate().unwrap();
    reference.open().unwrap();
    reference.activate().unwrap();
    let mut out = Output::default();
    for ch in 0..8 {
        out.volts[ch] = 0.2 * (1.0 + ch as f64); // 1 .. 8 N at 0.2 V/N
    }
    let (mut a, mut b) = (Input::default(), Input::default());
    for _ in 0..200 {
        d.exchange(&out, &mut a).unwrap();
        reference.exchange(&out, &mut b).unwrap();
        // The current command is quantised (4 mN steps), so the two plants may differ by a count.
        for ch in 0..8 {
            assert!((a.counts[ch] - b.counts[ch]).abs() <= 2, "{:?} vs {:?}", a.counts, b.counts);
        }
    }
    let emu = *boards.lock().unwrap().rig().truth();
    let inproc = *reference.truth();
    for h in 0..2 {
        for s in 0..4 {
            let (x, y) = (emu.hands[h].tension_n[s], inproc.hands[h].tension_n[s]);
            // One current digit is 3.3 / 4096 V = 4 mN at 0.2 V/N.
            assert!((x - y).abs() < 0.005, "hand {h} string {s}: {x} vs {y}");
        }
    }
    assert!(emu.hands[0].pos_m.distance(inproc.hands[0].pos_m) < 1e-4);
}

#[test]
fn inactive_driver_commands_zero_current() {
    let (mut d, boards, _) = driver(vec![1, 1]);
    d.open().unwrap();
    let out = Output { volts: [2.0; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    d.exchange(&out, &mut inp).unwrap();
    assert_eq!(boards.lock().unwrap().motor_currents(), [0; crate::MAX_CHANNELS]);
    d.activate().unwrap();
    d.exchange(&out, &mut inp).unwrap();
    assert_eq!(boards.lock().unwrap().motor_currents()[0], 2482);
    d.deactivate().unwrap();
    assert_eq!(boards.lock().unwrap().motor_currents(), [0; crate::MAX_CHANNELS]);
}

#[test]
fn a_corrupt_reply_is_rejected_and_leaves_the_counters_as_they_were() {
    let (mut d, _, corrupt) = driver(vec![1, 1]);
    d.open().unwrap();
    let mut inp = Input::default();
    d.exchange(&Output::default(), &mut inp).unwrap();
    let before = inp;
    *corrupt.lock().unwrap() = true;
    let e = d.exchange(&Output::default(), &mut inp).unwrap_err();
    assert_eq!(e.kind(), crate::ErrorKind::Corrupt, "{e}");
    assert_eq!(inp, before);
    d.exchange(&Output::default(), &mut inp).unwrap();
}

#[test]
fn no_board_names_the_port_and_what_to_check() {
    // A link nobody answers on.
    struct Silent;
    impl ByteLink for Silent {
        fn write_all(&mut self, _: &[u8], _: Instant) -> Result<(), DeviceError> {
            Ok(())
        }
        fn read_exact(&mut self, _: &mut [u8], _: Instant) -> Result<(), DeviceError> {
            Err(DeviceError::Timeout { waited_us: 1 })
        }
        fn clear_input(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
    }
    struct SilentConn;
    impl Connector for SilentConn {
        type Link = Silent;
        fn connect(&mut self) -> Result<Silent, DeviceError> {
            Ok(Silent)
        }
        fn describe(&self) -> &str {
            "/dev/ttyTEST"
        }
    }
    let mut d = UartDevice::new(
        SilentConn,
        UartOptions { enumerate_timeout: Duration::from_millis(1), ..UartOptions::default() },
    );
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("/dev/ttyTEST") && msg.contains("powered"), "{msg}");
}

#[test]
fn exchange_allocates_nothing() {
    let (mut d, _, _) = driver(vec![1, 1]);
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    d.exchange(&out, &mut inp).unwrap(); // warm the fake board's buffers
    let n = crate::sim::tests::allocations_during(|| {
        for _ in 0..100 {
            d.exchange(&out, &mut inp).unwrap();
        }
    });
    assert_eq!(n, 0);
}
