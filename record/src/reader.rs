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
    let mut rec = Recording { path: path.to_path_buf(), ..Default::default() };
    let mut schemas: HashMap<u16, (String, String, Vec<u8>)> = HashMap::new();
    let mut kinds: HashMap<u16, (usize, Option<Known>)> = HashMap::new();
    let mut seen_header = false;
    let bad = |what: String| RecordError::NotSpidar { path: path.to_path_buf(), what };
    while let Some(ev) = lr.next_event() {
        let ev = match ev {
            Ok(ev) => ev,
            Err(e) => {
                if !seen_header {
                    return Err(match e {
                        McapError::BadMagic | McapError::UnexpectedEof => {
                            bad(format!("it is not an MCAP file ({})", looks_like(path)))
                        }
                        e => bad(format!("its MCAP header does not read ({e})")),
                    });
                }
                rec.ending = Some(match e {
                    McapError::UnexpectedEof => Ending::CutShort { at_byte: rec.bytes_read },
                    e => Ending::Damaged { at_byte: rec.bytes_read, why: e.to_string() },
                });
                break;
            }
        };
        match ev {
            LinearReadEvent::ReadRequest(need) => {
                let buf = lr.insert(need.clamp(1, READ_SIZE));
                let n = loop {
                    match file.read(buf) {
                        Ok(n) => break n,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                        Err(e) => return Err(RecordError::Open { path: path.to_path_buf(), cause: e }),
                    }
                };
                rec.bytes_read += n as u64;
                lr.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => {
                let r = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) if seen_header => {
                        rec.ending = Some(Ending::Damaged { at_byte: rec.bytes_read, why: e.to_string() });
                        break;
                    }
                    Err(e) => return Err(bad(format!("its first record does not read ({e})"))),
                };
                use mcap::records::Record;
                match r {
                    Record::Header(h) => {
                        if h.profile != PROFILE {
                            return Err(bad(format!(
                                "it is an MCAP file of profile '{}' written by '{}', not a spidar recording",
                                h.profile, h.library
                            )));
                        }
                        rec.library = h.library;
                        seen_header = true;
                    }
                    Record::Metadata(m) => {
                        if m.name == META_SESSION {
                            let v = m.metadata.get("format_version").map(|s| s.as_str()).unwrap_or("none");
                            if v != FORMAT_VERSION.to_string() {
                                let by = m.metadata.get("spidar_version").map_or("?", |s| s.as_str());
                                return Err(RecordError::OtherVersion {
                                    path: path.to_path_buf(),
                                    found: format!("format {v}, written by spidar {by}"),
                                });
                            }
                            rec.session = m.metadata;
                        } else if m.name == META_END {
                            rec.end_meta = Some(m.metadata);
                        } else {
                            rec.other_meta.push((m.name, m.metadata));
                        }
                    }
                    Record::Attachment { header, data, .. } => {
                        rec.attachments.push((header.name, data.into_owned()))
                    }
                    Record::Schema { header, data } => {
                        schemas.insert(header.id, (header.name, header.encoding, data.into_owned()));
                    }
                    Record::Channel(c) => {
                        if kinds.contains_key(&c.id) {
                            continue; // repeated in the summary section
                        }
                        let (sname, senc, sdata) = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                        let kind = match known(&c.topic) {
                            Some((k, name, text)) => {
                                if rec.session.is_empty() {
                                    return Err(bad(
                                        "its channels come before the spidar metadata record".into()
                                    ));
                                }
                                if sname != name
                                    || senc != "ros2msg"
                                    || c.message_encoding != "cdr"
                                    || sdata != text.as_bytes()
                                {
                                    return Err(RecordError::OtherVersion {
                                        path: path.to_path_buf(),
                                        found: format!(
                                            "channel {} has schema '{sname}' ({senc}, {}) unlike this spidar's '{name}', written by spidar {}",
                                            c.topic,
                                            c.message_encoding,
                                            rec.meta("spidar_version")
                                        ),
                                    });
                                }
                                Some(k)
                            }
                            None => None,
                        };
                        kinds.insert(c.id, (rec.channels.len(), kind));
                        rec.channels.push(ChannelInfo {
                            id: c.id,
                            topic: c.topic,
                            schema: sname,
                            schema_encoding: senc,
                            message_encoding: c.message_encoding,
                            messages: 0,
                        });
                    }
                    Record::Message { header, data } => {
                        let Some(&(idx, kind)) = kinds.get(&header.channel_id) else {
                            rec.ending = Some(Ending::Damaged {
                                at_byte: rec.bytes_read,
                                why: format!("a message on unknown channel {}", header.channel_id),
                            });
                            break;
                        };
                        rec.channels[idx].messages += 1;
                        let corrupt = |e: cdr::DecodeError| RecordError::Corrupt {
                            path: path.to_path_buf(),
                            what: format!("message {} on {}: {e}", header.sequence, rec.channels[idx].topic),
                        };
                        let msg = match kind {
                            Some(Known::Tick) => {
                                let t: TickRecord = cdr::decode(&data).map_err(corrupt)?;
                                if let Some(_first) = rec.first_tick {
                                    rec.missing_ticks += t.tick.saturating_sub(rec.last_tick + 1);
                                } else {
                                    rec.first_tick = Some(t.tick);
                                }
                                rec.ticks += 1;
                                rec.last_tick = t.tick;
                                rec.last_t_s = t.t_s;
                                Msg::Tick(Box::new(t))
                            }
                            Some(Known::Sample) => {
                                Msg::Sample(Box::new(cdr::decode(&data).map_err(corrupt)?))
                            }
                            Some(Known::Model) => Msg::Model(Box::new(cdr::decode(&data).map_err(corrupt)?)),
                            Some(Known::Event) => Msg::Event(cdr::decode(&data).map_err(corrupt)?),
                            None => {
                                let ch = rec.channels[idx].clone();
                                if let Flow::Stop = visit(
                                    &rec,
                                    Msg::Other { channel: &ch, log_time_ns: header.log_time, data: &data },
                                )? {
                                    return Ok(rec);
                                }
                                continue;
                            }
                        };
                        if let Flow::Stop = visit(&rec, msg)? {
                            return Ok(rec);
                        }
                    }
                    Record::Footer(_) => rec.ending = Some(Ending::Complete),
                    _ => {}
                }
            }
        }
    }
    if !seen_header {
        return Err(bad(format!("it is not an MCAP file ({})", looks_like(path))));
    }
    if rec.session.is_empty() {
        return Err(bad("it has no spidar metadata record (cut short before the session started?)".into()));
    }
    if rec.ending.is_none() {
        rec.ending = Some(Ending::CutShort { at_byte: rec.bytes_read });
    }
    Ok(rec)
}
