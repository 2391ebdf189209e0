//! `motm bench logger`: what attaching the MCAP logger costs the control loop. It runs the
//! stack `--pairs` times without and with `--mcap` (seeds counted up from `--seed`, the order
//! of each pair alternating so a drift in machine load hits both sides alike) and reports, per
//! control process, the median and the worst over the runs of each run's p99 cycle time (the
//! process's last heartbeat: its last 2000 cycles), the ratio of those medians, and the median
//! over the pairs of each pair's ratio (the pairs share a seed and the machine's load of the
//! moment, so this one is the steadier on a noisy machine).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use crate::run::{RunArgs, RunReport, run_stack};

/// Arguments of `motm bench logger`.
#[derive(Args, Debug)]
pub struct LoggerBenchArgs {
    /// Pairs of runs (one without, one with the logger).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    pairs: u32,
    /// First seed; pair i runs seed + i on both sides.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Scenario file or name (default: the stack config's `scenario`).
    #[arg(long)]
    scenario: Option<String>,
    /// Folder for the logs written by the runs with the logger (default: the system's
    /// temporary folder).
    #[arg(long)]
    out_dir: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// The processes whose cycle time is the control loop's (the logger's own is not).
const CONTROL_PROCESSES: [&str; 8] = [
    "qp-resolver",
    "reacher",
    "final-phase",
    "base-planner",
    "perception",
    "panda-driver",
    "ld60-driver",
    "watchdog",
];

/// Median of `values` (sorts them); `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// One side's p99 cycle times, µs, per process over the runs.
#[derive(Default)]
struct Side {
    p99_us: BTreeMap<&'static str, Vec<f64>>,
    deadline_misses: BTreeMap<&'static str, u64>,
    failures: u32,
}

impl Side {
    /// Adds one run's figures.
    fn add(&mut self, report: &RunReport) {
        if !report.trial.success {
            self.failures += 1;
        }
        for name in CONTROL_PROCESSES {
            if let Some(p) = report.processes.iter().find(|p| p.name == name) {
                self.p99_us.entry(name).or_default().push(p.p99_cycle_us);
                *self.deadline_misses.entry(name).or_default() += p.deadline_misses;
            }
        }
    }

    /// Median and maximum of `name`'s per-run p99, µs.
    fn summary(&self, name: &str) -> Option<(f64, f64)> {
        let mut values = self.p99_us.get(name)?.clone();
        let median = median(&mut values)?;
        Some((median, *values.last()?))
    }
}

/// Each pair's with ÷ without p99 of `name`, sorted (the runs were added pair by pair).
fn pair_ratios(without: &Side, with: &Side, name: &str) -> Option<Vec<f64>> {
    let (off, on) = (without.p99_us.get(name)?, with.p99_us.get(name)?);
    let mut ratios: Vec<f64> = off.iter().zip(on).map(|(off, on)| on / off).collect();
    ratios.sort_by(f64::total_cmp);
    Some(ratios)
}

/// A distribution-free 95 % confidence interval of the median of `sorted` (the sign test's
/// order statistics: the k-th smallest and k-th largest value for the largest k with
/// P(Binomial(n, ½) < k) ≤ 2.5 %); `None` for fewer than 6 values, where no such k exists.
fn median_confidence_interval(sorted: &[f64]) -> Option<(f64, f64)> {
    let n = sorted.len();
    let total = 2f64.powi(i32::try_from(n).ok()?);
    // `below` sums C(n, i) for i < k; `choose` is C(n, k).
    let (mut below, mut choose, mut k) = (0.0, 1.0, 0);
    for i in 0..n {
        if (below + choose) / total > 0.025 {
            break;
        }
        below += choose;
        choose = choose * (n - i) as f64 / (i + 1) as f64;
        k = i + 1;
    }
    (k >= 1).then(|| (sorted[k - 1], sorted[n - k]))
}

/// Runs `motm bench logger`.
pub fn run(config_dir: &Path, args: &LoggerBenchArgs) -> Result<(), String> {
    let out_dir = args.out_dir.clone().unwrap_or_else(std::env::temp_dir);
    let (mut without, mut with) = (Side::default(), Side::default());
    for pair in 0..args.pairs {
        let seed = args.seed + u64::from(pair);
        let log = out_dir.join(format!(
            "motm-bench-logger-{}-{pair}.mcap",
            std::process::id()
        ));
        let order = if pair % 2 == 0 {
            [false, true]
        } else {
            [true, false]
        };
        for logged in order {
            let run_args = RunArgs {
                seed: Some(seed),
                scenario: args.scenario.clone(),
                mcap: logged.then(|| log.clone()),
                ..RunArgs::default()
            };
            let (report, _) = run_stack(config_dir, &run_args, false).map_err(|e| e.to_string())?;
            if !args.json {
                motm_bus::say!(
                    "pair {pair} seed {seed} {}: qp-resolver p99 {:.0} µs ({})",
                    if logged {
                        "with logger   "
                    } else {
                        "without logger"
                    },
                    report
                        .processes
                        .iter()
                        .find(|p| p.name == "qp-resolver")
                        .map_or(f64::NAN, |p| p.p99_cycle_us),
                    if report.trial.success {
                        "success"
                    } else {
                        "failed"
                    }
                );
            }
            if logged {
                with.add(&report);
                // The logs are not the point here; keep the disk clean.
                let _ = std::fs::remove_file(&log);
            } else {
                without.add(&report);
            }
        }
    }
    print_summary(&without, &with, args)
}

/// Prints the per-process table (or JSON).
fn print_summary(without: &Side, with: &Side, args: &LoggerBenchArgs) -> Result<(), String> {
    let mut rows = serde_json::Map::new();
    if !args.json {
        println!(
            "p99 cycle time over {} runs each side (median of the runs' p99 / worst run), µs:",
            args.pairs
        );
        println!(
            "{:<14} {:>18} {:>18} {:>8} {:>12} {:>13} {:>15}",
            "process",
            "without logger",
            "with logger",
            "ratio",
            "paired ratio",
            "95 % CI",
            "deadline misses"
        );
    }
    for name in CONTROL_PROCESSES {
        let (Some((off_median, off_max)), Some((on_median, on_max))) =
            (without.summary(name), with.summary(name))
        else {
            continue;
        };
        let ratio = on_median / off_median;
        let mut ratios = pair_ratios(without, with, name).unwrap_or_default();
        let paired = median(&mut ratios).unwrap_or(f64::NAN);
        let (low, high) = median_confidence_interval(&ratios).unwrap_or((f64::NAN, f64::NAN));
        let misses = (
            without.deadline_misses.get(name).copied().unwrap_or(0),
            with.deadline_misses.get(name).copied().unwrap_or(0),
        );
        if args.json {
            rows.insert(
                name.to_owned(),
                json!({
                    "without_median_p99_us": off_median,
                    "without_worst_p99_us": off_max,
                    "with_median_p99_us": on_median,
                    "with_worst_p99_us": on_max,
                    "ratio": ratio,
                    "paired_ratio": paired,
                    "paired_ratio_ci95": [low, high],
                    "without_p99_us_by_pair": without.p99_us.get(name),
                    "with_p99_us_by_pair": with.p99_us.get(name),
                    "deadline_misses_without": misses.0,
                    "deadline_misses_with": misses.1,
                }),
            );
        } else {
            println!(
                "{name:<14} {:>8.0} / {:>7.0} {:>8.0} / {:>7.0} {ratio:>8.2} {paired:>12.2}  {low:>5.2}–{high:<5.2} {:>6} / {:<6}",
                off_median, off_max, on_median, on_max, misses.0, misses.1
            );
        }
    }
    if args.json {
        println!(
            "{}",
            json!({
                "pairs": args.pairs,
                "failures_without": without.failures,
                "failures_with": with.failures,
                "processes": rows,
            })
        );
    } else {
        println!(
            "failed runs: {} without, {} with the logger",
            without.failures, with.failures
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_interval_takes_the_sign_test_order_statistics() {
        let values: Vec<f64> = (1..=30).map(f64::from).collect();
        // P(Bin(30, ½) ≤ 9) = 2.1 % ≤ 2.5 % < P(≤ 10) = 4.9 %: the 10th smallest and largest.
        assert_eq!(median_confidence_interval(&values), Some((10.0, 21.0)));
        // Six values: P(≤ 0) = 1.6 %, so the interval is the whole range.
        assert_eq!(median_confidence_interval(&values[..6]), Some((1.0, 6.0)));
        // Five: even the extremes leave 2 × 3.1 % outside, so there is no 95 % interval.
        assert_eq!(median_confidence_interval(&values[..5]), None);
    }
}
