//! What a run reports to the shell: its exit status. (What it reports to a person and to scripts
//! is its summary, `summary.rs`.)

use spidar_rt::{Counters, Lifecycle};

use crate::summary::FaultTally;

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
