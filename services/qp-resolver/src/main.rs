//! `qp-resolver`: the redundancy-resolution task ([`motm_tasks::resolver`]) as a process. It
//! runs on each reach or final twist's arrival, and at the control rate in between.

use std::process::ExitCode;

use motm_core::stack::resolver::ResolverCycleConfig;
use motm_tasks::resolver::ResolverTask;
use motm_wire::{Service, positive};

/// Flags of the QP resolver.
#[derive(Debug, Clone, clap::Args)]
struct Flags {
    /// Oldest twist or base target still used, s.
    #[arg(long, default_value_t = ResolverCycleConfig::default().max_twist_age)]
    max_twist_age: f64,
    /// Oldest joint state or odometry still used, s.
    #[arg(long, default_value_t = ResolverCycleConfig::default().max_state_age)]
    max_state_age: f64,
}

fn main() -> ExitCode {
    Service::new(&motm_graph::QP_RESOLVER, "Redundancy-resolution QP service").run(
        |setup, flags: Flags| {
            let limits = ResolverCycleConfig {
                max_twist_age: positive("--max-twist-age", flags.max_twist_age)?,
                max_state_age: positive("--max-state-age", flags.max_state_age)?,
            };
            Ok(ResolverTask::new(&setup.control(), limits))
        },
        |task| {
            let cycle = task.cycle();
            format!(
                "{} stopped cycles, {} hand-over fallbacks",
                cycle.stops(),
                cycle.fallbacks()
            )
        },
    )
}
