//! The signals that end a session: SIGINT (Ctrl-C), SIGTERM (systemd stop, `kill`) and SIGHUP
//! (a closing terminal) all ask for the same clean stop. The first one asks for the ramp-out
//! (force to zero, strings at minimum tension, device off, summary); a second one asks to stop at
//! once with the outputs zeroed. Every command that holds a device polls a [`Stop`].
//!
//! The handler is process-wide (installed once; later calls share it) and only counts, with
//! atomics: the work is done by whoever polls, so nothing unsafe runs inside a signal handler.
//!
//! A rig process under a supervisor (`spidar run` on real boards, see `supervisor`) also counts
//! the signals its supervisor received ([`Stop::with_forwarded`]): the larger of the two counts
//! is taken, so a Ctrl-C that reaches both processes counts once, and a `kill -TERM` sent to the
//! supervisor alone still stops the rig.
//!
//! Its supervisor's death is one stop, however often the kernel says so. The rig's parent-death
//! signal (SIGTERM, `PR_SET_PDEATHSIG`) is tied to the thread that forked it, and the kernel sends
//! it again every time the orphan is handed to another thread of the dying supervisor, then to
//! its new reaper: two or three SIGTERMs from one kill -9, which, counted as a second signal,
//! used to skip the ramp-out. So the handler reads who sent each signal: one from the
//! supervisor's pid (which never signals its rig otherwise: it talks through the shared page, and
//! kills with SIGKILL) makes the count at least one, the clean stop, and never more; a person's
//! signal after it is a second one. `ctrlc` cannot tell a signal's sender; hence the small
//! `sigaction` handler here.

use std::os::unix::process::ExitStatusExt;
use std::process::ExitStatus;
use std::sync::atomic::{AtomicI32, AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};

/// The stop signals this process received (the handler's count).
static SIGNALS: AtomicU32 = AtomicU32::new(0);
/// The supervisor's pid (0: this process has none).
static SUPERVISOR: AtomicI32 = AtomicI32::new(0);
/// The handler's installation, and the requests every installed [`Stop`] shares.
static INSTALLED: OnceLock<Result<Arc<AtomicU32>, String>> = OnceLock::new();

/// The signals that ask for the stop.
const STOP_SIGNALS: [libc::c_int; 3] = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP];

/// The handler: counts; a signal from the supervisor's pid (its death) makes the count at least
/// one. Only atomics: async-signal-safe.
extern "C" fn on_stop_signal(_: libc::c_int, info: *mut libc::siginfo_t, _: *mut libc::c_void) {
    // SAFETY: with SA_SIGINFO the kernel passes a valid siginfo; si_pid is set for signals sent
    // by a process (SI_USER, SI_QUEUE) and 0 for the terminal's.
    let from = if info.is_null() { 0 } else { unsafe { (*info).si_pid() } };
    let supervisor = SUPERVISOR.load(Ordering::SeqCst);
    if supervisor > 0 && from == supervisor {
        SIGNALS.fetch_max(1, Ordering::SeqCst);
    } else {
        SIGNALS.fetch_add(1, Ordering::SeqCst);
    }
}

fn install_handler() -> Result<Arc<AtomicU32>, String> {
    for sig in STOP_SIGNALS {
        // SAFETY: a zeroed sigaction with a valid handler, an empty mask and plain flags; the
        // handler only touches atomics.
        let rc = unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_stop_signal as *const () as libc::sighandler_t;
            sa.sa_flags = libc::SA_SIGINFO | libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut())
        };
        if rc != 0 {
            return Err(format!("signal {sig}: {}", std::io::Error::last_os_error()));
        }
    }
    Ok(Arc::new(AtomicU32::new(0)))
}

/// This process is a rig process watched by the supervisor `pid` (its parent): a stop signal
/// from that pid is the supervisor's death, counted once (see the module doc). Call before any
/// thread starts.
pub fn watched_by(pid: i32) {
    SUPERVISOR.store(pid, Ordering::SeqCst);
}

/// How many stop signals this process received, shared with the handler.
#[derive(Clone, Debug)]
pub struct Stop {
    /// Requests by [`Stop::request`] (shared by every installed `Stop`).
    count: Arc<AtomicU32>,
    /// Also counts the process's stop signals (an installed `Stop`).
    signals: bool,
    /// The signals a supervising process received and passed on.
    forwarded: Option<&'static AtomicU32>,
}

impl Stop {
    /// Installs the handler for SIGINT, SIGTERM and SIGHUP (once per process) and returns a
    /// counter that sees every stop signal.
    pub fn install() -> anyhow::Result<Stop> {
        let count = INSTALLED
            .get_or_init(install_handler)
            .clone()
            .map_err(|e| anyhow::anyhow!("installing the handler for SIGINT, SIGTERM and SIGHUP: {e}"))?;
        Ok(Stop { count, signals: true, forwarded: None })
    }

    /// A counter no signal reaches (tests, library callers that stop by other means).
    pub fn detached() -> Stop {
        Stop { count: Arc::new(AtomicU32::new(0)), signals: false, forwarded: None }
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
        let own = self.own_count();
        self.forwarded.map_or(own, |f| own.max(f.load(Ordering::SeqCst)))
    }

    /// This process's own requests only (what a supervisor passes on).
    pub fn own_count(&self) -> u32 {
        let signals = if self.signals { SIGNALS.load(Ordering::SeqCst) } else { 0 };
        self.count.load(Ordering::SeqCst) + signals
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
