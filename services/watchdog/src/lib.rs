//! The motm watchdog: the `watchdog` process ([`service`]), which raises safe-stop when a
//! control-path heartbeat or command stream goes stale or reports deadline misses (the decision
//! is `motm_core::watchdog::Watchdog`).

pub mod service;
