//! Position-based servoing (PBS) and frame changes for twists and Jacobians.
//!
//! [`p_servo`] follows robotics-toolbox-python's `p_servo`: the pose error is taken in the
//! *current* (tool) frame, `eTep = current⁻¹ · target`, as `[translation of eTep; RPY(eTep)]`
//! with the roll–pitch–yaw angles of `eTep`'s rotation in `zyx` order
//! (`R = Rz(yaw)·Ry(pitch)·Rx(roll)`). The returned twist is `gain · error`, so it is expressed in
//! the **current tool frame**. Use [`twist_tool_to_world`] to express it in the world frame.

use nalgebra::{Isometry3, Matrix6xX, Rotation3, Vector3, Vector6};

use crate::types::Twist;

/// How [`p_servo_with`] measures the rotation part of the pose error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RotationError {
    /// Roll–pitch–yaw angles (`zyx` order) of the relative rotation, as robotics-toolbox's
    /// default `method="rpy"`.
    #[default]
    Rpy,
    /// Angle–axis vector (axis × angle) of the relative rotation, as robotics-toolbox's
    /// `method="angle-axis"`.
    AngleAxis,
}

/// The pose error of `target` seen from `current`, in the current frame:
/// `[translation; rotation]` of `current⁻¹ · target`, rotation measured as `method` says.
pub fn pose_error(
    current: &Isometry3<f64>,
    target: &Isometry3<f64>,
    method: RotationError,
) -> Vector6<f64> {
    let relative = current.inv_mul(target);
    let translation = relative.translation.vector;
    let rotation: Vector3<f64> = match method {
        RotationError::Rpy => {
            let (roll, pitch, yaw) = relative.rotation.euler_angles();
            Vector3::new(roll, pitch, yaw)
        }
        RotationError::AngleAxis => relative.rotation.scaled_axis(),
    };
    Vector6::new(
        translation.x,
        translation.y,
        translation.z,
        rotation.x,
        rotation.y,
        rotation.z,
    )
}

/// Position-based servoing toward `target` with one `gain` for all six axes and RPY rotation
/// error, as robotics-toolbox-python's `p_servo(wTe, wTep, gain, threshold)`.
///
/// Returns the twist **in the current tool frame** and whether the L1 norm of the 6-D error is
/// below `threshold` (arrived).
pub fn p_servo(
    current: &Isometry3<f64>,
    target: &Isometry3<f64>,
    gain: f64,
    threshold: f64,
) -> (Twist, bool) {
    p_servo_with(
        current,
        target,
        &Vector6::repeat(gain),
        threshold,
        RotationError::Rpy,
    )
}

/// Position-based servoing with a per-axis `gains` vector and a choice of rotation error.
///
/// The twist is `gains ∘ error`, expressed in the current tool frame; arrived means
/// `Σ|error| < threshold`.
pub fn p_servo_with(
    current: &Isometry3<f64>,
    target: &Isometry3<f64>,
    gains: &Vector6<f64>,
    threshold: f64,
    method: RotationError,
) -> (Twist, bool) {
    let error = pose_error(current, target, method);
    let arrived = error.abs().sum() < threshold;
    (gains.component_mul(&error), arrived)
}

/// Rotates both halves of a twist `[v; ω]` by `rotation`.
fn rotate_twist(rotation: &Rotation3<f64>, twist: &Twist) -> Twist {
    let v = rotation * twist.fixed_rows::<3>(0);
    let w = rotation * twist.fixed_rows::<3>(3);
    Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z)
}

/// Expresses a tool-frame twist (about the tool point) in the world frame (same point).
pub fn twist_tool_to_world(tool_pose: &Isometry3<f64>, twist: &Twist) -> Twist {
    rotate_twist(&tool_pose.rotation.to_rotation_matrix(), twist)
}

/// Expresses a world-frame twist of the tool point in the tool frame.
pub fn twist_world_to_tool(tool_pose: &Isometry3<f64>, twist: &Twist) -> Twist {
    rotate_twist(&tool_pose.rotation.inverse().to_rotation_matrix(), twist)
}

/// Re-expresses a world-frame Jacobian (rows `[v; ω]` of the tool point) in the tool frame,
/// robotics-toolbox's `jacobe`.
pub fn jacobian_world_to_tool(
    tool_pose: &Isometry3<f64>,
    jacobian: &Matrix6xX<f64>,
) -> Matrix6xX<f64> {
    let r = tool_pose.rotation.inverse().to_rotation_matrix();
    let mut out = jacobian.clone();
    for mut column in out.column_iter_mut() {
        let rotated = rotate_twist(&r, &column.clone_owned());
        column.copy_from(&rotated);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn pose(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        )
    }

    #[test]
    fn error_is_expressed_in_the_current_frame() {
        // Current frame yawed by 90°: a world +x offset is −y in the current frame.
        let current = pose(0.0, 0.0, 0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let target = pose(1.0, 0.0, 0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2 + 0.2);
        let (twist, arrived) = p_servo(&current, &target, 2.0, 0.1);
        assert!(!arrived);
        assert!((twist[0] - 0.0).abs() < 1e-12);
        assert!((twist[1] + 2.0).abs() < 1e-12);
        assert!((twist[5] - 0.4).abs() < 1e-12);
        // In the world frame the translation part points along +x.
        let world = twist_tool_to_world(&current, &twist);
        assert!((world[0] - 2.0).abs() < 1e-12 && world[1].abs() < 1e-12);
        let back = twist_world_to_tool(&current, &world);
        assert!((back - twist).norm() < 1e-12);
    }

    #[test]
    fn rpy_error_matches_small_rotation_and_arrival_threshold() {
        let current = pose(0.3, -0.2, 0.5, 0.1, -0.2, 0.3);
        let target = current * pose(0.001, 0.002, 0.0, 0.003, -0.002, 0.001);
        let (twist, arrived) = p_servo(&current, &target, 1.0, 0.01);
        assert!(arrived, "L1 error 0.009 < 0.01");
        let expected = Vector6::new(0.001, 0.002, 0.0, 0.003, -0.002, 0.001);
        assert!((twist - expected).norm() < 1e-8);
        let (_, arrived) = p_servo(&current, &target, 1.0, 0.008);
        assert!(!arrived);
    }

    #[test]
    fn angle_axis_error_is_the_scaled_axis() {
        let current = Isometry3::identity();
        let target = pose(0.0, 0.0, 0.0, 0.0, 0.0, 0.5);
        let e = pose_error(&current, &target, RotationError::AngleAxis);
        assert!((e[5] - 0.5).abs() < 1e-12 && e[3].abs() < 1e-12);
    }

    #[test]
    fn tool_frame_jacobian_maps_joint_rates_to_tool_frame_twists() {
        let tool = pose(0.1, 0.2, 0.3, 0.4, -0.5, 0.6);
        let j = Matrix6xX::from_fn(3, |r, c| ((r * 3 + c) as f64).sin());
        let qd = nalgebra::DVector::from_vec(vec![0.3, -0.7, 1.1]);
        let world: Twist = (&j * &qd).fixed_rows::<6>(0).into_owned();
        let tool_j = jacobian_world_to_tool(&tool, &j);
        let in_tool: Twist = (&tool_j * &qd).fixed_rows::<6>(0).into_owned();
        assert!((in_tool - twist_world_to_tool(&tool, &world)).norm() < 1e-12);
    }
}
