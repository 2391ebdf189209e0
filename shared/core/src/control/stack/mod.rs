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
//! - **Target of the current task**: for a pick, a place or a press ([`TaskKind::is_perceived`]),
//!   perception's estimate once one has been published for that task; otherwise the mission's
//!   position of the target (the runner's rule). An estimate belongs to the current task when
//!   perception made it for that task: each estimate carries the index of the task perception
//!   was tracking ([`TargetSelector`]). This holds for a process restarted mid-task too (a
//!   final-phase controller restarted during a grasp sees perception's estimate of the moving
//!   cube at once, not the mission's nominal position, which is where the cube started).
//! - **Reach aim** and **resting gripper** are the functions [`crate::on_the_move`] uses
//!   ([`reach_aim`], [`resting_gripper`]), so both forms agree.
//! - **Twist rate limit** ([`crate::on_the_move::TwistRateLimit`]) is applied by the QP
//!   resolver, which picks the twist; the reacher applies the same limit to the twists it sees
//!   (its own and the final phase's) to know the tool state fed back to it.

pub mod base_planner;
pub mod final_phase;
pub mod perception;
pub mod reacher;
pub mod resolver;

use nalgebra::Vector3;

use crate::mission::{Phase, TaskKind};
use crate::on_the_move::OnTheMoveConfig;
use crate::types::{GripperCommand, TargetEstimate};

/// The mission as the services act on it. Once every task is done the robot drives on to the
/// run-out point with the arm at its ready pose ([`crate::on_the_move`]'s rule): the view then
/// has `phase == Complete`, `task_index == task_count`, and `kind`, `target` and
/// `next_waypoint` describe the last task.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionView {
    /// Index of the current task (equals `task_count` when the mission is complete).
    pub task_index: usize,
    /// Number of tasks in the mission (at least one).
    pub task_count: usize,
    /// Kind of the current task (of the last task once the mission is complete).
    pub kind: TaskKind,
    /// Phase of the current task.
    pub phase: Phase,
    /// The mission's position of the current (or last) target, m.
    pub target: Vector3<f64>,
    /// Where the base heads after the current target (the next target, or the run-out point
    /// after the last one), m.
    pub next_waypoint: Vector3<f64>,
    /// The odometry frame against the world, `[x, y, yaw]`
    /// ([`crate::localization::OdometryCorrection::offset`]): the targets are already in
    /// odometry, the rest of the known layout is corrected with this.
    pub odometry_offset: [f64; 3],
    /// The odometry correction predicts its drift
    /// ([`crate::localization::OdometryCorrection::calibrated`]).
    pub odometry_calibrated: bool,
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

    /// The task the base drives for: the current one, or the last one once complete.
    pub fn base_task_index(&self) -> usize {
        self.task_index.min(self.task_count.saturating_sub(1))
    }
}

/// The mission state as the supervisor publishes it, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionReport {
    /// Index of the current task (equals `task_count` when the mission is complete).
    pub task_index: usize,
    /// Number of tasks.
    pub task_count: usize,
    /// Kind of the current task (ignored once complete).
    pub kind: TaskKind,
    /// Phase of the current task.
    pub phase: Phase,
    /// The current task's target position, m (ignored once complete).
    pub target: Vector3<f64>,
    /// Where the base heads after the current target, if the supervisor says.
    pub next_waypoint: Option<Vector3<f64>>,
    /// The odometry frame against the world, `[x, y, yaw]`.
    pub odometry_offset: [f64; 3],
    /// The odometry correction predicts its drift.
    pub odometry_calibrated: bool,
}

/// Turns mission reports into [`MissionView`]s, remembering the last task so that the services
/// can go on after the mission completes.
///
/// Choice: when a report has no next waypoint, the base heads `run_out_distance` beyond the
/// target along the direction from the previous task's target (or along world x for the
/// first task seen), [`crate::mission::Mission::next_waypoint`]'s rule.
#[derive(Debug, Clone, Copy, Default)]
pub struct MissionLatch {
    run_out_distance: f64,
    last: Option<MissionView>,
}

impl MissionLatch {
    /// A latch that places missing run-out points `run_out_distance` beyond the target, m.
    pub fn new(run_out_distance: f64) -> Self {
        Self {
            run_out_distance,
            last: None,
        }
    }

    /// The view of `report`: `None` for an empty mission, or a completed one whose last task
    /// this process never saw.
    pub fn update(&mut self, report: &MissionReport) -> Option<MissionView> {
        if report.task_count == 0 {
            return None;
        }
        let complete = report.phase == Phase::Complete || report.task_index >= report.task_count;
        if complete {
            let last = self.last?;
            return Some(MissionView {
                task_index: report.task_count,
                task_count: report.task_count,
                phase: Phase::Complete,
                odometry_offset: report.odometry_offset,
                odometry_calibrated: report.odometry_calibrated,
                ..last
            });
        }
        let next_waypoint = report.next_waypoint.unwrap_or_else(|| {
            let from = self
                .last
                .filter(|l| l.task_index < report.task_index)
                .map_or(report.target - Vector3::x(), |l| l.target);
            let mut direction = report.target - from;
            direction.z = 0.0;
            let direction = direction.try_normalize(1e-9).unwrap_or_else(Vector3::x);
            report.target + direction * self.run_out_distance
        });
        let view = MissionView {
            task_index: report.task_index,
            task_count: report.task_count,
            kind: report.kind,
            phase: report.phase,
            target: report.target,
            next_waypoint,
            odometry_offset: report.odometry_offset,
            odometry_calibrated: report.odometry_calibrated,
        };
        self.last = Some(view);
        Some(view)
    }
}

/// A target estimate received from perception, with its publication stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerceivedTarget {
    /// The estimate.
    pub estimate: TargetEstimate,
    /// The mission task perception made it for.
    pub task_index: usize,
    /// Monotonic time perception published it, ns.
    pub stamp_ns: u64,
    /// Capture stamp of the image the estimate's position came from, ns.
    pub image_stamp_ns: u64,
}

/// The target of the current task and where it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelectedTarget {
    /// The target.
    pub target: TargetEstimate,
    /// Capture stamp of the image behind it, ns, when it is a perception estimate.
    pub image_stamp_ns: Option<u64>,
}

/// Picks the current task's target from the mission and perception (see the module doc).
#[derive(Debug, Clone, Copy, Default)]
pub struct TargetSelector;

impl TargetSelector {
    /// The target of `mission`'s current task, given perception's latest estimate (if any).
    pub fn select(
        &self,
        mission: &MissionView,
        perceived: Option<&PerceivedTarget>,
    ) -> TargetEstimate {
        self.select_with_source(mission, perceived).target
    }

    /// [`TargetSelector::select`], also saying which image the target came from.
    pub fn select_with_source(
        &self,
        mission: &MissionView,
        perceived: Option<&PerceivedTarget>,
    ) -> SelectedTarget {
        match perceived {
            Some(p)
                if mission.current_kind().is_some_and(TaskKind::is_perceived)
                    && p.task_index == mission.task_index =>
            {
                SelectedTarget {
                    target: p.estimate,
                    image_stamp_ns: Some(p.image_stamp_ns),
                }
            }
            _ => SelectedTarget {
                target: TargetEstimate::fixed(mission.target),
                image_stamp_ns: None,
            },
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
