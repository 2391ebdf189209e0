//! The in-process runner: one trial of a scenario with every task of the graph in one process,
//! scheduled in lockstep simulated time over the in-memory bus as fast as the CPU allows.
//!
//! MotM runs the very tasks the deployed services run ([`motm_tasks`]: the drivers,
//! perception, base planner, reacher, final phase, QP resolver and the supervisor's mission),
//! with the simulated hardware as one more task ([`crate::task::SimWorldTask`]), at the rates
//! and triggers of their rows in [`motm_graph::GRAPH`]. The messages on the bus are the
//! iceoryx2 payloads, validated on receipt exactly as the services validate them.
//!
//! The baselines run in the same simulated world: the reactive baseline and the planning
//! baseline read the sensors and command the hardware directly, each cycle at the control rate.
//! For the reactive baseline, the current pick's cube and the current press's button cap are
//! estimated by perception from the rendered palm image; until the first fix the scenario's
//! position stands in, and when the target leaves the view the last estimate is held.

use std::time::Instant;

use motm_core::camera::CameraConfig;
use motm_core::command_limiter::CommandLimiterConfig;
use motm_core::final_phase::FinalPhaseStage;
use motm_core::on_the_move::OnTheMoveConfig;
use motm_core::planning::{PlanRequest, PlanningConfig, PlanningController};
use motm_core::reactive::{ReactiveBaseline, ReactiveConfig};
use motm_core::resolver::RedundancyResolver;
use motm_core::{BaseVelocity, Robot, TargetEstimate};
use motm_graph::{Scheduler, Source, TaskSpec};
use motm_msgs::{self as msgs, topics};
use motm_tasks::ControlSetup;
use motm_tasks::baselines::{PlanningTask, ReactiveTask};
use motm_tasks::driver::{self, ArmDriverTask, BaseDriverTask};
use motm_tasks::final_phase::FinalPhaseTask;
use motm_tasks::mission::MissionSequencerTask;
use motm_tasks::perception::PerceptionTask;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::experiment::{Method, TrialLog, TrialResult, TrialTrace};
use crate::metrics::AccelerationFilterConfig;
use crate::objects::Button;
use crate::render::{BUTTON_BODY, BUTTON_RED, CONTAINER_BLUE, PLATFORM_WOOD, Scene, SceneBox};
use crate::scenario::Scenario;
use crate::sim_world::{SimWorld, SimWorldConfig, TrialStatus};
use crate::task::SimWorldTask;
use crate::world::{Outcome, World};

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
    /// Also keep a replay log of a MotM trial in the trace ([`TrialTrace::log`]): every
    /// sample on the bus and every task cycle's consumed and produced samples.
    pub record_log: bool,
    /// Also measure the wall-clock time of every task step ([`TrialTrace::step_ns`]), for
    /// `motm bench tasks`.
    pub time_steps: bool,
    /// Palm camera (the scenario's noise overrides its pixel noise and extrinsic error).
    pub camera: CameraConfig,
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
            record_log: false,
            time_steps: false,
            camera: CameraConfig::default(),
            acceleration: AccelerationFilterConfig::default(),
            motm: OnTheMoveConfig::default(),
            reactive: ReactiveConfig::default(),
            planning: PlanningConfig::default(),
        }
    }
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

/// Number of MotM internal columns at the end of a trace row.
const MOTM_COLUMNS: usize = 12;

/// MotM's internals for the trace, from what the tasks published and hold: phase, stage, the
/// resolved twist (linear), tool-to-target distance, slack, the base controller's speed target
/// and the first arm joint.
fn motm_internals(taps: &Taps, scheduler: &Scheduler, arm_q: &[f64]) -> [f64; MOTM_COLUMNS] {
    let phase = taps
        .mission
        .and_then(|m| msgs::TaskPhase::try_from(m.phase).ok())
        .map_or(0.0, |phase| match phase {
            msgs::TaskPhase::Reach => 0.0,
            msgs::TaskPhase::Final => 1.0,
            msgs::TaskPhase::Complete => 2.0,
        });
    let stage = scheduler
        .task::<FinalPhaseTask>(motm_graph::FINAL_PHASE.name)
        .and_then(FinalPhaseTask::stage)
        .map_or(-1.0, |stage| match stage {
            FinalPhaseStage::Approach => 0.0,
            FinalPhaseStage::Closing => 1.0,
            FinalPhaseStage::Lifting => 2.0,
            FinalPhaseStage::Releasing => 3.0,
            FinalPhaseStage::Pushing => 4.0,
            FinalPhaseStage::Retracting => 5.0,
            FinalPhaseStage::Done => 6.0,
        });
    let twist = taps.qp.map_or([0.0; 6], |q| q.twist);
    let offset = taps.mission.map_or([0.0; 3], |m| m.odometry_offset);
    let tool_to_target = scheduler
        .task::<MissionSequencerTask>(motm_graph::MISSION.name)
        .and_then(MissionSequencerTask::last)
        .map_or(f64::INFINITY, |m| m.tool_to_target);
    [
        phase,
        stage,
        twist[0],
        twist[1],
        twist[2],
        tool_to_target,
        taps.qp.map_or(0.0, |q| q.slack_norm),
        taps.base_target.map_or(0.0, |b| b.v),
        arm_q.first().copied().unwrap_or(0.0),
        offset[0],
        offset[1],
        offset[2],
    ]
}

/// The runner's own reader on the in-process bus, like the logger's tap on iceoryx2.
const RUNNER_READER: motm_graph::ReaderId = 1_000;

/// The latest samples of the topics the trace shows.
#[derive(Default)]
struct Taps {
    mission: Option<msgs::MissionState>,
    target: Option<msgs::TargetEstimate>,
    qp: Option<msgs::QpStatus>,
    base_target: Option<msgs::BaseVelocityCommand>,
    base_command: Option<msgs::BaseVelocityCommand>,
}

impl Taps {
    fn read(&mut self, bus: &mut motm_graph::MemBus) {
        let mut port = bus.port(RUNNER_READER);
        port.latest(topics::MISSION_STATE, &mut self.mission);
        port.latest(topics::PERCEPTION_TARGET, &mut self.target);
        port.latest(topics::CONTROL_QP_STATUS, &mut self.qp);
        port.latest(topics::BASE_VELOCITY_TARGET, &mut self.base_target);
        port.latest(topics::BASE_VELOCITY_COMMAND, &mut self.base_command);
    }
}

/// The front of every method's graph: `sim` as the hardware, the two drivers and, when
/// `perceive` names the mission's tasks, perception, at their rows' rates.
fn hardware_graph(
    robot: &Robot,
    sim: SimWorld,
    config: &RunnerConfig,
    perceive: Option<&[motm_core::mission::MissionTask]>,
) -> Result<Scheduler, String> {
    let physics_step_ns = (config.physics_step * 1e9).round() as u64;
    let control = config.control_rate_hz;
    let calibration = sim.camera().calibration();
    let stale = CommandLimiterConfig::default().stale_periods;
    let status_every = |rate: f64| (rate / DRIVER_STATUS_RATE_HZ).round().max(1.0) as u64;
    let rate = |spec: &TaskSpec| spec.rate.hz(control);
    let arm_rate = rate(&motm_graph::PANDA_DRIVER);
    let base_rate = rate(&motm_graph::LD60_DRIVER);
    let arm = driver::velocity_driver(driver::arm_axes(robot), 1.0 / arm_rate, control, stale)?;
    let base = driver::velocity_driver(driver::base_axes(robot), 1.0 / base_rate, control, stale)?;
    let truth_every = (1.0 / (TRUTH_RATE_HZ * config.physics_step))
        .round()
        .max(1.0) as u64;
    let mut s = Scheduler::new(physics_step_ns);
    s.add(
        SimWorldTask::new(sim, truth_every, 1),
        &motm_graph::SIM_WORLD,
        1.0 / config.physics_step,
    );
    s.add(
        ArmDriverTask::new(arm, driver::BaseBraking::of(robot), status_every(arm_rate)),
        &motm_graph::PANDA_DRIVER,
        arm_rate,
    );
    s.add(
        BaseDriverTask::new(base, status_every(base_rate)),
        &motm_graph::LD60_DRIVER,
        base_rate,
    );
    if let Some(tasks) = perceive {
        s.add(
            PerceptionTask::new(
                robot.clone(),
                config.motm.perception,
                calibration,
                PERCEPTION_HISTORY,
                config.motm.mission.run_out_distance,
            )
            .with_layout(tasks),
            &motm_graph::PERCEPTION,
            rate(&motm_graph::PERCEPTION),
        );
    }
    Ok(s)
}

/// The MotM graph of `scenario`: every task of [`motm_graph::GRAPH`] (but the watchdog, which
/// watches processes), with `sim` as the hardware. Replay builds the same graph.
pub fn motm_graph(
    robot: &Robot,
    scenario: &Scenario,
    sim: SimWorld,
    config: &RunnerConfig,
) -> Result<Scheduler, String> {
    let mut motm = config.motm.clone();
    motm.base.forward_speed = scenario.base_speed;
    let setup = ControlSetup {
        robot: robot.clone(),
        config: motm,
        rate_hz: config.control_rate_hz,
    };
    let start = scenario.start();
    let tasks = scenario.mission_tasks();
    let mut s = hardware_graph(robot, sim, config, Some(&tasks))?;
    motm_tasks::graph::add_control_tasks(
        &mut s,
        &setup,
        tasks,
        Vector3::new(start.x, start.y, 0.0),
    );
    Ok(s)
}

/// The graph of a baseline (`method` is not MotM), or why it cannot run on `scenario` (the
/// planning baseline plans one pick and place), as the trial's result.
fn baseline_graph(
    robot: &Robot,
    scenario: &Scenario,
    sim: SimWorld,
    config: &RunnerConfig,
    method: Method,
) -> Result<Result<Scheduler, String>, String> {
    let tasks = scenario.mission_tasks();
    let control = config.control_rate_hz;
    if method == Method::Reactive {
        let mut reactive = config.reactive.clone();
        reactive.max_base_speed = scenario.base_speed;
        reactive.object_yaw = config.motm.reacher.object_yaw;
        reactive.yaw_symmetry = config.motm.reacher.yaw_symmetry;
        let baseline = ReactiveBaseline::new(robot.clone(), reactive, tasks.clone());
        let mut s = hardware_graph(robot, sim, config, Some(&tasks))?;
        s.add(
            ReactiveTask::new(baseline, tasks, &config.motm.mission),
            &motm_graph::REACTIVE,
            motm_graph::REACTIVE.rate.hz(control),
        );
        return Ok(Ok(s));
    }
    let [object] = scenario.objects.as_slice() else {
        return Err(format!(
            "{}: the planning baseline plans one pick and place; this scenario has {} objects",
            scenario.path.display(),
            scenario.objects.len()
        ));
    };
    let request = PlanRequest {
        start_base: scenario.start(),
        start_base_speed: 0.0,
        cube: Vector3::from(object.position),
        container: Vector3::from(object.place),
        base_speed: scenario.base_speed,
    };
    let tracker = match PlanningController::from_request(robot, &request, &config.planning) {
        Ok(tracker) => tracker,
        Err(e) => return Ok(Err(format!("plan_failed: {e}"))),
    };
    let resolver = RedundancyResolver::for_robot(robot, config.motm.resolver.clone());
    let mut s = hardware_graph(robot, sim, config, None)?;
    s.add(
        PlanningTask::new(robot.clone(), tracker, resolver, tasks),
        &motm_graph::PLANNING,
        motm_graph::PLANNING.rate.hz(control),
    );
    Ok(Ok(s))
}

/// The driver status rate, Hz (the drivers' `--status-rate` default).
const DRIVER_STATUS_RATE_HZ: f64 = 50.0;
/// The ground-truth rate, Hz (sim-world's `--truth-rate` default).
const TRUTH_RATE_HZ: f64 = 100.0;
/// Tool poses perception keeps (its `--history` default).
const PERCEPTION_HISTORY: usize = 200;

/// The result of the trial `sim` ran, which took `wall` so far.
fn trial_result(sim: &SimWorld, wall_start: Instant) -> TrialResult {
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
    TrialResult {
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
        mishaps: sim.world().mishaps().iter().map(Into::into).collect(),
    }
}

/// A new trace of `sim`'s layout.
fn new_trace(sim: &SimWorld, objects: usize) -> TrialTrace {
    TrialTrace {
        containers: sim
            .world()
            .layout()
            .containers
            .iter()
            .map(|c| (c.rim_center.x, c.rim_center.y))
            .collect(),
        objects: vec![Vec::new(); objects],
        ..TrialTrace::default()
    }
}

/// Appends the sparse samples (base, tool, objects) of `truth` to `trace`.
fn sample_trace(trace: &mut TrialTrace, truth: &crate::Truth) {
    trace.base.push((truth.base_pose.x, truth.base_pose.y));
    let tool = truth.tool_pose.translation.vector;
    trace.ee.push((tool.x, tool.y));
    for (path, object) in trace.objects.iter_mut().zip(&truth.objects) {
        let p = object.position();
        path.push((p.x, p.y));
    }
}

/// One trace row: time, task, true and odometry poses, tool, target, cube, gripper, command,
/// then `internals`.
fn trace_row(
    sim: &SimWorld,
    task_index: usize,
    item: usize,
    target: &TargetEstimate,
    command: BaseVelocity,
    internals: &[f64],
) -> Vec<f64> {
    let truth = sim.truth();
    let sensors = sim.sensors();
    let tool = truth.tool_pose.translation.vector;
    let cube = truth
        .objects
        .get(item)
        .map_or(Vector3::zeros(), |o| o.position());
    let odom = &sensors.base_pose;
    let mut row = vec![
        truth.time,
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
        command.v,
        command.omega,
    ];
    row.extend_from_slice(internals);
    row
}

/// The simulated world of a trial's graph.
fn sim_of(s: &Scheduler) -> Option<&SimWorld> {
    s.task::<SimWorldTask>(motm_graph::SIM_WORLD.name)
        .map(SimWorldTask::sim)
}

/// One trial: the graph's tasks scheduled in lockstep until the world decides.
fn run_graph_trial(
    mut scheduler: Scheduler,
    scenario: &Scenario,
    method: Method,
    config: &RunnerConfig,
    record_trace: bool,
    wall_start: Instant,
) -> Result<(TrialResult, Option<TrialTrace>), String> {
    let tasks = scenario.mission_tasks();
    let mut trace = sim_of(&scheduler).map(|sim| new_trace(sim, scenario.objects.len()));
    if !record_trace {
        trace = None;
    }
    let mut log = (record_trace && config.record_log && method == Method::Motm).then(|| {
        scheduler.record_cycles();
        scheduler.bus().record_samples();
        TrialLog::default()
    });
    if record_trace && config.time_steps {
        scheduler.time_steps();
    }
    let control_ticks = ((1.0 / config.control_rate_hz) / config.physics_step)
        .round()
        .max(1.0) as u64;
    let mut taps = Taps::default();
    let mut tick = 0u64;
    while sim_of(&scheduler).map(SimWorld::status) == Some(TrialStatus::Running) {
        // Frames perception would not read are not rendered (the same trial either way).
        let perceiving = taps.mission.is_some_and(|m| {
            msgs::TaskPhase::try_from(m.phase) != Ok(msgs::TaskPhase::Complete)
                && tasks
                    .get(m.task_index as usize)
                    .is_some_and(|t| t.kind.is_perceived())
        });
        let has_perception = method != Method::Planning;
        if let Some(sim) = scheduler.task_mut::<SimWorldTask>(motm_graph::SIM_WORLD.name) {
            sim.set_rendering(has_perception && (perceiving || taps.mission.is_none()));
        }
        scheduler.tick();
        if let Some(log) = log.as_mut() {
            log.samples.extend(scheduler.bus().take_recorded());
            log.cycles.extend(scheduler.take_records());
        }
        let control_cycle = tick.is_multiple_of(control_ticks);
        let cycle = tick / control_ticks;
        tick += 1;
        if !control_cycle {
            continue;
        }
        taps.read(scheduler.bus());
        let Some(trace) = trace.as_mut() else {
            continue;
        };
        let Some(sim) = sim_of(&scheduler) else {
            break;
        };
        if config.record_cycles {
            let task_index = taps.mission.map_or(0, |m| m.task_index as usize);
            let item = tasks.get(task_index).map_or(0, |t| t.item);
            let target = taps.target.map_or_else(
                || {
                    TargetEstimate::fixed(
                        tasks
                            .get(task_index)
                            .map_or(Vector3::zeros(), |t| t.position),
                    )
                },
                |t| TargetEstimate {
                    position: Vector3::from(t.position),
                    velocity: Vector3::from(t.velocity),
                },
            );
            let command = taps
                .base_command
                .map_or(BaseVelocity::default(), |c| BaseVelocity {
                    v: c.v,
                    omega: c.omega,
                });
            let internals = if method == Method::Motm {
                motm_internals(&taps, &scheduler, &sim.sensors().arm_q)
            } else {
                [0.0; MOTM_COLUMNS]
            };
            trace.cycles.push(trace_row(
                sim, task_index, item, &target, command, &internals,
            ));
        }
        if cycle.is_multiple_of(config.trace_every.max(1) as u64) {
            sample_trace(trace, sim.truth());
        }
    }
    if let (Some(trace), Some(log)) = (trace.as_mut(), log) {
        trace.log = Some(log);
    }
    if let Some(trace) = trace.as_mut() {
        trace.step_ns = scheduler
            .step_times()
            .into_iter()
            .map(|(name, times)| (name, times.to_vec()))
            .collect();
    }
    let sim = sim_of(&scheduler).ok_or("the graph has no sim-world task")?;
    Ok((trial_result(sim, wall_start), trace))
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
    // The same world, camera, metrics and verdict as the sim-world process.
    let sim = SimWorld::new(robot, scenario, seed, config, SimWorldConfig::default())
        .map_err(|e| e.to_string())?;
    let scheduler = match method {
        Method::Motm => motm_graph(robot, scenario, sim, config)?,
        _ => match baseline_graph(robot, scenario, sim, config, method)? {
            Ok(scheduler) => scheduler,
            Err(failure) => {
                let result = TrialResult {
                    success: false,
                    failure: Some(failure),
                    task_time_s: 0.0,
                    mtph: 0.0,
                    ee_acc_mean: 0.0,
                    ee_acc_max: 0.0,
                    ee_acc_filter: String::new(),
                    sim_time_s: 0.0,
                    wall_time_s: wall_start.elapsed().as_secs_f64(),
                    round_trips_s: Vec::new(),
                    mishaps: Vec::new(),
                };
                return Ok((result, None));
            }
        },
    };
    run_graph_trial(
        scheduler,
        scenario,
        method,
        config,
        record_trace,
        wall_start,
    )
}
