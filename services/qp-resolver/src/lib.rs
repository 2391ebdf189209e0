//! The redundancy-resolution task ([`motm_tasks::resolver`]) as a process: `qp-resolver`, and
//! its hot standby `qp-resolver-standby` (the same task in a second process, whose commands
//! carry the standby's resolver id). Each runs on each reach or final twist's arrival, and at
//! the control rate in between.

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
    /// Longest the tool holds on the target without the active phase's twist, s.
    #[arg(long, default_value_t = ResolverCycleConfig::default().max_hold)]
    max_hold: f64,
}

/// Runs the resolver process of graph row `spec`, its commands carrying `resolver_id`.
pub fn run(spec: &'static motm_graph::TaskSpec, resolver_id: u32) -> ExitCode {
    Service::new(spec, "Redundancy-resolution QP service").run(
        |setup, flags: Flags| {
            let limits = ResolverCycleConfig {
                max_twist_age: positive("--max-twist-age", flags.max_twist_age)?,
                max_state_age: positive("--max-state-age", flags.max_state_age)?,
                max_hold: positive("--max-hold", flags.max_hold)?,
            };
            Ok(ResolverTask::new(&setup.control(), limits).with_resolver_id(resolver_id))
        },
        |task| {
            let cycle = task.cycle();
            format!(
                "{} stopped cycles, {} hand-over fallbacks, {} hold cycles",
                cycle.stops(),
                cycle.fallbacks(),
                cycle.holds()
            )
        },
    )
}
