//! The world's share of a recording: a [`WorldRecorder`] watches every world step (an
//! [`Observer`] of the scene's host) and writes, on its own thread, one MCAP file (zstd chunks)
//! with the bodies' poses as Foxglove `FrameTransforms` and their shapes as `SceneUpdate` (so the
//! file opens in a Foxglove or Lichtblick 3D panel), the virtual human's decisions, the crowd's
//! control states, and the world's events (hits, behaviour changes, characters falling).
//!
//! The stepping thread never waits for the disk: the observer copies one step's numbers into a
//! buffer taken from a fixed pool and hands it over with `try_send`; when every buffer is still
//! queued (the writer or the disk lags) the step is dropped and counted. It allocates nothing
//! after the first step. A crowd's drawn figures (for its skeletons and the view's frames) are
//! not computed there: on the steps that need them the observer copies the characters' figure
//! states into a buffer of a second, smaller pool, and the writer computes the figures.
//!
//! It also keeps what the live view drew, for `spidar replay` to draw it again exactly: the
//! view's frames at display rate with the heads-up display's numbers (`/world/view`), and the
//! view's scene description (attachment `view.json`).
//!
//! Channels (see docs/recording.md): `/world/tf`, `/world/scene`, `/world/step`,
//! `/world/boxer`, `/world/gaze` (where the virtual human looks, with `/world/gaze/drawn`, an
//! arrow for Foxglove), `/world/crowd`, `/world/event`, `/world/view`.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Receiver, Sender};
use glam::{DQuat, DVec3, Quat, Vec3};
use mcap::records::Metadata;
use mcap::{Attachment, Writer};
use spidar_msg::{RigInfo, RigState, RigStatus, HANDS, STRINGS};
use spidar_sim::character::drawn::FigureState;
use spidar_sim::collide::Shape;
use spidar_world::decisions::{Decisions, Gaze, Prediction, ReachTarget, BODY_BEHAVIOURS, HAND_BEHAVIOURS};
use spidar_world::look::{
    Look, LookShape, CHARACTER_HEAD_FLOATS, CHARACTER_STATE, JOINT_FLOATS, MAX_COUNTERS, SHAPE_FLOATS,
};
use spidar_world::view::{FrameFinisher, FrameMaker, Layout, StatusData};
use spidar_world::{Observer, StepView};

use crate::cdr::{self, Field};
use crate::channel::{self, ChannelSpec, Channels, Tap};
use crate::foxglove::*;
use crate::writer::{META_END, META_SESSION};
use crate::{message, RecordError, FORMAT_VERSION, SPIDAR_VERSION};

pub const TOPIC_TF: &str = "/world/tf";
pub const TOPIC_SCENE: &str = "/world/scene";
/// The behaviour labels, all of them in every message (a seek finds them all in the newest).
pub const TOPIC_LABELS: &str = "/world/labels";
/// A crowd's drawn figures, all of them in every message.
pub const TOPIC_SKELETONS: &str = "/world/skeletons";
pub const TOPIC_STEP: &str = "/world/step";
pub const TOPIC_BOXER: &str = "/world/boxer";
/// Where the virtual human looks, every step (scenes with one).
pub const TOPIC_GAZE: &str = "/world/gaze";
/// The same gaze drawn for Foxglove's 3D panel: an arrow from the eyes to the point looked at,
/// at the view's display rate.
pub const TOPIC_GAZE_DRAWN: &str = "/world/gaze/drawn";
pub const TOPIC_CROWD: &str = "/world/crowd";
pub const TOPIC_WORLD_EVENT: &str = "/world/event";
pub const TOPIC_VIEW: &str = "/world/view";
/// The attachment holding the live view's scene description (its `scene` message).
pub const VIEW_ATTACHMENT: &str = "view.json";
/// The view's frames are kept this often (scene time): the live view's display rate.
pub const VIEW_EVERY_S: f64 = 1.0 / 60.0;
/// The fixed frame every world frame hangs from.
pub const WORLD_FRAME: &str = "world";
/// The root frame above `world`: z up (Foxglove's 3D panel orbits about z), x as the world's x,
/// y the user's forward (world -z). `world` is this frame turned +90 degrees about x.
pub const Z_UP_FRAME: &str = "z_up";
/// Height of the first label above its body, and between two labels of one body (m, world up).
pub const LABEL_ABOVE_M: f64 = 0.2;
pub const LABEL_STEP_M: f64 = 0.07;
/// The scene's whole look (every entity) is written again this often (scene time), so a player
/// that seeks, or a file cut short, always has the shapes to draw.
pub const SCENE_EVERY_S: f64 = 1.0;
/// The crowd's skeletons (which move within their characters' frames) are drawn at most this
/// often (scene time): display rate, a third of the steps.
pub const SKELETON_EVERY_S: f64 = 1.0 / 60.0;
/// Steps the queue to the writer holds (a second of boxing steps).
pub const QUEUE_STEPS: usize = 384;
/// Buffers of a crowd's figure states, one per queued step that draws the figures: those at
/// display rate (a fifth of the steps), and those where a character's state changes.
pub const FIGURE_BUFFERS: usize = QUEUE_STEPS / 4;
/// Uncompressed bytes of messages per chunk.
pub const CHUNK_BYTES: u64 = 1 << 20;

/// The world recording of `spidar run --record FILE.mcap`: `FILE.world.mcap`, next to it.
pub fn world_path(rig_path: &Path) -> PathBuf {
    let stem = rig_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let stem = stem.strip_suffix(".world").unwrap_or(&stem).to_string();
    rig_path.with_file_name(format!("{stem}.world.mcap"))
}

/// One world step, as `/world/step`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WorldStep {
    pub step: u64,
    pub t_s: f64,
    pub samples: u32,
    pub proxies: u8,
    /// Steps the recorder dropped so far (its queue was full).
    pub dropped: u64,
}
message!(WorldStep = "spidar/WorldStep" {
    step: u64,
    /// scene time (the rig's loop clock for the first rig)
    t_s: f64,
    /// hand samples the step consumed
    samples: u32,
    /// proxies in the contact model it produced
    proxies: u8,
    /// steps not recorded so far (the recorder's queue was full)
    dropped: u64,
});

message!(ReachTarget = "spidar/Reach" {
    active: bool,
    /// the model body that moves
    body: u16,
    /// scene frame
    target_m: DVec3,
    start_s: f64,
    duration_s: f64,
});

message!(Prediction = "spidar/Prediction" {
    /// 0 none, 1 the user's attack lands, 2 the virtual human's attack lands, 3 the virtual human blocked, 4 the user blocked, 5 other
    class: u8,
    vh_body: u16,
    av_body: u16,
    /// predicted contact point (scene frame) and scene time
    point_m: DVec3,
    at_s: f64,
});

/// The virtual human after a step, as `/world/boxer`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BoxerMsg {
    pub t_s: f64,
    pub d: Decisions,
}

impl Field for BoxerMsg {
    fn ros_type() -> String {
        "spidar/Boxer".into()
    }
    fn definition() -> Option<String> {
        Some(
            "float64 t_s\nbool active\n# per hand (left, right): 0 standby, 1 attack, 2 block\nuint8[2] hands\n\
             # 0 standby, 1 avoidance\nuint8 body\n# hands (left, right), then the body\nspidar/Reach[3] reaches\n\
             spidar/Prediction prediction\nuint64 predictions\nuint64 attacks\nuint64 avoidances\nuint64 blocks\n\
             # the user's hands on its head or chest; its hands on the avatar's\nuint64 hits_taken\nuint64 hits_given\n\
             # wall time of the latest prediction\nfloat64 last_predict_s\n"
                .into(),
        )
    }
    fn collect(out: &mut Vec<(String, String)>) {
        if cdr::add_definition::<Self>(out) {
            ReachTarget::collect(out);
            Prediction::collect(out);
        }
    }
    fn write(&self, w: &mut cdr::Writer<'_>) {
        let d = &self.d;
        self.t_s.write(w);
        d.active.write(w);
        d.hands.write(w);
        d.body.write(w);
        d.reaches.write(w);
        d.prediction.write(w);
        for c in [d.predictions, d.attacks, d.avoidances, d.blocks, d.hits_taken, d.hits_given] {
            c.write(w);
        }
        d.last_predict_s.write(w);
    }
    fn read(r: &mut cdr::Reader<'_>) -> Result<Self, cdr::DecodeError> {
        let t_s = f64::read(r)?;
        let mut d = Decisions {
            active: bool::read(r)?,
            hands: <[u8; 2]>::read(r)?,
            body: u8::read(r)?,
            reaches: <[ReachTarget; 3]>::read(r)?,
            prediction: Prediction::read(r)?,
            ..Default::default()
        };
        for c in [
            &mut d.predictions,
            &mut d.attacks,
            &mut d.avoidances,
            &mut d.blocks,
            &mut d.hits_taken,
            &mut d.hits_given,
        ] {
            *c = u64::read(r)?;
        }
        d.last_predict_s = f64::read(r)?;
        Ok(BoxerMsg { t_s, d })
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        for n in ["t_s", "active", "hands[0]", "hands[1]", "body"] {
            out.push(cdr::join(prefix, n));
        }
        <[ReachTarget; 3]>::columns(&cdr::join(prefix, "reaches"), out);
        Prediction::columns(&cdr::join(prefix, "prediction"), out);
        for n in
            ["predictions", "attacks", "avoidances", "blocks", "hits_taken", "hits_given", "last_predict_s"]
        {
            out.push(cdr::join(prefix, n));
        }
    }
    fn csv(&self, out: &mut String) {
        let d = &self.d;
        self.t_s.csv(out);
        d.active.csv(out);
        for h in d.hands {
            out.push(',');
            out.push_str(HAND_BEHAVIOURS.get(h as usize).unwrap_or(&"?"));
        }
        out.push(',');
        out.push_str(BODY_BEHAVIOURS.get(d.body as usize).unwrap_or(&"?"));
        d.reaches.csv(out);
        d.prediction.csv(out);
        for c in [d.predictions, d.attacks, d.avoidances, d.blocks, d.hits_taken, d.hits_given] {
            c.csv(out);
        }
        d.last_predict_s.csv(out);
    }
}

/// Where the virtual human looks after a step, as `/world/gaze`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GazeMsg {
    pub t_s: f64,
    pub eye_m: DVec3,
    pub dir: DVec3,
    pub at_m: DVec3,
    pub attended: u8,
}
message!(GazeMsg = "spidar/Gaze" {
    t_s: f64,
    /// the eyes (the head's centre), the unit direction they point, the point looked at (scene frame)
    eye_m: DVec3,
    dir: DVec3,
    at_m: DVec3,
    /// the avatar's fist attention is on: 0 none, 1 left, 2 right
    attended: u8,
});

impl GazeMsg {
    pub fn of(t_s: f64, g: &Gaze) -> GazeMsg {
        GazeMsg { t_s, eye_m: g.eye_m, dir: g.dir, at_m: g.at_m, attended: g.attended }
    }
}

/// The crowd's control states after a step, as `/world/crowd`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CrowdMsg {
    pub t_s: f64,
    pub states: Vec<u8>,
    pub not_balancing: u32,
}
message!(CrowdMsg = "spidar/Crowd" {
    t_s: f64,
    /// per character: 0 balance, 1 fall, 2 down, 3 stand up
    states: Vec<u8>,
    not_balancing: u32,
});

/// The rig's status as the world last had it (the heads-up display's numbers), in `/world/view`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RigStatusMsg {
    pub known: bool,
    pub tick: u64,
    pub t_s: f64,
    pub state: u8,
    pub rate_hz: f64,
    pub lateness_p99_s: f64,
    pub force_n: [DVec3; HANDS],
    pub tensions_n: [f64; HANDS * STRINGS],
    pub faults: u64,
    pub device_errors: u64,
    pub stale_ticks: u64,
    pub clamped_ticks: u64,
    pub misses: u64,
    pub seen_t_s: f64,
}
message!(RigStatusMsg = "spidar/RigStatus" {
    /// false: the world had no status from a rig yet (the rest is zero)
    known: bool,
    /// the newest tick it summarises, and its loop-clock time
    tick: u64,
    t_s: f64,
    /// 0 unconfigured, 1 inactive, 2 active, 3 faulted, 4 stopping
    state: u8,
    rate_hz: f64,
    lateness_p99_s: f64,
    /// force applied to each hand (world frame)
    force_n: [DVec3; HANDS],
    /// commanded tension, hand 0 strings 0..3 then hand 1
    tensions_n: [f64; HANDS * STRINGS],
    /// running counts since the rig started
    faults: u64,
    device_errors: u64,
    stale_ticks: u64,
    clamped_ticks: u64,
    misses: u64,
    /// scene time the world first saw this tick's status
    seen_t_s: f64,
});

/// Per-hand string values as the messages carry them: hand 0's strings, then hand 1's.
fn flat<T: Copy>(x: &[[T; STRINGS]; HANDS]) -> [T; HANDS * STRINGS] {
    std::array::from_fn(|i| x[i / STRINGS][i % STRINGS])
}

/// The reverse of [`flat`].
fn per_hand<T: Copy>(x: &[T; HANDS * STRINGS]) -> [[T; STRINGS]; HANDS] {
    std::array::from_fn(|h| std::array::from_fn(|s| x[h * STRINGS + s]))
}

/// The rig's geometry as the world had it (anchors, home points, eye), in `/world/view`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RigGeometryMsg {
    pub known: bool,
    pub period_s: f64,
    pub anchors_m: [DVec3; HANDS * STRINGS],
    pub home_m: [DVec3; HANDS],
    pub tension_min_n: [f64; HANDS],
    pub tension_max_n: [f64; HANDS],
    pub force_limit_n: [f64; HANDS],
    pub grip_radius_m: [f64; HANDS],
    pub eye_m: DVec3,
}
message!(RigGeometryMsg = "spidar/RigGeometry" {
    /// false: no rig had said its geometry yet (the rest is zero)
    known: bool,
    period_s: f64,
    /// where each string leaves the frame, hand 0 strings 0..3 then hand 1 (world frame)
    anchors_m: [DVec3; HANDS * STRINGS],
    home_m: [DVec3; HANDS],
    tension_min_n: [f64; HANDS],
    tension_max_n: [f64; HANDS],
    force_limit_n: [f64; HANDS],
    grip_radius_m: [f64; HANDS],
    /// the user's eye point (world frame)
    eye_m: DVec3,
});

/// What the live view showed at one frame, as `/world/view`: the frame itself and the numbers of
/// the heads-up display. `spidar replay` sends them to the page again.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewFrameMsg {
    pub t_s: f64,
    pub steps: u64,
    pub step_rate_hz: f64,
    pub sample_t_s: f64,
    pub counters: [f64; MAX_COUNTERS],
    pub rig: RigStatusMsg,
    pub geometry: RigGeometryMsg,
    pub frame: Vec<f32>,
}
message!(ViewFrameMsg = "spidar/ViewFrame" {
    /// scene time of the step drawn
    t_s: f64,
    /// steps taken so far, and the step rate over the last half second
    steps: u64,
    step_rate_hz: f64,
    /// scene time of the newest hand sample (NaN: none yet)
    sample_t_s: f64,
    /// the scene's counters, in the order of the view description's `counters`
    counters: [f64; MAX_COUNTERS],
    rig: RigStatusMsg,
    geometry: RigGeometryMsg,
    /// the live view's binary frame (docs/view.md), as the page got it
    frame: Vec<f32>,
});

impl ViewFrameMsg {
    /// The heads-up display's numbers, as the live view's status message had them.
    pub fn status(&self) -> StatusData {
        let r = &self.rig;
        let state = match r.state {
            0 => RigState::Unconfigured,
            1 => RigState::Inactive,
            2 => RigState::Active,
            3 => RigState::Faulted,
            _ => RigState::Stopping,
        };
        let tensions_n = per_hand(&r.tensions_n);
        StatusData {
            t_s: self.t_s,
            steps: self.steps,
            step_rate_hz: self.step_rate_hz,
            rig: r.known.then_some(RigStatus {
                tick: r.tick,
                t_s: r.t_s,
                state,
                rate_hz: r.rate_hz,
                lateness_p99_s: r.lateness_p99_s,
                force_n: r.force_n,
                tensions_n,
                faults: r.faults,
                device_errors: r.device_errors,
                stale_ticks: r.stale_ticks,
                clamped_ticks: r.clamped_ticks,
                misses: r.misses,
            }),
            rig_seen_t_s: r.seen_t_s,
            sample_t_s: self.sample_t_s,
            counters: self.counters,
            ended: false,
        }
    }

    /// The rig's geometry, if the world had it.
    pub fn rig_info(&self) -> Option<RigInfo> {
        let g = &self.geometry;
        g.known.then(|| {
            let anchors_m = per_hand(&g.anchors_m);
            RigInfo {
                period_s: g.period_s,
                anchors_m,
                home_m: g.home_m,
                tension_min_n: g.tension_min_n,
                tension_max_n: g.tension_max_n,
                force_limit_n: g.force_limit_n,
                grip_radius_m: g.grip_radius_m,
                eye_m: g.eye_m,
                // The recording keeps no screen: a replay draws the user's eye without one.
                display: Default::default(),
                // Nor the rig file's `near_strings`: a replay marks near strings by the defaults.
                clearance: Default::default(),
            }
        })
    }

    fn new(s: &StatusData, info: Option<&RigInfo>, frame: Vec<f32>) -> ViewFrameMsg {
        let rig = s.rig.map_or(RigStatusMsg::default(), |r| {
            let tensions_n = flat(&r.tensions_n);
            RigStatusMsg {
                known: true,
                tick: r.tick,
                t_s: r.t_s,
                state: r.state as u8,
                rate_hz: r.rate_hz,
                lateness_p99_s: r.lateness_p99_s,
                force_n: r.force_n,
                tensions_n,
                faults: r.faults,
                device_errors: r.device_errors,
                stale_ticks: r.stale_ticks,
                clamped_ticks: r.clamped_ticks,
                misses: r.misses,
                seen_t_s: s.rig_seen_t_s,
            }
        });
        let geometry = info.map_or(RigGeometryMsg::default(), |i| {
            let anchors_m = flat(&i.anchors_m);
            RigGeometryMsg {
                known: true,
                period_s: i.period_s,
                anchors_m,
                home_m: i.home_m,
                tension_min_n: i.tension_min_n,
                tension_max_n: i.tension_max_n,
                force_limit_n: i.force_limit_n,
                grip_radius_m: i.grip_radius_m,
                eye_m: i.eye_m,
            }
        });
        ViewFrameMsg {
            t_s: s.t_s,
            steps: s.steps,
            step_rate_hz: s.step_rate_hz,
            sample_t_s: s.sample_t_s,
            counters: s.counters,
            rig,
            geometry,
            frame,
        }
    }
}

/// Names of the crowd's control states, by code.
pub const CROWD_STATES: [&str; 4] = ["balance", "fall", "down", "stand-up"];

/// A world event, as `/world/event`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WorldEventMsg {
    pub t_s: f64,
    pub kind: u8,
    pub index: u16,
    pub state: u8,
    pub text: String,
}
message!(WorldEventMsg = "spidar/WorldEvent" {
    t_s: f64,
    /// 1 hit taken (the user's hand on the virtual human's head or chest), 2 hit given (its hand on the avatar's head or chest), 3 a hand's behaviour changed, 4 the body's behaviour changed, 5 a character's control state changed
    kind: u8,
    /// the hand (0 left, 1 right) or the character
    index: u16,
    /// the new behaviour or control state (codes as in spidar/Boxer and spidar/Crowd)
    state: u8,
    text: String,
});

pub const EVENT_HIT_TAKEN: u8 = 1;
pub const EVENT_HIT_GIVEN: u8 = 2;
pub const EVENT_HAND: u8 = 3;
pub const EVENT_BODY: u8 = 4;
pub const EVENT_CHARACTER: u8 = 5;

/// The world channels, in the order of the writer's channel indexes: what a world recording
/// holds and what the world's live Foxglove server advertises.
pub fn channels() -> Vec<ChannelSpec> {
    vec![
        ChannelSpec::of::<FrameTransforms>(TOPIC_TF),
        ChannelSpec::of::<SceneUpdate>(TOPIC_SCENE),
        ChannelSpec::of::<WorldStep>(TOPIC_STEP),
        ChannelSpec::of::<BoxerMsg>(TOPIC_BOXER),
        ChannelSpec::of::<CrowdMsg>(TOPIC_CROWD),
        ChannelSpec::of::<WorldEventMsg>(TOPIC_WORLD_EVENT),
        ChannelSpec::of::<ViewFrameMsg>(TOPIC_VIEW),
        ChannelSpec::of::<SceneUpdate>(TOPIC_LABELS),
        ChannelSpec::of::<SceneUpdate>(TOPIC_SKELETONS),
        ChannelSpec::of::<GazeMsg>(TOPIC_GAZE),
        ChannelSpec::of::<SceneUpdate>(TOPIC_GAZE_DRAWN),
    ]
}

/// A decoded world message.
#[derive(Clone, Debug)]
pub enum WorldMsg {
    Step(WorldStep),
    Boxer(Box<BoxerMsg>),
    Gaze(GazeMsg),
    Crowd(CrowdMsg),
    Event(WorldEventMsg),
    /// `/world/tf`, `/world/scene` (for Foxglove) and `/world/view` (for `spidar replay`) are
    /// left encoded; they are counted.
    Drawing,
}

/// Decodes a message of a world channel (`None` for other topics). The channel's schema must be
/// this spidar's.
pub fn decode(topic: &str, schema: &str, data: &[u8]) -> Option<Result<WorldMsg, String>> {
    fn one<T: Field>(schema: &str, data: &[u8], f: impl Fn(T) -> WorldMsg) -> Result<WorldMsg, String> {
        if schema != T::ros_type() {
            return Err(format!("schema '{schema}' where this spidar writes '{}'", T::ros_type()));
        }
        cdr::decode::<T>(data).map(f).map_err(|e| e.to_string())
    }
    Some(match topic {
        TOPIC_STEP => one(schema, data, WorldMsg::Step),
        TOPIC_BOXER => one(schema, data, |b| WorldMsg::Boxer(Box::new(b))),
        TOPIC_GAZE => one(schema, data, WorldMsg::Gaze),
        TOPIC_CROWD => one(schema, data, WorldMsg::Crowd),
        TOPIC_WORLD_EVENT => one(schema, data, WorldMsg::Event),
        TOPIC_TF | TOPIC_SCENE | TOPIC_LABELS | TOPIC_SKELETONS | TOPIC_VIEW | TOPIC_GAZE_DRAWN => {
            Ok(WorldMsg::Drawing)
        }
        _ => return None,
    })
}

/// What made a world recording.
#[derive(Clone, Debug, Default)]
pub struct WorldInfo {
    /// The scene as asked (`boxing`, a file) and the scene's own name.
    pub scene: String,
    /// The scene's own name (`boxing`), as the live view shows it.
    pub name: String,
    pub command_line: String,
    /// `real` or `virtual`.
    pub clock: String,
    /// Unix time (ns) of scene time zero; default: when the file is created. `spidar run` gives
    /// the rig recording's, so both files share one time line.
    pub start_unix_ns: Option<u64>,
    /// Files that made the scene (name, text), attached.
    pub files: Vec<(String, String)>,
}

/// What a world recorder wrote and what it could not keep.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WorldRecordingReport {
    pub path: PathBuf,
    pub steps: u64,
    pub messages: u64,
    pub events: u64,
    /// Steps the queue had no room for (the writer or the disk lagged).
    pub dropped: u64,
    /// Steps not written because writing failed (see `error`).
    pub write_failed: u64,
    pub error: Option<String>,
    pub bytes: u64,
}

impl std::fmt::Display for WorldRecordingReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} world steps, {} messages, {} events, {:.1} MB; not kept: {} steps (recorder queue {}, write {})",
            self.path.display(),
            self.steps,
            self.messages,
            self.events,
            self.bytes as f64 / 1e6,
            self.dropped + self.write_failed,
            self.dropped,
            self.write_failed
        )?;
        if let Some(e) = &self.error {
            write!(f, "; WRITING FAILED: {e} (the file holds everything before it)")?;
        }
        Ok(())
    }
}

/// What a world recording holds by its own account, for a process that did not write it (the
/// rig's, when the world runs as its child process): its end record (read through the summary's
/// index), or, in a file without one (the world was killed), what reading it through finds.
pub fn report_of(path: &Path) -> Result<WorldRecordingReport, RecordError> {
    let bytes =
        std::fs::metadata(path).map_err(|e| RecordError::Open { path: path.to_path_buf(), cause: e })?.len();
    let mut r = WorldRecordingReport { path: path.to_path_buf(), bytes, ..Default::default() };
    match crate::reader::metadata_of(path, META_END)? {
        Some(m) => {
            let n = |k: &str| m.get(k).and_then(|v| v.parse().ok()).unwrap_or(0);
            (r.steps, r.dropped, r.write_failed) =
                (n("steps_recorded"), n("steps_dropped"), n("steps_write_failed"));
            (r.messages, r.events) = (n("messages"), n("events"));
        }
        None => {
            let s = summarize(path)?;
            (r.steps, r.dropped, r.events) = (s.steps, s.dropped, s.events);
            r.messages = s.recording.channels.iter().map(|c| c.messages).sum();
            r.error = Some(format!(
                "the world did not finish its recording ({}): it holds the steps written before it stopped",
                s.recording.ending.as_ref().map_or("not read to its end".into(), |e| e.to_string())
            ));
        }
    }
    Ok(r)
}

/// One step's numbers, copied on the stepping thread into a pooled buffer.
pub(crate) struct Snap {
    step: u64,
    t_s: f64,
    samples: u32,
    proxies: u8,
    /// The live view's frame of this step ([`Layout`]): the scene's poses every step, the rest
    /// when `view` (a frame the view would have sent); a crowd's figures only with `figures`.
    frame: Vec<f32>,
    words: usize,
    view: bool,
    /// Every entity is written again; the crowd's skeletons are.
    full: bool,
    skeletons: bool,
    /// The crowd's figure states, on the steps that draw the figures (`view` or `skeletons`).
    figures: Option<Vec<FigureState>>,
    status: StatusData,
    rig_info: Option<RigInfo>,
    decisions: Option<Decisions>,
}

/// Character `i`'s control state in a frame.
fn state_of(frame: &[f32], l: &Layout, i: usize) -> u8 {
    frame[l.characters_at + i * l.character_floats + CHARACTER_STATE].max(0.0) as u8
}

enum ToWriter {
    Step(Box<Snap>),
    Finish,
}

/// The observer half: copies each step into a pooled buffer (and, on the steps that draw a crowd's
/// figures, its figure states into a buffer of the second pool) and queues it. On the real clock
/// it never waits (a step whose buffers are not free is dropped and counted); on the virtual clock
/// (`clock: "virtual"`, a run as fast as the machine computes) nothing is real-time, so it waits
/// for the writer rather than lose steps.
pub struct WorldRecorder {
    maker: FrameMaker,
    wait: bool,
    next_view_t_s: f64,
    next_scene_t_s: f64,
    next_skeleton_t_s: f64,
    /// The crowd's states at the last step queued, and at this one.
    prev_states: Vec<u8>,
    states: Vec<u8>,
    full: Sender<ToWriter>,
    pub(crate) free: Receiver<Box<Snap>>,
    /// A buffer taken for a step that was dropped, for the next step.
    spare: Option<Box<Snap>>,
    pub(crate) figures_free: Receiver<Vec<FigureState>>,
    /// Figure states a step that draws the figures copies (0: the scene has none).
    figure_states: usize,
    dropped: Arc<AtomicU64>,
    steps: u64,
}

impl WorldRecorder {
    fn drop_step(&mut self, snap: Box<Snap>) {
        self.spare = Some(snap);
        self.dropped.fetch_add(1, Ordering::Relaxed);
    }
}

impl Observer for WorldRecorder {
    fn after_step(&mut self, s: &StepView<'_>) {
        self.steps += 1;
        let got = match self.spare.take() {
            Some(spare) => Some(spare),
            None if self.wait => self.free.recv().ok(),
            None => self.free.try_recv().ok(),
        };
        let Some(mut snap) = got else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        };
        snap.step = self.steps;
        snap.t_s = s.t_s;
        snap.samples = s.samples.len() as u32;
        snap.proxies = s.model.proxy_count;
        // What the live view would draw, as it makes it (the figures, when drawn, by the writer).
        self.maker.observe(s, true);
        snap.view = s.t_s >= self.next_view_t_s;
        snap.words = self.maker.write(&mut snap.frame, s, snap.view, false);
        // Which steps draw the skeletons: at display rate, with every entity, and when a
        // character's state (its colour) changes.
        let l = *self.maker.layout();
        self.states.clear();
        self.states.extend((0..l.characters).map(|i| state_of(&snap.frame, &l, i)));
        snap.full = s.t_s >= self.next_scene_t_s;
        snap.skeletons = l.characters > 0
            && (snap.full || s.t_s >= self.next_skeleton_t_s || self.states != self.prev_states);
        if self.figure_states > 0 && (snap.view || snap.skeletons) {
            let got =
                if self.wait { self.figures_free.recv().ok() } else { self.figures_free.try_recv().ok() };
            let Some(mut figures) = got else { return self.drop_step(snap) };
            s.scene.figure_states(&mut figures);
            snap.figures = Some(figures);
        }
        snap.status = *self.maker.status();
        snap.rig_info = s.rig_info.copied();
        snap.decisions = s.scene.decisions();
        let (t, view, full, skeletons) = (s.t_s, snap.view, snap.full, snap.skeletons);
        let sent = if self.wait {
            self.full.send(ToWriter::Step(snap)).is_ok()
        } else {
            self.full.try_send(ToWriter::Step(snap)).is_ok()
        };
        if !sent {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        if view {
            self.next_view_t_s = t + VIEW_EVERY_S;
        }
        if full {
            self.next_scene_t_s = t + SCENE_EVERY_S;
        }
        if skeletons {
            self.next_skeleton_t_s = t + SKELETON_EVERY_S;
        }
        std::mem::swap(&mut self.states, &mut self.prev_states);
    }
}

/// The writer half: owns the file and its thread; [`WorldRecording::finish`] ends the file.
pub struct WorldRecording {
    tx: Sender<ToWriter>,
    dropped: Arc<AtomicU64>,
    handle: Option<JoinHandle<WorldRecordingReport>>,
}

impl WorldRecording {
    /// Creates the file (an unwritable path fails here, before any step) and starts the writer
    /// thread; returns it and the observer to add to the scene's host.
    pub fn start(
        path: &Path,
        info: &WorldInfo,
        look: &Look,
    ) -> Result<(WorldRecording, WorldRecorder), RecordError> {
        Self::start_with(Some(path), info, look, None)
    }

    /// As [`WorldRecording::start`], writing the file at `path` (None: none) and handing every
    /// message to `tap` (a live server: the same channels and messages as the file).
    pub fn start_with(
        path: Option<&Path>,
        info: &WorldInfo,
        look: &Look,
        tap: Option<Box<dyn Tap>>,
    ) -> Result<(WorldRecording, WorldRecorder), RecordError> {
        let w = WorldWriter::create(path, info, look, tap)?;
        let layout = Layout::for_look(look);
        let (full_tx, full_rx) = bounded::<ToWriter>(QUEUE_STEPS + 1);
        let (free_tx, free_rx) = bounded::<Box<Snap>>(QUEUE_STEPS);
        for _ in 0..QUEUE_STEPS {
            let snap = Snap {
                step: 0,
                t_s: 0.0,
                samples: 0,
                proxies: 0,
                frame: vec![0.0; layout.max_words],
                words: 0,
                view: false,
                full: false,
                skeletons: false,
                figures: None,
                status: StatusData::default(),
                rig_info: None,
                decisions: None,
            };
            let _ = free_tx.try_send(Box::new(snap));
        }
        let figure_states = w.finisher.states();
        let (figures_tx, figures_rx) = bounded::<Vec<FigureState>>(FIGURE_BUFFERS);
        for _ in 0..if figure_states > 0 { FIGURE_BUFFERS } else { 0 } {
            let _ = figures_tx.try_send(vec![FigureState::default(); figure_states]);
        }
        let dropped = Arc::new(AtomicU64::new(0));
        let d = dropped.clone();
        let handle = std::thread::Builder::new()
            .name("spidar-world-recorder".into())
            .spawn(move || w.run(full_rx, free_tx, figures_tx, d))
            .map_err(|e| RecordError::Write {
                path: path.map_or_else(PathBuf::new, Path::to_path_buf),
                why: format!("starting the recorder thread: {e}"),
            })?;
        let rec = WorldRecorder {
            maker: FrameMaker::new(look),
            wait: info.clock == "virtual",
            next_view_t_s: f64::NEG_INFINITY,
            next_scene_t_s: f64::NEG_INFINITY,
            next_skeleton_t_s: f64::NEG_INFINITY,
            prev_states: Vec::with_capacity(layout.characters),
            states: Vec::with_capacity(layout.characters),
            full: full_tx.clone(),
            free: free_rx,
            spare: None,
            figures_free: figures_rx,
            figure_states,
            dropped: dropped.clone(),
            steps: 0,
        };
        Ok((WorldRecording { tx: full_tx, dropped, handle: Some(handle) }, rec))
    }

    /// Steps queued to the writer and not yet written.
    pub fn queued(&self) -> usize {
        self.tx.len()
    }

    /// Steps dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Writes what is queued and ends the file (summary and footer).
    pub fn finish(mut self) -> WorldRecordingReport {
        self.end()
    }

    fn end(&mut self) -> WorldRecordingReport {
        let _ = self.tx.send(ToWriter::Finish);
        let mut r = self.handle.take().and_then(|h| h.join().ok()).unwrap_or_else(|| WorldRecordingReport {
            error: Some("the world recorder thread panicked".into()),
            ..Default::default()
        });
        r.dropped = self.dropped.load(Ordering::Relaxed);
        r
    }
}

impl Drop for WorldRecording {
    fn drop(&mut self) {
        if self.handle.is_some() {
            self.end();
        }
    }
}

/// What is drawn for each moving shape: its frame and its entity.
struct Drawn {
    frame: String,
    entity: SceneEntity,
}

struct WorldWriter {
    w: Option<Writer<File>>,
    /// A file was asked for (`w` None then means writing failed).
    to_file: bool,
    /// A live server given every message.
    tap: Option<Box<dyn Tap>>,
    path: PathBuf,
    ch: Channels,
    look: Look,
    layout: Layout,
    finisher: FrameFinisher,
    shapes: Vec<Drawn>,
    statics: Vec<SceneEntity>,
    prev: Option<Decisions>,
    prev_labels: Vec<u8>,
    prev_states: Vec<u8>,
    report: WorldRecordingReport,
}

const TF: usize = 0;
const SCENE: usize = 1;
const STEP: usize = 2;
const BOXER: usize = 3;
const CROWD: usize = 4;
const EVENT: usize = 5;
const VIEW: usize = 6;
const LABELS: usize = 7;
const SKELETONS: usize = 8;
const GAZE: usize = 9;
const GAZE_DRAWN: usize = 10;

use crate::writer::describe;

/// The gaze as an arrow in the world frame, from the eyes to the point looked at (yellow, the
/// brighter while a fist is attended).
fn gaze_arrow(g: &Gaze, stamp: Time) -> SceneUpdate {
    let len = (g.at_m - g.eye_m).length();
    // A Foxglove arrow points along its pose's +x.
    let rot = DQuat::from_rotation_arc(DVec3::X, g.dir.normalize_or(DVec3::NEG_Z));
    let a = if g.attended > 0 { 1.0 } else { 0.5 };
    SceneUpdate {
        entities: vec![SceneEntity {
            timestamp: stamp,
            frame_id: WORLD_FRAME.into(),
            id: "gaze/virtual_human".into(),
            frame_locked: false,
            arrows: vec![ArrowPrimitive {
                pose: pose(g.eye_m, rot),
                shaft_length: (len - 0.04).max(0.0),
                shaft_diameter: 0.008,
                head_length: 0.04,
                head_diameter: 0.025,
                color: Color { r: 1.0, g: 0.85, b: 0.1, a },
            }],
            ..Default::default()
        }],
        ..Default::default()
    }
}

fn pose(pos: DVec3, q: DQuat) -> Pose {
    Pose {
        position: Point { x: pos.x, y: pos.y, z: pos.z },
        orientation: Quaternion { x: q.x, y: q.y, z: q.z, w: q.w },
    }
}

fn v3(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x, y, z }
}

/// The frame of label `i`: at its body, turned as the world.
fn label_frame(i: usize) -> String {
    format!("label/{i}")
}

/// `virtual human/head` -> `virtual_human/head`.
fn frame_name(name: &str) -> String {
    name.replace(' ', "_")
}

/// Adds the primitives drawing `shape` at `at` (in the entity's frame).
fn draw_shape(e: &mut SceneEntity, shape: &Shape, at: Pose, colour: Color) {
    let (p, q) = (
        DVec3::new(at.position.x, at.position.y, at.position.z),
        DQuat::from_xyzw(at.orientation.x, at.orientation.y, at.orientation.z, at.orientation.w),
    );
    match *shape {
        Shape::Sphere { radius_m } => {
            let d = 2.0 * radius_m;
            e.spheres.push(SpherePrimitive { pose: at, size: v3(d, d, d), color: colour });
        }
        Shape::Capsule { half_length_m, radius_m } => {
            let d = 2.0 * radius_m;
            // A cylinder's axis is its z; a capsule's is its y.
            let z_to_y = q * DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
            e.cylinders.push(CylinderPrimitive {
                pose: pose(p, z_to_y),
                size: v3(d, d, 2.0 * half_length_m),
                bottom_scale: 1.0,
                top_scale: 1.0,
                color: colour,
            });
            for s in [-1.0, 1.0] {
                let c = p + q * DVec3::new(0.0, s * half_length_m, 0.0);
                e.spheres.push(SpherePrimitive { pose: pose(c, q), size: v3(d, d, d), color: colour });
            }
        }
        Shape::Box { half_extents_m: h } => {
            e.cubes.push(CubePrimitive {
                pose: at,
                size: v3(2.0 * h.x, 2.0 * h.y, 2.0 * h.z),
                color: colour,
            });
        }
        Shape::Plane => {
            // The solid is below the plane through the origin with normal +y: a thin wide slab.
            let c = p + q * DVec3::new(0.0, -0.005, 0.0);
            e.cubes.push(CubePrimitive { pose: pose(c, q), size: v3(8.0, 0.01, 8.0), color: colour });
        }
    }
}

fn shape_entity(id: String, frame: String, s: &LookShape, at: Pose) -> SceneEntity {
    let mut e = SceneEntity { frame_id: frame, id, frame_locked: true, ..Default::default() };
    draw_shape(&mut e, &s.shape, at, Color::srgb(s.colour, 1.0));
    e
}

impl WorldWriter {
    /// The writer of a file at `path` (None: no file) and/or a live server `tap`.
    fn create(
        path: Option<&Path>,
        info: &WorldInfo,
        look: &Look,
        tap: Option<Box<dyn Tap>>,
    ) -> Result<WorldWriter, RecordError> {
        let start_ns = info.start_unix_ns.unwrap_or_else(crate::writer::unix_now_ns);
        let layout = Layout::for_look(look);
        let mut ch = Channels::new(start_ns);
        let w = match path {
            Some(path) => Some(Self::create_file(path, info, look, &layout, &mut ch)?),
            None => {
                ch.declare::<File>(None, self::channels()).expect("no file, nothing to fail");
                None
            }
        };
        // Frames of the moving shapes (unique names), and their entities in their own frames.
        let mut shapes: Vec<Drawn> = Vec::with_capacity(look.shapes.len());
        for (k, s) in look.shapes.iter().enumerate() {
            let mut frame = frame_name(&s.name);
            if shapes.iter().any(|d| d.frame == frame) {
                frame = format!("{frame}_{k}");
            }
            let entity = shape_entity(frame.clone(), frame.clone(), s, Pose::default());
            shapes.push(Drawn { frame, entity });
        }
        let statics = look
            .statics
            .iter()
            .enumerate()
            .map(|(i, (s, p, q))| {
                let mut e = shape_entity(format!("static/{i}"), WORLD_FRAME.into(), s, pose(*p, *q));
                e.frame_locked = false;
                e
            })
            .collect();
        let path = path.map_or_else(|| PathBuf::from("(live only)"), Path::to_path_buf);
        Ok(WorldWriter {
            to_file: w.is_some(),
            w,
            tap,
            report: WorldRecordingReport { path: path.clone(), ..Default::default() },
            path,
            ch,
            layout,
            finisher: FrameFinisher::new(look),
            look: look.clone(),
            shapes,
            statics,
            prev: None,
            prev_labels: Vec::new(),
            prev_states: Vec::new(),
        })
    }

    /// Creates the file and writes what made it; declares the channels.
    fn create_file(
        path: &Path,
        info: &WorldInfo,
        look: &Look,
        layout: &Layout,
        ch: &mut Channels,
    ) -> Result<Writer<File>, RecordError> {
        let create = |e: std::io::Error| RecordError::Create { path: path.to_path_buf(), cause: e };
        if path.is_dir() {
            return Err(create(std::io::Error::other("it is a directory")));
        }
        let file = File::create(path).map_err(create)?;
        let write = |e: mcap::McapError| RecordError::Write { path: path.to_path_buf(), why: describe(&e) };
        let mut w = channel::options(Some(CHUNK_BYTES)).create(file).map_err(write)?;
        let start_ns = ch.start_unix_ns();
        let mut meta = BTreeMap::new();
        for (k, v) in [
            ("format_version", FORMAT_VERSION.to_string()),
            ("spidar_version", SPIDAR_VERSION.to_string()),
            ("role", "world".to_string()),
            ("scene", info.scene.clone()),
            ("command_line", info.command_line.clone()),
            ("clock", info.clock.clone()),
            ("start_unix_ns", start_ns.to_string()),
        ] {
            meta.insert(k.to_string(), v);
        }
        w.write_metadata(&Metadata { name: META_SESSION.into(), metadata: meta }).map_err(write)?;
        for (name, text) in &info.files {
            w.attach(&Attachment {
                log_time: start_ns,
                create_time: start_ns,
                name: name.clone(),
                media_type: "text/plain".into(),
                data: text.as_bytes().into(),
            })
            .map_err(write)?;
        }
        // What the live view's page is told the scene looks like, for `spidar replay`.
        let view = spidar_world::view::json::scene(&info.name, look, layout, 1.0 / VIEW_EVERY_S);
        w.attach(&Attachment {
            log_time: start_ns,
            create_time: start_ns,
            name: VIEW_ATTACHMENT.into(),
            media_type: "application/json".into(),
            data: view.as_bytes().into(),
        })
        .map_err(write)?;
        // No chunk ends here: the schemas and channels go into the first chunk with its messages.
        ch.declare(Some(&mut w), self::channels()).map_err(write)?;
        Ok(w)
    }

    fn run(
        mut self,
        rx: Receiver<ToWriter>,
        free: Sender<Box<Snap>>,
        figures_free: Sender<Vec<FigureState>>,
        dropped: Arc<AtomicU64>,
    ) -> WorldRecordingReport {
        for m in rx {
            match m {
                ToWriter::Step(mut snap) => {
                    // The crowd's figures, drawn here from the states the step copied.
                    if let Some(figures) = snap.figures.take() {
                        self.finisher.finish(&mut snap.frame[..snap.words], &figures);
                        let _ = figures_free.try_send(figures);
                    }
                    self.write_step(&snap, dropped.load(Ordering::Relaxed));
                    let _ = free.try_send(snap);
                }
                ToWriter::Finish => break,
            }
        }
        self.finish(dropped.load(Ordering::Relaxed))
    }

    fn put<T: Field>(&mut self, ch: usize, t_s: f64, x: &T) -> bool {
        if self.to_file && self.w.is_none() {
            return false;
        }
        match self.ch.put(self.w.as_mut(), self.tap.as_deref_mut(), ch, t_s, x) {
            Ok(_) => {
                self.report.messages += 1;
                true
            }
            Err(e) => {
                self.report.error.get_or_insert(describe(&e));
                self.w = None;
                false
            }
        }
    }

    fn write_step(&mut self, s: &Snap, dropped: u64) {
        if self.to_file && self.w.is_none() {
            self.report.write_failed += 1;
            return;
        }
        let stamp = Time::from_ns(self.ch.log_ns(s.t_s));
        let mut ok = self.put(
            STEP,
            s.t_s,
            &WorldStep { step: s.step, t_s: s.t_s, samples: s.samples, proxies: s.proxies, dropped },
        );
        let (tf, states) = self.transforms(s, stamp);
        ok = ok && self.put(TF, s.t_s, &tf);
        let labels: Vec<u8> =
            (0..self.layout.labels).map(|i| s.frame[self.layout.labels_at + i].max(0.0) as u8).collect();
        ok = self.write_looks(ok, s, stamp, &labels, &states);
        // What the live view drew (at its display rate), for `spidar replay`.
        if s.view {
            let v = ViewFrameMsg::new(&s.status, s.rig_info.as_ref(), s.frame[..s.words].to_vec());
            ok = ok && self.put(VIEW, s.t_s, &v);
        }
        ok = self.write_decisions(ok, s);
        ok = self.write_crowd(ok, s, states);
        self.prev_labels = labels;
        if ok {
            self.report.steps += 1;
        } else {
            self.report.write_failed += 1;
        }
    }

    /// Where every body is (the y-up world under a z-up root, the link frame, each shape, each
    /// label's frame, each character), and the characters' states.
    fn transforms(&self, s: &Snap, stamp: Time) -> (FrameTransforms, Vec<u8>) {
        let l = self.layout;
        let mut tf = FrameTransforms {
            transforms: Vec::with_capacity(l.shapes + l.characters + self.look.labels.len() + 2),
        };
        // The y-up world under a z-up root, so Foxglove's 3D panel shows the floor as a floor.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        tf.transforms.push(FrameTransform {
            timestamp: stamp,
            parent_frame_id: Z_UP_FRAME.into(),
            child_frame_id: WORLD_FRAME.into(),
            translation: v3(0.0, 0.0, 0.0),
            rotation: Quaternion { x: h, y: 0.0, z: 0.0, w: h },
        });
        let off = self.look.link_offset_m;
        tf.transforms.push(FrameTransform {
            timestamp: stamp,
            parent_frame_id: WORLD_FRAME.into(),
            child_frame_id: "link".into(),
            translation: v3(off.x, off.y, off.z),
            rotation: Quaternion::default(),
        });
        for (k, d) in self.shapes.iter().enumerate() {
            let f = &s.frame[l.shapes_at + k * SHAPE_FLOATS..l.shapes_at + (k + 1) * SHAPE_FLOATS];
            tf.transforms.push(FrameTransform {
                timestamp: stamp,
                parent_frame_id: WORLD_FRAME.into(),
                child_frame_id: d.frame.clone(),
                translation: v3(f[0] as f64, f[1] as f64, f[2] as f64),
                rotation: Quaternion { x: f[3] as f64, y: f[4] as f64, z: f[5] as f64, w: f[6] as f64 },
            });
        }
        // Each labelled body's label frame: at the body, unturned (the world's up stays up), so
        // its labels stand above it however it turns.
        for (i, lab) in self.look.labels.iter().enumerate() {
            let at = lab.shape * SHAPE_FLOATS + l.shapes_at;
            let p = s.frame.get(at..at + 3).map_or([0.0; 3], |f| [f[0] as f64, f[1] as f64, f[2] as f64]);
            tf.transforms.push(FrameTransform {
                timestamp: stamp,
                parent_frame_id: WORLD_FRAME.into(),
                child_frame_id: label_frame(i),
                translation: v3(p[0], p[1], p[2]),
                rotation: Quaternion::default(),
            });
        }
        let mut states = Vec::with_capacity(l.characters);
        for i in 0..l.characters {
            let c = &s.frame[l.characters_at + i * l.character_floats..];
            tf.transforms.push(FrameTransform {
                timestamp: stamp,
                parent_frame_id: WORLD_FRAME.into(),
                child_frame_id: format!("character/{i}"),
                translation: v3(c[0] as f64, c[1] as f64, c[2] as f64),
                rotation: Quaternion { x: c[3] as f64, y: c[4] as f64, z: c[5] as f64, w: c[6] as f64 },
            });
            states.push(state_of(&s.frame, &l, i));
        }
        (tf, states)
    }

    /// What the bodies look like, on three topics so that the newest message of each (all a
    /// Foxglove 3D panel keeps after a seek) holds the whole of it: every shape now and then;
    /// every label when one changes; every skeleton at display rate (as the observer decided).
    /// Once a write failed (`ok` false) nothing more is written.
    fn write_looks(&mut self, mut ok: bool, s: &Snap, stamp: Time, labels: &[u8], states: &[u8]) -> bool {
        let l = self.layout;
        if s.full {
            let mut update = SceneUpdate::default();
            for d in &self.shapes {
                update.entities.push(SceneEntity { timestamp: stamp, ..d.entity.clone() });
            }
            for e in &self.statics {
                update.entities.push(SceneEntity { timestamp: stamp, ..e.clone() });
            }
            if !update.entities.is_empty() {
                ok = ok && self.put(SCENE, s.t_s, &update);
            }
        }
        if !self.look.labels.is_empty() && (s.full || labels != self.prev_labels.as_slice()) {
            let mut update = SceneUpdate::default();
            // Labels of one body stack upward, one line each.
            let mut line_of_shape: Vec<(usize, usize)> = Vec::new();
            for (i, lab) in self.look.labels.iter().enumerate() {
                let state = labels[i] as usize;
                let text = format!("{}: {}", lab.name, lab.states.get(state).map_or("?", |x| x.as_str()));
                let line = line_of_shape.iter().filter(|(shape, _)| *shape == lab.shape).count();
                line_of_shape.push((lab.shape, i));
                update.entities.push(SceneEntity {
                    timestamp: stamp,
                    frame_id: label_frame(i),
                    id: format!("label/{i}"),
                    frame_locked: true,
                    texts: vec![TextPrimitive {
                        pose: pose(
                            DVec3::new(0.0, LABEL_ABOVE_M + LABEL_STEP_M * line as f64, 0.0),
                            DQuat::IDENTITY,
                        ),
                        billboard: true,
                        font_size: 14.0,
                        scale_invariant: true,
                        color: Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 },
                        text,
                    }],
                    ..Default::default()
                });
            }
            ok = ok && self.put(LABELS, s.t_s, &update);
        }
        if let Some(crowd) = self.look.crowd.as_ref().filter(|_| s.skeletons) {
            let mut update = SceneUpdate::default();
            for (i, state) in states.iter().enumerate() {
                let c = &s.frame[l.characters_at + i * l.character_floats
                    ..(i + 1) * l.character_floats + l.characters_at];
                let colour = crowd.colours.get(*state as usize).copied().unwrap_or([200, 200, 200]);
                update.entities.push(SceneEntity {
                    timestamp: stamp,
                    frame_id: format!("character/{i}"),
                    id: format!("character/{i}"),
                    frame_locked: true,
                    lines: vec![skeleton(crowd, c, Color::srgb(colour, 1.0))],
                    ..Default::default()
                });
            }
            ok = ok && self.put(SKELETONS, s.t_s, &update);
        }
        ok
    }

    /// The virtual human's decisions and the events they make (hits, each hand's and the body's
    /// behaviour when it changes).
    fn write_decisions(&mut self, mut ok: bool, s: &Snap) -> bool {
        if let Some(d) = s.decisions {
            ok = ok && self.put(BOXER, s.t_s, &BoxerMsg { t_s: s.t_s, d });
            ok = ok && self.put(GAZE, s.t_s, &GazeMsg::of(s.t_s, &d.gaze));
            if s.view {
                ok = ok
                    && self.put(
                        GAZE_DRAWN,
                        s.t_s,
                        &gaze_arrow(&d.gaze, Time::from_ns(self.ch.log_ns(s.t_s))),
                    );
            }
            let p = self.prev.unwrap_or_default();
            let mut events = Vec::new();
            if d.hits_taken > p.hits_taken {
                events.push((
                    EVENT_HIT_TAKEN,
                    0,
                    0,
                    format!(
                        "hit taken (the user's hand on the virtual human's head or chest), {} so far",
                        d.hits_taken
                    ),
                ));
            }
            if d.hits_given > p.hits_given {
                events.push((
                    EVENT_HIT_GIVEN,
                    0,
                    0,
                    format!(
                        "hit given (the virtual human's hand on the avatar's head or chest), {} so far",
                        d.hits_given
                    ),
                ));
            }
            for h in 0..2 {
                if d.hands[h] != p.hands[h] || self.prev.is_none() {
                    let name = HAND_BEHAVIOURS.get(d.hands[h] as usize).unwrap_or(&"?");
                    events.push((
                        EVENT_HAND,
                        h as u16,
                        d.hands[h],
                        format!("{} hand: {name}", ["left", "right"][h]),
                    ));
                }
            }
            if d.body != p.body || self.prev.is_none() {
                let name = BODY_BEHAVIOURS.get(d.body as usize).unwrap_or(&"?");
                events.push((EVENT_BODY, 0, d.body, format!("body: {name}")));
            }
            for (kind, index, state, text) in events {
                ok = ok && self.put(EVENT, s.t_s, &WorldEventMsg { t_s: s.t_s, kind, index, state, text });
                self.report.events += 1;
            }
            self.prev = Some(d);
        }
        ok
    }

    /// The crowd's states, and an event for each character whose state changed.
    fn write_crowd(&mut self, mut ok: bool, s: &Snap, states: Vec<u8>) -> bool {
        if self.look.crowd.is_some() {
            for (i, st) in states.iter().enumerate() {
                if self.prev_states.get(i) != Some(st) {
                    let name = CROWD_STATES.get(*st as usize).unwrap_or(&"?");
                    let e = WorldEventMsg {
                        t_s: s.t_s,
                        kind: EVENT_CHARACTER,
                        index: i as u16,
                        state: *st,
                        text: format!("character {i}: {name}"),
                    };
                    ok = ok && self.put(EVENT, s.t_s, &e);
                    self.report.events += 1;
                }
            }
            let not_balancing = states.iter().filter(|s| **s != 0).count() as u32;
            ok =
                ok && self.put(CROWD, s.t_s, &CrowdMsg { t_s: s.t_s, states: states.clone(), not_balancing });
            self.prev_states = states;
        }
        ok
    }

    fn finish(mut self, dropped: u64) -> WorldRecordingReport {
        if let Some(mut w) = self.w.take() {
            let mut meta = BTreeMap::new();
            meta.insert("steps_recorded".to_string(), self.report.steps.to_string());
            meta.insert("steps_dropped".to_string(), dropped.to_string());
            meta.insert("steps_write_failed".to_string(), self.report.write_failed.to_string());
            meta.insert("messages".to_string(), self.report.messages.to_string());
            meta.insert("events".to_string(), self.report.events.to_string());
            let r = w
                .write_metadata(&Metadata { name: META_END.into(), metadata: meta })
                .and_then(|_| w.finish());
            if let Err(e) = r {
                self.report.error.get_or_insert(describe(&e));
            }
        }
        self.report.bytes = std::fs::metadata(&self.path).map_or(0, |m| m.len());
        self.report.clone()
    }
}

/// A character's drawn figure as line segments in its body frame: the frame carries each joint's
/// position in the scene frame, turned here into the body frame the character's transform gives.
pub(crate) fn skeleton(crowd: &spidar_world::look::LookCrowd, c: &[f32], colour: Color) -> LinePrimitive {
    let pos = Vec3::new(c[0], c[1], c[2]);
    let to_body = Quat::from_xyzw(c[3], c[4], c[5], c[6]).normalize().conjugate();
    let joint = |j: usize| {
        let o = CHARACTER_HEAD_FLOATS + JOINT_FLOATS * j;
        c.get(o..o + 3).map(|p| to_body * (Vec3::new(p[0], p[1], p[2]) - pos))
    };
    let mut points = Vec::with_capacity(2 * crowd.joints.len());
    for (j, joint_desc) in crowd.joints.iter().enumerate() {
        let Some(p) = joint_desc.parent.filter(|p| *p < j) else { continue };
        if let (Some(a), Some(b)) = (joint(p), joint(j)) {
            for q in [a, b] {
                points.push(Point { x: q.x as f64, y: q.y as f64, z: q.z as f64 });
            }
        }
    }
    LinePrimitive {
        r#type: 2,
        pose: Pose::default(),
        thickness: 0.04,
        scale_invariant: false,
        points,
        color: colour,
        ..Default::default()
    }
}

/// What a world recording holds (`spidar replay` prints it with the rig's).
#[derive(Clone, Debug, Default)]
pub struct WorldSummary {
    pub recording: crate::reader::Recording,
    pub steps: u64,
    pub first_t_s: f64,
    pub last_t_s: f64,
    /// Steps the recorder had dropped by the last recorded step.
    pub dropped: u64,
    /// The virtual human's last state (scenes with one).
    pub boxer: Option<Decisions>,
    /// Steps with each hand attacking, blocking; with the body avoiding.
    pub attack_steps: [u64; 2],
    pub block_steps: [u64; 2],
    pub avoid_steps: u64,
    /// Steps with the virtual human's gaze recorded, and of those with a fist attended.
    pub gaze_steps: u64,
    pub gaze_attended_steps: u64,
    pub hits_taken: u64,
    pub hits_given: u64,
    pub events: u64,
    /// Crowd: characters, and the most not balancing at once.
    pub characters: usize,
    pub most_not_balancing: u32,
    pub drawing_messages: u64,
}

/// Reads a world recording through.
pub fn summarize(path: &Path) -> Result<WorldSummary, RecordError> {
    let mut s = WorldSummary::default();
    let recording = crate::reader::read(path, |_, m| {
        let crate::reader::Msg::Other { channel, data, .. } = m else {
            return Ok(crate::reader::Flow::Continue);
        };
        let Some(msg) = decode(&channel.topic, &channel.schema, data) else {
            return Ok(crate::reader::Flow::Continue);
        };
        let msg = msg.map_err(|e| RecordError::Corrupt {
            path: path.to_path_buf(),
            what: format!("a message on {}: {e}", channel.topic),
        })?;
        match msg {
            WorldMsg::Step(st) => {
                if s.steps == 0 {
                    s.first_t_s = st.t_s;
                }
                s.steps += 1;
                s.last_t_s = st.t_s;
                s.dropped = st.dropped;
            }
            WorldMsg::Boxer(b) => {
                for h in 0..2 {
                    s.attack_steps[h] += u64::from(b.d.hands[h] == 1);
                    s.block_steps[h] += u64::from(b.d.hands[h] == 2);
                }
                s.avoid_steps += u64::from(b.d.body == 1);
                s.boxer = Some(b.d);
            }
            WorldMsg::Gaze(g) => {
                s.gaze_steps += 1;
                s.gaze_attended_steps += u64::from(g.attended > 0);
            }
            WorldMsg::Crowd(c) => {
                s.characters = c.states.len();
                s.most_not_balancing = s.most_not_balancing.max(c.not_balancing);
            }
            WorldMsg::Event(e) => {
                s.events += 1;
                s.hits_taken += u64::from(e.kind == EVENT_HIT_TAKEN);
                s.hits_given += u64::from(e.kind == EVENT_HIT_GIVEN);
            }
            WorldMsg::Drawing => s.drawing_messages += 1,
        }
        Ok(crate::reader::Flow::Continue)
    })?;
    s.recording = recording;
    Ok(s)
}

impl std::fmt::Display for WorldSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.recording;
        writeln!(f, "world recording {}", r.path.display())?;
        writeln!(
            f,
            "  scene        {} ({} clock), spidar {}",
            r.meta("scene"),
            r.meta("clock"),
            r.meta("spidar_version")
        )?;
        writeln!(
            f,
            "  steps        {} from t = {:.3} s to {:.3} s; {} dropped while recording; {} drawing messages (/world/tf, /world/scene)",
            self.steps, self.first_t_s, self.last_t_s, self.dropped, self.drawing_messages
        )?;
        if let Some(d) = &self.boxer {
            writeln!(
                f,
                "  virtual human {}: attacks {}, blocks {}, avoidances {}, predictions {}; steps attacking L/R {}/{}, blocking {}/{}, avoiding {}",
                if d.active { "active" } else { "passive" },
                d.attacks,
                d.blocks,
                d.avoidances,
                d.predictions,
                self.attack_steps[0],
                self.attack_steps[1],
                self.block_steps[0],
                self.block_steps[1],
                self.avoid_steps
            )?;
            if self.gaze_steps > 0 {
                writeln!(
                    f,
                    "  its gaze      {} steps, a fist attended in {}",
                    self.gaze_steps, self.gaze_attended_steps
                )?;
            }
        }
        if self.characters > 0 {
            writeln!(
                f,
                "  crowd        {} characters, at most {} not balancing at once",
                self.characters, self.most_not_balancing
            )?;
        }
        writeln!(
            f,
            "  events       {} (hits taken {}, given {})",
            self.events, self.hits_taken, self.hits_given
        )?;
        let e = match &r.ending {
            Some(e) => e.to_string(),
            None => "not read to its end".into(),
        };
        write!(f, "  ends         {e}; last step read at t = {:.3} s", self.last_t_s)
    }
}
