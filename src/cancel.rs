//! Stopping work from outside: a [`Cancel`] token that the caller keeps a clone of.
//!
//! An optimisation asked to stop ends after its current iteration and writes its outputs
//! as at any other end (its summary says `interrupted`, and a resume continues it); a
//! batch or comparison starts no further run; a render keeps the samples it has; a target
//! render ends the run with [`crate::Error::Interrupted`]. The library installs no signal
//! handler: the command line sets the token from Ctrl-C and SIGTERM.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A cancellation token: clones share one flag.
///
/// ```
/// let cancel = vkinverse::Cancel::new();
/// let watcher = cancel.clone();
/// assert!(!watcher.is_cancelled());
/// cancel.cancel();
/// assert!(watcher.is_cancelled());
/// ```
#[derive(Clone, Debug, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    /// A token not cancelled yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// A token over `flag`, which something else (a signal handler) may set.
    pub fn from_flag(flag: Arc<AtomicBool>) -> Self {
        Cancel(flag)
    }

    /// Asks the work that holds this token (or a clone) to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether the work was asked to stop.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}
