//! `motm run --fault`: carries out the fault schedule ([`motm_core::fault_schedule`]) on the
//! running stack and measures what follows: the supervisor's restart of a killed process, the
//! watchdog's safe-stop after a hang and its release, the drop of a NaN sample. Also counts the
//! watchdog's safe-stops, and adds the drivers' counters over every instance of a driver (a
//! restarted driver starts counting from zero).
//!
//! Times are measured on the monotonic clock that stamps every message, so a safe-stop latency
//! is the stamp of the watchdog's first raised sample minus the moment of the fault. The
//! safe-stop stream comes at the watchdog's rate and its subscriber queue holds a few samples:
//! should the run's loop fall behind by more than that, the first raised sample seen is a
//! later one, and the latency is over-, never under-estimated.

use std::collections::HashMap;

use motm_bus::inject::{INJECTABLE_TOPICS, Injector, Malformation, full_topic_name, open_injector};
use motm_bus::{Bus, BusError, Latest, Qos, Subscriber};
use motm_core::fault_schedule::{Fault, FaultKind, MissionEvents};
use motm_msgs::{
    DriverStatus, Heartbeat, SafeStop, SafeStopReason, SimTruth, SupervisedState, SupervisorStatus,
    services,
};
use serde::Serialize;

/// What happened to one injected fault.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FaultRecord {
    /// `kill`, `stop` or `nan`.
    pub kind: String,
    /// The service or topic hit.
    pub target: String,
    /// Scheduled time as given: simulated s (`4.5`) or a mission event and delay
    /// (`grasp+0.25`).
    pub when: String,
    /// Simulated time the fault was due at (`None`: its event never came).
    pub due_at_s: Option<f64>,
    /// Simulated time when the fault was injected (`None`: it never was).
    pub injected_at_s: Option<f64>,
    /// Pid signalled (kill, stop).
    pub pid: Option<u32>,
    /// `restarted`, `resumed`, `published`, `not_restarted`, `no_process`, ...
    pub outcome: String,
    /// Kill: from the kill to the supervisor reporting the new instance, ms.
    pub restart_ms: Option<f64>,
    /// Kill: from the kill to the first heartbeat of the new instance, ms.
    pub first_heartbeat_ms: Option<f64>,
    /// From the fault to the watchdog's first safe-stop sample after it, ms (a stop: the first
    /// within 100 ms of its SIGSTOP or of its SIGCONT).
    pub safe_stop_ms: Option<f64>,
    /// Stop: from SIGCONT to safe-stop released, ms.
    pub resumed_ms: Option<f64>,
}

/// The reason listed for a raise that began and ended between two samples of the safe-stop
/// stream (counted by the watchdog's `fault_raises`).
pub const UNSEEN_REASON: &str = "unseen (shorter than the polling period)";

/// The watchdog's safe-stops over the run.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SafeStopReport {
    /// Times safe-stop was raised for a fault (the start-up hold, reason `Starting`, until
    /// every control-path process is heard from, is not a fault and is not counted). Exact:
    /// the watchdog counts its raises in every sample, so a raise shorter than `motm run`'s
    /// polling period (20 Hz, 500 Hz with `--fault`) is counted too, with the reason
    /// [`UNSEEN_REASON`].
    pub count: u32,
    /// Of `count`, the raises before the watchdog first cleared safe-stop (a fault while the
    /// stack was starting).
    pub at_startup: u32,
    /// Reason of each raise, in order.
    pub reasons: Vec<String>,
    /// Largest safe-stop latency over the hang (stop) faults, ms (`None`: none measured).
    pub latency_ms: Option<f64>,
}

/// The fault checks that `motm run` makes before starting: every kill and stop names a
/// process of the stack (not the supervisor, which the run needs), every NaN an injectable
/// topic. The error names the flag.
pub fn check_targets(faults: &[Fault], processes: &[String]) -> Result<(), String> {
    for fault in faults {
        match fault.kind {
            FaultKind::Kill | FaultKind::Stop => {
                if !processes.contains(&fault.target) {
                    return Err(format!(
                        "--fault {}:{}: no process {:?} in the stack (processes: {})",
                        fault.kind.name(),
                        fault.target,
                        fault.target,
                        processes.join(", ")
                    ));
                }
            }
            FaultKind::Nan => {
                let topic = full_topic_name(&fault.target);
                if !INJECTABLE_TOPICS.contains(&topic.as_str()) {
                    return Err(format!(
                        "--fault nan:{}: cannot publish a NaN sample on {topic:?} (topics: {})",
                        fault.target,
                        INJECTABLE_TOPICS.join(", ")
                    ));
                }
            }
        }
    }
    Ok(())
}

/// How long after a stopped process's SIGSTOP, and after its SIGCONT, a safe-stop raise is the
/// stop's, ns. A hang can only raise by silencing a stream, and the watchdog sees a silent
/// stream after `stale_cycles` (3) periods: a hang without a standby raises 15-20 ms after the
/// SIGSTOP, and a resumed process's streams are fresh again within a few cycles of the
/// SIGCONT. Between the two windows a hot standby carries the stopped process's streams alone,
/// and a raise there is a stall of the standby itself; a stack on a shared 2-core machine also
/// raises, rarely, in a run without any fault (a 20-40 ms scheduling stall of the control path
/// is a stale command). Such raises are counted in the report's `safe_stops`, not given to the
/// stop. 100 ms is 20 control periods at 200 Hz.
const STOP_ATTRIBUTION_WINDOW_NS: u64 = 100_000_000;

/// Whether a safe-stop raised at `raise_ns` is the fault's, injected at `injected_ns` (a
/// stop: continued at `continued_ns`). A kill's or a NaN's is the first raise after it; a
/// stop's is within [`STOP_ATTRIBUTION_WINDOW_NS`] of its SIGSTOP or of its SIGCONT.
fn raise_is_the_faults(
    kind: FaultKind,
    injected_ns: u64,
    continued_ns: Option<u64>,
    raise_ns: u64,
) -> bool {
    let soon_after = |from: u64| raise_ns >= from && raise_ns - from <= STOP_ATTRIBUTION_WINDOW_NS;
    raise_ns >= injected_ns
        && (kind != FaultKind::Stop
            || soon_after(injected_ns)
            || continued_ns.is_some_and(soon_after))
}

/// A fault under way or done.
struct Tracked {
    fault: Fault,
    record: FaultRecord,
    /// Monotonic time of the injection, ns.
    injected_ns: Option<u64>,
    /// Stop: monotonic time of the SIGCONT, ns.
    continued_ns: Option<u64>,
    /// Stop: wall time when SIGCONT is due, ns.
    continue_at_ns: Option<u64>,
    /// Monotonic time of the safe-stop raise attributed to the fault, ns.
    raised_ns: Option<u64>,
}

/// Driver counters added over every instance (publisher) of each driver.
#[derive(Debug, Default)]
pub struct DriverTotals {
    /// Latest status per (driver topic, publisher id).
    latest: HashMap<(&'static str, u128), DriverStatus>,
}

impl DriverTotals {
    /// Takes in the newest status of the driver on `topic`.
    pub fn update(&mut self, topic: &'static str, status: &Latest<DriverStatus>) {
        if let (Some(s), Some(id)) = (status.get(), status.publisher_id()) {
            self.latest.insert((topic, id), *s);
        }
    }

    /// Commands beyond a limit, all instances.
    pub fn limit_violations(&self) -> u64 {
        self.latest.values().map(|d| d.limit_violations).sum()
    }

    /// Outputs beyond a limit, all instances.
    pub fn output_violations(&self) -> u64 {
        self.latest.values().map(|d| d.output_violations).sum()
    }

    /// Hot-standby takeovers at any driver instance: the most any one counted (each driver
    /// follows the resolvers on its own).
    pub fn resolver_takeovers(&self) -> u32 {
        self.latest
            .values()
            .map(|d| d.resolver_takeovers)
            .max()
            .unwrap_or(0)
    }

    /// Longest interval a hot-standby takeover made at any driver instance, ms.
    pub fn max_takeover_interval_ms(&self) -> f64 {
        self.latest
            .values()
            .map(|d| d.max_takeover_interval_ns as f64 / 1e6)
            .fold(0.0, f64::max)
    }

    /// Longest command gap at any instance, ms.
    pub fn max_command_gap_ms(&self) -> f64 {
        self.latest
            .values()
            .map(|d| d.max_command_gap_ns as f64 / 1e6)
            .fold(0.0, f64::max)
    }
}

/// The safe-stop stream as `motm run` reads it: the raises for a fault (seen, or counted by
/// the watchdog between two samples) and the releases.
#[derive(Debug, Default)]
struct SafeStopLog {
    /// Whether the watchdog has cleared safe-stop once (the stack is up).
    stack_up: bool,
    /// Whether safe-stop is raised for a fault (not the start-up hold).
    active: bool,
    /// The watchdog's count of fault raises in the last sample (`SafeStop::fault_raises`).
    fault_raises: u64,
    /// Monotonic stamps of every raise for a fault seen, ns.
    raises_ns: Vec<u64>,
    /// Monotonic stamps of every release after a raise for a fault, ns.
    releases_ns: Vec<u64>,
    report: SafeStopReport,
}

impl SafeStopLog {
    /// Takes in one sample of the stream. The watchdog counts its raises: those that began and
    /// ended between two samples read here are counted too, their reason unseen. A restarted
    /// watchdog counts from zero again.
    fn observe(&mut self, sample: &SafeStop) {
        let stamp = sample.header.stamp_ns;
        let reason = SafeStopReason::try_from(sample.reason);
        let fault = sample.active == 1 && reason != Ok(SafeStopReason::Starting);
        if sample.fault_raises < self.fault_raises {
            self.fault_raises = 0;
        }
        let seen = u64::from(fault && !self.active);
        let unseen = (sample.fault_raises - self.fault_raises).saturating_sub(seen);
        self.fault_raises = sample.fault_raises;
        for _ in 0..unseen {
            self.count(UNSEEN_REASON.to_owned());
        }
        if fault && !self.active {
            self.raises_ns.push(stamp);
            self.count(reason.map_or_else(|code| format!("code {code}"), |r| format!("{r:?}")));
        } else if !fault && self.active {
            self.releases_ns.push(stamp);
        }
        if sample.active == 0 {
            self.stack_up = true;
        }
        self.active = fault;
    }

    /// Counts a raise for `reason`.
    fn count(&mut self, reason: String) {
        self.report.count += 1;
        self.report.at_startup += u32::from(!self.stack_up);
        self.report.reasons.push(reason);
    }
}

/// Carries out a fault schedule and watches the safe-stop stream.
pub struct FaultRunner {
    tracked: Vec<Tracked>,
    injectors: Vec<Box<dyn Injector>>,
    safe_stop: Subscriber<SafeStop>,
    safe_stops: SafeStopLog,
    /// Largest simulated time seen (sim-world's clock; kept when sim-world restarts).
    sim_time: f64,
    /// The mission events so far, from sim-world's truth.
    events: MissionEvents,
}

/// Sends `sig` to `pid`.
fn signal(pid: u32, sig: libc::c_int) -> bool {
    // SAFETY: kill(2) has no memory-safety preconditions.
    unsafe { libc::kill(pid as libc::pid_t, sig) == 0 }
}

/// Milliseconds from `from` to `to` (monotonic ns).
fn ms(from: u64, to: u64) -> f64 {
    to.saturating_sub(from) as f64 / 1e6
}

impl FaultRunner {
    /// A runner of `faults` (already checked) on `bus`; opens the injectors now, so the
    /// receivers are connected before the first NaN sample.
    pub fn new(bus: &Bus, faults: &[Fault]) -> Result<Self, BusError> {
        let mut injectors: Vec<Box<dyn Injector>> = Vec::new();
        for fault in faults.iter().filter(|f| f.kind == FaultKind::Nan) {
            let topic = full_topic_name(&fault.target);
            if injectors.iter().all(|i| i.topic() != topic)
                && let Some(injector) = open_injector(bus, &topic)?
            {
                injectors.push(injector);
            }
        }
        Ok(Self {
            tracked: faults
                .iter()
                .map(|f| Tracked {
                    fault: f.clone(),
                    record: FaultRecord {
                        kind: f.kind.name().into(),
                        target: f.target.clone(),
                        when: f.when(),
                        due_at_s: None,
                        outcome: "not_injected".into(),
                        ..FaultRecord::default()
                    },
                    injected_ns: None,
                    continued_ns: None,
                    raised_ns: None,
                    continue_at_ns: None,
                })
                .collect(),
            injectors,
            safe_stop: Subscriber::new(bus, services::SAFETY_SAFE_STOP, &Qos::default())?,
            safe_stops: SafeStopLog::default(),
            sim_time: 0.0,
            events: MissionEvents::default(),
        })
    }

    /// Whether any fault is scheduled (the run then watches at a higher rate).
    pub fn has_faults(&self) -> bool {
        !self.tracked.is_empty()
    }

    /// Takes in the safe-stop samples that arrived.
    fn watch_safe_stop(&mut self) {
        while let Ok(Some(sample)) = self.safe_stop.receive() {
            self.safe_stops.observe(&sample);
        }
    }

    /// One step at monotonic `now_ns` with sim-world's latest truth (when known), the
    /// supervisor's table and the heartbeat readers (process name, latest heartbeat).
    pub fn step(
        &mut self,
        now_ns: u64,
        truth: Option<&SimTruth>,
        status: Option<&SupervisorStatus>,
        heartbeats: &[(String, Latest<Heartbeat>)],
    ) {
        self.watch_safe_stop();
        if let Some(t) = truth {
            self.sim_time = self.sim_time.max(t.sim_time);
            self.events.observe(
                t.sim_time,
                t.gripper_opening,
                t.held_object,
                t.buttons_pressed,
            );
        }
        let sim_time = self.sim_time;
        let row_of = |name: &str| {
            status.and_then(|s| s.processes().iter().find(|p| p.name() == name).copied())
        };
        for t in &mut self.tracked {
            t.record.due_at_s = t.fault.due_s(&self.events);
            if t.injected_ns.is_none() && t.record.due_at_s.is_some_and(|due| sim_time >= due) {
                t.record.injected_at_s = Some(sim_time);
                t.injected_ns = Some(now_ns);
                match t.fault.kind {
                    FaultKind::Kill | FaultKind::Stop => {
                        let row = row_of(&t.fault.target)
                            .filter(|r| r.state() == Some(SupervisedState::Running));
                        let sig = if t.fault.kind == FaultKind::Kill {
                            libc::SIGKILL
                        } else {
                            libc::SIGSTOP
                        };
                        match row {
                            Some(r) if signal(r.pid, sig) => {
                                t.record.pid = Some(r.pid);
                                t.record.outcome = if sig == libc::SIGKILL {
                                    "not_restarted".into()
                                } else {
                                    "stopped".into()
                                };
                                t.continue_at_ns = (t.fault.kind == FaultKind::Stop)
                                    .then(|| now_ns + (t.fault.duration_s * 1e9) as u64);
                            }
                            _ => t.record.outcome = "no_process".into(),
                        }
                    }
                    FaultKind::Nan => {
                        let topic = full_topic_name(&t.fault.target);
                        t.record.outcome = match self
                            .injectors
                            .iter_mut()
                            .find(|i| i.topic() == topic)
                            .map(|i| i.inject(Malformation::NotANumber))
                        {
                            Some(Ok(true)) => "published".into(),
                            Some(Ok(false)) => "published_without_real_sample".into(),
                            Some(Err(e)) => format!("publish_failed: {e}"),
                            None => "no_injector".into(),
                        };
                    }
                }
            }
            let (Some(injected), Some(pid)) = (t.injected_ns, t.record.pid) else {
                continue;
            };
            if let Some(due) = t.continue_at_ns
                && t.continued_ns.is_none()
                && now_ns >= due
            {
                signal(pid, libc::SIGCONT);
                t.continued_ns = Some(now_ns);
                t.record.outcome = "continued".into();
            }
            if t.fault.kind == FaultKind::Kill {
                if t.record.restart_ms.is_none()
                    && let Some(row) = row_of(&t.fault.target)
                    && row.pid != 0
                    && row.pid != pid
                {
                    t.record.restart_ms = Some(ms(injected, now_ns));
                    t.record.outcome = "restarted".into();
                }
                if t.record.first_heartbeat_ms.is_none()
                    && heartbeats.iter().any(|(name, beat)| {
                        *name == t.fault.target && beat.get().is_some_and(|b| b.pid != pid)
                    })
                {
                    t.record.first_heartbeat_ms = Some(ms(injected, now_ns));
                }
            }
        }
        self.attribute_safe_stops();
    }

    /// Links each injected fault to the first safe-stop raise after it, and each stop to the
    /// first release after its SIGCONT. A stop's raise counts only within
    /// [`STOP_ATTRIBUTION_WINDOW_NS`] of its SIGSTOP or of its SIGCONT: the only moments a hang
    /// can silence a stream (the report's `safe_stops` still counts every raise).
    fn attribute_safe_stops(&mut self) {
        for t in &mut self.tracked {
            let Some(injected) = t.injected_ns else {
                continue;
            };
            if t.record.safe_stop_ms.is_none()
                && let Some(&raise) = self
                    .safe_stops
                    .raises_ns
                    .iter()
                    .find(|&&r| raise_is_the_faults(t.fault.kind, injected, t.continued_ns, r))
            {
                t.raised_ns = Some(raise);
                t.record.safe_stop_ms = Some(ms(injected, raise));
            }
            // Resumed: the stop's own safe-stop released after the SIGCONT.
            if let Some(continued) = t.continued_ns
                && t.record.resumed_ms.is_none()
                && let Some(raised) = t.raised_ns
                && let Some(&release) = self
                    .safe_stops
                    .releases_ns
                    .iter()
                    .find(|&&r| r >= continued.max(raised))
            {
                t.record.resumed_ms = Some(ms(continued, release));
                t.record.outcome = "resumed".into();
            }
        }
    }

    /// Continues every process still stopped (before the stack is shut down) and returns the
    /// records and the safe-stop report.
    pub fn finish(mut self) -> (Vec<FaultRecord>, SafeStopReport) {
        for t in &mut self.tracked {
            if let (Some(pid), None, Some(_)) = (t.record.pid, t.continued_ns, t.continue_at_ns) {
                signal(pid, libc::SIGCONT);
            }
        }
        let latency = self
            .tracked
            .iter()
            .filter(|t| t.fault.kind == FaultKind::Stop)
            .filter_map(|t| t.record.safe_stop_ms)
            .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
        self.safe_stops.report.latency_ms = latency;
        (
            self.tracked.into_iter().map(|t| t.record).collect(),
            self.safe_stops.report,
        )
    }
}

/// Prints the safe-stops and the faults for `motm run`'s text report.
pub fn print_faults(faults: &[FaultRecord], safe_stops: &SafeStopReport) {
    let latency = safe_stops
        .latency_ms
        .map_or_else(String::new, |l| format!(", latency {l:.1} ms"));
    println!("safe-stops {}{latency}", safe_stops.count);
    let figure = |name: &str, value: Option<f64>| {
        value.map_or_else(String::new, |v| format!(", {name} {v:.0} ms"))
    };
    for f in faults {
        println!(
            "fault {}:{}@{} at {}: {}{}{}{}{}",
            f.kind,
            f.target,
            f.when,
            f.injected_at_s
                .map_or_else(|| "-".to_string(), |t| format!("{t:.2} s")),
            f.outcome,
            figure("restart", f.restart_ms),
            figure("first heartbeat", f.first_heartbeat_ms),
            figure("safe-stop", f.safe_stop_ms),
            figure("released", f.resumed_ms),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_core::fault_schedule::parse_schedule;
    use motm_msgs::Message;

    fn sample(stamp_ns: u64, reason: SafeStopReason, fault_raises: u64) -> SafeStop {
        let mut m = SafeStop::zeroed();
        m.header.stamp_ns = stamp_ns;
        m.active = u32::from(reason != SafeStopReason::None);
        m.reason = reason.into();
        m.fault_raises = fault_raises;
        m
    }

    #[test]
    fn a_stop_owns_only_the_raises_soon_after_its_sigstop_or_its_sigcont() {
        const MS: u64 = 1_000_000;
        let stop = |raise| raise_is_the_faults(FaultKind::Stop, 1000 * MS, Some(1300 * MS), raise);
        assert!(!stop(999 * MS), "before the SIGSTOP");
        assert!(
            stop(1015 * MS) && stop(1100 * MS),
            "the hang's stale stream"
        );
        assert!(
            !stop(1268 * MS),
            "mid-hang, with a standby carrying the streams"
        );
        assert!(stop(1305 * MS), "just after the SIGCONT");
        assert!(!stop(2000 * MS), "seconds later");
        // Still stopped: nothing after the first window is the stop's until the SIGCONT.
        assert!(!raise_is_the_faults(
            FaultKind::Stop,
            1000 * MS,
            None,
            1200 * MS
        ));
        // A kill owns the first raise after it, however late.
        assert!(raise_is_the_faults(
            FaultKind::Kill,
            1000 * MS,
            None,
            5000 * MS
        ));
        assert!(!raise_is_the_faults(
            FaultKind::Kill,
            1000 * MS,
            None,
            999 * MS
        ));
    }

    #[test]
    fn raises_between_two_samples_are_counted_with_an_unseen_reason() {
        let mut log = SafeStopLog::default();
        log.observe(&sample(1, SafeStopReason::Starting, 0));
        log.observe(&sample(2, SafeStopReason::None, 0));
        // Two raises came and went between samples; a third is seen raised.
        log.observe(&sample(3, SafeStopReason::None, 2));
        log.observe(&sample(4, SafeStopReason::StaleCommand, 3));
        log.observe(&sample(5, SafeStopReason::StaleCommand, 3));
        log.observe(&sample(6, SafeStopReason::None, 3));
        assert_eq!(log.report.count, 3);
        assert_eq!(log.report.at_startup, 0);
        assert_eq!(
            log.report.reasons,
            [UNSEEN_REASON, UNSEEN_REASON, "StaleCommand"]
        );
        assert_eq!(
            (log.raises_ns.as_slice(), log.releases_ns.as_slice()),
            (&[4][..], &[6][..])
        );
        // A restarted watchdog counts from zero: its first raise is one more.
        log.observe(&sample(7, SafeStopReason::Starting, 0));
        log.observe(&sample(8, SafeStopReason::HeartbeatLost, 1));
        assert_eq!(log.report.count, 4);
        assert_eq!(
            log.report.reasons.last().map(String::as_str),
            Some("HeartbeatLost")
        );
    }

    #[test]
    fn a_raise_while_the_stack_starts_counts_at_start_up() {
        let mut log = SafeStopLog::default();
        log.observe(&sample(1, SafeStopReason::Starting, 0));
        log.observe(&sample(2, SafeStopReason::HeartbeatLost, 1));
        log.observe(&sample(3, SafeStopReason::None, 1));
        log.observe(&sample(4, SafeStopReason::DeadlineMiss, 2));
        assert_eq!((log.report.count, log.report.at_startup), (2, 1));
    }

    #[test]
    fn injectable_topics_are_the_graphs_topics_of_a_corruptible_payload() {
        let published = motm_graph::published_topics();
        let payload = |name: &str| {
            published
                .iter()
                .find(|t| t.name == name)
                .map(|t| t.type_name)
                .unwrap_or_else(|| panic!("{name} is injectable but no task publishes it"))
        };
        let corruptible: Vec<&str> = INJECTABLE_TOPICS.iter().map(|t| payload(t)).collect();
        for topic in &published {
            if corruptible.contains(&topic.type_name) {
                assert!(
                    INJECTABLE_TOPICS.contains(&topic.name),
                    "{} carries a {} but is not injectable",
                    topic.name,
                    topic.type_name
                );
            }
        }
    }

    #[test]
    fn targets_must_be_stack_processes_or_injectable_topics() {
        let processes = vec!["qp-resolver".to_string(), "reacher".to_string()];
        let ok = parse_schedule(&[
            "kill:qp-resolver@1",
            "stop:reacher@2+0.3",
            "nan:arm/velocity_command@3",
            "nan:motm/v1/base/odometry@3",
        ])
        .unwrap();
        check_targets(&ok, &processes).unwrap();
        let err = check_targets(&parse_schedule(&["kill:supervisor@1"]).unwrap(), &processes)
            .unwrap_err();
        assert!(err.starts_with("--fault kill:supervisor") && err.contains("qp-resolver"));
        let err = check_targets(
            &parse_schedule(&["nan:safety/safe_stop@1"]).unwrap(),
            &processes,
        )
        .unwrap_err();
        assert!(err.contains("motm/v1/safety/safe_stop"), "{err}");
    }
}
