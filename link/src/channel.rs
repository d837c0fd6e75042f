//! The link inside one process: bounded channels between the loop and a world thread (or a test,
//! or a loop and scene interleaved on the virtual clock).
//!
//! The rig's side only `try_send`s and `try_recv`s, so it never blocks or allocates. The world's
//! side must poll too, never block in `recv` on a channel the loop sends to: crossbeam wakes a
//! blocked receiver through a mutex, and the loop must take no lock.

use crossbeam_channel::{bounded, Receiver, Sender, TrySendError};
use spidar_msg::{ContactModel, HandSample, RigStatus};

use crate::{RigLink, Sent};

/// Channel capacities of [`pair`].
pub const MODEL_CAPACITY: usize = 8;
pub const SAMPLE_CAPACITY: usize = 64;
pub const STATUS_CAPACITY: usize = 8;

/// The rig's end.
pub struct ChannelRigLink {
    models: Receiver<ContactModel>,
    samples: Sender<HandSample>,
    status: Sender<RigStatus>,
}

/// The world's end: send models, drain samples and statuses (never blocking).
pub struct ChannelWorldEnd {
    pub models: Sender<ContactModel>,
    pub samples: Receiver<HandSample>,
    pub status: Receiver<RigStatus>,
}

/// A connected pair with the default capacities.
pub fn pair() -> (ChannelRigLink, ChannelWorldEnd) {
    let (mt, mr) = bounded(MODEL_CAPACITY);
    let (st, sr) = bounded(SAMPLE_CAPACITY);
    let (rt, rr) = bounded(STATUS_CAPACITY);
    (
        ChannelRigLink { models: mr, samples: st, status: rt },
        ChannelWorldEnd { models: mt, samples: sr, status: rr },
    )
}

impl RigLink for ChannelRigLink {
    fn poll(&mut self, _now_s: f64) -> Option<ContactModel> {
        let mut newest = None;
        while let Ok(m) = self.models.try_recv() {
            newest = Some(m);
        }
        newest
    }

    fn send_sample(&mut self, s: &HandSample) -> Sent {
        match self.samples.try_send(*s) {
            Ok(()) => Sent::Queued,
            Err(TrySendError::Full(_)) => Sent::Dropped,
            Err(TrySendError::Disconnected(_)) => Sent::NoPeer,
        }
    }

    fn send_status(&mut self, s: &RigStatus) {
        // A status is a summary: when nobody reads them, the newest few are enough.
        let _ = self.status.try_send(*s);
    }
}

impl ChannelWorldEnd {
    /// The newest status queued, if any (the older ones are dropped).
    pub fn newest_status(&self) -> Option<RigStatus> {
        self.status.try_iter().last()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rig_takes_the_newest_model_and_counts_a_full_way() {
        let (mut rig, world) = pair();
        assert!(rig.poll(0.0).is_none());
        for seq in 1..=3 {
            world.models.send(ContactModel { seq, ..Default::default() }).unwrap();
        }
        assert_eq!(rig.poll(0.0).map(|m| m.seq), Some(3));
        assert!(rig.poll(0.0).is_none(), "each model is taken once");
        let s = HandSample::default();
        for _ in 0..SAMPLE_CAPACITY {
            assert_eq!(rig.send_sample(&s), Sent::Queued);
        }
        assert_eq!(rig.send_sample(&s), Sent::Dropped);
        drop(world);
        assert_eq!(rig.send_sample(&s), Sent::NoPeer);
    }
}
