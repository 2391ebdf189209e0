//! Closed-loop MotM trials of the press-button scenarios with the default noise (odometry
//! drift included): the cube is picked and placed, then the button is pressed on the move,
//! with the tool point on the cap, and the base touches nothing.

mod support;

use motm_sim::experiment::{CYCLE_COLUMNS, Method};
use motm_sim::objects::ObjectConfig;
use motm_sim::runner::RunnerConfig;
use support::{load_scenario, successful_trials};

fn column(name: &str) -> usize {
    CYCLE_COLUMNS
        .iter()
        .position(|c| *c == name)
        .unwrap_or_else(|| panic!("no trace column {name}"))
}

/// Runs MotM on `config/scenarios/<name>.toml` for every seed and asserts that each trial
/// succeeds (the cube placed and the button pressed, which ends the trial) and that on the
/// last cycle the true tool point is on the cap and pushed down by at least the button's
/// switching travel.
fn assert_button_pressed(name: &str) {
    let (robot, scenario) = load_scenario(name);
    let [button] = scenario.buttons.as_slice() else {
        panic!("{name}: expected one button");
    };
    let config = RunnerConfig {
        record_cycles: true,
        ..RunnerConfig::default()
    };
    let cap_radius = ObjectConfig::default().button_radius;
    let (x, y, z) = (column("tool_x"), column("tool_y"), column("tool_z"));
    for (seed, result, trace) in
        successful_trials(name, &robot, &scenario, Method::Motm, &config, true)
    {
        let trace = trace.expect("a trace was asked for");
        let last = trace.cycles.last().expect("at least one cycle");
        let [bx, by, bz] = button.position;
        let off_centre = (last[x] - bx).hypot(last[y] - by);
        let travel = bz - last[z];
        eprintln!(
            "{name} seed {seed}: pressed at {:.2} s, tool {:.1} mm off the cap's centre, \
             {:.1} mm down",
            result.sim_time_s,
            off_centre * 1e3,
            travel * 1e3
        );
        assert!(
            off_centre < cap_radius,
            "{name} seed {seed}: tool {off_centre} m off the cap's centre"
        );
        assert!(
            travel >= button.depth - 1e-3,
            "{name} seed {seed}: pushed {travel} m"
        );
    }
}

#[test]
fn motm_presses_the_button_after_a_place_on_the_other_side_of_the_base() {
    // The cube is passed on the base's right, the container on its left, then the button.
    assert_button_pressed("button");
}

#[test]
fn motm_presses_the_button_of_the_swap_scenario() {
    assert_button_pressed("button-swap");
}
