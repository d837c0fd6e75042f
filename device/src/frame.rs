//! Frame errors and counter wrap extension shared by every board protocol.
//!
//! Why it exists: each board's counters are narrower than the i64 the rest of the stack sees
//! (24-bit on USB Simple, 16-bit on SH-4 and UART), and each protocol rejects frames the same
//! way. Nothing here allocates or panics; errors are `Copy`.

/// Why a frame was rejected. `Copy`, so raising one in the tick allocates nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// Fewer bytes than the frame needs.
    Short { need: usize, got: usize },
    /// More bytes than the frame has (a caller passing the wrong slice).
    Long { want: usize, got: usize },
    /// The header byte is not the one this reply must start with.
    Header { want: u8, got: u8 },
    /// A board-info reply whose counts no known board has.
    NotABoard,
    /// A counter moved further in one tick than a string can (a corrupt payload byte).
    Jump { counts: u64 },
}

impl FrameError {
    /// A short message for `DeviceError::Corrupt`.
    pub fn what(self) -> &'static str {
        match self {
            FrameError::Short { .. } => "reply too short",
            FrameError::Long { .. } => "reply too long",
            FrameError::Header { .. } => "wrong header byte in the reply",
            FrameError::NotABoard => "board-info reply with impossible motor/sensor counts",
            FrameError::Jump { .. } => "a counter jumped further in one tick than a string can move",
        }
    }
}

/// Checks that a reply has exactly the `len` bytes its frame has.
pub fn exact_len(bytes: &[u8], len: usize) -> Result<(), FrameError> {
    if bytes.len() < len {
        Err(FrameError::Short { need: len, got: bytes.len() })
    } else if bytes.len() > len {
        Err(FrameError::Long { want: len, got: bytes.len() })
    } else {
        Ok(())
    }
}

/// Extends a wrapping counter of `BITS` bits (16 for UART and SH-4, 24 for USB Simple) to i64 by
/// adding the wrapped difference to the previous reading, and rejects steps no string can make
/// (a corrupt payload the protocol has no checksum for).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unwrap<const BITS: u32> {
    last: Option<i64>,
    value: i64,
}

impl<const BITS: u32> Default for Unwrap<BITS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const BITS: u32> Unwrap<BITS> {
    pub const fn new() -> Self {
        Unwrap { last: None, value: 0 }
    }

    /// Forgets the history: the next reading is taken as the (sign-extended) absolute count.
    pub fn reset(&mut self) {
        self.last = None;
    }

    pub fn value(&self) -> i64 {
        self.value
    }

    /// Takes a raw reading (only the low `BITS` bits matter). Fails, leaving the state as it was,
    /// when the step from the previous reading exceeds `max_step` counts.
    pub fn update(&mut self, raw: i64, max_step: i64) -> Result<i64, FrameError> {
        let raw = sign_extend(raw, BITS);
        let Some(last) = self.last else {
            self.last = Some(raw);
            self.value = raw;
            return Ok(raw);
        };
        let diff = sign_extend(raw.wrapping_sub(last), BITS);
        if diff.abs() > max_step {
            return Err(FrameError::Jump { counts: diff.unsigned_abs() });
        }
        self.last = Some(raw);
        self.value = self.value.wrapping_add(diff);
        Ok(self.value)
    }
}

/// Sign-extends the low `bits` bits of `v`.
pub const fn sign_extend(v: i64, bits: u32) -> i64 {
    let shift = 64 - bits;
    (v << shift) >> shift
}

impl From<FrameError> for crate::DeviceError {
    fn from(e: FrameError) -> Self {
        crate::DeviceError::Corrupt { what: e.what() }
    }
}
