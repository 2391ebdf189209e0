//! `base-planner`: the MotM base controller task ([`motm_tasks::base_planner`]) as a process,
//! at the control rate.

use std::process::ExitCode;

use motm_tasks::base_planner::BasePlannerTask;
use motm_wire::{NoFlags, Service};

fn main() -> ExitCode {
    Service::new(&motm_graph::BASE_PLANNER, "Base planner service").run(
        |setup, _: NoFlags| Ok(BasePlannerTask::new(&setup.control())),
        |task| format!("{} refused cycles", task.refused()),
    )
}
