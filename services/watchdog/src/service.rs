//! `watchdog`: watches the heartbeats of the stack's control-path processes and the two
//! command streams of the QP resolver, and publishes `SAFETY_SAFE_STOP` every cycle: raised
//! while any of them is stale or a process reports new deadline misses (the decision is
//! [`motm_core::watchdog::Watchdog`]), cleared when all is well again. A task and its hot
//! standby (the QP resolver's) count as one redundant source.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use motm_bus::{Bus, BusError, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::watchdog::{SafetyFault, SourceKind, Watchdog};
use motm_msgs::{
    ArmVelocityCommand, BaseVelocityCommand, Heartbeat, Message, SafeStop, SafeStopReason, services,
};
use motm_stack::StackConfig;

/// Exit code for bad input (a bad file, key or value).
const EXIT_BAD_INPUT: u8 = 2;

/// Raises safe-stop when the control path stalls.
#[derive(Parser)]
#[command(name = "watchdog")]
struct Args {
    /// Stack config file, or a name in the config folder (e.g. `frankie`): which processes
    /// are on the control path, and the watchdog settings.
    #[arg(long, default_value = "frankie")]
    stack: String,
    /// Config folder (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// Cycle rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Control rate, Hz: the command streams' period (default: the stack's `control_rate_hz`).
    #[arg(long)]
    control_rate: Option<f64>,
    /// Unused (every service takes a seed).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// What the watchdog watches: the names of the heartbeats and the control period.
struct Watched {
    stack: StackConfig,
    heartbeats: Vec<String>,
    control_period_ns: u64,
}

fn watched(args: &Args) -> Result<Watched, String> {
    let dir = motm_core::resolve_config_dir(args.config_dir.as_deref());
    let stack = StackConfig::from_file(&StackConfig::resolve(&dir, &args.stack))
        .map_err(|e| e.to_string())?;
    for (flag, rate) in [
        ("--rate", Some(args.rate)),
        ("--control-rate", args.control_rate),
    ] {
        if let Some(rate) = rate
            && !(rate.is_finite() && rate > 0.0)
        {
            return Err(format!("{flag} must be a finite number > 0, got {rate}"));
        }
    }
    let control_rate = args.control_rate.unwrap_or(stack.control_rate_hz);
    let heartbeats = stack
        .processes
        .iter()
        .filter(|p| p.control_path())
        .map(|p| p.name.clone())
        .collect();
    Ok(Watched {
        stack,
        heartbeats,
        control_period_ns: (1e9 / control_rate) as u64,
    })
}

/// The reason code and the name of the source at fault.
fn describe(fault: SafetyFault, names: &[String]) -> (SafeStopReason, String) {
    let (reason, index) = match fault {
        SafetyFault::HeartbeatLost(i) => (SafeStopReason::HeartbeatLost, i),
        SafetyFault::StaleCommand(i) => (SafeStopReason::StaleCommand, i),
        SafetyFault::DeadlineMiss(i) => (SafeStopReason::DeadlineMiss, i),
        SafetyFault::Starting(i) => (SafeStopReason::Starting, i),
    };
    (reason, names.get(index).cloned().unwrap_or_default())
}

fn run(args: &Args, watched: Watched) -> Result<(), BusError> {
    let bus = Bus::open("watchdog")?;
    let qos = Qos::default();
    let mut heartbeats = watched
        .heartbeats
        .iter()
        .map(|name| Latest::<Heartbeat>::new(&bus, &services::heartbeat(name), &qos))
        .collect::<Result<Vec<_>, _>>()?;
    let mut arm = Latest::<ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &qos)?;
    let mut base = Latest::<BaseVelocityCommand>::new(&bus, services::BASE_VELOCITY_COMMAND, &qos)?;
    let mut safe_stop = Publisher::<SafeStop>::new(&bus, services::SAFETY_SAFE_STOP, &qos)?;

    // Sources: the heartbeats, then the arm and base command streams.
    let mut names = watched.heartbeats.clone();
    names.push(services::ARM_VELOCITY_COMMAND.to_string());
    names.push(services::BASE_VELOCITY_COMMAND.to_string());
    let mut kinds = vec![SourceKind::Heartbeat; heartbeats.len()];
    let command = SourceKind::Command {
        period_ns: watched.control_period_ns,
    };
    kinds.extend([command, command]);
    let mut watchdog = Watchdog::new(watched.stack.watchdog, &kinds);
    // A task and its hot standbys are one redundant source.
    for (index, name) in watched.heartbeats.iter().enumerate() {
        let mut group = vec![index];
        group.extend(
            motm_graph::standbys_of(name)
                .filter_map(|standby| watched.heartbeats.iter().position(|n| n == standby.name)),
        );
        if group.len() > 1 {
            watchdog.redundant(&group);
        }
    }
    let arm_index = heartbeats.len();

    let mut last: Option<(SafeStopReason, String)> = None;
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(args.rate))?;
    service.run_periodic(|cycle| {
        let now = cycle.now_ns;
        for (index, beat) in heartbeats.iter_mut().enumerate() {
            if beat.update().unwrap_or(false)
                && let Some(b) = beat.get()
            {
                watchdog.heartbeat(index, b.header.stamp_ns, b.cycles, b.deadline_misses, now);
            }
        }
        if arm.update().unwrap_or(false)
            && let Some(c) = arm.get()
        {
            watchdog.command(arm_index, c.header.stamp_ns);
        }
        if base.update().unwrap_or(false)
            && let Some(c) = base.get()
        {
            watchdog.command(arm_index + 1, c.header.stamp_ns);
        }
        let verdict = watchdog.verdict(now).map(|fault| describe(fault, &names));
        let mut message = SafeStop::zeroed();
        message.active = u32::from(verdict.is_some());
        message.reason = verdict
            .as_ref()
            .map_or(SafeStopReason::None, |(reason, _)| *reason)
            .into();
        // A failed publish shows up downstream as a stale safe-stop stream.
        let _ = safe_stop.publish(message);
        // Start-up holds change source as processes come up: only their end is worth a line.
        let kind = |v: &Option<(SafeStopReason, String)>| v.as_ref().map(|(reason, _)| *reason);
        let starting = kind(&verdict) == Some(SafeStopReason::Starting);
        if verdict != last && !(starting && kind(&last) == Some(SafeStopReason::Starting)) {
            match &verdict {
                Some((SafeStopReason::Starting, source)) => {
                    motm_bus::say!("watchdog: holding safe-stop until {source} is up");
                }
                Some((reason, source)) => {
                    motm_bus::say!("watchdog: safe-stop raised: {reason:?} ({source})");
                }
                None if kind(&last) == Some(SafeStopReason::Starting) => {
                    motm_bus::say!("watchdog: the control path is up; safe-stop cleared");
                }
                None => motm_bus::say!("watchdog: safe-stop cleared"),
            }
        }
        last = verdict;
        Flow::Continue
    })?;
    Ok(())
}

/// The `watchdog` process: parses its flags, runs until stopped, and returns its exit status.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let watched = match watched(&args) {
        Ok(w) => w,
        Err(e) => {
            motm_bus::say!("watchdog: {e}");
            return ExitCode::from(EXIT_BAD_INPUT);
        }
    };
    match run(&args, watched) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            motm_bus::say!("watchdog: {e}");
            ExitCode::FAILURE
        }
    }
}
