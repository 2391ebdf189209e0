//! The whole Franka chain as real processes: `sim-world` (the physics), `fake-panda --physics
//! sim` (the FCI robot and hand, bridged to sim-world's `motm/v1/hw/*` services) and
//! `panda-driver --backend fci`, over loopback TCP/UDP and iceoryx2. Ignored by default because
//! it needs the two other binaries built next to panda-driver:
//!
//! ```text
//! cargo build -p motm-sim-world -p motm-fake-panda
//! cargo test -p motm-panda-driver --test fci_sim -- --ignored
//! ```

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use motm_bus::{Bus, IpcConfig, Latest, OwnedProcess, PREFIX_ENV, Publisher, Qos, remove_domain};
use motm_msgs::{
    ArmVelocityCommand, DriverMode, DriverStatus, GripperAction, GripperCommand, GripperState,
    JointState, Message, services,
};

const TIMEOUT: Duration = Duration::from_secs(60);

/// A condition on the driver's joint state, sim-world's, the gripper state and the status.
type Check<'a> =
    dyn FnMut(&JointState, &JointState, Option<&GripperState>, Option<&DriverStatus>) -> bool + 'a;

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

fn binary(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_BIN_EXE_panda-driver"))
        .parent()
        .unwrap()
        .join(name);
    assert!(
        path.exists(),
        "{} missing: cargo build -p motm-sim-world -p motm-fake-panda",
        path.display()
    );
    path
}

fn spawn(ipc: &IpcConfig, program: &Path, args: &[&str], log: &Path) -> OwnedProcess {
    OwnedProcess::spawn(
        Command::new(program)
            .arg("--config-dir")
            .arg(config_dir())
            .args(args)
            .env(PREFIX_ENV, &ipc.prefix)
            .stderr(std::fs::File::create(log).unwrap()),
    )
    .unwrap()
}

#[test]
#[ignore = "needs sim-world and fake-panda built; see the module docs"]
fn sim_world_fake_panda_and_the_fci_driver_move_and_grasp_together() {
    let ipc = IpcConfig {
        prefix: format!("motmt{}_fcis_", std::process::id()),
    };
    let dir = std::env::temp_dir();
    let id = std::process::id();
    let report = dir.join(format!("motm-fake-panda-{id}.json"));
    let driver_log = dir.join(format!("motm-fcis-driver-{id}.log"));
    let (fci_port, hand_port) = (20000 + (id % 20000) as u16, 40000 + (id % 20000) as u16);
    {
        let bus = Bus::open_with("fci-sim-test", &ipc).unwrap();
        let qos = Qos::default();
        let mut command =
            Publisher::<ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &qos)
                .unwrap();
        let mut gripper =
            Publisher::<GripperCommand>::new(&bus, services::ARM_GRIPPER_COMMAND, &qos).unwrap();
        let mut joints = Latest::<JointState>::new(&bus, services::ARM_JOINT_STATE, &qos).unwrap();
        let mut hw_joints = Latest::<JointState>::new(&bus, services::HW_ARM_STATE, &qos).unwrap();
        let mut gripper_state =
            Latest::<GripperState>::new(&bus, services::ARM_GRIPPER_STATE, &qos).unwrap();
        let mut status =
            Latest::<DriverStatus>::new(&bus, services::ARM_DRIVER_STATUS, &qos).unwrap();
        let sim = spawn(
            &ipc,
            &binary("sim-world"),
            &[],
            &dir.join(format!("motm-fcis-sim-{id}.log")),
        );
        let fake_args = [
            "--physics".to_owned(),
            "sim".to_owned(),
            "--fci-port".to_owned(),
            fci_port.to_string(),
            "--hand-port".to_owned(),
            hand_port.to_string(),
            "--report".to_owned(),
            report.display().to_string(),
        ];
        let fake_args: Vec<&str> = fake_args.iter().map(String::as_str).collect();
        let fake = OwnedProcess::spawn(
            Command::new(binary("fake-panda"))
                .args(&fake_args)
                .env(PREFIX_ENV, &ipc.prefix)
                .stderr(
                    std::fs::File::create(dir.join(format!("motm-fcis-fake-{id}.log"))).unwrap(),
                ),
        )
        .unwrap();
        std::thread::sleep(Duration::from_millis(500));
        let (fp, hp) = (fci_port.to_string(), hand_port.to_string());
        let driver = spawn(
            &ipc,
            Path::new(env!("CARGO_BIN_EXE_panda-driver")),
            &[
                "--backend",
                "fci",
                "--robot-ip",
                "127.0.0.1",
                "--fci-port",
                &fp,
                "--hand-port",
                &hp,
            ],
            &driver_log,
        );
        let mut step = |v: Option<[f64; 7]>, done: &mut Check<'_>| {
            let start = Instant::now();
            while start.elapsed() < TIMEOUT {
                if let Some(v) = v {
                    let mut m = ArmVelocityCommand::zeroed();
                    m.joint_count = 7;
                    m.velocity[..7].copy_from_slice(&v);
                    command.publish(m).unwrap();
                }
                joints.update().ok();
                hw_joints.update().ok();
                gripper_state.update().ok();
                status.update().ok();
                if let (Some(j), Some(h)) = (joints.get(), hw_joints.get())
                    && done(j, h, gripper_state.get(), status.get())
                {
                    return true;
                }
                bus.update_connections();
                std::thread::sleep(Duration::from_millis(5));
            }
            eprintln!(
                "last: driver {:?}\nhw {:?}\ngripper {:?}\nstatus {:?}",
                joints.get(),
                hw_joints.get(),
                gripper_state.get(),
                status.get()
            );
            false
        };
        let v = [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, -0.1];
        // The simulated arm follows the command through the FCI chain (sim-world's arm tracks
        // it within a few per cent); the driver's joint state is sim-world's, a cycle late at
        // most.
        assert!(
            step(Some(v), &mut |j, h, _, _| {
                (j.velocity[0] - 0.1).abs() < 1e-2
                    && (j.velocity[6] + 0.1).abs() < 1e-2
                    && (j.position[0] - h.position[0]).abs() < 1e-3
            }),
            "the simulated arm never followed"
        );
        let mut close = GripperCommand::zeroed();
        close.action = GripperAction::Close.into();
        gripper.publish(close).unwrap();
        assert!(
            step(Some(v), &mut |_, _, g, _| g
                .is_some_and(|g| g.width < 0.079)),
            "the simulated gripper never closed"
        );
        assert!(
            step(None, &mut |j, _, _, s| s
                .is_some_and(|s| s.mode() == Some(DriverMode::Stale))
                && j.velocity.iter().all(|v| v.abs() < 1e-6)),
            "the arm never stopped"
        );
        std::thread::sleep(Duration::from_millis(200));
        assert!(driver.terminate().unwrap().success());
        let fake_exit = fake.terminate().unwrap();
        assert!(sim.terminate().unwrap().success());
        assert!(
            fake_exit.success(),
            "fake-panda counted limit violations: {fake_exit:?}"
        );
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(report["limit_violations"]["commands"], 0, "{report}");
    assert_eq!(report["reflexes"], 0, "{report}");
    assert!(
        report["motions"].as_u64() >= Some(1) && report["finished"].as_u64() >= Some(1),
        "{report}"
    );
    assert!(report["hand"]["actions"].as_u64() >= Some(1), "{report}");
    let log = std::fs::read_to_string(&driver_log).unwrap();
    assert!(log.contains("state-to-command latency"), "{log}");
    // SAFETY: every process of this prefix has exited.
    unsafe { remove_domain(&ipc) }.unwrap();
}
