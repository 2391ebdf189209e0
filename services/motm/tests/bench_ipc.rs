//! `motm bench ipc` runs its echo peers as real processes, reports every case and cleans up.

use std::process::Command;

use serde_json::Value;

#[test]
fn bench_ipc_reports_every_case_with_ordered_statistics() {
    let out = Command::new(env!("CARGO_BIN_EXE_motm"))
        .args(["bench", "ipc", "--samples", "30", "--warmup", "5", "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    // Header, width and height, the frame's publication time, then the pixels.
    let image_bytes = 24 + 8 + 8 + 320 * 240 * 3;
    for (case, bytes) in [
        ("iceoryx2_64B", 64),
        ("uds_64B", 64),
        ("iceoryx2_image", image_bytes),
        ("uds_image", image_bytes),
    ] {
        let c = &report[case];
        assert_eq!(c["samples"], 30, "{case}");
        assert_eq!(c["payload_bytes"], bytes, "{case}");
        let median = c["median_us"].as_f64().unwrap();
        let p99 = c["p99_us"].as_f64().unwrap();
        let max = c["max_us"].as_f64().unwrap();
        assert!(0.0 < median && median <= p99 && p99 <= max, "{case}: {c}");
    }
    assert_eq!(report.as_object().unwrap().len(), 4);
}

#[test]
fn bench_ipc_rejects_zero_samples_with_exit_code_2() {
    let out = Command::new(env!("CARGO_BIN_EXE_motm"))
        .args(["bench", "ipc", "--samples", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--samples"));
}
