//! `motm log info FILE` and `motm log check FILE`: what an MCAP log written by the logger
//! holds, and whether it is sound. A log whose writer was killed is read up to its last whole
//! record; `check` accepts it when everything read is sound and says what was recovered.

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use motm_logger::inspect::{self, LogSummary};

use crate::CliError;

/// Arguments of `motm log`.
#[derive(Args, Debug)]
pub struct LogArgs {
    #[command(subcommand)]
    command: LogCommand,
}

/// The `motm log` subcommands.
#[derive(Subcommand, Debug)]
enum LogCommand {
    /// Print the channels, schemas, message counts and time range of an MCAP log.
    Info {
        /// The MCAP file.
        file: PathBuf,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Validate an MCAP log: exit 1 if it is corrupt or holds no message, 2 if it is missing.
    Check {
        /// The MCAP file.
        file: PathBuf,
    },
}

/// Reads and scans `file`: a missing or unreadable file is bad input, a corrupt one a failure.
fn load(file: &Path) -> Result<LogSummary, CliError> {
    let bytes =
        std::fs::read(file).map_err(|e| CliError::BadInput(format!("{}: {e}", file.display())))?;
    inspect::scan(&bytes).map_err(|e| CliError::Failed(format!("{}: corrupt: {e}", file.display())))
}

/// `motm log`.
pub fn run(args: &LogArgs) -> Result<(), CliError> {
    match &args.command {
        LogCommand::Info { file, json } => {
            let summary = load(file)?;
            if *json {
                println!("{}", inspect::info_json(&summary));
            } else {
                print!(
                    "{}",
                    inspect::info_text(&file.display().to_string(), &summary)
                );
            }
            Ok(())
        }
        LogCommand::Check { file } => {
            let summary = load(file)?;
            let problems = summary.problems();
            if !problems.is_empty() {
                return Err(CliError::Failed(format!(
                    "{}: {}",
                    file.display(),
                    problems.join("; ")
                )));
            }
            let state = if summary.complete {
                "complete".to_string()
            } else {
                format!(
                    "incomplete, recovered up to the last whole chunk ({} byte(s) after it dropped)",
                    summary.truncated_bytes
                )
            };
            println!(
                "{}: ok: {} messages on {} channels in {} chunks, {state}",
                file.display(),
                summary.messages(),
                summary.channels.len(),
                summary.chunks
            );
            Ok(())
        }
    }
}
