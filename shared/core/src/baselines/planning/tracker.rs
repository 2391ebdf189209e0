//! Open-loop tracking of a [`Plan`]: the planned velocities as feed-forward, plus servoing of
//! the robot's own measured base pose and tool pose to the planned ones. Nothing about the
//! object is observed after t = 0.

use nalgebra::{UnitQuaternion, Vector3};

use super::geometry::RobotGeometry;
use super::{Plan, PlanRequest, PlanningConfig, PlanningError, TrackingConfig};
use crate::robot::Robot;
use crate::types::{BaseVelocity, GripperCommand, RobotState, TaskProgress, Twist, wrap_angle};

/// Which part of the plan is being executed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanPhase {
    /// Before the grasp time: the gripper moves to the cube.
    Approach,
    /// Grasp dwell: the gripper holds still at the cube while the fingers close.
    Grasp,
    /// Between the grasp dwell and the drop: lift and carry.
    Carry,
    /// Drop dwell: the gripper holds still over the container while the fingers open.
    Drop,
    /// After the drop: base and gripper come to rest.
    Stop,
    /// The plan has ended.
    Finished,
}

/// One cycle's command from the planning baseline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanningCommand {
    /// Base velocity command.
    pub base: BaseVelocity,
    /// World-frame gripper twist for the redundancy resolver.
    pub gripper_twist: Twist,
    /// Gripper command (closed from the grasp time to the drop time).
    pub gripper: GripperCommand,
    /// `Done` once the plan has ended.
    pub progress: TaskProgress,
    /// Which part of the plan is active.
    pub phase: PlanPhase,
    /// False when the robot state was not finite; the velocities are then zero.
    pub state_valid: bool,
}

/// Tracks a [`Plan`]. A pure function of time and the measured robot state.
#[derive(Debug, Clone)]
pub struct PlanningController {
    plan: Plan,
    tracking: TrackingConfig,
    gripper_orientation: UnitQuaternion<f64>,
    base_speed_limit: f64,
    yaw_rate_limit: f64,
}

impl PlanningController {
    /// A controller that tracks `plan` for `robot`. The gripper orientation target is the
    /// ready-pose tool orientation turned by `tracking.gripper_yaw` about world z.
    pub fn new(plan: Plan, robot: &Robot, tracking: &TrackingConfig) -> Self {
        let geometry = RobotGeometry::from_robot(robot);
        Self {
            plan,
            tracking: tracking.clone(),
            gripper_orientation: UnitQuaternion::from_axis_angle(
                &Vector3::z_axis(),
                tracking.gripper_yaw,
            ) * geometry.ready_orientation,
            base_speed_limit: geometry.base_speed_limit,
            yaw_rate_limit: geometry.yaw_rate_limit,
        }
    }

    /// Plans for `request` (see [`super::plan`]) and returns the controller that tracks it.
    pub fn from_request(
        robot: &Robot,
        request: &PlanRequest,
        config: &PlanningConfig,
    ) -> Result<Self, PlanningError> {
        let plan = super::plan(robot, request, config)?;
        Ok(Self::new(plan, robot, &config.tracking))
    }

    /// The plan being tracked.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// The phase of the plan at time `t`.
    pub fn phase(&self, t: f64) -> PlanPhase {
        let plan = &self.plan;
        if t < plan.grasp_time() {
            PlanPhase::Approach
        } else if t < plan.grasp_end_time() {
            PlanPhase::Grasp
        } else if t < plan.drop_time() {
            PlanPhase::Carry
        } else if t < plan.drop_end_time() {
            PlanPhase::Drop
        } else if t < plan.finish_time() {
            PlanPhase::Stop
        } else {
            PlanPhase::Finished
        }
    }

    /// The command at time `t` (s since planning) for the measured `state`.
    ///
    /// Base: Kanayama tracking law on the planned pose, with the planned (v, ω) as feed-forward,
    /// saturated at the base limits. Gripper: planned velocity plus a proportional pull to the
    /// planned position, and a proportional pull to the top-down orientation, both saturated.
    /// A non-finite `t` or state gives zero velocities (never NaN).
    pub fn step(&self, t: f64, state: &RobotState) -> PlanningCommand {
        let t = if t.is_finite() { t.max(0.0) } else { f64::NAN };
        let gripper_closed = t >= self.plan.grasp_time() && t < self.plan.drop_time();
        let phase = if t.is_nan() {
            PlanPhase::Approach
        } else {
            self.phase(t)
        };
        let mut command = PlanningCommand {
            base: BaseVelocity::default(),
            gripper_twist: Twist::zeros(),
            gripper: if gripper_closed {
                GripperCommand::Close
            } else {
                GripperCommand::Open
            },
            progress: if phase == PlanPhase::Finished {
                TaskProgress::Done
            } else {
                TaskProgress::Active
            },
            phase,
            state_valid: false,
        };
        let base = &state.base;
        let tool = &state.tool_pose;
        let state_finite = base.x.is_finite()
            && base.y.is_finite()
            && base.yaw.is_finite()
            && tool.translation.vector.iter().all(|v| v.is_finite())
            && tool.rotation.coords.iter().all(|v| v.is_finite());
        if t.is_nan() || !state_finite {
            return command;
        }
        let reference = self.plan.sample(t);
        let gains = &self.tracking;

        // Base: Kanayama et al. (1990) tracking law in the robot frame.
        let (s, c) = base.yaw.sin_cos();
        let dx = reference.base.x - base.x;
        let dy = reference.base.y - base.y;
        let along = c * dx + s * dy;
        let cross = -s * dx + c * dy;
        let heading_error = wrap_angle(reference.base.yaw - base.yaw);
        let v_ref = reference.base_velocity.v;
        let v = v_ref * heading_error.cos() + gains.base_along_gain * along;
        let omega = reference.base_velocity.omega
            + v_ref
                * (gains.base_cross_gain * cross + gains.base_heading_gain * heading_error.sin());
        command.base = BaseVelocity {
            v: v.clamp(-self.base_speed_limit, self.base_speed_limit),
            omega: omega.clamp(-self.yaw_rate_limit, self.yaw_rate_limit),
        };

        // Gripper: feed-forward plus proportional servoing.
        let linear = clamp_norm(
            reference.gripper_velocity
                + gains.gripper_position_gain * (reference.gripper - tool.translation.vector),
            gains.max_gripper_speed,
        );
        let rotation_error = (self.gripper_orientation * tool.rotation.inverse()).scaled_axis();
        let angular = clamp_norm(
            gains.gripper_orientation_gain * rotation_error,
            gains.max_gripper_angular_speed,
        );
        command.gripper_twist = Twist::new(
            linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
        );
        command.state_valid = true;
        command
    }
}

/// `v` scaled down to norm `limit` if it is longer.
fn clamp_norm(v: Vector3<f64>, limit: f64) -> Vector3<f64> {
    let norm = v.norm();
    if norm > limit { v * (limit / norm) } else { v }
}
