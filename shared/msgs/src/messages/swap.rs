//! Hot swap of a task controller, as a request to the supervisor and the supervisor's answer.
//!
//! `motm swap` (or `motm run --swap`) publishes a [`SwapRequest`] on
//! [`crate::services::SUPERVISOR_SWAP_REQUEST`]; the supervisor, which owns every process of
//! the stack, performs the swap and reports each stage on
//! [`crate::services::SUPERVISOR_SWAP_STATUS`] as a [`SwapStatus`] carrying the request's id.
//! Publish-subscribe rather than request-response: the status is also what `motm status`, a
//! logger or a test can watch, and a requester that dies leaves nothing pending.

use iceoryx2::prelude::ZeroCopySend;

use super::{ControllerVariant, envelope, padding};
use crate::validate::Check;
use crate::{Header, Message, RejectReason, Rejection};

code_enum!(
    /// Processes that can be hot-swapped.
    SwappableProcess {
        /// The final-phase task controller (`services/final-phase`).
        FinalPhase = 0,
    }
);

impl SwappableProcess {
    /// The process (and heartbeat) name.
    pub fn name(self) -> &'static str {
        match self {
            SwappableProcess::FinalPhase => "final-phase",
        }
    }

    /// The swappable process called `name`, if any.
    pub fn from_name(name: &str) -> Option<Self> {
        (name == "final-phase").then_some(SwappableProcess::FinalPhase)
    }
}

/// A request to replace a running controller process by one of another variant.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SwapRequest")]
#[repr(C)]
pub struct SwapRequest {
    /// Common header.
    pub header: Header,
    /// Id chosen by the requester; the supervisor's [`SwapStatus`] carries it back.
    pub request_id: u64,
    /// Longest wait for the new controller's first command, ms (0: the stack's default).
    pub command_timeout_ms: u64,
    /// [`SwappableProcess`] code.
    pub process: u32,
    /// [`ControllerVariant`] code of the new controller (not `Reacher`).
    pub variant: u32,
}

message!(SwapRequest, |m, c| {
    c.code::<SwappableProcess>("process", m.process)?;
    let variant = c.code::<ControllerVariant>("variant", m.variant)?;
    if variant == ControllerVariant::Reacher {
        return Err(c.reject(
            "variant",
            None,
            RejectReason::Inconsistent("the reacher is not a final-phase variant"),
        ));
    }
    Ok(())
});

code_enum!(
    /// Where a swap stands.
    SwapStageCode {
        /// The new process is started; waiting for its heartbeat and first command.
        Starting = 0,
        /// The active-controller id is flipped and the old process stopped; measuring.
        Flipped = 1,
        /// Done: the new controller is active and owned by the supervisor.
        Done = 2,
        /// Failed: the old controller stays active (see [`SwapFailureCode`]).
        Failed = 3,
    }
);

code_enum!(
    /// Why a swap failed.
    SwapFailureCode {
        /// Not failed.
        None = 0,
        /// Another swap is in progress.
        Busy = 1,
        /// The process to replace is not running (or not in the stack).
        NotRunning = 2,
        /// The new process could not be started.
        SpawnFailed = 3,
        /// The new process sent no heartbeat in time.
        NoHeartbeat = 4,
        /// The new controller sent no command in time.
        NoCommand = 5,
        /// The new process exited before the flip.
        NewExited = 6,
    }
);

/// The supervisor's report on a swap request.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SwapStatus")]
#[repr(C)]
pub struct SwapStatus {
    /// Common header.
    pub header: Header,
    /// The request's id.
    pub request_id: u64,
    /// From starting the new process to its first `Running` heartbeat, ns (0 until then).
    pub heartbeat_wait_ns: u64,
    /// From starting the new process to its first command, ns (0 until then).
    pub command_wait_ns: u64,
    /// Stamp of the flip of the active-controller id, ns (0 before the flip).
    pub flip_stamp_ns: u64,
    /// The gap the swap made in the command stream, ns (0 until done): the longer of old's last
    /// command → flip and flip → new's first command; see `motm_core::hot_swap`.
    pub command_gap_ns: u64,
    /// Old controller's last command before the flip to the new one's first after it, ns.
    pub stamp_gap_ns: u64,
    /// Base forward speed at the flip (odometry), m/s.
    pub base_speed: f64,
    /// [`SwapStageCode`].
    pub stage: u32,
    /// [`SwapFailureCode`]; `None` exactly when the stage is not `Failed`.
    pub failure: u32,
    /// Pid of the replaced process.
    pub old_pid: u32,
    /// Pid of the new process (0 when it could not be started).
    pub new_pid: u32,
    /// Controller id of the replaced process.
    pub old_controller_id: u32,
    /// Controller id of the new process.
    pub new_controller_id: u32,
    /// [`ControllerVariant`] code of the new process.
    pub variant: u32,
    /// Explicit padding (zero).
    pub reserved: u32,
}

impl SwapStatus {
    /// The stage, if the code is valid.
    pub fn stage(&self) -> Option<SwapStageCode> {
        SwapStageCode::try_from(self.stage).ok()
    }

    /// The failure, if the code is valid.
    pub fn failure(&self) -> Option<SwapFailureCode> {
        SwapFailureCode::try_from(self.failure).ok()
    }

    /// Whether the swap is over (done or failed).
    pub fn is_final(&self) -> bool {
        matches!(
            self.stage(),
            Some(SwapStageCode::Done | SwapStageCode::Failed)
        )
    }
}

message!(SwapStatus, |m, c| {
    let stage = c.code::<SwapStageCode>("stage", m.stage)?;
    let failure = c.code::<SwapFailureCode>("failure", m.failure)?;
    c.code::<ControllerVariant>("variant", m.variant)?;
    if (stage == SwapStageCode::Failed) == (failure == SwapFailureCode::None) {
        return Err(c.reject(
            "failure",
            None,
            RejectReason::Inconsistent("failure must be None exactly when the stage is not Failed"),
        ));
    }
    c.in_range(
        "base_speed",
        m.base_speed,
        -envelope::BASE_SPEED,
        envelope::BASE_SPEED,
    )?;
    padding(c, m.reserved)
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_name_a_swappable_process_and_a_final_phase_variant() {
        let mut r = SwapRequest::zeroed();
        r.header = Header::new(10, 0);
        r.variant = ControllerVariant::PressButton.into();
        assert!(r.validate(100, None).is_ok());
        r.variant = ControllerVariant::Reacher.into();
        assert_eq!(r.validate(100, None).unwrap_err().field, "variant");
        r.variant = 9;
        assert_eq!(r.validate(100, None).unwrap_err().field, "variant");
        r.variant = ControllerVariant::Grasp.into();
        r.process = 4;
        assert_eq!(r.validate(100, None).unwrap_err().field, "process");
        assert_eq!(
            SwappableProcess::from_name("final-phase").map(SwappableProcess::name),
            Some("final-phase")
        );
        assert_eq!(SwappableProcess::from_name("reacher"), None);
    }

    #[test]
    fn a_status_fails_exactly_when_it_says_why() {
        let mut s = SwapStatus::zeroed();
        s.header = Header::new(10, 0);
        s.variant = ControllerVariant::PressButton.into();
        s.stage = SwapStageCode::Done.into();
        assert!(s.validate(100, None).is_ok());
        assert!(s.is_final());
        s.failure = SwapFailureCode::NoCommand.into();
        assert_eq!(s.validate(100, None).unwrap_err().field, "failure");
        s.stage = SwapStageCode::Failed.into();
        assert!(s.validate(100, None).is_ok());
        s.stage = SwapStageCode::Starting.into();
        s.failure = SwapFailureCode::None.into();
        assert!(!s.is_final());
        s.base_speed = f64::NAN;
        assert_eq!(s.validate(100, None).unwrap_err().field, "base_speed");
        s.base_speed = 0.0;
        s.reserved = 1;
        assert_eq!(s.validate(100, None).unwrap_err().field, "reserved");
    }
}
