//! Forward kinematics, the world-frame geometric Jacobian, the kinematic Hessian, Yoshikawa
//! manipulability and its gradient, for any [`Chain`].
//!
//! Jacobian columns are `[v; ω]` (linear velocity of the tool point, then angular velocity), one
//! per movable joint, in chain order. For a mobile manipulator whose chain starts with the two
//! virtual base joints (yaw, forward), the first two columns are the base's ω and v columns.

use nalgebra::{DVector, Isometry3, Matrix6, Matrix6xX, Vector3, Vector6};

use crate::chain::{Chain, JointKind};

/// A planar base pose in the world frame: position in metres, heading in radians.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BasePose {
    /// World x of the base frame origin.
    pub x: f64,
    /// World y of the base frame origin.
    pub y: f64,
    /// Heading about world z.
    pub yaw: f64,
}

impl BasePose {
    /// Creates a pose from x, y and yaw.
    pub fn new(x: f64, y: f64, yaw: f64) -> Self {
        Self { x, y, yaw }
    }

    /// The base frame as a 3-D transform (world from base).
    pub fn isometry(&self) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(self.x, self.y, 0.0), Vector3::z() * self.yaw)
    }
}

/// Tool pose and world-frame Jacobian of a chain at one configuration.
#[derive(Debug, Clone)]
pub struct ForwardKinematics {
    /// World pose of the tool frame.
    pub tool_pose: Isometry3<f64>,
    /// 6×n geometric Jacobian in the world frame, rows `[vx, vy, vz, wx, wy, wz]`.
    pub jacobian: Matrix6xX<f64>,
}

impl Chain {
    /// World pose of the tool at joint positions `q`, with the chain root at `world_from_root`.
    pub fn tool_pose(&self, world_from_root: &Isometry3<f64>, q: &[f64]) -> Isometry3<f64> {
        assert_eq!(q.len(), self.dof(), "joint vector length");
        let mut frame = *world_from_root;
        for (joint, &qi) in self.joints.iter().zip(q) {
            frame = frame * joint.origin * joint.motion(qi);
        }
        frame * self.tool
    }

    /// Tool pose and world-frame geometric Jacobian at joint positions `q`.
    pub fn forward(&self, world_from_root: &Isometry3<f64>, q: &[f64]) -> ForwardKinematics {
        assert_eq!(q.len(), self.dof(), "joint vector length");
        let n = self.dof();
        // First pass: store each joint's world origin in rows 0..3 and axis in rows 3..6.
        let mut jacobian = Matrix6xX::zeros(n);
        let mut frame = *world_from_root;
        for (i, (joint, &qi)) in self.joints.iter().zip(q).enumerate() {
            frame *= joint.origin;
            let axis = frame.rotation * joint.axis.into_inner();
            jacobian
                .fixed_view_mut::<3, 1>(0, i)
                .copy_from(&frame.translation.vector);
            jacobian.fixed_view_mut::<3, 1>(3, i).copy_from(&axis);
            frame *= joint.motion(qi);
        }
        let tool_pose = frame * self.tool;
        let tool_point = tool_pose.translation.vector;
        // Second pass: turn (origin, axis) into the column [v; ω].
        for (i, joint) in self.joints.iter().enumerate() {
            let origin: Vector3<f64> = jacobian.fixed_view::<3, 1>(0, i).into_owned();
            let axis: Vector3<f64> = jacobian.fixed_view::<3, 1>(3, i).into_owned();
            let (linear, angular) = match joint.kind {
                JointKind::Revolute => (axis.cross(&(tool_point - origin)), axis),
                JointKind::Prismatic => (axis, Vector3::zeros()),
            };
            jacobian.fixed_view_mut::<3, 1>(0, i).copy_from(&linear);
            jacobian.fixed_view_mut::<3, 1>(3, i).copy_from(&angular);
        }
        ForwardKinematics {
            tool_pose,
            jacobian,
        }
    }
}

/// Column `i` of the Hessian slice `H_j = ∂J/∂q_j`, derived from the Jacobian alone.
///
/// For `j ≤ i`: `[ω_j × v_i; ω_j × ω_i]`. For `j > i`: `[ω_i × v_j; 0]`. A prismatic joint has
/// `ω = 0`, which makes these formulas hold for it too.
#[inline]
fn hessian_column(jacobian: &Matrix6xX<f64>, j: usize, i: usize) -> Vector6<f64> {
    let lin = |k: usize| Vector3::new(jacobian[(0, k)], jacobian[(1, k)], jacobian[(2, k)]);
    let ang = |k: usize| Vector3::new(jacobian[(3, k)], jacobian[(4, k)], jacobian[(5, k)]);
    if j <= i {
        let w = ang(j);
        let a = w.cross(&lin(i));
        let b = w.cross(&ang(i));
        Vector6::new(a.x, a.y, a.z, b.x, b.y, b.z)
    } else {
        let a = ang(i).cross(&lin(j));
        Vector6::new(a.x, a.y, a.z, 0.0, 0.0, 0.0)
    }
}

/// The kinematic Hessian: `result[j]` is the 6×n matrix `∂J/∂q_j`.
pub fn hessian(jacobian: &Matrix6xX<f64>) -> Vec<Matrix6xX<f64>> {
    let n = jacobian.ncols();
    (0..n)
        .map(|j| Matrix6xX::from_fn(n, |r, i| hessian_column(jacobian, j, i)[r]))
        .collect()
}

/// Yoshikawa manipulability `√det(J Jᵀ)` of a 6×n Jacobian (0 at or near a singularity).
pub fn manipulability(jacobian: &Matrix6xX<f64>) -> f64 {
    let jjt: Matrix6<f64> = jacobian * jacobian.transpose();
    jjt.determinant().max(0.0).sqrt()
}

/// Manipulability and its gradient with respect to the joints of `jacobian`:
/// `∂m/∂q_j = m · tr(J H_jᵀ (J Jᵀ)⁻¹)`.
///
/// Returns a zero gradient when `J Jᵀ` is singular.
pub fn manipulability_gradient(jacobian: &Matrix6xX<f64>) -> (f64, DVector<f64>) {
    let n = jacobian.ncols();
    let jjt: Matrix6<f64> = jacobian * jacobian.transpose();
    let m = jjt.determinant().max(0.0).sqrt();
    let Some(chol) = jjt.cholesky() else {
        return (m, DVector::zeros(n));
    };
    // B = (J Jᵀ)⁻¹ J, so tr(J H_jᵀ (J Jᵀ)⁻¹) = Σ_i B[:, i] · H_j[:, i].
    let b = chol.solve(jacobian);
    let gradient = DVector::from_fn(n, |j, _| {
        let trace: f64 = (0..n)
            .map(|i| b.column(i).dot(&hessian_column(jacobian, j, i)))
            .sum();
        m * trace
    });
    (m, gradient)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_pose_isometry_places_and_turns_the_base() {
        let pose = BasePose::new(1.0, 2.0, std::f64::consts::FRAC_PI_2);
        let p = pose.isometry() * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p.coords - Vector3::new(1.0, 3.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn manipulability_of_a_singular_jacobian_is_zero_with_zero_gradient() {
        let j = Matrix6xX::<f64>::zeros(7);
        let (m, g) = manipulability_gradient(&j);
        assert_eq!(m, 0.0);
        assert!(g.iter().all(|v| *v == 0.0));
    }
}
