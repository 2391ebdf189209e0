//! Behaviour of the simulated world: determinism, the robot's imperfections, the grasp model,
//! drops, collisions and buttons.

use std::path::{Path, PathBuf};

use motm_core::{BasePose, BaseVelocity, GripperCommand, Robot};
use motm_sim::objects::ObjectState;
use motm_sim::{FailureReason, HardwareCommand, Noise, Outcome, Scenario, World};
use nalgebra::{Isometry3, UnitQuaternion, Vector3, Vector6};

const DT: f64 = 0.001;

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

fn frankie() -> Robot {
    Robot::load(&config_dir(), "frankie").unwrap()
}

/// Frankie's tool at the ready pose with the base at the origin, (0.634, 0, 0.7926), turned
/// to point straight down (at the ready pose it is tilted by 0.1 rad).
fn ready_tool(robot: &Robot) -> Isometry3<f64> {
    let mut tool = robot.tool_pose(&BasePose::default(), &robot.config.ready_pose);
    let z = tool.rotation * Vector3::z();
    let straighten = UnitQuaternion::rotation_between(&z, &-Vector3::z()).unwrap();
    tool.rotation = straighten * tool.rotation;
    tool
}

/// A scenario from TOML text with the given noise table appended.
fn scenario(body: &str, noise: &str) -> Scenario {
    let text = format!(
        "name = \"test\"\nrobot = \"frankie\"\nstart_pose = [0.0, 0.0, 0.0]\nbase_speed = 0.3\n{body}\n[noise]\n{noise}\n"
    );
    Scenario::from_toml_str(Path::new("test.toml"), &text).unwrap()
}

const NO_NOISE: &str = "camera_pixel_std = 0.0\ncamera_extrinsic_error = 0.0\nodometry_drift = 0.0\nbase_velocity_error = 0.0\narm_velocity_error = 0.0\nlatency = 0.0";

/// One static cube under the ready-pose tool at table height, with a container 0.45 m to the left.
fn bench_scene(cube_offset: Vector3<f64>) -> Scenario {
    let cube = Vector3::new(0.634, 0.0, 0.45) + cube_offset;
    let body = format!(
        "[[objects]]\nposition = [{}, {}, {}]\nmotion = \"static\"\nplace = [0.634, 0.45, 0.3]\n",
        cube.x, cube.y, cube.z
    );
    let s = scenario(&body, NO_NOISE);
    assert_eq!(s.noise, Noise::none());
    s
}

fn command(
    robot: &Robot,
    arm_qd: Vec<f64>,
    base: BaseVelocity,
    gripper: GripperCommand,
) -> HardwareCommand {
    assert_eq!(arm_qd.len(), robot.arm_dof());
    HardwareCommand {
        arm_qd,
        base,
        gripper,
    }
}

/// Resolved-rate servo of the tool point toward `target` for `seconds`, holding the tool's
/// orientation at `orientation`, from the true state (a perfect controller).
fn servo(
    world: &mut World,
    robot: &Robot,
    target: Vector3<f64>,
    orientation: &Isometry3<f64>,
    gripper: GripperCommand,
    seconds: f64,
) {
    for _ in 0..(seconds / DT).round() as usize {
        let truth = world.truth();
        let fk = robot.forward(&truth.base_pose, &truth.arm_q);
        let linear = ((target - fk.tool_pose.translation.vector) * 5.0).cap_magnitude(0.3);
        let rotation_error = (orientation.rotation * fk.tool_pose.rotation.inverse()).scaled_axis();
        let twist = Vector6::new(
            linear.x,
            linear.y,
            linear.z,
            2.0 * rotation_error.x,
            2.0 * rotation_error.y,
            2.0 * rotation_error.z,
        );
        let jacobian = Robot::arm_jacobian(&fk.jacobian);
        let qd = jacobian.pseudo_inverse(1e-9).unwrap() * twist;
        let cmd = command(
            robot,
            qd.iter().copied().collect(),
            BaseVelocity::default(),
            gripper,
        );
        world.step(DT, &cmd);
    }
}

fn hold(world: &mut World, robot: &Robot, gripper: GripperCommand, seconds: f64) {
    let cmd = command(
        robot,
        vec![0.0; robot.arm_dof()],
        BaseVelocity::default(),
        gripper,
    );
    for _ in 0..(seconds / DT).round() as usize {
        world.step(DT, &cmd);
    }
}

/// Brings the tool down onto the cube (through `approach`, above it) and closes the gripper.
fn grasp(world: &mut World, robot: &Robot, approach: Vector3<f64>, at: Vector3<f64>) {
    let orientation = ready_tool(robot);
    servo(
        world,
        robot,
        approach,
        &orientation,
        GripperCommand::Open,
        2.0,
    );
    servo(world, robot, at, &orientation, GripperCommand::Open, 1.5);
    servo(world, robot, at, &orientation, GripperCommand::Close, 0.8);
}

#[test]
fn a_scripted_perfect_grasp_holds_the_cube_and_lifts_it() {
    let robot = frankie();
    let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
    let cube = world.truth().objects[0].position();
    grasp(&mut world, &robot, cube + Vector3::new(0.0, 0.0, 0.1), cube);
    let truth = world.truth();
    let approach = truth.tool_pose.rotation * Vector3::z();
    assert!(
        (approach + Vector3::z()).norm() < 1e-3,
        "not top-down: {approach}"
    );
    assert_eq!(truth.held_object, Some(0));
    assert_eq!(truth.objects[0].state, ObjectState::Held);
    assert!(
        (truth.gripper_opening - 0.03).abs() < 0.002,
        "opening {}",
        truth.gripper_opening
    );
    let lift = cube + Vector3::new(0.0, 0.0, 0.15);
    servo(
        &mut world,
        &robot,
        lift,
        &ready_tool(&robot),
        GripperCommand::Close,
        2.0,
    );
    let truth = world.truth();
    assert!((truth.objects[0].position() - lift).norm() < 0.01);
    assert!((truth.objects[0].position() - truth.tool_pose.translation.vector).norm() < 0.01);
    assert_eq!(world.outcome(), None);
}

#[test]
fn a_closure_three_centimetres_off_along_the_finger_width_misses() {
    let robot = frankie();
    let tool_x = ready_tool(&robot).rotation * Vector3::x();
    let mut world = World::new(&robot, &bench_scene(tool_x * 0.03), 1);
    let cube = world.truth().objects[0].position();
    let at = cube - tool_x * 0.03;
    grasp(&mut world, &robot, at + Vector3::new(0.0, 0.0, 0.1), at);
    assert_eq!(world.truth().held_object, None);
    assert_eq!(world.truth().objects[0].state, ObjectState::OnPlatform);
    assert_eq!(
        world.outcome(),
        Some(Outcome::Failure(FailureReason::MissedGrasp))
    );
    assert_eq!(world.outcome().unwrap().failure(), Some("missed_grasp"));
    let mishaps = world.mishaps();
    assert_eq!(mishaps.len(), 1);
    assert_eq!(mishaps[0].reason, FailureReason::MissedGrasp);
    assert_eq!(mishaps[0].object, Some(0));
}

#[test]
fn a_finger_landing_on_the_cube_knocks_it_off() {
    let robot = frankie();
    let tool_y = ready_tool(&robot).rotation * Vector3::y();
    let mut world = World::new(&robot, &bench_scene(tool_y * 0.03), 1);
    let cube = world.truth().objects[0].position();
    let at = cube - tool_y * 0.03;
    grasp(&mut world, &robot, at + Vector3::new(0.0, 0.0, 0.1), at);
    assert_eq!(world.truth().objects[0].state, ObjectState::KnockedOff);
    assert_eq!(world.outcome().unwrap().failure(), Some("knocked_off"));
    // A scenario of one object: the lost cube ends the trial.
    assert_eq!(world.decided(), world.outcome());
    // The record says which cube and how: an open finger came down on it.
    let mishaps = world.mishaps();
    assert_eq!(mishaps.len(), 1, "{mishaps:?}");
    assert_eq!(mishaps[0].reason, FailureReason::KnockedOff);
    assert_eq!(mishaps[0].object, Some(0));
    assert_eq!(mishaps[0].detail, "finger");
    assert!(mishaps[0].time > 0.0 && mishaps[0].time <= world.truth().time);
}

#[test]
fn a_lost_cube_leaves_a_longer_mission_going_until_it_ends() {
    let robot = frankie();
    let tool_y = ready_tool(&robot).rotation * Vector3::y();
    let offset = tool_y * 0.03;
    let cube = Vector3::new(0.634, 0.0, 0.45) + offset;
    let body = format!(
        "[[objects]]\nposition = [{}, {}, {}]\nmotion = \"static\"\nplace = [0.634, 0.45, 0.3]\n\
         [[objects]]\nposition = [2.0, -1.0, 0.45]\nmotion = \"static\"\nplace = [0.634, 0.45, 0.3]\n",
        cube.x, cube.y, cube.z
    );
    let mut world = World::new(&robot, &scenario(&body, NO_NOISE), 1);
    let at = world.truth().objects[0].position() - offset;
    grasp(&mut world, &robot, at + Vector3::new(0.0, 0.0, 0.1), at);
    assert_eq!(world.truth().objects[0].state, ObjectState::KnockedOff);
    let knocked_off = Some(Outcome::Failure(FailureReason::KnockedOff));
    assert_eq!(world.outcome(), knocked_off);
    // The second cube is still to be picked: the trial goes on ...
    assert_eq!(world.decided(), None);
    world.step(
        DT,
        &command(
            &robot,
            vec![0.0; 7],
            BaseVelocity::default(),
            GripperCommand::Open,
        ),
    );
    assert_eq!(world.decided(), None);
    // ... until the mission ends, with the first failure; both are on record, the give-up once
    // however often it is reported.
    world.mission_gave_up();
    world.mission_gave_up();
    assert_eq!(world.decided(), knocked_off);
    let reasons: Vec<_> = world.mishaps().iter().map(|m| m.reason).collect();
    assert_eq!(
        reasons,
        [FailureReason::KnockedOff, FailureReason::TaskFailed]
    );
    assert!(FailureReason::KnockedOff.object_lost());
    assert!(!FailureReason::BaseCollision.object_lost());
    assert!(!FailureReason::TaskFailed.object_lost());
}

#[test]
fn a_gripper_sweeping_sideways_into_the_cube_knocks_it_off() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    let tool_y = orientation.rotation * Vector3::y();
    let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
    let cube = world.truth().objects[0].position();
    let aside = cube + tool_y * 0.12;
    servo(
        &mut world,
        &robot,
        aside + Vector3::new(0.0, 0.0, 0.1),
        &orientation,
        GripperCommand::Open,
        2.0,
    );
    servo(
        &mut world,
        &robot,
        aside,
        &orientation,
        GripperCommand::Open,
        1.5,
    );
    assert_eq!(world.outcome(), None, "the cube was hit before the sweep");
    servo(
        &mut world,
        &robot,
        cube - tool_y * 0.12,
        &orientation,
        GripperCommand::Open,
        2.0,
    );
    assert_eq!(
        world.outcome(),
        Some(Outcome::Failure(FailureReason::KnockedOff))
    );
    // An open hand, no closure: a finger or the palm swept into it.
    let detail = world.mishaps()[0].detail;
    assert!(detail == "finger" || detail == "palm", "{detail}");
    let landed = world.truth().objects[0].position();
    assert!(
        (landed.xy() - cube.xy()).norm() > 0.2,
        "still on the platform at {landed}"
    );
}

#[test]
fn the_cube_must_stay_in_the_window_for_the_whole_closure() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    let tool_x = orientation.rotation * Vector3::x();
    let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
    let cube = world.truth().objects[0].position();
    servo(
        &mut world,
        &robot,
        cube + Vector3::new(0.0, 0.0, 0.1),
        &orientation,
        GripperCommand::Open,
        2.0,
    );
    servo(
        &mut world,
        &robot,
        cube,
        &orientation,
        GripperCommand::Open,
        1.5,
    );
    // Centred when the fingers start closing, but the tool slides 5 cm along the finger width
    // while they close: the cube leaves the pads before the fingers reach it.
    servo(
        &mut world,
        &robot,
        cube + tool_x * 0.05,
        &orientation,
        GripperCommand::Close,
        0.8,
    );
    assert_eq!(world.truth().held_object, None);
    assert!(matches!(world.outcome(), Some(Outcome::Failure(_))));
}

#[test]
fn a_drop_over_the_container_succeeds_and_outside_fails() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    for (over, expected) in [
        (Vector3::new(0.634, 0.45, 0.55), Outcome::Success),
        (
            Vector3::new(0.634, -0.45, 0.55),
            Outcome::Failure(FailureReason::DroppedOutside),
        ),
    ] {
        let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
        let cube = world.truth().objects[0].position();
        grasp(&mut world, &robot, cube + Vector3::new(0.0, 0.0, 0.1), cube);
        servo(
            &mut world,
            &robot,
            cube + Vector3::new(0.0, 0.0, 0.15),
            &orientation,
            GripperCommand::Close,
            1.5,
        );
        servo(
            &mut world,
            &robot,
            over,
            &orientation,
            GripperCommand::Close,
            3.0,
        );
        assert_eq!(world.outcome(), None);
        assert_eq!(world.truth().held_object, Some(0));
        hold(&mut world, &robot, GripperCommand::Open, 1.0);
        assert_eq!(world.outcome(), Some(expected));
        let object = &world.truth().objects[0];
        match expected {
            Outcome::Success => {
                assert_eq!(object.state, ObjectState::Placed);
                assert!(object.placed_time.is_some());
                assert!((object.position().xy() - over.xy()).norm() < 0.02);
            }
            _ => assert_eq!(object.state, ObjectState::DroppedOutside),
        }
    }
}

#[test]
fn a_moving_release_carries_the_cube_forward() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
    let cube = world.truth().objects[0].position();
    grasp(&mut world, &robot, cube + Vector3::new(0.0, 0.0, 0.1), cube);
    servo(
        &mut world,
        &robot,
        Vector3::new(0.634, 0.2, 0.6),
        &orientation,
        GripperCommand::Close,
        2.0,
    );
    // Release while moving toward +y at up to 0.3 m/s: the cube flies on past the release point.
    let mut release_y = 0.0;
    let target = Vector3::new(0.634, 0.6, 0.6);
    for _ in 0..2000 {
        let y = world.truth().tool_pose.translation.y;
        let gripper = if y > 0.35 {
            GripperCommand::Open
        } else {
            GripperCommand::Close
        };
        if world.truth().held_object.is_some() {
            release_y = y;
        }
        servo(&mut world, &robot, target, &orientation, gripper, DT);
    }
    let landed = world.truth().objects[0].position();
    assert!(
        landed.y > release_y + 0.02,
        "landed at {landed}, released at y = {release_y}"
    );
}

#[test]
fn the_base_driving_into_a_platform_is_a_collision() {
    let robot = frankie();
    let mut world = World::new(&robot, &bench_scene(Vector3::new(0.5, 0.0, 0.0)), 1);
    let forward = command(
        &robot,
        vec![0.0; 7],
        BaseVelocity { v: 0.3, omega: 0.0 },
        GripperCommand::Open,
    );
    for _ in 0..3000 {
        world.step(DT, &forward);
    }
    assert_eq!(
        world.outcome(),
        Some(Outcome::Failure(FailureReason::BaseCollision))
    );
}

#[test]
fn pushing_a_button_by_its_depth_presses_it() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    let body = "[[buttons]]\nposition = [0.634, 0.0, 0.5]\ndepth = 0.01\n";
    let mut world = World::new(&robot, &scenario(body, NO_NOISE), 1);
    servo(
        &mut world,
        &robot,
        Vector3::new(0.634, 0.0, 0.495),
        &orientation,
        GripperCommand::Close,
        3.0,
    );
    assert!(!world.truth().buttons[0].pressed);
    assert!((world.truth().buttons[0].travel - 0.005).abs() < 1e-3);
    assert_eq!(world.outcome(), None);
    servo(
        &mut world,
        &robot,
        Vector3::new(0.634, 0.0, 0.488),
        &orientation,
        GripperCommand::Close,
        1.0,
    );
    assert!(world.truth().buttons[0].pressed);
    assert_eq!(world.outcome(), Some(Outcome::Success));
}

#[test]
fn latency_lag_and_acceleration_limits_shape_the_base_response() {
    let robot = frankie();
    let body =
        "[[objects]]\nposition = [5.0, 3.0, 0.45]\nmotion = \"static\"\nplace = [6.0, 3.0, 0.35]\n";
    let noise =
        "base_velocity_error = 0.0\narm_velocity_error = 0.0\nodometry_drift = 0.0\nlatency = 0.02";
    let mut world = World::new(&robot, &scenario(body, noise), 1);
    let acceleration_limit = robot.limits()[1].acceleration;
    let go = command(
        &robot,
        vec![0.0; 7],
        BaseVelocity { v: 0.5, omega: 0.0 },
        GripperCommand::Open,
    );
    let mut previous = 0.0;
    let mut started = None;
    for k in 1..=3000 {
        world.step(DT, &go);
        let v = world.truth().base_velocity.v;
        if v > 0.0 && started.is_none() {
            started = Some(k);
        }
        assert!(
            v - previous <= acceleration_limit * DT + 1e-12,
            "acceleration limit broken at step {k}"
        );
        assert!(v >= previous, "velocity fell at step {k}");
        previous = v;
    }
    // The command takes effect 20 ms after it is given.
    assert_eq!(started, Some(21));
    assert!((previous - 0.5).abs() < 1e-6, "steady state {previous}");
    // No odometry error in this scenario: odometry equals the truth.
    assert_eq!(world.sensors().base_pose, world.truth().base_pose);
}

#[test]
fn arm_joints_follow_their_command_with_a_first_order_lag() {
    let robot = frankie();
    let body =
        "[[objects]]\nposition = [5.0, 3.0, 0.45]\nmotion = \"static\"\nplace = [6.0, 3.0, 0.35]\n";
    let noise = "arm_velocity_error = 0.0\nlatency = 0.01";
    let mut world = World::new(&robot, &scenario(body, noise), 1);
    let mut arm_qd = vec![0.0; 7];
    arm_qd[0] = 0.5;
    let turn = command(
        &robot,
        arm_qd,
        BaseVelocity::default(),
        GripperCommand::Open,
    );
    let tau = world.config().arm_time_constant;
    for _ in 0..10 {
        world.step(DT, &turn);
    }
    assert_eq!(world.truth().arm_qd[0], 0.0);
    for _ in 0..(tau / DT).round() as usize {
        world.step(DT, &turn);
    }
    // One time constant after the latency: 1 − e⁻¹ of the step.
    let expected = 0.5 * (1.0 - (-1.0f64).exp());
    assert!(
        (world.truth().arm_qd[0] - expected).abs() < 0.01,
        "qd {}",
        world.truth().arm_qd[0]
    );
    assert_eq!(world.sensors().arm_qd, world.truth().arm_qd);
}

#[test]
fn velocity_errors_and_odometry_drift_differ_by_seed() {
    let robot = frankie();
    let s = Scenario::from_file(&config_dir().join("scenarios/exp1-static.toml")).unwrap();
    let go = command(
        &robot,
        vec![0.0; 7],
        BaseVelocity { v: 0.3, omega: 0.0 },
        GripperCommand::Open,
    );
    let mut finals = Vec::new();
    for seed in [1, 2, 3] {
        let mut world = World::new(&robot, &s, seed);
        // About 1.1 m straight ahead: stops short of the platform.
        for _ in 0..4000 {
            world.step(DT, &go);
        }
        let truth = world.truth().base_pose;
        let odometry = world.sensors().base_pose;
        let distance = truth.x.hypot(truth.y);
        let error = (odometry.x - truth.x).hypot(odometry.y - truth.y);
        assert!(error > 0.0, "odometry equals the truth");
        assert!(
            error < 3.0 * s.noise.odometry_drift * distance + 0.01,
            "drift {error} over {distance} m"
        );
        let v = world.truth().base_velocity.v;
        assert!(v != 0.3 && (v - 0.3).abs() < 0.3 * (3.0 * s.noise.base_velocity_error + 0.02));
        finals.push((truth.x, odometry.x));
    }
    assert!(finals[0] != finals[1] && finals[1] != finals[2]);
}

/// Runs a scripted, command-rich trial on the dynamic scenario with the default noise.
fn scripted_run(seed: u64) -> World {
    let robot = frankie();
    let s = Scenario::from_file(&config_dir().join("scenarios/exp1-dynamic.toml")).unwrap();
    let mut world = World::new(&robot, &s, seed);
    let dt = 0.005;
    for k in 0..800 {
        let t = k as f64 * dt;
        let arm_qd = (0..7).map(|i| 0.2 * (t + i as f64).sin()).collect();
        let base = BaseVelocity {
            v: 0.2,
            omega: 0.3 * (0.5 * t).sin(),
        };
        let gripper = if t > 2.0 {
            GripperCommand::Close
        } else {
            GripperCommand::Open
        };
        world.step(dt, &command(&robot, arm_qd, base, gripper));
    }
    world
}

#[test]
fn the_same_scenario_and_seed_give_bit_identical_worlds() {
    let a = scripted_run(42);
    let b = scripted_run(42);
    assert_eq!(a.truth(), b.truth());
    assert_eq!(a.sensors(), b.sensors());
    assert_eq!(a.outcome(), b.outcome());
    let c = scripted_run(43);
    assert_ne!(a.truth().objects[0].pose, c.truth().objects[0].pose);
    assert_ne!(a.sensors().base_pose, c.sensors().base_pose);
    // The moving cube really moved.
    let start = Vector3::new(2.0, 0.0, 0.45);
    assert!((a.truth().objects[0].position() - start).norm() > 0.05);
}

#[test]
fn malformed_commands_are_dropped_and_counted() {
    let robot = frankie();
    let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
    let mut arm_qd = vec![0.0; 7];
    arm_qd[3] = f64::NAN;
    world.step(
        DT,
        &command(
            &robot,
            arm_qd,
            BaseVelocity::default(),
            GripperCommand::Open,
        ),
    );
    let short = HardwareCommand {
        arm_qd: vec![0.1; 3],
        base: BaseVelocity {
            v: f64::INFINITY,
            omega: 0.0,
        },
        gripper: GripperCommand::Open,
    };
    world.step(DT, &short);
    assert_eq!(world.rejected_commands(), 2);
    assert!(world.truth().arm_q.iter().all(|q| q.is_finite()));
    assert_eq!(world.truth().arm_q, robot.config.ready_pose);
}

#[test]
fn the_squeeze_aligns_a_turned_cube_up_to_the_yaw_tolerance() {
    let robot = frankie();
    for (turn, held) in [(0.4, true), (0.75, false)] {
        let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
        let cube = world.truth().objects[0].position();
        let mut orientation = ready_tool(&robot);
        orientation.rotation =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), turn) * orientation.rotation;
        servo(
            &mut world,
            &robot,
            cube + Vector3::new(0.0, 0.0, 0.1),
            &orientation,
            GripperCommand::Open,
            2.0,
        );
        servo(
            &mut world,
            &robot,
            cube,
            &orientation,
            GripperCommand::Open,
            1.5,
        );
        servo(
            &mut world,
            &robot,
            cube,
            &orientation,
            GripperCommand::Close,
            0.8,
        );
        assert_eq!(
            world.truth().held_object.is_some(),
            held,
            "turned by {turn} rad"
        );
        if held {
            // Held square to the fingers: the cube turned with the squeeze.
            let in_tool =
                world.truth().tool_pose.rotation.inverse() * world.truth().objects[0].pose.rotation;
            let x = in_tool * Vector3::x();
            assert!(x.x.abs() < 1e-6 || x.y.abs() < 1e-6, "not square: {x}");
        } else {
            // Outside the window, the closing fingers meet the cube's edges and flick it away.
            assert_eq!(
                world.outcome(),
                Some(Outcome::Failure(FailureReason::KnockedOff))
            );
            assert_eq!(
                world.mishaps()[0].detail,
                "finger, closing, cube out of the grasp window: yaw"
            );
        }
    }
}

#[test]
fn closing_a_centimetre_high_while_descending_grasps_but_closing_above_the_cube_misses() {
    let robot = frankie();
    let orientation = ready_tool(&robot);
    for (height, held) in [(0.01, true), (0.025, false)] {
        let mut world = World::new(&robot, &bench_scene(Vector3::zeros()), 1);
        let cube = world.truth().objects[0].position();
        let start = cube + Vector3::new(0.0, 0.0, height);
        servo(
            &mut world,
            &robot,
            start + Vector3::new(0.0, 0.0, 0.1),
            &orientation,
            GripperCommand::Open,
            2.0,
        );
        servo(
            &mut world,
            &robot,
            start,
            &orientation,
            GripperCommand::Open,
            1.5,
        );
        let target = if held { cube } else { start };
        servo(
            &mut world,
            &robot,
            target,
            &orientation,
            GripperCommand::Close,
            0.8,
        );
        assert_eq!(
            world.truth().held_object.is_some(),
            held,
            "closed {height} m above"
        );
        if !held {
            assert_eq!(
                world.outcome(),
                Some(Outcome::Failure(FailureReason::MissedGrasp))
            );
        }
    }
}

#[test]
fn every_shipped_frankie_scenario_starts_clear_and_stays_running_at_rest() {
    let robot = frankie();
    let dir = config_dir().join("scenarios");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let s = Scenario::from_file(&path).unwrap();
        if s.robot != "frankie" {
            continue;
        }
        let mut world = World::new(&robot, &s, 3);
        hold(&mut world, &robot, GripperCommand::Open, 5.0);
        assert_eq!(world.outcome(), None, "{}", path.display());
        for object in &world.truth().objects {
            assert_eq!(object.state, ObjectState::OnPlatform, "{}", path.display());
        }
        checked += 1;
    }
    assert!(checked >= 5, "only {checked} frankie scenarios");
}
