//! Conversions between `motm-msgs` payloads (already validated by the bus) and the
//! `motm-core` types the cycle functions take.

use motm_core::kinematics::BasePose;
use motm_core::mission::{Phase, TaskKind};
use motm_core::mission_tracker::MissionTrackerOutput;
use motm_core::resolver::{ResolveStatus, ResolverOutput};
use motm_core::stack::base_planner::BasePlannerOutput;
use motm_core::stack::perception::PerceptionReport;
use motm_core::stack::reacher::PlanView;
use motm_core::stack::resolver::TwistSample;
use motm_core::stack::{MissionReport, PerceivedTarget};
use motm_core::{BaseVelocity, GripperCommand, TargetEstimate, TaskProgress, Twist, wrap_angle};
use motm_msgs as msgs;
use motm_msgs::{MAX_ARM_JOINTS, Message, envelope};
use nalgebra::Vector3;

/// `message` stamped at `stamp_ns` (the sink assigns the sequence number).
pub fn stamped<M: Message>(mut message: M, stamp_ns: u64) -> M {
    message.header_mut().stamp_ns = stamp_ns;
    message
}

/// The [`msgs::MissionState`] message of a mission tracker's output.
pub fn mission_state(out: &MissionTrackerOutput) -> msgs::MissionState {
    let mut m = msgs::MissionState::zeroed();
    m.task_index = out.task_index as u32;
    m.task_count = out.task_count as u32;
    m.task_kind = match out.kind {
        Some(TaskKind::Pick) | None => msgs::TaskKindCode::Pick,
        Some(TaskKind::Place) => msgs::TaskKindCode::Place,
        Some(TaskKind::PressButton) => msgs::TaskKindCode::PressButton,
    }
    .into();
    m.phase = phase_code(out.phase).into();
    m.current_target = out.current_target.into();
    if let Some(next) = out.next_target {
        m.next_target = next.into();
        m.has_next = 1;
    }
    m.odometry_offset = out.odometry_offset;
    m.odometry_calibrated = out.odometry_calibrated.into();
    m.failed_tasks = out.failed_tasks as u32;
    m
}

/// The core phase of a message phase.
pub fn phase(code: msgs::TaskPhase) -> Phase {
    match code {
        msgs::TaskPhase::Reach => Phase::Reach,
        msgs::TaskPhase::Final => Phase::Final,
        msgs::TaskPhase::Complete => Phase::Complete,
    }
}

/// The message phase of a core phase.
pub fn phase_code(phase: Phase) -> msgs::TaskPhase {
    match phase {
        Phase::Reach => msgs::TaskPhase::Reach,
        Phase::Final => msgs::TaskPhase::Final,
        Phase::Complete => msgs::TaskPhase::Complete,
    }
}

/// The core task kind of a message task kind.
pub fn task_kind(code: msgs::TaskKindCode) -> TaskKind {
    match code {
        msgs::TaskKindCode::Pick => TaskKind::Pick,
        msgs::TaskKindCode::Place => TaskKind::Place,
        msgs::TaskKindCode::PressButton => TaskKind::PressButton,
    }
}

/// The mission report in a mission state (`None` if a code is invalid, which validation
/// already excludes).
pub fn mission_report(m: &msgs::MissionState) -> Option<MissionReport> {
    Some(MissionReport {
        task_index: m.task_index as usize,
        task_count: m.task_count as usize,
        kind: task_kind(msgs::TaskKindCode::try_from(m.task_kind).ok()?),
        phase: phase(msgs::TaskPhase::try_from(m.phase).ok()?),
        target: Vector3::from(m.current_target),
        next_waypoint: (m.has_next == 1).then(|| Vector3::from(m.next_target)),
        odometry_offset: m.odometry_offset,
        odometry_calibrated: m.odometry_calibrated == 1,
    })
}

/// The base pose in an odometry sample.
pub fn base_pose(m: &msgs::BaseOdometry) -> BasePose {
    BasePose {
        x: m.x,
        y: m.y,
        yaw: m.yaw,
    }
}

/// The measured base velocity in an odometry sample.
pub fn base_velocity(m: &msgs::BaseOdometry) -> BaseVelocity {
    BaseVelocity {
        v: m.v,
        omega: m.omega,
    }
}

/// The joint positions in use in a joint state.
pub fn arm_q(m: &msgs::JointState) -> &[f64] {
    &m.position[..(m.joint_count as usize).min(MAX_ARM_JOINTS)]
}

/// A perception estimate with its publication stamp.
pub fn perceived(m: &msgs::TargetEstimate) -> PerceivedTarget {
    PerceivedTarget {
        estimate: TargetEstimate {
            position: Vector3::from(m.position),
            velocity: Vector3::from(m.velocity),
        },
        stamp_ns: m.header.stamp_ns,
        image_stamp_ns: m.image_stamp_ns,
        task_index: m.task_index as usize,
    }
}

/// The perception message for `report`; the header is stamped on publishing, at or after
/// the image stamp.
pub fn target_message(report: &PerceptionReport) -> msgs::TargetEstimate {
    let mut m = msgs::TargetEstimate::zeroed();
    m.image_stamp_ns = report.image_stamp_ns;
    m.position = report.estimate.position.into();
    m.velocity = report
        .estimate
        .velocity
        .map(|v| v.clamp(-envelope::OBJECT_SPEED, envelope::OBJECT_SPEED))
        .into();
    m.visible = u32::from(report.estimate.visible);
    m.task_index = report.task_index as u32;
    m
}

/// The base plan in a plan message.
pub fn plan_view(m: &msgs::BasePlan) -> PlanView {
    PlanView {
        task_index: m.task_index as usize,
        time_to_range: m.time_to_range,
        range_entry_pose: BasePose {
            x: m.range_entry_pose[0],
            y: m.range_entry_pose[1],
            yaw: m.range_entry_pose[2],
        },
    }
}

/// A pose as `[x, y, yaw]` with the yaw wrapped to [-π, π].
fn pose_array(p: &BasePose) -> [f64; 3] {
    [p.x, p.y, wrap_angle(p.yaw)]
}

/// The plan message of a base planner output (t_R within the message's envelope).
pub fn plan_message(out: &BasePlannerOutput) -> msgs::BasePlan {
    let mut m = msgs::BasePlan::zeroed();
    m.closest_approach = pose_array(&out.plan.closest_approach);
    m.time_to_range = out.plan.time_to_range.clamp(0.0, envelope::TIME_TO_RANGE);
    m.range_entry_pose = pose_array(&out.plan.range_entry_pose);
    m.task_index = out.task_index as u32;
    m.passed = u32::from(out.plan.passed);
    m.missed_passes = out.plan.missed_passes;
    m.gave_up = u32::from(out.plan.gave_up);
    m
}

/// A base velocity message.
pub fn base_command(v: &BaseVelocity) -> msgs::BaseVelocityCommand {
    let mut m = msgs::BaseVelocityCommand::zeroed();
    m.v = v.v;
    m.omega = v.omega;
    m
}

/// The base velocity in a base velocity message.
pub fn base_velocity_of(m: &msgs::BaseVelocityCommand) -> BaseVelocity {
    BaseVelocity {
        v: m.v,
        omega: m.omega,
    }
}

/// An arm velocity command for the joint velocities `qd` (at most [`MAX_ARM_JOINTS`]).
pub fn arm_command(qd: &[f64]) -> msgs::ArmVelocityCommand {
    let mut m = msgs::ArmVelocityCommand::zeroed();
    let n = qd.len().min(MAX_ARM_JOINTS);
    m.joint_count = n as u32;
    m.velocity[..n].copy_from_slice(&qd[..n]);
    m
}

/// A twist command.
pub fn twist_command(
    twist: &Twist,
    task_index: usize,
    phase: Phase,
    progress: TaskProgress,
    controller_id: u32,
) -> msgs::TwistCommand {
    let mut m = msgs::TwistCommand::zeroed();
    m.controller_id = controller_id;
    m.phase = phase_code(phase).into();
    m.twist = (*twist).into();
    m.task_index = task_index as u32;
    m.progress = match progress {
        TaskProgress::Active => msgs::TaskProgressCode::Active,
        TaskProgress::Done => msgs::TaskProgressCode::Done,
    }
    .into();
    m
}

/// A twist message as the resolver weighs it, aged at `now_ns`.
pub fn twist_sample(m: &msgs::TwistCommand, now_ns: u64) -> Option<TwistSample> {
    Some(TwistSample {
        twist: Twist::from(m.twist),
        task_index: m.task_index as usize,
        phase: phase(m.phase()?),
        controller_id: m.controller_id,
        age_ns: now_ns.saturating_sub(m.header.stamp_ns),
    })
}

/// The task progress a twist message reports.
pub fn progress(m: &msgs::TwistCommand) -> Option<TaskProgress> {
    Some(match m.progress()? {
        msgs::TaskProgressCode::Active => TaskProgress::Active,
        msgs::TaskProgressCode::Done => TaskProgress::Done,
    })
}

/// A gripper command message.
pub fn gripper_command(command: GripperCommand, controller_id: u32) -> msgs::GripperCommand {
    let mut m = msgs::GripperCommand::zeroed();
    m.controller_id = controller_id;
    m.action = match command {
        GripperCommand::Open => msgs::GripperAction::Open,
        GripperCommand::Close => msgs::GripperAction::Close,
    }
    .into();
    m
}

/// The QP status message of one resolve that took `solve_time_ns`, for a command that used the
/// image captured at `image_stamp_ns` and published at `image_published_ns` (if any).
/// `objective` stays zero: the resolver does not report it.
pub fn qp_status(
    out: &ResolverOutput,
    solve_time_ns: u64,
    image_stamp_ns: Option<u64>,
    image_published_ns: Option<u64>,
) -> msgs::QpStatus {
    let mut m = msgs::QpStatus::zeroed();
    m.outcome = match out.status {
        ResolveStatus::Solved => msgs::QpOutcome::Solved,
        ResolveStatus::AlmostSolved => msgs::QpOutcome::AlmostSolved,
        ResolveStatus::InvalidInput | ResolveStatus::SolverFailed => msgs::QpOutcome::Failed,
    }
    .into();
    m.iterations = out.iterations;
    m.solve_time_ns = solve_time_ns;
    let slack = out.slack.norm();
    m.slack_norm = if slack.is_finite() { slack } else { 0.0 };
    m.image_stamp_ns = image_stamp_ns.unwrap_or(0);
    m.image_published_ns = image_published_ns.unwrap_or(0);
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_core::base_controller::{BaseControllerOutput, PassSide};

    /// Every message built here passes the receivers' validation.
    fn valid<M: Message>(m: &M) {
        m.validate(u64::MAX, None).unwrap();
    }

    #[test]
    fn messages_round_trip_and_validate() {
        let twist = Twist::new(0.1, -0.2, 0.3, 0.0, 0.5, -0.6);
        let m = twist_command(&twist, 3, Phase::Final, TaskProgress::Done, 7);
        valid(&m);
        let s = twist_sample(&m, m.header.stamp_ns + 5).unwrap();
        assert_eq!(
            (s.twist, s.task_index, s.phase, s.controller_id, s.age_ns),
            (twist, 3, Phase::Final, 7, 5)
        );
        assert_eq!(progress(&m), Some(TaskProgress::Done));

        let pose = BasePose {
            x: 1.0,
            y: -2.0,
            yaw: 7.0,
        };
        let out = BasePlannerOutput {
            task_index: 1,
            plan: BaseControllerOutput {
                command: BaseVelocity { v: 0.3, omega: 0.1 },
                closest_approach: pose,
                side: PassSide::Left,
                time_to_range: f64::INFINITY,
                range_entry_pose: pose,
                passed: true,
                missed_passes: 2,
                gave_up: true,
            },
        };
        let plan = plan_message(&out);
        valid(&plan);
        assert_eq!((plan.missed_passes, plan.gave_up), (2, 1));
        assert_eq!(plan.time_to_range, envelope::TIME_TO_RANGE);
        assert!((plan.closest_approach[2] - wrap_angle(7.0)).abs() < 1e-12);
        let view = plan_view(&plan);
        assert_eq!(view.task_index, 1);
        assert_eq!(view.range_entry_pose.x, 1.0);

        let arm = arm_command(&[0.1, 0.2, 0.3]);
        valid(&arm);
        assert_eq!(arm.joint_count, 3);
        let base = base_command(&BaseVelocity {
            v: 0.2,
            omega: -0.1,
        });
        valid(&base);
        assert_eq!(
            base_velocity_of(&base),
            BaseVelocity {
                v: 0.2,
                omega: -0.1
            }
        );
        let resolved = ResolverOutput {
            base: BaseVelocity::default(),
            arm_qd: vec![0.0; 7],
            slack: nalgebra::Vector6::repeat(f64::NAN),
            status: ResolveStatus::SolverFailed,
            iterations: 3,
        };
        let mut status = qp_status(&resolved, 1_000, Some(42), Some(45));
        // Publishing stamps the header at or after the image.
        status.header.stamp_ns = 50;
        valid(&status);
        assert_eq!(
            msgs::QpOutcome::try_from(status.outcome),
            Ok(msgs::QpOutcome::Failed)
        );
        assert_eq!((status.image_stamp_ns, status.slack_norm), (42, 0.0));
        assert_eq!(status.image_published_ns, 45);
        let gripper = gripper_command(GripperCommand::Close, 4);
        valid(&gripper);
        assert_eq!(gripper.action(), Some(msgs::GripperAction::Close));
    }

    #[test]
    fn mission_states_decode() {
        let mut m = msgs::MissionState::zeroed();
        m.task_index = 1;
        m.task_count = 2;
        m.task_kind = msgs::TaskKindCode::Place.into();
        m.phase = msgs::TaskPhase::Final.into();
        m.current_target = [4.0, 0.0, 0.35];
        m.next_target = [6.0, 0.0, 0.35];
        valid(&m);
        let r = mission_report(&m).unwrap();
        assert_eq!(
            (r.task_index, r.task_count, r.kind, r.phase),
            (1, 2, TaskKind::Place, Phase::Final)
        );
        assert_eq!(r.next_waypoint, None);
        m.has_next = 1;
        assert_eq!(
            mission_report(&m).unwrap().next_waypoint,
            Some(Vector3::new(6.0, 0.0, 0.35))
        );
    }
}
