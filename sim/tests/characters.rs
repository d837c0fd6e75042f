//! Tests of the keyframe characters (seed 002): balance, pushes, falls and standing up on the crowd
//! stepper and in the general engine; the keyframe set's interpolation; determinism.

use glam::DVec3;
use spidar_sim::character::ai::Goal;
use spidar_sim::character::controller::Policy;
use spidar_sim::character::crowd::{Crowd, CrowdBody, CrowdWorld};
use spidar_sim::character::keyframe::KeyframeSet;
use spidar_sim::character::CharacterParams;
use spidar_sim::desc::{parse_body, ContactDesc, Gain};

const BODY: &str = include_str!("../../configs/body-character.ron");

fn contact() -> ContactDesc {
    ContactDesc { stiffness: Gain::Abs(4e5), damping: Gain::Abs(4000.0), friction: 0.0, slip_m_per_s: 0.01 }
}

fn crowd() -> Crowd {
    let body = CrowdBody::from_file(&parse_body(BODY, "body-character.ron").unwrap(), "body").unwrap();
    let world = CrowdWorld::new(0.003, DVec3::new(0.0, -9.81, 0.0), &contact(), body.mass_kg);
    let mut c = Crowd::new(body, world, CharacterParams::default(), KeyframeSet::builtin());
    c.statics.push((spidar_sim::collide::Shape::Plane, spidar_sim::collide::Pose::IDENTITY));
    c
}

fn steps(c: &mut Crowd, seconds: f64) {
    for _ in 0..(seconds / 0.003).round() as usize {
        c.step();
    }
}

#[test]
fn explore() {
    for (imp, h) in [(20.0, 0.3), (40.0, 0.3), (60.0, 0.3), (90.0, 0.6)] {
        let mut c = crowd();
        c.add(0.0, 0.0, 0.0, Goal::Stand);
        steps(&mut c, 1.0);
        let p = c.bodies[0].pos_m;
        c.add_impulse_at(0, p + DVec3::new(0.0, h, 0.0), DVec3::new(0.0, 0.0, imp));
        let mut last = Policy::Balance;
        for k in 0..5000 {
            c.step();
            let ch = &c.chars[0];
            if ch.control.policy != last || k % 500 == 0 {
                let b = c.body_space(0);
                println!("imp {imp} t {:.2} {:?} tx {:.2} tz {:.2} r {:.3?} v {:.2?} n {:.0} f {:.0?}", k as f64 * 0.003, ch.control.policy, b.theta_x, b.theta_z, b.r_m, b.r_dot_m_per_s, ch.ground.normal_n, ch.drive.force_n);
                last = ch.control.policy;
            }
        }
    }
}
