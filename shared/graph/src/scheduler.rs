//! The in-process runtime: a deterministic scheduler of tasks over the [`MemBus`], in lockstep
//! simulated time.
//!
//! Time advances in ticks of `tick_ns` (the physics step). At each tick every task runs, in
//! the order it was added (upstream first, as [`crate::GRAPH`] lists them), when its trigger
//! says so:
//! - [`Trigger::Timer`]: when its next release time has come (releases are `period` apart,
//!   from its first tick);
//! - [`Trigger::Arrival`]: when one of the trigger inputs holds a sample it has not read, or,
//!   if nothing arrived, once a period has passed since its last cycle.
//!
//! A task runs at most once per tick, and a sample published earlier in the same tick is
//! visible to the tasks after it (an event-driven chain reaches its end in one tick, as the
//! deployed iceoryx2 events do). Edge delays ([`MemBus::set_delay`]) model slower links.

use std::any::Any;

use crate::membus::{MemBus, ReaderId};
use crate::replay::{CompareSink, Difference, ReplaySource, SampleIndex};
use crate::spec::{TaskSpec, Trigger};
use crate::task::{Consumed, PortSet, Task};

/// What one cycle of a task did, for logs and replay.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleRecord {
    /// The task's name.
    pub task: &'static str,
    /// The task's cycle number, from 0.
    pub cycle: u64,
    /// The cycle's time, ns.
    pub now_ns: u64,
    /// The input samples the cycle consumed.
    pub consumed: Vec<Consumed>,
    /// The samples the cycle published.
    pub produced: Vec<Consumed>,
}

/// What replaying one logged cycle of a task gave.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayedCycle {
    /// The first output field that differs from the log, if any.
    pub difference: Option<Difference>,
    /// Consumed samples the log did not hold.
    pub missing_inputs: usize,
}

/// A task with its inputs, type-erased for the scheduler.
trait Scheduled {
    fn name(&self) -> &'static str;
    fn run(
        &mut self,
        bus: &mut MemBus,
        reader: ReaderId,
        record: Option<&mut Vec<CycleRecord>>,
        step_ns: Option<&mut Vec<u64>>,
    );
    fn replay(&mut self, record: &CycleRecord, index: &SampleIndex) -> ReplayedCycle;
    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

/// A task and the inputs it keeps between cycles.
struct Slot<T: Task> {
    task: T,
    inputs: T::Inputs,
    cycle: u64,
}

impl<T: Task + 'static> Scheduled for Slot<T> {
    fn name(&self) -> &'static str {
        self.task.name()
    }

    fn run(
        &mut self,
        bus: &mut MemBus,
        reader: ReaderId,
        record: Option<&mut Vec<CycleRecord>>,
        step_ns: Option<&mut Vec<u64>>,
    ) {
        let now = bus.now_ns();
        self.inputs.clear_queues();
        self.inputs.read(&mut bus.port(reader));
        let started = step_ns.is_some().then(std::time::Instant::now);
        let outputs = self.task.step(now, &self.inputs);
        if let (Some(times), Some(started)) = (step_ns, started) {
            times.push(started.elapsed().as_nanos() as u64);
        }
        let mut port = bus.port(reader);
        outputs.write(&mut port);
        let produced = port.produced();
        if let Some(records) = record {
            let mut consumed = Vec::new();
            self.inputs.held(&mut consumed);
            records.push(CycleRecord {
                task: self.task.name(),
                cycle: self.cycle,
                now_ns: now,
                consumed,
                produced,
            });
        }
        self.cycle += 1;
    }

    fn replay(&mut self, record: &CycleRecord, index: &SampleIndex) -> ReplayedCycle {
        let mut inputs = T::Inputs::default();
        let mut source = ReplaySource::new(index, &record.consumed);
        inputs.read(&mut source);
        let outputs = self.task.step(record.now_ns, &inputs);
        let mut published = Vec::new();
        let mut held = Vec::new();
        outputs.held(&mut held);
        published.extend(held.iter().map(|c| c.topic));
        let mut sink = CompareSink::new(index, &record.produced);
        outputs.write(&mut sink);
        sink.finish(&published);
        self.cycle += 1;
        ReplayedCycle {
            difference: sink.difference,
            missing_inputs: source.missing,
        }
    }

    fn as_any(&self) -> &dyn Any {
        &self.task
    }

    fn as_any_mut(&mut self) -> &mut dyn Any {
        &mut self.task
    }
}

/// One scheduled task and its timing.
struct Entry {
    slot: Box<dyn Scheduled>,
    period_ns: u64,
    next_release_ns: u64,
    last_run_ns: Option<u64>,
    arrival: Vec<&'static str>,
    /// Wall-clock durations of the task's steps, ns, when timed ([`Scheduler::time_steps`]).
    step_ns: Option<Vec<u64>>,
}

/// The deterministic in-process scheduler.
pub struct Scheduler {
    bus: MemBus,
    tick_ns: u64,
    entries: Vec<Entry>,
    records: Option<Vec<CycleRecord>>,
}

impl Scheduler {
    /// A scheduler stepping time by `tick_ns` (at least 1).
    pub fn new(tick_ns: u64) -> Self {
        Self {
            bus: MemBus::new(),
            tick_ns: tick_ns.max(1),
            entries: Vec::new(),
            records: None,
        }
    }

    /// Also keeps a [`CycleRecord`] of every cycle of every task ([`Scheduler::take_records`]).
    pub fn record_cycles(&mut self) {
        self.records.get_or_insert_with(Vec::new);
    }

    /// Also measures the wall-clock time of every step of every task added so far
    /// ([`Scheduler::step_times`]); for benchmarks (the schedule itself never reads a clock).
    pub fn time_steps(&mut self) {
        for entry in &mut self.entries {
            entry.step_ns.get_or_insert_with(Vec::new);
        }
    }

    /// The measured step durations of each timed task, ns, in task order.
    pub fn step_times(&self) -> Vec<(&'static str, &[u64])> {
        self.entries
            .iter()
            .filter_map(|e| e.step_ns.as_deref().map(|t| (e.slot.name(), t)))
            .collect()
    }

    /// The cycle records kept since the last call.
    pub fn take_records(&mut self) -> Vec<CycleRecord> {
        self.records
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Adds `task`, run at `rate_hz` with the trigger of its row `spec`; returns its reader id
    /// on the bus. Tasks run in the order they are added.
    pub fn add<T: Task + 'static>(&mut self, task: T, spec: &TaskSpec, rate_hz: f64) -> ReaderId {
        let period_ns = ((1e9 / rate_hz).round() as u64).max(1);
        let arrival = match spec.trigger {
            Trigger::Timer => Vec::new(),
            Trigger::Arrival(topics) => topics.iter().map(|t| t.name).collect(),
        };
        self.entries.push(Entry {
            slot: Box::new(Slot {
                task,
                inputs: T::Inputs::default(),
                cycle: 0,
            }),
            period_ns,
            next_release_ns: self.bus.now_ns(),
            last_run_ns: None,
            arrival,
            step_ns: None,
        });
        self.entries.len() - 1
    }

    /// The bus (to set edge delays, publish from outside, or read what was published).
    pub fn bus(&mut self) -> &mut MemBus {
        &mut self.bus
    }

    /// The simulated time, ns.
    pub fn now_ns(&self) -> u64 {
        self.bus.now_ns()
    }

    /// The task of type `T` named `name`, to read its state.
    pub fn task<T: 'static>(&self, name: &str) -> Option<&T> {
        self.entries
            .iter()
            .find(|e| e.slot.name() == name)
            .and_then(|e| e.slot.as_any().downcast_ref())
    }

    /// The task of type `T` named `name`, mutable (tests inject faults through it).
    pub fn task_mut<T: 'static>(&mut self, name: &str) -> Option<&mut T> {
        self.entries
            .iter_mut()
            .find(|e| e.slot.name() == name)
            .and_then(|e| e.slot.as_any_mut().downcast_mut())
    }

    /// Names of the scheduled tasks, in order.
    pub fn task_names(&self) -> Vec<&'static str> {
        self.entries.iter().map(|e| e.slot.name()).collect()
    }

    /// Replays the logged cycle `record` of its task (fed from `index`), comparing its outputs
    /// with the logged ones; `None` when no task of that name is scheduled. Replay steps the
    /// task's own state forward, so cycles must be replayed in order.
    pub fn replay(&mut self, record: &CycleRecord, index: &SampleIndex) -> Option<ReplayedCycle> {
        self.entries
            .iter_mut()
            .find(|e| e.slot.name() == record.task)
            .map(|e| e.slot.replay(record, index))
    }

    /// Runs the tasks due at the current time, then advances time by one tick.
    pub fn tick(&mut self) {
        let now = self.bus.now_ns();
        for (reader, entry) in self.entries.iter_mut().enumerate() {
            let arrived = entry
                .arrival
                .iter()
                .any(|topic| self.bus.has_new(topic, reader));
            let due = if entry.arrival.is_empty() {
                now >= entry.next_release_ns
            } else {
                arrived
                    || entry
                        .last_run_ns
                        .is_none_or(|last| now >= last + entry.period_ns)
            };
            if !due {
                continue;
            }
            if entry.arrival.is_empty() {
                while entry.next_release_ns <= now {
                    entry.next_release_ns += entry.period_ns;
                }
            }
            entry.last_run_ns = Some(now);
            entry.slot.run(
                &mut self.bus,
                reader,
                self.records.as_mut(),
                entry.step_ns.as_mut(),
            );
        }
        self.bus.set_now_ns(now + self.tick_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ports;
    use crate::spec::Rate;
    use motm_msgs::{JointState, Message, TwistCommand, topics};

    ports! {
        /// Nothing.
        struct NoInputs {}
    }
    ports! {
        /// A joint state.
        struct JointOut {
            /// Out.
            latest joints: JointState = topics::ARM_JOINT_STATE,
        }
    }
    ports! {
        /// Joint states of one cycle.
        struct JointIn {
            /// In.
            queue joints: JointState = topics::ARM_JOINT_STATE,
        }
    }
    ports! {
        /// A twist.
        struct TwistOut {
            /// Out.
            latest twist: TwistCommand = topics::CONTROL_REACH_TWIST,
        }
    }

    /// Publishes a joint state every cycle.
    struct Source;
    impl Task for Source {
        type Inputs = NoInputs;
        type Outputs = JointOut;
        fn name(&self) -> &'static str {
            "source"
        }
        fn step(&mut self, _now: u64, _inputs: &NoInputs) -> JointOut {
            let mut joints = JointState::zeroed();
            joints.joint_count = 1;
            JointOut {
                joints: Some(joints),
            }
        }
    }

    /// Records when it ran and how many samples it got.
    #[derive(Default)]
    struct Reader {
        runs: Vec<(u64, usize)>,
    }
    impl Task for Reader {
        type Inputs = JointIn;
        type Outputs = TwistOut;
        fn name(&self) -> &'static str {
            "reader"
        }
        fn step(&mut self, now: u64, inputs: &JointIn) -> TwistOut {
            self.runs.push((now, inputs.joints.len()));
            TwistOut::default()
        }
    }

    const fn spec(name: &'static str, trigger: Trigger) -> TaskSpec {
        TaskSpec {
            name,
            inputs: &[],
            outputs: &[],
            rate: Rate::Control,
            trigger,
            control_path: false,
            sim_only: false,
            host: crate::spec::Host::Process,
            standby_of: None,
        }
    }

    #[test]
    fn a_timer_task_runs_at_its_rate_and_an_arrival_task_on_each_sample() {
        const TIMER: TaskSpec = spec("reader", Trigger::Timer);
        const ARRIVAL: TaskSpec = spec(
            "reader",
            Trigger::Arrival(&[topics::ARM_JOINT_STATE.spec()]),
        );
        for (trigger, expected_runs) in [(TIMER, 3usize), (ARRIVAL, 10)] {
            let mut scheduler = Scheduler::new(1_000_000);
            scheduler.record_cycles();
            scheduler.add(Source, &spec("source", Trigger::Timer), 1000.0);
            scheduler.add(Reader::default(), &trigger, 250.0);
            for _ in 0..10 {
                scheduler.tick();
            }
            let reader = scheduler.task::<Reader>("reader").unwrap();
            assert_eq!(reader.runs.len(), expected_runs, "{trigger:?}");
            // Every sample reaches the reader, within the tick it was published in.
            let total: usize = reader.runs.iter().map(|r| r.1).sum();
            assert!(total >= reader.runs.len(), "{:?}", reader.runs);
            assert_eq!(reader.runs[0], (0, 1));
            let records = scheduler.take_records();
            assert_eq!(
                records.iter().filter(|r| r.task == "reader").count(),
                expected_runs
            );
        }
    }
}
