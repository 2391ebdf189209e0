//! systemd notifications of the service loop (`Type=notify` units with `WatchdogSec`):
//! `READY=1` after the first completed loop iteration, then `WATCHDOG=1` at half the watchdog
//! interval systemd asks for, again only after completed iterations, so that a process that
//! hangs in its step stops feeding the watchdog and systemd restarts it. `STOPPING=1` when the
//! loop ends. Through the `sd-notify` crate; everything is a no-op when `NOTIFY_SOCKET` is not
//! set (a process started by the supervisor or by hand).

use std::time::Duration;

use sd_notify::NotifyState;

/// The notification state of one service loop.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SystemdNotifier {
    /// Whether `NOTIFY_SOCKET` was set at start.
    enabled: bool,
    /// Whether `READY=1` was sent.
    ready_sent: bool,
    /// Interval between `WATCHDOG=1`, ns (half of `WATCHDOG_USEC`), when systemd asks for it.
    watchdog_every_ns: Option<u64>,
    /// When the last `WATCHDOG=1` was sent, ns.
    last_watchdog_ns: u64,
    /// Notifications that could not be sent.
    failures: u64,
}

impl SystemdNotifier {
    /// The notifier for this process's environment (`NOTIFY_SOCKET`, `WATCHDOG_USEC`,
    /// `WATCHDOG_PID`).
    pub fn from_env() -> Self {
        Self::new(
            std::env::var_os("NOTIFY_SOCKET").is_some(),
            sd_notify::watchdog_enabled(),
        )
    }

    /// A notifier that sends when `enabled`, feeding a watchdog of interval `watchdog`.
    pub fn new(enabled: bool, watchdog: Option<Duration>) -> Self {
        Self {
            enabled,
            ready_sent: false,
            watchdog_every_ns: watchdog.map(|w| (w.as_nanos() / 2).max(1) as u64),
            last_watchdog_ns: 0,
            failures: 0,
        }
    }

    /// Whether notifications are sent at all.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Whether `READY=1` was sent.
    pub fn ready_sent(&self) -> bool {
        self.ready_sent
    }

    /// Notifications that could not be sent.
    pub fn failures(&self) -> u64 {
        self.failures
    }

    /// Records a completed loop iteration at `now_ns`: sends `READY=1` after the first and
    /// `WATCHDOG=1` whenever half the watchdog interval has passed since the last one.
    pub fn iteration_done(&mut self, now_ns: u64) {
        if !self.enabled {
            return;
        }
        if !self.ready_sent {
            self.ready_sent = true;
            self.last_watchdog_ns = now_ns;
            self.send(&[NotifyState::Ready, NotifyState::Watchdog]);
            return;
        }
        if let Some(every) = self.watchdog_every_ns
            && now_ns.saturating_sub(self.last_watchdog_ns) >= every
        {
            self.last_watchdog_ns = now_ns;
            self.send(&[NotifyState::Watchdog]);
        }
    }

    /// Announces the end of the loop (`STOPPING=1`).
    pub fn stopping(&mut self) {
        if self.enabled {
            self.send(&[NotifyState::Stopping]);
        }
    }

    fn send(&mut self, states: &[NotifyState]) {
        if sd_notify::notify(states).is_err() {
            self.failures += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_disabled_notifier_never_counts_as_ready() {
        let mut n = SystemdNotifier::new(false, Some(Duration::from_millis(10)));
        n.iteration_done(1);
        assert!(!n.enabled() && !n.ready_sent());
        n.stopping();
        assert_eq!(n.failures(), 0);
    }
}
