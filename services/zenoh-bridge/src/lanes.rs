//! One lane per forwarded topic: an iceoryx2 subscriber whose samples go out as envelopes
//! (export), or an iceoryx2 publisher of the envelopes that come in (import). The lanes are
//! typed by the topic's payload; the bridge holds them type-erased.

use std::marker::PhantomData;

use motm_bus::{Bus, BusError, Publisher, Qos, Stamp, Subscriber, Trigger};
use motm_msgs::{self as msgs, Message, Rejection, SCHEMA_VERSION, services};

use crate::envelope::PayloadId;

/// The service settings of `topic`, as every process of the stack gives them.
pub fn qos_of(topic: &str) -> Qos {
    if topic.starts_with(services::HEARTBEAT_PREFIX) {
        Qos::default()
    } else {
        motm_runtime::qos(topic)
    }
}

/// A payload type the bridge can forward.
pub trait Kind: Sync {
    /// Type name, schema version and size of the payload.
    fn id(&self) -> PayloadId;
    /// An export lane of `topic` on `bus`.
    fn exporter(&self, bus: &Bus, topic: &str, qos: &Qos) -> Result<Box<dyn ExportLane>, BusError>;
    /// An import lane of `topic` on `bus`.
    fn importer(&self, bus: &Bus, topic: &str, qos: &Qos) -> Result<Box<dyn ImportLane>, BusError>;
}

/// The [`Kind`] of payload `M`.
pub struct Typed<M>(PhantomData<fn() -> M>);

impl<M> Typed<M> {
    /// The kind of `M`.
    pub const fn new() -> Self {
        Self(PhantomData)
    }
}

impl<M> Default for Typed<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<M: Message> Kind for Typed<M> {
    fn id(&self) -> PayloadId {
        PayloadId {
            type_name: M::NAME,
            schema_version: SCHEMA_VERSION,
            size: size_of::<M>(),
        }
    }

    fn exporter(&self, bus: &Bus, topic: &str, qos: &Qos) -> Result<Box<dyn ExportLane>, BusError> {
        Ok(Box::new(Export::<M> {
            subscriber: Subscriber::new(bus, topic, qos)?,
        }))
    }

    fn importer(&self, bus: &Bus, topic: &str, qos: &Qos) -> Result<Box<dyn ImportLane>, BusError> {
        Ok(Box::new(Import::<M> {
            publisher: Publisher::new(bus, topic, qos)?,
            scratch: zeroed_box(),
        }))
    }
}

/// Every payload type of the graph's topics and the heartbeats.
const KINDS: &[&dyn Kind] = {
    use msgs::*;
    &[
        &Typed::<JointState>::new(),
        &Typed::<GripperState>::new(),
        &Typed::<ArmVelocityCommand>::new(),
        &Typed::<GripperCommand>::new(),
        &Typed::<BaseOdometry>::new(),
        &Typed::<BaseVelocityCommand>::new(),
        &Typed::<TwistCommand>::new(),
        &Typed::<TargetEstimate>::new(),
        &Typed::<BasePlan>::new(),
        &Typed::<CameraImage>::new(),
        &Typed::<Heartbeat>::new(),
        &Typed::<MissionState>::new(),
        &Typed::<SafeStop>::new(),
        &Typed::<QpStatus>::new(),
        &Typed::<ActiveController>::new(),
        &Typed::<SimTruth>::new(),
        &Typed::<DriverStatus>::new(),
        &Typed::<SupervisorStatus>::new(),
    ]
};

/// The payload kind of service `topic`: a topic some task or the supervisor publishes
/// ([`motm_graph::published_topics`]), or a heartbeat; `None` for anything else.
pub fn kind_of(topic: &str) -> Option<&'static dyn Kind> {
    let type_name = if topic
        .strip_prefix(services::HEARTBEAT_PREFIX)
        .is_some_and(|rest| rest.len() > 1 && rest.starts_with('/'))
    {
        <msgs::Heartbeat as Message>::NAME
    } else {
        motm_graph::published_topics()
            .into_iter()
            .find(|t| t.name == topic)?
            .type_name
    };
    KINDS
        .iter()
        .copied()
        .find(|k| k.id().type_name == type_name)
}

/// Reads one topic's local samples for zenoh.
pub trait ExportLane {
    /// The wake-up of the topic's readers, when its publishers notify them.
    fn trigger(&self) -> Option<Trigger>;
    /// Hands every valid sample received since the last call to `out`, as its payload bytes;
    /// returns how many.
    fn drain(&mut self, out: &mut dyn FnMut(&[u8])) -> Result<usize, BusError>;
    /// Local samples dropped as invalid.
    fn rejected(&self) -> u64;
}

struct Export<M: Message> {
    subscriber: Subscriber<M>,
}

impl<M: Message> ExportLane for Export<M> {
    fn trigger(&self) -> Option<Trigger> {
        self.subscriber.trigger()
    }

    fn drain(&mut self, out: &mut dyn FnMut(&[u8])) -> Result<usize, BusError> {
        let mut n = 0;
        while let Some(sample) = self.subscriber.receive()? {
            out(bytes_of::<M>(&sample));
            n += 1;
        }
        Ok(n)
    }

    fn rejected(&self) -> u64 {
        self.subscriber.rejected()
    }
}

/// Why an import lane did not publish a sample.
#[derive(Debug)]
pub enum ImportError {
    /// The sample failed the receive-side checks (a bad number, a range, a code).
    Invalid(Rejection),
    /// The local publish failed.
    Bus(BusError),
}

/// Publishes one topic's samples from zenoh locally.
pub trait ImportLane {
    /// Checks `payload` (the sender's bytes, of the right size) against `now_ns` with every
    /// instant it holds ([`Message::for_each_instant`]) moved from the sender's clock to this
    /// host's by `stamp`, and publishes it with its moved header stamp.
    fn publish(
        &mut self,
        payload: &[u8],
        stamp: &dyn Fn(u64) -> u64,
        now_ns: u64,
    ) -> Result<(), ImportError>;
}

struct Import<M: Message> {
    publisher: Publisher<M>,
    /// The sample being checked (on the heap: a camera image is too large for a stack).
    scratch: Box<M>,
}

impl<M: Message> ImportLane for Import<M> {
    fn publish(
        &mut self,
        payload: &[u8],
        stamp: &dyn Fn(u64) -> u64,
        now_ns: u64,
    ) -> Result<(), ImportError> {
        assert_eq!(
            payload.len(),
            size_of::<M>(),
            "the envelope checked the size"
        );
        // SAFETY: `payload` holds exactly one `M` in this host's layout (checked by the
        // envelope's type name, schema version, size and byte order), and every bit pattern of
        // a `Message`'s integer and float fields is a value of it; the copy fills the whole
        // properly aligned `scratch`.
        unsafe {
            std::ptr::copy_nonoverlapping(
                payload.as_ptr(),
                (&mut *self.scratch as *mut M).cast::<u8>(),
                size_of::<M>(),
            );
        }
        self.scratch.for_each_instant(&mut |t| {
            if *t != 0 {
                *t = stamp(*t);
            }
        });
        let stamp_ns = self.scratch.header().stamp_ns;
        self.scratch
            .validate(now_ns, None)
            .map_err(ImportError::Invalid)?;
        self.publisher
            .publish_copy(Stamp::At(stamp_ns), &self.scratch)
            .map_err(ImportError::Bus)
    }
}

/// The bytes of a payload.
fn bytes_of<M: Message>(message: &M) -> &[u8] {
    // SAFETY: a `Message` is a `#[repr(C)]` struct of integers, floats and arrays of them with
    // explicit padding fields, so all of its bytes are initialised.
    unsafe { std::slice::from_raw_parts((message as *const M).cast::<u8>(), size_of::<M>()) }
}

/// An all-zero `M` on the heap, never built on the stack.
fn zeroed_box<M: Message>() -> Box<M> {
    let layout = std::alloc::Layout::new::<M>();
    // SAFETY: `Message` types are not zero-sized (they hold a header); all-zero bytes are a
    // valid `M` (the trait's contract), and the allocation has `M`'s layout, so the box owns it.
    unsafe {
        let ptr = std::alloc::alloc_zeroed(layout).cast::<M>();
        if ptr.is_null() {
            std::alloc::handle_alloc_error(layout);
        }
        Box::from_raw(ptr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::topics as t;

    #[test]
    fn every_published_topic_and_heartbeats_have_a_kind_of_their_payload() {
        for topic in motm_graph::published_topics() {
            let kind = kind_of(topic.name).unwrap_or_else(|| panic!("{}", topic.name));
            assert_eq!(kind.id().type_name, topic.type_name);
        }
        let heartbeat = kind_of(&services::heartbeat("perception")).unwrap();
        assert_eq!(heartbeat.id().type_name, <msgs::Heartbeat as Message>::NAME);
        assert!(kind_of(services::HEARTBEAT_PREFIX).is_none());
        assert!(kind_of("motm/v1/no/such").is_none());
        let image = kind_of(t::CAMERA_IMAGE.name()).unwrap().id();
        assert_eq!(image.size, size_of::<msgs::CameraImage>());
    }
}
