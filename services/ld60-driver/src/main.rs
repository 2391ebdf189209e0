//! `ld60-driver`: the base driver. At 50 Hz (default) it reads the base velocity command,
//! safe-stop and the hardware state; it sends the hardware a base velocity command that never
//! exceeds the base's speed and acceleration limits (ramping to zero when the command goes
//! stale or safe-stop is raised), and re-publishes odometry.

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_bus::Bus;
use motm_core::command_limiter::AxisLimits;
use motm_driver::{DriverArgs, DriverTopics, EXIT_BAD_INPUT, EXIT_FAILED};
use motm_msgs::{BaseOdometry, BaseVelocityCommand, Message, services};

/// Default driver loop rate, Hz.
const DEFAULT_RATE_HZ: f64 = 50.0;

/// The base driver: base velocity commands and odometry.
#[derive(Parser)]
#[command(name = "ld60-driver", version, about)]
struct Cli {
    #[command(flatten)]
    driver: DriverArgs,
}

/// The base's services and conversions; the axes are `[v, omega]`.
struct Base;

impl DriverTopics for Base {
    type Command = BaseVelocityCommand;
    type State = BaseOdometry;
    const COMMAND: &'static str = services::BASE_VELOCITY_COMMAND;
    const HW_COMMAND: &'static str = services::HW_BASE_COMMAND;
    const HW_STATE: &'static str = services::HW_BASE_STATE;
    const STATE: &'static str = services::BASE_ODOMETRY;
    const STATUS: &'static str = services::BASE_DRIVER_STATUS;

    fn command_velocity(command: &BaseVelocityCommand, out: &mut Vec<f64>) {
        out.extend_from_slice(&[command.v, command.omega]);
    }

    fn state_velocity(state: &BaseOdometry, out: &mut Vec<f64>) {
        out.extend_from_slice(&[state.v, state.omega]);
    }

    fn hardware_command(velocity: &[f64]) -> BaseVelocityCommand {
        let mut command = BaseVelocityCommand::zeroed();
        command.v = velocity[0];
        command.omega = velocity[1];
        command
    }
}

fn run(cli: Cli) -> Result<(), (u8, String)> {
    let args = &cli.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    let robot = args.load_robot().map_err(bad)?;
    let period = args.period(DEFAULT_RATE_HZ).map_err(bad)?;
    // Robot joints are [base_yaw (omega), base_forward (v), arm...]; the axes are [v, omega].
    let limits = robot.limits();
    let axes = vec![AxisLimits::from(&limits[1]), AxisLimits::from(&limits[0])];
    let driver = args.driver(axes, period).map_err(bad)?;
    let failed = |e: motm_bus::BusError| (EXIT_FAILED, e.to_string());
    let bus = Bus::open("ld60-driver").map_err(failed)?;
    let status_period = Duration::from_secs_f64(1.0 / args.status_rate);
    motm_driver::run_driver::<Base>(&bus, driver, period, status_period, |_, _| {})
        .map_err(failed)?;
    Ok(())
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    motm_driver::exit("ld60-driver", run(cli))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_commands_map_v_and_omega_in_axis_order() {
        let command = Base::hardware_command(&[0.3, -0.1]);
        assert_eq!((command.v, command.omega), (0.3, -0.1));
        let mut values = Vec::new();
        Base::command_velocity(&command, &mut values);
        assert_eq!(values, vec![0.3, -0.1]);
    }
}
