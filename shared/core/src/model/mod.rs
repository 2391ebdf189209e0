//! The robot model: URDF chains and their kinematics, the robot and its settings, the palm
//! camera, the manipulation range, and the small value types and errors every layer shares.

pub mod camera;
pub mod chain;
pub mod config_dir;
pub mod error;
pub mod kinematics;
pub mod reach_range;
pub mod robot;
pub mod types;
