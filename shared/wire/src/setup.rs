//! The command line every control service takes, and loading the robot, scenario and
//! controller settings it names.

use std::path::PathBuf;
use std::time::Duration;

use motm_core::Robot;
use motm_core::mission_file::MissionFile;
use motm_core::on_the_move::OnTheMoveConfig;
use motm_tasks::ControlSetup;

/// Robot used when neither `--robot` nor a scenario names one.
pub const DEFAULT_ROBOT: &str = "frankie";

/// Options shared by the control services.
#[derive(Debug, Clone, clap::Args)]
pub struct ServiceArgs {
    /// Config folder (default: $MOTM_CONFIG_DIR, then ./config, then the source tree's config/).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Scenario file: its mission (robot, base speed, tasks) is read; the simulated world's
    /// parts are left to the simulator.
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Robot name (default: the scenario's robot, else frankie).
    #[arg(long)]
    pub robot: Option<String>,
    /// Base forward speed, m/s (default: the scenario's).
    #[arg(long)]
    pub base_speed: Option<f64>,
    /// Trial seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Cycle rate, Hz.
    #[arg(long, default_value_t = 200.0)]
    pub rate: f64,
    /// Controller gains (TOML; default: `controllers.toml` in the config folder, else the
    /// built-in defaults).
    #[arg(long)]
    pub controllers: Option<PathBuf>,
}

/// Everything a control service loads at start-up.
#[derive(Debug, Clone)]
pub struct ServiceSetup {
    /// The config folder.
    pub config_dir: PathBuf,
    /// The robot model.
    pub robot: Robot,
    /// The mission of the scenario file, when one was given.
    pub mission: Option<MissionFile>,
    /// Controller settings (defaults, with the scenario's or the flag's base speed).
    pub config: OnTheMoveConfig,
    /// Trial seed.
    pub seed: u64,
    /// Cycle rate, Hz.
    pub rate_hz: f64,
}

pub use motm_core::resolve_config_dir;

impl ServiceSetup {
    /// Loads what `args` name; the error names the file or flag at fault.
    pub fn load(args: &ServiceArgs) -> Result<Self, String> {
        if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 10_000.0) {
            return Err(format!(
                "--rate: must be in (0, 10000] Hz, got {}",
                args.rate
            ));
        }
        let config_dir = resolve_config_dir(args.config_dir.as_deref());
        let mut mission = match &args.scenario {
            Some(path) => Some(MissionFile::from_file(path).map_err(|e| e.to_string())?),
            None => None,
        };
        let robot_name = args
            .robot
            .clone()
            .or_else(|| mission.as_ref().map(|s| s.robot.clone()))
            .unwrap_or_else(|| DEFAULT_ROBOT.to_owned());
        let robot = Robot::load(&config_dir, &robot_name).map_err(|e| e.to_string())?;
        let mut config = OnTheMoveConfig::for_stack(&config_dir, args.controllers.as_deref())
            .map_err(|e| e.to_string())?;
        if let Some(speed) = args.base_speed {
            match mission.as_mut() {
                Some(s) => s.set_base_speed(speed)?,
                None if speed.is_finite() && speed > 0.0 => {}
                None => return Err(format!("--base-speed: must be positive, got {speed}")),
            }
        }
        if let Some(speed) = args.base_speed.or(mission.as_ref().map(|s| s.base_speed)) {
            config.base.forward_speed = speed;
        }
        Ok(Self {
            config_dir,
            robot,
            mission,
            config,
            seed: args.seed,
            rate_hz: args.rate,
        })
    }

    /// What the control tasks are built from.
    pub fn control(&self) -> ControlSetup {
        ControlSetup {
            robot: self.robot.clone(),
            config: self.config.clone(),
            rate_hz: self.rate_hz,
        }
    }

    /// The cycle period.
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.rate_hz)
    }

    /// The cycle period, s.
    pub fn dt(&self) -> f64 {
        1.0 / self.rate_hz
    }
}

/// Unwraps a start-up result, or prints the error naming the process and exits with code 2.
pub fn exit_on_error<T, E: std::fmt::Display>(process: &str, result: Result<T, E>) -> T {
    match result {
        Ok(value) => value,
        Err(e) => {
            motm_bus::say!("{process}: {e}");
            std::process::exit(2);
        }
    }
}
