//! Closed-loop kinematic tests: the four MotM modules and the augmented QP drive an ideal
//! kinematic Frankie (joint and base velocities integrated exactly) through a pick and place,
//! while the base keeps driving. The base speed the QP commands must not drop below 80 % of v_F
//! during the grasp: that is the point of manipulation on-the-move.

use std::f64::consts::FRAC_PI_2;
use std::path::Path;

use motm_core::mission::{MissionTask, Phase, TaskKind};
use motm_core::on_the_move::{OnTheMove, OnTheMoveConfig, OnTheMoveInput};
use motm_core::{BasePose, BaseVelocity, GripperCommand, Robot, TargetEstimate};
use nalgebra::Vector3;

/// Control period of the test, s.
const DT: f64 = 0.005;
/// Commanded forward speed v_F, m/s.
const V_F: f64 = 0.3;
/// Finger opening when fully open, m.
const OPEN: f64 = 0.08;
/// Cube edge, m.
const CUBE: f64 = 0.03;
/// Finger speed, m/s (open to 30 mm in 0.5 s).
const FINGER_SPEED: f64 = 0.1;
/// Half-width of the container's opening, m.
const CONTAINER_HALF_WIDTH: f64 = 0.15;

fn frankie() -> Robot {
    Robot::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config"),
        "frankie",
    )
    .unwrap()
}

/// How a run ended.
#[derive(Debug)]
struct Run {
    picked: bool,
    placed_inside: bool,
    time: f64,
    min_base_speed_in_grasp: f64,
    grasp_cycles: usize,
    max_joint_excursion: f64,
}

/// Drives the ideal robot through pick at `cube` (moving at `cube_velocity`) and place at
/// `container`.
fn run(cube_start: Vector3<f64>, cube_velocity: Vector3<f64>, container: Vector3<f64>) -> Run {
    let robot = frankie();
    let mut config = OnTheMoveConfig::default();
    config.base.forward_speed = V_F;
    let tasks = vec![
        MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: cube_start,
        },
        MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: container,
        },
    ];
    let limits = robot.limits();
    let mut arm_q = robot.config.ready_pose.clone();
    let mut controller = OnTheMove::new(robot.clone(), config, tasks, Vector3::zeros());
    let mut base = BasePose::default();
    let mut base_velocity = BaseVelocity::default();
    let mut cube = cube_start;
    let mut opening = OPEN;
    let mut held = false;
    let mut released_at: Option<Vector3<f64>> = None;
    let mut result = Run {
        picked: false,
        placed_inside: false,
        time: 0.0,
        min_base_speed_in_grasp: f64::INFINITY,
        grasp_cycles: 0,
        max_joint_excursion: 0.0,
    };
    for k in 0..(40.0 / DT) as usize {
        let t = k as f64 * DT;
        let task = controller.mission().task_index();
        let target = if task == 0 {
            TargetEstimate {
                position: cube,
                velocity: if held {
                    Vector3::zeros()
                } else {
                    cube_velocity
                },
            }
        } else {
            TargetEstimate::fixed(container)
        };
        let out = controller.step(&OnTheMoveInput {
            t,
            dt: DT,
            base,
            base_velocity,
            arm_q: &arm_q,
            gripper_opening: opening,
            target,
        });
        assert!(out.base.v.is_finite() && out.base.omega.is_finite());
        assert!(
            out.arm_qd.iter().all(|v| v.is_finite()),
            "NaN joint velocity at t={t}"
        );
        if out.phase == Phase::Final && out.task_index == 0 {
            result.min_base_speed_in_grasp = result.min_base_speed_in_grasp.min(out.base.v);
            result.grasp_cycles += 1;
        }
        // Ideal kinematics.
        base.yaw += out.base.omega * DT;
        base.x += out.base.v * base.yaw.cos() * DT;
        base.y += out.base.v * base.yaw.sin() * DT;
        base_velocity = out.base;
        for (q, qd) in arm_q.iter_mut().zip(&out.arm_qd) {
            *q += qd * DT;
        }
        for (q, limit) in arm_q.iter().zip(&limits[2..]) {
            let excursion = (limit.position_min - q).max(q - limit.position_max);
            result.max_joint_excursion = result.max_joint_excursion.max(excursion);
        }
        // Gripper and cube.
        let tool = robot.tool_pose(&base, &arm_q);
        let cube_in_tool = tool.inverse_transform_point(&cube.into());
        match out.gripper {
            GripperCommand::Close if !held => {
                opening = (opening - FINGER_SPEED * DT).max(0.0);
                let between_fingers = cube_in_tool.x.abs() < 0.01
                    && cube_in_tool.y.abs() < (OPEN - CUBE) / 2.0
                    && cube_in_tool.z.abs() < 0.02;
                if opening <= CUBE && between_fingers && released_at.is_none() {
                    held = true;
                    opening = CUBE;
                }
            }
            GripperCommand::Open => {
                if held {
                    held = false;
                    released_at = Some(cube);
                }
                opening = (opening + FINGER_SPEED * DT).min(OPEN);
            }
            GripperCommand::Close => {}
        }
        if held {
            cube = tool.translation.vector;
            result.picked |= task == 1;
        } else if released_at.is_none() {
            cube += cube_velocity * DT;
        }
        if out.phase == Phase::Complete {
            result.time = t;
            break;
        }
    }
    if let Some(drop) = released_at {
        let offset = drop - container;
        result.placed_inside =
            offset.x.abs() < CONTAINER_HALF_WIDTH && offset.y.abs() < CONTAINER_HALF_WIDTH;
    }
    result
}

fn check(run: &Run) {
    eprintln!("{run:?}");
    assert!(run.picked, "cube not picked: {run:?}");
    assert!(
        run.placed_inside,
        "cube not dropped into the container: {run:?}"
    );
    assert!(run.grasp_cycles > 10, "no grasp phase seen: {run:?}");
    assert!(
        run.min_base_speed_in_grasp >= 0.8 * V_F,
        "base slowed to {:.3} m/s during the grasp (v_F {V_F}): {run:?}",
        run.min_base_speed_in_grasp
    );
    assert!(
        run.max_joint_excursion <= 1e-6,
        "a joint left its limits: {run:?}"
    );
}

#[test]
fn picks_a_static_cube_on_the_move_and_drops_it_into_the_container() {
    let run = run(
        Vector3::new(2.0, 0.6, 0.45),
        Vector3::zeros(),
        Vector3::new(3.6, 1.6, 0.35),
    );
    check(&run);
    assert!(run.time < 15.0, "took {:.1} s", run.time);
}

#[test]
fn picks_a_moving_cube_on_the_move() {
    let velocity = Vector3::new(FRAC_PI_2.cos(), FRAC_PI_2.sin(), 0.0) * 0.03;
    let run = run(
        Vector3::new(2.0, 0.5, 0.45),
        velocity,
        Vector3::new(3.6, 1.6, 0.35),
    );
    check(&run);
}
