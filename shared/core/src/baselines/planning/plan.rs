//! The planned trajectory: knots of base and gripper states, the event knots, how the solve
//! went, evaluation between knots and a check of the true (non-linearised) constraints.

use std::time::Duration;

use nalgebra::{Vector2, Vector3};

use super::geometry::RobotGeometry;
use crate::kinematics::BasePose;
use crate::types::{BaseVelocity, wrap_angle};

/// Below this speed, m/s, the base heading is not taken from the velocity but held.
pub(crate) const HEADING_SPEED: f64 = 1e-3;

/// How the QP solver finished on the last pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolveStatus {
    /// Solved to full accuracy.
    Solved,
    /// Solved to reduced accuracy (clarabel `AlmostSolved`).
    AlmostSolved,
}

/// A planned base and gripper trajectory, from t = 0 to rest.
#[derive(Debug, Clone)]
pub struct Plan {
    /// Time between knots, s.
    pub knot_spacing: f64,
    /// Time of each knot, s (`knot_times[k] = k · knot_spacing`).
    pub knot_times: Vec<f64>,
    /// Base pose at each knot; the yaw is the direction of the base velocity (held when the
    /// base is at rest).
    pub base: Vec<BasePose>,
    /// World base velocity at each knot, m/s.
    pub base_velocity: Vec<Vector2<f64>>,
    /// World base acceleration over each interval (one fewer than knots), m/s².
    pub base_acceleration: Vec<Vector2<f64>>,
    /// World gripper (tool point) position at each knot, m.
    pub gripper: Vec<Vector3<f64>>,
    /// World gripper velocity at each knot, m/s.
    pub gripper_velocity: Vec<Vector3<f64>>,
    /// World gripper acceleration over each interval, m/s².
    pub gripper_acceleration: Vec<Vector3<f64>>,
    /// Knot at which the gripper reaches the grasp position and starts closing.
    pub grasp_knot: usize,
    /// Last knot of the grasp dwell.
    pub grasp_end_knot: usize,
    /// Knot at which the gripper reaches the drop position and opens.
    pub drop_knot: usize,
    /// Last knot of the drop dwell.
    pub drop_end_knot: usize,
    /// Grasp position, fixed at planning time (the cube as perceived at t = 0), m.
    pub grasp_position: Vector3<f64>,
    /// Drop position (above the container), m.
    pub drop_position: Vector3<f64>,
    /// Solver status of the last pass.
    pub status: SolveStatus,
    /// Number of QPs solved (1 = the QP linearised about the nominal route only).
    pub passes: usize,
    /// Whether the base headings changed by less than the tolerance on the last pass.
    pub converged: bool,
    /// Interior-point iterations, summed over the passes.
    pub iterations: u32,
    /// Wall time of the whole planning (route, QP builds and solves), s.
    pub solve_time: Duration,
}

/// The plan evaluated at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanSample {
    /// Planned base pose.
    pub base: BasePose,
    /// Planned base velocity as forward speed and yaw rate (differential-drive flatness).
    pub base_velocity: BaseVelocity,
    /// Planned gripper position, m.
    pub gripper: Vector3<f64>,
    /// Planned gripper velocity, m/s.
    pub gripper_velocity: Vector3<f64>,
}

/// Worst values of the true constraint quantities over all knots of a plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConstraintReport {
    /// Largest base speed, m/s.
    pub max_base_speed: f64,
    /// Largest base acceleration, m/s².
    pub max_base_acceleration: f64,
    /// Largest base yaw rate between knots (heading difference / knot spacing), rad/s.
    pub max_yaw_rate: f64,
    /// Smallest base forward speed along its own heading, m/s (negative means reversing).
    pub min_forward_speed: f64,
    /// Largest horizontal gripper distance from the arm mount, m.
    pub max_horizontal_reach: f64,
    /// Largest 3-D gripper distance from the shoulder, m.
    pub max_reach: f64,
    /// Smallest distance of the gripper ahead of the mount along the base heading, m.
    pub min_forward_reach: f64,
    /// Smallest base-centre distance to the cube or the container, m.
    pub min_target_clearance: f64,
    /// Largest gripper speed, m/s.
    pub max_gripper_speed: f64,
    /// Largest gripper acceleration, m/s².
    pub max_gripper_acceleration: f64,
    /// Lowest gripper height, m.
    pub min_gripper_height: f64,
    /// Mean squared gripper acceleration over the plan, m²/s⁴ (the objective's main term).
    pub mean_squared_gripper_acceleration: f64,
}

/// Headings from velocities: the velocity direction, held (from `start_yaw`) while the speed is
/// below [`HEADING_SPEED`].
pub(crate) fn headings(velocities: &[Vector2<f64>], start_yaw: f64) -> Vec<f64> {
    let mut yaw = start_yaw;
    velocities
        .iter()
        .map(|v| {
            if v.norm() > HEADING_SPEED {
                yaw = v.y.atan2(v.x);
            }
            yaw
        })
        .collect()
}

impl Plan {
    /// Number of knots.
    pub fn knots(&self) -> usize {
        self.knot_times.len()
    }

    /// Time the gripper arrives at the grasp position and the fingers start closing, s.
    pub fn grasp_time(&self) -> f64 {
        self.knot_times[self.grasp_knot]
    }

    /// Time the fingers are closed and the lift starts, s.
    pub fn grasp_end_time(&self) -> f64 {
        self.knot_times[self.grasp_end_knot]
    }

    /// Time the gripper arrives at the drop position and opens, s.
    pub fn drop_time(&self) -> f64 {
        self.knot_times[self.drop_knot]
    }

    /// Time the drop dwell ends, s.
    pub fn drop_end_time(&self) -> f64 {
        self.knot_times[self.drop_end_knot]
    }

    /// Time at which base and gripper are at rest and the plan ends, s.
    pub fn finish_time(&self) -> f64 {
        self.knot_times[self.knots() - 1]
    }

    /// The plan at time `t` (clamped to [0, finish]): exact piecewise-quadratic evaluation.
    pub fn sample(&self, t: f64) -> PlanSample {
        let last = self.knots() - 1;
        let t = if t.is_finite() {
            t.clamp(0.0, self.finish_time())
        } else {
            0.0
        };
        let k = ((t / self.knot_spacing).floor() as usize).min(last.saturating_sub(1));
        let tau = (t - self.knot_times[k]).clamp(0.0, self.knot_spacing);
        let (base_acc, gripper_acc) = if last == 0 {
            (Vector2::zeros(), Vector3::zeros())
        } else {
            (self.base_acceleration[k], self.gripper_acceleration[k])
        };
        let base_b = &self.base[k];
        let base_position = Vector2::new(base_b.x, base_b.y)
            + self.base_velocity[k] * tau
            + 0.5 * base_acc * tau * tau;
        let base_velocity = self.base_velocity[k] + base_acc * tau;
        let speed = base_velocity.norm();
        let (yaw, omega) = if speed > HEADING_SPEED {
            let cross = base_velocity.x * base_acc.y - base_velocity.y * base_acc.x;
            (
                base_velocity.y.atan2(base_velocity.x),
                cross / (speed * speed),
            )
        } else {
            (base_b.yaw, 0.0)
        };
        PlanSample {
            base: BasePose::new(base_position.x, base_position.y, yaw),
            base_velocity: BaseVelocity { v: speed, omega },
            gripper: self.gripper[k]
                + self.gripper_velocity[k] * tau
                + 0.5 * gripper_acc * tau * tau,
            gripper_velocity: self.gripper_velocity[k] + gripper_acc * tau,
        }
    }

    /// Measures the true constraint quantities at every knot (with the real base heading, not
    /// the linearised one), for checking the plan against its limits.
    pub fn constraint_report(
        &self,
        geometry: &RobotGeometry,
        targets: &[Vector2<f64>],
    ) -> ConstraintReport {
        let max = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::NEG_INFINITY, f64::max);
        let min = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::INFINITY, f64::min);
        let relative = |k: usize| {
            let mount = geometry.mount_position(&self.base[k]);
            (
                self.gripper[k].xy() - mount,
                self.gripper[k].z - geometry.shoulder_height,
            )
        };
        let heading = |k: usize| Vector2::new(self.base[k].yaw.cos(), self.base[k].yaw.sin());
        let n = self.knots();
        let h = self.knot_spacing;
        ConstraintReport {
            max_base_speed: max(&mut self.base_velocity.iter().map(|v| v.norm())),
            max_base_acceleration: max(&mut self.base_acceleration.iter().map(|a| a.norm())),
            max_yaw_rate: max(
                &mut (1..n).map(|k| wrap_angle(self.base[k].yaw - self.base[k - 1].yaw).abs() / h)
            ),
            min_forward_speed: min(&mut (0..n).map(|k| heading(k).dot(&self.base_velocity[k]))),
            max_horizontal_reach: max(&mut (0..n).map(|k| relative(k).0.norm())),
            max_reach: max(&mut (0..n).map(|k| {
                let (xy, z) = relative(k);
                (xy.norm_squared() + z * z).sqrt()
            })),
            min_forward_reach: min(&mut (0..n).map(|k| heading(k).dot(&relative(k).0))),
            min_target_clearance: min(&mut (0..n).flat_map(|k| {
                let base = Vector2::new(self.base[k].x, self.base[k].y);
                targets.iter().map(move |t| (base - t).norm())
            })),
            max_gripper_speed: max(&mut self.gripper_velocity.iter().map(|v| v.norm())),
            max_gripper_acceleration: max(&mut self.gripper_acceleration.iter().map(|a| a.norm())),
            min_gripper_height: min(&mut self.gripper.iter().map(|p| p.z)),
            mean_squared_gripper_acceleration: self
                .gripper_acceleration
                .iter()
                .map(|a| a.norm_squared())
                .sum::<f64>()
                / self.gripper_acceleration.len().max(1) as f64,
        }
    }
}
