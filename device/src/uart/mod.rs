//! The `uart` backend: up to 8 UART motor-driver boards on one 2 Mbaud serial link
//! (reference/boards.md section 3), seen as one [`Device`] whose channels are the boards' motors
//! in board-id order (board 0's motors first).
//!
//! Why it exists: this is how current SPIDAR rigs are wired, and the board emulator
//! ([`crate::emulator`]) speaks the same protocol on a pseudo-terminal, so the whole stack is
//! tested through this driver without hardware. What it must never do: allocate, lock or panic in
//! [`Device::exchange`] or [`Device::reopen`] (both run in the 1 kHz tick), or block longer than
//! its reply deadline. The byte layouts live in [`protocol`]; this module only moves buffers
//! through a [`ByteLink`] and keeps the counters' wrap extension.
//!
//! One exchange: drop stale input, write every board's current command (with its padding) and
//! the tick's closing board-info header in one write, read every board's reply, decode, extend
//! the 16-bit positions to i64. Volts become current commands at `digits_per_volt` (default
//! 4096 / 3.3), clamped to +-4095 by the protocol: the DA range is about +-3.3 V.

pub mod protocol;

use std::ffi::CString;
use std::time::{Duration, Instant};

use crate::frame::Unwrap;
use crate::link::{open_serial, ByteLink, FdLink};
use crate::{short_string, Device, DeviceError, DeviceInfo, Input, OpenError, Output, MAX_CHANNELS};
use protocol::{
    BoardInfo, CurrentReply, INFO_REPLY_LEN, INFO_REQUEST_LEN, MAX_BOARDS, SET_CMD_LEN_REQUEST_LEN,
};

/// Status bit set in `Input::status` while the outputs are enabled.
pub const STATUS_ACTIVE: u32 = 1;

/// Opens the link to the boards. `connect` is called again by [`Device::reopen`] inside the tick,
/// so it must not allocate.
pub trait Connector: Send {
    type Link: ByteLink;
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
    type Link = FdLink;
    fn connect(&mut self) -> Result<FdLink, DeviceError> {
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
    /// DA scale: current-command digits per volt.
    pub digits_per_volt: f64,
    /// Largest counter step in one tick that is believed; a larger one is a corrupt reply.
    pub max_step_counts: i64,
}

impl Default for UartOptions {
    fn default() -> Self {
        UartOptions {
            reply_timeout: Duration::from_micros(800),
            enumerate_timeout: Duration::from_millis(20),
            digits_per_volt: protocol::DEFAULT_DIGITS_PER_VOLT,
            // 4096 counts of 2.9e-5 m is 12 cm in 1 ms: far beyond any hand.
            max_step_counts: 4096,
        }
    }
}

const TX_MAX: usize = 512;
const RX_MAX: usize = 256;

/// The UART boards on one link; see the module doc.
pub struct UartDevice<C: Connector> {
    conn: C,
    link: Option<C::Link>,
    opts: UartOptions,
    boards: heapless::Vec<BoardInfo, MAX_BOARDS>,
    /// First channel of each board in `boards`.
    offsets: [usize; MAX_BOARDS],
    channels: usize,
    unwrap: [Unwrap<16>; MAX_CHANNELS],
    info: DeviceInfo,
    opened: bool,
    active: bool,
    tx: [u8; TX_MAX],
    rx: [u8; RX_MAX],
    /// Latest currents read back from boards with current sensors (raw digits), per channel.
    currents: [i16; MAX_CHANNELS],
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
            offsets: [0; MAX_BOARDS],
            channels: 0,
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
            currents: [0; MAX_CHANNELS],
        }
    }

    /// The boards found by the last enumeration, in id order.
    pub fn boards(&self) -> &[BoardInfo] {
        &self.boards
    }

    pub fn options(&self) -> &UartOptions {
        &self.opts
    }

    /// Raw current readings of the boards that have current sensors, per channel.
    pub fn currents(&self) -> &[i16] {
        &self.currents[..self.channels]
    }

    /// Opens the link, enumerates the boards and tells each its command lengths, with errors
    /// that say what was found. Set-up time (allocates for the messages).
    pub fn open_detailed(&mut self) -> Result<(), OpenError> {
        let port = self.conn.describe().to_owned();
        self.link = None;
        self.opened = false;
        self.active = false;
        let mut link = self.conn.connect().map_err(|e| OpenError::from_serial(&port, e))?;
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
                     the emulator running?)"
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
        let mut off = 0;
        for (i, b) in found.iter().enumerate() {
            self.offsets[i] = off;
            off += usize::from(b.n_motor);
        }
        set_command_lengths(&mut link, &found, Instant::now() + self.opts.enumerate_timeout)
            .map_err(|e| OpenError::from_serial(&port, e))?;
        // Let the boards finish, then drop whatever they sent (the protocol's "drain the input").
        std::thread::sleep(Duration::from_millis(2));
        link.clear_input().map_err(|e| OpenError::from_serial(&port, e))?;
        let names: Vec<String> = found.iter().map(|b| format!("{}#{}", b.model_name(), b.id)).collect();
        self.info = DeviceInfo {
            board: short_string(&format!("UART {}", names.join("+"))),
            identity: short_string(&port),
            channels,
            volts_min: -f64::from(protocol::CURRENT_MAX) / self.opts.digits_per_volt,
            volts_max: f64::from(protocol::CURRENT_MAX) / self.opts.digits_per_volt,
        };
        self.boards = found;
        self.channels = channels;
        self.unwrap = [Unwrap::new(); MAX_CHANNELS];
        self.link = Some(link);
        self.opened = true;
        Ok(())
    }

    /// One exchange on an open link; errors are returned as they are (the caller drops the link
    /// on a disconnect).
    fn exchange_on_link(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        let Some(link) = self.link.as_mut() else {
            return Err(DeviceError::Disconnected { what: "UART link closed, waiting for the reopen" });
        };
        let deadline = Instant::now() + self.opts.reply_timeout;
        link.clear_input()?;
        let mut n = 0;
        let mut reply_len = 0;
        for (bi, b) in self.boards.iter().enumerate() {
            let mut cur = [0i16; protocol::MAX_MOTORS];
            if self.active {
                for (m, c) in cur.iter_mut().enumerate().take(usize::from(b.n_motor)) {
                    let v = out.volts.get(self.offsets[bi] + m).copied().unwrap_or(0.0);
                    *c = protocol::volts_to_current(v, self.opts.digits_per_volt);
                }
            }
            n += protocol::encode_current(b, &cur, &mut self.tx[n..])?;
            reply_len += b.current_reply_len();
        }
        let mut end = [0u8; 1 + protocol::TICK_END_ZEROS];
        protocol::encode_tick_end(self.boards.first().map_or(0, |b| b.id), &mut end);
        self.tx[n..n + end.len()].copy_from_slice(&end);
        n += end.len();
        link.write_all(&self.tx[..n], deadline)?;
        link.read_exact(&mut self.rx[..reply_len], deadline)?;

        // Decode everything before committing anything: a bad board leaves all counters as they were.
        let mut unwrap = self.unwrap;
        let mut counts = [0i64; MAX_CHANNELS];
        let mut currents = self.currents;
        let mut at = 0;
        for (bi, b) in self.boards.iter().enumerate() {
            let len = b.current_reply_len();
            let r: CurrentReply = protocol::decode_current_reply(b, &self.rx[at..at + len])?;
            at += len;
            for m in 0..usize::from(b.n_motor) {
                let ch = self.offsets[bi] + m;
                counts[ch] = unwrap[ch].update(i64::from(r.positions[m]), self.opts.max_step_counts)?;
                if m < usize::from(b.n_current) {
                    currents[ch] = r.currents[m];
                }
            }
        }
        self.unwrap = unwrap;
        self.currents = currents;
        inp.counts = counts;
        inp.status = if self.active { STATUS_ACTIVE } else { 0 };
        Ok(())
    }
}

/// Sends board `id` a board-info request and reads its answer.
fn identify<L: ByteLink>(link: &mut L, id: u8, deadline: Instant) -> Result<BoardInfo, DeviceError> {
    let mut req = [0u8; INFO_REQUEST_LEN];
    protocol::encode_info_request(id, &mut req);
    link.clear_input()?;
    link.write_all(&req, deadline)?;
    let mut rep = [0u8; INFO_REPLY_LEN];
    link.read_exact(&mut rep, deadline)?;
    Ok(protocol::decode_info_reply(id, &rep)?)
}

fn set_command_lengths<L: ByteLink>(
    link: &mut L,
    boards: &[BoardInfo],
    deadline: Instant,
) -> Result<(), DeviceError> {
    for b in boards {
        let mut buf = [0u8; SET_CMD_LEN_REQUEST_LEN];
        protocol::encode_set_command_lengths(b, &mut buf);
        link.write_all(&buf, deadline)?;
    }
    Ok(())
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

    fn deactivate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "deactivate before open")?;
        self.active = false;
        // Command zero currents at once rather than at the next tick.
        let mut scratch = Input::default();
        self.exchange(&Output::default(), &mut scratch)
    }

    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "exchange before open")?;
        let r = self.exchange_on_link(out, inp);
        if let Err(e) = r {
            if e.kind() == crate::ErrorKind::Disconnected {
                self.link = None; // closes the descriptor; the reopen opens a fresh one
            }
        }
        r
    }

    /// Opens the port again and checks that the same boards answer, all within `budget`.
    /// Counters restart (their history is forgotten): the rig must be homed again.
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
        self.unwrap = [Unwrap::new(); MAX_CHANNELS];
        self.link = Some(link);
        Ok(())
    }

    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[cfg(test)]
mod tests;
