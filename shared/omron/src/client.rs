//! The ArNetworking client on TCP (port 7272 on an LD-60): the handshake, the data map, and
//! the three named data the base driver uses.
//!
//! Handshake: the server sends INTRODUCTION; the client answers INTRODUCTION (user,
//! `md5(serverKey + passwordKey + password)`, protocol version, type 0) and TCP_ONLY; the
//! server sends CONNECTED (or REJECTED), then LIST, LISTARGRET and LISTGROUPANDFLAGS. The
//! client maps `ratioDrive`, `stop` and `updateNumbers` to their numbers through LIST and
//! requests `updateNumbers` every [`ClientConfig::update_interval_ms`].
//!
//! Every bad input is a typed [`ClientError`] and a count in [`ClientCounters`]: a bad
//! checksum skips that packet, bad framing drops bytes up to the next sync, a command number
//! that is neither fixed nor in LIST is reported and dropped, a dropped connection is
//! [`ClientError::Closed`]. None of them is ever turned into a command; what the caller does
//! (the driver stops the base) is its choice.

use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use thiserror::Error;

use crate::packet::{Packet, PacketError, PayloadReader, SYNC};
use crate::protocol::{
    ClientIntroduction, DataMap, RatioDrive, RejectReason, ServerIntroduction, UpdateNumbers,
    client, decode_list, is_fixed_server_command, password_hash, request_packet, server,
};

/// Name of the drive data.
pub const RATIO_DRIVE: &str = "ratioDrive";
/// Name of the stop data.
pub const STOP: &str = "stop";
/// Name of the odometry data.
pub const UPDATE_NUMBERS: &str = "updateNumbers";

/// Connection settings (config values: an LD-60's user and password are set on the robot).
#[derive(Debug, Clone, PartialEq)]
pub struct ClientConfig {
    /// User name.
    pub user: String,
    /// Password.
    pub password: String,
    /// The server key both sides are configured with (ARIA's default: empty).
    pub server_key: String,
    /// Protocol version sent (QUT's driver: `"5MTX"`).
    pub protocol_version: String,
    /// Longest wait for the TCP connection and for each handshake packet.
    pub timeout: Duration,
    /// `updateNumbers` request interval, ms (the server may broadcast at its own rate).
    pub update_interval_ms: i32,
}

impl Default for ClientConfig {
    fn default() -> Self {
        Self {
            user: "guest".into(),
            password: String::new(),
            server_key: String::new(),
            protocol_version: "5MTX".into(),
            timeout: Duration::from_secs(2),
            update_interval_ms: 100,
        }
    }
}

/// What went wrong on an ArNetworking connection.
#[derive(Debug, Error)]
pub enum ClientError {
    /// A socket error.
    #[error("socket: {0}")]
    Io(#[from] io::Error),
    /// A bad packet (checksum, framing, payload).
    #[error("bad packet: {0}")]
    Packet(#[from] PacketError),
    /// The server closed the connection.
    #[error("the server closed the connection")]
    Closed,
    /// The server rejected the client.
    #[error("rejected by the server ({reason:?}): {text}")]
    Rejected {
        /// Why.
        reason: RejectReason,
        /// The server's text.
        text: String,
    },
    /// The handshake did not complete.
    #[error("handshake: {0}")]
    Handshake(String),
    /// The server does not offer a data this client needs.
    #[error("the server offers no '{0}' data")]
    MissingData(&'static str),
    /// A packet whose command is neither a fixed command nor in the server's LIST.
    #[error("unknown command number {0}")]
    UnknownCommand(u16),
}

/// Counts of what the client sent and received.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClientCounters {
    /// Good packets received.
    pub packets_received: u64,
    /// Packets or bytes dropped as bad (checksum, framing, payload).
    pub bad_packets: u64,
    /// Packets with an unknown command number.
    pub unknown_commands: u64,
    /// `updateNumbers` decoded.
    pub odometry_updates: u64,
    /// `ratioDrive` packets sent.
    pub ratio_drives_sent: u64,
    /// `stop` packets sent.
    pub stops_sent: u64,
}

/// Something the server sent.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// An `updateNumbers` reply or broadcast.
    Numbers(UpdateNumbers),
    /// The server shuts down (SHUTDOWN).
    Shutdown,
    /// Another known packet (a fixed command or named data this client does not decode).
    Other(Packet),
}

/// The numbers of the data the driver uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Numbers {
    ratio_drive: u16,
    stop: u16,
    update_numbers: u16,
}

/// A connected, handshaken ArNetworking client.
#[derive(Debug)]
pub struct ArClient {
    stream: TcpStream,
    rx: Vec<u8>,
    nonblocking: bool,
    closed: bool,
    intro: ServerIntroduction,
    map: DataMap,
    numbers: Numbers,
    counters: ClientCounters,
}

impl ArClient {
    /// Connects to `addr`, runs the handshake and requests `updateNumbers`.
    pub fn connect(addr: impl ToSocketAddrs, config: &ClientConfig) -> Result<Self, ClientError> {
        let mut last = None;
        let mut stream = None;
        for a in addr.to_socket_addrs()? {
            match TcpStream::connect_timeout(&a, config.timeout) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = Some(e),
            }
        }
        let stream = match (stream, last) {
            (Some(s), _) => s,
            (None, Some(e)) => return Err(e.into()),
            (None, None) => return Err(ClientError::Handshake("no address to connect to".into())),
        };
        Self::handshake(stream, config)
    }

    /// Runs the handshake on a connected stream.
    pub fn handshake(stream: TcpStream, config: &ClientConfig) -> Result<Self, ClientError> {
        stream.set_nodelay(true)?;
        stream.set_write_timeout(Some(config.timeout))?;
        let mut c = Self {
            stream,
            rx: Vec::with_capacity(4096),
            nonblocking: false,
            closed: false,
            intro: ServerIntroduction {
                greeting: String::new(),
                udp_port: 0,
                auth_key: 0,
                intro_key: 0,
                password_key: String::new(),
                protocol_version: String::new(),
            },
            map: DataMap::default(),
            numbers: Numbers {
                ratio_drive: 0,
                stop: 0,
                update_numbers: 0,
            },
            counters: ClientCounters::default(),
        };
        let deadline = Instant::now() + config.timeout;
        let intro = c.expect_fixed(deadline, "INTRODUCTION")?;
        if intro.command != server::INTRODUCTION {
            return Err(ClientError::Handshake(format!(
                "expected INTRODUCTION, got command {}",
                intro.command
            )));
        }
        c.intro = ServerIntroduction::decode(&intro.payload)?;
        let hello = ClientIntroduction {
            udp_port: 0,
            user: config.user.clone(),
            password_hash: password_hash(
                &config.server_key,
                &c.intro.password_key,
                &config.password,
            ),
            protocol_version: config.protocol_version.clone(),
            client_type: 0,
        };
        c.send(&hello.to_packet())?;
        c.send(&Packet::empty(client::TCP_ONLY))?;
        let (mut connected, mut list, mut argret, mut groups) = (false, None, false, false);
        while !(connected && list.is_some() && argret && groups) {
            let p = c.expect_fixed(deadline, "CONNECTED and the lists")?;
            match p.command {
                server::CONNECTED => connected = true,
                server::REJECTED => {
                    let mut r = PayloadReader::new(&p.payload);
                    let reason = RejectReason::from_code(r.i16("reason")?);
                    let text = r.str("text").unwrap_or_default();
                    return Err(ClientError::Rejected { reason, text });
                }
                server::LIST => list = Some(decode_list(&p.payload)?),
                server::LISTARGRET => {
                    decode_list(&p.payload)?;
                    argret = true;
                }
                server::LISTGROUPANDFLAGS => {
                    decode_list(&p.payload)?;
                    groups = true;
                }
                // UDP_INTRO, TCP_ONLY and the like carry nothing a TCP-only client needs.
                _ => {}
            }
        }
        c.map = DataMap::from_entries(&list.unwrap_or_default());
        let need = |name: &'static str| c.map.number(name).ok_or(ClientError::MissingData(name));
        c.numbers = Numbers {
            ratio_drive: need(RATIO_DRIVE)?,
            stop: need(STOP)?,
            update_numbers: need(UPDATE_NUMBERS)?,
        };
        c.send(&request_packet(
            c.numbers.update_numbers,
            config.update_interval_ms,
        ))?;
        Ok(c)
    }

    /// Reads the next packet before `deadline`; during the handshake only fixed commands are
    /// expected.
    fn expect_fixed(&mut self, deadline: Instant, what: &str) -> Result<Packet, ClientError> {
        loop {
            if let Some(p) = self.next_buffered()? {
                if is_fixed_server_command(p.command) {
                    return Ok(p);
                }
                self.counters.unknown_commands += 1;
                return Err(ClientError::UnknownCommand(p.command));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ClientError::Handshake(format!(
                    "timed out waiting for {what}"
                )));
            }
            self.fill(left)?;
        }
    }

    /// The server's introduction.
    pub fn server_introduction(&self) -> &ServerIntroduction {
        &self.intro
    }

    /// The server's data names and numbers.
    pub fn data_map(&self) -> &DataMap {
        &self.map
    }

    /// Counters.
    pub fn counters(&self) -> ClientCounters {
        self.counters
    }

    /// Sends one packet.
    pub fn send(&mut self, packet: &Packet) -> Result<(), ClientError> {
        let bytes = packet.encode()?;
        self.stream.write_all(&bytes).map_err(|e| self.io_error(e))
    }

    /// Sends `ratioDrive` with `drive`.
    pub fn ratio_drive(&mut self, drive: &RatioDrive) -> Result<(), ClientError> {
        self.send(&Packet::new(self.numbers.ratio_drive, drive.payload()))?;
        self.counters.ratio_drives_sent += 1;
        Ok(())
    }

    /// Sends `stop`.
    pub fn stop(&mut self) -> Result<(), ClientError> {
        self.send(&Packet::empty(self.numbers.stop))?;
        self.counters.stops_sent += 1;
        Ok(())
    }

    /// Tells the server the client leaves (SHUTDOWN).
    pub fn shutdown(&mut self) -> Result<(), ClientError> {
        self.send(&Packet::empty(client::SHUTDOWN))
    }

    /// The next event, waiting at most `timeout` (zero: only what has already arrived).
    /// `Ok(None)`: nothing arrived.
    pub fn poll(&mut self, timeout: Duration) -> Result<Option<Event>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(p) = self.next_buffered()? {
                return self.event(p).map(Some);
            }
            if self.closed {
                return Err(ClientError::Closed);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if !self.fill(left)? {
                return Ok(None);
            }
        }
    }

    /// Classifies a packet.
    fn event(&mut self, p: Packet) -> Result<Event, ClientError> {
        if p.command == self.numbers.update_numbers {
            match UpdateNumbers::decode(&p.payload) {
                Ok(u) => {
                    self.counters.odometry_updates += 1;
                    Ok(Event::Numbers(u))
                }
                Err(e) => {
                    self.counters.bad_packets += 1;
                    Err(e.into())
                }
            }
        } else if p.command == server::SHUTDOWN {
            Ok(Event::Shutdown)
        } else if is_fixed_server_command(p.command) || self.map.name(p.command).is_some() {
            Ok(Event::Other(p))
        } else {
            self.counters.unknown_commands += 1;
            Err(ClientError::UnknownCommand(p.command))
        }
    }

    /// The next whole packet in the receive buffer. A bad one is dropped (a bad checksum: that
    /// packet; bad framing: bytes up to the next sync) and reported.
    fn next_buffered(&mut self) -> Result<Option<Packet>, ClientError> {
        match Packet::decode(&self.rx) {
            Ok(Some((p, used))) => {
                self.rx.drain(..used);
                self.counters.packets_received += 1;
                Ok(Some(p))
            }
            Ok(None) if self.closed && !self.rx.is_empty() => {
                let have = self.rx.len();
                let need = if have >= 4 {
                    usize::from(u16::from_le_bytes([self.rx[2], self.rx[3]]))
                } else {
                    crate::packet::MIN_PACKET_LEN
                };
                self.rx.clear();
                self.counters.bad_packets += 1;
                Err(PacketError::Truncated { have, need }.into())
            }
            Ok(None) => Ok(None),
            Err(e) => {
                self.counters.bad_packets += 1;
                let skip = match e {
                    PacketError::BadChecksum { .. } => {
                        usize::from(u16::from_le_bytes([self.rx[2], self.rx[3]]))
                    }
                    _ => self.rx[1..]
                        .windows(2)
                        .position(|w| w == SYNC)
                        .map_or(self.rx.len(), |p| p + 1),
                };
                self.rx.drain(..skip.min(self.rx.len()));
                Err(e.into())
            }
        }
    }

    /// Reads what arrives within `timeout` into the buffer; `false` if nothing did.
    fn fill(&mut self, timeout: Duration) -> Result<bool, ClientError> {
        let want_nonblocking = timeout.is_zero();
        if want_nonblocking != self.nonblocking {
            self.stream.set_nonblocking(want_nonblocking)?;
            self.nonblocking = want_nonblocking;
        }
        if !want_nonblocking {
            self.stream.set_read_timeout(Some(timeout))?;
        }
        let mut chunk = [0u8; 4096];
        match self.stream.read(&mut chunk) {
            Ok(0) => {
                self.closed = true;
                Ok(!self.rx.is_empty())
            }
            Ok(n) => {
                self.rx.extend_from_slice(&chunk[..n]);
                Ok(true)
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(false)
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(false),
            Err(e) => match self.io_error(e) {
                // A reset connection: what is left in the buffer is reported first.
                ClientError::Closed => Ok(!self.rx.is_empty()),
                other => Err(other),
            },
        }
    }

    /// A socket error; a reset connection is [`ClientError::Closed`].
    fn io_error(&mut self, e: io::Error) -> ClientError {
        match e.kind() {
            io::ErrorKind::ConnectionReset
            | io::ErrorKind::BrokenPipe
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::UnexpectedEof => {
                self.closed = true;
                ClientError::Closed
            }
            _ => ClientError::Io(e),
        }
    }
}
