//! What a run reports to scripts (`--json`) and to the shell (its exit status).

use serde_json::{json, Value};
use spidar_record::world::WorldRecordingReport;
use spidar_record::writer::RecordingReport;
use spidar_rt::telemetry::{Percentiles, Stats};
use spidar_rt::{Counters, Lifecycle};

use crate::summary::{FaultTally, SessionSummary, VirtualSummary};

/// Fails a run that ended faulted or whose rig never became active, so scripts and CI see it in
/// the exit status (the summary says the same in words).
pub fn check_outcome(
    final_state: Lifecycle,
    counters: &Counters,
    faults_seen: &FaultTally,
) -> anyhow::Result<()> {
    if final_state == Lifecycle::Faulted {
        let why = faults_seen.last().unwrap_or("see the summary");
        anyhow::bail!("the session ended faulted ({why})");
    }
    if counters.active_ticks == 0 {
        anyhow::bail!(
            "the rig never became active: it was not homed, or a fault or a stop came first; see the summary's faults"
        );
    }
    Ok(())
}

/// The faults, counted per kind.
fn faults(f: &FaultTally) -> Value {
    f.iter().map(|(kind, count)| json!({ "fault": kind, "count": count })).collect()
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
        "held_ticks": c.held,
        "late_replies": c.late_replies,
        "count_jumps": c.count_jumps,
        "residual_high": c.residual_high,
        "rehomes": c.rehomes,
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

/// The world's recording (`FILE.world.mcap`): what it kept and what it could not.
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

/// `spidar run --json`: the summary's figures, in SI units (seconds, newtons).
pub fn run_json(
    s: &SessionSummary,
    recording: Option<&RecordingReport>,
    world_recording: Option<&WorldRecordingReport>,
) -> Value {
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
        "faults": faults(&s.faults_seen),
        "scene_status": s.scene_status,
        "scene_steps": s.scene_steps,
        "scene_late_steps": s.scene_late,
        "models_received": c.models,
        "models_dropped": s.models_dropped,
        "dropped": { "telemetry": c.telemetry_dropped, "samples": c.samples_dropped, "events": c.events_dropped },
        "end": {
            "state": s.final_state.name(),
            "clean_stop": s.clean_stop,
            "halted": s.halted,
            "stop_signals": s.signals,
        },
        "recording": recording.map(recording_json),
        "world_recording": world_recording.map(world_recording_json),
    })
}

/// `spidar run --virtual --json`.
pub fn virtual_json(s: &VirtualSummary, world_recording: Option<&WorldRecordingReport>) -> Value {
    let c = &s.counters;
    json!({
        "command": "run",
        "measured": "the virtual clock: device, rt-loop and scene interleaved on one thread",
        "device": s.device,
        "scene": s.scene,
        "script": s.script,
        "rig_file": s.rig_file,
        "ticks": c.ticks,
        "rig_seconds": c.ticks as f64 * s.period_s,
        "seconds_asked": s.seconds,
        "wall_s": s.wall_s,
        "active_ticks": c.active_ticks,
        "compute_s": pct(&s.stats.compute.percentiles()),
        "forces": forces(&s.stats),
        "safety": safety(c),
        "faults": faults(&s.faults_seen),
        "scene_status": s.scene_status,
        "end": {
            "state": s.final_state.name(),
            "clean_stop": s.clean_stop,
            "halted": s.halted,
            "stop_signals": s.signals,
        },
        "recording": s.recording.as_ref().map(recording_json),
        "world_recording": world_recording.map(world_recording_json),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_faulted_or_never_active_session_fails_the_run() {
        let active = Counters { active_ticks: 10, ..Default::default() };
        let none = FaultTally::default();
        assert!(check_outcome(Lifecycle::Inactive, &active, &none).is_ok());
        let mut seen = FaultTally::default();
        seen.push("hand 0: pose could not be computed".into());
        seen.push("device error (Timeout)".into());
        let e = check_outcome(Lifecycle::Faulted, &active, &seen).unwrap_err();
        assert!(e.to_string().contains("ended faulted (device error (Timeout))"), "{e}");
        let never = Counters::default();
        assert!(check_outcome(Lifecycle::Inactive, &never, &none)
            .unwrap_err()
            .to_string()
            .contains("never became active"));
    }
}
