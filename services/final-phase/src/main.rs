//! `final-phase`: runs one final-phase task controller (grasp, drop or press-button: fixed with
//! `--variant`, or following the mission's task kind) during the final phase of the tasks it is
//! responsible for, and publishes the tool twist with the task's progress; outside the final
//! phase it publishes the resting gripper command. Every command carries the process's
//! `--controller-id`, so a hot swap can tell the old controller from the new one. The logic is
//! [`motm_core::stack::final_phase`].

use clap::Parser;
use motm_bus::{Bus, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::final_phase::FinalPhaseKind;
use motm_core::mission::Phase;
use motm_core::stack::final_phase::{FinalPhaseCycle, FinalPhaseCycleInput, VariantMode};
use motm_core::stack::seconds;
use motm_msgs as msgs;
use motm_msgs::services;
use motm_wire::inputs::ControlInputs;
use motm_wire::{ServiceArgs, ServiceSetup, convert, exit_on_error, report_exit};

/// Process (and heartbeat) name.
const PROCESS: &str = "final-phase";

/// Command line.
#[derive(Debug, Parser)]
#[command(name = PROCESS, about = "Final-phase task controller service")]
struct Cli {
    /// Common service options.
    #[command(flatten)]
    common: ServiceArgs,
    /// Controller variant: grasp, drop or press-button (default: the one each task calls for).
    #[arg(long)]
    variant: Option<FinalPhaseKind>,
    /// Id put in every command; the QP resolver uses the final twists of the active id only.
    #[arg(long, default_value_t = 1)]
    controller_id: u32,
}

fn main() {
    let cli = Cli::parse();
    let setup = exit_on_error(PROCESS, ServiceSetup::load(&cli.common));
    let mode = cli
        .variant
        .map_or(VariantMode::FollowMission, VariantMode::Fixed);
    exit_on_error(PROCESS, run(&setup, mode, cli.controller_id));
}

/// Opens the ports and runs the loop until SIGTERM/SIGINT.
fn run(
    setup: &ServiceSetup,
    mode: VariantMode,
    controller_id: u32,
) -> Result<(), motm_bus::BusError> {
    let bus = Bus::open(PROCESS)?;
    let qos = Qos::default();
    let mut inputs = ControlInputs::open(&bus, setup.config.mission.run_out_distance)?;
    let mut gripper_state =
        Latest::<msgs::GripperState>::new(&bus, services::ARM_GRIPPER_STATE, &qos)?;
    let mut twist_out =
        Publisher::<msgs::TwistCommand>::new(&bus, services::CONTROL_FINAL_TWIST, &qos)?;
    let mut gripper_out =
        Publisher::<msgs::GripperCommand>::new(&bus, services::ARM_GRIPPER_COMMAND, &qos)?;
    let mut cycle = FinalPhaseCycle::new(mode, setup.config.final_phase);
    let robot = &setup.robot;
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(setup.rate_hz))?;
    eprintln!(
        "{PROCESS}: running at {} Hz ({mode:?}, controller id {controller_id})",
        setup.rate_hz
    );
    service.run_periodic(|ctx| {
        // A failed receive leaves the previous value; the bus counts invalid samples.
        let _ = inputs.update();
        let _ = gripper_state.update();
        let snapshot = inputs.snapshot(ctx.now_ns);
        let (Some(mission), Some(measured), Some(target)) =
            (snapshot.mission, snapshot.measured, snapshot.target)
        else {
            return Flow::Continue;
        };
        if measured.arm_q.len() != robot.arm_dof() {
            return Flow::Continue;
        }
        let out = cycle.step(&FinalPhaseCycleInput {
            mission,
            t: seconds(ctx.now_ns),
            tool_pose: robot.tool_pose(&measured.base, measured.arm_q),
            base_pose: measured.base,
            base_velocity: measured.base_velocity,
            target,
            // Without a gripper state the controller refuses the cycle and nothing is sent.
            gripper_opening: gripper_state.get().map_or(f64::NAN, |g| g.width),
        });
        // Failed publishes show as stale commands, which the consumers act on.
        if let Some(control) = out.control.filter(|c| !c.input_rejected) {
            let _ = twist_out.publish(convert::twist_command(
                &control.twist,
                mission.task_index,
                Phase::Final,
                control.progress,
                controller_id,
            ));
        }
        if let Some(gripper) = out
            .gripper
            .filter(|_| out.control.is_none_or(|c| !c.input_rejected))
        {
            let _ = gripper_out.publish(convert::gripper_command(gripper, controller_id));
        }
        Flow::Continue
    })?;
    let details = format!("{} refused cycles", cycle.rejected());
    report_exit(PROCESS, &mut service, &bus, &details);
    Ok(())
}
