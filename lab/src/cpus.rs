//! Which CPUs a benchmark's threads and browsers run on, so that a bench can keep the world thread
//! on a core of its own as a rig does (its browser on the display machine or on other cores), and
//! what a thread's time on its CPU was (to tell a step that was slow from one that was preempted).
//!
//! Must never: pin silently (the placement is printed with the figures) or refuse a machine with
//! one CPU (there nothing is pinned).

use std::fmt;
use std::str::FromStr;

/// A CPU option as given: `auto` (the default), `any` (no pinning) or CPU numbers.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum CpuChoice {
    #[default]
    Auto,
    Any,
    /// CPU numbers, ascending, without repeats.
    Cpus(Vec<usize>),
}

impl FromStr for CpuChoice {
    type Err = String;

    /// `auto`, `any`, or a list of CPU numbers and ranges: `1`, `0,2`, `0-3,6`.
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        match s {
            "auto" => return Ok(CpuChoice::Auto),
            "any" => return Ok(CpuChoice::Any),
            _ => {}
        }
        let bad = || format!("'{s}': give CPU numbers and ranges (e.g. 1 or 0,2-3), 'any' or 'auto'");
        let mut cpus = Vec::new();
        for part in s.split(',') {
            let (a, b) = match part.split_once('-') {
                Some((a, b)) => (a, b),
                None => (part, part),
            };
            let (a, b): (usize, usize) =
                (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
            if a > b || b >= CPU_SETSIZE {
                return Err(bad());
            }
            cpus.extend(a..=b);
        }
        cpus.sort_unstable();
        cpus.dedup();
        Ok(CpuChoice::Cpus(cpus))
    }
}

/// CPUs a `cpu_set_t` can name.
const CPU_SETSIZE: usize = 8 * std::mem::size_of::<libc::cpu_set_t>();

/// Where a bench runs its threads: the world thread on `world`, everything else it starts (its
/// helper threads, the browsers and their drivers) on `others`. None: wherever the kernel puts it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Placement {
    pub world: Option<usize>,
    pub others: Option<Vec<usize>>,
}

impl Placement {
    /// The placement `world` and `others` ask for on a process allowed the CPUs `allowed`. `auto`:
    /// with two CPUs or more, the world on the last one and the rest on the others; with one,
    /// nothing pinned. Refused, naming the option: a CPU the process may not use, or the world's
    /// CPU among the others' (`any` lets them share it).
    pub fn resolve(world: &CpuChoice, others: &CpuChoice, allowed: &[usize]) -> Result<Placement, String> {
        let check = |name: &str, cpus: &[usize]| match cpus.iter().find(|c| !allowed.contains(c)) {
            Some(c) => {
                Err(format!("{name}: CPU {c} is not one this process may use (it may use {})", list(allowed)))
            }
            None => Ok(()),
        };
        let world = match world {
            CpuChoice::Any => None,
            CpuChoice::Auto => (allowed.len() >= 2).then(|| allowed[allowed.len() - 1]),
            CpuChoice::Cpus(c) if c.len() == 1 => {
                check("--world-cpu", c)?;
                Some(c[0])
            }
            CpuChoice::Cpus(_) => return Err("--world-cpu: give one CPU (or 'any' or 'auto')".into()),
        };
        let others = match others {
            CpuChoice::Any => None,
            CpuChoice::Auto => world
                .map(|w| allowed.iter().copied().filter(|&c| c != w).collect::<Vec<_>>())
                .filter(|rest| !rest.is_empty()),
            CpuChoice::Cpus(c) => {
                check("--browser-cpus", c)?;
                if let Some(w) = world.filter(|w| c.contains(w)) {
                    return Err(format!(
                        "--browser-cpus {}: CPU {w} is the world's (--world-cpu): leave it out, or give 'any'",
                        list(c)
                    ));
                }
                Some(c.clone())
            }
        };
        Ok(Placement { world, others })
    }
}

impl fmt::Display for Placement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.world {
            Some(w) => write!(f, "world thread on CPU {w}")?,
            None => write!(f, "world thread on any CPU")?,
        }
        match &self.others {
            Some(o) => write!(f, ", browsers and the bench's other threads on CPU {}", list(o)),
            None => write!(f, ", browsers and the bench's other threads on any CPU"),
        }
    }
}

/// `0,2,3`.
fn list(cpus: &[usize]) -> String {
    cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",")
}

/// The CPUs this thread may run on (empty when the kernel does not say).
pub fn allowed_cpus() -> Vec<usize> {
    // SAFETY: a zeroed cpu_set_t is valid and sched_getaffinity fills at most its size.
    let (ok, set) = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        let ok = libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0;
        (ok, set)
    };
    if !ok {
        return Vec::new();
    }
    // SAFETY: CPU_ISSET reads within the set for indices below its size.
    (0..CPU_SETSIZE).filter(|&c| unsafe { libc::CPU_ISSET(c, &set) }).collect()
}

/// Restricts the calling thread (and what it starts afterwards: threads and processes inherit it)
/// to `cpus`; an empty list leaves it as it is. Allocates nothing and only makes one system call,
/// so a child may call it between fork and exec.
pub fn pin_current_thread(cpus: &[usize]) -> std::io::Result<()> {
    if cpus.is_empty() {
        return Ok(());
    }
    // SAFETY: a zeroed cpu_set_t is valid; CPU_SET is given indices below its size only; pid 0 is
    // the calling thread.
    let ok = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &c in cpus.iter().filter(|&&c| c < CPU_SETSIZE) {
            libc::CPU_SET(c, &mut set);
        }
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
    };
    if ok {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Has `cmd`'s process start on `cpus` (empty: as its parent).
pub fn run_on(cmd: &mut std::process::Command, cpus: &[usize]) {
    use std::os::unix::process::CommandExt;
    if cpus.is_empty() {
        return;
    }
    let cpus = cpus.to_vec();
    // SAFETY: the closure makes one system call and allocates nothing (fine between fork and exec).
    unsafe {
        cmd.pre_exec(move || pin_current_thread(&cpus));
    }
}

/// The calling thread's CPU time so far (ns): the time it ran, not the time it waited for a CPU.
pub fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Times the calling thread was switched out while it could have run (preempted) so far.
pub fn thread_involuntary_switches() -> u64 {
    // SAFETY: a zeroed rusage is valid and getrusage fills it.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above; RUSAGE_THREAD is the calling thread.
    unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut ru) };
    ru.ru_nivcsw as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_parse_numbers_ranges_any_and_auto_and_refuse_the_rest() {
        assert_eq!("auto".parse::<CpuChoice>(), Ok(CpuChoice::Auto));
        assert_eq!(" any ".parse::<CpuChoice>(), Ok(CpuChoice::Any));
        assert_eq!("1".parse::<CpuChoice>(), Ok(CpuChoice::Cpus(vec![1])));
        assert_eq!("3,0-2,1".parse::<CpuChoice>(), Ok(CpuChoice::Cpus(vec![0, 1, 2, 3])));
        for bad in ["", "x", "2-1", "-1", "1,", "0-", "99999", "1.5"] {
            let e = bad.parse::<CpuChoice>().unwrap_err();
            assert!(e.contains("CPU numbers"), "{bad}: {e}");
        }
    }

    #[test]
    fn auto_puts_the_world_on_the_last_cpu_and_the_rest_elsewhere_and_pins_nothing_on_one_cpu() {
        let auto = Placement::resolve(&CpuChoice::Auto, &CpuChoice::Auto, &[0, 1]).unwrap();
        assert_eq!(auto, Placement { world: Some(1), others: Some(vec![0]) });
        assert_eq!(
            auto.to_string(),
            "world thread on CPU 1, browsers and the bench's other threads on CPU 0"
        );
        let four = Placement::resolve(&CpuChoice::Auto, &CpuChoice::Auto, &[0, 2, 3, 5]).unwrap();
        assert_eq!(four, Placement { world: Some(5), others: Some(vec![0, 2, 3]) });
        let one = Placement::resolve(&CpuChoice::Auto, &CpuChoice::Auto, &[3]).unwrap();
        assert_eq!(one, Placement::default());
        assert_eq!(
            one.to_string(),
            "world thread on any CPU, browsers and the bench's other threads on any CPU"
        );
        // `any` pins nothing; the world alone pinned leaves the rest free to share its CPU.
        assert_eq!(
            Placement::resolve(&CpuChoice::Any, &CpuChoice::Auto, &[0, 1]).unwrap(),
            Placement::default()
        );
        let world_only = Placement::resolve(&CpuChoice::Cpus(vec![0]), &CpuChoice::Any, &[0, 1]).unwrap();
        assert_eq!(world_only, Placement { world: Some(0), others: None });
        let chosen = Placement::resolve(&CpuChoice::Cpus(vec![0]), &CpuChoice::Auto, &[0, 1]).unwrap();
        assert_eq!(chosen, Placement { world: Some(0), others: Some(vec![1]) });
    }

    #[test]
    fn a_placement_that_cannot_be_kept_is_refused_naming_the_option() {
        let e = Placement::resolve(&CpuChoice::Cpus(vec![7]), &CpuChoice::Auto, &[0, 1]).unwrap_err();
        assert!(e.contains("--world-cpu") && e.contains("CPU 7") && e.contains("0,1"), "{e}");
        let e = Placement::resolve(&CpuChoice::Cpus(vec![0, 1]), &CpuChoice::Auto, &[0, 1]).unwrap_err();
        assert!(e.contains("--world-cpu: give one CPU"), "{e}");
        let e = Placement::resolve(&CpuChoice::Auto, &CpuChoice::Cpus(vec![4]), &[0, 1]).unwrap_err();
        assert!(e.contains("--browser-cpus") && e.contains("CPU 4"), "{e}");
        let e = Placement::resolve(&CpuChoice::Auto, &CpuChoice::Cpus(vec![0, 1]), &[0, 1]).unwrap_err();
        assert!(e.contains("--browser-cpus 0,1") && e.contains("CPU 1 is the world's"), "{e}");
    }

    /// A process started with `run_on` runs on those CPUs only (the kernel says so), and a thread
    /// pinned by `pin_current_thread` too; neither changes the thread that started it.
    #[test]
    fn a_child_started_on_cpus_runs_there_and_a_pinned_thread_too() {
        let allowed = allowed_cpus();
        let first = *allowed.first().expect("this process may run on some CPU");
        let mut cmd = std::process::Command::new("sh");
        cmd.args(["-c", "grep Cpus_allowed_list /proc/self/status"]);
        run_on(&mut cmd, &[first]);
        let out = String::from_utf8(cmd.output().expect("running sh").stdout).unwrap();
        assert_eq!(out.split_whitespace().last(), Some(first.to_string().as_str()), "{out}");
        assert_eq!(allowed_cpus(), allowed, "the parent's CPUs are unchanged");
        let on = std::thread::spawn(move || {
            pin_current_thread(&[first]).unwrap();
            allowed_cpus()
        })
        .join()
        .unwrap();
        assert_eq!(on, vec![first]);
        assert_eq!(allowed_cpus(), allowed);
    }

    /// A thread's CPU time does not grow while it sleeps (a step's wall time beyond its CPU time is
    /// time off its CPU), and a sleep is a voluntary switch, not a preemption.
    #[test]
    fn a_threads_cpu_time_does_not_count_its_sleeping() {
        let (c0, n0) = (thread_cpu_ns(), thread_involuntary_switches());
        std::thread::sleep(std::time::Duration::from_millis(50));
        let slept = thread_cpu_ns() - c0;
        assert!(slept < 10_000_000, "{slept} ns of CPU over a 50 ms sleep");
        assert!(thread_involuntary_switches() >= n0);
    }
}
