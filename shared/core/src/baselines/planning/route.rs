//! The nominal route: a polyline that passes the cube and then the container at the pass
//! distance (tangent geometry), driven at the requested base speed. It fixes the grasp, drop and
//! finish times before the QP is built, and gives the first QP its linearisation point.

use nalgebra::Vector2;

use super::geometry::RobotGeometry;
use super::{PlanRequest, PlanningConfig};
use crate::kinematics::BasePose;

/// Fine time step used to walk the nominal route when looking for the grasp and drop times, s.
const ROUTE_STEP: f64 = 0.01;

/// The nominal route and the event times taken from it.
#[derive(Debug, Clone)]
pub(crate) struct NominalRoute {
    /// Polyline vertices, starting at the start position.
    vertices: Vec<Vector2<f64>>,
    /// Start speed, m/s.
    start_speed: f64,
    /// Cruise speed, m/s.
    cruise_speed: f64,
    /// Acceleration used to reach the cruise speed, m/s².
    acceleration: f64,
    /// Start heading, used while the route has not moved yet.
    start_yaw: f64,
    /// Largest yaw rate of the nominal heading on the first leg, rad/s.
    max_yaw_rate: f64,
    /// Time the gripper reaches the grasp position on the nominal route, s.
    pub grasp_time: f64,
    /// Time the gripper reaches the drop position on the nominal route, s.
    pub drop_time: f64,
}

/// The tangent point from `from` on the circle of `radius` around `target`, on the side that
/// gives the shorter route to `next` (or, with no next point, the side that turns least from
/// `heading`). Returns `from` itself when it is already inside the circle.
fn tangent_point(
    from: Vector2<f64>,
    target: Vector2<f64>,
    radius: f64,
    next: Option<Vector2<f64>>,
    heading: f64,
) -> Vector2<f64> {
    let offset = target - from;
    let distance = offset.norm();
    if distance <= radius {
        return from;
    }
    let bearing = offset.y.atan2(offset.x);
    let half_angle = (radius / distance).asin();
    let length = (distance * distance - radius * radius).sqrt();
    let candidates = [bearing + half_angle, bearing - half_angle]
        .map(|angle| from + length * Vector2::new(angle.cos(), angle.sin()));
    let cost = |point: &Vector2<f64>| match next {
        Some(next) => (point - from).norm() + (next - point).norm(),
        None => {
            let d = point - from;
            crate::types::wrap_angle(d.y.atan2(d.x) - heading).abs()
        }
    };
    if cost(&candidates[1]) < cost(&candidates[0]) {
        candidates[1]
    } else {
        candidates[0]
    }
}

impl NominalRoute {
    /// Builds the route for `request` and finds the grasp and drop times on it.
    pub fn new(request: &PlanRequest, geometry: &RobotGeometry, config: &PlanningConfig) -> Self {
        let start = Vector2::new(request.start_base.x, request.start_base.y);
        let cube = request.cube.xy();
        let container = request.container.xy();
        let pass_cube = tangent_point(
            start,
            cube,
            config.pass_distance,
            Some(container),
            request.start_base.yaw,
        );
        let incoming = pass_cube - cube;
        let incoming_heading = if incoming.norm() > 0.0 {
            incoming.y.atan2(incoming.x)
        } else {
            request.start_base.yaw
        };
        let pass_container = tangent_point(
            pass_cube,
            container,
            config.pass_distance,
            None,
            incoming_heading,
        );
        let last_leg = pass_container - pass_cube;
        let direction = if last_leg.norm() > 1e-9 {
            last_leg.normalize()
        } else {
            Vector2::new(request.start_base.yaw.cos(), request.start_base.yaw.sin())
        };
        // Long enough to run past the container for any plan duration.
        let run_out = pass_container + direction * (10.0 + 100.0 * request.base_speed);
        let mut route = Self {
            vertices: vec![start, pass_cube, pass_container, run_out],
            start_speed: request.start_base_speed.min(request.base_speed),
            cruise_speed: request.base_speed,
            acceleration: 0.5 * geometry.base_acceleration,
            start_yaw: request.start_base.yaw,
            max_yaw_rate: config.max_yaw_rate.min(geometry.yaw_rate_limit),
            grasp_time: 0.0,
            drop_time: 0.0,
        };
        let event_range = config.event_range_fraction * geometry.manipulation_range;
        route.grasp_time = route.first_time_within(cube, event_range, 0.0, geometry);
        let earliest_drop = route.grasp_time
            + config.grasp_dwell
            + config.lift_time
            + config.approach_time
            + config.knot_spacing;
        route.drop_time = route.first_time_within(container, event_range, earliest_drop, geometry);
        route
    }

    /// Distance travelled along the route at time `t`.
    fn arc_length(&self, t: f64) -> f64 {
        let ramp = ((self.cruise_speed - self.start_speed) / self.acceleration).max(0.0);
        if t <= ramp {
            self.start_speed * t + 0.5 * self.acceleration * t * t
        } else {
            self.start_speed * ramp
                + 0.5 * self.acceleration * ramp * ramp
                + self.cruise_speed * (t - ramp)
        }
    }

    /// Base pose on the nominal route at time `t`: heading along the current leg, except on the
    /// first leg, where it turns from the start heading at no more than `max_yaw_rate`.
    pub fn pose(&self, t: f64) -> BasePose {
        let pose = self.leg_pose(t);
        let first_leg = self.vertices[1] - self.vertices[0];
        if (pose.x - self.vertices[0].x).hypot(pose.y - self.vertices[0].y) < first_leg.norm() {
            let turn = crate::types::wrap_angle(pose.yaw - self.start_yaw);
            let limit = self.max_yaw_rate * t;
            return BasePose::new(pose.x, pose.y, self.start_yaw + turn.clamp(-limit, limit));
        }
        pose
    }

    /// Base pose on the nominal route at time `t`, heading along the current leg.
    fn leg_pose(&self, t: f64) -> BasePose {
        let mut remaining = self.arc_length(t);
        let mut yaw = self.start_yaw;
        for pair in self.vertices.windows(2) {
            let leg = pair[1] - pair[0];
            let length = leg.norm();
            if length < 1e-9 {
                continue;
            }
            yaw = leg.y.atan2(leg.x);
            if remaining <= length {
                let p = pair[0] + leg * (remaining / length);
                return BasePose::new(p.x, p.y, yaw);
            }
            remaining -= length;
        }
        let last = self.vertices[self.vertices.len() - 1];
        BasePose::new(last.x, last.y, yaw)
    }

    /// The first time at or after `not_before` when the arm mount is within `range` of
    /// `target`; if that never happens within the route, the time of closest approach.
    fn first_time_within(
        &self,
        target: Vector2<f64>,
        range: f64,
        not_before: f64,
        geometry: &RobotGeometry,
    ) -> f64 {
        let total_length: f64 = self.vertices.windows(2).map(|p| (p[1] - p[0]).norm()).sum();
        let horizon = not_before + total_length / self.cruise_speed.max(1e-3);
        let mut best = (f64::INFINITY, not_before);
        let mut t = not_before;
        while t <= horizon {
            let distance = (geometry.mount_position(&self.pose(t)) - target).norm();
            if distance <= range {
                return t;
            }
            if distance < best.0 {
                best = (distance, t);
            } else if distance > best.0 + 1.0 {
                // Moving away from the target for good.
                break;
            }
            t += ROUTE_STEP;
        }
        best.1
    }
}
