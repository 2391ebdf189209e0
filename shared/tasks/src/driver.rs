//! The velocity drivers as tasks over the simulated (or real) hardware's topics: the arm driver
//! (1 kHz) and the base driver (50 Hz). Each reads every command sample, safe-stop and the
//! hardware state, steps a [`VelocityDriver`] (the limits are enforced there: it never sends a
//! velocity, acceleration or jerk beyond them, and ramps to zero on a stale command or
//! safe-stop), and publishes the hardware command, the re-published state (stamped with the
//! hardware's stamp) and a [`msgs::DriverStatus`] every `status_every` cycles.

use motm_core::command_limiter::LimiterMode;
use motm_core::velocity_driver::{DriverCounters, VelocityDriver};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, Message, topics};

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

/// What both drivers keep: the limiter, the status period and scratch buffers.
struct DriverCore {
    driver: VelocityDriver,
    status_every: u64,
    cycle: u64,
    values: Vec<f64>,
    measured: Vec<f64>,
}

impl DriverCore {
    fn new(driver: VelocityDriver, status_every: u64) -> Self {
        Self {
            driver,
            status_every: status_every.max(1),
            cycle: 0,
            values: Vec::with_capacity(8),
            measured: Vec::with_capacity(8),
        }
    }

    /// Steps the limiter; returns the velocity to send (if any) and the status when due.
    fn step(
        &mut self,
        now_ns: u64,
        stopped: bool,
        measured: Option<&[f64]>,
    ) -> (Option<Vec<f64>>, Option<msgs::DriverStatus>) {
        let velocity = self
            .driver
            .step(now_ns, stopped, measured)
            .map(<[f64]>::to_vec);
        let status = self
            .cycle
            .is_multiple_of(self.status_every)
            .then(|| convert::stamped(status_message(&self.driver.counters()), now_ns));
        self.cycle += 1;
        (velocity, status)
    }

    /// The limiter's counters.
    fn counters(&self) -> DriverCounters {
        self.driver.counters()
    }
}

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
    republished: Option<(u64, u64)>,
    gripper_republished: Option<(u64, u64)>,
}

impl ArmDriverTask {
    /// The arm driver over `driver`, sending its status every `status_every` cycles.
    pub fn new(driver: VelocityDriver, status_every: u64) -> Self {
        Self {
            core: DriverCore::new(driver, status_every),
            republished: None,
            gripper_republished: None,
        }
    }

    /// The limiter's counters.
    pub fn counters(&self) -> DriverCounters {
        self.core.counters()
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
            self.core.values.clear();
            self.core
                .values
                .extend_from_slice(&command.velocity[..command.joint_count as usize]);
            self.core
                .driver
                .receive(command.header.stamp_ns, &self.core.values);
        }
        let stopped = safe_stop(&inputs.safe_stop);
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
            .rfind(|c| forward_gripper(c, inputs.active.as_ref(), stopped))
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

    /// The limiter's counters.
    pub fn counters(&self) -> DriverCounters {
        self.core.counters()
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
            self.core
                .driver
                .receive(command.header.stamp_ns, &[command.v, command.omega]);
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
