//! Fault injection on the bus: publish malformed samples onto a topic beside its real
//! publisher, to show that every receiver drops and counts them (`motm run --fault nan:TOPIC`,
//! the bad-input tests).
//!
//! A malformed sample is a copy of the topic's latest real sample (so every other field is
//! plausible) with exactly one thing wrong, so a receiver that drops it does so for that reason.
//! A sequence number going backwards needs an accepted sample from the same publisher first:
//! the injector then sends an unchanged copy of the latest real sample (the receivers take it
//! in, as they would the original) and, right after it, the same copy with a smaller number.

use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, JointState, Message, MissionState,
    SCHEMA_VERSION, TargetEstimate, TwistCommand, services,
};

use crate::{Bus, BusError, Latest, Publisher, Qos, monotonic_now_ns};

/// One way of making a sample malformed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Malformation {
    /// A checked number is NaN.
    NotANumber,
    /// A checked number is infinite.
    Infinite,
    /// A checked number lies far outside its plausible range.
    OutOfRange,
    /// The timestamp lies one hour in the future.
    FutureStamp,
    /// The sequence number goes backwards.
    SequenceBackwards,
    /// The header carries another schema version.
    WrongSchemaVersion,
}

impl Malformation {
    /// Every malformation.
    pub const ALL: [Malformation; 6] = [
        Malformation::NotANumber,
        Malformation::Infinite,
        Malformation::OutOfRange,
        Malformation::FutureStamp,
        Malformation::SequenceBackwards,
        Malformation::WrongSchemaVersion,
    ];

    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Malformation::NotANumber => "nan",
            Malformation::Infinite => "inf",
            Malformation::OutOfRange => "out_of_range",
            Malformation::FutureStamp => "future_stamp",
            Malformation::SequenceBackwards => "sequence_backwards",
            Malformation::WrongSchemaVersion => "wrong_schema_version",
        }
    }

    /// The value a number-corrupting malformation writes (`None` for header ones).
    fn value(self) -> Option<f64> {
        match self {
            Malformation::NotANumber => Some(f64::NAN),
            Malformation::Infinite => Some(f64::INFINITY),
            // Beyond every envelope bound (the largest is 3600 s time-to-range).
            Malformation::OutOfRange => Some(1e9),
            _ => None,
        }
    }
}

/// A message with a range-checked number that a fault can overwrite.
pub trait Corruptible: Message {
    /// Writes `value` into one checked number (the first one of the message).
    fn set_checked_number(&mut self, value: f64);
}

impl Corruptible for ArmVelocityCommand {
    fn set_checked_number(&mut self, value: f64) {
        self.velocity[0] = value;
    }
}

impl Corruptible for BaseVelocityCommand {
    fn set_checked_number(&mut self, value: f64) {
        self.v = value;
    }
}

impl Corruptible for JointState {
    fn set_checked_number(&mut self, value: f64) {
        self.position[0] = value;
    }
}

impl Corruptible for BaseOdometry {
    fn set_checked_number(&mut self, value: f64) {
        self.x = value;
    }
}

impl Corruptible for MissionState {
    fn set_checked_number(&mut self, value: f64) {
        self.current_target[0] = value;
    }
}

impl Corruptible for TwistCommand {
    fn set_checked_number(&mut self, value: f64) {
        self.twist[0] = value;
    }
}

impl Corruptible for TargetEstimate {
    fn set_checked_number(&mut self, value: f64) {
        self.position[0] = value;
    }
}

/// Sends malformed samples on one topic.
pub trait Injector {
    /// The topic (service name).
    fn topic(&self) -> &str;

    /// Sends one sample malformed as `kind` (two for [`Malformation::SequenceBackwards`]: a
    /// valid copy, then the malformed one). Returns whether a real sample was there to copy;
    /// without one the all-zero sample is the base.
    fn inject(&mut self, kind: Malformation) -> Result<bool, BusError>;
}

/// An [`Injector`] for messages of type `M`.
struct TypedInjector<M: Corruptible> {
    topic: String,
    publisher: Publisher<M>,
    latest: Latest<M>,
    /// Sequence number of the next sample this injector sends.
    next_seq: u64,
}

/// Sequence numbers of injected samples start here, far above any real publisher's, so the
/// numbers of one injector keep increasing unless a fault says otherwise.
const FIRST_INJECTED_SEQ: u64 = 1 << 40;

impl<M: Corruptible> TypedInjector<M> {
    fn open(bus: &Bus, topic: &str) -> Result<Self, BusError> {
        let qos = Qos::default();
        Ok(Self {
            topic: topic.to_owned(),
            publisher: Publisher::new(bus, topic, &qos)?,
            latest: Latest::new(bus, topic, &qos)?,
            next_seq: FIRST_INJECTED_SEQ,
        })
    }

    /// The base sample with a fresh header of this injector.
    fn base(&mut self) -> Result<(M, bool), BusError> {
        self.latest.update()?;
        let (mut sample, real) = match self.latest.get() {
            Some(m) => (*m, true),
            None => (M::zeroed(), false),
        };
        let header = sample.header_mut();
        header.stamp_ns = monotonic_now_ns();
        header.seq = self.next_seq;
        header.schema_version = SCHEMA_VERSION;
        self.next_seq += 1;
        Ok((sample, real))
    }
}

impl<M: Corruptible> Injector for TypedInjector<M> {
    fn topic(&self) -> &str {
        &self.topic
    }

    fn inject(&mut self, kind: Malformation) -> Result<bool, BusError> {
        let (mut sample, real) = self.base()?;
        match kind {
            Malformation::NotANumber | Malformation::Infinite | Malformation::OutOfRange => {
                if let Some(value) = kind.value() {
                    sample.set_checked_number(value);
                }
            }
            Malformation::FutureStamp => {
                sample.header_mut().stamp_ns = monotonic_now_ns() + 3_600_000_000_000;
            }
            Malformation::SequenceBackwards => {
                // The valid copy first, then the same sample numbered one lower.
                self.publisher.publish_raw(sample)?;
                sample.header_mut().seq -= 1;
            }
            Malformation::WrongSchemaVersion => {
                sample.header_mut().schema_version = SCHEMA_VERSION + 1;
            }
        }
        self.publisher.publish_raw(sample)?;
        Ok(real)
    }
}

/// The topics an injector can be opened on (those whose payload has a checked number).
pub const INJECTABLE_TOPICS: [&str; 13] = [
    services::ARM_VELOCITY_COMMAND,
    services::HW_ARM_COMMAND,
    services::BASE_VELOCITY_COMMAND,
    services::BASE_VELOCITY_TARGET,
    services::HW_BASE_COMMAND,
    services::ARM_JOINT_STATE,
    services::HW_ARM_STATE,
    services::BASE_ODOMETRY,
    services::HW_BASE_STATE,
    services::MISSION_STATE,
    services::CONTROL_REACH_TWIST,
    services::CONTROL_FINAL_TWIST,
    services::PERCEPTION_TARGET,
];

/// The full service name of `topic`, which may omit the `motm/v1/` prefix.
pub fn full_topic_name(topic: &str) -> String {
    let prefix = format!("{}/", services::PREFIX);
    if topic.starts_with(&prefix) {
        topic.to_owned()
    } else {
        format!("{prefix}{topic}")
    }
}

/// Opens an injector on `topic` (with or without the `motm/v1/` prefix); `Ok(None)` when the
/// topic is not one of [`INJECTABLE_TOPICS`].
pub fn open_injector(bus: &Bus, topic: &str) -> Result<Option<Box<dyn Injector>>, BusError> {
    let topic = full_topic_name(topic);
    let injector: Box<dyn Injector> = match topic.as_str() {
        services::ARM_VELOCITY_COMMAND | services::HW_ARM_COMMAND => {
            Box::new(TypedInjector::<ArmVelocityCommand>::open(bus, &topic)?)
        }
        services::BASE_VELOCITY_COMMAND
        | services::BASE_VELOCITY_TARGET
        | services::HW_BASE_COMMAND => {
            Box::new(TypedInjector::<BaseVelocityCommand>::open(bus, &topic)?)
        }
        services::ARM_JOINT_STATE | services::HW_ARM_STATE => {
            Box::new(TypedInjector::<JointState>::open(bus, &topic)?)
        }
        services::BASE_ODOMETRY | services::HW_BASE_STATE => {
            Box::new(TypedInjector::<BaseOdometry>::open(bus, &topic)?)
        }
        services::MISSION_STATE => Box::new(TypedInjector::<MissionState>::open(bus, &topic)?),
        services::CONTROL_REACH_TWIST | services::CONTROL_FINAL_TWIST => {
            Box::new(TypedInjector::<TwistCommand>::open(bus, &topic)?)
        }
        services::PERCEPTION_TARGET => {
            Box::new(TypedInjector::<TargetEstimate>::open(bus, &topic)?)
        }
        _ => return Ok(None),
    };
    Ok(Some(injector))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{IpcConfig, cleanup::remove_domain, shared_memory_entries};
    use motm_msgs::RejectReason;

    #[test]
    fn every_malformation_is_dropped_for_its_own_reason() {
        let ipc = IpcConfig {
            prefix: format!("motmt{}_inject_", std::process::id()),
        };
        {
            let bus = Bus::open_with("inject", &ipc).unwrap();
            let qos = Qos {
                subscriber_buffer: 8,
                ..Qos::default()
            };
            let mut real =
                Publisher::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos).unwrap();
            let mut reader =
                crate::Subscriber::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos)
                    .unwrap();
            let mut injector = open_injector(&bus, "base/odometry").unwrap().unwrap();
            assert_eq!(injector.topic(), services::BASE_ODOMETRY);
            let mut odometry = BaseOdometry::zeroed();
            odometry.x = 2.0;
            real.publish(odometry).unwrap();
            assert_eq!(reader.receive().unwrap().unwrap().x, 2.0);
            for kind in Malformation::ALL {
                assert!(injector.inject(kind).unwrap(), "{kind:?} had a real sample");
                let before = reader.rejected();
                // The valid copy of a sequence fault is taken in, as the original was.
                while let Some(sample) = reader.receive().unwrap() {
                    assert_eq!(kind, Malformation::SequenceBackwards);
                    assert_eq!(sample.x, 2.0);
                }
                assert_eq!(reader.rejected(), before + 1, "{kind:?}");
                let rejection = reader.last_rejection().unwrap();
                let expected = match kind {
                    Malformation::NotANumber | Malformation::Infinite => {
                        matches!(rejection.reason, RejectReason::NotFinite)
                    }
                    Malformation::OutOfRange => {
                        matches!(rejection.reason, RejectReason::OutOfRange { .. })
                    }
                    Malformation::FutureStamp => {
                        matches!(rejection.reason, RejectReason::FutureTimestamp { .. })
                    }
                    Malformation::SequenceBackwards => {
                        matches!(rejection.reason, RejectReason::SequenceNotIncreasing { .. })
                    }
                    Malformation::WrongSchemaVersion => {
                        matches!(rejection.reason, RejectReason::WrongSchemaVersion { .. })
                    }
                };
                assert!(expected, "{kind:?} dropped as {rejection}");
            }
            assert!(open_injector(&bus, "safety/safe_stop").unwrap().is_none());
        }
        // SAFETY: the bus is dropped and no other process uses this prefix.
        unsafe { remove_domain(&ipc) }.unwrap();
        assert!(shared_memory_entries(&ipc).unwrap().is_empty());
    }
}
