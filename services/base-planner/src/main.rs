//! `base-planner`: the MotM base controller task ([`motm_tasks::base_planner`]) as a process,
//! at the control rate.

use std::process::ExitCode;

use motm_tasks::base_planner::BasePlannerTask;
use motm_wire::{NoFlags, Service};

fn main() -> ExitCode {
    Service::new(&motm_graph::BASE_PLANNER, "Base planner service").run(
        |setup, _: NoFlags| {
            let tasks = setup.mission.as_ref().map(|m| m.tasks.clone());
            Ok(BasePlannerTask::new(
                &setup.control(),
                &tasks.unwrap_or_default(),
            ))
        },
        |task| format!("{} refused cycles", task.refused()),
    )
}
