//! The final-phase task: one final-phase task controller (grasp, drop or press-button; fixed to
//! a variant or following the mission's task kind) during the final phase of the tasks it is
//! responsible for, and the resting gripper command outside it. Every command carries the
//! task's controller id, so a hot swap can tell the old controller from the new one.

use motm_core::Robot;
use motm_core::final_phase::FinalPhaseStage;
use motm_core::mission::{Phase, TaskKind};
use motm_core::reacher::{ReacherConfig, tool_yaw};
use motm_core::stack::final_phase::{FinalPhaseCycle, FinalPhaseCycleInput, VariantMode};
use motm_core::stack::seconds;
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};

use crate::view::{ControlView, Raw, read_joints};
use crate::{ControlSetup, convert};

ports! {
    /// What the final-phase controller reads.
    pub struct FinalPhaseInputs {
        /// The supervisor's mission.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
        /// The gripper's measured opening.
        latest gripper: msgs::GripperState = topics::ARM_GRIPPER_STATE,
    }
}

ports! {
    /// What the final-phase controller publishes.
    pub struct FinalPhaseOutputs {
        /// The final twist with the task's progress.
        latest twist: msgs::TwistCommand = topics::CONTROL_FINAL_TWIST,
        /// The gripper command.
        latest gripper: msgs::GripperCommand = topics::ARM_GRIPPER_COMMAND,
    }
}

/// The final-phase task.
pub struct FinalPhaseTask {
    robot: Robot,
    reacher: ReacherConfig,
    view: ControlView,
    cycle: FinalPhaseCycle,
    controller_id: u32,
    stage: Option<FinalPhaseStage>,
}

impl FinalPhaseTask {
    /// The controller of `setup` in `mode`, sending with `controller_id`.
    pub fn new(setup: &ControlSetup, mode: VariantMode, controller_id: u32) -> Self {
        Self {
            robot: setup.robot.clone(),
            reacher: setup.config.reacher.clone(),
            view: ControlView::new(setup.config.mission.run_out_distance),
            cycle: FinalPhaseCycle::new(mode, setup.config.final_phase),
            controller_id,
            stage: None,
        }
    }

    /// The controller's stage in the last cycle (`None` outside the final phase).
    pub fn stage(&self) -> Option<FinalPhaseStage> {
        self.stage
    }

    /// Cycles whose input was not finite.
    pub fn rejected(&self) -> u64 {
        self.cycle.rejected()
    }
}

impl Task for FinalPhaseTask {
    type Inputs = FinalPhaseInputs;
    type Outputs = FinalPhaseOutputs;

    fn name(&self) -> &'static str {
        motm_graph::FINAL_PHASE.name
    }

    fn step(&mut self, now_ns: u64, inputs: &FinalPhaseInputs) -> FinalPhaseOutputs {
        let snapshot = self.view.snapshot(Raw {
            mission: inputs.mission.as_ref(),
            joints: read_joints(&inputs.joints),
            odometry: inputs.odometry.as_ref(),
            target: inputs.target.as_ref(),
        });
        let (Some(mission), Some(measured), Some(target)) =
            (snapshot.mission, snapshot.measured, snapshot.target)
        else {
            self.stage = None;
            return FinalPhaseOutputs::default();
        };
        if measured.arm_q.len() != self.robot.arm_dof() {
            return FinalPhaseOutputs::default();
        }
        let tool_pose = self.robot.tool_pose(&measured.base, measured.arm_q);
        let grasp_yaw = (mission.kind == TaskKind::Pick).then(|| {
            self.reacher
                .grasp_yaw(mission.odometry_offset[2], tool_yaw(&tool_pose.rotation))
        });
        let out = self.cycle.step(&FinalPhaseCycleInput {
            mission,
            t: seconds(now_ns),
            tool_pose,
            base_pose: measured.base,
            base_velocity: measured.base_velocity,
            target,
            // Without a gripper state the controller refuses the cycle and nothing is sent.
            gripper_opening: inputs.gripper.as_ref().map_or(f64::NAN, |g| g.width),
            grasp_yaw,
        });
        self.stage = out.control.map(|c| c.stage);
        let accepted = out.control.is_none_or(|c| !c.input_rejected);
        FinalPhaseOutputs {
            twist: out.control.filter(|c| !c.input_rejected).map(|control| {
                convert::stamped(
                    convert::twist_command(
                        &control.twist,
                        mission.task_index,
                        Phase::Final,
                        control.progress,
                        self.controller_id,
                    ),
                    now_ns,
                )
            }),
            gripper: out.gripper.filter(|_| accepted).map(|gripper| {
                convert::stamped(
                    convert::gripper_command(gripper, self.controller_id),
                    now_ns,
                )
            }),
        }
    }
}
