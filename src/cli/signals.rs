//! SIGINT and SIGTERM (what farm schedulers send): the temporary files being written are
//! removed and the process exits with 130 or 143, as shells report signals.

use std::sync::atomic::{AtomicI32, Ordering};
use std::time::Duration;

static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    // Only an atomic store: the only async-signal-safe kind of work.
    SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the handlers and a watcher thread that does the cleanup on an ordinary thread.
/// Where the thread cannot start (a process at its memory limit from the outset), the
/// signals keep their default action, ending the process as before; the temporary files
/// it leaves are removed by the next run (`kpcn::io::atomic`).
pub fn exit_on_signals() {
    let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
    // A small stack: the watcher only polls, and under an address-space limit a default
    // 2 MiB stack can be what does not fit.
    let watcher = std::thread::Builder::new().name("kpcn-signals".into()).stack_size(64 << 10).spawn(|| {
        loop {
            let sig = SIGNAL.load(Ordering::SeqCst);
            if sig != 0 {
                kpcn::io::atomic::remove_live_temp_files();
                let what = if sig == libc::SIGINT { "interrupted" } else { "terminated" };
                eprintln!("kpcn: {what}; partial outputs removed");
                // _exit, not exit: other threads are still inside OpenImageIO, whose static
                // destructors exit() would run under their feet.
                // SAFETY: ends the process at once; nothing is left to clean up.
                unsafe { libc::_exit(128 + sig) };
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    if watcher.is_err() {
        // SAFETY: restores the default action; no handler of ours runs after this.
        unsafe {
            libc::signal(libc::SIGINT, libc::SIG_DFL);
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
        }
    }
}
