//! The simulated user's boxing scripts (`--script box`): straights, hooks and uppercuts with
//! either hand at the boxing scene's virtual human, at 2-7 m/s, single and in combinations, and
//! feints (punches that slow and stop short), mapped into the rig frame. They belong to the rig
//! side (they drive the simulated rig's hands), but are aimed from a passive copy of the world
//! the scene runs. Every punch is also returned as data ([`Punch`]) so an evaluation knows what
//! was thrown, when, at what and how fast.

use glam::DVec3;
use rand::{Rng, SeedableRng};
use spidar_device::sim::{Script, Segment, TrajectorySample};
use spidar_sim::boxer::reach::min_jerk;
use spidar_sim::boxer::{BoxerParams, BoxingWorld};

/// The shape of a punch's path from the guard to its target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum PunchKind {
    /// Straight from the guard to the target (a jab or a cross).
    Straight,
    /// Swung out to the side first, arriving from the side.
    Hook,
    /// Dropped below first, arriving from below.
    Uppercut,
}

impl PunchKind {
    pub const ALL: [PunchKind; 3] = [PunchKind::Straight, PunchKind::Hook, PunchKind::Uppercut];

    pub fn name(self) -> &'static str {
        match self {
            PunchKind::Straight => "straight",
            PunchKind::Hook => "hook",
            PunchKind::Uppercut => "uppercut",
        }
    }
}

/// Where a punch is aimed: a part of the virtual human in its guard.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum Aim {
    Head,
    Chest,
    /// Its left hand (on the user's right, +x) and right hand.
    LeftHand,
    RightHand,
    /// The left and right side of its chest (section 4.3's targets).
    LeftChest,
    RightChest,
}

impl Aim {
    /// The chest or one of its sides: a punch at the body.
    pub fn is_body(self) -> bool {
        matches!(self, Aim::Chest | Aim::LeftChest | Aim::RightChest)
    }

    pub fn name(self) -> &'static str {
        match self {
            Aim::Head => "head",
            Aim::Chest => "chest",
            Aim::LeftHand => "left hand",
            Aim::RightHand => "right hand",
            Aim::LeftChest => "left chest",
            Aim::RightChest => "right chest",
        }
    }
}

/// One punch of a script.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Punch {
    /// 0 the user's left hand, 1 the right.
    pub hand: usize,
    pub kind: PunchKind,
    pub aim: Aim,
    /// Slows and stops short of the target (0.22-0.32 m short of the aim point, 10-20 cm before the part's surface), then goes back.
    pub feint: bool,
    /// Planned peak speed of the hand along its path (the simulated arm follows with some lag).
    pub speed_m_per_s: f64,
    /// When the fist starts its way out, seconds after the script's start hold.
    pub start_s: f64,
    /// Where the way out starts (rig frame): the user's guard, or for a punch at the body the
    /// guard lowered by [`USER_BODY_DIP_M`].
    pub from_rig_m: DVec3,
    /// How long before `start_s` the hand leaves its guard to lower the level (0 for a punch at
    /// the head).
    pub dip_s: f64,
    /// Out to the end of the path, and back to the guard.
    pub out_s: f64,
    pub back_s: f64,
    /// Position in a combination (0: a single punch or the first of a combination).
    pub in_combo: u32,
    /// The aim point (rig frame).
    pub target_rig_m: DVec3,
    /// Where the way out ends on the path to the aim point, as the path's parameter: 1 for a
    /// punch, less for a feint.
    pub path_end: f64,
}

impl Punch {
    /// When the hand is back at its guard.
    pub fn end_s(&self) -> f64 {
        self.start_s + self.out_s + self.back_s
    }
}

/// What a box script throws.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanOptions {
    /// How many punches (feints included).
    pub punches: usize,
    pub kinds: Vec<PunchKind>,
    pub aims: Vec<Aim>,
    /// Which hands punch.
    pub hands: Vec<usize>,
    /// Share of feints, and of punches that start a combination (2 or 3 punches).
    pub feint_share: f64,
    pub combo_share: f64,
    /// Planned peak speed range (m/s).
    pub speed_m_per_s: (f64, f64),
    /// Pause range between two punches (or combinations) (s).
    pub pause_s: (f64, f64),
    /// A combination's punches alternate between the head and the chest (the first one's aim
    /// drawn, the next at the other level).
    pub high_low: bool,
    /// Where the user holds its fists between punches.
    pub guard: UserGuard,
}

/// Where the scripted user holds its fists between punches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UserGuard {
    /// A boxer's guard, the fists at the chin ([`user_guard_rig`]), raised into at the script's
    /// start; a punch at the body lowers the level first ([`USER_BODY_DIP_M`]). The `box` script's.
    #[default]
    Chin,
    /// The grips' home points, where the rig's grips rest and `user_offset_m` puts the avatar's
    /// hands in its own guard (the body model's); no rise, no dip, the first punch at the start.
    /// The reaction experiment's single straights (docs/boxing.md 5.3).
    Home,
}

impl Default for PlanOptions {
    /// The `box` script: all kinds, head and chest, both hands, a fifth of the punches feints, a
    /// quarter starting a combination; planned peak speeds 2-9 m/s, which the simulated arm
    /// (following with some lag) turns into about 2-7 m/s.
    fn default() -> Self {
        PlanOptions {
            punches: 2000,
            kinds: PunchKind::ALL.to_vec(),
            aims: vec![Aim::Head, Aim::Chest],
            hands: vec![0, 1],
            feint_share: 0.2,
            combo_share: 0.25,
            speed_m_per_s: (2.0, 9.0),
            pause_s: (0.6, 1.2),
            high_low: false,
            guard: UserGuard::Chin,
        }
    }
}

/// A box script: the punches and the two hands' scripts that throw them.
#[derive(Clone, Debug, PartialEq)]
pub struct BoxPlan {
    pub punches: Vec<Punch>,
    /// The two hands' scripts, every punch aimed at the virtual human's guard (open loop: what
    /// `spidar run --script box` plays, where the rig's side does not see the world).
    pub scripts: [Script; 2],
    /// The aim points of the guard the punches were planned at ([`aim_points_rig`]); a punch's
    /// `target_rig_m` minus its aim's point is its scatter.
    pub guard_aims_rig: [DVec3; 6],
    /// The user's own guard, where each hand waits between punches ([`user_guard_rig`]).
    pub user_guard_rig: [DVec3; 2],
}

/// How far below the virtual human's head centre the scripted user holds its fists: at the chin,
/// as a boxer guards it, the user taken as tall as the virtual human (its head centre is about
/// 8 cm above its chin). Measured on the product path (docs/boxing.md 5.1): from the cheekbones
/// (3 cm) straights at the head landed more often than hooks on the default seed.
pub const USER_GUARD_BELOW_HEAD_M: f64 = 0.08;

/// How long the scripted user takes to raise its hands from the rig's home points into its guard
/// at the start of a script; its first punch starts [`USER_GUARD_UP_S`] + 0.1 s after the start.
pub const USER_GUARD_UP_S: f64 = 0.5;

/// How far the scripted user lowers its fist before a punch at the body (the knees bend, as a boxer
/// changes levels to go to the body rather than punching down at it), and in how long: from the
/// guard at the chin this puts the fist about 5 cm under the rig's home points, 11 cm above the
/// chest's aim point.
pub const USER_BODY_DIP_M: f64 = 0.15;
pub const USER_BODY_DIP_S: f64 = 0.15;

/// The scripted user's guard (rig frame), from the aim points of the virtual human's guard
/// ([`aim_points_rig`]): each fist straight above its home point, at the height of the virtual
/// human's head less [`USER_GUARD_BELOW_HEAD_M`]. The rig's home points are where the grips rest,
/// at the virtual human's chest height; a boxer holds the fists at the chin, and a punch at the head
/// from the chest rises past the glove that guards the opponent's chin (docs/boxing.md 5.1).
pub fn user_guard_rig(rig: &spidar_rt::Rig, aims: &[DVec3; 6]) -> [DVec3; 2] {
    let y = aims[aim_index(Aim::Head)].y - USER_GUARD_BELOW_HEAD_M;
    [0, 1].map(|h| {
        let home = rig.hands[h].home_m;
        DVec3::new(home.x, y, home.z)
    })
}

/// The aim points of the scripted boxer, rig frame, for every [`Aim`]: where the virtual human's
/// parts are in its guard (a passive copy, settled), mapped back through `user_offset_m` and the
/// rig's transform, and a little through them, as a boxer aims.
pub fn aim_points_rig(rig: &spidar_rt::Rig, params: &BoxerParams) -> anyhow::Result<[DVec3; 6]> {
    // A passive copy: an active one might start a spontaneous attack while it settles, and the
    // targets would be where its parts were mid-punch.
    let mut w = BoxingWorld::new(BoxerParams { active: false, ..params.clone() })?;
    // Settle into the guard first (the default pose is not yet balanced under gravity).
    for _ in 0..200 {
        w.step(&[None, None]);
    }
    Ok(aim_points_now(&w, rig))
}

/// The aim points of every [`Aim`] where the virtual human's parts are now (rig frame; as
/// [`aim_points_rig`], which takes them from its settled guard).
pub fn aim_points_now(w: &BoxingWorld, rig: &spidar_rt::Rig) -> [DVec3; 6] {
    let vh = w.vh;
    // The virtual human faces +z (toward the user), its left is +x.
    let at = |b: usize, d: DVec3| w.com(b) + d;
    let to_rig = |p: DVec3| rig.rig_to_world.point_to_rig(p - w.params.user_offset_m);
    [
        to_rig(at(vh.head, DVec3::ZERO)),
        to_rig(at(vh.chest, DVec3::new(0.0, -0.03, 0.0))),
        to_rig(at(vh.hand[0], DVec3::new(0.0, 0.0, 0.02))),
        to_rig(at(vh.hand[1], DVec3::new(0.0, 0.0, 0.02))),
        to_rig(at(vh.chest, DVec3::new(0.07, -0.03, 0.0))),
        to_rig(at(vh.chest, DVec3::new(-0.07, -0.03, 0.0))),
    ]
}

fn aim_index(a: Aim) -> usize {
    match a {
        Aim::Head => 0,
        Aim::Chest => 1,
        Aim::LeftHand => 2,
        Aim::RightHand => 3,
        Aim::LeftChest => 4,
        Aim::RightChest => 5,
    }
}

/// The path of a punch of `kind` by `hand` from `from` to `to` (rig frame) at parameter `s` in
/// [0, 1]: a line, or a quadratic curve through a control point out to the side (hook) or below
/// (uppercut), so the fist arrives from there.
fn path_point(kind: PunchKind, hand: usize, from: DVec3, to: DVec3, s: f64) -> DVec3 {
    let mid = (from + to) * 0.5;
    let side = if hand == 0 { -1.0 } else { 1.0 };
    let c = match kind {
        PunchKind::Straight => return from + (to - from) * s,
        // A hook swings level with its target.
        PunchKind::Hook => DVec3::new(to.x + side * 0.26, to.y, to.z + 0.15),
        PunchKind::Uppercut => DVec3::new((mid.x + to.x) * 0.5, to.y - 0.32, to.z + 0.12),
    };
    let u = 1.0 - s;
    from * (u * u) + c * (2.0 * u * s) + to * (s * s)
}

fn path_length(kind: PunchKind, hand: usize, from: DVec3, to: DVec3, s_end: f64) -> f64 {
    let n = 64;
    (0..n)
        .map(|i| {
            let (a, b) = (i as f64 / n as f64 * s_end, (i + 1) as f64 / n as f64 * s_end);
            (path_point(kind, hand, from, to, b) - path_point(kind, hand, from, to, a)).length()
        })
        .sum()
}

/// The path parameter where a feint stops: `short_m` before the target, measured straight.
fn feint_end(kind: PunchKind, hand: usize, from: DVec3, to: DVec3, short_m: f64) -> f64 {
    let mut s = 1.0;
    while s > 0.2 && (path_point(kind, hand, from, to, s) - to).length() < short_m {
        s -= 0.01;
    }
    s
}

/// Samples of the way out (rig frame, every 2 ms), minimum-jerk in time along the path to `s_end`.
fn out_samples(
    kind: PunchKind,
    hand: usize,
    from: DVec3,
    to: DVec3,
    s_end: f64,
    out_s: f64,
) -> Vec<TrajectorySample> {
    let n = ((out_s / 0.002).ceil() as usize).max(2);
    (0..=n)
        .map(|i| {
            let t = out_s * i as f64 / n as f64;
            TrajectorySample { t_s: t, pos_m: path_point(kind, hand, from, to, s_end * min_jerk(t / out_s)) }
        })
        .collect()
}

/// A seeded box script: `opts.punches` punches and feints, thrown one after another with random
/// pauses, or in combinations of 2-3 with short ones; each punch's kind, aim, hand and speed
/// drawn from `opts`.
pub fn box_plan(
    rig: &spidar_rt::Rig,
    params: &BoxerParams,
    seed: u64,
    opts: &PlanOptions,
) -> anyhow::Result<BoxPlan> {
    anyhow::ensure!(
        !opts.kinds.is_empty() && !opts.aims.is_empty() && !opts.hands.is_empty(),
        "a box script needs at least one kind, aim and hand"
    );
    let aims = aim_points_rig(rig, params)?;
    let (guard, dip_m, mut t) = match opts.guard {
        UserGuard::Chin => (user_guard_rig(rig, &aims), USER_BODY_DIP_M, USER_GUARD_UP_S + 0.1),
        UserGuard::Home => ([rig.hands[0].home_m, rig.hands[1].home_m], 0.0, 0.0),
    };
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0xB0C5);
    let pick = |rng: &mut rand_pcg::Pcg64Mcg, n: usize| rng.random_range(0..n);
    let mut punches = Vec::with_capacity(opts.punches);
    let mut combo_left = 0u32;
    let mut in_combo = 0u32;
    let mut last_hand = 0usize;
    let (v_lo, v_hi) = opts.speed_m_per_s;
    while punches.len() < opts.punches {
        if combo_left == 0 {
            in_combo = 0;
            if rng.random::<f64>() < opts.combo_share {
                combo_left = rng.random_range(2..=3);
            } else {
                combo_left = 1;
            }
        }
        // A combination alternates hands when both punch.
        let hand = if in_combo > 0 && opts.hands.len() > 1 {
            1 - last_hand
        } else {
            opts.hands[pick(&mut rng, opts.hands.len())]
        };
        let kind = opts.kinds[pick(&mut rng, opts.kinds.len())];
        let drawn = opts.aims[pick(&mut rng, opts.aims.len())];
        // High-low: a combination's next punch goes to the other level, as a boxer feints (or
        // punches) high to hit low and the other way round.
        let aim = match punches.last().map(|p: &Punch| p.aim) {
            Some(Aim::Head) if opts.high_low && in_combo > 0 => Aim::Chest,
            Some(Aim::Chest) if opts.high_low && in_combo > 0 => Aim::Head,
            _ => drawn,
        };
        let feint = rng.random::<f64>() < opts.feint_share;
        let speed = if v_hi > v_lo { rng.random_range(v_lo..v_hi) } else { v_lo };
        // Scattered a little around the aim point, as no two punches land on the same spot.
        let scatter = DVec3::new(rng.random_range(-0.03..0.03), rng.random_range(-0.03..0.03), 0.0);
        let target = aims[aim_index(aim)] + scatter;
        // A punch at the body starts from a lower level (see [`USER_BODY_DIP_M`]).
        let (from, dip_s) = if aim.is_body() && dip_m > 0.0 {
            (guard[hand] - DVec3::Y * dip_m, USER_BODY_DIP_S)
        } else {
            (guard[hand], 0.0)
        };
        // `t` is when the hand leaves its guard.
        let start_s = t + dip_s;
        let s_end =
            if feint { feint_end(kind, hand, from, target, rng.random_range(0.22..0.32)) } else { 1.0 };
        let len = path_length(kind, hand, from, target, s_end);
        // Minimum-jerk peak speed is 1.875 x the mean.
        let out_s = (1.875 * len / speed).max(0.05);
        let back_s = rng.random_range(0.25..0.35);
        punches.push(Punch {
            hand,
            kind,
            aim,
            feint,
            speed_m_per_s: speed,
            start_s,
            from_rig_m: from,
            dip_s,
            out_s,
            back_s,
            in_combo,
            target_rig_m: target,
            path_end: s_end,
        });
        last_hand = hand;
        in_combo += 1;
        combo_left -= 1;
        // The next punch of a combination starts as this one comes back (with the other hand),
        // or after it is back (the same hand); the next combination after a pause.
        let next_same_hand = opts.hands.len() == 1;
        t = start_s
            + if combo_left > 0 {
                out_s + if next_same_hand { back_s } else { 0.5 * back_s } + rng.random_range(0.0..0.1)
            } else {
                out_s + back_s + rng.random_range(opts.pause_s.0..opts.pause_s.1)
            };
    }
    let scripts = hand_scripts(&punches, guard, opts.guard == UserGuard::Chin)?;
    Ok(BoxPlan { punches, scripts, guard_aims_rig: aims, user_guard_rig: guard })
}

/// How old what the [`SeeingUser`] aims from is when its punch leaves the guard: the picture's
/// age at the display (about 15-40 ms measured, docs/view.md) plus a person's visuomotor delay, the
/// time from a target's move to the hand's path changing in reaching experiments (about
/// 0.1-0.15 s). A punch is aimed where the part was seen that long before it starts and is not
/// corrected on the way (a punch's way out is 0.07-0.3 s, about that delay).
pub const USER_SEEING_DELAY_S: f64 = 0.15;

/// The scripted boxer in closed loop, as a person at the rig boxes: the punches of a [`BoxPlan`]
/// (when, which hand, kind, speed, feint, scatter), each aimed when it starts at the part where
/// the user saw it [`USER_SEEING_DELAY_S`] earlier, not at where it stood in its guard. Its
/// driver tells it what is seen after every world step ([`SeeingUser::see`]) and asks before
/// every rig tick for a hand to launch ([`SeeingUser::due`]). The virtual human steps back,
/// slips and leans; a user aiming at its guard punches the air (docs/boxing.md 5.1).
#[derive(Clone, Debug)]
pub struct SeeingUser {
    /// The punches as thrown: `target_rig_m` is the aim actually taken once launched.
    pub punches: Vec<Punch>,
    guard_aims: [DVec3; 6],
    /// The user's guard, where the hands wait between punches.
    guard: [DVec3; 2],
    next: usize,
    /// What was seen (script time, aim points), oldest first; trimmed to what a launch can need.
    seen: std::collections::VecDeque<(f64, [DVec3; 6])>,
    pub delay_s: f64,
}

impl SeeingUser {
    pub fn new(plan: &BoxPlan) -> SeeingUser {
        SeeingUser {
            punches: plan.punches.clone(),
            guard_aims: plan.guard_aims_rig,
            guard: plan.user_guard_rig,
            next: 0,
            seen: std::collections::VecDeque::with_capacity(128),
            delay_s: USER_SEEING_DELAY_S,
        }
    }

    /// The hands' scripts before any punch: both rise from home into the guard and hold it
    /// (launches replace them).
    pub fn holding_scripts(&self) -> [Script; 2] {
        self.guard.map(|g| {
            Script::from_segments(vec![guard_up(g), Segment::Hold { at_m: g.to_array(), for_s: 1e6 }], false)
        })
    }

    /// The virtual human's aim points as seen at script time `t_s` (rig frame, [`aim_points_now`]).
    pub fn see(&mut self, t_s: f64, aims: [DVec3; 6]) {
        self.seen.push_back((t_s, aims));
        // Keep the newest entry at or before the oldest time a launch can still ask for.
        while self.seen.len() > 2 && self.seen[1].0 <= t_s - self.delay_s - 0.05 {
            self.seen.pop_front();
        }
    }

    /// The aim points as seen at `t_s` (the newest seen at or before it; the guard before anything
    /// was seen).
    fn seen_at(&self, t_s: f64) -> [DVec3; 6] {
        self.seen.iter().rev().find(|(t, _)| *t <= t_s).map_or(self.guard_aims, |(_, a)| *a)
    }

    /// Before a rig tick at script time `now_s` of `period_s`: the next punch starting before the
    /// tick after it, if any, as (its index, its hand, the hand's script from now: a hold until
    /// the punch starts, its way out to the part where it was seen, the way back, the guard).
    /// Call again until `None` (two punches may start within one tick).
    pub fn due(&mut self, now_s: f64, period_s: f64) -> anyhow::Result<Option<(usize, usize, Script)>> {
        let Some(p) = self.punches.get(self.next).copied() else { return Ok(None) };
        // The hand leaves its guard `dip_s` before the fist starts out.
        if p.start_s - p.dip_s >= now_s + period_s {
            return Ok(None);
        }
        let i = self.next;
        self.next += 1;
        let a = aim_index(p.aim);
        let scatter = p.target_rig_m - self.guard_aims[a];
        let target = self.seen_at(p.start_s - self.delay_s)[a] + scatter;
        self.punches[i].target_rig_m = target;
        let h = p.hand;
        let mut segs = Vec::with_capacity(5);
        let wait = p.start_s - p.dip_s - now_s;
        if wait > 0.0 {
            segs.push(Segment::Hold { at_m: self.guard[h].to_array(), for_s: wait });
        }
        segs.extend(punch_segments(&p, self.guard[h], target)?);
        segs.push(Segment::Hold { at_m: self.guard[h].to_array(), for_s: 1e6 });
        Ok(Some((i, h, Script::from_segments(segs, false))))
    }
}

/// The start of every box script: the hand rises from where it starts (the rig's home point,
/// where the grips rest) into the user's `guard` in [`USER_GUARD_UP_S`].
fn guard_up(guard: DVec3) -> Segment {
    Segment::Reach { to_m: guard.to_array(), duration_s: USER_GUARD_UP_S }
}

/// A punch from the guard: the level lowered first if it goes to the body, its way out from
/// there to `target` (rig frame) along its kind's path, and its way back to `guard`.
fn punch_segments(p: &Punch, guard: DVec3, target: DVec3) -> anyhow::Result<Vec<Segment>> {
    let samples = out_samples(p.kind, p.hand, p.from_rig_m, target, p.path_end, p.out_s);
    let mut segs = Vec::with_capacity(3);
    if p.dip_s > 0.0 {
        segs.push(Segment::Reach { to_m: p.from_rig_m.to_array(), duration_s: p.dip_s });
    }
    segs.push(Segment::recorded("box script punch", samples)?);
    segs.push(Segment::Reach { to_m: guard.to_array(), duration_s: p.back_s });
    Ok(segs)
}

/// The two hands' scripts for `punches` (sorted by start): each hand rises into its guard (if
/// `rise`), holds it until its next punch, follows the punch's path out, and comes back in a
/// minimum-jerk reach.
fn hand_scripts(punches: &[Punch], guard: [DVec3; 2], rise: bool) -> anyhow::Result<[Script; 2]> {
    let mut segs: [Vec<Segment>; 2] = guard.map(|g| if rise { vec![guard_up(g)] } else { Vec::new() });
    let mut free_at = [if rise { USER_GUARD_UP_S } else { 0.0 }; 2];
    let hold = |at: DVec3, for_s: f64| Segment::Hold { at_m: at.to_array(), for_s };
    for p in punches {
        let h = p.hand;
        let wait = p.start_s - p.dip_s - free_at[h];
        anyhow::ensure!(wait >= -1e-9, "punches of one hand overlap at {:.3} s", p.start_s);
        if wait > 0.0 {
            segs[h].push(hold(guard[h], wait));
        }
        segs[h].extend(punch_segments(p, guard[h], p.target_rig_m)?);
        free_at[h] = p.end_s();
    }
    Ok([0, 1].map(|h| {
        let mut s = std::mem::take(&mut segs[h]);
        s.push(hold(guard[h], 1e6));
        Script::from_segments(s, false)
    }))
}

/// The `box` script's two hands (see [`box_plan`] and [`PlanOptions::default`]); `aim`, when
/// given, aims every punch there and throws no feints.
pub fn boxing_scripts(
    rig: &spidar_rt::Rig,
    params: &BoxerParams,
    seed: u64,
    punches: usize,
    aim: Option<Aim>,
) -> anyhow::Result<[Script; 2]> {
    let mut opts = PlanOptions { punches, ..Default::default() };
    if let Some(a) = aim {
        opts.aims = vec![a];
        opts.feint_share = 0.0;
    }
    Ok(box_plan(rig, params, seed, &opts)?.scripts)
}

/// Where the crowd scene's front row stands, rig frame, left to right: the chest surface of each
/// character keeping a spot (configs/scene-crowd.ron's `stations`), at 1.15 m above the floor.
pub fn crowd_targets_rig(rig: &spidar_rt::Rig) -> anyhow::Result<Vec<DVec3>> {
    use spidar_sim::character::ai::Goal;
    let crowd = spidar_sim::character::scene::builtin_crowd()?;
    let mut t: Vec<DVec3> = crowd
        .chars
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c.goal, Goal::Station { .. }))
        .map(|(i, _)| {
            let b = crowd.body_space(i);
            // The front of the trunk (its capsules' radius ahead of the centre line), chest high.
            let front = b.r_m + b.heading.e_zc * 0.13;
            rig.rig_to_world.point_to_rig(DVec3::new(front.x, 1.1, front.z))
        })
        .collect();
    t.sort_by(|a, b| a.x.total_cmp(&b.x));
    if t.is_empty() {
        anyhow::bail!("the crowd scene has no front row (stations) for the crowd script to reach");
    }
    Ok(t)
}

/// The scripted user of the crowd scene (`--script crowd`, its default): reaches into the front
/// row, each hand to the character in front of it, in a cycle of 10 s: a push with the right hand,
/// an off-centre push with the left (it turns), a shove with the right that its feet cannot catch
/// (it falls, gets up and steps back to its spot while the cycle goes on), another push with the
/// left. Depths and timing vary a little with the seed.
pub fn crowd_scripts(rig: &spidar_rt::Rig, seed: u64) -> anyhow::Result<[spidar_device::sim::Script; 2]> {
    use rand::{Rng, SeedableRng};
    use spidar_device::sim::{Script, Segment};
    let targets = crowd_targets_rig(rig)?;
    let (left, right) = (targets[0], targets[targets.len() - 1]);
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0xC0D5);
    let mut segs: [Vec<Segment>; 2] = [Vec::new(), Vec::new()];
    let mut clock = [0.0f64; 2];
    let hold = |at: DVec3, for_s: f64| Segment::Hold { at_m: at.to_array(), for_s };
    // One move of hand `h` starting at `start_s`: to `near` (just short of the chest) in 0.5 s,
    // then through to `to` in `push_s` (the push itself), then back home in 0.6 s.
    let mut go = |h: usize, start_s: f64, near: DVec3, to: DVec3, push_s: f64| {
        if start_s > clock[h] {
            segs[h].push(hold(home[h], start_s - clock[h]));
        }
        segs[h].push(Segment::Reach { to_m: near.to_array(), duration_s: 0.5 });
        segs[h].push(Segment::Reach { to_m: to.to_array(), duration_s: push_s });
        segs[h].push(Segment::Reach { to_m: home[h].to_array(), duration_s: 0.6 });
        clock[h] = start_s.max(clock[h]) + 1.1 + push_s;
    };
    // The front is -z in the rig frame: "into" a character is toward -z.
    let into = |t: DVec3, depth: f64, side: f64| t + DVec3::new(side, 0.0, -depth);
    for cycle in 0..60 {
        let t0 = 0.5 + cycle as f64 * 10.0;
        let j = |r: &mut rand_pcg::Pcg64Mcg| r.random_range(-0.2f64..0.2);
        let d = |r: &mut rand_pcg::Pcg64Mcg, lo: f64, hi: f64| -> f64 { r.random_range(lo..hi) };
        // A push: the hand presses a few centimetres in and comes back.
        let (a, b) = (d(&mut rng, 0.03, 0.05), j(&mut rng).abs());
        go(1, t0 + b, into(right, -0.05, 0.0), into(right, a, 0.0), 0.4);
        // Off the centre line: it turns.
        let (a, b) = (d(&mut rng, 0.04, 0.06), j(&mut rng));
        go(0, t0 + 2.5 + b, into(left, -0.05, -0.1), into(left, a, -0.1), 0.4);
        // The shove: at the shoulders, following through half a metre.
        let (a, b) = (d(&mut rng, 0.35, 0.45), j(&mut rng));
        let up = DVec3::ZERO;
        go(1, t0 + 5.0 + b, into(right, -0.05, 0.0) + up, into(right, a, 0.0) + up, 0.5);
        let (a, b) = (d(&mut rng, 0.03, 0.05), j(&mut rng));
        go(0, t0 + 7.5 + b, into(left, -0.05, 0.0), into(left, a, 0.0), 0.4);
    }
    Ok([0, 1].map(|h| {
        let mut s = std::mem::take(&mut segs[h]);
        s.push(hold(home[h], 1e6));
        Script::from_segments(s, false)
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn last_out_point(s: &Script) -> DVec3 {
        let rec = s.segments.iter().find_map(|g| match g {
            Segment::Recorded(r) => Some(r),
            _ => None,
        });
        rec.expect("a punch's way out").samples().last().unwrap().pos_m
    }

    /// The closed-loop user aims each punch, when it starts, at the part where it saw it
    /// `delay_s` before (here a body drifting away at 0.2 m/s), keeps the plan's scatter, and
    /// starts it on time: not a tick early, never late.
    #[test]
    fn a_seeing_user_aims_where_it_saw_the_part_its_delay_before_the_punch() {
        let rig = spidar_rt::Rig::default_rig();
        let opts = PlanOptions { punches: 6, feint_share: 0.0, combo_share: 0.0, ..Default::default() };
        let plan = box_plan(&rig, &BoxerParams::default(), 3, &opts).unwrap();
        let mut u = SeeingUser::new(&plan);
        let drift = |t: f64| DVec3::new(0.0, 0.0, -0.2 * t);
        let seen_at = |t: f64| plan.guard_aims_rig.map(|a| a + drift(t));
        let period = 0.001;
        let mut launched = Vec::new();
        for k in 0..20_000 {
            let now = k as f64 * period;
            while let Some((i, hand, script)) = u.due(now, period).unwrap() {
                launched.push((i, now, hand, script));
            }
            // The world sees every third tick, after the tick (as `Bout::tick`).
            if k % 3 == 2 {
                u.see(now + period, seen_at(now + period));
            }
        }
        assert_eq!(launched.len(), plan.punches.len(), "every punch is launched once");
        for (i, now, hand, script) in launched {
            let p = &plan.punches[i];
            assert_eq!(hand, p.hand);
            // Launched when the hand leaves its guard: the level's dip before a body punch.
            let leaves = p.start_s - p.dip_s;
            assert!(leaves >= now - 1e-12 && leaves < now + period, "punch {i} launched at {now}");
            // The newest sight at or before start - delay: world steps every 3 ms.
            // (Nothing seen yet, for a punch in the first 0.15 s: the guard.)
            let want_t = (((p.start_s - u.delay_s) / 0.003).floor() * 0.003).max(0.0);
            let k = aim_index(p.aim);
            let scatter = p.target_rig_m - plan.guard_aims_rig[k];
            let want = plan.guard_aims_rig[k] + drift(want_t) + scatter;
            let got = u.punches[i].target_rig_m;
            // Within one world step's drift (a sight exactly at the boundary may round either way).
            assert!((got - want).length() < 0.2 * 0.0031, "punch {i}: {got:?} vs {want:?}");
            // It goes there: the way out ends at the aim (no feints here), from a hold until its start.
            assert!((last_out_point(&script) - want).length() < 1e-9);
            match script.segments[0] {
                Segment::Hold { for_s, .. } => assert!((for_s - (leaves - now)).abs() < 1e-12),
                _ => assert!(leaves - now <= 0.0),
            }
        }
    }

    /// The box script's user boxes from a guard at the chin: both hands rise into it first, every
    /// punch at the head leaves from it, every punch at the body from it lowered by the level's
    /// dip (reached in the dip's time just before the punch), every way back ends in it, and a hook
    /// ends its swing level with its target.
    #[test]
    fn the_scripted_user_punches_from_a_guard_at_the_chin_and_dips_to_the_body() {
        let rig = spidar_rt::Rig::default_rig();
        let opts = PlanOptions { punches: 60, ..Default::default() };
        let plan = box_plan(&rig, &BoxerParams::default(), 7, &opts).unwrap();
        let head = plan.guard_aims_rig[aim_index(Aim::Head)];
        for h in 0..2 {
            let g = plan.user_guard_rig[h];
            assert!((g.y - (head.y - USER_GUARD_BELOW_HEAD_M)).abs() < 1e-12, "the guard is at the chin");
            assert!(g.y > rig.hands[h].home_m.y + 0.05, "above the grips' home: {g:?}");
            assert_eq!((g.x, g.z), (rig.hands[h].home_m.x, rig.hands[h].home_m.z));
            // The script's first move raises the hand into the guard, before any punch.
            match plan.scripts[h].segments[0] {
                Segment::Reach { to_m, duration_s } => {
                    assert_eq!(DVec3::from(to_m), g);
                    assert_eq!(duration_s, USER_GUARD_UP_S);
                }
                ref s => panic!("hand {h} starts with {s:?}"),
            }
        }
        assert!(plan.punches[0].start_s - plan.punches[0].dip_s > USER_GUARD_UP_S);
        let (mut body, mut head_n, mut hooks) = (0, 0, 0);
        for p in &plan.punches {
            let g = plan.user_guard_rig[p.hand];
            if p.aim.is_body() {
                body += 1;
                assert_eq!(p.from_rig_m, g - DVec3::Y * USER_BODY_DIP_M);
                assert_eq!(p.dip_s, USER_BODY_DIP_S);
            } else {
                head_n += 1;
                assert_eq!((p.from_rig_m, p.dip_s), (g, 0.0));
            }
            let segs = punch_segments(p, g, p.target_rig_m).unwrap();
            let rec = segs.iter().find_map(|s| match s {
                Segment::Recorded(r) => Some(r.samples()),
                _ => None,
            });
            let out = rec.expect("a way out");
            assert!((out[0].pos_m - p.from_rig_m).length() < 1e-12, "the way out starts where the dip ends");
            if p.dip_s > 0.0 {
                assert!(
                    matches!(segs[0], Segment::Reach { to_m, duration_s } if DVec3::from(to_m) == p.from_rig_m && duration_s == p.dip_s)
                );
            }
            assert!(
                matches!(segs.last(), Some(Segment::Reach { to_m, .. }) if DVec3::from(*to_m) == g),
                "back to the guard"
            );
            if p.kind == PunchKind::Hook && !p.feint {
                hooks += 1;
                // The last fifth of its way comes in within 1 cm of the target's height.
                let tail = &out[out.len() * 4 / 5..];
                assert!(
                    tail.iter().all(|s| (s.pos_m.y - p.target_rig_m.y).abs() < 0.01),
                    "a hook ends level"
                );
            }
        }
        assert!(body > 5 && head_n > 5 && hooks > 5, "{body} body, {head_n} head punches, {hooks} hooks");
    }

    /// Before anything is seen, a punch goes to the guard's aim point (the open-loop plan's).
    #[test]
    fn a_user_that_saw_nothing_aims_at_the_guard() {
        let rig = spidar_rt::Rig::default_rig();
        let opts = PlanOptions { punches: 1, feint_share: 0.0, combo_share: 0.0, ..Default::default() };
        let plan = box_plan(&rig, &BoxerParams::default(), 5, &opts).unwrap();
        let mut u = SeeingUser::new(&plan);
        let (i, _, _) = u.due(plan.punches[0].start_s, 0.001).unwrap().unwrap();
        assert!((u.punches[i].target_rig_m - plan.punches[0].target_rig_m).length() < 1e-12);
        assert!(u.due(1e3, 0.001).unwrap().is_none(), "one punch, launched once");
    }
}
