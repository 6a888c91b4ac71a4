//! The station's console output (status lines, events, the summary, `--check`'s report),
//! which a closed stdout cannot stop.
//!
//! Rust ignores SIGPIPE, so `println!` panics once nobody reads stdout any more — a
//! `scalpel-server | head`, a log pipe whose reader exited, a terminal closed over a
//! running station — and a panic on the main thread ends the station mid-session. Here
//! the first failed write is said once on stderr and the station runs on without status.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

/// Set once a write to stdout failed; later lines are dropped.
static STDOUT_GONE: AtomicBool = AtomicBool::new(false);

/// Writes one line to stdout; on failure says so once on stderr (if stderr is still
/// there) and drops this and every later line.
pub fn line(args: std::fmt::Arguments<'_>) {
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    let written = out
        .write_fmt(args)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush());
    if let Err(e) = written
        && !STDOUT_GONE.swap(true, Ordering::Relaxed)
    {
        error(format_args!(
            "stdout closed ({e}); the station runs on without status lines"
        ));
    }
}

/// Writes one line to stderr prefixed with the program's name; a closed stderr is
/// ignored (there is nowhere left to say it).
pub fn error(args: std::fmt::Arguments<'_>) {
    let _ = writeln!(std::io::stderr().lock(), "scalpel-server: {args}");
}

/// `println!` for the station's console: see [`line`].
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::console::line(format_args!($($arg)*))
    };
}
