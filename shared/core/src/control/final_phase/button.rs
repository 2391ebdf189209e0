//! Press a button from above, then retract (docs/algorithms.md §2). This controller exists to show
//! that the final phase can be swapped without touching the rest of the stack.
//!
//! Stages:
//! 1. [`Approach`](FinalPhaseStage::Approach): servo top-down to the hover pose,
//!    `hover_height` above the button's top surface, until within `hover_tolerance`.
//! 2. [`Pushing`](FinalPhaseStage::Pushing): move down to `press_depth` below the top surface at
//!    no more than `push_speed`, until within `depth_tolerance` of that depth (or after
//!    `push_timeout`, if the button stops the tool short).
//! 3. [`Retracting`](FinalPhaseStage::Retracting): back up to the hover pose at no more than
//!    `push_speed`, until within `hover_tolerance` (or after `retract_timeout`, if the arm
//!    cannot get there while the base drives on).
//! 4. [`Done`](FinalPhaseStage::Done): the hover pose is held.
//!
//! The gripper stays closed throughout, so the fingertips press as one.
//!
//! **The button's position is latched when the push begins.** Until then the controller follows
//! the target estimate (perception's fix of the cap, in the frame of the base's odometry). From
//! the hover pose down, the palm camera (4 cm above the tool point, 4 cm off the finger axis) is
//! within a few centimetres of the cap: the cap fills a large, strongly distorted part of the
//! fisheye image and the fingers come between, so its fixes drift by one to two centimetres
//! while the tool descends. A button does not move, so the push and the retraction go straight
//! down and up over where the cap was seen from the hover pose.

use nalgebra::Vector3;

use super::{
    ButtonConfig, FinalPhaseController, FinalPhaseInput, FinalPhaseKind, FinalPhaseOutput,
    FinalPhaseStage, ServoConfig, StageClock,
};
use crate::types::GripperCommand;

/// The press-button controller (`"press-button"`).
#[derive(Debug, Clone)]
pub struct ButtonController {
    servo: ServoConfig,
    config: ButtonConfig,
    stage: FinalPhaseStage,
    clock: StageClock,
    /// The button's top-face centre as estimated when the push began (see the module doc).
    latched: Option<Vector3<f64>>,
}

impl ButtonController {
    /// A controller at the start of its approach.
    pub fn new(servo: ServoConfig, config: ButtonConfig) -> Self {
        Self {
            servo,
            config,
            stage: FinalPhaseStage::Approach,
            clock: StageClock::default(),
            latched: None,
        }
    }

    /// The current stage.
    pub fn stage(&self) -> FinalPhaseStage {
        self.stage
    }

    /// The button's top-face centre: latched once the push has begun, the estimate before.
    fn button_top(&self, input: &FinalPhaseInput) -> Vector3<f64> {
        self.latched.unwrap_or(input.target.position)
    }

    fn hover_point(&self, input: &FinalPhaseInput) -> Vector3<f64> {
        self.button_top(input) + Vector3::z() * self.config.hover_height
    }

    fn pressed_point(&self, input: &FinalPhaseInput) -> Vector3<f64> {
        self.button_top(input) - Vector3::z() * self.config.press_depth
    }

    fn enter(&mut self, stage: FinalPhaseStage, t: f64) {
        self.stage = stage;
        self.clock.restart(t);
    }

    fn advance(&mut self, input: &FinalPhaseInput) {
        let tool = input.tool_pose.translation.vector;
        let at_hover = (self.hover_point(input) - tool).norm() < self.config.hover_tolerance;
        match self.stage {
            FinalPhaseStage::Approach if at_hover => {
                self.latched = Some(input.target.position);
                self.enter(FinalPhaseStage::Pushing, input.t);
            }
            FinalPhaseStage::Pushing => {
                let depth_reached =
                    tool.z <= self.pressed_point(input).z + self.config.depth_tolerance;
                if depth_reached || self.clock.elapsed(input.t) >= self.config.push_timeout {
                    self.enter(FinalPhaseStage::Retracting, input.t);
                }
            }
            FinalPhaseStage::Retracting
                if at_hover || self.clock.elapsed(input.t) >= self.config.retract_timeout =>
            {
                self.enter(FinalPhaseStage::Done, input.t);
            }
            _ => {}
        }
    }
}

impl FinalPhaseController for ButtonController {
    fn step(&mut self, input: &FinalPhaseInput) -> FinalPhaseOutput {
        if !input.is_finite() {
            return FinalPhaseOutput::hold(GripperCommand::Close, self.stage);
        }
        self.advance(input);
        let approach_limit = self.servo.correction_speed_limit(&input.base_velocity);
        let (goal, limit) = match self.stage {
            FinalPhaseStage::Pushing => (
                self.pressed_point(input),
                approach_limit.min(self.config.push_speed),
            ),
            FinalPhaseStage::Retracting => (
                self.hover_point(input),
                approach_limit.min(self.config.push_speed),
            ),
            _ => (self.hover_point(input), approach_limit),
        };
        // A latched button is still: no feed-forward of the estimate's velocity.
        let feed_forward = match self.latched {
            Some(_) => Vector3::zeros(),
            None => input.target.velocity,
        };
        let twist = self
            .servo
            .twist(&input.tool_pose, &goal, &feed_forward, limit);
        FinalPhaseOutput::new(twist, GripperCommand::Close, self.stage)
    }

    fn kind(&self) -> FinalPhaseKind {
        FinalPhaseKind::PressButton
    }

    fn reset(&mut self) {
        *self = Self::new(self.servo, self.config);
    }
}

#[cfg(test)]
mod tests {
    use super::super::sim::{KinematicWorld, TargetPath};
    use super::super::{FinalPhaseConfig, build};
    use super::*;
    use crate::types::TaskProgress;
    use nalgebra::{Isometry3, Vector3};
    use std::f64::consts::PI;

    const DT: f64 = 0.025;
    const BUTTON: Vector3<f64> = Vector3::new(1.5, 0.6, 0.7);

    #[test]
    fn pushes_to_depth_and_retracts() {
        let config = FinalPhaseConfig::default();
        let mut controller = build(FinalPhaseKind::PressButton, &config);
        let tool = Isometry3::new(BUTTON + Vector3::new(-0.05, -0.04, 0.09), Vector3::x() * PI);
        let mut world = KinematicWorld::new(tool, 0.3, TargetPath::Static(BUTTON), DT);
        world.graspable = false;
        let mut stages = vec![];
        let mut lowest_before_push = f64::INFINITY;
        let mut lowest = f64::INFINITY;
        let mut max_push_speed: f64 = 0.0;
        for _ in 0..600 {
            let out = controller.step(&world.input());
            assert_eq!(out.gripper, GripperCommand::Close);
            if stages.last() != Some(&out.stage) {
                stages.push(out.stage);
            }
            let z = world.tool.translation.vector.z - BUTTON.z;
            lowest = lowest.min(z);
            if out.stage == FinalPhaseStage::Approach {
                lowest_before_push = lowest_before_push.min(z);
            }
            if matches!(
                out.stage,
                FinalPhaseStage::Pushing | FinalPhaseStage::Retracting
            ) {
                max_push_speed = max_push_speed.max(out.twist.fixed_rows::<3>(0).norm());
            }
            world.advance(&out);
            if out.progress == TaskProgress::Done {
                break;
            }
        }
        assert_eq!(
            stages,
            [
                FinalPhaseStage::Approach,
                FinalPhaseStage::Pushing,
                FinalPhaseStage::Retracting,
                FinalPhaseStage::Done
            ]
        );
        let button = config.button;
        assert!(lowest_before_push > button.hover_height - button.hover_tolerance - 1e-3);
        assert!(
            lowest <= -button.press_depth + button.depth_tolerance
                && lowest > -button.press_depth - 0.003,
            "lowest point {lowest} m relative to the button top"
        );
        assert!(
            max_push_speed <= button.push_speed + 1e-9,
            "{max_push_speed}"
        );
        let end = world.tool.translation.vector - BUTTON;
        assert!(
            (end - Vector3::z() * button.hover_height).norm() < button.hover_tolerance + 1e-3,
            "{end}"
        );
    }

    /// A button controller with the default config and a world with the tool at its hover pose.
    fn at_the_hover_pose() -> (FinalPhaseConfig, ButtonController, KinematicWorld) {
        let config = FinalPhaseConfig::default();
        let controller = ButtonController::new(config.servo, config.button);
        let tool = Isometry3::new(
            BUTTON + Vector3::z() * config.button.hover_height,
            Vector3::x() * PI,
        );
        let mut world = KinematicWorld::new(tool, 0.0, TargetPath::Static(BUTTON), DT);
        world.graspable = false;
        (config, controller, world)
    }

    #[test]
    fn retracts_after_the_timeout_when_the_button_blocks_the_tool() {
        let (config, mut controller, mut world) = at_the_hover_pose();
        let mut retracted = false;
        for _ in 0..400 {
            let out = controller.step(&world.input());
            world.advance(&out);
            // A stiff button: the tool cannot go below its top surface.
            let p = &mut world.tool.translation.vector;
            p.z = p.z.max(BUTTON.z);
            if out.stage == FinalPhaseStage::Retracting {
                retracted = true;
                break;
            }
        }
        assert!(retracted);
        assert!(world.t >= config.button.push_timeout);
    }

    #[test]
    fn the_task_ends_after_the_retract_timeout_when_the_arm_cannot_reach_the_hover_pose() {
        let (config, mut controller, mut world) = at_the_hover_pose();
        let mut retracting_since = None;
        let mut done_at = None;
        for _ in 0..2000 {
            let out = controller.step(&world.input());
            world.advance(&out);
            // An arm held back by the base: the tool cannot rise above 2 cm over the cap.
            let p = &mut world.tool.translation.vector;
            p.z = p.z.min(BUTTON.z + 0.02);
            if out.stage == FinalPhaseStage::Retracting && retracting_since.is_none() {
                retracting_since = Some(world.t);
            }
            if out.stage == FinalPhaseStage::Done {
                done_at = Some(world.t);
                break;
            }
        }
        let (start, end) = (retracting_since.unwrap(), done_at.unwrap());
        assert!(end - start >= config.button.retract_timeout - 2.0 * DT);
        assert!(end - start <= config.button.retract_timeout + 2.0 * DT);
    }

    #[test]
    fn the_push_goes_down_where_the_button_was_seen_from_the_hover_pose() {
        let config = FinalPhaseConfig::default();
        let mut controller = ButtonController::new(config.servo, config.button);
        let tool = Isometry3::new(BUTTON + Vector3::new(-0.05, -0.04, 0.09), Vector3::x() * PI);
        let mut world = KinematicWorld::new(tool, 0.3, TargetPath::Static(BUTTON), DT);
        world.graspable = false;
        // Once the push begins, the estimate drifts 2 cm sideways (as a palm camera's fixes do
        // that close to the cap) and claims a sideways velocity.
        let drift = Vector3::new(0.02, 0.0, 0.0);
        let mut pushed = false;
        for _ in 0..600 {
            let mut input = world.input();
            if pushed {
                input.target.position += drift;
                input.target.velocity = Vector3::new(0.05, 0.0, 0.0);
            }
            let out = controller.step(&input);
            world.advance(&out);
            if out.stage == FinalPhaseStage::Pushing {
                pushed = true;
                let off = (world.tool.translation.vector - BUTTON).xy().norm();
                assert!(off < 0.006, "{off} m off the button during the push");
            }
            if out.progress == TaskProgress::Done {
                break;
            }
        }
        assert!(pushed);
        assert_eq!(controller.stage(), FinalPhaseStage::Done);
        // A new task forgets the latched position.
        controller.reset();
        assert_eq!(controller.stage(), FinalPhaseStage::Approach);
    }
}
