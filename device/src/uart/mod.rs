//! The `uart` backend: up to 8 UART motor-driver boards on one 2 Mbaud serial link
//! (`docs/protocols.md`, "UART boards"), seen as one [`Device`] whose channels are the boards'
//! motors in board-id order (board 0's motors first).
//!
//! Why it exists: this is how current SPIDAR rigs are wired, and the board emulator
//! ([`crate::emulator`]) speaks the same protocol on a pseudo-terminal, so the whole stack is
//! tested through this driver without hardware. What it must never do: allocate, lock or panic in
//! [`Device::exchange`] or [`Device::reopen`] (both run in the 1 kHz tick), block longer than its
//! reply deadline, or declare a command length of 0 to the boards (that locks every board on the
//! link with its motors on). The byte layouts live in [`protocol`]; this module moves buffers
//! through a [`ByteTransport`] and keeps the counters' wrap extension.
//!
//! Open: enumerate board ids 0..7, declare every board's real command lengths, then measure
//! which reply layout each board's firmware uses (one zero current command per board, its reply
//! length read up to the board-info reply that follows).
//!
//! One exchange: drop stale input; write every board's current command (with its padding) and a
//! board-info request for the first board, in one write; read every reply and the board-info
//! reply, in this tick; check the frame, decode, extend the 16-bit positions to i64. After a
//! failed exchange the next frame puts the board-info request first instead of last, so a
//! reply frame from the failed tick that arrives late is told apart by its order and never taken
//! as this tick's. After a write that was cut short the next frame starts with 40 zero bytes,
//! which complete whatever command the boards were in the middle of and bring their parsers
//! back to "waiting for a header".
//!
//! Volts become commands per channel: on boards without current sensors the command is a PWM
//! duty (1024 = 100 %, [`UartOptions::pwm_digits_per_volt`]), on boards with them a current
//! target (up to 4095, [`UartOptions::current_digits_per_volt`]); each is clamped to its range.

pub mod protocol;

use std::ffi::CString;
use std::time::{Duration, Instant};

use crate::frame::Unwrap;
use crate::transport::{open_serial, ByteTransport, FdTransport, PortReport, PortSetting};
use crate::{short_string, Device, DeviceError, DeviceInfo, Input, OpenError, Output, MAX_CHANNELS};
use protocol::{
    cmd, BoardInfo, CurrentReply, ReplyLayout, INFO_REPLY_LEN, INFO_REQUEST_LEN, INFO_TRAIL_ZEROS,
    MAX_BOARDS, MAX_MOTORS, RESYNC_ZEROS, SET_CMD_LEN_LEN, SET_CMD_LEN_TRAIL_ZEROS, TICK_END_ZEROS,
};

/// Status bit set in `Input::status` while the outputs are enabled.
pub const STATUS_ACTIVE: u32 = 1;

/// Opens the link to the boards. `connect` is called again by [`Device::reopen`] inside the tick,
/// so it must not allocate.
pub trait Connector: Send {
    type Link: ByteTransport;
    fn connect(&mut self) -> Result<Self::Link, DeviceError>;
    /// What the link is, for messages (e.g. the port path).
    fn describe(&self) -> &str;
}

/// A serial port (or pty) by path, opened raw at 2 Mbaud.
#[derive(Debug)]
pub struct SerialPath {
    path: CString,
    display: String,
    baud: u32,
}

impl SerialPath {
    pub fn new(path: &str) -> Result<SerialPath, OpenError> {
        let c = CString::new(path)
            .map_err(|_| OpenError::BadPath { path: path.into(), why: "contains a NUL byte".into() })?;
        Ok(SerialPath { path: c, display: path.into(), baud: protocol::BAUD })
    }
}

impl Connector for SerialPath {
    type Link = FdTransport;
    fn connect(&mut self) -> Result<FdTransport, DeviceError> {
        open_serial(&self.path, self.baud)
    }
    fn describe(&self) -> &str {
        &self.display
    }
}

/// Settings of the UART driver.
#[derive(Clone, Debug, PartialEq)]
pub struct UartOptions {
    /// Deadline of one exchange (write and read): keep it below the tick period.
    pub reply_timeout: Duration,
    /// How long each board id gets to answer the enumeration at open.
    pub enumerate_timeout: Duration,
    /// Boards without current sensors: PWM-duty digits per volt of the rig's scale (1024 digits
    /// = 100 % duty). The rig file's `uart_pwm_duty` section sets it.
    pub pwm_digits_per_volt: f64,
    /// Boards with current sensors: current-target digits per volt (up to 4095). The rig file's
    /// `uart_current_target` section sets it.
    pub current_digits_per_volt: f64,
    /// Largest counter step in one tick that is believed; a larger one is a corrupt reply.
    pub max_step_counts: i64,
}

impl Default for UartOptions {
    /// The lab host driver's scale (4096 digits per 3.3 V) for both kinds of board.
    fn default() -> Self {
        UartOptions {
            reply_timeout: Duration::from_micros(800),
            enumerate_timeout: Duration::from_millis(20),
            pwm_digits_per_volt: protocol::HOST_DIGITS_PER_VOLT,
            current_digits_per_volt: protocol::HOST_DIGITS_PER_VOLT,
            // 4096 counts of 2.9e-5 m is 12 cm in 1 ms: far beyond any hand.
            max_step_counts: 4096,
        }
    }
}

/// What a channel's command means on its board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandKind {
    /// A PWM duty, +-1024 = +-100 % (boards without current sensors).
    PwmDuty,
    /// A current target in current-sense ADC counts, up to +-4095 (boards with current sensors).
    CurrentTarget,
}

impl CommandKind {
    /// The command's range in digits.
    pub fn limit(self) -> i16 {
        match self {
            CommandKind::PwmDuty => protocol::PWM_FULL,
            CommandKind::CurrentTarget => protocol::CURRENT_MAX,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            CommandKind::PwmDuty => "PWM duty",
            CommandKind::CurrentTarget => "current target",
        }
    }
}

/// How one channel's volts become its board's command.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Channel {
    kind: CommandKind,
    digits_per_volt: f64,
}

impl Channel {
    const NONE: Channel = Channel { kind: CommandKind::PwmDuty, digits_per_volt: 0.0 };
    fn volts_max(&self) -> f64 {
        f64::from(self.kind.limit()) / self.digits_per_volt
    }
}

/// Where the board-info request of a tick's frame goes: last (the normal tick) or first (the
/// tick after a failed one, so a late frame of the failed tick is told apart by its order).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum InfoAt {
    Last,
    First,
}

/// Counters of what the driver did, for tests and `spidar devices --probe`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UartStats {
    pub exchanges: u64,
    pub failed: u64,
    /// Frames whose order showed they were an earlier tick's replies (discarded).
    pub late_frames: u64,
    /// Writes cut short, each followed by 40 zero bytes before the next command.
    pub resyncs: u64,
}

/// One board as `spidar devices --probe` reports it.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbedBoard {
    pub info: BoardInfo,
    pub layout: ReplyLayout,
    /// The command lengths declared to every board for this board's id.
    pub lengths: [u8; protocol::COMMANDS],
    /// What the motors' commands are (current targets for the sensed motors, PWM for the rest).
    pub commands: [CommandKind; MAX_MOTORS],
}

const TX_MAX: usize = 1024;
const RX_MAX: usize = 512;

/// The UART boards on one link; see the module doc.
pub struct UartDevice<C: Connector> {
    conn: C,
    pub(crate) link: Option<C::Link>,
    pub(crate) opts: UartOptions,
    boards: heapless::Vec<BoardInfo, MAX_BOARDS>,
    layouts: [ReplyLayout; MAX_BOARDS],
    /// First channel of each board in `boards`.
    offsets: [usize; MAX_BOARDS],
    channels: usize,
    chan: [Channel; MAX_CHANNELS],
    /// The first board's board-info reply, which ends (or starts) every tick's reply frame.
    marker: [u8; INFO_REPLY_LEN],
    unwrap: [Unwrap<16>; MAX_CHANNELS],
    info: DeviceInfo,
    opened: bool,
    active: bool,
    tx: [u8; TX_MAX],
    rx: [u8; RX_MAX],
    /// Latest sensor words of each channel's board reply (forces or currents), per channel.
    sensors: [i16; MAX_CHANNELS],
    /// A write was cut short: the next one starts with [`RESYNC_ZEROS`] zero bytes.
    resync: bool,
    /// The last exchange failed (its replies may still arrive).
    last_failed: bool,
    info_at: InfoAt,
    stats: UartStats,
    port: Option<PortReport>,
    latency_timer_ms: Option<u32>,
    warnings: Vec<String>,
}

impl UartDevice<SerialPath> {
    /// The boards on the serial port at `path` (not opened yet).
    pub fn on_port(path: &str, opts: UartOptions) -> Result<Self, OpenError> {
        Ok(UartDevice::new(SerialPath::new(path)?, opts))
    }
}

impl<C: Connector> UartDevice<C> {
    pub fn new(conn: C, opts: UartOptions) -> Self {
        UartDevice {
            conn,
            link: None,
            opts,
            boards: heapless::Vec::new(),
            layouts: [ReplyLayout::Forces; MAX_BOARDS],
            offsets: [0; MAX_BOARDS],
            channels: 0,
            chan: [Channel::NONE; MAX_CHANNELS],
            marker: [0; INFO_REPLY_LEN],
            unwrap: [Unwrap::new(); MAX_CHANNELS],
            info: DeviceInfo {
                board: short_string("UART boards (not opened)"),
                identity: heapless::String::new(),
                channels: 0,
                volts_min: 0.0,
                volts_max: 0.0,
            },
            opened: false,
            active: false,
            tx: [0; TX_MAX],
            rx: [0; RX_MAX],
            sensors: [0; MAX_CHANNELS],
            resync: false,
            last_failed: false,
            info_at: InfoAt::Last,
            stats: UartStats::default(),
            port: None,
            latency_timer_ms: None,
            warnings: Vec::new(),
        }
    }

    /// The boards found by the last enumeration, in id order.
    pub fn boards(&self) -> &[BoardInfo] {
        &self.boards
    }

    /// The reply layout each board in [`UartDevice::boards`] uses (measured at open).
    pub fn layouts(&self) -> &[ReplyLayout] {
        &self.layouts[..self.boards.len()]
    }

    pub fn options(&self) -> &UartOptions {
        &self.opts
    }

    pub fn stats(&self) -> UartStats {
        self.stats
    }

    /// What each channel's command means.
    pub fn command_kind(&self, channel: usize) -> Option<CommandKind> {
        (channel < self.channels).then(|| self.chan[channel].kind)
    }

    /// The largest volts channel `channel` can be given before its command clips.
    pub fn channel_volts_max(&self, channel: usize) -> Option<f64> {
        (channel < self.channels).then(|| self.chan[channel].volts_max())
    }

    /// Latest sensor words of each channel's board (forces or currents, in reply order), per
    /// channel of that board: channel `offset + i` holds the board's i-th sensor word.
    pub fn sensors(&self) -> &[i16] {
        &self.sensors[..self.channels]
    }

    /// What the serial port's set-up did (None before open, or on a link that is not a port).
    pub fn port_report(&self) -> Option<PortReport> {
        self.port
    }

    /// The USB serial adapter's latency timer read at open, when it has one.
    pub fn latency_timer_ms(&self) -> Option<u32> {
        self.latency_timer_ms
    }

    /// What will not work well, found at open (port settings, unused sensors, mixed boards).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Each board as `spidar devices --probe` reports it.
    pub fn probed(&self) -> Vec<ProbedBoard> {
        self.boards
            .iter()
            .enumerate()
            .map(|(bi, b)| {
                let mut commands = [CommandKind::PwmDuty; MAX_MOTORS];
                for (m, c) in commands.iter_mut().enumerate().take(usize::from(b.n_motor)) {
                    *c = self.chan[self.offsets[bi] + m].kind;
                }
                ProbedBoard { info: *b, layout: self.layouts[bi], lengths: b.command_lengths(), commands }
            })
            .collect()
    }

    /// Opens the link, enumerates the boards, tells each its command lengths and measures its
    /// reply layout, with errors that say what was found. Set-up time (allocates for messages).
    pub fn open_detailed(&mut self) -> Result<(), OpenError> {
        let port = self.conn.describe().to_owned();
        self.link = None;
        self.opened = false;
        self.active = false;
        let mut link = self.conn.connect().map_err(|e| OpenError::from_serial(&port, e))?;
        self.port = link.port_report();
        self.latency_timer_ms = crate::transport::latency_timer_ms(&port);
        let mut found: heapless::Vec<BoardInfo, MAX_BOARDS> = heapless::Vec::new();
        let mut garbage = Vec::new();
        for id in 0..MAX_BOARDS as u8 {
            match identify(&mut link, id, Instant::now() + self.opts.enumerate_timeout) {
                Ok(b) => {
                    let _ = found.push(b);
                }
                Err(DeviceError::Timeout { .. }) => {}
                Err(DeviceError::Corrupt { what }) => garbage.push(format!("id {id}: {what}")),
                Err(e) => return Err(OpenError::from_serial(&port, e)),
            }
        }
        if found.is_empty() {
            return Err(OpenError::NoBoard {
                port,
                found: if garbage.is_empty() {
                    "no board answered the enumeration at 2 Mbaud (is the board powered, the port right, \
                     the emulator running? Boards that stopped parsing after a bad command-length table \
                     answer again only after a power cycle)"
                        .into()
                } else {
                    format!("only malformed answers: {}", garbage.join("; "))
                },
            });
        }
        let channels: usize = found.iter().map(|b| usize::from(b.n_motor)).sum();
        if channels > MAX_CHANNELS {
            return Err(OpenError::WrongBoard {
                what: format!("{channels} motors on {port}: spidar drives at most {MAX_CHANNELS}"),
            });
        }
        set_command_lengths(&mut link, &found, Instant::now() + self.opts.enumerate_timeout)
            .map_err(|e| OpenError::from_serial(&port, e))?;
        // Let the boards finish, then drop whatever they sent (the protocol's "drain the input").
        std::thread::sleep(Duration::from_millis(2));
        link.clear_input().map_err(|e| OpenError::from_serial(&port, e))?;
        let mut layouts = [ReplyLayout::Forces; MAX_BOARDS];
        for (bi, b) in found.iter().enumerate() {
            layouts[bi] = match measure_layout(&mut link, b, Instant::now() + self.opts.enumerate_timeout) {
                Ok(l) => l,
                Err(Measured::NoReply(e)) => {
                    return Err(OpenError::Device {
                        what: format!(
                        "{port}: board id {} ({}) answered the enumeration but not a zero current command",
                        b.id,
                        b.model_name()
                    ),
                        source: e,
                    })
                }
                Err(Measured::Unknown { got }) => {
                    let known: Vec<String> = ReplyLayout::ALL
                        .iter()
                        .map(|l| format!("{} bytes ({})", b.current_reply_len(*l), l.firmware()))
                        .collect();
                    return Err(OpenError::WrongBoard {
                        what: format!(
                            "board id {} ({}) on {port} replied to the current command in a layout spidar does \
                             not know (the reply did not end where {} would; first bytes {:02x?}): check its firmware",
                            b.id,
                            b.model_name(),
                            known.join(" or "),
                            &got[..got.len().min(16)]
                        ),
                    });
                }
            };
        }
        self.install(&found, layouts);
        self.warnings = self.open_warnings(&port);
        self.describe_installed(&port);
        self.link = Some(link);
        self.opened = true;
        Ok(())
    }

    /// Opens the link to boards already known, without enumerating them: the boards and reply
    /// layouts another process found at its open (`boards()`, `layouts()`), whose command-length
    /// tables the boards still hold (they keep them until power-off). For the supervisor's
    /// takeover, which must write zero within milliseconds: a full open waits out every absent
    /// board id (`enumerate_timeout` each). The first frame starts with the resynchronising
    /// zeros, since the process before may have died in the middle of a write.
    pub fn open_known(&mut self, boards: &[BoardInfo], layouts: &[ReplyLayout]) -> Result<(), OpenError> {
        let port = self.conn.describe().to_owned();
        self.link = None;
        self.opened = false;
        self.active = false;
        if boards.is_empty() || boards.len() > MAX_BOARDS || layouts.len() != boards.len() {
            return Err(OpenError::WrongBoard {
                what: format!("{} known boards with {} layouts on {port}", boards.len(), layouts.len()),
            });
        }
        let channels: usize = boards.iter().map(|b| usize::from(b.n_motor)).sum();
        if channels > MAX_CHANNELS {
            return Err(OpenError::WrongBoard {
                what: format!("{channels} motors on {port}: spidar drives at most {MAX_CHANNELS}"),
            });
        }
        let link = self.conn.connect().map_err(|e| OpenError::from_serial(&port, e))?;
        self.port = link.port_report();
        let mut l = [ReplyLayout::Forces; MAX_BOARDS];
        l[..layouts.len()].copy_from_slice(layouts);
        self.install(boards, l);
        self.resync = true;
        self.last_failed = true;
        self.describe_installed(&port);
        self.link = Some(link);
        self.opened = true;
        Ok(())
    }

    /// The device info of the installed boards on `port`: their names, channels and volts range.
    fn describe_installed(&mut self, port: &str) {
        let names: Vec<String> = self.boards.iter().map(|b| format!("{}#{}", b.model_name(), b.id)).collect();
        let (vmin, vmax) = self.volts_range();
        self.info = DeviceInfo {
            board: short_string(&format!("UART {}", names.join("+"))),
            identity: short_string(port),
            channels: self.channels,
            volts_min: vmin,
            volts_max: vmax,
        };
    }

    /// Takes the boards found at open: channel table, counters, frame state.
    fn install(&mut self, found: &[BoardInfo], layouts: [ReplyLayout; MAX_BOARDS]) {
        let mut off = 0;
        self.chan = [Channel::NONE; MAX_CHANNELS];
        for (i, b) in found.iter().enumerate() {
            self.offsets[i] = off;
            for m in 0..usize::from(b.n_motor) {
                self.chan[off + m] = if b.current_sensed(m) {
                    Channel {
                        kind: CommandKind::CurrentTarget,
                        digits_per_volt: self.opts.current_digits_per_volt,
                    }
                } else {
                    Channel { kind: CommandKind::PwmDuty, digits_per_volt: self.opts.pwm_digits_per_volt }
                };
            }
            off += usize::from(b.n_motor);
        }
        self.boards = heapless::Vec::new();
        for b in found {
            let _ = self.boards.push(*b);
        }
        self.layouts = layouts;
        self.channels = off;
        if let Some(first) = found.first() {
            protocol::encode_info_reply(first, &mut self.marker);
        }
        self.unwrap = [Unwrap::new(); MAX_CHANNELS];
        self.resync = false;
        self.last_failed = false;
        self.info_at = InfoAt::Last;
    }

    /// The volts every channel can take: the narrowest channel's range (a board clips beyond it).
    fn volts_range(&self) -> (f64, f64) {
        let max = self.chan[..self.channels].iter().map(Channel::volts_max).fold(f64::INFINITY, f64::min);
        let max = if max.is_finite() { max } else { 0.0 };
        (-max, max)
    }

    fn open_warnings(&self, port: &str) -> Vec<String> {
        let mut w = Vec::new();
        match self.port.map(|p| p.low_latency) {
            Some(PortSetting::Failed(e)) => w.push(format!(
                "{port}: cannot set the port to low latency ({}): a USB serial adapter may then hold each reply \
                 for up to 16 ms and the 1 kHz exchange times out; set it with `setserial {port} low_latency`, or \
                 install configs/udev/99-spidar.rules (FTDI adapters: latency timer 1 ms)",
                std::io::Error::from_raw_os_error(e)
            )),
            Some(PortSetting::Done | PortSetting::NotApplicable) | None => {}
        }
        if let Some(ms) = self.latency_timer_ms.filter(|ms| *ms > 1) {
            w.push(format!(
                "{port}: the USB serial adapter's latency timer is {ms} ms (replies may arrive that late, after the \
                 tick's deadline): set it to 1 (configs/udev/99-spidar.rules does it for FTDI adapters)"
            ));
        }
        if let Some(PortSetting::Failed(e)) = self.port.map(|p| p.modem_lines_cleared) {
            w.push(format!(
                "{port}: cannot clear DTR and RTS ({}); the lab's driver clears both: if the boards do not \
                 answer, check how the adapter wires them",
                std::io::Error::from_raw_os_error(e)
            ));
        }
        let kinds: Vec<CommandKind> = self.chan[..self.channels].iter().map(|c| c.kind).collect();
        if kinds.contains(&CommandKind::PwmDuty) && kinds.contains(&CommandKind::CurrentTarget) {
            w.push(
                "boards with and without current sensors on one link: their commands differ (current target \
                 vs PWM duty) and so do their ranges; the narrower one limits every channel"
                    .into(),
            );
        }
        for b in self.boards.iter().filter(|b| b.n_force > 0) {
            w.push(format!(
                "board id {} ({}) has {} force sensors; spidar reads them but does not use them",
                b.id,
                b.model_name(),
                b.n_force
            ));
        }
        for b in self.boards.iter().filter(|b| protocol::MODELS.iter().all(|m| m.number != b.model)) {
            w.push(format!(
                "board id {} reports model {}, which spidar does not know: its lengths are computed from its \
                 counts ({} motors, {} current, {} force sensors)",
                b.id, b.model, b.n_motor, b.n_current, b.n_force
            ));
        }
        w
    }

    /// Builds this tick's frame into `tx`; returns its length and the reply frame's length.
    fn build_frame(&mut self, out: &Output, info_at: InfoAt) -> Result<(usize, usize), DeviceError> {
        let first = self.boards.first().map_or(0, |b| b.id);
        let mut n = 0;
        if self.resync {
            self.tx[..RESYNC_ZEROS].fill(0);
            n += RESYNC_ZEROS;
        }
        if info_at == InfoAt::First {
            n += protocol::encode_info_marker(first, INFO_TRAIL_ZEROS, &mut self.tx[n..])?;
        }
        let mut reply_len = INFO_REPLY_LEN;
        for (bi, b) in self.boards.iter().enumerate() {
            let mut cmd = [0i16; MAX_MOTORS];
            if self.active {
                for (m, c) in cmd.iter_mut().enumerate().take(usize::from(b.n_motor)) {
                    let ch = self.offsets[bi] + m;
                    let v = out.volts.get(ch).copied().unwrap_or(0.0);
                    let k = self.chan[ch];
                    *c = protocol::volts_to_digits(v, k.digits_per_volt, k.kind.limit());
                }
            }
            n += protocol::encode_current(b, self.layouts[bi], &cmd, &mut self.tx[n..])?;
            reply_len += b.current_reply_len(self.layouts[bi]);
        }
        if info_at == InfoAt::Last {
            n += protocol::encode_info_marker(first, TICK_END_ZEROS, &mut self.tx[n..])?;
        }
        Ok((n, reply_len))
    }

    /// One exchange on an open link; errors are returned as they are (the caller drops the link
    /// on a disconnect).
    fn exchange_on_link(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        if self.link.is_none() {
            return Err(DeviceError::Disconnected { what: "UART link closed, waiting for the reopen" });
        }
        let deadline = Instant::now() + self.opts.reply_timeout;
        let info_at = match (self.last_failed, self.info_at) {
            (false, _) => InfoAt::Last,
            (true, InfoAt::Last) => InfoAt::First,
            (true, InfoAt::First) => InfoAt::Last,
        };
        let (n, reply_len) = self.build_frame(out, info_at)?;
        self.info_at = info_at;
        self.last_failed = true; // until this exchange has succeeded
        self.stats.exchanges += 1;
        let Some(link) = self.link.as_mut() else {
            return Err(DeviceError::Disconnected { what: "UART link closed, waiting for the reopen" });
        };
        link.clear_input()?;
        if let Err(e) = link.write_all(&self.tx[..n], deadline) {
            // Some of the frame may have gone out: a board may be in the middle of a command.
            self.resync = true;
            self.stats.resyncs += 1;
            return Err(e);
        }
        self.resync = false;
        link.read_exact(&mut self.rx[..reply_len], deadline)?;

        // The frame's order: the marker (first board's board-info reply) last or first.
        let (marker_at, replies_at) = match info_at {
            InfoAt::Last => (reply_len - INFO_REPLY_LEN, 0),
            InfoAt::First => (0, INFO_REPLY_LEN),
        };
        let other_first = match info_at {
            InfoAt::Last => self.marker[0],
            InfoAt::First => protocol::header(cmd::CURRENT, self.boards.first().map_or(0, |b| b.id)),
        };
        if self.rx[marker_at..marker_at + INFO_REPLY_LEN] != self.marker {
            if self.rx[0] == other_first {
                self.stats.late_frames += 1;
                return Err(DeviceError::Corrupt { what: "a late reply from an earlier tick (discarded)" });
            }
            return Err(DeviceError::Corrupt { what: "the tick's board-info reply is missing or wrong" });
        }

        // Decode everything before committing anything: a bad board leaves all counters as they were.
        let mut unwrap = self.unwrap;
        let mut counts = [0i64; MAX_CHANNELS];
        let mut sensors = self.sensors;
        let mut at = replies_at;
        for (bi, b) in self.boards.iter().enumerate() {
            let layout = self.layouts[bi];
            let len = b.current_reply_len(layout);
            let r: CurrentReply = protocol::decode_current_reply(b, layout, &self.rx[at..at + len])?;
            at += len;
            let m = usize::from(b.n_motor);
            for i in 0..m {
                let ch = self.offsets[bi] + i;
                counts[ch] = unwrap[ch].update(i64::from(r.positions[i]), self.opts.max_step_counts)?;
                sensors[ch] = if i < b.reply_sensors(layout) { r.sensors[i] } else { 0 };
            }
        }
        self.unwrap = unwrap;
        self.sensors = sensors;
        inp.counts = counts;
        inp.status = if self.active { STATUS_ACTIVE } else { 0 };
        self.last_failed = false;
        Ok(())
    }
}

/// Sends board `id` a board-info request and reads its answer.
fn identify<L: ByteTransport>(link: &mut L, id: u8, deadline: Instant) -> Result<BoardInfo, DeviceError> {
    let mut req = [0u8; INFO_REQUEST_LEN];
    protocol::encode_info_request(id, &mut req);
    link.clear_input()?;
    link.write_all(&req, deadline)?;
    let mut rep = [0u8; INFO_REPLY_LEN];
    link.read_exact(&mut rep, deadline)?;
    Ok(protocol::decode_info_reply(id, &rep)?)
}

/// Tells every board the command lengths of each board in `boards` (each board stores the
/// lengths of every id it hears), then the trailing zeros.
fn set_command_lengths<L: ByteTransport>(
    link: &mut L,
    boards: &[BoardInfo],
    deadline: Instant,
) -> Result<(), DeviceError> {
    for b in boards {
        let mut buf = [0u8; SET_CMD_LEN_LEN];
        protocol::encode_set_command_lengths(b, &mut buf);
        link.write_all(&buf, deadline)?;
    }
    link.write_all(&[0u8; SET_CMD_LEN_TRAIL_ZEROS], deadline)
}

/// Why a board's reply layout could not be measured.
enum Measured {
    NoReply(DeviceError),
    /// The reply did not end where any known layout ends (the bytes read).
    Unknown {
        got: heapless::Vec<u8, 64>,
    },
}

/// Sends board `b` a zero current command and a board-info request, and finds the layout whose
/// reply length puts the board-info reply right after the current reply. Allocates nothing.
fn measure_layout<L: ByteTransport>(
    link: &mut L,
    b: &BoardInfo,
    deadline: Instant,
) -> Result<ReplyLayout, Measured> {
    let mut lens: heapless::Vec<(usize, ReplyLayout), 2> = heapless::Vec::new();
    for l in ReplyLayout::ALL {
        let len = b.current_reply_len(l);
        if !lens.iter().any(|(x, _)| *x == len) {
            let _ = lens.push((len, l));
        }
    }
    lens.sort_unstable_by_key(|(len, _)| *len);
    let longest = lens.iter().map(|(len, _)| *len).max().unwrap_or(0);
    let mut tx = [0u8; 128];
    let padding = (longest + 20).saturating_sub(b.current_cmd_len()).max(5);
    tx[0] = protocol::header(cmd::CURRENT, b.id);
    let mut n = b.current_cmd_len() + padding;
    tx[n] = protocol::header(cmd::BOARD_INFO, b.id);
    n += 1 + TICK_END_ZEROS;
    let mut expect = [0u8; INFO_REPLY_LEN];
    protocol::encode_info_reply(b, &mut expect);
    link.clear_input().map_err(Measured::NoReply)?;
    link.write_all(&tx[..n], deadline).map_err(Measured::NoReply)?;
    let mut rx = [0u8; 64];
    let mut got = 0;
    for &(len, layout) in &lens {
        let want = len + INFO_REPLY_LEN;
        if want > rx.len() {
            break;
        }
        if let Err(e) = link.read_exact(&mut rx[got..want], deadline) {
            return Err(if got == 0 {
                Measured::NoReply(e)
            } else {
                Measured::Unknown { got: heapless::Vec::from_slice(&rx[..got]).unwrap_or_default() }
            });
        }
        got = want;
        if rx[0] == protocol::header(cmd::CURRENT, b.id) && rx[len..want] == expect {
            return Ok(layout);
        }
    }
    Err(Measured::Unknown { got: heapless::Vec::from_slice(&rx[..got]).unwrap_or_default() })
}

impl<C: Connector> Device for UartDevice<C> {
    fn open(&mut self) -> Result<(), DeviceError> {
        self.open_detailed().map_err(|e| e.kind_error())
    }

    fn activate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "activate before open")?;
        self.active = true;
        Ok(())
    }

    /// Commands zero at once. The boards hold their last command whatever happens to the host,
    /// so a zero that did not go out is tried once more (a write cut short is followed by the
    /// resynchronising zeros); a failed read after a complete write still left the zero with
    /// the boards.
    fn deactivate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "deactivate before open")?;
        self.active = false;
        let mut scratch = Input::default();
        let first = self.exchange(&Output::default(), &mut scratch);
        if self.resync && self.link.is_some() {
            return self.exchange(&Output::default(), &mut scratch);
        }
        first
    }

    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "exchange before open")?;
        let r = self.exchange_on_link(out, inp);
        if let Err(e) = r {
            self.stats.failed += 1;
            if e.kind() == crate::ErrorKind::Disconnected {
                self.link = None; // closes the descriptor; the reopen opens a fresh one
            }
        }
        r
    }

    /// Opens the port again and checks that the same boards answer in the same layouts, all
    /// within `budget`. Counters restart (their history is forgotten): the rig must be homed again.
    fn reopen(&mut self, budget: Duration) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "reopen before open")?;
        let deadline = Instant::now() + budget;
        self.link = None;
        let mut link = self.conn.connect()?;
        for b in self.boards.iter() {
            let got = identify(&mut link, b.id, deadline)?;
            if got != *b {
                return Err(DeviceError::Protocol { what: "different boards answered after the reconnect" });
            }
        }
        set_command_lengths(&mut link, &self.boards, deadline)?;
        link.clear_input()?;
        for (bi, b) in self.boards.iter().enumerate() {
            let layout = measure_layout(&mut link, b, deadline).map_err(|e| match e {
                Measured::NoReply(e) => e,
                Measured::Unknown { .. } => {
                    DeviceError::Protocol { what: "a board's reply layout is not known after the reconnect" }
                }
            })?;
            if layout != self.layouts[bi] {
                return Err(DeviceError::Protocol { what: "a board's firmware changed after the reconnect" });
            }
        }
        self.unwrap = [Unwrap::new(); MAX_CHANNELS];
        self.resync = false;
        self.last_failed = false;
        self.info_at = InfoAt::Last;
        self.port = link.port_report();
        self.link = Some(link);
        Ok(())
    }

    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}
