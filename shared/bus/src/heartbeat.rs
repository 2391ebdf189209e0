//! Per-process heartbeat: liveness plus loop statistics, on `motm/v1/heartbeat/<process>`.

use motm_msgs::{Heartbeat, Message, ProcessState, services};

use crate::{Bus, BusError, CycleStats, Publisher, Qos};

/// Publishes this process's [`Heartbeat`]. A hung process stops publishing, which is how the
/// watchdog sees a hang (iceoryx2 itself only sees dead processes).
pub struct HeartbeatPublisher {
    publisher: Publisher<Heartbeat>,
    template: Heartbeat,
}

impl HeartbeatPublisher {
    /// Creates the heartbeat publisher of the process that owns `bus`.
    pub fn new(bus: &Bus) -> Result<Self, BusError> {
        let publisher = Publisher::new(bus, &services::heartbeat(bus.process()), &Qos::default())?;
        let mut template = Heartbeat::zeroed();
        template.pid = std::process::id();
        template.set_process_name(bus.process());
        Ok(Self {
            publisher,
            template,
        })
    }

    /// Publishes one heartbeat with the loop's statistics, its period (0 for event-driven
    /// loops) and the bus's count of rejected messages.
    pub fn publish(
        &mut self,
        state: ProcessState,
        stats: &mut CycleStats,
        period_ns: u64,
        rejected_messages: u64,
    ) -> Result<(), BusError> {
        let mut beat = self.template;
        beat.state = state.into();
        beat.cycles = stats.cycles();
        beat.deadline_misses = stats.deadline_misses();
        beat.rejected_messages = rejected_messages;
        beat.p99_cycle_ns = stats.percentile_ns(99.0);
        beat.max_cycle_ns = stats.max_cycle_ns();
        beat.period_ns = period_ns;
        beat.last_deadline_miss_ns = stats.last_deadline_miss_ns();
        self.publisher.publish(beat)
    }
}
