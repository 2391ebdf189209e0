//! Mobile manipulators: a URDF chain whose first two joints are the virtual base joints
//! (yaw, then forward), plus the per-robot settings of `config/robots/<name>.toml`.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix6xX};
use serde::Deserialize;

use crate::chain::{Chain, JointKind, JointLimits};
use crate::error::ModelError;
use crate::kinematics::{BasePose, ForwardKinematics, manipulability};

/// The robots that ship with a configuration in `config/robots/`.
pub const ROBOT_NAMES: [&str; 3] = ["frankie", "fetch", "husky_ur5"];

/// Number of virtual base joints at the start of every mobile chain (yaw, forward).
pub const BASE_JOINTS: usize = 2;

/// Contents of `config/robots/<name>.toml`. Unknown keys are errors.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Robot name, equal to the file stem.
    pub name: String,
    /// URDF file, relative to the TOML file's folder.
    pub urdf: String,
    /// The base footprint link at ground level; the chain starts here.
    pub root_link: String,
    /// The link whose origin is the tool (grasp) point.
    pub tool_link: String,
    /// Names of the two virtual base joints: a continuous yaw joint about z, then a prismatic
    /// forward joint along x. Their URDF `<limit>` gives the base's ω and v limits.
    pub base_joints: [String; 2],
    /// Arm joint positions of the ready pose (all non-base joints, in chain order).
    pub ready_pose: Vec<f64>,
    /// Base footprint length and width, m.
    pub footprint: [f64; 2],
    /// Arm manipulability a grasp must keep for its target to count as within manipulation range
    /// (0.08 for Frankie, as in the paper; for the other robots the same fraction of the arm's
    /// best top-down manipulability at table height).
    pub manipulability_threshold: f64,
    /// Manipulation range, m: the horizontal distance from the arm base (the first arm joint's
    /// frame, `reach_range::arm_base_in_base_frame`) within which a top-down grasp at table height
    /// (0.45 m) reaches manipulability above `manipulability_threshold`. Derived from the model
    /// (`reach_range::derive_manipulation_range`); `shared/core/tests/manipulation_range.rs`
    /// checks it.
    pub manipulation_range: f64,
    /// Arm joints the redundancy resolver holds at their ready position (servoed back to it
    /// whenever they are off) instead of using them to move the tool; none by default.
    /// Fetch holds its torso lift: left free, the QP (which costs every joint's speed alike)
    /// raised it to do the lifts and left it near its top, and with the shoulder that high a
    /// cube at table height is out of the arm's reach at the pass (the manipulation range is
    /// derived with the torso down).
    #[serde(default)]
    pub held_joints: Vec<String>,
}

/// A mobile manipulator model: its configuration and its kinematic chain.
#[derive(Debug, Clone)]
pub struct Robot {
    /// The parsed TOML configuration.
    pub config: RobotConfig,
    /// The chain from the base footprint to the tool, base joints first.
    pub chain: Chain,
    /// The TOML file the robot was loaded from.
    pub config_path: PathBuf,
}

impl Robot {
    /// Loads the robot called `name` from `<config_dir>/robots/<name>.toml`.
    pub fn load(config_dir: &Path, name: &str) -> Result<Self, ModelError> {
        let file = config_dir.join("robots").join(format!("{name}.toml"));
        if !ROBOT_NAMES.contains(&name) {
            return Err(ModelError::UnknownRobot {
                file,
                name: name.to_string(),
                known: ROBOT_NAMES.iter().map(|s| s.to_string()).collect(),
            });
        }
        Self::from_file(&file)
    }

    /// Loads a robot from its TOML configuration file.
    pub fn from_file(config_path: &Path) -> Result<Self, ModelError> {
        let config: RobotConfig = ModelError::parse_toml(config_path)?;
        let urdf_path = config_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(&config.urdf);
        let chain = Chain::from_urdf_file(&urdf_path, &config.root_link, &config.tool_link)?;
        let robot = Self {
            config,
            chain,
            config_path: config_path.to_path_buf(),
        };
        robot.validate(&urdf_path)?;
        Ok(robot)
    }

    fn validate(&self, urdf_path: &Path) -> Result<(), ModelError> {
        let expected = [JointKind::Revolute, JointKind::Prismatic];
        for (i, name) in self.config.base_joints.iter().enumerate() {
            let Some(joint) = self.chain.joints.get(i).filter(|j| &j.name == name) else {
                return Err(ModelError::invalid(
                    &self.config_path,
                    "base_joints",
                    format!(
                        "missing joint: '{name}' must be movable joint {i} of the chain in {}",
                        urdf_path.display()
                    ),
                ));
            };
            if joint.kind != expected[i] {
                return Err(ModelError::invalid(
                    urdf_path,
                    format!("joint '{name}' type"),
                    "base joints must be a yaw (continuous) then a forward (prismatic) joint",
                ));
            }
        }
        for (key, value) in [
            (
                "manipulability_threshold",
                self.config.manipulability_threshold,
            ),
            ("manipulation_range", self.config.manipulation_range),
        ] {
            if !(value > 0.0 && value.is_finite()) {
                return Err(ModelError::invalid(
                    &self.config_path,
                    key,
                    format!("must be positive and finite, got {value}"),
                ));
            }
        }
        if self.config.ready_pose.len() != self.arm_dof() {
            return Err(ModelError::invalid(
                &self.config_path,
                "ready_pose",
                format!(
                    "has {} values but the arm has {} joints",
                    self.config.ready_pose.len(),
                    self.arm_dof()
                ),
            ));
        }
        for (joint, q) in self.arm_joints().zip(&self.config.ready_pose) {
            let l = &joint.limits;
            if !(q.is_finite() && *q >= l.position_min && *q <= l.position_max) {
                return Err(ModelError::invalid(
                    &self.config_path,
                    "ready_pose",
                    format!("{q} is outside joint '{}' limits", joint.name),
                ));
            }
        }
        for name in &self.config.held_joints {
            if !self.arm_joints().any(|j| &j.name == name) {
                return Err(ModelError::invalid(
                    &self.config_path,
                    "held_joints",
                    format!(
                        "'{name}' is not an arm joint of the chain in {}",
                        urdf_path.display()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The held arm joints ([`RobotConfig::held_joints`]): each one's arm index and its ready
    /// position.
    pub fn held_joints(&self) -> Vec<(usize, f64)> {
        self.arm_joints()
            .zip(&self.config.ready_pose)
            .enumerate()
            .filter(|(_, (joint, _))| self.config.held_joints.contains(&joint.name))
            .map(|(k, (_, rest))| (k, *rest))
            .collect()
    }

    /// The robot's name.
    pub fn name(&self) -> &str {
        &self.config.name
    }

    /// Number of arm joints (every movable joint after the two base joints).
    pub fn arm_dof(&self) -> usize {
        self.chain.dof() - BASE_JOINTS
    }

    /// The arm joints, in chain order.
    pub fn arm_joints(&self) -> impl Iterator<Item = &crate::chain::ChainJoint> {
        self.chain.joints[BASE_JOINTS..].iter()
    }

    /// Limits of every movable joint, base joints first.
    pub fn limits(&self) -> Vec<JointLimits> {
        self.chain.joints.iter().map(|j| j.limits).collect()
    }

    /// The full joint vector with the virtual base joints at zero and the given arm positions.
    pub fn full_q(&self, arm_q: &[f64]) -> Vec<f64> {
        assert_eq!(arm_q.len(), self.arm_dof(), "arm joint vector length");
        let mut q = vec![0.0; BASE_JOINTS];
        q.extend_from_slice(arm_q);
        q
    }

    /// Tool pose and the full world Jacobian (base columns ω, v, then the arm) at `base` and `arm_q`.
    pub fn forward(&self, base: &BasePose, arm_q: &[f64]) -> ForwardKinematics {
        self.chain.forward(&base.isometry(), &self.full_q(arm_q))
    }

    /// World pose of the tool at `base` and `arm_q`.
    pub fn tool_pose(&self, base: &BasePose, arm_q: &[f64]) -> Isometry3<f64> {
        self.chain.tool_pose(&base.isometry(), &self.full_q(arm_q))
    }

    /// The arm-only columns of a full Jacobian.
    pub fn arm_jacobian(jacobian: &Matrix6xX<f64>) -> Matrix6xX<f64> {
        jacobian
            .columns(BASE_JOINTS, jacobian.ncols() - BASE_JOINTS)
            .into_owned()
    }

    /// Yoshikawa manipulability of the arm at `arm_q`.
    pub fn manipulability(&self, arm_q: &[f64]) -> f64 {
        let fk = self.forward(&BasePose::default(), arm_q);
        manipulability(&Self::arm_jacobian(&fk.jacobian))
    }
}
