//! `supervisor`: starts the processes of a stack config, restarts dead ones with backoff after
//! cleaning their iceoryx2 resources, publishes the process table, and runs the mission
//! (current task, next target, phase) on `MISSION_STATE` at the control rate.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use motm_bus::{Bus, Flow, IpcConfig, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::Robot;
use motm_core::mission::{Phase, TaskKind};
use motm_core::mission_tracker::{
    FinalProgress, MissionTracker, MissionTrackerInput, MissionTrackerOutput,
};
use motm_core::on_the_move::OnTheMoveConfig;
use motm_msgs::{
    BaseOdometry, JointState, MissionState, SupervisorStatus, TaskKindCode, TwistCommand, services,
};
use motm_sim::Scenario;
use motm_supervisor::swap::SwapDriver;
use motm_supervisor::{LaunchContext, LaunchSpec, ProcessTable, StackConfig, TableEvent, binaries};
use motm_wire::controllers::ControllerLatest;
use motm_wire::convert;
use nalgebra::Vector3;

/// Exit code for bad input (a bad file, key or value).
const EXIT_BAD_INPUT: u8 = 2;

/// Starts and supervises a motm stack and runs its mission.
#[derive(Parser)]
#[command(name = "supervisor")]
struct Args {
    /// Stack config file, or a name in the config folder (e.g. `frankie`).
    #[arg(long, default_value = "frankie")]
    stack: String,
    /// Config folder (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// Scenario file or name (default: the stack's `scenario`).
    #[arg(long)]
    scenario: Option<String>,
    /// Base speed v_F, m/s (default: the scenario's `base_speed`).
    #[arg(long)]
    base_speed: Option<f64>,
    /// Random seed (default: the stack's `seed`).
    #[arg(long)]
    seed: Option<u64>,
    /// Control rate, Hz (default: the stack's `control_rate_hz`).
    #[arg(long)]
    rate: Option<f64>,
    /// Folder of the service binaries (default: this executable's folder).
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Only manage the processes; publish no mission.
    #[arg(long)]
    no_mission: bool,
    /// Start no process: something else runs them (systemd units, see deploy/); the
    /// supervisor runs the mission only, and hot swaps are refused.
    #[arg(long)]
    no_spawn: bool,
    /// Print each process's name and expanded arguments (`name<TAB>args`, one per line) and
    /// exit; deploy/install.sh writes the systemd units' argument files from it.
    #[arg(long)]
    print_launch: bool,
}

/// Everything the supervisor needs, checked before anything starts.
struct Setup {
    stack: StackConfig,
    specs: Vec<LaunchSpec>,
    control_rate_hz: f64,
    mission: Option<MissionTracker>,
}

fn setup(args: &Args) -> Result<Setup, String> {
    let config_dir = motm_core::resolve_config_dir(args.config_dir.as_deref());
    let stack = StackConfig::from_file(&StackConfig::resolve(&config_dir, &args.stack))
        .map_err(|e| e.to_string())?;
    let control_rate_hz = args.rate.unwrap_or(stack.control_rate_hz);
    if !(control_rate_hz.is_finite() && control_rate_hz > 0.0) {
        return Err(format!(
            "--rate must be a finite number > 0, got {control_rate_hz}"
        ));
    }
    let scenario = motm_sim::scenario_path(
        &config_dir,
        args.scenario.as_deref().unwrap_or(&stack.scenario),
    );
    let bin_dir = match &args.bin_dir {
        Some(dir) => dir.clone(),
        None => binaries::own_dir().map_err(|e| format!("cannot find own executable: {e}"))?,
    };
    let missing = binaries::missing(&bin_dir, stack.processes.iter().map(|p| p.name.as_str()));
    // Without spawning, the binaries may live elsewhere (or not be installed, like sim-world).
    if !missing.is_empty() && !args.no_spawn && !args.print_launch {
        return Err(format!(
            "service binaries missing in {}: {}",
            bin_dir.display(),
            missing.join(", ")
        ));
    }
    let mut scenario_file = Scenario::from_file(&scenario).map_err(|e| e.to_string())?;
    if let Some(v) = args.base_speed {
        scenario_file.set_base_speed(v).map_err(|e| e.to_string())?;
    }
    let context = LaunchContext {
        config_dir: config_dir.clone(),
        scenario: scenario.clone(),
        base_speed: scenario_file.base_speed,
        seed: args.seed.unwrap_or(stack.seed),
        control_rate_hz,
    };
    let specs = stack
        .processes
        .iter()
        .map(|p| LaunchSpec {
            name: p.name.clone(),
            program: binaries::binary_path(&bin_dir, &p.name),
            args: stack.expand_args(p, &context),
            env: Vec::new(),
        })
        .collect();
    let mission = if args.no_mission {
        None
    } else {
        let robot = Robot::load(&config_dir, &scenario_file.robot).map_err(|e| e.to_string())?;
        let start = scenario_file.start();
        Some(MissionTracker::new(
            robot,
            OnTheMoveConfig::default(),
            scenario_file.mission_tasks(),
            Vector3::new(start.x, start.y, 0.0),
        ))
    };
    Ok(Setup {
        stack,
        specs,
        control_rate_hz,
        mission,
    })
}

/// Logs table events on stderr.
fn log(events: &[TableEvent]) {
    for event in events {
        match event {
            TableEvent::Started { name, pid, restart } => {
                let verb = if *restart { "restarted" } else { "started" };
                eprintln!("supervisor: {verb} {name} (pid {pid})");
            }
            TableEvent::Exited {
                name,
                pid,
                exit,
                restart_in,
            } => match restart_in {
                Some(delay) => eprintln!(
                    "supervisor: {name} (pid {pid}) exited ({exit}); restart in {} ms",
                    delay.as_millis()
                ),
                None => eprintln!("supervisor: {name} (pid {pid}) exited ({exit})"),
            },
            TableEvent::SpawnFailed { name, error } => {
                eprintln!("supervisor: cannot start {name}: {error}");
            }
            TableEvent::CleanupFailed { name, error } => {
                eprintln!("supervisor: cleanup after {name}: {error}");
            }
        }
    }
}

/// The mission task's bus inputs and the stamps that guard them.
struct MissionPorts {
    joints: Latest<JointState>,
    odometry: Latest<BaseOdometry>,
    target: Latest<motm_msgs::TargetEstimate>,
    final_twist: ControllerLatest<TwistCommand>,
    state: Publisher<MissionState>,
    /// When the current task started, ns: older perception estimates belong to another object.
    task_started_ns: u64,
}

impl MissionPorts {
    fn new(bus: &Bus, now_ns: u64) -> Result<Self, motm_bus::BusError> {
        let qos = Qos::default();
        Ok(Self {
            joints: Latest::new(bus, services::ARM_JOINT_STATE, &qos)?,
            odometry: Latest::new(bus, services::BASE_ODOMETRY, &qos)?,
            target: Latest::new(bus, services::PERCEPTION_TARGET, &qos)?,
            final_twist: ControllerLatest::new(bus, services::CONTROL_FINAL_TWIST, &qos)?,
            state: Publisher::new(bus, services::MISSION_STATE, &qos)?,
            task_started_ns: now_ns,
        })
    }

    /// One mission cycle at `now_ns`: read, step, publish. Task progress is taken from the
    /// `active` final-phase controller (any, until a hot swap names one).
    fn cycle(&mut self, tracker: &mut MissionTracker, now_ns: u64, active: Option<u32>) {
        // A failed read leaves the previous value, which the stamps guard.
        let _ = self.joints.update();
        let _ = self.odometry.update();
        let _ = self.target.update();
        let _ = self.final_twist.update();
        let out = match (self.joints.get(), self.odometry.get()) {
            (Some(joints), Some(odometry)) => {
                let estimate = self
                    .target
                    .get()
                    .map(convert::perceived)
                    .filter(|p| p.stamp_ns >= self.task_started_ns)
                    .map(|p| p.estimate);
                let final_progress = self.final_twist.get(active).and_then(|m| {
                    Some(FinalProgress {
                        task_index: m.task_index as usize,
                        progress: convert::progress(m)?,
                    })
                });
                tracker.step(&MissionTrackerInput {
                    base: convert::base_pose(odometry),
                    arm_q: convert::arm_q(joints),
                    estimate,
                    final_progress,
                })
            }
            _ => tracker.output(f64::INFINITY, false),
        };
        if out.changed {
            eprintln!(
                "supervisor: mission task {}/{} phase {:?} (tool to target {:.3} m)",
                out.task_index, out.task_count, out.phase, out.tool_to_target
            );
            if out.phase != Phase::Final {
                self.task_started_ns = now_ns;
            }
        }
        let _ = self.state.publish(mission_state(&out));
    }
}

/// The [`MissionState`] message of a mission output.
fn mission_state(out: &MissionTrackerOutput) -> MissionState {
    use motm_msgs::Message;
    let mut m = MissionState::zeroed();
    m.task_index = out.task_index as u32;
    m.task_count = out.task_count as u32;
    m.task_kind = match out.kind {
        Some(TaskKind::Pick) | None => TaskKindCode::Pick,
        Some(TaskKind::Place) => TaskKindCode::Place,
        Some(TaskKind::PressButton) => TaskKindCode::PressButton,
    }
    .into();
    m.phase = convert::phase_code(out.phase).into();
    m.current_target = out.current_target.into();
    if let Some(next) = out.next_target {
        m.next_target = next.into();
        m.has_next = 1;
    }
    m
}

fn run(setup: Setup) -> Result<(), String> {
    let Setup {
        stack,
        specs,
        control_rate_hz,
        mut mission,
    } = setup;
    let ipc = IpcConfig::from_env();
    let bus = Bus::open("supervisor").map_err(|e| e.to_string())?;
    let mut status =
        Publisher::<SupervisorStatus>::new(&bus, services::SUPERVISOR_STATUS, &Qos::default())
            .map_err(|e| e.to_string())?;
    let mut ports = match mission {
        Some(_) => {
            Some(MissionPorts::new(&bus, motm_bus::monotonic_now_ns()).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    // Every port is open before the first child starts (and before the first status says so).
    let grace = Duration::from_secs_f64(stack.shutdown_grace_ms / 1000.0);
    let mut swap = SwapDriver::new(&bus, stack.hot_swap, (1e9 / control_rate_hz) as u64, grace)
        .map_err(|e| e.to_string())?;
    let mut table = ProcessTable::new(specs, stack.restart, ipc);
    // The mission state is on the bus before the controllers start.
    if let (Some(ports), Some(tracker)) = (ports.as_mut(), mission.as_mut()) {
        ports.cycle(tracker, motm_bus::monotonic_now_ns(), None);
    }
    log(&table.start_all(motm_bus::monotonic_now_ns()));
    let _ = status.publish(table.status());
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(control_rate_hz))
        .map_err(|e| e.to_string())?;
    let status_every = (control_rate_hz / 10.0).ceil().max(1.0) as u64;
    let exit = service.run_periodic(|cycle| {
        let events = table.poll(cycle.now_ns);
        log(&events);
        let base_speed = ports
            .as_ref()
            .and_then(|p| p.odometry.get())
            .map_or(0.0, |o| o.v);
        let swapped = swap.poll(&mut table, cycle.now_ns, base_speed);
        if let (Some(ports), Some(tracker)) = (ports.as_mut(), mission.as_mut()) {
            ports.cycle(tracker, cycle.now_ns, swap.active_id());
        }
        if swapped || !events.is_empty() || cycle.cycle % status_every == 0 {
            let _ = status.publish(table.status());
        }
        Flow::Continue
    });
    eprintln!("supervisor: stopping the stack");
    swap.shutdown();
    log(&table.shutdown(grace));
    let _ = status.publish(table.status());
    exit.map(|_| ()).map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    let args = Args::parse();
    let mut setup = match setup(&args) {
        Ok(setup) => setup,
        Err(e) => {
            eprintln!("supervisor: {e}");
            return ExitCode::from(EXIT_BAD_INPUT);
        }
    };
    if args.print_launch {
        for spec in &setup.specs {
            println!("{}\t{}", spec.name, spec.args.join(" "));
        }
        return ExitCode::SUCCESS;
    }
    if args.no_spawn {
        setup.specs.clear();
    }
    match run(setup) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("supervisor: {e}");
            ExitCode::FAILURE
        }
    }
}
