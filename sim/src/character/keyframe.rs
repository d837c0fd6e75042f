//! The multidimensional keyframe set (seed 002, section 5): skeleton poses placed at points of the
//! keyframe space Q = {Theta_x, Theta_z, D_x, D_z, B}, and the interpolation that gives the pose at
//! any point of Q.
//!
//! Authoring (section 5.3): a set is a few 1-D keyframe animations, each along one axis of Q on a
//! line of one of two planes of a behaviour's subspace: the *front plane* (Theta_z = 0, D_x = 0:
//! leaning and walking to the front and back) and the *side plane* (Theta_x = 0, D_z = 0). The
//! paper's evaluation set puts all its keyframes there (section 6.1).
//!
//! Interpolation (chosen here; the paper leaves it open). In a plane, keyframes with the same lean
//! form a *row*: a closed loop over the walk phase D in [0, 1) (a row with one keyframe is the same
//! pose at every phase). The pose in a plane is the phase-interpolation of the two rows whose leans
//! bracket the point, blended linearly by lean (held beyond the outermost rows). The two planes are
//! combined as offsets from their shared origin keyframe, `q = q_front * blend(q_origin^-1 q_side)`
//! per joint (the side keyframes are stored as offsets), so a point of either plane gets exactly
//! that plane's pose. Rotations are blended as unit quaternions (normalised weighted sums, signs aligned), never as angles; the root offset linearly.
//! Behaviours are categorical and all adjacent (section 5.2): a change of B is a short blend in time
//! between the two behaviours' poses at the current point, so the pose never jumps.
//!
//! Properties (tested): exact at every keyframe; continuous everywhere, including across the walk
//! phase's wrap from 1 to 0; the change per step is bounded by the change of the point.
//!
//! Must never: allocate while posing (poses are fixed-capacity), or return a non-unit rotation.

use std::collections::BTreeMap;

use glam::{DVec3, Mat4, Quat, Vec3, Vec4};
use serde::Deserialize;
use spidar_config::{self as config, At, Bound, Checker, ConfigError};

use super::skeleton::{Joint, SkeletonPose, MAX_JOINTS};
use crate::spatial::quat_exp;
use crate::SimError;

/// The built-in evaluation set of section 6.1.
pub const KEYFRAMES_HUMANOID_RON: &str = include_str!("../../../configs/keyframes-humanoid.ron");

/// A point of the keyframe space.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct QPoint {
    /// Lean to the front, [-pi, pi] (rad).
    pub theta_x: f64,
    /// Lean to the side, [-pi/2, pi/2] (rad).
    pub theta_z: f64,
    /// Walk phases to the side and to the front, [0, 1).
    pub d_x: f64,
    pub d_z: f64,
    /// Behaviour index into `KeyframeSet::behaviours`.
    pub behaviour: u8,
}

/// A lean described by its direction, for the poses of large leans ([`KeyframeSet::pose_polar`]):
/// the lean toward the front (or back) and toward the side it amounts to, and the share of the
/// lean that is toward the front (1: straight ahead or back, 0: straight to the side).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Lean {
    pub front_rad: f64,
    pub side_rad: f64,
    pub front_share: f64,
}

// ---- file format ----

/// Which axis of Q a 1-D animation runs along.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
pub enum Axis {
    ThetaX,
    ThetaZ,
    Dx,
    Dz,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointFile {
    pub name: String,
    pub parent: Option<String>,
    /// Rest position of the joint in its parent's frame (the root's: in `S_r`) (m).
    pub offset_m: DVec3,
}

/// Where a 1-D animation's line lies: the coordinates it does not run along.
#[derive(Clone, Copy, Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct LineFile {
    #[serde(default)]
    pub theta_x_deg: f64,
    #[serde(default)]
    pub theta_z_deg: f64,
    #[serde(default)]
    pub d_x: f64,
    #[serde(default)]
    pub d_z: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyFile {
    /// Position along the animation's axis (degrees for leans, phase in [0, 1) for walks).
    pub at: f64,
    /// Joint rotations as rotation vectors in degrees; joints not named are at rest.
    #[serde(default)]
    pub pose: BTreeMap<String, DVec3>,
    /// Offset of the root joint from its rest position (m).
    #[serde(default)]
    pub root_m: DVec3,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnimationFile {
    pub name: String,
    pub behaviour: String,
    pub along: Axis,
    pub line: LineFile,
    pub keys: Vec<KeyFile>,
}

/// The legs that stand on the controller's feet: the ankle joints (their parents are the knees,
/// the knees' parents the hips) and the ankle's height above the sole.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LegsFile {
    pub ankles: (String, String),
    pub ankle_height_m: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframeFile {
    pub version: u32,
    pub name: String,
    pub stride_front_m: f64,
    pub stride_side_m: f64,
    pub behaviour_blend_s: f64,
    pub behaviours: Vec<String>,
    pub skeleton: Vec<JointFile>,
    #[serde(default)]
    pub legs: Option<LegsFile>,
    pub animations: Vec<AnimationFile>,
}

/// Largest length in a keyframe file (m): joint offsets, strides, root offsets. A skeleton or a
/// stride larger than this is a typo.
pub const LENGTH_MAX_M: f64 = 100.0;
/// Most animations in a set and keyframes in one animation.
pub const ANIMATIONS_MAX: usize = 1024;
pub const KEYS_MAX: usize = 1024;

// ---- the built set ----

/// One keyframe pose, joint rotations only up to the skeleton's length.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Key {
    phase: f64,
    pose: SkeletonPose,
}

#[derive(Clone, Debug)]
struct Row {
    lean: f64,
    keys: Vec<Key>,
    /// `keys[i].phase`, contiguous: posing searches these every step, and searching them inside
    /// the (large) keys touched a cache line per probe.
    phases: Vec<f64>,
    /// `1 / (phase of the next key - phase of key i)` around the loop: posing multiplies instead
    /// of dividing (filled by `Plane::align`).
    inv_span: Vec<f64>,
}

#[derive(Clone, Debug, Default)]
struct Plane {
    rows: Vec<Row>,
    /// `rows[i].lean`, contiguous (as `Row::phases`).
    leans: Vec<f64>,
    /// `1 / (leans[i + 1] - leans[i])` (filled by `Plane::align`).
    inv_lean_gap: Vec<f64>,
    /// Every pair of keyframes that can be blended together has its quaternions in the same
    /// hemisphere for every joint, so blending needs no per-step sign test (see `align`).
    aligned: bool,
}

#[derive(Clone, Debug)]
struct Subspace {
    front: Plane,
    side: Plane,
    /// The pose at the origin of the subspace (the side plane's keys are offsets from it).
    origin: SkeletonPose,
}

/// A keyframe as it was placed in Q, for tests and tools.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlacedKey {
    pub at: QPoint,
    pub pose: SkeletonPose,
}

/// A loaded, validated multidimensional keyframe set.
#[derive(Clone, Debug)]
pub struct KeyframeSet {
    pub name: String,
    pub joints: Vec<Joint>,
    pub behaviours: Vec<String>,
    /// Distance walked per walk cycle to the front and to the side (m): eqs 8, 9 with a stride.
    pub stride_front_m: f64,
    pub stride_side_m: f64,
    pub behaviour_blend_s: f64,
    pub animations: usize,
    pub keys: Vec<PlacedKey>,
    /// The legs posed onto the feet, if the file names them.
    pub legs: Option<super::legs::Legs>,
    /// Joints `0..posed` are interpolated; the rest are leaves no keyframe turns (their rotation
    /// moves nothing), left at rest. List leaves last in the skeleton and posing skips them.
    pub posed: usize,
    sub: Vec<Subspace>,
}

const SAME: f64 = 1e-9;

impl KeyframeSet {
    /// The built-in humanoid evaluation set.
    pub fn builtin() -> KeyframeSet {
        KeyframeSet::parse(KEYFRAMES_HUMANOID_RON, "configs/keyframes-humanoid.ron (built in)")
            .expect("the built-in keyframe set is valid (tested)")
    }

    pub fn load(path: &std::path::Path) -> Result<KeyframeSet, SimError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SimError::Io { path: path.display().to_string(), message: e.to_string() })?;
        KeyframeSet::parse(&text, &path.display().to_string())
    }

    /// Parses and validates a keyframe-set file; errors name the file, line, column and field.
    /// One function per part of the file: the header, the skeleton, the legs, the keyframes of the
    /// animations, and the behaviours' subspaces built from them.
    pub fn parse(text: &str, origin: &str) -> Result<KeyframeSet, SimError> {
        let f: KeyframeFile = config::parse_kind(text, origin, config::FileKind::Keyframes)?;
        let c = Checker::new(text, origin);
        c.version(f.version, 1)?;
        check_header(&c, &f)?;
        let joints = check_skeleton(&c, &f.skeleton)?;
        let legs = f.legs.as_ref().map(|l| check_legs(&c, l, &joints)).transpose()?;
        let (keys, planes) = place_keys(&c, &f, &joints)?;
        let sub = subspaces(&c, &f.behaviours, &keys, planes, joints.len())?;
        let posed = posed_joints(&joints, &keys);
        Ok(KeyframeSet {
            posed,
            name: f.name,
            joints,
            behaviours: f.behaviours,
            stride_front_m: f.stride_front_m,
            stride_side_m: f.stride_side_m,
            behaviour_blend_s: f.behaviour_blend_s,
            animations: f.animations.len(),
            keys,
            legs,
            sub,
        })
    }

    /// The pose at a point of Q (no behaviour blend).
    pub fn pose(&self, q: &QPoint, out: &mut SkeletonPose) {
        let n = self.posed;
        let s = &self.sub[(q.behaviour as usize).min(self.sub.len() - 1)];
        if s.side.rows.is_empty() || s.front.rows.is_empty() {
            let w = if s.side.rows.is_empty() {
                s.front.weights(q.theta_x, q.d_z)
            } else {
                s.side.weights(q.theta_z, q.d_x)
            };
            out.root_m = root4(&w);
            let w32 = weights32(&w, if s.side.rows.is_empty() { s.front.aligned } else { s.side.aligned });
            for j in 0..n {
                out.rot[j] = blend4(&w, &w32, j);
            }
            normalize_joints(&mut out.rot, n);
            return;
        }
        let f = s.front.weights(q.theta_x, q.d_z);
        let d = s.side.weights(q.theta_z, q.d_x);
        out.root_m = root4(&f) + root4(&d);
        let (f32w, d32w) = (weights32(&f, s.front.aligned), weights32(&d, s.side.aligned));
        for j in 0..n {
            // Normalising once at the end is enough: a product of unnormalised quaternions scales.
            out.rot[j] = blend4(&f, &f32w, j) * blend4(&d, &d32w, j);
        }
        normalize_joints(&mut out.rot, n);
    }

    /// The pose for a large lean, by its direction (see [`Lean`]): the front plane's pose at the
    /// lean toward the front or back and the side plane's at the lean toward the side, blended by
    /// how much of the lean is in each direction. A body lying down and rolling between its side
    /// and its face moves between the lying poses, never through the poses of falling.
    pub fn pose_polar(&self, lean: &Lean, d_x: f64, d_z: f64, behaviour: u8, out: &mut SkeletonPose) {
        let n = self.posed;
        let s = &self.sub[(behaviour as usize).min(self.sub.len() - 1)];
        let (wf, ws) = (lean.front_share, 1.0 - lean.front_share);
        let front = (!s.front.rows.is_empty() && wf > 0.0).then(|| s.front.weights(lean.front_rad, d_z));
        let side = (!s.side.rows.is_empty() && ws > 0.0).then(|| s.side.weights(lean.side_rad, d_x));
        let (wf, ws) = match (&front, &side) {
            (Some(_), None) => (1.0, 0.0),
            (None, Some(_)) => (0.0, 1.0),
            (None, None) => {
                *out = s.origin;
                return;
            }
            _ => (wf, ws),
        };
        out.root_m = Vec3::ZERO;
        if let Some(f) = &front {
            out.root_m += root4(f) * wf as f32;
        }
        if let Some(d) = &side {
            // The side keys are offsets from the origin.
            let root = if s.front.rows.is_empty() { Vec3::ZERO } else { s.origin.root_m };
            out.root_m += (root + root4(d)) * ws as f32;
        }
        let f32w = front.as_ref().map(|f| weights32(f, s.front.aligned));
        let d32w = side.as_ref().map(|d| weights32(d, s.side.aligned));
        for j in 0..n {
            let qf = match (&front, &f32w) {
                (Some(f), Some(w)) => blend4(f, w, j).normalize(),
                _ => Quat::IDENTITY,
            };
            let qs = match (&side, &d32w) {
                (Some(d), Some(w)) => {
                    let off = blend4(d, w, j).normalize();
                    if s.front.rows.is_empty() {
                        off
                    } else {
                        s.origin.rot[j] * off
                    }
                }
                _ => Quat::IDENTITY,
            };
            out.rot[j] = if front.is_none() {
                qs
            } else if side.is_none() {
                qf
            } else {
                nlerp2(qf, wf as f32, qs, ws as f32)
            };
        }
    }

    /// The pose at `q` blended with behaviour `from` by weight `1 - w` (w = 1: only `q`'s).
    pub fn pose_blended(&self, q: &QPoint, from: u8, w: f64, out: &mut SkeletonPose) {
        self.pose(q, out);
        if w >= 1.0 || from == q.behaviour {
            return;
        }
        let mut other = SkeletonPose::default();
        self.pose(&QPoint { behaviour: from, ..*q }, &mut other);
        let n = self.joints.len();
        for j in 0..n {
            out.rot[j] = nlerp2(other.rot[j], 1.0 - w as f32, out.rot[j], w as f32);
        }
        out.root_m = other.root_m * (1.0 - w as f32) + out.root_m * w as f32;
    }

    /// Planes (front and side of every behaviour) whose keyframes blend without sign tests.
    pub fn aligned_planes(&self) -> (usize, usize) {
        let planes = self.sub.iter().flat_map(|s| [&s.front, &s.side]).filter(|p| !p.rows.is_empty());
        planes.fold((0, 0), |(a, n), p| (a + p.aligned as usize, n + 1))
    }

    pub fn behaviour_index(&self, name: &str) -> Option<u8> {
        self.behaviours.iter().position(|b| b == name).map(|i| i as u8)
    }
}

// ---- checking a keyframe file, part by part (called by `KeyframeSet::parse`) ----

/// Lengths of the file (strides, joint and root offsets): longer is a typo.
const LENGTH_M: Bound =
    Bound::hard("length", 0.0, LENGTH_MAX_M, "m", "a skeleton or a stride longer than 100 m is a typo");
/// The blend between two behaviours.
const BLEND_S: Bound =
    Bound::hard("behaviour_blend_s", 1e-9, 60.0, "s", "a blend takes some time, and less than a minute");
/// Ankles above the sole.
const ANKLE_HEIGHT_M: Bound = Bound::hard("ankle_height_m", 0.0, 1.0, "m", "an ankle sits on its sole");

/// The strides, the blend time and how many of each list the file holds.
fn check_header(c: &Checker, f: &KeyframeFile) -> Result<(), ConfigError> {
    for (key, v) in [("stride_front_m", f.stride_front_m), ("stride_side_m", f.stride_side_m)] {
        c.positive(&At::key(key), v, "m", "a walk cycle moves the body")?;
        c.within(&At::key(key), v, &LENGTH_M)?;
    }
    c.within(&At::key("behaviour_blend_s"), f.behaviour_blend_s, &BLEND_S)?;
    c.count(&At::key("animations"), f.animations.len(), 1, ANIMATIONS_MAX, "animations")?;
    c.count(&At::key("skeleton"), f.skeleton.len(), 1, MAX_JOINTS, "joints")?;
    c.count(&At::key("behaviours"), f.behaviours.len(), 1, 255, "behaviours")
}

/// The joints: the first is the root, every other names an earlier joint as its parent, names are
/// unique and offsets bounded.
fn check_skeleton(c: &Checker, skeleton: &[JointFile]) -> Result<Vec<Joint>, ConfigError> {
    let mut joints: Vec<Joint> = Vec::new();
    for (i, j) in skeleton.iter().enumerate() {
        let parent_at = At::new(format!("skeleton[{i}].parent"), "parent", i);
        let parent = match &j.parent {
            None => {
                c.ensure(i == 0, &parent_at, || "only the first joint is the root; name a parent".into())?;
                None
            }
            Some(p) => {
                let k = joints.iter().position(|o| &o.name == p);
                c.ensure(k.is_some(), &parent_at, || {
                    format!("parent {p:?} is not a joint listed before {:?}", j.name)
                })?;
                k
            }
        };
        // The set's own `name` comes first in the text.
        c.ensure(
            !joints.iter().any(|o| o.name == j.name),
            &At::new(format!("skeleton[{i}].name"), "name", i + 1),
            || format!("joint name {:?} is used twice", j.name),
        )?;
        let offset_at = At::new(format!("skeleton[{i}].offset_m"), "offset_m", i);
        c.ensure(j.offset_m.is_finite(), &offset_at, || format!("{}: must be finite numbers", j.offset_m))?;
        c.within(&offset_at, j.offset_m.length(), &LENGTH_M)?;
        joints.push(Joint { name: j.name.clone(), parent, offset_m: j.offset_m });
    }
    Ok(joints)
}

/// The legs: two ankles of the skeleton, at a height above their soles.
fn check_legs(c: &Checker, l: &LegsFile, joints: &[Joint]) -> Result<super::legs::Legs, ConfigError> {
    let at = At::new("legs.ankles", "ankles", 0);
    let find = |name: &str| {
        let k = joints.iter().position(|j| j.name == name);
        c.ensure(k.is_some(), &at, || format!("no joint {name:?} in the skeleton")).map(|()| k.unwrap_or(0))
    };
    let (left, right) = (find(&l.ankles.0)?, find(&l.ankles.1)?);
    c.within(&At::new("legs.ankle_height_m", "ankle_height_m", 0), l.ankle_height_m, &ANKLE_HEIGHT_M)?;
    super::legs::Legs::new(joints, [left, right], l.ankle_height_m as f32).map_err(|m| c.error(&at, m))
}

/// Each behaviour's front and side planes, as the keyframes are placed in them.
type Planes = Vec<(Plane, Plane)>;

/// Every keyframe of every animation placed in Q and in its behaviour's front and side planes.
/// Two keyframes at one point must agree.
fn place_keys(
    c: &Checker,
    f: &KeyframeFile,
    joints: &[Joint],
) -> Result<(Vec<PlacedKey>, Planes), ConfigError> {
    let mut planes: Planes = vec![(Plane::default(), Plane::default()); f.behaviours.len()];
    let mut keys: Vec<PlacedKey> = Vec::new();
    let mut seen = KeysSeen { keys: 0, roots: 0 };
    for (ai, a) in f.animations.iter().enumerate() {
        let field = |s: &str| format!("animations[{ai}].{s}");
        let b = f.behaviours.iter().position(|x| x == &a.behaviour);
        c.ensure(b.is_some(), &At::new(field("behaviour"), "behaviour", ai + 1), || {
            format!("behaviour {:?} is not in `behaviours` {:?}", a.behaviour, f.behaviours)
        })?;
        let b = b.unwrap_or(0) as u8;
        c.count(&At::new(field("keys"), "keys", ai), a.keys.len(), 1, KEYS_MAX, "keyframes in an animation")?;
        let l = &a.line;
        let line_at = At::new(field("line"), "line", ai);
        c.ensure(
            [l.theta_x_deg, l.theta_z_deg, l.d_x, l.d_z].iter().all(|v| v.is_finite()),
            &line_at,
            || "the line's coordinates must be finite numbers".into(),
        )?;
        for (ki, k) in a.keys.iter().enumerate() {
            let (at, pose) = check_key(c, (ai, a), (ki, k), b, joints, &mut seen)?;
            let kf = At::new(field(&format!("keys[{ki}].at")), "at", seen.keys + ki);
            let in_front = at.theta_z.abs() < SAME && at.d_x.abs() < SAME;
            let in_side = at.theta_x.abs() < SAME && at.d_z.abs() < SAME;
            c.ensure(in_front || in_side, &line_at, || {
                "a keyframe must lie in the front plane (Theta_z = 0, D_x = 0) or the side plane (Theta_x = 0, \
                 D_z = 0); move its line"
                    .into()
            })?;
            if let Some(o) = keys.iter().find(|o| same_point(&o.at, &at)) {
                c.ensure(o.pose == pose, &kf, || {
                    "another keyframe sits at this point of Q with a different pose; a point has one pose"
                        .into()
                })?;
                continue;
            }
            keys.push(PlacedKey { at, pose });
            let (front, side) = &mut planes[usize::from(b)];
            if in_front {
                front.insert(at.theta_x, at.d_z, pose);
            }
            if in_side {
                side.insert(at.theta_z, at.d_x, pose);
            }
        }
        seen.keys += a.keys.len();
    }
    Ok((keys, planes))
}

/// How many `at:` and `root_m:` entries came before: they locate a key's values in the text.
struct KeysSeen {
    keys: usize,
    /// `root_m` is optional: its n-th appearance in the text is the n-th key that sets it.
    roots: usize,
}

/// One keyframe: its point of Q (the animation's line moved along its axis) within the leans and
/// phases Q allows, and its pose over the skeleton's joints.
fn check_key(
    c: &Checker,
    (ai, a): (usize, &AnimationFile),
    (ki, k): (usize, &KeyFile),
    behaviour: u8,
    joints: &[Joint],
    seen: &mut KeysSeen,
) -> Result<(QPoint, SkeletonPose), ConfigError> {
    let field = |s: &str| format!("animations[{ai}].keys[{ki}].{s}");
    let kf = At::new(field("at"), "at", seen.keys + ki);
    c.ensure(k.at.is_finite(), &kf, || "positions in Q must be finite numbers".into())?;
    let root = At::new(field("root_m"), "root_m", seen.roots);
    c.ensure(k.root_m.is_finite(), &root, || format!("{}: must be finite numbers", k.root_m))?;
    c.within(&root, k.root_m.length(), &LENGTH_M)?;
    seen.roots += usize::from(k.root_m != DVec3::ZERO);
    let l = &a.line;
    let mut at = QPoint {
        theta_x: l.theta_x_deg.to_radians(),
        theta_z: l.theta_z_deg.to_radians(),
        d_x: l.d_x,
        d_z: l.d_z,
        behaviour,
    };
    match a.along {
        Axis::ThetaX => at.theta_x = k.at.to_radians(),
        Axis::ThetaZ => at.theta_z = k.at.to_radians(),
        Axis::Dx => at.d_x = k.at,
        Axis::Dz => at.d_z = k.at,
    }
    let leans_ok = at.theta_x.abs() <= std::f64::consts::PI + SAME
        && at.theta_z.abs() <= std::f64::consts::FRAC_PI_2 + SAME;
    c.ensure(leans_ok, &kf, || {
        "leans must be within Theta_x in [-180, 180], Theta_z in [-90, 90] degrees".into()
    })?;
    let phases_ok = (0.0..1.0).contains(&at.d_x) && (0.0..1.0).contains(&at.d_z);
    c.ensure(phases_ok, &kf, || "walk phases must be in [0, 1)".into())?;
    let mut pose = SkeletonPose { root_m: k.root_m.as_vec3(), ..SkeletonPose::default() };
    let pose_at = At::new(field("pose"), "pose", seen.keys + ki);
    for (name, rv) in &k.pose {
        let j = joints.iter().position(|j| &j.name == name);
        c.ensure(j.is_some(), &pose_at, || format!("no joint {name:?} in the skeleton"))?;
        c.ensure(rv.is_finite() && rv.length() <= 36_000.0, &pose_at, || {
            format!("joint {name:?} has a non-finite rotation")
        })?;
        pose.rot[j.unwrap_or(0)] = quat_exp(*rv * (std::f64::consts::PI / 180.0)).as_quat();
    }
    Ok((at, pose))
}

/// Each behaviour's subspace from its planes: every behaviour has keyframes, and one with a side
/// plane has a front plane and an origin keyframe both share (the side keys become offsets from
/// it, so posing blends offsets and applies them with one product per joint).
fn subspaces(
    c: &Checker,
    behaviours: &[String],
    keys: &[PlacedKey],
    planes: Planes,
    n_joints: usize,
) -> Result<Vec<Subspace>, ConfigError> {
    let mut sub = Vec::with_capacity(planes.len());
    for (b, (mut front, mut side)) in planes.into_iter().enumerate() {
        c.ensure(!(front.rows.is_empty() && side.rows.is_empty()), &At::key("behaviours"), || {
            format!("behaviour {:?} has no keyframes", behaviours[b])
        })?;
        let origin = QPoint { behaviour: b as u8, ..QPoint::default() };
        let origin_key = keys.iter().find(|k| k.at.behaviour == b as u8 && same_point(&k.at, &origin));
        c.ensure(side.rows.is_empty() || (origin_key.is_some() && !front.rows.is_empty()), &At::key("animations"), || {
            format!(
                "behaviour {:?} has side-plane keyframes, so it needs keyframes in the front plane and one at the \
                 origin (all leans and phases 0) that both planes share",
                behaviours[b]
            )
        })?;
        let o = origin_key.map(|k| k.pose).unwrap_or_default();
        if !front.rows.is_empty() {
            let origin_inv: [Quat; MAX_JOINTS] = std::array::from_fn(|j| o.rot[j].inverse());
            for k in side.rows.iter_mut().flat_map(|row| row.keys.iter_mut()) {
                for j in 0..MAX_JOINTS {
                    let q = origin_inv[j].as_dquat() * k.pose.rot[j].as_dquat();
                    k.pose.rot[j] = q.normalize().as_quat();
                }
                k.pose.root_m -= o.root_m;
            }
        }
        front.align(n_joints);
        side.align(n_joints);
        sub.push(Subspace { front, side, origin: o });
    }
    Ok(sub)
}

/// How many leading joints posing must interpolate: up to the last joint that has a child or that
/// some keyframe turns.
fn posed_joints(joints: &[Joint], keys: &[PlacedKey]) -> usize {
    let mut last = 0;
    for (i, _) in joints.iter().enumerate() {
        let parent = joints.iter().any(|c| c.parent == Some(i));
        let turned = keys.iter().any(|k| k.pose.rot[i] != Quat::IDENTITY);
        if parent || turned {
            last = i + 1;
        }
    }
    last.max(1)
}

fn same_point(a: &QPoint, b: &QPoint) -> bool {
    a.behaviour == b.behaviour
        && (a.theta_x - b.theta_x).abs() < SAME
        && (a.theta_z - b.theta_z).abs() < SAME
        && (a.d_x - b.d_x).abs() < SAME
        && (a.d_z - b.d_z).abs() < SAME
}

impl Plane {
    /// Flips keyframe quaternions (q and -q are the same rotation) into the hemisphere of the
    /// plane's first keyframe, joint by joint, and records whether that makes every blendable pair
    /// (neighbours on a row, including across the wrap, and any two keyframes of adjacent rows)
    /// agree in sign. Where it does not, posing keeps the sign test.
    fn align(&mut self, n: usize) {
        self.inv_lean_gap = self.leans.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect();
        for row in &mut self.rows {
            let k = row.phases.len();
            row.inv_span = (0..k)
                .map(|i| {
                    let (pa, mut pb) = (row.phases[i], row.phases[(i + 1) % k]);
                    if pb <= pa {
                        pb += 1.0;
                    }
                    1.0 / (pb - pa)
                })
                .collect();
        }
        let Some(first) = self.rows.first().and_then(|r| r.keys.first()).map(|k| k.pose) else {
            self.aligned = true;
            return;
        };
        for row in &mut self.rows {
            for k in &mut row.keys {
                for j in 0..n {
                    if k.pose.rot[j].dot(first.rot[j]) < 0.0 {
                        k.pose.rot[j] = -k.pose.rot[j];
                    }
                }
            }
        }
        let agree = |a: &Key, b: &Key| (0..n).all(|j| a.pose.rot[j].dot(b.pose.rot[j]) >= 0.0);
        let mut ok = true;
        for (r, row) in self.rows.iter().enumerate() {
            let k = &row.keys;
            for i in 0..k.len() {
                ok &= agree(&k[i], &k[(i + 1) % k.len()]);
            }
            if let Some(next) = self.rows.get(r + 1) {
                ok &= k.iter().all(|a| next.keys.iter().all(|b| agree(a, b)));
            }
        }
        self.aligned = ok;
    }

    fn insert(&mut self, lean: f64, phase: f64, pose: SkeletonPose) {
        let r = match self.rows.iter().position(|r| (r.lean - lean).abs() < SAME) {
            Some(r) => r,
            None => {
                let at = self.rows.partition_point(|r| r.lean < lean);
                self.rows
                    .insert(at, Row { lean, keys: Vec::new(), phases: Vec::new(), inv_span: Vec::new() });
                self.leans.insert(at, lean);
                at
            }
        };
        let row = &mut self.rows[r];
        let at = row.keys.partition_point(|k| k.phase < phase);
        row.keys.insert(at, Key { phase, pose });
        row.phases.insert(at, phase);
    }

    /// The (up to) four keyframes around a point of the plane and their weights (sum 1).
    #[inline(always)]
    fn weights(&self, lean: f64, phase: f64) -> [(&SkeletonPose, f64); 4] {
        let rows = &self.rows;
        let hi = count_le(&self.leans, lean);
        if hi == 0 || hi == rows.len() {
            let r = &rows[if hi == 0 { 0 } else { rows.len() - 1 }];
            let (k0, k1, t) = r.bracket(phase);
            return [(&k0.pose, 1.0 - t), (&k1.pose, t), (&k0.pose, 0.0), (&k0.pose, 0.0)];
        }
        let (r0, r1) = (&rows[hi - 1], &rows[hi]);
        let u = (lean - r0.lean) * self.inv_lean_gap[hi - 1];
        let (a0, a1, ta) = r0.bracket(phase);
        let (b0, b1, tb) = r1.bracket(phase);
        [
            (&a0.pose, (1.0 - u) * (1.0 - ta)),
            (&a1.pose, (1.0 - u) * ta),
            (&b0.pose, u * (1.0 - tb)),
            (&b1.pose, u * tb),
        ]
    }
}

impl Row {
    /// The two keyframes around `phase` on the closed loop [0, 1) and the weight of the second.
    #[inline(always)]
    fn bracket(&self, phase: f64) -> (&Key, &Key, f64) {
        let k = &self.keys;
        if k.len() == 1 {
            return (&k[0], &k[0], 0.0);
        }
        // Phases from the correspondence are already in [0, 1): no floor (a libm call) for them.
        let p = if (0.0..1.0).contains(&phase) { phase } else { phase - phase.floor() };
        let i = count_le(&self.phases, p);
        let (a, b) = if i == 0 || i == k.len() { (k.len() - 1, 0) } else { (i - 1, i) };
        let pa = self.phases[a];
        let pp = if p < pa { p + 1.0 } else { p };
        (&k[a], &k[b], ((pp - pa) * self.inv_span[a]).clamp(0.0, 1.0))
    }
}

/// How many of the sorted `xs` are `<= x` (`partition_point(|v| v <= x)`): the lists are a few
/// keys long, and independent comparisons beat a binary search's chain of dependent loads.
#[inline(always)]
fn count_le(xs: &[f64], x: f64) -> usize {
    xs.iter().map(|&v| (v <= x) as usize).sum()
}

/// Weights in single precision and the index of the heaviest (the sign reference; `usize::MAX`
/// when the plane is pre-aligned and no sign test is needed).
#[inline]
fn weights32(w: &[(&SkeletonPose, f64); 4], aligned: bool) -> ([f32; 4], usize) {
    let w32 = [w[0].1 as f32, w[1].1 as f32, w[2].1 as f32, w[3].1 as f32];
    if aligned {
        return (w32, usize::MAX);
    }
    let mut heavy = 0;
    for i in 1..4 {
        if w[i].1 > w[heavy].1 {
            heavy = i;
        }
    }
    (w32, heavy)
}

/// Weighted sum of one joint's rotations (signs aligned with the heaviest), not normalised.
#[inline]
fn blend4(w: &[(&SkeletonPose, f64); 4], (wt, heavy): &([f32; 4], usize), j: usize) -> Quat {
    if *heavy == usize::MAX {
        let q = |i: usize| w[i].0.rot[j] * wt[i];
        return q(0) + q(1) + q(2) + q(3);
    }
    let r = w[*heavy].0.rot[j];
    let mut acc = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    for i in 0..4 {
        let q = w[i].0.rot[j];
        let s = if q.dot(r) < 0.0 { -wt[i] } else { wt[i] };
        acc += q * s;
    }
    acc
}

/// Normalises the first `n` joint rotations four at a time: one square root and one division
/// for four joints (one joint at a time, their latency was most of the cost of posing).
#[inline]
fn normalize_joints(rot: &mut [Quat; MAX_JOINTS], n: usize) {
    for c in (0..n.min(MAX_JOINTS)).step_by(4) {
        let q = |j: usize| Vec4::from(rot[j]);
        // Rows are the joints' x, y, z, w: the sum of the squared rows is the four lengths squared.
        let m = Mat4::from_cols(q(c), q(c + 1), q(c + 2), q(c + 3)).transpose();
        let len2 = m.x_axis * m.x_axis + m.y_axis * m.y_axis + m.z_axis * m.z_axis + m.w_axis * m.w_axis;
        let inv = Vec4::ONE / Vec4::from_array(len2.to_array().map(f32::sqrt));
        for k in 0..4.min(n - c) {
            rot[c + k] = Quat::from_vec4(Vec4::from(rot[c + k]) * inv[k]);
        }
    }
}

#[inline]
fn root4(w: &[(&SkeletonPose, f64); 4]) -> Vec3 {
    let r = |i: usize| w[i].0.root_m * w[i].1 as f32;
    r(0) + r(1) + r(2) + r(3)
}

#[inline]
fn nlerp2(a: Quat, wa: f32, b: Quat, wb: f32) -> Quat {
    let b = if a.dot(b) < 0.0 { -b } else { b };
    (a * wa + b * wb).normalize()
}
