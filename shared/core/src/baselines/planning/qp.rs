//! The planning QP: one conic quadratic program over all knots, for the base and the gripper
//! together, solved with clarabel.
//!
//! Decision variables, per knot k = 0..=N: base position (2), base velocity (2), gripper position
//! (3), gripper velocity (3); per interval k = 0..N: base acceleration (2) and gripper
//! acceleration (3), constant over the interval (exact double-integrator dynamics). The base is a
//! differential drive, modelled through its flat output (x, y): heading = direction of the
//! velocity, v = |ṗ|, ω = (ṗ × p̈)/|ṗ|².
//!
//! Convex constraints: initial state, dynamics, base speed ≤ v_F (SOC), base acceleration ≤ the
//! base limit (SOC), gripper speed and acceleration limits (SOC), horizontal reach from the arm
//! mount ≤ manipulation range (SOC), 3-D reach from the shoulder (SOC), grasp and drop positions
//! with zero velocity held over their dwell windows, approach/lift/carry heights, zero velocity at
//! the end. The constraints that depend on the base heading or are non-convex are linearised
//! about a reference trajectory (the nominal route, then the previous pass): the arm mount
//! offset, "gripper ahead of the mount", the yaw-rate limit |a_lat| ≤ ω_max·v_fwd (which also
//! forbids reversing), and the target clearance |p_b − target| ≥ r, replaced by its tangent
//! half-space (which is conservative: it implies the true constraint).

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use nalgebra::{Vector2, Vector3};

use super::geometry::{RobotGeometry, rotate};
use super::{PlanRequest, PlanningConfig, PlanningError};

/// Variables per knot: base position, base velocity, gripper position, gripper velocity.
const STATE: usize = 10;
/// Variables per interval: base acceleration, gripper acceleration.
const INPUT: usize = 5;

/// Where each variable lives in the decision vector.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layout {
    /// Number of intervals N (there are N + 1 knots).
    pub intervals: usize,
}

impl Layout {
    /// Total number of decision variables.
    pub fn variables(&self) -> usize {
        STATE * (self.intervals + 1) + INPUT * self.intervals
    }
    /// Index of base position component `axis` at knot `k`.
    pub fn base_position(&self, k: usize, axis: usize) -> usize {
        STATE * k + axis
    }
    /// Index of base velocity component `axis` at knot `k`.
    pub fn base_velocity(&self, k: usize, axis: usize) -> usize {
        STATE * k + 2 + axis
    }
    /// Index of gripper position component `axis` at knot `k`.
    pub fn gripper_position(&self, k: usize, axis: usize) -> usize {
        STATE * k + 4 + axis
    }
    /// Index of gripper velocity component `axis` at knot `k`.
    pub fn gripper_velocity(&self, k: usize, axis: usize) -> usize {
        STATE * k + 7 + axis
    }
    /// Index of base acceleration component `axis` over interval `k`.
    pub fn base_acceleration(&self, k: usize, axis: usize) -> usize {
        STATE * (self.intervals + 1) + INPUT * k + axis
    }
    /// Index of gripper acceleration component `axis` over interval `k`.
    pub fn gripper_acceleration(&self, k: usize, axis: usize) -> usize {
        STATE * (self.intervals + 1) + INPUT * k + 2 + axis
    }
}

/// The knots at which the task events happen, and the length of the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Schedule {
    /// First knot of the grasp dwell (the gripper arrives and starts closing).
    pub grasp: usize,
    /// Last knot of the grasp dwell (the fingers are closed; the lift starts).
    pub grasp_end: usize,
    /// Knot at which the gripper must be `approach_height` above the cube.
    pub approach: usize,
    /// Knot by which the gripper is `lift_height` above the grasp point.
    pub lifted: usize,
    /// First knot of the drop dwell (the gripper arrives and opens).
    pub drop: usize,
    /// Last knot of the drop dwell.
    pub drop_end: usize,
    /// Knot at which the carry height stops applying (before the drop).
    pub drop_approach: usize,
    /// Last knot; base and gripper are at rest.
    pub end: usize,
}

impl Schedule {
    /// Knots for grasp and drop times `grasp_time` and `drop_time` (rounded up to knots).
    pub fn new(grasp_time: f64, drop_time: f64, config: &PlanningConfig) -> Self {
        let h = config.knot_spacing;
        let knots = |t: f64| (t / h - 1e-9).ceil().max(0.0) as usize;
        let approach_knots = knots(config.approach_time);
        let grasp = knots(grasp_time).max(1);
        let grasp_end = grasp + knots(config.grasp_dwell);
        let lifted = grasp_end + knots(config.lift_time).max(1);
        let drop = knots(drop_time).max(lifted + approach_knots + 1);
        let drop_end = drop + knots(config.drop_dwell);
        Self {
            grasp,
            grasp_end,
            approach: grasp.saturating_sub(approach_knots),
            lifted,
            drop,
            drop_end,
            drop_approach: drop - approach_knots.max(1),
            end: drop_end + knots(config.stop_duration).max(1),
        }
    }
}

/// The point about which the heading-dependent and non-convex constraints are linearised.
#[derive(Debug, Clone)]
pub(crate) struct Linearisation {
    /// Reference base position at each knot.
    pub base: Vec<Vector2<f64>>,
    /// Reference base heading at each knot, rad.
    pub heading: Vec<f64>,
}

/// Everything the QP needs besides the linearisation.
#[derive(Debug, Clone)]
pub(crate) struct QpData<'a> {
    /// The planning request.
    pub request: &'a PlanRequest,
    /// Robot quantities.
    pub geometry: &'a RobotGeometry,
    /// Planner settings.
    pub config: &'a PlanningConfig,
    /// Event knots.
    pub schedule: Schedule,
    /// Gripper position at the start, m.
    pub start_gripper: Vector3<f64>,
    /// Where the gripper grasps the cube.
    pub grasp_position: Vector3<f64>,
    /// Where the gripper releases the cube.
    pub drop_position: Vector3<f64>,
}

/// Outcome of one QP solve.
#[derive(Debug, Clone)]
pub(crate) struct QpSolution {
    /// The decision vector.
    pub x: Vec<f64>,
    /// Clarabel's status.
    pub status: SolverStatus,
    /// Interior-point iterations.
    pub iterations: u32,
}

/// One sparse linear term: coefficient times variable.
type Term = (usize, f64);

/// Accumulates the rows `A x + s = b, s ∈ K` in clarabel's form.
struct ConeRows {
    rows: Vec<usize>,
    cols: Vec<usize>,
    values: Vec<f64>,
    rhs: Vec<f64>,
    cones: Vec<SupportedConeT<f64>>,
}

impl ConeRows {
    fn new() -> Self {
        Self {
            rows: Vec::new(),
            cols: Vec::new(),
            values: Vec::new(),
            rhs: Vec::new(),
            cones: Vec::new(),
        }
    }

    fn push_row(&mut self, terms: &[Term], rhs: f64) {
        let row = self.rhs.len();
        for &(col, value) in terms {
            self.rows.push(row);
            self.cols.push(col);
            self.values.push(value);
        }
        self.rhs.push(rhs);
    }

    /// Appends a cone of dimension `dim`, merging runs of zero or non-negative cones.
    fn push_cone(&mut self, cone: SupportedConeT<f64>) {
        use SupportedConeT::{NonnegativeConeT, ZeroConeT};
        match (self.cones.last_mut(), &cone) {
            (Some(ZeroConeT(n)), ZeroConeT(m))
            | (Some(NonnegativeConeT(n)), NonnegativeConeT(m)) => *n += *m,
            _ => self.cones.push(cone),
        }
    }

    /// Σ terms = rhs.
    fn equal(&mut self, terms: &[Term], rhs: f64) {
        self.push_row(terms, rhs);
        self.push_cone(SupportedConeT::ZeroConeT(1));
    }

    /// Σ terms ≤ rhs.
    fn at_most(&mut self, terms: &[Term], rhs: f64) {
        self.push_row(terms, rhs);
        self.push_cone(SupportedConeT::NonnegativeConeT(1));
    }

    /// Σ terms ≥ rhs.
    fn at_least(&mut self, terms: &[Term], rhs: f64) {
        let negated: Vec<Term> = terms.iter().map(|&(c, v)| (c, -v)).collect();
        self.at_most(&negated, -rhs);
    }

    /// ‖(Σ rows_i + offset_i)_i‖ ≤ bound.
    fn norm_at_most(&mut self, components: &[(Vec<Term>, f64)], bound: f64) {
        self.push_row(&[], bound);
        for (terms, offset) in components {
            let negated: Vec<Term> = terms.iter().map(|&(c, v)| (c, -v)).collect();
            self.push_row(&negated, *offset);
        }
        self.cones
            .push(SupportedConeT::SecondOrderConeT(components.len() + 1));
    }
}

/// Builds the QP for `data` linearised about `about` and solves it.
pub(crate) fn solve(data: &QpData, about: &Linearisation) -> Result<QpSolution, PlanningError> {
    let config = data.config;
    let geometry = data.geometry;
    let schedule = data.schedule;
    let layout = Layout {
        intervals: schedule.end,
    };
    let n = layout.intervals;
    let h = config.knot_spacing;
    let request = data.request;

    // Objective: h·Σ (w_g |a_g|² + w_b |a_b|²) = ½ xᵀ P x with P diagonal.
    let mut p_index = Vec::new();
    let mut p_value = Vec::new();
    for k in 0..n {
        for axis in 0..2 {
            p_index.push(layout.base_acceleration(k, axis));
            p_value.push(2.0 * h * config.base_acceleration_weight);
        }
        for axis in 0..3 {
            p_index.push(layout.gripper_acceleration(k, axis));
            p_value.push(2.0 * h * config.gripper_acceleration_weight);
        }
    }
    let nvars = layout.variables();
    let p = CscMatrix::new_from_triplets(nvars, nvars, p_index.clone(), p_index, p_value);
    let q = vec![0.0; nvars];

    let mut rows = ConeRows::new();

    // Initial state: base at the start, moving along its heading; gripper where the arm holds it.
    let start_heading = Vector2::new(request.start_base.yaw.cos(), request.start_base.yaw.sin());
    let start_velocity = start_heading * request.start_base_speed;
    for axis in 0..2 {
        let start = [request.start_base.x, request.start_base.y][axis];
        rows.equal(&[(layout.base_position(0, axis), 1.0)], start);
        rows.equal(
            &[(layout.base_velocity(0, axis), 1.0)],
            start_velocity[axis],
        );
    }
    for axis in 0..3 {
        let velocity = if axis < 2 { start_velocity[axis] } else { 0.0 };
        rows.equal(
            &[(layout.gripper_position(0, axis), 1.0)],
            data.start_gripper[axis],
        );
        rows.equal(&[(layout.gripper_velocity(0, axis), 1.0)], velocity);
    }

    // Dynamics: exact integration of a constant acceleration over each interval.
    for k in 0..n {
        let base = (0..2).map(|a| {
            [
                layout.base_position(k, a),
                layout.base_position(k + 1, a),
                layout.base_velocity(k, a),
                layout.base_velocity(k + 1, a),
                layout.base_acceleration(k, a),
            ]
        });
        let gripper = (0..3).map(|a| {
            [
                layout.gripper_position(k, a),
                layout.gripper_position(k + 1, a),
                layout.gripper_velocity(k, a),
                layout.gripper_velocity(k + 1, a),
                layout.gripper_acceleration(k, a),
            ]
        });
        for [p0, p1, v0, v1, acc] in base.chain(gripper) {
            rows.equal(&[(p1, 1.0), (p0, -1.0), (v0, -h), (acc, -0.5 * h * h)], 0.0);
            rows.equal(&[(v1, 1.0), (v0, -1.0), (acc, -h)], 0.0);
        }
    }

    let targets = [request.cube.xy(), request.container.xy()];
    let yaw_rate_limit = config.max_yaw_rate.min(geometry.yaw_rate_limit);
    for k in 0..=n {
        let heading = Vector2::new(about.heading[k].cos(), about.heading[k].sin());
        let mount = rotate(geometry.mount_offset, about.heading[k]);
        // Base speed at most v_F.
        rows.norm_at_most(
            &[
                (vec![(layout.base_velocity(k, 0), 1.0)], 0.0),
                (vec![(layout.base_velocity(k, 1), 1.0)], 0.0),
            ],
            request.base_speed,
        );
        // Gripper speed limit.
        rows.norm_at_most(
            &(0..3)
                .map(|a| (vec![(layout.gripper_velocity(k, a), 1.0)], 0.0))
                .collect::<Vec<_>>(),
            config.max_gripper_speed,
        );
        // Gripper relative to the arm mount (p_g − p_b − R(θ_ref)·mount).
        let relative = |axis: usize| -> (Vec<Term>, f64) {
            (
                vec![
                    (layout.gripper_position(k, axis), 1.0),
                    (layout.base_position(k, axis), -1.0),
                ],
                -mount[axis],
            )
        };
        // Horizontal reach: within the manipulation range of the mount.
        rows.norm_at_most(&[relative(0), relative(1)], geometry.manipulation_range);
        // 3-D reach from the shoulder.
        rows.norm_at_most(
            &[
                relative(0),
                relative(1),
                (
                    vec![(layout.gripper_position(k, 2), 1.0)],
                    -geometry.shoulder_height,
                ),
            ],
            config.max_reach,
        );
        // Gripper ahead of the mount along the heading.
        let (rx, ox) = relative(0);
        let (ry, oy) = relative(1);
        let mut ahead: Vec<Term> = rx.iter().map(|&(c, v)| (c, v * heading.x)).collect();
        ahead.extend(ry.iter().map(|&(c, v)| (c, v * heading.y)));
        rows.at_least(
            &ahead,
            config.min_forward_reach - (ox * heading.x + oy * heading.y),
        );
        // Gripper above the floor.
        rows.at_least(
            &[(layout.gripper_position(k, 2), 1.0)],
            config.min_gripper_height,
        );
        // Base clear of the targets: tangent half-space of the clearance circle.
        for target in targets {
            let away = about.base[k] - target;
            let normal = if away.norm() > 1e-9 {
                away.normalize()
            } else {
                heading
            };
            rows.at_least(
                &[
                    (layout.base_position(k, 0), normal.x),
                    (layout.base_position(k, 1), normal.y),
                ],
                config.target_clearance + normal.dot(&target),
            );
        }
        // Heading trust region: |lateral velocity| ≤ tan(δ) · forward velocity.
        let lateral = Vector2::new(-heading.y, heading.x);
        let slope = config.heading_trust_region.min(1.5).tan();
        for sign in [1.0, -1.0] {
            rows.at_most(
                &[
                    (
                        layout.base_velocity(k, 0),
                        sign * lateral.x - slope * heading.x,
                    ),
                    (
                        layout.base_velocity(k, 1),
                        sign * lateral.y - slope * heading.y,
                    ),
                ],
                0.0,
            );
        }
        if k < n {
            // Base acceleration limit.
            rows.norm_at_most(
                &[
                    (vec![(layout.base_acceleration(k, 0), 1.0)], 0.0),
                    (vec![(layout.base_acceleration(k, 1), 1.0)], 0.0),
                ],
                geometry.base_acceleration,
            );
            // Gripper acceleration limit.
            rows.norm_at_most(
                &(0..3)
                    .map(|a| (vec![(layout.gripper_acceleration(k, a), 1.0)], 0.0))
                    .collect::<Vec<_>>(),
                config.max_gripper_acceleration,
            );
            // Yaw rate: |a_lateral| ≤ ω_max · v_forward (also forbids reversing).
            let lateral = Vector2::new(-heading.y, heading.x);
            for sign in [1.0, -1.0] {
                rows.at_most(
                    &[
                        (layout.base_acceleration(k, 0), sign * lateral.x),
                        (layout.base_acceleration(k, 1), sign * lateral.y),
                        (layout.base_velocity(k, 0), -yaw_rate_limit * heading.x),
                        (layout.base_velocity(k, 1), -yaw_rate_limit * heading.y),
                    ],
                    0.0,
                );
            }
        }
    }

    // Grasp and drop: position held, velocity zero, over the dwell windows.
    let holds = [
        (schedule.grasp, schedule.grasp_end, data.grasp_position),
        (schedule.drop, schedule.drop_end, data.drop_position),
    ];
    for (first, last, position) in holds {
        for k in first..=last {
            for axis in 0..3 {
                rows.equal(&[(layout.gripper_position(k, axis), 1.0)], position[axis]);
            }
        }
        for axis in 0..3 {
            rows.equal(&[(layout.gripper_velocity(first, axis), 1.0)], 0.0);
        }
    }
    // Approach from above, lift, carry height.
    let grasp_z = data.grasp_position.z;
    let height = |k: usize| [(layout.gripper_position(k, 2), 1.0)];
    for k in schedule.approach..schedule.grasp {
        rows.at_least(&height(k), grasp_z);
    }
    rows.at_least(&height(schedule.approach), grasp_z + config.approach_height);
    for k in schedule.grasp_end + 1..schedule.lifted {
        rows.at_least(&height(k), grasp_z);
    }
    for k in schedule.lifted..=schedule.drop_approach {
        rows.at_least(&height(k), grasp_z + config.lift_height);
    }
    // At rest at the end.
    for axis in 0..2 {
        rows.equal(&[(layout.base_velocity(n, axis), 1.0)], 0.0);
    }
    for axis in 0..3 {
        rows.equal(&[(layout.gripper_velocity(n, axis), 1.0)], 0.0);
    }

    let a = CscMatrix::new_from_triplets(rows.rhs.len(), nvars, rows.rows, rows.cols, rows.values);
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .map_err(|e| PlanningError::Solver(format!("settings: {e:?}")))?;
    let mut solver = DefaultSolver::new(&p, &q, &a, &rows.rhs, &rows.cones, settings)
        .map_err(|e| PlanningError::Solver(format!("setup: {e}")))?;
    solver.solve();
    let status = solver.solution.status;
    match status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => {}
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
            return Err(PlanningError::Infeasible(format!(
                "the QP has no solution (clarabel {status:?}): the cube or the container cannot \
                 be reached at the scheduled times within the speed, reach and clearance limits"
            )));
        }
        other => {
            return Err(PlanningError::Solver(format!(
                "clarabel stopped with {other:?}"
            )));
        }
    }
    let x = solver.solution.x.clone();
    if x.iter().any(|v| !v.is_finite()) {
        return Err(PlanningError::Solver(
            "clarabel returned a non-finite solution".to_string(),
        ));
    }
    Ok(QpSolution {
        x,
        status,
        iterations: solver.solution.iterations,
    })
}
