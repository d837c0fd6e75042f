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
