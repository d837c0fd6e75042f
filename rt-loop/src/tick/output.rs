//! The tick's output phases, per hand: the landed blow's force, render the contact model at the
//! hand's pose, pass the force through the safety rules (gain, force limit, the avatar contact's
//! energy reserve), allocate string tensions and keep the force they produce within the limit,
//! write the volts; or replay the last output of a held hand.
//!
//! Why it exists apart: everything that decides what the strings pull is here, in the order it
//! runs (render -> safety -> allocate -> produced limit -> volts), each step a function of what
//! the one before made. It must never allocate, lock or panic, and never write a force that did
//! not pass `safety::guard`, the allocator and `produced::limit_produced` (a faulted rig's output
//! is theirs, at zero force).

use glam::DVec3;
use spidar_device::{Output, MAX_CHANNELS};
use spidar_msg::{ContactModel, HandState, MAX_PROXIES};

use super::{Counters, HandCore, HeldHand};
use crate::blow::BlowParams;
use crate::local;
use crate::produced::{self, ProducedLimit};
use crate::render::{self, Rendered};
use crate::rig::{HandRig, RigToWorld};
use crate::safety::{self, Guarded};
use crate::telemetry::HandRecord;
use crate::tension::{Allocation, Method};

/// What every hand's output shares in one tick.
#[derive(Clone, Copy)]
pub(super) struct TickView<'a> {
    pub(super) model: Option<&'a ContactModel>,
    /// The model's age (None: no model yet).
    pub(super) age_s: Option<f64>,
    /// Ramp times staleness while active, else 0.
    pub(super) gain: f64,
    pub(super) active: bool,
    pub(super) faulted: bool,
    /// The device exchange of this tick worked.
    pub(super) device_ok: bool,
    pub(super) xf: RigToWorld,
    pub(super) dt_s: f64,
}

/// The impulses both hands send back to the world in one tick, per proxy (see `HandSample`):
/// what the user's hand received, and what the virtual contact did.
pub(super) struct Impulses {
    pub(super) applied_n_s: [DVec3; MAX_PROXIES],
    pub(super) contact_n_s: [DVec3; MAX_PROXIES],
}

impl Impulses {
    pub(super) fn zero() -> Impulses {
        Impulses { applied_n_s: [DVec3::ZERO; MAX_PROXIES], contact_n_s: [DVec3::ZERO; MAX_PROXIES] }
    }
    fn add(&mut self, applied_n_s: &[DVec3; MAX_PROXIES], contact_n_s: &[DVec3; MAX_PROXIES]) {
        for ((acc, acc_contact), (m, mc)) in self
            .applied_n_s
            .iter_mut()
            .zip(self.contact_n_s.iter_mut())
            .zip(applied_n_s.iter().zip(contact_n_s.iter()))
        {
            *acc += *m;
            *acc_contact += *mc;
        }
    }
}

/// The safety phase's outcome for one hand.
#[derive(Clone, Copy, Debug)]
pub(super) struct SafeForce {
    /// The rendered force through the gain and the hand's force limit.
    pub(super) guarded: Guarded,
    /// The force commanded to the allocator (rig frame): `guarded`, scaled down by the avatar
    /// contact's energy reserve where it would give back more than the hand put in.
    pub(super) command_n: DVec3,
    pub(super) passivity_limited: bool,
}

/// Where one hand's output goes: the device's volts, both hands' impulses, the hand's state for
/// the scene and its record (written in place: the tick copies no more than it must).
pub(super) struct HandOut<'a> {
    pub(super) out: &'a mut Output,
    pub(super) impulses: &'a mut Impulses,
    pub(super) state: &'a mut HandState,
    pub(super) rec: &'a mut HandRecord,
}

/// One hand's output of one tick: volts, impulses, state and record into `to`, counted into
/// `counters`, and kept as the hand's last output. A held hand (`hold`, a rig not faulted, an
/// output to hold) repeats what the strings were told last tick.
pub(super) fn hand_output(
    hi: usize,
    h: &mut HandCore,
    hr: &HandRig,
    hold: bool,
    v: &TickView,
    counters: &mut Counters,
    to: HandOut,
) {
    // A faulted rig never holds (it outputs the safe tensions from this very tick).
    if hold && !v.faulted && h.last.some {
        counters.held[hi] += 1;
        return replay_held(h, hr, to);
    }
    let pose_ok = h.pose.valid && h.zero_m.is_some() && v.device_ok && !hold;
    let vel = h.velocity_if(pose_ok);
    // The avatar hand's contact (local model) engages the energy reserve while active.
    let engaged = v.active && v.model.is_some_and(|m| m.hand_contacts[hi].touching());
    h.passivity.observe(pose_ok.then_some(h.pose.pos_m), engaged);
    blow_phase(hi, h, pose_ok, vel, v, counters);
    let mut hand_impulses = [DVec3::ZERO; MAX_PROXIES];
    let (rendered, want_rig) = render_phase(hi, h, hr, vel, pose_ok, v, &mut hand_impulses);
    if rendered.stiffness_limited {
        counters.stiffness_limited[hi] += 1;
    }
    let safe = safety_phase(h, hr, want_rig, vel, v, engaged && pose_ok);
    if safe.guarded.non_finite {
        counters.non_finite += 1;
    }
    if safe.guarded.clamped {
        counters.clamped[hi] += 1;
    }
    if safe.passivity_limited {
        counters.passivity_limited[hi] += 1;
    }
    let (alloc, produced) = allocate_phase(h, hr, pose_ok, safe.command_n);
    if produced.limited {
        counters.produced_limited[hi] += 1;
    }
    if produced.unmet {
        counters.produced_unmet[hi] += 1;
    }
    h.passivity.commanded(alloc.force_n);
    let last = &mut h.last;
    hand_impulses_of(&rendered, &hand_impulses, want_rig, alloc.force_n, v.gain, last);
    if rendered.contacts > 0 {
        to.impulses.add(&last.impulses, &last.contact_impulses);
    }
    match alloc.method {
        Method::Exact => {}
        Method::Scaled => counters.infeasible[hi] += 1,
        Method::Fallback => counters.fallback[hi] += 1,
    }
    last.volts = volts_of(hr, &alloc.tensions_n);
    for (&ch, &volts) in hr.channels.iter().zip(last.volts.iter()) {
        if ch < MAX_CHANNELS {
            to.out.volts[ch] = volts;
        }
    }
    last.state = HandState {
        pos_world_m: v.xf.point(h.pose.pos_m),
        vel_world_m_per_s: v.xf.vector(vel),
        force_n: v.xf.vector(alloc.force_n),
        valid: pose_ok,
    };
    last.rec = HandRecord {
        pos_rig_m: h.pose.pos_m,
        vel_rig_m_per_s: vel,
        residual_m: h.pose.residual_m,
        valid: pose_ok,
        rendered_n: want_rig,
        commanded_n: safe.command_n,
        output_n: alloc.force_n,
        tensions_n: alloc.tensions_n,
        scale: alloc.scale,
        method: alloc.method,
        contacts: rendered.contacts,
        clamped: safe.guarded.clamped,
        stiffness_limited: rendered.stiffness_limited,
        non_finite: safe.guarded.non_finite,
        reserve_j: h.passivity.reserve_j(),
        passivity_limited: safe.passivity_limited,
        blow_n: h.blow_n * applied_share(want_rig, alloc.force_n),
        held: false,
    };
    last.some = true;
    *to.state = last.state;
    *to.rec = last.rec;
}

/// A held hand: its last volts written again (not left in `out`: the step does not depend on
/// what the buffer held), its last impulses sent again, its last state and record repeated.
fn replay_held(h: &mut HandCore, hr: &HandRig, to: HandOut) {
    for s in 0..4 {
        if let Some(v) = to.out.volts.get_mut(hr.channels[s]) {
            *v = h.last.volts[s];
        }
    }
    to.impulses.add(&h.last.impulses, &h.last.contact_impulses);
    // The held output is what the strings apply this tick: the energy reserve books the hand's
    // motion over a run of held ticks against it, not against the force commanded before the run.
    h.passivity.commanded(h.last.rec.output_n);
    *to.state = h.last.state;
    *to.rec = HandRecord { held: true, ..h.last.rec };
}

/// The blow phase: this tick's force of the newest landed blow on the hand (`blow.rs`: its push
/// and its burst after impact), into `h.blow_n` (rig frame) for the render
/// phase, counted: a blow felt, a push scaled by its reserve, a burst cut by its budget, the
/// bursts' work on the hand.
fn blow_phase(hi: usize, h: &mut HandCore, pose_ok: bool, vel: DVec3, v: &TickView, counters: &mut Counters) {
    let b = v.model.map(|m| m.blow).unwrap_or_default();
    let live = v.active && pose_ok && b.seq == h.blow.seq();
    let dir = v.xf.vector_to_rig(b.dir);
    let pos = live.then_some(h.pose.pos_m);
    let p = BlowParams::default();
    let t = h.blow.tick(&p, pos, vel, dir, v.gain, v.dt_s);
    h.blow_n = t.force.total_n();
    if t.burst_work_j > 0.0 {
        h.burst_given_j += t.burst_work_j;
        counters.blow_burst_uj[hi] = (h.burst_given_j * 1e6) as u64;
    }
    counters.blows_felt[hi] += u64::from(t.newly_felt);
    counters.blow_push_limited[hi] += u64::from(t.force.push_limited);
    counters.blow_burst_cut[hi] += u64::from(t.force.burst_cut);
}

/// The render phase: the force the contact model asks at the hand's pose (rig frame: the
/// proxies', the avatar hand's contact, the scene's extra force and the landed blow's, from the
/// blow phase) and each proxy's impulse
/// over the tick (world frame) into `impulses`. Nothing unless active with a trusted pose and a
/// model.
pub(super) fn render_phase(
    hi: usize,
    h: &HandCore,
    hr: &HandRig,
    vel_m_per_s: DVec3,
    pose_ok: bool,
    v: &TickView,
    impulses: &mut [DVec3; MAX_PROXIES],
) -> (Rendered, DVec3) {
    let (Some(m), true) = (v.model, v.active && pose_ok) else {
        return (Rendered::default(), DVec3::ZERO);
    };
    let age_s = v.age_s.unwrap_or(0.0).max(0.0);
    let pos_w = v.xf.point(h.pose.pos_m);
    let mut rendered = render::render_hand(
        hi,
        pos_w,
        v.xf.vector(vel_m_per_s),
        hr.grip_radius_m,
        hr.stiffness_limit_n_per_m,
        m,
        age_s,
        v.dt_s,
        impulses,
    );
    let l = local::render_contact(&m.hand_contacts[hi], pos_w, hr.stiffness_limit_n_per_m);
    rendered.stiffness_limited |= l.stiffness_limited;
    if l.force_n != DVec3::ZERO {
        rendered.contacts = rendered.contacts.saturating_add(1);
    }
    let want_rig = v.xf.vector_to_rig(rendered.force_n + l.force_n + m.extra_force_n[hi]) + h.blow_n;
    (rendered, want_rig)
}

/// The safety phase: the rendered force through the tick's gain and the hand's force limit
/// (non-finite to zero), then never more energy back to the hand than it put into the avatar
/// hand's contact: the guarded force is only scaled down along its direction, so the guard holds.
pub(super) fn safety_phase(
    h: &HandCore,
    hr: &HandRig,
    want_rig_n: DVec3,
    vel_m_per_s: DVec3,
    v: &TickView,
    engaged: bool,
) -> SafeForce {
    let guarded = safety::guard(want_rig_n, v.gain, hr.force_limit_n);
    let (command_n, passivity_limited) = h.passivity.limit(guarded.force_n, vel_m_per_s, v.dt_s, engaged);
    SafeForce { guarded, command_n, passivity_limited }
}

/// The allocation phase: string tensions for the commanded force, along the strings'
/// directions from the current pose, or from the last good one when it is not trusted; then the
/// force those tensions produce brought within the hand's force limit (`produced.rs`: the
/// fallback's may exceed it).
pub(super) fn allocate_phase(
    h: &mut HandCore,
    hr: &HandRig,
    pose_ok: bool,
    command_n: DVec3,
) -> (Allocation, ProducedLimit) {
    let dir_pos = if pose_ok { h.pose.pos_m } else { h.safe_pos_m };
    let dirs = h.kin.directions(dir_pos);
    let mut alloc = h.alloc.allocate(&dirs, command_n);
    let min_n = h.alloc.limits().min_n;
    let limited = produced::limit_produced(&mut alloc, &dirs, min_n, hr.force_limit_n, command_n);
    (alloc, limited)
}

/// Two impulses go back per proxy (see `HandSample`). The applied one is only what the user's
/// hand really received: the rendered force after the ramp, fade, clamp and allocation scaling
/// (all along its own direction). The virtual contact itself acts with the loop's gain only (a
/// stale or ramped-out model must not push the world either), never limited by what the rig can
/// display. `render_hand` already dropped non-finite contacts; the check keeps a NaN gain out.
/// Both zero when the hand touched nothing. Written into the hand's last output.
fn hand_impulses_of(
    rendered: &Rendered,
    impulses: &[DVec3; MAX_PROXIES],
    want_rig_n: DVec3,
    output_n: DVec3,
    gain: f64,
    last: &mut HeldHand,
) {
    last.impulses = [DVec3::ZERO; MAX_PROXIES];
    last.contact_impulses = [DVec3::ZERO; MAX_PROXIES];
    if rendered.contacts == 0 {
        return;
    }
    let applied = applied_share(want_rig_n, output_n);
    let mine = last.impulses.iter_mut().zip(last.contact_impulses.iter_mut());
    for ((m, mc), imp) in mine.zip(impulses.iter()) {
        *m = *imp * applied;
        let c = *imp * gain;
        if c.is_finite() {
            *mc = c;
        }
    }
}

/// The share of the rendered force `want_rig_n` the hand received in `output_n` (the gain, the
/// clamp, the reserve and the allocation all scale along its direction): 0 to 1, 0 for none.
fn applied_share(want_rig_n: DVec3, output_n: DVec3) -> f64 {
    let want_sq = want_rig_n.length_squared();
    let share = if want_sq > 0.0 { (output_n.dot(want_rig_n) / want_sq).clamp(0.0, 1.0) } else { 0.0 };
    if share.is_finite() {
        share
    } else {
        0.0
    }
}

/// The volts of a hand's four channels for its string tensions.
fn volts_of(hr: &HandRig, tensions_n: &[f64; 4]) -> [f64; 4] {
    std::array::from_fn(|s| tensions_n[s] * hr.volts_per_newton[s])
}
