//! The `motm-zenoh` process: its flags (a bridge config file, or the tasks run on another host
//! and which end this is; extra endpoints; the `bench` subcommand) and its main.

use std::path::PathBuf;
use std::process::ExitCode;

use crate::{BridgeConfig, Side};
use clap::{Parser, Subcommand};
use motm_bus::IpcConfig;

/// Exit code for bad input (a bad file, key or flag).
const EXIT_BAD_INPUT: u8 = 2;

/// Forwards motm topics between this host's iceoryx2 stack and zenoh.
#[derive(Parser)]
#[command(name = "motm-zenoh")]
struct Args {
    /// Bridge config file (name, export, import, listen, connect, namespace).
    #[arg(long, conflicts_with = "remote_task")]
    config: Option<PathBuf>,
    /// Bridge the topics of this task of the graph, run on the remote host (repeatable).
    #[arg(long)]
    remote_task: Vec<String>,
    /// Which end of a `--remote-task` bridge this is.
    #[arg(long, value_enum, default_value_t = Side::Stack)]
    side: Side,
    /// A zenoh endpoint to listen on, e.g. `tcp/0.0.0.0:7447` (repeatable; added to the config's).
    #[arg(long)]
    listen: Vec<String>,
    /// A zenoh endpoint to connect to, e.g. `tcp/gpu-box:7447` (repeatable; added to the config's).
    #[arg(long)]
    connect: Vec<String>,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Measure the bridge's added latency per hop beside a direct iceoryx2 hop.
    Bench(crate::bench::BenchArgs),
}

fn config(args: &Args) -> Result<BridgeConfig, String> {
    let mut config = match (&args.config, args.remote_task.is_empty()) {
        (Some(file), _) => BridgeConfig::from_file(file)?,
        (None, false) => BridgeConfig::for_remote_tasks(&args.remote_task, args.side)?,
        (None, true) => return Err("give --config FILE or --remote-task TASK".into()),
    };
    config.listen.extend(args.listen.iter().cloned());
    config.connect.extend(args.connect.iter().cloned());
    config.validate().map_err(|e| match &args.config {
        Some(file) => format!("{}: {e}", file.display()),
        None => e,
    })?;
    Ok(config)
}

/// The `motm-zenoh` process: parses its flags, bridges until stopped, and returns its exit
/// status (2 for bad input).
pub fn main() -> ExitCode {
    let args = Args::parse();
    if let Some(Command::Bench(bench)) = &args.command {
        return match crate::bench::run(bench) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                motm_bus::say!("motm-zenoh bench: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let config = match config(&args) {
        Ok(config) => config,
        Err(e) => {
            motm_bus::say!("motm-zenoh: {e}");
            return ExitCode::from(EXIT_BAD_INPUT);
        }
    };
    match crate::run(&config, &IpcConfig::from_env()) {
        Ok(stats) => {
            motm_bus::say!("{}: stopped: {}", config.name, stats.summary());
            ExitCode::SUCCESS
        }
        Err(e) => {
            motm_bus::say!("{}: {e}", config.name);
            ExitCode::FAILURE
        }
    }
}
