//! Device layer of spidar: everything that talks in raw board units (DA volts out, encoder
//! counts in) lives here and nowhere else.
//!
//! A backend implements [`Device`]: open, activate, deactivate, and one [`Device::exchange`] per
//! 1 kHz tick that writes every DA channel and reads every counter. `exchange` runs inside the
//! real-time tick, so implementations must not allocate, lock or panic on that path, and their
//! errors are plain `Copy` data (formatted only later, on a non-real-time thread).

#[cfg(test)]
mod convert_props;
#[cfg(test)]
mod decoder_props;
pub mod discover;
pub mod emulator;
pub mod frame;
pub mod sim;
pub mod transport;
pub mod uart;
#[cfg(test)]
mod uart_tests;
pub mod usb;

use thiserror::Error;

/// Most DA/counter channels one device can have.
pub const MAX_CHANNELS: usize = 16;

/// What the tick writes: DA volts per channel (only the first `DeviceInfo::channels` are used).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Output {
    pub volts: [f64; MAX_CHANNELS],
}

/// What the tick reads: counters extended to i64 (monotonic, no wrap) and board status bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Input {
    pub counts: [i64; MAX_CHANNELS],
    pub status: u32,
}

/// Identity and limits of an opened device.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceInfo {
    /// Board kind, e.g. "simulated SPIDAR-H".
    pub board: heapless::String<48>,
    /// Serial number, port or switch setting: whatever tells two boards apart.
    pub identity: heapless::String<48>,
    pub channels: usize,
    /// DA output range; commands outside it are clipped by the board.
    pub volts_min: f64,
    pub volts_max: f64,
}

/// The small code generic code reacts to (see embedded-hal's `ErrorKind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// No answer within the deadline; the next tick may succeed.
    Timeout,
    /// An answer arrived but was malformed (short, bad header, bad checksum).
    Corrupt,
    /// The board is gone (unplugged, port closed).
    Disconnected,
    /// The board answered something the protocol does not allow in this state.
    Protocol,
    Other,
}

/// Device errors. Every variant is `Copy` so that raising one inside the tick allocates nothing.
#[derive(Clone, Copy, Debug, Error, PartialEq)]
pub enum DeviceError {
    #[error("device did not answer within {waited_us} us: check the cable and that the board is powered")]
    Timeout { waited_us: u32 },
    #[error("corrupt reply from the device ({what}): check the cable; if it persists, the board firmware")]
    Corrupt { what: &'static str },
    #[error("device disconnected ({what}): reconnect it, then restart or wait for the reopen")]
    Disconnected { what: &'static str },
    #[error("protocol error: {what}")]
    Protocol { what: &'static str },
    #[error("device call not allowed while {state}: {what}")]
    WrongState { state: &'static str, what: &'static str },
    #[error("{what}")]
    Other { what: &'static str },
}

/// The error every backend gives for a call that needs an open device.
#[inline]
pub fn require_open(opened: bool, what: &'static str) -> Result<(), DeviceError> {
    if opened {
        Ok(())
    } else {
        Err(DeviceError::WrongState { state: "closed", what })
    }
}

impl DeviceError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            DeviceError::Timeout { .. } => ErrorKind::Timeout,
            DeviceError::Corrupt { .. } => ErrorKind::Corrupt,
            DeviceError::Disconnected { .. } => ErrorKind::Disconnected,
            DeviceError::Protocol { .. } | DeviceError::WrongState { .. } => ErrorKind::Protocol,
            DeviceError::Other { .. } => ErrorKind::Other,
        }
    }
}

/// A motor/encoder board (or the simulated rig) seen as DA volts out and counts in.
///
/// Lifecycle: `open` (identify, reset; outputs zero) -> `activate` (outputs enabled) ->
/// `exchange` once per tick -> `deactivate` (outputs zero). `exchange` may be called while
/// inactive: it then reads the counters and the board holds its outputs at zero.
pub trait Device: Send {
    fn open(&mut self) -> Result<(), DeviceError>;
    fn activate(&mut self) -> Result<(), DeviceError>;
    fn deactivate(&mut self) -> Result<(), DeviceError>;
    /// Writes `out` to every DA channel and reads every counter into `inp`. One call per tick;
    /// must not allocate, lock or panic.
    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError>;
    /// Valid after `open`.
    fn info(&self) -> &DeviceInfo;
    /// One bounded attempt to get a device back after it reported `Disconnected`, called by the
    /// loop from inside the tick at a limited rate: must not allocate or block past `budget`.
    /// On success the counters may have restarted, so the rig must be homed again.
    fn reopen(&mut self, budget: std::time::Duration) -> Result<(), DeviceError> {
        let _ = budget;
        Err(DeviceError::Other { what: "this device cannot be reopened: restart spidar" })
    }
}

impl<D: Device + ?Sized> Device for Box<D> {
    fn open(&mut self) -> Result<(), DeviceError> {
        (**self).open()
    }
    fn activate(&mut self) -> Result<(), DeviceError> {
        (**self).activate()
    }
    fn deactivate(&mut self) -> Result<(), DeviceError> {
        (**self).deactivate()
    }
    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        (**self).exchange(out, inp)
    }
    fn info(&self) -> &DeviceInfo {
        (**self).info()
    }
    fn reopen(&mut self, budget: std::time::Duration) -> Result<(), DeviceError> {
        (**self).reopen(budget)
    }
}

/// Why a board could not be opened, with what was found and what to do (set-up time only, so it
/// carries text; the tick's errors are the `Copy` [`DeviceError`]).
#[derive(Debug, Error)]
pub enum OpenError {
    #[error("{path}: {why}")]
    BadPath { path: String, why: String },
    #[error("no board on {port}: {found}")]
    NoBoard { port: String, found: String },
    #[error("no {board} found (USB {vid:04x}:{pid:04x}); USB devices seen: {found}. Check the cable and power, then `spidar devices`")]
    NoUsbBoard { board: &'static str, vid: u16, pid: u16, found: String },
    #[error("wrong board: {what}")]
    WrongBoard { what: String },
    #[error("permission denied opening {what}: {fix}")]
    Permission { what: String, fix: String },
    #[error("{what}")]
    Device {
        what: String,
        #[source]
        source: DeviceError,
    },
}

impl OpenError {
    pub(crate) fn from_serial(port: &str, e: DeviceError) -> OpenError {
        match e {
            DeviceError::Disconnected { .. } => OpenError::BadPath {
                path: port.into(),
                why: "no such serial port (list them with `spidar devices`; an emulator prints its path)"
                    .into(),
            },
            DeviceError::Other { what } if what.starts_with("permission") => {
                OpenError::Permission { what: port.into(), fix: what.into() }
            }
            e => OpenError::Device { what: port.into(), source: e },
        }
    }

    /// The plain `DeviceError` for the `Device` trait (the text of the others is lost there).
    pub fn kind_error(&self) -> DeviceError {
        match self {
            OpenError::Device { source, .. } => *source,
            OpenError::BadPath { .. } => DeviceError::Disconnected { what: "no such device" },
            OpenError::Permission { .. } => {
                DeviceError::Other { what: "permission denied (see `spidar devices`)" }
            }
            OpenError::NoBoard { .. } | OpenError::NoUsbBoard { .. } => {
                DeviceError::Protocol { what: "no board answered" }
            }
            OpenError::WrongBoard { .. } => DeviceError::Protocol { what: "wrong board" },
        }
    }
}

/// `v` clamped to `-max ..= max`, for any `f64`s without panicking (`f64::clamp` panics on NaN or
/// crossed bounds): a NaN `v` is 0, and a range that is NaN or negative (a board whose range is
/// unknown or nonsense) allows only 0, the safe command.
#[inline]
pub fn clamp_symmetric(v: f64, max: f64) -> f64 {
    if v.is_nan() || max.is_nan() || max < 0.0 {
        return 0.0;
    }
    v.clamp(-max, max)
}

/// Fills a `heapless::String`, cutting at capacity on a char boundary (set-up time only).
pub fn short_string<const N: usize>(s: &str) -> heapless::String<N> {
    let mut out = heapless::String::new();
    for c in s.chars() {
        if out.push(c).is_err() {
            break;
        }
    }
    out
}
