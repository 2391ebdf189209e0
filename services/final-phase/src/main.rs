//! `final-phase`: one final-phase task controller ([`motm_tasks::final_phase`]) as a process:
//! grasp, drop or press-button, fixed with `--variant` or following the mission's task kind.
//! Every command carries `--controller-id`, so a hot swap can tell the old controller from the
//! new one. It runs on each perception estimate's arrival, and at the control rate in between.

use std::process::ExitCode;

use motm_core::final_phase::FinalPhaseKind;
use motm_core::stack::final_phase::VariantMode;
use motm_tasks::final_phase::FinalPhaseTask;
use motm_wire::Service;

/// Flags of the final-phase controller.
#[derive(Debug, Clone, clap::Args)]
struct Flags {
    /// Controller variant: grasp, drop or press-button (default: the one each task calls for).
    #[arg(long)]
    variant: Option<FinalPhaseKind>,
    /// Id put in every command; the QP resolver uses the final twists of the active id only.
    #[arg(long, default_value_t = 1)]
    controller_id: u32,
}

fn main() -> ExitCode {
    Service::new(
        &motm_graph::FINAL_PHASE,
        "Final-phase task controller service",
    )
    .run(
        |setup, flags: Flags| {
            let mode = flags
                .variant
                .map_or(VariantMode::FollowMission, VariantMode::Fixed);
            motm_bus::say!(
                "final-phase: {mode:?}, controller id {}",
                flags.controller_id
            );
            Ok(FinalPhaseTask::new(
                &setup.control(),
                mode,
                flags.controller_id,
            ))
        },
        |task| format!("{} refused cycles", task.rejected()),
    )
}
