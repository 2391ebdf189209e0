//! The deployed control chain as real processes over iceoryx2: the five control services
//! (perception, base-planner, reacher, final-phase, qp-resolver) and the supervisor running
//! the mission task (`--no-spawn`: it starts nothing), with this test standing in for the
//! drivers (a kinematic robot that integrates the commands in real time). They must carry a
//! pick and a place of static targets through to the end of the mission, with finite commands
//! within the joint velocity limits, pass through the same mission phases in the same order as
//! the same tasks in one process (the in-process scheduler, on the same plant), and leave no
//! process and no shared memory behind. The two mission times are printed, not compared: the
//! plant here integrates in wall-clock time, which scheduling noise moves (the timing
//! equivalence of the two forms is the full stack's, `tests/e2e/equivalence.rs`).

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, IpcConfig, Latest, PREFIX_ENV, Publisher, Qos, Subscriber, remove_domain,
    shared_memory_entries,
};
use motm_core::kinematics::BasePose;
use motm_core::mission::{MissionTask, Phase};
use motm_core::mission_file::MissionFile;
use motm_core::on_the_move::OnTheMoveConfig;
use motm_core::{Robot, wrap_angle};
use motm_graph::{Scheduler, Source, Task, TaskSpec, ports};
use motm_msgs::topics;
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, GripperAction, GripperCommand,
    GripperState, JointState, Message, MissionState, services,
};
use motm_tasks::ControlSetup;
use motm_wire::convert;

/// The control services under test, in start order.
const SERVICES: [&str; 5] = [
    "perception",
    "base-planner",
    "reacher",
    "final-phase",
    "qp-resolver",
];

/// Longest time the mission may take (real time; it needs about 12 s).
const MISSION_TIMEOUT: Duration = Duration::from_secs(90);

/// Plant period.
const DT: Duration = Duration::from_millis(5);

/// The pick and place of these tests: a static cube and its container, straight ahead.
const SCENARIO: &str = r#"
name = "chain-pick-and-place"
robot = "frankie"
start_pose = [0.0, 0.0, 0.0]
base_speed = 0.3

[[objects]]
position = [2.0, 0.3, 0.45]
motion = "static"
place = [4.0, 0.3, 0.35]
"#;

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// The folder with the service binaries (next to this test's `deps/` folder). Under cargo
/// (`$CARGO` set) they are built first, so the test never runs stale binaries.
fn binaries() -> PathBuf {
    let dir = std::env::current_exe()
        .unwrap()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    if let Ok(cargo) = std::env::var("CARGO") {
        eprintln!("building the service binaries with {cargo}");
        let mut build = Command::new(cargo);
        build.args(["build", "-p", "motm-supervisor"]);
        for s in SERVICES {
            build.args(["-p", &format!("motm-{s}")]);
        }
        if !cfg!(debug_assertions) {
            build.arg("--release");
        }
        assert!(
            build.status().unwrap().success(),
            "cargo build of the services failed"
        );
    }
    for name in SERVICES.iter().chain(&["supervisor"]) {
        assert!(
            dir.join(name).is_file(),
            "{name} is missing in {}",
            dir.display()
        );
    }
    dir
}

/// The running processes; killed and reaped on drop if the test fails early.
struct Stack {
    children: Vec<(&'static str, Child)>,
}

impl Stack {
    /// The supervisor (mission only) first, so the mission is on the bus, then the services.
    fn start(ipc: &IpcConfig, rate: &str, scenario: &Path) -> Self {
        let dir = binaries();
        let mut children = Vec::new();
        let supervisor = Command::new(dir.join("supervisor"))
            .arg("--config-dir")
            .arg(config_dir())
            .arg("--scenario")
            .arg(scenario)
            .args(["--stack", "frankie", "--no-spawn", "--rate", rate])
            .env(PREFIX_ENV, &ipc.prefix)
            .spawn()
            .unwrap_or_else(|e| panic!("supervisor starts: {e}"));
        children.push(("supervisor", supervisor));
        for name in SERVICES {
            let child = Command::new(dir.join(name))
                .arg("--config-dir")
                .arg(config_dir())
                .arg("--scenario")
                .arg(scenario)
                .args(["--rate", rate, "--base-speed", "0.3"])
                .env(PREFIX_ENV, &ipc.prefix)
                .spawn()
                .unwrap_or_else(|e| panic!("{name} starts: {e}"));
            children.push((name, child));
        }
        Self { children }
    }

    /// Asserts that every process is still running.
    fn assert_alive(&mut self) {
        for (name, child) in &mut self.children {
            assert!(matches!(child.try_wait(), Ok(None)), "{name} died");
        }
    }

    /// SIGTERMs every process and asserts that each exits successfully.
    fn terminate(mut self) {
        for (_, child) in &self.children {
            // SAFETY: plain kill(2) on our own child, which has not been reaped yet.
            assert_eq!(
                unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) },
                0
            );
        }
        for (name, mut child) in self.children.drain(..) {
            let status = child.wait().unwrap();
            assert!(status.success(), "{name} exited with {status}");
        }
    }
}

impl Drop for Stack {
    fn drop(&mut self) {
        for (_, child) in &mut self.children {
            if let Ok(None) = child.try_wait() {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

/// The kinematic robot, standing in for the drivers.
struct Plant {
    base: BasePose,
    v: f64,
    omega: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    opening: f64,
    closing: bool,
}

impl Plant {
    /// A plant at rest in `robot`'s ready pose at the origin.
    fn at_rest(robot: &Robot) -> Self {
        Self {
            q: robot.config.ready_pose.clone(),
            qd: vec![0.0; robot.arm_dof()],
            base: BasePose::default(),
            v: 0.0,
            omega: 0.0,
            opening: 0.08,
            closing: false,
        }
    }

    /// Integrates the latest commands over `dt` seconds.
    fn integrate(&mut self, dt: f64) {
        self.base.x += self.v * self.base.yaw.cos() * dt;
        self.base.y += self.v * self.base.yaw.sin() * dt;
        self.base.yaw = wrap_angle(self.base.yaw + self.omega * dt);
        for (q, v) in self.q.iter_mut().zip(&self.qd) {
            *q += v * dt;
        }
        // The fingers move at 0.1 m/s and close on a 5 cm cube.
        self.opening = if self.closing {
            (self.opening - 0.1 * dt).max(0.05)
        } else {
            (self.opening + 0.1 * dt).min(0.08)
        };
    }
}

ports! {
    /// What the plant takes in the in-process form.
    struct PlantInputs {
        /// Arm command.
        latest arm: ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Base command.
        latest base: BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// Gripper command.
        latest gripper: GripperCommand = topics::ARM_GRIPPER_COMMAND,
    }
}

ports! {
    /// What the plant measures in the in-process form.
    struct PlantOutputs {
        /// Joint state.
        latest joints: JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: BaseOdometry = topics::BASE_ODOMETRY,
        /// Gripper state.
        latest gripper: GripperState = topics::ARM_GRIPPER_STATE,
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
            if let Some(arm) = &inputs.arm {
                self.qd
                    .copy_from_slice(&arm.velocity[..arm.joint_count as usize]);
            }
            if let Some(base) = &inputs.base {
                (self.v, self.omega) = (base.v, base.omega);
            }
            self.closing = inputs
                .gripper
                .is_some_and(|g| g.action() == Some(GripperAction::Close));
            self.integrate(DT.as_secs_f64());
        }
        let mut joints = JointState::zeroed();
        joints.joint_count = self.q.len() as u32;
        joints.position[..self.q.len()].copy_from_slice(&self.q);
        let mut odometry = BaseOdometry::zeroed();
        (odometry.x, odometry.y, odometry.yaw) = (self.base.x, self.base.y, self.base.yaw);
        (odometry.v, odometry.omega) = (self.v, self.omega);
        let mut gripper = GripperState::zeroed();
        gripper.width = self.opening;
        for h in [
            joints.header_mut(),
            odometry.header_mut(),
            gripper.header_mut(),
        ] {
            h.stamp_ns = now_ns;
        }
        PlantOutputs {
            joints: Some(joints),
            odometry: Some(odometry),
            gripper: Some(gripper),
        }
    }
}

/// Time the control tasks need in one process (the in-process scheduler) for the mission
/// `tasks` on the same plant, s, and the (task index, phase) states the mission went through.
fn single_process_mission(robot: &Robot, tasks: Vec<MissionTask>) -> (f64, Vec<(u32, u32)>) {
    let dt = DT.as_secs_f64();
    let mut scheduler = Scheduler::new(DT.as_nanos() as u64);
    let plant_spec = TaskSpec {
        name: "plant",
        inputs: &[],
        outputs: &[],
        rate: motm_graph::Rate::Control,
        trigger: motm_graph::Trigger::Timer,
        control_path: false,
        sim_only: true,
        host: motm_graph::Host::Process,
        standby_of: None,
    };
    scheduler.add(Plant::at_rest(robot), &plant_spec, 1.0 / dt);
    let setup = ControlSetup {
        robot: robot.clone(),
        config: OnTheMoveConfig::default(),
        rate_hz: 1.0 / dt,
    };
    motm_tasks::graph::add_control_tasks(&mut scheduler, &setup, tasks, nalgebra::Vector3::zeros());
    let mut mission: Option<MissionState> = None;
    let mut commanded: Option<ArmVelocityCommand> = None;
    let mut t = 0.0;
    let mut phases = Vec::new();
    loop {
        assert!(
            t < MISSION_TIMEOUT.as_secs_f64(),
            "single-process mission not complete"
        );
        scheduler.tick();
        let mut tap = scheduler.bus().port(1_000);
        tap.latest(topics::MISSION_STATE, &mut mission);
        tap.latest(topics::ARM_VELOCITY_COMMAND, &mut commanded);
        // The mission clock starts with the first command, as the deployed one's does.
        if commanded.is_some() {
            t += dt;
        }
        if let Some(phase) = mission.as_ref().map(phase_of)
            && phases.last() != Some(&phase)
        {
            phases.push(phase);
        }
        if mission.is_some_and(|m| m.phase == u32::from(convert::phase_code(Phase::Complete))) {
            return (t, phases);
        }
    }
}

#[test]
fn the_control_services_and_the_mission_carry_a_pick_and_place_through_over_iceoryx2() {
    run_pick_and_place("200");
}

#[test]
fn the_control_services_and_the_mission_also_work_at_1_khz() {
    run_pick_and_place("1000");
}

/// The (task index, phase code) of a mission state.
fn phase_of(m: &MissionState) -> (u32, u32) {
    (m.task_index, m.phase)
}

/// Runs the processes at `rate` Hz through a pick and place; see the file's doc.
fn run_pick_and_place(rate: &str) {
    let robot = Robot::load(&config_dir(), "frankie").unwrap();
    let limits = robot.limits();
    let folder = std::env::temp_dir().join(format!("motm-chain-{}-{rate}", std::process::id()));
    std::fs::create_dir_all(&folder).unwrap();
    let scenario_file = folder.join("scenario.toml");
    std::fs::write(&scenario_file, SCENARIO).unwrap();
    let mission = MissionFile::from_file(&scenario_file).unwrap();
    let (reference, reference_phases) = single_process_mission(&robot, mission.tasks);
    let mut plant = Plant::at_rest(&robot);
    let ipc = IpcConfig {
        prefix: format!("motmt{}_chain{rate}_", std::process::id()),
    };
    let code = |index: u32, phase: Phase| (index, u32::from(convert::phase_code(phase)));
    let mut phases = Vec::new();
    {
        let bus = Bus::open_with("chain-test", &ipc).unwrap();
        let qos = Qos::default();
        let mut joints_out =
            Publisher::<JointState>::new(&bus, services::ARM_JOINT_STATE, &qos).unwrap();
        let mut odometry_out =
            Publisher::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos).unwrap();
        let mut gripper_out =
            Publisher::<GripperState>::new(&bus, services::ARM_GRIPPER_STATE, &qos).unwrap();
        let mut arm_in =
            Subscriber::<ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &qos)
                .unwrap();
        let mut base_in =
            Subscriber::<BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_COMMAND, &qos)
                .unwrap();
        let mut gripper_in =
            Latest::<GripperCommand>::new(&bus, services::ARM_GRIPPER_COMMAND, &qos).unwrap();
        let mut mission_in =
            Latest::<MissionState>::new(&bus, services::MISSION_STATE, &qos).unwrap();
        let mut stack = Stack::start(&ipc, rate, &scenario_file);

        let start = Instant::now();
        let mut mission_time = 0.0;
        let mut last = Instant::now();
        let mut commands = 0u64;
        let mut moving_commands = 0u64;
        while phases.last() != Some(&code(2, Phase::Complete)) {
            assert!(
                start.elapsed() < MISSION_TIMEOUT,
                "mission not complete in time: {phases:?}, base {:?}",
                plant.base
            );
            std::thread::sleep(DT);
            let now = Instant::now();
            let dt = now.duration_since(last).as_secs_f64().min(0.05);
            plant.integrate(dt);
            // The mission clock starts with the first command, as the single process's does.
            if commands > 0 {
                mission_time += dt;
            }
            last = now;
            while let Some(arm) = arm_in.receive().unwrap() {
                let qd = &arm.velocity[..arm.joint_count as usize];
                assert_eq!(qd.len(), plant.q.len());
                for (v, limit) in qd.iter().zip(&limits[2..]) {
                    assert!(
                        v.is_finite() && v.abs() <= limit.velocity + 1e-9,
                        "arm command {v}"
                    );
                }
                plant.qd.copy_from_slice(qd);
                commands += 1;
            }
            while let Some(base) = base_in.receive().unwrap() {
                assert!(
                    base.v.abs() <= limits[1].velocity + 1e-9,
                    "base command {}",
                    base.v
                );
                assert!(
                    base.omega.abs() <= limits[0].velocity + 1e-9,
                    "base command {}",
                    base.omega
                );
                (plant.v, plant.omega) = (base.v, base.omega);
                if base.v > 0.05 {
                    moving_commands += 1;
                }
            }
            gripper_in.update().unwrap();
            plant.closing =
                gripper_in.get().and_then(GripperCommand::action) == Some(GripperAction::Close);
            mission_in.update().unwrap();
            if let Some(phase) = mission_in.get().map(phase_of)
                && phases.last() != Some(&phase)
            {
                phases.push(phase);
            }
            let mut joints = JointState::zeroed();
            joints.joint_count = plant.q.len() as u32;
            joints.position[..plant.q.len()].copy_from_slice(&plant.q);
            joints.velocity[..plant.q.len()].copy_from_slice(&plant.qd);
            joints_out.publish(joints).unwrap();
            let mut odometry = BaseOdometry::zeroed();
            (odometry.x, odometry.y, odometry.yaw) = (plant.base.x, plant.base.y, plant.base.yaw);
            (odometry.v, odometry.omega) = (plant.v, plant.omega);
            odometry_out.publish(odometry).unwrap();
            let mut gripper = GripperState::zeroed();
            gripper.width = plant.opening;
            gripper_out.publish(gripper).unwrap();
            stack.assert_alive();
        }
        eprintln!(
            "mission complete after {mission_time:.2} s (single process: {reference:.2} s), {commands} arm commands, base at ({:.2}, {:.2}); phases {phases:?}",
            plant.base.x, plant.base.y
        );
        assert_eq!(
            phases, reference_phases,
            "the same tasks in one process went through other phases"
        );
        assert!(moving_commands > 100, "the base must have been driven");
        stack.terminate();
    }
    assert_eq!(
        phases,
        vec![
            code(0, Phase::Reach),
            code(0, Phase::Final),
            code(1, Phase::Reach),
            code(1, Phase::Final),
            code(2, Phase::Complete)
        ]
    );
    std::fs::remove_dir_all(&folder).unwrap();
    // SAFETY: the test's bus is dropped and every process is reaped.
    unsafe { remove_domain(&ipc) }.unwrap();
    let left = shared_memory_entries(&ipc).unwrap();
    assert!(left.is_empty(), "stale iceoryx2 resources: {left:?}");
}
