//! A closed-loop Exp 2 run that once stood still: the base, wedged beside the row of
//! platforms after a pick with every route to the container blocked, turned neither way.

mod support;

use motm_sim::experiment::Method;
use motm_sim::runner::{RunnerConfig, run_trial};
use support::load_scenario;

#[test]
fn a_base_wedged_beside_exp2_s_row_turns_out_and_goes_on() {
    let (robot, mut scenario) = load_scenario("exp2");
    scenario.base_speed = 0.3;
    // Seed 28 stood from 59 s on, with two cubes dropped; turning out, it drops its third by
    // 75 s (the first round trip counted is the first drop's time).
    let config = RunnerConfig {
        timeout_base: 90.0,
        timeout_per_task: 0.0,
        ..RunnerConfig::default()
    };
    let (result, _) =
        run_trial(&robot, &scenario, Method::Motm, 28, &config, false).expect("the trial runs");
    assert!(
        result.round_trips_s.len() >= 3,
        "drops by 90 s: {} ({:?})",
        result.round_trips_s.len(),
        result.failure
    );
}
