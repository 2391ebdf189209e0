//! `motm bench ipc`: per-hop latency between two processes over iceoryx2, measured in the same
//! run as a Unix-domain-socket baseline with the same payloads (64 B and one camera image).
//!
//! The `motm` binary starts itself again as the echo peer (`motm bench ipc-echo`). Each round
//! the benchmark stamps a ready payload with `CLOCK_MONOTONIC` and sends it; the peer, woken by
//! the transport (an iceoryx2 data event through the standard service loop, or a blocking
//! socket read), takes the time as soon as the whole payload is readable and sends the
//! difference back in a small acknowledgement. The next round starts when the acknowledgement
//! arrived, so hops never queue. Both processes share the same monotonic clock.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};
use iceoryx2::prelude::ZeroCopySend;
use motm_bus::{
    Bus, Flow, IpcConfig, LoopConfig, PREFIX_ENV, Publisher, Qos, ServiceLoop, Stamp, Subscriber,
    monotonic_now_ns, percentile, remove_domain, shared_memory_entries,
};
use motm_msgs::{CAMERA_HEIGHT, CAMERA_WIDTH, CameraImage, Header, Message, Rejection};
use serde_json::{Map, Value, json};

/// Arguments of `motm bench ipc`.
#[derive(Args)]
pub struct IpcArgs {
    /// Measured round trips per case.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(1..))]
    samples: u32,
    /// Unmeasured warm-up round trips per case.
    #[arg(long, default_value_t = 200)]
    warmup: u32,
    /// Print one JSON object: per case `median_us`, `p99_us`, `max_us`, `payload_bytes`, `samples`.
    #[arg(long)]
    json: bool,
}

/// Arguments of the echo peer (`motm bench ipc-echo`, started by `motm bench ipc`).
#[derive(Args)]
pub struct EchoArgs {
    /// Which case to answer.
    #[arg(long, value_enum)]
    case: Case,
    /// Socket path of the Unix-domain-socket cases.
    #[arg(long)]
    socket: Option<PathBuf>,
}

/// One benchmark case: a transport and a payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Case {
    /// iceoryx2, 64-byte payload.
    Iceoryx2Small,
    /// Unix-domain socket, 64-byte payload.
    UdsSmall,
    /// iceoryx2, one camera image.
    Iceoryx2Image,
    /// Unix-domain socket, one camera image.
    UdsImage,
}

impl Case {
    /// Every case, in report order.
    const ALL: [Case; 4] = [
        Case::Iceoryx2Small,
        Case::UdsSmall,
        Case::Iceoryx2Image,
        Case::UdsImage,
    ];

    /// Key of the case in the report.
    fn key(self) -> &'static str {
        match self {
            Case::Iceoryx2Small => "iceoryx2_64B",
            Case::UdsSmall => "uds_64B",
            Case::Iceoryx2Image => "iceoryx2_image",
            Case::UdsImage => "uds_image",
        }
    }

    /// Bytes sent per hop.
    fn payload_bytes(self) -> usize {
        match self {
            Case::Iceoryx2Small | Case::UdsSmall => size_of::<SmallPing>(),
            Case::Iceoryx2Image | Case::UdsImage => size_of::<CameraImage>(),
        }
    }

    /// Whether the case runs over a Unix-domain socket.
    fn is_socket(self) -> bool {
        matches!(self, Case::UdsSmall | Case::UdsImage)
    }
}

/// Service of the 64-byte pings.
const SMALL_PING_SERVICE: &str = "motm/v1/bench/ping_small";
/// Service of the camera-image pings.
const IMAGE_PING_SERVICE: &str = "motm/v1/bench/ping_image";
/// Service of the acknowledgements.
const ACK_SERVICE: &str = "motm/v1/bench/ack";
/// Longest wait for a peer or an acknowledgement.
const TIMEOUT: Duration = Duration::from_secs(10);
/// `ping_seq` of the acknowledgement a peer sends once its ports are up.
const READY: u64 = u64::MAX;

/// The 64-byte benchmark payload.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("motm.v1.BenchSmallPing")]
#[repr(C)]
struct SmallPing {
    /// Common header; the stamp is the send time.
    header: Header,
    /// Filler up to 64 bytes.
    filler: [u8; 40],
}

/// The peer's answer to one ping.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("motm.v1.BenchAck")]
#[repr(C)]
struct Ack {
    /// Common header.
    header: Header,
    /// Sequence number of the ping answered ([`READY`] for the start-up acknowledgement).
    ping_seq: u64,
    /// Time from the ping's stamp to its receipt by the peer, ns.
    hop_ns: u64,
}

// SAFETY: both types hold only integers; all-zero bytes are valid.
unsafe impl Message for SmallPing {
    const NAME: &'static str = "BenchSmallPing";

    fn header(&self) -> &Header {
        &self.header
    }

    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }

    fn validate_fields(&self) -> Result<(), Rejection> {
        Ok(())
    }
}

// SAFETY: see `SmallPing`.
unsafe impl Message for Ack {
    const NAME: &'static str = "BenchAck";

    fn header(&self) -> &Header {
        &self.header
    }

    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }

    fn validate_fields(&self) -> Result<(), Rejection> {
        Ok(())
    }
}

/// Latency summary of one case, µs.
struct Summary {
    median_us: f64,
    p99_us: f64,
    max_us: f64,
}

impl Summary {
    /// Summarises hop times in ns.
    fn of(hops_ns: &mut [u64]) -> Self {
        let us = |ns: u64| ns as f64 / 1000.0;
        Self {
            median_us: us(percentile(hops_ns, 50.0)),
            p99_us: us(percentile(hops_ns, 99.0)),
            max_us: us(percentile(hops_ns, 100.0)),
        }
    }
}

/// Runs `motm bench ipc`.
pub fn run(args: &IpcArgs) -> Result<(), String> {
    let ipc = IpcConfig {
        prefix: format!("motmbench{}_", std::process::id()),
    };
    let mut report = Map::new();
    let mut result = Ok(());
    for case in Case::ALL {
        match measure(case, &ipc, args.warmup, args.samples) {
            Ok(mut hops) => {
                let s = Summary::of(&mut hops);
                if !args.json {
                    println!(
                        "{:<16} {:>8} B  median {:>8.1} µs  p99 {:>8.1} µs  max {:>8.1} µs",
                        case.key(),
                        case.payload_bytes(),
                        s.median_us,
                        s.p99_us,
                        s.max_us
                    );
                }
                report.insert(
                    case.key().to_owned(),
                    json!({
                        "median_us": s.median_us,
                        "p99_us": s.p99_us,
                        "max_us": s.max_us,
                        "payload_bytes": case.payload_bytes(),
                        "samples": hops.len(),
                    }),
                );
            }
            Err(e) => {
                result = Err(format!("bench ipc, case {}: {e}", case.key()));
                break;
            }
        }
    }
    // SAFETY: every peer has been reaped and this process's bus is dropped.
    unsafe { remove_domain(&ipc) }.map_err(|e| e.to_string())?;
    let left = shared_memory_entries(&ipc).map_err(|e| e.to_string())?;
    if !left.is_empty() {
        return Err(format!("bench ipc left shared memory behind: {left:?}"));
    }
    result?;
    if args.json {
        println!("{}", Value::Object(report));
    }
    Ok(())
}

/// A peer process, killed and reaped on drop unless it already exited.
struct Peer(Child);

impl Peer {
    /// Starts `motm bench ipc-echo` for `case`.
    fn spawn(case: Case, ipc: &IpcConfig, socket: Option<&Path>) -> Result<Self, String> {
        let exe = std::env::current_exe().map_err(|e| format!("cannot find own binary: {e}"))?;
        let mut command = Command::new(exe);
        command
            .args(["bench", "ipc-echo", "--case"])
            .arg(
                case.to_possible_value()
                    .expect("no skipped variants")
                    .get_name(),
            )
            .env(PREFIX_ENV, &ipc.prefix);
        if let Some(socket) = socket {
            command.arg("--socket").arg(socket);
        }
        command
            .spawn()
            .map(Peer)
            .map_err(|e| format!("cannot start the echo peer: {e}"))
    }

    /// Asks the peer to stop (SIGTERM) and waits for a successful exit.
    fn stop(mut self) -> Result<(), String> {
        // SAFETY: kill(2) on our own child, which has not been reaped yet.
        unsafe { libc::kill(self.0.id() as libc::pid_t, libc::SIGTERM) };
        self.wait()
    }

    /// Waits for a successful exit.
    fn wait(&mut self) -> Result<(), String> {
        let status = self.0.wait().map_err(|e| e.to_string())?;
        if status.success() {
            Ok(())
        } else {
            Err(format!("echo peer failed: {status}"))
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Measures `samples` hops of `case` after `warmup` unmeasured ones; returns the hop times, ns.
fn measure(case: Case, ipc: &IpcConfig, warmup: u32, samples: u32) -> Result<Vec<u64>, String> {
    let mut hops = Vec::with_capacity(samples as usize);
    let mut record = |round: u32, hop_ns: u64| {
        if round >= warmup {
            hops.push(hop_ns);
        }
    };
    let rounds = warmup + samples;
    if case.is_socket() {
        measure_socket(case, ipc, rounds, &mut record)?;
    } else {
        measure_iceoryx2(case, ipc, rounds, &mut record)?;
    }
    Ok(hops)
}

/// The iceoryx2 cases: ping on a waking service, wait for the acknowledgement on its event.
fn measure_iceoryx2(
    case: Case,
    ipc: &IpcConfig,
    rounds: u32,
    record: &mut impl FnMut(u32, u64),
) -> Result<(), String> {
    let e = |e: motm_bus::BusError| e.to_string();
    let bus = Bus::open_with("motm-bench", ipc).map_err(e)?;
    let qos = Qos::large().waking();
    let mut acks = Subscriber::<Ack>::new(&bus, ACK_SERVICE, &qos).map_err(e)?;
    let mut small = Publisher::<SmallPing>::new(&bus, SMALL_PING_SERVICE, &qos).map_err(e)?;
    let mut image = Publisher::<CameraImage>::new(&bus, IMAGE_PING_SERVICE, &qos).map_err(e)?;
    let mut peer = Peer::spawn(case, ipc, None)?;
    let mut wait_ack = |acks: &mut Subscriber<Ack>| -> Result<Ack, String> {
        let deadline = Instant::now() + TIMEOUT;
        loop {
            if let Some(ack) = acks.receive().map_err(e)? {
                return Ok(*ack);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                peer.0
                    .try_wait()
                    .ok()
                    .flatten()
                    .map_or(Ok(()), |s| Err(format!("echo peer exited early: {s}")))?;
                return Err("no acknowledgement from the echo peer".to_owned());
            }
            let listener = acks.listener().expect("created waking");
            listener
                .timed_wait(|_| {}, left)
                .map_err(|e| format!("waiting for the echo peer: {e:?}"))?;
        }
    };
    let ready = wait_ack(&mut acks)?;
    if ready.ping_seq != READY {
        return Err(format!("unexpected first acknowledgement {ready:?}"));
    }
    for round in 0..rounds {
        let seq = match case {
            Case::Iceoryx2Small => {
                let seq = small.next_seq();
                small
                    .publish_stamped(Stamp::Now, SmallPing::zeroed())
                    .map_err(e)?;
                seq
            }
            _ => {
                let seq = image.next_seq();
                // A frame is published at its exposure stamp or later.
                let now = motm_bus::monotonic_now_ns();
                image
                    .publish_with(Stamp::At(now), |m| {
                        m.image_published_ns = now;
                        m.width = CAMERA_WIDTH as u32;
                        m.height = CAMERA_HEIGHT as u32;
                        m.pixels[..8].copy_from_slice(&seq.to_le_bytes());
                    })
                    .map_err(e)?;
                seq
            }
        };
        let ack = wait_ack(&mut acks)?;
        if ack.ping_seq != seq {
            return Err(format!(
                "acknowledgement for ping {} instead of {seq}",
                ack.ping_seq
            ));
        }
        record(round, ack.hop_ns);
    }
    peer.stop()
}

/// The socket cases: a stream socket, payload stamped in its first 8 bytes.
fn measure_socket(
    case: Case,
    ipc: &IpcConfig,
    rounds: u32,
    record: &mut impl FnMut(u32, u64),
) -> Result<(), String> {
    let path = std::env::temp_dir().join(format!("motm-bench-{}.sock", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let listener = UnixListener::bind(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let result = (|| {
        let mut peer = Peer::spawn(case, ipc, Some(&path))?;
        let mut stream = accept_within(&listener, TIMEOUT, &mut peer)?;
        stream
            .set_read_timeout(Some(TIMEOUT))
            .map_err(|e| e.to_string())?;
        let mut payload = vec![0u8; case.payload_bytes()];
        for (i, b) in payload.iter_mut().enumerate() {
            *b = i as u8;
        }
        let mut ack = [0u8; 8];
        for round in 0..rounds {
            payload[..8].copy_from_slice(&monotonic_now_ns().to_le_bytes());
            stream.write_all(&payload).map_err(|e| e.to_string())?;
            stream
                .read_exact(&mut ack)
                .map_err(|e| format!("no acknowledgement from the echo peer: {e}"))?;
            record(round, u64::from_le_bytes(ack));
        }
        drop(stream); // end of stream: the peer exits
        peer.wait()
    })();
    let _ = std::fs::remove_file(&path);
    result
}

/// Accepts the peer's connection, giving up after `timeout` or when the peer exits.
fn accept_within(
    listener: &UnixListener,
    timeout: Duration,
    peer: &mut Peer,
) -> Result<UnixStream, String> {
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    let start = Instant::now();
    loop {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false).map_err(|e| e.to_string())?;
                return Ok(stream);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Ok(Some(status)) = peer.0.try_wait() {
                    return Err(format!("echo peer exited early: {status}"));
                }
                if start.elapsed() > timeout {
                    return Err("the echo peer did not connect".to_owned());
                }
                // Set-up only, outside any measurement.
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// Runs the echo peer (`motm bench ipc-echo`).
pub fn run_echo(args: &EchoArgs) -> Result<(), String> {
    match (args.case, &args.socket) {
        (Case::UdsSmall | Case::UdsImage, Some(path)) => echo_socket(args.case, path),
        (Case::UdsSmall | Case::UdsImage, None) => Err("--socket is required".to_owned()),
        (Case::Iceoryx2Small, _) => echo_iceoryx2::<SmallPing>(SMALL_PING_SERVICE),
        (Case::Iceoryx2Image, _) => echo_iceoryx2::<CameraImage>(IMAGE_PING_SERVICE),
    }
}

/// iceoryx2 echo: the standard service loop, woken by each ping.
fn echo_iceoryx2<P: Message>(ping_service: &str) -> Result<(), String> {
    let e = |e: motm_bus::BusError| e.to_string();
    let bus = Bus::open("motm-bench-echo").map_err(e)?;
    let qos = Qos::large().waking();
    let mut pings = Subscriber::<P>::new(&bus, ping_service, &qos).map_err(e)?;
    let mut acks = Publisher::<Ack>::new(&bus, ACK_SERVICE, &qos).map_err(e)?;
    let trigger = pings.trigger().expect("created waking");
    let mut service = ServiceLoop::new(&bus, LoopConfig::default()).map_err(e)?;
    let mut ack = Ack::zeroed();
    ack.ping_seq = READY;
    acks.publish(ack).map_err(e)?;
    let mut failure = None;
    service
        .run_on_data(&trigger, |_| {
            loop {
                match pings.receive() {
                    Ok(Some(ping)) => {
                        let now = monotonic_now_ns();
                        ack.ping_seq = ping.header().seq;
                        ack.hop_ns = now - ping.header().stamp_ns;
                        drop(ping);
                        if let Err(err) = acks.publish(ack) {
                            failure = Some(err.to_string());
                            return Flow::Stop;
                        }
                    }
                    Ok(None) => return Flow::Continue,
                    Err(err) => {
                        failure = Some(err.to_string());
                        return Flow::Stop;
                    }
                }
            }
        })
        .map_err(e)?;
    if pings.rejected() > 0 {
        return Err(format!(
            "{} pings rejected: {:?}",
            pings.rejected(),
            pings.last_rejection()
        ));
    }
    failure.map_or(Ok(()), Err)
}

/// Socket echo: blocking reads of whole payloads until the benchmark closes the stream.
fn echo_socket(case: Case, path: &Path) -> Result<(), String> {
    let mut stream = UnixStream::connect(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut payload = vec![0u8; case.payload_bytes()];
    loop {
        match stream.read_exact(&mut payload) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(e.to_string()),
        }
        let now = monotonic_now_ns();
        let stamp = u64::from_le_bytes(payload[..8].try_into().expect("8 bytes"));
        stream
            .write_all(&(now - stamp).to_le_bytes())
            .map_err(|e| e.to_string())?;
    }
}
