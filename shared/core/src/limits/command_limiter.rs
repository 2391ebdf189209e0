//! The drivers' last line of defence: a velocity command shaper that keeps the velocity, the
//! acceleration and the jerk of its output within the robot's limits whatever command reaches
//! it, and ramps to zero (within the same limits) when the command goes stale or safe-stop is
//! raised.
//!
//! [`CommandLimiter::step`] is a pure step function run once per driver period `dt`. Each axis
//! holds a velocity `v` and an acceleration `a` (the output's finite differences: `a_k =
//! (v_k − v_{k−1}) / dt`, jerk `(a_k − a_{k−1}) / dt`). Per step the acceleration may change by
//! at most `J·dt` and stay within `±A`; among the allowed accelerations the limiter picks the
//! one that approaches the target fastest while it can still brake onto it at the jerk limit
//! without overshooting (a discrete jerk-limited "bang-bang" law). Because the target is clamped
//! to `±V` and the brake-ahead margin holds at every step, the velocity never passes `±V`
//! either. An axis without a finite jerk limit (the base joints) is only acceleration-limited.
//!
//! **Spread stops.** A stop (stale command or safe-stop) can be spread over a given time
//! ([`CommandLimiter::set_stop_time`]): the target then falls linearly from the velocity at the
//! stop's onset to zero over that time, instead of being zero at once, and the shaper follows
//! it within the same limits. The arm driver uses it to stop together with a base that brakes
//! more slowly, so the tool keeps its place in the world while both stop (a cube between the
//! fingers is not swept away). 0 (the default) stops as fast as the limits allow.
//!
//! Violations: a command with the wrong length, a non-finite value or a velocity beyond the
//! limit counts as one limit violation. Non-finite and wrong-length commands are ignored (the
//! previous target stays); an over-limit velocity is clamped to the limit.

use std::path::Path;

use crate::chain::JointLimits;
use crate::error::ModelError;

/// Velocity, acceleration and jerk limits of one commanded axis (magnitudes, SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisLimits {
    /// Largest |velocity|.
    pub velocity: f64,
    /// Largest |acceleration|.
    pub acceleration: f64,
    /// Largest |jerk|; `f64::INFINITY` for an axis that is only acceleration-limited.
    pub jerk: f64,
}

impl From<&JointLimits> for AxisLimits {
    fn from(limits: &JointLimits) -> Self {
        Self {
            velocity: limits.velocity,
            acceleration: limits.acceleration,
            jerk: limits.jerk,
        }
    }
}

/// Settings of a [`CommandLimiter`]; serde-deserializable for the drivers' config.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CommandLimiterConfig {
    /// Expected period of the incoming command stream, s (the control rate's period: 5 ms at
    /// 200 Hz).
    pub command_period: f64,
    /// A command older than this many command periods is stale: the output ramps to zero.
    /// Chosen 3, the watchdog's default staleness, so a driver alone is as strict as the
    /// watchdog.
    pub stale_periods: u32,
    /// Relative tolerance on the velocity limit when counting a command as a violation
    /// (commands at the limit up to rounding are not violations). 1e-9.
    pub violation_tolerance: f64,
}

impl Default for CommandLimiterConfig {
    fn default() -> Self {
        Self {
            command_period: 0.005,
            stale_periods: 3,
            violation_tolerance: 1e-9,
        }
    }
}

impl CommandLimiterConfig {
    /// Age beyond which a command is stale, s.
    pub fn stale_after(&self) -> f64 {
        self.command_period * f64::from(self.stale_periods)
    }
}

/// What the limiter is doing in a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimiterMode {
    /// Following a fresh command.
    Tracking,
    /// No command ever came, or the last one is stale: ramping to (or holding) zero.
    Stale,
    /// Safe-stop is raised: ramping to (or holding) zero.
    SafeStop,
}

/// Input of one limiter step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimiterInput<'a> {
    /// A command that arrived since the last step (the newest one), if any.
    pub command: Option<&'a [f64]>,
    /// Age of the newest command ever received, s, at this step; `None` if none ever came.
    pub command_age: Option<f64>,
    /// Whether safe-stop is raised.
    pub safe_stop: bool,
}

/// Output of one limiter step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimiterOutput<'a> {
    /// Velocity to send to the hardware, one per axis.
    pub velocity: &'a [f64],
    /// What the limiter did.
    pub mode: LimiterMode,
    /// Whether this step's command was beyond a limit (counted in
    /// [`LimiterCounters::limit_violations`]).
    pub violation: bool,
}

/// Counters of a [`CommandLimiter`] since it was created.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LimiterCounters {
    /// Commands that arrived beyond a limit (velocity beyond the limit, non-finite or wrong
    /// length).
    pub limit_violations: u64,
    /// Commands whose velocity was clamped to the limit (a subset of the violations).
    pub clamped_commands: u64,
    /// Commands ignored because they had a non-finite value or the wrong length.
    pub ignored_commands: u64,
    /// Steps run in [`LimiterMode::Stale`].
    pub stale_steps: u64,
    /// Steps run in [`LimiterMode::SafeStop`].
    pub safe_stop_steps: u64,
}

/// State of one axis.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct AxisState {
    velocity: f64,
    acceleration: f64,
}

/// Jerk- and acceleration-limited velocity shaper with stale-command and safe-stop ramps. See
/// the module documentation.
#[derive(Debug, Clone)]
pub struct CommandLimiter {
    limits: Vec<AxisLimits>,
    config: CommandLimiterConfig,
    dt: f64,
    state: Vec<AxisState>,
    target: Vec<f64>,
    output: Vec<f64>,
    counters: LimiterCounters,
    /// Time to spread the next stop over, s (0: as fast as the limits allow).
    stop_time: f64,
    /// The stop in progress: its duration and the time elapsed, s.
    stop: Option<(f64, f64)>,
    /// The output velocities at the onset of the stop in progress.
    stop_from: Vec<f64>,
}

impl CommandLimiter {
    /// A limiter for axes with `limits`, stepped every `dt` seconds, at rest. Errors when `dt`
    /// is not positive and finite, or a velocity or acceleration limit is not positive and
    /// finite, or a jerk limit is not positive (infinite is allowed).
    pub fn new(
        limits: Vec<AxisLimits>,
        dt: f64,
        config: CommandLimiterConfig,
    ) -> Result<Self, ModelError> {
        let invalid = |key: String, detail: String| {
            ModelError::invalid(Path::new("<command limiter>"), key, detail)
        };
        if !(dt.is_finite() && dt > 0.0) {
            return Err(invalid("dt".into(), format!("must be positive, got {dt}")));
        }
        if !(config.command_period.is_finite() && config.command_period > 0.0) {
            return Err(invalid(
                "command_period".into(),
                format!("must be positive, got {}", config.command_period),
            ));
        }
        for (i, l) in limits.iter().enumerate() {
            if !(l.velocity.is_finite() && l.velocity > 0.0) {
                return Err(invalid(format!("axis {i} velocity"), positive(l.velocity)));
            }
            if !(l.acceleration.is_finite() && l.acceleration > 0.0) {
                return Err(invalid(
                    format!("axis {i} acceleration"),
                    positive(l.acceleration),
                ));
            }
            if l.jerk.is_nan() || l.jerk <= 0.0 {
                return Err(invalid(format!("axis {i} jerk"), positive(l.jerk)));
            }
        }
        let n = limits.len();
        Ok(Self {
            limits,
            config,
            dt,
            state: vec![AxisState::default(); n],
            target: vec![0.0; n],
            output: vec![0.0; n],
            counters: LimiterCounters::default(),
            stop_time: 0.0,
            stop: None,
            stop_from: vec![0.0; n],
        })
    }

    /// Spreads a stop that starts from now on over `seconds` (see the module documentation);
    /// a stop in progress keeps its time. Non-finite or negative values count as 0.
    pub fn set_stop_time(&mut self, seconds: f64) {
        self.stop_time = if seconds.is_finite() {
            seconds.max(0.0)
        } else {
            0.0
        };
    }

    /// Number of axes.
    pub fn axes(&self) -> usize {
        self.limits.len()
    }

    /// The axis limits.
    pub fn limits(&self) -> &[AxisLimits] {
        &self.limits
    }

    /// The step period, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The settings.
    pub fn config(&self) -> &CommandLimiterConfig {
        &self.config
    }

    /// Counters since creation.
    pub fn counters(&self) -> LimiterCounters {
        self.counters
    }

    /// The current output velocity, one per axis.
    pub fn velocity(&self) -> &[f64] {
        &self.output
    }

    /// Starts from measured velocities (e.g. after a driver restart while the hardware still
    /// moves), with zero acceleration and zero target. Non-finite values count as zero and
    /// values beyond the limit are clamped; a wrong length resets to rest.
    pub fn reset(&mut self, velocity: &[f64]) {
        for (i, (state, limits)) in self.state.iter_mut().zip(&self.limits).enumerate() {
            let v = velocity.get(i).copied().filter(|v| v.is_finite());
            let v = if velocity.len() == self.output.len() {
                v.unwrap_or(0.0)
            } else {
                0.0
            };
            state.velocity = v.clamp(-limits.velocity, limits.velocity);
            state.acceleration = 0.0;
            self.output[i] = state.velocity;
        }
        self.target.iter_mut().for_each(|t| *t = 0.0);
        self.stop = None;
    }

    /// One step: takes in the new command (if any), decides the mode and moves every axis one
    /// period towards its target within the limits.
    pub fn step(&mut self, input: &LimiterInput) -> LimiterOutput<'_> {
        let violation = input.command.is_some_and(|c| self.accept(c));
        let fresh = input
            .command_age
            .is_some_and(|age| age.is_finite() && age <= self.config.stale_after());
        let mode = if input.safe_stop {
            self.counters.safe_stop_steps += 1;
            LimiterMode::SafeStop
        } else if fresh {
            LimiterMode::Tracking
        } else {
            self.counters.stale_steps += 1;
            LimiterMode::Stale
        };
        // Share of the onset velocity the stop's target keeps this step (1 while tracking).
        let keep = if mode == LimiterMode::Tracking {
            self.stop = None;
            1.0
        } else {
            let (duration, elapsed) = match self.stop {
                Some(stop) => stop,
                None => {
                    self.stop_from.copy_from_slice(&self.output);
                    (self.stop_time, 0.0)
                }
            };
            self.stop = Some((duration, elapsed + self.dt));
            if duration > 0.0 {
                (1.0 - (elapsed + self.dt) / duration).max(0.0)
            } else {
                0.0
            }
        };
        for i in 0..self.limits.len() {
            let target = if mode == LimiterMode::Tracking {
                self.target[i]
            } else {
                self.stop_from[i] * keep
            };
            self.state[i] = advance(self.state[i], target, &self.limits[i], self.dt);
            self.output[i] = self.state[i].velocity;
        }
        LimiterOutput {
            velocity: &self.output,
            mode,
            violation,
        }
    }

    /// Takes in a new command as the target (the same as passing it in
    /// [`LimiterInput::command`]); returns whether it was a violation. Call it for every
    /// command that arrives, so each one is checked and counted even when several arrive
    /// between two steps.
    pub fn accept(&mut self, command: &[f64]) -> bool {
        if command.len() != self.limits.len() || command.iter().any(|v| !v.is_finite()) {
            self.counters.limit_violations += 1;
            self.counters.ignored_commands += 1;
            return true;
        }
        let mut clamped = false;
        for ((target, &value), limits) in self.target.iter_mut().zip(command).zip(&self.limits) {
            let bound = limits.velocity * (1.0 + self.config.violation_tolerance);
            if value.abs() > bound {
                clamped = true;
            }
            *target = value.clamp(-limits.velocity, limits.velocity);
        }
        if clamped {
            self.counters.limit_violations += 1;
            self.counters.clamped_commands += 1;
        }
        clamped
    }
}

/// Checks a stream of output velocities (one sample per `dt`) against the limits: velocity,
/// acceleration and jerk by finite differences, with a relative tolerance for rounding. The
/// drivers run it on their own output as a self-check; it starts from rest.
#[derive(Debug, Clone)]
pub struct LimitMonitor {
    limits: Vec<AxisLimits>,
    dt: f64,
    tolerance: f64,
    last: Vec<AxisState>,
    worst: [f64; 3],
    violations: u64,
}

impl LimitMonitor {
    /// A monitor for `limits` at period `dt`, accepting up to `1 + tolerance` times a limit.
    pub fn new(limits: &[AxisLimits], dt: f64, tolerance: f64) -> Self {
        Self {
            limits: limits.to_vec(),
            dt,
            tolerance,
            last: vec![AxisState::default(); limits.len()],
            worst: [0.0; 3],
            violations: 0,
        }
    }

    /// Restarts the finite differences from `velocity` at zero acceleration.
    pub fn reset(&mut self, velocity: &[f64]) {
        for (state, &v) in self.last.iter_mut().zip(velocity) {
            *state = AxisState {
                velocity: v,
                acceleration: 0.0,
            };
        }
    }

    /// Takes the next output sample; returns whether it broke a limit (or is not finite or has
    /// the wrong length), counting it.
    pub fn check(&mut self, velocity: &[f64]) -> bool {
        let mut broken = velocity.len() != self.limits.len();
        for ((&v, l), last) in velocity.iter().zip(&self.limits).zip(&mut self.last) {
            let a = (v - last.velocity) / self.dt;
            let j = (a - last.acceleration) / self.dt;
            let ratios = [
                v.abs() / l.velocity,
                a.abs() / l.acceleration,
                if l.jerk.is_finite() {
                    j.abs() / l.jerk
                } else {
                    0.0
                },
            ];
            for (worst, r) in self.worst.iter_mut().zip(ratios) {
                // A NaN ratio (non-finite output) is a violation too.
                if r.is_nan() || r > 1.0 + self.tolerance {
                    broken = true;
                }
                *worst = worst.max(r);
            }
            *last = AxisState {
                velocity: v,
                acceleration: a,
            };
        }
        if broken {
            self.violations += 1;
        }
        broken
    }

    /// Samples that broke a limit so far.
    pub fn violations(&self) -> u64 {
        self.violations
    }

    /// Largest ratio of |velocity|, |acceleration| and |jerk| to its limit seen so far.
    pub fn worst_ratios(&self) -> [f64; 3] {
        self.worst
    }
}

/// Message for a limit that must be positive.
fn positive(value: f64) -> String {
    format!("must be positive, got {value}")
}

/// Largest acceleration `a ≥ 0` such that after applying it for `dt` the axis can still brake
/// onto a target `error ≥ 0` ahead without overshoot: `a·dt + a·(a + j·dt)/(2j) ≤ error`, where
/// the second term bounds the velocity change still to come while the acceleration is braked to
/// zero at jerk `j` in steps of `dt`. With an infinite jerk limit the acceleration can drop to
/// zero at once, so the bound is `error / dt`.
fn approach_acceleration(error: f64, j: f64, dt: f64) -> f64 {
    if !j.is_finite() {
        return error / dt;
    }
    // a² + 3·j·dt·a − 2·j·error ≤ 0.
    let b = 3.0 * j * dt;
    0.5 * (-b + (b * b + 8.0 * j * error).sqrt())
}

/// Moves one axis one step towards `target` (assumed within `±limits.velocity`).
fn advance(state: AxisState, target: f64, limits: &AxisLimits, dt: f64) -> AxisState {
    let AxisState {
        velocity: v,
        acceleration: a,
    } = state;
    let max_change = limits.jerk * dt;
    // Allowed accelerations this step.
    let lower = (a - max_change).max(-limits.acceleration);
    let upper = (a + max_change).min(limits.acceleration);
    let error = target - v;
    // Land exactly on the target when one step can do it and the next step can bring the
    // acceleration back to zero.
    let exact = error / dt;
    if exact >= lower && exact <= upper && exact.abs() <= max_change {
        return AxisState {
            velocity: target,
            acceleration: exact,
        };
    }
    let wanted = if error >= 0.0 {
        approach_acceleration(error, limits.jerk, dt)
    } else {
        -approach_acceleration(-error, limits.jerk, dt)
    };
    let acceleration = wanted.clamp(lower, upper);
    let velocity = (v + acceleration * dt).clamp(-limits.velocity, limits.velocity);
    AxisState {
        velocity,
        acceleration: (velocity - v) / dt,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Panda joint 1 limits.
    const PANDA: AxisLimits = AxisLimits {
        velocity: 2.175,
        acceleration: 15.0,
        jerk: 7500.0,
    };
    /// LD-60 forward axis: acceleration-limited only.
    const BASE: AxisLimits = AxisLimits {
        velocity: 1.2,
        acceleration: 0.8,
        jerk: f64::INFINITY,
    };
    const DT: f64 = 0.001;

    fn limiter(limits: &[AxisLimits], dt: f64) -> CommandLimiter {
        CommandLimiter::new(limits.to_vec(), dt, CommandLimiterConfig::default()).unwrap()
    }

    /// Asserts that every output sample is within the limits.
    struct LimitChecker {
        monitor: LimitMonitor,
    }

    impl LimitChecker {
        fn new(limits: &[AxisLimits], dt: f64) -> Self {
            Self {
                monitor: LimitMonitor::new(limits, dt, 1e-9),
            }
        }

        fn check(&mut self, velocity: &[f64], context: &str) {
            assert!(
                !self.monitor.check(velocity),
                "{context}: a limit was exceeded by {velocity:?}: worst ratios {:?}",
                self.monitor.worst_ratios()
            );
        }
    }

    fn fresh(command: &[f64]) -> LimiterInput<'_> {
        LimiterInput {
            command: Some(command),
            command_age: Some(0.0),
            safe_stop: false,
        }
    }

    #[test]
    fn a_step_command_is_reached_exactly_within_every_limit() {
        let mut l = limiter(&[PANDA], DT);
        let mut checker = LimitChecker::new(&[PANDA], DT);
        let mut reached = None;
        for k in 0..2000 {
            let out = l.step(&fresh(&[1.5]));
            assert_eq!(out.mode, LimiterMode::Tracking);
            assert!(!out.violation);
            let v = out.velocity[0];
            checker.check(&[v], "step");
            assert!(v <= 1.5, "overshoot {v}");
            if v == 1.5 && reached.is_none() {
                reached = Some(k);
            }
        }
        // Time-optimal under A = 15, J = 7500 is about 1.5/15 + 15/7500 = 0.102 s.
        let reached = reached.expect("target reached exactly");
        assert!(
            (100..=110).contains(&reached),
            "reached after {reached} steps"
        );
        // The profile uses the limits (it is not needlessly slow).
        let worst = checker.monitor.worst_ratios();
        assert!(worst[1] > 0.99 && worst[2] > 0.99, "{worst:?}");
    }

    #[test]
    fn reversals_and_random_commands_never_exceed_a_limit() {
        let limits = [
            PANDA,
            AxisLimits {
                velocity: 2.61,
                acceleration: 20.0,
                jerk: 10000.0,
            },
            BASE,
        ];
        for dt in [0.001, 0.005, 0.02] {
            let mut l = limiter(&limits, dt);
            let mut checker = LimitChecker::new(&limits, dt);
            let mut rng = ChaCha8Rng::seed_from_u64(42);
            let mut command = vec![0.0; 3];
            for k in 0..20_000 {
                let event = rng.random_range(0..100);
                let mut input = LimiterInput {
                    command: None,
                    command_age: Some(0.0),
                    safe_stop: false,
                };
                let special;
                match event {
                    // New random command, often far beyond the limits.
                    0..=9 => {
                        for c in command.iter_mut() {
                            *c = rng.random_range(-5.0..5.0);
                        }
                        input.command = Some(&command);
                    }
                    // Full reversal at the limit.
                    10..=12 => {
                        for (c, l) in command.iter_mut().zip(&limits) {
                            *c = if *c > 0.0 { -l.velocity } else { l.velocity };
                        }
                        input.command = Some(&command);
                    }
                    13 => {
                        special = [f64::NAN, 1.0, f64::INFINITY];
                        input.command = Some(&special);
                    }
                    14 => {
                        special = [1.0, 1.0, 1.0];
                        input.command = Some(&special[..2]);
                    }
                    15..=19 => input.command_age = Some(1.0),
                    20..=22 => input.safe_stop = true,
                    23 => input.command_age = None,
                    24 => input.command_age = Some(f64::NAN),
                    _ => {}
                }
                let out = l.step(&input);
                checker.check(out.velocity, &format!("dt {dt} step {k}"));
            }
            let counters = l.counters();
            assert!(counters.ignored_commands > 0 && counters.clamped_commands > 0);
            assert_eq!(
                counters.limit_violations,
                counters.ignored_commands + counters.clamped_commands
            );
        }
    }

    #[test]
    fn non_finite_and_wrong_length_commands_are_counted_and_ignored() {
        let mut l = limiter(&[PANDA, PANDA], DT);
        for _ in 0..500 {
            l.step(&fresh(&[0.5, -0.5]));
        }
        assert_eq!(l.velocity(), &[0.5, -0.5]);
        let out = l.step(&fresh(&[f64::NAN, 0.0]));
        assert!(out.violation);
        assert_eq!(out.velocity, &[0.5, -0.5], "previous target kept");
        let out = l.step(&fresh(&[0.0]));
        assert!(out.violation);
        let out = l.step(&fresh(&[3.0, 0.0]));
        assert!(out.violation, "beyond the velocity limit");
        let c = l.counters();
        assert_eq!(
            (c.limit_violations, c.ignored_commands, c.clamped_commands),
            (3, 2, 1)
        );
        // The clamped command is followed up to the limit, not beyond.
        for _ in 0..1000 {
            l.step(&fresh(&[3.0, 0.0]));
        }
        assert_eq!(l.velocity()[0], PANDA.velocity);
        // A command exactly at the limit is not a violation.
        assert!(!l.step(&fresh(&[PANDA.velocity, 0.0])).violation);
    }

    /// Runs until the output is zero; returns the number of steps taken.
    fn steps_to_zero(
        l: &mut CommandLimiter,
        input: &LimiterInput,
        checker: &mut LimitChecker,
    ) -> usize {
        for k in 0..100_000 {
            let out = l.step(input);
            checker.check(out.velocity, "ramp");
            if out.velocity.iter().all(|&v| v == 0.0) {
                return k + 1;
            }
        }
        panic!("never reached zero");
    }

    #[test]
    fn a_stale_command_ramps_smoothly_to_zero_and_stays_there() {
        let limits = [PANDA, BASE];
        let mut l = limiter(&limits, DT);
        let mut checker = LimitChecker::new(&limits, DT);
        for _ in 0..3000 {
            let out = l.step(&fresh(&[2.0, 1.0]));
            checker.check(out.velocity, "spin up");
        }
        // Still fresh at exactly the stale age, stale just after.
        let stale_after = l.config().stale_after();
        let at_limit = LimiterInput {
            command: None,
            command_age: Some(stale_after),
            safe_stop: false,
        };
        assert_eq!(l.step(&at_limit).mode, LimiterMode::Tracking);
        checker.check(l.velocity(), "fresh");
        let stale = LimiterInput {
            command: None,
            command_age: Some(stale_after + 1e-6),
            safe_stop: false,
        };
        assert_eq!(l.step(&stale).mode, LimiterMode::Stale);
        checker.check(l.velocity(), "stale");
        let steps = steps_to_zero(&mut l, &stale, &mut checker);
        // The base axis decelerates at 0.8 m/s² from 1 m/s: 1.25 s; the arm is faster.
        assert!((1240..=1260).contains(&steps), "{steps} steps");
        for _ in 0..100 {
            let out = l.step(&stale);
            checker.check(out.velocity, "hold");
            assert_eq!(out.velocity, &[0.0, 0.0]);
        }
        assert!(l.counters().stale_steps > 1000);
    }

    #[test]
    fn safe_stop_overrides_a_fresh_command_and_releases_when_cleared() {
        let mut l = limiter(&[PANDA], DT);
        let mut checker = LimitChecker::new(&[PANDA], DT);
        for _ in 0..500 {
            checker.check(l.step(&fresh(&[-2.0])).velocity, "run");
        }
        let stop = LimiterInput {
            safe_stop: true,
            ..fresh(&[-2.0])
        };
        assert_eq!(l.step(&stop).mode, LimiterMode::SafeStop);
        checker.check(l.velocity(), "stop");
        let steps = steps_to_zero(&mut l, &stop, &mut checker);
        // 2 rad/s at 15 rad/s² plus the jerk ramps: about 0.135 s.
        assert!((130..=145).contains(&steps), "{steps} steps");
        assert_eq!(l.counters().safe_stop_steps as usize, steps + 1);
        for _ in 0..500 {
            checker.check(l.step(&fresh(&[-2.0])).velocity, "resume");
        }
        assert_eq!(l.velocity(), &[-2.0]);
    }

    #[test]
    fn no_command_yet_holds_zero_and_reset_starts_from_the_measured_velocity() {
        let mut l = limiter(&[PANDA, BASE], DT);
        let none = LimiterInput {
            command: None,
            command_age: None,
            safe_stop: false,
        };
        assert_eq!(l.step(&none).mode, LimiterMode::Stale);
        assert_eq!(l.velocity(), &[0.0, 0.0]);
        l.reset(&[1.0, f64::NAN]);
        assert_eq!(l.velocity(), &[1.0, 0.0]);
        l.reset(&[9.0, -9.0]);
        assert_eq!(l.velocity(), &[PANDA.velocity, -BASE.velocity]);
        let mut checker = LimitChecker::new(&[PANDA, BASE], DT);
        checker.monitor.reset(&[PANDA.velocity, -BASE.velocity]);
        steps_to_zero(&mut l, &none, &mut checker);
    }

    #[test]
    fn the_monitor_flags_steps_that_break_each_limit() {
        let mut m = LimitMonitor::new(&[PANDA], DT, 1e-9);
        // 7.5 rad/s² after one step: jerk 7500 is exactly at the limit.
        assert!(!m.check(&[0.0075 * DT]));
        // A velocity step of 0.1 rad/s in 1 ms is 100 rad/s²: beyond the acceleration limit.
        assert!(m.check(&[0.1]));
        assert!(m.check(&[f64::NAN]));
        assert!(m.check(&[]));
        assert_eq!(m.violations(), 3);
        let mut m = LimitMonitor::new(&[BASE], 0.02, 1e-9);
        assert!(
            !m.check(&[0.016]),
            "0.8 m/s² at once: no jerk limit on the base"
        );
        m.reset(&[1.2]);
        assert!(m.check(&[1.3]), "beyond the velocity limit");
    }

    #[test]
    fn bad_limits_and_periods_are_errors_naming_the_key() {
        let config = CommandLimiterConfig::default();
        let err = CommandLimiter::new(vec![PANDA], 0.0, config).unwrap_err();
        assert!(err.to_string().contains("dt"), "{err}");
        let bad = AxisLimits {
            acceleration: f64::INFINITY,
            ..PANDA
        };
        let err = CommandLimiter::new(vec![PANDA, bad], DT, config).unwrap_err();
        assert!(err.to_string().contains("axis 1 acceleration"), "{err}");
        let bad = AxisLimits {
            jerk: f64::NAN,
            ..PANDA
        };
        assert!(CommandLimiter::new(vec![bad], DT, config).is_err());
    }
}
