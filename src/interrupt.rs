//! Stopping a run with Ctrl-C (SIGINT). Once [`install`]ed, the first Ctrl-C asks the
//! runs in progress to stop: an optimisation ends after its current iteration and writes
//! its outputs as at any other end (its `summary.json` says `"interrupted": true`, and
//! `optimise --resume` continues it), and a batch or comparison starts no further run. A
//! second Ctrl-C ends the process at once with exit status 130, the shell's for SIGINT;
//! its run directory then holds the last committed checkpoint, as after any kill
//! (src/rundir.rs). Without [`install`] (a library caller's default) nothing here reacts
//! to signals and [`requested`] stays false.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock, Once};

/// Set by the first Ctrl-C.
static REQUESTED: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// Makes Ctrl-C stop the runs of this process as the module says. Once per process; a
/// later call does nothing.
pub fn install() -> std::io::Result<()> {
    static INSTALLED: Once = Once::new();
    let mut result = Ok(());
    INSTALLED.call_once(|| result = register());
    result
}

#[cfg(unix)]
fn register() -> std::io::Result<()> {
    use signal_hook::{consts::SIGINT, flag};
    // The exit is registered first, so that it sees the flag as the previous Ctrl-C left
    // it: the first sets the flag, the second finds it set and exits.
    flag::register_conditional_shutdown(SIGINT, 130, Arc::clone(&REQUESTED))?;
    flag::register(SIGINT, Arc::clone(&REQUESTED))?;
    Ok(())
}

#[cfg(not(unix))]
fn register() -> std::io::Result<()> {
    Ok(())
}

/// Whether a Ctrl-C has asked the runs to stop.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}
