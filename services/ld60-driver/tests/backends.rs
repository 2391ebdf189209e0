//! The base loop with its real backends: the LD-60 backend against the fake LD-60 on loopback
//! TCP (stale odometry gives a safe stop), the CAN backend against the fake AgileX base on the
//! in-memory bus (simulated clock) and on a replayed candump log; the config files parse.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use motm_agilex::{FakeBase, FakeBaseConfig, HostConfig, MemoryBus, ReplayBus};
use motm_core::command_limiter::AxisLimits;
use motm_core::velocity_driver::{VelocityDriver, VelocityDriverConfig};
use motm_fake_ld60::{FakeConfig, FakeLd60, spawn_kinematic};
use motm_ld60_driver::arnl::ArnlBase;
use motm_ld60_driver::base::{BaseFault, BaseLoop};
use motm_ld60_driver::can::CanBase;
use motm_ld60_driver::config::BaseConfig;
use motm_omron::ArClient;

const MS: u64 = 1_000_000;

fn config_dir() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../config"))
}

/// Frankie's base limits (v then ω) at 50 Hz, commands at 50 Hz.
fn driver() -> VelocityDriver {
    let axes = vec![
        AxisLimits {
            velocity: 1.2,
            acceleration: 0.8,
            jerk: f64::INFINITY,
        },
        AxisLimits {
            velocity: 1.5,
            acceleration: 2.0,
            jerk: f64::INFINITY,
        },
    ];
    let mut config = VelocityDriverConfig::default();
    config.limiter.command_period = 0.02;
    VelocityDriver::new(axes, 0.02, config).unwrap()
}

fn now_ns(origin: Instant) -> u64 {
    origin.elapsed().as_nanos() as u64 + 1
}

#[test]
fn ld60_drives_within_limits_and_stale_odometry_gives_a_safe_stop() {
    let ld60 = BaseConfig::from_file(&config_dir().join("bases/ld60.toml"))
        .unwrap()
        .arnl
        .unwrap();
    let robot = FakeLd60::start(FakeConfig {
        arnl_addr: SocketAddr::from(([127, 0, 0, 1], 0)),
        arcl_addr: None,
        drive: ld60.drive_limits(),
        stop_updates_after: Some(Duration::from_millis(1500)),
        ..FakeConfig::default()
    })
    .unwrap();
    let physics = spawn_kinematic(&robot, Duration::from_millis(5));
    let client = ArClient::connect(robot.arnl_addr(), &ld60.client()).unwrap();
    let stale_after = Duration::from_millis(300);
    let mut base = BaseLoop::new(
        ArnlBase::new(client, ld60.drive_limits()),
        driver(),
        stale_after,
    );
    let origin = Instant::now();
    let mut moving_at = None;
    let mut fault_at = None;
    let mut stopped_ok = false;
    while origin.elapsed() < Duration::from_millis(2600) {
        let t = now_ns(origin);
        base.receive(t, 0.3, 0.2);
        let out = base.cycle(t, false);
        if moving_at.is_none() && robot.commanded().0 > 0.1 {
            moving_at = Some(origin.elapsed());
        }
        if fault_at.is_none() && out.fault == Some(BaseFault::StaleOdometry) && t > 1_000 * MS {
            fault_at = Some(origin.elapsed());
        }
        if fault_at.is_some() {
            assert!(matches!(out.sent, None | Some((0.0, 0.0))), "{out:?}");
            stopped_ok = robot.commanded() == (0.0, 0.0);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let fake = robot.counters();
    assert!(moving_at.is_some(), "the robot was driven");
    let fault_at = fault_at.expect("stale odometry was detected");
    // Updates stop at 1.5 s; the fault comes after the 0.3 s stale limit.
    assert!(fault_at > Duration::from_millis(1500), "{fault_at:?}");
    assert!(stopped_ok, "the robot is stopped");
    assert!(fake.stops >= 1, "{fake:?}");
    assert!(base.faulted());
    // One safe stop at the start (no odometry yet), one when it went stale.
    assert_eq!(base.counters().safe_stops, 2);
    // Every drive the robot saw was within Frankie's speed and acceleration limits.
    assert_eq!(
        (fake.speed_violations, fake.accel_violations),
        (0, 0),
        "{fake:?}"
    );
    assert!(fake.ratio_drives > 50, "{fake:?}");
    let status = base.status();
    assert_eq!(status.hardware_ready, 0);
    robot.shutdown();
    physics.join().unwrap();
}

#[test]
fn a_dropped_connection_is_a_counted_error_and_a_safe_stop_never_a_command() {
    let robot = FakeLd60::start(FakeConfig {
        arnl_addr: SocketAddr::from(([127, 0, 0, 1], 0)),
        arcl_addr: None,
        ..FakeConfig::default()
    })
    .unwrap();
    let physics = spawn_kinematic(&robot, Duration::from_millis(5));
    let client = ArClient::connect(robot.arnl_addr(), &Default::default()).unwrap();
    let limits = FakeConfig::default().drive;
    let mut base = BaseLoop::new(
        ArnlBase::new(client, limits),
        driver(),
        Duration::from_millis(300),
    );
    let origin = Instant::now();
    while origin.elapsed() < Duration::from_millis(600) {
        let t = now_ns(origin);
        base.receive(t, 0.2, 0.0);
        base.cycle(t, false);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(!base.faulted());
    // A loaded machine may delay the first odometry past the stale limit (a safe stop at
    // start-up, by design): count only what the dropped connection adds.
    let safe_stops_before = base.counters().safe_stops;
    robot.shutdown();
    physics.join().unwrap();
    let mut faults = Vec::new();
    for _ in 0..10 {
        let t = now_ns(origin);
        base.receive(t, 0.2, 0.0);
        faults.push(base.cycle(t, false).fault);
        std::thread::sleep(Duration::from_millis(20));
    }
    // From the first cycle that sees the close on, every cycle is faulted.
    let first = faults.iter().position(Option::is_some).expect("a fault");
    assert!(
        first <= 2 && faults[first..].iter().all(Option::is_some),
        "{faults:?}"
    );
    assert!(base.faulted());
    assert!(base.counters().hardware_errors > 0);
    assert_eq!(base.counters().safe_stops, safe_stops_before + 1);
}

#[test]
fn can_enable_then_50_hz_commands_then_silence_stops_the_base() {
    let (host_end, base_end) = MemoryBus::pair();
    let mut fake = FakeBase::new(base_end, FakeBaseConfig::default());
    let mut base = BaseLoop::new(
        CanBase::new(host_end, HostConfig::default()).unwrap(),
        driver(),
        Duration::from_millis(200),
    );
    // The driver at 50 Hz, the fake base stepped every 10 ms, on a simulated clock.
    let mut last = None;
    for k in 0..150u64 {
        let t = k * 20 * MS + MS;
        fake.step(t).unwrap();
        base.receive(t, 0.4, -0.3);
        last = Some(base.cycle(t, false));
        fake.step(t + 10 * MS).unwrap();
    }
    let last = last.unwrap();
    assert_eq!(last.fault, None);
    assert_eq!(last.sent, Some((0.4, -0.3)));
    let s = last.state.expect("feedback decoded");
    assert!(
        (s.v - 0.4).abs() < 1e-9 && (s.omega + 0.3).abs() < 1e-9,
        "{s:?}"
    );
    assert!(s.x > 0.5 && s.yaw < -0.3, "{s:?}");
    assert_eq!(fake.counters().commands_accepted, 150);
    assert_eq!(fake.counters().limit_violations, 0);
    // The driver process stops: no more 0x111. The base stops on its own after 500 ms.
    let t0 = 150 * 20 * MS;
    for k in 0..48u64 {
        fake.step(t0 + k * 10 * MS).unwrap();
    }
    assert!(fake.velocity().0 > 0.39, "still driving at 470 ms");
    for k in 48..100u64 {
        fake.step(t0 + k * 10 * MS).unwrap();
    }
    assert_eq!(fake.velocity(), (0.0, 0.0));
    assert_eq!(fake.counters().command_timeouts, 1);
}

#[test]
fn a_candump_log_replayed_into_the_can_driver_gives_the_expected_odometry() {
    let log = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/agilex/tests/data/scout_turn.log"
    );
    let reader = socketcan::dump::Reader::from_file(log).unwrap();
    let mut base = BaseLoop::new(
        CanBase::new(ReplayBus::new(reader), HostConfig::default()).unwrap(),
        driver(),
        Duration::from_millis(200),
    );
    let mut t_ms = 0;
    let mut states = Vec::new();
    while !base.hardware().host().bus().finished() {
        base.hardware_mut()
            .host_mut()
            .bus_mut()
            .set_time_us(t_ms * 1000);
        if let Some(s) = base.cycle(t_ms * MS + 1, false).state {
            states.push(s);
        }
        t_ms += 20;
    }
    // Two motion states in the log; the pose at the last one is the whole log's.
    assert_eq!(states.len(), 2);
    let s = states[1];
    let yaw = 0.910 / 0.58;
    assert!((s.yaw - yaw).abs() < 1e-9, "{s:?}");
    assert!((s.x - (1.0 + 0.5 * yaw.cos())).abs() < 1e-9, "{s:?}");
    assert!((s.y - 0.5 * yaw.sin()).abs() < 1e-9, "{s:?}");
    // The driver wrote 0x421 first, then zero commands only (the log's feedback is stale
    // most of the time, so it is held stopped).
    let sent = &base.hardware().host().bus().sent;
    assert_eq!(sent[0].candump(), "421#0100000000000000");
    assert!(
        sent.iter()
            .skip(1)
            .all(|f| f.candump() == "111#0000000000000000")
    );
}

#[test]
fn the_base_configs_and_the_arnl_stack_parse() {
    let ld60 = BaseConfig::from_file(&config_dir().join("bases/ld60.toml")).unwrap();
    let a = ld60.arnl.unwrap();
    assert_eq!((a.port, a.arcl_port), (7272, 7171));
    assert_eq!(a.drive_limits().trans_vel_max, 1.8);
    assert!(ld60.can.is_none());
    let scout = BaseConfig::from_file(&config_dir().join("bases/scout.toml")).unwrap();
    assert_eq!(scout.can.unwrap().interface, "can0");
    let err = BaseConfig::parse(
        "[can]\ninterface = \"can0\"\ntrack_width = -1\nfeedback_timeout_ms = 1\n",
    )
    .unwrap_err();
    assert!(err.contains("track_width"), "{err}");
    assert!(BaseConfig::parse("[arnl]\nport = 1\n").is_err());
    let stack =
        motm_supervisor::StackConfig::from_file(&config_dir().join("frankie_arnl.toml")).unwrap();
    let names: Vec<&str> = stack.processes.iter().map(|p| p.name.as_str()).collect();
    let fake = names.iter().position(|n| *n == "fake-ld60").unwrap();
    let driver = names.iter().position(|n| *n == "ld60-driver").unwrap();
    assert!(
        fake < driver,
        "the fake robot starts before the driver: {names:?}"
    );
    let args = &stack.processes[driver].args;
    assert!(
        args.windows(2).any(|w| w == ["--backend", "arnl"]),
        "{args:?}"
    );
}
