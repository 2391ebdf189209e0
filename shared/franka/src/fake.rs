//! Fake robots that speak the real protocols on real sockets: [`FakeRobot`] (the FCI server:
//! TCP requests, 1 kHz UDP states, the motion lifecycle, libfranka's limit checks on every
//! command, extrapolation of lost commands and the communication-constraints reflex) and
//! [`FakeHand`] (the hand server). Both are stepped once per millisecond by
//! [`FakeRobot::cycle`] / [`FakeHand::cycle`]; their physics is a trait, so the `fake-panda`
//! binary plugs in the simulator and tests plug in [`IdealArm`] / [`IdealHand`].
//!
//! One cycle of [`FakeRobot`]: (1) accept a client (one at a time) and serve its TCP requests;
//! (2) take the newest command answering the last state (`message_id` equal to it; older ones
//! are late and dropped); (3) while moving, check it against the limits (velocity, and the
//! acceleration and jerk of `dq_c` against the previous command) and apply it, or, with no
//! command, extrapolate at constant acceleration and after `reflex_after` consecutive missed
//! cycles raise the communication-constraints reflex; (4) step the physics; (5) send the
//! state, `message_id` +1.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpListener, TcpStream, UdpSocket};

use crate::fci::{
    Command, ConnectStatus, ControllerMode, FCI_VERSION, Framer, MotionGeneratorMode, MoveStatus,
    RecoveryStatus, Request, Response, SetterStatus, StopMoveStatus,
};
use crate::hand::{
    GripperState, HAND_VERSION, HandCommand, HandRequest, HandResponse, HandStatus, hand_framer,
};
use crate::rate_limit::{ACCELERATION_LIMIT, DT, JERK_LIMIT, VELOCITY_LIMIT};
use crate::state::{
    COMMUNICATION_CONSTRAINTS_VIOLATION, ERROR_COUNT, RobotCommand, RobotMode, RobotState,
    StateGenerator,
};

/// The arm's physics as the fake sees it.
pub trait ArmPhysics {
    /// Applies the commanded joint velocity for one period `dt`.
    fn step(&mut self, dq_c: &[f64; 7], dt: f64);
    /// Measured joint positions and velocities.
    fn joints(&self) -> ([f64; 7], [f64; 7]);
}

/// An arm that follows its command exactly (`dq = dq_c`, `q += dq·dt`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct IdealArm {
    /// Joint positions, rad.
    pub q: [f64; 7],
    /// Joint velocities, rad/s.
    pub dq: [f64; 7],
}

impl ArmPhysics for IdealArm {
    fn step(&mut self, dq_c: &[f64; 7], dt: f64) {
        self.dq = *dq_c;
        for (q, v) in self.q.iter_mut().zip(dq_c) {
            *q += v * dt;
        }
    }
    fn joints(&self) -> ([f64; 7], [f64; 7]) {
        (self.q, self.dq)
    }
}

/// Commands the fake ignores on purpose (fault tests): those answering the states with
/// `message_id` in `[at_ms, at_ms + count)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DropPlan {
    /// Robot time of the first state whose command is dropped, ms.
    pub at_ms: u64,
    /// Number of consecutive commands dropped.
    pub count: u64,
}

/// Settings of a [`FakeRobot`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FakeRobotConfig {
    /// Consecutive cycles without a command that raise the communication-constraints reflex
    /// (libfranka's robot: 20).
    pub reflex_after: u32,
    /// Commands to drop.
    pub drop: Option<DropPlan>,
    /// Robot time at which one wrong-size (2372-byte) state is sent instead of the state.
    pub bad_state_at_ms: Option<u64>,
    /// Window of `control_command_success_rate`, cycles (the fraction of motion cycles with a
    /// command on time over the last this many).
    pub success_window: usize,
    /// Tolerance on the acceleration check, rad/s² (the jerk check uses it ×1000).
    pub tolerance: f64,
}

impl Default for FakeRobotConfig {
    fn default() -> Self {
        Self {
            reflex_after: 20,
            drop: None,
            bad_state_at_ms: None,
            success_window: 100,
            tolerance: 1e-6,
        }
    }
}

/// Commands beyond libfranka's limits, counted by the fake.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LimitViolations {
    /// Commands with any violation.
    pub commands: u64,
    /// Joint values beyond the velocity limit.
    pub velocity: u64,
    /// Joint values beyond the acceleration limit.
    pub acceleration: u64,
    /// Joint values beyond the jerk limit.
    pub jerk: u64,
    /// Commands with a NaN or infinite `dq_c` (treated as missing).
    pub non_finite: u64,
}

/// Counters of a [`FakeRobot`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeCounters {
    /// Cycles run.
    pub cycles: u64,
    /// States sent.
    pub states_sent: u64,
    /// Commands received on time.
    pub commands: u64,
    /// Commands that arrived after a newer state had gone out (dropped).
    pub late_commands: u64,
    /// Datagrams of the wrong size.
    pub bad_datagrams: u64,
    /// Commands dropped by the [`DropPlan`].
    pub dropped: u64,
    /// Motion cycles without a command (extrapolated).
    pub missed_cycles: u64,
    /// Longest run of consecutive missed cycles.
    pub max_consecutive_missed: u32,
    /// TCP connections accepted.
    pub connections: u64,
    /// Moves started.
    pub motions: u64,
    /// Motions finished by the client (Move `Success`).
    pub finished: u64,
    /// Reflexes raised.
    pub reflexes: u64,
    /// Motions cancelled by StopMove.
    pub cancelled: u64,
    /// Automatic error recoveries done.
    pub recoveries: u64,
    /// TCP requests that did not decode (the connection is then closed).
    pub protocol_errors: u64,
    /// The limit checks.
    pub violations: LimitViolations,
}

enum FakeMotion {
    Idle,
    Running { move_id: u32, missed: u32 },
}

struct Client {
    stream: TcpStream,
    framer: Framer,
    udp_target: Option<SocketAddr>,
}

/// The fake FCI robot. See the module documentation.
pub struct FakeRobot {
    config: FakeRobotConfig,
    listener: TcpListener,
    udp: UdpSocket,
    client: Option<Client>,
    time_ms: u64,
    motion: FakeMotion,
    dq_c: [f64; 7],
    ddq_c: [f64; 7],
    q_d: [f64; 7],
    robot_mode: RobotMode,
    errors: [bool; ERROR_COUNT],
    reflex_reason: [bool; ERROR_COUNT],
    window: VecDeque<bool>,
    counters: FakeCounters,
    buffer: Vec<u8>,
}

fn nonblocking_listener(ip: IpAddr, port: u16) -> std::io::Result<TcpListener> {
    let listener = TcpListener::bind(SocketAddr::new(ip, port))?;
    listener.set_nonblocking(true)?;
    Ok(listener)
}

/// Reads what is available from a non-blocking stream into `framer`; `false` when closed.
fn read_available(stream: &mut TcpStream, framer: &mut Framer) -> bool {
    let mut buf = [0u8; 1024];
    loop {
        match stream.read(&mut buf) {
            Ok(0) => return false,
            Ok(n) => framer.push(&buf[..n]),
            Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => return false,
        }
    }
}

fn write_all(stream: &mut TcpStream, bytes: &[u8]) -> bool {
    stream.set_nonblocking(false).is_ok()
        && stream.write_all(bytes).is_ok()
        && stream.set_nonblocking(true).is_ok()
}

impl FakeRobot {
    /// A fake robot listening on TCP `ip:port` (0: any free port), idle at robot time 0.
    pub fn bind(ip: IpAddr, port: u16, config: FakeRobotConfig) -> std::io::Result<Self> {
        let listener = nonblocking_listener(ip, port)?;
        let udp = UdpSocket::bind(SocketAddr::new(ip, 0))?;
        udp.set_nonblocking(true)?;
        Ok(Self {
            config,
            listener,
            udp,
            client: None,
            time_ms: 0,
            motion: FakeMotion::Idle,
            dq_c: [0.0; 7],
            ddq_c: [0.0; 7],
            q_d: [0.0; 7],
            robot_mode: RobotMode::Idle,
            errors: [false; ERROR_COUNT],
            reflex_reason: [false; ERROR_COUNT],
            window: VecDeque::with_capacity(config.success_window),
            counters: FakeCounters::default(),
            buffer: vec![0u8; 4096],
        })
    }

    /// The TCP port.
    pub fn port(&self) -> u16 {
        self.listener.local_addr().map(|a| a.port()).unwrap_or(0)
    }

    /// The counters.
    pub fn counters(&self) -> &FakeCounters {
        &self.counters
    }

    /// Robot time, ms (the last state's `message_id`).
    pub fn time_ms(&self) -> u64 {
        self.time_ms
    }

    /// Whether a client is connected.
    pub fn connected(&self) -> bool {
        self.client.is_some()
    }

    /// The robot mode.
    pub fn robot_mode(&self) -> RobotMode {
        self.robot_mode
    }

    /// The commanded joint velocity in effect (after extrapolation), rad/s.
    pub fn commanded_velocity(&self) -> [f64; 7] {
        self.dq_c
    }

    fn respond(&mut self, id: u32, response: Response) {
        if let Some(c) = &mut self.client
            && !write_all(&mut c.stream, &response.encode(id))
        {
            self.drop_client();
        }
    }

    fn drop_client(&mut self) {
        self.client = None;
        if let FakeMotion::Running { .. } = self.motion {
            // The client vanished mid-motion: the robot stops.
            self.stop_motion();
        }
    }

    fn stop_motion(&mut self) {
        self.motion = FakeMotion::Idle;
        self.dq_c = [0.0; 7];
        self.ddq_c = [0.0; 7];
        if self.robot_mode == RobotMode::Move {
            self.robot_mode = RobotMode::Idle;
        }
    }

    fn reflex(&mut self, move_id: u32) {
        self.stop_motion();
        self.robot_mode = RobotMode::Reflex;
        self.errors[COMMUNICATION_CONSTRAINTS_VIOLATION] = true;
        self.reflex_reason[COMMUNICATION_CONSTRAINTS_VIOLATION] = true;
        self.counters.reflexes += 1;
        self.respond(move_id, Response::Move(MoveStatus::ReflexAborted));
    }

    fn serve_tcp(&mut self) {
        if self.client.is_none()
            && let Ok((stream, _)) = self.listener.accept()
        {
            let _ = stream.set_nodelay(true);
            if stream.set_nonblocking(true).is_ok() {
                self.counters.connections += 1;
                self.client = Some(Client {
                    stream,
                    framer: Framer::fci(),
                    udp_target: None,
                });
            }
        }
        let Some(c) = &mut self.client else { return };
        if !read_available(&mut c.stream, &mut c.framer) {
            self.drop_client();
            return;
        }
        loop {
            let Some(c) = &mut self.client else { return };
            let message = match c.framer.next_message() {
                Ok(Some(m)) => m,
                Ok(None) => return,
                Err(_) => {
                    self.counters.protocol_errors += 1;
                    self.drop_client();
                    return;
                }
            };
            match Request::decode(&message) {
                Ok((id, request)) => self.handle(id, request),
                Err(_) => {
                    self.counters.protocol_errors += 1;
                    self.drop_client();
                    return;
                }
            }
        }
    }

    fn handle(&mut self, id: u32, request: Request) {
        match request {
            Request::Connect { version, udp_port } => {
                if version != FCI_VERSION {
                    self.respond(
                        id,
                        Response::Connect {
                            status: ConnectStatus::IncompatibleLibraryVersion,
                            version: FCI_VERSION,
                        },
                    );
                    self.drop_client();
                    return;
                }
                if let Some(c) = &mut self.client {
                    c.udp_target = c
                        .stream
                        .peer_addr()
                        .ok()
                        .map(|a| SocketAddr::new(a.ip(), udp_port));
                }
                self.respond(
                    id,
                    Response::Connect {
                        status: ConnectStatus::Success,
                        version: FCI_VERSION,
                    },
                );
            }
            Request::Move(m) => {
                let status = if m.controller_mode != ControllerMode::JointImpedance
                    || m.motion_generator_mode != MotionGeneratorMode::JointVelocity
                {
                    // This fake only runs joint-velocity motions.
                    MoveStatus::InvalidArgumentRejected
                } else if self.robot_mode != RobotMode::Idle {
                    MoveStatus::CommandNotPossibleRejected
                } else {
                    MoveStatus::MotionStarted
                };
                if status == MoveStatus::MotionStarted {
                    self.motion = FakeMotion::Running {
                        move_id: id,
                        missed: 0,
                    };
                    self.robot_mode = RobotMode::Move;
                    self.dq_c = [0.0; 7];
                    self.ddq_c = [0.0; 7];
                    self.window.clear();
                    self.counters.motions += 1;
                }
                self.respond(id, Response::Move(status));
            }
            Request::StopMove => {
                if let FakeMotion::Running { move_id, .. } = self.motion {
                    self.stop_motion();
                    self.counters.cancelled += 1;
                    self.respond(id, Response::StopMove(StopMoveStatus::Success));
                    self.respond(move_id, Response::Move(MoveStatus::Aborted));
                } else {
                    self.respond(id, Response::StopMove(StopMoveStatus::Rejected));
                }
            }
            Request::AutomaticErrorRecovery => {
                let status = match self.robot_mode {
                    RobotMode::Reflex | RobotMode::Idle => {
                        self.errors = [false; ERROR_COUNT];
                        self.reflex_reason = [false; ERROR_COUNT];
                        self.robot_mode = RobotMode::Idle;
                        self.counters.recoveries += 1;
                        RecoveryStatus::Success
                    }
                    _ => RecoveryStatus::CommandNotPossibleRejected,
                };
                self.respond(id, Response::AutomaticErrorRecovery(status));
            }
            other => {
                let status = if self.robot_mode == RobotMode::Move {
                    SetterStatus::CommandNotPossibleRejected
                } else {
                    SetterStatus::Success
                };
                let command: Command = other.command();
                self.respond(id, Response::Setter { command, status });
            }
        }
    }

    /// The newest command answering the last state, if any.
    fn take_command(&mut self) -> Option<RobotCommand> {
        let mut newest = None;
        loop {
            match self.udp.recv_from(&mut self.buffer) {
                Ok((n, _)) => match RobotCommand::decode(&self.buffer[..n]) {
                    Ok(c) if c.message_id == self.time_ms && self.time_ms > 0 => newest = Some(c),
                    Ok(_) => self.counters.late_commands += 1,
                    Err(_) => self.counters.bad_datagrams += 1,
                },
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => return newest,
            }
        }
    }

    /// Counts the limit violations of `dq` against the command in effect.
    fn check_limits(&mut self, dq: &[f64; 7]) {
        let tol = self.config.tolerance;
        let v = &mut self.counters.violations;
        let mut any = false;
        for i in 0..7 {
            let a = (dq[i] - self.dq_c[i]) / DT;
            let j = (a - self.ddq_c[i]) / DT;
            if dq[i].abs() > VELOCITY_LIMIT[i] {
                v.velocity += 1;
                any = true;
            }
            if a.abs() > ACCELERATION_LIMIT[i] + tol {
                v.acceleration += 1;
                any = true;
            }
            if j.abs() > JERK_LIMIT[i] + 1000.0 * tol {
                v.jerk += 1;
                any = true;
            }
        }
        if any {
            v.commands += 1;
        }
    }

    fn motion_step(&mut self, command: Option<RobotCommand>) {
        let FakeMotion::Running { move_id, missed } = self.motion else {
            return;
        };
        let command = command.filter(|c| {
            let dropped = self
                .config
                .drop
                .is_some_and(|d| (d.at_ms..d.at_ms + d.count).contains(&c.message_id));
            if dropped {
                self.counters.dropped += 1;
            }
            let finite = c.dq_c.iter().all(|v| v.is_finite());
            if !finite {
                self.counters.violations.non_finite += 1;
            }
            !dropped && finite
        });
        if self.window.len() == self.config.success_window {
            self.window.pop_front();
        }
        self.window.push_back(command.is_some());
        match command {
            Some(c) => {
                self.counters.commands += 1;
                self.check_limits(&c.dq_c);
                for i in 0..7 {
                    self.ddq_c[i] = (c.dq_c[i] - self.dq_c[i]) / DT;
                }
                self.dq_c = c.dq_c;
                self.motion = FakeMotion::Running { move_id, missed: 0 };
                if c.motion_generation_finished {
                    self.stop_motion();
                    self.counters.finished += 1;
                    self.respond(move_id, Response::Move(MoveStatus::Success));
                }
            }
            None => {
                let missed = missed + 1;
                self.counters.missed_cycles += 1;
                self.counters.max_consecutive_missed =
                    self.counters.max_consecutive_missed.max(missed);
                if missed >= self.config.reflex_after {
                    self.reflex(move_id);
                    return;
                }
                // Extrapolate at constant acceleration, within the velocity limit.
                let joints = self.dq_c.iter_mut().zip(self.ddq_c.iter_mut());
                for ((v, a), limit) in joints.zip(VELOCITY_LIMIT) {
                    let next = *v + *a * DT;
                    let clamped = next.clamp(-limit, limit);
                    if clamped != next {
                        *a = 0.0;
                    }
                    *v = clamped;
                }
                self.motion = FakeMotion::Running { move_id, missed };
            }
        }
    }

    fn state(&self, arm: &dyn ArmPhysics) -> RobotState {
        let (q, dq) = arm.joints();
        let running = matches!(self.motion, FakeMotion::Running { .. });
        let rate = if self.window.is_empty() {
            0.0
        } else {
            self.window.iter().filter(|&&ok| ok).count() as f64 / self.window.len() as f64
        };
        let mut identity = [0.0; 16];
        for k in 0..4 {
            identity[5 * k] = 1.0;
        }
        RobotState {
            message_id: self.time_ms,
            O_T_EE: identity,
            O_T_EE_d: identity,
            q,
            q_d: self.q_d,
            dq,
            dq_d: self.dq_c,
            ddq_d: self.ddq_c,
            theta: q,
            dtheta: dq,
            motion_generator_mode: if running {
                StateGenerator::JointVelocity as u8
            } else {
                StateGenerator::Idle as u8
            },
            controller_mode: 0,
            errors: self.errors,
            reflex_reason: self.reflex_reason,
            robot_mode: self.robot_mode as u8,
            control_command_success_rate: rate,
            ..RobotState::default()
        }
    }

    /// One 1 ms cycle. See the module documentation.
    pub fn cycle(&mut self, arm: &mut dyn ArmPhysics) {
        self.counters.cycles += 1;
        self.serve_tcp();
        let command = self.take_command();
        self.motion_step(command);
        arm.step(&self.dq_c, DT);
        for i in 0..7 {
            self.q_d[i] += self.dq_c[i] * DT;
        }
        if !matches!(self.motion, FakeMotion::Running { .. }) {
            self.q_d = arm.joints().0;
        }
        self.time_ms += 1;
        let Some(target) = self.client.as_ref().and_then(|c| c.udp_target) else {
            return;
        };
        let bytes = self.state(arm).encode();
        let out: &[u8] = if self.config.bad_state_at_ms == Some(self.time_ms) {
            &bytes[..RobotState::SIZE - 1]
        } else {
            &bytes
        };
        if self.udp.send_to(out, target).is_ok() {
            self.counters.states_sent += 1;
        }
    }

    /// A one-line summary of the counters.
    pub fn summary(&self) -> String {
        let c = &self.counters;
        format!(
            "robot time {} ms, {} states sent, {} commands, {} late, {} missed (max {} in a row), \
             {} dropped, {} motions, {} finished, {} reflexes, {} cancelled, limit violations: {} \
             commands (velocity {}, acceleration {}, jerk {}, non-finite {})",
            self.time_ms,
            c.states_sent,
            c.commands,
            c.late_commands,
            c.missed_cycles,
            c.max_consecutive_missed,
            c.dropped,
            c.motions,
            c.finished,
            c.reflexes,
            c.cancelled,
            c.violations.commands,
            c.violations.velocity,
            c.violations.acceleration,
            c.violations.jerk,
            c.violations.non_finite
        )
    }
}

/// What the hand is asked to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HandAction {
    /// Calibrate (open fully).
    Homing,
    /// Move to a width at a speed.
    Move {
        /// Target width, m.
        width: f64,
        /// Speed, m/s.
        speed: f64,
    },
    /// Close on an object; success if `width − ε_in < d < width + ε_out`.
    Grasp {
        /// Expected width, m.
        width: f64,
        /// Inner tolerance, m.
        epsilon_inner: f64,
        /// Outer tolerance, m.
        epsilon_outer: f64,
        /// Speed, m/s.
        speed: f64,
    },
}

/// The hand's physics as the fake sees it.
pub trait HandPhysics {
    /// Starts an action (replacing any running one).
    fn start(&mut self, action: HandAction);
    /// Stops the running action where the fingers are.
    fn stop(&mut self);
    /// Steps `dt`; returns whether the action succeeded once it completes.
    fn step(&mut self, dt: f64) -> Option<bool>;
    /// Opening, m, and whether an object is held.
    fn state(&self) -> (f64, bool);
}

/// A hand whose fingers move at the commanded speed and stop on an object of `object_width`
/// (if one is between them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdealHand {
    /// Opening, m.
    pub width: f64,
    /// Largest opening, m.
    pub max_width: f64,
    /// Width of the object between the fingers, if any.
    pub object_width: Option<f64>,
    action: Option<HandAction>,
    grasped: bool,
}

impl IdealHand {
    /// A hand open at `max_width` with an optional object.
    pub fn new(max_width: f64, object_width: Option<f64>) -> Self {
        Self {
            width: max_width,
            max_width,
            object_width,
            action: None,
            grasped: false,
        }
    }
}

impl HandPhysics for IdealHand {
    fn start(&mut self, action: HandAction) {
        self.grasped = false;
        self.action = Some(action);
    }
    fn stop(&mut self) {
        self.action = None;
    }
    fn step(&mut self, dt: f64) -> Option<bool> {
        let (target, speed) = match self.action? {
            HandAction::Homing => (self.max_width, 0.1),
            HandAction::Move { width, speed } => (width.clamp(0.0, self.max_width), speed),
            HandAction::Grasp { speed, .. } => (0.0, speed),
        };
        let floor = match self.object_width {
            Some(o) if target < o && self.width >= o => o,
            _ => 0.0,
        };
        let goal = target.max(floor);
        let stepped = (goal - self.width).clamp(-speed * dt, speed * dt);
        self.width += stepped;
        if (self.width - goal).abs() > 1e-12 {
            return None;
        }
        self.width = goal;
        let action = self.action.take()?;
        Some(match action {
            HandAction::Grasp {
                width,
                epsilon_inner,
                epsilon_outer,
                ..
            } => {
                let held = self.object_width.is_some_and(|o| goal == o);
                self.grasped = held
                    && width - epsilon_inner < self.width
                    && self.width < width + epsilon_outer;
                self.grasped
            }
            _ => (self.width - target).abs() < 1e-3,
        })
    }
    fn state(&self) -> (f64, bool) {
        (self.width, self.grasped)
    }
}

/// Settings of a [`FakeHand`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FakeHandConfig {
    /// A state every this many cycles (ms). *Uncertain* on the real hand; 10 (100 Hz).
    pub state_every_ms: u32,
    /// `max_width` reported, m.
    pub max_width: f64,
}

impl Default for FakeHandConfig {
    fn default() -> Self {
        Self {
            state_every_ms: 10,
            max_width: 0.08,
        }
    }
}

/// Counters of a [`FakeHand`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeHandCounters {
    /// Connections accepted.
    pub connections: u64,
    /// States sent.
    pub states_sent: u64,
    /// Actions started.
    pub actions: u64,
    /// Actions answered Success.
    pub succeeded: u64,
    /// Actions answered Unsuccessful or Aborted.
    pub failed: u64,
    /// Requests that did not decode.
    pub protocol_errors: u64,
}

struct HandClientConn {
    stream: TcpStream,
    framer: Framer,
    udp_target: Option<SocketAddr>,
}

/// The fake Franka Hand. See the module documentation.
pub struct FakeHand {
    config: FakeHandConfig,
    listener: TcpListener,
    udp: UdpSocket,
    client: Option<HandClientConn>,
    pending: Option<(u32, HandCommand)>,
    time_ms: u64,
    message_id: u32,
    counters: FakeHandCounters,
}

impl FakeHand {
    /// A fake hand listening on TCP `ip:port` (0: any free port).
    pub fn bind(ip: IpAddr, port: u16, config: FakeHandConfig) -> std::io::Result<Self> {
        let listener = nonblocking_listener(ip, port)?;
        let udp = UdpSocket::bind(SocketAddr::new(ip, 0))?;
        Ok(Self {
            config,
            listener,
            udp,
            client: None,
            pending: None,
            time_ms: 0,
            message_id: 0,
            counters: FakeHandCounters::default(),
        })
    }

    /// The TCP port.
    pub fn port(&self) -> u16 {
        self.listener.local_addr().map(|a| a.port()).unwrap_or(0)
    }

    /// The counters.
    pub fn counters(&self) -> &FakeHandCounters {
        &self.counters
    }

    fn respond(&mut self, id: u32, command: HandCommand, status: HandStatus, version: Option<u16>) {
        if command != HandCommand::Connect && command != HandCommand::Stop {
            if status == HandStatus::Success {
                self.counters.succeeded += 1;
            } else {
                self.counters.failed += 1;
            }
        }
        let bytes = HandResponse {
            command,
            status,
            version,
        }
        .encode(id);
        if let Some(c) = &mut self.client
            && !write_all(&mut c.stream, &bytes)
        {
            self.client = None;
        }
    }

    fn handle(&mut self, id: u32, request: HandRequest, hand: &mut dyn HandPhysics) {
        let action = match request {
            HandRequest::Connect { version, udp_port } => {
                let ok = version == HAND_VERSION;
                if let Some(c) = &mut self.client {
                    c.udp_target = c
                        .stream
                        .peer_addr()
                        .ok()
                        .map(|a| SocketAddr::new(a.ip(), udp_port));
                }
                let status = if ok {
                    HandStatus::Success
                } else {
                    HandStatus::Fail
                };
                self.respond(id, HandCommand::Connect, status, Some(HAND_VERSION));
                if !ok {
                    self.client = None;
                }
                return;
            }
            HandRequest::Stop => {
                hand.stop();
                if let Some((pid, pc)) = self.pending.take() {
                    self.respond(pid, pc, HandStatus::Aborted, None);
                }
                self.respond(id, HandCommand::Stop, HandStatus::Success, None);
                return;
            }
            HandRequest::Homing => HandAction::Homing,
            HandRequest::Move { width, speed } => HandAction::Move { width, speed },
            HandRequest::Grasp {
                width,
                epsilon_inner,
                epsilon_outer,
                speed,
                ..
            } => HandAction::Grasp {
                width,
                epsilon_inner,
                epsilon_outer,
                speed,
            },
        };
        // A new action preempts the running one, which is answered Aborted.
        if let Some((pid, pc)) = self.pending.take() {
            self.respond(pid, pc, HandStatus::Aborted, None);
        }
        self.counters.actions += 1;
        hand.start(action);
        self.pending = Some((id, request.command()));
    }

    /// One 1 ms cycle: serve requests, step the hand, answer a completed action, send the
    /// state every `state_every_ms`.
    pub fn cycle(&mut self, hand: &mut dyn HandPhysics) {
        if self.client.is_none()
            && let Ok((stream, _)) = self.listener.accept()
        {
            let _ = stream.set_nodelay(true);
            if stream.set_nonblocking(true).is_ok() {
                self.counters.connections += 1;
                self.client = Some(HandClientConn {
                    stream,
                    framer: hand_framer(),
                    udp_target: None,
                });
            }
        }
        if let Some(c) = &mut self.client {
            if read_available(&mut c.stream, &mut c.framer) {
                while let Some(c) = &mut self.client {
                    match c
                        .framer
                        .next_message()
                        .map(|m| m.map(|m| HandRequest::decode(&m)))
                    {
                        Ok(None) => break,
                        Ok(Some(Ok((id, request)))) => self.handle(id, request, hand),
                        Ok(Some(Err(_))) | Err(_) => {
                            self.counters.protocol_errors += 1;
                            self.client = None;
                            break;
                        }
                    }
                }
            } else {
                self.client = None;
                hand.stop();
                self.pending = None;
            }
        }
        if let Some(success) = hand.step(DT)
            && let Some((id, command)) = self.pending.take()
        {
            let status = if success {
                HandStatus::Success
            } else {
                HandStatus::Unsuccessful
            };
            self.respond(id, command, status, None);
        }
        self.time_ms += 1;
        if self
            .time_ms
            .is_multiple_of(u64::from(self.config.state_every_ms.max(1)))
            && let Some(target) = self.client.as_ref().and_then(|c| c.udp_target)
        {
            self.message_id = self.message_id.wrapping_add(1);
            let (width, is_grasped) = hand.state();
            let state = GripperState {
                message_id: self.message_id,
                width,
                max_width: self.config.max_width,
                is_grasped,
                temperature: 30,
            };
            if self.udp.send_to(&state.encode(), target).is_ok() {
                self.counters.states_sent += 1;
            }
        }
    }
}

/// Runs `cycle` every millisecond (deadline-scheduled; a late cycle is not repeated) while
/// it returns true.
pub fn run_every_ms(mut cycle: impl FnMut() -> bool) {
    let period = std::time::Duration::from_millis(1);
    let mut next = std::time::Instant::now();
    while cycle() {
        next += period;
        let now = std::time::Instant::now();
        if next > now {
            std::thread::sleep(next - now);
            let late = next.elapsed();
            if late > std::time::Duration::from_millis(20) {
                eprintln!("fake robot: woke {:.1} ms late", late.as_secs_f64() * 1e3);
            }
        } else {
            next = now;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ideal_hand_grasps_an_object_in_the_window_only() {
        let mut h = IdealHand::new(0.08, Some(0.03));
        let grasp = |w: f64| HandAction::Grasp {
            width: w,
            epsilon_inner: 0.005,
            epsilon_outer: 0.005,
            speed: 0.1,
        };
        h.start(grasp(0.03));
        let mut done = None;
        for _ in 0..2000 {
            if let Some(d) = h.step(1e-3) {
                done = Some(d);
                break;
            }
        }
        assert_eq!(done, Some(true));
        assert_eq!(h.state(), (0.03, true));
        h.start(HandAction::Move {
            width: 0.08,
            speed: 0.1,
        });
        while h.step(1e-3).is_none() {}
        h.start(grasp(0.05));
        let mut r = None;
        while r.is_none() {
            r = h.step(1e-3);
        }
        assert_eq!(r, Some(false), "the object is outside the window");
    }
}
