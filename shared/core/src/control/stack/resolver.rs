//! The QP-resolver process: picks the twist of the active phase and resolves it, with the base
//! planner's velocity target, into arm and base velocity commands.
//!
//! Choices (config values in [`ResolverCycleConfig`]):
//! - **Twist of the active phase**: the reacher's in the reach phase, the active final-phase
//!   controller's in the final phase (any final-phase controller's until an active-controller
//!   id has been received), for the current task and no older than `max_twist_age`.
//! - **Phase changes**: the controller of the new phase needs a cycle to notice the change;
//!   meanwhile (up to `max_twist_age` after the change) the freshest twist of either
//!   controller is used (counted as a fallback), so the command does not drop to zero at every
//!   hand-over.
//! - **The active phase's controller is gone** (no fresh twist of it after the hand-over
//!   window, or no twist at all: it died or hangs, and the supervisor restarts it): for up to
//!   `max_hold` the tool holds its place relative to the target ([`TwistSource::Hold`]: the
//!   twist is the target's velocity), while the base goes on to its target; after that, an
//!   all-zero command. Neither the other phase's twist, which aims elsewhere (the reacher's,
//!   above the cube, during a grasp), nor a stop of the arm alone, which would let the moving
//!   base sweep the tool through the cube, keeps the object.
//! - **Twist rate limit and e_t cap** as in [`crate::on_the_move`]: the chosen twist moves from
//!   the last resolved twist by at most [`crate::on_the_move::TwistRateLimit`] (its linear
//!   limit at the run's base speed, [`crate::on_the_move::TwistRateLimit::for_speed`]), and e_t is
//!   capped at `max_position_error`. After the mission the reacher's twist (arm at its ready
//!   pose) is the active one.
//! - **Base velocity error feed-forward** as in [`crate::on_the_move`]: the twist asked of the
//!   QP carries [`crate::base_slip::slip_correction`] for the measured base velocity against the
//!   base command resolved on the previous cycle.
//! - **Base target rate limit** as in [`crate::on_the_move`]
//!   ([`crate::base_command_rate`]).
//! - **Missing or stale input** (no mission, no twist for longer than `max_hold`): an
//!   all-zero command, which the drivers ramp to within their limits. A missing or stale base
//!   target is replaced by a zero target.
//! - **Stale robot state** (joint state or odometry older than `max_state_age`, e.g. a driver
//!   that died): no command at all ([`TwistSource::Withheld`]). Where the robot is is not known,
//!   so no zero is commanded either: the drivers see their command stream stop and stop the way
//!   they do for any lost stream, the arm spread over the base's braking, so that the tool
//!   keeps its place in the world while the base, still moving, brakes.

use serde::Deserialize;

use crate::base_command_rate::BaseCommandRate;
use crate::base_controller::BaseModel;
use crate::base_slip::slip_correction;
use crate::kinematics::BasePose;
use crate::mission::Phase;
use crate::on_the_move::OnTheMoveConfig;
use crate::resolver::{RedundancyResolver, ResolveStatus, ResolverOutput};
use crate::robot::Robot;
use crate::types::{BaseVelocity, TargetEstimate, Twist};

use super::{MissionView, reach_aim};

/// Staleness limits of the QP resolver's inputs.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ResolverCycleConfig {
    /// Oldest twist or base target still used, s (default 0.05: ten 200 Hz cycles).
    pub max_twist_age: f64,
    /// Oldest joint state or odometry still used, s (default 0.05).
    pub max_state_age: f64,
    /// Longest the tool holds on the target without the active phase's twist, s (default
    /// 0.5: a restart of the controller with margin).
    pub max_hold: f64,
}

impl Default for ResolverCycleConfig {
    fn default() -> Self {
        Self {
            max_twist_age: 0.05,
            max_state_age: 0.05,
            max_hold: 0.5,
        }
    }
}

/// A twist command as received, with its age.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwistSample {
    /// World twist.
    pub twist: Twist,
    /// Task the twist was computed for.
    pub task_index: usize,
    /// Phase the twist belongs to.
    pub phase: Phase,
    /// Id of the controller that sent it.
    pub controller_id: u32,
    /// Age at this cycle, ns.
    pub age_ns: u64,
}

/// The measured robot state.
#[derive(Debug, Clone, Copy)]
pub struct MeasuredState<'a> {
    /// Base pose (odometry).
    pub base: BasePose,
    /// Arm joint positions.
    pub arm_q: &'a [f64],
    /// Measured base velocity (odometry).
    pub base_velocity: BaseVelocity,
    /// Age of the older of joint state and odometry, ns.
    pub age_ns: u64,
}

/// What the QP resolver reads each cycle.
#[derive(Debug, Clone, Copy)]
pub struct ResolverCycleInput<'a> {
    /// The supervisor's mission state, if received.
    pub mission: Option<MissionView>,
    /// Joint state and odometry, if both were received.
    pub state: Option<MeasuredState<'a>>,
    /// Target of the current task (see [`super::TargetSelector`]).
    pub target: TargetEstimate,
    /// The reacher's latest twist.
    pub reach: Option<TwistSample>,
    /// The final-phase controllers' latest twist.
    pub final_twist: Option<TwistSample>,
    /// Id of the active final-phase controller, once announced.
    pub active_controller: Option<u32>,
    /// The base planner's latest velocity target and its age, ns.
    pub base_target: Option<(BaseVelocity, u64)>,
}

/// Where the resolved twist came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwistSource {
    /// The active phase's controller, for the current task.
    ActivePhase,
    /// The freshest twist of either controller, during a hand-over.
    Fallback,
    /// The active phase's controller sent nothing fresh after the hand-over window: the tool
    /// moves with the target.
    Hold,
    /// Nothing usable: the command is all zero.
    Stopped,
    /// The robot's state is stale: no command is sent (the output's command is all zero and
    /// must not be published).
    Withheld,
}

/// What the QP resolver publishes each cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolverCycleOutput {
    /// The command (all zero when `source` is [`TwistSource::Stopped`] or
    /// [`TwistSource::Withheld`]; not to be sent for the latter).
    pub resolved: ResolverOutput,
    /// The twist that was resolved.
    pub twist: Twist,
    /// Where it came from.
    pub source: TwistSource,
    /// The tool's distance to the current task's aim point, m (infinite when unknown; the QP's
    /// e_t is this capped at `max_position_error`).
    pub tool_to_target: f64,
}

/// The QP resolver with its twist selection.
pub struct ResolverCycle {
    robot: Robot,
    config: OnTheMoveConfig,
    limits: ResolverCycleConfig,
    resolver: RedundancyResolver,
    /// Control period, s.
    dt: f64,
    /// The last resolved (rate-limited) twist.
    last_twist: Twist,
    /// The base velocity resolved on the previous cycle.
    last_base_command: BaseVelocity,
    /// e_t handed to the QP on the previous cycle (none after a stop).
    last_position_error: Option<f64>,
    /// Rate limit on the base target handed to the QP.
    base_rate: BaseCommandRate,
    fallbacks: u64,
    stops: u64,
    holds: u64,
    /// The task and phase of the last cycle, and the cycles run since they changed.
    phase_seen: Option<(usize, Phase, u64)>,
    /// Cycles in a row without the active phase's twist.
    missing: u64,
}

impl ResolverCycle {
    /// A resolver for `robot` with the controller `config` and staleness `limits`, run every
    /// `dt` seconds.
    pub fn new(
        robot: Robot,
        config: OnTheMoveConfig,
        limits: ResolverCycleConfig,
        dt: f64,
    ) -> Self {
        let max_yaw_acceleration = BaseModel::from_robot(&robot).max_yaw_acceleration;
        let base_rate = BaseCommandRate::new(&robot, config.base_rate)
            .for_speed(config.base.forward_speed)
            .with_yaw_acceleration(config.base.yaw_acceleration(max_yaw_acceleration));
        Self {
            dt,
            last_twist: Twist::zeros(),
            last_base_command: BaseVelocity::default(),
            last_position_error: None,
            base_rate,
            resolver: RedundancyResolver::for_robot(&robot, config.resolver.clone()),
            robot,
            config,
            limits,
            fallbacks: 0,
            stops: 0,
            holds: 0,
            phase_seen: None,
            missing: 0,
        }
    }

    /// Cycles that held the tool on the target for want of the active phase's twist.
    pub fn holds(&self) -> u64 {
        self.holds
    }

    /// Counts the cycles since the mission's task or phase last changed; whether this cycle is
    /// still in the hand-over window after a change.
    fn in_handover(&mut self, mission: &MissionView) -> bool {
        let cycles = match self.phase_seen {
            Some((task, phase, n)) if task == mission.task_index && phase == mission.phase => n + 1,
            _ => 0,
        };
        self.phase_seen = Some((mission.task_index, mission.phase, cycles));
        cycles as f64 * self.dt <= self.limits.max_twist_age
    }

    /// The QP itself (limits, error count).
    pub fn resolver(&self) -> &RedundancyResolver {
        &self.resolver
    }

    /// Cycles that used a hand-over fallback twist.
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// Cycles that resolved nothing for want of usable input: an all-zero command, or none
    /// at all on a stale robot state.
    pub fn stops(&self) -> u64 {
        self.stops
    }

    /// Whether `sample` is fresh and from an acceptable sender.
    fn usable(&self, sample: &TwistSample, active: Option<u32>) -> bool {
        let fresh = (sample.age_ns as f64) * 1e-9 <= self.limits.max_twist_age;
        let sender_ok =
            sample.phase != Phase::Final || active.is_none_or(|id| id == sample.controller_id);
        fresh && sender_ok && sample.twist.iter().all(|x| x.is_finite())
    }

    /// Chooses the twist to resolve (see the module doc); `handover` is whether the phase
    /// changed less than the hand-over window ago, `missing_s` how long the active phase's
    /// twist has been missing before this cycle.
    pub fn select_twist(
        &self,
        mission: &MissionView,
        input: &ResolverCycleInput<'_>,
        handover: bool,
        missing_s: f64,
    ) -> Option<(Twist, TwistSource)> {
        let usable: Vec<TwistSample> = [input.reach, input.final_twist]
            .into_iter()
            .flatten()
            .filter(|s| self.usable(s, input.active_controller))
            .collect();
        // After the mission the reacher holds the arm at its ready pose.
        let phase = match mission.phase {
            Phase::Final => Phase::Final,
            Phase::Reach | Phase::Complete => Phase::Reach,
        };
        if let Some(s) = usable
            .iter()
            .find(|s| s.task_index == mission.task_index && s.phase == phase)
        {
            return Some((s.twist, TwistSource::ActivePhase));
        }
        if handover && let Some(s) = usable.iter().min_by_key(|s| s.age_ns) {
            return Some((s.twist, TwistSource::Fallback));
        }
        let v = input.target.velocity;
        let hold = Twist::new(v.x, v.y, v.z, 0.0, 0.0, 0.0);
        (missing_s < self.limits.max_hold && hold.iter().all(|x| x.is_finite()))
            .then_some((hold, TwistSource::Hold))
    }

    /// The all-zero command.
    fn stop(&mut self, tool_to_target: f64) -> ResolverCycleOutput {
        self.stops += 1;
        self.last_twist = Twist::zeros();
        self.last_base_command = BaseVelocity::default();
        self.last_position_error = None;
        self.base_rate.reset();
        ResolverCycleOutput {
            resolved: ResolverOutput {
                base: BaseVelocity::default(),
                arm_qd: vec![0.0; self.robot.arm_dof()],
                slack: nalgebra::Vector6::zeros(),
                status: ResolveStatus::InvalidInput,
                iterations: 0,
            },
            twist: Twist::zeros(),
            source: TwistSource::Stopped,
            tool_to_target,
        }
    }

    /// e_t for this cycle: `tool_to_target` capped at `max_position_error`, risen from the last
    /// cycle's by at most `max_position_error_rate` per second.
    fn position_error(&mut self, tool_to_target: f64) -> f64 {
        let capped = tool_to_target.min(self.config.max_position_error);
        let e_t = match self.last_position_error {
            Some(last) => capped.min(last + self.config.max_position_error_rate * self.dt),
            None => capped,
        };
        self.last_position_error = Some(e_t);
        e_t
    }

    /// The e_t handed to the QP on the last cycle, m (none before the first and after a stop).
    pub fn last_position_error(&self) -> Option<f64> {
        self.last_position_error
    }

    /// One cycle.
    pub fn step(&mut self, input: &ResolverCycleInput<'_>) -> ResolverCycleOutput {
        let max_state_age_ns = self.limits.max_state_age * 1e9;
        let (Some(mission), Some(state)) = (input.mission, input.state) else {
            return self.stop(f64::INFINITY);
        };
        if state.arm_q.len() != self.robot.arm_dof() || state.arm_q.iter().any(|q| !q.is_finite()) {
            return self.stop(f64::INFINITY);
        }
        if state.age_ns as f64 > max_state_age_ns {
            let mut out = self.stop(f64::INFINITY);
            out.source = TwistSource::Withheld;
            return out;
        }
        let tool = self.robot.tool_pose(&state.base, state.arm_q);
        let aim = reach_aim(mission.kind, &input.target, &self.config);
        let tool_to_target = (tool.translation.vector - aim.position).norm();
        let handover = self.in_handover(&mission);
        let missing_s = self.missing as f64 * self.dt;
        let chosen = self.select_twist(&mission, input, handover, missing_s);
        self.missing = match chosen {
            Some((_, TwistSource::ActivePhase)) => 0,
            _ => self.missing + 1,
        };
        let Some((twist, source)) = chosen else {
            return self.stop(tool_to_target);
        };
        match source {
            TwistSource::Fallback => self.fallbacks += 1,
            TwistSource::Hold => self.holds += 1,
            _ => {}
        }
        let base_target = match input.base_target {
            Some((target, age_ns)) if age_ns as f64 * 1e-9 <= self.limits.max_twist_age => target,
            _ => BaseVelocity::default(),
        };
        // The tool's acceleration budget is shared with the base's: the arm cancels the base's
        // acceleration at the tool only in part.
        let previous_base_target = self.base_rate.last();
        let base_target = self.base_rate.apply(base_target, self.dt);
        let base_acceleration = (base_target.v - previous_base_target.v) / self.dt;
        let twist = self
            .config
            .twist_rate
            .for_speed(self.config.base.forward_speed)
            .sharing(base_target.v, base_acceleration)
            .apply(&self.last_twist, &twist, self.dt);
        self.last_twist = twist;
        let correction = slip_correction(
            &self.robot,
            &state.base,
            state.arm_q,
            state.base_velocity,
            self.last_base_command,
            &self.config.base_slip,
        );
        let position_error = self.position_error(tool_to_target);
        let resolved = self.resolver.resolve_motm(
            &self.robot,
            &state.base,
            state.arm_q,
            twist + correction,
            position_error,
            Some(base_target),
        );
        self.last_base_command = resolved.base;
        ResolverCycleOutput {
            resolved,
            twist,
            source,
            tool_to_target,
        }
    }
}
