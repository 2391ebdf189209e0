//! `fake-ld60`: a fake Omron LD-60 on loopback TCP (ArNetworking, ARCL) whose physics is the
//! simulator's: each cycle it publishes the velocity its last `ratioDrive` asks for on
//! sim-world's `HW_BASE_COMMAND` and takes sim-world's `HW_BASE_STATE` as the robot's
//! odometry. `--physics kinematic` runs without sim-world (a unicycle within the robot's
//! acceleration limits). On exit it prints what it counted; with `$MOTM_FAKE_REPORT_DIR` set
//! (by `motm run --hardware fake`) it also writes its counts to `fake-ld60-<pid>.json` there,
//! every second and on exit.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use crate::{FakeConfig, FakeCounters, FakeLd60, RobotLimits, spawn_kinematic};
use clap::Parser;
use motm_bus::{Bus, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
use motm_core::Robot;
use motm_core::resolve_config_dir;
use motm_msgs::{BaseOdometry, BaseVelocityCommand, Message, services};
use motm_omron::{DriveLimits, Odometry};

/// Where the robot's motion comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Physics {
    /// sim-world's base, over `motm/v1/hw/base_command` and `hw/base_state`.
    Sim,
    /// A unicycle integrated in this process.
    Kinematic,
}

/// A fake LD-60 speaking ArNetworking and ARCL.
#[derive(Parser)]
#[command(name = "fake-ld60", version, about)]
struct Cli {
    /// Folder holding robots/ (default: $MOTM_CONFIG_DIR, ./config, or the source tree's config/).
    #[arg(long)]
    config_dir: Option<PathBuf>,
    /// Robot model whose base limits the fake checks commands against.
    #[arg(long, default_value = "frankie")]
    robot: String,
    /// Listen address.
    #[arg(long, default_value = "127.0.0.1")]
    host: IpAddr,
    /// ArNetworking port.
    #[arg(long, default_value_t = motm_omron::ARNL_PORT)]
    port: u16,
    /// ARCL port (0: no ARCL server).
    #[arg(long, default_value_t = motm_omron::ARCL_PORT)]
    arcl_port: u16,
    /// ArNetworking password (user `guest`).
    #[arg(long, default_value = "")]
    password: String,
    /// transVelMax, m/s (as config/bases/ld60.toml).
    #[arg(long, default_value_t = 1.8)]
    trans_vel_max: f64,
    /// rotVelMax, rad/s (as config/bases/ld60.toml).
    #[arg(long, default_value_t = 3.0)]
    rot_vel_max: f64,
    /// The robot stops this long after the last ratioDrive, s.
    #[arg(long, default_value_t = 2.0)]
    drive_timeout: f64,
    /// The robot's updateNumbers rate, Hz: the fastest it sends (a client's request interval,
    /// when longer, sets that client's rate).
    #[arg(long, default_value_t = 10.0)]
    update_rate: f64,
    /// Stop sending updateNumbers this many seconds after the start (stale-odometry test).
    #[arg(long)]
    stop_updates_after: Option<f64>,
    /// Press the e-stop this many seconds after the start.
    #[arg(long)]
    estop_at: Option<f64>,
    /// Relieve the e-stop this many seconds after the start.
    #[arg(long)]
    estop_release_at: Option<f64>,
    /// Physics.
    #[arg(long, value_enum, default_value_t = Physics::Sim)]
    physics: Physics,
    /// Bridge rate (commands to sim-world), Hz.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
}

fn config(cli: &Cli) -> Result<FakeConfig, String> {
    let dir = resolve_config_dir(cli.config_dir.as_deref());
    let robot = Robot::load(&dir, &cli.robot).map_err(|e| e.to_string())?;
    let l = robot.limits();
    for (flag, v) in [
        ("--drive-timeout", cli.drive_timeout),
        ("--update-rate", cli.update_rate),
        ("--rate", cli.rate),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!("{flag}: must be positive, got {v}"));
        }
    }
    let arcl_addr = (cli.arcl_port != 0).then(|| SocketAddr::new(cli.host, cli.arcl_port));
    Ok(FakeConfig {
        arnl_addr: SocketAddr::new(cli.host, cli.port),
        arcl_addr,
        password: cli.password.clone(),
        drive: DriveLimits {
            trans_vel_max: cli.trans_vel_max,
            rot_vel_max: cli.rot_vel_max,
            ..FakeConfig::default().drive
        },
        limits: RobotLimits {
            v: l[1].velocity,
            omega: l[0].velocity,
            accel_v: l[1].acceleration,
            accel_omega: l[0].acceleration,
        },
        drive_timeout: Duration::from_secs_f64(cli.drive_timeout),
        update_period: Duration::from_secs_f64(1.0 / cli.update_rate),
        stop_updates_after: cli.stop_updates_after.map(Duration::from_secs_f64),
        ..FakeConfig::default()
    })
}

fn odometry(m: &BaseOdometry) -> Odometry {
    Odometry {
        x: m.x,
        y: m.y,
        yaw: m.yaw,
        v: m.v,
        omega: m.omega,
        lateral: 0.0,
        battery_v: 26.1,
        temperature_c: None,
    }
}

/// Writes the counters to `$MOTM_FAKE_REPORT_DIR/fake-ld60-<pid>.json` when that is set
/// (`motm run --hardware fake` sums the violations of every instance).
fn write_run_report(c: &FakeCounters) {
    let Some(dir) = std::env::var_os(motm_graph::STAND_IN_REPORT_DIR_ENV) else {
        return;
    };
    let path = PathBuf::from(dir).join(format!("fake-ld60-{}.json", std::process::id()));
    let json = format!(
        "{{\"violations_total\":{},\"speed_violations\":{},\"accel_violations\":{},\"clients\":{},\"ratio_drives\":{},\"stops\":{},\"drive_timeouts\":{},\"bad_packets\":{},\"unknown_commands\":{},\"updates_sent\":{}}}",
        c.speed_violations + c.accel_violations,
        c.speed_violations,
        c.accel_violations,
        c.clients,
        c.ratio_drives,
        c.stops,
        c.drive_timeouts,
        c.bad_packets,
        c.unknown_commands,
        c.updates_sent
    );
    let tmp = path.with_extension("tmp");
    if let Err(e) = std::fs::write(&tmp, json).and_then(|()| std::fs::rename(&tmp, &path)) {
        motm_bus::say!("fake-ld60: {}: {e}", path.display());
    }
}

fn run(cli: &Cli) -> Result<(), (u8, String)> {
    let config = config(cli).map_err(|e| (2, e))?;
    let fake = FakeLd60::start(config).map_err(|e| (1, format!("listen: {e}")))?;
    motm_bus::say!(
        "fake-ld60: ArNetworking on {}, ARCL on {:?}",
        fake.arnl_addr(),
        fake.arcl_addr()
    );
    let failed = |e: motm_bus::BusError| (1, e.to_string());
    let bus = Bus::open("fake-ld60").map_err(failed)?;
    let qos = Qos::default();
    let period = Duration::from_secs_f64(1.0 / cli.rate);
    let kinematic = (cli.physics == Physics::Kinematic).then(|| spawn_kinematic(&fake, period));
    let mut command = Publisher::<BaseVelocityCommand>::new(&bus, services::HW_BASE_COMMAND, &qos)
        .map_err(failed)?;
    let mut state =
        Latest::<BaseOdometry>::new(&bus, services::HW_BASE_STATE, &qos).map_err(failed)?;
    let mut service = ServiceLoop::new(
        &bus,
        LoopConfig {
            period,
            ..LoopConfig::default()
        },
    )
    .map_err(failed)?;
    let mut origin = None;
    let report_every = (cli.rate.round() as u64).max(1);
    service
        .run_periodic(|cycle| {
            if cycle.cycle % report_every == 0 {
                write_run_report(&fake.counters());
            }
            let t = cycle.now_ns - *origin.get_or_insert(cycle.now_ns);
            let t = t as f64 * 1e-9;
            if let Some(at) = cli.estop_at {
                let released = cli.estop_release_at.is_some_and(|r| t >= r);
                fake.set_estop(t >= at && !released);
            }
            if cli.physics == Physics::Sim {
                let (v, omega) = fake.commanded();
                let mut m = BaseVelocityCommand::zeroed();
                m.v = v;
                m.omega = omega;
                if let Err(e) = command.publish(m) {
                    motm_bus::say!("fake-ld60: {e}");
                }
                if state.update().unwrap_or(false)
                    && let Some(s) = state.get()
                {
                    fake.set_odometry(odometry(s));
                }
            }
            Flow::Continue
        })
        .map_err(failed)?;
    motm_bus::say!("fake-ld60: {:?}", fake.counters());
    write_run_report(&fake.counters());
    fake.shutdown();
    if let Some(k) = kinematic {
        let _ = k.join();
    }
    Ok(())
}

/// The `fake-ld60` process: parses its flags, serves until stopped, and returns its exit status.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err((code, e)) => {
            motm_bus::say!("fake-ld60: {e}");
            ExitCode::from(code)
        }
    }
}
