//! Hot swap of a task controller (docs/architecture.md, "Supervisor, watchdog, hot swap"): the supervisor
//! starts the new controller process beside the old one, waits for the new one's heartbeat and
//! its first command sample, flips the active-controller id (which every consumer filters on),
//! then stops the old one. This module is the pure part: the sequence as a step function on
//! monotonic nanosecond times ([`HotSwap`]), the measurement of the gap in the command stream
//! across the flip ([`command_gap`]) and the rewriting of the controller's arguments
//! ([`swap_args`]). The supervisor does the spawning, signalling and publishing.
//!
//! **The command-stream gap.** A consumer keeps the newest command of each controller id and
//! uses the one of the active id. Before the flip that is the old controller's newest sample;
//! from the flip on it is the new controller's, which has been publishing (and so holds a
//! sample at most one period old) since before the flip. So the stream the consumers see is:
//! the old samples stamped before the flip, the flip itself (the new controller's held sample
//! becomes usable), then the new samples stamped after it. The gap the swap makes is the
//! longer of the two intervals that meet at the flip: from the old controller's last command
//! to the flip, and from the flip to the new controller's first command after it. "No control
//! cycle without a command" means it stays under one control period. Intervals farther from
//! the flip are each controller's own cycle jitter, not the swap's doing, and are left out.

use serde::Deserialize;

/// Tunables of a hot swap. Read from the `[hot_swap]` table of a stack config.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HotSwapConfig {
    /// Longest wait from starting the new process to its first `Running` heartbeat, ms.
    /// Chosen: 10 s, so that a debug build starting on a loaded machine still makes it; the
    /// old controller goes on controlling meanwhile, so a long wait costs nothing.
    pub heartbeat_timeout_ms: f64,
    /// Longest wait for the new controller's first command sample once its heartbeat came, ms,
    /// when the request does not say. A fixed-variant controller publishes only while the
    /// current task is of its kind, so this is also how long a swap may wait for such a task.
    pub command_timeout_ms: f64,
    /// Half-width of the window around the flip in which the command gap is measured, in
    /// control periods (default 20: 100 ms at 200 Hz on each side).
    pub gap_window_periods: u32,
    /// Consecutive commands the new controller must have sent on time (each within one and a
    /// half periods of the one before) before it takes over (default 20: 100 ms at 200 Hz).
    /// A process that has just started is often slow for its first cycles (page faults, cold
    /// caches); handing it control then would put its late cycles into the command stream.
    pub steady_commands: u32,
}

impl Default for HotSwapConfig {
    fn default() -> Self {
        Self {
            heartbeat_timeout_ms: 10_000.0,
            command_timeout_ms: 10_000.0,
            gap_window_periods: 20,
            steady_commands: 20,
        }
    }
}

impl HotSwapConfig {
    /// Checks that every value is finite and in range; returns the offending key otherwise.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (key, value) in [
            ("heartbeat_timeout_ms", self.heartbeat_timeout_ms),
            ("command_timeout_ms", self.command_timeout_ms),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err((key, format!("must be a finite number > 0, got {value}")));
            }
        }
        if self.gap_window_periods == 0 {
            return Err(("gap_window_periods", "must be at least 1".to_string()));
        }
        Ok(())
    }
}

/// Why a swap failed. The old controller stays active in every case.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwapFailure {
    /// The new process sent no `Running` heartbeat in time.
    NoHeartbeat,
    /// The new controller sent no command in time.
    NoCommand,
    /// The new process exited before the flip.
    NewExited,
}

/// Where a swap stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwapStage {
    /// Waiting for the new process's first `Running` heartbeat.
    WaitHeartbeat,
    /// Waiting for the new controller's first command sample.
    WaitCommand,
    /// Flipped at `flip_ns`; measuring the command stream until the window closes.
    Measuring {
        /// Time of the flip, ns.
        flip_ns: u64,
    },
    /// Finished: the new controller is active and the old one stopped.
    Done,
    /// Given up: the new process is stopped, the old one stays active.
    Failed(SwapFailure),
}

/// What the swap sees each supervisor cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SwapInput {
    /// Time of the cycle, ns.
    pub now_ns: u64,
    /// Whether a `Running` heartbeat of the new process has been seen.
    pub heartbeat_seen: bool,
    /// Whether a command sample of the new controller id has been seen.
    pub command_seen: bool,
    /// Whether the new process has exited.
    pub new_exited: bool,
}

/// What the supervisor must do after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwapAction {
    /// Nothing this cycle.
    Wait,
    /// Publish the new active-controller id now (stamped `now_ns`), hand the new process to
    /// the process table and stop the old one.
    Flip,
    /// The measuring window is over: compute the gap and report success.
    Finish,
    /// Stop the new process and report the failure.
    Abort(SwapFailure),
}

/// The swap sequence of one request as a step function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HotSwap {
    config: HotSwapConfig,
    command_timeout_ns: u64,
    window_ns: u64,
    started_ns: u64,
    heartbeat_ns: Option<u64>,
    command_ns: Option<u64>,
    stage: SwapStage,
}

/// Milliseconds to nanoseconds.
fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6) as u64
}

impl HotSwap {
    /// A swap whose new process was started at `started_ns`, with a control period of
    /// `period_ns` and `command_timeout_ms` (the request's, or the config's when `None`).
    pub fn new(
        config: HotSwapConfig,
        started_ns: u64,
        period_ns: u64,
        command_timeout_ms: Option<f64>,
    ) -> Self {
        Self {
            config,
            command_timeout_ns: ms_to_ns(command_timeout_ms.unwrap_or(config.command_timeout_ms)),
            window_ns: u64::from(config.gap_window_periods) * period_ns,
            started_ns,
            heartbeat_ns: None,
            command_ns: None,
            stage: SwapStage::WaitHeartbeat,
        }
    }

    /// Where the swap stands.
    pub fn stage(&self) -> SwapStage {
        self.stage
    }

    /// Half-width of the gap-measuring window, ns.
    pub fn window_ns(&self) -> u64 {
        self.window_ns
    }

    /// Time from the start to the first `Running` heartbeat, ns (once seen).
    pub fn heartbeat_wait_ns(&self) -> Option<u64> {
        self.heartbeat_ns.map(|t| t - self.started_ns)
    }

    /// Time from the start to the first command sample, ns (once seen).
    pub fn command_wait_ns(&self) -> Option<u64> {
        self.command_ns.map(|t| t - self.started_ns)
    }

    /// One supervisor cycle.
    pub fn step(&mut self, input: &SwapInput) -> SwapAction {
        let now = input.now_ns.max(self.started_ns);
        match self.stage {
            SwapStage::WaitHeartbeat | SwapStage::WaitCommand if input.new_exited => {
                self.fail(SwapFailure::NewExited)
            }
            SwapStage::WaitHeartbeat => {
                if input.heartbeat_seen {
                    self.heartbeat_ns = Some(now);
                    self.stage = SwapStage::WaitCommand;
                    // The command may have come in the same cycle.
                    return self.step(input);
                }
                if now - self.started_ns > ms_to_ns(self.config.heartbeat_timeout_ms) {
                    return self.fail(SwapFailure::NoHeartbeat);
                }
                SwapAction::Wait
            }
            SwapStage::WaitCommand => {
                let since = self.heartbeat_ns.unwrap_or(self.started_ns);
                if input.command_seen {
                    self.command_ns = Some(now);
                    self.stage = SwapStage::Measuring { flip_ns: now };
                    return SwapAction::Flip;
                }
                if now - since > self.command_timeout_ns {
                    return self.fail(SwapFailure::NoCommand);
                }
                SwapAction::Wait
            }
            SwapStage::Measuring { flip_ns } => {
                if now >= flip_ns + self.window_ns {
                    self.stage = SwapStage::Done;
                    SwapAction::Finish
                } else {
                    SwapAction::Wait
                }
            }
            SwapStage::Done | SwapStage::Failed(_) => SwapAction::Wait,
        }
    }

    fn fail(&mut self, failure: SwapFailure) -> SwapAction {
        self.stage = SwapStage::Failed(failure);
        SwapAction::Abort(failure)
    }
}

/// The command-stream gap across a flip (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandGap {
    /// The gap at the flip: the longer of old's last command → flip and flip → new's first
    /// command after it, ns.
    pub gap_ns: u64,
    /// From the old controller's last command before the flip to the new controller's first
    /// command after it, ns (the raw stamp interval, for comparison; at most two periods).
    pub stamp_gap_ns: u64,
    /// Old-controller commands in the window before the flip.
    pub old_samples: usize,
    /// New-controller commands in the window after the flip.
    pub new_samples: usize,
}

/// Measures the command gap across a flip at `flip_ns` from the stamps of the old and the new
/// controller's commands, over `[flip_ns - window_ns, flip_ns + window_ns]`. `None` when
/// either side has no sample in the window (the stream was not flowing: nothing to measure).
pub fn command_gap(old: &[u64], new: &[u64], flip_ns: u64, window_ns: u64) -> Option<CommandGap> {
    let from = flip_ns.saturating_sub(window_ns);
    let to = flip_ns + window_ns;
    let before: Vec<u64> = old
        .iter()
        .copied()
        .filter(|&s| s >= from && s < flip_ns)
        .collect();
    let after: Vec<u64> = new
        .iter()
        .copied()
        .filter(|&s| s >= flip_ns && s <= to)
        .collect();
    if before.is_empty() || after.is_empty() {
        return None;
    }
    let last_old = before.iter().copied().max()?;
    let first_new = after.iter().copied().min()?;
    Some(CommandGap {
        gap_ns: (flip_ns - last_old).max(first_new - flip_ns),
        stamp_gap_ns: first_new - last_old,
        old_samples: before.len(),
        new_samples: after.len(),
    })
}

/// When to flip, at or after `now_ns`, predicted from the controllers' last command stamps and
/// the common `period_ns`. Over one period there are two moments a flip makes a small gap:
/// midway from an old command to the new controller's next one (gap `phase / 2`, where `phase`
/// is how long after an old command the new one comes), and midway from that new command to
/// the new one after it (gap `(period + phase) / 2`). The first is chosen when it lies at least
/// a quarter period from the commands on either side (`phase` at least half a period): then a
/// late wake-up or a late command still leaves the gap under a period. Otherwise the second,
/// whose gap is at most three quarters of a period and which a late wake-up only shortens. Two
/// controllers in phase (both woken by the same input's arrival, say) are flipped half a period
/// after their commands, not at them. The wait is less than one period.
pub fn flip_time(now_ns: u64, last_old_ns: u64, last_new_ns: u64, period_ns: u64) -> u64 {
    let period = i128::from(period_ns.max(1));
    let phase = (i128::from(last_new_ns) - i128::from(last_old_ns)).rem_euclid(period);
    let offset = if 2 * phase >= period {
        phase / 2
    } else {
        (period + phase) / 2
    };
    let first = i128::from(last_old_ns) + offset - period;
    let now = i128::from(now_ns);
    let steps = if now > first {
        (now - first + period - 1) / period
    } else {
        0
    };
    (first + steps * period).max(now) as u64
}

/// The command gap a flip at `now_ns` would make, predicted from the controllers' last command
/// stamps and `period_ns`: the longer of the old controller's silence so far and the wait for
/// the new controller's next command. `None` while the new controller is late (silent for more
/// than a period): when its next command comes is not known.
pub fn predicted_gap(
    now_ns: u64,
    last_old_ns: u64,
    last_new_ns: u64,
    period_ns: u64,
) -> Option<u64> {
    let old_silence = now_ns.saturating_sub(last_old_ns);
    let next_new = last_new_ns + period_ns;
    (now_ns <= next_new).then(|| old_silence.max(next_new - now_ns))
}

/// Whether a flip at `now_ns` leaves a quarter period to spare below one period of gap
/// ([`predicted_gap`]): room for the jitter of the commands still to come.
pub fn flip_is_timely(now_ns: u64, last_old_ns: u64, last_new_ns: u64, period_ns: u64) -> bool {
    predicted_gap(now_ns, last_old_ns, last_new_ns, period_ns)
        .is_some_and(|gap| gap + period_ns / 4 <= period_ns)
}

/// Whether the last `count` intervals between the command `stamps` (in arrival order) are
/// each at most one and a half `period_ns`: the controller is cycling steadily.
pub fn steady(stamps: &[u64], period_ns: u64, count: usize) -> bool {
    let limit = period_ns + period_ns / 2;
    stamps.len() > count
        && stamps[stamps.len() - count - 1..]
            .windows(2)
            .all(|w| w[1].saturating_sub(w[0]) <= limit)
}

/// The arguments of the new controller process: `args` without any `--variant` and
/// `--controller-id` (spaced or `=` forms), then `--variant <variant> --controller-id <id>`.
pub fn swap_args(args: &[String], variant: &str, controller_id: u32) -> Vec<String> {
    const REPLACED: [&str; 2] = ["--variant", "--controller-id"];
    let mut out = Vec::with_capacity(args.len() + 4);
    let mut skip_value = false;
    for arg in args {
        if skip_value {
            skip_value = false;
            continue;
        }
        if REPLACED.contains(&arg.as_str()) {
            skip_value = true;
            continue;
        }
        if REPLACED
            .iter()
            .any(|flag| arg.starts_with(&format!("{flag}=")))
        {
            continue;
        }
        out.push(arg.clone());
    }
    out.extend([
        "--variant".to_string(),
        variant.to_string(),
        "--controller-id".to_string(),
        controller_id.to_string(),
    ]);
    out
}

/// The value of the last `flag` in `args` (`--flag value` or `--flag=value`), if any.
pub fn flag_value<'a>(args: &'a [String], flag: &str) -> Option<&'a str> {
    let mut value = None;
    for (i, arg) in args.iter().enumerate() {
        if arg == flag {
            value = args.get(i + 1).map(String::as_str);
        } else if let Some(v) = arg
            .strip_prefix(flag)
            .and_then(|rest| rest.strip_prefix('='))
        {
            value = Some(v);
        }
    }
    value
}

/// The controller id a process was started with: the value of `--controller-id` in `args`,
/// or `default` (the controller's own default) when absent or unreadable.
pub fn controller_id_of(args: &[String], default: u32) -> u32 {
    flag_value(args, "--controller-id")
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn input(now_ms: u64, heartbeat: bool, command: bool) -> SwapInput {
        SwapInput {
            now_ns: now_ms * MS,
            heartbeat_seen: heartbeat,
            command_seen: command,
            new_exited: false,
        }
    }

    #[test]
    fn a_swap_flips_after_heartbeat_and_command_then_finishes_after_the_window() {
        let mut swap = HotSwap::new(HotSwapConfig::default(), 1000 * MS, 5 * MS, None);
        assert_eq!(swap.step(&input(1100, false, false)), SwapAction::Wait);
        // A command without a heartbeat does not flip.
        assert_eq!(swap.step(&input(1150, false, true)), SwapAction::Wait);
        assert_eq!(swap.stage(), SwapStage::WaitHeartbeat);
        assert_eq!(swap.step(&input(1200, true, false)), SwapAction::Wait);
        assert_eq!(swap.stage(), SwapStage::WaitCommand);
        assert_eq!(swap.heartbeat_wait_ns(), Some(200 * MS));
        assert_eq!(swap.step(&input(1210, true, true)), SwapAction::Flip);
        assert_eq!(swap.stage(), SwapStage::Measuring { flip_ns: 1210 * MS });
        assert_eq!(swap.command_wait_ns(), Some(210 * MS));
        // The window is 20 periods = 100 ms.
        assert_eq!(swap.step(&input(1300, true, true)), SwapAction::Wait);
        assert_eq!(swap.step(&input(1310, true, true)), SwapAction::Finish);
        assert_eq!(swap.stage(), SwapStage::Done);
        assert_eq!(swap.step(&input(1400, true, true)), SwapAction::Wait);
    }

    #[test]
    fn heartbeat_and_command_in_one_cycle_flip_at_once() {
        let mut swap = HotSwap::new(HotSwapConfig::default(), 0, 5 * MS, None);
        assert_eq!(swap.step(&input(50, true, true)), SwapAction::Flip);
    }

    #[test]
    fn a_swap_gives_up_on_silence_or_an_early_exit() {
        let config = HotSwapConfig {
            heartbeat_timeout_ms: 500.0,
            command_timeout_ms: 300.0,
            ..HotSwapConfig::default()
        };
        let mut swap = HotSwap::new(config, 0, 5 * MS, None);
        assert_eq!(swap.step(&input(500, false, false)), SwapAction::Wait);
        assert_eq!(
            swap.step(&input(501, false, false)),
            SwapAction::Abort(SwapFailure::NoHeartbeat)
        );
        // The request's command timeout overrides the config's; it runs from the heartbeat.
        let mut swap = HotSwap::new(config, 0, 5 * MS, Some(1000.0));
        swap.step(&input(100, true, false));
        assert_eq!(swap.step(&input(1100, true, false)), SwapAction::Wait);
        assert_eq!(
            swap.step(&input(1101, true, false)),
            SwapAction::Abort(SwapFailure::NoCommand)
        );
        let mut swap = HotSwap::new(config, 0, 5 * MS, None);
        let exited = SwapInput {
            new_exited: true,
            ..input(10, true, true)
        };
        assert_eq!(
            swap.step(&exited),
            SwapAction::Abort(SwapFailure::NewExited)
        );
        assert_eq!(swap.stage(), SwapStage::Failed(SwapFailure::NewExited));
    }

    #[test]
    fn the_gap_is_the_longer_interval_that_meets_at_the_flip() {
        // Old every 5 ms at 0, 5, ..., 100; new every 5 ms at 2, 7, ...; flip at 51.
        let old: Vec<u64> = (0..=20).map(|k| k * 5 * MS).collect();
        let new: Vec<u64> = (0..=30).map(|k| (2 + k * 5) * MS).collect();
        let gap = command_gap(&old, &new, 51 * MS, 100 * MS).unwrap();
        // ... 45, 50, [flip 51], 52, 57, ...: old's last is 1 ms before, new's first 1 ms after.
        assert_eq!(gap.gap_ns, MS);
        // Raw stamps: old 50 → new 52.
        assert_eq!(gap.stamp_gap_ns, 2 * MS);
        assert_eq!(gap.old_samples, 11);
        assert_eq!(gap.new_samples, 20);
        // The old controller stalled before the flip: 45 and 50 missing, flip at 53.
        let stalled: Vec<u64> = old
            .iter()
            .copied()
            .filter(|&s| s != 45 * MS && s != 50 * MS)
            .collect();
        let gap = command_gap(&stalled, &new, 53 * MS, 100 * MS).unwrap();
        assert_eq!(gap.gap_ns, 13 * MS);
        assert_eq!(gap.stamp_gap_ns, 17 * MS);
        // A new controller whose first command after the flip comes late shows too.
        let gap = command_gap(&old, &[40 * MS, 80 * MS], 51 * MS, 100 * MS).unwrap();
        assert_eq!(gap.gap_ns, 29 * MS);
        // Samples outside the window do not count.
        let gap = command_gap(&old, &[40 * MS, 80 * MS], 51 * MS, 20 * MS);
        assert!(gap.is_none());
        assert!(command_gap(&[], &new, 51 * MS, 100 * MS).is_none());
        assert!(command_gap(&old, &[], 51 * MS, 100 * MS).is_none());
    }

    #[test]
    fn a_flip_is_timely_only_with_a_quarter_period_to_spare_on_both_sides() {
        // Old at 100 ms, new at 102 ms, 5 ms period: the new one's next command is at 107 ms.
        assert_eq!(
            predicted_gap(104 * MS, 100 * MS, 102 * MS, 5 * MS),
            Some(4 * MS)
        );
        assert_eq!(
            predicted_gap(103 * MS, 100 * MS, 102 * MS, 5 * MS),
            Some(4 * MS)
        );
        assert_eq!(
            predicted_gap(103_500_000, 100 * MS, 102 * MS, 5 * MS),
            Some(3_500_000)
        );
        assert!(flip_is_timely(103_500_000, 100 * MS, 102 * MS, 5 * MS));
        // Just after the new command (its next is a period away) or long after the old one.
        assert!(!flip_is_timely(102_100_000, 100 * MS, 102 * MS, 5 * MS));
        assert!(!flip_is_timely(104 * MS, 100 * MS, 102 * MS, 5 * MS));
        // The new controller late: nothing to predict.
        assert_eq!(predicted_gap(108 * MS, 107 * MS, 102 * MS, 5 * MS), None);
        assert!(!flip_is_timely(108 * MS, 107 * MS, 102 * MS, 5 * MS));
    }

    #[test]
    fn the_flip_falls_midway_between_commands_a_quarter_period_clear_of_them() {
        // Old at 100, 105, ...; new 4 ms after each old one: flip 2 ms after an old command.
        assert_eq!(flip_time(110 * MS, 100 * MS, 99 * MS, 5 * MS), 112 * MS);
        assert_eq!(flip_time(103 * MS, 100 * MS, 104 * MS, 5 * MS), 107 * MS);
        // New 2 ms after each old one: a flip between them would be 1 ms from each, so it falls
        // midway from a new command to the next new one, 3.5 ms after an old command.
        assert_eq!(flip_time(101 * MS, 100 * MS, 102 * MS, 5 * MS), 103_500_000);
        assert_eq!(flip_time(104 * MS, 100 * MS, 102 * MS, 5 * MS), 108_500_000);
        // In phase (both woken by the same arrival): half a period after their commands.
        assert_eq!(
            flip_time(100 * MS + 10, 100 * MS, 100 * MS, 5 * MS),
            102_500_000
        );
        // Never in the past, never a period or more ahead.
        for now in (100..130).map(|t| t * MS + 123) {
            let t = flip_time(now, 100 * MS, 97 * MS, 5 * MS);
            assert!(t >= now && t < now + 5 * MS, "{now} -> {t}");
        }
        // On ideal streams of any phase the gap there is at most three quarters of a period, the
        // flip is timely, and a wake-up up to a quarter period late keeps the gap under a period.
        let old: Vec<u64> = (0..40).map(|k| k * 5 * MS).collect();
        for lag in (0..20).map(|q| q * MS / 4) {
            let new: Vec<u64> = (0..40).map(|k| lag + k * 5 * MS).collect();
            let last_new = new.iter().copied().filter(|&s| s <= 60 * MS).max().unwrap();
            let flip = flip_time(60 * MS, 60 * MS, last_new, 5 * MS);
            let gap = command_gap(&old, &new, flip, 50 * MS).unwrap();
            assert!(gap.gap_ns <= 5 * MS * 3 / 4, "lag {lag}: {gap:?}");
            let late = command_gap(&old, &new, flip + 5 * MS / 4, 50 * MS).unwrap();
            assert!(late.gap_ns < 5 * MS, "lag {lag}, late wake-up: {late:?}");
            let (o, n) = (
                old.iter().copied().filter(|&s| s < flip).max().unwrap(),
                new.iter().copied().filter(|&s| s < flip).max().unwrap(),
            );
            assert!(flip_is_timely(flip, o, n, 5 * MS), "lag {lag}");
        }
    }

    #[test]
    fn a_controller_is_steady_after_enough_commands_on_time() {
        let regular: Vec<u64> = (0..30).map(|k| k * 5 * MS).collect();
        assert!(steady(&regular, 5 * MS, 20));
        assert!(!steady(&regular[..20], 5 * MS, 20));
        // One late cycle (8 ms) among the last 20 intervals: not yet.
        let mut late = regular.clone();
        for s in &mut late[25..] {
            *s += 3 * MS;
        }
        assert!(steady(&late, 5 * MS, 4));
        assert!(!steady(&late, 5 * MS, 5));
    }

    #[test]
    fn swap_args_replace_variant_and_id_in_every_form() {
        let args: Vec<String> = [
            "--rate",
            "200",
            "--variant",
            "grasp",
            "--controller-id=4",
            "--seed",
            "1",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(controller_id_of(&args, 1), 4);
        assert_eq!(
            swap_args(&args, "press-button", 5),
            [
                "--rate",
                "200",
                "--seed",
                "1",
                "--variant",
                "press-button",
                "--controller-id",
                "5"
            ]
        );
        let plain: Vec<String> = ["--rate", "200"].map(String::from).to_vec();
        assert_eq!(controller_id_of(&plain, 1), 1);
        let spaced: Vec<String> = ["--controller-id", "7", "--variant=drop"]
            .map(String::from)
            .to_vec();
        assert_eq!(controller_id_of(&spaced, 1), 7);
        assert_eq!(
            swap_args(&spaced, "grasp", 8),
            ["--variant", "grasp", "--controller-id", "8"]
        );
    }

    #[test]
    fn bad_configs_name_the_key() {
        let bad = HotSwapConfig {
            command_timeout_ms: f64::NAN,
            ..HotSwapConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "command_timeout_ms");
        let bad = HotSwapConfig {
            gap_window_periods: 0,
            ..HotSwapConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "gap_window_periods");
        assert!(HotSwapConfig::default().validate().is_ok());
    }
}
