//! The Foxglove message types a world recording uses, as `ros2msg` definitions (the field lists of
//! the released `foxglove_msgs` ROS 2 package, constants left out: they take no bytes; a test
//! compares them with Foxglove's own published definitions, `tests/tests/hil/foxglove.rs`), so Foxglove and
//! Lichtblick draw the world in a 3D panel: `foxglove_msgs/msg/FrameTransforms` (where every body
//! is) and `foxglove_msgs/msg/SceneUpdate` (what each body looks like, attached to its frame).
//!
//! Only the top-level types carry the `pkg/msg/Type` name (the schema's name); nested types are
//! named `pkg/Type`, as ROS 2 message definitions name them.

use crate::message;

/// `builtin_interfaces/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}
message!(Time = "builtin_interfaces/Time" { sec: i32, nanosec: u32 });

impl Time {
    pub fn from_ns(ns: u64) -> Time {
        Time { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }
}

/// `builtin_interfaces/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}
message!(Duration = "builtin_interfaces/Duration" { sec: i32, nanosec: u32 });

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}
message!(Vector3 = "geometry_msgs/Vector3" { x: f64, y: f64, z: f64 });

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}
message!(Point = "geometry_msgs/Point" { x: f64, y: f64, z: f64 });

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}
impl Default for Quaternion {
    fn default() -> Self {
        Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}
message!(Quaternion = "geometry_msgs/Quaternion" { x: f64, y: f64, z: f64, w: f64 });

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}
message!(Pose = "geometry_msgs/Pose" { position: Point, orientation: Quaternion });

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Color {
    pub r: f64,
    pub g: f64,
    pub b: f64,
    pub a: f64,
}
message!(Color = "foxglove_msgs/Color" { r: f64, g: f64, b: f64, a: f64 });

impl Color {
    pub fn srgb(c: [u8; 3], a: f64) -> Color {
        Color { r: c[0] as f64 / 255.0, g: c[1] as f64 / 255.0, b: c[2] as f64 / 255.0, a }
    }
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct KeyValuePair {
    pub key: String,
    pub value: String,
}
message!(KeyValuePair = "foxglove_msgs/KeyValuePair" { key: String, value: String });

#[derive(Clone, Debug, Default, PartialEq)]
pub struct ArrowPrimitive {
    pub pose: Pose,
    pub shaft_length: f64,
    pub shaft_diameter: f64,
    pub head_length: f64,
    pub head_diameter: f64,
    pub color: Color,
}
message!(ArrowPrimitive = "foxglove_msgs/ArrowPrimitive" {
    pose: Pose, shaft_length: f64, shaft_diameter: f64, head_length: f64, head_diameter: f64, color: Color,
});

/// A box (`size`: edge lengths).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CubePrimitive {
    pub pose: Pose,
    pub size: Vector3,
    pub color: Color,
}
message!(CubePrimitive = "foxglove_msgs/CubePrimitive" { pose: Pose, size: Vector3, color: Color });

/// A sphere or ellipsoid (`size`: diameters).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SpherePrimitive {
    pub pose: Pose,
    pub size: Vector3,
    pub color: Color,
}
message!(SpherePrimitive = "foxglove_msgs/SpherePrimitive" { pose: Pose, size: Vector3, color: Color });

/// A cylinder along its z axis (`size`: bounding box).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CylinderPrimitive {
    pub pose: Pose,
    pub size: Vector3,
    pub bottom_scale: f64,
    pub top_scale: f64,
    pub color: Color,
}
message!(CylinderPrimitive = "foxglove_msgs/CylinderPrimitive" {
    pose: Pose, size: Vector3, bottom_scale: f64, top_scale: f64, color: Color,
});

/// Lines: `type` 0 strip, 1 loop, 2 list (pairs of points).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LinePrimitive {
    pub r#type: u8,
    pub pose: Pose,
    pub thickness: f64,
    pub scale_invariant: bool,
    pub points: Vec<Point>,
    pub color: Color,
    pub colors: Vec<Color>,
    pub indices: Vec<u32>,
}
message!(LinePrimitive = "foxglove_msgs/LinePrimitive" {
    r#type: u8, pose: Pose, thickness: f64, scale_invariant: bool, points: Vec<Point>, color: Color,
    colors: Vec<Color>, indices: Vec<u32>,
});

#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleListPrimitive {
    pub pose: Pose,
    pub points: Vec<Point>,
    pub color: Color,
    pub colors: Vec<Color>,
    pub indices: Vec<u32>,
}
message!(TriangleListPrimitive = "foxglove_msgs/TriangleListPrimitive" {
    pose: Pose, points: Vec<Point>, color: Color, colors: Vec<Color>, indices: Vec<u32>,
});

#[derive(Clone, Debug, Default, PartialEq)]
pub struct TextPrimitive {
    pub pose: Pose,
    pub billboard: bool,
    pub font_size: f64,
    pub scale_invariant: bool,
    pub color: Color,
    pub text: String,
}
message!(TextPrimitive = "foxglove_msgs/TextPrimitive" {
    pose: Pose, billboard: bool, font_size: f64, scale_invariant: bool, color: Color, text: String,
});

#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelPrimitive {
    pub pose: Pose,
    pub scale: Vector3,
    pub color: Color,
    /// Draw the whole model in `color` instead of its own materials.
    pub override_color: bool,
    pub url: String,
    /// Media type of `data` (e.g. `model/gltf-binary`).
    pub media_type: String,
    pub data: Vec<u8>,
}
message!(ModelPrimitive = "foxglove_msgs/ModelPrimitive" {
    pose: Pose, scale: Vector3, color: Color, override_color: bool, url: String,
    media_type: String, data: Vec<u8>,
});

/// One drawn thing: primitives in the frame `frame_id` (following it when `frame_locked`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneEntity {
    pub timestamp: Time,
    pub frame_id: String,
    pub id: String,
    pub lifetime: Duration,
    pub frame_locked: bool,
    pub metadata: Vec<KeyValuePair>,
    pub arrows: Vec<ArrowPrimitive>,
    pub cubes: Vec<CubePrimitive>,
    pub spheres: Vec<SpherePrimitive>,
    pub cylinders: Vec<CylinderPrimitive>,
    pub lines: Vec<LinePrimitive>,
    pub triangles: Vec<TriangleListPrimitive>,
    pub texts: Vec<TextPrimitive>,
    pub models: Vec<ModelPrimitive>,
}
message!(SceneEntity = "foxglove_msgs/SceneEntity" {
    timestamp: Time, frame_id: String, id: String, lifetime: Duration, frame_locked: bool,
    metadata: Vec<KeyValuePair>, arrows: Vec<ArrowPrimitive>, cubes: Vec<CubePrimitive>,
    spheres: Vec<SpherePrimitive>, cylinders: Vec<CylinderPrimitive>, lines: Vec<LinePrimitive>,
    triangles: Vec<TriangleListPrimitive>, texts: Vec<TextPrimitive>, models: Vec<ModelPrimitive>,
});

/// `type` 0: the entity `id`; 1: every entity of the topic.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneEntityDeletion {
    pub timestamp: Time,
    pub r#type: u8,
    pub id: String,
}
message!(SceneEntityDeletion = "foxglove_msgs/SceneEntityDeletion" { timestamp: Time, r#type: u8, id: String });

#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneUpdate {
    pub deletions: Vec<SceneEntityDeletion>,
    pub entities: Vec<SceneEntity>,
}
message!(SceneUpdate = "foxglove_msgs/msg/SceneUpdate" {
    deletions: Vec<SceneEntityDeletion>, entities: Vec<SceneEntity>,
});

#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameTransform {
    pub timestamp: Time,
    pub parent_frame_id: String,
    pub child_frame_id: String,
    pub translation: Vector3,
    pub rotation: Quaternion,
}
message!(FrameTransform = "foxglove_msgs/FrameTransform" {
    timestamp: Time, parent_frame_id: String, child_frame_id: String, translation: Vector3,
    rotation: Quaternion,
});

#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameTransforms {
    pub transforms: Vec<FrameTransform>,
}
message!(FrameTransforms = "foxglove_msgs/msg/FrameTransforms" { transforms: Vec<FrameTransform> });
