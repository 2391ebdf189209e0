//! The watchdog's decision: raise safe-stop when a watched heartbeat or command stream goes
//! stale, or when a control-path process reports new deadline misses.
//!
//! Pure: the watchdog process feeds in what it received (with the senders' monotonic stamps)
//! and asks for a verdict each cycle. A hung process (SIGSTOP) stops publishing, so it shows up
//! here as a stale source although the operating system still sees it alive.
//!
//! Choices:
//! - **A source never seen holds the robot, and is not a fault.** Until every watched source has
//!   been heard from, safe-stop stays raised with [`SafetyFault::Starting`] (nothing moves before
//!   the control path is up). A process still starting is not a lost heartbeat: start-up holds
//!   are neither logged nor counted as safe-stops. A source heard once and then silent is lost,
//!   at start-up too.
//! - **Staleness** of a source is `stale_cycles` of its expected period without a sample.
//!   Heartbeats come every `heartbeat_interval_ms` (the service loop's default 100 ms); command
//!   streams every control period, so a hung resolver is caught within three control cycles.
//! - **Deadline misses** are cumulative counts in heartbeats: an increase by at least
//!   `deadline_miss_threshold` between two heartbeats, and by more than `deadline_miss_fraction`
//!   of the cycles run in between, raises safe-stop for `deadline_miss_hold_ms`. The defaults
//!   (1 and 0) trip on any miss, as on a real-time kernel; a loaded development machine needs a
//!   fraction (its stack config says so). A count that goes down (the process restarted) is a
//!   new baseline.
//! - **Redundant sources** ([`Watchdog::redundant`]): the heartbeats of a task and its hot
//!   standby count as one source. A fault of one member is no fault while another member of its
//!   group has none: a dead primary resolver leaves its standby commanding, and stopping the
//!   robot for it would defeat the standby. The command streams still have to stay fresh.
//! - **Priority** when several faults hold: lost heartbeat, then stale command, then deadline
//!   miss, then a source not started yet.

use serde::Deserialize;

/// Tunables of the watchdog. Read from the `[watchdog]` table of a stack config.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WatchdogConfig {
    /// Expected periods without a sample after which a source is stale (default 3).
    pub stale_cycles: u32,
    /// Expected interval between heartbeats, ms (the service loop's default, 100 ms).
    pub heartbeat_interval_ms: f64,
    /// New deadline misses between two heartbeats that raise safe-stop (0 disables the check).
    pub deadline_miss_threshold: u64,
    /// Fraction of the cycles between two heartbeats that must have missed, too (0 = any).
    pub deadline_miss_fraction: f64,
    /// How long safe-stop stays raised after a reported deadline miss, ms.
    pub deadline_miss_hold_ms: f64,
}

impl Default for WatchdogConfig {
    fn default() -> Self {
        Self {
            stale_cycles: 3,
            heartbeat_interval_ms: 100.0,
            deadline_miss_threshold: 1,
            deadline_miss_fraction: 0.0,
            deadline_miss_hold_ms: 100.0,
        }
    }
}

impl WatchdogConfig {
    /// Checks every value; returns the offending key otherwise.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if self.stale_cycles == 0 {
            return Err(("stale_cycles", "must be at least 1".to_string()));
        }
        for (key, value) in [
            ("heartbeat_interval_ms", self.heartbeat_interval_ms),
            ("deadline_miss_hold_ms", self.deadline_miss_hold_ms),
        ] {
            if !value.is_finite() || value <= 0.0 {
                return Err((key, format!("must be a finite number > 0, got {value}")));
            }
        }
        if !(0.0..=1.0).contains(&self.deadline_miss_fraction) {
            return Err((
                "deadline_miss_fraction",
                format!("must be in [0, 1], got {}", self.deadline_miss_fraction),
            ));
        }
        Ok(())
    }

    /// Staleness limit of a heartbeat, ns.
    pub fn heartbeat_timeout_ns(&self) -> u64 {
        (f64::from(self.stale_cycles) * self.heartbeat_interval_ms * 1e6) as u64
    }
}

/// What kind of stream a watched source is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// A process heartbeat (staleness and deadline misses are checked).
    Heartbeat,
    /// A command stream with the given period, ns (staleness is checked).
    Command {
        /// Expected interval between samples, ns.
        period_ns: u64,
    },
}

/// Why the watchdog raises safe-stop; the index names the source (order of [`Watchdog::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafetyFault {
    /// A heartbeat was received and then went stale.
    HeartbeatLost(usize),
    /// A command stream started and then went stale.
    StaleCommand(usize),
    /// A process reported new deadline misses.
    DeadlineMiss(usize),
    /// A source has not been heard from yet (the stack is starting).
    Starting(usize),
}

impl SafetyFault {
    /// The index of the source at fault.
    pub fn source(&self) -> usize {
        match *self {
            Self::HeartbeatLost(i)
            | Self::StaleCommand(i)
            | Self::DeadlineMiss(i)
            | Self::Starting(i) => i,
        }
    }
}

/// State kept per watched source.
#[derive(Debug, Clone, Copy)]
struct SourceState {
    kind: SourceKind,
    last_stamp_ns: Option<u64>,
    last_misses: Option<u64>,
    last_cycles: u64,
    miss_until_ns: Option<u64>,
    /// The redundant group the source belongs to, if any.
    group: Option<usize>,
}

/// The watchdog's state over its watched sources.
#[derive(Debug, Clone)]
pub struct Watchdog {
    config: WatchdogConfig,
    sources: Vec<SourceState>,
}

impl Watchdog {
    /// A watchdog over `sources` (indices into this slice name them in faults).
    pub fn new(config: WatchdogConfig, sources: &[SourceKind]) -> Self {
        Self {
            config,
            sources: sources
                .iter()
                .map(|&kind| SourceState {
                    kind,
                    last_stamp_ns: None,
                    last_misses: None,
                    last_cycles: 0,
                    miss_until_ns: None,
                    group: None,
                })
                .collect(),
        }
    }

    /// Records a heartbeat of source `index` stamped `stamp_ns` reporting `cycles` and
    /// `deadline_misses` in total, received at `now_ns`. Older stamps than the last one are
    /// ignored.
    pub fn heartbeat(
        &mut self,
        index: usize,
        stamp_ns: u64,
        cycles: u64,
        deadline_misses: u64,
        now_ns: u64,
    ) {
        let threshold = self.config.deadline_miss_threshold;
        let fraction = self.config.deadline_miss_fraction;
        let hold_ns = (self.config.deadline_miss_hold_ms * 1e6) as u64;
        let Some(source) = self.sources.get_mut(index) else {
            return;
        };
        if source.last_stamp_ns.is_some_and(|last| stamp_ns < last) {
            return;
        }
        source.last_stamp_ns = Some(stamp_ns);
        if let Some(previous) = source.last_misses
            && threshold > 0
            && deadline_misses >= previous + threshold
        {
            let new_misses = deadline_misses - previous;
            let new_cycles = cycles.saturating_sub(source.last_cycles);
            if new_misses as f64 > fraction * new_cycles as f64 {
                source.miss_until_ns = Some(now_ns + hold_ns);
            }
        }
        source.last_misses = Some(deadline_misses);
        source.last_cycles = cycles;
    }

    /// Records a sample of command stream `index` stamped `stamp_ns`.
    pub fn command(&mut self, index: usize, stamp_ns: u64) {
        if let Some(source) = self.sources.get_mut(index)
            && source.last_stamp_ns.is_none_or(|last| stamp_ns >= last)
        {
            source.last_stamp_ns = Some(stamp_ns);
        }
    }

    /// Makes the sources `members` one redundant source: a fault of one of them is none while
    /// another has no fault (a task and its hot standby). Unknown indices are ignored.
    pub fn redundant(&mut self, members: &[usize]) {
        let group = self
            .sources
            .iter()
            .filter_map(|s| s.group)
            .max()
            .map_or(0, |g| g + 1);
        for &index in members {
            if let Some(source) = self.sources.get_mut(index) {
                source.group = Some(group);
            }
        }
    }

    /// Every fault holding at `now_ns`, by source (a redundant group's only when all its
    /// members have one).
    pub fn faults(&self, now_ns: u64) -> Vec<SafetyFault> {
        let faults = self.source_faults(now_ns);
        let faulty = |index: usize| faults.iter().any(|f| f.source() == index);
        // A source whose group has a member without a fault.
        let covered = |index: usize| {
            self.sources[index].group.is_some_and(|group| {
                self.sources
                    .iter()
                    .enumerate()
                    .any(|(other, s)| other != index && s.group == Some(group) && !faulty(other))
            })
        };
        faults
            .iter()
            .copied()
            .filter(|fault| !covered(fault.source()))
            .collect()
    }

    /// Every fault of every source on its own.
    fn source_faults(&self, now_ns: u64) -> Vec<SafetyFault> {
        let mut faults = Vec::new();
        for (index, source) in self.sources.iter().enumerate() {
            let timeout_ns = match source.kind {
                SourceKind::Heartbeat => self.config.heartbeat_timeout_ns(),
                SourceKind::Command { period_ns } => {
                    u64::from(self.config.stale_cycles).saturating_mul(period_ns)
                }
            };
            let Some(stamp) = source.last_stamp_ns else {
                faults.push(SafetyFault::Starting(index));
                continue;
            };
            let stale = now_ns.saturating_sub(stamp) > timeout_ns;
            match source.kind {
                SourceKind::Heartbeat if stale => faults.push(SafetyFault::HeartbeatLost(index)),
                SourceKind::Command { .. } if stale => {
                    faults.push(SafetyFault::StaleCommand(index));
                }
                _ => {}
            }
            if source.miss_until_ns.is_some_and(|until| now_ns < until) {
                faults.push(SafetyFault::DeadlineMiss(index));
            }
        }
        faults
    }

    /// The fault that safe-stop reports at `now_ns` (by priority), or `None` when all is well.
    pub fn verdict(&self, now_ns: u64) -> Option<SafetyFault> {
        self.faults(now_ns)
            .into_iter()
            .min_by_key(|fault| match fault {
                SafetyFault::HeartbeatLost(i) => (0, *i),
                SafetyFault::StaleCommand(i) => (1, *i),
                SafetyFault::DeadlineMiss(i) => (2, *i),
                SafetyFault::Starting(i) => (3, *i),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// Two heartbeats (0, 1) and a 5 ms command stream (2).
    fn watchdog() -> Watchdog {
        Watchdog::new(
            WatchdogConfig::default(),
            &[
                SourceKind::Heartbeat,
                SourceKind::Heartbeat,
                SourceKind::Command { period_ns: 5 * MS },
            ],
        )
    }

    /// Feeds every source a fresh sample at `t`.
    fn feed_all(w: &mut Watchdog, t: u64, misses: u64) {
        // 100 cycles per millisecond of stamp: plenty, so any miss counts at fraction 0.
        w.heartbeat(0, t, t / 10_000, misses, t);
        w.heartbeat(1, t, t / 10_000, 0, t);
        w.command(2, t);
    }

    #[test]
    fn a_redundant_pair_faults_only_when_both_members_do() {
        let mut w = watchdog();
        w.redundant(&[0, 1]);
        // Only one of the pair has started: the pair is up.
        w.heartbeat(0, 0, 0, 0, 0);
        w.command(2, 0);
        assert_eq!(w.verdict(MS), None);
        feed_all(&mut w, 10 * MS, 0);
        // Member 0 goes silent (killed): no fault while member 1 beats.
        for t in (20..=600).step_by(10) {
            w.heartbeat(1, t * MS, t * 100, 0, t * MS);
            w.command(2, t * MS);
        }
        assert_eq!(w.verdict(600 * MS), None);
        // Member 1 goes silent as well (the commands still come): both are lost.
        for t in (600..=1000).step_by(5) {
            w.command(2, t * MS);
        }
        assert_eq!(w.verdict(1000 * MS), Some(SafetyFault::HeartbeatLost(0)));
        assert!(w.faults(1000 * MS).contains(&SafetyFault::HeartbeatLost(1)));
    }

    #[test]
    fn unseen_sources_hold_safe_stop_as_starting_until_all_are_heard() {
        let mut w = watchdog();
        assert_eq!(w.verdict(0), Some(SafetyFault::Starting(0)));
        w.heartbeat(0, 0, 0, 0, 0);
        w.heartbeat(1, 0, 0, 0, 0);
        assert_eq!(w.verdict(MS), Some(SafetyFault::Starting(2)));
        w.command(2, MS);
        assert_eq!(w.verdict(2 * MS), None);
    }

    #[test]
    fn a_source_heard_once_and_then_silent_is_lost_while_others_still_start() {
        let mut w = watchdog();
        w.heartbeat(0, 0, 0, 0, 0);
        // Source 1 and the commands are still starting; source 0 goes silent.
        assert_eq!(w.verdict(300 * MS), Some(SafetyFault::Starting(1)));
        assert_eq!(w.verdict(301 * MS), Some(SafetyFault::HeartbeatLost(0)));
    }

    #[test]
    fn a_command_stream_goes_stale_after_three_periods_and_recovers() {
        let mut w = watchdog();
        feed_all(&mut w, 1000 * MS, 0);
        // 15 ms (three periods) is still fine, 16 ms is not.
        assert_eq!(w.verdict(1015 * MS), None);
        assert_eq!(w.verdict(1016 * MS), Some(SafetyFault::StaleCommand(2)));
        w.command(2, 1017 * MS);
        assert_eq!(w.verdict(1018 * MS), None);
    }

    #[test]
    fn a_hung_process_loses_its_heartbeat_after_three_intervals() {
        let mut w = watchdog();
        feed_all(&mut w, 1000 * MS, 0);
        // Source 1 stops; the others go on.
        for t in (1005..=1400).step_by(5) {
            w.heartbeat(0, t * MS, t, 0, t * MS);
            w.command(2, t * MS);
            let expected = (t > 1300).then_some(SafetyFault::HeartbeatLost(1));
            assert_eq!(w.verdict(t * MS), expected, "t = {t} ms");
        }
    }

    #[test]
    fn new_deadline_misses_raise_safe_stop_for_the_hold_time() {
        let mut w = watchdog();
        // The first heartbeat sets the baseline, however many misses it reports.
        feed_all(&mut w, 1000 * MS, 5);
        assert_eq!(w.verdict(1001 * MS), None);
        feed_all(&mut w, 1010 * MS, 6);
        assert_eq!(w.verdict(1011 * MS), Some(SafetyFault::DeadlineMiss(0)));
        feed_all(&mut w, 1100 * MS, 6);
        assert_eq!(w.verdict(1105 * MS), Some(SafetyFault::DeadlineMiss(0)));
        assert_eq!(w.verdict(1110 * MS), None);
        // A restart resets the count: a lower count is a new baseline, not a miss.
        feed_all(&mut w, 1200 * MS, 0);
        assert_eq!(w.verdict(1201 * MS), None);
    }

    #[test]
    fn lost_heartbeats_take_priority_and_old_stamps_are_ignored() {
        let mut w = watchdog();
        feed_all(&mut w, 1000 * MS, 0);
        feed_all(&mut w, 1010 * MS, 3);
        // An out-of-order heartbeat neither refreshes nor changes the miss baseline.
        w.heartbeat(1, 500 * MS, 0, 0, 1011 * MS);
        assert_eq!(w.verdict(1011 * MS), Some(SafetyFault::DeadlineMiss(0)));
        let faults = w.faults(1400 * MS);
        assert!(faults.contains(&SafetyFault::HeartbeatLost(1)));
        assert!(faults.contains(&SafetyFault::StaleCommand(2)));
        assert_eq!(w.verdict(1400 * MS), Some(SafetyFault::HeartbeatLost(0)));
    }

    #[test]
    fn a_miss_fraction_tolerates_sparse_misses_but_not_dense_ones() {
        let config = WatchdogConfig {
            deadline_miss_threshold: 1,
            deadline_miss_fraction: 0.25,
            ..WatchdogConfig::default()
        };
        let mut w = Watchdog::new(config, &[SourceKind::Heartbeat]);
        w.heartbeat(0, 1000 * MS, 1000, 0, 1000 * MS);
        // 10 misses in 100 cycles: 10 %, tolerated.
        w.heartbeat(0, 1100 * MS, 1100, 10, 1100 * MS);
        assert_eq!(w.verdict(1101 * MS), None);
        // 30 misses in the next 100 cycles: 30 %, safe-stop.
        w.heartbeat(0, 1200 * MS, 1200, 40, 1200 * MS);
        assert_eq!(w.verdict(1201 * MS), Some(SafetyFault::DeadlineMiss(0)));
    }

    #[test]
    fn config_validation_names_the_key() {
        let bad = WatchdogConfig {
            stale_cycles: 0,
            ..WatchdogConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "stale_cycles");
        let bad = WatchdogConfig {
            heartbeat_interval_ms: f64::INFINITY,
            ..WatchdogConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "heartbeat_interval_ms");
        let bad = WatchdogConfig {
            deadline_miss_fraction: 1.5,
            ..WatchdogConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "deadline_miss_fraction");
    }
}
