//! # motm-core
//!
//! Robot models, kinematics and the control laws of reactive mobile manipulation on-the-move.
//! Everything here is pure code: no IPC and no I/O beyond reading model and configuration files.
//!
//! - [`base_controller`]: closest-approach geometry and the constant-speed polar base controller.
//! - [`camera`]: the palm camera's equidistant fisheye model, configuration and calibration.
//! - [`chain`]: serial chains loaded from URDF.
//! - [`config_dir`]: where the `config/` folder is.
//! - [`command_limiter`]: the drivers' velocity, acceleration and jerk limiter with stale-command and safe-stop ramps.
//! - [`final_phase`]: swappable final-phase task controllers (grasp, drop, press-button).
//! - [`kinematics`]: tool pose, world Jacobian, Hessian, manipulability and its gradient.
//! - [`input_check`]: refusing non-finite controller input.
//! - [`on_the_move`]: the four MotM modules and the QP composed into one control step.
//! - [`mission`]: which target is current, which is next, which phase is active.
//! - [`planning`]: the planning baseline (plan once with a QP, then track open-loop).
//! - [`quintic`]: quintic trajectories with full boundary conditions.
//! - [`reach_range`]: manipulation range derived from the model.
//! - [`reacher`]: transit-time trigger and quintic reach toward the predicted object.
//! - [`perception`]: cube position and velocity from palm-camera images.
//! - [`reactive`]: the reactive (holistic stop-and-grasp) baseline's task stages.
//! - [`robot`]: mobile manipulators (virtual base joints + arm) and their TOML configuration.
//! - [`types`]: value types shared by the control modules.
//! - [`velocity_driver`]: the arm and base drivers' logic: command ages and gaps, limiter, self-check.
//! - [`servo`]: position-based servoing and twist/Jacobian frame changes.
//! - [`stack`]: the control loop split into per-process cycle functions for the deployed stack.
//! - [`resolver`]: the holistic redundancy-resolution QP, augmented for on-the-move.
//! - [`holistic`]: the reactive holistic (stop-and-grasp) baseline controller.
//! - [`qp_scenario`]: random representative resolver problems (benchmarks, tests).
//! - [`error`]: errors that name the file and element at fault.
//! - [`fault_schedule`]: the `motm run --fault` schedule (kill, stop, NaN sample).
//! - [`facing`]: which arm joint the MotM facing term turns toward the gripper.

pub mod base_command_rate;
pub mod base_controller;
pub mod base_slip;
pub mod camera;
pub mod chain;
pub mod command_limiter;
pub mod config_dir;
pub mod error;
pub mod facing;
pub mod fault_schedule;
pub mod final_phase;
pub mod holistic;
pub mod hot_swap;
pub mod input_check;
pub mod kinematics;
pub mod mission;
pub mod mission_tracker;
pub mod on_the_move;
pub mod perception;
pub mod planning;
pub mod qp_scenario;
pub mod quintic;
pub mod reach_range;
pub mod reacher;
pub mod reactive;
pub mod resolver;
pub mod restart_policy;
pub mod robot;
pub mod servo;
pub mod stack;
pub mod types;
pub mod velocity_driver;
pub mod watchdog;

pub use chain::{Chain, ChainJoint, JointKind, JointLimits};
pub use config_dir::resolve_config_dir;
pub use error::ModelError;
pub use holistic::{HolisticConfig, HolisticController, HolisticInput, HolisticOutput};
pub use kinematics::{
    BasePose, ForwardKinematics, hessian, manipulability, manipulability_gradient,
};
pub use resolver::{
    Facing, RedundancyResolver, ResolveStatus, ResolverConfig, ResolverInput, ResolverOutput,
};
pub use robot::{BASE_JOINTS, ROBOT_NAMES, Robot, RobotConfig};
pub use servo::{p_servo, twist_tool_to_world, twist_world_to_tool};
pub use types::{
    BaseVelocity, GripperCommand, RobotState, TargetEstimate, TaskProgress, Twist, wrap_angle,
};
