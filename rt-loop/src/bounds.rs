//! The physical bounds of a rig file, in one place: what a value may be so that the rig cannot be
//! asked for danger, and why. `rig.rs` applies them while validating; a board's own range (what
//! its command means: DA volts, PWM duty, current target) plugs in through [`check_board_range`].
//!
//! Two kinds of limit:
//! - *hard* limits make the code meaningless when broken (a non-finite number, a zero force limit
//!   that would divide by zero, a fade of `-0.0` that never fades): never overridable;
//! - *physical* limits come from the hardware and the physics of the rig (below). A rig file may
//!   go beyond one only by naming its key in its `overrides` list; the run summary shows every
//!   override in effect.
//!
//! Nothing here runs in the tick.

use glam::DVec3;

use crate::tension::{Allocator, TensionLimits};

pub use crate::config::{Bound, Limit};

/// Lowest tension that keeps a string of a human-scale rig taut: below about 0.3 N a 3 m string
/// sags and its encoder reads long.
pub const TENSION_MIN_N: Bound = Bound::physical(
    "tension_min_n",
    0.3,
    3.0,
    "N",
    "strings need at least 0.3 N to stay taut, and the safe output (faults, inactive, stop) holds \
          every string at this tension: more than 3 N is felt as a pull when the rig should be quiet \
          (the lab used 0.5 .. 1 N)",
);

/// The SPIDAR-H's motors deliver about 20 N per string.
pub const TENSION_MAX_N: Bound = Bound::physical(
    "tension_max_n",
    1.0,
    25.0,
    "N",
    "the SPIDAR-H's motors deliver about 20 N per string; more is beyond the motors, not a setting",
);

/// The user's arm and the string drive damp a grip by at least this much (N s/m).
pub const GRIP_DAMPING_N_S_PER_M: Bound = Bound::physical(
    "grip_damping_n_s_per_m",
    0.5,
    30.0,
    "N s/m",
    "a lower estimate of the damping a relaxed arm holding the grip gives (a few N s/m); \
          overestimating it allows contacts stiff enough to buzz",
);

/// Metres of string per encoder count: any pulley and encoder of a string rig.
pub const METRES_PER_COUNT: Bound = Bound::physical(
    "metres_per_count",
    1e-6,
    1e-3,
    "m",
    "SPIDAR pulleys and encoders give 2.5e-5 .. 3e-5 m per count; 1e-6 .. 1e-3 m covers any \
          pulley and encoder a string rig uses (the sign only gives the counting direction)",
);

/// DA volts per newton of string tension.
pub const VOLTS_PER_NEWTON: Bound = Bound::physical(
    "volts_per_newton",
    0.02,
    1.0,
    "V/N",
    "the SPIDAR-H's amplifiers need 0.2 V/N, the desktop motors 0.37 V/N; 0.02 .. 1 V/N covers \
          any motor and amplifier of a string rig (the sign only gives the winding direction)",
);

/// The string length at counter zero.
pub const LENGTH_AT_ZERO_M: Bound = Bound::physical(
    "length_at_zero_m",
    0.0,
    20.0,
    "m",
    "a string's length is never negative: a negative length at counter zero means the counters \
          were not reset as the file assumes (home the rig instead)",
);

/// Radius of the fist's sphere in contact rendering.
pub const GRIP_RADIUS_M: Bound =
    Bound::physical("grip_radius_m", 0.01, 0.15, "m", "a fist is 3 .. 6 cm in radius");

/// Force ramps: the shortest ramp still felt as a ramp rather than a knock.
const RAMP_WHY: &str =
    "force must rise and fall over at least 50 ms (0 s is a step of full force into the hand)";
/// The ramp-in after activation and after a fault clears.
pub const RAMP_IN_S: Bound = Bound::physical("ramp_in_s", 0.05, 10.0, "s", RAMP_WHY);
/// The ramp-out on stop.
pub const RAMP_OUT_S: Bound = Bound::physical("ramp_out_s", 0.05, 10.0, "s", RAMP_WHY);

/// Age at which a contact model is stale and its force starts to fade.
pub const CONTACT_STALE_AFTER_S: Bound = Bound::physical(
    "contact_stale_after_s",
    0.005,
    0.1,
    "s",
    "the world sends a contact model every 3 ms step: a model is stale once it misses a couple of \
     steps (the default 30 ms is ten), and one older than 100 ms renders contacts where things were \
     a tenth of a second ago (20 cm behind a 2 m/s punch)",
);

/// Time for a stale contact model's force to fade out.
pub const CONTACT_FADE_S: Bound = Bound::physical(
    "contact_fade_s",
    0.01,
    1.0,
    "s",
    "a stale model's force must fade within a second (and over at least 10 ms, not as a step)",
);

/// Pose residual above which a pose is not trusted.
pub const RESIDUAL_FAULT_M: Bound = Bound::physical(
    "residual_fault_m",
    1e-4,
    0.01,
    "m",
    "a sound rig's residual is a few counts (0.1 mm); above 1 cm a slack string or a slipped \
          encoder would drive forces from a pose centimetres off",
);

/// Ticks in a row of high residual before the fault.
pub const RESIDUAL_FAULT_TICKS: Bound = Bound::physical(
    "residual_fault_ticks",
    1.0,
    100.0,
    "ticks",
    "an inconsistent pose must fault within 100 ticks (a larger count switches the pose check off)",
);

/// Good exchanges in a row before a transient fault clears (0, never, is always allowed).
pub const FAULT_RECOVERY_TICKS: Bound = Bound::physical(
    "fault_recovery_ticks",
    10.0,
    60_000.0,
    "ticks",
    "a link must answer at least 10 times in a row before force returns (0 = never recover)",
);

/// Ticks in a row without a usable reply, each holding the last output, before the fault.
pub const REPLY_FAULT_TICKS: Bound = Bound::physical(
    "reply_fault_ticks",
    1.0,
    20.0,
    "ticks",
    "the last output may be held for at most 20 ms of missing replies; then the rig must go safe",
);

/// Largest step of a string length from its prediction accepted in one tick.
pub const REPLY_JUMP_M: Bound = Bound::physical(
    "reply_jump_m",
    5e-4,
    0.02,
    "m",
    "a hand moves a string by less than a centimetre per tick beyond what its velocity predicts; \
          a larger tolerance lets corrupt counts through, a smaller one rejects real motion",
);

/// How still the grips must be held for the rig to home itself after homing was lost.
pub const REHOME_STILL_M: Bound = Bound::physical(
    "rehome_still_m",
    2e-4,
    0.01,
    "m",
    "a held grip moves each string by a millimetre or two; the tolerance must exceed the encoder \
          noise (at least 10 counts is checked too) and stay below a centimetre",
);

/// How long the grips must be held still for the rig to home itself.
pub const REHOME_STILL_S: Bound = Bound::physical(
    "rehome_still_s",
    0.3,
    10.0,
    "s",
    "the grips must rest at least 0.3 s so that a moving hand is never taken for a held one",
);

/// The stiffest penalty contact that stays stable on a grip with physical damping `b_n_s_per_m`
/// when rendered every `period_s`: `K_max = 2 b / (3 T)`.
///
/// Derivation (ours). A grip of mass `m` with physical damping `b` (the arm, the drive) touches a
/// virtual spring `K`. The loop reads the position at tick `k` and the force computed from it is
/// written at the next exchange and held for one period (zero-order hold), so the spring acts with
/// an average delay of `1.5 T`. For `w T << 1` (w = sqrt(K / m)) a delayed spring is
/// `K x(t - 1.5 T) ~ K x(t) - 1.5 K T v(t)`: it adds a negative damping of `1.5 K T`. The contact is
/// stable while the net damping stays positive, `b + D - 1.5 K T > 0`, that is
/// `K < 2 (b + D) / (3 T)`, with `D` the contact's own damping. A proxy's damping is not known when
/// the rig file is read, so the rig's stiffness limit uses `D = 0`: every contact is then stable
/// whatever damping the scene gives it. The unit test `stiffness_bound_separates_decay_from_growth`
/// integrates the sampled system finely and shows a contact 10 % below the bound decaying and
/// one 10 % above it growing (the true bound is 1 .. 2 % above ours; the mass drops out to first
/// order).
pub fn stiffness_limit_n_per_m(b_n_s_per_m: f64, period_s: f64) -> f64 {
    2.0 * b_n_s_per_m / (3.0 * period_s)
}

/// What the configured board can command: its DA (or duty, or current target) range in volts of
/// the host scale, checked against each string's `tension_max_n x |volts_per_newton|`.
/// Returns one line per string that the board would clip, empty when all fit.
pub fn check_board_range(
    tension_max_n: [f64; 2],
    volts_per_newton: [[f64; 4]; 2],
    volts_max: f64,
) -> Vec<String> {
    let mut out = Vec::new();
    for (h, vpn) in volts_per_newton.iter().enumerate() {
        for (s, v) in vpn.iter().enumerate() {
            let need = tension_max_n[h] * v.abs();
            // Written so that a NaN need does not fit either.
            let fits = need <= volts_max + 1e-9;
            if !fits {
                out.push(format!(
                    "hand {h} string {s}: {} N needs {need:.2} V, the board stops at {volts_max:.2} V ({:.1} N)",
                    tension_max_n[h],
                    volts_max / v.abs()
                ));
            }
        }
    }
    out
}

/// Smallest barycentric weight a home point must have in its hand's anchor tetrahedron (1 %):
/// strictly inside, where the strings can hold zero net force at minimum tension.
pub const HOME_INSIDE_MARGIN: f64 = 0.01;

/// The smallest barycentric weight of `p` in the tetrahedron of `anchors`: positive inside,
/// negative outside, about 0.25 at the centre. NaN for a degenerate tetrahedron.
pub fn inside_margin(anchors: &[DVec3; 4], p: DVec3) -> f64 {
    let [a0, a1, a2, a3] = *anchors;
    let vol = |a: DVec3, b: DVec3, c: DVec3, d: DVec3| (b - a).cross(c - a).dot(d - a);
    let total = vol(a0, a1, a2, a3);
    let w = [vol(p, a1, a2, a3), vol(a0, p, a2, a3), vol(a0, a1, p, a3), vol(a0, a1, a2, p)];
    w.iter().map(|wi| wi / total).fold(f64::INFINITY, f64::min)
}

/// The largest force the four strings can produce on a grip at `p` with tensions in
/// `[min_n, max_n]`: the allocator asked for a force far beyond reach in each of 26 directions
/// (axes, face and space diagonals), the largest it renders.
pub fn force_capacity_n(anchors: &[DVec3; 4], p: DVec3, min_n: f64, max_n: f64) -> f64 {
    let dirs = anchors.map(|a| (a - p).normalize_or_zero());
    let mut alloc = Allocator::new(TensionLimits { min_n, max_n });
    let mut best: f64 = 0.0;
    for x in -1..=1 {
        for y in -1..=1 {
            for z in -1..=1 {
                let d = DVec3::new(x as f64, y as f64, z as f64);
                if d == DVec3::ZERO {
                    continue;
                }
                let want = d.normalize() * 8.0 * max_n;
                best = best.max(alloc.allocate(&dirs, want).force_n.length());
            }
        }
    }
    best
}

/// An anchor's distance from the rig frame's origin, the centre of the workspace.
pub const ANCHOR_FROM_CENTRE_M: Bound = Bound::physical(
    "anchor_m",
    0.1,
    5.0,
    "m",
    "the rig frame's origin is the centre of the workspace: a SPIDAR-H puts its anchors about 2 .. 2.5 m \
     from it (a desktop SPIDAR about 0.2 m); beyond 5 m a string would be longer than the room, a typo \
     or a unit slip, and nearer than 0.1 m there is no room for a hand",
);

/// The velocity estimate's low-pass cut-off against the tick rate (the upper end is set per rig:
/// a tenth of the tick rate, see [`velocity_cutoff_hz`]).
pub const VELOCITY_CUTOFF_HZ: Bound = Bound::physical(
    "velocity_cutoff_hz",
    1.0,
    100.0,
    "Hz",
    "the filter acts as a low-pass only well below the Nyquist frequency, half the tick rate: above a \
     tenth of the tick rate (100 Hz at 1 kHz) it passes the encoder's count steps through as velocity \
     spikes that the damping forces turn into buzz, and below 1 Hz the estimate lags a moving hand by \
     more than 0.15 s",
);

/// [`VELOCITY_CUTOFF_HZ`] for a loop ticking every `period_s`.
pub fn velocity_cutoff_hz(period_s: f64) -> Bound {
    VELOCITY_CUTOFF_HZ.between(VELOCITY_CUTOFF_HZ.lo, 0.1 / period_s)
}

// ---------------------------------------------------------------------------------------------
// Hard limits: outside them the rule itself breaks. Never overridable. Those that depend on the
// tick period are completed by the functions below them.

/// The tick period.
pub const PERIOD_S: Bound = Bound::hard(
    "period_s",
    1e-4,
    1e-2,
    "s",
    "the loop runs between 100 Hz and 10 kHz: the stability bound, the ramps and the boards' protocols \
     assume a tick of 0.1 .. 10 ms",
);

/// Each coordinate of an anchor, the home point and the eye point (rig frame).
pub const COORDINATE_M: f64 = 20.0;

/// The eye point's coordinates (rig frame).
pub const EYE_M: f64 = 10.0;

/// The rig file's `near_strings.distance_m`: 0 marks only strings that touch; from 20 cm nearly
/// every string of a hand's reach is near another.
pub const NEAR_STRINGS_M: Bound = Bound::hard(
    "distance_m",
    0.0,
    0.2,
    "m",
    "0 marks only strings that touch, and from 20 cm every string is near",
);
/// The forearm capsule of `near_strings`: the wrist within a fist's reach of the grip's centre,
/// the elbow a forearm's length from it, a forearm's radius.
pub const FOREARM_WRIST_M: Bound =
    Bound::hard("forearm_wrist_m", 0.0, 0.25, "m", "the wrist is within a fist's length of the grip");
pub const FOREARM_ELBOW_M: Bound =
    Bound::hard("forearm_elbow_m", 0.05, 0.8, "m", "an adult forearm is 0.2 .. 0.35 m long");
pub const FOREARM_RADIUS_M: Bound =
    Bound::hard("forearm_radius_m", 0.0, 0.15, "m", "a forearm is 3 .. 6 cm in radius");

/// How often a lost device is reopened (0: never).
pub const DEVICE_REOPEN_S: Bound = Bound::hard(
    "device_reopen_s",
    0.0,
    60.0,
    "s",
    "0 never reopens; a minute is the longest wait that is still a retry",
);

/// A ramp's length.
pub const RAMP_HARD_S: Bound =
    Bound::hard("ramp_in_s / ramp_out_s", 0.0, 10.0, "s", "a ramp is a length of time");

/// Staleness and fade: at least one tick, or the model is stale (or gone) before it is used.
const TICK_WHY: &str = "the loop cannot act on less than one tick";
pub fn contact_stale_after_s_hard(period_s: f64) -> Bound {
    Bound::hard("contact_stale_after_s", period_s, 1.0, "s", TICK_WHY)
}
pub fn contact_fade_s_hard(period_s: f64) -> Bound {
    Bound::hard(
        "contact_fade_s",
        period_s,
        5.0,
        "s",
        "a fade of 0 or -0.0 never fades, and one tick is a step",
    )
}

/// How long a contact model may push the hand at all: staleness plus fade.
pub const CONTACT_FELT_S: Bound = Bound::hard(
    "contact_stale_after_s + contact_fade_s",
    0.0,
    1.0,
    "s",
    "a contact model must push the hand no more once it is a second old, whatever the overrides: by then \
     the world it shows has moved on (or is gone) and the hand would be pushed by what is no longer there",
);

/// The pose residual and the reply jump (metres).
pub const RESIDUAL_HARD_M: Bound = Bound::hard(
    "residual_fault_m",
    1e-5,
    1.0,
    "m",
    "below 10 um no encoder can judge it, above 1 m nothing is checked",
);
pub const REPLY_JUMP_HARD_M: Bound = Bound::hard(
    "reply_jump_m",
    1e-5,
    1.0,
    "m",
    "below 10 um no encoder can judge it, above 1 m nothing is checked",
);

/// How long the grips must rest to rehome: at least a tick.
pub fn rehome_still_s_hard(period_s: f64) -> Bound {
    Bound::hard("rehome_still_s", period_s, 60.0, "s", TICK_WHY)
}

/// Gauss-Newton iterations per tick.
pub const GAUSS_NEWTON_ITERATIONS: Bound = Bound::hard(
    "gauss_newton_iterations",
    1.0,
    10.0,
    "",
    "the closed-form seed needs at least one iteration to use all four strings, and more than 10 only \
     spends the tick (it converges in two)",
);

/// Every key an `overrides` list may name.
pub const OVERRIDABLE: [&str; 23] = [
    "tension_min_n",
    "tension_max_n",
    "force_limit_n",
    "stiffness_limit_n_per_m",
    "grip_damping_n_s_per_m",
    "grip_radius_m",
    "home_m",
    "metres_per_count",
    "volts_per_newton",
    "length_at_zero_m",
    "ramp_in_s",
    "ramp_out_s",
    "contact_fade_s",
    "residual_fault_m",
    "residual_fault_ticks",
    "fault_recovery_ticks",
    "reply_fault_ticks",
    "reply_jump_m",
    "rehome_still",
    "board_range",
    "contact_stale_after_s",
    "anchor_m",
    "velocity_cutoff_hz",
];

#[cfg(test)]
mod tests {
    use super::*;

    /// Largest displacement over the last `tail` ticks of a grip (mass `m`, damping `b`) pushed
    /// 1 mm into a spring `k` that the loop renders as it does: sampled every `t`, written one
    /// tick later and held. Integrated exactly enough (200 sub-steps per tick).
    fn late_amplitude(m: f64, b: f64, k: f64, t: f64) -> f64 {
        let (mut x, mut v) = (1e-3, 0.0);
        let mut sampled = x; // the sample the force of the coming period was computed from
        let sub = 200;
        let h = t / sub as f64;
        let (ticks, tail) = (8000, 1000);
        let mut amp: f64 = 0.0;
        for tick in 0..ticks {
            let force = k * sampled;
            let next_sample = x; // read at this tick, used from the next one
            for _ in 0..sub {
                let a = (-force - b * v) / m;
                v += a * h;
                x += v * h;
            }
            sampled = next_sample;
            if tick >= ticks - tail {
                amp = amp.max(x.abs());
            }
        }
        amp
    }

    #[test]
    fn stiffness_bound_separates_decay_from_growth() {
        let t = 0.001;
        for (m, b) in [(1.0, 8.0), (3.0, 8.0), (1.0, 3.0)] {
            let k_max = stiffness_limit_n_per_m(b, t);
            let below = late_amplitude(m, b, 0.9 * k_max, t);
            let above = late_amplitude(m, b, 1.1 * k_max, t);
            assert!(below < 0.5e-3, "m {m} b {b}: K = 0.9 K_max must decay, amplitude {below}");
            assert!(above > 1e-3, "m {m} b {b}: K = 1.1 K_max must grow, amplitude {above}");
        }
    }

    #[test]
    fn board_range_lists_each_string_it_would_clip() {
        let vpn = [[0.2; 4], [0.2, 0.2, -0.5, 0.2]];
        assert!(check_board_range([20.0, 20.0], [[0.2; 4]; 2], 4.0).is_empty());
        let w = check_board_range([20.0, 20.0], vpn, 4.0);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].starts_with("hand 1 string 2: 20 N needs 10.00 V"), "{}", w[0]);
        assert_eq!(check_board_range([f64::NAN, 1.0], [[0.2; 4]; 2], 4.0).len(), 4, "NaN never fits");
    }
}
