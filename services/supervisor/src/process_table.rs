//! The supervisor's process table: it starts each process, reaps it when it dies (`waitpid`
//! through [`std::process::Child::try_wait`]), removes the dead node's iceoryx2 resources, and
//! restarts it after the backoff of [`RestartBackoff`]. On shutdown it sends SIGTERM in reverse
//! start order, waits, SIGKILLs what is left and reaps everything.
//!
//! Every child runs in its own process group (a Ctrl-C on the terminal reaches only the
//! supervisor, which then stops the children in order) and gets SIGTERM if the supervisor dies
//! (`PR_SET_PDEATHSIG`), so no child outlives it.

use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use motm_bus::{IpcConfig, cleanup_dead_nodes};
use motm_core::restart_policy::{RestartBackoff, RestartDecision, RestartPolicy};
use motm_msgs::{MAX_SUPERVISED_PROCESSES, Message, SupervisedState, SupervisorStatus};

/// How to launch one process.
#[derive(Debug, Clone, PartialEq)]
pub struct LaunchSpec {
    /// Process name (heartbeat name).
    pub name: String,
    /// Executable.
    pub program: PathBuf,
    /// Arguments.
    pub args: Vec<String>,
    /// Extra environment variables (on top of the supervisor's own environment).
    pub env: Vec<(String, String)>,
}

/// Something that happened to a process, for the supervisor's log.
#[derive(Debug, Clone, PartialEq)]
pub enum TableEvent {
    /// A process started.
    Started {
        /// Process name.
        name: String,
        /// Its pid.
        pid: u32,
        /// Whether this was a restart.
        restart: bool,
    },
    /// A process exited and was reaped.
    Exited {
        /// Process name.
        name: String,
        /// Its pid.
        pid: u32,
        /// Exit code, or minus the signal number.
        exit: i32,
        /// When it will be restarted (`None`: it will not be).
        restart_in: Option<Duration>,
    },
    /// A process could not be spawned.
    SpawnFailed {
        /// Process name.
        name: String,
        /// Why.
        error: String,
    },
    /// Dead-node cleanup after an exit could not remove everything.
    CleanupFailed {
        /// Process name.
        name: String,
        /// Why.
        error: String,
    },
}

/// One row of the table.
#[derive(Debug)]
struct Entry {
    spec: LaunchSpec,
    child: Option<Child>,
    backoff: RestartBackoff,
    state: SupervisedState,
    restart_at_ns: Option<u64>,
    last_exit: i32,
}

/// The processes a supervisor manages.
#[derive(Debug)]
pub struct ProcessTable {
    entries: Vec<Entry>,
    ipc: IpcConfig,
    shutting_down: bool,
}

/// Exit code of a status, or minus the signal that ended the process.
fn exit_code(status: ExitStatus) -> i32 {
    status
        .code()
        .or_else(|| status.signal().map(|s| -s))
        .unwrap_or(i32::MIN)
}

impl ProcessTable {
    /// A table of `specs` (at most [`MAX_SUPERVISED_PROCESSES`]), restarted under `policy`,
    /// whose dead nodes are cleaned under `ipc` (the prefix the children use).
    pub fn new(specs: Vec<LaunchSpec>, policy: RestartPolicy, ipc: IpcConfig) -> Self {
        assert!(
            specs.len() <= MAX_SUPERVISED_PROCESSES,
            "too many processes"
        );
        Self {
            entries: specs
                .into_iter()
                .map(|spec| Entry {
                    spec,
                    child: None,
                    backoff: RestartBackoff::new(policy),
                    state: SupervisedState::Pending,
                    restart_at_ns: None,
                    last_exit: 0,
                })
                .collect(),
            ipc,
            shutting_down: false,
        }
    }

    /// Starts every process not started yet, in order.
    pub fn start_all(&mut self, now_ns: u64) -> Vec<TableEvent> {
        let mut events = Vec::new();
        for index in 0..self.entries.len() {
            if self.entries[index].state == SupervisedState::Pending {
                self.spawn(index, now_ns, false, &mut events);
            }
        }
        events
    }

    /// Reaps processes that exited, schedules their restarts and performs the restarts that
    /// are due at `now_ns`. Never blocks.
    pub fn poll(&mut self, now_ns: u64) -> Vec<TableEvent> {
        let mut events = Vec::new();
        let mut reaped = false;
        for entry in &mut self.entries {
            let Some(child) = entry.child.as_mut() else {
                continue;
            };
            let Ok(Some(status)) = child.try_wait() else {
                continue;
            };
            let pid = child.id();
            entry.child = None;
            entry.last_exit = exit_code(status);
            reaped = true;
            let restart_in = if self.shutting_down {
                entry.state = SupervisedState::Stopped;
                None
            } else {
                match entry.backoff.exited(now_ns) {
                    RestartDecision::RestartAt(at) => {
                        entry.state = SupervisedState::Restarting;
                        entry.restart_at_ns = Some(at);
                        Some(Duration::from_nanos(at - now_ns))
                    }
                    RestartDecision::GiveUp => {
                        entry.state = SupervisedState::Failed;
                        None
                    }
                }
            };
            events.push(TableEvent::Exited {
                name: entry.spec.name.clone(),
                pid,
                exit: entry.last_exit,
                restart_in,
            });
        }
        if reaped {
            // Reaped, so the dead nodes' liveness locks are released: clean up before any
            // restart, so the new instance finds its publisher and subscriber slots free.
            self.cleanup(&mut events);
        }
        if !self.shutting_down {
            for index in 0..self.entries.len() {
                let entry = &self.entries[index];
                if entry.state == SupervisedState::Restarting
                    && entry.restart_at_ns.is_some_and(|at| now_ns >= at)
                {
                    self.spawn(index, now_ns, true, &mut events);
                }
            }
        }
        events
    }

    /// Stops every process: SIGTERM in reverse start order (and SIGCONT, so a stopped process
    /// can act on it), up to `grace` for them to exit, then SIGKILL; reaps all and cleans up.
    pub fn shutdown(&mut self, grace: Duration) -> Vec<TableEvent> {
        self.shutting_down = true;
        let mut events = Vec::new();
        for entry in self.entries.iter_mut().rev() {
            if let Some(child) = &entry.child {
                signal(child.id(), libc::SIGTERM);
                signal(child.id(), libc::SIGCONT);
            }
            if entry.child.is_none() && entry.state != SupervisedState::Failed {
                entry.state = SupervisedState::Stopped;
            }
        }
        let deadline = Instant::now() + grace;
        loop {
            events.extend(self.poll(0));
            if self.running() == 0 {
                break;
            }
            if Instant::now() >= deadline {
                for entry in &mut self.entries {
                    if let Some(child) = entry.child.as_mut() {
                        let _ = child.kill();
                        let _ = child.wait();
                    }
                }
                events.extend(self.poll(0));
                break;
            }
            // Shutdown only: a short sleep between reaping attempts, off the control path.
            std::thread::sleep(Duration::from_millis(5));
        }
        self.cleanup(&mut events);
        events
    }

    /// Processes currently running.
    pub fn running(&self) -> usize {
        self.entries.iter().filter(|e| e.child.is_some()).count()
    }

    /// Pids of the running processes.
    pub fn pids(&self) -> Vec<u32> {
        self.entries
            .iter()
            .filter_map(|e| e.child.as_ref().map(Child::id))
            .collect()
    }

    /// The pid of the named process, if it runs.
    pub fn pid(&self, name: &str) -> Option<u32> {
        self.entry(name)?.child.as_ref().map(Child::id)
    }

    /// Restarts of the named process so far.
    pub fn restarts(&self, name: &str) -> Option<u32> {
        self.entry(name).map(|e| e.backoff.restarts())
    }

    /// State of the named process.
    pub fn state(&self, name: &str) -> Option<SupervisedState> {
        self.entry(name).map(|e| e.state)
    }

    /// The table as a [`SupervisorStatus`] message (header left for the publisher to stamp).
    pub fn status(&self) -> SupervisorStatus {
        let mut status = SupervisorStatus::zeroed();
        status.process_count = self.entries.len() as u32;
        status.shutting_down = u32::from(self.shutting_down);
        for (row, entry) in status.processes.iter_mut().zip(&self.entries) {
            row.set_name(&entry.spec.name);
            row.pid = entry.child.as_ref().map_or(0, Child::id);
            row.state = entry.state.into();
            row.restarts = entry.backoff.restarts();
            row.last_exit = entry.last_exit;
        }
        status
    }

    /// How the named process is launched (after a hot swap: the new variant's arguments).
    pub fn spec(&self, name: &str) -> Option<&LaunchSpec> {
        self.entry(name).map(|e| &e.spec)
    }

    /// Hot swap: makes the running `child`, started from `spec` at `started_ns`, the named
    /// process's instance (not counted as a restart), so that from now on the table reaps it and restarts it (from `spec`) when it dies.
    /// Returns the previous instance, which the table no longer watches: the caller stops and
    /// reaps it. `None` (and `child` is handed back) when the name is unknown or the table
    /// is shutting down.
    pub fn adopt(
        &mut self,
        name: &str,
        spec: LaunchSpec,
        child: Child,
        started_ns: u64,
    ) -> Result<Option<Child>, Child> {
        if self.shutting_down {
            return Err(child);
        }
        let Some(entry) = self.entries.iter_mut().find(|e| e.spec.name == name) else {
            return Err(child);
        };
        entry.spec = spec;
        entry.backoff.started(started_ns, false);
        entry.state = SupervisedState::Running;
        entry.restart_at_ns = None;
        Ok(entry.child.replace(child))
    }

    fn entry(&self, name: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.spec.name == name)
    }

    /// Spawns entry `index`.
    fn spawn(&mut self, index: usize, now_ns: u64, restart: bool, events: &mut Vec<TableEvent>) {
        let entry = &mut self.entries[index];
        let mut command = child_command(&entry.spec);
        entry.backoff.started(now_ns, restart);
        match command.spawn() {
            Ok(child) => {
                events.push(TableEvent::Started {
                    name: entry.spec.name.clone(),
                    pid: child.id(),
                    restart,
                });
                entry.child = Some(child);
                entry.state = SupervisedState::Running;
                entry.restart_at_ns = None;
            }
            Err(e) => {
                events.push(TableEvent::SpawnFailed {
                    name: entry.spec.name.clone(),
                    error: format!("{}: {e}", entry.spec.program.display()),
                });
                match entry.backoff.exited(now_ns) {
                    RestartDecision::RestartAt(at) => {
                        entry.state = SupervisedState::Restarting;
                        entry.restart_at_ns = Some(at);
                    }
                    RestartDecision::GiveUp => entry.state = SupervisedState::Failed,
                }
            }
        }
    }

    /// Removes dead nodes' resources, recording a failure as an event.
    fn cleanup(&self, events: &mut Vec<TableEvent>) {
        match cleanup_dead_nodes(&self.ipc) {
            Ok(report) if report.failed > 0 => events.push(TableEvent::CleanupFailed {
                name: "(dead nodes)".into(),
                error: format!("{} dead node(s) could not be cleaned", report.failed),
            }),
            Ok(_) => {}
            Err(e) => events.push(TableEvent::CleanupFailed {
                name: "(dead nodes)".into(),
                error: e.to_string(),
            }),
        }
    }
}

impl Drop for ProcessTable {
    /// Never leaves a child behind, even when the supervisor unwinds: kill and reap the rest.
    fn drop(&mut self) {
        for entry in &mut self.entries {
            if let Some(child) = entry.child.as_mut() {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

/// The command that starts a supervised child from `spec`: its own process group (a Ctrl-C on
/// the terminal reaches only the supervisor), SIGTERM when the supervisor dies, and none of
/// the supervisor's systemd notification variables.
pub fn child_command(spec: &LaunchSpec) -> Command {
    let parent = std::process::id() as libc::pid_t;
    let mut command = Command::new(&spec.program);
    command.args(&spec.args);
    command.envs(spec.env.iter().map(|(k, v)| (k, v)));
    // The supervisor's own systemd notification socket and watchdog are not the children's.
    for var in ["NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"] {
        command.env_remove(var);
    }
    // SAFETY: only async-signal-safe calls (setpgid, prctl, getppid) between fork and exec.
    unsafe {
        command.pre_exec(move || {
            if libc::setpgid(0, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The supervisor died before the death signal was armed.
            if libc::getppid() != parent {
                return Err(std::io::Error::other("supervisor exited"));
            }
            Ok(())
        });
    }
    command
}

/// Sends `sig` to `pid` (errors ignored: the process may just have exited).
pub fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill(2) has no memory-safety preconditions.
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}
