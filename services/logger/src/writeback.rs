//! The log file, written back to disk by the logger itself.
//!
//! Left to the kernel, a log's dirty pages are written back by kernel flusher threads, which
//! run at normal priority beside the control processes: on a two-core machine that made the
//! control loop's p99 cycle time 30 % longer with the logger attached, although the logger
//! itself runs under `SCHED_IDLE` (writing the same log to tmpfs cost nothing). So every
//! `writeback_bytes` written, [`WritebackFile`] starts the write-out of those pages itself
//! (`sync_file_range(2)`, in the logger's own idle-priority context), waits for the batch
//! before it to reach the disk, and drops that batch from the page cache
//! (`posix_fadvise(POSIX_FADV_DONTNEED)`): the streaming-write pattern, which also keeps the
//! log's page-cache footprint at two batches.

use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::os::fd::AsRawFd;

/// A file written in order whose pages the writer flushes itself (see the module docs).
pub struct WritebackFile {
    file: File,
    /// Bytes per write-out batch; 0 leaves write-back to the kernel.
    batch_bytes: u64,
    /// Bytes written so far (the file is only appended to).
    written: u64,
    /// Bytes whose write-out was started.
    started: u64,
    /// Bytes known to be on disk and dropped from the page cache.
    settled: u64,
    /// Failed `sync_file_range` / `posix_fadvise` calls (the data is still written; the
    /// kernel then writes it back itself).
    pub hint_errors: u64,
}

impl WritebackFile {
    /// Wraps `file` (empty, written from its start) with write-out batches of `batch_bytes`
    /// (0: no own write-out).
    pub fn new(file: File, batch_bytes: u64) -> Self {
        Self {
            file,
            batch_bytes,
            written: 0,
            started: 0,
            settled: 0,
            hint_errors: 0,
        }
    }

    /// Bytes written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Bytes written and dropped from the page cache so far.
    pub fn settled(&self) -> u64 {
        self.settled
    }

    /// `sync_file_range(2)` over bytes `from..to` of the file with `flags`; whether it worked.
    fn sync_range(&self, from: u64, to: u64, flags: libc::c_uint) -> bool {
        // SAFETY: a plain syscall on an open descriptor this struct owns.
        unsafe {
            libc::sync_file_range(
                self.file.as_raw_fd(),
                from as libc::off64_t,
                (to - from) as libc::off64_t,
                flags,
            ) == 0
        }
    }

    /// Starts the write-out of everything written since the last batch, then waits for the
    /// previous batch and drops it from the page cache.
    fn write_out(&mut self) {
        let (from, to) = (self.started, self.written);
        if !self.sync_range(from, to, libc::SYNC_FILE_RANGE_WRITE) {
            self.hint_errors += 1;
            return;
        }
        let (old_from, old_to) = (self.settled, from);
        if old_to > old_from {
            let waited = self.sync_range(
                old_from,
                old_to,
                libc::SYNC_FILE_RANGE_WAIT_BEFORE
                    | libc::SYNC_FILE_RANGE_WRITE
                    | libc::SYNC_FILE_RANGE_WAIT_AFTER,
            );
            // SAFETY: as in `sync_range`.
            let dropped = unsafe {
                libc::posix_fadvise(
                    self.file.as_raw_fd(),
                    old_from as libc::off_t,
                    (old_to - old_from) as libc::off_t,
                    libc::POSIX_FADV_DONTNEED,
                )
            } == 0;
            if !(waited && dropped) {
                self.hint_errors += 1;
            }
            self.settled = old_to;
        }
        self.started = to;
    }
}

impl Write for WritebackFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.file.write(buf)?;
        self.written += n as u64;
        if self.batch_bytes > 0 && self.written - self.started >= self.batch_bytes {
            self.write_out();
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.file.flush()
    }
}

impl Seek for WritebackFile {
    /// Only reports the position: the MCAP writer is set up never to seek back.
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        match pos {
            SeekFrom::Current(0) => Ok(self.written),
            _ => Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "the log file is written in order only",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    #[test]
    fn every_byte_reaches_the_file_in_order_and_old_batches_are_settled() {
        let path = std::env::temp_dir().join(format!("motm-writeback-{}", std::process::id()));
        let mut out = WritebackFile::new(File::create(&path).unwrap(), 4096);
        let mut expected = Vec::new();
        for i in 0..100u32 {
            let chunk: Vec<u8> = (0..1000).map(|j| ((i * 7 + j) % 251) as u8).collect();
            out.write_all(&chunk).unwrap();
            expected.extend_from_slice(&chunk);
        }
        out.flush().unwrap();
        assert_eq!(out.written(), 100_000);
        assert_eq!(out.stream_position().unwrap(), 100_000);
        assert_eq!(out.hint_errors, 0);
        // All but the last two batches are on disk and out of the page cache.
        assert!(out.settled() >= 100_000 - 3 * 4096, "{}", out.settled());
        assert!(out.seek(SeekFrom::Start(0)).is_err());
        let mut back = Vec::new();
        File::open(&path).unwrap().read_to_end(&mut back).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(back, expected);
    }
}
