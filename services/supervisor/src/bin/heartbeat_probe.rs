//! `heartbeat-probe`: the smallest motm process. It opens the bus under `--name`, runs a
//! service loop at `--rate` and publishes heartbeats until SIGTERM/SIGINT. Used to test the
//! supervisor's process management without the robot stack.

use std::process::ExitCode;

use clap::Parser;
use motm_bus::{Bus, Flow, LoopConfig, ServiceLoop};

/// A process that only heartbeats.
#[derive(Parser)]
struct Args {
    /// Process (node and heartbeat) name.
    #[arg(long)]
    name: String,
    /// Cycle rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
    /// Exit with code 3 after this many cycles (simulates a crash).
    #[arg(long)]
    exit_after: Option<u64>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    if !(args.rate.is_finite() && args.rate > 0.0) {
        motm_bus::say!(
            "heartbeat-probe: --rate must be a finite number > 0, got {}",
            args.rate
        );
        return ExitCode::from(2);
    }
    let run = || -> Result<bool, motm_bus::BusError> {
        let bus = Bus::open(&args.name)?;
        let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(args.rate))?;
        let mut crashed = false;
        service.run_periodic(|cycle| {
            if args.exit_after.is_some_and(|n| cycle.cycle + 1 >= n) {
                crashed = true;
                return Flow::Stop;
            }
            Flow::Continue
        })?;
        Ok(crashed)
    };
    match run() {
        Ok(false) => ExitCode::SUCCESS,
        Ok(true) => ExitCode::from(3),
        Err(e) => {
            motm_bus::say!("heartbeat-probe {}: {e}", args.name);
            ExitCode::FAILURE
        }
    }
}
