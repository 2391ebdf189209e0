//! Closed-loop kinematic tests of the control tasks as the scheduler runs them: the base
//! planner, reacher, final phase, QP resolver and mission drive an ideal kinematic Frankie
//! (joint and base velocities integrated exactly, perfect perception) through a pick and
//! place, while the base keeps driving.
//! - The base speed the QP commands must not drop below 80 % of v_F during the grasp: that is
//!   the point of manipulation on-the-move.
//! - With a base that drives 12 % faster than commanded (a drive gain error, measured by
//!   odometry), the base velocity error fed forward ([`motm_core::base_slip`]) lets the
//!   final-phase servo centre the tool over the cube before closing; without it the servo lags
//!   the cube by its steady-state offset.
//! - With the base target rate limit on ([`motm_core::base_command_rate`]), the base command
//!   never changes faster than the base's acceleration limits, through the grasp and the
//!   hand-over to the next task.

use std::f64::consts::FRAC_PI_2;
use std::path::Path;

use motm_core::final_phase::FinalPhaseStage;
use motm_core::mission::{MissionTask, TaskKind};
use motm_core::on_the_move::OnTheMoveConfig;
use motm_core::{BasePose, BaseVelocity, Robot};
use motm_graph::{Scheduler, Source, Task, TaskSpec, Trigger, ports};
use motm_msgs::{self as msgs, Message, topics};
use motm_tasks::ControlSetup;
use motm_tasks::final_phase::FinalPhaseTask;
use nalgebra::Vector3;

/// Control period of the test, s.
const DT: f64 = 0.005;
/// Finger opening when fully open, m.
const OPEN: f64 = 0.08;
/// Cube edge, m.
const CUBE: f64 = 0.03;
/// Finger speed, m/s (open to 30 mm in 0.5 s).
const FINGER_SPEED: f64 = 0.1;
/// Half-width of the container's opening, m.
const CONTAINER_HALF_WIDTH: f64 = 0.15;
/// The test's own reader on the bus.
const TAP: usize = 1_000;

fn frankie() -> Robot {
    Robot::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config"),
        "frankie",
    )
    .unwrap()
}

ports! {
    /// What the ideal robot takes: the QP's commands and the final phase's gripper command.
    struct PlantInputs {
        /// Arm command.
        latest arm: msgs::ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Base command.
        latest base: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// Gripper command.
        latest gripper: msgs::GripperCommand = topics::ARM_GRIPPER_COMMAND,
    }
}

ports! {
    /// What the ideal robot measures, and its perfect perception of the cube.
    struct PlantOutputs {
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Gripper state.
        latest gripper: msgs::GripperState = topics::ARM_GRIPPER_STATE,
        /// The cube, perfectly perceived.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
    }
}

/// An ideal kinematic robot with a gripper model and a cube.
struct Plant {
    robot: Robot,
    base: BasePose,
    base_velocity: BaseVelocity,
    base_gain: f64,
    arm_q: Vec<f64>,
    cube: Vector3<f64>,
    cube_velocity: Vector3<f64>,
    /// Whether the gripper model runs (otherwise the fingers report open throughout).
    gripper_model: bool,
    opening: f64,
    held: bool,
    picked: bool,
    released_at: Option<Vector3<f64>>,
    max_joint_excursion: f64,
}

impl Plant {
    fn new(robot: Robot, cube: Vector3<f64>, cube_velocity: Vector3<f64>) -> Self {
        Self {
            arm_q: robot.config.ready_pose.clone(),
            robot,
            base: BasePose::default(),
            base_velocity: BaseVelocity::default(),
            base_gain: 1.0,
            cube,
            cube_velocity,
            gripper_model: true,
            opening: OPEN,
            held: false,
            picked: false,
            released_at: None,
            max_joint_excursion: 0.0,
        }
    }

    fn integrate(&mut self, inputs: &PlantInputs) {
        let command = inputs
            .base
            .map_or(BaseVelocity::default(), |b| BaseVelocity {
                v: b.v,
                omega: b.omega,
            });
        assert!(command.v.is_finite() && command.omega.is_finite());
        self.base_velocity = BaseVelocity {
            v: command.v * self.base_gain,
            omega: command.omega * self.base_gain,
        };
        self.base.yaw += self.base_velocity.omega * DT;
        self.base.x += self.base_velocity.v * self.base.yaw.cos() * DT;
        self.base.y += self.base_velocity.v * self.base.yaw.sin() * DT;
        if let Some(arm) = &inputs.arm {
            let qd = &arm.velocity[..arm.joint_count as usize];
            assert!(qd.iter().all(|v| v.is_finite()), "NaN joint velocity");
            for (q, qd) in self.arm_q.iter_mut().zip(qd) {
                *q += qd * DT;
            }
        }
        let limits = self.robot.limits();
        for (q, limit) in self.arm_q.iter().zip(&limits[2..]) {
            let excursion = (limit.position_min - q).max(q - limit.position_max);
            self.max_joint_excursion = self.max_joint_excursion.max(excursion);
        }
        if !self.gripper_model {
            return;
        }
        let tool = self.robot.tool_pose(&self.base, &self.arm_q);
        let cube_in_tool = tool.inverse_transform_point(&self.cube.into());
        match inputs.gripper.and_then(|g| g.action()) {
            Some(msgs::GripperAction::Close) if !self.held => {
                self.opening = (self.opening - FINGER_SPEED * DT).max(0.0);
                let between_fingers = cube_in_tool.x.abs() < 0.01
                    && cube_in_tool.y.abs() < (OPEN - CUBE) / 2.0
                    && cube_in_tool.z.abs() < 0.02;
                if self.opening <= CUBE && between_fingers && self.released_at.is_none() {
                    self.held = true;
                    self.opening = CUBE;
                }
            }
            Some(msgs::GripperAction::Open) => {
                if self.held {
                    self.held = false;
                    self.released_at = Some(self.cube);
                }
                self.opening = (self.opening + FINGER_SPEED * DT).min(OPEN);
            }
            _ => {}
        }
        if self.held {
            self.cube = tool.translation.vector;
        } else if self.released_at.is_none() {
            self.cube += self.cube_velocity * DT;
        }
    }
}

impl Task for Plant {
    type Inputs = PlantInputs;
    type Outputs = PlantOutputs;

    fn name(&self) -> &'static str {
        "plant"
    }

    fn step(&mut self, now_ns: u64, inputs: &PlantInputs) -> PlantOutputs {
        if now_ns > 0 {
            self.integrate(inputs);
        }
        let mut joints = msgs::JointState::zeroed();
        joints.joint_count = self.arm_q.len() as u32;
        joints.position[..self.arm_q.len()].copy_from_slice(&self.arm_q);
        let mut odometry = msgs::BaseOdometry::zeroed();
        (odometry.x, odometry.y, odometry.yaw) = (self.base.x, self.base.y, self.base.yaw);
        (odometry.v, odometry.omega) = (self.base_velocity.v, self.base_velocity.omega);
        let mut gripper = msgs::GripperState::zeroed();
        gripper.width = self.opening;
        let mut target = msgs::TargetEstimate::zeroed();
        target.position = self.cube.into();
        let velocity = if self.held {
            Vector3::zeros()
        } else {
            self.cube_velocity
        };
        target.velocity = velocity.into();
        target.visible = 1;
        for m in [
            joints.header_mut(),
            odometry.header_mut(),
            gripper.header_mut(),
            target.header_mut(),
        ] {
            m.stamp_ns = now_ns;
        }
        PlantOutputs {
            joints: Some(joints),
            odometry: Some(odometry),
            gripper: Some(gripper),
            target: Some(target),
        }
    }
}

const PLANT: TaskSpec = TaskSpec {
    name: "plant",
    inputs: &[],
    outputs: &[],
    rate: motm_graph::Rate::Control,
    trigger: Trigger::Timer,
    control_path: false,
    sim_only: true,
    host: motm_graph::Host::Process,
    standby_of: None,
};

/// The plant and the control tasks, scheduled at the control period.
fn graph(
    config: OnTheMoveConfig,
    plant: Plant,
    cube: Vector3<f64>,
    container: Vector3<f64>,
) -> Scheduler {
    let robot = plant.robot.clone();
    let mut scheduler = Scheduler::new((DT * 1e9) as u64);
    scheduler.add(plant, &PLANT, 1.0 / DT);
    let tasks = vec![
        MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: cube,
        },
        MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: container,
        },
    ];
    let setup = ControlSetup {
        robot,
        config,
        rate_hz: 1.0 / DT,
    };
    motm_tasks::graph::add_control_tasks(&mut scheduler, &setup, tasks, Vector3::zeros());
    scheduler
}

/// What the test watches each cycle: the mission and the base command.
#[derive(Default)]
struct Watch {
    mission: Option<msgs::MissionState>,
    base: Option<msgs::BaseVelocityCommand>,
}

impl Watch {
    fn read(&mut self, scheduler: &mut Scheduler) {
        let mut port = scheduler.bus().port(TAP);
        port.latest(topics::MISSION_STATE, &mut self.mission);
        port.latest(topics::BASE_VELOCITY_COMMAND, &mut self.base);
    }

    fn task_and_phase(&self) -> (u32, Option<msgs::TaskPhase>) {
        self.mission.map_or((0, None), |m| {
            (m.task_index, msgs::TaskPhase::try_from(m.phase).ok())
        })
    }
}

/// How a pick and place ended.
#[derive(Debug)]
struct Run {
    picked: bool,
    placed_inside: bool,
    time: f64,
    min_base_speed_in_grasp: f64,
    grasp_cycles: usize,
    max_joint_excursion: f64,
}

/// Drives the ideal robot through pick at `cube` (moving at `cube_velocity`) and place at
/// `container` at `v_f`.
fn pick_and_place(
    cube: Vector3<f64>,
    cube_velocity: Vector3<f64>,
    container: Vector3<f64>,
    v_f: f64,
) -> Run {
    let mut config = OnTheMoveConfig::default();
    config.base.forward_speed = v_f;
    let plant = Plant::new(frankie(), cube, cube_velocity);
    let mut scheduler = graph(config, plant, cube, container);
    let mut watch = Watch::default();
    let mut run = Run {
        picked: false,
        placed_inside: false,
        time: 0.0,
        min_base_speed_in_grasp: f64::INFINITY,
        grasp_cycles: 0,
        max_joint_excursion: 0.0,
    };
    for k in 0..(40.0 / DT) as usize {
        scheduler.tick();
        watch.read(&mut scheduler);
        let (task, phase) = watch.task_and_phase();
        if phase == Some(msgs::TaskPhase::Final) && task == 0 {
            let v = watch.base.map_or(0.0, |b| b.v);
            run.min_base_speed_in_grasp = run.min_base_speed_in_grasp.min(v);
            run.grasp_cycles += 1;
        }
        let plant = scheduler.task_mut::<Plant>("plant").unwrap();
        plant.picked |= plant.held && task == 1;
        if phase == Some(msgs::TaskPhase::Complete) {
            run.time = k as f64 * DT;
            break;
        }
    }
    let plant = scheduler.task::<Plant>("plant").unwrap();
    run.picked = plant.picked;
    run.max_joint_excursion = plant.max_joint_excursion;
    if let Some(drop) = plant.released_at {
        let offset = drop - container;
        run.placed_inside =
            offset.x.abs() < CONTAINER_HALF_WIDTH && offset.y.abs() < CONTAINER_HALF_WIDTH;
    }
    run
}

fn check(run: &Run, v_f: f64) {
    eprintln!("{run:?}");
    assert!(run.picked, "cube not picked: {run:?}");
    assert!(
        run.placed_inside,
        "cube not dropped into the container: {run:?}"
    );
    assert!(run.grasp_cycles > 10, "no grasp phase seen: {run:?}");
    assert!(
        run.min_base_speed_in_grasp >= 0.8 * v_f,
        "base slowed to {:.3} m/s during the grasp (v_F {v_f}): {run:?}",
        run.min_base_speed_in_grasp
    );
    assert!(
        run.max_joint_excursion <= 1e-6,
        "a joint left its limits: {run:?}"
    );
}

#[test]
fn picks_a_static_cube_on_the_move_and_drops_it_into_the_container() {
    let run = pick_and_place(
        Vector3::new(2.0, 0.6, 0.45),
        Vector3::zeros(),
        Vector3::new(3.6, 1.6, 0.35),
        0.3,
    );
    check(&run, 0.3);
    assert!(run.time < 15.0, "took {:.1} s", run.time);
}

#[test]
fn picks_a_moving_cube_on_the_move() {
    let velocity = Vector3::new(FRAC_PI_2.cos(), FRAC_PI_2.sin(), 0.0) * 0.03;
    let run = pick_and_place(
        Vector3::new(2.0, 0.5, 0.45),
        velocity,
        Vector3::new(3.6, 1.6, 0.35),
        0.3,
    );
    check(&run, 0.3);
}

/// What the approach to the cube looked like.
struct Approach {
    /// Horizontal tool-to-cube offset on the first cycle of closing, m.
    offset_at_close: Option<f64>,
    /// Smallest horizontal tool-to-cube offset in the final phase's approach stage after its
    /// first half second (once the servo has settled), m.
    min_settled_offset: f64,
    /// Largest change per second of the commanded base ω (rad/s²) and v (m/s²).
    max_omega_rate: f64,
    max_v_rate: f64,
    /// Whether the mission moved on to the place task.
    handed_over: bool,
}

/// A static cube at 0.4 m/s on a base 12 % faster than commanded; the gripper reports open
/// throughout: it closes for the time-out, lifts, and the mission moves on to the place task.
fn approach(slip_feed_forward: bool, base_rate_limit: bool) -> Approach {
    let mut config = OnTheMoveConfig::default();
    config.base.forward_speed = 0.4;
    config.base_slip.enabled = slip_feed_forward;
    config.base_rate.enabled = base_rate_limit;
    let cube = Vector3::new(2.0, 0.0, 0.45);
    let mut plant = Plant::new(frankie(), cube, Vector3::zeros());
    plant.base_gain = 1.12;
    plant.gripper_model = false;
    let mut scheduler = graph(config, plant, cube, Vector3::new(4.0, 1.0, 0.35));
    let mut watch = Watch::default();
    let mut approach_started: Option<f64> = None;
    let mut last_command: Option<BaseVelocity> = None;
    let mut result = Approach {
        offset_at_close: None,
        min_settled_offset: f64::INFINITY,
        max_omega_rate: 0.0,
        max_v_rate: 0.0,
        handed_over: false,
    };
    for k in 0..(9.0 / DT) as usize {
        let t = k as f64 * DT;
        scheduler.tick();
        watch.read(&mut scheduler);
        let plant = scheduler.task::<Plant>("plant").unwrap();
        let tool = plant
            .robot
            .tool_pose(&plant.base, &plant.arm_q)
            .translation
            .vector;
        let offset = (tool - cube).xy().norm();
        let stage = scheduler
            .task::<FinalPhaseTask>(motm_graph::FINAL_PHASE.name)
            .and_then(FinalPhaseTask::stage);
        match stage {
            Some(FinalPhaseStage::Approach) => {
                let started = *approach_started.get_or_insert(t);
                if t - started > 0.5 {
                    result.min_settled_offset = result.min_settled_offset.min(offset);
                }
            }
            Some(FinalPhaseStage::Closing) if result.offset_at_close.is_none() => {
                result.offset_at_close = Some(offset);
            }
            _ => {}
        }
        result.handed_over |= watch.task_and_phase().0 > 0;
        if let Some(command) = watch.base.map(|b| BaseVelocity {
            v: b.v,
            omega: b.omega,
        }) {
            // Compare consecutive commands (the first starts from rest on both sides).
            if let Some(last) = last_command {
                result.max_omega_rate = result
                    .max_omega_rate
                    .max((command.omega - last.omega).abs() / DT);
                result.max_v_rate = result.max_v_rate.max((command.v - last.v).abs() / DT);
            }
            last_command = Some(command);
        }
    }
    result
}

#[test]
fn feed_forward_of_the_base_velocity_error_lets_the_grasp_close_on_a_fast_base() {
    let with = approach(true, false);
    let offset = with
        .offset_at_close
        .expect("the gripper closes on the cube with the feed-forward");
    assert!(offset < 0.005, "closed {offset} m off the cube");

    let without = approach(false, false);
    assert!(
        without.offset_at_close.is_none_or(|o| o > offset),
        "without the feed-forward the tool is not better centred"
    );
    assert!(
        without.min_settled_offset > 0.005,
        "without the feed-forward the servo lags the cube by its steady offset, got {} m",
        without.min_settled_offset
    );
}

#[test]
fn the_base_command_respects_the_base_acceleration_limits_through_the_hand_over() {
    let limits = frankie().limits().to_vec();
    let run = approach(true, true);
    assert!(run.handed_over, "the mission reaches the place task");
    // The QP's base rows are soft, so allow it 5 % beyond the target's limit.
    assert!(
        run.max_omega_rate <= limits[0].acceleration * 1.05,
        "ω command changed at {} rad/s²",
        run.max_omega_rate
    );
    assert!(
        run.max_v_rate <= limits[1].acceleration * 1.05,
        "v command changed at {} m/s²",
        run.max_v_rate
    );
}
