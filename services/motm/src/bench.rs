//! `motm bench`: timing of the control stack's hot paths on this machine.
//!
//! `motm bench qp` times one redundancy-resolution QP solve on Frankie (random reachable twists
//! with base tracking, the data of a MotM cycle) over many solves, then the whole control step
//! (kinematics, Hessian, QP build and solve) on the same problems.

use std::path::Path;
use std::time::Instant;

use clap::{Args, Subcommand};
use motm_core::qp_scenario::{QpScenario, ScenarioConfig};
use motm_core::{RedundancyResolver, ResolverConfig, Robot};
use serde_json::json;

/// Arguments of `motm bench`.
#[derive(Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

/// What to benchmark.
#[derive(Subcommand)]
enum BenchCommand {
    /// Time the redundancy-resolution QP (median, p99 and max µs) and the whole control step.
    Qp(QpArgs),
    /// Per-hop latency between two processes: iceoryx2 and a Unix-domain socket, 64 B and a
    /// camera image.
    Ipc(crate::bench_ipc::IpcArgs),
    /// End-to-end latency of the running stack: from a camera frame's publication to the first
    /// joint command computed from it (median, p99 and max µs over one `motm run`), and from
    /// the exposure of the image behind the target to every command (`exposure_*`).
    E2e(crate::run::RunArgs),
    /// The logger's cost to the control loop: p99 cycle times over runs without and with
    /// `--mcap` (median and worst run per process, and the ratio).
    Logger(crate::bench_logger::LoggerBenchArgs),
    /// The compute time of each task's step (median, p99 and max µs) over one in-process MotM
    /// trial: what each hop of the chain adds to the deployed latency.
    Tasks(TasksArgs),
    /// Echo peer of `motm bench ipc` (started by it).
    #[command(hide = true)]
    IpcEcho(crate::bench_ipc::EchoArgs),
}

/// Arguments of `motm bench qp`.
#[derive(Args)]
struct QpArgs {
    /// Robot name.
    #[arg(long, default_value = "frankie")]
    robot: String,
    /// Number of timed solves (at least 2000).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(2000..))]
    solves: u64,
    /// Seed of the random problems.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON object: median_us, p99_us, max_us, iterations (timed solves),
    /// solver_iterations_median, step_median_us, step_p99_us, errors.
    #[arg(long)]
    json: bool,
}

/// Arguments of `motm bench tasks`.
#[derive(Args)]
struct TasksArgs {
    /// Scenario file or name.
    #[arg(long, default_value = "exp1-dynamic")]
    scenario: String,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON object: `{"tasks": [{"name", "steps", "median_us", "p99_us",
    /// "max_us", "over_period"}], ...}` (`over_period`: steps longer than the control period).
    #[arg(long)]
    json: bool,
}

/// `motm bench tasks`.
fn run_tasks(config_dir: &Path, args: &TasksArgs) -> Result<(), String> {
    let (robot, scenario) = crate::trial::load(config_dir, &args.scenario, None, args.seed)
        .map_err(|e| e.to_string())?;
    let config = motm_sim::runner::RunnerConfig {
        time_steps: true,
        ..crate::trial::runner_config(config_dir, None).map_err(|e| e.to_string())?
    };
    let (result, trace) = motm_sim::runner::run_trial(
        &robot,
        &scenario,
        motm_sim::experiment::Method::Motm,
        args.seed,
        &config,
        true,
    )?;
    let trace = trace.ok_or("the trial kept no trace")?;
    // A step longer than the control period would miss its deadline in the deployed stack.
    let period_ns = 1e9 / config.control_rate_hz;
    let rows: Vec<_> = trace
        .step_ns
        .iter()
        .filter(|(_, times)| !times.is_empty())
        .map(|(name, times)| {
            let mut us: Vec<f64> = times.iter().map(|&ns| ns as f64 / 1e3).collect();
            let steps = us.len();
            let over = times.iter().filter(|&&ns| ns as f64 > period_ns).count();
            let (median, p99, max) = summarize(&mut us);
            json!({"name": name, "steps": steps, "median_us": median, "p99_us": p99, "max_us": max,
                   "over_period": over})
        })
        .collect();
    if args.json {
        println!(
            "{}",
            json!({"scenario": scenario.name, "seed": args.seed, "success": result.success, "tasks": rows})
        );
    } else {
        println!(
            "step compute time per task, {} seed {} (one in-process trial; over: steps longer \
             than the {:.1} ms control period):",
            scenario.name,
            args.seed,
            period_ns / 1e6
        );
        for row in &rows {
            println!(
                "  {:<13} {:>6} steps: median {:>7.1} µs, p99 {:>7.1} µs, max {:>8.1} µs, over {}",
                row["name"].as_str().unwrap_or(""),
                row["steps"],
                row["median_us"].as_f64().unwrap_or(0.0),
                row["p99_us"].as_f64().unwrap_or(0.0),
                row["max_us"].as_f64().unwrap_or(0.0),
                row["over_period"],
            );
        }
    }
    Ok(())
}

/// Runs `motm bench`.
pub fn run(config_dir: &Path, args: &BenchArgs) -> Result<(), String> {
    match &args.command {
        BenchCommand::Qp(qp) => run_qp(config_dir, qp),
        BenchCommand::Ipc(ipc) => crate::bench_ipc::run(ipc),
        BenchCommand::E2e(run) => run_e2e(config_dir, run),
        BenchCommand::Tasks(args) => run_tasks(config_dir, args),
        BenchCommand::Logger(logger) => crate::bench_logger::run(config_dir, logger),
        BenchCommand::IpcEcho(echo) => crate::bench_ipc::run_echo(echo),
    }
}

/// Distinct problems cycled through by the timing loops.
const PROBLEMS: usize = 2048;
/// Untimed solves before timing starts.
const WARM_UP: usize = 500;

/// Median, 99th percentile and maximum of durations in µs (sorts `samples`).
fn summarize(samples: &mut [f64]) -> (f64, f64, f64) {
    samples.sort_by(f64::total_cmp);
    let at = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize];
    (at(0.5), at(0.99), at(1.0))
}

/// `motm bench e2e`: one `motm run` with every QP status recorded. The headline figures are
/// from a frame's publication to the first joint command computed from it; the `exposure_*`
/// ones from the exposure of the image behind the target to every command that used it; with
/// `--swap`, the gap each hot swap left in the command stream.
fn run_e2e(config_dir: &Path, args: &crate::run::RunArgs) -> Result<(), String> {
    let (report, mut latencies) =
        crate::run::run_stack(config_dir, args, true).map_err(|e| e.to_string())?;
    if latencies.frame_us.is_empty() || latencies.exposure_us.is_empty() {
        return Err("no QP cycle reported a camera frame".into());
    }
    let samples = latencies.frame_us.len();
    let exposure_samples = latencies.exposure_us.len();
    let (median, p99, max) = summarize(&mut latencies.frame_us);
    let (exposure_median, exposure_p99, exposure_max) = summarize(&mut latencies.exposure_us);
    let summary = json!({
        "median_us": median,
        "p99_us": p99,
        "max_us": max,
        "samples": samples,
        "exposure_median_us": exposure_median,
        "exposure_p99_us": exposure_p99,
        "exposure_max_us": exposure_max,
        "exposure_samples": exposure_samples,
        "success": report.trial.success,
        "control_rate_hz": report.control_rate_hz,
        "scenario": report.scenario,
        "swap_command_gaps_ms": report.swaps.iter().map(|s| s.command_gap_ms).collect::<Vec<_>>(),
    });
    if args.json {
        println!("{summary}");
    } else {
        println!(
            "frame published → first joint command from it, over {samples} frames at {} Hz: median {median:.0} µs, p99 {p99:.0} µs, max {max:.0} µs",
            report.control_rate_hz,
        );
        println!(
            "image exposure → joint command, over {exposure_samples} QP cycles: median {exposure_median:.0} µs, p99 {exposure_p99:.0} µs, max {exposure_max:.0} µs (run {})",
            if report.trial.success {
                "succeeded"
            } else {
                "failed"
            }
        );
        for swap in &report.swaps {
            println!(
                "swap of {} to {}: command gap {:.3} ms (one control period: {:.3} ms)",
                swap.process,
                swap.variant,
                swap.command_gap_ms,
                1000.0 / report.control_rate_hz
            );
        }
    }
    Ok(())
}

fn run_qp(config_dir: &Path, args: &QpArgs) -> Result<(), String> {
    let robot = Robot::load(config_dir, &args.robot).map_err(|e| e.to_string())?;
    let problems = QpScenario::random_set(&robot, &ScenarioConfig::default(), PROBLEMS, args.seed);
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let solves = args.solves as usize;

    for problem in problems.iter().cycle().take(WARM_UP) {
        std::hint::black_box(resolver.resolve(&problem.input()));
    }
    let mut solve_us = Vec::with_capacity(solves);
    let mut solver_iterations = Vec::with_capacity(solves);
    for problem in problems.iter().cycle().take(solves) {
        let input = problem.input();
        let start = Instant::now();
        let out = resolver.resolve(&input);
        solve_us.push(start.elapsed().as_secs_f64() * 1e6);
        solver_iterations.push(f64::from(out.iterations));
    }
    let mut step_us = Vec::with_capacity(solves);
    for problem in problems.iter().cycle().take(solves) {
        let start = Instant::now();
        std::hint::black_box(problem.control_step(&robot, &mut resolver));
        step_us.push(start.elapsed().as_secs_f64() * 1e6);
    }
    let (median, p99, max) = summarize(&mut solve_us);
    let (step_median, step_p99, _) = summarize(&mut step_us);
    let (iterations_median, _, _) = summarize(&mut solver_iterations);
    let errors = resolver.error_count();
    if args.json {
        println!(
            "{}",
            json!({
                "robot": robot.name(),
                "median_us": median,
                "p99_us": p99,
                "max_us": max,
                "iterations": solves,
                "solver_iterations_median": iterations_median,
                "step_median_us": step_median,
                "step_p99_us": step_p99,
                "errors": errors,
            })
        );
    } else {
        println!("{} QP solve over {solves} solves:", robot.name());
        println!("  median {median:.1} µs, p99 {p99:.1} µs, max {max:.1} µs");
        println!("  interior-point iterations (median) {iterations_median}");
        println!("control step (kinematics, Hessian, build, solve):");
        println!("  median {step_median:.1} µs, p99 {step_p99:.1} µs");
        println!("failed solves: {errors}");
    }
    if errors > 0 {
        return Err(format!("{errors} benchmark problems failed to solve"));
    }
    Ok(())
}
