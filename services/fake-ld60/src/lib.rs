//! A fake Omron LD-60 that speaks the real protocols on loopback TCP: an ArNetworking server
//! (handshake, LIST, `ratioDrive`, `stop`, `updateNumbers` broadcasts) and an ARCL server
//! (login, `status`, `oneLineStatus`, `stop`, e-stop lines). Its physics is not here: whoever
//! runs it reads [`FakeLd60::commanded`] and writes [`FakeLd60::set_odometry`] (the
//! `fake-ld60` process, [`service`], bridges to sim-world; [`spawn_kinematic`] integrates a
//! unicycle for tests and standalone runs).
//!
//! Like the robot: a `ratioDrive` holds for [`FakeConfig::drive_timeout`] (2 s, the server's
//! "Timeout" setting), then the robot stops; `stop` stops it at once; while the e-stop is
//! pressed it stops and ignores drives. It counts what it saw, including commands beyond the
//! robot's speed and acceleration limits ([`FakeCounters`]). For the stale-odometry fault test
//! it can stop sending `updateNumbers` after [`FakeConfig::stop_updates_after`].

pub mod service;

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use motm_omron::arcl::{ArclStatus, END_OF_COMMANDS, PASSWORD_PROMPT};
use motm_omron::packet::{Packet, PayloadReader};
use motm_omron::protocol::{
    ClientIntroduction, FIRST_DATA_NUMBER, ListEntry, RejectReason, ServerIntroduction, client,
    list_packet, password_hash, server,
};
use motm_omron::{DriveLimits, Odometry, RatioDrive, UpdateNumbers};

/// The robot's own limits (from `config/robots/<robot>.toml`'s base joints), for counting
/// violations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotLimits {
    /// Largest |v|, m/s.
    pub v: f64,
    /// Largest |ω|, rad/s.
    pub omega: f64,
    /// Largest |dv/dt|, m/s².
    pub accel_v: f64,
    /// Largest |dω/dt|, rad/s².
    pub accel_omega: f64,
}

/// Settings of the fake robot.
#[derive(Debug, Clone, PartialEq)]
pub struct FakeConfig {
    /// ArNetworking listen address (port 0: any free port).
    pub arnl_addr: SocketAddr,
    /// ARCL listen address, if ARCL is served.
    pub arcl_addr: Option<SocketAddr>,
    /// ArNetworking user.
    pub user: String,
    /// ArNetworking password.
    pub password: String,
    /// Server key (shared with the client's config).
    pub server_key: String,
    /// Salt sent in the INTRODUCTION.
    pub password_key: String,
    /// Protocol version required of clients.
    pub protocol_version: String,
    /// ARCL password.
    pub arcl_password: String,
    /// What ratioDrive percentages mean.
    pub drive: DriveLimits,
    /// The robot's limits.
    pub limits: RobotLimits,
    /// A drive holds this long, then the robot stops (2 s).
    pub drive_timeout: Duration,
    /// `updateNumbers` period of the robot's own cycle, the fastest it sends (100 ms: 10 Hz);
    /// a client's REQUEST interval, when longer, sets that client's rate.
    pub update_period: Duration,
    /// Stop sending `updateNumbers` this long after the start (stale-odometry test).
    pub stop_updates_after: Option<Duration>,
    /// Timing slack of the acceleration check, s: a change of velocity counts as a violation
    /// when it exceeds `limit × (dt + slack)` (packets arrive with jitter); the first drive
    /// from rest is compared with the measured velocity over `2 × slack`.
    pub accel_slack: f64,
}

impl Default for FakeConfig {
    fn default() -> Self {
        Self {
            arnl_addr: SocketAddr::from(([127, 0, 0, 1], motm_omron::ARNL_PORT)),
            arcl_addr: Some(SocketAddr::from(([127, 0, 0, 1], motm_omron::ARCL_PORT))),
            user: "guest".into(),
            password: String::new(),
            server_key: String::new(),
            password_key: "motm".into(),
            protocol_version: "5MTX".into(),
            arcl_password: "adept".into(),
            drive: DriveLimits {
                trans_vel_max: 1.8,
                rot_vel_max: 3.0,
                reverse_fraction: 0.25,
                rot_at_full_speed_fraction: 0.5,
            },
            limits: RobotLimits {
                v: 1.2,
                omega: 1.5,
                accel_v: 0.8,
                accel_omega: 2.0,
            },
            drive_timeout: Duration::from_secs(2),
            update_period: Duration::from_millis(100),
            stop_updates_after: None,
            accel_slack: 0.02,
        }
    }
}

/// What the fake robot counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeCounters {
    /// Clients that completed the handshake.
    pub clients: u64,
    /// Clients rejected (bad user, password or protocol).
    pub rejected: u64,
    /// `ratioDrive` packets followed.
    pub ratio_drives: u64,
    /// `stop` packets.
    pub stops: u64,
    /// Drives that ran out (no ratioDrive for the timeout): the robot stopped.
    pub drive_timeouts: u64,
    /// Drives beyond the robot's speed limits.
    pub speed_violations: u64,
    /// Drives beyond the robot's acceleration limits (a zero drive, a stop, never counts).
    pub accel_violations: u64,
    /// Bad packets (framing, checksum, payload): the connection is closed.
    pub bad_packets: u64,
    /// Packets with a command number the server does not know.
    pub unknown_commands: u64,
    /// `updateNumbers` packets sent.
    pub updates_sent: u64,
    /// Drives ignored while the e-stop was pressed.
    pub ignored_drives: u64,
}

/// The data the server registers, in order (numbers from 256). Names other than the four the
/// project uses are there so that the numbers are not guessable.
pub const DATA_NAMES: [&str; 7] = [
    "getPath",
    "updateNumbers",
    "updateStrings",
    "setSafeDrive",
    "ratioDrive",
    "stop",
    "dockInfoChanged",
];

/// The number of data `name`.
pub fn data_number(name: &str) -> Option<u16> {
    DATA_NAMES
        .iter()
        .position(|n| *n == name)
        .map(|i| FIRST_DATA_NUMBER + i as u16)
}

#[derive(Debug)]
struct State {
    drive: Option<(f64, f64, Instant)>,
    last_velocity: (f64, f64),
    last_drive_at: Option<Instant>,
    odometry: Odometry,
    estop: bool,
    estop_generation: u64,
    counters: FakeCounters,
}

#[derive(Debug)]
struct Shared {
    config: FakeConfig,
    started: Instant,
    state: Mutex<State>,
    stop: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The velocity the robot is told to follow at `now` (zero after the timeout or `stop`).
    fn commanded(&self, now: Instant) -> (f64, f64) {
        let mut s = self.lock();
        if s.estop {
            return (0.0, 0.0);
        }
        match s.drive {
            Some((_, _, at)) if now.duration_since(at) > self.config.drive_timeout => {
                s.drive = None;
                s.last_drive_at = None;
                s.counters.drive_timeouts += 1;
                (0.0, 0.0)
            }
            Some((v, w, _)) => (v, w),
            None => (0.0, 0.0),
        }
    }

    fn ratio_drive(&self, drive: &RatioDrive, now: Instant) {
        let (v, w) = self.config.drive.velocity(drive);
        let l = self.config.limits;
        let mut s = self.lock();
        if s.estop {
            s.counters.ignored_drives += 1;
            return;
        }
        let tol = 1e-6;
        if v.abs() > l.v * (1.0 + tol) || w.abs() > l.omega * (1.0 + tol) {
            s.counters.speed_violations += 1;
        }
        // From rest (no drive yet, or after a stop or a timeout) the reference is the measured
        // velocity over twice the slack.
        let (dt, (v0, w0)) = match s.last_drive_at {
            Some(at) => (
                now.duration_since(at).as_secs_f64() + self.config.accel_slack,
                s.last_velocity,
            ),
            None => (
                2.0 * self.config.accel_slack,
                (s.odometry.v, s.odometry.omega),
            ),
        };
        // A zero drive is a stop: the robot brakes with its own deceleration, so it is not an
        // acceleration violation.
        if (v, w) != (0.0, 0.0)
            && ((v - v0).abs() > l.accel_v * dt * (1.0 + tol)
                || (w - w0).abs() > l.accel_omega * dt * (1.0 + tol))
        {
            s.counters.accel_violations += 1;
        }
        s.last_velocity = (v, w);
        s.last_drive_at = Some(now);
        s.drive = Some((v, w, now));
        s.counters.ratio_drives += 1;
    }

    fn stop_drive(&self) {
        let mut s = self.lock();
        s.drive = None;
        s.last_drive_at = None;
        s.counters.stops += 1;
    }

    fn updates_on(&self, now: Instant) -> bool {
        self.config
            .stop_updates_after
            .is_none_or(|t| now.duration_since(self.started) < t)
    }
}

/// A running fake LD-60: its servers run in threads until [`shutdown`](Self::shutdown) or
/// drop.
#[derive(Debug)]
pub struct FakeLd60 {
    shared: Arc<Shared>,
    arnl_addr: SocketAddr,
    arcl_addr: Option<SocketAddr>,
    threads: Vec<JoinHandle<()>>,
}

impl FakeLd60 {
    /// Binds the listeners and starts the servers.
    pub fn start(config: FakeConfig) -> io::Result<Self> {
        config
            .drive
            .validate()
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        let arnl = TcpListener::bind(config.arnl_addr)?;
        let arcl = config.arcl_addr.map(TcpListener::bind).transpose()?;
        let arnl_addr = arnl.local_addr()?;
        let arcl_addr = arcl.as_ref().map(|l| l.local_addr()).transpose()?;
        let shared = Arc::new(Shared {
            config,
            started: Instant::now(),
            state: Mutex::new(State {
                drive: None,
                last_velocity: (0.0, 0.0),
                last_drive_at: None,
                odometry: Odometry {
                    x: 0.0,
                    y: 0.0,
                    yaw: 0.0,
                    v: 0.0,
                    omega: 0.0,
                    lateral: 0.0,
                    battery_v: 26.1,
                    temperature_c: None,
                },
                estop: false,
                estop_generation: 0,
                counters: FakeCounters::default(),
            }),
            stop: AtomicBool::new(false),
        });
        let mut threads = vec![accept_loop(arnl, shared.clone(), serve_arnl)];
        if let Some(l) = arcl {
            threads.push(accept_loop(l, shared.clone(), serve_arcl));
        }
        Ok(Self {
            shared,
            arnl_addr,
            arcl_addr,
            threads,
        })
    }

    /// Where the ArNetworking server listens.
    pub fn arnl_addr(&self) -> SocketAddr {
        self.arnl_addr
    }

    /// Where the ARCL server listens.
    pub fn arcl_addr(&self) -> Option<SocketAddr> {
        self.arcl_addr
    }

    /// The velocity `(v, ω)` the robot is told to follow now.
    pub fn commanded(&self) -> (f64, f64) {
        self.shared.commanded(Instant::now())
    }

    /// The robot's measured state (from the physics).
    pub fn set_odometry(&self, odometry: Odometry) {
        self.shared.lock().odometry = odometry;
    }

    /// The robot's state as last set.
    pub fn odometry(&self) -> Odometry {
        self.shared.lock().odometry
    }

    /// Presses (`true`) or relieves the e-stop; ARCL clients get the line.
    pub fn set_estop(&self, pressed: bool) {
        let mut s = self.shared.lock();
        if s.estop != pressed {
            s.estop = pressed;
            s.estop_generation += 1;
            if pressed {
                s.drive = None;
            }
        }
    }

    /// Counters.
    pub fn counters(&self) -> FakeCounters {
        self.shared.lock().counters
    }

    /// Stops the servers and closes every connection.
    pub fn shutdown(mut self) {
        self.stop_threads();
    }

    fn stop_threads(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for FakeLd60 {
    fn drop(&mut self) {
        self.stop_threads();
    }
}

/// Integrates a unicycle that follows [`FakeLd60::commanded`] within the robot's acceleration
/// limits, every `period`, until the fake shuts down.
pub fn spawn_kinematic(fake: &FakeLd60, period: Duration) -> JoinHandle<()> {
    let shared = fake.shared.clone();
    std::thread::spawn(move || {
        let mut last = Instant::now();
        while !shared.stop.load(Ordering::Relaxed) {
            std::thread::sleep(period);
            let now = Instant::now();
            let dt = now.duration_since(last).as_secs_f64();
            last = now;
            let (tv, tw) = shared.commanded(now);
            let l = shared.config.limits;
            let mut s = shared.lock();
            let o = &mut s.odometry;
            o.v += (tv - o.v).clamp(-l.accel_v * dt, l.accel_v * dt);
            o.omega += (tw - o.omega).clamp(-l.accel_omega * dt, l.accel_omega * dt);
            o.x += o.v * o.yaw.cos() * dt;
            o.y += o.v * o.yaw.sin() * dt;
            let yaw = o.yaw + o.omega * dt;
            o.yaw = yaw.sin().atan2(yaw.cos());
        }
    })
}

type Serve = fn(TcpStream, &Shared) -> io::Result<()>;

fn accept_loop(listener: TcpListener, shared: Arc<Shared>, serve: Serve) -> JoinHandle<()> {
    std::thread::spawn(move || {
        listener.set_nonblocking(true).ok();
        let mut clients = Vec::new();
        while !shared.stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((stream, _)) => {
                    let shared = shared.clone();
                    clients.push(std::thread::spawn(move || {
                        stream.set_nonblocking(false).ok();
                        let _ = serve(stream, &shared);
                    }));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        }
        for c in clients {
            let _ = c.join();
        }
    })
}

fn send(stream: &mut TcpStream, packet: &Packet) -> io::Result<()> {
    let bytes = packet
        .encode()
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
    stream.write_all(&bytes)
}

fn entries(second: impl Fn(&str) -> (String, String)) -> Vec<ListEntry> {
    DATA_NAMES
        .iter()
        .map(|n| {
            let (first, second) = second(n);
            ListEntry {
                command: data_number(n).expect("registered"),
                first,
                second,
            }
        })
        .collect()
}

/// One ArNetworking client, until it leaves, sends garbage or the fake shuts down.
fn serve_arnl(mut stream: TcpStream, shared: &Shared) -> io::Result<()> {
    let c = &shared.config;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_millis(5)))?;
    send(
        &mut stream,
        &ServerIntroduction {
            greeting: "alpha".into(),
            udp_port: 0,
            auth_key: 0x1234_5678,
            intro_key: 0x9abc_def0,
            password_key: c.password_key.clone(),
            protocol_version: c.protocol_version.clone(),
        }
        .to_packet(),
    )?;
    let mut rx = Vec::new();
    let mut introduced = false;
    let mut connected = false;
    let mut subscribed = false;
    let mut next_update = Instant::now();
    let mut period = c.update_period;
    let numbers = (
        data_number("updateNumbers").expect("registered"),
        data_number("ratioDrive").expect("registered"),
        data_number("stop").expect("registered"),
    );
    let mut chunk = [0u8; 4096];
    while !shared.stop.load(Ordering::Relaxed) {
        match stream.read(&mut chunk) {
            Ok(0) => return Ok(()),
            Ok(n) => rx.extend_from_slice(&chunk[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e),
        }
        loop {
            let (p, used) = match Packet::decode(&rx) {
                Ok(Some(x)) => x,
                Ok(None) => break,
                Err(_) => {
                    shared.lock().counters.bad_packets += 1;
                    return Ok(());
                }
            };
            rx.drain(..used);
            let now = Instant::now();
            match p.command {
                client::INTRODUCTION if !introduced => {
                    let Ok(hello) = ClientIntroduction::decode(&p.payload) else {
                        shared.lock().counters.bad_packets += 1;
                        return Ok(());
                    };
                    let hash = password_hash(&c.server_key, &c.password_key, &c.password);
                    let reject = if hello.user != c.user || hello.password_hash != hash {
                        Some((RejectReason::BadUserPassword, "bad user or password"))
                    } else if hello.protocol_version != c.protocol_version {
                        Some((RejectReason::ProtocolMismatch, "protocol mismatch"))
                    } else {
                        None
                    };
                    if let Some((reason, text)) = reject {
                        shared.lock().counters.rejected += 1;
                        send(&mut stream, &reason.to_packet(text))?;
                        return Ok(());
                    }
                    introduced = true;
                }
                client::TCP_ONLY if introduced && !connected => {
                    connected = true;
                    shared.lock().counters.clients += 1;
                    send(&mut stream, &Packet::empty(server::CONNECTED))?;
                    let list = entries(|n| (n.to_owned(), format!("{n} (fake LD-60)")));
                    send(&mut stream, &list_packet(server::LIST, &list))?;
                    let argret = entries(|n| match n {
                        "ratioDrive" => (
                            "double trans, double rot, double throttle, double lat".into(),
                            "none".into(),
                        ),
                        _ => ("none".into(), "none".into()),
                    });
                    send(&mut stream, &list_packet(server::LISTARGRET, &argret))?;
                    let groups = entries(|_| ("RobotInfo".into(), String::new()));
                    send(
                        &mut stream,
                        &list_packet(server::LISTGROUPANDFLAGS, &groups),
                    )?;
                }
                client::SHUTDOWN => return Ok(()),
                _ if !connected => {
                    // Anything else before the handshake completes: a broken client.
                    shared.lock().counters.bad_packets += 1;
                    return Ok(());
                }
                client::REQUEST | client::REQUESTSTOP => {
                    let mut reader = PayloadReader::new(&p.payload);
                    let Ok(number) = reader.u16("cmd") else {
                        shared.lock().counters.bad_packets += 1;
                        return Ok(());
                    };
                    if number == numbers.0 {
                        subscribed = p.command == client::REQUEST;
                        next_update = now;
                        // The client's interval, never faster than the robot's own cycle.
                        period = match reader.i32("intervalMs") {
                            Ok(ms) if ms > 0 && p.command == client::REQUEST => c
                                .update_period
                                .max(Duration::from_millis(ms.unsigned_abs().into())),
                            _ => c.update_period,
                        };
                    }
                }
                n if n == numbers.1 => match RatioDrive::decode(&p.payload) {
                    Ok(d) => shared.ratio_drive(&d, now),
                    Err(_) => {
                        shared.lock().counters.bad_packets += 1;
                        return Ok(());
                    }
                },
                n if n == numbers.2 => shared.stop_drive(),
                n if n >= FIRST_DATA_NUMBER
                    && usize::from(n - FIRST_DATA_NUMBER) < DATA_NAMES.len() => {}
                _ => shared.lock().counters.unknown_commands += 1,
            }
        }
        let now = Instant::now();
        if subscribed && now >= next_update {
            next_update += period;
            if next_update < now {
                next_update = now + period;
            }
            if shared.updates_on(now) {
                let odometry = shared.lock().odometry;
                let u = UpdateNumbers::from_odometry(&odometry);
                send(&mut stream, &Packet::new(numbers.0, u.payload()))?;
                shared.lock().counters.updates_sent += 1;
            }
        }
    }
    Ok(())
}

/// The ARCL status of `o`.
fn arcl_status(o: &Odometry, estop: bool) -> ArclStatus {
    ArclStatus {
        status: Some(if estop {
            "EStop pressed".into()
        } else if o.v != 0.0 || o.omega != 0.0 {
            "Driving".into()
        } else {
            "Stopped".into()
        }),
        battery_voltage: Some(o.battery_v),
        location: Some((o.x * 1e3, o.y * 1e3, o.yaw.to_degrees())),
        localization_score: Some(1.0),
        temperature: Some(f64::from(o.temperature_c.unwrap_or(-128))),
    }
}

/// One ARCL client.
fn serve_arcl(stream: TcpStream, shared: &Shared) -> io::Result<()> {
    let mut out = stream.try_clone()?;
    stream.set_read_timeout(Some(Duration::from_millis(10)))?;
    let mut reader = BufReader::new(stream);
    out.write_all(format!("{PASSWORD_PROMPT}\r\n").as_bytes())?;
    let mut line = String::new();
    let mut logged_in = false;
    let mut estop_seen = shared.lock().estop_generation;
    while !shared.stop.load(Ordering::Relaxed) {
        match reader.read_line(&mut line) {
            Ok(0) => return Ok(()),
            Ok(_) if line.ends_with('\n') => {
                let cmd = std::mem::take(&mut line);
                let cmd = cmd.trim();
                if !logged_in {
                    if cmd != shared.config.arcl_password {
                        return Ok(());
                    }
                    logged_in = true;
                    out.write_all(
                        format!(
                            "Welcome to the server.\r\nYou can type 'help' at any time for the following commands\r\nCommands:\r\n\r\nstatus\tGets the status of the robot\r\noneLineStatus\tGets the status of the robot on one line\r\nstop\tStops the robot\r\n{END_OF_COMMANDS}\r\n"
                        )
                        .as_bytes(),
                    )?;
                    continue;
                }
                let (o, estop) = {
                    let s = shared.lock();
                    (s.odometry, s.estop)
                };
                match cmd.to_ascii_lowercase().as_str() {
                    "status" => out.write_all(arcl_status(&o, estop).to_lines().as_bytes())?,
                    "onelinestatus" => {
                        let lines = arcl_status(&o, estop).to_lines();
                        let one: Vec<&str> = lines.lines().collect();
                        out.write_all(format!("{}\r\n", one.join(" ")).as_bytes())?;
                    }
                    "stop" => {
                        shared.stop_drive();
                        out.write_all(b"Stopping\r\nStopped\r\n")?;
                    }
                    "" => {}
                    other => out.write_all(format!("Unknown command {other}\r\n").as_bytes())?,
                }
            }
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e),
        }
        if logged_in {
            let (generation, pressed) = {
                let s = shared.lock();
                (s.estop_generation, s.estop)
            };
            if generation != estop_seen {
                estop_seen = generation;
                let text: &[u8] = if pressed {
                    b"EStop pressed\r\n"
                } else {
                    b"EStop relieved\r\n"
                };
                out.write_all(text)?;
            }
        }
    }
    Ok(())
}
