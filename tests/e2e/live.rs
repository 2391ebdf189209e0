//! `motm run --live` with the real processes: a Foxglove WebSocket client connects to the
//! logger's live view during the run, subscribes to the transforms, the joint states and the
//! QP status, and gets their messages, each decoding with the advertised schema (protobuf) or
//! parsing as JSON, in non-decreasing wall-clock log times. With `--mcap` as well, one logger
//! process serves the view and writes a complete file.

use std::collections::BTreeMap;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::Child;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use motm_e2e::{one_stack_at_a_time, processes_mentioning, spawn_motm};
use motm_logger::live::{client_handshake, parse_message_data};
use motm_logger::protobuf_check::SchemaDecoder;
use motm_logger::recorder::topics;
use motm_msgs::services;
use serde_json::{Value, json};
use tungstenite::{Message, WebSocket};

/// Messages wanted on each watched channel.
const WANTED: u64 = 20;

/// Longest wait for the view to listen, or for the messages (generous: the machine is shared).
const PATIENCE: Duration = Duration::from_secs(120);

/// A loopback address with a port that was free a moment ago.
fn free_addr() -> SocketAddr {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
}

/// The topics watched: two protobuf channels of the 3D view and a JSON plot channel.
fn watched_topics() -> Vec<String> {
    vec![
        topics::TF.to_owned(),
        topics::JOINT_STATES.to_owned(),
        format!("/{}", services::CONTROL_QP_STATUS),
    ]
}

/// Connects to the live view at `addr` once it listens (`run` must still be running).
fn connect(addr: SocketAddr, run: &mut Child) -> WebSocket<TcpStream> {
    let start = Instant::now();
    loop {
        if let Ok(stream) = TcpStream::connect(addr) {
            stream.set_read_timeout(Some(PATIENCE)).unwrap();
            let socket =
                client_handshake(stream, addr).unwrap_or_else(|e| panic!("live view: {e}"));
            socket
                .get_ref()
                .set_read_timeout(Some(Duration::from_millis(100)))
                .unwrap();
            return socket;
        }
        if let Ok(Some(status)) = run.try_wait() {
            panic!("motm run exited ({status}) before the live view listened");
        }
        assert!(start.elapsed() < PATIENCE, "the live view never listened");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A subscribed channel: how to check its messages and what came.
struct Watched {
    topic: String,
    /// The schema decoder of a protobuf channel (`None`: JSON).
    decoder: Option<SchemaDecoder>,
    messages: u64,
    last_log_time_ns: u64,
}

/// Subscribes to `topics` as they are advertised and reads until each has [`WANTED`]
/// messages; checks every message. Returns the message count per topic.
fn watch(client: &mut WebSocket<TcpStream>, topics: &[String]) -> BTreeMap<String, u64> {
    let mut subscriptions: BTreeMap<u32, Watched> = BTreeMap::new();
    let mut server_info = false;
    let start = Instant::now();
    let now_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let counts = |s: &BTreeMap<u32, Watched>| -> BTreeMap<String, u64> {
        s.values().map(|w| (w.topic.clone(), w.messages)).collect()
    };
    while subscriptions.len() < topics.len() || subscriptions.values().any(|w| w.messages < WANTED)
    {
        assert!(
            start.elapsed() < PATIENCE,
            "too few messages: {:?}",
            counts(&subscriptions)
        );
        let message = match client.read() {
            Ok(message) => message,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            Err(e) => panic!("live view: {e}; so far {:?}", counts(&subscriptions)),
        };
        match message {
            Message::Text(text) => {
                let value: Value = serde_json::from_str(text.as_str()).expect("JSON");
                match value["op"].as_str() {
                    Some("serverInfo") => server_info = true,
                    Some("advertise") => {
                        assert!(server_info, "advertise before serverInfo");
                        let mut requests = Vec::new();
                        for channel in value["channels"].as_array().unwrap() {
                            let topic = channel["topic"].as_str().unwrap();
                            if !topics.iter().any(|t| t == topic) {
                                continue;
                            }
                            let id = channel["id"].as_u64().unwrap() as u32;
                            subscriptions.insert(id, watched(channel));
                            requests.push(json!({ "id": id, "channelId": id }));
                        }
                        if !requests.is_empty() {
                            client
                                .send(Message::text(
                                    json!({ "op": "subscribe", "subscriptions": requests })
                                        .to_string(),
                                ))
                                .unwrap();
                        }
                    }
                    other => panic!("unexpected op {other:?}"),
                }
            }
            Message::Binary(bytes) => {
                let (id, log_time_ns, payload) =
                    parse_message_data(&bytes).expect("a messageData frame");
                let watched = subscriptions
                    .get_mut(&id)
                    .unwrap_or_else(|| panic!("a message of unknown subscription {id}"));
                assert!(
                    log_time_ns >= watched.last_log_time_ns,
                    "{}: log time went back",
                    watched.topic
                );
                // Wall-clock (Unix) log times, as in the MCAP file.
                assert!(
                    log_time_ns.abs_diff(now_ns) < 600_000_000_000,
                    "{}: log time {log_time_ns} is not near now {now_ns}",
                    watched.topic
                );
                watched.last_log_time_ns = log_time_ns;
                match &watched.decoder {
                    Some(decoder) => {
                        let decoded = decoder
                            .decode(payload)
                            .unwrap_or_else(|e| panic!("{}: {e}", watched.topic));
                        assert!(decoded.fields > 0, "{}: an empty message", watched.topic);
                    }
                    None => {
                        let _: Value = serde_json::from_slice(payload)
                            .unwrap_or_else(|e| panic!("{}: {e}", watched.topic));
                    }
                }
                watched.messages += 1;
            }
            _ => {}
        }
    }
    counts(&subscriptions)
}

/// What to check the messages of an advertised `channel` with.
fn watched(channel: &Value) -> Watched {
    let topic = channel["topic"].as_str().unwrap().to_owned();
    let decoder = match channel["encoding"].as_str() {
        Some("protobuf") => {
            assert_eq!(channel["schemaEncoding"], "protobuf", "{channel}");
            let descriptor = data_encoding::BASE64
                .decode(channel["schema"].as_str().unwrap().as_bytes())
                .expect("a base64 schema");
            let name = channel["schemaName"].as_str().unwrap();
            Some(SchemaDecoder::new(name, &descriptor).expect("a descriptor set"))
        }
        Some("json") => {
            assert_eq!(channel["schemaEncoding"], "jsonschema", "{channel}");
            let schema: Value =
                serde_json::from_str(channel["schema"].as_str().unwrap()).expect("jsonschema");
            assert_eq!(schema["type"], "object", "{channel}");
            None
        }
        other => panic!("{topic}: unexpected encoding {other:?}"),
    };
    Watched {
        topic,
        decoder,
        messages: 0,
        last_log_time_ns: 0,
    }
}

/// Waits for `run` to end; its JSON report, after checking the run succeeded, left no
/// process behind and had one logger.
fn finish(run: Child, prefix: &str) -> Value {
    let out = run.wait_with_output().expect("motm run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "motm run failed: {stderr}");
    let report: Value = serde_json::from_slice(&out.stdout).expect("motm run --json report");
    let loggers: Vec<&Value> = report["processes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["name"] == "logger")
        .collect();
    assert_eq!(loggers.len(), 1, "{report}");
    assert!(loggers[0]["cycles"].as_u64().unwrap() > 0, "{report}");
    assert!(
        processes_mentioning(prefix).is_empty(),
        "the run left processes"
    );
    report
}

#[test]
fn motm_run_live_serves_transforms_joint_states_and_plots_to_a_foxglove_client() {
    let _stack = one_stack_at_a_time();
    let addr = free_addr();
    let prefix = format!("motme2e{}_live_", std::process::id());
    let mut run = spawn_motm(&["run", "--json", "--live", &addr.to_string()], &prefix);
    let mut client = connect(addr, &mut run);
    let counts = watch(&mut client, &watched_topics());
    drop(client);
    finish(run, &prefix);
    for topic in watched_topics() {
        assert!(counts[&topic] >= WANTED, "{counts:?}");
    }
}

#[test]
fn with_mcap_and_live_one_logger_serves_the_view_and_writes_a_complete_file() {
    let _stack = one_stack_at_a_time();
    let addr = free_addr();
    let path: PathBuf =
        std::env::temp_dir().join(format!("motm-e2e-{}-live.mcap", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let prefix = format!("motme2e{}_livemcap_", std::process::id());
    let mut run = spawn_motm(
        &[
            "run",
            "--json",
            "--mcap",
            path.to_str().unwrap(),
            "--live",
            &addr.to_string(),
        ],
        &prefix,
    );
    let mut client = connect(addr, &mut run);
    // The process serving the view is the one writing the file.
    let needle = format!("--out {}", path.display());
    let loggers: Vec<String> = processes_mentioning(path.to_str().unwrap())
        .into_iter()
        .filter_map(|pid| std::fs::read(format!("/proc/{pid}/cmdline")).ok())
        .map(|c| String::from_utf8_lossy(&c).replace('\0', " "))
        .filter(|c| c.contains(&needle))
        .collect();
    assert_eq!(loggers.len(), 1, "{loggers:?}");
    assert!(
        loggers[0].contains(&format!("--live {addr}")),
        "{loggers:?}"
    );
    let counts = watch(&mut client, &watched_topics()[..1]);
    drop(client);
    finish(run, &prefix);
    assert!(counts[topics::TF] >= WANTED, "{counts:?}");

    let bytes = std::fs::read(&path).expect("the log");
    let summary = motm_logger::scan(&bytes).expect("a readable log");
    assert!(summary.complete, "the logger did not finish the file");
    assert!(summary.problems().is_empty(), "{:?}", summary.problems());
    assert!(
        summary
            .channel(topics::TF)
            .expect("/tf in the file")
            .messages
            > counts[topics::TF],
        "the file holds the whole run, the client only what came after it subscribed"
    );
    let _ = std::fs::remove_file(&path);
}
