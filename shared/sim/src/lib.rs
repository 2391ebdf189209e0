//! # motm-sim
//!
//! The simulated world that stands in for the robot on any machine without one: a kinematic robot
//! with realistic imperfections, objects, a gripper with a grasp model, and a palm camera that
//! renders real images. Every random draw comes from a seeded RNG, so a scenario and a seed give
//! the same result bit for bit.
pub mod experiment;
pub mod metrics;
