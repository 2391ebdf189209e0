//! The in-process runner: one trial of a scenario with every module in one process, stepping in
//! lockstep simulated time as fast as the CPU allows.
//!
//! Rates (config values): physics 1 kHz, camera 30 Hz (with its latency), control 200 Hz. Each
//! control cycle reads the sensors and the latest object estimate, runs the method's step
//! function and sends the command to the world, exactly what the deployed processes do over
//! shared memory.
//!
//! Object estimates: the current pick's cube and the current press's button cap are estimated by
//! perception from the rendered palm image (see `TaskKind::is_perceived`); until the first fix
//! the scenario's position stands in (what a mission would be given), and when the target leaves
//! the view the last estimate is held. Containers are known positions. Perception is reset when a
//! new task starts, with the scenario position as its hint.

use std::collections::VecDeque;
use std::time::Instant;

use motm_core::camera::CameraConfig;
use motm_core::final_phase::FinalPhaseStage;
use motm_core::mission::{MissionTask, Phase};
use motm_core::on_the_move::{OnTheMove, OnTheMoveConfig, OnTheMoveInput, OnTheMoveOutput};
use motm_core::perception::{Perception, PerceptionConfig, PerceptionInput};
use motm_core::planning::{PlanRequest, PlanningConfig, PlanningController};
use motm_core::reactive::{ReactiveBaseline, ReactiveConfig, ReactiveInput};
use motm_core::resolver::RedundancyResolver;
use motm_core::{GripperCommand, Robot, RobotState, TargetEstimate, TaskProgress};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::experiment::{Method, TrialResult, TrialTrace};
use crate::metrics::AccelerationFilterConfig;
use crate::objects::Button;
use crate::render::{
    BUTTON_BODY, BUTTON_RED, CONTAINER_BLUE, PLATFORM_WOOD, PalmCamera, Scene, SceneBox,
};
use crate::scenario::Scenario;
use crate::sim_world::{HardwareInput, SimWorld, SimWorldConfig, TrialStatus};
use crate::world::{HardwareCommand, Outcome, World};

/// Settings of the runner and of every method it can run.
#[derive(Debug, Clone)]
pub struct RunnerConfig {
    /// Control rate, Hz.
    pub control_rate_hz: f64,
    /// Physics step, s.
    pub physics_step: f64,
    /// A trial times out after this many seconds plus `timeout_per_task` per task.
    pub timeout_base: f64,
    /// Extra time allowed per mission task, s.
    pub timeout_per_task: f64,
    /// Record one trace sample every this many control cycles.
    pub trace_every: usize,
    /// Also record every control cycle in the trace ([`TrialTrace::cycles`]).
    pub record_cycles: bool,
    /// Palm camera (the scenario's noise overrides its pixel noise and extrinsic error).
    pub camera: CameraConfig,
    /// Perception.
    pub perception: PerceptionConfig,
    /// EE acceleration filter.
    pub acceleration: AccelerationFilterConfig,
    /// MotM.
    pub motm: OnTheMoveConfig,
    /// Reactive baseline.
    pub reactive: ReactiveConfig,
    /// Planning baseline.
    pub planning: PlanningConfig,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            control_rate_hz: 200.0,
            physics_step: 0.001,
            timeout_base: 30.0,
            timeout_per_task: 40.0,
            trace_every: 10,
            record_cycles: false,
            camera: CameraConfig::default(),
            perception: PerceptionConfig::default(),
            acceleration: AccelerationFilterConfig::default(),
            motm: OnTheMoveConfig::default(),
            reactive: ReactiveConfig::default(),
            planning: PlanningConfig::default(),
        }
    }
}

/// e_t used in the QP's 1/e_t weights when tracking the planning baseline's EE twist: small, so
/// the slack is expensive and the planned twist is followed.
const PLANNING_POSITION_ERROR: f64 = 0.02;

/// A method's controller, stepped at the control rate.
enum Controller {
    /// MotM.
    Motm(Box<OnTheMove>),
    /// The reactive baseline.
    Reactive(Box<ReactiveBaseline>),
    /// The planning baseline: the plan's tracker plus the QP that turns its EE twist into joint
    /// velocities while the base follows the plan.
    Planning(Box<PlanningController>, Box<RedundancyResolver>),
}

/// The scene the camera sees: the fixed layout plus the cubes and button caps where they are
/// now.
pub(crate) struct SceneBuilder {
    fixed: Scene,
    cube_size: f64,
    buttons: Vec<Button>,
    marking_thickness: f64,
}

impl SceneBuilder {
    /// The fixed part of the scene of `world`.
    pub(crate) fn new(world: &World) -> Self {
        let layout = world.layout();
        let mut fixed = Scene::default();
        for platform in &layout.platforms {
            let rotation = UnitQuaternion::from_matrix(&platform.axes);
            fixed.boxes.push(SceneBox {
                pose: Isometry3::from_parts(Translation3::from(platform.center), rotation),
                size: platform.half_extents * 2.0,
                colour: PLATFORM_WOOD,
            });
        }
        for container in &layout.containers {
            let outer = 2.0 * (container.inner_half + container.wall);
            fixed.add_container(
                container.rim_center,
                0.0,
                outer,
                outer,
                container.wall,
                CONTAINER_BLUE,
            );
        }
        Self {
            fixed,
            cube_size: layout.cube_size,
            buttons: layout.buttons.clone(),
            marking_thickness: world.config().objects.button_marking_thickness,
        }
    }

    /// The scene with the cubes where they are now and each button's cap pushed down by its
    /// travel now.
    pub(crate) fn scene(&self, world: &World) -> Scene {
        let mut scene = self.fixed.clone();
        for object in &world.truth().objects {
            let mut cube = SceneBox::cube(object.position(), 0.0, self.cube_size);
            cube.pose.rotation = object.pose.rotation;
            scene.boxes.push(cube);
        }
        for (button, state) in self.buttons.iter().zip(&world.truth().buttons) {
            self.add_button_cap(&mut scene, button, state.travel);
        }
        scene
    }

    /// A button's cap, pushed down by `travel`: a square of the cap's diameter (the renderer
    /// draws boxes), a dark body standing on the pedestal and a thin red marking on top.
    fn add_button_cap(&self, scene: &mut Scene, button: &Button, travel: f64) {
        let top = button.top_center - Vector3::z() * travel;
        let pedestal_top = button.top_center.z - button.height;
        let marking = self.marking_thickness.min(top.z - pedestal_top);
        let side = 2.0 * button.radius;
        let body_height = top.z - marking - pedestal_top;
        if body_height > 0.0 {
            scene.boxes.push(SceneBox {
                pose: Isometry3::translation(top.x, top.y, pedestal_top + 0.5 * body_height),
                size: Vector3::new(side, side, body_height),
                colour: BUTTON_BODY,
            });
        }
        if marking > 0.0 {
            scene.boxes.push(SceneBox {
                pose: Isometry3::translation(top.x, top.y, top.z - 0.5 * marking),
                size: Vector3::new(side, side, marking),
                colour: BUTTON_RED,
            });
        }
    }
}

/// Tracks the current task's target: perception for picks and presses, known positions
/// otherwise.
struct TargetTracker {
    tasks: Vec<MissionTask>,
    perception: Perception,
    config: PerceptionConfig,
    task: Option<usize>,
    /// Recent (time, estimated tool pose) pairs, to pair a frame with the pose at its stamp.
    tool_history: VecDeque<(f64, Isometry3<f64>)>,
}

impl TargetTracker {
    fn new(tasks: Vec<MissionTask>, config: PerceptionConfig, camera: &PalmCamera) -> Self {
        Self {
            tasks,
            perception: Perception::new(config, camera.calibration()),
            config,
            task: None,
            tool_history: VecDeque::new(),
        }
    }

    /// Switches to task `index`, resetting perception for a new task.
    fn select(&mut self, index: usize, camera: &PalmCamera) {
        if self.task != Some(index) {
            self.task = Some(index);
            self.perception = Perception::new(self.config, camera.calibration());
        }
    }

    /// Records the estimated tool pose at time `t`.
    fn record_tool(&mut self, t: f64, pose: Isometry3<f64>) {
        self.tool_history.push_back((t, pose));
        while self.tool_history.len() > 200 {
            self.tool_history.pop_front();
        }
    }

    /// Whether [`TargetTracker::observe`] reads camera frames now (perceived tasks only).
    fn wants_frames(&self) -> bool {
        self.task
            .and_then(|i| self.tasks.get(i))
            .is_some_and(|task| task.kind.is_perceived())
    }

    /// Feeds one camera frame to perception (perceived tasks only).
    fn observe(&mut self, image: &[u8], width: u32, height: u32, stamp: f64) {
        let Some(task) = self.task.and_then(|i| self.tasks.get(i)) else {
            return;
        };
        if !task.kind.is_perceived() {
            return;
        }
        let Some(&(_, tool_pose)) = self
            .tool_history
            .iter()
            .min_by(|a, b| (a.0 - stamp).abs().total_cmp(&(b.0 - stamp).abs()))
        else {
            return;
        };
        self.perception.step(&PerceptionInput {
            image,
            width,
            height,
            stamp,
            tool_pose,
            object_height: task.position.z,
            target_hint: Some(task.position),
        });
    }

    /// The current task's target estimate.
    fn target(&self) -> TargetEstimate {
        let Some(task) = self.task.and_then(|i| self.tasks.get(i)) else {
            return TargetEstimate::fixed(Vector3::zeros());
        };
        let estimate = self.perception.estimate();
        if task.kind.is_perceived() && estimate.valid {
            estimate.target()
        } else {
            TargetEstimate::fixed(task.position)
        }
    }
}

/// Number of MotM internal columns at the end of a trace row.
const MOTM_COLUMNS: usize = 9;

/// MotM's internals for the trace: phase, stage, twist (linear), tool-to-target distance, slack,
/// the base controller's speed target and the first arm joint.
fn motm_internals(out: &OnTheMoveOutput, arm_q: &[f64]) -> [f64; MOTM_COLUMNS] {
    let phase = match out.phase {
        Phase::Reach => 0.0,
        Phase::Final => 1.0,
        Phase::Complete => 2.0,
    };
    let stage = out.stage.map_or(-1.0, |stage| match stage {
        FinalPhaseStage::Approach => 0.0,
        FinalPhaseStage::Closing => 1.0,
        FinalPhaseStage::Lifting => 2.0,
        FinalPhaseStage::Releasing => 3.0,
        FinalPhaseStage::Pushing => 4.0,
        FinalPhaseStage::Retracting => 5.0,
        FinalPhaseStage::Done => 6.0,
    });
    [
        phase,
        stage,
        out.twist[0],
        out.twist[1],
        out.twist[2],
        out.tool_to_target,
        out.slack_norm,
        out.base_target.v,
        arm_q.first().copied().unwrap_or(0.0),
    ]
}

/// Runs one trial of `scenario` with `method`. `Err` only when the trial cannot be set up (e.g.
/// the planning baseline on a scenario with more than one object).
pub fn run_trial(
    robot: &Robot,
    scenario: &Scenario,
    method: Method,
    seed: u64,
    config: &RunnerConfig,
    record_trace: bool,
) -> Result<(TrialResult, Option<TrialTrace>), String> {
    let wall_start = Instant::now();
    let tasks = scenario.mission_tasks();
    // The same world, camera, metrics and verdict as the sim-world process; the command is always
    // fresh here (age 0), so its hardware brakes never engage.
    let mut sim = SimWorld::new(robot, scenario, seed, config, SimWorldConfig::default())
        .map_err(|e| e.to_string())?;
    let mut tracker = TargetTracker::new(tasks.clone(), config.perception, sim.camera());
    let start = scenario.start();
    let mut motm_config = config.motm.clone();
    motm_config.base.forward_speed = scenario.base_speed;
    let mut controller = match method {
        Method::Motm => Controller::Motm(Box::new(OnTheMove::new(
            robot.clone(),
            motm_config,
            tasks.clone(),
            Vector3::new(start.x, start.y, 0.0),
        ))),
        Method::Reactive => {
            let mut reactive = config.reactive.clone();
            reactive.max_base_speed = scenario.base_speed;
            Controller::Reactive(Box::new(ReactiveBaseline::new(
                robot.clone(),
                reactive,
                tasks.clone(),
            )))
        }
        Method::Planning => {
            let [object] = scenario.objects.as_slice() else {
                return Err(format!(
                    "{}: the planning baseline plans one pick and place; this scenario has {} objects",
                    scenario.path.display(),
                    scenario.objects.len()
                ));
            };
            let request = PlanRequest {
                start_base: start,
                start_base_speed: 0.0,
                cube: Vector3::from(object.position),
                container: Vector3::from(object.place),
                base_speed: scenario.base_speed,
            };
            match PlanningController::from_request(robot, &request, &config.planning) {
                Ok(tracker) => Controller::Planning(
                    Box::new(tracker),
                    Box::new(RedundancyResolver::for_robot(
                        robot,
                        config.motm.resolver.clone(),
                    )),
                ),
                Err(e) => {
                    let result = TrialResult {
                        success: false,
                        failure: Some(format!("plan_failed: {e}")),
                        task_time_s: 0.0,
                        mtph: 0.0,
                        ee_acc_mean: 0.0,
                        ee_acc_max: 0.0,
                        ee_acc_filter: String::new(),
                        sim_time_s: 0.0,
                        wall_time_s: wall_start.elapsed().as_secs_f64(),
                        round_trips_s: Vec::new(),
                    };
                    return Ok((result, None));
                }
            }
        }
    };

    let control_dt = 1.0 / config.control_rate_hz;
    let physics_per_control = (control_dt / config.physics_step).round().max(1.0) as usize;
    let mut trace = record_trace.then(|| TrialTrace {
        containers: sim
            .world()
            .layout()
            .containers
            .iter()
            .map(|c| (c.rim_center.x, c.rim_center.y))
            .collect(),
        objects: vec![Vec::new(); scenario.objects.len()],
        ..TrialTrace::default()
    });
    let mut cycle = 0usize;
    let mut internals = [0.0; MOTM_COLUMNS];
    while sim.status() == TrialStatus::Running {
        let sensors = sim.sensors().clone();
        let t = sensors.time;
        // The tool pose the robot believes it has (odometry + joints), for perception.
        let believed_tool = robot.tool_pose(&sensors.base_pose, &sensors.arm_q);
        tracker.record_tool(t, believed_tool);
        let task_index = match &controller {
            Controller::Motm(c) => c.mission().task_index(),
            Controller::Reactive(c) => c.task_index(),
            Controller::Planning(..) => 0,
        };
        tracker.select(task_index.min(tasks.len().saturating_sub(1)), sim.camera());
        let target = tracker.target();
        let command = match &mut controller {
            Controller::Motm(c) => {
                let out = c.step(&OnTheMoveInput {
                    t,
                    dt: control_dt,
                    base: sensors.base_pose,
                    base_velocity: sensors.base_velocity,
                    arm_q: &sensors.arm_q,
                    gripper_opening: sensors.gripper_opening,
                    target,
                });
                internals = motm_internals(&out, &sensors.arm_q);
                HardwareCommand {
                    arm_qd: out.arm_qd,
                    base: out.base,
                    gripper: out.gripper,
                }
            }
            Controller::Reactive(c) => {
                let out = c.step(&ReactiveInput {
                    t,
                    base: sensors.base_pose,
                    arm_q: &sensors.arm_q,
                    gripper_opening: sensors.gripper_opening,
                    target,
                });
                HardwareCommand {
                    arm_qd: out.arm_qd,
                    base: out.base,
                    gripper: out.gripper,
                }
            }
            Controller::Planning(tracker, resolver) => {
                let state = RobotState {
                    base: sensors.base_pose,
                    base_velocity: sensors.base_velocity,
                    arm_q: sensors.arm_q.clone(),
                    tool_pose: believed_tool,
                };
                let plan = tracker.step(t, &state);
                let resolved = resolver.resolve_motm(
                    robot,
                    &sensors.base_pose,
                    &sensors.arm_q,
                    plan.gripper_twist,
                    PLANNING_POSITION_ERROR,
                    Some(plan.base),
                );
                let gripper = if plan.progress == TaskProgress::Done {
                    GripperCommand::Open
                } else {
                    plan.gripper
                };
                HardwareCommand {
                    arm_qd: resolved.arm_qd,
                    base: resolved.base,
                    gripper,
                }
            }
        };
        let input = HardwareInput {
            arm: Some((&command.arm_qd, 0.0)),
            base: Some((command.base, 0.0)),
            gripper: Some(command.gripper),
        };
        // Frames perception would not read are not rendered (the same trial either way).
        let wants_frames = tracker.wants_frames();
        for _ in 0..physics_per_control {
            if let Some(frame) = sim.step_rendering(&input, wants_frames) {
                tracker.observe(&frame.image, frame.width, frame.height, frame.stamp);
            }
        }
        let truth = sim.truth();
        if let Some(trace) = trace.as_mut().filter(|_| config.record_cycles) {
            let tool = truth.tool_pose.translation.vector;
            let cube = truth
                .objects
                .get(tasks.get(task_index).map_or(0, |t| t.item))
                .map_or(Vector3::zeros(), |o| o.position());
            let odom = &sensors.base_pose;
            let mut row = vec![
                t,
                task_index as f64,
                truth.base_pose.x,
                truth.base_pose.y,
                truth.base_pose.yaw,
                odom.x,
                odom.y,
                odom.yaw,
                truth.base_velocity.v,
                tool.x,
                tool.y,
                tool.z,
                target.position.x,
                target.position.y,
                target.position.z,
                cube.x,
                cube.y,
                cube.z,
                truth.gripper_opening,
                command.base.v,
                command.base.omega,
            ];
            row.extend_from_slice(&internals);
            trace.cycles.push(row);
        }
        if let Some(trace) = trace
            .as_mut()
            .filter(|_| cycle.is_multiple_of(config.trace_every.max(1)))
        {
            trace.base.push((truth.base_pose.x, truth.base_pose.y));
            let tool = truth.tool_pose.translation.vector;
            trace.ee.push((tool.x, tool.y));
            for (path, object) in trace.objects.iter_mut().zip(&truth.objects) {
                let p = object.position();
                path.push((p.x, p.y));
            }
        }
        cycle += 1;
    }
    let status = sim.status();
    let (success, failure) = (
        status == TrialStatus::Decided(Outcome::Success),
        status.failure().map(str::to_string),
    );
    let meter = sim.meter();
    let truth = sim.truth();
    let sim_time = truth.time;
    let mut placed: Vec<f64> = truth.objects.iter().filter_map(|o| o.placed_time).collect();
    placed.sort_by(f64::total_cmp);
    let round_trips_s = placed
        .iter()
        .scan(0.0, |last, &t| {
            let trip = t - *last;
            *last = t;
            Some(trip)
        })
        .collect();
    let result = TrialResult {
        success,
        failure,
        task_time_s: sim_time,
        mtph: if success { 3600.0 / sim_time } else { 0.0 },
        ee_acc_mean: meter.mean(),
        ee_acc_max: meter.max(),
        ee_acc_filter: meter.description().to_string(),
        sim_time_s: sim_time,
        wall_time_s: wall_start.elapsed().as_secs_f64(),
        round_trips_s,
    };
    Ok((result, trace))
}
