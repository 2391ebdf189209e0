//! The control loop of [`crate::on_the_move`] split into per-process cycle functions, for the
//! deployed stack where perception, the base planner, the reacher, the final-phase controller
//! and the QP resolver run as separate processes.
//!
//! Each submodule holds the state one process keeps and a pure `step` from the decoded inputs
//! of one cycle to that process's outputs; the service binaries only decode messages, call the
//! step and publish. The mission itself is sequenced by the supervisor, which the services see
//! as a [`MissionView`].
//!
//! Choices (shared by every service):
//! - **Target of the current task**: for a pick, perception's estimate once one has been
//!   published for that task; otherwise the mission's position of the target (the runner's
//!   rule). An estimate belongs to the current task when perception stamped it no earlier than
//!   the moment this process first saw the task ([`TargetSelector`]): perception resets on a new
//!   task and publishes only during picks, and picks are never back to back (a place lies
//!   between), so an estimate of the previous pick is always older than that moment.
//! - **Reach aim** and **resting gripper** are the functions [`crate::on_the_move`] uses
//!   ([`reach_aim`], [`resting_gripper`]), so both forms agree.

pub mod base_planner;
pub mod final_phase;
pub mod perception;
pub mod reacher;
pub mod resolver;

use nalgebra::Vector3;

use crate::mission::{Phase, TaskKind};
use crate::on_the_move::OnTheMoveConfig;
use crate::types::{GripperCommand, TargetEstimate};

/// The supervisor's mission state as a service receives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionView {
    /// Index of the current task (equals `task_count` when the mission is complete).
    pub task_index: usize,
    /// Number of tasks in the mission.
    pub task_count: usize,
    /// Kind of the current task (meaningless once the mission is complete).
    pub kind: TaskKind,
    /// Phase of the current task.
    pub phase: Phase,
    /// The mission's position of the current target, m.
    pub target: Vector3<f64>,
    /// Where the base heads after the current target (the next target, or the run-out point
    /// after the last one), m.
    pub next_waypoint: Vector3<f64>,
}

impl MissionView {
    /// Whether every task is done.
    pub fn is_complete(&self) -> bool {
        self.phase == Phase::Complete || self.task_index >= self.task_count
    }

    /// The current task's kind, or `None` once the mission is complete.
    pub fn current_kind(&self) -> Option<TaskKind> {
        (!self.is_complete()).then_some(self.kind)
    }
}

/// A target estimate received from perception, with its publication stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerceivedTarget {
    /// The estimate.
    pub estimate: TargetEstimate,
    /// Monotonic time perception published it, ns.
    pub stamp_ns: u64,
}

/// Picks the current task's target from the mission and perception (see the module doc).
#[derive(Debug, Clone, Copy, Default)]
pub struct TargetSelector {
    /// The task seen last and the monotonic time it was first seen, ns.
    task: Option<(usize, u64)>,
}

impl TargetSelector {
    /// The target of `mission`'s current task at monotonic time `now_ns`, given perception's
    /// latest estimate (if any).
    pub fn select(
        &mut self,
        mission: &MissionView,
        now_ns: u64,
        perceived: Option<&PerceivedTarget>,
    ) -> TargetEstimate {
        let seen_since = match self.task {
            Some((index, since)) if index == mission.task_index => since,
            _ => {
                self.task = Some((mission.task_index, now_ns));
                now_ns
            }
        };
        match perceived {
            Some(p)
                if mission.current_kind() == Some(TaskKind::Pick) && p.stamp_ns >= seen_since =>
            {
                p.estimate
            }
            _ => TargetEstimate::fixed(mission.target),
        }
    }
}

/// The point the arm is sent to for a task of `kind` whose target estimate is `target`: the
/// target itself, except for a place, whose container point is raised so that the reacher's
/// pre-grasp point is the drop controller's release point (`drop.release_height` above the
/// rim).
pub fn reach_aim(
    kind: TaskKind,
    target: &TargetEstimate,
    config: &OnTheMoveConfig,
) -> TargetEstimate {
    let mut aim = *target;
    if kind == TaskKind::Place {
        aim.position.z += config.final_phase.drop.release_height - config.reacher.pregrasp_height;
    }
    aim
}

/// The gripper command outside the final phase: open while reaching for a pick (or when there
/// is no task), closed while carrying to a place or pressing a button.
pub fn resting_gripper(kind: Option<TaskKind>) -> GripperCommand {
    match kind {
        Some(TaskKind::Pick) | None => GripperCommand::Open,
        Some(TaskKind::Place) | Some(TaskKind::PressButton) => GripperCommand::Close,
    }
}

/// Converts a monotonic time in ns to seconds (the core controllers' time unit; only
/// differences are used).
pub fn seconds(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

#[cfg(test)]
pub(crate) mod tests;
