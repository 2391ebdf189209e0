//! Where a periodic [`crate::ServiceLoop`] gets its ticks from.
//!
//! iceoryx2 0.10's `WaitSet::attach_interval` keeps its ticks on a fixed grid, but it waits for
//! the next one with `epoll_wait`, whose timeout is in whole milliseconds and which the WaitSet
//! rounds *up* (`div_ceil(1 ms)`), plus the kernel's timer slack (50 µs by default). At 1 kHz
//! the wait is then always a full millisecond from the *end* of the previous cycle, so each
//! wake-up is later than the last by the step time plus the slack, until the lateness passes
//! a period: that cycle misses its deadline, the tick after it is coalesced, and the drift
//! starts over (about one miss in ten cycles for a 0.1 ms step). At 200 Hz the same rounding
//! costs under a millisecond of a 5 ms period, so it rarely shows.
//!
//! [`PeriodicTimer`] is a Linux `timerfd` on `CLOCK_MONOTONIC` with absolute expirations
//! (`origin + k * period`), attached to the WaitSet as a file descriptor: the kernel's
//! high-resolution timer wakes the epoll wait at the tick itself, with no rounding, no drift
//! and no timer slack (timerfd expirations are exact; the wait has no timeout at all).

use std::str::FromStr;
use std::time::Duration;

use iceoryx2_bb_posix::file_descriptor::{FileDescriptor, FileDescriptorBased};
use iceoryx2_bb_posix::file_descriptor_set::SynchronousMultiplexing;

/// Environment variable that overrides [`crate::LoopConfig::tick_source`] for every periodic
/// loop of a process (`timerfd` or `waitset-interval`), for A/B measurements of a whole stack.
pub const TICK_SOURCE_ENV: &str = "MOTM_TICK_SOURCE";

/// The timer behind [`crate::ServiceLoop::run_periodic`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TickSource {
    /// A [`PeriodicTimer`] (`timerfd`, absolute `CLOCK_MONOTONIC` ticks) attached to the
    /// WaitSet as a file descriptor: wakes at the tick within the kernel's wake-up latency.
    /// The default.
    #[default]
    Timerfd,
    /// iceoryx2's `WaitSet::attach_interval`: a fixed tick grid, but waited for with a
    /// millisecond `epoll_wait` timeout rounded up, so at periods near 1 ms the wake-ups
    /// drift late and about one cycle in ten misses its deadline (see the module docs).
    WaitsetInterval,
}

impl TickSource {
    /// The name used in [`TICK_SOURCE_ENV`].
    pub fn name(self) -> &'static str {
        match self {
            Self::Timerfd => "timerfd",
            Self::WaitsetInterval => "waitset-interval",
        }
    }

    /// The source named by [`TICK_SOURCE_ENV`], if set; an unknown name is an error that names
    /// the variable and the accepted values.
    pub fn from_env() -> Result<Option<Self>, String> {
        match std::env::var(TICK_SOURCE_ENV) {
            Ok(value) => value
                .parse()
                .map(Some)
                .map_err(|e| format!("{TICK_SOURCE_ENV}: {e}")),
            Err(std::env::VarError::NotPresent) => Ok(None),
            Err(e) => Err(format!("{TICK_SOURCE_ENV}: {e}")),
        }
    }
}

impl FromStr for TickSource {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [Self::Timerfd, Self::WaitsetInterval]
            .into_iter()
            .find(|source| source.name() == s)
            .ok_or_else(|| {
                format!("unknown tick source '{s}' (expected timerfd or waitset-interval)")
            })
    }
}

/// A periodic `timerfd` on `CLOCK_MONOTONIC` whose ticks fall at `origin_ns + k * period`
/// (k ≥ 1), whatever the reader does in between. It becomes readable at each tick; attach it
/// to a WaitSet with `attach_notification` and call [`PeriodicTimer::acknowledge`] on each
/// wake-up (the descriptor stays readable until then).
#[derive(Debug)]
pub struct PeriodicTimer {
    fd: FileDescriptor,
    origin_ns: u64,
    period_ns: u64,
}

impl PeriodicTimer {
    /// A timer whose first tick is one `period` from now.
    pub fn start(period: Duration) -> std::io::Result<Self> {
        let period_ns = period.as_nanos() as u64;
        if period_ns == 0 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "timer period must be positive",
            ));
        }
        // SAFETY: plain syscall; the result is checked.
        let raw = unsafe {
            libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_NONBLOCK | libc::TFD_CLOEXEC,
            )
        };
        let fd = FileDescriptor::new(raw).ok_or_else(std::io::Error::last_os_error)?;
        let origin_ns = crate::monotonic_now_ns();
        let spec = libc::itimerspec {
            it_interval: timespec(period_ns),
            it_value: timespec(origin_ns + period_ns),
        };
        // SAFETY: `raw` is the timerfd just made (owned by `fd`); `spec` is a valid itimerspec.
        let rc = unsafe {
            libc::timerfd_settime(raw, libc::TFD_TIMER_ABSTIME, &spec, std::ptr::null_mut())
        };
        if rc != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(Self {
            fd,
            origin_ns,
            period_ns,
        })
    }

    /// Monotonic time from which the ticks count, ns: tick k falls at `origin + k * period`.
    pub fn origin_ns(&self) -> u64 {
        self.origin_ns
    }

    /// The period, ns.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Consumes the ticks that have passed since the last call and returns their number (0 on a
    /// spurious wake-up; more than 1 when ticks passed while the reader was busy or stopped).
    pub fn acknowledge(&self) -> u64 {
        let mut expirations = 0u64;
        // SAFETY: reads 8 bytes into a u64 from the owned, non-blocking timerfd.
        let n = unsafe {
            libc::read(
                self.fd.native_handle(),
                (&mut expirations as *mut u64).cast(),
                size_of::<u64>(),
            )
        };
        if n == size_of::<u64>() as isize {
            expirations
        } else {
            0
        }
    }
}

impl FileDescriptorBased for PeriodicTimer {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.fd
    }
}

impl SynchronousMultiplexing for PeriodicTimer {}

/// `ns` as a timespec.
fn timespec(ns: u64) -> libc::timespec {
    libc::timespec {
        tv_sec: (ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (ns % 1_000_000_000) as libc::c_long,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_sources_parse_by_name_and_reject_others() {
        for source in [TickSource::Timerfd, TickSource::WaitsetInterval] {
            assert_eq!(source.name().parse::<TickSource>(), Ok(source));
        }
        let error = "epoll".parse::<TickSource>().unwrap_err();
        assert!(
            error.contains("epoll") && error.contains("timerfd"),
            "{error}"
        );
        assert_eq!(TickSource::default(), TickSource::Timerfd);
    }

    #[test]
    fn timer_ticks_fall_on_its_grid_and_count_what_passed() {
        let timer = PeriodicTimer::start(Duration::from_millis(2)).unwrap();
        assert_eq!(timer.period_ns(), 2_000_000);
        // Nothing has expired yet unless this thread was descheduled for a whole period.
        let early = timer.acknowledge();
        std::thread::sleep(Duration::from_millis(11));
        let ticks_by = |now_ns: u64| (now_ns - timer.origin_ns()) / timer.period_ns();
        let before = ticks_by(crate::monotonic_now_ns());
        let passed = timer.acknowledge();
        let after = ticks_by(crate::monotonic_now_ns());
        // Every tick up to the read was counted exactly once: none lost, none invented.
        assert!(
            (before..=after).contains(&(early + passed)),
            "{early} + {passed} ticks counted, {before}..={after} passed"
        );
        // A sleep never ends early, so at least five ticks of the grid had passed at the read,
        // however late this thread ran; the timer fired, and the count was consumed.
        assert!(before >= 5, "{before} ticks of a 2 ms timer in 11 ms");
        assert!(passed > 0, "the timer never fired");
        assert_eq!(timer.acknowledge(), 0);
    }

    #[test]
    fn zero_period_is_rejected() {
        assert!(PeriodicTimer::start(Duration::ZERO).is_err());
    }
}
