//! What every fuzz target shares: one fixture per process (the repository's scene files,
//! linked into a temporary directory), and the macro that declares a target.

use std::path::Path;
use std::sync::OnceLock;
use vkinverse::fuzz::{Fixture, Target};

pub use libfuzzer_sys;

/// Runs `target` on `data` in this process's fixture; errors are expected, panics are not.
pub fn run(target: Target, data: &[u8]) {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    let fixture = FIXTURE.get_or_init(|| Fixture::new(&Path::new(env!("CARGO_MANIFEST_DIR")).join("..")).expect("the fuzz fixture"));
    let _ = fixture.run(target, data);
}

/// Declares the libFuzzer entry point for one [`Target`] variant.
#[macro_export]
macro_rules! target {
    ($target:ident) => {
        $crate::libfuzzer_sys::fuzz_target!(|data: &[u8]| $crate::run(vkinverse::fuzz::Target::$target, data));
    };
}
