//! The standard main loop of a motm process: wake on a WaitSet (interval timer or data
//! event), run one step, record the cycle, publish the heartbeat and refresh connections.

use std::time::Duration;

use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use motm_msgs::ProcessState;

use crate::{Bus, BusError, CycleStats, HeartbeatPublisher, Trigger, monotonic_now_ns};

/// Timing of a [`ServiceLoop`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopConfig {
    /// Cycle period of [`ServiceLoop::run_periodic`] (default 5 ms: the 200 Hz control rate).
    pub period: Duration,
    /// Longest acceptable cycle (wake to end of step); `None` means one period. A periodic
    /// cycle also misses its deadline when it starts more than this late, i.e. when the gap
    /// since the previous wake exceeds period + deadline (a lost tick).
    pub deadline: Option<Duration>,
    /// Interval between heartbeats (default 100 ms).
    pub heartbeat_period: Duration,
    /// Interval between connection refreshes, so restarted peers reconnect (default 100 ms).
    pub connection_refresh: Duration,
    /// Number of recent cycle times kept for percentiles (default 2000).
    pub stats_window: usize,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            period: Duration::from_millis(5),
            deadline: None,
            heartbeat_period: Duration::from_millis(100),
            connection_refresh: Duration::from_millis(100),
            stats_window: 2000,
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

/// The standard service loop of a process: it owns the heartbeat and the cycle statistics.
pub struct ServiceLoop<'bus> {
    bus: &'bus Bus,
    config: LoopConfig,
    stats: CycleStats,
    heartbeat: HeartbeatPublisher,
    last_wake_ns: Option<u64>,
    last_heartbeat_ns: u64,
    last_refresh_ns: u64,
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
            last_heartbeat_ns: now,
            last_refresh_ns: now,
        })
    }

    /// Cycle statistics so far.
    pub fn stats(&self) -> &CycleStats {
        &self.stats
    }

    /// Mutable statistics (percentiles need scratch space).
    pub fn stats_mut(&mut self) -> &mut CycleStats {
        &mut self.stats
    }

    /// Runs `step` once per period on the WaitSet's interval timer until it returns
    /// [`Flow::Stop`] or SIGTERM/SIGINT arrives. The step reads the latest samples, computes
    /// and publishes; this loop records its time and handles heartbeats and reconnections.
    pub fn run_periodic(
        &mut self,
        mut step: impl FnMut(&CycleContext) -> Flow,
    ) -> Result<LoopExit, BusError> {
        let waitset = Self::waitset()?;
        let tick = waitset
            .attach_interval(self.config.period)
            .map_err(|e| BusError::Loop(format!("{e:?}")))?;
        let period_ns = self.config.period.as_nanos() as u64;
        let mut stopped = false;
        let result = waitset.wait_and_process(|id| {
            if id.has_event_from(&tick) && self.cycle(period_ns, &mut step) == Flow::Stop {
                stopped = true;
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        self.finish(result, stopped, period_ns)
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
        let result = waitset.wait_and_process(|id| {
            if id.has_event_from(&on_data) {
                trigger.clear();
                if self.cycle(0, &mut step) == Flow::Stop {
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

    /// A WaitSet that reports SIGTERM and SIGINT.
    fn waitset() -> Result<WaitSet<ipc::Service>, BusError> {
        WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(|e| BusError::Loop(format!("{e:?}")))
    }

    /// Runs and records one cycle; `period_ns` is 0 for event-driven loops.
    fn cycle(&mut self, period_ns: u64, step: &mut impl FnMut(&CycleContext) -> Flow) -> Flow {
        let wake = monotonic_now_ns();
        let since_last_ns = self.last_wake_ns.map_or(0, |last| wake - last);
        self.last_wake_ns = Some(wake);
        let flow = step(&CycleContext {
            now_ns: wake,
            cycle: self.stats.cycles(),
            since_last_ns,
        });
        let end = monotonic_now_ns();
        let cycle_ns = end - wake;
        let deadline_ns = self.config.deadline_ns();
        let late_start = period_ns > 0 && since_last_ns > period_ns + deadline_ns;
        self.stats
            .record(cycle_ns, cycle_ns > deadline_ns || late_start, end);
        self.housekeeping(end, period_ns);
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
        self.heartbeat.publish(
            ProcessState::Stopping,
            &mut self.stats,
            period_ns,
            self.bus.rejected_messages(),
        )?;
        Ok(exit)
    }
}
