//! `perception`: the perception task ([`motm_tasks::perception`]) as a process. It runs on
//! each camera image's arrival, and at the control rate in between so that its tool-pose
//! history stays dense; its deadline is one camera frame (33 ms), since a cycle with an image
//! takes longer than one without.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use motm_core::camera::{CALIBRATION_FILE, CameraCalibration};
use motm_tasks::perception::PerceptionTask;
use motm_wire::Service;

/// Flags of perception.
#[derive(Debug, Clone, clap::Args)]
struct Flags {
    /// Tool poses kept to pair images with.
    #[arg(long, default_value_t = 200)]
    history: usize,
    /// The palm camera's calibration file (default: `cameras/palm.toml` in the config folder).
    #[arg(long)]
    calibration: Option<PathBuf>,
}

fn main() -> ExitCode {
    Service::new(&motm_graph::PERCEPTION, "Perception service")
        .deadline(Duration::from_millis(33))
        .run(
            |setup, flags: Flags| {
                let calibration = flags
                    .calibration
                    .unwrap_or_else(|| setup.config_dir.join(CALIBRATION_FILE));
                let calibration =
                    CameraCalibration::from_file(&calibration).map_err(|e| e.to_string())?;
                let tasks = setup.mission.as_ref().map(|m| m.tasks.clone());
                Ok(PerceptionTask::new(
                    setup.robot.clone(),
                    setup.config.perception,
                    calibration,
                    flags.history,
                    setup.config.mission.run_out_distance,
                )
                .with_layout(&tasks.unwrap_or_default()))
            },
            |task| format!("{} estimates", task.published()),
        )
}
