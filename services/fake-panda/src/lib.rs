//! The fake Franka Panda and Franka Hand: the `fake-panda` process ([`service`]), which serves
//! the real FCI and Hand protocols on loopback (`motm_franka::fake`) with the simulator's
//! physics behind them.

pub mod service;
