//! The boxer's parameters from RON (`configs/boxer.ron`), validated once into `BoxerParams`.
//!
//! Must never: accept a value that makes the world unstable or meaningless without saying which
//! field, where, and what range it needs.

use std::path::Path;

use glam::DVec3;
use serde::Deserialize;
use spidar_config::{self as config, At, Bound, Checker};

use super::mind::MindParams;
use super::perceive::{Skill, SkillLevel};
use super::BoxerParams;
use crate::SimError;

/// The built-in boxer file.
pub const BOXER_RON: &str = include_str!("../../../configs/boxer.ron");

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxerFile {
    pub version: u32,
    pub user_offset_m: (f64, f64, f64),
    pub coupling_k_n_per_m: f64,
    pub coupling_d_n_s_per_m: f64,
    pub coupling_max_n: f64,
    pub avatar_joint_scale: f64,
    pub damage_attenuation: f64,
    pub reach_arm_k_n_per_m: f64,
    pub reach_arm_d_n_s_per_m: f64,
    pub reach_body_k_n_per_m: f64,
    pub reach_body_d_n_s_per_m: f64,
    pub mind: MindFile,
    pub skill: String,
    pub skills: SkillsFile,
}

/// The levels, each once (an unknown level is an unknown field).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkillsFile {
    pub novice: SkillFile,
    pub amateur: SkillFile,
    pub pro: SkillFile,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkillFile {
    pub delay_s: f64,
    pub periphery_delay_s: f64,
    pub central_deg: f64,
    pub fov_deg: f64,
    pub gaze_deg_per_s: f64,
    pub noise_m: f64,
    pub speed_noise: f64,
    pub periphery_noise: f64,
    pub block_speed_m_per_s: f64,
    pub counter_chance: f64,
    pub counter_within_s: f64,
    pub avoid_chance: f64,
    pub refractory_s: f64,
    pub feint_recovery_s: f64,
    pub attention_dwell_s: f64,
    pub accel_seen: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MindFile {
    pub trigger_m_per_s: f64,
    pub approach_m_per_s: f64,
    pub horizon_s: f64,
    pub middle_grace_s: f64,
    pub predict_every_s: f64,
    pub decel_m_per_s2: f64,
    pub avoid_extend: f64,
    pub avoid_clearance_m: f64,
    pub avoid_time_fraction: f64,
    pub avoid_duck_cost: f64,
    pub avoid_lead_s: f64,
    pub lean_m: f64,
    pub block_time_fraction: f64,
    pub attack_per_step: f64,
    pub attack_min_s: f64,
    pub attack_max_s: f64,
    pub attack_scatter_m: f64,
    pub hold_s: f64,
    pub return_s: f64,
    pub fist_near_m: f64,
    pub stance_step_max_m: f64,
    pub stance_return_m_per_s: f64,
    pub brace_k_n_per_m: f64,
    pub brace_d_n_s_per_m: f64,
}

/// Why the boxer's numbers are bounded where they are (a reason per kind of number).
const SPRING: &str =
    "an explicit spring stepped every 3 ms is stable only while k dt^2 / m stays well under 4 on the \
                      part it moves (0.6 kg for a hand)";
const DAMPER: &str =
    "an explicit damper stepped every 3 ms is stable only while d dt / m stays under 2 on the part it moves";
const FRACTION: &str = "it is a share of a whole";
const SPEED: &str = "no hand or body moves faster than 20 m/s";
const TIME: &str = "the mind's decisions and motions span at most a few seconds";
const REACH: &str = "a boxer's reach and steps stay within a couple of metres";

/// Every number of a boxer file with its bound: (field path, value, bound).
fn boxer_numbers(f: &BoxerFile) -> [(&'static str, f64, Bound); 33] {
    let m = &f.mind;
    let b = |lo: f64, hi: f64, unit: &'static str, why: &'static str| Bound::hard("", lo, hi, unit, why);
    [
        ("coupling_k_n_per_m", f.coupling_k_n_per_m, b(1.0, 20_000.0, "N/m", SPRING)),
        ("coupling_d_n_s_per_m", f.coupling_d_n_s_per_m, b(0.0, 300.0, "N s/m", DAMPER)),
        (
            "coupling_max_n",
            f.coupling_max_n,
            b(1.0, 10_000.0, "N", "the coupling carries a punch, not a crash"),
        ),
        ("avatar_joint_scale", f.avatar_joint_scale, b(0.01, 1.0, "", FRACTION)),
        ("damage_attenuation", f.damage_attenuation, b(0.0, 1.0, "", FRACTION)),
        ("reach_arm_k_n_per_m", f.reach_arm_k_n_per_m, b(0.0, 60_000.0, "N/m", SPRING)),
        ("reach_arm_d_n_s_per_m", f.reach_arm_d_n_s_per_m, b(0.0, 400.0, "N s/m", DAMPER)),
        ("reach_body_k_n_per_m", f.reach_body_k_n_per_m, b(0.0, 400_000.0, "N/m", SPRING)),
        ("reach_body_d_n_s_per_m", f.reach_body_d_n_s_per_m, b(0.0, 2_500.0, "N s/m", DAMPER)),
        ("mind.trigger_m_per_s", m.trigger_m_per_s, b(0.0, 20.0, "m/s", SPEED)),
        ("mind.approach_m_per_s", m.approach_m_per_s, b(0.0, 20.0, "m/s", SPEED)),
        (
            "mind.horizon_s",
            m.horizon_s,
            b(0.003, 2.0, "s", "a prediction looks at least one step and at most 2 s ahead"),
        ),
        ("mind.middle_grace_s", m.middle_grace_s, b(0.0, 2.0, "s", TIME)),
        ("mind.predict_every_s", m.predict_every_s, b(0.0, 2.0, "s", TIME)),
        ("mind.decel_m_per_s2", m.decel_m_per_s2, b(0.0, 1000.0, "m/s^2", "a fist stops within its reach")),
        (
            "mind.avoid_extend",
            m.avoid_extend,
            b(1.0, 5.0, "", "an avoidance moves at least as far as the threat"),
        ),
        ("mind.avoid_clearance_m", m.avoid_clearance_m, b(0.0, 1.0, "m", REACH)),
        ("mind.avoid_time_fraction", m.avoid_time_fraction, b(0.1, 1.0, "", FRACTION)),
        ("mind.avoid_duck_cost", m.avoid_duck_cost, b(0.1, 100.0, "", "a cost compared with leaning aside")),
        ("mind.avoid_lead_s", m.avoid_lead_s, b(0.0, 2.0, "s", TIME)),
        ("mind.lean_m", m.lean_m, b(0.0, 0.5, "m", "a body leans by at most half a metre")),
        ("mind.block_time_fraction", m.block_time_fraction, b(0.1, 1.0, "", FRACTION)),
        ("mind.attack_per_step", m.attack_per_step, b(0.0, 1.0, "", "a probability")),
        ("mind.attack_min_s", m.attack_min_s, b(0.05, 5.0, "s", TIME)),
        ("mind.attack_max_s", m.attack_max_s, b(0.05, 5.0, "s", TIME)),
        (
            "mind.attack_scatter_m",
            m.attack_scatter_m,
            b(0.0, 0.3, "m", "a scatter around the target, not a miss"),
        ),
        ("mind.hold_s", m.hold_s, b(0.0, 5.0, "s", TIME)),
        ("mind.return_s", m.return_s, b(0.05, 5.0, "s", TIME)),
        ("mind.fist_near_m", m.fist_near_m, b(0.0, 2.0, "m", REACH)),
        ("mind.stance_step_max_m", m.stance_step_max_m, b(0.0, 0.5, "m", REACH)),
        ("mind.stance_return_m_per_s", m.stance_return_m_per_s, b(0.01, 5.0, "m/s", SPEED)),
        ("mind.brace_k_n_per_m", m.brace_k_n_per_m, b(0.0, 100_000.0, "N/m", SPRING)),
        ("mind.brace_d_n_s_per_m", m.brace_d_n_s_per_m, b(0.0, 5_000.0, "N s/m", DAMPER)),
    ]
}

const DELAY: &str =
    "a delay is a time since something happened: never negative, and a person's is under a second";
const ANGLE: &str = "an angle around the eye: a full turn at most";

/// Every number of one skill level with its bound: (field, value, bound).
fn skill_numbers(s: &SkillFile) -> [(&'static str, f64, Bound); 16] {
    let b = |lo: f64, hi: f64, unit: &'static str, why: &'static str| Bound::hard("", lo, hi, unit, why);
    [
        ("delay_s", s.delay_s, b(0.0, 1.0, "s", DELAY)),
        ("periphery_delay_s", s.periphery_delay_s, b(0.0, 1.0, "s", DELAY)),
        ("central_deg", s.central_deg, b(0.0, 360.0, "deg", ANGLE)),
        ("fov_deg", s.fov_deg, b(0.0, 360.0, "deg", ANGLE)),
        ("gaze_deg_per_s", s.gaze_deg_per_s, b(1.0, 1.0e6, "deg/s", "the eyes turn, however slowly")),
        ("noise_m", s.noise_m, b(0.0, 0.5, "m", "an error of sight, not blindness")),
        ("speed_noise", s.speed_noise, b(0.0, 1.0, "", "a Weber fraction of the speed")),
        (
            "periphery_noise",
            s.periphery_noise,
            b(1.0, 20.0, "", "the periphery sees no better than the centre"),
        ),
        ("block_speed_m_per_s", s.block_speed_m_per_s, b(0.0, 20.0, "m/s", SPEED)),
        ("counter_chance", s.counter_chance, b(0.0, 1.0, "", "a probability")),
        ("counter_within_s", s.counter_within_s, b(0.0, 5.0, "s", TIME)),
        ("avoid_chance", s.avoid_chance, b(0.0, 1.0, "", "a probability")),
        ("refractory_s", s.refractory_s, b(0.0, 1.0, "s", DELAY)),
        ("feint_recovery_s", s.feint_recovery_s, b(0.0, 1.0, "s", DELAY)),
        ("attention_dwell_s", s.attention_dwell_s, b(0.0, 1.0, "s", DELAY)),
        ("accel_seen", s.accel_seen, b(0.0, 1.0, "", "a share of the acceleration there is")),
    ]
}

/// Checks the levels (each key appears once per level, in the file's order novice, amateur,
/// pro) and resolves them.
fn parse_skills(c: &Checker, f: &SkillsFile) -> Result<[Skill; 3], SimError> {
    let levels =
        [(SkillLevel::Novice, &f.novice), (SkillLevel::Amateur, &f.amateur), (SkillLevel::Pro, &f.pro)];
    let mut out = [Skill::perfect(SkillLevel::Amateur, 0.0); 3];
    for (k, (level, s)) in levels.into_iter().enumerate() {
        for (key, v, bound) in skill_numbers(s) {
            c.within(&At::new(format!("skills.{}.{key}", level.name()), key, k), v, &bound)?;
        }
        c.ensure(
            s.central_deg <= s.fov_deg,
            &At::new(format!("skills.{}.central_deg", level.name()), "central_deg", k),
            || {
                format!(
                    "{} deg: the central field lies inside the field of view ({} deg)",
                    s.central_deg, s.fov_deg
                )
            },
        )?;
        out[k] = Skill {
            level,
            delay_s: s.delay_s,
            periphery_delay_s: s.periphery_delay_s,
            central_deg: s.central_deg,
            fov_deg: s.fov_deg,
            gaze_deg_per_s: s.gaze_deg_per_s,
            noise_m: s.noise_m,
            speed_noise: s.speed_noise,
            periphery_noise: s.periphery_noise,
            block_speed_m_per_s: s.block_speed_m_per_s,
            counter_chance: s.counter_chance,
            counter_within_s: s.counter_within_s,
            avoid_chance: s.avoid_chance,
            refractory_s: s.refractory_s,
            feint_recovery_s: s.feint_recovery_s,
            attention_dwell_s: s.attention_dwell_s,
            accel_seen: s.accel_seen,
        };
    }
    Ok(out)
}

/// Parses and validates boxer text; `origin` names it in errors.
pub fn parse_boxer(text: &str, origin: &str) -> Result<BoxerParams, SimError> {
    let f: BoxerFile = config::parse_kind(text, origin, config::FileKind::Boxer)?;
    let c = Checker::new(text, origin);
    c.version(f.version, 7)?;
    let o = f.user_offset_m;
    c.finite_within(&At::key("user_offset_m"), &[o.0, o.1, o.2], f64::MAX, "m")?;
    for (field, v, bound) in boxer_numbers(&f) {
        let key = field.rsplit('.').next().unwrap_or(field);
        c.within(&At::new(field, key, 0), v, &bound)?;
    }
    let m = &f.mind;
    c.ensure(m.attack_max_s > m.attack_min_s, &At::new("mind.attack_max_s", "attack_max_s", 0), || {
        format!("{} s: must be more than attack_min_s ({} s)", m.attack_max_s, m.attack_min_s)
    })?;
    let skills = parse_skills(&c, &f.skills)?;
    let level = SkillLevel::parse(&f.skill).map_err(|e| c.error(&At::key("skill"), e))?;
    Ok(BoxerParams {
        user_offset_m: DVec3::new(o.0, o.1, o.2),
        coupling_k_n_per_m: f.coupling_k_n_per_m,
        coupling_d_n_s_per_m: f.coupling_d_n_s_per_m,
        coupling_max_n: f.coupling_max_n,
        avatar_joint_scale: f.avatar_joint_scale,
        damage_attenuation: f.damage_attenuation,
        reach_arm_k_n_per_m: f.reach_arm_k_n_per_m,
        reach_arm_d_n_s_per_m: f.reach_arm_d_n_s_per_m,
        reach_body_k_n_per_m: f.reach_body_k_n_per_m,
        reach_body_d_n_s_per_m: f.reach_body_d_n_s_per_m,
        mind: MindParams {
            trigger_m_per_s: m.trigger_m_per_s,
            approach_m_per_s: m.approach_m_per_s,
            horizon_s: m.horizon_s,
            middle_grace_s: m.middle_grace_s,
            predict_every_s: m.predict_every_s,
            decel_m_per_s2: m.decel_m_per_s2,
            avoid_extend: m.avoid_extend,
            avoid_clearance_m: m.avoid_clearance_m,
            avoid_time_fraction: m.avoid_time_fraction,
            avoid_duck_cost: m.avoid_duck_cost,
            avoid_lead_s: m.avoid_lead_s,
            lean_m: m.lean_m,
            block_time_fraction: m.block_time_fraction,
            attack_per_step: m.attack_per_step,
            attack_s: (m.attack_min_s, m.attack_max_s),
            attack_scatter_m: m.attack_scatter_m,
            hold_s: m.hold_s,
            return_s: m.return_s,
            fist_near_m: m.fist_near_m,
            stance_step_max_m: m.stance_step_max_m,
            stance_return_m_per_s: m.stance_return_m_per_s,
            brace_k_n_per_m: m.brace_k_n_per_m,
            brace_d_n_s_per_m: m.brace_d_n_s_per_m,
            skill: skills[level.index()],
        },
        skills,
        active: true,
        seed: 0,
    })
}

/// Loads a boxer file.
pub fn load_boxer(path: &Path) -> Result<BoxerParams, SimError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SimError::Io { path: path.display().to_string(), message: e.to_string() })?;
    parse_boxer(&text, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_boxer_file_is_the_default() {
        let p = parse_boxer(BOXER_RON, "configs/boxer.ron").unwrap();
        assert_eq!(p, BoxerParams::default());
        assert_eq!(p.user_offset_m, DVec3::new(0.0, 0.3, -0.3));
    }

    #[test]
    fn a_bad_value_names_the_file_line_and_field() {
        let text = BOXER_RON.replacen("reach_arm_k_n_per_m: 40000.0", "reach_arm_k_n_per_m: 900000.0", 1);
        let SimError::Config(e) = parse_boxer(&text, "b.ron").unwrap_err() else {
            panic!("not a config error")
        };
        assert_eq!(e.field, "reach_arm_k_n_per_m");
        assert_eq!(e.origin, "b.ron");
        assert!(e.line > 0 && text.lines().nth(e.line - 1).unwrap().contains("900000"));
        let text = BOXER_RON.replacen("attack_max_s: 0.6", "attack_max_s: 0.2", 1);
        let SimError::Config(e) = parse_boxer(&text, "b.ron").unwrap_err() else {
            panic!("not a config error")
        };
        assert_eq!(e.field, "mind.attack_max_s");
        assert!(e.message.contains("attack_min_s"));
        let text = BOXER_RON.replacen("hold_s:", "holding_s:", 1);
        assert!(parse_boxer(&text, "b.ron").is_err(), "unknown fields are refused");
    }

    /// Refuses `text` naming `field` on the line that holds `needle`; returns the message.
    fn refused(text: &str, field: &str, needle: &str) -> String {
        let SimError::Config(e) = parse_boxer(text, "b.ron").unwrap_err() else {
            panic!("not a config error")
        };
        assert_eq!((e.field.as_str(), e.origin.as_str()), (field, "b.ron"), "{e}");
        assert!(text.lines().nth(e.line - 1).unwrap().contains(needle), "line {}: {e}", e.line);
        e.to_string()
    }

    #[test]
    fn skill_levels_are_refused_by_file_line_and_field() {
        // An unknown level chosen.
        let text = BOXER_RON.replacen("skill: \"amateur\"", "skill: \"champion\"", 1);
        let e = refused(&text, "skill", "champion");
        assert!(e.contains("novice, amateur, pro"), "{e}");
        // A negative delay (the novice's, the first level).
        let text = BOXER_RON.replacen("delay_s: 0.22,", "delay_s: -0.22,", 1);
        refused(&text, "skills.novice.delay_s", "-0.22");
        // A field of view over a full turn (the novice's).
        let text = BOXER_RON.replacen("fov_deg: 180.0", "fov_deg: 400.0", 1);
        let e = refused(&text, "skills.novice.fov_deg", "400");
        assert!(e.contains("360"), "{e}");
        // An unknown level among the levels.
        let text = BOXER_RON.replacen("pro: (", "champion: (", 1);
        let SimError::Config(e) = parse_boxer(&text, "b.ron").unwrap_err() else {
            panic!("not a config error")
        };
        assert!(e.to_string().contains("champion") && e.line > 0, "{e}");
    }

    #[test]
    fn every_level_loads_and_the_default_is_the_amateur() {
        let p = parse_boxer(BOXER_RON, "configs/boxer.ron").unwrap();
        assert_eq!(p.skill(), SkillLevel::Amateur);
        for level in SkillLevel::ALL {
            let q = p.clone().with_skill(level);
            assert_eq!(q.skill(), level);
            assert!(q.mind.skill.delay_s >= 0.1, "{level}: a person's delay");
        }
    }
}
