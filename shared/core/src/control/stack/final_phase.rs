//! The final-phase process: one final-phase task controller, fixed to a variant or following
//! the mission's task kind, plus the gripper command outside the final phase.

use nalgebra::Isometry3;

use crate::final_phase::{
    FinalPhaseConfig, FinalPhaseController, FinalPhaseInput, FinalPhaseKind, FinalPhaseOutput,
    ToolVelocityEstimate, build,
};
use crate::kinematics::BasePose;
use crate::mission::Phase;
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate};

use super::{MissionView, resting_gripper};

/// Which tasks a final-phase process performs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VariantMode {
    /// Only tasks of this kind; other tasks belong to another process.
    Fixed(FinalPhaseKind),
    /// Every task, with the controller its kind calls for.
    FollowMission,
}

/// What the final-phase process reads each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalPhaseCycleInput {
    /// The supervisor's mission state.
    pub mission: MissionView,
    /// Time of the cycle, s.
    pub t: f64,
    /// Measured tool pose (forward kinematics of the joint state at the odometry pose).
    pub tool_pose: Isometry3<f64>,
    /// Base pose (odometry).
    pub base_pose: BasePose,
    /// Measured base velocity (odometry).
    pub base_velocity: BaseVelocity,
    /// Target of the current task (see [`super::TargetSelector`]).
    pub target: TargetEstimate,
    /// Measured finger opening, m.
    pub gripper_opening: f64,
    /// The gripper yaw that grasps the current pick's object, when it is known
    /// ([`crate::reacher::ReacherConfig::grasp_yaw`]).
    pub grasp_yaw: Option<f64>,
}

/// What the final-phase process publishes each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalPhaseCycleOutput {
    /// The controller's output while the current task is in its final phase.
    pub control: Option<FinalPhaseOutput>,
    /// The gripper command, while this process is responsible for the current task (or the
    /// mission is complete).
    pub gripper: Option<GripperCommand>,
}

/// A final-phase controller that restarts from its first stage on every new task.
pub struct FinalPhaseCycle {
    mode: VariantMode,
    config: FinalPhaseConfig,
    controller: Box<dyn FinalPhaseController>,
    /// Updated every cycle, whoever owns the arm, so a controller knows the tool's velocity
    /// from its first cycle (the reach's hand-over).
    tool_velocity: ToolVelocityEstimate,
    task_index: Option<usize>,
    rejected: u64,
}

impl FinalPhaseCycle {
    /// A process in `mode` with `config`.
    pub fn new(mode: VariantMode, config: FinalPhaseConfig) -> Self {
        let first = match mode {
            VariantMode::Fixed(kind) => kind,
            VariantMode::FollowMission => FinalPhaseKind::Grasp,
        };
        Self {
            controller: build(first, &config),
            tool_velocity: ToolVelocityEstimate::default(),
            mode,
            config,
            task_index: None,
            rejected: 0,
        }
    }

    /// Cycles whose input was not finite.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// The controller variant that performs the current task, when this process is
    /// responsible for it.
    pub fn responsible_for(&self, mission: &MissionView) -> Option<FinalPhaseKind> {
        let wanted = FinalPhaseKind::from(mission.current_kind()?);
        match self.mode {
            VariantMode::FollowMission => Some(wanted),
            VariantMode::Fixed(kind) => (kind == wanted).then_some(kind),
        }
    }

    /// One cycle.
    pub fn step(&mut self, input: &FinalPhaseCycleInput) -> FinalPhaseCycleOutput {
        let tool_velocity = self
            .tool_velocity
            .update(input.t, input.tool_pose.translation.vector);
        let mission = &input.mission;
        if mission.is_complete() {
            let gripper = (self.mode == VariantMode::FollowMission).then(|| resting_gripper(None));
            return FinalPhaseCycleOutput {
                control: None,
                gripper,
            };
        }
        let Some(kind) = self.responsible_for(mission) else {
            return FinalPhaseCycleOutput {
                control: None,
                gripper: None,
            };
        };
        if self.task_index != Some(mission.task_index) || self.controller.kind() != kind {
            // A new task starts from its first stage.
            self.task_index = Some(mission.task_index);
            self.controller = build(kind, &self.config);
        }
        if mission.phase != Phase::Final {
            return FinalPhaseCycleOutput {
                control: None,
                gripper: Some(resting_gripper(mission.current_kind())),
            };
        }
        let out = self.controller.step(&FinalPhaseInput {
            t: input.t,
            tool_pose: input.tool_pose,
            base_pose: input.base_pose,
            base_velocity: input.base_velocity,
            target: input.target,
            gripper_opening: input.gripper_opening,
            tool_velocity,
            grasp_yaw: input.grasp_yaw,
        });
        if out.input_rejected {
            self.rejected += 1;
        }
        FinalPhaseCycleOutput {
            control: Some(out),
            gripper: Some(out.gripper),
        }
    }
}
