//! Message types of the motm stack: fixed-size `#[repr(C)]` payloads that iceoryx2 moves
//! between processes without copying or serialising, their service names and schema version,
//! and the validation every receiver applies before acting on a message.
//!
//! Every payload starts with a [`Header`] (monotonic timestamp, sequence number, schema
//! version). Payloads hold only integers and floats (and fixed arrays of them): no pointers, no
//! `Vec`, no `String`, no `Drop`. Enumerations travel as raw `u32` codes with typed accessors,
//! so a corrupt code is a [`Rejection`], never undefined behaviour.

mod messages;
pub mod services;
mod topic;
mod validate;

pub use messages::*;
pub use topic::{Topic, TopicSpec, topics};
pub use validate::{RejectReason, Rejection};

use iceoryx2::prelude::ZeroCopySend;
use validate::Check;

/// Version of the message schema. It is part of every service name (`motm/v1/...`), every
/// payload type name and every [`Header`]; bump it on any layout or meaning change.
pub const SCHEMA_VERSION: u32 = 1;

/// Common header carried first in every payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motm.v1.Header")]
#[repr(C)]
pub struct Header {
    /// Monotonic time (`CLOCK_MONOTONIC`) when the content was produced, ns.
    pub stamp_ns: u64,
    /// Per-publisher sequence number; starts at 0 and increases by one per sample.
    pub seq: u64,
    /// Schema version the publisher was built with; must equal [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Explicit padding; always zero.
    pub reserved: u32,
}

impl Header {
    /// A header of the current schema version with the given stamp and sequence number.
    pub const fn new(stamp_ns: u64, seq: u64) -> Self {
        Self {
            stamp_ns,
            seq,
            schema_version: SCHEMA_VERSION,
            reserved: 0,
        }
    }

    /// Checks the schema version, that the stamp is not in the future (`now_ns`, the receiver's
    /// monotonic clock) and that the sequence number moves forward from `last_seq` (the last
    /// sequence number accepted from the same publisher, if any).
    fn validate(&self, check: Check, now_ns: u64, last_seq: Option<u64>) -> Result<(), Rejection> {
        if self.schema_version != SCHEMA_VERSION {
            return Err(check.reject(
                "header.schema_version",
                None,
                RejectReason::WrongSchemaVersion {
                    found: self.schema_version,
                    expected: SCHEMA_VERSION,
                },
            ));
        }
        if self.stamp_ns > now_ns {
            return Err(check.reject(
                "header.stamp_ns",
                None,
                RejectReason::FutureTimestamp {
                    stamp_ns: self.stamp_ns,
                    now_ns,
                },
            ));
        }
        if let Some(last_seq) = last_seq
            && self.seq <= last_seq
        {
            return Err(check.reject(
                "header.seq",
                None,
                RejectReason::SequenceNotIncreasing {
                    seq: self.seq,
                    last_seq,
                },
            ));
        }
        Ok(())
    }
}

/// A motm payload: a fixed-size message with a [`Header`] and its own field validation.
///
/// # Safety
///
/// The all-zero bit pattern must be a valid value of the type (every field is an integer, a
/// float or a fixed array of them). Publishers rely on this to initialise large payloads in
/// place in shared memory before filling them in.
pub unsafe trait Message: ZeroCopySend + Copy + core::fmt::Debug + 'static {
    /// Short type name used in rejections and logs, e.g. `JointState`.
    const NAME: &'static str;

    /// The common header.
    fn header(&self) -> &Header;

    /// The common header, mutable (publishers stamp it).
    fn header_mut(&mut self) -> &mut Header;

    /// Checks the fields specific to this message: finite numbers, ranges, codes, consistency.
    fn validate_fields(&self) -> Result<(), Rejection>;

    /// Full receive-side validation: header ([`SCHEMA_VERSION`], stamp not after `now_ns`,
    /// sequence number after `last_seq`) and then every field.
    fn validate(&self, now_ns: u64, last_seq: Option<u64>) -> Result<(), Rejection> {
        self.header().validate(
            Check {
                message: Self::NAME,
            },
            now_ns,
            last_seq,
        )?;
        self.validate_fields()
    }

    /// The field that carries the time the sample was sent, if the type has one
    /// (`CameraImage::image_published_ns`, `QpStatus::published_ns`): a publisher fills it in
    /// when it is zero, just before the sample goes out, so that latencies measured from or to
    /// it leave out the work done before the send.
    fn publication_stamp_mut(&mut self) -> Option<&mut u64> {
        None
    }

    /// Calls `f` on every field that holds an instant of the publisher's `CLOCK_MONOTONIC`: the
    /// header's stamp and, for some payloads, the stamps of the image behind them, of their
    /// publication or of the last deadline miss (a field may be 0: unknown). A bridge to another
    /// host moves them all to that host's clock.
    fn for_each_instant(&mut self, f: &mut dyn FnMut(&mut u64)) {
        f(&mut self.header_mut().stamp_ns);
    }

    /// A value with every field zero and a current-version header.
    fn zeroed() -> Self {
        // SAFETY: the trait contract guarantees that all-zero bytes are a valid value.
        let mut value: Self = unsafe { core::mem::zeroed() };
        *value.header_mut() = Header::new(0, 0);
        value
    }
}

#[cfg(test)]
mod tests;
