//! The RON description language for bodies and scenes, and the builder that turns a scene into
//! a validated `Model`.
//!
//! A *body file* (`configs/body-upper.ron`, a character file) describes one articulation: links,
//! each with the joint to its parent, a mass, and collision shapes. A *scene file*
//! (`configs/scene-boxing.ron`) sets the step, gravity and contact gains, places static scenery,
//! and instantiates body files as named actors. Gains may be absolute or "rates" (fractions of the
//! critical gain, `docs/reference.md` section 4): `K = 2 rate m / dt^2`, `D = rate m / dt`.
//!
//! Must never: accept a file it cannot build faithfully. Every error names the file, line,
//! column and field and says what to change.

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use serde::Deserialize;
use spidar_config::{self as config, At, Bound, Checker, ConfigError};

use crate::collide::{Shape, ShapePose};
use crate::joint::{write_quat, JointKind, MAX_JOINT_DOF};
use crate::model::{
    box_inertia, ellipsoid_inertia, shape_bound, Articulation, Body, ContactParams, LimitParams, Model, Part,
    ShapeInst, Side,
};
use crate::spatial::{quat_exp, SInertia, Xform};
use crate::SimError;

/// The built-in upper-body description (26 DOF, boxing guard).
pub const BODY_UPPER_RON: &str = include_str!("../../configs/body-upper.ron");
/// The built-in two-boxer scene.
pub const SCENE_BOXING_RON: &str = include_str!("../../configs/scene-boxing.ron");

/// A gain given absolutely or as a fraction of the critical gain.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub enum Gain {
    /// Absolute value in the field's unit.
    Abs(f64),
    /// Dimensionless rate: stiffness `2 rate m / dt^2`, damping `rate m / dt`.
    Rate(f64),
}

impl Gain {
    pub fn stiffness(self, mass_kg: f64, dt_s: f64) -> f64 {
        match self {
            Gain::Abs(k) => k,
            Gain::Rate(r) => 2.0 * r * mass_kg / (dt_s * dt_s),
        }
    }
    pub fn damping(self, mass_kg: f64, dt_s: f64) -> f64 {
        match self {
            Gain::Abs(d) => d,
            Gain::Rate(r) => r * mass_kg / dt_s,
        }
    }
    pub(crate) fn value(self) -> f64 {
        match self {
            Gain::Abs(v) | Gain::Rate(v) => v,
        }
    }
}

/// Largest size of a shape (m), distance of anything from the origin (m), mass (kg), principal
/// inertia (kg m^2) and number of links a description may have: far beyond any rig, body or scene,
/// and small enough that products of them stay finite. Larger values are typos.
pub const SIZE_MAX_M: f64 = 1e3;
pub const POSITION_MAX_M: f64 = 1e5;
pub const MASS_MAX_KG: f64 = 1e6;
pub const INERTIA_MAX_KG_M2: f64 = 1e9;
pub const LINKS_MAX: usize = 256;
/// Largest gain (N/m, N s/m, N m/rad) or rate a description may give.
pub const GAIN_MAX: f64 = 1e12;

/// `v` is finite and within `max` of zero in every component.
fn bounded(v: DVec3, max: f64) -> bool {
    v.is_finite() && v.abs().max_element() <= max
}

impl ContactDesc {
    /// Checks the gains and friction: an error gives the field and what to do.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let (k, d) = (self.stiffness.value(), self.damping.value());
        if !(k > 0.0 && k <= GAIN_MAX) {
            return Err(("stiffness", format!("must be > 0 and at most {GAIN_MAX:e}, got {k}")));
        }
        if !(0.0..=GAIN_MAX).contains(&d) {
            return Err(("damping", format!("must be >= 0 and at most {GAIN_MAX:e}, got {d}")));
        }
        if let Gain::Rate(r) = self.stiffness {
            // Explicit penalty springs are stable for K dt^2 / m < 4 at the pair's effective mass,
            // which is below the reduced segment mass the rate uses: keep a margin.
            if r > 1.0 {
                return Err((
                    "stiffness",
                    format!("a contact stiffness rate of {r} is unstable with an explicit penalty (K dt^2/m = {}); use <= 1", 2.0 * r),
                ));
            }
        }
        if !(self.friction >= 0.0 && self.friction <= 100.0) {
            return Err(("friction", format!("must be in [0, 100], got {}", self.friction)));
        }
        if !(self.slip_m_per_s > 0.0 && self.slip_m_per_s <= 100.0) {
            return Err(("slip_m_per_s", format!("must be in (0, 100] m/s, got {}", self.slip_m_per_s)));
        }
        Ok(())
    }
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum ShapeDesc {
    Sphere {
        radius_m: f64,
    },
    /// Along the shape's local y axis.
    Capsule {
        half_length_m: f64,
        radius_m: f64,
    },
    Box {
        size_m: DVec3,
    },
    Plane,
}

impl ShapeDesc {
    /// The collision shape this describes (box sizes are full sizes here, half extents there).
    pub fn to_shape(self) -> Shape {
        match self {
            ShapeDesc::Sphere { radius_m } => Shape::Sphere { radius_m },
            ShapeDesc::Capsule { half_length_m, radius_m } => Shape::Capsule { half_length_m, radius_m },
            ShapeDesc::Box { size_m } => Shape::Box { half_extents_m: size_m * 0.5 },
            ShapeDesc::Plane => Shape::Plane,
        }
    }
    pub fn check(&self) -> Result<(), String> {
        let size = |v: f64| v > 0.0 && v <= SIZE_MAX_M;
        let ok = match *self {
            ShapeDesc::Sphere { radius_m } => size(radius_m),
            ShapeDesc::Capsule { half_length_m, radius_m } => {
                size(radius_m) && (0.0..=SIZE_MAX_M).contains(&half_length_m)
            }
            // Component by component: `min_element` would pass over a NaN.
            ShapeDesc::Box { size_m } => size(size_m.x) && size(size_m.y) && size(size_m.z),
            ShapeDesc::Plane => true,
        };
        if ok {
            Ok(())
        } else {
            Err(format!(
                "sizes must be positive numbers up to {SIZE_MAX_M} m (radius and box sizes > 0, half_length >= 0)"
            ))
        }
    }
}

impl ShapeFile {
    /// Checks the shape and where it is: an error gives what to change.
    pub fn check(&self) -> Result<(), String> {
        self.shape.check()?;
        if !bounded(self.pos_m, POSITION_MAX_M) {
            return Err(format!("pos_m must be finite and within {POSITION_MAX_M} m, got {}", self.pos_m));
        }
        if !bounded(self.rot_deg, 1e5) {
            return Err(format!("rot_deg must be finite, got {}", self.rot_deg));
        }
        Ok(())
    }
}

fn all_groups() -> u32 {
    u32::MAX
}
fn one() -> u32 {
    1
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeFile {
    pub name: String,
    pub shape: ShapeDesc,
    /// Position of the shape's centre in the link (or world) frame.
    #[serde(default)]
    pub pos_m: DVec3,
    /// Orientation as a rotation vector in degrees (a capsule's axis is its local y).
    #[serde(default)]
    pub rot_deg: DVec3,
    #[serde(default = "one")]
    pub group: u32,
    #[serde(default = "all_groups")]
    pub mask: u32,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum MassDesc {
    /// Solid ellipsoid with full sizes, centred at `centre_m` in the link frame.
    Ellipsoid { mass_kg: f64, size_m: DVec3, centre_m: DVec3 },
    /// Solid box with full sizes, centred at `centre_m`.
    Box { mass_kg: f64, size_m: DVec3, centre_m: DVec3 },
    /// Explicit principal inertia about the centre of mass (axes of the link frame).
    Explicit { mass_kg: f64, centre_m: DVec3, inertia_kg_m2: DVec3 },
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointDesc {
    pub kind: JointKind,
    /// Joint position in the parent link's frame (for a root: in the actor's frame).
    pub anchor_m: DVec3,
    /// Default (rest) pose, one value per degree of freedom in degrees: revolute `[angle]`,
    /// universal `[angle1, angle2]`, ball and free `[rx, ry, rz]` as a rotation vector.
    #[serde(default)]
    pub default_deg: Vec<f64>,
    /// Spring toward the default pose (N m/rad), or a rate with this link's mass.
    pub stiffness: Gain,
    /// Damper (N m s/rad), or a rate with this link's mass.
    pub damping: Gain,
    /// Free joints only: translational spring and damper toward the home position (N/m, N s/m).
    #[serde(default)]
    pub linear_stiffness: Option<Gain>,
    #[serde(default)]
    pub linear_damping: Option<Gain>,
    /// Per degree of freedom (min, max) in degrees; ball joints: rotation-vector components.
    #[serde(default)]
    pub limits_deg: Option<Vec<(f64, f64)>>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkDesc {
    pub name: String,
    #[serde(default)]
    pub part: Part,
    #[serde(default)]
    pub side: Side,
    /// Parent link name; `None` for the root.
    pub parent: Option<String>,
    pub joint: JointDesc,
    pub mass: MassDesc,
    #[serde(default)]
    pub shapes: Vec<ShapeFile>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyFile {
    pub version: u32,
    pub name: String,
    /// Where the numbers come from.
    pub source: String,
    /// The time step that `Rate` gains in this file are defined with.
    pub gain_dt_s: f64,
    /// The root's base spring also carries the body's weight (a stand holding an upper body at
    /// its home height), so the base spring only resists what moves it from home.
    #[serde(default)]
    pub base_carries_weight: bool,
    pub links: Vec<LinkDesc>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactDesc {
    /// Penalty spring on depth: N/m or a rate with the pair's reduced mass and the scene step.
    pub stiffness: Gain,
    pub damping: Gain,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// Slip speed below which friction is regularised (m/s).
    pub slip_m_per_s: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitDesc {
    pub stiffness_n_m_per_rad: f64,
    pub damping_n_m_s_per_rad: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorDesc {
    pub name: String,
    /// Body file, relative to the scene file (the built-in scenes may name "body-upper.ron").
    pub body: String,
    /// Actor frame origin in the world.
    pub pos_m: DVec3,
    /// Rotation of the actor frame about the world y axis (the bodies face -z at 0).
    #[serde(default)]
    pub yaw_deg: f64,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub version: u32,
    pub dt_s: f64,
    pub gravity_m_per_s2: DVec3,
    pub contact: ContactDesc,
    pub joint_limit: LimitDesc,
    #[serde(default)]
    pub statics: Vec<ShapeFile>,
    pub actors: Vec<ActorDesc>,
}

/// Parses and validates a body file: the step its gain rates refer to, then each link's place in
/// the tree, its joint, its mass and its shapes, each by its own function.
pub fn parse_body(text: &str, origin: &str) -> Result<BodyFile, SimError> {
    let f: BodyFile = config::parse_kind(text, origin, config::FileKind::Body)?;
    let c = Checker::new(text, origin);
    c.version(f.version, 1)?;
    let dt = c.positive(&At::key("gain_dt_s"), f.gain_dt_s, "s", "the rates are per step")?;
    c.within(&At::key("gain_dt_s"), dt, &GAIN_DT_S)?;
    c.count(&At::key("links"), f.links.len(), 1, LINKS_MAX, "links (a body's)")?;
    let mut shapes_seen = 0;
    for i in 0..f.links.len() {
        check_link_place(&c, &f.links, i)?;
        check_joint(&c, &f, i)?;
        check_mass(&c, i, &f.links[i].mass)?;
        check_shapes(&c, i, &f.links[i].shapes, &mut shapes_seen)?;
    }
    Ok(f)
}

/// The step a body's gain rates are computed for.
const GAIN_DT_S: Bound = Bound::hard("gain_dt_s", 0.0, 1.0, "s", "a simulation step is well under a second");

/// Link `i`'s place in the tree: the first link is the root, every other names an earlier link as
/// its parent, and names are unique.
fn check_link_place(c: &Checker, links: &[LinkDesc], i: usize) -> Result<(), ConfigError> {
    let l = &links[i];
    let at = |key: &'static str| At::new(format!("links[{i}].{key}"), key, i);
    match (&l.parent, i) {
        (None, 0) => {}
        (None, _) => return Err(c.error(&at("parent"), "only the first link may be the root")),
        (Some(_), 0) => return Err(c.error(&at("parent"), "the first link is the root: parent: None")),
        (Some(p), _) => c.ensure(links[..i].iter().any(|o| &o.name == p), &at("parent"), || {
            format!("no earlier link is named {p:?}; list parents before their children")
        })?,
    }
    c.ensure(!links[..i].iter().any(|o| o.name == l.name), &at("name"), || {
        format!("link name {:?} is used twice", l.name)
    })
}

/// Link `i`'s joint: its kind (unit axes, a free joint only at the root), anchor, default angles,
/// gains and limits.
fn check_joint(c: &Checker, f: &BodyFile, i: usize) -> Result<(), ConfigError> {
    let j = &f.links[i].joint;
    let at = |field: &str, key: &'static str| At::new(format!("links[{i}].joint.{field}"), key, i);
    // Optional keys: their n-th appearance in the text is the n-th link that sets them.
    let optional = |field: &str, key: &'static str| {
        At::new(format!("links[{i}].joint.{field}"), key, count_before(key, i, f))
    };
    let unit = |v: DVec3| (v.length() - 1.0).abs() <= 1e-6;
    match j.kind {
        JointKind::Universal { axis1, axis2 } => {
            c.ensure(unit(axis1) && unit(axis2), &at("kind", "kind"), || {
                "joint axes must be unit vectors".into()
            })?
        }
        JointKind::Revolute { axis } => {
            c.ensure(unit(axis), &at("kind", "kind"), || "joint axis must be a unit vector".into())?
        }
        JointKind::Free => {
            c.ensure(i == 0, &at("kind", "kind"), || "only the root may have a free joint".into())?
        }
        _ => {}
    }
    let nv = j.kind.nv();
    let defaults = if matches!(j.kind, JointKind::Free | JointKind::Ball) { 3 } else { nv };
    let n = j.default_deg.len();
    c.ensure(n == 0 || n == defaults, &optional("default_deg", "default_deg"), || {
        format!("a {} joint takes {defaults} default values, got {n}", j.kind.name())
    })?;
    c.finite_within(&at("anchor_m", "anchor_m"), &j.anchor_m.to_array(), POSITION_MAX_M, "m")?;
    c.ensure(j.default_deg.iter().all(|v| v.is_finite()), &optional("default_deg", "default_deg"), || {
        "default angles must be finite".into()
    })?;
    let gain_ok = |g: Gain| g.value() >= 0.0 && g.value() <= GAIN_MAX;
    c.ensure(gain_ok(j.stiffness) && gain_ok(j.damping), &at("stiffness", "stiffness"), || {
        format!("gains must be >= 0 and at most {GAIN_MAX:e}")
    })?;
    let linear = [j.linear_stiffness, j.linear_damping];
    c.ensure(
        linear.iter().flatten().all(|g| gain_ok(*g)),
        &optional("linear_stiffness", "linear_stiffness"),
        || format!("linear gains must be >= 0 and at most {GAIN_MAX:e}"),
    )?;
    if let Some(lims) = &j.limits_deg {
        let n = if matches!(j.kind, JointKind::Free) { 0 } else { nv };
        let ordered = lims.iter().all(|(lo, hi)| lo < hi && lo.is_finite() && hi.is_finite());
        c.ensure(lims.len() == n && ordered, &optional("limits_deg", "limits_deg"), || {
            format!(
                "a {} joint takes {n} (min, max) pairs with min < max (free joints take no limits)",
                j.kind.name()
            )
        })?;
    }
    Ok(())
}

/// Link `i`'s mass: positive and bounded mass and sizes (or inertias), a finite centre.
fn check_mass(c: &Checker, i: usize, mass: &MassDesc) -> Result<(), ConfigError> {
    // Component by component: `min_element` passes over a NaN.
    let positive = |v: DVec3, max: f64| [v.x, v.y, v.z].iter().all(|c| *c > 0.0 && *c <= max);
    let kg_ok = |m: f64| m > 0.0 && m <= MASS_MAX_KG;
    let (ok, centre) = match mass {
        MassDesc::Ellipsoid { mass_kg, size_m, centre_m } | MassDesc::Box { mass_kg, size_m, centre_m } => {
            (kg_ok(*mass_kg) && positive(*size_m, SIZE_MAX_M), *centre_m)
        }
        MassDesc::Explicit { mass_kg, inertia_kg_m2, centre_m } => {
            (kg_ok(*mass_kg) && positive(*inertia_kg_m2, INERTIA_MAX_KG_M2), *centre_m)
        }
    };
    c.ensure(ok && bounded(centre, POSITION_MAX_M), &At::new(format!("links[{i}].mass"), "mass", i), || {
        format!(
            "mass and sizes (or inertias) must be > 0 (at most {MASS_MAX_KG} kg, {SIZE_MAX_M} m, {INERTIA_MAX_KG_M2} \
             kg m^2), and the centre finite"
        )
    })
}

/// Link `i`'s collision shapes: sized, and never a plane (a plane cannot move).
fn check_shapes(c: &Checker, i: usize, shapes: &[ShapeFile], seen: &mut usize) -> Result<(), ConfigError> {
    for (j, s) in shapes.iter().enumerate() {
        let at = At::new(format!("links[{i}].shapes[{j}].shape"), "shape", *seen);
        s.check().map_err(|m| c.error(&at, m))?;
        c.ensure(!matches!(s.shape, ShapeDesc::Plane), &at, || {
            "a plane cannot move; put it in the scene's statics".into()
        })?;
        *seen += 1;
    }
    Ok(())
}

/// Occurrence index of the optional `key` for link `i`: how many earlier links also set it.
fn count_before(key: &str, i: usize, f: &BodyFile) -> usize {
    f.links[..i]
        .iter()
        .filter(|l| match key {
            "default_deg" => !l.joint.default_deg.is_empty(),
            "limits_deg" => l.joint.limits_deg.is_some(),
            _ => true,
        })
        .count()
}

/// Parses and validates a scene file (not the bodies it names).
pub fn parse_scene(text: &str, origin: &str) -> Result<SceneFile, SimError> {
    let f: SceneFile = config::parse_kind(text, origin, config::FileKind::BodyScene)?;
    let c = Checker::new(text, origin);
    c.version(f.version, 1)?;
    c.positive(&At::key("dt_s"), f.dt_s, "s", "the world steps forward")?;
    c.within(&At::key("dt_s"), f.dt_s, &SCENE_DT_S)?;
    c.finite_within(&At::key("gravity_m_per_s2"), &f.gravity_m_per_s2.to_array(), 1000.0, "m/s^2")?;
    f.contact.check().map_err(|(key, m)| c.error(&At::new(format!("contact.{key}"), key, 0), m))?;
    let lim = &f.joint_limit;
    let lim_ok = |v: f64| (0.0..=GAIN_MAX).contains(&v);
    c.ensure(
        lim_ok(lim.stiffness_n_m_per_rad) && lim_ok(lim.damping_n_m_s_per_rad),
        &At::key("joint_limit"),
        || format!("limit gains must be >= 0 and at most {GAIN_MAX:e}"),
    )?;
    for (i, s) in f.statics.iter().enumerate() {
        s.check().map_err(|m| c.error(&At::new(format!("statics[{i}].shape"), "shape", i), m))?;
    }
    c.ensure(!f.actors.is_empty(), &At::key("actors"), || "a scene needs at least one actor".into())?;
    // Statics may set `pos_m` too (those that leave it out are at the origin).
    let statics_placed = f.statics.iter().filter(|s| s.pos_m != DVec3::ZERO).count();
    for (i, a) in f.actors.iter().enumerate() {
        let placed = bounded(a.pos_m, POSITION_MAX_M) && a.yaw_deg.is_finite();
        c.ensure(placed, &At::new(format!("actors[{i}].pos_m"), "pos_m", statics_placed + i), || {
            format!("position (within {POSITION_MAX_M} m) and yaw must be finite")
        })?;
        c.ensure(
            !f.actors[..i].iter().any(|o| o.name == a.name),
            &At::new(format!("actors[{i}].name"), "name", i),
            || format!("actor {:?} twice", a.name),
        )?;
    }
    Ok(f)
}

/// A scene's step: the explicit contacts and the characters' controllers are tuned for steps of a
/// few milliseconds.
const SCENE_DT_S: Bound =
    Bound::hard("dt_s", 0.0, 0.02, "s", "explicit penalty contacts are stable only for short steps");

fn rotvec_deg(v: DVec3) -> DQuat {
    quat_exp(v * (std::f64::consts::PI / 180.0))
}

/// Loads a scene file and the body files it names (relative to it), and builds the model.
pub fn load_scene(path: &Path) -> Result<Model, SimError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SimError::Io { path: path.display().to_string(), message: e.to_string() })?;
    let origin = path.display().to_string();
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
    build_scene(&text, &origin, |name| {
        let p = dir.join(name);
        let t = std::fs::read_to_string(&p)
            .map_err(|e| SimError::Io { path: p.display().to_string(), message: e.to_string() })?;
        Ok((t, p.display().to_string()))
    })
}

/// The built-in boxing scene with the built-in upper body.
pub fn boxing_scene() -> Result<Model, SimError> {
    build_scene(SCENE_BOXING_RON, "configs/scene-boxing.ron (built in)", builtin_body)
}

/// Resolves the body files shipped in `configs/`.
pub fn builtin_body(name: &str) -> Result<(String, String), SimError> {
    match name {
        "body-upper.ron" => Ok((BODY_UPPER_RON.to_string(), "configs/body-upper.ron (built in)".into())),
        other => Err(SimError::Io { path: other.into(), message: "not a built-in body file".into() }),
    }
}

/// Builds a model from scene text; `resolve` returns (text, origin) of a named body file.
pub fn build_scene(
    text: &str,
    origin: &str,
    mut resolve: impl FnMut(&str) -> Result<(String, String), SimError>,
) -> Result<Model, SimError> {
    let scene = parse_scene(text, origin)?;
    let mut m = Model {
        dt_s: scene.dt_s,
        gravity_m_per_s2: scene.gravity_m_per_s2,
        bodies: Vec::new(),
        nq: 0,
        nv: 0,
        q_default: Vec::new(),
        shapes: Vec::new(),
        pairs: Vec::new(),
        articulations: Vec::new(),
        contact: ContactParams { slip_m_per_s: scene.contact.slip_m_per_s },
        limit: LimitParams {
            k_n_m_per_rad: scene.joint_limit.stiffness_n_m_per_rad,
            d_n_m_s_per_rad: scene.joint_limit.damping_n_m_s_per_rad,
        },
        implicit_joint_springs: true,
    };
    for s in &scene.statics {
        m.shapes.push(ShapeInst {
            name: s.name.clone(),
            body: None,
            shape: s.shape.to_shape(),
            local: ShapePose { pos_m: s.pos_m, rot: DMat3::from_quat(rotvec_deg(s.rot_deg)) },
            group: s.group,
            mask: s.mask,
            bound_m: shape_bound(&s.shape.to_shape()),
        });
    }
    for actor in &scene.actors {
        let (btext, borigin) = resolve(&actor.body)?;
        let body = parse_body(&btext, &borigin)?;
        let frame = Xform::from_pose(actor.pos_m, DQuat::from_rotation_y(actor.yaw_deg.to_radians()));
        add_articulation(&mut m, &actor.name, &body, &frame);
    }
    let contact = scene.contact.clone();
    let dt = scene.dt_s;
    m.build_pairs(|mred| {
        (contact.stiffness.stiffness(mred, dt), contact.damping.damping(mred, dt), contact.friction)
    });
    if m.pairs.len() > u16::MAX as usize || m.shapes.len() > u16::MAX as usize {
        return Err(SimError::Build("too many shapes (at most 65535)".into()));
    }
    Ok(m)
}

/// Appends one instance of a body description, its root placed by `frame` (world -> actor).
pub fn add_articulation(m: &mut Model, name: &str, body: &BodyFile, frame: &Xform) -> usize {
    let art = m.articulations.len();
    let first = m.bodies.len();
    let mut mass_total = 0.0;
    for (i, l) in body.links.iter().enumerate() {
        let parent = l.parent.as_ref().map(|p| first + body.links.iter().position(|o| &o.name == p).unwrap());
        let (mass_kg, centre, i_com) = match &l.mass {
            MassDesc::Ellipsoid { mass_kg, size_m, centre_m } => {
                (*mass_kg, *centre_m, ellipsoid_inertia(*mass_kg, *size_m))
            }
            MassDesc::Box { mass_kg, size_m, centre_m } => {
                (*mass_kg, *centre_m, box_inertia(*mass_kg, *size_m))
            }
            MassDesc::Explicit { mass_kg, centre_m, inertia_kg_m2 } => {
                (*mass_kg, *centre_m, DMat3::from_diagonal(*inertia_kg_m2))
            }
        };
        mass_total += mass_kg;
        let j = &l.joint;
        let nv = j.kind.nv();
        let mut stiffness = [0.0; MAX_JOINT_DOF];
        let mut damping = [0.0; MAX_JOINT_DOF];
        let (k, d) =
            (j.stiffness.stiffness(mass_kg, body.gain_dt_s), j.damping.damping(mass_kg, body.gain_dt_s));
        match j.kind {
            JointKind::Free => {
                let kl = j.linear_stiffness.unwrap_or(Gain::Abs(0.0)).stiffness(mass_kg, body.gain_dt_s);
                let dl = j.linear_damping.unwrap_or(Gain::Abs(0.0)).damping(mass_kg, body.gain_dt_s);
                stiffness = [k, k, k, kl, kl, kl];
                damping = [d, d, d, dl, dl, dl];
            }
            _ => {
                stiffness[..nv].fill(k);
                damping[..nv].fill(d);
            }
        }
        let limits = j.limits_deg.as_ref().map(|v| {
            let mut out = [(-f64::INFINITY, f64::INFINITY); 3];
            for (o, (lo, hi)) in out.iter_mut().zip(v) {
                *o = (lo.to_radians(), hi.to_radians());
            }
            out
        });
        // Roots: the joint frame is the actor frame; a free root's home pose is the anchor in it.
        let x_tree = if parent.is_none() && !matches!(j.kind, JointKind::Free) {
            Xform::translation(j.anchor_m).compose(frame)
        } else if parent.is_none() {
            *frame
        } else {
            Xform::translation(j.anchor_m)
        };
        let q_at = m.nq;
        let v_at = m.nv;
        m.nq += j.kind.nq();
        m.nv += nv;
        m.q_default.resize(m.nq, 0.0);
        let q = &mut m.q_default[q_at..m.nq];
        j.kind.zero(q);
        let deg = |k: usize| j.default_deg.get(k).copied().unwrap_or(0.0).to_radians();
        match j.kind {
            JointKind::Free => {
                q[0] = j.anchor_m.x;
                q[1] = j.anchor_m.y;
                q[2] = j.anchor_m.z;
                write_quat(&mut q[3..7], quat_exp(DVec3::new(deg(0), deg(1), deg(2))));
            }
            JointKind::Ball => write_quat(q, quat_exp(DVec3::new(deg(0), deg(1), deg(2)))),
            JointKind::Universal { .. } => {
                q[0] = deg(0);
                q[1] = deg(1);
            }
            JointKind::Revolute { .. } => q[0] = deg(0),
            JointKind::Fixed => {}
        }
        let body_index = first + i;
        m.bodies.push(Body {
            name: l.name.clone(),
            part: l.part,
            side: l.side,
            parent,
            articulation: art,
            joint: j.kind,
            x_tree,
            inertia: SInertia::rigid(mass_kg, centre, i_com),
            mass_kg,
            com_m: centre,
            inv_i_com: i_com.inverse(),
            q_at,
            v_at,
            stiffness,
            damping,
            limits,
        });
        for s in &l.shapes {
            let shape = s.shape.to_shape();
            m.shapes.push(ShapeInst {
                name: format!("{name}.{}", s.name),
                body: Some(body_index),
                shape,
                local: ShapePose { pos_m: s.pos_m, rot: DMat3::from_quat(rotvec_deg(s.rot_deg)) },
                group: s.group,
                mask: s.mask,
                bound_m: shape_bound(&shape),
            });
        }
    }
    m.articulations.push(Articulation {
        name: name.to_string(),
        kind: body.name.clone(),
        bodies: first..m.bodies.len(),
        mass_kg: mass_total,
        carries_weight: body.base_carries_weight,
    });
    art
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line_of(text: &str, needle: &str) -> usize {
        text.lines().position(|l| l.contains(needle)).unwrap() + 1
    }

    #[test]
    fn shipped_body_is_the_26_dof_upper_body() {
        let b = parse_body(BODY_UPPER_RON, "body-upper.ron").unwrap();
        assert_eq!(b.links.len(), 9);
        assert_eq!(b.links.iter().map(|l| l.joint.kind.nv()).sum::<usize>(), 26);
    }

    #[test]
    fn a_bad_mass_names_its_link_line_and_field() {
        let text = BODY_UPPER_RON.replacen("mass_kg: 2.4,", "mass_kg: -2.4,", 1);
        let e = parse_body(&text, "b.ron").unwrap_err().to_string();
        let line = line_of(&text, "mass_kg: -2.4");
        assert!(e.starts_with(&format!("b.ron:{line}:")), "{e}");
        assert!(e.contains("links[3].mass") && e.contains("must be > 0"), "{e}");
    }

    #[test]
    fn a_wrong_default_count_is_explained() {
        let text = BODY_UPPER_RON.replacen("default_deg: [140.0, 0.0],", "default_deg: [140.0],", 1);
        let e = parse_body(&text, "b.ron").unwrap_err().to_string();
        let line = line_of(&text, "default_deg: [140.0],");
        assert!(e.starts_with(&format!("b.ron:{line}:")), "{e}");
        assert!(e.contains("universal joint takes 2 default values, got 1"), "{e}");
    }

    #[test]
    fn an_unknown_field_is_located() {
        let text = BODY_UPPER_RON.replacen("gain_dt_s: 0.006,", "gain_dt_s: 0.006, colour: 3,", 1);
        let e = parse_body(&text, "b.ron").unwrap_err().to_string();
        assert!(e.contains("colour"), "{e}");
        assert!(e.starts_with(&format!("b.ron:{}:", line_of(&text, "colour"))), "{e}");
    }

    #[test]
    fn an_unstable_contact_rate_is_refused_with_the_reason() {
        let text = SCENE_BOXING_RON.replacen("stiffness: Rate(0.5)", "stiffness: Rate(5.0)", 1);
        let e = parse_scene(&text, "s.ron").unwrap_err().to_string();
        assert!(e.contains("unstable") && e.contains("use <= 1"), "{e}");
        assert!(e.starts_with(&format!("s.ron:{}:", line_of(&text, "Rate(5.0)"))), "{e}");
    }

    #[test]
    fn a_missing_body_file_names_it() {
        let text = SCENE_BOXING_RON.replacen("\"body-upper.ron\"", "\"nobody.ron\"", 1);
        let e = build_scene(&text, "s.ron", builtin_body).unwrap_err().to_string();
        assert!(e.contains("nobody.ron"), "{e}");
    }

    #[test]
    fn rate_gains_follow_the_labs_formula() {
        // Shoulder, fighter: P = 0.009 x 0.12 x 2m/dt^2, D = 0.012 x 10 x m/dt, m = 2.4 kg, dt = 6 ms.
        assert!((Gain::Rate(0.00108).stiffness(2.4, 0.006) - 144.0).abs() < 1e-9);
        assert!((Gain::Rate(0.12).damping(2.4, 0.006) - 48.0).abs() < 1e-9);
        assert_eq!(Gain::Abs(3.0).stiffness(2.4, 0.006), 3.0);
    }
}
