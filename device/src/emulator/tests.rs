//! The emulator on a real pseudo-terminal, driven by the real UART driver: each fault is seen by
//! the driver as the error kind the rt-loop reacts to, and the watchdog zeroes the motors.

use std::time::{Duration, Instant};

use glam::DVec3;

use super::*;
use crate::sim::{Script, SimRigParams};
use crate::uart::{UartDevice, UartOptions};
use crate::{DeviceError, ErrorKind};

fn lab_rig() -> SimRig {
    let p = SimRigParams::lab([DVec3::new(-0.15, 0.0, 0.0), DVec3::new(0.15, 0.0, 0.0)]);
    let holds = [Script::hold(p.hands[0].start_m), Script::hold(p.hands[1].start_m)];
    SimRig::new(p, holds).unwrap()
}

/// A link path of its own for each test (tests run in parallel).
fn link_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("spidar-emu-test-{}-{name}", std::process::id()))
}

fn start(name: &str, plant: PlantClock) -> (Emulator, UartDevice<crate::uart::SerialPath>) {
    let opts = EmulatorOptions { plant, ..Default::default() };
    let emu = Emulator::spawn(lab_rig(), opts, &link_path(name)).unwrap();
    // Generous deadlines: these tests check behaviour, not this machine's latency.
    let uo = UartOptions { reply_timeout: Duration::from_millis(100), ..UartOptions::default() };
    let mut dev = UartDevice::on_port(emu.link().to_str().unwrap(), uo).unwrap();
    dev.open_detailed().unwrap();
    (emu, dev)
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
    let (emu, mut dev) = start("basic", PlantClock::PerTick);
    assert_eq!(dev.info().channels, 8);
    assert_eq!(dev.info().board.as_str(), "UART B1M#0+B1M#1");
    dev.activate().unwrap();
    let out = Output { volts: [1.0; crate::MAX_CHANNELS] }; // 5 N on every string
    let mut inp = Input::default();
    for _ in 0..100 {
        dev.exchange(&out, &mut inp).unwrap();
    }
    let t = emu.control().truth();
    assert!((t.hands[0].tension_n[0] - 5.0).abs() < 0.01, "{:?}", t.hands[0].tension_n);
    assert_eq!(emu.control().stats().ticks, 100);
    assert!(inp.counts[..8].iter().any(|&c| c != 0));
}

#[test]
fn exchange_over_the_pty_allocates_nothing() {
    let (_emu, mut dev) = start("alloc", PlantClock::PerTick);
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

#[test]
fn each_fault_reaches_the_driver_as_its_error_kind_and_the_link_recovers() {
    let (emu, mut dev) = start("faults", PlantClock::PerTick);
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
    dev.exchange(&Output::default(), &mut inp).unwrap(); // the late reply was thrown away

    c.set_silent(true);
    assert_eq!(exchange_err(&mut dev).kind(), ErrorKind::Timeout);
    c.set_silent(false);
    dev.exchange(&Output::default(), &mut inp).unwrap();

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
}

#[test]
fn the_board_watchdog_zeroes_the_currents_when_commands_stop() {
    let (emu, mut dev) = start("watchdog", PlantClock::RealTime);
    dev.activate().unwrap();
    let out = Output { volts: [1.0; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    for _ in 0..20 {
        dev.exchange(&out, &mut inp).unwrap();
    }
    assert_eq!(emu.control().boards().motor_currents()[0], 1241);
    // The host stops sending (as if it hung): the boards must zero their motors by themselves.
    assert!(eventually(|| emu.control().boards().watchdog_tripped()));
    assert_eq!(emu.control().boards().motor_currents(), [0; crate::MAX_CHANNELS]);
    assert!(eventually(|| emu.control().truth().hands[0].tension_n.iter().all(|t| *t == 0.0)));
    assert_eq!(emu.control().stats().watchdog_trips, 1);
    // Commands again: currents again.
    dev.exchange(&out, &mut inp).unwrap();
    assert!(!emu.control().boards().watchdog_tripped());
}

#[test]
fn the_link_never_replaces_a_real_file() {
    let p = link_path("file");
    std::fs::write(&p, b"precious").unwrap();
    let err = Emulator::spawn(lab_rig(), EmulatorOptions::default(), &p).err().expect("must refuse");
    assert!(err.to_string().contains("not a symlink"), "{err}");
    assert_eq!(std::fs::read(&p).unwrap(), b"precious");
    std::fs::remove_file(&p).unwrap();
}
