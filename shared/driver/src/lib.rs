//! Wiring shared by the velocity drivers (`panda-driver`, `ld60-driver`): their common flags
//! ([`DriverArgs`]), the stack side of a driver on real hardware ([`hardware`]), and the arm
//! driver's set-up ([`arm`]).
//!
//! The driver logic is written once, in `motm_tasks::driver` (`ArmDriverTask`,
//! `BaseDriverTask`): it reads every command sample, safe-stop and the hardware state, steps a
//! `VelocityDriver` (the limits are enforced there), forwards the active controller's gripper
//! commands and publishes the hardware command, the re-published state (stamped with the
//! hardware's stamp) and a `DriverStatus` (`limit_violations`: commands that arrived beyond a
//! limit, clamped or ignored and counted; `output_violations`: the driver's own self-check,
//! always 0; `max_command_gap_ns`).
//!
//! Backends: `sim` runs that task on `motm_runtime::serve` (its graph row
//! `motm_graph::PANDA_DRIVER` / `LD60_DRIVER`), with sim-world's `motm/v1/hw/*` topics as the
//! hardware. The real backends step the same task with the robot as the state source and the
//! command sink ([`hardware::StackPorts`] carries the other topics): for the arm `fci`, the
//! Franka Panda and Hand over their own protocols ([`fci`]); for the base `arnl` (Omron LD-60)
//! and `can` (AgileX), in `ld60-driver`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use motm_core::command_limiter::{AxisLimits, CommandLimiterConfig};
use motm_core::velocity_driver::{DriverCounters, VelocityDriver};
use motm_core::{Robot, resolve_config_dir};

pub mod arm;
pub mod fci;
pub mod hardware;

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

impl Backend {
    /// The backend's name, as `--backend` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Sim => "sim",
            Self::Arnl => "arnl",
            Self::Can => "can",
            Self::Fci => "fci",
        }
    }
}

/// The driver's part of its closing line: what its counters say.
pub fn details(counters: &DriverCounters) -> String {
    let l = &counters.limiter;
    format!(
        "{} commands, {} limit violations ({} clamped, {} ignored), {} stale cycles, {} safe-stop cycles, {} output violations",
        counters.commands_received,
        l.limit_violations,
        l.clamped_commands,
        l.ignored_commands,
        l.stale_steps,
        l.safe_stop_steps,
        counters.output_violations
    )
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
    /// Real backends: wait this long for the robot to accept the connection at start, s.
    #[arg(long, default_value_t = 10.0)]
    pub connect_wait: f64,
    /// Scheduling niceness to run at (-20 to 19; below 0 needs CAP_SYS_NICE): on a shared
    /// machine without the robot's real-time drop-ins, a 1 kHz exchange with the robot needs
    /// the CPU before the other processes. Unset: inherited.
    #[arg(long, allow_negative_numbers = true)]
    pub nice: Option<i32>,
    /// Run under SCHED_FIFO at this priority (1 to 99; needs CAP_SYS_NICE), as the robot's
    /// systemd drop-ins do: on a loaded machine without them, the 1 kHz exchange with the robot
    /// must not wait for the CPU. Unset: inherited.
    #[arg(long)]
    pub fifo: Option<i32>,
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
            Some(name) => Some(scenario_robot(&dir, name)?),
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
        motm_tasks::driver::velocity_driver(
            limits,
            period.as_secs_f64(),
            self.control_rate,
            self.stale_periods,
        )
    }

    /// What either driver sets up first, in this order: `--nice` and `--fifo` for its graph row
    /// `spec`, the robot model, the period (`--rate`, else the row's rate) and the driver logic
    /// for the axes `axes` reads off the robot. An error names the flag or file at fault.
    pub fn prepare(
        &self,
        spec: &motm_graph::TaskSpec,
        axes: impl FnOnce(&Robot) -> Vec<AxisLimits>,
    ) -> Result<(Robot, VelocityDriver, Duration), String> {
        self.apply_priority(spec.name)?;
        let robot = self.load_robot()?;
        let period = self.period(spec.rate.hz(self.control_rate))?;
        let driver = self.driver(axes(&robot), period)?;
        Ok((robot, driver, period))
    }

    /// Applies `--nice` and `--fifo` to this process; a refusal (no CAP_SYS_NICE) is printed,
    /// not fatal.
    pub fn apply_priority(&self, process: &str) -> Result<(), String> {
        apply_priority(process, self.nice, self.fifo)
    }

    /// The connection wait from `--connect-wait`, checked.
    pub fn connect_wait(&self) -> Result<Duration, String> {
        let s = self.connect_wait;
        if s.is_finite() && s >= 0.0 {
            Ok(Duration::from_secs_f64(s))
        } else {
            Err(format!("--connect-wait: must be a time in s >= 0, got {s}"))
        }
    }

    /// Driver cycles between two status messages at `period` (from `--status-rate`).
    pub fn status_every(&self, period: Duration) -> u64 {
        ((1.0 / self.status_rate) / period.as_secs_f64())
            .round()
            .max(1.0) as u64
    }
}

/// The service loop settings of a driver at `period`.
pub fn loop_config(period: Duration) -> motm_bus::LoopConfig {
    motm_bus::LoopConfig {
        period,
        ..motm_bus::LoopConfig::default()
    }
}

/// The `robot` key of scenario `name` (a file, or a name in `<dir>/scenarios/`), read without
/// the simulator: the rest of the scenario is sim-world's.
fn scenario_robot(dir: &Path, name: &str) -> Result<String, String> {
    let direct = Path::new(name);
    let path = if direct.is_file() {
        direct.to_path_buf()
    } else {
        dir.join("scenarios").join(format!("{name}.toml"))
    };
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("--scenario {name}: {}: {e}", path.display()))?;
    let table: toml::Table = text
        .parse()
        .map_err(|e| format!("--scenario {name}: {}: {e}", path.display()))?;
    match table.get("robot") {
        Some(toml::Value::String(robot)) => Ok(robot.clone()),
        Some(other) => Err(format!(
            "--scenario {name}: {}: robot: must be a robot name, got {other}",
            path.display()
        )),
        None => Err(format!(
            "--scenario {name}: {}: robot: missing",
            path.display()
        )),
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

pub use motm_tasks::driver::status_message;

/// Applies `--nice NICE` (setpriority(2)) and `--fifo PRIO` (SCHED_FIFO, sched_setscheduler(2))
/// to this process. A value out of range is an error naming the flag; a refusal by the
/// system (no CAP_SYS_NICE) is printed and the process runs at the inherited priority.
pub fn apply_priority(process: &str, nice: Option<i32>, fifo: Option<i32>) -> Result<(), String> {
    if let Some(nice) = nice {
        if !(-20..=19).contains(&nice) {
            return Err(format!("--nice: must be -20 to 19, got {nice}"));
        }
        // SAFETY: setpriority(2) has no memory-safety preconditions; 0 is this process.
        if unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) } != 0 {
            let e = std::io::Error::last_os_error();
            motm_bus::say!("{process}: --nice {nice}: {e}; running at the inherited priority");
        }
    }
    if let Some(priority) = fifo {
        if !(1..=99).contains(&priority) {
            return Err(format!("--fifo: must be 1 to 99, got {priority}"));
        }
        let param = libc::sched_param {
            sched_priority: priority,
        };
        // SAFETY: `param` is a valid sched_param for the call; 0 is this process.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
            let e = std::io::Error::last_os_error();
            motm_bus::say!("{process}: --fifo {priority}: {e}; running at the inherited priority");
        }
    }
    Ok(())
}

/// Calls `connect` until it succeeds or `wait` has passed (100 ms apart): a robot that is
/// still booting, or a fake robot started just before the driver, is waited for. The error
/// names `what` and the last failure.
pub fn connect_within<T, E: std::fmt::Display>(
    what: &str,
    wait: Duration,
    mut connect: impl FnMut() -> Result<T, E>,
) -> Result<T, String> {
    let start = std::time::Instant::now();
    loop {
        match connect() {
            Ok(t) => return Ok(t),
            Err(e) if start.elapsed() >= wait => {
                return Err(format!(
                    "{what}: {e} (still failing after {:.1} s)",
                    start.elapsed().as_secs_f64()
                ));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

/// Maps a driver's result to its exit code, printing the error.
pub fn exit(process: &str, result: Result<(), (u8, String)>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err((code, message)) => {
            motm_bus::say!("{process}: {message}");
            ExitCode::from(code)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connecting_retries_until_the_wait_is_over() {
        let mut tries = 0;
        let ok = connect_within("x", Duration::from_secs(10), || {
            tries += 1;
            if tries < 3 { Err("refused") } else { Ok(tries) }
        });
        assert_eq!(ok, Ok(3));
        let err = connect_within::<(), _>("robot 1.2.3.4:1", Duration::ZERO, || Err("refused"))
            .unwrap_err();
        assert!(err.contains("robot 1.2.3.4:1: refused"), "{err}");
    }

    #[test]
    fn backend_names_are_the_flag_values() {
        use clap::ValueEnum;
        for b in Backend::value_variants() {
            assert_eq!(b.to_possible_value().unwrap().get_name(), b.name());
        }
    }

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
        let cli = Cli::try_parse_from(["d", "--nice", "-30"]).unwrap();
        assert!(cli.args.apply_priority("d").unwrap_err().contains("--nice"));
        let cli = Cli::try_parse_from(["d", "--fifo", "100"]).unwrap();
        assert!(cli.args.apply_priority("d").unwrap_err().contains("--fifo"));
        let cli = Cli::try_parse_from(["d", "--connect-wait=-1"]).unwrap();
        assert!(
            cli.args
                .connect_wait()
                .unwrap_err()
                .contains("--connect-wait")
        );
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
        assert!(err.contains("--scenario no-such-scenario"), "{err}");
        let dir = std::env::temp_dir().join(format!("motm-driver-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("robotless.toml");
        for (text, expected) in [
            ("name = \"x\"\n", "robot: missing"),
            ("robot = 3\n", "robot: must be a robot name"),
            ("robot = \n", "robotless.toml"),
        ] {
            std::fs::write(&file, text).unwrap();
            let err = parse(&["--scenario", file.to_str().unwrap()])
                .load_robot()
                .unwrap_err();
            assert!(
                err.contains(expected) && err.contains("--scenario"),
                "{err}"
            );
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
