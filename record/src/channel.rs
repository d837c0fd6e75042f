//! One MCAP channel writer for every recording (the rig's and the world's), and the tap that hands
//! the same encoded messages to a live server (Foxglove WebSocket).
//!
//! Why it exists: both recordings declare their channels the same way (a `ros2msg` schema and a
//! `cdr` channel per topic), number each channel's messages, put the loop-clock time on the
//! recording's wall-clock time line, and must keep chunk indexes Foxglove reads right: no chunk
//! may hold only schema and channel records (its index would start at time 0, and Foxglove and
//! Lichtblick take the smallest chunk start as the recording's start: 1970). So the schemas and
//! channels are declared without ending a chunk, and go into the first chunk with its messages.
//!
//! What it must never do: block or fail the session. A write error is returned to the recorder
//! (which stops writing and counts what is lost); a tap is told every message and must never
//! wait (a live server drops what a slow viewer cannot take).

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use mcap::records::MessageHeader;
use mcap::{McapError, WriteOptions, Writer};

use crate::cdr::{self, Field};
use crate::{PROFILE, SPIDAR_VERSION};

/// One channel as declared: its topic, its schema's name and its `ros2msg` text. A live server
/// advertises exactly these.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelSpec {
    pub topic: &'static str,
    pub schema_name: String,
    pub schema_text: String,
}

impl ChannelSpec {
    /// The channel of topic `topic` carrying `T`.
    pub fn of<T: Field>(topic: &'static str) -> ChannelSpec {
        ChannelSpec { topic, schema_name: T::ros_type(), schema_text: cdr::schema_text::<T>() }
    }
}

/// Message encoding of every spidar channel.
pub const MESSAGE_ENCODING: &str = "cdr";
/// Schema encoding of every spidar channel.
pub const SCHEMA_ENCODING: &str = "ros2msg";

/// Where encoded messages go besides a file: a live server. Called on the recorder's thread.
pub trait Tap: Send {
    /// One message of channel `ch` (its index among the declared channels) at `log_ns` (Unix ns).
    /// Must not wait.
    fn message(&mut self, ch: usize, log_ns: u64, data: &[u8]);
}

/// zstd level: 3 is zstd's default; higher levels cost the recorder thread more for a few
/// per cent (see docs/recording.md for the measurement).
pub const ZSTD_LEVEL: u32 = 3;

/// The writer options every spidar recording uses: zstd chunks, no seeking (a chunk is written
/// whole when it ends, so a process killed outright leaves every finished chunk intact).
/// `chunk_bytes`: None when the recorder ends chunks itself.
pub fn options(chunk_bytes: Option<u64>) -> WriteOptions {
    WriteOptions::new()
        .disable_seeking(true)
        .profile(PROFILE)
        .library(format!("spidar {SPIDAR_VERSION}"))
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(ZSTD_LEVEL)
        .compression_threads(0)
        .chunk_size(chunk_bytes)
}

/// Channels of one recording: their ids, per-channel sequence numbers, the time line, and an
/// encoding buffer reused for every message.
pub struct Channels {
    ids: Vec<u16>,
    seq: Vec<u32>,
    specs: Vec<ChannelSpec>,
    start_unix_ns: u64,
    buf: Vec<u8>,
}

impl Channels {
    /// No channel yet; times count from `start_unix_ns` (loop-clock zero).
    pub fn new(start_unix_ns: u64) -> Channels {
        Channels {
            ids: Vec::new(),
            seq: Vec::new(),
            specs: Vec::new(),
            start_unix_ns,
            buf: Vec::with_capacity(4096),
        }
    }

    /// Declares the channels in `w` (when there is a file), in order: channel `i` is `specs[i]`.
    /// Ends no chunk: the schemas and channels go into the first chunk with its first messages.
    pub fn declare<W: Write + Seek>(
        &mut self,
        w: Option<&mut Writer<W>>,
        specs: Vec<ChannelSpec>,
    ) -> Result<(), McapError> {
        if let Some(w) = w {
            for s in &specs {
                let sid = w.add_schema(&s.schema_name, SCHEMA_ENCODING, s.schema_text.as_bytes())?;
                self.ids.push(w.add_channel(sid, s.topic, MESSAGE_ENCODING, &BTreeMap::new())?);
            }
        }
        self.seq = vec![0; specs.len()];
        self.specs = specs;
        Ok(())
    }

    pub fn specs(&self) -> &[ChannelSpec] {
        &self.specs
    }

    /// Unix time (ns) the recording's times count from.
    pub fn start_unix_ns(&self) -> u64 {
        self.start_unix_ns
    }

    /// The Unix time (ns) of loop-clock time `t_s` (times before zero are taken as zero).
    pub fn log_ns(&self, t_s: f64) -> u64 {
        self.start_unix_ns.saturating_add((t_s.max(0.0) * 1e9).round() as u64)
    }

    /// Encodes `x` as channel `ch`'s next message at `t_s`, hands it to `tap` and writes it into
    /// `w`; returns its encoded size.
    pub fn put<T: Field, W: Write + Seek>(
        &mut self,
        w: Option<&mut Writer<W>>,
        tap: Option<&mut (dyn Tap + 'static)>,
        ch: usize,
        t_s: f64,
        x: &T,
    ) -> Result<usize, McapError> {
        let t = self.log_ns(t_s);
        cdr::encode(x, &mut self.buf);
        self.seq[ch] = self.seq[ch].wrapping_add(1);
        if let Some(tap) = tap {
            tap.message(ch, t, &self.buf);
        }
        if let Some(w) = w {
            let h = MessageHeader {
                channel_id: self.ids[ch],
                sequence: self.seq[ch],
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&h, &self.buf)?;
        }
        Ok(self.buf.len())
    }
}

/// A live Foxglove server takes the recorder's messages as they are written.
impl Tap for spidar_world::foxglove::Publisher {
    fn message(&mut self, ch: usize, log_ns: u64, data: &[u8]) {
        self.publish(ch, log_ns, data);
    }
}

/// A server owned by its writer (the rig's live channels) stops when the writer ends.
impl Tap for spidar_world::foxglove::FoxgloveServer {
    fn message(&mut self, ch: usize, log_ns: u64, data: &[u8]) {
        self.publish(ch, log_ns, data);
    }
}

/// The channels as a live Foxglove server advertises them.
pub fn foxglove_channels(specs: &[ChannelSpec]) -> Vec<spidar_world::foxglove::FoxgloveChannel> {
    specs
        .iter()
        .map(|s| spidar_world::foxglove::FoxgloveChannel {
            topic: s.topic.to_string(),
            encoding: MESSAGE_ENCODING.into(),
            schema_name: s.schema_name.clone(),
            schema: s.schema_text.clone(),
            schema_encoding: SCHEMA_ENCODING.into(),
        })
        .collect()
}
