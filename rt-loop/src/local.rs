//! The avatar hand's contact as a local model, rendered at 1 kHz, and the energy reserve that
//! keeps its updates passive (the boxing scene, seed 000 section 3.4; `docs/boxing.md` gives the
//! whole argument).
//!
//! The world steps every 3 ms. With each step it sends, per hand, the contact force acting on the
//! avatar's hand (`HandContact`): the force, the contact normal, the stiffness of the contact in
//! series with the coupling spring, and the user's hand position it was computed for. Between
//! two steps the loop carries that force along with the user's hand: along the force's direction
//! u, the normal force grows by the stiffness seen along u for every metre the hand moves against
//! u, and the contact ends where it would fall to zero:
//!
//! `F(x) = u max(0, |F0| + k (n.u)^2 (x0 - x).u)`.
//!
//! That is the force of a spring on one axis (the gradient of `k' / 2 max(0, s - x.u)^2`), so
//! between two models no loop of the hand gains energy from it. A new model every 3 ms moves
//! that spring: when it moves it out under a hand on its way out, the hand would be pushed out
//! harder than it was pushed in. So the loop also keeps, per hand, the energy the user's hand has
//! put into the contact (the work it did against the force the rig really applied, tick by
//! tick, from the measured motion) and never lets the rig give back more than that: when the
//! force about to be commanded would do more work on a hand moving with it than the reserve
//! holds, it is scaled down along its own direction ([`Passivity::limit`]). What the world's
//! own bodies put into the contact (the virtual human's block or punch driving into the avatar's
//! hand, `HandContact::source_w`) is credited to the reserve as each model arrives
//! ([`Passivity::credit`]): the loop adds no energy, the world may. A contact that
//! appears with the hand already inside it is therefore felt at once while the hand goes in (the
//! user pays for it), and not at all on the way out of it. The reserve counts only while the
//! hand is in an avatar-hand contact, and starts from nothing at every new one: outside a
//! contact nothing is stored, and the other forces a hand may feel (the avatar's damage) are not
//! the contact's to pay for.
//!
//! Allocation-free; never panics; the force goes through the safety phase like the proxies'.

use glam::DVec3;
use spidar_msg::HandContact;

/// The local model's force on one hand this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LocalRendered {
    /// World frame.
    pub force_n: DVec3,
    /// The model's stiffness was above the hand's limit and was softened.
    pub stiffness_limited: bool,
}

/// The force of the local model `c` on a hand at `pos_m` (world frame), its stiffness limited to
/// `stiffness_limit_n_per_m`. Zero when the model has no contact, the hand has moved out of it,
/// or anything in it is not finite.
pub fn render_contact(c: &HandContact, pos_m: DVec3, stiffness_limit_n_per_m: f64) -> LocalRendered {
    let f0 = c.force_n.length();
    let mut k = c.k_n_per_m;
    // Written so that NaN anywhere gives "no contact".
    if !(f0 > 0.0 && f0.is_finite() && k >= 0.0) {
        return LocalRendered::default();
    }
    let u = c.force_n / f0;
    let n = c.normal.normalize_or_zero();
    let mut out = LocalRendered::default();
    if k > stiffness_limit_n_per_m {
        k = stiffness_limit_n_per_m;
        out.stiffness_limited = true;
    }
    // The normal spring seen along u: a move d along u changes the depth by d (n.u) and the
    // normal force's component along u by k d (n.u)^2.
    let nu = n.dot(u);
    let f = f0 + k * nu * nu * (c.at_m - pos_m).dot(u);
    if !(f > 0.0 && f.is_finite()) {
        return out;
    }
    out.force_n = u * f;
    out
}

/// The energy reserve of one hand: passivity observer and limiter.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Passivity {
    /// Work the user's hand did against the force the rig applied since the contact began (J).
    /// Negative: the rig gave back more than it got, by that much.
    reserve_j: f64,
    /// The forces commanded on the last two ticks (rig frame), newest first. The board applies a
    /// tick's command from the next exchange to the one after, so the force commanded two ticks
    /// ago is the one that acted while the hand moved from the last pose to this one.
    commanded_n: [DVec3; 2],
    last_pos_m: Option<DVec3>,
}

impl Passivity {
    /// The reserve now (J).
    pub fn reserve_j(&self) -> f64 {
        self.reserve_j
    }

    /// Books the work of the force that acted while the hand moved from the last pose to `pos_m`
    /// (rig frame; None: no trusted pose this tick, the motion is not known and the next pose
    /// starts afresh). `engaged`: the hand is in a local-model contact; outside one the reserve
    /// is empty. Returns the work the user did on the rig this tick (J).
    pub fn observe(&mut self, pos_m: Option<DVec3>, engaged: bool) -> f64 {
        let mut work = 0.0;
        if let (true, Some(p), Some(last)) = (engaged, pos_m, self.last_pos_m) {
            // The force pushes the hand; the hand moving against it does work on the rig.
            work = -self.commanded_n[1].dot(p - last);
            if work.is_finite() {
                self.reserve_j += work;
            } else {
                work = 0.0;
            }
        }
        self.last_pos_m = pos_m;
        if !engaged {
            self.reserve_j = 0.0;
        }
        work
    }

    /// The force to command this tick: `f_n` (rig frame, after the safety phase) scaled down
    /// along its own direction so that the work it will do on a hand moving at `vel_m_per_s`
    /// over the tick it acts, after the tick already committed, stays within the reserve. Only
    /// while `engaged`; returns the force and whether it was scaled.
    pub fn limit(&self, f_n: DVec3, vel_m_per_s: DVec3, dt_s: f64, engaged: bool) -> (DVec3, bool) {
        if !engaged {
            return (f_n, false);
        }
        let out = f_n.dot(vel_m_per_s) * dt_s;
        // Written so that NaN also leaves the force alone (the safety phase has guarded it).
        if out.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return (f_n, false);
        }
        let committed = (self.commanded_n[0].dot(vel_m_per_s) * dt_s).max(0.0);
        let available = (self.reserve_j - committed).max(0.0);
        if out <= available {
            return (f_n, false);
        }
        (f_n * (available / out), true)
    }

    /// Credits `energy_j` the world put into the contact (ignored unless positive and finite).
    pub fn credit(&mut self, energy_j: f64) {
        if energy_j > 0.0 && energy_j.is_finite() {
            self.reserve_j += energy_j;
        }
    }

    /// Records the force really commanded this tick (rig frame, after the allocation).
    pub fn commanded(&mut self, f_n: DVec3) {
        self.commanded_n = [if f_n.is_finite() { f_n } else { DVec3::ZERO }, self.commanded_n[0]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contact(f: DVec3, n: DVec3, k: f64, at: DVec3) -> HandContact {
        HandContact { force_n: f, normal: n, k_n_per_m: k, at_m: at, source_w: 0.0 }
    }

    #[test]
    fn the_model_force_at_its_own_point_is_the_worlds_and_grows_with_the_depth() {
        let c = contact(DVec3::Z * 3.0, DVec3::Z, 2000.0, DVec3::new(0.1, 1.4, -0.3));
        let r = render_contact(&c, c.at_m, 5000.0);
        assert_eq!(r.force_n, DVec3::Z * 3.0);
        // 1 mm further in (against the normal): 2 N more; 1 mm out: 2 N less; sideways: same.
        let r = render_contact(&c, c.at_m - DVec3::Z * 0.001, 5000.0);
        assert!((r.force_n.z - 5.0).abs() < 1e-9, "{}", r.force_n);
        let r = render_contact(&c, c.at_m + DVec3::Z * 0.001, 5000.0);
        assert!((r.force_n.z - 1.0).abs() < 1e-9, "{}", r.force_n);
        let r = render_contact(&c, c.at_m + DVec3::X * 0.05, 5000.0);
        assert!((r.force_n.z - 3.0).abs() < 1e-9);
        // Out of it: nothing, never a pull.
        let r = render_contact(&c, c.at_m + DVec3::Z * 0.002, 5000.0);
        assert_eq!(r.force_n, DVec3::ZERO);
    }

    #[test]
    fn a_slanted_force_grows_by_the_normal_stiffness_seen_along_it() {
        // Friction tilts the force 45 degrees from the normal: along it, the stiffness is halved.
        let u = DVec3::new(1.0, 0.0, 1.0).normalize();
        let c = contact(u * 2.0, DVec3::Z, 2000.0, DVec3::ZERO);
        let r = render_contact(&c, -u * 0.001, 5000.0);
        assert!((r.force_n - u * 3.0).length() < 1e-9, "{}", r.force_n);
    }

    #[test]
    fn stiffness_is_limited_and_nan_renders_nothing() {
        let c = contact(DVec3::Y, DVec3::Y, 1e6, DVec3::ZERO);
        let r = render_contact(&c, -DVec3::Y * 0.001, 5000.0);
        assert!(r.stiffness_limited);
        assert!((r.force_n.y - 6.0).abs() < 1e-9);
        for bad in [
            contact(DVec3::new(f64::NAN, 0.0, 1.0), DVec3::Y, 1e3, DVec3::ZERO),
            contact(DVec3::Y, DVec3::Y, f64::NAN, DVec3::ZERO),
            contact(DVec3::Y, DVec3::Y, 1e3, DVec3::splat(f64::INFINITY)),
            HandContact::default(),
        ] {
            assert_eq!(render_contact(&bad, DVec3::ZERO, 5000.0).force_n, DVec3::ZERO, "{bad:?}");
        }
    }

    #[test]
    fn the_reserve_books_the_work_of_the_force_that_acted_two_ticks_later() {
        let mut p = Passivity::default();
        p.observe(Some(DVec3::ZERO), true);
        p.commanded(DVec3::Z * 2.0);
        // The tick after: that force has not acted yet (it goes out at this exchange).
        assert_eq!(p.observe(Some(-DVec3::Z * 0.001), true), 0.0);
        p.commanded(DVec3::Z * 4.0);
        // Now the 2 N acted while the hand went 1 mm in: 2 mJ into the reserve.
        let w = p.observe(Some(-DVec3::Z * 0.002), true);
        assert!((w - 0.002).abs() < 1e-12 && (p.reserve_j() - 0.002).abs() < 1e-12);
        // A deficit stays while the contact lasts.
        p.commanded(DVec3::Z);
        p.commanded(DVec3::Z);
        p.observe(Some(DVec3::Z * 0.002), true);
        assert!((p.reserve_j() + 0.002).abs() < 1e-12, "{}", p.reserve_j());
        // Out of contact the reserve is empty, and no work is booked there.
        assert_eq!(p.observe(Some(DVec3::Z * 0.003), false), 0.0);
        assert_eq!(p.reserve_j(), 0.0);
        // A pose that is not trusted breaks the chain: no work booked across it.
        assert_eq!(p.observe(None, false), 0.0);
        assert_eq!(p.observe(Some(DVec3::X), false), 0.0);
    }

    #[test]
    fn the_limiter_gives_back_no_more_than_the_reserve() {
        let mut p = Passivity::default();
        let (dt, v) = (0.001, DVec3::Z * 0.5); // moving out with the force at 0.5 m/s
                                               // Nothing in the reserve: a force pushing the hand out is cut to zero.
        let (f, limited) = p.limit(DVec3::Z * 4.0, v, dt, true);
        assert!(limited && f == DVec3::ZERO);
        // Moving in, or not engaged: untouched.
        assert_eq!(p.limit(DVec3::Z * 4.0, -v, dt, true), (DVec3::Z * 4.0, false));
        assert_eq!(p.limit(DVec3::Z * 4.0, v, dt, false), (DVec3::Z * 4.0, false));
        // 1 mJ in the reserve, 0.5 mm of outward motion a tick: at most 2 N.
        p.reserve_j = 0.001;
        let (f, limited) = p.limit(DVec3::Z * 4.0, v, dt, true);
        assert!(limited && (f.z - 2.0).abs() < 1e-9, "{f}");
        // Minus what the tick already commanded will do first (1 N: 0.5 mJ): 1 N left.
        p.commanded(DVec3::Z);
        let (f, _) = p.limit(DVec3::Z * 4.0, v, dt, true);
        assert!((f.z - 1.0).abs() < 1e-9, "{f}");
        // What the world credits is given back too; nothing else is credited.
        p.credit(0.0015);
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            p.credit(bad);
        }
        let (f, limited) = p.limit(DVec3::Z * 4.0, v, dt, true);
        assert!(!limited && f.z == 4.0, "{f}");
    }
}
