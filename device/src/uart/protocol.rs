//! The UART motor-driver boards' wire protocol (`docs/protocols.md`, section "UART boards") as
//! pure, allocation-free encode/decode functions over byte buffers, for both sides of the link:
//! the host (the [`super::UartDevice`] driver) and the boards (the emulator in
//! [`crate::emulator`], which runs one [`BoardParser`] per board as the firmware does).
//!
//! What it must never do: touch a transport, allocate, or panic on any input. Decoders return
//! [`FrameError`] for every frame the protocol does not allow (a property test feeds them random
//! and truncated bytes). The protocol has no checksum: a corrupt header or a short reply is
//! caught here, a corrupt payload byte only by the driver's plausibility check on counter steps.
//!
//! Two facts shape everything here:
//! - Every board skips the commands of the others by their length, taken from a per-board-id
//!   table the host declares ("set command lengths"). The boards' parser ends a command after
//!   `length - 1` bytes following its header, so a declared 0 never ends: the board stops
//!   parsing until it is power-cycled. [`BoardInfo::command_lengths`] therefore computes every
//!   command's real length from the board's counts and can never return 0.
//! - The reply to the current command changed with the firmware: since 2021-08 it carries the
//!   force sensors after the positions and velocities ([`ReplyLayout::Forces`]), before that the
//!   current sensors ([`ReplyLayout::Currents`]). The driver measures which one a board uses.

/// Link speed: 2 Mbaud, 8N1, no flow control.
pub const BAUD: u32 = 2_000_000;
use crate::frame::exact_len;
pub use crate::frame::FrameError;

/// Boards on one link have ids 0..7.
pub const MAX_BOARDS: usize = 8;
/// Most motors on one board (B5M has 8).
pub const MAX_MOTORS: usize = 8;
/// Most sensor words (currents or forces) after the velocities in one reply.
pub const MAX_SENSORS: usize = 8;
/// Number of command ids (0..11); "set command lengths" carries one length per id.
pub const COMMANDS: usize = 12;

/// Command ids (bits 3..7 of a header byte).
pub mod cmd {
    pub const NONE: u8 = 0;
    pub const BOARD_INFO: u8 = 1;
    pub const SET_CMD_LEN: u8 = 2;
    pub const ALL: u8 = 3;
    pub const SENSOR: u8 = 4;
    pub const DIRECT: u8 = 5;
    pub const CURRENT: u8 = 6;
    pub const INTERPOLATE: u8 = 7;
    pub const FORCE_CONTROL: u8 = 8;
    pub const SET_PARAM: u8 = 9;
    pub const RESET_SENSOR: u8 = 10;
    pub const GET_PARAM: u8 = 11;
}

/// Zero bytes that bring every board's parser back to "waiting for a header": before each
/// enumeration request, and before the next command after a write that was cut short (the zeros
/// complete whatever command a board was in the middle of, then are skipped as padding).
pub const RESYNC_ZEROS: usize = 40;
/// Enumeration: zero bytes before a board-info request.
pub const INFO_LEAD_ZEROS: usize = RESYNC_ZEROS;
/// Zero bytes after a board-info request when another command follows (the reply's padding).
pub const INFO_TRAIL_ZEROS: usize = 26;
/// Board-info reply: header, model, nTarget, nMotor, nCurrent, nForce, nTouch.
pub const INFO_REPLY_LEN: usize = 7;
/// Bytes of a whole enumeration request.
pub const INFO_REQUEST_LEN: usize = INFO_LEAD_ZEROS + 1 + INFO_TRAIL_ZEROS;
/// Zero bytes after "set command lengths".
pub const SET_CMD_LEN_TRAIL_ZEROS: usize = 5;
/// Bytes of one "set command lengths" command: header and 12 lengths.
pub const SET_CMD_LEN_LEN: usize = 1 + COMMANDS;
/// Zero bytes after the board-info header that ends a servo tick.
pub const TICK_END_ZEROS: usize = 5;
/// A PWM duty of 100 % (boards without current sensors copy the command to the duty and clip
/// it at +-this).
pub const PWM_FULL: i16 = 1024;
/// Largest current target of a board with current sensors (current-sense ADC counts).
pub const CURRENT_MAX: i16 = 4095;
/// The lab host driver's scale: a command of 4096 is 3.3 "V". Only a convention of the host:
/// the boards see digits (see [`PWM_FULL`] and [`CURRENT_MAX`] for what they mean).
pub const HOST_DIGITS_PER_VOLT: f64 = 4096.0 / 3.3;
/// Board position counts per motor revolution with the boards' default sensor (the motor's
/// magnetic angle sensor, 1/1024 revolution per count).
pub const MAGNET_COUNTS_PER_REV: u32 = 1024;

/// Header byte: board id in bits 0..2, command id in bits 3..7.
pub const fn header(command: u8, board: u8) -> u8 {
    (command << 3) | (board & 7)
}

/// (command, board) of a header byte.
pub const fn split_header(h: u8) -> (u8, u8) {
    (h >> 3, h & 7)
}

/// A known board model: its number (as reported in board info), name and counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Model {
    pub number: u8,
    pub name: &'static str,
    pub motors: u8,
    pub currents: u8,
    pub forces: u8,
}

/// The models the boards' firmware defines (all with 12 interpolation targets).
pub const MODELS: [Model; 7] = [
    Model { number: 1, name: "B1M", motors: 4, currents: 0, forces: 0 },
    Model { number: 2, name: "B1F", motors: 3, currents: 0, forces: 2 },
    Model { number: 3, name: "B2M", motors: 4, currents: 0, forces: 0 },
    Model { number: 4, name: "B2F", motors: 3, currents: 0, forces: 2 },
    Model { number: 5, name: "B3M", motors: 4, currents: 4, forces: 0 },
    Model { number: 6, name: "B3F", motors: 3, currents: 3, forces: 2 },
    Model { number: 7, name: "B5M", motors: 8, currents: 0, forces: 4 },
];

/// What follows the positions and velocities in a board's reply to the current command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ReplyLayout {
    /// Firmware since 2021-08: one word per force sensor (17 bytes for the 3- and 4-motor
    /// models, 41 for B5M).
    Forces,
    /// Firmware of 2020-01 to 2021-08: one word per current sensor (B3M 25 bytes, B3F 19,
    /// B1F/B2F 13, B1M/B2M 17).
    Currents,
}

impl ReplyLayout {
    pub const ALL: [ReplyLayout; 2] = [ReplyLayout::Forces, ReplyLayout::Currents];

    /// Which firmware replies this way, for messages.
    pub fn firmware(self) -> &'static str {
        match self {
            ReplyLayout::Forces => "firmware since 2021-08 (forces in the reply)",
            ReplyLayout::Currents => "firmware of 2020-21 (currents in the reply)",
        }
    }
}

/// What a board says about itself in reply to "board info".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct BoardInfo {
    pub id: u8,
    pub model: u8,
    pub n_target: u8,
    pub n_motor: u8,
    pub n_current: u8,
    pub n_force: u8,
    pub n_touch: u8,
}

impl BoardInfo {
    /// The board a known model number describes, at board id `id`.
    pub fn of_model(id: u8, model: u8) -> Option<BoardInfo> {
        let m = MODELS.iter().find(|e| e.number == model)?;
        Some(BoardInfo {
            id: id & 7,
            model,
            n_target: 12,
            n_motor: m.motors,
            n_current: m.currents,
            n_force: m.forces,
            n_touch: 0,
        })
    }

    /// The model number of a board name such as "B1M" (case-insensitive).
    pub fn model_by_name(name: &str) -> Option<u8> {
        MODELS.iter().find(|e| e.name.eq_ignore_ascii_case(name)).map(|e| e.number)
    }

    pub fn model_name(&self) -> &'static str {
        MODELS.iter().find(|e| e.number == self.model).map_or("unknown model", |e| e.name)
    }

    /// The presence rule of the protocol (model > 0 and 0 < nMotor + nCurrent + nForce < 100),
    /// and counts this driver can hold: 1..8 motors, at most 8 current and 8 force sensors.
    pub fn is_present(&self) -> bool {
        let sum = u32::from(self.n_motor) + u32::from(self.n_current) + u32::from(self.n_force);
        self.model > 0
            && sum > 0
            && sum < 100
            && self.n_motor >= 1
            && usize::from(self.n_motor) <= MAX_MOTORS
            && usize::from(self.n_current) <= MAX_SENSORS
            && usize::from(self.n_force) <= MAX_SENSORS
    }

    /// Whether motor `m`'s command is a current target (the board has a current sensor for it)
    /// rather than a PWM duty.
    pub fn current_sensed(&self, m: usize) -> bool {
        m < usize::from(self.n_current)
    }

    /// Bytes of this board's "current" command: header + nMotor x i16.
    pub fn current_cmd_len(&self) -> usize {
        1 + 2 * usize::from(self.n_motor)
    }

    /// Sensor words after the positions and velocities in the reply to "current".
    pub fn reply_sensors(&self, layout: ReplyLayout) -> usize {
        usize::from(match layout {
            ReplyLayout::Forces => self.n_force,
            ReplyLayout::Currents => self.n_current,
        })
    }

    /// Bytes of this board's reply to "current": header, nMotor positions, nMotor velocities,
    /// then the layout's sensor words.
    pub fn current_reply_len(&self, layout: ReplyLayout) -> usize {
        1 + 4 * usize::from(self.n_motor) + 2 * self.reply_sensors(layout)
    }

    /// Zero bytes the host sends after this board's current command: max(5, reply - cmd + 20),
    /// the time the board needs to clock its reply out before the next board's reply starts.
    pub fn current_padding(&self, layout: ReplyLayout) -> usize {
        (self.current_reply_len(layout) + 20).saturating_sub(self.current_cmd_len()).max(5)
    }

    /// The length (header included) of every command id 0..11 for this board, as the firmware
    /// lays the commands out, from the board's motor and force counts (positions, velocities and
    /// the other per-motor words are 2 bytes):
    ///
    /// | id | command | length |
    /// |---|---|---|
    /// | 0, 1, 4 | none, board info, sensor | 1 |
    /// | 2 | set command lengths | 13 |
    /// | 3 | all | 1 + 4 + 2M + 2M max(1, F) |
    /// | 5 | direct | 1 + 4M |
    /// | 6 | current | 1 + 2M |
    /// | 7 | interpolate | 1 + 2M + 3 |
    /// | 8 | force control | 1 + 2M + 2FM + 3 |
    /// | 9 | set param | 1 + 1 + max(4M, 8) |
    /// | 10 | reset sensor | 3 |
    /// | 11 | get param | 2 |
    ///
    /// For a B1M (M = 4, F = 0): `1 1 13 21 1 17 9 12 12 18 3 2`. Never 0 and never above 255
    /// for any board [`BoardInfo::is_present`] accepts (a test checks every combination).
    pub fn command_lengths(&self) -> [u8; COMMANDS] {
        let m = usize::from(self.n_motor);
        let f = usize::from(self.n_force);
        let mut l = [0usize; COMMANDS];
        l[usize::from(cmd::NONE)] = 1;
        l[usize::from(cmd::BOARD_INFO)] = 1;
        l[usize::from(cmd::SET_CMD_LEN)] = SET_CMD_LEN_LEN;
        // Mode, target count, period (2), then current[M] overlaid on pos[M] + (vel[M] or jacobian[F][M]).
        l[usize::from(cmd::ALL)] = 1 + 4 + 2 * m + 2 * m * f.max(1);
        l[usize::from(cmd::SENSOR)] = 1;
        l[usize::from(cmd::DIRECT)] = 1 + 4 * m;
        l[usize::from(cmd::CURRENT)] = self.current_cmd_len();
        // pos[M], period (2), target count (1).
        l[usize::from(cmd::INTERPOLATE)] = 1 + 2 * m + 3;
        l[usize::from(cmd::FORCE_CONTROL)] = 1 + 2 * m + 2 * f * m + 3;
        // Parameter type, then the largest of its alternatives: 2 x M words, or two 32-bit baud rates.
        l[usize::from(cmd::SET_PARAM)] = 1 + 1 + (4 * m).max(8);
        l[usize::from(cmd::RESET_SENSOR)] = 3;
        l[usize::from(cmd::GET_PARAM)] = 2;
        l.map(|x| x.clamp(1, 255) as u8)
    }
}

/// Writes the enumeration request for board `id` into `buf` (at least [`INFO_REQUEST_LEN`] bytes);
/// returns the bytes written.
pub fn encode_info_request(id: u8, buf: &mut [u8]) -> usize {
    let n = INFO_REQUEST_LEN.min(buf.len());
    buf[..n].fill(0);
    if let Some(b) = buf.get_mut(INFO_LEAD_ZEROS) {
        *b = header(cmd::BOARD_INFO, id);
    }
    n
}

/// Decodes board `id`'s 7-byte board-info reply.
pub fn decode_info_reply(id: u8, bytes: &[u8]) -> Result<BoardInfo, FrameError> {
    exact_len(bytes, INFO_REPLY_LEN)?;
    let want = header(cmd::BOARD_INFO, id);
    if bytes[0] != want {
        return Err(FrameError::Header { want, got: bytes[0] });
    }
    let info = BoardInfo {
        id: id & 7,
        model: bytes[1],
        n_target: bytes[2],
        n_motor: bytes[3],
        n_current: bytes[4],
        n_force: bytes[5],
        n_touch: bytes[6],
    };
    if info.is_present() {
        Ok(info)
    } else {
        Err(FrameError::NotABoard)
    }
}

/// The board side: writes `info`'s board-info reply into `buf` (7 bytes).
pub fn encode_info_reply(info: &BoardInfo, buf: &mut [u8; INFO_REPLY_LEN]) {
    *buf = [
        header(cmd::BOARD_INFO, info.id),
        info.model,
        info.n_target,
        info.n_motor,
        info.n_current,
        info.n_force,
        info.n_touch,
    ];
}

/// Writes "set command lengths" for `info` (header and 12 lengths) into `buf`; returns the bytes
/// written ([`SET_CMD_LEN_LEN`]). The lengths come from [`BoardInfo::command_lengths`]: none is 0.
pub fn encode_set_command_lengths(info: &BoardInfo, buf: &mut [u8; SET_CMD_LEN_LEN]) -> usize {
    buf[0] = header(cmd::SET_CMD_LEN, info.id);
    buf[1..].copy_from_slice(&info.command_lengths());
    SET_CMD_LEN_LEN
}

/// Volts of the host's scale to a board command: `volts x digits_per_volt`, rounded, clamped to
/// `+-limit` digits; NaN is 0. Never panics, for any input or scale: a negative `limit` allows 0.
pub fn volts_to_digits(volts: f64, digits_per_volt: f64, limit: i16) -> i16 {
    // `as` saturates to the i16 range (the limit's own magnitude may be 32768 for i16::MIN).
    crate::clamp_symmetric((volts * digits_per_volt).round(), f64::from(limit)) as i16
}

/// Writes board `info`'s current command (header, nMotor x i16 little-endian, then the padding
/// zeros for `layout`) into `buf`; returns the bytes written. `commands` must hold nMotor values.
pub fn encode_current(
    info: &BoardInfo,
    layout: ReplyLayout,
    commands: &[i16],
    buf: &mut [u8],
) -> Result<usize, FrameError> {
    let n = usize::from(info.n_motor);
    let len = info.current_cmd_len() + info.current_padding(layout);
    if buf.len() < len {
        return Err(FrameError::Short { need: len, got: buf.len() });
    }
    if commands.len() < n {
        return Err(FrameError::Short { need: n, got: commands.len() });
    }
    buf[..len].fill(0);
    buf[0] = header(cmd::CURRENT, info.id);
    for (i, c) in commands[..n].iter().enumerate() {
        buf[1 + 2 * i..3 + 2 * i].copy_from_slice(&c.to_le_bytes());
    }
    Ok(len)
}

/// A board-info request for board `board` followed by `zeros` zero bytes (the tick's closing
/// request takes [`TICK_END_ZEROS`]; one followed by more commands takes [`INFO_TRAIL_ZEROS`]).
/// Returns the bytes written.
pub fn encode_info_marker(board: u8, zeros: usize, buf: &mut [u8]) -> Result<usize, FrameError> {
    let len = 1 + zeros;
    if buf.len() < len {
        return Err(FrameError::Short { need: len, got: buf.len() });
    }
    buf[..len].fill(0);
    buf[0] = header(cmd::BOARD_INFO, board);
    Ok(len)
}

/// A decoded reply to "current".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CurrentReply {
    pub positions: [i16; MAX_MOTORS],
    pub velocities: [i16; MAX_MOTORS],
    /// Force-sensor words ([`ReplyLayout::Forces`]) or current-sensor words
    /// ([`ReplyLayout::Currents`]).
    pub sensors: [i16; MAX_SENSORS],
}

/// Decodes board `info`'s reply to "current" in `layout` (exactly
/// `info.current_reply_len(layout)` bytes).
pub fn decode_current_reply(
    info: &BoardInfo,
    layout: ReplyLayout,
    bytes: &[u8],
) -> Result<CurrentReply, FrameError> {
    if !info.is_present() {
        return Err(FrameError::NotABoard);
    }
    exact_len(bytes, info.current_reply_len(layout))?;
    let want = header(cmd::CURRENT, info.id);
    if bytes[0] != want {
        return Err(FrameError::Header { want, got: bytes[0] });
    }
    let m = usize::from(info.n_motor);
    let word = |i: usize| i16::from_le_bytes([bytes[1 + 2 * i], bytes[2 + 2 * i]]);
    let mut r = CurrentReply::default();
    for i in 0..m {
        r.positions[i] = word(i);
        r.velocities[i] = word(m + i);
    }
    for i in 0..info.reply_sensors(layout) {
        r.sensors[i] = word(2 * m + i);
    }
    Ok(r)
}

/// The board side: writes `reply` for board `info` in `layout` into `buf`; returns the bytes
/// written.
pub fn encode_current_reply(
    info: &BoardInfo,
    layout: ReplyLayout,
    reply: &CurrentReply,
    buf: &mut [u8],
) -> Result<usize, FrameError> {
    if !info.is_present() {
        return Err(FrameError::NotABoard);
    }
    let len = info.current_reply_len(layout);
    if buf.len() < len {
        return Err(FrameError::Short { need: len, got: buf.len() });
    }
    let m = usize::from(info.n_motor);
    buf[0] = header(cmd::CURRENT, info.id);
    let mut put = |i: usize, v: i16| buf[1 + 2 * i..3 + 2 * i].copy_from_slice(&v.to_le_bytes());
    for i in 0..m {
        put(i, reply.positions[i]);
        put(m + i, reply.velocities[i]);
    }
    for i in 0..info.reply_sensors(layout) {
        put(2 * m + i, reply.sensors[i]);
    }
    Ok(len)
}

// ---------------------------------------------------------------------------------------------
// The boards' side: the firmware's command parser.

/// A command a board's parser completed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HostCommand {
    BoardInfo {
        board: u8,
    },
    /// Every board takes this one, whatever its id: it stores the lengths for `board`.
    SetCommandLengths {
        board: u8,
        lengths: [u8; COMMANDS],
    },
    Current {
        board: u8,
        commands: [i16; MAX_MOTORS],
    },
    /// Another command for this board (taken by its declared length; not emulated).
    Other {
        board: u8,
        command: u8,
    },
}

/// What one byte did to a board's parser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ParseStep {
    /// A header addressed to this board arrived: the board starts its reply to this command now
    /// (a few byte times later on the wire), before the command's payload has arrived, so the
    /// reply carries the state from before the command.
    pub reply_to: Option<u8>,
    /// This byte completed a command this board reads (its own, or any "set command lengths").
    pub done: Option<HostCommand>,
}

/// One board's command parser, as the boards' firmware has it.
///
/// Every board sees every byte. Between commands, a zero byte or a header with a command id of
/// 12 or more is skipped. A header starts a command whose length is looked up in the table
/// entry for the header's board id; the command ends when `length - 1` further bytes have been
/// taken (a length of 1 ends it at the header). A length of 0 therefore never ends: the board
/// takes every following byte as payload and is lost until power-off ([`BoardParser::is_locked`]).
/// The tables start as the board's own command lengths for every id and are replaced by every
/// "set command lengths", whichever board it addresses. Never panics, whatever the bytes.
#[derive(Clone, Debug)]
pub struct BoardParser {
    id: u8,
    table: [[u8; COMMANDS]; MAX_BOARDS],
    header: u8,
    /// Bytes of the current command taken so far, header included (0: waiting for a header).
    taken: u64,
    /// Declared length of the current command.
    length: u8,
    /// Whether this board keeps the payload (its own command or "set command lengths").
    keep: bool,
    payload: [u8; 2 * MAX_MOTORS + COMMANDS],
    /// Header bytes skipped while waiting for a header (zero bytes not counted).
    pub skipped: u64,
}

impl BoardParser {
    /// The parser of board `info` after power-on.
    pub fn new(info: &BoardInfo) -> BoardParser {
        BoardParser {
            id: info.id & 7,
            table: [info.command_lengths(); MAX_BOARDS],
            header: 0,
            taken: 0,
            length: 0,
            keep: false,
            payload: [0; 2 * MAX_MOTORS + COMMANDS],
            skipped: 0,
        }
    }

    /// The length table this board uses for board id `board`'s commands.
    pub fn table(&self, board: u8) -> [u8; COMMANDS] {
        self.table[usize::from(board & 7)]
    }

    /// True once a command with a declared length of 0 has started: the board takes every later
    /// byte as its payload and never parses a command again (until power-off).
    pub fn is_locked(&self) -> bool {
        self.taken > 0 && self.length == 0
    }

    /// Feeds one byte.
    pub fn push(&mut self, b: u8) -> ParseStep {
        let mut step = ParseStep::default();
        if self.taken == 0 {
            if b == 0 {
                return step;
            }
            if usize::from(b >> 3) >= COMMANDS {
                self.skipped += 1;
                return step;
            }
            let (command, board) = split_header(b);
            self.header = b;
            self.length = self.table[usize::from(board)][usize::from(command)];
            self.keep = board == self.id || command == cmd::SET_CMD_LEN;
            if board == self.id {
                step.reply_to = Some(command);
            }
        } else if self.keep {
            if let Some(slot) = self.payload.get_mut((self.taken - 1) as usize) {
                *slot = b;
            }
        }
        // Ends after length - 1 bytes past the header; a length of 0 never does.
        if u64::from(self.length) == self.taken + 1 {
            self.taken = 0;
            if self.keep {
                step.done = Some(self.complete());
            }
        } else {
            self.taken = self.taken.saturating_add(1);
        }
        step
    }

    fn complete(&mut self) -> HostCommand {
        let (command, board) = split_header(self.header);
        match command {
            cmd::SET_CMD_LEN => {
                let mut lengths = [0u8; COMMANDS];
                lengths.copy_from_slice(&self.payload[..COMMANDS]);
                self.table[usize::from(board)] = lengths;
                HostCommand::SetCommandLengths { board, lengths }
            }
            cmd::BOARD_INFO => HostCommand::BoardInfo { board },
            cmd::CURRENT => {
                // The payload holds what the declared length let in; the rest reads as 0.
                let mut commands = [0i16; MAX_MOTORS];
                for (i, c) in commands.iter_mut().enumerate() {
                    *c = i16::from_le_bytes([self.payload[2 * i], self.payload[2 * i + 1]]);
                }
                let taken = usize::from(self.length.saturating_sub(1));
                for (i, c) in commands.iter_mut().enumerate() {
                    if 2 * i + 2 > taken {
                        *c = 0;
                    }
                }
                HostCommand::Current { board, commands }
            }
            _ => HostCommand::Other { board, command },
        }
    }
}
