//! The payload types and the plausibility envelope their fields are checked against.

use iceoryx2::prelude::ZeroCopySend;

use crate::validate::Check;
use crate::{Header, Message, RejectReason, Rejection};

/// Largest arm supported by the fixed-size joint arrays: Fetch's torso lift and seven arm joints
/// (the Panda has 7, the UR5 6). At 7 every Fetch joint state was rejected (`joint_count` out of
/// range) and nothing moved.
pub const MAX_ARM_JOINTS: usize = 8;

/// Palm camera image width, pixels (docs/algorithms.md: 320×240 RGB8).
pub const CAMERA_WIDTH: usize = 320;
/// Palm camera image height, pixels.
pub const CAMERA_HEIGHT: usize = 240;
/// Bytes per camera pixel (RGB8).
pub const CAMERA_CHANNELS: usize = 3;
/// Size of one camera image, bytes.
pub const CAMERA_IMAGE_BYTES: usize = CAMERA_WIDTH * CAMERA_HEIGHT * CAMERA_CHANNELS;

/// Capacity of the fixed-size process name in a [`Heartbeat`], bytes (UTF-8, zero padded).
pub const PROCESS_NAME_BYTES: usize = 32;

/// Physical plausibility envelope that received values are checked against. These bounds reject
/// garbage (corrupt or mis-scaled data); the robot's own, tighter limits are enforced by the
/// drivers whatever reaches them.
pub mod envelope {
    /// Largest accepted |joint position|, rad (continuous joints may wind a few turns).
    pub const JOINT_POSITION: f64 = 50.0;
    /// Largest accepted |joint velocity|, rad/s (the Panda's fastest joint is 2.61 rad/s).
    pub const JOINT_VELOCITY: f64 = 10.0;
    /// Largest accepted |world coordinate|, m.
    pub const WORLD_POSITION: f64 = 1000.0;
    /// Largest accepted |base forward speed|, m/s.
    pub const BASE_SPEED: f64 = 3.0;
    /// Largest accepted |base or end-effector angular speed|, rad/s.
    pub const ANGULAR_SPEED: f64 = 10.0;
    /// Largest accepted |end-effector linear speed| per axis, m/s.
    pub const EE_SPEED: f64 = 3.0;
    /// Largest accepted |tracked object speed| per axis, m/s.
    pub const OBJECT_SPEED: f64 = 5.0;
    /// Largest accepted gripper opening, m.
    pub const GRIPPER_WIDTH: f64 = 0.2;
    /// Largest accepted time-to-range, s.
    pub const TIME_TO_RANGE: f64 = 3600.0;
}

/// Declares a `#[repr(u32)]` enumeration carried as a raw code, with `TryFrom<u32>`.
macro_rules! code_enum {
    ($(#[$meta:meta])* $name:ident { $($(#[$vmeta:meta])* $variant:ident = $code:literal),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u32)]
        pub enum $name {
            $($(#[$vmeta])* $variant = $code),+
        }

        impl TryFrom<u32> for $name {
            type Error = u32;

            fn try_from(code: u32) -> Result<Self, u32> {
                match code {
                    $($code => Ok(Self::$variant),)+
                    other => Err(other),
                }
            }
        }

        impl From<$name> for u32 {
            fn from(value: $name) -> u32 {
                value as u32
            }
        }
    };
}

/// Implements [`Message`] for a payload with a `header` field; `$check` and `$msg` name the
/// field checker and the message inside the validation body.
macro_rules! message {
    ($ty:ident, instants = [$($instant:ident),+], published = $field:ident, |$msg:ident, $check:ident| $body:block) => {
        message!(@impl $ty, |$msg, $check| $body, {
            fn publication_stamp_mut(&mut self) -> Option<&mut u64> {
                Some(&mut self.$field)
            }

            fn for_each_instant(&mut self, f: &mut dyn FnMut(&mut u64)) {
                f(&mut self.header.stamp_ns);
                $(f(&mut self.$instant);)+
            }
        });
    };
    ($ty:ident, instants = [$($instant:ident),+], |$msg:ident, $check:ident| $body:block) => {
        message!(@impl $ty, |$msg, $check| $body, {
            fn for_each_instant(&mut self, f: &mut dyn FnMut(&mut u64)) {
                f(&mut self.header.stamp_ns);
                $(f(&mut self.$instant);)+
            }
        });
    };
    ($ty:ident, published = $field:ident, |$msg:ident, $check:ident| $body:block) => {
        message!(@impl $ty, |$msg, $check| $body, {
            fn publication_stamp_mut(&mut self) -> Option<&mut u64> {
                Some(&mut self.$field)
            }
        });
    };
    ($ty:ident, |$msg:ident, $check:ident| $body:block) => {
        message!(@impl $ty, |$msg, $check| $body, {});
    };
    (@impl $ty:ident, |$msg:ident, $check:ident| $body:block, { $($extra:item)* }) => {
        // SAFETY: every field of the payload is an integer, a float or an array of them.
        unsafe impl Message for $ty {
            const NAME: &'static str = stringify!($ty);

            fn header(&self) -> &Header {
                &self.header
            }

            fn header_mut(&mut self) -> &mut Header {
                &mut self.header
            }

            fn validate_fields(&self) -> Result<(), Rejection> {
                let $msg = self;
                let $check = Check {
                    message: stringify!($ty),
                };
                $body
            }

            $($extra)*
        }
    };
}

/// Accepts a boolean flag carried as `0` or `1`.
fn flag(check: Check, field: &'static str, value: u32) -> Result<bool, Rejection> {
    match value {
        0 => Ok(false),
        1 => Ok(true),
        other => Err(check.reject(field, None, RejectReason::UnknownCode(other))),
    }
}

/// Accepts an explicit padding field only when it is zero.
fn padding(check: Check, value: u32) -> Result<(), Rejection> {
    if value == 0 {
        Ok(())
    } else {
        Err(check.reject(
            "reserved",
            None,
            RejectReason::Inconsistent("padding must be zero"),
        ))
    }
}

/// Arm joint positions and velocities, from the arm driver (or the simulated hardware).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.JointState")]
#[repr(C)]
pub struct JointState {
    /// Common header.
    pub header: Header,
    /// Number of arm joints in use (1..=[`MAX_ARM_JOINTS`]); entries past it are zero.
    pub joint_count: u32,
    /// Explicit padding; always zero.
    pub reserved: u32,
    /// Joint positions, rad.
    pub position: [f64; MAX_ARM_JOINTS],
    /// Joint velocities, rad/s.
    pub velocity: [f64; MAX_ARM_JOINTS],
}

message!(JointState, |m, c| {
    let n = c.count("joint_count", m.joint_count, MAX_ARM_JOINTS)?;
    padding(c, m.reserved)?;
    c.joint_array("position", &m.position, n, envelope::JOINT_POSITION)?;
    c.joint_array("velocity", &m.velocity, n, envelope::JOINT_VELOCITY)
});

/// Gripper opening and grasp flag, from the arm driver.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.GripperState")]
#[repr(C)]
pub struct GripperState {
    /// Common header.
    pub header: Header,
    /// Finger opening, m.
    pub width: f64,
    /// 1 when an object is held, 0 otherwise.
    pub grasping: u32,
    /// Explicit padding; always zero.
    pub reserved: u32,
}

message!(GripperState, |m, c| {
    c.in_range("width", m.width, 0.0, envelope::GRIPPER_WIDTH)?;
    flag(c, "grasping", m.grasping)?;
    padding(c, m.reserved)
});

/// Base pose and velocity from odometry (world frame; yaw wrapped to [-π, π]).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.BaseOdometry")]
#[repr(C)]
pub struct BaseOdometry {
    /// Common header.
    pub header: Header,
    /// Base x in the world, m.
    pub x: f64,
    /// Base y in the world, m.
    pub y: f64,
    /// Base heading, rad, in [-π, π].
    pub yaw: f64,
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
}

message!(BaseOdometry, |m, c| {
    c.in_range(
        "x",
        m.x,
        -envelope::WORLD_POSITION,
        envelope::WORLD_POSITION,
    )?;
    c.in_range(
        "y",
        m.y,
        -envelope::WORLD_POSITION,
        envelope::WORLD_POSITION,
    )?;
    c.in_range("yaw", m.yaw, -core::f64::consts::PI, core::f64::consts::PI)?;
    c.in_range("v", m.v, -envelope::BASE_SPEED, envelope::BASE_SPEED)?;
    c.in_range(
        "omega",
        m.omega,
        -envelope::ANGULAR_SPEED,
        envelope::ANGULAR_SPEED,
    )
});

/// Base velocity (unicycle): the base planner's target, the QP's command to the base driver,
/// and the driver's command to the (simulated) hardware.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.BaseVelocityCommand")]
#[repr(C)]
pub struct BaseVelocityCommand {
    /// Common header.
    pub header: Header,
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
    /// Id of the resolver instance that computed the command (see
    /// [`ArmVelocityCommand::resolver_id`]).
    pub resolver_id: u32,
    /// Explicit padding; always zero.
    pub reserved: u32,
}

message!(BaseVelocityCommand, |m, c| {
    padding(c, m.reserved)?;
    c.in_range("v", m.v, -envelope::BASE_SPEED, envelope::BASE_SPEED)?;
    c.in_range(
        "omega",
        m.omega,
        -envelope::ANGULAR_SPEED,
        envelope::ANGULAR_SPEED,
    )
});

/// Arm joint velocity command: from the QP to the arm driver, and from the driver to the
/// (simulated) hardware.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.ArmVelocityCommand")]
#[repr(C)]
pub struct ArmVelocityCommand {
    /// Common header.
    pub header: Header,
    /// Number of arm joints in use (1..=[`MAX_ARM_JOINTS`]); entries past it are zero.
    pub joint_count: u32,
    /// Id of the resolver instance that computed the command (the primary's or its hot
    /// standby's; 0 for other senders), so a driver takes one instance's stream.
    pub resolver_id: u32,
    /// Joint velocities, rad/s.
    pub velocity: [f64; MAX_ARM_JOINTS],
}

message!(ArmVelocityCommand, |m, c| {
    let n = c.count("joint_count", m.joint_count, MAX_ARM_JOINTS)?;
    c.joint_array("velocity", &m.velocity, n, envelope::JOINT_VELOCITY)
});

code_enum!(
    /// What the gripper should do.
    GripperAction {
        /// Open the fingers.
        Open = 1,
        /// Close the fingers (grasp).
        Close = 2,
    }
);

/// Gripper command from the final-phase controller to the arm driver.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.GripperCommand")]
#[repr(C)]
pub struct GripperCommand {
    /// Common header.
    pub header: Header,
    /// Id of the controller that sent it (consumers drop commands of inactive controllers).
    pub controller_id: u32,
    /// [`GripperAction`] code.
    pub action: u32,
}

impl GripperCommand {
    /// The action, if the code is valid.
    pub fn action(&self) -> Option<GripperAction> {
        GripperAction::try_from(self.action).ok()
    }
}

message!(GripperCommand, |m, c| {
    c.code::<GripperAction>("action", m.action).map(|_| ())
});

code_enum!(
    /// Phase of the current task (mirrors `motm_core::Phase`).
    TaskPhase {
        /// Reaching towards the target while the base moves.
        Reach = 0,
        /// Final approach and grasp, place or press.
        Final = 1,
        /// The task is done.
        Complete = 2,
    }
);

/// End-effector twist target from the active phase controller (reacher or final phase).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.TwistCommand")]
#[repr(C)]
pub struct TwistCommand {
    /// Common header.
    pub header: Header,
    /// Id of the controller that sent it (consumers drop commands of inactive controllers).
    pub controller_id: u32,
    /// [`TaskPhase`] code the twist belongs to.
    pub phase: u32,
    /// Twist in the world frame `[vx, vy, vz, wx, wy, wz]`, m/s and rad/s.
    pub twist: [f64; 6],
    /// Index of the mission task the twist was computed for (consumers drop twists of another
    /// task).
    pub task_index: u32,
    /// [`TaskProgressCode`] of that task as the sending controller sees it (the final-phase
    /// controller reports `Done` when its task's motion is complete; the reacher always
    /// reports `Active`).
    pub progress: u32,
}

impl TwistCommand {
    /// The phase, if the code is valid.
    pub fn phase(&self) -> Option<TaskPhase> {
        TaskPhase::try_from(self.phase).ok()
    }

    /// The task progress, if the code is valid.
    pub fn progress(&self) -> Option<TaskProgressCode> {
        TaskProgressCode::try_from(self.progress).ok()
    }
}

message!(TwistCommand, |m, c| {
    c.code::<TaskPhase>("phase", m.phase)?;
    c.code::<TaskProgressCode>("progress", m.progress)?;
    for i in 0..6 {
        let max = if i < 3 {
            envelope::EE_SPEED
        } else {
            envelope::ANGULAR_SPEED
        };
        c.in_range_at("twist", Some(i), m.twist[i], -max, max)?;
    }
    Ok(())
});

/// Estimate of the current target object from perception (world frame).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.TargetEstimate")]
#[repr(C)]
pub struct TargetEstimate {
    /// Common header.
    pub header: Header,
    /// Stamp of the camera image the estimate was last updated from, ns (≤ `header.stamp_ns`).
    pub image_stamp_ns: u64,
    /// Publication time of that image ([`CameraImage::image_published_ns`]), ns: at or after
    /// `image_stamp_ns`, at or before `header.stamp_ns`; 0 when unknown.
    pub image_published_ns: u64,
    /// Object centre in the world, m.
    pub position: [f64; 3],
    /// Object velocity in the world, m/s.
    pub velocity: [f64; 3],
    /// 1 when the object was seen in that image, 0 when the estimate is a prediction.
    pub visible: u32,
    /// Index of the mission task the estimate was made for.
    pub task_index: u32,
}

message!(
    TargetEstimate,
    instants = [image_stamp_ns, image_published_ns],
    |m, c| {
        if m.image_stamp_ns > m.header.stamp_ns {
            return Err(c.reject(
                "image_stamp_ns",
                None,
                RejectReason::Inconsistent("image stamp after the estimate's own stamp"),
            ));
        }
        image_published(c, m.image_stamp_ns, m.image_published_ns, m.header.stamp_ns)?;
        c.all_within("position", &m.position, envelope::WORLD_POSITION)?;
        c.all_within("velocity", &m.velocity, envelope::OBJECT_SPEED)?;
        flag(c, "visible", m.visible)?;
        c.in_range(
            "task_index",
            f64::from(m.task_index),
            0.0,
            f64::from(u16::MAX),
        )
    }
);

/// Base planner output: where the base passes closest to the target and when the target
/// enters manipulation range.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.BasePlan")]
#[repr(C)]
pub struct BasePlan {
    /// Common header.
    pub header: Header,
    /// Closest-approach base pose `[x, y, yaw]`, m and rad.
    pub closest_approach: [f64; 3],
    /// Predicted time until the target is within manipulation range, s (0 when in range).
    pub time_to_range: f64,
    /// Base pose `[x, y, yaw]` predicted at `time_to_range` (the current pose when that is
    /// zero), m and rad.
    pub range_entry_pose: [f64; 3],
    /// Index of the mission task the plan was made for (consumers drop plans of another task).
    pub task_index: u32,
    /// 1 once the base has gone by the target (latched until the task changes), 0 before.
    pub passed: u32,
    /// Passes of the target the base has missed (the task still not done well past it) and
    /// come around for.
    pub missed_passes: u32,
    /// 1 once the base has given the target up (its reactive approach missed too): the
    /// mission reports the task failed and goes on.
    pub gave_up: u32,
}

message!(BasePlan, |m, c| {
    c.all_within(
        "closest_approach",
        &m.closest_approach[..2],
        envelope::WORLD_POSITION,
    )?;
    c.in_range_at(
        "closest_approach",
        Some(2),
        m.closest_approach[2],
        -core::f64::consts::PI,
        core::f64::consts::PI,
    )?;
    c.in_range(
        "time_to_range",
        m.time_to_range,
        0.0,
        envelope::TIME_TO_RANGE,
    )?;
    c.all_within(
        "range_entry_pose",
        &m.range_entry_pose[..2],
        envelope::WORLD_POSITION,
    )?;
    c.in_range_at(
        "range_entry_pose",
        Some(2),
        m.range_entry_pose[2],
        -core::f64::consts::PI,
        core::f64::consts::PI,
    )?;
    flag(c, "passed", m.passed)?;
    flag(c, "gave_up", m.gave_up).map(|_| ())
});

/// One palm-camera frame, RGB8, row-major, written in place in shared memory.
#[derive(Clone, Copy, ZeroCopySend)]
#[type_name("motm.v1.CameraImage")]
#[repr(C)]
pub struct CameraImage {
    /// Common header; the stamp is the exposure time.
    pub header: Header,
    /// Image width, pixels; must equal [`CAMERA_WIDTH`].
    pub width: u32,
    /// Image height, pixels; must equal [`CAMERA_HEIGHT`].
    pub height: u32,
    /// When the frame was sent, ns (monotonic, at or after the exposure `header.stamp_ns`;
    /// filled in by the publisher): the start of the frame-to-command latency.
    pub image_published_ns: u64,
    /// Pixels, `(row * width + column) * 3 + channel`.
    pub pixels: [u8; CAMERA_IMAGE_BYTES],
}

impl core::fmt::Debug for CameraImage {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CameraImage")
            .field("header", &self.header)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

message!(
    CameraImage,
    instants = [image_published_ns],
    published = image_published_ns,
    |m, c| {
        c.in_range(
            "width",
            f64::from(m.width),
            CAMERA_WIDTH as f64,
            CAMERA_WIDTH as f64,
        )?;
        c.in_range(
            "height",
            f64::from(m.height),
            CAMERA_HEIGHT as f64,
            CAMERA_HEIGHT as f64,
        )?;
        if m.image_published_ns < m.header.stamp_ns {
            return Err(c.reject(
                "image_published_ns",
                None,
                RejectReason::Inconsistent("frame published before its exposure"),
            ));
        }
        Ok(())
    }
);

/// Checks an image publication time carried downstream: 0 (unknown), or at or after the
/// image's exposure `image_stamp_ns` and at or before the carrying message's own `stamp_ns`.
fn image_published(
    c: Check,
    image_stamp_ns: u64,
    image_published_ns: u64,
    stamp_ns: u64,
) -> Result<(), Rejection> {
    if image_published_ns == 0 {
        return Ok(());
    }
    let reason = if image_published_ns > stamp_ns {
        "image published after the message's own stamp"
    } else if image_published_ns < image_stamp_ns {
        "image published before its exposure"
    } else {
        return Ok(());
    };
    Err(c.reject(
        "image_published_ns",
        None,
        RejectReason::Inconsistent(reason),
    ))
}

code_enum!(
    /// Lifecycle state of a process, reported in its heartbeat.
    ProcessState {
        /// Initialising: ports being opened, not yet cycling.
        Starting = 0,
        /// Cycling normally.
        Running = 1,
        /// Shutting down.
        Stopping = 2,
    }
);

/// Per-process liveness and loop statistics; a hung process stops sending these.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.Heartbeat")]
#[repr(C)]
pub struct Heartbeat {
    /// Common header.
    pub header: Header,
    /// Operating-system process id.
    pub pid: u32,
    /// [`ProcessState`] code.
    pub state: u32,
    /// Control cycles run since start.
    pub cycles: u64,
    /// Cycles that missed their deadline since start.
    pub deadline_misses: u64,
    /// Received messages dropped by validation since start.
    pub rejected_messages: u64,
    /// 99th percentile of recent cycle times, ns.
    pub p99_cycle_ns: u64,
    /// Longest cycle time since start, ns.
    pub max_cycle_ns: u64,
    /// Configured cycle period, ns (0 for purely event-driven processes).
    pub period_ns: u64,
    /// Monotonic time of the last deadline miss, ns (0 when none).
    pub last_deadline_miss_ns: u64,
    /// Process name, UTF-8, zero padded.
    pub process_name: [u8; PROCESS_NAME_BYTES],
}

impl Heartbeat {
    /// The lifecycle state, if the code is valid.
    pub fn state(&self) -> Option<ProcessState> {
        ProcessState::try_from(self.state).ok()
    }

    /// The process name (empty if it is not valid UTF-8).
    pub fn process_name(&self) -> &str {
        let len = self
            .process_name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(PROCESS_NAME_BYTES);
        core::str::from_utf8(&self.process_name[..len]).unwrap_or("")
    }

    /// Stores `name`, truncated to [`PROCESS_NAME_BYTES`] at a character boundary.
    pub fn set_process_name(&mut self, name: &str) {
        let mut len = name.len().min(PROCESS_NAME_BYTES);
        while !name.is_char_boundary(len) {
            len -= 1;
        }
        self.process_name = [0; PROCESS_NAME_BYTES];
        self.process_name[..len].copy_from_slice(&name.as_bytes()[..len]);
    }
}

message!(Heartbeat, instants = [last_deadline_miss_ns], |m, c| {
    c.code::<ProcessState>("state", m.state)?;
    if m.deadline_misses > m.cycles {
        return Err(c.reject(
            "deadline_misses",
            None,
            RejectReason::Inconsistent("more deadline misses than cycles"),
        ));
    }
    let len = m
        .process_name
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(PROCESS_NAME_BYTES);
    let padded_with_zeros = m.process_name[len..].iter().all(|&b| b == 0);
    if len == 0 || !padded_with_zeros || core::str::from_utf8(&m.process_name[..len]).is_err() {
        return Err(c.reject(
            "process_name",
            None,
            RejectReason::Inconsistent("must be non-empty zero-padded UTF-8"),
        ));
    }
    Ok(())
});

code_enum!(
    /// Kind of mission task (mirrors `motm_core::TaskKind`).
    TaskKindCode {
        /// Pick an object up.
        Pick = 0,
        /// Place the held object.
        Place = 1,
        /// Press a button.
        PressButton = 2,
    }
);

/// Mission progress from the supervisor: the current and next target and the phase.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.MissionState")]
#[repr(C)]
pub struct MissionState {
    /// Common header.
    pub header: Header,
    /// Index of the current task (equals `task_count` when the mission is complete).
    pub task_index: u32,
    /// Number of tasks in the mission.
    pub task_count: u32,
    /// [`TaskKindCode`] of the current task.
    pub task_kind: u32,
    /// [`TaskPhase`] code of the current task.
    pub phase: u32,
    /// Current target position in the world, m.
    pub current_target: [f64; 3],
    /// Next target position in the world, m (zero when there is none).
    pub next_target: [f64; 3],
    /// 1 when `next_target` holds a target, 0 otherwise.
    pub has_next: u32,
    /// Tasks the mission has given up so far (their target could not be reached on any
    /// approach; a pick's place goes with it), at most `task_count`.
    pub failed_tasks: u32,
    /// The odometry frame against the world, as the mission estimates it from landmark fixes:
    /// a world point `p` is at `R(yaw)·p + (x, y)` in odometry, `[x, y, yaw]` (m, rad). The
    /// targets above are already in odometry; this is for the rest of the known layout.
    pub odometry_offset: [f64; 3],
    /// 1 once the mission predicts the odometry drift between landmark fixes (its rate has been
    /// estimated), so that known positions in odometry are good to a few centimetres; 0 before.
    pub odometry_calibrated: u32,
}

message!(MissionState, |m, c| {
    c.in_range(
        "task_index",
        f64::from(m.task_index),
        0.0,
        f64::from(m.task_count),
    )?;
    c.code::<TaskKindCode>("task_kind", m.task_kind)?;
    c.code::<TaskPhase>("phase", m.phase)?;
    c.all_within(
        "current_target",
        &m.current_target,
        envelope::WORLD_POSITION,
    )?;
    c.all_within("next_target", &m.next_target, envelope::WORLD_POSITION)?;
    flag(c, "has_next", m.has_next)?;
    flag(c, "odometry_calibrated", m.odometry_calibrated)?;
    c.in_range(
        "failed_tasks",
        f64::from(m.failed_tasks),
        0.0,
        f64::from(m.task_count),
    )?;
    c.all_within(
        "odometry_offset",
        &m.odometry_offset[..2],
        envelope::WORLD_POSITION,
    )?;
    c.in_range_at(
        "odometry_offset",
        Some(2),
        m.odometry_offset[2],
        -core::f64::consts::PI,
        core::f64::consts::PI,
    )
});

code_enum!(
    /// Why safe-stop was raised.
    SafeStopReason {
        /// Not raised.
        None = 0,
        /// A control-path process missed its deadline.
        DeadlineMiss = 1,
        /// A process stopped sending heartbeats.
        HeartbeatLost = 2,
        /// A command stream went stale.
        StaleCommand = 3,
        /// An operator asked for it.
        Operator = 4,
        /// The stack is starting: a watched process or command stream has not been heard from
        /// yet. A hold, not a fault.
        Starting = 5,
    }
);

/// Safe-stop from the watchdog: when active, the drivers ramp to zero within their limits.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SafeStop")]
#[repr(C)]
pub struct SafeStop {
    /// Common header.
    pub header: Header,
    /// 1 when safe-stop is raised, 0 when cleared.
    pub active: u32,
    /// [`SafeStopReason`] code; `None` exactly when not active.
    pub reason: u32,
    /// Raises for a fault since the watchdog started (the start-up hold, `Starting`, is not
    /// one): a reader that samples the stream now and then still counts the short raises it
    /// did not see.
    pub fault_raises: u64,
}

message!(SafeStop, |m, c| {
    let active = flag(c, "active", m.active)?;
    let reason = c.code::<SafeStopReason>("reason", m.reason)?;
    if active == (reason == SafeStopReason::None) {
        return Err(c.reject(
            "reason",
            None,
            RejectReason::Inconsistent("reason must be None exactly when not active"),
        ));
    }
    Ok(())
});

code_enum!(
    /// Outcome of one redundancy-resolution QP solve.
    QpOutcome {
        /// Solved to tolerance.
        Solved = 0,
        /// Solved to reduced accuracy.
        AlmostSolved = 1,
        /// No solution; the resolver sent its fallback command.
        Failed = 2,
    }
);

/// Status of the last QP solve, from the QP resolver.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.QpStatus")]
#[repr(C)]
pub struct QpStatus {
    /// Common header.
    pub header: Header,
    /// [`QpOutcome`] code.
    pub outcome: u32,
    /// Solver iterations.
    pub iterations: u32,
    /// Solve time, ns.
    pub solve_time_ns: u64,
    /// Objective value at the solution.
    pub objective: f64,
    /// Norm of the task slack at the solution.
    pub slack_norm: f64,
    /// Capture stamp of the camera image behind the target estimate this command used, ns (0
    /// when the target was not a perception estimate): the end-to-end latency of the command
    /// is `header.stamp_ns - image_stamp_ns`.
    pub image_stamp_ns: u64,
    /// Publication time of that image, ns (0 when the target was not a perception estimate):
    /// the frame-to-command latency is `published_ns - image_published_ns`.
    pub image_published_ns: u64,
    /// The world twist that was resolved, after the twist rate limit
    /// `[vx, vy, vz, wx, wy, wz]`, m/s and rad/s: the tool's commanded motion, which the reacher
    /// feeds back as its tool state (all zero when the command was a stop).
    pub twist: [f64; 6],
    /// When this status was sent, ns (filled in by the publisher): the resolver sends it after
    /// the joint command of the same cycle, so it bounds that command's send time from above.
    pub published_ns: u64,
}

message!(
    QpStatus,
    instants = [image_stamp_ns, image_published_ns, published_ns],
    published = published_ns,
    |m, c| {
        c.code::<QpOutcome>("outcome", m.outcome)?;
        c.in_range("objective", m.objective, f64::MIN, f64::MAX)?;
        c.in_range("slack_norm", m.slack_norm, 0.0, f64::MAX)?;
        if m.image_stamp_ns > m.header.stamp_ns {
            return Err(c.reject(
                "image_stamp_ns",
                None,
                RejectReason::Inconsistent("image stamp after the status's own stamp"),
            ));
        }
        image_published(c, m.image_stamp_ns, m.image_published_ns, m.header.stamp_ns)?;
        if m.published_ns != 0 && m.published_ns < m.header.stamp_ns {
            return Err(c.reject(
                "published_ns",
                None,
                RejectReason::Inconsistent("sent before its own stamp"),
            ));
        }
        for i in 0..6 {
            let max = if i < 3 {
                envelope::EE_SPEED
            } else {
                envelope::ANGULAR_SPEED
            };
            c.in_range_at("twist", Some(i), m.twist[i], -max, max)?;
        }
        Ok(())
    }
);

code_enum!(
    /// Which controller variant is active.
    ControllerVariant {
        /// The reach-phase controller.
        Reacher = 0,
        /// Final phase: grasp.
        Grasp = 1,
        /// Final phase: place.
        Place = 2,
        /// Final phase: press a button.
        PressButton = 3,
    }
);

/// The active controller: consumers accept twist and gripper commands only from this id.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.ActiveController")]
#[repr(C)]
pub struct ActiveController {
    /// Common header.
    pub header: Header,
    /// Id that the active controller puts in its commands.
    pub controller_id: u32,
    /// [`ControllerVariant`] code.
    pub variant: u32,
}

message!(ActiveController, |m, c| {
    c.code::<ControllerVariant>("variant", m.variant)
        .map(|_| ())
});

code_enum!(
    /// Progress of a task's motion as its controller reports it (mirrors
    /// `motm_core::TaskProgress`).
    TaskProgressCode {
        /// Still working on the task.
        Active = 0,
        /// The task's motion is complete.
        Done = 1,
    }
);

/// Largest number of objects a [`SimTruth`] reports.
pub const MAX_SIM_OBJECTS: usize = 16;

code_enum!(
    /// How a simulated trial stands (mirrors `motm_sim::Outcome` plus running and timeout).
    SimOutcome {
        /// The trial is still running.
        Running = 0,
        /// Every cube landed in its container and every button was pressed.
        Success = 1,
        /// Failure: the gripper knocked a cube off its platform.
        KnockedOff = 2,
        /// Failure: a grasp closed on nothing.
        MissedGrasp = 3,
        /// Failure: a released cube landed outside its container.
        DroppedOutside = 4,
        /// Failure: the base drove into a platform or a container.
        BaseCollision = 5,
        /// Failure: the trial ran past its time limit.
        Timeout = 6,
        /// Failure: the mission gave a task up and ended with the job not done.
        TaskFailed = 7,
    }
);

/// Ground truth of the simulated world, from sim-world: for metrics and tests, never for the
/// controllers.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SimTruth")]
#[repr(C)]
pub struct SimTruth {
    /// Common header.
    pub header: Header,
    /// Simulation time, s.
    pub sim_time: f64,
    /// Simulation time when the outcome was decided, s (equals `sim_time` while running).
    pub task_time: f64,
    /// [`SimOutcome`] code.
    pub outcome: u32,
    /// Number of objects in use (0..=[`MAX_SIM_OBJECTS`]); entries past it are zero.
    pub object_count: u32,
    /// True tool (grasp point) position in the world, m.
    pub tool_position: [f64; 3],
    /// True base pose `[x, y, yaw]`, m and rad.
    pub base_pose: [f64; 3],
    /// Object centres `[x0, y0, z0, x1, ...]`, m.
    pub object_positions: [f64; 3 * MAX_SIM_OBJECTS],
    /// Simulation time each object was placed in its container, s; −1 when not (yet) placed.
    pub object_placed_time: [f64; MAX_SIM_OBJECTS],
    /// Index of the held object, or −1 when none is held.
    pub held_object: i32,
    /// Buttons that have registered their press so far.
    pub buttons_pressed: u32,
    /// Opening between the gripper fingers, m.
    pub gripper_opening: f64,
    /// Mean |EE acceleration| so far (low-pass filtered), m/s².
    pub ee_acc_mean: f64,
    /// Largest |EE acceleration| so far (low-pass filtered), m/s².
    pub ee_acc_max: f64,
    /// Hardware commands the world dropped (wrong length or non-finite) so far.
    pub rejected_commands: u64,
    /// Physics cycles that had to catch up on lost timer ticks so far.
    pub catch_up_cycles: u64,
}

impl SimTruth {
    /// The outcome, if the code is valid.
    pub fn outcome(&self) -> Option<SimOutcome> {
        SimOutcome::try_from(self.outcome).ok()
    }
}

message!(SimTruth, |m, c| {
    c.in_range("sim_time", m.sim_time, 0.0, f64::MAX)?;
    c.in_range("task_time", m.task_time, 0.0, m.sim_time)?;
    c.code::<SimOutcome>("outcome", m.outcome)?;
    let count = m.object_count as usize;
    if count > MAX_SIM_OBJECTS {
        return Err(c.reject(
            "object_count",
            None,
            RejectReason::OutOfRange {
                value: f64::from(m.object_count),
                min: 0.0,
                max: MAX_SIM_OBJECTS as f64,
            },
        ));
    }
    c.all_within("tool_position", &m.tool_position, envelope::WORLD_POSITION)?;
    c.all_within("base_pose", &m.base_pose, envelope::WORLD_POSITION)?;
    c.joint_array(
        "object_positions",
        &m.object_positions,
        3 * count,
        envelope::WORLD_POSITION,
    )?;
    for (i, &t) in m.object_placed_time.iter().enumerate() {
        let max = if i < count { m.sim_time } else { 0.0 };
        c.in_range_at("object_placed_time", Some(i), t, -1.0, max)?;
        if t < 0.0 && t != -1.0 {
            return Err(c.reject(
                "object_placed_time",
                Some(i),
                RejectReason::Inconsistent("must be -1 or a time"),
            ));
        }
    }
    if m.held_object < -1 || m.held_object >= count as i32 {
        return Err(c.reject(
            "held_object",
            None,
            RejectReason::OutOfRange {
                value: f64::from(m.held_object),
                min: -1.0,
                max: count as f64 - 1.0,
            },
        ));
    }
    c.in_range(
        "buttons_pressed",
        f64::from(m.buttons_pressed),
        0.0,
        f64::from(u16::MAX),
    )?;
    c.in_range(
        "gripper_opening",
        m.gripper_opening,
        0.0,
        envelope::GRIPPER_WIDTH,
    )?;
    c.in_range("ee_acc_mean", m.ee_acc_mean, 0.0, f64::MAX)?;
    c.in_range("ee_acc_max", m.ee_acc_max, 0.0, f64::MAX)
});

code_enum!(
    /// What a driver's command limiter is doing (mirrors `motm_core::command_limiter::LimiterMode`).
    DriverMode {
        /// Following a fresh command.
        Tracking = 0,
        /// No fresh command: ramping to (or holding) zero.
        Stale = 1,
        /// Safe-stop raised: ramping to (or holding) zero.
        SafeStop = 2,
    }
);

/// Status of a driver (panda-driver or ld60-driver): its mode and counters since start.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.DriverStatus")]
#[repr(C)]
pub struct DriverStatus {
    /// Common header.
    pub header: Header,
    /// [`DriverMode`] code.
    pub mode: u32,
    /// 1 when the hardware boundary (sim-world or the robot) reports state, 0 while waiting.
    pub hardware_ready: u32,
    /// Valid commands received.
    pub commands_received: u64,
    /// Commands that arrived beyond a limit (clamped or ignored, and counted).
    pub limit_violations: u64,
    /// Commands clamped to the velocity limit.
    pub clamped_commands: u64,
    /// Commands ignored (non-finite or wrong length).
    pub ignored_commands: u64,
    /// Driver cycles with a stale command (ramping to or holding zero).
    pub stale_cycles: u64,
    /// Driver cycles under safe-stop.
    pub safe_stop_cycles: u64,
    /// Driver outputs that broke a velocity, acceleration or jerk limit (must stay 0).
    pub output_violations: u64,
    /// Longest gap between consecutive received commands (header stamps), ns.
    pub max_command_gap_ns: u64,
    /// Id of the resolver instance whose commands the driver takes (0 before the first).
    pub resolver_id: u32,
    /// Times the driver turned to another resolver instance because the one it followed
    /// stopped commanding (a hot-standby takeover).
    pub resolver_takeovers: u32,
    /// Longest interval a takeover made between the commands the driver took, ns.
    pub max_takeover_interval_ns: u64,
}

impl DriverStatus {
    /// The mode, if the code is valid.
    pub fn mode(&self) -> Option<DriverMode> {
        DriverMode::try_from(self.mode).ok()
    }
}

message!(DriverStatus, |m, c| {
    c.code::<DriverMode>("mode", m.mode)?;
    flag(c, "hardware_ready", m.hardware_ready)?;
    if m.clamped_commands + m.ignored_commands != m.limit_violations {
        return Err(c.reject(
            "limit_violations",
            None,
            RejectReason::Inconsistent("must equal clamped_commands + ignored_commands"),
        ));
    }
    Ok(())
});

mod supervision;
pub use supervision::*;

mod swap;
pub use swap::*;

mod replay;
pub use replay::*;
