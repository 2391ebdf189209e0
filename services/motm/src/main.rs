//! `motm`: the user-facing command-line interface of the motm stack.

mod bench;
mod bench_ipc;
mod bench_logger;
mod error;
mod experiment;
mod faults;
mod kin;
mod log;
mod plots;
mod replay;
mod report;
mod run;
mod run_mcap;
mod status;
mod swap;
mod trial;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub use error::{CliError, EXIT_BAD_INPUT, EXIT_FAILED};

/// Reactive mobile manipulation on-the-move.
#[derive(Parser)]
#[command(name = "motm", version, about)]
struct Cli {
    /// Folder holding robots/, scenarios/ and the stack configs (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long, global = true)]
    config_dir: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the tool pose, world Jacobian and manipulability of a robot at a configuration.
    Kin(kin::KinArgs),
    /// Benchmark the control stack's hot paths (e.g. `motm bench qp --json`).
    Bench(bench::BenchArgs),
    /// Run one in-process trial of a scenario and print its metrics.
    Trial(trial::TrialArgs),
    /// Run the paper's experiments in-process and write tables and plots.
    Experiment(experiment::ExperimentArgs),
    /// Run the multi-process stack against the simulated world and print the trial metrics.
    Run(run::RunArgs),
    /// Show the live process table of a running stack.
    Status(status::StatusArgs),
    /// Hot-swap a controller process of a running stack (e.g. `motm swap final-phase press-button`).
    Swap(swap::SwapArgs),
    /// Inspect (`info`) or validate (`check`) an MCAP log written by `motm run --mcap`.
    Log(log::LogArgs),
    /// Replay a `motm trial --mcap` log through the control tasks (e.g. with new gains) and
    /// report the first cycle whose output differs.
    Replay(replay::ReplayArgs),
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    let config_dir = motm_core::resolve_config_dir(cli.config_dir.as_deref());
    let result = match cli.command {
        Command::Kin(args) => kin::run(&config_dir, &args).map_err(CliError::BadInput),
        Command::Bench(args) => bench::run(&config_dir, &args).map_err(CliError::BadInput),
        Command::Trial(args) => trial::run(&config_dir, &args),
        Command::Experiment(args) => experiment::run(&config_dir, &args),
        Command::Run(args) => run::run(&config_dir, &args),
        Command::Status(args) => status::run(&args),
        Command::Swap(args) => swap::run(&args),
        Command::Log(args) => log::run(&args),
        Command::Replay(args) => replay::run(&config_dir, &args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            motm_bus::say!("motm: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
