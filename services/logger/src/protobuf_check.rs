//! Decodes protobuf messages with nothing but a schema stored in an MCAP file (a serialized
//! `FileDescriptorSet`): every field of the message must be declared by the schema with a
//! matching wire type, strings must be UTF-8, nested messages are decoded recursively. This is
//! what a reader such as Foxglove does with the file, without any generated code.

use std::collections::HashMap;

use prost::Message as _;
use prost::encoding::decode_varint;
use prost_types::field_descriptor_proto::Type;
use prost_types::{DescriptorProto, FileDescriptorSet};

/// Deepest message nesting accepted (the foxglove schemas nest four levels at most).
const MAX_DEPTH: usize = 32;

/// A decoder for one top-level message type of a `FileDescriptorSet`.
#[derive(Debug, Clone)]
pub struct SchemaDecoder {
    /// Every message type of the set by full name with a leading dot (`.foxglove.Pose`).
    messages: HashMap<String, DescriptorProto>,
    /// Full name of the top-level type, with a leading dot.
    root: String,
}

/// What decoding one message found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Decoded {
    /// Fields read, nested fields included.
    pub fields: usize,
}

impl SchemaDecoder {
    /// Parses `descriptor` (a serialized `FileDescriptorSet`) and selects message type `name`
    /// (e.g. `foxglove.SceneUpdate`).
    pub fn new(name: &str, descriptor: &[u8]) -> Result<Self, String> {
        let set = FileDescriptorSet::decode(descriptor)
            .map_err(|e| format!("schema {name}: not a FileDescriptorSet: {e}"))?;
        let mut messages = HashMap::new();
        for file in &set.file {
            let package = file.package.as_deref().unwrap_or("");
            let prefix = if package.is_empty() {
                String::new()
            } else {
                format!(".{package}")
            };
            for message in &file.message_type {
                register(&mut messages, &prefix, message);
            }
        }
        let root = format!(".{name}");
        if !messages.contains_key(&root) {
            return Err(format!(
                "schema {name}: the descriptor set does not define it"
            ));
        }
        Ok(Self { messages, root })
    }

    /// Decodes `bytes` as the top-level type.
    pub fn decode(&self, bytes: &[u8]) -> Result<Decoded, String> {
        let mut decoded = Decoded::default();
        self.walk(&self.root, bytes, 0, &mut decoded)?;
        Ok(decoded)
    }

    /// Decodes `bytes` as message type `type_name`, counting fields into `decoded`.
    fn walk(
        &self,
        type_name: &str,
        mut bytes: &[u8],
        depth: usize,
        decoded: &mut Decoded,
    ) -> Result<(), String> {
        if depth > MAX_DEPTH {
            return Err(format!("{type_name}: nested deeper than {MAX_DEPTH}"));
        }
        let message = self
            .messages
            .get(type_name)
            .ok_or_else(|| format!("type {type_name} is not in the schema"))?;
        while !bytes.is_empty() {
            let key = decode_varint(&mut bytes).map_err(|e| format!("{type_name}: key: {e}"))?;
            let number = (key >> 3) as i32;
            let wire = (key & 7) as u8;
            let field = message
                .field
                .iter()
                .find(|f| f.number == Some(number))
                .ok_or_else(|| {
                    format!("{type_name}: field number {number} is not in the schema")
                })?;
            let name = field.name();
            let kind = field.r#type();
            let expected = wire_type(kind);
            // Repeated scalars may come packed (length-delimited).
            let packed = wire == 2 && expected != 2;
            if wire != expected && !packed {
                return Err(format!(
                    "{type_name}.{name}: wire type {wire}, the schema says {expected}"
                ));
            }
            let payload = take(&mut bytes, wire).map_err(|e| format!("{type_name}.{name}: {e}"))?;
            match kind {
                Type::Message | Type::Group => {
                    self.walk(field.type_name(), payload, depth + 1, decoded)?
                }
                Type::String => {
                    std::str::from_utf8(payload)
                        .map_err(|_| format!("{type_name}.{name}: string is not UTF-8"))?;
                }
                _ => {}
            }
            decoded.fields += 1;
        }
        Ok(())
    }
}

/// Adds `message` and its nested types under `prefix` (a package or outer type name).
fn register(
    messages: &mut HashMap<String, DescriptorProto>,
    prefix: &str,
    message: &DescriptorProto,
) {
    let full = format!("{prefix}.{}", message.name());
    for nested in &message.nested_type {
        register(messages, &full, nested);
    }
    messages.insert(full, message.clone());
}

/// The wire type a field of `kind` uses when not packed.
fn wire_type(kind: Type) -> u8 {
    match kind {
        Type::Double | Type::Fixed64 | Type::Sfixed64 => 1,
        Type::Float | Type::Fixed32 | Type::Sfixed32 => 5,
        Type::String | Type::Bytes | Type::Message => 2,
        Type::Group => 3,
        _ => 0,
    }
}

/// Takes the payload of a field of wire type `wire` off the front of `bytes`: the varint's
/// bytes, 8 or 4 bytes, or the length-delimited content.
fn take<'a>(bytes: &mut &'a [u8], wire: u8) -> Result<&'a [u8], String> {
    let len = match wire {
        0 => {
            let start = *bytes;
            decode_varint(bytes).map_err(|e| format!("varint: {e}"))?;
            return Ok(&start[..start.len() - bytes.len()]);
        }
        1 => 8,
        5 => 4,
        2 => {
            let len = decode_varint(bytes).map_err(|e| format!("length: {e}"))?;
            usize::try_from(len).map_err(|_| "length overflows".to_string())?
        }
        other => return Err(format!("unsupported wire type {other}")),
    };
    if bytes.len() < len {
        return Err(format!("needs {len} bytes, {} left", bytes.len()));
    }
    let (payload, rest) = bytes.split_at(len);
    *bytes = rest;
    Ok(payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::foxglove;

    #[test]
    fn foxglove_messages_decode_with_their_stored_descriptor_and_garbage_does_not() {
        let pose = foxglove::PoseInFrame {
            timestamp: Some(foxglove::Timestamp::from_ns(1_500_000_000)),
            frame_id: "world".into(),
            pose: Some(foxglove::Pose {
                position: Some(foxglove::Vector3 {
                    x: 1.0,
                    y: 2.0,
                    z: 3.0,
                }),
                orientation: Some(foxglove::Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                    w: 1.0,
                }),
            }),
        };
        let schema = foxglove::POSE_IN_FRAME;
        let decoder = SchemaDecoder::new(schema.name, schema.descriptor).unwrap();
        let decoded = decoder.decode(&pose.encode_to_vec()).unwrap();
        // timestamp + its 2 fields, frame_id, pose + position + its 3 fields, orientation + w
        // (proto3 leaves the zero x, y, z out): 11 fields.
        assert_eq!(decoded.fields, 11);
        // A RawImage is not a PoseInFrame: its field 2 is a fixed32, the schema's a string.
        let image = foxglove::RawImage {
            width: 2,
            height: 1,
            encoding: "rgb8".into(),
            step: 6,
            data: vec![0xff; 6],
            ..Default::default()
        };
        assert!(decoder.decode(&image.encode_to_vec()).is_err());
        assert!(decoder.decode(&[0x0a, 0x05, 0x01]).is_err(), "truncated");
        assert!(SchemaDecoder::new("foxglove.Nope", schema.descriptor).is_err());
    }
}
