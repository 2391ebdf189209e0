//! Feed-forward of the base's velocity error into the tool twist.
//!
//! The redundancy-resolution QP turns a world tool twist ν into base and arm velocities on the
//! assumption that the base moves as commanded. A real base does not: its drive has a gain error
//! of a few per cent, it lags its command, and it slips. At 0.4 m/s a 10 % gain error is 4 cm/s
//! of tool motion the arm never hears of; against the final-phase servo's k_P = 5 that leaves the
//! tool about 8 mm behind the object for as long as the base drives, which is exactly the margin
//! the grasp needs (ε_g = 1 cm).
//!
//! The fix is a disturbance feed-forward: the base's measured (odometry) velocity minus the
//! velocity it was last commanded is the part of its motion the QP did not plan for, and the tool
//! moves with it through the base columns of the Jacobian. Asking the QP for ν minus that motion
//! makes the arm cancel it, so the tool moves at ν in the odometry frame — the frame the tool
//! pose and the object estimate are both expressed in.
//!
//! Choices (each a [`BaseSlipConfig`] value):
//! - **Reference** is the base velocity the QP resolved on the previous cycle (what was sent to
//!   the driver), not the base controller's target: the QP may have used slack on the base rows.
//! - **Cap** on the correction's linear speed, so a bad odometry sample (a wheel slipping on a
//!   threshold) cannot throw the arm.

use nalgebra::{Matrix6xX, Vector3};
use serde::Deserialize;

use crate::kinematics::BasePose;
use crate::robot::Robot;
use crate::types::{BaseVelocity, Twist};

/// Tunables of the base-velocity-error feed-forward (the `[base_slip]` table).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseSlipConfig {
    /// Whether the correction is applied at all.
    pub enabled: bool,
    /// Largest linear speed of the correction at the tool, m/s (0.15: a 35 % error at the
    /// Frankie's 0.4 m/s, far beyond a healthy drive's; a larger measured error is an odometry
    /// glitch, not motion to follow).
    pub max_linear_correction: f64,
    /// Largest angular speed of the correction, rad/s (0.3).
    pub max_angular_correction: f64,
}

impl Default for BaseSlipConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_linear_correction: 0.15,
            max_angular_correction: 0.3,
        }
    }
}

/// The world twist the tool gets from a base moving at `velocity`, given the full Jacobian of
/// [`Robot::forward`] (base columns ω, v first).
pub fn base_motion_twist(jacobian: &Matrix6xX<f64>, velocity: BaseVelocity) -> Twist {
    jacobian.column(0) * velocity.omega + jacobian.column(1) * velocity.v
}

/// The twist to add to the tool twist asked of the QP so that the arm cancels the base's
/// unplanned motion: minus the tool motion caused by `measured − commanded`, capped per
/// [`BaseSlipConfig`]. Zero when disabled or when any input is not finite.
pub fn slip_correction(
    robot: &Robot,
    base: &BasePose,
    arm_q: &[f64],
    measured: BaseVelocity,
    commanded: BaseVelocity,
    config: &BaseSlipConfig,
) -> Twist {
    let error = BaseVelocity {
        v: measured.v - commanded.v,
        omega: measured.omega - commanded.omega,
    };
    let finite = [error.v, error.omega, base.x, base.y, base.yaw]
        .iter()
        .chain(arm_q)
        .all(|x| x.is_finite());
    if !config.enabled || !finite || arm_q.len() != robot.arm_dof() {
        return Twist::zeros();
    }
    let unplanned = base_motion_twist(&robot.forward(base, arm_q).jacobian, error);
    let linear = cap(
        -unplanned.fixed_rows::<3>(0).into_owned(),
        config.max_linear_correction,
    );
    let angular = cap(
        -unplanned.fixed_rows::<3>(3).into_owned(),
        config.max_angular_correction,
    );
    Twist::new(
        linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
    )
}

/// `v` scaled down to norm `limit` if longer.
fn cap(v: Vector3<f64>, limit: f64) -> Vector3<f64> {
    v.cap_magnitude(limit.max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frankie() -> Robot {
        let config_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&config_dir, "frankie").expect("frankie loads")
    }

    #[test]
    fn base_motion_twist_is_the_rigid_motion_of_the_tool() {
        let robot = frankie();
        let base = BasePose {
            x: 1.0,
            y: -0.5,
            yaw: 0.7,
        };
        let q = robot.config.ready_pose.clone();
        let fk = robot.forward(&base, &q);
        let velocity = BaseVelocity { v: 0.4, omega: 0.3 };
        let twist = base_motion_twist(&fk.jacobian, velocity);
        // Forward motion along the heading plus ω ẑ × (tool − base centre).
        let tool = fk.tool_pose.translation.vector;
        let arm = tool - Vector3::new(base.x, base.y, 0.0);
        let expected = Vector3::new(base.yaw.cos(), base.yaw.sin(), 0.0) * velocity.v
            + Vector3::z().cross(&arm) * velocity.omega;
        assert!(
            (twist.fixed_rows::<3>(0) - expected).norm() < 1e-9,
            "{twist}"
        );
        assert!((twist[5] - velocity.omega).abs() < 1e-12);
    }

    #[test]
    fn correction_cancels_the_unplanned_part_of_the_base_motion() {
        let robot = frankie();
        let base = BasePose::default();
        let q = robot.config.ready_pose.clone();
        let config = BaseSlipConfig::default();
        // The base drives 10 % faster than commanded: the tool is carried 4 cm/s further
        // forward than the QP planned, so the arm must be asked for 4 cm/s backward.
        let commanded = BaseVelocity { v: 0.4, omega: 0.0 };
        let measured = BaseVelocity {
            v: 0.44,
            omega: 0.0,
        };
        let correction = slip_correction(&robot, &base, &q, measured, commanded, &config);
        assert!((correction[0] + 0.04).abs() < 1e-9, "{correction}");
        assert!(correction.rows(1, 5).norm() < 1e-9, "{correction}");

        // The QP asked for ν + correction with the base at `commanded` gives a tool that, with
        // the base really at `measured`, moves at ν.
        let fk = robot.forward(&base, &q);
        let nu = Twist::new(0.0, 0.05, -0.02, 0.0, 0.0, 0.0);
        let actual = nu + correction + base_motion_twist(&fk.jacobian, measured)
            - base_motion_twist(&fk.jacobian, commanded);
        assert!((actual - nu).norm() < 1e-9, "{actual}");

        // A base that does what it is told needs no correction.
        let none = slip_correction(&robot, &base, &q, commanded, commanded, &config);
        assert_eq!(none, Twist::zeros());
    }

    #[test]
    fn correction_is_capped_disabled_or_zero_on_bad_input() {
        let robot = frankie();
        let base = BasePose::default();
        let q = robot.config.ready_pose.clone();
        let config = BaseSlipConfig::default();
        let commanded = BaseVelocity { v: 0.4, omega: 0.0 };
        let glitch = BaseVelocity { v: 2.0, omega: 3.0 };
        let capped = slip_correction(&robot, &base, &q, glitch, commanded, &config);
        assert!(capped.fixed_rows::<3>(0).norm() <= config.max_linear_correction + 1e-12);
        assert!(capped.fixed_rows::<3>(3).norm() <= config.max_angular_correction + 1e-12);
        assert!(capped.fixed_rows::<3>(0).norm() > 0.1, "{capped}");

        let off = BaseSlipConfig {
            enabled: false,
            ..config
        };
        let measured = BaseVelocity {
            v: 0.44,
            omega: 0.0,
        };
        assert_eq!(
            slip_correction(&robot, &base, &q, measured, commanded, &off),
            Twist::zeros()
        );
        let nan = BaseVelocity {
            v: f64::NAN,
            omega: 0.0,
        };
        assert_eq!(
            slip_correction(&robot, &base, &q, nan, commanded, &config),
            Twist::zeros()
        );
        assert_eq!(
            slip_correction(&robot, &base, &q[..3], measured, commanded, &config),
            Twist::zeros()
        );
    }
}
