//! Reproduces the reference run of robotics-toolbox-python's `holistic_mm_non_holonomic.py`
//! (docs/algorithms.md §2): Frankie at qr, target fkine(qr)·Rz(π) with rotation diag(−1, 1, −1),
//! x − 4.0 and z − 0.25, i.e. (−3.366, 0, 0.5426); the reference arrives (e_t < 0.02) in 252
//! steps at dt = 0.025.

use std::path::Path;

use motm_core::{BasePose, BaseVelocity, HolisticConfig, HolisticController, HolisticInput, Robot};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

const DT: f64 = 0.025;
const REFERENCE_STEPS: usize = 252;
const TOLERANCE_STEPS: usize = 25;

fn frankie() -> Robot {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    Robot::load(&config_dir, "frankie").expect("frankie model")
}

/// Rotate by ω·dt, then move v·dt along the new heading (docs/algorithms.md §1).
fn integrate_base(base: &BasePose, velocity: &BaseVelocity, dt: f64) -> BasePose {
    let yaw = base.yaw + velocity.omega * dt;
    BasePose::new(
        base.x + velocity.v * dt * yaw.cos(),
        base.y + velocity.v * dt * yaw.sin(),
        yaw,
    )
}

/// Runs the holistic controller to the reference target; returns the steps taken to arrive (or
/// `None` after `max_steps`) and the largest joint speed seen relative to the robot limits.
fn run(config: HolisticConfig, max_steps: usize) -> (Option<usize>, f64) {
    let robot = frankie();
    let limits = robot.limits();
    let mut arm_q = robot.config.ready_pose.clone();
    let mut base = BasePose::default();
    let start = robot.tool_pose(&base, &arm_q);
    let target = Isometry3::from_parts(
        Translation3::from(start.translation.vector + Vector3::new(-4.0, 0.0, -0.25)),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
    );
    assert!((target.translation.vector - Vector3::new(-3.366, 0.0, 0.5426)).norm() < 1e-3);
    let mut controller = HolisticController::new(robot, config);
    let mut worst_ratio: f64 = 0.0;
    for step in 1..=max_steps {
        let out = controller.step(&HolisticInput {
            base,
            arm_q: &arm_q,
            target,
        });
        assert!(
            out.status.is_ok(),
            "QP failed at step {step}: {:?}",
            out.status
        );
        if out.arrived {
            assert_eq!(controller.error_count(), 0);
            return (Some(step), worst_ratio);
        }
        worst_ratio = worst_ratio
            .max(out.base.omega.abs() / limits[0].velocity)
            .max(out.base.v.abs() / limits[1].velocity);
        for (k, (q, qd)) in arm_q.iter_mut().zip(&out.arm_qd).enumerate() {
            worst_ratio = worst_ratio.max(qd.abs() / limits[2 + k].velocity);
            *q += qd * DT;
        }
        base = integrate_base(&base, &out.base, DT);
    }
    (None, worst_ratio)
}

#[test]
fn faithful_holistic_run_arrives_like_the_reference() {
    let config = HolisticConfig {
        clamp_to_robot_limits: false,
        ..HolisticConfig::default()
    };
    let (steps, _) = run(config, 2 * REFERENCE_STEPS);
    let steps = steps.expect("arrives");
    eprintln!("faithful holistic run arrived in {steps} steps");
    assert!(
        steps.abs_diff(REFERENCE_STEPS) <= TOLERANCE_STEPS,
        "arrived in {steps} steps, reference {REFERENCE_STEPS} ± {TOLERANCE_STEPS}"
    );
}

#[test]
fn default_holistic_run_arrives_within_robot_limits() {
    let (steps, worst_ratio) = run(HolisticConfig::default(), 4 * REFERENCE_STEPS);
    let steps = steps.expect("arrives");
    eprintln!("default holistic run arrived in {steps} steps, worst speed ratio {worst_ratio:.3}");
    assert!(worst_ratio <= 1.0 + 1e-9, "speed ratio {worst_ratio}");
}

#[test]
fn non_finite_state_gives_a_zero_command_and_counts_an_error() {
    let robot = frankie();
    let arm_dof = robot.arm_dof();
    let mut controller = HolisticController::new(robot, HolisticConfig::default());
    let mut arm_q = vec![0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785];
    arm_q[1] = f64::NAN;
    let out = controller.step(&HolisticInput {
        base: BasePose::default(),
        arm_q: &arm_q,
        target: Isometry3::translation(1.0, 0.0, 0.5),
    });
    assert!(!out.status.is_ok());
    assert_eq!(out.base, BaseVelocity::default());
    assert_eq!(out.arm_qd, vec![0.0; arm_dof]);
    assert!(!out.arrived);
    assert_eq!(controller.error_count(), 1);
}
