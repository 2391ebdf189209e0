//! The reacher task: the reach-phase controller for the supervisor's current task, with the
//! base planner's plan and velocity target, at the measured joint state and odometry. The tool
//! state it feeds back is the twist the QP resolver last resolved (its status carries it).

use motm_core::mission::Phase;
use motm_core::stack::reacher::{ReacherCycle, ReacherCycleInput};
use motm_core::{BaseVelocity, TaskProgress, Twist};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, ControllerVariant, topics};

use crate::view::{ControlView, Raw, read_joints};
use crate::{ControlSetup, convert};

ports! {
    /// What the reacher reads.
    pub struct ReacherInputs {
        /// The supervisor's mission.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
        /// The base planner's plan.
        latest plan: msgs::BasePlan = topics::BASE_PLAN,
        /// The base planner's velocity target.
        latest base_target: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_TARGET,
        /// The QP resolver's status, with the twist it resolved.
        latest qp_status: msgs::QpStatus = topics::CONTROL_QP_STATUS,
    }
}

ports! {
    /// What the reacher publishes.
    pub struct ReacherOutputs {
        /// The reach twist (controller id 0), while the current task is reaching.
        latest twist: msgs::TwistCommand = topics::CONTROL_REACH_TWIST,
    }
}

/// The reacher task.
pub struct ReacherTask {
    view: ControlView,
    cycle: ReacherCycle,
    /// Sequence number of the last QP status fed back.
    fed_back: Option<u64>,
}

impl ReacherTask {
    /// The reacher of `setup`.
    pub fn new(setup: &ControlSetup) -> Self {
        Self {
            view: ControlView::new(setup.config.mission.run_out_distance),
            cycle: ReacherCycle::new(setup.robot.clone(), setup.config.clone(), setup.dt()),
            fed_back: None,
        }
    }
}

impl Task for ReacherTask {
    type Inputs = ReacherInputs;
    type Outputs = ReacherOutputs;

    fn name(&self) -> &'static str {
        motm_graph::REACHER.name
    }

    fn step(&mut self, now_ns: u64, inputs: &ReacherInputs) -> ReacherOutputs {
        if let Some(status) = &inputs.qp_status
            && self.fed_back != Some(status.header.seq)
        {
            self.fed_back = Some(status.header.seq);
            self.cycle.feedback(Twist::from(status.twist));
        }
        let snapshot = self.view.snapshot(Raw {
            mission: inputs.mission.as_ref(),
            joints: read_joints(&inputs.joints),
            odometry: inputs.odometry.as_ref(),
            target: inputs.target.as_ref(),
        });
        let (Some(mission), Some(measured), Some(target)) =
            (snapshot.mission, snapshot.measured, snapshot.target)
        else {
            return ReacherOutputs::default();
        };
        let out = self.cycle.step(&ReacherCycleInput {
            mission,
            base: measured.base,
            arm_q: measured.arm_q,
            target,
            plan: inputs.plan.as_ref().map(convert::plan_view),
            base_target: inputs
                .base_target
                .as_ref()
                .map_or(BaseVelocity::default(), convert::base_velocity_of),
        });
        ReacherOutputs {
            twist: out.ok().map(|out| {
                convert::stamped(
                    convert::twist_command(
                        &out.twist,
                        mission.task_index,
                        Phase::Reach,
                        TaskProgress::Active,
                        u32::from(ControllerVariant::Reacher),
                    ),
                    now_ns,
                )
            }),
        }
    }
}
