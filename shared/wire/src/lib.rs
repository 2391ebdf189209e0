//! # motm-wire
//!
//! What the service binaries share beyond their tasks (`motm-tasks`, `motm-sim`'s
//! `SimWorldTask`): the common command line and model loading ([`setup`]), the generic main of
//! a control service ([`serve`]: a service binary is its name, its flags and its task), and
//! the command line of the simulated world ([`sim_world`]). The tasks run on
//! `motm-runtime`'s ports and loops; their topics, rates and triggers are their rows of
//! `motm_graph::GRAPH`.

pub mod serve;
pub mod setup;
pub mod sim_world;

pub use motm_tasks::{controllers, convert};
pub use serve::{NoFlags, Service, parse, positive};
pub use setup::{ServiceArgs, ServiceSetup, exit_on_error};
