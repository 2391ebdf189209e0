//! The odometry frame against the mission's world frame (docs/algorithms.md §6).
//!
//! The mission knows where its objects are in the world; the controllers and perception work in
//! the odometry frame, which drifts from the world (about 1 % of the distance driven and of the
//! angle turned: tens of centimetres and several degrees over an Exp 2 run). Uncorrected, a
//! known position used before perception has seen the object (the base's route, perception's
//! first gate, the known platforms the route keeps clear of) is off by that much, and in a row
//! of cubes 12 cm apart perception then takes a neighbour for the target.
//!
//! [`OdometryCorrection`] estimates the rigid transform `odom = R(yaw)·world + translation` from
//! perception's fixes of objects that stand where the mission says (landmarks: static cubes
//! before they are grasped, containers, buttons). Each landmark task keeps a running mean of its
//! fixes (an anchor: the known position and where it is seen in odometry). With anchors of two
//! tasks at least `landmark_baseline` apart, the transform is the one that maps the two known
//! positions onto the two seen ones (the rotation from the direction between them, the
//! translation from their midpoint); with one anchor, the rotation is kept and the translation
//! moves the anchor's known position onto its seen one. The older anchor has drifted since it
//! was seen; that error (the drift of one leg of the mission) is what remains.
//!
//! Between fixes the correction is predicted from odometry. A differential base's odometry
//! drifts mostly through a scale error of its yaw rate (an error in the wheel base), so the
//! odometry frame turns against the world by a fixed fraction of the angle turned, about the
//! point where the base is while it turns. [`OdometryCorrection::advance`] turns the frame (and
//! the anchors seen in it) by that fraction of each odometry turn about the base; the fraction
//! is the latest two-anchor yaw over the angle turned since the start (odometry starts on the
//! world), once the base has turned at least [`MIN_TURN_FOR_RATE`]. Without this the frame
//! falls a lap's drift behind between fixes (several degrees: tens of centimetres at the far
//! end of a 3 m leg).

use nalgebra::{Rotation2, Vector2, Vector3};

use crate::kinematics::BasePose;
use crate::mission::{MissionConfig, MissionTask, TaskKind};
use crate::types::{TargetEstimate, wrap_angle};

/// Least angle turned in odometry, rad, before the yaw drift rate is estimated from it (half a
/// turn: a two-anchor yaw of about a degree of noise is then a rate error below 0.6 %).
pub const MIN_TURN_FOR_RATE: f64 = std::f64::consts::PI;

/// Largest yaw drift rate believed (odometry yaw error per radian turned): 10 %, ten times the
/// simulated wheel-odometry error.
pub const MAX_YAW_DRIFT_RATE: f64 = 0.1;

/// The odometry frame's estimated pose in the world, from landmark fixes (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryCorrection {
    fix_weight: f64,
    baseline: f64,
    yaw: f64,
    translation: Vector2<f64>,
    /// The last two landmark tasks' anchors, oldest first.
    anchors: Vec<Anchor>,
    /// The last odometry pose [`Self::advance`] saw.
    last_pose: Option<BasePose>,
    /// Odometry yaw turned since the start (unwrapped), rad.
    turned: f64,
    /// Estimated odometry yaw error per radian turned, once estimated.
    yaw_drift_rate: Option<f64>,
}

/// A landmark task's known position and the running mean of where it is seen.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Anchor {
    task: usize,
    known: Vector2<f64>,
    seen: Vector2<f64>,
}

impl OdometryCorrection {
    /// A correction that starts at the identity (odometry starts on the world). Each fix moves
    /// its anchor's mean by `fix_weight` of the way (0 turns the correction off); two anchors
    /// closer than `baseline` (m) do not fix the rotation.
    pub fn new(fix_weight: f64, baseline: f64) -> Self {
        Self {
            fix_weight,
            baseline,
            yaw: 0.0,
            translation: Vector2::zeros(),
            anchors: Vec::with_capacity(2),
            last_pose: None,
            turned: 0.0,
            yaw_drift_rate: None,
        }
    }

    /// Predicts the correction for the base's move to odometry pose `base`: the frame turns
    /// by the estimated drift of the yaw turned since the last call, about the base (see the
    /// module doc). Non-finite poses are ignored.
    pub fn advance(&mut self, base: &BasePose) {
        if self.fix_weight <= 0.0 || ![base.x, base.y, base.yaw].iter().all(|v| v.is_finite()) {
            return;
        }
        let Some(last) = self.last_pose.replace(*base) else {
            return;
        };
        let turn = wrap_angle(base.yaw - last.yaw);
        self.turned += turn;
        let drift = self.yaw_drift_rate.unwrap_or(0.0) * turn;
        if drift == 0.0 {
            return;
        }
        let rotation = Rotation2::new(drift);
        let pivot = Vector2::new(base.x, base.y);
        let turn_about = |p: Vector2<f64>| rotation * (p - pivot) + pivot;
        self.yaw = wrap_angle(self.yaw + drift);
        self.translation = turn_about(self.translation);
        for anchor in &mut self.anchors {
            anchor.seen = turn_about(anchor.seen);
        }
    }

    /// Estimated odometry yaw error per radian turned (0 until the base has turned
    /// [`MIN_TURN_FOR_RATE`] and two anchors fixed the yaw).
    pub fn yaw_drift_rate(&self) -> f64 {
        self.yaw_drift_rate.unwrap_or(0.0)
    }

    /// Whether the yaw drift rate has been estimated, so that the correction is predicted
    /// between fixes: known positions are then good to a few centimetres, where before they
    /// may be a lap's drift off.
    pub fn calibrated(&self) -> bool {
        self.yaw_drift_rate.is_some()
    }

    /// Where a world point is in the odometry frame (its height unchanged).
    pub fn to_odometry(&self, world: &Vector3<f64>) -> Vector3<f64> {
        world_to_odometry(&self.offset(), world)
    }

    /// The odometry frame's yaw in the world and its translation, `[x, y, yaw]` (m, rad).
    pub fn offset(&self) -> [f64; 3] {
        [self.translation.x, self.translation.y, self.yaw]
    }

    /// Takes a fix `seen` (odometry frame) of task `task`'s landmark, known at `known` (world).
    /// Non-finite values are ignored.
    pub fn observe(&mut self, task: usize, known: &Vector3<f64>, seen: &Vector3<f64>) {
        if self.fix_weight <= 0.0 || !known.iter().chain(seen.iter()).all(|v| v.is_finite()) {
            return;
        }
        let (known, seen) = (known.xy(), seen.xy());
        match self.anchors.last_mut() {
            Some(anchor) if anchor.task == task => {
                anchor.seen += self.fix_weight * (seen - anchor.seen);
            }
            _ => {
                if self.anchors.len() == 2 {
                    self.anchors.remove(0);
                }
                self.anchors.push(Anchor { task, known, seen });
            }
        }
        self.fit();
    }

    /// The transform from the anchors (see the module doc).
    fn fit(&mut self) {
        let Some(newest) = self.anchors.last().copied() else {
            return;
        };
        if let [a, b] = self.anchors[..] {
            let known = b.known - a.known;
            let seen = b.seen - a.seen;
            if known.norm() >= self.baseline && seen.norm() >= 0.5 * self.baseline {
                self.yaw = wrap_angle(seen.y.atan2(seen.x) - known.y.atan2(known.x));
                let rotation = Rotation2::new(self.yaw);
                let known_mid = 0.5 * (a.known + b.known);
                let seen_mid = 0.5 * (a.seen + b.seen);
                self.translation = seen_mid - rotation * known_mid;
                if self.turned.abs() >= MIN_TURN_FOR_RATE {
                    self.yaw_drift_rate = Some(
                        (self.yaw / self.turned).clamp(-MAX_YAW_DRIFT_RATE, MAX_YAW_DRIFT_RATE),
                    );
                }
                return;
            }
        }
        self.translation = newest.seen - Rotation2::new(self.yaw) * newest.known;
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
}

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
    /// when it is seen standing still. Only fixes taken with the tool within
    /// `landmark_max_range` of the task's aim (`tool_range`, m) count: from farther, a
    /// container is seen obliquely and its walls bias the fix. A fix farther than
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
        let landmark = tool_range <= self.max_range
            && match task.kind {
                TaskKind::Place | TaskKind::PressButton => {
                    self.last_fix_ns.is_none_or(|last| stamp > last)
                }
                TaskKind::Pick => grasp_begins && seen.velocity.norm() < self.max_speed,
            };
        let residual = (self.correction.to_odometry(&task.position) - seen.position)
            .xy()
            .norm();
        if landmark && residual <= self.max_residual {
            self.last_fix_ns = Some(self.last_fix_ns.map_or(stamp, |last| last.max(stamp)));
            self.correction
                .observe(index, &task.position, &seen.position);
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

    /// Odometry that has drifted: rotated by `yaw` about the world origin and shifted.
    fn drifted(yaw: f64, shift: Vector2<f64>, p: Vector3<f64>) -> Vector3<f64> {
        let xy = Rotation2::new(yaw) * p.xy() + shift;
        Vector3::new(xy.x, xy.y, p.z)
    }

    #[test]
    fn starts_at_the_identity_and_off_stays_there() {
        let p = Vector3::new(1.0, 2.0, 0.45);
        let mut c = OdometryCorrection::new(0.0, 1.0);
        c.observe(0, &p, &(p + Vector3::new(0.3, 0.0, 0.0)));
        assert_eq!(c.to_odometry(&p), p);
        assert_eq!(c.offset(), [0.0, 0.0, 0.0]);
    }

    #[test]
    fn one_landmark_fixes_the_translation() {
        let mut c = OdometryCorrection::new(1.0, 1.0);
        let cube = Vector3::new(0.0, 0.5, 0.45);
        let shift = Vector2::new(0.15, -0.1);
        c.observe(0, &cube, &drifted(0.0, shift, cube));
        let far = Vector3::new(3.0, 0.0, 0.35);
        assert!((c.to_odometry(&far) - drifted(0.0, shift, far)).norm() < 1e-12);
        // Heights are not touched.
        assert_eq!(c.to_odometry(&far).z, 0.35);
    }

    #[test]
    fn two_landmarks_apart_fix_the_rotation_too() {
        let (yaw, shift) = (-0.09, Vector2::new(0.2, 0.25));
        let row = Vector3::new(0.0, 0.42, 0.45);
        let container = Vector3::new(3.0, 0.0, 0.35);
        let mut c = OdometryCorrection::new(1.0, 1.0);
        c.observe(0, &row, &drifted(yaw, shift, row));
        c.observe(1, &container, &drifted(yaw, shift, container));
        let next = Vector3::new(0.0, 0.30, 0.45);
        let error = (c.to_odometry(&next) - drifted(yaw, shift, next)).norm();
        assert!(error < 1e-9, "{error}");
        assert!((c.offset()[2] - yaw).abs() < 1e-12);
        // A translation-only correction from the container would be 27 cm off at the row.
        let mut t = OdometryCorrection::new(1.0, 1.0);
        t.observe(1, &container, &drifted(yaw, shift, container));
        assert!((t.to_odometry(&next) - drifted(yaw, shift, next)).norm() > 0.2);
    }

    #[test]
    fn close_landmarks_keep_the_rotation_and_a_third_retires_the_first() {
        let mut c = OdometryCorrection::new(1.0, 1.0);
        let a = Vector3::new(0.0, 0.0, 0.4);
        let b = Vector3::new(0.3, 0.0, 0.4);
        c.observe(0, &a, &(a + Vector3::new(0.1, 0.0, 0.0)));
        c.observe(1, &b, &(b + Vector3::new(0.1, 0.05, 0.0)));
        assert_eq!(c.offset()[2], 0.0);
        assert!((c.to_odometry(&b) - (b + Vector3::new(0.1, 0.05, 0.0))).norm() < 1e-12);
        let d = Vector3::new(3.0, 0.0, 0.4);
        c.observe(2, &d, &d);
        assert_eq!(c.anchors.len(), 2);
        assert_eq!(c.anchors[0].task, 1);
    }

    #[test]
    fn once_the_drift_rate_is_known_the_frame_turns_with_the_base_between_fixes() {
        let mut c = OdometryCorrection::new(1.0, 1.0);
        // The base turns half a turn on the spot at the origin before any fix: no rate yet.
        for k in 0..=100 {
            c.advance(&BasePose::new(
                0.0,
                0.0,
                std::f64::consts::PI * k as f64 / 100.0,
            ));
        }
        assert!(!c.calibrated());
        // Two landmarks 3 m apart show the frame turned by 0.05 rad (1.6 % of the turn).
        let yaw = 0.05;
        let (row, container) = (Vector3::new(0.0, 0.5, 0.4), Vector3::new(3.0, 0.0, 0.4));
        c.observe(0, &row, &drifted(yaw, Vector2::zeros(), row));
        c.observe(1, &container, &drifted(yaw, Vector2::zeros(), container));
        assert!(c.calibrated());
        let rate = yaw / std::f64::consts::PI;
        assert!((c.yaw_drift_rate() - rate).abs() < 1e-9);
        // A quarter turn on the spot at (1, 2): the frame turns by the rate's share of it about
        // the base, which stays where it is in both frames.
        let pivot = Vector3::new(1.0, 2.0, 0.0);
        c.advance(&BasePose::new(1.0, 2.0, 0.0));
        let before = c.offset();
        let pivot_world = {
            let back =
                Rotation2::new(-before[2]) * (pivot.xy() - Vector2::new(before[0], before[1]));
            Vector3::new(back.x, back.y, 0.0)
        };
        for k in 1..=50 {
            c.advance(&BasePose::new(
                1.0,
                2.0,
                std::f64::consts::FRAC_PI_2 * k as f64 / 50.0,
            ));
        }
        let turned = c.offset()[2] - before[2];
        assert!(
            (turned - rate * std::f64::consts::FRAC_PI_2).abs() < 1e-9,
            "{turned}"
        );
        assert!((c.to_odometry(&pivot_world) - pivot).norm() < 1e-9);
        // Non-finite poses are ignored.
        c.advance(&BasePose::new(f64::NAN, 0.0, 0.0));
        assert!((c.offset()[2] - before[2] - turned).abs() < 1e-12);
    }

    #[test]
    fn fixes_of_one_landmark_are_averaged_and_bad_values_ignored() {
        let mut c = OdometryCorrection::new(0.5, 1.0);
        let p = Vector3::new(1.0, 1.0, 0.4);
        c.observe(0, &p, &(p + Vector3::new(0.2, 0.0, 0.0)));
        c.observe(0, &p, &p);
        assert!((c.offset()[0] - 0.1).abs() < 1e-12);
        c.observe(0, &p, &Vector3::new(f64::NAN, 0.0, 0.0));
        assert!((c.offset()[0] - 0.1).abs() < 1e-12);
    }

    #[test]
    fn a_container_is_a_landmark_only_seen_from_within_range() {
        let config = MissionConfig::default();
        let mut l = Localizer::new(&config);
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
        assert!((offset[0] - 0.1).abs() < 1e-12 && (offset[1] - 0.05).abs() < 1e-12);
        // A cube only as its grasp begins, and only seen still.
        let cube = MissionTask {
            kind: TaskKind::Pick,
            item: 1,
            position: Vector3::new(0.0, 0.4, 0.45),
        };
        let mut cube_seen = TargetEstimate::fixed(Vector3::new(0.1, 0.45, 0.45));
        l.locate(1, &cube, &cube_seen, 0.05, false, 3);
        assert_eq!(l.correction().offset(), offset);
        cube_seen.velocity.x = 0.05;
        l.locate(1, &cube, &cube_seen, 0.05, true, 4);
        assert_eq!(l.correction().offset(), offset);
    }
}
