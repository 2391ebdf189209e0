//! The reactive baseline: Haviland et al.'s holistic mobile-manipulation controller
//! (robotics-toolbox-python `examples/holistic_mm_non_holonomic.py`), "stop and grasp".
//!
//! Each step, exactly as the reference:
//! 1. `e_t` = L1 norm of the translation of `wTe⁻¹ · wTep` (tool frame);
//! 2. `ν = p_servo(wTe, wTep, gain 1.5)` in the **tool frame**, rotation part × 1.3;
//! 3. the QP of [`crate::resolver`] with the tool-frame Jacobian (`jacobe`), `Y = 0.01`,
//!    `Q = diag(Y/e_t base, Y arm, 1/e_t slack)`, `c = −∇m` on the arm, and the base facing term
//!    `c[ω] = −0.5·atan2(p_e.y, p_e.x)` (tool position in the base frame), no base tracking;
//! 4. the result is scaled by `0.7/e_t` when `e_t > 0.5`, else by 1.4;
//! 5. arrived when `e_t < 0.02` (measured before the step's motion).
//!
//! Differences from the reference, both configurable: the QP's base velocity bounds are
//! robotics-toolbox's Frankie `qdlim` (4 rad/s, 4 m/s) by default because the post-QP scaling
//! assumes them; and the final command is scaled down uniformly (direction kept) so that no joint
//! exceeds the robot's own velocity limits ([`HolisticConfig::clamp_to_robot_limits`]).

use nalgebra::{Isometry3, Vector6};
use serde::Deserialize;

use crate::kinematics::{BasePose, manipulability_gradient};
use crate::resolver::{
    Facing, RedundancyResolver, ResolveStatus, ResolverConfig, ResolverInput,
    margined_velocity_limits,
};
use crate::robot::{BASE_JOINTS, Robot};
use crate::servo::{RotationError, jacobian_world_to_tool, pose_error};
use crate::types::BaseVelocity;

/// Gains of the holistic baseline. Defaults are the reference example's values.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HolisticConfig {
    /// Position-based servoing gain. 1.5.
    pub servo_gain: f64,
    /// Extra factor on the rotational part of the servo twist. 1.3.
    pub rotation_gain_scale: f64,
    /// Arrival threshold on `e_t`, m. 0.02.
    pub arrival_error: f64,
    /// Above this `e_t` (m) the command is scaled by `far_speed_scale / e_t`. 0.5.
    pub far_error: f64,
    /// Numerator of the far-field scaling. 0.7.
    pub far_speed_scale: f64,
    /// Scaling applied when `e_t ≤ far_error`. 1.4.
    pub near_speed_scale: f64,
    /// Base (ω, v) velocity bounds used inside the QP, before scaling; `None` uses the robot
    /// model's. Default `[4.0, 4.0]`, robotics-toolbox's Frankie `qdlim`.
    pub qp_base_velocity_limits: Option<[f64; 2]>,
    /// Scale the final command uniformly so that every joint respects the robot's own velocity
    /// limits (with the resolver's margins). Default true.
    pub clamp_to_robot_limits: bool,
    /// The QP's gains (joint weight, damper, slack bound, margins).
    pub resolver: ResolverConfig,
}

impl Default for HolisticConfig {
    fn default() -> Self {
        Self {
            servo_gain: 1.5,
            rotation_gain_scale: 1.3,
            arrival_error: 0.02,
            far_error: 0.5,
            far_speed_scale: 0.7,
            near_speed_scale: 1.4,
            qp_base_velocity_limits: Some([4.0, 4.0]),
            clamp_to_robot_limits: true,
            resolver: ResolverConfig::default(),
        }
    }
}

/// One step's input to [`HolisticController::step`].
#[derive(Debug, Clone, Copy)]
pub struct HolisticInput<'a> {
    /// Base pose in the world.
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// World pose the tool must reach.
    pub target: Isometry3<f64>,
}

/// One step's output of [`HolisticController::step`].
#[derive(Debug, Clone, PartialEq)]
pub struct HolisticOutput {
    /// Base command (v, ω).
    pub base: BaseVelocity,
    /// Arm joint velocity command.
    pub arm_qd: Vec<f64>,
    /// Whether `e_t` was below the arrival threshold at the start of this step.
    pub arrived: bool,
    /// `e_t`: L1 norm of the tool-frame translation error, m.
    pub position_error: f64,
    /// How the QP ended (a failure gives a zero command).
    pub status: ResolveStatus,
}

/// The holistic reactive controller for one robot.
#[derive(Debug)]
pub struct HolisticController {
    robot: Robot,
    config: HolisticConfig,
    resolver: RedundancyResolver,
    robot_velocity_limits: Vec<f64>,
}

impl HolisticController {
    /// A controller for `robot`.
    pub fn new(robot: Robot, config: HolisticConfig) -> Self {
        let mut limits = robot.limits();
        if let Some([omega, v]) = config.qp_base_velocity_limits {
            limits[0].velocity = omega;
            limits[1].velocity = v;
        }
        let resolver = RedundancyResolver::new(&limits, config.resolver.clone());
        let robot_velocity_limits = margined_velocity_limits(&robot.limits(), &config.resolver);
        Self {
            robot,
            config,
            resolver,
            robot_velocity_limits,
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &HolisticConfig {
        &self.config
    }

    /// How many steps returned the zero fallback.
    pub fn error_count(&self) -> u64 {
        self.resolver.error_count()
    }

    /// One control step toward `input.target`.
    pub fn step(&mut self, input: &HolisticInput<'_>) -> HolisticOutput {
        let cfg = &self.config;
        let fk = self.robot.forward(&input.base, input.arm_q);
        let error = pose_error(&fk.tool_pose, &input.target, RotationError::Rpy);
        let position_error = error.fixed_rows::<3>(0).abs().sum();
        let arrived = position_error < cfg.arrival_error;
        let g = cfg.servo_gain;
        let gr = g * cfg.rotation_gain_scale;
        let twist = Vector6::new(g, g, g, gr, gr, gr).component_mul(&error);
        let jacobian = jacobian_world_to_tool(&fk.tool_pose, &fk.jacobian);
        let (_, gradient) = manipulability_gradient(&Robot::arm_jacobian(&fk.jacobian));
        let tool_in_base = input
            .base
            .isometry()
            .inverse_transform_point(&fk.tool_pose.translation.vector.into())
            .coords;
        let out = self.resolver.resolve(&ResolverInput {
            jacobian: &jacobian,
            twist,
            arm_q: input.arm_q,
            manipulability_gradient: &gradient,
            position_error,
            facing: Facing::Base { tool_in_base },
            base_velocity_target: None,
        });
        if !out.status.is_ok() {
            return HolisticOutput {
                base: BaseVelocity::default(),
                arm_qd: vec![0.0; self.robot.arm_dof()],
                arrived,
                position_error,
                status: out.status,
            };
        }
        let mut qd = out.joint_velocities();
        let scale = if position_error > cfg.far_error {
            cfg.far_speed_scale / position_error
        } else {
            cfg.near_speed_scale
        };
        qd *= scale;
        if cfg.clamp_to_robot_limits {
            let worst = qd
                .iter()
                .zip(&self.robot_velocity_limits)
                .map(|(v, lim)| v.abs() / lim)
                .fold(1.0, f64::max);
            qd /= worst;
        }
        HolisticOutput {
            base: BaseVelocity {
                v: qd[1],
                omega: qd[0],
            },
            arm_qd: qd.iter().skip(BASE_JOINTS).copied().collect(),
            arrived,
            position_error,
            status: out.status,
        }
    }
}
