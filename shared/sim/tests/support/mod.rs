//! What the closed-loop trial tests share: the scenarios they load and the seeds they run.
//! Each test crate uses a part of it.
#![allow(dead_code)]

use std::path::Path;

use motm_core::Robot;
use motm_sim::Scenario;
use motm_sim::experiment::{Method, TrialResult, TrialTrace};
use motm_sim::runner::{RunnerConfig, run_trial};
use motm_sim::scenario_path;

/// Seeds each scenario is run with.
pub const SEEDS: [u64; 3] = [1, 2, 3];

/// `config/scenarios/<name>.toml` and the robot it names.
pub fn load_scenario(name: &str) -> (Robot, Scenario) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let scenario =
        Scenario::from_file(&scenario_path(&dir, name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    let robot = Robot::load(&dir, &scenario.robot).unwrap();
    (robot, scenario)
}

/// Runs `method` on scenario `name` for every seed in [`SEEDS`] and asserts that each trial
/// succeeds with one round trip; returns each seed with its result and (when `record_trace`)
/// its trace.
pub fn successful_trials(
    name: &str,
    robot: &Robot,
    scenario: &Scenario,
    method: Method,
    config: &RunnerConfig,
    record_trace: bool,
) -> Vec<(u64, TrialResult, Option<TrialTrace>)> {
    SEEDS
        .into_iter()
        .map(|seed| {
            let (result, trace) =
                run_trial(robot, scenario, method, seed, config, record_trace).unwrap();
            assert!(
                result.success,
                "{name} seed {seed}: {:?} after {:.2} s",
                result.failure, result.sim_time_s
            );
            assert_eq!(result.round_trips_s.len(), 1, "{name} seed {seed}");
            (seed, result, trace)
        })
        .collect()
}
