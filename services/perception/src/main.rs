//! `perception`: records the tool pose the robot believes it has (each joint state at the
//! latest odometry pose), and for each new palm-camera image of the current pick pairs the
//! image with the pose nearest its capture stamp, runs cube perception and publishes the
//! estimate (with the stamp of the image it came from). The logic is
//! [`motm_core::stack::perception`].
//!
//! Assumption: camera image stamps are exposure times on the same monotonic clock as the
//! joint-state stamps. Run it at the control rate (not the camera rate): each cycle adds the
//! queued joint states to the tool-pose history, and an image waits at most one cycle. The loop's deadline is one camera frame (33 ms), since a cycle with an
//! image takes longer than one without.

use std::time::Duration;

use clap::Parser;
use motm_bus::{Bus, Flow, LoopConfig, Publisher, Qos, ServiceLoop, Subscriber};
use motm_core::camera::CameraConfig;
use motm_core::perception::PerceptionConfig;
use motm_core::stack::perception::{CameraFrame, PerceptionCycle};
use motm_msgs as msgs;
use motm_msgs::services;
use motm_wire::inputs::ControlInputs;
use motm_wire::{ServiceArgs, ServiceSetup, convert, exit_on_error, report_exit};

/// Process (and heartbeat) name.
const PROCESS: &str = "perception";

/// Longest acceptable cycle (one frame at 30 Hz).
const DEADLINE: Duration = Duration::from_millis(33);

/// Command line.
#[derive(Debug, Parser)]
#[command(name = PROCESS, about = "Perception service")]
struct Cli {
    /// Common service options.
    #[command(flatten)]
    common: ServiceArgs,
    /// Tool poses kept to pair images with.
    #[arg(long, default_value_t = 200)]
    history: usize,
}

fn main() {
    let cli = Cli::parse();
    let setup = exit_on_error(PROCESS, ServiceSetup::load(&cli.common));
    exit_on_error(PROCESS, run(&setup, cli.history));
}

/// Opens the ports and runs the loop until SIGTERM/SIGINT.
fn run(setup: &ServiceSetup, history: usize) -> Result<(), motm_bus::BusError> {
    let bus = Bus::open(PROCESS)?;
    // Joint states are drained from a queue (up to the service's buffer per cycle), not just
    // the latest, so the tool-pose history is denser than the loop rate.
    let mut inputs = ControlInputs::open_with(&bus, setup.config.mission.run_out_distance, false)?;
    let joint_qos = Qos::default();
    let mut joints =
        Subscriber::<msgs::JointState>::new(&bus, services::ARM_JOINT_STATE, &joint_qos)?;
    let mut images =
        Subscriber::<msgs::CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large())?;
    let mut target_out =
        Publisher::<msgs::TargetEstimate>::new(&bus, services::PERCEPTION_TARGET, &Qos::default())?;
    let calibration = setup.camera_calibration(&CameraConfig::default());
    let mut cycle = PerceptionCycle::new(PerceptionConfig::default(), calibration, history);
    let robot = &setup.robot;
    let mut published = 0u64;
    let config = LoopConfig {
        deadline: Some(DEADLINE.max(setup.period())),
        ..LoopConfig::with_rate(setup.rate_hz)
    };
    let mut service = ServiceLoop::new(&bus, config)?;
    eprintln!("{PROCESS}: running at {} Hz", setup.rate_hz);
    service.run_periodic(|ctx| {
        // A failed receive leaves the previous value; the bus counts invalid samples.
        let _ = inputs.update();
        let image = images.latest().ok().flatten();
        while let Ok(Some(state)) = joints.receive() {
            let arm_q = convert::arm_q(&state);
            if let Some(odometry) = inputs.odometry()
                && arm_q.len() == robot.arm_dof()
            {
                let pose = robot.tool_pose(&convert::base_pose(odometry), arm_q);
                cycle.record_tool(state.header.stamp_ns, pose);
            }
        }
        let snapshot = inputs.snapshot(ctx.now_ns);
        let (Some(mission), Some(image)) = (snapshot.mission, image) else {
            return Flow::Continue;
        };
        let frame = CameraFrame {
            pixels: &image.pixels,
            width: image.width,
            height: image.height,
            stamp_ns: image.header.stamp_ns,
        };
        if let Some(report) = cycle.observe(&mission, &frame) {
            // A failed publish leaves the previous estimate in use.
            if target_out.publish(convert::target_message(&report)).is_ok() {
                published += 1;
            }
        }
        Flow::Continue
    })?;
    let details = format!("{published} estimates");
    report_exit(PROCESS, &mut service, &bus, &details);
    Ok(())
}
