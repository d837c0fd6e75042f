//! What the world's viewers know of the rig while the world runs in the rig's process (`spidar
//! run`'s scene thread): the rig's geometry ([`rig_info`], once) and a low-rate status built from
//! the telemetry the session already reads ([`RigStatusFeed`]), handed to the scene thread's
//! observers through a bounded channel. A world in its own process gets the same two messages over
//! the rig-world link.

use crossbeam_channel::{Receiver, Sender};
use spidar_msg::{RigInfo, RigState, RigStatus, HANDS, STRINGS};
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{FaultReason, Lifecycle, Rig};

/// The rig's geometry in the world frame.
pub fn rig_info(rig: &Rig) -> RigInfo {
    let w = &rig.rig_to_world;
    let mut info = RigInfo { period_s: rig.period_s, eye_m: w.point(rig.eye_m), ..RigInfo::default() };
    for (h, hand) in rig.hands.iter().enumerate() {
        for s in 0..STRINGS {
            info.anchors_m[h][s] = w.point(hand.anchors_m[s]);
        }
        info.home_m[h] = w.point(hand.home_m);
        info.tension_min_n[h] = hand.tension_min_n;
        info.tension_max_n[h] = hand.tension_max_n;
        info.force_limit_n[h] = hand.force_limit_n;
        info.grip_radius_m[h] = hand.grip_radius_m;
    }
    info
}

/// Ticks whose lateness the status's p99 is taken over.
const WINDOW: usize = 500;
/// Ticks between two statuses (30 per second at 1 kHz).
const EVERY_TICKS: u64 = 33;

/// Builds [`RigStatus`]es from tick records and sends one every [`EVERY_TICKS`] ticks (dropped
/// when the scene thread has not taken the previous ones).
pub struct RigStatusFeed {
    tx: Sender<RigStatus>,
    rig: Rig,
    status: RigStatus,
    lateness: [f64; WINDOW],
    at: usize,
    filled: usize,
    window_start: Option<(u64, f64)>,
    last_fault: Option<FaultReason>,
    stopping: bool,
}

impl RigStatusFeed {
    /// The feed and the receiving end for the scene thread.
    pub fn new(rig: &Rig) -> (RigStatusFeed, Receiver<RigStatus>) {
        let (tx, rx) = crossbeam_channel::bounded(4);
        let feed = RigStatusFeed {
            tx,
            rig: rig.clone(),
            status: RigStatus::default(),
            lateness: [0.0; WINDOW],
            at: 0,
            filled: 0,
            window_start: None,
            last_fault: None,
            stopping: false,
        };
        (feed, rx)
    }

    /// The loop was asked to stop (force ramping out).
    pub fn stopping(&mut self) {
        self.stopping = true;
    }

    pub fn add(&mut self, r: &TickRecord) {
        let s = &mut self.status;
        s.tick = r.tick;
        s.t_s = r.t_s;
        s.state = match r.state {
            Lifecycle::Unconfigured => RigState::Unconfigured,
            Lifecycle::Inactive => RigState::Inactive,
            Lifecycle::Active if self.stopping => RigState::Stopping,
            Lifecycle::Active => RigState::Active,
            Lifecycle::Faulted => RigState::Faulted,
        };
        for h in 0..HANDS {
            s.force_n[h] = self.rig.rig_to_world.vector(r.hands[h].output_n);
            s.tensions_n[h] = r.hands[h].tensions_n;
            if r.hands[h].clamped {
                s.clamped_ticks += 1;
            }
        }
        if r.fault.is_some() && r.fault != self.last_fault {
            s.faults += 1;
            if matches!(r.fault, Some(FaultReason::Device(_))) {
                s.device_errors += 1;
            }
        }
        self.last_fault = r.fault;
        if r.state == Lifecycle::Active && r.contact_age_s > self.rig.safety.contact_stale_after_s {
            s.stale_ticks += 1;
        }
        if r.lateness_s > self.rig.period_s {
            s.misses += 1;
        }
        self.lateness[self.at] = r.lateness_s;
        self.at = (self.at + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        let (t0_tick, t0) = *self.window_start.get_or_insert((r.tick, r.t_s));
        if r.tick >= t0_tick + EVERY_TICKS {
            // The window's rate from the ticks and loop-clock time it spans.
            let span = r.t_s - t0;
            if span > 0.0 {
                s.rate_hz = (r.tick - t0_tick) as f64 / span;
            }
            let mut l = self.lateness;
            let l = &mut l[..self.filled];
            l.sort_by(f64::total_cmp);
            s.lateness_p99_s = l[((l.len() as f64 * 0.99) as usize).min(l.len() - 1)];
            self.window_start = Some((r.tick, r.t_s));
            let _ = self.tx.try_send(*s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use spidar_rt::telemetry::HandRecord;

    #[test]
    fn the_rig_status_summarises_the_telemetry_in_the_world_frame() {
        let rig = Rig::default_rig();
        let (mut feed, rx) = RigStatusFeed::new(&rig);
        for tick in 0..=EVERY_TICKS {
            let mut r = TickRecord {
                tick,
                t_s: tick as f64 * 0.001,
                lateness_s: if tick == 5 { 0.002 } else { 20e-6 },
                state: Lifecycle::Active,
                hands: [HandRecord { output_n: DVec3::new(0.0, 0.0, -2.0), ..Default::default() }; 2],
                ..Default::default()
            };
            if (10..12).contains(&tick) {
                r.fault = Some(FaultReason::Residual { hand: 0 });
                r.state = Lifecycle::Faulted;
            }
            feed.add(&r);
        }
        let s = rx.try_recv().expect("a status after 33 ticks");
        assert!((s.rate_hz - 1000.0).abs() < 1e-6, "{}", s.rate_hz);
        assert_eq!((s.faults, s.device_errors, s.misses), (1, 0, 1));
        assert_eq!(s.force_n[0], rig.rig_to_world.vector(DVec3::new(0.0, 0.0, -2.0)));
        assert_eq!(s.state, RigState::Active);
        let info = rig_info(&rig);
        assert_eq!(info.anchors_m[1][2], rig.rig_to_world.point(rig.hands[1].anchors_m[2]));
        assert_eq!(info.eye_m, rig.rig_to_world.point(rig.eye_m));
    }
}
