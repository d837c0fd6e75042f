//! Real-time set-up of the calling thread, in one place: lock memory, prefault the stack,
//! timer slack to 1 ns (the default 50 us slack delays every absolute sleep by up to that much),
//! SCHED_FIFO at a chosen priority, optional CPU pinning. Each step that is not permitted is
//! reported with what to do about it, and the loop goes on without it: a developer's laptop must
//! still run, a rig PC must say plainly when it is not real-time.

use thread_priority::{
    set_thread_priority_and_policy, thread_native_id, RealtimeThreadSchedulePolicy, ThreadPriority,
    ThreadPriorityValue, ThreadSchedulePolicy,
};

/// What to ask for.
#[derive(Clone, Debug)]
pub struct RtOptions {
    /// SCHED_FIFO priority (1..99); None keeps the normal scheduler.
    pub fifo_priority: Option<u8>,
    pub lock_memory: bool,
    /// Bytes of stack to touch now so the tick never page-faults on it.
    pub prefault_stack_bytes: usize,
    pub cpu: Option<usize>,
}

impl Default for RtOptions {
    fn default() -> Self {
        RtOptions { fifo_priority: Some(80), lock_memory: true, prefault_stack_bytes: 256 * 1024, cpu: None }
    }
}

/// What was obtained.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RtReport {
    /// e.g. "SCHED_FIFO 80" or "SCHED_OTHER (normal)".
    pub policy: String,
    pub fifo: bool,
    pub memory_locked: bool,
    pub stack_prefaulted_bytes: usize,
    pub cpu: Option<usize>,
    /// Timer slack obtained for this thread.
    pub timer_slack_ns: Option<u64>,
    /// One line per thing that was asked for and not obtained, with the remedy.
    pub warnings: Vec<String>,
}

impl std::fmt::Display for RtReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}, memory {}, timer slack {}, stack prefaulted {} KiB, cpu {}",
            self.policy,
            if self.memory_locked { "locked" } else { "not locked" },
            self.timer_slack_ns.map_or("default".to_string(), |n| format!("{n} ns")),
            self.stack_prefaulted_bytes / 1024,
            self.cpu.map_or("any".to_string(), |c| c.to_string())
        )
    }
}

/// Sets up the calling thread for real time and reports what it obtained.
pub fn setup_current_thread(opts: &RtOptions) -> RtReport {
    let mut rep = RtReport { policy: "SCHED_OTHER (normal)".into(), ..Default::default() };
    if opts.lock_memory {
        // SAFETY: mlockall has no memory-safety preconditions.
        let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        if r == 0 {
            rep.memory_locked = true;
        } else {
            rep.warnings.push(format!(
                "mlockall failed ({}): pages may be swapped out under the loop; raise RLIMIT_MEMLOCK \
                 (ulimit -l unlimited, or memlock in /etc/security/limits.conf) or run as root",
                std::io::Error::last_os_error()
            ));
        }
    }
    // SAFETY: PR_SET_TIMERSLACK takes a plain integer; it affects only this thread.
    if unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) } == 0 {
        rep.timer_slack_ns = Some(1);
    } else {
        rep.warnings.push(format!("could not set timer slack: {}", std::io::Error::last_os_error()));
    }
    if opts.prefault_stack_bytes > 0 {
        prefault_stack(opts.prefault_stack_bytes);
        rep.stack_prefaulted_bytes = opts.prefault_stack_bytes;
    }
    if let Some(cpu) = opts.cpu {
        match check_cpu(cpu) {
            Err(why) => rep.warnings.push(why),
            Ok(()) => {
                // SAFETY: a zeroed cpu_set_t is valid; `check_cpu` keeps CPU_SET within it; pid 0 =
                // this thread.
                let ok = unsafe {
                    let mut set: libc::cpu_set_t = std::mem::zeroed();
                    libc::CPU_SET(cpu, &mut set);
                    libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
                };
                if ok {
                    rep.cpu = Some(cpu);
                } else {
                    rep.warnings
                        .push(format!("pinning to CPU {cpu} failed ({})", std::io::Error::last_os_error()));
                }
            }
        }
    }
    if let Some(prio) = opts.fifo_priority {
        let value = ThreadPriorityValue::try_from(prio.clamp(1, 99)).ok();
        let res = match value {
            Some(v) => set_thread_priority_and_policy(
                thread_native_id(),
                ThreadPriority::Crossplatform(v),
                ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
            )
            .map_err(|e| format!("{e:?}")),
            None => Err(format!("priority {prio} out of range")),
        };
        match res {
            Ok(()) => {
                rep.fifo = true;
                rep.policy = format!("SCHED_FIFO {}", prio.clamp(1, 99));
            }
            Err(e) => rep.warnings.push(format!(
                "SCHED_FIFO not permitted ({e}): the loop runs with the normal scheduler and will see \
                 millisecond wake-up jitter; run as root, or grant rtprio (e.g. `@realtime - rtprio 95` in \
                 /etc/security/limits.conf, or setcap cap_sys_nice+ep on the binary)"
            )),
        }
    }
    rep
}

/// Checks a CPU number before pinning to it: it must be one this process may run on (so also
/// below the affinity mask's size, which `CPU_SET` does not check). Says which CPUs exist.
pub fn check_cpu(cpu: usize) -> Result<(), String> {
    let setsize = 8 * std::mem::size_of::<libc::cpu_set_t>();
    // SAFETY: a zeroed cpu_set_t is valid and sched_getaffinity fills at most its size.
    let (ok, set) = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        let ok = libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0;
        (ok, set)
    };
    // SAFETY: CPU_ISSET reads within the set for indices below its size.
    let allowed: Vec<usize> =
        if ok { (0..setsize).filter(|&c| unsafe { libc::CPU_ISSET(c, &set) }).collect() } else { Vec::new() };
    if cpu < setsize && (allowed.is_empty() || allowed.contains(&cpu)) {
        return Ok(());
    }
    Err(format!(
        "CPU {cpu} does not exist or is not available to this process (available: {}): pick one of those \
         for --cpu, or leave it out",
        if allowed.is_empty() {
            "unknown".to_string()
        } else {
            allowed.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(", ")
        }
    ))
}

#[inline(never)]
fn prefault_stack(bytes: usize) {
    // Touch the stack below us now so that the first deep call in the tick does not fault.
    const CHUNK: usize = 4096;
    fn touch(left: usize) {
        let buf = [0u8; CHUNK];
        std::hint::black_box(&buf);
        if left > CHUNK {
            touch(left - CHUNK);
        }
    }
    touch(bytes);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_impossible_cpu_is_refused_with_the_available_ones_and_not_pinned() {
        let e = check_cpu(5000).unwrap_err();
        assert!(e.contains("CPU 5000") && e.contains("available: "), "{e}");
        assert!(check_cpu(usize::MAX).is_err());
        // The thread goes on unpinned, with the reason among the warnings.
        let rep = std::thread::spawn(|| {
            setup_current_thread(&RtOptions {
                fifo_priority: None,
                lock_memory: false,
                prefault_stack_bytes: 0,
                cpu: Some(5000),
            })
        })
        .join()
        .unwrap();
        assert_eq!(rep.cpu, None);
        assert!(rep.warnings.iter().any(|w| w.contains("CPU 5000")), "{:?}", rep.warnings);
    }

    #[test]
    fn setup_reports_what_it_obtained_without_failing() {
        // Whether FIFO is granted depends on the machine; either way the report must say which.
        let h = std::thread::spawn(|| {
            let rep = setup_current_thread(&RtOptions { lock_memory: false, ..Default::default() });
            (rep.fifo, rep.policy.clone(), rep.warnings.len())
        });
        let (fifo, policy, warnings) = h.join().unwrap();
        if fifo {
            assert_eq!(policy, "SCHED_FIFO 80");
        } else {
            assert!(policy.starts_with("SCHED_OTHER") && warnings > 0);
        }
    }
}
