//! The bridge's wire format: one zenoh sample per iceoryx2 sample, the payload's `#[repr(C)]`
//! bytes behind a small header naming the payload type, the schema version and the payload
//! size, so that a bridge built with other message types refuses the sample instead of reading
//! garbage.
//!
//! Layout (integers little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 4 | magic `MOTM` |
//! | 1 | envelope version ([`ENVELOPE_VERSION`]) |
//! | 1 | n, length of the type name |
//! | n | payload type name ([`motm_msgs::Message::NAME`]) |
//! | 4 | schema version of the sender's build ([`motm_msgs::SCHEMA_VERSION`]) |
//! | 4 | payload size, bytes |
//! | 8 | sender id (random per bridge process) |
//! | 8 | sender's `CLOCK_MONOTONIC` at the send, ns |
//! | size | payload, in the sender's native layout |
//!
//! The payload is the host's in-memory layout: both hosts must have the same endianness (every
//! supported host is little-endian x86-64 or aarch64); the header says which it was and a
//! big-endian sender is refused.

use std::fmt;

/// First four bytes of every envelope.
pub const MAGIC: [u8; 4] = *b"MOTM";

/// Version of this layout.
pub const ENVELOPE_VERSION: u8 = 1;

/// Bit of the envelope version byte set by a big-endian sender.
const BIG_ENDIAN_FLAG: u8 = 0x80;

/// What a bridge knows about the payload of one topic: its type name, schema version and size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PayloadId {
    /// Payload type name ([`motm_msgs::Message::NAME`]).
    pub type_name: &'static str,
    /// Schema version ([`motm_msgs::SCHEMA_VERSION`]).
    pub schema_version: u32,
    /// Size of the payload, bytes.
    pub size: usize,
}

/// One decoded envelope, borrowing its payload from the received bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Envelope<'a> {
    /// Random id of the sending bridge process.
    pub sender: u64,
    /// The sender's monotonic clock when it sent the sample, ns.
    pub sent_ns: u64,
    /// The payload bytes (exactly [`PayloadId::size`] of them).
    pub payload: &'a [u8],
}

/// Why a received envelope was refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// Not an envelope of this bridge (bad magic, cut short, unknown envelope version).
    Malformed(String),
    /// The sender's payload type is another one.
    TypeName {
        /// The sender's type name.
        found: String,
        /// This build's type name.
        expected: &'static str,
    },
    /// The sender was built with another message schema.
    SchemaVersion {
        /// The sender's schema version.
        found: u32,
        /// This build's schema version.
        expected: u32,
    },
    /// The sender's payload has another size (another layout of the same type).
    Size {
        /// The sender's payload size, bytes.
        found: usize,
        /// This build's payload size, bytes.
        expected: usize,
    },
    /// The sender's byte order is not this host's.
    ByteOrder,
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::Malformed(why) => write!(f, "not a motm bridge envelope: {why}"),
            Refusal::TypeName { found, expected } => {
                write!(f, "payload type {found}, this build's is {expected}")
            }
            Refusal::SchemaVersion { found, expected } => write!(
                f,
                "message schema version {found}, this build's is {expected} (the two hosts run \
                 different builds of motm-msgs)"
            ),
            Refusal::Size { found, expected } => write!(
                f,
                "payload of {found} bytes, this build's is {expected} bytes (the two hosts run \
                 different builds of motm-msgs)"
            ),
            Refusal::ByteOrder => f.write_str("the sender's byte order is not this host's"),
        }
    }
}

/// The envelope version byte of this host.
fn version_byte() -> u8 {
    if cfg!(target_endian = "big") {
        ENVELOPE_VERSION | BIG_ENDIAN_FLAG
    } else {
        ENVELOPE_VERSION
    }
}

/// Encodes one sample of payload `id` into `out` (cleared first).
pub fn encode(id: &PayloadId, sender: u64, sent_ns: u64, payload: &[u8], out: &mut Vec<u8>) {
    debug_assert_eq!(payload.len(), id.size);
    let name = id.type_name.as_bytes();
    out.clear();
    out.reserve(30 + name.len() + payload.len());
    out.extend_from_slice(&MAGIC);
    out.push(version_byte());
    out.push(name.len().min(u8::MAX as usize) as u8);
    out.extend_from_slice(&name[..name.len().min(u8::MAX as usize)]);
    out.extend_from_slice(&id.schema_version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&sender.to_le_bytes());
    out.extend_from_slice(&sent_ns.to_le_bytes());
    out.extend_from_slice(payload);
}

/// Decodes an envelope that must carry payload `expected`; a mismatch is a [`Refusal`].
pub fn decode<'a>(bytes: &'a [u8], expected: &PayloadId) -> Result<Envelope<'a>, Refusal> {
    let mut rest = bytes;
    let mut take = |n: usize, what: &str| -> Result<&'a [u8], Refusal> {
        if rest.len() < n {
            return Err(Refusal::Malformed(format!(
                "cut short in the {what} ({} bytes in all)",
                bytes.len()
            )));
        }
        let (head, tail) = rest.split_at(n);
        rest = tail;
        Ok(head)
    };
    if take(4, "magic")? != MAGIC {
        return Err(Refusal::Malformed("bad magic".into()));
    }
    let version = take(1, "version")?[0];
    if version & !BIG_ENDIAN_FLAG != ENVELOPE_VERSION {
        return Err(Refusal::Malformed(format!(
            "envelope version {}, this build's is {ENVELOPE_VERSION}",
            version & !BIG_ENDIAN_FLAG
        )));
    }
    if version != version_byte() {
        return Err(Refusal::ByteOrder);
    }
    let name_len = take(1, "type name length")?[0] as usize;
    let name = take(name_len, "type name")?;
    let schema_version = u32::from_le_bytes(take(4, "schema version")?.try_into().unwrap());
    let size = u32::from_le_bytes(take(4, "payload size")?.try_into().unwrap()) as usize;
    let sender = u64::from_le_bytes(take(8, "sender id")?.try_into().unwrap());
    let sent_ns = u64::from_le_bytes(take(8, "send time")?.try_into().unwrap());
    if name != expected.type_name.as_bytes() {
        return Err(Refusal::TypeName {
            found: String::from_utf8_lossy(name).into_owned(),
            expected: expected.type_name,
        });
    }
    if schema_version != expected.schema_version {
        return Err(Refusal::SchemaVersion {
            found: schema_version,
            expected: expected.schema_version,
        });
    }
    if size != expected.size {
        return Err(Refusal::Size {
            found: size,
            expected: expected.size,
        });
    }
    let payload = take(size, "payload")?;
    if !rest.is_empty() {
        return Err(Refusal::Malformed(format!(
            "{} bytes after the payload",
            rest.len()
        )));
    }
    Ok(Envelope {
        sender,
        sent_ns,
        payload,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: PayloadId = PayloadId {
        type_name: "JointState",
        schema_version: 1,
        size: 5,
    };

    #[test]
    fn an_envelope_decodes_to_what_was_encoded() {
        let mut bytes = Vec::new();
        encode(&ID, 7, 123, b"hello", &mut bytes);
        let envelope = decode(&bytes, &ID).unwrap();
        assert_eq!(envelope.sender, 7);
        assert_eq!(envelope.sent_ns, 123);
        assert_eq!(envelope.payload, b"hello");
    }

    #[test]
    fn another_type_schema_or_size_is_refused_naming_both() {
        let mut bytes = Vec::new();
        encode(&ID, 7, 123, b"hello", &mut bytes);
        let other_schema = PayloadId {
            schema_version: 2,
            ..ID
        };
        assert_eq!(
            decode(&bytes, &other_schema),
            Err(Refusal::SchemaVersion {
                found: 1,
                expected: 2
            })
        );
        let other_type = PayloadId {
            type_name: "BaseOdometry",
            ..ID
        };
        let refusal = decode(&bytes, &other_type).unwrap_err();
        assert!(refusal.to_string().contains("JointState"), "{refusal}");
        assert!(refusal.to_string().contains("BaseOdometry"), "{refusal}");
        let other_size = PayloadId { size: 6, ..ID };
        assert_eq!(
            decode(&bytes, &other_size),
            Err(Refusal::Size {
                found: 5,
                expected: 6
            })
        );
    }

    #[test]
    fn cut_or_foreign_bytes_are_malformed() {
        let mut bytes = Vec::new();
        encode(&ID, 7, 123, b"hello", &mut bytes);
        for n in 0..bytes.len() {
            assert!(
                matches!(decode(&bytes[..n], &ID), Err(Refusal::Malformed(_))),
                "{n}"
            );
        }
        bytes[0] = b'X';
        assert!(matches!(decode(&bytes, &ID), Err(Refusal::Malformed(_))));
    }
}
