//! What one task cycle of the deployed stack consumed and produced, for replay logs.
//!
//! After each cycle the runtime publishes a [`TaskCycle`] on
//! [`crate::services::REPLAY_CYCLES`]: the task, its cycle number and time, and the samples
//! the cycle held as inputs and published, each by topic, sequence number and stamp. The
//! logger writes these beside the raw samples, so `motm replay` can feed every cycle's inputs
//! through the task again.
//!
//! Tasks and topics travel as indices into the stack's own tables (the graph's task list and
//! its list of published topics): the logger, built with the stack, turns them into names
//! before anything is written, so a log never depends on the indices.

use iceoryx2::prelude::ZeroCopySend;

use super::{flag, padding};
use crate::validate::Check;
use crate::{Header, Message, RejectReason, Rejection};

/// Most samples one [`TaskCycle`] lists (consumed and produced together).
pub const CYCLE_SAMPLES: usize = 48;

/// One sample a cycle consumed or produced.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("motm.v1.SampleRef")]
#[repr(C)]
pub struct SampleRef {
    /// Index of the topic in the stack's list of published topics.
    pub topic: u32,
    /// Explicit padding, zero.
    pub reserved: u32,
    /// The sample's sequence number.
    pub seq: u64,
    /// The sample's header stamp, ns.
    pub stamp_ns: u64,
}

/// One cycle of a task: what it consumed and what it published.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.TaskCycle")]
#[repr(C)]
pub struct TaskCycle {
    /// Common header.
    pub header: Header,
    /// The task's cycle number, from 0 at the process's start.
    pub cycle: u64,
    /// The cycle's time (the `now` its step was given), ns.
    pub now_ns: u64,
    /// Index of the task in the stack's graph table.
    pub task: u32,
    /// Operating-system pid of the process that ran it (a restart is a new instance).
    pub pid: u32,
    /// Entries of `samples` that are consumed inputs (they come first).
    pub consumed: u32,
    /// Entries of `samples` after the consumed ones that are produced outputs.
    pub produced: u32,
    /// 1 when the cycle had more samples than fit (the record is then incomplete).
    pub truncated: u32,
    /// Explicit padding, zero.
    pub reserved: u32,
    /// The consumed samples, then the produced ones.
    pub samples: [SampleRef; CYCLE_SAMPLES],
}

impl TaskCycle {
    /// The consumed samples.
    pub fn consumed(&self) -> &[SampleRef] {
        &self.samples[..self.consumed as usize]
    }

    /// The produced samples.
    pub fn produced(&self) -> &[SampleRef] {
        let start = self.consumed as usize;
        &self.samples[start..start + self.produced as usize]
    }
}

message!(TaskCycle, |m, c| {
    padding(c, m.reserved)?;
    if m.consumed as usize + m.produced as usize > CYCLE_SAMPLES {
        return Err(c.reject(
            "produced",
            None,
            RejectReason::Inconsistent("consumed + produced must not exceed CYCLE_SAMPLES"),
        ));
    }
    flag(c, "truncated", m.truncated)?;
    if let Some(i) = m.samples.iter().position(|s| s.reserved != 0) {
        return Err(c.reject(
            "samples.reserved",
            Some(i),
            RejectReason::Inconsistent("must be zero"),
        ));
    }
    Ok(())
});
