//! The watchdog task: takes the heartbeats of the stack's control-path processes and the two
//! command streams of the QP resolver, and publishes `SAFETY_SAFE_STOP` every cycle, raised
//! while any of them is stale or a process reports new deadline misses (the decision is
//! [`motm_core::watchdog::Watchdog`]), cleared when all is well again. A task and its hot
//! standby (the QP resolver's) count as one redundant source.

use motm_core::watchdog::{SafetyFault, SourceKind, Watchdog, WatchdogConfig};
use motm_graph::{Task, ports};
use motm_msgs::{
    ArmVelocityCommand, BaseVelocityCommand, Heartbeat, Message, SafeStop, SafeStopReason, topics,
};

ports! {
    /// What the watchdog reads: the command streams and the control path's heartbeats.
    pub struct WatchdogInputs {
        /// Joint velocity commands (the primary resolver's and the standby's).
        queue arm: ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Base velocity commands.
        queue base: BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// The arm driver's heartbeats.
        queue panda_driver: Heartbeat = topics::HEARTBEAT_PANDA_DRIVER,
        /// The base driver's heartbeats.
        queue ld60_driver: Heartbeat = topics::HEARTBEAT_LD60_DRIVER,
        /// The reacher's heartbeats.
        queue reacher: Heartbeat = topics::HEARTBEAT_REACHER,
        /// The final phase's heartbeats.
        queue final_phase: Heartbeat = topics::HEARTBEAT_FINAL_PHASE,
        /// The QP resolver's heartbeats.
        queue qp_resolver: Heartbeat = topics::HEARTBEAT_QP_RESOLVER,
        /// The QP resolver standby's heartbeats.
        queue qp_resolver_standby: Heartbeat = topics::HEARTBEAT_QP_RESOLVER_STANDBY,
    }
}

/// The heartbeat topics of [`WatchdogInputs`], in the order of [`WatchdogInputs::heartbeats`].
pub const HEARTBEAT_TOPICS: [motm_msgs::Topic<Heartbeat>; 6] = [
    topics::HEARTBEAT_PANDA_DRIVER,
    topics::HEARTBEAT_LD60_DRIVER,
    topics::HEARTBEAT_REACHER,
    topics::HEARTBEAT_FINAL_PHASE,
    topics::HEARTBEAT_QP_RESOLVER,
    topics::HEARTBEAT_QP_RESOLVER_STANDBY,
];

impl WatchdogInputs {
    /// The heartbeats of this cycle, one slice per topic of [`HEARTBEAT_TOPICS`].
    pub fn heartbeats(&self) -> [&[Heartbeat]; 6] {
        [
            &self.panda_driver,
            &self.ld60_driver,
            &self.reacher,
            &self.final_phase,
            &self.qp_resolver,
            &self.qp_resolver_standby,
        ]
    }
}

ports! {
    /// What the watchdog publishes.
    pub struct WatchdogOutputs {
        /// Raised or cleared, every cycle.
        latest safe_stop: SafeStop = topics::SAFETY_SAFE_STOP,
    }
}

/// The watchdog over the control-path processes of one stack.
#[derive(Debug, Clone)]
pub struct WatchdogTask {
    watchdog: Watchdog,
    /// Source names: the watched processes, then the arm and base command topics.
    names: Vec<String>,
    /// The source index of each topic of [`HEARTBEAT_TOPICS`] (`None`: not watched).
    slots: [Option<usize>; 6],
    /// The verdict of the last cycle: the reason and the source at fault.
    last: Option<(SafeStopReason, String)>,
    /// What the last cycle changed, for the operator.
    notice: Option<String>,
    /// Raises for a fault so far (not the start-up hold).
    fault_raises: u64,
}

impl WatchdogTask {
    /// A watchdog with `config` over the heartbeats of `processes` (the stack's processes; only
    /// those on the control path are watched) and the command streams of period
    /// `control_period_ns`.
    pub fn new<'a>(
        config: WatchdogConfig,
        processes: impl IntoIterator<Item = &'a str>,
        control_period_ns: u64,
    ) -> Self {
        let mut names: Vec<String> = processes
            .into_iter()
            .filter(|name| motm_graph::task(name).is_some_and(|t| t.control_path))
            .map(str::to_owned)
            .collect();
        let watched = names.len();
        let mut kinds = vec![SourceKind::Heartbeat; watched];
        let command = SourceKind::Command {
            period_ns: control_period_ns,
        };
        kinds.extend([command, command]);
        let mut watchdog = Watchdog::new(config, &kinds);
        // A task and its hot standbys are one redundant source.
        for (index, name) in names.iter().enumerate() {
            let mut group = vec![index];
            group.extend(
                motm_graph::standbys_of(name)
                    .filter_map(|standby| names.iter().position(|n| n == standby.name)),
            );
            if group.len() > 1 {
                watchdog.redundant(&group);
            }
        }
        let slots = HEARTBEAT_TOPICS.map(|topic| {
            let process = motm_graph::heartbeat_of(topic.name())?;
            names.iter().position(|n| n == process.name)
        });
        names.push(topics::ARM_VELOCITY_COMMAND.name().to_owned());
        names.push(topics::BASE_VELOCITY_COMMAND.name().to_owned());
        Self {
            watchdog,
            names,
            slots,
            last: None,
            notice: None,
            fault_raises: 0,
        }
    }

    /// The names of the watched sources: processes, then the two command topics.
    pub fn sources(&self) -> &[String] {
        &self.names
    }

    /// The reason code and the name of the source at fault.
    fn describe(&self, fault: SafetyFault) -> (SafeStopReason, String) {
        let (reason, index) = match fault {
            SafetyFault::HeartbeatLost(i) => (SafeStopReason::HeartbeatLost, i),
            SafetyFault::StaleCommand(i) => (SafeStopReason::StaleCommand, i),
            SafetyFault::DeadlineMiss(i) => (SafeStopReason::DeadlineMiss, i),
            SafetyFault::Starting(i) => (SafeStopReason::Starting, i),
        };
        (reason, self.names.get(index).cloned().unwrap_or_default())
    }

    /// The line for a change from the last verdict to `verdict`; start-up holds change source
    /// as processes come up, so only their end is worth a line.
    fn change(&self, verdict: &Option<(SafeStopReason, String)>) -> Option<String> {
        let kind = |v: &Option<(SafeStopReason, String)>| v.as_ref().map(|(reason, _)| *reason);
        let starting = Some(SafeStopReason::Starting);
        if *verdict == self.last || (kind(verdict) == starting && kind(&self.last) == starting) {
            return None;
        }
        Some(match verdict {
            Some((SafeStopReason::Starting, source)) => {
                format!("holding safe-stop until {source} is up")
            }
            Some((reason, source)) => format!("safe-stop raised: {reason:?} ({source})"),
            None if kind(&self.last) == starting => {
                "the control path is up; safe-stop cleared".to_owned()
            }
            None => "safe-stop cleared".to_owned(),
        })
    }
}

impl Task for WatchdogTask {
    type Inputs = WatchdogInputs;
    type Outputs = WatchdogOutputs;

    fn name(&self) -> &'static str {
        motm_graph::WATCHDOG.name
    }

    fn step(&mut self, now_ns: u64, inputs: &WatchdogInputs) -> WatchdogOutputs {
        let watched = self.names.len() - 2;
        for (slot, beats) in self.slots.into_iter().zip(inputs.heartbeats()) {
            let Some(index) = slot else {
                continue;
            };
            for b in beats {
                self.watchdog.heartbeat(
                    index,
                    b.header.stamp_ns,
                    b.cycles,
                    b.deadline_misses,
                    now_ns,
                );
            }
        }
        for c in &inputs.arm {
            self.watchdog.command(watched, c.header.stamp_ns);
        }
        for c in &inputs.base {
            self.watchdog.command(watched + 1, c.header.stamp_ns);
        }
        let verdict = self
            .watchdog
            .verdict(now_ns)
            .map(|fault| self.describe(fault));
        let mut message = SafeStop::zeroed();
        message.active = u32::from(verdict.is_some());
        message.reason = verdict
            .as_ref()
            .map_or(SafeStopReason::None, |(reason, _)| *reason)
            .into();
        let fault = |v: &Option<(SafeStopReason, String)>| {
            v.as_ref()
                .is_some_and(|(reason, _)| *reason != SafeStopReason::Starting)
        };
        if fault(&verdict) && !fault(&self.last) {
            self.fault_raises += 1;
        }
        message.fault_raises = self.fault_raises;
        self.notice = self.change(&verdict);
        self.last = verdict;
        WatchdogOutputs {
            safe_stop: Some(message),
        }
    }

    fn notice(&self) -> Option<&str> {
        self.notice.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_graph::PortSet;
    use motm_msgs::Header;

    const MS: u64 = 1_000_000;

    fn beat(stamp_ns: u64, cycles: u64, misses: u64) -> Heartbeat {
        let mut b = Heartbeat::zeroed();
        b.header = Header::new(stamp_ns, cycles);
        b.cycles = cycles;
        b.deadline_misses = misses;
        b
    }

    fn command<M: Message>(stamp_ns: u64) -> M {
        let mut m = M::zeroed();
        *m.header_mut() = Header::new(stamp_ns, stamp_ns / MS);
        m
    }

    fn verdict(out: &WatchdogOutputs) -> (u32, SafeStopReason) {
        let stop = out.safe_stop.as_ref().expect("published every cycle");
        (
            stop.active,
            SafeStopReason::try_from(stop.reason).expect("a reason code"),
        )
    }

    /// A watchdog over a reacher and the QP resolver with its standby, at 200 Hz commands.
    fn task() -> WatchdogTask {
        WatchdogTask::new(
            WatchdogConfig::default(),
            ["sim-world", "reacher", "qp-resolver", "qp-resolver-standby"],
            5 * MS,
        )
    }

    /// Inputs in which the reacher and both resolvers beat at `t` and both commands came.
    fn all_well(t: u64) -> WatchdogInputs {
        WatchdogInputs {
            arm: vec![command(t)],
            base: vec![command(t)],
            reacher: vec![beat(t, t / MS, 0)],
            qp_resolver: vec![beat(t, t / MS, 0)],
            qp_resolver_standby: vec![beat(t, t / MS, 0)],
            ..WatchdogInputs::default()
        }
    }

    #[test]
    fn only_the_stacks_control_path_processes_are_watched() {
        // The heartbeat slices come in the order of the heartbeat topics of the inputs.
        let inputs: Vec<&str> = WatchdogInputs::TOPICS[2..].iter().map(|t| t.name).collect();
        let topics: Vec<&str> = HEARTBEAT_TOPICS.iter().map(|t| t.name()).collect();
        assert_eq!(inputs, topics);
        let names: Vec<&str> = HEARTBEAT_TOPICS
            .iter()
            .filter_map(|t| motm_graph::heartbeat_of(t.name()))
            .map(|t| t.name)
            .collect();
        assert!(
            names
                .iter()
                .all(|n| motm_graph::task(n).is_some_and(|t| t.control_path))
        );
        assert_eq!(names.len(), 6);
        assert_eq!(
            task().sources(),
            [
                "reacher",
                "qp-resolver",
                "qp-resolver-standby",
                topics::ARM_VELOCITY_COMMAND.name(),
                topics::BASE_VELOCITY_COMMAND.name(),
            ]
        );
    }

    #[test]
    fn safe_stop_is_held_until_the_control_path_is_up_then_cleared_with_a_notice() {
        let mut w = task();
        let out = w.step(MS, &WatchdogInputs::default());
        assert_eq!(verdict(&out), (1, SafeStopReason::Starting));
        assert_eq!(w.notice(), Some("holding safe-stop until reacher is up"));
        // Still starting: no new line while the source changes.
        let out = w.step(
            2 * MS,
            &WatchdogInputs {
                reacher: vec![beat(2 * MS, 2, 0)],
                ..WatchdogInputs::default()
            },
        );
        assert_eq!(verdict(&out).1, SafeStopReason::Starting);
        assert_eq!(w.notice(), None);
        let out = w.step(3 * MS, &all_well(3 * MS));
        assert_eq!(verdict(&out), (0, SafeStopReason::None));
        assert_eq!(
            w.notice(),
            Some("the control path is up; safe-stop cleared")
        );
        w.step(4 * MS, &all_well(4 * MS));
        assert_eq!(w.notice(), None);
    }

    #[test]
    fn a_stale_command_stream_raises_safe_stop_and_names_it() {
        let mut w = task();
        let mut t = MS;
        while t <= 100 * MS {
            w.step(t, &all_well(t));
            t += MS;
        }
        // The base commands stop; heartbeats go on.
        let mut raised = None;
        while t <= 200 * MS {
            let mut inputs = all_well(t);
            inputs.base.clear();
            let out = w.step(t, &inputs);
            if verdict(&out).0 == 1 {
                raised = Some(t);
                break;
            }
            t += MS;
        }
        let raised = raised.expect("safe-stop raised");
        assert!(raised > 100 * MS + 5 * MS, "raised at {raised}");
        assert_eq!(
            w.notice().map(str::to_owned),
            Some(format!(
                "safe-stop raised: StaleCommand ({})",
                topics::BASE_VELOCITY_COMMAND.name()
            ))
        );
        // The start-up hold was not a fault raise; this is the first, and it is counted once.
        let mut inputs = all_well(t + MS);
        inputs.base.clear();
        let out = w.step(t + MS, &inputs);
        assert_eq!(
            out.safe_stop.map(|s| (s.active, s.fault_raises)),
            Some((1, 1))
        );
    }

    #[test]
    fn a_lost_heartbeat_raises_safe_stop_unless_a_standby_beats_for_it() {
        let timeout = WatchdogConfig::default().heartbeat_timeout_ns();
        let run = |drop_primary: bool, drop_standby: bool| {
            let mut w = task();
            let mut t = MS;
            let mut last = (0, SafeStopReason::None);
            while t <= 2 * timeout {
                let mut inputs = all_well(t);
                if t > timeout / 2 {
                    if drop_primary {
                        inputs.qp_resolver.clear();
                    }
                    if drop_standby {
                        inputs.qp_resolver_standby.clear();
                    }
                }
                last = verdict(&w.step(t, &inputs));
                t += MS;
            }
            last
        };
        assert_eq!(run(true, false), (0, SafeStopReason::None));
        assert_eq!(run(false, true), (0, SafeStopReason::None));
        assert_eq!(run(true, true), (1, SafeStopReason::HeartbeatLost));
    }

    #[test]
    fn a_heartbeat_of_a_process_outside_the_stack_is_not_watched() {
        let mut w = task();
        let mut t = MS;
        while t <= 50 * MS {
            let mut inputs = all_well(t);
            inputs.final_phase = vec![beat(t, t / MS, t / MS)];
            assert_eq!(verdict(&w.step(t, &inputs)), (0, SafeStopReason::None));
            t += MS;
        }
    }
}
