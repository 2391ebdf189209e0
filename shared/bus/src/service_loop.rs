//! The standard main loop of a motm process: wake on a WaitSet (periodic timer or data
//! event), run one step, record the cycle, publish the heartbeat and refresh connections.
//! The periodic timer is a `timerfd` by default (see [`crate::TickSource`] for why not the
//! WaitSet's own interval).

use std::time::Duration;

use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use motm_msgs::ProcessState;

use crate::{
    Bus, BusError, CycleStats, HeartbeatPublisher, PeriodicTimer, SystemdNotifier, TickSource,
    Trigger, monotonic_now_ns,
};

/// Timing of a [`ServiceLoop`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopConfig {
    /// Cycle period of [`ServiceLoop::run_periodic`] (default 5 ms: the 200 Hz control rate).
    pub period: Duration,
    /// Longest acceptable time from a cycle's release to the end of its step; `None` means
    /// one period. A periodic cycle is released at its timer tick, so a late wake-up counts
    /// against it; an event-driven cycle is released when it wakes. A tick that passes with
    /// no cycle at all, although the previous cycle had finished in time, is a miss too.
    pub deadline: Option<Duration>,
    /// Interval between heartbeats (default 100 ms).
    pub heartbeat_period: Duration,
    /// Interval between connection refreshes, so restarted peers reconnect (default 100 ms).
    pub connection_refresh: Duration,
    /// Number of recent cycle times kept for percentiles (default 2000).
    pub stats_window: usize,
    /// The timer of [`ServiceLoop::run_periodic`] (default [`TickSource::Timerfd`]; the
    /// environment variable [`crate::TICK_SOURCE_ENV`] overrides it for a whole process).
    pub tick_source: TickSource,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            period: Duration::from_millis(5),
            deadline: None,
            heartbeat_period: Duration::from_millis(100),
            connection_refresh: Duration::from_millis(100),
            stats_window: 2000,
            tick_source: TickSource::default(),
        }
    }
}

impl LoopConfig {
    /// A configuration with the given cycle rate, Hz, and defaults otherwise.
    pub fn with_rate(rate_hz: f64) -> Self {
        Self {
            period: Duration::from_secs_f64(1.0 / rate_hz),
            ..Self::default()
        }
    }

    /// The deadline in effect, ns.
    fn deadline_ns(&self) -> u64 {
        self.deadline.unwrap_or(self.period).as_nanos() as u64
    }
}

/// What the step sees of the current cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleContext {
    /// Monotonic time of the wake-up, ns.
    pub now_ns: u64,
    /// Index of this cycle, from 0.
    pub cycle: u64,
    /// Time since the previous wake-up, ns (0 in the first cycle).
    pub since_last_ns: u64,
    /// Monotonic time of the tick that released this cycle (the latest tick of the loop's
    /// grid at or before the wake-up), ns; `None` in event-driven loops. `now_ns` minus this
    /// is the wake-up lateness.
    pub tick_ns: Option<u64>,
}

/// Whether the loop goes on after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Run the next cycle.
    Continue,
    /// Leave the loop.
    Stop,
}

/// Why a loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopExit {
    /// The step returned [`Flow::Stop`].
    Stopped,
    /// SIGTERM was received.
    TerminationRequest,
    /// SIGINT was received.
    Interrupt,
}

/// The tick grid of a periodic loop: ticks fall at `origin_ns + k * period_ns`.
#[derive(Debug, Clone, Copy)]
struct Schedule {
    origin_ns: u64,
    period_ns: u64,
}

impl Schedule {
    /// Index and time of the latest tick at or before `t_ns` (tick 0 before the origin).
    fn tick_at(&self, t_ns: u64) -> (u64, u64) {
        let index = t_ns.saturating_sub(self.origin_ns) / self.period_ns;
        (index, self.origin_ns + index * self.period_ns)
    }
}

/// The last cycle of a periodic loop, for spotting lost ticks.
#[derive(Debug, Clone, Copy)]
struct LastTick {
    index: u64,
    end_ns: u64,
}

/// Whether a cycle missed its deadline: it ended more than `deadline_ns` after its release
/// (its tick, or its wake-up without a schedule), or a whole tick passed without a cycle
/// although the previous cycle had ended before that tick. Returns the miss flag and the
/// cycle's tick (for the next call).
fn deadline_missed(
    wake_ns: u64,
    end_ns: u64,
    deadline_ns: u64,
    schedule: Option<Schedule>,
    last: Option<LastTick>,
) -> (bool, Option<LastTick>) {
    let Some(s) = schedule else {
        return (end_ns - wake_ns > deadline_ns, None);
    };
    let (index, release) = s.tick_at(wake_ns);
    let overran = end_ns - release.min(wake_ns) > deadline_ns;
    let lost_tick = last.is_some_and(|last| {
        index > last.index + 1 && last.end_ns <= s.origin_ns + (last.index + 1) * s.period_ns
    });
    (overran || lost_tick, Some(LastTick { index, end_ns }))
}

/// The standard service loop of a process: it owns the heartbeat and the cycle statistics.
pub struct ServiceLoop<'bus> {
    bus: &'bus Bus,
    config: LoopConfig,
    stats: CycleStats,
    heartbeat: HeartbeatPublisher,
    last_wake_ns: Option<u64>,
    last_tick: Option<LastTick>,
    last_heartbeat_ns: u64,
    last_refresh_ns: u64,
    systemd: SystemdNotifier,
}

impl<'bus> ServiceLoop<'bus> {
    /// Creates the loop of the process that owns `bus` and announces it (heartbeat `Starting`).
    pub fn new(bus: &'bus Bus, config: LoopConfig) -> Result<Self, BusError> {
        let mut heartbeat = HeartbeatPublisher::new(bus)?;
        let mut stats = CycleStats::new(config.stats_window);
        heartbeat.publish(ProcessState::Starting, &mut stats, 0, 0)?;
        let now = monotonic_now_ns();
        Ok(Self {
            bus,
            config,
            stats,
            heartbeat,
            last_wake_ns: None,
            last_tick: None,
            last_heartbeat_ns: now,
            last_refresh_ns: now,
            systemd: SystemdNotifier::from_env(),
        })
    }

    /// The systemd notification state (`READY=1` and `WATCHDOG=1` after completed cycles).
    pub fn systemd(&self) -> &SystemdNotifier {
        &self.systemd
    }

    /// Cycle statistics so far.
    pub fn stats(&self) -> &CycleStats {
        &self.stats
    }

    /// Mutable statistics (percentiles need scratch space).
    pub fn stats_mut(&mut self) -> &mut CycleStats {
        &mut self.stats
    }

    /// Runs `step` once per period on the configured [`TickSource`] until it returns
    /// [`Flow::Stop`] or SIGTERM/SIGINT arrives. The step reads the latest samples, computes
    /// and publishes; this loop records its time and handles heartbeats and reconnections.
    /// Ticks that pass while a step runs (or while the process is stopped) are coalesced into
    /// one cycle; the deadline rule counts them.
    pub fn run_periodic(
        &mut self,
        mut step: impl FnMut(&CycleContext) -> Flow,
    ) -> Result<LoopExit, BusError> {
        let source = TickSource::from_env()
            .map_err(BusError::Loop)?
            .unwrap_or(self.config.tick_source);
        let timer = match source {
            TickSource::Timerfd => Some(
                PeriodicTimer::start(self.config.period)
                    .map_err(|e| BusError::Loop(format!("timerfd: {e}")))?,
            ),
            TickSource::WaitsetInterval => None,
        };
        let waitset = Self::waitset()?;
        // The WaitSet starts its interval's grid when the interval is attached: an origin
        // taken just before is at most a few µs early, so a wake-up right after a tick is never
        // attributed to the tick before it. A timerfd's grid is its own.
        let schedule = Schedule {
            origin_ns: timer
                .as_ref()
                .map_or_else(monotonic_now_ns, |t| t.origin_ns()),
            period_ns: self.config.period.as_nanos() as u64,
        };
        let (result, stopped) = match &timer {
            Some(timer) => {
                let tick = waitset
                    .attach_notification(timer)
                    .map_err(|e| BusError::Loop(format!("{e:?}")))?;
                self.process_ticks(&waitset, &tick, Some(timer), schedule, &mut step)
            }
            None => {
                let tick = waitset
                    .attach_interval(self.config.period)
                    .map_err(|e| BusError::Loop(format!("{e:?}")))?;
                self.process_ticks(&waitset, &tick, None, schedule, &mut step)
            }
        };
        self.finish(result, stopped, schedule.period_ns)
    }

    /// Runs a cycle on each wake-up from `tick` (for a `timer`, only when a tick expired: a
    /// spurious wake-up runs none) until `step` stops or SIGTERM/SIGINT arrives; also says
    /// whether `step` stopped it.
    fn process_ticks(
        &mut self,
        waitset: &WaitSet<ipc::Service>,
        tick: &WaitSetGuard<'_, '_, ipc::Service>,
        timer: Option<&PeriodicTimer>,
        schedule: Schedule,
        step: &mut impl FnMut(&CycleContext) -> Flow,
    ) -> (
        Result<WaitSetRunResult, iceoryx2::waitset::WaitSetRunError>,
        bool,
    ) {
        let mut stopped = false;
        let result = process_until_signalled(waitset, |id| {
            if id.has_event_from(tick)
                && timer.is_none_or(|t| t.acknowledge() > 0)
                && self.cycle(Some(schedule), step) == Flow::Stop
            {
                stopped = true;
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        (result, stopped)
    }

    /// Runs `step` each time a sample is announced on `trigger` (see
    /// [`crate::Subscriber::trigger`]); heartbeats and reconnections continue on their own
    /// timer when no data comes. Ends like [`ServiceLoop::run_periodic`].
    pub fn run_on_data(
        &mut self,
        trigger: &Trigger,
        mut step: impl FnMut(&CycleContext) -> Flow,
    ) -> Result<LoopExit, BusError> {
        let waitset = Self::waitset()?;
        let on_data = waitset
            .attach_notification(trigger.listener())
            .map_err(|e| BusError::Loop(format!("{e:?}")))?;
        let housekeeping = waitset
            .attach_interval(
                self.config
                    .heartbeat_period
                    .min(self.config.connection_refresh),
            )
            .map_err(|e| BusError::Loop(format!("{e:?}")))?;
        let mut stopped = false;
        let result = process_until_signalled(&waitset, |id| {
            if id.has_event_from(&on_data) {
                trigger.clear();
                // A notification whose sample an earlier cycle already took wakes no cycle.
                if trigger.has_samples() && self.cycle(None, &mut step) == Flow::Stop {
                    stopped = true;
                    return CallbackProgression::Stop;
                }
            } else if id.has_event_from(&housekeeping) {
                self.housekeeping(monotonic_now_ns(), 0);
            }
            CallbackProgression::Continue
        });
        self.finish(result, stopped, 0)
    }

    /// Runs `step` each time a sample is announced on any of `triggers`, and also when nothing
    /// was announced for a whole period (`LoopConfig::period`) since the last cycle, so a
    /// stalled upstream still gets cycles that act on it. Several announcements that arrive
    /// together run one cycle. Ends like [`ServiceLoop::run_periodic`].
    pub fn run_on_arrival(
        &mut self,
        triggers: &[Trigger],
        mut step: impl FnMut(&CycleContext) -> Flow,
    ) -> Result<LoopExit, BusError> {
        let waitset = Self::waitset()?;
        let guards = triggers
            .iter()
            .map(|t| waitset.attach_notification(t.listener()))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| BusError::Loop(format!("{e:?}")))?;
        // A WaitSet needs an attachment to wait on; without triggers this is the timeout only.
        let idle = guards
            .is_empty()
            .then(|| waitset.attach_interval(self.config.period))
            .transpose()
            .map_err(|e| BusError::Loop(format!("{e:?}")))?;
        let period_ns = self.config.period.as_nanos() as u64;
        let mut last_cycle_ns = monotonic_now_ns();
        let result = loop {
            // A request that arrived outside the wait does not interrupt it: checked each turn.
            if crate::termination::termination_requested() {
                break Ok(WaitSetRunResult::TerminationRequest);
            }
            let now = monotonic_now_ns();
            let timeout = Duration::from_nanos((last_cycle_ns + period_ns).saturating_sub(now));
            let mut arrived = false;
            let waited = waitset.wait_and_process_once_with_timeout(
                |id| {
                    if guards.iter().any(|g| id.has_event_from(g)) {
                        arrived = true;
                    }
                    CallbackProgression::Continue
                },
                timeout,
            );
            match waited {
                Ok(WaitSetRunResult::Interrupt) if !crate::termination::termination_requested() => {
                }
                Ok(WaitSetRunResult::AllEventsHandled) => {}
                other => break other,
            }
            if arrived {
                for trigger in triggers {
                    trigger.clear();
                }
                // A notification whose sample an earlier cycle already took wakes no cycle.
                arrived = triggers.iter().any(Trigger::has_samples);
            }
            let now = monotonic_now_ns();
            if arrived || now >= last_cycle_ns + period_ns {
                last_cycle_ns = now;
                if self.cycle(None, &mut step) == Flow::Stop {
                    break Ok(WaitSetRunResult::StopRequest);
                }
            }
        };
        drop(idle);
        let stopped = matches!(result, Ok(WaitSetRunResult::StopRequest));
        self.finish(result, stopped, period_ns)
    }

    /// A WaitSet that reports SIGTERM and SIGINT (see [`process_until_signalled`]).
    fn waitset() -> Result<WaitSet<ipc::Service>, BusError> {
        WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(|e| BusError::Loop(format!("{e:?}")))
    }

    /// Runs and records one cycle; `schedule` is `None` for event-driven loops.
    fn cycle(
        &mut self,
        schedule: Option<Schedule>,
        step: &mut impl FnMut(&CycleContext) -> Flow,
    ) -> Flow {
        let wake = monotonic_now_ns();
        let since_last_ns = self.last_wake_ns.map_or(0, |last| wake - last);
        self.last_wake_ns = Some(wake);
        let flow = step(&CycleContext {
            now_ns: wake,
            cycle: self.stats.cycles(),
            since_last_ns,
            tick_ns: schedule.map(|s| s.tick_at(wake).1),
        });
        let end = monotonic_now_ns();
        let (missed, tick) = deadline_missed(
            wake,
            end,
            self.config.deadline_ns(),
            schedule,
            self.last_tick,
        );
        self.last_tick = tick;
        self.stats.record(end - wake, missed, end);
        self.systemd.iteration_done(end);
        self.housekeeping(end, schedule.map_or(0, |s| s.period_ns));
        flow
    }

    /// Publishes the heartbeat and refreshes connections when they are due.
    fn housekeeping(&mut self, now_ns: u64, period_ns: u64) {
        if now_ns - self.last_heartbeat_ns >= self.config.heartbeat_period.as_nanos() as u64 {
            self.last_heartbeat_ns = now_ns;
            // A failed heartbeat is visible to the watchdog as a missing one.
            let _ = self.heartbeat.publish(
                ProcessState::Running,
                &mut self.stats,
                period_ns,
                self.bus.rejected_messages(),
            );
        }
        if now_ns - self.last_refresh_ns >= self.config.connection_refresh.as_nanos() as u64 {
            self.last_refresh_ns = now_ns;
            self.bus.update_connections();
        }
    }

    /// Maps the WaitSet result and announces the shutdown (heartbeat `Stopping`).
    fn finish(
        &mut self,
        result: Result<WaitSetRunResult, iceoryx2::waitset::WaitSetRunError>,
        stopped: bool,
        period_ns: u64,
    ) -> Result<LoopExit, BusError> {
        let exit = match result.map_err(|e| BusError::Loop(format!("{e:?}")))? {
            WaitSetRunResult::TerminationRequest => LoopExit::TerminationRequest,
            WaitSetRunResult::Interrupt => LoopExit::Interrupt,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {
                debug_assert!(stopped);
                LoopExit::Stopped
            }
        };
        self.systemd.stopping();
        self.heartbeat.publish(
            ProcessState::Stopping,
            &mut self.stats,
            period_ns,
            self.bus.rejected_messages(),
        )?;
        Ok(exit)
    }
}

/// Runs `waitset` until `on_event` stops it or SIGTERM/SIGINT arrives. A process stopped with
/// SIGSTOP and continued with SIGCONT (a hang, or a debugger) also wakes with an interrupted
/// wait, which the WaitSet reports like SIGINT: unless the signal handler saw SIGINT or
/// SIGTERM, the loop goes on, so the process resumes instead of shutting down.
fn process_until_signalled(
    waitset: &WaitSet<ipc::Service>,
    mut on_event: impl FnMut(WaitSetAttachmentId<ipc::Service>) -> CallbackProgression,
) -> Result<WaitSetRunResult, iceoryx2::waitset::WaitSetRunError> {
    loop {
        // A request that arrived outside the wait does not interrupt it: checked each turn.
        if crate::termination::termination_requested() {
            return Ok(WaitSetRunResult::TerminationRequest);
        }
        // A request that arrives while a callback runs does not interrupt the next wait either:
        // each event is preceded by a look at the latch.
        let mut terminated = false;
        let waited = waitset.wait_and_process(|id| {
            if crate::termination::termination_requested() {
                terminated = true;
                return CallbackProgression::Stop;
            }
            on_event(id)
        });
        if terminated {
            return Ok(WaitSetRunResult::TerminationRequest);
        }
        match waited {
            Ok(WaitSetRunResult::Interrupt) if !crate::termination::termination_requested() => {}
            other => return other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{IpcConfig, Latest, Qos, cleanup::remove_domain, shared_memory_entries};
    use motm_msgs::{Heartbeat, services};

    const MS: u64 = 1_000_000;

    /// Ticks every 5 ms from t = 100 ms.
    const SCHEDULE: Schedule = Schedule {
        origin_ns: 100 * MS,
        period_ns: 5 * MS,
    };

    #[test]
    fn a_cycle_misses_when_it_ends_after_release_plus_deadline() {
        // Woken 1 ms after tick 2 (t = 110 ms), done 3 ms later: 4 ms after release.
        let (missed, tick) = deadline_missed(111 * MS, 114 * MS, 5 * MS, Some(SCHEDULE), None);
        assert!(!missed);
        assert_eq!(tick.unwrap().index, 2);
        // Woken 4 ms late and running 2 ms: 6 ms after release, past a 5 ms deadline, although
        // the step alone took less than the deadline.
        let (missed, _) = deadline_missed(114 * MS, 116 * MS, 5 * MS, Some(SCHEDULE), None);
        assert!(missed);
    }

    #[test]
    fn a_lost_tick_is_a_miss_unless_the_previous_cycle_overran() {
        let finished_early = LastTick {
            index: 2,
            end_ns: 111 * MS,
        };
        // Tick 3 (115 ms) passed without a cycle; the next one runs at tick 4.
        let (missed, _) = deadline_missed(
            120 * MS,
            121 * MS,
            5 * MS,
            Some(SCHEDULE),
            Some(finished_early),
        );
        assert!(missed);
        // The previous cycle ran past tick 3 (it is already counted as a miss): the cycle
        // at tick 4 is on time.
        let overran = LastTick {
            index: 2,
            end_ns: 117 * MS,
        };
        let (missed, _) =
            deadline_missed(120 * MS, 121 * MS, 5 * MS, Some(SCHEDULE), Some(overran));
        assert!(!missed);
        // Consecutive ticks: no lost tick.
        let (missed, _) = deadline_missed(
            115 * MS,
            116 * MS,
            5 * MS,
            Some(SCHEDULE),
            Some(finished_early),
        );
        assert!(!missed);
    }

    #[test]
    fn an_event_driven_cycle_is_measured_from_its_wake_up() {
        assert!(!deadline_missed(7 * MS, 11 * MS, 5 * MS, None, None).0);
        assert!(deadline_missed(7 * MS, 13 * MS, 5 * MS, None, None).0);
    }

    #[test]
    fn periodic_loop_on_a_timerfd_counts_slow_cycles_stops_on_request_and_says_goodbye() {
        periodic_loop_counts_slow_cycles_stops_on_request_and_says_goodbye(TickSource::Timerfd);
    }

    #[test]
    fn periodic_loop_on_a_waitset_interval_counts_slow_cycles_stops_on_request_and_says_goodbye() {
        periodic_loop_counts_slow_cycles_stops_on_request_and_says_goodbye(
            TickSource::WaitsetInterval,
        );
    }

    fn periodic_loop_counts_slow_cycles_stops_on_request_and_says_goodbye(source: TickSource) {
        let ipc = IpcConfig {
            prefix: format!("motmt{}_loop{}_", std::process::id(), source as u8),
        };
        {
            let bus = Bus::open_with("looper", &ipc).unwrap();
            let mut heartbeat =
                Latest::<Heartbeat>::new(&bus, &services::heartbeat("looper"), &Qos::default())
                    .unwrap();
            let config = LoopConfig {
                tick_source: source,
                ..LoopConfig::with_rate(200.0)
            };
            let mut service = ServiceLoop::new(&bus, config).unwrap();
            let mut seen = Vec::new();
            let mut ticks = Vec::new();
            let exit = service
                .run_periodic(|cycle| {
                    seen.push(cycle.cycle);
                    let tick = cycle.tick_ns.unwrap();
                    assert!(tick <= cycle.now_ns);
                    ticks.push(tick);
                    // Cycles 2 and 5 run four periods: each is a deadline miss.
                    if cycle.cycle == 2 || cycle.cycle == 5 {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    if cycle.cycle == 9 {
                        Flow::Stop
                    } else {
                        Flow::Continue
                    }
                })
                .unwrap();
            assert_eq!(exit, LoopExit::Stopped);
            assert_eq!(seen, (0..10).collect::<Vec<_>>());
            // Each cycle is released by a later tick of one 5 ms grid.
            for pair in ticks.windows(2) {
                assert!(pair[1] > pair[0] && (pair[1] - pair[0]) % (5 * MS) == 0);
            }
            assert_eq!(service.stats().cycles(), 10);
            assert!(service.stats().deadline_misses() >= 2);
            assert!(service.stats().max_cycle_ns() >= 20 * MS);
            heartbeat.update().unwrap();
            let beat = heartbeat.get().unwrap();
            assert_eq!(beat.state(), Some(motm_msgs::ProcessState::Stopping));
            assert_eq!(beat.cycles, 10);
            assert_eq!(beat.deadline_misses, service.stats().deadline_misses());
            assert_eq!(beat.period_ns, 5 * MS);
        }
        // SAFETY: the bus is dropped and no other process uses this prefix.
        unsafe { remove_domain(&ipc) }.unwrap();
        assert_eq!(
            shared_memory_entries(&ipc).unwrap(),
            Vec::<std::path::PathBuf>::new()
        );
    }
}
