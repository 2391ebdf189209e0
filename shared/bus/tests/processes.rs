//! Cross-process tests: this test binary re-executes itself as the peer process (selected by
//! the `MOTM_BUS_TEST_ROLE` variable), so every sample really crosses a process boundary over
//! iceoryx2 shared memory. Each test uses its own iceoryx2 prefix and checks that nothing is
//! left in `/dev/shm` or iceoryx2's runtime folder afterwards.

use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, Flow, IpcConfig, Latest, LoopConfig, LoopExit, PREFIX_ENV, Publisher, Qos, ServiceLoop,
    Stamp, Subscriber, cleanup_dead_nodes, remove_domain, shared_memory_entries,
};
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, CAMERA_HEIGHT, CAMERA_IMAGE_BYTES, CAMERA_WIDTH, CameraImage,
    Heartbeat, JointState, Message, ProcessState, services,
};

/// Selects the peer role when the binary is re-executed.
const ROLE_ENV: &str = "MOTM_BUS_TEST_ROLE";

/// Longest wait for anything in these tests (generous: the machine is shared and noisy).
const TIMEOUT: Duration = Duration::from_secs(20);

/// Entry point of the peer processes. In a normal test run (no role set) it checks the role
/// dispatch itself: a peer started with a role it does not know fails, naming the role, and
/// leaves nothing on the bus (the other tests run the known roles).
#[test]
fn peer_process_entry() {
    let Ok(role) = std::env::var(ROLE_ENV) else {
        let ipc = unique_ipc("role");
        let out = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "peer_process_entry", "--test-threads=1"])
            .env(ROLE_ENV, "no-such-role")
            .env(PREFIX_ENV, &ipc.prefix)
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!out.status.success(), "{text}");
        assert!(text.contains("unknown role no-such-role"), "{text}");
        assert!(shared_memory_entries(&ipc).unwrap().is_empty());
        return;
    };
    match role.as_str() {
        "echo" => echo_peer(),
        "ticker" => ticker_peer(),
        "camera" => camera_peer(),
        other => panic!("unknown role {other}"),
    }
}

/// Echo peer: answers each arm velocity command with a joint state whose positions are the
/// commanded velocities, woken by data events; runs until SIGTERM.
fn echo_peer() {
    let bus = Bus::open("echo").unwrap();
    let mut commands = Subscriber::<ArmVelocityCommand>::new(
        &bus,
        services::ARM_VELOCITY_COMMAND,
        &Qos::default().waking(),
    )
    .unwrap();
    let mut replies =
        Publisher::<JointState>::new(&bus, services::ARM_JOINT_STATE, &Qos::default().waking())
            .unwrap();
    let trigger = commands.trigger().unwrap();
    let config = LoopConfig {
        heartbeat_period: Duration::from_millis(10),
        ..LoopConfig::default()
    };
    let mut service = ServiceLoop::new(&bus, config).unwrap();
    let exit = service
        .run_on_data(&trigger, |_| {
            while let Some(command) = commands.receive().unwrap() {
                let mut reply = JointState::zeroed();
                reply.joint_count = command.joint_count;
                reply.position = command.velocity;
                replies.publish(reply).unwrap();
            }
            Flow::Continue
        })
        .unwrap();
    assert_eq!(exit, LoopExit::TerminationRequest);
}

/// Ticker peer: publishes odometry at 200 Hz on the interval timer; runs until SIGTERM.
fn ticker_peer() {
    let bus = Bus::open("ticker").unwrap();
    let mut odometry =
        Publisher::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &Qos::default()).unwrap();
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(200.0)).unwrap();
    let exit = service
        .run_periodic(|cycle| {
            let mut m = BaseOdometry::zeroed();
            m.x = cycle.cycle as f64 * 1e-3;
            odometry.publish(m).unwrap();
            Flow::Continue
        })
        .unwrap();
    assert_eq!(exit, LoopExit::TerminationRequest);
}

/// Pixel value of a test frame: depends on the pixel index and the frame's sequence number.
fn test_pixel(index: usize, seq: u64) -> u8 {
    ((index as u64 + seq * 7) % 251) as u8
}

/// Camera peer: publishes camera images written in place at 50 Hz; runs until SIGTERM.
fn camera_peer() {
    let bus = Bus::open("camera").unwrap();
    let mut images =
        Publisher::<CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large()).unwrap();
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(50.0)).unwrap();
    let exit = service
        .run_periodic(|_| {
            let seq = images.next_seq();
            // A frame is published at its exposure stamp or later.
            let now = motm_bus::monotonic_now_ns();
            images
                .publish_with(Stamp::At(now), |image| {
                    image.image_published_ns = now;
                    image.width = CAMERA_WIDTH as u32;
                    image.height = CAMERA_HEIGHT as u32;
                    for (i, p) in image.pixels.iter_mut().enumerate() {
                        *p = test_pixel(i, seq);
                    }
                })
                .unwrap();
            Flow::Continue
        })
        .unwrap();
    assert_eq!(exit, LoopExit::TerminationRequest);
}

/// A peer process, killed and reaped on drop if the test fails before stopping it.
struct Peer {
    child: Child,
}

impl Peer {
    /// Starts this binary as the peer `role` with the iceoryx2 prefix of `ipc`.
    fn spawn(role: &str, ipc: &IpcConfig) -> Self {
        let child = Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "peer_process_entry",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(ROLE_ENV, role)
            .env(PREFIX_ENV, &ipc.prefix)
            .spawn()
            .unwrap();
        Self { child }
    }

    /// Sends SIGTERM and waits for the exit.
    fn terminate(mut self) -> ExitStatus {
        // SAFETY: plain kill(2) on our own child, which has not been reaped yet.
        let rc = unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        assert_eq!(rc, 0);
        self.child.wait().unwrap()
    }

    /// Kills with SIGKILL (no cleanup at all) and reaps.
    fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A prefix no other test or process uses.
fn unique_ipc(test: &str) -> IpcConfig {
    IpcConfig {
        prefix: format!("motmt{}_{test}_", std::process::id()),
    }
}

/// Polls `condition` every millisecond until it holds; panics after [`TIMEOUT`].
fn wait_until(what: &str, mut condition: impl FnMut() -> bool) {
    let start = Instant::now();
    while !condition() {
        assert!(start.elapsed() < TIMEOUT, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Removes the prefix's node-counter segment (every process of the prefix has exited) and
/// asserts that nothing else with the test's prefix is left behind.
fn assert_no_leftovers(ipc: &IpcConfig) {
    // SAFETY: the test's bus is dropped and its peers are reaped.
    assert!(unsafe { remove_domain(ipc) }.unwrap());
    let left = shared_memory_entries(ipc).unwrap();
    assert!(left.is_empty(), "stale iceoryx2 resources: {left:?}");
}

#[test]
fn echo_peer_answers_every_sample_drops_bad_ones_and_exits_cleanly() {
    let ipc = unique_ipc("echo");
    {
        let bus = Bus::open_with("echo-client", &ipc).unwrap();
        let mut commands = Publisher::<ArmVelocityCommand>::new(
            &bus,
            services::ARM_VELOCITY_COMMAND,
            &Qos::default().waking(),
        )
        .unwrap();
        let mut replies = Subscriber::<JointState>::new(
            &bus,
            services::ARM_JOINT_STATE,
            &Qos::default().waking(),
        )
        .unwrap();
        let mut heartbeat =
            Latest::<Heartbeat>::new(&bus, &services::heartbeat("echo"), &Qos::default()).unwrap();
        let peer = Peer::spawn("echo", &ipc);
        wait_until("the echo peer's heartbeat", || {
            heartbeat.update().unwrap();
            heartbeat.get().is_some()
        });

        for i in 0..50u32 {
            let mut command = ArmVelocityCommand::zeroed();
            command.joint_count = 7;
            command.velocity[0] = f64::from(i) * 1e-3;
            command.velocity[6] = -f64::from(i) * 1e-3;
            commands.publish(command).unwrap();
            let mut reply = None;
            wait_until("an echo", || {
                reply = replies.receive().unwrap().map(|r| *r);
                reply.is_some()
            });
            let reply = reply.unwrap();
            assert_eq!(reply.position[0], f64::from(i) * 1e-3);
            assert_eq!(reply.position[6], -f64::from(i) * 1e-3);
            assert_eq!(reply.header.seq, u64::from(i));
        }
        assert_eq!(replies.accepted(), 50);
        assert_eq!(replies.rejected(), 0);

        // A command with a NaN is dropped by the peer and counted, never echoed. It is sent
        // once the echoes show the peer connected: sent as soon as the peer's heartbeat came,
        // it could go out before the peer's subscriber was connected, and be lost unseen.
        let mut bad = ArmVelocityCommand::zeroed();
        bad.joint_count = 7;
        bad.velocity[2] = f64::NAN;
        commands.publish(bad).unwrap();
        wait_until("a heartbeat reporting the dropped command", || {
            heartbeat.update().unwrap();
            let beat = heartbeat.get().unwrap();
            beat.rejected_messages == 1 && beat.cycles >= 50
        });
        assert!(
            replies.receive().unwrap().is_none(),
            "the bad command was echoed"
        );
        let beat = *heartbeat.get().unwrap();
        assert_eq!(beat.process_name(), "echo");
        assert_eq!(beat.pid, peer.child.id());
        assert_eq!(beat.state(), Some(ProcessState::Running));

        assert!(peer.terminate().success());
        heartbeat.update().unwrap();
        assert_eq!(
            heartbeat.get().unwrap().state(),
            Some(ProcessState::Stopping)
        );
    }
    assert_no_leftovers(&ipc);
}

#[test]
fn subscriber_receives_again_from_a_killed_and_restarted_publisher() {
    let ipc = unique_ipc("restart");
    {
        let bus = Bus::open_with("odometry-reader", &ipc).unwrap();
        let mut odometry =
            Latest::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &Qos::default()).unwrap();

        let first = Peer::spawn("ticker", &ipc);
        wait_until("odometry from the first ticker", || {
            odometry.update().unwrap();
            odometry.get().is_some_and(|m| m.header.seq >= 10)
        });
        let first_id = odometry.publisher_id().unwrap();
        first.kill();

        let report = cleanup_dead_nodes(&ipc).unwrap();
        assert_eq!(report.cleaned, 1, "{report:?}");
        assert_eq!(report.failed, 0);

        // The restarted publisher counts from 0 again; samples are accepted because the
        // sequence check is per publisher.
        let second = Peer::spawn("ticker", &ipc);
        wait_until("odometry from the restarted ticker", || {
            odometry.update().unwrap();
            odometry.publisher_id() != Some(first_id)
                && odometry.get().is_some_and(|m| m.header.seq >= 10)
        });
        assert_eq!(odometry.subscriber().rejected(), 0);
        assert!(second.terminate().success());
    }
    assert_no_leftovers(&ipc);
}

#[test]
fn camera_images_cross_processes_in_place_with_every_pixel() {
    let ipc = unique_ipc("camera");
    {
        let bus = Bus::open_with("image-reader", &ipc).unwrap();
        let mut images =
            Subscriber::<CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large()).unwrap();
        let peer = Peer::spawn("camera", &ipc);
        let mut checked = 0;
        wait_until("five camera images", || {
            while let Some(image) = images.receive().unwrap() {
                let seq = image.header.seq;
                assert_eq!(image.pixels.len(), CAMERA_IMAGE_BYTES);
                let wrong = image
                    .pixels
                    .iter()
                    .enumerate()
                    .position(|(i, &p)| p != test_pixel(i, seq));
                assert_eq!(wrong, None, "frame {seq}");
                checked += 1;
            }
            checked >= 5
        });
        assert_eq!(images.rejected(), 0);
        assert!(peer.terminate().success());
    }
    assert_no_leftovers(&ipc);
}
