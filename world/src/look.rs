//! What a scene looks like to a viewer: a [`Look`] described once (the bodies as their collision
//! shapes in the scene's colours, the behaviour labels, the counters a heads-up display shows, a
//! crowd's skeleton) and the [`Poses`] a scene writes at display rate into the view's buffer.
//!
//! Why here and not in the view: a scene knows its bodies, the view knows only this plain data, so
//! the view serves any scene and a scene needs no network code. The layout of the poses is fixed
//! by the look, so a frame is a flat array of numbers the page reads at offsets it computed once.
//!
//! Must never: allocate or block in [`Poses`] (it runs on the world's stepping thread).

use std::sync::Arc;

use glam::{DQuat, DVec3};
use spidar_msg::ProxyId;
use spidar_sim::character::drawn::Figures;
use spidar_sim::collide::Shape;

/// Numbers per moving shape in a frame: position (3), rotation quaternion x, y, z, w (4).
pub const SHAPE_FLOATS: usize = 7;
/// Numbers per character before its joints: body position (3), body rotation (4), control state
/// (1), push force on it this step (1).
pub const CHARACTER_HEAD_FLOATS: usize = 9;
/// Where in a character's numbers its control state and the push force on it are.
pub const CHARACTER_STATE: usize = 7;
pub const CHARACTER_PUSH: usize = 8;
/// Numbers per joint of the drawn figure: its position in the scene frame (x, y, z).
pub const JOINT_FLOATS: usize = 3;
/// Numbers per contact: point (3), force on the body named first (3).
pub const CONTACT_FLOATS: usize = 6;
/// Numbers per gaze in a frame: the eyes xyz, the unit direction xyz, the point looked at xyz.
pub const GAZE_FLOATS: usize = 9;
/// Most contacts one frame carries (the scene's own and the rig's rendered ones).
pub const MAX_CONTACTS: usize = 32;
/// Most counters a scene shows.
pub const MAX_COUNTERS: usize = 8;

/// One drawn shape.
#[derive(Clone, Debug, PartialEq)]
pub struct LookShape {
    /// `actor/part`, for labels and tests.
    pub name: String,
    /// The collision shape, in its own frame (a capsule's axis is its y axis).
    pub shape: Shape,
    /// sRGB colour.
    pub colour: [u8; 3],
    /// The contact proxy id that stands for this shape's body, so the rig's rendered contacts on
    /// that proxy flash it.
    pub proxy: Option<ProxyId>,
}

/// A label that follows a shape and shows one of a few states (the virtual human's behaviour).
#[derive(Clone, Debug, PartialEq)]
pub struct LookLabel {
    pub name: String,
    /// Index into `Look::shapes` the label floats above.
    pub shape: usize,
    /// The names of the states, indexed by the state a frame carries.
    pub states: Vec<String>,
}

/// One joint of a crowd's skeleton (the keyframe set's).
#[derive(Clone, Debug, PartialEq)]
pub struct LookJoint {
    pub name: String,
    pub parent: Option<usize>,
    /// Rest position in the parent's frame (the root's: in the body frame) (m).
    pub offset_m: DVec3,
}

/// A crowd of keyframe characters, each drawn as its skeleton posed by the keyframe set.
#[derive(Clone, Debug)]
pub struct LookCrowd {
    pub characters: usize,
    pub joints: Vec<LookJoint>,
    /// Names of the control states (the controller's policies), indexed by a frame's state.
    pub states: Vec<String>,
    /// Colour of each state.
    pub colours: Vec<[u8; 3]>,
    /// A proxy's `ProxyId::body` is the index of the character it stands for.
    pub proxy_body_is_character: bool,
    /// What the figures are computed with off the stepping thread, from the states
    /// [`crate::Scene::figure_states`] copies (`None`: the scene always writes them itself).
    pub figures: Option<Arc<Figures>>,
}

/// A body drawn as a person (the boxing scene's virtual human and avatar): which moving shapes
/// are its segments and where its joints sit on them, so the page builds a humanoid mesh whose
/// pieces ride on the shapes' poses and meet at the simulated joints.
#[derive(Clone, Debug, PartialEq)]
pub struct LookHumanoid {
    /// The actor (`virtual human`, `avatar`): its shapes are named `actor/part`.
    pub name: String,
    pub segments: Vec<LookSegment>,
    pub joints: Vec<LookBodyJoint>,
    /// Clothes and skin (sRGB).
    pub colour: [u8; 3],
    pub skin: [u8; 3],
    /// Which way the body faces in its segments' frames (the body model's forward, -z).
    pub forward: DVec3,
}

/// One solid of a humanoid: its shape and what part of a body it is.
#[derive(Clone, Debug, PartialEq)]
pub struct LookSegment {
    /// Index into `Look::shapes`.
    pub shape: usize,
    /// `waist`, `chest`, `head`, `upper_arm`, `forearm` or `hand`.
    pub part: String,
    /// -1 left, 0 centre, 1 right.
    pub side: i8,
}

/// A joint between two segments: where it is in each one's shape frame (the two coincide in the
/// world: the simulation's joints hold together).
#[derive(Clone, Debug, PartialEq)]
pub struct LookBodyJoint {
    pub name: String,
    /// Indices into `Look::shapes`.
    pub parent_shape: usize,
    pub child_shape: usize,
    pub at_parent_m: DVec3,
    pub at_child_m: DVec3,
}

/// A person's eye in a scene with more than one (the spar scene's seats): the user's-eye camera
/// of the page asked for seat `i` (`?seat=i`) stands at `eye_m` looking at `focus_m`.
#[derive(Clone, Debug, PartialEq)]
pub struct LookEye {
    pub name: String,
    /// Scene frame.
    pub eye_m: DVec3,
    pub focus_m: DVec3,
}

/// A body that looks somewhere: its head's shape (the page turns that head's eyes to the frame's
/// point looked at).
#[derive(Clone, Debug)]
pub struct LookGaze {
    pub name: String,
    pub head_shape: usize,
}

/// The description of a scene for the view, built once.
#[derive(Clone, Debug)]
pub struct Look {
    /// Shapes moved every frame.
    pub shapes: Vec<LookShape>,
    /// Immovable scenery at its pose (the floor).
    pub statics: Vec<(LookShape, DVec3, DQuat)>,
    pub labels: Vec<LookLabel>,
    /// Names of the counters (at most [`MAX_COUNTERS`]).
    pub counters: Vec<String>,
    pub crowd: Option<LookCrowd>,
    /// Where the link's frame (the hand samples, contact proxies and rig geometry) sits in the
    /// scene's: scene = link + this (the boxing scene's `user_offset_m`).
    pub link_offset_m: DVec3,
    /// What the user's-eye camera looks at (scene frame).
    pub focus_m: DVec3,
    /// Bodies drawn as people (their shapes stay drawable as they are, a toggle).
    pub humanoids: Vec<LookHumanoid>,
    /// The people's eyes, one per seat, when the scene has several (else empty: the one user's
    /// eye is the rig's, or in front of `focus_m`).
    pub eyes: Vec<LookEye>,
    /// Bodies whose gaze each frame carries ([`GAZE_FLOATS`] each, [`Poses::gaze`]).
    pub gazes: Vec<LookGaze>,
}

impl Default for Look {
    fn default() -> Self {
        Look {
            shapes: Vec::new(),
            statics: Vec::new(),
            labels: Vec::new(),
            counters: Vec::new(),
            crowd: None,
            link_offset_m: DVec3::ZERO,
            focus_m: DVec3::new(0.0, 1.3, -1.0),
            humanoids: Vec::new(),
            eyes: Vec::new(),
            gazes: Vec::new(),
        }
    }
}

impl Look {
    /// Numbers per character in a frame.
    pub fn character_floats(&self) -> usize {
        self.crowd.as_ref().map_or(0, |c| CHARACTER_HEAD_FLOATS + JOINT_FLOATS * c.joints.len())
    }
}

/// A contact to draw: a point and the force on the body named first (scene frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DrawnContact {
    pub point_m: DVec3,
    pub force_n: DVec3,
}

/// Where a scene writes one frame's poses: sections of the view's frame buffer, sized by the
/// scene's [`Look`]. Indices out of range are ignored (a scene that grew after its look was
/// taken is drawn as it was described).
pub struct Poses<'a> {
    pub(crate) shapes: &'a mut [f32],
    pub(crate) shape_force: &'a mut [f32],
    pub(crate) labels: &'a mut [f32],
    pub(crate) counters: &'a mut [f64],
    pub(crate) characters: &'a mut [f32],
    pub(crate) character_floats: usize,
    pub(crate) gazes: &'a mut [f32],
    pub(crate) contacts: &'a mut [f32],
    pub(crate) contact_count: &'a mut usize,
    pub(crate) figures_now: bool,
}

impl Poses<'_> {
    /// Pose of moving shape `k` (scene frame).
    #[inline]
    pub fn shape(&mut self, k: usize, pos_m: DVec3, rot: DQuat) {
        if let Some(s) = self.shapes.get_mut(k * SHAPE_FLOATS..(k + 1) * SHAPE_FLOATS) {
            put3(&mut s[0..3], pos_m);
            put_quat(&mut s[3..7], rot);
        }
    }

    /// Adds a contact force's magnitude to shape `k` (a flash on the part hit).
    #[inline]
    pub fn shape_force(&mut self, k: usize, force_n: f64) {
        if let Some(f) = self.shape_force.get_mut(k) {
            *f += force_n as f32;
        }
    }

    #[inline]
    pub fn label(&mut self, i: usize, state: usize) {
        if let Some(l) = self.labels.get_mut(i) {
            *l = state as f32;
        }
    }

    #[inline]
    pub fn counter(&mut self, i: usize, value: f64) {
        if let Some(c) = self.counters.get_mut(i) {
            *c = value;
        }
    }

    /// Character `i`: its body pose and the joints of its drawn figure (scene frame), its control
    /// state and the force pushing it.
    #[inline]
    pub fn character(
        &mut self,
        i: usize,
        pos_m: DVec3,
        rot: DQuat,
        joints_m: &[DVec3],
        state: usize,
        push_n: f64,
    ) {
        let n = self.character_floats;
        if let Some(c) = self.characters.get_mut(i * n..(i + 1) * n) {
            put_character(c, pos_m, rot, joints_m, state, push_n);
        }
    }

    /// The characters' section and the numbers per character, for a scene that writes many at
    /// once (in parallel), each with [`put_character`].
    pub fn characters_mut(&mut self) -> (&mut [f32], usize) {
        (&mut *self.characters, self.character_floats)
    }

    /// Whether the characters' drawn figures are written now. When not, a scene writes each
    /// character without its joints (`put_character` with none): they are filled in later, off
    /// the stepping thread, from the states [`crate::Scene::figure_states`] copies.
    pub fn figures_now(&self) -> bool {
        self.figures_now
    }

    /// Adds the push force on character `i` (magnitude, N).
    #[inline]
    pub fn character_push(&mut self, i: usize, push_n: f64) {
        let n = self.character_floats;
        if let Some(p) = self.characters.get_mut(i * n + CHARACTER_PUSH) {
            *p += push_n as f32;
        }
    }

    /// Gaze `i` of the look's `gazes`: the eyes, the unit direction they point and the point
    /// looked at (scene frame).
    #[inline]
    pub fn gaze(&mut self, i: usize, eye_m: DVec3, dir: DVec3, at_m: DVec3) {
        if let Some(g) = self.gazes.get_mut(i * GAZE_FLOATS..(i + 1) * GAZE_FLOATS) {
            put3(&mut g[0..3], eye_m);
            put3(&mut g[3..6], dir);
            put3(&mut g[6..9], at_m);
        }
    }

    /// Adds a contact to draw (scene frame); false when the frame's contacts are full.
    #[inline]
    pub fn contact(&mut self, c: DrawnContact) -> bool {
        let k = *self.contact_count;
        let Some(s) = self.contacts.get_mut(k * CONTACT_FLOATS..(k + 1) * CONTACT_FLOATS) else {
            return false;
        };
        put3(&mut s[0..3], c.point_m);
        put3(&mut s[3..6], c.force_n);
        *self.contact_count += 1;
        true
    }
}

/// Writes one character's numbers (`c`: its share of a frame, see [`CHARACTER_HEAD_FLOATS`]): body
/// pose, control state, push force and the joints of its drawn figure (as many as `c` holds).
#[inline]
pub fn put_character(c: &mut [f32], pos_m: DVec3, rot: DQuat, joints_m: &[DVec3], state: usize, push_n: f64) {
    put3(&mut c[0..3], pos_m);
    put_quat(&mut c[3..7], rot);
    c[CHARACTER_STATE] = state as f32;
    c[CHARACTER_PUSH] = push_n as f32;
    put_joints(c, joints_m);
}

/// Writes the joints of one character's drawn figure into its numbers (`c`, as for
/// [`put_character`]), as many as `c` holds.
#[inline]
pub fn put_joints(c: &mut [f32], joints_m: &[DVec3]) {
    for (s, j) in c[CHARACTER_HEAD_FLOATS..].chunks_exact_mut(JOINT_FLOATS).zip(joints_m) {
        put3(s, *j);
    }
}

#[inline]
fn put3(s: &mut [f32], v: DVec3) {
    s[0] = v.x as f32;
    s[1] = v.y as f32;
    s[2] = v.z as f32;
}

#[inline]
fn put_quat(s: &mut [f32], q: DQuat) {
    s[0] = q.x as f32;
    s[1] = q.y as f32;
    s[2] = q.z as f32;
    s[3] = q.w as f32;
}

/// A rotation matrix as a unit quaternion (tolerant of rounding in the matrix).
#[inline]
pub(crate) fn quat(m: &glam::DMat3) -> glam::DQuat {
    glam::DQuat::from_mat3(m).normalize()
}
