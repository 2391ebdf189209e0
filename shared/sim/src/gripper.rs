//! The parallel gripper (Franka Hand-like): a finite closing speed and the collision geometry of
//! its fingers and palm.
//!
//! Tool frame convention (the URDF tool link, e.g. `panda_tcp`): the origin is the tool point
//! between the fingertips, z points out of the hand (the approach direction, down for a top-down
//! grasp), and the fingers close along y.

use nalgebra::{Isometry3, Vector3};
use serde::Deserialize;

use crate::geometry::OrientedBox;
use motm_core::GripperCommand;

/// Dimensions and speed of the gripper.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GripperConfig {
    /// Opening between the fingers when fully open, m (80 mm on the Franka Hand).
    pub max_opening: f64,
    /// Speed at which the opening changes, m/s. The Franka Hand closes slowly: 0.1 m/s takes
    /// 0.5 s from fully open to the 30 mm cube.
    pub speed: f64,
    /// Length of the fingers from the palm to the fingertips, along tool z, m.
    pub finger_length: f64,
    /// How far the fingertips reach past the tool point along tool z, m.
    pub tip_beyond_tool_point: f64,
    /// Width of a finger pad along tool x, m.
    pub finger_width: f64,
    /// Thickness of a finger along the closing direction (tool y), m.
    pub finger_thickness: f64,
    /// Size of the palm (hand body) along tool x, y and z, m; it sits just above the fingers.
    pub palm_size: [f64; 3],
}

impl Default for GripperConfig {
    fn default() -> Self {
        Self {
            max_opening: 0.08,
            speed: 0.1,
            finger_length: 0.045,
            tip_beyond_tool_point: 0.005,
            finger_width: 0.02,
            finger_thickness: 0.012,
            palm_size: [0.06, 0.2, 0.06],
        }
    }
}

impl GripperConfig {
    /// Tool-frame z of the fingertips (the far end of the fingers).
    pub fn tip_z(&self) -> f64 {
        self.tip_beyond_tool_point
    }

    /// Tool-frame z of the palm face (where the fingers start).
    pub fn palm_z(&self) -> f64 {
        self.tip_beyond_tool_point - self.finger_length
    }

    /// The two finger boxes in the world, for the tool pose and opening.
    pub fn fingers(&self, tool: &Isometry3<f64>, opening: f64) -> [OrientedBox; 2] {
        let half_width = 0.5 * self.finger_width;
        let inner = 0.5 * opening;
        let outer = inner + self.finger_thickness;
        let (z0, z1) = (self.palm_z(), self.tip_z());
        [
            OrientedBox::from_bounds(
                tool,
                Vector3::new(-half_width, inner, z0),
                Vector3::new(half_width, outer, z1),
            ),
            OrientedBox::from_bounds(
                tool,
                Vector3::new(-half_width, -outer, z0),
                Vector3::new(half_width, -inner, z1),
            ),
        ]
    }

    /// The palm box in the world, for the tool pose.
    pub fn palm(&self, tool: &Isometry3<f64>) -> OrientedBox {
        let [x, y, z] = self.palm_size;
        let face = self.palm_z();
        OrientedBox::from_bounds(
            tool,
            Vector3::new(-0.5 * x, -0.5 * y, face - z),
            Vector3::new(0.5 * x, 0.5 * y, face),
        )
    }
}

/// The state of the gripper's fingers.
#[derive(Debug, Clone, PartialEq)]
pub struct Gripper {
    /// Current opening between the fingers, m.
    pub opening: f64,
    /// The command being carried out.
    pub command: GripperCommand,
}

impl Gripper {
    /// A fully open gripper.
    pub fn open(config: &GripperConfig) -> Self {
        Self {
            opening: config.max_opening,
            command: GripperCommand::Open,
        }
    }

    /// Moves the fingers for `dt` seconds toward the commanded end, stopping at `blocked_at`
    /// (the width of a held object) when closing. Returns the opening before the step.
    pub fn step(&mut self, dt: f64, config: &GripperConfig, blocked_at: Option<f64>) -> f64 {
        let before = self.opening;
        let travel = config.speed * dt;
        self.opening = match self.command {
            GripperCommand::Open => (self.opening + travel).min(config.max_opening),
            GripperCommand::Close => (self.opening - travel).max(blocked_at.unwrap_or(0.0)),
        };
        before
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closing_from_open_to_cube_width_takes_half_a_second() {
        let config = GripperConfig::default();
        let mut gripper = Gripper::open(&config);
        gripper.command = GripperCommand::Close;
        let mut steps = 0;
        while gripper.opening > 0.03 + 1e-12 {
            gripper.step(0.001, &config, None);
            steps += 1;
        }
        assert_eq!(steps, 500);
        for _ in 0..1000 {
            gripper.step(0.001, &config, Some(0.02));
        }
        assert!((gripper.opening - 0.02).abs() < 1e-12);
    }

    #[test]
    fn fingers_sit_either_side_of_the_tool_point_along_y() {
        let config = GripperConfig::default();
        let fingers = config.fingers(&Isometry3::identity(), 0.08);
        assert!((fingers[0].center.y - (0.04 + 0.006)).abs() < 1e-12);
        assert!((fingers[1].center.y + (0.04 + 0.006)).abs() < 1e-12);
        assert!((fingers[0].center.z - (0.005 - 0.0225)).abs() < 1e-12);
        let palm = config.palm(&Isometry3::identity());
        assert!((palm.center.z - (-0.04 - 0.03)).abs() < 1e-12);
    }
}
