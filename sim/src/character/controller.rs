//! The character controller (seed 002, section 4.2): the inverted-pendulum model of equations 1-5
//! with a floor reaction bounded by the floor, the legs and the feet, state feedback toward the
//! target lean and velocity the character AI gives, PD braking and standing up after a fall, and
//! the control-policy state machine of the paper's Fig. 3.
//!
//! Model (per horizontal axis of the heading frame `S_c`, front and side alike): the body is a point
//! mass `M` on a massless rod of length `l` from the base `alpha` (where it touches the floor) to
//! the centre of mass, with inertia `I` about the centre of mass. The floor gives the normal force
//! `f_N` and, through the feet, a friction force `f_F` and a centre of pressure `beta` away from
//! `alpha` (the torque `tau = (beta - alpha) f_N`). Then `M r'' = f_F` (1, 4) and
//! `I theta'' = l sin(theta) f_N - l cos(theta) f_F - (beta - alpha) f_N` (3).
//!
//! The bounds (section 4.2, made physical):
//! - `|f_F| <= min(mu f_N, leg_force_max_n)`: the floor's friction and the legs' strength;
//! - `beta` inside the support of the planted feet ([`super::feet`]): where the feet are, not a
//!   fixed reach around the body. Feet move only by steps bounded by a person's step length, step
//!   rate and foot speed, so a push the feet cannot catch in time makes the character fall;
//! - the controller never adds energy the AI did not ask for: while the body's mechanical energy
//!   (kinetic plus potential above the floor) exceeds that of standing at the AI's target speed,
//!   every part of the drive that would do positive work is dropped. After a push the body can only
//!   lose energy to the legs, so it never moves faster than the push and gravity make it.
//!
//! Balance is state feedback that puts the lean first: the velocity loop asks for an acceleration,
//! the centre of pressure that keeps the lean on its target with that acceleration is solved from
//! (3); when the feet cannot give that centre of pressure, it goes to the edge of the support, the
//! force is solved from (3) again for the lean, and the character steps toward its capture point
//! (where its centre of mass would come to rest over a foot). When neither can hold the lean, it
//! falls.
//!
//! Turning: an off-centre push spins the body about the vertical; standing feet resist the spin
//! viscously (the twist of the feet on the floor, bounded by friction), so the angle turned is
//! proportional to the push's angular impulse, and the feet follow with a settling step (the
//! character pivots on one foot).
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
//! While fallen the character brakes (friction at its contact with the floor, bounded by the
//! floor's friction) and, lying on its side, rolls itself onto its face or its back (the body's
//! convex sides make that side unstable, section 6.1), where it can stand up.
//!
//! Must never: allocate, apply a force when the body does not touch the floor, exceed the bounds
//! above, or add energy while the body has more than the AI asked for.

use glam::DVec3;

use super::feet::{horizontal, side_sign, Feet, Support};
use super::params::{ControllerParams, TiltCosines};
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
    /// The friction force f_F, applied at `at_m` (the centre of pressure beta, on the floor).
    pub force_n: DVec3,
    pub at_m: DVec3,
    /// The centre-of-pressure torque `(beta - alpha) x f_N` plus the twisting torque of the feet.
    pub torque_n_m: DVec3,
    /// Where the centre of pressure is when the controller does nothing: `alpha`, where the body
    /// itself touches the floor.
    pub rest_m: DVec3,
    /// Parts of the drive dropped this step because they would have added energy (count).
    pub dropped: u8,
}

/// The controller's own state (part of the integration state: a prediction copies it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerState {
    pub policy: Policy,
    /// Time spent in the current policy (s).
    pub in_policy_s: f64,
    /// Time the stop conditions have held while fallen (s).
    pub still_s: f64,
    /// Where the feet are.
    pub feet: Feet,
    /// Mechanical energy of the body when it last stood still (J; 0: not yet): what standing
    /// costs, the reference of the energy bound.
    pub rest_energy_j: f64,
}

impl Default for ControllerState {
    fn default() -> Self {
        ControllerState {
            policy: Policy::Balance,
            in_policy_s: 0.0,
            still_s: 0.0,
            feet: Feet::default(),
            rest_energy_j: 0.0,
        }
    }
}

/// The mechanical energy of the body (J) with its potential energy measured from `floor_y`: the
/// quantity the controller never raises above what the AI asked for.
#[inline]
pub fn body_energy_j(p: &ControllerParams, mass_kg: f64, g: f64, b: &BodySpace, floor_y: f64) -> f64 {
    let v = b.r_dot_m_per_s;
    0.5 * mass_kg * v.length_squared()
        + 0.5 * p.lean_inertia_kg_m2 * (b.theta_x_dot * b.theta_x_dot + b.theta_z_dot * b.theta_z_dot)
        + 0.5 * p.yaw_inertia_kg_m2 * b.theta_y_dot * b.theta_y_dot
        + mass_kg * g * (b.r_m.y - floor_y)
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
        let spin = b.w_world.length();
        self.transition(p, cos, dt_s, b, ground, t, speed, spin);
        self.feet.update_grip(dt_s);
        let n = ground.normal_n;
        if !(n > 0.0) {
            // In the air: nothing to push on. A swing still finishes (the foot is drawn landing).
            self.feet.advance(p, dt_s, None);
            return Drive { at_m: b.r_m, rest_m: b.r_m, ..Drive::default() };
        }
        let alpha = ground.point_m;
        let h = b.heading;
        let l = p.base_to_com_m;
        let f_max = (p.floor_friction * n).min(p.leg_force_max_n);
        // Energy: what the AI asked for is standing (or walking at its speed); above that the drive
        // may only take energy out.
        let e = body_energy_j(p, mass_kg, g_m_per_s2, b, alpha.y);
        if self.policy == Policy::Balance && speed < 0.02 && spin < 0.02 && cos_tilt > cos.stand_done {
            self.rest_energy_j = e;
        }
        let e_stand = if self.rest_energy_j > 0.0 { self.rest_energy_j } else { mass_kg * g_m_per_s2 * l };
        let v0 = t.velocity_m_per_s;
        let e_cap = e_stand + 0.5 * mass_kg * v0.length_squared() + ENERGY_SLACK_J;
        // Nor may the legs make the body move faster than the AI asks (plus a walk's sway): a
        // body leaning back lowers its potential energy, which would otherwise let the legs run it
        // backward.
        let ke = e - mass_kg * g_m_per_s2 * (b.r_m.y - alpha.y);
        let v_allow = v0.length() + KE_SWAY_M_PER_S;
        let excess = e > e_cap || ke > 0.5 * mass_kg * v_allow * v_allow;
        let mut drive = match self.policy {
            Policy::Balance => self.balance(p, mass_kg, g_m_per_s2, dt_s, b, alpha, n, t, excess),
            Policy::Fall | Policy::Down => self.brake(p, mass_kg, dt_s, b, alpha, n),
            Policy::StandUp => self.stand_up(p, cos, mass_kg, g_m_per_s2, b, alpha),
        };
        // |f_F| within [f_F_min, f_F_max]: below the minimum the legs do not react.
        let f_len = drive.force_n.length();
        if f_len > f_max {
            drive.force_n *= f_max / f_len;
        } else if f_len < p.leg_force_min_n {
            drive.force_n = DVec3::ZERO;
        }
        // Turning: toward the AI's heading, or only damped; the feet's twist is friction-limited.
        let yaw_acc = match (self.policy, t.heading) {
            (Policy::Balance, Some(dir)) => {
                let (wy, ky) = (p.yaw_omega_rad_per_s, p.yaw_omega_rad_per_s.powi(2));
                ky * h.angle_to(dir) - 2.0 * wy * b.theta_y_dot
            }
            _ => -p.yaw_damping_per_s * b.theta_y_dot,
        };
        let yaw_max = n * p.yaw_arm_m;
        let tau_y = (p.yaw_inertia_kg_m2 * yaw_acc).clamp(-yaw_max, yaw_max);
        drive.torque_n_m += DVec3::Y * tau_y;
        // Standing up is the AI's own doing (section 6.1): it spends what getting up costs, which
        // ends at the standing energy the bound refers to.
        if excess && self.policy != Policy::StandUp {
            drive = passive(drive, b, alpha, n, tau_y);
        }
        drive
    }

    /// Fig. 3's transitions between the policies, from the lean (`b`), the body's horizontal
    /// `speed` and `spin`, the floor's contact and what the AI allows.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn transition(
        &mut self,
        p: &ControllerParams,
        cos: &TiltCosines,
        dt_s: f64,
        b: &BodySpace,
        ground: &Ground,
        t: &Targets,
        speed: f64,
        spin: f64,
    ) {
        let cos_tilt = b.e_yr.y;
        match self.policy {
            Policy::Balance if cos_tilt < cos.fall => {
                self.enter(Policy::Fall);
                self.feet.release();
            }
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
                    self.feet.release();
                }
            }
            Policy::Balance => {}
        }
    }

    /// The Fall and Down policies: friction at the contact `alpha` opposing its slip, viscous
    /// below the floor's bound, the spin braked and a body on its side rolled over.
    #[inline]
    fn brake(
        &mut self,
        p: &ControllerParams,
        mass_kg: f64,
        dt_s: f64,
        b: &BodySpace,
        alpha: DVec3,
        n: f64,
    ) -> Drive {
        let v_alpha = horizontal(b.r_dot_m_per_s + b.w_world.cross(alpha - b.r_m));
        let force = -v_alpha * (p.brake_rate_per_s * mass_kg);
        let spin_max = n * p.brake_arm_m;
        let w_h = horizontal(b.w_world);
        let mut torque = clamp_len(-w_h * (p.brake_spin_rate_per_s * p.lean_inertia_kg_m2), spin_max);
        torque += roll_torque(b, n * p.roll_arm_m);
        self.feet.advance(p, dt_s, None);
        Drive { force_n: force, at_m: alpha, torque_n_m: torque, rest_m: alpha, dropped: 0 }
    }

    /// The StandUp policy: PD control of the lean back to upright about the base `alpha`, the slip
    /// braked, the feet put down under the body once it is nearly up.
    #[inline]
    fn stand_up(
        &mut self,
        p: &ControllerParams,
        cos: &TiltCosines,
        mass_kg: f64,
        g_m_per_s2: f64,
        b: &BodySpace,
        alpha: DVec3,
    ) -> Drive {
        let (i, l, h) = (p.lean_inertia_kg_m2, p.base_to_com_m, b.heading);
        let (kp, kd) = (p.stand_omega_rad_per_s.powi(2), 2.0 * p.stand_omega_rad_per_s);
        let v_alpha = horizontal(b.r_dot_m_per_s + b.w_world.cross(alpha - b.r_m));
        let force = -v_alpha * (p.brake_rate_per_s * mass_kg);
        // The body turns about its base, not its centre of mass: the inertia the lean loop
        // moves is that about the base.
        let i_base = i + mass_kg * l * l;
        let up = |th: f64, sin_th: f64, th_dot: f64| {
            (i_base * (-kp * th - kd * th_dot) - mass_kg * g_m_per_s2 * l * sin_th)
                .clamp(-p.stand_torque_max_n_m, p.stand_torque_max_n_m)
        };
        let tau_x = up(b.theta_x, b.sin_cos_x.0, b.theta_x_dot);
        let tau_z = up(b.theta_z, b.sin_cos_z.0, b.theta_z_dot);
        // Nearly up: the feet go down under the body, where it will stand.
        if !self.feet.placed && b.e_yr.y > cos.fall {
            self.feet.place(p, alpha, h.e_xc, alpha.y);
        }
        Drive {
            force_n: force,
            at_m: alpha,
            torque_n_m: h.e_xc * tau_x - h.e_zc * tau_z,
            rest_m: alpha,
            dropped: 0,
        }
    }

    /// The Balance policy: stepping and the bounded balance law (see the module docs).
    #[allow(clippy::too_many_arguments)]
    fn balance(
        &mut self,
        p: &ControllerParams,
        mass_kg: f64,
        g: f64,
        dt_s: f64,
        b: &BodySpace,
        alpha: DVec3,
        n: f64,
        t: &Targets,
        excess: bool,
    ) -> Drive {
        let h = b.heading;
        let (i, l) = (p.lean_inertia_kg_m2, p.base_to_com_m);
        if !self.feet.placed {
            self.feet.place(p, alpha, h.e_xc, alpha.y);
        }
        let com = horizontal(b.r_m) + DVec3::Y * alpha.y;
        let v = horizontal(b.r_dot_m_per_s);
        let w0 = p.omega0(g);
        // The capture point: where a foot must be for the body to come to rest over it.
        let capture = com + v / w0;
        let v0 = horizontal(t.velocity_m_per_s);
        // Where a step should land: the capture point, shifted to the foot's own side.
        let aim = |k: usize| capture + h.e_xc * (side_sign(k) * p.hip_half_width_m * 0.5);
        // A swing in progress keeps aiming at the moving capture point.
        let retarget = self.feet.swinging().map(|k| self.feet.reachable(p, k, aim(k), h.e_xc, h.e_zc));
        self.feet.advance(p, dt_s, retarget);
        // The lean and velocity the AI wants.
        let (kp, kd) = (p.lean_omega_rad_per_s.powi(2), 2.0 * p.lean_zeta * p.lean_omega_rad_per_s);
        let acc = |v0: f64, v: f64| {
            (p.velocity_gain_per_s * (v0 - v)).clamp(-p.accel_max_m_per_s2, p.accel_max_m_per_s2)
        };
        let (v_side, v_front) = b.velocity_sc();
        let (v0_side, v0_front) = (v0.dot(h.e_xc), v0.dot(h.e_zc));
        let f_want = (acc(v0_side, v_side) * mass_kg, acc(v0_front, v_front) * mass_kg);
        let th_acc = (
            -kp * (b.theta_z - t.theta_z0) - kd * b.theta_z_dot,
            -kp * (b.theta_x - t.theta_x0) - kd * b.theta_x_dot,
        );
        // Equation 3 solved for the centre of pressure (offset from alpha) per axis.
        let cop = |(s, c): (f64, f64), f: f64, acc: f64| (n * l * s - l * c * f - i * acc) / n;
        let d_want = (cop(b.sin_cos_z, f_want.0, th_acc.0), cop(b.sin_cos_x, f_want.1, th_acc.1));
        let beta_want = alpha + h.e_xc * d_want.0 + h.e_zc * d_want.1;
        // Step when the feet cannot hold the body: the capture point (or the wanted centre of
        // pressure) is outside the support, or a planted foot is out of the legs' reach; or, nearly
        // still, to stand square under the body.
        let slid = self.feet.drag(p, com);
        let support = self.feet.support(p);
        if self.feet.swinging().is_none() && self.feet.since_land_s >= p.stance_min_s {
            self.maybe_step(p, b, com, capture, v, v0, support, beta_want, &aim);
        }
        let Some(support) = self.feet.support(p) else {
            return Drive { at_m: alpha, rest_m: alpha, ..Drive::default() };
        };
        if slid {
            // The feet trail at the legs' full reach and slide: no balance, only their friction,
            // where they are.
            let (mut rest, _) = support.project(alpha);
            rest.y = alpha.y;
            let v_rest = horizontal(b.r_dot_m_per_s + b.w_world.cross(rest - b.r_m));
            let f_max = (p.floor_friction * n).min(p.leg_force_max_n);
            let force = -v_rest * (f_max / v_rest.length().max(0.05));
            return Drive {
                force_n: force,
                at_m: rest,
                torque_n_m: (rest - alpha).cross(DVec3::Y * n),
                rest_m: alpha,
                dropped: 0,
            };
        }
        let (beta, _) = support.project(beta_want);
        let d = ((beta - alpha).dot(h.e_xc), (beta - alpha).dot(h.e_zc));
        // Where the centre of pressure had to give way, the force holds the lean instead (3): the
        // feet move under the body. Not while the body has more energy than the AI asked for: that
        // would run under a fall with energy the legs add; then the velocity loop keeps braking
        // and the lean gives (the step catches it, or the character falls).
        let lean_force =
            |(s, c): (f64, f64), d: f64, acc: f64| (n * (l * s - d) - i * acc) / (l * c.max(0.2));
        let given = |d: f64, d_want: f64| excess || (d - d_want).abs() < 1e-9;
        let f_side = if given(d.0, d_want.0) { f_want.0 } else { lean_force(b.sin_cos_z, d.0, th_acc.0) };
        let f_front = if given(d.1, d_want.1) { f_want.1 } else { lean_force(b.sin_cos_x, d.1, th_acc.1) };
        let mut beta = beta;
        beta.y = alpha.y;
        Drive {
            force_n: h.to_world(f_side, f_front),
            at_m: beta,
            torque_n_m: (beta - alpha).cross(DVec3::Y * n),
            rest_m: alpha,
            dropped: 0,
        }
    }

    /// Decides whether to start a step now, and with which foot.
    #[allow(clippy::too_many_arguments)]
    fn maybe_step(
        &mut self,
        p: &ControllerParams,
        b: &BodySpace,
        com: DVec3,
        capture: DVec3,
        v: DVec3,
        v0: DVec3,
        support: Option<Support>,
        beta_want: DVec3,
        aim: &dyn Fn(usize) -> DVec3,
    ) {
        let h = b.heading;
        let out_of_reach =
            |k: usize| horizontal(self.feet.foot[k].pos_m - com).length() > 0.9 * p.leg_reach_m;
        let outside = match support {
            Some(s) => s.project(capture).1 > 0.0 || s.project(beta_want).1 > 0.02,
            None => true,
        };
        if outside || out_of_reach(0) || out_of_reach(1) {
            // The foot that, landed, makes the support nearest the capture point; a foot out of
            // reach must go first.
            let mut best = (f64::INFINITY, 0usize, DVec3::ZERO);
            for k in 0..2 {
                if out_of_reach(1 - k) && !out_of_reach(k) {
                    continue;
                }
                let stance = self.feet.foot[1 - k].pos_m;
                let to = self.feet.reachable(p, k, aim(k), h.e_xc, h.e_zc);
                if horizontal(to - self.feet.foot[k].pos_m).length() < 0.02 {
                    continue;
                }
                // How far inside the landed feet the capture point is (the margin to brake) ...
                let s = Support { a_m: stance, b_m: to, radius_m: p.foot_support_m };
                let miss = s.signed_distance(capture);
                // ... and, while it swings, how far the centre of mass is outside the other foot:
                // lift the unloaded foot when it can do the job.
                let alone = Support { a_m: stance, b_m: stance, radius_m: p.foot_support_m };
                let loaded = alone.project(com).1;
                let cost = miss + 2.0 * loaded;
                if cost < best.0 {
                    best = (cost, k, to);
                }
            }
            if best.0.is_finite() {
                self.feet.lift(p, best.1, best.2, false);
            }
            return;
        }
        // Settling: nearly still and not asked to walk, a foot away from where standing puts it
        // steps there (one at a time: the other is the pivot).
        if v.length() < 0.15 && v0.length() < 0.05 {
            let home = |k: usize| {
                let mut at = com + h.e_xc * (side_sign(k) * p.hip_half_width_m);
                at.y = self.feet.foot[k].pos_m.y;
                at
            };
            let err = |k: usize| horizontal(self.feet.foot[k].pos_m - home(k)).length();
            // The foot farther from the centre of mass carries less: it steps, the other pivots.
            let far = |k: usize| horizontal(self.feet.foot[k].pos_m - com).length();
            let k = if far(0) >= far(1) { 0 } else { 1 };
            let k = if err(k) > p.settle_step_m { k } else { 1 - k };
            let alone = Support {
                a_m: self.feet.foot[1 - k].pos_m,
                b_m: self.feet.foot[1 - k].pos_m,
                radius_m: p.foot_support_m,
            };
            if err(k) > p.settle_step_m && alone.project(com).1 == 0.0 {
                let to = self.feet.reachable(p, k, home(k), h.e_xc, h.e_zc);
                if horizontal(to - self.feet.foot[k].pos_m).length() > 0.5 * p.settle_step_m {
                    self.feet.lift(p, k, to, true);
                }
            }
        }
    }
}

/// Energy above the AI's target the controller tolerates before it only brakes (J): keeps the
/// rule from chattering about the standing energy, which the contact's springiness moves by
/// millijoules.
const ENERGY_SLACK_J: f64 = 1.0;
/// Speed above the AI's target the kinetic-energy bound leaves for a walk's sway (m/s).
const KE_SWAY_M_PER_S: f64 = 0.35;

/// The drive made to do no positive work on the body, changing it as little as that takes: first
/// the force is scaled down, then the centre of pressure moved back toward where the feet's place
/// puts it (`rest_m`), then the twist dropped.
fn passive(d: Drive, b: &BodySpace, alpha: DVec3, n: f64, tau_y: f64) -> Drive {
    let w = b.w_world;
    let cop = d.torque_n_m - DVec3::Y * tau_y;
    let rest = (d.rest_m - alpha).cross(DVec3::Y * n);
    let v_at = |at: DVec3| b.r_dot_m_per_s + w.cross(at - b.r_m);
    let p_force = d.force_n.dot(v_at(d.at_m));
    let (p_cop, p_rest, p_yaw) = ((cop - rest).dot(w), rest.dot(w), tau_y * w.y);
    let mut out = d;
    let mut rest_p = p_rest + p_cop + p_yaw;
    // The force: scaled so the whole does no work (or dropped).
    let fs = if p_force > 0.0 { (-rest_p / p_force).clamp(0.0, 1.0) } else { 1.0 };
    out.force_n = d.force_n * fs;
    out.dropped += (fs < 1.0) as u8;
    rest_p = p_rest + p_yaw + p_force.min(0.0) + p_force.max(0.0) * fs;
    // The centre of pressure's chosen part.
    let cs = if p_cop > 0.0 && rest_p + p_cop > 0.0 { (-rest_p / p_cop).clamp(0.0, 1.0) } else { 1.0 };
    out.at_m = d.rest_m + (d.at_m - d.rest_m) * cs;
    let mut torque = rest + (cop - rest) * cs;
    out.dropped += (cs < 1.0) as u8;
    // The twist.
    if p_yaw > 0.0 && p_rest + p_cop * cs + p_force.min(0.0) + p_force.max(0.0) * fs > 0.0 {
        out.dropped += 1;
    } else {
        torque += DVec3::Y * tau_y;
    }
    out.torque_n_m = torque;
    out
}

/// Lying on its side, the torque that rolls the body onto its face (or its back, if it faces up
/// already), about its long axis, of at most `max_n_m`.
#[inline]
fn roll_torque(b: &BodySpace, max_n_m: f64) -> DVec3 {
    // Lying: the trunk axis near the floor's plane; on the side: the body's own left axis (e_xr)
    // near the vertical.
    if b.e_yr.y.abs() > 0.5 || b.e_xr.y.abs() < 0.25 {
        return DVec3::ZERO;
    }
    // Rolling about e_yr by phi changes e_xr.y at -e_zr.y per radian and e_zr.y at +e_xr.y.
    let face = if b.e_zr.y > 0.0 { 1.0 } else { -1.0 };
    let dir = b.e_xr.y.signum() * face;
    b.e_yr * (dir * max_n_m)
}

#[inline]
fn clamp_len(v: DVec3, max: f64) -> DVec3 {
    let l = v.length();
    if l > max {
        v * (max / l)
    } else {
        v
    }
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
