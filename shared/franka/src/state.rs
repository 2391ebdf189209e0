//! The 1 kHz UDP messages: [`RobotState`] (robot to client, 2373 bytes) and [`RobotCommand`]
//! (client to robot, 370 bytes), packed little-endian, every field at its fixed offset.

use crate::wire::{Field, ProtocolError};

/// Index of `communication_constraints_violation` in `errors` / `reflex_reason`.
pub const COMMUNICATION_CONSTRAINTS_VIOLATION: usize = 25;
/// Number of entries of `errors` / `reflex_reason` (the `Error` enum of libfranka-common).
pub const ERROR_COUNT: usize = 41;

/// Generates a packed struct with its field table, encoder and decoder.
macro_rules! packed {
    ($(#[$m:meta])* $name:ident, $message:literal, $size:literal {
        $($(#[$fm:meta])* $field:ident : $ty:ty = $off:literal),* $(,)?
    }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[allow(non_snake_case)]
        pub struct $name {
            $($(#[$fm])* pub $field: $ty),*
        }

        impl Default for $name {
            fn default() -> Self {
                Self::decode(&[0u8; $size]).expect("the size is right")
            }
        }

        impl $name {
            /// Encoded size, bytes.
            pub const SIZE: usize = $size;
            /// Every field: name, byte offset, size.
            pub const FIELDS: &'static [(&'static str, usize, usize)] =
                &[$((stringify!($field), $off, <$ty as Field>::SIZE)),*];

            /// Writes the message into `out`.
            pub fn encode_into(&self, out: &mut [u8; $size]) {
                $(self.$field.put(&mut out[$off..]);)*
            }

            /// The encoded message.
            pub fn encode(&self) -> [u8; $size] {
                let mut out = [0u8; $size];
                self.encode_into(&mut out);
                out
            }

            /// Decodes one datagram; any other size than [`Self::SIZE`] is an error.
            pub fn decode(bytes: &[u8]) -> Result<Self, ProtocolError> {
                if bytes.len() != $size {
                    return Err(ProtocolError::WrongSize {
                        message: $message,
                        expected: $size,
                        got: bytes.len(),
                    });
                }
                Ok(Self { $($field: <$ty as Field>::get(&bytes[$off..])),* })
            }
        }
    };
}

packed!(
    /// The robot's state, sent every millisecond (2373 bytes).
    RobotState, "RobotState", 2373 {
        /// Robot time, ms; +1 per cycle.
        message_id: u64 = 0,
        /// Measured end-effector pose in the base frame, column-major.
        O_T_EE: [f64; 16] = 8,
        /// Desired end-effector pose.
        O_T_EE_d: [f64; 16] = 136,
        /// Flange to end effector.
        F_T_EE: [f64; 16] = 264,
        /// End effector to stiffness frame.
        EE_T_K: [f64; 16] = 392,
        /// Flange to nominal end effector.
        F_T_NE: [f64; 16] = 520,
        /// Nominal to actual end effector.
        NE_T_EE: [f64; 16] = 648,
        /// End-effector mass, kg.
        m_ee: f64 = 776,
        /// End-effector inertia.
        I_ee: [f64; 9] = 784,
        /// End-effector centre of mass.
        F_x_Cee: [f64; 3] = 856,
        /// Load mass, kg.
        m_load: f64 = 880,
        /// Load inertia.
        I_load: [f64; 9] = 888,
        /// Load centre of mass.
        F_x_Cload: [f64; 3] = 960,
        /// Elbow configuration.
        elbow: [f64; 2] = 984,
        /// Desired elbow configuration.
        elbow_d: [f64; 2] = 1000,
        /// Measured joint torques, N·m.
        tau_J: [f64; 7] = 1016,
        /// Desired joint torques.
        tau_J_d: [f64; 7] = 1072,
        /// Torque derivatives.
        dtau_J: [f64; 7] = 1128,
        /// Measured joint positions, rad.
        q: [f64; 7] = 1184,
        /// Desired joint positions, rad.
        q_d: [f64; 7] = 1240,
        /// Measured joint velocities, rad/s.
        dq: [f64; 7] = 1296,
        /// Desired joint velocities (the last command the robot executed), rad/s.
        dq_d: [f64; 7] = 1352,
        /// Desired joint accelerations, rad/s².
        ddq_d: [f64; 7] = 1408,
        /// Joint contact flags.
        joint_contact: [f64; 7] = 1464,
        /// Cartesian contact flags.
        cartesian_contact: [f64; 6] = 1520,
        /// Joint collision flags.
        joint_collision: [f64; 7] = 1568,
        /// Cartesian collision flags.
        cartesian_collision: [f64; 6] = 1624,
        /// Filtered external torques.
        tau_ext_hat_filtered: [f64; 7] = 1672,
        /// External wrench in the base frame.
        O_F_ext_hat_K: [f64; 6] = 1728,
        /// External wrench in the stiffness frame.
        K_F_ext_hat_K: [f64; 6] = 1776,
        /// Desired end-effector twist.
        O_dP_EE_d: [f64; 6] = 1824,
        /// Gravity direction.
        O_ddP_O: [f64; 3] = 1872,
        /// Commanded elbow.
        elbow_c: [f64; 2] = 1896,
        /// Commanded elbow velocity.
        delbow_c: [f64; 2] = 1912,
        /// Commanded elbow acceleration.
        ddelbow_c: [f64; 2] = 1928,
        /// Commanded end-effector pose.
        O_T_EE_c: [f64; 16] = 1944,
        /// Commanded end-effector twist.
        O_dP_EE_c: [f64; 6] = 2072,
        /// Commanded end-effector acceleration.
        O_ddP_EE_c: [f64; 6] = 2120,
        /// Motor positions.
        theta: [f64; 7] = 2168,
        /// Motor velocities.
        dtheta: [f64; 7] = 2224,
        /// Motion generator code (see [`StateGenerator`]).
        motion_generator_mode: u8 = 2280,
        /// Controller code (see [`StateController`]).
        controller_mode: u8 = 2281,
        /// Current errors (indexed by libfranka-common's `Error`).
        errors: [bool; ERROR_COUNT] = 2282,
        /// Errors that caused the last reflex.
        reflex_reason: [bool; ERROR_COUNT] = 2323,
        /// Robot mode code (see [`RobotMode`]).
        robot_mode: u8 = 2364,
        /// Fraction of commands that arrived in time.
        control_command_success_rate: f64 = 2365,
    }
);

packed!(
    /// The client's command, one per received state (370 bytes).
    RobotCommand, "RobotCommand", 370 {
        /// Echo of the newest state's `message_id`.
        message_id: u64 = 0,
        /// Joint positions (unused here).
        q_c: [f64; 7] = 8,
        /// Joint velocities, rad/s.
        dq_c: [f64; 7] = 64,
        /// End-effector pose (unused here).
        O_T_EE_c: [f64; 16] = 120,
        /// End-effector twist (unused here).
        O_dP_EE_c: [f64; 6] = 248,
        /// Elbow (unused here).
        elbow_c: [f64; 2] = 296,
        /// Whether `elbow_c` is valid.
        valid_elbow: bool = 312,
        /// The last commands of a motion.
        motion_generation_finished: bool = 313,
        /// Torques (unused here).
        tau_J_d: [f64; 7] = 314,
    }
);

/// `motion_generator_mode` of the state (off by one from the Move request's enum).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum StateGenerator {
    /// No motion.
    Idle = 0,
    /// Joint positions.
    JointPosition = 1,
    /// Joint velocities.
    JointVelocity = 2,
    /// Cartesian poses.
    CartesianPosition = 3,
    /// Cartesian velocities.
    CartesianVelocity = 4,
}

/// `controller_mode` of the state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum StateController {
    /// Joint impedance.
    JointImpedance = 0,
    /// Cartesian impedance.
    CartesianImpedance = 1,
    /// External (torques).
    ExternalController = 2,
    /// Other.
    Other = 3,
}

/// `robot_mode` of the state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum RobotMode {
    /// Other.
    Other = 0,
    /// Idle: ready for a Move.
    Idle = 1,
    /// A motion is running.
    Move = 2,
    /// Hand guiding.
    Guiding = 3,
    /// A reflex stopped the robot.
    Reflex = 4,
    /// The user stop is pressed.
    UserStopped = 5,
    /// Recovering from an error.
    AutomaticErrorRecovery = 6,
}

impl RobotState {
    /// Whether a joint-velocity motion is running: generator JointVelocity, controller
    /// JointImpedance, robot mode Move.
    pub fn joint_velocity_motion_running(&self) -> bool {
        self.motion_generator_mode == StateGenerator::JointVelocity as u8
            && self.controller_mode == StateController::JointImpedance as u8
            && self.robot_mode == RobotMode::Move as u8
    }

    /// Whether the robot is idle (no motion generator, robot mode Idle).
    pub fn idle(&self) -> bool {
        self.motion_generator_mode == StateGenerator::Idle as u8
            && self.robot_mode == RobotMode::Idle as u8
    }

    /// Whether the robot is in a reflex.
    pub fn in_reflex(&self) -> bool {
        self.robot_mode == RobotMode::Reflex as u8
    }

    /// Indices of the errors set.
    pub fn active_errors(&self) -> impl Iterator<Item = usize> + '_ {
        self.errors
            .iter()
            .enumerate()
            .filter_map(|(i, &e)| e.then_some(i))
    }
}

impl RobotCommand {
    /// A joint-velocity command answering state `message_id`; every other field zero.
    pub fn joint_velocity(message_id: u64, dq_c: [f64; 7], finished: bool) -> Self {
        Self {
            message_id,
            dq_c,
            motion_generation_finished: finished,
            ..Self::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_layout(fields: &[(&str, usize, usize)], size: usize) {
        let mut at = 0;
        for &(name, offset, len) in fields {
            assert_eq!(
                offset, at,
                "field {name} is not right after the previous one"
            );
            at += len;
        }
        assert_eq!(at, size);
    }

    #[test]
    fn the_layouts_are_contiguous_and_of_the_listed_sizes() {
        check_layout(RobotState::FIELDS, 2373);
        check_layout(RobotCommand::FIELDS, 370);
        assert_eq!(RobotState::SIZE, 2373);
        assert_eq!(RobotCommand::SIZE, 370);
        let offset = |name: &str| {
            RobotState::FIELDS
                .iter()
                .find(|f| f.0 == name)
                .map(|f| f.1)
                .unwrap()
        };
        assert_eq!(offset("q"), 1184);
        assert_eq!(offset("dq"), 1296);
        assert_eq!(offset("dq_d"), 1352);
        assert_eq!(offset("ddq_d"), 1408);
        assert_eq!(offset("errors"), 2282);
        assert_eq!(offset("robot_mode"), 2364);
        assert_eq!(offset("control_command_success_rate"), 2365);
    }

    #[test]
    fn robot_state_fields_sit_at_their_offsets() {
        let mut s = RobotState {
            message_id: 0x0102_0304_0506_0708,
            motion_generator_mode: 2,
            controller_mode: 0,
            robot_mode: 4,
            control_command_success_rate: 0.5,
            ..RobotState::default()
        };
        s.q[0] = 1.0;
        s.dq[6] = -2.0;
        s.dq_d[3] = 0.25;
        s.ddq_d[1] = 4.0;
        s.errors[COMMUNICATION_CONSTRAINTS_VIOLATION] = true;
        s.reflex_reason[COMMUNICATION_CONSTRAINTS_VIOLATION] = true;
        let b = s.encode();
        let mut expected = vec![0u8; 2373];
        expected[0..8].copy_from_slice(&[8, 7, 6, 5, 4, 3, 2, 1]);
        expected[1184..1192].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0xf0, 0x3f]);
        expected[1296 + 48..1296 + 56].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0, 0xc0]);
        expected[1352 + 24..1352 + 32].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0xd0, 0x3f]);
        expected[1408 + 8..1408 + 16].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0x10, 0x40]);
        expected[2280] = 2;
        expected[2282 + 25] = 1;
        expected[2323 + 25] = 1;
        expected[2364] = 4;
        expected[2365..2373].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0xe0, 0x3f]);
        assert_eq!(b.to_vec(), expected);
        let back = RobotState::decode(&b).unwrap();
        assert_eq!(back, s);
        assert!(back.in_reflex());
        assert_eq!(back.active_errors().collect::<Vec<_>>(), vec![25]);
    }

    #[test]
    fn robot_command_fields_sit_at_their_offsets() {
        let mut dq = [0.0; 7];
        dq[0] = 1.0;
        dq[6] = 0.5;
        let c = RobotCommand::joint_velocity(42, dq, true);
        let b = c.encode();
        let mut expected = vec![0u8; 370];
        expected[0] = 42;
        expected[64..72].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0xf0, 0x3f]);
        expected[64 + 48..64 + 56].copy_from_slice(&[0, 0, 0, 0, 0, 0, 0xe0, 0x3f]);
        expected[313] = 1;
        assert_eq!(b.to_vec(), expected);
        assert_eq!(RobotCommand::decode(&b), Ok(c));
    }

    #[test]
    fn a_datagram_of_the_wrong_size_is_an_error() {
        assert_eq!(
            RobotState::decode(&[0u8; 2372]),
            Err(ProtocolError::WrongSize {
                message: "RobotState",
                expected: 2373,
                got: 2372
            })
        );
        assert_eq!(
            RobotCommand::decode(&[0u8; 371]),
            Err(ProtocolError::WrongSize {
                message: "RobotCommand",
                expected: 370,
                got: 371
            })
        );
    }

    #[test]
    fn motion_predicates_follow_the_modes() {
        let mut s = RobotState {
            motion_generator_mode: 2,
            controller_mode: 0,
            robot_mode: 2,
            ..RobotState::default()
        };
        assert!(s.joint_velocity_motion_running());
        s.controller_mode = 1;
        assert!(!s.joint_velocity_motion_running());
        s.motion_generator_mode = 0;
        s.robot_mode = 1;
        assert!(s.idle());
    }
}
