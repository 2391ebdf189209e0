//! A small kinematic world for the final-phase tests: an ideal tool that follows the commanded
//! world twist one cycle late, with a fraction of the base velocity leaking into its motion (the
//! resolver's imperfect compensation) and, optionally, its linear velocity changing no faster
//! than an acceleration limit (the resolver's twist rate limit), a base driving at constant
//! speed, a target on a circle or at rest, and a gripper that closes at a fixed rate and stops
//! on the cube.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::{FinalPhaseInput, FinalPhaseOutput};
use crate::kinematics::BasePose;
use crate::types::{BaseVelocity, GripperCommand, TargetEstimate, Twist};

/// Fully open finger distance of the Franka Hand, m.
pub const OPEN_WIDTH: f64 = 0.08;
/// Edge of the test cube, m.
pub const CUBE_WIDTH: f64 = 0.03;
/// Finger speed (distance change per second): 0.5 s from open to the cube.
pub const FINGER_SPEED: f64 = 0.1;

/// Largest lateral tool-to-cube offset at which closing fingers catch the cube, m.
pub const GRASP_LATERAL_TOLERANCE: f64 = 0.005;
/// Largest vertical tool-to-cube offset at which closing fingers catch the cube, m.
pub const GRASP_HEIGHT_TOLERANCE: f64 = 0.01;

/// How the target moves.
#[derive(Debug, Clone, Copy)]
pub enum TargetPath {
    /// At rest at a point.
    Static(Vector3<f64>),
    /// On a horizontal circle at constant speed, starting at angle 0.
    Circle {
        /// Circle centre.
        centre: Vector3<f64>,
        /// Radius, m.
        radius: f64,
        /// Speed along the circle, m/s.
        speed: f64,
    },
}

impl TargetPath {
    /// Position and velocity at time `t`.
    pub fn at(&self, t: f64) -> TargetEstimate {
        match *self {
            Self::Static(p) => TargetEstimate::fixed(p),
            Self::Circle {
                centre,
                radius,
                speed,
            } => {
                let angle = speed / radius * t;
                TargetEstimate {
                    position: centre + Vector3::new(angle.cos(), angle.sin(), 0.0) * radius,
                    velocity: Vector3::new(-angle.sin(), angle.cos(), 0.0) * speed,
                }
            }
        }
    }
}

/// The test world.
#[derive(Debug, Clone)]
pub struct KinematicWorld {
    /// Current time, s.
    pub t: f64,
    /// Control period, s.
    pub dt: f64,
    /// World pose of the tool.
    pub tool: Isometry3<f64>,
    /// Base pose.
    pub base: BasePose,
    /// Base velocity (constant).
    pub base_velocity: BaseVelocity,
    /// The target's free motion (before it is grasped).
    pub path: TargetPath,
    /// The target as the controller sees it.
    pub target: TargetEstimate,
    /// Finger opening, m.
    pub gripper_opening: f64,
    /// Whether the cube is held (it then moves with the tool).
    pub holding: bool,
    /// Whether closing fingers can catch the target (a cube); false for a container or button.
    pub graspable: bool,
    /// Fraction of the base's world velocity that leaks into the tool's motion.
    pub leak: f64,
    /// Largest change of the tool's commanded linear velocity per second, m/s² (infinite: the
    /// command is followed at once).
    pub max_linear_acceleration: f64,
    /// The tool's world linear velocity over the last period, m/s.
    pub tool_velocity: Vector3<f64>,
    /// The gripper yaw the controller is told to grasp at (none: any).
    pub grasp_yaw: Option<f64>,
    applied: Twist,
    held_offset: Vector3<f64>,
}

impl KinematicWorld {
    /// A world at t = 0 with the base at the origin driving along x at `base_speed`.
    pub fn new(tool: Isometry3<f64>, base_speed: f64, path: TargetPath, dt: f64) -> Self {
        Self {
            t: 0.0,
            dt,
            tool,
            base: BasePose::default(),
            base_velocity: BaseVelocity {
                v: base_speed,
                omega: 0.0,
            },
            path,
            target: path.at(0.0),
            gripper_opening: OPEN_WIDTH,
            holding: false,
            graspable: true,
            leak: 0.03,
            max_linear_acceleration: f64::INFINITY,
            tool_velocity: Vector3::zeros(),
            grasp_yaw: None,
            applied: Twist::zeros(),
            held_offset: Vector3::zeros(),
        }
    }

    /// Sets the tool moving at `velocity` (world, m/s), as a reach hands it over.
    pub fn set_tool_velocity(&mut self, velocity: Vector3<f64>) {
        self.applied.fixed_rows_mut::<3>(0).copy_from(&velocity);
        self.tool_velocity = velocity;
    }

    /// This cycle's controller input.
    pub fn input(&self) -> FinalPhaseInput {
        FinalPhaseInput {
            t: self.t,
            tool_pose: self.tool,
            base_pose: self.base,
            base_velocity: self.base_velocity,
            target: self.target,
            gripper_opening: self.gripper_opening,
            tool_velocity: self.tool_velocity,
            grasp_yaw: self.grasp_yaw,
        }
    }

    /// Tool position relative to the target, m.
    pub fn tool_from_target(&self) -> Vector3<f64> {
        self.tool.translation.vector - self.target.position
    }

    /// Advances one period, applying the previous command and storing `output` for the next.
    pub fn advance(&mut self, output: &FinalPhaseOutput) {
        let dt = self.dt;
        let heading = Vector3::new(self.base.yaw.cos(), self.base.yaw.sin(), 0.0);
        let base_world_velocity = heading * self.base_velocity.v;
        let linear = self.applied.fixed_rows::<3>(0).into_owned() + base_world_velocity * self.leak;
        let angular = self.applied.fixed_rows::<3>(3).into_owned();
        self.tool_velocity = linear;
        self.tool = Isometry3::from_parts(
            Translation3::from(self.tool.translation.vector + linear * dt),
            UnitQuaternion::from_scaled_axis(angular * dt) * self.tool.rotation,
        );
        let previous = self.applied.fixed_rows::<3>(0).into_owned();
        let change = output.twist.fixed_rows::<3>(0) - previous;
        let largest = self.max_linear_acceleration * dt;
        let change = if change.norm() > largest {
            change * (largest / change.norm())
        } else {
            change
        };
        self.applied = output.twist;
        self.applied
            .fixed_rows_mut::<3>(0)
            .copy_from(&(previous + change));

        self.base.x += base_world_velocity.x * dt;
        self.base.y += base_world_velocity.y * dt;
        self.base.yaw += self.base_velocity.omega * dt;

        let offset = self.tool_from_target();
        let between_fingers = self.graspable
            && offset.xy().norm() < GRASP_LATERAL_TOLERANCE
            && offset.z.abs() < GRASP_HEIGHT_TOLERANCE;
        let stop = if between_fingers { CUBE_WIDTH } else { 0.0 };
        match output.gripper {
            GripperCommand::Close => {
                self.gripper_opening = (self.gripper_opening - FINGER_SPEED * dt).max(stop);
                if !self.holding && between_fingers && self.gripper_opening <= CUBE_WIDTH {
                    self.holding = true;
                    self.held_offset = self.tool_from_target();
                }
            }
            GripperCommand::Open => {
                self.gripper_opening = (self.gripper_opening + FINGER_SPEED * dt).min(OPEN_WIDTH);
                if self.gripper_opening > CUBE_WIDTH {
                    self.holding = false;
                }
            }
        }

        self.t += dt;
        self.target = if self.holding {
            TargetEstimate {
                position: self.tool.translation.vector - self.held_offset,
                velocity: linear,
            }
        } else {
            self.path.at(self.t)
        };
    }
}
