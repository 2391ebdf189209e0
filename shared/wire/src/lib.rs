//! # motm-wire
//!
//! What the service binaries share beyond their tasks (`motm-tasks`): the common command line
//! and model loading ([`setup`]) and the generic main of a control service ([`serve`]: a
//! service binary is its name, its flags and its task). The tasks run on `motm-runtime`'s
//! ports and loops; their topics, rates and triggers are their rows of `motm_graph::GRAPH`.
//! (The simulated world's own command line is in the `sim-world` service.)

pub mod serve;
pub mod setup;

pub use motm_tasks::{controllers, convert};
pub use serve::{NoFlags, Service, parse, positive};
pub use setup::{ServiceArgs, ServiceSetup, exit_on_error};
