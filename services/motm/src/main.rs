//! `motm`: the user-facing command-line interface of the motm stack.

mod bench_ipc;
mod config_dir;
mod kin;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Exit code for bad input: a bad file, key, value or name.
pub const EXIT_BAD_INPUT: u8 = 2;

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
    /// Micro and system benchmarks (median, p99, max).
    #[command(subcommand)]
    Bench(BenchCommand),
}

/// Benchmarks of `motm bench`.
#[derive(Subcommand)]
enum BenchCommand {
    /// Per-hop latency between two processes: iceoryx2 and a Unix-domain socket, 64 B and a camera image.
    Ipc(bench_ipc::IpcArgs),
    /// Echo peer of `motm bench ipc` (started by it).
    #[command(hide = true)]
    IpcEcho(bench_ipc::EchoArgs),
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { EXIT_BAD_INPUT } else { 0 };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    let config_dir = config_dir::resolve(cli.config_dir);
    let result = match cli.command {
        Command::Kin(args) => kin::run(&config_dir, &args),
        Command::Bench(BenchCommand::Ipc(args)) => bench_ipc::run(&args),
        Command::Bench(BenchCommand::IpcEcho(args)) => bench_ipc::run_echo(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("motm: {e}");
            ExitCode::from(EXIT_BAD_INPUT)
        }
    }
}
