//! The character controller's settings ([`ControllerParams`], read from a crowd scene file) and
//! what is derived from them once. Apart from the controller so that the feet, the drawn figure
//! and the controller all read them without importing each other.
//!
//! Must never: accept a setting that makes the controller divide by zero or overflow (`check`).

use serde::Deserialize;

/// The controller's settings: the character's and the floor's (section 4.2: the bounds are
/// "determined from individual character settings and environment settings").
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ControllerParams {
    /// Distance from the base (the bottom of the body) to the centre of mass, the pendulum's l (m).
    pub base_to_com_m: f64,
    /// Inertia about the centre of mass around a horizontal axis, the paper's I_x (kg m^2).
    pub lean_inertia_kg_m2: f64,
    /// Inertia about the vertical (kg m^2).
    pub yaw_inertia_kg_m2: f64,
    /// Friction coefficient between feet and floor: f_F_max <= mu f_N.
    pub floor_friction: f64,
    /// Most horizontal force the legs give (N): the other half of f_F_max.
    pub leg_force_max_n: f64,
    /// Below this the legs do not react (N), the paper's f_F_min; 0 reacts to anything.
    pub leg_force_min_n: f64,
    /// Feet: standing, each is this far beside the centre line (m).
    pub hip_half_width_m: f64,
    /// The centre of pressure can be within this distance of a planted foot's centre (m).
    pub foot_support_m: f64,
    /// A step lands at most this far ahead of / behind / beside the other foot (m).
    pub step_front_max_m: f64,
    pub step_back_max_m: f64,
    pub step_side_max_m: f64,
    /// ... and at least this far to its own side of it (the legs never cross) (m).
    pub step_width_min_m: f64,
    /// A planted foot farther than this from the body's base (horizontally) carries nothing and
    /// must step (m).
    pub leg_reach_m: f64,
    /// Shortest swing (s) and shortest time on the ground between two steps (s): the step rate.
    pub swing_min_s: f64,
    pub stance_min_s: f64,
    /// Fastest average speed of a swinging foot (m/s).
    pub foot_speed_max_m_per_s: f64,
    /// How high a swinging foot lifts, for drawing (m).
    pub step_height_m: f64,
    /// Nearly still with a foot farther than this from where standing puts it: a settling step (m).
    pub settle_step_m: f64,
    /// Lean feedback: natural frequency (rad/s) and damping ratio of the lean loop.
    pub lean_omega_rad_per_s: f64,
    pub lean_zeta: f64,
    /// Velocity feedback gain (1/s) and the largest acceleration it asks for (m/s^2).
    pub velocity_gain_per_s: f64,
    pub accel_max_m_per_s2: f64,
    /// Lean (from the vertical) past which the character falls (deg).
    pub fall_angle_deg: f64,
    /// Braking while fallen: damping rate of the slide (1/s; bounded by the floor's friction) and
    /// of the rotation (1/s; its torque bounded by the weight times `brake_arm_m`).
    pub brake_rate_per_s: f64,
    pub brake_spin_rate_per_s: f64,
    pub brake_arm_m: f64,
    /// Lying on its side, the character rolls itself face up or face down with at most the weight
    /// times this arm (m).
    pub roll_arm_m: f64,
    /// Fallen and below these speeds for `settle_s`: stopped (m/s, rad/s, s).
    pub stop_speed_m_per_s: f64,
    pub stop_spin_rad_per_s: f64,
    pub settle_s: f64,
    /// Standing up: natural frequency of the PD lean loop (rad/s), its largest torque (N m), the
    /// lean below which the character is up again (deg), and how long it may take (s).
    pub stand_omega_rad_per_s: f64,
    pub stand_torque_max_n_m: f64,
    pub stand_done_deg: f64,
    pub stand_timeout_s: f64,
    /// Turning toward the AI's heading: natural frequency (rad/s). Without a heading the feet
    /// damp a spin at this rate (1/s). Either way the feet's twisting torque is at most the weight
    /// on them times `yaw_arm_m`.
    pub yaw_omega_rad_per_s: f64,
    pub yaw_damping_per_s: f64,
    pub yaw_arm_m: f64,
}

impl Default for ControllerParams {
    /// The paper's character (1.5 m, 40 kg, 10 I kg m^2) on a floor with friction 0.8, with the
    /// feet of a person of that size.
    fn default() -> Self {
        ControllerParams {
            base_to_com_m: 0.75,
            lean_inertia_kg_m2: 10.0,
            yaw_inertia_kg_m2: 10.0,
            floor_friction: 0.8,
            leg_force_max_n: 400.0,
            leg_force_min_n: 0.0,
            hip_half_width_m: 0.08,
            foot_support_m: 0.09,
            step_front_max_m: 0.6,
            step_back_max_m: 0.4,
            step_side_max_m: 0.45,
            step_width_min_m: 0.1,
            leg_reach_m: 0.45,
            swing_min_s: 0.22,
            stance_min_s: 0.05,
            foot_speed_max_m_per_s: 4.0,
            step_height_m: 0.08,
            settle_step_m: 0.06,
            lean_omega_rad_per_s: 8.0,
            lean_zeta: 1.0,
            velocity_gain_per_s: 2.0,
            accel_max_m_per_s2: 3.0,
            fall_angle_deg: 35.0,
            brake_rate_per_s: 25.0,
            brake_spin_rate_per_s: 4.0,
            brake_arm_m: 0.3,
            roll_arm_m: 0.1,
            stop_speed_m_per_s: 0.08,
            stop_spin_rad_per_s: 0.3,
            settle_s: 0.4,
            stand_omega_rad_per_s: 3.0,
            stand_torque_max_n_m: 600.0,
            stand_done_deg: 6.0,
            stand_timeout_s: 4.0,
            yaw_omega_rad_per_s: 4.0,
            yaw_damping_per_s: 1.0,
            yaw_arm_m: 0.05,
        }
    }
}

/// Largest value any length, time, rate or inertia of the controller may have: beyond it a
/// setting is a typo, not a character (a 1e300 m reach overflows the bounds' products).
const SETTING_MAX: f64 = 1e6;

impl ControllerParams {
    /// Checks the settings: an error gives the field and what to do.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let positive = [
            ("base_to_com_m", self.base_to_com_m),
            ("lean_inertia_kg_m2", self.lean_inertia_kg_m2),
            ("yaw_inertia_kg_m2", self.yaw_inertia_kg_m2),
            ("foot_support_m", self.foot_support_m),
            ("step_front_max_m", self.step_front_max_m),
            ("step_back_max_m", self.step_back_max_m),
            ("step_side_max_m", self.step_side_max_m),
            ("leg_reach_m", self.leg_reach_m),
            ("swing_min_s", self.swing_min_s),
            ("foot_speed_max_m_per_s", self.foot_speed_max_m_per_s),
            ("lean_omega_rad_per_s", self.lean_omega_rad_per_s),
            ("stand_omega_rad_per_s", self.stand_omega_rad_per_s),
            ("settle_s", self.settle_s),
            ("stand_timeout_s", self.stand_timeout_s),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v <= SETTING_MAX) {
                return Err((name, format!("must be a positive number up to {SETTING_MAX:e}, got {v}")));
            }
        }
        let non_negative = [
            ("floor_friction", self.floor_friction),
            ("leg_force_max_n", self.leg_force_max_n),
            ("leg_force_min_n", self.leg_force_min_n),
            ("hip_half_width_m", self.hip_half_width_m),
            ("step_width_min_m", self.step_width_min_m),
            ("stance_min_s", self.stance_min_s),
            ("step_height_m", self.step_height_m),
            ("settle_step_m", self.settle_step_m),
            ("lean_zeta", self.lean_zeta),
            ("velocity_gain_per_s", self.velocity_gain_per_s),
            ("accel_max_m_per_s2", self.accel_max_m_per_s2),
            ("brake_rate_per_s", self.brake_rate_per_s),
            ("brake_spin_rate_per_s", self.brake_spin_rate_per_s),
            ("brake_arm_m", self.brake_arm_m),
            ("roll_arm_m", self.roll_arm_m),
            ("stop_speed_m_per_s", self.stop_speed_m_per_s),
            ("stop_spin_rad_per_s", self.stop_spin_rad_per_s),
            ("stand_torque_max_n_m", self.stand_torque_max_n_m),
            ("yaw_omega_rad_per_s", self.yaw_omega_rad_per_s),
            ("yaw_damping_per_s", self.yaw_damping_per_s),
            ("yaw_arm_m", self.yaw_arm_m),
        ];
        for (name, v) in non_negative {
            if !(0.0..=SETTING_MAX).contains(&v) {
                return Err((name, format!("must be a number from 0 to {SETTING_MAX:e}, got {v}")));
            }
        }
        if self.leg_force_min_n > self.leg_force_max_n {
            return Err(("leg_force_min_n", "must not exceed leg_force_max_n".into()));
        }
        if self.step_width_min_m > self.step_side_max_m {
            return Err(("step_width_min_m", "must not exceed step_side_max_m".into()));
        }
        if !(self.fall_angle_deg > self.stand_done_deg
            && self.fall_angle_deg < 90.0
            && self.stand_done_deg > 0.0)
        {
            return Err((
                "fall_angle_deg",
                format!(
                    "must be between stand_done_deg ({}, itself > 0) and 90, got {}",
                    self.stand_done_deg, self.fall_angle_deg
                ),
            ));
        }
        Ok(())
    }

    /// Natural frequency of the pendulum, `sqrt(g / l)` (1/s): the capture point leads the centre
    /// of mass by its velocity over this.
    #[inline]
    pub fn omega0(&self, g: f64) -> f64 {
        (g / self.base_to_com_m).sqrt()
    }
}

/// Cosines of the lean thresholds, `fall_angle_deg` and `stand_done_deg`: the state machine compares
/// the trunk axis's height with them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TiltCosines {
    pub fall: f64,
    pub stand_done: f64,
}

impl ControllerParams {
    #[inline]
    pub fn tilt_cosines(&self) -> TiltCosines {
        TiltCosines {
            fall: self.fall_angle_deg.to_radians().cos(),
            stand_done: self.stand_done_deg.to_radians().cos(),
        }
    }
}
