//! `fake-panda`: a fake Franka Panda (FCI, protocol v5, TCP `--fci-port` + 1 kHz UDP) and a
//! fake Franka Hand (protocol v3, TCP `--hand-port` + UDP states) on `--ip` (loopback by
//! default), serving the whole motion lifecycle with libfranka's limit checks on every
//! command (see `motm_franka::fake`).
//!
//! Physics (`--physics`): `sim` (default) bridges to sim-world: every millisecond the commanded
//! joint velocity goes out on `motm/v1/hw/arm_command` and the joint state comes back from
//! `motm/v1/hw/arm_state`; hand actions become `motm/v1/hw/gripper_command` (Open for Homing
//! and for a Move wider than half the opening, Close otherwise) and the hand state comes from
//! `motm/v1/hw/gripper_state` (an action completes when the opening has not changed for
//! `--hand-settle-ms`). `ideal`: the arm follows its command exactly and the hand closes on
//! a 0.03 m object; no sim-world needed.
//!
//! Report: on SIGTERM/SIGINT (or after `--duration`) one status line goes to stderr (robot
//! time, states, commands, late and missed commands, reflexes, limit violations by kind) and,
//! with `--report FILE`, the same counters as a JSON object. With `$MOTM_FAKE_REPORT_DIR` set
//! (by `motm run --hardware fake`) the JSON also goes to `fake-panda-<pid>.json` there, every
//! second and on exit. Exit code 0, or 3 when any
//! command broke a limit.

use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, ValueEnum};
use motm_bus::{Bus, Latest, Publisher, Qos};
use motm_franka::fake::{
    ArmPhysics, DropPlan, FakeHand, FakeHandConfig, FakeRobot, FakeRobotConfig, HandAction,
    HandPhysics, IdealArm, IdealHand, run_every_ms,
};
use motm_franka::fci::FCI_PORT;
use motm_franka::hand::HAND_PORT;
use motm_msgs::{
    ArmVelocityCommand, GripperAction, GripperCommand, GripperState, JointState, Message, services,
};

/// Exit code for bad flags or sockets that cannot be bound.
const EXIT_BAD_INPUT: u8 = 2;
/// Exit code when a received command broke a limit.
const EXIT_VIOLATIONS: u8 = 3;

/// Where the fake's physics comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Physics {
    /// sim-world, over its `motm/v1/hw/*` services.
    Sim,
    /// An arm that follows its command exactly; a hand with a 0.03 m object.
    Ideal,
}

/// A fake Franka Panda and Franka Hand.
#[derive(Parser)]
#[command(name = "fake-panda", version, about)]
struct Cli {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    ip: IpAddr,
    /// FCI TCP port.
    #[arg(long, default_value_t = FCI_PORT)]
    fci_port: u16,
    /// Hand TCP port.
    #[arg(long, default_value_t = HAND_PORT)]
    hand_port: u16,
    /// Physics.
    #[arg(long, value_enum, default_value_t = Physics::Sim)]
    physics: Physics,
    /// Drop the commands answering the states from this robot time on, ms (fault tests).
    #[arg(long)]
    drop_at_ms: Option<u64>,
    /// Number of consecutive commands to drop (with `--drop-at-ms`).
    #[arg(long, default_value_t = 25)]
    drop_count: u64,
    /// Send one wrong-size state at this robot time, ms (fault tests).
    #[arg(long)]
    bad_state_at_ms: Option<u64>,
    /// Consecutive missed commands that raise the communication-constraints reflex.
    #[arg(long, default_value_t = 20)]
    reflex_after: u32,
    /// A hand state every this many ms.
    #[arg(long, default_value_t = 10)]
    hand_state_every_ms: u32,
    /// Sim physics: a hand action completes when the opening is steady this long, ms.
    #[arg(long, default_value_t = 100)]
    hand_settle_ms: u32,
    /// Stop after this many seconds (default: run until SIGTERM/SIGINT).
    #[arg(long)]
    duration: Option<f64>,
    /// Scheduling niceness to run at (-20 to 19; below 0 needs CAP_SYS_NICE), as a robot's
    /// controller has the CPU to itself.
    #[arg(long, allow_negative_numbers = true)]
    nice: Option<i32>,
    /// Run under SCHED_FIFO at this priority (1 to 99; needs CAP_SYS_NICE): the robot's
    /// controller keeps its 1 ms clock whatever else the machine runs.
    #[arg(long)]
    fifo: Option<i32>,
    /// Write the counters as JSON to this file on exit.
    #[arg(long)]
    report: Option<PathBuf>,
}

/// The arm of sim-world.
struct SimArm {
    command: Publisher<ArmVelocityCommand>,
    state: Latest<JointState>,
    joints: ([f64; 7], [f64; 7]),
}

impl ArmPhysics for SimArm {
    fn step(&mut self, dq_c: &[f64; 7], _dt: f64) {
        let mut m = ArmVelocityCommand::zeroed();
        m.joint_count = 7;
        m.velocity[..7].copy_from_slice(dq_c);
        if let Err(e) = self.command.publish(m) {
            motm_bus::say!("fake-panda: {e}");
        }
        if self.state.update().unwrap_or(false)
            && let Some(s) = self.state.get()
        {
            let n = (s.joint_count as usize).min(7);
            self.joints.0[..n].copy_from_slice(&s.position[..n]);
            self.joints.1[..n].copy_from_slice(&s.velocity[..n]);
        }
    }
    fn joints(&self) -> ([f64; 7], [f64; 7]) {
        self.joints
    }
}

/// The gripper of sim-world.
struct SimHand {
    command: Publisher<GripperCommand>,
    state: Latest<GripperState>,
    max_width: f64,
    settle_ms: u32,
    action: Option<HandAction>,
    steady: u32,
    elapsed: u32,
    last_width: f64,
}

impl HandPhysics for SimHand {
    fn start(&mut self, action: HandAction) {
        let open = match action {
            HandAction::Homing => true,
            HandAction::Move { width, .. } => width > 0.5 * self.max_width,
            HandAction::Grasp { .. } => false,
        };
        let mut m = GripperCommand::zeroed();
        m.action = if open {
            GripperAction::Open
        } else {
            GripperAction::Close
        }
        .into();
        if let Err(e) = self.command.publish(m) {
            motm_bus::say!("fake-panda: {e}");
        }
        self.action = Some(action);
        self.steady = 0;
        self.elapsed = 0;
    }
    fn stop(&mut self) {
        self.action = None;
    }
    fn step(&mut self, _dt: f64) -> Option<bool> {
        self.state.update().ok();
        let (width, grasped) = self.state();
        if (width - self.last_width).abs() < 1e-6 {
            self.steady += 1;
        } else {
            self.steady = 0;
        }
        self.last_width = width;
        let action = self.action?;
        self.elapsed += 1;
        if self.steady < self.settle_ms && self.elapsed < 10_000 {
            return None;
        }
        self.action = None;
        Some(match action {
            HandAction::Grasp {
                width: w,
                epsilon_inner,
                epsilon_outer,
                ..
            } => grasped && w - epsilon_inner < width && width < w + epsilon_outer,
            _ => self.elapsed < 10_000,
        })
    }
    fn state(&self) -> (f64, bool) {
        self.state
            .get()
            .map_or((0.0, false), |s| (s.width, s.grasping == 1))
    }
}

/// The counters as JSON.
fn report(robot: &FakeRobot, hand: &FakeHand) -> serde_json::Value {
    let c = robot.counters();
    let v = &c.violations;
    let h = hand.counters();
    serde_json::json!({
        "violations_total": v.commands,
        "robot_time_ms": robot.time_ms(),
        "states_sent": c.states_sent,
        "commands": c.commands,
        "late_commands": c.late_commands,
        "bad_datagrams": c.bad_datagrams,
        "dropped": c.dropped,
        "missed_cycles": c.missed_cycles,
        "max_consecutive_missed": c.max_consecutive_missed,
        "connections": c.connections,
        "motions": c.motions,
        "finished": c.finished,
        "reflexes": c.reflexes,
        "cancelled": c.cancelled,
        "recoveries": c.recoveries,
        "protocol_errors": c.protocol_errors,
        "limit_violations": {
            "commands": v.commands,
            "velocity": v.velocity,
            "acceleration": v.acceleration,
            "jerk": v.jerk,
            "non_finite": v.non_finite,
        },
        "hand": {
            "connections": h.connections,
            "states_sent": h.states_sent,
            "actions": h.actions,
            "succeeded": h.succeeded,
            "failed": h.failed,
            "protocol_errors": h.protocol_errors,
        },
    })
}

/// Writes `report` to `$MOTM_FAKE_REPORT_DIR/fake-panda-<pid>.json` when that is set (`motm
/// run --hardware fake` sums the violations of every instance).
fn write_run_report(report: &serde_json::Value) {
    if let Some(dir) = std::env::var_os(motm_graph::STAND_IN_REPORT_DIR_ENV) {
        let path = PathBuf::from(dir).join(format!("fake-panda-{}.json", std::process::id()));
        let tmp = path.with_extension("tmp");
        let written =
            std::fs::write(&tmp, report.to_string()).and_then(|()| std::fs::rename(&tmp, &path));
        if let Err(e) = written {
            motm_bus::say!("fake-panda: {}: {e}", path.display());
        }
    }
}

/// Runs `work`, one part of a robot cycle, and reports it when it takes over 20 ms: the
/// robot's 1 ms clock must not stall.
fn timed<R>(part: &str, work: impl FnOnce() -> R) -> R {
    const SLOW: std::time::Duration = std::time::Duration::from_millis(20);
    let since = std::time::Instant::now();
    let result = work();
    let took = since.elapsed();
    if took > SLOW {
        motm_bus::say!("fake-panda: {part} took {:.1} ms", took.as_secs_f64() * 1e3);
    }
    result
}

fn run(cli: &Cli) -> Result<bool, String> {
    motm_driver::apply_priority("fake-panda", cli.nice, cli.fifo)?;
    let config = FakeRobotConfig {
        reflex_after: cli.reflex_after,
        drop: cli.drop_at_ms.map(|at_ms| DropPlan {
            at_ms,
            count: cli.drop_count,
        }),
        bad_state_at_ms: cli.bad_state_at_ms,
        ..FakeRobotConfig::default()
    };
    let hand_config = FakeHandConfig {
        state_every_ms: cli.hand_state_every_ms,
        ..FakeHandConfig::default()
    };
    let bind = |what: &str, e: std::io::Error| format!("{what} on {}: {e}", cli.ip);
    let mut robot = FakeRobot::bind(cli.ip, cli.fci_port, config).map_err(|e| bind("FCI", e))?;
    let mut hand =
        FakeHand::bind(cli.ip, cli.hand_port, hand_config).map_err(|e| bind("hand", e))?;
    // The node also installs the SIGTERM/SIGINT handler that ends the loop.
    let bus = Bus::open("fake-panda").map_err(|e| e.to_string())?;
    let qos = Qos::default();
    let (mut arm, mut fingers): (Box<dyn ArmPhysics>, Box<dyn HandPhysics>) = match cli.physics {
        Physics::Ideal => (
            Box::new(IdealArm::default()),
            Box::new(IdealHand::new(hand_config.max_width, Some(0.03))),
        ),
        Physics::Sim => {
            let e = |e: motm_bus::BusError| e.to_string();
            (
                Box::new(SimArm {
                    command: Publisher::new(&bus, services::HW_ARM_COMMAND, &qos).map_err(e)?,
                    state: Latest::new(&bus, services::HW_ARM_STATE, &qos).map_err(e)?,
                    joints: ([0.0; 7], [0.0; 7]),
                }),
                Box::new(SimHand {
                    command: Publisher::new(&bus, services::HW_GRIPPER_COMMAND, &qos).map_err(e)?,
                    state: Latest::new(&bus, services::HW_GRIPPER_STATE, &qos).map_err(e)?,
                    max_width: hand_config.max_width,
                    settle_ms: cli.hand_settle_ms,
                    action: None,
                    steady: 0,
                    elapsed: 0,
                    last_width: 0.0,
                }),
            )
        }
    };
    motm_bus::say!(
        "fake-panda: FCI on {}:{}, hand on {}:{}, physics {:?}",
        cli.ip,
        robot.port(),
        cli.ip,
        hand.port(),
        cli.physics
    );
    let cycles = cli.duration.map(|d| (d * 1000.0).round() as u64);
    let mut refresh = 0u32;
    run_every_ms(|| {
        timed("the robot cycle", || robot.cycle(arm.as_mut()));
        timed("the hand cycle", || hand.cycle(fingers.as_mut()));
        refresh += 1;
        if refresh.is_multiple_of(100) {
            timed("update_connections", || bus.update_connections());
        }
        if refresh.is_multiple_of(1000) {
            timed("the report", || write_run_report(&report(&robot, &hand)));
        }
        !(motm_bus::termination::termination_requested()
            || cycles.is_some_and(|n| robot.counters().cycles >= n))
    });
    motm_bus::say!("fake-panda: {}", robot.summary());
    write_run_report(&report(&robot, &hand));
    if let Some(path) = &cli.report {
        let json = serde_json::to_string_pretty(&report(&robot, &hand)).expect("JSON");
        std::fs::write(path, json + "\n").map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(robot.counters().violations.commands == 0)
}

/// The `fake-panda` process: parses its flags, serves until stopped, and returns its exit status.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(EXIT_VIOLATIONS),
        Err(e) => {
            motm_bus::say!("fake-panda: {e}");
            ExitCode::from(EXIT_BAD_INPUT)
        }
    }
}
