//! Closed-loop MotM trials of the press-button scenarios with the default noise (odometry
//! drift included): the cube is picked and placed, then the button is pressed on the move,
//! with the tool point on the cap, and the base touches nothing.

use std::path::{Path, PathBuf};

use motm_core::Robot;
use motm_sim::Scenario;
use motm_sim::experiment::{CYCLE_COLUMNS, Method};
use motm_sim::objects::ObjectConfig;
use motm_sim::runner::{RunnerConfig, run_trial};

/// Seeds each scenario is run with.
const SEEDS: [u64; 3] = [1, 2, 3];

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

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
    let dir = config_dir();
    let scenario = Scenario::from_file(&dir.join("scenarios").join(format!("{name}.toml")))
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let [button] = scenario.buttons.as_slice() else {
        panic!("{name}: expected one button");
    };
    let robot = Robot::load(&dir, &scenario.robot).unwrap();
    let config = RunnerConfig {
        record_cycles: true,
        ..RunnerConfig::default()
    };
    let cap_radius = ObjectConfig::default().button_radius;
    let (x, y, z) = (column("tool_x"), column("tool_y"), column("tool_z"));
    for seed in SEEDS {
        let (result, trace) =
            run_trial(&robot, &scenario, Method::Motm, seed, &config, true).unwrap();
        assert!(
            result.success,
            "{name} seed {seed}: {:?} after {:.2} s",
            result.failure, result.sim_time_s
        );
        assert_eq!(result.round_trips_s.len(), 1, "{name} seed {seed}");
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
