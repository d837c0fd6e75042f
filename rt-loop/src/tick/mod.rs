//! One haptic tick, phase by phase: counts -> string lengths -> pose -> velocity -> render ->
//! safety -> tension allocation -> DA volts, plus the rig's lifecycle.
//!
//! `TickCore` is the computation only: no device, no clock, no channels. The loop (`runner.rs`)
//! gives it what the device read and writes what it returns, so the same code runs on the real
//! clock, on the virtual clock, and in the benchmarks. Everything here must never allocate, lock,
//! format or panic: the rig keeps pulling on a person's hands while it runs.
//!
//! `step` is the list of phases; each lives with its concern, and data flows one way:
//! - `lifecycle.rs`: the device's health, faults and their recovery, commands, homing and
//!   re-homing, and the force gain of the tick (ramps, the model's staleness);
//! - `input.rs`: per hand, the counts read and checked against the hand's motion, kinematics,
//!   velocity, and which hand's output is held;
//! - `output.rs`: per hand, render, safety, allocation, volts, and the held output replayed.
//!
//! Lifecycle (ros2_control's, with SPIDAR meanings; the names are in `control.rs`):
//! - `Inactive`: device open and powered; strings held at minimum tension with zero net force;
//!   homing allowed; no rendering.
//! - `Active`: forces rendered; ramped in after activation.
//! - `Faulted`: zero net force at minimum tension from the very tick the fault is seen; the
//!   reason is kept; cleared by command, or by itself after a transient device fault.
//!   `Unconfigured` (device not open) belongs to the loop around this core.
//! - Calibrating (`spidar calib`, set once by [`TickCore::calibrate`] before the first tick): the
//!   rig stays Inactive for good. The geometry is what is being measured, so the homing is
//!   forgotten and `Home` and `Activate` are refused; there is no pose, hence no residual check.
//!   The reply rules stay: late and corrupt replies hold and then fault as always, and each hand's
//!   counts are checked against the last reply taken (a step beyond `reply_jump_m` per tick since
//!   is rejected, held and counted; a run of them faults, transient). Calibration reads the counts
//!   of the ticks that were not held from the telemetry.
//!
//! A single unusable reply is not a fault: a late or missing reply, a reply the device calls
//! corrupt, counts that jump further than the hand can move, or a pose whose string lengths
//! disagree holds the last output for that tick (per hand where only one hand's counts are bad)
//! and is counted; only a run of them faults. `docs/safety.md` has every rule and bound.

mod input;
mod lifecycle;
mod output;
#[cfg(test)]
mod tests;

use glam::DVec3;
use spidar_device::{DeviceError, Input, Output};
use spidar_msg::{ContactModel, HandSample, HandState, HANDS, MAX_PROXIES};

use crate::blow::{BlowFeel, BlowParams};
pub use crate::control::{Command, Event, FaultReason, Lifecycle};
use crate::kinematics::{GripSolution, Kinematics};
use crate::local::Passivity;
use crate::rig::{HandRig, Rig};
use crate::safety::{Ramp, ReturnRamp};
use crate::telemetry::{HandRecord, TickRecord};
use crate::tension::{Allocator, TensionLimits};
use crate::velocity::VelocityFilter;
use output::{HandOut, Impulses, TickView};

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
    /// Ticks whose allocated tensions produced more than the force limit (fallback ticks, where
    /// the box QP picks the force closest to the asked one) and were scaled down toward minimum
    /// tension until the produced force met it (`produced.rs`).
    pub produced_limited: [u64; HANDS],
    /// Of those, ticks where even the minimum tensions alone produce more than the limit: the
    /// least force along the scaling was kept, still above the limit.
    pub produced_unmet: [u64; HANDS],
    /// Ticks where a proxy stiffer than the hand's limit was softened.
    pub stiffness_limited: [u64; HANDS],
    /// Ticks where the force of an avatar-hand contact was scaled down so the rig would not give
    /// the hand back more energy than it put into the contact (`local.rs`).
    pub passivity_limited: [u64; HANDS],
    /// Landed blows (boxing) whose force reached this hand (`blow.rs`), ticks whose blow push
    /// was scaled down by its reserve, ticks whose burst was cut by its energy budget, and the
    /// work the bursts did on the hand, positive parts summed (microjoules).
    pub blows_felt: [u64; HANDS],
    pub blow_push_limited: [u64; HANDS],
    pub blow_burst_cut: [u64; HANDS],
    pub blow_burst_uj: [u64; HANDS],
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
    /// The newest landed blow as this hand feels it, its force this tick (rig frame), and the
    /// work its bursts gave the hand so far (J).
    blow: BlowFeel,
    blow_n: DVec3,
    burst_given_j: f64,
    /// Ticks since this hand's counts were last accepted (1: the previous tick), when that was,
    /// and the string lengths they gave.
    since_accept: u32,
    accept_t_s: f64,
    lengths_m: [f64; 4],
    /// Rejected count jumps in a row.
    jump_run: u32,
    /// Calibrating: `counts` is a reply this hand took, the one the next is checked against
    /// (false at the start and after a fault: the next reply is taken as it comes).
    counts_taken: bool,
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
    /// Calibrating: Inactive for good, unhomed, counts checked step by step (see the module doc).
    calibrating: bool,
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
                blow: BlowFeel::default(),
                blow_n: DVec3::ZERO,
                burst_given_j: 0.0,
                since_accept: 1,
                accept_t_s: 0.0,
                lengths_m: [0.0; 4],
                jump_run: 0,
                counts_taken: false,
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
            calibrating: false,
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
    /// Calibration's loop (`spidar calib`): the rig stays Inactive, unhomed, its strings at
    /// minimum tension, every hand's counts checked against the last reply taken (see the module
    /// doc). Call before the first tick; there is no way back (a calibration ends the loop).
    pub fn calibrate(&mut self) {
        self.calibrating = true;
        self.homing_wait = None;
        self.awaiting_home = false;
        self.activate_after_homing = false;
        self.activate_after_rehome = false;
        for h in self.hands.iter_mut() {
            h.zero_m = None;
            h.counts_taken = false;
        }
    }
    /// The loop is calibration's (see [`TickCore::calibrate`]).
    pub fn is_calibrating(&self) -> bool {
        self.calibrating
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
            h.counts = input::read_counts(inp, hr);
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

    /// True while a homing request waits for the strings to settle.
    pub fn is_homing(&self) -> bool {
        self.homing_wait.is_some()
    }

    /// Replaces the contact model (the loop keeps only the newest one it received). The energy
    /// the world's bodies put into each avatar-hand contact over the step since the last model
    /// is credited to that hand's reserve (`local.rs`). A new landed blow starts on both hands
    /// (`blow.rs`).
    pub fn set_contact_model(&mut self, m: ContactModel) {
        self.counters.models += 1;
        let since_s = self.model.as_ref().map_or(0.0, |old| (m.stamp_s - old.stamp_s).clamp(0.0, 0.01));
        let blow = BlowParams::default();
        for (h, c) in self.hands.iter_mut().zip(m.hand_contacts.iter()) {
            h.passivity.credit(c.source_w * since_s);
            h.blow.start(&m.blow, &blow);
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
        // Device health (lifecycle.rs): a short run of bad replies holds every hand's output.
        let hold_all = self.device_health(io);
        let device_ok = io.is_ok();
        // Counts, kinematics, velocity per hand (input.rs); which hands hold their output.
        let hold = self.read_hands(now_s, device_ok, hold_all, inp);
        self.homing_step(device_ok);
        self.rehome_step(device_ok);
        // The tick's force gain (lifecycle.rs): ramps and the model's staleness.
        let gains = self.tick_gains(now_s);
        let view = TickView {
            model: self.model.as_ref(),
            age_s: gains.age_s,
            gain: gains.gain,
            active: gains.active,
            faulted: self.state == Lifecycle::Faulted,
            device_ok,
            xf: self.rig.rig_to_world,
            dt_s: self.rig.period_s,
        };
        rec.tick = tick;
        rec.t_s = now_s;
        rec.state = self.state;
        rec.fault = self.fault;
        rec.gain = gains.gain;
        rec.contact_age_s = gains.age_s.unwrap_or(f64::INFINITY);
        rec.awaiting_home = self.awaiting_home;
        // Render, safety, allocate, volts per hand (output.rs).
        let mut impulses = Impulses::zero();
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            let to = HandOut {
                out: &mut *out,
                impulses: &mut impulses,
                state: &mut sample.hands[hi],
                rec: &mut rec.hands[hi],
            };
            output::hand_output(hi, h, hr, hold[hi], &view, &mut self.counters, to);
        }
        sample.tick = tick;
        sample.t_s = now_s;
        sample.model_seq = self.model.as_ref().map_or(0, |m| m.seq);
        sample.proxy_impulse_n_s = impulses.applied_n_s;
        sample.proxy_contact_impulse_n_s = impulses.contact_n_s;
    }

    /// Runs one phase of the tick for both hands on the core's current state, as `step` runs
    /// it but without the phases around it, and returns a sum of what it made: for the
    /// benchmarks (`benches/tick.rs`), which time the phases apart; the loop only calls `step`.
    /// `Read` takes `inp`'s counts (pose, velocity, rejections, as `step` would); `Render`
    /// renders at each hand's pose against the current model; `Safety` guards the force each
    /// hand rendered on its last tick; `Allocate` shares out the force each hand commanded on
    /// its last tick. The gain is the ramp's (not stepped).
    pub fn run_phase(&mut self, phase: Phase, now_s: f64, inp: &Input) -> f64 {
        if phase == Phase::Read {
            let hold = self.read_hands(now_s, true, false, inp);
            return self
                .hands
                .iter()
                .zip(hold)
                .map(|(h, held)| h.pose.pos_m.x + f64::from(u8::from(held)))
                .sum();
        }
        let active = self.state == Lifecycle::Active;
        let view = TickView {
            model: self.model.as_ref(),
            age_s: self.model_age_s(now_s),
            gain: if active { self.ramp.gain() } else { 0.0 },
            active,
            faulted: self.state == Lifecycle::Faulted,
            device_ok: true,
            xf: self.rig.rig_to_world,
            dt_s: self.rig.period_s,
        };
        let mut made = 0.0;
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            let pose_ok = h.pose.valid && h.zero_m.is_some();
            let vel = h.velocity_if(pose_ok);
            let (rendered_n, commanded_n) = (h.last.rec.rendered_n, h.last.rec.commanded_n);
            made += match phase {
                Phase::Read => 0.0, // done above
                Phase::Render => {
                    let mut imp = [DVec3::ZERO; MAX_PROXIES];
                    output::render_phase(hi, h, hr, vel, pose_ok, &view, &mut imp).1.z
                }
                Phase::Safety => {
                    let touching = view.model.is_some_and(|m| m.hand_contacts[hi].touching());
                    let engaged = active && touching && pose_ok;
                    output::safety_phase(h, hr, rendered_n, vel, &view, engaged).command_n.z
                }
                Phase::Allocate => output::allocate_phase(h, hr, pose_ok, commanded_n).0.tensions_n[0],
            };
        }
        made
    }
}

/// A phase of the tick that `TickCore::run_phase` runs alone, for the benchmarks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Counts checked, kinematics, velocity (`input.rs`).
    Read,
    /// The contact model rendered at the hands' poses (`output.rs`).
    Render,
    /// Gain, force limit and the avatar contact's energy reserve (`output.rs`).
    Safety,
    /// String tensions for the commanded force, the produced force within the limit (`output.rs`).
    Allocate,
}
