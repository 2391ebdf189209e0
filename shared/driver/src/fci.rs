//! The `fci` backend of panda-driver: the real Franka Panda over FCI (or `fake-panda`), and the
//! Franka Hand. The robot is the clock: each cycle starts when a `RobotState` arrives, steps
//! the same [`VelocityDriver`] as the sim backend (the stack's limits, staleness and
//! safe-stop), passes its output through libfranka's low-pass filter and rate limiter
//! (in [`motm_franka::FciClient::command`]) and answers the state with one command. It
//! publishes `ARM_JOINT_STATE` (the robot's `q`, `dq`, waking), `ARM_GRIPPER_STATE` (each hand
//! state, waking) and `ARM_DRIVER_STATUS` like the sim backend, plus the heartbeat.
//!
//! Motions: a joint-velocity motion starts when the driver is tracking a fresh command and the
//! robot is idle; when the driver's output has ramped to zero (stale command or safe-stop) the
//! motion is finished, and a later fresh command starts a new one. A reflex or a robot that is
//! not idle sets the task's hardware hold (safe-stop; status mode `SafeStop`, `hardware_ready`
//! 0) and is printed once. The driver recovers on its own (AutomaticErrorRecovery) from one
//! reflex only, `communication_constraints_violation` alone, and only once the arm is at rest
//! and the driver's own output is zero, at most `--communication-recoveries-per-minute` times
//! in any minute ([`CommunicationRecovery`]): that reflex says the robot missed 20 commands (a
//! starved control loop), not that the arm touched anything, and the stack's watchdog has
//! already stopped the motion. Any other reflex (collision, limits) is held until an operator
//! acts; `--error-recovery` (an explicit user action, once at start) sends AutomaticErrorRecovery.
//! The systemd notifications (READY=1, WATCHDOG=1) follow completed cycles as in the standard
//! service loop. On SIGTERM/SIGINT the motion is ramped down and finished before the driver exits; the
//! latency from each state's arrival to its command being sent is printed then (median, p99,
//! max).

use std::net::IpAddr;
use std::time::{Duration, Instant};

use motm_bus::{
    Bus, BusError, CycleStats, HeartbeatPublisher, SystemdNotifier, monotonic_now_ns, percentile,
};
use motm_core::command_limiter::LimiterMode;
use motm_franka::fci::FCI_PORT;
use motm_franka::hand::{HAND_PORT, HandClient, HandConfig};
use motm_franka::{FciClient, FciConfig, Motion};
use motm_graph::{PANDA_DRIVER, Task};
use motm_msgs::{GripperAction, GripperState, JointState, Message, ProcessState};
use motm_tasks::driver::ArmDriverTask;

use crate::hardware::{StackPorts, from_hardware};
use crate::{EXIT_BAD_INPUT, EXIT_FAILED, connect_within};

/// Flags of the `fci` backend.
#[derive(Debug, Clone, clap::Args)]
pub struct FciArgs {
    /// The robot's (FCI) address; required with `--backend fci`.
    #[arg(long)]
    pub robot_ip: Option<IpAddr>,
    /// The robot's FCI TCP port.
    #[arg(long, default_value_t = FCI_PORT)]
    pub fci_port: u16,
    /// The Franka Hand's TCP port.
    #[arg(long, default_value_t = HAND_PORT)]
    pub hand_port: u16,
    /// Run without the Franka Hand.
    #[arg(long)]
    pub no_hand: bool,
    /// Send one AutomaticErrorRecovery at start (an explicit user action).
    #[arg(long)]
    pub error_recovery: bool,
    /// Communication-constraints reflexes the driver recovers from on its own (the arm at rest,
    /// no other error), at most this many in any minute; 0: held until an operator acts.
    #[arg(long, default_value_t = 3)]
    pub communication_recoveries_per_minute: u32,
    /// Close (Grasp): expected object width, m.
    #[arg(long, default_value_t = HandConfig::default().grasp_width)]
    pub grasp_width: f64,
    /// Close (Grasp): inner tolerance, m.
    #[arg(long, default_value_t = HandConfig::default().epsilon_inner)]
    pub grasp_epsilon_inner: f64,
    /// Close (Grasp): outer tolerance, m.
    #[arg(long, default_value_t = HandConfig::default().epsilon_outer)]
    pub grasp_epsilon_outer: f64,
    /// Close (Grasp): force, N.
    #[arg(long, default_value_t = HandConfig::default().force)]
    pub grasp_force: f64,
    /// Open (Move): width, m.
    #[arg(long, default_value_t = HandConfig::default().open_width)]
    pub open_width: f64,
    /// Speed of Open and Close, m/s.
    #[arg(long, default_value_t = HandConfig::default().speed)]
    pub gripper_speed: f64,
}

impl FciArgs {
    /// The hand settings from the flags.
    pub fn hand_config(&self) -> HandConfig {
        HandConfig {
            port: self.hand_port,
            open_width: self.open_width,
            speed: self.gripper_speed,
            grasp_width: self.grasp_width,
            epsilon_inner: self.grasp_epsilon_inner,
            epsilon_outer: self.grasp_epsilon_outer,
            force: self.grasp_force,
            ..HandConfig::default()
        }
    }
}

/// Latencies from a state's arrival to its command being sent, ns: the newest
/// [`LatencyStats::WINDOW`] in a ring, plus the maximum over all.
#[derive(Debug, Default, Clone)]
pub struct LatencyStats {
    samples: Vec<u64>,
    next: usize,
    max: u64,
}

impl LatencyStats {
    /// Samples kept for the percentiles.
    pub const WINDOW: usize = 100_000;

    /// Records one latency (constant time: the oldest sample is overwritten).
    pub fn record(&mut self, ns: u64) {
        self.max = self.max.max(ns);
        if self.samples.len() < Self::WINDOW {
            self.samples.push(ns);
        } else {
            self.samples[self.next] = ns;
        }
        self.next = (self.next + 1) % Self::WINDOW;
    }

    /// `(count, median, p99, max)` in ns (count and percentiles over the window).
    pub fn summary(&self) -> (usize, u64, u64, u64) {
        let mut s = self.samples.clone();
        let max = self.max;
        let n = s.len();
        if n == 0 {
            return (0, 0, 0, 0);
        }
        let median = percentile(&mut s, 50.0);
        let p99 = percentile(&mut s, 99.0);
        (n, median, p99, max)
    }
}

/// When the driver sends AutomaticErrorRecovery on its own: the robot is in a reflex whose
/// only error is `communication_constraints_violation`, every joint is at rest, the driver's
/// own output is zero, the last request is [`CommunicationRecovery::RETRY_NS`] old, and fewer
/// than `per_minute` requests were sent in the last minute.
#[derive(Debug, Clone, Default)]
pub struct CommunicationRecovery {
    per_minute: u32,
    sent_ns: std::collections::VecDeque<u64>,
    total: u64,
}

impl CommunicationRecovery {
    /// Joint speed under which a joint is at rest, rad/s.
    pub const AT_REST: f64 = 1e-3;
    /// Least time between two requests, ns (the robot answers within a few cycles).
    pub const RETRY_NS: u64 = 200_000_000;
    /// The window of `per_minute`, ns.
    pub const WINDOW_NS: u64 = 60_000_000_000;

    /// A policy allowing `per_minute` requests in any minute (0: never).
    pub fn new(per_minute: u32) -> Self {
        Self {
            per_minute,
            sent_ns: Default::default(),
            total: 0,
        }
    }

    /// Requests sent since the driver started.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Requests sent in the window ending at `now_ns`.
    pub fn recent(&self, now_ns: u64) -> usize {
        self.sent_ns
            .iter()
            .filter(|&&t| Self::in_window(t, now_ns))
            .count()
    }

    /// Whether a request sent at `sent_ns` counts against the minute ending at `now_ns`.
    fn in_window(sent_ns: u64, now_ns: u64) -> bool {
        now_ns.saturating_sub(sent_ns) < Self::WINDOW_NS
    }

    /// Whether to send AutomaticErrorRecovery now, for the robot's `state` and the driver's
    /// last `output`; a yes is counted as sent at `now_ns`.
    pub fn should_recover(
        &mut self,
        state: &motm_franka::RobotState,
        output: &[f64; 7],
        now_ns: u64,
    ) -> bool {
        let only_communication = state
            .active_errors()
            .eq([motm_franka::state::COMMUNICATION_CONSTRAINTS_VIOLATION]);
        let at_rest = state.dq.iter().all(|v| v.abs() < Self::AT_REST);
        let quiet = output.iter().all(|v| *v == 0.0);
        let retry = self
            .sent_ns
            .back()
            .is_none_or(|&t| now_ns.saturating_sub(t) >= Self::RETRY_NS);
        while self
            .sent_ns
            .front()
            .is_some_and(|&t| !Self::in_window(t, now_ns))
        {
            self.sent_ns.pop_front();
        }
        let allowed = self.sent_ns.len() < self.per_minute as usize;
        let go = state.in_reflex() && only_communication && at_rest && quiet && retry && allowed;
        if go {
            self.sent_ns.push_back(now_ns);
            self.total += 1;
        }
        go
    }
}

/// Whether the driver should finish the running motion: it is not tracking and its output
/// is zero.
pub fn should_finish(mode: LimiterMode, velocity: &[f64; 7]) -> bool {
    mode != LimiterMode::Tracking && velocity.iter().all(|v| *v == 0.0)
}

/// Runs the FCI driver until SIGTERM/SIGINT or a fatal connection error: each robot state is
/// one cycle of `task` (the arm driver task of every backend), with the robot's `q`, `dq` and
/// the hand's state as its `hw_*` inputs, and its `hw_*` outputs sent to the robot and hand.
/// The task sends its status as it was built to; the driver waits up to `wait` for the
/// robot and hand to accept the connection.
pub fn run_fci(
    bus: &Bus,
    mut task: ArmDriverTask,
    wait: Duration,
    args: &FciArgs,
) -> Result<(), (u8, String)> {
    let ip = args
        .robot_ip
        .ok_or((EXIT_BAD_INPUT, "--backend fci needs --robot-ip".to_owned()))?;
    if task.axes() != 7 {
        return Err((
            EXIT_BAD_INPUT,
            format!(
                "the FCI backend drives 7 joints, the robot has {}",
                task.axes()
            ),
        ));
    }
    let failed = |e: BusError| (EXIT_FAILED, e.to_string());
    let mut stack = StackPorts::<ArmDriverTask>::open(bus, &PANDA_DRIVER).map_err(failed)?;
    let mut heartbeat = HeartbeatPublisher::new(bus).map_err(failed)?;
    // systemd readiness and watchdog, as the standard service loop sends them (a no-op outside
    // systemd): READY=1 after the first completed cycle, WATCHDOG=1 after completed cycles.
    let mut systemd = SystemdNotifier::from_env();

    let lost = |e: motm_franka::FciError| (EXIT_FAILED, e.to_string());
    let config = FciConfig {
        port: args.fci_port,
        ..FciConfig::default()
    };
    let mut client = connect_within(&format!("FCI {ip}:{}", args.fci_port), wait, || {
        FciClient::connect(ip, config)
    })
    .map_err(|e| (EXIT_FAILED, e))?;
    let mut hand = if args.no_hand {
        None
    } else {
        let hand_config = args.hand_config();
        Some(
            connect_within(
                &format!("Franka Hand {ip}:{}", args.hand_port),
                wait,
                || HandClient::connect(ip, hand_config),
            )
            .map_err(|e| (EXIT_FAILED, e))?,
        )
    };
    motm_bus::say!(
        "panda-driver: connected to the robot at {ip}:{} (FCI v5){}",
        args.fci_port,
        if hand.is_some() { " and its hand" } else { "" }
    );
    if args.error_recovery {
        while !client.has_state() {
            client.next_state().map_err(lost)?;
        }
        client.request_error_recovery().map_err(lost)?;
        for _ in 0..10_000 {
            client.next_state().map_err(lost)?;
            if client.recovery().is_some() {
                break;
            }
        }
        motm_bus::say!(
            "panda-driver: AutomaticErrorRecovery: {:?}",
            client.recovery()
        );
    }

    let mut recovery = CommunicationRecovery::new(args.communication_recoveries_per_minute);
    let mut recovery_reported = true;
    let mut output = [0.0; 7];
    let mut latency = LatencyStats::default();
    let mut stats = CycleStats::new(2000);
    let mut hand_states = 0u64;
    let mut last_heartbeat = Instant::now();
    let mut reported_blocked = false;
    let mut stopping_for_exit = false;
    let mut exit_states = 0u32;
    loop {
        if !stopping_for_exit && motm_bus::termination::termination_requested() {
            stopping_for_exit = true;
        }
        if stopping_for_exit {
            exit_states += 1;
            if client.motion() == Motion::Idle || exit_states > 5000 {
                break;
            }
        }
        let ended = match client.next_state() {
            Ok(ended) => ended,
            // Asked to stop, and the robot went away first (a stack stopping all at once):
            // nothing is left to ramp down.
            Err(e) if stopping_for_exit || motm_bus::termination::termination_requested() => {
                motm_bus::say!("panda-driver: {e} while stopping");
                break;
            }
            Err(e) => return Err(lost(e)),
        };
        let arrival = client.state_received_at().unwrap_or_else(Instant::now);
        let now_ns = monotonic_now_ns();
        if let Some(end) = ended {
            motm_bus::say!("panda-driver: FCI motion ended: {}", end.describe());
        }
        let inputs = stack.read();
        let state = *client.state();
        // The robot takes no motion unless it is idle or moving: a reflex or a user stop holds
        // the driver in safe-stop until the robot is idle again.
        let blocked = !(state.idle() || state.joint_velocity_motion_running());
        if blocked && !reported_blocked {
            let errors: Vec<usize> = state.active_errors().collect();
            motm_bus::say!(
                "panda-driver: the robot is not commandable (robot_mode {}, errors {errors:?}); safe-stop held",
                state.robot_mode
            );
        }
        reported_blocked = blocked;
        if blocked
            && client.motion() == Motion::Idle
            && recovery.should_recover(&state, &output, now_ns)
        {
            match client.request_error_recovery() {
                Ok(()) => {
                    recovery_reported = false;
                    motm_bus::say!(
                        "panda-driver: communication-constraints reflex, the arm at rest: AutomaticErrorRecovery ({} in the last minute)",
                        recovery.recent(now_ns)
                    );
                }
                Err(e) => motm_bus::say!("panda-driver: AutomaticErrorRecovery: {e}"),
            }
        }
        if !recovery_reported && let Some(status) = client.recovery() {
            recovery_reported = true;
            motm_bus::say!("panda-driver: AutomaticErrorRecovery answered {status:?}");
        }
        task.set_hardware_hold(stopping_for_exit || blocked);
        let mut joints = JointState::zeroed();
        joints.joint_count = 7;
        joints.position[..7].copy_from_slice(&state.q);
        joints.velocity[..7].copy_from_slice(&state.dq);
        inputs.hw_state = Some(from_hardware(joints, state.message_id, now_ns));
        if let Some(hand) = &mut hand
            && let Some(s) = hand.poll().map_err(|e| (EXIT_FAILED, e.to_string()))?
        {
            let mut m = GripperState::zeroed();
            m.width = s.width.clamp(0.0, 0.2);
            m.grasping = s.is_grasped.into();
            hand_states += 1;
            inputs.hw_gripper = Some(from_hardware(m, hand_states, now_ns));
        }
        let stopped = task.hardware_hold() || inputs.safe_stop.is_some_and(|s| s.active == 1);
        let out = task.step(now_ns, inputs);
        let mut velocity = [0.0; 7];
        if let Some(command) = &out.hw_command {
            velocity.copy_from_slice(&command.velocity[..7]);
        }
        let mode = task.counters().mode;
        match client.motion() {
            Motion::Idle if mode == LimiterMode::Tracking && !stopped && state.idle() => {
                if let Err(e) = client.start_motion() {
                    motm_bus::say!("panda-driver: {e}");
                }
            }
            Motion::Running { .. } if should_finish(mode, &velocity) => client.finish(),
            _ => {}
        }
        output = velocity;
        if client.command(&velocity).map_err(lost)?.is_some() {
            latency.record(arrival.elapsed().as_nanos() as u64);
        }
        if let (Some(hand), Some(command)) = (&mut hand, &out.hw_gripper) {
            let request = match command.action() {
                Some(GripperAction::Open) => Some(hand.open_request()),
                Some(GripperAction::Close) => Some(hand.close_request()),
                None => None,
            };
            if let Some(request) = request {
                hand.request(request)
                    .map_err(|e| (EXIT_FAILED, e.to_string()))?;
            }
        }
        stack.write(out);
        systemd.iteration_done(monotonic_now_ns());
        let cycle_ns = arrival.elapsed().as_nanos() as u64;
        stats.record(cycle_ns, cycle_ns > 1_000_000, now_ns);
        if last_heartbeat.elapsed() >= Duration::from_millis(100) {
            last_heartbeat = Instant::now();
            heartbeat
                .publish(
                    ProcessState::Running,
                    &mut stats,
                    1_000_000,
                    bus.rejected_messages(),
                )
                .ok();
        }
    }
    systemd.stopping();
    let (n, median, p99, max) = latency.summary();
    let c = client.counters();
    motm_bus::say!(
        "panda-driver: FCI exit: {} states, {} lost, {} bad datagrams, {} commands, {} motions, {} reflexes, {} recoveries, {} safe stops, {} port failures; state-to-command latency over {n}: median {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        c.states,
        c.lost_states,
        c.bad_datagrams,
        c.commands_sent,
        c.motions,
        c.reflexes,
        recovery.total(),
        c.safe_stops,
        stack.failures(),
        median as f64 / 1e3,
        p99 as f64 / 1e3,
        max as f64 / 1e3
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_motion_finishes_only_at_zero_when_not_tracking() {
        assert!(!should_finish(LimiterMode::Tracking, &[0.0; 7]));
        assert!(!should_finish(
            LimiterMode::Stale,
            &[0.0, 0.0, 1e-9, 0.0, 0.0, 0.0, 0.0]
        ));
        assert!(should_finish(LimiterMode::Stale, &[0.0; 7]));
        assert!(should_finish(LimiterMode::SafeStop, &[0.0; 7]));
    }

    #[test]
    fn only_a_communication_reflex_at_rest_is_recovered_and_at_most_per_minute() {
        use motm_franka::RobotState;
        use motm_franka::state::COMMUNICATION_CONSTRAINTS_VIOLATION as CCV;
        let mut reflex = RobotState {
            robot_mode: 4,
            ..RobotState::default()
        };
        reflex.errors[CCV] = true;
        let quiet = [0.0; 7];
        let s = 1_000_000_000;
        let mut policy = CommunicationRecovery::new(2);
        // Not in a reflex, still moving, the driver still commanding, or another error: no.
        let idle = RobotState {
            robot_mode: 1,
            ..reflex
        };
        assert!(!policy.should_recover(&idle, &quiet, s));
        let mut moving = reflex;
        moving.dq[3] = 0.01;
        assert!(!policy.should_recover(&moving, &quiet, s));
        let mut commanding = quiet;
        commanding[0] = 1e-4;
        assert!(!policy.should_recover(&reflex, &commanding, s));
        let mut collision = reflex;
        collision.errors[CCV + 1] = true;
        assert!(!policy.should_recover(&collision, &quiet, s));
        // The communication reflex at rest: yes, not again within the retry time, twice a
        // minute at most, and again once the minute has passed.
        assert!(policy.should_recover(&reflex, &quiet, s));
        assert!(!policy.should_recover(&reflex, &quiet, s + 100_000_000));
        assert!(policy.should_recover(&reflex, &quiet, 2 * s));
        assert!(!policy.should_recover(&reflex, &quiet, 3 * s));
        assert_eq!(policy.recent(3 * s), 2);
        assert!(policy.should_recover(&reflex, &quiet, 62 * s));
        assert_eq!(policy.total(), 3);
        // 0 per minute: never.
        assert!(!CommunicationRecovery::new(0).should_recover(&reflex, &quiet, s));
    }

    #[test]
    fn latency_percentiles() {
        let mut l = LatencyStats::default();
        assert_eq!(l.summary(), (0, 0, 0, 0));
        for k in 1..=100 {
            l.record(k * 1000);
        }
        let (n, median, p99, max) = l.summary();
        assert_eq!((n, max), (100, 100_000));
        assert!((50_000..=51_000).contains(&median), "{median}");
        assert!((99_000..=100_000).contains(&p99), "{p99}");
    }
}
