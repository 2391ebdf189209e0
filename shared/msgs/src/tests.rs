//! Unit tests: every message accepts a valid instance and rejects each kind of bad field,
//! naming that field.

use super::*;

/// Receiver clock used by the tests, ns.
const NOW: u64 = 1_000_000_000;

/// Validates `m` as the first sample from its publisher at time [`NOW`].
fn check<M: Message>(m: &M) -> Result<(), Rejection> {
    m.validate(NOW, None)
}

/// Asserts that `m` is rejected at `field` (and `index`) for a reason matching `reason`.
fn assert_rejected<M: Message>(
    m: &M,
    field: &str,
    index: Option<usize>,
    reason: impl Fn(&RejectReason) -> bool,
) {
    let r = check(m).expect_err("message should be rejected");
    assert_eq!(r.message, M::NAME);
    assert_eq!((r.field, r.index), (field, index), "{r}");
    assert!(reason(&r.reason), "unexpected reason: {r}");
}

fn not_finite(r: &RejectReason) -> bool {
    matches!(r, RejectReason::NotFinite)
}

fn out_of_range(r: &RejectReason) -> bool {
    matches!(r, RejectReason::OutOfRange { .. })
}

fn unknown_code(r: &RejectReason) -> bool {
    matches!(r, RejectReason::UnknownCode(_))
}

fn inconsistent(r: &RejectReason) -> bool {
    matches!(r, RejectReason::Inconsistent(_))
}

fn header() -> Header {
    Header::new(NOW - 1_000, 5)
}

fn joint_state() -> JointState {
    JointState {
        header: header(),
        joint_count: 7,
        reserved: 0,
        position: [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785, 0.0],
        velocity: [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.0],
    }
}

#[test]
fn header_rejects_wrong_schema_version() {
    let mut m = joint_state();
    m.header.schema_version = SCHEMA_VERSION + 1;
    assert_rejected(&m, "header.schema_version", None, |r| {
        *r == RejectReason::WrongSchemaVersion {
            found: SCHEMA_VERSION + 1,
            expected: SCHEMA_VERSION,
        }
    });
}

#[test]
fn header_rejects_a_timestamp_in_the_future_but_accepts_now() {
    let mut m = joint_state();
    m.header.stamp_ns = NOW + 1;
    assert_rejected(
        &m,
        "header.stamp_ns",
        None,
        |r| matches!(r, RejectReason::FutureTimestamp { stamp_ns, now_ns } if *stamp_ns == NOW + 1 && *now_ns == NOW),
    );
    m.header.stamp_ns = NOW;
    assert_eq!(check(&m), Ok(()));
}

#[test]
fn header_rejects_a_sequence_number_that_does_not_move_forward() {
    let m = joint_state();
    assert_eq!(m.validate(NOW, Some(4)), Ok(()));
    for last in [5, 6, u64::MAX] {
        let r = m.validate(NOW, Some(last)).unwrap_err();
        assert_eq!(r.field, "header.seq");
        assert_eq!(
            r.reason,
            RejectReason::SequenceNotIncreasing {
                seq: 5,
                last_seq: last
            }
        );
    }
}

#[test]
fn joint_state_accepts_a_valid_sample_and_a_six_joint_arm() {
    assert_eq!(check(&joint_state()), Ok(()));
    let mut m = joint_state();
    m.joint_count = 6;
    m.position[6] = 0.0;
    m.velocity[6] = 0.0;
    assert_eq!(check(&m), Ok(()));
}

#[test]
fn joint_state_rejects_bad_fields() {
    let mut m = joint_state();
    m.position[3] = f64::NAN;
    assert_rejected(&m, "position", Some(3), not_finite);

    let mut m = joint_state();
    m.velocity[6] = f64::INFINITY;
    assert_rejected(&m, "velocity", Some(6), not_finite);

    let mut m = joint_state();
    m.velocity[1] = -(envelope::JOINT_VELOCITY + 0.1);
    assert_rejected(&m, "velocity", Some(1), out_of_range);

    for count in [0, MAX_ARM_JOINTS as u32 + 1] {
        let mut m = joint_state();
        m.joint_count = count;
        assert_rejected(&m, "joint_count", None, out_of_range);
    }

    let mut m = joint_state();
    m.joint_count = 6;
    m.velocity[6] = 0.0;
    assert_rejected(&m, "position", Some(6), inconsistent);

    let mut m = joint_state();
    m.reserved = 1;
    assert_rejected(&m, "reserved", None, inconsistent);
}

#[test]
fn gripper_state_rejects_bad_fields() {
    let ok = GripperState {
        header: header(),
        width: 0.04,
        grasping: 1,
        reserved: 0,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &GripperState { width: -0.01, ..ok },
        "width",
        None,
        out_of_range,
    );
    assert_rejected(
        &GripperState {
            width: f64::NAN,
            ..ok
        },
        "width",
        None,
        not_finite,
    );
    assert_rejected(
        &GripperState { grasping: 2, ..ok },
        "grasping",
        None,
        unknown_code,
    );
}

#[test]
fn base_odometry_rejects_bad_fields() {
    let ok = BaseOdometry {
        header: header(),
        x: 1.0,
        y: -2.0,
        yaw: 3.0,
        v: 0.3,
        omega: -0.2,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(&BaseOdometry { yaw: 3.2, ..ok }, "yaw", None, out_of_range);
    assert_rejected(&BaseOdometry { x: 1e4, ..ok }, "x", None, out_of_range);
    assert_rejected(
        &BaseOdometry {
            y: f64::NEG_INFINITY,
            ..ok
        },
        "y",
        None,
        not_finite,
    );
    assert_rejected(&BaseOdometry { v: f64::NAN, ..ok }, "v", None, not_finite);
    assert_rejected(
        &BaseOdometry { omega: 11.0, ..ok },
        "omega",
        None,
        out_of_range,
    );
}

#[test]
fn base_velocity_command_rejects_bad_fields() {
    let ok = BaseVelocityCommand {
        header: header(),
        v: 0.3,
        omega: 0.1,
        resolver_id: 1,
        reserved: 0,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &BaseVelocityCommand { v: 4.0, ..ok },
        "v",
        None,
        out_of_range,
    );
    assert_rejected(
        &BaseVelocityCommand {
            omega: f64::INFINITY,
            ..ok
        },
        "omega",
        None,
        not_finite,
    );
    assert_rejected(
        &BaseVelocityCommand { reserved: 1, ..ok },
        "reserved",
        None,
        inconsistent,
    );
}

#[test]
fn arm_velocity_command_rejects_bad_fields() {
    let ok = ArmVelocityCommand {
        header: header(),
        joint_count: 6,
        resolver_id: 2,
        velocity: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.0, 0.0],
    };
    assert_eq!(check(&ok), Ok(()));
    let mut m = ok;
    m.velocity[6] = 0.1;
    assert_rejected(&m, "velocity", Some(6), inconsistent);
    let mut m = ok;
    m.velocity[2] = f64::NAN;
    assert_rejected(&m, "velocity", Some(2), not_finite);
    let mut m = ok;
    m.velocity[0] = 20.0;
    assert_rejected(&m, "velocity", Some(0), out_of_range);
    assert_rejected(
        &ArmVelocityCommand {
            joint_count: 9,
            ..ok
        },
        "joint_count",
        None,
        out_of_range,
    );
}

#[test]
fn gripper_command_rejects_an_unknown_action() {
    let ok = GripperCommand {
        header: header(),
        controller_id: 3,
        action: GripperAction::Close.into(),
    };
    assert_eq!(check(&ok), Ok(()));
    assert_eq!(ok.action(), Some(GripperAction::Close));
    for bad in [0, 3, u32::MAX] {
        assert_rejected(&GripperCommand { action: bad, ..ok }, "action", None, |r| {
            *r == RejectReason::UnknownCode(bad)
        });
    }
}

#[test]
fn twist_command_rejects_bad_fields() {
    let ok = TwistCommand {
        header: header(),
        controller_id: 1,
        phase: TaskPhase::Reach.into(),
        twist: [0.1, 0.0, -0.1, 0.0, 0.5, 0.0],
        task_index: 0,
        progress: TaskProgressCode::Done.into(),
    };
    assert_eq!(check(&ok), Ok(()));
    assert_eq!(ok.phase(), Some(TaskPhase::Reach));
    let mut m = ok;
    m.twist[4] = f64::NAN;
    assert_rejected(&m, "twist", Some(4), not_finite);
    // 5 m/s is beyond the linear envelope but within the angular one.
    let mut m = ok;
    m.twist[0] = 5.0;
    assert_rejected(&m, "twist", Some(0), out_of_range);
    let mut m = ok;
    m.twist[3] = 5.0;
    assert_eq!(check(&m), Ok(()));
    assert_rejected(
        &TwistCommand { phase: 7, ..ok },
        "phase",
        None,
        unknown_code,
    );
    assert_eq!(ok.progress(), Some(TaskProgressCode::Done));
    assert_rejected(
        &TwistCommand { progress: 2, ..ok },
        "progress",
        None,
        unknown_code,
    );
}

#[test]
fn target_estimate_rejects_bad_fields() {
    let ok = TargetEstimate {
        header: header(),
        image_stamp_ns: NOW - 20_000_000,
        image_published_ns: NOW - 19_000_000,
        position: [2.0, 0.0, 0.45],
        velocity: [0.03, 0.0, 0.0],
        visible: 1,
        task_index: 0,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &TargetEstimate {
            image_stamp_ns: ok.header.stamp_ns + 1,
            ..ok
        },
        "image_stamp_ns",
        None,
        inconsistent,
    );
    for published in [ok.header.stamp_ns + 1, ok.image_stamp_ns - 1] {
        assert_rejected(
            &TargetEstimate {
                image_published_ns: published,
                ..ok
            },
            "image_published_ns",
            None,
            inconsistent,
        );
    }
    assert_eq!(
        check(&TargetEstimate {
            image_published_ns: 0,
            ..ok
        }),
        Ok(())
    );
    let mut m = ok;
    m.position[2] = f64::INFINITY;
    assert_rejected(&m, "position", Some(2), not_finite);
    let mut m = ok;
    m.velocity[1] = -6.0;
    assert_rejected(&m, "velocity", Some(1), out_of_range);
    assert_rejected(
        &TargetEstimate { visible: 5, ..ok },
        "visible",
        None,
        unknown_code,
    );
}

#[test]
fn base_plan_rejects_bad_fields() {
    let ok = BasePlan {
        header: header(),
        closest_approach: [2.0, -0.5, 0.1],
        time_to_range: 1.5,
        range_entry_pose: [1.2, -0.4, 0.05],
        task_index: 0,
        passed: 0,
        missed_passes: 0,
        gave_up: 0,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &BasePlan {
            time_to_range: -0.1,
            ..ok
        },
        "time_to_range",
        None,
        out_of_range,
    );
    let mut m = ok;
    m.closest_approach[2] = 4.0;
    assert_rejected(&m, "closest_approach", Some(2), out_of_range);
    let mut m = ok;
    m.closest_approach[1] = f64::NAN;
    assert_rejected(&m, "closest_approach", Some(1), not_finite);
    let mut m = ok;
    m.range_entry_pose[0] = f64::INFINITY;
    assert_rejected(&m, "range_entry_pose", Some(0), not_finite);
    let mut m = ok;
    m.range_entry_pose[2] = -4.0;
    assert_rejected(&m, "range_entry_pose", Some(2), out_of_range);
    assert_rejected(&BasePlan { passed: 2, ..ok }, "passed", None, unknown_code);
    assert_rejected(
        &BasePlan { gave_up: 2, ..ok },
        "gave_up",
        None,
        unknown_code,
    );
}

#[test]
fn camera_image_rejects_a_wrong_size() {
    let mut m = CameraImage::zeroed();
    m.header = header();
    m.width = CAMERA_WIDTH as u32;
    m.height = CAMERA_HEIGHT as u32;
    m.image_published_ns = m.header.stamp_ns;
    assert_eq!(check(&m), Ok(()));
    assert_eq!(
        core::mem::size_of::<CameraImage>(),
        24 + 8 + 8 + CAMERA_IMAGE_BYTES
    );
    m.image_published_ns = m.header.stamp_ns - 1;
    assert_rejected(&m, "image_published_ns", None, inconsistent);
    m.image_published_ns = m.header.stamp_ns;
    m.width = 160;
    assert_rejected(&m, "width", None, out_of_range);
    m.width = CAMERA_WIDTH as u32;
    m.height = 0;
    assert_rejected(&m, "height", None, out_of_range);
}

fn heartbeat() -> Heartbeat {
    let mut m = Heartbeat::zeroed();
    m.header = header();
    m.pid = 42;
    m.state = ProcessState::Running.into();
    m.cycles = 100;
    m.deadline_misses = 2;
    m.set_process_name("qp-resolver");
    m
}

#[test]
fn heartbeat_rejects_bad_fields() {
    let ok = heartbeat();
    assert_eq!(check(&ok), Ok(()));
    assert_eq!(ok.process_name(), "qp-resolver");
    assert_eq!(ok.state(), Some(ProcessState::Running));
    assert_rejected(&Heartbeat { state: 3, ..ok }, "state", None, unknown_code);
    assert_rejected(
        &Heartbeat {
            deadline_misses: 101,
            ..ok
        },
        "deadline_misses",
        None,
        inconsistent,
    );
    let mut m = ok;
    m.set_process_name("");
    assert_rejected(&m, "process_name", None, inconsistent);
    let mut m = ok;
    m.process_name[0] = 0xff;
    assert_rejected(&m, "process_name", None, inconsistent);
    let mut m = ok;
    m.process_name[31] = b'x';
    assert_rejected(&m, "process_name", None, inconsistent);
}

#[test]
fn heartbeat_name_is_truncated_at_a_character_boundary() {
    let mut m = heartbeat();
    let long = "é".repeat(20); // 40 bytes
    m.set_process_name(&long);
    assert_eq!(m.process_name(), "é".repeat(16));
    assert_eq!(check(&m), Ok(()));
}

#[test]
fn mission_state_rejects_bad_fields() {
    let ok = MissionState {
        header: header(),
        task_index: 1,
        task_count: 2,
        task_kind: TaskKindCode::Place.into(),
        phase: TaskPhase::Final.into(),
        current_target: [4.0, 0.0, 0.35],
        next_target: [0.0; 3],
        has_next: 0,
        failed_tasks: 0,
        odometry_offset: [0.1, -0.2, 0.05],
        odometry_calibrated: 1,
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &MissionState {
            odometry_calibrated: 2,
            ..ok
        },
        "odometry_calibrated",
        None,
        unknown_code,
    );
    let mut m = ok;
    m.odometry_offset[2] = 4.0;
    assert_rejected(&m, "odometry_offset", Some(2), out_of_range);
    let mut m = ok;
    m.odometry_offset[0] = f64::INFINITY;
    assert_rejected(&m, "odometry_offset", Some(0), not_finite);
    assert_rejected(
        &MissionState {
            task_index: 3,
            ..ok
        },
        "task_index",
        None,
        out_of_range,
    );
    assert_rejected(
        &MissionState { task_kind: 9, ..ok },
        "task_kind",
        None,
        unknown_code,
    );
    assert_rejected(
        &MissionState { phase: 3, ..ok },
        "phase",
        None,
        unknown_code,
    );
    assert_rejected(
        &MissionState { has_next: 2, ..ok },
        "has_next",
        None,
        unknown_code,
    );
    assert_rejected(
        &MissionState {
            failed_tasks: 3,
            ..ok
        },
        "failed_tasks",
        None,
        out_of_range,
    );
    let mut m = ok;
    m.next_target[0] = f64::NAN;
    assert_rejected(&m, "next_target", Some(0), not_finite);
    let mut m = ok;
    m.current_target[1] = 2000.0;
    assert_rejected(&m, "current_target", Some(1), out_of_range);
}

#[test]
fn safe_stop_reason_must_match_the_active_flag() {
    let raised = SafeStop {
        header: header(),
        active: 1,
        reason: SafeStopReason::DeadlineMiss.into(),
        fault_raises: 1,
    };
    let cleared = SafeStop {
        header: header(),
        active: 0,
        reason: SafeStopReason::None.into(),
        fault_raises: 1,
    };
    assert_eq!(check(&raised), Ok(()));
    assert_eq!(check(&cleared), Ok(()));
    assert_rejected(
        &SafeStop {
            reason: 0,
            ..raised
        },
        "reason",
        None,
        inconsistent,
    );
    assert_rejected(
        &SafeStop {
            reason: 2,
            ..cleared
        },
        "reason",
        None,
        inconsistent,
    );
    assert_rejected(
        &SafeStop {
            reason: 17,
            ..raised
        },
        "reason",
        None,
        unknown_code,
    );
    assert_rejected(
        &SafeStop {
            active: 7,
            ..raised
        },
        "active",
        None,
        unknown_code,
    );
}

#[test]
fn qp_status_rejects_bad_fields() {
    let ok = QpStatus {
        header: header(),
        outcome: QpOutcome::Solved.into(),
        iterations: 12,
        solve_time_ns: 80_000,
        objective: -3.5,
        slack_norm: 0.01,
        image_stamp_ns: NOW - 40_000_000,
        image_published_ns: NOW - 39_000_000,
        twist: [0.1, 0.0, 0.0, 0.0, 0.0, 0.2],
        published_ns: 0,
    };
    assert_eq!(check(&ok), Ok(()));
    // Sent at or after its own stamp, or not filled in.
    let sent = QpStatus {
        published_ns: ok.header.stamp_ns,
        ..ok
    };
    assert_eq!(check(&sent), Ok(()));
    assert_rejected(
        &QpStatus {
            published_ns: ok.header.stamp_ns - 1,
            ..ok
        },
        "published_ns",
        None,
        inconsistent,
    );
    let mut fast = ok;
    fast.twist[4] = f64::INFINITY;
    assert_rejected(&fast, "twist", Some(4), not_finite);
    assert_rejected(
        &QpStatus { outcome: 3, ..ok },
        "outcome",
        None,
        unknown_code,
    );
    assert_rejected(
        &QpStatus {
            objective: f64::NAN,
            ..ok
        },
        "objective",
        None,
        not_finite,
    );
    assert_rejected(
        &QpStatus {
            slack_norm: -1e-9,
            ..ok
        },
        "slack_norm",
        None,
        out_of_range,
    );
    assert_rejected(
        &QpStatus {
            image_stamp_ns: ok.header.stamp_ns + 1,
            ..ok
        },
        "image_stamp_ns",
        None,
        inconsistent,
    );
    for published in [ok.header.stamp_ns + 1, ok.image_stamp_ns - 1] {
        assert_rejected(
            &QpStatus {
                image_published_ns: published,
                ..ok
            },
            "image_published_ns",
            None,
            inconsistent,
        );
    }
}

#[test]
fn active_controller_rejects_an_unknown_variant() {
    let ok = ActiveController {
        header: header(),
        controller_id: 2,
        variant: ControllerVariant::Grasp.into(),
    };
    assert_eq!(check(&ok), Ok(()));
    assert_rejected(
        &ActiveController { variant: 4, ..ok },
        "variant",
        None,
        unknown_code,
    );
}

#[test]
fn rejection_message_names_the_message_field_and_value() {
    let mut m = joint_state();
    m.velocity[2] = 12.5;
    let text = check(&m).unwrap_err().to_string();
    assert_eq!(
        text,
        "JointState.velocity[2] rejected: 12.5 is outside [-10, 10]"
    );
}

#[test]
fn zeroed_messages_carry_the_current_schema_version() {
    let m = BaseOdometry::zeroed();
    assert_eq!(m.header, Header::new(0, 0));
    assert_eq!(m.validate(0, None), Ok(()));
}

fn sim_truth() -> SimTruth {
    let mut m = SimTruth::zeroed();
    m.header = header();
    m.sim_time = 12.5;
    m.task_time = 12.5;
    m.outcome = SimOutcome::Running.into();
    m.object_count = 2;
    m.tool_position = [0.6, 0.0, 0.8];
    m.base_pose = [1.0, 0.2, 0.1];
    m.object_positions[..6].copy_from_slice(&[2.0, 0.0, 0.45, 3.0, 1.0, 0.45]);
    m.object_placed_time = [-1.0; MAX_SIM_OBJECTS];
    m.object_placed_time[0] = 10.0;
    m.object_placed_time[2..].iter_mut().for_each(|t| *t = 0.0);
    m.held_object = 1;
    m.gripper_opening = 0.05;
    m.ee_acc_mean = 0.3;
    m.ee_acc_max = 2.0;
    m
}

#[test]
fn sim_truth_accepts_a_valid_instance_and_rejects_each_bad_field() {
    let good = sim_truth();
    assert_eq!(check(&good), Ok(()));
    assert_eq!(good.outcome(), Some(SimOutcome::Running));
    let mut m = good;
    m.outcome = 99;
    assert_rejected(&m, "outcome", None, unknown_code);
    let mut m = good;
    m.object_count = MAX_SIM_OBJECTS as u32 + 1;
    assert_rejected(&m, "object_count", None, out_of_range);
    let mut m = good;
    m.object_positions[6] = 1.0;
    assert_rejected(&m, "object_positions", Some(6), inconsistent);
    let mut m = good;
    m.tool_position[1] = f64::NAN;
    assert_rejected(&m, "tool_position", Some(1), not_finite);
    let mut m = good;
    m.held_object = 2;
    assert_rejected(&m, "held_object", None, out_of_range);
    let mut m = good;
    m.object_placed_time[1] = -0.5;
    assert_rejected(&m, "object_placed_time", Some(1), inconsistent);
    let mut m = good;
    m.object_placed_time[0] = 13.0;
    assert_rejected(&m, "object_placed_time", Some(0), out_of_range);
    let mut m = good;
    m.task_time = 20.0;
    assert_rejected(&m, "task_time", None, out_of_range);
    let mut m = good;
    m.ee_acc_max = f64::INFINITY;
    assert_rejected(&m, "ee_acc_max", None, not_finite);
}

#[test]
fn driver_status_accepts_a_valid_instance_and_rejects_each_bad_field() {
    let mut good = DriverStatus::zeroed();
    good.header = header();
    good.mode = DriverMode::Stale.into();
    good.hardware_ready = 1;
    good.commands_received = 100;
    good.limit_violations = 3;
    good.clamped_commands = 2;
    good.ignored_commands = 1;
    assert_eq!(check(&good), Ok(()));
    assert_eq!(good.mode(), Some(DriverMode::Stale));
    let mut m = good;
    m.mode = 7;
    assert_rejected(&m, "mode", None, unknown_code);
    let mut m = good;
    m.hardware_ready = 2;
    assert_rejected(&m, "hardware_ready", None, unknown_code);
    let mut m = good;
    m.limit_violations = 4;
    assert_rejected(&m, "limit_violations", None, inconsistent);
}
