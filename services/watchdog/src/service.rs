//! `watchdog`: runs the watchdog task ([`motm_tasks::watchdog`]) over the control-path
//! processes of the stack config, at `--rate` on its own timer.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use motm_bus::LoopConfig;
use motm_stack::StackConfig;
use motm_tasks::watchdog::WatchdogTask;

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

/// The watchdog task of the stack and the flags: the control-path processes the stack runs,
/// its watchdog settings and the control period.
fn task(args: &Args) -> Result<WatchdogTask, String> {
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
    Ok(WatchdogTask::new(
        stack.watchdog,
        stack.processes.iter().map(|p| p.name.as_str()),
        (1e9 / control_rate) as u64,
    ))
}

/// The `watchdog` process: parses its flags, runs until stopped, and returns its exit status.
pub fn main() -> ExitCode {
    let args = Args::parse();
    match task(&args) {
        Ok(mut task) => motm_runtime::serve(
            &motm_graph::WATCHDOG,
            &mut task,
            LoopConfig::with_rate(args.rate),
            |task| format!("watched {}", task.sources().join(", ")),
        ),
        Err(e) => {
            motm_bus::say!("watchdog: {e}");
            ExitCode::from(EXIT_BAD_INPUT)
        }
    }
}
