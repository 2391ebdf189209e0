//! # motm-sim
//!
//! The simulated world that stands in for the robot on any machine without one: a kinematic robot
//! with realistic imperfections, objects, a gripper with a grasp model, and a palm camera that
//! renders real images. Every random draw comes from a seeded RNG, so a scenario and a seed give
//! the same result bit for bit.

pub mod experiment;
pub mod generated;
pub mod geometry;
pub mod grasp;
pub mod gripper;
pub mod messages;
pub mod metrics;
pub mod objects;
mod pixel_noise;
pub mod random;
pub mod render;
pub mod replay;
pub mod runner;
pub mod scenario;
pub mod sim_world;
pub mod task;
pub mod trial_camera;
pub mod world;

pub use scenario::{Motion, Noise, Scenario, ScenarioButton, ScenarioObject, scenario_path};
pub use world::{
    FailureReason, HardwareCommand, Mishap, Outcome, Sensors, Truth, World, WorldConfig,
};
