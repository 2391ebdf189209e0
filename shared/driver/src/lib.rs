//! Wiring shared by the velocity drivers (`panda-driver`, `ld60-driver`): their common flags,
//! and the driver loop that reads the command stream, safe-stop and the hardware state, steps
//! a [`VelocityDriver`] (the limits are enforced there) and publishes the hardware command, the
//! re-published state and a [`DriverStatus`].
//!
//! | process | reads | publishes |
//! | --- | --- | --- |
//! | panda-driver (1 kHz) | `ARM_VELOCITY_COMMAND` (every sample), `ARM_GRIPPER_COMMAND`, `CONTROL_ACTIVE_CONTROLLER`, `SAFETY_SAFE_STOP`, `HW_ARM_STATE`, `HW_GRIPPER_STATE` | `HW_ARM_COMMAND`, `HW_GRIPPER_COMMAND`, `ARM_JOINT_STATE`, `ARM_GRIPPER_STATE` (both waking), `ARM_DRIVER_STATUS` |
//! | ld60-driver (50 Hz) | `BASE_VELOCITY_COMMAND` (every sample), `SAFETY_SAFE_STOP`, `HW_BASE_STATE` | `HW_BASE_COMMAND`, `BASE_ODOMETRY` (waking), `BASE_DRIVER_STATUS` |
//!
//! The state is re-published at the driver's own rate, stamped with the hardware's stamp.
//! [`DriverStatus`] (at `--status-rate`) carries `limit_violations` (commands that arrived
//! beyond a limit: clamped or ignored, and counted), `output_violations` (the driver's own
//! self-check, always 0) and `max_command_gap_ns`.
//!
//! Backends: `sim`, whose hardware boundary is sim-world (`motm/v1/hw/*` services); for the
//! arm `fci`, the Franka Panda and Hand over their own protocols ([`fci`]); for the base
//! `arnl` (Omron LD-60) and `can` (AgileX), whose loop is in `ld60-driver`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use motm_bus::{
    Bus, BusError, Flow, Latest, LoopConfig, LoopExit, Publisher, Qos, ServiceLoop, Stamp,
    Subscriber,
};
use motm_core::Robot;
use motm_core::command_limiter::{AxisLimits, CommandLimiterConfig};
use motm_core::velocity_driver::{VelocityDriver, VelocityDriverConfig};
use motm_msgs::{DriverStatus, Message, SafeStop, services};
use motm_sim::Scenario;
use motm_sim::scenario_path;
use motm_wire::setup::resolve_config_dir;

pub mod fci;

/// Robot used when neither `--robot` nor `--scenario` names one.
pub const DEFAULT_ROBOT: &str = "frankie";

/// Exit code for bad input (flags, config, robot model).
pub const EXIT_BAD_INPUT: u8 = 2;

/// Exit code for a failure at run time (the bus).
pub const EXIT_FAILED: u8 = 1;

/// Where a driver's hardware boundary is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The simulated hardware: sim-world's `motm/v1/hw/*` services.
    Sim,
    /// An Omron LD-60 over ArNetworking (TCP 7272) and ARCL (TCP 7171): `ld60-driver` only.
    Arnl,
    /// An AgileX base over CAN (protocol v2): `ld60-driver` only.
    Can,
    /// The Franka Panda over FCI and the Franka Hand (panda-driver only; see [`fci`]).
    Fci,
}

/// Flags common to both drivers.
#[derive(Debug, Clone, clap::Args)]
pub struct DriverArgs {
    /// Folder holding robots/ and scenarios/ (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Robot model (config/robots/<NAME>.toml); default: the scenario's robot, else frankie.
    #[arg(long)]
    pub robot: Option<String>,
    /// Scenario file (TOML) or name in `<config>/scenarios/`: only its robot is used.
    #[arg(long)]
    pub scenario: Option<String>,
    /// Driver loop rate, Hz (default: the driver's own).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Rate of the incoming command stream (the stack's control rate), Hz: sets the staleness
    /// clock.
    #[arg(long, default_value_t = 200.0)]
    pub control_rate: f64,
    /// A command older than this many command periods is stale: the driver ramps to zero.
    #[arg(long, default_value_t = CommandLimiterConfig::default().stale_periods)]
    pub stale_periods: u32,
    /// Rate of the driver status messages, Hz.
    #[arg(long, default_value_t = 50.0)]
    pub status_rate: f64,
    /// Hardware backend.
    #[arg(long, value_enum, default_value_t = Backend::Sim)]
    pub backend: Backend,
    /// Random seed (the drivers draw no random numbers; accepted like every service).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl DriverArgs {
    /// Loads the robot model: `--robot`, else the robot of `--scenario`, else frankie. A
    /// `--robot` that is not the scenario's robot is an error.
    pub fn load_robot(&self) -> Result<Robot, String> {
        let dir = resolve_config_dir(self.config_dir.as_deref());
        let from_scenario = match &self.scenario {
            Some(name) => {
                let path = scenario_path(&dir, name);
                Some(Scenario::from_file(&path).map_err(|e| e.to_string())?.robot)
            }
            None => None,
        };
        let name = match (&self.robot, from_scenario) {
            (Some(robot), Some(scenario_robot)) if *robot != scenario_robot => {
                return Err(format!(
                    "--robot {robot}: the scenario is for robot '{scenario_robot}'"
                ));
            }
            (Some(robot), _) => robot.clone(),
            (None, Some(scenario_robot)) => scenario_robot,
            (None, None) => DEFAULT_ROBOT.to_owned(),
        };
        Robot::load(&dir, &name).map_err(|e| e.to_string())
    }

    /// The driver period from `--rate` or `default_rate_hz`, checked.
    pub fn period(&self, default_rate_hz: f64) -> Result<Duration, String> {
        let rate = self.rate.unwrap_or(default_rate_hz);
        positive_rate("--rate", rate)?;
        Ok(Duration::from_secs_f64(1.0 / rate))
    }

    /// The driver logic for axes with `limits` at `period`, from the flags.
    pub fn driver(
        &self,
        limits: Vec<AxisLimits>,
        period: Duration,
    ) -> Result<VelocityDriver, String> {
        positive_rate("--control-rate", self.control_rate)?;
        positive_rate("--status-rate", self.status_rate)?;
        if self.stale_periods == 0 {
            return Err("--stale-periods: must be at least 1".into());
        }
        let config = VelocityDriverConfig {
            limiter: CommandLimiterConfig {
                command_period: 1.0 / self.control_rate,
                stale_periods: self.stale_periods,
                ..CommandLimiterConfig::default()
            },
        };
        VelocityDriver::new(limits, period.as_secs_f64(), config).map_err(|e| e.to_string())
    }
}

/// Checks that a rate flag is positive and finite.
fn positive_rate(flag: &str, rate: f64) -> Result<(), String> {
    if rate.is_finite() && rate > 0.0 {
        Ok(())
    } else {
        Err(format!("{flag}: must be a positive rate in Hz, got {rate}"))
    }
}

/// The services and conversions of one driver: its command type, the hardware's state type and
/// how velocities are read from and written to them.
pub trait DriverTopics {
    /// Incoming command (from the QP resolver) and outgoing hardware command.
    type Command: Message;
    /// Hardware state (from sim-world), re-published to the stack.
    type State: Message;
    /// Incoming command service.
    const COMMAND: &'static str;
    /// Outgoing hardware command service.
    const HW_COMMAND: &'static str;
    /// Incoming hardware state service.
    const HW_STATE: &'static str;
    /// Outgoing state service (the hardware state, re-published).
    const STATE: &'static str;
    /// Outgoing status service.
    const STATUS: &'static str;
    /// Appends the commanded velocities of `command` to `out` (all the values it carries, so
    /// that a wrong joint count reaches the limiter and is counted).
    fn command_velocity(command: &Self::Command, out: &mut Vec<f64>);
    /// Appends the measured velocities of `state` to `out`.
    fn state_velocity(state: &Self::State, out: &mut Vec<f64>);
    /// The hardware command carrying `velocity`.
    fn hardware_command(velocity: &[f64]) -> Self::Command;
}

pub use motm_tasks::driver::status_message;

/// Runs the loop of driver `T` at `period` until SIGTERM/SIGINT. `extra` runs once per cycle
/// after the velocity command (e.g. the gripper), with the safe-stop flag.
pub fn run_driver<T: DriverTopics>(
    bus: &Bus,
    mut driver: VelocityDriver,
    period: Duration,
    status_period: Duration,
    mut extra: impl FnMut(u64, bool),
) -> Result<LoopExit, BusError> {
    let qos = Qos::default();
    let mut commands = Subscriber::<T::Command>::new(bus, T::COMMAND, &qos)?;
    let mut safe_stop = Latest::<SafeStop>::new(bus, services::SAFETY_SAFE_STOP, &qos)?;
    let mut hw_state = Latest::<T::State>::new(bus, T::HW_STATE, &qos)?;
    let mut hw_command = Publisher::<T::Command>::new(bus, T::HW_COMMAND, &qos)?;
    // Controllers may wake on the re-published state.
    let mut state = Publisher::<T::State>::new(bus, T::STATE, &qos.waking())?;
    let mut status = Publisher::<DriverStatus>::new(bus, T::STATUS, &qos)?;
    let mut service = ServiceLoop::new(
        bus,
        LoopConfig {
            period,
            ..LoopConfig::default()
        },
    )?;
    let status_every = (status_period.as_secs_f64() / period.as_secs_f64())
        .round()
        .max(1.0) as u64;
    let mut values = Vec::with_capacity(8);
    let mut measured = Vec::with_capacity(8);
    service.run_periodic(|cycle| {
        // A failing port is logged once per cycle and treated as no input (the limiter then
        // ramps to zero on its own).
        while let Ok(Some(command)) = commands.receive() {
            values.clear();
            T::command_velocity(&command, &mut values);
            driver.receive(command.header().stamp_ns, &values);
        }
        safe_stop.update().ok();
        let stopped = safe_stop.get().is_some_and(|s| s.active == 1);
        let fresh_state = hw_state.update().unwrap_or(false);
        measured.clear();
        if let Some(s) = hw_state.get() {
            T::state_velocity(s, &mut measured);
            if fresh_state {
                let stamp = Stamp::At(s.header().stamp_ns);
                if let Err(e) = state.publish_stamped(stamp, *s) {
                    eprintln!("{}: {e}", bus.process());
                }
            }
        }
        let measured = (!measured.is_empty()).then_some(measured.as_slice());
        if let Some(velocity) = driver.step(cycle.now_ns, stopped, measured)
            && let Err(e) = hw_command.publish(T::hardware_command(velocity))
        {
            eprintln!("{}: {e}", bus.process());
        }
        extra(cycle.now_ns, stopped);
        if cycle.cycle % status_every == 0
            && let Err(e) = status.publish(status_message(&driver.counters()))
        {
            eprintln!("{}: {e}", bus.process());
        }
        Flow::Continue
    })
}

/// Maps a driver's result to its exit code, printing the error.
pub fn exit(process: &str, result: Result<(), (u8, String)>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err((code, message)) => {
            eprintln!("{process}: {message}");
            ExitCode::from(code)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_rates_are_errors_naming_the_flag() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            args: DriverArgs,
        }
        let cli = Cli::try_parse_from(["d", "--rate", "0"]).unwrap();
        assert!(cli.args.period(1000.0).unwrap_err().contains("--rate"));
        let cli = Cli::try_parse_from(["d", "--control-rate=-1"]).unwrap();
        let period = cli.args.period(1000.0).unwrap();
        assert_eq!(period, Duration::from_millis(1));
        let err = cli.args.driver(vec![], period).unwrap_err();
        assert!(err.contains("--control-rate"), "{err}");
        let cli = Cli::try_parse_from(["d", "--robot", "nope"]).unwrap();
        assert!(cli.args.load_robot().unwrap_err().contains("nope"));
    }

    #[test]
    fn the_robot_comes_from_the_flag_or_the_scenario() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            args: DriverArgs,
        }
        let parse = |args: &[&str]| Cli::try_parse_from([&["d"], args].concat()).unwrap().args;
        assert_eq!(parse(&[]).load_robot().unwrap().config.name, "frankie");
        let fetch = parse(&["--scenario", "platforms-fetch"])
            .load_robot()
            .unwrap();
        assert_eq!(fetch.config.name, "fetch");
        let err = parse(&["--scenario", "platforms-fetch", "--robot", "frankie"])
            .load_robot()
            .unwrap_err();
        assert!(
            err.contains("--robot frankie") && err.contains("fetch"),
            "{err}"
        );
        let err = parse(&["--scenario", "no-such-scenario"])
            .load_robot()
            .unwrap_err();
        assert!(err.contains("no-such-scenario"), "{err}");
    }
}
