//! The arm driver process (`panda-driver`): its flags ([`ArmDriverArgs`]) and its set-up
//! ([`run_arm_driver`]): the arm driver task (`motm_tasks::driver::ArmDriverTask`) on the
//! `sim` backend (`motm_runtime::serve`, graph row `panda-driver`) or on the `fci` backend
//! (the Franka Panda and Hand, [`crate::fci`]).

use std::process::ExitCode;

use motm_graph::PANDA_DRIVER;
use motm_tasks::driver::{ArmDriverTask, BaseBraking, arm_axes};

use crate::fci::FciArgs;
use crate::{Backend, DriverArgs, EXIT_BAD_INPUT, EXIT_FAILED, loop_config};

/// Every flag of the arm driver: the drivers' common ones and the `fci` backend's.
#[derive(Debug, Clone, clap::Args)]
pub struct ArmDriverArgs {
    /// The flags common to both drivers.
    #[command(flatten)]
    pub driver: DriverArgs,
    /// The `fci` backend's flags.
    #[command(flatten)]
    pub fci: FciArgs,
}

/// Runs the arm driver as `flags` say until it is stopped, and returns the process's exit code
/// (its closing line printed): bad flags, config or robot model exit with
/// [`EXIT_BAD_INPUT`], a failure at run time with [`EXIT_FAILED`].
pub fn run_arm_driver(flags: &ArmDriverArgs) -> ExitCode {
    let args = &flags.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    let setup = args
        .prepare(&PANDA_DRIVER, arm_axes)
        .and_then(|(robot, driver, period)| {
            Ok((
                driver,
                BaseBraking::of(&robot),
                period,
                args.connect_wait()?,
            ))
        });
    let (driver, braking, period, wait) = match setup {
        Ok(setup) => setup,
        Err(e) => return crate::exit("panda-driver", Err(bad(e))),
    };
    let mut task = ArmDriverTask::new(driver, braking, args.status_every(period));
    let result = match args.backend {
        Backend::Sim => {
            return motm_runtime::serve(&PANDA_DRIVER, &mut task, loop_config(period), |t| {
                crate::details(&t.counters())
            });
        }
        Backend::Fci => motm_bus::Bus::open(PANDA_DRIVER.name)
            .map_err(|e| (EXIT_FAILED, e.to_string()))
            .and_then(|bus| crate::fci::run_fci(&bus, task, wait, &flags.fci)),
        Backend::Arnl | Backend::Can => Err(bad(format!(
            "--backend {}: a base backend; the arm driver takes sim or fci",
            args.backend.name()
        ))),
    };
    crate::exit("panda-driver", result)
}
