//! `motm-zenoh bench`: the latency a bridge adds to a hop, beside a direct iceoryx2 hop in the
//! same run, for a 64-byte payload and a camera image.
//!
//! Two iceoryx2 prefixes stand for two hosts. A sender publishes on the first; a receiver
//! thread subscribed on both prefixes wakes on each sample's data event and takes the time from
//! the sample's publication stamp (filled in just before the send). On the first prefix that is
//! the direct iceoryx2 hop; on the second it is the bridged hop: the export half of one bridge
//! (woken by the same event), a zenoh put over loopback TCP to a second zenoh peer, the import
//! half of the other bridge, and its publish on the second prefix. Each round waits for both
//! arrivals, so hops never queue. Every thread shares the same monotonic clock.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Sender, channel};
use std::thread::JoinHandle;
use std::time::Duration;

use clap::Args;
use iceoryx2::prelude::*;
use motm_bus::{
    Bus, Flow, IpcConfig, LoopConfig, Publisher, Qos, ServiceLoop, Stamp, Subscriber,
    monotonic_now_ns, percentile, remove_domain,
};
use motm_msgs::{CAMERA_HEIGHT, CAMERA_WIDTH, CameraImage, Header, Message, Rejection};
use serde_json::{Value, json};

use crate::lanes::Typed;
use crate::{BridgeConfig, Exporter, Importer, Link, Stats, Topic};

/// Arguments of `motm-zenoh bench`.
#[derive(Debug, Clone, Args)]
pub struct BenchArgs {
    /// Measured hops per payload.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(1..))]
    pub samples: u32,
    /// Unmeasured warm-up hops per payload.
    #[arg(long, default_value_t = 200)]
    pub warmup: u32,
    /// Print one JSON object: per payload and path `median_us`, `p99_us`, `max_us`, and the
    /// bridge's added `added_median_us`, `added_p99_us`.
    #[arg(long)]
    pub json: bool,
}

/// The 64-byte benchmark payload.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("motm.v1.BenchZenohPing")]
#[repr(C)]
pub struct Ping {
    /// Common header.
    pub header: Header,
    /// When the sample was sent, ns (filled in by the publisher).
    pub published_ns: u64,
    /// Filler up to 64 bytes.
    pub filler: [u8; 32],
}

// SAFETY: integers only; all-zero bytes are valid.
unsafe impl Message for Ping {
    const NAME: &'static str = "BenchZenohPing";

    fn header(&self) -> &Header {
        &self.header
    }

    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }

    fn validate_fields(&self) -> Result<(), Rejection> {
        Ok(())
    }

    fn publication_stamp_mut(&mut self) -> Option<&mut u64> {
        Some(&mut self.published_ns)
    }
}

/// A payload whose publication time the receiver reads.
trait Published: Message {
    /// When the sample was sent, ns.
    fn published_ns(&self) -> u64;
}

impl Published for Ping {
    fn published_ns(&self) -> u64 {
        self.published_ns
    }
}

impl Published for CameraImage {
    fn published_ns(&self) -> u64 {
        self.image_published_ns
    }
}

/// Service of the 64-byte pings.
const PING: &str = "motm/v1/bench/zenoh_ping";
/// Service of the images.
const IMAGE: &str = "motm/v1/bench/zenoh_image";
/// Longest wait for one hop.
const TIMEOUT: Duration = Duration::from_secs(10);

static PING_KIND: Typed<Ping> = Typed::new();
static IMAGE_KIND: Typed<CameraImage> = Typed::new();

/// The two payloads with their service settings.
fn topics() -> [Topic<'static>; 2] {
    [
        (PING, &PING_KIND, Qos::default().waking()),
        (IMAGE, &IMAGE_KIND, Qos::large().waking()),
    ]
}

/// Hop times of one payload, ns: direct and bridged, one of each per round.
#[derive(Debug, Default)]
struct Hops {
    direct: Vec<u64>,
    bridged: Vec<u64>,
}

/// Median, p99 and max of `ns`, µs.
fn summary(ns: &mut [u64]) -> Value {
    let us = |v: u64| (v as f64 / 10.0).round() / 100.0;
    json!({
        "median_us": us(percentile(ns, 50.0)),
        "p99_us": us(percentile(ns, 99.0)),
        "max_us": us(percentile(ns, 100.0)),
        "samples": ns.len(),
    })
}

/// Runs the benchmark and prints its report.
pub fn run(args: &BenchArgs) -> Result<(), String> {
    let pid = std::process::id();
    let here = IpcConfig {
        prefix: format!("motmzb{pid}a_"),
    };
    let there = IpcConfig {
        prefix: format!("motmzb{pid}b_"),
    };
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| format!("no free loopback port: {e}"))?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let out = BridgeConfig {
        name: "bench-out".into(),
        export: vec![PING.into(), IMAGE.into()],
        import: Vec::new(),
        listen: vec![endpoint.clone()],
        connect: Vec::new(),
        namespace: format!("bench{pid}"),
        multicast_scouting: false,
    };
    let into = BridgeConfig {
        name: "bench-in".into(),
        export: Vec::new(),
        import: out.export.clone(),
        listen: Vec::new(),
        connect: vec![endpoint],
        ..out.clone()
    };
    let result = measure(args, &here, &there, &out, &into);
    for ipc in [&here, &there] {
        // SAFETY: every thread of the benchmark has ended and dropped its nodes.
        let _ = unsafe { remove_domain(ipc) };
    }
    let (mut ping, mut image, stats) = result?;
    let mut report = serde_json::Map::new();
    for (key, hops) in [("64B", &mut ping), ("image", &mut image)] {
        let added = |a: &mut Vec<u64>, b: &mut Vec<u64>, p: f64| {
            (percentile(b, p) as f64 - percentile(a, p) as f64) / 1000.0
        };
        let added_median = added(&mut hops.direct, &mut hops.bridged, 50.0);
        let added_p99 = added(&mut hops.direct, &mut hops.bridged, 99.0);
        report.insert(
            key.into(),
            json!({
                "payload_bytes": if key == "64B" { size_of::<Ping>() } else { size_of::<CameraImage>() },
                "iceoryx2": summary(&mut hops.direct),
                "bridged": summary(&mut hops.bridged),
                "added_median_us": (added_median * 100.0).round() / 100.0,
                "added_p99_us": (added_p99 * 100.0).round() / 100.0,
            }),
        );
    }
    report.insert("bridge".into(), json!(stats.summary()));
    if args.json {
        println!("{}", Value::Object(report));
    } else {
        for key in ["64B", "image"] {
            let r = &report[key];
            println!(
                "{key:>6} ({} B): iceoryx2 median {} µs p99 {} µs | bridged median {} µs p99 {} µs | added median {} µs p99 {} µs",
                r["payload_bytes"],
                r["iceoryx2"]["median_us"],
                r["iceoryx2"]["p99_us"],
                r["bridged"]["median_us"],
                r["bridged"]["p99_us"],
                r["added_median_us"],
                r["added_p99_us"]
            );
        }
        println!("bridge: {}", report["bridge"]);
    }
    Ok(())
}

/// Starts both bridges and the receiver, sends the pings, stops everything.
fn measure(
    args: &BenchArgs,
    here: &IpcConfig,
    there: &IpcConfig,
    out: &BridgeConfig,
    into: &BridgeConfig,
) -> Result<(Hops, Hops, Arc<Stats>), String> {
    let stop = Arc::new(AtomicBool::new(false));
    let stats = Arc::new(Stats::default());
    let e = |e: motm_bus::BusError| e.to_string();
    // Every service exists before a bridge or the receiver opens it.
    let bus = Bus::open_with("bench-sender", here).map_err(e)?;
    let mut ping = Publisher::<Ping>::new(&bus, PING, &topics()[0].2).map_err(e)?;
    let mut image = Publisher::<CameraImage>::new(&bus, IMAGE, &topics()[1].2).map_err(e)?;
    let (hop_send, hops) = channel::<(usize, bool, u64)>();
    let (ready_send, ready) = channel::<Result<(), String>>();
    let mut threads = vec![
        spawn_half(there, into, &stats, &ready_send, Importer::with_kinds, {
            let stop = stop.clone();
            move |_, mut importer| {
                while !stop.load(Ordering::Relaxed) {
                    importer.poll(Duration::from_millis(20));
                }
            }
        }),
        spawn_half(here, out, &stats, &ready_send, Exporter::with_kinds, {
            let stop = stop.clone();
            move |bus, mut exporter| {
                let triggers = exporter.triggers();
                let Ok(mut service) = ServiceLoop::new(bus, LoopConfig::with_rate(1000.0)) else {
                    return;
                };
                let _ = service.run_on_arrival(&triggers, |_| {
                    exporter.pump();
                    if stop.load(Ordering::Relaxed) {
                        Flow::Stop
                    } else {
                        Flow::Continue
                    }
                });
            }
        }),
    ];
    {
        let (here, there, stop, ready) = (
            here.clone(),
            there.clone(),
            stop.clone(),
            ready_send.clone(),
        );
        threads.push(std::thread::spawn(move || {
            if let Err(e) = receive(&here, &there, &stop, &hop_send, &ready) {
                let _ = ready.send(Err(e));
            }
        }));
    }
    let result = (|| {
        for _ in 0..3 {
            ready
                .recv_timeout(TIMEOUT)
                .map_err(|_| "a bench thread did not start".to_owned())??;
        }
        let rounds = args.warmup + args.samples;
        let mut results = [Hops::default(), Hops::default()];
        for (case, hops_of) in results.iter_mut().enumerate() {
            // The zenoh peers connect in the background: the warm-up waits for the first
            // bridged sample (rounds lost before are not counted).
            let mut round = 0;
            let mut connected = false;
            while round < rounds {
                let now = monotonic_now_ns();
                if case == 0 {
                    ping.publish(Ping::zeroed()).map_err(e)?;
                } else {
                    image
                        .publish_with(Stamp::At(now), |m| {
                            m.image_published_ns = now;
                            m.width = CAMERA_WIDTH as u32;
                            m.height = CAMERA_HEIGHT as u32;
                        })
                        .map_err(e)?;
                }
                let mut got = (None, None);
                let deadline = std::time::Instant::now()
                    + if connected {
                        TIMEOUT
                    } else {
                        Duration::from_millis(200)
                    };
                while got.0.is_none() || got.1.is_none() {
                    let left = deadline.saturating_duration_since(std::time::Instant::now());
                    match hops.recv_timeout(left) {
                        Ok((c, bridged, ns)) if c == case => {
                            if bridged {
                                got.1 = Some(ns);
                            } else {
                                got.0 = Some(ns);
                            }
                        }
                        Ok(_) => {}
                        Err(_) => break,
                    }
                }
                match got {
                    (Some(direct), Some(bridged)) => {
                        connected = true;
                        if round >= args.warmup {
                            hops_of.direct.push(direct);
                            hops_of.bridged.push(bridged);
                        }
                        round += 1;
                    }
                    _ if connected => return Err(format!("hop {round} of case {case} lost")),
                    _ => {}
                }
            }
        }
        let [a, b] = results;
        Ok((a, b))
    })();
    stop.store(true, Ordering::Relaxed);
    drop((ping, image, bus));
    for thread in threads {
        let _ = thread.join();
    }
    let (a, b) = result?;
    Ok((a, b, stats))
}

/// Starts a thread that opens the zenoh session of `config`, a node on `ipc` and one half of
/// the bridge (`open`, for the benchmark's payloads), says on `ready` whether that worked, and
/// then runs `work` with the node and the half.
fn spawn_half<H: 'static>(
    ipc: &IpcConfig,
    config: &BridgeConfig,
    stats: &Arc<Stats>,
    ready: &Sender<Result<(), String>>,
    open: fn(Link<'_>, &[Topic<'_>]) -> Result<H, String>,
    work: impl FnOnce(&Bus, H) + Send + 'static,
) -> JoinHandle<()> {
    let (ipc, config, stats, ready) = (ipc.clone(), config.clone(), stats.clone(), ready.clone());
    std::thread::spawn(move || {
        let opened = crate::open_session(&config).and_then(|session| {
            let bus = Bus::open_with(&config.name, &ipc).map_err(|e| e.to_string())?;
            let link = Link {
                bus: &bus,
                session: &session,
                config: &config,
                stats,
            };
            let half = open(link, &topics())?;
            Ok((session, bus, half))
        });
        match opened {
            Ok((_session, bus, half)) => {
                let _ = ready.send(Ok(()));
                work(&bus, half);
            }
            Err(e) => {
                let _ = ready.send(Err(e));
            }
        }
    })
}

/// The receiver: subscribed to both payloads on both prefixes, woken by their data events;
/// sends `(payload, bridged, hop ns)` for each sample.
fn receive(
    here: &IpcConfig,
    there: &IpcConfig,
    stop: &AtomicBool,
    hops: &Sender<(usize, bool, u64)>,
    ready: &Sender<Result<(), String>>,
) -> Result<(), String> {
    let e = |e: motm_bus::BusError| e.to_string();
    let near = Bus::open_with("bench-near", here).map_err(e)?;
    let far = Bus::open_with("bench-far", there).map_err(e)?;
    let [ping, image] = topics();
    let mut pings = [
        Subscriber::<Ping>::new(&near, ping.0, &ping.2).map_err(e)?,
        Subscriber::<Ping>::new(&far, ping.0, &ping.2).map_err(e)?,
    ];
    let mut images = [
        Subscriber::<CameraImage>::new(&near, image.0, &image.2).map_err(e)?,
        Subscriber::<CameraImage>::new(&far, image.0, &image.2).map_err(e)?,
    ];
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| format!("{e:?}"))?;
    let triggers: Vec<_> = pings
        .iter()
        .filter_map(Subscriber::trigger)
        .chain(images.iter().filter_map(Subscriber::trigger))
        .collect();
    let mut guards = Vec::new();
    for trigger in &triggers {
        guards.push(
            waitset
                .attach_notification(trigger.listener())
                .map_err(|e| format!("{e:?}"))?,
        );
    }
    let _ = ready.send(Ok(()));
    let mut last_refresh = monotonic_now_ns();
    while !stop.load(Ordering::Relaxed) {
        let _ = waitset.wait_and_process_once_with_timeout(
            |_| CallbackProgression::Continue,
            Duration::from_millis(20),
        );
        for (bridged, s) in pings.iter_mut().enumerate() {
            s.clear_notifications();
            while let Some(sample) = s.receive().map_err(e)? {
                let hop = monotonic_now_ns().saturating_sub(sample.published_ns());
                let _ = hops.send((0, bridged == 1, hop));
            }
        }
        for (bridged, s) in images.iter_mut().enumerate() {
            s.clear_notifications();
            while let Some(sample) = s.receive().map_err(e)? {
                let hop = monotonic_now_ns().saturating_sub(sample.published_ns());
                let _ = hops.send((1, bridged == 1, hop));
            }
        }
        if monotonic_now_ns() - last_refresh > 100_000_000 {
            near.update_connections();
            far.update_connections();
            last_refresh = monotonic_now_ns();
        }
    }
    Ok(())
}
