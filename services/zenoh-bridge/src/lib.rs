//! The zenoh bridge (`motm-zenoh`): forwards a configured set of topics between the local
//! iceoryx2 stack and zenoh key expressions (`motm/v1/...`, behind an optional namespace), both
//! ways, so that a stack can span hosts: perception on a GPU box, the live view or
//! `motm status` on a laptop.
//!
//! - **Export** ([`Exporter`]): a subscriber per exported topic on the local stack (validated
//!   like any reader's); each sample goes out as one zenoh sample in an [`envelope`] naming its
//!   payload type, schema version and size.
//! - **Import** ([`Importer`]): a zenoh subscriber per imported topic; an envelope of another
//!   payload type, schema version or size is refused with an error naming both sides and
//!   counted ([`Stats::refused`]); a good one is checked like any received sample and
//!   published on the local stack.
//! - **Clocks.** Stamps are `CLOCK_MONOTONIC`, which differs between hosts. Every instant an
//!   imported sample holds (its header stamp, an image's stamps: `Message::for_each_instant`)
//!   is moved to the local clock by the smallest `receive − send` seen from its sender (the
//!   clock offset plus the fastest transfer), so ages and their order are kept and no stamp is
//!   in the future.
//! - Only the topics the config names cross, and each one way only; the control loop never
//!   waits for the network: the bridge is one more reader and publisher of a topic, with the
//!   same non-blocking, safely overflowing services as every process.

pub mod bench;
pub mod config;
pub mod envelope;
pub mod lanes;
pub mod service;

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::Duration;

use motm_bus::{Bus, IpcConfig, LoopConfig, Qos, ServiceLoop, Trigger, monotonic_now_ns};
use zenoh::Wait;

pub use config::{BridgeConfig, REMOTE_BRIDGE, STACK_BRIDGE, Side};
use envelope::{PayloadId, Refusal};
use lanes::{ExportLane, ImportError, ImportLane, Kind};

/// What a bridge did, shared by its export and import halves.
#[derive(Debug, Default)]
pub struct Stats {
    /// Local samples put on zenoh.
    pub exported: AtomicU64,
    /// Samples from zenoh published locally.
    pub imported: AtomicU64,
    /// Samples from zenoh refused: another payload type, schema version, size or byte order,
    /// or not an envelope at all.
    pub refused: AtomicU64,
    /// Samples from zenoh of the right type that failed the receive-side checks.
    pub invalid: AtomicU64,
    /// Puts on zenoh or local publishes that failed.
    pub failed: AtomicU64,
}

impl Stats {
    /// One line of counts, for the log.
    pub fn summary(&self) -> String {
        format!(
            "{} exported, {} imported, {} refused, {} invalid, {} failed",
            self.exported.load(Ordering::Relaxed),
            self.imported.load(Ordering::Relaxed),
            self.refused.load(Ordering::Relaxed),
            self.invalid.load(Ordering::Relaxed),
            self.failed.load(Ordering::Relaxed),
        )
    }
}

/// Opens the zenoh session of `config`.
pub fn open_session(config: &BridgeConfig) -> Result<zenoh::Session, String> {
    zenoh::open(config.zenoh_config()?)
        .wait()
        .map_err(|e| format!("cannot open the zenoh session: {e}"))
}

/// A random id for this bridge process's envelopes.
fn sender_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
    hasher.write_u32(std::process::id());
    hasher.write_u64(monotonic_now_ns());
    hasher.finish()
}

/// The kind of a configured topic (checked by [`BridgeConfig::validate`]).
fn kind(topic: &str) -> Result<&'static dyn Kind, String> {
    lanes::kind_of(topic).ok_or_else(|| format!("{topic}: no payload type known"))
}

/// The export half: local samples of the exported topics onto zenoh.
pub struct Exporter {
    lanes: Vec<(
        Box<dyn ExportLane>,
        PayloadId,
        zenoh::pubsub::Publisher<'static>,
    )>,
    sender: u64,
    buffer: Vec<u8>,
    stats: Arc<Stats>,
}

/// A topic to bridge: its service name, payload kind and service settings.
pub type Topic<'a> = (&'a str, &'static dyn Kind, Qos);

/// What each half of a bridge opens on.
pub struct Link<'a> {
    /// The local stack.
    pub bus: &'a Bus,
    /// The zenoh session.
    pub session: &'a zenoh::Session,
    /// The bridge's config: its name and key namespace.
    pub config: &'a BridgeConfig,
    /// The counts both halves share.
    pub stats: Arc<Stats>,
}

/// The payload kind and service settings of each graph topic in `names` (an error names an
/// unknown one).
fn graph_topics(names: &[String]) -> Result<Vec<Topic<'_>>, String> {
    names
        .iter()
        .map(|t| Ok((t.as_str(), kind(t)?, lanes::qos_of(t))))
        .collect()
}

impl Exporter {
    /// Subscribes to every topic of the config's `export` on the link's stack and declares its
    /// zenoh publisher.
    pub fn open(link: Link<'_>) -> Result<Self, String> {
        let config = link.config;
        Self::with_kinds(link, &graph_topics(&config.export)?)
    }

    /// As [`Exporter::open`], for topics of the given kinds and service settings (a
    /// benchmark's own payloads).
    pub fn with_kinds(link: Link<'_>, topics: &[Topic<'_>]) -> Result<Self, String> {
        let mut lanes = Vec::new();
        for (topic, kind, qos) in topics {
            let lane = kind
                .exporter(link.bus, topic, qos)
                .map_err(|e| e.to_string())?;
            let key = link.config.key_of(topic);
            let publisher = link
                .session
                .declare_publisher(key.clone())
                .wait()
                .map_err(|e| format!("zenoh publisher {key}: {e}"))?;
            lanes.push((lane, kind.id(), publisher));
        }
        Ok(Self {
            lanes,
            sender: sender_id(),
            buffer: Vec::new(),
            stats: link.stats,
        })
    }

    /// The wake-ups of the exported topics whose publishers notify their readers.
    pub fn triggers(&self) -> Vec<Trigger> {
        self.lanes
            .iter()
            .filter_map(|(l, _, _)| l.trigger())
            .collect()
    }

    /// Puts every sample received since the last call on zenoh; returns how many.
    pub fn pump(&mut self) -> usize {
        let mut total = 0;
        for (lane, id, publisher) in &mut self.lanes {
            let buffer = &mut self.buffer;
            let stats = &self.stats;
            let sender = self.sender;
            let drained = lane.drain(&mut |payload| {
                envelope::encode(id, sender, monotonic_now_ns(), payload, buffer);
                match publisher.put(buffer.as_slice()).wait() {
                    Ok(()) => stats.exported.fetch_add(1, Ordering::Relaxed),
                    Err(_) => stats.failed.fetch_add(1, Ordering::Relaxed),
                };
            });
            match drained {
                Ok(n) => total += n,
                Err(_) => {
                    self.stats.failed.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        total
    }

    /// Local samples of the exported topics dropped as invalid.
    pub fn rejected(&self) -> u64 {
        self.lanes.iter().map(|(l, _, _)| l.rejected()).sum()
    }
}

/// The import half: samples of the imported topics from zenoh onto the local stack.
pub struct Importer {
    lanes: Vec<(String, PayloadId, Box<dyn ImportLane>)>,
    received: Receiver<(usize, Vec<u8>)>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    /// Per sender, the smallest `receive − send` seen, ns.
    clock_offsets: HashMap<u64, i128>,
    /// Per lane, refusals so far (the log says the 1st, 10th, 100th, ...).
    refusals: Vec<u64>,
    name: String,
    stats: Arc<Stats>,
}

impl Importer {
    /// Declares a zenoh subscriber for every topic of the config's `import` and opens its
    /// publisher on the link's stack.
    pub fn open(link: Link<'_>) -> Result<Self, String> {
        let config = link.config;
        Self::with_kinds(link, &graph_topics(&config.import)?)
    }

    /// As [`Importer::open`], for topics of the given kinds and service settings (a
    /// benchmark's own payloads).
    pub fn with_kinds(link: Link<'_>, topics: &[Topic<'_>]) -> Result<Self, String> {
        let (send, received): (Sender<(usize, Vec<u8>)>, _) = channel();
        let mut lanes = Vec::new();
        let mut subscribers = Vec::new();
        for (i, (topic, kind, qos)) in topics.iter().enumerate() {
            let lane = kind
                .importer(link.bus, topic, qos)
                .map_err(|e| e.to_string())?;
            lanes.push((topic.to_string(), kind.id(), lane));
            let key = link.config.key_of(topic);
            let send = send.clone();
            let subscriber = link
                .session
                .declare_subscriber(key.clone())
                .callback(move |sample| {
                    let _ = send.send((i, sample.payload().to_bytes().into_owned()));
                })
                .wait()
                .map_err(|e| format!("zenoh subscriber {key}: {e}"))?;
            subscribers.push(subscriber);
        }
        Ok(Self {
            refusals: vec![0; lanes.len()],
            lanes,
            received,
            _subscribers: subscribers,
            clock_offsets: HashMap::new(),
            name: link.config.name.clone(),
            stats: link.stats,
        })
    }

    /// Publishes what arrived, waiting up to `timeout` for the first sample; returns how many
    /// samples were published.
    pub fn poll(&mut self, timeout: Duration) -> usize {
        let mut published = 0;
        let mut next = self.received.recv_timeout(timeout).ok();
        while let Some((lane, bytes)) = next {
            if self.import(lane, &bytes) {
                published += 1;
            }
            next = self.received.try_recv().ok();
        }
        published
    }

    /// Checks and publishes one received envelope of lane `i`; returns whether it went out.
    fn import(&mut self, i: usize, bytes: &[u8]) -> bool {
        let (topic, id, lane) = &mut self.lanes[i];
        let envelope = match envelope::decode(bytes, id) {
            Ok(envelope) => envelope,
            Err(refusal) => {
                self.stats.refused.fetch_add(1, Ordering::Relaxed);
                self.refusals[i] += 1;
                say_refusal(&self.name, topic, &refusal, self.refusals[i]);
                return false;
            }
        };
        let now = monotonic_now_ns();
        let seen = now as i128 - envelope.sent_ns as i128;
        let offset = self
            .clock_offsets
            .entry(envelope.sender)
            .and_modify(|o| *o = (*o).min(seen))
            .or_insert(seen);
        let offset = *offset;
        let rebase = |stamp: u64| (stamp as i128 + offset).clamp(0, now as i128) as u64;
        match lane.publish(envelope.payload, &rebase, now) {
            Ok(()) => {
                self.stats.imported.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(ImportError::Invalid(_)) => {
                self.stats.invalid.fetch_add(1, Ordering::Relaxed);
                false
            }
            Err(ImportError::Bus(_)) => {
                self.stats.failed.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }
}

/// Logs the `count`th refusal on `topic` when `count` is 1, 10, 100, ...
fn say_refusal(bridge: &str, topic: &str, refusal: &Refusal, count: u64) {
    let mut n = count;
    while n.is_multiple_of(10) {
        n /= 10;
    }
    if n == 1 {
        motm_bus::say!(
            "{bridge}: refused a sample of {topic} from zenoh: {refusal} ({count} refused on it so far)"
        );
    }
}

/// Runs the bridge of `config` on the stack of `ipc` until SIGTERM or SIGINT: the import half on
/// a thread of its own (woken by zenoh), the export half in the standard service loop (woken by
/// the exported topics' data events, and at 1 kHz for topics that have none), which also
/// publishes the bridge's heartbeat. Returns the counts.
pub fn run(config: &BridgeConfig, ipc: &IpcConfig) -> Result<Arc<Stats>, String> {
    let session = open_session(config)?;
    let stats = Arc::new(Stats::default());
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_send, ready) = channel::<Result<(), String>>();
    let import = {
        let (session, config, ipc, stats, stop) = (
            session.clone(),
            config.clone(),
            ipc.clone(),
            stats.clone(),
            stop.clone(),
        );
        std::thread::Builder::new()
            .name("import".into())
            .spawn(move || {
                let opened = Bus::open_with(&format!("{}-import", config.name), &ipc)
                    .map_err(|e| e.to_string())
                    .and_then(|bus| {
                        Importer::open(Link {
                            bus: &bus,
                            session: &session,
                            config: &config,
                            stats,
                        })
                        .map(|imp| (bus, imp))
                    });
                let (bus, mut importer) = match opened {
                    Ok(opened) => {
                        let _ = ready_send.send(Ok(()));
                        opened
                    }
                    Err(e) => {
                        let _ = ready_send.send(Err(e));
                        return;
                    }
                };
                let mut last_refresh = monotonic_now_ns();
                while !stop.load(Ordering::Relaxed) {
                    importer.poll(Duration::from_millis(20));
                    if monotonic_now_ns() - last_refresh > 100_000_000 {
                        bus.update_connections();
                        last_refresh = monotonic_now_ns();
                    }
                }
            })
            .map_err(|e| format!("cannot start the import thread: {e}"))?
    };
    ready
        .recv()
        .map_err(|_| "the import thread ended".to_owned())??;
    let bus = Bus::open_with(&config.name, ipc).map_err(|e| e.to_string())?;
    let mut exporter = Exporter::open(Link {
        bus: &bus,
        session: &session,
        config,
        stats: stats.clone(),
    })?;
    motm_bus::say!(
        "{}: bridging {} topics out and {} in over zenoh (listen {:?}, connect {:?})",
        config.name,
        config.export.len(),
        config.import.len(),
        config.listen,
        config.connect
    );
    let triggers = exporter.triggers();
    let mut service = ServiceLoop::new(
        &bus,
        LoopConfig {
            deadline: Some(Duration::from_millis(20)),
            ..LoopConfig::with_rate(1000.0)
        },
    )
    .map_err(|e| e.to_string())?;
    let exit = service.run_on_arrival(&triggers, |_| {
        exporter.pump();
        motm_bus::Flow::Continue
    });
    stop.store(true, Ordering::Relaxed);
    let _ = import.join();
    let _ = session.close().wait();
    exit.map_err(|e| e.to_string())?;
    Ok(stats)
}
