//! The four MotM modules composed into one control step, for the in-process runner and tests.
//!
//! Each cycle: the mission says which task is current; the base controller drives past its
//! target toward the next one; the reacher (reach phase) or the final-phase controller (final
//! phase) gives the tool twist; the augmented QP resolves twist and base target into joint
//! velocities; the mission advances on the tool-to-target distance and the final phase's
//! progress. The deployed stack runs the same modules as separate processes.
//!
//! Choices:
//! - **Reach target of a place task** is the container point raised so that the reacher's
//!   pre-grasp point is the drop controller's release point (`drop.release_height` above the
//!   rim): the cube then arrives over the container, not beside its rim.
//! - **Gripper outside the final phase** follows the task: open while reaching for a pick, closed
//!   while carrying to a place or pressing a button.
//! - **Tool state fed back to the reacher** is the previous cycle's commanded twist and
//!   acceleration (the smoothest replanning; see [`crate::reacher::ToolState`]).
//! - **e_t** for the QP's 1/e_t weights is the tool's distance to the current target, capped at
//!   [`OnTheMoveConfig::max_position_error`].
//! - **Twist rate limit.** The twist sent to the QP changes by at most
//!   [`TwistRateLimit`] per second, so hand-overs (reacher → final phase → next task) do not jerk
//!   the tool.
//! - **Base velocity error feed-forward.** The twist sent to the QP also carries the correction
//!   of [`crate::base_slip`]: minus the tool motion caused by the difference between the base's
//!   measured velocity and the one the QP commanded on the previous cycle, so the arm cancels
//!   the base's gain error and lag instead of the final-phase servo chasing them.
//! - **Base target rate limit** (on by default, see [`crate::base_command_rate`]). When on, the
//!   base controller's velocity target reaches the QP with its change limited to the base's
//!   acceleration limits, so the QP never plans the arm around a base turn the base cannot make.
//! - **Bad input** (a non-finite estimate or joint value) gives an all-zero command for the cycle.

use std::path::Path;

use nalgebra::{Vector3, Vector6};
use serde::Deserialize;

use crate::base_command_rate::{BaseCommandRate, BaseCommandRateConfig};
use crate::base_controller::{
    BaseController, BaseControllerConfig, BaseControllerInput, BaseModel,
};
use crate::base_slip::{BaseSlipConfig, slip_correction};
use crate::error::ModelError;
use crate::final_phase::{
    FinalPhaseConfig, FinalPhaseController, FinalPhaseInput, FinalPhaseKind, FinalPhaseStage, build,
};
use crate::kinematics::BasePose;
use crate::mission::{Mission, MissionConfig, MissionTask, Phase};
use crate::reacher::{ReachMode, Reacher, ReacherConfig, ReacherInput, ToolState};
use crate::resolver::{RedundancyResolver, ResolveStatus, ResolverConfig};
use crate::robot::Robot;
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate, TaskProgress, Twist};

/// Limits on how fast the commanded tool twist may change.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwistRateLimit {
    /// Largest change of the linear velocity per second, m/s².
    pub linear_acceleration: f64,
    /// Largest change of the angular velocity per second, rad/s².
    pub angular_acceleration: f64,
}

impl Default for TwistRateLimit {
    fn default() -> Self {
        Self {
            linear_acceleration: 2.0,
            angular_acceleration: 4.0,
        }
    }
}

impl TwistRateLimit {
    /// `wanted`, moved from `last` by at most the allowed change in `dt` (direction kept).
    pub fn apply(&self, last: &Twist, wanted: &Twist, dt: f64) -> Twist {
        let change = wanted - last;
        let linear = change
            .fixed_rows::<3>(0)
            .into_owned()
            .cap_magnitude(self.linear_acceleration * dt);
        let angular = change
            .fixed_rows::<3>(3)
            .into_owned()
            .cap_magnitude(self.angular_acceleration * dt);
        last + Twist::new(
            linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
        )
    }
}

/// The controllers file of a config folder (`config/controllers.toml`).
pub const CONTROLLERS_FILE: &str = "controllers.toml";

/// Every tunable of the composed MotM controller, by module. Every key is optional.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OnTheMoveConfig {
    /// Mission sequencing.
    pub mission: MissionConfig,
    /// Base controller.
    pub base: BaseControllerConfig,
    /// Reacher.
    pub reacher: ReacherConfig,
    /// Final-phase controllers.
    pub final_phase: FinalPhaseConfig,
    /// Redundancy-resolution QP.
    pub resolver: ResolverConfig,
    /// Rate limit on the tool twist sent to the QP (smooths hand-overs between the reacher and
    /// the final phase, and between tasks).
    pub twist_rate: TwistRateLimit,
    /// Cap on e_t in the QP's 1/e_t weights, m. MotM's twists come from trajectories that must
    /// be followed, so the slack must stay expensive even when the target is metres away;
    /// the cap also keeps the weights from jumping when a new task starts.
    pub max_position_error: f64,
    /// Feed-forward of the base's velocity error into the twist sent to the QP.
    pub base_slip: BaseSlipConfig,
    /// Acceleration limit on the base velocity target sent to the QP.
    pub base_rate: BaseCommandRateConfig,
}

impl Default for OnTheMoveConfig {
    fn default() -> Self {
        Self {
            mission: MissionConfig::default(),
            base: BaseControllerConfig::default(),
            reacher: ReacherConfig::default(),
            final_phase: FinalPhaseConfig::default(),
            resolver: ResolverConfig::default(),
            twist_rate: TwistRateLimit::default(),
            max_position_error: 0.2,
            base_slip: BaseSlipConfig::default(),
            base_rate: BaseCommandRateConfig::default(),
        }
    }
}

impl OnTheMoveConfig {
    /// Loads and checks a controllers file (`config/controllers.toml`: tables by module, every
    /// key optional); unknown keys and bad values are errors naming the file and the key.
    pub fn load(file: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(file)?;
        Self::from_toml_str(file, &text)
    }

    /// The controllers of a stack: `file` when given (relative paths as given), else
    /// [`CONTROLLERS_FILE`] in `config_dir` when it exists, else the defaults. The deployed
    /// services and the in-process trials take their gains from the same file this way.
    pub fn for_stack(config_dir: &Path, file: Option<&Path>) -> Result<Self, ModelError> {
        match file {
            Some(file) => Self::load(file),
            None => {
                let default = config_dir.join(CONTROLLERS_FILE);
                if default.is_file() {
                    Self::load(&default)
                } else {
                    Ok(Self::default())
                }
            }
        }
    }

    /// Parses and checks TOML text that came from `file`.
    pub fn from_toml_str(file: &Path, text: &str) -> Result<Self, ModelError> {
        let config: Self = ModelError::parse_toml_str(file, text)?;
        config.validate(file)?;
        Ok(config)
    }

    /// Checks the modules' values; `file` is named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        self.base.validate(file)?;
        self.reacher.validate(file)?;
        self.final_phase.validate(file)?;
        let rates = [
            (
                "twist_rate.linear_acceleration",
                self.twist_rate.linear_acceleration,
            ),
            (
                "twist_rate.angular_acceleration",
                self.twist_rate.angular_acceleration,
            ),
            ("max_position_error", self.max_position_error),
        ];
        for (key, value) in rates {
            if !(value.is_finite() && value > 0.0) {
                return Err(ModelError::invalid(
                    file,
                    key,
                    format!("must be finite and positive, got {value}"),
                ));
            }
        }
        Ok(())
    }
}

/// What the controller reads each cycle.
#[derive(Debug, Clone, Copy)]
pub struct OnTheMoveInput<'a> {
    /// Time of the cycle, s.
    pub t: f64,
    /// Control period, s.
    pub dt: f64,
    /// Base pose (odometry).
    pub base: BasePose,
    /// Measured base velocity.
    pub base_velocity: BaseVelocity,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Measured finger opening, m.
    pub gripper_opening: f64,
    /// Latest estimate of the current task's target (perception's, or the mission's position
    /// when the object has not been seen).
    pub target: TargetEstimate,
}

/// What the controller commands each cycle, plus its internals for logging.
#[derive(Debug, Clone)]
pub struct OnTheMoveOutput {
    /// Base velocity command.
    pub base: BaseVelocity,
    /// Arm joint velocity command.
    pub arm_qd: Vec<f64>,
    /// Gripper command.
    pub gripper: GripperCommand,
    /// World twist the QP was asked for, before the base velocity error feed-forward.
    pub twist: Twist,
    /// The base controller's velocity target.
    pub base_target: BaseVelocity,
    /// Index of the current task after this cycle.
    pub task_index: usize,
    /// Phase after this cycle.
    pub phase: Phase,
    /// Stage of the final-phase controller (while in the final phase).
    pub stage: Option<FinalPhaseStage>,
    /// Reacher mode (while reaching).
    pub reach_mode: ReachMode,
    /// The base controller's time-to-manipulation-range, s.
    pub time_to_range: f64,
    /// QP solve status.
    pub qp_status: ResolveStatus,
    /// QP iterations.
    pub qp_iterations: u32,
    /// Norm of the QP's slack.
    pub slack_norm: f64,
    /// Tool-to-target distance, m.
    pub tool_to_target: f64,
    /// A task finished this cycle (its index is `task_index − 1`).
    pub task_done: bool,
}

/// Reactive manipulation on-the-move: mission + base controller + reacher + final phase + QP.
pub struct OnTheMove {
    robot: Robot,
    config: OnTheMoveConfig,
    mission: Mission,
    base: BaseController,
    reacher: Reacher,
    final_phase: Box<dyn FinalPhaseController>,
    resolver: RedundancyResolver,
    last_twist: Twist,
    last_acceleration: Vector6<f64>,
    /// The base velocity the QP commanded on the previous cycle.
    last_base_command: BaseVelocity,
    /// Rate limit on the base target handed to the QP.
    base_rate: BaseCommandRate,
    rejected_inputs: u64,
}

impl OnTheMove {
    /// A controller for `robot` performing `tasks` from base position `start`.
    pub fn new(
        robot: Robot,
        config: OnTheMoveConfig,
        tasks: Vec<MissionTask>,
        start: Vector3<f64>,
    ) -> Self {
        let first_kind = tasks
            .first()
            .map_or(FinalPhaseKind::Grasp, |t| t.kind.into());
        let base_rate = BaseCommandRate::new(&robot, config.base_rate);
        Self {
            mission: Mission::new(config.mission.clone(), tasks, start),
            base: BaseController::new(config.base.clone(), BaseModel::from_robot(&robot)),
            reacher: Reacher::new(config.reacher.clone(), &robot),
            final_phase: build(first_kind, &config.final_phase),
            resolver: RedundancyResolver::for_robot(&robot, config.resolver.clone()),
            robot,
            config,
            last_twist: Twist::zeros(),
            last_acceleration: Vector6::zeros(),
            last_base_command: BaseVelocity::default(),
            base_rate,
            rejected_inputs: 0,
        }
    }

    /// The mission: current task and phase.
    pub fn mission(&self) -> &Mission {
        &self.mission
    }

    /// The robot model.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// Cycles whose input was refused (non-finite), plus QP failures.
    pub fn error_count(&self) -> u64 {
        self.rejected_inputs + self.resolver.error_count()
    }

    /// The point the arm is sent to for `task` whose target estimate is `target`.
    fn reach_target(&self, task: &MissionTask, target: &TargetEstimate) -> TargetEstimate {
        crate::stack::reach_aim(task.kind, target, &self.config)
    }

    /// An all-zero command for a cycle that cannot be computed.
    fn hold(&mut self, task_index: usize, phase: Phase) -> OnTheMoveOutput {
        self.last_twist = Twist::zeros();
        self.last_acceleration = Vector6::zeros();
        self.last_base_command = BaseVelocity::default();
        self.base_rate.reset();
        OnTheMoveOutput {
            base: BaseVelocity::default(),
            arm_qd: vec![0.0; self.robot.arm_dof()],
            gripper: self.resting_gripper(),
            twist: Twist::zeros(),
            base_target: BaseVelocity::default(),
            task_index,
            phase,
            stage: None,
            reach_mode: ReachMode::Holding,
            time_to_range: 0.0,
            qp_status: ResolveStatus::InvalidInput,
            qp_iterations: 0,
            slack_norm: 0.0,
            tool_to_target: f64::INFINITY,
            task_done: false,
        }
    }

    /// The gripper command outside the final phase.
    fn resting_gripper(&self) -> GripperCommand {
        crate::stack::resting_gripper(self.mission.current_task().map(|t| t.kind))
    }

    /// One control cycle.
    pub fn step(&mut self, input: &OnTheMoveInput<'_>) -> OnTheMoveOutput {
        let task_index = self.mission.task_index();
        let phase = self.mission.phase();
        // After the last task the base drives on to the run-out point with the arm back at its
        // ready pose, so the robot does not stop dead at the drop.
        let (task, base_task_index) = match self.mission.current_task() {
            Some(task) => (*task, task_index),
            None => match self.mission.tasks().last() {
                Some(last) => (*last, task_index - 1),
                None => return self.hold(task_index, Phase::Complete),
            },
        };
        let finite = input.arm_q.iter().all(|q| q.is_finite())
            && input.arm_q.len() == self.robot.arm_dof()
            && input
                .target
                .position
                .iter()
                .chain(input.target.velocity.iter())
                .all(|v| v.is_finite())
            && input.gripper_opening.is_finite();
        if !finite {
            self.rejected_inputs += 1;
            return self.hold(task_index, phase);
        }
        let next = self.mission.next_waypoint(&task.position);
        let Ok(base_out) = self.base.step(&BaseControllerInput {
            task_index: base_task_index,
            base: input.base,
            target: input.target,
            next_target: next,
            dt: input.dt,
        }) else {
            self.rejected_inputs += 1;
            return self.hold(task_index, phase);
        };
        let tool_pose = self.robot.tool_pose(&input.base, input.arm_q);
        let aim = self.reach_target(&task, &input.target);
        let tool_to_target = (tool_pose.translation.vector - aim.position).norm();

        let wanted_kind = FinalPhaseKind::from(task.kind);
        let (twist, gripper, progress, stage, reach_mode) = match phase {
            Phase::Final => {
                if self.final_phase.kind() != wanted_kind {
                    self.final_phase = build(wanted_kind, &self.config.final_phase);
                }
                let out = self.final_phase.step(&FinalPhaseInput {
                    t: input.t,
                    tool_pose,
                    base_pose: input.base,
                    base_velocity: input.base_velocity,
                    target: input.target,
                    gripper_opening: input.gripper_opening,
                });
                self.last_acceleration = (out.twist - self.last_twist) / input.dt;
                (
                    out.twist,
                    out.gripper,
                    out.progress,
                    Some(out.stage),
                    ReachMode::Holding,
                )
            }
            _ => {
                let reached = self.reacher.step(&ReacherInput {
                    task_index,
                    base: input.base,
                    base_velocity: base_out.command,
                    tool: ToolState {
                        pose: tool_pose,
                        twist: self.last_twist,
                        acceleration: self.last_acceleration,
                    },
                    target: aim,
                    target_yaw: None,
                    time_to_range: base_out.time_to_range,
                    range_entry_pose: base_out.range_entry_pose,
                    dt: input.dt,
                });
                let Ok(out) = reached else {
                    self.rejected_inputs += 1;
                    return self.hold(task_index, phase);
                };
                self.last_acceleration = out.acceleration;
                (
                    out.twist,
                    self.resting_gripper(),
                    TaskProgress::Active,
                    None,
                    out.mode,
                )
            }
        };
        let twist = self
            .config
            .twist_rate
            .apply(&self.last_twist, &twist, input.dt);
        self.last_twist = twist;
        let correction = slip_correction(
            &self.robot,
            &input.base,
            input.arm_q,
            input.base_velocity,
            self.last_base_command,
            &self.config.base_slip,
        );

        let resolved = self.resolver.resolve_motm(
            &self.robot,
            &input.base,
            input.arm_q,
            twist + correction,
            tool_to_target.min(self.config.max_position_error),
            Some(self.base_rate.apply(base_out.command, input.dt)),
        );
        self.last_base_command = resolved.base;
        let status = self.mission.step(tool_to_target, progress);
        if status.changed && status.task_index != task_index {
            // A new task starts: its final-phase controller begins from its first stage.
            if let Some(next_task) = self.mission.current_task() {
                self.final_phase = build(next_task.kind.into(), &self.config.final_phase);
            }
        }
        OnTheMoveOutput {
            base: resolved.base,
            arm_qd: resolved.arm_qd,
            gripper,
            twist,
            base_target: base_out.command,
            task_index: status.task_index,
            phase: status.phase,
            stage,
            reach_mode,
            time_to_range: base_out.time_to_range,
            qp_status: resolved.status,
            qp_iterations: resolved.iterations,
            slack_norm: resolved.slack.norm(),
            tool_to_target,
            task_done: status.task_index != task_index,
        }
    }
}

#[cfg(test)]
mod config_file_tests {
    use super::*;

    #[test]
    fn the_shipped_controllers_file_is_the_defaults() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/controllers.toml");
        let loaded = OnTheMoveConfig::load(&file).unwrap();
        assert_eq!(
            format!("{loaded:?}"),
            format!("{:?}", OnTheMoveConfig::default())
        );
    }

    #[test]
    fn a_bad_controllers_file_names_the_file_and_the_key() {
        let file = Path::new("gains.toml");
        let cases = [
            ("[reacher]\narm_sped_ratio = 0.5\n", "arm_sped_ratio"),
            ("max_position_error = -1.0\n", "max_position_error"),
            (
                "[twist_rate]\nlinear_acceleration = nan\n",
                "linear_acceleration",
            ),
        ];
        for (text, key) in cases {
            let err = OnTheMoveConfig::from_toml_str(file, text)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("gains.toml") && err.contains(key),
                "{key}: {err}"
            );
        }
        let tuned = OnTheMoveConfig::from_toml_str(file, "[reacher]\narm_speed_ratio = 0.4\n");
        assert_eq!(tuned.unwrap().reacher.arm_speed_ratio, 0.4);
    }
}
