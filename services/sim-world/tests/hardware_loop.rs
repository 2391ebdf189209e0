//! The hardware loop as real processes: sim-world, panda-driver and ld60-driver run as their
//! own binaries over iceoryx2 (a unique prefix per run), and this test plays the controllers and
//! the watchdog. It checks that velocity commands reach the world limited, that every command a
//! driver sends the hardware is within the velocity, acceleration and jerk limits, that stale
//! commands and safe-stop ramp to zero within those limits, and that the run leaves nothing in
//! shared memory.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus};
use std::thread::sleep;
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, IpcConfig, Latest, PREFIX_ENV, Publisher, Qos, Subscriber, cleanup_dead_nodes,
    monotonic_now_ns, remove_domain, shared_memory_entries,
};
use motm_core::command_limiter::AxisLimits;
use motm_core::{BASE_JOINTS, Robot};
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, CAMERA_HEIGHT, CAMERA_WIDTH,
    CameraImage, DriverMode, DriverStatus, Heartbeat, JointState, Message, SafeStop,
    SafeStopReason, SimOutcome, SimTruth, services,
};

/// Longest wait for anything (generous: the machine is shared and noisy).
const TIMEOUT: Duration = Duration::from_secs(30);
/// Control period of the commands this test sends (200 Hz).
const COMMAND_PERIOD: Duration = Duration::from_millis(5);
/// The arm joint this test moves (the Panda's wrist: velocity 2.61, acceleration 20, jerk 10000).
const JOINT: usize = 6;

/// The processes this test starts.
const PROCESSES: [&str; 3] = ["sim-world", "panda-driver", "ld60-driver"];

/// The service binaries, next to sim-world. Under cargo (`$CARGO` set) the drivers are built
/// first, so that the test never runs stale driver binaries (a no-op when they are fresh).
fn binaries() -> [PathBuf; 3] {
    let sim = PathBuf::from(env!("CARGO_BIN_EXE_sim-world"));
    let dir = sim.parent().unwrap().to_path_buf();
    if let Ok(cargo) = std::env::var("CARGO") {
        eprintln!("building panda-driver and ld60-driver with {cargo}");
        let mut build = Command::new(cargo);
        build.args(["build", "-p", "motm-panda-driver", "-p", "motm-ld60-driver"]);
        if !cfg!(debug_assertions) {
            build.arg("--release");
        }
        assert!(
            build.status().unwrap().success(),
            "building the drivers failed"
        );
    }
    let [panda, ld60] = [dir.join("panda-driver"), dir.join("ld60-driver")];
    for binary in [&panda, &ld60] {
        assert!(binary.is_file(), "{} is missing", binary.display());
    }
    [sim, panda, ld60]
}

/// Child processes of one iceoryx2 prefix. If the test fails before shutting them down, they
/// are killed and the prefix's resources removed, so a failed run leaves nothing behind either.
struct Processes(Vec<(String, Child)>, IpcConfig);

impl Processes {
    fn spawn(&mut self, binary: &Path, args: &[&str], prefix: &str) {
        let child = Command::new(binary)
            .args(args)
            .env(PREFIX_ENV, prefix)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", binary.display()));
        let name = binary.file_name().unwrap().to_string_lossy().into_owned();
        self.0.push((name, child));
    }

    fn assert_running(&mut self) {
        for (name, child) in &mut self.0 {
            assert!(child.try_wait().unwrap().is_none(), "{name} exited early");
        }
    }

    /// SIGTERM to every process; waits for each and returns the exit statuses.
    fn terminate(&mut self) -> Vec<(String, ExitStatus)> {
        for (_, child) in &self.0 {
            // SAFETY: plain kill(2) on our own child's pid.
            unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
        }
        self.0
            .drain(..)
            .map(|(name, mut child)| (name, child.wait().unwrap()))
            .collect()
    }
}

impl Drop for Processes {
    fn drop(&mut self) {
        if self.0.is_empty() {
            return;
        }
        for (_, child) in &mut self.0 {
            let _ = child.kill();
            let _ = child.wait();
        }
        let _ = cleanup_dead_nodes(&self.1);
        // SAFETY: every child is reaped, and the test's own bus was dropped before this guard
        // (it is declared after it).
        let _ = unsafe { remove_domain(&self.1) };
    }
}

/// Checks a driver's hardware command stream against the limits: velocity on every sample,
/// acceleration across consecutive samples (by sequence number), jerk across three.
struct StreamCheck {
    limits: Vec<AxisLimits>,
    dt: f64,
    last: Option<(u64, Vec<f64>, Option<Vec<f64>>)>,
    samples: u64,
    jerk_checked: u64,
}

impl StreamCheck {
    fn new(limits: Vec<AxisLimits>, dt: f64) -> Self {
        Self {
            limits,
            dt,
            last: None,
            samples: 0,
            jerk_checked: 0,
        }
    }

    fn push(&mut self, seq: u64, velocity: &[f64]) {
        self.samples += 1;
        let tol = 1.0 + 1e-6;
        for (i, (v, l)) in velocity.iter().zip(&self.limits).enumerate() {
            assert!(
                v.abs() <= l.velocity * tol,
                "axis {i}: velocity {v} beyond {}",
                l.velocity
            );
        }
        let mut acceleration = None;
        if let Some((last_seq, last_v, last_a)) = &self.last
            && seq == last_seq + 1
        {
            let a: Vec<f64> = velocity
                .iter()
                .zip(last_v)
                .map(|(v, lv)| (v - lv) / self.dt)
                .collect();
            for (i, (a, l)) in a.iter().zip(&self.limits).enumerate() {
                assert!(
                    a.abs() <= l.acceleration * tol,
                    "axis {i} seq {seq}: acceleration {a} beyond {}",
                    l.acceleration
                );
            }
            if let Some(last_a) = last_a {
                for (i, ((a, la), l)) in a.iter().zip(last_a).zip(&self.limits).enumerate() {
                    let j = (a - la) / self.dt;
                    assert!(
                        j.abs() <= l.jerk * tol,
                        "axis {i} seq {seq}: jerk {j} beyond {}",
                        l.jerk
                    );
                }
                self.jerk_checked += 1;
            }
            acceleration = Some(a);
        }
        self.last = Some((seq, velocity.to_vec(), acceleration));
    }

    fn last_velocity(&self) -> Option<&[f64]> {
        self.last.as_ref().map(|(_, v, _)| v.as_slice())
    }
}

/// The test's own ports: the controllers' and the watchdog's outputs, and everything to watch.
struct Harness {
    arm_command: Publisher<ArmVelocityCommand>,
    base_command: Publisher<BaseVelocityCommand>,
    safe_stop: Publisher<SafeStop>,
    hw_arm: Subscriber<ArmVelocityCommand>,
    hw_base: Subscriber<BaseVelocityCommand>,
    joints: Latest<JointState>,
    odometry: Latest<BaseOdometry>,
    arm_status: Latest<DriverStatus>,
    base_status: Latest<DriverStatus>,
    truth: Latest<SimTruth>,
    arm_check: StreamCheck,
    base_check: StreamCheck,
    /// Largest |velocity| of the moved joint the arm driver sent the hardware.
    arm_peak: f64,
    /// Commands sent (arm and base each).
    sent: u64,
    camera: Subscriber<CameraImage>,
    /// Camera frames received, and the stamp of the last one.
    frames: u64,
    last_frame_ns: u64,
}

impl Harness {
    /// Drains every stream into the checks.
    fn poll(&mut self) {
        while let Some(c) = self.hw_arm.receive().unwrap() {
            let v = &c.velocity[..c.joint_count as usize];
            self.arm_peak = self.arm_peak.max(v[JOINT].abs());
            self.arm_check.push(c.header.seq, v);
        }
        while let Some(image) = self.camera.receive().unwrap() {
            assert_eq!(
                (image.width, image.height),
                (CAMERA_WIDTH as u32, CAMERA_HEIGHT as u32)
            );
            assert!(
                image.header.stamp_ns > self.last_frame_ns,
                "frames in order"
            );
            assert!(image.pixels.iter().any(|&p| p != 0), "a rendered image");
            self.last_frame_ns = image.header.stamp_ns;
            self.frames += 1;
        }
        while let Some(c) = self.hw_base.receive().unwrap() {
            self.base_check.push(c.header.seq, &[c.v, c.omega]);
        }
        for latest in [&mut self.arm_status, &mut self.base_status] {
            latest.update().unwrap();
        }
        self.joints.update().unwrap();
        self.odometry.update().unwrap();
        self.truth.update().unwrap();
    }

    /// Sends commands every control period for `duration` (polling in between), optionally
    /// with safe-stop raised.
    fn command_for(&mut self, duration: Duration, arm_joint: f64, base: [f64; 2]) {
        let start = Instant::now();
        let mut next = start;
        while start.elapsed() < duration {
            if Instant::now() >= next {
                next += COMMAND_PERIOD;
                let mut arm = ArmVelocityCommand::zeroed();
                arm.joint_count = 7;
                arm.velocity[JOINT] = arm_joint;
                self.arm_command.publish(arm).unwrap();
                let mut b = BaseVelocityCommand::zeroed();
                b.v = base[0];
                b.omega = base[1];
                self.base_command.publish(b).unwrap();
                self.sent += 1;
            }
            self.poll();
            sleep(Duration::from_micros(200));
        }
    }

    /// Polls until `done` holds.
    fn wait_for(&mut self, what: &str, mut done: impl FnMut(&Self) -> bool) {
        let start = Instant::now();
        while !done(self) {
            assert!(start.elapsed() < TIMEOUT, "timed out waiting for {what}");
            self.poll();
            sleep(Duration::from_micros(200));
        }
    }

    fn raise_safe_stop(&mut self, active: bool) {
        let mut m = SafeStop::zeroed();
        m.active = active.into();
        m.reason = if active {
            SafeStopReason::Operator
        } else {
            SafeStopReason::None
        }
        .into();
        self.safe_stop.publish(m).unwrap();
    }

    fn arm_mode(&self) -> Option<DriverMode> {
        self.arm_status.get().and_then(DriverStatus::mode)
    }

    fn base_mode(&self) -> Option<DriverMode> {
        self.base_status.get().and_then(DriverStatus::mode)
    }

    fn hw_arm_joint(&self) -> f64 {
        self.arm_check
            .last_velocity()
            .map_or(f64::NAN, |v| v[JOINT])
    }

    fn hw_base(&self) -> [f64; 2] {
        self.base_check
            .last_velocity()
            .map_or([f64::NAN; 2], |v| [v[0], v[1]])
    }

    fn world_joint_velocity(&self) -> f64 {
        self.joints.get().map_or(f64::NAN, |j| j.velocity[JOINT])
    }
}

#[test]
fn commands_reach_the_world_limited_and_stale_or_stopped_commands_ramp_to_zero() {
    let [sim_world, panda_driver, ld60_driver] = binaries();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let robot = Robot::load(&config, "frankie").unwrap();
    let limits = robot.limits();
    let arm_limits: Vec<AxisLimits> = limits[BASE_JOINTS..].iter().map(AxisLimits::from).collect();
    let base_limits = vec![AxisLimits::from(&limits[1]), AxisLimits::from(&limits[0])];
    let joint_limit = arm_limits[JOINT].velocity;

    let ipc = IpcConfig {
        prefix: format!("motmt{}_hw_", std::process::id()),
    };
    let prefix = ipc.prefix.clone();
    let mut processes = Processes(Vec::new(), ipc.clone());
    {
        let bus = Bus::open_with("hw-test", &ipc).unwrap();
        // This test creates the command services first, with deep queues, so that it sees
        // every sample the drivers send and the drivers see every command it sends.
        let deep = Qos {
            subscriber_buffer: 64,
            ..Qos::default()
        };
        let qos = Qos::default();
        let mut h = Harness {
            arm_command: Publisher::new(&bus, services::ARM_VELOCITY_COMMAND, &deep).unwrap(),
            base_command: Publisher::new(&bus, services::BASE_VELOCITY_COMMAND, &deep).unwrap(),
            safe_stop: Publisher::new(&bus, services::SAFETY_SAFE_STOP, &qos).unwrap(),
            hw_arm: Subscriber::new(&bus, services::HW_ARM_COMMAND, &deep).unwrap(),
            hw_base: Subscriber::new(&bus, services::HW_BASE_COMMAND, &deep).unwrap(),
            joints: Latest::new(&bus, services::ARM_JOINT_STATE, &qos).unwrap(),
            odometry: Latest::new(&bus, services::BASE_ODOMETRY, &qos).unwrap(),
            arm_status: Latest::new(&bus, services::ARM_DRIVER_STATUS, &qos).unwrap(),
            base_status: Latest::new(&bus, services::BASE_DRIVER_STATUS, &qos).unwrap(),
            truth: Latest::new(&bus, services::SIM_TRUTH, &qos).unwrap(),
            arm_check: StreamCheck::new(arm_limits, 0.001),
            base_check: StreamCheck::new(base_limits, 0.02),
            arm_peak: 0.0,
            sent: 0,
            camera: Subscriber::new(&bus, services::CAMERA_IMAGE, &Qos::large()).unwrap(),
            frames: 0,
            last_frame_ns: 0,
        };
        let mut heartbeats: Vec<Latest<Heartbeat>> = PROCESSES
            .iter()
            .map(|p| Latest::new(&bus, &services::heartbeat(p), &qos).unwrap())
            .collect();
        h.raise_safe_stop(false);
        let config_arg = config.to_string_lossy().into_owned();
        let common = ["--config-dir", config_arg.as_str()];
        processes.spawn(
            &sim_world,
            &[&common[..], &["--scenario", "exp1-dynamic"]].concat(),
            &prefix,
        );
        // Commands go stale after 20 periods (100 ms) instead of 3, so that a test process
        // descheduled on a loaded machine does not trip the ramp by accident.
        let driver_args = [
            &common[..],
            &[
                "--scenario",
                "exp1-dynamic",
                "--control-rate",
                "200",
                "--stale-periods",
                "20",
            ],
        ]
        .concat();
        processes.spawn(&panda_driver, &driver_args, &prefix);
        processes.spawn(&ld60_driver, &driver_args, &prefix);

        // Up: both drivers see the hardware, the world runs.
        h.wait_for("the drivers and the world", |h| {
            h.arm_status.get().is_some_and(|s| s.hardware_ready == 1)
                && h.base_status.get().is_some_and(|s| s.hardware_ready == 1)
                && h.truth.get().is_some()
        });
        processes.assert_running();
        assert_eq!(h.arm_mode(), Some(DriverMode::Stale), "no command yet");
        let start_x = h.odometry.get().unwrap().x;

        // Tracking: 0.5 rad/s on the wrist, 0.2 m/s and 0.1 rad/s on the base.
        h.command_for(Duration::from_millis(800), 0.5, [0.2, 0.1]);
        assert_eq!(h.arm_mode(), Some(DriverMode::Tracking));
        assert_eq!(
            h.hw_arm_joint(),
            0.5,
            "the driver passes a feasible command through"
        );
        let world = h.world_joint_velocity();
        assert!(
            (world - 0.5).abs() < 0.1,
            "the world's wrist moves at {world}"
        );
        let odometry = *h.odometry.get().unwrap();
        assert!(
            (odometry.v - 0.2).abs() < 0.05,
            "the base drives at {}",
            odometry.v
        );
        assert!(odometry.x > start_x + 0.02, "the base moved");

        // Beyond the limits: 3 rad/s (limit 2.61) and 2 m/s (limit 1.2) are clamped and counted.
        let over_limit_before = h.arm_status.get().unwrap().limit_violations;
        assert_eq!(over_limit_before, 0);
        let sent_before = h.sent;
        h.command_for(Duration::from_millis(400), 3.0, [2.0, 0.1]);
        let over_limit_sent = h.sent - sent_before;
        assert_eq!(
            h.hw_arm_joint(),
            joint_limit,
            "clamped to the joint's velocity limit"
        );
        assert!(h.arm_peak <= joint_limit);
        let world = h.world_joint_velocity();
        assert!(
            world > 2.0 && world < joint_limit * 1.1,
            "the world's wrist moves at {world}"
        );

        // Stale: no more commands. Both drivers ramp to zero within their limits and hold it.
        let stale_start = Instant::now();
        h.wait_for("the ramp to zero", |h| {
            h.hw_arm_joint() == 0.0 && h.hw_base() == [0.0, 0.0]
        });
        let ramp = stale_start.elapsed();
        // 2.61 rad/s at 20 rad/s² cannot stop faster than 0.13 s (this bounds from below; the
        // stream check above proves every step is within the limits).
        assert!(ramp > Duration::from_millis(130), "ramped down in {ramp:?}");
        h.command_for(Duration::ZERO, 0.0, [0.0, 0.0]);
        h.wait_for("the stale status", |h| {
            h.arm_mode() == Some(DriverMode::Stale) && h.base_mode() == Some(DriverMode::Stale)
        });
        // Let the world settle, then it is at rest.
        let rest = Instant::now();
        while rest.elapsed() < Duration::from_millis(300) {
            h.poll();
            sleep(Duration::from_millis(1));
        }
        assert_eq!(h.hw_arm_joint(), 0.0, "zero is held");
        let world = h.world_joint_velocity();
        assert!(
            world.abs() < 0.05,
            "the world's wrist still moves at {world}"
        );

        // Safe-stop while fresh commands keep coming: ramp to zero, then resume when cleared.
        h.command_for(Duration::from_millis(400), -0.8, [0.1, 0.0]);
        assert_eq!(h.hw_arm_joint(), -0.8);
        h.raise_safe_stop(true);
        let stopping = Instant::now();
        loop {
            h.command_for(Duration::from_millis(20), -0.8, [0.1, 0.0]);
            if h.hw_arm_joint() == 0.0 && h.hw_base() == [0.0, 0.0] {
                break;
            }
            assert!(
                stopping.elapsed() < TIMEOUT,
                "safe-stop never stopped the robot"
            );
        }
        assert_eq!(h.arm_mode(), Some(DriverMode::SafeStop));
        h.raise_safe_stop(false);
        h.command_for(Duration::from_millis(400), -0.8, [0.1, 0.0]);
        assert_eq!(
            h.hw_arm_joint(),
            -0.8,
            "control resumes after safe-stop clears"
        );
        assert_eq!(h.arm_mode(), Some(DriverMode::Tracking));

        // Counters: every over-limit command was counted, no output broke a limit.
        let after = monotonic_now_ns();
        h.wait_for("the final status", |h| {
            [&h.arm_status, &h.base_status]
                .iter()
                .all(|s| s.get().unwrap().header.stamp_ns > after)
        });
        let arm = *h.arm_status.get().unwrap();
        let base = *h.base_status.get().unwrap();
        assert_eq!(arm.limit_violations, over_limit_sent, "{arm:?}");
        assert_eq!(arm.limit_violations, arm.clamped_commands, "{arm:?}");
        assert_eq!(base.limit_violations, arm.limit_violations, "{base:?}");
        assert_eq!((arm.output_violations, base.output_violations), (0, 0));
        assert!(arm.stale_cycles > 0 && arm.safe_stop_cycles > 0, "{arm:?}");
        assert!(
            arm.max_command_gap_ns > 300_000_000,
            "the stale pause is the longest gap"
        );
        // The checks saw most of the streams, with full jerk checks.
        assert!(
            h.arm_check.jerk_checked > 1000,
            "{} jerk-checked",
            h.arm_check.jerk_checked
        );
        assert!(
            h.base_check.jerk_checked > 50,
            "{} jerk-checked",
            h.base_check.jerk_checked
        );
        let truth = h.truth.get().unwrap();
        assert_eq!(truth.outcome(), Some(SimOutcome::Running));
        // Camera frames at 30 Hz for the whole run (a loaded machine may drop a few).
        assert!(
            h.frames as f64 > 0.5 * 30.0 * truth.sim_time,
            "{} frames in {} s",
            h.frames,
            truth.sim_time
        );
        // Loop statistics, for the record (timing is not asserted on this shared machine).
        for (process, beat) in PROCESSES.iter().zip(&mut heartbeats) {
            beat.update().unwrap();
            let b = beat.get().unwrap();
            eprintln!(
                "{process}: {} cycles, {} deadline misses, p99 {} us, max {} us",
                b.cycles,
                b.deadline_misses,
                b.p99_cycle_ns / 1000,
                b.max_cycle_ns / 1000
            );
        }
        eprintln!("sim-world: {} catch-up cycles", truth.catch_up_cycles);
        assert!(truth.sim_time > 2.0);
        processes.assert_running();
    }
    for (name, status) in processes.terminate() {
        assert!(status.success(), "{name} exited with {status}");
    }
    // SAFETY: every process of this prefix has exited and the test's bus is dropped.
    unsafe { remove_domain(&ipc) }.unwrap();
    assert_eq!(shared_memory_entries(&ipc).unwrap(), Vec::<PathBuf>::new());
}

#[test]
fn bad_input_exits_with_code_2_naming_the_culprit() {
    let [sim_world, panda_driver, ld60_driver] = binaries();
    let cases: [(&Path, &[&str], &str); 5] = [
        (
            &sim_world,
            &["--scenario", "no-such-scenario"],
            "no-such-scenario",
        ),
        (&sim_world, &["--rate", "0"], "--rate"),
        (&sim_world, &["--robot", "fetch"], "--robot fetch"),
        (
            &panda_driver,
            &["--robot", "no-such-robot"],
            "no-such-robot",
        ),
        (&ld60_driver, &["--stale-periods", "0"], "--stale-periods"),
    ];
    for (binary, args, culprit) in cases {
        let out = Command::new(binary)
            .args(args)
            .env(PREFIX_ENV, format!("motmt{}_bad_", std::process::id()))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            out.status.code(),
            Some(2),
            "{} {args:?}: {stderr}",
            binary.display()
        );
        assert!(
            stderr.contains(culprit),
            "{} {args:?}: {stderr}",
            binary.display()
        );
    }
}
