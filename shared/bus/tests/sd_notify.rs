//! The service loop's systemd notifications against a Unix datagram socket standing in for
//! systemd's `NOTIFY_SOCKET`: `READY=1` only once a loop iteration has completed, `WATCHDOG=1`
//! at half of `WATCHDOG_USEC` after completed iterations, `STOPPING=1` at the end, and nothing
//! at all without `NOTIFY_SOCKET`. One test in this binary, so that setting the environment
//! races with no other test thread.

use std::os::unix::net::UnixDatagram;

use motm_bus::{Bus, Flow, IpcConfig, LoopConfig, ServiceLoop, remove_domain};

/// Every datagram waiting on `socket`, without blocking.
fn drain(socket: &UnixDatagram) -> Vec<String> {
    let mut out = Vec::new();
    let mut buf = [0u8; 512];
    while let Ok(n) = socket.recv(&mut buf) {
        out.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    out
}

/// Runs a 200 Hz loop for `cycles` cycles, calling `check` with the datagrams that arrived
/// before each step.
fn run_loop(bus: &Bus, cycles: u64, mut check: impl FnMut(u64)) {
    let mut service = ServiceLoop::new(bus, LoopConfig::with_rate(200.0)).unwrap();
    service
        .run_periodic(|cycle| {
            check(cycle.cycle);
            if cycle.cycle + 1 == cycles {
                Flow::Stop
            } else {
                Flow::Continue
            }
        })
        .unwrap();
}

#[test]
fn ready_and_watchdog_follow_real_loop_iterations_and_nothing_without_a_socket() {
    let dir = std::env::temp_dir().join(format!("motm-sdnotify-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("notify.sock");
    let _ = std::fs::remove_file(&path);
    let socket = UnixDatagram::bind(&path).unwrap();
    socket.set_nonblocking(true).unwrap();
    let ipc = IpcConfig {
        prefix: format!("motmt{}_sdn_", std::process::id()),
    };
    {
        let bus = Bus::open_with("sd-notify-test", &ipc).unwrap();
        // SAFETY: the only test of this binary; no other thread reads the environment.
        unsafe {
            std::env::set_var("NOTIFY_SOCKET", &path);
            // A 40 ms watchdog: WATCHDOG=1 every 20 ms, i.e. every 4th 5 ms cycle.
            std::env::set_var("WATCHDOG_USEC", "40000");
            std::env::set_var("WATCHDOG_PID", std::process::id().to_string());
        }
        let mut seen: Vec<(u64, String)> = Vec::new();
        run_loop(&bus, 40, |cycle| {
            let got = drain(&socket);
            if cycle == 0 {
                // Created, heartbeat sent, but no iteration done: not ready yet.
                assert!(got.is_empty(), "before the first iteration: {got:?}");
            }
            seen.extend(got.into_iter().map(|m| (cycle, m)));
        });
        seen.extend(drain(&socket).into_iter().map(|m| (40, m)));
        // READY=1 (with the first WATCHDOG=1) arrives after the first iteration, once.
        assert_eq!(seen[0].0, 1, "{seen:?}");
        assert_eq!(seen[0].1, "READY=1\nWATCHDOG=1\n");
        assert_eq!(
            seen.iter().filter(|(_, m)| m.contains("READY=1")).count(),
            1
        );
        // Then WATCHDOG=1 every 20 ms of wall time (at least 200 ms pass in 40 cycles), never
        // more than one per completed iteration.
        let watchdogs = seen.iter().filter(|(_, m)| m == "WATCHDOG=1\n").count();
        assert!(
            (5..40).contains(&watchdogs),
            "{watchdogs} watchdog pings: {seen:?}"
        );
        assert_eq!(seen.last().unwrap().1, "STOPPING=1\n");

        // Without NOTIFY_SOCKET nothing is sent.
        // SAFETY: as above.
        unsafe {
            std::env::remove_var("NOTIFY_SOCKET");
        }
        run_loop(&bus, 10, |_| {});
        assert_eq!(drain(&socket), Vec::<String>::new());
    }
    // SAFETY: the bus is dropped and no other process uses this prefix.
    unsafe { remove_domain(&ipc) }.unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
