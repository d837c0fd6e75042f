//! What a session reports when it ends: the live run's [`Summary`], the virtual run's
//! [`VirtualSummary`] and the faults counted per kind ([`FaultTally`]), as the text printed on exit.
//! (`report` turns the same structs into JSON and an exit status; `recording` into the recording's
//! end record.)

use spidar_rt::rt_thread::RtReport;
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

impl std::fmt::Display for VirtualSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        let rig_s = c.ticks as f64 * self.period_s;
        writeln!(
            f,
            "spidar run --virtual: {} ticks ({rig_s:.3} s of rig time, {} s asked) in {:.2} s wall ({:.0}x real time)",
            c.ticks,
            self.seconds,
            self.wall_s,
            rig_s / self.wall_s.max(1e-9)
        )?;
        writeln!(f, "  on           {}, scene {}, script {}", self.device, self.scene, self.script)?;
        if !self.rig_file.is_empty() {
            writeln!(f, "  rig file     {}", self.rig_file)?;
        }
        writeln!(f, "  ticks        {} active", c.active_ticks)?;
        writeln!(f, "  compute      {}", self.stats.compute.percentiles())?;
        if !self.scene_status.is_empty() {
            writeln!(f, "  scene        {}", self.scene_status)?;
        }
        writeln!(
            f,
            "  max force    left {:.2} N, right {:.2} N",
            self.stats.max_force_n[0], self.stats.max_force_n[1]
        )?;
        writeln!(
            f,
            "  safety       clamped {}/{}, infeasible {}/{}, fallback {}/{}, faults {}, device errors {}",
            c.clamped[0],
            c.clamped[1],
            c.infeasible[0],
            c.infeasible[1],
            c.fallback[0],
            c.fallback[1],
            c.faults,
            c.device_errors
        )?;
        write_held(f, c)?;
        write!(f, "{}", self.faults_seen)?;
        if let Some(r) = &self.recording {
            writeln!(f, "  recording    {r}")?;
        }
        write_end(f, self.final_state, self.clean_stop, self.halted, self.signals)
    }
}

/// The ticks that held the last safe output (a late, missing or rejected reply) and why.
fn write_held(f: &mut std::fmt::Formatter<'_>, c: &Counters) -> std::fmt::Result {
    writeln!(
        f,
        "               held ticks {}/{} (late replies {}, count jumps {}/{}, residual high {}/{}), rehomes {}",
        c.held[0],
        c.held[1],
        c.late_replies,
        c.count_jumps[0],
        c.count_jumps[1],
        c.residual_high[0],
        c.residual_high[1],
        c.rehomes
    )
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

impl std::fmt::Display for FaultTally {
    /// One line per kind: `  fault        12 x device error (Timeout)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (what, n) in self.iter() {
            writeln!(f, "  fault        {n} x {what}")?;
        }
        Ok(())
    }
}

impl std::fmt::Display for SessionSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        let s = &self.stats;
        let lat = s.lateness.percentiles();
        let comp = s.compute.percentiles();
        let io = s.io.percentiles();
        writeln!(
            f,
            "spidar run: {:.2} s on {}, scene {}, script {}",
            self.wall_s, self.device, self.scene, self.script
        )?;
        if !self.rig_file.is_empty() {
            writeln!(f, "  rig file     {}", self.rig_file)?;
        }
        writeln!(f, "  real time    {}", self.rt)?;
        if !self.overrides.is_empty() {
            writeln!(f, "  OVERRIDES    rig bounds exceeded on purpose: {}", self.overrides.join(", "))?;
        }
        for w in &self.rt.warnings {
            writeln!(f, "  warning      {w}")?;
        }
        writeln!(f, "  ticks        {} ({:.1} Hz), {} active", c.ticks, s.rate_hz(), c.active_ticks)?;
        writeln!(f, "  lateness     {lat}")?;
        writeln!(f, "  misses       {} ticks woke > 1 ms late", c.misses)?;
        writeln!(f, "  compute      {comp}  (per tick, both hands, excluding device I/O)")?;
        writeln!(f, "  device I/O   {io}")?;
        writeln!(f, "  max force    left {:.2} N, right {:.2} N", s.max_force_n[0], s.max_force_n[1])?;
        writeln!(
            f,
            "  tensions     {:.2} .. {:.2} N commanded",
            if s.min_tension_n.is_finite() { s.min_tension_n } else { 0.0 },
            s.max_tension_n
        )?;
        writeln!(
            f,
            "  safety       clamped {}/{}, infeasible {}/{}, fallback {}/{}, stiffness-limited {}/{} (left/right ticks)",
            c.clamped[0],
            c.clamped[1],
            c.infeasible[0],
            c.infeasible[1],
            c.fallback[0],
            c.fallback[1],
            c.stiffness_limited[0],
            c.stiffness_limited[1]
        )?;
        writeln!(
            f,
            "               passivity-limited {}/{} (avatar-hand contacts scaled to give back no more energy than put in)",
            c.passivity_limited[0], c.passivity_limited[1]
        )?;
        writeln!(
            f,
            "               stale-model ticks {}, non-finite forces {}, faults {}, device errors {}",
            c.stale, c.non_finite, c.faults, c.device_errors
        )?;
        write_held(f, c)?;
        write!(f, "{}", self.faults_seen)?;
        let late = self.scene_late.map_or(String::new(), |n| format!(" ({n} late)"));
        writeln!(
            f,
            "  scene        {} steps{late}, {} models received, {} dropped",
            self.scene_steps, c.models, self.models_dropped
        )?;
        if !self.scene_status.is_empty() {
            writeln!(f, "               {}", self.scene_status)?;
        }
        writeln!(f, "  world        {}", self.world)?;
        if let Some(l) = &self.link {
            writeln!(f, "  link         {l}")?;
        }
        if let Some(r) = &self.world_report {
            writeln!(f, "  world said   {r}")?;
        }
        writeln!(
            f,
            "  dropped      telemetry {}, samples {} (their impulses went with the next), impulses {}, events {}",
            c.telemetry_dropped, c.samples_dropped, c.impulses_lost, c.events_dropped
        )?;
        write_end(f, self.final_state, self.clean_stop, self.halted, self.signals)
    }
}

/// How a loop ended, in words.
/// The summary's last line: the final state, how the session stopped and on how many signals.
fn write_end(
    f: &mut std::fmt::Formatter<'_>,
    state: Lifecycle,
    clean_stop: bool,
    halted: bool,
    signals: u32,
) -> std::fmt::Result {
    let by = match signals {
        0 => String::new(),
        1 => ", on a stop signal".into(),
        n => format!(", on {n} stop signals"),
    };
    write!(f, "  end          {} ({}{by})", state.name(), end_words(clean_stop, halted))
}

fn end_words(clean_stop: bool, halted: bool) -> &'static str {
    match (clean_stop, halted) {
        (true, false) => "forces ramped out, strings at minimum tension, device off",
        (true, true) => "stopped at once: outputs zeroed without the ramp-out, device off",
        (false, _) => "NOT a clean stop",
    }
}
