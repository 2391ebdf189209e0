//! The latest-value inputs most control services read each cycle: mission state, joint state,
//! odometry and perception's target, turned into the core types.

use motm_bus::{Bus, BusError, Latest, Qos};
use motm_core::kinematics::BasePose;
use motm_core::stack::{MissionLatch, MissionView, TargetSelector};
use motm_core::{BaseVelocity, TargetEstimate};
use motm_msgs as msgs;
use motm_msgs::services;

use crate::convert;

/// Subscriptions to mission, joint state, odometry and perception target.
pub struct ControlInputs {
    mission: Latest<msgs::MissionState>,
    joints: Latest<msgs::JointState>,
    odometry: Latest<msgs::BaseOdometry>,
    target: Latest<msgs::TargetEstimate>,
    latch: MissionLatch,
    selector: TargetSelector,
}

/// The robot state measured by the drivers.
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// Base pose (odometry).
    pub base: BasePose,
    /// Measured base velocity (odometry).
    pub base_velocity: BaseVelocity,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Monotonic stamp of the older of joint state and odometry, ns.
    pub stamp_ns: u64,
}

/// One cycle's view of the inputs.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<'a> {
    /// The mission, once known.
    pub mission: Option<MissionView>,
    /// The measured state, once both joint state and odometry have arrived.
    pub measured: Option<Measured<'a>>,
    /// Target of the current task (with a mission).
    pub target: Option<TargetEstimate>,
}

impl ControlInputs {
    /// Subscribes on `bus`; a missing run-out point is placed `run_out_distance` beyond the
    /// last target.
    pub fn open(bus: &Bus, run_out_distance: f64) -> Result<Self, BusError> {
        let qos = Qos::default();
        Ok(Self {
            mission: Latest::new(bus, services::MISSION_STATE, &qos)?,
            joints: Latest::new(bus, services::ARM_JOINT_STATE, &qos)?,
            odometry: Latest::new(bus, services::BASE_ODOMETRY, &qos)?,
            target: Latest::new(bus, services::PERCEPTION_TARGET, &qos)?,
            latch: MissionLatch::new(run_out_distance),
            selector: TargetSelector::default(),
        })
    }

    /// Takes in every sample that arrived (invalid ones are dropped and counted by the bus).
    pub fn update(&mut self) -> Result<(), BusError> {
        self.mission.update()?;
        self.joints.update()?;
        self.odometry.update()?;
        self.target.update()?;
        Ok(())
    }

    /// The latest joint state message.
    pub fn joint_state(&self) -> Option<&msgs::JointState> {
        self.joints.get()
    }

    /// The inputs at monotonic time `now_ns`.
    pub fn snapshot(&mut self, now_ns: u64) -> Snapshot<'_> {
        let mission = self
            .mission
            .get()
            .and_then(convert::mission_report)
            .and_then(|report| self.latch.update(&report));
        let perceived = self.target.get().map(convert::perceived);
        let target = mission.map(|m| self.selector.select(&m, now_ns, perceived.as_ref()));
        let measured = match (self.joints.get(), self.odometry.get()) {
            (Some(joints), Some(odometry)) => Some(Measured {
                base: convert::base_pose(odometry),
                base_velocity: convert::base_velocity(odometry),
                arm_q: convert::arm_q(joints),
                stamp_ns: joints.header.stamp_ns.min(odometry.header.stamp_ns),
            }),
            _ => None,
        };
        Snapshot {
            mission,
            measured,
            target,
        }
    }
}
