//! Clocks for the loop: the real monotonic clock with absolute-deadline sleeps, and a virtual
//! clock for tests and faster-than-real-time runs.
//!
//! Times are integer nanoseconds since the clock's epoch (the loop's start), so a deadline
//! sequence never accumulates rounding error and virtual runs are bit-identical.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

pub trait Clock: Send {
    /// Nanoseconds since the clock's epoch.
    fn now_ns(&self) -> u64;
    /// Sleeps until the absolute time `deadline_ns` (returns at once if it has passed) and returns
    /// the time of waking. Must not allocate.
    fn sleep_until(&mut self, deadline_ns: u64) -> u64;
    /// True for the virtual clock: the loop may then run as fast as it can compute.
    fn is_virtual(&self) -> bool;
}

/// CLOCK_MONOTONIC with `clock_nanosleep(TIMER_ABSTIME)`: waking is tied to the deadline, not to
/// when the previous tick finished, so lateness does not accumulate. Optionally it sleeps only to
/// `spin_ns` before the deadline and busy-waits the rest: the kernel's wake-up latency is then
/// hidden, at the price of that much CPU per period.
#[derive(Clone, Copy, Debug)]
pub struct MonotonicClock {
    epoch_ns: u64,
    spin_ns: u64,
}

fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

impl MonotonicClock {
    pub fn new() -> MonotonicClock {
        MonotonicClock { epoch_ns: monotonic_ns(), spin_ns: 0 }
    }

    /// Sleep to `spin_ns` before each deadline, then spin (0: pure sleep).
    pub fn with_spin(mut self, spin_ns: u64) -> MonotonicClock {
        self.spin_ns = spin_ns;
        self
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        MonotonicClock::new()
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        monotonic_ns().saturating_sub(self.epoch_ns)
    }

    fn sleep_until(&mut self, deadline_ns: u64) -> u64 {
        let abs = self.epoch_ns + deadline_ns.saturating_sub(self.spin_ns);
        let ts = libc::timespec {
            tv_sec: (abs / 1_000_000_000) as libc::time_t,
            tv_nsec: (abs % 1_000_000_000) as _,
        };
        loop {
            // SAFETY: valid timespec; a null remainder is allowed with TIMER_ABSTIME.
            let r = unsafe {
                libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut())
            };
            if r != libc::EINTR {
                break;
            }
        }
        let mut now = self.now_ns();
        while now < deadline_ns {
            std::hint::spin_loop();
            now = self.now_ns();
        }
        now
    }

    fn is_virtual(&self) -> bool {
        false
    }
}

/// A clock that jumps to each deadline. Clones share the same time, so the scene side of a test
/// can read the time the loop is at.
#[derive(Clone, Default)]
pub struct VirtualClock {
    now: Arc<AtomicU64>,
    /// Added to the next wake-up only, to simulate a stall (a missed deadline).
    stall_ns: Arc<AtomicU64>,
}

impl VirtualClock {
    pub fn new() -> VirtualClock {
        VirtualClock::default()
    }
    /// Makes the next wake-up `ns` late.
    pub fn stall_next(&self, ns: u64) {
        self.stall_ns.store(ns, Ordering::Relaxed);
    }
    pub fn now_s(&self) -> f64 {
        self.now_ns() as f64 * 1e-9
    }
}

impl Clock for VirtualClock {
    fn now_ns(&self) -> u64 {
        self.now.load(Ordering::Relaxed)
    }

    fn sleep_until(&mut self, deadline_ns: u64) -> u64 {
        let stall = self.stall_ns.swap(0, Ordering::Relaxed);
        let t = self.now.load(Ordering::Relaxed).max(deadline_ns) + stall;
        self.now.store(t, Ordering::Relaxed);
        t
    }

    fn is_virtual(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_clock_jumps_to_deadlines_and_stalls_once() {
        let mut c = VirtualClock::new();
        let shared = c.clone();
        assert_eq!(c.sleep_until(1_000_000), 1_000_000);
        assert_eq!(shared.now_ns(), 1_000_000);
        c.stall_next(2_500_000);
        assert_eq!(c.sleep_until(2_000_000), 4_500_000);
        // A deadline already passed returns at once, at the current time.
        assert_eq!(c.sleep_until(3_000_000), 4_500_000);
    }

    #[test]
    fn monotonic_sleep_does_not_return_early() {
        let mut c = MonotonicClock::new();
        let d = c.now_ns() + 2_000_000;
        assert!(c.sleep_until(d) >= d);
        let mut c = MonotonicClock::new().with_spin(500_000);
        let d = c.now_ns() + 2_000_000;
        assert!(c.sleep_until(d) >= d, "spinning does not return early either");
    }
}
