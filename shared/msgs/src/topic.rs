//! Typed topics: a service name together with the payload type carried on it, so a port can
//! only ever be opened with the type its topic was declared with.

use core::marker::PhantomData;

use crate::Message;

/// A topic: the service name of a `motm/v1/...` publish-subscribe service and its payload type.
pub struct Topic<T> {
    name: &'static str,
    payload: PhantomData<fn() -> T>,
}

impl<T> Clone for Topic<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Topic<T> {}

impl<T> core::fmt::Debug for Topic<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name)
    }
}

impl<T: Message> Topic<T> {
    /// The topic carrying `T` on service `name`.
    pub const fn new(name: &'static str) -> Self {
        Self {
            name,
            payload: PhantomData,
        }
    }

    /// The service name.
    pub const fn name(&self) -> &'static str {
        self.name
    }

    /// The untyped description of this topic (name and payload type name), for tables.
    pub const fn spec(&self) -> TopicSpec {
        TopicSpec {
            name: self.name,
            type_name: T::NAME,
        }
    }
}

/// A topic as data: its service name and the short name of its payload type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TopicSpec {
    /// Service name, e.g. `motm/v1/arm/joint_state`.
    pub name: &'static str,
    /// Payload type name ([`Message::NAME`]), e.g. `JointState`.
    pub type_name: &'static str,
}

/// Every fixed topic of the stack, typed.
pub mod topics {
    use super::Topic;
    use crate::services as s;
    use crate::*;

    /// Joint state from the arm driver.
    pub const ARM_JOINT_STATE: Topic<JointState> = Topic::new(s::ARM_JOINT_STATE);
    /// Gripper state from the arm driver.
    pub const ARM_GRIPPER_STATE: Topic<GripperState> = Topic::new(s::ARM_GRIPPER_STATE);
    /// Joint velocity command to the arm driver.
    pub const ARM_VELOCITY_COMMAND: Topic<ArmVelocityCommand> = Topic::new(s::ARM_VELOCITY_COMMAND);
    /// Gripper command to the arm driver.
    pub const ARM_GRIPPER_COMMAND: Topic<GripperCommand> = Topic::new(s::ARM_GRIPPER_COMMAND);
    /// Odometry from the base driver.
    pub const BASE_ODOMETRY: Topic<BaseOdometry> = Topic::new(s::BASE_ODOMETRY);
    /// The base planner's velocity target.
    pub const BASE_VELOCITY_TARGET: Topic<BaseVelocityCommand> =
        Topic::new(s::BASE_VELOCITY_TARGET);
    /// Base twist command to the base driver.
    pub const BASE_VELOCITY_COMMAND: Topic<BaseVelocityCommand> =
        Topic::new(s::BASE_VELOCITY_COMMAND);
    /// The base planner's plan (t_R, range-entry pose, closest approach).
    pub const BASE_PLAN: Topic<BasePlan> = Topic::new(s::BASE_PLAN);
    /// Palm-camera images.
    pub const CAMERA_IMAGE: Topic<CameraImage> = Topic::new(s::CAMERA_IMAGE);
    /// Perception's estimate of the current target.
    pub const PERCEPTION_TARGET: Topic<TargetEstimate> = Topic::new(s::PERCEPTION_TARGET);
    /// The reacher's tool twist.
    pub const CONTROL_REACH_TWIST: Topic<TwistCommand> = Topic::new(s::CONTROL_REACH_TWIST);
    /// The final-phase controllers' tool twists.
    pub const CONTROL_FINAL_TWIST: Topic<TwistCommand> = Topic::new(s::CONTROL_FINAL_TWIST);
    /// The QP resolver's status, with the twist it resolved.
    pub const CONTROL_QP_STATUS: Topic<QpStatus> = Topic::new(s::CONTROL_QP_STATUS);
    /// Id of the active final-phase controller.
    pub const CONTROL_ACTIVE_CONTROLLER: Topic<ActiveController> =
        Topic::new(s::CONTROL_ACTIVE_CONTROLLER);
    /// The supervisor's mission state.
    pub const MISSION_STATE: Topic<MissionState> = Topic::new(s::MISSION_STATE);
    /// The watchdog's safe-stop.
    pub const SAFETY_SAFE_STOP: Topic<SafeStop> = Topic::new(s::SAFETY_SAFE_STOP);
    /// Arm command from the driver to the hardware.
    pub const HW_ARM_COMMAND: Topic<ArmVelocityCommand> = Topic::new(s::HW_ARM_COMMAND);
    /// Arm state from the hardware.
    pub const HW_ARM_STATE: Topic<JointState> = Topic::new(s::HW_ARM_STATE);
    /// Base command from the driver to the hardware.
    pub const HW_BASE_COMMAND: Topic<BaseVelocityCommand> = Topic::new(s::HW_BASE_COMMAND);
    /// Base state from the hardware.
    pub const HW_BASE_STATE: Topic<BaseOdometry> = Topic::new(s::HW_BASE_STATE);
    /// Gripper command from the driver to the hardware.
    pub const HW_GRIPPER_COMMAND: Topic<GripperCommand> = Topic::new(s::HW_GRIPPER_COMMAND);
    /// Gripper state from the hardware.
    pub const HW_GRIPPER_STATE: Topic<GripperState> = Topic::new(s::HW_GRIPPER_STATE);
    /// Ground truth of the simulated world.
    pub const SIM_TRUTH: Topic<SimTruth> = Topic::new(s::SIM_TRUTH);
    /// The arm driver's status.
    pub const ARM_DRIVER_STATUS: Topic<DriverStatus> = Topic::new(s::ARM_DRIVER_STATUS);
    /// The base driver's status.
    pub const BASE_DRIVER_STATUS: Topic<DriverStatus> = Topic::new(s::BASE_DRIVER_STATUS);
    /// The supervisor's process table.
    pub const SUPERVISOR_STATUS: Topic<SupervisorStatus> = Topic::new(s::SUPERVISOR_STATUS);
    /// Hot-swap requests to the supervisor.
    pub const SUPERVISOR_SWAP_REQUEST: Topic<SwapRequest> = Topic::new(s::SUPERVISOR_SWAP_REQUEST);
    /// The supervisor's hot-swap reports.
    pub const SUPERVISOR_SWAP_STATUS: Topic<SwapStatus> = Topic::new(s::SUPERVISOR_SWAP_STATUS);
    /// What each task cycle consumed and produced, from every task process.
    pub const REPLAY_CYCLES: Topic<TaskCycle> = Topic::new(s::REPLAY_CYCLES);

    // The heartbeats the watchdog watches: every process's service loop publishes one on
    // `services::heartbeat(name)`; these are the control path's (a test checks the names).

    /// Heartbeat of the arm driver.
    pub const HEARTBEAT_PANDA_DRIVER: Topic<Heartbeat> =
        Topic::new("motm/v1/heartbeat/panda-driver");
    /// Heartbeat of the base driver.
    pub const HEARTBEAT_LD60_DRIVER: Topic<Heartbeat> = Topic::new("motm/v1/heartbeat/ld60-driver");
    /// Heartbeat of the reacher.
    pub const HEARTBEAT_REACHER: Topic<Heartbeat> = Topic::new("motm/v1/heartbeat/reacher");
    /// Heartbeat of the final phase.
    pub const HEARTBEAT_FINAL_PHASE: Topic<Heartbeat> = Topic::new("motm/v1/heartbeat/final-phase");
    /// Heartbeat of the QP resolver.
    pub const HEARTBEAT_QP_RESOLVER: Topic<Heartbeat> = Topic::new("motm/v1/heartbeat/qp-resolver");
    /// Heartbeat of the QP resolver's hot standby.
    pub const HEARTBEAT_QP_RESOLVER_STANDBY: Topic<Heartbeat> =
        Topic::new("motm/v1/heartbeat/qp-resolver-standby");
}
