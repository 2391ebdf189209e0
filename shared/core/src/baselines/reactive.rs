//! The reactive baseline's task sequence ("stop and grasp", docs/algorithms.md §3): the holistic
//! controller of [`crate::holistic`] servoes the tool through fixed stages per task.
//!
//! - **Pick:** servo above the cube, descend onto it, close (servoing on), lift to a waypoint
//!   above the platform.
//! - **Place:** servo to the release point above the container, open.
//! - **Press a button:** servo above it, push down, come back up.
//!
//! The base slows to a stop near each target because of the holistic 1/e_t weights.
//!
//! Choices (config values):
//! - **Moving targets.** The holistic law is a pure P servo, which lags a target moving at v by
//!   v/k. Each stage aims at the target predicted `1/servo_gain` ahead (lead compensation), which
//!   removes the steady lag without changing the holistic law itself. Arrival is judged against
//!   the stage's point *without* the lead (the holistic `e_t` to the led point stays near
//!   v/k ≈ 2 cm on a cube moving at 3 cm/s, so the holistic arrival test alone never fires).
//! - **Grasp height.** The descent aims `grasp_depth` below the cube centre and the fingers close
//!   only within `grasp_error` of that point, so the tool point is inside the grasp model's height
//!   window (from 12 mm above to 25 mm below the centre) when the closure starts; closing at the
//!   holistic `e_t < 0.02` left the fingertips on the cube's top edge and knocked it off.
//! - **Orientation.** Top-down. A pick's gripper yaw is the yaw the objects stand at
//!   (`object_yaw`, the same prior as MotM's reacher: perception measures no yaw) plus the
//!   multiple of `yaw_symmetry` closest to the tool's current yaw; other tasks keep the tool's
//!   yaw. Keeping the tool's yaw on a pick, as the holistic reference does, closes the fingers
//!   on a cube turned by up to 45° from them wherever the base comes in at a slant (a row's
//!   cubes approached from the container), and they knock it off.
//! - **Stand.** A pick or a press with other known objects near its target starts, when the
//!   base is far, with a drive to the target's stand: `base_standoff + stand_margin` from it,
//!   in the direction whose footprint clears the other known objects (a row's neighbours,
//!   emptied platforms), nearest the base's side. The base turns on the spot to face it and
//!   drives there (the arm back at its ready pose), then the holistic law takes over, square
//!   to a row. Alone, the holistic law drives the base at
//!   the target along the line it comes from: after a place, reversing from a container, that
//!   line met a row of cubes at its end and at a slant, past platforms already emptied, and the
//!   base was held there for good (10 of 20 Exp 2 runs).
//! - **Base stand-off.** The base does not drive closer than `base_standoff` to the target
//!   (the holistic law alone would run it into the platform): its forward speed toward the
//!   target is capped at the speed from which it can still stop there. The stands of earlier
//!   targets (pick platforms, containers, button pedestals, which the base leaves after the
//!   task) only keep it `platform_clearance` away; every target counts, not picks alone: a base
//!   leaving a container toward a button beyond it drove into the container. The cap cuts
//!   the forward speed alone: the turn rate and the arm keep their command, so the holistic law
//!   can still turn the base away (scaling the whole command to zero froze the robot at a
//!   platform it had to leave). When an earlier platform blocks the way, the base turns in place
//!   toward the side of the current goal at `escape_turn_rate` until the platform leaves its
//!   path: the holistic facing term alone turns the base only as far as the tool, which can leave
//!   the platform in the way for good. A platform beside the target holds the base where its
//!   footprint, swept ahead, would come near it (a row's neighbour, met at a slant, is at the
//!   front corner); a base held so short of its stand-off turns square to the row
//!   (`squaring_tolerance`, `squaring_release`).
//! - **Giving up.** A task whose approach or descent makes no progress for `stall_timeout` is
//!   given up, with its place if it is a pick, and the mission goes on.
//! - **Closing** ends when the fingers reach `closed_opening` or after `closing_timeout`.

use nalgebra::{Isometry3, Translation3, Vector2, Vector3};
use serde::Deserialize;

use crate::holistic::{HolisticConfig, HolisticController, HolisticInput};
use crate::kinematics::BasePose;
use crate::localization::world_to_odometry;
use crate::mission::{MissionTask, TaskKind, give_up_task, next_open_task};
use crate::reacher::{symmetric_yaw, tool_yaw, top_down};
use crate::resolver::ResolveStatus;
use crate::robot::{BASE_JOINTS, Robot};
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate, wrap_angle};

/// Tunables of the reactive baseline's stages.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReactiveConfig {
    /// The holistic controller.
    pub holistic: HolisticConfig,
    /// Height of the pre-grasp point above the cube centre, m: high enough that the fingertips
    /// (45 mm below the tool point) clear the cube top on the way in.
    pub approach_height: f64,
    /// How far below the cube centre the tool point aims for the grasp, m. The grasp model's
    /// height window puts the tool point between 12 mm above and 25 mm below the centre (45 mm
    /// fingers, tips 5 mm past the tool point, 30 mm cube, 8 mm least pad overlap); 5 mm below
    /// sits near its middle and keeps the fingertips 5 mm above the platform top.
    pub grasp_depth: f64,
    /// The fingers start closing once the tool-frame L1 error to the grasp point (without the
    /// lead) is below this, m. 10 mm keeps the tool point inside the height window and the cube
    /// within the 15 mm lateral tolerance with room for perception and odometry error; the
    /// holistic arrival threshold (20 mm) does not. A push on a button ends within it too.
    pub grasp_error: f64,
    /// Height of the waypoint above the grasp point after closing, m.
    pub lift_height: f64,
    /// Height of the release point above the container rim, m.
    pub release_height: f64,
    /// Finger opening at which the grasp counts as closed, m.
    pub closed_opening: f64,
    /// Longest wait for the fingers to close, s.
    pub closing_timeout: f64,
    /// Wait after opening before the task counts as done, s.
    pub opening_time: f64,
    /// How far below the button top the tool point aims, m. The push ends within `grasp_error`
    /// of that point, so 20 mm pushes the cap at least 10 mm (the scenarios' switching travel)
    /// with the fingertips 5 mm past the tool point; ending at the holistic arrival (20 mm L1)
    /// with a 10 mm aim left the button unpressed.
    pub press_depth: f64,
    /// Closest the base centre may drive toward the current target horizontally, m. The
    /// holistic law has no obstacle model and would drive the base into the platform; inside
    /// this distance its forward speed toward the target is clamped to zero and the arm reaches.
    pub base_standoff: f64,
    /// Closest the base centre may drive toward an earlier target's stand (one it is leaving),
    /// measured along its heading, m. The base may have to turn in place there to get out of
    /// the platform's way, so this is the radius its footprint sweeps when turning (Frankie's
    /// 0.68 × 0.47 m footprint: 0.41 m half-diagonal) plus a platform's half-diagonal (0.21 m
    /// for the simulator's 0.3 m platform) plus 13 cm for odometry drift.
    pub platform_clearance: f64,
    /// Radius of a pick platform's footprint, m: the simulator's 0.3 m square platform's
    /// half-diagonal. An earlier platform beside the current target (one the base does not
    /// have to pass, such as the next one along a row) stops the base only when its footprint,
    /// grown by `footprint_margin`, would touch the base's: the leaving clearance there would
    /// hold the base out of the arm's reach of a target whose neighbours it approaches at a
    /// slant.
    pub platform_radius: f64,
    /// Margin kept between the base's footprint and a platform beside the target, m.
    pub footprint_margin: f64,
    /// Lag of the base's response to its command, s: the base overshoots the point where the
    /// speed cap stops it by its speed times this (it was measured to stop 5 cm past it from
    /// 0.3 m/s), and the cap for a platform beside the target allows for it. At a crawl the
    /// overshoot is nil, so a base creeping up to a row's neighbour is not held back for it.
    pub response_lag: f64,
    /// A pick or a press whose target is farther than this from its stand (m) begins with a
    /// drive to the stand: a point `base_standoff + stand_margin` from the target, in the
    /// direction out of the layout's way ([`ReactiveBaseline::stand`]) nearest the base's
    /// side. The holistic law alone drives the base at the target along the line it comes
    /// from; after a place, reversing from a container, that line met a row of cubes at its
    /// end and at a slant, past platforms already emptied, where the base was held for good.
    pub stand_travel_distance: f64,
    /// How much farther than `base_standoff` from the target the stand is, m: room for the
    /// holistic law to close in square.
    pub stand_margin: f64,
    /// The drive to the stand ends within this of it, m.
    pub stand_tolerance: f64,
    /// The drive to the stand turns on the spot while the stand's bearing is off the heading
    /// by more than this, rad; within it, it steers (heading gain `stand_heading_gain`).
    pub stand_turn_bearing: f64,
    /// Turn rate on the spot on the drive to the stand, rad/s.
    pub stand_turn_rate: f64,
    /// Turn rate per radian of the stand's bearing while driving to it, 1/s.
    pub stand_heading_gain: f64,
    /// Gain of the arm's return to its ready pose on the drive to the stand, 1/s (the tool is
    /// then high above the platforms, and the camera looks ahead of the base).
    pub ready_gain: f64,
    /// Turn rate while an earlier platform blocks the way, rad/s (a third of Frankie's 1.5 rad/s
    /// limit: a quarter turn takes about 3 s).
    pub escape_turn_rate: f64,
    /// A base held within this of a platform beside the target, and farther than this beyond
    /// `base_standoff` from the current target, turns square to the row, m.
    pub squaring_tolerance: f64,
    /// A squaring turn goes on until the platform leaves this much room ahead, m.
    pub squaring_release: f64,
    /// Half-width of the strip ahead of the base in which a platform counts as in its path, m
    /// (half the base width plus half a platform plus a margin).
    pub base_corridor: f64,
    /// Yaw the mission's objects stand at about world z, rad (MotM's `reacher.object_yaw`).
    pub object_yaw: f64,
    /// Symmetry of the objects about the vertical, rad (MotM's `reacher.yaw_symmetry`: π/2 for
    /// a cube).
    pub yaw_symmetry: f64,
    /// A task is given up (reported failed; the mission goes on with the next task that does
    /// not need it) when its approach or descent has not brought the tool `progress_distance`
    /// nearer its point for this long, s. 20 s: a drive to a target improves by that much every
    /// tenth of a second, and the stalls seen (a base held by a row's platforms with the arm at
    /// its reach, a base turning to and fro between two of them) last for good.
    pub stall_timeout: f64,
    /// Least improvement of the stage's error that counts as progress, m.
    pub progress_distance: f64,
    /// Largest base forward speed, m/s: the trial's v_F, so every method has the same top speed
    /// (the holistic law alone would drive Frankie's base at its 1.2 m/s limit).
    pub max_base_speed: f64,
}

impl Default for ReactiveConfig {
    fn default() -> Self {
        Self {
            holistic: HolisticConfig::default(),
            approach_height: 0.1,
            grasp_depth: 0.005,
            grasp_error: 0.01,
            lift_height: 0.15,
            release_height: 0.1,
            closed_opening: 0.032,
            closing_timeout: 1.0,
            opening_time: 0.5,
            press_depth: 0.02,
            base_standoff: 0.7,
            platform_clearance: 0.75,
            platform_radius: 0.21,
            footprint_margin: 0.05,
            response_lag: 0.23,
            stand_travel_distance: 0.5,
            stand_margin: 0.05,
            stand_tolerance: 0.1,
            stand_turn_bearing: 0.5,
            stand_turn_rate: 1.0,
            stand_heading_gain: 1.5,
            ready_gain: 1.0,
            escape_turn_rate: 0.5,
            squaring_tolerance: 0.03,
            squaring_release: 0.1,
            base_corridor: 0.55,
            object_yaw: 0.0,
            yaw_symmetry: std::f64::consts::FRAC_PI_2,
            stall_timeout: 20.0,
            progress_distance: 0.02,
            max_base_speed: 0.3,
        }
    }
}

/// Where the baseline stands within the current task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReactiveStage {
    /// Servoing to the point above the target.
    Approach,
    /// Descending onto the cube, or pushing the button.
    Descend,
    /// Fingers closing (pick) or opening (place).
    Gripper,
    /// Going up to the waypoint above the target.
    Lift,
    /// Every task is done.
    Complete,
}

/// The current approach's drive to its target's stand ([`ReactiveBaseline::stand`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum StandDrive {
    /// Not decided yet: the approach's first cycle decides.
    Undecided,
    /// The holistic law alone (no stand, the base near it, or there).
    Holistic,
    /// Driving to the stand in this direction from the target.
    To(Vector2<f64>),
}

/// One cycle's input.
#[derive(Debug, Clone, Copy)]
pub struct ReactiveInput<'a> {
    /// Time, s.
    pub t: f64,
    /// Base pose (odometry).
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Measured finger opening, m.
    pub gripper_opening: f64,
    /// Estimate of the current task's target.
    pub target: TargetEstimate,
    /// The odometry frame against the world (`[x, y, yaw]`,
    /// [`crate::localization::OdometryCorrection::offset`]): where the known platforms are.
    pub odometry_offset: [f64; 3],
}

/// One cycle's output.
#[derive(Debug, Clone, PartialEq)]
pub struct ReactiveOutput {
    /// Base command.
    pub base: BaseVelocity,
    /// Arm joint velocity command.
    pub arm_qd: Vec<f64>,
    /// Gripper command.
    pub gripper: GripperCommand,
    /// Stage after this cycle.
    pub stage: ReactiveStage,
    /// Index of the current task after this cycle.
    pub task_index: usize,
    /// QP status.
    pub qp_status: ResolveStatus,
    /// The holistic controller's e_t, m.
    pub position_error: f64,
    /// Distance from the tool to the input's target as the cycle began, m.
    pub tool_to_target: f64,
}

/// The reactive (holistic, stop-and-grasp) baseline over a list of tasks.
pub struct ReactiveBaseline {
    controller: HolisticController,
    config: ReactiveConfig,
    robot: Robot,
    tasks: Vec<MissionTask>,
    task: usize,
    stage: ReactiveStage,
    stage_start: f64,
    /// The grasp point and the held pose of the lift waypoint, fixed when the fingers close.
    anchor: Option<Vector3<f64>>,
    /// Whether each task was given up.
    failed: Vec<bool>,
    /// The platform a squaring turn is freeing the base from, and the turn rate.
    squaring: Option<(usize, f64)>,
    /// The current approach's drive to its stand.
    stand: StandDrive,
    /// When the stage's error last reached a new best by `progress_distance`, and that best.
    progress: Option<(f64, f64)>,
    gripper: GripperCommand,
    /// The base's forward acceleration limit, m/s² (from the model).
    base_deceleration: f64,
    /// The base footprint's half-length and half-width, m.
    half_footprint: [f64; 2],
    /// Fastest each arm joint returns to its ready pose, rad/s or m/s
    /// ([`READY_SPEED_SHARE`] of its limit).
    ready_speed: Vec<f64>,
}

impl ReactiveBaseline {
    /// A baseline for `robot` performing `tasks`.
    pub fn new(robot: Robot, config: ReactiveConfig, tasks: Vec<MissionTask>) -> Self {
        let stage = if tasks.is_empty() {
            ReactiveStage::Complete
        } else {
            ReactiveStage::Approach
        };
        let [length, width] = robot.config.footprint;
        let ready_speed = robot
            .limits()
            .iter()
            .skip(BASE_JOINTS)
            .map(|limits| READY_SPEED_SHARE * limits.velocity)
            .collect();
        Self {
            ready_speed,
            failed: vec![false; tasks.len()],
            half_footprint: [0.5 * length, 0.5 * width],
            base_deceleration: robot.limits()[1].acceleration,
            controller: HolisticController::new(robot.clone(), config.holistic.clone()),
            config,
            robot,
            tasks,
            task: 0,
            stage,
            stage_start: 0.0,
            anchor: None,
            progress: None,
            squaring: None,
            stand: StandDrive::Undecided,
            gripper: GripperCommand::Open,
        }
    }

    /// The stage within the current task.
    pub fn stage(&self) -> ReactiveStage {
        self.stage
    }

    /// Index of the current task.
    pub fn task_index(&self) -> usize {
        self.task
    }

    /// The current task, if any is left.
    pub fn current_task(&self) -> Option<&MissionTask> {
        self.tasks.get(self.task)
    }

    /// Errors of the holistic QP so far.
    pub fn error_count(&self) -> u64 {
        self.controller.error_count()
    }

    /// Moves to `stage` at time `t`.
    fn enter(&mut self, stage: ReactiveStage, t: f64) {
        self.stage = stage;
        self.stage_start = t;
        self.progress = None;
        self.stand = StandDrive::Undecided;
    }

    /// Records the stage's error at time `t` and tells whether the stage has stalled: its
    /// error has not come `progress_distance` below its best for `stall_timeout`.
    fn stalled(&mut self, t: f64, stage_error: f64) -> bool {
        let (since, best) = match self.progress {
            Some((_, best)) if stage_error < best - self.config.progress_distance => {
                (t, stage_error)
            }
            Some(progress) => progress,
            None => (t, stage_error),
        };
        self.progress = Some((since, best));
        t - since > self.config.stall_timeout
    }

    /// How many tasks were given up.
    pub fn failed_tasks(&self) -> usize {
        self.failed.iter().filter(|&&f| f).count()
    }

    /// Finishes the current task.
    fn next_task(&mut self, t: f64) {
        self.task = next_open_task(&self.failed, self.task + 1);
        self.go_on(t);
    }

    /// Gives the current task up ([`give_up_task`]: a pick's place goes with it), opens the
    /// fingers and goes on with the next task.
    fn give_up(&mut self, t: f64) {
        self.task = give_up_task(&self.tasks, &mut self.failed, self.task);
        self.gripper = GripperCommand::Open;
        self.go_on(t);
    }

    /// Starts the current task (or completes the mission when none is left).
    fn go_on(&mut self, t: f64) {
        self.anchor = None;
        let stage = if self.task >= self.tasks.len() {
            ReactiveStage::Complete
        } else {
            ReactiveStage::Approach
        };
        self.enter(stage, t);
    }

    /// The point the tool should be at in the current stage, for the target predicted `lead`
    /// seconds ahead.
    fn goal(&self, kind: TaskKind, target: &TargetEstimate, lead: f64) -> Vector3<f64> {
        let aim = target.predict(lead);
        let up = Vector3::z();
        match (kind, self.stage) {
            (TaskKind::Pick, ReactiveStage::Approach) => aim + up * self.config.approach_height,
            (TaskKind::Pick, ReactiveStage::Lift) => {
                self.anchor.unwrap_or(aim) + up * self.config.lift_height
            }
            (TaskKind::Pick, _) => aim - up * self.config.grasp_depth,
            (TaskKind::Place, _) => aim + up * self.config.release_height,
            (TaskKind::PressButton, ReactiveStage::Descend) => aim - up * self.config.press_depth,
            (TaskKind::PressButton, _) => aim + up * self.config.approach_height,
        }
    }

    /// Caps the forward speed so the base can still stop short of any target's stand that lies
    /// ahead in its path (within `base_corridor` of its heading line): `base_standoff` short of
    /// the current target where it is seen (`target`: the known position can be metres of drift
    /// or a neighbour's spacing off, and a stand-off from it can hold the base out of the arm's
    /// reach of the cube for good), `platform_clearance` short of earlier ones it has to pass and
    /// clear of those beside the target ([`Self::room_beside`]), where it also allows for the
    /// overshoot of its response lag.
    fn clamp_forward_speed(
        &self,
        base: &BasePose,
        target: &Vector3<f64>,
        offset: &[f64; 3],
        v: f64,
    ) -> f64 {
        let heading = Vector2::new(base.yaw.cos(), base.yaw.sin()) * v.signum();
        let from = Vector2::new(base.x, base.y);
        let last = (self.task + 1).min(self.tasks.len());
        let deceleration = self.base_deceleration;
        // The overshoot is the speed times the response lag, so the speed that stops in `room`
        // with it solves v² = 2a·(room − lag·v).
        let lag_term = deceleration * self.config.response_lag;
        let stoppable = self.tasks[..last]
            .iter()
            .enumerate()
            .filter_map(|(index, t)| {
                let current = index == self.task;
                let position = if current {
                    *target
                } else {
                    world_to_odometry(offset, &t.position)
                };
                let offset = position.xy() - from;
                let (along, beside) = along_and_beside(&offset, &heading);
                if !current && !self.passes(&offset, &(target.xy() - from)) {
                    return self.room_beside(along, beside).map(|room| {
                        (lag_term * lag_term + 2.0 * deceleration * room).sqrt() - lag_term
                    });
                }
                let keep = if current {
                    self.config.base_standoff
                } else {
                    self.config.platform_clearance
                };
                (along > 0.0 && beside < self.config.base_corridor)
                    .then(|| (2.0 * deceleration * (along - keep).max(0.0)).sqrt())
            })
            .fold(f64::INFINITY, f64::min);
        v.clamp(-stoppable, stoppable)
    }

    /// How far the base can drive straight ahead before its footprint (a rectangle) comes
    /// within `platform_radius + footprint_margin` of a platform `along` ahead of its centre
    /// and `beside` its heading line (m); `None` when the base passes it by. The swept
    /// rectangle, not a corridor and a distance along the heading: a platform of a row that the
    /// base meets at a slant is near the base's front corner, not its front.
    fn room_beside(&self, along: f64, beside: f64) -> Option<f64> {
        let [half_length, half_width] = self.half_footprint;
        let keep = self.config.platform_radius + self.config.footprint_margin;
        let lateral = (beside - half_width).max(0.0);
        (along > 0.0 && lateral < keep)
            .then(|| (along - half_length - (keep * keep - lateral * lateral).sqrt()).max(0.0))
    }

    /// Whether the base, to come within `base_standoff` of a goal at `to_goal` (from the base),
    /// has to pass a platform at `to_platform`. A platform beside the goal, such as the next
    /// one along a row, is not passed: the base keeps only clear of it
    /// (`platform_radius`) rather than the leaving clearance, and does not turn away from it.
    fn passes(&self, to_platform: &Vector2<f64>, to_goal: &Vector2<f64>) -> bool {
        to_goal.norm() > to_platform.norm() + self.config.base_standoff
    }

    /// The direction from `target` (odometry) of its stand, `base_standoff + stand_margin` out:
    /// of the directions every 10° whose footprint there, facing the target, keeps
    /// `platform_radius + footprint_margin` from every other known object (a row's neighbours,
    /// platforms emptied earlier), the one nearest the base's side. `None` when none is clear,
    /// and when no other object is within the stand's reach (its distance plus the footprint's
    /// half-length): a lone target's holistic approach meets nothing.
    fn stand(
        &self,
        target: &Vector3<f64>,
        base: &BasePose,
        offset: &[f64; 3],
    ) -> Option<Vector2<f64>> {
        let [half_length, half_width] = self.half_footprint;
        let distance = self.stand_distance();
        let keep = self.config.platform_radius + self.config.footprint_margin;
        let others: Vec<Vector2<f64>> = self
            .tasks
            .iter()
            .enumerate()
            .filter(|&(index, _)| index != self.task)
            .map(|(_, t)| world_to_odometry(offset, &t.position).xy() - target.xy())
            .filter(|p| p.norm() > self.config.stand_tolerance)
            .filter(|p| p.norm() < distance + half_length + keep)
            .collect();
        if others.is_empty() {
            return None;
        }
        let clear = |n: &Vector2<f64>| {
            others.iter().all(|p| {
                let (along, beside) = along_and_beside(p, n);
                let out = Vector2::new(
                    ((along - distance).abs() - half_length).max(0.0),
                    (beside - half_width).max(0.0),
                );
                out.norm() >= keep
            })
        };
        let side = (Vector2::new(base.x, base.y) - target.xy()).normalize();
        (0..STAND_DIRECTIONS)
            .map(|k| {
                let angle = std::f64::consts::TAU * k as f64 / STAND_DIRECTIONS as f64;
                Vector2::new(angle.cos(), angle.sin())
            })
            .filter(clear)
            .max_by(|a, b| a.dot(&side).total_cmp(&b.dot(&side)))
    }

    /// How far from its target a stand is, m: `base_standoff + stand_margin`.
    fn stand_distance(&self) -> f64 {
        self.config.base_standoff + self.config.stand_margin
    }

    /// The drive to the stand `stand` (odometry), and the arm's return to its ready pose:
    /// `None` once the base is within `stand_tolerance` of it.
    fn drive_to_stand(
        &self,
        input: &ReactiveInput<'_>,
        stand: &Vector2<f64>,
    ) -> Option<(BaseVelocity, Vec<f64>)> {
        let base = &input.base;
        let to_stand = stand - Vector2::new(base.x, base.y);
        let distance = to_stand.norm();
        if distance < self.config.stand_tolerance {
            return None;
        }
        let bearing = wrap_angle(to_stand.y.atan2(to_stand.x) - base.yaw);
        let rate = self.config.stand_turn_rate;
        let velocity = if bearing.abs() > self.config.stand_turn_bearing {
            BaseVelocity {
                v: 0.0,
                omega: rate.copysign(bearing),
            }
        } else {
            let v = (2.0 * self.base_deceleration * distance)
                .sqrt()
                .min(self.config.max_base_speed);
            BaseVelocity {
                v: self.clamp_forward_speed(
                    base,
                    &input.target.position,
                    &input.odometry_offset,
                    v,
                ),
                omega: (self.config.stand_heading_gain * bearing).clamp(-rate, rate),
            }
        };
        let arm_qd = self
            .robot
            .config
            .ready_pose
            .iter()
            .zip(input.arm_q)
            .zip(&self.ready_speed)
            .map(|((ready, q), top)| (self.config.ready_gain * (ready - q)).clamp(-top, *top))
            .collect();
        Some((velocity, arm_qd))
    }

    /// The turn that takes the base out of an earlier target's stand's way, when one blocks it:
    /// the platform lies in the strip ahead within `platform_clearance`, the base would have to
    /// pass it to come within `base_standoff` of `goal` (a platform beside the goal, such as
    /// the next one along a row, is not in the way), and the turn is toward the side of `goal`
    /// (world point) relative to the platform.
    fn escape_turn(&self, base: &BasePose, goal: &Vector3<f64>, offset: &[f64; 3]) -> Option<f64> {
        let heading = Vector2::new(base.yaw.cos(), base.yaw.sin());
        let from = Vector2::new(base.x, base.y);
        let to_goal = goal.xy() - from;
        self.tasks[..self.task.min(self.tasks.len())]
            .iter()
            .map(|t| world_to_odometry(offset, &t.position).xy() - from)
            .filter(|offset| {
                let (along, beside) = along_and_beside(offset, &heading);
                along > 0.0
                    && along <= self.config.platform_clearance
                    && beside < self.config.base_corridor
                    && self.passes(offset, &to_goal)
            })
            .map(|offset| {
                let side = offset.perp(&to_goal);
                self.config.escape_turn_rate * if side >= 0.0 { 1.0 } else { -1.0 }
            })
            .next()
    }

    /// The turn that frees a base held short of its stand-off from the current target (by
    /// more than `squaring_tolerance`) by an earlier target's stand beside the target (with less
    /// than `squaring_tolerance` of room), such as
    /// the next one along a row that the base meets at a slant: its front corner is what comes
    /// near the platform, and a turn toward the platform's side swings that corner back and
    /// squares the base's front to the row. The holistic law then drives on.
    fn squaring_turn(
        &mut self,
        base: &BasePose,
        target: &Vector3<f64>,
        offset: &[f64; 3],
    ) -> Option<f64> {
        let heading = Vector2::new(base.yaw.cos(), base.yaw.sin());
        let from = Vector2::new(base.x, base.y);
        let to_target = target.xy() - from;
        let room = |index: usize| {
            let to_platform = world_to_odometry(offset, &self.tasks[index].position).xy() - from;
            let (along, beside) = along_and_beside(&to_platform, &heading);
            (to_platform, self.room_beside(along, beside))
        };
        // A turn once begun goes on until the platform is `squaring_release` clear: the holistic
        // law's facing term, turning the base back at once, held it there for minutes.
        let held = self.squaring.filter(|&(index, _)| {
            room(index)
                .1
                .is_some_and(|r| r < self.config.squaring_release)
        });
        if held.is_some() {
            return held.map(|(_, omega)| omega);
        }
        if to_target.dot(&heading) < self.config.base_standoff + self.config.squaring_tolerance {
            return None;
        }
        let Some((index, to_platform)) = (0..self.task.min(self.tasks.len()))
            .map(|index| (index, room(index)))
            .filter(|(_, (to_platform, _))| !self.passes(to_platform, &to_target))
            .find(|(_, (_, room))| room.is_some_and(|room| room < self.config.squaring_tolerance))
            .map(|(index, (to_platform, _))| (index, to_platform))
        else {
            self.squaring = None;
            return None;
        };
        let left = heading.perp(&to_platform) >= 0.0;
        let omega = self.config.escape_turn_rate * if left { 1.0 } else { -1.0 };
        self.squaring = Some((index, omega));
        Some(omega)
    }

    /// One control cycle.
    pub fn step(&mut self, input: &ReactiveInput<'_>) -> ReactiveOutput {
        let tool = self.robot.tool_pose(&input.base, input.arm_q);
        let tool_to_target = (tool.translation.vector - input.target.position).norm();
        let Some(task) = self.current_task().copied() else {
            return self.idle(tool_to_target);
        };
        let goal = self.goal(
            task.kind,
            &input.target,
            1.0 / self.config.holistic.servo_gain,
        );
        // Distance to the stage's point where the target is now (no lead), in the holistic
        // law's own measure (L1 norm of the tool-frame translation).
        let stage_error = tool
            .inverse_transform_point(&self.goal(task.kind, &input.target, 0.0).into())
            .coords
            .abs()
            .sum();
        let arrived = stage_error < self.config.holistic.arrival_error;
        let reaching = matches!(self.stage, ReactiveStage::Approach | ReactiveStage::Descend);
        if self.stalled(input.t, stage_error) && reaching {
            self.give_up(input.t);
            return self.step(input);
        }
        let stand_distance = self.stand_distance();
        let stand_at = |n: &Vector2<f64>| input.target.position.xy() + n * stand_distance;
        if self.stage == ReactiveStage::Approach && self.stand == StandDrive::Undecided {
            let far = |n: &Vector2<f64>| {
                (stand_at(n) - Vector2::new(input.base.x, input.base.y)).norm()
                    > self.config.stand_travel_distance
            };
            self.stand = (task.kind != TaskKind::Place)
                .then(|| self.stand(&input.target.position, &input.base, &input.odometry_offset))
                .flatten()
                .filter(far)
                .map_or(StandDrive::Holistic, StandDrive::To);
        }
        if let StandDrive::To(n) = self.stand {
            match self.drive_to_stand(input, &stand_at(&n)) {
                Some((base, arm_qd)) => {
                    return self.output(
                        base,
                        arm_qd,
                        ResolveStatus::Solved,
                        stage_error,
                        tool_to_target,
                    );
                }
                None => self.stand = StandDrive::Holistic,
            }
        }
        let current_yaw = tool_yaw(&tool.rotation);
        let yaw = match task.kind {
            TaskKind::Pick => symmetric_yaw(
                self.config.object_yaw + input.odometry_offset[2],
                self.config.yaw_symmetry,
                current_yaw,
            ),
            _ => current_yaw,
        };
        let rotation = top_down(yaw);
        let target = Isometry3::from_parts(Translation3::from(goal), rotation);
        let out = self.controller.step(&HolisticInput {
            base: input.base,
            arm_q: input.arm_q,
            target,
        });
        // The top speed scales the whole command (base and arm alike), so the tool still moves
        // along the direction the QP chose instead of the arm assuming a base motion that is cut.
        let scale = if out.base.v.abs() > self.config.max_base_speed {
            self.config.max_base_speed / out.base.v.abs()
        } else {
            1.0
        };
        // The stand-off cuts the forward speed alone, so the base can still turn away.
        let offset = &input.odometry_offset;
        // The escape turn is for a base that wants to drive on toward the target: never while
        // the fingers are at the cube (descending, closing, lifting), where turning the base
        // sweeps the tool across the platform.
        let escaping = self.stage == ReactiveStage::Approach && out.base.v > 0.0;
        let escape = escaping
            .then(|| {
                self.escape_turn(&input.base, &goal, offset)
                    .or_else(|| self.squaring_turn(&input.base, &input.target.position, offset))
            })
            .flatten();
        let base = match escape {
            Some(omega) => BaseVelocity { v: 0.0, omega },
            None => BaseVelocity {
                v: self.clamp_forward_speed(
                    &input.base,
                    &input.target.position,
                    offset,
                    out.base.v * scale,
                ),
                omega: out.base.omega * scale,
            },
        };
        let arm_qd: Vec<f64> = out.arm_qd.iter().map(|qd| qd * scale).collect();
        let elapsed = input.t - self.stage_start;
        match (task.kind, self.stage) {
            (_, ReactiveStage::Approach) if arrived => {
                let next = match task.kind {
                    TaskKind::Place => ReactiveStage::Gripper,
                    _ => ReactiveStage::Descend,
                };
                self.enter(next, input.t);
            }
            (TaskKind::Pick, ReactiveStage::Descend) if stage_error < self.config.grasp_error => {
                self.gripper = GripperCommand::Close;
                self.enter(ReactiveStage::Gripper, input.t);
            }
            (TaskKind::PressButton, ReactiveStage::Descend)
                if stage_error < self.config.grasp_error =>
            {
                self.enter(ReactiveStage::Lift, input.t);
            }
            (TaskKind::Pick, ReactiveStage::Gripper)
                if input.gripper_opening <= self.config.closed_opening
                    || elapsed >= self.config.closing_timeout =>
            {
                self.anchor = Some(tool.translation.vector);
                self.enter(ReactiveStage::Lift, input.t);
            }
            (TaskKind::Place, ReactiveStage::Gripper) => {
                self.gripper = GripperCommand::Open;
                if elapsed >= self.config.opening_time {
                    self.next_task(input.t);
                }
            }
            (_, ReactiveStage::Lift) if arrived => self.next_task(input.t),
            _ => {}
        }
        if task.kind == TaskKind::PressButton {
            self.gripper = GripperCommand::Close;
        }
        self.output(base, arm_qd, out.status, out.position_error, tool_to_target)
    }

    /// The command once every task is done: stand still, gripper as it was.
    fn idle(&self, tool_to_target: f64) -> ReactiveOutput {
        self.output(
            BaseVelocity::default(),
            vec![0.0; self.robot.arm_dof()],
            ResolveStatus::Solved,
            0.0,
            tool_to_target,
        )
    }

    /// This cycle's output: the commands, with the gripper, stage and task as they stand.
    fn output(
        &self,
        base: BaseVelocity,
        arm_qd: Vec<f64>,
        qp_status: ResolveStatus,
        position_error: f64,
        tool_to_target: f64,
    ) -> ReactiveOutput {
        ReactiveOutput {
            base,
            arm_qd,
            gripper: self.gripper,
            stage: self.stage,
            task_index: self.task,
            qp_status,
            position_error,
            tool_to_target,
        }
    }
}

/// Directions tried for a target's stand ([`ReactiveBaseline::stand`]): every 10°.
const STAND_DIRECTIONS: usize = 36;

/// Share of each arm joint's velocity limit its return to the ready pose may use.
const READY_SPEED_SHARE: f64 = 0.5;

/// How far `offset` (from the base) lies ahead along the unit `heading`, and how far beside the
/// heading line, m.
fn along_and_beside(offset: &Vector2<f64>, heading: &Vector2<f64>) -> (f64, f64) {
    let along = offset.dot(heading);
    (along, (offset - heading * along).norm())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn frankie() -> Robot {
        let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&config_dir, "frankie").expect("frankie loads")
    }

    /// Pick a cube at (2, 0, 0.45), place it at (3.2, 2.4, 0.35) (exp1's layout).
    fn exp1_baseline() -> ReactiveBaseline {
        let tasks = vec![
            MissionTask {
                kind: TaskKind::Pick,
                item: 0,
                position: Vector3::new(2.0, 0.0, 0.45),
            },
            MissionTask {
                kind: TaskKind::Place,
                item: 0,
                position: Vector3::new(3.2, 2.4, 0.35),
            },
        ];
        ReactiveBaseline::new(frankie(), ReactiveConfig::default(), tasks)
    }

    fn step_at(
        baseline: &mut ReactiveBaseline,
        base: BasePose,
        target: Vector3<f64>,
    ) -> ReactiveOutput {
        let arm_q = baseline.robot.config.ready_pose.clone();
        baseline.step(&ReactiveInput {
            t: 0.0,
            base,
            arm_q: &arm_q,
            gripper_opening: 0.08,
            target: TargetEstimate::fixed(target),
            odometry_offset: [0.0; 3],
        })
    }

    #[test]
    fn descent_aims_below_the_cube_centre_inside_the_grasp_window() {
        let mut baseline = exp1_baseline();
        baseline.stage = ReactiveStage::Descend;
        let cube = Vector3::new(2.0, 0.0, 0.45);
        let goal = baseline.goal(TaskKind::Pick, &TargetEstimate::fixed(cube), 0.0);
        let below = cube.z - goal.z;
        assert!((below - baseline.config.grasp_depth).abs() < 1e-12);
        // Tool point between 12 mm above and 25 mm below the centre, even at the full error.
        assert!(below + baseline.config.grasp_error < 0.025);
        assert!(below - baseline.config.grasp_error > -0.012);
    }

    #[test]
    fn lead_does_not_count_toward_arrival_on_a_moving_cube() {
        let mut baseline = exp1_baseline();
        let base = BasePose::default();
        let tool = baseline
            .robot
            .tool_pose(&base, &baseline.robot.config.ready_pose)
            .translation
            .vector;
        // The cube sits right under the approach point and moves at 4.5 cm/s: the led point is
        // 3 cm ahead, yet the tool is where the stage wants it now.
        let cube = tool - Vector3::z() * baseline.config.approach_height;
        let arm_q = baseline.robot.config.ready_pose.clone();
        let out = baseline.step(&ReactiveInput {
            t: 0.0,
            base,
            arm_q: &arm_q,
            gripper_opening: 0.08,
            target: TargetEstimate {
                position: cube,
                velocity: Vector3::new(0.045, 0.0, 0.0),
            },
            odometry_offset: [0.0; 3],
        });
        assert!(out.position_error >= baseline.config.holistic.arrival_error);
        assert_eq!(out.stage, ReactiveStage::Descend);
    }

    #[test]
    fn base_stops_short_of_the_pick_platform() {
        let mut baseline = exp1_baseline();
        let at_standoff = BasePose {
            x: 2.0 - baseline.config.base_standoff,
            y: 0.0,
            yaw: 0.0,
        };
        let out = step_at(&mut baseline, at_standoff, Vector3::new(2.0, 0.0, 0.45));
        assert!(out.base.v <= 1e-9, "v = {}", out.base.v);
        // Far away the base drives at the top speed.
        let mut far = exp1_baseline();
        let out = step_at(&mut far, BasePose::default(), Vector3::new(2.0, 0.0, 0.45));
        assert!((out.base.v - far.config.max_base_speed).abs() < 1e-9);
    }

    #[test]
    fn the_stand_off_is_from_where_the_cube_is_seen() {
        // The cube is seen 0.8 m beyond its known position: inside the known position's
        // stand-off the base still drives on toward it.
        let mut baseline = exp1_baseline();
        let inside_known_standoff = BasePose {
            x: 1.5,
            y: 0.0,
            yaw: 0.0,
        };
        let out = step_at(
            &mut baseline,
            inside_known_standoff,
            Vector3::new(2.8, 0.0, 0.45),
        );
        assert!(out.base.v > 0.05, "v = {}", out.base.v);
    }

    #[test]
    fn base_turns_out_of_the_way_of_a_platform_it_has_picked_from() {
        let mut baseline = exp1_baseline();
        baseline.task = 1;
        let facing_platform = BasePose {
            x: 1.3,
            y: 0.0,
            yaw: 0.0,
        };
        let out = step_at(&mut baseline, facing_platform, Vector3::new(3.2, 2.4, 0.35));
        assert_eq!(out.base.v, 0.0);
        // The container is to the left: turn left.
        assert!((out.base.omega - baseline.config.escape_turn_rate).abs() < 1e-12);
        // Once the platform is out of the strip ahead, the holistic law drives again.
        let clear = BasePose {
            yaw: 1.0,
            ..facing_platform
        };
        let out = step_at(&mut baseline, clear, Vector3::new(3.2, 2.4, 0.35));
        assert!(out.base.v > 0.0);
    }

    #[test]
    fn a_platform_beside_the_next_cube_of_a_row_neither_turns_nor_holds_back_the_base() {
        // Two cubes of a slanted row; the first is picked and placed, the base drives at the
        // second with the first's platform 0.70 m ahead, inside the leaving clearance.
        let pick = |x: f64, y: f64| MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: Vector3::new(x, y, 0.45),
        };
        let place = MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(3.2, 2.4, 0.35),
        };
        let tasks = vec![pick(1.95, 0.12), place, pick(2.0, 0.0)];
        let mut baseline = ReactiveBaseline::new(frankie(), ReactiveConfig::default(), tasks);
        baseline.task = 2;
        let base = BasePose {
            x: 1.25,
            y: 0.0,
            yaw: 0.0,
        };
        let cube = Vector3::new(2.0, 0.0, 0.45);
        assert!(baseline.config.platform_clearance > 0.7);
        assert_eq!(baseline.escape_turn(&base, &cube, &[0.0; 3]), None);
        let v = baseline.clamp_forward_speed(&base, &cube, &[0.0; 3], 0.3);
        assert!(v > 0.05, "v = {v}");
        // Nearer, the cap allows for the base's response lag; where the footprint would come
        // within the platform's radius and margin (0.60 m ahead for Frankie), it stops the base.
        let closer = BasePose { x: 1.29, ..base };
        let v = baseline.clamp_forward_speed(&closer, &cube, &[0.0; 3], 0.3);
        assert!(v < 0.15, "v = {v}");
        let touching = BasePose { x: 1.35, ..base };
        let v = baseline.clamp_forward_speed(&touching, &cube, &[0.0; 3], 0.3);
        assert!(v.abs() < 1e-9, "v = {v}");
    }

    /// Five cubes in a row along y at x = 0, 0.12 m apart, each placed at (3, 0); working on
    /// the middle one's pick.
    fn row_baseline() -> ReactiveBaseline {
        let tasks = (0..5)
            .flat_map(|k| {
                let y = 0.24 - 0.12 * k as f64;
                [
                    MissionTask {
                        kind: TaskKind::Pick,
                        item: k,
                        position: Vector3::new(0.0, y, 0.45),
                    },
                    MissionTask {
                        kind: TaskKind::Place,
                        item: k,
                        position: Vector3::new(3.0, 0.0, 0.35),
                    },
                ]
            })
            .collect();
        let mut baseline = ReactiveBaseline::new(frankie(), ReactiveConfig::default(), tasks);
        baseline.task = 4;
        baseline
    }

    #[test]
    fn a_row_cube_s_stand_is_square_to_the_row_on_the_base_s_side() {
        let baseline = row_baseline();
        let cube = Vector3::new(0.0, 0.0, 0.45);
        let at = |x: f64, y: f64| BasePose { x, y, yaw: 0.0 };
        // From the container: straight out from the row.
        let n = baseline.stand(&cube, &at(3.0, 0.0), &[0.0; 3]);
        assert!(n.is_some_and(|n| (n - Vector2::new(1.0, 0.0)).norm() < 1e-9));
        // From beside the row's end, or behind the row at a slant: out from the row on the
        // base's side, at most 30° off square (the footprint there still clears the
        // neighbours' platforms), never along the row past them.
        for (base, x) in [(at(0.6, 1.0), 1.0), (at(-2.0, -1.5), -1.0)] {
            let n = baseline.stand(&cube, &base, &[0.0; 3]).expect("a stand");
            assert!(n.x * x >= 30f64.to_radians().cos() - 1e-9, "{base:?}: {n}");
        }
        // A lone cube has none: its holistic approach meets nothing.
        let lone = exp1_baseline();
        let cube = Vector3::new(2.0, 0.0, 0.45);
        assert_eq!(lone.stand(&cube, &at(2.0, 3.0), &[0.0; 3]), None);
        // With a platform beside it, the stand is on the base's side, to the nearest 10°.
        let mut beside = exp1_baseline();
        beside.tasks[1].position = Vector3::new(2.5, 0.0, 0.35);
        let n = beside.stand(&cube, &at(2.0, 3.0), &[0.0; 3]);
        assert!(
            n.is_some_and(|n| (n - Vector2::new(0.0, 1.0)).norm() < 1e-9),
            "{n:?}"
        );
    }

    #[test]
    fn a_far_pick_begins_with_a_drive_to_its_stand_and_the_arm_back_at_ready() {
        let mut baseline = row_baseline();
        let cube = Vector3::new(0.0, 0.0, 0.45);
        // Facing away from the stand (1.0 + standoff, 0) ... (0.75, 0): a turn on the spot.
        let away = BasePose {
            x: 2.5,
            y: 0.0,
            yaw: 0.0,
        };
        let out = step_at(&mut baseline, away, cube);
        assert_eq!(out.base.v, 0.0);
        assert_eq!(out.base.omega.abs(), baseline.config.stand_turn_rate);
        // Facing it: driving at the top speed, steering to it; an arm off its ready pose is
        // driven back to it.
        let facing = BasePose {
            yaw: std::f64::consts::PI,
            ..away
        };
        let mut arm_q = baseline.robot.config.ready_pose.clone();
        arm_q[0] += 0.3;
        let out = baseline.step(&ReactiveInput {
            t: 0.1,
            base: facing,
            arm_q: &arm_q,
            gripper_opening: 0.08,
            target: TargetEstimate::fixed(cube),
            odometry_offset: [0.0; 3],
        });
        assert!((out.base.v - baseline.config.max_base_speed).abs() < 1e-9);
        assert!(out.base.omega.abs() < 1e-9);
        assert!(out.arm_qd[0] < 0.0 && out.arm_qd[1..].iter().all(|qd| qd.abs() < 1e-12));
        // At the stand the holistic law takes over: the base is square to the row, and drives
        // no closer than the stand-off.
        let stand = BasePose {
            x: baseline.config.base_standoff + baseline.config.stand_margin,
            ..facing
        };
        let out = step_at(&mut baseline, stand, cube);
        assert!(out.base.v < 0.1, "{out:?}");
        assert_eq!(baseline.stand, StandDrive::Holistic);
    }

    #[test]
    fn a_pick_whose_reach_stalls_is_given_up_with_its_place() {
        let mut baseline = exp1_baseline();
        let base = BasePose::default();
        let cube = Vector3::new(2.0, 0.0, 0.45);
        let arm_q = baseline.robot.config.ready_pose.clone();
        let timeout = baseline.config.stall_timeout;
        let at = |baseline: &mut ReactiveBaseline, t: f64| {
            baseline.step(&ReactiveInput {
                t,
                base,
                arm_q: &arm_q,
                gripper_opening: 0.08,
                target: TargetEstimate::fixed(cube),
                odometry_offset: [0.0; 3],
            })
        };
        // The robot does not move between the cycles: the tool comes no nearer.
        let out = at(&mut baseline, 0.0);
        assert_eq!((out.task_index, baseline.failed_tasks()), (0, 0));
        let out = at(&mut baseline, timeout - 0.1);
        assert_eq!((out.task_index, baseline.failed_tasks()), (0, 0));
        let out = at(&mut baseline, timeout + 0.1);
        assert_eq!(out.stage, ReactiveStage::Complete);
        assert_eq!((out.task_index, baseline.failed_tasks()), (2, 2));
        assert_eq!(out.gripper, GripperCommand::Open);
    }

    #[test]
    fn progress_restarts_the_stall_clock() {
        let mut baseline = exp1_baseline();
        let timeout = baseline.config.stall_timeout;
        assert!(!baseline.stalled(0.0, 1.0));
        // 1.5 cm nearer is not progress, 2.5 cm is.
        assert!(!baseline.stalled(0.5 * timeout, 0.985));
        assert!(!baseline.stalled(0.9 * timeout, 0.975));
        assert!(!baseline.stalled(1.5 * timeout, 0.975));
        assert!(baseline.stalled(2.0 * timeout, 0.975));
    }

    #[test]
    fn a_platform_at_the_front_corner_leaves_the_room_of_the_swept_footprint() {
        let baseline = exp1_baseline();
        let [half_length, half_width] = baseline.half_footprint;
        let keep = baseline.config.platform_radius + baseline.config.footprint_margin;
        // Straight ahead: the front edge's distance less the kept radius.
        let room = baseline.room_beside(1.0, 0.0).unwrap();
        assert!((room - (1.0 - half_length - keep)).abs() < 1e-12);
        // Beside the corner, 10 cm out: the circle meets the corner later.
        let room = baseline.room_beside(1.0, half_width + 0.1).unwrap();
        let expected = 1.0 - half_length - (keep * keep - 0.01_f64).sqrt();
        assert!((room - expected).abs() < 1e-12);
        // Out of the swept strip, or behind: never in the way.
        assert_eq!(baseline.room_beside(1.0, half_width + keep + 0.01), None);
        assert_eq!(baseline.room_beside(-0.5, 0.0), None);
    }

    #[test]
    fn a_base_held_at_a_slant_by_a_rows_platform_turns_toward_it_until_clear() {
        // Two cubes of a row along y; the first is picked and placed. The base meets the row
        // at a slant, heading for the second with the first's platform at its front corner.
        let pick = |y: f64| MissionTask {
            kind: TaskKind::Pick,
            item: 0,
            position: Vector3::new(0.0, y, 0.45),
        };
        let place = MissionTask {
            kind: TaskKind::Place,
            item: 0,
            position: Vector3::new(3.0, 0.0, 0.35),
        };
        let tasks = vec![pick(0.42), place, pick(0.0)];
        let mut baseline = ReactiveBaseline::new(frankie(), ReactiveConfig::default(), tasks);
        baseline.task = 2;
        let cube = Vector3::new(0.0, 0.0, 0.45);
        let yaw = -2.5_f64;
        let distance = 0.85;
        let base = BasePose {
            x: -distance * yaw.cos(),
            y: -distance * yaw.sin(),
            yaw,
        };
        let v = baseline.clamp_forward_speed(&base, &cube, &[0.0; 3], 0.3);
        assert!(v < 0.1, "v = {v}");
        // The platform is on the right: the turn is clockwise.
        let omega = baseline.squaring_turn(&base, &cube, &[0.0; 3]);
        assert_eq!(omega, Some(-baseline.config.escape_turn_rate));
        // Turned part of the way (room above the trigger, below the release), it goes on.
        let turned = BasePose {
            yaw: yaw - 0.1,
            ..base
        };
        assert_eq!(
            baseline.squaring_turn(&turned, &cube, &[0.0; 3]),
            Some(-baseline.config.escape_turn_rate)
        );
        // Square to the row the platform is clear, and the holistic law drives on.
        let square = BasePose {
            yaw: std::f64::consts::PI,
            x: distance,
            y: 0.0,
        };
        assert_eq!(baseline.squaring_turn(&square, &cube, &[0.0; 3]), None);
        assert!(baseline.clamp_forward_speed(&square, &cube, &[0.0; 3], 0.3) > 0.1);
    }

    #[test]
    fn a_pick_turns_the_gripper_square_to_the_cube() {
        // The base heads 0.5 rad off the world axes; the cubes stand square to them.
        let mut baseline = exp1_baseline();
        let base = BasePose {
            x: 0.0,
            y: 0.0,
            yaw: 0.5,
        };
        let arm_q = baseline.robot.config.ready_pose.clone();
        let before = baseline.robot.tool_pose(&base, &arm_q);
        let out = baseline.step(&ReactiveInput {
            t: 0.0,
            base,
            arm_q: &arm_q,
            gripper_opening: 0.08,
            target: TargetEstimate::fixed(before.translation.vector + Vector3::new(0.0, 0.0, -0.2)),
            odometry_offset: [0.0; 3],
        });
        // The commanded motion turns the tool about z toward the nearest multiple of π/2.
        let mut q = arm_q.clone();
        for (q, qd) in q.iter_mut().zip(&out.arm_qd) {
            *q += qd * 0.05;
        }
        let after = baseline.robot.tool_pose(&base, &q);
        let quarter = std::f64::consts::FRAC_PI_2;
        let off = |yaw: f64| (yaw - quarter * (yaw / quarter).round()).abs();
        assert!(
            off(tool_yaw(&after.rotation)) < off(tool_yaw(&before.rotation)),
            "{} -> {}",
            tool_yaw(&before.rotation),
            tool_yaw(&after.rotation)
        );
    }

    #[test]
    fn a_container_left_behind_toward_a_button_beyond_it_is_kept_clear_of() {
        // The button scenario: after the drop the base faces the container, 0.74 m ahead, with
        // the button 2.8 m beyond it.
        let task = |kind: TaskKind, x: f64, y: f64, z: f64| MissionTask {
            kind,
            item: 0,
            position: Vector3::new(x, y, z),
        };
        let tasks = vec![
            task(TaskKind::Pick, 2.0, 0.0, 0.45),
            task(TaskKind::Place, 4.0, 1.0, 0.35),
            task(TaskKind::PressButton, 6.0, 0.0, 0.5),
        ];
        let mut baseline = ReactiveBaseline::new(frankie(), ReactiveConfig::default(), tasks);
        baseline.task = 2;
        let base = BasePose {
            x: 3.26,
            y: 1.0,
            yaw: 0.0,
        };
        let button = Vector3::new(6.0, 0.0, 0.5);
        let v = baseline.clamp_forward_speed(&base, &button, &[0.0; 3], 0.3);
        assert!(v.abs() < 1e-9, "v = {v}");
        // The button is to the right of the container: the base turns right, out of its way.
        let omega = baseline.escape_turn(&base, &button, &[0.0; 3]);
        assert_eq!(omega, Some(-baseline.config.escape_turn_rate));
    }
}
