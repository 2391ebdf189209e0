//! The manipulation range of a mobile manipulator, derived from its kinematic model.
//!
//! The paper counts a target as within manipulation range when the arm's manipulability on
//! arriving there is above a threshold (0.08 for Frankie, about 0.75 m for its targets). This
//! module turns that definition into a number: for top-down grasps at a given height it finds the
//! largest horizontal distance from the arm base at which the arm can be placed with
//! manipulability at or above the threshold.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6xX, Vector3};

use crate::chain::{JointKind, JointLimits};
use crate::kinematics::{BasePose, manipulability, manipulability_gradient};
use crate::robot::{BASE_JOINTS, Robot};

/// Position of the arm base (the frame of the first arm joint, with the base joints at zero)
/// in the base frame.
pub fn arm_base_in_base_frame(robot: &Robot) -> Vector3<f64> {
    robot.chain.joints[..=BASE_JOINTS]
        .iter()
        .fold(Isometry3::identity(), |frame, joint| frame * joint.origin)
        .translation
        .vector
}

/// Settings of the numeric search in [`derive_manipulation_range_with`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeSearch {
    /// First horizontal distance tried, m.
    pub start: f64,
    /// Last horizontal distance tried, m.
    pub end: f64,
    /// Grid spacing, m; the last grid point that passes is then refined by bisection.
    pub step: f64,
    /// Bisection rounds after the grid scan.
    pub refinements: usize,
    /// Damped-least-squares iterations per start configuration that also climb manipulability
    /// in the null space of the grasp task.
    pub iterations: usize,
    /// Final iterations on the grasp task alone, so the climb does not leave a residual.
    pub settle_iterations: usize,
    /// Spread start configurations tried per distance, besides the ready pose and the solution
    /// at the previous distance (the climb only finds the best pose of its own IK branch).
    pub spread_seeds: usize,
    /// Largest acceptable IK residual (position in m, tool-axis error in rad).
    pub tolerance: f64,
}

impl Default for RangeSearch {
    fn default() -> Self {
        Self {
            start: 0.1,
            end: 1.5,
            step: 0.02,
            refinements: 6,
            iterations: 400,
            settle_iterations: 60,
            spread_seeds: 8,
            tolerance: 1e-4,
        }
    }
}

/// Damping of the least-squares step.
const DAMPING: f64 = 1e-3;
/// Gain of the manipulability ascent in the null space of the grasp task.
const NULL_SPACE_GAIN: f64 = 4.0;
/// Largest joint step per iteration, rad or m.
const MAX_STEP: f64 = 0.1;

/// The largest horizontal distance from the arm base at which a top-down grasp with the tool
/// point at world height `grasp_height` reaches manipulability of at least `threshold`, m.
///
/// The base sits at the origin with the base joints at zero; the grasp point lies straight ahead
/// of the arm base (by the symmetry of the first arm joint, the direction does not matter while
/// that joint is inside its limits). "Top-down" fixes the tool z axis to point down; the tool's
/// yaw and the arm's remaining redundancy are free, and are used to maximise manipulability, so
/// the result is the best the arm can do at each distance (the resolver QP also climbs the
/// manipulability gradient). Returns 0 if no distance of the search passes.
pub fn derive_manipulation_range(robot: &Robot, threshold: f64, grasp_height: f64) -> f64 {
    derive_manipulation_range_with(robot, threshold, grasp_height, &RangeSearch::default())
}

/// [`derive_manipulation_range`] with explicit search settings.
pub fn derive_manipulation_range_with(
    robot: &Robot,
    threshold: f64,
    grasp_height: f64,
    search: &RangeSearch,
) -> f64 {
    let mut previous: Option<TopDownGrasp> = None;
    let mut best: Option<(f64, TopDownGrasp)> = None;
    let steps = ((search.end - search.start) / search.step).floor() as usize;
    for k in 0..=steps {
        let distance = search.start + k as f64 * search.step;
        let seed = previous.as_ref().map(|g| g.arm_q.as_slice());
        let grasp = best_top_down_grasp(robot, distance, grasp_height, seed, search);
        if let Some(g) = grasp.as_ref().filter(|g| g.manipulability >= threshold) {
            best = Some((distance, g.clone()));
        }
        previous = grasp;
    }
    let Some((mut passing, mut passing_grasp)) = best else {
        return 0.0;
    };
    let mut failing = passing + search.step;
    for _ in 0..search.refinements {
        let middle = 0.5 * (passing + failing);
        let seed = Some(passing_grasp.arm_q.as_slice());
        match best_top_down_grasp(robot, middle, grasp_height, seed, search) {
            Some(g) if g.manipulability >= threshold => {
                passing = middle;
                passing_grasp = g;
            }
            _ => failing = middle,
        }
    }
    passing
}

/// A converged top-down grasp found by [`best_top_down_grasp`].
#[derive(Debug, Clone, PartialEq)]
pub struct TopDownGrasp {
    /// Arm joint positions.
    pub arm_q: Vec<f64>,
    /// Arm manipulability at `arm_q`.
    pub manipulability: f64,
}

/// The best top-down grasp found for a grasp point `distance` ahead of the arm base at world
/// height `height`, over start configurations: the ready pose, `seed` (e.g. the solution at a
/// neighbouring distance) and `search.spread_seeds` configurations spread over the joint limits.
/// `None` if no start converges.
pub fn best_top_down_grasp(
    robot: &Robot,
    distance: f64,
    height: f64,
    seed: Option<&[f64]>,
    search: &RangeSearch,
) -> Option<TopDownGrasp> {
    let arm_base = arm_base_in_base_frame(robot);
    let goal = Vector3::new(arm_base.x + distance, arm_base.y, height);
    let mut starts = vec![robot.config.ready_pose.clone()];
    starts.extend(seed.map(<[f64]>::to_vec));
    starts.extend((1..=search.spread_seeds).map(|k| spread_configuration(robot, k)));
    starts
        .iter()
        .filter_map(|start| top_down_grasp_from(robot, &goal, start, search))
        .max_by(|a, b| a.manipulability.total_cmp(&b.manipulability))
}

/// The `k`-th configuration of a Halton sequence over the arm's joint ranges (unlimited joints:
/// one turn, or ±1 m).
fn spread_configuration(robot: &Robot, k: usize) -> Vec<f64> {
    const PRIMES: [usize; 12] = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37];
    robot
        .arm_joints()
        .enumerate()
        .map(|(i, joint)| {
            let base = PRIMES[i % PRIMES.len()];
            let (mut fraction, mut scale, mut n) = (0.0, 1.0, k);
            while n > 0 {
                scale /= base as f64;
                fraction += scale * (n % base) as f64;
                n /= base;
            }
            let unbounded = match joint.kind {
                JointKind::Revolute => std::f64::consts::PI,
                JointKind::Prismatic => 1.0,
            };
            let lower = joint.limits.position_min.max(-unbounded);
            let upper = joint.limits.position_max.min(unbounded);
            lower + fraction * (upper - lower)
        })
        .collect()
}

/// The rotation vector that turns `axis` onto straight down.
fn approach_error(axis: &Vector3<f64>) -> Vector3<f64> {
    let down = -Vector3::z();
    let angle = axis.dot(&down).clamp(-1.0, 1.0).acos();
    match axis.cross(&down).try_normalize(1e-12) {
        Some(rotation_axis) => rotation_axis * angle,
        None if angle < 1.0 => Vector3::zeros(),
        None => Vector3::x() * angle,
    }
}

/// Damped-least-squares IK from `start` for the tool point at `goal` with the tool z axis down,
/// climbing manipulability in the task's null space, then settling on the task alone.
fn top_down_grasp_from(
    robot: &Robot,
    goal: &Vector3<f64>,
    start: &[f64],
    search: &RangeSearch,
) -> Option<TopDownGrasp> {
    let limits: Vec<_> = robot.arm_joints().map(|j| j.limits).collect();
    let mut q = start.to_vec();
    let mut residual = f64::INFINITY;
    for iteration in 0..search.iterations + search.settle_iterations {
        let fk = robot.forward(&BasePose::default(), &q);
        let arm = Robot::arm_jacobian(&fk.jacobian);
        let position_error = goal - fk.tool_pose.translation.vector;
        let axis_error = approach_error(&(fk.tool_pose.rotation * Vector3::z()));
        residual = position_error.norm().max(axis_error.norm());
        // Task: tool point at the goal (3 rows) and tool z along −z (world x and y rotation rows).
        let error = DVector::from_column_slice(&[
            position_error.x,
            position_error.y,
            position_error.z,
            axis_error.x,
            axis_error.y,
        ]);
        let climb = iteration < search.iterations;
        let mut step = limited_step(&arm, &error, climb, &q, &limits)?;
        let largest = step.amax();
        if largest > MAX_STEP {
            step *= MAX_STEP / largest;
        }
        for ((qi, dq), l) in q.iter_mut().zip(step.iter()).zip(&limits) {
            *qi = (*qi + dq).clamp(l.position_min, l.position_max);
        }
    }
    (residual <= search.tolerance).then(|| TopDownGrasp {
        manipulability: manipulability(&Robot::arm_jacobian(
            &robot.forward(&BasePose::default(), &q).jacobian,
        )),
        arm_q: q,
    })
}

/// One damped-least-squares step on the task rows vx, vy, vz, ωx, ωy (rotation about the vertical
/// approach axis is free), plus manipulability ascent in the task's null space when `climb`.
/// Joints at a limit that the step would push further are locked out of the step, so the other
/// joints take over their share of the task.
fn limited_step(
    arm_jacobian: &Matrix6xX<f64>,
    error: &DVector<f64>,
    climb: bool,
    q: &[f64],
    limits: &[JointLimits],
) -> Option<DVector<f64>> {
    let n = q.len();
    let (_, gradient) = manipulability_gradient(arm_jacobian);
    let mut locked = vec![false; n];
    loop {
        let task = DMatrix::from_fn(
            5,
            n,
            |r, c| {
                if locked[c] { 0.0 } else { arm_jacobian[(r, c)] }
            },
        );
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
            let pushes_below = q[c] <= limits[c].position_min && step[c] < 0.0;
            let pushes_above = q[c] >= limits[c].position_max && step[c] > 0.0;
            if !locked[c] && (pushes_below || pushes_above) {
                locked[c] = true;
                newly_locked = true;
            }
        }
        if !newly_locked {
            return Some(step);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn frankie() -> Robot {
        let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&config_dir, "frankie").expect("frankie loads")
    }

    #[test]
    fn frankie_arm_base_is_on_the_mount() {
        let arm_base = arm_base_in_base_frame(&frankie());
        assert!((arm_base - Vector3::new(0.15, 0.0, 0.38 + 0.333)).norm() < 1e-9);
    }

    /// The configured `manipulation_range` of Frankie (0.75 m, the paper's figure) must agree
    /// with the model: top-down grasps of the 30 mm cube (centre 0.45 m above the floor, as in
    /// the scenarios) with manipulability ≥ 0.08. Tolerance: ±0.05 m, i.e. a few cube widths.
    #[test]
    fn frankie_derived_range_agrees_with_the_configured_one() {
        let robot = frankie();
        let derived = derive_manipulation_range(&robot, 0.08, 0.45);
        eprintln!("derived Frankie manipulation range: {derived:.3} m");
        assert!(
            (derived - robot.config.manipulation_range).abs() <= 0.05,
            "derived {derived:.3} m, configured {} m",
            robot.config.manipulation_range
        );
    }

    #[test]
    fn a_higher_threshold_gives_a_shorter_range() {
        let robot = frankie();
        let search = RangeSearch {
            step: 0.05,
            refinements: 3,
            iterations: 200,
            ..RangeSearch::default()
        };
        let loose = derive_manipulation_range_with(&robot, 0.05, 0.45, &search);
        let strict = derive_manipulation_range_with(&robot, 0.09, 0.45, &search);
        assert!(strict < loose, "strict {strict:.3} m, loose {loose:.3} m");
        assert!(strict > 0.0);
    }
}
