//! The command line's own parts: signals, progress and messages, and the run settings as
//! flags.

pub mod interrupt;
pub mod progress;
pub mod settings_args;
