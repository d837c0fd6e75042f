//! A simulated rig whose true geometry is wrong on purpose: what calibration is tried and tested
//! against without hardware.
//!
//! The truth differs from the configured rig as a hand-built one does: every anchor is off by
//! centimetres in a random direction, every string's metres per count by up to `mpc_error`, and
//! the counters start at arbitrary values. The grips are held stiffly (a jig, or a firm hand:
//! 1e5 N/m), so the 1 N holding tension moves them by tens of micrometres, not millimetres.
//! Deterministic for a seed; it must never share state with the configured rig it perturbs.

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use spidar_device::sim::{Script, SimHandParams, SimRig, SimRigParams, SimString};
use spidar_rt::Rig;

use crate::model::HandGeometry;
use crate::CalibError;

/// Arm stiffness and damping of the simulated operator while calibrating (critically damped for 1 kg).
pub const STIFF_ARM_K_N_PER_M: f64 = 1e5;
pub const STIFF_ARM_D_N_S_PER_M: f64 = 632.0;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimTruthOptions {
    pub seed: u64,
    /// Each anchor is moved by 0.5 .. 1 times this, in a random direction.
    pub anchor_error_m: f64,
    /// Each string's metres per count is the configured one times 1 +- (0.8 .. 1) this.
    pub mpc_error: f64,
    /// Gaussian encoder noise (counts, standard deviation) before quantisation.
    pub noise_counts: f64,
}

impl Default for SimTruthOptions {
    fn default() -> Self {
        SimTruthOptions { seed: 1, anchor_error_m: 0.05, mpc_error: 0.10, noise_counts: 0.5 }
    }
}

/// The true geometry of the simulated rig for `rig` perturbed as `opts` says.
pub fn truth_geometry(rig: &Rig, opts: &SimTruthOptions) -> [HandGeometry; 2] {
    let mut rng = Pcg64Mcg::seed_from_u64(opts.seed ^ 0xca11_b8a7e);
    std::array::from_fn(|h| {
        let hr = &rig.hands[h];
        let mut g = HandGeometry {
            anchors_m: hr.anchors_m,
            length_at_zero_m: [0.0; 4],
            metres_per_count: hr.metres_per_count,
        };
        for i in 0..4 {
            let dir = loop {
                let v = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                if (0.1..1.0).contains(&v.length()) {
                    break v.normalize();
                }
            };
            g.anchors_m[i] += dir * opts.anchor_error_m * rng.random_range(0.5..1.0);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            g.metres_per_count[i] *= 1.0 + sign * opts.mpc_error * rng.random_range(0.8..1.0);
            // Counters start anywhere: the length at count zero is the home length +- 0.5 m.
            g.length_at_zero_m[i] = (g.anchors_m[i] - hr.home_m).length() + rng.random_range(-0.5..0.5);
        }
        g
    })
}

/// The simulated rig with this truth, grips held stiffly at their home points.
pub fn sim_rig(
    rig: &Rig,
    truth: &[HandGeometry; 2],
    noise_counts: f64,
    seed: u64,
) -> Result<SimRig, CalibError> {
    let hands = std::array::from_fn(|h| {
        let hr = &rig.hands[h];
        let g = &truth[h];
        let strings = std::array::from_fn(|i| SimString {
            anchor_m: g.anchors_m[i],
            channel: hr.channels[i],
            metres_per_count: g.metres_per_count[i],
            length_at_zero_m: g.length_at_zero_m[i],
            volts_per_newton: hr.volts_per_newton[i],
            tension_max_n: hr.tension_max_n,
        });
        let mut p = SimHandParams::new(strings, hr.home_m);
        p.arm_k_n_per_m = STIFF_ARM_K_N_PER_M;
        p.arm_d_n_s_per_m = STIFF_ARM_D_N_S_PER_M;
        p
    });
    let mut p = SimRigParams::with_defaults(hands);
    p.period_s = rig.period_s;
    p.encoder_noise_counts = noise_counts;
    p.seed = seed;
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    Ok(SimRig::new(p, [Script::hold(home[0]), Script::hold(home[1])])?)
}
