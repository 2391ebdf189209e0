//! The grasp model: whether a closing gripper catches a cube, decided by geometry over the whole
//! closure (docs/algorithms.md §4), and whether the gripper hits a cube it is not grasping.
//!
//! A grasp succeeds only if the cube is in the grasp window from the moment the fingers start
//! closing until they reach it:
//! - lateral offset along the finger width (tool x) within `lateral_tolerance`;
//! - cube centre between the fingers along the closing direction (tool y); the fingers then push
//!   it to the middle as they close;
//! - height: the cube overlaps the finger pads by at least `min_height_overlap` along tool z,
//!   and does not reach into the palm;
//! - yaw: the cube's faces turned from the closing direction by at most `yaw_tolerance`; the
//!   squeeze turns it square to the fingers, which close on its edge length.
//!
//! A gripper part that overlaps a free cube outside this window (a finger landing on it, a finger
//! or the palm sweeping into it) knocks the cube off its platform.

use nalgebra::{Isometry3, Vector3};
use serde::Deserialize;

use crate::geometry::OrientedBox;
use crate::gripper::GripperConfig;

/// Tolerances of the grasp model.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraspConfig {
    /// Largest offset of the cube centre from the tool point along the finger width (tool x), m.
    /// 15 mm: half the cube still lies between the pads.
    pub lateral_tolerance: f64,
    /// Least overlap between the cube and the fingers along the approach (tool z), m. 8 mm (a
    /// quarter of the cube) lets the fingers close with the tool point up to 12 mm above the cube
    /// centre, so a controller that closes within about 1 cm of the target and keeps servoing
    /// can succeed.
    pub min_height_overlap: f64,
    /// Largest yaw between the cube's faces and the closing direction, rad. Parallel jaws that
    /// squeeze a square turn it to the nearest face-to-face orientation (Goldberg's squeeze
    /// function) from anywhere short of 45°; pad and platform friction resist the turn near 45°,
    /// so 0.6 rad (about 34°) is chosen.
    pub yaw_tolerance: f64,
    /// A closure that starts with a free cube centre within this distance of the tool point and
    /// ends empty is a missed grasp, m. Closures far from any cube (e.g. to press a button with
    /// the fingertips together) are not grasp attempts. 0.3 m: a gripper that closes where it
    /// expected a cube that has since moved (up to 0.3 m at 3 cm/s in 10 s) has missed it.
    pub attempt_distance: f64,
    /// Opening beyond the held width at which a held cube is released, m.
    pub release_clearance: f64,
}

impl Default for GraspConfig {
    fn default() -> Self {
        Self {
            lateral_tolerance: 0.015,
            min_height_overlap: 0.008,
            yaw_tolerance: 0.6,
            attempt_distance: 0.3,
            release_clearance: 0.002,
        }
    }
}

/// Where a cube is relative to the tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CubeInTool {
    /// Cube centre in the tool frame, m.
    pub offset: Vector3<f64>,
    /// Angle between the cube's nearest face normal and the closing direction (tool y), about
    /// tool z, in [−π/4, π/4] rad.
    pub yaw_misalignment: f64,
}

impl CubeInTool {
    /// The cube `cube` (its centre pose) seen from `tool`.
    pub fn new(tool: &Isometry3<f64>, cube: &Isometry3<f64>) -> Self {
        let offset = tool
            .inverse_transform_point(&cube.translation.vector.into())
            .coords;
        let cube_x_in_tool = tool.rotation.inverse() * (cube.rotation * Vector3::x());
        let angle = cube_x_in_tool.x.atan2(cube_x_in_tool.y);
        let quarter = std::f64::consts::FRAC_PI_2;
        let yaw_misalignment = angle - quarter * (angle / quarter).round();
        Self {
            offset,
            yaw_misalignment,
        }
    }
}

/// Why a cube is not in the grasp window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GraspMiss {
    /// Too far off the pads along the finger width.
    Lateral,
    /// Centre not between the fingers along the closing direction.
    NotBetweenFingers,
    /// Too high or too low relative to the finger pads.
    Height,
    /// Turned too far from the closing direction.
    Yaw,
}

impl GraspMiss {
    /// How a closing finger knocked off a cube that left the grasp window this way.
    pub fn knock_detail(self) -> &'static str {
        match self {
            Self::Lateral => "finger, closing, cube out of the grasp window: lateral",
            Self::NotBetweenFingers => "finger, closing, cube out of the grasp window: not between",
            Self::Height => "finger, closing, cube out of the grasp window: height",
            Self::Yaw => "finger, closing, cube out of the grasp window: yaw",
        }
    }
}

/// Whether a cube of edge `cube_size` at `cube` is in the grasp window at `opening`.
pub fn check_window(
    cube: &CubeInTool,
    opening: f64,
    cube_size: f64,
    gripper: &GripperConfig,
    config: &GraspConfig,
) -> Result<(), GraspMiss> {
    let half = 0.5 * cube_size;
    let offset = &cube.offset;
    if offset.x.abs() > config.lateral_tolerance {
        return Err(GraspMiss::Lateral);
    }
    if offset.y.abs() > 0.5 * opening {
        return Err(GraspMiss::NotBetweenFingers);
    }
    let (palm, tip) = (gripper.palm_z(), gripper.tip_z());
    let overlap = (offset.z + half).min(tip) - (offset.z - half).max(palm);
    if overlap < config.min_height_overlap || offset.z - half < palm {
        return Err(GraspMiss::Height);
    }
    if cube.yaw_misalignment.abs() > config.yaw_tolerance {
        return Err(GraspMiss::Yaw);
    }
    Ok(())
}

/// Which part of the gripper overlaps a cube.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contact {
    /// No overlap.
    None,
    /// A finger overlaps the cube.
    Finger,
    /// The palm overlaps the cube.
    Palm,
}

/// Which gripper part, if any, overlaps `cube` at the tool pose and opening.
pub fn contact(
    gripper: &GripperConfig,
    tool: &Isometry3<f64>,
    opening: f64,
    cube: &OrientedBox,
) -> Contact {
    if gripper.palm(tool).intersects(cube) {
        Contact::Palm
    } else if gripper
        .fingers(tool, opening)
        .iter()
        .any(|f| f.intersects(cube))
    {
        Contact::Finger
    } else {
        Contact::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// A top-down tool (z pointing down) at `position`, turned by `yaw` about world z.
    fn top_down(position: Vector3<f64>, yaw: f64) -> Isometry3<f64> {
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        Isometry3::from_parts(position.into(), turn * down)
    }

    fn cube_at(position: Vector3<f64>, yaw: f64) -> Isometry3<f64> {
        Isometry3::new(position, Vector3::z() * yaw)
    }

    fn window(tool: &Isometry3<f64>, cube: &Isometry3<f64>) -> Result<(), GraspMiss> {
        check_window(
            &CubeInTool::new(tool, cube),
            0.08,
            0.03,
            &GripperConfig::default(),
            &GraspConfig::default(),
        )
    }

    #[test]
    fn centred_cube_is_in_the_window() {
        let centre = Vector3::new(2.0, 0.0, 0.45);
        assert_eq!(
            window(&top_down(centre, 0.3), &cube_at(centre, 0.3)),
            Ok(())
        );
    }

    #[test]
    fn three_centimetre_lateral_offsets_are_rejected() {
        let tool = top_down(Vector3::new(2.0, 0.0, 0.45), 0.0);
        // Tool x is world x, tool y is world −y for this top-down tool.
        let along_width = cube_at(Vector3::new(2.03, 0.0, 0.45), 0.0);
        assert_eq!(window(&tool, &along_width), Err(GraspMiss::Lateral));
        let along_closing = cube_at(Vector3::new(2.0, 0.03, 0.45), 0.0);
        let config = GripperConfig::default();
        let cube_box = OrientedBox::new(&along_closing, Vector3::repeat(0.015));
        // At full opening the cube centre is still between the fingers, but a finger lands on it.
        assert_eq!(contact(&config, &tool, 0.08, &cube_box), Contact::Finger);
    }

    #[test]
    fn height_and_yaw_limits() {
        let centre = Vector3::new(2.0, 0.0, 0.45);
        let cube = cube_at(centre, 0.0);
        // Tool point 3 cm above the cube centre: the pads barely reach the cube.
        let high = top_down(centre + Vector3::new(0.0, 0.0, 0.03), 0.0);
        assert_eq!(window(&high, &cube), Err(GraspMiss::Height));
        // Tool point 4 cm below the cube centre: the cube is in the palm.
        let low = top_down(centre - Vector3::new(0.0, 0.0, 0.04), 0.0);
        assert_eq!(window(&low, &cube), Err(GraspMiss::Height));
        let turned = top_down(centre, 0.7);
        assert_eq!(window(&turned, &cube), Err(GraspMiss::Yaw));
        // A quarter turn is symmetric for a cube.
        let quarter = top_down(centre, std::f64::consts::FRAC_PI_2 + 0.1);
        assert_eq!(window(&quarter, &cube), Ok(()));
    }

    #[test]
    fn open_fingers_straddle_a_centred_cube_without_contact() {
        let centre = Vector3::new(2.0, 0.0, 0.45);
        let cube_box = OrientedBox::new(&cube_at(centre, 0.0), Vector3::repeat(0.015));
        let config = GripperConfig::default();
        let tool = top_down(centre, 0.0);
        assert_eq!(contact(&config, &tool, 0.08, &cube_box), Contact::None);
        assert_eq!(contact(&config, &tool, 0.029, &cube_box), Contact::Finger);
        let too_low = top_down(centre - Vector3::new(0.0, 0.0, 0.05), 0.0);
        assert_eq!(contact(&config, &too_low, 0.08, &cube_box), Contact::Palm);
    }
}
