//! Quintic polynomial trajectories: minimum-jerk-shaped motion between two states given by
//! position, velocity and acceleration, per axis (Corke, *Robotics, Vision and Control*).
//!
//! [`Quintic`] is one scalar axis; [`Quintic3`] is three independent axes sharing one duration,
//! used for the tool position and for the tool's rotation vector.

use nalgebra::Vector3;

/// Position, velocity and acceleration of one axis at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AxisState {
    /// Position (m or rad).
    pub position: f64,
    /// Rate of change of the position.
    pub velocity: f64,
    /// Rate of change of the velocity.
    pub acceleration: f64,
}

/// Position, velocity and acceleration of a 3-D point (or rotation vector) at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointState {
    /// Position.
    pub position: Vector3<f64>,
    /// Velocity.
    pub velocity: Vector3<f64>,
    /// Acceleration.
    pub acceleration: Vector3<f64>,
}

impl PointState {
    /// A state at `position` with zero velocity and acceleration.
    pub fn at_rest(position: Vector3<f64>) -> Self {
        Self {
            position,
            velocity: Vector3::zeros(),
            acceleration: Vector3::zeros(),
        }
    }

    /// The state of axis `i` (0 = x, 1 = y, 2 = z).
    pub fn axis(&self, i: usize) -> AxisState {
        AxisState {
            position: self.position[i],
            velocity: self.velocity[i],
            acceleration: self.acceleration[i],
        }
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.position.iter().all(|v| v.is_finite())
            && self.velocity.iter().all(|v| v.is_finite())
            && self.acceleration.iter().all(|v| v.is_finite())
    }
}

/// A scalar quintic `p(t) = Σ c_k t^k`, `k = 0..5`, on `t ∈ [0, duration]`.
///
/// Outside that interval it is extended smoothly in velocity: before 0 it holds the start state
/// (time is clamped to 0), after `duration` it continues from the end position at the end
/// velocity with zero acceleration. That way a trajectory that arrives with a non-zero velocity
/// (to match a moving object) keeps matching it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quintic {
    coefficients: [f64; 6],
    duration: f64,
}

impl Quintic {
    /// The quintic from `start` at t = 0 to `end` at t = `duration`.
    ///
    /// Returns `None` when `duration` is not a positive finite number or a boundary value is not
    /// finite.
    pub fn new(start: AxisState, end: AxisState, duration: f64) -> Option<Self> {
        let values = [
            start.position,
            start.velocity,
            start.acceleration,
            end.position,
            end.velocity,
            end.acceleration,
        ];
        if !(duration.is_finite() && duration > 0.0) || values.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let t = duration;
        let (t2, t3) = (t * t, t * t * t);
        let (p0, v0, a0) = (start.position, start.velocity, start.acceleration);
        let (p1, v1, a1) = (end.position, end.velocity, end.acceleration);
        let dp = p1 - p0;
        let c3 = (20.0 * dp - (8.0 * v1 + 12.0 * v0) * t - (3.0 * a0 - a1) * t2) / (2.0 * t3);
        let c4 = (-30.0 * dp + (14.0 * v1 + 16.0 * v0) * t + (3.0 * a0 - 2.0 * a1) * t2)
            / (2.0 * t3 * t);
        let c5 = (12.0 * dp - 6.0 * (v1 + v0) * t - (a0 - a1) * t2) / (2.0 * t3 * t2);
        Some(Self {
            coefficients: [p0, v0, 0.5 * a0, c3, c4, c5],
            duration,
        })
    }

    /// The duration given at construction, s.
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// Position, velocity and acceleration at time `t` (see the type's note on times outside
    /// `[0, duration]`).
    pub fn evaluate(&self, t: f64) -> AxisState {
        if t > self.duration {
            let end = self.evaluate_polynomial(self.duration);
            return AxisState {
                position: end.position + end.velocity * (t - self.duration),
                velocity: end.velocity,
                acceleration: 0.0,
            };
        }
        self.evaluate_polynomial(t.max(0.0))
    }

    fn evaluate_polynomial(&self, t: f64) -> AxisState {
        let c = &self.coefficients;
        let position = c[0] + t * (c[1] + t * (c[2] + t * (c[3] + t * (c[4] + t * c[5]))));
        let velocity =
            c[1] + t * (2.0 * c[2] + t * (3.0 * c[3] + t * (4.0 * c[4] + t * 5.0 * c[5])));
        let acceleration = 2.0 * c[2] + t * (6.0 * c[3] + t * (12.0 * c[4] + t * 20.0 * c[5]));
        AxisState {
            position,
            velocity,
            acceleration,
        }
    }
}

/// Three independent [`Quintic`] axes with one shared duration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quintic3 {
    axes: [Quintic; 3],
}

impl Quintic3 {
    /// The trajectory from `start` at t = 0 to `end` at t = `duration`; `None` under the same
    /// conditions as [`Quintic::new`].
    pub fn new(start: &PointState, end: &PointState, duration: f64) -> Option<Self> {
        let axis = |i: usize| Quintic::new(start.axis(i), end.axis(i), duration);
        Some(Self {
            axes: [axis(0)?, axis(1)?, axis(2)?],
        })
    }

    /// The shared duration, s.
    pub fn duration(&self) -> f64 {
        self.axes[0].duration()
    }

    /// The state at time `t`.
    pub fn evaluate(&self, t: f64) -> PointState {
        let [x, y, z] = self.axes.map(|axis| axis.evaluate(t));
        PointState {
            position: Vector3::new(x.position, y.position, z.position),
            velocity: Vector3::new(x.velocity, y.velocity, z.velocity),
            acceleration: Vector3::new(x.acceleration, y.acceleration, z.acceleration),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(position: f64, velocity: f64, acceleration: f64) -> AxisState {
        AxisState {
            position,
            velocity,
            acceleration,
        }
    }

    fn assert_state_near(actual: AxisState, expected: AxisState, tolerance: f64) {
        assert!(
            (actual.position - expected.position).abs() < tolerance
                && (actual.velocity - expected.velocity).abs() < tolerance
                && (actual.acceleration - expected.acceleration).abs() < tolerance,
            "{actual:?} != {expected:?}"
        );
    }

    #[test]
    fn boundary_conditions_are_met_at_both_ends() {
        let cases = [
            (state(0.0, 0.0, 0.0), state(1.0, 0.0, 0.0), 2.0),
            (state(-0.3, 0.4, -1.2), state(0.7, -0.03, 0.5), 0.8),
            (state(5.0, -2.0, 3.0), state(-1.0, 1.5, -4.0), 3.7),
            (state(0.1, 0.2, 0.3), state(0.1, 0.2, 0.3), 0.05),
        ];
        for (start, end, duration) in cases {
            let q = Quintic::new(start, end, duration).expect("valid quintic");
            assert_state_near(q.evaluate(0.0), start, 1e-9);
            assert_state_near(q.evaluate(duration), end, 1e-9);
        }
    }

    #[test]
    fn velocity_and_acceleration_are_derivatives_of_position() {
        let q = Quintic::new(state(-0.3, 0.4, -1.2), state(0.7, -0.03, 0.5), 0.8).unwrap();
        let h = 1e-6;
        for i in 1..8 {
            let t = 0.1 * i as f64;
            let (before, now, after) = (q.evaluate(t - h), q.evaluate(t), q.evaluate(t + h));
            assert!(((after.position - before.position) / (2.0 * h) - now.velocity).abs() < 1e-6);
            assert!(
                ((after.velocity - before.velocity) / (2.0 * h) - now.acceleration).abs() < 1e-5
            );
        }
    }

    #[test]
    fn rest_to_rest_is_the_minimum_jerk_profile() {
        // From rest to rest the quintic is 10s³ − 15s⁴ + 6s⁵ with s = t/T: peak speed 1.875·Δ/T
        // at the midpoint.
        let q = Quintic::new(state(0.0, 0.0, 0.0), state(2.0, 0.0, 0.0), 4.0).unwrap();
        let mid = q.evaluate(2.0);
        assert!((mid.position - 1.0).abs() < 1e-12);
        assert!((mid.velocity - 1.875 * 2.0 / 4.0).abs() < 1e-12);
        assert!(mid.acceleration.abs() < 1e-12);
    }

    #[test]
    fn beyond_the_end_it_continues_at_the_end_velocity() {
        let q = Quintic::new(state(0.0, 0.0, 0.0), state(1.0, 0.03, 0.0), 1.0).unwrap();
        let later = q.evaluate(3.0);
        assert!((later.position - 1.06).abs() < 1e-12);
        assert!((later.velocity - 0.03).abs() < 1e-12);
        assert_eq!(later.acceleration, 0.0);
        assert_state_near(q.evaluate(-1.0), state(0.0, 0.0, 0.0), 1e-15);
    }

    #[test]
    fn degenerate_durations_and_values_are_refused() {
        let zero = AxisState::default();
        assert!(Quintic::new(zero, zero, 0.0).is_none());
        assert!(Quintic::new(zero, zero, -1.0).is_none());
        assert!(Quintic::new(zero, zero, f64::NAN).is_none());
        assert!(Quintic::new(state(f64::INFINITY, 0.0, 0.0), zero, 1.0).is_none());
    }

    #[test]
    fn three_axes_meet_their_boundary_conditions() {
        let start = PointState {
            position: Vector3::new(0.6, 0.0, 0.8),
            velocity: Vector3::new(0.1, -0.2, 0.05),
            acceleration: Vector3::new(0.0, 0.3, -0.1),
        };
        let end = PointState {
            position: Vector3::new(1.2, -0.6, 0.5),
            velocity: Vector3::new(0.03, 0.0, 0.0),
            acceleration: Vector3::zeros(),
        };
        let q = Quintic3::new(&start, &end, 2.5).unwrap();
        for (t, expected) in [(0.0, start), (2.5, end)] {
            let s = q.evaluate(t);
            assert!((s.position - expected.position).norm() < 1e-9);
            assert!((s.velocity - expected.velocity).norm() < 1e-9);
            assert!((s.acceleration - expected.acceleration).norm() < 1e-9);
        }
    }
}
