//! The simulated world: a kinematic mobile manipulator with realistic imperfections, cubes on
//! platforms, containers, buttons, a gripper and its grasp model (docs/algorithms.md §4).
//!
//! [`World::step`] is a pure step function: it integrates the world by `dt` seconds under one
//! [`HardwareCommand`], in physics sub-steps of at most `1 / physics_rate_hz` (1 kHz). The robot
//! may read only [`World::sensors`] (odometry, joint encoders, gripper opening, time);
//! [`World::truth`] is for metrics, the renderer and tests. The world knows how each trial ends:
//! [`World::outcome`] (the first failure) and [`World::decided`] (when the trial is over: a
//! lost object ends a scenario of one object or button, but with more of them the mission goes
//! on, as a robot's would, until it ends or something worse happens).
//!
//! Imperfections of the robot, each from the scenario's `[noise]` table and the seed:
//! - **latency**: a command takes effect `noise.latency` seconds after it is given;
//! - **velocity error and noise**: each joint and each base axis has a per-trial gain error
//!   (normal, standard deviation `*_velocity_error`), plus per-step noise scaled from it;
//! - **tracking lag**: actual velocities follow the (erroneous) command through first-order lags;
//! - **base acceleration limits**: from the URDF `<limit acceleration>` of the base joints;
//! - **odometry drift**: odometry integrates the true motion with per-trial scale errors of
//!   forward speed and yaw rate (standard deviation `odometry_drift`), so the measured pose drifts
//!   from the true pose by about that fraction of the distance travelled.
//!
//! The world is kinematic: the gripper collides only with free cubes (see [`crate::grasp`]), the
//! base only with platforms and containers, and the arm with nothing. A released cube counts as
//! placed only in its own container (the one at its scenario `place`).

use std::collections::VecDeque;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::Deserialize;

use crate::geometry::OrientedBox;
use crate::grasp::{self, Contact, CubeInTool, GraspConfig, GraspMiss};
use crate::gripper::{Gripper, GripperConfig};
use crate::objects::{
    ButtonTruth, CubeMover, Layout, ObjectConfig, ObjectState, ObjectTruth, resting_pose,
};
use crate::random::{SimRng, Stream};
use crate::scenario::Scenario;
use motm_core::{BASE_JOINTS, BasePose, BaseVelocity, GripperCommand, JointLimits, Robot};

/// Tunables of the simulated world that are not part of a scenario.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WorldConfig {
    /// Physics rate, Hz: [`World::step`] integrates in sub-steps of at most one period.
    pub physics_rate_hz: f64,
    /// Time constant of the first-order lag with which arm joints track their velocity
    /// command, s (a torque-controlled Panda joint follows within a few tens of ms).
    pub arm_time_constant: f64,
    /// Time constant of the first-order lag with which the base tracks its velocity command, s.
    pub base_time_constant: f64,
    /// Standard deviation of the per-step velocity noise, as a multiple of the per-trial gain
    /// error's standard deviation (the noise is white at the physics rate, before the lag).
    pub velocity_noise_ratio: f64,
    /// Per-trial error factors are clamped to this many standard deviations.
    pub error_clamp_sigmas: f64,
    /// Height of the base body, m, for collisions with platforms and containers.
    pub base_height: f64,
    /// Objects, platforms, containers and buttons.
    pub objects: ObjectConfig,
    /// The gripper.
    pub gripper: GripperConfig,
    /// The grasp model.
    pub grasp: GraspConfig,
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            physics_rate_hz: 1000.0,
            arm_time_constant: 0.02,
            base_time_constant: 0.1,
            velocity_noise_ratio: 0.5,
            error_clamp_sigmas: 3.0,
            base_height: 0.4,
            objects: ObjectConfig::default(),
            gripper: GripperConfig::default(),
            grasp: GraspConfig::default(),
        }
    }
}

/// What the robot's drivers send to the hardware in one cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct HardwareCommand {
    /// Arm joint velocities, rad/s (or m/s for prismatic joints), in chain order without the
    /// virtual base joints.
    pub arm_qd: Vec<f64>,
    /// Base forward speed and yaw rate.
    pub base: BaseVelocity,
    /// Open or close the gripper.
    pub gripper: GripperCommand,
}

impl HardwareCommand {
    /// Everything still, gripper open.
    pub fn idle(arm_dof: usize) -> Self {
        Self {
            arm_qd: vec![0.0; arm_dof],
            base: BaseVelocity::default(),
            gripper: GripperCommand::Open,
        }
    }

    /// Whether the command has `arm_dof` joint velocities and only finite numbers.
    pub fn is_valid(&self, arm_dof: usize) -> bool {
        self.arm_qd.len() == arm_dof
            && self.arm_qd.iter().all(|v| v.is_finite())
            && self.base.v.is_finite()
            && self.base.omega.is_finite()
    }
}

/// What the robot can measure: everything a real robot's drivers report.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensors {
    /// Simulation time, s.
    pub time: f64,
    /// Base pose from odometry (drifts from the true pose).
    pub base_pose: BasePose,
    /// Base velocity from odometry.
    pub base_velocity: BaseVelocity,
    /// Arm joint positions from the encoders.
    pub arm_q: Vec<f64>,
    /// Arm joint velocities from the encoders.
    pub arm_qd: Vec<f64>,
    /// Opening between the gripper fingers, m.
    pub gripper_opening: f64,
}

/// The true state of the world, for metrics, the renderer and tests: never for the controllers.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// Simulation time, s.
    pub time: f64,
    /// True base pose.
    pub base_pose: BasePose,
    /// True base velocity.
    pub base_velocity: BaseVelocity,
    /// Arm joint positions.
    pub arm_q: Vec<f64>,
    /// Arm joint velocities.
    pub arm_qd: Vec<f64>,
    /// World pose of the tool (grasp point between the fingertips).
    pub tool_pose: Isometry3<f64>,
    /// World linear velocity of the tool point, m/s.
    pub tool_velocity: Vector3<f64>,
    /// Opening between the gripper fingers, m.
    pub gripper_opening: f64,
    /// Index of the held cube.
    pub held_object: Option<usize>,
    /// The cubes, in scenario order.
    pub objects: Vec<ObjectTruth>,
    /// The buttons, in scenario order.
    pub buttons: Vec<ButtonTruth>,
}

/// Why a trial failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FailureReason {
    /// The gripper hit a cube outside the grasp window and knocked it off its platform.
    KnockedOff,
    /// A grasp attempt closed on nothing.
    MissedGrasp,
    /// A released cube landed outside its container.
    DroppedOutside,
    /// The base drove into a platform or a container.
    BaseCollision,
    /// The mission gave a task up (its target was not reached on any approach) and ended
    /// without every object placed and every button pressed.
    TaskFailed,
}

impl FailureReason {
    /// Whether the failure loses one object (knocked off, missed, dropped outside) and leaves
    /// the robot able to go on with the rest of its mission.
    pub fn object_lost(&self) -> bool {
        matches!(
            self,
            Self::KnockedOff | Self::MissedGrasp | Self::DroppedOutside
        )
    }

    /// The reason as reported in trial results: `knocked_off`, `missed_grasp`,
    /// `dropped_outside`, `base_collision` or `task_failed`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::KnockedOff => "knocked_off",
            Self::MissedGrasp => "missed_grasp",
            Self::DroppedOutside => "dropped_outside",
            Self::BaseCollision => "base_collision",
            Self::TaskFailed => "task_failed",
        }
    }
}

/// How a trial ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Every cube landed in its container and every button was pressed.
    Success,
    /// The first failure.
    Failure(FailureReason),
}

impl Outcome {
    /// The failure reason string, or `None` for a success.
    pub fn failure(&self) -> Option<&'static str> {
        match self {
            Self::Success => None,
            Self::Failure(reason) => Some(reason.as_str()),
        }
    }
}

/// A cube held between the fingers.
#[derive(Debug, Clone, Copy)]
struct Held {
    index: usize,
    /// Cube pose in the tool frame (centred between the fingers, faces square to them).
    in_tool: Isometry3<f64>,
    /// Opening at which the fingers hold it.
    width: f64,
}

/// One failure as it happened: when, why, which object and how (the trial's result keeps them
/// all, so a run that lost several objects shows each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mishap {
    /// Simulated time, s.
    pub time: f64,
    /// What happened.
    pub reason: FailureReason,
    /// Index of the object concerned (scenario order), if one was.
    pub object: Option<usize>,
    /// How: for a knock-off, the gripper part and the closure's state ("palm", "finger",
    /// "finger, closing, cube out of the grasp window: height", ...); empty otherwise.
    pub detail: &'static str,
}

/// A closure of the gripper in progress, tracked against the grasp window.
#[derive(Debug, Clone, Copy)]
struct Closure {
    /// The cube that has been in the grasp window since the closure began.
    candidate: Option<usize>,
    /// The free cube nearest the tool point when the closure began, if one was within the
    /// attempt distance (the closure is then a grasp attempt).
    nearest: Option<usize>,
    /// Why the candidate left the grasp window, when it did (or why the nearest cube was out of
    /// it when the closure began, when no cube was in it).
    lost: Option<GraspMiss>,
}

/// Per-trial error factors, drawn once from the seed.
#[derive(Debug, Clone)]
struct TrialErrors {
    arm_gain: Vec<f64>,
    base_gain: [f64; 2],
    odometry_scale: [f64; 2],
}

/// The simulated world. See the module documentation.
#[derive(Debug, Clone)]
pub struct World {
    config: WorldConfig,
    robot: Robot,
    layout: Layout,
    obstacles: Vec<OrientedBox>,
    truth: Truth,
    sensors: Sensors,
    latency: f64,
    base_velocity_error: f64,
    arm_velocity_error: f64,
    errors: TrialErrors,
    pending: VecDeque<(f64, HardwareCommand)>,
    active: HardwareCommand,
    arm_limits: Vec<JointLimits>,
    base_limits: [JointLimits; 2],
    full_q: Vec<f64>,
    gripper: Gripper,
    closure: Option<Closure>,
    held: Option<Held>,
    movers: Vec<CubeMover>,
    base_noise: SimRng,
    arm_noise: SimRng,
    object_motion: SimRng,
    outcome: Option<Outcome>,
    mishaps: Vec<Mishap>,
    /// A failure that ends the trial has happened (any but a lost object), or the mission ended.
    ended: bool,
    rejected_commands: u64,
}

impl World {
    /// A world for `robot` in `scenario`, with the default [`WorldConfig`]; `seed` decides every
    /// random draw.
    pub fn new(robot: &Robot, scenario: &Scenario, seed: u64) -> Self {
        Self::with_config(robot, scenario, seed, WorldConfig::default())
    }

    /// A world with explicit tunables.
    pub fn with_config(robot: &Robot, scenario: &Scenario, seed: u64, config: WorldConfig) -> Self {
        let arm_dof = robot.arm_dof();
        let noise = &scenario.noise;
        let mut constants = SimRng::new(seed, Stream::TrialConstants);
        let sigmas = config.error_clamp_sigmas;
        let mut factor = |std: f64| 1.0 + constants.clamped_normal(std, sigmas);
        let errors = TrialErrors {
            arm_gain: (0..arm_dof)
                .map(|_| factor(noise.arm_velocity_error))
                .collect(),
            base_gain: [
                factor(noise.base_velocity_error),
                factor(noise.base_velocity_error),
            ],
            odometry_scale: [factor(noise.odometry_drift), factor(noise.odometry_drift)],
        };
        let layout = Layout::new(scenario, &config.objects);
        let obstacles = layout.obstacles().collect();
        let movers = scenario
            .objects
            .iter()
            .map(|o| CubeMover::new(o, &mut constants))
            .collect();
        let objects = scenario
            .objects
            .iter()
            .map(|o| ObjectTruth {
                pose: resting_pose(
                    Vector3::from(o.position),
                    constants.normal(config.objects.initial_yaw_std),
                ),
                velocity: Vector3::zeros(),
                state: ObjectState::OnPlatform,
                placed_time: None,
            })
            .collect();
        let limits = robot.limits();
        let arm_q = robot.config.ready_pose.clone();
        let start = scenario.start();
        let mut full_q = vec![0.0; BASE_JOINTS];
        full_q.extend_from_slice(&arm_q);
        let tool_pose = robot.chain.tool_pose(&start.isometry(), &full_q);
        let gripper = Gripper::open(&config.gripper);
        let truth = Truth {
            time: 0.0,
            base_pose: start,
            base_velocity: BaseVelocity::default(),
            arm_q: arm_q.clone(),
            arm_qd: vec![0.0; arm_dof],
            tool_pose,
            tool_velocity: Vector3::zeros(),
            gripper_opening: gripper.opening,
            held_object: None,
            objects,
            buttons: vec![ButtonTruth::default(); scenario.buttons.len()],
        };
        let sensors = Sensors {
            time: 0.0,
            base_pose: start,
            base_velocity: BaseVelocity::default(),
            arm_q,
            arm_qd: vec![0.0; arm_dof],
            gripper_opening: gripper.opening,
        };
        Self {
            robot: robot.clone(),
            layout,
            obstacles,
            truth,
            sensors,
            latency: noise.latency,
            base_velocity_error: noise.base_velocity_error,
            arm_velocity_error: noise.arm_velocity_error,
            errors,
            pending: VecDeque::new(),
            active: HardwareCommand::idle(arm_dof),
            arm_limits: limits[BASE_JOINTS..].to_vec(),
            base_limits: [limits[0], limits[1]],
            full_q,
            gripper,
            closure: None,
            held: None,
            movers,
            base_noise: SimRng::new(seed, Stream::BaseNoise),
            arm_noise: SimRng::new(seed, Stream::ArmNoise),
            object_motion: SimRng::new(seed, Stream::ObjectMotion),
            outcome: None,
            mishaps: Vec::new(),
            ended: false,
            rejected_commands: 0,
            config,
        }
    }

    /// What the robot can measure now.
    pub fn sensors(&self) -> &Sensors {
        &self.sensors
    }

    /// The true state of the world now.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// The fixed geometry: platforms, containers, buttons.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The robot model the world simulates.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// The tunables in use.
    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    /// The trial's result so far: `None` while nothing is decided, else success or the first
    /// failure (which sticks).
    pub fn outcome(&self) -> Option<Outcome> {
        self.outcome
    }

    /// How the trial ended, or `None` while it still runs. A lost object
    /// ([`FailureReason::object_lost`]) ends it only when the scenario has a single object or
    /// button (its pick and place are all there is to do): with more, the mission goes on with
    /// the tasks that do not need that object, and the trial ends, with that first failure,
    /// when the mission ends ([`World::mission_gave_up`]) or on a failure of any other kind.
    pub fn decided(&self) -> Option<Outcome> {
        let outcome = self.outcome?;
        let targets = self.truth.objects.len() + self.truth.buttons.len();
        let over = self.ended || outcome == Outcome::Success || targets <= 1;
        over.then_some(outcome)
    }

    /// The mission ended having given a task up, or without every object where it belongs:
    /// the trial ends, failed with [`FailureReason::TaskFailed`] unless it had already failed.
    pub fn mission_gave_up(&mut self) {
        self.fail(FailureReason::TaskFailed, None, "");
    }

    /// Every failure so far, in order.
    pub fn mishaps(&self) -> &[Mishap] {
        &self.mishaps
    }

    /// Number of commands dropped because they had the wrong length or a non-finite value.
    pub fn rejected_commands(&self) -> u64 {
        self.rejected_commands
    }

    /// Puts the robot at `base` (true and measured) with the arm at `arm_q`, at rest. For tests
    /// and scripted set-ups; a held cube moves with the tool.
    pub fn teleport_robot(&mut self, base: BasePose, arm_q: &[f64]) {
        assert_eq!(arm_q.len(), self.robot.arm_dof(), "arm joint vector length");
        self.truth.base_pose = base;
        self.truth.base_velocity = BaseVelocity::default();
        self.truth.arm_q.copy_from_slice(arm_q);
        self.truth.arm_qd.iter_mut().for_each(|v| *v = 0.0);
        self.truth.tool_pose = self.compute_tool_pose();
        self.truth.tool_velocity = Vector3::zeros();
        self.move_held_cube();
        self.sensors.base_pose = base;
        self.update_sensors();
    }

    /// Advances the world by `dt` seconds under `command`, given now. The command takes effect
    /// after the scenario's latency. A command with the wrong number of joints or a non-finite
    /// value is dropped (counted in [`World::rejected_commands`]) and the previous one stays in
    /// force. A non-positive or non-finite `dt` does nothing.
    pub fn step(&mut self, dt: f64, command: &HardwareCommand) {
        if !(dt.is_finite() && dt > 0.0) {
            return;
        }
        if command.is_valid(self.robot.arm_dof()) {
            self.pending
                .push_back((self.truth.time + self.latency, command.clone()));
        } else {
            self.rejected_commands += 1;
        }
        let substeps = (dt * self.config.physics_rate_hz - 1e-9).ceil().max(1.0) as usize;
        let h = dt / substeps as f64;
        for _ in 0..substeps {
            self.substep(h);
        }
        self.update_sensors();
    }

    fn substep(&mut self, h: f64) {
        while let Some((due, _)) = self.pending.front() {
            if *due > self.truth.time + 1e-12 {
                break;
            }
            let (_, command) = self.pending.pop_front().expect("front exists");
            self.active = command;
        }
        self.integrate_arm(h);
        self.integrate_base(h);
        let previous_tool = self.truth.tool_pose.translation.vector;
        self.truth.tool_pose = self.compute_tool_pose();
        self.truth.tool_velocity = (self.truth.tool_pose.translation.vector - previous_tool) / h;
        self.truth.time += h;
        self.step_gripper(h);
        self.step_objects(h);
        self.check_knocks();
        self.check_base_collision();
        self.step_buttons();
        self.check_success();
    }

    fn integrate_arm(&mut self, h: f64) {
        let alpha = 1.0 - (-h / self.config.arm_time_constant).exp();
        let noise_std = self.config.velocity_noise_ratio * self.arm_velocity_error;
        for i in 0..self.truth.arm_q.len() {
            let limits = &self.arm_limits[i];
            let command = self.active.arm_qd[i];
            let target = (command * self.errors.arm_gain[i]
                + self.arm_noise.normal(noise_std * command.abs()))
            .clamp(-limits.velocity, limits.velocity);
            let qd = &mut self.truth.arm_qd[i];
            *qd += (target - *qd) * alpha;
            let q = &mut self.truth.arm_q[i];
            *q += *qd * h;
            if *q < limits.position_min || *q > limits.position_max {
                *q = q.clamp(limits.position_min, limits.position_max);
                *qd = 0.0;
            }
        }
    }

    fn integrate_base(&mut self, h: f64) {
        let alpha = 1.0 - (-h / self.config.base_time_constant).exp();
        let noise_std = self.config.velocity_noise_ratio * self.base_velocity_error;
        let commands = [self.active.base.omega, self.active.base.v];
        let mut actual = [self.truth.base_velocity.omega, self.truth.base_velocity.v];
        for axis in 0..2 {
            let limits = &self.base_limits[axis];
            let command = commands[axis];
            let target = command * self.errors.base_gain[axis]
                + self.base_noise.normal(noise_std * command.abs());
            let lagged = actual[axis] + (target - actual[axis]) * alpha;
            let max_change = limits.acceleration * h;
            actual[axis] = (actual[axis] + (lagged - actual[axis]).clamp(-max_change, max_change))
                .clamp(-limits.velocity, limits.velocity);
        }
        let velocity = BaseVelocity {
            omega: actual[0],
            v: actual[1],
        };
        self.truth.base_velocity = velocity;
        advance_pose(&mut self.truth.base_pose, velocity, h);
        let measured = BaseVelocity {
            omega: velocity.omega * self.errors.odometry_scale[0],
            v: velocity.v * self.errors.odometry_scale[1],
        };
        self.sensors.base_velocity = measured;
        advance_pose(&mut self.sensors.base_pose, measured, h);
    }

    fn compute_tool_pose(&mut self) -> Isometry3<f64> {
        self.full_q[BASE_JOINTS..].copy_from_slice(&self.truth.arm_q);
        self.robot
            .chain
            .tool_pose(&self.truth.base_pose.isometry(), &self.full_q)
    }

    fn update_sensors(&mut self) {
        self.sensors.time = self.truth.time;
        self.sensors.arm_q.copy_from_slice(&self.truth.arm_q);
        self.sensors.arm_qd.copy_from_slice(&self.truth.arm_qd);
        self.sensors.gripper_opening = self.gripper.opening;
    }

    fn fail(&mut self, reason: FailureReason, object: Option<usize>, detail: &'static str) {
        // A collision is checked every step while it lasts, and a give-up may be reported
        // again: one record of a failure that concerns no object is enough.
        let repeated = object.is_none() && self.mishaps.iter().any(|m| m.reason == reason);
        if !repeated {
            self.mishaps.push(Mishap {
                time: self.truth.time,
                reason,
                object,
                detail,
            });
        }
        if self.outcome.is_none() {
            self.outcome = Some(Outcome::Failure(reason));
        }
        self.ended |= !reason.object_lost();
    }

    fn cube_half(&self) -> f64 {
        0.5 * self.config.objects.cube_size
    }

    fn step_gripper(&mut self, h: f64) {
        let command = self.active.gripper;
        if command != self.gripper.command {
            self.gripper.command = command;
            self.closure = match command {
                GripperCommand::Close if self.held.is_none() => Some(self.begin_closure()),
                _ => None,
            };
        }
        self.gripper
            .step(h, &self.config.gripper, self.held.map(|held| held.width));
        match command {
            GripperCommand::Close => self.follow_closure(),
            GripperCommand::Open => self.release_if_open(),
        }
        self.truth.gripper_opening = self.gripper.opening;
        self.truth.held_object = self.held.map(|held| held.index);
    }

    fn begin_closure(&self) -> Closure {
        let tool = &self.truth.tool_pose;
        let mut candidate: Option<(usize, f64)> = None;
        let mut nearest: Option<(usize, f64, Option<GraspMiss>)> = None;
        for (index, object) in self.truth.objects.iter().enumerate() {
            if object.state != ObjectState::OnPlatform {
                continue;
            }
            let relative = CubeInTool::new(tool, &object.pose);
            let distance = relative.offset.norm();
            let window = grasp::check_window(
                &relative,
                self.gripper.opening,
                self.config.objects.cube_size,
                &self.config.gripper,
                &self.config.grasp,
            );
            if distance <= self.config.grasp.attempt_distance
                && nearest.is_none_or(|(_, best, _)| distance < best)
            {
                nearest = Some((index, distance, window.err()));
            }
            if window.is_ok() && candidate.is_none_or(|(_, best)| distance < best) {
                candidate = Some((index, distance));
            }
        }
        let candidate = candidate.map(|(index, _)| index);
        Closure {
            candidate,
            nearest: nearest.map(|(index, _, _)| index),
            // The nearest cube was out of the window from the start.
            lost: nearest
                .and_then(|(_, _, miss)| miss)
                .filter(|_| candidate.is_none()),
        }
    }

    /// Follows a closure: keeps the candidate only while it stays in the grasp window, pushes it
    /// to the middle as the fingers close, and grasps it when they reach it.
    fn follow_closure(&mut self) {
        let Some(mut closure) = self.closure else {
            return;
        };
        let tool = self.truth.tool_pose;
        let opening = self.gripper.opening;
        if let Some(index) = closure.candidate {
            let cube = &mut self.truth.objects[index];
            let relative = CubeInTool::new(&tool, &cube.pose);
            let in_window = grasp::check_window(
                &relative,
                opening,
                self.config.objects.cube_size,
                &self.config.gripper,
                &self.config.grasp,
            );
            if in_window.is_err() || cube.state != ObjectState::OnPlatform {
                closure.candidate = None;
                closure.lost = in_window.err();
            } else {
                // The squeeze turns the cube square to the fingers, which stop at its edge length.
                let width = self.config.objects.cube_size;
                if opening <= width {
                    self.gripper.opening = width;
                    let aligned = UnitQuaternion::from_axis_angle(
                        &Vector3::z_axis(),
                        relative.yaw_misalignment,
                    ) * (tool.rotation.inverse() * cube.pose.rotation);
                    let centred = Vector3::new(relative.offset.x, 0.0, relative.offset.z);
                    self.held = Some(Held {
                        index,
                        in_tool: Isometry3::from_parts(centred.into(), aligned),
                        width,
                    });
                    cube.state = ObjectState::Held;
                    self.closure = None;
                    self.move_held_cube();
                    return;
                }
                // The fingers push the cube toward the middle: it may be off centre by at most
                // half the gap that is left.
                let room = 0.5 * (opening - width);
                if relative.offset.y.abs() > room {
                    let shift = relative.offset.y.signum() * room - relative.offset.y;
                    let mut push = tool.rotation * Vector3::y() * shift;
                    push.z = 0.0;
                    cube.pose.translation.vector += push;
                }
            }
        }
        if opening <= 0.0 {
            if closure.nearest.is_some() {
                self.fail(FailureReason::MissedGrasp, closure.nearest, "");
            }
            self.closure = None;
        } else {
            self.closure = Some(closure);
        }
    }

    fn release_if_open(&mut self) {
        let Some(held) = self.held else {
            return;
        };
        if self.gripper.opening > held.width + self.config.grasp.release_clearance {
            self.held = None;
            let cube = &mut self.truth.objects[held.index];
            cube.state = ObjectState::Falling;
            cube.velocity = self.truth.tool_velocity;
            self.settle_falling(held.index);
        }
    }

    fn move_held_cube(&mut self) {
        if let Some(held) = self.held {
            let cube = &mut self.truth.objects[held.index];
            cube.pose = self.truth.tool_pose * held.in_tool;
            cube.velocity = self.truth.tool_velocity;
        }
    }

    fn step_objects(&mut self, h: f64) {
        self.move_held_cube();
        let gravity = self.config.objects.gravity;
        for index in 0..self.truth.objects.len() {
            let cube = &mut self.truth.objects[index];
            match cube.state {
                ObjectState::OnPlatform => {
                    let mut position = cube.pose.translation.vector;
                    cube.velocity = self.movers[index].step(
                        &mut position,
                        h,
                        &mut self.object_motion,
                        &self.config.objects,
                    );
                    cube.pose.translation.vector = position;
                }
                ObjectState::Falling => {
                    cube.velocity.z -= gravity * h;
                    cube.pose.translation.vector += cube.velocity * h;
                    self.settle_falling(index);
                }
                _ => {}
            }
        }
    }

    /// Decides where a falling cube lands once its bottom reaches the rim of its container.
    fn settle_falling(&mut self, index: usize) {
        let half = self.cube_half();
        let container = self.layout.containers[self.layout.object_container[index]];
        let time = self.truth.time;
        let cube = &mut self.truth.objects[index];
        let position = cube.pose.translation.vector;
        if position.z - half > container.rim_center.z {
            return;
        }
        let inside = container.footprint_holds(&position, half);
        cube.velocity = Vector3::zeros();
        cube.pose = resting_pose(Vector3::new(position.x, position.y, half), cube.yaw());
        if inside {
            cube.state = ObjectState::Placed;
            cube.placed_time = Some(time);
        } else {
            cube.state = ObjectState::DroppedOutside;
            self.fail(FailureReason::DroppedOutside, Some(index), "");
        }
    }

    /// A gripper part that overlaps a free cube knocks it off, unless it is a finger closing on
    /// the cube that has been in the grasp window since the closure began.
    fn check_knocks(&mut self) {
        let tool = self.truth.tool_pose;
        let half = self.cube_half();
        let candidate = self.closure.and_then(|c| c.candidate);
        for index in 0..self.truth.objects.len() {
            let cube = &self.truth.objects[index];
            if cube.state != ObjectState::OnPlatform {
                continue;
            }
            let cube_box = OrientedBox::new(&cube.pose, Vector3::repeat(half));
            let hit = match grasp::contact(
                &self.config.gripper,
                &tool,
                self.gripper.opening,
                &cube_box,
            ) {
                Contact::None => None,
                Contact::Finger if candidate == Some(index) => None,
                Contact::Finger => Some(match self.closure {
                    None => "finger",
                    Some(Closure {
                        lost: Some(miss), ..
                    }) => miss.knock_detail(),
                    Some(_) => "finger, closing on another cube or none",
                }),
                Contact::Palm => Some("palm"),
            };
            if let Some(detail) = hit {
                self.knock_off(index, detail);
            }
        }
    }

    /// Throws a cube off its platform, in the direction the tool was moving relative to it.
    fn knock_off(&mut self, index: usize, detail: &'static str) {
        let platform = self.layout.platforms[index];
        let half_platform = platform.half_extents.x.max(platform.half_extents.y);
        let throw = half_platform + self.config.objects.knock_off_throw;
        let half = self.cube_half();
        let cube = &mut self.truth.objects[index];
        let relative = self.truth.tool_velocity - cube.velocity;
        let mut direction = Vector3::new(relative.x, relative.y, 0.0);
        if direction.norm() < 1e-9 {
            let away = cube.pose.translation.vector - self.truth.tool_pose.translation.vector;
            direction = Vector3::new(away.x, away.y, 0.0);
        }
        let direction = direction.try_normalize(1e-12).unwrap_or(Vector3::x());
        let landing = platform.center + direction * throw;
        cube.pose = resting_pose(Vector3::new(landing.x, landing.y, half), cube.yaw());
        cube.velocity = Vector3::zeros();
        cube.state = ObjectState::KnockedOff;
        self.fail(FailureReason::KnockedOff, Some(index), detail);
    }

    fn check_base_collision(&mut self) {
        let [length, width] = self.robot.config.footprint;
        let pose = self.truth.base_pose;
        let body = OrientedBox::upright(
            pose.x,
            pose.y,
            pose.yaw,
            0.5 * length,
            0.5 * width,
            self.config.base_height,
        );
        if self.obstacles.iter().any(|o| o.intersects(&body)) {
            self.fail(FailureReason::BaseCollision, None, "");
        }
    }

    /// A button's cap follows the tool point down while the tool point is over it; the press
    /// latches when the travel reaches the button's depth.
    fn step_buttons(&mut self) {
        let tool = self.truth.tool_pose.translation.vector;
        for (button, state) in self.layout.buttons.iter().zip(&mut self.truth.buttons) {
            let horizontal = (tool.xy() - button.top_center.xy()).norm();
            state.travel = if horizontal <= button.radius {
                (button.top_center.z - tool.z).clamp(0.0, self.config.objects.button_height)
            } else {
                0.0
            };
            if !state.pressed && state.travel >= button.depth {
                state.pressed = true;
                state.pressed_time = Some(self.truth.time);
            }
        }
    }

    fn check_success(&mut self) {
        if self.outcome.is_some() {
            return;
        }
        let placed = self
            .truth
            .objects
            .iter()
            .all(|o| o.state == ObjectState::Placed);
        let pressed = self.truth.buttons.iter().all(|b| b.pressed);
        if placed && pressed {
            self.outcome = Some(Outcome::Success);
        }
    }
}

/// Integrates a planar pose by one step: turn by ω·h, then move v·h along the new heading
/// (docs/algorithms.md §1).
fn advance_pose(pose: &mut BasePose, velocity: BaseVelocity, h: f64) {
    pose.yaw = motm_core::wrap_angle(pose.yaw + velocity.omega * h);
    pose.x += velocity.v * h * pose.yaw.cos();
    pose.y += velocity.v * h * pose.yaw.sin();
}
