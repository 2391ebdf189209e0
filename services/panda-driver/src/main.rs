//! `panda-driver`: the arm driver. At 1 kHz it reads the joint velocity command, the gripper
//! command, safe-stop and the hardware state; it sends the hardware a joint velocity command
//! that never exceeds the arm's velocity, acceleration and jerk limits (ramping to zero when
//! the command goes stale or safe-stop is raised), forwards gripper commands of the active
//! controller, and re-publishes joint and gripper state. The logic is the arm driver task
//! (`motm_tasks::driver::ArmDriverTask`) on every backend.
//!
//! `--backend sim` (default): the task on the runtime (`motm_runtime::serve`, graph row
//! `panda-driver`), its hardware sim-world's `motm/v1/hw/*` topics.
//! `--backend fci --robot-ip IP [--fci-port P --hand-port P]`: the Franka Panda over FCI and
//! the Franka Hand (or `fake-panda`), the task stepped on the robot's 1 kHz states; see
//! `motm_driver::fci`.

use std::process::ExitCode;

use clap::Parser;
use motm_driver::fci::FciArgs;
use motm_driver::{Backend, DriverArgs, EXIT_BAD_INPUT, EXIT_FAILED, loop_config};
use motm_graph::PANDA_DRIVER;
use motm_tasks::driver::{ArmDriverTask, BaseBraking, arm_axes};

/// The arm driver: joint velocity commands, gripper, joint and gripper state.
#[derive(Parser)]
#[command(name = "panda-driver", version, about)]
struct Cli {
    #[command(flatten)]
    driver: DriverArgs,
    #[command(flatten)]
    fci: FciArgs,
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    let args = &cli.driver;
    let bad = |e: String| (EXIT_BAD_INPUT, e);
    let setup = args
        .apply_priority(PANDA_DRIVER.name)
        .and_then(|()| args.load_robot())
        .and_then(|robot| {
            let period = args.period(PANDA_DRIVER.rate.hz(args.control_rate))?;
            Ok((
                args.driver(arm_axes(&robot), period)?,
                BaseBraking::of(&robot),
                period,
                args.connect_wait()?,
            ))
        });
    let (driver, braking, period, wait) = match setup {
        Ok(setup) => setup,
        Err(e) => return motm_driver::exit("panda-driver", Err(bad(e))),
    };
    let mut task = ArmDriverTask::new(driver, braking, args.status_every(period));
    let result = match args.backend {
        Backend::Sim => {
            return motm_runtime::serve(&PANDA_DRIVER, &mut task, loop_config(period), |t| {
                motm_driver::details(&t.counters())
            });
        }
        Backend::Fci => motm_bus::Bus::open(PANDA_DRIVER.name)
            .map_err(|e| (EXIT_FAILED, e.to_string()))
            .and_then(|bus| motm_driver::fci::run_fci(&bus, task, wait, &cli.fci)),
        Backend::Arnl | Backend::Can => Err(bad(format!(
            "--backend {}: a base backend; the arm driver takes sim or fci",
            args.backend.name()
        ))),
    };
    motm_driver::exit("panda-driver", result)
}
