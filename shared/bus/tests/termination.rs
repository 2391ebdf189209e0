//! The termination latch in a process of its own (a raised SIGTERM would stop every service
//! loop of a shared test process).

use motm_bus::termination;

#[test]
fn a_sigcont_after_the_sigterm_does_not_hide_it() {
    termination::install();
    assert!(!termination::termination_requested());
    // Both pending at once, as a supervisor's SIGTERM + SIGCONT reach a sleeping process:
    // blocked while raised, they are delivered in signal-number order on unblocking.
    // SAFETY: plain signal-mask calls on this thread.
    unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        libc::sigaddset(&mut set, libc::SIGTERM);
        libc::sigaddset(&mut set, libc::SIGCONT);
        let mut old: libc::sigset_t = std::mem::zeroed();
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, &mut old);
        libc::raise(libc::SIGTERM);
        libc::raise(libc::SIGCONT);
        libc::pthread_sigmask(libc::SIG_SETMASK, &old, std::ptr::null_mut());
    }
    assert!(termination::termination_requested());
    // Reading does not clear it.
    assert!(termination::termination_requested());
}
