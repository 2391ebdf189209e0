//! `ld60-driver`: the base driver. At 50 Hz (default) it reads the base velocity command,
//! safe-stop and the hardware state; it sends the hardware a base velocity command that never
//! exceeds the base's speed and acceleration limits (ramping to zero when the command goes
//! stale or safe-stop is raised), and re-publishes odometry.
//!
//! Backends: `sim` (sim-world's `motm/v1/hw/base_*` services); `arnl`, an Omron LD-60 over
//! ArNetworking (`--host`, ports and speeds from `config/bases/ld60.toml`); `can`, an AgileX
//! base (`--can-interface`, settings from `config/bases/scout.toml`). The real backends' loop
//! is `motm_ld60_driver::base`; the set-up is `motm_ld60_driver::service::run_base_driver`.

use std::process::ExitCode;

use clap::Parser;
use motm_ld60_driver::service::{BaseDriverArgs, run_base_driver};

/// The base driver: base velocity commands and odometry.
#[derive(Parser)]
#[command(name = "ld60-driver", version, about)]
struct Cli {
    #[command(flatten)]
    args: BaseDriverArgs,
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    run_base_driver(&Cli::parse().args)
}
