//! What the planner needs to know about the robot, derived from the robot model: where the arm is
//! mounted on the base, the base limits, the manipulation range and the ready-pose tool.

use nalgebra::{UnitQuaternion, Vector2, Vector3};

use crate::kinematics::BasePose;
use crate::robot::{BASE_JOINTS, Robot};

/// Robot quantities used by the planner, all taken from the [`Robot`] model.
#[derive(Debug, Clone)]
pub struct RobotGeometry {
    /// Horizontal position of the arm mount (the first arm joint frame) in the base frame, m.
    pub mount_offset: Vector2<f64>,
    /// Height of the first arm joint frame above the ground, m (the reach sphere's centre).
    pub shoulder_height: f64,
    /// Horizontal reach from the arm mount with good manipulability, m (robot config).
    pub manipulation_range: f64,
    /// Largest base forward speed, m/s (URDF limit of the forward base joint).
    pub base_speed_limit: f64,
    /// Largest base acceleration, m/s² (URDF limit of the forward base joint).
    pub base_acceleration: f64,
    /// Largest base yaw rate, rad/s (URDF limit of the yaw base joint).
    pub yaw_rate_limit: f64,
    /// Tool position at the ready pose with the base at the origin, in the base frame, m.
    pub ready_tool: Vector3<f64>,
    /// Tool orientation at the ready pose with the base at the origin.
    pub ready_orientation: UnitQuaternion<f64>,
}

impl RobotGeometry {
    /// Derives the planner's robot quantities from `robot`.
    pub fn from_robot(robot: &Robot) -> Self {
        let chain = &robot.chain;
        let mut frame = nalgebra::Isometry3::identity();
        for joint in &chain.joints[..BASE_JOINTS] {
            frame = frame * joint.origin * joint.motion(0.0);
        }
        frame *= chain.joints[BASE_JOINTS].origin;
        let mount = frame.translation.vector;
        let limits = robot.limits();
        let ready = robot.tool_pose(&BasePose::default(), &robot.config.ready_pose);
        Self {
            mount_offset: mount.xy(),
            shoulder_height: mount.z,
            manipulation_range: robot.config.manipulation_range,
            base_speed_limit: limits[1].velocity,
            base_acceleration: limits[1].acceleration,
            yaw_rate_limit: limits[0].velocity,
            ready_tool: ready.translation.vector,
            ready_orientation: ready.rotation,
        }
    }

    /// World (x, y) of the arm mount when the base is at `base`.
    pub fn mount_position(&self, base: &BasePose) -> Vector2<f64> {
        Vector2::new(base.x, base.y) + rotate(self.mount_offset, base.yaw)
    }

    /// World position of the ready-pose tool when the base is at `base`.
    pub fn ready_tool_position(&self, base: &BasePose) -> Vector3<f64> {
        (base.isometry() * nalgebra::Point3::from(self.ready_tool)).coords
    }
}

/// `v` rotated by `angle` about z.
pub(crate) fn rotate(v: Vector2<f64>, angle: f64) -> Vector2<f64> {
    let (s, c) = angle.sin_cos();
    Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}
