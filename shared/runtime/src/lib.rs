//! # motm-runtime
//!
//! The deployed form of a [`motm_graph::Task`]: the task runs as a process over iceoryx2, the
//! same code the in-process [`motm_graph::Scheduler`] runs over its in-memory bus.
//!
//! - [`BusPorts`] implements [`Source`] and [`Sink`] over `motm-bus` ports: one
//!   [`Subscriber`] per input topic and one [`Publisher`] per output topic, opened before the
//!   first cycle ([`BusPorts::open`]) and typed back by the [`Topic`] on each access.
//! - [`TaskPorts`] runs one cycle of a task on them (clear the queues, read, step, write): the
//!   supervisor steps its mission task with it inside its own loop.
//! - [`run_task`] runs a task on the standard [`ServiceLoop`] by its row's [`Trigger`]: a
//!   periodic timer, or the iceoryx2 events of its trigger inputs with a timeout of one
//!   period.
//!
//! Settings of the services ([`qos`]): the camera image uses [`Qos::large`]; publishers of a
//! topic that some task's [`Trigger::Arrival`] names notify its ready event
//! ([`Qos::waking`]), and a task listens to the events of its own trigger inputs only.
//!
//! Stamps: a task's output with a zero header stamp is stamped with the monotonic time at
//! publication; any other stamp is kept ([`Stamp::At`]). The publisher assigns the sequence
//! numbers.
//!
//! Replay records: after each cycle, [`TaskPorts::step`] publishes a [`msgs::TaskCycle`] on
//! [`topics::REPLAY_CYCLES`]: the task, its cycle and time, the samples its inputs held and the
//! samples it published (topic, sequence number, stamp). The logger writes them, with the raw
//! samples, into a log that `motm replay` feeds through the same tasks.

use std::any::Any;
use std::collections::HashMap;
use std::sync::Arc;

use motm_bus::{
    Bus, BusError, CycleStats, Flow, LoopConfig, LoopExit, Publisher, Qos, ServiceLoop, Stamp,
    Subscriber, Trigger as ReadyTrigger,
};
use motm_graph::{
    Consumed, PortSet, Sink, Source, Task, TaskSpec, TopicVisitor, Trigger, shared_copy,
};
use motm_msgs::{self as msgs, Message, Topic, topics};

/// The service settings of `topic` (the same in every process, since the first one to open a
/// service fixes them): [`Qos::large`] for the camera image, the defaults otherwise; with
/// [`Qos::waking`] when some task of [`motm_graph::GRAPH`] runs on its samples' arrival.
pub fn qos(topic: &str) -> Qos {
    let base = if topic == topics::CAMERA_IMAGE.name() {
        Qos::large()
    } else if topic == topics::REPLAY_CYCLES.name() {
        // Every task process publishes its cycles here (a restarted one beside the old one
        // for a moment), together thousands a second: the logger's queue holds half a second
        // of them at 4 kHz, and only the logger (and a spare) reads them.
        Qos {
            max_publishers: 2 * motm_graph::GRAPH.len(),
            max_subscribers: 2,
            tap_buffer: 2048,
            ..Qos::default()
        }
    } else if [
        topics::ARM_VELOCITY_COMMAND.name(),
        topics::BASE_VELOCITY_COMMAND.name(),
        topics::ARM_GRIPPER_COMMAND.name(),
    ]
    .contains(&topic)
    {
        // Commands: the drivers take every sample, so a driver that falls behind for a while
        // still sees each one.
        Qos {
            subscriber_buffer: 64,
            ..Qos::default()
        }
    } else {
        Qos::default()
    };
    if motm_graph::wakes_readers(topic) {
        base.waking()
    } else {
        base
    }
}

/// Subscribers kept free on every topic beyond the graph's readers: the logger, a tool
/// (`motm run`, `motm status`) and a restarted reader beside its dead predecessor's port.
pub const SPARE_SUBSCRIBERS: usize = 4;

/// The ports the graph needs on `topic`: `(publishers, subscribers)`, room for every task that
/// writes or reads it (a hot standby writes and reads what its primary does), twice the
/// writers (a restart beside its predecessor, a fault injector) and [`SPARE_SUBSCRIBERS`]
/// beyond the readers. [`Qos::default`] must cover it on every topic (a test checks), so
/// that whichever process creates a service, the stack fits.
pub fn graph_ports(topic: &str) -> (usize, usize) {
    let readers = motm_graph::GRAPH.iter().filter(|t| t.reads(topic)).count();
    let writers = motm_graph::GRAPH.iter().filter(|t| t.writes(topic)).count();
    (2 * writers, readers + SPARE_SUBSCRIBERS)
}

/// The bus ports of one task: a [`Source`] and a [`Sink`] over iceoryx2.
pub struct BusPorts {
    /// `Subscriber<T>` by topic name.
    subscribers: HashMap<&'static str, Box<dyn Any>>,
    /// `Publisher<T>` by topic name.
    publishers: HashMap<&'static str, Box<dyn Any>>,
    /// Ready events of the task's trigger inputs.
    triggers: Vec<ReadyTrigger>,
    /// The samples published in the current cycle.
    produced: Vec<Consumed>,
    /// Failed receives and publishes (each leaves the previous value in use).
    failures: u64,
    /// The last failure.
    last_failure: Option<BusError>,
}

/// Opens a port per visited topic.
struct Opener<'a> {
    bus: &'a Bus,
    spec: &'a TaskSpec,
    ports: &'a mut BusPorts,
    publish: bool,
    /// Topics not opened.
    except: &'a [&'a str],
    error: Option<BusError>,
}

impl TopicVisitor for Opener<'_> {
    fn topic<T: Message>(&mut self, topic: Topic<T>) {
        let name = topic.name();
        if self.error.is_some() || self.except.contains(&name) {
            return;
        }
        let qos = qos(name);
        let opened = if self.publish {
            Publisher::<T>::new(self.bus, name, &qos)
                .map(|p| self.ports.publishers.insert(name, Box::new(p)))
                .map(drop)
        } else {
            // Only the task's own trigger inputs need a listener (each takes an event slot).
            let wake = self.spec.triggered_by(name);
            let qos = Qos {
                wake_readers: wake,
                ..qos
            };
            Subscriber::<T>::new(self.bus, name, &qos).map(|s| {
                if let Some(trigger) = s.trigger() {
                    self.ports.triggers.push(trigger);
                }
                self.ports.subscribers.insert(name, Box::new(s));
            })
        };
        if let Err(e) = opened {
            self.error = Some(e);
        }
    }
}

impl BusPorts {
    /// Opens on `bus` one subscriber per topic of `I` and one publisher per topic of `O`, for
    /// the task of row `spec` (its trigger inputs also get their ready-event listeners).
    pub fn open<I: PortSet, O: PortSet>(bus: &Bus, spec: &TaskSpec) -> Result<Self, BusError> {
        Self::open_except::<I, O>(bus, spec, &[])
    }

    /// [`BusPorts::open`] without the topics named in `except` (a driver on real hardware:
    /// its `hw/*` topics are the robot). Reading or publishing one of them is a panic, like
    /// any topic outside the task's ports.
    pub fn open_except<I: PortSet, O: PortSet>(
        bus: &Bus,
        spec: &TaskSpec,
        except: &[&str],
    ) -> Result<Self, BusError> {
        let mut ports = Self {
            subscribers: HashMap::new(),
            publishers: HashMap::new(),
            triggers: Vec::new(),
            produced: Vec::new(),
            failures: 0,
            last_failure: None,
        };
        for publish in [false, true] {
            let mut opener = Opener {
                bus,
                spec,
                ports: &mut ports,
                publish,
                except,
                error: None,
            };
            if publish {
                O::visit(&mut opener);
            } else {
                I::visit(&mut opener);
            }
            if let Some(e) = opener.error {
                return Err(e);
            }
        }
        Ok(ports)
    }

    /// Takes the ready events of the trigger inputs (for [`ServiceLoop::run_on_arrival`]).
    pub fn take_triggers(&mut self) -> Vec<ReadyTrigger> {
        std::mem::take(&mut self.triggers)
    }

    /// Failed receives and publishes so far.
    pub fn failures(&self) -> u64 {
        self.failures
    }

    /// The last failed receive or publish.
    pub fn last_failure(&self) -> Option<&BusError> {
        self.last_failure.as_ref()
    }

    /// The subscriber of `topic`.
    fn subscriber<T: Message>(&mut self, topic: Topic<T>) -> &mut Subscriber<T> {
        self.subscribers
            .get_mut(topic.name())
            .and_then(|s| s.downcast_mut())
            .unwrap_or_else(|| panic!("{topic:?} is not an input of this task"))
    }

    /// Counts a failed receive or publish.
    fn failed(&mut self, error: BusError) {
        self.failures += 1;
        self.last_failure = Some(error);
    }
}

impl Source for BusPorts {
    fn latest<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<T>) {
        match self.subscriber(topic).latest() {
            Ok(Some(sample)) => *slot = Some(*sample),
            Ok(None) => {}
            Err(e) => self.failed(e),
        }
    }

    fn latest_shared<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<Arc<T>>) {
        match self.subscriber(topic).latest() {
            Ok(Some(sample)) => *slot = Some(shared_copy(&*sample)),
            Ok(None) => {}
            Err(e) => self.failed(e),
        }
    }

    fn queue<T: Message>(&mut self, topic: Topic<T>, out: &mut Vec<T>) {
        loop {
            match self.subscriber(topic).receive() {
                Ok(Some(sample)) => out.push(*sample),
                Ok(None) => return,
                Err(e) => return self.failed(e),
            }
        }
    }
}

impl Sink for BusPorts {
    fn publish<T: Message>(&mut self, topic: Topic<T>, message: &T) {
        let publisher: &mut Publisher<T> = self
            .publishers
            .get_mut(topic.name())
            .and_then(|p| p.downcast_mut())
            .unwrap_or_else(|| panic!("{topic:?} is not an output of this task"));
        let stamp_ns = match message.header().stamp_ns {
            0 => motm_bus::monotonic_now_ns(),
            ns => ns,
        };
        let seq = publisher.next_seq();
        match publisher.publish_copy(Stamp::At(stamp_ns), message) {
            Ok(()) => self.produced.push(Consumed {
                topic: topic.name(),
                seq,
                stamp_ns,
            }),
            Err(e) => self.failed(e),
        }
    }
}

/// A task's ports and the inputs it keeps between cycles: one call of [`TaskPorts::step`] is
/// one cycle.
pub struct TaskPorts<T: Task> {
    ports: BusPorts,
    inputs: T::Inputs,
    /// `None` for a task whose cycles are not recorded ([`motm_graph::records_cycles`]).
    cycles: Option<CycleLog>,
}

impl<T: Task> TaskPorts<T> {
    /// Opens the ports of task type `T`, row `spec`, on `bus`.
    pub fn open(bus: &Bus, spec: &TaskSpec) -> Result<Self, BusError> {
        Ok(Self {
            ports: BusPorts::open::<T::Inputs, T::Outputs>(bus, spec)?,
            inputs: T::Inputs::default(),
            cycles: motm_graph::records_cycles(spec)
                .then(|| CycleLog::open(bus, spec))
                .transpose()?,
        })
    }

    /// One cycle at `now_ns`: empties the queued inputs, takes in what arrived, steps `task`,
    /// publishes its outputs and then the cycle's [`msgs::TaskCycle`] record (when recorded).
    pub fn step(&mut self, task: &mut T, now_ns: u64) {
        self.inputs.clear_queues();
        self.inputs.read(&mut self.ports);
        self.ports.produced.clear();
        task.step(now_ns, &self.inputs).write(&mut self.ports);
        if let Some(cycles) = &mut self.cycles
            && let Err(e) = cycles.publish(now_ns, &self.inputs, &self.ports.produced)
        {
            self.ports.failed(e);
        }
    }

    /// The inputs as of the last cycle.
    pub fn inputs(&self) -> &T::Inputs {
        &self.inputs
    }

    /// The ports.
    pub fn ports(&self) -> &BusPorts {
        &self.ports
    }

    /// The ports, mutable (to take the triggers).
    pub fn ports_mut(&mut self) -> &mut BusPorts {
        &mut self.ports
    }
}

/// The publisher of a task's [`msgs::TaskCycle`] records, for replay logs.
struct CycleLog {
    publisher: Publisher<msgs::TaskCycle>,
    /// The task's index in [`motm_graph::GRAPH`].
    task: u32,
    /// This process's pid.
    pid: u32,
    /// Topic names in the order of [`motm_graph::published_topics`] (their index is their id).
    topics: Vec<&'static str>,
    cycle: u64,
    held: Vec<Consumed>,
    record: Box<msgs::TaskCycle>,
}

impl CycleLog {
    /// The cycle log of the task of row `spec`.
    fn open(bus: &Bus, spec: &TaskSpec) -> Result<Self, BusError> {
        let topic = topics::REPLAY_CYCLES.name();
        Ok(Self {
            publisher: Publisher::new(bus, topic, &qos(topic))?,
            task: motm_graph::GRAPH
                .iter()
                .position(|t| t.name == spec.name)
                .unwrap_or(usize::MAX) as u32,
            pid: std::process::id(),
            topics: motm_graph::published_topics()
                .iter()
                .map(|t| t.name)
                .collect(),
            cycle: 0,
            held: Vec::new(),
            record: Box::new(msgs::TaskCycle::zeroed()),
        })
    }

    /// Publishes the record of the cycle at `now_ns` that held `inputs` and published
    /// `produced`.
    fn publish(
        &mut self,
        now_ns: u64,
        inputs: &impl PortSet,
        produced: &[Consumed],
    ) -> Result<(), BusError> {
        self.held.clear();
        inputs.held(&mut self.held);
        let r = &mut *self.record;
        r.cycle = self.cycle;
        r.now_ns = now_ns;
        r.task = self.task;
        r.pid = self.pid;
        let mut n = 0;
        let mut truncated = false;
        let mut counts = [0u32; 2];
        for (list, count) in [&self.held[..], produced].into_iter().zip(&mut counts) {
            for sample in list {
                let Some(topic) = self.topics.iter().position(|t| *t == sample.topic) else {
                    truncated = true;
                    continue;
                };
                if n == msgs::CYCLE_SAMPLES {
                    truncated = true;
                    continue;
                }
                r.samples[n] = msgs::SampleRef {
                    topic: topic as u32,
                    reserved: 0,
                    seq: sample.seq,
                    stamp_ns: sample.stamp_ns,
                };
                n += 1;
                *count += 1;
            }
        }
        r.samples[n..].fill(msgs::SampleRef::default());
        [r.consumed, r.produced] = counts;
        r.truncated = truncated.into();
        self.cycle += 1;
        self.publisher.publish_copy(Stamp::At(now_ns), r)
    }
}

/// How a [`run_task`] ended, with the loop's statistics.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// Why the loop ended.
    pub exit: LoopExit,
    /// Cycles run.
    pub cycles: u64,
    /// Deadline misses.
    pub deadline_misses: u64,
    /// 99th percentile of the cycle time, ns.
    pub p99_cycle_ns: u64,
    /// Longest cycle, ns.
    pub max_cycle_ns: u64,
    /// Received messages dropped by validation.
    pub rejected_messages: u64,
    /// Failed receives and publishes.
    pub port_failures: u64,
}

impl RunReport {
    /// The report of a loop with statistics `stats` on `bus`.
    fn new(exit: LoopExit, stats: &mut CycleStats, bus: &Bus, port_failures: u64) -> Self {
        Self {
            exit,
            cycles: stats.cycles(),
            deadline_misses: stats.deadline_misses(),
            p99_cycle_ns: stats.percentile_ns(99.0),
            max_cycle_ns: stats.max_cycle_ns(),
            rejected_messages: bus.rejected_messages(),
            port_failures,
        }
    }

    /// The closing line of process `process`, with `details` from its task.
    pub fn line(&self, process: &str, details: &str) -> String {
        format!(
            "{process}: stopped after {} cycles, {} deadline misses, p99 cycle {} us, max {} us, {} rejected messages, {} port failures; {details}",
            self.cycles,
            self.deadline_misses,
            self.p99_cycle_ns / 1000,
            self.max_cycle_ns / 1000,
            self.rejected_messages,
            self.port_failures,
        )
    }
}

/// Runs `task` (row `spec`) on `bus` until SIGTERM or SIGINT: on the standard
/// [`ServiceLoop`] with `config` (its `period` is the task's rate), each cycle one
/// [`TaskPorts::step`] at the cycle's wake-up time. A [`Trigger::Timer`] task runs on the
/// periodic timer; a [`Trigger::Arrival`] task runs on each sample announced on its trigger
/// inputs, and after a whole period without one.
pub fn run_task<T: Task>(
    bus: &Bus,
    task: &mut T,
    spec: &TaskSpec,
    config: LoopConfig,
) -> Result<RunReport, BusError> {
    run_task_while(bus, task, spec, config, |_| true)
}

/// [`run_task`] that also ends after the first cycle after which `go_on(task)` is false.
pub fn run_task_while<T: Task>(
    bus: &Bus,
    task: &mut T,
    spec: &TaskSpec,
    config: LoopConfig,
    mut go_on: impl FnMut(&T) -> bool,
) -> Result<RunReport, BusError> {
    let mut ports = TaskPorts::<T>::open(bus, spec)?;
    let triggers = ports.ports_mut().take_triggers();
    let mut service = ServiceLoop::new(bus, config)?;
    let mut step = |cycle: &motm_bus::CycleContext| {
        ports.step(task, cycle.now_ns);
        if go_on(task) {
            Flow::Continue
        } else {
            Flow::Stop
        }
    };
    let exit = match spec.trigger {
        Trigger::Timer => service.run_periodic(&mut step)?,
        Trigger::Arrival(_) => service.run_on_arrival(&triggers, &mut step)?,
    };
    let failures = ports.ports().failures();
    Ok(RunReport::new(exit, service.stats_mut(), bus, failures))
}

/// Exit code of a service that failed at run time (the bus).
pub const EXIT_FAILED: u8 = 1;

/// The main of a service process: opens the bus as process `spec.name`, runs `task` with
/// [`run_task`] until SIGTERM or SIGINT, printing the task's [`Task::notice`] after each
/// cycle that has one, and prints the closing line (with `details` from the task); exits with
/// [`EXIT_FAILED`] and a message naming the process when the bus fails.
pub fn serve<T: Task>(
    spec: &TaskSpec,
    task: &mut T,
    config: LoopConfig,
    details: impl FnOnce(&T) -> String,
) -> std::process::ExitCode {
    let name = spec.name;
    let result = Bus::open(name).and_then(|bus| {
        let trigger = match spec.trigger {
            Trigger::Timer => "on its timer".to_owned(),
            Trigger::Arrival(topics) => {
                let names: Vec<&str> = topics.iter().map(|t| t.name).collect();
                format!("on {}", names.join(", "))
            }
        };
        motm_bus::say!(
            "{name}: running at {} Hz, {trigger}",
            1.0 / config.period.as_secs_f64()
        );
        run_task_while(&bus, task, spec, config, |task| {
            if let Some(notice) = task.notice() {
                motm_bus::say!("{name}: {notice}");
            }
            true
        })
    });
    match result {
        Ok(report) => {
            motm_bus::say!("{}", report.line(name, &details(task)));
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            motm_bus::say!("{name}: {e}");
            std::process::ExitCode::from(EXIT_FAILED)
        }
    }
}

#[cfg(test)]
mod tests;
