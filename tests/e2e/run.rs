//! `motm run --json` on Frankie exp1-dynamic with the real processes: the pick and place of a
//! moving cube on-the-move succeeds, no driver command exceeds a limit, and the run leaves no
//! process and no iceoryx2 resource behind. (That it does so as the in-process trial does,
//! with the task time within 3 %, is `equivalence.rs`.)

use motm_bus::IpcConfig;
use motm_e2e::{assert_nothing_left, motm, motm_json, one_stack_at_a_time, stack_processes};

/// Runs `motm run --json <extra>` with a fresh prefix; returns the report, whether the exit
/// status was success, and stderr. Checks on the way what every run must satisfy, success or
/// not: no driver command beyond a limit, every process cycled, no orphan, no stale shared
/// memory.
fn run_and_check(extra: &[&str]) -> (serde_json::Value, bool, String) {
    let prefix = format!(
        "motme2e{}_{}_",
        std::process::id(),
        extra.join("").replace(['-', '.'], "")
    );
    let mut args = vec!["run", "--json"];
    args.extend_from_slice(extra);
    let (report, success, stderr) = motm_json(&args, &prefix);
    assert_eq!(report["limit_violations"], 0, "{report}");
    assert_eq!(report["output_violations"], 0, "{report}");
    assert_eq!(report["stale_shm_entries"], 0, "{report}");
    assert!(
        report["sim_time_s"].as_f64().unwrap() > 0.0,
        "no truth from sim-world: {report}"
    );
    let processes = report["processes"].as_array().expect("processes");
    for name in stack_processes() {
        let p = processes
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{name} missing from {report}"));
        assert!(
            p["cycles"].as_u64().unwrap() > 0,
            "{name} never cycled: {report}"
        );
        assert!(p["pid"].as_u64().unwrap() > 0, "{report}");
        assert_eq!(p["restarts"], 0, "{name} restarted: {report}\n{stderr}");
    }
    assert_nothing_left(&report, &prefix);
    (report, success, stderr)
}

#[test]
fn motm_run_exp1_dynamic_succeeds() {
    let _one = one_stack_at_a_time();
    let (report, exit_ok, stderr) = run_and_check(&[]);
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
    assert!(report["failure"].is_null(), "{report}");
}

/// "Two hosts": perception on its own iceoryx2 prefix, its inputs and its target carried by
/// two zenoh peers on loopback TCP (multicast scouting off), and the task still completes.
/// Perception's heartbeat reaches the stack only through the bridge, so `run_and_check`
/// finding it cycling shows the bridge carried it.
#[test]
fn motm_run_with_perception_on_a_remote_host_behind_zenoh_succeeds() {
    let _one = one_stack_at_a_time();
    let (report, exit_ok, stderr) = run_and_check(&["--remote", "perception"]);
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
    let processes = report["processes"].as_array().unwrap();
    for bridge in [motm_graph::STACK_BRIDGE, motm_graph::REMOTE_BRIDGE] {
        let p = processes
            .iter()
            .find(|p| p["name"] == bridge)
            .unwrap_or_else(|| panic!("{bridge} missing from {report}"));
        assert!(p["cycles"].as_u64().unwrap() > 0, "{bridge}: {report}");
    }
    assert!(stderr.contains("zenoh-stack: bridging"), "{stderr}");
    assert!(stderr.contains("zenoh-remote: bridging"), "{stderr}");
}

#[test]
fn motm_run_rejects_a_bad_stack_config_with_exit_code_2() {
    let dir = std::env::temp_dir().join(format!("motm-e2e-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "robot = \"frankie\"\nscenario = \"exp1-dynamic\"\nrte = 1\n",
    )
    .unwrap();
    let out = motm(
        &["run", "--config", bad.to_str().unwrap()],
        &format!("motme2ebad{}_", std::process::id()),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("bad.toml") && stderr.contains("rte"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn motm_run_names_missing_service_binaries_and_exits_1() {
    let dir = std::env::temp_dir().join(format!("motm-e2e-missing-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let stack = dir.join("missing.toml");
    std::fs::write(
        &stack,
        "robot = \"frankie\"\nscenario = \"exp1-dynamic\"\npartial = true\n\
         [[process]]\nname = \"no-such-service\"\n",
    )
    .unwrap();
    let prefix = format!("motme2emissing{}_", std::process::id());
    let out = motm(&["run", "--config", stack.to_str().unwrap()], &prefix);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("service binaries missing") && stderr.contains("no-such-service"),
        "{stderr}"
    );
    // Nothing was started, so nothing of the prefix exists.
    let ipc = IpcConfig { prefix };
    assert!(motm_bus::shared_memory_entries(&ipc).unwrap().is_empty());
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn bad_flags_are_blamed_on_the_flag_with_exit_code_2() {
    let prefix = format!("motme2ebadflags{}_", std::process::id());
    for (args, expected) in [
        (
            &["trial", "--scenario", "exp1-dynamic", "--base-speed", "50"][..],
            "--base-speed 50: must be in (0, 2] m/s",
        ),
        // A negative number is a value, not a flag (no `=` needed).
        (
            &["trial", "--scenario", "exp1-dynamic", "--base-speed", "-1"][..],
            "--base-speed -1: must be in (0, 2] m/s",
        ),
        (
            &["run", "--config", "nosuch.toml"][..],
            "--config nosuch.toml: nosuch.toml: cannot read",
        ),
    ] {
        let out = motm(args, &prefix);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
        assert!(!stderr.contains(".toml.toml"), "{args:?}: {stderr}");
    }
}
