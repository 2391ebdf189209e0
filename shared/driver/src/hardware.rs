//! The stack side of a driver on real hardware. A real backend steps the same driver task as
//! the sim backend (`motm_tasks::driver`), but the task's hardware topics are the robot: the
//! backend fills the task's `hw_*` inputs from the robot and sends its `hw_*` outputs to it.
//! [`StackPorts`] opens every other port of the task on the bus (with the same service settings
//! as every other process, `motm_runtime::qos`) and never opens, let alone publishes, a
//! hardware topic. A driver's hardware topics are those of the stand-in that serves it in the
//! graph ([`hardware_topics`]: what `fake-panda` or `fake-ld60` exchanges with sim-world).

use std::sync::Arc;

use motm_bus::{Bus, BusError};
use motm_graph::{PortSet, Sink, Source, Task, TaskSpec};
use motm_msgs::{Message, Topic};
use motm_runtime::BusPorts;

/// The hardware topics of the driver of row `spec`: the topics of the stand-in that serves it
/// (none for a task that no stand-in serves).
pub fn hardware_topics(spec: &TaskSpec) -> Vec<&'static str> {
    motm_graph::STAND_INS
        .iter()
        .filter(|s| s.serves == spec.name)
        .flat_map(|s| s.inputs.iter().chain(s.outputs))
        .map(|t| t.name)
        .collect()
}

/// The bus ports of driver task `T` without its hardware topics, and its inputs.
pub struct StackPorts<T: Task> {
    ports: BusPorts,
    hardware: Vec<&'static str>,
    inputs: T::Inputs,
}

impl<T: Task> StackPorts<T> {
    /// Opens the ports on `bus` for the driver of row `spec`.
    pub fn open(bus: &Bus, spec: &TaskSpec) -> Result<Self, BusError> {
        let hardware = hardware_topics(spec);
        Ok(Self {
            ports: BusPorts::open_except::<T::Inputs, T::Outputs>(bus, spec, &hardware)?,
            hardware,
            inputs: T::Inputs::default(),
        })
    }

    /// Empties the queues and takes in what arrived since the last call on the stack's
    /// topics; the hardware inputs keep what the backend put there.
    pub fn read(&mut self) -> &mut T::Inputs {
        self.inputs.clear_queues();
        self.inputs.read(&mut StackSide {
            ports: &mut self.ports,
            hardware: &self.hardware,
        });
        &mut self.inputs
    }

    /// The inputs as of the last [`StackPorts::read`], with the backend's hardware inputs.
    pub fn inputs(&self) -> &T::Inputs {
        &self.inputs
    }

    /// Publishes the outputs that are set, but for the hardware commands (the backend sends
    /// those to the robot).
    pub fn write(&mut self, outputs: T::Outputs) {
        outputs.write(&mut StackSide {
            ports: &mut self.ports,
            hardware: &self.hardware,
        });
    }

    /// Failed receives and publishes so far.
    pub fn failures(&self) -> u64 {
        self.ports.failures()
    }
}

/// The bus ports, skipping the hardware topics.
struct StackSide<'a> {
    ports: &'a mut BusPorts,
    hardware: &'a [&'static str],
}

impl StackSide<'_> {
    fn stack<T: Message>(&self, topic: Topic<T>) -> bool {
        !self.hardware.contains(&topic.name())
    }
}

impl Source for StackSide<'_> {
    fn latest<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<T>) {
        if self.stack(topic) {
            self.ports.latest(topic, slot);
        }
    }

    fn latest_shared<T: Message>(&mut self, topic: Topic<T>, slot: &mut Option<Arc<T>>) {
        if self.stack(topic) {
            self.ports.latest_shared(topic, slot);
        }
    }

    fn queue<T: Message>(&mut self, topic: Topic<T>, out: &mut Vec<T>) {
        if self.stack(topic) {
            self.ports.queue(topic, out);
        }
    }
}

impl Sink for StackSide<'_> {
    fn publish<T: Message>(&mut self, topic: Topic<T>, message: &T) {
        if self.stack(topic) {
            self.ports.publish(topic, message);
        }
    }
}

/// `message` stamped `stamp_ns` with sequence number `seq` (a state from the robot, before the
/// task re-publishes it: the task tells new states by their sequence number and stamp).
pub fn from_hardware<M: Message>(mut message: M, seq: u64, stamp_ns: u64) -> M {
    let header = message.header_mut();
    header.seq = seq;
    header.stamp_ns = stamp_ns;
    message
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::topics;

    #[test]
    fn a_drivers_hardware_topics_are_its_stand_ins_and_only_hw_topics() {
        let mut arm = hardware_topics(&motm_graph::PANDA_DRIVER);
        arm.sort_unstable();
        let mut expected = vec![
            topics::HW_ARM_STATE.name(),
            topics::HW_GRIPPER_STATE.name(),
            topics::HW_ARM_COMMAND.name(),
            topics::HW_GRIPPER_COMMAND.name(),
        ];
        expected.sort_unstable();
        assert_eq!(arm, expected);
        let mut base = hardware_topics(&motm_graph::LD60_DRIVER);
        base.sort_unstable();
        assert_eq!(
            base,
            [topics::HW_BASE_COMMAND.name(), topics::HW_BASE_STATE.name()]
        );
        assert!(hardware_topics(&motm_graph::QP_RESOLVER).is_empty());
        // Every hardware topic is read or written by the driver, so none of its stack topics
        // is left out.
        for spec in [motm_graph::PANDA_DRIVER, motm_graph::LD60_DRIVER] {
            for name in hardware_topics(&spec) {
                assert!(name.contains("/hw/"), "{name}");
                assert!(spec.reads(name) || spec.writes(name), "{name}");
            }
        }
        let m = from_hardware(motm_msgs::JointState::zeroed(), 7, 9);
        assert_eq!((m.header.seq, m.header.stamp_ns), (7, 9));
    }
}
