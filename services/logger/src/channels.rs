//! The step shared by every sink (the MCAP file, the live WebSocket view): one channel per
//! topic, made on its first record (with the foxglove schema, or a jsonschema inferred from the
//! first JSON message), and each record encoded once into the bytes and times every sink sends.
//!
//! Log times are the records' own stamps moved from `CLOCK_MONOTONIC` to Unix time by one
//! offset taken at start (so Foxglove shows wall-clock times and the spacing of the samples is
//! exactly theirs). A stamp earlier than the channel's previous one (a restarted publisher
//! whose first sample predates the last one logged) is raised to it, so log times never
//! decrease within a channel; such raises are counted, and the publish time keeps the sample's
//! own stamp.

use std::borrow::Cow;
use std::collections::HashMap;

use crate::json::schema_of;
use crate::recorder::{Payload, Record};

/// Message encoding of the protobuf channels (MCAP and Foxglove WebSocket name).
pub const PROTOBUF: &str = "protobuf";
/// Message encoding of the JSON channels.
pub const JSON: &str = "json";
/// Schema encoding of the JSON channels' schemas.
pub const JSONSCHEMA: &str = "jsonschema";

/// A channel: its topic, how its messages are encoded and the schema that decodes them.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// Channel id, `0, 1, 2, …` in order of first record.
    pub id: u16,
    /// Topic.
    pub topic: String,
    /// Message encoding: [`PROTOBUF`] or [`JSON`].
    pub message_encoding: &'static str,
    /// Schema name: the foxglove message name, or the topic for a JSON channel.
    pub schema_name: String,
    /// Schema encoding: [`PROTOBUF`] (a `FileDescriptorSet`) or [`JSONSCHEMA`].
    pub schema_encoding: &'static str,
    /// Schema bytes: the serialized `FileDescriptorSet`, or the jsonschema text.
    pub schema: Cow<'static, [u8]>,
}

/// One record, encoded for the sinks.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedMessage<'a> {
    /// Its channel.
    pub channel: &'a ChannelInfo,
    /// Sequence number within the channel, from 1.
    pub sequence: u32,
    /// Log time (Unix, ns), never less than the channel's previous one.
    pub log_time_ns: u64,
    /// The sample's own stamp in Unix time, ns.
    pub publish_time_ns: u64,
    /// The message bytes (protobuf, or JSON text).
    pub data: Cow<'a, [u8]>,
}

/// A channel with its running state.
struct ChannelState {
    info: ChannelInfo,
    sequence: u32,
    last_log_time_ns: u64,
}

/// Every channel seen so far, by topic.
pub struct ChannelRegistry {
    channels: Vec<ChannelState>,
    by_topic: HashMap<String, usize>,
    /// Added to a monotonic stamp to get Unix time, ns.
    unix_offset_ns: i128,
    /// Records whose stamp was raised to keep the channel's log times non-decreasing.
    pub raised_stamps: u64,
    /// Records encoded.
    pub encoded: u64,
}

impl ChannelRegistry {
    /// No channels yet; `unix_offset_ns` moves monotonic stamps to Unix time.
    pub fn new(unix_offset_ns: i128) -> Self {
        Self {
            channels: Vec::new(),
            by_topic: HashMap::new(),
            unix_offset_ns,
            raised_stamps: 0,
            encoded: 0,
        }
    }

    /// Unix minus monotonic time, ns: what moves a sample's stamp to its log time.
    pub fn unix_offset_ns(&self) -> i128 {
        self.unix_offset_ns
    }

    /// Encodes `record`, making its channel when it is the topic's first.
    pub fn encode<'a>(&'a mut self, record: &'a Record) -> EncodedMessage<'a> {
        let unix_ns = (i128::from(record.stamp_ns) + self.unix_offset_ns).max(0) as u64;
        let index = match self.by_topic.get(&record.topic) {
            Some(&index) => index,
            None => {
                let index = self.channels.len();
                self.channels.push(ChannelState {
                    info: channel_of(index as u16, record),
                    sequence: 0,
                    last_log_time_ns: 0,
                });
                self.by_topic.insert(record.topic.clone(), index);
                index
            }
        };
        let channel = &mut self.channels[index];
        let log_time_ns = if unix_ns < channel.last_log_time_ns {
            self.raised_stamps += 1;
            channel.last_log_time_ns
        } else {
            unix_ns
        };
        channel.last_log_time_ns = log_time_ns;
        channel.sequence = channel.sequence.wrapping_add(1);
        self.encoded += 1;
        EncodedMessage {
            channel: &channel.info,
            sequence: channel.sequence,
            log_time_ns,
            publish_time_ns: unix_ns,
            data: match &record.payload {
                Payload::Protobuf(_, bytes) => Cow::Borrowed(bytes.as_slice()),
                Payload::Json(value) => Cow::Owned(value.to_string().into_bytes()),
                Payload::Raw(_, bytes) => Cow::Borrowed(bytes.as_slice()),
            },
        }
    }

    /// The channels, in id order.
    pub fn channels(&self) -> impl Iterator<Item = &ChannelInfo> {
        self.channels.iter().map(|c| &c.info)
    }
}

/// The channel `id` of `record`'s topic, with the schema of its payload.
fn channel_of(id: u16, record: &Record) -> ChannelInfo {
    match &record.payload {
        Payload::Protobuf(schema, _) => ChannelInfo {
            id,
            topic: record.topic.clone(),
            message_encoding: PROTOBUF,
            schema_name: schema.name.to_owned(),
            schema_encoding: PROTOBUF,
            schema: Cow::Borrowed(schema.descriptor),
        },
        Payload::Raw(type_name, _) => ChannelInfo {
            id,
            topic: record.topic.clone(),
            message_encoding: crate::replay_log::RAW_ENCODING,
            schema_name: (*type_name).to_owned(),
            schema_encoding: "",
            schema: Cow::Borrowed(&[]),
        },
        Payload::Json(value) => {
            let mut schema = schema_of(value);
            schema["title"] = record.topic.clone().into();
            ChannelInfo {
                id,
                topic: record.topic.clone(),
                message_encoding: JSON,
                schema_name: record.topic.clone(),
                schema_encoding: JSONSCHEMA,
                schema: Cow::Owned(schema.to_string().into_bytes()),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::foxglove as fg;

    fn json_record(topic: &str, stamp_ns: u64) -> Record {
        Record {
            topic: topic.into(),
            stamp_ns,
            payload: Payload::Json(serde_json::json!({ "x": 1.5 })),
        }
    }

    #[test]
    fn channels_are_made_once_per_topic_with_their_schema() {
        let mut registry = ChannelRegistry::new(1_000);
        let pose = Record {
            topic: "/pose".into(),
            stamp_ns: 5,
            payload: Payload::Protobuf(fg::POSE_IN_FRAME, vec![1, 2]),
        };
        let first = registry.encode(&pose);
        assert_eq!((first.channel.id, first.sequence), (0, 1));
        assert_eq!(first.channel.schema_name, "foxglove.PoseInFrame");
        assert_eq!(first.channel.schema.as_ref(), fg::POSE_IN_FRAME.descriptor);
        assert_eq!(first.log_time_ns, 1_005);
        assert_eq!(first.data.as_ref(), &[1, 2]);
        let plot = json_record("/plot", 7);
        let json = registry.encode(&plot);
        assert_eq!(json.channel.id, 1);
        assert_eq!(json.channel.message_encoding, JSON);
        let schema: serde_json::Value = serde_json::from_slice(&json.channel.schema).unwrap();
        assert_eq!(schema["properties"]["x"]["type"], "number");
        assert_eq!(schema["title"], "/plot");
        assert_eq!(json.data.as_ref(), br#"{"x":1.5}"#);
        let again = registry.encode(&pose);
        assert_eq!((again.channel.id, again.sequence), (0, 2));
        assert_eq!(registry.channels().count(), 2);
        assert_eq!(registry.encoded, 3);
    }

    #[test]
    fn an_earlier_stamp_is_raised_to_the_channels_last_log_time_and_counted() {
        let mut registry = ChannelRegistry::new(0);
        assert_eq!(registry.encode(&json_record("/a", 100)).log_time_ns, 100);
        let record = json_record("/a", 40);
        let late = registry.encode(&record);
        assert_eq!((late.log_time_ns, late.publish_time_ns), (100, 40));
        // Another channel keeps its own times.
        assert_eq!(registry.encode(&json_record("/b", 40)).log_time_ns, 40);
        assert_eq!(registry.raised_stamps, 1);
    }
}
