//! The replay log: what `motm replay` needs beside the views, in the same MCAP file.
//!
//! - One channel per topic, `/replay/<topic>`, with message encoding [`RAW_ENCODING`] and the
//!   payload type as schema name: every sample's `#[repr(C)]` bytes, header included.
//! - [`CYCLES_TOPIC`], JSON: one [`CycleJson`] per task cycle (task, process id, cycle, time,
//!   and the consumed and produced samples as `[topic, seq, stamp_ns]`).
//! - [`TRIAL_TOPIC`], JSON: one [`TrialInfo`], what replay needs to build the same tasks.
//!
//! `motm trial --mcap` writes such a log from the in-process scheduler; the logger writes one
//! from a running stack (`logger --replay`, which `motm run --mcap` passes), turning each
//! [`msgs::TaskCycle`]'s indices into names with the stack's own tables.

use std::path::PathBuf;

use motm_msgs as msgs;
use serde::{Deserialize, Serialize};

/// Message encoding of the raw payload channels.
pub const RAW_ENCODING: &str = "motm-raw-v1";
/// Channel of the cycle records.
pub const CYCLES_TOPIC: &str = "/replay/cycles";
/// Channel of the trial description.
pub const TRIAL_TOPIC: &str = "/replay/trial";
/// Prefix of the raw payload channels.
const RAW_PREFIX: &str = "/replay/";

/// The raw payload channel of `topic`.
pub fn raw_channel(topic: &str) -> String {
    format!("{RAW_PREFIX}{topic}")
}

/// The topic of raw payload channel `channel`, if it is one.
pub fn raw_topic(channel: &str) -> Option<&str> {
    channel.strip_prefix(RAW_PREFIX)
}

/// What replay needs to build the trial's tasks again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialInfo {
    /// Scenario file.
    pub scenario: PathBuf,
    /// Seed.
    pub seed: u64,
    /// Base speed, m/s.
    pub base_speed: f64,
}

/// One sample of a cycle record: `(topic, seq, stamp_ns)`.
pub type SampleJson = (String, u64, u64);

/// One task cycle, as written to [`CYCLES_TOPIC`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CycleJson {
    /// The task.
    pub task: String,
    /// The process that ran it (0 in the in-process form, where every task is one instance).
    #[serde(default)]
    pub pid: u32,
    /// The task's cycle number.
    pub cycle: u64,
    /// The cycle's time, ns.
    pub now_ns: u64,
    /// Whether the record lost samples that did not fit.
    #[serde(default)]
    pub truncated: bool,
    /// The samples the cycle's inputs held.
    pub consumed: Vec<SampleJson>,
    /// The samples the cycle published.
    pub produced: Vec<SampleJson>,
}

impl CycleJson {
    /// The record of `cycle`, with task names `tasks` and topic names `topics` (the stack's
    /// graph table and published topics, whose indices the record carries); an error names
    /// an index that is not in them.
    pub fn from_message(
        cycle: &msgs::TaskCycle,
        tasks: &[&str],
        topics: &[&str],
    ) -> Result<Self, String> {
        let list = |samples: &[msgs::SampleRef]| -> Result<Vec<SampleJson>, String> {
            samples
                .iter()
                .map(|s| {
                    let topic = topics.get(s.topic as usize).ok_or_else(|| {
                        format!("TaskCycle.samples.topic: unknown topic index {}", s.topic)
                    })?;
                    Ok(((*topic).to_owned(), s.seq, s.stamp_ns))
                })
                .collect()
        };
        Ok(Self {
            task: tasks
                .get(cycle.task as usize)
                .ok_or_else(|| format!("TaskCycle.task: unknown task index {}", cycle.task))?
                .to_string(),
            pid: cycle.pid,
            cycle: cycle.cycle,
            now_ns: cycle.now_ns,
            truncated: cycle.truncated == 1,
            consumed: list(cycle.consumed())?,
            produced: list(cycle.produced())?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::Message;

    #[test]
    fn a_task_cycle_becomes_names_and_a_bad_index_is_named() {
        let mut m = msgs::TaskCycle::zeroed();
        m.task = 1;
        m.pid = 42;
        m.cycle = 7;
        m.now_ns = 9;
        m.consumed = 1;
        m.produced = 1;
        m.samples[0] = msgs::SampleRef {
            topic: 0,
            reserved: 0,
            seq: 3,
            stamp_ns: 4,
        };
        m.samples[1] = msgs::SampleRef {
            topic: 1,
            reserved: 0,
            seq: 5,
            stamp_ns: 6,
        };
        let json = CycleJson::from_message(&m, &["a", "b"], &["x", "y"]).unwrap();
        assert_eq!(json.task, "b");
        assert_eq!((json.pid, json.cycle, json.now_ns), (42, 7, 9));
        assert_eq!(json.consumed, vec![("x".to_owned(), 3, 4)]);
        assert_eq!(json.produced, vec![("y".to_owned(), 5, 6)]);
        let text = serde_json::to_string(&json).unwrap();
        assert_eq!(serde_json::from_str::<CycleJson>(&text).unwrap(), json);
        m.samples[1].topic = 9;
        let err = CycleJson::from_message(&m, &["a", "b"], &["x", "y"]).unwrap_err();
        assert!(err.contains("topic index 9"), "{err}");
        assert_eq!(raw_topic(&raw_channel("motm/v1/a")), Some("motm/v1/a"));
    }
}
