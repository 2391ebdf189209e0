//! Arm/base redundancy resolution: the holistic QP of Haviland et al. (RA-L 2022), augmented for
//! manipulation on-the-move, solved with `clarabel`.
//!
//! # Problem
//!
//! Decision variable `x = [q̇ (n joints: base ω, base v, then the arm); δ (6 slacks)]`, so
//! 9 + 6 = 15 variables for Frankie. Minimise `½ xᵀ P x + cᵀ x` subject to:
//!
//! - **equality** `J q̇ + δ = ν` (the desired tool twist, met exactly while `δ = 0` is feasible);
//! - **bounds** per joint: `lower ≤ q̇ ≤ upper`, the intersection of
//!   - the joint velocity limit less libfranka's margins (see [`ResolverConfig::velocity_margin`]
//!     and [`ResolverConfig::acceleration_margin_time`]) for arm joints, the model's limit for the
//!     base joints, and
//!   - the joint-limit velocity damper: within the influence distance `π` of a position limit,
//!     `q̇ ≥ −(q − q_min − p_s)/(π − p_s)` (and the mirror at `q_max`);
//! - **bounds** on the slacks: `|δ| ≤ slack_bound`.
//!
//! Objective (with `e_t` = L1 norm of the tool translation error, at least
//! [`ResolverConfig::min_position_error`]):
//!
//! - `P = diag(Y/e_t for the base joints, Y for the arm joints, 1/e_t for the slacks)`;
//! - `c = −k_m · ∇m` on the arm joints (manipulability gradient);
//! - an optional facing term ([`Facing`]);
//! - optional **soft base-velocity tracking**: rows `q̇_ω − s_ω = ω*`, `q̇_v − s_v = v*` with slack
//!   cost `½ W s²`. The slacks are eliminated analytically (`s = q̇ − target`), which adds `W` to
//!   the base entries of `P` and `−W·target` to `c`: the same optimum as explicit slack
//!   variables, with two fewer variables and a fixed sparsity pattern.
//! - **held joints** (`Robot::held_joints`, Fetch's torso lift): the same soft row, at the same
//!   weight, for `q̇_j = clamp(q_ready − q, ±limit)` (a 1 s servo to the ready position), and
//!   no damper on them.
//!
//! The solver is built once with a fixed sparsity pattern (`P` diagonal; `A` = the dense 6×n
//! Jacobian block, the identity on the slacks, and ±1 bound rows), then only the numbers change
//! between cycles via `update_P`, `update_q`, `update_A` and `update_b` (presolve and dropping
//! of structural zeros are off, as data updates require).
//!
//! # Failure
//!
//! Non-finite or mis-sized input, a failed data update, a solver status other than
//! solved/almost-solved, or a non-finite solution all give the **all-zero command** and increment
//! [`RedundancyResolver::error_count`]: never NaN, never the previous command.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use nalgebra::{DVector, Matrix6xX, Vector3, Vector6};
use serde::Deserialize;

use crate::chain::JointLimits;
use crate::facing::FacingJoint;
use crate::robot::{BASE_JOINTS, Robot};
use crate::types::{BaseVelocity, Twist, wrap_angle};

/// Number of slack variables (one per twist component).
pub const SLACKS: usize = 6;
/// Rate, 1/s, at which a held arm joint is servoed back to its ready position (within its
/// velocity limit): a time constant of a second, well inside Fetch's torso speed of 0.1 m/s.
const HELD_JOINT_GAIN: f64 = 1.0;
/// Index of the base yaw-rate variable ω.
const BASE_OMEGA: usize = 0;
/// Index of the base forward-speed variable v.
const BASE_V: usize = 1;

/// Gains and limits of the redundancy-resolution QP. Every field has a default; unknown TOML
/// keys are errors.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ResolverConfig {
    /// `Y`: quadratic weight on joint velocities (the base joints get `Y/e_t`). Holistic: 0.01.
    pub joint_velocity_weight: f64,
    /// Lower clamp on `e_t`, m, so the `1/e_t` weights stay finite. 1e-3.
    pub min_position_error: f64,
    /// `k_m`: gain on the manipulability gradient in the linear cost. Holistic: 1.
    pub manipulability_gain: f64,
    /// The manipulability threshold `k_m` is tuned for, 0.08 (the Panda's, the paper's). A
    /// resolver made for a robot ([`RedundancyResolver::for_robot`]) scales the gradient term by
    /// this over the robot's own `manipulability_threshold`, so an arm whose manipulability is
    /// several times the Panda's (Fetch: threshold 0.28) is not pulled toward its most
    /// manipulable pose several times harder than it follows the tool twist. Frankie's scale is
    /// exactly 1.
    pub manipulability_reference_threshold: f64,
    /// `k_ε`: gain of the facing term ([`Facing`]). 0.5.
    pub facing_gain: f64,
    /// `W`: weight of the soft base-velocity tracking rows. Chosen 1e4: ten times the largest
    /// slack weight `1/e_t` (1000 at the `e_t` floor) and far above the base joint weight
    /// `Y/e_t`, so the base follows the base controller and the arm (then the slack) absorbs
    /// the tool twist, as the paper's base velocity is "controlled directly".
    pub base_tracking_weight: f64,
    /// `p_s`: damper stop distance, rad (or m for prismatic joints). 0.1.
    pub damper_stop_distance: f64,
    /// `π`: damper influence distance; the damper acts within this distance of a limit. 0.9.
    pub damper_influence_distance: f64,
    /// Bound on each slack variable. 10.
    pub slack_bound: f64,
    /// libfranka's `kLimitEps`: subtracted from every arm joint velocity limit. 1e-3.
    pub velocity_margin: f64,
    /// libfranka's `kTolNumberPacketsLost · kDeltaT` = 3 × 1 ms: the arm joint velocity limit is
    /// further reduced by this time × the joint's acceleration limit (when finite). 3e-3 s.
    pub acceleration_margin_time: f64,
    /// Interior-point iteration limit for one solve. 100.
    pub max_iterations: u32,
}

impl Default for ResolverConfig {
    fn default() -> Self {
        Self {
            joint_velocity_weight: 0.01,
            min_position_error: 1e-3,
            manipulability_gain: 1.0,
            manipulability_reference_threshold: 0.08,
            facing_gain: 0.5,
            base_tracking_weight: 1e4,
            damper_stop_distance: 0.1,
            damper_influence_distance: 0.9,
            slack_bound: 10.0,
            velocity_margin: 1e-3,
            acceleration_margin_time: 3e-3,
            max_iterations: 100,
        }
    }
}

/// Which orientation term goes into the linear cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Facing {
    /// No facing term.
    #[default]
    None,
    /// MotM: keep arm joint 1 facing the gripper,
    /// `c[arm1] = −k_ε · wrap(atan2(p.y, p.x) − q_arm1)`.
    ArmJoint1 {
        /// Tool position in the arm-base frame (the frame of the arm's first joint at zero).
        tool_in_arm_base: Vector3<f64>,
    },
    /// Holistic baseline: turn the base to face the tool, `c[ω] = −k_ε · atan2(p.y, p.x)`.
    Base {
        /// Tool position in the mobile base frame.
        tool_in_base: Vector3<f64>,
    },
    /// MotM for any arm: keep the arm's facing joint ([`crate::facing::FacingJoint`]) turned
    /// toward the gripper, `c[arm_index] = −k_ε · error`.
    ArmJoint {
        /// Index of the facing joint among the arm joints.
        arm_index: usize,
        /// Facing error, rad ([`crate::facing::FacingJoint::error`]).
        error: f64,
    },
}

/// One cycle's input to [`RedundancyResolver::resolve`].
#[derive(Debug, Clone, Copy)]
pub struct ResolverInput<'a> {
    /// Full 6×n Jacobian (columns base ω, base v, arm), in the same frame as `twist` (world for
    /// MotM; the holistic baseline uses the tool frame).
    pub jacobian: &'a Matrix6xX<f64>,
    /// Desired tool twist ν, `[v; ω]`.
    pub twist: Twist,
    /// Arm joint positions (no base joints), for the damper and the facing term.
    pub arm_q: &'a [f64],
    /// Gradient of the arm's manipulability with respect to the arm joints.
    pub manipulability_gradient: &'a DVector<f64>,
    /// `e_t`: L1 norm of the tool-to-target translation error, m.
    pub position_error: f64,
    /// Facing term to add.
    pub facing: Facing,
    /// The base controller's (v*, ω*), tracked softly when given.
    pub base_velocity_target: Option<BaseVelocity>,
}

/// How one resolve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResolveStatus {
    /// Solved to full accuracy.
    Solved,
    /// Solved to clarabel's reduced accuracy; the command is used.
    AlmostSolved,
    /// A NaN/∞ or a wrong-sized vector in the input: zero command.
    InvalidInput,
    /// The solver failed (infeasible, iteration limit, numerical error): zero command.
    SolverFailed,
}

impl ResolveStatus {
    /// Whether the command came from a solution (not the zero fallback).
    pub fn is_ok(self) -> bool {
        matches!(self, Self::Solved | Self::AlmostSolved)
    }
}

/// One cycle's output of [`RedundancyResolver::resolve`].
#[derive(Debug, Clone, PartialEq)]
pub struct ResolverOutput {
    /// Base command (v, ω).
    pub base: BaseVelocity,
    /// Arm joint velocity command.
    pub arm_qd: Vec<f64>,
    /// Slack δ: the part of ν not achieved (`J q̇ = ν − δ`).
    pub slack: Vector6<f64>,
    /// How the solve ended.
    pub status: ResolveStatus,
    /// Interior-point iterations used (0 when the input was rejected).
    pub iterations: u32,
}

impl ResolverOutput {
    /// The safe all-zero command.
    fn zero(arm_dof: usize, status: ResolveStatus, iterations: u32) -> Self {
        Self {
            base: BaseVelocity::default(),
            arm_qd: vec![0.0; arm_dof],
            slack: Vector6::zeros(),
            status,
            iterations,
        }
    }

    /// All joint velocities, base ω and v first, then the arm.
    pub fn joint_velocities(&self) -> DVector<f64> {
        let mut out = DVector::zeros(BASE_JOINTS + self.arm_qd.len());
        out[BASE_OMEGA] = self.base.omega;
        out[BASE_V] = self.base.v;
        for (o, v) in out.iter_mut().skip(BASE_JOINTS).zip(&self.arm_qd) {
            *o = *v;
        }
        out
    }
}

/// Velocity bound of one joint after libfranka's margins (arm joints only).
fn margined_velocity_limit(limits: &JointLimits, is_arm: bool, config: &ResolverConfig) -> f64 {
    if !is_arm {
        return limits.velocity;
    }
    let accel_margin = if limits.acceleration.is_finite() {
        config.acceleration_margin_time * limits.acceleration
    } else {
        0.0
    };
    (limits.velocity - config.velocity_margin - accel_margin).max(0.0)
}

/// Velocity bounds of every joint (base first) as the resolver uses them: the model's limit for
/// the base joints, the limit less libfranka's margins for the arm joints.
pub fn margined_velocity_limits(limits: &[JointLimits], config: &ResolverConfig) -> Vec<f64> {
    limits
        .iter()
        .enumerate()
        .map(|(i, l)| margined_velocity_limit(l, i >= BASE_JOINTS, config))
        .collect()
}

/// Whether every value is finite.
fn finite<'a>(mut values: impl Iterator<Item = &'a f64>) -> bool {
    values.all(|v| v.is_finite())
}

/// The holistic/MotM redundancy resolver: one clarabel solver, built once, updated per cycle.
pub struct RedundancyResolver {
    config: ResolverConfig,
    joints: usize,
    velocity_limit: Vec<f64>,
    position_limits: Vec<(f64, f64)>,
    solver: DefaultSolver<f64>,
    p_diag: Vec<f64>,
    linear: Vec<f64>,
    a_values: Vec<f64>,
    b: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    errors: u64,
    /// The robot's facing joint, when the resolver was made for a robot.
    facing_joint: Option<FacingJoint>,
    /// Scale of the manipulability gradient term: the reference threshold over the robot's (1
    /// when the resolver was not made for a robot).
    manipulability_scale: f64,
    /// Held arm joints (arm index, ready position): each is servoed to its ready position
    /// (`Robot::held_joints`).
    held: Vec<(usize, f64)>,
}

impl std::fmt::Debug for RedundancyResolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RedundancyResolver")
            .field("joints", &self.joints)
            .field("velocity_limit", &self.velocity_limit)
            .field("errors", &self.errors)
            .finish_non_exhaustive()
    }
}

/// Non-zeros stored per joint column of `A`: 6 Jacobian rows + 2 bound rows.
const JOINT_COLUMN_NNZ: usize = 8;
/// Non-zeros stored per slack column of `A`: 1 equality row + 2 bound rows.
const SLACK_COLUMN_NNZ: usize = 3;

impl RedundancyResolver {
    /// A resolver for `robot` (all joints, base first), with the model's velocity limits.
    pub fn for_robot(robot: &Robot, config: ResolverConfig) -> Self {
        let mut resolver = Self::new(&robot.limits(), config);
        resolver.facing_joint = FacingJoint::from_robot(robot);
        resolver.manipulability_scale = resolver.config.manipulability_reference_threshold
            / robot.config.manipulability_threshold;
        resolver.held = robot.held_joints();
        resolver
    }

    /// A resolver for joints with these `limits` (base ω, base v, then the arm).
    ///
    /// # Panics
    /// If fewer than [`BASE_JOINTS`] limits are given.
    pub fn new(limits: &[JointLimits], config: ResolverConfig) -> Self {
        let joints = limits.len();
        assert!(joints >= BASE_JOINTS, "a mobile chain has two base joints");
        let velocity_limit = margined_velocity_limits(limits, &config);
        let position_limits = limits
            .iter()
            .map(|l| (l.position_min, l.position_max))
            .collect();
        let vars = joints + SLACKS;
        let rows = SLACKS + 2 * vars;

        // P: diagonal, stored upper-triangular.
        let p_diag = vec![1.0; vars];
        let p = CscMatrix::new(
            vars,
            vars,
            (0..=vars).collect(),
            (0..vars).collect(),
            p_diag.clone(),
        );
        // A: column-major; joint columns [J rows 0..6, upper row, lower row], slack columns
        // [equality row, upper row, lower row]. Bound rows of variable k: 6 + 2k (x_k ≤ ub) and
        // 6 + 2k + 1 (−x_k ≤ −lb).
        let mut colptr = Vec::with_capacity(vars + 1);
        let mut rowval = Vec::new();
        let mut a_values = Vec::new();
        colptr.push(0);
        for k in 0..vars {
            if k < joints {
                for r in 0..SLACKS {
                    rowval.push(r);
                    a_values.push(0.0);
                }
            } else {
                rowval.push(k - joints);
                a_values.push(1.0);
            }
            rowval.push(SLACKS + 2 * k);
            a_values.push(1.0);
            rowval.push(SLACKS + 2 * k + 1);
            a_values.push(-1.0);
            colptr.push(rowval.len());
        }
        debug_assert_eq!(
            a_values.len(),
            joints * JOINT_COLUMN_NNZ + SLACKS * SLACK_COLUMN_NNZ
        );
        let a = CscMatrix::new(rows, vars, colptr, rowval, a_values.clone());
        let linear = vec![0.0; vars];
        let b = vec![1.0; rows];
        let cones = [
            SupportedConeT::ZeroConeT(SLACKS),
            SupportedConeT::NonnegativeConeT(2 * vars),
        ];
        let solver = DefaultSolver::new(&p, &linear, &a, &b, &cones, Self::settings(&config))
            .expect("the resolver's fixed QP structure is valid");
        Self {
            config,
            joints,
            velocity_limit,
            position_limits,
            solver,
            p_diag,
            linear,
            a_values,
            b,
            lower: vec![0.0; vars],
            upper: vec![0.0; vars],
            errors: 0,
            facing_joint: None,
            manipulability_scale: 1.0,
            held: Vec::new(),
        }
    }

    /// Clarabel's settings. Iterative refinement of the KKT solves stops at a residual of 1e-10
    /// (clarabel's defaults, 1e-13 relative and 1e-12 absolute, cost extra refinement steps on
    /// this small, well-scaled system): still two orders below the 1e-8 interior-point
    /// tolerances, so the solutions agree with the defaults' to ~1e-11, and a solve is ~13 %
    /// faster (`motm bench qp`).
    fn settings(config: &ResolverConfig) -> DefaultSettings<f64> {
        DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            .input_sparse_dropzeros(false)
            .max_iter(config.max_iterations)
            .iterative_refinement_reltol(1e-10)
            .iterative_refinement_abstol(1e-10)
            .build()
            .expect("valid clarabel settings")
    }

    /// The configuration in use.
    pub fn config(&self) -> &ResolverConfig {
        &self.config
    }

    /// Number of joints (base included).
    pub fn joints(&self) -> usize {
        self.joints
    }

    /// Velocity bound of every joint after margins, base first.
    pub fn velocity_limits(&self) -> &[f64] {
        &self.velocity_limit
    }

    /// How many resolves have returned the zero fallback.
    pub fn error_count(&self) -> u64 {
        self.errors
    }

    /// The joint velocity bounds `(lower, upper)` of the last resolve (after the damper), base
    /// first. Empty of meaning before the first resolve.
    pub fn last_bounds(&self) -> (&[f64], &[f64]) {
        (&self.lower[..self.joints], &self.upper[..self.joints])
    }

    /// Solves one cycle. Never returns NaN; on any failure returns zeros and counts an error.
    pub fn resolve(&mut self, input: &ResolverInput<'_>) -> ResolverOutput {
        let arm_dof = self.joints - BASE_JOINTS;
        match self.try_resolve(input) {
            Ok(output) => output,
            Err((status, iterations)) => {
                self.errors += 1;
                ResolverOutput::zero(arm_dof, status, iterations)
            }
        }
    }

    fn input_is_valid(&self, input: &ResolverInput<'_>) -> bool {
        let arm_dof = self.joints - BASE_JOINTS;
        let facing_ok = match input.facing {
            Facing::None => true,
            Facing::ArmJoint1 { tool_in_arm_base } => finite(tool_in_arm_base.iter()),
            Facing::Base { tool_in_base } => finite(tool_in_base.iter()),
            Facing::ArmJoint { arm_index, error } => arm_index < arm_dof && error.is_finite(),
        };
        let base_ok = input
            .base_velocity_target
            .is_none_or(|t| t.v.is_finite() && t.omega.is_finite());
        input.jacobian.ncols() == self.joints
            && input.arm_q.len() == arm_dof
            && input.manipulability_gradient.len() == arm_dof
            && finite(input.jacobian.iter())
            && finite(input.twist.iter())
            && finite(input.arm_q.iter())
            && finite(input.manipulability_gradient.iter())
            && input.position_error.is_finite()
            && facing_ok
            && base_ok
    }

    /// Fills `lower`/`upper` for every variable: velocity limits, damper, slack bounds.
    fn fill_bounds(&mut self, arm_q: &[f64]) {
        let ps = self.config.damper_stop_distance;
        let influence = self.config.damper_influence_distance;
        for j in 0..self.joints {
            let vmax = self.velocity_limit[j];
            let (mut lo, mut hi) = (-vmax, vmax);
            // Base virtual joints sit at zero each cycle; continuous/unbounded joints have
            // infinite limits and no damper.
            let q = if j < BASE_JOINTS {
                0.0
            } else {
                arm_q[j - BASE_JOINTS]
            };
            let (qmin, qmax) = self.position_limits[j];
            // A held joint is servoed to its ready position instead, which may sit at a limit
            // (Fetch's torso, down at 0 m): the damper would push it a stop distance off.
            let held = j >= BASE_JOINTS && self.held.iter().any(|&(k, _)| k == j - BASE_JOINTS);
            if !held && qmin.is_finite() && q - qmin <= influence {
                // Clamped to vmax so a joint pushed past its stop stays feasible.
                lo = lo.max((-(q - qmin - ps) / (influence - ps)).min(vmax));
            }
            if !held && qmax.is_finite() && qmax - q <= influence {
                hi = hi.min(((qmax - q - ps) / (influence - ps)).max(-vmax));
            }
            self.lower[j] = lo;
            self.upper[j] = hi;
        }
        for k in self.joints..self.joints + SLACKS {
            self.lower[k] = -self.config.slack_bound;
            self.upper[k] = self.config.slack_bound;
        }
    }

    fn try_resolve(
        &mut self,
        input: &ResolverInput<'_>,
    ) -> Result<ResolverOutput, (ResolveStatus, u32)> {
        if !self.input_is_valid(input) {
            return Err((ResolveStatus::InvalidInput, 0));
        }
        let n = self.joints;
        let cfg = &self.config;
        let e_t = input.position_error.abs().max(cfg.min_position_error);
        let y = cfg.joint_velocity_weight;

        // Objective.
        self.linear.iter_mut().for_each(|c| *c = 0.0);
        for j in 0..n {
            self.p_diag[j] = if j < BASE_JOINTS { y / e_t } else { y };
        }
        for k in n..n + SLACKS {
            self.p_diag[k] = 1.0 / e_t;
        }
        for (k, g) in input.manipulability_gradient.iter().enumerate() {
            self.linear[BASE_JOINTS + k] = -cfg.manipulability_gain * self.manipulability_scale * g;
        }
        match input.facing {
            Facing::None => {}
            Facing::ArmJoint1 {
                tool_in_arm_base: p,
            } => {
                let q1 = input.arm_q.first().copied().unwrap_or(0.0);
                self.linear[BASE_JOINTS] += -cfg.facing_gain * wrap_angle(p.y.atan2(p.x) - q1);
            }
            Facing::Base { tool_in_base: p } => {
                self.linear[BASE_OMEGA] += -cfg.facing_gain * p.y.atan2(p.x);
            }
            Facing::ArmJoint { arm_index, error } => {
                self.linear[BASE_JOINTS + arm_index] += -cfg.facing_gain * error;
            }
        }
        if let Some(target) = input.base_velocity_target {
            let w = cfg.base_tracking_weight;
            self.p_diag[BASE_OMEGA] += w;
            self.p_diag[BASE_V] += w;
            self.linear[BASE_OMEGA] -= w * target.omega;
            self.linear[BASE_V] -= w * target.v;
        }
        for &(k, rest) in &self.held {
            // Tracked like the base velocity: a soft row at the same weight.
            let j = BASE_JOINTS + k;
            let vmax = self.velocity_limit[j];
            let toward_rest = (HELD_JOINT_GAIN * (rest - input.arm_q[k])).clamp(-vmax, vmax);
            let w = cfg.base_tracking_weight;
            self.p_diag[j] += w;
            self.linear[j] -= w * toward_rest;
        }

        // Constraint matrix: only the Jacobian block changes.
        for j in 0..n {
            let start = j * JOINT_COLUMN_NNZ;
            for r in 0..SLACKS {
                self.a_values[start + r] = input.jacobian[(r, j)];
            }
        }
        // Right-hand side: ν, then the bounds.
        self.fill_bounds(input.arm_q);
        for r in 0..SLACKS {
            self.b[r] = input.twist[r];
        }
        for k in 0..n + SLACKS {
            self.b[SLACKS + 2 * k] = self.upper[k];
            self.b[SLACKS + 2 * k + 1] = -self.lower[k];
        }

        let updated = self
            .solver
            .update_P(&self.p_diag)
            .and_then(|_| self.solver.update_q(&self.linear))
            .and_then(|_| self.solver.update_A(&self.a_values))
            .and_then(|_| self.solver.update_b(&self.b));
        if updated.is_err() {
            return Err((ResolveStatus::SolverFailed, 0));
        }
        self.solver.solve();
        let solution = &self.solver.solution;
        let iterations = solution.iterations;
        let status = match solution.status {
            SolverStatus::Solved => ResolveStatus::Solved,
            SolverStatus::AlmostSolved => ResolveStatus::AlmostSolved,
            _ => return Err((ResolveStatus::SolverFailed, iterations)),
        };
        if solution.x.iter().any(|v| !v.is_finite()) {
            return Err((ResolveStatus::SolverFailed, iterations));
        }
        // Interior-point solutions can sit a hair outside a bound: clip to the exact bounds.
        let x: Vec<f64> = solution
            .x
            .iter()
            .zip(self.lower.iter().zip(&self.upper))
            .map(|(v, (lo, hi))| v.max(*lo).min(*hi))
            .collect();
        Ok(ResolverOutput {
            base: BaseVelocity {
                v: x[BASE_V],
                omega: x[BASE_OMEGA],
            },
            arm_qd: x[BASE_JOINTS..n].to_vec(),
            slack: Vector6::from_column_slice(&x[n..n + SLACKS]),
            status,
            iterations,
        })
    }
}

/// The MotM cycle around [`RedundancyResolver::resolve`], from robot state to command.
impl RedundancyResolver {
    /// Computes kinematics, the arm's manipulability gradient and the facing term (the robot's
    /// facing joint toward the gripper, [`FacingJoint`]) for `robot` at `base`/`arm_q`, then resolves the world-frame `twist` with the base tracking
    /// `base_velocity_target` (when given). `position_error` is `e_t`.
    pub fn resolve_motm(
        &mut self,
        robot: &Robot,
        base: &crate::kinematics::BasePose,
        arm_q: &[f64],
        twist: Twist,
        position_error: f64,
        base_velocity_target: Option<BaseVelocity>,
    ) -> ResolverOutput {
        if arm_q.len() != robot.arm_dof() || arm_q.iter().any(|q| !q.is_finite()) {
            self.errors += 1;
            return ResolverOutput::zero(self.joints - BASE_JOINTS, ResolveStatus::InvalidInput, 0);
        }
        let fk = robot.forward(base, arm_q);
        let (_, gradient) =
            crate::kinematics::manipulability_gradient(&Robot::arm_jacobian(&fk.jacobian));
        let facing = match self.facing_joint.or_else(|| FacingJoint::from_robot(robot)) {
            Some(joint) => Facing::ArmJoint {
                arm_index: joint.arm_index,
                error: joint.error(robot, base, arm_q, &fk.tool_pose.translation.vector),
            },
            None => Facing::None,
        };
        self.resolve(&ResolverInput {
            jacobian: &fk.jacobian,
            twist,
            arm_q,
            manipulability_gradient: &gradient,
            position_error,
            facing,
            base_velocity_target,
        })
    }
}

/// World frame of the arm's first joint at zero position (the "arm-base frame"), with the
/// virtual base joints at zero.
pub fn arm_base_frame(
    robot: &Robot,
    base: &crate::kinematics::BasePose,
) -> nalgebra::Isometry3<f64> {
    let mut frame = base.isometry();
    for joint in robot.chain.joints.iter().take(BASE_JOINTS) {
        frame = frame * joint.origin * joint.motion(0.0);
    }
    match robot.chain.joints.get(BASE_JOINTS) {
        Some(first_arm_joint) => frame * first_arm_joint.origin,
        None => frame,
    }
}

#[cfg(test)]
mod robot_scale_tests {
    use super::*;

    fn resolver(name: &str) -> RedundancyResolver {
        let robot = Robot::load(&crate::resolve_config_dir(None), name).expect("robot loads");
        RedundancyResolver::for_robot(&robot, ResolverConfig::default())
    }

    #[test]
    fn frankie_keeps_the_papers_manipulability_gain() {
        assert_eq!(resolver("frankie").manipulability_scale, 1.0);
    }

    #[test]
    fn an_arm_with_larger_manipulability_gets_a_smaller_gradient_weight() {
        let fetch = resolver("fetch");
        assert!((fetch.manipulability_scale - 0.08 / 0.28).abs() < 1e-12);
        assert_eq!(fetch.facing_joint.map(|f| f.arm_index), Some(1));
    }
}
