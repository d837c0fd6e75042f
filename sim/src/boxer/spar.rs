//! Two people box each other (issue 28): the boxing world with both upper bodies driven by a rig.
//!
//! The boxing world's two actors become two seats: seat 0 drives the avatar (at the origin,
//! facing -z), seat 1 the body that was the virtual human (0.80 m in front, turned to face it).
//! Each seat's user stands in their own rig the same way, facing -z: seat 1's hands reach the
//! world through the turn and place of its body ([`SeatFrame`]). Every step both bodies' hands
//! are pulled to their users' hands by the coupling spring-damper of the boxing scene (both
//! bodies get the avatar's softer joints); the fists collide with the other body; and each
//! seat's hands get their contacts as local models in that seat's own rig frame, as the boxing
//! scene reports the avatar's ([`HandContact`]), with the contacts on the rest of its body (the
//! blows it takes) summed for the scene to attenuate. The virtual human's mind does not run.
//!
//! A seat with nobody at it (not joined yet, or dropped out) is a standing opponent: its hands
//! are pulled to their guard, where they rest at the start, so it blocks what comes at its
//! guard and takes what goes past it.
//!
//! Must never: feed the coupling spring back to a user, or allocate in a step.

use glam::{DMat3, DVec3};
use spidar_msg::HandContact;

use super::{coupling_force, BoxerParams, BoxingWorld, HandTarget, Parts, StiffnessEstimate, AVATAR, BOXER};
use crate::passive::passive_forces;
use crate::step::integrate;
use crate::SimError;

/// Seats, one per rig.
pub const SEATS: usize = 2;

/// A punch that lands within this long after the last one is the same hit (a penalty contact
/// may touch, bounce and touch again within a few steps).
const HIT_GAP_S: f64 = 0.15;

/// Where a seat's rig frame sits in the world: `sim = rot (rig + offset) + origin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeatFrame {
    pub rot: DMat3,
    pub origin_m: DVec3,
    /// The boxing scene's `user_offset_m` (rig frame).
    pub offset_m: DVec3,
}

impl SeatFrame {
    pub fn to_sim(&self, p_rig: DVec3) -> DVec3 {
        self.rot * (p_rig + self.offset_m) + self.origin_m
    }
    pub fn vector_to_sim(&self, v: DVec3) -> DVec3 {
        self.rot * v
    }
    pub fn vector_to_rig(&self, v: DVec3) -> DVec3 {
        self.rot.transpose() * v
    }
    pub fn to_rig(&self, p_sim: DVec3) -> DVec3 {
        self.rot.transpose() * (p_sim - self.origin_m) - self.offset_m
    }
}

/// What one step did, per seat (rig frames).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SparReport {
    /// Per seat, per hand: the contact on the body's hand as the local model its rig renders.
    pub hand_contacts: [[HandContact; 2]; SEATS],
    /// Per seat: the contact forces on the body's other parts (the blows it takes), unattenuated.
    pub damage_force_n: [DVec3; SEATS],
    /// Per seat, per hand: the coupling spring's force (never fed back), world frame.
    pub coupling_force_n: [[DVec3; 2]; SEATS],
    /// Per seat, per hand: the fist touches the other body's head or chest, or its hand or
    /// forearm (a block).
    pub landed: [[bool; 2]; SEATS],
    pub blocked: [[bool; 2]; SEATS],
}

/// The boxing world with a rig at each body.
pub struct SparWorld {
    /// The model, state and workspace (its mind is not used).
    pub world: BoxingWorld,
    /// The bodies' parts, per seat.
    pub bodies: [Parts; SEATS],
    pub frames: [SeatFrame; SEATS],
    /// Per seat, per hand: where the hand rests at the start (world frame): an empty seat's guard.
    pub guard_m: [[DVec3; 2]; SEATS],
    pub last: SparReport,
    /// Per seat: punches that landed on the other body (head or chest).
    pub hits: [u64; SEATS],
    /// Per seat: punches the other body's guard stopped (the fist met its hand or forearm).
    pub blocked: [u64; SEATS],
    last_hit_s: [f64; SEATS],
    last_block_s: [f64; SEATS],
    hand_pair_k: [[Vec<f64>; 2]; SEATS],
    stiffness: [[StiffnessEstimate; 2]; SEATS],
}

impl SparWorld {
    pub fn new(params: BoxerParams) -> Result<SparWorld, SimError> {
        let mut world = BoxingWorld::new(BoxerParams { active: false, ..params })?;
        let s = world.params.avatar_joint_scale;
        // The second body is driven by a person too: the avatar's softer joints (not the root).
        for b in world.model.articulations[BOXER].bodies.clone().skip(1) {
            for k in world.model.bodies[b].stiffness.iter_mut() {
                *k *= s;
            }
            for d in world.model.bodies[b].damping.iter_mut() {
                *d *= s;
            }
        }
        world.prepared = false;
        world.begin_step();
        let bodies = [world.avatar, world.vh];
        let offset_m = world.params.user_offset_m;
        let root = |a: usize| world.model.articulations[a].bodies.start;
        // Each body's root frame in the world: the avatar's is the world's, the other's turned.
        let frame = |a: usize| {
            let x = &world.ws.x0[root(a)];
            let turn =
                if a == AVATAR { DMat3::IDENTITY } else { DMat3::from_rotation_y(std::f64::consts::PI) };
            let origin = DVec3::new(x.r.x, 0.0, x.r.z) * if a == AVATAR { 0.0 } else { 1.0 };
            SeatFrame { rot: turn, origin_m: origin, offset_m }
        };
        let frames = [frame(AVATAR), frame(BOXER)];
        let guard_m = bodies.map(|p| p.hand.map(|h| world.com(h)));
        let hand_pair_k = bodies.map(|p| p.hand.map(|hand| pair_stiffness(&world, hand)));
        Ok(SparWorld {
            world,
            bodies,
            frames,
            guard_m,
            last: SparReport::default(),
            hits: [0; SEATS],
            last_hit_s: [f64::NEG_INFINITY; SEATS],
            blocked: [0; SEATS],
            last_block_s: [f64::NEG_INFINITY; SEATS],
            hand_pair_k,
            stiffness: [[StiffnessEstimate::default(); 2]; SEATS],
        })
    }

    pub fn dt_s(&self) -> f64 {
        self.world.dt_s()
    }

    pub fn t_s(&self) -> f64 {
        self.world.state.t_s
    }

    /// One 3 ms step. `hands[seat]`: that seat's user's hands in its rig frame (None per hand: not
    /// tracked, only its joints hold it), or None for an empty seat (its hands hold their guard).
    pub fn step(&mut self, hands: &[Option<[Option<HandTarget>; 2]>; SEATS]) -> SparReport {
        let w = &mut self.world;
        w.begin_step();
        let mut rep = SparReport::default();
        let mut sim_targets = [[None; 2]; SEATS];
        for seat in 0..SEATS {
            let fr = &self.frames[seat];
            for h in 0..2 {
                let t = match &hands[seat] {
                    Some(user) => user[h].map(|t| HandTarget {
                        pos_m: fr.to_sim(t.pos_m),
                        vel_m_per_s: fr.vector_to_sim(t.vel_m_per_s),
                    }),
                    None => Some(HandTarget { pos_m: self.guard_m[seat][h], vel_m_per_s: DVec3::ZERO }),
                };
                sim_targets[seat][h] = t;
                let Some(t) = t else { continue };
                let b = self.bodies[seat].hand[h];
                let f = coupling_force(&w.model, &w.ws, b, &t, &w.params);
                let c = w.ws.com_world(&w.model, b);
                w.ws.add_force_at(b, c, f);
                rep.coupling_force_n[seat][h] = f;
            }
        }
        passive_forces(&w.model, &w.state, &mut w.ws);
        crate::aba::aba(&w.model, &w.state, &mut w.ws);
        integrate(&w.model, &mut w.state, &mut w.ws);
        w.prepared = false;
        w.begin_step();
        self.report_contacts(&sim_targets, &mut rep);
        let t = self.world.state.t_s;
        for seat in 0..SEATS {
            if rep.landed[seat].iter().any(|&x| x) {
                if t - self.last_hit_s[seat] > HIT_GAP_S {
                    self.hits[seat] += 1;
                }
                self.last_hit_s[seat] = t;
            }
            if rep.blocked[seat].iter().any(|&x| x) {
                if t - self.last_block_s[seat] > HIT_GAP_S {
                    self.blocked[seat] += 1;
                }
                self.last_block_s[seat] = t;
            }
        }
        self.last = rep;
        rep
    }

    /// The contacts of the new state, per seat, into `rep` (rig frames).
    fn report_contacts(&mut self, targets: &[[Option<HandTarget>; 2]; SEATS], rep: &mut SparReport) {
        let w = &self.world;
        let m = &w.model;
        let seat_of =
            |body: usize| (0..SEATS).find(|&s| m.articulations[[AVATAR, BOXER][s]].bodies.contains(&body));
        // Per seat and hand: the summed force, the stiffness-weighted normal, the summed
        // stiffness and the power the touched bodies put in (world frame).
        let mut sums = [[(DVec3::ZERO, DVec3::ZERO, 0.0f64, 0.0f64); 2]; SEATS];
        let mut damage = [DVec3::ZERO; SEATS];
        for c in &w.ws.contacts {
            let (Some(a), Some(b)) = (c.body_a.map(usize::from), c.body_b.map(usize::from)) else {
                continue;
            };
            for (me, f, n, other, other_shape) in
                [(a, c.force_n, c.normal, b, c.shape_b), (b, -c.force_n, -c.normal, a, c.shape_a)]
            {
                let Some(seat) = seat_of(me) else { continue };
                let (mine, theirs) = (&self.bodies[seat], &self.bodies[1 - seat]);
                if let Some(h) = mine.hand.iter().position(|&x| x == me) {
                    let k = self.hand_pair_k[seat][h][other_shape as usize];
                    let x = &w.ws.x0[other];
                    let v_other = w.ws.point_velocity(other, x.e * (c.point_m - x.r));
                    let s = &mut sums[seat][h];
                    s.0 += f;
                    s.1 += n * k;
                    s.2 += k;
                    s.3 += f.dot(v_other);
                    rep.landed[seat][h] |= other == theirs.head || other == theirs.chest;
                    rep.blocked[seat][h] |= theirs.hand.contains(&other) || theirs.forearm.contains(&other);
                } else {
                    damage[seat] += f;
                }
            }
        }
        let p = &w.params;
        let kc = p.coupling_k_n_per_m;
        for seat in 0..SEATS {
            let fr = self.frames[seat];
            rep.damage_force_n[seat] = fr.vector_to_rig(damage[seat]);
            for h in 0..2 {
                let (f, nk, k, source) = sums[seat][h];
                let Some(t) = targets[seat][h] else { continue };
                if f == DVec3::ZERO || !f.is_finite() {
                    self.stiffness[seat][h] = StiffnessEstimate::default();
                    continue;
                }
                let hand = self.bodies[seat].hand[h];
                let x = w.ws.point_world(hand, m.bodies[hand].com_m);
                let saturated = ((t.pos_m - x) * kc).length() >= p.coupling_max_n;
                let normal = nk.normalize_or(f.normalize_or_zero());
                let series = if k > 0.0 { kc * k / (kc + k) } else { 0.0 };
                // The slope is the same in any frame: estimated in the world's.
                let est = self.stiffness[seat][h].update(t.pos_m, f, normal);
                rep.hand_contacts[seat][h] = HandContact {
                    force_n: fr.vector_to_rig(f),
                    normal: fr.vector_to_rig(normal),
                    k_n_per_m: if saturated { 0.0 } else { est.clamp(0.0, series) },
                    at_m: fr.to_rig(t.pos_m),
                    source_w: if source.is_finite() { source } else { 0.0 },
                };
            }
        }
    }
}

/// Per shape of the model: the penalty stiffness of the pair `hand`'s shape forms with it.
fn pair_stiffness(w: &BoxingWorld, hand: usize) -> Vec<f64> {
    let m = &w.model;
    let mut k = vec![0.0; m.shapes.len()];
    for p in &m.pairs {
        let (a, b) = (p.a as usize, p.b as usize);
        if m.shapes[a].body == Some(hand) {
            k[b] = p.k_n_per_m;
        } else if m.shapes[b].body == Some(hand) {
            k[a] = p.k_n_per_m;
        }
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world() -> SparWorld {
        SparWorld::new(BoxerParams::default()).unwrap()
    }

    #[test]
    fn the_seats_frames_face_each_other() {
        let w = world();
        let (a, b) = (w.frames[0], w.frames[1]);
        // Each user's "forward" (-z in the rig) points at the other body.
        let fwd_a = a.vector_to_sim(-DVec3::Z);
        let fwd_b = b.vector_to_sim(-DVec3::Z);
        assert!((fwd_a + fwd_b).length() < 1e-12, "{fwd_a} {fwd_b}");
        let home = DVec3::new(0.1, 1.2, 0.0);
        assert!((b.to_rig(b.to_sim(home)) - home).length() < 1e-12);
        assert!(b.to_sim(home).z < a.to_sim(home).z, "seat 1 stands in front of seat 0");
    }

    #[test]
    fn empty_seats_hold_their_guard_and_nothing_touches() {
        let mut w = world();
        for _ in 0..300 {
            w.step(&[None, None]);
        }
        for seat in 0..SEATS {
            for h in 0..2 {
                let at = w.world.com(w.bodies[seat].hand[h]);
                assert!((at - w.guard_m[seat][h]).length() < 0.03, "seat {seat} hand {h} drifted to {at}");
                assert!(!w.last.hand_contacts[seat][h].touching());
            }
        }
        assert_eq!(w.hits, [0, 0]);
    }

    /// Seat 0 punches straight at the other body's head, which stands with its guard (an empty
    /// seat): the fist lands or is blocked, seat 0 feels it in its own frame (pushing its hand
    /// back, +z), and the other body takes it.
    #[test]
    fn a_punch_from_one_seat_lands_on_the_other_body_and_is_felt_back() {
        let mut w = world();
        let guard_rig = w.frames[0].to_rig(w.guard_m[0][1]);
        let head = w.world.com(w.bodies[1].head);
        let head_rig = w.frames[0].to_rig(head);
        let mut felt_back = 0;
        let mut landed_or_blocked = false;
        let mut other_took = 0.0f64;
        for i in 0..200 {
            let s = (i as f64 / 60.0).min(1.0);
            let pos = guard_rig + (head_rig - guard_rig) * s * 1.2;
            let t = HandTarget { pos_m: pos, vel_m_per_s: (head_rig - guard_rig) * 1.2 / 0.18 };
            let rep = w.step(&[Some([None, Some(t)]), None]);
            let c = rep.hand_contacts[0][1];
            if c.touching() {
                assert!(
                    c.force_n.z > 0.0,
                    "the blow pushes seat 0's hand back toward its user: {}",
                    c.force_n
                );
                felt_back += 1;
            }
            landed_or_blocked |= rep.landed[0][1] || rep.blocked[0][1];
            other_took =
                other_took.max(rep.damage_force_n[1].length() + rep.hand_contacts[1][0].force_n.length());
        }
        assert!(landed_or_blocked && felt_back > 3, "contact ticks {felt_back}");
        assert!(other_took > 1.0, "the other body took {other_took} N");
    }

    /// Two users throw the same punch at once: each feels its own contact in its own frame, alike.
    #[test]
    fn mirrored_punches_are_felt_alike_by_both_seats() {
        let mut w = world();
        // Both left hands: the whole bout turned half a turn is the same bout, seats swapped.
        let g = [w.frames[0].to_rig(w.guard_m[0][0]), w.frames[1].to_rig(w.guard_m[1][0])];
        let mut peak = [0.0f64; 2];
        for i in 0..150 {
            let s = (i as f64 / 50.0).min(1.0);
            let reach = DVec3::new(0.0, 0.0, -0.45) * s;
            let t0 = HandTarget { pos_m: g[0] + reach, vel_m_per_s: DVec3::ZERO };
            let t1 = HandTarget { pos_m: g[1] + reach, vel_m_per_s: DVec3::ZERO };
            let rep = w.step(&[Some([Some(t0), None]), Some([Some(t1), None])]);
            peak[0] = peak[0].max(rep.hand_contacts[0][0].force_n.length());
            peak[1] = peak[1].max(rep.hand_contacts[1][0].force_n.length());
        }
        assert!(peak[0] > 1.0 && peak[1] > 1.0, "{peak:?}");
        assert!(
            (peak[0] - peak[1]).abs() < 0.2 * peak[0].max(peak[1]),
            "the mirrored bout differs: {peak:?}"
        );
    }
}
