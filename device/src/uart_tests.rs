//! The UART protocol byte by byte (`docs/protocols.md`), and the driver against the emulator's
//! boards in-process (a fake transport that plays the boards' side with the firmware's parser).
//! Above both `uart` and `emulator` (and `discover`'s probe report), so neither module's tests
//! import the other: the crate's modules import each other in one direction only.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::DVec3;

use crate::emulator::{Boards, EmulatorOptions, PlantClock};
use crate::sim::{Script, SimRig, SimRigParams};
use crate::transport::ByteTransport;
use crate::uart::protocol::*;
use crate::uart::*;
use crate::{Device, DeviceError, Input, Output};

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
    let b5 = decode_info_reply(0, &[0x08, 7, 12, 8, 0, 4, 0]).unwrap();
    assert_eq!((b5.model_name(), b5.n_motor, b5.n_force), ("B5M", 8, 4));
    // Wrong header, model 0, no motors, a short reply: all rejected.
    assert!(matches!(decode_info_reply(1, &[0x0A, 5, 12, 4, 4, 0, 0]), Err(FrameError::Header { .. })));
    assert_eq!(decode_info_reply(2, &[0x0A, 0, 12, 4, 0, 0, 0]), Err(FrameError::NotABoard));
    assert_eq!(decode_info_reply(2, &[0x0A, 1, 12, 0, 0, 0, 0]), Err(FrameError::NotABoard));
    assert!(matches!(decode_info_reply(2, &[0x0A, 1, 12, 4]), Err(FrameError::Short { need: 7, got: 4 })));
}

/// Every model's command-length table, ids 0..11, worked out by hand from the firmware's
/// command layouts (docs/protocols.md).
const TABLES: [(&str, [u8; COMMANDS]); 7] = [
    ("B1M", [1, 1, 13, 21, 1, 17, 9, 12, 12, 18, 3, 2]),
    ("B1F", [1, 1, 13, 23, 1, 13, 7, 10, 22, 14, 3, 2]),
    ("B2M", [1, 1, 13, 21, 1, 17, 9, 12, 12, 18, 3, 2]),
    ("B2F", [1, 1, 13, 23, 1, 13, 7, 10, 22, 14, 3, 2]),
    ("B3M", [1, 1, 13, 21, 1, 17, 9, 12, 12, 18, 3, 2]),
    ("B3F", [1, 1, 13, 23, 1, 13, 7, 10, 22, 14, 3, 2]),
    ("B5M", [1, 1, 13, 85, 1, 33, 17, 20, 84, 34, 3, 2]),
];

#[test]
fn set_command_lengths_carries_every_models_real_table_byte_for_byte() {
    for (id, (name, table)) in TABLES.iter().enumerate() {
        let model = BoardInfo::model_by_name(name).unwrap();
        let b = BoardInfo::of_model(id as u8, model).unwrap();
        let mut buf = [0xEEu8; SET_CMD_LEN_LEN];
        assert_eq!(encode_set_command_lengths(&b, &mut buf), 13);
        assert_eq!(buf[0], (2 << 3) | id as u8, "{name}");
        assert_eq!(&buf[1..], table, "{name}");
        assert!(buf[1..].iter().all(|&l| l > 0), "{name}: a declared 0 locks every board");
    }
}

#[test]
fn command_lengths_are_never_zero_for_any_board_the_driver_accepts() {
    let mut checked = 0;
    for m in 0..=255u8 {
        for c in 0..=16u8 {
            for f in 0..=16u8 {
                let b = BoardInfo {
                    id: 0,
                    model: 9,
                    n_target: 12,
                    n_motor: m,
                    n_current: c,
                    n_force: f,
                    n_touch: 0,
                };
                if b.is_present() {
                    let l = b.command_lengths();
                    assert!(l.iter().all(|&x| x > 0), "{b:?}: {l:?}");
                    assert_eq!(usize::from(l[usize::from(cmd::CURRENT)]), b.current_cmd_len());
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 500, "{checked}");
}

/// Reply lengths of every model in both firmware generations.
const REPLY_LENS: [(&str, usize, usize); 7] = [
    ("B1M", 17, 17),
    ("B1F", 17, 13),
    ("B2M", 17, 17),
    ("B2F", 17, 13),
    ("B3M", 17, 25),
    ("B3F", 17, 19),
    ("B5M", 41, 33),
];

#[test]
fn reply_lengths_of_every_model_in_both_firmware_generations() {
    for (name, forces, currents) in REPLY_LENS {
        let b = BoardInfo::of_model(0, BoardInfo::model_by_name(name).unwrap()).unwrap();
        assert_eq!(b.current_reply_len(ReplyLayout::Forces), forces, "{name}");
        assert_eq!(b.current_reply_len(ReplyLayout::Currents), currents, "{name}");
    }
    // Padding: max(5, reply - cmd + 20).
    let b1m = BoardInfo::of_model(0, 1).unwrap();
    let b3m = BoardInfo::of_model(0, 5).unwrap();
    assert_eq!(b1m.current_padding(ReplyLayout::Forces), 28);
    assert_eq!(b3m.current_padding(ReplyLayout::Forces), 28);
    assert_eq!(b3m.current_padding(ReplyLayout::Currents), 36);
}

#[test]
fn current_command_is_header_then_little_endian_i16_then_padding() {
    let b = BoardInfo::of_model(0, 1).unwrap();
    let mut buf = [0xEEu8; 64];
    let n = encode_current(&b, ReplyLayout::Forces, &[1, -1, 1024, -1024], &mut buf).unwrap();
    assert_eq!(n, 9 + 28);
    assert_eq!(&buf[..9], &[0x30, 0x01, 0x00, 0xFF, 0xFF, 0x00, 0x04, 0x00, 0xFC]);
    assert!(buf[9..n].iter().all(|&b| b == 0));
    assert_eq!(buf[n], 0xEE, "nothing written past the frame");
}

#[test]
fn volts_become_digits_clamped_to_the_commands_range() {
    assert_eq!(volts_to_digits(1.0, HOST_DIGITS_PER_VOLT, CURRENT_MAX), 1241);
    assert_eq!(volts_to_digits(3.3, HOST_DIGITS_PER_VOLT, CURRENT_MAX), 4095);
    assert_eq!(volts_to_digits(-100.0, HOST_DIGITS_PER_VOLT, CURRENT_MAX), -4095);
    // A PWM duty stops at 100 %: 0.825 V of the lab's scale.
    assert_eq!(volts_to_digits(0.825, HOST_DIGITS_PER_VOLT, PWM_FULL), 1024);
    assert_eq!(volts_to_digits(3.3, HOST_DIGITS_PER_VOLT, PWM_FULL), 1024);
    assert_eq!(volts_to_digits(f64::NAN, HOST_DIGITS_PER_VOLT, PWM_FULL), 0);
}

#[test]
fn both_reply_layouts_decode_byte_for_byte() {
    let b3m = BoardInfo::of_model(1, 5).unwrap();
    let words = |ws: &[i16]| {
        let mut v = vec![0x31u8];
        for w in ws {
            v.extend_from_slice(&w.to_le_bytes());
        }
        v
    };
    // Since 2021-08: positions, velocities, no force sensors on a B3M: 17 bytes.
    let forces = words(&[100, -2, 32767, -32768, 1, 2, 3, 4]);
    assert_eq!(forces.len(), 17);
    let r = decode_current_reply(&b3m, ReplyLayout::Forces, &forces).unwrap();
    assert_eq!(&r.positions[..4], &[100, -2, 32767, -32768]);
    assert_eq!(&r.velocities[..4], &[1, 2, 3, 4]);
    assert_eq!(r.sensors, [0; MAX_SENSORS]);
    // 2020-21: the four currents follow: 25 bytes.
    let currents = words(&[100, -2, 32767, -32768, 1, 2, 3, 4, 10, 20, 30, 40]);
    assert_eq!(currents.len(), 25);
    let r2 = decode_current_reply(&b3m, ReplyLayout::Currents, &currents).unwrap();
    assert_eq!(&r2.sensors[..4], &[10, 20, 30, 40]);
    for (layout, bytes, r) in [(ReplyLayout::Forces, &forces, r), (ReplyLayout::Currents, &currents, r2)] {
        let mut again = [0u8; 64];
        let n = encode_current_reply(&b3m, layout, &r, &mut again).unwrap();
        assert_eq!(&again[..n], &bytes[..]);
    }
    // Each layout refuses the other's length, and a wrong header.
    assert!(decode_current_reply(&b3m, ReplyLayout::Forces, &currents).is_err());
    assert!(decode_current_reply(&b3m, ReplyLayout::Currents, &forces).is_err());
    let mut bad = forces.clone();
    bad[0] = 0x30;
    assert!(matches!(
        decode_current_reply(&b3m, ReplyLayout::Forces, &bad),
        Err(FrameError::Header { want: 0x31, got: 0x30 })
    ));
    // A B1F (3 motors, 2 force sensors) since 2021-08: the forces follow the velocities.
    let b1f = BoardInfo::of_model(0, 2).unwrap();
    let mut v = vec![0x30u8];
    for w in [7i16, 8, 9, 0, 0, 0, -5, 6] {
        v.extend_from_slice(&w.to_le_bytes());
    }
    let r = decode_current_reply(&b1f, ReplyLayout::Forces, &v).unwrap();
    assert_eq!((&r.positions[..3], &r.sensors[..2]), (&[7i16, 8, 9][..], &[-5i16, 6][..]));
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
fn the_boards_parser_takes_each_command_by_its_declared_length_as_the_firmware_does() {
    let b = BoardInfo::of_model(0, 1).unwrap();
    let mut p = BoardParser::new(&b);
    let mut buf = [0u8; 64];
    let n = encode_current(&b, ReplyLayout::Forces, &[5, 6, 7, 8], &mut buf).unwrap();
    let steps: Vec<ParseStep> = buf[..n].iter().map(|&x| p.push(x)).collect();
    assert_eq!(steps[0].reply_to, Some(cmd::CURRENT), "the reply starts at the header");
    let done: Vec<HostCommand> = steps.iter().filter_map(|s| s.done).collect();
    assert_eq!(done, vec![HostCommand::Current { board: 0, commands: [5, 6, 7, 8, 0, 0, 0, 0] }]);
    // Another board's command is skipped by its length, whatever its bytes.
    for x in [header(cmd::CURRENT, 3), 0x30, 0x30, 0x30, 0x30, 0x30, 0x30, 0x30, 0x30] {
        assert_eq!(p.push(x), ParseStep::default());
    }
    // A header with a command id of 12 or more is not a header.
    assert_eq!(p.push(12 << 3), ParseStep::default());
    assert_eq!(p.skipped, 1);
    let s = p.push(header(cmd::BOARD_INFO, 0));
    assert_eq!((s.reply_to, s.done), (Some(cmd::BOARD_INFO), Some(HostCommand::BoardInfo { board: 0 })));
    assert!(!p.is_locked());
}

#[test]
fn a_declared_length_of_zero_locks_the_parser_for_good() {
    let b = BoardInfo::of_model(0, 1).unwrap();
    let mut p = BoardParser::new(&b);
    // Board 2's table with DIRECT declared 0 (what the old driver sent for unused commands).
    let mut lens = BoardInfo::of_model(2, 1).unwrap().command_lengths();
    lens[usize::from(cmd::DIRECT)] = 0;
    let mut frame = vec![header(cmd::SET_CMD_LEN, 2)];
    frame.extend_from_slice(&lens);
    for x in frame {
        p.push(x);
    }
    assert_eq!(p.table(2), lens, "every board stores every board's table");
    assert!(!p.is_locked());
    // One stray byte that forms that header: board 0's parser is gone.
    p.push(header(cmd::DIRECT, 2));
    assert!(p.is_locked());
    let mut zero = [0u8; 64];
    let n = encode_current(&b, ReplyLayout::Forces, &[0; 4], &mut zero).unwrap();
    for _ in 0..100 {
        for &x in &zero[..n] {
            assert_eq!(p.push(x), ParseStep::default(), "nothing is heard again");
        }
        let s = p.push(header(cmd::BOARD_INFO, 0));
        assert_eq!(s, ParseStep::default());
    }
    assert!(p.is_locked());
}

// ---------------------------------------------------------------------------------------------
// The driver against the emulator's boards, in-process.

/// A fault the loopback applies to the next write.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Fault {
    #[default]
    None,
    /// Flip the first byte of the replies.
    Corrupt,
    /// Hand only the first `n` bytes to the boards, then report a timeout.
    CutWrite(usize),
    /// Hold the replies back; they arrive after the next write's `clear_input`.
    Late,
}

/// A byte link straight into `Boards` (no pty): what the host writes is fed to the boards at
/// once, their replies wait in a queue. Records every write.
struct Loopback {
    boards: Arc<Mutex<Boards>>,
    rx: VecDeque<u8>,
    out: Vec<u8>,
    ticks: Vec<(usize, usize)>,
    fault: Arc<Mutex<Fault>>,
    held: Vec<u8>,
    written: Arc<Mutex<Vec<Vec<u8>>>>,
    recording: Arc<std::sync::atomic::AtomicBool>,
}

impl ByteTransport for Loopback {
    fn write_all(&mut self, bytes: &[u8], _deadline: Instant) -> Result<(), DeviceError> {
        self.out.clear();
        self.ticks.clear();
        // Replies held back from the last write arrive now, after this tick's clear.
        self.rx.extend(self.held.drain(..));
        let fault = std::mem::take(&mut *self.fault.lock().unwrap());
        let sent = match fault {
            Fault::CutWrite(n) => &bytes[..n.min(bytes.len())],
            _ => bytes,
        };
        if self.recording.load(std::sync::atomic::Ordering::SeqCst) {
            self.written.lock().unwrap().push(sent.to_vec());
        }
        self.boards.lock().unwrap().feed(sent, Instant::now(), &mut self.out, &mut self.ticks);
        match fault {
            Fault::Corrupt if !self.out.is_empty() => self.out[0] ^= 0xFF,
            Fault::Late => {
                self.held.extend(self.out.iter());
                return Ok(());
            }
            Fault::CutWrite(_) => {
                self.rx.extend(self.out.iter());
                return Err(DeviceError::Timeout { waited_us: 800 });
            }
            _ => {}
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
    fault: Arc<Mutex<Fault>>,
    written: Arc<Mutex<Vec<Vec<u8>>>>,
    recording: Arc<std::sync::atomic::AtomicBool>,
}

impl Connector for LoopConnector {
    type Link = Loopback;
    fn connect(&mut self) -> Result<Loopback, DeviceError> {
        Ok(Loopback {
            boards: self.boards.clone(),
            rx: VecDeque::with_capacity(1024),
            out: Vec::with_capacity(1024),
            ticks: Vec::with_capacity(16),
            fault: self.fault.clone(),
            held: Vec::with_capacity(1024),
            written: self.written.clone(),
            recording: self.recording.clone(),
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

struct Rigged {
    dev: UartDevice<LoopConnector>,
    boards: Arc<Mutex<Boards>>,
    fault: Arc<Mutex<Fault>>,
    written: Arc<Mutex<Vec<Vec<u8>>>>,
    recording: Arc<std::sync::atomic::AtomicBool>,
}

fn rigged(models: Vec<u8>, layout: ReplyLayout) -> Rigged {
    let opts = EmulatorOptions { models, plant: PlantClock::PerTick, layout, ..Default::default() };
    let boards = Arc::new(Mutex::new(Boards::new(lab_rig(), opts).unwrap()));
    let fault = Arc::new(Mutex::new(Fault::None));
    let written = Arc::new(Mutex::new(Vec::new()));
    let recording = Arc::new(std::sync::atomic::AtomicBool::new(true));
    let conn = LoopConnector {
        boards: boards.clone(),
        fault: fault.clone(),
        written: written.clone(),
        recording: recording.clone(),
    };
    Rigged { dev: UartDevice::new(conn, UartOptions::default()), boards, fault, written, recording }
}

fn driver(models: Vec<u8>) -> (UartDevice<LoopConnector>, Arc<Mutex<Boards>>, Arc<Mutex<Fault>>) {
    let r = rigged(models, ReplyLayout::Forces);
    (r.dev, r.boards, r.fault)
}

#[test]
fn driver_enumerates_the_boards_and_numbers_channels_in_board_order() {
    let (mut d, _, _) = driver(vec![1, 5]);
    d.open().unwrap();
    assert_eq!(d.boards().len(), 2);
    assert_eq!(d.boards()[1].model_name(), "B3M");
    assert_eq!(d.info().channels, 8);
    assert_eq!(d.info().board.as_str(), "UART B1M#0+B3M#1");
    assert_eq!(d.command_kind(0), Some(CommandKind::PwmDuty));
    assert_eq!(d.command_kind(4), Some(CommandKind::CurrentTarget));
    // The B1M's PWM duty stops at 1024 digits: 0.825 V of the lab's scale; the narrower range
    // is the device's.
    assert!((d.channel_volts_max(0).unwrap() - 0.825).abs() < 1e-3);
    assert!((d.channel_volts_max(4).unwrap() - 3.299).abs() < 1e-3);
    assert!((d.info().volts_max - 0.825).abs() < 1e-3);
    assert!(
        d.warnings().iter().any(|w| w.contains("with and without current sensors")),
        "{:?}",
        d.warnings()
    );
}

#[test]
fn the_driver_declares_only_real_lengths_and_every_board_stores_them() {
    let r = rigged(vec![1, 7, 6], ReplyLayout::Forces);
    let mut d = r.dev;
    d.open().unwrap();
    let boards = r.boards.lock().unwrap();
    for p_id in 0..3u8 {
        let p = boards.parser(p_id).unwrap();
        for b in d.boards() {
            assert_eq!(p.table(b.id), b.command_lengths(), "board {p_id}'s table for id {}", b.id);
        }
    }
    assert_eq!(boards.locked(), 0);
    assert_eq!(boards.stats().length_tables, 3);
}

#[test]
fn the_driver_measures_each_boards_reply_layout_in_both_firmware_generations() {
    for layout in ReplyLayout::ALL {
        for models in [vec![1, 1], vec![5, 5], vec![2, 6], vec![7]] {
            let r = rigged(models.clone(), layout);
            let mut d = r.dev;
            d.open_detailed().unwrap_or_else(|e| panic!("{models:?} {layout:?}: {e}"));
            // Where both layouts have the same length (no sensors either way) either is right.
            for (b, l) in d.boards().iter().zip(d.layouts()) {
                assert_eq!(b.current_reply_len(*l), b.current_reply_len(layout), "{models:?} {layout:?}");
            }
            d.activate().unwrap();
            let mut inp = Input::default();
            let out = Output { volts: [0.1; crate::MAX_CHANNELS] };
            for _ in 0..20 {
                d.exchange(&out, &mut inp).unwrap_or_else(|e| panic!("{models:?} {layout:?}: {e}"));
            }
            assert_eq!(d.stats().failed, 0);
        }
    }
}

/// A board that answers the enumeration as a B3M and the current command with `reply_len`
/// bytes (None: not at all).
struct OddBoard {
    reply_len: Option<usize>,
    rx: VecDeque<u8>,
}

impl ByteTransport for OddBoard {
    fn write_all(&mut self, bytes: &[u8], _: Instant) -> Result<(), DeviceError> {
        for &b in bytes {
            if b == header(cmd::BOARD_INFO, 0) {
                self.rx.extend([0x08, 5, 12, 4, 4, 0, 0]);
            }
            if b == header(cmd::CURRENT, 0) {
                if let Some(n) = self.reply_len {
                    self.rx.push_back(b);
                    self.rx.extend(std::iter::repeat_n(0u8, n - 1));
                }
            }
        }
        Ok(())
    }
    fn read_exact(&mut self, buf: &mut [u8], _: Instant) -> Result<(), DeviceError> {
        if self.rx.len() < buf.len() {
            return Err(DeviceError::Timeout { waited_us: 1 });
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

struct OddConn(Option<usize>);

impl Connector for OddConn {
    type Link = OddBoard;
    fn connect(&mut self) -> Result<OddBoard, DeviceError> {
        Ok(OddBoard { reply_len: self.0, rx: VecDeque::new() })
    }
    fn describe(&self) -> &str {
        "/dev/ttyODD"
    }
}

fn open_odd(reply_len: Option<usize>) -> Result<UartDevice<OddConn>, String> {
    let opts = UartOptions { enumerate_timeout: Duration::from_millis(1), ..UartOptions::default() };
    let mut d = UartDevice::new(OddConn(reply_len), opts);
    d.open_detailed().map_err(|e| e.to_string())?;
    Ok(d)
}

#[test]
fn an_unknown_reply_layout_or_no_reply_fails_the_open_with_what_was_seen() {
    // The fake is right for both known layouts of a B3M (17 and 25 bytes)...
    assert_eq!(open_odd(Some(17)).unwrap().layouts(), &[ReplyLayout::Forces]);
    assert_eq!(open_odd(Some(25)).unwrap().layouts(), &[ReplyLayout::Currents]);
    // ... and a 21-byte reply is neither.
    let msg = open_odd(Some(21)).err().unwrap();
    assert!(
        msg.contains("board id 0 (B3M)") && msg.contains("17 bytes") && msg.contains("25 bytes"),
        "{msg}"
    );
    let msg = open_odd(None).err().unwrap();
    assert!(msg.contains("board id 0 (B3M)") && msg.contains("not a zero current command"), "{msg}");
}

#[test]
fn driver_reads_the_same_counts_and_drives_the_same_tensions_as_the_rig_in_process() {
    let (mut d, boards, _) = driver(vec![5, 5]); // current targets: no PWM clipping below 3.3 V
    let mut reference = lab_rig();
    d.open().unwrap();
    d.activate().unwrap();
    reference.open().unwrap();
    reference.activate().unwrap();
    // The open's layout measurement completed one servo tick: the emulated plant is one period ahead.
    reference.exchange(&Output::default(), &mut Input::default()).unwrap();
    let mut out = Output::default();
    for ch in 0..8 {
        out.volts[ch] = 0.2 * (1.0 + ch as f64); // 1 .. 8 N at 0.2 V/N
    }
    let (mut a, mut b) = (Input::default(), Input::default());
    for _ in 0..200 {
        d.exchange(&out, &mut a).unwrap();
        reference.exchange(&out, &mut b).unwrap();
        // The command is quantised (4 mN steps), so the two plants may differ by a count.
        for ch in 0..8 {
            assert!((a.counts[ch] - b.counts[ch]).abs() <= 2, "{:?} vs {:?}", a.counts, b.counts);
        }
    }
    let emu = *boards.lock().unwrap().rig().truth();
    let inproc = *reference.truth();
    for h in 0..2 {
        for s in 0..4 {
            let (x, y) = (emu.hands[h].tension_n[s], inproc.hands[h].tension_n[s]);
            // One digit is 3.3 / 4096 V = 4 mN at 0.2 V/N.
            assert!((x - y).abs() < 0.005, "hand {h} string {s}: {x} vs {y}");
        }
    }
    assert!(emu.hands[0].pos_m.distance(inproc.hands[0].pos_m) < 1e-4);
}

#[test]
fn a_pwm_board_clips_at_full_duty_and_a_current_board_does_not() {
    let (mut d, boards, _) = driver(vec![1, 5]);
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [2.0; crate::MAX_CHANNELS] }; // 10 N at 0.2 V/N
    let mut inp = Input::default();
    for _ in 0..50 {
        d.exchange(&out, &mut inp).unwrap();
    }
    let b = boards.lock().unwrap();
    assert_eq!(&b.motor_commands()[..8], &[1024, 1024, 1024, 1024, 2482, 2482, 2482, 2482]);
    let t = b.rig().truth();
    // Full duty is 1024 / (4096 / 3.3) = 0.825 V: 4.125 N, not 10.
    assert!((t.hands[0].tension_n[0] - 4.125).abs() < 0.01, "{:?}", t.hands[0].tension_n);
    assert!((t.hands[1].tension_n[0] - 10.0).abs() < 0.01, "{:?}", t.hands[1].tension_n);
}

#[test]
fn inactive_driver_commands_zero_and_deactivate_zeroes_at_once() {
    let (mut d, boards, _) = driver(vec![1, 1]);
    d.open().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    d.exchange(&out, &mut inp).unwrap();
    assert_eq!(boards.lock().unwrap().motor_commands(), [0; crate::MAX_CHANNELS]);
    d.activate().unwrap();
    d.exchange(&out, &mut inp).unwrap();
    assert_eq!(boards.lock().unwrap().motor_commands()[0], 621);
    d.deactivate().unwrap();
    assert_eq!(boards.lock().unwrap().motor_commands(), [0; crate::MAX_CHANNELS]);
}

#[test]
fn deactivate_after_a_cut_write_still_gets_the_zero_to_the_boards() {
    let (mut d, boards, fault) = driver(vec![1, 1]);
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    d.exchange(&out, &mut Input::default()).unwrap();
    *fault.lock().unwrap() = Fault::CutWrite(3);
    let _ = d.deactivate();
    assert_eq!(boards.lock().unwrap().motor_commands(), [0; crate::MAX_CHANNELS]);
    assert_eq!(boards.lock().unwrap().locked(), 0);
}

#[test]
fn a_corrupt_reply_is_rejected_and_leaves_the_counters_as_they_were() {
    let (mut d, _, fault) = driver(vec![1, 1]);
    d.open().unwrap();
    let mut inp = Input::default();
    d.exchange(&Output::default(), &mut inp).unwrap();
    let before = inp;
    *fault.lock().unwrap() = Fault::Corrupt;
    let e = d.exchange(&Output::default(), &mut inp).unwrap_err();
    assert_eq!(e.kind(), crate::ErrorKind::Corrupt, "{e}");
    assert_eq!(inp, before);
    d.exchange(&Output::default(), &mut inp).unwrap();
}

/// The bytes of one normal tick for `boards` (all commands zero), board-info request last.
fn tick_frame(boards: &[BoardInfo], info_first: bool) -> Vec<u8> {
    let mut v = Vec::new();
    if info_first {
        v.push(header(cmd::BOARD_INFO, boards[0].id));
        v.extend([0u8; INFO_TRAIL_ZEROS]);
    }
    for b in boards {
        let mut buf = [0u8; 128];
        let n = encode_current(b, ReplyLayout::Forces, &[0; 8], &mut buf).unwrap();
        v.extend_from_slice(&buf[..n]);
    }
    if !info_first {
        v.push(header(cmd::BOARD_INFO, boards[0].id));
        v.extend([0u8; TICK_END_ZEROS]);
    }
    v
}

#[test]
fn a_tick_writes_every_command_and_the_board_info_request_and_reads_its_reply_in_the_tick() {
    let r = rigged(vec![1, 1], ReplyLayout::Forces);
    let mut d = r.dev;
    d.open().unwrap();
    r.written.lock().unwrap().clear();
    d.exchange(&Output::default(), &mut Input::default()).unwrap();
    let w = r.written.lock().unwrap().clone();
    assert_eq!(w, vec![tick_frame(d.boards(), false)]);
    assert_eq!(w[0].len(), 2 * (9 + 28) + 6);
    // Nothing of this tick is left to arrive in the next one: the board-info reply was read.
    let link = d.link.as_ref().unwrap();
    assert!(link.rx.is_empty(), "{} bytes left over", link.rx.len());
}

#[test]
fn after_a_write_cut_short_the_next_frame_starts_with_40_zeros_and_the_boards_parse_it() {
    let r = rigged(vec![1, 1], ReplyLayout::Forces);
    let mut d = r.dev;
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    d.exchange(&out, &mut Input::default()).unwrap();
    r.written.lock().unwrap().clear();
    // The write stops in the middle of board 0's command: its parser waits for 5 more bytes.
    *r.fault.lock().unwrap() = Fault::CutWrite(4);
    let e = d.exchange(&out, &mut Input::default()).unwrap_err();
    assert_eq!(e.kind(), crate::ErrorKind::Timeout);
    d.deactivate().unwrap(); // commands zero from here
    let w = r.written.lock().unwrap().clone();
    assert_eq!(w.len(), 2);
    // The second write: 40 zeros, then the frame (board-info request first after a failure).
    let mut want = vec![0u8; RESYNC_ZEROS];
    want.extend(tick_frame(d.boards(), true));
    assert_eq!(w[1], want);
    assert_eq!(d.stats().resyncs, 1);
    let b = r.boards.lock().unwrap();
    assert_eq!(b.locked(), 0);
    assert_eq!(b.motor_commands(), [0; crate::MAX_CHANNELS], "the zero reached every motor");
    drop(b);
    // Without the zeros the same bytes leave board 0 taking the board-info request as payload.
    let mut fresh =
        Boards::new(lab_rig(), EmulatorOptions { plant: PlantClock::PerTick, ..Default::default() }).unwrap();
    let (mut o, mut t) = (Vec::new(), Vec::new());
    fresh.feed(&w[0], Instant::now(), &mut o, &mut t);
    o.clear();
    fresh.feed(&tick_frame(d.boards(), true), Instant::now(), &mut o, &mut t);
    assert!(!o.starts_with(&[header(cmd::BOARD_INFO, 0)]), "the board-info request was swallowed: {o:02x?}");
}

#[test]
fn a_late_reply_frame_is_never_taken_as_the_next_ticks() {
    let (mut d, boards, fault) = driver(vec![1, 1]);
    d.open().unwrap();
    d.activate().unwrap();
    let mut inp = Input::default();
    for _ in 0..5 {
        d.exchange(&Output::default(), &mut inp).unwrap();
    }
    // The hand moves under a command; the replies of this tick come late.
    let out =
        Output { volts: [0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] };
    *fault.lock().unwrap() = Fault::Late;
    assert_eq!(d.exchange(&out, &mut inp).unwrap_err().kind(), crate::ErrorKind::Timeout);
    let before = inp;
    // They arrive during the next tick, after its clear: recognised by their order, rejected.
    let e = d.exchange(&out, &mut inp).unwrap_err();
    assert!(e.to_string().contains("late reply"), "{e}");
    assert_eq!(inp, before, "nothing of the late frame was taken");
    assert_eq!(d.stats().late_frames, 1);
    // The tick after reads its own replies again: the counts the boards have now.
    d.exchange(&out, &mut inp).unwrap();
    let mut truth = Input::default();
    boards.lock().unwrap().rig_mut().sample(&mut truth).unwrap();
    // The driver's reading was sampled one plant period before this fresh one.
    for ch in 0..8 {
        assert!((inp.counts[ch] - truth.counts[ch]).abs() <= 40, "{:?} vs {:?}", inp.counts, truth.counts);
    }
}

#[test]
fn no_board_names_the_port_and_what_to_check() {
    // A link nobody answers on.
    struct Silent;
    impl ByteTransport for Silent {
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
    assert!(msg.contains("/dev/ttyTEST") && msg.contains("powered") && msg.contains("power cycle"), "{msg}");
}

#[test]
fn boards_locked_by_a_zero_length_do_not_answer_and_the_open_says_to_power_cycle() {
    let (mut d, boards, _) = driver(vec![1, 1]);
    {
        let mut b = boards.lock().unwrap();
        let mut lens = BoardInfo::of_model(0, 1).unwrap().command_lengths();
        lens[usize::from(cmd::DIRECT)] = 0;
        let mut frame = vec![header(cmd::SET_CMD_LEN, 0)];
        frame.extend_from_slice(&lens);
        let (mut o, mut t) = (Vec::new(), Vec::new());
        b.feed(&frame, Instant::now(), &mut o, &mut t);
        assert_eq!(b.locked(), 0);
        b.feed(&[header(cmd::DIRECT, 0)], Instant::now(), &mut o, &mut t);
        assert_eq!(b.locked(), 0b11, "one header locks every board on the link");
    }
    d.opts.enumerate_timeout = Duration::from_millis(1);
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("power cycle"), "{msg}");
}

#[test]
fn the_probe_report_names_each_boards_model_layout_lengths_and_what_will_not_work() {
    let r = rigged(vec![5], ReplyLayout::Currents);
    let mut d = r.dev;
    d.open().unwrap();
    let rep = crate::discover::probe_report(&d);
    for want in [
        "UART boards: 1, 4 channels",
        "id 0 B3M: 4 motors (current target), 4 current sensors, 0 force sensors",
        "2020-21 (currents in the reply), reply 25 bytes",
        "ids 0..11: 1 1 13 21 1 17 9 12 12 18 3 2",
        "port: not a serial port",
        "warning: 4 motors: a SPIDAR-H needs 8",
    ] {
        assert!(rep.contains(want), "{want:?} missing from:\n{rep}");
    }
}

#[test]
fn exchange_allocates_nothing() {
    let r = rigged(vec![1, 1], ReplyLayout::Forces);
    r.recording.store(false, std::sync::atomic::Ordering::SeqCst);
    let mut d = r.dev;
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

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]

    /// Whatever boards are on the link (any models, up to 16 motors, either firmware), the
    /// driver declares no 0 in any table, every board ends up with every board's real table, no
    /// board is ever locked, and every tick is taken.
    #[test]
    fn the_driver_never_sends_a_table_with_a_zero(
        models in proptest::collection::vec(1u8..=7, 1..=8),
        currents in proptest::bool::ANY,
    ) {
        let motors: usize = models.iter().map(|m| usize::from(BoardInfo::of_model(0, *m).unwrap().n_motor)).sum();
        proptest::prop_assume!(motors <= crate::MAX_CHANNELS);
        let layout = if currents { ReplyLayout::Currents } else { ReplyLayout::Forces };
        let r = rigged(models.clone(), layout);
        let mut d = r.dev;
        d.open().unwrap();
        d.activate().unwrap();
        let mut inp = Input::default();
        for _ in 0..5 {
            d.exchange(&Output { volts: [0.1; crate::MAX_CHANNELS] }, &mut inp).unwrap();
        }
        // Every "set command lengths" the driver wrote (found by its header and 13-byte size
        // in the writes of the open), and what the boards made of them.
        let written = r.written.lock().unwrap();
        let mut tables = 0;
        for w in written.iter() {
            if w.len() == SET_CMD_LEN_LEN && split_header(w[0]).0 == cmd::SET_CMD_LEN {
                proptest::prop_assert!(w[1..].iter().all(|&l| l > 0), "{:?}", w);
                tables += 1;
            }
        }
        proptest::prop_assert_eq!(tables, models.len());
        let b = r.boards.lock().unwrap();
        proptest::prop_assert_eq!(b.locked(), 0);
        for id in 0..models.len() as u8 {
            for other in d.boards() {
                proptest::prop_assert_eq!(b.parser(id).unwrap().table(other.id), other.command_lengths());
            }
        }
    }
}

#[test]
fn a_takeover_on_known_boards_zeroes_them_without_enumerating_even_after_a_cut_write() {
    let r = rigged(vec![1, 5], ReplyLayout::Currents);
    let mut d = r.dev;
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    d.exchange(&out, &mut Input::default()).unwrap();
    // The process dies in the middle of a write: board 0's parser waits for the rest.
    *r.fault.lock().unwrap() = Fault::CutWrite(4);
    let _ = d.exchange(&out, &mut Input::default());
    assert_ne!(r.boards.lock().unwrap().motor_commands(), [0; crate::MAX_CHANNELS]);
    let (boards, layouts) = (d.boards().to_vec(), d.layouts().to_vec());
    drop(d);
    let before = r.boards.lock().unwrap().stats();
    // Another process (the supervisor) with what the first one found.
    let conn = LoopConnector {
        boards: r.boards.clone(),
        fault: r.fault.clone(),
        written: r.written.clone(),
        recording: r.recording.clone(),
    };
    let mut t = UartDevice::new(conn, UartOptions::default());
    t.open_known(&boards, &layouts).unwrap();
    assert_eq!(t.info().board.as_str(), "UART B1M#0+B3M#1");
    assert_eq!(t.info().channels, 8);
    t.deactivate().unwrap();
    let b = r.boards.lock().unwrap();
    assert_eq!(b.motor_commands(), [0; crate::MAX_CHANNELS], "the zero reached every motor");
    assert_eq!(b.locked(), 0);
    let after = b.stats();
    assert_eq!(after.length_tables, before.length_tables, "no length tables sent again");
    // One board-info request marks the tick's frame; an enumeration would ask every id.
    assert_eq!(after.info_requests - before.info_requests, 1, "no enumeration");
}

#[test]
fn a_takeover_refuses_a_board_list_it_cannot_drive() {
    let (mut d, _, _) = driver(vec![1]);
    let b = BoardInfo::of_model(0, 1).unwrap();
    assert!(d.open_known(&[], &[]).is_err());
    assert!(d.open_known(&[b], &[]).is_err(), "a layout per board");
    assert!(d.open_known(&[b; 9], &[ReplyLayout::Forces; 9]).is_err());
    assert!(d.exchange(&Output::default(), &mut Input::default()).is_err(), "not opened");
}
