//! The tick core's tests, by concern: `lifecycle.rs` (states, faults and their recovery,
//! commands, homing and re-homing), `input.rs` (counts checked, poses, holding a hand),
//! `output.rs` (render, safety, allocation, the impulses sent back), and here the helpers they
//! share. They drive `TickCore` tick by tick with no device and no clock; they must never
//! depend on timing (the machine may be loaded) or on anything but the core's own behaviour.

use super::*;
use crate::tension::Method;
use spidar_device::{ErrorKind, MAX_CHANNELS};

mod blow;
mod calibrating;
mod input;
mod lifecycle;
mod output;

fn core() -> TickCore {
    TickCore::new(&Rig::default_rig()).unwrap()
}

/// Homes and activates, running through the settle time.
fn home_and_activate(c: &mut TickCore) {
    c.command(Command::Home);
    c.command(Command::Activate);
    run(c, (HOMING_SETTLE_S / c.rig().period_s).round() as usize + 1, Ok(()));
    assert_eq!(c.state(), Lifecycle::Active);
}

fn run(c: &mut TickCore, n: usize, io: Result<(), DeviceError>) -> (Output, TickRecord) {
    let mut out = Output::default();
    let mut rec = TickRecord::default();
    let mut s = HandSample::default();
    let inp = Input::default();
    for _ in 0..n {
        let t = c.counters.ticks as f64 * 0.001;
        c.step(t, io, &inp, &mut out, &mut s, &mut rec);
    }
    (out, rec)
}

const TIMEOUT: DeviceError = DeviceError::Timeout { waited_us: 900 };

fn reply_limit(c: &TickCore) -> usize {
    c.rig().safety.reply_fault_ticks as usize
}

/// A wall 1 cm in front of hand 0's home, 3 cm into the fist: a large force to hold.
fn pressing_wall(c: &TickCore) -> ContactModel {
    use spidar_msg::{Proxy, ProxyId, ProxyShape};
    let home = c.rig().rig_to_world.point(c.rig().hands[0].home_m);
    let mut m = ContactModel { seq: 1, ..Default::default() };
    m.push(Proxy {
        id: ProxyId { body: 3, part: 0 },
        shape: ProxyShape::Plane { point_m: home - DVec3::Z * 0.01, normal: DVec3::Z },
        k_n_per_m: 2000.0,
        d_n_s_per_m: 0.0,
        vel_m_per_s: DVec3::ZERO,
        hand_mask: 0b01,
    });
    m
}

/// One tick with explicit counts and device result; a fresh `m` when given.
fn tick_io(
    c: &mut TickCore,
    out: &mut Output,
    m: Option<ContactModel>,
    counts: &[i64; MAX_CHANNELS],
    io: Result<(), DeviceError>,
) -> (HandSample, TickRecord) {
    let (mut rec, mut s) = (TickRecord::default(), HandSample::default());
    let t = c.counters.ticks as f64 * 0.001;
    if let Some(mut m) = m {
        m.stamp_s = t;
        c.set_contact_model(m);
    }
    let inp = Input { counts: *counts, status: 0 };
    c.step(t, io, &inp, out, &mut s, &mut rec);
    (s, rec)
}

/// Counts of both hands for grips at `p` (rig frame), with the zero lengths homing took at home.
fn counts_at(c: &TickCore, p: [DVec3; 2]) -> [i64; MAX_CHANNELS] {
    let mut counts = [0i64; MAX_CHANNELS];
    for (h, hr) in c.rig().hands.iter().enumerate() {
        for s in 0..4 {
            let dl = (hr.anchors_m[s] - p[h]).length() - (hr.anchors_m[s] - hr.home_m).length();
            counts[hr.channels[s]] = (dl / hr.metres_per_count[s]).round() as i64;
        }
    }
    counts
}

/// One tick with a fresh `m` (stamped now); returns the sample and the record.
fn tick_with(c: &mut TickCore, m: Option<ContactModel>) -> (HandSample, TickRecord) {
    let (mut out, mut rec, mut s) = (Output::default(), TickRecord::default(), HandSample::default());
    let t = c.counters.ticks as f64 * 0.001;
    if let Some(mut m) = m {
        m.stamp_s = t;
        c.set_contact_model(m);
    }
    c.step(t, Ok(()), &Input::default(), &mut out, &mut s, &mut rec);
    (s, rec)
}
