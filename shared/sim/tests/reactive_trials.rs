//! Closed-loop trials of the reactive baseline (ALGORITHMS.md §3) with the scenarios' default
//! noise: it must pick the cube and drop it into the container, static or moving.

use std::path::{Path, PathBuf};

use motm_core::Robot;
use motm_sim::Scenario;
use motm_sim::experiment::Method;
use motm_sim::runner::{RunnerConfig, run_trial};

/// Seeds each scenario is run with.
const SEEDS: [u64; 3] = [1, 2, 3];

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// Runs the reactive baseline on `config/scenarios/<name>.toml` for every seed and asserts that
/// every trial succeeds by dropping the cube, within the runner's timeout.
fn assert_reactive_succeeds(name: &str) {
    let dir = config_dir();
    let scenario = Scenario::from_file(&dir.join("scenarios").join(format!("{name}.toml")))
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let robot = Robot::load(&dir, &scenario.robot).unwrap();
    let config = RunnerConfig::default();
    for seed in SEEDS {
        let (result, _) =
            run_trial(&robot, &scenario, Method::Reactive, seed, &config, false).unwrap();
        assert!(
            result.success,
            "{name} seed {seed}: {:?} after {:.2} s",
            result.failure, result.sim_time_s
        );
        assert!(result.failure.is_none());
        assert_eq!(result.round_trips_s.len(), 1, "{name} seed {seed}");
        assert!(
            result.task_time_s < config.timeout_base + config.timeout_per_task,
            "{name} seed {seed}: {} s",
            result.task_time_s
        );
    }
}

#[test]
fn reactive_baseline_picks_and_places_a_static_cube() {
    assert_reactive_succeeds("exp1-static");
}

#[test]
fn reactive_baseline_picks_and_places_a_moving_cube() {
    assert_reactive_succeeds("exp1-dynamic");
}
