//! Writes encoded records ([`EncodedMessage`]) to a chunked MCAP file: each channel of the
//! [`ChannelRegistry`](crate::channels::ChannelRegistry) is added to the file on its first
//! message (one schema per foxglove schema, one per JSON channel); chunks are written out when
//! full or `flush_interval_s` after they were opened, so a killed logger leaves a file readable
//! up to its last written chunk.

use std::collections::HashMap;
use std::io::{Seek, Write};

use mcap::records::MessageHeader;

use crate::channels::{ChannelInfo, EncodedMessage, PROTOBUF};

/// The MCAP writer with its channels.
pub struct McapSink<W: Write + Seek> {
    writer: mcap::Writer<W>,
    /// File channel id by registry channel id.
    channels: HashMap<u16, u16>,
    protobuf_schemas: HashMap<String, u16>,
    flush_interval_ns: u64,
    last_flush_ns: Option<u64>,
    /// Records written.
    pub written: u64,
}

impl<W: Write + Seek> McapSink<W> {
    /// Starts a file on `out`: chunks of about `chunk_bytes`, written out at least every
    /// `flush_interval_s`.
    pub fn new(out: W, chunk_bytes: u64, flush_interval_s: f64) -> Result<Self, mcap::McapError> {
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
            flush_interval_ns: (flush_interval_s.max(0.0) * 1e9) as u64,
            last_flush_ns: None,
            written: 0,
        })
    }

    /// Writes `message` (adding its channel to the file on its first message).
    pub fn write(&mut self, message: &EncodedMessage) -> Result<(), mcap::McapError> {
        let channel_id = match self.channels.get(&message.channel.id) {
            Some(&id) => id,
            None => {
                let id = self.add_channel(message.channel)?;
                self.channels.insert(message.channel.id, id);
                id
            }
        };
        self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id,
                sequence: message.sequence,
                log_time: message.log_time_ns,
                publish_time: message.publish_time_ns,
            },
            &message.data,
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

    /// Adds the schema (once per foxglove schema) and the channel `channel`.
    fn add_channel(&mut self, channel: &ChannelInfo) -> Result<u16, mcap::McapError> {
        let known = (channel.schema_encoding == PROTOBUF)
            .then(|| self.protobuf_schemas.get(&channel.schema_name).copied())
            .flatten();
        let schema_id = match known {
            Some(id) => id,
            None => {
                let id = self.writer.add_schema(
                    &channel.schema_name,
                    channel.schema_encoding,
                    &channel.schema,
                )?;
                if channel.schema_encoding == PROTOBUF {
                    self.protobuf_schemas
                        .insert(channel.schema_name.clone(), id);
                }
                id
            }
        };
        self.writer.add_channel(
            schema_id,
            &channel.topic,
            channel.message_encoding,
            &Default::default(),
        )
    }
}
