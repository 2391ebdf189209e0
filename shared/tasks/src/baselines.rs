//! The paper's baselines as tasks, so that they run in the same graph as MotM (the simulated
//! hardware, the drivers and, for the reactive baseline, perception) and are compared on the
//! same footing:
//! - [`ReactiveTask`]: the reactive (holistic, stop-and-grasp) baseline, with perception's
//!   estimate of the current pick or press taken by the stack's one selection rule;
//! - [`PlanningTask`]: the planning baseline, which plans once and tracks the plan, its
//!   end-effector twist resolved by the QP while the base follows the plan.
//!
//! Both publish the mission state (the task they work on), which perception and the logs follow.

use motm_core::kinematics::BasePose;
use motm_core::localization::{Localizer, OdometryCorrection};
use motm_core::mission::{MissionConfig, MissionTask, Phase, TaskKind};
use motm_core::mission_tracker::MissionTrackerOutput;
use motm_core::planning::PlanningController;
use motm_core::reactive::{ReactiveBaseline, ReactiveInput, ReactiveStage};
use motm_core::resolver::RedundancyResolver;
use motm_core::stack::{MissionView, TargetSelector, seconds};
use motm_core::{GripperCommand, Robot, RobotState, TaskProgress};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};
use nalgebra::Vector3;

use crate::convert;

ports! {
    /// What a baseline reads.
    pub struct BaselineInputs {
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// The gripper's opening.
        latest gripper: msgs::GripperState = topics::ARM_GRIPPER_STATE,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
    }
}

ports! {
    /// What the planning baseline reads.
    pub struct PlanningInputs {
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
    }
}

ports! {
    /// What a baseline publishes.
    pub struct BaselineOutputs {
        /// The task it works on.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Arm command.
        latest arm: msgs::ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Base command.
        latest base: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// Gripper command (controller id 0).
        latest gripper: msgs::GripperCommand = topics::ARM_GRIPPER_COMMAND,
    }
}

/// The mission state of a baseline working on `tasks[index]` (complete past the end), its
/// known positions put into odometry by `correction` (`None`: odometry taken as the world),
/// having given `failed_tasks` up.
fn mission_state(
    tasks: &[MissionTask],
    index: usize,
    correction: Option<&OdometryCorrection>,
    failed_tasks: usize,
    now_ns: u64,
) -> msgs::MissionState {
    let task = tasks.get(index);
    let to_odometry = |p: &Vector3<f64>| correction.map_or(*p, |c| c.to_odometry(p));
    let out = MissionTrackerOutput {
        task_index: index.min(tasks.len()),
        task_count: tasks.len(),
        kind: task.map(|t| t.kind),
        phase: if task.is_some() {
            Phase::Reach
        } else {
            Phase::Complete
        },
        current_target: task.map_or_else(Vector3::zeros, |t| to_odometry(&t.position)),
        next_target: task.and_then(|_| tasks.get(index + 1).map(|t| to_odometry(&t.position))),
        odometry_offset: correction.map_or([0.0; 3], OdometryCorrection::offset),
        odometry_calibrated: correction.is_some_and(OdometryCorrection::calibrated),
        tool_to_target: f64::INFINITY,
        failed_tasks,
        changed: false,
    };
    convert::stamped(convert::mission_state(&out), now_ns)
}

/// The commands of one baseline cycle.
fn commands(
    now_ns: u64,
    mission: msgs::MissionState,
    arm_qd: &[f64],
    base: &motm_core::BaseVelocity,
    gripper: GripperCommand,
) -> BaselineOutputs {
    BaselineOutputs {
        mission: Some(mission),
        arm: Some(convert::stamped(convert::arm_command(arm_qd), now_ns)),
        base: Some(convert::stamped(convert::base_command(base), now_ns)),
        gripper: Some(convert::stamped(
            convert::gripper_command(gripper, 0),
            now_ns,
        )),
    }
}

/// The reactive baseline task. It localizes as the MotM mission does ([`Localizer`]): the known
/// positions it publishes and keeps clear of are corrected into odometry with perception's
/// landmark fixes (a container at each fix, a cube as the fingers start closing on it).
pub struct ReactiveTask {
    baseline: ReactiveBaseline,
    tasks: Vec<MissionTask>,
    selector: TargetSelector,
    localizer: Localizer,
}

impl ReactiveTask {
    /// The baseline `baseline` over `tasks` (the same list it was built with), localizing
    /// with the landmark settings of `mission`.
    pub fn new(
        baseline: ReactiveBaseline,
        tasks: Vec<MissionTask>,
        mission: &MissionConfig,
    ) -> Self {
        Self {
            baseline,
            tasks,
            selector: TargetSelector,
            localizer: Localizer::new(mission),
        }
    }

    /// The baseline.
    pub fn baseline(&self) -> &ReactiveBaseline {
        &self.baseline
    }
}

impl Task for ReactiveTask {
    type Inputs = BaselineInputs;
    type Outputs = BaselineOutputs;

    fn name(&self) -> &'static str {
        motm_graph::REACTIVE.name
    }

    fn step(&mut self, now_ns: u64, inputs: &BaselineInputs) -> BaselineOutputs {
        let index = self.baseline.task_index();
        let (Some(joints), Some(odometry), Some(gripper)) =
            (&inputs.joints, &inputs.odometry, &inputs.gripper)
        else {
            let correction = self.localizer.correction();
            return BaselineOutputs {
                mission: Some(mission_state(
                    &self.tasks,
                    index,
                    Some(correction),
                    self.baseline.failed_tasks(),
                    now_ns,
                )),
                ..BaselineOutputs::default()
            };
        };
        let base = convert::base_pose(odometry);
        if index < self.tasks.len() {
            self.localizer.advance(&base);
        }
        let correction = self.localizer.correction();
        let mission = mission_state(
            &self.tasks,
            index,
            Some(correction),
            self.baseline.failed_tasks(),
            now_ns,
        );
        let last = self.tasks.last().copied();
        let Some(task) = self.tasks.get(index).copied().or(last) else {
            return BaselineOutputs::default();
        };
        let target = correction.to_odometry(&task.position);
        let offset = correction.offset();
        let view = MissionView {
            task_index: index,
            task_count: self.tasks.len(),
            kind: task.kind,
            phase: if index < self.tasks.len() {
                Phase::Reach
            } else {
                Phase::Complete
            },
            target,
            next_waypoint: target,
            odometry_offset: offset,
            odometry_calibrated: correction.calibrated(),
        };
        let perceived = inputs.target.as_ref().map(convert::perceived);
        let selected = self.selector.select_with_source(&view, perceived.as_ref());
        let before = self.baseline.stage();
        let out = self.baseline.step(&ReactiveInput {
            t: seconds(now_ns),
            base,
            arm_q: convert::arm_q(joints),
            gripper_opening: gripper.width,
            target: selected.target,
            odometry_offset: offset,
        });
        if let Some(stamp) = selected.image_stamp_ns {
            // A cube is a landmark as the fingers start closing on it.
            let grasp_begins = task.kind == TaskKind::Pick
                && before == ReactiveStage::Descend
                && out.stage == ReactiveStage::Gripper;
            // The tool's distance to the object (the baseline aims at the object itself).
            self.localizer.locate(
                index,
                &task,
                &selected.target,
                out.tool_to_target,
                grasp_begins,
                stamp,
            );
        }
        commands(now_ns, mission, &out.arm_qd, &out.base, out.gripper)
    }
}

/// e_t used in the QP's 1/e_t weights when tracking the planning baseline's EE twist: small, so
/// the slack is expensive and the planned twist is followed.
const PLANNING_POSITION_ERROR: f64 = 0.02;

/// The planning baseline task: the plan's tracker and the QP that resolves its twist.
pub struct PlanningTask {
    robot: Robot,
    tracker: PlanningController,
    resolver: RedundancyResolver,
    tasks: Vec<MissionTask>,
}

impl PlanningTask {
    /// The planning baseline tracking `tracker` for `robot` over its pick and place `tasks`,
    /// resolved by `resolver`.
    pub fn new(
        robot: Robot,
        tracker: PlanningController,
        resolver: RedundancyResolver,
        tasks: Vec<MissionTask>,
    ) -> Self {
        Self {
            robot,
            tracker,
            resolver,
            tasks,
        }
    }
}

impl Task for PlanningTask {
    type Inputs = PlanningInputs;
    type Outputs = BaselineOutputs;

    fn name(&self) -> &'static str {
        motm_graph::PLANNING.name
    }

    fn step(&mut self, now_ns: u64, inputs: &PlanningInputs) -> BaselineOutputs {
        let (Some(joints), Some(odometry)) = (&inputs.joints, &inputs.odometry) else {
            return BaselineOutputs::default();
        };
        let base: BasePose = convert::base_pose(odometry);
        let arm_q = convert::arm_q(joints);
        let state = RobotState {
            base,
            base_velocity: convert::base_velocity(odometry),
            arm_q: arm_q.to_vec(),
            tool_pose: self.robot.tool_pose(&base, arm_q),
        };
        let plan = self.tracker.step(seconds(now_ns), &state);
        let resolved = self.resolver.resolve_motm(
            &self.robot,
            &base,
            arm_q,
            plan.gripper_twist,
            PLANNING_POSITION_ERROR,
            Some(plan.base),
        );
        let (gripper, index) = if plan.progress == TaskProgress::Done {
            (GripperCommand::Open, self.tasks.len())
        } else if plan.gripper == GripperCommand::Close {
            (
                plan.gripper,
                self.tasks
                    .iter()
                    .position(|t| t.kind == TaskKind::Place)
                    .unwrap_or(0),
            )
        } else {
            (plan.gripper, 0)
        };
        let mission = mission_state(&self.tasks, index, None, 0, now_ns);
        commands(now_ns, mission, &resolved.arm_qd, &resolved.base, gripper)
    }
}
