//! The inputs most control tasks share (mission state, joint state, odometry, perception's
//! target), decoded into the core types with the one target-selection rule
//! ([`TargetSelector`]).

use motm_core::kinematics::BasePose;
use motm_core::stack::{MissionLatch, MissionView, TargetSelector};
use motm_core::{BaseVelocity, TargetEstimate};
use motm_msgs as msgs;

use crate::convert;

/// The robot state measured by the drivers.
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// Base pose (odometry).
    pub base: BasePose,
    /// Measured base velocity (odometry).
    pub base_velocity: BaseVelocity,
    /// Arm joint positions (empty when the task does not read joint states).
    pub arm_q: &'a [f64],
    /// Monotonic stamp of the older of joint state and odometry, ns.
    pub stamp_ns: u64,
}

/// One cycle's view of the shared inputs.
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
    /// Publication time of the frame perception computed `target` from, ns, when it is a
    /// perception estimate that carries one.
    pub image_published_ns: Option<u64>,
}

/// The raw shared inputs of one cycle.
#[derive(Debug, Clone, Copy)]
pub struct Raw<'a> {
    /// The supervisor's mission state.
    pub mission: Option<&'a msgs::MissionState>,
    /// The arm driver's joint state; `None` inside `Some` means the task reads none.
    pub joints: Option<Option<&'a msgs::JointState>>,
    /// The base driver's odometry.
    pub odometry: Option<&'a msgs::BaseOdometry>,
    /// Perception's estimate.
    pub target: Option<&'a msgs::TargetEstimate>,
}

/// The state a task keeps to decode its shared inputs: the mission latch (the last task, for
/// after the mission) and the target selector.
#[derive(Debug, Clone, Copy, Default)]
pub struct ControlView {
    latch: MissionLatch,
    selector: TargetSelector,
}

impl ControlView {
    /// A view that places a missing run-out point `run_out_distance` beyond the last target.
    pub fn new(run_out_distance: f64) -> Self {
        Self {
            latch: MissionLatch::new(run_out_distance),
            selector: TargetSelector,
        }
    }

    /// This cycle's inputs.
    pub fn snapshot<'a>(&mut self, raw: Raw<'a>) -> Snapshot<'a> {
        let mission = raw
            .mission
            .and_then(convert::mission_report)
            .and_then(|report| self.latch.update(&report));
        let perceived = raw.target.map(convert::perceived);
        let selected = mission.map(|m| self.selector.select_with_source(&m, perceived.as_ref()));
        let measured = match (raw.joints, raw.odometry) {
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
            image_published_ns: selected
                .and_then(|s| s.image_stamp_ns)
                .and(raw.target)
                .map(|t| t.image_published_ns)
                .filter(|&ns| ns > 0),
        }
    }
}

/// `Some(joints)` when a joint state has arrived, as [`Raw::joints`] wants it for a task that
/// reads joint states.
pub fn read_joints(joints: &Option<msgs::JointState>) -> Option<Option<&msgs::JointState>> {
    joints.as_ref().map(Some)
}
