//! The tick's input phase, per hand: the counts read and checked against the hand's motion,
//! the pose from the string lengths (kinematics), the velocity, and which hand's output is held.
//!
//! Why it exists apart: what a reply may be trusted with is one concern (`docs/safety.md`), and
//! the phases after it only see its outcome: a pose accepted, or a hand to hold, or a fault.
//! It must never write an output, allocate, or panic on any count (a count is untrusted data).

use glam::DVec3;
use spidar_device::Input;
use spidar_msg::HANDS;

use super::{FaultReason, HandCore, TickCore};
use crate::rig::{HandRig, Rig};

/// The rig's bounds the input phase checks a reply against.
#[derive(Clone, Copy)]
pub(super) struct ReadLimits {
    /// Rejected replies in a row (count jumps) that fault.
    reply_ticks: u32,
    /// How far a string may move in one period beyond its predicted motion (`reply_jump_m`).
    jump_m: f64,
    /// Pose residual above which a hand's lengths are not used, and the run of them that faults.
    residual_m: f64,
    residual_ticks: u32,
    gauss_newton_iterations: u32,
    dt_s: f64,
    /// Calibrating: an unhomed hand's counts are checked against the last reply taken.
    calibrating: bool,
}

impl ReadLimits {
    pub(super) fn of(rig: &Rig, calibrating: bool) -> ReadLimits {
        let s = &rig.safety;
        ReadLimits {
            reply_ticks: s.reply_fault_ticks.max(1),
            jump_m: s.reply_jump_m,
            residual_m: s.residual_fault_m,
            residual_ticks: s.residual_fault_ticks.max(1),
            gauss_newton_iterations: rig.estimation.gauss_newton_iterations,
            dt_s: rig.period_s,
            calibrating,
        }
    }
}

/// What one hand's counts gave this tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Reading {
    /// No usable exchange this tick: the last pose stays (the safe output uses it).
    NoReply,
    /// Not homed: the counts are taken as they come (homing uses them), no pose.
    Unhomed,
    /// Counts accepted: a new pose, velocity and string lengths.
    Accepted,
    /// The counts jumped further than the hand can move: rejected; `fault` once a run of them
    /// reached the limit, else the hand is held.
    Jumped { fault: bool },
    /// The pose could not be computed (non-finite lengths or result).
    PoseInvalid,
    /// The string lengths disagree beyond the residual limit: not used; `fault` once a run of
    /// them reached the limit, else the hand is held.
    Residual { fault: bool },
}

impl TickCore {
    /// Reads both hands' counts (when the exchange worked), counts what was rejected, faults on
    /// a run of rejections, and returns which hands hold their last output this tick (all of
    /// them when `hold_all`: a tolerated bad reply).
    pub(super) fn read_hands(
        &mut self,
        now_s: f64,
        device_ok: bool,
        hold_all: bool,
        inp: &Input,
    ) -> [bool; HANDS] {
        let lim = ReadLimits::of(&self.rig, self.calibrating);
        let mut fault = None;
        let mut hold = [hold_all; HANDS];
        for (hi, (h, hr)) in self.hands.iter_mut().zip(self.rig.hands.iter()).enumerate() {
            let hand = hi as u8;
            match read_hand(h, hr, &lim, device_ok, now_s, inp) {
                Reading::NoReply | Reading::Unhomed | Reading::Accepted => {}
                Reading::Jumped { fault: f } => {
                    self.counters.count_jumps[hi] += 1;
                    if f {
                        fault = Some(FaultReason::CountJump { hand });
                    } else {
                        hold[hi] = true;
                    }
                }
                Reading::PoseInvalid => fault = Some(FaultReason::PoseInvalid { hand }),
                Reading::Residual { fault: f } => {
                    self.counters.residual_high[hi] += 1;
                    if f {
                        fault = Some(FaultReason::Residual { hand });
                    } else {
                        hold[hi] = true;
                    }
                }
            }
        }
        if let Some(f) = fault {
            self.enter_fault(f);
        }
        hold
    }
}

/// One hand's input phase. A hand whose counts cannot be trusted this tick is held: its pose,
/// velocity and output stay those of its last accepted tick.
pub(super) fn read_hand(
    h: &mut HandCore,
    hr: &HandRig,
    lim: &ReadLimits,
    device_ok: bool,
    now_s: f64,
    inp: &Input,
) -> Reading {
    if !device_ok {
        h.since_accept = h.since_accept.saturating_add(1);
        return Reading::NoReply; // keep the last pose; the safe output uses it
    }
    let counts = read_counts(inp, hr);
    let Some(zero) = h.zero_m else {
        if lim.calibrating {
            // No pose to predict from: the counts may step by `reply_jump_m` per tick since the
            // last reply taken (a grip moved by hand moves less), not by a corrupt count's 12 cm.
            let periods = h.periods_since_accept(now_s, lim.dt_s);
            let tol_m = lim.jump_m * f64::from(periods);
            let step_m = |s: usize| ((counts[s] - h.counts[s]) as f64 * hr.metres_per_count[s]).abs();
            if h.counts_taken && (0..4).any(|s| step_m(s) > tol_m) {
                h.jump_run += 1;
                h.since_accept = h.since_accept.saturating_add(1);
                return Reading::Jumped { fault: h.jump_run >= lim.reply_ticks };
            }
            h.jump_run = 0;
            h.counts_taken = true;
            h.since_accept = 1;
            h.accept_t_s = now_s;
        }
        h.prev_counts = std::mem::replace(&mut h.counts, counts);
        h.pose.valid = false;
        return Reading::Unhomed;
    };
    let mut lengths = [0.0; 4];
    for s in 0..4 {
        lengths[s] = zero[s] + counts[s] as f64 * hr.metres_per_count[s];
    }
    let periods = h.periods_since_accept(now_s, lim.dt_s);
    if h.count_jumped(&lengths, lim, periods) {
        h.jump_run += 1;
        h.since_accept = h.since_accept.saturating_add(1);
        return Reading::Jumped { fault: h.jump_run >= lim.reply_ticks };
    }
    h.jump_run = 0;
    let pose = h.kin.solve(&lengths, lim.gauss_newton_iterations);
    if !pose.valid {
        h.pose = pose;
        return Reading::PoseInvalid;
    }
    // The four strings' redundancy: lengths that disagree are not used.
    if pose.residual_m > lim.residual_m {
        h.bad_residual_ticks += 1;
        h.since_accept = h.since_accept.saturating_add(1);
        let fault = h.bad_residual_ticks >= lim.residual_ticks;
        if fault {
            h.pose = pose;
        }
        return Reading::Residual { fault };
    }
    h.bad_residual_ticks = 0;
    h.prev_counts = std::mem::replace(&mut h.counts, counts);
    h.pose = pose;
    h.lengths_m = lengths;
    h.vel.update_after(pose.pos_m, periods);
    h.since_accept = 1;
    h.accept_t_s = now_s;
    h.safe_pos_m = pose.pos_m;
    Reading::Accepted
}

impl HandCore {
    /// The count step against the hand's motion: where the last pose and velocity put each
    /// string now. A corrupt count lands centimetres away; a hand cannot. False without a
    /// velocity history (nothing to predict from).
    fn count_jumped(&self, lengths_m: &[f64; 4], lim: &ReadLimits, periods: u32) -> bool {
        let Some(pred) = self.predicted_lengths(lim.dt_s, periods) else { return false };
        // `reply_jump_m` per period, plus one period of the string's own predicted motion: a
        // reply is sampled when it reaches the board, up to a reply deadline away from the
        // tick's time, so a fast hand's counts may be that much ahead or behind.
        let k = f64::from(periods);
        // A NaN length is a jump too.
        (0..4).any(|s| {
            let tol = lim.jump_m * k + (pred[s] - self.lengths_m[s]).abs() / k;
            let within = (lengths_m[s] - pred[s]).abs() <= tol;
            !within
        })
    }

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

    /// The velocity the output phases use: the filter's when the pose is trusted, else zero.
    pub(super) fn velocity_if(&self, pose_ok: bool) -> DVec3 {
        if pose_ok {
            self.vel.velocity()
        } else {
            DVec3::ZERO
        }
    }
}

/// The counts of a hand's four channels (a channel the input lacks reads 0).
pub(super) fn read_counts(inp: &Input, hr: &HandRig) -> [i64; 4] {
    hr.channels.map(|ch| inp.counts.get(ch).copied().unwrap_or(0))
}
