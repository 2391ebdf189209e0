//! `motm trial --mcap FILE` writes the replay log of an in-process MotM trial, and `motm run
//! --mcap FILE` has the logger write one from the running stack; `motm replay FILE [--task
//! NAME] [--config FILE] [--json]` feeds either's logged inputs through the same tasks (with
//! the gains of `--config`, if given) and reports, per task, the cycles replayed and the first
//! cycle whose output differs.
//!
//! The log format is [`motm_logger::replay_log`]'s: raw payload channels, one JSON record per
//! task cycle, and the trial's description.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use clap::Args;
use motm_graph::replay::RawSample;
use motm_graph::{Consumed, CycleRecord, TopicSpec};
use motm_logger::replay_log::{
    CYCLES_TOPIC, CycleJson, RAW_ENCODING, SampleJson, TRIAL_TOPIC, TrialInfo, raw_channel,
    raw_topic,
};
use motm_sim::experiment::TrialLog;
use motm_sim::replay::replay_log;

use crate::CliError;

fn refs(list: &[Consumed]) -> Vec<SampleJson> {
    list.iter()
        .map(|c| (c.topic.to_owned(), c.seq, c.stamp_ns))
        .collect()
}

/// The graph's topic named `topic`, from `topics` (every logged topic is one of the graph's).
fn graph_topic(topics: &[TopicSpec], topic: &str) -> Option<TopicSpec> {
    topics.iter().find(|t| t.name == topic).copied()
}

/// Reads a header field (`u64` at `offset`) of a raw sample of `topic`.
fn header_u64(topic: &str, bytes: &[u8], offset: usize) -> Result<u64, String> {
    bytes
        .get(offset..offset + 8)
        .and_then(|b| b.try_into().ok())
        .map(u64::from_le_bytes)
        .ok_or_else(|| format!("{topic}: a sample shorter than its header"))
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
                    .add_channel(
                        schema,
                        &raw_channel(sample.topic),
                        RAW_ENCODING,
                        &no_metadata,
                    )
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
            pid: 0,
            cycle: record.cycle,
            now_ns: record.now_ns,
            truncated: false,
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

/// A replay log read back: the trial, its samples and cycle records, and the process of each
/// cycle record (0 for every cycle of an in-process log).
pub struct ReadLog {
    /// The trial.
    pub info: TrialInfo,
    /// Samples and cycle records.
    pub log: TrialLog,
    /// The pid of each of `log.cycles`.
    pub pids: Vec<u32>,
    /// Cycle records that lost samples (more than a record holds).
    pub truncated: u64,
}

/// Reads a replay log: written by [`write_log`] (`motm trial --mcap`) or by the logger of a
/// running stack (`motm run --mcap`).
pub fn read_log(path: &Path) -> Result<ReadLog, String> {
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let bytes = std::fs::read(path).map_err(|e| fail(&e))?;
    let topics = motm_graph::published_topics();
    let static_topic = |topic: &str| graph_topic(&topics, topic).map(|t| t.name);
    let mut info = None;
    let mut log = TrialLog::default();
    let mut pids = Vec::new();
    let mut truncated = 0;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| fail(&e))?;
    for message in stream {
        let message = message.map_err(|e| fail(&e))?;
        let channel = message.channel.topic.as_str();
        if channel == TRIAL_TOPIC {
            info = Some(serde_json::from_slice(&message.data).map_err(|e| fail(&e))?);
        } else if channel == CYCLES_TOPIC {
            let c: CycleJson = serde_json::from_slice(&message.data).map_err(|e| fail(&e))?;
            let task = motm_graph::task(&c.task)
                .ok_or_else(|| fail(&format!("cycle record of unknown task '{}'", c.task)))?
                .name;
            let list = |refs: Vec<SampleJson>| -> Result<Vec<Consumed>, String> {
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
            truncated += u64::from(c.truncated);
            pids.push(c.pid);
            log.cycles.push(CycleRecord {
                task,
                cycle: c.cycle,
                now_ns: c.now_ns,
                consumed: list(c.consumed)?,
                produced: list(c.produced)?,
            });
        } else if message.channel.message_encoding == RAW_ENCODING {
            // Samples of services outside the graph (heartbeats, swap requests) feed no task.
            let Some(topic) = static_topic(raw_topic(channel).unwrap_or(channel)) else {
                continue;
            };
            let data = &message.data;
            log.samples.push(RawSample {
                topic,
                seq: header_u64(topic, data, 8).map_err(|e| fail(&e))?,
                stamp_ns: header_u64(topic, data, 0).map_err(|e| fail(&e))?,
                bytes: data.to_vec(),
            });
        }
    }
    let info = info.ok_or_else(|| {
        fail(&"no trial description: not a replay log (`motm trial --mcap`, `motm run --mcap`)")
    })?;
    Ok(ReadLog {
        info,
        log,
        pids,
        truncated,
    })
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
    let ReadLog {
        info,
        log,
        pids,
        truncated,
    } = read_log(&args.log).map_err(CliError::BadInput)?;
    if truncated > 0 {
        motm_bus::say!("motm replay: {truncated} cycle records lost samples that did not fit");
    }
    let scenario_arg = info.scenario.to_string_lossy().into_owned();
    let (robot, scenario) =
        crate::trial::load(config_dir, &scenario_arg, Some(info.base_speed), info.seed)?;
    // The gains to replay with: `--config`, else the ones the trial ran with by default.
    let config = crate::trial::runner_config(config_dir, args.config.as_deref())?;
    let tasks = replay_log(
        &robot,
        &scenario,
        info.seed,
        &config,
        &log,
        &pids,
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
