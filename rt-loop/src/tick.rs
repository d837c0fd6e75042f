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

use glam::DVec3;
use spidar_device::{DeviceError, ErrorKind, Input, Output, MAX_CHANNELS};
use spidar_msg::{ContactModel, HandSample, HandState, HANDS, MAX_PROXIES};

use crate::kinematics::{Kinematics, Pose};
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
}

impl FaultReason {
    /// Transient faults clear themselves after enough good ticks.
    pub fn is_transient(self) -> bool {
        matches!(self, FaultReason::Device(ErrorKind::Timeout | ErrorKind::Corrupt))
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
        }
    }
}

/// What the control side may ask of the loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// Preset the counters' zero lengths so each grip reads its home point (Inactive only). Done
    /// after the strings have been held at minimum tension for `HOMING_SETTLE_S`, so no string is
    /// still slack (a slack string reads long and would bake its sag into the zero length).
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
    /// Non-finite forces replaced by zero.
    pub non_finite: u64,
    /// Active ticks with a stale (fading) or missing contact model.
    pub stale: u64,
    /// Ticks with the pose residual above its limit.
    pub residual_high: [u64; HANDS],
    pub faults: u64,
    pub device_errors: u64,
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
    counts: [i64; 4],
    pose: Pose,
    /// Last pose that was valid: the safe output's string directions come from it.
    safe_pos_m: DVec3,
    bad_residual_ticks: u32,
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
                pose: Pose { pos_m: hr.home_m, residual_m: 0.0, valid: false },
                safe_pos_m: hr.home_m,
                bad_residual_ticks: 0,
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
            for s in 0..4 {
                h.counts[s] = inp.counts.get(hr.channels[s]).copied().unwrap_or(0);
            }
        }
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
            self.activate_after_homing = false;
            self.emit(Event::Refused {
                command: Command::Home,
                why: "a fault interrupted homing: home again",
            });
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
        }
        self.set_state(Lifecycle::Faulted);
        self.emit(Event::Fault(why));
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
        }
        if to_active {
            self.ramp.rise();
            self.set_state(Lifecycle::Active);
        } else {
            self.set_state(Lifecycle::Inactive);
        }
    }

    /// Applies a command; refusals are reported as events. `Stop` is handled by the loop.
    pub fn command(&mut self, c: Command) {
        let refuse = |s: &mut Self, why| s.emit(Event::Refused { command: c, why });
        match c {
            Command::Home => {
                if self.state != Lifecycle::Inactive {
                    return refuse(self, "homing needs the rig inactive: deactivate first");
                }
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
        self.homing_wait = None;
        for (h, hr) in self.hands.iter_mut().zip(self.rig.hands.iter()) {
            h.zero_m = Some(hr.home_offsets(h.counts, hr.home_m));
            h.vel.reset();
            h.bad_residual_ticks = 0;
        }
        self.emit(Event::Homed);
        if std::mem::take(&mut self.activate_after_homing) {
            self.command(Command::Activate);
        }
    }

    /// True while a homing request waits for the strings to settle.
    pub fn is_homing(&self) -> bool {
        self.homing_wait.is_some()
    }

    /// Replaces the contact model (the loop keeps only the newest one it received).
    pub fn set_contact_model(&mut self, m: ContactModel) {
        self.counters.models += 1;
        self.model = Some(m);
    }

    /// The age of the current contact model at `now_s`.
    pub fn model_age_s(&self, now_s: f64) -> Option<f64> {
        self.model.as_ref().map(|m| now_s - m.stamp_s)
    }

    /// One tick. `io` is the result of the device exchange that produced `inp`. Writes the volts
    /// for the next exchange into `out`, the message for the scene into `sample`, and the
    /// telemetry into `rec` (its timing fields are the loop's to fill).
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

        // Device health and fault recovery.
        match io {
            Err(e) => {
                self.counters.device_errors += 1;
                // Recovery needs good exchanges in a row.
                self.good_ticks = 0;
                self.enter_fault(FaultReason::Device(e.kind()));
            }
            Ok(()) => {
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

        // Kinematics and velocity, per hand.
        let mut fault = None;
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            if device_ok {
                for s in 0..4 {
                    h.counts[s] = inp.counts.get(hr.channels[s]).copied().unwrap_or(0);
                }
            }
            let Some(zero) = h.zero_m else {
                h.pose.valid = false;
                continue;
            };
            if !device_ok {
                continue; // keep the last pose; the safe output uses it
            }
            let mut lengths = [0.0; 4];
            for s in 0..4 {
                lengths[s] = zero[s] + h.counts[s] as f64 * hr.metres_per_count[s];
            }
            h.pose = h.kin.solve(&lengths, self.rig.estimation.gauss_newton_iterations);
            if !h.pose.valid {
                fault = Some(FaultReason::PoseInvalid { hand: hi as u8 });
                continue;
            }
            h.vel.update(h.pose.pos_m);
            h.safe_pos_m = h.pose.pos_m;
            if h.pose.residual_m > self.rig.safety.residual_fault_m {
                self.counters.residual_high[hi] += 1;
                h.bad_residual_ticks += 1;
                if h.bad_residual_ticks >= self.rig.safety.residual_fault_ticks.max(1) {
                    fault = Some(FaultReason::Residual { hand: hi as u8 });
                }
            } else {
                h.bad_residual_ticks = 0;
            }
        }
        if let Some(f) = fault {
            self.enter_fault(f);
        }
        self.homing_step(device_ok);

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
        let xf = self.rig.rig_to_world;
        let mut impulses = [DVec3::ZERO; MAX_PROXIES];
        let mut contact_impulses = [DVec3::ZERO; MAX_PROXIES];
        *out = Output::default();
        rec.tick = tick;
        rec.t_s = now_s;
        rec.state = self.state;
        rec.fault = self.fault;
        rec.gain = gain;
        rec.contact_age_s = age.unwrap_or(f64::INFINITY);
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            let pose_ok = h.pose.valid && h.zero_m.is_some() && device_ok;
            let vel = if pose_ok { h.vel.velocity() } else { DVec3::ZERO };
            let mut rendered = Rendered::default();
            let mut want_rig = DVec3::ZERO;
            let mut hand_impulses = [DVec3::ZERO; MAX_PROXIES];
            if active && pose_ok {
                if let Some(m) = self.model.as_ref() {
                    let age_s = age.unwrap_or(0.0).max(0.0);
                    rendered = render::render_hand(
                        hi,
                        xf.point(h.pose.pos_m),
                        xf.vector(vel),
                        hr.grip_radius_m,
                        hr.stiffness_limit_n_per_m,
                        m,
                        age_s,
                        dt,
                        &mut hand_impulses,
                    );
                    want_rig = xf.vector_to_rig(rendered.force_n + m.extra_force_n[hi]);
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
            // Directions from the current pose, or from the last good one when it is not trusted.
            let dir_pos = if pose_ok { h.pose.pos_m } else { h.safe_pos_m };
            let alloc: Allocation = h.alloc.allocate(&h.kin.directions(dir_pos), g.force_n);
            // Two impulses go back per proxy (see `HandSample`). The applied one is only what the
            // user's hand really received: the rendered force after the ramp, fade, clamp and
            // allocation scaling (all along its own direction).
            let want_sq = want_rig.length_squared();
            let applied =
                if want_sq > 0.0 { (alloc.force_n.dot(want_rig) / want_sq).clamp(0.0, 1.0) } else { 0.0 };
            // The virtual contact itself acts with the loop's gain only (a stale or ramped-out
            // model must not push the world either), never limited by what the rig can display.
            // `render_hand` already dropped non-finite contacts; the check keeps a NaN gain out.
            if rendered.contacts > 0 {
                for ((acc, acc_contact), imp) in
                    impulses.iter_mut().zip(contact_impulses.iter_mut()).zip(hand_impulses.iter())
                {
                    *acc += *imp * applied;
                    let c = *imp * gain;
                    if c.is_finite() {
                        *acc_contact += c;
                    }
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
                pos_m: xf.point(h.pose.pos_m),
                vel_m_per_s: xf.vector(vel),
                force_n: xf.vector(alloc.force_n),
                valid: pose_ok,
            };
            rec.hands[hi] = HandRecord {
                pos_m: h.pose.pos_m,
                vel_m_per_s: vel,
                residual_m: h.pose.residual_m,
                valid: pose_ok,
                rendered_n: want_rig,
                commanded_n: g.force_n,
                output_n: alloc.force_n,
                tensions_n: alloc.tensions_n,
                scale: alloc.scale,
                method: alloc.method,
                contacts: rendered.contacts,
                clamped: g.clamped,
                stiffness_limited: rendered.stiffness_limited,
                non_finite: g.non_finite,
            };
        }
        sample.tick = tick;
        sample.t_s = now_s;
        sample.model_seq = self.model.as_ref().map_or(0, |m| m.seq);
        sample.proxy_impulse_n_s = impulses;
        sample.proxy_contact_impulse_n_s = contact_impulses;
    }
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

    #[test]
    fn device_error_faults_at_once_and_a_transient_one_recovers_to_active() {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 600, Ok(()));
        assert_eq!(c.ramp_gain(), 1.0);
        let (out, rec) = run(&mut c, 1, Err(DeviceError::Timeout { waited_us: 900 }));
        assert_eq!(c.state(), Lifecycle::Faulted);
        assert_eq!(rec.gain, 0.0);
        assert!(out.volts[..8].iter().all(|v| *v >= 0.2 - 1e-12), "strings stay taut: {:?}", out.volts);
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need - 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Faulted);
        run(&mut c, 1, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
        assert!(c.ramp_gain() < 0.01, "force ramps in again after the fault");
        assert_eq!(c.counters().faults, 1);
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
    fn a_reopened_device_clears_the_fault_to_inactive_and_unhomed() {
        let mut c = core();
        home_and_activate(&mut c);
        run(&mut c, 10, Err(DeviceError::Timeout { waited_us: 1 }));
        run(&mut c, 1, Err(DeviceError::Disconnected { what: "test" }));
        assert_eq!(
            c.fault(),
            Some(FaultReason::Device(ErrorKind::Disconnected)),
            "a disconnect outranks a timeout"
        );
        c.device_reopened();
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Inactive, "never straight back to Active after a reopen");
        assert!(!c.is_homed(), "the counters may have restarted: home again");
        c.command(Command::Activate);
        assert_eq!(c.state(), Lifecycle::Inactive);
        assert_eq!(c.counters().reopens, 1);
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
    fn recovery_needs_good_exchanges_in_a_row() {
        let mut c = core();
        home_and_activate(&mut c);
        let need = c.rig().safety.fault_recovery_ticks as usize;
        run(&mut c, 1, Err(DeviceError::Timeout { waited_us: 1 }));
        for _ in 0..3 {
            run(&mut c, need - 1, Ok(()));
            run(&mut c, 1, Err(DeviceError::Corrupt { what: "test" }));
        }
        assert_eq!(c.state(), Lifecycle::Faulted, "a flaky link must not count its good ticks across errors");
        run(&mut c, need, Ok(()));
        assert_eq!(c.state(), Lifecycle::Active);
    }
}
