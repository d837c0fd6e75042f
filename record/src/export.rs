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
    let s: String = topic.trim_start_matches('/').chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
    format!("{s}.csv")
}

struct Sink {
    path: PathBuf,
    w: BufWriter<File>,
    rows: u64,
    line: String,
}

impl Sink {
    fn new<T: Field>(dir: &Path, topic: &str) -> Result<Sink, RecordError> {
        let path = dir.join(file_name(topic));
        let f = File::create(&path).map_err(|e| RecordError::Create { path: path.clone(), source: e })?;
        let mut cols = Vec::new();
        T::columns("", &mut cols);
        let mut s = Sink { path, w: BufWriter::with_capacity(1 << 20, f), rows: 0, line: cols.join(",") };
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

/// Writes one CSV file per decoded channel of the recording at `path` into `dir`.
pub fn export_csv(path: &Path, dir: &Path) -> Result<ExportReport, RecordError> {
    std::fs::create_dir_all(dir).map_err(|e| RecordError::Create { path: dir.to_path_buf(), source: e })?;
    let mut tick = Sink::new::<TickRecord>(dir, TOPIC_TICK)?;
    let mut sample = Sink::new::<HandSample>(dir, TOPIC_SAMPLE)?;
    let mut model = Sink::new::<TakenModel>(dir, TOPIC_MODEL)?;
    let mut event = Sink::new::<EventMsg>(dir, TOPIC_EVENT)?;
    let mut skipped: Vec<String> = Vec::new();
    let recording = reader::read(path, |_, m| {
        match m {
            Msg::Tick(t) => tick.row(t.as_ref())?,
            Msg::Sample(s) => sample.row(s.as_ref())?,
            Msg::Model(x) => model.row(x.as_ref())?,
            Msg::Event(e) => event.row(&e)?,
            Msg::Other { channel, .. } => {
                if !skipped.contains(&channel.topic) {
                    skipped.push(channel.topic.clone());
                }
            }
        }
        Ok(Flow::Continue)
    })?;
    let mut files = Vec::new();
    for mut s in [tick, sample, model, event] {
        s.w.flush().map_err(|e| RecordError::Write { path: s.path.clone(), why: e.to_string() })?;
        files.push((s.path, s.rows));
    }
    Ok(ExportReport { recording, files, skipped })
}
