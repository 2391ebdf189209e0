//! `motm kin` end to end: the built binary, its JSON output and its exit codes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use motm_core::{BasePose, Robot};
use serde_json::Value;

/// The repository's `config/` folder.
fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

fn motm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_motm"))
        .args(args)
        .output()
        .expect("motm runs")
}

/// Runs `motm kin ... --json` on the shipped config and parses its output.
fn kin_json(robot: &str, extra: &[&str]) -> Value {
    let config = config_dir();
    let mut args = vec![
        "--config-dir",
        config.to_str().unwrap(),
        "kin",
        "--robot",
        robot,
        "--json",
    ];
    args.extend_from_slice(extra);
    let out = motm(&args);
    assert!(
        out.status.success(),
        "motm kin --robot {robot} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn numbers(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .expect("an array")
        .iter()
        .map(|v| v.as_f64().expect("a number"))
        .collect()
}

fn matrix(value: &Value) -> Vec<Vec<f64>> {
    value
        .as_array()
        .expect("rows")
        .iter()
        .map(numbers)
        .collect()
}

#[test]
fn frankie_reference_as_json() {
    let out = kin_json(
        "frankie",
        &[
            "--base",
            "0,0,0",
            "--q",
            "0,-0.3,0,-2.2,0,2.0,0.7853981633974483",
        ],
    );
    let p = numbers(&out["position"]);
    let expected = [0.634, 0.0, 0.7926];
    assert_eq!(p.len(), 3);
    for (a, b) in p.iter().zip(expected) {
        assert!((a - b).abs() < 1e-3, "position {p:?}");
    }
    let m = out["manipulability"].as_f64().unwrap();
    assert!((m - 0.0838).abs() < 1e-3, "manipulability {m}");

    let rotation = matrix(&out["rotation"]);
    assert_eq!(rotation.len(), 3);
    for (i, row) in rotation.iter().enumerate() {
        assert_eq!(row.len(), 3);
        for (j, _) in row.iter().enumerate() {
            let dot: f64 = (0..3).map(|k| rotation[i][k] * rotation[j][k]).sum();
            let identity = if i == j { 1.0 } else { 0.0 };
            assert!((dot - identity).abs() < 1e-9, "rotation not orthonormal");
        }
    }
    // Row-major and equal to the library's rotation; at qr the gripper points (nearly) down.
    let robot = Robot::load(&config_dir(), "frankie").unwrap();
    let qr = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, std::f64::consts::FRAC_PI_4];
    let fk = robot.forward(&BasePose::default(), &qr);
    let expected_rotation = fk.tool_pose.rotation.to_rotation_matrix();
    for (i, row) in rotation.iter().enumerate() {
        for (j, value) in row.iter().enumerate() {
            assert!(
                (value - expected_rotation[(i, j)]).abs() < 1e-9,
                "{rotation:?}"
            );
        }
    }
    assert!(rotation[2][2] < -0.99, "{rotation:?}");

    let jacobian = matrix(&out["jacobian"]);
    assert_eq!(jacobian.len(), 6);
    assert!(jacobian.iter().all(|row| row.len() == 9));
    for (i, row) in jacobian.iter().enumerate() {
        for (j, value) in row.iter().enumerate() {
            assert!(
                (value - fk.jacobian[(i, j)]).abs() < 1e-9,
                "jacobian[{i}][{j}]"
            );
        }
    }
    // Base columns (docs/algorithms.md §1): ω column [−p.y, p.x, 0, 0, 0, 1], v column [1, 0, 0, 0, 0, 0].
    let column = |c: usize| -> Vec<f64> { jacobian.iter().map(|row| row[c]).collect() };
    let expected_omega = [-p[1], p[0], 0.0, 0.0, 0.0, 1.0];
    let expected_v = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for (a, b) in column(0).iter().zip(expected_omega) {
        assert!((a - b).abs() < 1e-9, "base ω column {:?}", column(0));
    }
    for (a, b) in column(1).iter().zip(expected_v) {
        assert!((a - b).abs() < 1e-9, "base v column {:?}", column(1));
    }
}

#[test]
fn base_pose_moves_the_tool() {
    let out = kin_json(
        "frankie",
        &[
            "--base",
            "1,2,1.5707963267948966",
            "--q",
            "0,-0.3,0,-2.2,0,2.0,0.7853981633974483",
        ],
    );
    let p = numbers(&out["position"]);
    for (a, b) in p.iter().zip([1.0, 2.634, 0.7926]) {
        assert!((a - b).abs() < 1e-3, "position {p:?}");
    }
}

#[test]
fn fetch_and_husky_ur5_work_at_their_ready_pose() {
    for (robot, arm_dof) in [("fetch", 8), ("husky_ur5", 6)] {
        let out = kin_json(robot, &[]);
        assert_eq!(out["robot"], robot);
        let p = numbers(&out["position"]);
        assert!(p[0] > 0.3, "{robot} tool at {p:?}");
        let jacobian = matrix(&out["jacobian"]);
        assert_eq!(jacobian.len(), 6);
        assert!(
            jacobian.iter().all(|row| row.len() == 2 + arm_dof),
            "{robot}"
        );
        let m = out["manipulability"].as_f64().unwrap();
        assert!(m > 0.01, "{robot} manipulability {m}");
    }
}

#[test]
fn human_readable_output_names_the_robot() {
    let config = config_dir();
    let out = motm(&[
        "--config-dir",
        config.to_str().unwrap(),
        "kin",
        "--robot",
        "husky_ur5",
    ]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("husky_ur5"), "{text}");
    assert!(text.contains("manipulability"), "{text}");
}

#[test]
fn unknown_robot_exits_with_code_2_and_names_the_file() {
    let config = config_dir();
    let out = motm(&[
        "--config-dir",
        config.to_str().unwrap(),
        "kin",
        "--robot",
        "turtlebot",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("turtlebot.toml"), "{stderr}");
    assert!(stderr.contains("unknown robot 'turtlebot'"), "{stderr}");
    assert!(out.stdout.is_empty());
}

#[test]
fn broken_urdf_exits_with_code_2_and_names_the_file_and_element() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("kin-cli-broken-urdf");
    let robots = dir.join("robots");
    std::fs::create_dir_all(&robots).unwrap();
    let shipped = config_dir().join("robots");
    std::fs::copy(
        shipped.join("husky_ur5.toml"),
        robots.join("husky_ur5.toml"),
    )
    .unwrap();
    let urdf = std::fs::read_to_string(shipped.join("husky_ur5.urdf")).unwrap();
    let broken = urdf.replace(
        "<origin xyz=\"-0.425 0 0\" rpy=\"0 0 0\"/>",
        "<origin xyz=\"-0.425 zero 0\" rpy=\"0 0 0\"/>",
    );
    assert_ne!(broken, urdf);
    std::fs::write(robots.join("husky_ur5.urdf"), broken).unwrap();

    let out = motm(&[
        "--config-dir",
        dir.to_str().unwrap(),
        "kin",
        "--robot",
        "husky_ur5",
        "--json",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("husky_ur5.urdf"), "{stderr}");
    assert!(
        stderr.contains("joint 'ur5_elbow' <origin xyz>"),
        "{stderr}"
    );
    assert!(stderr.contains("'zero' is not a number"), "{stderr}");
    assert!(out.stdout.is_empty());
}

#[test]
fn wrong_number_of_joints_exits_with_code_2() {
    let config = config_dir();
    let out = motm(&[
        "--config-dir",
        config.to_str().unwrap(),
        "kin",
        "--robot",
        "fetch",
        "--q",
        "0,0,0",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--q"), "{stderr}");
}
