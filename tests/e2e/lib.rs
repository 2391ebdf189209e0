//! Helpers of the end-to-end tests: build and run the `motm` CLI through Cargo, and check
//! that a run left no process and no shared memory behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Runs `motm <args>` via `cargo run` (so `motm run` builds any missing service binary) with
/// the iceoryx2 prefix `prefix`.
pub fn motm(args: &[&str], prefix: &str) -> Output {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    Command::new(cargo)
        .current_dir(workspace_root())
        .args(["run", "--quiet", "-p", "motm", "--"])
        .args(args)
        .env(motm_bus::PREFIX_ENV, prefix)
        .output()
        .expect("cargo run -p motm")
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
