//! String-geometry calibration of a SPIDAR-H: homing, guided recording, the geometry fit, its
//! report and plots, verification at check points, and writing the result into the rig file.
//!
//! Why it exists: the rig is assembled by hand, its anchors are taped to within centimetres, its
//! counters start anywhere and its metres per count differ from theory by 10 % or more. Every
//! position and force the rig renders depends on that geometry, so it is measured here, from
//! counts recorded with the grip at many poses, with its uncertainty and observability stated.
//!
//! What it must never do: run inside the 1 kHz tick or drive a device (nothing here is
//! real-time: recording reads the tick records of the rt-loop, which holds the strings at minimum
//! tension under its own rules, `TickCore::calibrate`), return a geometry that the data do not
//! determine without saying so (degenerate data is an error, weakly determined parameters are
//! named), or leave a half-written rig file (see [`rigfile`]).
//!
//! Flow: [`record`] (the loop's records through [`ticks::Ticks`]: a [`ticks::VirtualLoop`] here,
//! or the real-time loop of `spidar-runtime`'s calibration session; [`sim`] builds a simulated rig
//! with a wrong-on-purpose truth) -> [`session::SessionFile`] (RON, saved after every pose) ->
//! [`fit`] with its [`quality`] verdict -> report text and [`plot`] SVGs -> [`rigfile`] update
//! (written as [`safefile`] says) -> [`verify`] at check points.

pub mod console;
pub mod display;
pub mod fit;
pub mod jig;
pub mod model;
pub mod plot;
pub mod quality;
pub mod record;
pub mod rigfile;
pub mod rigmap;
pub mod rigmap_plot;
pub mod safefile;
pub mod session;
pub mod sim;
pub mod ticks;
pub mod verify;

pub use fit::{fit_hand, FitOptions, HandFit};
pub use model::HandGeometry;

/// Errors of the calibration crate. Every one a user can cause says what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error(transparent)]
    Config(#[from] spidar_rt::ConfigError),
    #[error("device: {0}")]
    Device(#[from] spidar_device::DeviceError),
    #[error("{file}: {what}: {source}")]
    Io {
        file: String,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}:{line}:{column}: {message}")]
    Parse { file: String, line: usize, column: usize, message: String },
    #[error("{file}: {message}")]
    BadFile { file: String, message: String },
    /// The data cannot determine the geometry; the message says why and what to record.
    #[error("hand {hand}: {message}")]
    Degenerate { hand: usize, message: String },
    /// A string reads inconsistent lengths: slack, slipping on its pulley, or a bad encoder.
    #[error(
        "hand {hand} string {string}: {bad} of {total} readings disagree with the others by more \
         than {limit_mm:.1} mm (worst {worst_mm:.1} mm at pose {worst_pose}): the string is slack or \
         slipping, or its encoder miscounts; check its tension and pulley, then record again"
    )]
    InconsistentString {
        hand: usize,
        string: usize,
        bad: usize,
        total: usize,
        limit_mm: f64,
        worst_mm: f64,
        worst_pose: usize,
    },
    #[error("hand {hand}: the fit did not converge ({why}); check the data for gross errors (wrong hand, swapped channels) and the configured anchors for typos")]
    NoConvergence { hand: usize, why: String },
    #[error("recording: {0}")]
    Recording(String),
    /// The operator stopped the recording (q, or the console closed); outputs were switched off.
    #[error("aborted: {0}")]
    Aborted(String),
    /// A stop signal came (Ctrl-C, SIGTERM, SIGHUP); outputs were switched off.
    #[error("interrupted by {0}")]
    Interrupted(String),
    /// The board stopped answering for good (disconnected, or silent past the limit).
    #[error("the board was lost: {0}")]
    BoardLost(String),
    /// An option out of range; the message names it and its range.
    #[error("{0}")]
    Options(String),
    #[error("simulated rig: {0}")]
    Sim(#[from] spidar_device::sim::SimRigError),
    #[error("rig file {file}: {message}")]
    RigFile { file: String, message: String },
    #[error("plot {file}: {message}")]
    Plot { file: String, message: String },
}

/// RON parse with file, line and column in the error (as `spidar_rt::config` does for rig files).
pub(crate) fn parse_ron<T: serde::de::DeserializeOwned>(text: &str, origin: &str) -> Result<T, CalibError> {
    ron::Options::default().from_str(text).map_err(|e| CalibError::Parse {
        file: origin.to_string(),
        line: e.span.start.line,
        column: e.span.start.col,
        message: e.code.to_string(),
    })
}

/// Parses RON text that must say it is of kind `kind` (its top-level `kind` entry).
pub(crate) fn parse_ron_kind<T: serde::de::DeserializeOwned>(
    text: &str,
    origin: &str,
    kind: spidar_config::FileKind,
) -> Result<T, CalibError> {
    let body = spidar_config::expect_kind(text, origin, kind).map_err(|e| CalibError::Parse {
        file: e.origin,
        line: e.line,
        column: e.column,
        message: e.message,
    })?;
    parse_ron(&body, origin)
}

/// Reads a whole file of at most `spidar_config::MAX_FILE_BYTES` (a device or a pipe that never
/// ends is refused), naming it in the error.
pub(crate) fn read_text(path: &std::path::Path, what: &'static str) -> Result<String, CalibError> {
    spidar_config::read_capped(path, spidar_config::MAX_FILE_BYTES).map_err(|e| CalibError::BadFile {
        file: path.display().to_string(),
        message: format!("{what}: {}", e.message),
    })
}

/// Now as UTC, RFC 3339 to the second: what the rig file and sessions record.
pub fn utc_now() -> String {
    humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()
}
