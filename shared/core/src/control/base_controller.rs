//! The MotM base controller (paper section III-B.1; docs/algorithms.md §2 "Base controller").
//!
//! The base drives a **route** through each target's closest-approach pose ξ_C, the pose at
//! r_C beside the target from which the arm works on it while the base keeps moving:
//! 1. **Pass plans.** A pass plan is a side (the target on the base's left or right) and a
//!    heading; ξ_C is the target offset by r_C to that side of the heading. The route to it is
//!    the shortest Dubins path (arcs of at least `min_turn_radius`, [`crate::route`]) to the
//!    start of a straight **run-in** `run_in` long that ends at ξ_C, then a straight **run-out**
//!    `run_out` long: the arm reaches during the run-in and grasps, drops or presses while the
//!    base goes straight, and only then does the base turn away.
//! 2. **Choice.** Each step the controller scores every pass plan (both sides, the heading
//!    straight from the base to the tangent point and `heading_candidates` headings evenly
//!    round the circle): the route's length to ξ_C, plus the run-in and run-out, plus the
//!    shortest Dubins path from the end of the run-out to a tangent pose on the next target's
//!    r_C circle, plus `crossing_cost` when the run-in leads over a target still to come (the
//!    arm would reach across it, the camera look along it). A plan whose route comes within
//!    `clearance` of a known target (a platform, a container or a button of the mission) other
//!    than at its own pass is refused; a next leg that does is charged a detour. The best plan
//!    replaces the current one only when it is shorter by `replan_margin`, so the choice does
//!    not flicker. So a target on either side, a next target beside or behind (the base turns
//!    round the far side, a U-turn), zigzags and targets in a row all come from one rule, with
//!    no case for any layout.
//! 3. **Commitment.** Once the base is on the run-in (within `run_in_tolerance` of its line,
//!    heading along it) the plan is fixed until the target is passed, and the base follows the
//!    line through the current ξ_C: a moving target moves its line, and the base follows it.
//!    A base that falls off the line by twice the tolerance (the target moved too far, the base
//!    slipped) plans again: if no short route is left, the route comes around for a second
//!    approach. Before it is on the run-in, a kept plan's route planned again may turn at
//!    `tight_turn_radius` where the wide radius would need a loop (the run-in's start moved
//!    behind the base's turn onto it).
//! 4. **Passed latch.** Set when the base is within r_C of the target, or the target is abeam or
//!    behind within r_C + `pass_margin`; cleared when the task index changes. Once passed, t_R
//!    is 0 and the base drives the route to the next target's pass plan, chosen the same way
//!    (without a target after it); when the task changes that plan is where the new task's
//!    choice starts.
//! 5. **Following.** Pure pursuit of the point `look_ahead` along the route (beyond the route's
//!    end, straight on along the run-in line), at the forward speed v_F within the base's speed
//!    limit. ω is saturated at the base's yaw-rate limit and changes by at most
//!    `yaw_acceleration_fraction` × its yaw acceleration limit per second, and at most
//!    `yaw_acceleration_per_speed` × v_F ([`BaseControllerConfig::yaw_acceleration`]; ramping
//!    from rest at the first step), so the command is one the base can execute and the QP, which
//!    is handed it as the base target, plans the arm for the turn that happens. The turns of a
//!    route need ω = v_F/R on arcs of radius R, so the time to get into one stays the same at
//!    any v_F; the arm cancels the base's yaw acceleration at the tool (0.6 m out) only as well
//!    as it knows it, and at the URDF limit a slow run's start and its turns after each task
//!    jerked the tool as hard as a fast run's.
//! 6. **t_R.** The time until the target is within the robot's manipulation range of the arm
//!    base (first arm joint), along the route at the commanded speed times the drive's measured
//!    ratio of speed to command (`DriveRatio`), with the target moving at its estimated
//!    velocity; and the base pose then. If the route never brings it within range, the time of
//!    the closest predicted approach.
//!
//! Everything is recomputed from the latest estimates every step, so a moving target is
//! followed and a wrong estimate corrected.

use std::path::Path;

use nalgebra::{Rotation2, Vector2};
use serde::Deserialize;

use crate::error::ModelError;
use crate::facing::{FacingJoint, FacingReach};
use crate::input_check::{NonFiniteInput, ensure_finite};
use crate::kinematics::BasePose;
use crate::reach_range::arm_base_in_base_frame;
use crate::robot::Robot;
use crate::route::{DubinsPath, pursue};
use crate::types::{BaseVelocity, TargetEstimate, wrap_angle};

/// On which side of the target the base passes, seen along its direction of travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PassSide {
    /// The base passes to the left of the target (the target is on the base's right).
    #[default]
    Left,
    /// The base passes to the right of the target (the target is on the base's left).
    Right,
}

impl PassSide {
    /// +1 for [`PassSide::Left`], −1 for [`PassSide::Right`]: the sign of the tangent angle γ.
    pub fn sign(self) -> f64 {
        match self {
            Self::Left => 1.0,
            Self::Right => -1.0,
        }
    }
}

/// Tunables of the base controller (the `[base]` table of a controller config).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseControllerConfig {
    /// Constant forward speed v_F, m/s (clamped to the base's speed limit).
    pub forward_speed: f64,
    /// Closest-approach radius r_C = r_R + r_P = 0.25 + 0.35 m. A controller raises it for a
    /// wide base to keep [`BaseControllerConfig::pass_clearance`]
    /// ([`BaseController::new`]; its [`BaseController::config`] holds the value in use).
    pub closest_approach_radius: f64,
    /// Smallest gap, m, between the side of the base's footprint and a target's obstacle
    /// circle (`obstacle_radius`) as the base passes the target at r_C: r_C is at least half the
    /// footprint's width + `obstacle_radius` + this. 0.1: Frankie (0.47 m wide) keeps 0.115 m
    /// at r_C = 0.6 m and Fetch (0.56 m) 0.1 m, both unchanged; the Husky (0.67 m) passes at
    /// 0.655 m instead of 0.6 m, where its long front corners, swinging out as it steered onto
    /// a container's moving estimate, struck the container.
    pub pass_clearance: f64,
    /// Smallest turning radius of a route's arcs, m (the radius is also at least v_F over the
    /// base's yaw-rate limit). 0.6 m: turning round a target at r_C, the arc's centre is the
    /// target, and the base's corners swing out by a few centimetres only.
    pub min_turn_radius: f64,
    /// Turning radius, m, a kept plan's route may use instead of `min_turn_radius` where that
    /// one would need a loop (also at least v_F over the yaw-rate limit; 0 turns it off). A
    /// target first seen 0.15 m from where it was expected moves the start of the run-in behind
    /// the base's turn onto it; at the wide radius only a loop reached it, and the loop, costed
    /// afresh, lost the plan to a pass of the far side of a row.
    pub tight_turn_radius: f64,
    /// Length of the straight run-in that ends at ξ_C, m: the arm's reach happens on it.
    pub run_in: f64,
    /// Length of the straight run-out after ξ_C, m: the grasp and the lift, the drop or the
    /// press happen on it before the base turns.
    pub run_out: f64,
    /// Pure-pursuit look-ahead along the route, m.
    pub look_ahead: f64,
    /// Headings of ξ_C tried evenly round the circle (besides the straight approach), per side.
    pub heading_candidates: usize,
    /// Weight of a route's turning in its cost, m per rad: of two routes of about the same
    /// length, the straighter one (the arm reaches more easily from a base that goes straight).
    pub turn_cost: f64,
    /// Extra length charged to a pass plan whose run-in leads over another of the mission's
    /// targets still to come, m ([`BaseControllerConfig::crossing_width`]): the arm would reach
    /// across it and the camera would look along it. Approached end-on from the side where the
    /// rest of a row still stands, the target's blob merged with its neighbours' and the grasp
    /// went to a neighbour, or the open fingers swept one off (Exp 2: most failed runs came
    /// round the row's far end). Passing the row from its cleared end, or across it, costs
    /// about a metre more at most.
    pub crossing_cost: f64,
    /// Half-width of the corridor a run-in leads over, m: a later target within this of the
    /// line through the target along the pass heading, and before it by at most `run_in`, is
    /// crossed.
    pub crossing_width: f64,
    /// A new pass plan replaces the current one only when its route is shorter by this, m.
    pub replan_margin: f64,
    /// The route is planned again when the base is this far off it, or the target this far
    /// from where it was when the route was planned, m.
    pub replan_deviation: f64,
    /// Period at which the pass plan is chosen again while the route is followed, s.
    pub replan_period: f64,
    /// The route (not the plan) is planned again when the target has moved this far since, m.
    pub route_refresh_distance: f64,
    /// Within this distance along the route from ξ_C the pass plan no longer changes, m: the
    /// reacher starts the arm's transit about this far out, and a new heading would swing the
    /// arm away from the target it is reaching for.
    pub commit_distance: f64,
    /// Radius of the circle a known target (a platform, a container, a button) is taken to fill,
    /// m. 0.22: the half-diagonal of the 0.3 m platforms and containers, plus a centimetre.
    pub obstacle_radius: f64,
    /// Smallest gap a route keeps between the base's footprint and a known target's circle, m.
    pub clearance: f64,
    /// Largest distance from the run-in line at which the base counts as on it, m.
    pub run_in_tolerance: f64,
    /// The "passed" latch is set when the base is within r_C of the target, or when the target is
    /// abeam or behind the base (no component ahead) while within r_C plus this margin, m.
    pub pass_margin: f64,
    /// Fraction of the base's yaw acceleration limit (URDF `base_yaw` acceleration) the
    /// commanded ω may change by per second. 1.0: the base's full capability.
    pub yaw_acceleration_fraction: f64,
    /// Yaw acceleration allowed per unit of the base speed v_F, rad/s² per m/s (6: 1.2 rad/s² at
    /// 0.2 m/s, the LD-60's 2 rad/s² from 0.33 m/s); see
    /// [`BaseControllerConfig::yaw_acceleration`].
    pub yaw_acceleration_per_speed: f64,
    /// Fraction of v_F the base drives at once it is past a target's ξ_C while the task is
    /// still not done (a late reach, a lift, a drop or a press), so that the arm finishes near
    /// the target instead of being carried away from it.
    pub linger_speed_fraction: f64,
    /// While lingering, the base slows in proportion to how far the target is behind the arm's
    /// base (along the heading), to a stop this far behind it, m (0 turns it off).
    pub linger_stop_distance: f64,
    /// A pass is missed when the base has been past ξ_C this long with the task still not done,
    /// s (0 turns it off): the base comes around for another approach
    /// ([`BaseController::missed_passes`]). 8 s: a grasp and its lift, a drop or a press take
    /// 1–3 s from ξ_C on, and a late reach is over, one way or the other, well before.
    pub pass_timeout: f64,
    /// Passes made on the move before the base does the task the reactive way: on the next
    /// approach it slows to a stop with the target abeam of the arm's base, and waits there
    /// until the task is done (or `pass_timeout` runs out again).
    pub moving_passes: u32,
    /// On a reactive approach the base slows in proportion to the distance, along its heading,
    /// from the arm's base to the target, from v_F this far out to a stop abeam of it, m.
    pub reactive_slow_distance: f64,
    /// The command is checked this far ahead, s (0 turns the check off): the footprint, driven
    /// at the commanded v with ω ramping to the command at the yaw acceleration limit, must
    /// keep `clearance` from every known target (or come no closer to it than now). If it does
    /// not, the nearest turn rate that does is commanded instead, then half the speed, then a
    /// turn on the spot. Routes are planned clear, but pure pursuit cuts their corners and a
    /// route planned afresh from a lagging pose can swing the base across a platform.
    pub guard_horizon: f64,
    /// Where the arm's facing joint stops short of a full turn, the lingering base stops
    /// earlier than `linger_stop_distance`: before the target's bearing from that joint's axis
    /// comes within this of the joint's limit, rad (0.2: the QP's joint-limit damper stops the
    /// joint 0.1 rad short of its limit, and the arm needs a little more to reach round).
    pub linger_bearing_margin: f64,
}

impl Default for BaseControllerConfig {
    fn default() -> Self {
        Self {
            forward_speed: 0.3,
            closest_approach_radius: 0.6,
            pass_clearance: 0.1,
            min_turn_radius: 0.6,
            tight_turn_radius: 0.35,
            run_in: 1.0,
            run_out: 0.4,
            look_ahead: 0.4,
            heading_candidates: 16,
            turn_cost: 0.5,
            crossing_cost: 2.0,
            crossing_width: 0.3,
            replan_margin: 0.3,
            replan_deviation: 0.3,
            replan_period: 1.0,
            route_refresh_distance: 0.05,
            commit_distance: 2.5,
            obstacle_radius: 0.22,
            clearance: 0.03,
            run_in_tolerance: 0.3,
            pass_margin: 0.3,
            yaw_acceleration_fraction: 1.0,
            yaw_acceleration_per_speed: 6.0,
            linger_speed_fraction: 0.5,
            linger_stop_distance: 0.4,
            pass_timeout: 8.0,
            moving_passes: 2,
            reactive_slow_distance: 0.6,
            guard_horizon: 1.0,
            linger_bearing_margin: 0.2,
        }
    }
}

impl BaseControllerConfig {
    /// The yaw acceleration the commanded ω may change by, rad/s², for a base whose limit is
    /// `max_yaw_acceleration`: that limit × `yaw_acceleration_fraction`, and at most
    /// `yaw_acceleration_per_speed` × v_F (`forward_speed`). The QP resolver limits the base
    /// target it hands on to the same value.
    pub fn yaw_acceleration(&self, max_yaw_acceleration: f64) -> f64 {
        let limit = max_yaw_acceleration * self.yaw_acceleration_fraction;
        let scaled = self.yaw_acceleration_per_speed * self.forward_speed.abs();
        if scaled.is_finite() && scaled > 0.0 {
            limit.min(scaled)
        } else {
            limit
        }
    }

    /// Checks the values; `file` is the configuration file they came from, named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        let positive = |v: f64| v > 0.0 && v.is_finite();
        let non_negative = |v: f64| v >= 0.0 && v.is_finite();
        let checks = [
            ("forward_speed", positive(self.forward_speed)),
            (
                "closest_approach_radius",
                positive(self.closest_approach_radius),
            ),
            ("pass_clearance", non_negative(self.pass_clearance)),
            ("min_turn_radius", positive(self.min_turn_radius)),
            ("tight_turn_radius", non_negative(self.tight_turn_radius)),
            ("run_in", non_negative(self.run_in)),
            ("run_out", non_negative(self.run_out)),
            ("look_ahead", positive(self.look_ahead)),
            (
                "heading_candidates",
                (1..=360).contains(&self.heading_candidates),
            ),
            ("turn_cost", non_negative(self.turn_cost)),
            ("crossing_cost", non_negative(self.crossing_cost)),
            ("crossing_width", non_negative(self.crossing_width)),
            ("replan_margin", non_negative(self.replan_margin)),
            ("replan_deviation", positive(self.replan_deviation)),
            ("replan_period", positive(self.replan_period)),
            (
                "route_refresh_distance",
                positive(self.route_refresh_distance),
            ),
            ("commit_distance", non_negative(self.commit_distance)),
            ("obstacle_radius", non_negative(self.obstacle_radius)),
            ("clearance", non_negative(self.clearance)),
            ("run_in_tolerance", positive(self.run_in_tolerance)),
            ("pass_margin", non_negative(self.pass_margin)),
            (
                "yaw_acceleration_fraction",
                positive(self.yaw_acceleration_fraction),
            ),
            (
                "yaw_acceleration_per_speed",
                positive(self.yaw_acceleration_per_speed),
            ),
            (
                "linger_speed_fraction",
                self.linger_speed_fraction > 0.0 && self.linger_speed_fraction <= 1.0,
            ),
            (
                "linger_stop_distance",
                non_negative(self.linger_stop_distance),
            ),
            ("pass_timeout", non_negative(self.pass_timeout)),
            ("guard_horizon", non_negative(self.guard_horizon)),
            (
                "reactive_slow_distance",
                positive(self.reactive_slow_distance),
            ),
            (
                "linger_bearing_margin",
                (0.0..std::f64::consts::FRAC_PI_2).contains(&self.linger_bearing_margin),
            ),
        ];
        for (key, ok) in checks {
            if !ok {
                return Err(ModelError::invalid(
                    file,
                    format!("base.{key}"),
                    "out of range (need forward_speed, closest_approach_radius, min_turn_radius, \
                     look_ahead, replan_deviation, replan_period, route_refresh_distance, run_in_tolerance, \
                     yaw_acceleration_fraction, yaw_acceleration_per_speed, reactive_slow_distance > 0; \
                     run_in, run_out, turn_cost, replan_margin, commit_distance, obstacle_radius, \
                     clearance, pass_margin, linger_stop_distance, pass_clearance, pass_timeout, \
                     guard_horizon, tight_turn_radius ≥ 0; 0 ≤ linger_bearing_margin < π/2; \
                     1 ≤ heading_candidates ≤ 360; 0 < linger_speed_fraction ≤ 1)",
                ));
            }
        }
        Ok(())
    }
}

/// What the base controller reads each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseControllerInput {
    /// Index of the current mission task. When it changes, the "passed" latch starts afresh and
    /// the plan made for the next target becomes the current one.
    pub task_index: usize,
    /// Current base pose (odometry).
    pub base: BasePose,
    /// Latest estimate of the current target (only x and y are used for driving; the velocity
    /// feeds the time-to-range estimate).
    pub target: TargetEstimate,
    /// Position of the next target (x and y are used).
    pub next_target: nalgebra::Vector3<f64>,
    /// Position of the target after the next one, if the mission has one: the next target's
    /// pass is chosen for the way on to it (x and y are used).
    pub after_next: Option<nalgebra::Vector3<f64>>,
    /// Time since the previous step, s: bounds the change of ω (see the module docs).
    pub dt: f64,
}

/// What the base controller produces each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseControllerOutput {
    /// Base velocity command, within the base's v and ω limits.
    pub command: BaseVelocity,
    /// Closest-approach pose ξ_C of the current target (once it is passed, the next target's).
    pub closest_approach: BasePose,
    /// The side on which the base passes the current target.
    pub side: PassSide,
    /// t_R: predicted time until the target is within manipulation range of the arm base, s.
    /// Zero once it is in range or passed. If the predicted path never brings it within range,
    /// the time of the closest predicted approach.
    pub time_to_range: f64,
    /// Predicted base pose at `time_to_range` (the current pose when that is zero).
    pub range_entry_pose: BasePose,
    /// True once the base has gone by the target (latched until the task changes, or until
    /// the pass is missed).
    pub passed: bool,
    /// Passes of the current target missed so far ([`BaseController::missed_passes`]).
    pub missed_passes: u32,
    /// The base has given up the current target ([`BaseController::gave_up`]).
    pub gave_up: bool,
}

/// The robot properties the base controller needs, taken from the model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseModel {
    /// Horizontal distance from the arm base within which the target can be manipulated, m.
    pub manipulation_range: f64,
    /// Horizontal position of the arm base (first arm joint) in the base frame, m.
    pub arm_base: Vector2<f64>,
    /// Base forward-speed limit, m/s.
    pub max_speed: f64,
    /// Base yaw-rate limit, rad/s.
    pub max_yaw_rate: f64,
    /// Base yaw acceleration limit, rad/s².
    pub max_yaw_acceleration: f64,
    /// Half the footprint's length and width (a rectangle about the base frame's origin), m.
    pub half_extents: Vector2<f64>,
    /// How far round the arm's facing joint turns, when its limits stop it short of a full
    /// turn (Fetch's shoulder pan, ±92°): the lingering base stops before a target falls
    /// behind the bearings the arm can face ([`BaseControllerConfig::linger_bearing_margin`]).
    pub facing_reach: Option<FacingReach>,
}

impl BaseModel {
    /// Where the arm base (first arm joint) is, horizontally, with the base at `pose`.
    pub fn arm_base_at(&self, pose: &BasePose) -> Vector2<f64> {
        Vector2::new(pose.x, pose.y) + Rotation2::new(pose.yaw) * self.arm_base
    }

    /// Reads the properties from a robot model: the manipulation range from its configuration,
    /// the arm base from its chain, and the v and ω limits from its two virtual base joints.
    pub fn from_robot(robot: &Robot) -> Self {
        let limits = robot.limits();
        let arm_base = arm_base_in_base_frame(robot);
        Self {
            manipulation_range: robot.config.manipulation_range,
            arm_base: Vector2::new(arm_base.x, arm_base.y),
            max_speed: limits[1].velocity,
            max_yaw_rate: limits[0].velocity,
            max_yaw_acceleration: limits[0].acceleration,
            half_extents: Vector2::new(
                0.5 * robot.config.footprint[0],
                0.5 * robot.config.footprint[1],
            ),
            facing_reach: FacingJoint::from_robot(robot).and_then(|f| f.reach(robot)),
        }
    }

    /// How far behind the arm base (along the heading) a target at `target` may fall, with the
    /// base at `pose`, before the arm's facing joint can no longer face it with `margin` rad to
    /// spare before its limit, m; `None` when the joint turns all the way round. A target
    /// abeam of the joint's axis needs a bearing of ±90°, so a joint that stops at ±92° (Fetch)
    /// allows it barely to pass the axis; the Panda's ±166° allow more than a metre.
    pub fn max_target_behind(
        &self,
        pose: &BasePose,
        target: &Vector2<f64>,
        margin: f64,
    ) -> Option<f64> {
        let reach = self.facing_reach?;
        let turn = Rotation2::new(pose.yaw);
        let axis = Vector2::new(pose.x, pose.y) + turn * reach.axis;
        let local = turn.inverse() * (target - axis);
        // The farthest bearing the joint may face on the target's side, past abeam (π/2) by at
        // most a little under a quarter turn so that the tangent stays finite.
        let limit = if local.y >= 0.0 {
            reach.max_bearing - margin
        } else {
            -(reach.min_bearing + margin)
        };
        let past_abeam = (limit - std::f64::consts::FRAC_PI_2).clamp(-1.5, 1.5);
        let behind_axis = local.y.abs() * past_abeam.tan();
        Some(behind_axis + (reach.axis.x - self.arm_base.x))
    }
}

/// How the base passes one target: the side and the heading of ξ_C.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassPlan {
    /// The side the base passes on.
    pub side: PassSide,
    /// Heading of ξ_C, rad.
    pub heading: f64,
}

impl PassPlan {
    /// ξ_C for a target at `target`: the target offset by `radius` to the plan's side.
    pub fn pose(&self, target: Vector2<f64>, radius: f64) -> BasePose {
        let (sin, cos) = self.heading.sin_cos();
        let offset = Vector2::new(-sin, cos) * (self.side.sign() * radius);
        BasePose::new(target.x + offset.x, target.y + offset.y, self.heading)
    }
}

/// The pose `distance` along `pose`'s heading (backward for a negative distance).
fn along(pose: &BasePose, distance: f64) -> BasePose {
    BasePose::new(
        pose.x + distance * pose.yaw.cos(),
        pose.y + distance * pose.yaw.sin(),
        pose.yaw,
    )
}

/// The base's offset from the line of `pose`: (along its heading, to its left).
fn line_offset(base: &BasePose, pose: &BasePose) -> (f64, f64) {
    let d = Vector2::new(base.x - pose.x, base.y - pose.y);
    let (sin, cos) = pose.yaw.sin_cos();
    (d.x * cos + d.y * sin, -d.x * sin + d.y * cos)
}

/// Straight leads tried before a route counts as blocked, in turning radii: none, then driving
/// on one and two radii before turning (away from a platform just passed, past a container
/// just dropped into).
const LEADS: [f64; 3] = [0.0, 1.0, 2.0];

/// While every route is blocked, a route point within this bearing of the heading (rad) counts
/// as straight ahead, through what blocks the way (see `BaseController::step`).
const BLOCKED_STRAIGHT_AHEAD: f64 = 0.2;

/// Time step of the command check ([`BaseControllerConfig::guard_horizon`]), s.
const GUARD_STEP: f64 = 0.1;

/// Turn rates the command check tries: this many steps of the yaw-rate limit each way.
const GUARD_TURNS: i32 = 6;

/// With neither the commanded speed, nor half of it, nor a turn on the spot clear, the command
/// check lets the base creep on at this fraction of v_F.
const GUARD_CREEP: f64 = 0.25;

/// A base wedged (no command forward or on the spot clear) backs out this far, straight back
/// where that is clear, before it drives on again, m: backing out only until a forward
/// command cleared, it drove straight back into the wedge.
const BACK_OUT_DISTANCE: f64 = 0.3;

/// Shortest stretch of odometry over which [`DriveRatio`] measures the base's speed, s.
const DRIVE_WINDOW: f64 = 0.5;

/// Range of the drive ratio believed ([`DriveRatio`]).
const DRIVE_RATIO_RANGE: (f64, f64) = (0.7, 1.3);

/// Largest spread of the commanded speed within a window, as a fraction of its mean, for the
/// window to count ([`DriveRatio`]): a speed measured while the command changes lags it.
const DRIVE_STEADY: f64 = 0.05;

/// The base's forward speed against its command, measured from odometry over windows of at
/// least [`DRIVE_WINDOW`] while the command holds steady: a drive with a gain error goes at a
/// fixed fraction of what it is told (Exp 1 seed 9 at 0.4 m/s: 0.354 m/s). t_R predicted at
/// the commanded speed then comes early, and the reach timed to it stretched the arm 5 cm past
/// its manipulation range before the base caught up (the arm's workspace limit stopped the
/// tool: Exp 1's peak |a| at 0.4 m/s). Windows start and end on fresh odometry (a pose
/// unlike the step before's), which arrives slower than the control steps.
#[derive(Debug, Clone, Copy)]
struct DriveRatio {
    /// The window's start: the clock and the pose.
    start: Option<(f64, BasePose)>,
    /// The pose of the step before.
    last: Option<BasePose>,
    /// The commanded distance over the window, m, and the command's least and largest speed.
    commanded: f64,
    low: f64,
    high: f64,
    /// The latest ratio, clamped to [`DRIVE_RATIO_RANGE`].
    ratio: f64,
}

impl Default for DriveRatio {
    fn default() -> Self {
        Self {
            start: None,
            last: None,
            commanded: 0.0,
            low: f64::INFINITY,
            high: f64::NEG_INFINITY,
            ratio: 1.0,
        }
    }
}

impl DriveRatio {
    /// Takes the odometry pose `base` at `clock`; on fresh odometry a window at least
    /// [`DRIVE_WINDOW`] long ends (its ratio taken when its command held steady and forward)
    /// and the next begins.
    fn observe(&mut self, clock: f64, base: &BasePose) {
        let fresh = self.last.is_none_or(|last| last != *base);
        self.last = Some(*base);
        if !fresh {
            return;
        }
        match self.start {
            Some((at, from)) if clock - at >= DRIVE_WINDOW => {
                let elapsed = clock - at;
                let mean = self.commanded / elapsed;
                let steady = self.low > 0.0 && self.high - self.low <= DRIVE_STEADY * mean;
                if steady {
                    let moved = Vector2::new(base.x - from.x, base.y - from.y).norm();
                    let ratio = moved / self.commanded;
                    if ratio.is_finite() {
                        self.ratio = ratio.clamp(DRIVE_RATIO_RANGE.0, DRIVE_RATIO_RANGE.1);
                    }
                }
                self.restart(clock, base);
            }
            Some(_) => {}
            None => self.restart(clock, base),
        }
    }

    /// Adds this step's commanded forward `speed`, held for `dt`.
    fn command(&mut self, speed: f64, dt: f64) {
        if self.start.is_some() {
            self.commanded += speed * dt;
            self.low = self.low.min(speed);
            self.high = self.high.max(speed);
        }
    }

    /// The speed the base will go at when told `speed`.
    fn predict(&self, speed: f64) -> f64 {
        speed * self.ratio
    }

    fn restart(&mut self, clock: f64, base: &BasePose) {
        *self = Self {
            start: Some((clock, *base)),
            last: Some(*base),
            ratio: self.ratio,
            ..Self::default()
        };
    }
}

/// Known positions closer than this are one place, m ([`BaseController::crossing_charge`]).
const SAME_PLACE: f64 = 0.05;

/// Spacing of the points at which a route is checked against the known targets, m.
const CLEARANCE_STEP: f64 = 0.1;

/// Extra length charged for a next leg that passes too close to a known target, m: enough to
/// prefer any clear plan, not so much that a blocked next leg (it is planned again later)
/// decides alone.
const BLOCKED_NEXT_LEG: f64 = 5.0;

/// While every route is blocked, the search for a clear one runs at most this often, s (the
/// base turns on the spot meanwhile; a seventh of a turn at the LD-60's half yaw rate).
const BLOCKED_REPLAN_PERIOD: f64 = 0.25;

/// The tangent from `base` to the circle of radius `radius` around `target` on `side`: the
/// tangent point and the tangent direction. `None` when the base is on or inside the circle.
pub fn tangent_point(
    base: Vector2<f64>,
    target: Vector2<f64>,
    radius: f64,
    side: PassSide,
) -> Option<(Vector2<f64>, f64)> {
    let to_target = target - base;
    let d = to_target.norm();
    if d <= radius {
        return None;
    }
    let phi = to_target.y.atan2(to_target.x);
    let gamma = (radius / d).asin();
    let rho = (d * d - radius * radius).sqrt();
    let direction = phi + side.sign() * gamma;
    Some((
        base + rho * Vector2::new(direction.cos(), direction.sin()),
        wrap_angle(direction),
    ))
}

fn xy(v: &nalgebra::Vector3<f64>) -> Vector2<f64> {
    Vector2::new(v.x, v.y)
}

/// The approach to one target: its pass plan, the route kept to it, and whether the base is
/// committed to it (on its run-in).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Approach {
    plan: Option<PassPlan>,
    route: Option<KeptRoute>,
    committed: bool,
    /// While no route to any pass plan keeps clear of the known targets: when that was found,
    /// and the route the base turns toward meanwhile ([`Approach::blocked`]).
    blocked_route: Option<(f64, DubinsPath)>,
}

impl Approach {
    /// No route to any pass plan keeps clear of the known targets.
    fn blocked(&self) -> bool {
        self.blocked_route.is_some()
    }
}

/// A planned route and how far along it the base is.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KeptRoute {
    /// The Dubins path to the start of the run-in (then straight on along it).
    path: DubinsPath,
    /// Distance along the path of the point closest to the base, m.
    progress: f64,
    /// Where the target was when the route was planned.
    target: Vector2<f64>,
    /// Controller clock when the route was planned (or last kept), s.
    planned_at: f64,
}

/// How far ahead of the last progress the base's projection onto a route is searched, m.
const TRACK_WINDOW: f64 = 0.6;

/// Resolution of that search, m.
const TRACK_STEP: f64 = 0.01;

impl KeptRoute {
    /// Moves the progress to the route point nearest the base (searching ahead of the last
    /// one) and returns the base's distance from it, m.
    fn track(&mut self, base: &BasePose) -> f64 {
        let at = Vector2::new(base.x, base.y);
        let sampler = self.path.sampler();
        let distance = |s: f64| {
            let p = sampler.sample(s);
            (Vector2::new(p.x, p.y) - at).norm()
        };
        let steps = (TRACK_WINDOW / TRACK_STEP) as usize;
        let (mut best_s, mut best_d) = (self.progress, distance(self.progress));
        for k in 1..=steps {
            let s = self.progress + k as f64 * TRACK_STEP;
            let d = distance(s);
            if d < best_d {
                (best_s, best_d) = (s, d);
            }
        }
        self.progress = best_s;
        best_d
    }
}

/// The targets after the one being passed (the next and the one after, where known), with
/// what [`BaseController::look_ahead`] works out once per choice of pass plan.
struct Ahead {
    targets: [Option<Vector2<f64>>; 2],
    /// Per fixed-heading pass plan of the next target: the start of its run-in and the leg on
    /// from its run-out (`None`: its straight is blocked). Empty without a target after it.
    fixed: Vec<Option<(BasePose, f64)>>,
    /// The known positions of the targets after the next one, in task order: the next
    /// target's plans are charged for crossing them ([`BaseController::crossing_charge`]).
    later: Vec<Vector2<f64>>,
}

/// What the controller drives along this step.
enum Route {
    /// A kept route (the Dubins path to the start of the run-in, then straight on along it)
    /// and the base's progress along it, m.
    Path(DubinsPath, f64),
    /// The run-in line of ξ_C (the base is on it).
    Line(BasePose),
}

/// The base controller: a step function plus the small state it latches between steps.
#[derive(Debug, Clone)]
pub struct BaseController {
    config: BaseControllerConfig,
    model: BaseModel,
    /// Known positions of the mission's targets (platforms, containers, buttons).
    layout: Vec<Vector2<f64>>,
    task_index: Option<usize>,
    current: Approach,
    next: Approach,
    passed: bool,
    closest_approach: BasePose,
    /// The ω commanded on the previous step (0 at rest, before the first step).
    last_omega: f64,
    /// Sum of the steps' `dt`, s.
    clock: f64,
    /// Passes of the current target missed so far.
    missed: u32,
    /// Time spent past the current target's ξ_C (or, on a reactive approach, within its slow
    /// zone) with its task not done, s.
    lingered: f64,
    /// After a missed pass: the passed latch waits for a fresh approach (the base on the run-in
    /// well before ξ_C).
    rearm: bool,
    /// While every route is blocked: the direction the base turns on the spot (+1 left).
    blocked_turn: Option<f64>,
    /// While every route is blocked: how often the command check has refused the turn and
    /// reversed it.
    blocked_reversals: u32,
    /// How much farther a wedged base backs out, m ([`BACK_OUT_DISTANCE`]).
    backing_out: f64,
    /// Times the pass plans were scored (the planner's costly search).
    plan_searches: std::cell::Cell<u64>,
    /// The base's speed against its command, measured over windows of odometry.
    drive: DriveRatio,
}

impl BaseController {
    /// A controller with `config` for the robot described by `model`, with no known layout.
    pub fn new(mut config: BaseControllerConfig, model: BaseModel) -> Self {
        config.closest_approach_radius = config
            .closest_approach_radius
            .max(model.half_extents.y + config.obstacle_radius + config.pass_clearance);
        Self {
            config,
            model,
            layout: Vec::new(),
            task_index: None,
            current: Approach::default(),
            next: Approach::default(),
            passed: false,
            closest_approach: BasePose::default(),
            last_omega: 0.0,
            clock: 0.0,
            missed: 0,
            lingered: 0.0,
            rearm: false,
            blocked_turn: None,
            blocked_reversals: 0,
            backing_out: 0.0,
            plan_searches: std::cell::Cell::new(0),
            drive: DriveRatio::default(),
        }
    }

    /// How many times the pass plans have been scored: the planner's costly search (every
    /// plan, every Dubins word, the footprint along each), run when a route is (re)planned.
    pub fn plan_searches(&self) -> u64 {
        self.plan_searches.get()
    }

    /// The same controller, keeping its routes' footprint clear of the known positions of the
    /// mission's targets (`layout`: platforms, containers and buttons; only x and y are used).
    /// The layout is in task order (task `k`'s target at index `k`): the targets after the
    /// current task's are the ones still to come ([`BaseControllerConfig::crossing_cost`]).
    pub fn with_layout(mut self, layout: &[nalgebra::Vector3<f64>]) -> Self {
        self.set_layout(layout);
        self
    }

    /// Replaces the known positions the routes keep clear of (see [`BaseController::with_layout`]).
    pub fn set_layout(&mut self, layout: &[nalgebra::Vector3<f64>]) {
        self.layout = layout.iter().map(xy).collect();
    }

    /// The configuration.
    pub fn config(&self) -> &BaseControllerConfig {
        &self.config
    }

    /// The robot properties in use.
    pub fn model(&self) -> &BaseModel {
        &self.model
    }

    /// The forward speed actually commanded: v_F within the base's speed limit.
    pub fn speed(&self) -> f64 {
        self.config.forward_speed.min(self.model.max_speed)
    }

    /// Turning radius of the routes' arcs: `min_turn_radius`, or more if the yaw-rate limit
    /// needs it at the forward speed.
    pub fn turn_radius(&self) -> f64 {
        self.config.min_turn_radius.max(self.yaw_rate_radius())
    }

    /// The tight turning radius of a kept plan's re-route: `tight_turn_radius`, or more if the
    /// yaw-rate limit needs it at the forward speed (0: off).
    fn tight_turn_radius(&self) -> f64 {
        if self.config.tight_turn_radius <= 0.0 {
            return 0.0;
        }
        self.config.tight_turn_radius.max(self.yaw_rate_radius())
    }

    /// The smallest turning radius the yaw-rate limit allows at the forward speed, m.
    fn yaw_rate_radius(&self) -> f64 {
        self.speed() / self.model.max_yaw_rate.max(1e-6)
    }

    /// One control step. Errors (and changes no state) if an input is not finite.
    pub fn step(
        &mut self,
        input: &BaseControllerInput,
    ) -> Result<BaseControllerOutput, NonFiniteInput> {
        let b = &input.base;
        ensure_finite("base", &[b.x, b.y, b.yaw])?;
        ensure_finite("target.position", input.target.position.iter())?;
        ensure_finite("target.velocity", input.target.velocity.iter())?;
        ensure_finite("next_target", input.next_target.iter())?;
        if let Some(after) = &input.after_next {
            ensure_finite("after_next", after.iter())?;
        }
        ensure_finite("dt", std::slice::from_ref(&input.dt))?;
        self.clock += input.dt.max(0.0);
        self.drive.observe(self.clock, &input.base);

        if self.task_index != Some(input.task_index) {
            if self.task_index.is_some() {
                self.current = std::mem::take(&mut self.next);
            }
            self.next = Approach::default();
            self.task_index = Some(input.task_index);
            self.passed = false;
            self.missed = 0;
            self.lingered = 0.0;
            self.rearm = false;
        }
        if self.config.pass_timeout > 0.0 && self.lingered > self.config.pass_timeout {
            self.miss_pass();
        }

        let base_xy = Vector2::new(b.x, b.y);
        let target = xy(&input.target.position);
        let next = xy(&input.next_target);
        let after_next = input.after_next.as_ref().map(xy);
        let to_target = target - base_xy;
        let heading = Vector2::new(b.yaw.cos(), b.yaw.sin());
        let r_c = self.config.closest_approach_radius;
        if !self.passed && !self.rearm {
            let d = to_target.norm();
            let abeam_or_behind = to_target.dot(&heading) <= 0.0;
            self.passed = d <= r_c || (abeam_or_behind && d < r_c + self.config.pass_margin);
        }
        let mut obstacles = self.layout.clone();
        obstacles.extend([target, next]);

        // Once passed, the base goes straight on to the end of the run-out (the lift, the drop
        // or the press happen there); from ξ_C on, while the task is still not done, it slows
        // to give the arm the time it needs.
        let current_pass = self.current.plan.map(|plan| plan.pose(target, r_c));
        let on_run_out = self.passed
            && current_pass.is_some_and(|pass| {
                let (u, e) = line_offset(b, &pass);
                u < self.config.run_out && e.abs() <= 2.0 * self.config.run_in_tolerance
            });
        // Past ξ_C means on its line beyond it: being anywhere ahead of ξ_C's heading (a
        // container passed heading north, seen from a pick-up place north of it) is not.
        let past_pass = self.passed
            || !self.rearm
                && current_pass.is_some_and(|pass| {
                    let (u, e) = line_offset(b, &pass);
                    u > 0.0
                        && u <= self.config.run_out
                        && e.abs() <= 2.0 * self.config.run_in_tolerance
                });
        let speed = if past_pass {
            // The reactive way: the farther the target falls behind the arm's base, the slower
            // the base, down to a stop `linger_stop_distance` behind it. A drop or a lift that
            // began late, with the target already behind, otherwise swung the arm's first joint
            // into its limit damper and the base carried the tool away from the container.
            // The stop comes earlier, by `shift`, where the arm's facing joint could not turn
            // far enough round to reach the target that far behind (Fetch: the base stopped
            // with the cube 0.4 m behind its torso, out of the shoulder pan's ±92°, and the
            // arm never reached it).
            let behind = -(target - self.model.arm_base_at(b)).dot(&heading);
            let stop = self.config.linger_stop_distance;
            let shift = self
                .model
                .max_target_behind(b, &target, self.config.linger_bearing_margin)
                .map_or(0.0, |allowed| (stop - allowed).max(0.0));
            let scale = if stop > 0.0 {
                (1.0 - (behind + shift) / stop).clamp(0.0, 1.0)
            } else {
                1.0
            };
            self.speed() * self.config.linger_speed_fraction * scale
        } else {
            self.speed()
        };
        let route = if let (true, Some(pass)) = (on_run_out, current_pass) {
            Route::Line(pass)
        } else if self.passed {
            let mut approach = self.next;
            let route = self.approach(
                &mut approach,
                b,
                next,
                [after_next, None],
                (&obstacles, self.later_targets(input.task_index + 2)),
                self.clock,
            );
            self.next = approach;
            route
        } else {
            let mut approach = self.current;
            let route = self.approach(
                &mut approach,
                b,
                target,
                [Some(next), after_next],
                (&obstacles, self.later_targets(input.task_index + 1)),
                self.clock,
            );
            self.current = approach;
            route
        };
        if self.rearm && self.current.committed {
            self.rearm = false;
        }
        // The reactive way, after `moving_passes` missed passes: on the run-in and the run-out
        // of the target, the base slows to a stop with the target abeam of the arm's base.
        // The speed is that of a constant deceleration to the stop, so the stop is reached.
        let reactive_line = self.missed >= self.config.moving_passes
            && !self.gave_up()
            && matches!(route, Route::Line(_))
            && (!self.passed || on_run_out);
        let (speed, waiting) = if reactive_line {
            let ahead = (target - self.model.arm_base_at(b)).dot(&heading);
            let slow = self.config.reactive_slow_distance;
            (
                self.speed() * (ahead / slow).clamp(0.0, 1.0).sqrt(),
                past_pass || ahead <= slow,
            )
        } else if self.gave_up() {
            (self.speed(), false)
        } else {
            (speed, past_pass)
        };
        self.lingered = if waiting {
            self.lingered + input.dt.max(0.0)
        } else {
            0.0
        };
        let (pass, point) = match &route {
            Route::Line(pass) => {
                // The point the base reaches in look_ahead/v, where the line (moving with the
                // target) will be by then: without that lead, a line moving sideways at w is
                // followed w·look_ahead/v behind.
                let (u, _) = line_offset(b, pass);
                let point = along(pass, u + self.config.look_ahead);
                // Only before ξ_C: once the arm holds the object, its estimate moves with the
                // gripper, not on its own. At most the run-in tolerance.
                let lead = if past_pass {
                    Vector2::zeros()
                } else {
                    let lead = xy(&input.target.velocity)
                        * (self.config.look_ahead / self.speed().max(1e-3));
                    lead * (self.config.run_in_tolerance / lead.norm().max(1e-9)).min(1.0)
                };
                (*pass, Vector2::new(point.x, point.y) + lead)
            }
            Route::Path(path, progress) => {
                let point = path.sample(progress + self.config.look_ahead);
                (
                    along(&path.sample(path.length()), self.config.run_in),
                    Vector2::new(point.x, point.y),
                )
            }
        };
        self.closest_approach = pass;
        // With every route blocked the base stops and turns on the spot toward the route it
        // would take, until a clear one opens (a base close in front of a container after a
        // drop cannot turn away at the minimum radius without touching it).
        let driving = if self.passed {
            &self.next
        } else {
            &self.current
        };
        // The direction of the turn is kept while the block lasts (reversed below when the
        // command check refuses it): a route point straight ahead, through what blocks the way,
        // would otherwise leave the base facing it for good; then it turns away from the
        // nearest known target.
        let blocked = driving.blocked() && !matches!(route, Route::Line(_));
        let (speed, wanted_omega) = if blocked {
            let offset = point - Vector2::new(b.x, b.y);
            let bearing = wrap_angle(offset.y.atan2(offset.x) - b.yaw);
            let limit = 0.5 * self.model.max_yaw_rate;
            let turn = *self.blocked_turn.get_or_insert_with(|| {
                if bearing.abs() > BLOCKED_STRAIGHT_AHEAD {
                    bearing.signum()
                } else {
                    let nearest = obstacles
                        .iter()
                        .min_by(|p, q| (*p - base_xy).norm().total_cmp(&(*q - base_xy).norm()));
                    nearest.map_or(1.0, |o| {
                        let away = o - base_xy;
                        if wrap_angle(away.y.atan2(away.x) - b.yaw) > 0.0 {
                            -1.0
                        } else {
                            1.0
                        }
                    })
                }
            });
            let wanted = if bearing.abs() > BLOCKED_STRAIGHT_AHEAD && bearing.signum() == turn {
                (2.0 * bearing).clamp(-limit, limit)
            } else {
                turn * limit
            };
            (0.0, wanted)
        } else {
            self.blocked_turn = None;
            self.blocked_reversals = 0;
            (speed, pursue(b, point, speed))
        };
        let backing = (self.backing_out > 0.0)
            .then(|| self.back_out(b, &obstacles))
            .flatten();
        let (speed, wanted_omega) = if let Some((speed, omega)) = backing {
            self.backing_out -= speed.abs() * input.dt.max(0.0);
            (speed, omega)
        } else {
            let (speed, guarded) = self.guard(b, speed, wanted_omega, &obstacles);
            self.backing_out = if speed < 0.0 { BACK_OUT_DISTANCE } else { 0.0 };
            // A blocked base whose turn the check refuses turns the other way round: kept, the
            // refused turn and the check's nearest clear one, the other way, alternated from
            // cycle to cycle, and the base stood wedged beside Exp 2's row (seed 28, 770 s).
            if blocked && guarded * wanted_omega <= 0.0 {
                self.blocked_turn = self.blocked_turn.map(|turn| -turn);
                self.blocked_reversals += 1;
            }
            // Refused both ways, the turn swings to and fro inside the wedge the check allows
            // (a square footprint facing a container close ahead: generated Fetch layouts
            // stood so until their timeout). The base backs out, and turns again from there.
            if self.blocked_reversals >= 2 {
                self.blocked_reversals = 0;
                self.blocked_turn = None;
                self.backing_out = BACK_OUT_DISTANCE;
            }
            (speed, guarded)
        };

        let max_change = self
            .config
            .yaw_acceleration(self.model.max_yaw_acceleration)
            * input.dt.max(0.0);
        let omega = wanted_omega
            .clamp(self.last_omega - max_change, self.last_omega + max_change)
            .clamp(-self.model.max_yaw_rate, self.model.max_yaw_rate);
        self.last_omega = omega;
        self.drive.command(speed, input.dt.max(0.0));

        let (time_to_range, range_entry_pose) = if self.passed {
            (0.0, *b)
        } else {
            self.time_to_range(b, &route, &input.target, self.drive.predict(speed.max(0.0)))
        };

        Ok(BaseControllerOutput {
            command: BaseVelocity { v: speed, omega },
            closest_approach: self.closest_approach,
            side: self.current.plan.map(|p| p.side).unwrap_or_default(),
            time_to_range,
            range_entry_pose,
            passed: self.passed,
            missed_passes: self.missed,
            gave_up: self.gave_up(),
        })
    }

    /// Whether the base has given up the current target: the reactive approach missed too
    /// (more than `moving_passes` passes missed). The base then drives on to the next target
    /// at v_F, and the mission is to report the task failed and go on.
    pub fn gave_up(&self) -> bool {
        self.config.pass_timeout > 0.0 && self.missed > self.config.moving_passes
    }

    /// Passes of the current target missed so far. A pass is missed when the base has been
    /// past ξ_C (or, on a reactive approach, in its slow zone) for `pass_timeout` with the
    /// task still not done: a reach that fell short, a grasp the arm could not finish. The
    /// base then comes around: the passed latch clears, the plan is chosen afresh from where
    /// the base is, and the latch waits for the base to be back on a run-in, well before ξ_C.
    /// From `moving_passes` missed passes on, the approach is the reactive one.
    pub fn missed_passes(&self) -> u32 {
        self.missed
    }

    /// `(v, ω)`, or the command nearest it that keeps the footprint clear of the known targets
    /// over `guard_horizon` (see [`BaseControllerConfig::guard_horizon`]).
    fn guard(&self, base: &BasePose, v: f64, omega: f64, obstacles: &[Vector2<f64>]) -> (f64, f64) {
        if self.config.guard_horizon <= 0.0 {
            return (v, omega);
        }
        let clear = |v: f64, omega: f64| self.clear_command(base, v, omega, obstacles);
        if clear(v, omega) {
            return (v, omega);
        }
        let turns = self.guard_turns(omega);
        // Standing still is always clear, and never a way out: on the spot only a turn counts,
        // and with no turn clear the base creeps on, as straight as it can; with no way on
        // either, it backs out.
        let creep = GUARD_CREEP * self.speed();
        [v, 0.5 * v, 0.0, creep]
            .into_iter()
            .find_map(|speed| {
                turns
                    .iter()
                    .find(|&&w| (speed > 0.0 || w != 0.0) && clear(speed, w))
                    .map(|&w| (speed, w))
            })
            .or_else(|| self.back_out(base, obstacles))
            .unwrap_or((0.0, 0.0))
    }

    /// The command that backs a wedged base out at the creep speed, as straight as is clear
    /// ([`BACK_OUT_DISTANCE`]), or `None` when no way back is clear either.
    fn back_out(&self, base: &BasePose, obstacles: &[Vector2<f64>]) -> Option<(f64, f64)> {
        let back = -GUARD_CREEP * self.speed();
        self.guard_turns(0.0)
            .into_iter()
            .find(|&w| self.clear_command(base, back, w, obstacles))
            .map(|w| (back, w))
    }

    /// The turn rates the command check tries, nearest `omega` first.
    fn guard_turns(&self, omega: f64) -> Vec<f64> {
        let max_rate = self.model.max_yaw_rate;
        let mut turns: Vec<f64> = (-GUARD_TURNS..=GUARD_TURNS)
            .map(|k| max_rate * k as f64 / GUARD_TURNS as f64)
            .collect();
        turns.sort_by(|a, b| (a - omega).abs().total_cmp(&(b - omega).abs()));
        turns
    }

    /// Whether `(v, ω)` from `base`, with ω ramping to it at the yaw acceleration limit, keeps
    /// the footprint `clearance` from every known target (or no closer than now) over
    /// `guard_horizon`.
    fn clear_command(
        &self,
        base: &BasePose,
        v: f64,
        omega: f64,
        obstacles: &[Vector2<f64>],
    ) -> bool {
        let horizon = self.config.guard_horizon;
        let acceleration = self
            .config
            .yaw_acceleration(self.model.max_yaw_acceleration);
        let steps = (horizon / GUARD_STEP).ceil() as usize;
        let mut pose = *base;
        let mut w = self.last_omega;
        let poses = (0..steps).map(move |_| {
            w += (omega - w).clamp(-acceleration * GUARD_STEP, acceleration * GUARD_STEP);
            pose.yaw = wrap_angle(pose.yaw + w * GUARD_STEP);
            pose.x += v * GUARD_STEP * pose.yaw.cos();
            pose.y += v * GUARD_STEP * pose.yaw.sin();
            pose
        });
        self.clear_poses(base, v.abs() * horizon, obstacles, poses)
    }

    /// Gives up the current pass (see [`BaseController::missed_passes`]); after the reactive
    /// one, the target ([`BaseController::gave_up`]).
    fn miss_pass(&mut self) {
        self.missed += 1;
        self.lingered = 0.0;
        if self.gave_up() {
            self.passed = true;
            return;
        }
        self.passed = false;
        self.rearm = true;
        self.current = Approach::default();
        self.next = Approach::default();
    }

    /// Whether the base is on the run-in of `pass` (ξ_C): on its line within the tolerance,
    /// heading along it, and not past ξ_C by more than the run-out.
    fn on_run_in(&self, base: &BasePose, pass: &BasePose, tolerance: f64) -> bool {
        let (u, e) = line_offset(base, pass);
        u >= -self.config.run_in - self.config.run_in_tolerance
            && u <= self.config.run_out
            && e.abs() <= tolerance
            && wrap_angle(base.yaw - pass.yaw).abs() <= std::f64::consts::FRAC_PI_4
            && (!self.rearm || u <= -0.5 * self.config.run_in)
    }

    /// Updates `approach` toward `target` (then the targets `ahead` of it, the next and the one
    /// after, where known) and returns the route to drive.
    ///
    /// The route is kept between steps and followed (its progress found by projecting the base
    /// onto it); it is planned again, with the choice of pass plan, when there is none, when the
    /// base is `replan_deviation` off it, when the target has moved `replan_deviation` since it
    /// was planned, and every `replan_period` (keeping the plan unless another is shorter by
    /// `replan_margin`). A route planned afresh every step would not be the one driven: the
    /// base lags each new shortest path a little, and from the lagging pose the shortest path
    /// can be another word (a loop), so the choice would jump.
    fn approach(
        &self,
        approach: &mut Approach,
        base: &BasePose,
        target: Vector2<f64>,
        ahead: [Option<Vector2<f64>>; 2],
        (obstacles, later): (&[Vector2<f64>], &[Vector2<f64>]),
        clock: f64,
    ) -> Route {
        let config = &self.config;
        let r_c = config.closest_approach_radius;
        let tolerance = config.run_in_tolerance;
        if approach.committed {
            match approach.plan {
                Some(plan) if self.on_run_in(base, &plan.pose(target, r_c), 2.0 * tolerance) => {
                    return Route::Line(plan.pose(target, r_c));
                }
                _ => {
                    approach.committed = false;
                    approach.route = None;
                }
            }
        }
        // Every route was blocked a moment ago: the base turns on the spot toward the route it
        // found, and the search (every plan, every Dubins word, every lead, the footprint along
        // each: tens of milliseconds when nothing is clear) is not run again every cycle.
        if let Some((at, path)) = approach.blocked_route
            && clock - at < BLOCKED_REPLAN_PERIOD
        {
            return Route::Path(path, 0.0);
        }
        let radius = self.turn_radius();
        // Worked out only when plans are scored, not on the steps that follow the kept route.
        let look_ahead = std::cell::OnceCell::new();
        // The targets still to come after the next one (the layout is in task order).
        let later_next = later.get(1..).unwrap_or_default();
        let ahead =
            || look_ahead.get_or_init(|| self.look_ahead(ahead, obstacles, later_next, radius));
        // Follow the kept route while it is valid.
        let mut kept_cost = None;
        if let (Some(route), Some(plan)) = (&mut approach.route, approach.plan) {
            let deviation = route.track(base);
            let moved = (target - route.target).norm();
            let valid = deviation <= config.replan_deviation && moved <= config.replan_deviation;
            let to_pass = route.path.length() - route.progress + config.run_in;
            let fresh = moved <= config.route_refresh_distance;
            if valid
                && fresh
                && (clock - route.planned_at < config.replan_period
                    || to_pass <= config.commit_distance)
            {
                return self.route_or_line(approach, base, target);
            }
            if to_pass <= config.commit_distance
                || (valid && clock - route.planned_at < config.replan_period)
            {
                // Close in (the arm is already reaching for the target), or the target moved a
                // little: the plan stays, only the route to it is planned again, so that the
                // route driven (and t_R along it) is the one to where the target is now.
                let planned_at = route.planned_at;
                approach.route = Some(KeptRoute {
                    path: self.reroute(base, &plan, target, radius, obstacles),
                    progress: 0.0,
                    target,
                    planned_at,
                });
                return self.route_or_line(approach, base, target);
            }
            if valid {
                let pass = plan.pose(target, r_c);
                let rest = DubinsPath::shortest(
                    &route.path.sample(route.progress),
                    &route.path.sample(route.path.length()),
                    route.path.radius,
                );
                kept_cost = Some(
                    route.path.length() - route.progress
                        + config.turn_cost * rest.turning()
                        + config.run_in
                        + config.run_out
                        + self.crossing_charge(&plan, target, later)
                        + self.next_leg(&along(&pass, config.run_out), ahead(), obstacles, radius),
                );
            }
        }
        let candidates = self.candidates(base, target);
        self.plan_searches.set(self.plan_searches.get() + 1);
        let mut best: Option<(PassPlan, f64)> = None;
        for plan in &candidates {
            if let Some(cost) = self.score(base, target, ahead(), plan, (obstacles, later), radius)
                && best.is_none_or(|(_, c)| cost < c)
            {
                best = Some((*plan, cost));
            }
        }
        let keep = matches!((best, kept_cost), (Some((_, b)), Some(k)) if k <= b + config.replan_margin)
            || (best.is_none() && kept_cost.is_some());
        if keep {
            if let Some(route) = &mut approach.route {
                route.planned_at = clock;
            }
            return self.route_or_line(approach, base, target);
        }
        let blocked = best.is_none();
        let plan = match best {
            Some((plan, _)) => plan,
            // Every route is blocked: the base turns on the spot (see `step`) toward the
            // shortest, blocked or not, and plans again after `BLOCKED_REPLAN_PERIOD`.
            None => candidates
                .iter()
                .map(|plan| {
                    let start = self.run_in_start(plan, target);
                    (*plan, DubinsPath::shortest(base, &start, radius).length())
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(plan, _)| plan)
                .unwrap_or(PassPlan {
                    side: PassSide::Left,
                    heading: base.yaw,
                }),
        };
        approach.plan = Some(plan);
        let path = self.route_to(base, &plan, target, radius, obstacles);
        if blocked {
            approach.route = None;
            approach.blocked_route = Some((clock, path));
            return Route::Path(path, 0.0);
        }
        approach.blocked_route = None;
        approach.route = Some(KeptRoute {
            path,
            progress: 0.0,
            target,
            planned_at: clock,
        });
        self.route_or_line(approach, base, target)
    }

    /// The run-in line once the base is on it (committing to the plan), else the kept route.
    fn route_or_line(
        &self,
        approach: &mut Approach,
        base: &BasePose,
        target: Vector2<f64>,
    ) -> Route {
        let plan = approach.plan.unwrap_or_default();
        let pass = plan.pose(target, self.config.closest_approach_radius);
        match &approach.route {
            Some(route) if !self.on_run_in(base, &pass, self.config.run_in_tolerance) => {
                Route::Path(route.path, route.progress)
            }
            _ => {
                approach.committed = true;
                Route::Line(pass)
            }
        }
    }

    /// The known positions of the mission's targets from task `first` on (the layout is in
    /// task order): the ones still to come.
    fn later_targets(&self, first: usize) -> &[Vector2<f64>] {
        self.layout.get(first..).unwrap_or_default()
    }

    /// [`BaseControllerConfig::crossing_cost`] when `plan`'s run-in to `target` leads over one
    /// of the `later` targets (within `crossing_width` of the line through the target along
    /// the pass heading, and before it by at most `run_in`), else 0. A later target at the
    /// target's own place (a place back where the pick was) is not another one.
    fn crossing_charge(
        &self,
        plan: &PassPlan,
        target: Vector2<f64>,
        later: &[Vector2<f64>],
    ) -> f64 {
        let config = &self.config;
        let direction = Vector2::new(plan.heading.cos(), plan.heading.sin());
        let crossed = later.iter().any(|p| {
            let offset = p - target;
            let before = -offset.dot(&direction);
            let aside = offset.perp(&direction).abs();
            offset.norm() > SAME_PLACE
                && before > 0.0
                && before <= config.run_in
                && aside <= config.crossing_width
        });
        if crossed { config.crossing_cost } else { 0.0 }
    }

    /// The start of `plan`'s run-in for a target at `target`: `run_in` before ξ_C.
    fn run_in_start(&self, plan: &PassPlan, target: Vector2<f64>) -> BasePose {
        along(
            &plan.pose(target, self.config.closest_approach_radius),
            -self.config.run_in,
        )
    }

    /// The route from `base` to the start of a kept `plan`'s run-in: [`Self::route_to`], or
    /// the same at the tight turning radius ([`BaseControllerConfig::tight_turn_radius`]) where
    /// that one is clear and saves a loop (turns less by more than π).
    fn reroute(
        &self,
        base: &BasePose,
        plan: &PassPlan,
        target: Vector2<f64>,
        radius: f64,
        obstacles: &[Vector2<f64>],
    ) -> DubinsPath {
        let wide = self.route_to(base, plan, target, radius, obstacles);
        let tight_radius = self.tight_turn_radius();
        // No route turns less than not at all: a wide route turning π or less has no loop to save.
        if tight_radius <= 0.0 || tight_radius >= radius || wide.turning() <= std::f64::consts::PI {
            return wide;
        }
        let start = self.run_in_start(plan, target);
        match self.clear_route(base, &start, tight_radius, obstacles) {
            Some(tight) if tight.turning() + std::f64::consts::PI < wide.turning() => tight,
            _ => wide,
        }
    }

    /// The route from `base` to the start of `plan`'s run-in: the shortest clear one, or the
    /// shortest blocked or not when none is clear.
    fn route_to(
        &self,
        base: &BasePose,
        plan: &PassPlan,
        target: Vector2<f64>,
        radius: f64,
        obstacles: &[Vector2<f64>],
    ) -> DubinsPath {
        let start = self.run_in_start(plan, target);
        self.clear_route(base, &start, radius, obstacles)
            .unwrap_or_else(|| DubinsPath::shortest(base, &start, radius))
    }

    /// The length of the route past `target` with `plan` and on toward the targets `ahead`,
    /// plus its crossing charge for the targets `later` ([`BaseController::crossing_charge`]),
    /// or `None` when the route to ξ_C or its run-in and run-out come within `clearance` of a
    /// known target.
    fn score(
        &self,
        base: &BasePose,
        target: Vector2<f64>,
        ahead: &Ahead,
        plan: &PassPlan,
        (obstacles, later): (&[Vector2<f64>], &[Vector2<f64>]),
        radius: f64,
    ) -> Option<f64> {
        let config = &self.config;
        let pass = plan.pose(target, config.closest_approach_radius);
        let straight = config.run_in + config.run_out;
        let mut cost = if self.on_run_in(base, &pass, config.run_in_tolerance) {
            let (u, _) = line_offset(base, &pass);
            if !self.clear_line(&along(&pass, u), config.run_out - u, obstacles) {
                return None;
            }
            config.run_out - u
        } else {
            let start = self.run_in_start(plan, target);
            let path = self.clear_route(base, &start, radius, obstacles)?;
            if !self.clear_line(&start, straight, obstacles) {
                return None;
            }
            path.length() + config.turn_cost * path.turning() + straight
        };
        cost += self.next_leg(&along(&pass, config.run_out), ahead, obstacles, radius);
        Some(cost + self.crossing_charge(plan, target, later))
    }

    /// The pass plans tried for a target at `target` from `from`: on each side, the heading of
    /// the tangent from `from` to its r_C circle ([`BaseController::tangent_plan`]) and the
    /// fixed headings ([`BaseController::fixed_plans`]).
    fn candidates(&self, from: &BasePose, target: Vector2<f64>) -> Vec<PassPlan> {
        let mut candidates = Vec::with_capacity(2 * self.config.heading_candidates + 2);
        for side in [PassSide::Left, PassSide::Right] {
            candidates.extend(self.tangent_plan(from, target, side));
            candidates.extend(self.fixed_plans(side));
        }
        candidates
    }

    /// The pass plan on `side` whose heading is the tangent from `from` to `target`'s r_C
    /// circle (none from inside it).
    fn tangent_plan(
        &self,
        from: &BasePose,
        target: Vector2<f64>,
        side: PassSide,
    ) -> Option<PassPlan> {
        let at = Vector2::new(from.x, from.y);
        tangent_point(at, target, self.config.closest_approach_radius, side)
            .map(|(_, heading)| PassPlan { side, heading })
    }

    /// The pass plans on `side` at `heading_candidates` headings evenly round the circle: the
    /// same from wherever the base comes.
    fn fixed_plans(&self, side: PassSide) -> impl Iterator<Item = PassPlan> {
        let n = self.config.heading_candidates;
        (0..n).map(move |k| PassPlan {
            side,
            heading: wrap_angle(k as f64 * std::f64::consts::TAU / n as f64),
        })
    }

    /// The targets `ahead` of the one being passed, with the part of the way on past the next
    /// one that does not depend on where the base comes from, worked out once per choice of
    /// pass plan: for each of the next target's fixed-heading plans, the start of its run-in
    /// and the leg from its run-out on to the target after ([`BaseController::tangent_leg`]),
    /// or `None` where its straight is blocked. The choice scores some 34 plans, each against
    /// every pass of the next target; the legs on (footprint clearance checks along every
    /// Dubins word) made a step of the base planner take up to 120 ms on Exp 2.
    fn look_ahead(
        &self,
        ahead: [Option<Vector2<f64>>; 2],
        obstacles: &[Vector2<f64>],
        later: &[Vector2<f64>],
        radius: f64,
    ) -> Ahead {
        let fixed = match ahead {
            [Some(next), Some(after)] => [PassSide::Left, PassSide::Right]
                .into_iter()
                .flat_map(|side| self.fixed_plans(side))
                .map(|plan| self.pass_on(&plan, next, after, obstacles, later, radius))
                .collect(),
            _ => Vec::new(),
        };
        Ahead {
            targets: ahead,
            fixed,
            later: later.to_vec(),
        }
    }

    /// For `plan` past `next`: the start of its run-in and the leg from the end of its run-out
    /// on to `after` (with the plan's crossing charge for the targets `later` than `next`), or
    /// `None` when its straight comes within clearance of a known target.
    fn pass_on(
        &self,
        plan: &PassPlan,
        next: Vector2<f64>,
        after: Vector2<f64>,
        obstacles: &[Vector2<f64>],
        later: &[Vector2<f64>],
        radius: f64,
    ) -> Option<(BasePose, f64)> {
        let straight = self.config.run_in + self.config.run_out;
        let start = self.run_in_start(plan, next);
        if !self.clear_line(&start, straight, obstacles) {
            return None;
        }
        let on = along(&start, straight);
        let crossing = self.crossing_charge(plan, next, later);
        Some((
            start,
            crossing + self.tangent_leg(&on, after, obstacles, radius),
        ))
    }

    /// The cost of the way on from `out` (the end of a run-out) past the targets `ahead`:
    /// 0 without a next target. With a target after the next, the cheapest pass of the next
    /// one (its shortest route, turning, run-in and run-out, whose straight keeps clear of the
    /// known targets) plus the leg from its run-out on to the one after
    /// ([`BaseController::tangent_leg`]); with the next target only, that leg to it. So the
    /// pass of each target is chosen for the two after it: a drop chosen without the pick that
    /// follows it sent the base round the far side of the pick-up row on every lap.
    fn next_leg(
        &self,
        out: &BasePose,
        ahead: &Ahead,
        obstacles: &[Vector2<f64>],
        radius: f64,
    ) -> f64 {
        let [Some(next), after] = ahead.targets else {
            return 0.0;
        };
        let Some(after) = after else {
            return self.tangent_leg(out, next, obstacles, radius);
        };
        let config = &self.config;
        let straight = config.run_in + config.run_out;
        let tangents = [PassSide::Left, PassSide::Right]
            .into_iter()
            .filter_map(|side| self.tangent_plan(out, next, side))
            .map(|plan| self.pass_on(&plan, next, after, obstacles, &ahead.later, radius));
        tangents
            .chain(ahead.fixed.iter().copied())
            .flatten()
            .map(|(start, on)| {
                let path = DubinsPath::shortest(out, &start, radius);
                path.length() + config.turn_cost * path.turning() + straight + on
            })
            .min_by(f64::total_cmp)
            .unwrap_or(BLOCKED_NEXT_LEG)
    }

    /// Length of the shortest route from `out` (the end of a run-out) to a tangent pose on
    /// `next`'s r_C circle, plus a detour charge if it comes within clearance of a known target;
    /// 0 from inside its circle.
    fn tangent_leg(
        &self,
        out: &BasePose,
        next: Vector2<f64>,
        obstacles: &[Vector2<f64>],
        radius: f64,
    ) -> f64 {
        [PassSide::Left, PassSide::Right]
            .into_iter()
            .filter_map(|side| {
                tangent_point(
                    Vector2::new(out.x, out.y),
                    next,
                    self.config.closest_approach_radius,
                    side,
                )
            })
            .map(|(point, heading)| {
                let goal = BasePose::new(point.x, point.y, heading);
                let (path, blocked) = match self.clear_route(out, &goal, radius, obstacles) {
                    Some(path) => (path, 0.0),
                    None => (DubinsPath::shortest(out, &goal, radius), BLOCKED_NEXT_LEG),
                };
                path.length() + self.config.turn_cost * path.turning() + blocked
            })
            .min_by(f64::total_cmp)
            .unwrap_or(0.0)
    }

    /// The shortest Dubins path from `from` to `to` whose footprint keeps clear of every
    /// obstacle (trying every word, shortest first, then the same after driving straight on a
    /// little: [`LEADS`]), if any.
    fn clear_route(
        &self,
        from: &BasePose,
        to: &BasePose,
        radius: f64,
        obstacles: &[Vector2<f64>],
    ) -> Option<DubinsPath> {
        LEADS.iter().find_map(|&lead| {
            DubinsPath::words_after(from, lead * radius, to, radius)
                .into_iter()
                .find(|path| self.clear_path(path, obstacles))
        })
    }

    /// Whether the base's footprint keeps clear of every obstacle all along `path`.
    fn clear_path(&self, path: &DubinsPath, obstacles: &[Vector2<f64>]) -> bool {
        let sampler = path.sampler();
        // On an arc the footprint's far corner moves by 1 + |corner| / radius per metre driven.
        let rate = 1.0 + self.model.half_extents.norm() / path.radius.max(1e-6);
        self.clear_sweep(&path.start, path.length(), rate, obstacles, |s| {
            sampler.sample(s)
        })
    }

    /// Whether the base's footprint keeps clear of every obstacle along the straight line
    /// `length` long from `start`.
    fn clear_line(&self, start: &BasePose, length: f64, obstacles: &[Vector2<f64>]) -> bool {
        let length = length.max(0.0);
        self.clear_sweep(start, length, 1.0, obstacles, |s| {
            along(start, s.min(length))
        })
    }

    /// Whether the footprint is clear ([`BaseController::clear_poses`]) at every
    /// `CLEARANCE_STEP` along a route `length` long from `start` (the last sample at or up to a
    /// step past its end), its pose at arc length `s` being `pose_at(s)`, on which no point of
    /// the footprint moves faster than `rate` m per metre driven. Samples that cannot be closer
    /// than the clear one before them (its margin over its threshold, divided by `rate`,
    /// reaches past them) are not worked out: the answer is that of checking every sample, at
    /// a fraction of the cost where the obstacles are far.
    fn clear_sweep(
        &self,
        start: &BasePose,
        length: f64,
        rate: f64,
        obstacles: &[Vector2<f64>],
        pose_at: impl Fn(f64) -> BasePose,
    ) -> bool {
        let near = self.near_obstacles(start, length, obstacles);
        if near.is_empty() {
            return true;
        }
        let steps = (length / CLEARANCE_STEP).ceil() as usize;
        let mut k = 0;
        while k <= steps {
            let s = k as f64 * CLEARANCE_STEP;
            let Some(margin) = self.footprint_margin(&pose_at(s), &near) else {
                return false;
            };
            // Every pose up to `free` further on keeps a margin of at least 0.
            let free = (margin - 1e-9).max(0.0) / rate;
            k = (((s + free) / CLEARANCE_STEP).floor() as usize + 1).max(k + 1);
        }
        true
    }

    /// Whether, at every one of `poses` (a route `length` long from `start`), the footprint is
    /// `obstacle_radius + clearance` from every obstacle, or at least no closer than at the
    /// start (a base that starts too close, e.g. right after a drop, may still drive away).
    fn clear_poses(
        &self,
        start: &BasePose,
        length: f64,
        obstacles: &[Vector2<f64>],
        mut poses: impl Iterator<Item = BasePose>,
    ) -> bool {
        let near = self.near_obstacles(start, length, obstacles);
        poses.all(|pose| self.footprint_margin(&pose, &near).is_some())
    }

    /// The obstacles a route `length` long from `start` could come within
    /// `obstacle_radius + clearance` of, each with the footprint distance it must keep: that
    /// one, or at least (1 mm short of) its distance at `start`.
    fn near_obstacles(
        &self,
        start: &BasePose,
        length: f64,
        obstacles: &[Vector2<f64>],
    ) -> Vec<(Vector2<f64>, f64)> {
        let required = self.config.obstacle_radius + self.config.clearance;
        let reach = length + required + self.model.half_extents.norm();
        let origin = Vector2::new(start.x, start.y);
        obstacles
            .iter()
            .filter(|o| (*o - origin).norm() <= reach)
            .map(|o| {
                let at_start = self.footprint_distance(start, o);
                (*o, required.min(at_start - 1e-3))
            })
            .collect()
    }

    /// The smallest margin of the footprint at `pose` over the distances the `near` obstacles
    /// must keep ([`BaseController::near_obstacles`]), or `None` when one is closer.
    fn footprint_margin(&self, pose: &BasePose, near: &[(Vector2<f64>, f64)]) -> Option<f64> {
        let (sin, cos) = pose.yaw.sin_cos();
        near.iter().try_fold(f64::INFINITY, |margin, (o, keep)| {
            let d = self.footprint_distance_rotated(pose, sin, cos, o);
            (d >= *keep).then_some(margin.min(d - keep))
        })
    }

    /// Distance from the base's footprint (a rectangle about the base frame's origin) at
    /// `pose` to the point `o`, m (0 inside).
    fn footprint_distance(&self, pose: &BasePose, o: &Vector2<f64>) -> f64 {
        let (sin, cos) = pose.yaw.sin_cos();
        self.footprint_distance_rotated(pose, sin, cos, o)
    }

    /// [`BaseController::footprint_distance`] with the sine and cosine of `pose.yaw` given.
    fn footprint_distance_rotated(
        &self,
        pose: &BasePose,
        sin: f64,
        cos: f64,
        o: &Vector2<f64>,
    ) -> f64 {
        let d = o - Vector2::new(pose.x, pose.y);
        let local = Vector2::new(d.x * cos + d.y * sin, -d.x * sin + d.y * cos);
        let half = self.model.half_extents;
        Vector2::new(
            (local.x.abs() - half.x).max(0.0),
            (local.y.abs() - half.y).max(0.0),
        )
        .norm()
    }

    /// t_R along `route` at constant `speed`, with the target moving at its estimated velocity.
    /// Returns the time and the base pose then.
    fn time_to_range(
        &self,
        base: &BasePose,
        route: &Route,
        target: &TargetEstimate,
        speed: f64,
    ) -> (f64, BasePose) {
        let range = self.model.manipulation_range;
        // A zero speed (from a degenerate configuration) would make the prediction NaN.
        let speed = speed.max(1e-3);
        let target_xy = xy(&target.position);
        let target_velocity = xy(&target.velocity);
        // On the run-in the base follows the line through ξ_C, which moves with the target: it
        // drives along the line and moves with the target's motion across it.
        let across = |pass: &BasePose| {
            let normal = Vector2::new(-pass.yaw.sin(), pass.yaw.cos());
            normal * normal.dot(&target_velocity)
        };
        let pose_at = |s: f64| match route {
            Route::Path(path, progress) => path.sample(progress + s),
            Route::Line(pass) => {
                let drift = across(pass) * (s / speed);
                along(
                    &BasePose::new(base.x + drift.x, base.y + drift.y, pass.yaw),
                    s,
                )
            }
        };
        let route_length = match route {
            Route::Path(path, progress) => path.length() - progress,
            Route::Line(_) => 0.0,
        };
        // No point of the arm base closes on the target faster than this.
        let closing = speed
            + target_velocity.norm()
            + self.model.max_yaw_rate * self.model.arm_base.norm()
            + 1e-6;
        let horizon = (route_length + self.config.run_in + self.config.run_out) / speed + 10.0;
        let mut t = 0.0;
        let mut pose = *base;
        let mut closest = (f64::INFINITY, 0.0, *base);
        for _ in 0..10_000 {
            let distance =
                (self.model.arm_base_at(&pose) - (target_xy + target_velocity * t)).norm();
            if distance <= range {
                return (t, pose);
            }
            if distance < closest.0 {
                closest = (distance, t, pose);
            }
            if t > horizon {
                break;
            }
            t += ((distance - range) / closing).max(0.02);
            pose = pose_at(speed * t);
        }
        (closest.1, closest.2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use std::f64::consts::FRAC_PI_2;

    const DT: f64 = 0.02;

    fn frankie_like() -> BaseModel {
        BaseModel {
            manipulation_range: 0.75,
            arm_base: Vector2::new(0.15, 0.0),
            max_speed: 1.2,
            max_yaw_rate: 1.5,
            max_yaw_acceleration: 2.0,
            half_extents: Vector2::new(0.34, 0.235),
            facing_reach: None,
        }
    }

    #[test]
    fn a_wide_base_passes_farther_out_to_keep_its_clearance() {
        let config = BaseControllerConfig::default();
        let frankie = BaseController::new(config.clone(), frankie_like());
        assert_eq!(frankie.config().closest_approach_radius, 0.6);
        let husky = BaseModel {
            half_extents: Vector2::new(0.495, 0.335),
            ..frankie_like()
        };
        let husky = BaseController::new(config, husky);
        assert!((husky.config().closest_approach_radius - 0.655).abs() < 1e-12);
    }

    #[test]
    fn the_linger_stop_keeps_the_target_within_the_facing_joint_s_reach() {
        // Fetch-like: the shoulder pan 0.12 m ahead of the arm base (the torso), stopping at ±92°.
        let model = BaseModel {
            arm_base: Vector2::new(-0.087, 0.0),
            facing_reach: Some(FacingReach {
                axis: Vector2::new(0.033, 0.0),
                min_bearing: -1.6056,
                max_bearing: 1.6056,
            }),
            ..frankie_like()
        };
        let base = BasePose::new(1.0, 0.0, 0.0);
        // A target 0.6 m to the right: with 0.2 rad to spare the pan faces at most 1.4056 rad,
        // short of abeam, so the target must stay 0.6·tan(0.165) ahead of the pan axis.
        let allowed = model
            .max_target_behind(&base, &Vector2::new(1.5, -0.6), 0.2)
            .expect("the pan stops short of a full turn");
        let expected = 0.6 * (1.4056 - std::f64::consts::FRAC_PI_2).tan() + 0.12;
        assert!((allowed - expected).abs() < 1e-9, "{allowed} vs {expected}");
        // The same on the left, and no limit for a joint that turns all the way round.
        let left = model.max_target_behind(&base, &Vector2::new(1.5, 0.6), 0.2);
        assert!((left.unwrap() - expected).abs() < 1e-9);
        assert_eq!(
            frankie_like().max_target_behind(&base, &Vector2::new(1.5, 0.6), 0.2),
            None
        );
    }

    /// Integrates a unicycle as docs/algorithms.md §1 says: rotate by ω·dt, then move v·dt along the
    /// new heading.
    fn integrate(base: &mut BasePose, command: BaseVelocity, dt: f64) {
        base.yaw = wrap_angle(base.yaw + command.omega * dt);
        base.x += command.v * dt * base.yaw.cos();
        base.y += command.v * dt * base.yaw.sin();
    }

    /// One step of `controller` on task `task_index`, toward the standing `target` and then
    /// `next`, with `base` moved by the command.
    fn step_toward(
        controller: &mut BaseController,
        base: &mut BasePose,
        task_index: usize,
        target: Vector3<f64>,
        next: Vector3<f64>,
    ) -> BaseControllerOutput {
        let out = controller
            .step(&BaseControllerInput {
                task_index,
                base: *base,
                target: TargetEstimate::fixed(target),
                next_target: next,
                after_next: None,
                dt: DT,
            })
            .unwrap();
        integrate(base, out.command, DT);
        out
    }

    struct Pass {
        /// Smallest base–target distance over the run, m.
        min_distance: f64,
        /// Cross product heading × (target − base) at the closest approach: < 0 means the target
        /// was on the right.
        target_side: f64,
        /// Side reported by the controller at the closest approach.
        side: PassSide,
        /// Every commanded forward speed, and whether the target was passed then.
        speeds: Vec<(f64, bool)>,
        /// Time of the first step reporting "passed", s.
        passed_at: Option<f64>,
        /// Smallest distance from the base to the next target over the run, m.
        min_distance_to_next: f64,
    }

    fn drive_past(
        config: BaseControllerConfig,
        start: BasePose,
        target: Vector3<f64>,
        target_velocity: Vector3<f64>,
        next: Vector3<f64>,
        duration: f64,
    ) -> Pass {
        let mut controller = BaseController::new(config, frankie_like());
        let mut base = start;
        let mut pass = Pass {
            min_distance: f64::INFINITY,
            target_side: 0.0,
            side: PassSide::Left,
            speeds: Vec::new(),
            passed_at: None,
            min_distance_to_next: f64::INFINITY,
        };
        let steps = (duration / DT) as usize;
        for k in 0..steps {
            let t = k as f64 * DT;
            let position = target + target_velocity * t;
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target: TargetEstimate {
                        position,
                        velocity: target_velocity,
                    },
                    next_target: next,
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            let to_target = Vector2::new(position.x - base.x, position.y - base.y);
            let distance = to_target.norm();
            if distance < pass.min_distance {
                pass.min_distance = distance;
                pass.target_side = Vector2::new(base.yaw.cos(), base.yaw.sin()).perp(&to_target);
                pass.side = out.side;
            }
            if out.passed && pass.passed_at.is_none() {
                pass.passed_at = Some(t);
            }
            assert!(out.command.omega.is_finite() && out.command.omega.abs() <= 1.5);
            pass.speeds.push((out.command.v, out.passed));
            integrate(&mut base, out.command, DT);
            pass.min_distance_to_next = pass
                .min_distance_to_next
                .min(Vector2::new(next.x - base.x, next.y - base.y).norm());
        }
        pass
    }

    fn assert_passes(pass: &Pass, side: PassSide) {
        eprintln!("closest approach {:.4} m", pass.min_distance);
        assert!(
            (pass.min_distance - 0.6).abs() < 0.05,
            "closest approach {:.3} m, expected 0.6 ± 0.05",
            pass.min_distance
        );
        assert_eq!(pass.side, side);
        match side {
            PassSide::Left => assert!(pass.target_side < 0.0, "target should be on the right"),
            PassSide::Right => assert!(pass.target_side > 0.0, "target should be on the left"),
        }
        assert!(pass.passed_at.is_some(), "the passed latch never set");
        // v_F until the target is passed; then, the task never being done here, half of it.
        for &(v, passed) in &pass.speeds {
            let expected = if passed { 0.15 } else { 0.3 };
            assert!((v - expected).abs() < 1e-12, "{v} (passed: {passed})");
        }
    }

    /// The default config, except that the base neither stops behind a passed target nor
    /// comes around for it: the tasks of these drives never finish (there is no arm), and the
    /// stop and the second approach are tested on their own
    /// (`a_pending_target_falling_behind_slows_the_base_to_a_stop`,
    /// `a_missed_pass_comes_around_and_then_stops_beside_the_target`).
    fn drive_past_config() -> BaseControllerConfig {
        BaseControllerConfig {
            linger_stop_distance: 0.0,
            pass_timeout: 0.0,
            ..BaseControllerConfig::default()
        }
    }

    /// The configurations the drives run with (one element, so the tests can loop over
    /// variants).
    fn configs() -> [BaseControllerConfig; 1] {
        [drive_past_config()]
    }

    #[test]
    fn passes_a_static_target_at_r_c_on_the_side_of_a_left_next_target() {
        for config in configs() {
            let pass = drive_past(
                config,
                BasePose::new(0.0, 0.0, 0.0),
                Vector3::new(3.0, 0.0, 0.45),
                Vector3::zeros(),
                Vector3::new(5.0, 2.0, 0.35),
                40.0,
            );
            assert_passes(&pass, PassSide::Left);
            // After passing, the base heads for the next target's r_C circle: it goes by the
            // next target too, at about r_C, never at it.
            assert!(
                (0.5..0.75).contains(&pass.min_distance_to_next),
                "went by the next target at {:.3} m",
                pass.min_distance_to_next
            );
        }
    }

    #[test]
    fn passes_a_static_target_at_r_c_on_the_side_of_a_right_next_target() {
        for config in configs() {
            let pass = drive_past(
                config,
                BasePose::new(0.0, 0.0, 0.3),
                Vector3::new(3.0, 0.5, 0.45),
                Vector3::zeros(),
                Vector3::new(5.0, -2.0, 0.35),
                40.0,
            );
            assert_passes(&pass, PassSide::Right);
            // After passing, the base heads for the next target's r_C circle: it goes by the
            // next target too, at about r_C, never at it.
            assert!(
                (0.5..0.75).contains(&pass.min_distance_to_next),
                "went by the next target at {:.3} m",
                pass.min_distance_to_next
            );
        }
    }

    #[test]
    fn passes_a_slowly_moving_target_at_r_c() {
        for (velocity, next, side) in [
            (
                Vector3::new(0.0, 0.03, 0.0),
                Vector3::new(5.0, 1.0, 0.35),
                PassSide::Left,
            ),
            (
                Vector3::new(-0.03, 0.0, 0.0),
                Vector3::new(5.0, -1.0, 0.35),
                PassSide::Right,
            ),
            (
                Vector3::new(0.02, -0.02, 0.0),
                Vector3::new(5.0, -1.0, 0.35),
                PassSide::Right,
            ),
            (
                Vector3::new(0.03, 0.0, 0.0),
                Vector3::new(3.5, 3.0, 0.35),
                PassSide::Left,
            ),
        ] {
            for config in configs() {
                let pass = drive_past(
                    config,
                    BasePose::new(0.0, 0.0, 0.0),
                    Vector3::new(3.0, 0.0, 0.45),
                    velocity,
                    next,
                    15.0,
                );
                assert_passes(&pass, side);
            }
        }
    }

    #[test]
    fn a_pending_target_falling_behind_slows_the_base_to_a_stop() {
        let config = BaseControllerConfig::default();
        let model = frankie_like();
        // The base heads along +x; the target is 0.5 m to its left (within r_C: passed),
        // `behind` m behind the arm's base.
        let speed_with_target_behind = |behind: f64| {
            let mut controller = BaseController::new(config.clone(), model);
            let target = Vector3::new(model.arm_base.x - behind, 0.5, 0.45);
            controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base: BasePose::new(0.0, 0.0, 0.0),
                    target: TargetEstimate::fixed(target),
                    next_target: Vector3::new(6.0, 0.0, 0.35),
                    after_next: None,
                    dt: 0.005,
                })
                .unwrap()
                .command
                .v
        };
        let linger = config.forward_speed * config.linger_speed_fraction;
        let stop = config.linger_stop_distance;
        assert!((speed_with_target_behind(0.0) - linger).abs() < 1e-9);
        let half = speed_with_target_behind(0.5 * stop);
        assert!((half - 0.5 * linger).abs() < 1e-9, "{half}");
        assert_eq!(speed_with_target_behind(stop + 0.1), 0.0);
    }

    #[test]
    fn a_missed_pass_comes_around_and_then_stops_beside_the_target() {
        // The task never ends (no arm): after `pass_timeout` past the target the base comes
        // around for a second pass; that one missed too (`moving_passes` = 2), the third
        // approach is the reactive one, to a stop with the target abeam of the arm's base.
        let config = BaseControllerConfig::default();
        let model = frankie_like();
        let mut controller = BaseController::new(config.clone(), model);
        let target = Vector3::new(3.0, 0.0, 0.45);
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        // Per pass (index = passes missed before it): the closest the base came to the target.
        let mut closest = vec![f64::INFINITY; 3];
        let mut stopped_beside = None;
        for k in 0..(150.0 / DT) as usize {
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target: TargetEstimate::fixed(target),
                    next_target: Vector3::new(8.0, 0.0, 0.35),
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            assert_eq!(out.missed_passes, controller.missed_passes());
            let pass = (out.missed_passes as usize).min(2);
            let at = Vector2::new(base.x, base.y);
            closest[pass] = closest[pass].min((xy(&target) - at).norm());
            if out.missed_passes == 2 && out.command.v == 0.0 && stopped_beside.is_none() {
                let heading = Vector2::new(base.yaw.cos(), base.yaw.sin());
                let ahead = (xy(&target) - model.arm_base_at(&base)).dot(&heading);
                stopped_beside = Some((k as f64 * DT, ahead, (xy(&target) - at).norm()));
            }
            integrate(&mut base, out.command, DT);
        }
        // Every pass, the reactive one too, goes by the target at about r_C.
        for d in &closest {
            assert!((d - 0.6).abs() < 0.1, "passes came within {closest:?}");
        }
        let (t, ahead, distance) = stopped_beside.expect("the reactive approach never stopped");
        assert!(
            ahead.abs() < 0.02,
            "stopped with the target {ahead:.3} m ahead (t = {t:.1} s)"
        );
        assert!(
            (distance - 0.6).abs() < 0.1,
            "stopped {distance:.3} m from the target"
        );
        // Waiting there another `pass_timeout` missed the third pass as well: the base gives
        // the target up and drives on to the next one, at v_F.
        assert_eq!(controller.missed_passes(), 3);
        assert!(controller.gave_up());
        assert!(base.x > 6.0 && base.y.abs() < 1.0, "gave up at {base:?}");
    }

    #[test]
    fn a_command_into_a_known_target_is_turned_aside() {
        let controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let base = BasePose::new(0.0, 0.0, 0.0);
        // Nothing near: the command stands.
        assert_eq!(controller.guard(&base, 0.3, 0.1, &[]), (0.3, 0.1));
        let far = [Vector2::new(3.0, 0.0)];
        assert_eq!(controller.guard(&base, 0.3, 0.0, &far), (0.3, 0.0));
        // A platform 0.85 m ahead: the front (0.34 m out) is 0.29 m from its circle, and a
        // second at 0.3 m/s straight on would bring it within the clearance. No turn the base
        // can get into within the second clears it at that speed (ω ramps at the limit): it
        // goes on at half the speed, straight on as asked.
        let ahead = [Vector2::new(0.85, 0.0)];
        assert_eq!(controller.guard(&base, 0.3, 0.0, &ahead), (0.15, 0.0));
        // Ahead to the left, a turn to the right clears it at the full speed.
        let aside = [Vector2::new(0.85, 0.25)];
        let (v, omega) = controller.guard(&base, 0.3, 0.0, &aside);
        assert!(v == 0.3 && omega < 0.0, "({v}, {omega})");
        // Pressed against it, where a turn on the spot or creeping on would bring a corner
        // closer, the base backs out straight at the creep speed; with another known target
        // close behind it too, it stands.
        let touching = [Vector2::new(0.6, 0.0)];
        let creep = GUARD_CREEP * 0.3;
        assert_eq!(controller.guard(&base, 0.3, 0.0, &touching), (-creep, 0.0));
        let sandwiched = [Vector2::new(0.6, 0.0), Vector2::new(-0.6, 0.0)];
        assert_eq!(controller.guard(&base, 0.3, 0.0, &sandwiched), (0.0, 0.0));
        // Beside it, stopped and asked to turn toward it, the base turns on the spot no faster
        // than keeps the front corner clear within the second; never not at all.
        let beside = [Vector2::new(0.2, 0.55)];
        let (v, omega) = controller.guard(&base, 0.0, 0.5, &beside);
        assert!(v == 0.0 && omega != 0.0 && omega < 0.5, "({v}, {omega})");
    }

    #[test]
    fn a_wedged_base_backs_out_its_distance_and_then_drives_on() {
        // A platform pressed against the front of the base, the target beyond it: no command
        // forward or on the spot is clear. The base backs out BACK_OUT_DISTANCE, straight,
        // before it drives on, round the platform and past the target at r_C; backing out
        // only until a forward command cleared, it drove straight back in.
        let platform = Vector3::new(0.6, 0.0, 0.45);
        let target = Vector3::new(2.5, 0.0, 0.45);
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like())
            .with_layout(&[platform, target]);
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        let mut backed = 0.0;
        let mut drove_on = false;
        let mut closest = f64::INFINITY;
        for step in 0..(16.0 / DT) as usize {
            let out = step_toward(&mut controller, &mut base, 1, target, target);
            if step == 0 {
                assert!(out.command.v < 0.0, "{:?}", out.command);
            }
            if out.command.v < 0.0 {
                assert!(!drove_on, "backed out again after driving on");
                backed -= out.command.v * DT;
            } else if out.command.v > 0.0 {
                drove_on = true;
            }
            closest = closest.min((xy(&target) - Vector2::new(base.x, base.y)).norm());
        }
        assert!(
            (backed - BACK_OUT_DISTANCE).abs() < 0.02,
            "backed out {backed:.3} m"
        );
        assert!(drove_on);
        assert!(
            (closest - 0.6).abs() < 0.1,
            "passed {closest:.3} m from the target"
        );
    }

    #[test]
    fn a_square_base_facing_a_container_close_ahead_backs_out_instead_of_swinging_for_good() {
        // Generated Fetch layout 18 after its first drop: the container 0.6 m ahead and to the
        // right, the next pick 2 m behind. A turn on the spot out of the way is refused beyond
        // a wedge either side (the square footprint's corners come nearer the container); the
        // base swung to and fro in that wedge until the trial's timeout.
        let fetch_like = BaseModel {
            arm_base: Vector2::new(0.0, 0.0),
            half_extents: Vector2::new(0.28, 0.28),
            ..frankie_like()
        };
        let container = Vector3::new(-2.141, -4.088, 0.35);
        let pick = Vector3::new(-4.570, -4.413, 0.45);
        let next = Vector3::new(-5.535, -6.503, 0.35);
        let layout = [Vector3::new(-2.898, -2.093, 0.45), container, pick, next];
        let mut controller =
            BaseController::new(BaseControllerConfig::default(), fetch_like).with_layout(&layout);
        let start = BasePose::new(-2.597, -3.688, -0.7);
        let mut base = start;
        let mut nearest_container = f64::INFINITY;
        for _ in 0..(20.0 / DT) as usize {
            step_toward(&mut controller, &mut base, 2, pick, next);
            nearest_container =
                nearest_container.min((xy(&container) - Vector2::new(base.x, base.y)).norm());
        }
        let moved = (Vector2::new(base.x - start.x, base.y - start.y)).norm();
        assert!(moved > 1.0, "the base stood at {base:?}");
        assert!(
            nearest_container > 0.5,
            "came {nearest_container:.3} m from the container"
        );
    }

    #[test]
    fn a_base_boxed_in_turns_on_the_spot_and_searches_four_times_a_second() {
        // Known targets all round, 0.75 m off: no route to the pass keeps clear of them.
        let ring: Vec<Vector3<f64>> = (0..8)
            .map(|k| {
                let angle = k as f64 * std::f64::consts::FRAC_PI_4;
                Vector3::new(0.75 * angle.cos(), 0.75 * angle.sin(), 0.45)
            })
            .collect();
        let mut controller =
            BaseController::new(BaseControllerConfig::default(), frankie_like()).with_layout(&ring);
        let dt = 0.005;
        let mut turned = 0.0;
        for _ in 0..200 {
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base: BasePose::new(0.0, 0.0, 0.0),
                    target: TargetEstimate::fixed(Vector3::new(3.0, 2.0, 0.45)),
                    next_target: Vector3::new(-3.0, 2.0, 0.35),
                    after_next: None,
                    dt,
                })
                .unwrap();
            assert_eq!(out.command.v, 0.0);
            turned += out.command.omega.abs() * dt;
        }
        assert!(turned > 0.0, "the boxed-in base stood still");
        // One search on the first step, then one every BLOCKED_REPLAN_PERIOD: four or five in
        // the second, not two hundred.
        let searches = controller.plan_searches();
        assert!((4..=5).contains(&searches), "{searches} searches in 1 s");
    }

    #[test]
    fn the_clearance_sweep_agrees_with_checking_every_sample() {
        use rand::{RngExt, SeedableRng};
        let controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let point = |rng: &mut rand_chacha::ChaCha8Rng, half: f64| {
            Vector2::new(rng.random_range(-half..half), rng.random_range(-half..half))
        };
        let (mut clear, mut blocked) = (0, 0);
        for _ in 0..300 {
            let (a, b) = (point(&mut rng, 2.0), point(&mut rng, 2.0));
            let start = BasePose::new(a.x, a.y, rng.random_range(-3.2..3.2));
            let goal = BasePose::new(b.x, b.y, rng.random_range(-3.2..3.2));
            let obstacles: Vec<_> = (0..6).map(|_| point(&mut rng, 3.0)).collect();
            let radius = rng.random_range(0.3..1.2);
            for path in DubinsPath::words_after(&start, rng.random_range(0.0..1.0), &goal, radius) {
                let length = path.length();
                let sampler = path.sampler();
                let steps = (length / CLEARANCE_STEP).ceil() as usize;
                let every = (0..=steps).map(|k| sampler.sample(k as f64 * CLEARANCE_STEP));
                let expected = controller.clear_poses(&path.start, length, &obstacles, every);
                assert_eq!(
                    controller.clear_path(&path, &obstacles),
                    expected,
                    "{path:?}"
                );
                let line = controller.clear_poses(
                    &start,
                    length,
                    &obstacles,
                    (0..=steps).map(|k| along(&start, (k as f64 * CLEARANCE_STEP).min(length))),
                );
                assert_eq!(controller.clear_line(&start, length, &obstacles), line);
                if expected { clear += 1 } else { blocked += 1 }
            }
        }
        assert!(
            clear > 100 && blocked > 100,
            "{clear} clear, {blocked} blocked"
        );
    }

    #[test]
    fn starting_inside_r_c_counts_as_passed_and_heads_for_the_next_target() {
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let out = controller
            .step(&BaseControllerInput {
                task_index: 0,
                base: BasePose::new(0.0, 0.0, 0.0),
                target: TargetEstimate::fixed(Vector3::new(0.3, 0.2, 0.45)),
                next_target: Vector3::new(0.0, 3.0, 0.35),
                after_next: None,
                // A long step, so that the turn-acceleration limit lets the command through.
                dt: 1.0,
            })
            .unwrap();
        assert!(out.passed);
        assert_eq!(out.time_to_range, 0.0);
        // The next target is 3 m away, 90° to the left: the route turns left, and ξ_C is the
        // next target's, r_C from it.
        assert!(out.command.omega > 0.1, "{}", out.command.omega);
        let pass = Vector2::new(out.closest_approach.x, out.closest_approach.y);
        assert!(((pass - Vector2::new(0.0, 3.0)).norm() - 0.6).abs() < 1e-9);
    }

    #[test]
    fn frankie_model_comes_from_its_config_and_urdf() {
        let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let robot = Robot::load(&config_dir, "frankie").unwrap();
        let model = BaseModel::from_robot(&robot);
        assert_eq!(model.manipulation_range, 0.75);
        assert!((model.arm_base - Vector2::new(0.15, 0.0)).norm() < 1e-12);
        assert_eq!((model.max_speed, model.max_yaw_rate), (1.2, 1.5));
    }

    #[test]
    fn the_plan_holds_while_the_next_target_jitters() {
        // The next target is almost straight ahead: both sides cost about the same, and noise
        // on its position must not flip the side while driving.
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        let mut sides = Vec::new();
        for k in 0..300 {
            let jitter = if k % 2 == 0 { 0.1 } else { -0.1 };
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target: TargetEstimate::fixed(Vector3::new(3.0, 0.0, 0.45)),
                    next_target: Vector3::new(6.0, jitter, 0.35),
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            if !out.passed {
                sides.push(out.side);
            }
            integrate(&mut base, out.command, DT);
        }
        assert!(sides.windows(2).all(|w| w[0] == w[1]), "{sides:?}");
    }

    #[test]
    fn time_to_range_counts_down_and_matches_the_actual_entry() {
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let target = Vector3::new(4.0, 0.0, 0.45);
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        let mut predictions = Vec::new();
        let mut entered_at = None;
        for k in 0..1000 {
            let t = k as f64 * DT;
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target: TargetEstimate::fixed(target),
                    next_target: Vector3::new(7.0, 1.0, 0.35),
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            let model = controller.model();
            let in_range =
                (model.arm_base_at(&base) - xy(&target)).norm() <= model.manipulation_range;
            if entered_at.is_none() && in_range {
                entered_at = Some(t);
                assert_eq!(out.time_to_range, 0.0);
            }
            if entered_at.is_none() {
                assert!(out.time_to_range > 0.0);
            }
            predictions.push((t, out.time_to_range));
            integrate(&mut base, out.command, DT);
        }
        let entered_at = entered_at.expect("never entered manipulation range");
        // Once the base is on its tangent line (after the first 2 s) the prediction is exact to
        // within a few steps.
        for &(t, t_r) in predictions
            .iter()
            .filter(|(t, _)| (2.0..entered_at).contains(t))
        {
            assert!(
                (t + t_r - entered_at).abs() < 0.1,
                "at t = {t:.2} s predicted entry at {:.2} s, actual {entered_at:.2} s",
                t + t_r
            );
        }
    }

    #[test]
    fn time_to_range_allows_for_a_drive_slower_than_its_command() {
        // The drive goes at 0.88 of what it is told, and odometry arrives every fourth step
        // (50 Hz against 200 Hz). Once the drive's ratio is measured, t_R predicts the entry
        // into manipulation range to within a few steps; at the commanded speed it came up to
        // 1.5 s early.
        let run = |gain: f64| {
            let mut controller =
                BaseController::new(BaseControllerConfig::default(), frankie_like());
            let target = Vector3::new(5.0, 0.0, 0.45);
            let mut base = BasePose::new(0.0, 0.0, 0.0);
            let mut odometry = base;
            let mut predictions = Vec::new();
            let mut entered_at = None;
            for k in 0..2000 {
                let t = k as f64 * DT;
                if k % 4 == 0 {
                    odometry = base;
                }
                let out = controller
                    .step(&BaseControllerInput {
                        task_index: 0,
                        base: odometry,
                        target: TargetEstimate::fixed(target),
                        next_target: Vector3::new(8.0, 1.0, 0.35),
                        after_next: None,
                        dt: DT,
                    })
                    .unwrap();
                let model = controller.model();
                let in_range =
                    (model.arm_base_at(&base) - xy(&target)).norm() <= model.manipulation_range;
                if entered_at.is_none() && in_range {
                    entered_at = Some(t);
                }
                predictions.push((t, out.time_to_range));
                let actual = BaseVelocity {
                    v: gain * out.command.v,
                    omega: out.command.omega,
                };
                integrate(&mut base, actual, DT);
            }
            let entered_at = entered_at.expect("never entered manipulation range");
            predictions
                .iter()
                .filter(|(t, _)| (4.0..entered_at - 0.5).contains(t))
                .map(|&(t, t_r)| (t + t_r - entered_at).abs())
                .fold(0.0, f64::max)
        };
        let error = run(0.88);
        assert!(error < 0.1, "predicted entry off by up to {error:.2} s");
        // A drive that does what it is told is predicted as well as before.
        let exact = run(1.0);
        assert!(exact < 0.1, "predicted entry off by up to {exact:.2} s");
    }

    #[test]
    fn speed_and_yaw_rate_respect_the_base_limits() {
        let model = BaseModel {
            max_speed: 0.25,
            max_yaw_rate: 0.4,
            ..frankie_like()
        };
        let mut controller = BaseController::new(BaseControllerConfig::default(), model);
        // Target behind the base: the controller wants to turn hard.
        let out = controller
            .step(&BaseControllerInput {
                task_index: 0,
                base: BasePose::new(0.0, 0.0, 0.0),
                target: TargetEstimate::fixed(Vector3::new(-3.0, 0.5, 0.45)),
                next_target: Vector3::new(-6.0, 0.0, 0.35),
                after_next: None,
                dt: 1.0,
            })
            .unwrap();
        assert_eq!(out.command.v, 0.25);
        // The turn is as tight as the yaw-rate limit allows at this speed, never tighter.
        assert!(
            (out.command.omega.abs() - 0.4).abs() < 1e-9,
            "{}",
            out.command.omega
        );
    }

    #[test]
    fn non_finite_input_is_an_error_naming_the_field() {
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let err = controller
            .step(&BaseControllerInput {
                task_index: 0,
                base: BasePose::new(0.0, 0.0, 0.0),
                target: TargetEstimate::fixed(Vector3::new(f64::NAN, 0.0, 0.45)),
                next_target: Vector3::new(6.0, 0.0, 0.35),
                after_next: None,
                dt: DT,
            })
            .unwrap_err();
        assert_eq!(err.field, "target.position");
    }

    #[test]
    fn a_degenerate_configuration_still_gives_finite_outputs() {
        let config = BaseControllerConfig {
            forward_speed: 0.0,
            run_in: 0.0,
            run_out: 0.0,
            ..BaseControllerConfig::default()
        };
        let mut controller = BaseController::new(config, frankie_like());
        for target in [Vector3::new(3.0, 0.0, 0.45), Vector3::new(0.0, 0.0, 0.45)] {
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base: BasePose::new(0.0, 0.0, 0.0),
                    target: TargetEstimate::fixed(target),
                    next_target: target,
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            let values = [
                out.command.v,
                out.command.omega,
                out.time_to_range,
                out.range_entry_pose.x,
                out.range_entry_pose.yaw,
                out.closest_approach.x,
            ];
            assert!(values.iter().all(|v| v.is_finite()), "{out:?}");
        }
    }

    #[test]
    fn the_turn_command_is_rate_limited_across_a_goal_switch() {
        let model = frankie_like();
        let mut controller = BaseController::new(BaseControllerConfig::default(), model);
        let max_change = model.max_yaw_acceleration * DT;
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        // Task 0: a target ahead and to the right, next target far to the left.
        let mut input = BaseControllerInput {
            task_index: 0,
            base,
            target: TargetEstimate::fixed(Vector3::new(3.0, -0.5, 0.45)),
            next_target: Vector3::new(4.0, 3.0, 0.35),
            after_next: None,
            dt: DT,
        };
        let mut last = 0.0;
        let mut largest_step: f64 = 0.0;
        for k in 0..1500 {
            if k == 300 {
                // The task ends: the goal jumps to a target behind and to the left, where the
                // polar law asks for a hard turn the other way.
                input.task_index = 1;
                input.target = TargetEstimate::fixed(Vector3::new(-2.0, 2.0, 0.35));
                input.next_target = Vector3::new(-4.0, 0.0, 0.45);
            }
            input.base = base;
            let out = controller.step(&input).unwrap();
            largest_step = largest_step.max((out.command.omega - last).abs());
            last = out.command.omega;
            integrate(&mut base, out.command, DT);
        }
        assert!(
            largest_step <= max_change + 1e-12,
            "ω changed by {largest_step} in one step, limit {max_change}"
        );
        // The limit spreads the turn, it does not stop it: the base ends up heading back.
        assert!(base.x < 2.0, "the base never turned round: {base:?}");
    }

    #[test]
    fn a_kept_plan_whose_run_in_start_moved_behind_the_turn_is_rerouted_tight_without_a_loop() {
        // The base heads west along y = 2.01 toward a pass of the target heading south, the
        // target on its right; the target was just seen 0.17 m north of where it was expected,
        // so the run-in's start (0.6, 1.605) lies inside the base's turn at 0.6 m.
        let controller = BaseController::new(
            BaseControllerConfig {
                forward_speed: 0.3,
                ..BaseControllerConfig::default()
            },
            frankie_like(),
        );
        let base = BasePose::new(1.13, 2.01, std::f64::consts::PI);
        let target = Vector2::new(0.0, 0.605);
        let plan = PassPlan {
            side: PassSide::Left,
            heading: -FRAC_PI_2,
        };
        let radius = controller.turn_radius();
        let wide = controller.route_to(&base, &plan, target, radius, &[]);
        assert!(wide.turning() > 1.5 * std::f64::consts::PI, "{wide:?}");
        let route = controller.reroute(&base, &plan, target, radius, &[]);
        assert!(route.turning() < std::f64::consts::PI, "{route:?}");
        assert!(route.radius < radius && route.radius >= 0.35);
        let end = route.sample(route.length());
        let start = controller.run_in_start(&plan, target);
        assert!((end.x - start.x).abs() < 1e-6 && (end.y - start.y).abs() < 1e-6);
        // Off, the route is the wide one.
        let off = BaseController::new(
            BaseControllerConfig {
                forward_speed: 0.3,
                tight_turn_radius: 0.0,
                ..BaseControllerConfig::default()
            },
            frankie_like(),
        );
        assert_eq!(off.reroute(&base, &plan, target, radius, &[]), wide);
    }

    #[test]
    fn a_u_turn_keeps_its_side_and_turns_away_from_the_target() {
        // Experiment 2's container: approached from the west with the next target (the next
        // cube) back west, slightly north. The base must pass on one side and turn round the
        // far side, never crossing the target's front.
        let mut controller = BaseController::new(drive_past_config(), frankie_like());
        let target = Vector3::new(3.0, 0.0, 0.35);
        let next = Vector3::new(0.0, 0.42, 0.45);
        let mut base = BasePose::new(0.6, -0.3, 0.0);
        let mut sides = Vec::new();
        let mut min_distance = f64::INFINITY;
        let mut turned_back = false;
        for _ in 0..1500 {
            let out = controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target: TargetEstimate::fixed(target),
                    next_target: next,
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            if !out.passed {
                sides.push(out.side);
            }
            eprintln!(
                "U {:.2} {:.2} {:.2} {:?} {:.2} {:.2} {:.2} w={:.2} p={} c={}",
                base.x,
                base.y,
                base.yaw,
                out.side,
                out.closest_approach.x,
                out.closest_approach.y,
                out.closest_approach.yaw,
                out.command.omega,
                out.passed,
                controller.current.committed
            );
            min_distance =
                min_distance.min((Vector2::new(3.0, 0.0) - Vector2::new(base.x, base.y)).norm());
            turned_back |= base.yaw.cos() < -0.9;
            integrate(&mut base, out.command, DT);
        }
        assert!(
            sides.windows(2).all(|w| w[0] == w[1]),
            "the side flipped: {sides:?}"
        );
        assert!(
            min_distance > 0.55,
            "came within {min_distance:.3} m of the target"
        );
        assert!(turned_back, "never turned back toward the next target");
    }

    #[test]
    fn the_pass_pose_is_r_c_beside_the_target_on_its_side() {
        let target = Vector2::new(3.0, 1.0);
        let left = PassPlan {
            side: PassSide::Left,
            heading: 0.0,
        }
        .pose(target, 0.6);
        // Heading east and passing on the left: the base is north of the target.
        assert!((left.x - 3.0).abs() < 1e-12 && (left.y - 1.6).abs() < 1e-12);
        let right = PassPlan {
            side: PassSide::Right,
            heading: std::f64::consts::FRAC_PI_2,
        }
        .pose(target, 0.6);
        // Heading north and passing on the right: the base is east of the target.
        assert!((right.x - 3.6).abs() < 1e-12 && (right.y - 1.0).abs() < 1e-12);
    }

    /// Drives a unicycle through `targets` in turn (each task ends when the base has passed its
    /// target), returning the smallest distance to each target while it is the current one and
    /// the smallest distance to every obstacle in `layout` over the whole run.
    fn drive_mission(
        start: BasePose,
        targets: &[Vector3<f64>],
        layout: &[Vector3<f64>],
        duration: f64,
    ) -> (Vec<f64>, f64, bool) {
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like())
            .with_layout(layout);
        let mut base = start;
        let mut task = 0;
        let mut closest = vec![f64::INFINITY; targets.len()];
        let mut nearest_obstacle = f64::INFINITY;
        for _ in 0..(duration / DT) as usize {
            if task == targets.len() {
                return (closest, nearest_obstacle, true);
            }
            let next = targets.get(task + 1).copied().unwrap_or(targets[task]);
            let out = controller
                .step(&BaseControllerInput {
                    task_index: task,
                    base,
                    target: TargetEstimate::fixed(targets[task]),
                    next_target: next,
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            let at = Vector2::new(base.x, base.y);
            closest[task] = closest[task].min((xy(&targets[task]) - at).norm());
            for o in layout {
                nearest_obstacle = nearest_obstacle.min((xy(o) - at).norm());
            }
            if out.passed {
                task += 1;
            }
            integrate(&mut base, out.command, DT);
        }
        (closest, nearest_obstacle, task == targets.len())
    }

    #[test]
    fn a_target_behind_is_reached_by_turning_round() {
        // Pick ahead, then a place behind the start: the base turns round and passes it at r_C.
        let targets = [Vector3::new(3.0, 0.0, 0.45), Vector3::new(-1.0, 0.5, 0.35)];
        let (closest, nearest, done) =
            drive_mission(BasePose::new(0.0, 0.0, 0.0), &targets, &targets, 60.0);
        assert!(done, "did not pass every target: {closest:?}");
        for d in &closest {
            assert!((d - 0.6).abs() < 0.1, "passed at {closest:?}");
        }
        assert!(nearest > 0.55, "came within {nearest:.3} m of a target");
    }

    #[test]
    fn zigzags_and_a_row_of_targets_are_passed_clear_of_the_others() {
        let zigzag = [
            Vector3::new(3.0, 0.5, 0.45),
            Vector3::new(5.0, -1.0, 0.35),
            Vector3::new(7.0, 1.0, 0.45),
            Vector3::new(9.0, -1.0, 0.35),
        ];
        let (closest, nearest, done) =
            drive_mission(BasePose::new(0.0, 0.0, 0.0), &zigzag, &zigzag, 90.0);
        assert!(done, "{closest:?}");
        assert!(closest.iter().all(|d| (d - 0.6).abs() < 0.1), "{closest:?}");
        assert!(nearest > 0.55, "came within {nearest:.3} m of a target");
        // Experiment 2's loop: a row of platforms 0.12 m apart, a container 3 m east; two
        // round trips, never closer than the clearance to any platform.
        let row: Vec<Vector3<f64>> = (0..10)
            .map(|k| Vector3::new(0.0, 0.54 - 0.12 * k as f64, 0.45))
            .collect();
        let container = Vector3::new(3.0, 0.0, 0.35);
        let mut layout = row.clone();
        layout.push(container);
        let targets = [row[0], container, row[1], container, row[2]];
        let (closest, nearest, done) = drive_mission(
            BasePose::new(0.6, 2.0, -FRAC_PI_2),
            &targets,
            &layout,
            120.0,
        );
        assert!(done, "{closest:?}");
        assert!(closest.iter().all(|d| (d - 0.6).abs() < 0.1), "{closest:?}");
        assert!(nearest > 0.45, "came within {nearest:.3} m of a platform");
    }

    #[test]
    fn a_run_in_over_a_target_still_to_come_is_charged() {
        let controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let target = Vector2::new(0.0, 0.0);
        let north = PassPlan {
            side: PassSide::Left,
            heading: FRAC_PI_2,
        };
        let charge = |plan: &PassPlan, later: &[Vector2<f64>]| {
            controller.crossing_charge(plan, target, later)
        };
        // Before the target on the run-in, within the corridor: charged.
        assert_eq!(charge(&north, &[Vector2::new(0.1, -0.5)]), 2.0);
        // Beside the corridor, beyond the run-in, after the target, or at its own place: not.
        assert_eq!(charge(&north, &[Vector2::new(0.4, -0.5)]), 0.0);
        assert_eq!(charge(&north, &[Vector2::new(0.0, -1.2)]), 0.0);
        assert_eq!(charge(&north, &[Vector2::new(0.0, 0.5)]), 0.0);
        assert_eq!(charge(&north, &[Vector2::new(0.0, -0.02)]), 0.0);
        // Heading across the row, the same cube is abeam: not charged.
        let east = PassPlan {
            side: PassSide::Left,
            heading: 0.0,
        };
        assert_eq!(charge(&east, &[Vector2::new(0.0, -0.12)]), 0.0);
    }

    #[test]
    fn a_row_is_approached_from_its_cleared_end_when_the_detour_costs_less_than_the_charge() {
        // Three cubes in a row along y, picked north to south; the base starts south of the
        // row heading north. Straight on, the run-in to the first (north) cube leads over the
        // two still to come. Coming round to pass it from the cleared end costs a few metres:
        // with a charge above that the base comes round; without one it goes straight on.
        let row: Vec<Vector3<f64>> = (0..3)
            .map(|k| Vector3::new(0.0, -0.12 * k as f64, 0.45))
            .collect();
        let heading_for = |crossing_cost: f64, task: usize| {
            let config = BaseControllerConfig {
                crossing_cost,
                ..BaseControllerConfig::default()
            };
            let mut controller = BaseController::new(config, frankie_like()).with_layout(&row);
            let out = controller
                .step(&BaseControllerInput {
                    task_index: task,
                    base: BasePose::new(0.6, -3.0, FRAC_PI_2),
                    target: TargetEstimate::fixed(row[task]),
                    next_target: row.get(task + 1).copied().unwrap_or(row[task]),
                    after_next: row.get(task + 2).copied(),
                    dt: DT,
                })
                .unwrap();
            out.closest_approach.yaw
        };
        let straight_on = heading_for(0.0, 0);
        assert!(
            straight_on.sin() > 0.9,
            "heading {straight_on:.2} without the charge"
        );
        let around = heading_for(8.0, 0);
        assert!(around.sin() < 0.4, "heading {around:.2} leads over the row");
        // The last cube has none still to come: the charge changes nothing.
        assert_eq!(heading_for(8.0, 2), heading_for(0.0, 2));
    }

    #[test]
    fn config_rejects_unknown_keys_and_bad_values() {
        let file = Path::new("controllers.toml");
        let err = ModelError::parse_toml_str::<BaseControllerConfig>(file, "k_gamma = 1.0\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("controllers.toml") && err.contains("k_gamma"),
            "{err}"
        );
        let config: BaseControllerConfig =
            ModelError::parse_toml_str(file, "run_in = -1.0\nmin_turn_radius = 0.8\n").unwrap();
        assert_eq!(config.min_turn_radius, 0.8);
        let err = config.validate(file).unwrap_err().to_string();
        assert!(err.contains("base.run_in"), "{err}");
        BaseControllerConfig::default().validate(file).unwrap();
    }
}
