//! The reacher process: the reacher driven by the mission, the base planner's plan and the
//! measured arm state. The tool state fed back to it is the commanded motion: the twist the QP
//! resolver resolved last (the one twist-rate state of the stack, which the resolver keeps and
//! publishes), with the reacher's own planned acceleration while it is the one reaching, and
//! the resolved twist's rate of change otherwise (final phase, hand-overs). The reacher plans
//! within the resolver's linear twist rate limit at the run's base speed
//! ([`crate::reacher::Reacher::with_acceleration_limit`]).

use nalgebra::Vector6;

use crate::kinematics::BasePose;
use crate::mission::{Phase, TaskKind};
use crate::on_the_move::OnTheMoveConfig;
use crate::reacher::{Reacher, ReacherInput, ReacherOutput, ToolState};
use crate::robot::Robot;
use crate::types::{BaseVelocity, TargetEstimate, Twist};

use super::{MissionView, reach_aim};

/// The base planner's plan as the reacher uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanView {
    /// Index of the task the plan was made for.
    pub task_index: usize,
    /// t_R, s.
    pub time_to_range: f64,
    /// Base pose predicted at t_R.
    pub range_entry_pose: BasePose,
}

/// What the reacher reads each cycle.
#[derive(Debug, Clone, Copy)]
pub struct ReacherCycleInput<'a> {
    /// The supervisor's mission state.
    pub mission: MissionView,
    /// Base pose (odometry).
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Target of the current task (see [`super::TargetSelector`]).
    pub target: TargetEstimate,
    /// The latest base plan, if any.
    pub plan: Option<PlanView>,
    /// The base planner's velocity target (zero when none has arrived).
    pub base_target: BaseVelocity,
}

/// Why a reacher cycle produced no twist.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReacherIdle {
    /// The current task is in its final phase.
    NotReaching,
    /// No base plan for the current task has arrived yet.
    NoPlan,
    /// The arm state has the wrong size or a non-finite value.
    BadInput,
}

/// The reacher with the tool state it feeds back (previous commanded twist and acceleration).
#[derive(Debug, Clone)]
pub struct ReacherCycle {
    robot: Robot,
    config: OnTheMoveConfig,
    reacher: Reacher,
    /// Control period, s.
    dt: f64,
    last_twist: Twist,
    last_acceleration: Vector6<f64>,
    /// The reacher's own last twist and planned acceleration, until the resolver reports.
    own: Option<(Twist, Vector6<f64>)>,
}

impl ReacherCycle {
    /// A reacher for `robot` with `config`, run every `dt` seconds.
    pub fn new(robot: Robot, config: OnTheMoveConfig, dt: f64) -> Self {
        Self {
            reacher: Reacher::new(config.reacher.clone(), &robot)
                .with_acceleration_limit(config.twist_rate.linear_limit(config.base.forward_speed)),
            robot,
            config,
            dt,
            last_twist: Twist::zeros(),
            last_acceleration: Vector6::zeros(),
            own: None,
        }
    }

    /// Takes in the twist the QP resolver resolved (rate-limited, or zero when it stopped):
    /// the tool state fed back from now on. Its acceleration is the reacher's own plan when the
    /// reacher produced the last twist, else the resolved twist's rate of change.
    pub fn feedback(&mut self, resolved: Twist) {
        if !resolved.iter().all(|x| x.is_finite()) {
            return;
        }
        let derived = (resolved - self.last_twist) / self.dt;
        self.last_acceleration = self.own.take().map_or(derived, |(_, planned)| planned);
        self.last_twist = resolved;
    }

    /// One cycle: the reach twist of the current task (after the last task, the ready pose
    /// held while the base drives on), or why there is none. The twist is the reacher's own;
    /// the QP resolver rate-limits it.
    pub fn step(&mut self, input: &ReacherCycleInput<'_>) -> Result<ReacherOutput, ReacherIdle> {
        let mission = &input.mission;
        if mission.phase == Phase::Final {
            return Err(ReacherIdle::NotReaching);
        }
        let plan = input
            .plan
            .filter(|p| p.task_index == mission.base_task_index())
            .ok_or(ReacherIdle::NoPlan)?;
        if input.arm_q.len() != self.robot.arm_dof() || input.arm_q.iter().any(|q| !q.is_finite()) {
            return Err(ReacherIdle::BadInput);
        }
        let tool_pose = self.robot.tool_pose(&input.base, input.arm_q);
        let aim = reach_aim(mission.kind, &input.target, &self.config);
        let out = self
            .reacher
            .step(&ReacherInput {
                task_index: mission.task_index,
                base: input.base,
                base_velocity: input.base_target,
                tool: ToolState {
                    pose: tool_pose,
                    twist: self.last_twist,
                    acceleration: self.last_acceleration,
                },
                target: aim,
                // The objects' yaw is known in the world; the arm works in odometry, whose
                // frame has turned against the world by the correction's yaw.
                target_yaw: (mission.kind == TaskKind::Pick)
                    .then(|| self.config.reacher.pick_yaw(mission.odometry_offset[2])),
                time_to_range: plan.time_to_range,
                range_entry_pose: plan.range_entry_pose,
                dt: self.dt,
            })
            .map_err(|_| ReacherIdle::BadInput)?;
        self.own = Some((out.twist, out.acceleration));
        Ok(out)
    }
}
