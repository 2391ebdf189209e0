//! The planning baseline (paper section III-C, docs/algorithms.md §3): plan once at t = 0, then track
//! the plan open-loop.
//!
//! **Planning.** One minimum-acceleration trajectory for the base and the gripper together,
//! solved as one conic QP with clarabel over time knots (formulation in `planning/qp.rs`):
//! initial state; gripper position and zero velocity at the fixed grasp and drop times (held
//! while the fingers close or open); base and gripper at rest at the finish time; base forward
//! speed ≤ v_F; gripper within the manipulation range of the arm mount and within the arm's
//! 3-D reach, and ahead of the mount (the "minimum and maximum base–gripper distance"); base
//! centre clear of the cube and the container. The grasp, drop and finish times are fixed before
//! the QP, from a nominal route that passes the cube and the container at the pass distance at
//! speed v_F: the grasp is scheduled when the arm mount comes within a fraction of the
//! manipulation range of the cube, the drop likewise for the container.
//!
//! The heading-dependent constraints are linearised about the nominal route; with
//! `max_passes > 1` the QP is solved again about its own solution until the headings settle
//! (sequential convex programming). Each pass is one QP over the whole horizon.
//!
//! **Tracking.** [`PlanningController`] servos the robot's own measured state (odometry and
//! tool pose) to the planned base and gripper poses, with the plan's velocities as feed-forward.
//! The object is never re-observed: the grasp position is the cube as perceived at t = 0, so
//! the baseline fails on moving objects for that reason alone.

mod config;
mod geometry;
mod plan;
mod qp;
mod route;
mod tracker;

#[cfg(test)]
mod tests;

use std::time::Instant;

use nalgebra::{Vector2, Vector3};

pub use config::{PlanningConfig, TrackingConfig};
pub use geometry::RobotGeometry;
pub use plan::{ConstraintReport, Plan, PlanSample, SolveStatus};
pub use tracker::{PlanPhase, PlanningCommand, PlanningController};

use crate::kinematics::BasePose;
use crate::robot::Robot;
use qp::{Layout, Linearisation, QpData, Schedule};
use route::NominalRoute;

/// Fraction of v_F below which a knot's heading does not count towards pass convergence.
const CONVERGENCE_SPEED_FRACTION: f64 = 0.1;

/// What to plan: where the robot starts and where the cube and the container are.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanRequest {
    /// Base pose at t = 0.
    pub start_base: BasePose,
    /// Base forward speed at t = 0, m/s (0 for a standing start). The arm starts at its ready
    /// pose, moving with the base.
    pub start_base_speed: f64,
    /// Cube position as perceived at t = 0, m: the gripper's tool point grasps here.
    pub cube: Vector3<f64>,
    /// Container position, m; the cube is dropped `drop_height` above it.
    pub container: Vector3<f64>,
    /// Base speed v_F, m/s: the largest base forward speed of the plan.
    pub base_speed: f64,
}

/// Why no plan could be made.
#[derive(Debug, thiserror::Error)]
pub enum PlanningError {
    /// A configuration value is out of range.
    #[error("planning config: {key}: {message}")]
    Config {
        /// The key at fault (e.g. `knot_spacing`).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// A request value is out of range.
    #[error("planning request: {field}: {message}")]
    Request {
        /// The request field at fault (e.g. `cube`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The constraints cannot all be met.
    #[error("planning is infeasible: {0}")]
    Infeasible(String),
    /// The solver failed for another reason.
    #[error("planning solver failed: {0}")]
    Solver(String),
}

impl PlanningError {
    /// A [`PlanningError::Config`] for `key`.
    pub fn config(key: &str, message: impl Into<String>) -> Self {
        Self::Config {
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// A [`PlanningError::Request`] for `field`.
    pub fn request(field: &str, message: impl Into<String>) -> Self {
        Self::Request {
            field: field.to_string(),
            message: message.into(),
        }
    }
}

impl PlanRequest {
    /// Checks every value against the robot's limits, naming the field at fault.
    pub fn validate(&self, geometry: &RobotGeometry) -> Result<(), PlanningError> {
        let base = &self.start_base;
        if !(base.x.is_finite() && base.y.is_finite() && base.yaw.is_finite()) {
            return Err(PlanningError::request("start_base", "must be finite"));
        }
        for (field, p) in [("cube", &self.cube), ("container", &self.container)] {
            if p.iter().any(|v| !v.is_finite()) {
                return Err(PlanningError::request(field, "must be finite"));
            }
        }
        if !(self.base_speed.is_finite() && self.base_speed > 0.0) {
            return Err(PlanningError::request(
                "base_speed",
                format!("{} must be > 0", self.base_speed),
            ));
        }
        if self.base_speed > geometry.base_speed_limit {
            return Err(PlanningError::request(
                "base_speed",
                format!(
                    "{} exceeds the base limit {} m/s",
                    self.base_speed, geometry.base_speed_limit
                ),
            ));
        }
        if !(self.start_base_speed.is_finite()
            && self.start_base_speed >= 0.0
            && self.start_base_speed <= self.base_speed)
        {
            return Err(PlanningError::request(
                "start_base_speed",
                format!(
                    "{} must be within [0, base_speed = {}]",
                    self.start_base_speed, self.base_speed
                ),
            ));
        }
        Ok(())
    }
}

/// Plans the base and gripper trajectory for `request` (see the module documentation).
pub fn plan(
    robot: &Robot,
    request: &PlanRequest,
    config: &PlanningConfig,
) -> Result<Plan, PlanningError> {
    let started = Instant::now();
    config.validate()?;
    let geometry = RobotGeometry::from_robot(robot);
    request.validate(&geometry)?;

    let route = NominalRoute::new(request, &geometry, config);
    let schedule = Schedule::new(route.grasp_time, route.drop_time, config);
    let h = config.knot_spacing;
    let layout = Layout {
        intervals: schedule.end,
    };
    let data = QpData {
        request,
        geometry: &geometry,
        config,
        schedule,
        start_gripper: geometry.ready_tool_position(&request.start_base),
        grasp_position: request.cube,
        drop_position: request.container + Vector3::z() * config.drop_height,
    };
    let mut about = {
        let poses: Vec<BasePose> = (0..=schedule.end)
            .map(|k| route.pose(k as f64 * h))
            .collect();
        Linearisation {
            base: poses.iter().map(|p| Vector2::new(p.x, p.y)).collect(),
            heading: poses.iter().map(|p| p.yaw).collect(),
        }
    };

    let mut passes = 0;
    let mut iterations = 0;
    let (solution, headings, converged) = loop {
        let solution = qp::solve(&data, &about)?;
        passes += 1;
        iterations += solution.iterations;
        let velocities: Vec<Vector2<f64>> = (0..=schedule.end)
            .map(|k| {
                Vector2::new(
                    solution.x[layout.base_velocity(k, 0)],
                    solution.x[layout.base_velocity(k, 1)],
                )
            })
            .collect();
        let headings = plan::headings(&velocities, request.start_base.yaw);
        // Headings near rest are ill-defined and move the mount little: only knots faster than
        // CONVERGENCE_SPEED_FRACTION · v_F count towards convergence.
        let change = headings
            .iter()
            .zip(&about.heading)
            .zip(&velocities)
            .filter(|(_, v)| v.norm() >= CONVERGENCE_SPEED_FRACTION * request.base_speed)
            .map(|((a, b), _)| crate::types::wrap_angle(a - b).abs())
            .fold(0.0, f64::max);
        let converged = change < config.heading_tolerance;
        if converged || passes >= config.max_passes {
            break (solution, headings, converged);
        }
        about = Linearisation {
            base: (0..=schedule.end)
                .map(|k| {
                    Vector2::new(
                        solution.x[layout.base_position(k, 0)],
                        solution.x[layout.base_position(k, 1)],
                    )
                })
                .collect(),
            heading: headings,
        };
    };

    let x = &solution.x;
    let v2 = |f: &dyn Fn(usize) -> usize, k: usize| Vector2::new(x[f(k)], x[f(k) + 1]);
    let v3 = |f: &dyn Fn(usize) -> usize, k: usize| Vector3::new(x[f(k)], x[f(k) + 1], x[f(k) + 2]);
    let knots = 0..=schedule.end;
    let intervals = 0..schedule.end;
    Ok(Plan {
        knot_spacing: h,
        knot_times: knots.clone().map(|k| k as f64 * h).collect(),
        base: knots
            .clone()
            .map(|k| {
                let p = v2(&|k| layout.base_position(k, 0), k);
                BasePose::new(p.x, p.y, headings[k])
            })
            .collect(),
        base_velocity: knots
            .clone()
            .map(|k| v2(&|k| layout.base_velocity(k, 0), k))
            .collect(),
        base_acceleration: intervals
            .clone()
            .map(|k| v2(&|k| layout.base_acceleration(k, 0), k))
            .collect(),
        gripper: knots
            .clone()
            .map(|k| v3(&|k| layout.gripper_position(k, 0), k))
            .collect(),
        gripper_velocity: knots
            .map(|k| v3(&|k| layout.gripper_velocity(k, 0), k))
            .collect(),
        gripper_acceleration: intervals
            .map(|k| v3(&|k| layout.gripper_acceleration(k, 0), k))
            .collect(),
        grasp_knot: schedule.grasp,
        grasp_end_knot: schedule.grasp_end,
        drop_knot: schedule.drop,
        drop_end_knot: schedule.drop_end,
        grasp_position: data.grasp_position,
        drop_position: data.drop_position,
        status: match solution.status {
            clarabel::solver::SolverStatus::Solved => SolveStatus::Solved,
            _ => SolveStatus::AlmostSolved,
        },
        passes,
        converged,
        iterations,
        solve_time: started.elapsed(),
    })
}
