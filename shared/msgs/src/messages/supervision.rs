//! The supervisor's process table, published so that `motm status`, `motm run` and restarted
//! processes can see which processes run, under which pid, and how often each was restarted.

use iceoryx2::prelude::ZeroCopySend;

use super::{PROCESS_NAME_BYTES, padding};
use crate::validate::Check;
use crate::{Header, Message, RejectReason, Rejection};

/// Most processes one supervisor manages.
pub const MAX_SUPERVISED_PROCESSES: usize = 16;

code_enum!(
    /// Lifecycle of a supervised process, as the supervisor sees it.
    SupervisedState {
        /// Not started yet.
        Pending = 0,
        /// Running under the pid in the entry.
        Running = 1,
        /// Exited; a restart is scheduled after the backoff.
        Restarting = 2,
        /// Exited and will not be restarted (restart budget used up or spawn failure).
        Failed = 3,
        /// Stopped on purpose (shutdown).
        Stopped = 4,
    }
);

/// One row of the [`SupervisorStatus`] table.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SupervisedProcess")]
#[repr(C)]
pub struct SupervisedProcess {
    /// Process name, UTF-8, zero padded.
    pub name: [u8; PROCESS_NAME_BYTES],
    /// Operating-system pid of the current instance (0 when none runs).
    pub pid: u32,
    /// [`SupervisedState`] code.
    pub state: u32,
    /// Restarts so far.
    pub restarts: u32,
    /// Exit code of the last exit, or minus the signal number that ended it (0 when none).
    pub last_exit: i32,
}

impl SupervisedProcess {
    /// The lifecycle state, if the code is valid.
    pub fn state(&self) -> Option<SupervisedState> {
        SupervisedState::try_from(self.state).ok()
    }

    /// The process name (empty if it is not valid UTF-8).
    pub fn name(&self) -> &str {
        let len = self
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(PROCESS_NAME_BYTES);
        core::str::from_utf8(&self.name[..len]).unwrap_or("")
    }

    /// Stores `name`, truncated to [`PROCESS_NAME_BYTES`] at a character boundary.
    pub fn set_name(&mut self, name: &str) {
        let mut len = name.len().min(PROCESS_NAME_BYTES);
        while !name.is_char_boundary(len) {
            len -= 1;
        }
        self.name = [0; PROCESS_NAME_BYTES];
        self.name[..len].copy_from_slice(&name.as_bytes()[..len]);
    }
}

/// The supervisor's process table.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("motm.v1.SupervisorStatus")]
#[repr(C)]
pub struct SupervisorStatus {
    /// Common header.
    pub header: Header,
    /// Rows in use at the front of `processes`.
    pub process_count: u32,
    /// 1 while the supervisor shuts the stack down, 0 otherwise.
    pub shutting_down: u32,
    /// The supervised processes, in start order.
    pub processes: [SupervisedProcess; MAX_SUPERVISED_PROCESSES],
}

impl SupervisorStatus {
    /// The rows in use.
    pub fn processes(&self) -> &[SupervisedProcess] {
        let count = (self.process_count as usize).min(MAX_SUPERVISED_PROCESSES);
        &self.processes[..count]
    }
}

message!(SupervisorStatus, |m, c| {
    if m.process_count as usize > MAX_SUPERVISED_PROCESSES {
        return Err(c.reject(
            "process_count",
            None,
            RejectReason::OutOfRange {
                value: f64::from(m.process_count),
                min: 0.0,
                max: MAX_SUPERVISED_PROCESSES as f64,
            },
        ));
    }
    if m.shutting_down > 1 {
        return Err(c.reject(
            "shutting_down",
            None,
            RejectReason::UnknownCode(m.shutting_down),
        ));
    }
    for (i, row) in m.processes().iter().enumerate() {
        check_row(c, i, row)?;
    }
    padding_rows(c, m)
});

/// Checks one row: a known state and a non-empty zero-padded UTF-8 name.
fn check_row(c: Check, index: usize, row: &SupervisedProcess) -> Result<(), Rejection> {
    if SupervisedState::try_from(row.state).is_err() {
        return Err(c.reject(
            "processes.state",
            Some(index),
            RejectReason::UnknownCode(row.state),
        ));
    }
    let len = row
        .name
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(PROCESS_NAME_BYTES);
    let padded = row.name[len..].iter().all(|&b| b == 0);
    if len == 0 || !padded || core::str::from_utf8(&row.name[..len]).is_err() {
        return Err(c.reject(
            "processes.name",
            Some(index),
            RejectReason::Inconsistent("must be non-empty zero-padded UTF-8"),
        ));
    }
    Ok(())
}

/// Rows past `process_count` must be all zero.
fn padding_rows(c: Check, m: &SupervisorStatus) -> Result<(), Rejection> {
    let count = (m.process_count as usize).min(MAX_SUPERVISED_PROCESSES);
    for row in &m.processes[count..] {
        let zero = row.name.iter().all(|&b| b == 0)
            && row.pid == 0
            && row.state == 0
            && row.restarts == 0
            && row.last_exit == 0;
        if !zero {
            return padding(c, 1);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> SupervisorStatus {
        let mut s = SupervisorStatus::zeroed();
        s.header = Header::new(10, 0);
        s.process_count = 2;
        for (row, name) in s.processes.iter_mut().zip(["sim-world", "watchdog"]) {
            row.set_name(name);
            row.pid = 42;
            row.state = SupervisedState::Running.into();
        }
        s
    }

    #[test]
    fn a_valid_table_is_accepted_and_read_back() {
        let s = status();
        assert!(s.validate(100, None).is_ok());
        let names: Vec<_> = s.processes().iter().map(SupervisedProcess::name).collect();
        assert_eq!(names, ["sim-world", "watchdog"]);
        assert_eq!(s.processes()[1].state(), Some(SupervisedState::Running));
    }

    #[test]
    fn bad_tables_are_rejected_naming_the_field() {
        let mut s = status();
        s.process_count = MAX_SUPERVISED_PROCESSES as u32 + 1;
        assert_eq!(s.validate(100, None).unwrap_err().field, "process_count");
        let mut s = status();
        s.processes[1].state = 99;
        let r = s.validate(100, None).unwrap_err();
        assert_eq!((r.field, r.index), ("processes.state", Some(1)));
        let mut s = status();
        s.processes[0].name = [0; PROCESS_NAME_BYTES];
        assert_eq!(s.validate(100, None).unwrap_err().field, "processes.name");
        let mut s = status();
        s.processes[5].pid = 7;
        assert_eq!(s.validate(100, None).unwrap_err().field, "reserved");
        let mut s = status();
        s.shutting_down = 2;
        assert_eq!(s.validate(100, None).unwrap_err().field, "shutting_down");
    }
}
