//! The odometry frame against the mission's world frame (docs/algorithms.md §6).
//!
//! The mission knows where its objects are in the world; the controllers and perception work in
//! the odometry frame, which drifts from the world. Uncorrected, a known position used before
//! perception has seen the object (the base's route, perception's first gate, the known
//! platforms the route keeps clear of) is off by that drift, and in a row of cubes 12 cm apart
//! perception then takes a neighbour for the target.
//!
//! A wheeled base's odometry drifts mostly through two systematic errors: a scale error of the
//! distance driven (a wrong wheel radius) and one of the angle turned (a wrong wheel base).
//! [`OdometryCorrection`] calibrates both online. It keeps the odometry's path as short
//! segments (distance and turn); the world path is the same segments with the distance scaled
//! by `a` and the turn by `b`, from the start pose (where odometry starts). Perception's
//! fixes of landmarks (objects that stand where the mission says: static cubes before they are
//! grasped, containers, buttons) are kept where they were taken on that path, as seen from the
//! base. `(a, b)` is the least-squares fit that puts every fix on its known position (a few
//! Gauss-Newton steps, with a prior of 1 for both so that a scale the fixes cannot yet tell,
//! the turn's before the base has turned, stays at 1). The start pose is fitted too, with a
//! prior of a few centimetres and a degree: a robot is never placed exactly where it is said to
//! start. Each landmark task weighs as one: its fixes share a weight, the newer ones more
//! (`fix_weight`), and a container's fixes count for less than a cube's ([`CONTAINER_FIX_STD`]).
//! The transform published is the one that maps the calibrated world pose of the base onto its
//! odometry pose: exact at the base, and off far from it only by what the fit gets wrong.
//!
//! A two-anchor transform, the earlier design, rotated the frame from the directions between
//! the last two landmarks seen; the older one had drifted a leg's worth since, and on long
//! missions with many turns the error at the base reached 0.3-0.7 m between fixes.

use nalgebra::{Matrix2, Rotation2, SMatrix, SVector, Vector2, Vector3};

use crate::kinematics::BasePose;
use crate::mission::{MissionConfig, MissionTask, TaskKind};
use crate::types::{TargetEstimate, wrap_angle};

/// Least angle turned in odometry, either way, rad, before the turn's scale counts as known
/// (half a turn): the known layout is then trusted ([`OdometryCorrection::calibrated`]).
pub const MIN_TURN_TO_TRUST_LAYOUT: f64 = std::f64::consts::PI;

/// Standard deviation of the prior on each scale factor: 5 %, five times the simulated
/// wheel-odometry error.
const SCALE_PRIOR_STD: f64 = 0.05;

/// Standard deviation of a cube's or a button's fixes, m (perception's error at a few
/// decimetres, seen from above).
pub const FIX_STD: f64 = 0.02;

/// Standard deviation of a container's fixes, m: the outline fit (`crate::outline`) is within
/// millimetres from over the container, but seen from beside it, low, an image now and then
/// gives a fix a wall's height (0.1-0.15 m) off.
pub const CONTAINER_FIX_STD: f64 = 0.1;

/// Standard deviation of the prior on the start pose's position, m: the start is known, as
/// well as a robot is placed by hand or by a map.
const START_PRIOR_STD: f64 = 0.05;

/// Standard deviation of the prior on the start pose's heading, rad (about 1°).
const START_YAW_PRIOR_STD: f64 = 0.02;

/// Largest scale error believed, either factor: 20 %.
const MAX_SCALE_ERROR: f64 = 0.2;

/// A path segment ends once it is this long, m, or has turned [`SEGMENT_TURN`]: the world path
/// is rebuilt from segments, each at its mid heading (off by under 0.1 mm per segment).
const SEGMENT_LENGTH: f64 = 0.1;

/// See [`SEGMENT_LENGTH`], rad.
const SEGMENT_TURN: f64 = 0.02;

/// Gauss-Newton steps per fit (the residuals are close to linear in the scales: two settle).
const FIT_STEPS: usize = 3;

/// A fix's weight below which it is dropped (its task's newer fixes carry the task).
const MIN_FIX_WEIGHT: f64 = 1e-3;

/// The odometry frame's estimated pose in the world, from landmark fixes (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryCorrection {
    fix_weight: f64,
    baseline: f64,
    /// Distance and turn scale from odometry to the world.
    scale: [f64; 2],
    /// The start pose's error: the world start is the first odometry pose moved by this
    /// `[x, y, yaw]`.
    start_error: [f64; 3],
    /// The odometry path so far: (distance, turn) per segment.
    segments: Vec<[f64; 2]>,
    /// The segment being built.
    open: [f64; 2],
    /// The first odometry pose seen: the world pose of the start.
    start: Option<BasePose>,
    /// The last odometry pose [`Self::advance`] saw.
    last_pose: Option<BasePose>,
    /// The calibrated world pose at `last_pose`.
    world: Option<BasePose>,
    /// Odometry yaw turned since the start, either way, rad.
    turned: f64,
    /// The landmark fixes, oldest first.
    fixes: Vec<Fix>,
    /// Whether the turn's scale counts as known.
    calibrated: bool,
    /// The transform `[x, y, yaw]` from the world into odometry.
    offset: [f64; 3],
}

/// One fix of a landmark: where on the path it was taken and where the landmark was then seen
/// from the base.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fix {
    task: usize,
    known: Vector2<f64>,
    /// Segments complete when the fix was taken.
    segment: usize,
    /// The landmark in the base frame of the odometry pose then.
    seen: Vector2<f64>,
    /// Share of its task's weight.
    weight: f64,
    /// Standard deviation of the landmark's fixes, m.
    std: f64,
}

impl OdometryCorrection {
    /// A correction that starts at the identity (odometry starts on the world). Each new fix of
    /// a landmark takes `fix_weight` of its task's weight, the older ones sharing the rest (0
    /// turns the correction off); the known layout is trusted once the base has turned
    /// [`MIN_TURN_TO_TRUST_LAYOUT`] and fixes of two landmarks at least `baseline` (m) apart
    /// are in.
    pub fn new(fix_weight: f64, baseline: f64) -> Self {
        Self {
            fix_weight,
            baseline,
            scale: [1.0, 1.0],
            start_error: [0.0; 3],
            segments: Vec::new(),
            open: [0.0, 0.0],
            start: None,
            last_pose: None,
            world: None,
            turned: 0.0,
            fixes: Vec::new(),
            calibrated: false,
            offset: [0.0; 3],
        }
    }

    /// Takes the base's move to odometry pose `base`: extends the path, moves the calibrated
    /// world pose by the scaled move, and sets the transform so that it maps that onto `base`.
    /// Non-finite poses are ignored.
    pub fn advance(&mut self, base: &BasePose) {
        if self.fix_weight <= 0.0 || ![base.x, base.y, base.yaw].iter().all(|v| v.is_finite()) {
            return;
        }
        let Some(last) = self.last_pose.replace(*base) else {
            self.start = Some(*base);
            self.world = Some(*base);
            return;
        };
        let turn = wrap_angle(base.yaw - last.yaw);
        let moved = Vector2::new(base.x - last.x, base.y - last.y);
        let heading = Vector2::new(last.yaw.cos(), last.yaw.sin());
        let distance = moved.norm().copysign(moved.dot(&heading));
        if self.open[0] * distance < 0.0 {
            self.close_segment();
        }
        self.open[0] += distance;
        self.open[1] += turn;
        self.turned += turn.abs();
        if let Some(world) = &mut self.world {
            *world = step(world, self.scale, [distance, turn]);
        }
        if self.open[0].abs() >= SEGMENT_LENGTH || self.open[1].abs() >= SEGMENT_TURN {
            self.close_segment();
        }
        self.update_offset();
    }

    /// The estimated scale of the distance and of the turn, from odometry to the world (1 for
    /// perfect odometry).
    pub fn scale(&self) -> [f64; 2] {
        self.scale
    }

    /// Whether the turn's scale is known (see [`OdometryCorrection::new`]): known positions are
    /// then good to a few centimetres, where before they may be a lap's drift off.
    pub fn calibrated(&self) -> bool {
        self.calibrated
    }

    /// Where a world point is in the odometry frame (its height unchanged).
    pub fn to_odometry(&self, world: &Vector3<f64>) -> Vector3<f64> {
        world_to_odometry(&self.offset, world)
    }

    /// The odometry frame's yaw in the world and its translation, `[x, y, yaw]` (m, rad).
    pub fn offset(&self) -> [f64; 3] {
        self.offset
    }

    /// Takes a fix `seen` (odometry frame, at the last pose [`Self::advance`] saw) of task
    /// `task`'s landmark, known at `known` (world), whose fixes scatter by `std` (m), and fits
    /// the scales again. Non-finite values, and fixes before any pose, are ignored.
    pub fn observe(&mut self, task: usize, known: &Vector3<f64>, seen: &Vector3<f64>, std: f64) {
        if self.fix_weight <= 0.0
            || !known.iter().chain(seen.iter()).all(|v| v.is_finite())
            || !(std.is_finite() && std > 0.0)
        {
            return;
        }
        let Some(pose) = self.last_pose else {
            return;
        };
        self.close_segment();
        let weight = self.fix_weight.min(1.0);
        let mut first = true;
        for fix in self.fixes.iter_mut().filter(|f| f.task == task) {
            fix.weight *= 1.0 - weight;
            first = false;
        }
        self.fixes.retain(|f| f.weight >= MIN_FIX_WEIGHT);
        let relative = Rotation2::new(-pose.yaw) * (seen.xy() - Vector2::new(pose.x, pose.y));
        self.fixes.push(Fix {
            task,
            known: known.xy(),
            segment: self.segments.len(),
            seen: relative,
            weight: if first { 1.0 } else { weight },
            std,
        });
        self.fit();
        self.calibrated = self.calibrated
            || self.turned >= MIN_TURN_TO_TRUST_LAYOUT
                && self
                    .fixes
                    .iter()
                    .any(|f| (f.known - known.xy()).norm() >= self.baseline);
    }

    /// Ends the open segment.
    fn close_segment(&mut self) {
        if self.open != [0.0, 0.0] {
            self.segments.push(std::mem::take(&mut self.open));
        }
    }

    /// Fits the scales and the start's error to the fixes (see the module doc) and rebuilds
    /// the world pose.
    fn fit(&mut self) {
        let Some(odometry_start) = self.start else {
            return;
        };
        let prior = SVector::<f64, PARAMETERS>::from([
            SCALE_PRIOR_STD,
            SCALE_PRIOR_STD,
            START_PRIOR_STD,
            START_PRIOR_STD,
            START_YAW_PRIOR_STD,
        ])
        .map(|std| 1.0 / (std * std));
        let mut x = self.parameters();
        let centre = SVector::<f64, PARAMETERS>::from([1.0, 1.0, 0.0, 0.0, 0.0]);
        for _ in 0..FIT_STEPS {
            let mut normal = SMatrix::<f64, PARAMETERS, PARAMETERS>::from_diagonal(&prior);
            let mut gradient = prior.component_mul(&(centre - x));
            let start = moved_start(&odometry_start, &x);
            let mut walk = Walk::new(&start, [x[0], x[1]]);
            let mut done = 0;
            for fix in &self.fixes {
                while done < fix.segment {
                    walk.take(self.segments[done]);
                    done += 1;
                }
                let (predicted, jacobian) = walk.landmark(fix.seen);
                let residual = fix.known - predicted;
                let info = fix.weight / (fix.std * fix.std);
                normal += info * jacobian.transpose() * jacobian;
                gradient += info * jacobian.transpose() * residual;
            }
            let Some(delta) = normal.lu().solve(&gradient) else {
                return;
            };
            x += delta;
            for scale in x.iter_mut().take(2) {
                *scale = scale.clamp(1.0 - MAX_SCALE_ERROR, 1.0 + MAX_SCALE_ERROR);
            }
        }
        self.scale = [x[0], x[1]];
        self.start_error = [x[2], x[3], x[4]];
        let mut world = moved_start(&odometry_start, &x);
        for segment in self.segments.iter().chain(std::iter::once(&self.open)) {
            world = step(&world, self.scale, *segment);
        }
        self.world = Some(world);
        self.update_offset();
    }

    /// The fitted parameters: the two scales and the start's error.
    fn parameters(&self) -> SVector<f64, PARAMETERS> {
        let [a, b] = self.scale;
        let [x, y, yaw] = self.start_error;
        SVector::from([a, b, x, y, yaw])
    }

    /// The transform that maps the world pose onto the last odometry pose.
    fn update_offset(&mut self) {
        let (Some(world), Some(odometry)) = (self.world, self.last_pose) else {
            return;
        };
        let yaw = wrap_angle(odometry.yaw - world.yaw);
        let translation = Vector2::new(odometry.x, odometry.y)
            - Rotation2::new(yaw) * Vector2::new(world.x, world.y);
        self.offset = [translation.x, translation.y, yaw];
    }
}

/// The parameters fitted: the distance and turn scales, and the start's `[x, y, yaw]` error.
const PARAMETERS: usize = 5;

/// The world start: the odometry start moved by the start error of the parameters `x`.
fn moved_start(start: &BasePose, x: &SVector<f64, PARAMETERS>) -> BasePose {
    BasePose::new(start.x + x[2], start.y + x[3], start.yaw + x[4])
}

/// The pose after a segment `(distance, turn)` of odometry driven with the scales, at the
/// segment's mid heading.
fn step(pose: &BasePose, scale: [f64; 2], [distance, turn]: [f64; 2]) -> BasePose {
    let mid = pose.yaw + 0.5 * scale[1] * turn;
    BasePose::new(
        pose.x + scale[0] * distance * mid.cos(),
        pose.y + scale[0] * distance * mid.sin(),
        pose.yaw + scale[1] * turn,
    )
}

/// The world path walked segment by segment with the derivatives of the pose by the scales.
struct Walk {
    start: Vector2<f64>,
    pose: BasePose,
    scale: [f64; 2],
    /// d(x, y)/d(a, b), columns a and b.
    d_position: Matrix2<f64>,
    /// Odometry turn since the start (the yaw's derivative by b).
    turned: f64,
}

impl Walk {
    fn new(start: &BasePose, scale: [f64; 2]) -> Self {
        Self {
            start: Vector2::new(start.x, start.y),
            pose: *start,
            scale,
            d_position: Matrix2::zeros(),
            turned: 0.0,
        }
    }

    fn take(&mut self, segment: [f64; 2]) {
        let [distance, turn] = segment;
        let mid_turned = self.turned + 0.5 * turn;
        let mid = self.pose.yaw + 0.5 * self.scale[1] * turn;
        let (sin, cos) = mid.sin_cos();
        let along = Vector2::new(cos, sin);
        let across = Vector2::new(-sin, cos);
        let d_a = distance * along;
        let d_b = self.scale[0] * distance * mid_turned * across;
        self.d_position += Matrix2::from_columns(&[d_a, d_b]);
        self.pose = step(&self.pose, self.scale, segment);
        self.turned += turn;
    }

    /// Where a point `seen` in the base frame is in the world, and its derivatives by the
    /// parameters (the scales, and the start's x, y and yaw: a turn of the start turns the
    /// whole path about it).
    fn landmark(&self, seen: Vector2<f64>) -> (Vector2<f64>, SMatrix<f64, 2, PARAMETERS>) {
        let offset = Rotation2::new(self.pose.yaw) * seen;
        let point = Vector2::new(self.pose.x, self.pose.y) + offset;
        let d_yaw = Vector2::new(-offset.y, offset.x) * self.turned;
        let from_start = point - self.start;
        let mut jacobian = SMatrix::<f64, 2, PARAMETERS>::zeros();
        jacobian.set_column(0, &self.d_position.column(0));
        jacobian.set_column(1, &(self.d_position.column(1) + d_yaw));
        jacobian[(0, 2)] = 1.0;
        jacobian[(1, 3)] = 1.0;
        jacobian.set_column(4, &Vector2::new(-from_start.y, from_start.x));
        (point, jacobian)
    }
}

/// The odometry correction fed by the landmark rule: which of perception's fixes show an object
/// standing where the mission knows it. The MotM mission tracker and the reactive baseline
/// both localize with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Localizer {
    correction: OdometryCorrection,
    /// A cube is a landmark only while seen slower than this, m/s.
    max_speed: f64,
    /// A fix farther than this from the known position's prediction is not taken, m.
    max_residual: f64,
    /// A fix taken with the tool farther than this from the task's aim is not taken, m.
    max_range: f64,
    /// The newest image stamp taken as a landmark fix.
    last_fix_ns: Option<u64>,
    /// The current task's first fix: task index, image stamp (ns) and position.
    first_fix: Option<(usize, u64, Vector3<f64>)>,
}

/// Shortest time, s, a cube must have been seen before its grasp begins to count as a landmark:
/// its mean speed over that time is what tells a cube standing still from one moving slowly
/// (perception's velocity, fitted over half a second, read under 0.02 m/s for cubes moving at
/// 0.03 m/s, and their fixes, a quarter of a metre from where the mission knew them, bent the
/// odometry calibration).
pub const MIN_LANDMARK_TRACK: f64 = 1.0;

impl Localizer {
    /// A localizer with the mission's landmark settings.
    pub fn new(config: &MissionConfig) -> Self {
        Self {
            correction: OdometryCorrection::new(
                config.landmark_fix_weight,
                config.landmark_baseline,
            ),
            max_speed: config.landmark_max_speed,
            max_residual: config.landmark_max_residual,
            max_range: config.landmark_max_range,
            last_fix_ns: None,
            first_fix: None,
        }
    }

    /// The correction.
    pub fn correction(&self) -> &OdometryCorrection {
        &self.correction
    }

    /// Predicts the correction for the base's move (see [`OdometryCorrection::advance`]).
    pub fn advance(&mut self, base: &BasePose) {
        self.correction.advance(base);
    }

    /// Feeds perception's fix `seen` (from the image stamped `stamp`) of task `index`, `task`,
    /// to the correction when the task's object is a landmark at this moment: every new fix of
    /// a container or a button; a cube's once, on the cycle its grasp begins (`grasp_begins`),
    /// when it is seen standing still: slower than `landmark_max_speed` now, and on average
    /// since its first fix, at least [`MIN_LANDMARK_TRACK`] before. Only fixes taken with the
    /// tool within `landmark_max_range` of the task's aim (`tool_range`, m) count: from
    /// farther, a container is seen obliquely and its walls bias the fix. A fix farther than
    /// `landmark_max_residual` from where the correction puts the known position is another
    /// object, and is not taken.
    pub fn locate(
        &mut self,
        index: usize,
        task: &MissionTask,
        seen: &TargetEstimate,
        tool_range: f64,
        grasp_begins: bool,
        stamp: u64,
    ) {
        if self.first_fix.is_none_or(|(task, _, _)| task != index) {
            self.first_fix = Some((index, stamp, seen.position));
        }
        // Mean speed since the first fix, over at least MIN_LANDMARK_TRACK.
        let still = self.first_fix.is_some_and(|(_, first, position)| {
            let span = stamp.saturating_sub(first) as f64 * 1e-9;
            span >= MIN_LANDMARK_TRACK
                && (seen.position - position).xy().norm() < self.max_speed * span
        });
        let landmark = tool_range <= self.max_range
            && match task.kind {
                TaskKind::Place | TaskKind::PressButton => {
                    self.last_fix_ns.is_none_or(|last| stamp > last)
                }
                TaskKind::Pick => grasp_begins && still && seen.velocity.norm() < self.max_speed,
            };
        let residual = (self.correction.to_odometry(&task.position) - seen.position)
            .xy()
            .norm();
        if landmark && residual <= self.max_residual {
            self.last_fix_ns = Some(self.last_fix_ns.map_or(stamp, |last| last.max(stamp)));
            let std = match task.kind {
                TaskKind::Place => CONTAINER_FIX_STD,
                TaskKind::Pick | TaskKind::PressButton => FIX_STD,
            };
            self.correction
                .observe(index, &task.position, &seen.position, std);
        }
    }
}

/// Where `world` is in the odometry frame whose pose against the world is `offset`
/// (`[x, y, yaw]`, [`OdometryCorrection::offset`]): `R(yaw)·world + (x, y)`, height unchanged.
pub fn world_to_odometry(offset: &[f64; 3], world: &Vector3<f64>) -> Vector3<f64> {
    let xy = Rotation2::new(offset[2]) * world.xy() + Vector2::new(offset[0], offset[1]);
    Vector3::new(xy.x, xy.y, world.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A base driven by speed and turn-rate commands, with its true pose and the pose its
    /// odometry measures (distance and turn scaled by `odometry_scale`).
    struct Drive {
        truth: BasePose,
        odometry: BasePose,
        odometry_scale: [f64; 2],
    }

    impl Drive {
        fn new(truth: BasePose, odometry: BasePose, odometry_scale: [f64; 2]) -> Self {
            Self {
                truth,
                odometry,
                odometry_scale,
            }
        }

        /// Drives at `v` (m/s) and `omega` (rad/s) for `seconds`, the correction advancing on
        /// every 20 ms odometry pose.
        fn drive(&mut self, c: &mut OdometryCorrection, v: f64, omega: f64, seconds: f64) {
            let dt = 0.02;
            for _ in 0..(seconds / dt).round() as usize {
                advance(&mut self.truth, v, omega, dt);
                let [sv, sw] = self.odometry_scale;
                advance(&mut self.odometry, sv * v, sw * omega, dt);
                c.advance(&self.odometry);
            }
        }

        /// Where the world point `p` is in the odometry frame now: as far from the measured
        /// pose, in its frame, as it truly is from the base.
        fn in_odometry(&self, p: &Vector3<f64>) -> Vector3<f64> {
            let t = &self.truth;
            let relative = Rotation2::new(-t.yaw) * (p.xy() - Vector2::new(t.x, t.y));
            let o = &self.odometry;
            let xy = Vector2::new(o.x, o.y) + Rotation2::new(o.yaw) * relative;
            Vector3::new(xy.x, xy.y, p.z)
        }

        /// A perfect fix of the landmark of `task` at `p`.
        fn fix(&self, c: &mut OdometryCorrection, task: usize, p: &Vector3<f64>) {
            c.observe(task, p, &self.in_odometry(p), FIX_STD);
        }

        /// How far the correction puts the world point `p` from where it is in odometry, m.
        fn error(&self, c: &OdometryCorrection, p: &Vector3<f64>) -> f64 {
            (c.to_odometry(p) - self.in_odometry(p)).norm()
        }

        /// The world point 1 m ahead of the base.
        fn ahead(&self) -> Vector3<f64> {
            let t = &self.truth;
            Vector3::new(t.x + t.yaw.cos(), t.y + t.yaw.sin(), 0.4)
        }
    }

    fn advance(pose: &mut BasePose, v: f64, omega: f64, dt: f64) {
        let mid = pose.yaw + 0.5 * omega * dt;
        pose.x += v * dt * mid.cos();
        pose.y += v * dt * mid.sin();
        pose.yaw += omega * dt;
    }

    /// A mission's worth of driving: legs of 3 m joined by half turns on alternate sides, a
    /// landmark fixed at the end of each leg (task `k` at the end of leg `k`).
    fn mission(c: &mut OdometryCorrection, drive: &mut Drive, legs: usize) {
        for k in 0..legs {
            drive.drive(c, 0.3, 0.0, 10.0);
            let landmark = drive.ahead();
            drive.fix(c, k, &landmark);
            let side = if k % 2 == 0 { 1.0 } else { -1.0 };
            drive.drive(c, 0.3, side * 0.3, std::f64::consts::PI / 0.3);
        }
    }

    #[test]
    fn off_stays_at_the_identity() {
        let start = BasePose::new(0.0, 0.0, 0.0);
        let mut drive = Drive::new(start, start, [1.03, 0.97]);
        let mut c = OdometryCorrection::new(0.0, 1.0);
        mission(&mut c, &mut drive, 3);
        assert_eq!(c.offset(), [0.0, 0.0, 0.0]);
        assert_eq!(c.scale(), [1.0, 1.0]);
        assert!(!c.calibrated());
    }

    #[test]
    fn landmarks_calibrate_the_odometry_and_the_frame_holds_between_fixes() {
        let start = BasePose::new(1.0, -2.0, 0.4);
        // Odometry reads 2 % long and turns 3 % short.
        let mut drive = Drive::new(start, start, [1.02, 0.97]);
        let mut c = OdometryCorrection::new(0.3, 1.0);
        mission(&mut c, &mut drive, 4);
        let [a, b] = c.scale();
        assert!((a - 1.0 / 1.02).abs() < 0.002, "distance scale {a}");
        assert!((b - 1.0 / 0.97).abs() < 0.002, "turn scale {b}");
        assert!(c.calibrated());
        // Another 9 m with two half turns and no fix: the known positions near the base stay
        // good to a centimetre, where uncorrected odometry is far off.
        let uncorrected = OdometryCorrection::new(0.0, 1.0);
        for side in [1.0, -1.0] {
            drive.drive(&mut c, 0.3, 0.0, 10.0);
            drive.drive(&mut c, 0.3, side * 0.3, std::f64::consts::PI / 0.3);
        }
        drive.drive(&mut c, 0.3, 0.0, 10.0);
        let near = drive.ahead();
        assert!(drive.error(&c, &near) < 0.01, "{}", drive.error(&c, &near));
        assert!(drive.error(&uncorrected, &near) > 0.3);
    }

    #[test]
    fn a_start_placed_off_is_found() {
        let odometry_start = BasePose::new(0.0, 0.0, 0.0);
        // The robot truly starts 6 cm and 1.5 degrees off where it was said to be.
        let truth = BasePose::new(0.05, -0.03, 0.026);
        let mut drive = Drive::new(truth, odometry_start, [1.0, 1.0]);
        let mut c = OdometryCorrection::new(0.3, 1.0);
        mission(&mut c, &mut drive, 3);
        let near = drive.ahead();
        assert!(drive.error(&c, &near) < 0.01, "{}", drive.error(&c, &near));
    }

    #[test]
    fn a_landmark_weighs_as_one_however_often_it_is_seen() {
        let start = BasePose::new(0.0, 0.0, 0.0);
        let run = |repeats: usize| {
            let mut drive = Drive::new(start, start, [1.02, 0.98]);
            let mut c = OdometryCorrection::new(0.3, 1.0);
            drive.drive(&mut c, 0.3, 0.2, 8.0);
            let first = drive.ahead();
            drive.fix(&mut c, 0, &first);
            drive.drive(&mut c, 0.3, -0.2, 8.0);
            let second = drive.ahead();
            // A biased landmark, seen `repeats` times from the same place.
            let biased = second + Vector3::new(0.05, 0.0, 0.0);
            for _ in 0..repeats {
                c.observe(1, &biased, &drive.in_odometry(&second), FIX_STD);
            }
            c.offset()
        };
        let (once, often) = (run(1), run(30));
        for (o, p) in once.iter().zip(often.iter()) {
            assert!((o - p).abs() < 1e-3, "{once:?} {often:?}");
        }
    }

    #[test]
    fn bad_values_and_fixes_before_any_pose_are_ignored() {
        let mut c = OdometryCorrection::new(0.3, 1.0);
        let p = Vector3::new(1.0, 1.0, 0.4);
        c.observe(0, &p, &(p + Vector3::new(0.2, 0.0, 0.0)), FIX_STD);
        assert_eq!(c.offset(), [0.0, 0.0, 0.0]);
        c.advance(&BasePose::new(0.0, 0.0, 0.0));
        c.advance(&BasePose::new(f64::NAN, 0.0, 0.0));
        c.advance(&BasePose::new(0.5, 0.0, 0.0));
        c.observe(0, &p, &Vector3::new(f64::NAN, 0.0, 0.0), FIX_STD);
        c.observe(0, &p, &p, 0.0);
        assert_eq!(c.offset(), [0.0, 0.0, 0.0]);
        c.observe(0, &p, &(p + Vector3::new(0.1, 0.0, 0.0)), FIX_STD);
        assert!(c.offset()[0] > 0.01, "{:?}", c.offset());
        assert!(c.offset().iter().all(|v| v.is_finite()));
    }

    #[test]
    fn the_layout_is_trusted_once_turned_half_a_turn_with_landmarks_apart() {
        let start = BasePose::new(0.0, 0.0, 0.0);
        let mut drive = Drive::new(start, start, [1.01, 0.99]);
        let mut c = OdometryCorrection::new(0.3, 1.0);
        mission(&mut c, &mut drive, 1);
        assert!(!c.calibrated());
        mission(&mut c, &mut drive, 2);
        assert!(c.calibrated());
    }

    #[test]
    fn a_container_is_a_landmark_only_seen_from_within_range() {
        let config = MissionConfig::default();
        let mut l = Localizer::new(&config);
        l.advance(&BasePose::new(0.0, 0.0, 0.0));
        l.advance(&BasePose::new(2.0, 0.0, 0.0));
        let container = MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(3.0, 0.0, 0.35),
        };
        let seen = TargetEstimate::fixed(Vector3::new(3.1, 0.05, 0.35));
        // Seen from afar (obliquely, biased by its walls): not taken.
        l.locate(
            0,
            &container,
            &seen,
            config.landmark_max_range + 0.5,
            false,
            1,
        );
        assert_eq!(l.correction().offset(), [0.0, 0.0, 0.0]);
        // From within range: taken.
        l.locate(
            0,
            &container,
            &seen,
            config.landmark_max_range - 0.05,
            false,
            2,
        );
        let offset = l.correction().offset();
        assert_ne!(offset, [0.0, 0.0, 0.0]);
        // A cube only as its grasp begins, and only seen still.
        let cube = MissionTask {
            kind: TaskKind::Pick,
            item: 1,
            position: Vector3::new(2.0, 0.4, 0.45),
        };
        const S: u64 = 1_000_000_000;
        let mut cube_seen = TargetEstimate::fixed(Vector3::new(2.1, 0.45, 0.45));
        l.locate(1, &cube, &cube_seen, 0.05, false, 3 * S);
        assert_eq!(l.correction().offset(), offset);
        // Its grasp begins half a second after its first fix: too short a look to tell.
        l.locate(1, &cube, &cube_seen, 0.05, true, 3 * S + S / 2);
        assert_eq!(l.correction().offset(), offset);
        cube_seen.velocity.x = 0.05;
        l.locate(1, &cube, &cube_seen, 0.05, true, 5 * S);
        assert_eq!(l.correction().offset(), offset);
        cube_seen.velocity.x = 0.0;
        // Seen still now, but 0.1 m from its first fix 2.5 s before: a cube moving slowly.
        let mut moved = cube_seen;
        moved.position.x += 0.1;
        l.locate(1, &cube, &moved, 0.05, true, 5 * S + S / 2);
        assert_eq!(l.correction().offset(), offset);
        l.locate(1, &cube, &cube_seen, 0.05, true, 6 * S);
        assert_ne!(l.correction().offset(), offset);
    }
}
