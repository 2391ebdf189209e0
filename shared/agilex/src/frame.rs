//! CAN frames of AgileX protocol v2 (CAN 2.0B at 500 kbit/s, 11-bit IDs, DLC 8, fields
//! big-endian and signed unless noted, no checksum), and their conversion to `socketcan`'s
//! frames and `candump -L` text.

use socketcan::{CanAnyFrame, CanDataFrame, CanFrame, EmbeddedFrame, Id, StandardId};
use thiserror::Error;

/// Host → base: motion command (every 20 ms; the base stops 500 ms after the last one).
pub const MOTION_COMMAND: u16 = 0x111;
/// Host → base: control mode (`[0] = 0x01`: CAN command mode).
pub const CONTROL_MODE: u16 = 0x421;
/// Host → base: clear faults (`[0]` 0 all, 1–4 motor n).
pub const CLEAR_FAULTS: u16 = 0x441;
/// Base → host: system state (100 ms).
pub const SYSTEM_STATE: u16 = 0x211;
/// Base → host: motion state, laid out as the motion command (20 ms).
pub const MOTION_STATE: u16 = 0x221;
/// Base → host: wheel odometry, left and right i32 mm (20 ms).
pub const ODOMETRY: u16 = 0x311;
/// Base → host: first actuator state (0x251–0x258).
pub const ACTUATOR_FIRST: u16 = 0x251;
/// Base → host: last actuator state.
pub const ACTUATOR_LAST: u16 = 0x258;

/// A classic data frame with an 11-bit ID.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Frame {
    /// 11-bit identifier.
    pub id: u16,
    /// Data length, 0..=8.
    pub len: u8,
    /// Data (bytes past `len` are zero).
    pub data: [u8; 8],
}

/// A frame that is not an AgileX frame (or not a valid one).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    /// An identifier beyond 11 bits.
    #[error("CAN id {0:#x} is not an 11-bit id")]
    BadId(u32),
    /// More than 8 data bytes.
    #[error("{0} data bytes (classic CAN carries at most 8)")]
    TooLong(usize),
    /// An extended, remote, error or FD frame.
    #[error("not a classic data frame with an 11-bit id: {0}")]
    NotStandardData(String),
    /// A protocol frame with fewer bytes than its layout needs.
    #[error("frame {id:#05x} has {len} bytes, needs {need}")]
    Short {
        /// Identifier.
        id: u16,
        /// Bytes present.
        len: u8,
        /// Bytes needed.
        need: u8,
    },
}

impl Frame {
    /// A frame with `id` and up to 8 bytes of `data`.
    pub fn new(id: u16, data: &[u8]) -> Result<Self, FrameError> {
        if id > 0x7FF {
            return Err(FrameError::BadId(u32::from(id)));
        }
        if data.len() > 8 {
            return Err(FrameError::TooLong(data.len()));
        }
        let mut d = [0; 8];
        d[..data.len()].copy_from_slice(data);
        Ok(Self {
            id,
            len: data.len() as u8,
            data: d,
        })
    }

    /// The data bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// As a `socketcan` frame.
    pub fn to_socketcan(&self) -> CanFrame {
        let id = StandardId::new(self.id).expect("checked at construction");
        CanFrame::Data(CanDataFrame::new(id, self.bytes()).expect("at most 8 bytes"))
    }

    /// From a `socketcan` frame (only standard data frames are AgileX frames).
    pub fn from_socketcan(frame: &CanFrame) -> Result<Self, FrameError> {
        match frame {
            CanFrame::Data(d) => match d.id() {
                Id::Standard(id) => Self::new(id.as_raw(), d.data()),
                Id::Extended(id) => Err(FrameError::NotStandardData(format!(
                    "extended id {:#x}",
                    id.as_raw()
                ))),
            },
            CanFrame::Remote(_) => Err(FrameError::NotStandardData("remote frame".into())),
            CanFrame::Error(_) => Err(FrameError::NotStandardData("error frame".into())),
        }
    }

    /// From any frame of a `candump` record.
    pub fn from_any(frame: &CanAnyFrame) -> Result<Self, FrameError> {
        match frame {
            CanAnyFrame::Normal(d) => Self::from_socketcan(&CanFrame::Data(*d)),
            CanAnyFrame::Remote(_) => Err(FrameError::NotStandardData("remote frame".into())),
            CanAnyFrame::Error(_) => Err(FrameError::NotStandardData("error frame".into())),
            CanAnyFrame::Fd(_) => Err(FrameError::NotStandardData("CAN FD frame".into())),
        }
    }

    /// candump notation, `111#0096000000000000`.
    pub fn candump(&self) -> String {
        let mut s = format!("{:03X}#", self.id);
        for b in self.bytes() {
            s += &format!("{b:02X}");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_convert_to_socketcan_and_back() {
        let f = Frame::new(0x311, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        assert_eq!(Frame::from_socketcan(&f.to_socketcan()).unwrap(), f);
        assert_eq!(f.candump(), "311#0102030405060708");
        assert_eq!(Frame::new(0x800, &[]), Err(FrameError::BadId(0x800)));
        assert_eq!(Frame::new(0x111, &[0; 9]), Err(FrameError::TooLong(9)));
        let ext = CanFrame::Data(
            CanDataFrame::new(socketcan::ExtendedId::new(0x111).unwrap(), &[0]).unwrap(),
        );
        assert!(Frame::from_socketcan(&ext).is_err());
    }
}
