//! The spar scene (issue 28): two people box each other, one rig per seat, one world.
//!
//! `spidar world --scene spar` listens for two rigs ([`spidar_link::world::WorldLink::bind_seats`]).
//! The world is the boxing world with both bodies driven ([`spidar_sim::boxer::spar`]): seat 0's
//! user drives the avatar, seat 1's the body in front of it. Every 3 ms step each seat gets its
//! own model, stamped on its own rig's clock: the contacts on its body's hands as local models
//! (the other's blows and blocks on its fists), and the blows its body takes, attenuated as the
//! boxing scene attenuates them, on both hands. Each rig renders them at 1 kHz and keeps them
//! passive with its energy reserve (`spidar_rt::local`), whatever the network between them does.
//!
//! The scene is also a [`Scene`] for what watches it: its look ([`SparScene::look`]) draws both
//! bodies as people (seat 0 blue, seat 1 red) with an eye per seat, so the live view shows the
//! bout from either person's eye or an orbit, and the world's recording holds both bodies and
//! their contacts.
//!
//! A seat with nobody at it (not joined yet, dropped out) is a standing opponent holding its
//! guard; [`serve_spar`] says so when it happens. With nobody at either seat the world pauses.
//!
//! Must never: send a seat the other seat's contacts, or the coupling spring.

use std::time::{Duration, Instant};

use glam::DVec3;
use spidar_link::sock::realtime_ns;
use spidar_link::world::{rig_time_now, Arrived, WorldEvent, WorldLink};
use spidar_msg::{ContactModel, HandSample, HANDS};
use spidar_sim::boxer::spar::{SparWorld, SEATS};
use spidar_sim::boxer::{BoxerParams, HandTarget, AVATAR, BOXER};

use crate::boxing::look::{humanoid, AVATAR_COLOUR, AVATAR_GLOVE, FLOOR_COLOUR, VH_COLOUR, VH_GLOVE};
use crate::host::ServeReport;
use crate::look::{Look, LookEye, LookShape, Poses};
use crate::{Observer, Scene, StepView};

/// The scene's name, as `--scene` takes it.
pub const NAME: &str = "spar";

/// Two users' bodies in one boxing world.
pub struct SparScene {
    pub world: SparWorld,
    seq: [u64; SEATS],
    /// Per seat: a user is there (else the body holds its guard).
    present: [bool; SEATS],
    targets: [[Option<HandTarget>; HANDS]; SEATS],
}

impl SparScene {
    pub fn new(params: BoxerParams) -> anyhow::Result<SparScene> {
        Ok(SparScene {
            world: SparWorld::new(params)?,
            seq: [0; SEATS],
            present: [false; SEATS],
            targets: [[None; HANDS]; SEATS],
        })
    }

    pub fn step_s(&self) -> f64 {
        self.world.dt_s()
    }

    /// A user sits down at `seat` (true) or leaves it (false: the body holds its guard).
    pub fn set_present(&mut self, seat: usize, present: bool) {
        self.present[seat] = present;
        self.targets[seat] = [None; HANDS];
    }

    pub fn present(&self) -> [bool; SEATS] {
        self.present
    }

    /// One step with each seat's samples since the last (oldest first; the newest is where the
    /// user's hands are); returns each seat's model stamped `stamps_s[seat]` (its rig's clock).
    pub fn step(&mut self, samples: [&[HandSample]; SEATS], stamps_s: [f64; SEATS]) -> [ContactModel; SEATS] {
        let mut hands = [None; SEATS];
        for seat in 0..SEATS {
            if !self.present[seat] {
                continue;
            }
            if let Some(s) = samples[seat].last() {
                for h in 0..HANDS {
                    let hs = s.hands[h];
                    self.targets[seat][h] = hs
                        .valid
                        .then_some(HandTarget { pos_m: hs.pos_world_m, vel_m_per_s: hs.vel_world_m_per_s });
                }
            }
            hands[seat] = Some(self.targets[seat]);
        }
        let rep = self.world.step(&hands);
        let att = self.world.world.params.damage_attenuation;
        std::array::from_fn(|seat| {
            self.seq[seat] += 1;
            ContactModel {
                seq: self.seq[seat],
                stamp_s: stamps_s[seat],
                hand_contacts: rep.hand_contacts[seat],
                extra_force_n: [rep.damage_force_n[seat] * att; HANDS],
                ..Default::default()
            }
        })
    }

    /// Who is where, the hits each landed and the punches the other's guard stopped.
    pub fn status(&self) -> String {
        let who = |s: usize| if self.present[s] { "a person" } else { "a standing opponent" };
        let w = &self.world;
        format!(
            "seat 0: {} ({} hits landed, {} blocked) | seat 1: {} ({} hits landed, {} blocked)",
            who(0),
            w.hits[0],
            w.blocked[0],
            who(1),
            w.hits[1],
            w.blocked[1]
        )
    }
}

/// Where a seat's user's eye is in their rig frame when the rig says nothing (the view page's
/// default eye: above and behind the grips).
const EYE_RIG_M: DVec3 = DVec3::new(0.0, 1.45, 0.4);

/// The counters the heads-up display shows, in the order [`SparScene::pose`] writes them.
const COUNTERS: [&str; 2] = ["seat 0 hits landed", "seat 1 hits landed"];

/// The actor a seat's body is drawn as (its shapes are `seat N/part`).
pub fn actor(seat: usize) -> &'static str {
    ["seat 0", "seat 1"][seat]
}

impl Scene for SparScene {
    fn name(&self) -> &str {
        NAME
    }

    fn step_s(&self) -> f64 {
        self.world.dt_s()
    }

    /// Stepped as a one-rig scene, the rig takes seat 0 and boxes whoever is at seat 1 (a
    /// standing opponent unless [`SparScene::set_present`] says otherwise).
    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel {
        if !self.present[0] {
            self.set_present(0, true);
        }
        let [m, _] = SparScene::step(self, [samples, &[]], [t_s, 0.0]);
        m
    }

    fn status(&self) -> String {
        SparScene::status(self)
    }

    /// Both bodies as their collision shapes and as people, seat 0's in blue, seat 1's in red
    /// (gloves darker), and each seat's eye looking at the other's head.
    fn look(&self) -> Look {
        let w = &self.world.world;
        let m = &w.model;
        let seat_of =
            |b: usize| (0..SEATS).find(|&s| m.articulations[[AVATAR, BOXER][s]].bodies.contains(&b));
        let shapes = m
            .shapes
            .iter()
            .map(|s| {
                let (actor, colour, glove) = match s.body.and_then(seat_of) {
                    Some(0) => (actor(0), AVATAR_COLOUR, AVATAR_GLOVE),
                    Some(_) => (actor(1), VH_COLOUR, VH_GLOVE),
                    None if s.body.is_some() => ("body", AVATAR_COLOUR, AVATAR_COLOUR),
                    None => ("scenery", FLOOR_COLOUR, FLOOR_COLOUR),
                };
                let is_glove = s.body.is_some_and(|b| self.world.bodies.iter().any(|p| p.hand.contains(&b)));
                LookShape {
                    name: format!("{actor}/{}", s.name.rsplit('.').next().unwrap_or(&s.name)),
                    shape: s.shape,
                    colour: if is_glove { glove } else { colour },
                    proxy: None,
                }
            })
            .collect();
        let head = |seat: usize| w.com(self.world.bodies[seat].head) - DVec3::new(0.0, 0.1, 0.0);
        let eyes = (0..SEATS)
            .map(|seat| LookEye {
                name: actor(seat).into(),
                eye_m: self.world.frames[seat].to_sim(EYE_RIG_M),
                focus_m: head(1 - seat),
            })
            .collect();
        Look {
            shapes,
            counters: COUNTERS.iter().map(|c| c.to_string()).collect(),
            link_offset_m: w.params.user_offset_m,
            focus_m: head(1),
            humanoids: vec![
                humanoid(m, AVATAR, actor(0), AVATAR_COLOUR),
                humanoid(m, BOXER, actor(1), VH_COLOUR),
            ],
            eyes,
            gazes: Vec::new(),
            ..Look::default()
        }
    }

    /// Every shape's pose, the contacts between the bodies (the part hit flashes), the hits.
    fn pose(&self, out: &mut Poses<'_>) {
        let w = &self.world.world;
        crate::boxing::look::pose_shapes_and_contacts(&w.ws, out);
        for (i, h) in self.world.hits.iter().enumerate() {
            out.counter(i, *h as f64);
        }
    }
}

/// What the spar world says about an event on its link.
pub fn describe(e: &WorldEvent, present: [bool; SEATS]) -> String {
    let other = |seat: usize| {
        let o = 1 - seat;
        if present[o] {
            format!("seat {o} boxes a standing opponent with its guard up until someone joins")
        } else {
            "nobody is boxing: the world waits".to_string()
        }
    };
    match e {
        WorldEvent::Connected { rig, seat, again, .. } => {
            let with = if present[1 - seat] {
                format!("boxing the person at seat {}", 1 - seat)
            } else {
                format!("boxing a standing opponent until someone takes seat {}", 1 - seat)
            };
            let verb = if *again { "connected again" } else { "joined" };
            format!("seat {seat}: the rig at {rig} {verb}, {with}")
        }
        WorldEvent::Left { rig, seat } => format!("seat {seat}: the rig at {rig} stopped; {}", other(*seat)),
        WorldEvent::Lost { rig, silent_s, seat } => {
            format!("seat {seat}: the rig at {rig} lost (silent for {silent_s:.2} s); {}", other(*seat))
        }
        other => crate::host::describe(other),
    }
}

/// Runs the two-seat world on this clock until `stop()` says so; `say` gets one line per event.
/// Each seat's model is stamped with its rig's time now (its newest sample plus the time since it
/// arrived), so each rig sees the model's true age on its own clock. The `observers` (the live
/// view, the world's recording) see every step at world time, with seat 0's samples and model.
pub fn serve_spar(
    scene: &mut SparScene,
    link: &mut WorldLink,
    observers: &mut [Box<dyn Observer>],
    stop: &dyn Fn() -> bool,
    say: &mut dyn FnMut(&str),
) -> ServeReport {
    let mut rep = ServeReport::default();
    let step = Duration::from_secs_f64(scene.step_s());
    let mut arrived: Vec<Arrived> = Vec::with_capacity(512);
    let mut events = Vec::new();
    let mut samples: [Vec<HandSample>; SEATS] = std::array::from_fn(|_| Vec::with_capacity(256));
    let mut anchor: [Option<(f64, i64)>; SEATS] = [None; SEATS];
    let mut deadline: Option<Instant> = None;
    while !stop() {
        let anyone = (0..SEATS).any(|s| link.peer_at(s).is_some());
        if anyone {
            let d = *deadline.get_or_insert_with(Instant::now);
            if let Some(wait) = d.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        } else {
            deadline = None;
            link.wait(Duration::from_millis(50));
        }
        link.drain(&mut arrived, &mut events);
        for e in events.drain(..) {
            match e {
                WorldEvent::Connected { seat, .. } => scene.set_present(seat, true),
                WorldEvent::Left { seat, .. } | WorldEvent::Lost { seat, .. } => {
                    scene.set_present(seat, false);
                    anchor[seat] = None;
                    rep.pauses += 1;
                }
                _ => {}
            }
            say(&describe(&e, scene.present()));
        }
        for s in samples.iter_mut() {
            s.clear();
        }
        for a in arrived.drain(..) {
            if a.seat < SEATS && scene.present()[a.seat] {
                samples[a.seat].push(a.sample);
                anchor[a.seat] = Some((a.sample.t_s, a.arrived_ns));
            }
        }
        if !anyone {
            continue;
        }
        let d = deadline.get_or_insert_with(Instant::now);
        *d += step;
        let late = Instant::now().saturating_duration_since(*d);
        if late > Duration::ZERO {
            rep.late_steps += 1;
            if late > 10 * step {
                *d = Instant::now();
            }
        }
        let now = realtime_ns();
        let stamps = anchor.map(|a| a.map_or(0.0, |(t, at)| rig_time_now(t, at, now)));
        let t0 = Instant::now();
        let models = scene.step([&samples[0], &samples[1]], stamps);
        rep.max_step_s = rep.max_step_s.max(t0.elapsed().as_secs_f64());
        rep.steps += 1;
        let view = StepView {
            t_s: scene.world.t_s(),
            scene: &*scene,
            samples: &samples[0],
            model: &models[0],
            rig_info: None,
            rig_status: None,
        };
        for o in observers.iter_mut() {
            o.after_step(&view);
        }
        for seat in 0..SEATS {
            if anchor[seat].is_some() {
                link.send_model_to(seat, &models[seat], &mut events);
            }
        }
    }
    link.close();
    rep.link = *link.stats();
    rep
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use spidar_msg::HandState;

    fn sample(t_s: f64, right_m: DVec3) -> HandSample {
        let mut s = HandSample { t_s, ..Default::default() };
        s.hands[1] = HandState { pos_world_m: right_m, valid: true, ..Default::default() };
        s
    }

    #[test]
    fn each_seat_gets_its_own_contacts_stamped_on_its_own_clock() {
        let mut sc = SparScene::new(BoxerParams::default()).unwrap();
        sc.set_present(0, true);
        sc.set_present(1, true);
        let w = &sc.world;
        let guard = w.frames[0].to_rig(w.guard_m[0][1]);
        let head = w.frames[0].to_rig(w.world.com(w.bodies[1].head));
        let home1 = w.frames[1].to_rig(w.guard_m[1][1]);
        let (mut felt0, mut felt1_blow) = (0.0f64, 0.0f64);
        for i in 0..200 {
            let s = (i as f64 / 60.0).min(1.0);
            let s0 = sample(10.0 + i as f64 * 0.003, guard + (head - guard) * s * 1.2);
            let s1 = sample(500.0 + i as f64 * 0.003, home1);
            let m = sc.step([&[s0], &[s1]], [s0.t_s, s1.t_s]);
            assert_eq!((m[0].stamp_s, m[1].stamp_s), (s0.t_s, s1.t_s), "each on its rig's clock");
            assert_eq!((m[0].seq, m[1].seq), (i + 1, i + 1));
            felt0 = felt0.max(m[0].hand_contacts[1].force_n.length());
            felt1_blow =
                felt1_blow.max(m[1].extra_force_n[0].length() + m[1].hand_contacts[0].force_n.length());
        }
        assert!(felt0 > 1.0, "seat 0 felt its punch: {felt0} N");
        assert!(felt1_blow > 0.1, "seat 1 felt the blow or the block: {felt1_blow} N");
        assert!(sc.status().contains("seat 0: a person"), "{}", sc.status());
    }

    #[test]
    fn an_empty_seat_is_a_standing_opponent_and_the_world_says_so() {
        let mut sc = SparScene::new(BoxerParams::default()).unwrap();
        let e =
            WorldEvent::Connected { rig: "udp://10.0.0.2:5000".into(), session: 1, again: false, seat: 0 };
        sc.set_present(0, true);
        let line = describe(&e, sc.present());
        assert!(line.contains("standing opponent until someone takes seat 1"), "{line}");
        sc.set_present(1, true);
        sc.set_present(0, false);
        let e = WorldEvent::Lost { rig: "udp://10.0.0.2:5000".into(), silent_s: 0.6, seat: 0 };
        let line = describe(&e, sc.present());
        assert!(line.contains("seat 1 boxes a standing opponent"), "{line}");
        assert!(sc.status().contains("seat 0: a standing opponent"), "{}", sc.status());
    }
}
