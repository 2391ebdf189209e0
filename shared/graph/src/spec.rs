//! The graph as data: every task of the stack, the typed topics it reads and writes, its rate
//! and its trigger. The supervisor's process list, the logger's taps, the fault-injection
//! targets, the systemd units' `Wants=`, the end-to-end process list and `motm status` are
//! derived from [`GRAPH`]; each task type checks its own ports against its row in a test.

use motm_msgs::TopicSpec;
use motm_msgs::topics as t;

/// How often a task runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rate {
    /// At the stack's control rate (`control_rate_hz`, 200 Hz by default).
    Control,
    /// At a fixed rate of its own, Hz (the stack config may override it).
    Hz(f64),
}

impl Rate {
    /// The rate in Hz for a stack whose control rate is `control_rate_hz`.
    pub fn hz(&self, control_rate_hz: f64) -> f64 {
        match *self {
            Self::Control => control_rate_hz,
            Self::Hz(hz) => hz,
        }
    }
}

/// What makes a task run a cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Trigger {
    /// Its own timer, at its rate.
    Timer,
    /// The arrival of a sample on one of these inputs, or its own timer when nothing arrived
    /// for a whole period (so that a stalled upstream still gets a cycle that acts on it).
    Arrival(&'static [TopicSpec]),
}

/// Where a task runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Host {
    /// Its own process, of the task's name.
    Process,
    /// Inside the supervisor process (the mission task).
    Supervisor,
}

/// One row of the graph table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskSpec {
    /// Task name, which is also its process, binary and heartbeat name.
    pub name: &'static str,
    /// The topics it reads.
    pub inputs: &'static [TopicSpec],
    /// The topics it publishes.
    pub outputs: &'static [TopicSpec],
    /// How often it runs.
    pub rate: Rate,
    /// What makes it run.
    pub trigger: Trigger,
    /// Whether it is on the control path: the watchdog safe-stops when its heartbeat goes
    /// stale or it misses deadlines.
    pub control_path: bool,
    /// Whether it exists only in simulation (sim-world).
    pub sim_only: bool,
    /// Where it runs.
    pub host: Host,
    /// For a hot standby: the task it stands by for. It is a second instance of that task's
    /// logic in a process of its own, solving every cycle beside it; its consumers take its
    /// outputs when the primary's stop, and the watchdog counts the two as one redundant
    /// source. A stack config may leave it out (no standby).
    pub standby_of: Option<&'static str>,
}

impl TaskSpec {
    /// Whether the task reads `topic`.
    pub fn reads(&self, topic: &str) -> bool {
        self.inputs.iter().any(|s| s.name == topic)
    }

    /// Whether the task publishes `topic`.
    pub fn writes(&self, topic: &str) -> bool {
        self.outputs.iter().any(|s| s.name == topic)
    }

    /// Whether the task runs as a process of its own (everything but the mission task).
    pub fn is_process(&self) -> bool {
        self.host == Host::Process
    }

    /// Whether a sample's arrival on `topic` runs a cycle of the task ([`Trigger::Arrival`]).
    pub fn triggered_by(&self, topic: &str) -> bool {
        match self.trigger {
            Trigger::Timer => false,
            Trigger::Arrival(topics) => topics.iter().any(|t| t.name == topic),
        }
    }
}

/// The simulated hardware.
pub const SIM_WORLD: TaskSpec = TaskSpec {
    name: "sim-world",
    inputs: &[
        t::HW_ARM_COMMAND.spec(),
        t::HW_BASE_COMMAND.spec(),
        t::HW_GRIPPER_COMMAND.spec(),
        t::MISSION_STATE.spec(),
    ],
    outputs: &[
        t::HW_ARM_STATE.spec(),
        t::HW_BASE_STATE.spec(),
        t::HW_GRIPPER_STATE.spec(),
        t::CAMERA_IMAGE.spec(),
        t::SIM_TRUTH.spec(),
    ],
    rate: Rate::Hz(1000.0),
    trigger: Trigger::Timer,
    control_path: false,
    sim_only: true,
    host: Host::Process,
    standby_of: None,
};

/// The arm driver.
pub const PANDA_DRIVER: TaskSpec = TaskSpec {
    name: "panda-driver",
    inputs: &[
        t::ARM_VELOCITY_COMMAND.spec(),
        t::ARM_GRIPPER_COMMAND.spec(),
        t::CONTROL_ACTIVE_CONTROLLER.spec(),
        t::SAFETY_SAFE_STOP.spec(),
        t::HW_ARM_STATE.spec(),
        t::HW_GRIPPER_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
    ],
    outputs: &[
        t::HW_ARM_COMMAND.spec(),
        t::HW_GRIPPER_COMMAND.spec(),
        t::ARM_JOINT_STATE.spec(),
        t::ARM_GRIPPER_STATE.spec(),
        t::ARM_DRIVER_STATUS.spec(),
    ],
    rate: Rate::Hz(1000.0),
    trigger: Trigger::Timer,
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The base driver.
pub const LD60_DRIVER: TaskSpec = TaskSpec {
    name: "ld60-driver",
    inputs: &[
        t::BASE_VELOCITY_COMMAND.spec(),
        t::SAFETY_SAFE_STOP.spec(),
        t::HW_BASE_STATE.spec(),
    ],
    outputs: &[
        t::HW_BASE_COMMAND.spec(),
        t::BASE_ODOMETRY.spec(),
        t::BASE_DRIVER_STATUS.spec(),
    ],
    rate: Rate::Hz(50.0),
    trigger: Trigger::Timer,
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// Perception of the current pick's cube or press's button.
pub const PERCEPTION: TaskSpec = TaskSpec {
    name: "perception",
    inputs: &[
        t::MISSION_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::ARM_JOINT_STATE.spec(),
        t::CAMERA_IMAGE.spec(),
    ],
    outputs: &[t::PERCEPTION_TARGET.spec()],
    rate: Rate::Control,
    trigger: Trigger::Arrival(&[t::CAMERA_IMAGE.spec()]),
    control_path: false,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The MotM base controller.
pub const BASE_PLANNER: TaskSpec = TaskSpec {
    name: "base-planner",
    inputs: &[
        t::MISSION_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::PERCEPTION_TARGET.spec(),
    ],
    outputs: &[t::BASE_VELOCITY_TARGET.spec(), t::BASE_PLAN.spec()],
    rate: Rate::Control,
    trigger: Trigger::Timer,
    control_path: false,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The reach-phase controller.
pub const REACHER: TaskSpec = TaskSpec {
    name: "reacher",
    inputs: &[
        t::MISSION_STATE.spec(),
        t::ARM_JOINT_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::PERCEPTION_TARGET.spec(),
        t::BASE_PLAN.spec(),
        t::BASE_VELOCITY_TARGET.spec(),
        t::CONTROL_QP_STATUS.spec(),
    ],
    outputs: &[t::CONTROL_REACH_TWIST.spec()],
    rate: Rate::Control,
    trigger: Trigger::Arrival(&[t::PERCEPTION_TARGET.spec()]),
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The hot-swappable final-phase task controller.
pub const FINAL_PHASE: TaskSpec = TaskSpec {
    name: "final-phase",
    inputs: &[
        t::MISSION_STATE.spec(),
        t::ARM_JOINT_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::PERCEPTION_TARGET.spec(),
        t::ARM_GRIPPER_STATE.spec(),
    ],
    outputs: &[t::CONTROL_FINAL_TWIST.spec(), t::ARM_GRIPPER_COMMAND.spec()],
    rate: Rate::Control,
    trigger: Trigger::Arrival(&[t::PERCEPTION_TARGET.spec()]),
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The redundancy-resolution QP.
pub const QP_RESOLVER: TaskSpec = TaskSpec {
    name: "qp-resolver",
    inputs: &[
        t::MISSION_STATE.spec(),
        t::ARM_JOINT_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::PERCEPTION_TARGET.spec(),
        t::CONTROL_REACH_TWIST.spec(),
        t::CONTROL_FINAL_TWIST.spec(),
        t::CONTROL_ACTIVE_CONTROLLER.spec(),
        t::BASE_VELOCITY_TARGET.spec(),
    ],
    outputs: &[
        t::ARM_VELOCITY_COMMAND.spec(),
        t::BASE_VELOCITY_COMMAND.spec(),
        t::CONTROL_QP_STATUS.spec(),
    ],
    rate: Rate::Control,
    trigger: Trigger::Arrival(&[t::CONTROL_REACH_TWIST.spec(), t::CONTROL_FINAL_TWIST.spec()]),
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The hot-standby redundancy-resolution QP: the same task as [`QP_RESOLVER`], solving every
/// cycle from the same inputs, whose commands the drivers take when the primary's stop.
pub const QP_RESOLVER_STANDBY: TaskSpec = TaskSpec {
    name: "qp-resolver-standby",
    standby_of: Some(QP_RESOLVER.name),
    ..QP_RESOLVER
};

/// The watchdog: the two command streams and the heartbeat of every control-path task (the
/// ones a stack config leaves out are not expected).
pub const WATCHDOG: TaskSpec = TaskSpec {
    name: "watchdog",
    inputs: &[
        t::ARM_VELOCITY_COMMAND.spec(),
        t::BASE_VELOCITY_COMMAND.spec(),
        t::HEARTBEAT_PANDA_DRIVER.spec(),
        t::HEARTBEAT_LD60_DRIVER.spec(),
        t::HEARTBEAT_REACHER.spec(),
        t::HEARTBEAT_FINAL_PHASE.spec(),
        t::HEARTBEAT_QP_RESOLVER.spec(),
        t::HEARTBEAT_QP_RESOLVER_STANDBY.spec(),
    ],
    outputs: &[t::SAFETY_SAFE_STOP.spec()],
    rate: Rate::Hz(1000.0),
    trigger: Trigger::Timer,
    control_path: false,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The supervisor's mission task.
pub const MISSION: TaskSpec = TaskSpec {
    name: "mission",
    inputs: &[
        t::ARM_JOINT_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::PERCEPTION_TARGET.spec(),
        t::CONTROL_FINAL_TWIST.spec(),
        t::CONTROL_ACTIVE_CONTROLLER.spec(),
        t::BASE_PLAN.spec(),
    ],
    outputs: &[t::MISSION_STATE.spec()],
    rate: Rate::Control,
    trigger: Trigger::Timer,
    control_path: false,
    sim_only: false,
    host: Host::Supervisor,
    standby_of: None,
};

/// Every task of the stack, in start order (upstream first): the one table the rest derives
/// from.
pub const GRAPH: &[TaskSpec] = &[
    SIM_WORLD,
    PANDA_DRIVER,
    LD60_DRIVER,
    PERCEPTION,
    BASE_PLANNER,
    REACHER,
    FINAL_PHASE,
    QP_RESOLVER,
    QP_RESOLVER_STANDBY,
    WATCHDOG,
    MISSION,
];

/// The reactive baseline (stop and grasp): in its graph it replaces the mission, the base
/// planner, the reacher, the final phase and the QP resolver; it sequences its own tasks and
/// publishes the mission state perception follows.
pub const REACTIVE: TaskSpec = TaskSpec {
    name: "reactive",
    inputs: &[
        t::ARM_JOINT_STATE.spec(),
        t::BASE_ODOMETRY.spec(),
        t::ARM_GRIPPER_STATE.spec(),
        t::PERCEPTION_TARGET.spec(),
    ],
    outputs: &[
        t::MISSION_STATE.spec(),
        t::ARM_VELOCITY_COMMAND.spec(),
        t::BASE_VELOCITY_COMMAND.spec(),
        t::ARM_GRIPPER_COMMAND.spec(),
    ],
    rate: Rate::Control,
    trigger: Trigger::Timer,
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The planning baseline (plan once, then track the plan open loop): in its graph it replaces
/// the same tasks as the reactive baseline, and perception.
pub const PLANNING: TaskSpec = TaskSpec {
    name: "planning",
    inputs: &[t::ARM_JOINT_STATE.spec(), t::BASE_ODOMETRY.spec()],
    outputs: &[
        t::MISSION_STATE.spec(),
        t::ARM_VELOCITY_COMMAND.spec(),
        t::BASE_VELOCITY_COMMAND.spec(),
        t::ARM_GRIPPER_COMMAND.spec(),
    ],
    rate: Rate::Control,
    trigger: Trigger::Timer,
    control_path: true,
    sim_only: false,
    host: Host::Process,
    standby_of: None,
};

/// The baselines' tasks, for the in-process comparisons of the paper's experiments.
pub const BASELINES: &[TaskSpec] = &[REACTIVE, PLANNING];

/// A process that stands in for a robot's hardware behind a driver backend, in simulation
/// only. It is no task of the graph: it speaks the hardware's own protocol to its driver and
/// bridges to sim-world over topics the graph already has.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StandIn {
    /// Process and binary name.
    pub name: &'static str,
    /// The driver process it serves, which it is started before.
    pub serves: &'static str,
    /// The topics it reads.
    pub inputs: &'static [TopicSpec],
    /// The topics it publishes (in place of the driver, whose backend then does not).
    pub outputs: &'static [TopicSpec],
}

/// The hardware stand-ins a stack may add to the graph's processes.
pub const STAND_INS: &[StandIn] = &[
    StandIn {
        name: "fake-panda",
        serves: "panda-driver",
        inputs: &[t::HW_ARM_STATE.spec(), t::HW_GRIPPER_STATE.spec()],
        outputs: &[t::HW_ARM_COMMAND.spec(), t::HW_GRIPPER_COMMAND.spec()],
    },
    StandIn {
        name: "fake-ld60",
        serves: "ld60-driver",
        inputs: &[t::HW_BASE_STATE.spec()],
        outputs: &[t::HW_BASE_COMMAND.spec()],
    },
];

/// The environment variable naming the folder where stand-ins write their counts
/// (`<name>-<pid>.json`, rewritten every second and on exit), for `motm run --hardware fake`
/// to report the limit violations the fake robots saw (`violations_total` in each file).
pub const STAND_IN_REPORT_DIR_ENV: &str = "MOTM_FAKE_REPORT_DIR";

/// The stand-in `name`.
pub fn stand_in(name: &str) -> Option<&'static StandIn> {
    STAND_INS.iter().find(|s| s.name == name)
}

/// Topics the supervisor publishes itself, outside any task: the hot swap's active-controller
/// id and the process table.
pub const SUPERVISOR_TOPICS: &[TopicSpec] = &[
    t::CONTROL_ACTIVE_CONTROLLER.spec(),
    t::SUPERVISOR_STATUS.spec(),
];

/// The zenoh bridge on the stack's host when some of the graph's processes run on another
/// host (`motm run --remote`, the `motm-zenoh` binary).
pub const STACK_BRIDGE: &str = "zenoh-stack";

/// The zenoh bridge on the host of the remote processes (`motm run --remote`).
pub const REMOTE_BRIDGE: &str = "zenoh-remote";

/// The row of task `name`.
pub fn task(name: &str) -> Option<&'static TaskSpec> {
    GRAPH.iter().find(|t| t.name == name)
}

/// Whether some task of [`GRAPH`] runs on the arrival of samples on `topic`, so that its
/// publishers must wake the readers.
pub fn wakes_readers(topic: &str) -> bool {
    GRAPH.iter().any(|t| t.triggered_by(topic))
}

/// The control tasks a replay log rebuilds and replays: every row but the simulator's and the
/// watchdog's. The watchdog supervises the deployed processes (their heartbeats' arrival), not
/// the control loop: it has nothing to check in a log, and its 1 kHz cycles are not recorded.
///
/// A hot standby is not replayed: it is its primary's logic again, fed the same samples, and
/// the in-process runtime (which has no process to lose) runs the primary alone.
pub fn replayed_tasks() -> impl Iterator<Item = &'static TaskSpec> {
    GRAPH
        .iter()
        .filter(|t| !t.sim_only && t.name != WATCHDOG.name && t.standby_of.is_none())
}

/// The hot standbys of task `name` (see [`TaskSpec::standby_of`]).
pub fn standbys_of(name: &str) -> impl Iterator<Item = &'static TaskSpec> {
    GRAPH.iter().filter(move |t| t.standby_of == Some(name))
}

/// The tasks that run as processes of their own, in start order.
pub fn processes() -> impl Iterator<Item = &'static TaskSpec> {
    GRAPH.iter().filter(|t| t.is_process())
}

/// Whether the runtime records the cycles of task `spec` for replay logs: every task's but the
/// watchdog's (see [`replayed_tasks`]).
pub fn records_cycles(spec: &TaskSpec) -> bool {
    spec.name != WATCHDOG.name
}

/// The task whose process publishes heartbeat topic `topic` (every process's service loop
/// publishes its own, `motm_msgs::services::heartbeat(name)`).
pub fn heartbeat_of(topic: &str) -> Option<&'static TaskSpec> {
    let name = topic.strip_prefix(motm_msgs::services::HEARTBEAT_PREFIX)?;
    task(name.strip_prefix('/')?).filter(|t| t.is_process())
}

/// Every topic some task or the supervisor publishes, once each, in table order (the logger's
/// taps).
pub fn published_topics() -> Vec<TopicSpec> {
    let mut out: Vec<TopicSpec> = SUPERVISOR_TOPICS.to_vec();
    for spec in GRAPH {
        for topic in spec.outputs {
            if !out.contains(topic) {
                out.push(*topic);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_input_is_published_by_some_task_and_names_are_unique() {
        let published = published_topics();
        for spec in GRAPH {
            for input in spec.inputs {
                assert!(
                    published.contains(input) || heartbeat_of(input.name).is_some(),
                    "{} reads {} which no task publishes",
                    spec.name,
                    input.name
                );
            }
            if let Trigger::Arrival(topics) = spec.trigger {
                for topic in topics {
                    assert!(
                        spec.reads(topic.name),
                        "{} triggers on {}",
                        spec.name,
                        topic.name
                    );
                }
            }
        }
        let mut names: Vec<&str> = GRAPH.iter().map(|t| t.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), GRAPH.len());
    }

    #[test]
    fn the_watchdog_reads_the_heartbeat_of_every_control_path_task_and_the_commands() {
        let mut watched: Vec<&str> = WATCHDOG
            .inputs
            .iter()
            .filter_map(|topic| heartbeat_of(topic.name))
            .map(|t| t.name)
            .collect();
        let mut control_path: Vec<&str> = GRAPH
            .iter()
            .filter(|t| t.control_path)
            .map(|t| t.name)
            .collect();
        watched.sort_unstable();
        control_path.sort_unstable();
        assert_eq!(watched, control_path);
        for topic in WATCHDOG.inputs {
            if let Some(task) = heartbeat_of(topic.name) {
                assert_eq!(topic.name, motm_msgs::services::heartbeat(task.name));
            }
        }
        assert_eq!(WATCHDOG.inputs.len(), control_path.len() + 2);
        assert!(WATCHDOG.reads(t::ARM_VELOCITY_COMMAND.name()));
        assert!(WATCHDOG.reads(t::BASE_VELOCITY_COMMAND.name()));
        assert!(heartbeat_of("motm/v1/heartbeat/mission").is_none());
        assert!(heartbeat_of(t::ARM_JOINT_STATE.name()).is_none());
    }

    #[test]
    fn a_topic_has_one_type_everywhere() {
        for a in GRAPH.iter().flat_map(|t| t.inputs.iter().chain(t.outputs)) {
            for b in GRAPH.iter().flat_map(|t| t.inputs.iter().chain(t.outputs)) {
                if a.name == b.name {
                    assert_eq!(a.type_name, b.type_name, "{}", a.name);
                }
            }
        }
    }

    #[test]
    fn stand_ins_serve_a_driver_and_use_the_graphs_topics() {
        let published = published_topics();
        for stand_in in STAND_INS {
            assert!(task(stand_in.name).is_none(), "{}", stand_in.name);
            let driver = task(stand_in.serves).expect("a task of the graph");
            assert!(driver.is_process() && !driver.sim_only, "{}", driver.name);
            for topic in stand_in.inputs.iter().chain(stand_in.outputs) {
                assert!(
                    published.contains(topic),
                    "{}: {}",
                    stand_in.name,
                    topic.name
                );
            }
        }
        assert_eq!(stand_in("fake-ld60").map(|s| s.serves), Some("ld60-driver"));
        assert_eq!(
            stand_in("fake-panda").map(|s| s.serves),
            Some("panda-driver")
        );
    }

    #[test]
    fn every_topic_carries_the_schema_version() {
        let prefix = format!("{}/", motm_msgs::services::PREFIX);
        assert_eq!(prefix, format!("motm/v{}/", motm_msgs::SCHEMA_VERSION));
        let swap = [
            t::SUPERVISOR_SWAP_REQUEST.name(),
            t::SUPERVISOR_SWAP_STATUS.name(),
        ];
        for name in published_topics().iter().map(|t| t.name).chain(swap) {
            assert!(name.starts_with(&prefix), "{name}");
        }
        assert!(motm_msgs::services::heartbeat("watchdog").starts_with(&prefix));
    }

    #[test]
    fn the_processes_are_every_task_but_the_mission() {
        let names: Vec<&str> = processes().map(|t| t.name).collect();
        assert_eq!(names.len(), GRAPH.len() - 1);
        assert!(!names.contains(&"mission"));
        assert_eq!(task("qp-resolver").map(|t| t.control_path), Some(true));
    }

    #[test]
    fn the_event_driven_chain_wakes_on_image_target_and_twists_only() {
        for topic in [
            t::CAMERA_IMAGE.name(),
            t::PERCEPTION_TARGET.name(),
            t::CONTROL_REACH_TWIST.name(),
            t::CONTROL_FINAL_TWIST.name(),
        ] {
            assert!(wakes_readers(topic), "{topic}");
        }
        assert!(!wakes_readers(t::ARM_JOINT_STATE.name()));
        assert!(PERCEPTION.triggered_by(t::CAMERA_IMAGE.name()));
        assert!(!BASE_PLANNER.triggered_by(t::PERCEPTION_TARGET.name()));
        assert!(QP_RESOLVER.triggered_by(t::CONTROL_FINAL_TWIST.name()));
    }
}
