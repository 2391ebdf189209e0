//! `motm run --mcap FILE` / `--live [ADDR]`: the logger process beside the stack (one process
//! for both: it writes the file and serves the Foxglove WebSocket live view). It is started
//! before the supervisor (it attaches to each service as it appears) and stopped before it
//! (SIGTERM: the logger writes its last chunk and the summary), so the file covers the whole run.

use std::net::{SocketAddr, TcpListener};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

use motm_supervisor::binaries;
use serde::Serialize;

use crate::CliError;

/// Name of the logger binary.
const LOGGER: &str = "logger";

/// Address of `motm run --live` without a value: Foxglove's default, on the loopback only.
pub const DEFAULT_LIVE_ADDR: &str = "127.0.0.1:8765";

/// What the logger makes: an MCAP file, a live view, or both.
#[derive(Debug, Clone, Copy)]
pub struct LoggerOutputs<'a> {
    /// `--mcap FILE`.
    pub mcap: Option<&'a Path>,
    /// `--live ADDR`.
    pub live: Option<SocketAddr>,
}

/// Makes `command`'s process get SIGTERM when this process exits, so no child outlives a
/// `motm run` that was killed.
pub fn exit_with_parent(command: &mut Command) {
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                return Err(std::io::Error::other("motm run exited"));
            }
            Ok(())
        });
    }
}

impl LoggerOutputs<'_> {
    /// Whether the logger is wanted at all.
    pub fn any(&self) -> bool {
        self.mcap.is_some() || self.live.is_some()
    }

    /// Bad input, found before anything starts: a file that cannot be written, an address
    /// that cannot be listened on (in use, not local).
    pub fn check(&self) -> Result<(), CliError> {
        if let Some(out) = self.mcap {
            std::fs::File::create(out)
                .map_err(|e| CliError::BadInput(format!("--mcap {}: {e}", out.display())))?;
        }
        if let Some(addr) = self.live {
            TcpListener::bind(addr)
                .map_err(|e| CliError::BadInput(format!("--live {addr}: {e}")))?;
        }
        Ok(())
    }
}

/// The run the logger logs: what it draws the scene from and what the replay log records.
#[derive(Debug, Clone, Copy)]
pub struct LoggedRun<'a> {
    /// Folder holding robots/ and scenarios/.
    pub config_dir: &'a Path,
    /// Robot name.
    pub robot: &'a str,
    /// Scenario file.
    pub scenario: &'a Path,
    /// Seed.
    pub seed: u64,
    /// Base speed, m/s.
    pub base_speed: f64,
}

/// The running logger.
pub struct LoggerProcess {
    child: Child,
    /// Where the logger writes its final counts (`logger --final-stats`).
    stats_file: PathBuf,
}

/// What the logger read and lost in a run (its final counts).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoggerLoss {
    /// Samples the logger read from the stack's services.
    pub samples_received: u64,
    /// Samples it never read: overwritten in its full queues (the services overflow safely,
    /// so a logger that falls behind loses its oldest samples instead of slowing a publisher).
    pub samples_lost: u64,
    /// `samples_lost / (samples_received + samples_lost)`.
    pub lost_fraction: f64,
    /// Records it read but dropped because its writer thread fell behind.
    pub records_dropped: u64,
}

impl LoggerLoss {
    /// Parses the logger's `--final-stats` JSON; the error names the file.
    fn from_json(text: &str, file: &Path) -> Result<Self, String> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("{}: {e}", file.display()))?;
        let count = |key: &str| {
            value[key]
                .as_u64()
                .ok_or_else(|| format!("{}: no {key}", file.display()))
        };
        let (samples_received, samples_lost) = (count("samples_received")?, count("samples_lost")?);
        let total = samples_received + samples_lost;
        Ok(Self {
            samples_received,
            samples_lost,
            lost_fraction: if total == 0 {
                0.0
            } else {
                samples_lost as f64 / total as f64
            },
            records_dropped: count("records_dropped")?,
        })
    }
}

impl LoggerProcess {
    /// Starts `logger [--out FILE --replay] [--live ADDR]` from `bin_dir` on iceoryx2 prefix
    /// `prefix` (building it with `$CARGO` when it is missing and `motm` runs through Cargo);
    /// the outputs were checked with [`LoggerOutputs::check`]. A file also holds the replay
    /// log, so that `motm replay FILE` can feed the run's task cycles again.
    pub fn start(
        bin_dir: &Path,
        prefix: &str,
        outputs: LoggerOutputs,
        run: LoggedRun,
    ) -> Result<Self, CliError> {
        if !binaries::missing(bin_dir, [LOGGER]).is_empty()
            && let Some(cargo) = std::env::var_os("CARGO")
            && let Err(e) =
                binaries::cargo_build(Path::new(&cargo), bin_dir, &["motm-logger".to_string()])
        {
            motm_bus::say!("motm run: {e}");
        }
        let mut command = Command::new(binaries::binary_path(bin_dir, LOGGER));
        let stats_file = std::env::temp_dir().join(format!("motm-logger-stats-{prefix}.json"));
        let _ = std::fs::remove_file(&stats_file);
        command.arg("--final-stats").arg(&stats_file);
        if let Some(out) = outputs.mcap {
            command.arg("--out").arg(out).arg("--replay");
        }
        if let Some(addr) = outputs.live {
            command.arg("--live").arg(addr.to_string());
        }
        command
            .arg("--config-dir")
            .arg(run.config_dir)
            .arg("--robot")
            .arg(run.robot)
            .arg("--scenario")
            .arg(run.scenario)
            .arg("--seed")
            .arg(run.seed.to_string())
            .arg("--base-speed")
            .arg(run.base_speed.to_string())
            .env(motm_bus::PREFIX_ENV, prefix);
        exit_with_parent(&mut command);
        let child = command.spawn().map_err(|e| {
            CliError::Failed(format!(
                "cannot start the logger (`cargo build -p motm-logger`): {e}"
            ))
        })?;
        Ok(Self { child, stats_file })
    }

    /// Stops the logger (SIGTERM, SIGKILL after `grace`) and returns what it read and lost;
    /// an error when it did not finish the file cleanly.
    pub fn stop(mut self, grace: Duration) -> Result<LoggerLoss, CliError> {
        let exit = crate::run::stop_supervisor(&mut self.child, grace);
        let stats = std::fs::read_to_string(&self.stats_file);
        let _ = std::fs::remove_file(&self.stats_file);
        match exit {
            Some(s) if s.success() => {}
            Some(s) => return Err(CliError::Failed(format!("logger exited with {s}"))),
            None => return Err(CliError::Failed("logger did not stop".into())),
        }
        let text = stats.map_err(|e| {
            CliError::Failed(format!("logger counts {}: {e}", self.stats_file.display()))
        })?;
        LoggerLoss::from_json(&text, &self.stats_file).map_err(CliError::Failed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loggers_final_counts_give_its_lost_fraction_and_a_missing_key_names_the_file() {
        let file = Path::new("/tmp/stats.json");
        let loss = LoggerLoss::from_json(
            r#"{"samples_received": 900, "samples_lost": 100, "records_dropped": 3, "lost_by_service": {}}"#,
            file,
        )
        .unwrap();
        assert_eq!(loss.samples_received, 900);
        assert_eq!(loss.samples_lost, 100);
        assert_eq!(loss.records_dropped, 3);
        assert!((loss.lost_fraction - 0.1).abs() < 1e-12);
        let err = LoggerLoss::from_json(r#"{"samples_received": 1}"#, file).unwrap_err();
        assert!(
            err.contains("/tmp/stats.json") && err.contains("samples_lost"),
            "{err}"
        );
    }
}
