//! The supervisor's mission task: the [`Mission`] sequencer fed from the bus (joint state,
//! odometry, the selected target estimate and the final-phase controller's progress).
//!
//! Choices:
//! - **Target of the current task**: for a perceived task (pick, place or press,
//!   [`TaskKind::is_perceived`]), the estimate the caller selected for it (perception's, by the
//!   stack's one selection rule, `crate::stack::TargetSelector`), otherwise the mission's known
//!   position.
//! - **Tool-to-target distance** is measured to the reach aim ([`crate::stack::reach_aim`]), exactly as the
//!   composed controller measures it, so both switch to the final phase at the same point.
//! - **Final-phase progress** counts only when it names the current task and the mission is
//!   in the final phase: a stale "done" of the previous task can never skip the next one.
//! - **Next target** is [`Mission::next_waypoint`]: the next task's target, or the run-out
//!   point beyond the last one, so the base planner never needs the task list.
//! - **Odometry frame.** The known positions are in the world, the controllers work in
//!   odometry: the tracker corrects the known positions it publishes with the odometry
//!   correction ([`Localizer`]), fed with perception's fixes of landmarks. Containers
//!   and buttons are landmarks for every fix of theirs; a cube is one only as its grasp begins,
//!   if perception then sees it still (`landmark_max_speed`), because the robot is never told
//!   which cubes move.

use nalgebra::Vector3;

use crate::kinematics::BasePose;
use crate::localization::Localizer;
use crate::mission::{Mission, MissionTask, Phase, TaskKind};
use crate::on_the_move::OnTheMoveConfig;
use crate::robot::Robot;
use crate::stack::reach_aim;
use crate::types::{TargetEstimate, TaskProgress};

/// Progress reported by the final-phase controller, for one task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FinalProgress {
    /// Index of the task the controller works on.
    pub task_index: usize,
    /// Its progress.
    pub progress: TaskProgress,
}

/// What the mission task reads each cycle.
#[derive(Debug, Clone, Copy)]
pub struct MissionTrackerInput<'a> {
    /// Base pose (odometry).
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// The current task's selected estimate (perception's, or the known position), if any.
    pub estimate: Option<TargetEstimate>,
    /// Capture stamp of the image behind `estimate`, ns, when it is perception's.
    pub fix_stamp_ns: Option<u64>,
    /// The final-phase controller's latest progress report, if any.
    pub final_progress: Option<FinalProgress>,
    /// The base planner has given up the current task's target ([`Mission::give_up`]).
    pub gave_up: bool,
}

/// What the mission task publishes after a cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionTrackerOutput {
    /// Index of the current task (the task count when complete).
    pub task_index: usize,
    /// Number of tasks.
    pub task_count: usize,
    /// Kind of the current task (`None` when complete).
    pub kind: Option<TaskKind>,
    /// The active phase.
    pub phase: Phase,
    /// The current task's known position, in odometry (zero when complete).
    pub current_target: Vector3<f64>,
    /// Where the base heads after the current target, in odometry (`None` when complete).
    pub next_target: Option<Vector3<f64>>,
    /// The odometry frame against the world, `[x, y, yaw]` ([`OdometryCorrection::offset`]).
    pub odometry_offset: [f64; 3],
    /// The odometry correction predicts its drift ([`OdometryCorrection::calibrated`]).
    pub odometry_calibrated: bool,
    /// Tool-to-aim distance this cycle, m (infinite when it could not be computed).
    pub tool_to_target: f64,
    /// Tasks given up so far.
    pub failed_tasks: usize,
    /// The task or phase changed this cycle.
    pub changed: bool,
}

/// The mission sequencer with the inputs the supervisor has.
#[derive(Debug, Clone)]
pub struct MissionTracker {
    robot: Robot,
    config: OnTheMoveConfig,
    mission: Mission,
    localizer: Localizer,
}

impl MissionTracker {
    /// A mission over `tasks` for `robot`, base starting at `start`; `config` is the one the
    /// control services use (mission thresholds and the reach aim's heights).
    pub fn new(
        robot: Robot,
        config: OnTheMoveConfig,
        tasks: Vec<MissionTask>,
        start: Vector3<f64>,
    ) -> Self {
        Self {
            localizer: Localizer::new(&config.mission),
            mission: Mission::new(config.mission.clone(), tasks, start),
            robot,
            config,
        }
    }

    /// The mission.
    pub fn mission(&self) -> &Mission {
        &self.mission
    }

    /// Restores the mission at a task and phase (after a supervisor restart).
    pub fn resume(&mut self, task_index: usize, phase: Phase) {
        self.mission.resume(task_index, phase);
    }

    /// The current state without stepping.
    pub fn output(&self, tool_to_target: f64, changed: bool) -> MissionTrackerOutput {
        let task = self.mission.current_task();
        MissionTrackerOutput {
            task_index: self.mission.task_index(),
            task_count: self.mission.tasks().len(),
            kind: task.map(|t| t.kind),
            phase: self.mission.phase(),
            current_target: task.map_or_else(Vector3::zeros, |t| {
                self.localizer.correction().to_odometry(&t.position)
            }),
            next_target: task.map(|t| {
                self.localizer
                    .correction()
                    .to_odometry(&self.mission.next_waypoint(&t.position))
            }),
            odometry_offset: self.localizer.correction().offset(),
            odometry_calibrated: self.localizer.correction().calibrated(),
            tool_to_target,
            failed_tasks: self.mission.failed_tasks(),
            changed,
        }
    }

    /// One cycle: measures the tool-to-aim distance and advances the sequencer.
    pub fn step(&mut self, input: &MissionTrackerInput<'_>) -> MissionTrackerOutput {
        let Some(task) = self.mission.current_task().copied() else {
            return self.output(f64::INFINITY, false);
        };
        self.localizer.advance(&input.base);
        if input.gave_up && self.mission.give_up() {
            return self.output(f64::INFINITY, true);
        }
        let target = match input.estimate {
            Some(estimate)
                if task.kind.is_perceived()
                    && estimate.position.iter().all(|v| v.is_finite())
                    && estimate.velocity.iter().all(|v| v.is_finite()) =>
            {
                estimate
            }
            _ => TargetEstimate::fixed(self.localizer.correction().to_odometry(&task.position)),
        };
        let finite = input.arm_q.len() == self.robot.arm_dof()
            && input.arm_q.iter().all(|q| q.is_finite())
            && [input.base.x, input.base.y, input.base.yaw]
                .iter()
                .all(|v| v.is_finite());
        let tool_to_target = if finite {
            let tool = self.robot.tool_pose(&input.base, input.arm_q);
            let aim = reach_aim(task.kind, &target, &self.config);
            (tool.translation.vector - aim.position).norm()
        } else {
            f64::INFINITY
        };
        let progress = match input.final_progress {
            Some(report)
                if report.task_index == self.mission.task_index()
                    && self.mission.phase() == Phase::Final =>
            {
                report.progress
            }
            _ => TaskProgress::Active,
        };
        let (index, phase) = (self.mission.task_index(), self.mission.phase());
        let status = self.mission.step(tool_to_target, progress);
        if let Some(stamp) = input.fix_stamp_ns {
            // A cube is a landmark on the cycle its grasp begins.
            let grasp_begins = (phase, status.phase) == (Phase::Reach, Phase::Final);
            self.localizer
                .locate(index, &task, &target, tool_to_target, grasp_begins, stamp);
        }
        self.output(tool_to_target, status.changed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn robot() -> Robot {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&dir, "frankie").unwrap()
    }

    /// The Frankie ready pose (tool at (0.634, 0, 0.7926) with the base at the origin).
    const READY: [f64; 7] = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, std::f64::consts::FRAC_PI_4];

    fn tracker(tasks: Vec<MissionTask>) -> MissionTracker {
        MissionTracker::new(robot(), OnTheMoveConfig::default(), tasks, Vector3::zeros())
    }

    fn pick_place(pick: Vector3<f64>, place: Vector3<f64>) -> Vec<MissionTask> {
        vec![
            MissionTask {
                kind: TaskKind::Pick,
                item: 0,
                position: pick,
            },
            MissionTask {
                kind: TaskKind::Place,
                item: 0,
                position: place,
            },
        ]
    }

    fn input(base: BasePose, estimate: Option<TargetEstimate>) -> MissionTrackerInput<'static> {
        MissionTrackerInput {
            base,
            arm_q: &READY,
            estimate,
            fix_stamp_ns: estimate.map(|_| 1),
            final_progress: None,
            gave_up: false,
        }
    }

    #[test]
    fn switches_to_final_when_the_tool_reaches_the_perceived_target() {
        let tool = Vector3::new(0.634, 0.0, 0.7926);
        // The known position is 1 m off; perception sees the cube right at the tool.
        let mut t = tracker(pick_place(
            tool + Vector3::x(),
            Vector3::new(4.0, 0.0, 0.35),
        ));
        let out = t.step(&input(BasePose::new(0.0, 0.0, 0.0), None));
        assert_eq!(out.phase, Phase::Reach);
        assert!(
            (out.tool_to_target - 1.0).abs() < 1e-3,
            "{}",
            out.tool_to_target
        );
        assert_eq!(out.next_target, Some(Vector3::new(4.0, 0.0, 0.35)));
        let seen = TargetEstimate::fixed(tool + Vector3::new(0.0, 0.05, 0.0));
        let out = t.step(&input(BasePose::new(0.0, 0.0, 0.0), Some(seen)));
        assert!(out.changed);
        assert_eq!(out.phase, Phase::Final);
        assert!((out.tool_to_target - 0.05).abs() < 1e-3);
    }

    #[test]
    fn progress_counts_only_for_the_current_task_in_the_final_phase() {
        let tool = Vector3::new(0.634, 0.0, 0.7926);
        let mut t = tracker(pick_place(tool, Vector3::new(4.0, 0.0, 0.35)));
        let base = BasePose::new(0.0, 0.0, 0.0);
        let done = |task_index| {
            Some(FinalProgress {
                task_index,
                progress: TaskProgress::Done,
            })
        };
        // "Done" while reaching is ignored; the tool is at the target, so the phase turns Final.
        let out = t.step(&MissionTrackerInput {
            final_progress: done(0),
            ..input(base, None)
        });
        assert_eq!((out.task_index, out.phase), (0, Phase::Final));
        // A report about another task is ignored.
        let out = t.step(&MissionTrackerInput {
            final_progress: done(1),
            ..input(base, None)
        });
        assert_eq!((out.task_index, out.phase), (0, Phase::Final));
        let out = t.step(&MissionTrackerInput {
            final_progress: done(0),
            ..input(base, None)
        });
        assert_eq!(
            (out.task_index, out.phase, out.kind),
            (1, Phase::Reach, Some(TaskKind::Place))
        );
        // The previous task's "done" cannot complete the place task.
        let out = t.step(&MissionTrackerInput {
            final_progress: done(0),
            ..input(base, None)
        });
        assert_eq!(out.task_index, 1);
        // The last task's next target is the run-out point beyond it.
        let next = out.next_target.unwrap();
        assert!(next.x > 4.0, "{next}");
    }

    #[test]
    fn bad_joint_values_never_advance_the_mission() {
        let tool = Vector3::new(0.634, 0.0, 0.7926);
        let mut t = tracker(pick_place(tool, Vector3::new(4.0, 0.0, 0.35)));
        let q = [f64::NAN; 7];
        let out = t.step(&MissionTrackerInput {
            base: BasePose::new(0.0, 0.0, 0.0),
            arm_q: &q,
            estimate: None,
            fix_stamp_ns: None,
            final_progress: None,
            gave_up: false,
        });
        assert_eq!(out.phase, Phase::Reach);
        assert!(out.tool_to_target.is_infinite());
    }

    #[test]
    fn landmark_fixes_correct_the_known_positions_into_odometry() {
        let tool = Vector3::new(0.634, 0.0, 0.7926);
        // The cube's known position is 6 cm off where odometry sees it; the container is 3 m on.
        let seen = tool;
        let known = tool - Vector3::new(0.06, 0.0, 0.0);
        let container = Vector3::new(3.0, 0.0, 0.35);
        let mut t = tracker(pick_place(known, container));
        let base = BasePose::new(0.0, 0.0, 0.0);
        // While reaching, a cube's fixes are not used (it may be moving) ...
        let far = TargetEstimate::fixed(seen + Vector3::new(0.0, 0.2, 0.0));
        let out = t.step(&input(base, Some(far)));
        assert_eq!((out.phase, out.odometry_offset), (Phase::Reach, [0.0; 3]));
        assert_eq!(out.next_target, Some(container));
        // ... it is a landmark as its grasp begins, seen still (now, and on average since its
        // first fix, 20 s before): the rest of the mission moves with it.
        let out = t.step(&MissionTrackerInput {
            fix_stamp_ns: Some(20_000_000_001),
            ..input(base, Some(TargetEstimate::fixed(seen)))
        });
        assert_eq!(out.phase, Phase::Final);
        // It moves by most of the 6 cm: one fix (2 cm) against the start pose's prior (5 cm)
        // takes 2500/(2500 + 400) of it.
        let next = out.next_target.unwrap();
        let moved = next - container;
        assert!(
            (moved.x - 0.06 * 2500.0 / 2900.0).abs() < 1e-3 && moved.yz().norm() < 1e-6,
            "{next}"
        );
        // A cube seen moving as its grasp begins corrects nothing.
        let mut moving = tracker(pick_place(known, container));
        moving.step(&input(base, Some(far)));
        let out = moving.step(&input(
            base,
            Some(TargetEstimate {
                position: seen,
                velocity: Vector3::new(0.03, 0.0, 0.0),
            }),
        ));
        assert_eq!((out.phase, out.odometry_offset), (Phase::Final, [0.0; 3]));
    }
}
