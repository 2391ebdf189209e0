//! `motm-franka`: the Franka Panda's FCI (libfranka 0.9.2's robot server protocol, version 5)
//! and the Franka Hand (gripper protocol version 3), written from the protocol facts alone (no
//! libfranka code): packed little-endian codecs ([`fci`], [`state`], [`hand`]), libfranka's
//! low-pass filter and rate limiter ([`rate_limit`]), the FCI client state machine
//! ([`client`]), a non-blocking hand client ([`hand::HandClient`]) and fake robots that speak
//! the same protocol on real sockets ([`fake`]). No dependency on the simulator: the
//! `fake-panda` binary plugs the simulator into [`fake::ArmPhysics`] / [`fake::HandPhysics`].
//!
//! The protocol choices where the facts are uncertain are listed in the crate's README.md.
#![warn(missing_docs)]

pub mod client;
pub mod fake;
pub mod fci;
pub mod hand;
pub mod rate_limit;
pub mod state;
pub mod wire;

pub use client::{FciClient, FciConfig, FciCounters, FciError, Motion, MotionEnd, SafeStopCause};
pub use hand::{HandClient, HandConfig, HandError};
pub use rate_limit::{RateLimitConfig, RateLimiter};
pub use state::{RobotCommand, RobotState};
pub use wire::ProtocolError;
