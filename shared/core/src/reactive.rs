//! The reactive baseline's task sequence ("stop and grasp", ALGORITHMS.md §3): the holistic
//! controller of [`crate::holistic`] servoes the tool through fixed stages per task.
//!
//! - **Pick:** servo above the cube, descend onto it, close (servoing on), lift to a waypoint
//!   above the platform.
//! - **Place:** servo to the release point above the container, open.
//! - **Press a button:** servo above it, push down, come back up.
//!
//! The base slows to a stop near each target because of the holistic 1/e_t weights.
//!
//! Choices (config values):
//! - **Moving targets.** The holistic law is a pure P servo, which lags a target moving at v by
//!   v/k. Each stage aims at the target predicted `1/servo_gain` ahead (lead compensation), which
//!   removes the steady lag without changing the holistic law itself.
//! - **Orientation.** Top-down, keeping the tool's current yaw (the cube's yaw is not measured).
//! - **Base stand-off.** The base does not drive closer than `base_standoff` to the target
//!   (the holistic law alone would run it into the platform): its forward speed toward the
//!   target is capped at the speed from which it can still stop there.
//! - **Closing** ends when the fingers reach `closed_opening` or after `closing_timeout`.

use nalgebra::{Isometry3, Translation3, Vector3};
use serde::Deserialize;

use crate::holistic::{HolisticConfig, HolisticController, HolisticInput};
use crate::kinematics::BasePose;
use crate::mission::{MissionTask, TaskKind};
use crate::reacher::{tool_yaw, top_down};
use crate::resolver::ResolveStatus;
use crate::robot::Robot;
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate};

/// Tunables of the reactive baseline's stages.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReactiveConfig {
    /// The holistic controller.
    pub holistic: HolisticConfig,
    /// Height of the pre-grasp point above the cube centre, m: high enough that the fingertips
    /// (45 mm below the tool point) clear the cube top on the way in.
    pub approach_height: f64,
    /// Height of the waypoint above the grasp point after closing, m.
    pub lift_height: f64,
    /// Height of the release point above the container rim, m.
    pub release_height: f64,
    /// Finger opening at which the grasp counts as closed, m.
    pub closed_opening: f64,
    /// Longest wait for the fingers to close, s.
    pub closing_timeout: f64,
    /// Wait after opening before the task counts as done, s.
    pub opening_time: f64,
    /// How far below the button top to push, m.
    pub press_depth: f64,
    /// Closest the base centre may drive toward the current target horizontally, m. The
    /// holistic law has no obstacle model and would drive the base into the platform; inside
    /// this distance its forward speed toward the target is clamped to zero and the arm reaches.
    pub base_standoff: f64,
    /// Half-width of the strip ahead of the base in which a platform counts as in its path, m
    /// (half the base width plus half a platform plus a margin).
    pub base_corridor: f64,
    /// Largest base forward speed, m/s: the trial's v_F, so every method has the same top speed
    /// (the holistic law alone would drive Frankie's base at its 1.2 m/s limit).
    pub max_base_speed: f64,
}

impl Default for ReactiveConfig {
    fn default() -> Self {
        Self {
            holistic: HolisticConfig::default(),
            approach_height: 0.1,
            lift_height: 0.15,
            release_height: 0.1,
            closed_opening: 0.032,
            closing_timeout: 1.0,
            opening_time: 0.5,
            press_depth: 0.01,
            base_standoff: 0.7,
            base_corridor: 0.55,
            max_base_speed: 0.3,
        }
    }
}

/// Where the baseline stands within the current task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReactiveStage {
    /// Servoing to the point above the target.
    Approach,
    /// Descending onto the cube, or pushing the button.
    Descend,
    /// Fingers closing (pick) or opening (place).
    Gripper,
    /// Going up to the waypoint above the target.
    Lift,
    /// Every task is done.
    Complete,
}

/// One cycle's input.
#[derive(Debug, Clone, Copy)]
pub struct ReactiveInput<'a> {
    /// Time, s.
    pub t: f64,
    /// Base pose (odometry).
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Measured finger opening, m.
    pub gripper_opening: f64,
    /// Estimate of the current task's target.
    pub target: TargetEstimate,
}

/// One cycle's output.
#[derive(Debug, Clone, PartialEq)]
pub struct ReactiveOutput {
    /// Base command.
    pub base: BaseVelocity,
    /// Arm joint velocity command.
    pub arm_qd: Vec<f64>,
    /// Gripper command.
    pub gripper: GripperCommand,
    /// Stage after this cycle.
    pub stage: ReactiveStage,
    /// Index of the current task after this cycle.
    pub task_index: usize,
    /// QP status.
    pub qp_status: ResolveStatus,
    /// The holistic controller's e_t, m.
    pub position_error: f64,
}

/// The reactive (holistic, stop-and-grasp) baseline over a list of tasks.
pub struct ReactiveBaseline {
    controller: HolisticController,
    config: ReactiveConfig,
    robot: Robot,
    tasks: Vec<MissionTask>,
    task: usize,
    stage: ReactiveStage,
    stage_start: f64,
    /// The grasp point and the held pose of the lift waypoint, fixed when the fingers close.
    anchor: Option<Vector3<f64>>,
    gripper: GripperCommand,
    /// The base's forward acceleration limit, m/s² (from the model).
    base_deceleration: f64,
}

impl ReactiveBaseline {
    /// A baseline for `robot` performing `tasks`.
    pub fn new(robot: Robot, config: ReactiveConfig, tasks: Vec<MissionTask>) -> Self {
        let stage = if tasks.is_empty() {
            ReactiveStage::Complete
        } else {
            ReactiveStage::Approach
        };
        Self {
            base_deceleration: robot.limits()[1].acceleration,
            controller: HolisticController::new(robot.clone(), config.holistic.clone()),
            config,
            robot,
            tasks,
            task: 0,
            stage,
            stage_start: 0.0,
            anchor: None,
            gripper: GripperCommand::Open,
        }
    }

    /// Index of the current task.
    pub fn task_index(&self) -> usize {
        self.task
    }

    /// The current task, if any is left.
    pub fn current_task(&self) -> Option<&MissionTask> {
        self.tasks.get(self.task)
    }

    /// Errors of the holistic QP so far.
    pub fn error_count(&self) -> u64 {
        self.controller.error_count()
    }

    /// Moves to `stage` at time `t`.
    fn enter(&mut self, stage: ReactiveStage, t: f64) {
        self.stage = stage;
        self.stage_start = t;
    }

    /// Finishes the current task.
    fn next_task(&mut self, t: f64) {
        self.task += 1;
        self.anchor = None;
        let stage = if self.task >= self.tasks.len() {
            ReactiveStage::Complete
        } else {
            ReactiveStage::Approach
        };
        self.enter(stage, t);
    }

    /// The point the tool should be at in the current stage.
    fn goal(&self, kind: TaskKind, target: &TargetEstimate) -> Vector3<f64> {
        let lead = 1.0 / self.config.holistic.servo_gain;
        let aim = target.predict(lead);
        let up = Vector3::z();
        match (kind, self.stage) {
            (TaskKind::Pick, ReactiveStage::Approach) => aim + up * self.config.approach_height,
            (TaskKind::Pick, ReactiveStage::Lift) => {
                self.anchor.unwrap_or(aim) + up * self.config.lift_height
            }
            (TaskKind::Pick, _) => aim,
            (TaskKind::Place, _) => aim + up * self.config.release_height,
            (TaskKind::PressButton, ReactiveStage::Descend) => aim - up * self.config.press_depth,
            (TaskKind::PressButton, _) => aim + up * self.config.approach_height,
        }
    }

    /// Caps the forward speed so the base can still stop `base_standoff` short of any pick
    /// platform (earlier or current) that lies ahead in its path (within `base_corridor` of its
    /// heading line).
    fn clamp_forward_speed(&self, base: &BasePose, v: f64) -> f64 {
        let heading = nalgebra::Vector2::new(base.yaw.cos(), base.yaw.sin()) * v.signum();
        let from = nalgebra::Vector2::new(base.x, base.y);
        let last = (self.task + 1).min(self.tasks.len());
        let room = self.tasks[..last]
            .iter()
            .filter(|t| t.kind == TaskKind::Pick)
            .filter_map(|t| {
                let offset = t.position.xy() - from;
                let along = offset.dot(&heading);
                let beside = (offset - heading * along).norm();
                (along > 0.0 && beside < self.config.base_corridor)
                    .then_some((along - self.config.base_standoff).max(0.0))
            })
            .fold(f64::INFINITY, f64::min);
        let stoppable = (2.0 * self.base_deceleration * room).sqrt();
        v.clamp(-stoppable, stoppable)
    }

    /// One control cycle.
    pub fn step(&mut self, input: &ReactiveInput<'_>) -> ReactiveOutput {
        let Some(task) = self.current_task().copied() else {
            return self.idle();
        };
        let tool = self.robot.tool_pose(&input.base, input.arm_q);
        let goal = self.goal(task.kind, &input.target);
        let rotation = top_down(tool_yaw(&tool.rotation));
        let target = Isometry3::from_parts(Translation3::from(goal), rotation);
        let out = self.controller.step(&HolisticInput {
            base: input.base,
            arm_q: input.arm_q,
            target,
        });
        // Speed caps scale the whole command (base and arm alike), so the tool still moves along
        // the direction the QP chose instead of the arm assuming a base motion that is cut.
        let allowed = self
            .clamp_forward_speed(&input.base, out.base.v)
            .abs()
            .min(self.config.max_base_speed);
        let scale = if out.base.v.abs() > allowed {
            allowed / out.base.v.abs()
        } else {
            1.0
        };
        let base = BaseVelocity {
            v: out.base.v * scale,
            omega: out.base.omega * scale,
        };
        let arm_qd: Vec<f64> = out.arm_qd.iter().map(|qd| qd * scale).collect();
        let elapsed = input.t - self.stage_start;
        match (task.kind, self.stage) {
            (_, ReactiveStage::Approach) if out.arrived => {
                let next = match task.kind {
                    TaskKind::Place => ReactiveStage::Gripper,
                    _ => ReactiveStage::Descend,
                };
                self.enter(next, input.t);
            }
            (TaskKind::Pick, ReactiveStage::Descend) if out.arrived => {
                self.gripper = GripperCommand::Close;
                self.enter(ReactiveStage::Gripper, input.t);
            }
            (TaskKind::PressButton, ReactiveStage::Descend) if out.arrived => {
                self.enter(ReactiveStage::Lift, input.t);
            }
            (TaskKind::Pick, ReactiveStage::Gripper)
                if input.gripper_opening <= self.config.closed_opening
                    || elapsed >= self.config.closing_timeout =>
            {
                self.anchor = Some(tool.translation.vector);
                self.enter(ReactiveStage::Lift, input.t);
            }
            (TaskKind::Place, ReactiveStage::Gripper) => {
                self.gripper = GripperCommand::Open;
                if elapsed >= self.config.opening_time {
                    self.next_task(input.t);
                }
            }
            (_, ReactiveStage::Lift) if out.arrived => self.next_task(input.t),
            _ => {}
        }
        if task.kind == TaskKind::PressButton {
            self.gripper = GripperCommand::Close;
        }
        ReactiveOutput {
            base,
            arm_qd,
            gripper: self.gripper,
            stage: self.stage,
            task_index: self.task,
            qp_status: out.status,
            position_error: out.position_error,
        }
    }

    /// The command once every task is done: stand still, gripper as it was.
    fn idle(&self) -> ReactiveOutput {
        ReactiveOutput {
            base: BaseVelocity::default(),
            arm_qd: vec![0.0; self.robot.arm_dof()],
            gripper: self.gripper,
            stage: ReactiveStage::Complete,
            task_index: self.task,
            qp_status: ResolveStatus::Solved,
            position_error: 0.0,
        }
    }
}
