//! The AgileX protocol-v2 messages this project uses, in SI units, and their frames.
//!
//! | ID | layout |
//! | --- | --- |
//! | 0x111 / 0x221 | linear i16 ×0.001 m/s, angular i16 ×0.001 rad/s, lateral i16 ×0.001 m/s, steering i16 ×0.001 rad |
//! | 0x421 | `[0]` 0x01 = CAN command mode |
//! | 0x441 | `[0]` 0 all, 1–4 motor n |
//! | 0x211 | `[0]` 0 normal, 1 e-stop, 2 exception; `[1]` mode; `[2..3]` battery u16 ×0.1 V; `[4..5]` error code u16; `[7]` count |
//! | 0x311 | left i32 mm, right i32 mm |
//!
//! The error-code bit positions are *uncertain* (the vendor manuals and SDK disagree): the
//! code is carried as a raw u16 and any non-zero value counts as a fault.

use crate::frame::{
    CLEAR_FAULTS, CONTROL_MODE, Frame, FrameError, MOTION_COMMAND, MOTION_STATE, ODOMETRY,
    SYSTEM_STATE,
};

/// Linear, angular, lateral and steering: the 0x111 command and the 0x221 state.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Motion {
    /// Forward speed, m/s.
    pub linear: f64,
    /// Yaw rate, rad/s.
    pub angular: f64,
    /// Lateral speed, m/s (Ranger only).
    pub lateral: f64,
    /// Steering angle, rad (Ranger only).
    pub steering: f64,
}

/// Scales `x` by 1000 into an i16, saturating; `true` if it saturated (or was not finite).
fn milli(x: f64) -> (i16, bool) {
    if !x.is_finite() {
        return (0, true);
    }
    let m = (x * 1000.0).round();
    let c = m.clamp(f64::from(i16::MIN), f64::from(i16::MAX));
    (c as i16, c != m)
}

impl Motion {
    /// The frame with `id` (0x111 or 0x221) and whether a field saturated.
    pub fn to_frame(&self, id: u16) -> (Frame, bool) {
        let mut data = [0u8; 8];
        let mut saturated = false;
        for (i, x) in [self.linear, self.angular, self.lateral, self.steering]
            .into_iter()
            .enumerate()
        {
            let (v, s) = milli(x);
            saturated |= s;
            data[2 * i..2 * i + 2].copy_from_slice(&v.to_be_bytes());
        }
        (Frame::new(id, &data).expect("8 bytes"), saturated)
    }

    /// Decodes a 0x111 or 0x221 frame.
    pub fn from_frame(frame: &Frame) -> Result<Self, FrameError> {
        need(frame, 8)?;
        let f = |i: usize| f64::from(i16::from_be_bytes([frame.data[i], frame.data[i + 1]])) * 1e-3;
        Ok(Self {
            linear: f(0),
            angular: f(2),
            lateral: f(4),
            steering: f(6),
        })
    }
}

/// Checks that `frame` has at least `len` bytes.
fn need(frame: &Frame, len: u8) -> Result<(), FrameError> {
    if frame.len < len {
        Err(FrameError::Short {
            id: frame.id,
            len: frame.len,
            need: len,
        })
    } else {
        Ok(())
    }
}

/// The base's state (0x211 `[0]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VehicleState {
    /// 0: normal.
    Normal,
    /// 1: e-stop.
    EStop,
    /// 2: exception.
    Exception,
    /// Any other code.
    Other(u8),
}

/// Who controls the base (0x211 `[1]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlMode {
    /// 0: standby (0x111 is ignored).
    Standby,
    /// 1: CAN command mode.
    Can,
    /// 2: UART.
    Uart,
    /// 3: the RC transmitter (it overrides CAN).
    Rc,
    /// Any other code.
    Other(u8),
}

impl ControlMode {
    /// From the wire code.
    pub fn from_code(c: u8) -> Self {
        match c {
            0 => Self::Standby,
            1 => Self::Can,
            2 => Self::Uart,
            3 => Self::Rc,
            o => Self::Other(o),
        }
    }

    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Self::Standby => 0,
            Self::Can => 1,
            Self::Uart => 2,
            Self::Rc => 3,
            Self::Other(o) => o,
        }
    }
}

impl VehicleState {
    /// From the wire code.
    pub fn from_code(c: u8) -> Self {
        match c {
            0 => Self::Normal,
            1 => Self::EStop,
            2 => Self::Exception,
            o => Self::Other(o),
        }
    }

    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Self::Normal => 0,
            Self::EStop => 1,
            Self::Exception => 2,
            Self::Other(o) => o,
        }
    }
}

/// 0x211 system state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SystemState {
    /// Vehicle state.
    pub vehicle: VehicleState,
    /// Control mode.
    pub mode: ControlMode,
    /// Battery voltage, V (0.1 V resolution).
    pub battery_v: f64,
    /// Raw error code (bit positions *uncertain*).
    pub error_code: u16,
    /// Rolling count.
    pub count: u8,
}

impl SystemState {
    /// The frame.
    pub fn to_frame(&self) -> Frame {
        let b = ((self.battery_v * 10.0).round().clamp(0.0, 65535.0) as u16).to_be_bytes();
        let e = self.error_code.to_be_bytes();
        let data = [
            self.vehicle.code(),
            self.mode.code(),
            b[0],
            b[1],
            e[0],
            e[1],
            0,
            self.count,
        ];
        Frame::new(SYSTEM_STATE, &data).expect("8 bytes")
    }

    /// Decodes a 0x211 frame.
    pub fn from_frame(frame: &Frame) -> Result<Self, FrameError> {
        need(frame, 8)?;
        let d = &frame.data;
        Ok(Self {
            vehicle: VehicleState::from_code(d[0]),
            mode: ControlMode::from_code(d[1]),
            battery_v: f64::from(u16::from_be_bytes([d[2], d[3]])) / 10.0,
            error_code: u16::from_be_bytes([d[4], d[5]]),
            count: d[7],
        })
    }
}

/// 0x311 wheel odometry: distance travelled by each side since power-up, mm.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WheelOdometry {
    /// Left side, mm.
    pub left_mm: i32,
    /// Right side, mm.
    pub right_mm: i32,
}

impl WheelOdometry {
    /// The frame.
    pub fn to_frame(&self) -> Frame {
        let mut data = [0u8; 8];
        data[..4].copy_from_slice(&self.left_mm.to_be_bytes());
        data[4..].copy_from_slice(&self.right_mm.to_be_bytes());
        Frame::new(ODOMETRY, &data).expect("8 bytes")
    }

    /// Decodes a 0x311 frame.
    pub fn from_frame(frame: &Frame) -> Result<Self, FrameError> {
        need(frame, 8)?;
        let d = &frame.data;
        Ok(Self {
            left_mm: i32::from_be_bytes([d[0], d[1], d[2], d[3]]),
            right_mm: i32::from_be_bytes([d[4], d[5], d[6], d[7]]),
        })
    }
}

/// The 0x421 frame that puts the base in CAN command mode.
pub fn enable_can_mode() -> Frame {
    Frame::new(CONTROL_MODE, &[0x01, 0, 0, 0, 0, 0, 0, 0]).expect("8 bytes")
}

/// The 0x441 frame that clears the faults of `motor` (0: all).
pub fn clear_faults(motor: u8) -> Frame {
    Frame::new(CLEAR_FAULTS, &[motor, 0, 0, 0, 0, 0, 0, 0]).expect("8 bytes")
}

/// A 0x111 motion command for forward speed `v` and yaw rate `omega`, and whether it saturated.
pub fn motion_command(v: f64, omega: f64) -> (Frame, bool) {
    Motion {
        linear: v,
        angular: omega,
        ..Motion::default()
    }
    .to_frame(MOTION_COMMAND)
}

/// A base-to-host frame, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Feedback {
    /// 0x211.
    System(SystemState),
    /// 0x221.
    Motion(Motion),
    /// 0x311.
    Odometry(WheelOdometry),
}

impl Feedback {
    /// Decodes a feedback frame; `Ok(None)` for an ID that is not decoded here (actuator
    /// states, or host-to-base frames seen on a shared bus or in a log).
    pub fn decode(frame: &Frame) -> Result<Option<Self>, FrameError> {
        Ok(Some(match frame.id {
            SYSTEM_STATE => Self::System(SystemState::from_frame(frame)?),
            MOTION_STATE => Self::Motion(Motion::from_frame(frame)?),
            ODOMETRY => Self::Odometry(WheelOdometry::from_frame(frame)?),
            _ => return Ok(None),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_0_15_is_the_worked_example() {
        let (f, saturated) = motion_command(0.15, 0.0);
        assert!(!saturated);
        assert_eq!(f.candump(), "111#0096000000000000");
        let m = Motion::from_frame(&f).unwrap();
        assert!((m.linear - 0.15).abs() < 1e-12 && m.angular == 0.0);
        // Negative values are two's complement, big-endian.
        let (f, _) = motion_command(-0.15, 0.5);
        assert_eq!(f.candump(), "111#FF6A01F400000000");
        assert!(motion_command(40.0, 0.0).1, "beyond i16 ×0.001 saturates");
        assert!(motion_command(f64::NAN, 0.0).1);
    }

    #[test]
    fn feedback_frames_round_trip() {
        let s = SystemState {
            vehicle: VehicleState::EStop,
            mode: ControlMode::Can,
            battery_v: 26.4,
            error_code: 0x0102,
            count: 7,
        };
        let f = s.to_frame();
        assert_eq!(f.candump(), "211#0101010801020007");
        assert_eq!(Feedback::decode(&f).unwrap(), Some(Feedback::System(s)));
        let o = WheelOdometry {
            left_mm: -1000,
            right_mm: 70000,
        };
        assert_eq!(o.to_frame().candump(), "311#FFFFFC1800011170");
        assert_eq!(
            Feedback::decode(&o.to_frame()).unwrap(),
            Some(Feedback::Odometry(o))
        );
        assert_eq!(Feedback::decode(&enable_can_mode()).unwrap(), None);
        let short = Frame::new(0x221, &[0, 1]).unwrap();
        assert!(matches!(
            Feedback::decode(&short),
            Err(FrameError::Short { need: 8, .. })
        ));
        assert_eq!(clear_faults(0).candump(), "441#0000000000000000");
    }
}
