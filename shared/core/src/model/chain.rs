//! Serial kinematic chains extracted from URDF descriptions.
//!
//! A [`Chain`] is the path of movable joints from a root link to a tool link. Fixed joints on the
//! path are folded into the origin of the next movable joint (or into the tool offset), so the
//! forward kinematics walks only the joints that move.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::error::ModelError;

/// How a joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about the joint axis (URDF `revolute` or `continuous`).
    Revolute,
    /// Translation along the joint axis (URDF `prismatic`).
    Prismatic,
}

/// Position, velocity, acceleration and jerk limits of one joint, in SI units (rad or m).
///
/// Infinite values mean "no limit" (a `continuous` joint has infinite position limits; a joint
/// whose URDF gives no `jerk` has an infinite jerk limit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    /// Lowest position.
    pub position_min: f64,
    /// Highest position.
    pub position_max: f64,
    /// Largest speed magnitude.
    pub velocity: f64,
    /// Largest acceleration magnitude.
    pub acceleration: f64,
    /// Largest jerk magnitude.
    pub jerk: f64,
}

/// One movable joint of a [`Chain`].
#[derive(Debug, Clone)]
pub struct ChainJoint {
    /// The URDF joint name.
    pub name: String,
    /// Revolute or prismatic.
    pub kind: JointKind,
    /// Transform from the previous movable joint's frame (or the root link) to this joint's frame
    /// at zero position, with any fixed joints in between folded in.
    pub origin: Isometry3<f64>,
    /// Joint axis in the joint's own frame.
    pub axis: Unit<Vector3<f64>>,
    /// Limits from the URDF `<limit>` element.
    pub limits: JointLimits,
}

impl ChainJoint {
    /// The transform this joint adds at position `q`.
    pub fn motion(&self, q: f64) -> Isometry3<f64> {
        match self.kind {
            JointKind::Revolute => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&self.axis, q),
            ),
            JointKind::Prismatic => Isometry3::from_parts(
                Translation3::from(self.axis.into_inner() * q),
                UnitQuaternion::identity(),
            ),
        }
    }
}

/// A serial chain of movable joints from a root link to a tool link.
#[derive(Debug, Clone)]
pub struct Chain {
    /// The link the chain starts from (its frame is the chain's base frame).
    pub root_link: String,
    /// The link whose origin is the tool point.
    pub tool_link: String,
    /// Movable joints, root first.
    pub joints: Vec<ChainJoint>,
    /// Fixed transform from the last movable joint's frame to the tool frame.
    pub tool: Isometry3<f64>,
}

impl Chain {
    /// Number of movable joints.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// Index of the joint called `name`.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Loads the chain from `root_link` to `tool_link` out of the URDF file at `path`.
    pub fn from_urdf_file(
        path: &Path,
        root_link: &str,
        tool_link: &str,
    ) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(path)?;
        Self::from_urdf_str(path, &text, root_link, tool_link)
    }

    /// Parses URDF `text` (read from `path`, which is used in error messages) into a chain.
    pub fn from_urdf_str(
        path: &Path,
        text: &str,
        root_link: &str,
        tool_link: &str,
    ) -> Result<Self, ModelError> {
        if let Some((element, message)) = find_bad_number(text) {
            return Err(ModelError::invalid(path, element, message));
        }
        let robot = urdf_rs::read_from_string(text)
            .map_err(|e| ModelError::invalid(path, "<robot>", e.to_string()))?;
        chain_from_robot(path, &robot, root_link, tool_link)
    }
}

fn pose_to_isometry(pose: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = pose.xyz.0;
    let [roll, pitch, yaw] = pose.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

fn chain_from_robot(
    path: &Path,
    robot: &urdf_rs::Robot,
    root_link: &str,
    tool_link: &str,
) -> Result<Chain, ModelError> {
    let link_names: Vec<&str> = robot.links.iter().map(|l| l.name.as_str()).collect();
    for joint in &robot.joints {
        for (role, link) in [("parent", &joint.parent.link), ("child", &joint.child.link)] {
            if !link_names.contains(&link.as_str()) {
                return Err(ModelError::invalid(
                    path,
                    format!("joint '{}' <{role}>", joint.name),
                    format!("link '{link}' is not defined"),
                ));
            }
        }
    }
    for (name, role) in [(root_link, "root"), (tool_link, "tool")] {
        if !link_names.contains(&name) {
            return Err(ModelError::invalid(
                path,
                format!("<link name=\"{name}\">"),
                format!("the {role} link is missing"),
            ));
        }
    }

    let mut parent_joint: HashMap<&str, &urdf_rs::Joint> = HashMap::new();
    for joint in &robot.joints {
        if parent_joint
            .insert(joint.child.link.as_str(), joint)
            .is_some()
        {
            return Err(ModelError::invalid(
                path,
                format!("joint '{}'", joint.name),
                format!("link '{}' has two parent joints", joint.child.link),
            ));
        }
    }

    // Walk from the tool up to the root, then reverse.
    let mut path_joints = Vec::new();
    let mut link = tool_link;
    while link != root_link {
        let joint = parent_joint.get(link).ok_or_else(|| {
            ModelError::invalid(
                path,
                format!("<link name=\"{link}\">"),
                format!("missing joint: no joint has this link as its child, so it is not connected to root link '{root_link}'"),
            )
        })?;
        path_joints.push(*joint);
        link = joint.parent.link.as_str();
        if path_joints.len() > robot.joints.len() {
            return Err(ModelError::invalid(
                path,
                "<joint>",
                "the joints form a cycle",
            ));
        }
    }
    path_joints.reverse();

    let mut joints = Vec::new();
    let mut pending = Isometry3::identity();
    for joint in path_joints {
        let origin = pending * pose_to_isometry(&joint.origin);
        let element = |what: &str| format!("joint '{}' {what}", joint.name);
        let kind = match joint.joint_type {
            urdf_rs::JointType::Fixed => {
                pending = origin;
                continue;
            }
            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => JointKind::Revolute,
            urdf_rs::JointType::Prismatic => JointKind::Prismatic,
            ref other => {
                return Err(ModelError::invalid(
                    path,
                    element("type"),
                    format!("{other:?} joints are not supported in a serial chain"),
                ));
            }
        };
        let axis = Vector3::from(joint.axis.xyz.0);
        let axis = Unit::try_new(axis, 1e-9).ok_or_else(|| {
            ModelError::invalid(path, element("<axis xyz>"), "axis has zero length")
        })?;
        let limit = &joint.limit;
        let (position_min, position_max) = if joint.joint_type == urdf_rs::JointType::Continuous {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            (limit.lower, limit.upper)
        };
        let limits = JointLimits {
            position_min,
            position_max,
            velocity: limit.velocity,
            acceleration: limit.acceleration,
            jerk: limit.jerk,
        };
        if !(limits.velocity > 0.0 && limits.velocity.is_finite()) {
            return Err(ModelError::invalid(
                path,
                element("<limit velocity>"),
                format!(
                    "velocity limit must be positive and finite, got {}",
                    limits.velocity
                ),
            ));
        }
        if !(limits.acceleration > 0.0 && limits.acceleration.is_finite()) {
            return Err(ModelError::invalid(
                path,
                element("<limit acceleration>"),
                "acceleration limit must be positive and finite (URDF 1.2 `acceleration` attribute)",
            ));
        }
        joints.push(ChainJoint {
            name: joint.name.clone(),
            kind,
            origin,
            axis,
            limits,
        });
        pending = Isometry3::identity();
    }
    if joints.is_empty() {
        return Err(ModelError::invalid(
            path,
            format!("<link name=\"{tool_link}\">"),
            format!("no movable joint between '{root_link}' and '{tool_link}'"),
        ));
    }
    Ok(Chain {
        root_link: root_link.to_string(),
        tool_link: tool_link.to_string(),
        joints,
        tool: pending,
    })
}

/// Attributes whose values are whitespace-separated numbers in URDF.
const NUMERIC_ATTRIBUTES: &[&str] = &[
    "xyz",
    "rpy",
    "lower",
    "upper",
    "effort",
    "velocity",
    "acceleration",
    "deceleration",
    "jerk",
    "value",
    "ixx",
    "ixy",
    "ixz",
    "iyy",
    "iyz",
    "izz",
    "radius",
    "length",
    "size",
    "rgba",
    "scale",
    "multiplier",
    "offset",
    "damping",
    "friction",
];

/// Scans URDF text for a numeric attribute that does not parse, returning the element and message.
///
/// urdf-rs reports such errors without saying where they are; this names the line, the enclosing
/// joint or link, the element and the attribute.
fn find_bad_number(text: &str) -> Option<(String, String)> {
    let mut owner = String::from("<robot>");
    let mut rest = text;
    let mut offset = 0;
    while let Some(start) = rest.find('<') {
        let end = rest[start..].find('>')? + start;
        let tag = &rest[start + 1..end];
        let tag_offset = offset + start;
        offset += end + 1;
        rest = &rest[end + 1..];
        if tag.starts_with('/') || tag.starts_with('?') || tag.starts_with('!') {
            continue;
        }
        let element = tag
            .split_whitespace()
            .next()
            .unwrap_or("")
            .trim_end_matches('/');
        let attributes = parse_attributes(tag);
        if (element == "joint" || element == "link")
            && let Some((_, name)) = attributes.iter().find(|(k, _)| *k == "name")
        {
            owner = format!("{element} '{name}'");
        }
        for (key, value) in &attributes {
            if !NUMERIC_ATTRIBUTES.contains(key) || element == "material" {
                continue;
            }
            if let Some(bad) = value.split_whitespace().find(|t| t.parse::<f64>().is_err()) {
                let line = text[..tag_offset].matches('\n').count() + 1;
                return Some((
                    format!("line {line}, {owner} <{element} {key}>"),
                    format!("'{bad}' is not a number"),
                ));
            }
        }
    }
    None
}

/// Splits `name key="value" key2='value'` into (key, value) pairs.
fn parse_attributes(tag: &str) -> Vec<(&str, &str)> {
    let mut out = Vec::new();
    let mut rest = tag;
    while let Some(eq) = rest.find('=') {
        let key = rest[..eq].split_whitespace().last().unwrap_or("");
        let after = rest[eq + 1..].trim_start();
        let Some(quote) = after.chars().next().filter(|c| *c == '"' || *c == '\'') else {
            break;
        };
        let Some(close) = after[1..].find(quote) else {
            break;
        };
        out.push((key, &after[1..1 + close]));
        rest = &after[close + 2..];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_LINK: &str = r#"<robot name="t" version="1.2">
  <link name="base"/><link name="a"/><link name="tool"/>
  <joint name="j1" type="revolute">
    <origin xyz="0 0 1" rpy="0 0 0"/><parent link="base"/><child link="a"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="2" acceleration="3"/>
  </joint>
  <joint name="tcp" type="fixed">
    <origin xyz="1 0 0"/><parent link="a"/><child link="tool"/>
  </joint>
</robot>"#;

    #[test]
    fn fixed_tool_joint_is_folded_into_the_tool_offset() {
        let chain = Chain::from_urdf_str(Path::new("t.urdf"), TWO_LINK, "base", "tool").unwrap();
        assert_eq!(chain.dof(), 1);
        assert!((chain.tool.translation.vector - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(chain.joints[0].limits.acceleration, 3.0);
    }

    #[test]
    fn bad_number_names_file_joint_and_attribute() {
        let text = TWO_LINK.replace("upper=\"1\"", "upper=\"1.x\"");
        let err = Chain::from_urdf_str(Path::new("t.urdf"), &text, "base", "tool").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with("t.urdf: line 5, joint 'j1' <limit upper>"),
            "{msg}"
        );
        assert!(msg.contains("'1.x' is not a number"), "{msg}");
    }

    #[test]
    fn missing_joint_names_the_disconnected_link() {
        let text = TWO_LINK.replace(
            r#"<joint name="tcp" type="fixed">
    <origin xyz="1 0 0"/><parent link="a"/><child link="tool"/>
  </joint>"#,
            "",
        );
        let err = Chain::from_urdf_str(Path::new("t.urdf"), &text, "base", "tool").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("t.urdf: <link name=\"tool\">: missing joint"),
            "{msg}"
        );
    }

    #[test]
    fn undefined_link_and_missing_acceleration_are_errors() {
        let text = TWO_LINK.replace("<parent link=\"base\"/>", "<parent link=\"nowhere\"/>");
        let msg = Chain::from_urdf_str(Path::new("t.urdf"), &text, "base", "tool")
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("joint 'j1' <parent>: link 'nowhere' is not defined"),
            "{msg}"
        );
        let text = TWO_LINK.replace(" acceleration=\"3\"", "");
        let msg = Chain::from_urdf_str(Path::new("t.urdf"), &text, "base", "tool")
            .unwrap_err()
            .to_string();
        assert!(msg.contains("joint 'j1' <limit acceleration>"), "{msg}");
    }
}
