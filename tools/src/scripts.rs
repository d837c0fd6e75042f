//! The simulated user's boxing scripts (`--script box`): jabs and hooks aimed at where the
//! boxing scene's virtual human stands in its guard, mapped into the rig frame. They belong to
//! the rig side (they drive the simulated rig's hands), but are computed from a passive copy of
//! the world the scene runs.

use glam::DVec3;
use spidar_sim::boxer::{BoxerParams, BoxingWorld};

/// Targets of the scripted boxer, rig frame: where the virtual human's head, chest, left hand and
/// right hand are in its guard, mapped back through `user_offset_m` and the rig's transform.
pub fn punch_targets_rig(rig: &spidar_rt::Rig, params: &BoxerParams) -> anyhow::Result<[DVec3; 4]> {
    // A passive copy: an active one might start a spontaneous attack while it settles, and the
    // targets would be where its parts were mid-punch.
    let mut w = BoxingWorld::new(BoxerParams { active: false, ..params.clone() })?;
    // Settle into the guard first (the default pose is not yet balanced under gravity).
    for _ in 0..200 {
        w.begin_step();
        w.step(&[None, None]);
    }
    w.begin_step();
    let vh = w.vh;
    // Aim at the front surface: a few cm in front of the centres (the VH faces +z).
    let front = |b: usize, dz: f64| w.com(b) + DVec3::new(0.0, 0.0, dz);
    let to_rig = |p: DVec3| rig.rig_to_world.point_to_rig(p - params.user_offset_m);
    Ok([
        to_rig(front(vh.head, 0.06)),
        to_rig(front(vh.chest, 0.10)),
        to_rig(front(vh.hand[0], 0.03)),
        to_rig(front(vh.hand[1], 0.03)),
    ])
}

/// The scripted user of the boxing scene (`--script box`): jabs and hooks at the virtual human's
/// head, chest and hands, one hand at a time, with random pauses; seeded, so a run repeats.
/// `target` limits every punch to one of the four targets (head, chest, left hand, right hand).
pub fn boxing_scripts(
    rig: &spidar_rt::Rig,
    params: &BoxerParams,
    seed: u64,
    punches: usize,
    target: Option<usize>,
) -> anyhow::Result<[spidar_device::sim::Script; 2]> {
    use rand::{Rng, SeedableRng};
    use spidar_device::sim::{Script, Segment};
    let targets = punch_targets_rig(rig, params)?;
    let home = [rig.hands[0].home_m, rig.hands[1].home_m];
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0xB0C5);
    let mut segs: [Vec<Segment>; 2] = [Vec::new(), Vec::new()];
    let hold = |at: DVec3, for_s: f64| Segment::Hold { at_m: at.to_array(), for_s };
    for _ in 0..punches {
        let hand = rng.random_range(0..2usize);
        let t = target.unwrap_or_else(|| rng.random_range(0..4usize));
        let mut to = targets[t];
        // Aim a little through the target, as a boxer does.
        to.z -= 0.05;
        let hook = rng.random::<f64>() < 0.3;
        let out_s = rng.random_range(0.2..0.32);
        let pause = rng.random_range(0.5..1.2);
        let mut dur = 0.0;
        if hook {
            // Swing out to the side first, then in.
            let side = if hand == 0 { -0.2 } else { 0.2 };
            let wind = home[hand] + DVec3::new(side, 0.05, -0.1);
            segs[hand].push(Segment::Reach { to_m: wind.to_array(), duration_s: 0.2 });
            segs[hand].push(Segment::Reach { to_m: to.to_array(), duration_s: out_s });
            segs[hand].push(Segment::Reach { to_m: home[hand].to_array(), duration_s: 0.35 });
            dur += 0.2 + out_s + 0.35;
        } else {
            segs[hand].push(Segment::Jab { to_m: to.to_array(), out_s, back_s: 0.35 });
            dur += out_s + 0.35;
        }
        segs[hand].push(hold(home[hand], pause));
        segs[1 - hand].push(hold(home[1 - hand], dur + pause));
    }
    Ok([0, 1].map(|h| {
        let mut s = std::mem::take(&mut segs[h]);
        s.push(hold(home[h], 1e6));
        Script::from_segments(s, false)
    }))
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
