//! The motm control graph: every process is a [`Task`] (typed inputs and outputs, a pure
//! step), and the graph is data ([`GRAPH`]: each task, the typed topics it reads and writes,
//! its rate and its trigger). Two runtimes run the same tasks: the deployed service main over
//! iceoryx2 (in `motm-runtime`), and the deterministic in-process [`Scheduler`] over the
//! [`MemBus`], for fast Monte-Carlo trials and tests.

mod membus;
pub mod replay;
mod scheduler;
mod spec;
mod task;

pub use membus::{MemBus, MemPort, ReaderId};
pub use motm_msgs::{Topic, TopicSpec, topics};
pub use scheduler::{CycleRecord, Scheduler};
pub use spec::*;
pub use task::{
    Consumed, PortSet, Sink, Source, Task, TopicVisitor, boxed_zeroed, consumed, shared_copy,
    shared_zeroed,
};
