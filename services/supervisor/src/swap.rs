//! Hot swap of the final-phase controller, performed by the supervisor, which owns every
//! process of the stack.
//!
//! **How `motm swap` talks to the supervisor.** The requester publishes a
//! [`SwapRequest`] (request id, process, variant, optional command timeout) on
//! `SUPERVISOR_SWAP_REQUEST`; the supervisor answers on `SUPERVISOR_SWAP_STATUS` with a
//! [`SwapStatus`] carrying the same id at each stage (`Starting`, `Flipped`, then `Done` or
//! `Failed`). One swap runs at a time; a request that comes during one is answered `Busy`.
//!
//! **The sequence** (pure logic in [`motm_core::hot_swap`]):
//! 1. announce the old controller's id as active (consumers then drop anything else), and start
//!    the new process from the old one's launch arguments with `--variant <new>` and a new
//!    `--controller-id` (one more than any id used so far);
//! 2. wait for its `Running` heartbeat (a real loop iteration) and for it to command steadily
//!    (`hot_swap.steady_commands` commands on time, from its first command sample; a fixed variant publishes only while the current task is of its kind, so the swap waits
//!    for such a task, up to the command timeout); the old controller keeps control meanwhile;
//! 3. flip `CONTROL_ACTIVE_CONTROLLER` to the new id (timed midway between two commands, a
//!    quarter period clear of both, [`flip_time`]), hand the new process to the process
//!    table (which from then on restarts it, with the new arguments, if it dies) and send the
//!    old one SIGTERM; it is reaped here and never restarted;
//! 4. measure the command gap across the flip from the stamps of both controllers' commands
//!    (gripper commands and final-phase twists) and report `Done`.
//!
//! On any failure the new process is stopped and the old one stays active.

use std::process::Child;
use std::time::{Duration, Instant};

use motm_bus::{Bus, BusError, IpcConfig, Publisher, Qos, Stamp, Subscriber, monotonic_now_ns};
use motm_core::final_phase::FinalPhaseKind;
use motm_core::hot_swap::{
    HotSwap, HotSwapConfig, SwapAction, SwapFailure, SwapInput, command_gap, controller_id_of,
    flag_value, flip_is_timely, flip_time, steady, swap_args,
};
use motm_msgs::{
    ActiveController, ControllerVariant, GripperCommand, Heartbeat, Message, ProcessState,
    SwapFailureCode, SwapRequest, SwapStageCode, SwapStatus, SwappableProcess, TwistCommand,
    services,
};

use crate::LaunchSpec;
use crate::process_table::{ProcessTable, child_command, signal};

/// The final-phase controller's own `--controller-id` default, assumed when its launch
/// arguments name none.
pub const DEFAULT_CONTROLLER_ID: u32 = 1;

/// Attempts at timing the flip while both controllers are on time (see [`SwapDriver::flip`]);
/// each waits less than a period, so the flip comes within 20 periods.
const FLIP_TRIES: usize = 20;

/// Most command stamps kept per controller during one swap (a minute at 200 Hz, two streams).
const MAX_STAMPS: usize = 24_000;

/// The final-phase controller kind of a variant code (the reacher has none).
fn kind_of(variant: ControllerVariant) -> Option<FinalPhaseKind> {
    match variant {
        ControllerVariant::Reacher => None,
        ControllerVariant::Grasp => Some(FinalPhaseKind::Grasp),
        ControllerVariant::Place => Some(FinalPhaseKind::Drop),
        ControllerVariant::PressButton => Some(FinalPhaseKind::PressButton),
    }
}

/// The variant code of a final-phase controller kind.
pub fn variant_of(kind: FinalPhaseKind) -> ControllerVariant {
    match kind {
        FinalPhaseKind::Grasp => ControllerVariant::Grasp,
        FinalPhaseKind::Drop => ControllerVariant::Place,
        FinalPhaseKind::PressButton => ControllerVariant::PressButton,
    }
}

/// The fixed variant in a controller's launch arguments; a mission-following controller (no
/// `--variant`) is announced as `Grasp`, its first task's variant.
fn launched_variant(args: &[String]) -> ControllerVariant {
    flag_value(args, "--variant")
        .and_then(|v| v.parse::<FinalPhaseKind>().ok())
        .map_or(ControllerVariant::Grasp, variant_of)
}

/// Waits until the monotonic clock reaches `target_ns` (less than a control period, once per
/// swap): a sleep for the bulk, then a short spin, since a sleep alone overshoots by up to a
/// scheduler tick.
fn wait_until(target_ns: u64) {
    const SPIN_NS: u64 = 300_000;
    let now = monotonic_now_ns();
    if target_ns > now + SPIN_NS {
        std::thread::sleep(Duration::from_nanos(target_ns - now - SPIN_NS));
    }
    while monotonic_now_ns() < target_ns {
        std::hint::spin_loop();
    }
}

/// A swap in progress.
struct InProgress {
    name: &'static str,
    swap: HotSwap,
    spec: LaunchSpec,
    /// The new process until the table adopts it at the flip.
    child: Option<Child>,
    report: SwapStatus,
    heartbeat_seen: bool,
    command_seen: bool,
    old_stamps: Vec<u64>,
    new_stamps: Vec<u64>,
}

/// A process on its way out: SIGTERM sent at `since`, reaped here.
struct Retiring {
    child: Child,
    since: Instant,
}

/// The supervisor's hot-swap service: requests in, status and the active-controller id out.
pub struct SwapDriver {
    config: HotSwapConfig,
    period_ns: u64,
    grace: Duration,
    ipc: IpcConfig,
    requests: Subscriber<SwapRequest>,
    status: Publisher<SwapStatus>,
    active: Publisher<ActiveController>,
    heartbeats: Subscriber<Heartbeat>,
    twists: Subscriber<TwistCommand>,
    grippers: Subscriber<GripperCommand>,
    active_id: Option<u32>,
    highest_id: u32,
    current: Option<InProgress>,
    retiring: Vec<Retiring>,
}

impl SwapDriver {
    /// Opens the swap ports on `bus`; `period_ns` is the control period, `grace` how long a
    /// retiring process may take to exit after SIGTERM, `ipc` the prefix to clean up under.
    pub fn new(
        bus: &Bus,
        config: HotSwapConfig,
        period_ns: u64,
        grace: Duration,
    ) -> Result<Self, BusError> {
        let qos = Qos::default();
        let process = SwappableProcess::FinalPhase.name();
        Ok(Self {
            config,
            period_ns,
            grace,
            ipc: bus.ipc_config().clone(),
            requests: Subscriber::new(bus, services::SUPERVISOR_SWAP_REQUEST, &qos)?,
            status: Publisher::new(bus, services::SUPERVISOR_SWAP_STATUS, &qos)?,
            active: Publisher::new(bus, services::CONTROL_ACTIVE_CONTROLLER, &qos)?,
            heartbeats: Subscriber::new(bus, &services::heartbeat(process), &qos)?,
            twists: Subscriber::new(bus, services::CONTROL_FINAL_TWIST, &qos)?,
            grippers: Subscriber::new(bus, services::ARM_GRIPPER_COMMAND, &qos)?,
            active_id: None,
            highest_id: 0,
            current: None,
            retiring: Vec::new(),
        })
    }

    /// The active final-phase controller id, once a swap has named one.
    pub fn active_id(&self) -> Option<u32> {
        self.active_id
    }

    /// One supervisor cycle at `now_ns`; `base_speed` is the measured base speed (reported at
    /// the flip). Returns whether the process table changed (so its status is republished).
    pub fn poll(&mut self, table: &mut ProcessTable, now_ns: u64, base_speed: f64) -> bool {
        self.reap_retiring();
        self.take_samples();
        let mut changed = false;
        while let Ok(Some(request)) = self.requests.receive() {
            let request = *request;
            if self.current.is_some() {
                self.reject(&request, SwapFailureCode::Busy, 0, 0);
            } else {
                self.start(table, &request, now_ns);
            }
        }
        let Some(current) = self.current.as_mut() else {
            return changed;
        };
        let new_exited = current
            .child
            .as_mut()
            .is_some_and(|c| !matches!(c.try_wait(), Ok(None)));
        // The new controller takes over once it commands steadily, not at its first command.
        let steady_commands = self.config.steady_commands as usize;
        let command_steady =
            current.command_seen && steady(&current.new_stamps, self.period_ns, steady_commands);
        let action = current.swap.step(&SwapInput {
            now_ns,
            heartbeat_seen: current.heartbeat_seen,
            command_seen: command_steady,
            new_exited,
        });
        match action {
            SwapAction::Wait => {}
            SwapAction::Flip => {
                self.flip(table, base_speed);
                changed = true;
            }
            SwapAction::Finish => self.finish(),
            SwapAction::Abort(failure) => self.abort(failure),
        }
        changed
    }

    /// Stops a swap in progress and every retiring process (SIGTERM, then SIGKILL after the
    /// grace period); for the supervisor's shutdown.
    pub fn shutdown(&mut self) {
        if let Some(mut current) = self.current.take()
            && let Some(child) = current.child.take()
        {
            self.retire(child);
        }
        let deadline = Instant::now() + self.grace;
        while !self.retiring.is_empty() && Instant::now() < deadline {
            self.reap_retiring();
            // Shutdown only: a short sleep between reaping attempts, off the control path.
            std::thread::sleep(Duration::from_millis(5));
        }
        for mut r in self.retiring.drain(..) {
            let _ = r.child.kill();
            let _ = r.child.wait();
        }
    }

    /// Reads the heartbeats and command streams; records what the swap in progress needs.
    fn take_samples(&mut self) {
        let current = self.current.as_mut();
        let (new_pid, ids) = match &current {
            Some(c) => (
                c.report.new_pid,
                Some((c.report.old_controller_id, c.report.new_controller_id)),
            ),
            None => (0, None),
        };
        let mut heartbeat_seen = false;
        while let Ok(Some(beat)) = self.heartbeats.receive() {
            heartbeat_seen |=
                new_pid != 0 && beat.pid == new_pid && beat.state() == Some(ProcessState::Running);
        }
        let mut stamps: Vec<(u32, u64)> = Vec::new();
        while let Ok(Some(m)) = self.twists.receive() {
            stamps.push((m.controller_id, m.header.stamp_ns));
        }
        while let Ok(Some(m)) = self.grippers.receive() {
            stamps.push((m.controller_id, m.header.stamp_ns));
        }
        let (Some(current), Some((old_id, new_id))) = (current, ids) else {
            return;
        };
        current.heartbeat_seen |= heartbeat_seen;
        for (id, stamp) in stamps {
            if id == new_id {
                current.command_seen = true;
                if current.new_stamps.len() < MAX_STAMPS {
                    current.new_stamps.push(stamp);
                }
            } else if id == old_id && current.old_stamps.len() < MAX_STAMPS {
                current.old_stamps.push(stamp);
            }
        }
    }

    /// Starts the swap of `request`.
    fn start(&mut self, table: &ProcessTable, request: &SwapRequest, now_ns: u64) {
        let (Ok(process), Ok(variant)) = (
            SwappableProcess::try_from(request.process),
            ControllerVariant::try_from(request.variant),
        ) else {
            // The subscriber validated both codes; unreachable for a valid sample.
            return;
        };
        let Some(kind) = kind_of(variant) else {
            return;
        };
        let name = process.name();
        let (Some(old_pid), Some(old_spec)) = (table.pid(name), table.spec(name).cloned()) else {
            self.reject(request, SwapFailureCode::NotRunning, 0, 0);
            return;
        };
        let old_id = controller_id_of(&old_spec.args, DEFAULT_CONTROLLER_ID);
        self.highest_id = self.highest_id.max(old_id);
        let new_id = self.highest_id + 1;
        self.highest_id = new_id;
        if self.active_id != Some(old_id) {
            // Consumers accept any controller until one is named: name the old one before the
            // new one can publish.
            self.publish_active(old_id, launched_variant(&old_spec.args), None);
        }
        let spec = LaunchSpec {
            args: swap_args(&old_spec.args, kind.name(), new_id),
            ..old_spec
        };
        let mut report = SwapStatus::zeroed();
        report.request_id = request.request_id;
        report.stage = SwapStageCode::Starting.into();
        report.old_pid = old_pid;
        report.old_controller_id = old_id;
        report.new_controller_id = new_id;
        report.variant = variant.into();
        let child = match child_command(&spec).spawn() {
            Ok(child) => child,
            Err(e) => {
                motm_bus::say!(
                    "supervisor: swap {}: cannot start {}: {e}",
                    request.request_id,
                    spec.program.display()
                );
                self.reject(request, SwapFailureCode::SpawnFailed, old_pid, old_id);
                return;
            }
        };
        report.new_pid = child.id();
        motm_bus::say!(
            "supervisor: swap {}: started {name} {} (pid {}, controller id {new_id}) beside pid {old_pid} (controller id {old_id})",
            request.request_id,
            kind.name(),
            child.id()
        );
        let timeout_ms =
            (request.command_timeout_ms > 0).then_some(request.command_timeout_ms as f64);
        self.current = Some(InProgress {
            name,
            swap: HotSwap::new(self.config, now_ns, self.period_ns, timeout_ms),
            spec,
            child: Some(child),
            report,
            heartbeat_seen: false,
            command_seen: false,
            old_stamps: Vec::new(),
            new_stamps: Vec::new(),
        });
        let _ = self.status.publish(report);
    }

    /// Flips the active id at the best moment within a period ([`flip_time`]) at which both
    /// controllers are on time, hands the new process to the table and stops the old one.
    fn flip(&mut self, table: &mut ProcessTable, base_speed: f64) {
        // A few tries at most: each waits less than a period.
        for _ in 0..FLIP_TRIES {
            let Some((old, new)) = self.last_stamps() else {
                break;
            };
            let now = monotonic_now_ns();
            if now.saturating_sub(old) >= 2 * self.period_ns {
                // The old controller does not command (not its task): nothing to time.
                break;
            }
            wait_until(flip_time(now, old, new, self.period_ns));
            self.take_samples();
            // Flip only while both controllers are on time: at the chosen moment the gap the
            // flip would make leaves a quarter period to spare ([`flip_is_timely`]). A
            // controller silent for longer is in a late cycle, or the wait overslept: wait for
            // the next commands and time the flip again.
            if let Some((old, new)) = self.last_stamps()
                && flip_is_timely(monotonic_now_ns(), old, new, self.period_ns)
            {
                break;
            }
        }
        self.flip_now(table, base_speed);
    }

    /// The newest command stamps of the old and the new controller in the swap in progress.
    fn last_stamps(&self) -> Option<(u64, u64)> {
        let c = self.current.as_ref()?;
        Some((
            c.old_stamps.iter().copied().max()?,
            c.new_stamps.iter().copied().max()?,
        ))
    }

    /// Flips at once (see [`SwapDriver::flip`]). The command queues are read just before and
    /// just after, so that no command near the flip is lost to a full queue.
    fn flip_now(&mut self, table: &mut ProcessTable, base_speed: f64) {
        self.take_samples();
        let Some(mut current) = self.current.take() else {
            return;
        };
        let new_id = current.report.new_controller_id;
        let variant =
            ControllerVariant::try_from(current.report.variant).unwrap_or(ControllerVariant::Grasp);
        let flip_ns = monotonic_now_ns();
        self.publish_active(new_id, variant, Some(flip_ns));
        if let Some(child) = current.child.take() {
            match table.adopt(current.name, current.spec.clone(), child, flip_ns) {
                Ok(Some(old)) => self.retire(old),
                Ok(None) => {}
                Err(child) => self.retire(child),
            }
        }
        let r = &mut current.report;
        r.stage = SwapStageCode::Flipped.into();
        r.flip_stamp_ns = flip_ns;
        r.heartbeat_wait_ns = current.swap.heartbeat_wait_ns().unwrap_or(0);
        r.command_wait_ns = current.swap.command_wait_ns().unwrap_or(0);
        r.base_speed = if base_speed.is_finite() {
            base_speed
        } else {
            0.0
        };
        motm_bus::say!(
            "supervisor: swap {}: controller id {} active (heartbeat after {:.0} ms, first command after {:.0} ms); stopping pid {}",
            r.request_id,
            new_id,
            r.heartbeat_wait_ns as f64 / 1e6,
            r.command_wait_ns as f64 / 1e6,
            r.old_pid
        );
        let _ = self.status.publish(current.report);
        self.current = Some(current);
        self.take_samples();
    }

    /// Measures the gap and reports success.
    fn finish(&mut self) {
        let Some(mut current) = self.current.take() else {
            return;
        };
        let r = &mut current.report;
        match command_gap(
            &current.old_stamps,
            &current.new_stamps,
            r.flip_stamp_ns,
            current.swap.window_ns(),
        ) {
            Some(gap) => {
                r.command_gap_ns = gap.gap_ns;
                r.stamp_gap_ns = gap.stamp_gap_ns;
                motm_bus::say!(
                    "supervisor: swap {}: done; command gap {:.2} ms (raw stamps {:.2} ms, {} old and {} new commands around the flip)",
                    r.request_id,
                    gap.gap_ns as f64 / 1e6,
                    gap.stamp_gap_ns as f64 / 1e6,
                    gap.old_samples,
                    gap.new_samples
                );
            }
            None => motm_bus::say!(
                "supervisor: swap {}: done; no command stream around the flip to measure",
                r.request_id
            ),
        }
        r.stage = SwapStageCode::Done.into();
        let _ = self.status.publish(current.report);
    }

    /// Stops the new process and reports the failure; the old controller stays active.
    fn abort(&mut self, failure: SwapFailure) {
        let Some(mut current) = self.current.take() else {
            return;
        };
        if let Some(child) = current.child.take() {
            self.retire(child);
        }
        let code = match failure {
            SwapFailure::NoHeartbeat => SwapFailureCode::NoHeartbeat,
            SwapFailure::NoCommand => SwapFailureCode::NoCommand,
            SwapFailure::NewExited => SwapFailureCode::NewExited,
        };
        motm_bus::say!(
            "supervisor: swap {}: failed ({code:?}); controller id {} stays active",
            current.report.request_id,
            current.report.old_controller_id
        );
        current.report.stage = SwapStageCode::Failed.into();
        current.report.failure = code.into();
        let _ = self.status.publish(current.report);
    }

    /// Answers `request` with a failure before anything started.
    fn reject(&mut self, request: &SwapRequest, code: SwapFailureCode, old_pid: u32, old_id: u32) {
        motm_bus::say!(
            "supervisor: swap {}: refused ({code:?})",
            request.request_id
        );
        let mut report = SwapStatus::zeroed();
        report.request_id = request.request_id;
        report.stage = SwapStageCode::Failed.into();
        report.failure = code.into();
        report.variant = request.variant;
        report.old_pid = old_pid;
        report.old_controller_id = old_id;
        let _ = self.status.publish(report);
    }

    /// Publishes the active controller id (stamped `at`, or now).
    fn publish_active(&mut self, id: u32, variant: ControllerVariant, at: Option<u64>) {
        let mut m = ActiveController::zeroed();
        m.controller_id = id;
        m.variant = variant.into();
        let stamp = at.map_or(Stamp::Now, Stamp::At);
        if let Err(e) = self.active.publish_stamped(stamp, m) {
            motm_bus::say!("supervisor: cannot publish the active controller: {e}");
        }
        self.active_id = Some(id);
    }

    /// Sends SIGTERM (and SIGCONT, so a stopped process can act on it) and keeps the child
    /// to reap it.
    fn retire(&mut self, child: Child) {
        signal(child.id(), libc::SIGTERM);
        signal(child.id(), libc::SIGCONT);
        self.retiring.push(Retiring {
            child,
            since: Instant::now(),
        });
    }

    /// Reaps retiring processes that exited; SIGKILLs those past the grace period. Cleans
    /// their iceoryx2 resources after a reap.
    fn reap_retiring(&mut self) {
        let before = self.retiring.len();
        let grace = self.grace;
        self.retiring.retain_mut(|r| {
            if let Ok(Some(status)) = r.child.try_wait() {
                motm_bus::say!("supervisor: retired pid {} exited ({status})", r.child.id());
                return false;
            }
            if r.since.elapsed() > grace {
                let _ = r.child.kill();
                let _ = r.child.wait();
                motm_bus::say!("supervisor: retired pid {} killed", r.child.id());
                return false;
            }
            true
        });
        if self.retiring.len() < before {
            let _ = motm_bus::cleanup_dead_nodes(&self.ipc);
        }
    }
}

impl Drop for SwapDriver {
    /// Never leaves a child behind: kill and reap what is left.
    fn drop(&mut self) {
        if let Some(child) = self.current.as_mut().and_then(|c| c.child.as_mut()) {
            let _ = child.kill();
            let _ = child.wait();
        }
        for r in &mut self.retiring {
            let _ = r.child.kill();
            let _ = r.child.wait();
        }
    }
}
