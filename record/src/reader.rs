//! Reading a recording back, in file order, from any spidar recording: complete, cut short
//! (killed, disk full) or damaged part way.
//!
//! What is read is checked before it is trusted: the file must be MCAP (magic), spidar's (the
//! header's profile), of this spidar's recording format (the `spidar` metadata record), and each
//! known channel must carry exactly this spidar's schema. Anything else is an error that names
//! what is wrong. Chunks are checked against their CRC before any message in them is used, so a
//! file cut short or damaged yields every message before the first bad chunk and says where it
//! ends ([`Ending`]).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::McapError;
use spidar_msg::HandSample;
use spidar_rt::telemetry::TickRecord;

use crate::cdr::{self, Field};
use crate::schema::{EventMsg, TakenModel, TOPIC_EVENT, TOPIC_MODEL, TOPIC_SAMPLE, TOPIC_TICK};
use crate::writer::{META_END, META_SESSION, RIG_ATTACHMENT};
use crate::{RecordError, FORMAT_VERSION, PROFILE};

/// No record of a spidar recording is near this long; a longer one is damage, not data.
pub(crate) const RECORD_LIMIT: usize = 64 << 20;
const READ_SIZE: usize = 1 << 20;

/// How the readable part of a file ends.
#[derive(Clone, Debug, PartialEq)]
pub enum Ending {
    /// The recording was finished normally (its summary and footer are there).
    Complete,
    /// The file stops part way, as when the session was killed or the disk filled up: every
    /// complete chunk before that point was read.
    CutShort { at_byte: u64 },
    /// The data is damaged from `at_byte` on (`why`); everything before it was read.
    Damaged { at_byte: u64, why: String },
}

impl std::fmt::Display for Ending {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Ending::Complete => write!(f, "complete"),
            Ending::CutShort { at_byte } => {
                write!(f, "cut short at byte {at_byte} (the session was killed or the disk filled up): read up to the last complete chunk")
            }
            Ending::Damaged { at_byte, why } => {
                write!(f, "damaged from byte {at_byte} ({why}): read up to there")
            }
        }
    }
}

/// One channel of a recording.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelInfo {
    pub id: u16,
    pub topic: String,
    pub schema: String,
    pub schema_encoding: String,
    pub message_encoding: String,
    pub messages: u64,
}

/// What a recording holds besides its messages, and how far it could be read.
#[derive(Clone, Debug, Default)]
pub struct Recording {
    pub path: PathBuf,
    /// The MCAP header's library field (`spidar 0.1.0`).
    pub library: String,
    /// The `spidar` metadata record: what made the session.
    pub session: BTreeMap<String, String>,
    /// The `spidar.end` metadata record, written when the session ended normally.
    pub end_meta: Option<BTreeMap<String, String>>,
    /// Other metadata records, by name.
    pub other_meta: Vec<(String, BTreeMap<String, String>)>,
    /// (name, bytes) of every attachment.
    pub attachments: Vec<(String, Vec<u8>)>,
    pub channels: Vec<ChannelInfo>,
    /// None when the reading was stopped before the end.
    pub ending: Option<Ending>,
    /// Tick records read, the first and last tick and its loop-clock time.
    pub ticks: u64,
    pub first_tick: Option<u64>,
    pub last_tick: u64,
    pub last_t_s: f64,
    /// Ticks missing between two recorded ones (records dropped while recording).
    pub missing_ticks: u64,
    pub bytes_read: u64,
}

impl Recording {
    /// The text of an attachment.
    pub fn attachment_text(&self, name: &str) -> Option<String> {
        self.attachments.iter().find(|(n, _)| n == name).map(|(_, b)| String::from_utf8_lossy(b).into_owned())
    }
    /// The rig file the session ran with.
    pub fn rig_text(&self) -> Option<String> {
        self.attachment_text(RIG_ATTACHMENT)
    }
    pub fn meta(&self, key: &str) -> &str {
        self.session.get(key).map_or("?", |s| s.as_str())
    }
    /// Where the readable part ends, in words.
    pub fn ends(&self) -> String {
        let e = match &self.ending {
            Some(e) => e.to_string(),
            None => "not read to its end (the reading stopped early)".into(),
        };
        match self.first_tick {
            Some(_) => format!("{e}; last tick read {} at t = {:.3} s", self.last_tick, self.last_t_s),
            None => format!("{e}; no tick recorded"),
        }
    }
}

/// One decoded message.
pub enum Msg<'a> {
    Tick(Box<TickRecord>),
    Sample(Box<HandSample>),
    Model(Box<TakenModel>),
    Event(EventMsg),
    /// A channel this spidar does not decode (e.g. a later world channel).
    Other {
        channel: &'a ChannelInfo,
        log_time_ns: u64,
        data: &'a [u8],
    },
}

/// What the visitor wants next.
pub enum Flow {
    Continue,
    Stop,
}

#[derive(Clone, Copy, PartialEq)]
enum Known {
    Tick,
    Sample,
    Model,
    Event,
}

fn known(topic: &str) -> Option<(Known, String, String)> {
    Some(match topic {
        TOPIC_TICK => (Known::Tick, TickRecord::ros_type(), cdr::schema_text::<TickRecord>()),
        TOPIC_SAMPLE => (Known::Sample, HandSample::ros_type(), cdr::schema_text::<HandSample>()),
        TOPIC_MODEL => (Known::Model, TakenModel::ros_type(), cdr::schema_text::<TakenModel>()),
        TOPIC_EVENT => (Known::Event, EventMsg::ros_type(), cdr::schema_text::<EventMsg>()),
        _ => return None,
    })
}

/// The summary section of an MCAP file (its chunk, attachment and metadata indexes), read from the
/// end of the file; None when it has none that reads (a file cut short).
pub(crate) fn read_summary(file: &File, len: u64) -> Option<mcap::Summary> {
    use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
    use std::io::SeekFrom;
    use std::os::unix::fs::FileExt;
    let opts = SummaryReaderOptions::default().with_file_size(len).with_record_length_limit(RECORD_LIMIT);
    let mut r = SummaryReader::new_with_options(opts);
    let mut pos = 0u64;
    while let Some(ev) = r.next_event() {
        match ev.ok()? {
            SummaryReadEvent::ReadRequest(n) => {
                let k = file.read_at(r.insert(n), pos).ok()?;
                pos += k as u64;
                r.notify_read(k);
            }
            SummaryReadEvent::SeekRequest(to) => {
                pos = match to {
                    SeekFrom::Start(p) => p,
                    SeekFrom::End(e) => len.checked_add_signed(e)?,
                    SeekFrom::Current(c) => pos.checked_add_signed(c)?,
                };
                r.notify_seeked(pos);
            }
        }
    }
    r.finish()
}

/// A metadata record of a complete file, found through its summary's metadata index (without
/// reading the data). None when the file has no summary or no such record.
pub fn metadata_of(path: &Path, name: &str) -> Result<Option<BTreeMap<String, String>>, RecordError> {
    use std::os::unix::fs::FileExt;
    let open = |e| RecordError::Open { path: path.to_path_buf(), cause: e };
    let file = File::open(path).map_err(open)?;
    let len = file.metadata().map_err(open)?.len();
    let Some(summary) = read_summary(&file, len) else { return Ok(None) };
    let Some(ix) = summary.metadata_indexes.iter().find(|m| m.name == name) else { return Ok(None) };
    let bad = |what: String| RecordError::Corrupt { path: path.to_path_buf(), what };
    if ix.length > RECORD_LIMIT as u64 || ix.length < 9 {
        return Err(bad(format!("its metadata index gives {name} a length of {} bytes", ix.length)));
    }
    let mut buf = vec![0u8; ix.length as usize];
    file.read_exact_at(&mut buf, ix.offset).map_err(open)?;
    match mcap::parse_record(buf[0], &buf[9..]) {
        Ok(mcap::records::Record::Metadata(m)) => Ok(Some(m.metadata)),
        _ => Err(bad(format!("the metadata record {name} does not read where its index says"))),
    }
}

/// Only the file's first bytes, for saying what a foreign file is.
fn looks_like(path: &Path) -> String {
    let mut head = [0u8; 8];
    let n = File::open(path).and_then(|mut f| f.read(&mut head)).unwrap_or(0);
    if n == 0 {
        "it is empty".into()
    } else {
        format!("it starts with {:02x?}", &head[..n])
    }
}

/// Reads `path` from start to end, calling `visit` with every message in file order (with what
/// has been read so far), and returns what the recording holds and where it ends.
pub fn read(
    path: &Path,
    mut visit: impl FnMut(&Recording, Msg<'_>) -> Result<Flow, RecordError>,
) -> Result<Recording, RecordError> {
    let mut file = File::open(path).map_err(|e| RecordError::Open { path: path.to_path_buf(), cause: e })?;
    let opts = LinearReaderOptions::default()
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(RECORD_LIMIT);
    let mut lr = LinearReader::new_with_options(opts);
    let mut r = Reading::new(path);
    while let Some(ev) = lr.next_event() {
        let ev = match ev {
            Ok(ev) => ev,
            Err(e) => {
                r.stopped_by(e)?;
                break;
            }
        };
        match ev {
            LinearReadEvent::ReadRequest(need) => {
                let buf = lr.insert(need.clamp(1, READ_SIZE));
                let n = read_some(&mut file, buf)
                    .map_err(|e| RecordError::Open { path: path.to_path_buf(), cause: e })?;
                r.rec.bytes_read += n as u64;
                lr.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => match r.record(opcode, data, &mut visit)? {
                Flow::Continue
                    if r.rec.ending.is_some() && !matches!(r.rec.ending, Some(Ending::Complete)) =>
                {
                    break
                }
                Flow::Continue => {}
                Flow::Stop => return Ok(r.rec),
            },
        }
    }
    r.finish()
}

/// Reads what the file has into `buf` (retrying an interrupted read).
fn read_some(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match file.read(buf) {
            Ok(n) => return Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
}

/// What [`read`] knows while it reads: the recording so far, the schemas and the channels' kinds.
struct Reading<'p> {
    path: &'p Path,
    rec: Recording,
    schemas: HashMap<u16, (String, String, Vec<u8>)>,
    /// Per channel id: its index in `rec.channels` and what spidar knows it as.
    kinds: HashMap<u16, (usize, Option<Known>)>,
    seen_header: bool,
}

impl<'p> Reading<'p> {
    fn new(path: &'p Path) -> Reading<'p> {
        Reading {
            path,
            rec: Recording { path: path.to_path_buf(), ..Default::default() },
            schemas: HashMap::new(),
            kinds: HashMap::new(),
            seen_header: false,
        }
    }

    fn not_spidar(&self, what: String) -> RecordError {
        RecordError::NotSpidar { path: self.path.to_path_buf(), what }
    }

    /// The reader stopped on `e`: before the header the file is not a recording; after it, the
    /// recording ends there (cut short or damaged).
    fn stopped_by(&mut self, e: McapError) -> Result<(), RecordError> {
        if !self.seen_header {
            return Err(match e {
                McapError::BadMagic | McapError::UnexpectedEof => {
                    self.not_spidar(format!("it is not an MCAP file ({})", looks_like(self.path)))
                }
                e => self.not_spidar(format!("its MCAP header does not read ({e})")),
            });
        }
        let at_byte = self.rec.bytes_read;
        self.rec.ending = Some(match e {
            McapError::UnexpectedEof => Ending::CutShort { at_byte },
            e => Ending::Damaged { at_byte, why: e.to_string() },
        });
        Ok(())
    }

    /// One record: the header, metadata, attachments, schemas, channels, messages (handed to
    /// `visit`) and the footer. A record that does not read ends the recording there (after the
    /// header) and the reading stops: `rec.ending` then says where.
    fn record(
        &mut self,
        opcode: u8,
        data: &[u8],
        visit: &mut impl FnMut(&Recording, Msg<'_>) -> Result<Flow, RecordError>,
    ) -> Result<Flow, RecordError> {
        use mcap::records::Record;
        let r = match mcap::parse_record(opcode, data) {
            Ok(r) => r,
            Err(e) if self.seen_header => {
                self.rec.ending = Some(Ending::Damaged { at_byte: self.rec.bytes_read, why: e.to_string() });
                return Ok(Flow::Continue);
            }
            Err(e) => return Err(self.not_spidar(format!("its first record does not read ({e})"))),
        };
        match r {
            Record::Header(h) => self.header(h)?,
            Record::Metadata(m) => self.metadata(m)?,
            Record::Attachment { header, data, .. } => {
                self.rec.attachments.push((header.name, data.into_owned()))
            }
            Record::Schema { header, data } => {
                self.schemas.insert(header.id, (header.name, header.encoding, data.into_owned()));
            }
            Record::Channel(c) => self.channel(c)?,
            Record::Message { header, data } => return self.message(&header, &data, visit),
            Record::Footer(_) => self.rec.ending = Some(Ending::Complete),
            _ => {}
        }
        Ok(Flow::Continue)
    }

    fn header(&mut self, h: mcap::records::Header) -> Result<(), RecordError> {
        if h.profile != PROFILE {
            return Err(self.not_spidar(format!(
                "it is an MCAP file of profile '{}' written by '{}', not a spidar recording",
                h.profile, h.library
            )));
        }
        self.rec.library = h.library;
        self.seen_header = true;
        Ok(())
    }

    /// The session's metadata (which must be of this format's version), the end's, or another.
    fn metadata(&mut self, m: mcap::records::Metadata) -> Result<(), RecordError> {
        if m.name == META_SESSION {
            let v = m.metadata.get("format_version").map(|s| s.as_str()).unwrap_or("none");
            if v != FORMAT_VERSION.to_string() {
                let by = m.metadata.get("spidar_version").map_or("?", |s| s.as_str());
                return Err(RecordError::OtherVersion {
                    path: self.path.to_path_buf(),
                    found: format!("format {v}, written by spidar {by}"),
                });
            }
            self.rec.session = m.metadata;
        } else if m.name == META_END {
            self.rec.end_meta = Some(m.metadata);
        } else {
            self.rec.other_meta.push((m.name, m.metadata));
        }
        Ok(())
    }

    /// A channel (once: the summary section repeats them): a spidar channel must carry this
    /// spidar's schema, after the session's metadata.
    fn channel(&mut self, c: mcap::records::Channel) -> Result<(), RecordError> {
        if self.kinds.contains_key(&c.id) {
            return Ok(());
        }
        let (sname, senc, sdata) = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
        let kind = match known(&c.topic) {
            Some((k, name, text)) => {
                if self.rec.session.is_empty() {
                    return Err(self.not_spidar("its channels come before the spidar metadata record".into()));
                }
                if sname != name
                    || senc != "ros2msg"
                    || c.message_encoding != "cdr"
                    || sdata != text.as_bytes()
                {
                    return Err(RecordError::OtherVersion {
                        path: self.path.to_path_buf(),
                        found: format!(
                            "channel {} has schema '{sname}' ({senc}, {}) unlike this spidar's '{name}', written by spidar {}",
                            c.topic,
                            c.message_encoding,
                            self.rec.meta("spidar_version")
                        ),
                    });
                }
                Some(k)
            }
            None => None,
        };
        self.kinds.insert(c.id, (self.rec.channels.len(), kind));
        self.rec.channels.push(ChannelInfo {
            id: c.id,
            topic: c.topic,
            schema: sname,
            schema_encoding: senc,
            message_encoding: c.message_encoding,
            messages: 0,
        });
        Ok(())
    }

    /// A message: decoded when spidar knows its channel (a tick also counts the ticks missing
    /// before it), handed to `visit` as it is otherwise.
    fn message(
        &mut self,
        header: &mcap::records::MessageHeader,
        data: &[u8],
        visit: &mut impl FnMut(&Recording, Msg<'_>) -> Result<Flow, RecordError>,
    ) -> Result<Flow, RecordError> {
        let Some(&(idx, kind)) = self.kinds.get(&header.channel_id) else {
            self.rec.ending = Some(Ending::Damaged {
                at_byte: self.rec.bytes_read,
                why: format!("a message on unknown channel {}", header.channel_id),
            });
            return Ok(Flow::Continue);
        };
        let rec = &mut self.rec;
        rec.channels[idx].messages += 1;
        let corrupt = |e: cdr::DecodeError| RecordError::Corrupt {
            path: self.path.to_path_buf(),
            what: format!("message {} on {}: {e}", header.sequence, rec.channels[idx].topic),
        };
        let msg = match kind {
            Some(Known::Tick) => {
                let t: TickRecord = cdr::decode(data).map_err(corrupt)?;
                if rec.first_tick.is_some() {
                    rec.missing_ticks += t.tick.saturating_sub(rec.last_tick + 1);
                } else {
                    rec.first_tick = Some(t.tick);
                }
                rec.ticks += 1;
                rec.last_tick = t.tick;
                rec.last_t_s = t.t_s;
                Msg::Tick(Box::new(t))
            }
            Some(Known::Sample) => Msg::Sample(Box::new(cdr::decode(data).map_err(corrupt)?)),
            Some(Known::Model) => Msg::Model(Box::new(cdr::decode(data).map_err(corrupt)?)),
            Some(Known::Event) => Msg::Event(cdr::decode(data).map_err(corrupt)?),
            None => {
                let ch = rec.channels[idx].clone();
                return visit(rec, Msg::Other { channel: &ch, log_time_ns: header.log_time, data });
            }
        };
        visit(rec, msg)
    }

    /// The recording, once the file is read to its end: a file without a header or a session is
    /// not a recording; one without a footer was cut short.
    fn finish(mut self) -> Result<Recording, RecordError> {
        if !self.seen_header {
            return Err(self.not_spidar(format!("it is not an MCAP file ({})", looks_like(self.path))));
        }
        if self.rec.session.is_empty() {
            return Err(self.not_spidar(
                "it has no spidar metadata record (cut short before the session started?)".into(),
            ));
        }
        if self.rec.ending.is_none() {
            self.rec.ending = Some(Ending::CutShort { at_byte: self.rec.bytes_read });
        }
        Ok(self.rec)
    }
}
