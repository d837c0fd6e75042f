//! The produced-force limit: the last check of every hand's output, after the tension
//! allocation. The safety phase clamps the force *asked for* to the hand's `force_limit_n`; this
//! phase makes the force the allocated tensions *produce*, `sum t_i u_i`, keep that limit too.
//!
//! Why it exists: the allocator renders the asked force exactly, or scaled back along its own
//! direction, and both stay within the limit; but where not even zero net force is feasible (the
//! grip outside its anchor tetrahedron) its box-QP fallback picks the tensions whose force is
//! *closest* to the asked one, and that force can be larger than the limit (an audit measured
//! 4.07 N against the rig's 4 N, through the board emulator, on fallback ticks).
//!
//! Method. Write each tension as `t_i = min + d_i` (`d_i >= 0`): the produced force is
//! `f_min + g` with `f_min = min sum u_i` (every string at minimum) and `g = sum d_i u_i`. When
//! `|f_min + g|` is above the limit, every `d_i` is scaled by the one factor `alpha` in `[0, 1)`
//! that puts `|f_min + alpha g|` on the limit (the larger root of a quadratic): every string
//! stays within `[min, max]` (they only move toward `min`), and the force stays the allocator's
//! up to the common shrink of what the strings add above their minimum. Where even the minimum
//! tensions alone exceed the limit (`|f_min| > limit`: a limit below what taut strings pull, only
//! possible with a very low `force_limit_n` far outside the frame) nothing of this form meets it:
//! `alpha` is then the one that makes `|f_min + alpha g|` smallest, the hand gets the least force
//! along that line (never more than the minimum tensions' own), and the tick is counted as unmet.
//!
//! Must never: raise a tension or lower one below `min`, leave a produced force above the limit
//! by more than [`PRODUCED_TOL_N`] unless the tick is reported as unmet, allocate, lock, format
//! or panic (whatever the input: NaN directions are treated as zero, as the allocator does).

use glam::DVec3;

use crate::tension::Allocation;

/// Rounding slack: a produced force up to this much above the limit is left as it is (the exact
/// and scaled allocations hit the limit itself to within ~1e-15 N when the asked force was
/// clamped to it; those ticks are not "limited").
pub const PRODUCED_TOL_N: f64 = 1e-9;

/// What the phase did to one hand's allocation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProducedLimit {
    /// The produced force was above the limit and the tensions above minimum were scaled down.
    pub limited: bool,
    /// Even the minimum tensions alone produce more than the limit: the least force along the
    /// scaling line was kept (still above the limit).
    pub unmet: bool,
}

/// Brings the force `alloc`'s tensions produce on a grip pulled along `dirs` within `limit_n`
/// (see the module documentation), updating `alloc.tensions_n`, `alloc.force_n` and, when it
/// acts, `alloc.scale` (the fraction of `asked_n` along its own direction, as the fallback
/// reports it). `min_n` is the hand's minimum tension.
pub fn limit_produced(
    alloc: &mut Allocation,
    dirs: &[DVec3; 4],
    min_n: f64,
    limit_n: f64,
    asked_n: DVec3,
) -> ProducedLimit {
    let u = dirs.map(|d| if d.is_finite() { d } else { DVec3::ZERO });
    let mag = produced(&u, &alloc.tensions_n).length();
    if mag.is_nan() || mag <= limit_n + PRODUCED_TOL_N {
        // NaN: nothing to measure against (the allocator's tensions are in the box).
        return ProducedLimit::default();
    }
    let f_min = (u[0] + u[1] + u[2] + u[3]) * min_n;
    let d = alloc.tensions_n.map(|t| (t - min_n).max(0.0));
    let g = produced(&u, &d);
    let (a, b) = (g.length_squared(), f_min.dot(g));
    let c = f_min.length_squared() - limit_n * limit_n;
    let (alpha, unmet) = if a.is_nan() || a <= 0.0 {
        (0.0, true)
    } else if c > 0.0 {
        // The minimum tensions alone are beyond the limit: the least force along the line.
        ((-b / a).clamp(0.0, 1.0), true)
    } else {
        // Larger root of a alpha^2 + 2 b alpha + c = 0 (c <= 0: one root >= 0), in the form
        // that does not cancel.
        let root = (b * b - a * c).max(0.0).sqrt();
        let alpha = if b > 0.0 { -c / (b + root) } else { (root - b) / a };
        (alpha.clamp(0.0, 1.0), false)
    };
    let alpha = if alpha.is_finite() { alpha } else { 0.0 };
    for (t, di) in alloc.tensions_n.iter_mut().zip(d) {
        *t = min_n + alpha * di;
    }
    alloc.force_n = produced(&u, &alloc.tensions_n);
    let ff = asked_n.length_squared();
    let frac = if ff > 0.0 && ff.is_finite() { alloc.force_n.dot(asked_n) / ff } else { 0.0 };
    alloc.scale = if frac.is_nan() { 0.0 } else { frac.clamp(0.0, alloc.scale.max(0.0)) };
    ProducedLimit { limited: true, unmet }
}

/// `sum t_i u_i`.
fn produced(u: &[DVec3; 4], t: &[f64; 4]) -> DVec3 {
    u[0] * t[0] + u[1] * t[1] + u[2] * t[2] + u[3] * t[3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tension::{Allocator, Method, TensionLimits};
    use proptest::prelude::*;

    const RIG: TensionLimits = TensionLimits { min_n: 1.0, max_n: 20.0 };
    const LIMIT_N: f64 = 4.0;

    /// Hand 0's anchors of the shipped rig (configs/rig.ron).
    const ANCHORS: [[f64; 3]; 4] =
        [[-1.75, 2.00, 1.12], [1.65, 2.17, -1.34], [-1.65, -0.90, -1.44], [1.65, -0.99, 0.50]];

    fn dirs_at(p: DVec3) -> [DVec3; 4] {
        ANCHORS.map(|a| (DVec3::from_array(a) - p).normalize())
    }

    fn cfg(cases: u32) -> ProptestConfig {
        spidar_testkit::proptest_config(0x0270_f0ce, cases)
    }

    /// The loop's two phases for one hand: allocate, then limit what it produces.
    fn allocate_and_limit(
        p: DVec3,
        asked: DVec3,
        lim: TensionLimits,
        limit_n: f64,
    ) -> (Allocation, ProducedLimit) {
        let u = dirs_at(p);
        let mut al = Allocator::new(lim).allocate(&u, asked);
        let r = limit_produced(&mut al, &u, lim.min_n, limit_n, asked);
        (al, r)
    }

    #[test]
    fn the_fallback_below_the_frame_is_brought_to_the_limit_with_every_string_taut() {
        // 1.2 m below the origin the hand is out of its tetrahedron: every string pulls up, so a
        // level force cannot be rendered even scaled down (fallback). The box QP's closest force
        // to a level 4 N is then larger than 4 N in some directions: find the worst.
        let p = DVec3::new(0.0, -1.2, 0.0);
        let u = dirs_at(p);
        let (raw, asked) = (0..72)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 72.0;
                let asked = DVec3::new(a.cos(), 0.0, a.sin()) * LIMIT_N;
                (Allocator::new(RIG).allocate(&u, asked), asked)
            })
            .max_by(|a, b| a.0.force_n.length().total_cmp(&b.0.force_n.length()))
            .unwrap();
        assert_eq!(raw.method, Method::Fallback);
        assert!(raw.force_n.length() > LIMIT_N + 0.01, "the case needs a fallback above the limit: {raw:?}");
        let (al, r) = allocate_and_limit(p, asked, RIG, LIMIT_N);
        assert_eq!(r, ProducedLimit { limited: true, unmet: false });
        assert!((al.force_n.length() - LIMIT_N).abs() < 1e-9, "{al:?}");
        assert!(al.tensions_n.iter().all(|&t| (RIG.min_n..=RIG.max_n).contains(&t)));
        // Only shrunk toward minimum, never raised.
        for (t, t0) in al.tensions_n.iter().zip(raw.tensions_n) {
            assert!(*t <= t0 + 1e-12 && *t >= RIG.min_n);
        }
    }

    #[test]
    fn minimum_tensions_beyond_a_tiny_limit_are_reported_unmet_and_get_the_least_force() {
        let p = DVec3::new(0.0, -1.2, 0.0);
        let u = dirs_at(p);
        let f_min = (u[0] + u[1] + u[2] + u[3]) * RIG.min_n;
        let limit = 0.5 * f_min.length();
        let (al, r) = allocate_and_limit(p, DVec3::Y * limit, RIG, limit);
        assert_eq!(r, ProducedLimit { limited: true, unmet: true });
        assert!(al.force_n.length() <= f_min.length() + 1e-9, "{al:?} vs {f_min}");
        assert!(al.tensions_n.iter().all(|&t| (RIG.min_n..=RIG.max_n).contains(&t)));
    }

    #[test]
    fn forces_within_reach_are_left_exactly_as_allocated() {
        let u = dirs_at(DVec3::ZERO);
        for asked in [DVec3::ZERO, DVec3::X * 4.0, DVec3::new(1.0, -2.0, 3.0).normalize() * 4.0] {
            let raw = Allocator::new(RIG).allocate(&u, asked);
            let (al, r) = allocate_and_limit(DVec3::ZERO, asked, RIG, LIMIT_N);
            assert_eq!(r, ProducedLimit::default());
            assert_eq!(al.tensions_n, raw.tensions_n);
        }
    }

    proptest! {
        #![proptest_config(cfg(4000))]

        /// Hands anywhere from well inside to far outside the frame (down to 2.5 m below the
        /// origin, where the strings all pull up), asked any force up to 50 N: the produced force
        /// is never above the limit unless the minimum tensions alone are (then it is no more than
        /// theirs and reported), and every tension is within its range.
        #[test]
        fn the_produced_force_never_exceeds_the_limit(
            x in -2.0f64..2.0, y in -2.5f64..2.2, z in -1.6f64..1.3,
            fx in -50.0f64..50.0, fy in -50.0f64..50.0, fz in -50.0f64..50.0,
            limit_n in prop_oneof![Just(4.0f64), 0.5f64..10.0],
        ) {
            let p = DVec3::new(x, y, z);
            // What the safety phase hands the allocator: the asked force clamped to the limit.
            let mut asked = DVec3::new(fx, fy, fz);
            if asked.length() > limit_n {
                asked *= limit_n / asked.length();
            }
            let u = dirs_at(p);
            let (al, r) = allocate_and_limit(p, asked, RIG, limit_n);
            prop_assert!(al.tensions_n.iter().all(|&t| (RIG.min_n..=RIG.max_n).contains(&t)), "{:?}", al);
            let f = al.force_n.length();
            let f_min = ((u[0] + u[1] + u[2] + u[3]) * RIG.min_n).length();
            if r.unmet {
                prop_assert!(f_min > limit_n && f <= f_min + 1e-9, "{} {} {:?}", f, f_min, al);
            } else {
                prop_assert!(f <= limit_n + PRODUCED_TOL_N, "produced {} N, limit {} N: {:?}", f, limit_n, al);
            }
            // The force reported is the one the tensions make.
            let made = u.iter().zip(al.tensions_n).fold(DVec3::ZERO, |acc, (ui, ti)| acc + *ui * ti);
            prop_assert!((made - al.force_n).length() < 1e-9);
        }
    }
}
