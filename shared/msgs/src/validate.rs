//! Validation of received messages: the [`Rejection`] error and the field checks shared by
//! every message type.

use core::fmt;

/// Why a received message was dropped: the message type, the offending field and the reason.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rejection {
    /// Type name of the rejected message, e.g. `JointState`.
    pub message: &'static str,
    /// Name of the offending field, e.g. `velocity` or `header.seq`.
    pub field: &'static str,
    /// Element index when the field is an array.
    pub index: Option<usize>,
    /// What is wrong with the field.
    pub reason: RejectReason,
}

/// What is wrong with a rejected field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RejectReason {
    /// The value is NaN or infinite.
    NotFinite,
    /// The value lies outside the accepted range `[min, max]`.
    OutOfRange {
        /// The received value.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
    /// The timestamp lies after the receiver's current monotonic time.
    FutureTimestamp {
        /// The received timestamp, ns.
        stamp_ns: u64,
        /// The receiver's clock when it checked, ns.
        now_ns: u64,
    },
    /// The sequence number did not move forward.
    SequenceNotIncreasing {
        /// The received sequence number.
        seq: u64,
        /// The last sequence number accepted from the same publisher.
        last_seq: u64,
    },
    /// The message was built with another schema version.
    WrongSchemaVersion {
        /// The received version.
        found: u32,
        /// The version this build understands.
        expected: u32,
    },
    /// An enumeration field holds a code that names no variant.
    UnknownCode(u32),
    /// The field contradicts another field of the same message.
    Inconsistent(&'static str),
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.message, self.field)?;
        if let Some(i) = self.index {
            write!(f, "[{i}]")?;
        }
        write!(f, " rejected: ")?;
        match self.reason {
            RejectReason::NotFinite => write!(f, "not a finite number"),
            RejectReason::OutOfRange { value, min, max } => {
                write!(f, "{value} is outside [{min}, {max}]")
            }
            RejectReason::FutureTimestamp { stamp_ns, now_ns } => write!(
                f,
                "timestamp {stamp_ns} ns is {} ns in the future",
                stamp_ns - now_ns
            ),
            RejectReason::SequenceNotIncreasing { seq, last_seq } => write!(
                f,
                "sequence number {seq} does not follow the last accepted {last_seq}"
            ),
            RejectReason::WrongSchemaVersion { found, expected } => {
                write!(f, "schema version {found}, expected {expected}")
            }
            RejectReason::UnknownCode(code) => write!(f, "unknown code {code}"),
            RejectReason::Inconsistent(why) => write!(f, "{why}"),
        }
    }
}

impl std::error::Error for Rejection {}

/// Field checker bound to one message type; each check names the field it rejects.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Check {
    /// Type name of the message being checked.
    pub message: &'static str,
}

impl Check {
    /// Builds a rejection of `field` for `reason`.
    pub fn reject(
        &self,
        field: &'static str,
        index: Option<usize>,
        reason: RejectReason,
    ) -> Rejection {
        Rejection {
            message: self.message,
            field,
            index,
            reason,
        }
    }

    /// Accepts a finite value within `[min, max]`.
    pub fn in_range(
        &self,
        field: &'static str,
        value: f64,
        min: f64,
        max: f64,
    ) -> Result<(), Rejection> {
        self.in_range_at(field, None, value, min, max)
    }

    /// Accepts a finite array element within `[min, max]`.
    pub fn in_range_at(
        &self,
        field: &'static str,
        index: Option<usize>,
        value: f64,
        min: f64,
        max: f64,
    ) -> Result<(), Rejection> {
        if !value.is_finite() {
            return Err(self.reject(field, index, RejectReason::NotFinite));
        }
        if value < min || value > max {
            return Err(self.reject(field, index, RejectReason::OutOfRange { value, min, max }));
        }
        Ok(())
    }

    /// Accepts an array whose every element is finite and within `[-max_abs, max_abs]`.
    pub fn all_within(
        &self,
        field: &'static str,
        values: &[f64],
        max_abs: f64,
    ) -> Result<(), Rejection> {
        values
            .iter()
            .enumerate()
            .try_for_each(|(i, &v)| self.in_range_at(field, Some(i), v, -max_abs, max_abs))
    }

    /// Accepts an array whose used prefix of `count` elements is within `[-max_abs, max_abs]`
    /// and whose unused tail is exactly zero.
    pub fn joint_array(
        &self,
        field: &'static str,
        values: &[f64],
        count: usize,
        max_abs: f64,
    ) -> Result<(), Rejection> {
        self.all_within(field, &values[..count], max_abs)?;
        match values[count..].iter().position(|&v| v != 0.0) {
            Some(i) => Err(self.reject(
                field,
                Some(count + i),
                RejectReason::Inconsistent("entries past joint_count must be zero"),
            )),
            None => Ok(()),
        }
    }

    /// Accepts a code that converts into the enumeration `E`.
    pub fn code<E: TryFrom<u32>>(&self, field: &'static str, code: u32) -> Result<E, Rejection> {
        E::try_from(code).map_err(|_| self.reject(field, None, RejectReason::UnknownCode(code)))
    }

    /// Accepts a count in `1..=max`.
    pub fn count(&self, field: &'static str, count: u32, max: usize) -> Result<usize, Rejection> {
        let c = count as usize;
        if c == 0 || c > max {
            return Err(self.reject(
                field,
                None,
                RejectReason::OutOfRange {
                    value: f64::from(count),
                    min: 1.0,
                    max: max as f64,
                },
            ));
        }
        Ok(c)
    }
}
