//! `motm run --mcap FILE` / `--live [ADDR]`: the logger process beside the stack (one process
//! for both: it writes the file and serves the Foxglove WebSocket live view). It is started
//! before the supervisor (it attaches to each service as it appears) and stopped before it
//! (SIGTERM: the logger writes its last chunk and the summary), so the file covers the whole run.

use std::net::{SocketAddr, TcpListener};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command};
use std::time::Duration;

use motm_supervisor::binaries;

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
        Ok(Self { child })
    }

    /// Stops the logger (SIGTERM, SIGKILL after `grace`); an error when it did not finish the
    /// file cleanly.
    pub fn stop(mut self, grace: Duration) -> Result<(), CliError> {
        match crate::run::stop_supervisor(&mut self.child, grace) {
            Some(s) if s.success() => Ok(()),
            Some(s) => Err(CliError::Failed(format!("logger exited with {s}"))),
            None => Err(CliError::Failed("logger did not stop".into())),
        }
    }
}
