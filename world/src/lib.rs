//! The world side of the rig-world link: the scenes that produce contact models for the rt-loop
//! at the simulation's rate (3 ms) and consume the hand samples it sends back.
//!
//! The built-in rig-check scene ([`walls`]) is the template the physics simulation follows: it
//! receives every `HandSample` (positions, velocities, and the impulses the rt-loop applied to
//! each proxy), steps, and sends one `ContactModel` stamped with the loop-clock time it is valid at.
//! The boxing scene ([`boxing`]) runs the reactive virtual human, the crowd scene ([`crowd`]) the
//! keyframe characters. Whatever hosts a scene steps it through a [`host::Stepper`]: the world
//! process ([`host::serve`], `spidar world`), a thread in the rig's process on the real clock, or
//! the loop's own thread interleaved with it on the virtual clock (both wired in
//! `spidar_runtime::session`).

pub mod boxing;
pub mod crowd;
pub mod decisions;
pub mod foxglove;
pub mod host;
pub mod look;
pub mod spar;
pub mod view;
pub mod walls;

use spidar_msg::{ContactModel, HandSample, RigInfo, RigStatus};

pub trait Scene: Send {
    fn name(&self) -> &str;
    /// Time between two steps.
    fn step_s(&self) -> f64;
    /// Advances the scene to loop-clock time `t_s`, given the samples received since the last
    /// step (oldest first), and returns the contact model valid at `t_s`.
    fn step(&mut self, t_s: f64, samples: &[HandSample]) -> ContactModel;
    /// A short live status for the status line.
    fn status(&self) -> String {
        String::new()
    }
    /// What the scene looks like to a viewer (called once, when a view starts). The default draws
    /// only what every scene has: the rig, the hands and the contact proxies.
    fn look(&self) -> look::Look {
        look::Look::default()
    }
    /// Writes the poses of what [`Scene::look`] described, after a step, at display rate. Runs on
    /// the stepping thread: it only copies numbers (no allocation, no locks). A crowd's drawn
    /// figures take longer: they are written only when [`look::Poses::figures_now`] says so.
    fn pose(&self, _out: &mut look::Poses<'_>) {}
    /// Copies what its characters' drawn figures depend on after a step (as many as `out` holds),
    /// for another thread to compute them with the look's [`look::LookCrowd::figures`]. Runs on
    /// the stepping thread: a copy. Scenes without a crowd copy nothing; a scene that wraps
    /// another hands this on with [`Scene::pose`] (the look it hands on promises the figures).
    fn figure_states(&self, _out: &mut [spidar_sim::character::drawn::FigureState]) {}
    /// What the scene's virtual human decided (recorded after every step); `None` for scenes
    /// without one. Runs on the stepping thread: it only copies numbers.
    fn decisions(&self) -> Option<decisions::Decisions> {
        None
    }
}

/// What a world step shows an [`Observer`].
pub struct StepView<'a> {
    /// Loop-clock time of the step.
    pub t_s: f64,
    pub scene: &'a dyn Scene,
    /// The hand samples the step consumed (oldest first).
    pub samples: &'a [HandSample],
    /// The contact model the step produced.
    pub model: &'a ContactModel,
    /// The rig's geometry and newest status, when a rig is connected and has sent them.
    pub rig_info: Option<&'a RigInfo>,
    pub rig_status: Option<&'a RigStatus>,
}

/// Something that watches the world step by step (the live view, the recorder). Whatever hosts a
/// scene (the world process, the in-process scene thread) calls every observer after every step,
/// on the stepping thread: an observer copies what it needs and hands it to its own threads. It
/// must never block or do slow work here, so the 3 ms step does not notice it.
pub trait Observer: Send {
    fn after_step(&mut self, step: &StepView<'_>);
}

fn other_what(kind: spidar_config::FileKind) -> &'static str {
    match kind {
        spidar_config::FileKind::CrowdScene => "crowd",
        _ => "walls",
    }
}

/// Builds a scene by name (`boxing`, `boxing-passive`, `crowd`, `walls`) or from a file of any
/// name that says what it is (its `kind`): a boxer file (the boxing scene with those
/// parameters), a crowd scene file or a walls scene file.
pub fn load(name_or_path: &str) -> anyhow::Result<Box<dyn Scene>> {
    load_with_skill(name_or_path, None)
}

/// [`load`], with the virtual human at `skill` (a level of its boxer file: novice, amateur, pro)
/// instead of the file's own; refused for a scene without a virtual human.
pub fn load_with_skill(name_or_path: &str, skill: Option<&str>) -> anyhow::Result<Box<dyn Scene>> {
    use spidar_config::FileKind;
    use spidar_sim::boxer::{BoxerParams, SkillLevel};
    let level = skill.map(SkillLevel::parse).transpose().map_err(|e| anyhow::anyhow!("--skill: {e}"))?;
    let boxing = |p: BoxerParams| -> anyhow::Result<Box<dyn Scene>> {
        let p = match level {
            Some(l) => p.with_skill(l),
            None => p,
        };
        Ok(Box::new(boxing::BoxingScene::new(p)?))
    };
    let no_skill = |what: &str| -> anyhow::Result<Box<dyn Scene>> {
        anyhow::bail!(
            "--skill sets the virtual human's level, and the {what} scene has none: leave --skill out"
        )
    };
    const TAKES: &str =
        "--scene takes boxing, boxing-passive, crowd, walls, or a boxer, crowd scene or walls \
                         scene file (configs/boxer.ron, configs/scene-crowd.ron, configs/scene-walls.ron)";
    match name_or_path {
        "walls" | "crowd" if level.is_some() => return no_skill(name_or_path),
        "walls" => return Ok(Box::new(walls::WallsScene::builtin())),
        spar::NAME => anyhow::bail!(
            "scene 'spar' needs two rigs and a world of its own: start `spidar world --scene spar --listen \
             udp://0.0.0.0:7700` and connect each rig with `spidar run --world udp://HOST:7700` (docs/spar.md)"
        ),
        "crowd" => return Ok(Box::new(crowd::CrowdScene::builtin()?)),
        "boxing" => return boxing(BoxerParams::default()),
        "boxing-passive" => return boxing(BoxerParams { active: false, ..Default::default() }),
        _ => {}
    }
    let path = std::path::Path::new(name_or_path);
    if !path.is_file() {
        anyhow::bail!("unknown scene '{name_or_path}' (and no such file): {TAKES}");
    }
    let (_, text) = spidar_config::load_file::<serde::de::IgnoredAny>(path)?;
    let kind = spidar_config::peek_kind(&text, name_or_path)?;
    Ok(match kind {
        FileKind::Boxer => boxing(spidar_sim::boxer::load_boxer(path)?)?,
        FileKind::CrowdScene | FileKind::WallsScene if level.is_some() => no_skill(other_what(kind))?,
        FileKind::CrowdScene => Box::new(crowd::CrowdScene::load(path)?),
        FileKind::WallsScene => Box::new(walls::WallsScene::load(path)?),
        other => anyhow::bail!(
            "{name_or_path}: this is {} (kind \"{}\"), not a scene: {TAKES}",
            other.what(),
            other.tag()
        ),
    })
}
