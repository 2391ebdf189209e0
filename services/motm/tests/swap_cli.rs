//! `motm swap` end to end without a stack: a process or variant that cannot be swapped is bad
//! input (exit code 2, naming it), and a request nobody answers fails (exit code 1) after the
//! timeout, leaving nothing behind.

use std::process::Command;

use motm_bus::IpcConfig;

fn swap(args: &[&str], prefix: &str) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_motm"))
        .arg("swap")
        .args(args)
        .args(["--prefix", prefix])
        .output()
        .expect("motm runs");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn bad_targets_are_bad_input_and_an_unanswered_request_fails() {
    let prefix = format!("motmt{}_swapcli_", std::process::id());
    let (code, err) = swap(&["reacher", "grasp"], &prefix);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("'reacher'") && err.contains("final-phase"),
        "{err}"
    );
    let (code, err) = swap(&["final-phase", "push"], &prefix);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("unknown variant 'push'"), "{err}");
    let (code, err) = swap(&["final-phase", "grasp", "--timeout", "0"], &prefix);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--timeout"), "{err}");
    // No supervisor on this prefix: no answer within the timeout.
    let (code, err) = swap(
        &["final-phase", "press-button", "--timeout", "0.5"],
        &prefix,
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("no final answer"), "{err}");
    let ipc = IpcConfig { prefix };
    // SAFETY: the motm process has exited; nothing else uses this prefix.
    unsafe { motm_bus::remove_domain(&ipc) }.unwrap();
    assert_eq!(
        motm_bus::shared_memory_entries(&ipc).unwrap(),
        Vec::<std::path::PathBuf>::new()
    );
}
