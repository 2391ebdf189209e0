//! The runtime over a real iceoryx2 bus (a private prefix per test).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use motm_bus::{Bus, IpcConfig, LoopConfig, LoopExit, Subscriber, remove_domain};
use motm_graph::{Host, Rate, TaskSpec, Trigger, ports};
use motm_msgs::{JointState, Message, TwistCommand, topics};

use super::*;

ports! {
    /// Nothing.
    struct NoInputs {}
}

ports! {
    /// A twist and a joint state.
    struct WriterOutputs {
        /// Stamped by the task.
        latest twist: TwistCommand = topics::CONTROL_REACH_TWIST,
        /// Stamped by the sink.
        latest joints: JointState = topics::ARM_JOINT_STATE,
    }
}

ports! {
    /// Every twist of a cycle.
    struct ReaderInputs {
        /// The twists.
        queue twists: TwistCommand = topics::CONTROL_REACH_TWIST,
    }
}

/// Publishes a twist stamped `1000 + cycle` and a joint state with a zero stamp each cycle.
struct Writer {
    cycle: u64,
}

impl Task for Writer {
    type Inputs = NoInputs;
    type Outputs = WriterOutputs;
    fn name(&self) -> &'static str {
        "writer"
    }
    fn step(&mut self, _now_ns: u64, _inputs: &NoInputs) -> WriterOutputs {
        self.cycle += 1;
        let mut twist = TwistCommand::zeroed();
        twist.header.stamp_ns = 1000 + self.cycle;
        let mut joints = JointState::zeroed();
        joints.joint_count = 1;
        WriterOutputs {
            twist: Some(twist),
            joints: Some(joints),
        }
    }
}

/// Records how many twists each cycle got.
#[derive(Default)]
struct Reader {
    per_cycle: Vec<usize>,
}

impl Task for Reader {
    type Inputs = ReaderInputs;
    type Outputs = NoInputs;
    fn name(&self) -> &'static str {
        "reader"
    }
    fn step(&mut self, _now_ns: u64, inputs: &ReaderInputs) -> NoInputs {
        self.per_cycle.push(inputs.twists.len());
        NoInputs::default()
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
        host: Host::Process,
        standby_of: None,
    }
}

const WRITER: TaskSpec = spec("writer", Trigger::Timer);
const ON_TWIST: TaskSpec = spec(
    "reader",
    Trigger::Arrival(&[topics::CONTROL_REACH_TWIST.spec()]),
);

fn ipc(test: &str) -> IpcConfig {
    IpcConfig {
        prefix: format!("motmt{}_rt{test}_", std::process::id()),
    }
}

fn clean(ipc: &IpcConfig) {
    // SAFETY: every bus of this prefix is dropped and no other process uses it.
    unsafe { remove_domain(ipc) }.unwrap();
    assert!(motm_bus::shared_memory_entries(ipc).unwrap().is_empty());
}

#[test]
fn the_sink_keeps_a_tasks_stamp_stamps_a_zero_one_now_and_numbers_the_samples() {
    let ipc = ipc("stamps");
    {
        let bus = Bus::open_with("writer", &ipc).unwrap();
        let mut twists = Subscriber::<TwistCommand>::new(
            &bus,
            topics::CONTROL_REACH_TWIST.name(),
            &qos(topics::CONTROL_REACH_TWIST.name()),
        )
        .unwrap();
        let mut joints = Subscriber::<JointState>::new(
            &bus,
            topics::ARM_JOINT_STATE.name(),
            &qos(topics::ARM_JOINT_STATE.name()),
        )
        .unwrap();
        let mut ports = TaskPorts::<Writer>::open(&bus, &WRITER).unwrap();
        let mut writer = Writer { cycle: 0 };
        let before = motm_bus::monotonic_now_ns();
        ports.step(&mut writer, 5);
        ports.step(&mut writer, 6);
        let after = motm_bus::monotonic_now_ns();
        for (seq, stamp) in [(0, 1001), (1, 1002)] {
            let twist = twists.receive().unwrap().unwrap();
            assert_eq!((twist.header.seq, twist.header.stamp_ns), (seq, stamp));
            let joint = joints.receive().unwrap().unwrap();
            assert_eq!(joint.header.seq, seq);
            assert!((before..=after).contains(&joint.header.stamp_ns));
        }
        assert!(twists.receive().unwrap().is_none());
        assert_eq!(ports.ports().failures(), 0);
    }
    clean(&ipc);
}

#[test]
fn an_arrival_task_runs_on_each_sample_of_its_trigger_input() {
    let ipc = ipc("arrival");
    {
        let bus = Bus::open_with("reader", &ipc).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let writer = {
            let (ipc, stop) = (ipc.clone(), stop.clone());
            std::thread::spawn(move || {
                let bus = Bus::open_with("writer", &ipc).unwrap();
                let mut ports = TaskPorts::<Writer>::open(&bus, &WRITER).unwrap();
                let mut writer = Writer { cycle: 0 };
                while !stop.load(Ordering::Relaxed) {
                    ports.step(&mut writer, 0);
                    std::thread::sleep(Duration::from_millis(5));
                }
                writer.cycle
            })
        };
        let mut reader = Reader::default();
        // A period far longer than the test: every cycle is woken by a sample.
        let config = LoopConfig::with_rate(1.0 / 600.0);
        let report = run_task_while(&bus, &mut reader, &ON_TWIST, config, |r| {
            r.per_cycle.iter().sum::<usize>() < 5
        })
        .unwrap();
        stop.store(true, Ordering::Relaxed);
        let written = writer.join().unwrap();
        assert_eq!(report.exit, LoopExit::Stopped);
        assert!(
            reader.per_cycle.iter().all(|&n| n >= 1),
            "{:?}",
            reader.per_cycle
        );
        assert_eq!(report.cycles, reader.per_cycle.len() as u64);
        assert!(written >= 5);
    }
    clean(&ipc);
}

#[test]
fn an_arrival_task_still_cycles_once_a_period_when_nothing_arrives() {
    let ipc = ipc("idle");
    {
        let bus = Bus::open_with("reader", &ipc).unwrap();
        let mut reader = Reader::default();
        let report = run_task_while(
            &bus,
            &mut reader,
            &ON_TWIST,
            LoopConfig::with_rate(100.0),
            |r| r.per_cycle.len() < 3,
        )
        .unwrap();
        assert_eq!(report.exit, LoopExit::Stopped);
        assert_eq!(reader.per_cycle, [0, 0, 0]);
    }
    clean(&ipc);
}

#[test]
fn only_the_camera_is_large_only_trigger_inputs_wake_and_every_reader_has_room() {
    assert_eq!(qos(topics::CAMERA_IMAGE.name()), Qos::large().waking());
    assert_eq!(qos(topics::ARM_JOINT_STATE.name()), Qos::default());
    assert_eq!(
        qos(topics::PERCEPTION_TARGET.name()),
        Qos::default().waking()
    );
}

#[test]
fn every_topic_has_room_for_the_graphs_ports_whoever_creates_it() {
    for topic in motm_graph::published_topics() {
        let (publishers, subscribers) = graph_ports(topic.name);
        let q = qos(topic.name);
        assert!(
            publishers <= q.max_publishers && subscribers <= q.max_subscribers,
            "{}: the graph needs {publishers} publishers and {subscribers} subscribers, {q:?}",
            topic.name
        );
        let d = Qos::default();
        assert!(
            publishers <= d.max_publishers && subscribers <= d.max_subscribers,
            "{}: a service created with the defaults has no room for the graph",
            topic.name
        );
    }
    // Primary and standby resolver, each with room for a restart beside it.
    assert_eq!(graph_ports(topics::ARM_VELOCITY_COMMAND.name()).0, 4);
}
