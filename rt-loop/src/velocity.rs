//! Hand velocity from successive poses.
//!
//! A finite difference through a first-order low-pass: v += a ((p - p_prev)/dt - v), with
//! a = 1 - exp(-2 pi fc dt). Its lag behind the true velocity is dt (1 - a) / a for the filter plus
//! dt / 2 for the difference: at the default 60 Hz cut-off and 1 kHz, 2.7 ms. (The lab's filter,
//! v = 0.8 v + 0.2 dp/dt computed before the pose update, is a = 0.2 plus one more tick: 5.5 ms.)
//! Penalty damping acts on this estimate: a lower cut-off means less encoder quantisation noise in
//! the damping force and more lag. Allocation-free; never panics.

use glam::DVec3;

#[derive(Clone, Copy, Debug)]
pub struct VelocityFilter {
    alpha: f64,
    inv_dt: f64,
    prev: Option<DVec3>,
    vel: DVec3,
}

impl VelocityFilter {
    pub fn new(cutoff_hz: f64, dt_s: f64) -> VelocityFilter {
        let alpha = 1.0 - (-2.0 * std::f64::consts::PI * cutoff_hz * dt_s).exp();
        VelocityFilter { alpha, inv_dt: 1.0 / dt_s, prev: None, vel: DVec3::ZERO }
    }

    /// Feeds the pose of this tick and returns the velocity estimate.
    pub fn update(&mut self, pos_m: DVec3) -> DVec3 {
        self.update_after(pos_m, 1)
    }

    /// Feeds a pose taken `ticks` periods after the previous one (ticks without a usable pose in
    /// between were skipped), so the difference is divided by the time that really passed.
    pub fn update_after(&mut self, pos_m: DVec3, ticks: u32) -> DVec3 {
        if let Some(prev) = self.prev {
            let raw = (pos_m - prev) * (self.inv_dt / f64::from(ticks.max(1)));
            self.vel += (raw - self.vel) * self.alpha;
        }
        self.prev = Some(pos_m);
        self.vel
    }

    /// True once a pose has been fed since the last reset (a velocity exists).
    pub fn has_history(&self) -> bool {
        self.prev.is_some()
    }

    /// Forgets the history (after a fault or homing, when poses jump).
    pub fn reset(&mut self) {
        self.prev = None;
        self.vel = DVec3::ZERO;
    }

    pub fn velocity(&self) -> DVec3 {
        self.vel
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_velocity_is_recovered() {
        let mut f = VelocityFilter::new(60.0, 0.001);
        let v = DVec3::new(0.5, -1.0, 2.0);
        let mut est = DVec3::ZERO;
        for k in 0..200 {
            est = f.update(v * (k as f64 * 0.001));
        }
        assert!((est - v).length() < 1e-9, "{est}");
    }

    #[test]
    fn ramp_lags_by_the_stated_delay() {
        // For a ramp input the steady-state lag of a first-order filter is its time constant.
        let (fc, dt) = (60.0, 0.001);
        let mut f = VelocityFilter::new(fc, dt);
        let acc = 3.0;
        let mut est = DVec3::ZERO;
        let n = 500;
        for k in 0..=n {
            let t = k as f64 * dt;
            est = f.update(DVec3::X * 0.5 * acc * t * t);
        }
        let t = n as f64 * dt;
        let lag = t - est.x / acc; // time at which the true velocity equalled the estimate
        let filter_lag = dt * (1.0 - f.alpha) / f.alpha;
        assert!((lag - (filter_lag + dt / 2.0)).abs() < 1e-5, "lag {lag}");
        assert!((lag - 0.0027).abs() < 1e-4, "documented 2.7 ms, got {lag}");
    }
}
