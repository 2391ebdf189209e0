//! The watchdog process against a fake control path published from this test: safe-stop is
//! raised until the control path is heard, cleared while heartbeats and commands flow, and
//! raised again when the command stream stalls. Waits are bounded only to fail, not timed.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, CycleStats, HeartbeatPublisher, IpcConfig, Latest, Publisher, Qos, cleanup_dead_nodes,
    remove_domain,
};
use motm_msgs::{
    ArmVelocityCommand, BaseVelocityCommand, Message, ProcessState, SafeStop, SafeStopReason,
    services,
};

const WATCHDOG: &str = env!("CARGO_BIN_EXE_watchdog");
const PATIENCE: Duration = Duration::from_secs(20);

#[test]
fn safe_stop_follows_the_control_path() {
    let ipc = IpcConfig {
        prefix: format!("motmt{}_wd_", std::process::id()),
    };
    let dir = std::env::temp_dir().join(format!("motm-wd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let stack = dir.join("stack.toml");
    std::fs::write(
        &stack,
        "robot = \"frankie\"\nscenario = \"exp1-dynamic\"\ncontrol_rate_hz = 200.0\n\
         partial = true\n[[process]]\nname = \"qp-resolver\"\n",
    )
    .unwrap();
    let mut watchdog = ChildGuard(
        Command::new(WATCHDOG)
            .arg("--stack")
            .arg(&stack)
            .env(motm_bus::PREFIX_ENV, &ipc.prefix)
            .stdin(Stdio::null())
            .spawn()
            .unwrap(),
    );
    {
        // This test plays the qp-resolver.
        let bus = Bus::open_with("qp-resolver", &ipc).unwrap();
        let qos = Qos::default();
        let mut heartbeat = HeartbeatPublisher::new(&bus).unwrap();
        let mut stats = CycleStats::new(16);
        let mut arm =
            Publisher::<ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &qos)
                .unwrap();
        let mut base =
            Publisher::<BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_COMMAND, &qos)
                .unwrap();
        let mut safe_stop =
            Latest::<SafeStop>::new(&bus, services::SAFETY_SAFE_STOP, &qos).unwrap();
        let mut read = |bus: &Bus| {
            bus.update_connections();
            let _ = safe_stop.update();
            safe_stop.get().map(|s| (s.active, s.reason))
        };
        let start = Instant::now();
        // Nothing heard yet: held while the stack starts (not a fault).
        while read(&bus).is_none() {
            assert!(start.elapsed() < PATIENCE, "no safe-stop from the watchdog");
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(read(&bus), Some((1, SafeStopReason::Starting.into())));
        // Heartbeats and commands flow: cleared.
        let mut cleared = false;
        while !cleared {
            assert!(start.elapsed() < PATIENCE, "safe-stop never cleared");
            stats.record(1000, false, motm_bus::monotonic_now_ns());
            heartbeat
                .publish(ProcessState::Running, &mut stats, 5_000_000, 0)
                .unwrap();
            let mut command = ArmVelocityCommand::zeroed();
            command.joint_count = 7;
            arm.publish(command).unwrap();
            base.publish(BaseVelocityCommand::zeroed()).unwrap();
            std::thread::sleep(Duration::from_millis(2));
            cleared = read(&bus) == Some((0, SafeStopReason::None.into()));
        }
        // Commands stop while heartbeats go on: raised for a stale command.
        let mut raised = None;
        while raised.is_none() {
            assert!(
                start.elapsed() < PATIENCE,
                "stale commands never raised safe-stop"
            );
            heartbeat
                .publish(ProcessState::Running, &mut stats, 5_000_000, 0)
                .unwrap();
            std::thread::sleep(Duration::from_millis(2));
            raised = read(&bus).filter(|s| s.0 == 1);
        }
        assert_eq!(raised, Some((1, SafeStopReason::StaleCommand.into())));
    }
    // SAFETY: kill(2) on our own child.
    unsafe { libc_kill(watchdog.0.id()) };
    assert!(watchdog.0.wait().unwrap().success());
    cleanup_dead_nodes(&ipc).unwrap();
    // SAFETY: the watchdog has exited and this test's bus is dropped.
    unsafe { remove_domain(&ipc) }.unwrap();
    assert_eq!(
        motm_bus::shared_memory_entries(&ipc).unwrap(),
        Vec::<PathBuf>::new()
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// SIGTERM to `pid`.
unsafe fn libc_kill(pid: u32) {
    // SAFETY: kill(2) has no memory-safety preconditions.
    unsafe {
        libc::kill(pid as i32, libc::SIGTERM);
    }
}

/// Kills the child if the test fails before stopping it, so no process outlives the test.
struct ChildGuard(std::process::Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}
