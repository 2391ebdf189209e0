//! The task interface: a task is a struct with typed inputs, outputs and config, and a pure
//! [`Task::step`]. It never opens a port, sleeps or loops; a runtime (the deployed service
//! main, or the in-process [`crate::Scheduler`]) fills its inputs from a bus, steps it and
//! publishes its outputs.

use std::sync::Arc;

use motm_msgs::{Message, Topic, TopicSpec};

/// One process's logic as a pure step from typed inputs to typed outputs.
pub trait Task {
    /// The topics the task reads, as a [`PortSet`] (latest values persist between cycles;
    /// queued samples are those that arrived since the previous cycle).
    type Inputs: PortSet + Default;
    /// The topics the task publishes, as a [`PortSet`] (only the fields that are set).
    type Outputs: PortSet;

    /// The task's name in the graph table ([`crate::GRAPH`]).
    fn name(&self) -> &'static str;

    /// One cycle at monotonic time `now_ns` (the same clock the message stamps use).
    fn step(&mut self, now_ns: u64, inputs: &Self::Inputs) -> Self::Outputs;

    /// What the last step has for the operator (a change of state), if anything. A task never
    /// prints: the deployed runtime prints this after the cycle.
    fn notice(&self) -> Option<&str> {
        None
    }
}

/// Where a runtime takes samples from: an iceoryx2 node or the in-memory bus. Every sample is
/// validated ([`Message::validate`]) before it is handed out; rejected samples are dropped and
/// counted by the source.
pub trait Source {
    /// Replaces `slot` with the newest valid sample on `topic` that arrived since the last
    /// call (leaves it when nothing new came).
    fn latest<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<T>);

    /// [`Source::latest`] for large payloads (camera images), shared instead of copied.
    fn latest_shared<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<Arc<T>>);

    /// Appends every valid sample on `topic` that arrived since the last call, oldest first.
    fn queue<T: Message>(&mut self, topic: Topic<T>, out: &mut Vec<T>);
}

/// Where a runtime publishes outputs. The sink assigns the sequence number; a header stamp of
/// zero is replaced by the publication time, any other stamp is kept (a camera frame carries
/// its exposure time).
pub trait Sink {
    /// Publishes `message` on `topic`.
    fn publish<T: Message>(&mut self, topic: Topic<T>, message: &T);

    /// Publishes a shared large payload (the in-memory bus shares it without copying).
    fn publish_shared<T: Message>(&mut self, topic: Topic<T>, message: Arc<T>) {
        self.publish(topic, message.as_ref());
    }
}

/// One input sample a task consumed in a cycle, for replay logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Consumed {
    /// Service name of the topic.
    pub topic: &'static str,
    /// The sample's sequence number.
    pub seq: u64,
    /// The sample's stamp, ns.
    pub stamp_ns: u64,
}

/// A set of typed ports, declared with [`ports!`](crate::ports): the inputs or the outputs of
/// a task.
pub trait PortSet {
    /// The topics of the set, in field order.
    const TOPICS: &'static [TopicSpec];

    /// Takes in what arrived on every topic from `source`.
    fn read<S: Source>(&mut self, source: &mut S);

    /// Publishes every field that holds a value to `sink`.
    fn write<K: Sink>(self, sink: &mut K);

    /// Empties the queued fields (before a cycle's read).
    fn clear_queues(&mut self);

    /// The samples held, by topic and sequence number (what a cycle consumed, for replay).
    fn held(&self, out: &mut Vec<Consumed>);

    /// Calls `visitor` once per topic of the set, typed, in field order (a runtime opens its
    /// ports with it before the first cycle).
    fn visit<V: TopicVisitor>(visitor: &mut V);
}

/// Something that is shown every typed topic of a [`PortSet`] ([`PortSet::visit`]).
pub trait TopicVisitor {
    /// One topic of the set.
    fn topic<T: Message>(&mut self, topic: Topic<T>);
}

/// The [`Consumed`] record of one sample on `topic`.
pub fn consumed<T: Message>(topic: Topic<T>, message: &T) -> Consumed {
    Consumed {
        topic: topic.name(),
        seq: message.header().seq,
        stamp_ns: message.header().stamp_ns,
    }
}

/// An all-zero message on the heap, never built on the stack (camera images are hundreds of
/// kilobytes).
pub fn boxed_zeroed<T: Message>() -> Box<T> {
    // SAFETY: all-zero bytes are a valid `T` (the `Message` contract); the header is then set
    // as `Message::zeroed` sets it.
    let mut message = unsafe { Box::<T>::new_zeroed().assume_init() };
    *message.header_mut() = motm_msgs::Header::new(0, 0);
    message
}

/// An all-zero message in a fresh [`Arc`] (so no other owner yet: [`Arc::get_mut`] succeeds),
/// never built on the stack; a payload written into it is published without another copy.
pub fn shared_zeroed<T: Message>() -> Arc<T> {
    // SAFETY: all-zero bytes are a valid `T` (the `Message` contract).
    let mut message = unsafe { Arc::<T>::new_zeroed().assume_init() };
    *Arc::get_mut(&mut message)
        .expect("a fresh Arc has one owner")
        .header_mut() = motm_msgs::Header::new(0, 0);
    message
}

/// A shared copy of `message`, copied once straight into its [`Arc`] and never built on the
/// stack (camera images are hundreds of kilobytes).
pub fn shared_copy<T: Message>(message: &T) -> Arc<T> {
    let mut shared = Arc::<T>::new_uninit();
    let slot = Arc::get_mut(&mut shared).expect("a fresh Arc has one owner");
    // SAFETY: the copy writes exactly one `T` into the fresh allocation, which is then
    // initialised.
    unsafe {
        std::ptr::copy_nonoverlapping(message as *const T, slot.as_mut_ptr(), 1);
        shared.assume_init()
    }
}

/// Declares a [`PortSet`]: a struct whose fields are typed ports.
///
/// Each field is `latest NAME: Type = TOPIC` (an `Option<Type>` holding the newest sample),
/// `shared NAME: Type = TOPIC` (an `Option<Arc<Type>>`, for large payloads) or
/// `queue NAME: Type = TOPIC` (a `Vec<Type>` of the samples of one cycle).
///
/// ```
/// use motm_graph::ports;
/// use motm_msgs::{JointState, TwistCommand, topics};
///
/// ports! {
///     /// What an example task reads.
///     pub struct ExampleInputs {
///         /// The newest joint state.
///         latest joints: JointState = topics::ARM_JOINT_STATE,
///         /// Every twist of the cycle.
///         queue twists: TwistCommand = topics::CONTROL_FINAL_TWIST,
///     }
/// }
/// use motm_graph::PortSet;
/// assert_eq!(ExampleInputs::TOPICS.len(), 2);
/// ```
#[macro_export]
macro_rules! ports {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $(
                $(#[$fmeta:meta])*
                $kind:ident $field:ident : $ty:ty = $topic:expr
            ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Default)]
        $vis struct $name {
            $(
                $(#[$fmeta])*
                pub $field: $crate::ports!(@ty $kind $ty),
            )*
        }

        impl $crate::PortSet for $name {
            const TOPICS: &'static [$crate::TopicSpec] = &[$($topic.spec()),*];

            #[allow(unused_variables)]
            fn read<S: $crate::Source>(&mut self, source: &mut S) {
                $($crate::ports!(@read $kind source, $topic, self.$field);)*
            }

            #[allow(unused_variables)]
            fn write<K: $crate::Sink>(self, sink: &mut K) {
                $($crate::ports!(@write $kind sink, $topic, self.$field);)*
            }

            fn clear_queues(&mut self) {
                $($crate::ports!(@clear $kind self.$field);)*
            }

            #[allow(unused_variables)]
            fn held(&self, out: &mut Vec<$crate::Consumed>) {
                $($crate::ports!(@held $kind out, $topic, self.$field);)*
            }

            #[allow(unused_variables)]
            fn visit<V: $crate::TopicVisitor>(visitor: &mut V) {
                $(visitor.topic($topic);)*
            }
        }
    };
    (@ty latest $ty:ty) => { Option<$ty> };
    (@ty shared $ty:ty) => { Option<std::sync::Arc<$ty>> };
    (@ty queue $ty:ty) => { Vec<$ty> };
    (@read latest $s:ident, $topic:expr, $f:expr) => { $s.latest($topic, &mut $f) };
    (@read shared $s:ident, $topic:expr, $f:expr) => { $s.latest_shared($topic, &mut $f) };
    (@read queue $s:ident, $topic:expr, $f:expr) => { $s.queue($topic, &mut $f) };
    (@write latest $k:ident, $topic:expr, $f:expr) => {
        if let Some(m) = &$f { $k.publish($topic, m) }
    };
    (@write shared $k:ident, $topic:expr, $f:expr) => {
        if let Some(m) = $f { $k.publish_shared($topic, m) }
    };
    (@write queue $k:ident, $topic:expr, $f:expr) => {
        for m in &$f { $k.publish($topic, m) }
    };
    (@clear latest $f:expr) => { () };
    (@clear shared $f:expr) => { () };
    (@clear queue $f:expr) => { $f.clear() };
    (@held latest $o:ident, $topic:expr, $f:expr) => {
        if let Some(m) = &$f { $o.push($crate::consumed($topic, m)) }
    };
    (@held shared $o:ident, $topic:expr, $f:expr) => {
        if let Some(m) = &$f { $o.push($crate::consumed($topic, m.as_ref())) }
    };
    (@held queue $o:ident, $topic:expr, $f:expr) => {
        for m in &$f { $o.push($crate::consumed($topic, m)) }
    };
}
