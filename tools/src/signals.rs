//! The signals that end a session: SIGINT (Ctrl-C), SIGTERM (systemd stop, `kill`) and SIGHUP
//! (a closing terminal) all ask for the same clean stop. The first one asks for the ramp-out
//! (force to zero, strings at minimum tension, device off, summary); a second one asks to stop at
//! once with the outputs zeroed. Every command that holds a device polls a [`Stop`].
//!
//! The handler is process-wide (installed once; later calls share it) and only counts: the work
//! is done by whoever polls, so nothing unsafe runs inside a signal handler.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::Context;

static COUNT: OnceLock<Arc<AtomicU32>> = OnceLock::new();

/// How many stop signals this process received, shared with the handler.
#[derive(Clone, Debug)]
pub struct Stop {
    count: Arc<AtomicU32>,
}

impl Stop {
    /// Installs the handler for SIGINT, SIGTERM and SIGHUP (once per process) and returns the
    /// shared counter.
    pub fn install() -> anyhow::Result<Stop> {
        if let Some(c) = COUNT.get() {
            return Ok(Stop { count: c.clone() });
        }
        let count = Arc::new(AtomicU32::new(0));
        let c = count.clone();
        ctrlc::set_handler(move || {
            c.fetch_add(1, Ordering::SeqCst);
        })
        .context("installing the handler for SIGINT, SIGTERM and SIGHUP")?;
        let _ = COUNT.set(count.clone());
        Ok(Stop { count })
    }

    /// A counter no signal reaches (tests, library callers that stop by other means).
    pub fn detached() -> Stop {
        Stop { count: Arc::new(AtomicU32::new(0)) }
    }

    /// A clean stop was asked for (one signal or more, or [`Stop::request`]).
    pub fn requested(&self) -> bool {
        self.count.load(Ordering::SeqCst) >= 1
    }

    /// A second signal came: stop at once, outputs zeroed, no ramp.
    pub fn urgent(&self) -> bool {
        self.count.load(Ordering::SeqCst) >= 2
    }

    /// Asks for a stop as a signal would (a time limit, `quit` on a console).
    pub fn request(&self) {
        self.count.fetch_add(1, Ordering::SeqCst);
    }

    pub fn count(&self) -> u32 {
        self.count.load(Ordering::SeqCst)
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
}
