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
//! Stamps: a task's output with a zero header stamp is stamped at publication
//! ([`Stamp::Now`]); any other stamp is kept ([`Stamp::At`]). The publisher assigns the
//! sequence numbers.

use std::any::Any;
use std::collections::HashMap;
use std::sync::Arc;

use motm_bus::{
    Bus, BusError, CycleStats, Flow, LoopConfig, LoopExit, Publisher, Qos, ServiceLoop, Stamp,
    Subscriber, Trigger as ReadyTrigger,
};
use motm_graph::{PortSet, Sink, Source, Task, TaskSpec, TopicVisitor, Trigger, boxed_copy};
use motm_msgs::{Message, Topic, topics};

/// The service settings of `topic` (the same in every process, since the first one to open a
/// service fixes them): [`Qos::large`] for the camera image, the defaults otherwise; with
/// [`Qos::waking`] when some task of [`motm_graph::GRAPH`] runs on its samples' arrival.
pub fn qos(topic: &str) -> Qos {
    let base = if topic == topics::CAMERA_IMAGE.name() {
        Qos::large()
    } else {
        Qos::default()
    };
    if motm_graph::wakes_readers(topic) {
        base.waking()
    } else {
        base
    }
}

/// The bus ports of one task: a [`Source`] and a [`Sink`] over iceoryx2.
pub struct BusPorts {
    /// `Subscriber<T>` by topic name.
    subscribers: HashMap<&'static str, Box<dyn Any>>,
    /// `Publisher<T>` by topic name.
    publishers: HashMap<&'static str, Box<dyn Any>>,
    /// Ready events of the task's trigger inputs.
    triggers: Vec<ReadyTrigger>,
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
    error: Option<BusError>,
}

impl TopicVisitor for Opener<'_> {
    fn topic<T: Message>(&mut self, topic: Topic<T>) {
        if self.error.is_some() {
            return;
        }
        let name = topic.name();
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
        let mut ports = Self {
            subscribers: HashMap::new(),
            publishers: HashMap::new(),
            triggers: Vec::new(),
            failures: 0,
            last_failure: None,
        };
        for publish in [false, true] {
            let mut opener = Opener {
                bus,
                spec,
                ports: &mut ports,
                publish,
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
            Ok(Some(sample)) => *slot = Some(Arc::from(boxed_copy(&*sample))),
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
        let stamp = match message.header().stamp_ns {
            0 => Stamp::Now,
            ns => Stamp::At(ns),
        };
        if let Err(e) = publisher.publish_copy(stamp, message) {
            self.failed(e);
        }
    }
}

/// A task's ports and the inputs it keeps between cycles: one call of [`TaskPorts::step`] is
/// one cycle.
pub struct TaskPorts<T: Task> {
    ports: BusPorts,
    inputs: T::Inputs,
}

impl<T: Task> TaskPorts<T> {
    /// Opens the ports of task type `T`, row `spec`, on `bus`.
    pub fn open(bus: &Bus, spec: &TaskSpec) -> Result<Self, BusError> {
        Ok(Self {
            ports: BusPorts::open::<T::Inputs, T::Outputs>(bus, spec)?,
            inputs: T::Inputs::default(),
        })
    }

    /// One cycle at `now_ns`: empties the queued inputs, takes in what arrived, steps `task`
    /// and publishes its outputs.
    pub fn step(&mut self, task: &mut T, now_ns: u64) {
        self.inputs.clear_queues();
        self.inputs.read(&mut self.ports);
        task.step(now_ns, &self.inputs).write(&mut self.ports);
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
/// [`run_task`] until SIGTERM or SIGINT and prints the closing line (with `details` from the
/// task); exits with [`EXIT_FAILED`] and a message naming the process when the bus fails.
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
        eprintln!(
            "{name}: running at {} Hz, {trigger}",
            1.0 / config.period.as_secs_f64()
        );
        run_task(&bus, task, spec, config)
    });
    match result {
        Ok(report) => {
            eprintln!("{}", report.line(name, &details(task)));
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{name}: {e}");
            std::process::ExitCode::from(EXIT_FAILED)
        }
    }
}

#[cfg(test)]
mod tests;
