//! Closed loop: a kinematic Frankie whose base drives 12 % faster than commanded (a drive gain
//! error, measured by odometry) picks a static cube at 0.4 m/s and heads for the container.
//! - With the base velocity error fed forward ([`motm_core::base_slip`]) the final-phase servo
//!   centres the tool over the cube before closing; without it the servo lags the cube by its
//!   steady-state offset.
//! - With the base target rate limit on ([`motm_core::base_command_rate`], off by default), the
//!   base command never changes faster than the base's acceleration limits, through the grasp
//!   and the hand-over to the next task.

use std::path::Path;

use motm_core::final_phase::FinalPhaseStage;
use motm_core::mission::{MissionTask, TaskKind};
use motm_core::on_the_move::{OnTheMove, OnTheMoveConfig, OnTheMoveInput};
use motm_core::{BasePose, BaseVelocity, Robot, TargetEstimate};
use nalgebra::Vector3;

/// Control period, s.
const DT: f64 = 0.005;
/// Commanded forward speed, m/s.
const V_F: f64 = 0.4;
/// Actual over commanded base velocity.
const BASE_GAIN: f64 = 1.12;

/// What the approach to the cube looked like.
struct Approach {
    /// Horizontal tool-to-cube offset on the first cycle of closing, m.
    offset_at_close: Option<f64>,
    /// Smallest horizontal tool-to-cube offset in the final phase's approach stage after its
    /// first half second (once the servo has settled), m.
    min_settled_offset: f64,
    /// Largest change per second of the commanded base ω (rad/s²) and v (m/s²).
    max_omega_rate: f64,
    max_v_rate: f64,
    /// Whether the mission moved on to the place task.
    handed_over: bool,
}

fn approach(slip_feed_forward: bool, base_rate_limit: bool) -> Approach {
    let robot = Robot::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config"),
        "frankie",
    )
    .unwrap();
    let mut config = OnTheMoveConfig::default();
    config.base.forward_speed = V_F;
    config.base_slip.enabled = slip_feed_forward;
    config.base_rate.enabled = base_rate_limit;
    let cube = Vector3::new(2.0, 0.0, 0.45);
    let tasks = vec![
        MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: cube,
        },
        MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(4.0, 1.0, 0.35),
        },
    ];
    let mut arm_q = robot.config.ready_pose.clone();
    let mut controller = OnTheMove::new(robot.clone(), config, tasks, Vector3::zeros());
    let mut base = BasePose::default();
    let mut base_velocity = BaseVelocity::default();
    let mut approach_started: Option<f64> = None;
    let mut base_velocity_command = BaseVelocity::default();
    let mut result = Approach {
        offset_at_close: None,
        min_settled_offset: f64::INFINITY,
        max_omega_rate: 0.0,
        max_v_rate: 0.0,
        handed_over: false,
    };
    // The gripper reports open throughout: it closes for the time-out, lifts, and the mission
    // moves on to the place task.
    for k in 0..(9.0 / DT) as usize {
        let t = k as f64 * DT;
        let out = controller.step(&OnTheMoveInput {
            t,
            dt: DT,
            base,
            base_velocity,
            arm_q: &arm_q,
            gripper_opening: 0.08,
            target: TargetEstimate::fixed(cube),
        });
        let tool = robot.tool_pose(&base, &arm_q).translation.vector;
        let offset = (tool - cube).xy().norm();
        match out.stage {
            Some(FinalPhaseStage::Approach) => {
                let started = *approach_started.get_or_insert(t);
                if t - started > 0.5 {
                    result.min_settled_offset = result.min_settled_offset.min(offset);
                }
            }
            Some(FinalPhaseStage::Closing) if result.offset_at_close.is_none() => {
                result.offset_at_close = Some(offset);
            }
            _ => {}
        }
        result.handed_over |= out.task_index > 0;
        if k > 0 {
            // The first cycle starts from rest on both sides; compare consecutive commands.
            let last = base_velocity_command;
            result.max_omega_rate = result
                .max_omega_rate
                .max((out.base.omega - last.omega).abs() / DT);
            result.max_v_rate = result.max_v_rate.max((out.base.v - last.v).abs() / DT);
        }
        base_velocity_command = out.base;
        // The base moves BASE_GAIN times faster than commanded; odometry measures it.
        base_velocity = BaseVelocity {
            v: out.base.v * BASE_GAIN,
            omega: out.base.omega * BASE_GAIN,
        };
        base.yaw += base_velocity.omega * DT;
        base.x += base_velocity.v * base.yaw.cos() * DT;
        base.y += base_velocity.v * base.yaw.sin() * DT;
        for (q, qd) in arm_q.iter_mut().zip(&out.arm_qd) {
            *q += qd * DT;
        }
    }
    result
}

#[test]
fn feed_forward_of_the_base_velocity_error_lets_the_grasp_close_on_a_fast_base() {
    let with = approach(true, false);
    let offset = with
        .offset_at_close
        .expect("the gripper closes on the cube with the feed-forward");
    assert!(offset < 0.005, "closed {offset} m off the cube");

    let without = approach(false, false);
    assert!(
        without.offset_at_close.is_none_or(|o| o > offset),
        "without the feed-forward the tool is not better centred"
    );
    assert!(
        without.min_settled_offset > 0.005,
        "without the feed-forward the servo lags the cube by its steady offset, got {} m",
        without.min_settled_offset
    );
}

#[test]
fn the_base_command_respects_the_base_acceleration_limits_through_the_hand_over() {
    let robot = Robot::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config"),
        "frankie",
    )
    .unwrap();
    let limits = robot.limits();
    let run = approach(true, true);
    assert!(run.handed_over, "the mission reaches the place task");
    // The QP's base rows are soft, so allow it 5 % beyond the target's limit.
    assert!(
        run.max_omega_rate <= limits[0].acceleration * 1.05,
        "ω command changed at {} rad/s²",
        run.max_omega_rate
    );
    assert!(
        run.max_v_rate <= limits[1].acceleration * 1.05,
        "v command changed at {} m/s²",
        run.max_v_rate
    );
}
