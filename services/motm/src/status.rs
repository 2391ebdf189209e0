//! `motm status`: the live process table of a running stack, from the supervisor's table and
//! every process's heartbeat: pid, state, restarts, rate, cycles, deadline misses, p99 cycle
//! time and the age of the last deadline miss.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use motm_bus::{Bus, IpcConfig, Latest, Qos};
use motm_msgs::{Heartbeat, SupervisedState, SupervisorStatus, services};
use serde::Serialize;

use crate::CliError;
use crate::run::registry_dir;

/// Arguments of `motm status`.
#[derive(Args, Debug)]
pub struct StatusArgs {
    /// iceoryx2 prefix of the stack (default: $MOTM_IPC_PREFIX, else the one running `motm run`).
    #[arg(long)]
    pub prefix: Option<String>,
    /// How long to wait for the supervisor's table, ms.
    #[arg(long, default_value_t = 1000)]
    pub wait_ms: u64,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// One row of the status table.
#[derive(Debug, Clone, Serialize)]
pub struct StatusRow {
    /// Process name.
    pub name: String,
    /// Pid (0 when not running).
    pub pid: u32,
    /// Supervisor's view: pending, running, restarting, failed, stopped; outside its table,
    /// running (a heartbeat was heard) or missing.
    pub state: String,
    /// Restarts so far.
    pub restarts: u32,
    /// Configured cycle rate from the heartbeat, Hz (0 for event-driven or no heartbeat).
    pub rate_hz: f64,
    /// Cycles of the current instance.
    pub cycles: u64,
    /// Deadline misses of the current instance.
    pub deadline_misses: u64,
    /// 99th percentile cycle time, µs.
    pub p99_cycle_us: f64,
    /// Seconds since the last deadline miss (`None` when there was none).
    pub last_miss_s_ago: Option<f64>,
    /// Seconds since the last heartbeat (`None` when none was received).
    pub heartbeat_age_s: Option<f64>,
}

/// The prefix to look at: flag, environment, or the single running `motm run`.
fn prefix(args: &StatusArgs) -> Result<String, CliError> {
    stack_prefix(args.prefix.clone())
}

/// The iceoryx2 prefix of the stack to talk to: `explicit` (a `--prefix` flag), else
/// `$MOTM_IPC_PREFIX`, else the one stack that `motm run` is running, else the deployed stack's
/// ([`motm_bus::DEPLOYED_PREFIX`], which systemd's units set).
pub fn stack_prefix(explicit: Option<String>) -> Result<String, CliError> {
    if let Some(p) = explicit.or_else(|| std::env::var(motm_bus::PREFIX_ENV).ok()) {
        return Ok(p);
    }
    let live: Vec<String> = std::fs::read_dir(registry_dir())
        .into_iter()
        .flatten()
        .flatten()
        .filter(|entry| {
            std::fs::read_to_string(entry.path())
                .ok()
                .and_then(|pid| pid.trim().parse::<u32>().ok())
                .is_some_and(|pid| PathBuf::from(format!("/proc/{pid}")).exists())
        })
        .map(|entry| entry.file_name().to_string_lossy().into_owned())
        .collect();
    match live.as_slice() {
        [one] => Ok(one.clone()),
        [] => Ok(motm_bus::DEPLOYED_PREFIX.to_owned()),
        many => Err(CliError::BadInput(format!(
            "several stacks are running ({}); choose one with --prefix",
            many.join(", ")
        ))),
    }
}

/// The processes `motm status` shows, given the names in the supervisor's table: the graph's
/// processes that run on the robot (not simulation-only) or that the table lists, in the
/// graph's order; then the table's other processes (a hardware stand-in, say), in its order;
/// then the supervisor.
fn expected_processes(table: &[&str]) -> Vec<String> {
    let mut names: Vec<String> = motm_graph::processes()
        .filter(|t| !t.sim_only || table.contains(&t.name))
        .map(|t| t.name.to_owned())
        .collect();
    for name in table {
        if !names.iter().any(|n| n == name) {
            names.push((*name).to_owned());
        }
    }
    names.push("supervisor".into());
    names
}

fn state_name(state: Option<SupervisedState>) -> &'static str {
    match state {
        Some(SupervisedState::Pending) => "pending",
        Some(SupervisedState::Running) => "running",
        Some(SupervisedState::Restarting) => "restarting",
        Some(SupervisedState::Failed) => "failed",
        Some(SupervisedState::Stopped) => "stopped",
        None => "unknown",
    }
}

/// The folder of the iceoryx2 config that points iceoryx2's own `iox2` tools at `ipc`'s
/// prefix: `iox2` 0.10 has no flag or environment variable for a config file and reads
/// `./config/iceoryx2.toml` from its working directory first, so `cd` there and run
/// `iox2 service list`, `iox2 node list` or `iox2 service hz SERVICE`.
pub fn iox2_dir(ipc: &IpcConfig) -> PathBuf {
    std::env::temp_dir().join("motm-iox2").join(&ipc.prefix)
}

/// Writes `<iox2_dir>/config/iceoryx2.toml`: the processes' iceoryx2 config (the file of
/// `$MOTM_ICEORYX2_CONFIG`, or iceoryx2's own lookup) with `ipc`'s prefix. Returns the folder.
pub fn write_iox2_config(ipc: &IpcConfig) -> Result<PathBuf, String> {
    let config = ipc.iceoryx2().map_err(|e| e.to_string())?;
    let text = toml::to_string(&config).map_err(|e| format!("iceoryx2 config: {e}"))?;
    let dir = iox2_dir(ipc);
    let file = dir.join("config").join("iceoryx2.toml");
    std::fs::create_dir_all(dir.join("config"))
        .and_then(|()| std::fs::write(&file, text))
        .map_err(|e| format!("{}: {e}", file.display()))?;
    Ok(dir)
}

/// `motm status`.
pub fn run(args: &StatusArgs) -> Result<(), CliError> {
    let ipc = IpcConfig {
        prefix: prefix(args)?,
    };
    let failed = |e: motm_bus::BusError| CliError::Failed(e.to_string());
    let bus =
        Bus::open_with(&format!("motm-status-{}", std::process::id()), &ipc).map_err(failed)?;
    let qos = Qos::default();
    let mut table =
        Latest::<SupervisorStatus>::new(&bus, services::SUPERVISOR_STATUS, &qos).map_err(failed)?;
    let start = Instant::now();
    let wait = Duration::from_millis(args.wait_ms);
    // A one-shot reader: poll briefly for the latest table (history delivers it on connect).
    while table.get().is_none() && start.elapsed() < wait {
        bus.update_connections();
        let _ = table.update();
        std::thread::sleep(Duration::from_millis(10));
    }
    let Some(status) = table.get().copied() else {
        return Err(CliError::Failed(format!(
            "no supervisor answers on prefix {} within {} ms",
            ipc.prefix, args.wait_ms
        )));
    };
    let table_names: Vec<&str> = status.processes().iter().map(|p| p.name()).collect();
    let names = expected_processes(&table_names);
    let mut beats = names
        .iter()
        .map(|n| Latest::<Heartbeat>::new(&bus, &services::heartbeat(n), &qos))
        .collect::<Result<Vec<_>, _>>()
        .map_err(failed)?;
    let beat_wait = Instant::now();
    while beats.iter().any(|b| b.get().is_none())
        && beat_wait.elapsed() < Duration::from_millis(300)
    {
        bus.update_connections();
        for b in &mut beats {
            let _ = b.update();
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let now = motm_bus::monotonic_now_ns();
    let rows: Vec<StatusRow> = names
        .iter()
        .zip(&beats)
        .map(|(name, beat)| {
            let row = status.processes().iter().find(|p| p.name() == name);
            let b = beat.get();
            StatusRow {
                name: name.clone(),
                pid: row.map_or_else(|| b.map_or(0, |b| b.pid), |r| r.pid),
                state: match (row, b) {
                    (Some(r), _) => state_name(r.state()).into(),
                    (None, Some(_)) => "running".into(),
                    (None, None) => "missing".into(),
                },
                restarts: row.map_or(0, |r| r.restarts),
                rate_hz: b
                    .filter(|b| b.period_ns > 0)
                    .map_or(0.0, |b| 1e9 / b.period_ns as f64),
                cycles: b.map_or(0, |b| b.cycles),
                deadline_misses: b.map_or(0, |b| b.deadline_misses),
                p99_cycle_us: b.map_or(0.0, |b| b.p99_cycle_ns as f64 / 1000.0),
                last_miss_s_ago: b
                    .filter(|b| b.last_deadline_miss_ns > 0)
                    .map(|b| now.saturating_sub(b.last_deadline_miss_ns) as f64 / 1e9),
                heartbeat_age_s: b.map(|b| now.saturating_sub(b.header.stamp_ns) as f64 / 1e9),
            }
        })
        .collect();
    let iox2 = write_iox2_config(&ipc).map_err(CliError::Failed)?;
    if args.json {
        let out = serde_json::json!({
            "ipc_prefix": ipc.prefix,
            "iox2_dir": iox2,
            "processes": rows,
        });
        println!("{out}");
    } else {
        println!(
            "stack on iceoryx2 prefix {} (iceoryx2's tools: cd {} && iox2 service list)",
            ipc.prefix,
            iox2.display()
        );
        println!(
            "{:<14} {:>8} {:<10} {:>8} {:>8} {:>9} {:>7} {:>8} {:>10}",
            "process",
            "pid",
            "state",
            "restarts",
            "rate Hz",
            "cycles",
            "misses",
            "p99 µs",
            "last miss"
        );
        for r in &rows {
            println!(
                "{:<14} {:>8} {:<10} {:>8} {:>8.0} {:>9} {:>7} {:>8.0} {:>10}",
                r.name,
                r.pid,
                r.state,
                r.restarts,
                r.rate_hz,
                r.cycles,
                r.deadline_misses,
                r.p99_cycle_us,
                r.last_miss_s_ago
                    .map_or_else(|| "-".to_string(), |s| format!("{s:.1} s ago"))
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expected_processes_are_the_graphs_with_the_tables_extras_and_the_supervisor() {
        let robot: Vec<&str> = motm_graph::processes()
            .filter(|t| !t.sim_only)
            .map(|t| t.name)
            .collect();
        // Under systemd the supervisor's table is empty: every robot process is still expected.
        let names = expected_processes(&[]);
        assert_eq!(names[..robot.len()], robot[..]);
        assert_eq!(names[robot.len()..], ["supervisor"]);
        assert!(!names.iter().any(|n| n == "sim-world"));
        // A simulated stack lists sim-world (in graph order) and a stand-in (after the graph's).
        let names = expected_processes(&["sim-world", "fake-ld60", "qp-resolver"]);
        assert_eq!(names[0], "sim-world");
        assert_eq!(names[1..=robot.len()], robot[..]);
        assert_eq!(names[robot.len() + 1..], ["fake-ld60", "supervisor"]);
    }
}

#[cfg(test)]
mod iox2_tests {
    use super::*;

    #[test]
    fn the_iox2_config_is_the_processes_config_with_the_stacks_prefix() {
        let ipc = IpcConfig {
            prefix: format!("motmiox2t{}_", std::process::id()),
        };
        let dir = write_iox2_config(&ipc).unwrap();
        let file = dir.join("config").join("iceoryx2.toml");
        // Read back as iceoryx2 reads it (the prefix forced to another value first).
        let other = IpcConfig {
            prefix: "other_".into(),
        };
        let mut read = other.iceoryx2_from(Some(&file)).unwrap();
        let text = std::fs::read_to_string(&file).unwrap();
        assert!(
            text.contains(&format!("prefix = \"{}\"", ipc.prefix)),
            "{text}"
        );
        read.global.prefix = ipc.iceoryx2().unwrap().global.prefix;
        assert_eq!(read, ipc.iceoryx2().unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
