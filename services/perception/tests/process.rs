//! The real `perception` process over iceoryx2: this test publishes a pick mission, the robot's
//! state and a palm-camera image rendered with the cube in view, and checks the estimate the
//! process publishes; then that a malformed image is dropped and counted, that nothing is
//! published for a place, and that the process exits cleanly leaving no shared memory behind.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, IpcConfig, Latest, OwnedProcess, PREFIX_ENV, Publisher, Qos, Stamp, Subscriber,
    monotonic_now_ns, remove_domain, shared_memory_entries,
};
use motm_core::Robot;
use motm_core::camera::CameraConfig;
use motm_core::kinematics::BasePose;
use motm_msgs::{
    BaseOdometry, CAMERA_HEIGHT, CAMERA_WIDTH, CameraImage, Heartbeat, JointState, Message,
    MissionState, TargetEstimate, TaskKindCode, TaskPhase, services,
};
use motm_sim::render::{Renderer, Scene, SceneBox};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Longest wait for anything (generous: the machine is shared and noisy).
const TIMEOUT: Duration = Duration::from_secs(30);

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// Starts the service on `ipc`'s prefix (killed and reaped on drop if the test fails early).
fn spawn_service(ipc: &IpcConfig) -> OwnedProcess {
    OwnedProcess::spawn(
        Command::new(env!("CARGO_BIN_EXE_perception"))
            .arg("--config-dir")
            .arg(config_dir())
            .env(PREFIX_ENV, &ipc.prefix),
    )
    .expect("perception starts")
}

fn mission(kind: TaskKindCode, task_index: u32, target: Vector3<f64>) -> MissionState {
    let mut m = MissionState::zeroed();
    m.task_index = task_index;
    m.task_count = 2;
    m.task_kind = kind.into();
    m.phase = TaskPhase::Reach.into();
    m.current_target = target.into();
    m.next_target = [4.0, 0.0, 0.35];
    m.has_next = 1;
    m
}

#[test]
fn perception_process_estimates_the_cube_in_view_and_drops_malformed_images() {
    let robot = Robot::load(&config_dir(), "frankie").unwrap();
    let q = robot.config.ready_pose.clone();
    let base = BasePose::default();
    let tool = robot.tool_pose(&base, &q);
    // The cube 12 cm below the tool and a little off its axis, on a 0.45 m high surface.
    let tool_position = tool.translation.vector;
    let cube = Vector3::new(tool_position.x + 0.03, tool_position.y - 0.02, 0.45);
    let camera = CameraConfig::default();
    let renderer = Renderer::new(camera.model(), 0.0);
    let mut scene = Scene::default();
    scene.boxes.push(SceneBox::cube(cube, 0.0, 0.05));
    let image = renderer.render(
        &scene,
        &(tool * camera.tool_from_camera.isometry()),
        &mut ChaCha8Rng::seed_from_u64(1),
    );

    let ipc = IpcConfig {
        prefix: format!("motmt{}_perception_", std::process::id()),
    };
    {
        let bus = Bus::open_with("perception-test", &ipc).unwrap();
        let qos = Qos::default();
        let mut mission_out =
            Publisher::<MissionState>::new(&bus, services::MISSION_STATE, &qos).unwrap();
        let mut joints_out =
            Publisher::<JointState>::new(&bus, services::ARM_JOINT_STATE, &qos).unwrap();
        let mut odometry_out =
            Publisher::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos).unwrap();
        let mut images_out =
            Publisher::<CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large().waking())
                .unwrap();
        let mut estimates =
            Subscriber::<TargetEstimate>::new(&bus, services::PERCEPTION_TARGET, &qos).unwrap();
        let mut heartbeat =
            Latest::<Heartbeat>::new(&bus, &services::heartbeat("perception"), &qos).unwrap();
        let service = spawn_service(&ipc);

        // The mission's position is 10 cm off: perception must find the cube itself.
        let hint = cube + Vector3::new(0.1, 0.0, 0.0);
        let mut publish_state = |kind: TaskKindCode, task_index: u32| {
            mission_out
                .publish(mission(kind, task_index, hint))
                .unwrap();
            let mut joints = JointState::zeroed();
            joints.joint_count = 7;
            joints.position[..7].copy_from_slice(&q);
            joints_out.publish(joints).unwrap();
            odometry_out.publish(BaseOdometry::zeroed()).unwrap();
        };
        let mut publish_image = |width: u32| {
            // Captured and published just now, after the joint state it is paired with.
            let now = monotonic_now_ns();
            images_out
                .publish_with(Stamp::At(now), |frame| {
                    frame.image_published_ns = now;
                    frame.width = width;
                    frame.height = CAMERA_HEIGHT as u32;
                    frame.pixels.copy_from_slice(&image);
                })
                .unwrap();
        };

        let start = Instant::now();
        let estimate = loop {
            assert!(start.elapsed() < TIMEOUT, "no estimate from perception");
            publish_state(TaskKindCode::Pick, 0);
            std::thread::sleep(Duration::from_millis(10));
            publish_image(CAMERA_WIDTH as u32);
            std::thread::sleep(Duration::from_millis(20));
            if let Some(estimate) = estimates.latest().unwrap() {
                break *estimate;
            }
        };
        let found = Vector3::from(estimate.position);
        assert!(
            (found - cube).norm() < 0.01,
            "estimate {found} for a cube at {cube}"
        );
        assert_eq!(estimate.visible, 1);
        assert!(estimate.image_stamp_ns > 0 && estimate.image_stamp_ns <= estimate.header.stamp_ns);
        // The estimate names the frame it was computed from, published with its exposure.
        assert_eq!(estimate.image_published_ns, estimate.image_stamp_ns);

        // A malformed image (wrong width) is dropped and counted, never processed.
        publish_image(CAMERA_WIDTH as u32 + 1);
        let start = Instant::now();
        loop {
            assert!(start.elapsed() < TIMEOUT, "rejection not reported");
            publish_state(TaskKindCode::Pick, 0);
            std::thread::sleep(Duration::from_millis(20));
            heartbeat.update().unwrap();
            if heartbeat.get().is_some_and(|h| h.rejected_messages >= 1) {
                break;
            }
        }

        // A place: the cube may be in view, but nothing is published for it.
        while estimates.receive().unwrap().is_some() {}
        for _ in 0..20 {
            publish_state(TaskKindCode::Place, 1);
            std::thread::sleep(Duration::from_millis(5));
            publish_image(CAMERA_WIDTH as u32);
            std::thread::sleep(Duration::from_millis(10));
        }
        // The mission is published before each image, so perception knows of the place
        // before it sees any image of it.
        let during_place: Vec<TargetEstimate> =
            std::iter::from_fn(|| estimates.receive().unwrap().map(|e| *e)).collect();
        assert!(
            during_place.is_empty(),
            "estimates during a place: {during_place:?}"
        );

        let status = service.terminate().unwrap();
        assert!(status.success(), "perception exited with {status}");
    }
    // SAFETY: the test's bus is dropped and the service is reaped.
    unsafe { remove_domain(&ipc) }.unwrap();
    let left = shared_memory_entries(&ipc).unwrap();
    assert!(left.is_empty(), "stale iceoryx2 resources: {left:?}");
}
