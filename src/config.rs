//! What a [`crate::Device`] is made with: the device to use, the validation layer, where
//! rendered targets are cached, the BVH layout, and the stops that tests use. Nothing in
//! the library reads the environment: the command line fills a [`Config`] with
//! [`Config::from_env`], and a library caller sets its fields (or calls the same
//! function) itself.

pub use crate::bvh::BvhLayout;
use std::path::PathBuf;
use std::time::Duration;

/// How to make a [`crate::Device`] and how the work on it behaves.
///
/// ```
/// let config = vkinverse::Config { validation: false, ..vkinverse::Config::default() };
/// assert!(config.device.is_none(), "the best device is picked");
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Config {
    /// Device index or a case-insensitive part of its name; `None` picks the best device
    /// (discrete > integrated > virtual > CPU).
    pub device: Option<String>,
    /// Enable the Khronos validation layer with synchronization validation. A message it
    /// reports then fails the public call during which it came.
    pub validation: bool,
    /// Never map device-local buffers, even where the driver makes them host-visible (as
    /// lavapipe does): every transfer then goes through staging buffers, as on a discrete
    /// GPU.
    pub unmappable_device_memory: bool,
    /// Longest wait for one submission; `None` means 120 s (lavapipe is slow).
    pub timeout: Option<Duration>,
    /// Where rendered targets are cached when the scene's own directory cannot take them;
    /// `None`: nowhere else (the target is then rendered anew by each run).
    pub cache_dir: Option<PathBuf>,
    /// The BVH's node layout on the device.
    pub bvh_layout: BvhLayout,
    /// Keep the compressed BVH's traversal stack in an array instead of registers (to
    /// measure one against the other, or where the array measures faster).
    pub bvh_stack_array: bool,
    /// Stops at named steps of a run, for tests of what a kill leaves behind (debug builds
    /// only; the run directory's module names the steps).
    pub debug_stops: DebugStops,
}

/// Where a debug build stops a run (the run directory's module names the steps:
/// `run.locked`, `overwrite.cleared`, `checkpoint.written`, `checkpoint.committed`,
/// `run.checkpointed`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DebugStops {
    /// Abort the process the N-th time (the number, from 1) it reaches the step.
    pub abort_at: Option<(String, u32)>,
    /// Print `vkinverse: paused at STEP` and sleep a minute there.
    pub pause_at: Option<String>,
}

/// The environment variables [`Config::from_env`] reads, with what each sets.
pub const ENVIRONMENT: [(&str, &str); 8] = [
    ("VKINVERSE_DEVICE", "the device (index or part of its name)"),
    ("VKINVERSE_VALIDATION", "1: the validation layer on"),
    ("VKINVERSE_UNMAPPABLE_DEVICE_MEMORY", "1: device memory never mapped"),
    ("VKINVERSE_CACHE_DIR", "the target cache (default: the user's cache directory's vkinverse/)"),
    ("VKINVERSE_BVH_LAYOUT", "binary, wide or cw8"),
    ("VKINVERSE_BVH_STACK", "array or auto"),
    ("VKINVERSE_DEBUG_ABORT_AT", "STEP[:N] (debug builds)"),
    ("VKINVERSE_DEBUG_PAUSE_AT", "STEP (debug builds)"),
];

impl Config {
    /// The configuration the environment asks for ([`ENVIRONMENT`]), over the defaults,
    /// with the user's cache directory as the target cache. Returns the configuration and
    /// a warning for each value it could not use (which it ignores).
    pub fn from_env() -> (Config, Vec<String>) {
        Self::from_vars(|name| std::env::var(name).ok(), dirs::cache_dir().map(|d| d.join("vkinverse")))
    }

    /// [`Self::from_env`] over the variables `var` returns, with `user_cache` as the cache
    /// when `VKINVERSE_CACHE_DIR` is not set.
    pub fn from_vars(var: impl Fn(&str) -> Option<String>, user_cache: Option<PathBuf>) -> (Config, Vec<String>) {
        let mut warnings = Vec::new();
        let mut config = Config {
            device: var("VKINVERSE_DEVICE").filter(|d| !d.is_empty()),
            validation: var("VKINVERSE_VALIDATION").is_some_and(|v| v == "1"),
            unmappable_device_memory: var("VKINVERSE_UNMAPPABLE_DEVICE_MEMORY").is_some_and(|v| v == "1"),
            cache_dir: var("VKINVERSE_CACHE_DIR").map(PathBuf::from).or(user_cache),
            ..Config::default()
        };
        if let Some(name) = var("VKINVERSE_BVH_LAYOUT") {
            match name.parse() {
                Ok(layout) => config.bvh_layout = layout,
                Err(e) => warnings.push(format!("VKINVERSE_BVH_LAYOUT: {e}; using {}", BvhLayout::default().name())),
            }
        }
        match var("VKINVERSE_BVH_STACK").as_deref() {
            None | Some("auto") => {}
            Some("array") => config.bvh_stack_array = true,
            Some(other) => warnings.push(format!("VKINVERSE_BVH_STACK: '{other}' is not array or auto; using auto")),
        }
        if let Some(at) = var("VKINVERSE_DEBUG_ABORT_AT") {
            let (name, nth) = at.split_once(':').map_or((at.as_str(), 1), |(s, n)| (s, n.parse().unwrap_or(1)));
            config.debug_stops.abort_at = Some((name.to_string(), nth));
        }
        config.debug_stops.pause_at = var("VKINVERSE_DEBUG_PAUSE_AT");
        (config, warnings)
    }

    /// The options of the GPU layer's context.
    pub(crate) fn context_options(&self) -> crate::gpu::ContextOptions {
        crate::gpu::ContextOptions {
            device: self.device.clone(),
            validation: self.validation,
            timeout: self.timeout,
            unmappable_device_memory: self.unmappable_device_memory,
            storage_buffer_range_cap: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_environment_fills_every_field_and_bad_values_warn() {
        let vars = [
            ("VKINVERSE_DEVICE", "llvmpipe"),
            ("VKINVERSE_VALIDATION", "1"),
            ("VKINVERSE_UNMAPPABLE_DEVICE_MEMORY", "1"),
            ("VKINVERSE_CACHE_DIR", "/tmp/c"),
            ("VKINVERSE_BVH_LAYOUT", "wide"),
            ("VKINVERSE_BVH_STACK", "array"),
            ("VKINVERSE_DEBUG_ABORT_AT", "run.locked:2"),
            ("VKINVERSE_DEBUG_PAUSE_AT", "checkpoint.written"),
        ];
        assert_eq!(vars.map(|(n, _)| n), ENVIRONMENT.map(|(n, _)| n), "every variable read is listed");
        let get = |name: &str| vars.iter().find(|(n, _)| *n == name).map(|(_, v)| v.to_string());
        let (c, warnings) = Config::from_vars(get, Some("/home/u/.cache/vkinverse".into()));
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(c.device.as_deref(), Some("llvmpipe"));
        assert!(c.validation && c.unmappable_device_memory && c.bvh_stack_array);
        assert_eq!(c.cache_dir, Some(PathBuf::from("/tmp/c")));
        assert_eq!(c.bvh_layout, BvhLayout::Wide);
        assert_eq!(c.debug_stops.abort_at, Some(("run.locked".to_string(), 2)));
        assert_eq!(c.debug_stops.pause_at.as_deref(), Some("checkpoint.written"));
        // Nothing set: the defaults, with the user's cache.
        let (c, warnings) = Config::from_vars(|_| None, Some("/home/u/.cache/vkinverse".into()));
        assert!(warnings.is_empty());
        assert_eq!(c, Config { cache_dir: Some("/home/u/.cache/vkinverse".into()), ..Config::default() });
        // Values it cannot use are named and ignored.
        let bad = |name: &str| match name {
            "VKINVERSE_BVH_LAYOUT" => Some("octree".to_string()),
            "VKINVERSE_BVH_STACK" => Some("heap".to_string()),
            _ => None,
        };
        let (c, warnings) = Config::from_vars(bad, None);
        assert_eq!((c.bvh_layout, c.bvh_stack_array), (BvhLayout::default(), false));
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings[0].contains("VKINVERSE_BVH_LAYOUT") && warnings[1].contains("heap"), "{warnings:?}");
    }
}
