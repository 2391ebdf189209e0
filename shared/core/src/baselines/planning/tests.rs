//! Tests of the planning baseline on Frankie and the paper's Exp-1 layout.

use std::path::Path;
use std::sync::OnceLock;

use nalgebra::{Isometry3, Translation3, Vector2, Vector3};

use super::*;
use crate::types::{BaseVelocity, GripperCommand, RobotState, TaskProgress};

/// Solver feasibility tolerance on the convex (exactly modelled) constraints.
const SOLVER_TOLERANCE: f64 = 1e-5;
/// Allowed error of the heading-linearised constraints measured with the true heading, m.
const LINEARISATION_TOLERANCE: f64 = 5e-3;

fn frankie() -> &'static Robot {
    static ROBOT: OnceLock<Robot> = OnceLock::new();
    ROBOT.get_or_init(|| {
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&config, "frankie").expect("frankie model")
    })
}

/// The paper's Exp-1 layout at 0.3 m/s from a standing start at the origin, heading +x.
fn exp1_request() -> PlanRequest {
    PlanRequest {
        start_base: BasePose::new(0.0, 0.0, 0.0),
        start_base_speed: 0.0,
        cube: Vector3::new(2.0, 0.6, 0.45),
        container: Vector3::new(3.6, 1.6, 0.35),
        base_speed: 0.3,
    }
}

fn exp1_plan() -> &'static Plan {
    static PLAN: OnceLock<Plan> = OnceLock::new();
    PLAN.get_or_init(|| plan(frankie(), &exp1_request(), &PlanningConfig::default()).unwrap())
}

fn targets(request: &PlanRequest) -> [Vector2<f64>; 2] {
    [request.cube.xy(), request.container.xy()]
}

#[test]
fn exp1_plan_meets_its_constraints_at_every_knot() {
    let plan = exp1_plan();
    let request = exp1_request();
    let config = PlanningConfig::default();
    let geometry = RobotGeometry::from_robot(frankie());
    let report = plan.constraint_report(&geometry, &targets(&request));
    eprintln!(
        "Exp-1 plan: grasp {:.2} s, drop {:.2} s, finish {:.2} s, {} knots, {} passes \
         (converged {}), {} iterations, solve {:.1} ms, status {:?}",
        plan.grasp_time(),
        plan.drop_time(),
        plan.finish_time(),
        plan.knots(),
        plan.passes,
        plan.converged,
        plan.iterations,
        plan.solve_time.as_secs_f64() * 1e3,
        plan.status,
    );
    eprintln!("{report:#?}");
    assert_meets_constraints(plan, &request, &config);
}

#[test]
fn exp1_plan_starts_at_the_start_state_and_ends_at_rest() {
    let plan = exp1_plan();
    let request = exp1_request();
    let geometry = RobotGeometry::from_robot(frankie());
    let start_tool = geometry.ready_tool_position(&request.start_base);
    assert!((plan.base[0].x - request.start_base.x).abs() < 1e-6);
    assert!((plan.base[0].y - request.start_base.y).abs() < 1e-6);
    assert!((plan.base[0].yaw - request.start_base.yaw).abs() < 1e-9);
    assert!(plan.base_velocity[0].norm() < 1e-6);
    assert!((plan.gripper[0] - start_tool).norm() < 1e-6);
    assert!(plan.gripper_velocity[0].norm() < 1e-6);
    let last = plan.knots() - 1;
    assert!(plan.base_velocity[last].norm() < 1e-6);
    assert!(plan.gripper_velocity[last].norm() < 1e-6);
    // The base actually travels: it ends beyond the cube.
    assert!(plan.base[last].x > request.cube.x);
}

#[test]
fn exp1_plan_holds_the_grasp_and_drop_positions_at_their_knots() {
    let plan = exp1_plan();
    let request = exp1_request();
    let config = PlanningConfig::default();
    assert_eq!(plan.grasp_position, request.cube);
    for k in plan.grasp_knot..=plan.grasp_end_knot {
        assert!((plan.gripper[k] - request.cube).norm() < 1e-6, "knot {k}");
        assert!(plan.gripper_velocity[k].norm() < 1e-6, "knot {k}");
    }
    let drop = request.container + Vector3::z() * config.drop_height;
    for k in plan.drop_knot..=plan.drop_end_knot {
        assert!((plan.gripper[k] - drop).norm() < 1e-6, "knot {k}");
        assert!(plan.gripper_velocity[k].norm() < 1e-6, "knot {k}");
    }
    // The dwell windows last at least as long as configured.
    assert!(plan.grasp_end_time() - plan.grasp_time() >= config.grasp_dwell - 1e-9);
    assert!(plan.drop_end_time() - plan.drop_time() >= config.drop_dwell - 1e-9);
    // Approach from above and lift.
    let approach =
        plan.grasp_knot - (config.approach_time / config.knot_spacing - 1e-9).ceil() as usize;
    assert!(plan.gripper[approach].z >= request.cube.z + config.approach_height - 1e-6);
    for k in approach..plan.grasp_knot {
        assert!(plan.gripper[k].z >= request.cube.z - 1e-6);
    }
    // Before the grasp, the base could not have reached the cube faster at v_F.
    let geometry = RobotGeometry::from_robot(frankie());
    let lower_bound =
        (request.cube.xy().norm() - geometry.manipulation_range - geometry.mount_offset.norm())
            / request.base_speed;
    assert!(plan.grasp_time() >= lower_bound);
    assert!(plan.drop_time() > plan.grasp_end_time());
}

#[test]
fn exp1_tracking_an_ideal_robot_follows_the_plan() {
    let robot = frankie();
    let config = PlanningConfig::default();
    let controller = PlanningController::new(exp1_plan().clone(), robot, &config.tracking);
    let plan = controller.plan();
    // Start 5 cm off to the side: the tracker must pull the base back onto the plan.
    let mut base = BasePose::new(0.0, 0.05, 0.0);
    let start = robot.tool_pose(&base, &robot.config.ready_pose);
    let mut tool =
        Isometry3::from_parts(Translation3::from(start.translation.vector), start.rotation);
    let dt = 0.01;
    let steps = (plan.finish_time() / dt).ceil() as usize + 10;
    let mut worst_gripper_error_at_grasp: f64 = 0.0;
    let mut closed_at = None;
    let mut opened_at = None;
    let mut last = None;
    for i in 0..steps {
        let t = i as f64 * dt;
        let state = RobotState {
            base,
            base_velocity: Default::default(),
            arm_q: robot.config.ready_pose.clone(),
            tool_pose: tool,
        };
        let command = controller.step(t, &state);
        assert!(command.state_valid);
        assert!(command.gripper_twist.iter().all(|v| v.is_finite()));
        if command.gripper == GripperCommand::Close && closed_at.is_none() {
            closed_at = Some(t);
        }
        if closed_at.is_some() && command.gripper == GripperCommand::Open && opened_at.is_none() {
            opened_at = Some(t);
        }
        if command.phase == PlanPhase::Grasp {
            worst_gripper_error_at_grasp = worst_gripper_error_at_grasp
                .max((tool.translation.vector - plan.grasp_position).norm());
        }
        // Ideal kinematic robot: rotate, then translate along the new heading.
        base.yaw += command.base.omega * dt;
        base.x += command.base.v * dt * base.yaw.cos();
        base.y += command.base.v * dt * base.yaw.sin();
        let twist = command.gripper_twist;
        tool.translation.vector += Vector3::new(twist[0], twist[1], twist[2]) * dt;
        tool.rotation = nalgebra::UnitQuaternion::from_scaled_axis(
            Vector3::new(twist[3], twist[4], twist[5]) * dt,
        ) * tool.rotation;
        last = Some(command);
    }
    let end = plan.base[plan.knots() - 1];
    eprintln!(
        "tracking: worst gripper error during the grasp {:.4} m, base end error {:.4} m",
        worst_gripper_error_at_grasp,
        Vector2::new(base.x - end.x, base.y - end.y).norm()
    );
    assert!(worst_gripper_error_at_grasp < 0.01);
    assert!(Vector2::new(base.x - end.x, base.y - end.y).norm() < 0.02);
    assert!((closed_at.unwrap() - plan.grasp_time()).abs() <= dt + 1e-9);
    assert!((opened_at.unwrap() - plan.drop_time()).abs() <= dt + 1e-9);
    assert_eq!(last.unwrap().progress, TaskProgress::Done);
}

#[test]
fn tracker_gives_zero_velocities_for_a_non_finite_state() {
    let robot = frankie();
    let controller = PlanningController::new(
        exp1_plan().clone(),
        robot,
        &PlanningConfig::default().tracking,
    );
    let mut state = RobotState {
        base: BasePose::new(f64::NAN, 0.0, 0.0),
        base_velocity: Default::default(),
        arm_q: robot.config.ready_pose.clone(),
        tool_pose: robot.tool_pose(&BasePose::default(), &robot.config.ready_pose),
    };
    let command = controller.step(1.0, &state);
    assert!(!command.state_valid);
    assert_eq!(command.base, BaseVelocity::default());
    assert_eq!(command.gripper_twist, crate::types::Twist::zeros());
    state.base.x = 0.0;
    let command = controller.step(f64::INFINITY, &state);
    assert!(!command.state_valid);
    assert_eq!(command.gripper_twist, crate::types::Twist::zeros());
    assert!(controller.step(1.0, &state).state_valid);
}

#[test]
fn sampling_between_knots_is_consistent_with_the_knots() {
    let plan = exp1_plan();
    for k in [0, 7, plan.grasp_knot, plan.knots() - 1] {
        let sample = plan.sample(plan.knot_times[k]);
        assert!((sample.gripper - plan.gripper[k]).norm() < 1e-9);
        assert!((sample.base.x - plan.base[k].x).abs() < 1e-9);
    }
    // Velocity is the derivative of position between knots.
    let t = 3.0 * plan.knot_spacing + 0.37 * plan.knot_spacing;
    let dt = 1e-6;
    let (a, b) = (plan.sample(t - dt), plan.sample(t + dt));
    let numeric = (b.gripper - a.gripper) / (2.0 * dt);
    assert!((numeric - plan.sample(t).gripper_velocity).norm() < 1e-6);
}

#[test]
fn moving_start_and_single_pass_also_plan() {
    let request = PlanRequest {
        start_base_speed: 0.3,
        ..exp1_request()
    };
    let config = PlanningConfig {
        max_passes: 1,
        ..PlanningConfig::default()
    };
    let plan = plan(frankie(), &request, &config).unwrap();
    assert_eq!(plan.passes, 1);
    assert!((plan.base_velocity[0] - Vector2::new(0.3, 0.0)).norm() < 1e-6);
    assert!((plan.gripper[plan.grasp_knot] - request.cube).norm() < 1e-6);
    // Starting at speed, the grasp comes no later than from a standing start.
    assert!(plan.grasp_time() <= exp1_plan().grasp_time());
}

#[test]
fn unreachable_cube_is_a_clear_infeasibility_error() {
    let request = PlanRequest {
        cube: Vector3::new(2.0, 0.6, 2.5),
        ..exp1_request()
    };
    match plan(frankie(), &request, &PlanningConfig::default()) {
        Err(PlanningError::Infeasible(message)) => {
            assert!(message.contains("cannot be reached"), "{message}");
        }
        other => panic!("expected an infeasibility error, got {other:?}"),
    }
}

#[test]
fn bad_requests_and_configs_name_the_field() {
    let robot = frankie();
    let config = PlanningConfig::default();
    let cases = [
        (
            PlanRequest {
                base_speed: 0.0,
                ..exp1_request()
            },
            "base_speed",
        ),
        (
            PlanRequest {
                base_speed: 5.0,
                ..exp1_request()
            },
            "base_speed",
        ),
        (
            PlanRequest {
                cube: Vector3::new(f64::NAN, 0.0, 0.4),
                ..exp1_request()
            },
            "cube",
        ),
        (
            PlanRequest {
                start_base_speed: -0.1,
                ..exp1_request()
            },
            "start_base_speed",
        ),
    ];
    for (request, field) in cases {
        match plan(robot, &request, &config) {
            Err(PlanningError::Request { field: f, .. }) => assert_eq!(f, field),
            other => panic!("expected a request error on {field}, got {other:?}"),
        }
    }
    let bad = PlanningConfig {
        knot_spacing: -0.1,
        ..PlanningConfig::default()
    };
    match plan(robot, &exp1_request(), &bad) {
        Err(PlanningError::Config { key, .. }) => assert_eq!(key, "knot_spacing"),
        other => panic!("expected a config error, got {other:?}"),
    }
}

#[test]
fn config_reads_from_toml_and_rejects_unknown_keys() {
    let config: PlanningConfig =
        toml::from_str("knot_spacing = 0.05\n[tracking]\ngripper_position_gain = 3.0\n").unwrap();
    assert_eq!(config.knot_spacing, 0.05);
    assert_eq!(config.tracking.gripper_position_gain, 3.0);
    assert_eq!(config.max_passes, PlanningConfig::default().max_passes);
    assert!(toml::from_str::<PlanningConfig>("knot_spcing = 0.05").is_err());
}

/// Asserts that `plan` meets every constraint of `config` at every knot, measured with the true
/// base heading.
fn assert_meets_constraints(plan: &Plan, request: &PlanRequest, config: &PlanningConfig) {
    let geometry = RobotGeometry::from_robot(frankie());
    let report = plan.constraint_report(&geometry, &targets(request));
    assert!(plan.converged, "the heading linearisation settles");
    assert_eq!(plan.status, SolveStatus::Solved);
    assert!(report.max_base_speed <= request.base_speed + SOLVER_TOLERANCE);
    assert!(report.max_base_acceleration <= geometry.base_acceleration + SOLVER_TOLERANCE);
    assert!(report.max_gripper_speed <= config.max_gripper_speed + SOLVER_TOLERANCE);
    assert!(report.max_gripper_acceleration <= config.max_gripper_acceleration + SOLVER_TOLERANCE);
    assert!(report.min_gripper_height >= config.min_gripper_height - SOLVER_TOLERANCE);
    // The clearance half-spaces are conservative: the true distance holds exactly.
    assert!(report.min_target_clearance >= config.target_clearance - SOLVER_TOLERANCE);
    // Heading-dependent constraints, measured with the true heading.
    assert!(report.max_horizontal_reach <= geometry.manipulation_range + LINEARISATION_TOLERANCE);
    assert!(report.max_reach <= config.max_reach + LINEARISATION_TOLERANCE);
    assert!(report.min_forward_reach >= config.min_forward_reach - LINEARISATION_TOLERANCE);
    assert!(
        report.min_forward_speed >= -SOLVER_TOLERANCE,
        "the base never reverses"
    );
    assert!(
        report.max_yaw_rate <= 1.05 * config.max_yaw_rate.min(geometry.yaw_rate_limit),
        "yaw rate {} above the planned limit {}",
        report.max_yaw_rate,
        config.max_yaw_rate
    );
}

#[test]
fn mirrored_layout_with_a_turned_start_also_meets_its_constraints() {
    let request = PlanRequest {
        start_base: BasePose::new(0.5, 0.2, -0.3),
        start_base_speed: 0.1,
        cube: Vector3::new(2.4, -0.8, 0.45),
        container: Vector3::new(4.0, -1.8, 0.35),
        base_speed: 0.4,
    };
    let config = PlanningConfig::default();
    let plan = plan(frankie(), &request, &config).unwrap();
    assert_meets_constraints(&plan, &request, &config);
    assert!((plan.gripper[plan.grasp_knot] - request.cube).norm() < 1e-6);
    let drop = request.container + Vector3::z() * config.drop_height;
    assert!((plan.gripper[plan.drop_knot] - drop).norm() < 1e-6);
}
