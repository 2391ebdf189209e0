//! The in-memory bus of the in-process runtime: the same messages as iceoryx2 carries, with
//! the same receive-side validation, in simulated time, and a delay per edge.
//!
//! Semantics (those of the deployed services' iceoryx2 settings):
//! - a reader sees the samples published since its previous read, oldest first; one that
//!   first reads after samples were published gets the newest one (history of one);
//! - a sample published at `t` on an edge with delay `d` is visible to that reader from
//!   `t + d` on;
//! - every sample is validated on receipt ([`Message::validate`]: schema, stamp not in the
//!   future, sequence moving forward, fields); a rejected one is dropped and counted.

use std::any::Any;
use std::collections::VecDeque;
use std::sync::Arc;

use motm_msgs::{Message, Rejection, Topic};

use crate::replay::{RawSample, raw_bytes};
use crate::task::{Consumed, Sink, Source, consumed, shared_copy};

/// Identifies one reader of the bus (a scheduled task).
pub type ReaderId = usize;

/// A small map searched linearly: a bus has a few dozen topics and a channel a few readers, so
/// a scan of pointer-equal keys beats hashing on every read.
#[derive(Debug)]
struct SmallMap<K, V> {
    entries: Vec<(K, V)>,
}

impl<K, V> Default for SmallMap<K, V> {
    fn default() -> Self {
        Self {
            entries: Vec::new(),
        }
    }
}

impl<K: Copy + PartialEq, V> SmallMap<K, V> {
    fn get(&self, key: &K) -> Option<&V> {
        self.entries.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    fn get_mut(&mut self, key: &K) -> Option<&mut V> {
        self.entries
            .iter_mut()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v)
    }

    fn get_or_insert_with(&mut self, key: K, value: impl FnOnce() -> V) -> &mut V {
        let i = match self.entries.iter().position(|(k, _)| *k == key) {
            Some(i) => i,
            None => {
                self.entries.push((key, value()));
                self.entries.len() - 1
            }
        };
        &mut self.entries[i].1
    }

    fn insert(&mut self, key: K, value: V) {
        match self.get_mut(&key) {
            Some(v) => *v = value,
            None => self.entries.push((key, value)),
        }
    }

    fn values(&self) -> impl Iterator<Item = &V> {
        self.entries.iter().map(|(_, v)| v)
    }

    fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// A topic name as a map key: equal when the strings are (pointer-equal names compare first).
#[derive(Debug, Clone, Copy)]
struct Name(&'static str);

impl PartialEq for Name {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self.0, other.0) || self.0 == other.0
    }
}

/// One reader's place in a channel.
#[derive(Debug, Clone, Copy)]
struct Cursor {
    next: u64,
    last_seq: Option<u64>,
}

/// The samples of one topic.
struct Channel<T> {
    /// (publication time, index, sample), oldest first.
    samples: VecDeque<(u64, u64, Arc<T>)>,
    next_index: u64,
    next_seq: u64,
    cursors: SmallMap<ReaderId, Cursor>,
}

impl<T> Channel<T> {
    fn new() -> Self {
        Self {
            samples: VecDeque::new(),
            next_index: 0,
            next_seq: 0,
            cursors: SmallMap::default(),
        }
    }

    /// Drops the samples every reader has passed (keeping the newest for late readers).
    fn trim(&mut self) {
        let oldest_needed = self
            .cursors
            .values()
            .map(|c| c.next)
            .min()
            .unwrap_or(self.next_index)
            .min(self.next_index.saturating_sub(1));
        while self
            .samples
            .front()
            .is_some_and(|(_, index, _)| *index < oldest_needed)
        {
            self.samples.pop_front();
        }
    }
}

/// The in-memory bus.
#[derive(Default)]
pub struct MemBus {
    now_ns: u64,
    channels: SmallMap<Name, Box<dyn AnyChannel>>,
    delays: SmallMap<(Name, ReaderId), u64>,
    rejected: u64,
    last_rejection: Option<Rejection>,
    recorded: Option<Vec<RawSample>>,
}

impl MemBus {
    /// An empty bus at time zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// The bus's simulated monotonic time, ns.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Sets the simulated time (it never goes back).
    pub fn set_now_ns(&mut self, now_ns: u64) {
        self.now_ns = self.now_ns.max(now_ns);
    }

    /// Sets the delay of the edge from `topic` to `reader`, ns.
    pub fn set_delay(&mut self, topic: &'static str, reader: ReaderId, delay_ns: u64) {
        self.delays.insert((Name(topic), reader), delay_ns);
    }

    /// The delay of the edge from `topic` to `reader`, ns (0 unless set).
    fn delay(&self, topic: &'static str, reader: ReaderId) -> u64 {
        if self.delays.is_empty() {
            return 0;
        }
        self.delays
            .get(&(Name(topic), reader))
            .copied()
            .unwrap_or(0)
    }

    /// Samples dropped by validation so far.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// Why the last sample was dropped.
    pub fn last_rejection(&self) -> Option<&Rejection> {
        self.last_rejection.as_ref()
    }

    fn channel<T: Message>(&mut self, topic: Topic<T>) -> &mut Channel<T> {
        self.channels
            .get_or_insert_with(Name(topic.name()), || Box::new(Channel::<T>::new()))
            .as_any_mut()
            .downcast_mut::<Channel<T>>()
            .unwrap_or_else(|| panic!("topic {topic:?} used with two payload types"))
    }

    /// Also keeps the raw bytes of every sample published from now on
    /// ([`MemBus::take_recorded`]), for replay logs.
    pub fn record_samples(&mut self) {
        self.recorded.get_or_insert_with(Vec::new);
    }

    /// The samples recorded since the last call.
    pub fn take_recorded(&mut self) -> Vec<RawSample> {
        self.recorded
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Publishes `sample` now: the bus assigns the sequence number and stamps a zero stamp
    /// with the current time. Returns the sample as published (topic, sequence number, stamp).
    pub fn publish<T: Message>(&mut self, topic: Topic<T>, sample: Arc<T>) -> Consumed {
        let now = self.now_ns;
        let channel = self.channel(topic);
        let mut sample = sample;
        let message = Arc::make_mut(&mut sample);
        let header = message.header_mut();
        header.seq = channel.next_seq;
        if header.stamp_ns == 0 {
            header.stamp_ns = now;
        }
        // Sent now, as a deployed publisher fills it in.
        if let Some(sent) = message.publication_stamp_mut()
            && *sent == 0
        {
            *sent = now;
        }
        channel.next_seq += 1;
        let index = channel.next_index;
        channel.next_index += 1;
        let seq = sample.header().seq;
        if let Some(recorded) = self.recorded.as_mut() {
            recorded.push(RawSample {
                topic: topic.name(),
                seq,
                stamp_ns: sample.header().stamp_ns,
                bytes: raw_bytes(sample.as_ref()),
            });
        }
        let published = consumed(topic, sample.as_ref());
        let channel = self.channel(topic);
        channel.samples.push_back((now, index, sample));
        channel.trim();
        published
    }

    /// Whether `reader` has an unread sample on `topic` that is visible now.
    pub fn has_new(&self, topic: &'static str, reader: ReaderId) -> bool {
        let delay = self.delay(topic, reader);
        let Some(channel) = self.channels.get(&Name(topic)) else {
            return false;
        };
        channel.has_new(reader, self.now_ns, delay)
    }

    /// The visible samples `reader` has not read yet on `topic`, validated, oldest first.
    pub fn read<T: Message>(&mut self, topic: Topic<T>, reader: ReaderId) -> Vec<Arc<T>> {
        let mut out = Vec::new();
        self.read_each(topic, reader, |sample| out.push(Arc::clone(sample)));
        out
    }

    /// The newest of the samples [`MemBus::read`] would return (the same reading, without
    /// collecting them).
    pub fn read_newest<T: Message>(&mut self, topic: Topic<T>, reader: ReaderId) -> Option<Arc<T>> {
        let mut newest = None;
        self.read_each(topic, reader, |sample| newest = Some(Arc::clone(sample)));
        newest
    }

    /// [`MemBus::read`], handing each sample to `each` in turn.
    fn read_each<T: Message>(
        &mut self,
        topic: Topic<T>,
        reader: ReaderId,
        mut each: impl FnMut(&Arc<T>),
    ) {
        let now = self.now_ns;
        let delay = self.delay(topic.name(), reader);
        let channel = self.channel(topic);
        let first_unread = channel.next_index.saturating_sub(1);
        let cursor = *channel.cursors.get_or_insert_with(reader, || Cursor {
            next: first_unread,
            last_seq: None,
        });
        let mut next = cursor.next;
        let mut last_seq = cursor.last_seq;
        let mut rejections = Vec::new();
        for (published, index, sample) in &channel.samples {
            if *index < next {
                continue;
            }
            if published + delay > now {
                break;
            }
            next = index + 1;
            match sample.validate(now, last_seq) {
                Ok(()) => {
                    last_seq = Some(sample.header().seq);
                    each(sample);
                }
                Err(rejection) => rejections.push(rejection),
            }
        }
        channel.cursors.insert(reader, Cursor { next, last_seq });
        channel.trim();
        self.rejected += rejections.len() as u64;
        if let Some(last) = rejections.pop() {
            self.last_rejection = Some(last);
        }
    }

    /// The bus as `reader`'s [`Source`] and as a [`Sink`].
    pub fn port(&mut self, reader: ReaderId) -> MemPort<'_> {
        MemPort {
            bus: self,
            reader,
            produced: Vec::new(),
        }
    }
}

/// The untyped part of a channel.
trait AnyChannel: Any {
    /// Whether `reader` has an unread sample visible at `now` through an edge delay `delay`.
    fn has_new(&self, reader: ReaderId, now: u64, delay: u64) -> bool;
    /// The channel as `Any`, to get the typed channel back.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: 'static> AnyChannel for Channel<T> {
    fn has_new(&self, reader: ReaderId, now: u64, delay: u64) -> bool {
        let next = self
            .cursors
            .get(&reader)
            .map_or(self.next_index.saturating_sub(1), |c| c.next);
        self.samples
            .iter()
            .rev()
            .take_while(|(_, index, _)| *index >= next)
            .any(|(published, _, _)| published + delay <= now)
    }

    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// The bus seen by one reader: a [`Source`] and a [`Sink`]. As a sink it notes what it
/// published ([`MemPort::produced`]).
pub struct MemPort<'a> {
    bus: &'a mut MemBus,
    reader: ReaderId,
    produced: Vec<Consumed>,
}

impl MemPort<'_> {
    /// The samples published through this port, with the sequence numbers the bus gave them.
    pub fn produced(self) -> Vec<Consumed> {
        self.produced
    }
}

impl Source for MemPort<'_> {
    fn latest<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<T>) {
        if let Some(newest) = self.bus.read_newest(topic, self.reader) {
            *slot = Some(*newest);
        }
    }

    fn latest_shared<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<Arc<T>>) {
        if let Some(newest) = self.bus.read_newest(topic, self.reader) {
            *slot = Some(newest);
        }
    }

    fn queue<T: Message>(&mut self, topic: Topic<T>, out: &mut Vec<T>) {
        out.extend(self.bus.read(topic, self.reader).iter().map(|s| **s));
    }
}

impl Sink for MemPort<'_> {
    fn publish<T: Message>(&mut self, topic: Topic<T>, message: &T) {
        self.publish_shared(topic, shared_copy(message));
    }

    fn publish_shared<T: Message>(&mut self, topic: Topic<T>, message: Arc<T>) {
        let published = self.bus.publish(topic, message);
        self.produced.push(published);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::{JointState, topics};

    fn joint(value: f64) -> Arc<JointState> {
        let mut m = JointState::zeroed();
        m.joint_count = 1;
        m.position[0] = value;
        Arc::new(m)
    }

    #[test]
    fn a_reader_sees_samples_in_order_once_the_edge_delay_has_passed() {
        let mut bus = MemBus::new();
        let topic = topics::ARM_JOINT_STATE;
        bus.set_delay(topic.name(), 1, 2_000);
        // Reader 0 registers before anything is published.
        assert!(bus.read(topic, 0).is_empty());
        assert!(bus.read(topic, 1).is_empty());
        bus.set_now_ns(1_000);
        bus.publish(topic, joint(1.0));
        bus.publish(topic, joint(2.0));
        let seen: Vec<f64> = bus.read(topic, 0).iter().map(|m| m.position[0]).collect();
        assert_eq!(seen, [1.0, 2.0]);
        assert!(!bus.has_new(topic.name(), 1));
        assert!(bus.read(topic, 1).is_empty());
        bus.set_now_ns(3_000);
        assert!(bus.has_new(topic.name(), 1));
        assert_eq!(bus.read(topic, 1).len(), 2);
        assert!(bus.read(topic, 0).is_empty(), "read once");
        // Sequence numbers and stamps were assigned by the bus.
        bus.publish(topic, joint(3.0));
        let third = bus.read(topic, 0);
        assert_eq!((third[0].header.seq, third[0].header.stamp_ns), (2, 3_000));
    }

    #[test]
    fn a_late_reader_gets_the_newest_sample_only() {
        let mut bus = MemBus::new();
        let topic = topics::ARM_JOINT_STATE;
        for v in [1.0, 2.0, 3.0] {
            bus.publish(topic, joint(v));
        }
        let seen = bus.read(topic, 7);
        assert_eq!(seen.len(), 1);
        assert_eq!(seen[0].position[0], 3.0);
    }

    #[test]
    fn an_invalid_sample_is_dropped_and_counted() {
        let mut bus = MemBus::new();
        let topic = topics::ARM_JOINT_STATE;
        assert!(bus.read(topic, 0).is_empty());
        bus.publish(topic, joint(f64::NAN));
        bus.publish(topic, joint(0.5));
        let seen = bus.read(topic, 0);
        assert_eq!(seen.len(), 1);
        assert_eq!(seen[0].position[0], 0.5);
        assert_eq!(bus.rejected(), 1);
        let why = bus
            .last_rejection()
            .map(ToString::to_string)
            .unwrap_or_default();
        assert!(why.contains("position"), "{why}");
    }
}
