//! `spidar replay FILE`: what a recording holds, in a few lines: what made it, how long, the
//! rt-loop's figures recomputed from its ticks, the forces, the events, and where it ends.

use std::path::Path;

use spidar_rt::telemetry::Stats;
use spidar_rt::Lifecycle;

use crate::reader::{self, Flow, Msg, Recording};
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

impl std::fmt::Display for RecordingSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.recording;
        let s = &self.stats;
        let span = s.first_t_s.map_or(0.0, |t0| s.last_t_s - t0);
        writeln!(f, "recording {}: {:.2} s of rig time, {}", r.path.display(), span, r.library)?;
        writeln!(
            f,
            "  session      rig {}, scene {}, script {}, device {}, seed {}, {} clock",
            r.meta("rig"),
            r.meta("scene"),
            r.meta("script"),
            r.meta("device"),
            r.meta("seed"),
            r.meta("clock")
        )?;
        writeln!(f, "  command      {}", r.meta("command_line"))?;
        let names: Vec<&str> = r.attachments.iter().map(|(n, _)| n.as_str()).collect();
        writeln!(f, "  attached     {}", names.join(", "))?;
        for c in &r.channels {
            writeln!(
                f,
                "  channel      {:<20} {:>9} messages  {} ({} / {})",
                c.topic, c.messages, c.schema, c.schema_encoding, c.message_encoding
            )?;
        }
        writeln!(
            f,
            "  ticks        {} ({:.1} Hz), {} active, {} missing (dropped while recording)",
            r.ticks,
            s.rate_hz(),
            self.active_ticks,
            r.missing_ticks
        )?;
        let lat = s.lateness.percentiles();
        writeln!(f, "  lateness     {lat}")?;
        writeln!(f, "  misses       {} ticks woke > 1 ms late", s.late_over_1ms)?;
        writeln!(f, "  compute      {}", s.compute.percentiles())?;
        writeln!(f, "  max force    left {:.2} N, right {:.2} N", s.max_force_n[0], s.max_force_n[1])?;
        writeln!(
            f,
            "  tensions     {:.2} .. {:.2} N commanded",
            if s.min_tension_n.is_finite() { s.min_tension_n } else { 0.0 },
            s.max_tension_n
        )?;
        writeln!(
            f,
            "  contacts     {} / {} hits (left/right), clamped {}/{} ticks",
            self.hits[0], self.hits[1], self.clamped[0], self.clamped[1]
        )?;
        writeln!(
            f,
            "  link         {} hand samples sent, {} contact models taken",
            self.samples, self.models
        )?;
        writeln!(f, "  events       {} ({} faults)", self.event_count, self.faults)?;
        for e in &self.events {
            writeln!(f, "    t {:8.3} s  tick {:>8}  {}", e.t_s, e.tick, e.text)?;
        }
        if self.event_count > self.events.len() as u64 {
            writeln!(f, "    ... {} more", self.event_count - self.events.len() as u64)?;
        }
        if let Some(end) = &r.end_meta {
            let g = |k: &str| end.get(k).map_or("?", |s| s.as_str());
            writeln!(
                f,
                "  session end  {} after {} ticks ({} recorded, {} dropped by telemetry, {} by the recorder), clean stop {}",
                g("final_state"),
                g("ticks"),
                g("ticks_recorded"),
                g("telemetry_dropped"),
                g("queue_dropped"),
                g("clean_stop")
            )?;
        } else if let Some(st) = self.final_state {
            writeln!(f, "  session end  not recorded; the last tick was {}", st.name())?;
        }
        write!(f, "  file         {}", r.ends())
    }
}
