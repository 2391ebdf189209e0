//! `base-planner`: each cycle, runs the MotM base controller for the supervisor's current task
//! at the measured odometry and publishes the base velocity target and the plan (t_R,
//! range-entry pose, closest approach). The logic is [`motm_core::stack::base_planner`].

use clap::Parser;
use motm_bus::{Bus, Flow, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::stack::base_planner::{BasePlannerCycle, BasePlannerInput};
use motm_msgs as msgs;
use motm_msgs::services;
use motm_wire::inputs::ControlInputs;
use motm_wire::{ServiceArgs, ServiceSetup, convert, exit_on_error, report_exit};

/// Process (and heartbeat) name.
const PROCESS: &str = "base-planner";

/// Command line.
#[derive(Debug, Parser)]
#[command(name = PROCESS, about = "Base planner service")]
struct Cli {
    /// Common service options.
    #[command(flatten)]
    common: ServiceArgs,
}

fn main() {
    let cli = Cli::parse();
    let setup = exit_on_error(PROCESS, ServiceSetup::load(&cli.common));
    exit_on_error(PROCESS, run(&setup));
}

/// Opens the ports and runs the loop until SIGTERM/SIGINT.
fn run(setup: &ServiceSetup) -> Result<(), motm_bus::BusError> {
    let bus = Bus::open(PROCESS)?;
    let qos = Qos::default();
    // The base controller needs no joint state.
    let mut inputs = ControlInputs::open_with(&bus, setup.config.mission.run_out_distance, false)?;
    let mut target_out =
        Publisher::<msgs::BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_TARGET, &qos)?;
    let mut plan_out = Publisher::<msgs::BasePlan>::new(&bus, services::BASE_PLAN, &qos)?;
    let mut planner = BasePlannerCycle::new(&setup.robot, setup.config.base.clone());
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(setup.rate_hz))?;
    eprintln!(
        "{PROCESS}: running at {} Hz, base speed {} m/s",
        setup.rate_hz, setup.config.base.forward_speed
    );
    service.run_periodic(|ctx| {
        // A failed receive leaves the previous value; the bus counts invalid samples.
        let _ = inputs.update();
        let snapshot = inputs.snapshot(ctx.now_ns);
        let (Some(mission), Some(measured), Some(target)) =
            (snapshot.mission, snapshot.measured, snapshot.target)
        else {
            return Flow::Continue;
        };
        if let Some(out) = planner.step(&BasePlannerInput {
            mission,
            base: measured.base,
            target,
            dt: 1.0 / setup.rate_hz,
        }) {
            // A failed publish shows as a stale target, which the QP resolver replaces by zero.
            let _ = target_out.publish(convert::base_command(&out.plan.command));
            let _ = plan_out.publish(convert::plan_message(&out));
        }
        Flow::Continue
    })?;
    let details = format!("{} refused cycles", planner.refused());
    report_exit(PROCESS, &mut service, &bus, &details);
    Ok(())
}
