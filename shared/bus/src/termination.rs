//! SIGTERM/SIGINT as a latch that stays set.
//!
//! iceoryx2's signal handler keeps only the *last* signal, and reading it clears it. Two things
//! lose a termination request that way:
//! - a supervisor sends SIGTERM and then SIGCONT (so that a stopped process can act on it);
//!   when both are pending at once the kernel runs the handlers in signal-number order, so
//!   SIGCONT (18) overwrites SIGTERM (15) and the process never sees it (measured: the fake
//!   Panda ran on until SIGKILL in 2 of 3 shutdowns);
//! - two readers of the request (a WaitSet and the loop around it) each clear it for the other.
//!
//! [`install`] puts a handler on SIGTERM and SIGINT that sets a process-wide flag and nothing
//! else (async-signal-safe). It does not use `SA_RESTART`, so a blocking wait returns early as
//! before. [`termination_requested`] reads the flag and never clears it.

use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);
static INSTALL: Once = Once::new();

extern "C" fn latch(_signal: libc::c_int) {
    REQUESTED.store(true, Ordering::SeqCst);
}

/// Installs the SIGTERM/SIGINT latch (once per process; later calls do nothing). iceoryx2's own
/// handlers are set up first, so that they cannot replace this one later.
pub fn install() {
    INSTALL.call_once(|| {
        // Creates iceoryx2's handler singleton (it registers its handlers once, on creation)
        // and takes over a request that arrived before this point.
        if let Some(
            iceoryx2_bb_posix::signal::NonFatalFetchableSignal::Terminate
            | iceoryx2_bb_posix::signal::NonFatalFetchableSignal::Interrupt,
        ) = iceoryx2_bb_posix::signal::SignalHandler::last_signal()
        {
            REQUESTED.store(true, Ordering::SeqCst);
        }
        for signal in [libc::SIGTERM, libc::SIGINT] {
            // SAFETY: `action` is fully initialised; `latch` only stores to an atomic.
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = latch as *const () as libc::sighandler_t;
                libc::sigemptyset(&mut action.sa_mask);
                action.sa_flags = 0;
                libc::sigaction(signal, &action, std::ptr::null_mut());
            }
        }
    });
}

/// Whether SIGTERM or SIGINT has arrived since [`install`] (it stays true).
pub fn termination_requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}
