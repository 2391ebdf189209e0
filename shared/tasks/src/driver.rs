//! The velocity drivers as tasks over the simulated (or real) hardware's topics: the arm driver
//! (1 kHz) and the base driver (50 Hz). Each reads every command sample, safe-stop and the
//! hardware state, steps a [`VelocityDriver`] (the limits are enforced there: it never sends a
//! velocity, acceleration or jerk beyond them, and ramps to zero on a stale command or
//! safe-stop), and publishes the hardware command, the re-published state (stamped with the
//! hardware's stamp) and a [`msgs::DriverStatus`] every `status_every` cycles.
//!
//! The sim backend runs them on the runtime with sim-world's `hw/*` topics; a real backend
//! steps the same task with the robot's state in the `hw_*` inputs and sends the `hw_*`
//! outputs to the robot. A robot that is not fit to move (a reflex, a faulted base) sets the
//! task's hardware hold ([`ArmDriverTask::set_hardware_hold`]): the driver then ramps to zero
//! as under safe-stop, and its status says `SafeStop` with `hardware_ready` 0.
//!
//! **The arm stops with the base.** The base brakes at its deceleration limit (about 0.4 s from
//! 0.3 m/s on Frankie); an arm that stopped within milliseconds would sweep the tool through
//! the world by the base's braking distance, and knock a cube off from between closing
//! fingers. So the arm driver spreads every stop (stale command, safe-stop) over the time the
//! base needs to brake from its last odometry ([`BaseBraking`]), scaling its motion down with
//! the base's: the tool keeps its place in the world while both stop. A hardware hold (a
//! reflex) still stops at once. The spread is capped at [`MAX_STOP_SPREAD_S`].

use motm_core::command_limiter::LimiterMode;
use motm_core::velocity_driver::{DriverCounters, VelocityDriver};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, Message, topics};

use crate::controllers::ResolverSelector;
use crate::convert;

/// The status message of a driver with `counters`.
pub fn status_message(counters: &DriverCounters) -> msgs::DriverStatus {
    let mut status = msgs::DriverStatus::zeroed();
    status.mode = match counters.mode {
        LimiterMode::Tracking => msgs::DriverMode::Tracking,
        LimiterMode::Stale => msgs::DriverMode::Stale,
        LimiterMode::SafeStop => msgs::DriverMode::SafeStop,
    }
    .into();
    status.hardware_ready = counters.hardware_ready.into();
    status.commands_received = counters.commands_received;
    status.limit_violations = counters.limiter.limit_violations;
    status.clamped_commands = counters.limiter.clamped_commands;
    status.ignored_commands = counters.limiter.ignored_commands;
    status.stale_cycles = counters.limiter.stale_steps;
    status.safe_stop_cycles = counters.limiter.safe_stop_steps;
    status.output_violations = counters.output_violations;
    status.max_command_gap_ns = counters.max_command_gap_ns;
    status
}

/// Whether a gripper command goes to the hardware: only from the active controller (any
/// controller until one is named), and never under safe-stop (the gripper holds).
pub fn forward_gripper(
    command: &msgs::GripperCommand,
    active: Option<&msgs::ActiveController>,
    safe_stop: bool,
) -> bool {
    !safe_stop && active.is_none_or(|a| a.controller_id == command.controller_id)
}

/// Longest time the arm driver spreads a stop over, s: a stop never takes longer than this,
/// whatever the odometry says.
pub const MAX_STOP_SPREAD_S: f64 = 1.0;

/// How long the base takes to brake from a twist, at its deceleration limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseBraking {
    /// Forward deceleration limit, m/s².
    pub linear: f64,
    /// Turning deceleration limit, rad/s².
    pub angular: f64,
}

impl BaseBraking {
    /// The base of `robot`.
    pub fn of(robot: &motm_core::Robot) -> Self {
        let axes = base_axes(robot);
        Self {
            linear: axes[0].acceleration,
            angular: axes[1].acceleration,
        }
    }

    /// Time to brake from forward speed `v` (m/s) and turn rate `omega` (rad/s), s, at most
    /// [`MAX_STOP_SPREAD_S`]; 0 for a non-finite twist.
    pub fn time(&self, v: f64, omega: f64) -> f64 {
        let t = (v.abs() / self.linear).max(omega.abs() / self.angular);
        if t.is_finite() {
            t.min(MAX_STOP_SPREAD_S)
        } else {
            0.0
        }
    }
}

/// A quarter of a control period: how long a driver waits for the resolver it follows before it
/// takes the standby's command of that cycle ([`ResolverSelector`]). Both instances' commands
/// of a cycle come within a fraction of a millisecond of each other, so a quarter period
/// (1.25 ms at 200 Hz) passes a live instance over only when it is that late.
const TAKEOVER_WAIT_DIVISOR: u64 = 4;

/// What both drivers keep: the limiter, the resolver selection, the status period, the
/// hardware hold and a scratch buffer for the measured velocity.
struct DriverCore {
    driver: VelocityDriver,
    resolvers: ResolverSelector,
    status_every: u64,
    cycle: u64,
    hold: bool,
    measured: Vec<f64>,
}

impl DriverCore {
    fn new(driver: VelocityDriver, status_every: u64) -> Self {
        let period_ns = (driver.command_period() * 1e9) as u64;
        Self {
            resolvers: ResolverSelector::new(period_ns, period_ns / TAKEOVER_WAIT_DIVISOR),
            driver,
            status_every: status_every.max(1),
            cycle: 0,
            hold: false,
            measured: Vec::with_capacity(8),
        }
    }

    /// Takes in `velocity`, commanded by resolver instance `resolver_id` at `stamp_ns`, when it
    /// is from the instance followed ([`ResolverSelector`]).
    fn receive(&mut self, resolver_id: u32, stamp_ns: u64, velocity: &[f64]) {
        if let Some((held_ns, held)) = self.resolvers.due(stamp_ns) {
            self.driver.receive(held_ns, &held);
        }
        if self.resolvers.offer(resolver_id, stamp_ns, velocity) {
            self.driver.receive(stamp_ns, velocity);
        }
    }

    /// Steps the limiter; returns the velocity to send (if any) and the status when due.
    fn step(
        &mut self,
        now_ns: u64,
        stopped: bool,
        measured: Option<&[f64]>,
    ) -> (Option<Vec<f64>>, Option<msgs::DriverStatus>) {
        if let Some((stamp_ns, velocity)) = self.resolvers.due(now_ns) {
            self.driver.receive(stamp_ns, &velocity);
        }
        let velocity = self
            .driver
            .step(now_ns, stopped || self.hold, measured)
            .map(<[f64]>::to_vec);
        let status = self.cycle.is_multiple_of(self.status_every).then(|| {
            let mut status = status_message(&self.driver.counters());
            status.resolver_id = self.resolvers.following();
            status.resolver_takeovers = self.resolvers.takeovers();
            status.max_takeover_interval_ns = self.resolvers.max_takeover_interval_ns();
            if self.hold {
                status.mode = msgs::DriverMode::SafeStop.into();
                status.hardware_ready = 0;
            }
            convert::stamped(status, now_ns)
        });
        self.cycle += 1;
        (velocity, status)
    }

    /// The limiter's counters.
    fn counters(&self) -> DriverCounters {
        self.driver.counters()
    }
}

/// The hardware hold of both driver tasks.
macro_rules! hardware_hold {
    ($task:ty) => {
        impl $task {
            /// Holds the driver in safe-stop while `hold` (the robot is not fit to move): its
            /// output ramps to zero and its status says `SafeStop`, hardware not ready.
            pub fn set_hardware_hold(&mut self, hold: bool) {
                self.core.hold = hold;
            }

            /// Whether the hardware hold is set.
            pub fn hardware_hold(&self) -> bool {
                self.core.hold
            }

            /// The limiter's counters.
            pub fn counters(&self) -> DriverCounters {
                self.core.counters()
            }
        }
    };
}

hardware_hold!(ArmDriverTask);
hardware_hold!(BaseDriverTask);

/// Whether safe-stop is raised.
fn safe_stop(message: &Option<msgs::SafeStop>) -> bool {
    message.as_ref().is_some_and(|s| s.active == 1)
}

/// `message` when it is newer than the one re-published last (remembered in `last`).
fn fresh<M: Message>(message: &Option<M>, last: &mut Option<(u64, u64)>) -> Option<M> {
    let m = message.as_ref()?;
    let id = (m.header().seq, m.header().stamp_ns);
    (*last != Some(id)).then(|| {
        *last = Some(id);
        *m
    })
}

ports! {
    /// What the arm driver reads.
    pub struct ArmDriverInputs {
        /// Every joint velocity command of the cycle.
        queue commands: msgs::ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Every gripper command of the cycle.
        queue gripper: msgs::GripperCommand = topics::ARM_GRIPPER_COMMAND,
        /// The active final-phase controller.
        latest active: msgs::ActiveController = topics::CONTROL_ACTIVE_CONTROLLER,
        /// Safe-stop.
        latest safe_stop: msgs::SafeStop = topics::SAFETY_SAFE_STOP,
        /// The hardware's arm state.
        latest hw_state: msgs::JointState = topics::HW_ARM_STATE,
        /// The hardware's gripper state.
        latest hw_gripper: msgs::GripperState = topics::HW_GRIPPER_STATE,
        /// The base's odometry: how long its braking takes.
        latest base: msgs::BaseOdometry = topics::BASE_ODOMETRY,
    }
}

ports! {
    /// What the arm driver publishes.
    pub struct ArmDriverOutputs {
        /// The limited joint velocity command to the hardware.
        latest hw_command: msgs::ArmVelocityCommand = topics::HW_ARM_COMMAND,
        /// The gripper command forwarded to the hardware.
        latest hw_gripper: msgs::GripperCommand = topics::HW_GRIPPER_COMMAND,
        /// The joint state, re-published.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// The gripper state, re-published.
        latest gripper: msgs::GripperState = topics::ARM_GRIPPER_STATE,
        /// Status and limit counters.
        latest status: msgs::DriverStatus = topics::ARM_DRIVER_STATUS,
    }
}

/// The arm driver task.
pub struct ArmDriverTask {
    core: DriverCore,
    braking: BaseBraking,
    republished: Option<(u64, u64)>,
    gripper_republished: Option<(u64, u64)>,
}

impl ArmDriverTask {
    /// The arm driver over `driver`, stopping with a base that brakes as `braking`, sending its
    /// status every `status_every` cycles.
    pub fn new(driver: VelocityDriver, braking: BaseBraking, status_every: u64) -> Self {
        Self {
            core: DriverCore::new(driver, status_every),
            braking,
            republished: None,
            gripper_republished: None,
        }
    }

    /// Number of joints driven.
    pub fn axes(&self) -> usize {
        self.core.driver.axes()
    }
}

impl Task for ArmDriverTask {
    type Inputs = ArmDriverInputs;
    type Outputs = ArmDriverOutputs;

    fn name(&self) -> &'static str {
        motm_graph::PANDA_DRIVER.name
    }

    fn step(&mut self, now_ns: u64, inputs: &ArmDriverInputs) -> ArmDriverOutputs {
        for command in &inputs.commands {
            self.core.receive(
                command.resolver_id,
                command.header.stamp_ns,
                &command.velocity[..command.joint_count as usize],
            );
        }
        let stopped = safe_stop(&inputs.safe_stop);
        let spread = match &inputs.base {
            Some(odometry) if !self.core.hold => self.braking.time(odometry.v, odometry.omega),
            _ => 0.0,
        };
        self.core.driver.set_stop_time(spread);
        self.core.measured.clear();
        if let Some(state) = &inputs.hw_state {
            self.core
                .measured
                .extend_from_slice(&state.velocity[..state.joint_count as usize]);
        }
        let measured = std::mem::take(&mut self.core.measured);
        let (velocity, status) = self.core.step(
            now_ns,
            stopped,
            (!measured.is_empty()).then_some(&measured[..]),
        );
        self.core.measured = measured;
        let hw_gripper = inputs
            .gripper
            .iter()
            .rfind(|c| forward_gripper(c, inputs.active.as_ref(), stopped || self.core.hold))
            .map(|c| convert::stamped(*c, now_ns));
        ArmDriverOutputs {
            hw_command: velocity.map(|v| convert::stamped(convert::arm_command(&v), now_ns)),
            hw_gripper,
            joints: fresh(&inputs.hw_state, &mut self.republished),
            gripper: fresh(&inputs.hw_gripper, &mut self.gripper_republished),
            status,
        }
    }
}

ports! {
    /// What the base driver reads.
    pub struct BaseDriverInputs {
        /// Every base twist command of the cycle.
        queue commands: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// Safe-stop.
        latest safe_stop: msgs::SafeStop = topics::SAFETY_SAFE_STOP,
        /// The hardware's base state.
        latest hw_state: msgs::BaseOdometry = topics::HW_BASE_STATE,
    }
}

ports! {
    /// What the base driver publishes.
    pub struct BaseDriverOutputs {
        /// The limited base twist command to the hardware.
        latest hw_command: msgs::BaseVelocityCommand = topics::HW_BASE_COMMAND,
        /// The odometry, re-published.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Status and limit counters.
        latest status: msgs::DriverStatus = topics::BASE_DRIVER_STATUS,
    }
}

/// The base driver task. Its axes are `[v, omega]`.
pub struct BaseDriverTask {
    core: DriverCore,
    republished: Option<(u64, u64)>,
}

impl BaseDriverTask {
    /// The base driver over `driver` (axes `[v, omega]`), sending its status every
    /// `status_every` cycles.
    pub fn new(driver: VelocityDriver, status_every: u64) -> Self {
        Self {
            core: DriverCore::new(driver, status_every),
            republished: None,
        }
    }
}

impl Task for BaseDriverTask {
    type Inputs = BaseDriverInputs;
    type Outputs = BaseDriverOutputs;

    fn name(&self) -> &'static str {
        motm_graph::LD60_DRIVER.name
    }

    fn step(&mut self, now_ns: u64, inputs: &BaseDriverInputs) -> BaseDriverOutputs {
        for command in &inputs.commands {
            self.core.receive(
                command.resolver_id,
                command.header.stamp_ns,
                &[command.v, command.omega],
            );
        }
        let stopped = safe_stop(&inputs.safe_stop);
        let measured = inputs.hw_state.as_ref().map(|s| [s.v, s.omega]);
        let (velocity, status) = self
            .core
            .step(now_ns, stopped, measured.as_ref().map(|m| &m[..]));
        BaseDriverOutputs {
            hw_command: velocity.map(|v| {
                convert::stamped(
                    convert::base_command(&motm_core::BaseVelocity {
                        v: v[0],
                        omega: v[1],
                    }),
                    now_ns,
                )
            }),
            odometry: fresh(&inputs.hw_state, &mut self.republished),
            status,
        }
    }
}

/// The arm's axis limits of `robot` (its joints after the two base joints).
pub fn arm_axes(robot: &motm_core::Robot) -> Vec<motm_core::command_limiter::AxisLimits> {
    robot.limits()[motm_core::BASE_JOINTS..]
        .iter()
        .map(motm_core::command_limiter::AxisLimits::from)
        .collect()
}

/// The base's axis limits of `robot`, in `[v, omega]` order (its joints are
/// `[yaw (omega), forward (v), arm...]`).
pub fn base_axes(robot: &motm_core::Robot) -> Vec<motm_core::command_limiter::AxisLimits> {
    let limits = robot.limits();
    vec![
        motm_core::command_limiter::AxisLimits::from(&limits[1]),
        motm_core::command_limiter::AxisLimits::from(&limits[0]),
    ]
}

/// A velocity driver over `axes` stepped every `period_s`, for a command stream at
/// `control_rate_hz` that is stale after `stale_periods` periods.
pub fn velocity_driver(
    axes: Vec<motm_core::command_limiter::AxisLimits>,
    period_s: f64,
    control_rate_hz: f64,
    stale_periods: u32,
) -> Result<VelocityDriver, String> {
    use motm_core::command_limiter::CommandLimiterConfig;
    use motm_core::velocity_driver::VelocityDriverConfig;
    let config = VelocityDriverConfig {
        limiter: CommandLimiterConfig {
            command_period: 1.0 / control_rate_hz,
            stale_periods,
            ..CommandLimiterConfig::default()
        },
    };
    VelocityDriver::new(axes, period_s, config).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_core::command_limiter::LimiterCounters;
    use motm_msgs::DriverMode;

    #[test]
    fn the_hardware_hold_ramps_to_zero_reports_a_safe_stop_and_holds_the_gripper() {
        use motm_core::command_limiter::AxisLimits;
        let axes = vec![
            AxisLimits {
                velocity: 1.0,
                acceleration: 1.0,
                jerk: f64::INFINITY,
            };
            7
        ];
        let driver = velocity_driver(axes, 0.001, 200.0, 10).unwrap();
        let braking = BaseBraking {
            linear: 1.0,
            angular: 1.0,
        };
        let mut task = ArmDriverTask::new(driver, braking, 1);
        let mut inputs = ArmDriverInputs::default();
        let mut state = msgs::JointState::zeroed();
        state.joint_count = 7;
        inputs.hw_state = Some(state);
        let speed = |out: &ArmDriverOutputs| out.hw_command.map_or(0.0, |c| c.velocity[0]);
        let mut last = 0.0;
        for k in 1..=200u64 {
            let now = k * 1_000_000;
            let mut c = convert::arm_command(&[0.5; 7]);
            c.header.stamp_ns = now;
            inputs.commands = vec![c];
            last = speed(&task.step(now, &inputs));
        }
        assert!(last > 0.15, "tracking: {last}");
        task.set_hardware_hold(true);
        let mut close = msgs::GripperCommand::zeroed();
        close.action = msgs::GripperAction::Close.into();
        inputs.gripper = vec![close];
        for k in 201..=600u64 {
            let now = k * 1_000_000;
            let mut c = convert::arm_command(&[0.5; 7]);
            c.header.stamp_ns = now;
            inputs.commands = vec![c];
            let out = task.step(now, &inputs);
            let v = speed(&out);
            // Never faster than the acceleration limit allows on the way down.
            assert!(
                v <= last + 1e-12 && last - v <= 1.0 * 0.001 + 1e-9,
                "{last} -> {v}"
            );
            last = v;
            assert!(
                out.hw_gripper.is_none(),
                "no gripper command under the hold"
            );
            let status = out.status.unwrap();
            assert_eq!(status.mode(), Some(DriverMode::SafeStop));
            assert_eq!(status.hardware_ready, 0);
        }
        assert_eq!(last, 0.0);
        task.set_hardware_hold(false);
        let out = task.step(601_000_000, &inputs);
        assert!(out.hw_gripper.is_some());
        assert_eq!(out.status.unwrap().hardware_ready, 1);
    }

    #[test]
    fn status_message_carries_every_counter_and_validates() {
        let counters = DriverCounters {
            limiter: LimiterCounters {
                limit_violations: 5,
                clamped_commands: 3,
                ignored_commands: 2,
                stale_steps: 7,
                safe_stop_steps: 11,
            },
            commands_received: 13,
            output_violations: 0,
            max_command_gap_ns: 17,
            mode: LimiterMode::SafeStop,
            hardware_ready: true,
        };
        let m = status_message(&counters);
        assert_eq!(m.mode(), Some(DriverMode::SafeStop));
        assert_eq!(
            (
                m.commands_received,
                m.limit_violations,
                m.stale_cycles,
                m.safe_stop_cycles
            ),
            (13, 5, 7, 11)
        );
        assert_eq!((m.hardware_ready, m.max_command_gap_ns), (1, 17));
        assert_eq!(m.validate(1, None), Ok(()));
    }
}
