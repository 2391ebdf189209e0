//! iceoryx2 service names. Every name starts with `motm/v<SCHEMA_VERSION>/`, so a process built
//! with other message types cannot attach to a service of this version. This is the one place
//! the names are spelt; the typed topics ([`crate::topics`]) and the graph's table
//! (`motm_graph::GRAPH`, which lists who publishes and reads each) are made of them.

/// Prefix of every service name of this schema version.
pub const PREFIX: &str = "motm/v1";

/// Arm joint state from the arm driver ([`crate::JointState`]).
pub const ARM_JOINT_STATE: &str = "motm/v1/arm/joint_state";
/// Gripper state from the arm driver ([`crate::GripperState`]).
pub const ARM_GRIPPER_STATE: &str = "motm/v1/arm/gripper_state";
/// Joint velocity command from the QP resolver to the arm driver ([`crate::ArmVelocityCommand`]).
pub const ARM_VELOCITY_COMMAND: &str = "motm/v1/arm/velocity_command";
/// Gripper command from the final-phase controller ([`crate::GripperCommand`]).
pub const ARM_GRIPPER_COMMAND: &str = "motm/v1/arm/gripper_command";
/// Base odometry from the base driver ([`crate::BaseOdometry`]).
pub const BASE_ODOMETRY: &str = "motm/v1/base/odometry";
/// Base velocity target from the base planner ([`crate::BaseVelocityCommand`]).
pub const BASE_VELOCITY_TARGET: &str = "motm/v1/base/velocity_target";
/// Base velocity command from the QP resolver to the base driver ([`crate::BaseVelocityCommand`]).
pub const BASE_VELOCITY_COMMAND: &str = "motm/v1/base/velocity_command";
/// Closest approach and time-to-range from the base planner ([`crate::BasePlan`]).
pub const BASE_PLAN: &str = "motm/v1/base/plan";
/// Palm camera image ([`crate::CameraImage`]).
pub const CAMERA_IMAGE: &str = "motm/v1/camera/image";
/// Target object estimate from perception ([`crate::TargetEstimate`]).
pub const PERCEPTION_TARGET: &str = "motm/v1/perception/target";
/// End-effector twist target from the reacher ([`crate::TwistCommand`]).
pub const CONTROL_REACH_TWIST: &str = "motm/v1/control/reach_twist";
/// End-effector twist target from the final-phase controller ([`crate::TwistCommand`]).
pub const CONTROL_FINAL_TWIST: &str = "motm/v1/control/final_twist";
/// Status of the QP resolver's last solve ([`crate::QpStatus`]).
pub const CONTROL_QP_STATUS: &str = "motm/v1/control/qp_status";
/// Active controller id ([`crate::ActiveController`]).
pub const CONTROL_ACTIVE_CONTROLLER: &str = "motm/v1/control/active_controller";
/// Mission and task state from the supervisor ([`crate::MissionState`]).
pub const MISSION_STATE: &str = "motm/v1/mission/state";
/// Safe-stop from the watchdog ([`crate::SafeStop`]).
pub const SAFETY_SAFE_STOP: &str = "motm/v1/safety/safe_stop";
/// Arm command from the arm driver to the simulated (or real) hardware ([`crate::ArmVelocityCommand`]).
pub const HW_ARM_COMMAND: &str = "motm/v1/hw/arm_command";
/// Arm state from the simulated (or real) hardware ([`crate::JointState`]).
pub const HW_ARM_STATE: &str = "motm/v1/hw/arm_state";
/// Base command from the base driver to the simulated (or real) hardware ([`crate::BaseVelocityCommand`]).
pub const HW_BASE_COMMAND: &str = "motm/v1/hw/base_command";
/// Base state from the simulated (or real) hardware ([`crate::BaseOdometry`]).
pub const HW_BASE_STATE: &str = "motm/v1/hw/base_state";

/// Prefix of the per-process heartbeat services ([`crate::Heartbeat`]).
pub const HEARTBEAT_PREFIX: &str = "motm/v1/heartbeat";

/// Heartbeat service of one process, e.g. `motm/v1/heartbeat/qp-resolver`.
pub fn heartbeat(process: &str) -> String {
    format!("{HEARTBEAT_PREFIX}/{process}")
}

/// Event service that wakes the readers of `service` when a sample was published on it.
pub fn ready_event(service: &str) -> String {
    format!("{service}/ready")
}

/// The supervisor's process table ([`crate::SupervisorStatus`]).
pub const SUPERVISOR_STATUS: &str = "motm/v1/supervisor/status";

/// Gripper command from the arm driver to the simulated (or real) hardware ([`crate::GripperCommand`]).
pub const HW_GRIPPER_COMMAND: &str = "motm/v1/hw/gripper_command";
/// Gripper state from the simulated (or real) hardware ([`crate::GripperState`]).
pub const HW_GRIPPER_STATE: &str = "motm/v1/hw/gripper_state";
/// Ground truth of the simulated world ([`crate::SimTruth`]).
pub const SIM_TRUTH: &str = "motm/v1/sim/truth";
/// Status and limit counters of the arm driver ([`crate::DriverStatus`]).
pub const ARM_DRIVER_STATUS: &str = "motm/v1/arm/driver_status";
/// Status and limit counters of the base driver ([`crate::DriverStatus`]).
pub const BASE_DRIVER_STATUS: &str = "motm/v1/base/driver_status";

/// Hot-swap requests to the supervisor ([`crate::SwapRequest`]).
pub const SUPERVISOR_SWAP_REQUEST: &str = "motm/v1/supervisor/swap_request";
/// The supervisor's hot-swap reports ([`crate::SwapStatus`]).
pub const SUPERVISOR_SWAP_STATUS: &str = "motm/v1/supervisor/swap_status";
/// What each task cycle of the deployed stack consumed and produced ([`crate::TaskCycle`]),
/// from every task process: the replay log's index.
pub const REPLAY_CYCLES: &str = "motm/v1/replay/cycles";
