//! The systemd deployment: `deploy/install.sh` installs into a scratch folder, and
//! `systemd-analyze verify` accepts every installed unit (the template for each process with
//! its drop-ins, and `motm.target`) without a warning; `motm.target` wants exactly the graph's
//! processes that run on the robot. `systemd-analyze` is required: without it the test fails
//! and says how to install it (`.ci/run` does).

use std::path::Path;
use std::process::Command;

use motm_e2e::{stack_bin_dir, workspace_root};

/// Runs `systemd-analyze verify <unit>` with `units` searched first; returns (success, output).
fn verify(units: &Path, unit: &str) -> (bool, String) {
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(units.join(unit))
        .env("SYSTEMD_UNIT_PATH", format!("{}:", units.display()))
        .output()
        .expect("systemd-analyze");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// The units `motm.target` should want: one per process hosting a task of the graph that is not
/// simulation-only (the mission task's is the supervisor), in the graph's order.
fn robot_units() -> Vec<String> {
    let mut units: Vec<String> = Vec::new();
    for task in motm_graph::GRAPH.iter().filter(|t| !t.sim_only) {
        let process = match task.host {
            motm_graph::Host::Process => task.name,
            motm_graph::Host::Supervisor => "supervisor",
        };
        let unit = format!("motm@{process}.service");
        if !units.contains(&unit) {
            units.push(unit);
        }
    }
    units
}

#[test]
fn motm_target_wants_the_graphs_processes_that_run_on_the_robot() {
    let path = workspace_root().join("deploy/systemd/motm.target");
    let text = std::fs::read_to_string(&path).unwrap();
    let wanted: Vec<String> = text
        .lines()
        .filter_map(|line| line.trim().strip_prefix("Wants="))
        .flat_map(str::split_whitespace)
        .map(String::from)
        .collect();
    let expected = robot_units();
    assert!(expected.contains(&"motm@qp-resolver.service".to_string()));
    assert!(!expected.contains(&"motm@sim-world.service".to_string()));
    assert_eq!(
        wanted,
        expected,
        "{}: the Wants= lines must name the graph's processes that are not sim_only, in order",
        path.display()
    );
}

#[test]
fn installed_units_pass_systemd_analyze_verify() {
    if let Err(e) = Command::new("systemd-analyze").arg("--version").output() {
        panic!(
            "systemd-analyze is required for this test ({e}); install it with \
             `apt-get install -y --no-install-recommends systemd` (Debian; `.ci/run` does)"
        );
    }
    let root = std::env::temp_dir().join(format!("motm-deploy-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let bin = stack_bin_dir();
    let status = Command::new("bash")
        .arg(workspace_root().join("deploy/install.sh"))
        .args(["--prefix", &root.join("opt").display().to_string()])
        .args(["--confdir", &root.join("etc").display().to_string()])
        .args(["--unitdir", &root.join("units").display().to_string()])
        .args(["--bin-dir", &bin.display().to_string()])
        .args(["--no-user", "--no-enable", "--link"])
        .status()
        .expect("bash deploy/install.sh");
    assert!(status.success(), "install.sh failed");
    let units = root.join("units");
    let template = std::fs::read_to_string(units.join("motm@.service")).unwrap();
    for key in [
        "Type=notify",
        "WatchdogSec=",
        "Restart=on-failure",
        "RemoveIPC=no",
        "User=motm",
    ] {
        assert!(template.contains(key), "motm@.service lacks {key}");
    }
    // One argument file per process; the supervisor only runs the mission under systemd.
    let mut instances: Vec<String> = std::fs::read_dir(root.join("etc/env"))
        .unwrap()
        .map(|e| {
            let name = e.unwrap().file_name().to_string_lossy().into_owned();
            name.trim_end_matches(".env").to_owned()
        })
        .collect();
    instances.sort();
    for name in [
        "panda-driver",
        "qp-resolver",
        "final-phase",
        "supervisor",
        "watchdog",
    ] {
        assert!(instances.iter().any(|i| i == name), "{name}: {instances:?}");
    }
    let supervisor = std::fs::read_to_string(root.join("etc/env/supervisor.env")).unwrap();
    assert!(supervisor.contains("--no-spawn"), "{supervisor}");
    // The command line and the logger are installed, and the logger has its unit's arguments.
    for binary in ["motm", "logger", "supervisor", "panda-driver"] {
        assert!(
            root.join("opt/bin").join(binary).exists(),
            "{binary} not installed"
        );
    }
    assert!(instances.iter().any(|i| i == "logger"), "{instances:?}");
    // The deployed stack's prefix is the one `motm status` looks at without flags.
    let prefix = format!(
        "Environment={}={}",
        motm_bus::PREFIX_ENV,
        motm_bus::DEPLOYED_PREFIX
    );
    assert!(template.contains(&prefix), "motm@.service lacks {prefix}");
    // A drop-in that pins a process resets the template's CPUAffinity first (systemd merges
    // repeated assignments).
    for entry in std::fs::read_dir(&units).unwrap() {
        let dir = entry.unwrap().path();
        let Ok(confs) = std::fs::read_dir(&dir) else {
            continue;
        };
        for conf in confs {
            let text = std::fs::read_to_string(conf.unwrap().path()).unwrap();
            let affinity: Vec<&str> = text
                .lines()
                .filter(|l| l.starts_with("CPUAffinity="))
                .collect();
            if !affinity.is_empty() {
                assert_eq!(
                    affinity[0],
                    "CPUAffinity=",
                    "{}: {affinity:?}",
                    dir.display()
                );
                assert_eq!(affinity.len(), 2, "{}: {affinity:?}", dir.display());
            }
        }
    }
    for instance in &instances {
        let (ok, output) = verify(&units, &format!("motm@{instance}.service"));
        assert!(ok && output.trim().is_empty(), "motm@{instance}: {output}");
    }
    let (ok, output) = verify(&units, "motm.target");
    assert!(ok && output.trim().is_empty(), "motm.target: {output}");

    // The check is not vacuous: a misspelt key in a drop-in is reported.
    let dropin = units.join("motm@qp-resolver.service.d/realtime.conf");
    let text = std::fs::read_to_string(&dropin).unwrap();
    std::fs::write(&dropin, text.replace("WatchdogSec=", "WatchdogSecs=")).unwrap();
    let (_, output) = verify(&units, "motm@qp-resolver.service");
    assert!(output.contains("WatchdogSecs"), "{output}");
    let _ = std::fs::remove_dir_all(&root);
}
