//! `perception`: records the tool pose the robot believes it has (joint state at the odometry
//! pose) at each joint state, and for each new palm-camera image of the current pick pairs the
//! image with the pose nearest its capture stamp, runs cube perception and publishes the
//! estimate (with the stamp of the image it came from). The logic is
//! [`motm_core::stack::perception`].
//!
//! Assumption: camera image stamps are exposure times on the same monotonic clock as the
//! joint-state stamps. The loop's deadline is one camera frame (33 ms), since a cycle with an
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
    let mut inputs = ControlInputs::open(&bus, setup.config.mission.run_out_distance)?;
    let mut images =
        Subscriber::<msgs::CameraImage>::new(&bus, services::CAMERA_IMAGE, &Qos::large())?;
    let mut target_out =
        Publisher::<msgs::TargetEstimate>::new(&bus, services::PERCEPTION_TARGET, &Qos::default())?;
    let calibration = setup.camera_calibration(&CameraConfig::default());
    let mut cycle = PerceptionCycle::new(PerceptionConfig::default(), calibration, history);
    let robot = &setup.robot;
    let mut last_pose_stamp = None;
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
        let stamp = inputs.joint_state().map(|j| j.header.stamp_ns);
        let snapshot = inputs.snapshot(ctx.now_ns);
        if let Some(measured) = snapshot.measured
            && measured.arm_q.len() == robot.arm_dof()
            && stamp != last_pose_stamp
        {
            last_pose_stamp = stamp;
            let pose = robot.tool_pose(&measured.base, measured.arm_q);
            cycle.record_tool(stamp.unwrap_or(measured.stamp_ns), pose);
        }
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
