//! The bridge between two zenoh peers on loopback (multicast scouting off): a sample exported
//! on one iceoryx2 prefix arrives on the other with its stamps kept, and an envelope of another
//! schema version, payload type or size is refused, counted and never published.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use motm_bus::{Bus, IpcConfig, Publisher, Stamp, Subscriber, remove_domain};
use motm_msgs::{Message, SCHEMA_VERSION, TargetEstimate, topics};
use motm_zenoh::envelope::{self, PayloadId};
use motm_zenoh::{BridgeConfig, Exporter, Importer, Link, Stats, lanes, open_session};
use zenoh::Wait;

/// A free loopback TCP port.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A bridge config of `name` importing (or exporting) perception's target.
fn config(
    name: &str,
    import: bool,
    listen: Option<String>,
    connect: Option<String>,
) -> BridgeConfig {
    let topic = vec![topics::PERCEPTION_TARGET.name().to_owned()];
    let config = BridgeConfig {
        name: name.into(),
        export: if import { Vec::new() } else { topic.clone() },
        import: if import { topic } else { Vec::new() },
        listen: listen.into_iter().collect(),
        connect: connect.into_iter().collect(),
        namespace: format!("test{}", std::process::id()),
        multicast_scouting: false,
    };
    config.validate().unwrap();
    config
}

/// A valid target estimate stamped `stamp_ns`, its image 2 ms older.
fn target(stamp_ns: u64) -> TargetEstimate {
    let mut t = TargetEstimate::zeroed();
    t.header.stamp_ns = stamp_ns;
    t.image_stamp_ns = stamp_ns - 2_000_000;
    t.image_published_ns = stamp_ns - 1_000_000;
    t.position = [2.0, 0.1, 0.45];
    t.visible = 1;
    t
}

/// Polls `importer` until `done` or 10 s pass.
fn poll_until(importer: &mut Importer, mut done: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) {
        importer.poll(Duration::from_millis(10));
        if done() {
            return true;
        }
    }
    false
}

#[test]
fn a_sample_crosses_two_prefixes_and_a_mismatched_schema_is_refused_and_counted() {
    let pid = std::process::id();
    let here = IpcConfig {
        prefix: format!("motmzt{pid}a_"),
    };
    let there = IpcConfig {
        prefix: format!("motmzt{pid}b_"),
    };
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let out_config = config("test-out", false, Some(endpoint.clone()), None);
    let in_config = config("test-in", true, None, Some(endpoint));
    let out_stats = Arc::new(Stats::default());
    let in_stats = Arc::new(Stats::default());
    {
        let out_session = open_session(&out_config).unwrap();
        let in_session = open_session(&in_config).unwrap();
        let near = Bus::open_with("test-near", &here).unwrap();
        let far = Bus::open_with("test-far", &there).unwrap();
        let qos = lanes::qos_of(topics::PERCEPTION_TARGET.name());
        let mut publisher =
            Publisher::<TargetEstimate>::new(&near, topics::PERCEPTION_TARGET.name(), &qos)
                .unwrap();
        let mut exporter = Exporter::open(Link {
            bus: &near,
            session: &out_session,
            config: &out_config,
            stats: out_stats.clone(),
        })
        .unwrap();
        let mut importer = Importer::open(Link {
            bus: &far,
            session: &in_session,
            config: &in_config,
            stats: in_stats.clone(),
        })
        .unwrap();
        let mut reader =
            Subscriber::<TargetEstimate>::new(&far, topics::PERCEPTION_TARGET.name(), &qos)
                .unwrap();

        // The peers connect in the background: publish until a sample comes through.
        let mut received = None;
        let start = Instant::now();
        while received.is_none() && start.elapsed() < Duration::from_secs(10) {
            let now = motm_bus::monotonic_now_ns();
            publisher
                .publish_stamped(Stamp::At(now), target(now))
                .unwrap();
            exporter.pump();
            importer.poll(Duration::from_millis(50));
            received = reader.receive().unwrap().map(|r| (*r, now));
        }
        let (got, sent_stamp) = received.expect("a sample crossed the bridge within 10 s");
        assert_eq!(got.position, [2.0, 0.1, 0.45]);
        assert_eq!(got.visible, 1);
        // One host, one clock: every instant moves by the same small offset (at most the
        // transfer time), so the image stays 2 ms before the estimate.
        let moved = got.header.stamp_ns - sent_stamp;
        assert!(moved < 50_000_000, "stamp moved by {moved} ns");
        assert_eq!(got.header.stamp_ns - got.image_stamp_ns, 2_000_000);
        assert_eq!(got.header.stamp_ns - got.image_published_ns, 1_000_000);
        assert!(out_stats.exported.load(Ordering::Relaxed) >= 1);
        assert_eq!(in_stats.refused.load(Ordering::Relaxed), 0);

        // A sender built with another schema version, another payload type or another size.
        let key = in_config.key_of(topics::PERCEPTION_TARGET.name());
        let foreign = out_session.declare_publisher(key).wait().unwrap();
        let good = PayloadId {
            type_name: <TargetEstimate as Message>::NAME,
            schema_version: SCHEMA_VERSION,
            size: size_of::<TargetEstimate>(),
        };
        let now = motm_bus::monotonic_now_ns();
        let sample = target(now);
        // SAFETY: a `TargetEstimate` is plain integers and floats with no implicit padding.
        let bytes = unsafe {
            std::slice::from_raw_parts(
                (&sample as *const TargetEstimate).cast::<u8>(),
                size_of::<TargetEstimate>(),
            )
        };
        let mut wire = Vec::new();
        let wrong = [
            PayloadId {
                schema_version: SCHEMA_VERSION + 1,
                ..good
            },
            PayloadId {
                type_name: "BaseOdometry",
                ..good
            },
        ];
        for id in wrong {
            envelope::encode(&id, 99, now, bytes, &mut wire);
            foreign.put(wire.clone()).wait().unwrap();
        }
        // Another size: the payload cut by 8 bytes.
        let short = PayloadId {
            size: size_of::<TargetEstimate>() - 8,
            ..good
        };
        envelope::encode(&short, 99, now, &bytes[..short.size], &mut wire);
        foreign.put(wire.clone()).wait().unwrap();
        assert!(
            poll_until(&mut importer, || in_stats.refused.load(Ordering::Relaxed)
                >= 3),
            "refusals: {}",
            in_stats.summary()
        );
        assert_eq!(in_stats.refused.load(Ordering::Relaxed), 3);
        // None of them reached the stack.
        while let Some(r) = reader.receive().unwrap() {
            assert!(r.header.stamp_ns < now, "a refused sample was published");
        }
        // The same sample with this build's schema goes through.
        envelope::encode(&good, 99, now, bytes, &mut wire);
        foreign.put(wire).wait().unwrap();
        let mut through = false;
        assert!(poll_until(&mut importer, || {
            through |= reader.receive().unwrap().is_some();
            through
        }));
        assert_eq!(in_stats.refused.load(Ordering::Relaxed), 3);
        assert_eq!(in_stats.invalid.load(Ordering::Relaxed), 0);
        let _ = out_session.close().wait();
        let _ = in_session.close().wait();
    }
    for ipc in [&here, &there] {
        // SAFETY: every node of the test is dropped.
        unsafe { remove_domain(ipc) }.unwrap();
        assert!(motm_bus::shared_memory_entries(ipc).unwrap().is_empty());
    }
}

#[test]
fn an_invalid_sample_of_the_right_type_is_counted_and_not_published() {
    let pid = std::process::id();
    let there = IpcConfig {
        prefix: format!("motmzt{pid}c_"),
    };
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let in_config = config("test-in", true, Some(endpoint.clone()), None);
    let out_config = config("test-out", false, None, Some(endpoint));
    let stats = Arc::new(Stats::default());
    {
        let in_session = open_session(&in_config).unwrap();
        let out_session = open_session(&out_config).unwrap();
        let far = Bus::open_with("test-far", &there).unwrap();
        let qos = lanes::qos_of(topics::PERCEPTION_TARGET.name());
        let mut importer = Importer::open(Link {
            bus: &far,
            session: &in_session,
            config: &in_config,
            stats: stats.clone(),
        })
        .unwrap();
        let mut reader =
            Subscriber::<TargetEstimate>::new(&far, topics::PERCEPTION_TARGET.name(), &qos)
                .unwrap();
        let foreign = out_session
            .declare_publisher(in_config.key_of(topics::PERCEPTION_TARGET.name()))
            .wait()
            .unwrap();
        let id = PayloadId {
            type_name: <TargetEstimate as Message>::NAME,
            schema_version: SCHEMA_VERSION,
            size: size_of::<TargetEstimate>(),
        };
        let mut bad = target(motm_bus::monotonic_now_ns());
        bad.position[0] = f64::NAN;
        // SAFETY: as above.
        let bytes = unsafe {
            std::slice::from_raw_parts(
                (&bad as *const TargetEstimate).cast::<u8>(),
                size_of::<TargetEstimate>(),
            )
        };
        let mut wire = Vec::new();
        envelope::encode(&id, 7, motm_bus::monotonic_now_ns(), bytes, &mut wire);
        // Until the peers are connected, puts are lost: send until one is counted.
        let start = Instant::now();
        while stats.invalid.load(Ordering::Relaxed) == 0
            && start.elapsed() < Duration::from_secs(10)
        {
            foreign.put(wire.clone()).wait().unwrap();
            importer.poll(Duration::from_millis(50));
        }
        assert!(
            stats.invalid.load(Ordering::Relaxed) >= 1,
            "{}",
            stats.summary()
        );
        assert_eq!(stats.imported.load(Ordering::Relaxed), 0);
        assert!(reader.receive().unwrap().is_none());
        let _ = in_session.close().wait();
        let _ = out_session.close().wait();
    }
    // SAFETY: every node of the test is dropped.
    unsafe { remove_domain(&there) }.unwrap();
}
