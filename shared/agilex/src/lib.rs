//! AgileX CAN bases, protocol v2 (Scout 2.0, Scout Mini, Tracer, Ranger): the frames
//! ([`frame`], [`protocol`]), a small [`CanBus`] trait with a `socketcan` socket, an in-memory
//! pair, a `candump -L` logger and a log replayer ([`bus`]), the host side a driver uses
//! ([`host`]) and a fake base ([`fake`]).
//!
//! Protocol facts (from the vendor's protocol-v2 documents and SDK, Apache-2.0): CAN 2.0B at
//! 500 kbit/s, 11-bit IDs, DLC 8, big-endian signed fields, no checksum. The host sends 0x421
//! (CAN mode) once, then 0x111 every 20 ms; the base stops after 500 ms without a 0x111. The
//! base sends 0x221 and 0x311 every 20 ms and 0x211 every 100 ms. *Uncertain*, so config
//! values or raw data: the error-code bits of 0x211 (kept raw), the track width of the wheel
//! odometry ([`host::HostConfig`]).
//!
//! The crate does not depend on the simulator.

pub mod bus;
pub mod fake;
pub mod frame;
pub mod host;
pub mod protocol;

pub use bus::{CanBus, CanBusError, LoggingBus, MemoryBus, ReplayBus, SocketCanBus};
pub use fake::{FakeBase, FakeBaseConfig, FakeBaseCounters, FakeBaseHandle};
pub use frame::{Frame, FrameError};
pub use host::{AgilexHost, BaseOdometry, HostConfig, HostCounters, HostFault};
