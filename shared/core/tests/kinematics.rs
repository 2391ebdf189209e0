//! Kinematics of the shipped robot models: the Frankie reference values, the world Jacobian, the
//! Hessian and the manipulability gradient against central finite differences, and the errors a
//! broken model gives.

mod common;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use motm_core::{
    BasePose, ModelError, ROBOT_NAMES, Robot, hessian, manipulability, manipulability_gradient,
};
use nalgebra::{Isometry3, Matrix6xX, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use common::{config_dir, load, random_arm_q, random_position};

/// Random configurations checked per robot.
const CONFIGURATIONS: usize = 25;
/// Central-difference step, rad or m.
const STEP: f64 = 1e-6;
/// Largest accepted difference between an analytic derivative and its central difference.
const FD_TOLERANCE: f64 = 1e-6;

/// A random world pose of the chain root and a random full joint vector (base joints included).
fn random_configuration(rng: &mut ChaCha8Rng, robot: &Robot) -> (Isometry3<f64>, Vec<f64>) {
    let base = BasePose::new(
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0),
        rng.random_range(-PI..PI),
    );
    let q = robot
        .chain
        .joints
        .iter()
        .map(|j| random_position(rng, j.kind, &j.limits))
        .collect();
    (base.isometry(), q)
}

/// `q` with joint `j` moved by `delta`.
fn nudged(q: &[f64], j: usize, delta: f64) -> Vec<f64> {
    let mut q = q.to_vec();
    q[j] += delta;
    q
}

/// Central-difference Jacobian of the tool pose: linear rows from the position, angular rows from
/// the rotation `R(q+h) R(q−h)ᵀ` (world frame).
fn finite_difference_jacobian(robot: &Robot, root: &Isometry3<f64>, q: &[f64]) -> Matrix6xX<f64> {
    let mut jacobian = Matrix6xX::zeros(q.len());
    for j in 0..q.len() {
        let plus = robot.chain.tool_pose(root, &nudged(q, j, STEP));
        let minus = robot.chain.tool_pose(root, &nudged(q, j, -STEP));
        let linear = (plus.translation.vector - minus.translation.vector) / (2.0 * STEP);
        let angular = (plus.rotation * minus.rotation.inverse()).scaled_axis() / (2.0 * STEP);
        jacobian.fixed_view_mut::<3, 1>(0, j).copy_from(&linear);
        jacobian.fixed_view_mut::<3, 1>(3, j).copy_from(&angular);
    }
    jacobian
}

fn assert_close(what: &str, analytic: &Matrix6xX<f64>, numeric: &Matrix6xX<f64>) {
    let error = (analytic - numeric).abs().max();
    assert!(
        error < FD_TOLERANCE,
        "{what}: largest difference {error:e}\nanalytic {analytic:.6}\nnumeric {numeric:.6}"
    );
}

#[test]
fn frankie_ready_pose_matches_the_reference() {
    let robot = load("frankie");
    let qr = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, PI / 4.0];
    let fk = robot.forward(&BasePose::new(0.0, 0.0, 0.0), &qr);
    let p = fk.tool_pose.translation.vector;
    assert!(
        (p - Vector3::new(0.634, 0.0, 0.7926)).norm() < 1e-3,
        "tool at {p:?}"
    );
    let m = manipulability(&Robot::arm_jacobian(&fk.jacobian));
    assert!((m - 0.0838).abs() < 1e-3, "manipulability {m}");
    assert!((robot.manipulability(&qr) - m).abs() < 1e-12);
}

#[test]
fn frankie_reference_moves_with_the_base() {
    let robot = load("frankie");
    let qr = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, PI / 4.0];
    let p = robot
        .tool_pose(&BasePose::new(1.0, 2.0, PI / 2.0), &qr)
        .translation
        .vector;
    assert!(
        (p - Vector3::new(1.0, 2.634, 0.7926)).norm() < 1e-3,
        "tool at {p:?}"
    );
}

#[test]
fn jacobian_matches_finite_differences_for_every_robot() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for name in ROBOT_NAMES {
        let robot = load(name);
        for trial in 0..CONFIGURATIONS {
            let (root, q) = random_configuration(&mut rng, &robot);
            let fk = robot.chain.forward(&root, &q);
            let pose = robot.chain.tool_pose(&root, &q);
            assert!((fk.tool_pose.translation.vector - pose.translation.vector).norm() < 1e-12);
            assert!(fk.tool_pose.rotation.angle_to(&pose.rotation) < 1e-12);
            let numeric = finite_difference_jacobian(&robot, &root, &q);
            assert_close(
                &format!("{name} Jacobian, configuration {trial} {q:?}"),
                &fk.jacobian,
                &numeric,
            );
        }
    }
}

#[test]
fn base_columns_follow_the_algorithms_formulas() {
    // docs/algorithms.md §1: with the virtual joints at zero, col ω = [−(p.y − b.y), p.x − b.x, 0, 0, 0, 1]
    // and col v = [cos θ, sin θ, 0, 0, 0, 0].
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for name in ROBOT_NAMES {
        let robot = load(name);
        let base = BasePose::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            0.7,
        );
        let fk = robot.forward(&base, &random_arm_q(&mut rng, &robot));
        let p = fk.tool_pose.translation.vector;
        let expected = Matrix6xX::from_column_slice(&[
            -(p.y - base.y),
            p.x - base.x,
            0.0,
            0.0,
            0.0,
            1.0,
            base.yaw.cos(),
            base.yaw.sin(),
            0.0,
            0.0,
            0.0,
            0.0,
        ]);
        let actual = fk.jacobian.columns(0, 2).into_owned();
        assert!((actual - expected).abs().max() < 1e-12, "{name}");
    }
}

#[test]
fn hessian_matches_finite_differences_of_the_jacobian() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    for name in ROBOT_NAMES {
        let robot = load(name);
        for trial in 0..CONFIGURATIONS {
            let (root, q) = random_configuration(&mut rng, &robot);
            let slices = hessian(&robot.chain.forward(&root, &q).jacobian);
            assert_eq!(slices.len(), q.len());
            for (j, slice) in slices.iter().enumerate() {
                let plus = robot.chain.forward(&root, &nudged(&q, j, STEP)).jacobian;
                let minus = robot.chain.forward(&root, &nudged(&q, j, -STEP)).jacobian;
                let numeric = (plus - minus) / (2.0 * STEP);
                assert_close(
                    &format!("{name} Hessian slice {j}, configuration {trial} {q:?}"),
                    slice,
                    &numeric,
                );
            }
        }
    }
}

#[test]
fn manipulability_gradient_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let arm_manipulability = |robot: &Robot, base: &BasePose, arm_q: &[f64]| {
        manipulability(&Robot::arm_jacobian(&robot.forward(base, arm_q).jacobian))
    };
    for name in ROBOT_NAMES {
        let robot = load(name);
        let mut nonzero = 0;
        for trial in 0..CONFIGURATIONS {
            let base = BasePose::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(-PI..PI),
            );
            let q = random_arm_q(&mut rng, &robot);
            let arm_jacobian = Robot::arm_jacobian(&robot.forward(&base, &q).jacobian);
            let (m, gradient) = manipulability_gradient(&arm_jacobian);
            assert!((m - manipulability(&arm_jacobian)).abs() < 1e-12);
            assert_eq!(gradient.len(), robot.arm_dof());
            if m > 1e-3 {
                nonzero += 1;
            }
            for j in 0..q.len() {
                let numeric = (arm_manipulability(&robot, &base, &nudged(&q, j, STEP))
                    - arm_manipulability(&robot, &base, &nudged(&q, j, -STEP)))
                    / (2.0 * STEP);
                assert!(
                    (gradient[j] - numeric).abs() < FD_TOLERANCE,
                    "{name} configuration {trial} {q:?}: ∂m/∂q{j} = {} but finite difference {numeric}",
                    gradient[j]
                );
            }
        }
        assert!(
            nonzero >= CONFIGURATIONS / 2,
            "{name}: too few configurations away from a singularity to test the gradient"
        );
    }
}

#[test]
fn ready_poses_hold_the_tool_ahead_pointing_down_with_good_manipulability() {
    for name in ROBOT_NAMES {
        let robot = load(name);
        let ready = robot.config.ready_pose.clone();
        let fk = robot.forward(&BasePose::default(), &ready);
        let p = fk.tool_pose.translation.vector;
        let m = manipulability(&Robot::arm_jacobian(&fk.jacobian));
        assert!(p.x > 0.3 && p.y.abs() < 0.05, "{name}: ready tool at {p:?}");
        assert!(
            (0.3..1.0).contains(&p.z),
            "{name}: ready tool height {}",
            p.z
        );
        assert!(
            m > robot.config.manipulability_threshold,
            "{name}: ready-pose manipulability {m}"
        );
        // Within 0.15 rad of straight down (Frankie's qr from the paper tilts 0.1 rad).
        let approach = fk.tool_pose.rotation * Vector3::z();
        assert!(
            approach.angle(&-Vector3::z()) < 0.15,
            "{name}: ready tool approach axis {approach:?} does not point down"
        );
    }
}

/// Copies the shipped robot configs into a fresh folder, with `edit` applied to `file`.
fn broken_config(test: &str, file: &str, edit: impl Fn(&str) -> String) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("kinematics-{test}"));
    let robots = dir.join("robots");
    std::fs::create_dir_all(&robots).unwrap();
    for entry in std::fs::read_dir(config_dir().join("robots")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap();
        let mut text = std::fs::read_to_string(&path).unwrap();
        if name == file {
            let edited = edit(&text);
            assert_ne!(edited, text, "the edit must change {file}");
            text = edited;
        }
        std::fs::write(robots.join(name), text).unwrap();
    }
    dir
}

fn load_error(dir: &Path, name: &str) -> String {
    let err: ModelError = Robot::load(dir, name).expect_err("the model must not load");
    err.to_string()
}

#[test]
fn urdf_with_a_missing_joint_names_the_file_and_link() {
    let dir = broken_config("missing-joint", "frankie.urdf", |text| {
        let start = text.find("<joint name=\"panda_joint4\"").unwrap();
        let end = start + text[start..].find("</joint>").unwrap() + "</joint>".len();
        format!("{}{}", &text[..start], &text[end..])
    });
    let msg = load_error(&dir, "frankie");
    let file = dir.join("robots").join("frankie.urdf");
    assert!(msg.starts_with(&format!("{}: ", file.display())), "{msg}");
    assert!(msg.contains("<link name=\"panda_link4\">"), "{msg}");
    assert!(msg.contains("missing joint"), "{msg}");
}

#[test]
fn urdf_with_a_bad_number_names_the_file_joint_and_attribute() {
    let dir = broken_config("bad-number", "fetch.urdf", |text| {
        text.replace("lower=\"-2.251\"", "lower=\"-2.2.51\"")
    });
    let msg = load_error(&dir, "fetch");
    let file = dir.join("robots").join("fetch.urdf");
    assert!(msg.starts_with(&format!("{}: ", file.display())), "{msg}");
    assert!(
        msg.contains("joint 'elbow_flex_joint' <limit lower>"),
        "{msg}"
    );
    assert!(msg.contains("'-2.2.51' is not a number"), "{msg}");
}

#[test]
fn unknown_robot_names_the_missing_file_and_the_known_robots() {
    let msg = load_error(&config_dir(), "turtlebot");
    let file = config_dir().join("robots").join("turtlebot.toml");
    assert!(
        msg.starts_with(&format!("{}: unknown robot 'turtlebot'", file.display())),
        "{msg}"
    );
    for name in ROBOT_NAMES {
        assert!(msg.contains(name), "{msg}");
    }
}

#[test]
fn robot_toml_with_an_unknown_key_names_the_file_and_key() {
    let dir = broken_config("unknown-key", "husky_ur5.toml", |text| {
        text.replace("footprint =", "foot_print =")
    });
    let msg = load_error(&dir, "husky_ur5");
    let file = dir.join("robots").join("husky_ur5.toml");
    assert!(
        msg.starts_with(&format!("{}: line ", file.display())),
        "{msg}"
    );
    assert!(msg.contains("foot_print"), "{msg}");
}

#[test]
fn robot_toml_with_a_negative_range_names_the_file_and_key() {
    let dir = broken_config("negative-range", "fetch.toml", |text| {
        text.replace("manipulation_range = ", "manipulation_range = -")
    });
    let msg = load_error(&dir, "fetch");
    let file = dir.join("robots").join("fetch.toml");
    assert!(
        msg.starts_with(&format!("{}: manipulation_range: ", file.display())),
        "{msg}"
    );
}

#[test]
fn a_held_joint_that_is_not_an_arm_joint_names_the_file_and_key() {
    let dir = broken_config("held-joint", "fetch.toml", |text| {
        text.replace("\"torso_lift_joint\"]", "\"torso_joint\"]")
    });
    let msg = load_error(&dir, "fetch");
    let file = dir.join("robots").join("fetch.toml");
    assert!(
        msg.starts_with(&format!("{}: held_joints: ", file.display())),
        "{msg}"
    );
    assert!(msg.contains("'torso_joint' is not an arm joint"), "{msg}");
}
