//! Drop into a container on the move (docs/algorithms.md §2).
//!
//! Stages:
//! 1. [`Approach`](FinalPhaseStage::Approach): servo to the release point, `release_height`
//!    above the container's rim centre, with the container's velocity as feed-forward; the
//!    gripper stays closed on the object. The base keeps driving: nothing here waits for it.
//! 2. [`Releasing`](FinalPhaseStage::Releasing): once within `release_tolerance` of the release
//!    point, open while servoing continues, until the opening reaches `released_opening` or
//!    `opening_timeout` passes.
//! 3. [`Done`](FinalPhaseStage::Done): the object is released; the tool keeps tracking the
//!    release point with the gripper open.

use nalgebra::Vector3;

use super::{
    DropConfig, FinalPhaseController, FinalPhaseInput, FinalPhaseKind, FinalPhaseOutput,
    FinalPhaseStage, ServoConfig, StageClock,
};
use crate::types::GripperCommand;

/// The drop-into-container controller (`"drop"`).
#[derive(Debug, Clone)]
pub struct DropController {
    servo: ServoConfig,
    config: DropConfig,
    stage: FinalPhaseStage,
    clock: StageClock,
}

impl DropController {
    /// A controller at the start of its approach, gripper closed on the object.
    pub fn new(servo: ServoConfig, config: DropConfig) -> Self {
        Self {
            servo,
            config,
            stage: FinalPhaseStage::Approach,
            clock: StageClock::default(),
        }
    }

    /// The current stage.
    pub fn stage(&self) -> FinalPhaseStage {
        self.stage
    }

    fn gripper(&self) -> GripperCommand {
        match self.stage {
            FinalPhaseStage::Approach => GripperCommand::Close,
            _ => GripperCommand::Open,
        }
    }

    fn release_point(&self, input: &FinalPhaseInput) -> Vector3<f64> {
        input.target.position + Vector3::z() * self.config.release_height
    }

    fn advance(&mut self, input: &FinalPhaseInput) {
        let tool = input.tool_pose.translation.vector;
        if self.stage == FinalPhaseStage::Approach
            && (self.release_point(input) - tool).norm() < self.config.release_tolerance
        {
            self.stage = FinalPhaseStage::Releasing;
            self.clock.restart(input.t);
        }
        if self.stage == FinalPhaseStage::Releasing
            && (input.gripper_opening >= self.config.released_opening
                || self.clock.elapsed(input.t) >= self.config.opening_timeout)
        {
            self.stage = FinalPhaseStage::Done;
        }
    }
}

impl FinalPhaseController for DropController {
    fn step(&mut self, input: &FinalPhaseInput) -> FinalPhaseOutput {
        if !input.is_finite() {
            return FinalPhaseOutput::hold(self.gripper(), self.stage);
        }
        self.advance(input);
        let limit = self.servo.correction_speed_limit(&input.base_velocity);
        let twist = self.servo.twist(
            &input.tool_pose,
            &self.release_point(input),
            &input.target.velocity,
            limit,
        );
        FinalPhaseOutput::new(twist, self.gripper(), self.stage)
    }

    fn kind(&self) -> FinalPhaseKind {
        FinalPhaseKind::Drop
    }

    fn reset(&mut self) {
        *self = Self::new(self.servo, self.config);
    }
}

#[cfg(test)]
mod tests {
    use super::super::sim::{KinematicWorld, OPEN_WIDTH, TargetPath};
    use super::super::{FinalPhaseConfig, build};
    use super::*;
    use crate::types::{TaskProgress, Twist};
    use nalgebra::{Isometry3, Vector3};
    use std::f64::consts::PI;

    const DT: f64 = 0.025;
    const CONTAINER: Vector3<f64> = Vector3::new(4.0, -0.5, 0.35);

    #[test]
    fn opens_above_the_container_without_stopping() {
        let config = FinalPhaseConfig::default();
        let mut controller = build(FinalPhaseKind::Drop, &config);
        let start = CONTAINER + Vector3::new(-0.07, 0.05, 0.12);
        let tool = Isometry3::new(start, Vector3::x() * PI);
        let mut world = KinematicWorld::new(tool, 0.3, TargetPath::Static(CONTAINER), DT);
        world.graspable = false;
        world.gripper_opening = 0.03; // holding the cube
        let release_point = CONTAINER + Vector3::z() * config.drop.release_height;
        let mut opened_at = None;
        let mut done = false;
        for _ in 0..200 {
            let out = controller.step(&world.input());
            if out.gripper == GripperCommand::Open && opened_at.is_none() {
                opened_at = Some(world.tool.translation.vector);
            }
            if opened_at.is_none() {
                assert_eq!(out.stage, FinalPhaseStage::Approach);
            }
            world.advance(&out);
            // The base never slows down for the drop.
            assert_eq!(world.base_velocity.v, 0.3);
            if out.progress == TaskProgress::Done {
                done = true;
                break;
            }
        }
        let opened_at = opened_at.expect("never opened");
        let miss = (opened_at - release_point).norm();
        assert!(
            miss < config.drop.release_tolerance,
            "opened {miss} m from the release point"
        );
        assert!(done, "never finished");
        assert!(world.gripper_opening >= config.drop.released_opening);
        assert!(world.gripper_opening <= OPEN_WIDTH);
        // Still over the opening when done.
        let offset = world.tool.translation.vector - release_point;
        assert!(
            offset.xy().norm() < config.drop.release_tolerance,
            "{offset}"
        );
    }

    #[test]
    fn follows_a_moving_container_and_opens_over_it() {
        let config = FinalPhaseConfig::default();
        let mut controller = DropController::new(config.servo, config.drop);
        let path = TargetPath::Circle {
            centre: CONTAINER,
            radius: 0.5,
            speed: 0.05,
        };
        let tool = Isometry3::new(
            path.at(0.0).position + Vector3::new(0.0, 0.08, 0.15),
            Vector3::x() * PI,
        );
        let mut world = KinematicWorld::new(tool, 0.3, path, DT);
        world.graspable = false;
        world.gripper_opening = 0.03;
        let mut released_offset = None;
        for _ in 0..200 {
            let out = controller.step(&world.input());
            if out.gripper == GripperCommand::Open && released_offset.is_none() {
                released_offset =
                    Some(world.tool_from_target() - Vector3::z() * config.drop.release_height);
            }
            world.advance(&out);
            if out.progress == TaskProgress::Done {
                break;
            }
        }
        let offset = released_offset.expect("never opened");
        assert!(offset.norm() < config.drop.release_tolerance, "{offset}");
        assert_eq!(controller.stage(), FinalPhaseStage::Done);
    }

    #[test]
    fn does_not_open_while_far_from_the_release_point() {
        let config = FinalPhaseConfig::default();
        let mut controller = DropController::new(config.servo, config.drop);
        let tool = Isometry3::new(CONTAINER + Vector3::new(0.0, 0.0, 0.3), Vector3::x() * PI);
        let input = KinematicWorld::new(tool, 0.3, TargetPath::Static(CONTAINER), DT).input();
        let out = controller.step(&input);
        assert_eq!(out.gripper, GripperCommand::Close);
        assert_eq!(out.stage, FinalPhaseStage::Approach);
        assert!(
            out.twist[2] < 0.0,
            "moves down toward the release point: {}",
            out.twist
        );

        let mut bad = input;
        bad.base_pose.yaw = f64::NAN;
        let held = controller.step(&bad);
        assert_eq!(held.twist, Twist::zeros());
        assert_eq!(held.gripper, GripperCommand::Close);
    }
}
