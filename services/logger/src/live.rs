//! The live view: the logger's channels served with the Foxglove WebSocket protocol
//! (subprotocol `foxglove.websocket.v1`), so Foxglove's "Open connection" shows a running stack
//! with the same channels and schemas as the MCAP file.
//!
//! On connect a client gets `serverInfo` and one `advertise` of every channel seen so far; a
//! channel that appears later is advertised to every client then. A client `subscribe`s to
//! channels (`unsubscribe`s by subscription id) and gets each message of them as a binary
//! `messageData` frame: byte `0x01`, the subscription id (u32 LE), the log time (u64 LE, Unix
//! ns, the MCAP log time) and the message bytes.
//!
//! It never blocks the logger loop: the listener and every socket are non-blocking, and
//! [`LiveSink::poll`] only does what the sockets take at once. Memory stays bounded: at most
//! `max_clients` connections (handshakes included; a handshake not done within
//! `handshake_timeout_s` is dropped), client messages of at most `max_client_message_bytes`,
//! and per client a queue of at most `client_queue_bytes` of message frames: when a client
//! reads slower than the stack publishes, its oldest queued messages are dropped (counted in
//! [`LiveStats::dropped_messages`]). Control messages (`serverInfo`, `advertise`) are never
//! dropped; there is one per channel at most. A client that closes or errors is dropped.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::io;
use std::net::{SocketAddr, TcpListener, TcpStream};

use serde::Deserialize;
use serde_json::{Value, json};
use tungstenite::handshake::server::{ErrorResponse, Request, Response, ServerHandshake};
use tungstenite::handshake::{HandshakeError, MidHandshake};
use tungstenite::http::{HeaderValue, StatusCode};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

use crate::channels::{ChannelInfo, EncodedMessage, PROTOBUF};

/// The WebSocket subprotocol of the Foxglove WebSocket protocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";

/// Opcode of a binary `messageData` frame.
pub const MESSAGE_DATA: u8 = 0x01;

/// Bytes of a `messageData` frame before the message: opcode, subscription id, log time.
pub const MESSAGE_DATA_HEADER: usize = 1 + 4 + 8;

/// Server name sent in `serverInfo`.
const SERVER_NAME: &str = "motm-logger";

/// Connections accepted per [`LiveSink::poll`] at most (the rest wait in the listen backlog).
const ACCEPTS_PER_POLL: usize = 8;

/// Client messages read per client per [`LiveSink::poll`] at most, so a flooding client cannot
/// hold the logger loop.
const READS_PER_POLL: usize = 64;

/// Settings of the live view (`[live]` in the logger settings).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveConfig {
    /// Most connections at once, handshakes included; more are refused. 4: a Foxglove window
    /// or two plus a script.
    pub max_clients: usize,
    /// Most bytes of message frames queued for one client; past it the oldest are dropped.
    /// 4 MiB holds about a second of everything at the default rates (the camera dominates).
    pub client_queue_bytes: usize,
    /// Time a connection may take to finish its WebSocket handshake, s.
    pub handshake_timeout_s: f64,
    /// Largest message a client may send (subscribe/unsubscribe are small), bytes.
    pub max_client_message_bytes: usize,
}

impl Default for LiveConfig {
    fn default() -> Self {
        Self {
            max_clients: 4,
            client_queue_bytes: 4 << 20,
            handshake_timeout_s: 5.0,
            max_client_message_bytes: 64 << 10,
        }
    }
}

/// Counters of the live view.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveStats {
    /// Clients connected now (handshake done).
    pub clients: usize,
    /// Connections whose handshake succeeded, ever.
    pub connections: u64,
    /// Connections refused (too many clients, bad handshake, handshake timeout).
    pub refused: u64,
    /// `messageData` frames handed to the sockets.
    pub sent_messages: u64,
    /// `messageData` frames dropped because a client's queue was full.
    pub dropped_messages: u64,
}

/// The handshake callback: answers with the Foxglove subprotocol when the client offers it,
/// refuses a client that offers only other subprotocols.
struct Subprotocol;

impl tungstenite::handshake::server::Callback for Subprotocol {
    fn on_request(
        self,
        request: &Request,
        mut response: Response,
    ) -> Result<Response, ErrorResponse> {
        let offered: Vec<&str> = request
            .headers()
            .get_all("Sec-WebSocket-Protocol")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .map(str::trim)
            .collect();
        if offered.contains(&SUBPROTOCOL) {
            response.headers_mut().insert(
                "Sec-WebSocket-Protocol",
                HeaderValue::from_static(SUBPROTOCOL),
            );
            Ok(response)
        } else if offered.is_empty() {
            Ok(response)
        } else {
            let mut refusal = ErrorResponse::new(Some(format!("subprotocol {SUBPROTOCOL} only")));
            *refusal.status_mut() = StatusCode::BAD_REQUEST;
            Err(refusal)
        }
    }
}

/// A connection whose handshake is not done yet.
struct Pending {
    handshake: MidHandshake<ServerHandshake<TcpStream, Subprotocol>>,
    started_ns: u64,
}

/// A connected client.
struct Client {
    socket: WebSocket<TcpStream>,
    /// Channel id by subscription id.
    subscriptions: HashMap<u32, u16>,
    /// `serverInfo` and `advertise` texts to send, never dropped.
    control: VecDeque<String>,
    /// `messageData` frames to send, oldest first.
    data: VecDeque<Vec<u8>>,
    data_bytes: usize,
}

/// Whether `error` only says the socket cannot go on without blocking.
fn would_block(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e) if e.kind() == io::ErrorKind::WouldBlock)
}

impl Client {
    /// Queues a frame, dropping the oldest queued ones past `limit` bytes; returns how many
    /// were dropped (the frame itself when it alone is over the limit).
    fn queue(&mut self, frame: Vec<u8>, limit: usize) -> u64 {
        if frame.len() > limit {
            return 1;
        }
        let mut dropped = 0;
        while self.data_bytes + frame.len() > limit {
            let oldest = self.data.pop_front().expect("queued bytes are in frames");
            self.data_bytes -= oldest.len();
            dropped += 1;
        }
        self.data_bytes += frame.len();
        self.data.push_back(frame);
        dropped
    }

    /// Reads what the client sent (at most [`READS_PER_POLL`] messages) and applies
    /// subscriptions to channels in `known`.
    fn read(&mut self, known: &BTreeMap<u16, Value>) -> Result<(), tungstenite::Error> {
        for _ in 0..READS_PER_POLL {
            match self.socket.read() {
                Ok(Message::Text(text)) => self.apply(text.as_str(), known),
                Ok(_) => {}
                Err(e) if would_block(&e) => return Ok(()),
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Applies one client operation; anything else (bad JSON, other ops) is ignored.
    fn apply(&mut self, text: &str, known: &BTreeMap<u16, Value>) {
        let Ok(request) = serde_json::from_str::<Value>(text) else {
            return;
        };
        match request["op"].as_str() {
            Some("subscribe") => {
                for subscription in request["subscriptions"].as_array().into_iter().flatten() {
                    let id = subscription["id"]
                        .as_u64()
                        .and_then(|v| u32::try_from(v).ok());
                    let channel = subscription["channelId"]
                        .as_u64()
                        .and_then(|v| u16::try_from(v).ok())
                        .filter(|c| known.contains_key(c));
                    if let (Some(id), Some(channel)) = (id, channel) {
                        self.subscriptions.insert(id, channel);
                    }
                }
            }
            Some("unsubscribe") => {
                for id in request["subscriptionIds"].as_array().into_iter().flatten() {
                    if let Some(id) = id.as_u64().and_then(|v| u32::try_from(v).ok()) {
                        self.subscriptions.remove(&id);
                    }
                }
            }
            _ => {}
        }
    }

    /// Hands queued messages to the socket until it would block; returns the `messageData`
    /// frames handed over. The socket holds at most one message beyond what the kernel took.
    fn send(&mut self) -> Result<u64, tungstenite::Error> {
        let mut sent = 0;
        loop {
            match self.socket.flush() {
                Ok(()) => {}
                Err(e) if would_block(&e) => return Ok(sent),
                Err(e) => return Err(e),
            }
            let message = if let Some(text) = self.control.pop_front() {
                Message::text(text)
            } else if let Some(frame) = self.data.pop_front() {
                self.data_bytes -= frame.len();
                sent += 1;
                Message::binary(frame)
            } else {
                return Ok(sent);
            };
            match self.socket.write(message) {
                Ok(()) => {}
                // The message stays in the socket's buffer, sent on the next flush.
                Err(e) if would_block(&e) => return Ok(sent),
                Err(e) => return Err(e),
            }
        }
    }
}

/// The `messageData` frame of `data` for subscription `subscription` at `log_time_ns`.
pub fn message_data(subscription: u32, log_time_ns: u64, data: &[u8]) -> Vec<u8> {
    let mut frame = Vec::with_capacity(MESSAGE_DATA_HEADER + data.len());
    frame.push(MESSAGE_DATA);
    frame.extend_from_slice(&subscription.to_le_bytes());
    frame.extend_from_slice(&log_time_ns.to_le_bytes());
    frame.extend_from_slice(data);
    frame
}

/// A `messageData` frame split into subscription id, log time (ns) and message bytes; `None`
/// when `frame` is not one.
pub fn parse_message_data(frame: &[u8]) -> Option<(u32, u64, &[u8])> {
    if frame.len() < MESSAGE_DATA_HEADER || frame[0] != MESSAGE_DATA {
        return None;
    }
    let subscription = u32::from_le_bytes(frame[1..5].try_into().ok()?);
    let log_time_ns = u64::from_le_bytes(frame[5..13].try_into().ok()?);
    Some((subscription, log_time_ns, &frame[MESSAGE_DATA_HEADER..]))
}

/// The WebSocket request a client of the live view at `addr` sends: it offers the Foxglove
/// subprotocol (for `tungstenite::client`).
pub fn client_request(addr: SocketAddr) -> tungstenite::handshake::client::Request {
    use tungstenite::client::IntoClientRequest;
    let mut request = format!("ws://{addr}")
        .into_client_request()
        .expect("a ws:// URL of a socket address is valid");
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    request
}

/// A client of the live view over `stream`, already connected to `addr`: the WebSocket
/// handshake of [`client_request`], and an error unless the server accepted the Foxglove
/// subprotocol.
pub fn client_handshake(
    stream: TcpStream,
    addr: SocketAddr,
) -> Result<WebSocket<TcpStream>, String> {
    let (socket, response) =
        tungstenite::client(client_request(addr), stream).map_err(|e| match e {
            HandshakeError::Failure(e) => format!("handshake: {e}"),
            HandshakeError::Interrupted(_) => "handshake timed out".to_owned(),
        })?;
    let accepted = response.headers().get("Sec-WebSocket-Protocol");
    if accepted.is_none_or(|v| v.as_bytes() != SUBPROTOCOL.as_bytes()) {
        return Err(format!("the server answered subprotocol {accepted:?}"));
    }
    Ok(socket)
}

/// The `advertise` entry of `channel`: a protobuf schema goes base64-encoded, a jsonschema
/// as its text.
pub fn advertisement(channel: &ChannelInfo) -> Value {
    let schema = if channel.schema_encoding == PROTOBUF {
        data_encoding::BASE64.encode(&channel.schema)
    } else {
        String::from_utf8_lossy(&channel.schema).into_owned()
    };
    json!({
        "id": channel.id,
        "topic": channel.topic,
        "encoding": channel.message_encoding,
        "schemaName": channel.schema_name,
        "schema": schema,
        "schemaEncoding": channel.schema_encoding,
    })
}

/// The `advertise` message of `channels`.
fn advertise<'a>(channels: impl IntoIterator<Item = &'a Value>) -> String {
    json!({ "op": "advertise", "channels": channels.into_iter().collect::<Vec<_>>() }).to_string()
}

/// The Foxglove WebSocket server.
pub struct LiveSink {
    listener: TcpListener,
    config: LiveConfig,
    websocket: WebSocketConfig,
    server_info: String,
    pending: Vec<Pending>,
    clients: Vec<Client>,
    /// `advertise` entry of every channel seen, by channel id.
    channels: BTreeMap<u16, Value>,
    stats: LiveStats,
}

impl LiveSink {
    /// Listens on `addr` (port 0: any free port, see [`LiveSink::local_addr`]).
    pub fn bind(addr: SocketAddr, config: LiveConfig) -> io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let session = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis());
        let server_info = json!({
            "op": "serverInfo",
            "name": SERVER_NAME,
            "capabilities": [],
            "supportedEncodings": [],
            "metadata": {},
            "sessionId": format!("{}-{session}", std::process::id()),
        })
        .to_string();
        // Each message is written as soon as the socket takes it (no batching), so the socket's
        // own buffer holds at most the one message the kernel did not take yet.
        let websocket = WebSocketConfig::default()
            .write_buffer_size(0)
            .read_buffer_size(4096)
            .max_message_size(Some(config.max_client_message_bytes))
            .max_frame_size(Some(config.max_client_message_bytes));
        Ok(Self {
            listener,
            config,
            websocket,
            server_info,
            pending: Vec::new(),
            clients: Vec::new(),
            channels: BTreeMap::new(),
            stats: LiveStats::default(),
        })
    }

    /// The address listened on.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// The counters.
    pub fn stats(&self) -> LiveStats {
        LiveStats {
            clients: self.clients.len(),
            ..self.stats
        }
    }

    /// Advertises `message`'s channel when it is new and queues the message for every
    /// subscription to it. Nothing is sent here: [`LiveSink::poll`] sends.
    pub fn write(&mut self, message: &EncodedMessage) {
        let channel = message.channel.id;
        if !self.channels.contains_key(&channel) {
            let entry = advertisement(message.channel);
            let text = advertise([&entry]);
            for client in &mut self.clients {
                client.control.push_back(text.clone());
            }
            self.channels.insert(channel, entry);
        }
        let limit = self.config.client_queue_bytes;
        for client in &mut self.clients {
            let subscriptions: Vec<u32> = client
                .subscriptions
                .iter()
                .filter(|&(_, &c)| c == channel)
                .map(|(&id, _)| id)
                .collect();
            for id in subscriptions {
                let frame = message_data(id, message.log_time_ns, &message.data);
                self.stats.dropped_messages += client.queue(frame, limit);
            }
        }
    }

    /// Accepts connections, moves handshakes on, reads the clients' requests and sends what
    /// is queued, without blocking; `now_ns` (any monotonic clock) times out handshakes.
    pub fn poll(&mut self, now_ns: u64) {
        self.accept(now_ns);
        let timeout_ns = (self.config.handshake_timeout_s.max(0.0) * 1e9) as u64;
        for pending in std::mem::take(&mut self.pending) {
            if now_ns.saturating_sub(pending.started_ns) > timeout_ns {
                self.stats.refused += 1;
                continue;
            }
            self.finish_handshake(pending.handshake.handshake(), pending.started_ns);
        }
        let channels = &self.channels;
        let stats = &mut self.stats;
        self.clients.retain_mut(|client| {
            let result = client.read(channels).and_then(|()| client.send());
            match result {
                Ok(sent) => {
                    stats.sent_messages += sent;
                    true
                }
                Err(_) => false,
            }
        });
    }

    /// Closes every client's connection with a WebSocket close (best effort, without
    /// blocking: what the socket does not take at once is lost), so clients see the view end
    /// rather than a reset.
    pub fn close(mut self) {
        for client in &mut self.clients {
            let _ = client.socket.close(None);
        }
    }

    /// Accepts waiting connections (at most [`ACCEPTS_PER_POLL`]), refusing those past
    /// `max_clients`.
    fn accept(&mut self, now_ns: u64) {
        for _ in 0..ACCEPTS_PER_POLL {
            let stream = match self.listener.accept() {
                Ok((stream, _)) => stream,
                Err(_) => return,
            };
            if self.clients.len() + self.pending.len() >= self.config.max_clients
                || stream.set_nonblocking(true).is_err()
            {
                self.stats.refused += 1;
                continue;
            }
            let _ = stream.set_nodelay(true);
            let handshake = ServerHandshake::start(stream, Subprotocol, Some(self.websocket));
            self.finish_handshake(handshake.handshake(), now_ns);
        }
    }

    /// Keeps a handshake that is still going on, or makes a client of a finished one.
    fn finish_handshake(
        &mut self,
        result: Result<
            WebSocket<TcpStream>,
            HandshakeError<ServerHandshake<TcpStream, Subprotocol>>,
        >,
        started_ns: u64,
    ) {
        match result {
            Ok(socket) => {
                let mut control = VecDeque::from([self.server_info.clone()]);
                if !self.channels.is_empty() {
                    control.push_back(advertise(self.channels.values()));
                }
                self.clients.push(Client {
                    socket,
                    subscriptions: HashMap::new(),
                    control,
                    data: VecDeque::new(),
                    data_bytes: 0,
                });
                self.stats.connections += 1;
            }
            Err(HandshakeError::Interrupted(handshake)) => self.pending.push(Pending {
                handshake,
                started_ns,
            }),
            Err(HandshakeError::Failure(_)) => self.stats.refused += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_data_frame_parses_back_and_other_bytes_do_not() {
        let frame = message_data(0x0102_0304, 0x1122_3344_5566_7788, b"abc");
        assert_eq!(frame[..5], [MESSAGE_DATA, 0x04, 0x03, 0x02, 0x01]);
        assert_eq!(
            parse_message_data(&frame),
            Some((0x0102_0304, 0x1122_3344_5566_7788, &b"abc"[..]))
        );
        assert_eq!(parse_message_data(&frame[..12]), None);
        let mut other = frame.clone();
        other[0] = 0x02;
        assert_eq!(parse_message_data(&other), None);
    }

    #[test]
    fn protobuf_schemas_are_advertised_in_base64_and_jsonschemas_as_text() {
        let mut registry = crate::ChannelRegistry::new(0);
        let pose = crate::Record {
            topic: "/pose".into(),
            stamp_ns: 0,
            payload: crate::recorder::Payload::Protobuf(crate::foxglove::POSE_IN_FRAME, vec![]),
        };
        let entry = advertisement(registry.encode(&pose).channel);
        let schema = entry["schema"].as_str().unwrap();
        assert_eq!(
            data_encoding::BASE64.decode(schema.as_bytes()).unwrap(),
            crate::foxglove::POSE_IN_FRAME.descriptor
        );
        assert_eq!(entry["schemaEncoding"], "protobuf");
        let plot = crate::Record {
            topic: "/plot".into(),
            stamp_ns: 0,
            payload: crate::recorder::Payload::Json(json!({ "v": 1.0 })),
        };
        let entry = advertisement(registry.encode(&plot).channel);
        let schema: Value = serde_json::from_str(entry["schema"].as_str().unwrap()).unwrap();
        assert_eq!(schema["properties"]["v"]["type"], "number");
        assert_eq!(
            (entry["id"].as_u64(), &entry["encoding"]),
            (Some(1), &json!("json"))
        );
    }
}
