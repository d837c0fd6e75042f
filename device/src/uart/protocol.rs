//! The UART motor-driver boards' wire protocol (reference/boards.md section 3) as pure,
//! allocation-free encode/decode functions over byte buffers, for both sides of the link: the
//! host (the [`super::UartDevice`] driver) and the boards (the emulator in [`crate::emulator`]).
//!
//! What it must never do: touch a transport, allocate, or panic on any input. Decoders return
//! [`FrameError`] for every frame the protocol does not allow (a property test feeds them random
//! and truncated bytes). The protocol has no checksum: a corrupt header or a short reply is
//! caught here, a corrupt payload byte only by the driver's plausibility check on counter steps.

/// Link speed: 2 Mbaud, 8N1, no flow control.
pub const BAUD: u32 = 2_000_000;
use crate::frame::exact_len;
pub use crate::frame::FrameError;

/// Boards on one link have ids 0..7.
pub const MAX_BOARDS: usize = 8;
/// Most motors on one board (B1M/B2M/B3M have 4).
pub const MAX_MOTORS: usize = 4;
/// Most current sensors on one board.
pub const MAX_CURRENTS: usize = 4;
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

/// Enumeration: zero bytes before a board-info request (they resynchronise every board's parser,
/// a zero byte being the header "board 0, no command").
pub const INFO_LEAD_ZEROS: usize = 40;
/// Zero bytes after a board-info request during enumeration.
pub const INFO_TRAIL_ZEROS: usize = 26;
/// Board-info reply: header, model, nTarget, nMotor, nCurrent, nForce, nTouch.
pub const INFO_REPLY_LEN: usize = 7;
/// Bytes of a whole enumeration request.
pub const INFO_REQUEST_LEN: usize = INFO_LEAD_ZEROS + 1 + INFO_TRAIL_ZEROS;
/// Zero bytes after "set command lengths".
pub const SET_CMD_LEN_TRAIL_ZEROS: usize = 5;
/// Bytes of a whole "set command lengths" request: header, 12 lengths, trailing zeros.
pub const SET_CMD_LEN_REQUEST_LEN: usize = 1 + COMMANDS + SET_CMD_LEN_TRAIL_ZEROS;
/// Zero bytes after the board-info header that ends a servo tick.
pub const TICK_END_ZEROS: usize = 5;
/// Largest current command: the DA range of the board.
pub const CURRENT_MAX: i16 = 4095;
/// Default DA scale: a current command of 4096 is 3.3 V.
pub const DEFAULT_DIGITS_PER_VOLT: f64 = 4096.0 / 3.3;

/// Header byte: board id in bits 0..2, command id in bits 3..7.
pub const fn header(command: u8, board: u8) -> u8 {
    (command << 3) | (board & 7)
}

/// (command, board) of a header byte.
pub const fn split_header(h: u8) -> (u8, u8) {
    (h >> 3, h & 7)
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
    /// The known board models (reference/boards.md): model number -> (name, motors, currents, forces).
    pub const MODELS: [(u8, &'static str, u8, u8, u8); 6] = [
        (1, "B1M", 4, 0, 0),
        (2, "B1F", 3, 0, 2),
        (3, "B2M", 4, 0, 0),
        (4, "B2F", 3, 0, 2),
        (5, "B3M", 4, 4, 0),
        (6, "B3F", 3, 3, 2),
    ];

    /// The board a known model number describes, at board id `id`.
    pub fn of_model(id: u8, model: u8) -> Option<BoardInfo> {
        let &(_, _, m, c, f) = Self::MODELS.iter().find(|e| e.0 == model)?;
        Some(BoardInfo { id: id & 7, model, n_target: 12, n_motor: m, n_current: c, n_force: f, n_touch: 0 })
    }

    /// The model number of a board name such as "B1M" (case-insensitive).
    pub fn model_by_name(name: &str) -> Option<u8> {
        Self::MODELS.iter().find(|e| e.1.eq_ignore_ascii_case(name)).map(|e| e.0)
    }

    pub fn model_name(&self) -> &'static str {
        Self::MODELS.iter().find(|e| e.0 == self.model).map_or("unknown model", |e| e.1)
    }

    /// The presence rule of the protocol: model > 0 and 0 < nMotor + nCurrent + nForce < 100, and
    /// (ours) counts this driver can hold.
    pub fn is_present(&self) -> bool {
        let sum = u32::from(self.n_motor) + u32::from(self.n_current) + u32::from(self.n_force);
        self.model > 0
            && sum > 0
            && sum < 100
            && usize::from(self.n_motor) <= MAX_MOTORS
            && usize::from(self.n_current) <= MAX_CURRENTS
    }

    /// Bytes of this board's "current" command: header + nMotor x i16.
    pub fn current_cmd_len(&self) -> usize {
        1 + 2 * usize::from(self.n_motor)
    }

    /// Bytes of this board's reply to "current": header, nMotor positions, nMotor velocities,
    /// nCurrent currents (17 for a 4-motor M board, 25 for a B3M, as documented).
    pub fn current_reply_len(&self) -> usize {
        1 + 4 * usize::from(self.n_motor) + 2 * usize::from(self.n_current)
    }

    /// Zero bytes the host sends after this board's current command: max(5, reply - cmd + 20),
    /// the time the board needs to clock its reply out.
    pub fn current_padding(&self) -> usize {
        (self.current_reply_len() + 20).saturating_sub(self.current_cmd_len()).max(5)
    }

    /// The per-command lengths (including the header) the host declares to this board. Only the
    /// commands spidar sends have known lengths; the others are declared 0 and never sent.
    pub fn command_lengths(&self) -> [u8; COMMANDS] {
        let mut l = [0u8; COMMANDS];
        l[usize::from(cmd::BOARD_INFO)] = 1;
        l[usize::from(cmd::SET_CMD_LEN)] = (1 + COMMANDS) as u8;
        l[usize::from(cmd::CURRENT)] = self.current_cmd_len() as u8;
        l
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

/// Writes "set command lengths" for `info` (header, 12 lengths, 5 zeros) into `buf`; returns the
/// bytes written ([`SET_CMD_LEN_REQUEST_LEN`]).
pub fn encode_set_command_lengths(info: &BoardInfo, buf: &mut [u8; SET_CMD_LEN_REQUEST_LEN]) -> usize {
    buf.fill(0);
    buf[0] = header(cmd::SET_CMD_LEN, info.id);
    buf[1..1 + COMMANDS].copy_from_slice(&info.command_lengths());
    SET_CMD_LEN_REQUEST_LEN
}

/// Volts to a current command: `volts x digits_per_volt`, rounded, clamped to +-4095; NaN is 0.
pub fn volts_to_current(volts: f64, digits_per_volt: f64) -> i16 {
    let d = (volts * digits_per_volt).round();
    if d.is_nan() {
        0
    } else {
        d.clamp(-f64::from(CURRENT_MAX), f64::from(CURRENT_MAX)) as i16
    }
}

/// Writes board `info`'s current command (header, nMotor x i16 little-endian, then the padding
/// zeros) into `buf`; returns the bytes written. `currents` must hold nMotor values.
pub fn encode_current(info: &BoardInfo, currents: &[i16], buf: &mut [u8]) -> Result<usize, FrameError> {
    let n = usize::from(info.n_motor);
    let len = info.current_cmd_len() + info.current_padding();
    if buf.len() < len {
        return Err(FrameError::Short { need: len, got: buf.len() });
    }
    if currents.len() < n {
        return Err(FrameError::Short { need: n, got: currents.len() });
    }
    buf[..len].fill(0);
    buf[0] = header(cmd::CURRENT, info.id);
    for (i, c) in currents[..n].iter().enumerate() {
        buf[1 + 2 * i..3 + 2 * i].copy_from_slice(&c.to_le_bytes());
    }
    Ok(len)
}

/// The end of a servo tick: a board-info header for the first board and 5 zeros.
pub fn encode_tick_end(first_board: u8, buf: &mut [u8; 1 + TICK_END_ZEROS]) {
    buf.fill(0);
    buf[0] = header(cmd::BOARD_INFO, first_board);
}

/// A decoded reply to "current".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CurrentReply {
    pub positions: [i16; MAX_MOTORS],
    pub velocities: [i16; MAX_MOTORS],
    pub currents: [i16; MAX_CURRENTS],
}

/// Decodes board `info`'s reply to "current" (exactly `info.current_reply_len()` bytes).
pub fn decode_current_reply(info: &BoardInfo, bytes: &[u8]) -> Result<CurrentReply, FrameError> {
    if !info.is_present() {
        return Err(FrameError::NotABoard);
    }
    exact_len(bytes, info.current_reply_len())?;
    let want = header(cmd::CURRENT, info.id);
    if bytes[0] != want {
        return Err(FrameError::Header { want, got: bytes[0] });
    }
    let m = usize::from(info.n_motor);
    let c = usize::from(info.n_current);
    let word = |i: usize| i16::from_le_bytes([bytes[1 + 2 * i], bytes[2 + 2 * i]]);
    let mut r = CurrentReply::default();
    for i in 0..m {
        r.positions[i] = word(i);
        r.velocities[i] = word(m + i);
    }
    for i in 0..c {
        r.currents[i] = word(2 * m + i);
    }
    Ok(r)
}

/// The board side: writes `reply` for board `info` into `buf`; returns the bytes written.
pub fn encode_current_reply(
    info: &BoardInfo,
    reply: &CurrentReply,
    buf: &mut [u8],
) -> Result<usize, FrameError> {
    let len = info.current_reply_len();
    if buf.len() < len {
        return Err(FrameError::Short { need: len, got: buf.len() });
    }
    let m = usize::from(info.n_motor).min(MAX_MOTORS);
    let c = usize::from(info.n_current).min(MAX_CURRENTS);
    buf[0] = header(cmd::CURRENT, info.id);
    let mut put = |i: usize, v: i16| buf[1 + 2 * i..3 + 2 * i].copy_from_slice(&v.to_le_bytes());
    for i in 0..m {
        put(i, reply.positions[i]);
        put(m + i, reply.velocities[i]);
    }
    for i in 0..c {
        put(2 * m + i, reply.currents[i]);
    }
    Ok(len)
}

/// What a board's parser made of the host's byte stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HostCommand {
    BoardInfo {
        board: u8,
    },
    SetCommandLengths {
        board: u8,
        lengths: [u8; COMMANDS],
    },
    Current {
        board: u8,
        currents: [i16; MAX_MOTORS],
    },
    /// A command this emulator does not implement, skipped by its declared length.
    Unsupported {
        board: u8,
        command: u8,
    },
}

/// The boards' side of the link: a streaming parser that turns the host's bytes into commands.
///
/// Every board sees every byte; zero bytes are "board 0, no command" and are skipped, which is
/// what the host's zero padding relies on. A command's payload length is known from the board's
/// motor count (current), the protocol (set command lengths), or the lengths the host declared.
/// A header addressed to an absent board is skipped like padding (no board takes it). Never
/// panics, whatever the bytes.
#[derive(Clone, Debug)]
pub struct BoardParser {
    boards: [Option<BoardInfo>; MAX_BOARDS],
    declared: [[u8; COMMANDS]; MAX_BOARDS],
    /// The header being collected and how many payload bytes it needs.
    pending: Option<(u8, usize)>,
    payload: [u8; 32],
    got: usize,
    /// Bytes of commands for absent boards or with unknown lengths.
    pub skipped: u64,
}

impl BoardParser {
    pub fn new(boards: [Option<BoardInfo>; MAX_BOARDS]) -> BoardParser {
        BoardParser {
            boards,
            declared: [[0; COMMANDS]; MAX_BOARDS],
            pending: None,
            payload: [0; 32],
            got: 0,
            skipped: 0,
        }
    }

    /// Forgets any half-received command (the link was reset).
    pub fn reset(&mut self) {
        self.pending = None;
        self.got = 0;
    }

    /// Feeds one byte; returns a command when this byte completed one.
    pub fn push(&mut self, b: u8) -> Option<HostCommand> {
        if let Some((h, need)) = self.pending {
            self.payload[self.got] = b;
            self.got += 1;
            if self.got < need {
                return None;
            }
            self.pending = None;
            return Some(self.complete(h));
        }
        let (command, board) = split_header(b);
        let Some(info) = self.boards[usize::from(board)] else {
            if b != 0 {
                self.skipped += 1;
            }
            return None;
        };
        let need = match command {
            cmd::NONE => return None,
            cmd::BOARD_INFO => 0,
            cmd::SET_CMD_LEN => COMMANDS,
            cmd::CURRENT => 2 * usize::from(info.n_motor),
            c if usize::from(c) < COMMANDS => {
                usize::from(self.declared[usize::from(board)][usize::from(c)]).saturating_sub(1)
            }
            _ => {
                self.skipped += 1;
                return None;
            }
        };
        let need = need.min(self.payload.len());
        if need == 0 {
            return Some(self.complete(b));
        }
        self.pending = Some((b, need));
        self.got = 0;
        None
    }

    fn complete(&mut self, h: u8) -> HostCommand {
        let (command, board) = split_header(h);
        match command {
            cmd::BOARD_INFO => HostCommand::BoardInfo { board },
            cmd::SET_CMD_LEN => {
                let mut lengths = [0u8; COMMANDS];
                lengths.copy_from_slice(&self.payload[..COMMANDS]);
                self.declared[usize::from(board)] = lengths;
                HostCommand::SetCommandLengths { board, lengths }
            }
            cmd::CURRENT => {
                let mut currents = [0i16; MAX_MOTORS];
                let n = self.boards[usize::from(board)].map_or(0, |i| usize::from(i.n_motor));
                for (i, c) in currents.iter_mut().enumerate().take(n) {
                    *c = i16::from_le_bytes([self.payload[2 * i], self.payload[2 * i + 1]]);
                }
                HostCommand::Current { board, currents }
            }
            _ => HostCommand::Unsupported { board, command },
        }
    }
}
