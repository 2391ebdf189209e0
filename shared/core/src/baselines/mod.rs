//! The paper's baselines (section III-C): the holistic reactive controller of Haviland et al.
//! and its stop-and-grasp task sequence, and the planning baseline.

pub mod holistic;
pub mod planning;
pub mod reactive;
