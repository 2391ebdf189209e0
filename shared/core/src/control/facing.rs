//! Which arm joint the MotM facing term turns toward the gripper, and where that joint "faces".
//!
//! The paper's extra QP term keeps "the first arm joint facing the gripper". For the Panda the
//! first arm joint is the vertical shoulder axis and it faces +x of its frame at zero, so the
//! error is `atan2(p.y, p.x) − q1`. That is not true of every arm:
//! - the UR5's shoulder pan points the arm along −x of its frame at zero (the ready pose turns
//!   it by about π), and its shoulder offset puts the tool to one side of the pan direction;
//! - Fetch's first arm joint is the torso lift (prismatic); its vertical axis is the shoulder pan,
//!   the second arm joint.
//!
//! So the facing joint and its offset are derived from the model: the facing joint is the first
//! revolute arm joint whose axis is vertical with the joints before it at the ready pose, and
//! its offset is the direction of the tool, seen from that joint's axis in the joint's
//! zero-position frame, at the ready pose, less the joint's ready position. The facing error is
//! then `wrap(atan2(p.y, p.x) − q − offset)`, p being the tool in that frame: zero at the ready
//! pose, and for the Panda (offset 0) exactly the paper's term.

use nalgebra::{Isometry3, Vector2, Vector3};

use crate::chain::JointKind;
use crate::kinematics::BasePose;
use crate::robot::{BASE_JOINTS, Robot};
use crate::types::wrap_angle;

/// Smallest |z| of a unit joint axis (in the base frame) for the axis to count as vertical.
const VERTICAL_AXIS: f64 = 0.999;

/// Offsets below this are set to exactly 0 rad, so an arm that faces +x at zero (the Panda) gets
/// the paper's term bit for bit rather than a rounding residue of its forward kinematics.
const ZERO_OFFSET: f64 = 1e-9;

/// The arm joint the facing term acts on, and the direction it faces at zero position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FacingJoint {
    /// Index of the joint among the arm joints (0 = first arm joint).
    pub arm_index: usize,
    /// Direction of the tool from the joint axis at the joint's zero position, minus the joint
    /// position, at the ready pose, rad.
    pub offset: f64,
}

impl FacingJoint {
    /// The facing joint of `robot`, derived from its chain and ready pose. `None` when the arm
    /// has no revolute joint with a vertical axis (then no facing term applies).
    pub fn from_robot(robot: &Robot) -> Option<Self> {
        let ready = &robot.config.ready_pose;
        let arm_index = (0..robot.arm_dof()).find(|&i| {
            let joint = &robot.chain.joints[BASE_JOINTS + i];
            joint.kind == JointKind::Revolute
                && (zero_frame(robot, ready, i).rotation * joint.axis.into_inner())
                    .z
                    .abs()
                    >= VERTICAL_AXIS
        })?;
        let tool = robot
            .tool_pose(&BasePose::default(), ready)
            .translation
            .vector;
        let p = zero_frame(robot, ready, arm_index).inverse_transform_vector(
            &(tool - zero_frame(robot, ready, arm_index).translation.vector),
        );
        let offset = wrap_angle(p.y.atan2(p.x) - ready[arm_index]);
        Some(Self {
            arm_index,
            offset: if offset.abs() < ZERO_OFFSET {
                0.0
            } else {
                offset
            },
        })
    }

    /// The facing error at `base`/`arm_q` with the tool at world position `tool`, rad: the turn
    /// `atan2(p.y, p.x) − q − offset` that faces the tool, taken the short way round unless
    /// that way ends past the joint's position limits while the long way does not (or ends
    /// less far past them): then the long way. Positive counter-clockwise. A tool that lags a
    /// hard turn of the base drifts behind the shoulder and across it; the short way would
    /// then wind the joint onto its limit (the Panda's joint 1 at −2.8 rad with the tool
    /// behind on the left), from where the next target on the other side is out of reach. The
    /// joint instead turns back round the front.
    pub fn error(&self, robot: &Robot, base: &BasePose, arm_q: &[f64], tool: &Vector3<f64>) -> f64 {
        let frame = base.isometry() * zero_frame(robot, arm_q, self.arm_index);
        let p = frame.inverse_transform_vector(&(tool - frame.translation.vector));
        let q = arm_q[self.arm_index];
        let short = wrap_angle(p.y.atan2(p.x) - q - self.offset);
        let limits = &robot.chain.joints[BASE_JOINTS + self.arm_index].limits;
        let past_limits = |turn: f64| {
            let goal = q + turn;
            (limits.position_min - goal)
                .max(goal - limits.position_max)
                .max(0.0)
        };
        let long = short - std::f64::consts::TAU.copysign(short);
        if past_limits(short) > past_limits(long) {
            long
        } else {
            short
        }
    }
}

/// How far round the arm's facing joint can turn the arm: the joint's axis and the bearings
/// (about the base heading, seen from that axis) it faces at its position limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FacingReach {
    /// Where the facing joint's axis is, horizontally, in the base frame, m.
    pub axis: Vector2<f64>,
    /// Bearing the joint faces at its lower position limit, rad (about the base's x axis,
    /// counter-clockwise positive).
    pub min_bearing: f64,
    /// Bearing the joint faces at its upper position limit, rad.
    pub max_bearing: f64,
}

impl FacingJoint {
    /// The facing joint's reach on `robot` (the joints before it at the ready pose), or `None`
    /// when its position limits allow a full turn or more (the UR5's ±2π): then no bearing is
    /// out of its reach.
    pub fn reach(&self, robot: &Robot) -> Option<FacingReach> {
        let limits = &robot.limits()[BASE_JOINTS + self.arm_index];
        let span = limits.position_max - limits.position_min;
        // Continuous joints (infinite limits) and joints of a turn or more.
        if span.is_nan() || span >= std::f64::consts::TAU {
            return None;
        }
        let frame = zero_frame(robot, &robot.config.ready_pose, self.arm_index);
        let x = frame.rotation * Vector3::x();
        let frame_yaw = x.y.atan2(x.x);
        let axis = frame.translation.vector;
        Some(FacingReach {
            axis: Vector2::new(axis.x, axis.y),
            min_bearing: frame_yaw + limits.position_min + self.offset,
            max_bearing: frame_yaw + limits.position_max + self.offset,
        })
    }
}

/// Frame of arm joint `arm_index` at its zero position, in the mobile base frame (base joints at
/// zero), with the arm joints before it at `arm_q`.
fn zero_frame(robot: &Robot, arm_q: &[f64], arm_index: usize) -> Isometry3<f64> {
    let joints = &robot.chain.joints;
    let mut frame = Isometry3::identity();
    for joint in &joints[..BASE_JOINTS] {
        frame = frame * joint.origin * joint.motion(0.0);
    }
    for (joint, q) in joints[BASE_JOINTS..BASE_JOINTS + arm_index]
        .iter()
        .zip(arm_q)
    {
        frame = frame * joint.origin * joint.motion(*q);
    }
    frame * joints[BASE_JOINTS + arm_index].origin
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robot(name: &str) -> Robot {
        Robot::load(&crate::resolve_config_dir(None), name).expect("robot loads")
    }

    #[test]
    fn panda_faces_along_x_with_no_offset() {
        let frankie = robot("frankie");
        let facing = FacingJoint::from_robot(&frankie).expect("the Panda has a vertical joint 1");
        assert_eq!(
            facing,
            FacingJoint {
                arm_index: 0,
                offset: 0.0
            }
        );
    }

    #[test]
    fn ur5_pan_faces_backwards_at_zero() {
        let husky = robot("husky_ur5");
        let facing = FacingJoint::from_robot(&husky).expect("the UR5 has a vertical pan joint");
        assert_eq!(facing.arm_index, 0);
        // The pan points the arm along −x at zero; the shoulder offset tilts it a little.
        assert!(
            (facing.offset.abs() - std::f64::consts::PI).abs() < 0.4,
            "{facing:?}"
        );
    }

    #[test]
    fn fetch_faces_with_its_shoulder_pan_not_the_torso() {
        let fetch = robot("fetch");
        let facing = FacingJoint::from_robot(&fetch).expect("Fetch has a shoulder pan");
        assert_eq!(facing.arm_index, 1);
        assert!(facing.offset.abs() < 1e-6, "{facing:?}");
    }

    #[test]
    fn only_fetch_s_shoulder_pan_has_a_reach_short_of_a_full_turn() {
        assert!(
            FacingJoint::from_robot(&robot("husky_ur5"))
                .and_then(|f| f.reach(&robot("husky_ur5")))
                .is_none()
        );
        let fetch = robot("fetch");
        let reach = FacingJoint::from_robot(&fetch)
            .and_then(|f| f.reach(&fetch))
            .expect("Fetch's pan stops at ±1.6056 rad");
        assert!((reach.max_bearing - 1.6056).abs() < 1e-6, "{reach:?}");
        assert!((reach.min_bearing + 1.6056).abs() < 1e-6, "{reach:?}");
        // The shoulder pan sits 0.119525 m ahead of the torso, itself 0.086875 m behind the
        // base centre.
        assert!((reach.axis.x - 0.03265).abs() < 1e-6, "{reach:?}");
        let frankie = robot("frankie");
        let panda = FacingJoint::from_robot(&frankie)
            .and_then(|f| f.reach(&frankie))
            .expect("the Panda's joint 1 stops at ±2.8973 rad");
        assert!((panda.max_bearing - 2.8973).abs() < 1e-6, "{panda:?}");
    }

    #[test]
    fn error_is_zero_at_the_ready_pose_and_follows_the_tool() {
        for name in crate::ROBOT_NAMES {
            let robot = robot(name);
            let facing = FacingJoint::from_robot(&robot).expect("every shipped arm has one");
            let ready = robot.config.ready_pose.clone();
            let base = BasePose::new(1.0, -2.0, 0.7);
            let tool = robot.tool_pose(&base, &ready).translation.vector;
            let at_ready = facing.error(&robot, &base, &ready, &tool);
            assert!(at_ready.abs() < 1e-9, "{name}: {at_ready}");
            // Turning the facing joint away from the tool (tool fixed) gives an error of the
            // opposite sign: the term turns the joint back.
            let mut turned = ready.clone();
            turned[facing.arm_index] += 0.2;
            let error = facing.error(&robot, &base, &turned, &tool);
            assert!((error + 0.2).abs() < 1e-9, "{name}: {error}");
        }
    }

    #[test]
    fn a_tool_across_the_back_is_faced_round_the_front_not_past_the_limit() {
        let robot = robot("frankie");
        let facing = FacingJoint::from_robot(&robot).expect("the Panda's joint 1");
        let base = BasePose::new(0.5, 0.2, -0.4);
        let mut q = robot.config.ready_pose.clone();
        // The tool placed at `bearing` about joint 1's axis, in its zero-position frame.
        let tool_at = |q: &[f64], bearing: f64| {
            let frame = base.isometry() * zero_frame(&robot, q, facing.arm_index);
            frame.translation.vector
                + frame.rotation * Vector3::new(0.5 * bearing.cos(), 0.5 * bearing.sin(), 0.0)
        };
        // Behind on the right, within reach of the limit (−2.8973): the short way.
        q[0] = -2.0;
        let error = facing.error(&robot, &base, &q, &tool_at(&q, -2.5));
        assert!((error + 0.5).abs() < 1e-9, "{error}");
        // Across the back, on the left: the short way (−0.58 rad) ends past the limit, so the
        // joint turns back round the front (+5.7 rad).
        q[0] = -2.8;
        let error = facing.error(&robot, &base, &q, &tool_at(&q, 2.9));
        assert!((error - 5.7).abs() < 1e-9, "{error}");
    }
}
