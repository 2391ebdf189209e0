//! `reacher`: the reach-phase task ([`motm_tasks::reacher`]) as a process. It runs on each
//! perception estimate's arrival, and at the control rate in between.

use std::process::ExitCode;

use motm_tasks::reacher::ReacherTask;
use motm_wire::{NoFlags, Service};

fn main() -> ExitCode {
    Service::new(&motm_graph::REACHER, "Reacher service").run(
        |setup, _: NoFlags| Ok(ReacherTask::new(&setup.control())),
        |_| String::new(),
    )
}
