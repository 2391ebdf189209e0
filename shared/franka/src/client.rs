//! The FCI client: a state machine over one TCP connection (requests and responses) and one
//! UDP socket (the 1 kHz state/command exchange). The robot is the clock: the caller blocks in
//! [`FciClient::next_state`] until a state arrives, then answers it with at most one
//! [`FciClient::command`], which echoes the state's `message_id`.
//!
//! Motion lifecycle (joint velocity, as libfranka 0.9.2 runs it):
//! [`FciClient::start_motion`] sends Move (controller JointImpedance, generator JointVelocity,
//! deviations `{10.0, 3.12, 2π}`); the motion is [`Motion::Starting`] until the Move response
//! `MotionStarted` has arrived *and* a state shows generator 2 / controller 0 / robot mode 2, and
//! no command is sent meanwhile. [`Motion::Running`]: every command goes through the
//! [`RateLimiter`]. [`FciClient::finish`] ramps to zero within the limits
//! ([`Motion::Stopping`]), then repeats the last command with `motion_generation_finished` until
//! the robot is idle ([`Motion::Finishing`]), then reads the final Move response. A reflex, a
//! mode change or any non-success Move response ends the motion with a [`MotionEnd`] that says
//! why; a bad datagram or a non-finite command starts the same safe ramp-and-finish. Automatic
//! error recovery is only ever sent by [`FciClient::request_error_recovery`].

use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream, UdpSocket};
use std::time::Duration;

use crate::fci::{
    FCI_PORT, FCI_VERSION, Framer, MoveRequest, MoveStatus, RecoveryStatus, Request, Response,
    StopMoveStatus,
};
use crate::rate_limit::{RateLimitConfig, RateLimiter};
use crate::state::{COMMUNICATION_CONSTRAINTS_VIOLATION, RobotCommand, RobotState};
use crate::wire::ProtocolError;

/// Settings of an [`FciClient`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FciConfig {
    /// The robot's TCP port (1337; tests use another).
    pub port: u16,
    /// Longest wait for the TCP connection and the Connect response.
    pub connect_timeout: Duration,
    /// No valid state for this long means the connection is lost (the robot streams every
    /// 1 ms; 100 ms is 100 lost states).
    pub state_timeout: Duration,
    /// Most states to wait, after Move, for the motion to show running (or, after the finish,
    /// for the final Move response) before the motion is declared aborted.
    pub transition_states: u32,
    /// The low-pass filter and rate limiter.
    pub rate_limit: RateLimitConfig,
    /// While stopping, |dq_d| and |dq_c| below this (rad/s) on every joint lets the finish
    /// begin.
    pub finish_velocity: f64,
}

impl Default for FciConfig {
    fn default() -> Self {
        Self {
            port: FCI_PORT,
            connect_timeout: Duration::from_secs(5),
            state_timeout: Duration::from_millis(100),
            transition_states: 1000,
            rate_limit: RateLimitConfig::default(),
            finish_velocity: 1e-3,
        }
    }
}

/// A fatal client error: the connection cannot go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FciError {
    /// A socket operation failed.
    #[error("FCI {context}: {detail}")]
    Io {
        /// What was being done.
        context: &'static str,
        /// The OS error.
        detail: String,
    },
    /// The TCP stream carried bytes that do not decode, or Connect was refused.
    #[error("FCI protocol: {0}")]
    Protocol(#[from] ProtocolError),
    /// The robot closed the TCP connection or stopped streaming states.
    #[error("FCI connection lost: {0}")]
    ConnectionLost(String),
    /// The call is not possible in the current motion state.
    #[error("FCI: {0}")]
    NotPossible(&'static str),
}

fn io(context: &'static str) -> impl Fn(std::io::Error) -> FciError {
    move |e| FciError::Io {
        context,
        detail: e.to_string(),
    }
}

/// Where the motion is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Motion {
    /// No motion: states are read, no command is sent.
    Idle,
    /// Move sent; waiting for `MotionStarted` and for the state to show the motion running.
    Starting {
        /// The Move's request id.
        command_id: u32,
        /// Whether `MotionStarted` arrived.
        started: bool,
        /// States seen since the Move.
        waited: u32,
    },
    /// Running: one command per state.
    Running {
        /// The Move's request id.
        command_id: u32,
    },
    /// Ramping to zero within the limits before finishing (the safe stop).
    Stopping {
        /// The Move's request id.
        command_id: u32,
    },
    /// Sending `motion_generation_finished` until the robot is idle.
    Finishing {
        /// The Move's request id.
        command_id: u32,
    },
    /// The robot left the motion (or is idle after the finish): waiting for the Move response.
    AwaitingResponse {
        /// The Move's request id.
        command_id: u32,
        /// States seen since.
        waited: u32,
    },
    /// StopMove sent: waiting for its response and for the robot to be idle.
    Cancelling {
        /// The Move's request id.
        command_id: u32,
        /// The StopMove's request id.
        stop_id: u32,
        /// Whether the StopMove response arrived.
        answered: bool,
    },
}

/// Why the client started a safe stop of its own.
#[derive(Debug, Clone, PartialEq)]
pub enum SafeStopCause {
    /// The caller asked to finish.
    Requested,
    /// A datagram that does not decode arrived.
    BadDatagram(ProtocolError),
    /// The caller passed a non-finite velocity.
    NonFiniteCommand,
}

/// How a motion ended.
#[derive(Debug, Clone, PartialEq)]
pub enum MotionEnd {
    /// Finished by the client (final Move response `Success`), with the cause of the finish.
    Finished(SafeStopCause),
    /// A reflex stopped it: the reflex reasons (error indices) and the Move response status if
    /// one came.
    Reflex {
        /// Indices of `reflex_reason` (or `errors`) set.
        reasons: Vec<usize>,
        /// The final Move response.
        status: Option<MoveStatus>,
    },
    /// The robot rejected the Move.
    Rejected(MoveStatus),
    /// The robot aborted it (any other non-success Move response, or none in time).
    Aborted(Option<MoveStatus>),
    /// Cancelled by StopMove, with its status.
    Cancelled(StopMoveStatus),
}

impl MotionEnd {
    /// Whether the robot stopped on `communication_constraints_violation`.
    pub fn communication_constraints_violation(&self) -> bool {
        matches!(self, Self::Reflex { reasons, .. } if reasons.contains(&COMMUNICATION_CONSTRAINTS_VIOLATION))
    }

    /// A one-line description for status output.
    pub fn describe(&self) -> String {
        match self {
            Self::Finished(SafeStopCause::Requested) => "finished".into(),
            Self::Finished(cause) => format!("safe stop: {cause:?}"),
            Self::Reflex { reasons, status } => {
                let ccv = if reasons.contains(&COMMUNICATION_CONSTRAINTS_VIOLATION) {
                    " (communication_constraints_violation)"
                } else {
                    ""
                };
                format!("reflex, reasons {reasons:?}{ccv}, Move response {status:?}")
            }
            Self::Rejected(s) => format!("Move rejected: {s:?}"),
            Self::Aborted(s) => format!("motion aborted: {s:?}"),
            Self::Cancelled(s) => format!("cancelled (StopMove {s:?})"),
        }
    }
}

/// Counters of an [`FciClient`] since it connected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FciCounters {
    /// Valid states received.
    pub states: u64,
    /// States lost (gaps in `message_id`).
    pub lost_states: u64,
    /// States skipped because a newer one was already queued.
    pub skipped_states: u64,
    /// Datagrams that did not decode (wrong size) or came from another address.
    pub bad_datagrams: u64,
    /// Commands sent.
    pub commands_sent: u64,
    /// Non-finite velocities passed to [`FciClient::command`] (never sent).
    pub non_finite_commands: u64,
    /// TCP responses that matched no pending request.
    pub unexpected_responses: u64,
    /// Motions started (Move sent).
    pub motions: u64,
    /// Motions that ended in a reflex.
    pub reflexes: u64,
    /// Safe stops the client started (bad input, or requested).
    pub safe_stops: u64,
}

/// The FCI client. See the module documentation.
pub struct FciClient {
    config: FciConfig,
    tcp: TcpStream,
    udp: UdpSocket,
    robot: SocketAddr,
    framer: Framer,
    next_id: u32,
    limiter: RateLimiter,
    state: RobotState,
    has_state: bool,
    answered: bool,
    motion: Motion,
    cause: SafeStopCause,
    last_sent: [f64; 7],
    last_end: Option<MotionEnd>,
    last_error: Option<ProtocolError>,
    recovery: Option<RecoveryStatus>,
    recovery_id: Option<u32>,
    counters: FciCounters,
    recv_buffer: Box<[u8; 4096]>,
    send_buffer: [u8; RobotCommand::SIZE],
    received_at: Option<std::time::Instant>,
}

impl FciClient {
    /// Connects to the robot at `ip` (TCP `config.port`), binds the UDP socket on port 0 of
    /// the same local address and sends Connect (version 5). A refused version is
    /// [`ProtocolError::IncompatibleVersion`].
    pub fn connect(ip: IpAddr, config: FciConfig) -> Result<Self, FciError> {
        let limiter = RateLimiter::new(config.rate_limit).map_err(|e| FciError::Io {
            context: "config",
            detail: e,
        })?;
        let addr = SocketAddr::new(ip, config.port);
        let mut tcp =
            TcpStream::connect_timeout(&addr, config.connect_timeout).map_err(io("TCP connect"))?;
        tcp.set_nodelay(true).map_err(io("TCP setup"))?;
        let local = tcp.local_addr().map_err(io("TCP setup"))?;
        let udp = UdpSocket::bind(SocketAddr::new(local.ip(), 0)).map_err(io("UDP bind"))?;
        udp.set_read_timeout(Some(config.state_timeout))
            .map_err(io("UDP setup"))?;
        let udp_port = udp.local_addr().map_err(io("UDP setup"))?.port();
        tcp.write_all(
            &Request::Connect {
                version: FCI_VERSION,
                udp_port,
            }
            .encode(0),
        )
        .map_err(io("Connect"))?;
        tcp.set_read_timeout(Some(config.connect_timeout))
            .map_err(io("TCP setup"))?;
        let mut framer = Framer::fci();
        let (_, response) = loop {
            if let Some(m) = framer.next_message()? {
                break Response::decode(&m)?;
            }
            let mut buf = [0u8; 64];
            let n = tcp.read(&mut buf).map_err(io("Connect response"))?;
            if n == 0 {
                return Err(FciError::ConnectionLost(
                    "closed before the Connect response".into(),
                ));
            }
            framer.push(&buf[..n]);
        };
        match response {
            Response::Connect {
                status: crate::fci::ConnectStatus::Success,
                ..
            } => {}
            Response::Connect { version, .. } => {
                return Err(ProtocolError::IncompatibleVersion {
                    message: "Connect response",
                    ours: FCI_VERSION,
                    theirs: version,
                }
                .into());
            }
            other => {
                return Err(ProtocolError::UnexpectedCommand {
                    message: "Connect response",
                    expected: 0,
                    got: other.command() as u32,
                }
                .into());
            }
        }
        tcp.set_nonblocking(true).map_err(io("TCP setup"))?;
        Ok(Self {
            config,
            tcp,
            udp,
            robot: SocketAddr::new(ip, 0),
            framer,
            next_id: 1,
            limiter,
            state: RobotState::default(),
            has_state: false,
            answered: true,
            motion: Motion::Idle,
            cause: SafeStopCause::Requested,
            last_sent: [0.0; 7],
            last_end: None,
            last_error: None,
            recovery: None,
            recovery_id: None,
            counters: FciCounters::default(),
            recv_buffer: Box::new([0u8; 4096]),
            send_buffer: [0u8; RobotCommand::SIZE],
            received_at: None,
        })
    }

    /// The newest state (all zeros before the first).
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// Whether a state has arrived.
    pub fn has_state(&self) -> bool {
        self.has_state
    }

    /// The measured joint positions and velocities (the robot's `q`, `dq`).
    pub fn joints(&self) -> ([f64; 7], [f64; 7]) {
        (self.state.q, self.state.dq)
    }

    /// Where the motion is.
    pub fn motion(&self) -> Motion {
        self.motion
    }

    /// Whether a motion is running and takes the caller's commands.
    pub fn running(&self) -> bool {
        matches!(self.motion, Motion::Running { .. })
    }

    /// How the last motion ended.
    pub fn last_end(&self) -> Option<&MotionEnd> {
        self.last_end.as_ref()
    }

    /// The last decoding error of a datagram or response.
    pub fn last_error(&self) -> Option<&ProtocolError> {
        self.last_error.as_ref()
    }

    /// The counters.
    pub fn counters(&self) -> FciCounters {
        self.counters
    }

    /// The answer to the last error recovery request, once it came.
    pub fn recovery(&self) -> Option<RecoveryStatus> {
        self.recovery
    }

    /// When the newest state's datagram was read from the socket (the start of the cycle's
    /// latency budget).
    pub fn state_received_at(&self) -> Option<std::time::Instant> {
        self.received_at
    }

    /// The client's UDP port.
    pub fn udp_port(&self) -> u16 {
        self.udp.local_addr().map(|a| a.port()).unwrap_or(0)
    }

    fn send_request(&mut self, request: Request) -> Result<u32, FciError> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let bytes = request.encode(id);
        // Requests are small: a non-blocking socket takes them whole unless the peer is gone.
        let mut at = 0;
        let mut spins = 0;
        while at < bytes.len() {
            match self.tcp.write(&bytes[at..]) {
                Ok(0) => return Err(FciError::ConnectionLost("TCP write returned 0".into())),
                Ok(n) => at += n,
                Err(e) if e.kind() == ErrorKind::WouldBlock && spins < 1000 => {
                    spins += 1;
                    std::thread::sleep(Duration::from_micros(10));
                }
                Err(e) => return Err(io("TCP write")(e)),
            }
        }
        Ok(id)
    }

    /// Starts a joint-velocity motion (sends Move). Only from [`Motion::Idle`] with the robot
    /// idle.
    pub fn start_motion(&mut self) -> Result<(), FciError> {
        if self.motion != Motion::Idle {
            return Err(FciError::NotPossible("a motion is already under way"));
        }
        if !self.state.idle() {
            return Err(FciError::NotPossible(
                "the robot is not idle (reflex or user stop?)",
            ));
        }
        let command_id = self.send_request(Request::Move(MoveRequest::joint_velocity()))?;
        self.counters.motions += 1;
        self.motion = Motion::Starting {
            command_id,
            started: false,
            waited: 0,
        };
        Ok(())
    }

    /// Finishes the running motion: a ramp to zero within the limits, then the finish.
    pub fn finish(&mut self) {
        self.safe_stop(SafeStopCause::Requested);
    }

    fn safe_stop(&mut self, cause: SafeStopCause) {
        if let Motion::Running { command_id } = self.motion {
            self.counters.safe_stops += 1;
            self.cause = cause;
            self.motion = Motion::Stopping { command_id };
        }
    }

    /// Cancels the motion with StopMove (the robot stops it itself).
    pub fn cancel(&mut self) -> Result<(), FciError> {
        let command_id = match self.motion {
            Motion::Running { command_id }
            | Motion::Stopping { command_id }
            | Motion::Finishing { command_id }
            | Motion::Starting { command_id, .. } => command_id,
            _ => return Err(FciError::NotPossible("no motion to cancel")),
        };
        let stop_id = self.send_request(Request::StopMove)?;
        self.motion = Motion::Cancelling {
            command_id,
            stop_id,
            answered: false,
        };
        Ok(())
    }

    /// Sends AutomaticErrorRecovery (an explicit user action: the client never sends it on
    /// its own). The answer shows in [`FciClient::recovery`].
    pub fn request_error_recovery(&mut self) -> Result<(), FciError> {
        if self.motion != Motion::Idle {
            return Err(FciError::NotPossible("a motion is under way"));
        }
        self.recovery = None;
        self.recovery_id = Some(self.send_request(Request::AutomaticErrorRecovery)?);
        Ok(())
    }

    fn end(&mut self, end: MotionEnd) -> Option<MotionEnd> {
        if matches!(end, MotionEnd::Reflex { .. }) {
            self.counters.reflexes += 1;
        }
        self.motion = Motion::Idle;
        self.last_end = Some(end.clone());
        Some(end)
    }

    fn reflex_reasons(&self) -> Vec<usize> {
        let reasons: Vec<usize> = self
            .state
            .reflex_reason
            .iter()
            .enumerate()
            .filter_map(|(i, &r)| r.then_some(i))
            .collect();
        if reasons.is_empty() {
            self.state.active_errors().collect()
        } else {
            reasons
        }
    }

    /// Blocks until the next valid state arrives (keeping the newest if several are queued),
    /// reads any TCP responses and advances the motion. Returns how a motion ended, when one
    /// did. A wrong-size datagram is counted, kept in [`FciClient::last_error`] and starts a
    /// safe stop; it is never answered. No state for `state_timeout`, or a closed or corrupt
    /// TCP stream, is a fatal [`FciError`].
    pub fn next_state(&mut self) -> Result<Option<MotionEnd>, FciError> {
        self.receive_state()?;
        let mut ended = self.poll_tcp()?;
        if ended.is_none() {
            ended = self.advance();
        }
        Ok(ended)
    }

    fn receive_state(&mut self) -> Result<(), FciError> {
        let mut got = false;
        let mut blocking = true;
        loop {
            let r = self.udp.recv_from(&mut self.recv_buffer[..]);
            match r {
                Ok((n, from)) => {
                    let at = std::time::Instant::now();
                    if self.robot.port() != 0 && from != self.robot {
                        self.counters.bad_datagrams += 1;
                        continue;
                    }
                    match RobotState::decode(&self.recv_buffer[..n]) {
                        Ok(state) => {
                            if self.has_state && state.message_id <= self.state.message_id {
                                self.counters.skipped_states += 1;
                                continue;
                            }
                            if self.has_state {
                                self.counters.lost_states +=
                                    state.message_id - self.state.message_id - 1;
                            }
                            if got {
                                self.counters.skipped_states += 1;
                            }
                            self.robot = from;
                            self.received_at = Some(at);
                            self.state = state;
                            self.has_state = true;
                            self.counters.states += 1;
                            got = true;
                        }
                        Err(e) => {
                            self.counters.bad_datagrams += 1;
                            self.last_error = Some(e.clone());
                            self.safe_stop(SafeStopCause::BadDatagram(e));
                        }
                    }
                    if got && blocking {
                        // Drain what else is queued: the newest state wins.
                        self.udp.set_nonblocking(true).map_err(io("UDP setup"))?;
                        blocking = false;
                    }
                }
                Err(e) if !blocking && e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    return Err(FciError::ConnectionLost(format!(
                        "no RobotState for {:?}",
                        self.config.state_timeout
                    )));
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => {
                    if !blocking {
                        self.udp.set_nonblocking(false).ok();
                    }
                    return Err(io("UDP receive")(e));
                }
            }
        }
        self.udp.set_nonblocking(false).map_err(io("UDP setup"))?;
        self.answered = false;
        Ok(())
    }

    fn poll_tcp(&mut self) -> Result<Option<MotionEnd>, FciError> {
        let mut buf = [0u8; 256];
        loop {
            match self.tcp.read(&mut buf) {
                Ok(0) => {
                    self.motion = Motion::Idle;
                    return Err(FciError::ConnectionLost("the robot closed TCP".into()));
                }
                Ok(n) => self.framer.push(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(io("TCP read")(e)),
            }
        }
        let mut ended = None;
        while let Some(message) = self.framer.next_message()? {
            let (id, response) = match Response::decode(&message) {
                Ok(r) => r,
                Err(e) => {
                    self.last_error = Some(e.clone());
                    return Err(e.into());
                }
            };
            if let Some(end) = self.on_response(id, response) {
                ended = Some(end);
            }
        }
        Ok(ended)
    }

    fn on_response(&mut self, id: u32, response: Response) -> Option<MotionEnd> {
        let move_id = match self.motion {
            Motion::Starting { command_id, .. }
            | Motion::Running { command_id }
            | Motion::Stopping { command_id }
            | Motion::Finishing { command_id }
            | Motion::AwaitingResponse { command_id, .. }
            | Motion::Cancelling { command_id, .. } => Some(command_id),
            Motion::Idle => None,
        };
        match response {
            Response::Move(status) if Some(id) == move_id => match (self.motion, status) {
                (
                    Motion::Starting {
                        command_id, waited, ..
                    },
                    MoveStatus::MotionStarted,
                ) => {
                    self.motion = Motion::Starting {
                        command_id,
                        started: true,
                        waited,
                    };
                    None
                }
                (Motion::Cancelling { .. }, _) => None,
                (_, MoveStatus::Success) => {
                    let cause = self.cause.clone();
                    self.end(MotionEnd::Finished(cause))
                }
                (_, MoveStatus::ReflexAborted) => {
                    let reasons = self.reflex_reasons();
                    self.end(MotionEnd::Reflex {
                        reasons,
                        status: Some(status),
                    })
                }
                (
                    Motion::Starting { .. },
                    s @ (MoveStatus::CommandNotPossibleRejected
                    | MoveStatus::StartAtSingularPoseRejected
                    | MoveStatus::InvalidArgumentRejected),
                ) => self.end(MotionEnd::Rejected(s)),
                (_, s) => self.end(MotionEnd::Aborted(Some(s))),
            },
            Response::StopMove(status) => match self.motion {
                Motion::Cancelling {
                    command_id,
                    stop_id,
                    ..
                } if stop_id == id => {
                    if status == StopMoveStatus::Success {
                        self.motion = Motion::Cancelling {
                            command_id,
                            stop_id,
                            answered: true,
                        };
                        None
                    } else {
                        self.end(MotionEnd::Cancelled(status))
                    }
                }
                _ => {
                    self.counters.unexpected_responses += 1;
                    None
                }
            },
            Response::AutomaticErrorRecovery(status) if Some(id) == self.recovery_id => {
                self.recovery = Some(status);
                self.recovery_id = None;
                None
            }
            _ => {
                self.counters.unexpected_responses += 1;
                None
            }
        }
    }

    fn advance(&mut self) -> Option<MotionEnd> {
        let s = &self.state;
        match self.motion {
            Motion::Starting {
                command_id,
                started,
                waited,
            } => {
                if started && s.joint_velocity_motion_running() {
                    self.motion = Motion::Running { command_id };
                } else if started && s.in_reflex() {
                    self.motion = Motion::AwaitingResponse {
                        command_id,
                        waited: 0,
                    };
                } else if waited >= self.config.transition_states {
                    return self.end(MotionEnd::Aborted(None));
                } else {
                    self.motion = Motion::Starting {
                        command_id,
                        started,
                        waited: waited + 1,
                    };
                }
                None
            }
            Motion::Running { command_id }
            | Motion::Stopping { command_id }
            | Motion::Finishing { command_id }
                if !s.joint_velocity_motion_running() =>
            {
                // The robot left the motion: a reflex, an abort or (finishing) the end.
                self.motion = Motion::AwaitingResponse {
                    command_id,
                    waited: 0,
                };
                None
            }
            Motion::AwaitingResponse { command_id, waited } => {
                if waited >= self.config.transition_states {
                    if s.in_reflex() {
                        let reasons = self.reflex_reasons();
                        return self.end(MotionEnd::Reflex {
                            reasons,
                            status: None,
                        });
                    }
                    return self.end(MotionEnd::Aborted(None));
                }
                self.motion = Motion::AwaitingResponse {
                    command_id,
                    waited: waited + 1,
                };
                None
            }
            Motion::Cancelling { answered: true, .. } if s.idle() => {
                self.end(MotionEnd::Cancelled(StopMoveStatus::Success))
            }
            _ => None,
        }
    }

    /// Answers the newest state with joint velocity `dq` (rad/s), once per state. Running:
    /// `dq` goes through the rate limiter and out. Stopping: `dq` is ignored and the ramp to
    /// zero goes out. Finishing: the last command goes out again with
    /// `motion_generation_finished`. Otherwise nothing is sent. Returns the velocity sent, if
    /// any. A non-finite `dq` is never sent: it is counted and starts the safe stop.
    pub fn command(&mut self, dq: &[f64; 7]) -> Result<Option<[f64; 7]>, FciError> {
        if self.answered {
            return Ok(None);
        }
        let (target, finished) = match self.motion {
            Motion::Running { .. } if dq.iter().all(|v| v.is_finite()) => (*dq, false),
            Motion::Running { .. } => {
                self.counters.non_finite_commands += 1;
                self.last_error = Some(ProtocolError::NotFinite {
                    message: "RobotCommand",
                    field: "dq_c",
                });
                self.safe_stop(SafeStopCause::NonFiniteCommand);
                ([0.0; 7], false)
            }
            Motion::Stopping { .. } => ([0.0; 7], false),
            Motion::Finishing { .. } => (self.last_sent, true),
            _ => return Ok(None),
        };
        let dq_c = if finished {
            target
        } else {
            match self
                .limiter
                .limit(&target, &self.state.dq_d, &self.state.ddq_d)
            {
                Ok(v) => v,
                Err(e) => {
                    // The robot's own dq_d/ddq_d were not finite: send nothing; the robot
                    // stops on its own.
                    self.last_error = Some(e.clone());
                    return Err(e.into());
                }
            }
        };
        if let Motion::Stopping { command_id } = self.motion {
            let v = self.config.finish_velocity;
            if dq_c
                .iter()
                .chain(self.state.dq_d.iter())
                .all(|x| x.abs() < v)
            {
                self.motion = Motion::Finishing { command_id };
            }
        }
        let finished = finished || matches!(self.motion, Motion::Finishing { .. });
        RobotCommand::joint_velocity(self.state.message_id, dq_c, finished)
            .encode_into(&mut self.send_buffer);
        self.udp
            .send_to(&self.send_buffer, self.robot)
            .map_err(io("UDP send"))?;
        self.answered = true;
        self.last_sent = dq_c;
        self.counters.commands_sent += 1;
        Ok(Some(dq_c))
    }
}
