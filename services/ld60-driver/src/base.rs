//! The loop of a real base: commands through the same [`VelocityDriver`] limits as the sim
//! backend, odometry from the hardware, and a safe stop when the hardware is not fit to
//! drive.
//!
//! Each cycle [`BaseLoop::cycle`] reads what the hardware sent. The base is *faulted* when its
//! odometry is older than the stale limit (or never came), when reading it failed (a bad
//! packet, a dropped connection: counted, never turned into a command) or when the hardware
//! reports a fault (e-stop, another control mode). On entering a fault the loop sends the
//! hardware's safe stop (zero velocity, then its stop command) and then zero every cycle, while
//! the driver ramps its own output to zero under safe-stop. It leaves the fault only when the
//! hardware is fit again and the driver's output has reached zero, so driving resumes from
//! rest within the acceleration limits.

use std::time::Duration;

use motm_bus::{
    Bus, BusError, Flow, Latest, LoopConfig, LoopExit, Publisher, Qos, ServiceLoop, Stamp,
    Subscriber,
};
use motm_core::velocity_driver::VelocityDriver;
use motm_msgs::{BaseOdometry, BaseVelocityCommand, DriverStatus, Message, SafeStop, services};

/// The base's state as the hardware reports it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BaseState {
    /// x, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// Heading, rad.
    pub yaw: f64,
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
}

/// A base's hardware boundary.
pub trait BaseHardware {
    /// Reads everything that arrived by `now_ns`; the newest state if one came. An error is
    /// bad input or a lost connection.
    fn poll(&mut self, now_ns: u64) -> Result<Option<BaseState>, String>;
    /// Sends a velocity command.
    fn drive(&mut self, v: f64, omega: f64) -> Result<(), String>;
    /// Stops the base: zero velocity, then the hardware's stop command if it has one.
    fn safe_stop(&mut self) -> Result<(), String>;
    /// A fault the hardware reports at `now_ns` (e-stop, wrong control mode), if any.
    fn fault(&self, now_ns: u64) -> Option<String>;
}

/// Why the loop holds the base stopped.
#[derive(Debug, Clone, PartialEq)]
pub enum BaseFault {
    /// No odometry yet, or older than the stale limit.
    StaleOdometry,
    /// Reading the hardware failed.
    Hardware(String),
    /// The hardware reports a fault.
    Reported(String),
}

/// Counts of a [`BaseLoop`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BaseCounters {
    /// Failed reads or writes of the hardware.
    pub hardware_errors: u64,
    /// Times the loop entered a fault.
    pub faults: u64,
    /// Safe stops sent.
    pub safe_stops: u64,
    /// Cycles spent faulted.
    pub faulted_cycles: u64,
}

/// What one cycle did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CycleOutput {
    /// A new state from the hardware.
    pub state: Option<BaseState>,
    /// The velocity sent.
    pub sent: Option<(f64, f64)>,
    /// The fault the base is held stopped for.
    pub fault: Option<BaseFault>,
}

/// The base loop over hardware `H`.
#[derive(Debug)]
pub struct BaseLoop<H> {
    hardware: H,
    driver: VelocityDriver,
    stale_after_ns: u64,
    state: Option<(BaseState, u64)>,
    faulted: bool,
    counters: BaseCounters,
}

impl<H: BaseHardware> BaseLoop<H> {
    /// A loop driving `hardware` through `driver` (axes `[v, ω]`); odometry older than
    /// `stale_after` is stale.
    pub fn new(hardware: H, driver: VelocityDriver, stale_after: Duration) -> Self {
        Self {
            hardware,
            driver,
            stale_after_ns: stale_after.as_nanos() as u64,
            state: None,
            faulted: false,
            counters: BaseCounters::default(),
        }
    }

    /// The hardware.
    pub fn hardware(&self) -> &H {
        &self.hardware
    }

    /// The hardware, mutably.
    pub fn hardware_mut(&mut self) -> &mut H {
        &mut self.hardware
    }

    /// The velocity driver (its counters feed the status message).
    pub fn driver(&self) -> &VelocityDriver {
        &self.driver
    }

    /// Counters.
    pub fn counters(&self) -> BaseCounters {
        self.counters
    }

    /// Whether the base is held stopped.
    pub fn faulted(&self) -> bool {
        self.faulted
    }

    /// Takes in one velocity command stamped `stamp_ns`.
    pub fn receive(&mut self, stamp_ns: u64, v: f64, omega: f64) {
        self.driver.receive(stamp_ns, &[v, omega]);
    }

    /// One cycle at `now_ns` (`safe_stop`: the stack's safe-stop flag).
    pub fn cycle(&mut self, now_ns: u64, safe_stop: bool) -> CycleOutput {
        let mut out = CycleOutput::default();
        let mut fault = None;
        match self.hardware.poll(now_ns) {
            Ok(Some(s)) => {
                self.state = Some((s, now_ns));
                out.state = Some(s);
            }
            Ok(None) => {}
            Err(e) => {
                self.counters.hardware_errors += 1;
                fault = Some(BaseFault::Hardware(e));
            }
        }
        let stale = self
            .state
            .is_none_or(|(_, at)| now_ns.saturating_sub(at) > self.stale_after_ns);
        if fault.is_none() {
            fault = if stale {
                Some(BaseFault::StaleOdometry)
            } else {
                self.hardware.fault(now_ns).map(BaseFault::Reported)
            };
        }
        let measured = self.state.filter(|_| !stale).map(|(s, _)| [s.v, s.omega]);
        if fault.is_some() || self.faulted {
            if !self.faulted {
                self.faulted = true;
                self.counters.faults += 1;
                self.counters.safe_stops += 1;
                if let Err(e) = self.hardware.safe_stop() {
                    self.counters.hardware_errors += 1;
                    eprintln!("ld60-driver: safe stop: {e}");
                }
            } else if let Err(_e) = self.hardware.drive(0.0, 0.0) {
                self.counters.hardware_errors += 1;
            } else {
                out.sent = Some((0.0, 0.0));
            }
            self.counters.faulted_cycles += 1;
            let ramp = self
                .driver
                .step(now_ns, true, measured.as_ref().map(|m| m.as_slice()));
            let at_rest = ramp.is_some_and(|v| v.iter().all(|x| *x == 0.0));
            if fault.is_none() && at_rest {
                self.faulted = false;
            }
            out.fault = fault;
            return out;
        }
        if let Some(v) =
            self.driver
                .step(now_ns, safe_stop, measured.as_ref().map(|m| m.as_slice()))
        {
            let (v, omega) = (v[0], v[1]);
            match self.hardware.drive(v, omega) {
                Ok(()) => out.sent = Some((v, omega)),
                Err(e) => {
                    self.counters.hardware_errors += 1;
                    out.fault = Some(BaseFault::Hardware(e));
                }
            }
        }
        out
    }

    /// The status message: the driver's counters; `hardware_ready` only while not faulted.
    pub fn status(&self) -> DriverStatus {
        let mut s = motm_driver::status_message(&self.driver.counters());
        s.hardware_ready = u32::from(self.driver.counters().hardware_ready && !self.faulted);
        s
    }
}

/// The odometry message of `state`.
pub fn odometry_message(state: &BaseState) -> BaseOdometry {
    let mut m = BaseOdometry::zeroed();
    m.x = state.x;
    m.y = state.y;
    m.yaw = state.yaw;
    m.v = state.v;
    m.omega = state.omega;
    m
}

/// Runs `base` at `period` on the bus until SIGTERM/SIGINT: reads `BASE_VELOCITY_COMMAND`
/// and `SAFETY_SAFE_STOP`, publishes `BASE_ODOMETRY` (waking, stamped when the state arrived)
/// and `BASE_DRIVER_STATUS`.
pub fn run_base<H: BaseHardware>(
    bus: &Bus,
    mut base: BaseLoop<H>,
    period: Duration,
    status_period: Duration,
) -> Result<LoopExit, BusError> {
    let qos = Qos::default();
    let mut commands =
        Subscriber::<BaseVelocityCommand>::new(bus, services::BASE_VELOCITY_COMMAND, &qos)?;
    let mut safe_stop = Latest::<SafeStop>::new(bus, services::SAFETY_SAFE_STOP, &qos)?;
    let mut odometry = Publisher::<BaseOdometry>::new(bus, services::BASE_ODOMETRY, &qos.waking())?;
    let mut status = Publisher::<DriverStatus>::new(bus, services::BASE_DRIVER_STATUS, &qos)?;
    let mut service = ServiceLoop::new(
        bus,
        LoopConfig {
            period,
            ..LoopConfig::default()
        },
    )?;
    let status_every = (status_period.as_secs_f64() / period.as_secs_f64())
        .round()
        .max(1.0) as u64;
    let mut last_fault = None;
    service.run_periodic(|cycle| {
        while let Ok(Some(c)) = commands.receive() {
            base.receive(c.header().stamp_ns, c.v, c.omega);
        }
        safe_stop.update().ok();
        let stopped = safe_stop.get().is_some_and(|s| s.active == 1);
        let out = base.cycle(cycle.now_ns, stopped);
        if let Some(s) = out.state
            && let Err(e) = odometry.publish_stamped(Stamp::At(cycle.now_ns), odometry_message(&s))
        {
            eprintln!("{}: {e}", bus.process());
        }
        if out.fault != last_fault {
            if let Some(f) = &out.fault {
                eprintln!("{}: base held stopped: {f:?}", bus.process());
            }
            last_fault = out.fault.clone();
        }
        if cycle.cycle % status_every == 0
            && let Err(e) = status.publish(base.status())
        {
            eprintln!("{}: {e}", bus.process());
        }
        Flow::Continue
    })
}
