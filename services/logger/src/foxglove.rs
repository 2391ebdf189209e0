//! The foxglove protobuf schemas the logger writes: prost message structs (the subset of fields
//! the logger fills; tags as in the foxglove `.proto` files) and the serialized
//! `FileDescriptorSet` of each top-level schema, stored in the MCAP file as its schema so any
//! reader (Foxglove, `motm log check`) decodes the messages without this code. See
//! `foxglove/NOTICE.md` for where the descriptor sets come from.
//!
//! There is a standard `foxglove.JointStates` schema (named joints with position, velocity,
//! acceleration, effort), so joint states use it.

/// A time since the Unix epoch (`google.protobuf.Timestamp`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Timestamp {
    /// Whole seconds.
    #[prost(int64, tag = "1")]
    pub seconds: i64,
    /// Nanoseconds within the second, `0..1e9`.
    #[prost(int32, tag = "2")]
    pub nanos: i32,
}

impl Timestamp {
    /// The timestamp of `ns` nanoseconds since the Unix epoch.
    pub fn from_ns(ns: u64) -> Self {
        Self {
            seconds: (ns / 1_000_000_000) as i64,
            nanos: (ns % 1_000_000_000) as i32,
        }
    }
}

/// A 3-vector (`foxglove.Vector3`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Vector3 {
    /// x.
    #[prost(double, tag = "1")]
    pub x: f64,
    /// y.
    #[prost(double, tag = "2")]
    pub y: f64,
    /// z.
    #[prost(double, tag = "3")]
    pub z: f64,
}

/// A point (`foxglove.Point3`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Point3 {
    /// x.
    #[prost(double, tag = "1")]
    pub x: f64,
    /// y.
    #[prost(double, tag = "2")]
    pub y: f64,
    /// z.
    #[prost(double, tag = "3")]
    pub z: f64,
}

/// A rotation (`foxglove.Quaternion`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Quaternion {
    /// x.
    #[prost(double, tag = "1")]
    pub x: f64,
    /// y.
    #[prost(double, tag = "2")]
    pub y: f64,
    /// z.
    #[prost(double, tag = "3")]
    pub z: f64,
    /// w.
    #[prost(double, tag = "4")]
    pub w: f64,
}

/// A position and orientation (`foxglove.Pose`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Pose {
    /// Position.
    #[prost(message, optional, tag = "1")]
    pub position: Option<Vector3>,
    /// Orientation.
    #[prost(message, optional, tag = "2")]
    pub orientation: Option<Quaternion>,
}

/// An RGBA color, each channel in 0..1 (`foxglove.Color`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct Color {
    /// Red.
    #[prost(double, tag = "1")]
    pub r: f64,
    /// Green.
    #[prost(double, tag = "2")]
    pub g: f64,
    /// Blue.
    #[prost(double, tag = "3")]
    pub b: f64,
    /// Alpha.
    #[prost(double, tag = "4")]
    pub a: f64,
}

/// One parent → child transform (`foxglove.FrameTransform`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct FrameTransform {
    /// Time of the transform.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Parent frame.
    #[prost(string, tag = "2")]
    pub parent_frame_id: String,
    /// Child frame.
    #[prost(string, tag = "3")]
    pub child_frame_id: String,
    /// Child origin in the parent frame.
    #[prost(message, optional, tag = "4")]
    pub translation: Option<Vector3>,
    /// Child orientation in the parent frame.
    #[prost(message, optional, tag = "5")]
    pub rotation: Option<Quaternion>,
}

/// A set of transforms (`foxglove.FrameTransforms`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct FrameTransforms {
    /// The transforms.
    #[prost(message, repeated, tag = "1")]
    pub transforms: Vec<FrameTransform>,
}

/// One joint's state (`foxglove.JointState`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct JointState {
    /// Joint name.
    #[prost(string, tag = "1")]
    pub name: String,
    /// Position, rad.
    #[prost(double, optional, tag = "2")]
    pub position: Option<f64>,
    /// Velocity, rad/s.
    #[prost(double, optional, tag = "3")]
    pub velocity: Option<f64>,
}

/// The joints of a robot at one time (`foxglove.JointStates`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct JointStates {
    /// Time of the state.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// The joints.
    #[prost(message, repeated, tag = "2")]
    pub joints: Vec<JointState>,
}

/// A pose in a named frame (`foxglove.PoseInFrame`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct PoseInFrame {
    /// Time of the pose.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Frame the pose is in.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// The pose.
    #[prost(message, optional, tag = "3")]
    pub pose: Option<Pose>,
}

/// An uncompressed image (`foxglove.RawImage`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct RawImage {
    /// Exposure time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Camera frame.
    #[prost(string, tag = "7")]
    pub frame_id: String,
    /// Width, pixels.
    #[prost(fixed32, tag = "2")]
    pub width: u32,
    /// Height, pixels.
    #[prost(fixed32, tag = "3")]
    pub height: u32,
    /// Pixel encoding, e.g. `rgb8`.
    #[prost(string, tag = "4")]
    pub encoding: String,
    /// Bytes per row.
    #[prost(fixed32, tag = "5")]
    pub step: u32,
    /// Pixels.
    #[prost(bytes = "vec", tag = "6")]
    pub data: Vec<u8>,
}

/// A box (`foxglove.CubePrimitive`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct CubePrimitive {
    /// Centre and orientation.
    #[prost(message, optional, tag = "1")]
    pub pose: Option<Pose>,
    /// Size along each axis.
    #[prost(message, optional, tag = "2")]
    pub size: Option<Vector3>,
    /// Color.
    #[prost(message, optional, tag = "3")]
    pub color: Option<Color>,
}

/// An ellipsoid (`foxglove.SpherePrimitive`).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct SpherePrimitive {
    /// Centre and orientation.
    #[prost(message, optional, tag = "1")]
    pub pose: Option<Pose>,
    /// Diameter along each axis.
    #[prost(message, optional, tag = "2")]
    pub size: Option<Vector3>,
    /// Color.
    #[prost(message, optional, tag = "3")]
    pub color: Option<Color>,
}

/// An arrow (`foxglove.ArrowPrimitive`); identity orientation points along +x.
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct ArrowPrimitive {
    /// Tail position and orientation.
    #[prost(message, optional, tag = "1")]
    pub pose: Option<Pose>,
    /// Shaft length.
    #[prost(double, tag = "2")]
    pub shaft_length: f64,
    /// Shaft diameter.
    #[prost(double, tag = "3")]
    pub shaft_diameter: f64,
    /// Head length.
    #[prost(double, tag = "4")]
    pub head_length: f64,
    /// Head diameter.
    #[prost(double, tag = "5")]
    pub head_diameter: f64,
    /// Color.
    #[prost(message, optional, tag = "6")]
    pub color: Option<Color>,
}

/// Line kind of a [`LinePrimitive`]: `0` strip, `1` loop, `2` separate segments.
pub const LINE_STRIP: i32 = 0;

/// A polyline (`foxglove.LinePrimitive`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct LinePrimitive {
    /// Line kind ([`LINE_STRIP`]).
    #[prost(int32, tag = "1")]
    pub r#type: i32,
    /// Origin of the points.
    #[prost(message, optional, tag = "2")]
    pub pose: Option<Pose>,
    /// Thickness, m.
    #[prost(double, tag = "3")]
    pub thickness: f64,
    /// Whether the thickness is in pixels.
    #[prost(bool, tag = "4")]
    pub scale_invariant: bool,
    /// Points.
    #[prost(message, repeated, tag = "5")]
    pub points: Vec<Point3>,
    /// Color.
    #[prost(message, optional, tag = "6")]
    pub color: Option<Color>,
}

/// One visual entity (`foxglove.SceneEntity`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct SceneEntity {
    /// Time of the entity.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Frame of the primitives.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// Id; a later entity with the same id replaces it.
    #[prost(string, tag = "3")]
    pub id: String,
    /// Arrows.
    #[prost(message, repeated, tag = "7")]
    pub arrows: Vec<ArrowPrimitive>,
    /// Boxes.
    #[prost(message, repeated, tag = "8")]
    pub cubes: Vec<CubePrimitive>,
    /// Spheres.
    #[prost(message, repeated, tag = "9")]
    pub spheres: Vec<SpherePrimitive>,
    /// Lines.
    #[prost(message, repeated, tag = "11")]
    pub lines: Vec<LinePrimitive>,
}

/// Entities to add or replace (`foxglove.SceneUpdate`).
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct SceneUpdate {
    /// The entities.
    #[prost(message, repeated, tag = "2")]
    pub entities: Vec<SceneEntity>,
}

/// A top-level foxglove schema: its full name and serialized `FileDescriptorSet`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schema {
    /// Full protobuf name, e.g. `foxglove.FrameTransforms`.
    pub name: &'static str,
    /// Serialized `google.protobuf.FileDescriptorSet` holding the message and its dependencies.
    pub descriptor: &'static [u8],
}

/// `foxglove.FrameTransforms`.
pub const FRAME_TRANSFORMS: Schema = Schema {
    name: "foxglove.FrameTransforms",
    descriptor: include_bytes!("foxglove/FrameTransforms.bin"),
};
/// `foxglove.SceneUpdate`.
pub const SCENE_UPDATE: Schema = Schema {
    name: "foxglove.SceneUpdate",
    descriptor: include_bytes!("foxglove/SceneUpdate.bin"),
};
/// `foxglove.JointStates`.
pub const JOINT_STATES: Schema = Schema {
    name: "foxglove.JointStates",
    descriptor: include_bytes!("foxglove/JointStates.bin"),
};
/// `foxglove.PoseInFrame`.
pub const POSE_IN_FRAME: Schema = Schema {
    name: "foxglove.PoseInFrame",
    descriptor: include_bytes!("foxglove/PoseInFrame.bin"),
};
/// `foxglove.RawImage`.
pub const RAW_IMAGE: Schema = Schema {
    name: "foxglove.RawImage",
    descriptor: include_bytes!("foxglove/RawImage.bin"),
};
