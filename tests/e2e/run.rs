//! `motm run --json` on Frankie exp1-dynamic with the real processes: the pick and place of a
//! moving cube on-the-move succeeds as the in-process trial does (task time within 5 %), no
//! driver command exceeds a limit, and the run leaves no process and no iceoryx2 resource
//! behind.

use motm_bus::IpcConfig;
use motm_e2e::{motm, processes_mentioning, stack_processes};

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
    let out = motm(&args, &prefix);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("no JSON report ({e}); stdout {stdout}; stderr {stderr}"));
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
    // No orphans: every pid of the run is gone (or a zombie of an unrelated reaper).
    for p in processes {
        let pid = p["pid"].as_u64().unwrap();
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
        assert!(
            stat.is_empty() || stat.contains(") Z "),
            "pid {pid} ({}) survived",
            p["name"]
        );
    }
    assert!(processes_mentioning(&prefix).is_empty());
    let ipc = IpcConfig { prefix };
    assert_eq!(
        motm_bus::shared_memory_entries(&ipc).unwrap(),
        Vec::<std::path::PathBuf>::new()
    );
    (report, out.status.success(), stderr)
}

#[test]
fn motm_run_exp1_dynamic_succeeds_like_the_in_process_trial() {
    let (report, exit_ok, stderr) = run_and_check(&[]);
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(exit_ok, "{stderr}");
    assert!(report["failure"].is_null(), "{report}");
    // Equivalence: the in-process trial of the same scenario and seed succeeds too, and the
    // task times agree within 5 %.
    let trial = motm(
        &[
            "trial",
            "--scenario",
            "exp1-dynamic",
            "--seed",
            "1",
            "--json",
        ],
        &format!("motme2etrial{}_", std::process::id()),
    );
    let trial: serde_json::Value =
        serde_json::from_slice(&trial.stdout).expect("motm trial --json prints JSON");
    assert_eq!(trial["success"], true, "{trial}");
    let multi = report["task_time_s"].as_f64().unwrap();
    let single = trial["task_time_s"].as_f64().unwrap();
    assert!(
        (multi - single).abs() <= 0.05 * single,
        "task time {multi} s multi-process vs {single} s in-process"
    );
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
