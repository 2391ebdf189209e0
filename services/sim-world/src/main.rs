//! `sim-world`: the simulated hardware. It steps the world in real time at the physics rate
//! (1 kHz) on the service loop's timer, from the newest hardware commands of the drivers, and
//! publishes the arm, base and gripper state every step, palm-camera images at the camera rate
//! (written in place in shared memory) and the ground truth ([`motm_msgs::SimTruth`]).
//!
//! | reads | publishes |
//! | --- | --- |
//! | `HW_ARM_COMMAND`, `HW_BASE_COMMAND`, `HW_GRIPPER_COMMAND` | `HW_ARM_STATE`, `HW_BASE_STATE`, `HW_GRIPPER_STATE` (every step), `CAMERA_IMAGE` (30 Hz, `Qos::large()`, stamped with the exposure time), `SIM_TRUTH` (`--truth-rate`, and at once when the outcome is decided) |
//!
//! Real time: each cycle runs the physics steps due since the first cycle (normally one, up to
//! `--max-catch-up` after lost timer ticks; beyond that the simulation falls behind). A hardware
//! command older than `--command-timeout` is braked to zero within the robot's limits.
use motm_sim::messages as convert;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_bus::{Bus, BusError, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop, Stamp};
use motm_core::{BaseVelocity, Robot};
use motm_msgs::{
    ArmVelocityCommand, BaseOdometry, BaseVelocityCommand, CameraImage, GripperCommand,
    GripperState, JointState, SimTruth, services,
};
use motm_sim::Scenario;
use motm_sim::runner::RunnerConfig;
use motm_sim::scenario_path;
use motm_sim::sim_world::{HardwareInput, SimWorld, SimWorldConfig};
use motm_wire::setup::resolve_config_dir;

/// Exit code for bad input (flags, scenario, robot model).
const EXIT_BAD_INPUT: u8 = 2;
/// Exit code for a failure at run time (the bus).
const EXIT_FAILED: u8 = 1;

/// The simulated hardware: world, palm camera and ground truth.
#[derive(Parser)]
#[command(name = "sim-world", version, about)]
struct Cli {
    /// Folder holding robots/ and scenarios/ (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// Scenario file (TOML), or the name of one in `<config>/scenarios/`.
    #[arg(long, default_value = "exp1-dynamic")]
    scenario: String,
    /// Robot model; must be the scenario's (default: the scenario's).
    #[arg(long)]
    robot: Option<String>,
    /// Base speed, m/s (overrides the scenario's `base_speed`).
    #[arg(long)]
    base_speed: Option<f64>,
    /// Trial seed (as `motm trial --seed`); perception must get the same one, since the camera
    /// calibration error is drawn from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Physics rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Control rate of the stack, Hz: the EE acceleration metric is sampled at it, as in the
    /// in-process runner.
    #[arg(long, default_value_t = 200.0)]
    control_rate: f64,
    /// Rate of the ground-truth messages, Hz (a decided outcome is published at once).
    #[arg(long, default_value_t = 100.0)]
    truth_rate: f64,
    /// A hardware velocity command older than this is replaced by zero, s.
    #[arg(long, default_value_t = SimWorldConfig::default().command_timeout)]
    command_timeout: f64,
    /// Most physics steps one cycle may run to catch up on lost timer ticks (beyond that the
    /// simulation falls behind real time).
    #[arg(long, default_value_t = 10)]
    max_catch_up: u64,
}

/// Builds the world from the flags; every error is bad input.
fn setup(cli: &Cli) -> Result<SimWorld, String> {
    let config_dir = resolve_config_dir(cli.config_dir.as_deref());
    let path = scenario_path(&config_dir, &cli.scenario);
    let mut scenario = Scenario::from_file(&path).map_err(|e| e.to_string())?;
    if let Some(v) = cli.base_speed {
        scenario.set_base_speed(v).map_err(|e| e.to_string())?;
    }
    if let Some(robot) = &cli.robot
        && robot != &scenario.robot
    {
        return Err(format!(
            "--robot {robot}: the scenario {} is for robot '{}'",
            path.display(),
            scenario.robot
        ));
    }
    let robot = Robot::load(&config_dir, &scenario.robot).map_err(|e| e.to_string())?;
    for (flag, rate) in [
        ("--rate", cli.rate),
        ("--control-rate", cli.control_rate),
        ("--truth-rate", cli.truth_rate),
    ] {
        if !(rate.is_finite() && rate > 0.0) {
            return Err(format!("{flag}: must be a positive rate in Hz, got {rate}"));
        }
    }
    if !(cli.command_timeout.is_finite() && cli.command_timeout > 0.0) {
        return Err(format!(
            "--command-timeout: must be positive, got {}",
            cli.command_timeout
        ));
    }
    let runner = RunnerConfig {
        physics_step: 1.0 / cli.rate,
        control_rate_hz: cli.control_rate,
        ..RunnerConfig::default()
    };
    let config = SimWorldConfig {
        command_timeout: cli.command_timeout,
    };
    SimWorld::new(&robot, &scenario, cli.seed, &runner, config).map_err(|e| e.to_string())
}

/// Age of a message stamped `stamp_ns` at `now_ns`, s.
fn age(now_ns: u64, stamp_ns: u64) -> f64 {
    now_ns.saturating_sub(stamp_ns) as f64 * 1e-9
}

fn serve(cli: &Cli, mut sim: SimWorld) -> Result<(), BusError> {
    let bus = Bus::open("sim-world")?;
    let qos = Qos::default();
    let mut arm_in = Latest::<ArmVelocityCommand>::new(&bus, services::HW_ARM_COMMAND, &qos)?;
    let mut base_in = Latest::<BaseVelocityCommand>::new(&bus, services::HW_BASE_COMMAND, &qos)?;
    let mut gripper_in = Latest::<GripperCommand>::new(&bus, services::HW_GRIPPER_COMMAND, &qos)?;
    let mut arm_out = Publisher::<JointState>::new(&bus, services::HW_ARM_STATE, &qos)?;
    let mut base_out = Publisher::<BaseOdometry>::new(&bus, services::HW_BASE_STATE, &qos)?;
    let mut gripper_out = Publisher::<GripperState>::new(&bus, services::HW_GRIPPER_STATE, &qos)?;
    let mut camera_out =
        Publisher::<CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large().waking())?;
    let mut truth_out = Publisher::<SimTruth>::new(&bus, services::SIM_TRUTH, &qos)?;
    let period = Duration::from_secs_f64(sim.physics_step());
    let period_ns = period.as_nanos() as u64;
    let truth_every = ((1.0 / cli.truth_rate) / sim.physics_step())
        .round()
        .max(1.0) as u64;
    let mut service = ServiceLoop::new(
        &bus,
        LoopConfig {
            period,
            ..LoopConfig::default()
        },
    )?;
    let mut origin_ns = None;
    let mut steps_done = 0u64;
    let mut catch_up_cycles = 0u64;
    let mut last_status = sim.status();
    let mut arm_qd = Vec::with_capacity(sim.command().arm_qd.len());
    let report = |e: BusError| eprintln!("sim-world: {e}");
    service.run_periodic(|cycle| {
        let now = cycle.now_ns;
        let origin = *origin_ns.get_or_insert(now);
        arm_in.update().ok();
        base_in.update().ok();
        gripper_in.update().ok();
        arm_qd.clear();
        let arm = arm_in.get().map(|c| {
            arm_qd.extend_from_slice(&c.velocity[..c.joint_count as usize]);
            age(now, c.header.stamp_ns)
        });
        let input = HardwareInput {
            arm: arm.map(|a| (arm_qd.as_slice(), a)),
            base: base_in.get().map(|c| {
                (
                    BaseVelocity {
                        v: c.v,
                        omega: c.omega,
                    },
                    age(now, c.header.stamp_ns),
                )
            }),
            gripper: gripper_in.get().and_then(convert::gripper_command),
        };
        // Real time: run the steps that are due since the first cycle (normally one).
        let due = (now - origin) / period_ns + 1 - steps_done;
        let steps = due.min(cli.max_catch_up);
        if steps > 1 {
            catch_up_cycles += 1;
        }
        let mut frame = None;
        for _ in 0..steps {
            if let Some(f) = sim.step(&input) {
                frame = Some(f);
            }
        }
        // Steps beyond the catch-up limit are dropped: the simulation falls behind.
        steps_done += due;
        let sensors = sim.sensors();
        arm_out
            .publish(convert::joint_state(sensors))
            .unwrap_or_else(report);
        base_out
            .publish(convert::odometry(sensors))
            .unwrap_or_else(report);
        gripper_out
            .publish(convert::gripper_state(sim.truth()))
            .unwrap_or_else(report);
        if let Some(frame) = frame {
            // The frame's age in simulated time, mapped onto the monotonic clock.
            let stamp = now.saturating_sub(((sim.truth().time - frame.stamp) * 1e9) as u64);
            camera_out
                .publish_with(Stamp::At(stamp), |image| {
                    convert::camera_image(&frame, image)
                })
                .unwrap_or_else(report);
        }
        let status = sim.status();
        if cycle.cycle.is_multiple_of(truth_every) || status != last_status {
            last_status = status;
            truth_out
                .publish(convert::truth(&sim, catch_up_cycles))
                .unwrap_or_else(report);
        }
        Flow::Continue
    })?;
    Ok(())
}

fn main() -> ExitCode {
    // clap prints usage errors and exits with code 2 (bad input), help with 0.
    let cli = Cli::parse();
    let sim = match setup(&cli) {
        Ok(sim) => sim,
        Err(e) => {
            eprintln!("sim-world: {e}");
            return ExitCode::from(EXIT_BAD_INPUT);
        }
    };
    match serve(&cli, sim) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("sim-world: {e}");
            ExitCode::from(EXIT_FAILED)
        }
    }
}
