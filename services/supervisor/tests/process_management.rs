//! Process management with real processes (`heartbeat-probe`): start, kill -9, restart with
//! backoff, crash loops, clean shutdown, no orphans and no stale shared memory. Waits are
//! bounded by generous timeouts only to fail instead of hanging; no timing is asserted.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use motm_bus::{Bus, IpcConfig, Latest, Qos, cleanup_dead_nodes, remove_domain};
use motm_core::restart_policy::RestartPolicy;
use motm_msgs::{Heartbeat, SupervisedState, SupervisorStatus, services};
use motm_supervisor::{LaunchSpec, ProcessTable, TableEvent};

const PROBE: &str = env!("CARGO_BIN_EXE_heartbeat-probe");
const SUPERVISOR: &str = env!("CARGO_BIN_EXE_supervisor");
/// Upper bound on any wait, so a broken build fails instead of hanging.
const PATIENCE: Duration = Duration::from_secs(20);

fn ipc(test: &str) -> IpcConfig {
    IpcConfig {
        prefix: format!("motmt{}_{test}_", std::process::id()),
    }
}

fn now_ns() -> u64 {
    motm_bus::monotonic_now_ns()
}

fn probe(name: &str, ipc: &IpcConfig, extra: &[&str]) -> LaunchSpec {
    let mut args = vec!["--name".to_string(), name.to_string()];
    args.extend(extra.iter().map(|s| s.to_string()));
    LaunchSpec {
        name: name.to_string(),
        program: PathBuf::from(PROBE),
        args,
        env: vec![(motm_bus::PREFIX_ENV.to_string(), ipc.prefix.clone())],
    }
}

fn alive(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

/// Polls `condition` every few ms until it holds; panics after [`PATIENCE`].
fn wait_for(what: &str, mut condition: impl FnMut() -> bool) {
    let start = Instant::now();
    while !condition() {
        assert!(start.elapsed() < PATIENCE, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Waits for a heartbeat of `name` from process `pid`.
fn wait_heartbeat(bus: &Bus, name: &str, pid: u32) {
    let mut beat = Latest::<Heartbeat>::new(bus, &services::heartbeat(name), &Qos::default())
        .expect("heartbeat subscriber");
    wait_for(&format!("a heartbeat of {name} pid {pid}"), || {
        bus.update_connections();
        let _ = beat.update();
        beat.get().is_some_and(|b| b.pid == pid)
    });
}

/// Removes the prefix's last segment and asserts nothing is left.
fn assert_clean(ipc: &IpcConfig) {
    cleanup_dead_nodes(ipc).unwrap();
    // SAFETY: every process of this prefix has exited and every node here was dropped.
    unsafe { remove_domain(ipc) }.unwrap();
    assert_eq!(
        motm_bus::shared_memory_entries(ipc).unwrap(),
        Vec::<PathBuf>::new()
    );
}

#[test]
fn kill_9_is_reaped_cleaned_and_restarted_then_shutdown_leaves_nothing() {
    let ipc = ipc("kill");
    let mut old_pids = Vec::new();
    {
        let observer = Bus::open_with("observer", &ipc).unwrap();
        let mut table = ProcessTable::new(
            vec![probe("probe-a", &ipc, &[]), probe("probe-b", &ipc, &[])],
            RestartPolicy::default(),
            ipc.clone(),
        );
        let events = table.start_all(now_ns());
        assert_eq!(events.len(), 2, "{events:?}");
        let a = table.pid("probe-a").unwrap();
        let b = table.pid("probe-b").unwrap();
        wait_heartbeat(&observer, "probe-a", a);
        wait_heartbeat(&observer, "probe-b", b);

        // SAFETY: kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(a as i32, libc::SIGKILL) }, 0);
        let mut events = Vec::new();
        wait_for("the restart of probe-a", || {
            events.extend(table.poll(now_ns()));
            table.pid("probe-a").is_some_and(|p| p != a)
        });
        assert!(
            events.iter().any(|e| matches!(e, TableEvent::Exited { name, pid, exit: -9, restart_in: Some(_) } if name == "probe-a" && *pid == a)),
            "{events:?}"
        );
        assert!(!alive(a), "the killed process was not reaped");
        assert_eq!(table.restarts("probe-a"), Some(1));
        assert_eq!(table.restarts("probe-b"), Some(0));
        assert_eq!(table.pid("probe-b"), Some(b));
        let a2 = table.pid("probe-a").unwrap();
        // The new instance took over the dead one's node name and heartbeat service.
        wait_heartbeat(&observer, "probe-a", a2);

        let status = table.status();
        let rows = status.processes();
        assert_eq!(rows[0].name(), "probe-a");
        assert_eq!(rows[0].restarts, 1);
        assert_eq!(rows[0].last_exit, -9);
        assert_eq!(rows[0].state(), Some(SupervisedState::Running));

        old_pids.extend([a, a2, b]);
        table.shutdown(Duration::from_secs(5));
        assert_eq!(table.running(), 0);
        assert_eq!(table.state("probe-a"), Some(SupervisedState::Stopped));
        for pid in &old_pids {
            assert!(!alive(*pid), "pid {pid} outlived the shutdown");
        }
    }
    assert_clean(&ipc);
}

#[test]
fn a_crash_loop_backs_off_exponentially_and_gives_up_at_the_budget() {
    let ipc = ipc("crash");
    let policy = RestartPolicy {
        initial_backoff_ms: 20.0,
        multiplier: 2.0,
        max_backoff_ms: 1000.0,
        stable_after_ms: 60_000.0,
        max_restarts: 3,
    };
    let mut table = ProcessTable::new(
        vec![probe("crasher", &ipc, &["--exit-after", "3"])],
        policy,
        ipc.clone(),
    );
    let mut events = table.start_all(now_ns());
    wait_for("the restart budget to run out", || {
        events.extend(table.poll(now_ns()));
        table.state("crasher") == Some(SupervisedState::Failed)
    });
    let delays: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            TableEvent::Exited {
                exit, restart_in, ..
            } => {
                assert_eq!(*exit, 3, "{events:?}");
                Some(restart_in.map(|d| d.as_millis()))
            }
            _ => None,
        })
        .collect();
    assert_eq!(delays, [Some(20), Some(40), Some(80), None]);
    assert_eq!(table.restarts("crasher"), Some(3));
    assert_eq!(table.running(), 0);
    drop(table);
    assert_clean(&ipc);
}

/// Writes a stack config with one heartbeat-probe process into a fresh folder.
fn probe_stack(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("motm-sup-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("probe-stack.toml");
    std::fs::write(
        &path,
        r#"
robot = "frankie"
scenario = "exp1-dynamic"
partial = true
[restart]
initial_backoff_ms = 50.0
[[process]]
name = "heartbeat-probe"
rate_hz = 100.0
args = ["--name", "heartbeat-probe", "--rate", "{rate}"]
"#,
    )
    .unwrap();
    path
}

/// Kills the supervisor if a test fails before stopping it, so it never outlives the test.
struct SupervisorGuard(std::process::Child);

impl Drop for SupervisorGuard {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

fn start_supervisor(ipc: &IpcConfig, stack: &Path) -> SupervisorGuard {
    let bin_dir = Path::new(PROBE).parent().unwrap();
    let child = Command::new(SUPERVISOR)
        .arg("--stack")
        .arg(stack)
        .arg("--bin-dir")
        .arg(bin_dir)
        .arg("--no-mission")
        .env(motm_bus::PREFIX_ENV, &ipc.prefix)
        .stdin(Stdio::null())
        .spawn()
        .expect("supervisor starts");
    SupervisorGuard(child)
}

/// Waits for a supervisor status that satisfies `condition`, returning it.
fn wait_status(
    bus: &Bus,
    status: &mut Latest<SupervisorStatus>,
    what: &str,
    condition: impl Fn(&SupervisorStatus) -> bool,
) -> SupervisorStatus {
    let mut found = None;
    wait_for(what, || {
        bus.update_connections();
        let _ = status.update();
        found = status.get().copied().filter(|s| condition(s));
        found.is_some()
    });
    found.unwrap()
}

#[test]
fn supervisor_binary_restarts_a_killed_child_and_stops_cleanly_on_sigterm() {
    let ipc = ipc("binary");
    let stack = probe_stack("binary");
    let mut guard = start_supervisor(&ipc, &stack);
    let supervisor = &mut guard.0;
    let mut pids = Vec::new();
    {
        let observer = Bus::open_with("observer", &ipc).unwrap();
        let mut status = Latest::<SupervisorStatus>::new(
            &observer,
            services::SUPERVISOR_STATUS,
            &Qos::default(),
        )
        .unwrap();
        let first = wait_status(&observer, &mut status, "the probe to run", |s| {
            s.processes().first().is_some_and(|p| p.pid != 0)
        });
        let probe_pid = first.processes()[0].pid;
        wait_heartbeat(&observer, "heartbeat-probe", probe_pid);
        // SAFETY: kill(2) on a process of this test's stack.
        assert_eq!(unsafe { libc::kill(probe_pid as i32, libc::SIGKILL) }, 0);
        let restarted = wait_status(&observer, &mut status, "the restart", |s| {
            let row = s.processes()[0];
            row.restarts == 1 && row.pid != 0 && row.pid != probe_pid
        });
        let row = restarted.processes()[0];
        assert_eq!(row.last_exit, -9);
        assert_eq!(row.state(), Some(SupervisedState::Running));
        wait_heartbeat(&observer, "heartbeat-probe", row.pid);
        pids.extend([probe_pid, row.pid]);
    }
    // SAFETY: kill(2) on our own child.
    assert_eq!(
        unsafe { libc::kill(supervisor.id() as i32, libc::SIGTERM) },
        0
    );
    let exit = supervisor.wait().unwrap();
    assert!(exit.success(), "supervisor exit: {exit}");
    for pid in pids {
        assert!(!alive(pid), "pid {pid} is an orphan");
    }
    assert_clean(&ipc);
    let _ = std::fs::remove_dir_all(stack.parent().unwrap());
}

#[test]
fn children_do_not_outlive_a_killed_supervisor() {
    let ipc = ipc("orphan");
    let stack = probe_stack("orphan");
    let mut guard = start_supervisor(&ipc, &stack);
    let supervisor = &mut guard.0;
    let probe_pid;
    {
        let observer = Bus::open_with("observer", &ipc).unwrap();
        let mut status = Latest::<SupervisorStatus>::new(
            &observer,
            services::SUPERVISOR_STATUS,
            &Qos::default(),
        )
        .unwrap();
        let first = wait_status(&observer, &mut status, "the probe to run", |s| {
            s.processes().first().is_some_and(|p| p.pid != 0)
        });
        probe_pid = first.processes()[0].pid;
        wait_heartbeat(&observer, "heartbeat-probe", probe_pid);
    }
    supervisor.kill().unwrap();
    supervisor.wait().unwrap();
    // The probe got SIGTERM from the death signal and exits by itself (reaped by init).
    wait_for("the orphaned probe to exit", || {
        std::fs::read_to_string(format!("/proc/{probe_pid}/stat"))
            .map_or(true, |stat| stat.contains(") Z "))
    });
    assert_clean(&ipc);
    let _ = std::fs::remove_dir_all(stack.parent().unwrap());
}

#[test]
fn a_hot_swapped_instance_is_owned_and_restarted_with_its_own_arguments_the_old_one_never() {
    let ipc = ipc("adopt");
    {
        let observer = Bus::open_with("observer", &ipc).unwrap();
        let mut table = ProcessTable::new(
            vec![probe("swapped", &ipc, &["--rate", "100"])],
            RestartPolicy::default(),
            ipc.clone(),
        );
        table.start_all(now_ns());
        let old = table.pid("swapped").unwrap();
        wait_heartbeat(&observer, "swapped", old);
        // The new instance runs beside the old one (same name, another argument), then the
        // table adopts it and hands the old one back.
        let new_spec = probe("swapped", &ipc, &["--rate", "50"]);
        let child = motm_supervisor::process_table::child_command(&new_spec)
            .spawn()
            .unwrap();
        let new = child.id();
        wait_heartbeat(&observer, "swapped", new);
        let mut previous = table
            .adopt("swapped", new_spec, child, now_ns())
            .unwrap()
            .expect("the old instance");
        assert_eq!(previous.id(), old);
        assert_eq!(table.pid("swapped"), Some(new));
        assert_eq!(table.restarts("swapped"), Some(0));
        // The old instance dies: the table no longer watches it, so nothing is restarted.
        // SAFETY: kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(old as i32, libc::SIGKILL) }, 0);
        previous.wait().unwrap();
        for _ in 0..20 {
            assert_eq!(table.poll(now_ns()), Vec::new());
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(table.pid("swapped"), Some(new));
        // The new instance dies: it is restarted, from its own arguments.
        // SAFETY: kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(new as i32, libc::SIGKILL) }, 0);
        wait_for("the restart of the swapped-in instance", || {
            table.poll(now_ns());
            table.pid("swapped").is_some_and(|p| p != new)
        });
        let restarted = table.pid("swapped").unwrap();
        let cmdline = std::fs::read(format!("/proc/{restarted}/cmdline")).unwrap();
        let args: Vec<String> = cmdline
            .split(|&b| b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        assert!(
            args.windows(2).any(|w| w[0] == "--rate" && w[1] == "50"),
            "{args:?}"
        );
        assert_eq!(table.restarts("swapped"), Some(1));
        table.shutdown(Duration::from_secs(5));
        for pid in [old, new, restarted] {
            assert!(!alive(pid), "pid {pid} outlived the shutdown");
        }
    }
    assert_clean(&ipc);
}
