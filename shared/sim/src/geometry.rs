//! Oriented boxes and their overlap test: the collision geometry of the simulated world (cubes,
//! gripper fingers and palm, platforms, containers and the robot base).

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

/// A box with a centre, an orientation and half extents along its own axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    /// World position of the box centre, m.
    pub center: Vector3<f64>,
    /// Columns are the box's x, y and z axes in the world frame.
    pub axes: Matrix3<f64>,
    /// Half the box size along each of its axes, m.
    pub half_extents: Vector3<f64>,
}

impl OrientedBox {
    /// A box whose frame is `pose` (centre and orientation), with the given half extents.
    pub fn new(pose: &Isometry3<f64>, half_extents: Vector3<f64>) -> Self {
        Self {
            center: pose.translation.vector,
            axes: pose.rotation.to_rotation_matrix().into_inner(),
            half_extents,
        }
    }

    /// A box in `frame` spanning `[min, max]` along the frame's axes.
    pub fn from_bounds(frame: &Isometry3<f64>, min: Vector3<f64>, max: Vector3<f64>) -> Self {
        let center_local = (min + max) * 0.5;
        let axes = frame.rotation.to_rotation_matrix().into_inner();
        Self {
            center: frame.transform_point(&Point3::from(center_local)).coords,
            axes,
            half_extents: (max - min) * 0.5,
        }
    }

    /// An upright box standing on the floor: footprint centre `(x, y)`, yaw, footprint half sizes
    /// and height.
    pub fn upright(
        x: f64,
        y: f64,
        yaw: f64,
        half_length: f64,
        half_width: f64,
        height: f64,
    ) -> Self {
        let frame = Isometry3::new(Vector3::new(x, y, 0.0), Vector3::z() * yaw);
        Self::from_bounds(
            &frame,
            Vector3::new(-half_length, -half_width, 0.0),
            Vector3::new(half_length, half_width, height),
        )
    }

    /// Whether a world point lies inside the box (boundary included).
    pub fn contains(&self, point: &Vector3<f64>) -> bool {
        let local = self.axes.transpose() * (point - self.center);
        (0..3).all(|i| local[i].abs() <= self.half_extents[i])
    }

    /// Whether two boxes overlap (separating-axis test over the 15 candidate axes).
    pub fn intersects(&self, other: &OrientedBox) -> bool {
        // Rotation of `other` in this box's frame, and the centre offset in this frame.
        let rotation = self.axes.transpose() * other.axes;
        let t = self.axes.transpose() * (other.center - self.center);
        // A small epsilon keeps near-parallel edge axes from producing false separations.
        let abs_rotation = rotation.abs().add_scalar(1e-12);
        let a = &self.half_extents;
        let b = &other.half_extents;
        for i in 0..3 {
            let ra = a[i];
            let rb = b.dot(&abs_rotation.row(i).transpose());
            if t[i].abs() > ra + rb {
                return false;
            }
        }
        for j in 0..3 {
            let ra = a.dot(&abs_rotation.column(j));
            let rb = b[j];
            let distance = t.dot(&rotation.column(j));
            if distance.abs() > ra + rb {
                return false;
            }
        }
        for i in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            for j in 0..3 {
                let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
                let ra = a[i1] * abs_rotation[(i2, j)] + a[i2] * abs_rotation[(i1, j)];
                let rb = b[j1] * abs_rotation[(i, j2)] + b[j2] * abs_rotation[(i, j1)];
                let distance = t[i2] * rotation[(i1, j)] - t[i1] * rotation[(i2, j)];
                if distance.abs() > ra + rb {
                    return false;
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_4;

    fn cube(x: f64, y: f64, z: f64, yaw: f64, half: f64) -> OrientedBox {
        OrientedBox::new(
            &Isometry3::new(Vector3::new(x, y, z), Vector3::z() * yaw),
            Vector3::repeat(half),
        )
    }

    #[test]
    fn separated_and_touching_boxes() {
        let a = cube(0.0, 0.0, 0.0, 0.0, 0.5);
        assert!(a.intersects(&cube(0.9, 0.0, 0.0, 0.0, 0.5)));
        assert!(!a.intersects(&cube(1.1, 0.0, 0.0, 0.0, 0.5)));
        assert!(!a.intersects(&cube(0.0, 0.0, 1.2, 0.3, 0.5)));
    }

    #[test]
    fn rotated_box_reaches_further_along_its_diagonal() {
        let a = cube(0.0, 0.0, 0.0, 0.0, 0.5);
        // A 45°-turned unit cube reaches 0.707 along x: at 1.15 it overlaps, at 1.25 it does not.
        assert!(a.intersects(&cube(1.15, 0.0, 0.0, FRAC_PI_4, 0.5)));
        assert!(!a.intersects(&cube(1.25, 0.0, 0.0, FRAC_PI_4, 0.5)));
    }

    #[test]
    fn crossing_bars_touch_only_when_close() {
        // Two long thin bars crossing in x and y at different heights do not touch.
        let x_bar = OrientedBox::new(&Isometry3::identity(), Vector3::new(1.0, 0.05, 0.05));
        let y_bar = OrientedBox::new(
            &Isometry3::new(Vector3::new(0.0, 0.0, 0.11), Vector3::zeros()),
            Vector3::new(0.05, 1.0, 0.05),
        );
        assert!(!x_bar.intersects(&y_bar));
        let touching = OrientedBox {
            center: Vector3::new(0.0, 0.0, 0.09),
            ..y_bar
        };
        assert!(x_bar.intersects(&touching));
    }

    #[test]
    fn upright_box_contains_its_inside() {
        let b = OrientedBox::upright(2.0, 0.0, 0.0, 0.2, 0.1, 0.4);
        assert!(b.contains(&Vector3::new(2.1, 0.05, 0.3)));
        assert!(!b.contains(&Vector3::new(2.1, 0.15, 0.3)));
        assert!(!b.contains(&Vector3::new(2.1, 0.05, 0.45)));
    }
}
