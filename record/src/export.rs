//! `spidar export FILE --csv DIR`: one CSV file per channel, with a header line naming every
//! column the way Foxglove's message paths do (`hands[0].output_n.x`). Enumerations are written
//! by name, numbers as the shortest text that reads back to the same value.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use spidar_msg::HandSample;
use spidar_rt::telemetry::TickRecord;

use crate::cdr::Field;
use crate::reader::{self, Flow, Msg, Recording};
use crate::schema::{EventMsg, TakenModel, TOPIC_EVENT, TOPIC_MODEL, TOPIC_SAMPLE, TOPIC_TICK};
use crate::RecordError;

/// What `export_csv` wrote.
pub struct ExportReport {
    pub recording: Recording,
    /// (file, rows) per channel written.
    pub files: Vec<(PathBuf, u64)>,
    /// Channels this spidar does not decode, left out.
    pub skipped: Vec<String>,
}

impl std::fmt::Display for ExportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "export {}", self.recording.path.display())?;
        for (p, n) in &self.files {
            writeln!(f, "  wrote        {} ({n} rows)", p.display())?;
        }
        for s in &self.skipped {
            writeln!(f, "  skipped      {s} (not a channel this spidar decodes)")?;
        }
        write!(f, "  recording    {}", self.recording.ends())
    }
}

/// `/rig/tick` -> `rig_tick.csv`.
pub fn file_name(topic: &str) -> String {
    let s: String = topic
        .trim_start_matches('/')
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    format!("{s}.csv")
}

struct Sink {
    topic: &'static str,
    path: PathBuf,
    w: BufWriter<File>,
    rows: u64,
    line: String,
}

impl Sink {
    fn new<T: Field>(dir: &Path, topic: &'static str) -> Result<Sink, RecordError> {
        let path = dir.join(file_name(topic));
        let f = File::create(&path).map_err(|e| RecordError::Create { path: path.clone(), cause: e })?;
        let mut cols = Vec::new();
        T::columns("", &mut cols);
        let mut s =
            Sink { topic, path, w: BufWriter::with_capacity(1 << 20, f), rows: 0, line: cols.join(",") };
        s.line.push('\n');
        s.flush_line()?;
        Ok(s)
    }
    fn flush_line(&mut self) -> Result<(), RecordError> {
        let path = &self.path;
        self.w
            .write_all(self.line.as_bytes())
            .map_err(|e| RecordError::Write { path: path.clone(), why: e.to_string() })
    }
    fn row<T: Field>(&mut self, x: &T) -> Result<(), RecordError> {
        self.line.clear();
        x.csv(&mut self.line);
        self.line.push('\n');
        // Every cell was written with a comma before it: drop the first.
        self.line.remove(0);
        self.rows += 1;
        self.flush_line()
    }
}

/// One decoded message on its way to its CSV writer.
enum Row {
    Tick(Box<TickRecord>),
    Sample(Box<HandSample>),
    Model(Box<TakenModel>),
    Event(EventMsg),
}

/// Rows handed to a writer thread at once.
const BATCH: usize = 512;

impl Row {
    fn topic(&self) -> &'static str {
        match self {
            Row::Tick(_) => TOPIC_TICK,
            Row::Sample(_) => TOPIC_SAMPLE,
            Row::Model(_) => TOPIC_MODEL,
            Row::Event(_) => TOPIC_EVENT,
        }
    }
}

/// Writes the rows it receives into its sinks (each thread has its own channels); returns them
/// when the sender is gone.
fn writer(rx: crossbeam_channel::Receiver<Vec<Row>>, mut sinks: Vec<Sink>) -> Result<Vec<Sink>, RecordError> {
    for batch in rx {
        for row in batch {
            let Some(s) = sinks.iter_mut().find(|s| s.topic == row.topic()) else { continue };
            match row {
                Row::Tick(t) => s.row(t.as_ref())?,
                Row::Sample(x) => s.row(x.as_ref())?,
                Row::Model(x) => s.row(x.as_ref())?,
                Row::Event(e) => s.row(&e)?,
            }
        }
    }
    for s in sinks.iter_mut() {
        s.w.flush().map_err(|e| RecordError::Write { path: s.path.clone(), why: e.to_string() })?;
    }
    Ok(sinks)
}

/// Writes one CSV file per decoded channel of the recording at `path` into `dir`. The file is
/// read and decoded on the calling thread while two threads format and write the rows (the ticks
/// on one, the other channels on the other), so an hour exports in well under a minute.
pub fn export_csv(path: &Path, dir: &Path) -> Result<ExportReport, RecordError> {
    std::fs::create_dir_all(dir).map_err(|e| RecordError::Create { path: dir.to_path_buf(), cause: e })?;
    let ticks = vec![Sink::new::<TickRecord>(dir, TOPIC_TICK)?];
    let others = vec![
        Sink::new::<HandSample>(dir, TOPIC_SAMPLE)?,
        Sink::new::<TakenModel>(dir, TOPIC_MODEL)?,
        Sink::new::<EventMsg>(dir, TOPIC_EVENT)?,
    ];
    let mut skipped: Vec<String> = Vec::new();
    std::thread::scope(|scope| {
        let (ta, ra) = crossbeam_channel::bounded::<Vec<Row>>(8);
        let (tb, rb) = crossbeam_channel::bounded::<Vec<Row>>(8);
        let a = scope.spawn(move || writer(ra, ticks));
        let b = scope.spawn(move || writer(rb, others));
        let (mut ba, mut bb) = (Vec::with_capacity(BATCH), Vec::with_capacity(BATCH));
        // A writer that stopped (write error) closes its channel: stop reading, report its error.
        let send = |tx: &crossbeam_channel::Sender<Vec<Row>>, batch: &mut Vec<Row>, force: bool| {
            if batch.len() >= BATCH || (force && !batch.is_empty()) {
                let full = std::mem::replace(batch, Vec::with_capacity(BATCH));
                return tx.send(full).is_ok();
            }
            true
        };
        let read = reader::read(path, |_, m| {
            let ok = match m {
                Msg::Tick(t) => {
                    ba.push(Row::Tick(t));
                    send(&ta, &mut ba, false)
                }
                Msg::Sample(x) => {
                    bb.push(Row::Sample(x));
                    send(&tb, &mut bb, false)
                }
                Msg::Model(x) => {
                    bb.push(Row::Model(x));
                    send(&tb, &mut bb, false)
                }
                Msg::Event(e) => {
                    bb.push(Row::Event(e));
                    send(&tb, &mut bb, false)
                }
                Msg::Other { channel, .. } => {
                    if !skipped.contains(&channel.topic) {
                        skipped.push(channel.topic.clone());
                    }
                    true
                }
            };
            Ok(if ok { Flow::Continue } else { Flow::Stop })
        });
        send(&ta, &mut ba, true);
        send(&tb, &mut bb, true);
        drop((ta, tb));
        let join = |h: std::thread::ScopedJoinHandle<'_, Result<Vec<Sink>, RecordError>>| {
            h.join().unwrap_or_else(|_| {
                Err(RecordError::Write {
                    path: dir.to_path_buf(),
                    why: "a CSV writer thread panicked".into(),
                })
            })
        };
        let (sa, sb) = (join(a), join(b));
        let recording = read?;
        let mut files = Vec::new();
        for s in sa?.into_iter().chain(sb?) {
            files.push((s.path, s.rows));
        }
        Ok(ExportReport { recording, files, skipped })
    })
}

/// Writes one CSV file per spidar channel of a world recording (`world_step.csv`,
/// `world_boxer.csv`, `world_crowd.csv`, `world_event.csv`, `world_gaze.csv`) into `dir`; the Foxglove drawing
/// channels (`/world/tf`, `/world/scene`) are listed as skipped. A world recording is small: one
/// thread.
pub fn export_world_csv(path: &Path, dir: &Path) -> Result<ExportReport, RecordError> {
    use crate::world::{self, BoxerMsg, CrowdMsg, GazeMsg, WorldEventMsg, WorldMsg, WorldStep};
    std::fs::create_dir_all(dir).map_err(|e| RecordError::Create { path: dir.to_path_buf(), cause: e })?;
    let mut sinks = [
        Sink::new::<WorldStep>(dir, world::TOPIC_STEP)?,
        Sink::new::<BoxerMsg>(dir, world::TOPIC_BOXER)?,
        Sink::new::<CrowdMsg>(dir, world::TOPIC_CROWD)?,
        Sink::new::<WorldEventMsg>(dir, world::TOPIC_WORLD_EVENT)?,
        Sink::new::<GazeMsg>(dir, world::TOPIC_GAZE)?,
    ];
    let mut skipped: Vec<String> = Vec::new();
    let recording = reader::read(path, |_, m| {
        let Msg::Other { channel, data, .. } = m else { return Ok(Flow::Continue) };
        let msg = match world::decode(&channel.topic, &channel.schema, data) {
            Some(Ok(m)) => m,
            Some(Err(e)) => {
                return Err(RecordError::Corrupt {
                    path: path.to_path_buf(),
                    what: format!("a message on {}: {e}", channel.topic),
                })
            }
            None => WorldMsg::Drawing,
        };
        match msg {
            WorldMsg::Step(x) => sinks[0].row(&x)?,
            WorldMsg::Boxer(x) => sinks[1].row(x.as_ref())?,
            WorldMsg::Crowd(x) => sinks[2].row(&x)?,
            WorldMsg::Event(x) => sinks[3].row(&x)?,
            WorldMsg::Gaze(x) => sinks[4].row(&x)?,
            WorldMsg::Drawing => {
                if !skipped.contains(&channel.topic) {
                    skipped.push(channel.topic.clone());
                }
            }
        }
        Ok(Flow::Continue)
    })?;
    let mut files = Vec::new();
    for mut s in sinks {
        s.w.flush().map_err(|e| RecordError::Write { path: s.path.clone(), why: e.to_string() })?;
        files.push((s.path, s.rows));
    }
    Ok(ExportReport { recording, files, skipped })
}
