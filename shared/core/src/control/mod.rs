//! The MotM control laws (paper section III): the base controller, the reacher, the
//! final-phase task controllers, the redundancy-resolution QP, perception and the mission
//! sequencer, with the per-process cycle functions the tasks step ([`stack`]) and the
//! controllers' config ([`on_the_move`]).

pub mod base_command_rate;
pub mod base_controller;
pub mod base_slip;
pub mod facing;
pub mod final_phase;
pub mod input_check;
pub mod localization;
pub mod mission;
pub mod mission_file;
pub mod mission_tracker;
pub mod on_the_move;
pub mod outline;
pub mod perception;
pub mod qp_scenario;
pub mod quintic;
pub mod reacher;
pub mod resolver;
pub mod route;
pub mod servo;
pub mod stack;
