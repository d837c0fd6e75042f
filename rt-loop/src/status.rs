//! What the rig tells the world about itself: its geometry once ([`rig_info`]) and a low-rate
//! summary ([`StatusWindow`] builds the `RigStatus` the loop sends every `STATUS_EVERY` ticks).
//!
//! The summary's rate and lateness p99 come from fixed arrays (a log-spaced histogram of the last
//! two windows of ticks), so building one allocates nothing and costs a few hundred additions.

use spidar_msg::{RigInfo, RigState, RigStatus, HANDS, STRINGS};

use crate::rig::Rig;
use crate::telemetry::TickRecord;
use crate::tick::{Counters, Lifecycle};

/// A status goes to the world every this many ticks (about 60 Hz at 1 kHz).
pub const STATUS_EVERY: u64 = 16;
/// Ticks per window of the rate and lateness figures; a status summarises the last two.
const WINDOW_TICKS: u32 = 256;
/// Four buckets per octave from 1 us up (about 19 % wide), bucket 0 below 1 us.
const BUCKETS: usize = 4 * 20 + 1;

/// The rig's geometry in the world frame, for the world's viewers.
pub fn rig_info(rig: &Rig) -> RigInfo {
    let xf = &rig.rig_to_world;
    let mut info = RigInfo { period_s: rig.period_s, eye_m: xf.point(rig.eye_m), ..Default::default() };
    for (h, hr) in rig.hands.iter().enumerate().take(HANDS) {
        for s in 0..STRINGS {
            info.anchors_m[h][s] = xf.point(hr.anchors_m[s]);
        }
        info.home_m[h] = xf.point(hr.home_m);
        info.tension_min_n[h] = hr.tension_min_n;
        info.tension_max_n[h] = hr.tension_max_n;
        info.force_limit_n[h] = hr.force_limit_n;
        info.grip_radius_m[h] = hr.grip_radius_m;
    }
    info.clearance = rig.near_strings;
    info.clearance.forearm.toward_elbow = xf.vector(rig.near_strings.forearm.toward_elbow);
    if let Some(d) = &rig.display {
        info.display = spidar_msg::DisplayInfo {
            present: true,
            lower_left_m: xf.point(d.lower_left_m),
            lower_right_m: xf.point(d.lower_right_m()),
            upper_left_m: xf.point(d.upper_left_m()),
            eye_separation_m: d.eye_separation_m,
            stereo: d.stereo.code(),
        };
    }
    info
}

fn bucket(lateness_s: f64) -> usize {
    let us = lateness_s * 1e6;
    if us.is_nan() || us < 1.0 {
        return 0;
    }
    (1 + (us.log2() * 4.0) as usize).min(BUCKETS - 1)
}

fn bucket_top_s(b: usize) -> f64 {
    if b == 0 {
        1e-6
    } else {
        1e-6 * 2f64.powf(b as f64 / 4.0)
    }
}

/// Rate and lateness over the last two windows of ticks.
pub struct StatusWindow {
    hist: [[u32; BUCKETS]; 2],
    count: [u32; 2],
    start_t_s: [f64; 2],
    cur: usize,
}

impl Default for StatusWindow {
    fn default() -> Self {
        StatusWindow { hist: [[0; BUCKETS]; 2], count: [0; 2], start_t_s: [f64::NAN; 2], cur: 0 }
    }
}

impl StatusWindow {
    /// Adds one tick.
    pub fn add(&mut self, rec: &TickRecord) {
        if self.count[self.cur] >= WINDOW_TICKS {
            self.cur ^= 1;
            self.hist[self.cur] = [0; BUCKETS];
            self.count[self.cur] = 0;
        }
        if self.count[self.cur] == 0 {
            self.start_t_s[self.cur] = rec.t_s;
        }
        self.hist[self.cur][bucket(rec.lateness_s)] += 1;
        self.count[self.cur] += 1;
    }

    /// Ticks per second since the older window started.
    fn rate_hz(&self, now_s: f64) -> f64 {
        let old = self.cur ^ 1;
        let (n, t0) = if self.count[old] > 0 {
            (self.count[old] + self.count[self.cur], self.start_t_s[old])
        } else {
            (self.count[self.cur], self.start_t_s[self.cur])
        };
        let dt = now_s - t0;
        if n > 1 && dt > 0.0 {
            (n - 1) as f64 / dt
        } else {
            0.0
        }
    }

    /// Upper edge of the bucket holding the 99th percentile of lateness.
    fn lateness_p99_s(&self) -> f64 {
        let total: u32 = self.count.iter().sum();
        if total == 0 {
            return 0.0;
        }
        let want = (total as f64 * 0.99).ceil() as u32;
        let mut acc = 0;
        for b in 0..BUCKETS {
            acc += self.hist[0][b] + self.hist[1][b];
            if acc >= want {
                return bucket_top_s(b);
            }
        }
        bucket_top_s(BUCKETS - 1)
    }

    /// The status after the tick `rec`.
    pub fn status(&self, rec: &TickRecord, counters: &Counters, stopping: bool, rig: &Rig) -> RigStatus {
        let xf = &rig.rig_to_world;
        let state = match (stopping, rec.state) {
            (true, _) => RigState::Stopping,
            (_, Lifecycle::Unconfigured) => RigState::Unconfigured,
            (_, Lifecycle::Inactive) => RigState::Inactive,
            (_, Lifecycle::Active) => RigState::Active,
            (_, Lifecycle::Faulted) => RigState::Faulted,
        };
        let mut st = RigStatus {
            tick: rec.tick,
            t_s: rec.t_s,
            state,
            rate_hz: self.rate_hz(rec.t_s),
            lateness_p99_s: self.lateness_p99_s(),
            faults: counters.faults,
            device_errors: counters.device_errors,
            stale_ticks: counters.stale,
            clamped_ticks: counters.clamped.iter().sum(),
            misses: counters.misses,
            ..Default::default()
        };
        for h in 0..HANDS {
            st.force_n[h] = xf.vector(rec.hands[h].output_n);
            st.tensions_n[h] = rec.hands[h].tensions_n;
        }
        st
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_and_lateness_p99_follow_the_ticks() {
        let mut w = StatusWindow::default();
        let mut rec = TickRecord::default();
        for i in 0..1000u64 {
            rec.tick = i;
            rec.t_s = i as f64 * 0.001;
            // 2 % of ticks 2 ms late, the rest 20 us.
            rec.lateness_s = if i % 50 == 0 { 2e-3 } else { 20e-6 };
            w.add(&rec);
        }
        let r = Rig::default_rig();
        let st = w.status(&rec, &Counters::default(), false, &r);
        assert!((st.rate_hz - 1000.0).abs() < 1.0, "{}", st.rate_hz);
        // 488 ticks in the two windows (512..999), 10 of them late: p99 lands on the late bucket.
        assert!(st.lateness_p99_s > 1.6e-3 && st.lateness_p99_s < 2.4e-3, "{}", st.lateness_p99_s);
        for i in 0..600u64 {
            rec.t_s = (1000 + i) as f64 * 0.001;
            rec.lateness_s = 20e-6;
            w.add(&rec);
        }
        let p99 = w.status(&rec, &Counters::default(), true, &r);
        assert!(p99.lateness_p99_s > 16e-6 && p99.lateness_p99_s < 24e-6, "{}", p99.lateness_p99_s);
        assert_eq!(p99.state, RigState::Stopping);
    }

    #[test]
    fn rig_info_is_in_the_world_frame() {
        let r = Rig::default_rig();
        let info = rig_info(&r);
        assert_eq!(info.home_m[0], r.rig_to_world.point(r.hands[0].home_m));
        assert_eq!(info.anchors_m[1][3], r.rig_to_world.point(r.hands[1].anchors_m[3]));
        assert_eq!(info.force_limit_n[1], r.hands[1].force_limit_n);
        assert_eq!(info.period_s, r.period_s);
    }
}
