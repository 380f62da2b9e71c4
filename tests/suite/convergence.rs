//! Convergence on the bundled scenes: Adam and the meta-estimator both bring the parameter
//! error of `scenes/cornell` and `scenes/spiral` down by at least 10× with the scenes'
//! own settings (Adam at the meta-estimator's cost per iteration: spp + fd_spp samples
//! for its gradient).
//!
//! At 2–3 samples per pixel the parameters do not settle on the reference: they wander
//! around it with the gradient noise, by a few hundredths on the principled parameters
//! of the spiral scene. So the test takes the error where a run has settled — the mean
//! of the parameter error over the last fifth of the iterations — rather than the last
//! iteration alone, whose value depends on where the wandering happens to stop.

use crate::common;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use vkinverse::optim::spec::Spec;
use vkinverse::run::{optimise, Observer, Outcome};
use vkinverse::scene::{Film, LoadOptions, Scene};
use vkinverse::settings::RunSettings;
use vkinverse::{Diagnostics, LogRow, Mode, RunOptions};

/// Collects the parameter error after every iteration.
struct Errors(Vec<f64>);

impl Observer for Errors {
    fn iteration(&mut self, p: &LogRow, _: &[Diagnostics]) -> ControlFlow<()> {
        self.0.push(p.param_error.expect("reference scene"));
        ControlFlow::Continue(())
    }
}

fn bundled(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name).join("scene.toml")
}

/// Runs `optimiser` on the bundled scene and returns (initial error, settled error).
fn run(scene_name: &str, optimiser: &str) -> (f64, f64) {
    let scene = Scene::load(bundled(scene_name)).expect("bundled scene");
    let mut settings = RunSettings::of_scene(&scene);
    settings.optimiser = optimiser.parse::<Spec>().unwrap();
    if optimiser == "adam" {
        settings.spp += settings.fd_spp;
    }
    let out = std::env::temp_dir().join(format!("vkinverse-convergence-{scene_name}-{optimiser}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut errors = Errors(Vec::new());
    let outcome = common::with_gpu(|ctx| {
        optimise(&common::device(ctx), &scene, &settings, &RunOptions { out_dir: Some(&out), mode: Mode::New, cancel: Default::default() }, &mut errors)
            .expect("optimisation runs")
    });
    let Outcome::Finished(run) = outcome else { panic!("a new run finishes") };
    let (summary, errors) = (run.summary, errors.0);
    let _ = std::fs::remove_dir_all(&out);
    assert_eq!(Some(errors.len() as u32), settings.iterations);
    assert_eq!(run.log.rows.len(), errors.len() + 1, "the returned log: row 0 and one per iteration");
    assert_eq!(summary.nonfinite_gradients, 0);
    let initial = summary.initial_param_error.expect("reference scene");
    let tail = &errors[errors.len() - errors.len() / 5..];
    let settled = tail.iter().sum::<f64>() / tail.len() as f64;
    eprintln!("{scene_name} {optimiser}: parameter error {initial:.4} -> {settled:.4} (mean of the last {} iterations)", tail.len());
    (initial, settled)
}

fn assert_tenfold(scene_name: &str, optimiser: &str) {
    let (initial, settled) = run(scene_name, optimiser);
    assert!(settled * 10.0 <= initial, "{scene_name}, {optimiser}: error {initial} fell only to {settled} ({:.1}×)", initial / settled);
}

#[test]
fn cornell_meta() {
    assert_tenfold("cornell", "meta");
}

#[test]
fn cornell_adam() {
    assert_tenfold("cornell", "adam");
}

#[test]
fn spiral_meta() {
    assert_tenfold("spiral", "meta");
}

#[test]
fn spiral_adam() {
    assert_tenfold("spiral", "adam");
}

/// (time_s, parameter error) after every iteration of a run.
struct Timed(Vec<(f64, f64)>);

impl Observer for Timed {
    fn iteration(&mut self, p: &LogRow, _: &[Diagnostics]) -> ControlFlow<()> {
        self.0.push((p.time_s, p.param_error.expect("reference scene")));
        ControlFlow::Continue(())
    }
}

/// The Cornell box at 16 × 16 with direct light only: a few milliseconds per iteration.
fn small_cornell() -> Scene {
    let options = LoadOptions { film: Some(Film { width: 16, height: 16 }), max_depth: Some(2) };
    Scene::load_with(bundled("cornell"), &options).expect("bundled scene")
}

/// Runs `optimiser` for `iterations` on `scene` with `spp` and `seed` and returns its
/// (time, error) curve.
fn timed_run(scene: &Scene, optimiser: &str, spp: u32, iterations: u32, seed: u64) -> Vec<(f64, f64)> {
    let mut settings = RunSettings::of_scene(scene);
    (settings.optimiser, settings.spp, settings.iterations, settings.seed) = (optimiser.parse::<Spec>().unwrap(), spp, Some(iterations), seed);
    let out = std::env::temp_dir().join(format!("vkinverse-equal-time-{optimiser}-{seed}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut curve = Timed(Vec::new());
    common::with_gpu(|ctx| {
        optimise(&common::device(ctx), scene, &settings, &RunOptions { out_dir: Some(&out), mode: Mode::New, cancel: Default::default() }, &mut curve)
            .expect("optimisation runs")
    });
    let _ = std::fs::remove_dir_all(&out);
    curve.0
}

/// The mean error over the last fifth of the points of `curve` up to `time`.
fn settled_by(curve: &[(f64, f64)], time: f64) -> f64 {
    let upto: Vec<f64> = curve.iter().take_while(|p| p.0 <= time).map(|p| p.1).collect();
    assert!(upto.len() >= 10, "only {} points by {time} s", upto.len());
    let tail = &upto[upto.len() - upto.len() / 5..];
    tail.iter().sum::<f64>() / tail.len() as f64
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The meta-estimator with its defaults (spec `meta`, 2 + 1 finite-difference spp) settles
/// at or below Adam at the same samples per iteration (3 spp), both at the scene's rate, at
/// equal wall time: Adam runs half as many iterations again, and its error is read up to the
/// time meta took. The median over three seeds of the ratio of settled errors must be at
/// most 1. Measured on lavapipe (a loaded 2-core machine, whose load moves the iteration
/// counts Adam gets by meta's time between 95 and 225): 0.21, 0.36, 0.52 for seeds 1-3
/// (0.26, 0.35, 0.33 with the earlier `decay_d=0.9`); the seed's configuration
/// (`meta-seed`, before the carried image) gave 2.7, 1.5, 2.3 and fails.
#[test]
fn meta_defaults_settle_at_or_below_adam_at_equal_time() {
    let scene = small_cornell();
    let ratios: Vec<f64> = [1u64, 2, 3]
        .iter()
        .map(|&seed| {
            let meta = timed_run(&scene, "meta", 2, 150, seed);
            let adam = timed_run(&scene, "adam", 3, 225, seed);
            let time = meta.last().unwrap().0;
            let (m, a) = (settled_by(&meta, time), settled_by(&adam, time));
            eprintln!("seed {seed}: meta {m:.5}, adam {a:.5} by {time:.2} s ({} adam iterations)", adam.iter().take_while(|p| p.0 <= time).count());
            m / a
        })
        .collect();
    let ratio = median(ratios.clone());
    assert!(ratio <= 1.0, "meta's settled error is {ratio:.2}× Adam's at equal time (per seed {ratios:?})");
}
