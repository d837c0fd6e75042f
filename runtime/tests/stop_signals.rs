//! The stop signals as the kernel delivers them, in a process of their own (the handler is
//! process-wide): a supervisor's death is one stop however many parent-death signals come, and a
//! person's signal after it is the second, urgent one.
//!
//! The supervisor's parent-death signal is a SIGTERM whose sender is the supervisor's pid. Here
//! this test process plays the supervisor of itself: it declares its own pid the supervisor's, so
//! the SIGTERMs it sends itself arrive exactly as a dying supervisor's do; `kill` run as another
//! process is the person.

use std::process::Command;
use std::time::{Duration, Instant};

use spidar_runtime::signals::{self, Stop};

/// Waits (up to a generous bound on a loaded machine) until `stop` counts `n`.
fn wait_for(stop: &Stop, n: u32) -> u32 {
    let until = Instant::now() + Duration::from_secs(30);
    while stop.count() < n && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(5));
    }
    // A signal more than expected would show up here too.
    std::thread::sleep(Duration::from_millis(50));
    stop.count()
}

#[test]
fn the_supervisors_death_signalled_three_times_is_one_stop_and_a_persons_signal_after_it_the_second() {
    let stop = Stop::install().unwrap();
    let me = std::process::id() as i32;
    signals::watched_by(me);
    assert_eq!(stop.count(), 0);
    // The supervisor dies: its parent-death signal, once per thread the orphan passed through.
    for k in 1..=3 {
        // SAFETY: a signal to this process, whose handler is installed.
        assert_eq!(unsafe { libc::kill(me, libc::SIGTERM) }, 0);
        assert_eq!(wait_for(&stop, 1), 1, "after parent-death signal {k}");
        assert!(stop.requested() && !stop.urgent(), "one clean stop, never the urgent one");
    }
    // Then a person sends SIGTERM (from another process): the second stop, at once.
    let ok = Command::new("kill").args(["-TERM", &me.to_string()]).status().unwrap().success();
    assert!(ok);
    assert_eq!(wait_for(&stop, 2), 2);
    assert!(stop.urgent());
    // A Stop made later sees the same count (the handler is process-wide).
    assert_eq!(Stop::install().unwrap().count(), 2);
}
