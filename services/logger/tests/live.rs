//! The live view over real sockets: a tungstenite client speaks the Foxglove WebSocket
//! protocol to a [`LiveSink`] on an ephemeral port. The sink runs on its own thread, fed
//! records as the logger loop feeds it, and polled every millisecond.

use std::net::{SocketAddr, TcpStream};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use motm_logger::foxglove as fg;
use motm_logger::live::{LiveStats, client_handshake, client_request, parse_message_data};
use motm_logger::protobuf_check::SchemaDecoder;
use motm_logger::recorder::{Payload, Record};
use motm_logger::{ChannelRegistry, LiveConfig, LiveSink};
use prost::Message as _;
use serde_json::{Value, json};
use tungstenite::handshake::HandshakeError;
use tungstenite::{Message, WebSocket};

/// Longest wait for anything over the loopback (generous: the machine may be loaded).
const PATIENCE: Duration = Duration::from_secs(60);

/// Monotonic → Unix offset of the test's registry, ns.
const UNIX_OFFSET_NS: i128 = 1_700_000_000_000_000_000;

/// What the test asks of the server thread.
enum Command {
    /// Encode and write a record.
    Record(Record),
    /// Reply with the counters.
    Stats(mpsc::Sender<LiveStats>),
}

/// A live sink on its own thread: records in, polled every millisecond.
struct Server {
    addr: SocketAddr,
    commands: mpsc::Sender<Command>,
    thread: JoinHandle<()>,
}

impl Server {
    fn start(config: LiveConfig) -> Self {
        let mut sink = LiveSink::bind("127.0.0.1:0".parse().unwrap(), config).expect("bind");
        let addr = sink.local_addr().unwrap();
        let (commands, inbox) = mpsc::channel();
        let thread = std::thread::spawn(move || {
            let mut registry = ChannelRegistry::new(UNIX_OFFSET_NS);
            let start = Instant::now();
            loop {
                match inbox.recv_timeout(Duration::from_millis(1)) {
                    Ok(Command::Record(record)) => sink.write(&registry.encode(&record)),
                    Ok(Command::Stats(reply)) => {
                        let _ = reply.send(sink.stats());
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                    Err(mpsc::RecvTimeoutError::Disconnected) => return sink.close(),
                }
                sink.poll(start.elapsed().as_nanos() as u64);
            }
        });
        Self {
            addr,
            commands,
            thread,
        }
    }

    fn feed(&self, record: Record) {
        self.commands.send(Command::Record(record)).expect("server");
    }

    /// The counters; a server that does not answer within [`PATIENCE`] is blocked.
    fn stats(&self) -> LiveStats {
        let (reply, answer) = mpsc::channel();
        self.commands.send(Command::Stats(reply)).expect("server");
        answer
            .recv_timeout(PATIENCE)
            .expect("the live sink blocked")
    }

    fn stop(self) {
        drop(self.commands);
        self.thread.join().expect("server thread");
    }
}

/// A tool-pose record at monotonic `stamp_ns` with x = `x`.
fn pose(stamp_ns: u64, x: f64) -> Record {
    let message = fg::PoseInFrame {
        timestamp: Some(fg::Timestamp::from_ns(stamp_ns)),
        frame_id: "world".into(),
        pose: Some(fg::Pose {
            position: Some(fg::Vector3 { x, y: 0.5, z: 1.0 }),
            orientation: Some(fg::Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
    };
    Record {
        topic: "/ee_pose".into(),
        stamp_ns,
        payload: Payload::Protobuf(fg::POSE_IN_FRAME, message.encode_to_vec()),
    }
}

/// A JSON record on `topic` at `stamp_ns`.
fn plot(topic: &str, stamp_ns: u64, value: f64) -> Record {
    Record {
        topic: topic.into(),
        stamp_ns,
        payload: Payload::Json(json!({ "solve_time_us": value, "outcome": "Solved" })),
    }
}

/// Connects a client offering the Foxglove subprotocol; reads then time out after 20 ms.
fn connect(addr: SocketAddr) -> WebSocket<TcpStream> {
    let stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    let socket = client_handshake(stream, addr).unwrap_or_else(|e| panic!("{e}"));
    socket
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    socket
}

/// The next message of `client`, calling `between` while none has come; panics after
/// [`PATIENCE`].
fn next_message(client: &mut WebSocket<TcpStream>, mut between: impl FnMut()) -> Message {
    let start = Instant::now();
    while start.elapsed() < PATIENCE {
        match client.read() {
            Ok(message) => return message,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                between()
            }
            Err(e) => panic!("client read: {e}"),
        }
    }
    panic!("no message within {PATIENCE:?}");
}

/// The next JSON text message of `client`.
fn next_text(client: &mut WebSocket<TcpStream>) -> Value {
    match next_message(client, || {}) {
        Message::Text(text) => serde_json::from_str(text.as_str()).expect("JSON"),
        other => panic!("expected a text message, got {other:?}"),
    }
}

/// A decoded `messageData` frame.
struct MessageData {
    subscription: u32,
    log_time_ns: u64,
    payload: Vec<u8>,
}

/// Splits a binary `messageData` frame.
fn message_data(message: &Message) -> MessageData {
    let Message::Binary(bytes) = message else {
        panic!("expected a binary message, got {message:?}");
    };
    let (subscription, log_time_ns, payload) =
        parse_message_data(bytes).expect("a messageData frame");
    MessageData {
        subscription,
        log_time_ns,
        payload: payload.to_vec(),
    }
}

/// The advertised channel of `topic` in an `advertise` message.
fn channel<'a>(advertise: &'a Value, topic: &str) -> &'a Value {
    assert_eq!(advertise["op"], "advertise");
    advertise["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == topic)
        .unwrap_or_else(|| panic!("{topic} not advertised in {advertise}"))
}

fn unix_ns(stamp_ns: u64) -> u64 {
    (i128::from(stamp_ns) + UNIX_OFFSET_NS) as u64
}

#[test]
fn a_client_gets_server_info_the_channels_and_the_messages_it_subscribed_to() {
    let server = Server::start(LiveConfig::default());
    server.feed(pose(1_000, 0.0));
    server.feed(plot("/qp", 1_000, 0.0));
    // Commands are handled in order: once the counters come, both channels exist.
    server.stats();
    let mut client = connect(server.addr);

    let info = next_text(&mut client);
    assert_eq!(info["op"], "serverInfo");
    assert_eq!(info["name"], "motm-logger");
    assert_eq!(info["capabilities"], json!([]));
    assert!(info["sessionId"].is_string(), "{info}");
    let advertise = next_text(&mut client);
    let ee = channel(&advertise, "/ee_pose").clone();
    assert_eq!(ee["encoding"], "protobuf");
    assert_eq!(ee["schemaName"], "foxglove.PoseInFrame");
    assert_eq!(ee["schemaEncoding"], "protobuf");
    let descriptor = data_encoding::BASE64
        .decode(ee["schema"].as_str().unwrap().as_bytes())
        .expect("base64 schema");
    let decoder = SchemaDecoder::new("foxglove.PoseInFrame", &descriptor).expect("descriptor");
    let qp = channel(&advertise, "/qp").clone();
    assert_eq!(qp["encoding"], "json");
    assert_eq!(qp["schemaEncoding"], "jsonschema");
    let schema: Value = serde_json::from_str(qp["schema"].as_str().unwrap()).unwrap();
    assert_eq!(schema["properties"]["solve_time_us"]["type"], "number");

    client
        .send(Message::text(
            json!({ "op": "subscribe", "subscriptions": [
                { "id": 7, "channelId": ee["id"] },
                { "id": 9, "channelId": qp["id"] },
            ]})
            .to_string(),
        ))
        .unwrap();
    // Records keep coming (as from the logger loop) until both subscriptions got one.
    let mut stamp = 1_000;
    let mut last_log_time = [0u64; 2];
    let (mut poses, mut plots) = (0, 0);
    while poses < 3 || plots < 3 {
        let message = next_message(&mut client, || {
            stamp += 1_000_000;
            server.feed(pose(stamp, stamp as f64 * 1e-9));
            server.feed(plot("/qp", stamp, 42.0));
        });
        let data = message_data(&message);
        let slot = match data.subscription {
            7 => {
                decoder
                    .decode(&data.payload)
                    .expect("decodes with the schema");
                let decoded = fg::PoseInFrame::decode(data.payload.as_slice()).unwrap();
                let stamp_ns = data.log_time_ns - UNIX_OFFSET_NS as u64;
                let x = decoded.pose.unwrap().position.unwrap().x;
                assert_eq!(x, stamp_ns as f64 * 1e-9, "payload and log time match");
                poses += 1;
                0
            }
            9 => {
                let value: Value = serde_json::from_slice(&data.payload).expect("JSON");
                assert_eq!(value["solve_time_us"], 42.0);
                plots += 1;
                1
            }
            other => panic!("unknown subscription {other}"),
        };
        assert!(
            data.log_time_ns > unix_ns(1_000),
            "a message from before subscribing"
        );
        assert!(
            data.log_time_ns >= last_log_time[slot],
            "log time went back"
        );
        last_log_time[slot] = data.log_time_ns;
    }

    // A channel that appears later is advertised to the connected client.
    server.feed(plot("/late", stamp, 1.0));
    let late = loop {
        if let Message::Text(text) = next_message(&mut client, || {}) {
            break serde_json::from_str::<Value>(text.as_str()).unwrap();
        }
    };
    assert_eq!(late["channels"].as_array().unwrap().len(), 1, "{late}");
    assert_eq!(channel(&late, "/late")["encoding"], "json");

    // Unsubscribing from the poses and subscribing again to the plots (id 11): a client's
    // requests are applied in order and its messages are sent in order, so once a message of
    // subscription 11 came, no pose may follow.
    client
        .send(Message::text(
            json!({ "op": "unsubscribe", "subscriptionIds": [7] }).to_string(),
        ))
        .unwrap();
    client
        .send(Message::text(
            json!({ "op": "subscribe", "subscriptions": [{ "id": 11, "channelId": qp["id"] }] })
                .to_string(),
        ))
        .unwrap();
    let mut resubscribed = 0;
    while resubscribed < 5 {
        let data = message_data(&next_message(&mut client, || {
            stamp += 1_000_000;
            server.feed(pose(stamp, 0.0));
            server.feed(plot("/qp", stamp, 42.0));
        }));
        match data.subscription {
            7 => assert_eq!(resubscribed, 0, "a pose after unsubscribing"),
            11 => resubscribed += 1,
            _ => {}
        }
    }
    let stats = server.stats();
    assert_eq!((stats.clients, stats.connections), (1, 1));
    assert_eq!(stats.dropped_messages, 0, "{stats:?}");
    assert!(stats.sent_messages >= 6 + 5, "{stats:?}");
    // When the sink ends, the client gets a WebSocket close (after what was still queued).
    server.stop();
    loop {
        match next_message(&mut client, || {}) {
            Message::Close(_) => break,
            Message::Binary(_) => {}
            other => panic!("expected the close, got {other:?}"),
        }
    }
}

#[test]
fn a_client_that_does_not_read_loses_its_oldest_messages_and_the_sink_never_waits() {
    let config = LiveConfig {
        client_queue_bytes: 1 << 20,
        ..LiveConfig::default()
    };
    let server = Server::start(config);
    server.feed(plot("/image", 0, 0.0));
    server.stats();
    let mut client = connect(server.addr);
    assert_eq!(next_text(&mut client)["op"], "serverInfo");
    let id = channel(&next_text(&mut client), "/image")["id"].clone();
    client
        .send(Message::text(
            json!({ "op": "subscribe", "subscriptions": [{ "id": 1, "channelId": id }] })
                .to_string(),
        ))
        .unwrap();
    // Wait until the subscription is in: a message comes through.
    let mut stamp = 0;
    let first = message_data(&next_message(&mut client, || {
        stamp += 1;
        server.feed(plot("/image", stamp, 0.0));
    }));
    assert_eq!(first.subscription, 1);

    // 200 messages of 256 kB (50 MB, far beyond the socket buffers and the 1 MB queue) while
    // the client reads nothing: the sink keeps answering, and drops.
    let padding = "x".repeat(256 << 10);
    let burst_start = stamp + 1;
    for _ in 0..200 {
        stamp += 1;
        server.feed(Record {
            topic: "/image".into(),
            stamp_ns: stamp,
            payload: Payload::Json(json!({ "solve_time_us": 0.0, "outcome": padding })),
        });
    }
    let stats = server.stats();
    assert!(stats.dropped_messages > 0, "{stats:?}");
    assert_eq!(stats.clients, 1, "a slow client is kept");

    // Reading now, the client gets what was queued: some of the burst is missing, but the
    // last message is there and times never go back.
    let mut last_log_time = 0;
    let mut received = 0;
    loop {
        let data = message_data(&next_message(&mut client, || {}));
        assert!(data.log_time_ns >= last_log_time);
        last_log_time = data.log_time_ns;
        if data.log_time_ns >= unix_ns(burst_start) {
            received += 1;
        }
        if data.log_time_ns == unix_ns(stamp) {
            break;
        }
    }
    assert!(
        received < 200,
        "{received} of 200 arrived: nothing was dropped"
    );
    assert_eq!(
        received + server.stats().dropped_messages,
        200,
        "every message of the burst is either received or counted as dropped"
    );
    server.stop();
}

#[test]
fn closed_clients_are_dropped_and_clients_past_the_limit_are_refused() {
    let server = Server::start(LiveConfig {
        max_clients: 1,
        ..LiveConfig::default()
    });
    let mut first = connect(server.addr);
    assert_eq!(next_text(&mut first)["op"], "serverInfo");
    // A second connection is closed without a handshake.
    let mut second = TcpStream::connect(server.addr).unwrap();
    second.set_read_timeout(Some(PATIENCE)).unwrap();
    std::io::Write::write_all(
        &mut second,
        b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
          Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
    )
    .unwrap();
    let mut buffer = [0u8; 64];
    let read = std::io::Read::read(&mut second, &mut buffer);
    assert!(
        matches!(read, Ok(0)) || read.is_err(),
        "the refused connection was answered"
    );
    assert_eq!(server.stats().refused, 1);

    first.close(None).unwrap();
    let start = Instant::now();
    while server.stats().clients > 0 {
        assert!(start.elapsed() < PATIENCE, "the closed client was kept");
        let _ = first.read();
        std::thread::sleep(Duration::from_millis(5));
    }
    // Its slot is free again.
    let mut third = connect(server.addr);
    assert_eq!(next_text(&mut third)["op"], "serverInfo");
    assert_eq!(server.stats().connections, 2);
    server.stop();
}

#[test]
fn a_client_offering_only_another_subprotocol_is_refused_and_one_offering_none_is_served() {
    let server = Server::start(LiveConfig::default());
    let stream = TcpStream::connect(server.addr).unwrap();
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    let mut request = client_request(server.addr);
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "some.other.v1".parse().unwrap());
    match tungstenite::client(request, stream) {
        Err(HandshakeError::Failure(tungstenite::Error::Http(response))) => {
            assert_eq!(response.status(), 400);
        }
        Err(e) => panic!("expected a refusal, got {e}"),
        Ok(_) => panic!("a client of another subprotocol was served"),
    }
    // A bare WebSocket client (no subprotocol offered) is served.
    let stream = TcpStream::connect(server.addr).unwrap();
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    let mut request = client_request(server.addr);
    request.headers_mut().remove("Sec-WebSocket-Protocol");
    let (mut client, _) = tungstenite::client(request, stream).expect("served");
    client
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    assert_eq!(next_text(&mut client)["op"], "serverInfo");
    let stats = server.stats();
    assert_eq!((stats.refused, stats.connections), (1, 1), "{stats:?}");
    server.stop();
}
