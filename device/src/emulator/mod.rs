//! The UART board emulator: a set of UART motor-driver boards, backed by the simulated rig,
//! serving the real wire protocol on a pseudo-terminal, and behaving as the boards' firmware
//! does (`docs/protocols.md`).
//!
//! Why it exists: the serial driver ([`crate::uart`]) and everything above it must be proven end
//! to end without hardware, against boards that fail the way real ones do. `spidar emulate` runs
//! this in its own process; tests run it on a thread of their own process ([`Emulator::spawn`])
//! and switch its faults through [`Control`].
//!
//! Two parts:
//! - [`Boards`]: the boards themselves, bytes in and bytes out, no I/O. Each board runs the
//!   firmware's command parser ([`BoardParser`]): a command-length table per board id, a command
//!   ends after its declared length, a declared 0 never ends (the board is lost until
//!   power-off, [`Boards::locked`]). A board answers a header addressed to it at once, with the
//!   state from before the command. The reply to the current command has the layout of the
//!   firmware generation chosen ([`EmulatorOptions::layout`]). A motor without a current sensor
//!   takes its command as a PWM duty clipped at +-1024, one with a sensor as a current target;
//!   a motor held stalled at high duty is derated by the thermal limit ([`motor`]). **No
//!   watchdog**: the last command is held whatever the host does; an optional one exists for
//!   experiments ([`EmulatorOptions::watchdog`], off unless asked for).
//! - [`Emulator`]: a pty, a symlink to it in a directory private to the user ([`symlink`]), and a
//!   thread moving bytes between them, applying the faults: dropped replies, corrupted bytes,
//!   extra delay, boards that hear nothing, disconnect (the pty is closed and the link removed)
//!   and reconnect (a new pty behind the same link). The boards stay powered through a
//!   disconnect: their parsers and tables keep their state, as real boards do.
//!
//! Plant time ([`PlantClock`]): `PerTick` advances the simulated rig by one period for each
//! complete servo tick the host sends (every board's current command), sampling the encoders at
//! the tick's first current header, so a run is the same as the in-process simulated rig
//! whatever the machine's timing (tests); `RealTime` advances it every period of the wall clock
//! with the latest commands, as real boards do (`spidar emulate`), from the first current
//! command on (until then the simulated user holds the grips at home).
//!
//! What it must never do: take commands for a board it did not announce, reply out of protocol
//! (the host's decoder would accept garbage), or let a test pass on a safety feature the boards
//! lack (a watchdog, a tolerant parser, an unclipped PWM).

pub mod motor;
pub mod symlink;

use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::sim::{SimRig, Truth};
use crate::uart::protocol::{
    self, cmd, BoardInfo, BoardParser, CurrentReply, HostCommand, ReplyLayout, INFO_REPLY_LEN, MAX_BOARDS,
    MAX_MOTORS,
};
use crate::{Device, Input, Output, MAX_CHANNELS};
use motor::MotorHeat;

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
    /// Board model numbers (1 = B1M ... 7 = B5M); board ids are 0, 1, ... in this order.
    pub models: Vec<u8>,
    pub plant: PlantClock,
    /// The firmware generation: the layout of the reply to the current command.
    pub layout: ReplyLayout,
    /// Experiments only: zero the motors when no current command came for this long. The real
    /// boards have no watchdog; None (the default) emulates them as they are.
    pub watchdog: Option<Duration>,
    /// How PWM-duty digits map back to the simulated rig's volts (as the host's driver maps them).
    pub pwm_digits_per_volt: f64,
    /// How current-target digits map back to the simulated rig's volts.
    pub current_digits_per_volt: f64,
    /// Position counts per motor revolution (the thermal limit watches the motor's speed).
    pub counts_per_rev: f64,
    /// Run the serving thread at this SCHED_FIFO priority (as a board answers at once); falls
    /// back to the normal scheduler when not permitted ([`Control::fifo`] tells which).
    pub fifo_priority: Option<i32>,
}

impl Default for EmulatorOptions {
    /// Two B1M boards (8 motors, a SPIDAR-H) with the current firmware, real-time plant, no
    /// watchdog, the lab host driver's scale.
    fn default() -> Self {
        EmulatorOptions {
            models: vec![1, 1],
            plant: PlantClock::RealTime,
            layout: ReplyLayout::Forces,
            watchdog: None,
            pwm_digits_per_volt: protocol::HOST_DIGITS_PER_VOLT,
            current_digits_per_volt: protocol::HOST_DIGITS_PER_VOLT,
            counts_per_rev: f64::from(protocol::MAGNET_COUNTS_PER_REV),
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
                let known: Vec<&str> = protocol::MODELS.iter().map(|m| m.name).collect();
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
    /// "Set command lengths" commands heard (counted once, whichever board they address).
    pub length_tables: u64,
    /// Complete servo ticks (every board's current command received).
    pub ticks: u64,
    /// Plant periods advanced.
    pub plant_steps: u64,
    pub watchdog_trips: u64,
    pub replies_dropped: u64,
    pub replies_corrupted: u64,
    pub replies_delayed: u64,
    /// Header bytes no board could take (a command id of 12 or more), summed over the boards.
    pub bytes_skipped: u64,
}

/// The boards on one link and the simulated rig behind them; bytes in, bytes out.
#[derive(Debug)]
pub struct Boards {
    boards: [Option<BoardInfo>; MAX_BOARDS],
    parsers: [Option<BoardParser>; MAX_BOARDS],
    offsets: [usize; MAX_BOARDS],
    present: u8,
    rig: SimRig,
    opts: EmulatorOptions,
    period: Duration,
    /// Heat updates every this many plant steps.
    heat_every: u64,
    /// Commands of this tick so far, and which boards sent theirs.
    tick_commands: [[i16; MAX_MOTORS]; MAX_BOARDS],
    tick_mask: u8,
    /// Where this tick's current replies start in the caller's output (for the fault layer).
    tick_start: Option<usize>,
    /// The commands the motors are driven with, as received (zeroed only by the opt-in watchdog).
    latched: [[i16; MAX_MOTORS]; MAX_BOARDS],
    heat: [MotorHeat; MAX_CHANNELS],
    /// What each motor is driven with after clipping and the thermal limit: command digits and duty.
    driven: [(f64, f64); MAX_CHANNELS],
    counts: Input,
    prev_counts: [i64; MAX_CHANNELS],
    /// PerTick: the encoders were sampled for this tick already.
    sampled: bool,
    last_command: Option<Instant>,
    tripped: bool,
    next_plant: Option<Instant>,
    stats: BoardStats,
}

impl Boards {
    /// The boards `opts.models` in front of `rig` (opened and activated here: the board drives its
    /// motors whenever it has a command).
    pub fn new(mut rig: SimRig, opts: EmulatorOptions) -> Result<Boards, String> {
        let mut boards = [None; MAX_BOARDS];
        let mut parsers = [const { None }; MAX_BOARDS];
        let mut offsets = [0; MAX_BOARDS];
        let mut off = 0;
        if opts.models.is_empty() || opts.models.len() > MAX_BOARDS {
            return Err(format!("the emulator needs 1 to {MAX_BOARDS} boards"));
        }
        for (v, name) in [
            (opts.pwm_digits_per_volt, "PWM digits per volt"),
            (opts.current_digits_per_volt, "current digits per volt"),
            (opts.counts_per_rev, "counts per revolution"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be a positive number, not {v}"));
            }
        }
        for (id, &m) in opts.models.iter().enumerate() {
            let b = BoardInfo::of_model(id as u8, m).ok_or_else(|| format!("unknown board model {m}"))?;
            boards[id] = Some(b);
            parsers[id] = Some(BoardParser::new(&b));
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
        let heat_every = ((1.0 / motor::HEAT_RATE_HZ) / rig.params().period_s).round().max(1.0) as u64;
        let truth_counts = initial_counts(&rig);
        counts.counts = truth_counts;
        Ok(Boards {
            boards,
            parsers,
            offsets,
            present,
            rig,
            opts,
            period,
            heat_every,
            tick_commands: [[0; MAX_MOTORS]; MAX_BOARDS],
            tick_mask: 0,
            tick_start: None,
            latched: [[0; MAX_MOTORS]; MAX_BOARDS],
            heat: [MotorHeat::default(); MAX_CHANNELS],
            driven: [(0.0, 0.0); MAX_CHANNELS],
            counts,
            prev_counts: truth_counts,
            sampled: false,
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
    pub fn options(&self) -> &EmulatorOptions {
        &self.opts
    }
    pub fn stats(&self) -> BoardStats {
        let mut s = self.stats;
        s.bytes_skipped = self.parsers.iter().flatten().map(|p| p.skipped).sum();
        s
    }
    pub fn board_infos(&self) -> impl Iterator<Item = &BoardInfo> {
        self.boards.iter().flatten()
    }
    /// The parser of board `id` (its length tables, whether it is locked).
    pub fn parser(&self, id: u8) -> Option<&BoardParser> {
        self.parsers.get(usize::from(id)).and_then(|p| p.as_ref())
    }
    /// Boards whose parser is lost after a command with a declared length of 0 (bit = board id):
    /// they take no command again until power-off and hold their last one.
    pub fn locked(&self) -> u8 {
        let mut m = 0;
        for (id, p) in self.parsers.iter().enumerate() {
            if p.as_ref().is_some_and(BoardParser::is_locked) {
                m |= 1 << id;
            }
        }
        m
    }
    /// True while the opt-in watchdog holds the motors at zero.
    pub fn watchdog_tripped(&self) -> bool {
        self.tripped
    }
    /// The commands the motors are driven with now, per channel (digits, as received).
    pub fn motor_commands(&self) -> [i16; MAX_CHANNELS] {
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
    /// The duty (0..1) each motor ran at in the last plant step, after clipping and the
    /// thermal limit.
    pub fn duties(&self) -> [f64; MAX_CHANNELS] {
        self.driven.map(|(_, d)| d)
    }
    /// The thermal state of each motor.
    pub fn heat(&self) -> [MotorHeat; MAX_CHANNELS] {
        self.heat
    }

    /// A new link (the pty was reopened): the boards keep their state (they stay powered), only
    /// this emulator's bookkeeping of the tick restarts.
    pub fn reset_link(&mut self) {
        self.tick_mask = 0;
        self.tick_start = None;
    }

    /// Takes the host's bytes; appends the boards' replies to `out`, and to `ticks` the byte range
    /// in `out` of each servo tick's current replies (for the fault layer).
    pub fn feed(&mut self, bytes: &[u8], now: Instant, out: &mut Vec<u8>, ticks: &mut Vec<(usize, usize)>) {
        for &b in bytes {
            let mut length_table = false;
            for id in 0..MAX_BOARDS {
                let Some(p) = self.parsers[id].as_mut() else { continue };
                let step = p.push(b);
                if let Some(c) = step.reply_to {
                    self.reply(id, c, out);
                }
                match step.done {
                    Some(HostCommand::Current { board, commands }) if usize::from(board) == id => {
                        self.take_current(id, commands, now, out, ticks);
                    }
                    Some(HostCommand::SetCommandLengths { .. }) => length_table = true,
                    _ => {}
                }
            }
            if length_table {
                self.stats.length_tables += 1;
            }
        }
    }

    /// Board `id`'s reply to a header for command `c`, at once (the state before the command).
    fn reply(&mut self, id: usize, c: u8, out: &mut Vec<u8>) {
        let Some(b) = self.boards[id] else { return };
        match c {
            cmd::BOARD_INFO => {
                self.stats.info_requests += 1;
                let mut rep = [0u8; INFO_REPLY_LEN];
                protocol::encode_info_reply(&b, &mut rep);
                out.extend_from_slice(&rep);
            }
            cmd::CURRENT => {
                if self.opts.plant == PlantClock::PerTick && !self.sampled {
                    self.prev_counts = self.counts.counts;
                    let _ = self.rig.sample(&mut self.counts);
                    self.sampled = true;
                }
                if self.tick_start.is_none() {
                    self.tick_start = Some(out.len());
                }
                let mut r = CurrentReply::default();
                for m in 0..usize::from(b.n_motor) {
                    let ch = self.offsets[id] + m;
                    // The board's counter is 16 bits: it wraps (the host extends it).
                    r.positions[m] = self.counts.counts[ch] as i16;
                    r.velocities[m] =
                        (self.counts.counts[ch] - self.prev_counts[ch]).clamp(-32768, 32767) as i16;
                }
                if self.opts.layout == ReplyLayout::Currents {
                    // The sensed current: the target as far as the board reaches it.
                    for m in 0..usize::from(b.n_current).min(usize::from(b.n_motor)) {
                        r.sensors[m] = self.driven[self.offsets[id] + m].0.round() as i16;
                    }
                } // Forces: the rig has no force sensors, they read 0.
                let mut buf = [0u8; 64];
                if let Ok(n) = protocol::encode_current_reply(&b, self.opts.layout, &r, &mut buf) {
                    out.extend_from_slice(&buf[..n]);
                }
            }
            // Other commands are not emulated (the driver never sends them): no reply.
            _ => {}
        }
    }

    fn take_current(
        &mut self,
        id: usize,
        commands: [i16; MAX_MOTORS],
        now: Instant,
        out: &[u8],
        ticks: &mut Vec<(usize, usize)>,
    ) {
        self.stats.current_commands += 1;
        self.last_command = Some(now);
        self.tripped = false;
        self.tick_commands[id] = commands;
        self.tick_mask |= 1 << id;
        if self.opts.plant == PlantClock::RealTime {
            // A real board applies its command at once.
            self.latched[id] = commands;
        }
        if self.tick_mask == self.present {
            self.tick_mask = 0;
            self.stats.ticks += 1;
            ticks.push((self.tick_start.take().unwrap_or(0).min(out.len()), out.len()));
            if self.opts.plant == PlantClock::PerTick {
                self.latched = self.tick_commands;
                let drive = self.drive();
                let _ = self.rig.apply(&drive);
                self.after_step();
                self.sampled = false;
            }
        }
    }

    /// Runs the opt-in watchdog and, on the real-time plant clock, the plant up to `now`.
    pub fn idle(&mut self, now: Instant) {
        if let (Some(last), Some(wd)) = (self.last_command, self.opts.watchdog) {
            if !self.tripped && now.duration_since(last) > wd {
                self.tripped = true;
                self.stats.watchdog_trips += 1;
                self.latched = [[0; MAX_MOTORS]; MAX_BOARDS];
            }
        }
        // The simulated user holds the grips at home until the host starts servoing (as an
        // operator does while the rig homes): the plant starts with the first current command.
        if self.opts.plant == PlantClock::RealTime && self.last_command.is_some() {
            let mut next = *self.next_plant.get_or_insert(now);
            let mut steps = 0;
            while now >= next && steps < 10 {
                let drive = self.drive();
                self.prev_counts = self.counts.counts;
                let _ = self.rig.exchange(&drive, &mut self.counts);
                self.after_step();
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

    /// The rig's volts for this period: each motor's command through its board's clipping and
    /// thermal limit, back in the host's volts.
    fn drive(&mut self) -> Output {
        let mut out = Output::default();
        for (id, b) in self.boards.iter().enumerate() {
            let Some(b) = b else { continue };
            for m in 0..usize::from(b.n_motor) {
                let ch = self.offsets[id] + m;
                let sensed = b.current_sensed(m);
                let (digits, duty) = motor::drive(self.latched[id][m], sensed, self.heat[ch].duty_limit);
                self.driven[ch] = (digits, duty);
                let dpv =
                    if sensed { self.opts.current_digits_per_volt } else { self.opts.pwm_digits_per_volt };
                out.volts[ch] = digits / dpv;
            }
        }
        out
    }

    /// After each plant step: the thermal limit's update every 0.1 s.
    fn after_step(&mut self) {
        self.stats.plant_steps += 1;
        if !self.stats.plant_steps.is_multiple_of(self.heat_every) {
            return;
        }
        let period_s = self.period.as_secs_f64();
        for ch in 0..MAX_CHANNELS {
            let dc = (self.counts.counts[ch] - self.prev_counts[ch]) as f64;
            let speed = dc / self.opts.counts_per_rev / period_s;
            self.heat[ch].update(self.driven[ch].1, speed);
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
    /// The pty the link points at now (the serving thread's), for removing the link at the end.
    pty: Mutex<Option<PathBuf>>,
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
    /// The boards hear nothing and answer nothing until unset (a cut cable): they hold their
    /// last command meanwhile.
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
    symlink: PathBuf,
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
    #[error("emulator: cannot create the link {path}: {source} (choose another path with --symlink)")]
    Link { path: String, source: std::io::Error },
    #[error("emulator: will not replace {path}: {why}")]
    LinkTaken { path: String, why: String },
    #[error("emulator: the private directory {path} cannot be used: {why}")]
    PrivateDir { path: String, why: String },
}

/// An open pty master and the path of its slave.
struct Pty {
    master: OwnedFd,
    /// The emulator keeps the slave open too, so the master does not read EIO while no host is
    /// attached. Closed with the master when the pty is dropped.
    _slave: OwnedFd,
    path: PathBuf,
}

impl Pty {
    fn open() -> Result<Pty, std::io::Error> {
        let mut master = -1;
        let mut slave = -1;
        // SAFETY: openpty writes two descriptors; the null name/termios/winsize are allowed.
        let r = unsafe {
            libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null(), std::ptr::null())
        };
        if r != 0 {
            return Err(std::io::Error::last_os_error());
        }
        // SAFETY: both descriptors were just opened and belong to nothing else.
        let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        let mut name = [0 as libc::c_char; 128];
        // SAFETY: the buffer and its length are valid.
        let r = unsafe { libc::ptsname_r(master.as_raw_fd(), name.as_mut_ptr(), name.len()) };
        if r != 0 {
            return Err(std::io::Error::from_raw_os_error(r));
        }
        // SAFETY: ptsname_r wrote a NUL-terminated name into `name`.
        let path = PathBuf::from(unsafe { CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned());
        // Raw, binary-transparent: no echo, no line discipline (the host sets the same).
        // SAFETY: valid descriptors; termios is plain data.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            if libc::tcgetattr(slave.as_raw_fd(), &mut t) == 0 {
                libc::cfmakeraw(&mut t);
                libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t);
            }
            let flags = libc::fcntl(master.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        Ok(Pty { master, _slave: slave, path })
    }

    fn fd(&self) -> libc::c_int {
        self.master.as_raw_fd()
    }
}

impl Emulator {
    /// Starts the boards in front of `rig` on a new pty, reachable at `link` (a symlink that
    /// survives reconnects). Only a dangling link to a pty (an emulator that was killed) is
    /// replaced; anything else at `link` is refused ([`symlink::claim`]).
    pub fn spawn(rig: SimRig, opts: EmulatorOptions, link: &Path) -> Result<Emulator, EmulatorError> {
        let opts_fifo = opts.fifo_priority;
        let boards = Boards::new(rig, opts).map_err(EmulatorError::Config)?;
        symlink::claim(link)?;
        let pty = Pty::open().map_err(EmulatorError::Pty)?;
        symlink::publish(link, &pty.path)?;
        let faults = Arc::new(Faults::default());
        *faults.pty.lock().unwrap_or_else(|p| p.into_inner()) = Some(pty.path.clone());
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
        Ok(Emulator { symlink: link.to_path_buf(), control, thread: Some(thread) })
    }

    /// The stable path a host opens (a symlink to the current pty).
    pub fn symlink(&self) -> &Path {
        &self.symlink
    }

    /// The pty the link points at now.
    pub fn pty_path(&self) -> Option<PathBuf> {
        std::fs::read_link(&self.symlink).ok()
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
        // Also when the serving thread panicked: the link goes if it still points at our pty.
        if let Some(p) = self.control.faults.pty.lock().unwrap_or_else(|p| p.into_inner()).take() {
            symlink::remove_if_ours(&self.symlink, &p);
        }
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
            if let Some(p) = pty.take() {
                symlink::remove_if_ours(&link, &p.path);
            } // dropping the pty closes the master, which hangs up the host's end
            *f.pty.lock().unwrap_or_else(|p| p.into_inner()) = None;
            f.connected.store(false, Ordering::SeqCst);
        }
        if f.reconnect.swap(false, Ordering::SeqCst) && pty.is_none() {
            if let Ok(p) = Pty::open() {
                if symlink::claim(&link).and_then(|()| symlink::publish(&link, &p.path)).is_ok() {
                    control.boards().reset_link();
                    *f.pty.lock().unwrap_or_else(|p| p.into_inner()) = Some(p.path.clone());
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
        let mut pfd = libc::pollfd { fd: p.fd(), events: libc::POLLIN, revents: 0 };
        let n = unsafe { libc::poll(&mut pfd, 1, timeout_ms) };
        if n > 0 && pfd.revents & libc::POLLIN != 0 {
            let r = unsafe { libc::read(p.fd(), inbuf.as_mut_ptr().cast(), inbuf.len()) };
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
                    write_all_nonblocking(p.fd(), &out);
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
