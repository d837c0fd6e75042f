//! What a UART board does with a motor's command, as its firmware does it: the command of a
//! motor without a current sensor is copied to the PWM duty (1024 = 100 %) and clipped at
//! +-1024; a motor with a current sensor is driven toward a current target. Either way a thermal
//! limit derates a motor that is held stalled at high duty: every 0.1 s its heat grows by the
//! duty (weighted by how stalled it is) less a release of 0.5; above a quarter of the limit
//! (20 s of full duty stalled) the allowed duty falls linearly from 100 % to 50 % at the limit,
//! where heating and release balance.
//!
//! Model assumptions (ours, not the firmware's): a stalled motor's tension is proportional to
//! its duty; a current target is reached exactly when the duty it needs (target / 4095) is
//! allowed, else it falls short in proportion.

use crate::uart::protocol::{CURRENT_MAX, PWM_FULL};

/// Heat released per 0.1 s, in duty (0..1) units.
pub const HEAT_RELEASE: f64 = 0.5;
/// The heat at which the duty is limited to [`HEAT_RELEASE`]: 20 s of full duty stalled
/// (10 updates a second, each adding 1 - 0.5).
pub const HEAT_LIMIT: f64 = 20.0 * 10.0 * HEAT_RELEASE;
/// Heat updates per second.
pub const HEAT_RATE_HZ: f64 = 10.0;
/// The smallest "fastest speed seen" (revolutions per second). How stalled a motor is weighs its
/// heating: `(v_max - 1.5 |v|) / v_max`, clamped to 0..1 (1 when still, 0 from two thirds of
/// `v_max` on).
pub const STALL_SPEED_REV_S: f64 = 5.0;

/// One motor's thermal state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorHeat {
    pub heat: f64,
    /// Fastest speed seen, rev/s (at least [`STALL_SPEED_REV_S`]).
    pub v_max: f64,
    /// The duty (0..1) the thermal limit allows now.
    pub duty_limit: f64,
}

impl Default for MotorHeat {
    fn default() -> Self {
        MotorHeat { heat: 0.0, v_max: STALL_SPEED_REV_S, duty_limit: 1.0 }
    }
}

impl MotorHeat {
    /// One 0.1 s update with the duty (0..1) applied and the motor's speed (rev/s).
    pub fn update(&mut self, duty: f64, speed_rev_s: f64) {
        let speed = speed_rev_s.abs();
        if speed.is_finite() {
            self.v_max = self.v_max.max(speed);
        }
        let stalled = ((self.v_max - 1.5 * speed) / self.v_max).clamp(0.0, 1.0);
        let stalled = if stalled.is_nan() { 0.0 } else { stalled };
        self.heat = (self.heat + stalled * duty.abs().min(1.0) - HEAT_RELEASE).max(0.0);
        self.duty_limit = if self.heat > HEAT_LIMIT / 4.0 {
            let left = ((HEAT_LIMIT - self.heat) / (0.75 * HEAT_LIMIT)).clamp(0.0, 1.0);
            HEAT_RELEASE + (1.0 - HEAT_RELEASE) * left
        } else {
            1.0
        };
    }
}

/// What a motor's command drives, in the command's own digits after the board's clipping and
/// thermal limit, and the duty (0..1) that takes.
pub fn drive(command: i16, current_sensed: bool, duty_limit: f64) -> (f64, f64) {
    let full = f64::from(if current_sensed { CURRENT_MAX } else { PWM_FULL });
    let wanted = f64::from(command).clamp(-full, full);
    let duty = (wanted.abs() / full).min(duty_limit);
    (wanted.signum() * duty * full, duty)
}
