//! Replay of an in-process MotM trial's log: with the same gains every control task's every
//! cycle gives the logged outputs; with one gain changed the divergence is found and named.

mod support;

use motm_sim::experiment::Method;
use motm_sim::replay::replay_log;
use motm_sim::runner::{RunnerConfig, run_trial};

#[test]
fn a_trial_log_replays_without_a_difference_and_a_changed_gain_is_reported() {
    let (robot, scenario) = support::load_scenario("exp1-dynamic");
    let config = RunnerConfig {
        record_log: true,
        ..RunnerConfig::default()
    };
    let (result, trace) = run_trial(&robot, &scenario, Method::Motm, 3, &config, true).unwrap();
    assert!(result.success, "{result:?}");
    let log = trace.and_then(|t| t.log).expect("a replay log");
    let same = replay_log(&robot, &scenario, 3, &config, &log, &[], None).unwrap();
    let names: Vec<&str> = same.iter().map(|r| r.name).collect();
    for spec in motm_graph::replayed_tasks() {
        assert!(
            names.contains(&spec.name),
            "{} replayed: {names:?}",
            spec.name
        );
    }
    for task in &same {
        assert!(task.cycles > 100, "{task:?}");
        assert_eq!(task.missing_inputs, 0, "{task:?}");
        assert_eq!(task.differing_cycles, 0, "{task:?}");
    }
    // A different reacher gain: the reacher's twists differ from the log, first in a
    // twist field, and the other tasks (fed the logged inputs) still agree.
    let mut changed = config.clone();
    changed.motm.reacher.arm_speed_ratio *= 0.7;
    let replay = replay_log(&robot, &scenario, 3, &changed, &log, &[], Some("reacher")).unwrap();
    let [reacher] = replay.as_slice() else {
        panic!("{replay:?}")
    };
    assert!(reacher.differing_cycles > 0, "{reacher:?}");
    let first = reacher.first_difference.as_ref().unwrap();
    assert_eq!(first.topic, "motm/v1/control/reach_twist");
    assert!(first.field.starts_with("twist["), "{first:?}");
    assert_ne!(first.logged, first.replayed);
    let others = replay_log(
        &robot,
        &scenario,
        3,
        &changed,
        &log,
        &[],
        Some("base-planner"),
    )
    .unwrap();
    assert_eq!(others[0].differing_cycles, 0, "{others:?}");
    assert!(replay_log(&robot, &scenario, 3, &config, &log, &[], Some("sim-world")).is_err());
}
