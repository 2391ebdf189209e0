//! `ld60-driver`: the base driver. At 50 Hz (default) it reads the base velocity command,
//! safe-stop and the hardware state; it sends the hardware a base velocity command that never
//! exceeds the base's speed and acceleration limits (ramping to zero when the command goes
//! stale or safe-stop is raised), and re-publishes odometry.
//!
//! Backends: `sim` (sim-world's `motm/v1/hw/base_*` services); `arnl`, an Omron LD-60 over
//! ArNetworking (`--host`, ports and speeds from `config/bases/ld60.toml`); `can`, an AgileX
//! base (`--can-interface`, settings from `config/bases/scout.toml`). The real backends' loop
//! is `motm_ld60_driver::base`.

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_bus::Bus;
use motm_core::resolve_config_dir;
use motm_driver::{Backend, DriverArgs, EXIT_BAD_INPUT, EXIT_FAILED, loop_config};
use motm_graph::LD60_DRIVER;
use motm_ld60_driver::arnl::ArnlBase;
use motm_ld60_driver::base::{BaseHardware, BaseLoop, run_base};
use motm_ld60_driver::can;
use motm_ld60_driver::config::BaseConfig;
use motm_tasks::driver::{BaseDriverTask, base_axes};

/// The base driver: base velocity commands and odometry.
#[derive(Parser)]
#[command(name = "ld60-driver", version, about)]
struct Cli {
    #[command(flatten)]
    driver: DriverArgs,
    /// Base hardware settings: a name in `<config>/bases/` or a file (default: `ld60` for
    /// `arnl`, `scout` for `can`).
    #[arg(long)]
    base_config: Option<String>,
    /// `arnl`: the robot's address.
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// `arnl`: ArNetworking port (default: the base config's).
    #[arg(long)]
    port: Option<u16>,
    /// `arnl`: ARCL port, 0 to not watch ARCL (default: the base config's).
    #[arg(long)]
    arcl_port: Option<u16>,
    /// `arnl`: updateNumbers request interval, ms (default: the base config's).
    #[arg(long)]
    update_interval_ms: Option<i32>,
    /// `can`: CAN interface (default: the base config's).
    #[arg(long)]
    can_interface: Option<String>,
}

fn run(cli: Cli) -> Result<ExitCode, (u8, String)> {
    let args = &cli.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    args.apply_priority(LD60_DRIVER.name).map_err(bad)?;
    let robot = args.load_robot().map_err(bad)?;
    let period = args
        .period(LD60_DRIVER.rate.hz(args.control_rate))
        .map_err(bad)?;
    let driver = args.driver(base_axes(&robot), period).map_err(bad)?;
    let status_every = args.status_every(period);
    let failed = |e: motm_bus::BusError| (EXIT_FAILED, e.to_string());
    if args.backend == Backend::Sim {
        let mut task = BaseDriverTask::new(driver, status_every);
        return Ok(motm_runtime::serve(
            &LD60_DRIVER,
            &mut task,
            loop_config(period),
            |t| motm_driver::details(&t.counters()),
        ));
    }
    let base = |default: &str| {
        let dir = resolve_config_dir(args.config_dir.as_deref());
        let name = cli.base_config.as_deref().unwrap_or(default);
        BaseConfig::from_file(&BaseConfig::path(&dir, name)).map_err(bad)
    };
    let missing = |section: &str| bad(format!("--base-config: the base config has no [{section}]"));
    let serve = |hardware, stale_ms: f64| {
        let stale = Duration::from_secs_f64(stale_ms * 1e-3);
        let bus = Bus::open(LD60_DRIVER.name).map_err(failed)?;
        run_base(
            &bus,
            BaseLoop::new(hardware, driver, status_every, stale),
            period,
        )
        .map(drop)
        .map_err(failed)
    };
    match args.backend {
        Backend::Arnl => {
            let mut a = base("ld60")?.arnl.ok_or_else(|| missing("arnl"))?;
            match cli.update_interval_ms {
                Some(ms) if ms <= 0 => {
                    return Err(bad(format!("--update-interval-ms: must be > 0, got {ms}")));
                }
                Some(ms) => a.update_interval_ms = ms,
                None => {}
            }
            let wait = args.connect_wait().map_err(bad)?;
            let hardware = ArnlBase::open(&a, &cli.host, cli.port, cli.arcl_port, wait)
                .map_err(|e| (EXIT_FAILED, e))?;
            serve(
                Box::new(hardware) as Box<dyn BaseHardware>,
                a.odometry_stale_ms,
            )
            .map(|()| ExitCode::SUCCESS)
        }
        Backend::Can => {
            let c = base("scout")?.can.ok_or_else(|| missing("can"))?;
            let hardware = can::open(&c, cli.can_interface.as_deref())?;
            serve(Box::new(hardware), c.feedback_timeout_ms).map(|()| ExitCode::SUCCESS)
        }
        Backend::Sim | Backend::Fci => Err(bad(
            "--backend fci: the Franka arm's backend; the base driver takes sim, arnl or can"
                .into(),
        )),
    }
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => motm_driver::exit("ld60-driver", Err(e)),
    }
}
