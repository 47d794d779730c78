//! Ctrl-C (SIGINT) and SIGTERM as a request to stop rather than an exit: a robot link that is
//! told to end first stops the robot and writes what it has (`deploy`, `monitor`). The handler
//! only records the signal; the loops ask [`requested`] between reports.

use std::sync::atomic::{AtomicI32, Ordering};

static RECEIVED: AtomicI32 = AtomicI32::new(0);

extern "C" fn note(signal: libc::c_int) {
    // Only an atomic store: all a signal handler may safely do.
    RECEIVED.store(signal, Ordering::SeqCst);
}

/// From now on SIGINT and SIGTERM are recorded, not fatal.
pub fn install() {
    let handler = note as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: `note` is async-signal-safe (one atomic store) and lives for the whole program.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}

/// Which signal asked the process to stop, if one did.
pub fn requested() -> Option<&'static str> {
    match RECEIVED.load(Ordering::SeqCst) {
        0 => None,
        libc::SIGINT => Some("Ctrl-C (SIGINT)"),
        libc::SIGTERM => Some("SIGTERM"),
        _ => Some("a signal"),
    }
}
