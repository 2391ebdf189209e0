//! Whole lines on standard error from many processes at once.
//!
//! Every process of a stack writes to the same terminal or journal. Rust's standard error is
//! unbuffered, so `eprintln!` issues one write per formatted piece, and the lines of processes
//! stopping together (at shutdown) interleave mid-line. [`say!`](crate::say) formats the line
//! first and writes it, newline included, in one `write` call, which the kernel keeps whole for
//! lines up to `PIPE_BUF` (4096 bytes) on a pipe.

use std::io::Write;

/// Writes `line` and a newline to standard error in one call (errors are ignored, as
/// `eprintln!`'s are not: a closed standard error must never stop a control process).
pub fn say_line(line: &str) {
    let mut whole = String::with_capacity(line.len() + 1);
    whole.push_str(line);
    whole.push('\n');
    let _ = std::io::stderr().lock().write_all(whole.as_bytes());
}

/// `eprintln!` that writes the whole line at once ([`say_line`]).
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::say_line(&format!($($arg)*))
    };
}
