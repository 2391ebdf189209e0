//! The real `qp-resolver` process over iceoryx2: this test publishes a mission, joint state,
//! odometry, a reach twist and a base target, and checks the commands the process sends; then
//! that a NaN joint state is dropped and counted, that a stale twist stops the robot, and that
//! the process exits cleanly on SIGTERM leaving nothing in shared memory.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, IpcConfig, Latest, OwnedProcess, PREFIX_ENV, Publisher, Qos, Subscriber, remove_domain,
    shared_memory_entries,
};
use motm_core::Robot;
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, Heartbeat, JointState, Message,
    MissionState, QpOutcome, QpStatus, TaskKindCode, TaskPhase, TaskProgressCode, TwistCommand,
    services,
};

/// Longest wait for anything (generous: the machine is shared and noisy).
const TIMEOUT: Duration = Duration::from_secs(30);

/// Frankie's ready pose.
const READY: [f64; 7] = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, std::f64::consts::FRAC_PI_4];

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// Starts the service on `ipc`'s prefix (killed and reaped on drop if the test fails early).
fn spawn_service(ipc: &IpcConfig) -> OwnedProcess {
    OwnedProcess::spawn(
        Command::new(env!("CARGO_BIN_EXE_qp-resolver"))
            .arg("--config-dir")
            .arg(config_dir())
            .args(["--rate", "200"])
            .env(PREFIX_ENV, &ipc.prefix),
    )
    .expect("qp-resolver starts")
}

/// The inputs the test feeds the service.
struct Feeder {
    mission: Publisher<MissionState>,
    joints: Publisher<JointState>,
    odometry: Publisher<BaseOdometry>,
    reach: Publisher<TwistCommand>,
    base_target: Publisher<BaseVelocityCommand>,
}

impl Feeder {
    fn new(bus: &Bus) -> Self {
        let qos = Qos::default();
        Self {
            mission: Publisher::new(bus, services::MISSION_STATE, &qos).unwrap(),
            joints: Publisher::new(bus, services::ARM_JOINT_STATE, &qos).unwrap(),
            odometry: Publisher::new(bus, services::BASE_ODOMETRY, &qos).unwrap(),
            reach: Publisher::new(bus, services::CONTROL_REACH_TWIST, &qos).unwrap(),
            base_target: Publisher::new(bus, services::BASE_VELOCITY_TARGET, &qos).unwrap(),
        }
    }

    /// Publishes one consistent set of inputs: a pick in its reach phase, the arm at its ready
    /// pose, the base moving at 0.3 m/s; the reach twist only when `with_twist`.
    fn publish(&mut self, with_twist: bool) {
        let mut mission = MissionState::zeroed();
        mission.task_count = 2;
        mission.task_kind = TaskKindCode::Pick.into();
        mission.phase = TaskPhase::Reach.into();
        mission.current_target = [2.0, 0.0, 0.45];
        mission.next_target = [4.0, 0.0, 0.35];
        mission.has_next = 1;
        self.mission.publish(mission).unwrap();
        self.joints.publish(joint_state(READY)).unwrap();
        let mut odometry = BaseOdometry::zeroed();
        odometry.v = 0.3;
        self.odometry.publish(odometry).unwrap();
        let mut target = BaseVelocityCommand::zeroed();
        target.v = 0.3;
        self.base_target.publish(target).unwrap();
        if with_twist {
            let mut twist = TwistCommand::zeroed();
            twist.phase = TaskPhase::Reach.into();
            twist.progress = TaskProgressCode::Active.into();
            twist.twist = [0.05, 0.0, 0.02, 0.0, 0.0, 0.0];
            self.reach.publish(twist).unwrap();
        }
    }
}

fn joint_state(position: [f64; 7]) -> JointState {
    let mut joints = JointState::zeroed();
    joints.joint_count = 7;
    joints.position[..7].copy_from_slice(&position);
    joints
}

/// What the service sent.
struct Commands {
    arm: Subscriber<ArmVelocityCommand>,
    base: Subscriber<BaseVelocityCommand>,
    status: Latest<QpStatus>,
    heartbeat: Latest<Heartbeat>,
}

/// One arm command with the base command of the same cycle.
struct Sent {
    arm: Vec<f64>,
    base: (f64, f64),
}

impl Commands {
    fn new(bus: &Bus) -> Self {
        let qos = Qos::default();
        Self {
            arm: Subscriber::new(bus, services::ARM_VELOCITY_COMMAND, &qos).unwrap(),
            base: Subscriber::new(bus, services::BASE_VELOCITY_COMMAND, &qos).unwrap(),
            status: Latest::new(bus, services::CONTROL_QP_STATUS, &qos).unwrap(),
            heartbeat: Latest::new(bus, &services::heartbeat("qp-resolver"), &qos).unwrap(),
        }
    }

    /// The newest command pair, if a new one arrived.
    fn latest(&mut self) -> Option<Sent> {
        let arm = self.arm.latest().unwrap()?;
        let base = self.base.latest().unwrap()?;
        self.status.update().unwrap();
        Some(Sent {
            arm: arm.velocity[..arm.joint_count as usize].to_vec(),
            base: (base.v, base.omega),
        })
    }
}

/// Feeds inputs every 5 ms until `done` accepts a command; panics after [`TIMEOUT`].
fn feed_until(
    feeder: &mut Feeder,
    commands: &mut Commands,
    with_twist: bool,
    what: &str,
    mut done: impl FnMut(&Sent, &mut Commands) -> bool,
) {
    let start = Instant::now();
    loop {
        assert!(start.elapsed() < TIMEOUT, "timed out waiting for {what}");
        feeder.publish(with_twist);
        std::thread::sleep(Duration::from_millis(5));
        if let Some(command) = commands.latest()
            && done(&command, commands)
        {
            return;
        }
    }
}

#[test]
fn qp_resolver_process_turns_a_twist_into_limited_commands_and_drops_nan_input() {
    let robot = Robot::load(&config_dir(), "frankie").unwrap();
    let limits = robot.limits();
    let ipc = IpcConfig {
        prefix: format!("motmt{}_qp_", std::process::id()),
    };
    {
        let bus = Bus::open_with("qp-resolver-test", &ipc).unwrap();
        let mut feeder = Feeder::new(&bus);
        let mut commands = Commands::new(&bus);
        let service = spawn_service(&ipc);

        // A resolved command: moving, finite, within every velocity limit, from a solved QP.
        let mut resolved = 0;
        feed_until(
            &mut feeder,
            &mut commands,
            true,
            "resolved commands",
            |c, commands| {
                let base = [c.base.0, c.base.1];
                assert!(
                    c.arm.iter().chain(&base).all(|v| v.is_finite()),
                    "non-finite command"
                );
                assert_eq!(c.arm.len(), 7);
                // Full joint order: base yaw, base forward, arm.
                let full = [c.base.1, c.base.0]
                    .into_iter()
                    .chain(c.arm.iter().copied());
                for (v, limit) in full.zip(&limits) {
                    assert!(
                        v.abs() <= limit.velocity + 1e-9,
                        "{v} beyond {}",
                        limit.velocity
                    );
                }
                let moving = c.arm.iter().any(|v| v.abs() > 1e-4) && c.base.0 > 0.1;
                let solved = commands.status.get().is_some_and(|s| {
                    matches!(
                        s.outcome.try_into(),
                        Ok(QpOutcome::Solved | QpOutcome::AlmostSolved)
                    )
                });
                if moving && solved {
                    resolved += 1;
                }
                resolved >= 10
            },
        );

        // A NaN joint state is dropped and counted (the heartbeat reports it); commands stay
        // finite and keep coming from the last valid state.
        let mut bad = READY;
        bad[2] = f64::NAN;
        feeder.joints.publish(joint_state(bad)).unwrap();
        feed_until(
            &mut feeder,
            &mut commands,
            true,
            "the rejection in the heartbeat",
            |c, commands| {
                assert!(c.arm.iter().all(|v| v.is_finite()));
                commands.heartbeat.update().unwrap();
                commands
                    .heartbeat
                    .get()
                    .is_some_and(|h| h.rejected_messages >= 1)
            },
        );

        // Without a twist the command goes to zero once the last one is stale.
        feed_until(
            &mut feeder,
            &mut commands,
            false,
            "a stop on a stale twist",
            |c, _| c.arm.iter().all(|v| *v == 0.0) && c.base == (0.0, 0.0),
        );

        let status = service.terminate().unwrap();
        assert!(status.success(), "qp-resolver exited with {status}");
    }
    // SAFETY: the test's bus is dropped and the service is reaped.
    unsafe { remove_domain(&ipc) }.unwrap();
    let left = shared_memory_entries(&ipc).unwrap();
    assert!(left.is_empty(), "stale iceoryx2 resources: {left:?}");
}
