//! Representative redundancy-resolution problems for benchmarks and randomized tests.
//!
//! A scenario is a random arm configuration (away from the joint limits by
//! [`ScenarioConfig::limit_clearance`]) and a *reachable* tool twist `ν = J·q̇₀`, where `q̇₀` is a
//! random joint velocity within a fraction of the limits, so `J q̇ = ν` is feasible.

use nalgebra::{DVector, Matrix6xX};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::kinematics::{BasePose, manipulability_gradient};
use crate::resolver::{Facing, RedundancyResolver, ResolverInput, ResolverOutput, arm_base_frame};
use crate::robot::{BASE_JOINTS, Robot};
use crate::types::{BaseVelocity, Twist};

/// How random scenarios are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScenarioConfig {
    /// Distance kept from each arm joint's position limits, rad. 0.3.
    pub limit_clearance: f64,
    /// `q̇₀` is drawn within ± this fraction of each joint's velocity limit. 0.3.
    pub velocity_fraction: f64,
    /// Include a base velocity target (MotM) rather than none (holistic). true.
    pub base_tracking: bool,
}

impl Default for ScenarioConfig {
    fn default() -> Self {
        Self {
            limit_clearance: 0.3,
            velocity_fraction: 0.3,
            base_tracking: true,
        }
    }
}

/// One representative QP: all the data of a [`ResolverInput`], owned.
#[derive(Debug, Clone)]
pub struct QpScenario {
    /// Base pose the kinematics were computed at.
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: Vec<f64>,
    /// Full world Jacobian.
    pub jacobian: Matrix6xX<f64>,
    /// Reachable world twist.
    pub twist: Twist,
    /// The joint velocity that produces `twist` exactly (`twist = J·joint_velocity`).
    pub joint_velocity: DVector<f64>,
    /// Arm manipulability gradient.
    pub gradient: DVector<f64>,
    /// `e_t`, m.
    pub position_error: f64,
    /// Facing term (arm joint 1 toward the tool).
    pub facing: Facing,
    /// Base velocity target, when tracking.
    pub base_velocity_target: Option<BaseVelocity>,
}

impl QpScenario {
    /// Draws a random scenario for `robot`.
    pub fn random<R: Rng + ?Sized>(robot: &Robot, config: &ScenarioConfig, rng: &mut R) -> Self {
        let limits = robot.limits();
        let arm_q: Vec<f64> = limits[BASE_JOINTS..]
            .iter()
            .map(|l| {
                let lo = l.position_min + config.limit_clearance;
                let hi = l.position_max - config.limit_clearance;
                if lo < hi {
                    rng.random_range(lo..hi)
                } else {
                    0.5 * (l.position_min + l.position_max)
                }
            })
            .collect();
        let joint_velocity = DVector::from_iterator(
            limits.len(),
            limits.iter().map(|l| {
                let v = config.velocity_fraction * l.velocity;
                rng.random_range(-v..v)
            }),
        );
        let base = BasePose::new(
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
            rng.random_range(-3.0..3.0),
        );
        let position_error = rng.random_range(0.01..1.0);
        Self::at(
            robot,
            base,
            arm_q,
            joint_velocity,
            position_error,
            config.base_tracking,
        )
    }

    /// `count` random scenarios from a ChaCha8 generator seeded with `seed` (reproducible).
    pub fn random_set(
        robot: &Robot,
        config: &ScenarioConfig,
        count: usize,
        seed: u64,
    ) -> Vec<Self> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..count)
            .map(|_| Self::random(robot, config, &mut rng))
            .collect()
    }

    /// The scenario at a given state whose twist is produced by `joint_velocity`; the base
    /// target (when `base_tracking`) is the base part of `joint_velocity`.
    pub fn at(
        robot: &Robot,
        base: BasePose,
        arm_q: Vec<f64>,
        joint_velocity: DVector<f64>,
        position_error: f64,
        base_tracking: bool,
    ) -> Self {
        let fk = robot.forward(&base, &arm_q);
        let twist: Twist = (&fk.jacobian * &joint_velocity)
            .fixed_rows::<6>(0)
            .into_owned();
        let (_, gradient) = manipulability_gradient(&Robot::arm_jacobian(&fk.jacobian));
        let tool_in_arm_base = arm_base_frame(robot, &base)
            .inverse_transform_point(&fk.tool_pose.translation.vector.into())
            .coords;
        let base_velocity_target = base_tracking.then(|| BaseVelocity {
            v: joint_velocity[1],
            omega: joint_velocity[0],
        });
        Self {
            base,
            arm_q,
            jacobian: fk.jacobian,
            twist,
            joint_velocity,
            gradient,
            position_error,
            facing: Facing::ArmJoint1 { tool_in_arm_base },
            base_velocity_target,
        }
    }

    /// The whole MotM control step for this scenario's state: kinematics, manipulability
    /// gradient (Hessian), QP build and solve ([`RedundancyResolver::resolve_motm`]).
    pub fn control_step(&self, robot: &Robot, resolver: &mut RedundancyResolver) -> ResolverOutput {
        resolver.resolve_motm(
            robot,
            &self.base,
            &self.arm_q,
            self.twist,
            self.position_error,
            self.base_velocity_target,
        )
    }

    /// The resolver input for this scenario.
    pub fn input(&self) -> ResolverInput<'_> {
        ResolverInput {
            jacobian: &self.jacobian,
            twist: self.twist,
            arm_q: &self.arm_q,
            manipulability_gradient: &self.gradient,
            position_error: self.position_error,
            facing: self.facing,
            base_velocity_target: self.base_velocity_target,
        }
    }
}
