//! Supervision: the watchdog's rules, the hot swap of a task controller, the restart policy and
//! the fault schedule of `motm run --fault`.

pub mod fault_schedule;
pub mod hot_swap;
pub mod restart_policy;
pub mod watchdog;
