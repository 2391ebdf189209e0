//! `motm run --hardware fake`: the drivers on their real backends (`fci`, `arnl`) speak the
//! real protocols over loopback sockets to `fake-panda` and `fake-ld60`, whose physics is
//! sim-world's. Frankie's exp1-dynamic succeeds with no command beyond a limit at the drivers
//! nor at the fake robots; a killed panda-driver is restarted, connects to the fake robot again,
//! and the task goes on; a driver stalled for 100 ms recovers the robot from its
//! communication-constraints reflex, and the task goes on.

use motm_e2e::{assert_nothing_left, motm_json, one_stack_at_a_time, stack_processes};

/// Runs `motm run --hardware fake --json <extra>`; checks what every such run must satisfy and
/// returns the report, whether it exited with success, and stderr.
fn run_fake(tag: &str, extra: &[&str]) -> (serde_json::Value, bool, String) {
    let prefix = format!("motmhw{}_{tag}_", std::process::id());
    let mut args = vec!["run", "--hardware", "fake", "--json"];
    args.extend_from_slice(extra);
    let (report, success, stderr) = motm_json(&args, &prefix);
    assert_eq!(report["hardware"], "fake", "{report}");
    assert_eq!(report["backends"]["panda-driver"], "fci", "{report}");
    assert_eq!(report["backends"]["ld60-driver"], "arnl", "{report}");
    assert_eq!(report["limit_violations"], 0, "{report}\n{stderr}");
    assert_eq!(report["output_violations"], 0, "{report}\n{stderr}");
    assert_eq!(report["fake_robot_violations"], 0, "{report}\n{stderr}");
    assert_eq!(report["stale_shm_entries"], 0, "{report}");
    let processes = report["processes"].as_array().expect("processes");
    for name in stack_processes()
        .into_iter()
        .chain(["fake-panda", "fake-ld60"])
    {
        let p = processes
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{name} missing from {report}"));
        assert!(p["pid"].as_u64().unwrap() > 0, "{name}: {report}");
    }
    assert_nothing_left(&report, &prefix);
    (report, success, stderr)
}

/// The row of process `name` in `report`.
fn process<'a>(report: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    report["processes"]
        .as_array()
        .and_then(|ps| ps.iter().find(|p| p["name"] == name))
        .unwrap_or_else(|| panic!("{name} missing from {report}"))
}

/// The restarts of process `name` in `report`.
fn restarts(report: &serde_json::Value, name: &str) -> u64 {
    process(report, name)["restarts"].as_u64().unwrap()
}

#[test]
fn exp1_dynamic_succeeds_on_the_fake_robots_over_the_real_protocols() {
    let _turn = one_stack_at_a_time();
    let (report, exit_ok, stderr) = run_fake("run", &["--seed", "1"]);
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
    for name in stack_processes().into_iter().chain(["fake-ld60"]) {
        assert_eq!(restarts(&report, name), 0, "{name}: {report}\n{stderr}");
    }
    // The drivers spoke the protocols: the FCI driver connected and the LD-60 driver drove.
    assert!(
        stderr.contains(
            "panda-driver: connected to the robot at 127.0.0.1:1337 (FCI v5) and its hand"
        ),
        "{stderr}"
    );
    assert!(stderr.contains("fake-panda: robot time"), "{stderr}");
    let cycles = process(&report, "panda-driver")["cycles"].as_u64().unwrap();
    assert!(cycles > 1000, "{report}");
}

#[test]
fn a_killed_panda_driver_reconnects_to_the_fake_robot_and_the_task_goes_on() {
    let _turn = one_stack_at_a_time();
    let (report, exit_ok, stderr) =
        run_fake("kill", &["--seed", "1", "--fault", "kill:panda-driver@4"]);
    let record = &report["faults_injected"][0];
    assert_eq!(record["kind"], "kill", "{report}");
    assert_eq!(record["outcome"], "restarted", "{report}\n{stderr}");
    assert_eq!(restarts(&report, "panda-driver"), 1, "{report}");
    assert_eq!(restarts(&report, "fake-panda"), 0, "{report}");
    let connected = stderr
        .matches("panda-driver: connected to the robot at 127.0.0.1:1337")
        .count();
    assert_eq!(
        connected, 2,
        "one connection per driver instance:\n{stderr}"
    );
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
}

#[test]
fn a_stalled_panda_driver_is_recovered_from_the_robots_reflex_and_the_task_goes_on() {
    // A 100 ms SIGSTOP of the driver mid-task: the fake robot misses 20 commands in a row and
    // stops on its communication-constraints reflex, as the Panda does. Once the arm is at
    // rest the resumed driver sends AutomaticErrorRecovery and a new motion, and the task
    // completes with no limit exceeded.
    let _turn = one_stack_at_a_time();
    let (report, exit_ok, stderr) = run_fake(
        "stall",
        &["--seed", "1", "--fault", "stop:panda-driver@6+0.1"],
    );
    let record = &report["faults_injected"][0];
    assert_eq!(record["kind"], "stop", "{report}");
    assert_eq!(record["outcome"], "resumed", "{report}\n{stderr}");
    assert_eq!(restarts(&report, "panda-driver"), 0, "{report}");
    assert!(
        stderr.contains("(communication_constraints_violation)"),
        "no reflex:\n{stderr}"
    );
    assert!(
        stderr.contains("panda-driver: AutomaticErrorRecovery answered Success"),
        "{stderr}"
    );
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
}
