//! The host side of an AgileX base: enable CAN mode, send motion commands, decode feedback
//! into odometry, and tell when the base is not fit to drive (no feedback, e-stop, exception,
//! another control mode).
//!
//! Odometry: the pose is integrated from the 0x311 wheel distances (differential drive with
//! the configured track width, a config value: skid-steer bases slip, so it is an effective
//! width), the velocity is the 0x221 motion state. Time is passed in (ns, any monotonic
//! origin), so the logic is the same on a real bus, an in-memory bus or a replayed log.

use std::time::Duration;

use crate::bus::{CanBus, CanBusError};
use crate::frame::FrameError;
use crate::protocol::{
    ControlMode, Feedback, Motion, SystemState, VehicleState, WheelOdometry, clear_faults,
    enable_can_mode, motion_command,
};

/// Settings of an [`AgilexHost`] (config values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HostConfig {
    /// Effective track width for the odometry, m.
    pub track_width: f64,
    /// Feedback (0x221) older than this is stale, s.
    pub feedback_timeout: f64,
}

impl Default for HostConfig {
    fn default() -> Self {
        Self {
            // Scout 2.0: 0.58 m between the wheel centres (*uncertain*, config).
            track_width: 0.58,
            feedback_timeout: 0.2,
        }
    }
}

/// The base's odometry.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BaseOdometry {
    /// x from the first wheel reading, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Heading, rad in [−π, π].
    pub yaw: f64,
    /// Forward speed, m/s (0x221).
    pub v: f64,
    /// Yaw rate, rad/s (0x221).
    pub omega: f64,
}

/// Why the base may not be driven now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HostFault {
    /// No motion state yet, or none within the feedback timeout.
    NoFeedback,
    /// The base reports an e-stop.
    EStop,
    /// The base reports an exception (with its raw error code).
    Exception(u16),
    /// The base is not in CAN command mode (standby, or the RC transmitter took over).
    NotCanMode(ControlMode),
}

/// Counts of an [`AgilexHost`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HostCounters {
    /// Feedback frames decoded.
    pub feedback_frames: u64,
    /// Frames that failed to decode (short).
    pub bad_frames: u64,
    /// Frames with an ID not decoded here (actuators, host frames).
    pub ignored_frames: u64,
    /// Motion commands sent.
    pub commands_sent: u64,
    /// Commands saturated at the i16 range.
    pub saturated_commands: u64,
}

/// The host side of a base on bus `B`.
#[derive(Debug)]
pub struct AgilexHost<B> {
    bus: B,
    config: HostConfig,
    odometry: BaseOdometry,
    last_wheels: Option<WheelOdometry>,
    motion_at_ns: Option<u64>,
    system: Option<SystemState>,
    counters: HostCounters,
}

impl<B: CanBus> AgilexHost<B> {
    /// A host on `bus`.
    pub fn new(bus: B, config: HostConfig) -> Self {
        Self {
            bus,
            config,
            odometry: BaseOdometry::default(),
            last_wheels: None,
            motion_at_ns: None,
            system: None,
            counters: HostCounters::default(),
        }
    }

    /// The bus.
    pub fn bus(&self) -> &B {
        &self.bus
    }

    /// The bus, mutably.
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// Sends 0x421: CAN command mode.
    pub fn enable(&mut self) -> Result<(), CanBusError> {
        self.bus.send(&enable_can_mode())
    }

    /// Sends 0x441: clear the faults of every motor.
    pub fn clear_faults(&mut self) -> Result<(), CanBusError> {
        self.bus.send(&clear_faults(0))
    }

    /// Sends a 0x111 motion command.
    pub fn command(&mut self, v: f64, omega: f64) -> Result<(), CanBusError> {
        let (frame, saturated) = motion_command(v, omega);
        self.bus.send(&frame)?;
        self.counters.commands_sent += 1;
        self.counters.saturated_commands += u64::from(saturated);
        Ok(())
    }

    /// Reads every frame already received (feedback stamped `now_ns`); returns how many
    /// motion states arrived. A frame that does not decode is counted and returned as an
    /// error after the others are read.
    pub fn poll(&mut self, now_ns: u64) -> Result<usize, CanBusError> {
        let mut motions = 0;
        let mut bad = None;
        while let Some(frame) = self.bus.receive(Duration::ZERO)? {
            match Feedback::decode(&frame) {
                Ok(Some(fb)) => {
                    self.counters.feedback_frames += 1;
                    motions += usize::from(self.take(fb, now_ns));
                }
                Ok(None) => self.counters.ignored_frames += 1,
                Err(e) => {
                    self.counters.bad_frames += 1;
                    bad = Some(e);
                }
            }
        }
        match bad {
            Some(e) => Err(CanBusError::Frame(e)),
            None => Ok(motions),
        }
    }

    /// Takes in one feedback message; `true` for a motion state.
    fn take(&mut self, fb: Feedback, now_ns: u64) -> bool {
        match fb {
            Feedback::Motion(Motion {
                linear, angular, ..
            }) => {
                self.odometry.v = linear;
                self.odometry.omega = angular;
                self.motion_at_ns = Some(now_ns);
                return true;
            }
            Feedback::System(s) => self.system = Some(s),
            Feedback::Odometry(w) => {
                if let Some(last) = self.last_wheels {
                    let dl = f64::from(w.left_mm.wrapping_sub(last.left_mm)) * 1e-3;
                    let dr = f64::from(w.right_mm.wrapping_sub(last.right_mm)) * 1e-3;
                    let ds = 0.5 * (dl + dr);
                    let dth = (dr - dl) / self.config.track_width;
                    let mid = self.odometry.yaw + 0.5 * dth;
                    self.odometry.x += ds * mid.cos();
                    self.odometry.y += ds * mid.sin();
                    let yaw = self.odometry.yaw + dth;
                    self.odometry.yaw = yaw.sin().atan2(yaw.cos());
                }
                self.last_wheels = Some(w);
            }
        }
        false
    }

    /// The odometry so far.
    pub fn odometry(&self) -> BaseOdometry {
        self.odometry
    }

    /// The last system state.
    pub fn system(&self) -> Option<SystemState> {
        self.system
    }

    /// Age of the newest motion state at `now_ns`, s.
    pub fn feedback_age(&self, now_ns: u64) -> Option<f64> {
        self.motion_at_ns
            .map(|t| now_ns.saturating_sub(t) as f64 * 1e-9)
    }

    /// Why the base may not be driven at `now_ns`, if it may not. The control mode is only
    /// checked once a system state arrived (the host enables CAN mode itself).
    pub fn fault(&self, now_ns: u64) -> Option<HostFault> {
        match self.feedback_age(now_ns) {
            None => return Some(HostFault::NoFeedback),
            Some(age) if age > self.config.feedback_timeout => return Some(HostFault::NoFeedback),
            _ => {}
        }
        let s = self.system?;
        match s.vehicle {
            VehicleState::EStop => Some(HostFault::EStop),
            VehicleState::Exception | VehicleState::Other(_) => {
                Some(HostFault::Exception(s.error_code))
            }
            VehicleState::Normal if s.mode != ControlMode::Can => {
                Some(HostFault::NotCanMode(s.mode))
            }
            VehicleState::Normal => None,
        }
    }

    /// Counters.
    pub fn counters(&self) -> HostCounters {
        self.counters
    }
}

/// Keeps [`FrameError`] reachable from the host module (it is what `poll` reports).
pub type HostFrameError = FrameError;
