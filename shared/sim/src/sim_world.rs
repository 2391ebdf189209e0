//! The simulated hardware as the multi-process stack sees it: the [`World`], the palm camera
//! and the trial metrics, stepped one physics period at a time from the latest hardware
//! commands. The sim-world process wraps this; it must behave like the in-process runner
//! ([`crate::runner`]), so it takes its rates, timeouts, camera and metric settings from the same
//! [`RunnerConfig`] and builds the camera the same way ([`PalmCamera::for_trial`]).
//!
//! Hardware commands that stop coming are not held forever: like the Panda's communication
//! reflex and the LD-60's own command timeout, once the newest command is older than
//! [`SimWorldConfig::command_timeout`] the hardware brakes to zero velocity on its own, within
//! the robot's velocity, acceleration and jerk limits (a [`CommandLimiter`] in its stale mode).
//! Fresh commands pass through unchanged: limiting them is the drivers' job.

use motm_core::command_limiter::{AxisLimits, CommandLimiter, CommandLimiterConfig, LimiterInput};
use motm_core::{BASE_JOINTS, BaseVelocity, GripperCommand, ModelError, Robot};

use crate::metrics::AccelerationMeter;
use crate::render::{CameraFrame, Exposure, PalmCamera, Scene};
use crate::runner::{RunnerConfig, SceneBuilder};
use crate::scenario::Scenario;
use crate::world::{FailureReason, HardwareCommand, Outcome, Sensors, Truth, World};

/// Settings of [`SimWorld`] beyond the [`RunnerConfig`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimWorldConfig {
    /// A hardware velocity command older than this is replaced by zero, s. Chosen 0.1 s: far
    /// beyond the drivers' periods (1 ms arm, 20 ms base), so only a dead or hung driver trips it.
    pub command_timeout: f64,
}

impl Default for SimWorldConfig {
    fn default() -> Self {
        Self {
            command_timeout: 0.1,
        }
    }
}

/// How a simulated trial stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrialStatus {
    /// Still running.
    Running,
    /// Decided by the world (success or a failure).
    Decided(Outcome),
    /// Ran past the time limit (the runner's `timeout_base + timeout_per_task · tasks`).
    TimedOut,
}

impl TrialStatus {
    /// The failure reason string as trial results report it (`None` while running or on
    /// success).
    pub fn failure(&self) -> Option<&'static str> {
        match self {
            Self::Running => None,
            Self::Decided(outcome) => outcome.failure(),
            Self::TimedOut => Some("timeout"),
        }
    }

    /// The world's failure reason, if the trial failed in the world.
    pub fn failure_reason(&self) -> Option<FailureReason> {
        match self {
            Self::Decided(Outcome::Failure(reason)) => Some(*reason),
            _ => None,
        }
    }
}

/// The newest hardware commands and their ages, as one physics step sees them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HardwareInput<'a> {
    /// Newest arm joint velocity command and its age, s.
    pub arm: Option<(&'a [f64], f64)>,
    /// Newest base velocity command and its age, s.
    pub base: Option<(BaseVelocity, f64)>,
    /// Newest gripper command (a gripper holds its last command; it never goes stale).
    pub gripper: Option<GripperCommand>,
}

/// Limiter input of a hardware brake: no command, so the limiter ramps to zero.
const BRAKE: LimiterInput<'static> = LimiterInput {
    command: None,
    command_age: None,
    safe_stop: false,
};

/// The world, camera and metrics of one simulated trial. See the module documentation.
pub struct SimWorld {
    world: World,
    camera: PalmCamera,
    scenes: SceneBuilder,
    no_scene: Scene,
    meter: AccelerationMeter,
    config: SimWorldConfig,
    physics_step: f64,
    steps_per_metric: u64,
    steps: u64,
    timeout: f64,
    status: TrialStatus,
    task_time: f64,
    command: HardwareCommand,
    arm_brake: CommandLimiter,
    base_brake: CommandLimiter,
}

impl SimWorld {
    /// A trial of `scenario` for `robot` with `seed`, timed and measured as `runner` says.
    /// Errors when the physics step or the robot's limits cannot drive the hardware brakes.
    pub fn new(
        robot: &Robot,
        scenario: &Scenario,
        seed: u64,
        runner: &RunnerConfig,
        config: SimWorldConfig,
    ) -> Result<Self, ModelError> {
        let limits = robot.limits();
        let brake = |axes: Vec<AxisLimits>| {
            CommandLimiter::new(axes, runner.physics_step, CommandLimiterConfig::default())
        };
        let arm_brake = brake(limits[BASE_JOINTS..].iter().map(AxisLimits::from).collect())?;
        // Base axes in [v, omega] order; the robot's joints are [yaw (omega), forward (v)].
        let base_brake = brake(vec![
            AxisLimits::from(&limits[1]),
            AxisLimits::from(&limits[0]),
        ])?;
        let world = World::new(robot, scenario, seed);
        let control_dt = 1.0 / runner.control_rate_hz;
        let steps_per_metric = (control_dt / runner.physics_step).round().max(1.0) as u64;
        let tasks = scenario.mission_tasks().len();
        Ok(Self {
            camera: PalmCamera::for_trial(&runner.camera, scenario, seed),
            scenes: SceneBuilder::new(&world),
            no_scene: Scene::default(),
            meter: AccelerationMeter::new(&runner.acceleration, control_dt),
            config,
            physics_step: runner.physics_step,
            steps_per_metric,
            steps: 0,
            timeout: runner.timeout_base + runner.timeout_per_task * tasks as f64,
            status: TrialStatus::Running,
            task_time: 0.0,
            command: HardwareCommand::idle(robot.arm_dof()),
            arm_brake,
            base_brake,
            world,
        })
    }

    /// One physics period, s.
    pub fn physics_step(&self) -> f64 {
        self.physics_step
    }

    /// The palm camera (its calibration is what perception should use).
    pub fn camera(&self) -> &PalmCamera {
        &self.camera
    }

    /// What the robot's sensors measure.
    pub fn sensors(&self) -> &Sensors {
        self.world.sensors()
    }

    /// Ground truth.
    pub fn truth(&self) -> &Truth {
        self.world.truth()
    }

    /// The world.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// How the trial stands; the first decision sticks.
    pub fn status(&self) -> TrialStatus {
        self.status
    }

    /// The mission ended having given a task up, or without every object where it belongs:
    /// the trial fails with `task_failed` at the next step (unless it is already decided).
    pub fn mission_gave_up(&mut self) {
        self.world.mission_gave_up();
    }

    /// Simulation time when the trial was decided (the current time while it runs), s.
    pub fn task_time(&self) -> f64 {
        match self.status {
            TrialStatus::Running => self.world.truth().time,
            _ => self.task_time,
        }
    }

    /// The EE acceleration meter (sampled at the control rate, as in the runner).
    pub fn meter(&self) -> &AccelerationMeter {
        &self.meter
    }

    /// The command in force in the last step.
    pub fn command(&self) -> &HardwareCommand {
        &self.command
    }

    /// Advances one physics period under the newest commands; returns the camera frame that
    /// became available, if any.
    pub fn step(&mut self, input: &HardwareInput) -> Option<CameraFrame> {
        let exposure = self.step_exposing(input)?;
        Some(self.camera.frame(&exposure))
    }

    /// [`SimWorld::step`] without drawing the frame that became available: it is returned as an
    /// [`Exposure`] for [`PalmCamera::render`] to draw into a buffer of the caller's, or to
    /// drop unseen. The world, the captures and every drawn frame are the same either way.
    pub fn step_exposing(&mut self, input: &HardwareInput) -> Option<Exposure> {
        let arm_dof = self.command.arm_qd.len();
        let timeout = self.config.command_timeout;
        match input.arm {
            Some((qd, age)) if age <= timeout && qd.len() == arm_dof => {
                self.command.arm_qd.copy_from_slice(qd);
                self.arm_brake.reset(qd);
            }
            _ => {
                let braked = self.arm_brake.step(&BRAKE);
                self.command.arm_qd.copy_from_slice(braked.velocity);
            }
        }
        match input.base {
            Some((base, age)) if age <= timeout => {
                self.command.base = base;
                self.base_brake.reset(&[base.v, base.omega]);
            }
            _ => {
                let braked = self.base_brake.step(&BRAKE).velocity;
                self.command.base = BaseVelocity {
                    v: braked[0],
                    omega: braked[1],
                };
            }
        }
        if let Some(gripper) = input.gripper {
            self.command.gripper = gripper;
        }
        self.world.step(self.physics_step, &self.command);
        self.steps += 1;
        let now = self.world.truth().time;
        let tool = self.world.truth().tool_pose;
        // The scene is only built when a frame is captured.
        let frame = if self.camera.next_capture() <= now {
            let scene = self.scenes.scene(&self.world);
            self.camera.expose(&scene, &tool, now)
        } else {
            self.camera.expose(&self.no_scene, &tool, now)
        };
        if self.steps.is_multiple_of(self.steps_per_metric) {
            self.meter.push(tool.translation.vector);
        }
        if self.status == TrialStatus::Running {
            if let Some(outcome) = self.world.decided() {
                self.status = TrialStatus::Decided(outcome);
                self.task_time = now;
            } else if now >= self.timeout {
                self.status = TrialStatus::TimedOut;
                self.task_time = now;
            }
        }
        frame
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_core::command_limiter::LimitMonitor;
    use std::path::Path;

    fn setup() -> (Robot, Scenario) {
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let robot = Robot::load(&config, "frankie").unwrap();
        let scenario = Scenario::from_file(&config.join("scenarios/exp1-dynamic.toml")).unwrap();
        (robot, scenario)
    }

    #[test]
    fn commands_move_the_robot_stale_ones_stop_it_and_frames_come_at_the_camera_rate() {
        let (robot, scenario) = setup();
        let runner = RunnerConfig::default();
        let mut sim =
            SimWorld::new(&robot, &scenario, 3, &runner, SimWorldConfig::default()).unwrap();
        let qd = vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5];
        let mut frames = 0;
        let start_q = sim.sensors().arm_q[6];
        let start_x = sim.truth().base_pose.x;
        for k in 0..500 {
            let input = HardwareInput {
                arm: Some((&qd, 0.0)),
                base: Some((BaseVelocity { v: 0.3, omega: 0.0 }, 0.0)),
                gripper: Some(GripperCommand::Open),
            };
            if let Some(frame) = sim.step(&input) {
                frames += 1;
                assert_eq!(frame.image.len(), (frame.width * frame.height * 3) as usize);
                assert!(frame.stamp <= (k + 1) as f64 * 0.001 + 1e-9);
            }
        }
        assert!((sim.truth().time - 0.5).abs() < 1e-9);
        // 30 Hz for 0.5 s, minus the frames still in flight.
        assert!((13..=16).contains(&frames), "{frames} frames");
        let moved_q = sim.sensors().arm_q[6] - start_q;
        assert!(moved_q > 0.15 && moved_q < 0.3, "joint 7 moved {moved_q}");
        assert!(sim.truth().base_pose.x > start_x + 0.02, "the base moved");
        assert!(sim.truth().arm_qd[6] > 0.4);
        // The same commands, now too old: the hardware brakes to zero within the limits.
        let limits = robot.limits();
        let mut monitor = LimitMonitor::new(
            &[
                AxisLimits::from(&limits[BASE_JOINTS + 6]),
                AxisLimits::from(&limits[1]),
            ],
            0.001,
            1e-9,
        );
        monitor.reset(&[0.5, 0.3]);
        let mut braking_steps = 0;
        for _ in 0..1000 {
            sim.step(&HardwareInput {
                arm: Some((&qd, 0.2)),
                base: Some((BaseVelocity { v: 0.3, omega: 0.0 }, 0.2)),
                gripper: None,
            });
            let command = sim.command();
            assert!(
                !monitor.check(&[command.arm_qd[6], command.base.v]),
                "{command:?}"
            );
            if command.base.v != 0.0 {
                braking_steps += 1;
            }
        }
        // 0.3 m/s at 0.8 m/s²: a ramp of 375 ms, not a step.
        assert!((370..=380).contains(&braking_steps), "{braking_steps}");
        assert_eq!(sim.command().arm_qd, vec![0.0; 7]);
        assert_eq!(sim.command().base, BaseVelocity::default());
        assert!(sim.truth().arm_qd[6].abs() < 1e-3);
        assert!(sim.truth().base_velocity.v.abs() < 0.05);
        assert_eq!(sim.status(), TrialStatus::Running);
        assert!(sim.meter().max() > 0.0);
    }

    #[test]
    fn the_trial_times_out_at_the_runner_limit() {
        let (robot, scenario) = setup();
        let runner = RunnerConfig {
            timeout_base: 0.05,
            timeout_per_task: 0.0,
            ..RunnerConfig::default()
        };
        let mut sim =
            SimWorld::new(&robot, &scenario, 3, &runner, SimWorldConfig::default()).unwrap();
        let idle = HardwareInput {
            arm: None,
            base: None,
            gripper: None,
        };
        for _ in 0..49 {
            sim.step(&idle);
        }
        assert_eq!(sim.status(), TrialStatus::Running);
        for _ in 0..10 {
            sim.step(&idle);
        }
        assert_eq!(sim.status(), TrialStatus::TimedOut);
        assert_eq!(sim.status().failure(), Some("timeout"));
        assert!((sim.task_time() - 0.05).abs() < 1.5e-3);
        assert!(sim.truth().time > sim.task_time());
    }
}
