//! `sim-world`: the simulated hardware ([`motm_sim::task::SimWorldTask`]) as a process. It
//! steps the world in real time at the physics rate (1 kHz) from the newest hardware commands
//! of the drivers, and publishes the arm, base and gripper state every step, palm-camera
//! images at the camera rate (stamped with their exposure time, carrying their publication
//! time) and the ground truth. The flags are [`args::SimWorldArgs`].

use std::process::ExitCode;

use args::SimWorldArgs;

mod args;

fn main() -> ExitCode {
    let args: SimWorldArgs = motm_wire::parse("sim-world", "The simulated hardware");
    let (mut task, timing) = match args.build() {
        Ok(built) => built,
        Err(e) => {
            motm_bus::say!("sim-world: {e}");
            return ExitCode::from(motm_wire::serve::EXIT_BAD_INPUT);
        }
    };
    motm_runtime::serve(&motm_graph::SIM_WORLD, &mut task, timing, |task| {
        format!("{} s simulated", task.sim().truth().time)
    })
}
