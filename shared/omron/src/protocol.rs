//! ArNetworking messages: fixed command numbers, the handshake packets, the data lists and the
//! named data this project uses (`ratioDrive`, `stop`, `updateNumbers`).

use std::collections::BTreeMap;

use md5::{Digest, Md5};

use crate::packet::{Packet, PacketError, PayloadReader, PayloadWriter};

/// Fixed commands sent by the server.
pub mod server {
    /// The server is shutting down.
    pub const SHUTDOWN: u16 = 1;
    /// The server's introduction (opens the handshake).
    pub const INTRODUCTION: u16 = 2;
    /// UDP introduction.
    pub const UDP_INTRO: u16 = 3;
    /// UDP confirmation.
    pub const UDP_CONFIRM: u16 = 4;
    /// The client is connected.
    pub const CONNECTED: u16 = 5;
    /// The client is rejected: `byte2 reason`, `str`.
    pub const REJECTED: u16 = 6;
    /// TCP only.
    pub const TCP_ONLY: u16 = 7;
    /// The named data: `u16 count`, `{u16 cmd, str name, str description}`.
    pub const LIST: u16 = 129;
    /// One named data entry.
    pub const LISTSINGLE: u16 = 130;
    /// Argument and return descriptions: `u16 count`, `{u16 cmd, str args, str ret}`.
    pub const LISTARGRET: u16 = 131;
    /// One argument/return entry.
    pub const LISTARGRETSINGLE: u16 = 132;
    /// Groups and flags: `u16 count`, `{u16 cmd, str group, str flags}`.
    pub const LISTGROUPANDFLAGS: u16 = 133;
    /// One group/flags entry.
    pub const LISTGROUPANDFLAGSSINGLE: u16 = 134;
}

/// Fixed commands sent by the client.
pub mod client {
    /// The client is leaving.
    pub const SHUTDOWN: u16 = 1;
    /// The client's introduction.
    pub const INTRODUCTION: u16 = 2;
    /// UDP introduction.
    pub const UDP_INTRO: u16 = 3;
    /// UDP confirmation.
    pub const UDP_CONFIRM: u16 = 4;
    /// Use TCP only (no UDP).
    pub const TCP_ONLY: u16 = 5;
    /// Ask for the lists again.
    pub const LIST: u16 = 128;
    /// Request named data: `u16 cmd`, `byte4 intervalMs` (−1: only when broadcast).
    pub const REQUEST: u16 = 129;
    /// Stop a request: `u16 cmd`.
    pub const REQUESTSTOP: u16 = 130;
}

/// First named data number; named data are numbered from here in registration order.
pub const FIRST_DATA_NUMBER: u16 = 256;

/// Whether `command` is a fixed command number a server may send.
pub fn is_fixed_server_command(command: u16) -> bool {
    matches!(command, 1..=7 | 129..=134)
}

/// The server's INTRODUCTION.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServerIntroduction {
    /// Always `"alpha"` in ARIA 2.9.1.
    pub greeting: String,
    /// The server's UDP port.
    pub udp_port: u16,
    /// Authentication key (UDP).
    pub auth_key: u32,
    /// Introduction key (UDP).
    pub intro_key: u32,
    /// Salt of the password hash.
    pub password_key: String,
    /// The server's protocol version.
    pub protocol_version: String,
}

impl ServerIntroduction {
    /// The packet.
    pub fn to_packet(&self) -> Packet {
        Packet::new(
            server::INTRODUCTION,
            PayloadWriter::new()
                .str(&self.greeting)
                .u16(self.udp_port)
                .u32(self.auth_key)
                .u32(self.intro_key)
                .str(&self.password_key)
                .str(&self.protocol_version)
                .finish(),
        )
    }

    /// Decodes the payload of a server INTRODUCTION.
    pub fn decode(payload: &[u8]) -> Result<Self, PacketError> {
        let mut r = PayloadReader::new(payload);
        Ok(Self {
            greeting: r.str("greeting")?,
            udp_port: r.u16("udpPort")?,
            auth_key: r.u32("authKey")?,
            intro_key: r.u32("introKey")?,
            password_key: r.str("passwordKey")?,
            protocol_version: r.str("protocolVersion")?,
        })
    }
}

/// The hash a client sends: `md5(server_key + password_key + password)`.
pub fn password_hash(server_key: &str, password_key: &str, password: &str) -> [u8; 16] {
    let mut h = Md5::new();
    h.update(server_key.as_bytes());
    h.update(password_key.as_bytes());
    h.update(password.as_bytes());
    h.finalize().into()
}

/// The client's INTRODUCTION.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientIntroduction {
    /// The client's UDP port (unused with TCP_ONLY).
    pub udp_port: u16,
    /// User name.
    pub user: String,
    /// [`password_hash`].
    pub password_hash: [u8; 16],
    /// The client's protocol version (QUT's driver sends `"5MTX"`).
    pub protocol_version: String,
    /// Client type (0).
    pub client_type: u8,
}

impl ClientIntroduction {
    /// The packet.
    pub fn to_packet(&self) -> Packet {
        Packet::new(
            client::INTRODUCTION,
            PayloadWriter::new()
                .u16(self.udp_port)
                .str(&self.user)
                .bytes(&self.password_hash)
                .str(&self.protocol_version)
                .u8(self.client_type)
                .finish(),
        )
    }

    /// Decodes the payload of a client INTRODUCTION.
    pub fn decode(payload: &[u8]) -> Result<Self, PacketError> {
        let mut r = PayloadReader::new(payload);
        let udp_port = r.u16("udpPort")?;
        let user = r.str("user")?;
        let mut password_hash = [0; 16];
        password_hash.copy_from_slice(r.bytes(16, "passwordHash")?);
        Ok(Self {
            udp_port,
            user,
            password_hash,
            protocol_version: r.str("protocolVersion")?,
            client_type: r.u8("type")?,
        })
    }
}

/// Why a server rejected a client (REJECTED's `byte2 reason`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RejectReason {
    /// 1: bad user or password.
    BadUserPassword,
    /// 4: protocol version mismatch.
    ProtocolMismatch,
    /// 5: too many clients.
    TooManyClients,
    /// 6: client type mismatch.
    TypeMismatch,
    /// Any other code.
    Other(i16),
}

impl RejectReason {
    /// From the wire code.
    pub fn from_code(code: i16) -> Self {
        match code {
            1 => Self::BadUserPassword,
            4 => Self::ProtocolMismatch,
            5 => Self::TooManyClients,
            6 => Self::TypeMismatch,
            other => Self::Other(other),
        }
    }

    /// The wire code.
    pub fn code(self) -> i16 {
        match self {
            Self::BadUserPassword => 1,
            Self::ProtocolMismatch => 4,
            Self::TooManyClients => 5,
            Self::TypeMismatch => 6,
            Self::Other(c) => c,
        }
    }

    /// The REJECTED packet with this reason and `text`.
    pub fn to_packet(self, text: &str) -> Packet {
        Packet::new(
            server::REJECTED,
            PayloadWriter::new().i16(self.code()).str(text).finish(),
        )
    }
}

/// One entry of a LIST, LISTARGRET or LISTGROUPANDFLAGS packet: a data number and two strings
/// (name and description; arguments and return; group and flags).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ListEntry {
    /// Data number.
    pub command: u16,
    /// First string.
    pub first: String,
    /// Second string.
    pub second: String,
}

/// Encodes a list packet (`command` is LIST, LISTARGRET or LISTGROUPANDFLAGS).
pub fn list_packet(command: u16, entries: &[ListEntry]) -> Packet {
    let mut w = PayloadWriter::new().u16(entries.len() as u16);
    for e in entries {
        w = w.u16(e.command).str(&e.first).str(&e.second);
    }
    Packet::new(command, w.finish())
}

/// Decodes a list packet's payload.
pub fn decode_list(payload: &[u8]) -> Result<Vec<ListEntry>, PacketError> {
    let mut r = PayloadReader::new(payload);
    let count = r.u16("count")?;
    (0..count)
        .map(|_| {
            Ok(ListEntry {
                command: r.u16("cmd")?,
                first: r.str("name")?,
                second: r.str("description")?,
            })
        })
        .collect()
}

/// Data names to numbers, from a LIST.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DataMap {
    by_name: BTreeMap<String, u16>,
    by_number: BTreeMap<u16, String>,
}

impl DataMap {
    /// The map of a LIST's entries.
    pub fn from_entries(entries: &[ListEntry]) -> Self {
        let mut map = Self::default();
        for e in entries {
            map.by_name.insert(e.first.clone(), e.command);
            map.by_number.insert(e.command, e.first.clone());
        }
        map
    }

    /// The number of data `name`.
    pub fn number(&self, name: &str) -> Option<u16> {
        self.by_name.get(name).copied()
    }

    /// The name of data number `number`.
    pub fn name(&self, number: u16) -> Option<&str> {
        self.by_number.get(&number).map(String::as_str)
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.by_name.len()
    }

    /// Whether the map is empty.
    pub fn is_empty(&self) -> bool {
        self.by_name.is_empty()
    }
}

/// REQUEST(129) of data `number` every `interval_ms` (−1: only when the server broadcasts).
pub fn request_packet(number: u16, interval_ms: i32) -> Packet {
    Packet::new(
        client::REQUEST,
        PayloadWriter::new().u16(number).i32(interval_ms).finish(),
    )
}

/// REQUESTSTOP(130) of data `number`.
pub fn request_stop_packet(number: u16) -> Packet {
    Packet::new(
        client::REQUESTSTOP,
        PayloadWriter::new().u16(number).finish(),
    )
}

/// `ratioDrive`'s arguments, percentages in −100…100.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RatioDrive {
    /// Translation, % of the top speed.
    pub trans: f64,
    /// Rotation, % of the top rotation speed.
    pub rot: f64,
    /// Throttle, % (scales the translation).
    pub throttle: f64,
    /// Lateral, % (0 on a differential base).
    pub lateral: f64,
}

impl RatioDrive {
    /// Standing still, full throttle.
    pub const ZERO: Self = Self {
        trans: 0.0,
        rot: 0.0,
        throttle: 100.0,
        lateral: 0.0,
    };

    /// The payload: four `%g` doubles.
    pub fn payload(&self) -> Vec<u8> {
        PayloadWriter::new()
            .double(self.trans)
            .double(self.rot)
            .double(self.throttle)
            .double(self.lateral)
            .finish()
    }

    /// Decodes and range-checks a payload (a value outside −100…100 or not finite is an error).
    pub fn decode(payload: &[u8]) -> Result<Self, PacketError> {
        let mut r = PayloadReader::new(payload);
        let drive = Self {
            trans: r.double("trans")?,
            rot: r.double("rot")?,
            throttle: r.double("throttle")?,
            lateral: r.double("lateral")?,
        };
        for (field, v) in [
            ("trans", drive.trans),
            ("rot", drive.rot),
            ("throttle", drive.throttle),
            ("lateral", drive.lateral),
        ] {
            if !(v.is_finite() && (-100.0..=100.0).contains(&v)) {
                return Err(PacketError::BadField {
                    field,
                    detail: format!("{v} is outside -100..100"),
                });
            }
        }
        Ok(drive)
    }
}

/// `updateNumbers`: the robot's pose, speeds, battery and temperature, in the protocol's units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UpdateNumbers {
    /// Battery voltage × 10.
    pub battery_dv: i16,
    /// x, mm.
    pub x_mm: i32,
    /// y, mm.
    pub y_mm: i32,
    /// Heading, degrees.
    pub th_deg: i16,
    /// Forward speed, mm/s.
    pub vel_mm_s: i16,
    /// Rotation speed, deg/s.
    pub rot_vel_deg_s: i16,
    /// Lateral speed, mm/s.
    pub lat_vel_mm_s: i16,
    /// Temperature, °C (−128: unknown).
    pub temperature_c: i8,
}

impl UpdateNumbers {
    /// Payload bytes (19: odd, so the checksum skips the temperature byte).
    pub const LEN: usize = 19;

    /// The payload.
    pub fn payload(&self) -> Vec<u8> {
        PayloadWriter::new()
            .i16(self.battery_dv)
            .i32(self.x_mm)
            .i32(self.y_mm)
            .i16(self.th_deg)
            .i16(self.vel_mm_s)
            .i16(self.rot_vel_deg_s)
            .i16(self.lat_vel_mm_s)
            .i8(self.temperature_c)
            .finish()
    }

    /// Decodes a payload (a short one is an error).
    pub fn decode(payload: &[u8]) -> Result<Self, PacketError> {
        let mut r = PayloadReader::new(payload);
        Ok(Self {
            battery_dv: r.i16("battery")?,
            x_mm: r.i32("x")?,
            y_mm: r.i32("y")?,
            th_deg: r.i16("th")?,
            vel_mm_s: r.i16("vel")?,
            rot_vel_deg_s: r.i16("rotVel")?,
            lat_vel_mm_s: r.i16("latVel")?,
            temperature_c: r.i8("temperature")?,
        })
    }

    /// As odometry in SI units.
    pub fn odometry(&self) -> Odometry {
        let yaw = f64::from(self.th_deg).to_radians();
        Odometry {
            x: f64::from(self.x_mm) * 1e-3,
            y: f64::from(self.y_mm) * 1e-3,
            yaw: (yaw.sin()).atan2(yaw.cos()),
            v: f64::from(self.vel_mm_s) * 1e-3,
            omega: f64::from(self.rot_vel_deg_s).to_radians(),
            lateral: f64::from(self.lat_vel_mm_s) * 1e-3,
            battery_v: f64::from(self.battery_dv) * 0.1,
            temperature_c: (self.temperature_c != -128).then_some(self.temperature_c),
        }
    }

    /// From odometry in SI units, rounded to the protocol's resolution (1 mm, 1°, 1 mm/s,
    /// 1°/s) and saturated at the fields' ranges.
    pub fn from_odometry(o: &Odometry) -> Self {
        fn i16_of(x: f64) -> i16 {
            x.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
        }
        fn i32_of(x: f64) -> i32 {
            x.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
        }
        Self {
            battery_dv: i16_of(o.battery_v * 10.0),
            x_mm: i32_of(o.x * 1e3),
            y_mm: i32_of(o.y * 1e3),
            th_deg: i16_of(o.yaw.to_degrees()),
            vel_mm_s: i16_of(o.v * 1e3),
            rot_vel_deg_s: i16_of(o.omega.to_degrees()),
            lat_vel_mm_s: i16_of(o.lateral * 1e3),
            temperature_c: o.temperature_c.unwrap_or(-128),
        }
    }
}

/// The base's odometry in SI units (from [`UpdateNumbers`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Odometry {
    /// x, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Heading, rad in [−π, π].
    pub yaw: f64,
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
    /// Lateral speed, m/s.
    pub lateral: f64,
    /// Battery voltage, V.
    pub battery_v: f64,
    /// Temperature, °C, when known.
    pub temperature_c: Option<i8>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn introductions_round_trip_and_the_hash_is_md5_of_the_concatenation() {
        let s = ServerIntroduction {
            greeting: "alpha".into(),
            udp_port: 7272,
            auth_key: 0x01020304,
            intro_key: 0x0a0b0c0d,
            password_key: "salt".into(),
            protocol_version: "5MTX".into(),
        };
        let p = s.to_packet();
        assert_eq!(p.command, 2);
        assert_eq!(ServerIntroduction::decode(&p.payload).unwrap(), s);
        // md5("") and md5("abc") are the RFC 1321 test vectors.
        let empty = password_hash("", "", "");
        assert_eq!(empty[..4], [0xd4, 0x1d, 0x8c, 0xd9]);
        let abc = password_hash("a", "b", "c");
        assert_eq!(abc[..4], [0x90, 0x01, 0x50, 0x98]);
        let c = ClientIntroduction {
            udp_port: 0,
            user: "guest".into(),
            password_hash: abc,
            protocol_version: "5MTX".into(),
            client_type: 0,
        };
        assert_eq!(
            ClientIntroduction::decode(&c.to_packet().payload).unwrap(),
            c
        );
        assert!(ClientIntroduction::decode(&c.to_packet().payload[..10]).is_err());
    }

    #[test]
    fn lists_map_names_to_numbers() {
        let entries = vec![
            ListEntry {
                command: 256,
                first: "updateNumbers".into(),
                second: "pose".into(),
            },
            ListEntry {
                command: 300,
                first: "ratioDrive".into(),
                second: "drive".into(),
            },
        ];
        let p = list_packet(server::LIST, &entries);
        let decoded = decode_list(&p.payload).unwrap();
        assert_eq!(decoded, entries);
        let map = DataMap::from_entries(&decoded);
        assert_eq!(map.number("ratioDrive"), Some(300));
        assert_eq!(map.name(256), Some("updateNumbers"));
        assert_eq!(map.number("nope"), None);
        // A count larger than the entries present is an error, not a short list.
        let mut bad = p.payload.clone();
        bad[0] = 3;
        assert!(decode_list(&bad).is_err());
    }

    #[test]
    fn update_numbers_decode_to_si_odometry() {
        let u = UpdateNumbers {
            battery_dv: 261,
            x_mm: 1500,
            y_mm: -250,
            th_deg: 90,
            vel_mm_s: 300,
            rot_vel_deg_s: -30,
            lat_vel_mm_s: 0,
            temperature_c: -128,
        };
        let payload = u.payload();
        assert_eq!(payload.len(), UpdateNumbers::LEN);
        assert_eq!(UpdateNumbers::decode(&payload).unwrap(), u);
        let o = u.odometry();
        assert!((o.x - 1.5).abs() < 1e-12 && (o.y + 0.25).abs() < 1e-12);
        assert!((o.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((o.v - 0.3).abs() < 1e-12 && (o.omega + 30f64.to_radians()).abs() < 1e-12);
        assert!((o.battery_v - 26.1).abs() < 1e-12);
        assert_eq!(o.temperature_c, None);
        assert_eq!(UpdateNumbers::from_odometry(&o), u);
        assert!(UpdateNumbers::decode(&payload[..18]).is_err());
        // th = 270° is −90°.
        let o = UpdateNumbers { th_deg: 270, ..u }.odometry();
        assert!((o.yaw + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn ratio_drive_payloads_are_range_checked() {
        let d = RatioDrive {
            trans: 50.0,
            rot: 0.0,
            throttle: 100.0,
            lateral: 0.0,
        };
        assert_eq!(RatioDrive::decode(&d.payload()).unwrap(), d);
        let bad = RatioDrive { trans: 150.0, ..d };
        assert!(RatioDrive::decode(&bad.payload()).is_err());
        let nan = RatioDrive { rot: f64::NAN, ..d };
        assert!(RatioDrive::decode(&nan.payload()).is_err());
        assert!(RatioDrive::decode(&d.payload()[..5]).is_err());
    }
}
