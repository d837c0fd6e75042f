//! What a session reports when it ends: the live run's [`SessionSummary`], the virtual run's
//! [`VirtualSummary`] and the faults counted per kind ([`FaultTally`]). Each is rendered once, into
//! a [`Summary`] that prints as the text shown on exit and as the JSON of `--json`; the lines all
//! summaries share are `spidar_rt::summary`'s. (`report` turns a session into an exit status;
//! `recording` into the recording's end record.)

use serde_json::{json, Value};
use spidar_record::world::WorldRecordingReport;
use spidar_record::writer::RecordingReport;
use spidar_rt::rt_thread::RtReport;
use spidar_rt::summary::{self as lines, Summary};
use spidar_rt::telemetry::Stats;
use spidar_rt::{Counters, Lifecycle};

/// What a virtual run reports at the end.
#[derive(Debug)]
pub struct VirtualSummary {
    pub device: String,
    pub scene: String,
    pub script: String,
    /// The rig file the run used (`RigSource::describe`; set by the caller).
    pub rig_file: String,
    /// Rig time asked for, and wall time taken (s).
    pub seconds: f64,
    pub wall_s: f64,
    /// The rig's tick period (s).
    pub period_s: f64,
    pub stats: Stats,
    pub counters: Counters,
    pub scene_status: String,
    pub final_state: Lifecycle,
    pub faults_seen: FaultTally,
    pub clean_stop: bool,
    pub halted: bool,
    pub signals: u32,
    /// What `VirtualOptions::recorder` wrote.
    pub recording: Option<spidar_record::writer::RecordingReport>,
}

impl VirtualSummary {
    /// The summary of a virtual run, with the world's recording when there is one.
    pub fn summary(&self, world_recording: Option<&WorldRecordingReport>) -> Summary {
        let c = &self.counters;
        let rig_s = c.ticks as f64 * self.period_s;
        let mut out = Summary::new(format!(
            "spidar run --virtual: {} ticks ({rig_s:.3} s of rig time, {} s asked) in {:.2} s wall ({:.0}x real time)",
            c.ticks,
            self.seconds,
            self.wall_s,
            rig_s / self.wall_s.max(1e-9)
        ));
        out.field("command", "run")
            .field("measured", "the virtual clock: device, rt-loop and scene interleaved on one thread")
            .field("ticks", c.ticks)
            .field("rig_seconds", rig_s)
            .field("seconds_asked", self.seconds)
            .field("wall_s", self.wall_s);
        out.line("on", format!("{}, scene {}, script {}", self.device, self.scene, self.script));
        out.field("device", self.device.as_str())
            .field("scene", self.scene.as_str())
            .field("script", self.script.as_str());
        rig_file(&mut out, &self.rig_file);
        out.row("ticks", format!("{} active", c.active_ticks), "active_ticks", c.active_ticks);
        lines::compute(&mut out, &self.stats, "");
        scene_status(&mut out, "scene", &self.scene_status);
        lines::forces(&mut out, &self.stats, false);
        out.row(
            "safety",
            format!("{}, faults {}, device errors {}", lines::clamped_counts(c), c.faults, c.device_errors),
            "safety",
            lines::safety_json(c),
        );
        lines::held(&mut out, c);
        self.faults_seen.lines(&mut out);
        recording_line(&mut out, self.recording.as_ref());
        lines::end(&mut out, self.final_state, self.clean_stop, self.halted, self.signals);
        world_recording_line(&mut out, world_recording);
        out
    }
}

impl std::fmt::Display for VirtualSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.summary(None))
    }
}

/// `rig file`: the rig file the run used (always in the JSON, in the text when known).
fn rig_file(out: &mut Summary, rig_file: &str) {
    if !rig_file.is_empty() {
        out.line("rig file", rig_file);
    }
    out.field("rig_file", rig_file);
}

/// The scene's own status at the end, under `label` (in the text when it says something).
fn scene_status(out: &mut Summary, label: &'static str, status: &str) {
    if !status.is_empty() {
        out.line(label, status);
    }
    out.field("scene_status", status);
}

/// `recording`: what the rig's recording kept (`null` in the JSON without one).
fn recording_line(out: &mut Summary, r: Option<&RecordingReport>) {
    match r {
        Some(r) => out.row("recording", r.to_string(), "recording", recording_json(r)),
        None => out.field("recording", Value::Null),
    };
}

/// `world rec.`: what the world's recording kept (`null` in the JSON without one).
fn world_recording_line(out: &mut Summary, r: Option<&WorldRecordingReport>) {
    match r {
        Some(r) => out.row("world rec.", r.to_string(), "world_recording", world_recording_json(r)),
        None => out.field("world_recording", Value::Null),
    };
}

/// The rig's recording for scripts: what it kept and what it could not.
pub fn recording_json(r: &RecordingReport) -> Value {
    json!({
        "path": r.path.display().to_string(),
        "ticks": r.ticks,
        "samples": r.samples,
        "models": r.models,
        "events": r.events,
        "bytes": r.bytes,
        "not_kept": {
            "total": r.lost(),
            "telemetry_dropped": r.telemetry_dropped,
            "queue_dropped": r.queue_dropped,
            "write_failed": r.write_failed,
        },
        "error": r.error,
    })
}

/// The world's recording (`FILE.world.mcap`) for scripts: what it kept and what it could not.
pub fn world_recording_json(r: &WorldRecordingReport) -> Value {
    json!({
        "path": r.path.display().to_string(),
        "steps": r.steps,
        "messages": r.messages,
        "events": r.events,
        "bytes": r.bytes,
        "not_kept": {
            "total": r.dropped + r.write_failed,
            "queue_dropped": r.dropped,
            "write_failed": r.write_failed,
        },
        "error": r.error,
    })
}

/// What a live run reports at the end.
#[derive(Debug)]
pub struct SessionSummary {
    pub device: String,
    pub scene: String,
    pub script: String,
    pub wall_s: f64,
    pub rt: RtReport,
    pub stats: Stats,
    pub counters: Counters,
    pub scene_steps: u64,
    /// Steps that started late (known for a thread world; a world process reports its own).
    pub scene_late: Option<u64>,
    pub models_dropped: u64,
    /// The scene's own status at the end (`Scene::status`).
    pub scene_status: String,
    /// Where the world ran, and what became of it.
    pub world: String,
    /// The link's counters (a world process).
    pub link: Option<String>,
    /// The world process's own report.
    pub world_report: Option<String>,
    pub final_state: Lifecycle,
    /// Faults and refused commands, counted per kind.
    pub faults_seen: FaultTally,
    pub clean_stop: bool,
    /// Stopped at once by a second stop signal: outputs zeroed without the ramp-out.
    pub halted: bool,
    /// Stop signals received (0: the run ended by its time limit or by itself).
    pub signals: u32,
    /// What `LiveOptions::recorder` wrote.
    pub recording: Option<spidar_record::writer::RecordingReport>,
    /// Rig-file bounds overridden for this run (shown, never silent).
    pub overrides: Vec<String>,
    /// The rig file the run used (`RigSource::describe`; empty: not said).
    pub rig_file: String,
}

/// Faults and refused commands seen during a session, counted per kind in the order each kind
/// first came (a flaky cable gives one line with its count, not a line per fault).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultTally {
    kinds: Vec<(String, u64)>,
    last: Option<usize>,
}

impl FaultTally {
    pub fn push(&mut self, what: String) {
        match self.kinds.iter().position(|(k, _)| *k == what) {
            Some(i) => {
                self.kinds[i].1 += 1;
                self.last = Some(i);
            }
            None => {
                self.kinds.push((what, 1));
                self.last = Some(self.kinds.len() - 1);
            }
        }
    }
    /// Every kind with its count, first seen first.
    pub fn iter(&self) -> impl Iterator<Item = (&str, u64)> {
        self.kinds.iter().map(|(k, n)| (k.as_str(), *n))
    }
    /// The kind of the newest one.
    pub fn last(&self) -> Option<&str> {
        self.last.map(|i| self.kinds[i].0.as_str())
    }
    pub fn total(&self) -> u64 {
        self.kinds.iter().map(|(_, n)| n).sum()
    }
    pub fn is_empty(&self) -> bool {
        self.kinds.is_empty()
    }
}

impl FaultTally {
    /// One `fault` line per kind (`12 x device error (Timeout)`), and the counts for scripts.
    pub fn lines(&self, out: &mut Summary) {
        for (what, n) in self.iter() {
            out.line("fault", format!("{n} x {what}"));
        }
        let counts: Value =
            self.iter().map(|(kind, count)| json!({ "fault": kind, "count": count })).collect();
        out.field("faults", counts);
    }
}

impl SessionSummary {
    /// The summary of a live run, with what its recordings kept.
    pub fn summary(
        &self,
        recording: Option<&RecordingReport>,
        world_recording: Option<&WorldRecordingReport>,
    ) -> Summary {
        let c = &self.counters;
        let s = &self.stats;
        let mut out = Summary::new(format!(
            "spidar run: {:.2} s on {}, scene {}, script {}",
            self.wall_s, self.device, self.scene, self.script
        ));
        out.field("command", "run")
            .field("measured", "the live path: device, rt-loop on the real clock, scene thread")
            .field("device", self.device.as_str())
            .field("scene", self.scene.as_str())
            .field("script", self.script.as_str())
            .field("wall_s", self.wall_s);
        rig_file(&mut out, &self.rig_file);
        self.real_time(&mut out);
        out.row(
            "ticks",
            format!("{} ({:.1} Hz), {} active", c.ticks, s.rate_hz(), c.active_ticks),
            "ticks",
            c.ticks,
        );
        out.field("rate_hz", s.rate_hz()).field("active_ticks", c.active_ticks);
        lines::lateness(&mut out, s, c.misses);
        lines::compute(&mut out, s, "  (per tick, both hands, excluding device I/O)");
        let io = s.io.percentiles();
        out.row("device I/O", io.to_string(), "device_io_s", lines::percentiles_json(&io));
        lines::forces(&mut out, s, true);
        safety(&mut out, c);
        self.faults_seen.lines(&mut out);
        self.world(&mut out);
        out.row(
            "dropped",
            format!(
                "telemetry {}, samples {} (their impulses went with the next), impulses {}, events {}",
                c.telemetry_dropped, c.samples_dropped, c.impulses_lost, c.events_dropped
            ),
            "dropped",
            json!({ "telemetry": c.telemetry_dropped, "samples": c.samples_dropped, "events": c.events_dropped }),
        );
        lines::end(&mut out, self.final_state, self.clean_stop, self.halted, self.signals);
        recording_line(&mut out, recording);
        world_recording_line(&mut out, world_recording);
        out
    }

    /// `real time`: the loop thread's scheduling, the overrides in effect and the warnings.
    fn real_time(&self, out: &mut Summary) {
        let rt = &self.rt;
        let figures = json!({
            "policy": rt.policy,
            "fifo": rt.fifo,
            "memory_locked": rt.memory_locked,
            "cpu": rt.cpu,
            "warnings": rt.warnings,
        });
        out.row("real time", rt.to_string(), "real_time", figures);
        if !self.overrides.is_empty() {
            out.line("OVERRIDES", format!("rig bounds exceeded on purpose: {}", self.overrides.join(", ")));
        }
        out.field("overrides", self.overrides.clone());
        for w in &rt.warnings {
            out.line("warning", w.as_str());
        }
    }

    /// `scene`, `world`, `link`, `world said`: what the world did and what became of it.
    fn world(&self, out: &mut Summary) {
        let c = &self.counters;
        let late = self.scene_late.map_or(String::new(), |n| format!(" ({n} late)"));
        out.line(
            "scene",
            format!(
                "{} steps{late}, {} models received, {} dropped",
                self.scene_steps, c.models, self.models_dropped
            ),
        );
        out.field("scene_steps", self.scene_steps)
            .field("scene_late_steps", self.scene_late)
            .field("models_received", c.models)
            .field("models_dropped", self.models_dropped);
        scene_status(out, "", &self.scene_status);
        out.row("world", self.world.as_str(), "world", self.world.as_str());
        if let Some(l) = &self.link {
            out.row("link", l.as_str(), "link", l.as_str());
        }
        if let Some(r) = &self.world_report {
            out.row("world said", r.as_str(), "world_said", r.as_str());
        }
    }
}

/// A live run's `safety` lines: what the safety phase did, per hand.
fn safety(out: &mut Summary, c: &Counters) {
    out.row(
        "safety",
        format!(
            "{}, stiffness-limited {}/{} (left/right ticks)",
            lines::clamped_counts(c),
            c.stiffness_limited[0],
            c.stiffness_limited[1]
        ),
        "safety",
        lines::safety_json(c),
    );
    out.line(
        "",
        format!(
            "passivity-limited {}/{} (avatar-hand contacts scaled to give back no more energy than put in)",
            c.passivity_limited[0], c.passivity_limited[1]
        ),
    );
    out.line(
        "",
        format!(
            "blows felt {}/{}, burst energy {:.1}/{:.1} mJ, bursts cut {}/{} and pushes limited {}/{} ticks (landed blows, `docs/boxing.md` 6)",
            c.blows_felt[0],
            c.blows_felt[1],
            c.blow_burst_uj[0] as f64 * 1e-3,
            c.blow_burst_uj[1] as f64 * 1e-3,
            c.blow_burst_cut[0],
            c.blow_burst_cut[1],
            c.blow_push_limited[0],
            c.blow_push_limited[1],
        ),
    );
    out.field(
        "blows",
        serde_json::json!({
            "felt": c.blows_felt,
            "burst_energy_uj": c.blow_burst_uj,
            "burst_cut_ticks": c.blow_burst_cut,
            "push_limited_ticks": c.blow_push_limited,
        }),
    );
    out.line(
        "",
        format!(
            "stale-model ticks {}, non-finite forces {}, faults {}, device errors {}",
            c.stale, c.non_finite, c.faults, c.device_errors
        ),
    );
    lines::held(out, c);
}

impl std::fmt::Display for SessionSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.summary(None, None))
    }
}
