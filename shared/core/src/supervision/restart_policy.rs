//! When a supervisor restarts a process that died: exponential backoff that resets once a
//! process has stayed up long enough, and an optional cap on restarts.
//!
//! Pure bookkeeping on monotonic nanosecond times; the supervisor does the `waitpid`, the
//! cleanup and the spawn.

use serde::Deserialize;

/// Tunables of the restart backoff. Read from the `[restart]` table of a stack config.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RestartPolicy {
    /// Delay before the first restart after a crash, ms. Chosen: 100 ms, well inside the
    /// 500 ms restart budget, yet long enough not to spin on a process that dies at start.
    pub initial_backoff_ms: f64,
    /// Factor applied to the delay for each further crash without a stable run in between.
    pub multiplier: f64,
    /// Longest delay between restarts, ms.
    pub max_backoff_ms: f64,
    /// A process that ran this long before dying counts as stable: its backoff starts over, ms.
    pub stable_after_ms: f64,
    /// Restarts allowed in total before giving up (0 = never give up).
    pub max_restarts: u32,
}

impl Default for RestartPolicy {
    fn default() -> Self {
        Self {
            initial_backoff_ms: 100.0,
            multiplier: 2.0,
            max_backoff_ms: 2000.0,
            stable_after_ms: 5000.0,
            max_restarts: 0,
        }
    }
}

impl RestartPolicy {
    /// Checks that every value is finite and in range; returns the offending key otherwise.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let positive = [
            ("initial_backoff_ms", self.initial_backoff_ms),
            ("max_backoff_ms", self.max_backoff_ms),
            ("stable_after_ms", self.stable_after_ms),
        ];
        for (key, value) in positive {
            if !value.is_finite() || value < 0.0 {
                return Err((key, format!("must be a finite number >= 0, got {value}")));
            }
        }
        if !self.multiplier.is_finite() || self.multiplier < 1.0 {
            return Err((
                "multiplier",
                format!("must be a finite number >= 1, got {}", self.multiplier),
            ));
        }
        if self.max_backoff_ms < self.initial_backoff_ms {
            return Err((
                "max_backoff_ms",
                format!(
                    "must be >= initial_backoff_ms ({}), got {}",
                    self.initial_backoff_ms, self.max_backoff_ms
                ),
            ));
        }
        Ok(())
    }
}

/// What to do about a process that just exited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartDecision {
    /// Restart it at this monotonic time, ns.
    RestartAt(u64),
    /// The restart budget is used up: leave it down.
    GiveUp,
}

/// Restart bookkeeping of one process.
#[derive(Debug, Clone)]
pub struct RestartBackoff {
    policy: RestartPolicy,
    /// Crashes since the last stable run.
    consecutive: u32,
    /// Restarts so far.
    restarts: u32,
    /// When the current instance started, ns.
    started_ns: Option<u64>,
}

impl RestartBackoff {
    /// Fresh bookkeeping under `policy`.
    pub fn new(policy: RestartPolicy) -> Self {
        Self {
            policy,
            consecutive: 0,
            restarts: 0,
            started_ns: None,
        }
    }

    /// Restarts done so far.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }

    /// Records that an instance started at `now_ns` (the first start or a restart).
    pub fn started(&mut self, now_ns: u64, is_restart: bool) {
        self.started_ns = Some(now_ns);
        if is_restart {
            self.restarts += 1;
        }
    }

    /// Records that the instance exited at `now_ns` and decides when to restart it.
    pub fn exited(&mut self, now_ns: u64) -> RestartDecision {
        let ran_ns = self.started_ns.map_or(0, |s| now_ns.saturating_sub(s));
        if ran_ns as f64 >= self.policy.stable_after_ms * 1e6 {
            self.consecutive = 0;
        }
        if self.policy.max_restarts > 0 && self.restarts >= self.policy.max_restarts {
            return RestartDecision::GiveUp;
        }
        let delay_ms = (self.policy.initial_backoff_ms
            * self.policy.multiplier.powi(self.consecutive.min(64) as i32))
        .min(self.policy.max_backoff_ms);
        self.consecutive = self.consecutive.saturating_add(1);
        RestartDecision::RestartAt(now_ns + (delay_ms * 1e6) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn backoff_grows_caps_and_resets_after_a_stable_run() {
        let mut b = RestartBackoff::new(RestartPolicy::default());
        b.started(0, false);
        // Dies at once, again and again: 100, 200, 400, 800, 1600, 2000 (cap), 2000 ms.
        let mut now = 10 * MS;
        let mut delays = Vec::new();
        for _ in 0..7 {
            let RestartDecision::RestartAt(at) = b.exited(now) else {
                panic!("gave up with unlimited restarts");
            };
            delays.push((at - now) / MS);
            now = at;
            b.started(now, true);
            now += MS;
        }
        assert_eq!(delays, [100, 200, 400, 800, 1600, 2000, 2000]);
        assert_eq!(b.restarts(), 7);
        // A run of 6 s is stable: the next delay is the initial one again.
        assert_eq!(
            b.exited(now + 6000 * MS),
            RestartDecision::RestartAt(now + 6100 * MS)
        );
    }

    #[test]
    fn gives_up_after_the_restart_budget() {
        let policy = RestartPolicy {
            max_restarts: 2,
            ..RestartPolicy::default()
        };
        let mut b = RestartBackoff::new(policy);
        b.started(0, false);
        for _ in 0..2 {
            let RestartDecision::RestartAt(at) = b.exited(MS) else {
                panic!("gave up too early");
            };
            b.started(at, true);
        }
        assert_eq!(b.exited(10_000 * MS), RestartDecision::GiveUp);
    }

    #[test]
    fn invalid_policies_name_their_key() {
        let bad = RestartPolicy {
            multiplier: 0.5,
            ..RestartPolicy::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "multiplier");
        let bad = RestartPolicy {
            initial_backoff_ms: f64::NAN,
            ..RestartPolicy::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "initial_backoff_ms");
        let bad = RestartPolicy {
            max_backoff_ms: 10.0,
            ..RestartPolicy::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "max_backoff_ms");
        assert!(RestartPolicy::default().validate().is_ok());
    }
}
