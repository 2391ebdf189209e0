//! The real `panda-driver --backend fci` process against the fake robot and hand (the
//! `motm-franka` fake servers, at 1 kHz in a thread of this test) over loopback TCP and UDP,
//! with the stack's side played over iceoryx2 by this test: velocity commands go in, the
//! robot follows them within libfranka's limits, joint, gripper and status messages come out;
//! stale commands ramp down and finish the motion; dropped commands raise the reflex, which
//! the driver reports as a safe stop and, the arm at rest, recovers from on its own (unless
//! told not to). Waits are bounded (generously: the machine is shared),
//! no timing is asserted.

use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use motm_bus::{Bus, IpcConfig, Latest, OwnedProcess, PREFIX_ENV, Publisher, Qos, remove_domain};
use motm_franka::fake::{
    DropPlan, FakeHand, FakeHandConfig, FakeRobot, FakeRobotConfig, IdealArm, IdealHand,
    run_every_ms,
};
use motm_msgs::{
    ArmVelocityCommand, DriverMode, DriverStatus, GripperAction, GripperCommand, GripperState,
    JointState, Message, services,
};

const TIMEOUT: Duration = Duration::from_secs(30);
const LOCALHOST: IpAddr = IpAddr::V4(Ipv4Addr::LOCALHOST);

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

struct Fake {
    port: u16,
    hand_port: u16,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<FakeRobot>>,
}

impl Fake {
    fn start(config: FakeRobotConfig) -> Self {
        let mut robot = FakeRobot::bind(LOCALHOST, 0, config).unwrap();
        let mut hand = FakeHand::bind(LOCALHOST, 0, FakeHandConfig::default()).unwrap();
        let (port, hand_port) = (robot.port(), hand.port());
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut arm = IdealArm::default();
            let mut fingers = IdealHand::new(0.08, Some(0.03));
            run_every_ms(|| {
                robot.cycle(&mut arm);
                hand.cycle(&mut fingers);
                !flag.load(Ordering::Relaxed)
            });
            robot
        });
        Self {
            port,
            hand_port,
            stop,
            thread: Some(thread),
        }
    }

    fn finish(mut self) -> FakeRobot {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().unwrap()
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn spawn_driver(ipc: &IpcConfig, fake: &Fake, log: &Path, extra: &[&str]) -> OwnedProcess {
    OwnedProcess::spawn(
        Command::new(env!("CARGO_BIN_EXE_panda-driver"))
            .arg("--config-dir")
            .arg(config_dir())
            .args(["--backend", "fci", "--robot-ip", "127.0.0.1"])
            .args(["--fci-port", &fake.port.to_string()])
            .args(["--hand-port", &fake.hand_port.to_string()])
            .args(extra)
            .env(PREFIX_ENV, &ipc.prefix)
            .stderr(std::fs::File::create(log).unwrap()),
    )
    .expect("panda-driver starts")
}

/// The stack's side of the driver.
struct Stack {
    command: Publisher<ArmVelocityCommand>,
    gripper: Publisher<GripperCommand>,
    joints: Latest<JointState>,
    gripper_state: Latest<GripperState>,
    status: Latest<DriverStatus>,
}

impl Stack {
    fn new(bus: &Bus) -> Self {
        let qos = Qos::default();
        Self {
            command: Publisher::new(bus, services::ARM_VELOCITY_COMMAND, &qos).unwrap(),
            gripper: Publisher::new(bus, services::ARM_GRIPPER_COMMAND, &qos).unwrap(),
            joints: Latest::new(bus, services::ARM_JOINT_STATE, &qos).unwrap(),
            gripper_state: Latest::new(bus, services::ARM_GRIPPER_STATE, &qos).unwrap(),
            status: Latest::new(bus, services::ARM_DRIVER_STATUS, &qos).unwrap(),
        }
    }

    /// Every 5 ms (the stack's 200 Hz), sends `velocity` if given, until `done` or the timeout.
    fn until(
        &mut self,
        bus: &Bus,
        velocity: Option<f64>,
        mut done: impl FnMut(&mut Self) -> bool,
    ) -> bool {
        let start = Instant::now();
        while start.elapsed() < TIMEOUT {
            if let Some(v) = velocity {
                let mut m = ArmVelocityCommand::zeroed();
                m.joint_count = 7;
                m.velocity[..7].fill(v);
                self.command.publish(m).unwrap();
            }
            self.joints.update().ok();
            self.gripper_state.update().ok();
            self.status.update().ok();
            if done(self) {
                return true;
            }
            bus.update_connections();
            std::thread::sleep(Duration::from_millis(5));
        }
        false
    }
}

#[test]
fn the_fci_driver_follows_commands_grasps_and_finishes_on_stale_commands() {
    let ipc = IpcConfig {
        prefix: format!("motmt{}_fci_", std::process::id()),
    };
    let log = std::env::temp_dir().join(format!("motm-fci-driver-{}.log", std::process::id()));
    let fake = Fake::start(FakeRobotConfig::default());
    {
        let bus = Bus::open_with("fci-test", &ipc).unwrap();
        let mut stack = Stack::new(&bus);
        let driver = spawn_driver(&ipc, &fake, &log, &[]);
        // Tracking: the robot's joint velocity reaches the command.
        assert!(
            stack.until(&bus, Some(0.2), |s| s
                .joints
                .get()
                .is_some_and(|j| j.joint_count == 7
                    && j.velocity[..7].iter().all(|v| (v - 0.2).abs() < 1e-3))),
            "the robot never followed the command"
        );
        let status = *stack.status.get().expect("a status");
        assert_eq!(status.mode(), Some(DriverMode::Tracking));
        assert_eq!((status.hardware_ready, status.limit_violations), (1, 0));
        assert_eq!(status.validate(motm_bus::monotonic_now_ns(), None), Ok(()));
        // Close: a Grasp on the 0.03 m object.
        let mut close = GripperCommand::zeroed();
        close.action = GripperAction::Close.into();
        stack.gripper.publish(close).unwrap();
        assert!(
            stack
                .until(&bus, Some(0.2), |s| s.gripper_state.get().is_some_and(
                    |g| g.grasping == 1 && (g.width - 0.03).abs() < 1e-9
                )),
            "the hand never grasped"
        );
        // No more commands: stale, ramp to zero, motion finished.
        assert!(
            stack.until(&bus, None, |s| s
                .status
                .get()
                .is_some_and(|st| st.mode() == Some(DriverMode::Stale))
                && s.joints
                    .get()
                    .is_some_and(|j| j.velocity.iter().all(|v| v.abs() < 1e-9))),
            "the robot never stopped"
        );
        // Fresh commands again: a new motion.
        assert!(
            stack.until(&bus, Some(-0.2), |s| s
                .joints
                .get()
                .is_some_and(|j| j.velocity[..7]
                    .iter()
                    .all(|v| (v + 0.2).abs() < 1e-3))),
            "no new motion after the finish"
        );
        let status = driver.terminate().unwrap();
        assert!(status.success(), "{status:?}");
    }
    let robot = fake.finish();
    let c = robot.counters();
    assert!(c.motions >= 2 && c.finished >= 2, "{}", robot.summary());
    assert_eq!(c.reflexes, 0, "{}", robot.summary());
    assert_eq!(c.violations.commands, 0, "{}", robot.summary());
    let log = std::fs::read_to_string(&log).unwrap();
    assert!(log.contains("FCI motion ended: finished"), "{log}");
    assert!(log.contains("state-to-command latency"), "{log}");
    // SAFETY: every process of this prefix has exited.
    unsafe { remove_domain(&ipc) }.unwrap();
}

/// The fake robot drops 25 commands while the motion runs (the robot's reflex comes after 20),
/// with `extra` flags to the driver; once the driver counted safe-stop cycles for the reflex
/// and `after` has then held, returns the robot and the driver's log.
fn reflex_run(
    tag: &str,
    extra: &[&str],
    mut after: impl FnMut(&mut Stack, &Bus) -> bool,
) -> (FakeRobot, String) {
    let ipc = IpcConfig {
        prefix: format!("motmt{}_{tag}_", std::process::id()),
    };
    let log = std::env::temp_dir().join(format!("motm-fci-{tag}-{}.log", std::process::id()));
    let fake = Fake::start(FakeRobotConfig {
        drop: Some(DropPlan {
            at_ms: 8000,
            count: 25,
        }),
        ..FakeRobotConfig::default()
    });
    {
        let bus = Bus::open_with(&format!("fci-{tag}-test"), &ipc).unwrap();
        let mut stack = Stack::new(&bus);
        let driver = spawn_driver(&ipc, &fake, &log, extra);
        assert!(
            stack.until(&bus, Some(0.1), |s| s.joints.get().is_some_and(|j| (j
                .velocity[0]
                - 0.1)
                .abs()
                < 1e-3)),
            "the robot never followed the command"
        );
        // The drop comes while the motion runs: the reflex holds the driver in safe-stop. The
        // status (50 Hz) may show the hold for less than a period when the driver recovers at
        // once, so the reflex is seen in its cumulative count of safe-stop cycles.
        let safe_stops = |s: &Stack| s.status.get().map_or(0, |st| st.safe_stop_cycles);
        let before = safe_stops(&stack);
        assert!(
            stack.until(&bus, Some(0.1), |s| safe_stops(s) > before),
            "the driver never reported the reflex"
        );
        assert!(
            after(&mut stack, &bus),
            "{}",
            std::fs::read_to_string(&log).unwrap()
        );
        let status = driver.terminate().unwrap();
        assert!(status.success(), "{status:?}");
    }
    let robot = fake.finish();
    assert_eq!(robot.counters().reflexes, 1, "{}", robot.summary());
    assert_eq!(
        robot.counters().violations.commands,
        0,
        "{}",
        robot.summary()
    );
    let log = std::fs::read_to_string(&log).unwrap();
    assert!(log.contains("communication_constraints_violation"), "{log}");
    assert!(log.contains("not commandable"), "{log}");
    // SAFETY: every process of this prefix has exited.
    unsafe { remove_domain(&ipc) }.unwrap();
    (robot, log)
}

#[test]
fn a_communication_reflex_is_recovered_once_the_arm_is_at_rest_and_the_robot_follows_again() {
    let (robot, log) = reflex_run("fcic", &[], |stack, bus| {
        stack.until(bus, Some(0.1), |s| {
            s.status
                .get()
                .is_some_and(|st| st.mode() == Some(DriverMode::Tracking) && st.hardware_ready == 1)
                && s.joints
                    .get()
                    .is_some_and(|j| (j.velocity[0] - 0.1).abs() < 1e-3)
        })
    });
    assert_eq!(robot.counters().recoveries, 1, "{}", robot.summary());
    assert!(robot.counters().motions >= 2, "{}", robot.summary());
    assert!(
        log.contains("AutomaticErrorRecovery answered Success"),
        "{log}"
    );
    assert!(log.contains("1 reflexes, 1 recoveries"), "{log}");
}

#[test]
fn dropped_commands_raise_a_reflex_that_the_driver_holds_without_automatic_recovery() {
    // Two more seconds of fresh commands: the safe-stop is still held.
    let (robot, _log) = reflex_run(
        "fcir",
        &["--communication-recoveries-per-minute", "0"],
        |stack, bus| {
            assert!(
                stack.until(bus, Some(0.1), |s| s.status.get().is_some_and(|st| {
                    st.mode() == Some(DriverMode::SafeStop) && st.hardware_ready == 0
                })),
                "the driver never reported the held safe-stop"
            );
            let start = Instant::now();
            let mut held = true;
            stack.until(bus, Some(0.1), |s| {
                held &= s.status.get().is_some_and(|st| {
                    st.mode() == Some(DriverMode::SafeStop) && st.hardware_ready == 0
                });
                !held || start.elapsed() > Duration::from_secs(2)
            });
            held
        },
    );
    assert_eq!(robot.counters().recoveries, 0, "never recovered");
}
