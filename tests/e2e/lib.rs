//! Helpers of the end-to-end tests: build and run the `motm` CLI through Cargo, and check
//! that a run left no process and no shared memory behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The packages of the stack's binaries: `motm run` only builds missing ones, so the tests
/// build them all first to never run a stale binary.
pub const STACK_PACKAGES: [&str; 15] = [
    "motm",
    "motm-supervisor",
    "motm-sim-world",
    "motm-panda-driver",
    "motm-ld60-driver",
    "motm-perception",
    "motm-base-planner",
    "motm-reacher",
    "motm-final-phase",
    "motm-qp-resolver",
    "motm-watchdog",
    "motm-logger",
    "motm-fake-panda",
    "motm-fake-ld60",
    "motm-zenoh",
];

/// Every process of a Frankie run (the names of their heartbeats): the graph's processes, in
/// start order, and the supervisor.
pub fn stack_processes() -> Vec<&'static str> {
    motm_graph::processes()
        .map(|t| t.name)
        .chain(["supervisor"])
        .collect()
}

/// Builds [`STACK_PACKAGES`] once per test process.
fn build_stack() {
    static BUILD: std::sync::Once = std::sync::Once::new();
    BUILD.call_once(|| {
        let mut command = Command::new(cargo());
        command
            .current_dir(workspace_root())
            .args(["build", "--quiet"]);
        for package in STACK_PACKAGES {
            command.args(["-p", package]);
        }
        let status = command.status().expect("cargo build");
        assert!(status.success(), "cargo build of the stack failed");
    });
}

/// The Cargo that runs the tests.
fn cargo() -> String {
    std::env::var("CARGO").unwrap_or_else(|_| "cargo".into())
}

/// The command `motm <args>` via `cargo run` with the iceoryx2 prefix `prefix`, after
/// building every binary of the stack.
pub fn motm_command(args: &[&str], prefix: &str) -> Command {
    build_stack();
    let mut command = Command::new(cargo());
    command
        .current_dir(workspace_root())
        .args(["run", "--quiet", "-p", "motm", "--"])
        .args(args)
        .env(motm_bus::PREFIX_ENV, prefix);
    command
}

/// Runs `motm <args>` (see [`motm_command`]) and waits for it.
pub fn motm(args: &[&str], prefix: &str) -> Output {
    motm_command(args, prefix)
        .output()
        .expect("cargo run -p motm")
}

/// Runs `motm <args>` with prefix `prefix` (see [`motm_command`]) and parses its one JSON
/// report; returns the report, whether the exit status was success, and stderr.
pub fn motm_json(args: &[&str], prefix: &str) -> (serde_json::Value, bool, String) {
    let out = motm(args, prefix);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("no JSON report ({e}); stdout {stdout}; stderr {stderr}"));
    (report, out.status.success(), stderr)
}

/// Held by each test that runs a stack while it runs, so that two stacks of one test binary
/// never share the machine's few cores (they would measure the load). A test that failed
/// while holding it does not block the others.
pub fn one_stack_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static ONE_STACK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    ONE_STACK
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Checks that a `motm run` with iceoryx2 prefix `prefix` and JSON `report` left nothing
/// behind: every pid of its processes is gone (or a zombie of an unrelated reaper), no process
/// mentions the prefix, and no shared memory of the prefix is left.
pub fn assert_nothing_left(report: &serde_json::Value, prefix: &str) {
    for p in report["processes"].as_array().expect("processes") {
        let pid = p["pid"].as_u64().unwrap();
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
        assert!(
            stat.is_empty() || stat.contains(") Z "),
            "pid {pid} ({}) survived",
            p["name"]
        );
    }
    assert!(processes_mentioning(prefix).is_empty());
    let ipc = motm_bus::IpcConfig {
        prefix: prefix.to_owned(),
    };
    assert_eq!(
        motm_bus::shared_memory_entries(&ipc).unwrap(),
        Vec::<PathBuf>::new()
    );
}

/// Pids of live (non-zombie) processes whose command line mentions `needle`.
pub fn processes_mentioning(needle: &str) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        let stat = std::fs::read_to_string(entry.path().join("stat")).unwrap_or_default();
        if String::from_utf8_lossy(&cmdline).contains(needle) && !stat.contains(") Z ") {
            found.push(pid);
        }
    }
    found
}

/// Starts `motm <args>` (see [`motm_command`]) in the background with stdout and stderr
/// piped; the caller waits for it.
pub fn spawn_motm(args: &[&str], prefix: &str) -> std::process::Child {
    motm_command(args, prefix)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("cargo run -p motm")
}

/// The folder of the stack's binaries, after building them (the target folder of this test).
pub fn stack_bin_dir() -> PathBuf {
    build_stack();
    let exe = std::env::current_exe().expect("test executable");
    // <target>/<profile>/deps/<test>: the binaries are in <target>/<profile>.
    exe.parent()
        .and_then(Path::parent)
        .expect("target profile folder")
        .to_path_buf()
}
