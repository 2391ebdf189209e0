//! The base-planner process: the base controller driven by the supervisor's mission.

use crate::base_controller::{
    BaseController, BaseControllerConfig, BaseControllerInput, BaseControllerOutput, BaseModel,
};
use nalgebra::Vector3;

use crate::kinematics::BasePose;
use crate::localization::world_to_odometry;
use crate::robot::Robot;
use crate::types::TargetEstimate;

use super::MissionView;

/// What the base planner reads each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasePlannerInput {
    /// The supervisor's mission state.
    pub mission: MissionView,
    /// Base pose (odometry).
    pub base: BasePose,
    /// Target of the current task (see [`super::TargetSelector`]).
    pub target: TargetEstimate,
    /// Control period, s (bounds the change of the turn command between cycles).
    pub dt: f64,
}

/// What the base planner publishes each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasePlannerOutput {
    /// Index of the task the plan is for (the last task once the mission is complete).
    pub task_index: usize,
    /// The base controller's output: velocity target, closest approach, t_R, range-entry pose.
    pub plan: BaseControllerOutput,
}

/// The base controller plus a count of refused cycles.
#[derive(Debug, Clone)]
pub struct BasePlannerCycle {
    controller: BaseController,
    /// The mission's known layout, in the world, in task order (the target after the next is
    /// the one two tasks on).
    layout: Vec<Vector3<f64>>,
    /// The odometry offset the controller's layout was last corrected with.
    layout_offset: [f64; 3],
    refused: u64,
    /// The mission is complete and the base has reached the run-out point: it stands.
    stopped: bool,
}

impl BasePlannerCycle {
    /// A planner for `robot` with `config` (its `forward_speed` is the scenario's base speed),
    /// routing clear of `layout`, the known positions of the mission's targets in the world
    /// (corrected into odometry with the mission's odometry offset each cycle).
    pub fn new(robot: &Robot, config: BaseControllerConfig, layout: &[Vector3<f64>]) -> Self {
        Self {
            controller: BaseController::new(config, BaseModel::from_robot(robot))
                .with_layout(layout),
            layout: layout.to_vec(),
            layout_offset: [0.0; 3],
            refused: 0,
            stopped: false,
        }
    }

    /// Cycles whose input was not finite.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// One cycle (after the last task, toward the run-out point): `None` when the input was
    /// not finite (counted in [`BasePlannerCycle::refused`]). Once the mission is complete and
    /// the last target passed, the base stands for good from where it has lingered to a stop
    /// or come within r_C + `pass_margin` of the run-out point. Before, the last target's
    /// pass timed out as missed, the base came around, gave it up and drove on at v_F round
    /// the run-out point for as long as the stack ran.
    pub fn step(&mut self, input: &BasePlannerInput) -> Option<BasePlannerOutput> {
        let task_index = input.mission.base_task_index();
        let offset = input.mission.odometry_offset;
        if offset != self.layout_offset && offset.iter().all(|v| v.is_finite()) {
            let corrected: Vec<_> = self
                .layout
                .iter()
                .map(|p| world_to_odometry(&offset, p))
                .collect();
            self.controller.set_layout(&corrected);
            self.layout_offset = offset;
        }
        match self.controller.step(&BaseControllerInput {
            task_index,
            base: input.base,
            target: input.target,
            next_target: input.mission.next_waypoint,
            after_next: self
                .layout
                .get(task_index + 2)
                .filter(|_| offset.iter().all(|v| v.is_finite()))
                .map(|p| world_to_odometry(&offset, p)),
            dt: input.dt,
        }) {
            Ok(mut plan) => {
                let config = self.controller.config();
                let near_run_out = || {
                    let at = nalgebra::Vector2::new(input.base.x, input.base.y);
                    (input.mission.next_waypoint.xy() - at).norm()
                        <= config.closest_approach_radius + config.pass_margin
                };
                self.stopped = input.mission.is_complete()
                    && (self.stopped || plan.passed && (plan.command.v <= 0.0 || near_run_out()));
                if self.stopped {
                    plan.command = crate::types::BaseVelocity { v: 0.0, omega: 0.0 };
                }
                Some(BasePlannerOutput { task_index, plan })
            }
            Err(_) => {
                self.refused += 1;
                None
            }
        }
    }
}
