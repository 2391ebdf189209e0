//! The logic of a velocity-controlled driver (the arm's and the base's), free of I/O: it takes
//! in the commands that arrive, measures their ages and the gaps between them, waits for the
//! hardware's first state, and steps a [`CommandLimiter`] whose output goes to the hardware,
//! checking that output with a [`LimitMonitor`].

use crate::command_limiter::{
    AxisLimits, CommandLimiter, CommandLimiterConfig, LimitMonitor, LimiterCounters, LimiterInput,
    LimiterMode,
};
use crate::error::ModelError;

/// Settings of a [`VelocityDriver`].
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VelocityDriverConfig {
    /// The command limiter.
    pub limiter: CommandLimiterConfig,
}

/// Counters and state of a [`VelocityDriver`], for its status message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverCounters {
    /// The limiter's counters.
    pub limiter: LimiterCounters,
    /// Commands received.
    pub commands_received: u64,
    /// Outputs that broke a limit (the limiter guarantees none; this is the self-check).
    pub output_violations: u64,
    /// Longest gap between the stamps of consecutive commands, ns.
    pub max_command_gap_ns: u64,
    /// Mode of the last step.
    pub mode: LimiterMode,
    /// Whether the hardware has reported its state (the driver commands it only then).
    pub hardware_ready: bool,
}

/// A velocity driver's logic. See the module documentation.
#[derive(Debug, Clone)]
pub struct VelocityDriver {
    limiter: CommandLimiter,
    monitor: LimitMonitor,
    last_stamp_ns: Option<u64>,
    max_gap_ns: u64,
    commands_received: u64,
    hardware_ready: bool,
    mode: LimiterMode,
}

impl VelocityDriver {
    /// A driver for axes with `limits`, stepped every `dt` seconds.
    pub fn new(
        limits: Vec<AxisLimits>,
        dt: f64,
        config: VelocityDriverConfig,
    ) -> Result<Self, ModelError> {
        let limiter = CommandLimiter::new(limits, dt, config.limiter)?;
        let monitor = LimitMonitor::new(limiter.limits(), dt, 1e-6);
        Ok(Self {
            limiter,
            monitor,
            last_stamp_ns: None,
            max_gap_ns: 0,
            commands_received: 0,
            hardware_ready: false,
            mode: LimiterMode::Stale,
        })
    }

    /// Number of axes.
    pub fn axes(&self) -> usize {
        self.limiter.axes()
    }

    /// The period of the command stream it expects, s.
    pub fn command_period(&self) -> f64 {
        self.limiter.config().command_period
    }

    /// Spreads the next stop over `seconds` (see [`CommandLimiter::set_stop_time`]).
    pub fn set_stop_time(&mut self, seconds: f64) {
        self.limiter.set_stop_time(seconds);
    }

    /// Takes in one command stamped `stamp_ns` (call it for every command that arrived, oldest
    /// first: each is checked against the limits and counted; the newest is the target).
    pub fn receive(&mut self, stamp_ns: u64, velocity: &[f64]) {
        self.commands_received += 1;
        if let Some(last) = self.last_stamp_ns {
            self.max_gap_ns = self.max_gap_ns.max(stamp_ns.saturating_sub(last));
        }
        self.last_stamp_ns = Some(self.last_stamp_ns.map_or(stamp_ns, |l| l.max(stamp_ns)));
        self.limiter.accept(velocity);
    }

    /// One driver cycle at monotonic time `now_ns`: `measured` is the hardware's current
    /// velocity if it reported one. Returns the velocity to send, or `None` while the hardware
    /// has not reported yet (the driver then starts from the measured velocity, so a restarted
    /// driver takes over a moving robot without a step).
    pub fn step(
        &mut self,
        now_ns: u64,
        safe_stop: bool,
        measured: Option<&[f64]>,
    ) -> Option<&[f64]> {
        if !self.hardware_ready {
            let measured = measured?;
            self.limiter.reset(measured);
            self.monitor.reset(self.limiter.velocity());
            self.hardware_ready = true;
        }
        let command_age = self
            .last_stamp_ns
            .map(|stamp| now_ns.saturating_sub(stamp) as f64 * 1e-9);
        let out = self.limiter.step(&LimiterInput {
            command: None,
            command_age,
            safe_stop,
        });
        self.mode = out.mode;
        self.monitor.check(out.velocity);
        Some(self.limiter.velocity())
    }

    /// Counters and state.
    pub fn counters(&self) -> DriverCounters {
        DriverCounters {
            limiter: self.limiter.counters(),
            commands_received: self.commands_received,
            output_violations: self.monitor.violations(),
            max_command_gap_ns: self.max_gap_ns,
            mode: self.mode,
            hardware_ready: self.hardware_ready,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn panda_like() -> VelocityDriver {
        let limits = vec![
            AxisLimits {
                velocity: 2.0,
                acceleration: 10.0,
                jerk: 5000.0,
            };
            2
        ];
        VelocityDriver::new(limits, 0.001, VelocityDriverConfig::default()).unwrap()
    }

    #[test]
    fn waits_for_the_hardware_then_starts_from_its_velocity() {
        let mut d = panda_like();
        d.receive(0, &[1.0, 1.0]);
        assert_eq!(d.step(MS, false, None), None);
        assert!(!d.counters().hardware_ready);
        // A restarted driver finds the robot moving at 0.5 rad/s: no step down to zero.
        let out = d.step(2 * MS, false, Some(&[0.5, -0.5])).unwrap().to_vec();
        assert!(
            (out[0] - 0.5).abs() < 0.01 && (out[1] + 0.5).abs() < 0.01,
            "{out:?}"
        );
        assert_eq!(d.counters().output_violations, 0);
    }

    #[test]
    fn every_command_is_checked_even_when_several_arrive_in_one_cycle() {
        let mut d = panda_like();
        d.step(0, false, Some(&[0.0, 0.0]));
        d.receive(MS, &[3.0, 0.0]);
        d.receive(2 * MS, &[0.0, f64::NAN]);
        d.receive(3 * MS, &[1.0, 0.0]);
        d.step(3 * MS, false, None);
        let c = d.counters();
        assert_eq!(c.commands_received, 3);
        assert_eq!(
            (
                c.limiter.limit_violations,
                c.limiter.clamped_commands,
                c.limiter.ignored_commands
            ),
            (2, 1, 1)
        );
        for k in 0..500 {
            d.receive((4 + k) * MS, &[1.0, 0.0]);
            d.step((4 + k) * MS, false, None);
        }
        assert_eq!(
            d.step(504 * MS, false, None).unwrap(),
            &[1.0, 0.0],
            "the newest is the target"
        );
    }

    #[test]
    fn follows_fresh_commands_measures_gaps_and_stops_when_they_go_stale() {
        let mut d = panda_like();
        d.step(0, false, Some(&[0.0, 0.0]));
        // Commands every 5 ms, one of them 12 ms late.
        let mut stamp = 0;
        let mut now = 0;
        for k in 0..200 {
            stamp += if k == 50 { 12 * MS } else { 5 * MS };
            d.receive(stamp, &[1.0, -1.0]);
            for _ in 0..5 {
                now = now.max(stamp) + MS;
                d.step(now, false, None);
            }
        }
        let c = d.counters();
        assert_eq!(c.mode, LimiterMode::Tracking);
        assert_eq!(c.commands_received, 200);
        assert_eq!(c.max_command_gap_ns, 12 * MS);
        assert_eq!(d.step(now, false, None).unwrap(), &[1.0, -1.0]);
        // No more commands: stale after 3 command periods (15 ms), then down to zero.
        let mut stale_at = None;
        for k in 1..1000 {
            let out = d.step(now + k * MS, false, None).unwrap().to_vec();
            if d.counters().mode == LimiterMode::Stale && stale_at.is_none() {
                stale_at = Some(now + k * MS - stamp);
            }
            if k > 500 {
                assert_eq!(out, vec![0.0, 0.0]);
            }
        }
        let stale_at = stale_at.unwrap();
        // Exactly 15 ms is the boundary (up to rounding); 1 ms later it is stale for sure.
        assert!((15 * MS..=16 * MS).contains(&stale_at), "{stale_at}");
        assert_eq!(d.counters().output_violations, 0);
        assert_eq!(d.counters().limiter.limit_violations, 0);
    }
}
