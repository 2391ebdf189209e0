//! Closed-loop trials of the reactive baseline (docs/algorithms.md §3) with the scenarios' default
//! noise: it must pick the cube and drop it into the container, static or moving.

mod support;

use motm_sim::experiment::Method;
use motm_sim::runner::RunnerConfig;
use support::{load_scenario, successful_trials};

/// Runs the reactive baseline on `config/scenarios/<name>.toml` for every seed and asserts that
/// every trial succeeds by dropping the cube, within the runner's timeout.
fn assert_reactive_succeeds(name: &str) {
    let (robot, scenario) = load_scenario(name);
    let config = RunnerConfig::default();
    for (seed, result, _) in
        successful_trials(name, &robot, &scenario, Method::Reactive, &config, false)
    {
        assert!(result.failure.is_none());
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
