//! Tests of the per-process cycle functions, including their agreement with the single-process
//! controller they are split from.

use std::path::Path;

use nalgebra::Vector3;

use super::base_planner::{BasePlannerCycle, BasePlannerInput};
use super::final_phase::{FinalPhaseCycle, FinalPhaseCycleInput, VariantMode};
use super::reacher::{PlanView, ReacherCycle, ReacherCycleInput, ReacherIdle};
use super::resolver::{
    MeasuredState, ResolverCycle, ResolverCycleConfig, ResolverCycleInput, TwistSample, TwistSource,
};
use super::*;
use crate::final_phase::FinalPhaseKind;
use crate::kinematics::BasePose;
use crate::robot::Robot;
use crate::types::{BaseVelocity, Twist};

const MS: u64 = 1_000_000;

fn frankie() -> Robot {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    Robot::load(&config_dir, "frankie").expect("frankie loads")
}

fn view(task_index: usize, kind: TaskKind, phase: Phase) -> MissionView {
    MissionView {
        task_index,
        task_count: 2,
        kind,
        phase,
        target: Vector3::new(2.0, 0.0, 0.45),
        next_waypoint: Vector3::new(4.0, 0.0, 0.35),
        odometry_offset: [0.0; 3],
        odometry_calibrated: false,
    }
}

#[test]
fn latch_keeps_the_last_task_after_completion_and_fills_in_run_out_points() {
    let mut latch = MissionLatch::new(2.0);
    let mut report = MissionReport {
        task_index: 0,
        task_count: 2,
        kind: TaskKind::Pick,
        phase: Phase::Reach,
        target: Vector3::new(2.0, 0.0, 0.45),
        next_waypoint: None,
        odometry_offset: [0.0; 3],
        odometry_calibrated: false,
    };
    // A completed mission whose tasks this process never saw: nothing to act on.
    let complete = MissionReport {
        task_index: 2,
        phase: Phase::Complete,
        target: Vector3::zeros(),
        ..report
    };
    assert_eq!(latch.update(&complete), None);
    // No next waypoint for the first task: 2 m beyond the target along x.
    let view = latch.update(&report).unwrap();
    assert!((view.next_waypoint - Vector3::new(4.0, 0.0, 0.45)).norm() < 1e-12);
    report.next_waypoint = Some(Vector3::new(4.0, 3.0, 0.35));
    assert_eq!(
        latch.update(&report).unwrap().next_waypoint,
        Vector3::new(4.0, 3.0, 0.35)
    );
    // The last task, without a run-out point: along the direction from the previous target.
    let place = MissionReport {
        task_index: 1,
        kind: TaskKind::Place,
        target: Vector3::new(2.0, 3.0, 0.35),
        next_waypoint: None,
        ..report
    };
    let view = latch.update(&place).unwrap();
    assert!((view.next_waypoint - Vector3::new(2.0, 5.0, 0.35)).norm() < 1e-12);
    let done = latch.update(&complete).unwrap();
    assert!(done.is_complete());
    assert_eq!((done.task_index, done.base_task_index()), (2, 1));
    assert_eq!((done.kind, done.target), (TaskKind::Place, place.target));
    assert_eq!(done.current_kind(), None);
    let empty = MissionReport {
        task_count: 0,
        task_index: 0,
        ..report
    };
    assert_eq!(latch.update(&empty), None);
}

#[test]
fn selector_uses_perception_only_for_the_current_pick_or_press() {
    let selector = TargetSelector;
    let seen = PerceivedTarget {
        estimate: TargetEstimate {
            position: Vector3::new(2.05, 0.02, 0.45),
            velocity: Vector3::new(0.03, 0.0, 0.0),
        },
        task_index: 0,
        stamp_ns: 1_000 * MS,
        image_stamp_ns: 960 * MS,
    };
    // The pick (task 0): the mission's position until perception has an estimate of task 0.
    let pick = view(0, TaskKind::Pick, Phase::Reach);
    assert_eq!(selector.select(&pick, None).position, pick.target);
    assert_eq!(selector.select(&pick, Some(&seen)), seen.estimate);
    let source = selector.select_with_source(&pick, Some(&seen));
    assert_eq!(source.image_stamp_ns, Some(960 * MS));
    // The place: the mission's container position, whatever perception last said.
    let mut place = view(1, TaskKind::Place, Phase::Reach);
    place.target = Vector3::new(4.0, 0.0, 0.35);
    let chosen = selector.select_with_source(&place, Some(&seen));
    assert_eq!(chosen.target, TargetEstimate::fixed(place.target));
    assert_eq!(chosen.image_stamp_ns, None);
    // A later task of the mission (its index 2 or 3 of 4) at `target`: the mission's target
    // while perception's latest estimate is of another task (`seen`, task 0), perception's
    // once it publishes one for this task, however old the process that asks (a restarted
    // one included).
    let takes_only_its_own_estimate = |kind: TaskKind, task_index: usize, target: Vector3<f64>| {
        let mut task = view(task_index, kind, Phase::Reach);
        task.task_count = 4;
        task.target = target;
        assert_eq!(
            selector.select(&task, Some(&seen)),
            TargetEstimate::fixed(target)
        );
        let own = PerceivedTarget { task_index, ..seen };
        assert_eq!(selector.select(&task, Some(&own)), own.estimate);
    };
    // A press: perception's estimate of the button cap (the mission's button position is in
    // the world frame, the tools' poses in the drifting odometry frame).
    takes_only_its_own_estimate(TaskKind::PressButton, 3, Vector3::new(6.0, 0.0, 0.5));
    // A later pick ignores the previous pick's estimate.
    takes_only_its_own_estimate(TaskKind::Pick, 2, Vector3::new(6.0, 1.0, 0.45));
}

#[test]
fn place_aim_is_raised_to_the_release_point_and_the_gripper_rests_by_task() {
    let config = OnTheMoveConfig::default();
    let target = TargetEstimate::fixed(Vector3::new(4.0, 0.0, 0.35));
    let raise = config.final_phase.drop.release_height - config.reacher.pregrasp_height;
    assert!(raise.abs() > 1e-6, "the test needs a non-zero raise");
    let aim = reach_aim(TaskKind::Place, &target, &config);
    assert!((aim.position.z - (0.35 + raise)).abs() < 1e-12);
    assert_eq!(reach_aim(TaskKind::Pick, &target, &config), target);
    assert_eq!(resting_gripper(Some(TaskKind::Pick)), GripperCommand::Open);
    assert_eq!(
        resting_gripper(Some(TaskKind::Place)),
        GripperCommand::Close
    );
    assert_eq!(
        resting_gripper(Some(TaskKind::PressButton)),
        GripperCommand::Close
    );
    assert_eq!(resting_gripper(None), GripperCommand::Open);
}

#[test]
fn base_planner_drives_for_the_last_task_after_completion_and_refuses_nan() {
    let robot = frankie();
    let mut planner = BasePlannerCycle::new(&robot, Default::default(), &[]);
    let mission = view(0, TaskKind::Pick, Phase::Reach);
    let input = BasePlannerInput {
        mission,
        base: BasePose::default(),
        target: TargetEstimate::fixed(mission.target),
        dt: 0.005,
    };
    let out = planner.step(&input).expect("a plan");
    assert_eq!(out.task_index, 0);
    assert!(out.plan.command.v > 0.0);
    assert!(out.plan.time_to_range > 0.0);
    let mut bad = input;
    bad.base.yaw = f64::NAN;
    assert!(planner.step(&bad).is_none());
    assert_eq!(planner.refused(), 1);
    let mut done = input;
    done.mission.task_index = 2;
    done.mission.phase = Phase::Complete;
    let out = planner.step(&done).expect("drives on after the mission");
    assert_eq!(out.task_index, 1);
    assert!(out.plan.command.v > 0.0);
    assert_eq!(planner.refused(), 1);
}

/// The base planner's commands over `seconds` with the base held at `base` past the last
/// target (2, 0) of `mission`.
fn commands_held_past_the_target(mission: MissionView, base: BasePose, seconds: f64) -> Vec<f64> {
    let robot = frankie();
    let mut planner = BasePlannerCycle::new(&robot, Default::default(), &[]);
    let input = BasePlannerInput {
        mission,
        base,
        target: TargetEstimate::fixed(Vector3::new(2.0, 0.0, 0.45)),
        dt: 0.005,
    };
    (0..(seconds / input.dt) as usize)
        .map(|_| planner.step(&input).expect("a plan").plan.command.v)
        .collect()
}

#[test]
fn after_the_mission_the_base_stands_instead_of_coming_around() {
    // Held past the target with its task not done, the base lingers to a stop and, after the
    // pass timeout, comes around for another approach.
    let base = BasePose::new(2.4, 0.6, 0.0);
    let active = commands_held_past_the_target(view(1, TaskKind::Place, Phase::Final), base, 10.0);
    assert_eq!(active[0], 0.0);
    assert!(
        active.iter().any(|&v| v > 0.0),
        "the missed pass comes around"
    );
    // Once the mission is complete the base stands at that stop for good.
    let mut done = view(2, TaskKind::Place, Phase::Complete);
    done.task_index = 2;
    let complete = commands_held_past_the_target(done, base, 10.0);
    assert!(complete.iter().all(|&v| v == 0.0));
    // Near the run-out point (4, 0) it stands too.
    let near = commands_held_past_the_target(done, BasePose::new(3.5, 0.3, 0.0), 1.0);
    assert!(near.iter().all(|&v| v == 0.0));
}

#[test]
fn reacher_waits_for_a_plan_of_its_task_and_is_idle_in_the_final_phase() {
    let robot = frankie();
    let q = robot.config.ready_pose.clone();
    let mut reacher = ReacherCycle::new(robot, OnTheMoveConfig::default(), 0.005);
    let mission = view(1, TaskKind::Place, Phase::Reach);
    let mut input = ReacherCycleInput {
        mission,
        base: BasePose::default(),
        arm_q: &q,
        target: TargetEstimate::fixed(mission.target),
        plan: Some(PlanView {
            task_index: 0,
            time_to_range: 3.0,
            range_entry_pose: BasePose::default(),
        }),
        base_target: BaseVelocity { v: 0.3, omega: 0.0 },
    };
    assert_eq!(reacher.step(&input).unwrap_err(), ReacherIdle::NoPlan);
    input.plan.as_mut().unwrap().task_index = 1;
    let out = reacher.step(&input).expect("a twist");
    assert!(out.twist.iter().all(|x| x.is_finite()));
    input.mission.phase = Phase::Final;
    assert_eq!(reacher.step(&input).unwrap_err(), ReacherIdle::NotReaching);
    input.mission.phase = Phase::Reach;
    let short = &q[..3];
    input.arm_q = short;
    assert_eq!(reacher.step(&input).unwrap_err(), ReacherIdle::BadInput);
}

#[test]
fn a_fixed_variant_acts_only_on_its_own_tasks() {
    let mut drop =
        FinalPhaseCycle::new(VariantMode::Fixed(FinalPhaseKind::Drop), Default::default());
    let robot = frankie();
    let q = robot.config.ready_pose.clone();
    let base = BasePose::default();
    let mut input = FinalPhaseCycleInput {
        mission: view(0, TaskKind::Pick, Phase::Final),
        t: 0.0,
        tool_pose: robot.tool_pose(&base, &q),
        base_pose: base,
        base_velocity: BaseVelocity::default(),
        target: TargetEstimate::fixed(Vector3::new(0.7, 0.0, 0.4)),
        gripper_opening: 0.08,
        grasp_yaw: None,
    };
    let out = drop.step(&input);
    assert_eq!((out.control, out.gripper), (None, None));
    input.mission = view(1, TaskKind::Place, Phase::Reach);
    let out = drop.step(&input);
    assert_eq!(out.control, None);
    assert_eq!(out.gripper, Some(GripperCommand::Close));
    input.mission.phase = Phase::Final;
    let out = drop.step(&input);
    assert!(out.control.is_some());
    input.tool_pose.translation.vector.x = f64::NAN;
    let out = drop.step(&input);
    assert!(out.control.unwrap().input_rejected);
    assert_eq!(out.control.unwrap().twist, Twist::zeros());
    assert_eq!(drop.rejected(), 1);
}

fn sample(twist: Twist, task_index: usize, phase: Phase, age_ns: u64) -> TwistSample {
    TwistSample {
        twist,
        task_index,
        phase,
        controller_id: 1,
        age_ns,
    }
}

#[test]
fn resolver_picks_the_active_phase_falls_back_in_hand_overs_and_stops_on_stale_input() {
    let robot = frankie();
    let q = robot.config.ready_pose.clone();
    let limits = robot.limits();
    // No rate limit here, so the chosen twist is resolved as it is.
    let mut config = OnTheMoveConfig::default();
    config.twist_rate.linear_acceleration = 1e9;
    config.twist_rate.linear_acceleration_per_speed = 1e9;
    config.twist_rate.angular_acceleration = 1e9;
    let mut resolver = ResolverCycle::new(robot, config, ResolverCycleConfig::default(), 0.005);
    let reach_twist = Twist::new(0.05, 0.0, 0.0, 0.0, 0.0, 0.0);
    let final_twist = Twist::new(0.0, 0.0, -0.05, 0.0, 0.0, 0.0);
    let mission = view(0, TaskKind::Pick, Phase::Final);
    let mut input = ResolverCycleInput {
        mission: Some(mission),
        state: Some(MeasuredState {
            base: BasePose::default(),
            arm_q: &q,
            base_velocity: BaseVelocity::default(),
            age_ns: 2 * MS,
        }),
        target: TargetEstimate::fixed(mission.target),
        reach: Some(sample(reach_twist, 0, Phase::Reach, MS)),
        final_twist: Some(sample(final_twist, 0, Phase::Final, 3 * MS)),
        active_controller: None,
        base_target: Some((BaseVelocity { v: 0.3, omega: 0.0 }, MS)),
    };
    let out = resolver.step(&input);
    assert_eq!(
        (out.twist, out.source),
        (final_twist, TwistSource::ActivePhase)
    );
    assert!(out.resolved.status.is_ok());
    let qd = out.resolved.joint_velocities();
    for (v, limit) in qd.iter().zip(&limits) {
        assert!(
            v.is_finite() && v.abs() <= limit.velocity + 1e-9,
            "{v} vs {}",
            limit.velocity
        );
    }
    assert!((out.tool_to_target - (robot_tool_distance(&q, &mission))).abs() < 1e-12);
    // The twist rate limit (the default one) applies to whatever is chosen.
    let rate_limited = || {
        ResolverCycle::new(
            frankie(),
            OnTheMoveConfig::default(),
            ResolverCycleConfig::default(),
            0.005,
        )
    };
    // With the base at rest its linear limit is the one at the run's base speed.
    input.base_target = Some((BaseVelocity::default(), MS));
    let out = rate_limited().step(&input);
    let defaults = OnTheMoveConfig::default();
    let limit = defaults
        .twist_rate
        .linear_limit(defaults.base.forward_speed)
        * 0.005;
    assert!((out.twist.norm() - limit).abs() < 1e-12, "{}", out.twist);
    // With the base speeding up from rest, the limit gives up a share of its acceleration,
    // down to the floor.
    input.base_target = Some((BaseVelocity { v: 0.3, omega: 0.0 }, MS));
    let out = rate_limited().step(&input);
    let floor = defaults.twist_rate.min_linear_acceleration * 0.005;
    assert!(
        out.twist.norm() < limit - 1e-9 && out.twist.norm() >= floor - 1e-12,
        "{} vs {limit} (floor {floor})",
        out.twist
    );
    // Another controller is active: its twist has not come yet, so the reach twist bridges.
    input.active_controller = Some(2);
    let out = resolver.step(&input);
    assert_eq!(
        (out.twist, out.source),
        (reach_twist, TwistSource::Fallback)
    );
    assert_eq!(resolver.fallbacks(), 1);
    // The active controller stays silent past the hand-over window (50 ms, ten cycles): the
    // tool holds its place relative to the target, moving with it.
    input.target = TargetEstimate {
        position: mission.target,
        velocity: nalgebra::Vector3::new(0.1, 0.0, 0.0),
    };
    let sources: Vec<TwistSource> = (0..12).map(|_| resolver.step(&input).source).collect();
    assert_eq!(sources[..9], [TwistSource::Fallback; 9], "{sources:?}");
    assert_eq!(sources[11], TwistSource::Hold, "{sources:?}");
    assert_eq!(
        resolver.step(&input).twist,
        Twist::new(0.1, 0.0, 0.0, 0.0, 0.0, 0.0)
    );
    assert!(resolver.holds() >= 2);
    input.target = TargetEstimate::fixed(mission.target);
    // Every twist stale: the hold goes on, up to max_hold (0.5 s in all), then an all-zero
    // command.
    input.active_controller = None;
    input.reach.as_mut().unwrap().age_ns = 60 * MS;
    input.final_twist.as_mut().unwrap().age_ns = 60 * MS;
    let sources: Vec<TwistSource> = (0..100).map(|_| resolver.step(&input).source).collect();
    let held = sources.iter().filter(|s| **s == TwistSource::Hold).count();
    assert!(
        held > 80 && sources[99] == TwistSource::Stopped,
        "{sources:?}"
    );
    let out = resolver.step(&input);
    assert_eq!(out.source, TwistSource::Stopped);
    assert!(out.resolved.arm_qd.iter().all(|v| *v == 0.0));
    assert_eq!(out.resolved.base, BaseVelocity::default());
    // A stale robot state withholds the command, even with fresh twists.
    input.final_twist.as_mut().unwrap().age_ns = MS;
    input.state.as_mut().unwrap().age_ns = 80 * MS;
    assert_eq!(resolver.step(&input).source, TwistSource::Withheld);
    // After the mission the reacher's twist (for the task index past the last) is active.
    input.state.as_mut().unwrap().age_ns = MS;
    let mission = input.mission.as_mut().unwrap();
    mission.phase = Phase::Complete;
    mission.task_index = 2;
    input.reach = Some(sample(reach_twist, 2, Phase::Reach, MS));
    let stops = resolver.stops();
    let out = resolver.step(&input);
    assert_eq!(
        (out.twist, out.source),
        (reach_twist, TwistSource::ActivePhase)
    );
    assert_eq!(resolver.stops(), stops);
    // No mission at all: stop.
    input.mission = None;
    assert_eq!(resolver.step(&input).source, TwistSource::Stopped);
    assert_eq!(resolver.stops(), stops + 1);
}

/// Tool-to-target distance of Frankie at the origin with joints `q`.
fn robot_tool_distance(q: &[f64], mission: &MissionView) -> f64 {
    let tool = frankie().tool_pose(&BasePose::default(), q);
    (tool.translation.vector - mission.target).norm()
}

#[test]
fn perception_pairs_each_image_with_the_nearest_tool_pose_and_restarts_per_pick() {
    use super::perception::{CameraFrame, PerceptionCycle};
    use crate::camera::CameraConfig;
    use crate::perception::PerceptionConfig;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    let mut calibration = CameraConfig::default().calibration();
    calibration.tool_from_camera = Isometry3::identity();
    let (w, h) = (320usize, 240usize);
    let grey = vec![100u8; w * h * 3];
    let mut red = grey.clone();
    for v in 117..=121 {
        for u in 157..=161 {
            red[(v * w + u) * 3..(v * w + u) * 3 + 3].copy_from_slice(&[200, 20, 20]);
        }
    }
    let looking_down = |x: f64| {
        Isometry3::from_parts(
            Translation3::new(x, 0.0, 0.5),
            UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0),
        )
    };
    fn frame(pixels: &[u8], stamp_ns: u64) -> CameraFrame<'_> {
        CameraFrame {
            pixels,
            width: 320,
            height: 240,
            stamp_ns,
        }
    }
    let mut cycle = PerceptionCycle::new(PerceptionConfig::default(), calibration, 200);
    let mut pick = view(0, TaskKind::Pick, Phase::Reach);
    pick.target = Vector3::zeros();
    // No tool pose yet: nothing to pair the image with.
    assert!(cycle.observe(&pick, &frame(&red, 1_000 * MS)).is_none());
    cycle.record_tool(1_000 * MS, looking_down(1.0));
    cycle.record_tool(2_000 * MS, looking_down(0.0));
    // Captured at 1.9 s: paired with the pose at 2 s, so the cube is under x = 0.
    let report = cycle
        .observe(&pick, &frame(&red, 1_900 * MS))
        .expect("a fix");
    assert!(report.estimate.visible && report.estimate.valid);
    assert!(report.estimate.position.x.abs() < 0.01, "{report:?}");
    assert_eq!(report.image_stamp_ns, 1_900 * MS);
    // Out of view: the fix is held, with the stamp of the image it came from.
    let held = cycle
        .observe(&pick, &frame(&grey, 1_950 * MS))
        .expect("held fix");
    assert!(!held.estimate.visible);
    assert_eq!(held.image_stamp_ns, 1_900 * MS);
    // A place publishes nothing; a press publishes its button cap's fix; the next pick starts
    // from scratch.
    let place = view(1, TaskKind::Place, Phase::Reach);
    assert!(cycle.observe(&place, &frame(&red, 1_960 * MS)).is_none());
    let mut press = view(1, TaskKind::PressButton, Phase::Reach);
    press.task_index = 3;
    press.task_count = 5;
    press.target = Vector3::zeros();
    let cap = cycle
        .observe(&press, &frame(&red, 1_960 * MS))
        .expect("a fix of the cap");
    assert!(
        cap.estimate.visible && cap.estimate.position.x.abs() < 0.01,
        "{cap:?}"
    );
    let mut next_pick = pick;
    next_pick.task_index = 2;
    next_pick.task_count = 4;
    assert!(
        cycle
            .observe(&next_pick, &frame(&grey, 1_970 * MS))
            .is_none()
    );
    // Non-finite tool poses are not recorded.
    let mut nan_pose = looking_down(0.0);
    nan_pose.translation.vector.x = f64::NAN;
    cycle.record_tool(1_980 * MS, nan_pose);
    let report = cycle
        .observe(&next_pick, &frame(&red, 1_980 * MS))
        .expect("a fix");
    assert!(report.estimate.position.iter().all(|x| x.is_finite()));
}
