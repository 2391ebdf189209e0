//! Replay: a task's cycles fed again from logged input samples, its outputs compared with the
//! logged ones.
//!
//! A log holds every sample published on the bus (its raw bytes, by topic and sequence
//! number) and one [`crate::CycleRecord`] per task cycle: the samples the cycle consumed and
//! the samples it produced. Replaying a cycle fills a fresh input set from the consumed samples
//! ([`ReplaySource`]), steps the task and compares each output with the logged sample of the
//! same topic ([`CompareSink`]), field by field, ignoring the sequence number (the runtime's)
//! and the QP's solve time (wall clock).

use std::collections::HashMap;
use std::sync::Arc;

use motm_msgs::{Message, Topic};

use crate::task::{Consumed, Sink, Source, boxed_zeroed};

/// One logged sample: its topic, sequence number, stamp and raw bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawSample {
    /// Service name of the topic.
    pub topic: &'static str,
    /// Sequence number.
    pub seq: u64,
    /// Header stamp, ns.
    pub stamp_ns: u64,
    /// The payload's bytes (`size_of::<T>()` of its type).
    pub bytes: Vec<u8>,
}

/// The bytes of `message` (payloads are `#[repr(C)]` plain data, as iceoryx2 moves them).
pub fn raw_bytes<T: Message>(message: &T) -> Vec<u8> {
    // SAFETY: `T` is plain data (the `Message` contract: integers, floats and arrays of them,
    // with explicit padding fields), so every byte of it is initialised.
    unsafe {
        std::slice::from_raw_parts((message as *const T).cast::<u8>(), size_of::<T>()).to_vec()
    }
}

/// The message whose bytes are `bytes`, if the length is `T`'s.
pub fn from_raw<T: Message>(bytes: &[u8]) -> Option<Box<T>> {
    if bytes.len() != size_of::<T>() {
        return None;
    }
    let mut message = boxed_zeroed::<T>();
    // SAFETY: the lengths match, and every bit pattern of the plain-data fields is a valid `T`
    // apart from codes, which `Message::validate` checks before use.
    unsafe {
        std::ptr::copy_nonoverlapping(
            bytes.as_ptr(),
            (message.as_mut() as *mut T).cast::<u8>(),
            bytes.len(),
        );
    }
    Some(message)
}

/// Logged samples by topic, sequence number and stamp (a restarted publisher counts its
/// sequence numbers from 0 again; the stamp tells its samples from the old ones).
#[derive(Debug, Default)]
pub struct SampleIndex {
    samples: HashMap<(String, u64, u64), RawSample>,
}

impl SampleIndex {
    /// An index of `samples`.
    pub fn new(samples: impl IntoIterator<Item = RawSample>) -> Self {
        Self {
            samples: samples
                .into_iter()
                .map(|s| ((s.topic.to_owned(), s.seq, s.stamp_ns), s))
                .collect(),
        }
    }

    /// The sample of `topic` with sequence number `seq` and stamp `stamp_ns`.
    pub fn get(&self, topic: &str, seq: u64, stamp_ns: u64) -> Option<&RawSample> {
        self.samples.get(&(topic.to_owned(), seq, stamp_ns))
    }

    /// Samples indexed.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the index is empty.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

/// The samples one logged cycle consumed, as a [`Source`].
pub struct ReplaySource<'a> {
    index: &'a SampleIndex,
    consumed: &'a [Consumed],
    /// Consumed samples missing from the log.
    pub missing: usize,
}

impl<'a> ReplaySource<'a> {
    /// The source of a cycle that consumed `consumed`, looked up in `index`.
    pub fn new(index: &'a SampleIndex, consumed: &'a [Consumed]) -> Self {
        Self {
            index,
            consumed,
            missing: 0,
        }
    }

    fn samples<T: Message>(&mut self, topic: Topic<T>) -> Vec<Box<T>> {
        let mut out = Vec::new();
        for c in self.consumed.iter().filter(|c| c.topic == topic.name()) {
            match self
                .index
                .get(c.topic, c.seq, c.stamp_ns)
                .and_then(|s| from_raw::<T>(&s.bytes))
            {
                Some(m) => out.push(m),
                None => self.missing += 1,
            }
        }
        out
    }
}

impl Source for ReplaySource<'_> {
    fn latest<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<T>) {
        if let Some(m) = self.samples(topic).pop() {
            *slot = Some(*m);
        }
    }

    fn latest_shared<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<Arc<T>>) {
        if let Some(m) = self.samples(topic).pop() {
            *slot = Some(Arc::from(m));
        }
    }

    fn queue<T: Message>(&mut self, topic: Topic<T>, out: &mut Vec<T>) {
        out.extend(self.samples(topic).into_iter().map(|m| *m));
    }
}

/// The first field where a replayed output differs from the logged one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Difference {
    /// The topic.
    pub topic: String,
    /// The field path, e.g. `velocity[2]`.
    pub field: String,
    /// The logged value.
    pub logged: String,
    /// The replayed value.
    pub replayed: String,
}

/// A [`Sink`] that compares each output with the logged sample the cycle produced on its topic.
pub struct CompareSink<'a> {
    index: &'a SampleIndex,
    produced: &'a [Consumed],
    /// The first difference of the cycle, if any.
    pub difference: Option<Difference>,
}

impl<'a> CompareSink<'a> {
    /// A sink comparing against the samples `produced` (looked up in `index`).
    pub fn new(index: &'a SampleIndex, produced: &'a [Consumed]) -> Self {
        Self {
            index,
            produced,
            difference: None,
        }
    }

    fn compare<T: Message>(&mut self, topic: Topic<T>, replayed: &T) {
        if self.difference.is_some() {
            return;
        }
        let logged = self
            .produced
            .iter()
            .find(|c| c.topic == topic.name())
            .and_then(|c| self.index.get(c.topic, c.seq, c.stamp_ns))
            .and_then(|s| from_raw::<T>(&s.bytes));
        let Some(logged) = logged else {
            self.difference = Some(Difference {
                topic: topic.name().to_owned(),
                field: "(sample)".into(),
                logged: "none".into(),
                replayed: "published".into(),
            });
            return;
        };
        let (a, b) = (
            leaves(&format!("{logged:?}")),
            leaves(&format!("{replayed:?}")),
        );
        for ((path, x), (_, y)) in a.iter().zip(&b) {
            if x != y && !ignored(path) {
                self.difference = Some(Difference {
                    topic: topic.name().to_owned(),
                    field: path.clone(),
                    logged: x.clone(),
                    replayed: y.clone(),
                });
                return;
            }
        }
    }

    /// Notes outputs the log has but the replay did not publish.
    pub fn finish(&mut self, published: &[&str]) {
        if self.difference.is_some() {
            return;
        }
        if let Some(c) = self.produced.iter().find(|c| !published.contains(&c.topic)) {
            self.difference = Some(Difference {
                topic: c.topic.to_owned(),
                field: "(sample)".into(),
                logged: "published".into(),
                replayed: "none".into(),
            });
        }
    }
}

/// Fields replay does not compare: the runtime's sequence number, the QP's wall-clock solve
/// time and the time a publisher sent the sample ([`Message::publication_stamp_mut`]).
fn ignored(path: &str) -> bool {
    path.ends_with("header.seq") || path.ends_with("solve_time_ns") || path == "published_ns"
}

impl Sink for CompareSink<'_> {
    fn publish<T: Message>(&mut self, topic: Topic<T>, message: &T) {
        self.compare(topic, message);
    }
}

/// The leaves of a `{:?}` rendering of a struct: `(path, value)` in field order, e.g.
/// `("header.stamp_ns", "5")`, `("position[2]", "0.1")`.
pub fn leaves(debug: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut path: Vec<String> = Vec::new();
    let mut index: Vec<Option<usize>> = Vec::new();
    let mut key = String::new();
    let mut token = String::new();
    let flush = |token: &mut String,
                 path: &[String],
                 index: &[Option<usize>],
                 key: &str,
                 out: &mut Vec<(String, String)>| {
        let value = token.trim();
        if value.is_empty() {
            return;
        }
        let mut p = path.join(".");
        if let Some(Some(i)) = index.last() {
            p.push_str(&format!("[{i}]"));
        } else if !key.is_empty() {
            if !p.is_empty() {
                p.push('.');
            }
            p.push_str(key);
        }
        out.push((p, value.to_owned()));
        token.clear();
    };
    for ch in debug.chars() {
        match ch {
            '{' => {
                token.clear();
                if !key.is_empty() {
                    path.push(std::mem::take(&mut key));
                }
                index.push(None);
            }
            '[' => {
                token.clear();
                if !key.is_empty() {
                    path.push(std::mem::take(&mut key));
                }
                index.push(Some(0));
            }
            '}' | ']' => {
                flush(&mut token, &path, &index, &key, &mut out);
                key.clear();
                index.pop();
                if !path.is_empty() && index.len() < path.len() + 1 {
                    path.pop();
                }
            }
            ',' => {
                flush(&mut token, &path, &index, &key, &mut out);
                key.clear();
                if let Some(Some(i)) = index.last_mut() {
                    *i += 1;
                }
            }
            ':' if index.last().is_some_and(Option::is_none) => {
                key = token.trim().to_owned();
                token.clear();
            }
            _ => token.push(ch),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::{JointState, topics};

    #[test]
    fn leaves_name_nested_fields_and_array_elements() {
        let l = leaves("A { header: H { stamp_ns: 5, seq: 1 }, count: 2, v: [1.0, 2.5] }");
        assert_eq!(
            l,
            vec![
                ("header.stamp_ns".to_owned(), "5".to_owned()),
                ("header.seq".to_owned(), "1".to_owned()),
                ("count".to_owned(), "2".to_owned()),
                ("v[0]".to_owned(), "1.0".to_owned()),
                ("v[1]".to_owned(), "2.5".to_owned()),
            ]
        );
    }

    #[test]
    fn a_changed_field_is_reported_with_both_values_and_the_sequence_number_is_not() {
        let mut logged = JointState::zeroed();
        logged.joint_count = 2;
        logged.position[1] = 0.5;
        logged.header.seq = 7;
        let index = SampleIndex::new([RawSample {
            topic: topics::ARM_JOINT_STATE.name(),
            seq: 7,
            stamp_ns: 0,
            bytes: raw_bytes(&logged),
        }]);
        let produced = [Consumed {
            topic: topics::ARM_JOINT_STATE.name(),
            seq: 7,
            stamp_ns: 0,
        }];
        let mut same = logged;
        same.header.seq = 0;
        let mut sink = CompareSink::new(&index, &produced);
        sink.publish(topics::ARM_JOINT_STATE, &same);
        assert_eq!(sink.difference, None);
        let mut changed = same;
        changed.position[1] = 0.25;
        let mut sink = CompareSink::new(&index, &produced);
        sink.publish(topics::ARM_JOINT_STATE, &changed);
        let d = sink.difference.unwrap();
        assert_eq!(
            (d.field.as_str(), d.logged.as_str(), d.replayed.as_str()),
            ("position[1]", "0.5", "0.25")
        );
        // The consumed sample reads back as it was logged.
        let mut source = ReplaySource::new(&index, &produced);
        let mut slot = None;
        source.latest(topics::ARM_JOINT_STATE, &mut slot);
        assert_eq!(slot.map(|m| m.position[1]), Some(0.5));
        assert_eq!(source.missing, 0);
    }
}
