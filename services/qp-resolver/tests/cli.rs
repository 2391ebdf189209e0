//! Bad command-line input: a clear error naming the flag or file, and exit code 2.

use std::path::Path;
use std::process::Command;

fn run(args: &[&str]) -> (Option<i32>, String) {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let out = Command::new(env!("CARGO_BIN_EXE_qp-resolver"))
        .arg("--config-dir")
        .arg(&config_dir)
        .args(args)
        // Never reaches the bus, but keep it away from any live stack all the same.
        .env(
            motm_bus::PREFIX_ENV,
            format!("motmt{}_cli_", std::process::id()),
        )
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn bad_flags_and_files_exit_with_code_2_and_say_what_is_wrong() {
    let (code, err) = run(&["--rate", "0"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("--rate"), "{err}");
    let (code, err) = run(&["--max-twist-age=-1"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("--max-twist-age"), "{err}");
    let (code, err) = run(&["--robot", "no-such-robot"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("no-such-robot"), "{err}");
    let (code, err) = run(&["--scenario", "/nonexistent/scenario.toml"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("/nonexistent/scenario.toml"), "{err}");
    let (code, _) = run(&["--no-such-flag"]);
    assert_eq!(code, Some(2));
}
