//! Writes [`Record`]s to a chunked MCAP file: one channel per topic, made on its first record
//! (with the foxglove schema, or a jsonschema inferred from the first JSON message), chunks
//! written out when full or `flush_interval_s` after they were opened, so a killed logger
//! leaves a file readable up to its last written chunk.
//!
//! Log times are the records' own stamps moved from `CLOCK_MONOTONIC` to Unix time by one
//! offset taken at start (so Foxglove shows wall-clock times and the spacing of the samples is
//! exactly theirs). A stamp earlier than the channel's previous
//! one (a restarted publisher whose first sample predates the last one logged) is raised to
//! it, so log times never decrease within a channel; such raises are counted, and the publish
//! time keeps the sample's own stamp.

use std::collections::HashMap;
use std::io::{Seek, Write};

use mcap::records::MessageHeader;

use crate::foxglove::Schema;
use crate::json::schema_of;
use crate::recorder::{Payload, Record};

/// A channel of the file.
struct Channel {
    id: u16,
    sequence: u32,
    last_log_time_ns: u64,
}

/// The MCAP writer with its channels.
pub struct McapSink<W: Write + Seek> {
    writer: mcap::Writer<W>,
    channels: HashMap<String, Channel>,
    protobuf_schemas: HashMap<&'static str, u16>,
    /// Added to a monotonic stamp to get Unix time, ns.
    unix_offset_ns: i128,
    flush_interval_ns: u64,
    last_flush_ns: Option<u64>,
    /// Records whose stamp was raised to keep the channel's log times non-decreasing.
    pub raised_stamps: u64,
    /// Records written.
    pub written: u64,
}

impl<W: Write + Seek> McapSink<W> {
    /// Starts a file on `out`: chunks of about `chunk_bytes`, written out at least every
    /// `flush_interval_s`; `unix_offset_ns` moves monotonic stamps to Unix time.
    pub fn new(
        out: W,
        chunk_bytes: u64,
        flush_interval_s: f64,
        unix_offset_ns: i128,
    ) -> Result<Self, mcap::McapError> {
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(chunk_bytes))
            // No seeking: each chunk is built in memory and written whole, so a killed logger
            // never leaves a chunk with a placeholder header in the file.
            .disable_seeking(true)
            .profile("")
            .create(out)?;
        Ok(Self {
            writer,
            channels: HashMap::new(),
            protobuf_schemas: HashMap::new(),
            unix_offset_ns,
            flush_interval_ns: (flush_interval_s.max(0.0) * 1e9) as u64,
            last_flush_ns: None,
            raised_stamps: 0,
            written: 0,
        })
    }

    /// Writes `record`.
    pub fn write(&mut self, record: &Record) -> Result<(), mcap::McapError> {
        let unix_ns = (i128::from(record.stamp_ns) + self.unix_offset_ns).max(0) as u64;
        let data = match &record.payload {
            Payload::Protobuf(_, bytes) => std::borrow::Cow::Borrowed(bytes.as_slice()),
            Payload::Json(value) => std::borrow::Cow::Owned(value.to_string().into_bytes()),
        };
        if !self.channels.contains_key(&record.topic) {
            let id = self.add_channel(record)?;
            self.channels.insert(
                record.topic.clone(),
                Channel {
                    id,
                    sequence: 0,
                    last_log_time_ns: 0,
                },
            );
        }
        let channel = self
            .channels
            .get_mut(&record.topic)
            .expect("inserted above");
        let log_time = if unix_ns < channel.last_log_time_ns {
            self.raised_stamps += 1;
            channel.last_log_time_ns
        } else {
            unix_ns
        };
        channel.last_log_time_ns = log_time;
        channel.sequence = channel.sequence.wrapping_add(1);
        self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id: channel.id,
                sequence: channel.sequence,
                log_time,
                publish_time: unix_ns,
            },
            &data,
        )?;
        self.written += 1;
        Ok(())
    }

    /// Writes out the open chunk when it has been open `flush_interval_s` at monotonic time
    /// `now_ns` (the writer already writes a chunk out when it is full).
    pub fn flush_if_due(&mut self, now_ns: u64) -> Result<(), mcap::McapError> {
        let last = *self.last_flush_ns.get_or_insert(now_ns);
        if now_ns.saturating_sub(last) >= self.flush_interval_ns {
            self.writer.flush()?;
            self.last_flush_ns = Some(now_ns);
        }
        Ok(())
    }

    /// Writes the summary and footer; the file is then complete.
    pub fn finish(mut self) -> Result<W, mcap::McapError> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }

    /// Adds the schema (once per foxglove schema) and the channel of `record`'s topic.
    fn add_channel(&mut self, record: &Record) -> Result<u16, mcap::McapError> {
        let (schema_id, encoding) = match &record.payload {
            Payload::Protobuf(Schema { name, descriptor }, _) => {
                let id = match self.protobuf_schemas.get(name) {
                    Some(&id) => id,
                    None => {
                        let id = self.writer.add_schema(name, "protobuf", descriptor)?;
                        self.protobuf_schemas.insert(name, id);
                        id
                    }
                };
                (id, "protobuf")
            }
            Payload::Json(value) => {
                let mut schema = schema_of(value);
                schema["title"] = record.topic.clone().into();
                let id = self.writer.add_schema(
                    &record.topic,
                    "jsonschema",
                    schema.to_string().as_bytes(),
                )?;
                (id, "json")
            }
        };
        self.writer
            .add_channel(schema_id, &record.topic, encoding, &Default::default())
    }
}
