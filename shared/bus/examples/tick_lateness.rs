//! Wake-up lateness of a periodic loop: how long after its tick each cycle starts.
//!
//! ```text
//! cargo run --release -p motm-bus --example tick_lateness -- \
//!     [--rate 1000] [--seconds 10] [--step-us 100] [--slack-ns N] [SOURCE...]
//! ```
//!
//! SOURCE is `timerfd` or `waitset-interval` (a [`ServiceLoop`] with that [`TickSource`]) or
//! `nanosleep` (a bare `clock_nanosleep(TIMER_ABSTIME)` loop on the same grid, for reference;
//! it cannot wait for data). Default: all three, one after another. Each cycle busy-waits
//! `--step-us` to stand in for a control step. `--slack-ns` sets the thread's timer slack
//! (`PR_SET_TIMERSLACK`) first. Reports, per source: cycles, lost ticks (ticks with no cycle),
//! deadline misses (the service loop's rule; not counted for `nanosleep`) and the lateness
//! median / p99 / max. Compare sources under the same load (`nice -n -20` on a busy machine).

use std::time::Duration;

use motm_bus::{
    Bus, Flow, IpcConfig, LoopConfig, ServiceLoop, TickSource, monotonic_now_ns, percentile,
    remove_domain,
};

/// Command-line options.
struct Options {
    rate_hz: f64,
    seconds: f64,
    step_us: u64,
    slack_ns: Option<u64>,
    sources: Vec<String>,
}

fn parse() -> Result<Options, String> {
    let mut options = Options {
        rate_hz: 1000.0,
        seconds: 10.0,
        step_us: 100,
        slack_ns: None,
        sources: Vec::new(),
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = |name: &str| {
            args.next()
                .ok_or_else(|| format!("{name} needs a value"))
                .and_then(|v| v.parse::<f64>().map_err(|e| format!("{name} {v}: {e}")))
        };
        match arg.as_str() {
            "--rate" => options.rate_hz = value("--rate")?,
            "--seconds" => options.seconds = value("--seconds")?,
            "--step-us" => options.step_us = value("--step-us")? as u64,
            "--slack-ns" => options.slack_ns = Some(value("--slack-ns")? as u64),
            "timerfd" | "waitset-interval" | "nanosleep" => options.sources.push(arg),
            other => return Err(format!("unknown argument '{other}'")),
        }
    }
    if !(options.rate_hz > 0.0 && options.seconds > 0.0) {
        return Err("--rate and --seconds must be positive".into());
    }
    if options.sources.is_empty() {
        options.sources = vec![
            "waitset-interval".into(),
            "timerfd".into(),
            "nanosleep".into(),
        ];
    }
    Ok(options)
}

/// What one source did.
struct Run {
    cycles: u64,
    lost_ticks: u64,
    deadline_misses: Option<u64>,
    lateness_ns: Vec<u64>,
}

/// Busy-waits `us` microseconds from `from_ns`.
fn spin(from_ns: u64, us: u64) {
    while monotonic_now_ns() < from_ns + us * 1000 {
        std::hint::spin_loop();
    }
}

fn run_service_loop(source: TickSource, options: &Options) -> Result<Run, String> {
    let ipc = IpcConfig {
        prefix: format!("motmb{}_tick_", std::process::id()),
    };
    let e = |e: motm_bus::BusError| e.to_string();
    let cycles = (options.seconds * options.rate_hz) as u64;
    let mut lateness_ns = Vec::with_capacity(cycles as usize);
    let mut ticks = (0, 0); // (first tick, last tick) seen
    let (done, misses) = {
        let bus = Bus::open_with("tick-lateness", &ipc).map_err(e)?;
        let config = LoopConfig {
            tick_source: source,
            ..LoopConfig::with_rate(options.rate_hz)
        };
        let mut service = ServiceLoop::new(&bus, config).map_err(e)?;
        service
            .run_periodic(|cycle| {
                let tick = cycle.tick_ns.expect("a periodic loop has ticks");
                lateness_ns.push(cycle.now_ns - tick);
                if cycle.cycle == 0 {
                    ticks.0 = tick;
                }
                ticks.1 = tick;
                spin(cycle.now_ns, options.step_us);
                if cycle.cycle + 1 >= cycles {
                    Flow::Stop
                } else {
                    Flow::Continue
                }
            })
            .map_err(e)?;
        let stats = service.stats();
        (stats.cycles(), stats.deadline_misses())
    };
    // SAFETY: the bus is dropped and no other process uses this prefix.
    unsafe { remove_domain(&ipc) }.map_err(|e| e.to_string())?;
    let period_ns = (1e9 / options.rate_hz) as u64;
    Ok(Run {
        cycles: done,
        lost_ticks: ((ticks.1 - ticks.0) / period_ns + 1).saturating_sub(done),
        deadline_misses: Some(misses),
        lateness_ns,
    })
}

fn run_nanosleep(options: &Options) -> Run {
    let period_ns = (1e9 / options.rate_hz) as u64;
    let cycles = (options.seconds * options.rate_hz) as u64;
    let origin = monotonic_now_ns();
    let mut lateness_ns = Vec::with_capacity(cycles as usize);
    let mut next = 1;
    let mut lost_ticks = 0;
    for _ in 0..cycles {
        let tick = origin + next * period_ns;
        let ts = libc::timespec {
            tv_sec: (tick / 1_000_000_000) as libc::time_t,
            tv_nsec: (tick % 1_000_000_000) as libc::c_long,
        };
        // SAFETY: a valid absolute timespec; an interrupted sleep just wakes early (re-checked).
        unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        let wake = monotonic_now_ns();
        lateness_ns.push(wake.saturating_sub(tick));
        spin(wake, options.step_us);
        // Like a coalescing timer: the next cycle is at the first tick after this one ends.
        let after = (monotonic_now_ns() - origin) / period_ns + 1;
        lost_ticks += after - next - 1;
        next = after;
    }
    Run {
        cycles,
        lost_ticks,
        deadline_misses: None,
        lateness_ns,
    }
}

fn main() {
    let options = match parse() {
        Ok(options) => options,
        Err(message) => {
            eprintln!("tick_lateness: {message}");
            std::process::exit(2);
        }
    };
    if let Some(slack) = options.slack_ns {
        // SAFETY: plain prctl on this thread; the result is checked.
        if unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, slack as libc::c_ulong) } != 0 {
            eprintln!("tick_lateness: PR_SET_TIMERSLACK failed");
            std::process::exit(1);
        }
    }
    println!(
        "{} Hz, {} s, step {} us, timer slack {} ns",
        options.rate_hz,
        options.seconds,
        options.step_us,
        std::fs::read_to_string("/proc/self/timerslack_ns")
            .unwrap_or_default()
            .trim()
    );
    println!(
        "{:<17} {:>7} {:>6} {:>7} {:>10} {:>10} {:>10}",
        "source", "cycles", "lost", "misses", "late p50", "late p99", "late max"
    );
    for name in &options.sources {
        let run = match name.as_str() {
            "nanosleep" => Ok(run_nanosleep(&options)),
            source => run_service_loop(source.parse().expect("a known source"), &options),
        };
        let mut run = match run {
            Ok(run) => run,
            Err(message) => {
                eprintln!("tick_lateness: {name}: {message}");
                std::process::exit(1);
            }
        };
        let mut us = |p: f64| percentile(&mut run.lateness_ns, p) as f64 / 1e3;
        println!(
            "{:<17} {:>7} {:>6} {:>7} {:>8.1}us {:>8.1}us {:>8.1}us",
            name,
            run.cycles,
            run.lost_ticks,
            run.deadline_misses
                .map_or("-".to_string(), |m| m.to_string()),
            us(50.0),
            us(99.0),
            us(100.0),
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}
