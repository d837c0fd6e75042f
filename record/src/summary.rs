//! `spidar replay FILE`: what a recording holds, in a few lines: what made it, how long, the
//! rt-loop's figures recomputed from its ticks, the forces, the events, and where it ends. Built
//! once as a `spidar_rt::summary::Summary`, printed as text or as JSON (`--json`).

use std::path::Path;

use serde_json::json;
use spidar_rt::summary::{self as lines, Summary};
use spidar_rt::telemetry::Stats;
use spidar_rt::Lifecycle;

use crate::reader::{self, Ending, Flow, Msg, Recording};
use crate::schema::EventMsg;
use crate::RecordError;

/// Events listed in full; the rest are counted.
const EVENTS_LISTED: usize = 20;

/// A recording's summary.
pub struct RecordingSummary {
    pub recording: Recording,
    /// The rt-loop's statistics over the recorded ticks.
    pub stats: Stats,
    pub active_ticks: u64,
    pub samples: u64,
    pub models: u64,
    pub events: Vec<EventMsg>,
    pub event_count: u64,
    pub faults: u64,
    /// Contact onsets per hand (a hand touching something after touching nothing).
    pub hits: [u64; 2],
    pub clamped: [u64; 2],
    pub final_state: Option<Lifecycle>,
}

pub fn summarize(path: &Path) -> Result<RecordingSummary, RecordError> {
    let mut stats = Stats::new();
    let (mut active, mut samples, mut models, mut faults, mut n_events) = (0, 0, 0, 0, 0);
    let mut events = Vec::new();
    let mut hits = [0u64; 2];
    let mut clamped = [0u64; 2];
    let mut touching = [false; 2];
    let mut final_state = None;
    let recording = reader::read(path, |_, m| {
        match m {
            Msg::Tick(t) => {
                stats.add(&t);
                active += (t.state == Lifecycle::Active) as u64;
                for h in 0..2 {
                    let now = t.hands[h].contacts > 0;
                    hits[h] += (now && !touching[h]) as u64;
                    touching[h] = now;
                    clamped[h] += t.hands[h].clamped as u64;
                }
                final_state = Some(t.state);
            }
            Msg::Sample(_) => samples += 1,
            Msg::Model(_) => models += 1,
            Msg::Event(e) => {
                n_events += 1;
                faults += e.is_fault() as u64;
                if events.len() < EVENTS_LISTED {
                    events.push(e);
                }
            }
            Msg::Other { .. } => {}
        }
        Ok(Flow::Continue)
    })?;
    Ok(RecordingSummary {
        recording,
        stats,
        active_ticks: active,
        samples,
        models,
        events,
        event_count: n_events,
        faults,
        hits,
        clamped,
        final_state,
    })
}

impl RecordingSummary {
    /// The summary: the text `spidar replay FILE` prints and the JSON of `--json`, built once.
    pub fn summary(&self) -> Summary {
        let r = &self.recording;
        let s = &self.stats;
        let span = s.first_t_s.map_or(0.0, |t0| s.last_t_s - t0);
        let mut out =
            Summary::new(format!("recording {}: {:.2} s of rig time, {}", r.path.display(), span, r.library));
        out.field("command", "replay").field("file", r.path.display().to_string());
        self.what_made_it(&mut out);
        out.line(
            "ticks",
            format!(
                "{} ({:.1} Hz), {} active, {} missing (dropped while recording)",
                r.ticks,
                s.rate_hz(),
                self.active_ticks,
                r.missing_ticks
            ),
        );
        out.field("ticks", r.ticks)
            .field("missing_ticks", r.missing_ticks)
            .field("active_ticks", self.active_ticks);
        lines::lateness(&mut out, s, s.late_over_1ms);
        lines::compute(&mut out, s, "");
        lines::forces(&mut out, s, true);
        out.field("max_force_n", json!(s.max_force_n));
        out.row(
            "contacts",
            format!(
                "{} / {} hits (left/right), clamped {}/{} ticks",
                self.hits[0], self.hits[1], self.clamped[0], self.clamped[1]
            ),
            "hits",
            json!(self.hits),
        );
        out.line("link", format!("{} hand samples sent, {} contact models taken", self.samples, self.models));
        out.row(
            "events",
            format!("{} ({} faults)", self.event_count, self.faults),
            "events",
            self.event_count,
        );
        out.field("faults", self.faults);
        for e in &self.events {
            out.raw_line(format!("    t {:8.3} s  tick {:>8}  {}", e.t_s, e.tick, e.text));
        }
        if self.event_count > self.events.len() as u64 {
            out.raw_line(format!("    ... {} more", self.event_count - self.events.len() as u64));
        }
        self.ending(&mut out);
        out
    }

    /// `session`, `command`, `attached`, `channel`: what made the recording and what it holds.
    fn what_made_it(&self, out: &mut Summary) {
        let r = &self.recording;
        out.line(
            "session",
            format!(
                "rig {}, scene {}, script {}, device {}, seed {}, {} clock",
                r.meta("rig"),
                r.meta("scene"),
                r.meta("script"),
                r.meta("device"),
                r.meta("seed"),
                r.meta("clock")
            ),
        );
        out.field("session", json!(r.session));
        out.line("command", r.meta("command_line"));
        let names: Vec<&str> = r.attachments.iter().map(|(n, _)| n.as_str()).collect();
        out.row("attached", names.join(", "), "attachments", json!(names));
        let mut channels = Vec::new();
        for c in &r.channels {
            out.line(
                "channel",
                format!(
                    "{:<20} {:>9} messages  {} ({} / {})",
                    c.topic, c.messages, c.schema, c.schema_encoding, c.message_encoding
                ),
            );
            channels.push(json!({
                "topic": c.topic, "schema": c.schema, "schema_encoding": c.schema_encoding,
                "message_encoding": c.message_encoding, "messages": c.messages,
            }));
        }
        out.field("channels", channels);
    }

    /// `session end` and `file`: how the session ended and where the readable file ends.
    fn ending(&self, out: &mut Summary) {
        let r = &self.recording;
        if let Some(end) = &r.end_meta {
            let g = |k: &str| end.get(k).map_or("?", |s| s.as_str());
            out.line(
                "session end",
                format!(
                    "{} after {} ticks ({} recorded, {} dropped by telemetry, {} by the recorder), clean stop {}",
                    g("final_state"),
                    g("ticks"),
                    g("ticks_recorded"),
                    g("telemetry_dropped"),
                    g("queue_dropped"),
                    g("clean_stop")
                ),
            );
        } else if let Some(st) = self.final_state {
            out.line("session end", format!("not recorded; the last tick was {}", st.name()));
        }
        out.field("end", json!(r.end_meta));
        out.row("file", r.ends(), "ends", r.ends());
        out.field("complete", r.ending == Some(Ending::Complete));
    }
}

impl std::fmt::Display for RecordingSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.summary())
    }
}
