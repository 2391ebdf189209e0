//! `panda-driver`: the arm driver. At 1 kHz it reads the joint velocity command, the gripper
//! command, safe-stop and the hardware state; it sends the hardware a joint velocity command
//! that never exceeds the arm's velocity, acceleration and jerk limits (ramping to zero when
//! the command goes stale or safe-stop is raised), forwards gripper commands of the active
//! controller, and re-publishes joint and gripper state.
//!
//! `--backend sim` (default): the hardware is sim-world's `motm/v1/hw/*` services.
//! `--backend fci --robot-ip IP [--fci-port P --hand-port P]`: the Franka Panda over FCI and
//! the Franka Hand (or `fake-panda`), driven by the robot's 1 kHz states; see
//! `motm_driver::fci`.

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_bus::{Bus, Latest, Publisher, Qos, Stamp, Subscriber};
use motm_core::BASE_JOINTS;
use motm_core::command_limiter::AxisLimits;
use motm_driver::fci::FciArgs;
use motm_driver::{Backend, DriverArgs, DriverTopics, EXIT_BAD_INPUT, EXIT_FAILED};
use motm_msgs::{
    ActiveController, ArmVelocityCommand, GripperCommand, GripperState, JointState, Message,
    services,
};

/// Default driver loop rate, Hz (the Panda's 1 kHz control interface).
const DEFAULT_RATE_HZ: f64 = 1000.0;

/// The arm driver: joint velocity commands, gripper, joint and gripper state.
#[derive(Parser)]
#[command(name = "panda-driver", version, about)]
struct Cli {
    #[command(flatten)]
    driver: DriverArgs,
    #[command(flatten)]
    fci: FciArgs,
}

/// The arm's services and conversions.
struct Arm;

impl DriverTopics for Arm {
    type Command = ArmVelocityCommand;
    type State = JointState;
    const COMMAND: &'static str = services::ARM_VELOCITY_COMMAND;
    const HW_COMMAND: &'static str = services::HW_ARM_COMMAND;
    const HW_STATE: &'static str = services::HW_ARM_STATE;
    const STATE: &'static str = services::ARM_JOINT_STATE;
    const STATUS: &'static str = services::ARM_DRIVER_STATUS;

    fn command_velocity(command: &ArmVelocityCommand, out: &mut Vec<f64>) {
        out.extend_from_slice(&command.velocity[..command.joint_count as usize]);
    }

    fn state_velocity(state: &JointState, out: &mut Vec<f64>) {
        out.extend_from_slice(&state.velocity[..state.joint_count as usize]);
    }

    fn hardware_command(velocity: &[f64]) -> ArmVelocityCommand {
        let mut command = ArmVelocityCommand::zeroed();
        command.joint_count = velocity.len() as u32;
        command.velocity[..velocity.len()].copy_from_slice(velocity);
        command
    }
}

/// Whether a gripper command goes to the hardware: only from the active controller (any
/// controller until one is named), and never under safe-stop (the gripper holds).
fn forward_gripper(
    command: &GripperCommand,
    active: Option<&ActiveController>,
    safe_stop: bool,
) -> bool {
    !safe_stop && active.is_none_or(|a| a.controller_id == command.controller_id)
}

fn run(cli: Cli) -> Result<(), (u8, String)> {
    let args = &cli.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    let robot = args.load_robot().map_err(bad)?;
    let period = args.period(DEFAULT_RATE_HZ).map_err(bad)?;
    let limits = robot.limits()[BASE_JOINTS..]
        .iter()
        .map(AxisLimits::from)
        .collect();
    let driver = args.driver(limits, period).map_err(bad)?;
    let failed = |e: motm_bus::BusError| (EXIT_FAILED, e.to_string());
    let bus = Bus::open("panda-driver").map_err(failed)?;
    let status_period = Duration::from_secs_f64(1.0 / args.status_rate);
    match args.backend {
        Backend::Fci => {
            return motm_driver::fci::run_fci(
                &bus,
                driver,
                status_period,
                &cli.fci,
                forward_gripper,
            );
        }
        Backend::Arnl | Backend::Can => {
            return Err(bad(format!(
                "--backend {:?}: a base backend; the arm driver takes sim or fci",
                args.backend
            )
            .to_lowercase()));
        }
        Backend::Sim => {}
    }
    let qos = Qos::default();
    let mut gripper_in =
        Subscriber::<GripperCommand>::new(&bus, services::ARM_GRIPPER_COMMAND, &qos)
            .map_err(failed)?;
    let mut active =
        Latest::<ActiveController>::new(&bus, services::CONTROL_ACTIVE_CONTROLLER, &qos)
            .map_err(failed)?;
    let mut hw_gripper_state =
        Latest::<GripperState>::new(&bus, services::HW_GRIPPER_STATE, &qos).map_err(failed)?;
    let mut hw_gripper = Publisher::<GripperCommand>::new(&bus, services::HW_GRIPPER_COMMAND, &qos)
        .map_err(failed)?;
    let mut gripper_state =
        Publisher::<GripperState>::new(&bus, services::ARM_GRIPPER_STATE, &qos.waking())
            .map_err(failed)?;
    motm_driver::run_driver::<Arm>(&bus, driver, period, status_period, |_, safe_stop| {
        active.update().ok();
        while let Ok(Some(command)) = gripper_in.receive() {
            if forward_gripper(&command, active.get(), safe_stop)
                && let Err(e) = hw_gripper.publish(*command)
            {
                eprintln!("panda-driver: {e}");
            }
        }
        if hw_gripper_state.update().unwrap_or(false)
            && let Some(state) = hw_gripper_state.get()
            && let Err(e) = gripper_state.publish_stamped(Stamp::At(state.header.stamp_ns), *state)
        {
            eprintln!("panda-driver: {e}");
        }
    })
    .map_err(failed)?;
    Ok(())
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    motm_driver::exit("panda-driver", run(cli))
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::GripperAction;

    #[test]
    fn gripper_commands_pass_only_from_the_active_controller_and_not_under_safe_stop() {
        let mut command = GripperCommand::zeroed();
        command.controller_id = 3;
        command.action = GripperAction::Close.into();
        let mut active = ActiveController::zeroed();
        active.controller_id = 3;
        assert!(forward_gripper(&command, None, false));
        assert!(forward_gripper(&command, Some(&active), false));
        assert!(!forward_gripper(&command, Some(&active), true));
        active.controller_id = 4;
        assert!(!forward_gripper(&command, Some(&active), false));
    }

    #[test]
    fn commands_convert_both_ways_with_their_joint_count() {
        let command = Arm::hardware_command(&[0.1, 0.2, 0.3]);
        assert_eq!(command.joint_count, 3);
        assert_eq!(command.validate(1, None), Ok(()));
        let mut values = Vec::new();
        Arm::command_velocity(&command, &mut values);
        assert_eq!(values, vec![0.1, 0.2, 0.3]);
    }
}
