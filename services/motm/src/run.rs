//! `motm run`: the deployed stack against the simulated world. It starts the supervisor (which
//! starts every process of the stack config), waits for sim-world's verdict, prints the trial
//! metrics as `motm trial` does plus the process table, the drivers' limit violations and the
//! largest command gap, then stops everything and removes the run's iceoryx2 resources.
//!
//! Each run uses its own iceoryx2 prefix (`$MOTM_IPC_PREFIX`, or `motm<pid>_`), so runs and
//! tests can go on side by side. The prefix is recorded in `<tmp>/motm-stacks/` while the run
//! lasts, for `motm status`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use clap::Args;
use motm_bus::{Bus, Flow, IpcConfig, Latest, LoopConfig, Qos, ServiceLoop, Subscriber};
use motm_msgs::{
    DriverStatus, Heartbeat, QpStatus, SimOutcome, SimTruth, SupervisorStatus, services,
};
use motm_sim::Scenario;
use motm_sim::experiment::TrialResult;
use motm_supervisor::{StackConfig, binaries};
use serde::Serialize;

use crate::CliError;
use crate::faults::{DriverTotals, FaultRecord, FaultRunner, SafeStopReport, check_targets};
use crate::swap::{SwapClient, SwapReport, parse_plan};

/// Arguments of `motm run`.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Stack config: a file, or a name in the config folder (`frankie`, `fetch`, `husky_ur5`).
    #[arg(long, default_value = "frankie")]
    pub config: String,
    /// Scenario file or name, or `generated:<robot>` (the generated layout of the seed;
    /// default: the stack config's `scenario`).
    #[arg(long)]
    pub scenario: Option<String>,
    /// Base speed v_F, m/s (default: the scenario's `base_speed`).
    #[arg(long, allow_negative_numbers = true)]
    pub base_speed: Option<f64>,
    /// Control rate, Hz (default: the stack config's `control_rate_hz`).
    #[arg(long, allow_negative_numbers = true)]
    pub rate: Option<f64>,
    /// RNG seed (default: the stack config's `seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Give up after this much wall-clock time, s (default: twice the scenario's time limit).
    #[arg(long, allow_negative_numbers = true)]
    pub timeout: Option<f64>,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Inject a fault (repeatable): `kill:SERVICE@WHEN`, `stop:SERVICE@WHEN+DURATION`
    /// (SIGSTOP, then SIGCONT after DURATION) or `nan:TOPIC@WHEN` (one NaN sample). WHEN is
    /// SECONDS of simulated time, or a mission event and a delay: `grasp|place|press[#N][+SECONDS]`
    /// (`kill:qp-resolver@grasp+0.25`: a quarter second into the first grasp closure).
    #[arg(long = "fault", value_name = "FAULT")]
    pub faults: Vec<String>,
    /// Hot-swap a controller during the run: `PROCESS:VARIANT@SECONDS` (wall-clock seconds
    /// after the stack started), e.g. `final-phase:press-button@12`; may be repeated.
    #[arg(long = "swap", value_name = "PROCESS:VARIANT@SECONDS")]
    pub swaps: Vec<String>,
    /// Also log every service of the run to this MCAP file (the `logger` process).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Also serve every service of the run live with the Foxglove WebSocket protocol on ADDR
    /// (default 127.0.0.1:8765; Foxglove: Open connection → `ws://ADDR`). With `--mcap`, the
    /// same logger process writes the file and serves the view.
    #[arg(
        long,
        value_name = "ADDR",
        num_args = 0..=1,
        default_missing_value = crate::run_mcap::DEFAULT_LIVE_ADDR
    )]
    pub live: Option<std::net::SocketAddr>,
    /// The robot hardware: `sim` (the drivers' sim backends on sim-world), or `fake` (the
    /// stack config's `fake_hardware` stack: fake robots speaking the real protocols on
    /// loopback over sim-world's physics, the drivers on their real backends).
    #[arg(long, value_enum, default_value_t = Hardware::Sim)]
    pub hardware: Hardware,
    /// Run this process as if on another host (repeatable), e.g. `--remote perception`: on
    /// its own iceoryx2 prefix (`<prefix>remote_`), its topics bridged to the stack by two
    /// `motm-zenoh` peers over loopback TCP; the report lists `zenoh-stack` and `zenoh-remote`.
    #[arg(long, value_name = "PROCESS")]
    pub remote: Vec<String>,
}

/// What the drivers drive in `motm run`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Hardware {
    /// sim-world's hardware topics.
    Sim,
    /// Fake robots on loopback sockets, over sim-world's physics.
    Fake,
}

impl Default for RunArgs {
    /// The arguments of a bare `motm run`.
    fn default() -> Self {
        use clap::{Args as _, FromArgMatches};
        let matches = Self::augment_args(clap::Command::new("run")).get_matches_from(["run"]);
        Self::from_arg_matches(&matches).expect("the defaults of motm run parse")
    }
}

/// One process's figures, from its last heartbeat and the supervisor's table.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ProcessReport {
    /// Process name.
    pub name: String,
    /// Pid of the last instance seen.
    pub pid: u32,
    /// Restarts by the supervisor.
    pub restarts: u32,
    /// Cycles of the last instance.
    pub cycles: u64,
    /// Deadline misses of the last instance.
    pub deadline_misses: u64,
    /// 99th percentile cycle time of the last instance, µs.
    pub p99_cycle_us: f64,
    /// Messages its bus dropped as invalid.
    pub rejected_messages: u64,
}

/// What `motm run --json` prints.
#[derive(Debug, Clone, Serialize)]
pub struct RunReport {
    /// The trial metrics, as `motm trial` prints them.
    #[serde(flatten)]
    pub trial: TrialResult,
    /// Scenario name.
    pub scenario: String,
    /// Base speed, m/s.
    pub base_speed: f64,
    /// Control rate, Hz.
    pub control_rate_hz: f64,
    /// Every supervised process plus the supervisor.
    pub processes: Vec<ProcessReport>,
    /// Commands that reached a driver beyond a limit (arm plus base).
    pub limit_violations: u64,
    /// Driver outputs that broke a limit (arm plus base; must be 0).
    pub output_violations: u64,
    /// Longest gap between consecutive commands at a driver, ms.
    pub max_command_gap_ms: f64,
    /// Times a driver turned from the QP resolver it followed to the other instance (the
    /// primary's hot standby, or back), the most at any driver.
    pub resolver_takeovers: u32,
    /// Longest interval between the commands a driver took across a takeover, ms: about a
    /// control period plus the driver's wait for the instance it followed.
    pub max_takeover_interval_ms: f64,
    /// What the drivers drove: `sim`, or `fake` (the stack has fake robots).
    pub hardware: Hardware,
    /// The `--backend` of each driver.
    pub backends: std::collections::BTreeMap<String, String>,
    /// Commands beyond a limit that the fake robots saw (every instance of each; 0 without
    /// fake robots).
    pub fake_robot_violations: u64,
    /// The run's iceoryx2 prefix.
    pub ipc_prefix: String,
    /// Files of the prefix left in /dev/shm or iceoryx2's folder after the run (must be 0).
    pub stale_shm_entries: usize,
    /// The watchdog's safe-stops after the stack came up.
    pub safe_stops: SafeStopReport,
    /// The `--fault` faults and what followed each.
    pub faults_injected: Vec<FaultRecord>,
    /// The hot swaps requested with `--swap`, with their measured command gap.
    pub swaps: Vec<SwapReport>,
    /// What the logger read and lost (`--mcap`, `--live`); null without a logger.
    pub logger: Option<crate::run_mcap::LoggerLoss>,
}

/// Frame-to-command latencies of one run, from the QP status stream, µs.
#[derive(Debug, Clone, Default)]
pub struct Latencies {
    /// From a frame's publication (`image_published_ns`) to the first QP command computed
    /// from it (one sample per frame that reached a command).
    pub frame_us: Vec<f64>,
    /// From the exposure of the image behind the target (`image_stamp_ns`) to each QP
    /// command that used it (one sample per QP cycle with a perceived target).
    pub exposure_us: Vec<f64>,
    /// Publication time of the newest frame seen in a status, ns.
    last_frame_ns: u64,
}

impl Latencies {
    /// Takes in one QP status: its command was sent no later than the status
    /// (`published_ns`; the cycle's stamp from a resolver that does not fill it in).
    pub fn record(&mut self, status: &QpStatus) {
        let stamp = match status.published_ns {
            0 => status.header.stamp_ns,
            sent => sent,
        };
        if status.image_stamp_ns > 0 {
            self.exposure_us
                .push(stamp.saturating_sub(status.image_stamp_ns) as f64 / 1e3);
        }
        if status.image_published_ns > self.last_frame_ns {
            self.last_frame_ns = status.image_published_ns;
            self.frame_us
                .push(stamp.saturating_sub(status.image_published_ns) as f64 / 1e3);
        }
    }
}

/// Latest samples of everything `motm run` watches.
struct Watch {
    truth: Latest<SimTruth>,
    status: Latest<SupervisorStatus>,
    arm_driver: Latest<DriverStatus>,
    base_driver: Latest<DriverStatus>,
    heartbeats: Vec<(String, Latest<Heartbeat>)>,
    /// Last heartbeat seen per process (kept when the process goes away).
    last_beats: Vec<Option<Heartbeat>>,
    /// QP status stream, when end-to-end latency is measured (`motm bench e2e`).
    qp_status: Option<Subscriber<QpStatus>>,
    /// Frame-to-command latencies seen so far.
    latencies: Latencies,
    /// The drivers' counters over all their instances.
    drivers: DriverTotals,
}

impl Watch {
    fn new(bus: &Bus, names: &[String], measure_latency: bool) -> Result<Self, motm_bus::BusError> {
        let qos = Qos::default();
        Ok(Self {
            qp_status: if measure_latency {
                Some(Subscriber::new(bus, services::CONTROL_QP_STATUS, &qos)?)
            } else {
                None
            },
            latencies: Latencies::default(),
            drivers: DriverTotals::default(),
            truth: Latest::new(bus, services::SIM_TRUTH, &qos)?,
            status: Latest::new(bus, services::SUPERVISOR_STATUS, &qos)?,
            arm_driver: Latest::new(bus, services::ARM_DRIVER_STATUS, &qos)?,
            base_driver: Latest::new(bus, services::BASE_DRIVER_STATUS, &qos)?,
            heartbeats: names
                .iter()
                .map(|n| Ok((n.clone(), Latest::new(bus, &services::heartbeat(n), &qos)?)))
                .collect::<Result<_, motm_bus::BusError>>()?,
            last_beats: vec![None; names.len()],
        })
    }

    /// Takes in everything that arrived.
    fn update(&mut self) {
        // A failed read keeps the previous values; the report says what was seen.
        let _ = self.truth.update();
        if let Some(qp) = self.qp_status.as_mut() {
            while let Ok(Some(sample)) = qp.receive() {
                self.latencies.record(&sample);
            }
        }
        let _ = self.status.update();
        let _ = self.arm_driver.update();
        let _ = self.base_driver.update();
        self.drivers
            .update(services::ARM_DRIVER_STATUS, &self.arm_driver);
        self.drivers
            .update(services::BASE_DRIVER_STATUS, &self.base_driver);
        for ((_, beat), last) in self.heartbeats.iter_mut().zip(&mut self.last_beats) {
            let _ = beat.update();
            if let Some(b) = beat.get() {
                *last = Some(*b);
            }
        }
    }

    /// The process table for the report.
    fn processes(&self) -> Vec<ProcessReport> {
        let table = self.status.get();
        self.heartbeats
            .iter()
            .zip(&self.last_beats)
            .map(|((name, _), beat)| {
                let row = table.and_then(|t| t.processes().iter().find(|p| p.name() == name));
                ProcessReport {
                    name: name.clone(),
                    pid: beat.map_or(row.map_or(0, |r| r.pid), |b| b.pid),
                    restarts: row.map_or(0, |r| r.restarts),
                    cycles: beat.map_or(0, |b| b.cycles),
                    deadline_misses: beat.map_or(0, |b| b.deadline_misses),
                    p99_cycle_us: beat.map_or(0.0, |b| b.p99_cycle_ns as f64 / 1000.0),
                    rejected_messages: beat.map_or(0, |b| b.rejected_messages),
                }
            })
            .collect()
    }
}

/// The failure name of an outcome (as `motm trial` names it), `None` on success or running.
fn failure_name(outcome: SimOutcome) -> Option<&'static str> {
    match outcome {
        SimOutcome::Running | SimOutcome::Success => None,
        SimOutcome::KnockedOff => Some("knocked_off"),
        SimOutcome::MissedGrasp => Some("missed_grasp"),
        SimOutcome::DroppedOutside => Some("dropped_outside"),
        SimOutcome::BaseCollision => Some("base_collision"),
        SimOutcome::Timeout => Some("timeout"),
        SimOutcome::TaskFailed => Some("task_failed"),
    }
}

/// The trial metrics from sim-world's last truth (or a failure when none came).
fn trial_result(truth: Option<&SimTruth>, failure: Option<String>, wall_s: f64) -> TrialResult {
    let Some(t) = truth else {
        return TrialResult {
            success: false,
            failure: Some(failure.unwrap_or_else(|| "no_truth_from_sim_world".into())),
            task_time_s: 0.0,
            mtph: 0.0,
            ee_acc_mean: 0.0,
            ee_acc_max: 0.0,
            ee_acc_filter: String::new(),
            sim_time_s: 0.0,
            wall_time_s: wall_s,
            round_trips_s: Vec::new(),
            mishaps: Vec::new(),
        };
    };
    let outcome = t.outcome().unwrap_or(SimOutcome::Running);
    let success = outcome == SimOutcome::Success && failure.is_none();
    let failure = failure.or_else(|| match outcome {
        SimOutcome::Running => Some("not_finished".into()),
        other => failure_name(other).map(str::to_owned),
    });
    let count = (t.object_count as usize).min(t.object_placed_time.len());
    let mut placed: Vec<f64> = t.object_placed_time[..count]
        .iter()
        .copied()
        .filter(|&p| p >= 0.0)
        .collect();
    placed.sort_by(f64::total_cmp);
    let round_trips_s = placed
        .iter()
        .scan(0.0, |last, &p| {
            let trip = p - *last;
            *last = p;
            Some(trip)
        })
        .collect();
    TrialResult {
        success,
        failure,
        task_time_s: t.task_time,
        mtph: if success && t.task_time > 0.0 {
            3600.0 / t.task_time
        } else {
            0.0
        },
        ee_acc_mean: t.ee_acc_mean,
        ee_acc_max: t.ee_acc_max,
        ee_acc_filter: "sim-world".into(),
        sim_time_s: t.sim_time,
        wall_time_s: wall_s,
        round_trips_s,
        mishaps: Vec::new(),
    }
}

/// The folder where running stacks record their prefix (for `motm status`).
pub fn registry_dir() -> PathBuf {
    std::env::temp_dir().join("motm-stacks")
}

/// The binary (and package) of the zenoh bridge.
const BRIDGE_BINARY: &str = "motm-zenoh";

/// Makes sure every binary is there, building it with `$CARGO` when run through Cargo.
/// The scenario file the services read: the named or given file, or a generated layout
/// (`generated:<robot>`, the one of `seed`) written to the temporary folder, since every
/// service loads the scenario from its file.
fn scenario_file(config_dir: &Path, scenario: &str, seed: u64) -> Result<PathBuf, CliError> {
    let Some(robot) = motm_sim::generated::robot_of(scenario) else {
        return Ok(motm_sim::scenario_path(config_dir, scenario));
    };
    let path = std::env::temp_dir().join(format!(
        "motm-generated-{robot}-{seed}-{}.toml",
        std::process::id()
    ));
    std::fs::write(&path, motm_sim::generated::layout_toml(robot, seed))
        .map_err(|e| CliError::Failed(format!("cannot write {}: {e}", path.display())))?;
    Ok(path)
}

fn ensure_binaries(stack: &StackConfig, remote: bool) -> Result<PathBuf, CliError> {
    let dir = binaries::own_dir()
        .map_err(|e| CliError::Failed(format!("cannot find own executable: {e}")))?;
    let mut names = vec!["supervisor".to_string()];
    names.extend(stack.processes.iter().map(|p| p.name.clone()));
    if remote {
        names.push(BRIDGE_BINARY.into());
    }
    let missing = binaries::missing(&dir, names.iter().map(String::as_str));
    if missing.is_empty() {
        return Ok(dir);
    }
    let package_of = |name: &str| match stack.process(name) {
        Some(p) => p.package(),
        None if name == BRIDGE_BINARY => BRIDGE_BINARY.to_owned(),
        None => format!("motm-{name}"),
    };
    let packages: Vec<String> = missing.iter().map(|n| package_of(n)).collect();
    if let Some(cargo) = std::env::var_os("CARGO") {
        motm_bus::say!(
            "motm run: building the missing service binaries ({}) with cargo",
            missing.join(", ")
        );
        if let Err(e) = binaries::cargo_build(Path::new(&cargo), &dir, &packages) {
            motm_bus::say!("motm run: {e}");
        }
    }
    let still = binaries::missing(&dir, names.iter().map(String::as_str));
    if still.is_empty() {
        Ok(dir)
    } else {
        Err(CliError::Failed(format!(
            "service binaries missing in {}: {} (build them with `cargo build -p {}`)",
            dir.display(),
            still.join(", "),
            still
                .iter()
                .map(|n| package_of(n))
                .collect::<Vec<_>>()
                .join(" -p ")
        )))
    }
}

/// Sends `sig` to `pid`.
fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill(2) has no memory-safety preconditions.
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// Stops the supervisor (which stops the stack): SIGTERM, then SIGKILL after `grace`. The
/// logger is stopped the same way.
pub(crate) fn stop_supervisor(
    supervisor: &mut Child,
    grace: Duration,
) -> Option<std::process::ExitStatus> {
    if let Ok(Some(status)) = supervisor.try_wait() {
        return Some(status);
    }
    signal(supervisor.id(), libc::SIGTERM);
    let deadline = Instant::now() + grace;
    while Instant::now() < deadline {
        if let Ok(Some(status)) = supervisor.try_wait() {
            return Some(status);
        }
        // Shutdown only: a short sleep between reaping attempts.
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = supervisor.kill();
    supervisor.wait().ok()
}

/// `motm run`.
/// Runs the stack once; `measure_latency` also records the camera-to-command latency of every
/// QP cycle (the watch loop then runs faster than the control rate so no sample is missed).
pub fn run_stack(
    config_dir: &Path,
    args: &RunArgs,
    measure_latency: bool,
) -> Result<(RunReport, Latencies), CliError> {
    let bad = |e: String| CliError::BadInput(e);
    let stack_error = |flag: &str, e: motm_core::ModelError| {
        bad(match e {
            // A file that is not there is the flag's fault; a bad key is the file's.
            motm_core::ModelError::Io { .. } => format!("{flag}: {e}"),
            e => e.to_string(),
        })
    };
    let mut stack_path = StackConfig::resolve(config_dir, &args.config);
    let mut stack = StackConfig::from_file(&stack_path)
        .map_err(|e| stack_error(&format!("--config {}", args.config), e))?;
    if args.hardware == Hardware::Fake {
        let fake = stack.fake_hardware.clone().ok_or_else(|| {
            bad(format!(
                "--hardware fake: the stack config {} names no fake_hardware stack",
                stack_path.display()
            ))
        })?;
        stack_path = StackConfig::resolve(config_dir, &fake);
        stack = StackConfig::from_file(&stack_path).map_err(|e| bad(e.to_string()))?;
    }
    let hardware = if stack.stand_ins().next().is_some() {
        Hardware::Fake
    } else {
        Hardware::Sim
    };
    let seed = args.seed.unwrap_or(stack.seed);
    let scenario_path = scenario_file(
        config_dir,
        args.scenario.as_deref().unwrap_or(&stack.scenario),
        seed,
    )?;
    let mut scenario = Scenario::from_file(&scenario_path).map_err(|e| bad(e.to_string()))?;
    if let Some(v) = args.base_speed {
        scenario.set_base_speed(v).map_err(|e| bad(e.to_string()))?;
    }
    let rate = args.rate.unwrap_or(stack.control_rate_hz);
    if !(rate.is_finite() && rate > 0.0) {
        return Err(bad(format!(
            "--rate must be a finite number > 0, got {rate}"
        )));
    }
    let timeout_s = args.timeout.unwrap_or_else(|| {
        let limits = motm_sim::runner::RunnerConfig::default();
        2.0 * (limits.timeout_base
            + limits.timeout_per_task * scenario.mission_tasks().len() as f64)
    });
    if !(timeout_s.is_finite() && timeout_s > 0.0) {
        return Err(bad(format!(
            "--timeout must be a finite number > 0, got {timeout_s}"
        )));
    }
    // The robot model is checked here too, so a bad URDF or robot file exits 2 naming the
    // file and key before anything starts (the supervisor would otherwise exit on it).
    motm_core::Robot::load(config_dir, &scenario.robot).map_err(|e| bad(e.to_string()))?;
    let faults =
        motm_core::fault_schedule::parse_schedule(&args.faults).map_err(|e| bad(e.to_string()))?;
    let process_names: Vec<String> = stack.processes.iter().map(|p| p.name.clone()).collect();
    check_targets(&faults, &process_names).map_err(bad)?;
    let swap_plans = args
        .swaps
        .iter()
        .map(|s| parse_plan(s))
        .collect::<Result<Vec<_>, _>>()?;
    let logger_outputs = crate::run_mcap::LoggerOutputs {
        mcap: args.mcap.as_deref(),
        live: args.live,
    };
    logger_outputs.check()?;
    for name in &args.remote {
        if stack.process(name).is_none() {
            return Err(bad(format!(
                "--remote {name}: not a process of the stack config {}",
                stack_path.display()
            )));
        }
    }
    let bin_dir = ensure_binaries(&stack, !args.remote.is_empty())?;

    let ipc = IpcConfig {
        prefix: std::env::var(motm_bus::PREFIX_ENV)
            .ok()
            .filter(|p| !p.is_empty())
            .unwrap_or_else(|| format!("motm{}_", std::process::id())),
    };
    ipc.iceoryx2().map_err(|e| bad(e.to_string()))?;
    let registry = registry_dir().join(&ipc.prefix);
    let fake_reports = std::env::temp_dir().join(format!("motm-fake-robots-{}", ipc.prefix));
    let _ = std::fs::remove_dir_all(&fake_reports);
    std::fs::create_dir_all(&fake_reports)
        .map_err(|e| CliError::Failed(format!("cannot create {}: {e}", fake_reports.display())))?;
    let _ = std::fs::create_dir_all(registry_dir());
    let _ = std::fs::write(&registry, format!("{}\n", std::process::id()));
    let iox2 = crate::status::write_iox2_config(&ipc).map_err(CliError::Failed)?;
    motm_bus::say!(
        "motm run: {} at {} m/s, {} Hz control, iceoryx2 prefix {} (`MOTM_IPC_PREFIX={} motm status`; iceoryx2's tools: `cd {} && iox2 service list`)",
        scenario.name,
        scenario.base_speed,
        rate,
        ipc.prefix,
        ipc.prefix,
        iox2.display()
    );

    let wall = Instant::now();
    let mut command = Command::new(binaries::binary_path(&bin_dir, "supervisor"));
    command
        .arg("--stack")
        .arg(&stack_path)
        .arg("--config-dir")
        .arg(config_dir)
        .arg("--scenario")
        .arg(&scenario_path)
        .arg("--base-speed")
        .arg(scenario.base_speed.to_string())
        .arg("--seed")
        .arg(seed.to_string())
        .arg("--rate")
        .arg(rate.to_string())
        .arg("--bin-dir")
        .arg(&bin_dir)
        .env(motm_bus::PREFIX_ENV, &ipc.prefix)
        .env(motm_graph::STAND_IN_REPORT_DIR_ENV, &fake_reports);
    for name in &args.remote {
        command.arg("--remote").arg(name);
    }
    crate::run_mcap::exit_with_parent(&mut command);
    let with_logger = logger_outputs.any();
    let logger = if with_logger {
        Some(crate::run_mcap::LoggerProcess::start(
            &bin_dir,
            &ipc.prefix,
            logger_outputs,
            crate::run_mcap::LoggedRun {
                config_dir,
                robot: &stack.robot,
                scenario: &scenario_path,
                seed,
                base_speed: scenario.base_speed,
            },
        )?)
    } else {
        None
    };
    if args.mcap.is_some() {
        // The replay log holds every sample from the first only if the logger's taps exist
        // before the stack starts.
        wait_for_logger(&ipc, LOGGER_START_TIMEOUT);
    }
    let mut supervisor = command
        .spawn()
        .map_err(|e| CliError::Failed(format!("cannot start the supervisor: {e}")))?;

    let mut names: Vec<String> = stack.processes.iter().map(|p| p.name.clone()).collect();
    names.push("supervisor".into());
    if !args.remote.is_empty() {
        names.push(motm_graph::STACK_BRIDGE.into());
        names.push(motm_graph::REMOTE_BRIDGE.into());
    }
    if with_logger {
        names.push("logger".into());
    }
    let watched = (|| -> Result<_, motm_bus::BusError> {
        let bus = Bus::open_with("motm-run", &ipc)?;
        let mut watch = Watch::new(&bus, &names, measure_latency)?;
        let mut fault_runner = FaultRunner::new(&bus, &faults)?;
        let mut swaps = swap_plans
            .iter()
            .map(|p| Ok((p.at_s, SwapClient::new(&bus, p.process, p.kind, 0)?)))
            .collect::<Result<Vec<_>, motm_bus::BusError>>()?;
        let mut failure = None;
        // Faults are timed and measured to a few ms: the watch loop then runs at 500 Hz.
        let watch_rate = if measure_latency {
            4.0 * rate
        } else if fault_runner.has_faults() {
            500.0
        } else {
            20.0
        };
        let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(watch_rate))?;
        let exit = service.run_periodic(|cycle| {
            watch.update();
            fault_runner.step(
                cycle.now_ns,
                watch.truth.get(),
                watch.status.get(),
                &watch.heartbeats,
            );
            let elapsed = wall.elapsed().as_secs_f64();
            for (at_s, client) in &mut swaps {
                if !client.sent() && elapsed >= *at_s {
                    let plan = client.report();
                    motm_bus::say!(
                        "motm run: requesting the swap of {} to {} at {elapsed:.2} s",
                        plan.process,
                        plan.variant
                    );
                    if let Err(e) = client.send(elapsed) {
                        motm_bus::say!("motm run: swap request failed: {e}");
                    }
                }
                client.update();
            }
            if watch
                .truth
                .get()
                .and_then(SimTruth::outcome)
                .is_some_and(|o| o != SimOutcome::Running)
            {
                return Flow::Stop;
            }
            if let Ok(Some(status)) = supervisor.try_wait() {
                failure = Some(format!("supervisor_exited ({status})"));
                return Flow::Stop;
            }
            if wall.elapsed().as_secs_f64() > timeout_s {
                failure = Some("wall_clock_timeout".into());
                return Flow::Stop;
            }
            Flow::Continue
        })?;
        if exit != motm_bus::LoopExit::Stopped {
            failure = Some("interrupted".into());
        }
        let (records, safe_stops) = fault_runner.finish();
        Ok((
            trial_result(watch.truth.get(), failure, wall.elapsed().as_secs_f64()),
            std::mem::take(&mut watch.latencies),
            watch.processes(),
            std::mem::take(&mut watch.drivers),
            records,
            safe_stops,
            swaps.iter().map(|(_, c)| c.report()).collect::<Vec<_>>(),
        ))
    })();
    let grace = Duration::from_secs_f64(stack.shutdown_grace_ms / 1000.0 + 5.0);
    let logger_exit = logger.map(|l| l.stop(grace));
    let supervisor_exit = stop_supervisor(&mut supervisor, grace);
    // Every process of the stack has exited: clean what dead ones left, then the prefix itself,
    // unless a process from outside the stack (an attached `iox2 service hz`, say) is still on
    // it: its resources then stay and are counted as left behind.
    for ipc in [&ipc, &ipc.remote()] {
        let _ = motm_bus::cleanup_dead_nodes(ipc);
        match motm_bus::live_nodes(ipc) {
            Ok(live) if live.is_empty() => {
                // SAFETY: the supervisor and every process it started have exited, this run's
                // bus is dropped, and no other node is alive on the prefix.
                let _ = unsafe { motm_bus::remove_domain(ipc) };
            }
            Ok(live) => motm_bus::say!(
                "motm run: still on iceoryx2 prefix {} at the end of the run: {} (stop iceoryx2 tools such as `iox2 service hz` before the run ends)",
                ipc.prefix,
                live.join(", ")
            ),
            Err(e) => motm_bus::say!("motm run: {e}"),
        }
    }
    let stale = motm_bus::shared_memory_entries(&ipc).map_or(0, |e| e.len());
    let _ = std::fs::remove_file(&registry);
    let _ = std::fs::remove_dir_all(&iox2);
    let fake_robot_violations = fake_robot_violations(&fake_reports);
    let _ = std::fs::remove_dir_all(&fake_reports);
    let fake_robot_violations = fake_robot_violations.map_err(CliError::Failed)?;
    let (trial, latencies, processes, drivers, faults_injected, safe_stops, swaps) =
        watched.map_err(|e| CliError::Failed(e.to_string()))?;
    let logger = logger_exit.transpose()?;
    if supervisor_exit.is_some_and(|s| !s.success()) {
        motm_bus::say!("motm run: supervisor exit: {}", supervisor_exit.unwrap());
    }
    let report = RunReport {
        trial,
        scenario: scenario.name.clone(),
        base_speed: scenario.base_speed,
        control_rate_hz: rate,
        processes,
        limit_violations: drivers.limit_violations(),
        output_violations: drivers.output_violations(),
        max_command_gap_ms: drivers.max_command_gap_ms(),
        resolver_takeovers: drivers.resolver_takeovers(),
        max_takeover_interval_ms: drivers.max_takeover_interval_ms(),
        hardware,
        backends: stack.driver_backends().into_iter().collect(),
        fake_robot_violations,
        ipc_prefix: ipc.prefix.clone(),
        stale_shm_entries: stale,
        safe_stops,
        faults_injected,
        swaps,
        logger,
    };
    Ok((report, latencies))
}

/// The sum of `violations_total` over the fake robots' count files in `dir` (see
/// [`motm_graph::STAND_IN_REPORT_DIR_ENV`]); a file that does not parse is an error naming it.
fn fake_robot_violations(dir: &Path) -> Result<u64, String> {
    let mut total = 0;
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_none_or(|e| e != "json") {
            continue;
        }
        let text =
            std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        total += value["violations_total"]
            .as_u64()
            .ok_or_else(|| format!("{}: no violations_total", path.display()))?;
    }
    Ok(total)
}

/// `motm run`.
pub fn run(config_dir: &Path, args: &RunArgs) -> Result<(), CliError> {
    let (report, _) = run_stack(config_dir, args, false)?;
    print_report(&report, args.json)?;
    let stale = report.stale_shm_entries;
    if stale > 0 {
        return Err(CliError::Failed(format!(
            "{stale} iceoryx2 resource(s) of prefix {} left behind",
            report.ipc_prefix
        )));
    }
    if let Some(swap) = report.swaps.iter().find(|s| s.outcome != "done") {
        return Err(CliError::Failed(format!(
            "swap of {} to {} {}",
            swap.process, swap.variant, swap.outcome
        )));
    }
    if report.trial.success {
        Ok(())
    } else {
        Err(CliError::Failed(format!(
            "run failed: {}",
            report.trial.failure.clone().unwrap_or_default()
        )))
    }
}

/// Prints the report as JSON or text.
fn print_report(report: &RunReport, json: bool) -> Result<(), CliError> {
    if json {
        println!(
            "{}",
            serde_json::to_string(report).map_err(|e| CliError::Failed(e.to_string()))?
        );
        return Ok(());
    }
    let t = &report.trial;
    println!(
        "{} at {:.2} m/s, {} Hz control (multi-process): {}",
        report.scenario,
        report.base_speed,
        report.control_rate_hz,
        match &t.failure {
            None => "success".to_string(),
            Some(reason) => format!("failed ({reason})"),
        }
    );
    println!(
        "task time {:.2} s, MTPH {:.1}, EE |a| mean {:.2} max {:.2} m/s²",
        t.task_time_s, t.mtph, t.ee_acc_mean, t.ee_acc_max
    );
    println!(
        "simulated {:.1} s in {:.2} s wall; limit violations {}, output violations {}, max command gap {:.1} ms",
        t.sim_time_s,
        t.wall_time_s,
        report.limit_violations,
        report.output_violations,
        report.max_command_gap_ms
    );
    let backends: Vec<String> = report
        .backends
        .iter()
        .map(|(driver, backend)| format!("{driver} {backend}"))
        .collect();
    println!(
        "hardware {:?} ({}); limit violations seen by the fake robots {}",
        report.hardware,
        backends.join(", "),
        report.fake_robot_violations
    );
    println!(
        "{:<14} {:>8} {:>8} {:>9} {:>8} {:>10}",
        "process", "pid", "restarts", "cycles", "misses", "p99 µs"
    );
    for p in &report.processes {
        println!(
            "{:<14} {:>8} {:>8} {:>9} {:>8} {:>10.0}",
            p.name, p.pid, p.restarts, p.cycles, p.deadline_misses, p.p99_cycle_us
        );
    }
    crate::faults::print_faults(&report.faults_injected, &report.safe_stops);
    for s in &report.swaps {
        println!(
            "swap {} -> {} at {:.1} s: {}; pid {} -> {}; command gap {:.2} ms at base speed {:.2} m/s",
            s.process,
            s.variant,
            s.requested_at_s,
            s.outcome,
            s.old_pid,
            s.new_pid,
            s.command_gap_ms,
            s.base_speed
        );
    }
    if let Some(l) = &report.logger {
        println!(
            "logger: {} samples read, {} lost ({:.1} %; a full queue drops its oldest sample), {} records dropped",
            l.samples_received,
            l.samples_lost,
            100.0 * l.lost_fraction,
            l.records_dropped
        );
    }
    Ok(())
}

/// Longest wait for the logger's taps before the stack starts anyway.
const LOGGER_START_TIMEOUT: Duration = Duration::from_secs(10);

/// Waits until the logger's heartbeat service exists (it is created after the logger's taps),
/// at most `timeout`; a warning when it does not appear.
fn wait_for_logger(ipc: &IpcConfig, timeout: Duration) {
    let heartbeat = motm_msgs::services::heartbeat("logger");
    let start = Instant::now();
    while start.elapsed() < timeout {
        if ipc.service_exists(&heartbeat).unwrap_or(false) {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    motm_bus::say!(
        "motm run: the logger did not start within {} s; its log may miss the first samples",
        timeout.as_secs()
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::Message;

    fn truth(outcome: SimOutcome, placed: &[f64]) -> SimTruth {
        let mut t = SimTruth::zeroed();
        t.sim_time = 13.0;
        t.task_time = 12.5;
        t.outcome = outcome.into();
        t.object_count = placed.len() as u32;
        t.object_placed_time[..placed.len()].copy_from_slice(placed);
        t.ee_acc_mean = 0.4;
        t
    }

    #[test]
    fn success_gives_mtph_and_round_trips_from_placement_times() {
        let t = truth(SimOutcome::Success, &[12.5, 6.0]);
        let r = trial_result(Some(&t), None, 14.0);
        assert!(r.success && r.failure.is_none());
        assert!((r.mtph - 3600.0 / 12.5).abs() < 1e-9);
        assert_eq!(r.round_trips_s, [6.0, 6.5]);
        assert_eq!(
            (r.sim_time_s, r.wall_time_s, r.ee_acc_mean),
            (13.0, 14.0, 0.4)
        );
    }

    #[test]
    fn failures_are_named_as_motm_trial_names_them() {
        let t = truth(SimOutcome::KnockedOff, &[-1.0]);
        let r = trial_result(Some(&t), None, 1.0);
        assert_eq!(r.failure.as_deref(), Some("knocked_off"));
        assert!(!r.success && r.mtph == 0.0 && r.round_trips_s.is_empty());
        // A stack failure overrides even a success reported by the world.
        let t = truth(SimOutcome::Success, &[5.0]);
        let r = trial_result(Some(&t), Some("interrupted".into()), 1.0);
        assert_eq!(
            (r.success, r.failure.as_deref()),
            (false, Some("interrupted"))
        );
        let r = trial_result(Some(&truth(SimOutcome::Running, &[])), None, 1.0);
        assert_eq!(r.failure.as_deref(), Some("not_finished"));
        let r = trial_result(None, None, 1.0);
        assert_eq!(r.failure.as_deref(), Some("no_truth_from_sim_world"));
    }
}
