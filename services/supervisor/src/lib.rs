//! The motm supervisor's library: the stack configuration (`config/<robot>.toml`: which
//! processes run, at which rates, with which arguments), the process table that starts,
//! reaps and restarts them, and where their binaries are found; [`service`] is the
//! `supervisor` process. The `supervisor` binary and `motm run` both use it.

pub mod binaries;
pub mod process_table;
pub mod service;
pub use motm_stack as stack;
pub mod swap;

pub use motm_sim::scenario_path;
pub use process_table::{LaunchSpec, ProcessTable, TableEvent};
pub use stack::{LaunchContext, ProcessConfig, StackConfig};
