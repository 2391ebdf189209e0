//! `motm trial --mcap FILE` writes the replay log of an in-process MotM trial; `motm replay FILE
//! [--task NAME] [--config FILE] [--json]` feeds its logged inputs through the same tasks
//! (with the gains of `--config`, if given) and reports, per task, the cycles replayed and the
//! first cycle whose output differs.
//!
//! Log format (MCAP): one channel per topic (`message_encoding` `motm-raw-v1`, schema name the
//! payload type; each message the payload's `#[repr(C)]` bytes), one JSON channel
//! `motm/replay/cycles` (one message per task cycle: task, cycle, time, the consumed and the
//! produced samples as `[topic, seq, stamp_ns]`), and one JSON message on `motm/replay/trial`
//! (scenario, seed, base speed): what replay needs to build the same tasks.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use clap::Args;
use motm_graph::replay::RawSample;
use motm_graph::{Consumed, CycleRecord, TopicSpec};
use motm_sim::experiment::TrialLog;
use motm_sim::replay::replay_log;
use serde::{Deserialize, Serialize};

use crate::CliError;

/// Channel of the cycle records.
const CYCLES_TOPIC: &str = "motm/replay/cycles";
/// Channel of the trial description.
const TRIAL_TOPIC: &str = "motm/replay/trial";
/// Message encoding of the raw payload channels.
const RAW_ENCODING: &str = "motm-raw-v1";

/// What replay needs to build the trial's tasks again.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrialInfo {
    /// Scenario file.
    pub scenario: PathBuf,
    /// Seed.
    pub seed: u64,
    /// Base speed, m/s.
    pub base_speed: f64,
}

/// A cycle record as JSON.
#[derive(Serialize, Deserialize)]
struct CycleJson {
    task: String,
    cycle: u64,
    now_ns: u64,
    consumed: Vec<(String, u64, u64)>,
    produced: Vec<(String, u64, u64)>,
}

fn refs(list: &[Consumed]) -> Vec<(String, u64, u64)> {
    list.iter()
        .map(|c| (c.topic.to_owned(), c.seq, c.stamp_ns))
        .collect()
}

/// The graph's topic named `topic`, from `topics` (every logged topic is one of the graph's).
fn graph_topic(topics: &[TopicSpec], topic: &str) -> Option<TopicSpec> {
    topics.iter().find(|t| t.name == topic).copied()
}

/// Writes `log` of the trial `info` to `path`.
pub fn write_log(path: &Path, info: &TrialInfo, log: &TrialLog) -> Result<(), String> {
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let file = std::fs::File::create(path).map_err(|e| fail(&e))?;
    let mut writer = mcap::Writer::new(std::io::BufWriter::new(file)).map_err(|e| fail(&e))?;
    let topics = motm_graph::published_topics();
    let mut channels: BTreeMap<&str, u16> = BTreeMap::new();
    let no_metadata = BTreeMap::new();
    let json_channel = |writer: &mut mcap::Writer<_>, topic: &str| -> Result<u16, String> {
        writer
            .add_channel(0, topic, "json", &no_metadata)
            .map_err(|e| fail(&e))
    };
    let trial = json_channel(&mut writer, TRIAL_TOPIC)?;
    let cycles = json_channel(&mut writer, CYCLES_TOPIC)?;
    let header = |channel_id: u16, sequence: u32, time: u64| mcap::records::MessageHeader {
        channel_id,
        sequence,
        log_time: time,
        publish_time: time,
    };
    let info_json = serde_json::to_vec(info).map_err(|e| fail(&e))?;
    writer
        .write_to_known_channel(&header(trial, 0, 0), &info_json)
        .map_err(|e| fail(&e))?;
    for sample in &log.samples {
        let channel = match channels.get(sample.topic) {
            Some(id) => *id,
            None => {
                let type_name =
                    graph_topic(&topics, sample.topic).map_or("unknown", |t| t.type_name);
                let schema = writer
                    .add_schema(type_name, "", &[])
                    .map_err(|e| fail(&e))?;
                let id = writer
                    .add_channel(schema, sample.topic, RAW_ENCODING, &no_metadata)
                    .map_err(|e| fail(&e))?;
                channels.insert(sample.topic, id);
                id
            }
        };
        writer
            .write_to_known_channel(
                &header(channel, sample.seq as u32, sample.stamp_ns),
                &sample.bytes,
            )
            .map_err(|e| fail(&e))?;
    }
    for (i, record) in log.cycles.iter().enumerate() {
        let json = serde_json::to_vec(&CycleJson {
            task: record.task.to_owned(),
            cycle: record.cycle,
            now_ns: record.now_ns,
            consumed: refs(&record.consumed),
            produced: refs(&record.produced),
        })
        .map_err(|e| fail(&e))?;
        writer
            .write_to_known_channel(&header(cycles, i as u32, record.now_ns), &json)
            .map_err(|e| fail(&e))?;
    }
    writer.finish().map_err(|e| fail(&e))?;
    Ok(())
}

/// Reads a log written by [`write_log`].
pub fn read_log(path: &Path) -> Result<(TrialInfo, TrialLog), String> {
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let bytes = std::fs::read(path).map_err(|e| fail(&e))?;
    let topics = motm_graph::published_topics();
    let static_topic = |topic: &str| graph_topic(&topics, topic).map(|t| t.name);
    let mut info = None;
    let mut log = TrialLog::default();
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| fail(&e))?;
    for message in stream {
        let message = message.map_err(|e| fail(&e))?;
        let topic = message.channel.topic.as_str();
        if topic == TRIAL_TOPIC {
            info = Some(serde_json::from_slice(&message.data).map_err(|e| fail(&e))?);
        } else if topic == CYCLES_TOPIC {
            let c: CycleJson = serde_json::from_slice(&message.data).map_err(|e| fail(&e))?;
            let task = motm_graph::task(&c.task)
                .ok_or_else(|| fail(&format!("cycle record of unknown task '{}'", c.task)))?
                .name;
            let list = |refs: Vec<(String, u64, u64)>| -> Result<Vec<Consumed>, String> {
                refs.into_iter()
                    .map(|(topic, seq, stamp_ns)| {
                        Ok(Consumed {
                            topic: static_topic(&topic)
                                .ok_or_else(|| fail(&format!("unknown topic '{topic}'")))?,
                            seq,
                            stamp_ns,
                        })
                    })
                    .collect()
            };
            log.cycles.push(CycleRecord {
                task,
                cycle: c.cycle,
                now_ns: c.now_ns,
                consumed: list(c.consumed)?,
                produced: list(c.produced)?,
            });
        } else if message.channel.message_encoding == RAW_ENCODING {
            let topic =
                static_topic(topic).ok_or_else(|| fail(&format!("unknown topic '{topic}'")))?;
            let seq = u64::from_le_bytes(
                message
                    .data
                    .get(8..16)
                    .and_then(|b| b.try_into().ok())
                    .ok_or_else(|| fail(&format!("{topic}: a sample shorter than its header")))?,
            );
            log.samples.push(RawSample {
                topic,
                seq,
                stamp_ns: message.log_time,
                bytes: message.data.to_vec(),
            });
        }
    }
    let info = info.ok_or_else(|| fail(&"no trial description: not a `motm trial --mcap` log"))?;
    Ok((info, log))
}

/// Arguments of `motm replay`.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The log (`motm trial --mcap`).
    pub log: PathBuf,
    /// Replay only this task.
    #[arg(long)]
    pub task: Option<String>,
    /// Controller gains (a controllers file, as `config/controllers.toml`) to replay with
    /// (default: that file, the gains `motm trial` runs with).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `motm replay`.
pub fn run(config_dir: &Path, args: &ReplayArgs) -> Result<(), CliError> {
    let (info, log) = read_log(&args.log).map_err(CliError::BadInput)?;
    let scenario_arg = info.scenario.to_string_lossy().into_owned();
    let (robot, scenario) = crate::trial::load(config_dir, &scenario_arg, Some(info.base_speed))?;
    // The gains to replay with: `--config`, else the ones the trial ran with by default.
    let config = crate::trial::runner_config(config_dir, args.config.as_deref())?;
    let tasks = replay_log(
        &robot,
        &scenario,
        info.seed,
        &config,
        &log,
        args.task.as_deref(),
    )
    .map_err(CliError::BadInput)?;
    if args.json {
        let json = serde_json::json!({ "tasks": tasks });
        println!("{json}");
    } else {
        for task in &tasks {
            print!(
                "{:<13} {:>6} cycles, {:>6} differing",
                task.name, task.cycles, task.differing_cycles
            );
            match &task.first_difference {
                None => println!(),
                Some(d) => println!(
                    "; first at cycle {} (t = {:.3} s): {} {}: logged {}, replayed {}",
                    d.cycle,
                    d.now_ns as f64 * 1e-9,
                    d.topic,
                    d.field,
                    d.logged,
                    d.replayed
                ),
            }
        }
    }
    Ok(())
}
