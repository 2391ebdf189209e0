//! The loop of a real base: the same base driver task as the sim backend ([`BaseDriverTask`]:
//! the limits, staleness and safe-stop), odometry from the hardware, and a safe stop when the
//! hardware is not fit to drive.
//!
//! Each cycle [`BaseLoop::cycle`] reads what the hardware sent. The base is *faulted* when its
//! odometry is older than the stale limit (or never came), when reading it failed (a bad
//! packet, a dropped connection: counted, never turned into a command) or when the hardware
//! reports a fault (e-stop, another control mode). On entering a fault the loop sends the
//! hardware's safe stop (zero velocity, then its stop command) and then zero every cycle, while
//! the task's hardware hold ramps the driver's own output to zero. It leaves the fault only when the
//! hardware is fit again and the driver's output has reached zero, so driving resumes from
//! rest within the acceleration limits.

use std::time::Duration;

use motm_bus::{Bus, BusError, Flow, LoopExit, ServiceLoop};
use motm_core::velocity_driver::VelocityDriver;
use motm_driver::hardware::{StackPorts, from_hardware};
use motm_driver::status_message;
use motm_graph::{LD60_DRIVER, Task};
use motm_msgs::{
    BaseOdometry, BaseVelocityCommand, DriverStatus, Message, SafeStop, SafeStopReason,
};
use motm_tasks::driver::{BaseDriverInputs, BaseDriverOutputs, BaseDriverTask};

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

impl<H: BaseHardware + ?Sized> BaseHardware for Box<H> {
    fn poll(&mut self, now_ns: u64) -> Result<Option<BaseState>, String> {
        (**self).poll(now_ns)
    }
    fn drive(&mut self, v: f64, omega: f64) -> Result<(), String> {
        (**self).drive(v, omega)
    }
    fn safe_stop(&mut self) -> Result<(), String> {
        (**self).safe_stop()
    }
    fn fault(&self, now_ns: u64) -> Option<String> {
        (**self).fault(now_ns)
    }
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
    /// The odometry to re-publish (a new state that is not stale).
    pub odometry: Option<BaseOdometry>,
    /// The status message, when due.
    pub status: Option<DriverStatus>,
    /// A new state from the hardware.
    pub state: Option<BaseState>,
    /// The velocity sent.
    pub sent: Option<(f64, f64)>,
    /// The fault the base is held stopped for.
    pub fault: Option<BaseFault>,
}

/// The base loop over hardware `H`: the base driver task of every backend
/// ([`BaseDriverTask`]), stepped with the hardware's odometry as its `hw_state` and its
/// `hw_command` sent to the hardware.
pub struct BaseLoop<H> {
    hardware: H,
    task: BaseDriverTask,
    inputs: BaseDriverInputs,
    stale_after_ns: u64,
    state: Option<(BaseState, u64)>,
    states: u64,
    faulted: bool,
    counters: BaseCounters,
}

impl<H: BaseHardware> BaseLoop<H> {
    /// A loop driving `hardware` through `driver` (axes `[v, ω]`, a status every
    /// `status_every` cycles); odometry older than `stale_after` is stale.
    pub fn new(
        hardware: H,
        driver: VelocityDriver,
        status_every: u64,
        stale_after: Duration,
    ) -> Self {
        Self {
            hardware,
            task: BaseDriverTask::new(driver, status_every),
            inputs: BaseDriverInputs::default(),
            stale_after_ns: stale_after.as_nanos() as u64,
            state: None,
            states: 0,
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

    /// The driver task (its counters feed the status message).
    pub fn task(&self) -> &BaseDriverTask {
        &self.task
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
        let mut m = BaseVelocityCommand::zeroed();
        m.header.stamp_ns = stamp_ns;
        m.v = v;
        m.omega = omega;
        self.inputs.commands.push(m);
    }

    /// Takes in the stack's inputs of one cycle (every command sample, safe-stop).
    pub fn receive_stack(&mut self, stack: &mut BaseDriverInputs) {
        self.inputs.commands.append(&mut stack.commands);
        self.inputs.safe_stop = stack.safe_stop;
    }

    /// One cycle at `now_ns` (`safe_stop`: the stack's safe-stop flag, on top of the one
    /// [`BaseLoop::receive_stack`] took in).
    pub fn cycle(&mut self, now_ns: u64, safe_stop: bool) -> CycleOutput {
        let mut out = CycleOutput::default();
        let mut fault = None;
        match self.hardware.poll(now_ns) {
            Ok(Some(s)) => {
                self.state = Some((s, now_ns));
                self.states += 1;
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
        // The task measures (and re-publishes) only odometry that is not stale.
        self.inputs.hw_state = self
            .state
            .filter(|_| !stale)
            .map(|(s, at)| from_hardware(odometry_message(&s), self.states, at));
        let stack_safe_stop = self.inputs.safe_stop;
        if safe_stop {
            self.inputs.safe_stop = Some(raised());
        }
        let entering = fault.is_some() && !self.faulted;
        self.task.set_hardware_hold(fault.is_some() || self.faulted);
        let step = self.task.step(now_ns, &self.inputs);
        self.inputs.commands.clear();
        self.inputs.safe_stop = stack_safe_stop;
        out.odometry = step.odometry;
        out.status = step.status;
        let velocity = step.hw_command.map(|c| (c.v, c.omega));
        if fault.is_some() || self.faulted {
            if entering {
                self.faulted = true;
                self.counters.faults += 1;
                self.counters.safe_stops += 1;
                if let Err(e) = self.hardware.safe_stop() {
                    self.counters.hardware_errors += 1;
                    motm_bus::say!("ld60-driver: safe stop: {e}");
                }
            } else if let Err(_e) = self.hardware.drive(0.0, 0.0) {
                self.counters.hardware_errors += 1;
            } else {
                out.sent = Some((0.0, 0.0));
            }
            self.counters.faulted_cycles += 1;
            // Driving resumes only from rest: the driver's own output has ramped to zero.
            if fault.is_none() && velocity == Some((0.0, 0.0)) {
                self.faulted = false;
            }
            out.fault = fault;
            return out;
        }
        if let Some((v, omega)) = velocity {
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

    /// The status message now: the driver's counters; `hardware_ready` only while not
    /// faulted.
    pub fn status(&self) -> DriverStatus {
        let mut s = status_message(&self.task.counters());
        s.hardware_ready = u32::from(self.task.counters().hardware_ready && !self.faulted);
        s
    }
}

/// A raised safe-stop message.
fn raised() -> SafeStop {
    let mut m = SafeStop::zeroed();
    m.active = 1;
    m.reason = SafeStopReason::Operator.into();
    m
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
/// and `SAFETY_SAFE_STOP`, publishes `BASE_ODOMETRY` (stamped when the state arrived) and
/// `BASE_DRIVER_STATUS` (the task's outputs), with the runtime's service settings.
pub fn run_base<H: BaseHardware>(
    bus: &Bus,
    mut base: BaseLoop<H>,
    period: Duration,
) -> Result<LoopExit, BusError> {
    let mut stack = StackPorts::<BaseDriverTask>::open(bus, &LD60_DRIVER)?;
    let mut service = ServiceLoop::new(bus, motm_driver::loop_config(period))?;
    let mut last_fault = None;
    let exit = service.run_periodic(|cycle| {
        base.receive_stack(stack.read());
        let out = base.cycle(cycle.now_ns, false);
        if out.fault != last_fault {
            if let Some(f) = &out.fault {
                motm_bus::say!("{}: base held stopped: {f:?}", bus.process());
            }
            last_fault = out.fault.clone();
        }
        stack.write(BaseDriverOutputs {
            hw_command: None,
            odometry: out.odometry,
            status: out.status,
        });
        Flow::Continue
    })?;
    motm_bus::say!(
        "{}: stopped; {:?}; {}",
        bus.process(),
        base.counters(),
        motm_driver::details(&base.task().counters())
    );
    Ok(exit)
}
