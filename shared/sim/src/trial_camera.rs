//! The palm camera of one trial, built the same way wherever a trial runs: in the in-process
//! runner, in the simulated-world process, and in the perception process (which needs the
//! calibration the camera hands out, error included).

use motm_core::camera::CameraConfig;

use crate::render::PalmCamera;
use crate::scenario::Scenario;

/// Salt mixed into the trial seed for the camera's own random draws (pixel noise, calibration
/// error), so that they do not repeat the world's.
pub const CAMERA_SEED_SALT: u64 = 0x5eed_ca3e_0000_0001;

impl PalmCamera {
    /// The camera of a trial of `scenario` with `seed`: `config` with the scenario's pixel noise
    /// and extrinsic calibration error, seeded from `seed ^ CAMERA_SEED_SALT`.
    pub fn for_trial(config: &CameraConfig, scenario: &Scenario, seed: u64) -> Self {
        let mut config = *config;
        config.pixel_noise_std = scenario.noise.camera_pixel_std;
        config.extrinsic_error = scenario.noise.camera_extrinsic_error;
        PalmCamera::new(&config, seed ^ CAMERA_SEED_SALT)
    }
}
