//! # motm-wire
//!
//! What the control services (perception, base-planner, reacher, final-phase, qp-resolver)
//! share beyond their step functions: the common command line and model loading ([`setup`]),
//! conversions between `motm-msgs` payloads and `motm-core` types ([`convert`]), and the
//! latest-value inputs most services read each cycle ([`inputs`]).
//!
//! Topics of the control services (names from `motm_msgs::services`):
//!
//! | process | reads | publishes |
//! | --- | --- | --- |
//! | perception | `CAMERA_IMAGE`, `ARM_JOINT_STATE` (queued), `BASE_ODOMETRY`, `MISSION_STATE` | `PERCEPTION_TARGET` (held estimate of the current pick, with `image_stamp_ns`) |
//! | base-planner | `BASE_ODOMETRY`, `MISSION_STATE`, `PERCEPTION_TARGET` | `BASE_VELOCITY_TARGET`, `BASE_PLAN` (t_R, range-entry pose, closest approach, task index) |
//! | reacher | `ARM_JOINT_STATE`, `BASE_ODOMETRY`, `MISSION_STATE`, `PERCEPTION_TARGET`, `BASE_PLAN`, `BASE_VELOCITY_TARGET`, `CONTROL_FINAL_TWIST` (of the active controller, `CONTROL_ACTIVE_CONTROLLER`) | `CONTROL_REACH_TWIST` (controller id 0) |
//! | final-phase | `ARM_JOINT_STATE`, `BASE_ODOMETRY`, `MISSION_STATE`, `PERCEPTION_TARGET`, `ARM_GRIPPER_STATE` | `CONTROL_FINAL_TWIST` (with task index and progress), `ARM_GRIPPER_COMMAND` |
//! | qp-resolver | `ARM_JOINT_STATE`, `BASE_ODOMETRY`, `MISSION_STATE`, `PERCEPTION_TARGET`, `CONTROL_REACH_TWIST`, `CONTROL_FINAL_TWIST`, `CONTROL_ACTIVE_CONTROLLER`, `BASE_VELOCITY_TARGET` | `ARM_VELOCITY_COMMAND`, `BASE_VELOCITY_COMMAND`, `CONTROL_QP_STATUS` |
//!
//! The final phase reports its task as done with `TwistCommand::progress == Done` (and the
//! task's index); the mission's supervisor advances on that.

pub mod controllers;
pub mod inputs;
pub mod setup;

pub use motm_tasks::convert;
pub use setup::{ServiceArgs, ServiceSetup, exit_on_error, report_exit};
