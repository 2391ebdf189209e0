//! `motm trial`: one in-process trial of a scenario with one method, printed as JSON or text.

use std::path::{Path, PathBuf};

use clap::Args;
use motm_core::Robot;
use motm_core::on_the_move::OnTheMoveConfig;
use motm_sim::experiment::{Method, TrialResult, TrialSpec, TrialTrace};
use motm_sim::runner::{RunnerConfig, run_trial};
use motm_sim::{Scenario, scenario_path};

use crate::CliError;

/// Arguments of `motm trial`.
#[derive(Args, Debug)]
pub struct TrialArgs {
    /// Scenario file (TOML), the name of one in `<config>/scenarios/`, or `generated:<robot>`
    /// (the generated layout of `--seed`).
    #[arg(long)]
    pub scenario: String,
    /// Control method: motm, reactive or planning.
    #[arg(long, default_value = "motm")]
    pub method: Method,
    /// Base speed v_F, m/s (overrides the scenario's `base_speed`).
    #[arg(long, allow_negative_numbers = true)]
    pub base_speed: Option<f64>,
    /// RNG seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write every control cycle (true and estimated poses, target estimate, cube, gripper,
    /// base command) to this CSV file.
    #[arg(long)]
    pub trace_csv: Option<PathBuf>,
    /// Write the trial's replay log (every sample on the bus and every task cycle) to this
    /// MCAP file, for `motm replay` (MotM only).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Controller gains (TOML; default: `controllers.toml` in the config folder, the file the
    /// deployed stack reads).
    #[arg(long)]
    pub controllers: Option<PathBuf>,
    /// Write the scenario the trial runs (a generated layout's text, or the file's) to this
    /// TOML file, to read it or run it again with `motm run --scenario`.
    #[arg(long)]
    pub save_scenario: Option<PathBuf>,
}

/// The runner settings with the controller gains of `controllers` (default: the config
/// folder's `controllers.toml`, as the deployed services read it); a bad file is bad input.
pub fn runner_config(
    config_dir: &Path,
    controllers: Option<&Path>,
) -> Result<RunnerConfig, CliError> {
    let motm = OnTheMoveConfig::for_stack(config_dir, controllers)
        .map_err(|e| CliError::BadInput(e.to_string()))?;
    Ok(RunnerConfig {
        motm,
        ..RunnerConfig::default()
    })
}

/// Loads a scenario and its robot, with the base speed overridden when given. A generated
/// layout (`generated:<robot>`, [`motm_sim::generated`]) is the one of `seed`.
pub fn load(
    config_dir: &Path,
    scenario: &str,
    base_speed: Option<f64>,
    seed: u64,
) -> Result<(Robot, Scenario), CliError> {
    let (path, text) = scenario_text(config_dir, scenario, seed)?;
    let mut scenario =
        Scenario::from_toml_str(&path, &text).map_err(|e| CliError::BadInput(e.to_string()))?;
    if let Some(v) = base_speed {
        scenario
            .set_base_speed(v)
            .map_err(|e| CliError::BadInput(e.to_string()))?;
    }
    let robot =
        Robot::load(config_dir, &scenario.robot).map_err(|e| CliError::BadInput(e.to_string()))?;
    Ok((robot, scenario))
}

/// The path and text of a scenario: a file, a name in `<config>/scenarios/`, or a generated
/// layout (`generated:<robot>`, the one of `seed`; its path is the name).
pub fn scenario_text(
    config_dir: &Path,
    scenario: &str,
    seed: u64,
) -> Result<(PathBuf, String), CliError> {
    if let Some(robot) = motm_sim::generated::robot_of(scenario) {
        return Ok((
            PathBuf::from(scenario),
            motm_sim::generated::layout_toml(robot, seed),
        ));
    }
    let path = scenario_path(config_dir, scenario);
    let text = motm_core::ModelError::read_to_string(&path)
        .map_err(|e| CliError::BadInput(e.to_string()))?;
    Ok((path, text))
}

/// Runs the trial an experiment spec describes.
pub fn run_spec(
    config_dir: &Path,
    spec: &TrialSpec,
    config: &RunnerConfig,
    trace: bool,
) -> Result<(TrialResult, Option<TrialTrace>), CliError> {
    let (robot, scenario) = load(config_dir, &spec.scenario, Some(spec.base_speed), spec.seed)?;
    run_trial(&robot, &scenario, spec.method, spec.seed, config, trace).map_err(CliError::BadInput)
}

/// `motm trial`.
pub fn run(config_dir: &Path, args: &TrialArgs) -> Result<(), CliError> {
    let (robot, scenario) = load(config_dir, &args.scenario, args.base_speed, args.seed)?;
    if let Some(path) = &args.save_scenario {
        let (_, text) = scenario_text(config_dir, &args.scenario, args.seed)?;
        std::fs::write(path, text)
            .map_err(|e| CliError::Failed(format!("--save-scenario {}: {e}", path.display())))?;
    }
    if args.mcap.is_some() && args.method != Method::Motm {
        return Err(CliError::BadInput(format!(
            "--mcap: replay logs are written for --method motm, not {}",
            args.method
        )));
    }
    let config = RunnerConfig {
        record_cycles: args.trace_csv.is_some(),
        record_log: args.mcap.is_some(),
        ..runner_config(config_dir, args.controllers.as_deref())?
    };
    let (result, mut trace) = run_trial(
        &robot,
        &scenario,
        args.method,
        args.seed,
        &config,
        args.trace_csv.is_some() || args.mcap.is_some(),
    )
    .map_err(CliError::BadInput)?;
    if let Some(path) = &args.mcap {
        let log = trace
            .as_mut()
            .and_then(|t| t.log.take())
            .ok_or_else(|| CliError::Failed("the trial kept no replay log".into()))?;
        let info = motm_logger::replay_log::TrialInfo {
            scenario: scenario.path.clone(),
            seed: args.seed,
            base_speed: scenario.base_speed,
        };
        crate::replay::write_log(path, &info, &log).map_err(CliError::Failed)?;
    }
    if let (Some(path), Some(trace)) = (&args.trace_csv, trace) {
        let mut csv = motm_sim::experiment::CYCLE_COLUMNS.join(",") + "\n";
        for row in &trace.cycles {
            let cells: Vec<String> = row.iter().map(|v| format!("{v:.5}")).collect();
            csv += &cells.join(",");
            csv.push('\n');
        }
        std::fs::write(path, csv)
            .map_err(|e| CliError::Failed(format!("{}: {e}", path.display())))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&result).map_err(|e| CliError::Failed(e.to_string()))?
        );
    } else {
        println!(
            "{} with {} at {:.2} m/s, seed {}: {}",
            scenario.name,
            args.method,
            scenario.base_speed,
            args.seed,
            match &result.failure {
                None => "success".to_string(),
                Some(reason) => format!("failed ({reason})"),
            }
        );
        println!(
            "task time {:.2} s, MTPH {:.1}, EE |a| mean {:.2} max {:.2} m/s² ({})",
            result.task_time_s,
            result.mtph,
            result.ee_acc_mean,
            result.ee_acc_max,
            result.ee_acc_filter
        );
        println!(
            "simulated {:.1} s in {:.2} s wall ({:.0}× real time)",
            result.sim_time_s,
            result.wall_time_s,
            result.sim_time_s / result.wall_time_s.max(1e-9)
        );
    }
    if result.success {
        Ok(())
    } else {
        Err(CliError::Failed(format!(
            "trial failed: {}",
            result.failure.unwrap_or_default()
        )))
    }
}
