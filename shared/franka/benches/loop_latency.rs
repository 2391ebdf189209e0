//! The driver's latency from a `RobotState`'s arrival (the datagram read from the socket) to
//! its command being sent, over real loopback UDP against the fake robot at 1 kHz in another
//! thread: each cycle runs the stack's [`VelocityDriver`] limits (as panda-driver does), then
//! libfranka's filter and rate limiter, encodes and sends. Prints the median, p99 and max over
//! `MOTM_FCI_BENCH_CYCLES` cycles (default 10 000). Target: p99 < 300 µs.
//!
//! Run: `cargo bench -p motm-franka --bench loop_latency`.

use std::net::{IpAddr, Ipv4Addr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use motm_core::command_limiter::AxisLimits;
use motm_core::velocity_driver::{VelocityDriver, VelocityDriverConfig};
use motm_franka::fake::{FakeRobot, FakeRobotConfig, IdealArm, run_every_ms};
use motm_franka::rate_limit::{ACCELERATION_LIMIT, JERK_LIMIT, VELOCITY_LIMIT};
use motm_franka::{FciClient, FciConfig};

fn main() {
    let cycles: usize = std::env::var("MOTM_FCI_BENCH_CYCLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    let ip = IpAddr::V4(Ipv4Addr::LOCALHOST);
    let mut robot = FakeRobot::bind(ip, 0, FakeRobotConfig::default()).unwrap();
    let port = robot.port();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let fake = std::thread::spawn(move || {
        let mut arm = IdealArm::default();
        run_every_ms(|| {
            robot.cycle(&mut arm);
            !flag.load(Ordering::Relaxed)
        });
        robot
    });
    let mut client = FciClient::connect(
        ip,
        FciConfig {
            port,
            ..FciConfig::default()
        },
    )
    .unwrap();
    let limits = (0..7)
        .map(|i| AxisLimits {
            velocity: VELOCITY_LIMIT[i],
            acceleration: ACCELERATION_LIMIT[i],
            jerk: JERK_LIMIT[i],
        })
        .collect();
    let mut driver = VelocityDriver::new(limits, 1e-3, VelocityDriverConfig::default()).unwrap();
    while !client.has_state() {
        client.next_state().unwrap();
    }
    client.start_motion().unwrap();
    while !client.running() {
        client.next_state().unwrap();
    }
    let mut samples = Vec::with_capacity(cycles);
    let mut k = 0u64;
    while samples.len() < cycles {
        client.next_state().unwrap();
        let arrival = client.state_received_at().unwrap();
        let now_ns = k * 1_000_000;
        let target = [0.5 * ((k as f64) * 1e-3).sin(); 7];
        driver.receive(now_ns, &target);
        let mut v = [0.0; 7];
        v.copy_from_slice(
            driver
                .step(now_ns, false, Some(&client.state().dq))
                .unwrap(),
        );
        if client.command(&v).unwrap().is_some() {
            samples.push(arrival.elapsed().as_nanos() as u64);
        }
        k += 1;
    }
    client.finish();
    while client.next_state().unwrap().is_none() {
        client.command(&[0.0; 7]).unwrap();
    }
    let c = client.counters();
    drop(client);
    stop.store(true, Ordering::Relaxed);
    let robot = fake.join().unwrap();
    samples.sort_unstable();
    let at = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize] as f64 / 1e3;
    println!(
        "fci state-to-command latency over {} cycles: median {:.1} µs, p99 {:.1} µs, max {:.1} µs (target p99 < 300 µs)",
        samples.len(),
        at(0.5),
        at(0.99),
        at(1.0)
    );
    println!(
        "client: {} states, {} lost, {} skipped; fake: {}",
        c.states,
        c.lost_states,
        c.skipped_states,
        robot.summary()
    );
}
