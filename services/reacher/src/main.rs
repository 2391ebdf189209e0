//! `reacher`: each cycle of the reach phase, runs the reacher for the supervisor's current task
//! with the base planner's plan and velocity target at the measured joint state and odometry,
//! and publishes the tool twist. While the final phase runs it follows the final-phase twists,
//! so that its tool state is the commanded motion when the next task begins. The logic is
//! [`motm_core::stack::reacher`].

use clap::Parser;
use motm_bus::{Bus, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop, Subscriber};
use motm_core::mission::Phase;
use motm_core::stack::reacher::{ReacherCycle, ReacherCycleInput};
use motm_core::{BaseVelocity, TaskProgress, Twist};
use motm_msgs as msgs;
use motm_msgs::{ControllerVariant, services};
use motm_wire::inputs::ControlInputs;
use motm_wire::{ServiceArgs, ServiceSetup, convert, exit_on_error, report_exit};

/// Process (and heartbeat) name.
const PROCESS: &str = "reacher";

/// Command line.
#[derive(Debug, Parser)]
#[command(name = PROCESS, about = "Reacher service")]
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
    let mut inputs = ControlInputs::open(&bus, setup.config.mission.run_out_distance)?;
    let mut plan = Latest::<msgs::BasePlan>::new(&bus, services::BASE_PLAN, &qos)?;
    let mut base_target =
        Latest::<msgs::BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_TARGET, &qos)?;
    let mut final_twists =
        Subscriber::<msgs::TwistCommand>::new(&bus, services::CONTROL_FINAL_TWIST, &qos)?;
    // During a hot swap two final-phase controllers publish: follow the active one only.
    let mut active =
        Latest::<msgs::ActiveController>::new(&bus, services::CONTROL_ACTIVE_CONTROLLER, &qos)?;
    let mut qp_status = Latest::<msgs::QpStatus>::new(&bus, services::CONTROL_QP_STATUS, &qos)?;
    let mut twist_out =
        Publisher::<msgs::TwistCommand>::new(&bus, services::CONTROL_REACH_TWIST, &qos)?;
    let mut reacher = ReacherCycle::new(setup.robot.clone(), setup.config.clone(), setup.dt());
    let controller_id = u32::from(ControllerVariant::Reacher);
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(setup.rate_hz))?;
    eprintln!("{PROCESS}: running at {} Hz", setup.rate_hz);
    service.run_periodic(|ctx| {
        // A failed receive leaves the previous value; the bus counts invalid samples.
        let _ = inputs.update();
        let _ = plan.update();
        let _ = base_target.update();
        let snapshot = inputs.snapshot(ctx.now_ns);
        let Some(mission) = snapshot.mission else {
            // Drain, so that old final-phase twists are not followed later.
            while let Ok(Some(_)) = final_twists.receive() {}
            return Flow::Continue;
        };
        let _ = active.update();
        let active_id = active.get().map(|a| a.controller_id);
        while let Ok(Some(_)) = final_twists.receive() {}
        let _ = active_id;
        if let Ok(true) = qp_status.update()
            && let Some(status) = qp_status.get()
        {
            reacher.feedback(Twist::from(status.twist));
        }
        let (Some(measured), Some(target)) = (snapshot.measured, snapshot.target) else {
            return Flow::Continue;
        };
        let out = reacher.step(&ReacherCycleInput {
            mission,
            base: measured.base,
            arm_q: measured.arm_q,
            target,
            plan: plan.get().map(convert::plan_view),
            base_target: base_target
                .get()
                .map_or(BaseVelocity::default(), convert::base_velocity_of),
        });
        if let Ok(out) = out {
            // A failed publish shows as a stale twist, which the QP resolver acts on.
            let _ = twist_out.publish(convert::twist_command(
                &out.twist,
                mission.task_index,
                Phase::Reach,
                TaskProgress::Active,
                controller_id,
            ));
        }
        Flow::Continue
    })?;
    let details = String::new();
    report_exit(PROCESS, &mut service, &bus, &details);
    Ok(())
}
