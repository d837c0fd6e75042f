//! Real hardware from the command line: building the board drivers from options, the UART board
//! emulator (`spidar emulate`), device discovery (`spidar devices`) and the serial-link benchmark
//! (`spidar bench uart`).
//!
//! Why it exists: `main.rs` parses arguments; this turns checked options into opened devices with
//! errors a person can act on. What it must never do: start driving motors before the device is
//! identified, or hide that the board's DA range clips tensions the rig file asks for.

use std::io::BufRead;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use spidar_device::emulator::{symlink, Control, Emulator, EmulatorOptions, PlantClock};
use spidar_device::sim::Script;
use spidar_device::uart::protocol::ReplyLayout;
use spidar_device::uart::{UartDevice, UartOptions};
use spidar_device::usb::rusb_transport::RusbOpener;
use spidar_device::usb::{UsbBoard, UsbKind, UsbOptions};
use spidar_device::{Device, DeviceInfo, Input, Output};
use spidar_rt::rt_thread::{self, RtOptions, RtReport};
use spidar_rt::telemetry::{DurationHist, Percentiles};
use spidar_rt::{Command, Endpoints, MonotonicClock, Rig, RtLoop};

use crate::session::{sim_device, SimOptions};
use crate::supervisor::Shared;

/// The default link of `spidar emulate` (a symlink to its pty in a directory private to the
/// user: `$XDG_RUNTIME_DIR/spidar/uart`, or `/tmp/spidar-<uid>/uart`).
pub fn default_symlink() -> anyhow::Result<PathBuf> {
    Ok(symlink::default_symlink()?)
}

/// Which real board, with its options.
#[derive(Clone, Debug)]
pub enum HardwareChoice {
    Uart { port: String, opts: UartOptions },
    Usb { kind: UsbKind, opts: UsbOptions },
}

/// Which device drives the rig (`--device` of `spidar run` and `spidar calib`).
#[derive(Clone, Copy, clap::ValueEnum, PartialEq, Eq, Debug)]
pub enum DeviceKind {
    /// The simulated SPIDAR-H: motors, strings, encoders and a scripted user's hands.
    Sim,
    /// UART motor-driver boards on a serial port (--port; `spidar emulate` gives one).
    Uart,
    /// The USB 2.0 Simple amplifier board (0cec:0203; --switch picks one of several).
    UsbSimple,
    /// The USB 2.0 SH-4 amplifier board (0cec:0205; --switch picks one of several).
    UsbSh4,
}

/// Options of the real boards, shared by `spidar run` and `spidar calib`.
#[derive(clap::Args, Clone, Debug)]
pub struct HardwareArgs {
    /// Serial port of the UART boards (e.g. /dev/ttyUSB0). Default: the link of a running
    /// `spidar emulate` (it prints the path).
    #[arg(long)]
    pub port: Option<String>,
    /// Rotary switch of the USB board to use (0..15).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=15))]
    pub switch: Option<u8>,
    /// The board's command digits per volt, overriding the rig file's `boards:` section (for
    /// UART boards both the PWM duty's and the current target's).
    #[arg(long)]
    pub digits_per_volt: Option<f64>,
    /// Deadline of one exchange with the board, in microseconds (keep it below the tick period).
    #[arg(long, default_value_t = 800, value_parser = clap::value_parser!(u64).range(50..=100_000))]
    pub reply_timeout_us: u64,
}

impl HardwareArgs {
    /// The checked board choice for `rig` (its `boards:` section gives each board's scale and
    /// range); `None` for the simulated rig.
    pub fn choice(&self, kind: DeviceKind, rig: &Rig) -> anyhow::Result<Option<HardwareChoice>> {
        if let Some(d) = self.digits_per_volt {
            if !(d.is_finite() && d > 0.0) {
                bail!("--digits-per-volt must be a positive number");
            }
        }
        let timeout = Duration::from_micros(self.reply_timeout_us);
        Ok(match kind {
            DeviceKind::Sim => None,
            DeviceKind::Uart => {
                let port = match self.port.clone() {
                    Some(p) => p,
                    None => {
                        let l = default_symlink()?;
                        if std::fs::symlink_metadata(&l).is_err() {
                            bail!(
                                "--device uart needs --port PATH (see `spidar devices`), or a running `spidar emulate` \
                                 (its link {} is not there)",
                                l.display()
                            );
                        }
                        l.display().to_string()
                    }
                };
                let mut opts = uart_options(rig, timeout);
                if let Some(d) = self.digits_per_volt {
                    opts.pwm_digits_per_volt = d;
                    opts.current_digits_per_volt = d;
                }
                Some(HardwareChoice::Uart { port, opts })
            }
            DeviceKind::UsbSimple | DeviceKind::UsbSh4 => {
                let kind = if kind == DeviceKind::UsbSimple { UsbKind::Simple } else { UsbKind::Sh4 };
                let mut opts = UsbOptions {
                    switch: self.switch,
                    reply_timeout: timeout,
                    digits_per_volt: rig.boards.usb_digits_per_volt,
                    volts_max: rig.boards.usb_limit_v,
                    ..UsbOptions::default()
                };
                if let Some(d) = self.digits_per_volt {
                    opts.digits_per_volt = d;
                }
                Some(HardwareChoice::Usb { kind, opts })
            }
        })
    }
}

/// The UART driver's options for `rig`: its boards' command scales, and a reply deadline. The
/// enumeration at open waits as long for each board id as an exchange waits for its reply, and at
/// least the driver's 20 ms: who allows slow replies (a board behind a slow link, an emulator on a
/// busy machine) gets them at open too.
pub fn uart_options(rig: &Rig, reply_timeout: Duration) -> UartOptions {
    UartOptions {
        reply_timeout,
        enumerate_timeout: reply_timeout.max(UartOptions::default().enumerate_timeout),
        pwm_digits_per_volt: rig.boards.uart_pwm_digits_per_volt,
        current_digits_per_volt: rig.boards.uart_current_digits_per_volt,
        ..UartOptions::default()
    }
}

/// The emulator's options for `rig`: the boards `models` with firmware `layout`, mapping their
/// commands back to the rig's volts as the driver maps them out.
pub fn emulator_options(
    rig: &Rig,
    models: Vec<u8>,
    layout: ReplyLayout,
    plant: PlantClock,
) -> EmulatorOptions {
    EmulatorOptions {
        models,
        plant,
        layout,
        pwm_digits_per_volt: rig.boards.uart_pwm_digits_per_volt,
        current_digits_per_volt: rig.boards.uart_current_digits_per_volt,
        counts_per_rev: f64::from(rig.boards.uart_counts_per_rev()),
        ..EmulatorOptions::default()
    }
}

/// Opens the chosen board (identify, reset) with a message that says what was found; boxed so
/// the session code takes any device.
pub fn open_hardware(choice: &HardwareChoice) -> anyhow::Result<Box<dyn Device>> {
    open_hardware_for(choice, None)
}

/// [`open_hardware`] in a rig process under a supervisor (`page`): the UART boards found are
/// published on the page, so a takeover need not enumerate them again.
pub fn open_hardware_for(choice: &HardwareChoice, page: Option<&Shared>) -> anyhow::Result<Box<dyn Device>> {
    Ok(match choice {
        HardwareChoice::Uart { port, opts } => {
            let mut d = UartDevice::on_port(port, opts.clone())?;
            d.open_detailed().with_context(|| format!("opening the UART boards on {port}"))?;
            for w in d.warnings() {
                crate::errln!("warning: {w}");
            }
            if let Some(page) = page {
                page.publish_uart(d.boards(), d.layouts());
            }
            Box::new(d)
        }
        HardwareChoice::Usb { kind, opts } => {
            let mut d = UsbBoard::new(*kind, RusbOpener::new()?, *opts);
            d.open_detailed().with_context(|| format!("opening the {}", kind.name()))?;
            Box::new(d)
        }
    })
}

/// The supervisor's open, to write zero after the rig process died or hung: UART boards the rig
/// process published on `page` are opened without enumerating them (milliseconds instead of a
/// 20 ms wait for each absent board id); anything else, or a failure of that fast open, is a full
/// open. (The USB boards' open has no such wait.)
pub fn open_for_takeover(choice: &HardwareChoice, page: &Shared) -> anyhow::Result<Box<dyn Device>> {
    if let (HardwareChoice::Uart { port, opts }, Some((boards, layouts))) = (choice, page.known_uart()) {
        let mut d = UartDevice::on_port(port, opts.clone())?;
        if d.open_known(&boards, &layouts).is_ok() {
            return Ok(Box::new(d));
        }
    }
    open_hardware(choice)
}

/// Refuses a board that cannot give what the rig file asks: channels it lacks, or tensions whose
/// volts the board's DA range clips (unless the rig overrides `board_range`; the bound itself is
/// `Rig::check_board_range`).
pub fn check_rig_against(rig: &Rig, info: &DeviceInfo) -> anyhow::Result<()> {
    if rig.channels() > info.channels {
        bail!(
            "the rig file uses {} channels but {} has {}: check the strings' channel numbers",
            rig.channels(),
            info.board,
            info.channels
        );
    }
    rig.check_board_range(&info.board, info.volts_max).map_err(anyhow::Error::msg)
}

// ---------------------------------------------------------------------------------------------
// spidar emulate

/// Options of `spidar emulate`.
pub struct EmulateOptions {
    pub symlink: PathBuf,
    pub emulator: EmulatorOptions,
    pub sim: SimOptions,
}

/// Starts the emulator in front of the simulated rig `rig` with the user's hands on `scripts`.
pub fn start_emulator(rig: &Rig, scripts: [Script; 2], opts: &EmulateOptions) -> anyhow::Result<Emulator> {
    let sim = sim_device(rig, scripts, &opts.sim)?;
    let channels: usize = opts
        .emulator
        .models
        .iter()
        .filter_map(|m| spidar_device::uart::protocol::BoardInfo::of_model(0, *m))
        .map(|b| usize::from(b.n_motor))
        .sum();
    if channels < rig.channels() {
        bail!(
            "the boards have {channels} motors but the rig file uses {} channels: add boards (e.g. --boards B1M,B1M)",
            rig.channels()
        );
    }
    Ok(Emulator::spawn(sim, opts.emulator.clone(), &opts.symlink)?)
}

pub const EMULATE_HELP: &str =
    "commands: drop N | corrupt N | delay N MS | silent on|off | disconnect | reconnect | status | quit";

/// Applies one stdin command to the emulator; returns a reply line, or None to quit.
pub fn emulate_command(c: &Control, line: &str) -> Option<String> {
    let w: Vec<&str> = line.split_whitespace().collect();
    let num = |i: usize| w.get(i).and_then(|s| s.parse::<u32>().ok());
    Some(match w.as_slice() {
        [] => String::new(),
        ["quit"] | ["exit"] => return None,
        ["drop", _] if num(1).is_some() => {
            c.drop_replies(num(1).unwrap_or(0));
            format!("dropping the next {} replies", w[1])
        }
        ["corrupt", _] if num(1).is_some() => {
            c.corrupt_replies(num(1).unwrap_or(0));
            format!("corrupting the next {} replies", w[1])
        }
        ["delay", _, _] if num(1).is_some() && num(2).is_some() => {
            c.delay_replies(num(1).unwrap_or(0), Duration::from_millis(u64::from(num(2).unwrap_or(0))));
            format!("delaying the next {} replies by {} ms", w[1], w[2])
        }
        ["silent", "on"] => {
            c.set_silent(true);
            "boards cut off: they hear and answer nothing, and hold their last command (no watchdog)".into()
        }
        ["silent", "off"] => {
            c.set_silent(false);
            "boards answering again".into()
        }
        ["disconnect"] => {
            c.disconnect();
            "disconnected (pty closed, link removed)".into()
        }
        ["reconnect"] => {
            c.reconnect();
            "reconnecting (new pty behind the same link)".into()
        }
        ["status"] => status(c),
        _ => format!("unknown command '{line}'; {EMULATE_HELP}"),
    })
}

fn status(c: &Control) -> String {
    let s = c.stats();
    let (up, n) = c.connection();
    let b = c.boards();
    let t = b.rig().truth();
    let watchdog = match b.options().watchdog {
        None => "none (as the real boards)".to_string(),
        Some(w) if b.watchdog_tripped() => {
            format!("{} ms, TRIPPED (motors at zero), {} trips", w.as_millis(), s.watchdog_trips)
        }
        Some(w) => format!("{} ms, {} trips", w.as_millis(), s.watchdog_trips),
    };
    let locked = b.locked();
    let locked = if locked == 0 {
        String::new()
    } else {
        format!("; LOCKED boards {locked:#010b} (a command of declared length 0: power-cycle, i.e. restart the emulator)")
    };
    let derated = b.heat().iter().filter(|h| h.duty_limit < 1.0).count();
    format!(
        "{} (pty #{n}); {} ticks, {} plant steps; watchdog {watchdog}; replies dropped {}, corrupted {}, delayed {}; \
         {derated} motors thermally derated{locked}; rig t {:.2} s, left hand at ({:.3}, {:.3}, {:.3}) m",
        if up { "connected" } else { "disconnected" },
        s.ticks,
        s.plant_steps,
        s.replies_dropped,
        s.replies_corrupted,
        s.replies_delayed,
        t.t_s,
        t.hands[0].pos_m.x,
        t.hands[0].pos_m.y,
        t.hands[0].pos_m.z,
    )
}

/// Runs `spidar emulate` until a stop signal (Ctrl-C, SIGTERM, SIGHUP), `quit` on stdin, or
/// `seconds`; then prints the boards' final status, stops serving and removes the link.
pub fn run_emulator(emu: Emulator, stop: &crate::signals::Stop, seconds: Option<f64>) -> anyhow::Result<()> {
    let c = emu.control().clone();
    let quit = Arc::new(AtomicBool::new(false));
    {
        let (c, quit) = (c.clone(), quit.clone());
        // Stdin may be closed (run in the background): then only Ctrl-C or --seconds end it.
        std::thread::Builder::new().name("emulate-stdin".into()).spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                match emulate_command(&c, line.trim()) {
                    Some(r) if !r.is_empty() => crate::outln!("{r}"),
                    Some(_) => {}
                    None => {
                        quit.store(true, Ordering::SeqCst);
                        break;
                    }
                }
            }
        })?;
    }
    let start = Instant::now();
    let why = loop {
        if stop.requested() {
            break "a stop signal";
        }
        if quit.load(Ordering::SeqCst) {
            break "quit";
        }
        if seconds.is_some_and(|s| start.elapsed().as_secs_f64() >= s) {
            break "time up";
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    crate::outln!("{}", status(&c));
    let link = emu.symlink().display().to_string();
    emu.stop();
    crate::outln!("spidar emulate: stopped ({why}); link {link} removed");
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// spidar devices

/// The report of `spidar devices`.
pub fn devices_report(extra_ports: &[String], probe: bool) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    // A running emulator's link is not listed by the OS: check it too.
    let mut extra = extra_ports.to_vec();
    let emulator = default_symlink().ok().map(|l| l.display().to_string());
    if let Some(l) = emulator.as_ref() {
        if std::fs::symlink_metadata(l).is_ok() && !extra.contains(l) {
            extra.push(l.clone());
        }
    }
    let (mut ports, warn) = spidar_device::discover::serial_ports(&extra, probe);
    for p in ports.iter_mut().filter(|p| Some(&p.path) == emulator.as_ref()) {
        p.kind = "spidar emulate's link".into();
    }
    let _ = writeln!(s, "serial ports (UART boards, 2 Mbaud):");
    if let Some(w) = warn {
        let _ = writeln!(s, "  {w}");
    }
    if ports.is_empty() {
        let _ = writeln!(s, "  none found (a pty is not listed by the OS: add it with --port PATH)");
    }
    for p in &ports {
        let status = match &p.status {
            Ok(what) => what.replace('\n', "\n      "),
            Err(why) => format!("cannot use: {why}"),
        };
        let _ = writeln!(s, "  {:<22} {:<28} {}", p.path, p.kind, status);
    }
    let _ = writeln!(s, "USB devices (Simple 0cec:0203, SH-4 0cec:0205):");
    match spidar_device::discover::usb_devices() {
        Err(e) => {
            let _ = writeln!(s, "  {e}");
        }
        Ok(devs) => {
            if devs.is_empty() {
                let _ = writeln!(s, "  none");
            }
            let devs_kinds: Vec<Option<UsbKind>> = devs.iter().map(|d| d.kind).collect();
            for d in devs {
                let what = match d.kind {
                    Some(k) => k.name().to_string(),
                    None => "not a SPIDAR board".into(),
                };
                let open = match &d.seen.openable {
                    None => String::new(),
                    Some(Ok(())) => {
                        "opens (run with --device usb-simple/usb-sh4; the switch is read at open)".into()
                    }
                    Some(Err(e)) => format!("cannot open: {e}"),
                };
                let _ = writeln!(
                    s,
                    "  {:<18} {:04x}:{:04x}  {what}  {open}",
                    d.seen.place(),
                    d.seen.vid,
                    d.seen.pid
                );
            }
            // Only when one of our boards is there: opening resets it.
            let ours = |k: UsbKind| devs_kinds.contains(&Some(k));
            if probe {
                for kind in [UsbKind::Simple, UsbKind::Sh4] {
                    if ours(kind) {
                        let _ = writeln!(s, "  {}: {}", kind.name(), probe_usb(kind));
                    }
                }
            }
        }
    }
    s
}

/// Opens every board of `kind` to read its switch (resets it: only when no rig is running on it).
fn probe_usb(kind: UsbKind) -> String {
    let opener = match RusbOpener::new() {
        Ok(o) => o,
        Err(e) => return e.to_string(),
    };
    let mut d = UsbBoard::new(kind, opener, UsbOptions::default());
    match d.open_detailed() {
        Ok(()) => format!("one board, switch {}, 8 channels", d.switch()),
        // With several boards the error lists each one's switch; with none, what was seen.
        Err(e) => e.to_string(),
    }
}

// ---------------------------------------------------------------------------------------------
// spidar bench uart

/// What `spidar bench uart` measured.
pub struct UartBenchReport {
    pub boards: String,
    /// One exchange (write every board's command, read every reply), back to back.
    pub round_trip: Percentiles,
    pub round_trip_timeouts: u64,
    pub rt: RtReport,
    /// The 1 kHz loop through the link: wake-up lateness and exchange time.
    pub lateness: Percentiles,
    pub io: Percentiles,
    pub ticks: u64,
    pub misses: u64,
    pub device_errors: u64,
    pub faults: u64,
}

impl std::fmt::Display for UartBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "spidar bench uart: the UART driver against the board emulator on a pseudo-terminal ({})",
            self.boards
        )?;
        writeln!(
            f,
            "  round trip   {}  ({} exchanges back to back, {} timed out)",
            self.round_trip, self.round_trip.count, self.round_trip_timeouts
        )?;
        writeln!(f, "  real time    {}", self.rt)?;
        for w in &self.rt.warnings {
            writeln!(f, "  warning      {w}")?;
        }
        writeln!(f, "  1 kHz loop   {} ticks through the pty", self.ticks)?;
        writeln!(f, "  lateness     {}", self.lateness)?;
        writeln!(f, "  device I/O   {}", self.io)?;
        write!(
            f,
            "  misses       {} ticks > 1 ms late; device errors {}, faults {}",
            self.misses, self.device_errors, self.faults
        )
    }
}

/// Round trips, then the loop for `seconds`, both through an in-process emulator on a pty.
pub fn bench_uart(
    rig: &Rig,
    scripts: [Script; 2],
    exchanges: u64,
    seconds: f64,
    rt: &RtOptions,
    reply_timeout: Duration,
) -> anyhow::Result<UartBenchReport> {
    let link = symlink::private_dir()?.join(format!("bench-uart-{}", std::process::id()));
    let opts = EmulateOptions {
        symlink: link.clone(),
        emulator: EmulatorOptions {
            // Both ends real-time when the loop is, as a board answers at once.
            fifo_priority: rt.fifo_priority.map(|p| i32::from(p.saturating_sub(10).max(1))),
            ..emulator_options(rig, vec![1, 1], ReplyLayout::Forces, PlantClock::RealTime)
        },
        sim: SimOptions::default(),
    };
    let emu = start_emulator(rig, scripts, &opts)?;
    // The board side as a real device process would be: its own real-time thread.
    let uo = uart_options(rig, reply_timeout);
    let port = link.to_string_lossy().into_owned();
    let rig2 = rig.clone();
    let rt2 = rt.clone();
    let handle = std::thread::Builder::new().name("spidar-bench-uart".into()).spawn(
        move || -> anyhow::Result<UartBenchReport> {
            let report = rt_thread::setup_current_thread(&rt2);
            let mut dev = UartDevice::on_port(&port, uo)?;
            dev.open_detailed()?;
            let boards = dev.info().board.to_string();
            dev.activate().map_err(|e| anyhow::anyhow!("{e}"))?;
            let mut h = DurationHist::default();
            let mut timeouts = 0;
            let out = Output::default();
            let mut inp = Input::default();
            for _ in 0..exchanges {
                let t = Instant::now();
                match dev.exchange(&out, &mut inp) {
                    Ok(()) => h.record(t.elapsed().as_secs_f64()),
                    Err(_) => timeouts += 1,
                }
            }
            let (ep, far) = Endpoints::pair();
            let mut rtl = RtLoop::new(dev, MonotonicClock::new(), &rig2, ep)?;
            rtl.configure().map_err(|e| anyhow::anyhow!("opening the boards: {e}"))?;
            rtl.command(Command::Home);
            rtl.command(Command::Activate);
            let ticks = (seconds / rig2.period_s).round() as u64;
            let (mut late, mut io) = (DurationHist::default(), DurationHist::default());
            for _ in 0..ticks {
                rtl.tick();
                let r = rtl.last_record();
                late.record(r.lateness_s);
                io.record(r.io_s);
                for _ in far.telemetry.try_iter() {}
                for _ in far.samples.try_iter() {}
            }
            rtl.command(Command::Stop);
            let mut guard = 0;
            while rtl.tick() && guard < 5000 {
                guard += 1;
            }
            let c = *rtl.core().counters();
            Ok(UartBenchReport {
                boards,
                round_trip: h.percentiles(),
                round_trip_timeouts: timeouts,
                rt: report,
                lateness: late.percentiles(),
                io: io.percentiles(),
                ticks,
                misses: c.misses,
                device_errors: c.device_errors,
                faults: c.faults,
            })
        },
    )?;
    let r = handle.join().map_err(|_| anyhow::anyhow!("the benchmark thread panicked"))?;
    emu.stop();
    r
}
