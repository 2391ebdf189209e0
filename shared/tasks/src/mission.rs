//! The mission task (run by the supervisor): the mission sequencer fed from the bus (joint
//! state, odometry, perception's estimate and the active final-phase controller's progress),
//! publishing the current task, its target, the next waypoint and the phase.
//!
//! Perception's estimate is taken for the current task by the stack's one rule,
//! [`TargetSelector`]: for a perceived task (pick or press), once perception has published an
//! estimate stamped no earlier than the moment this task first saw the current task.

use motm_core::Robot;
use motm_core::mission::{MissionTask as MissionItem, Phase, TaskKind};
use motm_core::mission_tracker::{
    FinalProgress, MissionTracker, MissionTrackerInput, MissionTrackerOutput,
};
use motm_core::on_the_move::OnTheMoveConfig;
use motm_core::stack::{MissionView, TargetSelector};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};
use nalgebra::Vector3;

use crate::controllers::PerController;
use crate::convert;

ports! {
    /// What the mission task reads.
    pub struct MissionInputs {
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
        /// The final-phase controllers' twists, with their task's progress.
        queue final_twists: msgs::TwistCommand = topics::CONTROL_FINAL_TWIST,
        /// The active final-phase controller (any, until a hot swap names one).
        latest active: msgs::ActiveController = topics::CONTROL_ACTIVE_CONTROLLER,
        /// The base planner's plan: whether it gave the current task's target up.
        latest plan: msgs::BasePlan = topics::BASE_PLAN,
    }
}

ports! {
    /// What the mission task publishes.
    pub struct MissionOutputs {
        /// The mission state.
        latest state: msgs::MissionState = topics::MISSION_STATE,
    }
}

/// The mission task.
pub struct MissionSequencerTask {
    tracker: MissionTracker,
    selector: TargetSelector,
    final_twists: PerController<msgs::TwistCommand>,
    last: Option<MissionTrackerOutput>,
}

impl MissionSequencerTask {
    /// The mission over `tasks` for `robot`, base starting at `start`, with the controllers'
    /// `config` (mission thresholds and the reach aim's heights).
    pub fn new(
        robot: Robot,
        config: OnTheMoveConfig,
        tasks: Vec<MissionItem>,
        start: Vector3<f64>,
    ) -> Self {
        Self {
            tracker: MissionTracker::new(robot, config, tasks, start),
            selector: TargetSelector,
            final_twists: PerController::default(),
            last: None,
        }
    }

    /// The sequencer (to resume it after a supervisor restart, or read the mission).
    pub fn tracker_mut(&mut self) -> &mut MissionTracker {
        &mut self.tracker
    }

    /// The output of the last cycle.
    pub fn last(&self) -> Option<&MissionTrackerOutput> {
        self.last.as_ref()
    }

    /// The mission as the control tasks see it, before this cycle's step.
    fn view(&self) -> MissionView {
        let now = self.tracker.output(f64::INFINITY, false);
        MissionView {
            task_index: now.task_index,
            task_count: now.task_count,
            kind: now.kind.unwrap_or(TaskKind::Pick),
            phase: if now.kind.is_none() {
                Phase::Complete
            } else {
                now.phase
            },
            target: now.current_target,
            next_waypoint: now.next_target.unwrap_or(now.current_target),
            odometry_offset: now.odometry_offset,
            odometry_calibrated: now.odometry_calibrated,
        }
    }
}

impl Task for MissionSequencerTask {
    type Inputs = MissionInputs;
    type Outputs = MissionOutputs;

    fn name(&self) -> &'static str {
        motm_graph::MISSION.name
    }

    fn step(&mut self, now_ns: u64, inputs: &MissionInputs) -> MissionOutputs {
        self.final_twists.extend(&inputs.final_twists);
        let view = self.view();
        let perceived = inputs.target.as_ref().map(convert::perceived);
        let selected = self.selector.select_with_source(&view, perceived.as_ref());
        let out = match (&inputs.joints, &inputs.odometry) {
            (Some(joints), Some(odometry)) => {
                let active = inputs.active.as_ref().map(|a| a.controller_id);
                let final_progress = self.final_twists.get(active).and_then(|m| {
                    Some(FinalProgress {
                        task_index: m.task_index as usize,
                        progress: convert::progress(m)?,
                    })
                });
                self.tracker.step(&MissionTrackerInput {
                    base: convert::base_pose(odometry),
                    arm_q: convert::arm_q(joints),
                    estimate: Some(selected.target),
                    fix_stamp_ns: selected.image_stamp_ns,
                    final_progress,
                    gave_up: inputs.plan.as_ref().is_some_and(|p| {
                        p.gave_up == 1 && p.task_index as usize == view.task_index
                    }),
                })
            }
            _ => self.tracker.output(f64::INFINITY, false),
        };
        self.last = Some(out);
        MissionOutputs {
            state: Some(convert::stamped(convert::mission_state(&out), now_ns)),
        }
    }
}
