//! The character controller (seed 002, section 4.2): the inverted-pendulum model of equations 1-5
//! with a bounded floor reaction, state feedback toward the target lean and velocity the character
//! AI gives, PD braking and standing up after a fall, and the control-policy state machine of the
//! paper's Fig. 3.
//!
//! Model (per horizontal axis of the heading frame `S_c`, front and side alike): the body is a point
//! mass `M` on a massless rod of length `l` from the base `alpha` (where it touches the floor) to
//! the centre of mass, with inertia `I` about the centre of mass. The floor gives the normal force
//! `f_N`, the controller a friction force `f_F` at the base and a torque `tau` standing for the
//! centre of pressure `beta` being away from `alpha` (`tau = (beta - alpha) f_N`). Then
//! `M r'' = f_F` (1, 4) and `I theta'' = l sin(theta) f_N - l cos(theta) f_F + tau` (3), which
//! linearised is `I theta'' = M g l theta - M l r'' + tau` (5; the paper's sign of the `r''` term
//! follows its own axis convention). The bounds: `tau` in `[-f_N reach_back, f_N reach_front]`
//! (the centre of pressure stays within the legs' reach), `f_F_min <= |f_F| <= f_F_max` with
//! `f_F_max = min(mu f_N, leg force)` (the floor's friction and the legs' strength). With no
//! floor contact there is no control at all.
//!
//! Balance is state feedback that puts the lean first: the velocity loop asks for an acceleration,
//! the torque that keeps the lean on its target with that acceleration is computed from (3), and
//! when the centre of pressure cannot give it the feet move instead (the force at the base is
//! solved from (3) with the torque at its bound): that is the character stepping in the direction
//! it was pushed. When neither can hold the lean it falls.
//!
//! The state machine (Fig. 3's figure is not in the text available to us; these transitions follow
//! sections 4.2 and 6.1):
//!
//! ```text
//! Balance --lean > fall_angle--> Fall --slow and still for settle_s--> Down
//! Down --still, and the AI allows it (not on its side, not sliding)--> StandUp
//! Down --moving again--> Fall
//! StandUp --lean < stand_done--> Balance
//! StandUp --timeout, or the AI forbids it--> Fall
//! ```
//!
//! Must never: allocate, apply a force when the body does not touch the floor, or exceed the
//! bounds above.

use glam::DVec3;
use serde::Deserialize;

use super::space::BodySpace;

/// The control policy (Fig. 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Policy {
    /// Upright: state feedback toward the AI's lean and velocity (standing and walking).
    Balance,
    /// Tipped past the fall angle: no balance any more, PD braking of the slide and the rotation.
    Fall,
    /// Fallen and stopped: lying, braked; the AI decides whether to stand up.
    Down,
    /// PD control of the lean back to upright.
    StandUp,
}

impl Policy {
    pub fn name(self) -> &'static str {
        match self {
            Policy::Balance => "balance",
            Policy::Fall => "fall",
            Policy::Down => "down",
            Policy::StandUp => "stand-up",
        }
    }
}

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
    /// How far the centre of pressure can move ahead of / behind / beside the base (m): tau bounds.
    pub reach_front_m: f64,
    pub reach_back_m: f64,
    pub reach_side_m: f64,
    /// Lean feedback: natural frequency (rad/s) and damping ratio of the lean loop.
    pub lean_omega_rad_per_s: f64,
    pub lean_zeta: f64,
    /// Velocity feedback gain (1/s) and the largest acceleration it asks for (m/s^2).
    pub velocity_gain_per_s: f64,
    pub accel_max_m_per_s2: f64,
    /// Lean (from the vertical) past which the character falls (deg).
    pub fall_angle_deg: f64,
    /// Braking while fallen: damping rate of the slide (1/s) and of the rotation (1/s).
    pub brake_rate_per_s: f64,
    pub brake_spin_rate_per_s: f64,
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
    /// Turning: heading loop natural frequency (rad/s), and the largest twisting torque of the
    /// feet per newton of weight on them (m): `|tau_y| <= f_N yaw_arm`.
    pub yaw_omega_rad_per_s: f64,
    pub yaw_arm_m: f64,
}

impl Default for ControllerParams {
    /// The paper's character (1.5 m, 40 kg, 10 I kg m^2) on a floor with friction 0.8.
    fn default() -> Self {
        ControllerParams {
            base_to_com_m: 0.75,
            lean_inertia_kg_m2: 10.0,
            yaw_inertia_kg_m2: 10.0,
            floor_friction: 0.8,
            leg_force_max_n: 400.0,
            leg_force_min_n: 0.0,
            reach_front_m: 0.25,
            reach_back_m: 0.15,
            reach_side_m: 0.15,
            lean_omega_rad_per_s: 8.0,
            lean_zeta: 1.0,
            velocity_gain_per_s: 2.0,
            accel_max_m_per_s2: 3.0,
            fall_angle_deg: 35.0,
            brake_rate_per_s: 4.0,
            brake_spin_rate_per_s: 4.0,
            stop_speed_m_per_s: 0.08,
            stop_spin_rad_per_s: 0.3,
            settle_s: 0.4,
            stand_omega_rad_per_s: 3.0,
            stand_torque_max_n_m: 600.0,
            stand_done_deg: 6.0,
            stand_timeout_s: 4.0,
            yaw_omega_rad_per_s: 4.0,
            yaw_arm_m: 0.05,
        }
    }
}

impl ControllerParams {
    /// Checks the settings: an error gives the field and what to do.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let positive = [
            ("base_to_com_m", self.base_to_com_m),
            ("lean_inertia_kg_m2", self.lean_inertia_kg_m2),
            ("yaw_inertia_kg_m2", self.yaw_inertia_kg_m2),
            ("lean_omega_rad_per_s", self.lean_omega_rad_per_s),
            ("stand_omega_rad_per_s", self.stand_omega_rad_per_s),
            ("settle_s", self.settle_s),
            ("stand_timeout_s", self.stand_timeout_s),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return Err((name, format!("must be a positive number, got {v}")));
            }
        }
        let non_negative = [
            ("floor_friction", self.floor_friction),
            ("leg_force_max_n", self.leg_force_max_n),
            ("leg_force_min_n", self.leg_force_min_n),
            ("reach_front_m", self.reach_front_m),
            ("reach_back_m", self.reach_back_m),
            ("reach_side_m", self.reach_side_m),
            ("lean_zeta", self.lean_zeta),
            ("velocity_gain_per_s", self.velocity_gain_per_s),
            ("accel_max_m_per_s2", self.accel_max_m_per_s2),
            ("brake_rate_per_s", self.brake_rate_per_s),
            ("brake_spin_rate_per_s", self.brake_spin_rate_per_s),
            ("stop_speed_m_per_s", self.stop_speed_m_per_s),
            ("stop_spin_rad_per_s", self.stop_spin_rad_per_s),
            ("stand_torque_max_n_m", self.stand_torque_max_n_m),
            ("yaw_omega_rad_per_s", self.yaw_omega_rad_per_s),
            ("yaw_arm_m", self.yaw_arm_m),
        ];
        for (name, v) in non_negative {
            if !(v >= 0.0 && v.is_finite()) {
                return Err((name, format!("must be >= 0, got {v}")));
            }
        }
        if self.leg_force_min_n > self.leg_force_max_n {
            return Err(("leg_force_min_n", "must not exceed leg_force_max_n".into()));
        }
        if !(self.fall_angle_deg > self.stand_done_deg && self.fall_angle_deg < 90.0) {
            return Err((
                "fall_angle_deg",
                format!(
                    "must be between stand_done_deg ({}) and 90, got {}",
                    self.stand_done_deg, self.fall_angle_deg
                ),
            ));
        }
        Ok(())
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

/// What the AI asks of the controller this step (section 3: "goal of attitude and locomotion").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Targets {
    /// Target leans (rad) toward the front and the side.
    pub theta_x0: f64,
    pub theta_z0: f64,
    /// Target horizontal velocity (world, m/s).
    pub velocity_m_per_s: DVec3,
    /// Horizontal direction (world, any non-zero length) to face; `None`: only damp turning (a
    /// push that turns the body is kept). A direction, not an angle: the controller needs only the
    /// angle between it and the body's heading, one `atan2`.
    pub heading: Option<DVec3>,
    /// May a fallen character stand up now (the AI's decision, section 6.1)?
    pub may_stand_up: bool,
}

impl Default for Targets {
    fn default() -> Self {
        Targets {
            theta_x0: 0.0,
            theta_z0: 0.0,
            velocity_m_per_s: DVec3::ZERO,
            heading: None,
            may_stand_up: true,
        }
    }
}

/// The floor under the character as the last step's contacts saw it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ground {
    /// Total normal force from the floor (N).
    pub normal_n: f64,
    /// Where it acts: the normal-force-weighted centre of the floor contacts, the paper's alpha.
    pub point_m: DVec3,
}

/// What the controller applies for one step (world frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Drive {
    /// The friction force f_F, applied at `at_m` (the base alpha).
    pub force_n: DVec3,
    pub at_m: DVec3,
    /// The centre-of-pressure torque (about the two horizontal axes) plus the twisting torque.
    pub torque_n_m: DVec3,
}

/// The controller's own state (part of the integration state: a prediction copies it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerState {
    pub policy: Policy,
    /// Time spent in the current policy (s).
    pub in_policy_s: f64,
    /// Time the stop conditions have held while fallen (s).
    pub still_s: f64,
}

impl Default for ControllerState {
    fn default() -> Self {
        ControllerState { policy: Policy::Balance, in_policy_s: 0.0, still_s: 0.0 }
    }
}

impl ControllerState {
    fn enter(&mut self, p: Policy) {
        self.policy = p;
        self.in_policy_s = 0.0;
        self.still_s = 0.0;
    }

    /// Runs the state machine and computes the drive for one step of `dt_s`.
    #[allow(clippy::too_many_arguments)]
    pub fn control(
        &mut self,
        p: &ControllerParams,
        mass_kg: f64,
        g_m_per_s2: f64,
        dt_s: f64,
        b: &BodySpace,
        ground: &Ground,
        t: &Targets,
    ) -> Drive {
        self.control_with(p, &p.tilt_cosines(), mass_kg, g_m_per_s2, dt_s, b, ground, t)
    }

    /// [`ControllerState::control`] with the threshold cosines computed by the caller (once per
    /// step for a whole crowd: a libm `cos` per character was a percent of a crowd step).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn control_with(
        &mut self,
        p: &ControllerParams,
        cos: &TiltCosines,
        mass_kg: f64,
        g_m_per_s2: f64,
        dt_s: f64,
        b: &BodySpace,
        ground: &Ground,
        t: &Targets,
    ) -> Drive {
        self.in_policy_s += dt_s;
        // Lean from the vertical compared by its cosine (the trunk axis's height), no acos.
        let cos_tilt = b.e_yr.y;
        let (v_side, v_front) = b.velocity_sc();
        let speed = (v_side * v_side + v_front * v_front).sqrt();
        let spin = DVec3::new(b.theta_x_dot, b.theta_y_dot, b.theta_z_dot).length();
        // Fig. 3 transitions.
        match self.policy {
            Policy::Balance if cos_tilt < cos.fall => self.enter(Policy::Fall),
            Policy::Fall | Policy::Down => {
                if speed < p.stop_speed_m_per_s && spin < p.stop_spin_rad_per_s && ground.normal_n > 0.0 {
                    self.still_s += dt_s;
                } else {
                    self.still_s = 0.0;
                }
                if self.policy == Policy::Fall && self.still_s >= p.settle_s {
                    self.enter(Policy::Down);
                } else if self.policy == Policy::Down && self.still_s >= p.settle_s && t.may_stand_up {
                    self.enter(Policy::StandUp);
                } else if self.policy == Policy::Down && self.still_s == 0.0 {
                    // Pushed or sliding again.
                    self.enter(Policy::Fall);
                }
            }
            Policy::StandUp => {
                let rates = (b.theta_x_dot * b.theta_x_dot + b.theta_z_dot * b.theta_z_dot).sqrt();
                if cos_tilt > cos.stand_done && rates < 1.0 {
                    self.enter(Policy::Balance);
                } else if self.in_policy_s > p.stand_timeout_s || !t.may_stand_up {
                    self.enter(Policy::Fall);
                }
            }
            Policy::Balance => {}
        }
        let n = ground.normal_n;
        if !(n > 0.0) {
            return Drive { at_m: b.r_m, ..Drive::default() };
        }
        let l = p.base_to_com_m;
        let i = p.lean_inertia_kg_m2;
        let f_max = (p.floor_friction * n).min(p.leg_force_max_n);
        let tau_front = (-n * p.reach_back_m, n * p.reach_front_m);
        let tau_side = (-n * p.reach_side_m, n * p.reach_side_m);
        let (f_side, f_front, tau_x, tau_z);
        match self.policy {
            Policy::Balance => {
                let (kp, kd) = (p.lean_omega_rad_per_s.powi(2), 2.0 * p.lean_zeta * p.lean_omega_rad_per_s);
                let v0 = t.velocity_m_per_s;
                let (v0_side, v0_front) = (v0.dot(b.heading.e_xc), v0.dot(b.heading.e_zc));
                let acc = |v0: f64, v: f64| {
                    (p.velocity_gain_per_s * (v0 - v)).clamp(-p.accel_max_m_per_s2, p.accel_max_m_per_s2)
                };
                (f_front, tau_x) = balance_axis(
                    b.theta_x,
                    b.sin_cos_x,
                    b.theta_x_dot,
                    t.theta_x0,
                    acc(v0_front, v_front) * mass_kg,
                    (kp, kd, i, l, n),
                    tau_front,
                );
                (f_side, tau_z) = balance_axis(
                    b.theta_z,
                    b.sin_cos_z,
                    b.theta_z_dot,
                    t.theta_z0,
                    acc(v0_side, v_side) * mass_kg,
                    (kp, kd, i, l, n),
                    tau_side,
                );
            }
            Policy::Fall | Policy::Down => {
                f_front = -p.brake_rate_per_s * mass_kg * v_front;
                f_side = -p.brake_rate_per_s * mass_kg * v_side;
                tau_x = (-p.brake_spin_rate_per_s * i * b.theta_x_dot).clamp(tau_front.0, tau_front.1);
                tau_z = (-p.brake_spin_rate_per_s * i * b.theta_z_dot).clamp(tau_side.0, tau_side.1);
            }
            Policy::StandUp => {
                let (kp, kd) = (p.stand_omega_rad_per_s.powi(2), 2.0 * p.stand_omega_rad_per_s);
                f_front = -p.brake_rate_per_s * mass_kg * v_front;
                f_side = -p.brake_rate_per_s * mass_kg * v_side;
                let up = |th: f64, sin_th: f64, th_dot: f64| {
                    (i * (-kp * th - kd * th_dot) - mass_kg * g_m_per_s2 * l * sin_th)
                        .clamp(-p.stand_torque_max_n_m, p.stand_torque_max_n_m)
                };
                tau_x = up(b.theta_x, b.sin_cos_x.0, b.theta_x_dot);
                tau_z = up(b.theta_z, b.sin_cos_z.0, b.theta_z_dot);
            }
        }
        // |f_F| within [f_F_min, f_F_max]: below the minimum the legs do not react.
        let mut f = b.heading.to_world(f_side, f_front);
        let f_len = f.length();
        if f_len > f_max {
            f *= f_max / f_len;
        } else if f_len < p.leg_force_min_n {
            f = DVec3::ZERO;
        }
        // Turning: toward the AI's heading, or only damped; the feet's twist is friction-limited.
        let (wy, ky) = (p.yaw_omega_rad_per_s, p.yaw_omega_rad_per_s.powi(2));
        let yaw_acc = match (self.policy, t.heading) {
            (Policy::Balance, Some(dir)) => ky * b.heading.angle_to(dir) - 2.0 * wy * b.theta_y_dot,
            _ => -2.0 * wy * b.theta_y_dot,
        };
        let yaw_max = n * p.yaw_arm_m.max(0.0);
        let tau_y = (p.yaw_inertia_kg_m2 * yaw_acc).clamp(-yaw_max, yaw_max);
        // Rotation about +e_xc leans toward the front; about -e_zc toward the side.
        let torque = b.heading.e_xc * tau_x - b.heading.e_zc * tau_z + DVec3::Y * tau_y;
        Drive { force_n: f, at_m: ground.point_m, torque_n_m: torque }
    }
}

/// One axis of the balance feedback: returns (f_F, tau). `f_want` is what the velocity loop asks
/// for; the lean loop has priority (see the module docs).
#[inline]
fn balance_axis(
    theta: f64,
    (s, c): (f64, f64),
    theta_dot: f64,
    theta0: f64,
    f_want: f64,
    (kp, kd, i, l, n): (f64, f64, f64, f64, f64),
    (tau_min, tau_max): (f64, f64),
) -> (f64, f64) {
    let acc = -kp * (theta - theta0) - kd * theta_dot;
    // Equation 3 solved for the torque that gives `acc` with the wanted force.
    let tau = i * acc - l * s * n + l * c * f_want;
    if tau >= tau_min && tau <= tau_max {
        return (f_want, tau);
    }
    // The centre of pressure is at its limit: move the feet (solve (3) for f_F).
    let tau = tau.clamp(tau_min, tau_max);
    let f = (l * s * n + tau - i * acc) / (l * c.max(0.2));
    (f, tau)
}

/// Angle wrapped into (-pi, pi].
#[inline]
pub fn wrap_pi(a: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let w = a - tau * (a / tau).round();
    if w <= -std::f64::consts::PI {
        w + tau
    } else {
        w
    }
}
