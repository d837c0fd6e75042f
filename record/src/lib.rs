//! Recordings of spidar sessions: one MCAP file per session, with zstd-compressed chunks.
//!
//! - [`writer`]: the [`Recorder`](writer::Recorder) writes the rig's channels (every tick, every
//!   hand sample, every contact model taken, every event) and the files and versions that made
//!   the session; [`writer::RecorderThread`] runs it on its own non-real-time thread.
//! - [`reader`]: reads a recording back, also one cut short, checking it is spidar's own.
//! - [`verify`]: re-runs the rt-loop's tick core from the recorded inputs and checks every output.
//! - [`export`]: one CSV file per channel. [`plot`]: SVG plots of a session.
//! - [`play`]: the live view's frames of a world recording, found by time, for `spidar replay`.
//!
//! The channels, schemas and metadata are described in the repository's `docs/recording.md`.

pub mod cdr;
pub mod channel;
pub mod export;
pub mod foxglove;
pub mod plot;
pub mod schema;

/// Format of the recordings this spidar writes and reads (in the `spidar` metadata record).
/// Raised whenever a schema or the meaning of a channel changes.
pub const FORMAT_VERSION: u32 = 5;
/// The MCAP header's profile: what tells a spidar recording from any other MCAP file.
pub const PROFILE: &str = "spidar";
/// spidar's version, as written into recordings.
pub const SPIDAR_VERSION: &str = env!("CARGO_PKG_VERSION");

pub mod play;
pub mod reader;
pub mod summary;
pub mod verify;
pub mod world;
pub mod writer;

#[cfg(test)]
mod play_tests;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod world_tests;

use std::path::PathBuf;

/// Errors of recording and reading recordings. Each says what to do.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    // The cause is in the text (not a `source`), so it is said once.
    #[error("cannot create the recording {}: {cause}; choose a path in a writable directory", path.display())]
    Create { path: PathBuf, cause: std::io::Error },
    #[error("writing the recording {} failed: {why}", path.display())]
    Write { path: PathBuf, why: String },
    #[error("cannot read {}: {cause}", path.display())]
    Open { path: PathBuf, cause: std::io::Error },
    #[error("{} is not a spidar recording: {what}", path.display())]
    NotSpidar { path: PathBuf, what: String },
    #[error("{} was recorded by another version of spidar ({found}); this spidar {} reads recording format {}: replay it with the spidar that wrote it", path.display(), SPIDAR_VERSION, FORMAT_VERSION)]
    OtherVersion { path: PathBuf, found: String },
    #[error("cannot replay {}: {why}", path.display())]
    Replay { path: PathBuf, why: String },
    #[error("{} is damaged: {what}", path.display())]
    Corrupt { path: PathBuf, what: String },
}
