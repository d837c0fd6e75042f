//! The simulated SPIDAR-H: a full plant behind the `Device` trait.
//!
//! Why it exists: without hardware everything (the rt-loop, the tools, hardware-in-the-loop
//! tests through the board emulator) runs against this rig, so it has to behave like the real
//! one in the ways the software above depends on: DA volts become string tensions within the
//! motor's limits, strings pull a grip held by a simulated user's hand, and encoders report the
//! string lengths quantised to counts, with optional noise, slack and motor lag. Ground truth
//! (true grip positions, tensions and forces) is exposed for tests, which is what the real rig
//! can never give.
//!
//! What it must never do: allocate, lock, panic or read the wall clock inside
//! [`Device::exchange`] (it runs in the 1 kHz tick, which a test checks under a failing
//! allocator), or give different results for the same seed, parameters, scripts and inputs
//! (tests pin digests of whole runs). All allocation (scripts, trajectory files) happens in
//! [`SimRig::new`] and [`SimRig::set_script`].
//!
//! Frame: the rig frame (metres, y up, origin at the centre of the workspace, the user facing
//! -z).
//!
//! # Plant semantics
//! - [`Device::exchange`] fails with `WrongState` before [`Device::open`]. Otherwise it first
//!   samples the encoders of the *current* state (as a real board samples on request): for
//!   string i, `counts = floor((length + slack - length_at_zero_m) / metres_per_count + noise)`
//!   where `noise` is gaussian with std dev `encoder_noise_counts` (drawn only when that is
//!   positive) and `slack = slack_length_m * (1 - tension / slack_tension_n)` while the
//!   string's actual tension is below `slack_tension_n` (a sagging string looks reeled out).
//!   Counts of unused channels are 0; `status` bit 0 ([`STATUS_ACTIVE`]) is set while active.
//! - It then latches the commands: volts clipped to `+-board_volts_max` (NaN reads as 0),
//!   `tension = volts / volts_per_newton` clamped to `[0, tension_max_n]` (strings cannot
//!   push); all zero while not active. They are held for the whole period (zero-order hold).
//! - It then advances the plant by `period_s` in `substeps` steps of semi-implicit Euler
//!   (velocity first, then position with the new velocity). Per substep and hand, motor tension
//!   first moves toward its command by the exact first-order update
//!   `t += (cmd - t) (1 - exp(-h / motor_time_constant_s))` (ideal when the constant is 0),
//!   then `m a = sum_i t_i u_i + k_arm (x_target - x) + d_arm (v_target - v)` with `u_i` the
//!   unit vector from the grip to anchor i and the script target evaluated at the substep's
//!   start time. No gravity: the arm holds the grip's weight. The plant's time is
//!   `exchanges x period_s`, whatever the wall clock does.
//! - [`Truth`] after an exchange: time, position and velocity at the end of the period, the
//!   target at that time, and tensions and forces of the period's last substep.
//! - `open` marks the board open and inactive with zero commands; counts are absolute (the
//!   counter reads 0 at `length_at_zero_m`, which is what the rig config says), so they
//!   correspond to the current true lengths at once. The plant keeps running through
//!   open/close. `activate`/`deactivate` enable/disable the outputs (`deactivate` zeroes the
//!   commands at once).
//! - Fault injection ([`SimRig::fail_next`]): a failing exchange leaves `inp` untouched,
//!   ignores `out` (the command did not reach the board) and advances the plant with the last
//!   command held, as time goes on in the real world: no board has a watchdog.
//! - [`SimRig::sample`] and [`SimRig::apply`] are the two halves of an exchange, for the board
//!   emulator, whose boards answer a command with the counts they have before taking it.
//!
//! Scripts ([`Script`]) say where the simulated user wants each hand; see [`script`].

pub mod script;
#[cfg(test)]
pub(crate) mod tests;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use thiserror::Error;

use crate::{short_string, Device, DeviceError, DeviceInfo, Input, Output, MAX_CHANNELS};
pub use script::{
    builtin_script, Recorded, Script, ScriptCursor, ScriptFile, Segment, Target, TrajectorySample,
    BUILTIN_SCRIPTS,
};

/// `Input::status` bit set while the outputs are enabled.
pub const STATUS_ACTIVE: u32 = 1;

/// One string: motor, pulley and encoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimString {
    /// Where the string leaves the frame (its pulley), rig frame.
    pub anchor_m: DVec3,
    /// DA/counter channel index (< `MAX_CHANNELS`), distinct across the rig.
    pub channel: usize,
    /// Signed: `counts = floor((length_m - length_at_zero_m) / metres_per_count)`.
    pub metres_per_count: f64,
    /// String length when the counter reads 0.
    pub length_at_zero_m: f64,
    /// Signed (winding direction): commanded `tension_n = volts / volts_per_newton`.
    pub volts_per_newton: f64,
    /// Motor limit; tension is clamped to `[0, tension_max_n]`.
    pub tension_max_n: f64,
}

/// One hand: its 4 strings and the simulated user's arm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimHandParams {
    pub strings: [SimString; 4],
    /// Where the grip starts, at rest; also where its script starts.
    pub start_m: DVec3,
    /// Grip plus effective hand mass.
    pub mass_kg: f64,
    /// Arm stiffness toward the script target.
    pub arm_k_n_per_m: f64,
    /// Arm damping on (target velocity - hand velocity).
    pub arm_d_n_s_per_m: f64,
}

impl SimHandParams {
    pub const DEFAULT_MASS_KG: f64 = 1.0;
    pub const DEFAULT_ARM_K_N_PER_M: f64 = 200.0;
    pub const DEFAULT_ARM_D_N_S_PER_M: f64 = 20.0;

    /// A hand with the default arm (1 kg, 200 N/m, 20 N s/m).
    pub fn new(strings: [SimString; 4], start_m: DVec3) -> SimHandParams {
        SimHandParams {
            strings,
            start_m,
            mass_kg: Self::DEFAULT_MASS_KG,
            arm_k_n_per_m: Self::DEFAULT_ARM_K_N_PER_M,
            arm_d_n_s_per_m: Self::DEFAULT_ARM_D_N_S_PER_M,
        }
    }
}

/// Everything about the simulated rig except the scripts.
#[derive(Clone, Debug, PartialEq)]
pub struct SimRigParams {
    pub hands: [SimHandParams; 2],
    /// Plant time advanced per exchange.
    pub period_s: f64,
    /// Semi-implicit Euler substeps per period.
    pub substeps: u32,
    /// Std dev of gaussian encoder noise, in counts, added before quantisation; 0 = off.
    pub encoder_noise_counts: f64,
    /// Below this actual tension a string sags; 0 = off.
    pub slack_tension_n: f64,
    /// Extra length the encoder sees at zero tension (linearly less up to `slack_tension_n`).
    pub slack_length_m: f64,
    /// First-order lag of tension toward its command; 0 = ideal motors.
    pub motor_time_constant_s: f64,
    /// DA range is `+-board_volts_max`.
    pub board_volts_max: f64,
    /// Seeds the encoder noise.
    pub seed: u64,
}

impl SimRigParams {
    /// 1 kHz, 10 substeps, no noise, no slack, ideal motors, +-10 V, seed 0.
    pub fn with_defaults(hands: [SimHandParams; 2]) -> SimRigParams {
        SimRigParams {
            hands,
            period_s: 0.001,
            substeps: 10,
            encoder_noise_counts: 0.0,
            slack_tension_n: 0.0,
            slack_length_m: 0.0,
            motor_time_constant_s: 0.0,
            board_volts_max: 10.0,
            seed: 0,
        }
    }

    /// The lab's human-scale two-hand rig (docs/reference.md section 1): hand 0 on channels
    /// 0-3, hand 1 on 4-7, 2.924e-5 m per count, 0.2 V/N, 20 N motors, counters zeroed with
    /// the grip at the origin (the lab's homing), grips starting at `start_m`.
    pub fn lab(start_m: [DVec3; 2]) -> SimRigParams {
        const ANCHORS: [[[f64; 3]; 4]; 2] = [
            [[-1.75, 2.00, 1.12], [1.65, 2.17, -1.34], [-1.65, -0.90, -1.44], [1.65, -0.99, 0.50]],
            [[1.58, 2.00, 1.12], [-1.65, 2.18, -1.34], [1.65, -0.98, -1.44], [-1.65, -0.98, 0.50]],
        ];
        let hand = |h: usize| {
            let strings = core::array::from_fn(|i| {
                let anchor_m = DVec3::from(ANCHORS[h][i]);
                SimString {
                    anchor_m,
                    channel: 4 * h + i,
                    metres_per_count: 2.924062107079e-5,
                    length_at_zero_m: anchor_m.length(),
                    volts_per_newton: 0.2,
                    tension_max_n: 20.0,
                }
            });
            SimHandParams::new(strings, start_m[h])
        };
        SimRigParams::with_defaults([hand(0), hand(1)])
    }
}

/// Ground truth of one hand.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandTruth {
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
    /// Script target (plus any push offset) at `Truth::t_s`.
    pub target_m: DVec3,
    /// Actual string tensions applied in the last substep.
    pub tension_n: [f64; 4],
    /// Net force of the strings on the grip: `sum t_i unit(anchor_i - pos)`.
    pub string_force_n: DVec3,
    /// Force of the arm on the grip.
    pub arm_force_n: DVec3,
}

/// Ground truth of the rig (valid after construction, updated by every exchange).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Truth {
    /// Plant time: exchanges so far x period.
    pub t_s: f64,
    pub hands: [HandTruth; 2],
}

/// Set-up errors of the simulated rig and its scripts.
#[derive(Debug, Error)]
pub enum SimRigError {
    #[error("simulated rig: {field}: {problem}")]
    InvalidParam { field: String, problem: String },
    #[error("script {script}, segment {segment}: {problem}")]
    InvalidScript { script: String, segment: usize, problem: String },
    #[error("trajectory {file}, line {line}: {problem}")]
    Trajectory { file: String, line: usize, problem: String },
    #[error("cannot read {what} {file}: {source} (check the path; relative paths are relative to the script file, or to the current directory)")]
    Io {
        file: String,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}:{line}:{column}: {message}")]
    Parse { file: String, line: usize, column: usize, message: String },
    #[error("hand index {hand} out of range: the rig has hands 0 and 1")]
    NoSuchHand { hand: usize },
}

/// Integration state of one hand.
#[derive(Clone, Debug)]
struct HandState {
    pos: DVec3,
    vel: DVec3,
    tension: [f64; 4],
    command: [f64; 4],
    cursor: ScriptCursor,
    /// Plant time at which the current script started.
    script_t0: f64,
    push_m: DVec3,
}

impl HandState {
    fn target(&mut self, script: &Script, t_s: f64) -> Target {
        self.cursor.target(script, t_s - self.script_t0)
    }
}

/// The simulated rig; see the module doc for its semantics.
#[derive(Debug)]
pub struct SimRig {
    params: SimRigParams,
    scripts: [Script; 2],
    hands: [HandState; 2],
    truth: Truth,
    info: DeviceInfo,
    rng: Pcg64Mcg,
    /// Per-substep motor update fraction, `1 - exp(-h / tau)`.
    lag_alpha: f64,
    ticks: u64,
    opened: bool,
    active: bool,
    fail_remaining: u32,
    fail_error: DeviceError,
}

impl SimRig {
    /// Validates the parameters and scripts (loading any trajectory files, relative to the
    /// current directory) and puts both grips at rest at their start positions.
    pub fn new(params: SimRigParams, mut scripts: [Script; 2]) -> Result<SimRig, SimRigError> {
        validate(&params)?;
        for (i, s) in scripts.iter_mut().enumerate() {
            s.prepare(std::path::Path::new(""), &format!("hand {i}"))?;
        }
        let tau = params.motor_time_constant_s;
        let h = params.period_s / f64::from(params.substeps);
        let lag_alpha = if tau > 0.0 { 1.0 - (-h / tau).exp() } else { 1.0 };
        let max_channel = params.hands.iter().flat_map(|hp| hp.strings.iter().map(|s| s.channel)).max();
        let info = DeviceInfo {
            board: short_string("simulated SPIDAR-H"),
            identity: short_string(&format!("sim seed {}", params.seed)),
            channels: max_channel.map_or(0, |c| c + 1),
            volts_min: -params.board_volts_max,
            volts_max: params.board_volts_max,
        };
        let hand = |hp: &SimHandParams| HandState {
            pos: hp.start_m,
            vel: DVec3::ZERO,
            tension: [0.0; 4],
            command: [0.0; 4],
            cursor: ScriptCursor::new(hp.start_m),
            script_t0: 0.0,
            push_m: DVec3::ZERO,
        };
        let hands = [hand(&params.hands[0]), hand(&params.hands[1])];
        let mut rig = SimRig {
            rng: Pcg64Mcg::seed_from_u64(params.seed),
            params,
            scripts,
            hands,
            truth: Truth::default(),
            info,
            lag_alpha,
            ticks: 0,
            opened: false,
            active: false,
            fail_remaining: 0,
            fail_error: DeviceError::Other { what: "injected fault" },
        };
        for h in 0..2 {
            rig.update_truth(h, [0.0; 4], DVec3::ZERO, DVec3::ZERO);
        }
        rig.update_targets();
        Ok(rig)
    }

    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    pub fn params(&self) -> &SimRigParams {
        &self.params
    }

    pub fn script(&self, hand: usize) -> Option<&Script> {
        self.scripts.get(hand)
    }

    /// Exchanges so far (each advanced the plant by `period_s`).
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Replaces a hand's script; it starts now, from the hand's current target. Trajectory
    /// files are loaded relative to the current directory.
    ///
    /// Panics on a hand index other than 0 or 1 or an invalid script; use
    /// [`SimRig::try_set_script`] for scripts from users.
    pub fn set_script(&mut self, hand: usize, script: Script) {
        if let Err(e) = self.try_set_script(hand, script) {
            panic!("SimRig::set_script: {e}");
        }
    }

    /// [`SimRig::set_script`] that reports bad scripts and hands instead of panicking.
    pub fn try_set_script(&mut self, hand: usize, mut script: Script) -> Result<(), SimRigError> {
        if hand >= 2 {
            return Err(SimRigError::NoSuchHand { hand });
        }
        script.prepare(std::path::Path::new(""), &format!("hand {hand}"))?;
        let from = self.truth.hands[hand].target_m - self.hands[hand].push_m;
        let st = &mut self.hands[hand];
        st.cursor.reset(from);
        st.script_t0 = self.truth.t_s;
        self.scripts[hand] = script;
        self.update_targets();
        Ok(())
    }

    /// Fault injection: the next `n` exchanges fail with `error`; their outputs are not applied
    /// and the plant advances with the last command held (the boards have no watchdog).
    /// `n = 0` cancels pending failures.
    pub fn fail_next(&mut self, n: u32, error: DeviceError) {
        self.fail_remaining = n;
        self.fail_error = error;
    }

    /// An external push: the hand's arm target is offset by `offset_m` from the script (until
    /// set again; `DVec3::ZERO` removes it). Out-of-range hands are ignored.
    pub fn set_push(&mut self, hand: usize, offset_m: DVec3) {
        if let Some(st) = self.hands.get_mut(hand) {
            if offset_m.is_finite() {
                st.push_m = offset_m;
            }
        }
        self.update_targets();
    }

    /// The first half of an exchange: the encoders of the current state, without advancing
    /// (what a board answers before it takes its command).
    pub fn sample(&mut self, inp: &mut Input) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "sample before open")?;
        self.sample_encoders(inp);
        Ok(())
    }

    /// The second half of an exchange: latch `out` and advance the plant by one period.
    /// [`SimRig::sample`] then [`SimRig::apply`] is exactly one [`Device::exchange`].
    pub fn apply(&mut self, out: &Output) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "apply before open")?;
        self.latch_commands(Some(out));
        self.advance();
        Ok(())
    }

    /// True string length of string `i` of `hand` (rig geometry, no slack).
    pub fn true_length_m(&self, hand: usize, i: usize) -> f64 {
        (self.params.hands[hand].strings[i].anchor_m - self.hands[hand].pos).length()
    }

    fn sample_encoders(&mut self, inp: &mut Input) {
        inp.counts = [0; MAX_CHANNELS];
        let p = &self.params;
        for (hp, st) in p.hands.iter().zip(self.hands.iter()) {
            for (s, &tension) in hp.strings.iter().zip(st.tension.iter()) {
                let mut length = (s.anchor_m - st.pos).length();
                if p.slack_tension_n > 0.0 && tension < p.slack_tension_n {
                    length += p.slack_length_m * (1.0 - tension / p.slack_tension_n);
                }
                let mut c = (length - s.length_at_zero_m) / s.metres_per_count;
                if p.encoder_noise_counts > 0.0 {
                    let z: f64 = self.rng.sample(StandardNormal);
                    c += z * p.encoder_noise_counts;
                }
                // `as` saturates (NaN -> 0), so this cannot panic whatever the state.
                if let Some(slot) = inp.counts.get_mut(s.channel) {
                    *slot = c.floor() as i64;
                }
            }
        }
        inp.status = if self.active { STATUS_ACTIVE } else { 0 };
    }

    fn latch_commands(&mut self, out: Option<&Output>) {
        let vmax = self.params.board_volts_max;
        for (hp, st) in self.params.hands.iter().zip(self.hands.iter_mut()) {
            for (s, cmd) in hp.strings.iter().zip(st.command.iter_mut()) {
                *cmd = match out {
                    Some(out) if self.active => {
                        let v = out.volts.get(s.channel).copied().unwrap_or(0.0);
                        let t = crate::clamp_symmetric(v, vmax) / s.volts_per_newton;
                        // Never panics: a NaN tension (a zero scale) or a NaN or negative motor
                        // limit is no tension.
                        if t.is_nan() || s.tension_max_n.is_nan() || s.tension_max_n < 0.0 {
                            0.0
                        } else {
                            t.clamp(0.0, s.tension_max_n)
                        }
                    }
                    _ => 0.0,
                };
            }
        }
    }

    fn advance(&mut self) {
        let n = self.params.substeps;
        let h = self.params.period_s / f64::from(n);
        let t0 = self.ticks as f64 * self.params.period_s;
        for hand in 0..2 {
            let hp = self.params.hands[hand];
            let st = &mut self.hands[hand];
            let script = &self.scripts[hand];
            let mut string_f = DVec3::ZERO;
            let mut arm_f = DVec3::ZERO;
            for k in 0..n {
                let t = t0 + f64::from(k) * h;
                for (tn, cmd) in st.tension.iter_mut().zip(st.command.iter()) {
                    *tn += (cmd - *tn) * self.lag_alpha;
                }
                string_f = string_force(&hp, st.pos, &st.tension);
                let target = st.target(script, t);
                arm_f = hp.arm_k_n_per_m * (target.pos_m + st.push_m - st.pos)
                    + hp.arm_d_n_s_per_m * (target.vel_m_per_s - st.vel);
                st.vel += (string_f + arm_f) * (h / hp.mass_kg);
                st.pos += st.vel * h;
            }
            let tension = st.tension;
            self.update_truth(hand, tension, string_f, arm_f);
        }
        self.ticks += 1;
        self.truth.t_s = self.ticks as f64 * self.params.period_s;
        self.update_targets();
    }

    /// Truth targets at `truth.t_s`.
    fn update_targets(&mut self) {
        for (hand, st) in self.hands.iter_mut().enumerate() {
            let target = st.target(&self.scripts[hand], self.truth.t_s);
            self.truth.hands[hand].target_m = target.pos_m + st.push_m;
        }
    }

    /// Truth of one hand after a period, except its target.
    fn update_truth(&mut self, hand: usize, tension: [f64; 4], string_f: DVec3, arm_f: DVec3) {
        let st = &self.hands[hand];
        self.truth.hands[hand] = HandTruth {
            pos_m: st.pos,
            vel_m_per_s: st.vel,
            target_m: self.truth.hands[hand].target_m,
            tension_n: tension,
            string_force_n: string_f,
            arm_force_n: arm_f,
        };
    }
}

/// Net force of the strings on a grip at `pos`.
fn string_force(hp: &SimHandParams, pos: DVec3, tension: &[f64; 4]) -> DVec3 {
    hp.strings
        .iter()
        .zip(tension.iter())
        // A grip exactly at a pulley has no string direction: that string pulls nothing.
        .map(|(s, t)| (s.anchor_m - pos).normalize_or_zero() * *t)
        .sum()
}

impl Device for SimRig {
    fn open(&mut self) -> Result<(), DeviceError> {
        self.opened = true;
        self.active = false;
        self.latch_commands(None);
        Ok(())
    }

    fn activate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "activate before open")?;
        self.active = true;
        Ok(())
    }

    fn deactivate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "deactivate before open")?;
        self.active = false;
        self.latch_commands(None);
        Ok(())
    }

    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "exchange before open")?;
        if self.fail_remaining > 0 {
            self.fail_remaining -= 1;
            self.advance();
            return Err(self.fail_error);
        }
        self.sample_encoders(inp);
        self.latch_commands(Some(out));
        self.advance();
        Ok(())
    }

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The simulated board never really goes away: a reopen succeeds at once (the plant kept running).
    fn reopen(&mut self, _budget: std::time::Duration) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "reopen before open")?;
        Ok(())
    }
}

fn validate(p: &SimRigParams) -> Result<(), SimRigError> {
    let bad = |field: String, problem: String| Err(SimRigError::InvalidParam { field, problem });
    let positive = |field: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            bad(field.to_owned(), format!("{v} must be a finite number > 0"))
        }
    };
    let non_negative = |field: &str, v: f64| {
        if v.is_finite() && v >= 0.0 {
            Ok(())
        } else {
            bad(field.to_owned(), format!("{v} must be a finite number >= 0"))
        }
    };
    positive("period_s", p.period_s)?;
    if p.substeps == 0 || p.substeps > 10_000 {
        return bad("substeps".into(), format!("{} must be between 1 and 10000", p.substeps));
    }
    non_negative("encoder_noise_counts", p.encoder_noise_counts)?;
    non_negative("slack_tension_n", p.slack_tension_n)?;
    non_negative("slack_length_m", p.slack_length_m)?;
    non_negative("motor_time_constant_s", p.motor_time_constant_s)?;
    positive("board_volts_max", p.board_volts_max)?;
    let mut used = [None::<(usize, usize)>; MAX_CHANNELS];
    for (h, hp) in p.hands.iter().enumerate() {
        let f = |name: &str| format!("hands[{h}].{name}");
        if !hp.start_m.is_finite() {
            return bad(f("start_m"), format!("{} is not finite", hp.start_m));
        }
        positive(&f("mass_kg"), hp.mass_kg)?;
        non_negative(&f("arm_k_n_per_m"), hp.arm_k_n_per_m)?;
        non_negative(&f("arm_d_n_s_per_m"), hp.arm_d_n_s_per_m)?;
        for (i, s) in hp.strings.iter().enumerate() {
            let f = |name: &str| format!("hands[{h}].strings[{i}].{name}");
            if !s.anchor_m.is_finite() {
                return bad(f("anchor_m"), format!("{} is not finite", s.anchor_m));
            }
            if !s.length_at_zero_m.is_finite() {
                return bad(f("length_at_zero_m"), format!("{} is not finite", s.length_at_zero_m));
            }
            for (name, v) in
                [("metres_per_count", s.metres_per_count), ("volts_per_newton", s.volts_per_newton)]
            {
                if !v.is_finite() || v == 0.0 {
                    return bad(
                        f(name),
                        format!("{v} must be finite and non-zero (its sign is the direction)"),
                    );
                }
            }
            non_negative(&f("tension_max_n"), s.tension_max_n)?;
            let Some(slot) = used.get_mut(s.channel) else {
                return bad(
                    f("channel"),
                    format!("{} is out of range: the board has channels 0..{}", s.channel, MAX_CHANNELS - 1),
                );
            };
            if let Some((h0, i0)) = *slot {
                return bad(
                    f("channel"),
                    format!(
                        "{} is already used by hands[{h0}].strings[{i0}]; give each string its own",
                        s.channel
                    ),
                );
            }
            *slot = Some((h, i));
        }
    }
    Ok(())
}
