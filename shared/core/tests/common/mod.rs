//! Helpers shared by the motm-core integration tests.

#![allow(dead_code)]

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use motm_core::{JointKind, JointLimits, Robot};
use rand::{Rng, RngExt};

/// The repository's `config/` folder.
pub fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// Loads one of the shipped robots.
pub fn load(name: &str) -> Robot {
    Robot::load(&config_dir(), name).unwrap_or_else(|e| panic!("loading {name}: {e}"))
}

/// A random position within `limits`. Unlimited joints (continuous revolute, the prismatic base
/// joint) are drawn from one turn or ±1 m.
pub fn random_position(rng: &mut impl Rng, kind: JointKind, limits: &JointLimits) -> f64 {
    let unbounded = match kind {
        JointKind::Revolute => PI,
        JointKind::Prismatic => 1.0,
    };
    let lower = limits.position_min.max(-unbounded);
    let upper = limits.position_max.min(unbounded);
    rng.random_range(lower..=upper)
}

/// A random arm configuration within the robot's joint limits.
pub fn random_arm_q(rng: &mut impl Rng, robot: &Robot) -> Vec<f64> {
    robot
        .arm_joints()
        .map(|j| random_position(rng, j.kind, &j.limits))
        .collect()
}
