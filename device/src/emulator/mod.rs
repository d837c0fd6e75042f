//! The UART board emulator: a set of UART motor-driver boards, backed by the simulated rig,
//! serving the real wire protocol on a pseudo-terminal.
//!
//! Why it exists: the serial driver ([`crate::uart`]) and everything above it must be proven end
//! to end without hardware. `spidar emulate` runs this in its own process; tests run it on a
//! thread of their own process ([`Emulator::spawn`]) and switch its faults through [`Control`].
//!
//! Two parts:
//! - [`Boards`]: the boards themselves, bytes in and bytes out, no I/O: enumeration, command
//!   lengths, the current command and its replies, a board-side watchdog that zeroes the motor
//!   currents when commands stop for longer than `watchdog`, and the rig behind them.
//! - [`Emulator`]: a pty, a symlink at a stable path (as udev gives a USB serial adapter), and a
//!   thread moving bytes between them, applying the faults: dropped replies, corrupted bytes,
//!   extra delay, a board that stops answering, disconnect (the pty is closed and the link path
//!   removed) and reconnect (a new pty behind the same link path).
//!
//! Plant time ([`PlantClock`]): `PerTick` advances the simulated rig by one period for each
//! complete servo tick the host sends (every board's current command), so a run is the same as
//! the in-process simulated rig whatever the machine's timing (tests); `RealTime` advances it
//! every period of the wall clock with the latest commands, as real boards do (`spidar emulate`),
//! from the first current command on (until then the simulated user holds the grips at home).
//!
//! What it must never do: take commands for a board it did not announce, reply out of protocol
//! (the host's decoder would accept garbage), or keep currents on after the watchdog expired.

use std::ffi::CStr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::sim::{SimRig, Truth};
use crate::uart::protocol::{
    self, BoardInfo, BoardParser, CurrentReply, HostCommand, INFO_REPLY_LEN, MAX_BOARDS, MAX_MOTORS,
};
use crate::{Device, Input, Output, MAX_CHANNELS};

/// When the simulated rig advances.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlantClock {
    /// One period per complete servo tick from the host (deterministic; tests).
    PerTick,
    /// One period per period of the wall clock, with the latest commands (like real boards).
    RealTime,
}

/// What the emulated boards are.
#[derive(Clone, Debug)]
pub struct EmulatorOptions {
    /// Board model numbers (1 = B1M ... 6 = B3F); board ids are 0, 1, ... in this order.
    pub models: Vec<u8>,
    pub plant: PlantClock,
    /// The boards zero their currents when no current command came for this long.
    pub watchdog: Duration,
    /// Current-command digits per volt (as the host's driver).
    pub digits_per_volt: f64,
    /// Run the serving thread at this SCHED_FIFO priority (as a board answers at once); falls
    /// back to the normal scheduler when not permitted ([`Control::fifo`] tells which).
    pub fifo_priority: Option<i32>,
}

impl Default for EmulatorOptions {
    /// Two B1M boards (8 motors, a SPIDAR-H), real-time plant, 50 ms watchdog.
    fn default() -> Self {
        EmulatorOptions {
            models: vec![1, 1],
            plant: PlantClock::RealTime,
            watchdog: Duration::from_millis(50),
            digits_per_volt: protocol::DEFAULT_DIGITS_PER_VOLT,
            fifo_priority: None,
        }
    }
}

/// Parses a board list such as "B1M,B1M" or "B3M".
pub fn parse_models(list: &str) -> Result<Vec<u8>, String> {
    let mut v = Vec::new();
    for name in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        match BoardInfo::model_by_name(name) {
            Some(m) => v.push(m),
            None => {
                let known: Vec<&str> = BoardInfo::MODELS.iter().map(|m| m.1).collect();
                return Err(format!("unknown board '{name}': use {}", known.join(", ")));
            }
        }
    }
    if v.is_empty() || v.len() > MAX_BOARDS {
        return Err(format!("give 1 to {MAX_BOARDS} boards, e.g. B1M,B1M"));
    }
    Ok(v)
}

/// Counters of what the boards did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoardStats {
    pub info_requests: u64,
    pub current_commands: u64,
    /// Complete servo ticks (every board's current command received).
    pub ticks: u64,
    /// Plant periods advanced.
    pub plant_steps: u64,
    pub watchdog_trips: u64,
    pub replies_dropped: u64,
    pub replies_corrupted: u64,
    pub replies_delayed: u64,
    /// Bytes no board took (commands for absent boards, unknown commands).
    pub bytes_skipped: u64,
}

/// The boards on one link and the simulated rig behind them; bytes in, bytes out.
#[derive(Debug)]
pub struct Boards {
    boards: [Option<BoardInfo>; MAX_BOARDS],
    offsets: [usize; MAX_BOARDS],
    present: u8,
    parser: BoardParser,
    rig: SimRig,
    opts: EmulatorOptions,
    period: Duration,
    /// Current commands of this tick so far, and which boards sent theirs.
    tick_currents: [[i16; MAX_MOTORS]; MAX_BOARDS],
    tick_mask: u8,
    /// The currents the motors are driven with (zeroed by the watchdog).
    latched: [[i16; MAX_MOTORS]; MAX_BOARDS],
    counts: Input,
    prev_counts: [i64; MAX_CHANNELS],
    last_command: Option<Instant>,
    tripped: bool,
    next_plant: Option<Instant>,
    stats: BoardStats,
}

impl Boards {
    /// The boards `opts.models` in front of `rig` (opened and activated here: the board drives its
    /// motors whenever it has a current command).
    pub fn new(mut rig: SimRig, opts: EmulatorOptions) -> Result<Boards, String> {
        let mut boards = [None; MAX_BOARDS];
        let mut offsets = [0; MAX_BOARDS];
        let mut off = 0;
        if opts.models.is_empty() || opts.models.len() > MAX_BOARDS {
            return Err(format!("the emulator needs 1 to {MAX_BOARDS} boards"));
        }
        for (id, &m) in opts.models.iter().enumerate() {
            let b = BoardInfo::of_model(id as u8, m).ok_or_else(|| format!("unknown board model {m}"))?;
            boards[id] = Some(b);
            offsets[id] = off;
            off += usize::from(b.n_motor);
        }
        if off > MAX_CHANNELS {
            return Err(format!("{off} motors: at most {MAX_CHANNELS}"));
        }
        let present = (1u16 << opts.models.len()).wrapping_sub(1) as u8;
        rig.open().map_err(|e| e.to_string())?;
        rig.activate().map_err(|e| e.to_string())?;
        // What the counters show before the first plant step (the rig's state at power-on).
        let mut counts = Input::default();
        let period = Duration::from_secs_f64(rig.params().period_s);
        let truth_counts = initial_counts(&rig);
        counts.counts = truth_counts;
        Ok(Boards {
            boards,
            offsets,
            present,
            parser: BoardParser::new(boards),
            rig,
            opts,
            period,
            tick_currents: [[0; MAX_MOTORS]; MAX_BOARDS],
            tick_mask: 0,
            latched: [[0; MAX_MOTORS]; MAX_BOARDS],
            counts,
            prev_counts: truth_counts,
            last_command: None,
            tripped: false,
            next_plant: None,
            stats: BoardStats::default(),
        })
    }

    pub fn rig(&self) -> &SimRig {
        &self.rig
    }
    pub fn rig_mut(&mut self) -> &mut SimRig {
        &mut self.rig
    }
    pub fn stats(&self) -> BoardStats {
        let mut s = self.stats;
        s.bytes_skipped = self.parser.skipped;
        s
    }
    pub fn board_infos(&self) -> impl Iterator<Item = &BoardInfo> {
        self.boards.iter().flatten()
    }
    /// True while the watchdog holds the motors at zero.
    pub fn watchdog_tripped(&self) -> bool {
        self.tripped
    }
    /// The currents the motors are driven with now, per channel (digits).
    pub fn motor_currents(&self) -> [i16; MAX_CHANNELS] {
        let mut c = [0; MAX_CHANNELS];
        for (id, b) in self.boards.iter().enumerate() {
            if let Some(b) = b {
                for m in 0..usize::from(b.n_motor) {
                    c[self.offsets[id] + m] = self.latched[id][m];
                }
            }
        }
        c
    }

    /// A new link: forget any half-received command.
    pub fn reset_link(&mut self) {
        self.parser.reset();
        self.tick_mask = 0;
    }

    /// Takes the host's bytes; appends the boards' replies to `out`, and to `ticks` the byte range
    /// in `out` of each servo tick's current replies (for the fault layer).
    pub fn feed(&mut self, bytes: &[u8], now: Instant, out: &mut Vec<u8>, ticks: &mut Vec<(usize, usize)>) {
        for &b in bytes {
            let Some(c) = self.parser.push(b) else { continue };
            match c {
                HostCommand::BoardInfo { board } => {
                    self.stats.info_requests += 1;
                    if let Some(info) = self.boards[usize::from(board)] {
                        let mut rep = [0u8; INFO_REPLY_LEN];
                        protocol::encode_info_reply(&info, &mut rep);
                        out.extend_from_slice(&rep);
                    }
                }
                HostCommand::SetCommandLengths { .. } | HostCommand::Unsupported { .. } => {}
                HostCommand::Current { board, currents } => {
                    self.stats.current_commands += 1;
                    self.last_command = Some(now);
                    self.tripped = false;
                    let id = usize::from(board);
                    self.tick_currents[id] = currents;
                    self.tick_mask |= 1 << id;
                    if self.opts.plant == PlantClock::RealTime {
                        // A real board applies its command and answers at once with what it has.
                        self.latched[id] = currents;
                        let start = out.len();
                        self.reply(id, out);
                        if self.tick_mask == self.present {
                            self.tick_mask = 0;
                            self.stats.ticks += 1;
                        }
                        ticks.push((start, out.len()));
                    } else if self.tick_mask == self.present {
                        self.tick_mask = 0;
                        self.stats.ticks += 1;
                        self.latched = self.tick_currents;
                        self.step_plant();
                        let start = out.len();
                        for id in 0..MAX_BOARDS {
                            if self.boards[id].is_some() {
                                self.reply(id, out);
                            }
                        }
                        ticks.push((start, out.len()));
                    }
                }
            }
        }
    }

    /// Runs the watchdog and, on the real-time plant clock, the plant up to `now`.
    pub fn idle(&mut self, now: Instant) {
        if let Some(last) = self.last_command {
            if !self.tripped && now.duration_since(last) > self.opts.watchdog {
                self.tripped = true;
                self.stats.watchdog_trips += 1;
                self.latched = [[0; MAX_MOTORS]; MAX_BOARDS];
            }
        }
        // The simulated user holds the grips at home until the host starts servoing (as an
        // operator does while the rig homes): the plant starts with the first current command.
        if self.opts.plant == PlantClock::RealTime && self.last_command.is_some() {
            let next = *self.next_plant.get_or_insert(now);
            let mut next = next;
            let mut steps = 0;
            while now >= next && steps < 10 {
                self.step_plant();
                next += self.period;
                steps += 1;
            }
            if now >= next {
                next = now + self.period; // stalled: do not run a burst of catch-up steps
            }
            self.next_plant = Some(next);
        }
    }

    /// When the real-time plant next needs to step.
    pub fn next_wake(&self) -> Option<Instant> {
        match self.opts.plant {
            PlantClock::RealTime => self.next_plant,
            PlantClock::PerTick => None,
        }
    }

    fn step_plant(&mut self) {
        let mut out = Output::default();
        for (id, b) in self.boards.iter().enumerate() {
            if let Some(b) = b {
                for m in 0..usize::from(b.n_motor) {
                    out.volts[self.offsets[id] + m] =
                        f64::from(self.latched[id][m]) / self.opts.digits_per_volt;
                }
            }
        }
        self.prev_counts = self.counts.counts;
        let _ = self.rig.exchange(&out, &mut self.counts);
        self.stats.plant_steps += 1;
    }

    fn reply(&mut self, id: usize, out: &mut Vec<u8>) {
        let Some(b) = self.boards[id] else { return };
        let mut r = CurrentReply::default();
        for m in 0..usize::from(b.n_motor) {
            let ch = self.offsets[id] + m;
            // The board's counter is 16 bits: it wraps (the host extends it).
            r.positions[m] = self.counts.counts[ch] as i16;
            r.velocities[m] = (self.counts.counts[ch] - self.prev_counts[ch]).clamp(-32768, 32767) as i16;
            if m < usize::from(b.n_current) {
                r.currents[m] = self.latched[id][m];
            }
        }
        let mut buf = [0u8; 32];
        if let Ok(n) = protocol::encode_current_reply(&b, &r, &mut buf) {
            out.extend_from_slice(&buf[..n]);
        }
    }
}

/// Encoder counts of the rig's current state, without advancing it (what the boards show at power-on).
fn initial_counts(rig: &SimRig) -> [i64; MAX_CHANNELS] {
    let mut c = [0i64; MAX_CHANNELS];
    for (h, hp) in rig.params().hands.iter().enumerate() {
        for (i, s) in hp.strings.iter().enumerate() {
            let len = rig.true_length_m(h, i);
            if let Some(slot) = c.get_mut(s.channel) {
                *slot = ((len - s.length_at_zero_m) / s.metres_per_count).floor() as i64;
            }
        }
    }
    c
}

/// Faults switched at run time; see [`Control`].
#[derive(Debug, Default)]
struct Faults {
    drop: AtomicU32,
    corrupt: AtomicU32,
    delay_n: AtomicU32,
    delay_us: AtomicU32,
    silent: AtomicBool,
    disconnect: AtomicBool,
    reconnect: AtomicBool,
    stop: AtomicBool,
    /// Bumped each time a new pty is up (the first one is 1).
    connections: AtomicU64,
    connected: AtomicBool,
    fifo: AtomicBool,
}

/// Switches the emulator's faults from another thread (tests, the stdin of `spidar emulate`).
#[derive(Clone, Debug)]
pub struct Control {
    faults: Arc<Faults>,
    boards: Arc<Mutex<Boards>>,
}

impl Control {
    /// The next `n` servo ticks get no reply (the boards still apply the commands).
    pub fn drop_replies(&self, n: u32) {
        self.faults.drop.store(n, Ordering::SeqCst);
    }
    /// The next `n` servo ticks' replies have their first byte (a header) corrupted.
    pub fn corrupt_replies(&self, n: u32) {
        self.faults.corrupt.store(n, Ordering::SeqCst);
    }
    /// The next `n` servo ticks' replies are sent `delay` late.
    pub fn delay_replies(&self, n: u32, delay: Duration) {
        self.faults.delay_us.store(delay.as_micros().min(u32::MAX as u128) as u32, Ordering::SeqCst);
        self.faults.delay_n.store(n, Ordering::SeqCst);
    }
    /// The boards stop answering (and stop taking commands, so their watchdog trips) until unset.
    pub fn set_silent(&self, silent: bool) {
        self.faults.silent.store(silent, Ordering::SeqCst);
    }
    /// Unplug: the pty is closed and the link path removed.
    pub fn disconnect(&self) {
        self.faults.disconnect.store(true, Ordering::SeqCst);
    }
    /// Plug back in: a new pty behind the same link path.
    pub fn reconnect(&self) {
        self.faults.reconnect.store(true, Ordering::SeqCst);
    }
    /// Whether a pty is up, and how many have been (1 after start, +1 per reconnect).
    pub fn connection(&self) -> (bool, u64) {
        (self.faults.connected.load(Ordering::SeqCst), self.faults.connections.load(Ordering::SeqCst))
    }
    /// Whether the serving thread got SCHED_FIFO.
    pub fn fifo(&self) -> bool {
        self.faults.fifo.load(Ordering::SeqCst)
    }
    /// The boards (and the simulated rig behind them), locked.
    pub fn boards(&self) -> MutexGuard<'_, Boards> {
        self.boards.lock().unwrap_or_else(|p| p.into_inner())
    }
    pub fn truth(&self) -> Truth {
        *self.boards().rig().truth()
    }
    pub fn stats(&self) -> BoardStats {
        self.boards().stats()
    }
    /// Pending one-shot faults (drop, corrupt, delay) not yet used.
    pub fn pending_faults(&self) -> u32 {
        self.faults.drop.load(Ordering::SeqCst)
            + self.faults.corrupt.load(Ordering::SeqCst)
            + self.faults.delay_n.load(Ordering::SeqCst)
    }
}

/// A running emulator: its pty, link path and serving thread. Dropping it stops the thread and
/// removes the link.
pub struct Emulator {
    link: PathBuf,
    control: Control,
    thread: Option<JoinHandle<()>>,
}

/// Errors setting the emulator up.
#[derive(Debug, thiserror::Error)]
pub enum EmulatorError {
    #[error("emulator: {0}")]
    Config(String),
    #[error("emulator: cannot create a pseudo-terminal: {0}")]
    Pty(std::io::Error),
    #[error("emulator: cannot create the link {path}: {source} (choose another path with --link)")]
    Link { path: String, source: std::io::Error },
}

/// An open pty master and the path of its slave.
struct Pty {
    master: libc::c_int,
    /// The emulator keeps the slave open too, so the master does not read EIO while no host is attached.
    slave: libc::c_int,
    path: PathBuf,
}

impl Pty {
    fn open() -> Result<Pty, std::io::Error> {
        let mut master = -1;
        let mut slave = -1;
        let r = unsafe {
            libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null(), std::ptr::null())
        };
        if r != 0 {
            return Err(std::io::Error::last_os_error());
        }
        let mut name = [0 as libc::c_char; 128];
        let r = unsafe { libc::ptsname_r(master, name.as_mut_ptr(), name.len()) };
        if r != 0 {
            let e = std::io::Error::from_raw_os_error(r);
            unsafe {
                libc::close(master);
                libc::close(slave);
            }
            return Err(e);
        }
        let path = PathBuf::from(unsafe { CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned());
        // Raw, binary-transparent: no echo, no line discipline (the host sets the same).
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            if libc::tcgetattr(slave, &mut t) == 0 {
                libc::cfmakeraw(&mut t);
                libc::tcsetattr(slave, libc::TCSANOW, &t);
            }
            let flags = libc::fcntl(master, libc::F_GETFL);
            libc::fcntl(master, libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        Ok(Pty { master, slave, path })
    }
}

impl Drop for Pty {
    fn drop(&mut self) {
        unsafe {
            libc::close(self.slave);
            libc::close(self.master);
        }
    }
}

/// Points the symlink `link` at `target`, replacing an old symlink but never anything else.
fn point_link(link: &Path, target: &Path) -> Result<(), std::io::Error> {
    match std::fs::symlink_metadata(link) {
        Ok(m) if m.file_type().is_symlink() => std::fs::remove_file(link)?,
        Ok(_) => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "exists and is not a symlink (not replaced)",
            ))
        }
        Err(_) => {}
    }
    std::os::unix::fs::symlink(target, link)
}

impl Emulator {
    /// Starts the boards in front of `rig` on a new pty, reachable at `link` (a symlink that
    /// survives reconnects; it is replaced if it exists).
    pub fn spawn(rig: SimRig, opts: EmulatorOptions, link: &Path) -> Result<Emulator, EmulatorError> {
        let opts_fifo = opts.fifo_priority;
        let boards = Boards::new(rig, opts).map_err(EmulatorError::Config)?;
        let pty = Pty::open().map_err(EmulatorError::Pty)?;
        point_link(link, &pty.path)
            .map_err(|source| EmulatorError::Link { path: link.display().to_string(), source })?;
        let faults = Arc::new(Faults::default());
        faults.connections.store(1, Ordering::SeqCst);
        faults.connected.store(true, Ordering::SeqCst);
        let control = Control { faults, boards: Arc::new(Mutex::new(boards)) };
        let c = control.clone();
        let link_owned = link.to_path_buf();
        let fifo = opts_fifo;
        let thread = std::thread::Builder::new()
            .name("spidar-emulator".into())
            .spawn(move || {
                if let Some(prio) = fifo {
                    let p = libc::sched_param { sched_priority: prio };
                    let ok =
                        unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &p) }
                            == 0;
                    c.faults.fifo.store(ok, Ordering::SeqCst);
                }
                serve(pty, c, link_owned)
            })
            .map_err(EmulatorError::Pty)?;
        Ok(Emulator { link: link.to_path_buf(), control, thread: Some(thread) })
    }

    /// The stable path a host opens (a symlink to the current pty).
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// The pty the link points at now.
    pub fn pty_path(&self) -> Option<PathBuf> {
        std::fs::read_link(&self.link).ok()
    }

    pub fn control(&self) -> &Control {
        &self.control
    }

    /// Stops serving and removes the link.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.control.faults.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        remove_link(&self.link);
    }
}

/// Removes the link if it is (still) a symlink.
fn remove_link(link: &Path) {
    if std::fs::symlink_metadata(link).is_ok_and(|m| m.file_type().is_symlink()) {
        let _ = std::fs::remove_file(link);
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The serving thread: poll the pty, feed the boards, apply the faults, write the replies.
fn serve(first: Pty, control: Control, link: PathBuf) {
    let f = &control.faults;
    let mut pty = Some(first);
    let mut inbuf = [0u8; 4096];
    let mut out = Vec::with_capacity(4096);
    let mut ticks = Vec::with_capacity(16);
    while !f.stop.load(Ordering::SeqCst) {
        if f.disconnect.swap(false, Ordering::SeqCst) {
            pty = None; // closing the master hangs up the host's end
            remove_link(&link);
            f.connected.store(false, Ordering::SeqCst);
        }
        if f.reconnect.swap(false, Ordering::SeqCst) && pty.is_none() {
            if let Ok(p) = Pty::open() {
                if point_link(&link, &p.path).is_ok() {
                    control.boards().reset_link();
                    pty = Some(p);
                    f.connections.fetch_add(1, Ordering::SeqCst);
                    f.connected.store(true, Ordering::SeqCst);
                }
            }
        }
        let now = Instant::now();
        let wake = control.boards().next_wake();
        let timeout_ms = wake
            .map_or(2, |w| w.saturating_duration_since(now).as_micros().div_ceil(1000) as i32)
            .clamp(0, 2);
        let Some(p) = pty.as_ref() else {
            std::thread::sleep(Duration::from_millis(1));
            control.boards().idle(Instant::now());
            continue;
        };
        let mut pfd = libc::pollfd { fd: p.master, events: libc::POLLIN, revents: 0 };
        let n = unsafe { libc::poll(&mut pfd, 1, timeout_ms) };
        if n > 0 && pfd.revents & libc::POLLIN != 0 {
            let r = unsafe { libc::read(p.master, inbuf.as_mut_ptr().cast(), inbuf.len()) };
            if r > 0 {
                let bytes = &inbuf[..r as usize];
                if !f.silent.load(Ordering::SeqCst) {
                    out.clear();
                    ticks.clear();
                    control.boards().feed(bytes, Instant::now(), &mut out, &mut ticks);
                    let delay = apply_faults(f, &control, &mut out, &ticks);
                    if let Some(d) = delay {
                        std::thread::sleep(d);
                    }
                    write_all_nonblocking(p.master, &out);
                }
            }
        } else if n > 0 && pfd.revents & libc::POLLHUP != 0 {
            // No host has the slave open right now (only our own slave fd): nothing to read.
            std::thread::sleep(Duration::from_micros(200));
        }
        control.boards().idle(Instant::now());
    }
}

/// Applies the one-shot faults to this batch's servo-tick replies; returns a delay to wait first.
fn apply_faults(
    f: &Faults,
    control: &Control,
    out: &mut Vec<u8>,
    ticks: &[(usize, usize)],
) -> Option<Duration> {
    let take =
        |a: &AtomicU32| a.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |v| v.checked_sub(1)).is_ok();
    let mut delay = None;
    // Walk backwards so removing a range keeps the earlier ranges valid.
    for &(start, end) in ticks.iter().rev() {
        if start >= end {
            continue;
        }
        if take(&f.drop) {
            out.drain(start..end);
            control.boards().stats.replies_dropped += 1;
        } else if take(&f.corrupt) {
            out[start] ^= 0xA5;
            control.boards().stats.replies_corrupted += 1;
        } else if take(&f.delay_n) {
            delay = Some(Duration::from_micros(u64::from(f.delay_us.load(Ordering::SeqCst))));
            control.boards().stats.replies_delayed += 1;
        }
    }
    delay
}

fn write_all_nonblocking(fd: libc::c_int, mut bytes: &[u8]) {
    let give_up = Instant::now() + Duration::from_millis(50);
    while !bytes.is_empty() && Instant::now() < give_up {
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        if n > 0 {
            bytes = &bytes[n as usize..];
        } else {
            // The host is not reading (queue full) or gone: like a UART overrun, bytes are lost.
            std::thread::sleep(Duration::from_micros(100));
        }
    }
}

#[cfg(test)]
mod tests;
