//! `ld60-driver`: the base driver. At 50 Hz (default) it reads the base velocity command,
//! safe-stop and the hardware state; it sends the hardware a base velocity command that never
//! exceeds the base's speed and acceleration limits (ramping to zero when the command goes
//! stale or safe-stop is raised), and re-publishes odometry.
//!
//! Backends: `sim` (sim-world's `motm/v1/hw/base_*` services); `arnl`, an Omron LD-60 over
//! ArNetworking (`--host`, ports and speeds from `config/bases/ld60.toml`); `can`, an AgileX
//! base (`--can-interface`, settings from `config/bases/scout.toml`). The real backends' loop
//! is `motm_ld60_driver::base`.

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_agilex::{HostConfig, SocketCanBus};
use motm_bus::Bus;
use motm_core::command_limiter::AxisLimits;
use motm_driver::{Backend, DriverArgs, DriverTopics, EXIT_BAD_INPUT, EXIT_FAILED};
use motm_ld60_driver::arnl::ArnlBase;
use motm_ld60_driver::base::{BaseLoop, run_base};
use motm_ld60_driver::can::CanBase;
use motm_ld60_driver::config::BaseConfig;
use motm_msgs::{BaseOdometry, BaseVelocityCommand, Message, services};
use motm_wire::setup::resolve_config_dir;

/// Default driver loop rate, Hz.
const DEFAULT_RATE_HZ: f64 = 50.0;

/// The base driver: base velocity commands and odometry.
#[derive(Parser)]
#[command(name = "ld60-driver", version, about)]
struct Cli {
    #[command(flatten)]
    driver: DriverArgs,
    /// Base hardware settings: a name in `<config>/bases/` or a file (default: `ld60` for
    /// `arnl`, `scout` for `can`).
    #[arg(long)]
    base_config: Option<String>,
    /// `arnl`: the robot's address.
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// `arnl`: ArNetworking port (default: the base config's).
    #[arg(long)]
    port: Option<u16>,
    /// `arnl`: ARCL port, 0 to not watch ARCL (default: the base config's).
    #[arg(long)]
    arcl_port: Option<u16>,
    /// `can`: CAN interface (default: the base config's).
    #[arg(long)]
    can_interface: Option<String>,
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
    let status_period = Duration::from_secs_f64(1.0 / args.status_rate);
    let base_config = |default: &str| {
        let dir = resolve_config_dir(args.config_dir.as_deref());
        let name = cli.base_config.as_deref().unwrap_or(default);
        BaseConfig::from_file(&BaseConfig::path(&dir, name)).map_err(bad)
    };
    match args.backend {
        Backend::Fci => {
            return Err(bad(
                "--backend fci: the Franka arm's backend; the base driver takes sim, arnl or can"
                    .into(),
            ));
        }
        Backend::Sim => {
            let bus = Bus::open("ld60-driver").map_err(failed)?;
            motm_driver::run_driver::<Base>(&bus, driver, period, status_period, |_, _| {})
                .map_err(failed)?;
        }
        Backend::Arnl => {
            let config = base_config("ld60")?;
            let a = config
                .arnl
                .ok_or_else(|| bad("the base config has no [arnl]".into()))?;
            let addr = (cli.host.as_str(), cli.port.unwrap_or(a.port));
            let client = motm_omron::ArClient::connect(addr, &a.client()).map_err(|e| {
                (
                    EXIT_FAILED,
                    format!("ArNetworking {}:{}: {e}", addr.0, addr.1),
                )
            })?;
            let mut hardware = ArnlBase::new(client, a.drive_limits());
            let arcl_port = cli.arcl_port.unwrap_or(a.arcl_port);
            if arcl_port != 0 {
                let arcl =
                    std::net::ToSocketAddrs::to_socket_addrs(&(cli.host.as_str(), arcl_port))
                        .ok()
                        .and_then(|mut a| a.next());
                let watched = arcl
                    .ok_or_else(|| "no address".to_owned())
                    .and_then(|addr| {
                        hardware.watch_arcl(addr, &a.arcl_password, a.client().timeout)
                    });
                if let Err(e) = watched {
                    eprintln!("ld60-driver: ARCL not watched (e-stop lines unseen): {e}");
                }
            }
            let stale = Duration::from_secs_f64(a.odometry_stale_ms * 1e-3);
            let bus = Bus::open("ld60-driver").map_err(failed)?;
            run_base(
                &bus,
                BaseLoop::new(hardware, driver, stale),
                period,
                status_period,
            )
            .map_err(failed)?;
        }
        Backend::Can => {
            let config = base_config("scout")?;
            let c = config
                .can
                .ok_or_else(|| bad("the base config has no [can]".into()))?;
            let interface = cli.can_interface.clone().unwrap_or(c.interface.clone());
            let socket = SocketCanBus::open(&interface)
                .map_err(|e| (EXIT_FAILED, format!("CAN interface {interface}: {e}")))?;
            let host = HostConfig {
                track_width: c.track_width,
                feedback_timeout: c.feedback_timeout_ms * 1e-3,
            };
            let hardware = CanBase::new(socket, host).map_err(|e| (EXIT_FAILED, e))?;
            let stale = Duration::from_secs_f64(c.feedback_timeout_ms * 1e-3);
            let bus = Bus::open("ld60-driver").map_err(failed)?;
            run_base(
                &bus,
                BaseLoop::new(hardware, driver, stale),
                period,
                status_period,
            )
            .map_err(failed)?;
        }
    }
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
