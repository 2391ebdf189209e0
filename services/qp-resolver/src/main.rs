//! `qp-resolver`: each cycle, picks the tool twist of the active phase (the reacher's, or the
//! active final-phase controller's), resolves it with the base planner's velocity target at
//! the measured joint state and odometry, and publishes the arm and base velocity commands and
//! the QP status. The logic is [`motm_core::stack::resolver`].

use std::time::Instant;

use clap::Parser;
use motm_bus::{Bus, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::stack::resolver::{
    MeasuredState, ResolverCycle, ResolverCycleConfig, ResolverCycleInput,
};
use motm_msgs as msgs;
use motm_msgs::services;
use motm_wire::controllers::ControllerLatest;
use motm_wire::inputs::ControlInputs;
use motm_wire::{ServiceArgs, ServiceSetup, convert, exit_on_error, report_exit};

/// Process (and heartbeat) name.
const PROCESS: &str = "qp-resolver";

/// Command line.
#[derive(Debug, Parser)]
#[command(name = PROCESS, about = "Redundancy-resolution QP service")]
struct Cli {
    /// Common service options.
    #[command(flatten)]
    common: ServiceArgs,
    /// Oldest twist or base target still used, s.
    #[arg(long, default_value_t = ResolverCycleConfig::default().max_twist_age)]
    max_twist_age: f64,
    /// Oldest joint state or odometry still used, s.
    #[arg(long, default_value_t = ResolverCycleConfig::default().max_state_age)]
    max_state_age: f64,
}

fn main() {
    let cli = Cli::parse();
    let setup = exit_on_error(PROCESS, ServiceSetup::load(&cli.common));
    for (flag, value) in [
        ("--max-twist-age", cli.max_twist_age),
        ("--max-state-age", cli.max_state_age),
    ] {
        if !(value.is_finite() && value > 0.0) {
            exit_on_error::<(), _>(
                PROCESS,
                Err(format!("{flag}: must be positive, got {value}")),
            );
        }
    }
    let limits = ResolverCycleConfig {
        max_twist_age: cli.max_twist_age,
        max_state_age: cli.max_state_age,
    };
    exit_on_error(PROCESS, run(&setup, limits));
}

/// Opens the ports and runs the loop until SIGTERM/SIGINT.
fn run(setup: &ServiceSetup, limits: ResolverCycleConfig) -> Result<(), motm_bus::BusError> {
    let bus = Bus::open(PROCESS)?;
    let qos = Qos::default();
    let mut inputs = ControlInputs::open(&bus, setup.config.mission.run_out_distance)?;
    let mut reach = Latest::<msgs::TwistCommand>::new(&bus, services::CONTROL_REACH_TWIST, &qos)?;
    // Newest twist per controller: during a hot swap old and new publish side by side.
    let mut final_twist =
        ControllerLatest::<msgs::TwistCommand>::new(&bus, services::CONTROL_FINAL_TWIST, &qos)?;
    let mut active =
        Latest::<msgs::ActiveController>::new(&bus, services::CONTROL_ACTIVE_CONTROLLER, &qos)?;
    let mut base_target =
        Latest::<msgs::BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_TARGET, &qos)?;
    let mut arm_out =
        Publisher::<msgs::ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &qos)?;
    let mut base_out =
        Publisher::<msgs::BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_COMMAND, &qos)?;
    let mut status_out = Publisher::<msgs::QpStatus>::new(&bus, services::CONTROL_QP_STATUS, &qos)?;
    let mut cycle = ResolverCycle::new(
        setup.robot.clone(),
        setup.config.clone(),
        limits,
        setup.dt(),
    );
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(setup.rate_hz))?;
    eprintln!("{PROCESS}: running at {} Hz", setup.rate_hz);
    service.run_periodic(|ctx| {
        let now = ctx.now_ns;
        // A failed receive leaves the previous value; the bus counts invalid samples.
        let _ = inputs.update();
        let _ = reach.update();
        let _ = final_twist.update();
        let _ = active.update();
        let _ = base_target.update();
        let snapshot = inputs.snapshot(now);
        let started = Instant::now();
        let out = cycle.step(&ResolverCycleInput {
            mission: snapshot.mission,
            state: snapshot.measured.map(|m| MeasuredState {
                base: m.base,
                arm_q: m.arm_q,
                base_velocity: m.base_velocity,
                age_ns: now.saturating_sub(m.stamp_ns),
            }),
            target: snapshot
                .target
                .unwrap_or_else(|| motm_core::TargetEstimate::fixed(Default::default())),
            reach: reach.get().and_then(|m| convert::twist_sample(m, now)),
            final_twist: final_twist
                .get(active.get().map(|m| m.controller_id))
                .and_then(|m| convert::twist_sample(m, now)),
            active_controller: active.get().map(|m| m.controller_id),
            base_target: base_target.get().map(|m| {
                (
                    convert::base_velocity_of(m),
                    now.saturating_sub(m.header.stamp_ns),
                )
            }),
        });
        let solve_ns = started.elapsed().as_nanos() as u64;
        // A failed publish shows as a gap that the drivers and the watchdog act on.
        let _ = arm_out.publish(convert::arm_command(&out.resolved.arm_qd));
        let _ = base_out.publish(convert::base_command(&out.resolved.base));
        let mut status = convert::qp_status(&out.resolved, solve_ns, snapshot.image_stamp_ns);
        status.twist = out.twist.into();
        let _ = status_out.publish(status);
        Flow::Continue
    })?;
    let details = format!(
        "{} stopped cycles, {} hand-over fallbacks",
        cycle.stops(),
        cycle.fallbacks()
    );
    report_exit(PROCESS, &mut service, &bus, &details);
    Ok(())
}
