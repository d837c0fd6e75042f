//! One haptic tick, phase by phase: counts -> string lengths -> pose -> velocity -> render ->
//! safety -> tension allocation -> DA volts, plus the rig's lifecycle.
//!
//! `TickCore` is the computation only: no device, no clock, no channels. The loop (`runner.rs`)
//! gives it what the device read and writes what it returns, so the same code runs on the real
//! clock, on the virtual clock, and in the benchmarks. Everything here must never allocate, lock,
//! format or panic: the rig keeps pulling on a person's hands while it runs.
//!
//! Lifecycle (ros2_control's, with SPIDAR meanings):
//! - `Inactive`: device open and powered; strings held at minimum tension with zero net force;
//!   homing allowed; no rendering.
//! - `Active`: forces rendered; ramped in after activation.
//! - `Faulted`: zero net force at minimum tension from the very tick the fault is seen; the
//!   reason is kept; cleared by command, or by itself after a transient device fault.
//!   `Unconfigured` (device not open) belongs to the loop around this core.
//!
//! A single unusable reply is not a fault: a late or missing reply, a reply the device calls
//! corrupt, counts that jump further than the hand can move, or a pose whose string lengths
//! disagree holds the last output for that tick (per hand where only one hand's counts are bad)
//! and is counted; only a run of them faults. `docs/safety.md` has every rule and bound.

use glam::DVec3;
use spidar_device::{DeviceError, ErrorKind, Input, Output, MAX_CHANNELS};
use spidar_msg::{ContactModel, HandSample, HandState, HANDS, MAX_PROXIES};

use crate::kinematics::{GripSolution, Kinematics};
use crate::local::{self, Passivity};
use crate::render::{self, Rendered};
use crate::rig::{HandRig, Rig};
use crate::safety::{self, Ramp, ReturnRamp};
use crate::telemetry::{HandRecord, TickRecord};
use crate::tension::{Allocation, Allocator, Method, TensionLimits};
use crate::velocity::VelocityFilter;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Lifecycle {
    #[default]
    Unconfigured,
    Inactive,
    Active,
    Faulted,
}

impl Lifecycle {
    pub fn name(self) -> &'static str {
        match self {
            Lifecycle::Unconfigured => "unconfigured",
            Lifecycle::Inactive => "inactive",
            Lifecycle::Active => "active",
            Lifecycle::Faulted => "faulted",
        }
    }
}

/// Why the rig went to `Faulted`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FaultReason {
    /// The device exchange failed.
    Device(ErrorKind),
    /// The pose of this hand could not be computed (non-finite lengths or result).
    PoseInvalid { hand: u8 },
    /// The string lengths of this hand disagree beyond the residual limit for too long
    /// (slack string, slipped encoder, wrong anchors).
    Residual { hand: u8 },
    /// This hand's counts jumped further than the hand can move, tick after tick (corrupt
    /// replies, or an encoder that slipped).
    CountJump { hand: u8 },
}

impl FaultReason {
    /// Transient faults clear themselves after enough good ticks.
    pub fn is_transient(self) -> bool {
        matches!(
            self,
            FaultReason::Device(ErrorKind::Timeout | ErrorKind::Corrupt) | FaultReason::CountJump { .. }
        )
    }
}

impl std::fmt::Display for FaultReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FaultReason::Device(k) => write!(f, "device error ({k:?})"),
            FaultReason::PoseInvalid { hand } => write!(f, "hand {hand}: pose could not be computed"),
            FaultReason::Residual { hand } => {
                write!(
                    f,
                    "hand {hand}: string lengths disagree (slack string, slipped encoder or wrong anchors)"
                )
            }
            FaultReason::CountJump { hand } => {
                write!(
                    f,
                    "hand {hand}: counts jumped beyond any hand motion, tick after tick (corrupt replies?)"
                )
            }
        }
    }
}

/// What the control side may ask of the loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// Preset the counters' zero lengths so each grip reads its home point (Inactive; while
    /// Faulted it is kept and done when the fault clears). Done after the strings have been held
    /// at minimum tension for `HOMING_SETTLE_S`, so no string is still slack (a slack string reads
    /// long and would bake its sag into the zero length).
    Home,
    /// Start rendering forces (Inactive and homed only); force ramps in.
    Activate,
    /// Ramp force out and return to Inactive.
    Deactivate,
    /// Leave Faulted for Inactive.
    ClearFault,
    /// Ramp out, hold minimum tension briefly, switch the device off and end the loop.
    Stop,
}

/// What the loop tells the control side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    State(Lifecycle),
    Fault(FaultReason),
    Homed,
    Refused {
        command: Command,
        why: &'static str,
    },
    /// The device came back after a disconnect; the rig returns to Inactive and must be homed.
    DeviceReopened,
    /// Homing was lost (a fault during homing, a reopened device): hold both grips still at
    /// their home points and the rig homes itself after `rehome_still_s`, or send `Home`.
    HomeNeeded,
    Stopped,
}

/// Everything the rig counts; reported live and at exit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    pub ticks: u64,
    pub active_ticks: u64,
    /// Ticks whose force was clamped to the hand's limit.
    pub clamped: [u64; HANDS],
    /// Ticks whose force could not be rendered in full and was scaled back along its direction.
    pub infeasible: [u64; HANDS],
    /// Ticks where not even zero force was feasible and the box-QP fallback chose the tensions.
    pub fallback: [u64; HANDS],
    /// Ticks where a proxy stiffer than the hand's limit was softened.
    pub stiffness_limited: [u64; HANDS],
    /// Ticks where the force of an avatar-hand contact was scaled down so the rig would not give
    /// the hand back more energy than it put into the contact (`local.rs`).
    pub passivity_limited: [u64; HANDS],
    /// Non-finite forces replaced by zero.
    pub non_finite: u64,
    /// Active ticks with a stale (fading) or missing contact model.
    pub stale: u64,
    /// Ticks with the pose residual above its limit.
    pub residual_high: [u64; HANDS],
    pub faults: u64,
    pub device_errors: u64,
    /// Ticks whose exchange failed (late, missing or corrupt reply) without faulting: the last
    /// output was held for them.
    pub late_replies: u64,
    /// Replies whose counts for this hand jumped further than the hand can move (rejected).
    pub count_jumps: [u64; HANDS],
    /// Ticks this hand's output was held (any of the reasons above, or a high residual).
    pub held: [u64; HANDS],
    /// Homings the rig started by itself after homing was lost (grips held still at home).
    pub rehomes: u64,
    /// Attempts to reopen a disconnected device, and how many succeeded.
    pub reopen_attempts: u64,
    pub reopens: u64,
    /// Deadline misses (woke more than one period late), counted by the loop.
    pub misses: u64,
    pub telemetry_dropped: u64,
    /// Samples the link could not take at once (the world not draining); their impulses went
    /// with the next sample that got through.
    pub samples_dropped: u64,
    /// Samples whose impulses could not be carried either (the model changed meanwhile and the
    /// way was still full, or no world was connected).
    pub impulses_lost: u64,
    pub events_dropped: u64,
    /// Contact models received.
    pub models: u64,
}

/// Time the strings are held at minimum tension before homing takes the counts.
pub const HOMING_SETTLE_S: f64 = 0.1;

struct HandCore {
    kin: Kinematics,
    alloc: Allocator,
    vel: VelocityFilter,
    /// String length at counter zero, per string; None until homed.
    zero_m: Option<[f64; 4]>,
    /// Counts of the last accepted reply, and of the one before (homing checks they agree).
    counts: [i64; 4],
    prev_counts: [i64; 4],
    pose: GripSolution,
    /// Last pose that was valid: the safe output's string directions come from it.
    safe_pos_m: DVec3,
    bad_residual_ticks: u32,
    /// Energy reserve of the avatar-hand contact (local model).
    passivity: Passivity,
    /// Ticks since this hand's counts were last accepted (1: the previous tick), when that was,
    /// and the string lengths they gave.
    since_accept: u32,
    accept_t_s: f64,
    lengths_m: [f64; 4],
    /// Rejected count jumps in a row.
    jump_run: u32,
    /// What this hand output on its last computed tick, for holding it.
    last: HeldHand,
    /// Stillness window for the automatic re-homing: count range per string and its length.
    still_min: [i64; 4],
    still_max: [i64; 4],
    still_ticks: u32,
}

/// One hand's output of one tick, as held on a tick without usable counts.
#[derive(Clone, Copy, Default)]
struct HeldHand {
    /// False until the hand has computed an output.
    some: bool,
    /// The volts of its four channels.
    volts: [f64; 4],
    rec: HandRecord,
    state: HandState,
    impulses: [DVec3; MAX_PROXIES],
    contact_impulses: [DVec3; MAX_PROXIES],
}

/// The computation of one tick and the lifecycle around it.
pub struct TickCore {
    rig: Rig,
    hands: [HandCore; HANDS],
    state: Lifecycle,
    fault: Option<FaultReason>,
    /// Return to Active (not just Inactive) when a transient fault clears.
    resume_active: bool,
    /// The device was reopened after a disconnect: the fault clears after enough good ticks, to
    /// Inactive and unhomed.
    reopened: bool,
    good_ticks: u32,
    ramp: Ramp,
    /// Force comes back over a ramp after the contact model was lost (a world restarted).
    model_return: ReturnRamp,
    deactivating: bool,
    /// Ticks left before a requested homing takes the counts.
    homing_wait: Option<u32>,
    /// An activation asked for while homing was pending: done once homed.
    activate_after_homing: bool,
    /// Device errors (late, missing, corrupt replies) in a row.
    bad_reply_run: u32,
    /// Homing was lost: waiting for the grips to be held still at home (or for `Home`).
    awaiting_home: bool,
    /// Activate once the lost homing is done again (the rig was, or was about to be, active).
    activate_after_rehome: bool,
    /// `Home` arrived while faulted: home as soon as the fault clears.
    home_after_fault: bool,
    model: Option<ContactModel>,
    counters: Counters,
    events: heapless::Deque<Event, 16>,
}

impl TickCore {
    /// Builds the core for a validated rig; allocates here and never again.
    pub fn new(rig: &Rig) -> Result<TickCore, crate::RtError> {
        let mk = |h: usize, hr: &HandRig| -> Result<HandCore, crate::RtError> {
            let kin = Kinematics::new(hr.anchors_m)
                .map_err(|e| crate::RtError::Geometry { hand: h, why: e.to_string() })?;
            let alloc = Allocator::new(TensionLimits { min_n: hr.tension_min_n, max_n: hr.tension_max_n });
            Ok(HandCore {
                kin,
                alloc,
                vel: VelocityFilter::new(rig.estimation.velocity_cutoff_hz, rig.period_s),
                zero_m: hr.length_at_zero_m,
                counts: [0; 4],
                prev_counts: [0; 4],
                pose: GripSolution { pos_m: hr.home_m, residual_m: 0.0, valid: false },
                safe_pos_m: hr.home_m,
                bad_residual_ticks: 0,
                passivity: Passivity::default(),
                since_accept: 1,
                accept_t_s: 0.0,
                lengths_m: [0.0; 4],
                jump_run: 0,
                last: HeldHand::default(),
                still_min: [0; 4],
                still_max: [0; 4],
                still_ticks: 0,
            })
        };
        Ok(TickCore {
            hands: [mk(0, &rig.hands[0])?, mk(1, &rig.hands[1])?],
            rig: rig.clone(),
            state: Lifecycle::Inactive,
            fault: None,
            resume_active: false,
            reopened: false,
            good_ticks: 0,
            ramp: Ramp::new(rig.safety.ramp_in_s, rig.safety.ramp_out_s, rig.period_s),
            model_return: ReturnRamp::new(rig.safety.ramp_in_s, rig.period_s),
            deactivating: false,
            homing_wait: None,
            activate_after_homing: false,
            bad_reply_run: 0,
            awaiting_home: false,
            activate_after_rehome: false,
            home_after_fault: false,
            model: None,
            counters: Counters::default(),
            events: heapless::Deque::new(),
        })
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }
    pub fn state(&self) -> Lifecycle {
        self.state
    }
    pub fn fault(&self) -> Option<FaultReason> {
        self.fault
    }
    pub fn counters(&self) -> &Counters {
        &self.counters
    }
    pub fn counters_mut(&mut self) -> &mut Counters {
        &mut self.counters
    }
    pub fn is_homed(&self) -> bool {
        self.hands.iter().all(|h| h.zero_m.is_some())
    }
    /// Current force gain from the ramp (0 .. 1).
    pub fn ramp_gain(&self) -> f64 {
        self.ramp.gain()
    }
    /// True once a deactivation or stop has fully ramped out.
    pub fn is_quiet(&self) -> bool {
        self.state != Lifecycle::Active && self.ramp.gain() == 0.0
    }
    /// Takes the counters as read before the first tick, so homing can use them at once.
    pub fn observe_counts(&mut self, inp: &Input) {
        for (h, hr) in self.hands.iter_mut().zip(self.rig.hands.iter()) {
            h.counts = read_counts(inp, hr);
            h.prev_counts = h.counts;
        }
    }
    /// True while homing is lost and the rig waits for the grips to be held still at home.
    pub fn is_awaiting_home(&self) -> bool {
        self.awaiting_home
    }
    pub fn pop_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    fn emit(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.counters.events_dropped += 1;
        }
    }

    fn set_state(&mut self, s: Lifecycle) {
        if self.state != s {
            self.state = s;
            self.emit(Event::State(s));
        }
    }

    fn enter_fault(&mut self, why: FaultReason) {
        if self.state == Lifecycle::Faulted {
            // A disconnect outranks whatever faulted first: it forgets the homing when it clears.
            let lost = FaultReason::Device(ErrorKind::Disconnected);
            if why == lost && self.fault != Some(lost) {
                self.fault = Some(lost);
                self.emit(Event::Fault(why));
            }
            return;
        }
        if self.homing_wait.take().is_some() {
            // Homing is lost, not the operator's intent: home again (by itself once the grips are
            // held still at home) and activate if that was asked.
            self.activate_after_rehome |= std::mem::take(&mut self.activate_after_homing);
            self.lose_homing();
        }
        self.resume_active = self.state == Lifecycle::Active && !self.deactivating;
        self.deactivating = false;
        self.fault = Some(why);
        self.good_ticks = 0;
        self.ramp.cut();
        self.counters.faults += 1;
        for h in self.hands.iter_mut() {
            h.vel.reset();
            h.bad_residual_ticks = 0;
            h.jump_run = 0;
        }
        self.set_state(Lifecycle::Faulted);
        self.emit(Event::Fault(why));
    }

    /// Homing is gone (interrupted, or the counters may have restarted): wait for it again.
    fn lose_homing(&mut self) {
        if !self.awaiting_home {
            self.awaiting_home = true;
            self.emit(Event::HomeNeeded);
        }
        for h in self.hands.iter_mut() {
            h.still_ticks = 0;
        }
    }

    /// The loop reopened the device after a disconnect. Its counters may have restarted, so the
    /// homing is forgotten; the fault clears to Inactive after `fault_recovery_ticks` good ticks.
    pub fn device_reopened(&mut self) {
        self.counters.reopens += 1;
        self.emit(Event::DeviceReopened);
        if self.fault == Some(FaultReason::Device(ErrorKind::Disconnected)) {
            self.reopened = true;
            self.good_ticks = 0;
        }
    }

    fn leave_fault(&mut self, to_active: bool) {
        self.fault = None;
        if std::mem::take(&mut self.reopened) {
            for h in self.hands.iter_mut() {
                h.zero_m = None;
                h.vel.reset();
            }
            self.activate_after_rehome |= std::mem::take(&mut self.resume_active);
            self.lose_homing();
        }
        if to_active {
            self.ramp.rise();
            self.set_state(Lifecycle::Active);
        } else {
            self.set_state(Lifecycle::Inactive);
            if std::mem::take(&mut self.home_after_fault) {
                self.command(Command::Home);
            }
        }
    }

    /// Applies a command; refusals are reported as events. `Stop` is handled by the loop.
    pub fn command(&mut self, c: Command) {
        let refuse = |s: &mut Self, why| s.emit(Event::Refused { command: c, why });
        match c {
            Command::Home => {
                if self.state == Lifecycle::Faulted {
                    self.home_after_fault = true;
                    return;
                }
                if self.state != Lifecycle::Inactive {
                    return refuse(self, "homing needs the rig inactive: deactivate first");
                }
                self.awaiting_home = false;
                if self.homing_wait.is_none() {
                    self.homing_wait = Some((HOMING_SETTLE_S / self.rig.period_s).round() as u32);
                    // The pose is about to be redefined: until then it is unknown (no residual
                    // check on the old zero lengths; the safe output uses the last good pose).
                    for h in self.hands.iter_mut() {
                        h.zero_m = None;
                    }
                }
            }
            Command::Activate => match self.state {
                Lifecycle::Active if !self.deactivating => {}
                Lifecycle::Inactive if self.homing_wait.is_some() => self.activate_after_homing = true,
                Lifecycle::Active | Lifecycle::Inactive => {
                    if !self.is_homed() {
                        return refuse(self, "not homed: hold each grip at its home point and home first");
                    }
                    self.deactivating = false;
                    self.ramp.rise();
                    self.set_state(Lifecycle::Active);
                }
                _ => refuse(self, "cannot activate while faulted or unconfigured: clear the fault first"),
            },
            Command::Deactivate | Command::Stop => {
                self.resume_active = false;
                self.activate_after_homing = false;
                self.activate_after_rehome = false;
                if self.state == Lifecycle::Active {
                    self.deactivating = true;
                    self.ramp.fall();
                }
            }
            Command::ClearFault => {
                if self.state == Lifecycle::Faulted {
                    self.resume_active = false;
                    self.leave_fault(false);
                }
            }
        }
    }

    /// Counts down a pending homing while the strings hold minimum tension, then takes this
    /// tick's counts as the home point's.
    fn homing_step(&mut self, device_ok: bool) {
        let Some(left) = self.homing_wait else { return };
        if self.state != Lifecycle::Inactive || !device_ok {
            return;
        }
        if left > 0 {
            self.homing_wait = Some(left - 1);
            return;
        }
        // The grips are held still: a count that moved further than a hand can in one tick since
        // the last reply is corrupt, and homing on it would bake the error into the zero length.
        let tol = self.rig.safety.reply_jump_m;
        let mut steady = true;
        for (hi, (h, hr)) in self.hands.iter().zip(self.rig.hands.iter()).enumerate() {
            let jumped = (0..4)
                .any(|s| ((h.counts[s] - h.prev_counts[s]) as f64 * hr.metres_per_count[s]).abs() > tol);
            if jumped {
                self.counters.count_jumps[hi] += 1;
                steady = false;
            }
        }
        if !steady {
            return; // try again next tick
        }
        self.homing_wait = None;
        for (h, hr) in self.hands.iter_mut().zip(self.rig.hands.iter()) {
            h.zero_m = Some(hr.home_offsets(h.counts, hr.home_m));
            h.vel.reset();
            h.bad_residual_ticks = 0;
        }
        self.emit(Event::Homed);
        let activate = std::mem::take(&mut self.activate_after_homing);
        if std::mem::take(&mut self.activate_after_rehome) || activate {
            self.command(Command::Activate);
        }
    }

    /// While homing is lost and the rig is inactive: homes by itself once every string of both
    /// hands has stayed within `rehome_still_m` for `rehome_still_s` (the grips held still, where
    /// the operator was told to hold them: at home). The window restarts whenever a string moves
    /// more; its tolerance is at least 10 encoder counts (checked in the rig file), so encoder
    /// noise alone never keeps it from completing.
    fn rehome_step(&mut self, device_ok: bool) {
        if !self.awaiting_home
            || self.state != Lifecycle::Inactive
            || self.homing_wait.is_some()
            || !device_ok
        {
            return;
        }
        let need = (self.rig.safety.rehome_still_s / self.rig.period_s).round() as u32;
        let (tol, jump) = (self.rig.safety.rehome_still_m, self.rig.safety.reply_jump_m);
        let mut all_still = true;
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            // An unhomed hand's counts are taken as they come: a reply that disagrees with the one
            // before by more than a hand moves in a tick is corrupt (or the hand moves fast, and
            // the next replies will say so): it neither extends nor restarts the window.
            let step = |s: usize| ((h.counts[s] - h.prev_counts[s]) as f64 * hr.metres_per_count[s]).abs();
            if (0..4).any(|s| step(s) > jump) {
                self.counters.count_jumps[hi] += 1;
                all_still &= h.still_ticks >= need;
                continue;
            }
            let mut moved = h.still_ticks == 0;
            for s in 0..4 {
                let lo = h.still_min[s].min(h.counts[s]);
                let hi = h.still_max[s].max(h.counts[s]);
                if (hi - lo) as f64 * hr.metres_per_count[s].abs() > tol {
                    moved = true;
                }
            }
            if moved {
                h.still_min = h.counts;
                h.still_max = h.counts;
                h.still_ticks = 1;
            } else {
                for s in 0..4 {
                    h.still_min[s] = h.still_min[s].min(h.counts[s]);
                    h.still_max[s] = h.still_max[s].max(h.counts[s]);
                }
                h.still_ticks = h.still_ticks.saturating_add(1);
            }
            all_still &= h.still_ticks >= need;
        }
        if all_still {
            self.counters.rehomes += 1;
            self.command(Command::Home);
        }
    }

    /// True while a homing request waits for the strings to settle.
    pub fn is_homing(&self) -> bool {
        self.homing_wait.is_some()
    }

    /// Replaces the contact model (the loop keeps only the newest one it received). The energy
    /// the world's bodies put into each avatar-hand contact over the step since the last model
    /// is credited to that hand's reserve (`local.rs`).
    pub fn set_contact_model(&mut self, m: ContactModel) {
        self.counters.models += 1;
        let since_s = self.model.as_ref().map_or(0.0, |old| (m.stamp_s - old.stamp_s).clamp(0.0, 0.01));
        for (h, c) in self.hands.iter_mut().zip(m.hand_contacts.iter()) {
            h.passivity.credit(c.source_w * since_s);
        }
        self.model = Some(m);
    }

    /// The contact model in use (the newest received).
    pub fn contact_model(&self) -> Option<&ContactModel> {
        self.model.as_ref()
    }

    /// The age of the current contact model at `now_s`.
    pub fn model_age_s(&self, now_s: f64) -> Option<f64> {
        self.model.as_ref().map(|m| now_s - m.stamp_s)
    }

    /// One tick. `io` is the result of the device exchange that produced `inp`. Writes the volts
    /// for the next exchange into `out` (a held hand's are its last ones again), the message
    /// for the scene into `sample`, and the telemetry into `rec` (its timing fields are the loop's
    /// to fill).
    pub fn step(
        &mut self,
        now_s: f64,
        io: Result<(), DeviceError>,
        inp: &Input,
        out: &mut Output,
        sample: &mut HandSample,
        rec: &mut TickRecord,
    ) {
        let tick = self.counters.ticks;
        self.counters.ticks += 1;
        let dt = self.rig.period_s;
        let safety = &self.rig.safety;
        let (reply_limit, jump_m) = (safety.reply_fault_ticks.max(1), safety.reply_jump_m);
        let (residual_limit, residual_ticks) = (safety.residual_fault_m, safety.residual_fault_ticks.max(1));

        // Device health: a short run of late, missing or corrupt replies holds the last output;
        // a longer one, or any other error, faults.
        let mut hold_all = false;
        match io {
            Err(e) => {
                self.counters.device_errors += 1;
                // Recovery needs good exchanges in a row.
                self.good_ticks = 0;
                self.bad_reply_run = self.bad_reply_run.saturating_add(1);
                let tolerable = matches!(e.kind(), ErrorKind::Timeout | ErrorKind::Corrupt)
                    && self.state != Lifecycle::Faulted
                    && self.bad_reply_run < reply_limit;
                if tolerable {
                    self.counters.late_replies += 1;
                    hold_all = true;
                } else {
                    self.enter_fault(FaultReason::Device(e.kind()));
                }
            }
            Ok(()) => {
                self.bad_reply_run = 0;
                if let Some(f) = self.fault {
                    self.good_ticks = self.good_ticks.saturating_add(1);
                    let need = self.rig.safety.fault_recovery_ticks;
                    if (f.is_transient() || self.reopened) && need > 0 && self.good_ticks >= need {
                        // After a reopen the homing is gone: back to Inactive, never straight to Active.
                        let to_active = self.resume_active && !self.reopened;
                        self.leave_fault(to_active);
                    }
                }
            }
        }
        let device_ok = io.is_ok();

        // Kinematics and velocity, per hand. A hand whose counts cannot be trusted this tick is
        // held: its pose, velocity and output stay those of its last accepted tick.
        let mut fault = None;
        let mut hold = [hold_all; HANDS];
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            if !device_ok {
                h.since_accept = h.since_accept.saturating_add(1);
                continue; // keep the last pose; the safe output uses it
            }
            let counts = read_counts(inp, hr);
            let Some(zero) = h.zero_m else {
                h.prev_counts = std::mem::replace(&mut h.counts, counts);
                h.pose.valid = false;
                continue;
            };
            let mut lengths = [0.0; 4];
            for s in 0..4 {
                lengths[s] = zero[s] + counts[s] as f64 * hr.metres_per_count[s];
            }
            // The count step against the hand's motion: where the last pose and velocity put each
            // string now. A corrupt count lands centimetres away; a hand cannot.
            let periods = h.periods_since_accept(now_s, dt);
            if let Some(pred) = h.predicted_lengths(dt, periods) {
                // `reply_jump_m` per period, plus one period of the string's own predicted motion:
                // a reply is sampled when it reaches the board, up to a reply deadline away from
                // the tick's time, so a fast hand's counts may be that much ahead or behind.
                let k = f64::from(periods);
                // A NaN length is a jump too.
                let jumped = (0..4).any(|s| {
                    let tol = jump_m * k + (pred[s] - h.lengths_m[s]).abs() / k;
                    let within = (lengths[s] - pred[s]).abs() <= tol;
                    !within
                });
                if jumped {
                    self.counters.count_jumps[hi] += 1;
                    h.jump_run += 1;
                    h.since_accept = h.since_accept.saturating_add(1);
                    if h.jump_run >= reply_limit {
                        fault = Some(FaultReason::CountJump { hand: hi as u8 });
                    } else {
                        hold[hi] = true;
                    }
                    continue;
                }
            }
            h.jump_run = 0;
            let pose = h.kin.solve(&lengths, self.rig.estimation.gauss_newton_iterations);
            if !pose.valid {
                h.pose = pose;
                fault = Some(FaultReason::PoseInvalid { hand: hi as u8 });
                continue;
            }
            // The four strings' redundancy: lengths that disagree are not used.
            if pose.residual_m > residual_limit {
                self.counters.residual_high[hi] += 1;
                h.bad_residual_ticks += 1;
                h.since_accept = h.since_accept.saturating_add(1);
                if h.bad_residual_ticks >= residual_ticks {
                    h.pose = pose;
                    fault = Some(FaultReason::Residual { hand: hi as u8 });
                } else {
                    hold[hi] = true;
                }
                continue;
            }
            h.bad_residual_ticks = 0;
            h.prev_counts = std::mem::replace(&mut h.counts, counts);
            h.pose = pose;
            h.lengths_m = lengths;
            h.vel.update_after(pose.pos_m, periods);
            h.since_accept = 1;
            h.accept_t_s = now_s;
            h.safe_pos_m = pose.pos_m;
        }
        if let Some(f) = fault {
            self.enter_fault(f);
        }
        self.homing_step(device_ok);
        self.rehome_step(device_ok);

        // Render, safety, allocate, volts.
        let age = self.model_age_s(now_s);
        let stale_gain = safety::staleness_gain(
            age,
            self.rig.safety.contact_stale_after_s,
            self.rig.safety.contact_fade_s,
        );
        let ramp_gain = self.ramp.step();
        let active = self.state == Lifecycle::Active;
        // Only a model that existed and faded out counts as lost (start-up has none yet).
        let stale_gain = self.model_return.step(stale_gain, active && age.is_some());
        if active {
            self.counters.active_ticks += 1;
            if stale_gain < 1.0 {
                self.counters.stale += 1;
            }
        }
        if self.deactivating && ramp_gain == 0.0 {
            self.deactivating = false;
            self.set_state(Lifecycle::Inactive);
        }
        let gain = if active { ramp_gain * stale_gain } else { 0.0 };
        let faulted = self.state == Lifecycle::Faulted;
        let xf = self.rig.rig_to_world;
        let mut impulses = [DVec3::ZERO; MAX_PROXIES];
        let mut contact_impulses = [DVec3::ZERO; MAX_PROXIES];
        rec.tick = tick;
        rec.t_s = now_s;
        rec.state = self.state;
        rec.fault = self.fault;
        rec.gain = gain;
        rec.contact_age_s = age.unwrap_or(f64::INFINITY);
        rec.awaiting_home = self.awaiting_home;
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            // Holding repeats what the strings were told last tick: a faulted rig never holds
            // (it outputs the safe tensions from this very tick).
            if hold[hi] && !faulted && h.last.some {
                self.counters.held[hi] += 1;
                // Written again, not left in `out`: the step does not depend on what the buffer held.
                for s in 0..4 {
                    if let Some(v) = out.volts.get_mut(hr.channels[s]) {
                        *v = h.last.volts[s];
                    }
                }
                for (acc, imp) in impulses.iter_mut().zip(h.last.impulses.iter()) {
                    *acc += *imp;
                }
                for (acc, imp) in contact_impulses.iter_mut().zip(h.last.contact_impulses.iter()) {
                    *acc += *imp;
                }
                sample.hands[hi] = h.last.state;
                rec.hands[hi] = HandRecord { held: true, ..h.last.rec };
                // The held output is what the strings apply this tick: the energy reserve books
                // the hand's motion over a run of held ticks against it, not against the force
                // commanded before the run.
                h.passivity.commanded(h.last.rec.output_n);
                continue;
            }
            let pose_ok = h.pose.valid && h.zero_m.is_some() && device_ok && !hold[hi];
            let vel = if pose_ok { h.vel.velocity() } else { DVec3::ZERO };
            let mut rendered = Rendered::default();
            let mut want_rig = DVec3::ZERO;
            let mut hand_impulses = [DVec3::ZERO; MAX_PROXIES];
            // The avatar hand's contact (local model) engages the energy reserve while active.
            let engaged = active && self.model.as_ref().is_some_and(|m| m.hand_contacts[hi].touching());
            h.passivity.observe(pose_ok.then_some(h.pose.pos_m), engaged);
            if active && pose_ok {
                if let Some(m) = self.model.as_ref() {
                    let age_s = age.unwrap_or(0.0).max(0.0);
                    let pos_w = xf.point(h.pose.pos_m);
                    rendered = render::render_hand(
                        hi,
                        pos_w,
                        xf.vector(vel),
                        hr.grip_radius_m,
                        hr.stiffness_limit_n_per_m,
                        m,
                        age_s,
                        dt,
                        &mut hand_impulses,
                    );
                    let l = local::render_contact(&m.hand_contacts[hi], pos_w, hr.stiffness_limit_n_per_m);
                    rendered.stiffness_limited |= l.stiffness_limited;
                    if l.force_n != DVec3::ZERO {
                        rendered.contacts = rendered.contacts.saturating_add(1);
                    }
                    want_rig = xf.vector_to_rig(rendered.force_n + l.force_n + m.extra_force_n[hi]);
                }
            }
            if rendered.stiffness_limited {
                self.counters.stiffness_limited[hi] += 1;
            }
            let g = safety::guard(want_rig, gain, hr.force_limit_n);
            if g.non_finite {
                self.counters.non_finite += 1;
            }
            if g.clamped {
                self.counters.clamped[hi] += 1;
            }
            // Never more energy back to the hand than it put into the avatar hand's contact: the
            // guarded force is only scaled down along its direction, so the safety phase holds.
            let (command, limited) = h.passivity.limit(g.force_n, vel, dt, engaged && pose_ok);
            if limited {
                self.counters.passivity_limited[hi] += 1;
            }
            // Directions from the current pose, or from the last good one when it is not trusted.
            let dir_pos = if pose_ok { h.pose.pos_m } else { h.safe_pos_m };
            let alloc: Allocation = h.alloc.allocate(&h.kin.directions(dir_pos), command);
            h.passivity.commanded(alloc.force_n);
            // Two impulses go back per proxy (see `HandSample`). The applied one is only what the
            // user's hand really received: the rendered force after the ramp, fade, clamp and
            // allocation scaling (all along its own direction).
            let want_sq = want_rig.length_squared();
            let applied =
                if want_sq > 0.0 { (alloc.force_n.dot(want_rig) / want_sq).clamp(0.0, 1.0) } else { 0.0 };
            // The virtual contact itself acts with the loop's gain only (a stale or ramped-out
            // model must not push the world either), never limited by what the rig can display.
            // `render_hand` already dropped non-finite contacts; the check keeps a NaN gain out.
            let mut mine = [DVec3::ZERO; MAX_PROXIES];
            let mut mine_contact = [DVec3::ZERO; MAX_PROXIES];
            if rendered.contacts > 0 {
                for ((m, mc), imp) in mine.iter_mut().zip(mine_contact.iter_mut()).zip(hand_impulses.iter()) {
                    *m = *imp * applied;
                    let c = *imp * gain;
                    if c.is_finite() {
                        *mc = c;
                    }
                }
                for ((acc, acc_contact), (m, mc)) in impulses
                    .iter_mut()
                    .zip(contact_impulses.iter_mut())
                    .zip(mine.iter().zip(mine_contact.iter()))
                {
                    *acc += *m;
                    *acc_contact += *mc;
                }
            }
            match alloc.method {
                Method::Exact => {}
                Method::Scaled => self.counters.infeasible[hi] += 1,
                Method::Fallback => self.counters.fallback[hi] += 1,
            }
            for s in 0..4 {
                let ch = hr.channels[s];
                if ch < MAX_CHANNELS {
                    out.volts[ch] = alloc.tensions_n[s] * hr.volts_per_newton[s];
                }
            }
            sample.hands[hi] = HandState {
                pos_world_m: xf.point(h.pose.pos_m),
                vel_world_m_per_s: xf.vector(vel),
                force_n: xf.vector(alloc.force_n),
                valid: pose_ok,
            };
            rec.hands[hi] = HandRecord {
                pos_rig_m: h.pose.pos_m,
                vel_rig_m_per_s: vel,
                residual_m: h.pose.residual_m,
                valid: pose_ok,
                rendered_n: want_rig,
                commanded_n: command,
                output_n: alloc.force_n,
                tensions_n: alloc.tensions_n,
                scale: alloc.scale,
                method: alloc.method,
                contacts: rendered.contacts,
                clamped: g.clamped,
                stiffness_limited: rendered.stiffness_limited,
                non_finite: g.non_finite,
                reserve_j: h.passivity.reserve_j(),
                passivity_limited: limited,
                held: false,
            };
            h.last = HeldHand {
                some: true,
                volts: std::array::from_fn(|s| alloc.tensions_n[s] * hr.volts_per_newton[s]),
                rec: rec.hands[hi],
                state: sample.hands[hi],
                impulses: mine,
                contact_impulses: mine_contact,
            };
        }
        sample.tick = tick;
        sample.t_s = now_s;
        sample.model_seq = self.model.as_ref().map_or(0, |m| m.seq);
        sample.proxy_impulse_n_s = impulses;
        sample.proxy_contact_impulse_n_s = contact_impulses;
    }
}

impl HandCore {
    /// Periods since the last accepted reply: the ticks run since, or the time that passed when
    /// the loop woke late (on the real clock a late tick's counts moved for longer).
    fn periods_since_accept(&self, now_s: f64, dt_s: f64) -> u32 {
        let by_time = ((now_s - self.accept_t_s) / dt_s).round();
        // `as` saturates (and a NaN gives 0), so this never panics.
        self.since_accept.max(by_time as u32)
    }

    /// Where each string should be now, `periods` after the last accepted reply: its length
    /// then, plus the change the hand's velocity makes of it (the step is predicted, not the
    /// length, so the pose's own residual does not count as a jump). None without a velocity
    /// history (first tick, after homing or a fault).
    fn predicted_lengths(&self, dt_s: f64, periods: u32) -> Option<[f64; 4]> {
        if !(self.pose.valid && self.vel.has_history()) {
            return None;
        }
        let p = self.pose.pos_m;
        let ahead = self.kin.lengths(p + self.vel.velocity() * (dt_s * f64::from(periods)));
        let now = self.kin.lengths(p);
        Some(std::array::from_fn(|s| self.lengths_m[s] + (ahead[s] - now[s])))
    }
}

/// The counts of a hand's four channels (a channel the input lacks reads 0).
fn read_counts(inp: &Input, hr: &HandRig) -> [i64; 4] {
    hr.channels.map(|ch| inp.counts.get(ch).copied().unwrap_or(0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn core() -> TickCore {
        TickCore::new(&Rig::default_rig()).unwrap()
    }

    /// Homes and activates, running through the settle time.
    fn home_and_activate(c: &mut TickCore) {
        c.command(Command::Home);
        c.command(Command::Activate);
        run(c, (HOMING_SETTLE_S / c.rig().period_s).round() as usize + 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
    }

    fn run(c: &mut TickCore, n: usize, io: Result<(), DeviceError>) -> (Output, TickRecord) {
        let mut out = Output::default();
        let mut rec = TickRecord::default();
        let mut s = HandSample::default();
        let inp = Input::default();
        for _ in 0..n {
            let t = c.counters.ticks as f64 * 0.001;
            c.step(t, io, &inp, &mut out, &mut s, &mut rec);
        }
        (out, rec)
    }

    #[test]
    fn activation_is_refused_until_homed() {
        let mut c = core();
        c.command(Command::Activate);
        assert_eq!(c.state(), Lifecycle::Inactive);
        assert!(matches!(c.pop_event(), Some(Event::Refused { command: Command::Activate, .. })));
        c.command(Command::Home);
        c.command(Command::Activate); // waits for homing instead of being refused
        assert_eq!(c.state(), Lifecycle::Inactive);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive, "homing waits for the strings to settle");
        run(&mut c, 1, Ok(()));
        assert_eq!(c.pop_event(), Some(Event::Homed));
        assert_eq!(c.state(), Lifecycle::Active);
    }

    #[test]
    fn inactive_output_is_zero_net_force_at_minimum_tension() {
        let mut c = core();
        c.command(Command::Home);
        let (_, rec) = run(&mut c, 3, Ok(()));
        for h in &rec.hands {
            assert!(h.output_n.length() < 1e-9, "{}", h.output_n);
            let min = h.tensions_n.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!((min - 1.0).abs() < 1e-9, "{:?}", h.tensions_n);
        }
    }

    const TIMEOUT: DeviceError = DeviceError::Timeout { waited_us: 900 };

    fn reply_limit(c: &TickCore) -> usize {
        c.rig().safety.reply_fault_ticks as usize
    }

    #[test]
    fn a_run_of_late_replies_faults_and_a_transient_fault_recovers_to_active() {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        assert_eq!(c.ramp_gain(), 1.0);
        let n = reply_limit(&c);
        run(&mut c, n - 1, Err(TIMEOUT));
        assert_eq!(c.state(), Lifecycle::Active, "a short run is held, not a fault");
        let (out, rec) = run(&mut c, 1, Err(TIMEOUT));
        assert_eq!(c.state(), Lifecycle::Faulted);
        assert_eq!(c.fault(), Some(FaultReason::Device(ErrorKind::Timeout)));
        assert_eq!(rec.gain, 0.0);
        assert!(rec.hands.iter().all(|h| !h.held), "a fault is never held");
        assert!(out.volts[..8].iter().all(|v| *v >= 0.2 - 1e-12), "strings stay taut: {:?}", out.volts);
        let need = c.rig().safety.fault_recovery_ticks as usize;
        assert!((10..100).contains(&need), "recovery takes tens of ticks: {need}");
        run(&mut c, need - 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Faulted);
        run(&mut c, 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
        assert!(c.ramp_gain() < 0.01, "force ramps in again after the fault");
        let k = c.counters();
        assert_eq!((k.faults, k.device_errors, k.late_replies), (1, n as u64, n as u64 - 1));
        assert_eq!(k.held, [n as u64 - 1; 2]);
    }

    /// A wall 1 cm in front of hand 0's home, 3 cm into the fist: a large force to hold.
    fn pressing_wall(c: &TickCore) -> ContactModel {
        use spidar_msg::{Proxy, ProxyId, ProxyShape};
        let home = c.rig().rig_to_world.point(c.rig().hands[0].home_m);
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.push(Proxy {
            id: ProxyId { body: 3, part: 0 },
            shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
            k_n_per_m: 2000.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: 0b01,
        });
        m
    }

    /// One tick with explicit counts and device result; a fresh `m` when given.
    fn tick_io(
        c: &mut TickCore,
        out: &mut Output,
        m: Option<ContactModel>,
        counts: &[i64; MAX_CHANNELS],
        io: Result<(), DeviceError>,
    ) -> (HandSample, TickRecord) {
        let (mut rec, mut s) = (TickRecord::default(), HandSample::default());
        let t = c.counters.ticks as f64 * 0.001;
        if let Some(mut m) = m {
            m.stamp_s = t;
            c.set_contact_model(m);
        }
        let inp = Input { counts: *counts, status: 0 };
        c.step(t, io, &inp, out, &mut s, &mut rec);
        (s, rec)
    }

    #[test]
    fn a_late_reply_burst_shorter_than_the_limit_keeps_force_while_a_longer_one_faults() {
        let mut c = core();
        home_and_activate(&mut c);
        let m = pressing_wall(&c);
        let mut out = Output::default();
        let zero = [0i64; MAX_CHANNELS];
        for _ in 0..600 {
            tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
        }
        let (s0, r0) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
        let pressing = out;
        assert!(r0.hands[0].commanded_n.length() > 3.9, "{r0:?}");
        let n = reply_limit(&c);
        for i in 0..n - 1 {
            let (s, r) = tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
            assert_eq!(r.state, Lifecycle::Active, "burst tick {i}");
            assert_eq!(out, pressing, "the last output is held, to the volt");
            assert!(r.hands.iter().all(|h| h.held));
            assert_eq!(r.hands[0].commanded_n, r0.hands[0].commanded_n);
            assert_eq!(s.proxy_impulse_n_s, s0.proxy_impulse_n_s, "the held force is the applied one");
            assert_eq!(s.proxy_contact_impulse_n_s, s0.proxy_contact_impulse_n_s);
            assert!(s0.proxy_contact_impulse_n_s[0].length() > 0.0);
            assert_eq!(s.hands, s0.hands);
        }
        let (_, r) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
        assert!(r.state == Lifecycle::Active && !r.hands[0].held && r.hands[0].commanded_n.length() > 3.9);
        assert_eq!(c.counters().late_replies, n as u64 - 1);
        assert_eq!(c.counters().faults, 0);
        // One more than the limit: faulted on the n-th, safe at once.
        for _ in 0..n - 1 {
            tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
        }
        assert_eq!(c.state(), Lifecycle::Active);
        let (_, r) = tick_io(&mut c, &mut out, Some(m), &zero, Err(TIMEOUT));
        assert_eq!(r.state, Lifecycle::Faulted);
        assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
        assert!(r.hands[0].output_n.length() < 1e-9);
        assert_ne!(out, pressing);
        let k = c.counters();
        assert_eq!((k.faults, k.late_replies, k.device_errors), (1, 2 * n as u64 - 2, 2 * n as u64 - 1));
    }

    /// After a run of held ticks the energy reserve books the hand's motion over them against the
    /// held output (what the strings applied), not against the force commanded two ticks before
    /// the run.
    #[test]
    fn motion_over_held_ticks_is_booked_against_the_held_output() {
        let mut c = core();
        home_and_activate(&mut c);
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let at_w = c.rig().rig_to_world.point(home[0]);
        let contact = |seq: u64, f: f64| {
            let mut m = ContactModel { seq, ..Default::default() };
            m.hand_contacts[0] = spidar_msg::HandContact {
                force_n: DVec3::Z * f,
                normal: DVec3::Z,
                k_n_per_m: 0.0,
                at_m: at_w,
                source_w: 0.0,
            };
            m
        };
        let mut out = Output::default();
        let still = counts_at(&c, home);
        for _ in 0..600 {
            tick_io(&mut c, &mut out, Some(contact(1, 1.0)), &still, Ok(()));
        }
        let (_, before) = tick_io(&mut c, &mut out, Some(contact(1, 1.0)), &still, Ok(()));
        let (_, last) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &still, Ok(()));
        let (f_before, f_held) = (before.hands[0].output_n, last.hands[0].output_n);
        assert!(f_held.length() > 2.0 * f_before.length(), "{f_before} {f_held}");
        let reserve0 = last.hands[0].reserve_j;
        for _ in 0..3 {
            let (_, r) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &still, Err(TIMEOUT));
            assert!(r.hands[0].held);
        }
        // The hand went 1 mm into the held force over the held ticks.
        let d = -f_held.normalize() * 0.001;
        let moved = counts_at(&c, [home[0] + d, home[1]]);
        let (_, r) = tick_io(&mut c, &mut out, Some(contact(2, 3.0)), &moved, Ok(()));
        assert!(!r.hands[0].held && r.hands[0].valid);
        let booked = r.hands[0].reserve_j - reserve0;
        let want = -f_held.dot(d);
        assert!((booked - want).abs() < 0.1 * want, "booked {booked} J, the held force did {want} J");
    }

    /// The energy the world's bodies put into an avatar-hand contact (its power times the time
    /// since the last model) goes into that hand's reserve; a gap in the models counts for at
    /// most 10 ms (a world that was gone does not credit its absence).
    #[test]
    fn the_worlds_energy_into_a_contact_is_credited_over_the_time_between_models() {
        let mut c = core();
        home_and_activate(&mut c);
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let at_w = c.rig().rig_to_world.point(home[0]);
        let contact = |seq: u64, source_w: f64| {
            let mut m = ContactModel { seq, ..Default::default() };
            m.hand_contacts[0] = spidar_msg::HandContact {
                force_n: DVec3::Z,
                normal: DVec3::Z,
                k_n_per_m: 0.0,
                at_m: at_w,
                source_w,
            };
            m
        };
        let mut out = Output::default();
        let still = counts_at(&c, home);
        for _ in 0..600 {
            tick_io(&mut c, &mut out, Some(contact(1, 0.0)), &still, Ok(()));
        }
        let reserve = |r: &TickRecord| r.hands[0].reserve_j;
        let (_, r0) = tick_io(&mut c, &mut out, Some(contact(1, 0.0)), &still, Ok(()));
        // A model every tick (1 ms apart) at 2 W: 2 mJ each.
        let (_, r1) = tick_io(&mut c, &mut out, Some(contact(2, 2.0)), &still, Ok(()));
        assert!((reserve(&r1) - reserve(&r0) - 0.002).abs() < 1e-9, "{} -> {}", reserve(&r0), reserve(&r1));
        // Two ticks without a model, then one: 3 ms at 2 W.
        tick_io(&mut c, &mut out, None, &still, Ok(()));
        tick_io(&mut c, &mut out, None, &still, Ok(()));
        let (_, r2) = tick_io(&mut c, &mut out, Some(contact(3, 2.0)), &still, Ok(()));
        assert!((reserve(&r2) - reserve(&r1) - 0.006).abs() < 1e-9, "{} -> {}", reserve(&r1), reserve(&r2));
        // 20 ticks without a model (late, not yet stale: still engaged), then one: 21 ms, of
        // which 10 count.
        for _ in 0..20 {
            tick_io(&mut c, &mut out, None, &still, Ok(()));
        }
        let (_, r3) = tick_io(&mut c, &mut out, Some(contact(4, 2.0)), &still, Ok(()));
        assert!((reserve(&r3) - reserve(&r2) - 0.02).abs() < 1e-9, "{} -> {}", reserve(&r2), reserve(&r3));
    }

    /// After a late reply the count step's tolerance covers two periods of the hand's motion, and
    /// the string's own predicted motion over one period (not over two, or four): a corrupt count
    /// just beyond that is rejected on the tick it arrives, one just within it is taken.
    #[test]
    fn after_a_late_reply_a_count_just_beyond_the_fast_hands_tolerance_is_rejected() {
        let dt = 0.001;
        let v = DVec3::new(2.0, 0.0, 0.0); // a fast punch: 2 mm per tick
                                           // The string that moves most per tick, and how much.
        let probe = core();
        let hr = probe.rig().hands[0].clone();
        let home = hr.home_m;
        let len = |p: DVec3, s: usize| (hr.anchors_m[s] - p).length();
        let (s_max, m) = (0..4)
            .map(|s| (s, (len(home + v * dt, s) - len(home, s)).abs()))
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        assert!(m > 0.001, "{m}");
        let jump = probe.rig().safety.reply_jump_m;
        // Run a hand at constant speed, one late reply, then a reply off by `err_m` on s_max.
        let taken = |err_m: f64| {
            let mut c = core();
            home_and_activate(&mut c);
            let other = c.rig().hands[1].home_m;
            let mut out = Output::default();
            for i in 0..100 {
                let counts = counts_at(&c, [home + v * (dt * i as f64), other]);
                tick_io(&mut c, &mut out, None, &counts, Ok(()));
            }
            let counts = counts_at(&c, [home + v * (dt * 100.0), other]);
            tick_io(&mut c, &mut out, None, &counts, Err(TIMEOUT));
            let p = home + v * (dt * 101.0);
            let mut counts = counts_at(&c, [p, other]);
            counts[hr.channels[s_max]] += (err_m / hr.metres_per_count[s_max]).round() as i64;
            let jumps = c.counters().count_jumps[0];
            let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
            assert_eq!(r.state, Lifecycle::Active);
            (c.counters().count_jumps[0] == jumps, r.hands[0].held)
        };
        // Two periods of reply jump, plus one period of the string's motion (m), plus half a
        // period more: beyond; half a period less: within.
        assert_eq!(taken(2.0 * jump + 1.5 * m), (false, true), "rejected, held");
        assert_eq!(taken(2.0 * jump + 0.5 * m), (true, false), "taken");
    }

    /// An avatar-hand contact's force is rendered as the world gives it (its direction, not only
    /// its size); a hand that moves with it while the reserve is empty has it scaled down, and
    /// every such tick is counted.
    #[test]
    fn an_avatar_hand_contact_is_rendered_as_given_and_each_passivity_limited_tick_counted() {
        let mut c = core();
        home_and_activate(&mut c);
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let f = DVec3::new(0.0, 0.5, 1.5);
        let xf = c.rig().rig_to_world;
        let contact = |p_rig: DVec3| {
            let mut m = ContactModel { seq: 1, ..Default::default() };
            m.hand_contacts[0] = spidar_msg::HandContact {
                force_n: f,
                normal: f.normalize(),
                k_n_per_m: 0.0,
                at_m: xf.point(p_rig),
                source_w: 0.0,
            };
            m
        };
        let mut out = Output::default();
        let still = counts_at(&c, home);
        let mut r = TickRecord::default();
        for _ in 0..600 {
            r = tick_io(&mut c, &mut out, Some(contact(home[0])), &still, Ok(())).1;
        }
        // World and rig axes agree here.
        assert!((r.hands[0].commanded_n - f).length() < 1e-9, "{:?}", r.hands[0]);
        assert!(!r.hands[0].passivity_limited);
        let before = c.counters().passivity_limited;
        // The hand goes along the force at 0.5 m/s: the force would give it energy it never put in.
        let mut limited = 0;
        for i in 1..=40 {
            let p = home[0] + f.normalize() * (0.0005 * i as f64);
            let counts = counts_at(&c, [p, home[1]]);
            let (_, r) = tick_io(&mut c, &mut out, Some(contact(p)), &counts, Ok(()));
            if r.hands[0].passivity_limited {
                limited += 1;
                assert!(r.hands[0].commanded_n.length() < f.length());
                assert!(r.hands[0].commanded_n.dot(f) >= 0.0, "scaled along its own direction");
            }
        }
        assert!(limited > 20, "{limited}");
        assert_eq!(c.counters().passivity_limited, [before[0] + limited, before[1]]);
    }

    /// Counts of both hands for grips at `p` (rig frame), with the zero lengths homing took at home.
    fn counts_at(c: &TickCore, p: [DVec3; 2]) -> [i64; MAX_CHANNELS] {
        let mut counts = [0i64; MAX_CHANNELS];
        for (h, hr) in c.rig().hands.iter().enumerate() {
            for s in 0..4 {
                let dl = (hr.anchors_m[s] - p[h]).length() - (hr.anchors_m[s] - hr.home_m).length();
                counts[hr.channels[s]] = (dl / hr.metres_per_count[s]).round() as i64;
            }
        }
        counts
    }

    #[test]
    fn a_corrupt_count_is_rejected_on_the_tick_it_arrives_and_a_run_of_them_faults() {
        let mut c = core();
        home_and_activate(&mut c);
        let m = pressing_wall(&c);
        let mut out = Output::default();
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        // The hands move at 1 m/s along x: each tick's counts follow them.
        let at = |k: usize| home.map(|h| h + DVec3::X * (k as f64 * 1e-3));
        let k = std::cell::Cell::new(0);
        let step = |c: &mut TickCore, out: &mut Output, corrupt: Option<(usize, i64)>| {
            let mut counts = counts_at(c, at(k.get()));
            if let Some((ch, by)) = corrupt {
                counts[ch] += by;
            }
            k.set(k.get() + 1);
            tick_io(c, out, Some(m), &counts, Ok(())).1
        };
        for _ in 0..700 {
            step(&mut c, &mut out, None);
        }
        let before = step(&mut c, &mut out, None);
        let held_out = out;
        assert!(!before.hands[0].held);
        // A reply with 4096 counts (12 cm) too many on hand 0's string 2: rejected at once.
        let r = step(&mut c, &mut out, Some((2, 4096)));
        assert!(r.hands[0].held && !r.hands[1].held, "only the hand with the bad count is held");
        assert_eq!(r.hands[0].pos_rig_m, before.hands[0].pos_rig_m);
        assert_eq!(out.volts[..4], held_out.volts[..4]);
        assert_eq!(c.counters().count_jumps, [1, 0]);
        // The next good reply is accepted, from where the hand really is now.
        let r = step(&mut c, &mut out, None);
        assert!(!r.hands[0].held);
        assert!((r.hands[0].pos_rig_m - at(k.get() - 1)[0]).length() < 1e-4, "{}", r.hands[0].pos_rig_m);
        assert!(
            (r.hands[0].vel_rig_m_per_s.x - 1.0).abs() < 0.05,
            "velocity over the skipped tick: {}",
            r.hands[0].vel_rig_m_per_s
        );
        // Small corruptions too: 200 counts (6 mm) on hand 1.
        let r = step(&mut c, &mut out, Some((5, -200)));
        assert!(r.hands[1].held && !r.hands[0].held);
        assert_eq!(c.counters().count_jumps, [1, 1]);
        assert_eq!(c.counters().faults, 0);
        // Counts that stay away (an encoder that slipped, a board that keeps garbling) fault.
        let n = reply_limit(&c);
        for _ in 0..n - 1 {
            assert_eq!(step(&mut c, &mut out, Some((0, 3000))).state, Lifecycle::Active);
        }
        let r = step(&mut c, &mut out, Some((0, 3000)));
        assert_eq!(r.fault, Some(FaultReason::CountJump { hand: 0 }));
        assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
        assert_eq!(c.counters().count_jumps, [1 + n as u64, 1]);
        assert_eq!(c.counters().held, [1 + n as u64 - 1, 1]);
    }

    #[test]
    fn a_tick_that_woke_late_is_judged_by_the_time_that_passed_not_as_a_jump() {
        let mut c = core();
        home_and_activate(&mut c);
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let (mut out, mut rec, mut s) = (Output::default(), TickRecord::default(), HandSample::default());
        // The hands move at 1 m/s along x; on the real clock.
        let mut t = c.counters.ticks as f64 * 0.001;
        let mut x = 0.0;
        let mut tick = |c: &mut TickCore, dt: f64| {
            t += dt;
            x += dt; // 1 m/s
            let inp = Input { counts: counts_at(c, home.map(|h| h + DVec3::X * x)), status: 0 };
            c.step(t, Ok(()), &inp, &mut out, &mut s, &mut rec);
            rec
        };
        for _ in 0..300 {
            tick(&mut c, 0.001);
        }
        // The loop wakes 6 ms late: the hands moved 6 mm, three times the per-tick tolerance.
        let r = tick(&mut c, 0.006);
        assert!(!r.hands[0].held && !r.hands[1].held, "{:?}", c.counters());
        assert_eq!(c.counters().count_jumps, [0, 0]);
        assert!(
            (r.hands[0].vel_rig_m_per_s.x - 1.0).abs() < 0.05,
            "velocity over the late tick: {}",
            r.hands[0].vel_rig_m_per_s
        );
    }

    #[test]
    fn a_fast_steady_hand_is_never_taken_for_a_jump_and_its_volts_are_its_tensions() {
        let mut c = core();
        home_and_activate(&mut c);
        let m = pressing_wall(&c);
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let mut out = Output::default();
        // Both hands speed up at 30 m/s^2 to 3 m/s (3 mm per tick, beyond reply_jump_m alone),
        // then sweep on: the prediction from their velocity keeps every reply.
        let along = |k: usize| {
            let t = k as f64 * 1e-3;
            if t < 0.1 {
                15.0 * t * t
            } else {
                0.15 + 3.0 * (t - 0.1)
            }
        };
        for k in 0..200 {
            let p = home.map(|h| h + DVec3::new(0.0, 1.0, -1.0).normalize() * along(k));
            let counts = counts_at(&c, p);
            let (_, r) = tick_io(&mut c, &mut out, Some(m), &counts, Ok(()));
            for (h, hr) in c.rig().hands.iter().enumerate() {
                for s in 0..4 {
                    let want = r.hands[h].tensions_n[s] * hr.volts_per_newton[s];
                    assert_eq!(out.volts[hr.channels[s]], want, "the volts written are the tensions'");
                }
            }
        }
        assert_eq!(c.counters().count_jumps, [0, 0]);
        assert_eq!(c.counters().held, [0, 0]);
    }

    #[test]
    fn a_pose_above_the_residual_limit_is_held_and_a_run_of_them_faults() {
        let mut c = core();
        home_and_activate(&mut c);
        let mut out = Output::default();
        let zero = [0i64; MAX_CHANNELS];
        for _ in 0..10 {
            tick_io(&mut c, &mut out, None, &zero, Ok(()));
        }
        // String 1 of hand 0 creeps 0.2 mm per tick (a slipping encoder): slow enough for the jump
        // check, inconsistent with the other three.
        let mpc = c.rig().hands[0].metres_per_count[1];
        let limit = c.rig().safety.residual_fault_ticks;
        let mut held = 0;
        let mut fault_at = None;
        for i in 1..400 {
            let mut counts = zero;
            counts[1] = (i as f64 * 0.2e-3 / mpc).round() as i64;
            let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
            if r.state == Lifecycle::Faulted {
                fault_at = Some(r.fault);
                break;
            }
            held += r.hands[0].held as u64;
        }
        assert_eq!(fault_at, Some(Some(FaultReason::Residual { hand: 0 })));
        assert_eq!(held, u64::from(limit) - 1, "each tick above the limit before the fault is held");
        assert_eq!(c.counters().residual_high[0], u64::from(limit));
        assert_eq!(c.counters().held, [u64::from(limit) - 1, 0]);
        assert_eq!(c.counters().count_jumps, [0, 0]);
    }

    #[test]
    fn a_faulted_rig_is_never_held_and_its_safe_output_comes_from_the_last_good_pose() {
        let mut c = core();
        home_and_activate(&mut c);
        let mut out = Output::default();
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        let away = [home[0] + DVec3::new(0.1, 0.2, 0.0), home[1]];
        let counts = counts_at(&c, away);
        for _ in 0..3 {
            let h0 = counts_at(&c, home);
            tick_io(&mut c, &mut out, None, &h0, Ok(()));
        }
        // Walk hand 0 to `away` slowly, then a reply that makes a length negative: no pose.
        for k in 1..=200 {
            let p = [home[0] + (away[0] - home[0]) * (k as f64 / 200.0), home[1]];
            let cp = counts_at(&c, p);
            tick_io(&mut c, &mut out, None, &cp, Ok(()));
        }
        let _ = counts;
        c.command(Command::Home); // refused while active: nothing changes
        let mut bad = counts_at(&c, away);
        bad[0] = -1_000_000_000;
        // Without a velocity history the jump check cannot judge it; the kinematics refuse it.
        for h in c.hands.iter_mut() {
            h.vel.reset();
        }
        let (_, r) = tick_io(&mut c, &mut out, None, &bad, Ok(()));
        assert_eq!(r.fault, Some(FaultReason::PoseInvalid { hand: 0 }));
        let h = &r.hands[0];
        assert!(!h.held && !h.valid);
        assert!(h.tensions_n.iter().all(|t| t.is_finite() && *t >= 1.0 - 1e-9 && *t <= 20.0), "{h:?}");
        assert!(h.output_n.length() < 1e-9, "zero net force at the last good pose: {}", h.output_n);
        // Those tensions balance at `away` (where the grip is), not at home.
        let dirs = c.hands[0].kin.directions(away[0]);
        let net: DVec3 = (0..4).map(|s| dirs[s] * h.tensions_n[s]).sum();
        assert!(net.length() < 1e-3, "{net}");
    }

    #[test]
    fn disconnect_is_not_transient() {
        let mut c = core();
        c.command(Command::Home);
        run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
        run(&mut c, 1000, Ok(()));
        assert_eq!(c.state(), Lifecycle::Faulted);
        c.command(Command::ClearFault);
        assert_eq!(c.state(), Lifecycle::Inactive);
    }

    #[test]
    fn deactivate_ramps_out_then_goes_inactive() {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        c.command(Command::Deactivate);
        let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
        run(&mut c, ramp_out - 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
        run(&mut c, 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive);
        assert!(c.is_quiet());
    }

    #[test]
    fn a_reopened_device_clears_the_fault_to_inactive_and_unhomed_then_rehomes_when_held_still() {
        let mut c = core();
        home_and_activate(&mut c);
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        assert_eq!(c.fault(), Some(FaultReason::Device(ErrorKind::Timeout)));
        while c.pop_event().is_some() {}
        run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
        assert_eq!(c.pop_event(), Some(Event::Fault(FaultReason::Device(ErrorKind::Disconnected))));
        run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
        run(&mut c, 10, Err(TIMEOUT));
        assert_eq!(c.pop_event(), None, "reported once");
        assert_eq!(
            c.fault(),
            Some(FaultReason::Device(ErrorKind::Disconnected)),
            "a disconnect outranks a timeout"
        );
        assert_eq!(c.counters().faults, 1, "one fault, its reason upgraded");
        c.device_reopened();
        while c.pop_event().is_some() {}
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive, "never straight back to Active after a reopen");
        assert!(!c.is_homed(), "the counters may have restarted: home again");
        assert!(c.is_awaiting_home());
        assert!(std::iter::from_fn(|| c.pop_event()).any(|e| e == Event::HomeNeeded), "the operator is told");
        c.command(Command::Activate);
        assert_eq!(c.state(), Lifecycle::Inactive);
        assert_eq!(c.counters().reopens, 1);
        // The grips are held still (the counts do not move): after rehome_still_s the rig homes
        // itself, and since it was active before the disconnect, it activates again.
        // (The window opened on the tick the fault cleared.)
        let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
        let (_, rec) = run(&mut c, still - 2, Ok(()));
        assert!(!c.is_homing() && c.counters().rehomes == 0);
        assert!(rec.awaiting_home, "the status can say what to do");
        let (_, rec) = run(&mut c, 1, Ok(()));
        assert!(!rec.awaiting_home);
        assert!(c.is_homing() && !c.is_awaiting_home());
        assert_eq!(c.counters().rehomes, 1);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        assert!(c.is_homed());
        assert_eq!(c.state(), Lifecycle::Active);
    }

    #[test]
    fn a_fault_during_homing_lets_the_rig_home_again_without_a_restart() {
        let mut c = core();
        c.command(Command::Home);
        c.command(Command::Activate);
        run(&mut c, 20, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        assert_eq!(c.state(), Lifecycle::Faulted);
        assert!(!c.is_homing() && c.is_awaiting_home());
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive);
        // The grips are moving (the operator walked away): no homing while they move.
        let mut out = Output::default();
        let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
        let mut counts = [0i64; MAX_CHANNELS];
        for i in 0..3 * still {
            counts[6] = ((i / 50) % 2) as i64 * 200; // 6 mm back and forth every 50 ms
            tick_io(&mut c, &mut out, None, &counts, Ok(()));
        }
        assert_eq!(c.counters().rehomes, 0, "a moving grip is never taken for a held one");
        // Encoder noise of a few counts does not count as motion.
        for i in 0..still + 1 {
            counts[6] = 200 + [0, 3, -2, 1][i % 4];
            tick_io(&mut c, &mut out, None, &counts, Ok(()));
        }
        assert_eq!(c.counters().rehomes, 1);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active, "the Activate that was waiting for homing is kept");
    }

    #[test]
    fn garbled_replies_neither_stop_nor_fake_the_stillness_that_rehomes() {
        let mut c = core();
        c.command(Command::Home);
        run(&mut c, 20, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert!(c.is_awaiting_home());
        // Grips held still, but every 20th reply has a count 4096 off.
        let mut out = Output::default();
        let still = (c.rig().safety.rehome_still_s / c.rig().period_s).round() as usize;
        let mut ticks = 0;
        while c.counters().rehomes == 0 {
            let mut counts = [0i64; MAX_CHANNELS];
            if ticks % 20 == 7 {
                counts[ticks % 8] = 4096;
            }
            tick_io(&mut c, &mut out, None, &counts, Ok(()));
            ticks += 1;
            assert!(ticks < 2 * still, "the garbled replies kept the rig from homing");
        }
        assert!(ticks >= still, "{ticks}");
        assert!(c.counters().count_jumps.iter().sum::<u64>() > 0);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        assert!(c.is_homed());
        assert_eq!(c.hands[0].zero_m, Some(c.rig().hands[0].home_offsets([0; 4], c.rig().hands[0].home_m)));
    }

    #[test]
    fn home_sent_while_faulted_homes_as_soon_as_the_fault_clears() {
        let mut c = core();
        c.command(Command::Home);
        run(&mut c, 20, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        c.command(Command::Home);
        assert!(!std::iter::from_fn(|| c.pop_event()).any(|e| matches!(e, Event::Refused { .. })));
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive);
        assert!(c.is_homing() && !c.is_awaiting_home());
        assert_eq!(c.counters().rehomes, 0, "asked for, not automatic");
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        assert!(c.is_homed());
        assert_eq!(c.state(), Lifecycle::Inactive, "no Activate was asked");
    }

    #[test]
    fn homing_takes_steady_counts_wherever_they_are() {
        // Counters far from zero (a board that was never reset) and a grip that trembles by 20
        // counts (0.6 mm) from one reply to the next: that is steady, homing goes ahead.
        let mut c = core();
        c.command(Command::Home);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        let mut out = Output::default();
        let mut counts = [0i64; MAX_CHANNELS];
        for (ch, n) in counts.iter_mut().enumerate() {
            *n = 100_000 + 1_000 * ch as i64;
        }
        for _ in 0..settle {
            tick_io(&mut c, &mut out, None, &counts, Ok(()));
        }
        counts[5] += 20;
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
        assert!(c.is_homed(), "a tremor is not a jump");
        assert_eq!(c.counters().count_jumps, [0, 0]);
        let h1: [i64; 4] = std::array::from_fn(|s| counts[c.rig().hands[1].channels[s]]);
        assert_eq!(c.hands[1].zero_m, Some(c.rig().hands[1].home_offsets(h1, c.rig().hands[1].home_m)));
    }

    #[test]
    fn the_rehoming_window_counts_only_good_replies_of_an_inactive_rig() {
        // Ticks until the rig re-homes itself after a fault during homing, with `spoil` applied
        // on the first ticks after the fault cleared.
        fn ticks_to_rehome(spoil: usize, err: Option<DeviceError>) -> usize {
            let mut c = core();
            c.command(Command::Home);
            run(&mut c, 20, Ok(()));
            let n = reply_limit(&c);
            run(&mut c, n, Err(TIMEOUT));
            let need = c.rig().safety.fault_recovery_ticks as usize;
            run(&mut c, need, Ok(()));
            assert_eq!(c.state(), Lifecycle::Inactive);
            let mut ticks = 0;
            if let Some(e) = err {
                run(&mut c, spoil, Err(e));
                ticks += spoil;
            }
            while c.counters().rehomes == 0 {
                run(&mut c, 1, Ok(()));
                ticks += 1;
                assert!(ticks < 5000);
            }
            ticks
        }
        let clean = ticks_to_rehome(0, None);
        // Held ticks (no reply) are not still ticks: they add to the wait.
        assert_eq!(ticks_to_rehome(4, Some(TIMEOUT)), clean + 4);
        // A faulted rig does not home by itself, however still the grips.
        let text = crate::rig::DEFAULT_RIG_RON.replace("fault_recovery_ticks: 30", "fault_recovery_ticks: 0");
        let mut c = TickCore::new(&Rig::from_str(&text, "t").unwrap()).unwrap();
        c.command(Command::Home);
        run(&mut c, 20, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        run(&mut c, 3000, Ok(()));
        assert!(c.is_awaiting_home() && c.state() == Lifecycle::Faulted);
        assert_eq!(c.counters().rehomes, 0);
        assert!(!c.is_homing());
    }

    #[test]
    fn homing_settles_on_good_replies_only() {
        let mut c = core();
        c.command(Command::Home);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle - 2, Ok(()));
        run(&mut c, 3, Err(TIMEOUT)); // held, not a fault: the settle clock waits
        assert_eq!(c.state(), Lifecycle::Inactive);
        run(&mut c, 2, Ok(()));
        assert!(c.is_homing(), "a held tick is not a settled one");
        run(&mut c, 1, Ok(()));
        assert!(c.is_homed());
    }

    #[test]
    fn homing_waits_for_two_replies_that_agree() {
        let mut c = core();
        c.command(Command::Home);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle, Ok(()));
        let mut out = Output::default();
        let mut counts = [0i64; MAX_CHANNELS];
        counts[3] = 4096; // a corrupt reply on the very tick homing takes the counts
        tick_io(&mut c, &mut out, None, &counts, Ok(()));
        assert!(c.is_homing() && c.counters().count_jumps == [1, 0]);
        tick_io(&mut c, &mut out, None, &[0; MAX_CHANNELS], Ok(()));
        assert!(c.is_homing(), "the good reply disagrees with the corrupt one before it");
        tick_io(&mut c, &mut out, None, &[0; MAX_CHANNELS], Ok(()));
        assert!(c.is_homed());
        assert_eq!(c.hands[0].zero_m, Some(c.rig().hands[0].home_offsets([0; 4], c.rig().hands[0].home_m)));
    }

    #[test]
    fn a_fault_while_inactive_or_ramping_out_never_resumes_active() {
        for ramping_out in [false, true] {
            let mut c = core();
            home_and_activate(&mut c);
            run(&mut c, 600, Ok(()));
            c.command(if ramping_out { Command::Stop } else { Command::Deactivate });
            if !ramping_out {
                run(&mut c, 400, Ok(()));
                assert_eq!(c.state(), Lifecycle::Inactive);
            } else {
                run(&mut c, 50, Ok(()));
                assert_eq!(c.state(), Lifecycle::Active, "still ramping out");
            }
            let (n, need) = (reply_limit(&c), c.rig().safety.fault_recovery_ticks as usize);
            run(&mut c, n, Err(DeviceError::Corrupt { what: "test" }));
            assert_eq!(c.state(), Lifecycle::Faulted);
            run(&mut c, need + 5, Ok(()));
            assert_eq!(c.state(), Lifecycle::Inactive, "ramping out: {ramping_out}");
            assert_eq!(c.ramp_gain(), 0.0);
        }
    }

    #[test]
    fn activate_during_a_ramp_out_ramps_back_in() {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        c.command(Command::Deactivate);
        run(&mut c, 100, Ok(()));
        let low = c.ramp_gain();
        assert!(low < 1.0 && low > 0.0);
        c.command(Command::Activate);
        let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
        run(&mut c, ramp_out, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
        assert!(c.ramp_gain() > low, "{} after {low}", c.ramp_gain());
    }

    #[test]
    fn fault_recovery_ticks_zero_never_recovers() {
        let text = crate::rig::DEFAULT_RIG_RON.replace("fault_recovery_ticks: 30", "fault_recovery_ticks: 0");
        let mut c = TickCore::new(&Rig::from_str(&text, "t").unwrap()).unwrap();
        home_and_activate(&mut c);
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        run(&mut c, 5000, Ok(()));
        assert_eq!(c.state(), Lifecycle::Faulted);
        c.command(Command::ClearFault);
        assert_eq!(c.state(), Lifecycle::Inactive);
    }

    /// One tick with a fresh `m` (stamped now); returns the sample and the record.
    fn tick_with(c: &mut TickCore, m: Option<ContactModel>) -> (HandSample, TickRecord) {
        let (mut out, mut rec, mut s) = (Output::default(), TickRecord::default(), HandSample::default());
        let t = c.counters.ticks as f64 * 0.001;
        if let Some(mut m) = m {
            m.stamp_s = t;
            c.set_contact_model(m);
        }
        c.step(t, Ok(()), &Input::default(), &mut out, &mut s, &mut rec);
        (s, rec)
    }

    /// A proxy touched with no force (zero stiffness and damping: a trigger volume) is a contact
    /// that renders nothing: the impulses sent back are zero, never NaN (0 / 0 in the applied share).
    #[test]
    fn a_contact_with_no_force_sends_zero_impulses_not_nan() {
        use spidar_msg::{Proxy, ProxyId, ProxyShape};
        let mut c = core();
        home_and_activate(&mut c);
        let home = c.rig().rig_to_world.point(c.rig().hands[0].home_m);
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.push(Proxy {
            id: ProxyId { body: 3, part: 0 },
            shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
            k_n_per_m: 0.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: 0b01,
        });
        for _ in 0..600 {
            tick_with(&mut c, Some(m));
        }
        let (s, rec) = tick_with(&mut c, Some(m));
        assert_eq!(rec.hands[0].contacts, 1, "touching: {:?}", rec.hands[0]);
        assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO);
        assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
    }

    #[test]
    fn contact_impulse_is_the_rendered_force_with_the_gain_but_without_the_clamp() {
        use spidar_msg::{Proxy, ProxyId, ProxyShape};
        let mut c = core();
        home_and_activate(&mut c);
        // Hand 0 sits at home (counts stay zero); a wall 1 cm in front of its centre, 3 cm deep
        // into the 4 cm fist: 2000 N/m x 0.03 m = 60 N, far above the 4 N clamp.
        let xf = c.rig().rig_to_world;
        let home = xf.point(c.rig().hands[0].home_m);
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.push(Proxy {
            id: ProxyId { body: 3, part: 0 },
            shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
            k_n_per_m: 2000.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: 0b01,
        });
        let dt = c.rig().period_s;
        let limit = c.rig().hands[0].force_limit_n;
        // While ramping in (gain about 0.2, still 12 N), then at full gain.
        run(&mut c, 100, Ok(()));
        for _ in 0..2 {
            let (s, rec) = tick_with(&mut c, Some(m));
            assert!(rec.gain > 0.0 && rec.hands[0].clamped, "{rec:?}");
            let contact = s.proxy_contact_impulse_n_s[0];
            let want = -DVec3::Z * 60.0 * rec.gain * dt;
            assert!((contact - want).length() < 1e-12, "{contact} vs {want}");
            let applied = s.proxy_impulse_n_s[0].length() / dt;
            assert!(applied <= limit + 1e-9 && applied > 0.9 * limit, "{applied} N applied");
            assert!(s.proxy_contact_impulse_n_s[1..].iter().all(|i| *i == DVec3::ZERO));
            // Keep the model fresh to full gain (a model that faded out would ramp back in).
            for _ in 0..600 {
                tick_with(&mut c, Some(m));
            }
        }
        // The model goes stale and fades: the contact fades with it, to exactly zero.
        let fade = c.rig().safety.contact_stale_after_s + c.rig().safety.contact_fade_s;
        let mut last = f64::INFINITY;
        for _ in 0..(fade / dt).round() as usize + 1 {
            let (s, rec) = tick_with(&mut c, None);
            let contact = s.proxy_contact_impulse_n_s[0].length() / dt;
            assert!((contact - 60.0 * rec.gain).abs() < 1e-9 && contact <= last, "{contact} N");
            last = contact;
        }
        let (s, _) = tick_with(&mut c, None);
        assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
        assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO);
    }

    #[test]
    fn the_scenes_extra_force_is_rendered_as_given_and_every_safety_counter_counts_its_ticks() {
        use spidar_msg::{Proxy, ProxyId, ProxyShape};
        let mut c = core();
        home_and_activate(&mut c);
        let mut out = Output::default();
        let zero = [0i64; MAX_CHANNELS];
        let extra = |f: DVec3| {
            let mut m = ContactModel { seq: 1, ..Default::default() };
            m.extra_force_n = [f, DVec3::ZERO];
            m
        };
        for _ in 0..600 {
            tick_io(&mut c, &mut out, Some(extra(DVec3::ZERO)), &zero, Ok(()));
        }
        let base = *c.counters();
        // The scene's extra force, as given (world and rig axes agree here).
        let (_, r) = tick_io(&mut c, &mut out, Some(extra(DVec3::new(0.0, 1.0, -2.0))), &zero, Ok(()));
        assert!((r.hands[0].commanded_n - DVec3::new(0.0, 1.0, -2.0)).length() < 1e-12, "{r:?}");
        assert!((r.hands[0].output_n - DVec3::new(0.0, 1.0, -2.0)).length() < 1e-9);
        // 7 ticks above the 4 N limit: clamped 7 times, on hand 0 only.
        for _ in 0..7 {
            tick_io(&mut c, &mut out, Some(extra(DVec3::X * 10.0)), &zero, Ok(()));
        }
        // 3 ticks of a NaN force: replaced by zero, counted.
        for _ in 0..3 {
            let (_, r) = tick_io(&mut c, &mut out, Some(extra(DVec3::NAN)), &zero, Ok(()));
            assert_eq!(r.hands[0].commanded_n, DVec3::ZERO);
        }
        // 5 ticks against a proxy stiffer than the limit, 1 mm deep.
        let home = c.rig().rig_to_world.point(c.rig().hands[1].home_m);
        let mut stiff = ContactModel { seq: 2, ..Default::default() };
        stiff.push(Proxy {
            id: ProxyId { body: 1, part: 0 },
            shape: ProxyShape::Plane { point_m: home - DVec3::Y * 0.039, normal: DVec3::Y },
            k_n_per_m: 1e6,
            d_n_s_per_m: 0.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: 0b10,
        });
        for _ in 0..5 {
            let (_, r) = tick_io(&mut c, &mut out, Some(stiff), &zero, Ok(()));
            assert!((r.hands[1].commanded_n.y - 4.0).abs() < 1e-9, "5000 N/m x 1 mm = 5 N, clamped to 4");
        }
        // 100 ticks with no new model: the ticks past contact_stale_after_s are stale.
        let (mut stale, mut clamped_fading) = (0, 0);
        for _ in 0..100 {
            let (_, r) = tick_io(&mut c, &mut out, None, &zero, Ok(()));
            stale += (r.contact_age_s > c.rig().safety.contact_stale_after_s) as u64;
            clamped_fading += r.hands[1].clamped as u64;
        }
        assert!((60..=71).contains(&stale), "{stale}");
        // The stiff contact goes on (fading) while the model ages: clamped while above 4 N.
        assert!((30..60).contains(&clamped_fading), "{clamped_fading}");
        let k = c.counters();
        assert_eq!(k.clamped, [base.clamped[0] + 7, base.clamped[1] + 5 + clamped_fading]);
        assert_eq!(k.non_finite, base.non_finite + 3);
        assert_eq!(k.stiffness_limited, [base.stiffness_limited[0], base.stiffness_limited[1] + 5 + 100]);
        assert_eq!(k.stale, base.stale + stale);
        assert_eq!(k.active_ticks, base.active_ticks + 1 + 7 + 3 + 5 + 100);
        assert_eq!(k.infeasible, base.infeasible);
        assert_eq!(k.fallback, base.fallback);
        assert_eq!(k.models, base.models + 1 + 7 + 3 + 5);
    }

    #[test]
    fn a_grip_outside_its_frame_is_counted_as_fallback_every_tick() {
        let mut c = core();
        home_and_activate(&mut c);
        let mut out = Output::default();
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        // Hand 1 walks 1 mm per tick down to 1.5 m below the rig origin, out of its tetrahedron
        // (zero net force is then infeasible: the box-QP fallback chooses the tensions).
        let mut fallback = 0;
        let mut infeasible = 0;
        for k in 0..1500 {
            let p = [home[0], home[1] - DVec3::Y * (k as f64 * 1e-3)];
            let counts = counts_at(&c, p);
            let (_, r) = tick_io(&mut c, &mut out, None, &counts, Ok(()));
            assert!(!r.hands[1].held, "walking is not a jump");
            fallback += (r.hands[1].method == Method::Fallback) as u64;
            infeasible += (r.hands[1].method == Method::Scaled) as u64;
        }
        assert!(fallback > 100, "{fallback}");
        assert_eq!(c.counters().fallback, [0, fallback]);
        assert_eq!(c.counters().infeasible, [0, infeasible]);
    }

    #[test]
    fn nothing_is_rendered_while_inactive_and_a_contact_pushing_nothing_gives_back_nothing() {
        let mut c = core();
        c.command(Command::Home);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        let m = pressing_wall(&c);
        assert_eq!(c.contact_model(), None);
        let mut out = Output::default();
        let zero = [0i64; MAX_CHANNELS];
        let (s, r) = tick_io(&mut c, &mut out, Some(m), &zero, Ok(()));
        assert_eq!(c.contact_model().map(|m| m.seq), Some(1), "the newest model is kept");
        assert_eq!((r.hands[0].rendered_n, r.hands[0].contacts), (DVec3::ZERO, 0), "inactive: no rendering");
        assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
        // Active, the fist 1 cm inside a heavily damped plane but leaving it at 1 m/s: the damper
        // cancels the spring (a penalty contact never pulls), so the force and impulses are zero,
        // not NaN.
        use spidar_msg::{Proxy, ProxyId, ProxyShape};
        c.command(Command::Activate);
        let home = c.rig().hands[0].home_m;
        let world = c.rig().rig_to_world.point(home);
        let mut damped = ContactModel { seq: 2, ..Default::default() };
        damped.push(Proxy {
            id: ProxyId { body: 3, part: 0 },
            shape: ProxyShape::Plane { point_m: world - DVec3::Z * 0.03, normal: DVec3::Z },
            k_n_per_m: 2000.0,
            d_n_s_per_m: 5000.0,
            vel_m_per_s: DVec3::ZERO,
            hand_mask: 0b01,
        });
        for k in 0..9 {
            let p = [home + DVec3::Z * (k as f64 * 1e-3), c.rig().hands[1].home_m];
            let counts = counts_at(&c, p);
            let (s, r) = tick_io(&mut c, &mut out, Some(damped), &counts, Ok(()));
            if k > 4 {
                assert_eq!(r.hands[0].contacts, 1, "tick {k}");
                assert_eq!(r.hands[0].rendered_n, DVec3::ZERO, "tick {k}");
                assert_eq!(s.proxy_impulse_n_s[0], DVec3::ZERO, "tick {k}: {:?}", s.proxy_impulse_n_s[0]);
                assert_eq!(s.proxy_contact_impulse_n_s[0], DVec3::ZERO);
            }
        }
    }

    #[test]
    fn a_force_beyond_what_the_strings_can_render_there_is_counted_as_infeasible() {
        let mut c = core();
        home_and_activate(&mut c);
        let mut out = Output::default();
        let home = [c.rig().hands[0].home_m, c.rig().hands[1].home_m];
        // Hand 0 walks 0.3 m to its outer side (-x), where the strings give about 2 N outward.
        let mut m = ContactModel { seq: 1, ..Default::default() };
        m.extra_force_n = [DVec3::X * -4.0, DVec3::ZERO];
        let mut scaled = 0;
        for k in 0..=300 {
            let p = [home[0] - DVec3::X * (k as f64 * 1e-3), home[1]];
            let counts = counts_at(&c, p);
            let (_, r) = tick_io(&mut c, &mut out, Some(m), &counts, Ok(()));
            scaled += (r.hands[0].method == Method::Scaled) as u64;
            if k == 300 {
                assert_eq!(r.hands[0].method, Method::Scaled);
                assert!(r.hands[0].output_n.length() < 3.9 && r.hands[0].scale < 1.0, "{:?}", r.hands[0]);
            }
        }
        assert!(scaled > 10);
        assert_eq!(c.counters().infeasible, [scaled, 0]);
    }

    #[test]
    fn names_and_reasons_say_what_they_are() {
        let names = [Lifecycle::Unconfigured, Lifecycle::Inactive, Lifecycle::Active, Lifecycle::Faulted]
            .map(Lifecycle::name);
        assert_eq!(names, ["unconfigured", "inactive", "active", "faulted"]);
        let says = |f: FaultReason| f.to_string();
        assert_eq!(says(FaultReason::Device(ErrorKind::Timeout)), "device error (Timeout)");
        assert!(says(FaultReason::PoseInvalid { hand: 1 }).starts_with("hand 1: pose"));
        assert!(says(FaultReason::Residual { hand: 0 }).contains("slack string"));
        assert!(says(FaultReason::CountJump { hand: 1 }).starts_with("hand 1: counts jumped"));
    }

    #[test]
    fn events_beyond_the_queue_are_dropped_and_counted() {
        let mut c = core();
        for _ in 0..20 {
            c.command(Command::Activate); // refused: not homed
        }
        assert_eq!(c.counters().events_dropped, 4);
        assert_eq!(std::iter::from_fn(|| c.pop_event()).count(), 16);
    }

    #[test]
    fn quiet_only_when_not_active_and_the_force_has_ramped_out() {
        let mut c = core();
        assert!(c.is_quiet());
        c.command(Command::Home);
        let settle = (HOMING_SETTLE_S / c.rig().period_s).round() as usize;
        run(&mut c, settle + 1, Ok(()));
        assert!(c.is_homed() && c.is_quiet());
        c.command(Command::Activate);
        assert!(!c.is_quiet(), "active, though the ramp has not risen yet");
        run(&mut c, 600, Ok(()));
        assert!(!c.is_quiet(), "active");
        c.command(Command::Stop);
        run(&mut c, 100, Ok(()));
        assert!(!c.is_quiet(), "still ramping out");
        let ramp_out = (c.rig().safety.ramp_out_s / c.rig().period_s).round() as usize;
        run(&mut c, ramp_out, Ok(()));
        assert!(c.is_quiet());
        // A fault is quiet at once (the ramp is cut).
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        let n = reply_limit(&c);
        run(&mut c, n, Err(TIMEOUT));
        assert!(c.is_quiet());
    }

    #[test]
    fn the_loop_counts_into_the_cores_counters() {
        let mut c = core();
        c.counters_mut().misses += 2;
        c.counters_mut().samples_dropped += 1;
        assert_eq!((c.counters().misses, c.counters().samples_dropped), (2, 1));
    }

    #[test]
    fn recovery_needs_good_exchanges_in_a_row() {
        let mut c = core();
        home_and_activate(&mut c);
        let need = c.rig().safety.fault_recovery_ticks as usize;
        let n = reply_limit(&c);
        run(&mut c, n, Err(DeviceError::Timeout { waited_us: 1 }));
        for _ in 0..3 {
            run(&mut c, need - 1, Ok(()));
            run(&mut c, 1, Err(DeviceError::Corrupt { what: "test" }));
        }
        assert_eq!(c.state(), Lifecycle::Faulted, "a flaky link must not count its good ticks across errors");
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
        assert_eq!(c.counters().faults, 1);
    }
}
