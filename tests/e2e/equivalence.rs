//! The two forms of the one graph agree: for the same scenario and seed, `motm trial` (the
//! tasks scheduled in one process) and `motm run` (the same tasks as processes over iceoryx2)
//! give the same success and the same failure reason, with task times within 3 %.
//!
//! Scenarios: exp1-dynamic (a moving cube), button (the press must register: the trial
//! succeeds only then) and two-in-a-row (two picks and places). Seeds: 1 by default (CI);
//! `MOTM_EQUIVALENCE_SEEDS=10` runs seeds 1 to 10 of each.

use motm_e2e::{motm, one_stack_at_a_time};

/// Largest relative difference of the task times.
const TOLERANCE: f64 = 0.03;

fn seeds() -> u64 {
    std::env::var("MOTM_EQUIVALENCE_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

fn json(out: &std::process::Output, what: &str) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{what}: no JSON ({e}); stderr {}",
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

fn check(scenario: &str) {
    for seed in 1..=seeds() {
        let seed_arg = seed.to_string();
        let common = [
            "--scenario",
            scenario,
            "--seed",
            seed_arg.as_str(),
            "--json",
        ];
        let prefix = format!(
            "motmeq{}_{}_{seed}_",
            std::process::id(),
            scenario.replace('-', "")
        );
        // The trial takes the machine too: a deployed stack runs in real time, and a trial of
        // another test beside it would starve it (2 cores).
        let _stack = one_stack_at_a_time();
        let trial = json(
            &motm(&[&["trial"], &common[..]].concat(), &prefix),
            "motm trial",
        );
        let run = json(
            &motm(&[&["run"], &common[..]].concat(), &prefix),
            "motm run",
        );
        let context = format!("{scenario} seed {seed}: trial {trial}\nrun {run}");
        assert_eq!(trial["success"], run["success"], "{context}");
        assert_eq!(trial["failure"], run["failure"], "{context}");
        let (a, b) = (
            trial["task_time_s"].as_f64().unwrap(),
            run["task_time_s"].as_f64().unwrap(),
        );
        assert!(
            (a - b).abs() <= TOLERANCE * a,
            "task time {b} s deployed vs {a} s in-process: {context}"
        );
    }
}

#[test]
fn exp1_dynamic_is_the_same_in_both_forms() {
    check("exp1-dynamic");
}

#[test]
fn a_button_press_is_the_same_in_both_forms() {
    check("button");
}

#[test]
fn two_picks_and_places_are_the_same_in_both_forms() {
    check("two-in-a-row");
}
