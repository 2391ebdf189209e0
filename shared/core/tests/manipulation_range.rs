//! Each robot's `manipulation_range`, recomputed from its model.
//!
//! Definition (ALGORITHMS.md §2, base controller): the horizontal distance from the arm base (the
//! axis of the first revolute arm joint) within which a top-down grasp at table height reaches
//! arm manipulability above the robot's `manipulability_threshold`. The grasp is searched by
//! damped-least-squares inverse kinematics on the tool position and approach axis (tool z pointing
//! straight down, free rotation about it), climbing manipulability in the null space of that task,
//! from several start configurations; the best converged grasp counts.
//!
//! Each robot's threshold is the same fraction of its arm's best top-down manipulability at table
//! height as Frankie's 0.08 (from the paper) is of the Panda's. Results (threshold; best top-down
//! manipulability; range): Frankie 0.08, 0.1239, 0.774 m; Fetch 0.28, 0.4335, 0.754 m;
//! Husky+UR5 0.0705, 0.1091, 0.833 m. The configs hold these ranges rounded to 1 cm.

mod common;

use motm_core::{BasePose, JointKind, JointLimits, Robot, manipulability_gradient};
use nalgebra::{DMatrix, DVector, Isometry3, Matrix6xX, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use common::{load, random_arm_q};

/// Height of the grasp point (the cube centre in the example scenario of DESIGN.md), m.
const TABLE_HEIGHT: f64 = 0.45;
/// Distance between the scanned targets, m; the edge is then refined by bisection to 1 mm.
const SCAN_STEP: f64 = 0.02;
/// Random start configurations tried per target, besides the ready pose and the neighbour's grasp.
const RANDOM_SEEDS: usize = 8;
/// Inverse-kinematics iterations per start configuration that also climb manipulability.
const CLIMB_ITERATIONS: usize = 400;
/// Final iterations on the task alone, to converge after the climb.
const SETTLE_ITERATIONS: usize = 60;
/// Damping of the least-squares step.
const DAMPING: f64 = 1e-3;
/// Gain of the manipulability ascent in the task's null space.
const NULL_SPACE_GAIN: f64 = 4.0;
/// Largest joint step per iteration, rad or m.
const MAX_STEP: f64 = 0.1;
/// A grasp counts when its tool point is this close to the target, m...
const POSITION_TOLERANCE: f64 = 1e-4;
/// ...and its approach axis this close to straight down, rad.
const ANGLE_TOLERANCE: f64 = 1e-3;

/// A converged top-down grasp.
#[derive(Clone)]
struct Grasp {
    arm_q: Vec<f64>,
    manipulability: f64,
}

/// World position of the first revolute arm joint with the base at the origin and the arm at `arm_q`.
fn arm_base(robot: &Robot, arm_q: &[f64]) -> Vector3<f64> {
    let q = robot.full_q(arm_q);
    let mut frame = Isometry3::identity();
    for (joint, &qi) in robot
        .chain
        .joints
        .iter()
        .zip(&q)
        .skip(motm_core::BASE_JOINTS)
    {
        frame *= joint.origin;
        if joint.kind == JointKind::Revolute {
            return frame.translation.vector;
        }
        frame *= joint.motion(qi);
    }
    panic!("{} has no revolute arm joint", robot.name());
}

/// The rotation vector that turns `from` onto straight down.
fn approach_error(from: &Vector3<f64>) -> Vector3<f64> {
    let down = -Vector3::z();
    let axis = from.cross(&down);
    let angle = from.dot(&down).clamp(-1.0, 1.0).acos();
    match axis.try_normalize(1e-12) {
        Some(axis) => axis * angle,
        None if angle < 1.0 => Vector3::zeros(),
        None => Vector3::x() * angle,
    }
}

/// One damped-least-squares step on the task rows vx, vy, vz, ωx, ωy (rotation about the vertical
/// approach axis is free), plus manipulability ascent in the task's null space when `climb`.
/// Joints at a limit that the step would push further are locked out of the step.
fn limited_step(
    jacobian: &Matrix6xX<f64>,
    error: &DVector<f64>,
    climb: bool,
    q: &[f64],
    limits: &[JointLimits],
) -> Option<DVector<f64>> {
    let n = q.len();
    let (_, gradient) = manipulability_gradient(jacobian);
    let mut locked = vec![false; n];
    loop {
        let task = DMatrix::from_fn(5, n, |r, c| if locked[c] { 0.0 } else { jacobian[(r, c)] });
        let damped = &task * task.transpose() + DMatrix::identity(5, 5) * DAMPING * DAMPING;
        let pseudo_inverse = task.transpose() * damped.try_inverse()?;
        let mut step = &pseudo_inverse * error;
        if climb {
            let free_gradient =
                DVector::from_fn(n, |c, _| if locked[c] { 0.0 } else { gradient[c] });
            let null_space = DMatrix::identity(n, n) - &pseudo_inverse * &task;
            step += null_space * free_gradient * NULL_SPACE_GAIN;
        }
        let mut newly_locked = false;
        for c in 0..n {
            let at_lower = q[c] <= limits[c].position_min && step[c] < 0.0;
            let at_upper = q[c] >= limits[c].position_max && step[c] > 0.0;
            if !locked[c] && (at_lower || at_upper) {
                locked[c] = true;
                newly_locked = true;
            }
        }
        if !newly_locked {
            return Some(step);
        }
    }
}

/// Searches a top-down grasp of `target` (world frame, base at the origin) from `seed`.
fn top_down_grasp(robot: &Robot, target: &Vector3<f64>, seed: &[f64]) -> Option<Grasp> {
    let limits: Vec<_> = robot.arm_joints().map(|j| j.limits).collect();
    let mut q = seed.to_vec();
    let mut converged = false;
    for iteration in 0..CLIMB_ITERATIONS + SETTLE_ITERATIONS {
        let fk = robot.forward(&BasePose::default(), &q);
        let jacobian = Robot::arm_jacobian(&fk.jacobian);
        let position_error = target - fk.tool_pose.translation.vector;
        let angle_error = approach_error(&(fk.tool_pose.rotation * Vector3::z()));
        converged =
            position_error.norm() < POSITION_TOLERANCE && angle_error.norm() < ANGLE_TOLERANCE;
        let error = DVector::from_column_slice(&[
            position_error.x,
            position_error.y,
            position_error.z,
            angle_error.x,
            angle_error.y,
        ]);
        let climb = iteration < CLIMB_ITERATIONS;
        let mut step = limited_step(&jacobian, &error, climb, &q, &limits)?;
        let largest = step.amax();
        if largest > MAX_STEP {
            step *= MAX_STEP / largest;
        }
        for ((qi, dq), l) in q.iter_mut().zip(step.iter()).zip(&limits) {
            *qi = (*qi + dq).clamp(l.position_min, l.position_max);
        }
    }
    converged.then(|| Grasp {
        manipulability: robot.manipulability(&q),
        arm_q: q,
    })
}

/// The best top-down grasp of `target` over the ready pose, `neighbour` and random seeds.
fn best_grasp(
    robot: &Robot,
    target: &Vector3<f64>,
    neighbour: Option<&Grasp>,
    rng: &mut ChaCha8Rng,
) -> Option<Grasp> {
    let mut seeds = vec![robot.config.ready_pose.clone()];
    seeds.extend(neighbour.map(|g| g.arm_q.clone()));
    seeds.extend((0..RANDOM_SEEDS).map(|_| random_arm_q(rng, robot)));
    seeds
        .iter()
        .filter_map(|seed| top_down_grasp(robot, target, seed))
        .max_by(|a, b| a.manipulability.total_cmp(&b.manipulability))
}

/// What the scan found for one robot.
struct RangeScan {
    /// Outer edge of the region where a top-down grasp has manipulability above the threshold, m.
    range: f64,
    /// Best top-down manipulability over all scanned distances.
    peak: f64,
}

/// Scans targets straight ahead of the arm base at table height for the robot's manipulation range.
fn scan(robot: &Robot, threshold: f64) -> RangeScan {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let base = arm_base(robot, &robot.config.ready_pose);
    let target = |r: f64| Vector3::new(base.x + r, base.y, TABLE_HEIGHT);
    let mut peak = 0.0_f64;
    let mut last_inside: Option<(f64, Grasp)> = None;
    let mut neighbour: Option<Grasp> = None;
    let mut r = SCAN_STEP;
    while r < 1.5 {
        let grasp = best_grasp(robot, &target(r), neighbour.as_ref(), &mut rng);
        if let Some(g) = &grasp {
            peak = peak.max(g.manipulability);
            if g.manipulability > threshold {
                last_inside = Some((r, g.clone()));
            }
        }
        neighbour = grasp;
        r += SCAN_STEP;
    }
    let (mut inside, grasp) = last_inside.expect("no grasp above the threshold at any distance");
    let mut outside = inside + SCAN_STEP;
    let mut seed = grasp;
    while outside - inside > 1e-3 {
        let middle = 0.5 * (inside + outside);
        match best_grasp(robot, &target(middle), Some(&seed), &mut rng) {
            Some(g) if g.manipulability > threshold => {
                inside = middle;
                seed = g;
            }
            _ => outside = middle,
        }
    }
    RangeScan {
        range: inside,
        peak,
    }
}

#[test]
fn manipulation_ranges_match_the_models() {
    let frankie = load("frankie");
    let frankie_scan = scan(&frankie, frankie.config.manipulability_threshold);
    let fraction = frankie.config.manipulability_threshold / frankie_scan.peak;
    let mut problems = Vec::new();
    for name in motm_core::ROBOT_NAMES {
        let robot = load(name);
        let threshold = robot.config.manipulability_threshold;
        let found = if name == "frankie" {
            RangeScan {
                range: frankie_scan.range,
                peak: frankie_scan.peak,
            }
        } else {
            scan(&robot, threshold)
        };
        println!(
            "{name}: threshold {threshold}, peak top-down manipulability {:.4} (threshold/peak {:.3}), range {:.3} m (config {})",
            found.peak,
            threshold / found.peak,
            found.range,
            robot.config.manipulation_range
        );
        if (found.range - robot.config.manipulation_range).abs() >= 0.01 {
            problems.push(format!(
                "{name}: manipulation range is {:.3} m, config says {}",
                found.range, robot.config.manipulation_range
            ));
        }
        if (threshold / found.peak - fraction).abs() >= 0.01 {
            problems.push(format!(
                "{name}: threshold {threshold} is {:.3} of the peak {:.4}; Frankie's is {fraction:.3}",
                threshold / found.peak,
                found.peak
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
