//! Playing a world recording back into the live view: [`ViewTrack`] finds the frames the live
//! view drew (`/world/view`) at any time of the recording without reading it from its start, and
//! [`Player`] moves through them at a speed, pauses and seeks.
//!
//! How a time is found: MCAP chunks carry the first and last log time of their messages. A
//! complete file lists every chunk in its summary section (the chunk index, read from the end of
//! the file); a file cut short has no summary, and the same index is built from the chunk records'
//! headers, hopping from record to record (a few bytes read per chunk, nothing decompressed). A
//! seek then decompresses the one chunk that holds the time (about 1 MiB of messages), whatever
//! the file's length.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::{op, ChunkIndex};
use mcap::sans_io::indexed_reader::{IndexedReadEvent, IndexedReader, IndexedReaderOptions, ReadOrder};

use crate::cdr::{self, Field};
use crate::reader::{self, read_summary, Ending, Flow, RECORD_LIMIT};
use crate::world::{ViewFrameMsg, TOPIC_VIEW, VIEW_ATTACHMENT};
use crate::RecordError;

/// Where a track's chunk index came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Indexed {
    /// The file's summary section (a recording that ended normally).
    Summary,
    /// The chunk records' headers (a file cut short or damaged: it has no summary).
    ChunkHeaders,
}

/// The live view's frames in a world recording, found by time.
pub struct ViewTrack {
    pub path: PathBuf,
    file: Arc<File>,
    chunks: Vec<ChunkIndex>,
    channel: u16,
    /// The live view's scene description (its `scene` message), as the page got it.
    pub description: String,
    /// Unix time (ns) of scene time zero: a message's log time is this plus its time.
    start_ns: u64,
    /// Scene times of the first and the last frame.
    pub first_t_s: f64,
    pub last_t_s: f64,
    /// How the readable part of the file ends.
    pub ending: Ending,
    pub indexed: Indexed,
}

/// A view frame and its log time.
type Timed = (u64, ViewFrameMsg);

impl ViewTrack {
    /// Opens a world recording and indexes its frames. Errors name what is missing: a file that is
    /// not a spidar recording or of another version (as every reader), a rig recording (no view),
    /// a world recording made before views were recorded, a file cut short before its first frame.
    pub fn open(path: &Path) -> Result<ViewTrack, RecordError> {
        let replay = |why: String| RecordError::Replay { path: path.to_path_buf(), why };
        // Checks what the file is, and reads what comes before the first message: the metadata,
        // the view's description and the channels.
        let head = reader::read(path, |_, _| Ok(Flow::Stop))?;
        if head.meta("role") != "world" {
            return Err(replay(
                "it is a rig recording: the view draws the world's (FILE.world.mcap, next to it)".into(),
            ));
        }
        let Some(view) = head.channels.iter().find(|c| c.topic == TOPIC_VIEW) else {
            return Err(replay(format!(
                "it holds no view frames ({TOPIC_VIEW}): it was recorded by a spidar that did not keep them; \
                 `spidar replay --no-view` prints what it holds"
            )));
        };
        if view.schema != ViewFrameMsg::ros_type() {
            return Err(RecordError::OtherVersion {
                path: path.to_path_buf(),
                found: format!("channel {TOPIC_VIEW} has schema '{}'", view.schema),
            });
        }
        let description = head.attachment_text(VIEW_ATTACHMENT).ok_or_else(|| {
            replay(format!("it has no {VIEW_ATTACHMENT} attachment (the view's description)"))
        })?;
        let start_ns = head
            .session
            .get("start_unix_ns")
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| replay("its metadata has no start_unix_ns".into()))?;
        let file = File::open(path).map_err(|e| RecordError::Open { path: path.to_path_buf(), cause: e })?;
        let len =
            file.metadata().map_err(|e| RecordError::Open { path: path.to_path_buf(), cause: e })?.len();
        let (chunks, ending, indexed) = match read_summary(&file, len) {
            Some(s) if !s.chunk_indexes.is_empty() => (s.chunk_indexes, Ending::Complete, Indexed::Summary),
            _ => {
                let (c, e) = scan_chunks(&file, len);
                (c, e, Indexed::ChunkHeaders)
            }
        };
        let mut track = ViewTrack {
            path: path.to_path_buf(),
            file: Arc::new(file),
            chunks,
            channel: view.id,
            description,
            start_ns,
            first_t_s: 0.0,
            last_t_s: 0.0,
            ending,
            indexed,
        };
        let none = || replay("it holds no view frame (cut short before the first one?)".into());
        let first = track.cursor(IndexedReaderOptions::new())?.next()?.ok_or_else(none)?;
        let last = track
            .cursor(IndexedReaderOptions::new().with_order(ReadOrder::ReverseLogTime))?
            .next()?
            .ok_or_else(none)?;
        track.first_t_s = first.1.t_s;
        track.last_t_s = last.1.t_s;
        Ok(track)
    }

    /// Chunks in the index.
    pub fn chunks(&self) -> usize {
        self.chunks.len()
    }

    fn log_ns(&self, t_s: f64) -> u64 {
        // As the recorder stamps its messages.
        self.start_ns.saturating_add((t_s.max(0.0) * 1e9).round() as u64)
    }

    fn cursor(&self, opts: IndexedReaderOptions) -> Result<Cursor, RecordError> {
        let summary = mcap::Summary { chunk_indexes: self.chunks.clone(), ..Default::default() };
        let r = IndexedReader::new_with_options(&summary, opts.with_record_length_limit(RECORD_LIMIT))
            .map_err(|e| self.damaged(e.to_string()))?;
        Ok(Cursor {
            r,
            file: self.file.clone(),
            buf: Vec::new(),
            channel: self.channel,
            path: self.path.clone(),
        })
    }

    fn damaged(&self, why: String) -> RecordError {
        RecordError::Corrupt { path: self.path.clone(), what: why }
    }

    /// The frame showing at `t_s`: the last one at or before it (the first one before the first).
    pub fn frame_at(&self, t_s: f64) -> Result<ViewFrameMsg, RecordError> {
        Ok(self.timed_at(t_s)?.1)
    }

    fn timed_at(&self, t_s: f64) -> Result<Timed, RecordError> {
        let back =
            IndexedReaderOptions::new().with_order(ReadOrder::ReverseLogTime).ending_at(self.log_ns(t_s));
        if let Some(f) = self.cursor(back)?.next()? {
            return Ok(f);
        }
        self.cursor(IndexedReaderOptions::new())?
            .next()?
            .ok_or_else(|| self.damaged("its frames could not be read again".into()))
    }
}

/// Frames of a track in time order (or reverse), read chunk by chunk as needed.
struct Cursor {
    r: IndexedReader,
    file: Arc<File>,
    buf: Vec<u8>,
    channel: u16,
    path: PathBuf,
}

impl Cursor {
    fn next(&mut self) -> Result<Option<Timed>, RecordError> {
        let bad = |what: String| RecordError::Corrupt { path: self.path.clone(), what };
        loop {
            let (offset, length) = match self.r.next_event() {
                None => return Ok(None),
                Some(Err(e)) => return Err(bad(e.to_string())),
                Some(Ok(IndexedReadEvent::Message { header, data })) => {
                    if header.channel_id != self.channel {
                        continue;
                    }
                    let m: ViewFrameMsg = cdr::decode(data)
                        .map_err(|e| bad(format!("message {} on {TOPIC_VIEW}: {e}", header.sequence)))?;
                    return Ok(Some((header.log_time, m)));
                }
                Some(Ok(IndexedReadEvent::ReadChunkRequest { offset, length })) => (offset, length),
            };
            self.buf.resize(length, 0);
            self.file
                .read_exact_at(&mut self.buf, offset)
                .map_err(|e| bad(format!("reading a chunk: {e}")))?;
            self.r.insert_chunk_record_data(offset, &self.buf).map_err(|e| bad(e.to_string()))?;
        }
    }
}

/// The chunk index of a file without a summary, from its chunk records' headers, and where the
/// readable part ends (a record that runs past the end of the file, or does not parse).
fn scan_chunks(file: &File, len: u64) -> (Vec<ChunkIndex>, Ending) {
    let mut chunks = Vec::new();
    let mut pos = mcap::MAGIC.len() as u64;
    let damaged = |at_byte: u64, why: &str| Ending::Damaged { at_byte, why: why.into() };
    loop {
        let mut head = [0u8; 9];
        if file.read_exact_at(&mut head, pos).is_err() {
            return (chunks, Ending::CutShort { at_byte: pos });
        }
        let opcode = head[0];
        let body = u64::from_le_bytes(head[1..9].try_into().unwrap_or_default());
        if body > RECORD_LIMIT as u64 {
            return (chunks, damaged(pos, "a record longer than any spidar writes"));
        }
        let end = pos + 9 + body;
        if end > len {
            return (chunks, Ending::CutShort { at_byte: pos });
        }
        match opcode {
            op::CHUNK => {
                // start, end, uncompressed size, CRC, compression (u32 length + text), compressed size
                let mut h = [0u8; 32];
                if body < 40 || file.read_exact_at(&mut h, pos + 9).is_err() {
                    return (chunks, damaged(pos, "a chunk's header does not read"));
                }
                let u = |i: usize| u64::from_le_bytes(h[i..i + 8].try_into().unwrap_or_default());
                let clen = u32::from_le_bytes(h[28..32].try_into().unwrap_or_default()) as u64;
                let mut rest = vec![0u8; clen.min(64) as usize + 8];
                if clen > 64 || file.read_exact_at(&mut rest, pos + 9 + 32).is_err() {
                    return (chunks, damaged(pos, "a chunk's compression does not read"));
                }
                let compressed_size =
                    u64::from_le_bytes(rest[clen as usize..].try_into().unwrap_or_default());
                if 32 + clen + 8 + compressed_size != body {
                    return (chunks, damaged(pos, "a chunk's sizes do not add up"));
                }
                chunks.push(ChunkIndex {
                    message_start_time: u(0),
                    message_end_time: u(8),
                    chunk_start_offset: pos,
                    chunk_length: 9 + body,
                    message_index_offsets: Default::default(),
                    message_index_length: 0,
                    compression: String::from_utf8_lossy(&rest[..clen as usize]).into_owned(),
                    compressed_size,
                    uncompressed_size: u(16),
                });
            }
            op::DATA_END | op::FOOTER => return (chunks, Ending::Complete),
            _ => {}
        }
        pos = end;
    }
}

/// Moves through a track: plays at a speed, pauses, seeks. The host calls [`Player::advance`]
/// with the wall time gone by and sends the frame it returns.
pub struct Player {
    track: ViewTrack,
    /// The frames after the one shown, and the next one read ahead.
    ahead: Option<Cursor>,
    next: Option<Timed>,
    shown: Timed,
    t_s: f64,
    playing: bool,
    speed: f64,
}

/// Speeds a player accepts.
pub const SPEEDS: std::ops::RangeInclusive<f64> = 0.0625..=16.0;

impl Player {
    /// A player at the track's first frame, paused.
    pub fn new(track: ViewTrack) -> Result<Player, RecordError> {
        let t = track.first_t_s;
        let shown = track.timed_at(t)?;
        let mut p = Player { track, ahead: None, next: None, shown, t_s: t, playing: false, speed: 1.0 };
        p.read_ahead_from(p.shown.0)?;
        Ok(p)
    }

    pub fn track(&self) -> &ViewTrack {
        &self.track
    }

    /// The playback position (scene time); the frame shown is the last one at or before it.
    pub fn t_s(&self) -> f64 {
        self.t_s
    }

    pub fn frame(&self) -> &ViewFrameMsg {
        &self.shown.1
    }

    pub fn playing(&self) -> bool {
        self.playing
    }

    pub fn speed(&self) -> f64 {
        self.speed
    }

    /// At the last frame (playing stops there).
    pub fn at_end(&self) -> bool {
        self.t_s >= self.track.last_t_s
    }

    /// Plays (from the start again when at the end) or pauses.
    pub fn play(&mut self, on: bool) -> Result<(), RecordError> {
        if on && self.at_end() {
            self.seek(self.track.first_t_s)?;
        }
        self.playing = on;
        Ok(())
    }

    /// Sets the speed (clamped to [`SPEEDS`]).
    pub fn set_speed(&mut self, x: f64) {
        if x.is_finite() {
            self.speed = x.clamp(*SPEEDS.start(), *SPEEDS.end());
        }
    }

    /// Goes to scene time `t_s` (clamped to the track): shows the last frame at or before it.
    pub fn seek(&mut self, t_s: f64) -> Result<&ViewFrameMsg, RecordError> {
        let t = if t_s.is_nan() { self.t_s } else { t_s.clamp(self.track.first_t_s, self.track.last_t_s) };
        self.shown = self.track.timed_at(t)?;
        self.t_s = t;
        self.read_ahead_from(self.shown.0)?;
        Ok(&self.shown.1)
    }

    fn read_ahead_from(&mut self, log_ns: u64) -> Result<(), RecordError> {
        let mut c = self.track.cursor(IndexedReaderOptions::new().starting_after(log_ns))?;
        self.next = c.next()?;
        self.ahead = Some(c);
        Ok(())
    }

    /// Moves the position by `wall_s` of wall time at the speed, while playing. Returns the newest
    /// frame the position passed (None: the same frame is still showing). Stops at the end.
    pub fn advance(&mut self, wall_s: f64) -> Result<Option<&ViewFrameMsg>, RecordError> {
        if !self.playing || wall_s.is_nan() || wall_s <= 0.0 {
            return Ok(None);
        }
        self.t_s = (self.t_s + wall_s * self.speed).min(self.track.last_t_s);
        let mut moved = false;
        while let Some(n) = self.next.take() {
            if n.1.t_s > self.t_s {
                self.next = Some(n);
                break;
            }
            self.shown = n;
            moved = true;
            self.next = match self.ahead.as_mut() {
                Some(c) => c.next()?,
                None => None,
            };
        }
        if self.next.is_none() {
            // Nothing after the frame shown: the end of the track.
            self.t_s = self.track.last_t_s;
            self.playing = false;
        }
        Ok(moved.then_some(&self.shown.1))
    }
}
