//! Typed ports over `motm-msgs` payloads: publishers that stamp headers, subscribers that
//! validate every sample before handing it out, and a latest-value reader.

use std::ops::Deref;
use std::rc::{Rc, Weak};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use motm_msgs::{Header, Message, Rejection, services};

use crate::{Bus, BusError, BusShared, Connectable, monotonic_now_ns};

/// Service quality settings. On open these are minimum requirements: the first process to
/// create a service fixes them, later ones must ask for no more.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Publishers allowed at once (4: a task and its hot standby, each with room for a
    /// restart or hot-swap overlap, or a fault injector).
    pub max_publishers: usize,
    /// Subscribers allowed at once (12: the graph's most-read topic, the odometry, has eight
    /// readers, plus the logger, a tool and restart overlaps). The defaults are the same for
    /// every topic, so that whichever process creates a service (a tool, a test) gives it
    /// room for the whole stack.
    pub max_subscribers: usize,
    /// Samples a newly connected subscriber receives at once (the latest state).
    pub history_size: usize,
    /// Samples queued per subscriber; the oldest is overwritten when full (safe overflow), so
    /// a slow reader never blocks a publisher.
    pub subscriber_buffer: usize,
    /// Samples queued for a tap ([`Subscriber::attach`], the logger): the service's largest
    /// queue, deeper than a task's so that a logger that falls behind for a while still reads
    /// every sample (each slot costs one sample of shared memory per subscriber).
    pub tap_buffer: usize,
    /// Samples a subscriber may hold at once ([`Latest`] holds one while receiving the next).
    pub max_borrowed: usize,
    /// Whether publishers also notify a `<service>/ready` event after each sample, so readers
    /// can wake on data instead of a timer.
    pub wake_readers: bool,
}

impl Default for Qos {
    fn default() -> Self {
        Self {
            max_publishers: 4,
            max_subscribers: 12,
            history_size: 1,
            subscriber_buffer: 4,
            tap_buffer: 256,
            max_borrowed: 2,
            wake_readers: false,
        }
    }
}

impl Qos {
    /// Settings for large payloads such as camera images: a short queue, so that the shared
    /// memory a publisher reserves (one chunk per queue slot per subscriber) stays small.
    pub fn large() -> Self {
        Self {
            subscriber_buffer: 2,
            tap_buffer: 16,
            ..Self::default()
        }
    }

    /// These settings, with readers woken on each sample.
    pub fn waking(self) -> Self {
        Self {
            wake_readers: true,
            ..self
        }
    }
}

/// When a published sample is stamped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamp {
    /// The monotonic time just before the sample is sent.
    Now,
    /// An explicit monotonic time, ns (e.g. a camera frame's exposure time).
    At(u64),
}

/// Opens (or creates) the publish-subscribe service `name` for payload `M`.
fn open_service<M: Message>(
    bus: &Bus,
    name: &str,
    qos: &Qos,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, M, ()>,
    BusError,
> {
    bus.node
        .service_builder(&Bus::service_name(name)?)
        .publish_subscribe::<M>()
        .max_publishers(qos.max_publishers)
        .max_subscribers(qos.max_subscribers)
        .history_size(qos.history_size)
        .subscriber_max_buffer_size(qos.subscriber_buffer.max(qos.tap_buffer))
        .subscriber_max_borrowed_samples(qos.max_borrowed)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| BusError::Service {
            service: name.to_owned(),
            detail: e.to_string(),
        })
}

/// Opens (or creates) the `<name>/ready` event service.
fn open_event(
    bus: &Bus,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, BusError> {
    let event = services::ready_event(name);
    bus.node
        .service_builder(&Bus::service_name(&event)?)
        .event()
        .open_or_create()
        .map_err(|e| BusError::Service {
            service: event,
            detail: e.to_string(),
        })
}

/// Creates a port; if that fails (typically `ExceedsMaxSupportedPublishers` or
/// `...Subscribers` because a dead process still holds a slot), removes the dead nodes'
/// resources from the service and tries once more.
fn with_dead_node_cleanup<T, E>(
    service: &impl PortFactory,
    mut create: impl FnMut() -> Result<T, E>,
) -> Result<T, E> {
    create().or_else(|_| {
        service.try_cleanup_dead_nodes();
        create()
    })
}

/// Builds a [`BusError::Port`] for `service`.
fn port_error(service: &str, e: impl std::fmt::Display) -> BusError {
    BusError::Port {
        service: service.to_owned(),
        detail: e.to_string(),
    }
}

/// The iceoryx2 ports behind a [`Publisher`], shared with the bus for connection refresh.
struct PublisherPorts<M: Message> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, M, ()>,
    notifier: Option<Notifier<ipc::Service>>,
}

impl<M: Message> Connectable for PublisherPorts<M> {
    fn refresh(&self) {
        // A failed connection is retried on the next refresh or send.
        let _ = self.publisher.update_connections();
        if let Some(notifier) = &self.notifier {
            let _ = notifier.update_connections();
        }
    }
}

/// Fills in `message`'s publication stamp ([`Message::publication_stamp_mut`]) with the
/// monotonic time now, when it has one and it is zero.
fn stamp_publication<M: Message>(message: &mut M) {
    if let Some(sent) = message.publication_stamp_mut()
        && *sent == 0
    {
        *sent = monotonic_now_ns();
    }
}

/// Publishes `M` samples on one service, stamping each header with the schema version, a
/// sequence number counting from 0 and a monotonic timestamp.
pub struct Publisher<M: Message> {
    ports: Rc<PublisherPorts<M>>,
    service: String,
    next_seq: u64,
}

impl<M: Message> Publisher<M> {
    /// Creates a publisher on service `name` of `bus`.
    pub fn new(bus: &Bus, name: &str, qos: &Qos) -> Result<Self, BusError> {
        let service = open_service::<M>(bus, name, qos)?;
        let publisher = with_dead_node_cleanup(&service, || service.publisher_builder().create())
            .map_err(|e| port_error(name, e))?;
        let notifier = if qos.wake_readers {
            let event = open_event(bus, name)?;
            Some(
                event
                    .notifier_builder()
                    .create()
                    .map_err(|e| port_error(name, e))?,
            )
        } else {
            None
        };
        let ports = Rc::new(PublisherPorts {
            publisher,
            notifier,
        });
        let weak: Weak<PublisherPorts<M>> = Rc::downgrade(&ports);
        bus.register(weak);
        Ok(Self {
            ports,
            service: name.to_owned(),
            next_seq: 0,
        })
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// Sequence number the next sample will carry.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Publishes `message` stamped now.
    pub fn publish(&mut self, message: M) -> Result<(), BusError> {
        self.publish_stamped(Stamp::Now, message)
    }

    /// Publishes `message` with the given stamp (its header is overwritten).
    pub fn publish_stamped(&mut self, stamp: Stamp, mut message: M) -> Result<(), BusError> {
        let sample = self
            .ports
            .publisher
            .loan_uninit()
            .map_err(|e| port_error(&self.service, e))?;
        *message.header_mut() = self.header(stamp);
        stamp_publication(&mut message);
        let sample = sample.write_payload(message);
        self.send(sample)
    }

    /// Publishes `message` exactly as given, header included (stamp, sequence number and
    /// schema version are not touched, and the publisher's own sequence does not advance): for
    /// fault-injection tests that send malformed samples. Never use it for real data.
    pub fn publish_raw(&mut self, message: M) -> Result<(), BusError> {
        let sample = self
            .ports
            .publisher
            .loan_uninit()
            .map_err(|e| port_error(&self.service, e))?;
        self.send(sample.write_payload(message))
    }

    /// Publishes a sample built in place in shared memory: the payload starts all-zero,
    /// `fill` writes it, then the header is stamped. Use this for large payloads (camera
    /// images), which should never be built on the stack.
    pub fn publish_with(
        &mut self,
        stamp: Stamp,
        fill: impl FnOnce(&mut M),
    ) -> Result<(), BusError> {
        let mut sample = self
            .ports
            .publisher
            .loan_uninit()
            .map_err(|e| port_error(&self.service, e))?;
        // SAFETY: `Message` guarantees that all-zero bytes are a valid `M`.
        let mut sample = unsafe {
            sample.payload_mut().as_mut_ptr().write_bytes(0, 1);
            sample.assume_init()
        };
        fill(sample.payload_mut());
        *sample.payload_mut().header_mut() = self.header(stamp);
        stamp_publication(sample.payload_mut());
        self.send(sample)
    }

    /// Publishes a copy of `message` written straight into shared memory (never through the
    /// stack, so large payloads cost one copy), with its header replaced by the next one.
    pub fn publish_copy(&mut self, stamp: Stamp, message: &M) -> Result<(), BusError> {
        let mut sample = self
            .ports
            .publisher
            .loan_uninit()
            .map_err(|e| port_error(&self.service, e))?;
        // SAFETY: one whole `M` is copied into the loaned, properly aligned payload, which is
        // then fully initialised.
        let mut sample = unsafe {
            std::ptr::copy_nonoverlapping(
                message as *const M,
                sample.payload_mut().as_mut_ptr(),
                1,
            );
            sample.assume_init()
        };
        *sample.payload_mut().header_mut() = self.header(stamp);
        stamp_publication(sample.payload_mut());
        self.send(sample)
    }

    /// Connects to subscribers that appeared since the last send.
    pub fn update_connections(&self) {
        self.ports.refresh();
    }

    /// The next header, advancing the sequence number.
    fn header(&mut self, stamp: Stamp) -> Header {
        let stamp_ns = match stamp {
            Stamp::Now => monotonic_now_ns(),
            Stamp::At(ns) => ns,
        };
        let header = Header::new(stamp_ns, self.next_seq);
        self.next_seq += 1;
        header
    }

    /// Sends a filled sample and wakes the readers.
    fn send(
        &self,
        sample: iceoryx2::sample_mut::SampleMut<ipc::Service, M, ()>,
    ) -> Result<(), BusError> {
        sample.send().map_err(|e| port_error(&self.service, e))?;
        if let Some(notifier) = &self.ports.notifier {
            notifier
                .notify()
                .map_err(|e| port_error(&self.service, e))?;
        }
        Ok(())
    }
}

/// A validated sample, read in place from shared memory. It dereferences to the payload.
pub struct Received<M: Message> {
    sample: Sample<ipc::Service, M, ()>,
}

impl<M: Message> Received<M> {
    /// Unique id of the publisher that sent the sample (changes when the publisher restarts).
    pub fn publisher_id(&self) -> u128 {
        self.sample.header().publisher_id().value()
    }
}

impl<M: Message> Deref for Received<M> {
    type Target = M;

    fn deref(&self) -> &M {
        self.sample.payload()
    }
}

impl<M: Message> std::fmt::Debug for Received<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.sample.payload().fmt(f)
    }
}

/// The iceoryx2 ports behind a [`Subscriber`], shared with the bus for connection refresh.
struct SubscriberPorts<M: Message> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, M, ()>,
    listener: Option<Listener<ipc::Service>>,
}

impl<M: Message> Connectable for SubscriberPorts<M> {
    fn refresh(&self) {
        // `has_samples` connects to new publishers; a failure is retried next time.
        let _ = self.subscriber.has_samples();
    }
}

/// Access to a ready-event listener, whatever the payload type.
trait HasListener {
    /// The listener (always present for ports behind a [`Trigger`]).
    fn listener(&self) -> &Listener<ipc::Service>;

    /// Whether samples wait to be received (`true` when that cannot be told).
    fn has_samples(&self) -> bool;
}

impl<M: Message> HasListener for SubscriberPorts<M> {
    fn listener(&self) -> &Listener<ipc::Service> {
        self.listener
            .as_ref()
            .expect("a trigger is only made for a subscriber with a listener")
    }

    fn has_samples(&self) -> bool {
        self.subscriber.has_samples().unwrap_or(true)
    }
}

/// Wakes a service loop when a sample arrives on a subscriber's service.
pub struct Trigger {
    ports: Rc<dyn HasListener>,
}

impl Trigger {
    /// The listener to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        self.ports.listener()
    }

    /// Consumes pending notifications without blocking (else the WaitSet wakes again).
    pub fn clear(&self) {
        let _ = self.listener().try_wait(|_| {});
    }

    /// Whether a sample waits on the subscriber. A notification can outlive its sample: a
    /// cycle that ran between the publisher's send and its notify has already taken it.
    pub fn has_samples(&self) -> bool {
        self.ports.has_samples()
    }
}

/// How many publishers' sequence numbers a subscriber remembers (restarts add new ids).
const TRACKED_PUBLISHERS: usize = 8;

/// Receives `M` samples from one service. Every sample is validated
/// ([`Message::validate`]: schema version, stamp not in the future, sequence number moving
/// forward per publisher, field ranges); bad samples are dropped and counted, never returned.
pub struct Subscriber<M: Message> {
    ports: Rc<SubscriberPorts<M>>,
    service: String,
    shared: Rc<BusShared>,
    /// `(publisher id, last accepted sequence number)`, most recent publisher last.
    last_seq: Vec<(u128, u64)>,
    accepted: u64,
    rejected: u64,
    last_rejection: Option<Rejection>,
}

impl<M: Message> Subscriber<M> {
    /// Creates a subscriber on service `name` of `bus`; with `qos.wake_readers` it also
    /// listens to the service's ready event (see [`Subscriber::listener`]).
    pub fn new(bus: &Bus, name: &str, qos: &Qos) -> Result<Self, BusError> {
        let service = open_service::<M>(bus, name, qos)?;
        let subscriber = with_dead_node_cleanup(&service, || {
            service
                .subscriber_builder()
                .buffer_size(qos.subscriber_buffer)
                .create()
        })
        .map_err(|e| port_error(name, e))?;
        let listener = if qos.wake_readers {
            let event = open_event(bus, name)?;
            Some(
                event
                    .listener_builder()
                    .create()
                    .map_err(|e| port_error(name, e))?,
            )
        } else {
            None
        };
        Ok(Self::from_ports(
            bus,
            name,
            SubscriberPorts {
                subscriber,
                listener,
            },
        ))
    }

    /// A tap's subscriber on service `name`, opened or created with the settings `qos` that
    /// every process of the stack gives the service, with the service's deepest queue
    /// ([`Qos::tap_buffer`]). A logger that must see every sample from the first one (the
    /// replay log) creates the services this way before the stack starts.
    pub fn tap(bus: &Bus, name: &str, qos: &Qos) -> Result<Self, BusError> {
        let service = open_service::<M>(bus, name, qos)?;
        let subscriber = with_dead_node_cleanup(&service, || {
            service
                .subscriber_builder()
                .buffer_size(qos.subscriber_buffer.max(qos.tap_buffer))
                .create()
        })
        .map_err(|e| port_error(name, e))?;
        Ok(Self::from_ports(
            bus,
            name,
            SubscriberPorts {
                subscriber,
                listener: None,
            },
        ))
    }

    /// Attaches a subscriber to the existing service `name` without creating it and without
    /// asking for any service setting, so a tap (the logger) never changes a service or fails
    /// on the settings its creator chose. `Ok(None)` when the service does not exist (yet).
    /// The subscriber takes one of the service's subscriber slots; its queue has the service's
    /// buffer size and overflows safely (the publisher overwrites the oldest sample).
    pub fn attach(bus: &Bus, name: &str) -> Result<Option<Self>, BusError> {
        let service = match bus
            .node
            .service_builder(&Bus::service_name(name)?)
            .publish_subscribe::<M>()
            .open()
        {
            Ok(service) => service,
            Err(iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError::DoesNotExist) => {
                return Ok(None);
            }
            Err(e) => {
                return Err(BusError::Service {
                    service: name.to_owned(),
                    detail: e.to_string(),
                });
            }
        };
        let subscriber = with_dead_node_cleanup(&service, || service.subscriber_builder().create())
            .map_err(|e| port_error(name, e))?;
        Ok(Some(Self::from_ports(
            bus,
            name,
            SubscriberPorts {
                subscriber,
                listener: None,
            },
        )))
    }

    /// Wraps created ports and registers them for connection refresh.
    fn from_ports(bus: &Bus, name: &str, ports: SubscriberPorts<M>) -> Self {
        let ports = Rc::new(ports);
        let weak: Weak<SubscriberPorts<M>> = Rc::downgrade(&ports);
        bus.register(weak);
        Self {
            ports,
            service: name.to_owned(),
            shared: bus.shared.clone(),
            last_seq: Vec::with_capacity(TRACKED_PUBLISHERS),
            accepted: 0,
            rejected: 0,
            last_rejection: None,
        }
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// The next valid sample in arrival order, or `None` when the queue is empty. Invalid
    /// samples on the way are dropped and counted.
    pub fn receive(&mut self) -> Result<Option<Received<M>>, BusError> {
        loop {
            let Some(sample) = self
                .ports
                .subscriber
                .receive()
                .map_err(|e| port_error(&self.service, e))?
            else {
                return Ok(None);
            };
            let publisher = sample.header().publisher_id().value();
            let slot = self.last_seq.iter().position(|(id, _)| *id == publisher);
            let last = slot.map(|i| self.last_seq[i].1);
            match sample.payload().validate(monotonic_now_ns(), last) {
                Ok(()) => {
                    let seq = sample.payload().header().seq;
                    match slot {
                        Some(i) => self.last_seq[i].1 = seq,
                        None => {
                            if self.last_seq.len() == TRACKED_PUBLISHERS {
                                self.last_seq.remove(0);
                            }
                            self.last_seq.push((publisher, seq));
                        }
                    }
                    self.accepted += 1;
                    return Ok(Some(Received { sample }));
                }
                Err(rejection) => {
                    self.rejected += 1;
                    self.shared.rejected.set(self.shared.rejected.get() + 1);
                    self.last_rejection = Some(rejection);
                }
            }
        }
    }

    /// Drains the queue and returns the newest valid sample, or `None` when nothing new came.
    pub fn latest(&mut self) -> Result<Option<Received<M>>, BusError> {
        let mut newest = None;
        while let Some(sample) = self.receive()? {
            newest = Some(sample);
        }
        Ok(newest)
    }

    /// The ready-event listener (present when created with `qos.wake_readers`), for a
    /// WaitSet to wake on.
    pub fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.ports.listener.as_ref()
    }

    /// A handle on this subscriber's ready event for [`crate::ServiceLoop::run_on_data`],
    /// separate from the subscriber so that the step can still read it; `None` unless created
    /// with `qos.wake_readers`.
    pub fn trigger(&self) -> Option<Trigger> {
        self.ports.listener.as_ref()?;
        Some(Trigger {
            ports: self.ports.clone(),
        })
    }

    /// Consumes pending ready notifications without blocking (else a WaitSet wakes again).
    pub fn clear_notifications(&self) {
        if let Some(listener) = &self.ports.listener {
            let _ = listener.try_wait(|_| {});
        }
    }

    /// Valid samples received so far.
    pub fn accepted(&self) -> u64 {
        self.accepted
    }

    /// Invalid samples dropped so far.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// Why the last invalid sample was dropped.
    pub fn last_rejection(&self) -> Option<&Rejection> {
        self.last_rejection.as_ref()
    }
}

/// Latest-value reader: each [`Latest::update`] drains the queue to the newest valid sample
/// and keeps it (in place, without copying) until a newer one arrives.
pub struct Latest<M: Message> {
    subscriber: Subscriber<M>,
    current: Option<Received<M>>,
}

impl<M: Message> Latest<M> {
    /// Creates a latest-value reader on service `name` of `bus`.
    pub fn new(bus: &Bus, name: &str, qos: &Qos) -> Result<Self, BusError> {
        Ok(Self {
            subscriber: Subscriber::new(bus, name, qos)?,
            current: None,
        })
    }

    /// Takes in every sample that arrived; returns whether the value changed.
    pub fn update(&mut self) -> Result<bool, BusError> {
        let mut changed = false;
        // Assigning drops the previous sample, so at most two are held at once.
        while let Some(sample) = self.subscriber.receive()? {
            self.current = Some(sample);
            changed = true;
        }
        Ok(changed)
    }

    /// The newest valid value received so far.
    pub fn get(&self) -> Option<&M> {
        self.current.as_deref()
    }

    /// Age of the newest value at `now_ns` (from its header stamp), ns.
    pub fn age_ns(&self, now_ns: u64) -> Option<u64> {
        self.get()
            .map(|m| now_ns.saturating_sub(m.header().stamp_ns))
    }

    /// Id of the publisher that sent the newest value (changes when it restarts).
    pub fn publisher_id(&self) -> Option<u128> {
        self.current.as_ref().map(Received::publisher_id)
    }

    /// The underlying subscriber (counters, listener).
    pub fn subscriber(&self) -> &Subscriber<M> {
        &self.subscriber
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{IpcConfig, cleanup::remove_domain, shared_memory_entries};
    use motm_msgs::{BaseOdometry, JointState};

    #[test]
    fn another_payload_type_on_a_service_name_is_a_clear_error() {
        let ipc = IpcConfig {
            prefix: format!("motmt{}_types_", std::process::id()),
        };
        {
            let bus = Bus::open_with("types", &ipc).unwrap();
            let _state =
                Publisher::<JointState>::new(&bus, services::ARM_JOINT_STATE, &Qos::default())
                    .unwrap();
            let err =
                Subscriber::<BaseOdometry>::new(&bus, services::ARM_JOINT_STATE, &Qos::default())
                    .err()
                    .expect("payload type mismatch must fail");
            let text = err.to_string();
            assert!(text.contains(services::ARM_JOINT_STATE), "{text}");
            assert!(text.contains("IncompatibleTypes"), "{text}");
        }
        // SAFETY: the bus is dropped and no other process uses this prefix.
        unsafe { remove_domain(&ipc) }.unwrap();
        assert!(shared_memory_entries(&ipc).unwrap().is_empty());
    }

    #[test]
    fn subscriber_drops_and_counts_invalid_samples_and_keeps_the_valid_ones() {
        let ipc = IpcConfig {
            prefix: format!("motmt{}_reject_", std::process::id()),
        };
        {
            let bus = Bus::open_with("rejects", &ipc).unwrap();
            let qos = Qos {
                subscriber_buffer: 8,
                ..Qos::default()
            };
            let mut publisher =
                Publisher::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos).unwrap();
            let mut latest =
                Latest::<BaseOdometry>::new(&bus, services::BASE_ODOMETRY, &qos).unwrap();
            let mut odometry = BaseOdometry::zeroed();
            odometry.x = 1.0;
            publisher.publish(odometry).unwrap();
            publisher
                .publish(BaseOdometry {
                    yaw: f64::NAN,
                    ..odometry
                })
                .unwrap();
            publisher
                .publish_stamped(Stamp::At(u64::MAX), odometry)
                .unwrap();
            assert!(latest.update().unwrap());
            assert_eq!(latest.get().unwrap().x, 1.0);
            assert_eq!(latest.get().unwrap().header.seq, 0);
            assert_eq!(latest.subscriber().rejected(), 2);
            assert_eq!(bus.rejected_messages(), 2);
            let last = latest.subscriber().last_rejection().unwrap();
            assert_eq!(last.field, "header.stamp_ns");
            // Nothing new: the value stays.
            assert!(!latest.update().unwrap());
            assert_eq!(latest.get().unwrap().x, 1.0);
        }
        // SAFETY: the bus is dropped and no other process uses this prefix.
        unsafe { remove_domain(&ipc) }.unwrap();
        assert!(shared_memory_entries(&ipc).unwrap().is_empty());
    }
}
