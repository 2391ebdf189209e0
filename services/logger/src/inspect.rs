//! Reading an MCAP log back: a record-by-record scan that tells a complete file from one whose
//! writer was killed (it stops at the last whole record and reports the cut-off tail), checks
//! chunk CRCs, decodes every protobuf message with the schema stored in the file and parses
//! every JSON message, and sums up channels, schemas, message counts and time ranges. This is
//! `motm log info` and `motm log check`.

use std::collections::BTreeMap;

use mcap::records::Record;
use serde_json::Value;

use crate::protobuf_check::SchemaDecoder;

/// One channel of a log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChannelSummary {
    /// Channel id.
    pub id: u16,
    /// Topic.
    pub topic: String,
    /// Message encoding (`protobuf`, `json`).
    pub message_encoding: String,
    /// Schema name (empty without a schema).
    pub schema_name: String,
    /// Schema encoding (`protobuf`, `jsonschema`).
    pub schema_encoding: String,
    /// Messages read.
    pub messages: u64,
    /// Earliest log time, ns.
    pub first_log_time_ns: u64,
    /// Latest log time, ns.
    pub last_log_time_ns: u64,
    /// Messages whose log time is earlier than the previous one on the channel.
    pub log_time_decreases: u64,
    /// Messages that did not decode with the channel's schema (or are not valid JSON).
    pub decode_failures: u64,
    /// The first decode failure.
    pub first_failure: Option<String>,
}

/// What a scan of a log found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LogSummary {
    /// Channels by id.
    pub channels: BTreeMap<u16, ChannelSummary>,
    /// Chunks read whole.
    pub chunks: u64,
    /// Whether the file ends with a footer and the closing magic (the writer finished it).
    pub complete: bool,
    /// Bytes after the last whole record of an incomplete file (a record cut off mid-write).
    pub truncated_bytes: u64,
    /// File size, bytes.
    pub file_bytes: u64,
}

impl LogSummary {
    /// Messages over all channels.
    pub fn messages(&self) -> u64 {
        self.channels.values().map(|c| c.messages).sum()
    }

    /// Earliest and latest log time over all channels that have messages, ns.
    pub fn time_range_ns(&self) -> Option<(u64, u64)> {
        let with = || self.channels.values().filter(|c| c.messages > 0);
        Some((
            with().map(|c| c.first_log_time_ns).min()?,
            with().map(|c| c.last_log_time_ns).max()?,
        ))
    }

    /// The channel with topic `topic`.
    pub fn channel(&self, topic: &str) -> Option<&ChannelSummary> {
        self.channels.values().find(|c| c.topic == topic)
    }

    /// Problems that make the log unusable: none means `motm log check` accepts it. A file
    /// cut off by a killed writer is accepted when everything before the cut is sound.
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if self.messages() == 0 {
            problems.push("no messages".to_string());
        }
        for c in self.channels.values() {
            if c.decode_failures > 0 {
                problems.push(format!(
                    "{}: {} message(s) do not decode with schema '{}' ({})",
                    c.topic,
                    c.decode_failures,
                    c.schema_name,
                    c.first_failure.as_deref().unwrap_or("")
                ));
            }
            if c.log_time_decreases > 0 {
                problems.push(format!(
                    "{}: log time decreases {} time(s)",
                    c.topic, c.log_time_decreases
                ));
            }
        }
        problems
    }
}

/// A schema as stored in the file, with its decoder when it is a protobuf schema.
struct StoredSchema {
    name: String,
    encoding: String,
    decoder: Option<Result<SchemaDecoder, String>>,
}

/// Scan state: schemas and channels seen so far.
#[derive(Default)]
struct Scan {
    schemas: BTreeMap<u16, StoredSchema>,
    summary: LogSummary,
    /// Decoders by schema id for channels (looked up per message).
    channel_schema: BTreeMap<u16, u16>,
}

/// Opcode of the MCAP footer record.
const FOOTER_OPCODE: u8 = 0x02;
/// Bytes of a record's opcode and length prefix.
const RECORD_PREFIX: usize = 9;

/// Scans a whole log held in memory. Errors name what is corrupt (bad magic, a record that
/// does not parse, a chunk whose CRC does not match, a message on an unknown channel); a file
/// merely cut off after its last whole record is not an error (see [`LogSummary::complete`]).
pub fn scan(bytes: &[u8]) -> Result<LogSummary, String> {
    let magic = mcap::MAGIC;
    if bytes.len() < magic.len() || &bytes[..magic.len()] != magic {
        return Err("not an MCAP file (bad magic)".into());
    }
    let mut scan = Scan::default();
    scan.summary.file_bytes = bytes.len() as u64;
    let mut pos = magic.len();
    loop {
        let rest = &bytes[pos..];
        if rest.len() < RECORD_PREFIX {
            scan.summary.truncated_bytes = rest.len() as u64;
            break;
        }
        let opcode = rest[0];
        let len = u64::from_le_bytes(rest[1..RECORD_PREFIX].try_into().expect("8 bytes"));
        let Some(end) = usize::try_from(len)
            .ok()
            .and_then(|l| l.checked_add(RECORD_PREFIX))
            .filter(|&end| end <= rest.len())
        else {
            scan.summary.truncated_bytes = rest.len() as u64;
            break;
        };
        let body = &rest[RECORD_PREFIX..end];
        let record = mcap::parse_record(opcode, body)
            .map_err(|e| format!("record at byte {pos} (opcode {opcode:#04x}): {e}"))?;
        scan.record(record, pos)?;
        pos += end;
        if opcode == FOOTER_OPCODE {
            if &bytes[pos..] != magic {
                return Err(format!(
                    "footer at byte {} is not followed by the closing magic",
                    pos - end
                ));
            }
            scan.summary.complete = true;
            break;
        }
    }
    Ok(scan.summary)
}

impl Scan {
    /// Takes in one record at byte `pos` (a record inside a chunk reports its chunk's `pos`).
    fn record(&mut self, record: Record<'_>, pos: usize) -> Result<(), String> {
        match record {
            Record::Schema { header, .. } if self.schemas.contains_key(&header.id) => {}
            Record::Schema { header, data } => {
                let decoder = (header.encoding == "protobuf")
                    .then(|| SchemaDecoder::new(&header.name, &data));
                self.schemas.insert(
                    header.id,
                    StoredSchema {
                        name: header.name,
                        encoding: header.encoding,
                        decoder,
                    },
                );
            }
            // The summary section repeats the channels (and schemas): keep the first ones.
            Record::Channel(channel) if self.summary.channels.contains_key(&channel.id) => {}
            Record::Channel(channel) => {
                let schema = self.schemas.get(&channel.schema_id);
                self.channel_schema.insert(channel.id, channel.schema_id);
                self.summary.channels.insert(
                    channel.id,
                    ChannelSummary {
                        id: channel.id,
                        topic: channel.topic,
                        message_encoding: channel.message_encoding,
                        schema_name: schema.map(|s| s.name.clone()).unwrap_or_default(),
                        schema_encoding: schema.map(|s| s.encoding.clone()).unwrap_or_default(),
                        ..ChannelSummary::default()
                    },
                );
            }
            Record::Message { header, data } => {
                let schema = self
                    .channel_schema
                    .get(&header.channel_id)
                    .and_then(|id| self.schemas.get(id));
                let Some(channel) = self.summary.channels.get_mut(&header.channel_id) else {
                    return Err(format!(
                        "message at byte {pos} on unknown channel {}",
                        header.channel_id
                    ));
                };
                let result = match (channel.message_encoding.as_str(), schema) {
                    (
                        "protobuf",
                        Some(StoredSchema {
                            decoder: Some(d), ..
                        }),
                    ) => d
                        .as_ref()
                        .map_err(Clone::clone)
                        .and_then(|d| d.decode(&data).map(|_| ())),
                    ("protobuf", _) => Err("protobuf channel without a protobuf schema".into()),
                    ("json", _) => serde_json::from_slice::<Value>(&data)
                        .map(|_| ())
                        .map_err(|e| format!("not JSON: {e}")),
                    _ => Ok(()),
                };
                if let Err(e) = result {
                    channel.decode_failures += 1;
                    channel.first_failure.get_or_insert(e);
                }
                if channel.messages == 0 {
                    channel.first_log_time_ns = header.log_time;
                } else if header.log_time < channel.last_log_time_ns {
                    channel.log_time_decreases += 1;
                }
                channel.first_log_time_ns = channel.first_log_time_ns.min(header.log_time);
                channel.last_log_time_ns = channel.last_log_time_ns.max(header.log_time);
                channel.messages += 1;
            }
            Record::Chunk { header, data } => {
                if header.compression.is_empty()
                    && header.uncompressed_crc != 0
                    && crc32fast::hash(&data) != header.uncompressed_crc
                {
                    return Err(format!("chunk at byte {pos}: CRC mismatch"));
                }
                let reader = mcap::read::ChunkReader::new(header, &data)
                    .map_err(|e| format!("chunk at byte {pos}: {e}"))?;
                for inner in reader {
                    let inner = inner.map_err(|e| format!("chunk at byte {pos}: {e}"))?;
                    self.record(inner, pos)?;
                }
                self.summary.chunks += 1;
            }
            _ => {}
        }
        Ok(())
    }
}

/// Human-readable `motm log info` text for `summary` of file `name`.
pub fn info_text(name: &str, summary: &LogSummary) -> String {
    let mut out = format!(
        "{name}: {} bytes, {} chunk(s), {} message(s), {}\n",
        summary.file_bytes,
        summary.chunks,
        summary.messages(),
        if summary.complete {
            "complete".to_string()
        } else {
            format!(
                "incomplete (writer stopped early; {} byte(s) after the last whole record)",
                summary.truncated_bytes
            )
        }
    );
    if let Some((start, end)) = summary.time_range_ns() {
        out += &format!(
            "time range: {:.3} .. {:.3} s (Unix time), {:.3} s\n",
            start as f64 / 1e9,
            end as f64 / 1e9,
            (end - start) as f64 / 1e9
        );
    }
    out += &format!(
        "{:<44} {:<10} {:<26} {:>8} {:>9}\n",
        "channel", "encoding", "schema", "messages", "span s"
    );
    for c in summary.channels.values() {
        out += &format!(
            "{:<44} {:<10} {:<26} {:>8} {:>9.3}\n",
            c.topic,
            c.message_encoding,
            c.schema_name,
            c.messages,
            c.last_log_time_ns.saturating_sub(c.first_log_time_ns) as f64 / 1e9
        );
    }
    out
}

/// The summary as one JSON object (`motm log info --json`).
pub fn info_json(summary: &LogSummary) -> Value {
    let channels: Vec<Value> = summary
        .channels
        .values()
        .map(|c| {
            serde_json::json!({
                "id": c.id,
                "topic": c.topic,
                "message_encoding": c.message_encoding,
                "schema": c.schema_name,
                "schema_encoding": c.schema_encoding,
                "messages": c.messages,
                "first_log_time_ns": c.first_log_time_ns,
                "last_log_time_ns": c.last_log_time_ns,
                "log_time_decreases": c.log_time_decreases,
                "decode_failures": c.decode_failures,
            })
        })
        .collect();
    let (start, end) = summary.time_range_ns().unwrap_or((0, 0));
    serde_json::json!({
        "file_bytes": summary.file_bytes,
        "complete": summary.complete,
        "truncated_bytes": summary.truncated_bytes,
        "chunks": summary.chunks,
        "messages": summary.messages(),
        "start_ns": start,
        "end_ns": end,
        "channels": channels,
        "problems": summary.problems(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channels::ChannelRegistry;
    use crate::foxglove as fg;
    use crate::recorder::{Payload, Record};
    use crate::sink::McapSink;
    use prost::Message as _;

    /// A finished log of `n` pose records and `n` JSON records, in chunks of about 2 kB.
    fn log(n: u64) -> Vec<u8> {
        let mut sink = McapSink::new(std::io::Cursor::new(Vec::new()), 2048, 1.0).unwrap();
        let mut channels = ChannelRegistry::new(1_000);
        for i in 0..n {
            let pose = fg::PoseInFrame {
                timestamp: Some(fg::Timestamp::from_ns(i)),
                frame_id: "world".into(),
                pose: None,
            };
            let records = [
                Record {
                    topic: "/pose".into(),
                    stamp_ns: 1_000 * i,
                    payload: Payload::Protobuf(fg::POSE_IN_FRAME, pose.encode_to_vec()),
                },
                Record {
                    topic: "/plot".into(),
                    stamp_ns: 1_000 * i,
                    payload: Payload::Json(serde_json::json!({ "i": i })),
                },
            ];
            for record in &records {
                sink.write(&channels.encode(record)).unwrap();
            }
        }
        sink.finish().unwrap().into_inner()
    }

    #[test]
    fn a_finished_log_is_complete_with_every_message_decoded() {
        let bytes = log(200);
        let summary = scan(&bytes).unwrap();
        assert!(summary.complete);
        assert_eq!(summary.truncated_bytes, 0);
        assert!(summary.chunks > 2, "{summary:?}");
        let pose = summary.channel("/pose").unwrap();
        assert_eq!(pose.messages, 200);
        assert_eq!(pose.schema_name, "foxglove.PoseInFrame");
        assert_eq!(pose.first_log_time_ns, 1_000);
        assert_eq!(pose.last_log_time_ns, 1_000 + 199_000);
        assert_eq!(
            summary.channel("/plot").unwrap().schema_encoding,
            "jsonschema"
        );
        assert!(summary.problems().is_empty(), "{:?}", summary.problems());
    }

    #[test]
    fn a_cut_off_log_is_read_up_to_its_last_whole_chunk() {
        let bytes = log(200);
        let whole = scan(&bytes).unwrap().messages();
        // Cut in the middle of the data section, as a killed writer leaves it.
        let cut = &bytes[..bytes.len() / 2];
        let summary = scan(cut).unwrap();
        assert!(!summary.complete);
        assert!(summary.truncated_bytes > 0);
        assert!(summary.messages() > 0 && summary.messages() < whole);
        assert!(summary.problems().is_empty(), "{:?}", summary.problems());
        // Only the magic: readable, but empty, which check rejects.
        let empty = scan(&bytes[..mcap::MAGIC.len()]).unwrap();
        assert_eq!(empty.messages(), 0);
        assert_eq!(empty.problems(), vec!["no messages".to_string()]);
    }

    #[test]
    fn corruption_inside_a_chunk_and_a_bad_magic_are_errors() {
        let mut bytes = log(50);
        // The first chunk's data starts well after its header; flip a byte inside it.
        let chunk = bytes
            .iter()
            .position(|&b| b == 0x06)
            .expect("a chunk opcode");
        bytes[chunk + 120] ^= 0xff;
        assert!(scan(&bytes).is_err());
        assert!(scan(b"not an mcap file").is_err());
    }
}
