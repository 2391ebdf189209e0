//! A child process owned by its parent: SIGTERM for a clean stop, killed and reaped on drop, so
//! a test or a tool that fails early never leaves a service running.

use std::process::{Child, Command, ExitStatus};

/// A running child process; killed and reaped when dropped if it is still running.
pub struct OwnedProcess {
    child: Child,
}

impl OwnedProcess {
    /// Starts `command`.
    pub fn spawn(command: &mut Command) -> std::io::Result<Self> {
        Ok(Self {
            child: command.spawn()?,
        })
    }

    /// The process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Sends SIGTERM (the services' clean stop) and waits for the exit.
    pub fn terminate(mut self) -> std::io::Result<ExitStatus> {
        // SAFETY: plain kill(2) on our own child, which has not been reaped yet.
        let rc = unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        if rc != 0 {
            return Err(std::io::Error::last_os_error());
        }
        self.child.wait()
    }
}

impl Drop for OwnedProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
