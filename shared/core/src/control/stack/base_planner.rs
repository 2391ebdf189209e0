//! The base-planner process: the base controller driven by the supervisor's mission.

use crate::base_controller::{
    BaseController, BaseControllerConfig, BaseControllerInput, BaseControllerOutput, BaseModel,
};
use nalgebra::Vector3;

use crate::kinematics::BasePose;
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
    refused: u64,
}

impl BasePlannerCycle {
    /// A planner for `robot` with `config` (its `forward_speed` is the scenario's base speed),
    /// routing clear of `layout`, the known positions of the mission's targets.
    pub fn new(robot: &Robot, config: BaseControllerConfig, layout: &[Vector3<f64>]) -> Self {
        Self {
            controller: BaseController::new(config, BaseModel::from_robot(robot))
                .with_layout(layout),
            refused: 0,
        }
    }

    /// Cycles whose input was not finite.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// One cycle (after the last task, toward the run-out point): `None` when the input was
    /// not finite (counted in [`BasePlannerCycle::refused`]).
    pub fn step(&mut self, input: &BasePlannerInput) -> Option<BasePlannerOutput> {
        let task_index = input.mission.base_task_index();
        match self.controller.step(&BaseControllerInput {
            task_index,
            base: input.base,
            target: input.target,
            next_target: input.mission.next_waypoint,
            dt: input.dt,
        }) {
            Ok(plan) => Some(BasePlannerOutput { task_index, plan }),
            Err(_) => {
                self.refused += 1;
                None
            }
        }
    }
}
