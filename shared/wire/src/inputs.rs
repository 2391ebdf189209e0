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
    joints: Option<Latest<msgs::JointState>>,
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
    /// Arm joint positions (empty when joint states are not read).
    pub arm_q: &'a [f64],
    /// Monotonic stamp of the older of joint state and odometry, ns.
    pub stamp_ns: u64,
}

/// One cycle's view of the inputs.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<'a> {
    /// The mission, once known.
    pub mission: Option<MissionView>,
    /// The measured state, once odometry and (when read) joint state have arrived.
    pub measured: Option<Measured<'a>>,
    /// Target of the current task (with a mission).
    pub target: Option<TargetEstimate>,
    /// Capture stamp of the image behind `target`, ns, when it is a perception estimate.
    pub image_stamp_ns: Option<u64>,
}

impl ControlInputs {
    /// Subscribes on `bus` to all four inputs; a missing run-out point is placed
    /// `run_out_distance` beyond the last target.
    pub fn open(bus: &Bus, run_out_distance: f64) -> Result<Self, BusError> {
        Self::open_with(bus, run_out_distance, true)
    }

    /// Subscribes on `bus`, to joint states only when `with_joints` (each subscriber takes one
    /// of a service's limited subscriber slots).
    pub fn open_with(
        bus: &Bus,
        run_out_distance: f64,
        with_joints: bool,
    ) -> Result<Self, BusError> {
        let qos = Qos::default();
        Ok(Self {
            mission: Latest::new(bus, services::MISSION_STATE, &qos)?,
            joints: if with_joints {
                Some(Latest::new(bus, services::ARM_JOINT_STATE, &qos)?)
            } else {
                None
            },
            odometry: Latest::new(bus, services::BASE_ODOMETRY, &qos)?,
            target: Latest::new(bus, services::PERCEPTION_TARGET, &qos)?,
            latch: MissionLatch::new(run_out_distance),
            selector: TargetSelector::default(),
        })
    }

    /// Takes in every sample that arrived (invalid ones are dropped and counted by the bus).
    pub fn update(&mut self) -> Result<(), BusError> {
        self.mission.update()?;
        if let Some(joints) = &mut self.joints {
            joints.update()?;
        }
        self.odometry.update()?;
        self.target.update()?;
        Ok(())
    }

    /// The latest odometry message.
    pub fn odometry(&self) -> Option<&msgs::BaseOdometry> {
        self.odometry.get()
    }

    /// The inputs at monotonic time `now_ns`.
    pub fn snapshot(&mut self, now_ns: u64) -> Snapshot<'_> {
        let mission = self
            .mission
            .get()
            .and_then(convert::mission_report)
            .and_then(|report| self.latch.update(&report));
        let perceived = self.target.get().map(convert::perceived);
        let selected = mission.map(|m| {
            self.selector
                .select_with_source(&m, now_ns, perceived.as_ref())
        });
        let joints = match &self.joints {
            Some(latest) => latest.get().map(Some),
            None => Some(None),
        };
        let measured = match (joints, self.odometry.get()) {
            (Some(joints), Some(odometry)) => Some(Measured {
                base: convert::base_pose(odometry),
                base_velocity: convert::base_velocity(odometry),
                arm_q: joints.map_or(&[][..], convert::arm_q),
                stamp_ns: joints.map_or(odometry.header.stamp_ns, |j| {
                    j.header.stamp_ns.min(odometry.header.stamp_ns)
                }),
            }),
            _ => None,
        };
        Snapshot {
            mission,
            measured,
            target: selected.map(|s| s.target),
            image_stamp_ns: selected.and_then(|s| s.image_stamp_ns),
        }
    }
}
