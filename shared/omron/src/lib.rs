//! Clients for the Omron LD-60 (ARAM): the ArNetworking binary protocol, which drives the
//! base ([`client::ArClient`]: handshake, `ratioDrive`, `stop`, `updateNumbers`), and the ARCL
//! text protocol ([`arcl::ArclClient`]: login, status, e-stop and docking lines).
//!
//! Protocol facts come from ARIA 2.9.1's ArNetworking (GPL: only the facts, no code) and the
//! ARCL reference guide; what is *uncertain* for ARAM is a config value:
//!
//! | fact | where |
//! | --- | --- |
//! | packet framing, checksum (high byte first, starts at byte 3, skips the last byte of an odd payload) | [`packet`] |
//! | doubles as `%g` strings, strings NUL-terminated, integers little-endian | [`packet`] |
//! | handshake, REJECTED reasons, LIST mapping names to numbers from 256 | [`protocol`], [`client`] |
//! | ratioDrive percentages from transVelMax / rotVelMax, reverse cap ¼, rotation falling to ½ at full speed (config) | [`drive`] |
//! | updateNumbers fields and units (1 mm, 1°, 1 mm/s, 1°/s) | [`protocol::UpdateNumbers`] |
//! | user, password, server key, protocol version `5MTX`, update interval (config) | [`client::ClientConfig`] |
//! | the server stops the base 2 s after the last ratioDrive (its "Timeout" setting) | the fake robot (`motm-fake-ld60`) |
//!
//! The crate does not depend on the simulator: it only speaks the protocols.

pub mod arcl;
pub mod client;
pub mod drive;
pub mod packet;
pub mod protocol;

pub use arcl::{ArclClient, ArclError, ArclLine, ArclStatus};
pub use client::{ArClient, ClientConfig, ClientCounters, ClientError, Event};
pub use drive::{DriveLimits, RatioCommand};
pub use packet::{Packet, PacketError};
pub use protocol::{Odometry, RatioDrive, UpdateNumbers};

/// Default ArNetworking port.
pub const ARNL_PORT: u16 = 7272;
/// Default ARCL port.
pub const ARCL_PORT: u16 = 7171;
