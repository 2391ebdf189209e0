//! The Franka Hand: its TCP protocol (version 3, port 1338, 10-byte header), its 23-byte UDP
//! [`GripperState`], and a non-blocking [`HandClient`] that a 1 kHz loop can poll.
//!
//! The hand answers an action (Homing, Move, Grasp) only when it completes, which takes up to
//! seconds; the client therefore never blocks after Connect: [`HandClient::request`] sends (or,
//! while an action is pending, queues: the newest queued request wins and goes out when the
//! pending one is answered), and [`HandClient::poll`] reads states and responses.

use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream, UdpSocket};
use std::time::Duration;

use crate::fci::{Framer, code_enum};
use crate::wire::{ProtocolError, Reader, Writer};

/// The hand's TCP port.
pub const HAND_PORT: u16 = 1338;
/// The gripper protocol version this crate speaks.
pub const HAND_VERSION: u16 = 3;
/// Size of the hand's TCP header, bytes.
pub const HAND_HEADER_SIZE: usize = 10;

code_enum!(
    /// Hand command numbers.
    HandCommand: u16, "hand header" {
        /// Connect.
        Connect = 0,
        /// Calibrate the fingers.
        Homing = 1,
        /// Close on an object.
        Grasp = 2,
        /// Move the fingers to a width.
        Move = 3,
        /// Stop the current action.
        Stop = 4,
    }
);

code_enum!(
    /// Hand response status (Connect: 0 Success, 1 IncompatibleLibraryVersion).
    HandStatus: u16, "hand response" {
        /// Done.
        Success = 0,
        /// Failed (Connect: incompatible version).
        Fail = 1,
        /// Done but not as asked (e.g. no object in the grasp window).
        Unsuccessful = 2,
        /// Stopped by a later command.
        Aborted = 3,
    }
);

/// A hand request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HandRequest {
    /// Connect with `version`; the hand streams states to `udp_port`.
    Connect {
        /// Protocol version ([`HAND_VERSION`]).
        version: u16,
        /// The client's UDP port.
        udp_port: u16,
    },
    /// Calibrate.
    Homing,
    /// Close until an object is held; success if `width − ε_in < d < width + ε_out`.
    Grasp {
        /// Expected object width, m.
        width: f64,
        /// Inner tolerance, m.
        epsilon_inner: f64,
        /// Outer tolerance, m.
        epsilon_outer: f64,
        /// Speed, m/s.
        speed: f64,
        /// Force, N.
        force: f64,
    },
    /// Move to `width` (m) at `speed` (m/s).
    Move {
        /// Target width, m.
        width: f64,
        /// Speed, m/s.
        speed: f64,
    },
    /// Stop.
    Stop,
}

fn hand_header(w: &mut Writer, command: HandCommand, command_id: u32, size: usize) {
    w.write(command as u16).write(command_id).write(size as u32);
}

/// Reads a hand header: (command, id, size); checks the size against the bytes.
fn read_hand_header<'a>(
    message: &'static str,
    bytes: &'a [u8],
) -> Result<(HandCommand, u32, Reader<'a>), ProtocolError> {
    let mut r = Reader::new(message, bytes);
    let command = r.read::<u16>("command")?;
    let id = r.read::<u32>("command_id")?;
    let size = r.read::<u32>("size")?;
    let command = HandCommand::from_code(command, "command")?;
    if size as usize != bytes.len() {
        return Err(ProtocolError::WrongSize {
            message,
            expected: size as usize,
            got: bytes.len(),
        });
    }
    Ok((
        command,
        id,
        Reader::new(message, &bytes[HAND_HEADER_SIZE..]),
    ))
}

impl HandRequest {
    /// The command number.
    pub fn command(&self) -> HandCommand {
        match self {
            Self::Connect { .. } => HandCommand::Connect,
            Self::Homing => HandCommand::Homing,
            Self::Grasp { .. } => HandCommand::Grasp,
            Self::Move { .. } => HandCommand::Move,
            Self::Stop => HandCommand::Stop,
        }
    }

    /// Total encoded size: Connect 14, Homing/Stop 10, Move 26, Grasp 50.
    pub fn size(&self) -> usize {
        HAND_HEADER_SIZE
            + match self {
                Self::Connect { .. } => 4,
                Self::Homing | Self::Stop => 0,
                Self::Grasp { .. } => 40,
                Self::Move { .. } => 16,
            }
    }

    /// The encoded message with request id `command_id`.
    pub fn encode(&self, command_id: u32) -> Vec<u8> {
        let mut w = Writer::default();
        hand_header(&mut w, self.command(), command_id, self.size());
        match *self {
            Self::Connect { version, udp_port } => {
                w.write(version).write(udp_port);
            }
            Self::Homing | Self::Stop => {}
            Self::Grasp {
                width,
                epsilon_inner,
                epsilon_outer,
                speed,
                force,
            } => {
                w.write(width)
                    .write(epsilon_inner)
                    .write(epsilon_outer)
                    .write(speed)
                    .write(force);
            }
            Self::Move { width, speed } => {
                w.write(width).write(speed);
            }
        }
        w.bytes
    }

    /// Decodes one whole request; returns its id and the request.
    pub fn decode(bytes: &[u8]) -> Result<(u32, Self), ProtocolError> {
        let (command, id, mut r) = read_hand_header("hand request", bytes)?;
        let request = match command {
            HandCommand::Connect => Self::Connect {
                version: r.read("version")?,
                udp_port: r.read("udp_port")?,
            },
            HandCommand::Homing => Self::Homing,
            HandCommand::Grasp => Self::Grasp {
                width: r.read("width")?,
                epsilon_inner: r.read("epsilon_inner")?,
                epsilon_outer: r.read("epsilon_outer")?,
                speed: r.read("speed")?,
                force: r.read("force")?,
            },
            HandCommand::Move => Self::Move {
                width: r.read("width")?,
                speed: r.read("speed")?,
            },
            HandCommand::Stop => Self::Stop,
        };
        r.finish()?;
        Ok((id, request))
    }
}

/// A hand response.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HandResponse {
    /// Which request it answers.
    pub command: HandCommand,
    /// Status.
    pub status: HandStatus,
    /// The hand's version (Connect only).
    pub version: Option<u16>,
}

impl HandResponse {
    /// The encoded message answering request `command_id` (Connect 14 bytes, others 12).
    pub fn encode(&self, command_id: u32) -> Vec<u8> {
        let mut w = Writer::default();
        let size = HAND_HEADER_SIZE + if self.version.is_some() { 4 } else { 2 };
        hand_header(&mut w, self.command, command_id, size);
        w.write(self.status as u16);
        if let Some(v) = self.version {
            w.write(v);
        }
        w.bytes
    }

    /// Decodes one whole response; returns its id and the response.
    pub fn decode(bytes: &[u8]) -> Result<(u32, Self), ProtocolError> {
        let (command, id, mut r) = read_hand_header("hand response", bytes)?;
        let status = HandStatus::from_code(r.read("status")?, "status")?;
        let version = if command == HandCommand::Connect {
            Some(r.read("version")?)
        } else {
            None
        };
        r.finish()?;
        Ok((
            id,
            Self {
                command,
                status,
                version,
            },
        ))
    }
}

/// The hand's UDP state (23 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GripperState {
    /// Hand time; +1 per state.
    pub message_id: u32,
    /// Finger opening, m.
    pub width: f64,
    /// Opening found by homing, m.
    pub max_width: f64,
    /// Whether an object is held.
    pub is_grasped: bool,
    /// Temperature, °C.
    pub temperature: u16,
}

impl GripperState {
    /// Encoded size, bytes.
    pub const SIZE: usize = 23;

    /// The encoded datagram.
    pub fn encode(&self) -> [u8; 23] {
        let mut w = Writer::default();
        w.write(self.message_id)
            .write(self.width)
            .write(self.max_width)
            .write(self.is_grasped)
            .write(self.temperature);
        w.bytes.try_into().expect("23 bytes")
    }

    /// Decodes one datagram; any other size than 23 is an error.
    pub fn decode(bytes: &[u8]) -> Result<Self, ProtocolError> {
        if bytes.len() != Self::SIZE {
            return Err(ProtocolError::WrongSize {
                message: "GripperState",
                expected: Self::SIZE,
                got: bytes.len(),
            });
        }
        let mut r = Reader::new("GripperState", bytes);
        Ok(Self {
            message_id: r.read("message_id")?,
            width: r.read("width")?,
            max_width: r.read("max_width")?,
            is_grasped: r.read("is_grasped")?,
            temperature: r.read("temperature")?,
        })
    }
}

/// A framer for hand messages (10-byte header, size at 6).
pub fn hand_framer() -> Framer {
    Framer::new("hand message", HAND_HEADER_SIZE, 6)
}

/// Settings of a [`HandClient`], including what the stack's Open and Close become.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandConfig {
    /// The hand's TCP port (1338).
    pub port: u16,
    /// Longest wait for the connection and the Connect response.
    pub connect_timeout: Duration,
    /// Open: Move to this width, m (the Franka Hand opens to 0.08).
    pub open_width: f64,
    /// Speed of Open and Close, m/s.
    pub speed: f64,
    /// Close: Grasp with this expected object width, m (the simulator's cube is 0.03).
    pub grasp_width: f64,
    /// Close: inner tolerance, m.
    pub epsilon_inner: f64,
    /// Close: outer tolerance, m.
    pub epsilon_outer: f64,
    /// Close: grasp force, N.
    pub force: f64,
}

impl Default for HandConfig {
    fn default() -> Self {
        Self {
            port: HAND_PORT,
            connect_timeout: Duration::from_secs(5),
            open_width: 0.08,
            speed: 0.1,
            grasp_width: 0.03,
            epsilon_inner: 0.03,
            epsilon_outer: 0.05,
            force: 20.0,
        }
    }
}

/// A hand client error: the connection cannot go on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HandError {
    /// A socket operation failed.
    #[error("hand {context}: {detail}")]
    Io {
        /// What was being done.
        context: &'static str,
        /// The OS error.
        detail: String,
    },
    /// Bytes that do not decode, or Connect refused.
    #[error("hand protocol: {0}")]
    Protocol(#[from] ProtocolError),
    /// The hand closed the connection.
    #[error("hand connection lost")]
    ConnectionLost,
}

fn hio(context: &'static str) -> impl Fn(std::io::Error) -> HandError {
    move |e| HandError::Io {
        context,
        detail: e.to_string(),
    }
}

/// Counters of a [`HandClient`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HandCounters {
    /// Valid states received.
    pub states: u64,
    /// Datagrams that did not decode.
    pub bad_datagrams: u64,
    /// Requests sent.
    pub requests: u64,
    /// Responses received.
    pub responses: u64,
    /// Queued requests replaced by a newer one before they went out.
    pub superseded: u64,
}

/// The non-blocking hand client. See the module documentation.
pub struct HandClient {
    config: HandConfig,
    tcp: TcpStream,
    udp: UdpSocket,
    framer: Framer,
    next_id: u32,
    pending: Option<(u32, HandCommand)>,
    queued: Option<HandRequest>,
    state: Option<GripperState>,
    last_result: Option<(HandCommand, HandStatus)>,
    last_error: Option<ProtocolError>,
    counters: HandCounters,
}

impl HandClient {
    /// Connects to the hand at `ip` and sends Connect (version 3); blocks until the answer.
    pub fn connect(ip: IpAddr, config: HandConfig) -> Result<Self, HandError> {
        let addr = SocketAddr::new(ip, config.port);
        let mut tcp = TcpStream::connect_timeout(&addr, config.connect_timeout)
            .map_err(hio("TCP connect"))?;
        tcp.set_nodelay(true).map_err(hio("TCP setup"))?;
        let local = tcp.local_addr().map_err(hio("TCP setup"))?;
        let udp = UdpSocket::bind(SocketAddr::new(local.ip(), 0)).map_err(hio("UDP bind"))?;
        udp.set_nonblocking(true).map_err(hio("UDP setup"))?;
        let udp_port = udp.local_addr().map_err(hio("UDP setup"))?.port();
        tcp.write_all(
            &HandRequest::Connect {
                version: HAND_VERSION,
                udp_port,
            }
            .encode(0),
        )
        .map_err(hio("Connect"))?;
        tcp.set_read_timeout(Some(config.connect_timeout))
            .map_err(hio("TCP setup"))?;
        let mut framer = hand_framer();
        let (_, response) = loop {
            if let Some(m) = framer.next_message()? {
                break HandResponse::decode(&m)?;
            }
            let mut buf = [0u8; 64];
            let n = tcp.read(&mut buf).map_err(hio("Connect response"))?;
            if n == 0 {
                return Err(HandError::ConnectionLost);
            }
            framer.push(&buf[..n]);
        };
        if response.command != HandCommand::Connect {
            return Err(ProtocolError::UnexpectedCommand {
                message: "hand Connect response",
                expected: 0,
                got: u32::from(response.command as u16),
            }
            .into());
        }
        if response.status != HandStatus::Success {
            return Err(ProtocolError::IncompatibleVersion {
                message: "hand Connect response",
                ours: HAND_VERSION,
                theirs: response.version.unwrap_or(0),
            }
            .into());
        }
        tcp.set_nonblocking(true).map_err(hio("TCP setup"))?;
        Ok(Self {
            config,
            tcp,
            udp,
            framer,
            next_id: 1,
            pending: None,
            queued: None,
            state: None,
            last_result: None,
            last_error: None,
            counters: HandCounters::default(),
        })
    }

    /// The Move request that opens the hand.
    pub fn open_request(&self) -> HandRequest {
        HandRequest::Move {
            width: self.config.open_width,
            speed: self.config.speed,
        }
    }

    /// The Grasp request that closes the hand.
    pub fn close_request(&self) -> HandRequest {
        HandRequest::Grasp {
            width: self.config.grasp_width,
            epsilon_inner: self.config.epsilon_inner,
            epsilon_outer: self.config.epsilon_outer,
            speed: self.config.speed,
            force: self.config.force,
        }
    }

    /// Sends `request` now, or queues it while an action is pending (Stop always goes out at
    /// once).
    pub fn request(&mut self, request: HandRequest) -> Result<(), HandError> {
        if self.pending.is_some() && request != HandRequest::Stop {
            if self.queued.replace(request).is_some() {
                self.counters.superseded += 1;
            }
            return Ok(());
        }
        self.send(request)
    }

    fn send(&mut self, request: HandRequest) -> Result<(), HandError> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let bytes = request.encode(id);
        let mut at = 0;
        while at < bytes.len() {
            match self.tcp.write(&bytes[at..]) {
                Ok(0) => return Err(HandError::ConnectionLost),
                Ok(n) => at += n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    std::thread::sleep(Duration::from_micros(10));
                }
                Err(e) => return Err(hio("TCP write")(e)),
            }
        }
        self.counters.requests += 1;
        if request != HandRequest::Stop {
            self.pending = Some((id, request.command()));
        }
        Ok(())
    }

    /// Reads what has arrived (never blocks): returns the newest state if one came. Completed
    /// actions show in [`HandClient::last_result`]; a queued request then goes out.
    pub fn poll(&mut self) -> Result<Option<GripperState>, HandError> {
        let mut newest = None;
        let mut buf = [0u8; 64];
        loop {
            match self.udp.recv(&mut buf) {
                Ok(n) => match GripperState::decode(&buf[..n]) {
                    Ok(s) => {
                        self.counters.states += 1;
                        newest = Some(s);
                    }
                    Err(e) => {
                        self.counters.bad_datagrams += 1;
                        self.last_error = Some(e);
                    }
                },
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(hio("UDP receive")(e)),
            }
        }
        if newest.is_some() {
            self.state = newest;
        }
        loop {
            match self.tcp.read(&mut buf) {
                Ok(0) => return Err(HandError::ConnectionLost),
                Ok(n) => self.framer.push(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(hio("TCP read")(e)),
            }
        }
        while let Some(m) = self.framer.next_message()? {
            let (id, response) = HandResponse::decode(&m)?;
            self.counters.responses += 1;
            if self.pending.is_some_and(|(p, _)| p == id) {
                self.pending = None;
                self.last_result = Some((response.command, response.status));
                if let Some(next) = self.queued.take() {
                    self.send(next)?;
                }
            }
        }
        Ok(newest)
    }

    /// The newest state.
    pub fn state(&self) -> Option<GripperState> {
        self.state
    }

    /// The command and status of the last completed action.
    pub fn last_result(&self) -> Option<(HandCommand, HandStatus)> {
        self.last_result
    }

    /// Whether an action is pending.
    pub fn busy(&self) -> bool {
        self.pending.is_some()
    }

    /// The last decoding error of a datagram.
    pub fn last_error(&self) -> Option<&ProtocolError> {
        self.last_error.as_ref()
    }

    /// The counters.
    pub fn counters(&self) -> HandCounters {
        self.counters
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_byte_for_byte() {
        assert_eq!(
            HandRequest::Connect {
                version: 3,
                udp_port: 0x0102
            }
            .encode(0),
            [0, 0, 0, 0, 0, 0, 14, 0, 0, 0, 3, 0, 2, 1]
        );
        assert_eq!(
            HandRequest::Homing.encode(5),
            [1, 0, 5, 0, 0, 0, 10, 0, 0, 0]
        );
        assert_eq!(HandRequest::Stop.encode(6), [4, 0, 6, 0, 0, 0, 10, 0, 0, 0]);
        let m = HandRequest::Move {
            width: 0.08,
            speed: 0.1,
        };
        let mut expected = vec![3, 0, 2, 0, 0, 0, 26, 0, 0, 0];
        expected.extend_from_slice(&0.08f64.to_le_bytes());
        expected.extend_from_slice(&0.1f64.to_le_bytes());
        assert_eq!(m.encode(2), expected);
        let g = HandRequest::Grasp {
            width: 0.03,
            epsilon_inner: 0.005,
            epsilon_outer: 0.006,
            speed: 0.1,
            force: 20.0,
        };
        let b = g.encode(3);
        assert_eq!(b.len(), 50);
        assert_eq!(&b[..10], &[2, 0, 3, 0, 0, 0, 50, 0, 0, 0]);
        assert_eq!(&b[42..50], &20.0f64.to_le_bytes());
        for r in [m, g, HandRequest::Homing, HandRequest::Stop] {
            assert_eq!(HandRequest::decode(&r.encode(9)), Ok((9, r)));
        }
    }

    #[test]
    fn responses_are_byte_for_byte() {
        let c = HandResponse {
            command: HandCommand::Connect,
            status: HandStatus::Success,
            version: Some(3),
        };
        assert_eq!(c.encode(0), [0, 0, 0, 0, 0, 0, 14, 0, 0, 0, 0, 0, 3, 0]);
        assert_eq!(HandResponse::decode(&c.encode(0)), Ok((0, c)));
        let g = HandResponse {
            command: HandCommand::Grasp,
            status: HandStatus::Unsuccessful,
            version: None,
        };
        assert_eq!(g.encode(4), [2, 0, 4, 0, 0, 0, 12, 0, 0, 0, 2, 0]);
        assert_eq!(HandResponse::decode(&g.encode(4)), Ok((4, g)));
    }

    #[test]
    fn the_state_is_23_bytes_byte_for_byte() {
        let s = GripperState {
            message_id: 7,
            width: 0.5,
            max_width: 1.0,
            is_grasped: true,
            temperature: 0x0102,
        };
        let b = s.encode();
        let mut expected = vec![7, 0, 0, 0];
        expected.extend_from_slice(&0.5f64.to_le_bytes());
        expected.extend_from_slice(&1.0f64.to_le_bytes());
        expected.extend_from_slice(&[1, 2, 1]);
        assert_eq!(b.to_vec(), expected);
        assert_eq!(GripperState::decode(&b), Ok(s));
        assert_eq!(
            GripperState::decode(&b[..22]),
            Err(ProtocolError::WrongSize {
                message: "GripperState",
                expected: 23,
                got: 22
            })
        );
    }

    #[test]
    fn bad_hand_messages_are_typed_errors() {
        let mut b = HandRequest::Stop.encode(0);
        b[0] = 9;
        assert_eq!(
            HandRequest::decode(&b),
            Err(ProtocolError::UnknownValue {
                message: "hand header",
                field: "command",
                value: 9
            })
        );
        let b = HandRequest::Move {
            width: 0.0,
            speed: 0.0,
        }
        .encode(0);
        assert!(matches!(
            HandRequest::decode(&b[..20]),
            Err(ProtocolError::WrongSize {
                expected: 26,
                got: 20,
                ..
            })
        ));
        // A header that claims 20 bytes on a 20-byte Move: the width fits, speed does not.
        let mut b = b[..20].to_vec();
        b[6] = 20;
        assert!(matches!(
            HandRequest::decode(&b),
            Err(ProtocolError::Truncated { field: "speed", .. })
        ));
    }
}
