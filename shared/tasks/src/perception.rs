//! The perception task: keeps the robot state it believes it has (each joint state at the
//! latest odometry pose), and for each new palm-camera image of the current pick or press
//! pairs the image with the tool pose of the state nearest its capture stamp, runs perception
//! and publishes the estimate (with the stamp of the image it came from). The tool pose is
//! computed for that one state only, not for every 1 kHz joint state.
//!
//! Assumption: camera image stamps are exposure times on the same monotonic clock as the
//! joint-state stamps. The task runs on each image's arrival, and at the control rate in
//! between so that its tool-pose history stays dense.

use std::collections::VecDeque;
use std::sync::Arc;

use motm_core::Robot;
use motm_core::camera::CameraCalibration;
use motm_core::kinematics::BasePose;
use motm_core::perception::PerceptionConfig;
use motm_core::stack::perception::{CameraFrame, PerceptionCycle};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};

use crate::convert;
use crate::view::{ControlView, Raw};

ports! {
    /// What perception reads.
    pub struct PerceptionInputs {
        /// The supervisor's mission.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Every joint state since the last cycle (for the tool-pose history).
        queue joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// The newest camera image.
        shared image: msgs::CameraImage = topics::CAMERA_IMAGE,
    }
}

ports! {
    /// What perception publishes.
    pub struct PerceptionOutputs {
        /// The estimate of the current target.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
    }
}

/// One believed robot state: its stamp, the base pose and the arm's joint positions.
type BelievedState = (u64, BasePose, [f64; msgs::MAX_ARM_JOINTS]);

/// The perception task.
pub struct PerceptionTask {
    robot: Robot,
    view: ControlView,
    cycle: PerceptionCycle,
    /// The last `history` believed states, oldest first.
    states: VecDeque<BelievedState>,
    history: usize,
    /// The image processed last (its sequence number and stamp).
    last_image: Option<(u64, u64)>,
    published: u64,
}

impl PerceptionTask {
    /// Perception for `robot` with `config` and the camera `calibration`, keeping `history`
    /// tool poses; `run_out_distance` as the mission's.
    pub fn new(
        robot: Robot,
        config: PerceptionConfig,
        calibration: CameraCalibration,
        history: usize,
        run_out_distance: f64,
    ) -> Self {
        Self {
            robot,
            view: ControlView::new(run_out_distance),
            cycle: PerceptionCycle::new(config, calibration, history),
            states: VecDeque::with_capacity(history.max(1)),
            history: history.max(1),
            last_image: None,
            published: 0,
        }
    }

    /// The same, knowing the mission's `tasks` (see [`PerceptionCycle::with_layout`]).
    pub fn with_layout(mut self, tasks: &[motm_core::mission::MissionTask]) -> Self {
        self.cycle = self.cycle.with_layout(tasks);
        self
    }

    /// Estimates published so far.
    pub fn published(&self) -> u64 {
        self.published
    }
}

impl Task for PerceptionTask {
    type Inputs = PerceptionInputs;
    type Outputs = PerceptionOutputs;

    fn name(&self) -> &'static str {
        motm_graph::PERCEPTION.name
    }

    fn step(&mut self, now_ns: u64, inputs: &PerceptionInputs) -> PerceptionOutputs {
        if let Some(odometry) = &inputs.odometry {
            let base = convert::base_pose(odometry);
            for state in &inputs.joints {
                if convert::arm_q(state).len() == self.robot.arm_dof() {
                    if self.states.len() == self.history {
                        self.states.pop_front();
                    }
                    self.states
                        .push_back((state.header.stamp_ns, base, state.position));
                }
            }
        }
        let snapshot = self.view.snapshot(Raw {
            mission: inputs.mission.as_ref(),
            joints: Some(None),
            odometry: inputs.odometry.as_ref(),
            target: None,
        });
        let (Some(mission), Some(image)) = (snapshot.mission, inputs.image.as_ref()) else {
            return PerceptionOutputs::default();
        };
        let id = (image.header.seq, image.header.stamp_ns);
        if self.last_image == Some(id) {
            return PerceptionOutputs::default();
        }
        self.last_image = Some(id);
        let image: &Arc<msgs::CameraImage> = image;
        let frame = CameraFrame {
            pixels: &image.pixels,
            width: image.width,
            height: image.height,
            stamp_ns: image.header.stamp_ns,
        };
        // The tool pose of the state nearest the exposure (the first of equals, as the pose
        // history picks).
        if let Some((stamp, base, q)) = self
            .states
            .iter()
            .min_by_key(|(stamp, _, _)| stamp.abs_diff(frame.stamp_ns))
        {
            let arm_q = &q[..self.robot.arm_dof()];
            self.cycle
                .record_tool(*stamp, self.robot.tool_pose(base, arm_q));
        }
        let report = self.cycle.observe(&mission, &frame);
        self.published += u64::from(report.is_some());
        PerceptionOutputs {
            target: report.map(|r| {
                let mut m = convert::target_message(&r);
                // The frame this estimate was computed from: the start of its latency.
                m.image_published_ns = image.image_published_ns;
                // The runtime reads its clock before the inputs: a frame that arrived in
                // between was published after `now_ns`, and an estimate is never stamped
                // before the frame it came from.
                convert::stamped(m, now_ns.max(image.image_published_ns))
            }),
        }
    }
}
