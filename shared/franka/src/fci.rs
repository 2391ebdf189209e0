//! FCI TCP messages (robot server protocol version 5, port 1337): the 12-byte header, the
//! requests and their responses, packed little-endian.

use crate::wire::{ProtocolError, Reader, Writer};

/// The robot's TCP port.
pub const FCI_PORT: u16 = 1337;
/// The robot server protocol version this crate speaks.
pub const FCI_VERSION: u16 = 5;
/// Size of the TCP header, bytes.
pub const HEADER_SIZE: usize = 12;
/// Largest TCP message accepted, bytes (the largest request, SetCollisionBehavior, is 428).
pub const MAX_MESSAGE_SIZE: usize = 1024;

/// Generates a `u8`/`u16`/`u32` code enum with a checked conversion from the raw value.
macro_rules! code_enum {
    ($(#[$m:meta])* $name:ident: $repr:ty, $message:literal { $($(#[$vm:meta])* $v:ident = $n:literal),* $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr($repr)]
        pub enum $name {
            $($(#[$vm])* $v = $n),*
        }
        impl $name {
            /// The value from its code; an unknown code is an error naming `field`.
            pub fn from_code(code: $repr, field: &'static str) -> Result<Self, crate::wire::ProtocolError> {
                match code {
                    $($n => Ok(Self::$v),)*
                    other => Err(crate::wire::ProtocolError::UnknownValue {
                        message: $message,
                        field,
                        value: u32::from(other),
                    }),
                }
            }
        }
    };
}
pub(crate) use code_enum;

code_enum!(
    /// FCI command numbers (the header's `command`).
    Command: u32, "FCI header" {
        /// Connect.
        Connect = 0,
        /// Start a motion.
        Move = 1,
        /// Cancel the running motion.
        StopMove = 2,
        /// GetCartesianLimit (not used by this client).
        GetCartesianLimit = 3,
        /// SetCollisionBehavior.
        SetCollisionBehavior = 4,
        /// SetJointImpedance.
        SetJointImpedance = 5,
        /// SetCartesianImpedance.
        SetCartesianImpedance = 6,
        /// SetGuidingMode (not used by this client).
        SetGuidingMode = 7,
        /// SetEEToK (not used by this client).
        SetEeToK = 8,
        /// SetNEToEE (not used by this client).
        SetNeToEe = 9,
        /// SetLoad.
        SetLoad = 10,
        /// SetFilters (not used by this client).
        SetFilters = 11,
        /// Leave a reflex.
        AutomaticErrorRecovery = 12,
        /// LoadModelLibrary (not used by this client).
        LoadModelLibrary = 13,
    }
);

code_enum!(
    /// Connect response status.
    ConnectStatus: u8, "Connect response" {
        /// Connected.
        Success = 0,
        /// The robot speaks another version.
        IncompatibleLibraryVersion = 1,
    }
);

code_enum!(
    /// Move response status.
    MoveStatus: u8, "Move response" {
        /// The motion finished.
        Success = 0,
        /// The motion started (first response).
        MotionStarted = 1,
        /// Another motion replaced it.
        Preempted = 2,
        /// Not possible now (e.g. in Reflex).
        CommandNotPossibleRejected = 3,
        /// The pose is singular.
        StartAtSingularPoseRejected = 4,
        /// A bad mode or deviation.
        InvalidArgumentRejected = 5,
        /// A reflex stopped it.
        ReflexAborted = 6,
        /// The emergency stop stopped it.
        EmergencyAborted = 7,
        /// Bad input stopped it.
        InputErrorAborted = 8,
        /// Aborted otherwise.
        Aborted = 9,
    }
);

code_enum!(
    /// StopMove response status.
    StopMoveStatus: u8, "StopMove response" {
        /// Stopped.
        Success = 0,
        /// Rejected.
        Rejected = 1,
        /// Emergency stop.
        EmergencyAborted = 2,
        /// A reflex.
        ReflexAborted = 3,
        /// Aborted otherwise.
        Aborted = 4,
    }
);

code_enum!(
    /// Setter response status (SetCollisionBehavior, SetJointImpedance, ...).
    SetterStatus: u8, "setter response" {
        /// Applied.
        Success = 0,
        /// Not possible now.
        CommandNotPossibleRejected = 1,
        /// Bad values.
        InvalidArgumentRejected = 2,
    }
);

code_enum!(
    /// AutomaticErrorRecovery response status (libfranka-common `service_types.h`).
    RecoveryStatus: u8, "AutomaticErrorRecovery response" {
        /// Recovered: the robot is idle again.
        Success = 0,
        /// Not possible now.
        CommandNotPossibleRejected = 1,
        /// A manual recovery (user stop) is needed.
        ManualErrorRecoveryRequiredRejected = 2,
        /// A reflex.
        ReflexAborted = 3,
        /// Emergency stop.
        EmergencyAborted = 4,
        /// Aborted otherwise.
        Aborted = 5,
    }
);

code_enum!(
    /// Move `controller_mode`.
    ControllerMode: u32, "Move request" {
        /// The robot's joint impedance controller.
        JointImpedance = 0,
        /// The robot's Cartesian impedance controller.
        CartesianImpedance = 1,
        /// Torques from the client.
        ExternalController = 2,
    }
);

code_enum!(
    /// Move `motion_generator_mode`.
    MotionGeneratorMode: u32, "Move request" {
        /// Joint positions.
        JointPosition = 0,
        /// Joint velocities (the only one this client uses).
        JointVelocity = 1,
        /// Cartesian poses.
        CartesianPosition = 2,
        /// Cartesian velocities.
        CartesianVelocity = 3,
    }
);

/// The 12-byte header of every FCI TCP message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// The command.
    pub command: Command,
    /// Request id (the client counts from 0; a response echoes its request's).
    pub command_id: u32,
    /// Size of the whole message, header included, bytes.
    pub size: u32,
}

impl Header {
    /// The encoded header.
    pub fn encode(&self) -> [u8; HEADER_SIZE] {
        let mut w = Writer::default();
        w.write(self.command as u32)
            .write(self.command_id)
            .write(self.size);
        w.bytes.try_into().expect("12 bytes")
    }

    /// Decodes the header at the start of `bytes` (an unknown command is an error).
    pub fn decode(bytes: &[u8]) -> Result<Self, ProtocolError> {
        let mut r = Reader::new("FCI header", bytes);
        let command = r.read::<u32>("command")?;
        let command_id = r.read("command_id")?;
        let size = r.read("size")?;
        Ok(Self {
            command: Command::from_code(command, "command")?,
            command_id,
            size,
        })
    }
}

/// A Move request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveRequest {
    /// The controller.
    pub controller_mode: ControllerMode,
    /// The motion generator.
    pub motion_generator_mode: MotionGeneratorMode,
    /// Maximum path deviation (translation m, rotation rad, elbow rad).
    pub maximum_path_deviation: [f64; 3],
    /// Maximum goal pose deviation (translation m, rotation rad, elbow rad).
    pub maximum_goal_pose_deviation: [f64; 3],
}

/// The deviations libfranka sends with a joint-velocity Move: `{10.0, 3.12, 2π}`.
pub const JOINT_VELOCITY_DEVIATION: [f64; 3] = [10.0, 3.12, 2.0 * std::f64::consts::PI];

impl MoveRequest {
    /// A joint-velocity motion as libfranka starts one: controller JointImpedance, generator
    /// JointVelocity, both deviations [`JOINT_VELOCITY_DEVIATION`].
    pub fn joint_velocity() -> Self {
        Self {
            controller_mode: ControllerMode::JointImpedance,
            motion_generator_mode: MotionGeneratorMode::JointVelocity,
            maximum_path_deviation: JOINT_VELOCITY_DEVIATION,
            maximum_goal_pose_deviation: JOINT_VELOCITY_DEVIATION,
        }
    }
}

/// SetCollisionBehavior thresholds (N·m for joints, N and N·m for Cartesian).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionBehavior {
    /// Lower torque thresholds while accelerating.
    pub lower_torque_thresholds_acceleration: [f64; 7],
    /// Upper torque thresholds while accelerating.
    pub upper_torque_thresholds_acceleration: [f64; 7],
    /// Lower torque thresholds otherwise.
    pub lower_torque_thresholds_nominal: [f64; 7],
    /// Upper torque thresholds otherwise.
    pub upper_torque_thresholds_nominal: [f64; 7],
    /// Lower force thresholds while accelerating.
    pub lower_force_thresholds_acceleration: [f64; 6],
    /// Upper force thresholds while accelerating.
    pub upper_force_thresholds_acceleration: [f64; 6],
    /// Lower force thresholds otherwise.
    pub lower_force_thresholds_nominal: [f64; 6],
    /// Upper force thresholds otherwise.
    pub upper_force_thresholds_nominal: [f64; 6],
}

/// An FCI request (client to robot). SetCollisionBehavior makes it large (416 bytes); requests
/// are rare (never per cycle), so it stays a plain `Copy` value.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// Connect with `version`; the robot streams states to `udp_port`.
    Connect {
        /// Protocol version ([`FCI_VERSION`]).
        version: u16,
        /// The client's UDP port.
        udp_port: u16,
    },
    /// Start a motion.
    Move(MoveRequest),
    /// Cancel the running motion.
    StopMove,
    /// Leave a reflex.
    AutomaticErrorRecovery,
    /// Collision thresholds.
    SetCollisionBehavior(CollisionBehavior),
    /// Joint stiffness, N·m/rad.
    SetJointImpedance([f64; 7]),
    /// Cartesian stiffness.
    SetCartesianImpedance([f64; 6]),
    /// The payload.
    SetLoad {
        /// Mass, kg.
        mass: f64,
        /// Centre of mass in the flange frame, m.
        f_x_cload: [f64; 3],
        /// Inertia, kg·m², column-major.
        load_inertia: [f64; 9],
    },
}

impl Request {
    /// The command number.
    pub fn command(&self) -> Command {
        match self {
            Self::Connect { .. } => Command::Connect,
            Self::Move(_) => Command::Move,
            Self::StopMove => Command::StopMove,
            Self::AutomaticErrorRecovery => Command::AutomaticErrorRecovery,
            Self::SetCollisionBehavior(_) => Command::SetCollisionBehavior,
            Self::SetJointImpedance(_) => Command::SetJointImpedance,
            Self::SetCartesianImpedance(_) => Command::SetCartesianImpedance,
            Self::SetLoad { .. } => Command::SetLoad,
        }
    }

    /// Total encoded size, bytes.
    pub fn size(&self) -> usize {
        HEADER_SIZE
            + match self {
                Self::Connect { .. } => 4,
                Self::Move(_) => 56,
                Self::StopMove | Self::AutomaticErrorRecovery => 0,
                Self::SetCollisionBehavior(_) => 4 * 56 + 4 * 48,
                Self::SetJointImpedance(_) => 56,
                Self::SetCartesianImpedance(_) => 48,
                Self::SetLoad { .. } => 104,
            }
    }

    /// The encoded message with request id `command_id`.
    pub fn encode(&self, command_id: u32) -> Vec<u8> {
        let header = Header {
            command: self.command(),
            command_id,
            size: self.size() as u32,
        };
        let mut w = Writer::default();
        w.write(header.encode());
        match self {
            Self::Connect { version, udp_port } => {
                w.write(*version).write(*udp_port);
            }
            Self::Move(m) => {
                w.write(m.controller_mode as u32)
                    .write(m.motion_generator_mode as u32)
                    .write(m.maximum_path_deviation)
                    .write(m.maximum_goal_pose_deviation);
            }
            Self::StopMove | Self::AutomaticErrorRecovery => {}
            Self::SetCollisionBehavior(c) => {
                w.write(c.lower_torque_thresholds_acceleration)
                    .write(c.upper_torque_thresholds_acceleration)
                    .write(c.lower_torque_thresholds_nominal)
                    .write(c.upper_torque_thresholds_nominal)
                    .write(c.lower_force_thresholds_acceleration)
                    .write(c.upper_force_thresholds_acceleration)
                    .write(c.lower_force_thresholds_nominal)
                    .write(c.upper_force_thresholds_nominal);
            }
            Self::SetJointImpedance(k) => {
                w.write(*k);
            }
            Self::SetCartesianImpedance(k) => {
                w.write(*k);
            }
            Self::SetLoad {
                mass,
                f_x_cload,
                load_inertia,
            } => {
                w.write(*mass).write(*f_x_cload).write(*load_inertia);
            }
        }
        debug_assert_eq!(w.bytes.len(), self.size());
        w.bytes
    }

    /// Decodes one whole request message (header included); returns its id and the request.
    /// Commands this crate does not implement are [`ProtocolError::UnknownCommand`].
    pub fn decode(bytes: &[u8]) -> Result<(u32, Self), ProtocolError> {
        const M: &str = "FCI request";
        let header = Header::decode(bytes)?;
        check_size(M, &header, bytes)?;
        let mut r = Reader::new(M, &bytes[HEADER_SIZE..]);
        let request = match header.command {
            Command::Connect => Self::Connect {
                version: r.read("version")?,
                udp_port: r.read("udp_port")?,
            },
            Command::Move => Self::Move(MoveRequest {
                controller_mode: ControllerMode::from_code(
                    r.read("controller_mode")?,
                    "controller_mode",
                )?,
                motion_generator_mode: MotionGeneratorMode::from_code(
                    r.read("motion_generator_mode")?,
                    "motion_generator_mode",
                )?,
                maximum_path_deviation: r.read("maximum_path_deviation")?,
                maximum_goal_pose_deviation: r.read("maximum_goal_pose_deviation")?,
            }),
            Command::StopMove => Self::StopMove,
            Command::AutomaticErrorRecovery => Self::AutomaticErrorRecovery,
            Command::SetCollisionBehavior => Self::SetCollisionBehavior(CollisionBehavior {
                lower_torque_thresholds_acceleration: r.read("lower_torque_acceleration")?,
                upper_torque_thresholds_acceleration: r.read("upper_torque_acceleration")?,
                lower_torque_thresholds_nominal: r.read("lower_torque_nominal")?,
                upper_torque_thresholds_nominal: r.read("upper_torque_nominal")?,
                lower_force_thresholds_acceleration: r.read("lower_force_acceleration")?,
                upper_force_thresholds_acceleration: r.read("upper_force_acceleration")?,
                lower_force_thresholds_nominal: r.read("lower_force_nominal")?,
                upper_force_thresholds_nominal: r.read("upper_force_nominal")?,
            }),
            Command::SetJointImpedance => Self::SetJointImpedance(r.read("K_theta")?),
            Command::SetCartesianImpedance => Self::SetCartesianImpedance(r.read("K_x")?),
            Command::SetLoad => Self::SetLoad {
                mass: r.read("m_load")?,
                f_x_cload: r.read("F_x_Cload")?,
                load_inertia: r.read("I_load")?,
            },
            other => {
                return Err(ProtocolError::UnknownCommand {
                    message: M,
                    command: other as u32,
                });
            }
        };
        r.finish()?;
        Ok((header.command_id, request))
    }
}

/// An FCI response (robot to client).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response {
    /// Connect: status and the robot's version.
    Connect {
        /// Status.
        status: ConnectStatus,
        /// The robot's protocol version.
        version: u16,
    },
    /// Move (sent twice: `MotionStarted`, then how it ended).
    Move(MoveStatus),
    /// StopMove.
    StopMove(StopMoveStatus),
    /// AutomaticErrorRecovery.
    AutomaticErrorRecovery(RecoveryStatus),
    /// A setter (`command` is one of the Set* commands).
    Setter {
        /// Which setter.
        command: Command,
        /// Status.
        status: SetterStatus,
    },
}

impl Response {
    /// The command number.
    pub fn command(&self) -> Command {
        match self {
            Self::Connect { .. } => Command::Connect,
            Self::Move(_) => Command::Move,
            Self::StopMove(_) => Command::StopMove,
            Self::AutomaticErrorRecovery(_) => Command::AutomaticErrorRecovery,
            Self::Setter { command, .. } => *command,
        }
    }

    /// Total encoded size, bytes (15 for Connect, 13 otherwise).
    pub fn size(&self) -> usize {
        match self {
            Self::Connect { .. } => HEADER_SIZE + 3,
            _ => HEADER_SIZE + 1,
        }
    }

    /// The encoded message answering request `command_id`.
    pub fn encode(&self, command_id: u32) -> Vec<u8> {
        let header = Header {
            command: self.command(),
            command_id,
            size: self.size() as u32,
        };
        let mut w = Writer::default();
        w.write(header.encode());
        match self {
            Self::Connect { status, version } => {
                w.write(*status as u8).write(*version);
            }
            Self::Move(s) => {
                w.write(*s as u8);
            }
            Self::StopMove(s) => {
                w.write(*s as u8);
            }
            Self::AutomaticErrorRecovery(s) => {
                w.write(*s as u8);
            }
            Self::Setter { status, .. } => {
                w.write(*status as u8);
            }
        }
        w.bytes
    }

    /// Decodes one whole response message (header included); returns its id and the response.
    pub fn decode(bytes: &[u8]) -> Result<(u32, Self), ProtocolError> {
        const M: &str = "FCI response";
        let header = Header::decode(bytes)?;
        check_size(M, &header, bytes)?;
        let mut r = Reader::new(M, &bytes[HEADER_SIZE..]);
        let response = match header.command {
            Command::Connect => Self::Connect {
                status: ConnectStatus::from_code(r.read("status")?, "status")?,
                version: r.read("version")?,
            },
            Command::Move => Self::Move(MoveStatus::from_code(r.read("status")?, "status")?),
            Command::StopMove => {
                Self::StopMove(StopMoveStatus::from_code(r.read("status")?, "status")?)
            }
            Command::AutomaticErrorRecovery => Self::AutomaticErrorRecovery(
                RecoveryStatus::from_code(r.read("status")?, "status")?,
            ),
            command @ (Command::SetCollisionBehavior
            | Command::SetJointImpedance
            | Command::SetCartesianImpedance
            | Command::SetLoad) => Self::Setter {
                command,
                status: SetterStatus::from_code(r.read("status")?, "status")?,
            },
            other => {
                return Err(ProtocolError::UnknownCommand {
                    message: M,
                    command: other as u32,
                });
            }
        };
        r.finish()?;
        Ok((header.command_id, response))
    }
}

/// Checks the header's size against the bytes of the message.
fn check_size(message: &'static str, header: &Header, bytes: &[u8]) -> Result<(), ProtocolError> {
    if header.size as usize != bytes.len() {
        return Err(ProtocolError::WrongSize {
            message,
            expected: header.size as usize,
            got: bytes.len(),
        });
    }
    Ok(())
}

/// Reassembles messages from a TCP byte stream whose header carries the whole message's size
/// as a `u32` at `size_offset` (FCI: 12-byte header, size at 8; hand: 10-byte header, size
/// at 6).
#[derive(Debug, Clone)]
pub struct Framer {
    message: &'static str,
    header_size: usize,
    size_offset: usize,
    buffer: Vec<u8>,
}

impl Framer {
    /// A framer for FCI messages.
    pub fn fci() -> Self {
        Self::new("FCI message", HEADER_SIZE, 8)
    }

    /// A framer for headers of `header_size` bytes with the size at `size_offset`.
    pub fn new(message: &'static str, header_size: usize, size_offset: usize) -> Self {
        Self {
            message,
            header_size,
            size_offset,
            buffer: Vec::with_capacity(2 * MAX_MESSAGE_SIZE),
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buffer.extend_from_slice(bytes);
    }

    /// Bytes held that do not yet form a whole message.
    pub fn pending(&self) -> usize {
        self.buffer.len()
    }

    /// The next whole message, if one has arrived. A size field below the header's size or
    /// above [`MAX_MESSAGE_SIZE`] is an error (the stream cannot be resynchronised).
    pub fn next_message(&mut self) -> Result<Option<Vec<u8>>, ProtocolError> {
        if self.buffer.len() < self.header_size {
            return Ok(None);
        }
        let size = u32::from_le_bytes(
            self.buffer[self.size_offset..self.size_offset + 4]
                .try_into()
                .expect("4 bytes"),
        ) as usize;
        if size < self.header_size || size > MAX_MESSAGE_SIZE {
            return Err(ProtocolError::WrongSize {
                message: self.message,
                expected: self.header_size,
                got: size,
            });
        }
        if self.buffer.len() < size {
            return Ok(None);
        }
        let rest = self.buffer.split_off(size);
        Ok(Some(std::mem::replace(&mut self.buffer, rest)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Little-endian bytes of a list of f64.
    fn f64s(values: &[f64]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn connect_request_is_16_bytes_byte_for_byte() {
        let bytes = Request::Connect {
            version: 5,
            udp_port: 0x1234,
        }
        .encode(7);
        assert_eq!(
            bytes,
            [0, 0, 0, 0, 7, 0, 0, 0, 16, 0, 0, 0, 5, 0, 0x34, 0x12]
        );
        assert_eq!(
            Request::decode(&bytes),
            Ok((
                7,
                Request::Connect {
                    version: 5,
                    udp_port: 0x1234
                }
            ))
        );
    }

    #[test]
    fn connect_response_is_15_bytes_byte_for_byte() {
        let r = Response::Connect {
            status: ConnectStatus::IncompatibleLibraryVersion,
            version: 4,
        };
        let bytes = r.encode(0);
        assert_eq!(bytes, [0, 0, 0, 0, 0, 0, 0, 0, 15, 0, 0, 0, 1, 4, 0]);
        assert_eq!(Response::decode(&bytes), Ok((0, r)));
    }

    #[test]
    fn move_request_is_68_bytes_byte_for_byte() {
        let bytes = Request::Move(MoveRequest::joint_velocity()).encode(1);
        let mut expected = vec![1, 0, 0, 0, 1, 0, 0, 0, 68, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0];
        let dev = f64s(&[10.0, 3.12, std::f64::consts::TAU]);
        expected.extend_from_slice(&dev);
        expected.extend_from_slice(&dev);
        assert_eq!(bytes.len(), 68);
        assert_eq!(bytes, expected);
        assert_eq!(
            Request::decode(&bytes),
            Ok((1, Request::Move(MoveRequest::joint_velocity())))
        );
    }

    #[test]
    fn status_responses_are_13_bytes_byte_for_byte() {
        let cases = [
            (Response::Move(MoveStatus::MotionStarted), 1u8, 1u8),
            (Response::Move(MoveStatus::ReflexAborted), 1, 6),
            (Response::StopMove(StopMoveStatus::Success), 2, 0),
            (
                Response::AutomaticErrorRecovery(RecoveryStatus::Success),
                12,
                0,
            ),
            (
                Response::Setter {
                    command: Command::SetJointImpedance,
                    status: SetterStatus::InvalidArgumentRejected,
                },
                5,
                2,
            ),
        ];
        for (r, command, status) in cases {
            let bytes = r.encode(9);
            assert_eq!(
                bytes,
                [command, 0, 0, 0, 9, 0, 0, 0, 13, 0, 0, 0, status],
                "{r:?}"
            );
            assert_eq!(Response::decode(&bytes), Ok((9, r)));
        }
    }

    #[test]
    fn header_only_requests_are_12_bytes() {
        assert_eq!(
            Request::StopMove.encode(3),
            [2, 0, 0, 0, 3, 0, 0, 0, 12, 0, 0, 0]
        );
        assert_eq!(
            Request::AutomaticErrorRecovery.encode(4),
            [12, 0, 0, 0, 4, 0, 0, 0, 12, 0, 0, 0]
        );
    }

    #[test]
    fn setter_requests_have_the_listed_sizes_and_round_trip() {
        let c = CollisionBehavior {
            lower_torque_thresholds_acceleration: [1.0; 7],
            upper_torque_thresholds_acceleration: [2.0; 7],
            lower_torque_thresholds_nominal: [3.0; 7],
            upper_torque_thresholds_nominal: [4.0; 7],
            lower_force_thresholds_acceleration: [5.0; 6],
            upper_force_thresholds_acceleration: [6.0; 6],
            lower_force_thresholds_nominal: [7.0; 6],
            upper_force_thresholds_nominal: [8.0; 6],
        };
        let cases = [
            (Request::SetCollisionBehavior(c), 428),
            (Request::SetJointImpedance([3000.0; 7]), 68),
            (Request::SetCartesianImpedance([100.0; 6]), 60),
            (
                Request::SetLoad {
                    mass: 0.5,
                    f_x_cload: [0.0, 0.0, 0.1],
                    load_inertia: [0.01; 9],
                },
                116,
            ),
        ];
        for (r, size) in cases {
            let bytes = r.encode(2);
            assert_eq!(bytes.len(), size, "{r:?}");
            assert_eq!(&bytes[8..12], &(size as u32).to_le_bytes());
            assert_eq!(Request::decode(&bytes), Ok((2, r)));
        }
        let bytes = Request::SetJointImpedance([1.5; 7]).encode(0);
        assert_eq!(&bytes[12..20], &1.5f64.to_le_bytes());
    }

    #[test]
    fn bad_messages_are_typed_errors() {
        // Unknown command number.
        let mut bytes = Request::StopMove.encode(0);
        bytes[0] = 99;
        assert_eq!(
            Request::decode(&bytes),
            Err(ProtocolError::UnknownValue {
                message: "FCI header",
                field: "command",
                value: 99
            })
        );
        // Truncated header.
        assert!(matches!(
            Header::decode(&[0, 0, 0, 0, 1]),
            Err(ProtocolError::Truncated {
                field: "command_id",
                ..
            })
        ));
        // Header size disagrees with the bytes.
        let bytes = Request::Move(MoveRequest::joint_velocity()).encode(0);
        assert_eq!(
            Request::decode(&bytes[..40]),
            Err(ProtocolError::WrongSize {
                message: "FCI request",
                expected: 68,
                got: 40
            })
        );
        // Unknown status.
        let mut bytes = Response::Move(MoveStatus::Success).encode(0);
        bytes[12] = 42;
        assert_eq!(
            Response::decode(&bytes),
            Err(ProtocolError::UnknownValue {
                message: "Move response",
                field: "status",
                value: 42
            })
        );
        // A command this crate does not implement.
        let mut bytes = Request::StopMove.encode(0);
        bytes[0] = Command::LoadModelLibrary as u8;
        assert_eq!(
            Request::decode(&bytes),
            Err(ProtocolError::UnknownCommand {
                message: "FCI request",
                command: 13
            })
        );
    }

    #[test]
    fn the_framer_splits_a_stream_and_rejects_bad_sizes() {
        let mut f = Framer::fci();
        let a = Request::StopMove.encode(0);
        let b = Request::Connect {
            version: 5,
            udp_port: 1,
        }
        .encode(1);
        let stream = [a.clone(), b.clone()].concat();
        f.push(&stream[..5]);
        assert_eq!(f.next_message(), Ok(None));
        f.push(&stream[5..20]);
        assert_eq!(f.next_message(), Ok(Some(a)));
        assert_eq!(f.next_message(), Ok(None));
        f.push(&stream[20..]);
        assert_eq!(f.next_message(), Ok(Some(b)));
        assert_eq!(f.pending(), 0);
        f.push(&[0, 0, 0, 0, 0, 0, 0, 0, 3, 0, 0, 0]);
        assert!(matches!(
            f.next_message(),
            Err(ProtocolError::WrongSize { got: 3, .. })
        ));
    }
}
