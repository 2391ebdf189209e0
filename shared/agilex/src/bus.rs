//! The small CAN bus trait the protocol code is written over, and its implementations:
//! [`SocketCanBus`] (a real `socketcan` socket), [`MemoryBus`] (a pair of connected in-memory
//! endpoints, for tests and the fake base), [`LoggingBus`] (writes the traffic of any bus as
//! `candump -L` lines) and [`ReplayBus`] (feeds a `candump -L` log back in).

use std::collections::VecDeque;
use std::io::{self, BufRead, Write};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::time::Duration;

use socketcan::dump::{CanDumpRecord, Reader};
use socketcan::{CanAnyFrame, CanSocket, Socket};
use thiserror::Error;

use crate::frame::{Frame, FrameError};

/// A bus failure.
#[derive(Debug, Error)]
pub enum CanBusError {
    /// A socket or file error.
    #[error("CAN I/O: {0}")]
    Io(#[from] io::Error),
    /// The other end of an in-memory bus is gone.
    #[error("the other end of the CAN bus is gone")]
    Disconnected,
    /// A frame that is not a classic 11-bit data frame.
    #[error("{0}")]
    Frame(#[from] FrameError),
    /// A `candump` log line that does not parse.
    #[error("candump log: {0}")]
    Log(String),
}

/// Sends and receives classic CAN frames.
pub trait CanBus {
    /// Sends one frame.
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError>;
    /// The next frame, waiting at most `timeout` (zero: only one already there); `Ok(None)` if
    /// none came.
    fn receive(&mut self, timeout: Duration) -> Result<Option<Frame>, CanBusError>;
}

impl<B: CanBus + ?Sized> CanBus for Box<B> {
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        (**self).send(frame)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Frame>, CanBusError> {
        (**self).receive(timeout)
    }
}

/// A `socketcan` raw CAN socket on an interface (`can0`).
#[derive(Debug)]
pub struct SocketCanBus {
    socket: CanSocket,
}

impl SocketCanBus {
    /// Opens interface `name`. On a machine without `AF_CAN` this fails with `EAFNOSUPPORT`
    /// (see [`is_unsupported`]); without the interface, with `ENODEV`.
    pub fn open(name: &str) -> io::Result<Self> {
        let socket = CanSocket::open(name)?;
        socket.set_nonblocking(true)?;
        Ok(Self { socket })
    }
}

/// Whether `e` says the kernel has no CAN sockets at all (`EAFNOSUPPORT`).
pub fn is_unsupported(e: &io::Error) -> bool {
    e.raw_os_error() == Some(97)
}

impl CanBus for SocketCanBus {
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        self.socket.write_frame(&frame.to_socketcan())?;
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Frame>, CanBusError> {
        let got = if timeout.is_zero() {
            self.socket.read_frame()
        } else {
            self.socket.read_frame_timeout(timeout)
        };
        match got {
            Ok(f) => Ok(Some(Frame::from_socketcan(&f)?)),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(e) => Err(e.into()),
        }
    }
}

/// One end of an in-memory bus: what one end sends, the other receives, in order.
#[derive(Debug)]
pub struct MemoryBus {
    tx: Sender<Frame>,
    rx: Receiver<Frame>,
}

impl MemoryBus {
    /// Two connected endpoints.
    pub fn pair() -> (Self, Self) {
        let (a_tx, b_rx) = mpsc::channel();
        let (b_tx, a_rx) = mpsc::channel();
        (Self { tx: a_tx, rx: a_rx }, Self { tx: b_tx, rx: b_rx })
    }
}

impl CanBus for MemoryBus {
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        self.tx.send(*frame).map_err(|_| CanBusError::Disconnected)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Frame>, CanBusError> {
        if timeout.is_zero() {
            match self.rx.try_recv() {
                Ok(f) => Ok(Some(f)),
                Err(TryRecvError::Empty) => Ok(None),
                Err(TryRecvError::Disconnected) => Err(CanBusError::Disconnected),
            }
        } else {
            match self.rx.recv_timeout(timeout) {
                Ok(f) => Ok(Some(f)),
                Err(RecvTimeoutError::Timeout) => Ok(None),
                Err(RecvTimeoutError::Disconnected) => Err(CanBusError::Disconnected),
            }
        }
    }
}

/// Microseconds since the Unix epoch (candump's timestamps).
pub fn unix_time_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// Wraps a bus and writes every frame sent and received as a `candump -L` line
/// (`(1735270496.916858) can0 111#0096000000000000`).
pub struct LoggingBus<B, W> {
    inner: B,
    out: W,
    device: String,
    clock: Box<dyn FnMut() -> u64 + Send>,
}

impl<B, W> std::fmt::Debug for LoggingBus<B, W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoggingBus")
            .field("device", &self.device)
            .finish_non_exhaustive()
    }
}

impl<B: CanBus, W: Write> LoggingBus<B, W> {
    /// Logs `inner`'s traffic to `out` as device `device`, stamped with the wall clock.
    pub fn new(inner: B, out: W, device: &str) -> Self {
        Self::with_clock(inner, out, device, unix_time_us)
    }

    /// As [`new`](Self::new), stamped by `clock` (µs).
    pub fn with_clock(
        inner: B,
        out: W,
        device: &str,
        clock: impl FnMut() -> u64 + Send + 'static,
    ) -> Self {
        Self {
            inner,
            out,
            device: device.to_owned(),
            clock: Box::new(clock),
        }
    }

    /// The writer the log goes to.
    pub fn writer(&self) -> &W {
        &self.out
    }

    /// The wrapped bus and the writer.
    pub fn into_inner(self) -> (B, W) {
        (self.inner, self.out)
    }

    fn log(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        let record = CanDumpRecord {
            t_us: (self.clock)(),
            device: self.device.clone(),
            frame: CanAnyFrame::from(frame.to_socketcan()),
            direction: None,
        };
        writeln!(self.out, "{record}")?;
        Ok(())
    }
}

impl<B: CanBus, W: Write> CanBus for LoggingBus<B, W> {
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        self.inner.send(frame)?;
        self.log(frame)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Frame>, CanBusError> {
        let got = self.inner.receive(timeout)?;
        if let Some(f) = &got {
            self.log(f)?;
        }
        Ok(got)
    }
}

/// Feeds the frames of a `candump -L` log (read with `socketcan::dump::Reader`) to whoever
/// receives, up to a replay time; what is sent is kept in [`sent`](Self::sent).
#[derive(Debug)]
pub struct ReplayBus<R> {
    reader: Reader<R>,
    next: Option<CanDumpRecord>,
    first_t_us: Option<u64>,
    until_us: u64,
    done: bool,
    /// Frames sent to this bus, oldest first.
    pub sent: VecDeque<Frame>,
    /// Records of the log that are not classic 11-bit data frames (skipped).
    pub skipped: u64,
}

impl<R: BufRead> ReplayBus<R> {
    /// Replays `reader`'s records; everything is delivered until
    /// [`set_time_us`](Self::set_time_us) limits it.
    pub fn new(reader: Reader<R>) -> Self {
        Self {
            reader,
            next: None,
            first_t_us: None,
            until_us: u64::MAX,
            done: false,
            sent: VecDeque::new(),
            skipped: 0,
        }
    }

    /// Delivers only records stamped up to `t_us` after the log's first record.
    pub fn set_time_us(&mut self, t_us: u64) {
        self.until_us = t_us;
    }

    /// Whether the whole log has been delivered.
    pub fn finished(&self) -> bool {
        self.done && self.next.is_none()
    }

    fn peek(&mut self) -> Result<Option<&CanDumpRecord>, CanBusError> {
        if self.next.is_none() && !self.done {
            match self.reader.next_record() {
                Ok(Some(r)) => {
                    self.first_t_us.get_or_insert(r.t_us);
                    self.next = Some(r);
                }
                Ok(None) => self.done = true,
                Err(e) => return Err(CanBusError::Log(format!("{e:?}"))),
            }
        }
        Ok(self.next.as_ref())
    }
}

impl<R: BufRead> CanBus for ReplayBus<R> {
    fn send(&mut self, frame: &Frame) -> Result<(), CanBusError> {
        self.sent.push_back(*frame);
        Ok(())
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Option<Frame>, CanBusError> {
        loop {
            let until = self.until_us;
            let Some(t_us) = self.peek()?.map(|r| r.t_us) else {
                return Ok(None);
            };
            let first = self.first_t_us.unwrap_or(t_us);
            if t_us.saturating_sub(first) > until {
                return Ok(None);
            }
            let record = self.next.take().expect("peeked");
            match Frame::from_any(&record.frame) {
                Ok(f) => return Ok(Some(f)),
                Err(_) => self.skipped += 1,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::motion_command;

    #[test]
    fn memory_endpoints_are_connected_both_ways() {
        let (mut a, mut b) = MemoryBus::pair();
        let f = motion_command(0.15, 0.0).0;
        a.send(&f).unwrap();
        assert_eq!(b.receive(Duration::ZERO).unwrap(), Some(f));
        assert_eq!(b.receive(Duration::ZERO).unwrap(), None);
        b.send(&f).unwrap();
        assert_eq!(a.receive(Duration::from_millis(1)).unwrap(), Some(f));
        drop(b);
        assert!(matches!(a.send(&f), Err(CanBusError::Disconnected)));
    }

    #[test]
    fn a_logged_stream_replays_to_the_same_frames() {
        let (a, mut b) = MemoryBus::pair();
        let mut t = 1_735_270_496_916_858u64;
        let mut log = LoggingBus::with_clock(a, Vec::new(), "can0", move || {
            t += 20_000;
            t
        });
        let frames = [motion_command(0.15, 0.0).0, motion_command(-0.1, 0.2).0];
        for f in &frames {
            log.send(f).unwrap();
        }
        b.send(&frames[1]).unwrap();
        assert_eq!(log.receive(Duration::ZERO).unwrap(), Some(frames[1]));
        let (_, text) = log.into_inner();
        let text = String::from_utf8(text).unwrap();
        assert_eq!(
            text.lines().next().unwrap(),
            "(1735270496.936858) can0 111#0096000000000000"
        );
        let mut replay = ReplayBus::new(Reader::from_reader(text.as_bytes()));
        replay.set_time_us(20_000);
        assert_eq!(replay.receive(Duration::ZERO).unwrap(), Some(frames[0]));
        assert_eq!(replay.receive(Duration::ZERO).unwrap(), Some(frames[1]));
        assert_eq!(
            replay.receive(Duration::ZERO).unwrap(),
            None,
            "later than the replay time"
        );
        replay.set_time_us(u64::MAX);
        assert_eq!(replay.receive(Duration::ZERO).unwrap(), Some(frames[1]));
        assert_eq!(replay.receive(Duration::ZERO).unwrap(), None);
        assert!(replay.finished());
        let mut bad = ReplayBus::new(Reader::from_reader(&b"(1.0) can0 111#00\n"[..]));
        assert!(matches!(
            bad.receive(Duration::ZERO),
            Err(CanBusError::Log(_))
        ));
    }

    #[test]
    fn a_real_socket_works_or_is_skipped_with_the_reason() {
        match SocketCanBus::open("can0") {
            Ok(mut bus) => {
                // Only on a machine with a CAN interface: sending must not fail.
                bus.send(&motion_command(0.0, 0.0).0).unwrap();
            }
            Err(e) if is_unsupported(&e) => {
                eprintln!("skipped: this kernel has no AF_CAN sockets (EAFNOSUPPORT): {e}");
            }
            Err(e) => eprintln!("skipped: no CAN interface can0 here: {e}"),
        }
    }
}
