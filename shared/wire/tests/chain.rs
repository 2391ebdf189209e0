//! The five control services as real processes, closing the loop over iceoryx2 with this test
//! process standing in for the supervisor (the mission) and for the drivers (a kinematic
//! robot that integrates the commands in real time). The services must carry a pick and a
//! place of static targets through to the end of the mission, with finite commands within
//! the joint velocity limits, take the single-process controller's time within 5 %, and leave
//! no process and no shared memory behind.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, IpcConfig, Latest, PREFIX_ENV, Publisher, Qos, Subscriber, remove_domain,
    shared_memory_entries,
};
use motm_core::kinematics::BasePose;
use motm_core::mission::{Mission, MissionConfig, MissionTask, Phase, TaskKind};
use motm_core::on_the_move::{OnTheMove, OnTheMoveConfig, OnTheMoveInput};
use motm_core::stack::reach_aim;
use motm_core::{BaseVelocity, Robot, TargetEstimate, TaskProgress, wrap_angle};
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, GripperAction, GripperCommand,
    GripperState, JointState, Message, MissionState, TaskKindCode, TwistCommand, services,
};
use motm_wire::convert;
use nalgebra::Vector3;

/// The services under test, in start order.
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

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// The folder with the service binaries (next to this test's `deps/` folder); builds them
/// with `$CARGO` when one is missing.
fn binaries() -> PathBuf {
    let dir = std::env::current_exe()
        .unwrap()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    if SERVICES.iter().any(|s| !dir.join(s).is_file()) {
        let cargo = std::env::var("CARGO").expect("service binaries missing and $CARGO not set");
        eprintln!("building the service binaries with {cargo}");
        let mut build = Command::new(cargo);
        build.arg("build");
        for s in SERVICES {
            build.args(["-p", &format!("motm-{s}")]);
        }
        assert!(
            build.status().unwrap().success(),
            "cargo build of the services failed"
        );
    }
    dir
}

/// The running services; killed and reaped on drop if the test fails early.
struct Stack {
    children: Vec<(&'static str, Child)>,
}

impl Stack {
    fn start(ipc: &IpcConfig, rate: &str) -> Self {
        let dir = binaries();
        let children = SERVICES
            .iter()
            .map(|&name| {
                let child = Command::new(dir.join(name))
                    .arg("--config-dir")
                    .arg(config_dir())
                    .args(["--rate", rate, "--base-speed", "0.3"])
                    .env(PREFIX_ENV, &ipc.prefix)
                    .spawn()
                    .unwrap_or_else(|e| panic!("{name} starts: {e}"));
                (name, child)
            })
            .collect();
        Self { children }
    }

    /// Asserts that every service is still running.
    fn assert_alive(&mut self) {
        for (name, child) in &mut self.children {
            assert!(matches!(child.try_wait(), Ok(None)), "{name} died");
        }
    }

    /// SIGTERMs every service and asserts that each exits successfully.
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

/// The kinematic robot and the mission, standing in for drivers and supervisor.
struct Plant {
    robot: Robot,
    config: OnTheMoveConfig,
    mission: Mission,
    base: BasePose,
    v: f64,
    omega: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    opening: f64,
    closing: bool,
}

impl Plant {
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

    /// The supervisor's step: tool-to-aim distance and the final phase's progress.
    fn step_mission(&mut self, progress: TaskProgress) {
        let Some(task) = self.mission.current_task().copied() else {
            return;
        };
        let tool = self.robot.tool_pose(&self.base, &self.q).translation.vector;
        let aim = reach_aim(
            task.kind,
            &TargetEstimate::fixed(task.position),
            &self.config,
        );
        self.mission.step((tool - aim.position).norm(), progress);
    }

    fn mission_state(&self) -> MissionState {
        let mut m = MissionState::zeroed();
        m.task_index = self.mission.task_index() as u32;
        m.task_count = self.mission.tasks().len() as u32;
        m.phase = convert::phase_code(self.mission.phase()).into();
        let (kind, target) = match self.mission.current_task() {
            Some(task) => (task.kind, task.position),
            None => (TaskKind::Pick, Vector3::zeros()),
        };
        m.task_kind = match kind {
            TaskKind::Pick => TaskKindCode::Pick,
            TaskKind::Place => TaskKindCode::Place,
            TaskKind::PressButton => TaskKindCode::PressButton,
        }
        .into();
        if self.mission.current_task().is_some() {
            m.current_target = target.into();
            m.next_target = self.mission.next_waypoint(&target).into();
            m.has_next = 1;
        }
        m
    }
}

/// The pick and place of these tests.
fn tasks() -> Vec<MissionTask> {
    vec![
        MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: Vector3::new(2.0, 0.3, 0.45),
        },
        MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(4.0, 0.3, 0.35),
        },
    ]
}

/// A plant at rest at the start, with `tasks`' mission.
fn plant(robot: Robot) -> Plant {
    Plant {
        q: robot.config.ready_pose.clone(),
        qd: vec![0.0; robot.arm_dof()],
        robot,
        config: OnTheMoveConfig::default(),
        mission: Mission::new(MissionConfig::default(), tasks(), Vector3::zeros()),
        base: BasePose::default(),
        v: 0.0,
        omega: 0.0,
        opening: 0.08,
        closing: false,
    }
}

/// Time the single-process controller needs for the mission on the same plant, s.
fn single_process_mission_time(robot: &Robot) -> f64 {
    let mut plant = plant(robot.clone());
    let mut controller = OnTheMove::new(
        robot.clone(),
        plant.config.clone(),
        tasks(),
        Vector3::zeros(),
    );
    let dt = DT.as_secs_f64();
    let mut t = 0.0;
    while controller.mission().phase() != Phase::Complete {
        assert!(
            t < MISSION_TIMEOUT.as_secs_f64(),
            "single-process mission not complete"
        );
        let task = controller.mission().current_task().copied().unwrap();
        let out = controller.step(&OnTheMoveInput {
            t,
            dt,
            base: plant.base,
            base_velocity: BaseVelocity {
                v: plant.v,
                omega: plant.omega,
            },
            arm_q: &plant.q,
            gripper_opening: plant.opening,
            target: TargetEstimate::fixed(task.position),
        });
        (plant.v, plant.omega) = (out.base.v, out.base.omega);
        plant.qd.copy_from_slice(&out.arm_qd);
        plant.closing = out.gripper == motm_core::GripperCommand::Close;
        plant.integrate(dt);
        t += dt;
    }
    t
}

#[test]
fn the_control_services_carry_a_pick_and_place_through_over_iceoryx2() {
    run_pick_and_place("200");
}

#[test]
fn the_control_services_also_work_at_1_khz() {
    run_pick_and_place("1000");
}

/// Runs the services at `rate` Hz through a pick and place; see the file's doc.
fn run_pick_and_place(rate: &str) {
    let robot = Robot::load(&config_dir(), "frankie").unwrap();
    let limits = robot.limits();
    let reference = single_process_mission_time(&robot);
    let mut plant = plant(robot);
    let ipc = IpcConfig {
        prefix: format!("motmt{}_chain{rate}_", std::process::id()),
    };
    let mut phases = vec![(0, Phase::Reach)];
    {
        let bus = Bus::open_with("chain-test", &ipc).unwrap();
        let qos = Qos::default();
        let mut mission_out =
            Publisher::<MissionState>::new(&bus, services::MISSION_STATE, &qos).unwrap();
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
        let mut final_in =
            Latest::<TwistCommand>::new(&bus, services::CONTROL_FINAL_TWIST, &qos).unwrap();
        let mut stack = Stack::start(&ipc, rate);

        let start = Instant::now();
        let mut mission_time = 0.0;
        let mut last = Instant::now();
        let mut commands = 0u64;
        let mut moving_commands = 0u64;
        while plant.mission.phase() != Phase::Complete {
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
            final_in.update().unwrap();
            let progress = final_in
                .get()
                .filter(|m| m.task_index as usize == plant.mission.task_index())
                .and_then(convert::progress)
                .unwrap_or(TaskProgress::Active);
            plant.step_mission(progress);
            let phase = (plant.mission.task_index(), plant.mission.phase());
            if phases.last() != Some(&phase) {
                phases.push(phase);
            }
            mission_out.publish(plant.mission_state()).unwrap();
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
        // The equivalence criterion between the deployed and the in-process form.
        assert!(
            (mission_time - reference).abs() <= 0.05 * reference,
            "mission took {mission_time:.2} s over processes, {reference:.2} s in one"
        );
        assert!(moving_commands > 100, "the base must have been driven");
        stack.terminate();
    }
    assert_eq!(
        phases,
        vec![
            (0, Phase::Reach),
            (0, Phase::Final),
            (1, Phase::Reach),
            (1, Phase::Final),
            (2, Phase::Complete)
        ]
    );
    // SAFETY: the test's bus is dropped and every service is reaped.
    unsafe { remove_domain(&ipc) }.unwrap();
    let left = shared_memory_entries(&ipc).unwrap();
    assert!(left.is_empty(), "stale iceoryx2 resources: {left:?}");
}
