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
use crate::mission::{Mission, MissionConfig, MissionTask};
use crate::on_the_move::{OnTheMove, OnTheMoveInput};
use crate::robot::Robot;
use crate::types::{BaseVelocity, TaskProgress, Twist};

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
    }
}

/// The report the supervisor would publish for `mission` (what it knows once complete is not
/// used by the services).
fn report_of(mission: &Mission) -> MissionReport {
    let task = mission.current_task().copied();
    let target = task.map_or(Vector3::zeros(), |t| t.position);
    MissionReport {
        task_index: mission.task_index(),
        task_count: mission.tasks().len(),
        kind: task.map_or(TaskKind::Pick, |t| t.kind),
        phase: mission.phase(),
        target,
        next_waypoint: task.map(|_| mission.next_waypoint(&target)),
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
    let mut selector = TargetSelector::default();
    let seen = PerceivedTarget {
        estimate: TargetEstimate {
            position: Vector3::new(2.05, 0.02, 0.45),
            velocity: Vector3::new(0.03, 0.0, 0.0),
        },
        stamp_ns: 1_000 * MS,
        image_stamp_ns: 960 * MS,
    };
    // The pick starts at t = 900 ms: the estimate stamped at 1000 ms belongs to it.
    let pick = view(0, TaskKind::Pick, Phase::Reach);
    assert_eq!(selector.select(&pick, 900 * MS, None).position, pick.target);
    assert_eq!(
        selector.select(&pick, 1_010 * MS, Some(&seen)),
        seen.estimate
    );
    let source = selector.select_with_source(&pick, 1_015 * MS, Some(&seen));
    assert_eq!(source.image_stamp_ns, Some(960 * MS));
    // The place: the mission's container position, whatever perception last said.
    let mut place = view(1, TaskKind::Place, Phase::Reach);
    place.target = Vector3::new(4.0, 0.0, 0.35);
    let chosen = selector.select_with_source(&place, 1_020 * MS, Some(&seen));
    assert_eq!(chosen.target, TargetEstimate::fixed(place.target));
    assert_eq!(chosen.image_stamp_ns, None);
    // A later task of the mission (its index 2 or 3 of 4) at `target`: the mission's target
    // while perception's latest estimate is `seen` (made before the task started), perception's
    // once it publishes one stamped `fresh_ms`.
    let mut takes_only_a_fresh_estimate =
        |kind: TaskKind, task_index: usize, target: Vector3<f64>, asked_ms: u64, fresh_ms: u64| {
            let mut task = view(task_index, kind, Phase::Reach);
            task.task_count = 4;
            task.target = target;
            assert_eq!(
                selector.select(&task, asked_ms * MS, Some(&seen)),
                TargetEstimate::fixed(target)
            );
            let fresh = PerceivedTarget {
                stamp_ns: fresh_ms * MS,
                ..seen
            };
            assert_eq!(
                selector.select(&task, (fresh_ms + 10) * MS, Some(&fresh)),
                fresh.estimate
            );
        };
    // A press: perception's estimate of the button cap once it is fresh (the mission's button
    // position is in the world frame, the tools' poses in the drifting odometry frame).
    takes_only_a_fresh_estimate(
        TaskKind::PressButton,
        3,
        Vector3::new(6.0, 0.0, 0.5),
        1_030,
        1_040,
    );
    // A later pick ignores the previous pick's estimate until perception publishes anew.
    takes_only_a_fresh_estimate(
        TaskKind::Pick,
        2,
        Vector3::new(6.0, 1.0, 0.45),
        5_000,
        5_030,
    );
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
    let mut planner = BasePlannerCycle::new(&robot, Default::default());
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
    // The twist rate limit applies to whatever is chosen.
    let mut slow = ResolverCycle::new(
        frankie(),
        OnTheMoveConfig::default(),
        ResolverCycleConfig::default(),
        0.005,
    );
    let out = slow.step(&input);
    let limit = OnTheMoveConfig::default().twist_rate.linear_acceleration * 0.005;
    assert!((out.twist.norm() - limit).abs() < 1e-12, "{}", out.twist);
    // Another controller is active: its twist has not come yet, so the reach twist bridges.
    input.active_controller = Some(2);
    let out = resolver.step(&input);
    assert_eq!(
        (out.twist, out.source),
        (reach_twist, TwistSource::Fallback)
    );
    assert_eq!(resolver.fallbacks(), 1);
    // Every twist stale: all-zero command.
    input.active_controller = None;
    input.reach.as_mut().unwrap().age_ns = 60 * MS;
    input.final_twist.as_mut().unwrap().age_ns = 60 * MS;
    let out = resolver.step(&input);
    assert_eq!(out.source, TwistSource::Stopped);
    assert!(out.resolved.arm_qd.iter().all(|v| *v == 0.0));
    assert_eq!(out.resolved.base, BaseVelocity::default());
    // A stale joint state stops too, even with fresh twists.
    input.final_twist.as_mut().unwrap().age_ns = MS;
    input.state.as_mut().unwrap().age_ns = 80 * MS;
    assert_eq!(resolver.step(&input).source, TwistSource::Stopped);
    // After the mission the reacher's twist (for the task index past the last) is active.
    input.state.as_mut().unwrap().age_ns = MS;
    let mission = input.mission.as_mut().unwrap();
    mission.phase = Phase::Complete;
    mission.task_index = 2;
    input.reach = Some(sample(reach_twist, 2, Phase::Reach, MS));
    let out = resolver.step(&input);
    assert_eq!(
        (out.twist, out.source),
        (reach_twist, TwistSource::ActivePhase)
    );
    assert_eq!(resolver.stops(), 2);
    // No mission at all: stop.
    input.mission = None;
    assert_eq!(resolver.step(&input).source, TwistSource::Stopped);
    assert_eq!(resolver.stops(), 3);
}

/// Tool-to-target distance of Frankie at the origin with joints `q`.
fn robot_tool_distance(q: &[f64], mission: &MissionView) -> f64 {
    let tool = frankie().tool_pose(&BasePose::default(), q);
    (tool.translation.vector - mission.target).norm()
}

/// The split services, run in lockstep with zero latency and a supervisor's mission, command
/// exactly what the single-process controller commands, through both phases of a pick and a
/// place and on after the mission.
#[test]
fn the_split_cycles_agree_with_the_single_process_controller() {
    let robot = frankie();
    let config = OnTheMoveConfig::default();
    let dt = 0.005;
    let tasks = vec![
        MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: Vector3::new(2.0, 0.3, 0.45),
        },
        MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(4.0, 0.3, 0.35),
        },
    ];
    let start = Vector3::zeros();
    let mut whole = OnTheMove::new(robot.clone(), config.clone(), tasks.clone(), start);
    let mut mission = Mission::new(MissionConfig::default(), tasks, start);
    let mut latch = MissionLatch::new(config.mission.run_out_distance);
    let mut selector = TargetSelector::default();
    let mut planner = BasePlannerCycle::new(&robot, config.base.clone());
    let mut reacher = ReacherCycle::new(robot.clone(), config.clone(), dt);
    let mut final_phase = FinalPhaseCycle::new(VariantMode::FollowMission, config.final_phase);
    let mut resolver = ResolverCycle::new(
        robot.clone(),
        config.clone(),
        ResolverCycleConfig::default(),
        dt,
    );

    let mut base = BasePose::default();
    let mut base_velocity = BaseVelocity::default();
    let mut q = robot.config.ready_pose.clone();
    let mut opening = 0.08;
    let mut phases_seen = Vec::new();
    // Up to 40 s, and on for 100 cycles after the mission completes.
    let mut complete_cycles = 0;
    for cycle in 0..8000u64 {
        if mission.phase() == Phase::Complete {
            complete_cycles += 1;
            if complete_cycles > 100 {
                break;
            }
        }
        let t = cycle as f64 * dt;
        let now_ns = cycle * 5 * MS;
        let view = latch.update(&report_of(&mission)).expect("a mission");
        let target = selector.select(&view, now_ns, None);
        let expected = whole.step(&OnTheMoveInput {
            t,
            dt,
            base,
            base_velocity,
            arm_q: &q,
            gripper_opening: opening,
            target,
        });

        let plan = planner
            .step(&BasePlannerInput {
                mission: view,
                base,
                target,
                dt,
            })
            .expect("a plan");
        let tool_pose = robot.tool_pose(&base, &q);
        let fp = final_phase.step(&FinalPhaseCycleInput {
            mission: view,
            t,
            tool_pose,
            base_pose: base,
            base_velocity,
            target,
            gripper_opening: opening,
        });
        let mut reach = None;
        let mut final_twist = None;
        let mut progress = TaskProgress::Active;
        if let Some(control) = fp.control {
            final_twist = Some(sample(control.twist, view.task_index, Phase::Final, 0));
            progress = control.progress;
        } else {
            let out = reacher
                .step(&ReacherCycleInput {
                    mission: view,
                    base,
                    arm_q: &q,
                    target,
                    plan: Some(PlanView {
                        task_index: plan.task_index,
                        time_to_range: plan.plan.time_to_range,
                        range_entry_pose: plan.plan.range_entry_pose,
                    }),
                    base_target: plan.plan.command,
                })
                .expect("a reach twist");
            reach = Some(sample(out.twist, view.task_index, Phase::Reach, 0));
            assert_eq!(out.mode, expected.reach_mode, "cycle {cycle}");
        }
        let out = resolver.step(&ResolverCycleInput {
            mission: Some(view),
            state: Some(MeasuredState {
                base,
                arm_q: &q,
                base_velocity,
                age_ns: 0,
            }),
            target,
            reach,
            final_twist,
            active_controller: None,
            base_target: Some((plan.plan.command, 0)),
        });
        // The reacher's tool state is the twist the resolver resolved.
        reacher.feedback(out.twist);
        mission.step(out.tool_to_target, progress);

        assert_eq!(out.source, TwistSource::ActivePhase, "cycle {cycle}");
        assert_eq!(out.twist, expected.twist, "cycle {cycle}");
        assert_eq!(out.resolved.arm_qd, expected.arm_qd, "cycle {cycle}");
        assert_eq!(out.resolved.base, expected.base, "cycle {cycle}");
        assert_eq!(fp.gripper, Some(expected.gripper), "cycle {cycle}");
        assert_eq!(plan.plan.command, expected.base_target, "cycle {cycle}");
        assert_eq!(
            (mission.task_index(), mission.phase()),
            (expected.task_index, expected.phase)
        );
        if phases_seen.last() != Some(&(expected.task_index, expected.phase)) {
            phases_seen.push((expected.task_index, expected.phase));
        }

        // A kinematic plant: integrate the command, the base with a drive gain error (so both
        // compositions feed the same velocity error forward); the fingers close at 0.1 m/s onto
        // a 5 cm cube.
        base_velocity = BaseVelocity {
            v: expected.base.v * 1.05,
            omega: expected.base.omega * 0.97,
        };
        base.x += base_velocity.v * base.yaw.cos() * dt;
        base.y += base_velocity.v * base.yaw.sin() * dt;
        base.yaw = crate::types::wrap_angle(base.yaw + base_velocity.omega * dt);
        for (qi, v) in q.iter_mut().zip(&expected.arm_qd) {
            *qi += v * dt;
        }
        opening = match expected.gripper {
            GripperCommand::Open => (opening + 0.1 * dt).min(0.08),
            GripperCommand::Close => (opening - 0.1 * dt).max(0.05),
        };
    }
    assert_eq!(
        phases_seen,
        vec![
            (0, Phase::Reach),
            (0, Phase::Final),
            (1, Phase::Reach),
            (1, Phase::Final),
            (2, Phase::Complete)
        ],
        "the run must go through the whole mission and on after it"
    );
}

/// Perception with the camera at the tool, looking straight down from 0.5 m at the world
/// origin, sees a red square at the principal point.
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
