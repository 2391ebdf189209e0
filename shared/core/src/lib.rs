//! # motm-core
//!
//! Robot models, kinematics and the control laws of reactive mobile manipulation on-the-move.
//! Everything here is pure code: no IPC and no I/O beyond reading model and configuration files.
//!
//! - [`chain`]: serial chains loaded from URDF.
//! - [`kinematics`]: tool pose, world Jacobian, Hessian, manipulability and its gradient.
//! - [`mission`]: which target is current, which is next, which phase is active.
//! - [`planning`]: the planning baseline (plan once with a QP, then track open-loop).
//! - [`robot`]: mobile manipulators (virtual base joints + arm) and their TOML configuration.
//! - [`types`]: value types shared by the control modules.
//! - [`error`]: errors that name the file and element at fault.

pub mod chain;
pub mod error;
pub mod kinematics;
pub mod mission;
pub mod planning;
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
