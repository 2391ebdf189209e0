//! The stack's shared time base.

/// Current `CLOCK_MONOTONIC` time in ns: the clock every message header is stamped with. It is
/// the same clock in every process on the machine, so stamps compare across processes.
pub fn monotonic_now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always available on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0, "clock_gettime(CLOCK_MONOTONIC) failed");
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_never_goes_backwards() {
        let mut last = monotonic_now_ns();
        assert!(last > 0);
        for _ in 0..1000 {
            let now = monotonic_now_ns();
            assert!(now >= last);
            last = now;
        }
    }
}
