//! The tick core's lifecycle: the device's health, faults and their recovery, the commands,
//! homing and re-homing, and the force gain of each tick (the ramps and the model's staleness).
//!
//! Why it exists apart: every state change of the rig is decided here and nowhere else, so the
//! rules of `docs/safety.md` (a run of bad replies faults, a fault cuts force at once, recovery
//! needs good exchanges in a row) can be read in one place. It must never write an output,
//! allocate, lock or panic: it runs inside the 1 kHz tick.

use spidar_device::{DeviceError, ErrorKind};

use super::{Command, Event, FaultReason, Lifecycle, TickCore, HOMING_SETTLE_S};
use crate::safety;

/// The force gain of one tick and what it was computed from.
#[derive(Clone, Copy, Debug)]
pub(super) struct TickGains {
    /// The contact model's age (None: no model yet).
    pub(super) age_s: Option<f64>,
    /// Ramp times staleness while active, else 0.
    pub(super) gain: f64,
    /// The rig was active when the tick's gain was taken (a ramp-out ending this tick still
    /// renders it, at gain 0).
    pub(super) active: bool,
}

impl TickCore {
    /// The device health phase: a short run of late, missing or corrupt replies holds the last
    /// output (returns true: hold every hand); a longer one, or any other error, faults. Good
    /// exchanges count toward a transient fault's recovery.
    pub(super) fn device_health(&mut self, io: Result<(), DeviceError>) -> bool {
        let reply_limit = self.rig.safety.reply_fault_ticks.max(1);
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
        hold_all
    }

    /// The gain phase: steps the activation ramp and the model's return ramp, counts active and
    /// stale ticks, and ends a finished ramp-out (to Inactive).
    pub(super) fn tick_gains(&mut self, now_s: f64) -> TickGains {
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
        TickGains { age_s: age, gain, active }
    }

    pub(super) fn emit(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.counters.events_dropped += 1;
        }
    }

    pub(super) fn set_state(&mut self, s: Lifecycle) {
        if self.state != s {
            self.state = s;
            self.emit(Event::State(s));
        }
    }

    pub(super) fn enter_fault(&mut self, why: FaultReason) {
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
            h.counts_taken = false;
        }
        self.set_state(Lifecycle::Faulted);
        self.emit(Event::Fault(why));
    }

    /// Homing is gone (interrupted, or the counters may have restarted): wait for it again.
    pub(super) fn lose_homing(&mut self) {
        if self.calibrating {
            return; // never homed: nothing to lose, nothing to wait for
        }
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

    pub(super) fn leave_fault(&mut self, to_active: bool) {
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
        if self.calibrating && matches!(c, Command::Home | Command::Activate) {
            return refuse(
                self,
                "calibrating: the strings stay at minimum tension, unhomed, until the loop ends",
            );
        }
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
    pub(super) fn homing_step(&mut self, device_ok: bool) {
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
    pub(super) fn rehome_step(&mut self, device_ok: bool) {
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
}
