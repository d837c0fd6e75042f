//! Recordings of spidar sessions: one MCAP file per session, with zstd-compressed chunks.
//!
//! - [`writer`]: the [`Recorder`](writer::Recorder) writes the rig's channels (every tick, every
//!   hand sample, every contact model taken, every event) and the files and versions that made
//!   the session; [`writer::RecorderThread`] runs it on its own non-real-time thread.
//! - [`reader`]: reads a recording back, also one cut short, checking it is spidar's own.
//! - [`verify`]: re-runs the rt-loop's tick core from the recorded inputs and checks every output.
//! - [`export`]: one CSV file per channel. [`plot`]: SVG plots of a session.
//!
//! The channels, schemas and metadata are described in the repository's `docs/recording.md`.

pub mod cdr;
pub mod schema;

/// Format of the recordings this spidar writes and reads (in the `spidar` metadata record).
/// Raised whenever a schema or the meaning of a channel changes.
pub const FORMAT_VERSION: u32 = 1;
/// The MCAP header's profile: what tells a spidar recording from any other MCAP file.
pub const PROFILE: &str = "spidar";
/// spidar's version, as written into recordings.
pub const SPIDAR_VERSION: &str = env!("CARGO_PKG_VERSION");
