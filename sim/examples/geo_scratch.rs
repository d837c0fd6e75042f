use glam::DVec3;
use spidar_sim::boxer::{min_jerk, BoxerParams, BoxingWorld, HandTarget};
fn main() {
    let mk = || {
        let mut w = BoxingWorld::new(BoxerParams { active: false, ..Default::default() }).unwrap();
        for _ in 0..300 {
            w.step(&[None, None]);
        }
        w
    };
    let w = mk();
    println!(
        "vh head {:.3?} chest {:.3?} hands {:.3?} {:.3?}",
        w.com(w.vh.head),
        w.com(w.vh.chest),
        w.com(w.vh.hand[0]),
        w.com(w.vh.hand[1])
    );
    println!("av hands {:.3?} {:.3?}", w.com(w.avatar.hand[0]), w.com(w.avatar.hand[1]));
    for (name, part) in [("head", w.vh.head), ("chest", w.vh.chest)] {
        for hand in 0..2 {
            for extra in [0.0, 0.05, 0.10] {
                let mut w = mk();
                let from = w.com(w.avatar.hand[hand]) - w.params.user_offset_m;
                let aim = w.com(part) + DVec3::new(0.0, 0.0, 0.0) - w.params.user_offset_m
                    + DVec3::new(0.0, 0.0, -extra);
                let guard = [0, 1].map(|h| w.com(w.avatar.hand[h]));
                let (mut hit_head, mut hit_chest, mut maxf) = (0, 0, 0.0f64);
                let mut closest = f64::INFINITY;
                for k in 0..300 {
                    let t = k as f64 * 0.003;
                    let tau = (t / 0.3).min(1.0);
                    let p = from + (aim - from) * min_jerk(tau);
                    let mut tg =
                        [0, 1].map(|h| Some(HandTarget { pos_m: guard[h], vel_m_per_s: DVec3::ZERO }));
                    tg[hand] =
                        Some(HandTarget { pos_m: p + w.params.user_offset_m, vel_m_per_s: DVec3::ZERO });
                    let r = w.step(&tg);
                    hit_head += r.head_hit[hand] as i32;
                    hit_chest += r.chest_hit[hand] as i32;
                    maxf = maxf.max(r.hand_contacts[hand].force_n.length());
                    closest = closest.min((w.com(w.avatar.hand[hand]) - w.com(part)).length());
                }
                println!("{name} hand {hand} extra {extra}: head steps {hit_head} chest steps {hit_chest} max force {maxf:.1} closest fist-centre {closest:.3} final fist {:.3?} user {:.3?}", w.com(w.avatar.hand[hand]), aim);
            }
        }
    }
}
