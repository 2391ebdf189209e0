//! Settings of the planning baseline: knot spacing, task timing, reach limits, weights and the
//! gains of the open-loop tracker. Every field has a default; the struct is read from TOML with
//! unknown keys rejected.

use serde::Deserialize;

use super::PlanningError;

/// Settings of the planner (the QP over time knots) and of the tracker that follows the plan.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlanningConfig {
    /// Time between knots, s. Accelerations are constant between knots.
    pub knot_spacing: f64,
    /// Weight of the squared gripper (EE) acceleration in the objective. The paper's planner
    /// minimises EE acceleration; this is the main term.
    pub gripper_acceleration_weight: f64,
    /// Weight of the squared base acceleration in the objective. Chosen small but non-zero so the
    /// base path is smooth and unique.
    pub base_acceleration_weight: f64,
    /// Smallest distance, m, between the base centre and the cube or the container, enforced at
    /// every knot (the paper's "minimum distance between base and targets").
    pub target_clearance: f64,
    /// Distance, m, at which the nominal route passes the cube and the container (tangent
    /// geometry, as the MotM base controller's r_C). Used to fix the grasp and drop times and as
    /// the linearisation point of the clearance constraint. Must be at least `target_clearance`.
    pub pass_distance: f64,
    /// Fraction of the robot's manipulation range at which the grasp (and drop) is scheduled on
    /// the nominal route: the grasp time is the first time the arm mount comes within
    /// `event_range_fraction × manipulation_range` of the cube.
    pub event_range_fraction: f64,
    /// Smallest forward distance, m, of the gripper ahead of the arm mount, along the base heading.
    /// Keeps the gripper in front of the arm (the Panda cannot work behind itself) and away from
    /// the base column.
    pub min_forward_reach: f64,
    /// Largest 3-D distance, m, from the arm's shoulder (first arm joint frame) to the gripper.
    pub max_reach: f64,
    /// Lowest gripper height, m.
    pub min_gripper_height: f64,
    /// Largest planned base yaw rate, rad/s (capped by the robot's yaw-rate limit). Enforced,
    /// linearised, as |lateral acceleration| ≤ max_yaw_rate · forward speed. Chosen well below
    /// the base limit so the plan turns gracefully; the tracker may use the full limit.
    pub max_yaw_rate: f64,
    /// Largest gripper speed, m/s (Panda Cartesian limit 1.7 m/s).
    pub max_gripper_speed: f64,
    /// Largest gripper acceleration, m/s² (Panda Cartesian limit 13 m/s²).
    pub max_gripper_acceleration: f64,
    /// How long the gripper is held still at the grasp position while the fingers close, s.
    pub grasp_dwell: f64,
    /// How long the gripper is held still at the drop position while the fingers open, s.
    pub drop_dwell: f64,
    /// Height above the grasp point, m, that the gripper must be at `approach_time` before the
    /// grasp (it comes down onto the cube from above).
    pub approach_height: f64,
    /// Time before the grasp, s, at which the gripper must be `approach_height` above the cube;
    /// between then and the grasp it stays above the grasp height.
    pub approach_time: f64,
    /// Height above the grasp point, m, that the gripper reaches `lift_time` after the fingers
    /// have closed, and keeps while carrying until `approach_time` before the drop.
    pub lift_height: f64,
    /// Time after the grasp dwell, s, by which the gripper is `lift_height` above the grasp point.
    pub lift_time: f64,
    /// Height of the drop position above the container position, m.
    pub drop_height: f64,
    /// Time from the end of the drop dwell to the end of the plan, where base and gripper are at
    /// rest, s.
    pub stop_duration: f64,
    /// Maximum number of QP solves. The first QP is linearised about the nominal route; each
    /// further one about the previous solution (sequential convex programming) until the base
    /// headings change by less than `heading_tolerance`. 1 means exactly one QP.
    pub max_passes: usize,
    /// Trust region of the heading linearisation, rad: at every knot the planned base velocity
    /// must point within this angle of the reference heading, so that the heading-dependent
    /// constraints stay accurate. Further passes move the reference.
    pub heading_trust_region: f64,
    /// Largest heading change, rad, between two passes at which the plan counts as converged.
    pub heading_tolerance: f64,
    /// Gains and limits of the open-loop tracker.
    pub tracking: TrackingConfig,
}

impl Default for PlanningConfig {
    fn default() -> Self {
        Self {
            knot_spacing: 0.1,
            gripper_acceleration_weight: 1.0,
            base_acceleration_weight: 0.1,
            target_clearance: 0.5,
            pass_distance: 0.6,
            event_range_fraction: 0.9,
            min_forward_reach: 0.1,
            max_reach: 0.85,
            min_gripper_height: 0.05,
            max_yaw_rate: 0.5,
            max_gripper_speed: 1.7,
            max_gripper_acceleration: 13.0,
            grasp_dwell: 0.5,
            drop_dwell: 0.2,
            approach_height: 0.05,
            approach_time: 0.5,
            lift_height: 0.1,
            lift_time: 0.5,
            drop_height: 0.15,
            stop_duration: 3.0,
            max_passes: 8,
            heading_trust_region: 0.3,
            heading_tolerance: 0.01,
            tracking: TrackingConfig::default(),
        }
    }
}

/// Gains and limits of [`super::PlanningController`]: it servos the robot's own measured state to
/// the planned poses (odometry and joint feedback only; the object is never re-observed).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingConfig {
    /// Gain on the along-track base position error, 1/s (Kanayama tracking law).
    pub base_along_gain: f64,
    /// Gain on the cross-track base position error, 1/m² (Kanayama tracking law).
    pub base_cross_gain: f64,
    /// Gain on the base heading error, 1/m (Kanayama tracking law, multiplied by the speed).
    pub base_heading_gain: f64,
    /// Proportional gain on the gripper position error, 1/s.
    pub gripper_position_gain: f64,
    /// Proportional gain on the gripper orientation error, 1/s.
    pub gripper_orientation_gain: f64,
    /// Largest commanded gripper linear speed, m/s.
    pub max_gripper_speed: f64,
    /// Largest commanded gripper angular speed, rad/s.
    pub max_gripper_angular_speed: f64,
    /// World yaw of the top-down gripper, rad: the tool keeps its ready-pose orientation,
    /// turned by this yaw about world z (0 aligns the fingers with the cube faces for a cube
    /// that is square to the world axes).
    pub gripper_yaw: f64,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        Self {
            base_along_gain: 1.0,
            base_cross_gain: 4.0,
            base_heading_gain: 3.0,
            gripper_position_gain: 5.0,
            gripper_orientation_gain: 2.0,
            max_gripper_speed: 1.0,
            max_gripper_angular_speed: 1.5,
            gripper_yaw: 0.0,
        }
    }
}

impl PlanningConfig {
    /// Checks every value, naming the key at fault.
    pub fn validate(&self) -> Result<(), PlanningError> {
        let positive = [
            ("knot_spacing", self.knot_spacing),
            (
                "gripper_acceleration_weight",
                self.gripper_acceleration_weight,
            ),
            ("base_acceleration_weight", self.base_acceleration_weight),
            ("pass_distance", self.pass_distance),
            ("event_range_fraction", self.event_range_fraction),
            ("max_reach", self.max_reach),
            ("max_yaw_rate", self.max_yaw_rate),
            ("max_gripper_speed", self.max_gripper_speed),
            ("max_gripper_acceleration", self.max_gripper_acceleration),
            ("heading_tolerance", self.heading_tolerance),
            ("heading_trust_region", self.heading_trust_region),
            (
                "tracking.max_gripper_speed",
                self.tracking.max_gripper_speed,
            ),
            (
                "tracking.max_gripper_angular_speed",
                self.tracking.max_gripper_angular_speed,
            ),
        ];
        let non_negative = [
            ("target_clearance", self.target_clearance),
            ("min_forward_reach", self.min_forward_reach),
            ("grasp_dwell", self.grasp_dwell),
            ("drop_dwell", self.drop_dwell),
            ("approach_height", self.approach_height),
            ("approach_time", self.approach_time),
            ("lift_height", self.lift_height),
            ("lift_time", self.lift_time),
            ("drop_height", self.drop_height),
            ("stop_duration", self.stop_duration),
            ("tracking.base_along_gain", self.tracking.base_along_gain),
            ("tracking.base_cross_gain", self.tracking.base_cross_gain),
            (
                "tracking.base_heading_gain",
                self.tracking.base_heading_gain,
            ),
            (
                "tracking.gripper_position_gain",
                self.tracking.gripper_position_gain,
            ),
            (
                "tracking.gripper_orientation_gain",
                self.tracking.gripper_orientation_gain,
            ),
        ];
        for (key, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(PlanningError::config(key, format!("{value} must be > 0")));
            }
        }
        for (key, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(PlanningError::config(key, format!("{value} must be >= 0")));
            }
        }
        if !self.min_gripper_height.is_finite() {
            return Err(PlanningError::config(
                "min_gripper_height",
                "must be finite",
            ));
        }
        if !self.tracking.gripper_yaw.is_finite() {
            return Err(PlanningError::config(
                "tracking.gripper_yaw",
                "must be finite",
            ));
        }
        if self.pass_distance < self.target_clearance {
            return Err(PlanningError::config(
                "pass_distance",
                format!(
                    "{} is below target_clearance {}",
                    self.pass_distance, self.target_clearance
                ),
            ));
        }
        if self.max_passes == 0 {
            return Err(PlanningError::config("max_passes", "must be at least 1"));
        }
        Ok(())
    }
}
