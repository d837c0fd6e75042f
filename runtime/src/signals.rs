//! The signals that end a session: SIGINT (Ctrl-C), SIGTERM (systemd stop, `kill`) and SIGHUP
//! (a closing terminal) all ask for the same clean stop. The first one asks for the ramp-out
//! (force to zero, strings at minimum tension, device off, summary); a second one asks to stop at
//! once with the outputs zeroed. Every command that holds a device polls a [`Stop`].
//!
//! The handler is process-wide (installed once; later calls share it) and only counts: the work
//! is done by whoever polls, so nothing unsafe runs inside a signal handler.
//!
//! A rig process under a supervisor (`spidar run` on real boards, see `supervisor`) also counts
//! the signals its supervisor received ([`Stop::with_forwarded`]): the larger of the two counts
//! is taken, so a Ctrl-C that reaches both processes counts once, and a `kill -TERM` sent to the
//! supervisor alone still stops the rig.

use std::os::unix::process::ExitStatusExt;
use std::process::ExitStatus;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::Context;

static COUNT: OnceLock<Arc<AtomicU32>> = OnceLock::new();

/// How many stop signals this process received, shared with the handler.
#[derive(Clone, Debug)]
pub struct Stop {
    count: Arc<AtomicU32>,
    /// The signals a supervising process received and passed on.
    forwarded: Option<&'static AtomicU32>,
}

impl Stop {
    /// Installs the handler for SIGINT, SIGTERM and SIGHUP (once per process) and returns the
    /// shared counter.
    pub fn install() -> anyhow::Result<Stop> {
        if let Some(c) = COUNT.get() {
            return Ok(Stop { count: c.clone(), forwarded: None });
        }
        let count = Arc::new(AtomicU32::new(0));
        let c = count.clone();
        ctrlc::set_handler(move || {
            c.fetch_add(1, Ordering::SeqCst);
        })
        .context("installing the handler for SIGINT, SIGTERM and SIGHUP")?;
        let _ = COUNT.set(count.clone());
        Ok(Stop { count, forwarded: None })
    }

    /// A counter no signal reaches (tests, library callers that stop by other means).
    pub fn detached() -> Stop {
        Stop { count: Arc::new(AtomicU32::new(0)), forwarded: None }
    }

    /// Also counts the stop signals a supervisor writes into `forwarded` (the larger count wins).
    pub fn with_forwarded(mut self, forwarded: &'static AtomicU32) -> Stop {
        self.forwarded = Some(forwarded);
        self
    }

    /// A clean stop was asked for (one signal or more, or [`Stop::request`]).
    pub fn requested(&self) -> bool {
        self.count() >= 1
    }

    /// A second signal came: stop at once, outputs zeroed, no ramp.
    pub fn urgent(&self) -> bool {
        self.count() >= 2
    }

    /// Asks for a stop as a signal would (a time limit, `quit` on a console).
    pub fn request(&self) {
        self.count.fetch_add(1, Ordering::SeqCst);
    }

    /// Stop requests so far: this process's own, or its supervisor's if that is more.
    pub fn count(&self) -> u32 {
        let own = self.count.load(Ordering::SeqCst);
        self.forwarded.map_or(own, |f| own.max(f.load(Ordering::SeqCst)))
    }

    /// The counter itself, for a library that polls it without knowing of signals (calib).
    pub fn counter(&self) -> Arc<AtomicU32> {
        self.count.clone()
    }

    /// This process's own requests only (what a supervisor passes on).
    pub fn own_count(&self) -> u32 {
        self.count.load(Ordering::SeqCst)
    }
}

/// Says how a process ended.
pub fn describe_exit(s: ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exited with status {c}"),
        (_, Some(9)) => "was killed (signal 9, SIGKILL)".into(),
        (_, Some(sig)) => {
            format!("ended by signal {sig}{}", if s.core_dumped() { " (core dumped)" } else { "" })
        }
        _ => "ended".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_request_asks_for_the_clean_stop_and_a_second_for_the_urgent_one() {
        let s = Stop::detached();
        assert!(!s.requested() && !s.urgent());
        s.request();
        assert!(s.requested() && !s.urgent());
        let t = s.clone();
        t.request();
        assert!(s.urgent());
    }

    #[test]
    fn a_signal_seen_by_both_processes_counts_once_and_one_seen_by_the_supervisor_alone_counts_too() {
        let forwarded: &'static AtomicU32 = Box::leak(Box::new(AtomicU32::new(0)));
        let s = Stop::detached().with_forwarded(forwarded);
        forwarded.store(1, Ordering::SeqCst); // the supervisor alone got SIGTERM
        assert!(s.requested() && !s.urgent());
        s.request(); // the same Ctrl-C reached this process too
        assert!(!s.urgent(), "one Ctrl-C is one request");
        forwarded.store(2, Ordering::SeqCst);
        assert!(s.urgent());
        assert_eq!(s.own_count(), 1);
    }
}
