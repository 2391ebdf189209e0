//! The command line of `sim-world` and the [`SimWorldTask`] it builds.

use std::path::PathBuf;

use motm_bus::LoopConfig;
use motm_core::Robot;
use motm_sim::Scenario;
use motm_sim::runner::RunnerConfig;
use motm_sim::scenario_path;
use motm_sim::sim_world::{SimWorld, SimWorldConfig};
use motm_sim::task::SimWorldTask;

use motm_core::resolve_config_dir;

/// The flags of `sim-world`.
#[derive(Debug, Clone, clap::Args)]
pub struct SimWorldArgs {
    /// Folder holding robots/ and scenarios/ (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Scenario file (TOML), or the name of one in `<config>/scenarios/`.
    #[arg(long, default_value = "exp1-dynamic")]
    pub scenario: String,
    /// Robot model; must be the scenario's (default: the scenario's).
    #[arg(long)]
    pub robot: Option<String>,
    /// Base speed, m/s (overrides the scenario's `base_speed`).
    #[arg(long)]
    pub base_speed: Option<f64>,
    /// Trial seed (as `motm trial --seed`); perception must get the same one, since the camera
    /// calibration error is drawn from it.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Physics rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    pub rate: f64,
    /// Control rate of the stack, Hz: the EE acceleration metric is sampled at it, as in the
    /// in-process runner.
    #[arg(long, default_value_t = 200.0)]
    pub control_rate: f64,
    /// Rate of the ground-truth messages, Hz (a decided outcome is published at once).
    #[arg(long, default_value_t = 100.0)]
    pub truth_rate: f64,
    /// A hardware velocity command older than this is replaced by zero, s.
    #[arg(long, default_value_t = SimWorldConfig::default().command_timeout)]
    pub command_timeout: f64,
    /// Most physics steps one cycle may run to catch up on lost timer ticks (beyond that the
    /// simulation falls behind real time).
    #[arg(long, default_value_t = 10)]
    pub max_catch_up: u64,
}

impl SimWorldArgs {
    /// The world task and its loop timing (one cycle per physics step); every error is bad
    /// input and names the flag or file.
    pub fn build(&self) -> Result<(SimWorldTask, LoopConfig), String> {
        let config_dir = resolve_config_dir(self.config_dir.as_deref());
        let path = scenario_path(&config_dir, &self.scenario);
        let mut scenario = Scenario::from_file(&path).map_err(|e| e.to_string())?;
        if let Some(v) = self.base_speed {
            scenario.set_base_speed(v).map_err(|e| e.to_string())?;
        }
        if let Some(robot) = &self.robot
            && robot != &scenario.robot
        {
            return Err(format!(
                "--robot {robot}: the scenario {} is for robot '{}'",
                path.display(),
                scenario.robot
            ));
        }
        let robot = Robot::load(&config_dir, &scenario.robot).map_err(|e| e.to_string())?;
        for (flag, rate) in [
            ("--rate", self.rate),
            ("--control-rate", self.control_rate),
            ("--truth-rate", self.truth_rate),
            ("--command-timeout", self.command_timeout),
        ] {
            motm_wire::positive(flag, rate)?;
        }
        let runner = RunnerConfig {
            physics_step: 1.0 / self.rate,
            control_rate_hz: self.control_rate,
            ..RunnerConfig::default()
        };
        let config = SimWorldConfig {
            command_timeout: self.command_timeout,
        };
        let sim = SimWorld::new(&robot, &scenario, self.seed, &runner, config)
            .map_err(|e| e.to_string())?;
        let truth_every = ((1.0 / self.truth_rate) / sim.physics_step())
            .round()
            .max(1.0) as u64;
        let timing = LoopConfig::with_rate(self.rate);
        Ok((
            SimWorldTask::new(sim, truth_every, self.max_catch_up),
            timing,
        ))
    }
}
