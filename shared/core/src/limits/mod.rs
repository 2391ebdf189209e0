//! The drivers' limits: the command limiter (velocity, acceleration and jerk, ramps to zero
//! on a stale command or safe-stop) and the velocity driver built on it.

pub mod command_limiter;
pub mod velocity_driver;
