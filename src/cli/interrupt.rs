//! Stopping a run with Ctrl-C (SIGINT), or with SIGTERM (a batch scheduler's notice before
//! it kills a job). Once [`install`]ed, the first such signal cancels the library's work
//! through the [`Cancel`] token of [`token`]: an optimisation ends after its current
//! iteration and writes its outputs as at any other end (its `summary.json` says
//! `"interrupted": true`, and `optimise --resume` continues it), a batch or comparison
//! starts no further run, and a render keeps the samples it has. The command then exits
//! with status 128 + the signal's number (130 for Ctrl-C, 143 for SIGTERM), as the shell
//! reports a process the signal ended. A second signal ends the process at once with that
//! status; its run directory then holds the last committed checkpoint, as after any kill.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, LazyLock, Once};
use vkinverse::Cancel;

/// Set by the first signal.
static REQUESTED: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// The number of the last signal that asked to stop (0: none).
static SIGNAL: LazyLock<Arc<AtomicUsize>> = LazyLock::new(|| Arc::new(AtomicUsize::new(0)));

/// SIGINT's number, whose exit status stands for a stop without a recorded signal.
const SIGINT: usize = 2;

/// Makes SIGINT and SIGTERM stop the work of this process as the module says. Once per
/// process; a later call does nothing.
pub fn install() -> std::io::Result<()> {
    static INSTALLED: Once = Once::new();
    let mut result = Ok(());
    INSTALLED.call_once(|| result = register());
    result
}

#[cfg(unix)]
fn register() -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    for signal in [SIGINT, SIGTERM] {
        // The exit is registered first, so that it sees the flag as the previous signal
        // left it: the first sets the flag, the second finds it set and exits.
        flag::register_conditional_shutdown(signal, 128 + signal, Arc::clone(&REQUESTED))?;
        flag::register(signal, Arc::clone(&REQUESTED))?;
        flag::register_usize(signal, Arc::clone(&SIGNAL), signal as usize)?;
    }
    Ok(())
}

#[cfg(not(unix))]
fn register() -> std::io::Result<()> {
    Ok(())
}

/// Whether a signal has asked the work to stop.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}

/// The token the first signal cancels.
pub fn token() -> Cancel {
    Cancel::from_flag(Arc::clone(&REQUESTED))
}

/// The exit status of work a signal stopped: 128 + its number.
pub fn exit_status() -> u8 {
    let signal = match SIGNAL.load(Ordering::Relaxed) {
        0 => SIGINT,
        s => s,
    };
    u8::try_from(128 + signal).unwrap_or(u8::MAX)
}
