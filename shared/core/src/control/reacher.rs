//! The MotM reacher (paper section III-B.2; docs/algorithms.md §2 "Reacher").
//!
//! Until the arm has to start, the tool holds its ready pose relative to the base. The arm starts
//! when the time until the base is in manipulation range, t_R (from the base controller), is no
//! longer than the arm's transit time t_A = (distance to go, in the base frame) / (k_A·v_B). From
//! then on, every step, a quintic is planned from the tool's current state to the predicted
//! pre-grasp point, arriving at T = max(t_R, t_A) with the object's velocity, and the command is
//! the trajectory's velocity one control step ahead.
//!
//! Choices (each a [`ReacherConfig`] value where it is a number):
//! - **Transit distance.** t_A uses the distance from the tool's position in the current base
//!   frame to the pre-grasp point predicted at t_R, expressed in the base frame predicted at t_R
//!   (the base controller's `range_entry_pose`). The plain world distance would include the
//!   base's own drive and start the arm as soon as the mission begins.
//! - **v_B** is the base controller's commanded forward speed, so the trigger does not fire at
//!   start-up while the base is still at rest.
//! - **Trigger latch.** Once started, the reacher keeps reaching until the task changes, even if
//!   t_R > t_A again (t_A shrinks as the arm moves; flipping back would make the arm oscillate).
//! - **Pre-grasp point.** The goal is `pregrasp_height` above the object; the final-phase
//!   controller descends the rest.
//! - **Arrival velocity.** The trajectory ends with the object's estimated velocity and zero
//!   acceleration, so the tool matches a moving object; the end point is the object's position
//!   extrapolated over the trajectory duration.
//! - **Start state.** The quintic starts from the measured tool pose with the twist and
//!   acceleration of [`ToolState`] (normally the previous command), so replanning is smooth.
//! - **Orientation.** The gripper goes to a top-down pose (tool z axis straight down). Its yaw is
//!   the object's yaw modulo its symmetry when known, else the ready pose's yaw relative to the
//!   base, at the base heading predicted at t_R. The rotation follows the same quintic time
//!   scaling on the remaining rotation vector (world frame), ending at rest. The palm camera is
//!   not pointed at the object during the approach: the palm fisheye (about 180° field of view)
//!   keeps the object in view from a top-down pose.

use std::path::Path;

use nalgebra::{Isometry3, Rotation3, UnitQuaternion, Vector3, Vector6};
use serde::Deserialize;

use crate::error::ModelError;
use crate::input_check::{NonFiniteInput, ensure_finite};
use crate::kinematics::BasePose;
use crate::quintic::{PointState, Quintic3};
use crate::robot::Robot;
use crate::types::{BaseVelocity, TargetEstimate, Twist, wrap_angle};

/// Floor on k_A·v_B in t_A, m/s, guarding against a zero or negative configured k_A.
const MIN_ARM_SPEED: f64 = 1e-6;

/// Cap on the trajectory duration T, s.
const MAX_DURATION: f64 = 1e6;

/// Tunables of the reacher (the `[reacher]` table of a controller config).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReacherConfig {
    /// k_A: the arm's average transit speed in the base frame is k_A·v_B.
    pub arm_speed_ratio: f64,
    /// The reacher aims this far straight above the object (the pre-grasp point), m. The
    /// final-phase controller descends the rest, so the approach ends from above and the fingers
    /// do not sweep into the cube. It must be smaller than the final-phase hand-over distance
    /// d_T (0.1 m), or the hand-over would never happen. 0.065 m: the fingertips reach 5 mm
    /// below the tool point, so they clear a 30 mm cube's top by 4.5 cm at the pre-grasp point,
    /// room for the 3–4.5 cm a Fetch or UR5 tool sinks below its command at the hand-over.
    pub pregrasp_height: f64,
    /// Shortest trajectory duration T, s, so that a trajectory that is almost done does not
    /// demand a huge velocity.
    pub min_duration: f64,
    /// Lower clamp on the base speed v_B in t_A, m/s, so a stopped base does not divide by zero.
    pub min_base_speed: f64,
    /// Gain of the proportional correction toward the ready pose while holding, 1/s.
    pub hold_gain: f64,
    /// Largest speed of the holding correction, m/s: after a task the tool returns to the ready
    /// pose at most this fast instead of jumping back with the full gain.
    pub hold_max_speed: f64,
    /// Side-change margin, m. When the tool and the pre-grasp point (predicted at t_R, in the
    /// base frame predicted at t_R) lie on opposite sides of the ready pose, each more than
    /// this far to the side, the arm keeps holding, which pulls the tool back toward the ready
    /// pose in front of the base, until the tool is within this of the ready pose's side
    /// offset; only then may the reach start. A straight path from one side to the other
    /// would run through the arm's own base column (the shoulder joint winds to its limit and
    /// the reach is lost), as after a pick on one side of the base when the place lies on the
    /// other. 0.2 m: well outside a reach that stays on one side (the tool then sits some
    /// 0.5–0.6 m to the side), and the swing then passes in front of the shoulder.
    pub side_change_margin: f64,
    /// Symmetry of the object about the vertical, rad (π/2 for a cube). When the object's yaw is
    /// known, the gripper yaw is the object's yaw plus the multiple of this closest to the
    /// gripper's current yaw.
    pub yaw_symmetry: f64,
    /// Yaw the mission's objects stand at about world z, rad: 0, square to the world frame, as
    /// the cubes are set down. Perception measures no yaw, so a pick's gripper yaw is this plus
    /// the multiple of `yaw_symmetry` closest to the gripper's current yaw, whatever the base's
    /// heading as it passes the object.
    pub object_yaw: f64,
    /// Fraction of the tool twist's linear acceleration limit (the QP resolver's twist rate
    /// limit at the run's base speed) that a reach trajectory may use at its peak (0.9). A
    /// quintic that would need more is given a longer duration than max(t_R, t_A), so that the
    /// rate limit never cuts into the plan: a cut plan arrives late and fast, and the hand-over
    /// to the final phase then jerks the tool. Outside (0, 1] nothing is stretched.
    pub acceleration_fraction: f64,
    /// How far over the acceleration limit a reach that fell behind may go to keep its arrival
    /// time (2.0). A stretched reach never ends later than the plan before it, so that
    /// replanning cannot make the arrival recede; but when the tool lagged its command (the
    /// base turned hard with the arm out) and arriving by then would take more than this times
    /// the limit, the reach is given longer instead. Kept to its time it reached the hand-over
    /// distance at 0.77 m/s with 0.4 m/s downward, too fast for the final phase to brake above
    /// the cube, and swept it off (Exp 2 at 0.4 m/s). Below that ratio the late plan keeps its
    /// time: the arm is then only a little harder on the tool than the limit.
    pub late_acceleration_ratio: f64,
    /// How far below the pre-grasp point's height a reaching tool may sink, m (0.01). A reach
    /// runs straight from above to the pre-grasp point, but a tool that lags its command (the
    /// arm at the edge of its reach, the base turning on the spot) keeps descending while its
    /// horizontal travel stalls, and arrived at the height of the row's cubes a few decimetres
    /// short of the target, where the hand swept the neighbours off (Exp 2). Below this the
    /// reach's downward velocity is dropped and the shortfall climbed back at `hold_gain`.
    pub sink_margin: f64,
}

impl Default for ReacherConfig {
    fn default() -> Self {
        Self {
            arm_speed_ratio: 0.8,
            pregrasp_height: 0.065,
            min_duration: 0.2,
            min_base_speed: 0.05,
            hold_gain: 2.0,
            hold_max_speed: 0.25,
            side_change_margin: 0.2,
            yaw_symmetry: std::f64::consts::FRAC_PI_2,
            object_yaw: 0.0,
            acceleration_fraction: 0.9,
            late_acceleration_ratio: 2.0,
            sink_margin: 0.01,
        }
    }
}

impl ReacherConfig {
    /// The yaw a pick's object stands at in the odometry frame, whose frame has turned against
    /// the world by `odometry_yaw_offset` (the mission's correction).
    pub fn pick_yaw(&self, odometry_yaw_offset: f64) -> f64 {
        self.object_yaw + odometry_yaw_offset
    }

    /// The gripper yaw that grasps a pick's object ([`Self::pick_yaw`]) turning the gripper
    /// least from `current_yaw` ([`symmetric_yaw`]).
    pub fn grasp_yaw(&self, odometry_yaw_offset: f64, current_yaw: f64) -> f64 {
        symmetric_yaw(
            self.pick_yaw(odometry_yaw_offset),
            self.yaw_symmetry,
            current_yaw,
        )
    }

    /// Checks the values; `file` is the configuration file they came from, named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        let checks = [
            ("arm_speed_ratio", self.arm_speed_ratio > 0.0),
            (
                "pregrasp_height",
                (0.0..0.1).contains(&self.pregrasp_height),
            ),
            ("min_duration", self.min_duration > 0.0),
            ("min_base_speed", self.min_base_speed > 0.0),
            ("hold_gain", self.hold_gain >= 0.0),
            ("hold_max_speed", self.hold_max_speed > 0.0),
            ("side_change_margin", self.side_change_margin >= 0.0),
            ("yaw_symmetry", self.yaw_symmetry > 0.0),
            ("object_yaw", self.object_yaw.is_finite()),
            (
                "acceleration_fraction",
                self.acceleration_fraction > 0.0 && self.acceleration_fraction <= 1.0,
            ),
            (
                "late_acceleration_ratio",
                self.late_acceleration_ratio >= 1.0,
            ),
            ("sink_margin", self.sink_margin >= 0.0),
        ];
        for (key, ok) in checks {
            if !ok {
                return Err(ModelError::invalid(
                    file,
                    format!("reacher.{key}"),
                    "out of range (need k_A > 0, 0 ≤ pregrasp_height < 0.1, min_duration > 0, \
                     min_base_speed > 0, hold_gain ≥ 0, hold_max_speed > 0, \
                     side_change_margin ≥ 0, yaw_symmetry > 0, object_yaw finite, \
                     0 < acceleration_fraction ≤ 1, late_acceleration_ratio ≥ 1, \
                     sink_margin ≥ 0)",
                ));
            }
        }
        Ok(())
    }
}

/// The tool's current motion state, world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolState {
    /// Measured tool pose.
    pub pose: Isometry3<f64>,
    /// Tool twist `[v; ω]`. Passing the previous step's [`ReacherOutput::twist`] (the command)
    /// gives the smoothest replanning; a measured twist also works.
    pub twist: Twist,
    /// Tool acceleration `[a; α]`, normally the previous step's [`ReacherOutput::acceleration`].
    pub acceleration: Vector6<f64>,
}

/// What the reacher reads each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReacherInput {
    /// Index of the current mission task; when it changes the reacher goes back to holding.
    pub task_index: usize,
    /// Current base pose.
    pub base: BasePose,
    /// The base velocity commanded this step by the base controller. Its forward speed is v_B
    /// in t_A (the measured speed is zero at start-up and would start the arm at once), and
    /// while holding, the tool is carried with this base motion so that the resolver can keep
    /// the arm still.
    pub base_velocity: BaseVelocity,
    /// The tool's current state.
    pub tool: ToolState,
    /// Latest estimate of the object (the grasp point, e.g. the cube centre).
    pub target: TargetEstimate,
    /// The object's yaw about the vertical, if known, rad.
    pub target_yaw: Option<f64>,
    /// t_R from the base controller, s.
    pub time_to_range: f64,
    /// The base pose predicted at t_R, from the base controller.
    pub range_entry_pose: BasePose,
    /// Control period, s: the command is the trajectory velocity this far ahead.
    pub dt: f64,
}

/// Whether the arm holds its ready pose or reaches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReachMode {
    /// The tool holds the ready pose relative to the base.
    #[default]
    Holding,
    /// The tool follows the quintic toward the object (latched until the task changes).
    Reaching,
}

/// What the reacher produces each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReacherOutput {
    /// World twist command for the tool `[v; ω]`.
    pub twist: Twist,
    /// The trajectory's acceleration at the same instant as `twist` (zero while holding); feed it
    /// back as [`ToolState::acceleration`].
    pub acceleration: Vector6<f64>,
    /// Holding or reaching.
    pub mode: ReachMode,
    /// t_A, the arm transit time estimate, s.
    pub transit_time: f64,
    /// T, the duration of this step's trajectory, s (zero while holding).
    pub duration: f64,
    /// Goal pose of this step's trajectory: the pre-grasp pose at T (the ready pose while holding).
    pub goal: Isometry3<f64>,
}

/// The reacher: a step function plus the latched mode.
#[derive(Debug, Clone)]
pub struct Reacher {
    config: ReacherConfig,
    ready_tool: Isometry3<f64>,
    task_index: Option<usize>,
    mode: ReachMode,
    /// Largest peak linear acceleration of a reach trajectory, m/s² (infinite: none).
    max_acceleration: f64,
    /// Duration of the last step's reach trajectory, s (none while holding): a stretched reach
    /// never ends later than the one planned before it.
    last_duration: Option<f64>,
}

/// How much longer than max(t_R, t_A) an acceleration-limited reach may take, at most (×4).
const MAX_DURATION_STRETCH: f64 = 4.0;

/// Factor by which an acceleration-limited reach's duration grows per try (1.05).
const DURATION_STEP: f64 = 1.05;

/// Instants at which a trajectory's acceleration is sampled for its peak (the acceleration of a
/// quintic is a cubic per axis: 16 samples find its peak within a few per cent).
const ACCELERATION_SAMPLES: usize = 16;

/// A top-down tool orientation with the given yaw: the tool z axis points down and the tool
/// x axis points along `yaw` in the horizontal plane.
pub fn top_down(yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
}

/// The gripper yaw that grasps an object standing at `object_yaw` with the given `symmetry`
/// about the vertical (rad; π/2 for a cube, 0 for none) and turns the gripper least from
/// `current_yaw`: the object's yaw plus the multiple of the symmetry closest to the current yaw.
pub fn symmetric_yaw(object_yaw: f64, symmetry: f64, current_yaw: f64) -> f64 {
    if symmetry > 0.0 {
        object_yaw + (wrap_angle(current_yaw - object_yaw) / symmetry).round() * symmetry
    } else {
        object_yaw
    }
}

/// The yaw of a tool orientation: the heading of its x axis projected on the horizontal plane.
pub fn tool_yaw(rotation: &UnitQuaternion<f64>) -> f64 {
    let x = rotation * Vector3::x();
    x.y.atan2(x.x)
}

impl Reacher {
    /// A reacher whose ready pose is the tool pose, in the base frame, at the robot's
    /// configured ready joint positions.
    pub fn new(config: ReacherConfig, robot: &Robot) -> Self {
        let ready_tool = robot.tool_pose(&BasePose::default(), &robot.config.ready_pose);
        Self::with_ready_tool(config, ready_tool)
    }

    /// A reacher with an explicit ready tool pose in the base frame.
    pub fn with_ready_tool(config: ReacherConfig, ready_tool: Isometry3<f64>) -> Self {
        Self {
            config,
            ready_tool,
            task_index: None,
            mode: ReachMode::Holding,
            max_acceleration: f64::INFINITY,
            last_duration: None,
        }
    }

    /// This reacher with its reach trajectories kept within `limit` m/s² of peak linear
    /// acceleration, times [`ReacherConfig::acceleration_fraction`] (see there). A limit that
    /// is not finite and positive sets none.
    pub fn with_acceleration_limit(mut self, limit: f64) -> Self {
        let max = limit * self.config.acceleration_fraction;
        self.max_acceleration = if max.is_finite() && max > 0.0 {
            max
        } else {
            f64::INFINITY
        };
        self
    }

    /// The largest peak linear acceleration a reach trajectory may have, m/s² (infinite: none).
    pub fn max_acceleration(&self) -> f64 {
        self.max_acceleration
    }

    /// The configuration.
    pub fn config(&self) -> &ReacherConfig {
        &self.config
    }

    /// The ready tool pose in the base frame.
    pub fn ready_tool(&self) -> &Isometry3<f64> {
        &self.ready_tool
    }

    /// One control step. Errors (and changes no state) if an input is not finite or `dt` is not
    /// positive.
    pub fn step(&mut self, input: &ReacherInput) -> Result<ReacherOutput, NonFiniteInput> {
        check_input(input)?;
        if self.task_index != Some(input.task_index) {
            self.task_index = Some(input.task_index);
            self.mode = ReachMode::Holding;
            self.last_duration = None;
        }
        let config = &self.config;
        let time_to_range = input.time_to_range.max(0.0);
        let pregrasp = Vector3::z() * config.pregrasp_height;

        // t_A: from the tool's position in the current base frame to the pre-grasp point predicted
        // at t_R, in the base frame predicted at t_R. The distance is the arm's own travel
        // relative to the base; the world distance would include the base's drive and trigger
        // the arm far too early.
        let goal_at_range = input.target.predict(time_to_range) + pregrasp;
        let goal_in_entry_frame = input
            .range_entry_pose
            .isometry()
            .inverse_transform_point(&goal_at_range.into());
        let tool_in_base_frame = input
            .base
            .isometry()
            .inverse_transform_point(&input.tool.pose.translation.vector.into());
        let base_speed = input.base_velocity.v.abs().max(config.min_base_speed);
        let arm_speed = (config.arm_speed_ratio * base_speed).max(MIN_ARM_SPEED);
        let transit_time = (goal_in_entry_frame - tool_in_base_frame).norm() / arm_speed;

        let start = PointState {
            position: input.tool.pose.translation.vector,
            velocity: input.tool.twist.fixed_rows::<3>(0).into_owned(),
            acceleration: input.tool.acceleration.fixed_rows::<3>(0).into_owned(),
        };
        // The trigger uses the transit time the reach would actually take: t_A, or longer when a
        // reach of t_A would need more than the acceleration limit, so that a stretched reach
        // starts early instead of arriving late.
        let starts = self.mode == ReachMode::Holding
            && !self.changes_side(&tool_in_base_frame.coords, &goal_in_entry_frame.coords)
            && (time_to_range <= transit_time
                || time_to_range
                    <= self
                        .timed_translation(
                            &start,
                            &input.target,
                            pregrasp,
                            transit_time.max(config.min_duration).min(MAX_DURATION),
                            f64::INFINITY,
                        )
                        .0);
        if starts {
            self.mode = ReachMode::Reaching;
        }
        if self.mode == ReachMode::Holding {
            return Ok(self.hold(input, transit_time));
        }

        // At least one control period and the configured floor; capped so that a degenerate
        // configuration cannot produce an infinite duration.
        let timed = time_to_range
            .max(transit_time)
            .max(config.min_duration)
            .max(input.dt)
            .min(MAX_DURATION);
        let current_yaw = tool_yaw(&input.tool.pose.rotation);
        let goal_yaw = match input.target_yaw {
            Some(yaw) => symmetric_yaw(yaw, config.yaw_symmetry, current_yaw),
            None => input.range_entry_pose.yaw + tool_yaw(&self.ready_tool.rotation),
        };
        let goal_rotation = top_down(goal_yaw);
        let twist = &input.tool.twist;
        let acceleration = &input.tool.acceleration;
        let latest = self
            .last_duration
            .map_or(f64::INFINITY, |last| last - input.dt);
        let (duration, goal_position, translation) =
            self.timed_translation(&start, &input.target, pregrasp, timed, latest);
        self.last_duration = Some(duration);
        // Rotation: the remaining rotation vector r (world frame) goes from its current value to
        // zero on the same time scaling; the tool's angular velocity is −ṙ.
        let remaining = (goal_rotation * input.tool.pose.rotation.inverse()).scaled_axis();
        let rotation = Quintic3::new(
            &PointState {
                position: remaining,
                velocity: -twist.fixed_rows::<3>(3).into_owned(),
                acceleration: -acceleration.fixed_rows::<3>(3).into_owned(),
            },
            &PointState::at_rest(Vector3::zeros()),
            duration,
        )
        .expect("finite inputs and a positive duration");

        let mut ahead = translation.evaluate(input.dt);
        let sunk = goal_position.z - config.sink_margin - input.tool.pose.translation.z;
        if sunk > 0.0 {
            ahead.velocity.z = ahead.velocity.z.max(config.hold_gain * sunk);
            ahead.acceleration.z = 0.0;
        }
        let turn = rotation.evaluate(input.dt);
        Ok(ReacherOutput {
            twist: stack(&ahead.velocity, &-turn.velocity),
            acceleration: stack(&ahead.acceleration, &-turn.acceleration),
            mode: self.mode,
            transit_time,
            duration,
            goal: Isometry3::from_parts(goal_position.into(), goal_rotation),
        })
    }

    /// The reach's translation: the quintic from `start` to the pre-grasp point (`pregrasp`
    /// above the target predicted at the arrival), arriving at `timed` = max(t_R, t_A) or, when
    /// that would take more peak acceleration than [`Reacher::max_acceleration`] (or than the
    /// start's own, when that is already higher), at the first of a geometric series of longer
    /// durations (up to [`MAX_DURATION_STRETCH`] × `timed`, and never past `latest`, the end of
    /// the last step's plan: replanned each step, a stretch that could recede would let the tool
    /// creep toward a goal it never reaches) that does not. A plan that even at `latest` needs
    /// more than [`ReacherConfig::late_acceleration_ratio`] times the limit has fallen behind:
    /// it is stretched past `latest` (within the same bound) until it fits. Returns the
    /// duration, the goal and the quintic.
    fn timed_translation(
        &self,
        start: &PointState,
        target: &TargetEstimate,
        pregrasp: Vector3<f64>,
        timed: f64,
        latest: f64,
    ) -> (f64, Vector3<f64>, Quintic3) {
        let plan = |duration: f64| {
            let goal = target.predict(duration) + pregrasp;
            let quintic = Quintic3::new(
                start,
                &PointState {
                    position: goal,
                    velocity: target.velocity,
                    acceleration: Vector3::zeros(),
                },
                duration,
            )
            .expect("finite inputs and a positive duration");
            (duration, goal, quintic)
        };
        let planned = plan(timed);
        if !self.max_acceleration.is_finite() {
            return planned;
        }
        let allowed = self.max_acceleration.max(start.acceleration.norm());
        let longest = (timed * MAX_DURATION_STRETCH).min(MAX_DURATION);
        // The plan stretched up to `until`, with its peak acceleration.
        let stretch = |mut planned: (f64, Vector3<f64>, Quintic3), until: f64| {
            let mut peak = peak_acceleration(&planned.2);
            while peak > allowed && planned.0 * DURATION_STEP <= until {
                planned = plan(planned.0 * DURATION_STEP);
                peak = peak_acceleration(&planned.2);
            }
            (planned, peak)
        };
        let (kept, peak) = stretch(planned, longest.min(latest));
        if peak > allowed * self.config.late_acceleration_ratio {
            stretch(kept, longest).0
        } else {
            kept
        }
    }

    /// Whether the reach from `tool` (base frame) to `goal` (base frame at range entry) would
    /// cross from one side of the ready pose to the other
    /// ([`ReacherConfig::side_change_margin`]).
    fn changes_side(&self, tool: &Vector3<f64>, goal: &Vector3<f64>) -> bool {
        let centre = self.ready_tool.translation.vector.y;
        let margin = self.config.side_change_margin;
        let (tool_side, goal_side) = (tool.y - centre, goal.y - centre);
        tool_side.abs() > margin && goal_side.abs() > margin && tool_side * goal_side < 0.0
    }

    /// Holding: the tool carried by the base as if fixed to it where it is, plus a proportional
    /// pull back to the ready pose. The feed-forward is the base's velocity at the tool's own
    /// point, not at the ready pose's: after a pick behind the base's side the tool is far from
    /// the ready pose, and carried at the ready pose's velocity while the base turns it would
    /// sweep across the back of the base (the difference is the turn rate times the lever
    /// between the two points), folding the arm over itself.
    fn hold(&self, input: &ReacherInput, transit_time: f64) -> ReacherOutput {
        let base = &input.base;
        let ready = base.isometry() * self.ready_tool;
        let lever = input.tool.pose.translation.vector - Vector3::new(base.x, base.y, 0.0);
        let yaw_rate = Vector3::z() * input.base_velocity.omega;
        let carried = Vector3::new(base.yaw.cos(), base.yaw.sin(), 0.0) * input.base_velocity.v
            + yaw_rate.cross(&lever);
        let gain = self.config.hold_gain;
        let position_error = ready.translation.vector - input.tool.pose.translation.vector;
        let rotation_error = (ready.rotation * input.tool.pose.rotation.inverse()).scaled_axis();
        ReacherOutput {
            twist: stack(
                &(carried + (position_error * gain).cap_magnitude(self.config.hold_max_speed)),
                &(yaw_rate + rotation_error * gain),
            ),
            acceleration: Vector6::zeros(),
            mode: ReachMode::Holding,
            transit_time,
            duration: 0.0,
            goal: ready,
        }
    }
}

/// The largest acceleration magnitude of `quintic` over its duration, sampled at
/// [`ACCELERATION_SAMPLES`] + 1 instants.
fn peak_acceleration(quintic: &Quintic3) -> f64 {
    let duration = quintic.duration();
    (0..=ACCELERATION_SAMPLES)
        .map(|k| {
            quintic
                .evaluate(duration * k as f64 / ACCELERATION_SAMPLES as f64)
                .acceleration
                .norm()
        })
        .fold(0.0, f64::max)
}

fn stack(linear: &Vector3<f64>, angular: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(
        linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
    )
}

fn check_input(input: &ReacherInput) -> Result<(), NonFiniteInput> {
    let b = &input.base;
    ensure_finite("base", &[b.x, b.y, b.yaw])?;
    let v = &input.base_velocity;
    ensure_finite("base_velocity", &[v.v, v.omega])?;
    ensure_finite("tool.pose", input.tool.pose.translation.vector.iter())?;
    ensure_finite("tool.pose", input.tool.pose.rotation.coords.iter())?;
    ensure_finite("tool.twist", input.tool.twist.iter())?;
    ensure_finite("tool.acceleration", input.tool.acceleration.iter())?;
    ensure_finite("target.position", input.target.position.iter())?;
    ensure_finite("target.velocity", input.target.velocity.iter())?;
    ensure_finite("target_yaw", input.target_yaw.iter())?;
    ensure_finite("time_to_range", &[input.time_to_range])?;
    let e = &input.range_entry_pose;
    ensure_finite("range_entry_pose", &[e.x, e.y, e.yaw])?;
    if !(input.dt.is_finite() && input.dt > 0.0) {
        return Err(NonFiniteInput { field: "dt" });
    }
    Ok(())
}

/// Integrates a tool pose by a world twist over `dt` (rotation by the exponential of ω·dt).
pub fn integrate_tool_pose(pose: &Isometry3<f64>, twist: &Twist, dt: f64) -> Isometry3<f64> {
    let linear = Vector3::new(twist[0], twist[1], twist[2]);
    let angular = Vector3::new(twist[3], twist[4], twist[5]);
    let turn = UnitQuaternion::from_rotation_matrix(&Rotation3::new(angular * dt));
    Isometry3::from_parts(
        (pose.translation.vector + linear * dt).into(),
        turn * pose.rotation,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base_controller::{
        BaseController, BaseControllerConfig, BaseControllerInput, BaseModel,
    };
    use nalgebra::Vector2;

    const DT: f64 = 0.02;

    /// Frankie's ready tool pose in the base frame (tool point at (0.634, 0, 0.7926), top-down).
    fn ready_tool() -> Isometry3<f64> {
        Isometry3::from_parts(Vector3::new(0.634, 0.0, 0.7926).into(), top_down(0.0))
    }

    fn frankie_base() -> BaseModel {
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

    /// One step of the closed loop, recorded.
    struct Sample {
        time: f64,
        output: ReacherOutput,
        time_to_range: f64,
        tool: Isometry3<f64>,
        target: Vector3<f64>,
        base: BasePose,
    }

    /// The base controller drives a kinematic unicycle past the object while the reacher moves
    /// an ideal tool (it integrates the commanded twist exactly).
    fn run(target_start: Vector3<f64>, target_velocity: Vector3<f64>, seconds: f64) -> Vec<Sample> {
        let mut base_controller =
            BaseController::new(BaseControllerConfig::default(), frankie_base());
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let mut base = BasePose::new(0.0, 0.0, 0.0);
        let mut tool = ToolState {
            pose: base.isometry() * ready_tool(),
            twist: Twist::zeros(),
            acceleration: Vector6::zeros(),
        };
        let mut samples = Vec::new();
        for k in 0..(seconds / DT) as usize {
            let time = k as f64 * DT;
            let target = TargetEstimate {
                position: target_start + target_velocity * time,
                velocity: target_velocity,
            };
            let base_out = base_controller
                .step(&BaseControllerInput {
                    task_index: 0,
                    base,
                    target,
                    next_target: Vector3::new(6.0, 0.0, 0.35),
                    after_next: None,
                    dt: DT,
                })
                .unwrap();
            let output = reacher
                .step(&ReacherInput {
                    task_index: 0,
                    base,
                    base_velocity: base_out.command,
                    tool,
                    target,
                    target_yaw: None,
                    time_to_range: base_out.time_to_range,
                    range_entry_pose: base_out.range_entry_pose,
                    dt: DT,
                })
                .unwrap();
            samples.push(Sample {
                time,
                output,
                time_to_range: base_out.time_to_range,
                tool: tool.pose,
                target: target.position,
                base,
            });
            tool = ToolState {
                pose: integrate_tool_pose(&tool.pose, &output.twist, DT),
                twist: output.twist,
                acceleration: output.acceleration,
            };
            let base_velocity = base_out.command;
            base.yaw = wrap_angle(base.yaw + base_velocity.omega * DT);
            base.x += base_velocity.v * DT * base.yaw.cos();
            base.y += base_velocity.v * DT * base.yaw.sin();
        }
        samples
    }

    fn trigger_index(samples: &[Sample]) -> usize {
        samples
            .iter()
            .position(|s| s.output.mode == ReachMode::Reaching)
            .expect("the reacher never started")
    }

    #[test]
    fn a_tool_held_behind_the_base_while_it_turns_moves_only_toward_the_ready_pose() {
        // After a pick at the base's right rear, the base turns left hard while the
        // target is far: the tool must move, relative to the base, straight toward the ready
        // pose, not be swept across the base's back by the turn.
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let base = BasePose::new(1.0, 2.0, 0.3);
        let omega = 0.5;
        let tool_in_base = Vector3::new(-0.2, -0.56, 0.55);
        let tool = base.isometry() * Isometry3::from_parts(tool_in_base.into(), top_down(0.0));
        let out = reacher
            .step(&ReacherInput {
                task_index: 0,
                base,
                base_velocity: BaseVelocity { v: 0.3, omega },
                tool: ToolState {
                    pose: tool,
                    twist: Twist::zeros(),
                    acceleration: Vector6::zeros(),
                },
                target: TargetEstimate::fixed(Vector3::new(20.0, 2.0, 0.45)),
                target_yaw: None,
                time_to_range: 60.0,
                range_entry_pose: BasePose::new(20.0, 2.6, 0.0),
                dt: DT,
            })
            .unwrap();
        assert_eq!(out.mode, ReachMode::Holding);
        // The tool's velocity relative to the base, in the base frame: the world velocity less
        // the base's rigid-body velocity at the tool, turned into the base frame.
        let lever = tool.translation.vector - Vector3::new(base.x, base.y, 0.0);
        let carried = Vector3::new(base.yaw.cos(), base.yaw.sin(), 0.0) * 0.3
            + (Vector3::z() * omega).cross(&lever);
        let world = out.twist.fixed_rows::<3>(0).into_owned();
        let relative = base.isometry().inverse_transform_vector(&(world - carried));
        let to_ready = ready_tool().translation.vector - tool_in_base;
        let across = relative.cross(&to_ready.normalize()).norm();
        assert!(relative.dot(&to_ready) > 0.0, "{relative}");
        assert!(across < 1e-9, "{relative} is not toward {to_ready}");
    }

    #[test]
    fn holds_the_ready_pose_until_the_transit_time_trigger() {
        let samples = run(Vector3::new(3.0, 0.0, 0.45), Vector3::zeros(), 14.0);
        let start = trigger_index(&samples);
        // The arm waits: it does not start in the first second, with the target 3 m away.
        assert!(
            samples[start].time > 1.0,
            "started at {:.2} s",
            samples[start].time
        );
        for s in &samples[..start] {
            assert!(s.time_to_range > s.output.transit_time);
            let ready = s.base.isometry() * ready_tool();
            assert!(
                (ready.translation.vector - s.tool.translation.vector).norm() < 1e-3,
                "drifted from the ready pose at {:.2} s",
                s.time
            );
            assert!(ready.rotation.angle_to(&s.tool.rotation) < 1e-3);
        }
        // It starts at the first step where t_R ≤ t_A, and stays started even if that flips back.
        let first = &samples[start];
        assert!(first.time_to_range <= first.output.transit_time);
        assert!(
            samples[start..]
                .iter()
                .all(|s| s.output.mode == ReachMode::Reaching)
        );
        // Independent check of t_A at the trigger. The base passes the object (3 m ahead) with it
        // 0.6 m to its right and enters range when the arm base (0.15 m ahead of the base) is
        // 0.75 m from it: the pre-grasp point is then at (0.6, −0.6, 0.5) in the base frame.
        // From the ready tool point (0.634, 0, 0.7926) that is 0.668 m, at k_A·v_F.
        let distance = (Vector3::new(0.6, -0.6, 0.5) - Vector3::new(0.634, 0.0, 0.7926)).norm();
        let expected: f64 = distance / (ReacherConfig::default().arm_speed_ratio * 0.3);
        assert!(
            (first.output.transit_time - expected).abs() < 0.05,
            "t_A {:.3} s at the trigger, expected {expected:.3} s",
            first.output.transit_time
        );
        // t_R falls by DT per step, so at the first step with t_R ≤ t_A it is within DT of t_A.
        assert!((first.time_to_range - expected).abs() < DT + 0.05);
    }

    /// Runs the loop and checks that the tool reaches the pre-grasp point above the object, with
    /// the object's velocity, when the base enters manipulation range.
    fn assert_arrives(target_velocity: Vector3<f64>) {
        let samples = run(Vector3::new(3.0, 0.0, 0.45), target_velocity, 12.0);
        let entry = samples
            .iter()
            .position(|s| s.time_to_range == 0.0)
            .expect("never in range");
        let pregrasp = Vector3::z() * ReacherConfig::default().pregrasp_height;
        let error = |s: &Sample| ((s.target + pregrasp) - s.tool.translation.vector).norm();
        let arrival = samples
            .iter()
            .position(|s| error(s) < 0.005)
            .expect("never arrived");
        let (arrived, entered) = (samples[arrival].time, samples[entry].time);
        // Within 0.6 s of range entry: the base follows a planned route onto the run-in, which
        // pure pursuit shortens a little in the turn, and for an object moving across the path
        // t_R along that route runs up to half a second long, so the reach starts that late.
        assert!(
            arrived <= entered + 0.6,
            "arrived at {arrived:.2} s, range entry at {entered:.2} s"
        );
        assert!(
            arrived > entered - 1.0,
            "arrived at {arrived:.2} s, long before {entered:.2} s"
        );
        // From one trajectory floor (0.2 s) after arrival, the tool stays on the moving
        // pre-grasp point with the object's velocity, top-down.
        let settled = arrival.max(entry) + 10;
        for s in &samples[settled..settled + 25] {
            assert!(
                error(s) < 0.002,
                "position error {:.4} m at {:.2} s",
                error(s),
                s.time
            );
            let velocity = s.output.twist.fixed_rows::<3>(0).into_owned();
            assert!(
                (velocity - target_velocity).norm() < 0.005,
                "velocity {velocity:?} vs object {target_velocity:?} at {:.2} s",
                s.time
            );
            let down = s.tool.rotation * Vector3::z();
            assert!(down.z < -0.999, "gripper not top-down: {down:?}");
        }
        // Never NaN, and no wild speeds on the way.
        for s in &samples {
            assert!(s.output.twist.iter().all(|v| v.is_finite()));
            assert!(s.output.twist.fixed_rows::<3>(0).norm() < 1.0);
        }
    }

    #[test]
    fn arrives_on_a_static_object() {
        assert_arrives(Vector3::zeros());
    }

    #[test]
    fn arrives_on_a_moving_object_with_its_velocity() {
        assert_arrives(Vector3::new(0.0, 0.03, 0.0));
        assert_arrives(Vector3::new(-0.03, 0.0, 0.0));
    }

    #[test]
    fn an_acceleration_limited_reach_takes_longer_and_keeps_within_the_limit() {
        let tool = ToolState {
            pose: ready_tool(),
            twist: Twist::zeros(),
            acceleration: Vector6::zeros(),
        };
        let input = ReacherInput {
            task_index: 0,
            base: BasePose::default(),
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            tool,
            target: TargetEstimate::fixed(Vector3::new(0.6, -0.6, 0.45)),
            target_yaw: None,
            time_to_range: 0.5,
            range_entry_pose: BasePose::default(),
            dt: DT,
        };
        let mut free = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let unlimited = free.step(&input).unwrap();
        let peak = |duration: f64, goal: Vector3<f64>| {
            peak_acceleration(
                &Quintic3::new(
                    &PointState::at_rest(tool.pose.translation.vector),
                    &PointState::at_rest(goal),
                    duration,
                )
                .unwrap(),
            )
        };
        let unlimited_peak = peak(unlimited.duration, unlimited.goal.translation.vector);
        let limit = 0.3;
        assert!(unlimited_peak > limit, "{unlimited_peak}");
        let mut limited = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool())
            .with_acceleration_limit(limit);
        let out = limited.step(&input).unwrap();
        assert_eq!(out.mode, ReachMode::Reaching);
        assert!(out.duration > unlimited.duration);
        let allowed = limit * ReacherConfig::default().acceleration_fraction;
        assert!(peak(out.duration, out.goal.translation.vector) <= allowed + 1e-9);
        // The next step's plan does not end later than this one.
        let next = limited.step(&input).unwrap();
        assert!(
            next.duration <= out.duration - DT + 1e-9,
            "{} {}",
            next.duration,
            out.duration
        );
        // A reach that fell behind (the tool now moves away from the goal at 0.5 m/s) would need
        // more than `late_acceleration_ratio` × the limit to arrive by then: it is given longer
        // than the plan before it, and keeps within the limit.
        let behind = limited
            .step(&ReacherInput {
                tool: ToolState {
                    twist: Twist::new(0.0, 0.5, 0.0, 0.0, 0.0, 0.0),
                    ..tool
                },
                ..input
            })
            .unwrap();
        assert!(behind.duration > next.duration, "{}", behind.duration);
        let quintic = Quintic3::new(
            &PointState {
                position: tool.pose.translation.vector,
                velocity: Vector3::new(0.0, 0.5, 0.0),
                acceleration: Vector3::zeros(),
            },
            &PointState::at_rest(behind.goal.translation.vector),
            behind.duration,
        )
        .unwrap();
        assert!(peak_acceleration(&quintic) <= allowed + 1e-9);
    }

    #[test]
    fn a_tool_sunk_below_the_pregrasp_height_far_from_the_target_is_not_taken_lower() {
        // The tool lags its command: 4 cm under the pre-grasp point's height, still 0.4 m short
        // of it, and moving down. The plan from there would go on descending; the floor stops
        // that and climbs back.
        let pregrasp = ReacherConfig::default().pregrasp_height;
        let target = Vector3::new(0.9, -0.6, 0.45);
        let sunk = target + Vector3::new(-0.4, 0.0, pregrasp - 0.04);
        let input = ReacherInput {
            task_index: 0,
            base: BasePose::default(),
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            tool: ToolState {
                pose: Isometry3::from_parts(sunk.into(), ready_tool().rotation),
                twist: Twist::new(0.2, 0.0, -0.15, 0.0, 0.0, 0.0),
                acceleration: Vector6::zeros(),
            },
            target: TargetEstimate::fixed(target),
            target_yaw: None,
            time_to_range: 0.0,
            range_entry_pose: BasePose::default(),
            dt: DT,
        };
        let floored = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool())
            .step(&input)
            .unwrap();
        assert_eq!(floored.mode, ReachMode::Reaching);
        let gain = ReacherConfig::default().hold_gain;
        let margin = ReacherConfig::default().sink_margin;
        assert!(
            (floored.twist[2] - gain * (0.04 - margin)).abs() < 1e-9,
            "climbs back at the hold gain: {}",
            floored.twist[2]
        );
        assert_eq!(floored.acceleration[2], 0.0);
        // Without the floor the plan descends further.
        let config = ReacherConfig {
            sink_margin: 1.0,
            ..ReacherConfig::default()
        };
        let free = Reacher::with_ready_tool(config, ready_tool())
            .step(&input)
            .unwrap();
        assert!(free.twist[2] < 0.0, "{}", free.twist[2]);
        // The horizontal motion is the plan's either way.
        assert_eq!(floored.twist[0], free.twist[0]);
    }

    #[test]
    fn the_command_is_the_trajectory_velocity_one_step_ahead() {
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let tool = ToolState {
            pose: ready_tool(),
            twist: Twist::zeros(),
            acceleration: Vector6::zeros(),
        };
        let target = TargetEstimate::fixed(Vector3::new(0.6, -0.6, 0.45));
        let input = ReacherInput {
            task_index: 0,
            base: BasePose::default(),
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            tool,
            target,
            target_yaw: None,
            time_to_range: 0.5,
            range_entry_pose: BasePose::default(),
            dt: DT,
        };
        let out = reacher.step(&input).unwrap();
        assert_eq!(out.mode, ReachMode::Reaching);
        let expected = Quintic3::new(
            &PointState::at_rest(tool.pose.translation.vector),
            &PointState::at_rest(out.goal.translation.vector),
            out.duration,
        )
        .unwrap()
        .evaluate(DT);
        let linear = out.twist.fixed_rows::<3>(0).into_owned();
        assert!((linear - expected.velocity).norm() < 1e-12);
        assert!(linear.norm() > 0.0);
        // Starting from rest, a quintic's velocity at t = 0 is zero: the command is not that.
        assert!(
            (out.goal.translation.vector
                - (target.position + Vector3::z() * ReacherConfig::default().pregrasp_height))
                .norm()
                < 1e-12
        );
    }

    #[test]
    fn the_gripper_yaw_follows_a_known_object_yaw_modulo_its_symmetry() {
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let out = reacher
            .step(&ReacherInput {
                task_index: 0,
                base: BasePose::default(),
                base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
                tool: ToolState {
                    pose: ready_tool(),
                    twist: Twist::zeros(),
                    acceleration: Vector6::zeros(),
                },
                target: TargetEstimate::fixed(Vector3::new(0.6, -0.6, 0.45)),
                target_yaw: Some(1.9),
                time_to_range: 0.0,
                range_entry_pose: BasePose::default(),
                dt: DT,
            })
            .unwrap();
        // 1.9 − π/2 = 0.329 rad is the equivalent closest to the current yaw of 0.
        let yaw = tool_yaw(&out.goal.rotation);
        assert!(
            (yaw - (1.9 - std::f64::consts::FRAC_PI_2)).abs() < 1e-9,
            "{yaw}"
        );
    }

    #[test]
    fn frankie_ready_tool_is_the_ready_pose_tool_point_top_down() {
        let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let robot = Robot::load(&config_dir, "frankie").unwrap();
        let reacher = Reacher::new(ReacherConfig::default(), &robot);
        let ready = reacher.ready_tool();
        assert!((ready.translation.vector - Vector3::new(0.634, 0.0, 0.7926)).norm() < 1e-3);
        let down = ready.rotation * Vector3::z();
        eprintln!("ready tool z {down:?}, yaw {}", tool_yaw(&ready.rotation));
        assert!(down.z < -0.99, "ready tool z axis {down:?}");
    }

    #[test]
    fn a_degenerate_configuration_still_gives_finite_outputs() {
        let config = ReacherConfig {
            arm_speed_ratio: 0.0,
            min_duration: 0.0,
            min_base_speed: 0.0,
            ..ReacherConfig::default()
        };
        let mut reacher = Reacher::with_ready_tool(config, ready_tool());
        let out = reacher
            .step(&ReacherInput {
                task_index: 0,
                base: BasePose::default(),
                base_velocity: BaseVelocity::default(),
                tool: ToolState {
                    pose: ready_tool(),
                    twist: Twist::zeros(),
                    acceleration: Vector6::zeros(),
                },
                target: TargetEstimate::fixed(ready_tool().translation.vector),
                target_yaw: None,
                time_to_range: 0.0,
                range_entry_pose: BasePose::default(),
                dt: DT,
            })
            .unwrap();
        assert!(
            out.twist
                .iter()
                .chain(out.acceleration.iter())
                .all(|v| v.is_finite())
        );
        assert!(out.transit_time.is_finite() && out.duration.is_finite());
    }

    #[test]
    fn a_new_task_starts_by_holding_again() {
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let mut input = ReacherInput {
            task_index: 0,
            base: BasePose::default(),
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            tool: ToolState {
                pose: ready_tool(),
                twist: Twist::zeros(),
                acceleration: Vector6::zeros(),
            },
            target: TargetEstimate::fixed(Vector3::new(0.6, -0.6, 0.45)),
            target_yaw: None,
            time_to_range: 0.0,
            range_entry_pose: BasePose::default(),
            dt: DT,
        };
        assert_eq!(reacher.step(&input).unwrap().mode, ReachMode::Reaching);
        input.task_index = 1;
        input.time_to_range = 30.0;
        assert_eq!(reacher.step(&input).unwrap().mode, ReachMode::Holding);
        input.dt = 0.0;
        assert_eq!(reacher.step(&input).unwrap_err().field, "dt");
        input.dt = DT;
        input.tool.twist[4] = f64::NAN;
        assert_eq!(reacher.step(&input).unwrap_err().field, "tool.twist");
    }

    #[test]
    fn config_rejects_unknown_keys_and_a_pregrasp_beyond_the_hand_over() {
        let file = Path::new("controllers.toml");
        let err = ModelError::parse_toml_str::<ReacherConfig>(file, "k_a = 0.5\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("controllers.toml") && err.contains("k_a"),
            "{err}"
        );
        let config: ReacherConfig =
            ModelError::parse_toml_str(file, "pregrasp_height = 0.12\n").unwrap();
        let err = config.validate(file).unwrap_err().to_string();
        assert!(err.contains("reacher.pregrasp_height"), "{err}");
        ReacherConfig::default().validate(file).unwrap();
    }

    /// A reach whose goal is on the other side of the base holds (pulling the tool back toward
    /// the ready pose) until the tool is back in front; the same reach from in front starts.
    #[test]
    fn a_reach_to_the_other_side_of_the_base_starts_only_from_in_front() {
        let base = BasePose::new(0.0, 0.0, 0.0);
        // The place lies 0.6 m to the left at range entry, which is now (t_R = 0).
        let target = TargetEstimate::fixed(Vector3::new(0.4, 0.6, 0.4));
        let input_with_tool = |tool_position: Vector3<f64>| ReacherInput {
            task_index: 1,
            base,
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            tool: ToolState {
                pose: Isometry3::from_parts(tool_position.into(), top_down(0.0)),
                twist: Twist::zeros(),
                acceleration: Vector6::zeros(),
            },
            target,
            target_yaw: None,
            time_to_range: 0.0,
            range_entry_pose: base,
            dt: DT,
        };
        // Just after a pick on the right: the tool is 0.6 m to the right.
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let out = reacher
            .step(&input_with_tool(Vector3::new(0.4, -0.6, 0.5)))
            .unwrap();
        assert_eq!(out.mode, ReachMode::Holding);
        assert!(out.twist[1] > 0.1, "pulled back toward the middle: {out:?}");
        // Back within the side-change margin: the reach starts (and stays latched).
        let out = reacher
            .step(&input_with_tool(Vector3::new(0.55, -0.15, 0.6)))
            .unwrap();
        assert_eq!(out.mode, ReachMode::Reaching);
        let out = reacher
            .step(&input_with_tool(Vector3::new(0.4, -0.6, 0.5)))
            .unwrap();
        assert_eq!(out.mode, ReachMode::Reaching);
        // A goal on the same side as the tool starts at once.
        let mut reacher = Reacher::with_ready_tool(ReacherConfig::default(), ready_tool());
        let same_side = ReacherInput {
            target: TargetEstimate::fixed(Vector3::new(0.4, -0.6, 0.4)),
            ..input_with_tool(Vector3::new(0.4, -0.5, 0.5))
        };
        assert_eq!(reacher.step(&same_side).unwrap().mode, ReachMode::Reaching);
    }
}
