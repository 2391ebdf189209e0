//! Final-phase task controllers: the module that owns the arm once the tool is within
//! d_T of the target (docs/algorithms.md §2, paper section III-B).
//!
//! Every controller implements [`FinalPhaseController`], so the stack can swap one for another at
//! run time (`motm swap final-phase <variant>`): build the new one with [`build`] and feed it the
//! same [`FinalPhaseInput`]. Three variants exist:
//!
//! - [`GraspController`] (`"grasp"`): position-based servoing onto the object, close, lift.
//! - [`DropController`] (`"drop"`): servo above a container on the move, open, done.
//! - [`ButtonController`] (`"press-button"`): hover above a button, push in, retract.
//!
//! All of them share one servo law ([`ServoConfig`]): a world-frame proportional term with gain
//! k_P, saturated, plus feed-forward of the target velocity, and a top-down orientation term.
//! Commands are world-frame twists for the redundancy resolver; the base's own motion is the
//! resolver's business, not the controller's.
//!
//! Non-finite input never reaches the control law: the controller answers with a zero twist,
//! keeps its gripper command and its stage, and sets [`FinalPhaseOutput::input_rejected`].

mod button;
mod drop;
mod grasp;

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::Deserialize;

use crate::error::ModelError;
use crate::kinematics::BasePose;
use crate::mission::TaskKind;
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate, TaskProgress, Twist};

pub use button::ButtonController;
pub use drop::DropController;
pub use grasp::GraspController;

/// Which final-phase task a controller performs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FinalPhaseKind {
    /// Grasp the object and lift it (`"grasp"`).
    Grasp,
    /// Drop the held object into a container without stopping (`"drop"`).
    Drop,
    /// Press a button from above and retract (`"press-button"`).
    PressButton,
}

impl FinalPhaseKind {
    /// Every kind, in a fixed order.
    pub const ALL: [FinalPhaseKind; 3] = [Self::Grasp, Self::Drop, Self::PressButton];

    /// The name used on the command line and in configuration files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Grasp => "grasp",
            Self::Drop => "drop",
            Self::PressButton => "press-button",
        }
    }
}

impl From<TaskKind> for FinalPhaseKind {
    /// The controller that performs a mission task: pick → grasp, place → drop.
    fn from(task: TaskKind) -> Self {
        match task {
            TaskKind::Pick => Self::Grasp,
            TaskKind::Place => Self::Drop,
            TaskKind::PressButton => Self::PressButton,
        }
    }
}

impl fmt::Display for FinalPhaseKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A final-phase controller name that does not exist.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown final-phase controller '{name}': expected one of grasp, drop, press-button")]
pub struct UnknownFinalPhaseKind {
    /// The name that was given.
    pub name: String,
}

impl FromStr for FinalPhaseKind {
    type Err = UnknownFinalPhaseKind;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|kind| kind.name() == s)
            .ok_or_else(|| UnknownFinalPhaseKind {
                name: s.to_string(),
            })
    }
}

/// What a final-phase controller reads each control cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalPhaseInput {
    /// Time of this cycle, s (monotonic; only differences are used).
    pub t: f64,
    /// Measured world pose of the tool (TCP); its z axis is the approach direction.
    pub tool_pose: Isometry3<f64>,
    /// Base pose in the world (odometry).
    pub base_pose: BasePose,
    /// Measured base velocity; its forward speed sets the servo speed limit v_B·k_A.
    pub base_velocity: BaseVelocity,
    /// The task's target: the cube centre (grasp), the container centre at rim height (drop),
    /// or the centre of the button's top surface (press-button), with its world velocity.
    pub target: TargetEstimate,
    /// Measured distance between the gripper fingers, m.
    pub gripper_opening: f64,
    /// Measured world velocity of the tool point, m/s ([`ToolVelocityEstimate`]; zero when
    /// not yet known).
    pub tool_velocity: Vector3<f64>,
    /// The gripper yaw that grasps the object, rad, when the task is a pick and the object's
    /// yaw is known (the grasp servos the tool to it; other tasks ignore it).
    pub grasp_yaw: Option<f64>,
}

impl FinalPhaseInput {
    /// True when every number in the input is finite.
    pub fn is_finite(&self) -> bool {
        let pose_finite = self
            .tool_pose
            .translation
            .vector
            .iter()
            .all(|x| x.is_finite())
            && self.tool_pose.rotation.coords.iter().all(|x| x.is_finite());
        let base_finite = [
            self.base_pose.x,
            self.base_pose.y,
            self.base_pose.yaw,
            self.base_velocity.v,
            self.base_velocity.omega,
        ]
        .iter()
        .all(|x| x.is_finite());
        let target_finite = self
            .target
            .position
            .iter()
            .chain(self.target.velocity.iter())
            .chain(self.tool_velocity.iter())
            .chain(self.grasp_yaw.iter())
            .all(|x| x.is_finite());
        self.t.is_finite()
            && self.gripper_opening.is_finite()
            && pose_finite
            && base_finite
            && target_finite
    }
}

/// The tool point's world velocity, estimated from its measured positions: the displacement over
/// the last `window` seconds. The window spans several odometry periods: the tool pose is the
/// arm's forward kinematics at the latest odometry pose, which arrives at 50 Hz while the joints
/// are measured every cycle, so the pose saws back and forth by the base's motion in one odometry
/// period, and a one-cycle difference reads that as ±0.1 m/s. A step implying more than
/// `max_speed` (an odometry jump) is not motion: the estimate starts again from there.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolVelocityEstimate {
    /// Span of the displacement, s.
    pub window: f64,
    /// Fastest believable tool speed, m/s.
    pub max_speed: f64,
    samples: std::collections::VecDeque<(f64, Vector3<f64>)>,
    velocity: Vector3<f64>,
}

impl Default for ToolVelocityEstimate {
    /// 60 ms (three odometry periods) and 3 m/s (beyond any arm of the stack's TCP speed).
    fn default() -> Self {
        Self {
            window: 0.06,
            max_speed: 3.0,
            samples: std::collections::VecDeque::new(),
            velocity: Vector3::zeros(),
        }
    }
}

impl ToolVelocityEstimate {
    /// Takes the tool position measured at `t` and returns the velocity estimate (zero until a
    /// window's worth of samples is in). A time that does not advance, or a non-finite sample,
    /// leaves the estimate as it is.
    pub fn update(&mut self, t: f64, position: Vector3<f64>) -> Vector3<f64> {
        if !(t.is_finite() && position.iter().all(|x| x.is_finite())) {
            return self.velocity;
        }
        if let Some(&(last_t, last_position)) = self.samples.back() {
            if t <= last_t {
                return self.velocity;
            }
            if (position - last_position).norm() > self.max_speed * (t - last_t) {
                self.samples.clear();
                self.velocity = Vector3::zeros();
            }
        }
        self.samples.push_back((t, position));
        while self.samples.len() > 2 && t - self.samples[1].0 >= self.window {
            self.samples.pop_front();
        }
        if let Some(&(first_t, first_position)) = self.samples.front()
            && t - first_t >= self.window
        {
            self.velocity = (position - first_position) / (t - first_t);
        }
        self.velocity
    }
}

/// Which step of its task a controller is in (for logging and the mission sequencer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum FinalPhaseStage {
    /// Servoing toward the working pose (grasp point, release point or hover pose).
    #[default]
    Approach,
    /// Gripper closing on the object while servoing continues.
    Closing,
    /// Object held, tool rising to the lift height.
    Lifting,
    /// Gripper opening over the container while servoing continues.
    Releasing,
    /// Tool moving down onto the button.
    Pushing,
    /// Tool returning to the hover pose above the button.
    Retracting,
    /// The task's motion is complete; the tool holds its final pose relative to the target.
    Done,
}

impl FinalPhaseStage {
    /// A short lower-case name for logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Approach => "approach",
            Self::Closing => "closing",
            Self::Lifting => "lifting",
            Self::Releasing => "releasing",
            Self::Pushing => "pushing",
            Self::Retracting => "retracting",
            Self::Done => "done",
        }
    }

    /// [`TaskProgress::Done`] for [`FinalPhaseStage::Done`], otherwise active.
    pub fn progress(self) -> TaskProgress {
        if self == Self::Done {
            TaskProgress::Done
        } else {
            TaskProgress::Active
        }
    }
}

impl fmt::Display for FinalPhaseStage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What a final-phase controller commands each control cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalPhaseOutput {
    /// World-frame tool twist `[vx, vy, vz, wx, wy, wz]` for the redundancy resolver; always finite.
    pub twist: Twist,
    /// What the gripper should do.
    pub gripper: GripperCommand,
    /// Whether the task's motion is complete.
    pub progress: TaskProgress,
    /// The controller's current stage.
    pub stage: FinalPhaseStage,
    /// True when this cycle's input was not finite: the twist is zero and nothing advanced.
    pub input_rejected: bool,
}

impl FinalPhaseOutput {
    /// An output for `stage` with the given twist; a non-finite twist is replaced by zero.
    fn new(twist: Twist, gripper: GripperCommand, stage: FinalPhaseStage) -> Self {
        let twist = if twist.iter().all(|x| x.is_finite()) {
            twist
        } else {
            Twist::zeros()
        };
        Self {
            twist,
            gripper,
            progress: stage.progress(),
            stage,
            input_rejected: false,
        }
    }

    /// The answer to non-finite input: zero twist, same gripper command and stage.
    fn hold(gripper: GripperCommand, stage: FinalPhaseStage) -> Self {
        Self {
            input_rejected: true,
            ..Self::new(Twist::zeros(), gripper, stage)
        }
    }
}

/// A final-phase task controller: a pure step function with internal task state.
///
/// Implementations are `Send` so a controller can be moved into the thread or process that runs
/// it and replaced by another at run time.
pub trait FinalPhaseController: Send {
    /// Computes this cycle's command. Non-finite input yields a zero twist and holds the state.
    fn step(&mut self, input: &FinalPhaseInput) -> FinalPhaseOutput;
    /// Which task this controller performs.
    fn kind(&self) -> FinalPhaseKind;
    /// Forgets all task state, ready to start the task again from the approach.
    fn reset(&mut self);
}

/// Builds the controller for `kind` with `config`.
pub fn build(kind: FinalPhaseKind, config: &FinalPhaseConfig) -> Box<dyn FinalPhaseController> {
    match kind {
        FinalPhaseKind::Grasp => Box::new(GraspController::new(config.servo, config.grasp)),
        FinalPhaseKind::Drop => Box::new(DropController::new(config.servo, config.drop)),
        FinalPhaseKind::PressButton => Box::new(ButtonController::new(config.servo, config.button)),
    }
}

/// The servo law shared by every final-phase controller.
///
/// Linear: `v = sat(k_P·(p* − p), v_corr) + v_ff`, then `|v| ≤ max_linear_speed`, where
/// `v_corr = clamp(|v_B|·k_A, min_correction_speed, max_linear_speed)` and `v_ff` is the target's
/// velocity. The paper caps the servo speed at v_B·k_A; the cap applies to the correction term
/// only, so that feed-forward of a moving target is never cut, and the floor keeps a slow or
/// stopped base from freezing the arm. Angular: `ω = sat(k_R·θ·u, max_angular_speed)`, where
/// θ·u is the smallest rotation that turns the tool z axis to world −z (top-down; the tool's yaw
/// is left where it is, since the target estimate carries no yaw).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServoConfig {
    /// Proportional gain k_P on the world-frame position error, 1/s (paper: 5).
    pub position_gain: f64,
    /// k_A: the correction speed limit is this times the base forward speed (paper: 0.5).
    pub speed_gain: f64,
    /// Floor of the correction speed limit, m/s, used when the base is slow or stopped (0.05).
    pub min_correction_speed: f64,
    /// Hard limit on the commanded linear speed, feed-forward included, m/s (0.5).
    pub max_linear_speed: f64,
    /// Proportional gain on the top-down orientation error, 1/s (2.0).
    pub orientation_gain: f64,
    /// Hard limit on the commanded angular speed, rad/s (1.0).
    pub max_angular_speed: f64,
}

impl Default for ServoConfig {
    fn default() -> Self {
        Self {
            position_gain: 5.0,
            speed_gain: 0.5,
            min_correction_speed: 0.05,
            max_linear_speed: 0.5,
            orientation_gain: 2.0,
            max_angular_speed: 1.0,
        }
    }
}

impl ServoConfig {
    /// The correction speed limit for the current base velocity, m/s.
    pub fn correction_speed_limit(&self, base_velocity: &BaseVelocity) -> f64 {
        (base_velocity.v.abs() * self.speed_gain)
            .clamp(self.min_correction_speed, self.max_linear_speed)
    }

    /// The servo twist that brings the tool to `goal` (world position) top-down, with
    /// `feed_forward` added to the saturated correction and the correction capped at
    /// `correction_limit` (m/s).
    pub fn twist(
        &self,
        tool_pose: &Isometry3<f64>,
        goal: &Vector3<f64>,
        feed_forward: &Vector3<f64>,
        correction_limit: f64,
    ) -> Twist {
        self.twist_to_yaw(tool_pose, goal, feed_forward, correction_limit, None)
    }

    /// [`Self::twist`], and with `yaw` the tool is also turned about the vertical to that yaw
    /// (top-down at `yaw`, as the reacher aims it) instead of only tilted top-down.
    pub fn twist_to_yaw(
        &self,
        tool_pose: &Isometry3<f64>,
        goal: &Vector3<f64>,
        feed_forward: &Vector3<f64>,
        correction_limit: f64,
        yaw: Option<f64>,
    ) -> Twist {
        let error = goal - tool_pose.translation.vector;
        let correction = saturate(error * self.position_gain, correction_limit);
        let linear = saturate(correction + feed_forward, self.max_linear_speed);
        let orientation_error = match yaw {
            Some(yaw) => {
                (crate::reacher::top_down(yaw) * tool_pose.rotation.inverse()).scaled_axis()
            }
            None => top_down_error(&tool_pose.rotation),
        };
        let angular = saturate(
            orientation_error * self.orientation_gain,
            self.max_angular_speed,
        );
        Twist::new(
            linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
        )
    }

    fn validate(&self, file: &Path) -> Result<(), ModelError> {
        let fields = [
            ("servo.position_gain", self.position_gain),
            ("servo.speed_gain", self.speed_gain),
            ("servo.min_correction_speed", self.min_correction_speed),
            ("servo.max_linear_speed", self.max_linear_speed),
            ("servo.orientation_gain", self.orientation_gain),
            ("servo.max_angular_speed", self.max_angular_speed),
        ];
        require_positive(file, &fields)?;
        if self.min_correction_speed > self.max_linear_speed {
            return Err(ModelError::invalid(
                file,
                "servo.min_correction_speed",
                format!(
                    "{} exceeds servo.max_linear_speed = {}",
                    self.min_correction_speed, self.max_linear_speed
                ),
            ));
        }
        Ok(())
    }
}

/// Scales `v` down so that its norm is at most `limit`.
fn saturate(v: Vector3<f64>, limit: f64) -> Vector3<f64> {
    let norm = v.norm();
    if norm > limit { v * (limit / norm) } else { v }
}

/// The world-frame rotation vector (axis × angle) that turns the tool z axis onto world −z.
fn top_down_error(rotation: &UnitQuaternion<f64>) -> Vector3<f64> {
    let approach = rotation * Vector3::z();
    let down = -Vector3::z();
    match UnitQuaternion::rotation_between(&approach, &down) {
        Some(turn) => turn.scaled_axis(),
        // Pointing straight up: any horizontal axis works; use the tool x axis.
        None => (rotation * Vector3::x()) * std::f64::consts::PI,
    }
}

/// The angle between the tool z axis and world −z, rad.
pub fn top_down_angle(rotation: &UnitQuaternion<f64>) -> f64 {
    top_down_error(rotation).norm()
}

/// Tunables of the three controllers, read from a TOML file with tables `[servo]`, `[grasp]`,
/// `[drop]` and `[button]`; every key is optional and unknown keys are errors.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FinalPhaseConfig {
    /// The servo law shared by all controllers.
    pub servo: ServoConfig,
    /// The grasp controller.
    pub grasp: GraspConfig,
    /// The drop controller.
    pub drop: DropConfig,
    /// The press-button controller.
    pub button: ButtonConfig,
}

impl FinalPhaseConfig {
    /// Loads and checks a config file, naming the file and key on error.
    pub fn load(file: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(file)?;
        Self::from_toml_str(file, &text)
    }

    /// Parses and checks TOML text that came from `file`.
    pub fn from_toml_str(file: &Path, text: &str) -> Result<Self, ModelError> {
        let config: Self = ModelError::parse_toml_str(file, text)?;
        config.validate(file)?;
        Ok(config)
    }

    /// Checks that every value is finite and in range; `file` is named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        self.servo.validate(file)?;
        self.grasp.validate(file)?;
        self.drop.validate(file)?;
        self.button.validate(file)
    }
}

/// Fails on the first `(key, value)` that is not finite and strictly positive.
fn require_positive(file: &Path, fields: &[(&str, f64)]) -> Result<(), ModelError> {
    match fields.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        Some((key, value)) => Err(ModelError::invalid(
            file,
            *key,
            format!("must be a finite number above zero, got {value}"),
        )),
        None => Ok(()),
    }
}

/// Tunables of the grasp controller.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraspConfig {
    /// ε_g: the gripper closes when the tool is within this distance of the grasp point, m.
    /// 0.01: a 30 mm cube in the 80 mm Franka Hand leaves 25 mm per side, so 1 cm keeps the
    /// fingers well clear while servoing continues to tighten the error during closure.
    pub close_distance: f64,
    /// The gripper closes only when the tool z axis is also within this angle of world −z,
    /// rad (0.087 = 5°: closing while tilted would push the cube with one finger first).
    pub close_max_tilt: f64,
    /// Grasp point relative to the target (cube centre), world frame, m. Zero grasps the centre.
    pub grasp_offset: [f64; 3],
    /// Slope of the descent cone: while approaching, the goal is raised by this times the
    /// horizontal error, so the fingers come down onto the object rather than sweep into it
    /// from the side (1.0: a 45° cone; 0 disables it).
    pub descent_slope: f64,
    /// The cone's horizontal error is also taken where the tool comes to rest relative to the
    /// object when braked at this deceleration, when that is farther off, m/s² (1.0; 0 disables
    /// it): v²/2a along its relative velocity v. A reach that ran late hands the tool over still
    /// moving at a few decimetres a second, and the twist's rate limit (1.05 m/s² at 0.3 m/s)
    /// brakes it over centimetres: measured from where the tool is, the cone let the fingers
    /// down onto the object's top edge as the tool overshot it (Exp 2 knock-offs). 0.5 m/s²
    /// kept Exp 1's tool over the cube longer (9.98 s against 9.72 s at 0.4 m/s); 1.0 costs
    /// 0.03 s there.
    pub descent_braking: f64,
    /// The grasp counts as closed when the finger opening falls to this, m (0.032: the 30 mm
    /// cube plus 2 mm).
    pub closed_opening: f64,
    /// The hand counts as open above this opening, m (0.07: the Franka Hand opens to 0.08, the
    /// grippers of the other robots wider). A controller whose first cycle finds the hand less
    /// open than this with the tool at the grasp point was restarted during the closure.
    pub open_opening: f64,
    /// Lift anyway after closing this long, s, in case the fingers stall above
    /// `closed_opening` (1.0; the hand needs about 0.5 s to close).
    pub closing_timeout: f64,
    /// How far to lift the object after closing, m (0.1).
    pub lift_height: f64,
    /// Done when the tool is within this of the lift height, m (0.01).
    pub lift_tolerance: f64,
    /// Done anyway after lifting this long, s (1.5; a 0.1 m lift at the servo's speed limit
    /// takes about 0.7 s). With the base driving away from the grasp point (a turn toward the
    /// next target right after the grasp) the arm is stretched and the tool cannot rise the
    /// whole lift height there; the next phase's reach carries the object on from wherever it
    /// is, instead of the phase never ending.
    pub lifting_timeout: f64,
}

impl Default for GraspConfig {
    fn default() -> Self {
        Self {
            close_distance: 0.01,
            close_max_tilt: 5f64.to_radians(),
            grasp_offset: [0.0; 3],
            descent_slope: 1.0,
            descent_braking: 1.0,
            closed_opening: 0.032,
            open_opening: 0.07,
            closing_timeout: 1.0,
            lift_height: 0.1,
            lift_tolerance: 0.01,
            lifting_timeout: 1.5,
        }
    }
}

impl GraspConfig {
    fn validate(&self, file: &Path) -> Result<(), ModelError> {
        require_positive(
            file,
            &[
                ("grasp.close_distance", self.close_distance),
                ("grasp.close_max_tilt", self.close_max_tilt),
                ("grasp.closed_opening", self.closed_opening),
                ("grasp.open_opening", self.open_opening),
                ("grasp.closing_timeout", self.closing_timeout),
                ("grasp.lift_height", self.lift_height),
                ("grasp.lift_tolerance", self.lift_tolerance),
                ("grasp.lifting_timeout", self.lifting_timeout),
            ],
        )?;
        require_non_negative(file, "grasp.descent_slope", self.descent_slope)?;
        require_non_negative(file, "grasp.descent_braking", self.descent_braking)?;
        if let Some(bad) = self.grasp_offset.iter().find(|x| !x.is_finite()) {
            return Err(ModelError::invalid(
                file,
                "grasp.grasp_offset",
                format!("must be finite, got {bad}"),
            ));
        }
        Ok(())
    }
}

/// Fails unless `value` is finite and not negative.
fn require_non_negative(file: &Path, key: &str, value: f64) -> Result<(), ModelError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ModelError::invalid(
            file,
            key,
            format!("must be a finite number, zero or above, got {value}"),
        ))
    }
}

/// Tunables of the drop-into-container controller.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DropConfig {
    /// Height of the release point above the container's rim centre, m (0.1: the cube falls
    /// clear of the rim without bouncing out).
    pub release_height: f64,
    /// The gripper opens when the tool is within this distance of the release point, m (0.02).
    pub release_tolerance: f64,
    /// The drop counts as done when the finger opening reaches this, m (0.05: the 30 mm cube
    /// is free).
    pub released_opening: f64,
    /// Done anyway after opening this long, s (0.5).
    pub opening_timeout: f64,
}

impl Default for DropConfig {
    fn default() -> Self {
        Self {
            release_height: 0.1,
            release_tolerance: 0.02,
            released_opening: 0.05,
            opening_timeout: 0.5,
        }
    }
}

impl DropConfig {
    fn validate(&self, file: &Path) -> Result<(), ModelError> {
        require_non_negative(file, "drop.release_height", self.release_height)?;
        require_positive(
            file,
            &[
                ("drop.release_tolerance", self.release_tolerance),
                ("drop.released_opening", self.released_opening),
                ("drop.opening_timeout", self.opening_timeout),
            ],
        )
    }
}

/// Tunables of the press-button controller.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ButtonConfig {
    /// Height of the hover pose above the button's top surface, m (0.05).
    pub hover_height: f64,
    /// How far to push below the button's top surface, m (0.015). A button switches at a
    /// given travel (10 mm for the buttons of the scenarios, within a 20 mm stroke) and the
    /// push ends `depth_tolerance` short of this depth, so it must exceed the switching travel
    /// by more than that tolerance: 15 mm − 2 mm leaves 3 mm of margin and stays 5 mm inside
    /// the stroke.
    pub press_depth: f64,
    /// The hover pose is reached (before pushing, and after retracting) within this, m (0.005).
    pub hover_tolerance: f64,
    /// The push depth is reached within this, m (0.002).
    pub depth_tolerance: f64,
    /// Speed limit while pushing and retracting, m/s (0.05: a gentle press).
    pub push_speed: f64,
    /// Retract anyway after pushing this long, s, in case the button stops the tool short of
    /// the depth (2.0).
    pub push_timeout: f64,
    /// Done anyway after retracting this long, s (1.5; the 5 cm back up take 1 s at the push
    /// speed). As with the grasp's lift, a base driving on from the button can leave the arm
    /// unable to hold the hover pose within its tolerance; the press has registered by then,
    /// and a retraction that never ended held the task while the base circled.
    pub retract_timeout: f64,
}

impl Default for ButtonConfig {
    fn default() -> Self {
        Self {
            hover_height: 0.05,
            press_depth: 0.015,
            hover_tolerance: 0.005,
            depth_tolerance: 0.002,
            push_speed: 0.05,
            push_timeout: 2.0,
            retract_timeout: 1.5,
        }
    }
}

impl ButtonConfig {
    fn validate(&self, file: &Path) -> Result<(), ModelError> {
        require_positive(
            file,
            &[
                ("button.hover_height", self.hover_height),
                ("button.press_depth", self.press_depth),
                ("button.hover_tolerance", self.hover_tolerance),
                ("button.depth_tolerance", self.depth_tolerance),
                ("button.push_speed", self.push_speed),
                ("button.push_timeout", self.push_timeout),
                ("button.retract_timeout", self.retract_timeout),
            ],
        )
    }
}

/// When the current stage began, for the time-outs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct StageClock {
    started: Option<f64>,
}

impl StageClock {
    /// Seconds since the stage began at `t` (never negative); starts the clock on first use.
    fn elapsed(&mut self, t: f64) -> f64 {
        let started = *self.started.get_or_insert(t);
        (t - started).max(0.0)
    }

    /// Restarts the clock at `t`.
    fn restart(&mut self, t: f64) {
        self.started = Some(t);
    }
}

#[cfg(test)]
mod sim;

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn kind_names_round_trip_and_unknown_names_are_errors() {
        for kind in FinalPhaseKind::ALL {
            assert_eq!(kind.to_string().parse::<FinalPhaseKind>(), Ok(kind));
        }
        assert_eq!(
            "press-button".parse::<FinalPhaseKind>(),
            Ok(FinalPhaseKind::PressButton)
        );
        let err = "push".parse::<FinalPhaseKind>().unwrap_err();
        assert_eq!(err.name, "push");
        let message = err.to_string();
        assert!(
            message.contains("'push'") && message.contains("press-button"),
            "{message}"
        );
        assert!("Grasp".parse::<FinalPhaseKind>().is_err());
    }

    #[test]
    fn task_kinds_map_to_their_controllers() {
        assert_eq!(FinalPhaseKind::from(TaskKind::Pick), FinalPhaseKind::Grasp);
        assert_eq!(FinalPhaseKind::from(TaskKind::Place), FinalPhaseKind::Drop);
        assert_eq!(
            FinalPhaseKind::from(TaskKind::PressButton),
            FinalPhaseKind::PressButton
        );
    }

    #[test]
    fn the_tool_velocity_spans_the_odometry_period_and_restarts_on_a_jump() {
        // A tool at rest in the world while the base drives at 0.3 m/s: the joints are measured
        // every 5 ms but the odometry only every 20 ms, so the pose saws by 6 mm.
        let mut estimate = ToolVelocityEstimate::default();
        let mut worst: f64 = 0.0;
        for step in 0..200 {
            let t = step as f64 * 0.005;
            let since_odometry = t % 0.02;
            let sawtooth = Vector3::new(0.3 * since_odometry, 0.0, 0.0);
            let v = estimate.update(t, Vector3::new(1.0, 0.5, 0.5) + sawtooth);
            if t > 0.1 {
                worst = worst.max(v.norm());
            }
        }
        assert!(worst < 0.12, "a tool at rest read as moving at {worst} m/s");
        let one_cycle = 0.3 * 0.015 / 0.005;
        assert!(
            worst < one_cycle,
            "{worst} against {one_cycle} from one cycle"
        );

        // Moving steadily at 0.4 m/s along y it reads 0.4 m/s; a repeated time changes nothing.
        let mut estimate = ToolVelocityEstimate::default();
        let mut v = Vector3::zeros();
        for step in 0..40 {
            let t = step as f64 * 0.005;
            v = estimate.update(t, Vector3::new(0.0, 0.4 * t, 0.0));
        }
        assert!((v - Vector3::new(0.0, 0.4, 0.0)).norm() < 1e-9, "{v}");
        let t = 39.0 * 0.005;
        assert_eq!(estimate.update(t, Vector3::new(5.0, 5.0, 5.0)), v);
        assert_eq!(estimate.update(f64::NAN, Vector3::zeros()), v);

        // A jump of 10 cm in one cycle (20 m/s) is not motion: the estimate starts again.
        let jumped = estimate.update(0.2, Vector3::new(0.1, 0.08, 0.0));
        assert_eq!(jumped, Vector3::zeros());
        let after = estimate.update(0.3, Vector3::new(0.1, 0.08 + 0.04, 0.0));
        assert!(
            (after - Vector3::new(0.0, 0.4, 0.0)).norm() < 1e-9,
            "{after}"
        );
    }

    #[test]
    fn build_gives_the_requested_kind() {
        let config = FinalPhaseConfig::default();
        for kind in FinalPhaseKind::ALL {
            assert_eq!(build(kind, &config).kind(), kind);
        }
    }

    #[test]
    fn controllers_swap_at_run_time_through_the_trait() {
        fn assert_send<T: Send>(_: &T) {}
        let config = FinalPhaseConfig::default();
        let button = Vector3::new(1.0, 0.0, 0.6);
        let input = FinalPhaseInput {
            t: 0.0,
            tool_pose: Isometry3::new(button + Vector3::new(0.0, 0.0, 0.005), Vector3::x() * PI),
            base_pose: BasePose::default(),
            base_velocity: BaseVelocity { v: 0.3, omega: 0.0 },
            target: TargetEstimate::fixed(button),
            gripper_opening: 0.08,
            tool_velocity: Vector3::zeros(),
            grasp_yaw: None,
        };
        let mut active: Box<dyn FinalPhaseController> = build(FinalPhaseKind::Grasp, &config);
        assert_send(&active);
        // The grasp controller sees a "cube" 5 mm away and closes on it.
        let grasping = active.step(&input);
        assert_eq!(grasping.stage, FinalPhaseStage::Closing);
        assert_eq!(grasping.gripper, GripperCommand::Close);

        // Swap in the button controller by name, as `motm swap final-phase press-button` does.
        active = build("press-button".parse().unwrap(), &config);
        assert_eq!(active.kind(), FinalPhaseKind::PressButton);
        let pressing = active.step(&input);
        assert_eq!(pressing.stage, FinalPhaseStage::Approach);
        assert!(
            pressing.twist[2] > 0.0,
            "rises to the hover pose first: {}",
            pressing.twist
        );

        // And back: the new grasp controller starts from its own beginning.
        active = build(FinalPhaseKind::Grasp, &config);
        let mut far = input;
        far.tool_pose.translation.vector.z += 0.05;
        let fresh = active.step(&far);
        assert_eq!(fresh.stage, FinalPhaseStage::Approach);
        assert_eq!(fresh.gripper, GripperCommand::Open);

        // Every kind, driven through the same trait object, answers bad input the same way.
        let mut bad = input;
        bad.t = f64::NAN;
        for kind in FinalPhaseKind::ALL {
            let mut controller = build(kind, &config);
            let out = controller.step(&bad);
            assert_eq!(out.twist, Twist::zeros(), "{kind}");
            assert!(out.input_rejected, "{kind}");
            assert_eq!(out.stage, FinalPhaseStage::Approach, "{kind}");
            controller.reset();
            assert!(!controller.step(&input).input_rejected, "{kind}");
        }
    }

    #[test]
    fn config_parses_partial_toml_and_names_bad_keys() {
        let file = Path::new("final_phase.toml");
        let config = FinalPhaseConfig::from_toml_str(
            file,
            "[grasp]\nclose_distance = 0.008\n[button]\npress_depth = 0.02\n",
        )
        .unwrap();
        assert_eq!(config.grasp.close_distance, 0.008);
        assert_eq!(config.button.press_depth, 0.02);
        assert_eq!(config.servo, ServoConfig::default());

        let unknown = FinalPhaseConfig::from_toml_str(file, "[grasp]\nclose_dist = 0.01\n")
            .unwrap_err()
            .to_string();
        assert!(
            unknown.contains("final_phase.toml") && unknown.contains("close_dist"),
            "{unknown}"
        );

        let negative = FinalPhaseConfig::from_toml_str(file, "[servo]\nposition_gain = -5.0\n")
            .unwrap_err()
            .to_string();
        assert!(
            negative.contains("final_phase.toml") && negative.contains("servo.position_gain"),
            "{negative}"
        );

        let inverted = FinalPhaseConfig::from_toml_str(
            file,
            "[servo]\nmin_correction_speed = 0.6\nmax_linear_speed = 0.5\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            inverted.contains("servo.min_correction_speed"),
            "{inverted}"
        );
    }

    #[test]
    fn servo_saturates_correction_but_keeps_feed_forward() {
        let servo = ServoConfig::default();
        let tool = Isometry3::new(Vector3::zeros(), Vector3::x() * PI); // top-down
        let goal = Vector3::new(1.0, 0.0, 0.0);
        let feed_forward = Vector3::new(0.0, 0.03, 0.0);
        let limit = servo.correction_speed_limit(&BaseVelocity { v: 0.3, omega: 0.0 });
        assert!((limit - 0.15).abs() < 1e-12);
        let twist = servo.twist(&tool, &goal, &feed_forward, limit);
        assert!((twist[0] - 0.15).abs() < 1e-12, "{twist}");
        assert!((twist[1] - 0.03).abs() < 1e-12, "{twist}");
        assert!(
            twist.fixed_rows::<3>(3).norm() < 1e-9,
            "top-down needs no turn: {twist}"
        );

        // A stopped base still gets the floor; a fast one is capped by the hard limit.
        let stopped = servo.correction_speed_limit(&BaseVelocity::default());
        assert_eq!(stopped, servo.min_correction_speed);
        let fast = servo.correction_speed_limit(&BaseVelocity { v: 5.0, omega: 0.0 });
        assert_eq!(fast, servo.max_linear_speed);

        // Feed-forward beyond the hard limit is cut to it.
        let runaway = servo.twist(&tool, &goal, &Vector3::new(0.0, 3.0, 0.0), limit);
        assert!(runaway.fixed_rows::<3>(0).norm() <= servo.max_linear_speed + 1e-12);
    }

    #[test]
    fn orientation_term_turns_the_tool_down_within_its_limit() {
        let servo = ServoConfig::default();
        // Tool z pointing straight up (identity), and tilted 30° from down.
        for rotation in [
            UnitQuaternion::identity(),
            UnitQuaternion::from_scaled_axis(Vector3::x() * (PI - PI / 6.0)),
        ] {
            let tool = Isometry3::from_parts(Vector3::zeros().into(), rotation);
            let twist = servo.twist(&tool, &Vector3::zeros(), &Vector3::zeros(), 0.1);
            let omega = twist.fixed_rows::<3>(3).into_owned();
            assert!(omega.norm() <= servo.max_angular_speed + 1e-12);
            assert!(omega.norm() > 0.5, "{omega}");
            // A small step along ω reduces the angle to top-down.
            let turned = UnitQuaternion::from_scaled_axis(omega * 0.01) * rotation;
            assert!(top_down_angle(&turned) < top_down_angle(&rotation));
        }
    }
}
