//! The simulated hardware as a task: it steps the world from the newest hardware commands of
//! the drivers and publishes the arm, base and gripper state every physics step, palm-camera
//! images at the camera rate (stamped with their exposure time) and the ground truth.
//!
//! Time: the world's time 0 is the task's first cycle. Each cycle runs the physics steps due
//! since then (one when the runtime keeps up; at most `max_catch_up` after lost timer ticks,
//! beyond which the simulation falls behind). A hardware command older than the world's
//! command timeout is braked to zero within the robot's limits.

use std::sync::Arc;

use motm_core::BaseVelocity;
use motm_graph::{Task, ports, shared_zeroed};
use motm_msgs::{self as msgs, topics};

use motm_tasks::convert::stamped;

use crate::messages;
use crate::sim_world::{HardwareInput, SimWorld, TrialStatus};

ports! {
    /// What the simulated hardware reads.
    pub struct SimWorldInputs {
        /// The arm driver's joint velocity command.
        latest arm: msgs::ArmVelocityCommand = topics::HW_ARM_COMMAND,
        /// The base driver's twist command.
        latest base: msgs::BaseVelocityCommand = topics::HW_BASE_COMMAND,
        /// The arm driver's gripper command.
        latest gripper: msgs::GripperCommand = topics::HW_GRIPPER_COMMAND,
        /// The mission: once it is complete with a task given up, or complete for
        /// `MISSION_END_GRACE_S` with the trial undecided, the trial has failed.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
    }
}

ports! {
    /// What the simulated hardware publishes.
    pub struct SimWorldOutputs {
        /// Arm state.
        latest arm: msgs::JointState = topics::HW_ARM_STATE,
        /// Base state.
        latest base: msgs::BaseOdometry = topics::HW_BASE_STATE,
        /// Gripper state.
        latest gripper: msgs::GripperState = topics::HW_GRIPPER_STATE,
        /// A palm-camera image, when one became available.
        shared image: msgs::CameraImage = topics::CAMERA_IMAGE,
        /// Ground truth (every `truth_every` steps, and at once when the outcome is decided).
        latest truth: msgs::SimTruth = topics::SIM_TRUTH,
    }
}

/// The simulated-hardware task.
pub struct SimWorldTask {
    sim: SimWorld,
    period_ns: u64,
    truth_every: u64,
    max_catch_up: u64,
    origin_ns: Option<u64>,
    steps_done: u64,
    catch_up_cycles: u64,
    cycle: u64,
    last_status: TrialStatus,
    render: bool,
    arm_qd: Vec<f64>,
    /// When the mission was first seen complete, ns.
    complete_since_ns: Option<u64>,
}

/// A mission complete this long without the trial decided ended with a task not done, s: the
/// last drop's cube has landed well within it. A pick that took a neighbouring cube for its own
/// completes the mission with a cube left behind, and the trial ran to its timeout.
const MISSION_END_GRACE_S: f64 = 5.0;

impl SimWorldTask {
    /// The world `sim`, publishing the truth every `truth_every` physics steps and running at
    /// most `max_catch_up` steps per cycle.
    pub fn new(sim: SimWorld, truth_every: u64, max_catch_up: u64) -> Self {
        let period_ns = (sim.physics_step() * 1e9).round() as u64;
        Self {
            last_status: sim.status(),
            arm_qd: Vec::with_capacity(sim.command().arm_qd.len()),
            complete_since_ns: None,
            sim,
            period_ns: period_ns.max(1),
            truth_every: truth_every.max(1),
            max_catch_up: max_catch_up.max(1),
            origin_ns: None,
            steps_done: 0,
            catch_up_cycles: 0,
            cycle: 0,
            render: true,
        }
    }

    /// The world.
    pub fn sim(&self) -> &SimWorld {
        &self.sim
    }

    /// Whether camera frames are rendered. A frame nobody reads need not be: the world, the
    /// captures and every rendered frame are the same either way.
    pub fn set_rendering(&mut self, render: bool) {
        self.render = render;
    }
}

/// Age of a message stamped `stamp_ns` at `now_ns`, s.
fn age(now_ns: u64, stamp_ns: u64) -> f64 {
    now_ns.saturating_sub(stamp_ns) as f64 * 1e-9
}

impl Task for SimWorldTask {
    type Inputs = SimWorldInputs;
    type Outputs = SimWorldOutputs;

    fn name(&self) -> &'static str {
        motm_graph::SIM_WORLD.name
    }

    fn step(&mut self, now_ns: u64, inputs: &SimWorldInputs) -> SimWorldOutputs {
        let origin = *self.origin_ns.get_or_insert(now_ns);
        if let Some(mission) = &inputs.mission
            && msgs::TaskPhase::try_from(mission.phase) == Ok(msgs::TaskPhase::Complete)
        {
            let since = *self.complete_since_ns.get_or_insert(now_ns);
            if mission.failed_tasks > 0 || age(now_ns, since) >= MISSION_END_GRACE_S {
                self.sim.mission_gave_up();
            }
        }
        self.arm_qd.clear();
        let arm = inputs.arm.as_ref().map(|c| {
            self.arm_qd
                .extend_from_slice(&c.velocity[..c.joint_count as usize]);
            age(now_ns, c.header.stamp_ns)
        });
        let input = HardwareInput {
            arm: arm.map(|a| (self.arm_qd.as_slice(), a)),
            base: inputs.base.as_ref().map(|c| {
                (
                    BaseVelocity {
                        v: c.v,
                        omega: c.omega,
                    },
                    age(now_ns, c.header.stamp_ns),
                )
            }),
            gripper: inputs.gripper.as_ref().and_then(messages::gripper_command),
        };
        // Real time: run the steps that are due since the first cycle (normally one).
        let due = (now_ns - origin) / self.period_ns + 1 - self.steps_done;
        let steps = due.min(self.max_catch_up);
        if steps > 1 {
            self.catch_up_cycles += 1;
        }
        // Only the newest frame delivered in this cycle is drawn, straight into the message.
        let mut exposure = None;
        for _ in 0..steps {
            if let Some(e) = self.sim.step_exposing(&input) {
                exposure = Some(e);
            }
        }
        // Steps beyond the catch-up limit are dropped: the simulation falls behind.
        self.steps_done += due;
        let sensors = self.sim.sensors();
        let image = exposure.filter(|_| self.render).map(|exposure| {
            // The frame's age in simulated time, mapped onto the monotonic clock.
            let age = ((self.sim.truth().time - exposure.stamp()) * 1e9) as u64;
            let stamp = now_ns.saturating_sub(age);
            let mut shared = shared_zeroed::<msgs::CameraImage>();
            let image = Arc::get_mut(&mut shared).expect("a fresh message has one owner");
            messages::camera_image(self.sim.camera(), &exposure, image);
            image.header.stamp_ns = stamp.max(1);
            // `image_published_ns` stays 0: the publisher fills in when the frame is sent, the
            // start of the frame-to-command latency (after the render).
            shared
        });
        let status = self.sim.status();
        let truth = (self.cycle.is_multiple_of(self.truth_every) || status != self.last_status)
            .then(|| {
                self.last_status = status;
                stamped(messages::truth(&self.sim, self.catch_up_cycles), now_ns)
            });
        self.cycle += 1;
        SimWorldOutputs {
            arm: Some(stamped(messages::joint_state(sensors), now_ns)),
            base: Some(stamped(messages::odometry(sensors), now_ns)),
            gripper: Some(stamped(messages::gripper_state(self.sim.truth()), now_ns)),
            image,
            truth,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::RunnerConfig;
    use crate::scenario::Scenario;
    use crate::sim_world::{SimWorldConfig, TrialStatus};
    use motm_core::robot::Robot;
    use std::path::Path;

    /// The world of exp1-dynamic told, every 10 ms for `seconds`, that its mission is complete
    /// with `failed_tasks` given up; the trial's status after each second.
    fn told_complete(failed_tasks: u32, seconds: usize) -> Vec<TrialStatus> {
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let robot = Robot::load(&config, "frankie").unwrap();
        let scenario = Scenario::from_file(&config.join("scenarios/exp1-dynamic.toml")).unwrap();
        let runner = RunnerConfig::default();
        let sim = SimWorld::new(&robot, &scenario, 1, &runner, SimWorldConfig::default()).unwrap();
        let mut task = SimWorldTask::new(sim, 1, 20);
        task.render = false;
        let mut statuses = Vec::new();
        for k in 0..=(100 * seconds as u64) {
            let now_ns = k * 10_000_000;
            let inputs = SimWorldInputs {
                mission: Some(msgs::MissionState {
                    header: msgs::Header::new(now_ns, k),
                    task_index: 2,
                    task_count: 2,
                    task_kind: 1,
                    phase: msgs::TaskPhase::Complete as u32,
                    current_target: [0.0; 3],
                    next_target: [0.0; 3],
                    has_next: 0,
                    failed_tasks,
                    odometry_offset: [0.0; 3],
                    odometry_calibrated: 0,
                }),
                ..SimWorldInputs::default()
            };
            task.step(now_ns, &inputs);
            if k % 100 == 0 {
                statuses.push(task.sim().status());
            }
        }
        statuses
    }

    #[test]
    fn a_mission_complete_without_every_object_placed_fails_the_trial_after_a_grace() {
        let failed = TrialStatus::Decided(crate::world::Outcome::Failure(
            crate::world::FailureReason::TaskFailed,
        ));
        let statuses = told_complete(0, 6);
        // Within the grace the last drop's cube may still be falling: undecided.
        assert!(
            statuses[..5].iter().all(|s| *s == TrialStatus::Running),
            "{statuses:?}"
        );
        assert_eq!(statuses[6], failed);
        // With a task given up it fails at once.
        assert_eq!(told_complete(1, 1)[1], failed);
    }
}
