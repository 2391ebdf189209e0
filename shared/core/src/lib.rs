//! # motm-core
//!
//! Robot models, kinematics and the control laws of reactive mobile manipulation on-the-move.
//! Everything here is pure code: no IPC and no I/O beyond reading model and configuration files.
//!
//! - [`base_controller`]: closest-approach geometry and the constant-speed polar base controller.
//! - [`chain`]: serial chains loaded from URDF.
//! - [`final_phase`]: swappable final-phase task controllers (grasp, drop, press-button).
//! - [`kinematics`]: tool pose, world Jacobian, Hessian, manipulability and its gradient.
//! - [`input_check`]: refusing non-finite controller input.
//! - [`mission`]: which target is current, which is next, which phase is active.
//! - [`quintic`]: quintic trajectories with full boundary conditions.
//! - [`reach_range`]: manipulation range derived from the model.
//! - [`reacher`]: transit-time trigger and quintic reach toward the predicted object.
//! - [`robot`]: mobile manipulators (virtual base joints + arm) and their TOML configuration.
//! - [`types`]: value types shared by the control modules.
//! - [`error`]: errors that name the file and element at fault.

pub mod base_controller;
pub mod chain;
pub mod error;
pub mod final_phase;
pub mod input_check;
pub mod kinematics;
pub mod mission;
pub mod quintic;
pub mod reach_range;
pub mod reacher;
pub mod robot;
pub mod types;

pub use chain::{Chain, ChainJoint, JointKind, JointLimits};
pub use error::ModelError;
pub use kinematics::{
    BasePose, ForwardKinematics, hessian, manipulability, manipulability_gradient,
};
pub use robot::{BASE_JOINTS, ROBOT_NAMES, Robot, RobotConfig};
pub use types::{
    BaseVelocity, GripperCommand, RobotState, TargetEstimate, TaskProgress, Twist, wrap_angle,
};
