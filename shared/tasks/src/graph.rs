//! The control part of the graph, composed once for every in-process use: the base planner,
//! the reacher, the final phase, the QP resolver and the supervisor's mission, added to a
//! [`Scheduler`] at their rows' rates and triggers. The in-process runner adds the simulated
//! hardware, the drivers and perception in front of them; closed-loop tests add an ideal plant.

use motm_core::mission::MissionTask;
use motm_core::stack::final_phase::VariantMode;
use motm_core::stack::resolver::ResolverCycleConfig;
use motm_graph::{self as graph, Scheduler};
use nalgebra::Vector3;

use crate::ControlSetup;
use crate::base_planner::BasePlannerTask;
use crate::final_phase::FinalPhaseTask;
use crate::mission::MissionSequencerTask;
use crate::reacher::ReacherTask;
use crate::resolver::ResolverTask;

/// The final-phase controller's id (its `--controller-id` default).
pub const FINAL_PHASE_CONTROLLER_ID: u32 = 1;

/// Adds the control tasks for the mission `tasks` (base starting at `start`) to `scheduler`,
/// in the graph's order; the mission task comes last, so a cycle's control acts on the
/// mission state of the cycle before, as the deployed tasks do.
pub fn add_control_tasks(
    scheduler: &mut Scheduler,
    setup: &ControlSetup,
    tasks: Vec<MissionTask>,
    start: Vector3<f64>,
) {
    let rate = |spec: &graph::TaskSpec| spec.rate.hz(setup.rate_hz);
    scheduler.add(
        BasePlannerTask::new(setup, &tasks),
        &graph::BASE_PLANNER,
        rate(&graph::BASE_PLANNER),
    );
    scheduler.add(
        ReacherTask::new(setup),
        &graph::REACHER,
        rate(&graph::REACHER),
    );
    scheduler.add(
        FinalPhaseTask::new(setup, VariantMode::FollowMission, FINAL_PHASE_CONTROLLER_ID),
        &graph::FINAL_PHASE,
        rate(&graph::FINAL_PHASE),
    );
    scheduler.add(
        ResolverTask::new(setup, ResolverCycleConfig::default()),
        &graph::QP_RESOLVER,
        rate(&graph::QP_RESOLVER),
    );
    scheduler.add(
        MissionSequencerTask::new(setup.robot.clone(), setup.config.clone(), tasks, start),
        &graph::MISSION,
        rate(&graph::MISSION),
    );
}
