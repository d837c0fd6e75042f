//! Recordings written and read back: by this crate's reader and by the `mcap` crate's own
//! readers (an independent check of the file), cut short, and mutated at random.

use std::path::PathBuf;

use glam::DVec3;
use proptest::prelude::*;
use spidar_msg::ContactModel;
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Command, Event, Lifecycle};

use crate::reader::{self, Ending, Flow, Msg};
use crate::schema::{TOPIC_EVENT, TOPIC_MODEL, TOPIC_SAMPLE, TOPIC_TICK};
use crate::writer::{EndInfo, Recorder, SessionInfo, CHUNK_BYTES};
use crate::RecordError;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("spidar-record-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn info() -> SessionInfo {
    SessionInfo {
        rig_origin: "test".into(),
        rig_text: spidar_rt::rig::DEFAULT_RIG_RON.into(),
        scene: "walls".into(),
        script: "tour".into(),
        device: "none".into(),
        files: vec![("scene.ron".into(), "(version: 1)".into())],
        ..Default::default()
    }
}

/// Record `i` of a synthetic session: moving hands, a model every third tick, a few events.
fn record(i: u64) -> TickRecord {
    let t = i as f64 * 1e-3;
    let mut r =
        TickRecord { tick: i, t_s: t, lateness_s: 1e-5 * (i % 7) as f64, gain: 1.0, ..Default::default() };
    r.state = if i < 100 { Lifecycle::Inactive } else { Lifecycle::Active };
    for h in 0..2 {
        r.hands[h].pos_rig_m = DVec3::new((t * 3.0).sin(), 0.1 * h as f64, (t * 2.0).cos());
        r.hands[h].output_n = DVec3::new(0.0, (t * 5.0).sin() * 3.0, 0.0);
        r.hands[h].tensions_n = [1.0 + t, 2.0, 3.0 - (t * 0.1).sin(), 4.0];
        r.hands[h].contacts = ((i / 200) % 2) as u8;
    }
    for c in 0..8 {
        r.input.counts[c] = (i as i64) * (c as i64 - 3);
        r.output.volts[c] = 0.2 + 0.01 * c as f64;
    }
    r.sample.tick = i;
    r.sample.t_s = t;
    if i.is_multiple_of(3) {
        r.model = Some(ContactModel { seq: i / 3 + 1, stamp_s: t, ..Default::default() });
    }
    if i == 0 {
        r.commands.push(Command::Home);
        r.commands.push(Command::Activate);
    }
    if i == 100 {
        r.events.push(Event::Homed);
        r.events.push(Event::State(Lifecycle::Active));
    }
    r
}

fn write(path: &std::path::Path, ticks: u64) -> Vec<TickRecord> {
    let mut rec = Recorder::create(path, &info()).unwrap();
    let recs: Vec<TickRecord> = (0..ticks).map(record).collect();
    for r in &recs {
        rec.write_tick(r);
    }
    let rep = rec.finish(&EndInfo {
        ticks,
        final_state: "inactive".into(),
        clean_stop: true,
        ..Default::default()
    });
    assert_eq!(rep.error, None);
    assert_eq!(rep.ticks, ticks);
    recs
}

/// Every tick record read back, with the model of its tick and its sample put back in.
fn read_back(path: &std::path::Path) -> Result<(reader::Recording, Vec<TickRecord>), RecordError> {
    let mut out: Vec<TickRecord> = Vec::new();
    let mut model = None;
    let mut events = Vec::new();
    let rec = reader::read(path, |_, m| {
        match m {
            Msg::Model(m) => model = Some(*m),
            Msg::Event(e) => events.push(e),
            Msg::Tick(t) => {
                let mut t = *t;
                t.model = model.take().filter(|m| m.tick == t.tick).map(|m| m.model);
                out.push(t);
            }
            Msg::Sample(s) => {
                if let Some(t) = out.last_mut() {
                    t.sample = *s;
                }
            }
            Msg::Other { .. } => {}
        }
        Ok(Flow::Continue)
    })?;
    assert!(events.iter().all(|e| e.tick == 100), "{events:?}");
    Ok((rec, out))
}

#[test]
fn a_recording_reads_back_exactly_with_what_made_it() {
    let p = temp("exact.mcap");
    let recs = write(&p, 3000);
    let (rec, back) = read_back(&p).unwrap();
    assert_eq!(rec.ending, Some(Ending::Complete));
    assert_eq!(back.len(), recs.len());
    for (a, b) in recs.iter().zip(&back) {
        let mut a = *a;
        a.events = Default::default(); // on their own channel
        assert_eq!(*b, a, "tick {}", a.tick);
    }
    assert_eq!(rec.meta("format_version"), crate::FORMAT_VERSION.to_string());
    assert_eq!(rec.meta("scene"), "walls");
    assert_eq!(rec.rig_text().as_deref(), Some(spidar_rt::rig::DEFAULT_RIG_RON));
    assert_eq!(rec.attachment_text("scene.ron").as_deref(), Some("(version: 1)"));
    assert_eq!(rec.end_meta.as_ref().and_then(|m| m.get("ticks")).map(|s| s.as_str()), Some("3000"));
    assert_eq!((rec.first_tick, rec.last_tick, rec.missing_ticks), (Some(0), 2999, 0));
}

/// What the mcap crate's own reader finds in a file's summary: the summary, and every channel's
/// (topic, schema name, schema encoding, message encoding), sorted.
pub(crate) fn mcap_topics(bytes: &[u8]) -> (mcap::Summary, Vec<(String, String, String, String)>) {
    let summary = mcap::Summary::read(bytes).unwrap().expect("a summary section");
    let mut topics: Vec<(String, String, String, String)> = summary
        .channels
        .values()
        .map(|c| {
            let s = c.schema.as_ref().expect("every channel has a schema");
            (c.topic.clone(), s.name.clone(), s.encoding.clone(), c.message_encoding.clone())
        })
        .collect();
    topics.sort();
    (summary, topics)
}

#[test]
fn the_mcap_crates_own_reader_lists_the_channels_schemas_and_messages() {
    let p = temp("independent.mcap");
    write(&p, 2000);
    let bytes = std::fs::read(&p).unwrap();
    let (summary, topics) = mcap_topics(&bytes);
    let want = |t: &str, s: &str| (t.to_string(), s.to_string(), "ros2msg".to_string(), "cdr".to_string());
    assert_eq!(
        topics,
        vec![
            want(TOPIC_MODEL, "spidar/TakenModel"),
            want(TOPIC_EVENT, "spidar/Event"),
            want(TOPIC_SAMPLE, "spidar/HandSample"),
            want(TOPIC_TICK, "spidar/Tick"),
        ]
    );
    let stats = summary.stats.expect("statistics");
    assert_eq!(stats.message_count, 2000 + 2000 + 667 + 2);
    assert!(summary.chunk_indexes.iter().all(|c| c.compression == "zstd"), "every chunk is zstd");
    assert!(summary.chunk_indexes.len() > 1);
    // No chunk of schemas and channels alone (its index would start the recording in 1970).
    assert!(summary.chunk_indexes.iter().all(|c| c.message_start_time >= stats.message_start_time));
    assert!(stats.message_start_time > 1_000_000_000 * 1_600_000_000, "a start after 2020");
    // Every message, streamed by the mcap crate, on the channels above.
    let mut per_topic = std::collections::BTreeMap::<String, u64>::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        *per_topic.entry(m.unwrap().channel.topic.clone()).or_default() += 1;
    }
    assert_eq!(per_topic[TOPIC_TICK], 2000);
    assert_eq!(per_topic[TOPIC_MODEL], 667);
    // Its header says whose it is.
    let h = mcap::read::LinearReader::new(&bytes).unwrap().next().unwrap().unwrap();
    match h {
        mcap::records::Record::Header(h) => assert_eq!(h.profile, "spidar"),
        other => panic!("first record {other:?}"),
    }
}

#[test]
fn a_recording_cut_short_reads_up_to_its_last_complete_chunk() {
    let p = temp("whole.mcap");
    let recs = write(&p, 6000);
    let bytes = std::fs::read(&p).unwrap();
    let chunks = mcap::Summary::read(&bytes).unwrap().unwrap().chunk_indexes;
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    // Cut in the middle of the third chunk: the first two (and what they hold) survive.
    let c = &chunks[2];
    let cut = (c.chunk_start_offset + c.chunk_length / 2) as usize;
    let q = temp("cut.mcap");
    std::fs::write(&q, &bytes[..cut]).unwrap();
    let (rec, back) = read_back(&q).unwrap();
    assert_eq!(rec.ending, Some(Ending::CutShort { at_byte: cut as u64 }));
    assert!(rec.ends().contains("cut short"), "{}", rec.ends());
    let last_kept = chunks[1].message_end_time;
    let kept = back.len();
    assert!(kept > 0 && back.iter().all(|t| t.tick < recs.len() as u64));
    assert_eq!(
        back.last().map(|t| rec_time(&info_start(&rec), t.t_s)),
        Some(last_kept),
        "up to the end of chunk 2"
    );
    for (a, b) in recs.iter().zip(&back) {
        assert_eq!(a.tick, b.tick);
        assert_eq!(a.hands, b.hands);
    }
}

fn info_start(rec: &reader::Recording) -> u64 {
    rec.meta("start_unix_ns").parse().unwrap()
}

fn rec_time(start: &u64, t_s: f64) -> u64 {
    start + (t_s * 1e9).round() as u64
}

#[test]
fn foreign_files_and_other_versions_are_refused_by_name() {
    let p = temp("foreign.txt");
    std::fs::write(&p, b"hello, world").unwrap();
    let e = read_back(&p).unwrap_err().to_string();
    assert!(e.contains("not a spidar recording") && e.contains("not an MCAP file"), "{e}");

    let empty = temp("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    assert!(read_back(&empty).unwrap_err().to_string().contains("it is empty"));

    // An MCAP file of another profile.
    let other = temp("other.mcap");
    {
        let f = std::fs::File::create(&other).unwrap();
        let mut w = mcap::WriteOptions::new().profile("ros2").create(f).unwrap();
        w.finish().unwrap();
    }
    let e = read_back(&other).unwrap_err().to_string();
    assert!(e.contains("profile 'ros2'"), "{e}");

    // A spidar recording of another format: the version number in the metadata record.
    let p = temp("version.mcap");
    write(&p, 10);
    let mut bytes = std::fs::read(&p).unwrap();
    let key = b"format_version";
    let at = bytes.windows(key.len()).position(|w| w == key).unwrap();
    // The value follows its 4-byte length.
    let v = at + key.len() + 4;
    assert_eq!(bytes[v], b'0' + crate::FORMAT_VERSION as u8);
    bytes[v] = b'9';
    std::fs::write(&p, &bytes).unwrap();
    let e = read_back(&p).unwrap_err().to_string();
    assert!(e.contains("another version of spidar (format 9"), "{e}");
}

#[test]
fn a_schema_unlike_this_spidars_is_refused_naming_the_channel() {
    // What another spidar would write: the same profile and format number, the tick channel with
    // a field renamed.
    let p = temp("schema.mcap");
    {
        let f = std::fs::File::create(&p).unwrap();
        let mut w = mcap::WriteOptions::new().profile(crate::PROFILE).create(f).unwrap();
        let mut meta = std::collections::BTreeMap::new();
        meta.insert("format_version".to_string(), crate::FORMAT_VERSION.to_string());
        meta.insert("spidar_version".to_string(), "0.0.1".to_string());
        w.write_metadata(&mcap::records::Metadata { name: "spidar".into(), metadata: meta }).unwrap();
        let text = crate::cdr::schema_text::<TickRecord>().replace("lateness_s", "late_s");
        let sid = w.add_schema("spidar/Tick", "ros2msg", text.as_bytes()).unwrap();
        let ch = w.add_channel(sid, TOPIC_TICK, "cdr", &Default::default()).unwrap();
        let mut buf = Vec::new();
        crate::cdr::encode(&record(0), &mut buf);
        let h = mcap::records::MessageHeader { channel_id: ch, sequence: 1, log_time: 1, publish_time: 1 };
        w.write_to_known_channel(&h, &buf).unwrap();
        w.finish().unwrap();
    }
    let e = read_back(&p).unwrap_err().to_string();
    assert!(
        e.contains("another version of spidar") && e.contains("channel /rig/tick") && e.contains("0.0.1"),
        "{e}"
    );
}

#[test]
fn an_unwritable_path_is_refused_when_the_recording_is_created() {
    let dir = temp("a-directory");
    std::fs::create_dir_all(&dir).unwrap();
    let e = Recorder::create(&dir, &info()).err().unwrap().to_string();
    assert!(e.contains("cannot create the recording") && e.contains("writable"), "{e}");
    let e = Recorder::create(&temp("no/such/dir/x.mcap"), &info()).err().unwrap().to_string();
    assert!(e.contains("cannot create the recording"), "{e}");
}

/// A small recording, kept in memory for the property test.
fn small_file() -> &'static [u8] {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(|| {
        let p = temp("small.mcap");
        write(&p, (CHUNK_BYTES / 1000).max(1200));
        std::fs::read(&p).unwrap()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// Flipped bytes, a cut, or both: reading gives the messages of intact chunks or an error
    /// that names the file, never a panic, and never a tick that was not recorded.
    #[test]
    fn mutated_files_read_or_fail_clearly_and_never_panic(
        flips in proptest::collection::vec((0usize..usize::MAX, 1u8..=255), 0..6),
        cut in proptest::option::of(0usize..usize::MAX),
        case in 0u32..u32::MAX,
    ) {
        let mut bytes = small_file().to_vec();
        for (at, x) in &flips {
            let i = at % bytes.len();
            bytes[i] ^= x;
        }
        if let Some(c) = cut {
            bytes.truncate(c % (bytes.len() + 1));
        }
        let p = temp(&format!("mutated-{case}.mcap"));
        std::fs::write(&p, &bytes).unwrap();
        match read_back(&p) {
            Ok((rec, back)) => {
                prop_assert!(rec.ending.is_some());
                for t in &back {
                    let mut want = record(t.tick);
                    want.events = Default::default();
                    prop_assert_eq!(t.hands, want.hands);
                }
            }
            Err(e) => {
                let s = e.to_string();
                prop_assert!(s.contains(&p.display().to_string()), "{}", s);
            }
        }
        let _ = std::fs::remove_file(&p);
    }
}

/// The schemas as docs/recording.md lists them: every one, exactly as this code writes it.
#[test]
fn docs_list_every_schema_as_implemented() {
    use crate::cdr::schema_text;
    let docs = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/recording.md")).unwrap();
    for (name, text) in [
        ("spidar/Tick", schema_text::<TickRecord>()),
        ("spidar/HandSample", schema_text::<spidar_msg::HandSample>()),
        ("spidar/TakenModel", schema_text::<crate::schema::TakenModel>()),
        ("spidar/Event", schema_text::<crate::schema::EventMsg>()),
    ] {
        if std::env::var("SPIDAR_PRINT_SCHEMAS").is_ok() {
            // How the docs' listing is made.
            println!("### `{name}`\n\n```\n{text}```\n");
            continue;
        }
        assert!(
            docs.contains(&text),
            "docs/recording.md does not list the schema of {name} as written:\n{text}"
        );
    }
}

/// A file on a disk that fills up after `left` more bytes.
struct FillsUp {
    f: std::fs::File,
    left: usize,
}

impl std::io::Write for FillsUp {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            return Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "no space left on device"));
        }
        let n = buf.len().min(self.left);
        self.left -= n;
        self.f.write(&buf[..n])
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.f.flush()
    }
}

impl std::io::Seek for FillsUp {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.f.seek(pos)
    }
}

#[test]
fn a_full_disk_stops_the_recording_counts_what_was_lost_and_keeps_the_rest() {
    let p = temp("full.mcap");
    let sink = FillsUp { f: std::fs::File::create(&p).unwrap(), left: 300_000 };
    let mut rec = Recorder::with_sink(sink, &p, &info()).unwrap();
    let n = 6000;
    for i in 0..n {
        rec.write_tick(&record(i));
    }
    let rep = rec.finish(&EndInfo { ticks: n, ..Default::default() });
    let e = rep.error.clone().expect("the full disk is reported");
    assert!(e.contains("no space left"), "{e}");
    assert!(rep.ticks > 0 && rep.write_failed > 0, "{rep:?}");
    assert_eq!(rep.ticks + rep.write_failed, n, "every tick is either kept or counted lost");
    assert!(rep.to_string().contains("WRITING FAILED"), "{rep}");
    // The file holds exactly the ticks reported kept, in order from the first.
    let (r, back) = read_back(&p).unwrap();
    assert!(matches!(r.ending, Some(Ending::CutShort { .. })), "{:?}", r.ending);
    assert_eq!(back.len() as u64, rep.ticks);
    assert!(back.iter().enumerate().all(|(i, t)| t.tick == i as u64));
}
