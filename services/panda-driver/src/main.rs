//! `panda-driver`: the arm driver. At 1 kHz it reads the joint velocity command, the gripper
//! command, safe-stop and the hardware state; it sends the hardware a joint velocity command
//! that never exceeds the arm's velocity, acceleration and jerk limits (ramping to zero when
//! the command goes stale or safe-stop is raised), forwards gripper commands of the active
//! controller, and re-publishes joint and gripper state. The logic is the arm driver task
//! (`motm_tasks::driver::ArmDriverTask`) on every backend; the set-up is
//! `motm_driver::arm::run_arm_driver`.
//!
//! `--backend sim` (default): the task on the runtime (`motm_runtime::serve`, graph row
//! `panda-driver`), its hardware sim-world's `motm/v1/hw/*` topics.
//! `--backend fci --robot-ip IP [--fci-port P --hand-port P]`: the Franka Panda over FCI and
//! the Franka Hand (or `fake-panda`), the task stepped on the robot's 1 kHz states; see
//! `motm_driver::fci`.

use std::process::ExitCode;

use clap::Parser;
use motm_driver::arm::{ArmDriverArgs, run_arm_driver};

/// The arm driver: joint velocity commands, gripper, joint and gripper state.
#[derive(Parser)]
#[command(name = "panda-driver", version, about)]
struct Cli {
    #[command(flatten)]
    args: ArmDriverArgs,
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    run_arm_driver(&Cli::parse().args)
}
