//! Writing a recording: the [`Recorder`] (one MCAP file, zstd chunks) and the
//! [`RecorderThread`] that runs it beside a live session.
//!
//! The rt-loop never waits for a recording: its tick sends a [`TickRecord`] on the telemetry
//! channel it always fills (dropped and counted when full); the session's consumer hands each
//! record to the recorder thread in batches (dropped and counted when that queue is full); the
//! recorder thread encodes and compresses. A write error (disk full) stops the writing and
//! counts every record after it; the file keeps every chunk written before, and a reader
//! reads it up to there.
//!
//! One tick becomes, in this order: its events, the contact model it took (if any), the tick,
//! and the hand sample it sent. Everything before the first message (the header, the metadata,
//! the attachments) is written when the file is created, so even a file cut short says what
//! made it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Sender, TrySendError};
use mcap::records::Metadata;
use mcap::{Attachment, Writer};
use spidar_rt::telemetry::TickRecord;

use crate::cdr::Field;
use crate::channel::{self, ChannelSpec, Channels, Tap};
use crate::schema::{EventMsg, TakenModel, TOPIC_EVENT, TOPIC_MODEL, TOPIC_SAMPLE, TOPIC_TICK};
use crate::{RecordError, FORMAT_VERSION, SPIDAR_VERSION};

/// Uncompressed size of a chunk. A session killed outright loses at most the chunk being filled
/// (about half a second of ticks at 1 kHz).
pub const CHUNK_BYTES: u64 = 1 << 20;
/// Name of the metadata record that says what made the recording.
pub const META_SESSION: &str = "spidar";
/// Name of the metadata record written when a recording ends normally.
pub const META_END: &str = "spidar.end";
/// Name of the rig file's attachment.
pub const RIG_ATTACHMENT: &str = "rig.ron";

/// What made a session: written into the recording's metadata and attachments.
#[derive(Clone, Debug, Default)]
pub struct SessionInfo {
    /// Where the rig file came from (a path, or the built-in file's name).
    pub rig_origin: String,
    /// The rig file's text (RON), attached as `rig.ron`: replay builds the tick core from it.
    pub rig_text: String,
    pub scene: String,
    pub script: String,
    pub device: String,
    /// Seed of the simulated rig and random scripts.
    pub seed: u64,
    /// The command line that ran the session.
    pub command_line: String,
    /// True when the session ran on the virtual clock.
    pub virtual_clock: bool,
    /// Other files that made the session (scene, script, boxer files): (name, text), attached.
    pub files: Vec<(String, String)>,
}

/// How a session ended, written as the `spidar.end` metadata record.
#[derive(Clone, Debug, Default)]
pub struct EndInfo {
    /// Ticks the loop ran.
    pub ticks: u64,
    /// Records the loop's telemetry channel dropped (the consumer lagged).
    pub telemetry_dropped: u64,
    pub final_state: String,
    pub clean_stop: bool,
    pub faults: u64,
}

/// What a recorder wrote and what it could not keep.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RecordingReport {
    pub path: PathBuf,
    pub ticks: u64,
    pub samples: u64,
    pub models: u64,
    pub events: u64,
    /// Records the recorder's queue had no room for (the disk or the recorder thread lagged).
    pub queue_dropped: u64,
    /// Records not written because writing failed (see `error`).
    pub write_failed: u64,
    /// Records the loop's telemetry channel dropped before the recorder saw them.
    pub telemetry_dropped: u64,
    /// The first write error, e.g. a full disk.
    pub error: Option<String>,
    pub bytes: u64,
}

impl RecordingReport {
    /// Every tick record that is not in the file.
    pub fn lost(&self) -> u64 {
        self.queue_dropped + self.write_failed + self.telemetry_dropped
    }
}

impl std::fmt::Display for RecordingReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} ticks, {} samples, {} models, {} events, {:.1} MB; not kept: {} (telemetry {}, recorder queue {}, write {})",
            self.path.display(),
            self.ticks,
            self.samples,
            self.models,
            self.events,
            self.bytes as f64 / 1e6,
            self.lost(),
            self.telemetry_dropped,
            self.queue_dropped,
            self.write_failed
        )?;
        if let Some(e) = &self.error {
            write!(f, "; WRITING FAILED: {e} (the file holds everything before it)")?;
        }
        Ok(())
    }
}

/// One open recording.
pub struct Recorder<W: Write + Seek = File> {
    w: Option<Writer<Counted<W>>>,
    /// Bytes the sink has taken, and how many of them end the last chunk written whole.
    written: Arc<AtomicU64>,
    kept_bytes: u64,
    path: PathBuf,
    ch: Channels,
    /// Bytes of messages in the chunk being filled, and its messages per channel.
    chunk_bytes: u64,
    pending: [u64; 4],
    report: RecordingReport,
}

const TICK: usize = 0;
const SAMPLE: usize = 1;
const MODEL: usize = 2;
const EVENT: usize = 3;

/// An error and its causes, e.g. `I/O error from writing ...: no space left on device`.
pub(crate) fn describe(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cause = c.source();
    }
    s
}

/// A sink that counts the bytes it takes, so a failed recording can be cut back to its last
/// whole chunk.
struct Counted<W> {
    inner: W,
    n: Arc<AtomicU64>,
}

impl<W: Write> Write for Counted<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let k = self.inner.write(buf)?;
        self.n.fetch_add(k as u64, Ordering::Relaxed);
        Ok(k)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<W: Seek> Seek for Counted<W> {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

pub(crate) fn unix_now_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

impl Recorder {
    /// Creates the file and writes what made the session. Fails (before any session starts)
    /// when the path cannot be written.
    pub fn create(path: &Path, info: &SessionInfo) -> Result<Recorder, RecordError> {
        let create = |e: std::io::Error| RecordError::Create { path: path.to_path_buf(), cause: e };
        if path.is_dir() {
            return Err(create(std::io::Error::other("it is a directory")));
        }
        // Straight to the file (unbuffered): each finished chunk reaches the system at once.
        let file = File::create(path).map_err(create)?;
        Recorder::with_sink(file, path, info)
    }
}

impl<W: Write + Seek> Recorder<W> {
    /// A recorder writing into `sink` (`path` names it in reports and errors).
    pub fn with_sink(sink: W, path: &Path, info: &SessionInfo) -> Result<Recorder<W>, RecordError> {
        // Chunks are ended here (`end_chunk`), so the recorder knows which ticks each holds.
        let opts = channel::options(None);
        let write = |e: mcap::McapError| RecordError::Write { path: path.to_path_buf(), why: describe(&e) };
        let written = Arc::new(AtomicU64::new(0));
        let mut w = opts.create(Counted { inner: sink, n: written.clone() }).map_err(write)?;
        let start_unix_ns = unix_now_ns();
        let mut meta = BTreeMap::new();
        for (k, v) in [
            ("format_version", FORMAT_VERSION.to_string()),
            ("spidar_version", SPIDAR_VERSION.to_string()),
            ("rig", info.rig_origin.clone()),
            ("scene", info.scene.clone()),
            ("script", info.script.clone()),
            ("device", info.device.clone()),
            ("seed", info.seed.to_string()),
            ("command_line", info.command_line.clone()),
            ("clock", if info.virtual_clock { "virtual" } else { "real" }.to_string()),
            ("start_unix_ns", start_unix_ns.to_string()),
        ] {
            meta.insert(k.to_string(), v);
        }
        w.write_metadata(&Metadata { name: META_SESSION.into(), metadata: meta }).map_err(write)?;
        let mut attach = |name: &str, text: &str| {
            w.attach(&Attachment {
                log_time: start_unix_ns,
                create_time: start_unix_ns,
                name: name.into(),
                media_type: "text/plain".into(),
                data: text.as_bytes().into(),
            })
        };
        attach(RIG_ATTACHMENT, &info.rig_text).map_err(write)?;
        for (name, text) in &info.files {
            attach(name, text).map_err(write)?;
        }
        // The header, metadata and attachments reach the disk before the session starts; the
        // schemas and channels go into the first chunk, with the first ticks (see `channel`).
        let mut ch = Channels::new(start_unix_ns);
        ch.declare(Some(&mut w), rig_channels()).map_err(write)?;
        let kept_bytes = written.load(Ordering::Relaxed);
        Ok(Recorder {
            w: Some(w),
            written,
            kept_bytes,
            path: path.to_path_buf(),
            ch,
            chunk_bytes: 0,
            pending: [0; 4],
            report: RecordingReport { path: path.to_path_buf(), ..Default::default() },
        })
    }

    fn put<T: Field>(&mut self, ch: usize, t_s: f64, x: &T) -> bool {
        let Some(w) = self.w.as_mut() else { return false };
        match self.ch.put(Some(w), None, ch, t_s, x) {
            Ok(n) => {
                self.chunk_bytes += n as u64;
                self.pending[ch] += 1;
                true
            }
            Err(e) => {
                self.fail(describe(&e));
                false
            }
        }
    }

    /// Stops writing after an I/O error (the writer's state is then unknown). The file keeps
    /// every chunk finished before; the ticks of the chunk being filled are lost and counted.
    ///
    /// A chunk whose write failed may still have reached the disk whole (only the index records
    /// after it missing), so the file is cut back to the end of the last chunk written whole:
    /// it then holds exactly the ticks reported kept.
    fn fail(&mut self, why: String) {
        self.report.error.get_or_insert(why);
        self.w = None;
        if self.written.load(Ordering::Relaxed) > self.kept_bytes {
            let cut = std::fs::OpenOptions::new()
                .write(true)
                .open(&self.path)
                .and_then(|f| f.set_len(self.kept_bytes));
            if let Err(e) = cut {
                let note = format!(" (cutting the file back to its last whole chunk failed too: {e})");
                if let Some(err) = self.report.error.as_mut() {
                    err.push_str(&note);
                }
            }
        }
        self.report.write_failed += self.pending[TICK];
        self.pending = [0; 4];
    }

    /// Ends the chunk being filled and writes it; its messages count as kept once it is written.
    fn end_chunk(&mut self) {
        let Some(w) = self.w.as_mut() else { return };
        match w.flush() {
            Ok(()) => {
                let [t, s, m, e] = std::mem::take(&mut self.pending);
                self.report.ticks += t;
                self.report.samples += s;
                self.report.models += m;
                self.report.events += e;
                self.chunk_bytes = 0;
                self.kept_bytes = self.written.load(Ordering::Relaxed);
            }
            Err(e) => self.fail(describe(&e)),
        }
    }

    /// Writes one tick: its events, the model it took, the tick, the sample. It counts as kept
    /// once the chunk holding it is written.
    pub fn write_tick(&mut self, r: &TickRecord) {
        if self.w.is_none() {
            self.report.write_failed += 1;
            return;
        }
        let mut ok = true;
        for e in r.events.iter() {
            ok = ok && self.put(EVENT, r.t_s, &EventMsg::new(r.tick, r.t_s, &e));
        }
        if let Some(m) = r.model {
            ok = ok && self.put(MODEL, r.t_s, &TakenModel { tick: r.tick, model: m });
        }
        ok = ok && self.put(TICK, r.t_s, r) && self.put(SAMPLE, r.t_s, &r.sample);
        if !ok {
            // This tick's own messages were counted nowhere yet.
            self.report.write_failed += 1;
            return;
        }
        if self.chunk_bytes >= CHUNK_BYTES {
            self.end_chunk();
        }
    }

    /// Ends the recording: the last chunk, the `spidar.end` record, the summary and footer.
    pub fn finish(mut self, end: &EndInfo) -> RecordingReport {
        self.report.telemetry_dropped = end.telemetry_dropped;
        self.end_chunk();
        if let Some(mut w) = self.w.take() {
            let mut meta = BTreeMap::new();
            for (k, v) in [
                ("ticks", end.ticks.to_string()),
                ("ticks_recorded", self.report.ticks.to_string()),
                ("telemetry_dropped", end.telemetry_dropped.to_string()),
                ("queue_dropped", self.report.queue_dropped.to_string()),
                ("final_state", end.final_state.clone()),
                ("clean_stop", end.clean_stop.to_string()),
                ("faults", end.faults.to_string()),
            ] {
                meta.insert(k.to_string(), v);
            }
            let r = w
                .write_metadata(&Metadata { name: META_END.into(), metadata: meta })
                .and_then(|_| w.finish());
            if let Err(e) = r {
                self.report.error.get_or_insert(describe(&e));
            }
        }
        self.report.bytes = std::fs::metadata(&self.path).map_or(0, |m| m.len());
        self.report.clone()
    }

    pub fn report(&self) -> &RecordingReport {
        &self.report
    }

    /// Unix time (ns) the recording's times count from (loop-clock zero).
    pub fn start_unix_ns(&self) -> u64 {
        self.ch.start_unix_ns()
    }
}

/// The rig's channels, in the order of the recorder's channel indexes (`TICK`, `SAMPLE`, `MODEL`,
/// `EVENT`): what a rig recording holds and what a live server of the rig advertises.
pub fn rig_channels() -> Vec<ChannelSpec> {
    vec![
        ChannelSpec::of::<TickRecord>(TOPIC_TICK),
        ChannelSpec::of::<spidar_msg::HandSample>(TOPIC_SAMPLE),
        ChannelSpec::of::<TakenModel>(TOPIC_MODEL),
        ChannelSpec::of::<EventMsg>(TOPIC_EVENT),
    ]
}

/// The rig's messages for a live server (Foxglove), without a file: the recorder's channels,
/// messages and order.
pub struct LiveRig {
    ch: Channels,
    tap: Box<dyn Tap>,
}

impl LiveRig {
    /// Times count from `start_unix_ns` (loop-clock zero; the recording's, when there is one).
    pub fn new(start_unix_ns: u64, tap: Box<dyn Tap>) -> LiveRig {
        let mut ch = Channels::new(start_unix_ns);
        ch.declare::<File>(None, rig_channels()).expect("no file, nothing to fail");
        LiveRig { ch, tap }
    }

    /// One tick's messages, in the recorder's order: its events, the model it took, the tick,
    /// the sample.
    pub fn write_tick(&mut self, r: &TickRecord) {
        // Without a file nothing can fail: the tap takes every message.
        let tap = &mut *self.tap;
        for e in r.events.iter() {
            let _ = self.ch.put::<_, File>(
                None,
                Some(&mut *tap),
                EVENT,
                r.t_s,
                &EventMsg::new(r.tick, r.t_s, &e),
            );
        }
        if let Some(m) = r.model {
            let _ = self.ch.put::<_, File>(
                None,
                Some(&mut *tap),
                MODEL,
                r.t_s,
                &TakenModel { tick: r.tick, model: m },
            );
        }
        let _ = self.ch.put::<_, File>(None, Some(&mut *tap), TICK, r.t_s, r);
        let _ = self.ch.put::<_, File>(None, Some(&mut *tap), SAMPLE, r.t_s, &r.sample);
    }
}

/// Records handed over per batch.
const BATCH: usize = 64;
/// Batches the queue holds (4 s of ticks at 1 kHz).
const QUEUE_BATCHES: usize = 64;

/// A [`Recorder`] on its own thread, fed with tick records by a session's telemetry consumer.
pub struct RecorderThread {
    tx: Option<Sender<Vec<TickRecord>>>,
    batch: Vec<TickRecord>,
    dropped: u64,
    to_file: bool,
    /// The thread hands back the file and the live server when its queue closes: the file is
    /// finished before the server goes, so a live client that sees the stream end finds the
    /// recording complete.
    handle: Option<JoinHandle<(Option<Recorder>, Option<LiveRig>)>>,
}

impl std::fmt::Debug for RecorderThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RecorderThread {{ queued: {}, dropped: {} }}", self.batch.len(), self.dropped)
    }
}

impl RecorderThread {
    pub fn spawn(rec: Recorder) -> Result<RecorderThread, RecordError> {
        Self::spawn_with(Some(rec), None)
    }

    /// A thread writing every tick into `rec` (None: no file) and handing it to `live` (a live
    /// Foxglove server of the rig's channels).
    pub fn spawn_with(rec: Option<Recorder>, live: Option<LiveRig>) -> Result<RecorderThread, RecordError> {
        let (tx, rx) = bounded::<Vec<TickRecord>>(QUEUE_BATCHES);
        let to_file = rec.is_some();
        let handle = std::thread::Builder::new()
            .name("spidar-recorder".into())
            .spawn(move || {
                let (mut rec, mut live) = (rec, live);
                for batch in rx {
                    for r in &batch {
                        if let Some(rec) = rec.as_mut() {
                            rec.write_tick(r);
                        }
                        if let Some(l) = live.as_mut() {
                            l.write_tick(r);
                        }
                    }
                }
                (rec, live)
            })
            .map_err(|e| RecordError::Write {
                path: PathBuf::new(),
                why: format!("starting the recorder thread: {e}"),
            })?;
        Ok(RecorderThread {
            tx: Some(tx),
            batch: Vec::with_capacity(BATCH),
            dropped: 0,
            to_file,
            handle: Some(handle),
        })
    }

    /// Queues one record; never waits (a full queue drops the batch and counts it).
    pub fn push(&mut self, r: &TickRecord) {
        self.batch.push(*r);
        if self.batch.len() >= BATCH {
            self.send(false);
        }
    }

    fn send(&mut self, wait: bool) {
        let batch = std::mem::replace(&mut self.batch, Vec::with_capacity(BATCH));
        let n = batch.len() as u64;
        let Some(tx) = self.tx.as_ref() else { return };
        let sent = if wait {
            tx.send(batch).is_ok()
        } else {
            match tx.try_send(batch) {
                Ok(()) => true,
                Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => false,
            }
        };
        if !sent {
            self.dropped += n;
        }
    }

    /// True when it writes a file (not only a live server).
    pub fn records_to_file(&self) -> bool {
        self.to_file
    }

    /// Writes what is queued and ends the recording (a thread without a file reports nothing
    /// written).
    pub fn finish(mut self, end: &EndInfo) -> Result<RecordingReport, RecordError> {
        self.send(true);
        drop(self.tx.take());
        let (rec, live) = self.handle.take().and_then(|h| h.join().ok()).ok_or_else(|| {
            RecordError::Write { path: PathBuf::new(), why: "the recorder thread panicked".into() }
        })?;
        let report = rec.map(|mut rec| {
            rec.report.queue_dropped = self.dropped;
            rec.finish(end)
        });
        // Only now the live server closes its clients.
        drop(live);
        Ok(report.unwrap_or_default())
    }
}
