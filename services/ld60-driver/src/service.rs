//! The base driver process (`ld60-driver`): its flags ([`BaseDriverArgs`]) and its set-up
//! ([`run_base_driver`]): the base driver task (`motm_tasks::driver::BaseDriverTask`) on the
//! `sim` backend (`motm_runtime::serve`, graph row `ld60-driver`), or in the real bases' loop
//! ([`crate::base`]) on `arnl` (an Omron LD-60, [`crate::arnl`]) or `can` (an AgileX base,
//! [`crate::can`]), with the settings of `<config>/bases/*.toml` ([`crate::config`]).

use std::process::ExitCode;
use std::time::Duration;

use motm_bus::Bus;
use motm_core::resolve_config_dir;
use motm_driver::{Backend, DriverArgs, EXIT_BAD_INPUT, EXIT_FAILED, loop_config};
use motm_graph::LD60_DRIVER;
use motm_tasks::driver::{BaseDriverTask, base_axes};

use crate::arnl::ArnlBase;
use crate::base::{BaseHardware, BaseLoop, run_base};
use crate::can;
use crate::config::BaseConfig;

/// Every flag of the base driver: the drivers' common ones and the real backends'.
#[derive(Debug, Clone, clap::Args)]
pub struct BaseDriverArgs {
    /// The flags common to both drivers.
    #[command(flatten)]
    pub driver: DriverArgs,
    /// Base hardware settings: a name in `<config>/bases/` or a file (default: `ld60` for
    /// `arnl`, `scout` for `can`).
    #[arg(long)]
    pub base_config: Option<String>,
    /// `arnl`: the robot's address.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// `arnl`: ArNetworking port (default: the base config's).
    #[arg(long)]
    pub port: Option<u16>,
    /// `arnl`: ARCL port, 0 to not watch ARCL (default: the base config's).
    #[arg(long)]
    pub arcl_port: Option<u16>,
    /// `arnl`: updateNumbers request interval, ms (default: the base config's).
    #[arg(long)]
    pub update_interval_ms: Option<i32>,
    /// `can`: CAN interface (default: the base config's).
    #[arg(long)]
    pub can_interface: Option<String>,
}

/// Runs the base driver as `flags` say until it is stopped, and returns the process's exit
/// code (its closing line printed): bad flags, config or robot model exit with
/// [`EXIT_BAD_INPUT`], a failure at run time with [`EXIT_FAILED`].
pub fn run_base_driver(flags: &BaseDriverArgs) -> ExitCode {
    match run(flags) {
        Ok(code) => code,
        Err(e) => motm_driver::exit("ld60-driver", Err(e)),
    }
}

fn run(cli: &BaseDriverArgs) -> Result<ExitCode, (u8, String)> {
    let args = &cli.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    let (_, driver, period) = args.prepare(&LD60_DRIVER, base_axes).map_err(bad)?;
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
