//! The MotM base controller (paper section III-B.1; docs/algorithms.md §2 "Base controller").
//!
//! Each step it
//! 1. computes the closest-approach pose ξ_C: the tangent point from the base to the circle of
//!    radius r_C around the target, on the side that bends toward the next target;
//! 2. drives toward ξ_C with Corke's polar controller modified for a constant forward speed v_F:
//!    `v = v_F`, `ω = (k_α·α + k_β·β)·v_F/ρ`;
//! 3. estimates t_R, the time until the target is within the robot's manipulation range of the
//!    arm base, and the base pose at that moment.
//!
//! Everything is recomputed from the latest estimates every step, so a moving target is followed.
//! Once the base has gone by the target (the "passed" latch) it steers for the next target's
//! closest-approach circle instead.
//!
//! Choices (each a [`BaseControllerConfig`] value where it is a number):
//! - **Heading of ξ_C**: toward the next target, as docs/algorithms.md says; the tangent direction is
//!   the alternative ([`ApproachHeading`]).
//! - **Side**: for a bend under 90° (direction base→target to direction target→next), the side of
//!   the line base→target on which the next target lies (the paper's "bends toward N"). For a
//!   larger bend (toward a U-turn, the next target behind, as in experiment 2's loop) that sign
//!   test is ill-posed: the base approaches offset by r_C from the line, and the sign flips as it
//!   closes in, sending the base across the target's front. There the side is the one whose way
//!   past the target turns the base less ([`pass_rotation`]: onto the tangent line, then away
//!   from the target toward the next one). Both with hysteresis
//!   ([`BaseControllerConfig::side_hysteresis`]), and fixed within `side_commit_distance`.
//! - **Passed latch**: set when the base is within r_C of the target, or the target is abeam or
//!   behind within r_C + `pass_margin`; cleared when the task index changes. Once passed, t_R
//!   is 0 and the goal is on the next target's r_C circle (below).
//! - **β sign**: Corke's `β = θ_goal − ψ`, the convention under which k_α > 1, k_β < 0 is stable.
//! - **t_R path model**: straight to ξ_C, then straight on along ξ_C's heading, at v_F, with the
//!   target moving at its estimated velocity; "in range" is the horizontal distance from the arm
//!   base (first arm joint) to the target within the robot's `manipulation_range`.
//! - **Limits**: v = min(v_F, v_max) and ω saturated at ±ω_max, from the two virtual base joints.
//! - **Turn acceleration**: the commanded ω changes by at most `yaw_acceleration_fraction` × the
//!   base's yaw acceleration limit per second (ramping from rest at the first step). The polar
//!   law steps ω when the goal jumps (a task ends and the goal switches to the next target, or
//!   the passed latch sets); the base cannot follow such a step, and the redundancy-resolution
//!   QP, which is handed this command as the base target, would plan the arm around a turn that
//!   does not happen (the tool then jerks). Limiting it here, where the path is decided, keeps the
//!   command one the base can execute, so the QP's base target and the base agree.
//! - **Turn at ξ_C**: ξ_C's heading is turned from the tangent direction toward the next target
//!   by at most `max_approach_turn`. With a large bend at the target (the next target is beside
//!   or behind, as in the paper's experiment 2 loop) a heading toward the next target would make
//!   the polar law cut the corner: it turns toward the next target before the target is abeam,
//!   so the base swings away from the cube while the arm is reaching for it. With the limit the
//!   base goes by the target nearly straight and makes the rest of the turn after passing it.
//! - **Look-ahead near ξ_C**: within `min_goal_distance` of ξ_C the base aims at the point that
//!   far ahead on ξ_C's line instead ([`look_ahead`]), so a target moving along with the base
//!   (whose tangent point stays just ahead) does not make the polar law weave.
//! - **After passing**: the goal is the tangent point on the next target's r_C circle on the side
//!   that needs the smaller turn from the current heading (β = 0), not the next target itself, so
//!   a task that takes longer than expected (a slow lift, a late release) never drives the base
//!   at the next platform or container. Inside that circle the base drives straight on.

use std::path::Path;

use nalgebra::{Rotation2, Vector2};
use serde::Deserialize;

use crate::error::ModelError;
use crate::input_check::{NonFiniteInput, ensure_finite};
use crate::kinematics::BasePose;
use crate::reach_range::arm_base_in_base_frame;
use crate::robot::Robot;
use crate::types::{BaseVelocity, TargetEstimate, wrap_angle};

/// Heading of the closest-approach pose ξ_C.
///
/// Both choices pass a static or slowly moving target at r_C to within a few millimetres in the
/// unicycle tests below, because ξ_C is recomputed every step: the base keeps re-aiming at the
/// tangent point as it moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ApproachHeading {
    /// Toward the next target, as in docs/algorithms.md (the default): the base is already turning
    /// toward the next target as it goes by.
    #[default]
    TowardNext,
    /// Along the tangent to the r_C circle (the direction from the base to ξ_C): the base goes by
    /// the target on a straight line and turns toward the next target only once it has passed.
    Tangent,
}

/// On which side of the target the base passes, seen along its direction of travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PassSide {
    /// The base passes to the left of the target (the target is on the base's right); chosen
    /// when the next target lies to the left of the line from the base to the target.
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

/// Tunables of the base controller (the `[base_controller]` table of a controller config).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseControllerConfig {
    /// Constant forward speed v_F, m/s (clamped to the base's speed limit).
    pub forward_speed: f64,
    /// Closest-approach radius r_C = r_R + r_P = 0.25 + 0.35 m.
    pub closest_approach_radius: f64,
    /// Polar-controller gain on α (stable for k_α > 1).
    pub k_alpha: f64,
    /// Polar-controller gain on β (stable for k_β < 0).
    pub k_beta: f64,
    /// Lower clamp on ρ, the distance to the goal pose, in `ω = (k_α·α + k_β·β)·v_F/ρ`, m; also
    /// the look-ahead: closer to ξ_C than this, the base aims at the point this far ahead on
    /// ξ_C's line ([`look_ahead`]).
    pub min_goal_distance: f64,
    /// Heading of ξ_C.
    pub approach_heading: ApproachHeading,
    /// Side-choice hysteresis. For a bend under 90° the bend is `b = sin δ`, δ being the turn
    /// from the direction base→target to the direction target→next; the side switches to the
    /// left only when `b > side_hysteresis` and to the right only when `b < −side_hysteresis`.
    /// For a larger bend the side switches only when the other side's way past the target turns
    /// the base less by more than this many radians ([`pass_rotation`]). In between the previous
    /// side is kept; on a task's first step the raw comparison decides. 0.1 ≈ a 6° turn.
    pub side_hysteresis: f64,
    /// Within this distance of the target the side no longer changes (except on a task's first
    /// step), m. Changing sides means crossing the target's front, 2·r_C sideways; close in the
    /// base cannot do that at its forward speed, and the rotation test, which assumes it can,
    /// would send it across the target. 1.5 m: 2.5·r_C.
    pub side_commit_distance: f64,
    /// The "passed" latch is set when the base is within r_C of the target, or when the target is
    /// abeam or behind the base (no component ahead) while within r_C plus this margin, m.
    pub pass_margin: f64,
    /// Largest turn from the tangent direction at ξ_C to ξ_C's heading (toward the next target),
    /// rad. π/12 (15°): the exp1 layouts bend about 6° at the cube and are unaffected; larger
    /// bends (exp2's loop) are made after the target is passed, not while the arm reaches.
    pub max_approach_turn: f64,
    /// Fraction of the base's yaw acceleration limit (URDF `base_yaw` acceleration) the
    /// commanded ω may change by per second. 1.0: the base's full capability.
    pub yaw_acceleration_fraction: f64,
}

impl Default for BaseControllerConfig {
    fn default() -> Self {
        Self {
            forward_speed: 0.3,
            closest_approach_radius: 0.6,
            k_alpha: 4.0,
            k_beta: -1.5,
            min_goal_distance: 0.2,
            approach_heading: ApproachHeading::default(),
            side_hysteresis: 0.1,
            side_commit_distance: 1.5,
            pass_margin: 0.3,
            max_approach_turn: std::f64::consts::PI / 12.0,
            yaw_acceleration_fraction: 1.0,
        }
    }
}

impl BaseControllerConfig {
    /// Checks the values; `file` is the configuration file they came from, named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        let checks = [
            ("forward_speed", self.forward_speed > 0.0),
            (
                "closest_approach_radius",
                self.closest_approach_radius > 0.0,
            ),
            ("k_alpha", self.k_alpha > 1.0),
            ("k_beta", self.k_beta < 0.0),
            ("min_goal_distance", self.min_goal_distance > 0.0),
            (
                "side_hysteresis",
                (0.0..std::f64::consts::PI).contains(&self.side_hysteresis),
            ),
            ("pass_margin", self.pass_margin >= 0.0),
            ("side_commit_distance", self.side_commit_distance >= 0.0),
            (
                "max_approach_turn",
                (0.0..=std::f64::consts::PI).contains(&self.max_approach_turn),
            ),
            (
                "yaw_acceleration_fraction",
                self.yaw_acceleration_fraction > 0.0 && self.yaw_acceleration_fraction.is_finite(),
            ),
        ];
        for (key, ok) in checks {
            if !ok {
                return Err(ModelError::invalid(
                    file,
                    format!("base_controller.{key}"),
                    "out of range (need v_F > 0, r_C > 0, k_α > 1, k_β < 0, \
                     min_goal_distance > 0, 0 ≤ side_hysteresis < π, pass_margin ≥ 0, side_commit_distance ≥ 0, \
                     0 ≤ max_approach_turn ≤ π, yaw_acceleration_fraction > 0)",
                ));
            }
        }
        Ok(())
    }
}

/// What the base controller reads each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseControllerInput {
    /// Index of the current mission task. When it changes, the side choice and the "passed"
    /// latch start afresh.
    pub task_index: usize,
    /// Current base pose (odometry).
    pub base: BasePose,
    /// Latest estimate of the current target (only x and y are used for driving; the velocity
    /// feeds the time-to-range estimate).
    pub target: TargetEstimate,
    /// Position of the next target (x and y are used).
    pub next_target: nalgebra::Vector3<f64>,
    /// Time since the previous step, s: bounds the change of ω (see the module docs).
    pub dt: f64,
}

/// What the base controller produces each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseControllerOutput {
    /// Base velocity command, within the base's v and ω limits.
    pub command: BaseVelocity,
    /// Closest-approach pose ξ_C (kept at its last value once the target is passed; the base
    /// pose at the task's first step if the target was already passed then).
    pub closest_approach: BasePose,
    /// The side on which the base passes the target.
    pub side: PassSide,
    /// t_R: predicted time until the target is within manipulation range of the arm base, s.
    /// Zero once it is in range or passed. If the predicted path never brings it within range,
    /// the time of the closest predicted approach.
    pub time_to_range: f64,
    /// Predicted base pose at `time_to_range` (the current pose when that is zero).
    pub range_entry_pose: BasePose,
    /// True once the base has gone by the target (latched until the task changes).
    pub passed: bool,
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
}

impl BaseModel {
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
        }
    }
}

/// The base controller: a step function plus the small state it latches between steps.
#[derive(Debug, Clone)]
pub struct BaseController {
    config: BaseControllerConfig,
    model: BaseModel,
    task_index: Option<usize>,
    side: PassSide,
    passed: bool,
    closest_approach: BasePose,
    /// The ω commanded on the previous step (0 at rest, before the first step).
    last_omega: f64,
}

/// Output of the polar controller for one goal pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolarCommand {
    /// Yaw-rate command (before saturation), rad/s.
    pub omega: f64,
    /// Distance to the goal, m.
    pub rho: f64,
    /// Angle from the current heading to the vector toward the goal, rad.
    pub alpha: f64,
    /// `wrap(θ_goal − ψ)`, ψ being the direction of the vector toward the goal, rad.
    pub beta: f64,
}

/// Floor under the configured ρ clamp, m, so that a zero `min_goal_distance` cannot divide by 0.
const MIN_GOAL_DISTANCE: f64 = 1e-3;

/// Corke's polar controller at constant forward speed: `ω = (k_α·α + k_β·β)·v/max(ρ, ρ_min)`.
///
/// β uses Corke's sign convention, `β = θ_goal − ψ` (ψ: direction of the vector to the goal),
/// for which k_α > 1, k_β < 0 is the stable region quoted in the paper.
pub fn polar_control(
    base: &BasePose,
    goal: &BasePose,
    speed: f64,
    config: &BaseControllerConfig,
) -> PolarCommand {
    let to_goal = Vector2::new(goal.x - base.x, goal.y - base.y);
    let rho = to_goal.norm();
    let psi = to_goal.y.atan2(to_goal.x);
    let alpha = wrap_angle(psi - base.yaw);
    let beta = wrap_angle(goal.yaw - psi);
    let omega = (config.k_alpha * alpha + config.k_beta * beta) * speed
        / rho.max(config.min_goal_distance).max(MIN_GOAL_DISTANCE);
    PolarCommand {
        omega,
        rho,
        alpha,
        beta,
    }
}

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

/// `goal` moved along its own heading until it is at least `distance` from `base`.
///
/// Near ξ_C the polar law is ill-conditioned: α and β swing as ρ → 0 (the clamp on ρ only
/// bounds the gain). A target moving along with the base keeps its tangent point just ahead of
/// the base, so the base would weave hard there; aiming at a point on the goal's line at least
/// `distance` ahead keeps the command smooth and still brings the base onto that line.
pub fn look_ahead(base: &BasePose, goal: BasePose, distance: f64) -> BasePose {
    let heading = Vector2::new(goal.yaw.cos(), goal.yaw.sin());
    let offset = Vector2::new(goal.x - base.x, goal.y - base.y);
    // Smallest s ≥ 0 with |offset + s·heading| ≥ distance.
    let along = offset.dot(&heading);
    let c = offset.norm_squared() - distance * distance;
    if c >= 0.0 {
        return goal;
    }
    let s = -along + (along * along - c).sqrt();
    BasePose::new(goal.x + s * heading.x, goal.y + s * heading.y, goal.yaw)
}

/// A turn `angle` in (−π, π] taken the way round that `side` turns at its target: left (in
/// (−π/2, 3π/2)) for [`PassSide::Left`], right (in (−3π/2, π/2)) for [`PassSide::Right`]. A small
/// turn the other way (under π/2) is kept as it is.
pub fn turn_toward_side(angle: f64, side: PassSide) -> f64 {
    use std::f64::consts::{FRAC_PI_2, TAU};
    match side {
        PassSide::Left if angle < -FRAC_PI_2 => angle + TAU,
        PassSide::Right if angle > FRAC_PI_2 => angle - TAU,
        _ => angle,
    }
}

/// Net rotation of the base's heading, rad (positive to the left), on the way from `base` past
/// `target` on `side` toward `next`: the turn onto the tangent line to the r_C circle, then the
/// turn at the tangent point from the tangent direction toward `next`. At the target the base
/// turns away from it (left when passing on the left, the target on its right), so that turn is
/// taken in (−π/2, 3π/2) on the left and in (−3π/2, π/2) on the right: a small turn toward the
/// target's side is allowed (it happens once the target is behind), a large one goes the other
/// way round. `None` when the base is inside the circle.
pub fn pass_rotation(
    base: &BasePose,
    target: Vector2<f64>,
    next: Vector2<f64>,
    radius: f64,
    side: PassSide,
) -> Option<f64> {
    let (point, heading) = tangent_point(Vector2::new(base.x, base.y), target, radius, side)?;
    let onto_tangent = wrap_angle(heading - base.yaw);
    let to_next = next - point;
    let departure = to_next.y.atan2(to_next.x);
    Some(onto_tangent + turn_toward_side(wrap_angle(departure - heading), side))
}

fn xy(v: &nalgebra::Vector3<f64>) -> Vector2<f64> {
    Vector2::new(v.x, v.y)
}

impl BaseController {
    /// A controller with `config` for the robot described by `model`.
    pub fn new(config: BaseControllerConfig, model: BaseModel) -> Self {
        Self {
            config,
            model,
            task_index: None,
            side: PassSide::Left,
            passed: false,
            closest_approach: BasePose::default(),
            last_omega: 0.0,
        }
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
        ensure_finite("dt", std::slice::from_ref(&input.dt))?;

        if self.task_index != Some(input.task_index) {
            self.task_index = Some(input.task_index);
            self.passed = false;
            self.side = PassSide::Left;
            self.closest_approach = input.base;
            self.update_side(input, true);
        } else {
            self.update_side(input, false);
        }

        let base_xy = Vector2::new(b.x, b.y);
        let target = xy(&input.target.position);
        let next = xy(&input.next_target);
        let to_target = target - base_xy;
        let heading = Vector2::new(b.yaw.cos(), b.yaw.sin());
        let r_c = self.config.closest_approach_radius;
        if !self.passed {
            let d = to_target.norm();
            let abeam_or_behind = to_target.dot(&heading) <= 0.0;
            self.passed = d <= r_c || (abeam_or_behind && d < r_c + self.config.pass_margin);
        }
        let speed = self.speed();

        let tangent = if self.passed {
            None
        } else {
            tangent_point(base_xy, target, r_c, self.side)
        };
        let goal = match tangent {
            Some((point, tangent_heading)) => {
                let yaw = match self.config.approach_heading {
                    ApproachHeading::Tangent => tangent_heading,
                    ApproachHeading::TowardNext => {
                        let toward_next = (next.y - point.y).atan2(next.x - point.x);
                        let limit = self.config.max_approach_turn;
                        wrap_angle(
                            tangent_heading
                                + wrap_angle(toward_next - tangent_heading).clamp(-limit, limit),
                        )
                    }
                };
                self.closest_approach = BasePose::new(point.x, point.y, yaw);
                self.closest_approach
            }
            None => self.after_pass_goal(b, next),
        };
        let goal = if self.passed {
            goal
        } else {
            look_ahead(b, goal, self.config.min_goal_distance)
        };
        let polar = polar_control(b, &goal, speed, &self.config);
        let polar_omega = if self.passed {
            // β = 0, and α taken the way round that turns away from the passed target (it may
            // exceed π: a U-turn goes round the far side).
            let alpha = turn_toward_side(wrap_angle(polar.alpha), self.side);
            self.config.k_alpha * alpha * speed
                / polar
                    .rho
                    .max(self.config.min_goal_distance)
                    .max(MIN_GOAL_DISTANCE)
        } else {
            polar.omega
        };
        let max_change = self.model.max_yaw_acceleration
            * self.config.yaw_acceleration_fraction
            * input.dt.max(0.0);
        let omega = polar_omega
            .clamp(self.last_omega - max_change, self.last_omega + max_change)
            .clamp(-self.model.max_yaw_rate, self.model.max_yaw_rate);
        self.last_omega = omega;

        let (time_to_range, range_entry_pose) = if self.passed {
            (0.0, *b)
        } else {
            self.time_to_range(b, &goal, &input.target, speed)
        };

        Ok(BaseControllerOutput {
            command: BaseVelocity { v: speed, omega },
            closest_approach: self.closest_approach,
            side: self.side,
            time_to_range,
            range_entry_pose,
            passed: self.passed,
        })
    }

    /// The goal once the target is passed: the tangent point on the next target's r_C circle
    /// reached with the smaller turn away from the passed target (left after passing on the left),
    /// with the heading pointing at it (β = 0). Inside that circle: straight on.
    fn after_pass_goal(&self, base: &BasePose, next: Vector2<f64>) -> BasePose {
        let base_xy = Vector2::new(base.x, base.y);
        let r_c = self.config.closest_approach_radius;
        let turn = |heading: f64| turn_toward_side(wrap_angle(heading - base.yaw), self.side).abs();
        let point = [PassSide::Left, PassSide::Right]
            .into_iter()
            .filter_map(|side| tangent_point(base_xy, next, r_c, side))
            .min_by(|a, b| turn(a.1).total_cmp(&turn(b.1)));
        match point {
            Some((point, heading)) => BasePose::new(point.x, point.y, heading),
            None => {
                let ahead = base_xy + Vector2::new(base.yaw.cos(), base.yaw.sin());
                BasePose::new(ahead.x, ahead.y, base.yaw)
            }
        }
    }

    fn update_side(&mut self, input: &BaseControllerInput, fresh: bool) {
        let base_xy = Vector2::new(input.base.x, input.base.y);
        let target = xy(&input.target.position);
        let next = xy(&input.next_target);
        let distance = (target - base_xy).norm();
        if self.passed || (!fresh && distance < self.config.side_commit_distance) {
            return;
        }
        let (Some(a), Some(c)) = (
            (target - base_xy).try_normalize(1e-9),
            (next - target).try_normalize(1e-9),
        ) else {
            return;
        };
        let band = if fresh {
            0.0
        } else {
            self.config.side_hysteresis
        };
        if a.dot(&c) >= 0.0 {
            // A bend under 90°: the side of the line base→target on which the next target lies.
            let bend = a.perp(&c);
            if bend > band {
                self.side = PassSide::Left;
            } else if bend < -band {
                self.side = PassSide::Right;
            }
            return;
        }
        // A bend over 90° (toward a U-turn): the side that turns the base less.
        let r_c = self.config.closest_approach_radius;
        let rotation = |side| pass_rotation(&input.base, target, next, r_c, side);
        let (Some(left), Some(right)) = (rotation(PassSide::Left), rotation(PassSide::Right))
        else {
            return;
        };
        if left.abs() + band < right.abs() {
            self.side = PassSide::Left;
        } else if right.abs() + band < left.abs() {
            self.side = PassSide::Right;
        }
    }

    /// t_R along the predicted path: a straight run from the base to the goal pose, then straight
    /// on along the goal heading, at constant speed, with the target moving at its estimated
    /// velocity. Returns the time and the base pose then.
    fn time_to_range(
        &self,
        base: &BasePose,
        goal: &BasePose,
        target: &TargetEstimate,
        speed: f64,
    ) -> (f64, BasePose) {
        let range = self.model.manipulation_range;
        // A zero speed (from a degenerate configuration) would make the prediction NaN.
        let speed = speed.max(1e-3);
        let target_xy = xy(&target.position);
        let target_velocity = xy(&target.velocity);
        let arm_base_at =
            |position: Vector2<f64>, yaw: f64| position + Rotation2::new(yaw) * self.model.arm_base;
        let base_xy = Vector2::new(base.x, base.y);
        if (arm_base_at(base_xy, base.yaw) - target_xy).norm() <= range {
            return (0.0, *base);
        }
        let goal_xy = Vector2::new(goal.x, goal.y);
        let first_length = (goal_xy - base_xy).norm();
        let first_heading = if first_length > 1e-9 {
            (goal_xy.y - base_xy.y).atan2(goal_xy.x - base_xy.x)
        } else {
            goal.yaw
        };
        // Segments: (start time, start position, direction of travel, heading that carries the
        // arm base, duration). On the first segment the arm base keeps the current heading, so
        // that τ = 0 agrees with the in-range check above.
        let segments = [
            (0.0, base_xy, first_heading, base.yaw, first_length / speed),
            (
                first_length / speed,
                goal_xy,
                goal.yaw,
                goal.yaw,
                f64::INFINITY,
            ),
        ];
        let mut closest = (f64::INFINITY, 0.0, *base);
        for (start_time, start, yaw, arm_yaw, duration) in segments {
            let direction = Vector2::new(yaw.cos(), yaw.sin());
            // Arm base relative to the target: r(τ) = r0 + w·τ for τ in [0, duration].
            let r0 = arm_base_at(start, arm_yaw) - (target_xy + target_velocity * start_time);
            let w = direction * speed - target_velocity;
            let pose_at = |tau: f64| {
                let p = start + direction * speed * tau;
                BasePose::new(p.x, p.y, yaw)
            };
            if let Some(tau) = first_entry(&r0, &w, range).filter(|t| *t <= duration) {
                return (start_time + tau, pose_at(tau));
            }
            let w2 = w.norm_squared();
            let tau_min = if w2 > 0.0 {
                (-r0.dot(&w) / w2).clamp(0.0, duration.min(1e6))
            } else {
                0.0
            };
            let distance = (r0 + w * tau_min).norm();
            if distance < closest.0 {
                closest = (distance, start_time + tau_min, pose_at(tau_min));
            }
        }
        (closest.1, closest.2)
    }
}

/// Smallest τ ≥ 0 with |r0 + w·τ| ≤ range, if any.
fn first_entry(r0: &Vector2<f64>, w: &Vector2<f64>, range: f64) -> Option<f64> {
    let c = r0.norm_squared() - range * range;
    if c <= 0.0 {
        return Some(0.0);
    }
    let a = w.norm_squared();
    let b = 2.0 * r0.dot(w);
    let discriminant = b * b - 4.0 * a * c;
    if a <= 0.0 || discriminant < 0.0 || b >= 0.0 {
        return None;
    }
    Some((-b - discriminant.sqrt()) / (2.0 * a))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    const DT: f64 = 0.02;

    fn frankie_like() -> BaseModel {
        BaseModel {
            manipulation_range: 0.75,
            arm_base: Vector2::new(0.15, 0.0),
            max_speed: 1.2,
            max_yaw_rate: 1.5,
            max_yaw_acceleration: 2.0,
        }
    }

    /// Integrates a unicycle as docs/algorithms.md §1 says: rotate by ω·dt, then move v·dt along the
    /// new heading.
    fn integrate(base: &mut BasePose, command: BaseVelocity, dt: f64) {
        base.yaw = wrap_angle(base.yaw + command.omega * dt);
        base.x += command.v * dt * base.yaw.cos();
        base.y += command.v * dt * base.yaw.sin();
    }

    struct Pass {
        /// Smallest base–target distance over the run, m.
        min_distance: f64,
        /// Cross product heading × (target − base) at the closest approach: < 0 means the target
        /// was on the right.
        target_side: f64,
        /// Side reported by the controller at the closest approach.
        side: PassSide,
        /// Every commanded forward speed.
        speeds: Vec<f64>,
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
            pass.speeds.push(out.command.v);
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
        assert!(pass.speeds.iter().all(|v| (v - 0.3).abs() < 1e-12));
    }

    /// Both closest-approach headings.
    fn configs() -> [BaseControllerConfig; 2] {
        [ApproachHeading::TowardNext, ApproachHeading::Tangent].map(|approach_heading| {
            BaseControllerConfig {
                approach_heading,
                ..BaseControllerConfig::default()
            }
        })
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
                20.0,
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
                20.0,
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
    fn starting_inside_r_c_counts_as_passed_and_heads_for_the_next_target() {
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let out = controller
            .step(&BaseControllerInput {
                task_index: 0,
                base: BasePose::new(0.0, 0.0, 0.0),
                target: TargetEstimate::fixed(Vector3::new(0.3, 0.2, 0.45)),
                next_target: Vector3::new(0.0, 3.0, 0.35),
                // A long step, so that the turn-acceleration limit lets the polar law through.
                dt: 1.0,
            })
            .unwrap();
        assert!(out.passed);
        assert_eq!(out.time_to_range, 0.0);
        assert_eq!(out.closest_approach, BasePose::new(0.0, 0.0, 0.0));
        // The next target is 3 m away, 90° to the left. The goal is the tangent point on its
        // r_C circle needing the smaller turn, at π/2 − asin(r_C/3), ρ = √(3² − r_C²) away, with
        // the heading pointing at it (β = 0): ω = k_α·α·v_F/ρ.
        let alpha = std::f64::consts::FRAC_PI_2 - (0.6f64 / 3.0).asin();
        let expected = 4.0 * alpha * 0.3 / (9.0f64 - 0.36).sqrt();
        assert!(
            (out.command.omega - expected).abs() < 1e-12,
            "{}",
            out.command.omega
        );
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
    fn the_side_holds_inside_the_hysteresis_band() {
        // The next target is almost straight ahead, slightly to the right: within the band the
        // initial choice (right, from the sign of the bend) must be kept while driving.
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
        let mut input = BaseControllerInput {
            task_index: 0,
            base: BasePose::new(0.0, 0.0, 0.0),
            target: TargetEstimate::fixed(Vector3::new(3.0, 0.0, 0.45)),
            next_target: Vector3::new(6.0, -0.1, 0.35),
            dt: DT,
        };
        assert_eq!(controller.step(&input).unwrap().side, PassSide::Right);
        // Noise moves the next target slightly to the left: still inside the band, keep right.
        input.next_target.y = 0.1;
        assert_eq!(controller.step(&input).unwrap().side, PassSide::Right);
        // A clear bend to the left switches.
        input.next_target.y = 1.5;
        assert_eq!(controller.step(&input).unwrap().side, PassSide::Left);
        // A new task starts from the raw sign again.
        input.task_index = 1;
        input.next_target.y = -0.1;
        assert_eq!(controller.step(&input).unwrap().side, PassSide::Right);
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
                    dt: DT,
                })
                .unwrap();
            let arm_base =
                Vector2::new(base.x, base.y) + Rotation2::new(base.yaw) * Vector2::new(0.15, 0.0);
            if entered_at.is_none() && (arm_base - Vector2::new(target.x, target.y)).norm() <= 0.75
            {
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
                dt: 1.0,
            })
            .unwrap();
        assert_eq!(out.command.v, 0.25);
        assert_eq!(out.command.omega.abs(), 0.4);
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
                dt: DT,
            })
            .unwrap_err();
        assert_eq!(err.field, "target.position");
    }

    #[test]
    fn a_degenerate_configuration_still_gives_finite_outputs() {
        let config = BaseControllerConfig {
            forward_speed: 0.0,
            min_goal_distance: 0.0,
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
    fn a_u_turn_keeps_its_side_and_turns_away_from_the_target() {
        // Experiment 2's container: approached from the west with the next target (the next
        // cube) back west, slightly north. The base must pass on one side and turn round the
        // far side, never crossing the target's front.
        let mut controller = BaseController::new(BaseControllerConfig::default(), frankie_like());
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
                    dt: DT,
                })
                .unwrap();
            if !out.passed {
                sides.push(out.side);
            }
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
    fn pass_rotation_prefers_the_side_the_next_target_bends_to() {
        let base = BasePose::new(0.0, 0.0, 0.0);
        let target = Vector2::new(3.0, 0.0);
        let rotation =
            |next: Vector2<f64>, side| pass_rotation(&base, target, next, 0.6, side).unwrap();
        // A 90° bend to the left: left is the short way round.
        let next = Vector2::new(3.0, 3.0);
        assert!(rotation(next, PassSide::Left).abs() < rotation(next, PassSide::Right).abs());
        // A clear bend to the right.
        let next = Vector2::new(5.0, -3.0);
        assert!(rotation(next, PassSide::Right).abs() < rotation(next, PassSide::Left).abs());
        // Passing on the left and then turning right by more than 90° goes the long way round.
        assert!(rotation(Vector2::new(2.0, -3.0), PassSide::Left) > std::f64::consts::PI);
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
            ModelError::parse_toml_str(file, "k_beta = 1.5\napproach_heading = \"toward_next\"\n")
                .unwrap();
        assert_eq!(config.approach_heading, ApproachHeading::TowardNext);
        let err = config.validate(file).unwrap_err().to_string();
        assert!(err.contains("base_controller.k_beta"), "{err}");
        BaseControllerConfig::default().validate(file).unwrap();
    }
}
