//! `logger`: attaches to every iceoryx2 service of a running stack (the prefix from
//! `$MOTM_IPC_PREFIX`) and writes what it reads to a chunked MCAP file (`--out`), serves it
//! live with the Foxglove WebSocket protocol (`--live ADDR`), or both, until SIGTERM/SIGINT.
//! Each record is encoded once ([`ChannelRegistry`]) for both.
//!
//! It never slows a publisher: it only opens existing services (never creates one or asks for
//! settings), takes one subscriber slot per service, and the services overflow safely (a full
//! queue drops its oldest sample, counted in `/logger/stats`). Memory stays bounded: samples
//! are read in place and released at once, and at most one chunk is held before it is written.
//! Services that appear later (a late start, a restart) are attached within a second;
//! heartbeat services are found by listing the prefix's services.

use std::collections::BTreeSet;
use std::fs::File;
use std::net::SocketAddr;
use std::path::PathBuf;

use crate::json::ToJson;
use crate::recorder::{Payload, Recorder, topics};
use crate::replay_log::{self, TrialInfo};
use crate::{
    ChannelRegistry, LiveSink, LoggerConfig, McapSink, Record, SceneLayout, WritebackFile,
};
use clap::Parser;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use motm_bus::{Bus, BusError, Flow, LoopConfig, ServiceLoop, Subscriber};
use motm_msgs::{self as msgs, Message, Topic, TopicSpec, services};

/// Process (and heartbeat) name.
const PROCESS: &str = "logger";

/// How often missing services are looked for again, ns.
const ATTACH_PERIOD_NS: u64 = 1_000_000_000;

/// How often the prefix's live nodes are listed for heartbeat services outside the
/// supervisor's table (the supervisor's own, a process started by hand), ns. Listing opens and
/// parses each node's files, so it is rare; the heartbeats of the processes in the table are
/// tapped as soon as they appear there. In the logger's first [`STARTUP_NS`] the listing runs
/// every [`ATTACH_PERIOD_NS`], while the stack comes up.
const LIST_PERIOD_NS: u64 = 5_000_000_000;

/// The logger's start-up time with the short listing period, ns.
const STARTUP_NS: u64 = 10_000_000_000;

/// How often `/logger/stats` is written, ns.
const STATS_PERIOD_NS: u64 = 1_000_000_000;

/// Command line.
#[derive(Debug, Parser)]
#[command(
    name = PROCESS,
    about = "Log every iceoryx2 service of a running motm stack to an MCAP file, serve it live to Foxglove, or both",
    group(clap::ArgGroup::new("output").required(true).multiple(true).args(["out", "live"]))
)]
struct Cli {
    /// Output MCAP file (overwritten).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Serve the channels live with the Foxglove WebSocket protocol on this address, e.g.
    /// `127.0.0.1:8765` (port 0: any free port, printed at start).
    #[arg(long, value_name = "ADDR")]
    live: Option<SocketAddr>,
    /// Folder holding robots/ and scenarios/ (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// Robot model for the transforms (`frankie`, `fetch`, `husky_ur5`).
    #[arg(long, default_value = "frankie")]
    robot: String,
    /// Scenario file or name, for the platforms and containers of the scene (none when absent).
    #[arg(long)]
    scenario: Option<String>,
    /// Logger settings: a TOML file with keys of the logger config (rates, decimation, chunk size).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Also write the replay log (every sample raw, every task cycle's record) for `motm
    /// replay`; with `--scenario`, `--seed` and `--base-speed` describing the run.
    #[arg(long)]
    replay: bool,
    /// The run's seed (with `--replay`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The run's base speed, m/s (with `--replay`; default: the scenario's).
    #[arg(long)]
    base_speed: Option<f64>,
    /// At exit, write the taps' final counts to this file as one JSON object
    /// (`samples_received`, `samples_lost`, `records_dropped`, `lost_by_service`, ...; the keys
    /// of `/logger/stats`), for `motm run` to report the logger's losses.
    #[arg(long, value_name = "FILE")]
    final_stats: Option<PathBuf>,
}

/// One tapped service: its subscriber (once the service exists), what to do with a sample,
/// and counters.
struct Tap<M: Message> {
    service: String,
    subscriber: Option<Subscriber<M>>,
    handle: fn(&mut Recorder, &str, &M, &mut Vec<Record>),
    /// Last sequence number read from each publisher, to count lost samples.
    last: Vec<(u128, u64)>,
    received: u64,
    lost: u64,
    attach_error: Option<String>,
}

/// A tap of any payload type.
trait Source {
    /// Attaches the subscriber if the service exists now; with `create`, creates the service
    /// (with the settings every process of the stack gives it) when it does not.
    fn attach(&mut self, bus: &Bus, create: bool);
    /// Reads every queued sample into records.
    fn drain(&mut self, recorder: &mut Recorder, out: &mut Vec<Record>) -> Result<(), BusError>;
    /// Service name, samples read, samples lost (queue overflow).
    fn counts(&self) -> (&str, u64, u64);
    /// Whether the subscriber is attached.
    fn attached(&self) -> bool;
}

impl<M: Message> Tap<M> {
    /// A tap of `topic` handling samples with `handle`.
    fn typed(
        topic: Topic<M>,
        handle: fn(&mut Recorder, &str, &M, &mut Vec<Record>),
    ) -> Box<dyn Source> {
        Self::boxed(topic.name(), handle)
    }

    /// A tap of `service` handling samples with `handle`.
    fn boxed(
        service: &str,
        handle: fn(&mut Recorder, &str, &M, &mut Vec<Record>),
    ) -> Box<dyn Source> {
        Box::new(Self {
            service: service.to_owned(),
            subscriber: None,
            handle,
            last: Vec::new(),
            received: 0,
            lost: 0,
            attach_error: None,
        })
    }
}

impl<M: Message> Source for Tap<M> {
    fn attach(&mut self, bus: &Bus, create: bool) {
        if self.subscriber.is_some() {
            return;
        }
        let attached = if create {
            Subscriber::<M>::tap(bus, &self.service, &motm_runtime::qos(&self.service)).map(Some)
        } else {
            Subscriber::<M>::attach(bus, &self.service)
        };
        match attached {
            Ok(subscriber) => self.subscriber = subscriber,
            Err(e) => {
                let text = e.to_string();
                if self.attach_error.as_deref() != Some(&text) {
                    motm_bus::say!("{PROCESS}: {text} (retrying)");
                    self.attach_error = Some(text);
                }
            }
        }
    }

    fn drain(&mut self, recorder: &mut Recorder, out: &mut Vec<Record>) -> Result<(), BusError> {
        let Some(subscriber) = &mut self.subscriber else {
            return Ok(());
        };
        while let Some(sample) = subscriber.receive()? {
            let publisher = sample.publisher_id();
            let seq = sample.header().seq;
            match self.last.iter_mut().find(|(p, _)| *p == publisher) {
                Some((_, last_seq)) => {
                    self.lost += seq.saturating_sub(*last_seq + 1);
                    *last_seq = seq;
                }
                None => self.last.push((publisher, seq)),
            }
            self.received += 1;
            recorder.replay_sample(&self.service, &*sample, out);
            (self.handle)(recorder, &self.service, &sample, out);
        }
        Ok(())
    }

    fn counts(&self) -> (&str, u64, u64) {
        (&self.service, self.received, self.lost)
    }

    fn attached(&self) -> bool {
        self.subscriber.is_some()
    }
}

/// Logs a sample on its JSON channel only.
fn raw<M: Message + ToJson>(
    recorder: &mut Recorder,
    service: &str,
    sample: &M,
    out: &mut Vec<Record>,
) {
    recorder.raw(service, sample, out);
}

/// A tap of `topic` that logs its samples on their JSON channel only, when `M` is its payload.
fn raw_of<M: Message + ToJson>(topic: TopicSpec) -> Option<Box<dyn Source>> {
    (topic.type_name == M::NAME).then(|| Tap::<M>::boxed(topic.name, raw))
}

/// Makes the tap of a topic when its payload is of one type ([`raw_of`]).
type TapMaker = fn(TopicSpec) -> Option<Box<dyn Source>>;

/// The payload types the logger logs as JSON alone (see [`tap_of`]).
const RAW_TAPS: &[TapMaker] = {
    use msgs::*;
    &[
        raw_of::<JointState>,
        raw_of::<GripperState>,
        raw_of::<ArmVelocityCommand>,
        raw_of::<GripperCommand>,
        raw_of::<BaseOdometry>,
        raw_of::<BaseVelocityCommand>,
        raw_of::<TwistCommand>,
        raw_of::<QpStatus>,
        raw_of::<ActiveController>,
        raw_of::<MissionState>,
        raw_of::<SafeStop>,
        raw_of::<DriverStatus>,
    ]
};

/// The tap of one topic with what is made of its samples: the recorder's views of the topics
/// it draws (robot, plan, target, truth, camera, process table) besides their JSON channel,
/// the JSON channel alone for any other topic of a known payload type; `None` otherwise.
fn tap_of(topic: TopicSpec) -> Option<Box<dyn Source>> {
    use motm_msgs::topics as t;
    use services as s;
    Some(match topic.name {
        s::ARM_JOINT_STATE => Tap::typed(t::ARM_JOINT_STATE, |r, name, m, out| {
            r.raw(name, m, out);
            r.joint_state(m, out);
        }),
        s::BASE_ODOMETRY => Tap::typed(t::BASE_ODOMETRY, |r, name, m, out| {
            r.raw(name, m, out);
            r.odometry(m);
        }),
        s::BASE_PLAN => Tap::typed(t::BASE_PLAN, |r, name, m, out| {
            r.raw(name, m, out);
            r.plan(m);
        }),
        s::PERCEPTION_TARGET => Tap::typed(t::PERCEPTION_TARGET, |r, name, m, out| {
            r.raw(name, m, out);
            r.target(m, out);
        }),
        s::CONTROL_REACH_TWIST => Tap::typed(t::CONTROL_REACH_TWIST, |r, name, m, out| {
            r.raw(name, m, out);
            r.reach_twist(m);
        }),
        s::SIM_TRUTH => Tap::typed(t::SIM_TRUTH, |r, name, m, out| {
            r.raw(name, m, out);
            r.truth(m, out);
        }),
        s::CAMERA_IMAGE => Tap::typed(t::CAMERA_IMAGE, |r, _, m, out| r.camera(m, out)),
        s::SUPERVISOR_STATUS => Tap::typed(t::SUPERVISOR_STATUS, |r, name, m, out| {
            r.raw(name, m, out);
            r.supervisor_status(m);
        }),
        _ => return RAW_TAPS.iter().find_map(|of| of(topic)),
    })
}

/// Every fixed service of the stack with what is made of its samples: every topic the graph
/// publishes ([`motm_graph::published_topics`]) and the supervisor's hot-swap services.
fn fixed_taps() -> Vec<Box<dyn Source>> {
    use motm_msgs::topics as t;
    // The cycle records come first, so each pass drains them before the samples: a task
    // publishes a cycle's record after its outputs, and its inputs before that, so every record
    // a pass reads has its samples queued already and read in the same pass. (Drained last, a
    // record published during the pass would leave its samples to the next pass, and the last
    // pass at shutdown would log records whose samples it never read.)
    let mut taps: Vec<Box<dyn Source>> = vec![Tap::typed(t::REPLAY_CYCLES, |r, _, m, out| {
        r.task_cycle(m, out)
    })];
    taps.extend(
        motm_graph::published_topics()
            .into_iter()
            .filter_map(|topic| {
                let tap = tap_of(topic);
                if tap.is_none() {
                    motm_bus::say!(
                        "{PROCESS}: {} not logged: no tap for its payload {}",
                        topic.name,
                        topic.type_name
                    );
                }
                tap
            }),
    );
    taps.push(Tap::typed(t::SUPERVISOR_SWAP_REQUEST, raw));
    taps.push(Tap::typed(t::SUPERVISOR_SWAP_STATUS, raw));
    taps
}

/// Finds the heartbeat services to tap. Each process's bus node is named after the process
/// and publishes `heartbeat(name)`; names come from the supervisor's table at once and from a
/// listing of the prefix's live nodes (see [`LIST_PERIOD_NS`]). A name without a heartbeat
/// service (a tool such as `motm status`) is tried again at the next listing.
/// Whether `service` is one of the graph's topics or the cycle records: what the replay log
/// must hold from the first sample.
fn is_graph_service(service: &str) -> bool {
    service == services::REPLAY_CYCLES
        || motm_graph::published_topics()
            .iter()
            .any(|t| t.name == service)
}

struct HeartbeatDiscovery {
    /// The iceoryx2 config of the prefix (read once: it does not change under a running stack).
    config: iceoryx2::config::Config,
    /// Heartbeat services already tapped.
    tapped: BTreeSet<String>,
    started_ns: u64,
    last_list_ns: Option<u64>,
}

impl HeartbeatDiscovery {
    /// Discovery on `bus`'s prefix, starting at `now_ns`.
    fn new(bus: &Bus, now_ns: u64) -> Result<Self, BusError> {
        Ok(Self {
            config: bus.ipc_config().iceoryx2()?,
            tapped: BTreeSet::new(),
            started_ns: now_ns,
            last_list_ns: None,
        })
    }

    /// Adds to `taps` a tap for every heartbeat service found since the last call.
    fn poll(
        &mut self,
        now_ns: u64,
        bus: &Bus,
        recorder: &mut Recorder,
        taps: &mut Vec<Box<dyn Source>>,
    ) {
        let mut processes = recorder.take_new_processes();
        let period = if now_ns.saturating_sub(self.started_ns) < STARTUP_NS {
            ATTACH_PERIOD_NS
        } else {
            LIST_PERIOD_NS
        };
        if self
            .last_list_ns
            .is_none_or(|t| now_ns.saturating_sub(t) >= period)
        {
            self.last_list_ns = Some(now_ns);
            let _ = Node::<ipc::Service>::list(&self.config, |state| {
                if let NodeState::Alive(view) = state
                    && let Some(details) = view.details()
                {
                    processes.push(details.name().as_str().to_owned());
                }
                CallbackProgression::Continue
            });
        }
        for process in processes {
            let service = services::heartbeat(&process);
            if self.tapped.contains(&service) {
                continue;
            }
            let mut tap = Tap::<msgs::Heartbeat>::boxed(&service, raw);
            tap.attach(bus, false);
            if tap.attached() {
                self.tapped.insert(service);
                taps.push(tap);
            }
        }
    }
}

/// Loads the settings, the robot and the scene layout.
fn setup(cli: &Cli) -> Result<(LoggerConfig, Recorder, Option<TrialInfo>), String> {
    let config_dir = motm_core::resolve_config_dir(cli.config_dir.as_deref());
    let config: LoggerConfig = match &cli.settings {
        Some(path) => {
            let text =
                std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
            toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?
        }
        None => LoggerConfig::default(),
    };
    let replay = config.replay || cli.replay;
    let config = LoggerConfig {
        replay,
        // A replay log must hold every sample: the logger then competes for the CPU like the
        // stack's processes instead of waiting for idle time.
        idle_scheduling: config.idle_scheduling && !replay,
        ..config
    };
    for (key, value) in [
        ("poll_rate_hz", config.poll_rate_hz),
        ("raw_rate_hz", config.raw_rate_hz),
        ("tf_rate_hz", config.tf_rate_hz),
        ("scene_rate_hz", config.scene_rate_hz),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(format!("logger settings: {key} must be > 0, got {value}"));
        }
    }
    let robot =
        motm_core::robot::Robot::load(&config_dir, &cli.robot).map_err(|e| e.to_string())?;
    let mut trial = None;
    let layout = match &cli.scenario {
        Some(name) => {
            let path = motm_sim::scenario_path(&config_dir, name);
            let scenario = motm_sim::Scenario::from_file(&path).map_err(|e| e.to_string())?;
            trial = Some(TrialInfo {
                scenario: path,
                seed: cli.seed,
                base_speed: cli.base_speed.unwrap_or(scenario.base_speed),
            });
            SceneLayout::from_scenario(&scenario)
        }
        None => SceneLayout::default(),
    };
    let trial = match (config.replay, trial) {
        (false, _) => None,
        (true, Some(trial)) => Some(trial),
        (true, None) => return Err("--replay: needs --scenario (the run replay rebuilds)".into()),
    };
    Ok((config.clone(), Recorder::new(robot, layout, config), trial))
}

/// Monotonic → Unix time offset, ns.
fn unix_offset_ns() -> i128 {
    let unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    unix - i128::from(motm_bus::monotonic_now_ns())
}

/// The `logger` process: parses its flags and taps the stack until SIGTERM or SIGINT.
pub fn main() {
    let cli = Cli::parse();
    let (config, mut recorder, trial) = match setup(&cli) {
        Ok(setup) => setup,
        Err(e) => {
            motm_bus::say!("{PROCESS}: {e}");
            std::process::exit(2);
        }
    };
    if config.idle_scheduling {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: sched_setscheduler(2) reads `param` only. A failure leaves the normal
        // policy, which is only less polite.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } != 0 {
            motm_bus::say!("{PROCESS}: cannot switch to SCHED_IDLE; running at normal priority");
        }
        // ioprio_set(IOPRIO_WHO_PROCESS, self, IOPRIO_CLASS_IDLE): the disk only when idle.
        const IOPRIO_WHO_PROCESS: libc::c_long = 1;
        const IOPRIO_IDLE: libc::c_long = 3 << 13;
        // SAFETY: ioprio_set(2) takes plain integers. A failure keeps the normal I/O class.
        if unsafe { libc::syscall(libc::SYS_ioprio_set, IOPRIO_WHO_PROCESS, 0, IOPRIO_IDLE) } != 0 {
            motm_bus::say!(
                "{PROCESS}: cannot switch to the idle I/O class; keeping the normal one"
            );
        }
    }
    if let Err(e) = run(&cli, &config, &mut recorder, trial) {
        motm_bus::say!("{PROCESS}: {e}");
        std::process::exit(1);
    }
}

/// Where the records go: each is encoded once, then written to the file and the live view.
struct Sinks {
    channels: ChannelRegistry,
    file: Option<(PathBuf, McapSink<WritebackFile>)>,
    live: Option<LiveSink>,
}

impl Sinks {
    /// Creates the file and binds the live view that `cli` asks for.
    fn open(cli: &Cli, config: &LoggerConfig) -> Result<Self, String> {
        let file = match &cli.out {
            Some(path) => {
                let name = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
                let file = File::create(path).map_err(|e| name(&e))?;
                let file = WritebackFile::new(file, config.writeback_bytes);
                let sink = McapSink::new(file, config.chunk_bytes, config.flush_interval_s)
                    .map_err(|e| name(&e))?;
                Some((path.clone(), sink))
            }
            None => None,
        };
        let live = match cli.live {
            Some(addr) => {
                let live = LiveSink::bind(addr, config.live.clone())
                    .map_err(|e| format!("--live {addr}: {e}"))?;
                let bound = live
                    .local_addr()
                    .map_err(|e| format!("--live {addr}: {e}"))?;
                motm_bus::say!("{PROCESS}: Foxglove WebSocket live view on ws://{bound}");
                Some(live)
            }
            None => None,
        };
        Ok(Self {
            channels: ChannelRegistry::new(unix_offset_ns()),
            file,
            live,
        })
    }

    /// Encodes `record` and hands it to every sink.
    fn write(&mut self, record: &Record) -> Result<(), String> {
        let message = self.channels.encode(record);
        if let Some((path, file)) = &mut self.file {
            file.write(&message)
                .map_err(|e| format!("{}: {e}", path.display()))?;
        }
        // The replay log's raw samples go to the file only: no viewer decodes them.
        if let Some(live) = &mut self.live
            && !matches!(record.payload, Payload::Raw(..))
        {
            live.write(&message);
        }
        Ok(())
    }

    /// End of a cycle at monotonic `now_ns`: writes out a due chunk, serves the live clients.
    fn end_cycle(&mut self, now_ns: u64) -> Result<(), String> {
        if let Some(live) = &mut self.live {
            live.poll(now_ns);
        }
        match &mut self.file {
            Some((path, file)) => file
                .flush_if_due(now_ns)
                .map_err(|e| format!("{}: {e}", path.display())),
            None => Ok(()),
        }
    }

    /// Finishes the file; what was written, for the exit message.
    fn finish(self) -> Result<String, String> {
        let mut done = format!("encoded {} messages", self.channels.encoded);
        if let Some((path, file)) = self.file {
            let written = file.written;
            file.finish()
                .map_err(|e| format!("{}: {e}", path.display()))?;
            done += &format!("; wrote {written} to {}", path.display());
        }
        if let Some(live) = self.live {
            let stats = live.stats();
            live.close();
            done += &format!(
                "; live view: {} connections, {} messages sent, {} dropped",
                stats.connections, stats.sent_messages, stats.dropped_messages
            );
        }
        Ok(done)
    }
}

/// Taps the bus until SIGTERM/SIGINT, then finishes the file.
fn run(
    cli: &Cli,
    config: &LoggerConfig,
    recorder: &mut Recorder,
    trial: Option<TrialInfo>,
) -> Result<(), String> {
    let mut sinks = Sinks::open(cli, config)?;
    recorder.set_unix_offset(sinks.channels.unix_offset_ns());
    if let Some(trial) = trial {
        sinks.write(&Record {
            topic: replay_log::TRIAL_TOPIC.into(),
            stamp_ns: motm_bus::monotonic_now_ns(),
            payload: Payload::Json(serde_json::to_value(trial).map_err(|e| e.to_string())?),
        })?;
    }
    let bus = Bus::open(PROCESS).map_err(|e| e.to_string())?;
    let mut taps = fixed_taps();
    // The replay log must hold every sample from the first: the logger creates the graph's
    // services itself, before the stack starts (`motm run` waits for its heartbeat, which
    // appears after this).
    let created: Vec<bool> = taps
        .iter()
        .map(|tap| config.replay && is_graph_service(tap.counts().0))
        .collect();
    for (tap, &create) in taps.iter_mut().zip(&created) {
        tap.attach(&bus, create);
    }
    // Reading never waits for the disk: a writer thread owns the file and the live view, and
    // this loop hands it each cycle's records. Its queue holds `WRITER_QUEUE_CYCLES` cycles;
    // a cycle that finds it full is dropped and counted (`records_dropped`).
    let (batches, queue) = std::sync::mpsc::sync_channel::<Batch>(WRITER_QUEUE_CYCLES);
    let writer = std::thread::Builder::new()
        .name("logger-writer".into())
        .spawn(move || write_batches(sinks, queue))
        .map_err(|e| format!("cannot start the writer thread: {e}"))?;
    let mut records = Vec::new();
    let mut dropped = 0u64;
    let mut writer_gone = false;
    let mut last_attach: Option<u64> = None;
    let mut discovery =
        HeartbeatDiscovery::new(&bus, motm_bus::monotonic_now_ns()).map_err(|e| e.to_string())?;
    let mut last_stats: Option<u64> = None;
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(config.poll_rate_hz))
        .map_err(|e| e.to_string())?;
    let exit = service
        .run_periodic(|cycle| {
            let now = cycle.now_ns;
            discovery.poll(now, &bus, recorder, &mut taps);
            if last_attach.is_none_or(|t| now.saturating_sub(t) >= ATTACH_PERIOD_NS) {
                last_attach = Some(now);
                for tap in &mut taps {
                    tap.attach(&bus, false);
                }
            }
            for tap in &mut taps {
                if let Err(e) = tap.drain(recorder, &mut records) {
                    motm_bus::say!("{PROCESS}: {e}");
                }
            }
            let stats = last_stats
                .is_none_or(|t| now.saturating_sub(t) >= STATS_PERIOD_NS)
                .then(|| {
                    last_stats = Some(now);
                    tap_stats(&taps, recorder, dropped)
                });
            let batch = Batch {
                now_ns: now,
                records: std::mem::take(&mut records),
                stats,
            };
            match batches.try_send(batch) {
                Ok(()) => Flow::Continue,
                Err(std::sync::mpsc::TrySendError::Full(batch)) => {
                    dropped += batch.records.len() as u64;
                    Flow::Continue
                }
                Err(std::sync::mpsc::TrySendError::Disconnected(_)) => {
                    writer_gone = true;
                    Flow::Stop
                }
            }
        })
        .map_err(|e| e.to_string())?;
    drop(batches);
    let done = writer
        .join()
        .map_err(|_| "the writer thread panicked".to_string())??;
    if writer_gone {
        return Err("the writer stopped".into());
    }
    let stats = tap_stats(&taps, recorder, dropped);
    motm_bus::say!(
        "{PROCESS}: {exit:?}; {done}; {} samples read, {} lost; {dropped} records dropped",
        stats["samples_received"],
        stats["samples_lost"]
    );
    if let Some(file) = &cli.final_stats {
        std::fs::write(file, serde_json::Value::Object(stats).to_string())
            .map_err(|e| format!("--final-stats {}: {e}", file.display()))?;
    }
    Ok(())
}

/// Cycles of records the writer thread's queue holds (2 s at the default 250 Hz).
const WRITER_QUEUE_CYCLES: usize = 500;

/// One cycle of the reading loop, for the writer thread.
struct Batch {
    /// The cycle's time, ns.
    now_ns: u64,
    /// The cycle's records.
    records: Vec<Record>,
    /// The taps' part of `/logger/stats`, when one is due.
    stats: Option<serde_json::Map<String, serde_json::Value>>,
}

/// The writer thread: every batch into the sinks, then the file's end; the closing summary.
fn write_batches(
    mut sinks: Sinks,
    batches: std::sync::mpsc::Receiver<Batch>,
) -> Result<String, String> {
    for batch in batches {
        for record in &batch.records {
            sinks.write(record)?;
        }
        if let Some(mut stats) = batch.stats {
            let live = sinks.live.as_ref().map(LiveSink::stats).unwrap_or_default();
            stats.insert("records_written".into(), sinks.channels.encoded.into());
            stats.insert("raised_stamps".into(), sinks.channels.raised_stamps.into());
            stats.insert("live_clients".into(), live.clients.into());
            stats.insert("live_sent_messages".into(), live.sent_messages.into());
            stats.insert("live_dropped_messages".into(), live.dropped_messages.into());
            sinks.write(&Record {
                topic: topics::LOGGER_STATS.into(),
                stamp_ns: batch.now_ns,
                payload: Payload::Json(serde_json::Value::Object(stats)),
            })?;
        }
        sinks.end_cycle(batch.now_ns)?;
    }
    sinks.finish()
}

/// The taps' part of the `/logger/stats` record (the writer adds its own counters).
fn tap_stats(
    taps: &[Box<dyn Source>],
    recorder: &Recorder,
    dropped: u64,
) -> serde_json::Map<String, serde_json::Value> {
    let mut lost_by_service = serde_json::Map::new();
    let (mut received, mut lost, mut attached) = (0, 0, 0);
    for tap in taps {
        let (name, r, l) = tap.counts();
        received += r;
        lost += l;
        attached += u64::from(r > 0);
        if l > 0 {
            lost_by_service.insert(name.to_owned(), l.into());
        }
    }
    let mut stats = serde_json::Map::new();
    stats.insert("services_with_samples".into(), attached.into());
    stats.insert("samples_received".into(), received.into());
    stats.insert("samples_lost".into(), lost.into());
    stats.insert("records_dropped".into(), dropped.into());
    stats.insert(
        "bad_cycle_records".into(),
        recorder.bad_cycle_records().into(),
    );
    stats.insert("lost_by_service".into(), lost_by_service.into());
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fixed_taps_are_the_graphs_published_topics_the_swap_services_and_the_cycle_records() {
        let tapped: Vec<String> = fixed_taps()
            .iter()
            .map(|tap| tap.counts().0.to_owned())
            .collect();
        // The cycle records first (see `fixed_taps`).
        let mut expected = vec![services::REPLAY_CYCLES.to_owned()];
        expected.extend(
            motm_graph::published_topics()
                .iter()
                .map(|t| t.name.to_owned()),
        );
        expected.extend([
            services::SUPERVISOR_SWAP_REQUEST.to_owned(),
            services::SUPERVISOR_SWAP_STATUS.to_owned(),
        ]);
        assert_eq!(tapped, expected);
        assert!(tapped.iter().any(|t| t == services::SIM_TRUTH));
    }

    #[test]
    fn a_topic_of_an_unknown_payload_type_gets_no_tap() {
        let unknown = TopicSpec {
            name: "motm/v1/test/unknown",
            type_name: "NoSuchMessage",
        };
        assert!(tap_of(unknown).is_none());
        let known = TopicSpec {
            name: "motm/v1/test/known",
            type_name: <msgs::SafeStop as Message>::NAME,
        };
        assert_eq!(tap_of(known).unwrap().counts().0, "motm/v1/test/known");
    }
}
