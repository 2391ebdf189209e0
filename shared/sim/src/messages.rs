//! Conversions between the simulated world's values and the bus messages.

use crate::render::{Exposure, PalmCamera};
use crate::sim_world::{SimWorld, TrialStatus};
use crate::{FailureReason, Outcome, Sensors, Truth};
use motm_core::{GripperCommand, wrap_angle};
use motm_msgs::{
    BaseOdometry, CAMERA_IMAGE_BYTES, CameraImage, GripperAction, GripperState, JointState,
    MAX_ARM_JOINTS, MAX_SIM_OBJECTS, Message, SimOutcome, SimTruth,
};

/// The arm state the encoders measure.
pub fn joint_state(sensors: &Sensors) -> JointState {
    let mut m = JointState::zeroed();
    let n = sensors.arm_q.len().min(MAX_ARM_JOINTS);
    m.joint_count = n as u32;
    m.position[..n].copy_from_slice(&sensors.arm_q[..n]);
    m.velocity[..n].copy_from_slice(&sensors.arm_qd[..n]);
    m
}

/// The base odometry (yaw wrapped to [-π, π]).
pub fn odometry(sensors: &Sensors) -> BaseOdometry {
    let mut m = BaseOdometry::zeroed();
    m.x = sensors.base_pose.x;
    m.y = sensors.base_pose.y;
    m.yaw = wrap_angle(sensors.base_pose.yaw);
    m.v = sensors.base_velocity.v;
    m.omega = sensors.base_velocity.omega;
    m
}

/// The gripper state: opening and whether it holds a cube.
pub fn gripper_state(truth: &Truth) -> GripperState {
    let mut m = GripperState::zeroed();
    m.width = truth.gripper_opening;
    m.grasping = truth.held_object.is_some().into();
    m
}

/// The gripper command a message asks for (`None` for an invalid code).
pub fn gripper_command(m: &motm_msgs::GripperCommand) -> Option<GripperCommand> {
    match m.action()? {
        GripperAction::Open => Some(GripperCommand::Open),
        GripperAction::Close => Some(GripperCommand::Close),
    }
}

/// Draws `exposure` through `camera` into an image message in place: straight into its
/// pixels when the frame fits (the bytes beyond it are left as they are), through a copy
/// otherwise (the frame cut to the message).
pub fn camera_image(camera: &PalmCamera, exposure: &Exposure, image: &mut CameraImage) {
    let (width, height) = camera.size();
    image.width = width;
    image.height = height;
    let n = width as usize * height as usize * 3;
    if let Some(pixels) = image.pixels.get_mut(..n) {
        camera.render(exposure, pixels);
    } else {
        let frame = camera.frame(exposure).image;
        image.pixels.copy_from_slice(&frame[..CAMERA_IMAGE_BYTES]);
    }
}

/// The outcome code of a trial status.
pub fn outcome(status: TrialStatus) -> SimOutcome {
    match status {
        TrialStatus::Running => SimOutcome::Running,
        TrialStatus::TimedOut => SimOutcome::Timeout,
        TrialStatus::Decided(Outcome::Success) => SimOutcome::Success,
        TrialStatus::Decided(Outcome::Failure(reason)) => match reason {
            FailureReason::KnockedOff => SimOutcome::KnockedOff,
            FailureReason::MissedGrasp => SimOutcome::MissedGrasp,
            FailureReason::DroppedOutside => SimOutcome::DroppedOutside,
            FailureReason::BaseCollision => SimOutcome::BaseCollision,
            FailureReason::TaskFailed => SimOutcome::TaskFailed,
        },
    }
}

/// The ground truth of `sim`.
pub fn truth(sim: &SimWorld, catch_up_cycles: u64) -> SimTruth {
    let truth = sim.truth();
    let mut m = SimTruth::zeroed();
    m.sim_time = truth.time;
    m.task_time = sim.task_time().min(truth.time);
    m.outcome = outcome(sim.status()).into();
    let count = truth.objects.len().min(MAX_SIM_OBJECTS);
    m.object_count = count as u32;
    m.tool_position
        .copy_from_slice(truth.tool_pose.translation.vector.as_slice());
    m.base_pose = [
        truth.base_pose.x,
        truth.base_pose.y,
        wrap_angle(truth.base_pose.yaw),
    ];
    m.object_placed_time = [0.0; MAX_SIM_OBJECTS];
    for (i, object) in truth.objects.iter().take(count).enumerate() {
        m.object_positions[3 * i..3 * i + 3].copy_from_slice(object.position().as_slice());
        m.object_placed_time[i] = object.placed_time.unwrap_or(-1.0);
    }
    m.held_object = truth
        .held_object
        .filter(|&i| i < count)
        .map_or(-1, |i| i as i32);
    m.buttons_pressed = truth.buttons.iter().filter(|b| b.pressed).count() as u32;
    m.gripper_opening = truth.gripper_opening;
    m.ee_acc_mean = sim.meter().mean();
    m.ee_acc_max = sim.meter().max();
    m.rejected_commands = sim.world().rejected_commands();
    m.catch_up_cycles = catch_up_cycles;
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Scenario;
    use crate::runner::RunnerConfig;
    use crate::sim_world::{HardwareInput, SimWorldConfig};
    use motm_core::Robot;
    use std::path::Path;

    #[test]
    fn every_message_from_a_running_world_validates() {
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let robot = Robot::load(&config, "frankie").unwrap();
        let scenario = Scenario::from_file(&config.join("scenarios/exp1-dynamic.toml")).unwrap();
        let mut sim = SimWorld::new(
            &robot,
            &scenario,
            1,
            &RunnerConfig::default(),
            SimWorldConfig::default(),
        )
        .unwrap();
        let qd = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1];
        let mut exposure = None;
        for _ in 0..100 {
            let input = HardwareInput {
                arm: Some((&qd, 0.0)),
                base: None,
                gripper: None,
            };
            exposure = sim.step_exposing(&input).or(exposure);
        }
        let now = 1_000_000_000;
        let joints = joint_state(sim.sensors());
        assert_eq!(joints.validate(now, None), Ok(()));
        assert_eq!(joints.joint_count, 7);
        assert!(joints.velocity[6] > 0.05);
        assert_eq!(odometry(sim.sensors()).validate(now, None), Ok(()));
        assert_eq!(gripper_state(sim.truth()).validate(now, None), Ok(()));
        let t = truth(&sim, 2);
        assert_eq!(t.validate(now, None), Ok(()));
        assert_eq!(t.outcome(), Some(SimOutcome::Running));
        assert_eq!(t.object_count as usize, scenario.objects.len());
        assert_eq!(t.object_placed_time[0], -1.0);
        assert_eq!(t.catch_up_cycles, 2);
        assert!((t.sim_time - 0.1).abs() < 1e-9);
        let exposure = exposure.expect("a frame within 100 ms");
        let frame = sim.camera().frame(&exposure);
        let mut image = CameraImage::zeroed();
        camera_image(sim.camera(), &exposure, &mut image);
        assert_eq!(image.validate(now, None), Ok(()));
        assert_eq!(&image.pixels[..], &frame.image[..]);
    }

    #[test]
    fn outcomes_map_to_their_codes() {
        assert_eq!(outcome(TrialStatus::Running), SimOutcome::Running);
        assert_eq!(outcome(TrialStatus::TimedOut), SimOutcome::Timeout);
        assert_eq!(
            outcome(TrialStatus::Decided(Outcome::Failure(
                FailureReason::MissedGrasp
            ))),
            SimOutcome::MissedGrasp
        );
        assert_eq!(
            outcome(TrialStatus::Decided(Outcome::Success)),
            SimOutcome::Success
        );
    }
}
