//! The host side against the fake base on the in-memory bus, on a simulated clock (no wall
//! clock), and a `candump -L` log replayed into the host.

use motm_agilex::bus::{CanBus, ReplayBus};
use motm_agilex::protocol::ControlMode;
use motm_agilex::{
    AgilexHost, FakeBase, FakeBaseConfig, HostConfig, HostFault, LoggingBus, MemoryBus,
};
use socketcan::dump::Reader;

const MS: u64 = 1_000_000;

/// Steps the fake every 10 ms and the host every 20 ms (50 Hz) from `from` to `to` (ms),
/// commanding `command(t)` while it gives `Some`.
fn run<B: CanBus, H: CanBus>(
    base: &mut FakeBase<B>,
    host: &mut AgilexHost<H>,
    from: u64,
    to: u64,
    command: impl Fn(u64) -> Option<(f64, f64)>,
) {
    let mut t = from;
    while t < to {
        if t.is_multiple_of(20) {
            host.poll(t * MS).unwrap();
            if let Some((v, w)) = command(t) {
                host.command(v, w).unwrap();
            }
        }
        base.step(t * MS).unwrap();
        t += 10;
    }
    host.poll(to * MS).unwrap();
}

#[test]
fn enable_then_commands_at_50_hz_give_decoded_feedback_and_silence_stops_the_base() {
    let (host_end, base_end) = MemoryBus::pair();
    let mut base = FakeBase::new(base_end, FakeBaseConfig::default());
    let mut host = AgilexHost::new(host_end, HostConfig::default());
    // Standby: commands are ignored until 0x421.
    run(&mut base, &mut host, 0, 200, |_| Some((0.3, 0.0)));
    assert_eq!(base.mode(), ControlMode::Standby);
    assert_eq!(base.velocity(), (0.0, 0.0));
    assert_eq!(base.counters().commands_accepted, 0);
    assert!(base.counters().commands_ignored >= 9);
    assert_eq!(
        host.fault(200 * MS),
        Some(HostFault::NotCanMode(ControlMode::Standby))
    );
    host.enable().unwrap();
    run(&mut base, &mut host, 200, 2200, |_| Some((0.3, 0.2)));
    assert_eq!(base.mode(), ControlMode::Can);
    assert_eq!(host.fault(2200 * MS), None);
    let o = host.odometry();
    assert!(
        (o.v - 0.3).abs() < 1e-9 && (o.omega - 0.2).abs() < 1e-9,
        "{o:?}"
    );
    // About 1.8 s at 0.3 m/s after the ramp: the pose comes from the wheel odometry.
    let travelled = o.x.hypot(o.y);
    assert!((0.5..0.6).contains(&travelled), "{o:?}");
    assert!(o.yaw > 0.3, "{o:?}");
    let accepted = base.counters().commands_accepted;
    assert_eq!(accepted, 100, "50 Hz for 2 s");
    // Silence: the base keeps going until 500 ms after the last command, then stops.
    run(&mut base, &mut host, 2200, 2680, |_| None);
    assert!(base.velocity().0 > 0.29, "still moving before the timeout");
    run(&mut base, &mut host, 2680, 3200, |_| None);
    assert_eq!(base.velocity(), (0.0, 0.0));
    assert_eq!(base.counters().command_timeouts, 1);
    assert_eq!(host.odometry().v, 0.0);
    // And the host sees stale feedback once the base is gone.
    assert_eq!(host.fault(3500 * MS), Some(HostFault::NoFeedback));
}

#[test]
fn an_estop_is_reported_and_stops_the_base() {
    let (host_end, base_end) = MemoryBus::pair();
    let mut base = FakeBase::new(base_end, FakeBaseConfig::default());
    let mut host = AgilexHost::new(host_end, HostConfig::default());
    host.enable().unwrap();
    run(&mut base, &mut host, 0, 1000, |_| Some((0.5, 0.0)));
    base.set_estop(true);
    run(&mut base, &mut host, 1000, 1200, |_| Some((0.5, 0.0)));
    assert_eq!(host.fault(1200 * MS), Some(HostFault::EStop));
    assert_eq!(base.velocity(), (0.0, 0.0));
    assert!(base.counters().commands_ignored > 0);
}

#[test]
fn a_candump_log_replayed_into_the_host_gives_the_expected_odometry() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/scout_turn.log");
    let mut host = AgilexHost::new(
        ReplayBus::new(Reader::from_file(path).unwrap()),
        HostConfig::default(),
    );
    // Replay at 50 Hz on the log's clock.
    let mut t_ms = 0;
    while !host.bus().finished() {
        host.bus_mut().set_time_us(t_ms * 1000);
        host.poll(t_ms * MS).unwrap();
        if t_ms == 1010 {
            let o = host.odometry();
            assert!(
                (o.x - 1.0).abs() < 1e-12 && o.y == 0.0 && o.yaw == 0.0,
                "{o:?}"
            );
            assert!((o.v - 0.5).abs() < 1e-12);
        }
        t_ms += 20;
    }
    // 1 m straight, then a turn on the spot (±455 mm on a 0.58 m track), then 0.5 m.
    let yaw = 0.910 / 0.58;
    let o = host.odometry();
    assert!((o.yaw - yaw).abs() < 1e-9, "{o:?}");
    assert!((o.x - (1.0 + 0.5 * yaw.cos())).abs() < 1e-9, "{o:?}");
    assert!((o.y - 0.5 * yaw.sin()).abs() < 1e-9, "{o:?}");
    assert_eq!(o.v, 0.0);
    let c = host.counters();
    // 0x421, 0x111 (host frames) and 0x251 (actuator) are not feedback.
    assert_eq!(
        (c.feedback_frames, c.ignored_frames, c.bad_frames),
        (7, 3, 0)
    );
}

#[test]
fn the_driver_traffic_written_as_candump_replays_to_the_same_odometry() {
    let (host_end, base_end) = MemoryBus::pair();
    let mut base = FakeBase::new(base_end, FakeBaseConfig::default());
    let mut clock_us = 1_700_000_000_000_000u64;
    let shared = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(clock_us));
    let reader = shared.clone();
    let logged = LoggingBus::with_clock(host_end, Vec::new(), "can0", move || {
        reader.load(std::sync::atomic::Ordering::Relaxed)
    });
    let mut host = AgilexHost::new(logged, HostConfig::default());
    host.enable().unwrap();
    let mut t: u64 = 0;
    while t < 1500 {
        shared.store(clock_us, std::sync::atomic::Ordering::Relaxed);
        if t.is_multiple_of(20) {
            host.poll(t * MS).unwrap();
            host.command(0.4, if t < 700 { 0.0 } else { 0.5 }).unwrap();
        }
        base.step(t * MS).unwrap();
        t += 10;
        clock_us += 10_000;
    }
    shared.store(clock_us, std::sync::atomic::Ordering::Relaxed);
    host.poll(t * MS).unwrap();
    let live = host.odometry();
    let sent = host.counters().commands_sent;
    let log = host.bus().writer().clone();
    let mut replayed = AgilexHost::new(
        ReplayBus::new(Reader::from_reader(log.as_slice())),
        HostConfig::default(),
    );
    replayed.poll(0).unwrap();
    assert_eq!(replayed.odometry(), live);
    let host_frames = replayed.counters().ignored_frames;
    assert_eq!(
        host_frames,
        sent + 1,
        "the commands and the 0x421 are in the log"
    );
    assert!(live.x > 0.3 && live.yaw > 0.2, "{live:?}");
}
