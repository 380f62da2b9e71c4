//! The integration tests, one module per subject, in one binary: the test harness shares
//! its threads among every test at once, where a binary per subject would wait for each
//! one's slowest test before the next starts, and the suite links once.
//!
//! Tests that measure or change what belongs to the whole process (its resident memory,
//! its environment) run in their own binary, `tests/process.rs`.

mod common;

mod api;
mod bench;
mod bsdf;
mod bvh;
mod cli;
mod compare_batch;
mod contracts;
mod convergence;
mod docs;
mod finite_difference;
mod fuzz;
mod gpu_layer;
mod gradients;
mod hostile;
mod import;
mod media;
mod mitsuba_files;
mod optim_gpu;
mod render;
mod rng;
mod scene_errors;
mod targets;
