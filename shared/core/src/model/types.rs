//! Small value types shared by the control modules.

use nalgebra::{Isometry3, Vector3, Vector6};

/// A planar base velocity: forward speed `v` (m/s) and yaw rate `omega` (rad/s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BaseVelocity {
    /// Forward speed along the base x axis.
    pub v: f64,
    /// Yaw rate about world z.
    pub omega: f64,
}

/// A world-frame spatial velocity of the end effector, `[vx, vy, vz, wx, wy, wz]`.
pub type Twist = Vector6<f64>;

/// What the stack believes about a target object: world position and velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetEstimate {
    /// World position of the target point (e.g. the cube centre), m.
    pub position: Vector3<f64>,
    /// World velocity of the target, m/s (zero for a static object).
    pub velocity: Vector3<f64>,
}

impl TargetEstimate {
    /// A target that does not move.
    pub fn fixed(position: Vector3<f64>) -> Self {
        Self {
            position,
            velocity: Vector3::zeros(),
        }
    }

    /// Where the target will be after `dt` seconds at its current velocity.
    pub fn predict(&self, dt: f64) -> Vector3<f64> {
        self.position + self.velocity * dt
    }
}

/// What the gripper should do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GripperCommand {
    /// Open fully (or stay open).
    #[default]
    Open,
    /// Close on an object.
    Close,
}

/// Where a final-phase task stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TaskProgress {
    /// Still working.
    #[default]
    Active,
    /// The task's motion is complete (e.g. the cube is lifted, dropped or the button pressed).
    Done,
}

/// The robot state every controller reads in one cycle.
#[derive(Debug, Clone)]
pub struct RobotState {
    /// Base pose in the world (from odometry).
    pub base: crate::kinematics::BasePose,
    /// Measured base velocity.
    pub base_velocity: BaseVelocity,
    /// Arm joint positions (the virtual base joints are not included).
    pub arm_q: Vec<f64>,
    /// World pose of the tool at `arm_q`.
    pub tool_pose: Isometry3<f64>,
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut w = a.rem_euclid(two_pi);
    if w > std::f64::consts::PI {
        w -= two_pi;
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_maps_into_half_open_interval() {
        use std::f64::consts::PI;
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-PI / 2.0 - 2.0 * PI) + PI / 2.0).abs() < 1e-12);
        assert!((wrap_angle(0.25) - 0.25).abs() < 1e-15);
    }
}
