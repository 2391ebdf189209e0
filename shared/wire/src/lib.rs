//! # motm-wire
//!
//! What the control services (perception, base-planner, reacher, final-phase, qp-resolver)
//! share beyond their step functions: the common command line and model loading ([`setup`]),
//! conversions between `motm-msgs` payloads and `motm-core` types ([`convert`]), and the
//! latest-value inputs most services read each cycle ([`inputs`]).

pub mod convert;
pub mod inputs;
pub mod setup;

pub use setup::{ServiceArgs, ServiceSetup, exit_on_error, report_exit};
