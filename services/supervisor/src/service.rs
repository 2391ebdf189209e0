//! `supervisor`: starts the processes of a stack config, restarts dead ones with backoff after
//! cleaning their iceoryx2 resources, publishes the process table, and runs the mission
//! (current task, next target, phase) on `MISSION_STATE` at the control rate.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use crate::swap::SwapDriver;
use crate::{LaunchContext, LaunchSpec, ProcessTable, StackConfig, TableEvent, binaries};
use clap::Parser;
use motm_bus::{Bus, Flow, IpcConfig, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::Robot;
use motm_core::on_the_move::OnTheMoveConfig;
use motm_msgs::{SupervisorStatus, services};
use motm_runtime::TaskPorts;
use motm_sim::Scenario;
use motm_tasks::mission::MissionSequencerTask;
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
    /// Run this process of the stack as if on another host (repeatable): on the iceoryx2 prefix
    /// `<prefix>remote_`, bridged to the stack by two `motm-zenoh` peers over loopback TCP
    /// (`zenoh-stack` and `zenoh-remote`, supervised like the others).
    #[arg(long, value_name = "PROCESS")]
    remote: Vec<String>,
}

/// Everything the supervisor needs, checked before anything starts.
struct Setup {
    stack: StackConfig,
    specs: Vec<LaunchSpec>,
    control_rate_hz: f64,
    mission: Option<MissionSequencerTask>,
    /// Files written for this run (the simulated camera's calibration), removed when it ends.
    run_files: Vec<PathBuf>,
}

/// The calibration file perception is launched with. With the simulated world in the stack the
/// camera is the simulated one, so perception gets that camera's own calibration, its
/// extrinsic error drawn from the seed as sim-world draws it (written for this run into the
/// temp folder, named by the iceoryx2 prefix); on a robot it is the stack's `calibration`
/// file. Either is read back here, so a bad file stops the stack before it starts. Returns the
/// file, and again when it was written for this run.
fn camera_calibration(
    stack: &StackConfig,
    config_dir: &std::path::Path,
    scenario: &Scenario,
    seed: u64,
) -> Result<(PathBuf, Option<PathBuf>), String> {
    let (file, written) = if stack.process(motm_graph::SIM_WORLD.name).is_some() {
        let calibration = motm_sim::render::PalmCamera::for_trial(
            &motm_core::camera::CameraConfig::default(),
            scenario,
            seed,
        )
        .calibration();
        let file = std::env::temp_dir().join(format!(
            "{}camera-calibration.toml",
            IpcConfig::from_env().prefix
        ));
        std::fs::write(&file, calibration.to_toml())
            .map_err(|e| format!("cannot write {}: {e}", file.display()))?;
        (file.clone(), Some(file))
    } else {
        (stack.calibration_file(config_dir), None)
    };
    motm_core::camera::CameraCalibration::from_file(&file).map_err(|e| e.to_string())?;
    Ok((file, written))
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
    for name in &args.remote {
        if stack.process(name).is_none() || motm_graph::task(name).is_none() {
            return Err(format!(
                "--remote {name}: not a process of the graph in {}",
                stack.path.display()
            ));
        }
    }
    let bridge_binary = (!args.remote.is_empty()).then_some(BRIDGE_BINARY);
    let missing = binaries::missing(
        &bin_dir,
        stack
            .processes
            .iter()
            .map(|p| p.name.as_str())
            .chain(bridge_binary),
    );
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
    let controllers_file = stack.controllers_file(&config_dir);
    let controllers = OnTheMoveConfig::load(&controllers_file).map_err(|e| e.to_string())?;
    let seed = args.seed.unwrap_or(stack.seed);
    let (calibration, written) = camera_calibration(&stack, &config_dir, &scenario_file, seed)?;
    let run_files: Vec<PathBuf> = written.into_iter().collect();
    let context = LaunchContext {
        calibration,
        controllers: controllers_file,
        config_dir: config_dir.clone(),
        scenario: scenario.clone(),
        base_speed: scenario_file.base_speed,
        seed,
        control_rate_hz,
    };
    let remote_env = || {
        vec![(
            motm_bus::PREFIX_ENV.to_owned(),
            IpcConfig::from_env().remote().prefix,
        )]
    };
    let mut specs: Vec<LaunchSpec> = stack
        .processes
        .iter()
        .map(|p| LaunchSpec {
            name: p.name.clone(),
            program: binaries::binary_path(&bin_dir, &p.name),
            args: stack.expand_args(p, &context),
            env: if args.remote.contains(&p.name) {
                remote_env()
            } else {
                Vec::new()
            },
        })
        .collect();
    if !args.remote.is_empty() {
        // The bridges start first, so that both ends of every bridged topic are up before the
        // processes that use them, and stop last.
        specs.splice(0..0, bridge_specs(&bin_dir, &args.remote, remote_env())?);
    }
    let mission = if args.no_mission {
        None
    } else {
        let robot = Robot::load(&config_dir, &scenario_file.robot).map_err(|e| e.to_string())?;
        let start = scenario_file.start();
        Some(MissionSequencerTask::new(
            robot,
            controllers,
            scenario_file.mission_tasks(),
            Vector3::new(start.x, start.y, 0.0),
        ))
    };
    Ok(Setup {
        stack,
        specs,
        control_rate_hz,
        mission,
        run_files,
    })
}

/// The binary of the zenoh bridge (package `motm-zenoh`).
const BRIDGE_BINARY: &str = "motm-zenoh";

/// The two bridges of `--remote`: the stack's end listening on a free loopback port, the
/// remote end (with environment `remote_env`) connecting to it.
fn bridge_specs(
    bin_dir: &std::path::Path,
    remote: &[String],
    remote_env: Vec<(String, String)>,
) -> Result<Vec<LaunchSpec>, String> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| format!("--remote: no free loopback port for the bridge: {e}"))?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let args = |side: &str, endpoint_flag: &str| {
        let mut args: Vec<String> = remote
            .iter()
            .flat_map(|r| ["--remote-task".to_owned(), r.clone()])
            .collect();
        args.extend([
            "--side".to_owned(),
            side.to_owned(),
            endpoint_flag.to_owned(),
            endpoint.clone(),
        ]);
        args
    };
    Ok(vec![
        LaunchSpec {
            name: motm_graph::STACK_BRIDGE.to_owned(),
            program: binaries::binary_path(bin_dir, BRIDGE_BINARY),
            args: args("stack", "--listen"),
            env: Vec::new(),
        },
        LaunchSpec {
            name: motm_graph::REMOTE_BRIDGE.to_owned(),
            program: binaries::binary_path(bin_dir, BRIDGE_BINARY),
            args: args("remote", "--connect"),
            env: remote_env,
        },
    ])
}

/// Logs table events on stderr.
fn log(events: &[TableEvent]) {
    for event in events {
        match event {
            TableEvent::Started { name, pid, restart } => {
                let verb = if *restart { "restarted" } else { "started" };
                motm_bus::say!("supervisor: {verb} {name} (pid {pid})");
            }
            TableEvent::Exited {
                name,
                pid,
                exit,
                restart_in,
            } => match restart_in {
                Some(delay) => motm_bus::say!(
                    "supervisor: {name} (pid {pid}) exited ({exit}); restart in {} ms",
                    delay.as_millis()
                ),
                None => motm_bus::say!("supervisor: {name} (pid {pid}) exited ({exit})"),
            },
            TableEvent::SpawnFailed { name, error } => {
                motm_bus::say!("supervisor: cannot start {name}: {error}");
            }
            TableEvent::CleanupFailed { name, error } => {
                motm_bus::say!("supervisor: cleanup after {name}: {error}");
            }
        }
    }
}

/// The mission task on the bus: its ports, stepped once per supervisor cycle.
struct Mission {
    task: MissionSequencerTask,
    ports: TaskPorts<MissionSequencerTask>,
}

impl Mission {
    fn open(bus: &Bus, task: MissionSequencerTask) -> Result<Self, motm_bus::BusError> {
        Ok(Self {
            task,
            ports: TaskPorts::open(bus, &motm_graph::MISSION)?,
        })
    }

    /// One mission cycle at `now_ns` (read, step, publish); logs a change of task or phase.
    fn cycle(&mut self, now_ns: u64) {
        self.ports.step(&mut self.task, now_ns);
        if let Some(out) = self.task.last().filter(|out| out.changed) {
            motm_bus::say!(
                "supervisor: mission task {}/{} phase {:?} (tool to target {:.3} m)",
                out.task_index,
                out.task_count,
                out.phase,
                out.tool_to_target
            );
        }
    }

    /// The base's forward speed in the latest odometry, m/s.
    fn base_speed(&self) -> f64 {
        self.ports.inputs().odometry.map_or(0.0, |o| o.v)
    }
}

fn run(setup: Setup) -> Result<(), String> {
    let Setup {
        stack,
        specs,
        control_rate_hz,
        mission,
        run_files: _,
    } = setup;
    let ipc = IpcConfig::from_env();
    let bus = Bus::open("supervisor").map_err(|e| e.to_string())?;
    let mut status =
        Publisher::<SupervisorStatus>::new(&bus, services::SUPERVISOR_STATUS, &Qos::default())
            .map_err(|e| e.to_string())?;
    let mut mission = match mission {
        Some(task) => Some(Mission::open(&bus, task).map_err(|e| e.to_string())?),
        None => None,
    };
    // Every port is open before the first child starts (and before the first status says so).
    let grace = Duration::from_secs_f64(stack.shutdown_grace_ms / 1000.0);
    let mut swap = SwapDriver::new(&bus, stack.hot_swap, (1e9 / control_rate_hz) as u64, grace)
        .map_err(|e| e.to_string())?;
    let mut table = ProcessTable::new(specs, stack.restart, ipc);
    // The mission state is on the bus before the controllers start.
    if let Some(mission) = mission.as_mut() {
        mission.cycle(motm_bus::monotonic_now_ns());
    }
    log(&table.start_all(motm_bus::monotonic_now_ns()));
    let _ = status.publish(table.status());
    let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(control_rate_hz))
        .map_err(|e| e.to_string())?;
    let status_every = (control_rate_hz / 10.0).ceil().max(1.0) as u64;
    let exit = service.run_periodic(|cycle| {
        let events = table.poll(cycle.now_ns);
        log(&events);
        let base_speed = mission.as_ref().map_or(0.0, Mission::base_speed);
        let swapped = swap.poll(&mut table, cycle.now_ns, base_speed);
        // The mission follows the active controller on CONTROL_ACTIVE_CONTROLLER.
        if let Some(mission) = mission.as_mut() {
            mission.cycle(cycle.now_ns);
        }
        if swapped || !events.is_empty() || cycle.cycle % status_every == 0 {
            let _ = status.publish(table.status());
        }
        Flow::Continue
    });
    motm_bus::say!("supervisor: stopping the stack");
    swap.shutdown();
    log(&table.shutdown(grace));
    let _ = status.publish(table.status());
    exit.map(|_| ()).map_err(|e| e.to_string())
}

/// The `supervisor` process: parses its flags, runs until stopped, and returns its exit status.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let mut setup = match setup(&args) {
        Ok(setup) => setup,
        Err(e) => {
            motm_bus::say!("supervisor: {e}");
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
    let run_files = setup.run_files.clone();
    let result = run(setup);
    for file in run_files {
        let _ = std::fs::remove_file(file);
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            motm_bus::say!("supervisor: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn config_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
    }

    #[test]
    fn perception_gets_the_simulated_cameras_calibration_or_the_robots_file() {
        let dir = config_dir();
        let scenario = Scenario::from_file(&motm_sim::scenario_path(&dir, "exp1-dynamic")).unwrap();
        // With sim-world in the stack: the trial camera's calibration, extrinsic error included,
        // written for the run and read back exactly.
        let sim = StackConfig::from_file(&dir.join("frankie.toml")).unwrap();
        let (file, written) = camera_calibration(&sim, &dir, &scenario, 7).unwrap();
        assert_eq!(written.as_ref(), Some(&file));
        let expected = motm_sim::render::PalmCamera::for_trial(
            &motm_core::camera::CameraConfig::default(),
            &scenario,
            7,
        )
        .calibration();
        let read = motm_core::camera::CameraCalibration::from_file(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        assert_eq!(read, expected);
        assert_ne!(
            read,
            motm_core::camera::CameraConfig::default().calibration()
        );
        // Without it (a robot): the stack's `calibration` file, checked before anything starts.
        let mut robot = sim.clone();
        robot
            .processes
            .retain(|p| p.name != motm_graph::SIM_WORLD.name);
        let (file, written) = camera_calibration(&robot, &dir, &scenario, 7).unwrap();
        assert_eq!((file, written), (dir.join("cameras/palm.toml"), None));
        robot.calibration = PathBuf::from("cameras/missing.toml");
        let err = camera_calibration(&robot, &dir, &scenario, 7).unwrap_err();
        assert!(err.contains("cameras/missing.toml"), "{err}");
    }
}
