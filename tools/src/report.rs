//! What a run reports to scripts (`--json`) and to the shell (its exit status).

use serde_json::{json, Value};
use spidar_record::writer::RecordingReport;
use spidar_rt::telemetry::{Percentiles, Stats};
use spidar_rt::{Counters, Lifecycle};

use crate::session::Summary;

/// Fails a run that ended faulted or whose rig never became active, so scripts and CI see it in
/// the exit status (the summary says the same in words).
pub fn check_outcome(
    final_state: Lifecycle,
    counters: &Counters,
    faults_seen: &[String],
) -> anyhow::Result<()> {
    if final_state == Lifecycle::Faulted {
        let why = faults_seen.last().map_or("see the summary".to_string(), |f| f.clone());
        anyhow::bail!("the session ended faulted ({why})");
    }
    if counters.active_ticks == 0 {
        anyhow::bail!(
            "the rig never became active: it was not homed or a fault came first; see the summary's faults"
        );
    }
    Ok(())
}

fn pct(p: &Percentiles) -> Value {
    json!({ "count": p.count, "p50": p.p50_s, "p99": p.p99_s, "p999": p.p999_s, "max": p.max_s })
}

fn safety(c: &Counters) -> Value {
    json!({
        "clamped_ticks": c.clamped,
        "infeasible_ticks": c.infeasible,
        "fallback_ticks": c.fallback,
        "stiffness_limited_ticks": c.stiffness_limited,
        "stale_model_ticks": c.stale,
        "non_finite_forces": c.non_finite,
        "faults": c.faults,
        "device_errors": c.device_errors,
        "reopens": c.reopens,
    })
}

fn forces(s: &Stats) -> Value {
    json!({
        "max_force_n": s.max_force_n,
        "tension_n": {
            "min": if s.min_tension_n.is_finite() { s.min_tension_n } else { 0.0 },
            "max": s.max_tension_n,
        },
    })
}

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

/// `spidar run --json`: the summary's figures, in SI units (seconds, newtons).
pub fn run_json(s: &Summary, recording: Option<&RecordingReport>) -> Value {
    let c = &s.counters;
    json!({
        "command": "run",
        "measured": "the live path: device, rt-loop on the real clock, scene thread",
        "device": s.device,
        "scene": s.scene,
        "script": s.script,
        "rig_file": s.rig_file,
        "wall_s": s.wall_s,
        "real_time": {
            "policy": s.rt.policy,
            "fifo": s.rt.fifo,
            "memory_locked": s.rt.memory_locked,
            "cpu": s.rt.cpu,
            "warnings": s.rt.warnings,
        },
        "ticks": c.ticks,
        "rate_hz": s.stats.rate_hz(),
        "active_ticks": c.active_ticks,
        "lateness_s": pct(&s.stats.lateness.percentiles()),
        "misses": c.misses,
        "compute_s": pct(&s.stats.compute.percentiles()),
        "device_io_s": pct(&s.stats.io.percentiles()),
        "forces": forces(&s.stats),
        "safety": safety(c),
        "faults": s.faults_seen,
        "scene_status": s.scene_status,
        "scene_steps": s.scene_steps,
        "scene_late_steps": s.scene_late,
        "models_received": c.models,
        "models_dropped": s.models_dropped,
        "dropped": { "telemetry": c.telemetry_dropped, "samples": c.samples_dropped, "events": c.events_dropped },
        "end": { "state": s.final_state.name(), "clean_stop": s.clean_stop },
        "recording": recording.map(recording_json),
    })
}

/// What a run on the virtual clock reports.
pub struct VirtualRunReport<'a> {
    pub ticks: u64,
    pub rig_seconds: f64,
    pub wall_s: f64,
    pub stats: &'a Stats,
    pub counters: &'a Counters,
    pub scene_status: &'a str,
    pub end: Lifecycle,
    pub recording: Option<&'a RecordingReport>,
    /// The rig file the run used (`RigSource::describe`).
    pub rig_file: &'a str,
}

/// `spidar run --virtual --json`.
pub fn virtual_json(r: &VirtualRunReport<'_>) -> Value {
    json!({
        "command": "run",
        "measured": "the virtual clock: device, rt-loop and scene interleaved on one thread",
        "ticks": r.ticks,
        "rig_seconds": r.rig_seconds,
        "rig_file": r.rig_file,
        "wall_s": r.wall_s,
        "active_ticks": r.counters.active_ticks,
        "compute_s": pct(&r.stats.compute.percentiles()),
        "forces": forces(r.stats),
        "safety": safety(r.counters),
        "scene_status": r.scene_status,
        "end": { "state": r.end.name() },
        "recording": r.recording.map(recording_json),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_faulted_or_never_active_session_fails_the_run() {
        let active = Counters { active_ticks: 10, ..Default::default() };
        assert!(check_outcome(Lifecycle::Inactive, &active, &[]).is_ok());
        let e = check_outcome(Lifecycle::Faulted, &active, &["device error (Timeout)".into()]).unwrap_err();
        assert!(e.to_string().contains("ended faulted (device error (Timeout))"), "{e}");
        let never = Counters::default();
        assert!(check_outcome(Lifecycle::Inactive, &never, &[])
            .unwrap_err()
            .to_string()
            .contains("never became active"));
    }
}
