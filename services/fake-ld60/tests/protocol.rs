//! The LD-60 clients (`motm-omron`) against the fake robot's servers, in-process on real
//! loopback TCP; and the client against a raw server that sends bad input.

use std::io::Write;
use std::net::{SocketAddr, TcpListener};
use std::time::{Duration, Instant};

use motm_fake_ld60::{FakeConfig, FakeLd60, data_number, spawn_kinematic};
use motm_omron::packet::Packet;
use motm_omron::protocol::{ListEntry, RejectReason, ServerIntroduction, list_packet, server};
use motm_omron::{
    ArClient, ArclClient, ArclError, ArclLine, ClientConfig, ClientError, Event, Odometry,
    RatioDrive,
};

fn loopback() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 0))
}

fn fake(config: FakeConfig) -> FakeLd60 {
    FakeLd60::start(FakeConfig {
        arnl_addr: loopback(),
        arcl_addr: Some(loopback()),
        ..config
    })
    .unwrap()
}

/// Polls until an odometry update arrives (at most `within`).
fn next_numbers(c: &mut ArClient, within: Duration) -> Option<Odometry> {
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        if let Some(Event::Numbers(u)) = c.poll(Duration::from_millis(20)).unwrap() {
            return Some(u.odometry());
        }
    }
    None
}

#[test]
fn handshake_maps_the_data_and_drives_reach_the_robot() {
    let robot = fake(FakeConfig::default());
    robot.set_odometry(Odometry {
        x: 1.5,
        y: -0.25,
        yaw: 0.5,
        v: 0.0,
        omega: 0.0,
        lateral: 0.0,
        battery_v: 26.1,
        temperature_c: Some(31),
    });
    let mut c = ArClient::connect(robot.arnl_addr(), &ClientConfig::default()).unwrap();
    assert_eq!(c.server_introduction().greeting, "alpha");
    assert_eq!(c.data_map().number("ratioDrive"), data_number("ratioDrive"));
    assert_eq!(c.data_map().number("ratioDrive"), Some(260));
    let o = next_numbers(&mut c, Duration::from_secs(2)).expect("updateNumbers");
    assert!((o.x - 1.5).abs() < 1e-9 && (o.y + 0.25).abs() < 1e-9);
    // 1° resolution on the wire.
    assert!((o.yaw - 29f64.to_radians()).abs() < 1e-9, "{o:?}");
    assert_eq!(o.temperature_c, Some(31));
    // 50 % of transVelMax 1.8 is 0.9 m/s.
    c.ratio_drive(&RatioDrive {
        trans: 50.0,
        ..RatioDrive::ZERO
    })
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(2);
    while robot.commanded().0 == 0.0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    let (v, w) = robot.commanded();
    assert!((v - 0.9).abs() < 1e-9 && w == 0.0, "{v} {w}");
    c.stop().unwrap();
    let deadline = Instant::now() + Duration::from_secs(2);
    while robot.counters().stops == 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(robot.commanded(), (0.0, 0.0));
    let counters = robot.counters();
    assert_eq!(
        (counters.clients, counters.ratio_drives, counters.stops),
        (1, 1, 1)
    );
    // 0.9 m/s from rest in one packet is beyond the 0.8 m/s² limit; within the speed limit.
    assert_eq!(
        (counters.speed_violations, counters.accel_violations),
        (0, 1)
    );
}

#[test]
fn a_wrong_password_is_rejected() {
    let robot = fake(FakeConfig {
        password: "secret".into(),
        ..FakeConfig::default()
    });
    let err = ArClient::connect(robot.arnl_addr(), &ClientConfig::default()).unwrap_err();
    assert!(
        matches!(
            err,
            ClientError::Rejected {
                reason: RejectReason::BadUserPassword,
                ..
            }
        ),
        "{err}"
    );
    let ok = ClientConfig {
        password: "secret".into(),
        ..ClientConfig::default()
    };
    ArClient::connect(robot.arnl_addr(), &ok).unwrap();
    assert_eq!(robot.counters().rejected, 1);
}

#[test]
fn the_robot_stops_when_drives_stop_coming_and_counts_speeding() {
    let robot = fake(FakeConfig {
        drive_timeout: Duration::from_millis(300),
        ..FakeConfig::default()
    });
    let mut c = ArClient::connect(robot.arnl_addr(), &ClientConfig::default()).unwrap();
    let physics = spawn_kinematic(&robot, Duration::from_millis(5));
    // 100 % is 1.8 m/s, beyond Frankie's 1.2 m/s.
    c.ratio_drive(&RatioDrive {
        trans: 100.0,
        ..RatioDrive::ZERO
    })
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(2);
    while robot.commanded().0 == 0.0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(robot.commanded().0 > 1.0);
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        robot.commanded(),
        (0.0, 0.0),
        "stopped after the drive timeout"
    );
    let counters = robot.counters();
    assert_eq!((counters.drive_timeouts, counters.speed_violations), (1, 1));
    assert!(robot.odometry().x > 0.0, "the kinematic physics moved");
    robot.shutdown();
    physics.join().unwrap();
}

#[test]
fn update_numbers_stop_after_the_configured_time() {
    let robot = fake(FakeConfig {
        stop_updates_after: Some(Duration::from_millis(400)),
        ..FakeConfig::default()
    });
    let mut c = ArClient::connect(robot.arnl_addr(), &ClientConfig::default()).unwrap();
    assert!(next_numbers(&mut c, Duration::from_secs(1)).is_some());
    std::thread::sleep(Duration::from_millis(500));
    while c.poll(Duration::ZERO).unwrap().is_some() {}
    assert!(next_numbers(&mut c, Duration::from_millis(500)).is_none());
    let sent = robot.counters().updates_sent;
    assert!((2..=6).contains(&sent), "{sent} updates in 0.4 s at 10 Hz");
}

/// A server that completes the handshake, then sends `bad` and closes.
fn raw_server(bad: Vec<Vec<u8>>) -> SocketAddr {
    let listener = TcpListener::bind(loopback()).unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let intro = ServerIntroduction {
            greeting: "alpha".into(),
            udp_port: 0,
            auth_key: 0,
            intro_key: 0,
            password_key: String::new(),
            protocol_version: "5MTX".into(),
        };
        let entries: Vec<ListEntry> = ["updateNumbers", "ratioDrive", "stop"]
            .iter()
            .enumerate()
            .map(|(i, n)| ListEntry {
                command: 256 + i as u16,
                first: (*n).into(),
                second: String::new(),
            })
            .collect();
        let mut out = intro.to_packet().encode().unwrap();
        for p in [
            Packet::empty(server::CONNECTED),
            list_packet(server::LIST, &entries),
            list_packet(server::LISTARGRET, &entries),
            list_packet(server::LISTGROUPANDFLAGS, &entries),
        ] {
            out.extend(p.encode().unwrap());
        }
        s.write_all(&out).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        for b in bad {
            s.write_all(&b).unwrap();
        }
        std::thread::sleep(Duration::from_millis(50));
    });
    addr
}

#[test]
fn bad_input_from_the_server_is_a_typed_counted_error() {
    let good = Packet::new(256, vec![0; 19]).encode().unwrap();
    let mut bad_sum = good.clone();
    let n = bad_sum.len();
    bad_sum[n - 1] ^= 0x55;
    let unknown = Packet::empty(999).encode().unwrap();
    let short_numbers = Packet::new(256, vec![0; 5]).encode().unwrap();
    let truncated = good[..10].to_vec();
    let addr = raw_server(vec![
        bad_sum,
        good.clone(),
        unknown,
        short_numbers,
        b"\x01\x02".to_vec(),
        good,
        truncated,
    ]);
    let mut c = ArClient::connect(addr, &ClientConfig::default()).unwrap();
    let mut results = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(3);
    while Instant::now() < deadline {
        match c.poll(Duration::from_millis(20)) {
            Ok(None) => {}
            Ok(Some(e)) => results.push(Ok(e)),
            Err(ClientError::Closed) => break,
            Err(e) => results.push(Err(e.to_string())),
        }
    }
    let kinds: Vec<String> = results
        .iter()
        .map(|r| match r {
            Ok(Event::Numbers(_)) => "numbers".to_owned(),
            Ok(other) => format!("{other:?}"),
            Err(e) => e.clone(),
        })
        .collect();
    assert_eq!(kinds.len(), 7, "{kinds:?}");
    assert!(kinds[0].contains("bad checksum"), "{kinds:?}");
    assert_eq!(kinds[1], "numbers");
    assert!(kinds[2].contains("unknown command number 999"), "{kinds:?}");
    assert!(kinds[3].contains("payload too short"), "{kinds:?}");
    assert!(kinds[4].contains("bad sync"), "{kinds:?}");
    assert_eq!(kinds[5], "numbers");
    assert!(kinds[6].contains("truncated"), "{kinds:?}");
    let counters = c.counters();
    assert_eq!(counters.odometry_updates, 2);
    assert_eq!(counters.unknown_commands, 1);
    assert_eq!(counters.bad_packets, 4);
    assert!(matches!(c.poll(Duration::ZERO), Err(ClientError::Closed)));
}

#[test]
fn arcl_login_status_and_estop_lines() {
    let robot = fake(FakeConfig::default());
    let addr = robot.arcl_addr().unwrap();
    let err = ArclClient::connect(addr, "wrong", Duration::from_secs(2)).unwrap_err();
    assert!(
        matches!(err, ArclError::Closed | ArclError::Login(_)),
        "{err}"
    );
    let mut arcl = ArclClient::connect(addr, "adept", Duration::from_secs(2)).unwrap();
    robot.set_odometry(Odometry {
        x: 2.0,
        y: 1.0,
        yaw: std::f64::consts::FRAC_PI_2,
        v: 0.0,
        omega: 0.0,
        lateral: 0.0,
        battery_v: 25.5,
        temperature_c: None,
    });
    let s = arcl.status(Duration::from_secs(2)).unwrap();
    assert_eq!(s.status.as_deref(), Some("Stopped"));
    assert_eq!(s.location, Some((2000.0, 1000.0, 90.0)));
    assert_eq!(s.battery_voltage, Some(25.5));
    let one = arcl.one_line_status(Duration::from_secs(2)).unwrap();
    assert_eq!(one, s);
    robot.set_estop(true);
    let mut seen = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(2);
    while seen.len() < 2 && Instant::now() < deadline {
        if let Some(l) = arcl.next_line(Duration::from_millis(20)).unwrap() {
            seen.push(l);
            robot.set_estop(false);
        }
    }
    assert_eq!(seen, vec![ArclLine::EStopPressed, ArclLine::EStopRelieved]);
    arcl.send("frobnicate").unwrap();
    let l = arcl.next_line(Duration::from_secs(2)).unwrap();
    assert_eq!(l, Some(ArclLine::UnknownCommand("frobnicate".into())));
}
