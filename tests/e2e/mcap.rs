//! `motm run --mcap` with the real processes: the logger's file holds every expected channel
//! with messages, each protobuf message decodes with the schema stored in the file, log times
//! never decrease within a channel, `motm log check` accepts it, and `motm replay` of it gives
//! every control task's logged outputs again (and sees a changed gain). A logger killed mid-run
//! leaves a file `motm log check` still accepts, up to its last whole chunk.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use motm_e2e::{motm, motm_command, one_stack_at_a_time, processes_mentioning};
use motm_logger::foxglove as fg;
use motm_logger::protobuf_check::SchemaDecoder;
use motm_logger::recorder::topics;
use motm_logger::replay_log;
use motm_msgs::services;
use prost::Message as _;

/// A fresh output path in the temp folder.
fn out_path(name: &str) -> PathBuf {
    let path = std::env::temp_dir().join(format!("motm-e2e-{}-{name}.mcap", std::process::id()));
    let _ = std::fs::remove_file(&path);
    path
}

/// The channels a run must fill: the 3D view, the image, the plots and the raw services.
fn expected_topics() -> Vec<String> {
    let mut topics: Vec<String> = [
        topics::TF,
        topics::JOINT_STATES,
        topics::EE_POSE,
        topics::TARGET_POSE,
        topics::SCENE,
        topics::CAMERA_IMAGE,
        topics::KINEMATICS,
        topics::LOGGER_STATS,
    ]
    .map(String::from)
    .to_vec();
    for service in [
        services::ARM_JOINT_STATE,
        services::BASE_ODOMETRY,
        services::BASE_PLAN,
        services::CONTROL_QP_STATUS,
        services::CONTROL_REACH_TWIST,
        services::MISSION_STATE,
        services::SAFETY_SAFE_STOP,
        services::SIM_TRUTH,
        services::ARM_DRIVER_STATUS,
        services::SUPERVISOR_STATUS,
    ] {
        topics.push(format!("/{service}"));
    }
    for process in [
        "qp-resolver",
        "reacher",
        "watchdog",
        "panda-driver",
        "supervisor",
    ] {
        topics.push(format!("/{}", services::heartbeat(process)));
    }
    topics
}

#[test]
fn motm_run_mcap_logs_every_channel_decodable_with_its_stored_schema() {
    let _stack = one_stack_at_a_time();
    let path = out_path("run");
    let prefix = format!("motme2e{}_mcap_", std::process::id());
    let out = motm(
        &["run", "--json", "--mcap", path.to_str().unwrap()],
        &prefix,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "motm run failed: {stderr}");
    let report: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("motm run --json report");
    let logger = report["processes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "logger")
        .unwrap_or_else(|| panic!("no logger in {report}"));
    assert!(logger["cycles"].as_u64().unwrap() > 0, "{report}");

    let bytes = std::fs::read(&path).expect("the log");
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let mut last_log_time: BTreeMap<String, u64> = BTreeMap::new();
    let mut decoders: BTreeMap<String, SchemaDecoder> = BTreeMap::new();
    let mut tf_frames = Vec::new();
    let mut joints = 0;
    for message in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let message = message.expect("a whole message");
        let topic = message.channel.topic.clone();
        let last = last_log_time.entry(topic.clone()).or_insert(0);
        assert!(message.log_time >= *last, "{topic}: log time went back");
        *last = message.log_time;
        *counts.entry(topic.clone()).or_insert(0) += 1;
        let schema = message
            .channel
            .schema
            .as_ref()
            .expect("every channel has a schema");
        match message.channel.message_encoding.as_str() {
            "protobuf" => {
                assert_eq!(schema.encoding, "protobuf");
                let decoder = decoders.entry(topic.clone()).or_insert_with(|| {
                    SchemaDecoder::new(&schema.name, &schema.data).expect("a descriptor set")
                });
                decoder
                    .decode(&message.data)
                    .unwrap_or_else(|e| panic!("{topic}: {e}"));
            }
            "json" => {
                assert_eq!(schema.encoding, "jsonschema");
                let _: serde_json::Value =
                    serde_json::from_slice(&message.data).expect("JSON message");
            }
            // The replay log's raw samples: the payload type's name, its bytes.
            replay_log::RAW_ENCODING => {
                assert!(replay_log::raw_topic(&topic).is_some(), "{topic}");
                assert!(
                    !schema.name.is_empty() && !message.data.is_empty(),
                    "{topic}"
                );
            }
            other => panic!("{topic}: unexpected encoding {other}"),
        }
        if topic == topics::TF && tf_frames.is_empty() {
            let tf = fg::FrameTransforms::decode(message.data.as_ref()).unwrap();
            tf_frames = tf
                .transforms
                .iter()
                .map(|t| t.child_frame_id.clone())
                .collect();
        }
        if topic == topics::JOINT_STATES && joints == 0 {
            joints = fg::JointStates::decode(message.data.as_ref())
                .unwrap()
                .joints
                .len();
        }
    }
    for topic in expected_topics() {
        assert!(
            counts.get(&topic).copied().unwrap_or(0) > 0,
            "{topic} missing or empty: {counts:?}"
        );
    }
    // Frankie: world → base → 7 arm joints → tool; joint states for the 7 arm joints.
    assert_eq!(
        tf_frames.first().map(String::as_str),
        Some("base"),
        "{tf_frames:?}"
    );
    assert_eq!(
        tf_frames.last().map(String::as_str),
        Some("tool"),
        "{tf_frames:?}"
    );
    assert_eq!(tf_frames.len(), 9, "{tf_frames:?}");
    assert_eq!(joints, 7);

    let check = motm(&["log", "check", path.to_str().unwrap()], &prefix);
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        check.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&check.stderr)
    );
    assert!(text.contains("complete"), "{text}");

    // Replay: every control task's logged cycles, fed again through the same tasks, give the
    // logged outputs; a changed reacher gain is seen in the reacher's first twist.
    let replay = |extra: &[&str]| -> serde_json::Value {
        let out = motm(
            &[&["replay", path.to_str().unwrap(), "--json"], extra].concat(),
            &prefix,
        );
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).expect("motm replay --json")
    };
    let same = replay(&[]);
    let tasks = same["tasks"].as_array().unwrap();
    for spec in motm_graph::replayed_tasks() {
        assert!(
            tasks.iter().any(|t| t["name"] == spec.name),
            "{} not replayed: {same}",
            spec.name
        );
    }
    for task in tasks {
        assert!(task["cycles"].as_u64().unwrap() > 100, "{task}");
        assert_eq!(task["missing_inputs"], 0, "{task}");
        assert_eq!(task["differing_cycles"], 0, "{task}");
    }
    let gains = out_path("gains").with_extension("toml");
    std::fs::write(&gains, "[reacher]\narm_speed_ratio = 0.35\n").unwrap();
    let changed = replay(&["--task", "reacher", "--config", gains.to_str().unwrap()]);
    let reacher = &changed["tasks"][0];
    assert_eq!(reacher["name"], "reacher", "{changed}");
    assert!(
        reacher["differing_cycles"].as_u64().unwrap() > 0,
        "{changed}"
    );
    assert_eq!(
        reacher["first_difference"]["topic"], "motm/v1/control/reach_twist",
        "{changed}"
    );
    let _ = std::fs::remove_file(&gains);
    let _ = std::fs::remove_file(&path);
}

#[test]
fn motm_log_check_exits_2_for_a_missing_file_and_1_for_garbage() {
    let path = out_path("garbage");
    let missing = motm(&["log", "check", path.to_str().unwrap()], "motme2e_unused_");
    assert_eq!(missing.status.code(), Some(2));
    std::fs::write(&path, b"\x89MCAP0\r\n but then nothing sensible").unwrap();
    let garbage = motm(&["log", "check", path.to_str().unwrap()], "motme2e_unused_");
    assert_eq!(garbage.status.code(), Some(1));
    let _ = std::fs::remove_file(&path);
}

/// Waits until `path` holds at least `bytes` bytes, or `timeout` passes.
fn wait_for_size(path: &Path, bytes: u64, timeout: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if std::fs::metadata(path).is_ok_and(|m| m.len() >= bytes) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    false
}

#[test]
fn a_logger_killed_mid_run_leaves_a_file_that_log_check_accepts() {
    let _stack = one_stack_at_a_time();
    let path = out_path("killed");
    let prefix = format!("motme2e{}_mcapkill_", std::process::id());
    // motm_command builds the whole stack, the logger included, before the run starts.
    let mut run = motm_command(
        &["run", "--json", "--mcap", path.to_str().unwrap()],
        &prefix,
    )
    .stdout(Stdio::null())
    .stderr(Stdio::null())
    .spawn()
    .expect("motm run");
    // Whole chunks (512 kB, or whatever a second brought) are written within seconds: the
    // camera alone is ~1.4 MB/s.
    let grew = wait_for_size(&path, 3 << 19, Duration::from_secs(120));
    let needle = format!("--out {}", path.display());
    let loggers: Vec<u32> = processes_mentioning(path.to_str().unwrap())
        .into_iter()
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|c| {
                String::from_utf8_lossy(&c)
                    .replace('\0', " ")
                    .contains(&needle)
            })
        })
        .collect();
    for pid in &loggers {
        // SAFETY: kill(2) has no memory-safety preconditions; the pid is our logger child.
        unsafe {
            libc::kill(*pid as libc::pid_t, libc::SIGKILL);
        }
    }
    // The run goes on without its logger and reports it (exit 1); wait for it to end.
    let _ = run.wait();
    assert!(grew, "the log never reached 1.5 MB");
    assert_eq!(loggers.len(), 1, "expected one logger process");
    assert!(
        processes_mentioning(&prefix).is_empty(),
        "the run left processes"
    );

    let check = motm(&["log", "check", path.to_str().unwrap()], &prefix);
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        check.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&check.stderr)
    );
    assert!(text.contains("incomplete"), "{text}");
    let info = motm(&["log", "info", "--json", path.to_str().unwrap()], &prefix);
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("info JSON");
    assert_eq!(info["complete"], false);
    assert!(info["messages"].as_u64().unwrap() > 1000, "{info}");
    assert!(info["chunks"].as_u64().unwrap() >= 2, "{info}");
    let _ = std::fs::remove_file(&path);
}
