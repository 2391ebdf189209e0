//! # motm-tasks
//!
//! Every process of the motm stack as a [`motm_graph::Task`]: typed inputs and outputs over the
//! `motm-msgs` topics of its row in [`motm_graph::GRAPH`], and a pure step over the
//! `motm-core` control laws. The deployed service main (`motm-runtime`) and the in-process
//! scheduler (`motm-sim`'s runner) run these same tasks, so the control loop exists once.
//!
//! | task | module |
//! | --- | --- |
//! | perception | [`perception`] |
//! | base-planner | [`base_planner`] |
//! | reacher | [`reacher`] |
//! | final-phase | [`final_phase`] |
//! | qp-resolver | [`resolver`] |
//! | mission (in the supervisor) | [`mission`] |
//! | panda-driver, ld60-driver | [`driver`] |
//! | watchdog | [`watchdog`] |
//!
//! The final phase reports its task as done with `TwistCommand::progress == Done` (and the
//! task's index); the mission task advances on that.

pub mod base_planner;
pub mod baselines;
pub mod controllers;
pub mod convert;
pub mod driver;
pub mod final_phase;
pub mod graph;
pub mod mission;
pub mod perception;
pub mod reacher;
pub mod resolver;
pub mod view;
pub mod watchdog;

use motm_core::Robot;
use motm_core::on_the_move::OnTheMoveConfig;

/// What every control task is built from: the robot model, the controllers' config and the
/// control rate.
#[derive(Debug, Clone)]
pub struct ControlSetup {
    /// The robot model.
    pub robot: Robot,
    /// The controllers' config (its `base.forward_speed` is the run's base speed).
    pub config: OnTheMoveConfig,
    /// Control rate, Hz.
    pub rate_hz: f64,
}

impl ControlSetup {
    /// The control period, s.
    pub fn dt(&self) -> f64 {
        1.0 / self.rate_hz
    }
}

#[cfg(test)]
mod tests;
