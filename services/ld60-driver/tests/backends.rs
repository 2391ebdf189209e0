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
        1,
        stale_after,
    );
    let origin = Instant::now();
    let mut moving_at = None;
    let mut fault_at = None;
    let mut stopped_ok = false;
    let mut first_cycle = None;
    while origin.elapsed() < Duration::from_millis(2600) {
        let t = now_ns(origin);
        base.receive(t, 0.3, 0.2);
        let out = base.cycle(t, false);
        first_cycle.get_or_insert_with(|| out.clone());
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
    // One safe stop at the start when the first cycle had no odometry yet (the fake answers
    // the updateNumbers request at once, so on a loaded machine it may already be there), and
    // one when it went stale.
    let first = first_cycle.unwrap();
    let at_start = u64::from(first.state.is_none());
    assert_eq!(
        first.fault.is_some(),
        first.state.is_none(),
        "a safe stop at the start exactly without odometry: {first:?}"
    );
    assert_eq!(base.counters().safe_stops, at_start + 1);
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
        1,
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
        1,
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
        1,
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

#[test]
fn a_dropped_arnetworking_connection_is_made_again_and_driving_resumes_from_rest() {
    let ld60 = BaseConfig::from_file(&config_dir().join("bases/ld60.toml"))
        .unwrap()
        .arnl
        .unwrap();
    let fake_config = FakeConfig {
        arnl_addr: SocketAddr::from(([127, 0, 0, 1], 0)),
        arcl_addr: None,
        drive: ld60.drive_limits(),
        update_period: Duration::from_millis(20),
        ..FakeConfig::default()
    };
    let first = FakeLd60::start(fake_config.clone()).unwrap();
    let addr = first.arnl_addr();
    let physics = spawn_kinematic(&first, Duration::from_millis(5));
    let mut client = ld60.client();
    client.update_interval_ms = 20;
    let hardware = ArnlBase::connect(addr, client, ld60.drive_limits()).unwrap();
    let mut base = BaseLoop::new(hardware, driver(), 1, Duration::from_millis(300));
    let origin = Instant::now();
    let cycle = |base: &mut BaseLoop<ArnlBase>| {
        let t = now_ns(origin);
        base.receive(t, 0.2, 0.0);
        let out = base.cycle(t, false);
        std::thread::sleep(Duration::from_millis(20));
        out
    };
    let mut moved = false;
    for _ in 0..40 {
        cycle(&mut base);
        moved |= first.commanded().0 > 0.1;
    }
    assert!(moved && !base.faulted(), "{:?}", base.counters());
    let errors_before = base.counters().hardware_errors;
    first.shutdown();
    physics.join().unwrap();
    // The robot is gone: once the close is seen (within two cycles), every cycle is faulted
    // and nothing is sent; the base reconnects (in vain) at most every RECONNECT_EVERY.
    let outs: Vec<_> = (0..10).map(|_| cycle(&mut base)).collect();
    assert!(
        outs[2..]
            .iter()
            .all(|o| o.sent.is_none() && o.fault.is_some()),
        "{outs:?}"
    );
    assert!(base.faulted() && !base.hardware().connected());
    assert!(base.counters().hardware_errors > errors_before);
    // The robot is back on the same address: the driver connects again with the whole
    // handshake and, once odometry flows, drives from rest.
    let second = FakeLd60::start(FakeConfig {
        arnl_addr: addr,
        ..fake_config
    })
    .unwrap();
    let physics = spawn_kinematic(&second, Duration::from_millis(5));
    let mut resumed = None;
    let mut first_drive = None;
    for i in 0..150 {
        let out = cycle(&mut base);
        if base.hardware().connected() && !base.faulted() && resumed.is_none() {
            resumed = Some(i);
        }
        if first_drive.is_none()
            && let Some((v, _)) = out.sent
            && v > 0.0
        {
            first_drive = Some(v);
        }
        if resumed.is_some() && second.commanded().0 > 0.1 {
            break;
        }
    }
    assert!(resumed.is_some(), "never resumed: {:?}", base.counters());
    assert_eq!(base.hardware().reconnects, 1);
    let fake = second.counters();
    assert_eq!(fake.clients, 1, "{fake:?}");
    assert!(second.commanded().0 > 0.1, "driving resumed: {fake:?}");
    // From rest: the first drive after the reconnection is one acceleration step (0.8 m/s² at
    // 50 Hz), and the fake robot saw no drive beyond its limits.
    assert!(first_drive.unwrap() <= 0.8 * 0.02 + 1e-9, "{first_drive:?}");
    assert_eq!(
        (fake.speed_violations, fake.accel_violations),
        (0, 0),
        "{fake:?}"
    );
    second.shutdown();
    physics.join().unwrap();
}

#[test]
fn a_can_interface_that_cannot_be_opened_is_named_and_nothing_runs() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_ld60-driver"))
        .args(["--backend", "can", "--can-interface", "motmnosuch0"])
        .env("MOTM_IPC_PREFIX", format!("motmcan{}_", std::process::id()))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--can-interface motmnosuch0: cannot open the CAN socket"),
        "{stderr}"
    );
    // No such interface is bad input (2); a kernel without CAN sockets is a failure (1).
    let expected = if stderr.contains("AF_CAN") { 1 } else { 2 };
    assert_eq!(out.status.code(), Some(expected), "{stderr}");
    // It stopped before the bus: no driver status line, no loop.
    assert!(!stderr.contains("stopped;"), "{stderr}");
}
