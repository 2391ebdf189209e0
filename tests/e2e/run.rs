//! `motm run --json` on Frankie exp1-dynamic with the real processes: the pick and place of a
//! moving cube on-the-move succeeds, no driver command exceeds a limit, and the run leaves no
//! process and no iceoryx2 resource behind.

use motm_bus::IpcConfig;
use motm_e2e::{motm, processes_mentioning};

#[test]
fn motm_run_exp1_dynamic_succeeds_and_leaves_nothing_behind() {
    let prefix = format!("motme2e{}_", std::process::id());
    let out = motm(&["run", "--json"], &prefix);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("no JSON report ({e}); stdout {stdout}; stderr {stderr}"));
    assert_eq!(report["success"], true, "{report}\n{stderr}");
    assert!(out.status.success(), "exit {}: {stderr}", out.status);
    assert_eq!(report["limit_violations"], 0, "{report}");
    assert_eq!(report["output_violations"], 0, "{report}");
    assert_eq!(report["stale_shm_entries"], 0, "{report}");
    let processes = report["processes"].as_array().expect("processes");
    for name in [
        "sim-world",
        "panda-driver",
        "ld60-driver",
        "perception",
        "base-planner",
        "reacher",
        "final-phase",
        "qp-resolver",
        "watchdog",
        "supervisor",
    ] {
        let p = processes
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{name} missing from {report}"));
        assert!(
            p["cycles"].as_u64().unwrap() > 0,
            "{name} never cycled: {report}"
        );
        assert!(p["pid"].as_u64().unwrap() > 0, "{report}");
    }
    // No orphans: nothing of this run is still alive (the stack's processes carry the
    // prefix in their environment, so look for their pids).
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
    // No stale shared memory.
    let ipc = IpcConfig { prefix };
    assert_eq!(
        motm_bus::shared_memory_entries(&ipc).unwrap(),
        Vec::<std::path::PathBuf>::new()
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
