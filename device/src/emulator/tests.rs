//! The emulated boards as the firmware behaves (in-process, with made-up instants: no wall
//! clock), and the emulator on a real pseudo-terminal driven by the real UART driver: each fault
//! is seen by the driver as the error kind the rt-loop reacts to.

use std::time::{Duration, Instant};

use glam::DVec3;

use super::*;
use crate::sim::{Script, SimRigParams};
use crate::uart::protocol::{encode_current, encode_set_command_lengths, header, SET_CMD_LEN_LEN};
use crate::uart::{UartDevice, UartOptions};
use crate::{DeviceError, ErrorKind};

fn lab_rig() -> SimRig {
    let p = SimRigParams::lab([DVec3::new(-0.15, 0.0, 0.0), DVec3::new(0.15, 0.0, 0.0)]);
    let holds = [Script::hold(p.hands[0].start_m), Script::hold(p.hands[1].start_m)];
    SimRig::new(p, holds).unwrap()
}

fn boards(models: Vec<u8>, plant: PlantClock) -> Boards {
    Boards::new(lab_rig(), EmulatorOptions { models, plant, ..Default::default() }).unwrap()
}

/// Feeds `bytes`; returns the boards' replies.
fn feed(b: &mut Boards, bytes: &[u8], now: Instant) -> Vec<u8> {
    let (mut out, mut ticks) = (Vec::new(), Vec::new());
    b.feed(bytes, now, &mut out, &mut ticks);
    out
}

/// One servo tick's current commands for every board (all motors at `cmd` digits).
fn tick(b: &Boards, cmds: &[i16]) -> Vec<u8> {
    let mut v = Vec::new();
    let mut ch = 0;
    for info in b.board_infos() {
        let n = usize::from(info.n_motor);
        let mut buf = [0u8; 128];
        let len = encode_current(info, ReplyLayout::Forces, &cmds[ch..ch + n], &mut buf).unwrap();
        v.extend_from_slice(&buf[..len]);
        ch += n;
    }
    v
}

/// One servo tick fed to the boards; returns their replies.
fn step(b: &mut Boards, cmds: &[i16], now: Instant) -> Vec<u8> {
    let frame = tick(b, cmds);
    feed(b, &frame, now)
}

fn declare_lengths(b: &mut Boards) {
    let infos: Vec<BoardInfo> = b.board_infos().copied().collect();
    for info in infos {
        let mut buf = [0u8; SET_CMD_LEN_LEN];
        encode_set_command_lengths(&info, &mut buf);
        feed(b, &buf, Instant::now());
    }
}

#[test]
fn a_declared_zero_locks_every_emulated_board_with_its_motors_on() {
    let mut b = boards(vec![1, 1], PlantClock::PerTick);
    declare_lengths(&mut b);
    let t0 = Instant::now();
    let on = tick(&b, &[500; 8]);
    assert_eq!(feed(&mut b, &on, t0).len(), 2 * 17, "both boards answer");
    assert_eq!(b.motor_commands()[..8], [500; 8]);
    // A table with one 0 (an unused command, as the old driver declared it) for board 1 ...
    let mut lens = BoardInfo::of_model(1, 1).unwrap().command_lengths();
    lens[usize::from(cmd::INTERPOLATE)] = 0;
    let mut frame = vec![header(cmd::SET_CMD_LEN, 1)];
    frame.extend_from_slice(&lens);
    feed(&mut b, &frame, t0);
    assert_eq!(b.locked(), 0);
    // ... and one misaligned byte that reads as that header: both boards are lost.
    feed(&mut b, &[header(cmd::INTERPOLATE, 1)], t0);
    assert_eq!(b.locked(), 0b11);
    // The zero sent at stop is never heard, nor anything after it: the motors keep 500.
    let stop = tick(&b, &[0; 8]);
    for _ in 0..50 {
        assert!(feed(&mut b, &stop, t0).is_empty(), "a locked board answers nothing");
        let mut enumerate = [0u8; crate::uart::protocol::INFO_REQUEST_LEN];
        crate::uart::protocol::encode_info_request(0, &mut enumerate);
        assert!(feed(&mut b, &enumerate, t0).is_empty());
    }
    assert_eq!(b.motor_commands()[..8], [500; 8]);
    assert!(b.rig().truth().hands[0].tension_n.iter().all(|t| *t > 2.0));
}

#[test]
fn each_board_skips_the_others_commands_by_their_declared_lengths() {
    // A B5M (8 motors, 17-byte command) next to a B1M (9-byte command): the B1M only parses the
    // B5M's command right once it has been told the B5M's lengths.
    // Real-time plant: a board takes its command at once (no waiting for a whole tick).
    let mut b = boards(vec![1, 7], PlantClock::RealTime);
    let b5m = *b.board_infos().nth(1).unwrap();
    let mut cmd = [0u8; 128];
    // Payload bytes that read as a B1M current header (0x30) if the B1M took the wrong length.
    let n = encode_current(&b5m, ReplyLayout::Forces, &[0x3030; 8], &mut cmd).unwrap();
    assert_eq!(b.parser(0).unwrap().table(1)[usize::from(cmd::CURRENT)], 9, "power-on: its own length");
    let before = b.stats().current_commands;
    feed(&mut b, &cmd[..n], Instant::now());
    assert!(b.stats().current_commands > before + 1, "the B1M took a payload byte for its own header");
    // Told the lengths, it skips the B5M's command whole.
    let mut b = boards(vec![1, 7], PlantClock::RealTime);
    declare_lengths(&mut b);
    assert_eq!(b.parser(0).unwrap().table(1), b5m.command_lengths());
    let before = b.stats().current_commands;
    let replies = feed(&mut b, &cmd[..n], Instant::now());
    assert_eq!(b.stats().current_commands, before + 1);
    assert_eq!(replies.len(), 41, "only the B5M answers, 41 bytes since 2021-08");
    assert_eq!(b.motor_commands()[4..12], [0x3030; 8]);
    assert_eq!(b.motor_commands()[..4], [0; 4]);
}

#[test]
fn the_boards_answer_in_the_layout_of_the_firmware_generation_chosen() {
    for (layout, len) in [(ReplyLayout::Forces, 17), (ReplyLayout::Currents, 25)] {
        let opts =
            EmulatorOptions { models: vec![5], plant: PlantClock::PerTick, layout, ..Default::default() };
        let mut b = Boards::new(lab_rig(), opts).unwrap();
        declare_lengths(&mut b);
        step(&mut b, &[300; 4], Instant::now());
        let r = step(&mut b, &[300; 4], Instant::now());
        assert_eq!(r.len(), len, "{layout:?}");
        let info = *b.board_infos().next().unwrap();
        let d = crate::uart::protocol::decode_current_reply(&info, layout, &r).unwrap();
        if layout == ReplyLayout::Currents {
            assert_eq!(&d.sensors[..4], &[300; 4], "the sensed currents reach the target");
        }
    }
}

#[test]
fn a_board_answers_with_the_counts_from_before_its_command_as_the_in_process_rig_does() {
    let mut b = boards(vec![1, 1], PlantClock::PerTick);
    declare_lengths(&mut b);
    let mut reference = lab_rig();
    reference.open().unwrap();
    reference.activate().unwrap();
    let info = *b.board_infos().next().unwrap();
    for k in 0..300 {
        let c = if k < 100 { 0 } else { 600 };
        let r = step(&mut b, &[c; 8], Instant::now());
        let d = crate::uart::protocol::decode_current_reply(&info, ReplyLayout::Forces, &r[..17]).unwrap();
        let mut inp = Input::default();
        let mut out = Output::default();
        out.volts[..8].fill(f64::from(c) / protocol::HOST_DIGITS_PER_VOLT);
        reference.exchange(&out, &mut inp).unwrap();
        assert_eq!(
            &d.positions[..4],
            &std::array::from_fn::<i16, 4, _>(|i| inp.counts[i] as i16),
            "tick {k}"
        );
    }
}

#[test]
fn no_watchdog_unless_asked_the_last_command_is_held() {
    let t0 = Instant::now();
    let mut b = boards(vec![1, 1], PlantClock::RealTime);
    declare_lengths(&mut b);
    step(&mut b, &[400; 8], t0);
    // The host goes silent for a minute of plant time: nothing changes on the boards.
    for k in 1..=60_000u64 {
        b.idle(t0 + Duration::from_millis(k));
    }
    assert_eq!(b.motor_commands()[..8], [400; 8]);
    assert!(!b.watchdog_tripped());
    assert_eq!(b.stats().watchdog_trips, 0);
    assert!(b.rig().truth().hands[0].tension_n.iter().all(|t| *t > 1.0));
    // The opt-in watchdog (experiments only) zeroes them after its time.
    let opts = EmulatorOptions { watchdog: Some(Duration::from_millis(50)), ..Default::default() };
    let mut w = Boards::new(lab_rig(), opts).unwrap();
    declare_lengths(&mut w);
    step(&mut w, &[400; 8], t0);
    w.idle(t0 + Duration::from_millis(40));
    assert!(!w.watchdog_tripped());
    w.idle(t0 + Duration::from_millis(60));
    assert!(w.watchdog_tripped());
    assert_eq!(w.motor_commands(), [0; MAX_CHANNELS]);
}

#[test]
fn pwm_is_clipped_at_full_duty_on_boards_without_current_sensors() {
    let mut b = boards(vec![1, 5], PlantClock::PerTick);
    declare_lengths(&mut b);
    for _ in 0..20 {
        step(&mut b, &[4095; 8], Instant::now());
    }
    let d = b.duties();
    assert_eq!(&d[..8], &[1.0; 8]);
    let t = b.rig().truth();
    // B1M (hand 0): 1024 digits = 0.825 V = 4.125 N; B3M (hand 1): 4095 digits = 3.3 V = 16.5 N.
    assert!(t.hands[0].tension_n.iter().all(|x| (x - 4.125).abs() < 1e-3), "{:?}", t.hands[0].tension_n);
    assert!(t.hands[1].tension_n.iter().all(|x| (x - 16.496).abs() < 1e-2), "{:?}", t.hands[1].tension_n);
}

#[test]
fn a_stalled_motor_at_full_duty_is_slowly_derated_and_one_at_low_duty_never() {
    let mut b = boards(vec![1, 1], PlantClock::PerTick);
    declare_lengths(&mut b);
    // Hand 0's strings at full duty, hand 1's at 40 %: the grips are held, the motors stall.
    let mut cmds = [1024i16; 8];
    cmds[4..].fill(410);
    let frame = tick(&b, &cmds);
    let mut limit_at = Vec::new();
    for k in 1..=50_000u32 {
        feed(&mut b, &frame, Instant::now());
        if k % 1000 == 0 {
            limit_at.push(b.heat()[0].duty_limit);
            assert_eq!(b.heat()[4].duty_limit, 1.0, "40 % duty never derates (t = {k} ms)");
        }
    }
    // Full for the first 5 s (heat below a quarter of the limit), then falling ...
    assert!(limit_at[..5].iter().all(|l| *l == 1.0), "{limit_at:?}");
    assert!(limit_at[10] < 1.0 && limit_at[10] > limit_at[20], "{limit_at:?}");
    // ... toward 50 %, where heating and release balance.
    let last = *limit_at.last().unwrap();
    assert!((last - 0.5).abs() < 0.05, "{limit_at:?}");
    assert!((b.duties()[0] - last).abs() < 0.01, "{} vs {last}", b.duties()[0]);
    assert!(b.rig().truth().hands[0].tension_n[0] < 0.6 * 4.125);
}

// ---------------------------------------------------------------------------------------------
// On a pseudo-terminal, through the real driver.

/// A link path of its own for each test (tests run in parallel).
fn link_path(name: &str) -> PathBuf {
    symlink::private_dir().unwrap().join(format!("emu-test-{}-{name}", std::process::id()))
}

fn start_with(name: &str, opts: EmulatorOptions) -> (Emulator, UartDevice<crate::uart::SerialPath>) {
    let emu = Emulator::spawn(lab_rig(), opts, &link_path(name)).unwrap();
    // Generous deadlines: these tests check behaviour, not this machine's latency.
    let uo = UartOptions { reply_timeout: Duration::from_millis(100), ..UartOptions::default() };
    let mut dev = UartDevice::on_port(emu.symlink().to_str().unwrap(), uo).unwrap();
    dev.open_detailed().unwrap();
    (emu, dev)
}

fn start(name: &str) -> (Emulator, UartDevice<crate::uart::SerialPath>) {
    start_with(name, EmulatorOptions { plant: PlantClock::PerTick, ..Default::default() })
}

/// Polls `f` until true, for at most 10 s (a safety net, not a timing assertion).
fn eventually(mut f: impl FnMut() -> bool) -> bool {
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    false
}

#[test]
fn driver_enumerates_two_b1m_boards_over_the_pty_and_drives_the_rig() {
    let (emu, mut dev) = start("basic");
    assert_eq!(dev.info().channels, 8);
    assert_eq!(dev.info().board.as_str(), "UART B1M#0+B1M#1");
    // A pty has no latency setting and no modem lines: not applicable, not a warning.
    let port = dev.port_report().unwrap();
    assert_eq!(port.low_latency, crate::transport::PortSetting::NotApplicable);
    assert_eq!(port.modem_lines_cleared, crate::transport::PortSetting::NotApplicable);
    assert!(dev.warnings().is_empty(), "{:?}", dev.warnings());
    dev.activate().unwrap();
    let out = Output { volts: [0.6; crate::MAX_CHANNELS] }; // 3 N on every string
    let mut inp = Input::default();
    for _ in 0..100 {
        dev.exchange(&out, &mut inp).unwrap();
    }
    let t = emu.control().truth();
    assert!((t.hands[0].tension_n[0] - 3.0).abs() < 0.01, "{:?}", t.hands[0].tension_n);
    // The open's layout measurement made one tick (both boards' current commands).
    assert_eq!(emu.control().stats().ticks, 101);
    assert!(inp.counts[..8].iter().any(|&c| c != 0));
}

#[test]
fn the_driver_meets_both_firmware_generations_and_b5m_boards_over_the_pty() {
    for (models, layout) in [(vec![5, 5], ReplyLayout::Currents), (vec![7], ReplyLayout::Forces)] {
        let opts = EmulatorOptions {
            models: models.clone(),
            plant: PlantClock::PerTick,
            layout,
            ..Default::default()
        };
        let (emu, mut dev) = start_with(&format!("gen-{}-{:?}", models.len(), layout), opts);
        assert!(dev.layouts().iter().all(|l| *l == layout), "{models:?}");
        dev.activate().unwrap();
        let mut inp = Input::default();
        for _ in 0..50 {
            dev.exchange(&Output { volts: [0.4; crate::MAX_CHANNELS] }, &mut inp).unwrap();
        }
        assert_eq!(emu.control().boards().locked(), 0);
        dev.deactivate().unwrap();
        assert_eq!(emu.control().boards().motor_commands(), [0; MAX_CHANNELS]);
    }
}

#[test]
fn exchange_over_the_pty_allocates_nothing() {
    let (_emu, mut dev) = start("alloc");
    dev.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    dev.exchange(&out, &mut inp).unwrap();
    let n = crate::sim::tests::allocations_during(|| {
        for _ in 0..200 {
            dev.exchange(&out, &mut inp).unwrap();
        }
    });
    assert_eq!(n, 0);
}

fn exchange_err(dev: &mut UartDevice<crate::uart::SerialPath>) -> DeviceError {
    let mut inp = Input::default();
    dev.exchange(&Output::default(), &mut inp).unwrap_err()
}

/// Exchanges until one succeeds (a late reply costs the ticks until it has arrived); at most 20.
fn exchange_until_ok(dev: &mut UartDevice<crate::uart::SerialPath>) -> u32 {
    let mut inp = Input::default();
    for k in 0..20 {
        if dev.exchange(&Output::default(), &mut inp).is_ok() {
            return k;
        }
    }
    panic!("no good exchange in 20: {:?}", dev.stats());
}

#[test]
fn each_fault_reaches_the_driver_as_its_error_kind_and_the_link_recovers() {
    let (emu, mut dev) = start("faults");
    let c = emu.control().clone();
    let mut inp = Input::default();
    dev.exchange(&Output::default(), &mut inp).unwrap();

    c.drop_replies(1);
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Timeout);
    dev.exchange(&Output::default(), &mut inp).unwrap();

    c.corrupt_replies(1);
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Corrupt);
    dev.exchange(&Output::default(), &mut inp).unwrap();

    c.delay_replies(1, Duration::from_millis(300));
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Timeout);
    std::thread::sleep(Duration::from_millis(400));
    exchange_until_ok(&mut dev); // the late reply is never taken for a later tick's

    c.set_silent(true);
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Timeout);
    c.set_silent(false);
    exchange_until_ok(&mut dev);

    c.disconnect();
    assert!(eventually(|| !c.connection().0));
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Disconnected);
    assert_eq!(dev.reopen(Duration::from_millis(50)).unwrap_err().kind(), ErrorKind::Disconnected);
    c.reconnect();
    assert!(eventually(|| c.connection() == (true, 2)));
    dev.reopen(Duration::from_millis(200)).unwrap();
    dev.exchange(&Output::default(), &mut inp).unwrap();
    let s = c.stats();
    assert_eq!((s.replies_dropped, s.replies_corrupted, s.replies_delayed), (1, 1, 1));
    assert_eq!(c.boards().locked(), 0);
}

// ---------------------------------------------------------------------------------------------
// The link.

#[test]
fn the_link_lives_in_a_private_directory() {
    use std::os::unix::fs::MetadataExt;
    let d = symlink::private_dir().unwrap();
    let m = std::fs::symlink_metadata(&d).unwrap();
    assert!(m.is_dir());
    assert_eq!(m.mode() & 0o077, 0, "no access for others: {:o}", m.mode());
    assert_eq!(m.uid(), unsafe { libc::getuid() });
    assert_eq!(symlink::default_symlink().unwrap(), d.join("uart"));
}

#[test]
fn the_link_never_replaces_what_it_did_not_make() {
    // A real file.
    let p = link_path("file");
    std::fs::write(&p, b"precious").unwrap();
    let err = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).err().expect("must refuse");
    assert!(err.to_string().contains("not a symlink"), "{err}");
    assert_eq!(std::fs::read(&p).unwrap(), b"precious");
    std::fs::remove_file(&p).unwrap();
    // A symlink to something that is not a pty.
    let p = link_path("other");
    std::os::unix::fs::symlink("/etc/hostname", &p).unwrap();
    let err = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).err().expect("must refuse");
    assert!(err.to_string().contains("not a pseudo-terminal"), "{err}");
    assert_eq!(std::fs::read_link(&p).unwrap(), PathBuf::from("/etc/hostname"));
    std::fs::remove_file(&p).unwrap();
    // The live link of another emulator.
    let first = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &link_path("live")).unwrap();
    let err =
        Emulator::spawn(lab_rig(), EmulatorOptions::default(), first.symlink()).err().expect("must refuse");
    assert!(err.to_string().contains("another emulator"), "{err}");
    assert_eq!(std::fs::read_link(first.symlink()).ok(), first.pty_path());
}

#[test]
fn a_dangling_pty_link_left_by_a_killed_emulator_is_replaced_and_every_exit_removes_the_link() {
    let p = link_path("stale");
    std::os::unix::fs::symlink("/dev/pts/999999", &p).unwrap();
    let emu = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).unwrap();
    assert_ne!(std::fs::read_link(&p).unwrap(), PathBuf::from("/dev/pts/999999"));
    emu.stop();
    assert!(std::fs::symlink_metadata(&p).is_err(), "stop removes the link");
    let emu = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).unwrap();
    drop(emu);
    assert!(std::fs::symlink_metadata(&p).is_err(), "drop removes the link");
    // A panic that unwinds drops the emulator too.
    let p2 = p.clone();
    let r = std::thread::spawn(move || {
        let _emu = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p2).unwrap();
        panic!("test panic with an emulator running");
    })
    .join();
    assert!(r.is_err());
    assert!(std::fs::symlink_metadata(&p).is_err(), "a panic removes the link");
    // The link is not removed when it no longer points at this emulator's pty.
    let emu = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).unwrap();
    std::fs::remove_file(&p).unwrap();
    std::os::unix::fs::symlink("/etc/hostname", &p).unwrap();
    drop(emu);
    assert_eq!(std::fs::read_link(&p).unwrap(), PathBuf::from("/etc/hostname"));
    std::fs::remove_file(&p).unwrap();
}
