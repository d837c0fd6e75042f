//! The supervisor: `spidar run` on real boards is two processes. The one started from the shell
//! is a small, non-real-time supervisor; it starts the rig (the real-time loop, the world, the
//! status line: everything `spidar run` does) as its child from this same executable, and
//! watches it. If the rig process dies without its clean stop (kill -9, an abort, a panic) or
//! stops ticking (a hung loop, SIGSTOP), the supervisor kills it, opens the boards itself and
//! writes zero to every channel, says so and exits non-zero.
//!
//! Why it exists: no board stops its motors by itself. The UART boards' firmware holds the last
//! command until the next one (no watchdog), and nothing is known of the USB boards, so a rig
//! process that dies while the strings pull on a person's hands leaves them pulling until the
//! power is cut. Only another process can make that way out safe. (A host that loses power, or a
//! supervisor killed together with its rig, is beyond any software: the rig needs its hardware
//! emergency stop.)
//!
//! How they talk: one page of shared memory (`memfd_create`, passed to the child by descriptor
//! number in `SPIDAR_SUPERVISOR_FD`), holding
//! - the loop's [`Lifeline`]: the heartbeat the tick writes with one atomic store (no system call,
//!   no lock, no allocation: the tick stays real-time), and the halt flag;
//! - the stop signals the supervisor received, which the rig counts as its own (the larger count
//!   wins, so a Ctrl-C that reaches both processes counts once);
//! - whether the rig is driving the boards (set once its loop has configured them);
//! - the UART boards the rig process found at its open, so the takeover writes zero at once
//!   instead of enumerating them again (an enumeration waits out every absent board id).
//!
//! The supervisor polls the page every [`POLL`] (5 ms). No new beat for [`STALL`] (60 ms) while
//! the loop runs, or an exit while driving without the loop's `DONE`, is a takeover: zero is on
//! the boards within 100 ms of the loop's last tick. The supervisor runs one SCHED_FIFO priority
//! above the loop (see [`supervise`]). The rig child dies with the supervisor
//! (`PR_SET_PDEATHSIG`: SIGTERM, its clean stop; the kernel may send it more than once as the
//! supervisor's threads die, and the rig counts it once: `signals`).
//!
//! What the safe output is: zero on every channel. Nothing regulates the strings any more, so
//! they go slack (no minimum tension: keeping that would need a running loop).

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::process::{Child, Command, ExitStatus};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use spidar_device::uart::protocol::{BoardInfo, ReplyLayout, MAX_BOARDS};
use spidar_device::{Device, Input, Output};
use spidar_rt::rt_thread::{self, RtOptions};
use spidar_rt::Lifeline;

use crate::signals::describe_exit;
use crate::signals::Stop;

/// The environment variable that gives the rig process the shared page's descriptor.
pub const ENV_FD: &str = "SPIDAR_SUPERVISOR_FD";
/// No beat for this long while the loop runs: the rig process is hung (or stopped). With
/// [`POLL`] and the takeover's few milliseconds, zero is on the boards within 100 ms of the last
/// tick. A loop at its SCHED_FIFO priority that misses 60 ticks in a row is broken, not slow.
pub const STALL: Duration = Duration::from_millis(60);
/// How often the supervisor looks.
pub const POLL: Duration = Duration::from_millis(5);
/// After the second stop signal the rig process has this long to end before it is killed.
pub const URGENT_GRACE: Duration = Duration::from_secs(2);
/// Exit status of a supervisor that took the boards over and wrote zero to them.
pub const EXIT_TOOK_OVER: u8 = 3;
/// Exit status of a supervisor that had to take the boards over and could not write zero.
pub const EXIT_TAKEOVER_FAILED: u8 = 4;

/// The page shared by the supervisor and the rig process.
#[repr(C)]
#[derive(Debug, Default)]
pub struct Shared {
    /// The loop's heartbeat and halt flag.
    pub lifeline: Lifeline,
    /// Stop signals the supervisor received (the rig takes the larger of this and its own count).
    pub stops: AtomicU32,
    /// Non-zero once the rig's loop has configured the boards: from then on an end without the
    /// loop's `DONE` is a takeover.
    pub driving: AtomicU32,
    /// How many UART boards the rig process found at its open (0: none published).
    uart_count: AtomicU32,
    /// Each of those boards, packed by [`pack_board`]: what the takeover needs to write zero
    /// without enumerating them again.
    uart_boards: [AtomicU64; MAX_BOARDS],
}

impl Shared {
    /// The rig says it drives the boards from now on.
    pub fn set_driving(&self) {
        self.driving.store(1, Ordering::SeqCst);
    }

    fn driving(&self) -> bool {
        self.driving.load(Ordering::SeqCst) != 0
    }

    /// The rig process publishes the UART boards it found (at its open, before it drives them),
    /// so a takeover can write zero at once instead of enumerating: an enumeration waits out
    /// every absent board id, far longer than the takeover may take.
    pub fn publish_uart(&self, boards: &[BoardInfo], layouts: &[ReplyLayout]) {
        let n = boards.len().min(MAX_BOARDS).min(layouts.len());
        for (slot, (b, l)) in self.uart_boards.iter().zip(boards.iter().zip(layouts)).take(n) {
            slot.store(pack_board(b, *l), Ordering::Relaxed);
        }
        self.uart_count.store(n as u32, Ordering::Release);
    }

    /// The UART boards the rig process published, if any and if every entry is a board spidar
    /// knows (the page of a dying process is not trusted further: anything else means a full
    /// open).
    pub fn known_uart(&self) -> Option<(Vec<BoardInfo>, Vec<ReplyLayout>)> {
        let n = self.uart_count.load(Ordering::Acquire) as usize;
        if n == 0 || n > MAX_BOARDS {
            return None;
        }
        let (mut boards, mut layouts) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for slot in &self.uart_boards[..n] {
            let (b, l) = unpack_board(slot.load(Ordering::Relaxed))?;
            boards.push(b);
            layouts.push(l);
        }
        // The enumeration found them in id order, each once.
        if boards.windows(2).any(|w| w[0].id >= w[1].id) {
            return None;
        }
        Some((boards, layouts))
    }
}

/// One UART board in a word: its board-info reply's fields, and its reply layout.
fn pack_board(b: &BoardInfo, l: ReplyLayout) -> u64 {
    let layout = ReplyLayout::ALL.iter().position(|x| *x == l).unwrap_or(0) as u8;
    u64::from_le_bytes([b.id, b.model, b.n_target, b.n_motor, b.n_current, b.n_force, b.n_touch, layout])
}

/// The board [`pack_board`] packed, if it is a board the driver accepts (the protocol's presence
/// rule) at a valid id.
fn unpack_board(w: u64) -> Option<(BoardInfo, ReplyLayout)> {
    let [id, model, n_target, n_motor, n_current, n_force, n_touch, layout] = w.to_le_bytes();
    let b = BoardInfo { id, model, n_target, n_motor, n_current, n_force, n_touch };
    if usize::from(id) >= MAX_BOARDS || !b.is_present() {
        return None;
    }
    Some((b, *ReplyLayout::ALL.get(usize::from(layout))?))
}

/// The shared page and its descriptor. The mapping is never unmapped (it lives as long as the
/// process), which is what makes the `&'static` references to it sound.
pub struct Page {
    shared: &'static Shared,
    fd: OwnedFd,
}

impl Page {
    /// A new zeroed page (the supervisor's side).
    pub fn create() -> anyhow::Result<Page> {
        // SAFETY: a NUL-terminated name and plain flags; the result is checked.
        let raw = unsafe { libc::memfd_create(c"spidar-supervisor".as_ptr(), libc::MFD_CLOEXEC) };
        if raw < 0 {
            return Err(std::io::Error::last_os_error())
                .context("creating the supervisor's shared page (memfd_create)");
        }
        // SAFETY: a descriptor we just created and nobody else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        // SAFETY: ftruncate on our own descriptor.
        if unsafe { libc::ftruncate(fd.as_raw_fd(), page_len() as libc::off_t) } != 0 {
            return Err(std::io::Error::last_os_error()).context("sizing the supervisor's shared page");
        }
        Page::map(fd)
    }

    /// Maps the page behind `fd` (a memfd of at least one page).
    fn map(fd: OwnedFd) -> anyhow::Result<Page> {
        // SAFETY: an fstat of a valid descriptor into a zeroed struct.
        let mut st: libc::stat = unsafe { std::mem::zeroed() };
        if unsafe { libc::fstat(fd.as_raw_fd(), &mut st) } != 0 {
            return Err(std::io::Error::last_os_error()).context("checking the supervisor's shared page");
        }
        if (st.st_mode & libc::S_IFMT) != libc::S_IFREG
            || (st.st_size as usize) < std::mem::size_of::<Shared>()
        {
            bail!("descriptor {} is not the supervisor's shared page", fd.as_raw_fd());
        }
        // SAFETY: a fresh shared mapping of a file at least `page_len()` long; checked for failure.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                page_len(),
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                fd.as_raw_fd(),
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return Err(std::io::Error::last_os_error()).context("mapping the supervisor's shared page");
        }
        // SAFETY: the mapping is page-aligned, at least as large as `Shared`, zero-filled or
        // written only through these atomics (all-zero bytes are valid atomics), shared only with
        // the other process through the same atomics, and never unmapped: it is valid for 'static.
        let shared: &'static Shared = unsafe { &*(p as *const Shared) };
        Ok(Page { shared, fd })
    }

    pub fn shared(&self) -> &'static Shared {
        self.shared
    }

    fn raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

fn page_len() -> usize {
    std::mem::size_of::<Shared>().next_multiple_of(4096)
}

static ATTACHED: OnceLock<Option<Page>> = OnceLock::new();

/// The rig process's side: the page its supervisor gave it, if any. Call early in `main`, before
/// any thread starts (it removes the environment variable, so the world process it starts does
/// not see it, and closes the descriptor on exec).
pub fn attach_from_env() -> anyhow::Result<Option<&'static Shared>> {
    if let Some(p) = ATTACHED.get() {
        return Ok(p.as_ref().map(|p| p.shared));
    }
    let Some(v) = std::env::var_os(ENV_FD) else {
        let _ = ATTACHED.set(None);
        return Ok(None);
    };
    std::env::remove_var(ENV_FD);
    let raw: RawFd = v.to_str().and_then(|s| s.parse().ok()).filter(|fd| *fd > 2).with_context(|| {
        format!("{ENV_FD}={v:?} is not a descriptor number (it is set by spidar's supervisor)")
    })?;
    // SAFETY: F_GETFD only asks whether the descriptor is open.
    if unsafe { libc::fcntl(raw, libc::F_GETFD) } < 0 {
        bail!("{ENV_FD}={raw}: no such descriptor (it is set by spidar's supervisor, not by hand)");
    }
    // SAFETY: the supervisor created this descriptor for this process and passed it on alone;
    // this is the one place that claims it (guarded by ATTACHED).
    let fd = unsafe { OwnedFd::from_raw_fd(raw) };
    // SAFETY: setting close-on-exec on our own descriptor.
    unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) };
    let page = Page::map(fd)?;
    let shared = page.shared;
    let _ = ATTACHED.set(Some(page));
    // The parent is the supervisor (`spawn_rig` checked it before exec): its parent-death signal
    // is one stop, however often the kernel sends it (see `signals`).
    // SAFETY: getppid has no preconditions.
    crate::signals::watched_by(unsafe { libc::getppid() });
    Ok(Some(shared))
}

/// The supervisor's page, once [`attach_from_env`] found one.
pub fn attached() -> Option<&'static Shared> {
    ATTACHED.get().and_then(|p| p.as_ref().map(|p| p.shared))
}

/// Starts `program args` as the rig process with the page: it keeps the page's descriptor
/// across exec and gets SIGTERM (its clean stop) if this process dies.
pub fn spawn_rig(
    page: &Page,
    program: &std::path::Path,
    args: &[std::ffi::OsString],
) -> anyhow::Result<Child> {
    let fd = page.raw_fd();
    let parent = std::process::id();
    let mut cmd = Command::new(program);
    cmd.args(args).env(ENV_FD, fd.to_string());
    // SAFETY: only async-signal-safe calls (fcntl, prctl, getppid) between fork and exec, no
    // allocation.
    unsafe {
        cmd.pre_exec(move || {
            if libc::fcntl(fd, libc::F_SETFD, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() as u32 != parent {
                return Err(std::io::Error::from_raw_os_error(libc::ESRCH)); // the supervisor already ended
            }
            Ok(())
        });
    }
    cmd.spawn().with_context(|| format!("starting the rig process {}", program.display()))
}

/// How a watched rig process ended.
#[derive(Debug)]
pub enum Ended {
    /// On its own, with the boards switched off by its loop (or never driven).
    Clean(ExitStatus),
    /// On its own (killed, aborted, failed) while its loop still drove the boards.
    Died(ExitStatus),
    /// Its loop stopped ticking for `stalled` (hung, or the process was stopped): killed.
    Hung { stalled: Duration },
    /// It was still there `URGENT_GRACE` after the second stop signal: killed.
    Unresponsive,
}

impl Ended {
    /// The boards may still hold a command: the supervisor must write zero.
    pub fn needs_takeover(&self) -> bool {
        !matches!(self, Ended::Clean(_))
    }

    /// What happened, for a person.
    pub fn describe(&self) -> String {
        match self {
            Ended::Clean(s) => format!("the rig process {}", describe_exit(*s)),
            Ended::Died(s) => format!("the rig process {} while its loop drove the boards", describe_exit(*s)),
            Ended::Hung { stalled } => format!(
                "the rig process's loop stopped ticking (no heartbeat for {} ms: hung, or the process was stopped); killed it",
                stalled.as_millis()
            ),
            Ended::Unresponsive => format!(
                "the rig process did not end within {} s of the second stop signal; killed it",
                URGENT_GRACE.as_secs()
            ),
        }
    }
}

/// Watches the rig process `child` through `shared` until it ends, passing on the stop signals
/// `stop` counts; kills it when its loop stops ticking for `stall`, or when it outlives
/// `URGENT_GRACE` after a second signal.
pub fn watch(child: &mut Child, shared: &Shared, stop: &Stop, stall: Duration) -> anyhow::Result<Ended> {
    let mut last = 0u64;
    let mut last_change = Instant::now();
    let mut urgent_since: Option<Instant> = None;
    loop {
        let n = stop.own_count();
        if n > shared.stops.load(Ordering::SeqCst) {
            shared.stops.store(n, Ordering::SeqCst);
        }
        if n >= 2 {
            // Also straight to the loop, in case the rig's control thread is the one that hangs.
            shared.lifeline.halt();
            urgent_since.get_or_insert_with(Instant::now);
        }
        if let Some(status) = child.try_wait().context("waiting for the rig process")? {
            let clean = !shared.driving() || shared.lifeline.done();
            return Ok(if clean { Ended::Clean(status) } else { Ended::Died(status) });
        }
        let now = Instant::now();
        let beat = shared.lifeline.beat.load(Ordering::Acquire);
        if beat == 0 || beat == Lifeline::DONE || beat != last {
            // Not running yet, finished, or alive: the stall clock starts again.
            last = beat;
            last_change = now;
        } else if now - last_change >= stall {
            let stalled = now - last_change;
            kill_and_reap(child);
            return Ok(Ended::Hung { stalled });
        }
        if urgent_since.is_some_and(|t| now - t >= URGENT_GRACE) {
            kill_and_reap(child);
            return Ok(if shared.driving() && !shared.lifeline.done() {
                Ended::Unresponsive
            } else {
                Ended::Clean(ExitStatus::from_raw(libc::SIGKILL))
            });
        }
        std::thread::sleep(POLL);
    }
}

fn kill_and_reap(child: &mut Child) {
    let _ = child.kill(); // SIGKILL: also ends a stopped process
    let _ = child.wait();
}

/// Opens the boards with `open` and writes zero to every channel (twice: a frame lost on the
/// way must not leave a command standing). Retries the open a few times: the dead process's hold
/// on the device may take a moment to go. Returns what was zeroed.
pub fn take_over(open: &mut dyn FnMut() -> anyhow::Result<Box<dyn Device>>) -> anyhow::Result<String> {
    let mut tries = 0;
    let mut dev = loop {
        tries += 1;
        match open() {
            Ok(d) => break d,
            Err(e) if tries >= 5 => return Err(e.context("opening the boards to write zero")),
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    };
    let mut inp = Input::default();
    let first = dev.exchange(&Output::default(), &mut inp);
    let off = dev.deactivate();
    if let (Err(a), Err(b)) = (first, off) {
        bail!("writing zero to the boards failed twice: {a}; {b}");
    }
    let info = dev.info();
    Ok(format!("{} ({}), {} channels", info.board, info.identity, info.channels))
}

/// `spidar run` on real boards: runs this executable with the same arguments as the rig process,
/// watches it, and takes the boards over (`open`) if it dies or hangs while driving them. Returns
/// this process's exit status: the rig's own when it ended cleanly, else `EXIT_TOOK_OVER` or
/// `EXIT_TAKEOVER_FAILED`.
///
/// `fifo_priority`: the rig loop's SCHED_FIFO priority, if it asks for one. The supervisor then
/// runs one above it (after starting the rig, which must not inherit it): a loop that hangs in a
/// busy loop at its real-time priority would otherwise starve the very process that is to stop
/// it. Its cost to the loop is a few microseconds every [`POLL`].
pub fn supervise(
    stop: &Stop,
    fifo_priority: Option<u8>,
    open: &mut dyn FnMut(&Shared) -> anyhow::Result<Box<dyn Device>>,
) -> anyhow::Result<u8> {
    let page = Page::create()?;
    let exe = std::env::current_exe().context("finding this executable to start the rig process")?;
    let args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    let mut child = spawn_rig(&page, &exe, &args)?;
    if let Some(p) = fifo_priority {
        let opts = RtOptions {
            fifo_priority: Some(p.saturating_add(1).min(99)),
            lock_memory: false,
            prefault_stack_bytes: 0,
            cpu: None,
        };
        if !rt_thread::setup_current_thread(&opts).fifo {
            eprintln!(
                "spidar supervisor: warning: SCHED_FIFO not permitted: a loop hung at its real-time priority may \
                 delay the takeover"
            );
        }
    }
    let shared = page.shared();
    let ended = watch(&mut child, shared, stop, stall_limit())?;
    Ok(finish(&ended, &mut || open(shared), &mut |line| eprintln!("{line}")))
}

/// The stall limit: [`STALL`], or `SPIDAR_SUPERVISOR_STALL_MS` (10 ms to 60 s) for a loop that
/// runs without SCHED_FIFO on a busy machine (tests), where a scheduling stall of 60 ms is not a
/// hang. Never below 10 ms.
pub fn stall_limit() -> Duration {
    std::env::var("SPIDAR_SUPERVISOR_STALL_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .map_or(STALL, |ms| Duration::from_millis(ms.clamp(10, 60_000)))
}

/// After the rig process ended: the exit status to give, and the takeover if one is needed.
pub fn finish(
    ended: &Ended,
    open: &mut dyn FnMut() -> anyhow::Result<Box<dyn Device>>,
    say: &mut dyn FnMut(String),
) -> u8 {
    match ended {
        Ended::Clean(s) => match (s.code(), s.signal()) {
            (Some(c), _) => c.clamp(0, 255) as u8,
            (_, Some(sig)) => (128 + sig).clamp(0, 255) as u8,
            _ => 1,
        },
        e => {
            let t0 = Instant::now();
            match take_over(open) {
                Ok(what) => {
                    say(format!(
                        "spidar supervisor: {}; took the boards over and wrote zero to every channel of {what} in {} ms \
                         (no tension: the strings are slack). Exit status {EXIT_TOOK_OVER}.",
                        e.describe(),
                        t0.elapsed().as_millis()
                    ));
                    EXIT_TOOK_OVER
                }
                Err(err) => {
                    say(format!(
                        "spidar supervisor: {}; COULD NOT WRITE ZERO TO THE BOARDS ({err:#}): the motors may still \
                         pull. Press the rig's emergency stop or switch the motor power off now. Exit status \
                         {EXIT_TAKEOVER_FAILED}.",
                        e.describe()
                    ));
                    EXIT_TAKEOVER_FAILED
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use spidar_device::transport::BulkTransport;
    use spidar_device::usb::protocol::{self as p, SimpleCommand};
    use spidar_device::usb::{UsbBoard, UsbKind, UsbOpener, UsbOptions};
    use spidar_device::{DeviceError, OpenError};

    use super::*;

    /// A USB board (Simple or SH-4) that keeps the DA values it was last sent.
    #[derive(Default)]
    struct FakeBoard {
        sh4: bool,
        da: [i16; p::CHANNELS],
        pending: bool,
        opens: u32,
    }

    struct FakeTransport(Arc<Mutex<FakeBoard>>);

    impl BulkTransport for FakeTransport {
        fn bulk_write(&mut self, _: u8, data: &[u8], _: Duration) -> Result<(), DeviceError> {
            let mut b = self.0.lock().unwrap();
            if b.sh4 {
                b.da = p::sh4_decode_out(data).map_err(|_| DeviceError::Corrupt { what: "fake" })?;
                b.pending = true;
            } else {
                match p::simple_decode_command(data).map_err(|_| DeviceError::Corrupt { what: "fake" })? {
                    SimpleCommand::SetDa(da) => b.da = da,
                    SimpleCommand::RequestCounters => b.pending = true,
                    _ => {}
                }
            }
            Ok(())
        }
        fn bulk_read(&mut self, _: u8, buf: &mut [u8], _: Duration) -> Result<usize, DeviceError> {
            let mut b = self.0.lock().unwrap();
            if !std::mem::take(&mut b.pending) {
                return Err(DeviceError::Timeout { waited_us: 0 });
            }
            Ok(if b.sh4 {
                let mut pk = [0u8; p::SH4_LEN];
                p::sh4_encode_in(&p::Sh4In { da_echo: b.da, ..Default::default() }, &mut pk);
                buf[..p::SH4_LEN].copy_from_slice(&pk);
                p::SH4_LEN
            } else {
                let mut pk = [0u8; p::SIMPLE_LEN];
                p::simple_encode_counters(&p::SimpleCounters { counts: [0; p::CHANNELS], pio: 0 }, &mut pk);
                buf[..p::SIMPLE_LEN].copy_from_slice(&pk);
                p::SIMPLE_LEN
            })
        }
        fn reset_in(&mut self, _: u8) -> Result<(), DeviceError> {
            Ok(())
        }
    }

    struct FakeBus(Arc<Mutex<FakeBoard>>);

    impl UsbOpener for FakeBus {
        type Link = FakeTransport;
        fn candidates(&mut self, _: u16, _: u16) -> Result<Vec<(String, FakeTransport)>, OpenError> {
            self.0.lock().unwrap().opens += 1;
            Ok(vec![("bus 1 addr 2".into(), FakeTransport(self.0.clone()))])
        }
        fn seen(&mut self) -> String {
            String::new()
        }
    }

    /// A board left pulling: every channel at 1 V, as a killed rig process leaves it.
    fn pulling(sh4: bool) -> Arc<Mutex<FakeBoard>> {
        Arc::new(Mutex::new(FakeBoard { sh4, da: [415; p::CHANNELS], ..Default::default() }))
    }

    fn opener(board: Arc<Mutex<FakeBoard>>) -> impl FnMut() -> anyhow::Result<Box<dyn Device>> {
        move || {
            let kind = if board.lock().unwrap().sh4 { UsbKind::Sh4 } else { UsbKind::Simple };
            let mut d = UsbBoard::new(kind, FakeBus(board.clone()), UsbOptions::default());
            d.open_detailed()?;
            Ok(Box::new(d) as Box<dyn Device>)
        }
    }

    /// A stand-in for the rig process: a real child process that does nothing.
    fn rig_child(page: &Page) -> Child {
        spawn_rig(page, std::path::Path::new("sleep"), &["30".into()]).unwrap()
    }

    #[test]
    fn a_rig_process_killed_while_driving_leaves_zero_on_the_usb_board() {
        let page = Page::create().unwrap();
        let shared = page.shared();
        let mut child = rig_child(&page);
        shared.set_driving();
        shared.lifeline.beat.store(123, Ordering::SeqCst);
        // SAFETY: kill -9 of the child we started and have not reaped.
        unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
        // A stall limit no loaded machine reaches: the exit is what must be seen.
        let ended = watch(&mut child, shared, &Stop::detached(), Duration::from_secs(3600)).unwrap();
        assert!(matches!(ended, Ended::Died(s) if s.signal() == Some(libc::SIGKILL)), "{ended:?}");
        let board = pulling(false);
        let mut said = Vec::new();
        let code = finish(&ended, &mut opener(board.clone()), &mut |l| said.push(l));
        assert_eq!(code, EXIT_TOOK_OVER, "{said:?}");
        assert_eq!(board.lock().unwrap().da, [0; p::CHANNELS], "the supervisor wrote zero DA");
        assert!(said[0].contains("killed (signal 9") && said[0].contains("USB Simple"), "{said:?}");
    }

    #[test]
    fn a_loop_that_stops_beating_is_killed_and_the_sh4_board_zeroed() {
        let page = Page::create().unwrap();
        let shared = page.shared();
        let mut child = rig_child(&page);
        shared.set_driving();
        // The loop beats 50 times, then hangs.
        let beats = std::thread::spawn(move || {
            for i in 1..=50 {
                shared.lifeline.beat.store(i, Ordering::Release);
                std::thread::sleep(Duration::from_millis(1));
            }
        });
        let ended = watch(&mut child, shared, &Stop::detached(), STALL).unwrap();
        beats.join().unwrap();
        let Ended::Hung { stalled } = ended else { panic!("{ended:?}") };
        assert!(stalled >= STALL);
        assert!(child.try_wait().unwrap().is_some(), "the hung process was killed and reaped");
        let board = pulling(true);
        let mut said = Vec::new();
        assert_eq!(finish(&ended, &mut opener(board.clone()), &mut |l| said.push(l)), EXIT_TOOK_OVER);
        assert_eq!(board.lock().unwrap().da, [0; p::CHANNELS]);
        assert!(said[0].contains("stopped ticking") && said[0].contains("SH-4"), "{said:?}");
    }

    #[test]
    fn a_clean_end_leaves_the_boards_alone_and_passes_the_exit_status_on() {
        let page = Page::create().unwrap();
        let shared = page.shared();
        let mut child =
            spawn_rig(&page, std::path::Path::new("sh"), &["-c".into(), "exit 1".into()]).unwrap();
        shared.set_driving();
        shared.lifeline.beat.store(Lifeline::DONE, Ordering::SeqCst);
        let ended = watch(&mut child, shared, &Stop::detached(), STALL).unwrap();
        assert!(matches!(ended, Ended::Clean(_)), "{ended:?}");
        let board = pulling(false);
        assert_eq!(finish(&ended, &mut opener(board.clone()), &mut |_| {}), 1);
        assert_eq!(board.lock().unwrap().opens, 0, "the boards were not touched");
        assert_eq!(board.lock().unwrap().da, [415; p::CHANNELS]);
    }

    #[test]
    fn signals_are_passed_on_and_a_rig_that_ignores_the_second_is_ended() {
        let page = Page::create().unwrap();
        let shared = page.shared();
        let mut child = rig_child(&page);
        shared.set_driving();
        shared.lifeline.beat.store(7, Ordering::SeqCst);
        let stop = Stop::detached();
        stop.request();
        stop.request();
        let ended = watch(&mut child, shared, &stop, Duration::from_secs(3600)).unwrap();
        assert_eq!(shared.stops.load(Ordering::SeqCst), 2, "both signals passed on");
        assert!(shared.lifeline.halt.load(Ordering::SeqCst) != 0, "the loop was told to halt");
        assert!(matches!(ended, Ended::Unresponsive), "{ended:?}");
        assert!(child.try_wait().unwrap().is_some());
    }

    #[test]
    fn a_failed_takeover_says_to_use_the_emergency_stop() {
        let mut said = Vec::new();
        let code =
            finish(&Ended::Hung { stalled: STALL }, &mut || anyhow::bail!("no board"), &mut |l| said.push(l));
        assert_eq!(code, EXIT_TAKEOVER_FAILED);
        assert!(said[0].contains("emergency stop"), "{said:?}");
    }

    #[test]
    fn the_uart_boards_published_by_the_rig_come_back_whole_and_a_scribbled_page_is_not_trusted() {
        let page = Page::create().unwrap();
        let shared = page.shared();
        assert_eq!(shared.known_uart(), None, "nothing published");
        let b0 = BoardInfo::of_model(0, 1).unwrap();
        let b2 = BoardInfo { n_touch: 3, ..BoardInfo::of_model(2, 6).unwrap() };
        shared.publish_uart(&[b0, b2], &[ReplyLayout::Forces, ReplyLayout::Currents]);
        assert_eq!(
            shared.known_uart(),
            Some((vec![b0, b2], vec![ReplyLayout::Forces, ReplyLayout::Currents]))
        );
        // A dying process may have written anything: a board no driver accepts, an unknown
        // layout, ids out of order or a count beyond the table all mean a full open.
        let bad = |w: u64| {
            shared.uart_boards[1].store(w, Ordering::Relaxed);
            shared.known_uart()
        };
        let good = shared.uart_boards[1].load(Ordering::Relaxed);
        assert_eq!(bad(good & !0xFF00), None, "model 0");
        assert_eq!(bad(good | (9 << 56)), None, "layout 9");
        assert_eq!(bad(good & !0xFF), None, "id 0 twice");
        assert_eq!(bad((good & !0xFF) | 8), None, "id 8");
        assert!(bad(good).is_some());
        shared.uart_count.store(MAX_BOARDS as u32 + 1, Ordering::Release);
        assert_eq!(shared.known_uart(), None);
    }

    #[test]
    fn the_page_is_shared_with_the_child_through_its_descriptor() {
        // The descriptor named in the environment is open in the rig process (it survives exec).
        let page = Page::create().unwrap();
        let mut child = spawn_rig(
            &page,
            std::path::Path::new("sh"),
            &["-c".into(), format!("test -e /proc/self/fd/${ENV_FD} && echo ok").into()],
        )
        .unwrap();
        assert!(child.wait().unwrap().success());
    }
}
