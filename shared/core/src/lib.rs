//! # motm-core
//!
//! Robot models, kinematics and the control laws of reactive mobile manipulation on-the-move.
//! Everything here is pure code: no IPC and no I/O beyond reading model and configuration files.
//!
//! The folders are the layers:
//! - [`model`]: the robot model (robot, URDF chains, kinematics, palm camera, manipulation
//!   range, shared value types and errors);
//! - [`control`]: the MotM control laws (base controller, reacher, final-phase controllers,
//!   redundancy-resolution QP, perception, mission) and the per-process cycle functions;
//! - [`baselines`]: the reactive (holistic) and the planning baselines;
//! - [`supervision`]: watchdog rules, hot swap, restart policy, fault schedule;
//! - [`limits`]: the drivers' command limiter and velocity driver.
//!
//! The tasks that run these laws as processes are in `motm-tasks`, the graph and its runtimes
//! in `motm-graph` and `motm-runtime`.

pub mod baselines;
pub mod control;
pub mod limits;
pub mod model;
pub mod supervision;

// Every module is also reachable at the crate root, so that a path names the concept
// (`motm_core::reacher`) while the folders show the layer it belongs to.
pub use baselines::{holistic, planning, reactive};
pub use control::{
    base_command_rate, base_controller, base_slip, facing, final_phase, input_check, localization,
    mission, mission_file, mission_tracker, on_the_move, outline, perception, qp_scenario, quintic,
    reacher, resolver, route, servo, stack,
};
pub use limits::{command_limiter, velocity_driver};
pub use model::{camera, chain, config_dir, error, kinematics, reach_range, robot, types};
pub use supervision::{fault_schedule, hot_swap, restart_policy, watchdog};

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
