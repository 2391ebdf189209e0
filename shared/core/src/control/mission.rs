//! Mission sequencing: which target is current, which is next, and which phase is active.
//!
//! A mission is an ordered list of tasks (pick this cube, drop it there, press that button). The
//! base controller always drives past the current target toward the next one; arm control belongs
//! to the reacher until the tool is within `final_phase_distance` of the target, then to the
//! final-phase task controller until it reports [`TaskProgress::Done`]. Sequencing lives here, not
//! inside a controller, so the in-process runner and the supervisor share one implementation.

use nalgebra::Vector3;
use serde::Deserialize;

use crate::types::TaskProgress;

/// What a task does at its target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskKind {
    /// Grasp the object at the target and lift it.
    Pick,
    /// Drop the held object into the container at the target.
    Place,
    /// Press the button at the target.
    PressButton,
}

impl TaskKind {
    /// Whether the task's target is found by perception in the palm camera's images rather
    /// than taken from the mission's position: cubes (picks) and button caps (presses).
    ///
    /// The mission's positions are in the world frame, but the controllers work in the frame of
    /// the base's odometry, which drifts by about 1 % of the distance driven. A 30 mm cube or a
    /// button cap of 30 mm radius, metres from the start, is missed by that much; an object
    /// seen by the palm camera is located relative to the tool, in the same odometry frame as
    /// the tool, so the drift cancels. A place is perceived too (the container is blue): over a
    /// mission of tens of metres the drift grows past what a 300 mm container forgives.
    pub fn is_perceived(self) -> bool {
        matches!(self, Self::Pick | Self::Place | Self::PressButton)
    }
}

/// One step of a mission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionTask {
    /// What to do.
    pub kind: TaskKind,
    /// Index of the object (for picks and places) or button the task refers to.
    pub item: usize,
    /// World position of the target as known when the mission was made; perception may refine it.
    pub position: Vector3<f64>,
}

/// Which controller owns the arm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Phase {
    /// The reacher brings the tool toward the target while the base drives.
    #[default]
    Reach,
    /// The final-phase task controller performs the task.
    Final,
    /// Every task is done.
    Complete,
}

/// Tunables of the mission sequencer.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MissionConfig {
    /// Tool-to-target distance below which the final-phase controller takes over, m
    /// (d_T = 0.1 m in the paper).
    pub final_phase_distance: f64,
    /// How far past the last target the base keeps driving, m: the "next target" of the last
    /// task, along the direction from the second-to-last target (or the start) to the last one.
    pub run_out_distance: f64,
    /// The share of its landmark's weight each new perception fix takes from the earlier ones,
    /// 0–1 (0 turns the odometry correction off; `crate::localization`). 0.3: a few fixes (a
    /// tenth of a second at 30 Hz) settle a landmark, and one stray fix counts for less than a
    /// third of it.
    pub landmark_fix_weight: f64,
    /// The known layout is trusted (perception's first gates rely on it) once landmarks at
    /// least this far apart have been fixed and the base has turned half a turn, m. 1 m: a
    /// centimetre of error in the fixes is then at most 0.6° of rotation.
    pub landmark_baseline: f64,
    /// A cube counts as a landmark (standing where the mission knows it) when perception's
    /// estimate of it is slower than this as the grasp begins, m/s. 0.02 m/s: the moving cubes
    /// go at 0.03 m/s and more, while a standing cube's estimate reads up to about 0.013 m/s as
    /// the grasp begins at 0.4 m/s (0.01 refused most of them: the correction went without the
    /// pick-up row and drifted by decimetres; Exp 2 seed 3 drove into the row).
    pub landmark_max_speed: f64,
    /// A landmark fix farther than this from where the correction puts its known position is
    /// not used, m (0.3 m: perception's own gate for cubes).
    pub landmark_max_residual: f64,
    /// A fix is a landmark fix only while the tool is within this distance of the task's aim,
    /// m. 0.3 m: a container seen from farther is seen obliquely, and its walls bias the fix by
    /// 5-20 cm (on Exp 2 such fixes moved the correction 8-10 cm, near the cubes' 12 cm spacing).
    pub landmark_max_range: f64,
}

impl Default for MissionConfig {
    fn default() -> Self {
        Self {
            final_phase_distance: 0.1,
            run_out_distance: 2.0,
            landmark_fix_weight: 0.3,
            landmark_baseline: 1.0,
            landmark_max_speed: 0.02,
            landmark_max_residual: 0.3,
            landmark_max_range: 0.3,
        }
    }
}

impl MissionConfig {
    /// Checks the values; `file` is named in the error.
    pub fn validate(&self, file: &std::path::Path) -> Result<(), crate::ModelError> {
        let checks = [
            (
                "mission.final_phase_distance",
                self.final_phase_distance,
                f64::MIN_POSITIVE,
                f64::MAX,
            ),
            (
                "mission.run_out_distance",
                self.run_out_distance,
                0.0,
                f64::MAX,
            ),
            (
                "mission.landmark_fix_weight",
                self.landmark_fix_weight,
                0.0,
                1.0,
            ),
            (
                "mission.landmark_baseline",
                self.landmark_baseline,
                f64::MIN_POSITIVE,
                f64::MAX,
            ),
            (
                "mission.landmark_max_speed",
                self.landmark_max_speed,
                0.0,
                f64::MAX,
            ),
            (
                "mission.landmark_max_residual",
                self.landmark_max_residual,
                f64::MIN_POSITIVE,
                f64::MAX,
            ),
            (
                "mission.landmark_max_range",
                self.landmark_max_range,
                f64::MIN_POSITIVE,
                f64::MAX,
            ),
        ];
        for (key, value, min, max) in checks {
            if !(value.is_finite() && value >= min && value <= max) {
                return Err(crate::ModelError::invalid(
                    file,
                    key,
                    format!("must be finite and within [{min}, {max}], got {value}"),
                ));
            }
        }
        Ok(())
    }
}

/// Marks `tasks[current]` given up in `failed`, with the places of the same object when it is
/// a pick (there is nothing to place), and returns the index of the next task not given up
/// (the task count when none is left).
pub fn give_up_task(tasks: &[MissionTask], failed: &mut [bool], current: usize) -> usize {
    let Some(task) = tasks.get(current) else {
        return current;
    };
    failed[current] = true;
    if task.kind == TaskKind::Pick {
        for (later, failed) in tasks.iter().zip(failed.iter_mut()).skip(current + 1) {
            if later.kind == TaskKind::Place && later.item == task.item {
                *failed = true;
            }
        }
    }
    next_open_task(failed, current + 1)
}

/// The index of the first task from `from` on that is not given up in `failed` (the task count
/// when none is left).
pub fn next_open_task(failed: &[bool], from: usize) -> usize {
    (from..failed.len())
        .find(|&index| !failed[index])
        .unwrap_or(failed.len())
}

/// The mission state machine.
#[derive(Debug, Clone)]
pub struct Mission {
    config: MissionConfig,
    tasks: Vec<MissionTask>,
    start: Vector3<f64>,
    current: usize,
    phase: Phase,
    /// Whether each task was given up.
    failed: Vec<bool>,
}

/// What the sequencer reports after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionStatus {
    /// Index of the current task (equal to the task count when complete).
    pub task_index: usize,
    /// The active phase.
    pub phase: Phase,
    /// True on the step where the phase or task changed.
    pub changed: bool,
}

impl Mission {
    /// A mission over `tasks`, starting with the base at `start` (world position).
    pub fn new(config: MissionConfig, tasks: Vec<MissionTask>, start: Vector3<f64>) -> Self {
        let phase = if tasks.is_empty() {
            Phase::Complete
        } else {
            Phase::Reach
        };
        Self {
            config,
            failed: vec![false; tasks.len()],
            tasks,
            start,
            current: 0,
            phase,
        }
    }

    /// Gives the current task up (its target could not be reached: the base gave it up after
    /// its passes, see `crate::base_controller`) and goes on with the next task that does not
    /// depend on it ([`give_up_task`]). Returns whether a task was given up.
    pub fn give_up(&mut self) -> bool {
        if self.current_task().is_none() {
            return false;
        }
        self.current = give_up_task(&self.tasks, &mut self.failed, self.current);
        self.phase = if self.current >= self.tasks.len() {
            Phase::Complete
        } else {
            Phase::Reach
        };
        true
    }

    /// How many tasks were given up.
    pub fn failed_tasks(&self) -> usize {
        self.failed.iter().filter(|&&f| f).count()
    }

    /// The tasks, in order.
    pub fn tasks(&self) -> &[MissionTask] {
        &self.tasks
    }

    /// The active phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Index of the current task.
    pub fn task_index(&self) -> usize {
        self.current
    }

    /// The current task, if any is left.
    pub fn current_task(&self) -> Option<&MissionTask> {
        self.tasks.get(self.current)
    }

    /// The task after the current one that is not given up, if any.
    pub fn next_task(&self) -> Option<&MissionTask> {
        self.tasks
            .get(next_open_task(&self.failed, self.current + 1))
    }

    /// Where the base should head after the current target: the next task's target, or a point
    /// `run_out_distance` beyond the last target.
    pub fn next_waypoint(&self, current_target: &Vector3<f64>) -> Vector3<f64> {
        if let Some(next) = self.next_task() {
            return next.position;
        }
        // Once every task is done the "current" target is the last one.
        let index = self.current.min(self.tasks.len().saturating_sub(1));
        let from = if index > 0 {
            self.tasks[index - 1].position
        } else {
            self.start
        };
        let mut direction = current_target - from;
        direction.z = 0.0;
        let direction = direction.try_normalize(1e-9).unwrap_or_else(Vector3::x);
        current_target + direction * self.config.run_out_distance
    }

    /// Restores a mission at a given task and phase (e.g. after a process restart).
    pub fn resume(&mut self, task_index: usize, phase: Phase) {
        self.current = task_index.min(self.tasks.len());
        self.phase = if self.current == self.tasks.len() {
            Phase::Complete
        } else {
            phase
        };
    }

    /// Advances the sequencer given the tool-to-target distance and the final-phase progress.
    pub fn step(&mut self, tool_to_target: f64, final_progress: TaskProgress) -> MissionStatus {
        let before = (self.current, self.phase);
        match self.phase {
            Phase::Reach if tool_to_target < self.config.final_phase_distance => {
                self.phase = Phase::Final;
            }
            Phase::Final if final_progress == TaskProgress::Done => {
                // A task given up earlier is skipped: the place of a pick given up with other
                // tasks between them would otherwise run with nothing in the hand.
                self.current = next_open_task(&self.failed, self.current + 1);
                self.phase = if self.current >= self.tasks.len() {
                    Phase::Complete
                } else {
                    Phase::Reach
                };
            }
            _ => {}
        }
        MissionStatus {
            task_index: self.current,
            phase: self.phase,
            changed: before != (self.current, self.phase),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pick_and_place() -> Mission {
        Mission::new(
            MissionConfig::default(),
            vec![
                MissionTask {
                    kind: TaskKind::Pick,
                    item: 0,
                    position: Vector3::new(2.0, 0.0, 0.45),
                },
                MissionTask {
                    kind: TaskKind::Place,
                    item: 0,
                    position: Vector3::new(4.0, 0.0, 0.35),
                },
            ],
            Vector3::zeros(),
        )
    }

    #[test]
    fn phases_follow_distance_then_progress() {
        let mut m = pick_and_place();
        assert_eq!(m.step(0.5, TaskProgress::Active).phase, Phase::Reach);
        let s = m.step(0.09, TaskProgress::Active);
        assert!(s.changed && s.phase == Phase::Final);
        // Moving away again does not hand the arm back to the reacher.
        assert_eq!(m.step(0.5, TaskProgress::Active).phase, Phase::Final);
        let s = m.step(0.5, TaskProgress::Done);
        assert_eq!((s.task_index, s.phase), (1, Phase::Reach));
        m.step(0.05, TaskProgress::Active);
        let s = m.step(0.05, TaskProgress::Done);
        assert_eq!(s.phase, Phase::Complete);
        assert!(m.current_task().is_none());
    }

    #[test]
    fn next_waypoint_is_next_task_or_run_out_beyond_the_last() {
        let mut m = pick_and_place();
        let current = m.current_task().unwrap().position;
        assert_eq!(m.next_waypoint(&current), Vector3::new(4.0, 0.0, 0.35));
        m.resume(1, Phase::Reach);
        let current = m.current_task().unwrap().position;
        let w = m.next_waypoint(&current);
        assert!((w - Vector3::new(6.0, 0.0, 0.35)).norm() < 1e-12, "{w}");
    }

    #[test]
    fn giving_up_a_pick_gives_up_its_place_and_goes_on() {
        let pick = |item, y| MissionTask {
            kind: TaskKind::Pick,
            item,
            position: Vector3::new(2.0, y, 0.45),
        };
        let place = |item| MissionTask {
            kind: TaskKind::Place,
            item,
            position: Vector3::new(4.0, 0.0, 0.35),
        };
        let mut m = Mission::new(
            MissionConfig::default(),
            vec![pick(0, 0.0), place(0), pick(1, 0.2), place(1)],
            Vector3::zeros(),
        );
        m.step(0.05, TaskProgress::Active);
        assert_eq!(m.phase(), Phase::Final);
        // The first pick is given up in its final phase: its place goes too, the next pick is
        // current and reaching.
        assert!(m.give_up());
        assert_eq!(
            (m.task_index(), m.phase(), m.failed_tasks()),
            (2, Phase::Reach, 2)
        );
        // A place given up alone leaves the rest; the mission then is complete.
        m.step(0.05, TaskProgress::Active);
        m.step(0.05, TaskProgress::Done);
        assert!(m.give_up());
        assert_eq!((m.phase(), m.failed_tasks()), (Phase::Complete, 3));
        assert!(!m.give_up());
    }

    #[test]
    fn a_place_given_up_with_its_pick_is_skipped_after_the_task_between_them() {
        let task = |kind, item, x| MissionTask {
            kind,
            item,
            position: Vector3::new(x, 0.0, 0.45),
        };
        let mut m = Mission::new(
            MissionConfig::default(),
            vec![
                task(TaskKind::Pick, 0, 2.0),
                task(TaskKind::PressButton, 1, 3.0),
                task(TaskKind::Place, 0, 4.0),
                task(TaskKind::Pick, 2, 5.0),
            ],
            Vector3::zeros(),
        );
        // The pick is given up: the press is current, and the base is to head on to the last
        // pick, not to the place given up with the first.
        assert!(m.give_up());
        assert_eq!((m.task_index(), m.failed_tasks()), (1, 2));
        assert_eq!(m.next_task().map(|t| t.item), Some(2));
        assert_eq!(m.next_waypoint(&Vector3::new(3.0, 0.0, 0.45)).x, 5.0);
        // The press done, the mission goes on to the last pick, past the place.
        m.step(0.05, TaskProgress::Active);
        let s = m.step(0.05, TaskProgress::Done);
        assert_eq!((s.task_index, s.phase), (3, Phase::Reach));
        assert!(m.next_task().is_none());
    }

    #[test]
    fn empty_mission_is_complete() {
        let m = Mission::new(MissionConfig::default(), vec![], Vector3::zeros());
        assert_eq!(m.phase(), Phase::Complete);
    }
}
