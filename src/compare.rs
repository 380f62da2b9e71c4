//! `vkinverse compare`: several optimisers on one scene at equal cost, on one plot.
//!
//! Every optimiser runs with the same settings and seed — the same wall-time budget when one
//! is given, else the same iteration count — into `OUTDIR/<label>/` (the outputs of
//! `optimise`). The error is the parameter RMSE when the reference is known (every run logs
//! it), else the image loss. OUTDIR then receives:
//! - `error_vs_time.png`: every run's error against wall time, log scale;
//! - `curves.csv`: `label,time_s,error`, the points behind the plot;
//! - `optimiser.png`: every run's optimiser diagnostics (`optimiser.csv`) overlaid;
//! - `compare.csv` and `compare.json`: per run the final error, the wall time at which the
//!   error first reached each of [`LEVELS`] times the first run's final error, and the
//!   speed-up over the first run;
//! - `finals.png` (`finals-K.png` for sensor K of several): the target, then every run's
//!   final image in the order of the runs, side by side (`crate::preview`).
//!
//! The levels are relative to the first run (the baseline): 2× its final error is where the
//! runs are well under way, 1× is where the baseline ends, ½× is where only a faster
//! optimiser gets within the budget. The speed-up of a run is the baseline's time to reach
//! its own final error divided by the run's time to reach that error; it is empty when the
//! run never reaches it, or when either time is 0 (the error started below the level).

use crate::device::Device;
use crate::error::{Error, Result};
use crate::image::write_bytes_atomic;
use crate::optim::csv::DiagLog;
use crate::optim::spec::Spec;
use crate::optim::Optimiser;
use crate::report::{write_curves, Curve};
use crate::run::{optimise_or_read, read_diagnostics, Observer, RunOptions, DIAG_CSV};
use crate::scene::Scene;
use crate::settings::{RunSettings, Settings};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// Error levels, as multiples of the first run's final error.
pub const LEVELS: [f64; 3] = [2.0, 1.0, 0.5];

/// What the error of a comparison is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// RMSE between the parameters and the scene's reference values.
    ParamError,
    /// Image loss against the targets (when a target image makes the reference unknown).
    Loss,
}

impl Metric {
    pub fn describe(self) -> &'static str {
        match self {
            Metric::ParamError => "parameter RMSE",
            Metric::Loss => "image loss",
        }
    }
}

/// One error level.
#[derive(Clone, Debug, Serialize)]
pub struct Level {
    /// Multiple of the first run's final error.
    pub factor: f64,
    pub error: f64,
}

/// One optimiser's result.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    pub label: String,
    pub optimiser: Optimiser,
    /// Its directory under OUTDIR.
    pub dir: String,
    pub iterations: u32,
    pub time_s: f64,
    pub final_error: Option<f64>,
    /// The result's image error less the reference's at the same random numbers
    /// (`summary.json`'s `final_image_error` − `reference_image_error`; None when the
    /// reference is unknown): the runs of a comparison share their seed, so these compare.
    pub image_error_over_reference: Option<f64>,
    /// Wall time at which the error first reached each level (None: never).
    pub time_to_level: Vec<Option<f64>>,
    pub speedup: Option<f64>,
}

/// What `compare.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    pub scene: String,
    pub metric: Metric,
    /// The label of the first run, which the levels and speed-ups refer to.
    pub baseline: String,
    pub settings: serde_json::Value,
    pub levels: Vec<Level>,
    pub runs: Vec<Run>,
}

/// The first time at which `curve` is at or below `level`.
fn time_to_reach(curve: &[(f64, f64)], level: f64) -> Option<f64> {
    curve.iter().find(|p| p.1 <= level).map(|p| p.0)
}

fn factor_name(f: f64) -> String {
    format!("{f}x")
}

/// Runs every spec on `scene` with `over` (the settings given outside the scene) into the
/// output directory of `options` (required), each run's directory treated as its mode says,
/// and writes the comparison. The observer hears each run start and its iterations; a
/// cancellation ends the comparison with [`Error::Interrupted`] and writes no table.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::scene::{Film, LoadOptions};
/// use vkinverse::{Config, Device, Mode, RunOptions, Scene, Settings, Spec};
/// let device = Device::new(&Config::from_env().0)?;
/// let small = LoadOptions { film: Some(Film { width: 16, height: 16 }), max_depth: None };
/// let scene = Scene::load_with("scenes/cornell/scene.toml", &small)?;
/// let dir = std::env::temp_dir().join(format!("vkinverse-doc-compare-{}", std::process::id()));
/// let over = Settings { iterations: Some(3), target_spp: Some(16), ..Settings::default() };
/// let options = RunOptions { out_dir: Some(&dir), mode: Mode::Overwrite, cancel: Default::default() };
/// let specs = Spec::parse_list("meta,adam")?;
/// let comparison = vkinverse::compare::compare(&device, &scene, &over, &specs, &options, &mut ())?;
/// assert_eq!(comparison.runs.len(), 2);
/// assert!(dir.join("compare.csv").is_file() && dir.join("adam/log.csv").is_file());
/// # Ok(())
/// # }
/// ```
pub fn compare(device: &Device, scene: &Scene, over: &Settings, specs: &[Spec], options: &RunOptions, observer: &mut dyn Observer) -> Result<Comparison> {
    if specs.is_empty() {
        return Err(Error::Invalid("no optimisers to compare".into()));
    }
    let out_dir = options.out_dir.ok_or_else(|| Error::Invalid("a comparison needs an output directory".into()))?;
    let (mode, cancel) = (options.mode, &options.cancel);
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| Error::Io { path, source }
    };
    // Held for the whole comparison: no other run writes into the directory meanwhile.
    let _lock = crate::rundir::RunDir::open_table(out_dir, mode, &device.config().debug_stops)?;
    let mut settings_json = serde_json::Value::Null;
    // Per run: (summary, parameter-error curve, loss curve).
    let mut results = Vec::new();
    for spec in specs {
        if cancel.is_cancelled() {
            return Err(Error::Interrupted(format!("{} was not run; no comparison written", spec.label)));
        }
        let own = Settings { optimiser: Some(spec.clone()), ..Default::default() };
        let st: RunSettings = Settings::resolve(&scene.optimise.settings, &over.then(&own));
        observer.run_started(&spec.label, st.iterations);
        let dir = out_dir.join(spec.dir_name());
        let run = optimise_or_read(device, scene, &st, &RunOptions { out_dir: Some(&dir), mode, cancel: cancel.clone() }, observer).map_err(|e| match e {
            Error::Interrupted(m) => Error::Interrupted(format!("{} {m}; no comparison written", spec.label)),
            e => e,
        })?;
        let (err, loss) = run.log.curves();
        if settings_json.is_null() {
            settings_json = serde_json::to_value(&run.summary.settings).unwrap_or_default();
            if let Some(map) = settings_json.as_object_mut() {
                // Each run's optimiser is in its row.
                map.remove("optimiser");
            }
        }
        results.push((run.summary, err, loss));
    }

    let metric = if results.iter().all(|r| !r.1.is_empty()) { Metric::ParamError } else { Metric::Loss };
    let curves: Vec<Curve> = specs
        .iter()
        .zip(&results)
        .map(|(spec, (_, err, loss))| Curve { name: spec.label.clone(), points: if metric == Metric::ParamError { err.clone() } else { loss.clone() } })
        .collect();
    let baseline_final = curves[0].points.last().map(|p| p.1);
    let levels: Vec<Level> = match baseline_final {
        Some(e) => LEVELS.iter().map(|&factor| Level { factor, error: factor * e }).collect(),
        None => Vec::new(),
    };
    // The baseline's time to its own final error; the speed-ups divide it.
    let baseline_time = baseline_final.and_then(|e| time_to_reach(&curves[0].points, e));
    let runs: Vec<Run> = specs
        .iter()
        .zip(&results)
        .zip(&curves)
        .map(|((spec, (summary, _, _)), curve)| {
            let own = baseline_final.and_then(|e| time_to_reach(&curve.points, e));
            let speedup = match (baseline_time, own) {
                (Some(b), Some(t)) if b > 0.0 && t > 0.0 => Some(b / t),
                _ => None,
            };
            Run {
                label: spec.label.clone(),
                optimiser: spec.optimiser,
                dir: spec.dir_name(),
                iterations: summary.iterations,
                time_s: summary.total_time_s,
                final_error: curve.points.last().map(|p| p.1),
                image_error_over_reference: summary.final_image_error.zip(summary.reference_image_error).map(|(e, r)| e - r),
                time_to_level: levels.iter().map(|l| time_to_reach(&curve.points, l.error)).collect(),
                speedup,
            }
        })
        .collect();
    let comparison = Comparison { scene: scene.path.display().to_string(), metric, baseline: specs[0].label.clone(), settings: settings_json, levels, runs };

    let path = out_dir.join("compare.csv");
    write_bytes_atomic(&path, &comparison.csv()?).map_err(io(&path))?;
    let json = serde_json::to_string_pretty(&comparison).map_err(|e| Error::Invalid(e.to_string()))?;
    let path = out_dir.join("compare.json");
    write_bytes_atomic(&path, json.as_bytes()).map_err(io(&path))?;
    let title = format!("{}: {} vs time", comparison.scene, metric.describe());
    write_curves(&out_dir.join("curves.csv"), &out_dir.join("error_vs_time.png"), &title, metric.describe(), &curves).map_err(Error::Invalid)?;
    // Every run's optimiser diagnostics overlaid, labelled by spec.
    let diags = specs.iter().map(|s| read_diagnostics(&out_dir.join(s.dir_name()).join(DIAG_CSV))).collect::<Result<Vec<_>>>()?;
    let runs: Vec<(&str, &DiagLog)> = specs.iter().map(|s| s.label.as_str()).zip(&diags).collect();
    let path = out_dir.join("optimiser.png");
    crate::optim::csv::plot(&path, &format!("{}: optimiser diagnostics", comparison.scene), &runs)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    let dirs: Vec<std::path::PathBuf> = specs.iter().map(|s| out_dir.join(s.dir_name())).collect();
    if let Some(missing) = crate::preview::write_finals(out_dir, scene.sensors.len(), &dirs.iter().map(|d| d.as_path()).collect::<Vec<_>>())? {
        observer
            .warning(&format!("finals.png not written: {} is missing (a run from before runs wrote their pictures; --overwrite reruns it)", missing.display()));
    }
    Ok(comparison)
}

fn opt_num(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

impl Comparison {
    /// `compare.csv`: one row per run; a time or speed-up that does not exist is empty.
    pub fn csv(&self) -> Result<Vec<u8>> {
        let mut header: Vec<String> = ["label", "optimiser", "iterations", "time_s", "final_error"].map(String::from).to_vec();
        header.extend(self.levels.iter().map(|l| format!("time_to_{}", factor_name(l.factor))));
        header.push("speedup".into());
        header.push("image_error_over_reference".into());
        let rows = self.runs.iter().map(|r| {
            let mut row = vec![r.label.clone(), r.optimiser.name().to_string(), r.iterations.to_string(), r.time_s.to_string(), opt_num(r.final_error)];
            row.extend(r.time_to_level.iter().map(|t| opt_num(*t)));
            row.push(opt_num(r.speedup));
            row.push(opt_num(r.image_error_over_reference));
            row
        });
        crate::report::csv_bytes(&header, rows).map_err(Error::Invalid)
    }

    /// The table printed by `vkinverse compare`.
    pub fn table(&self) -> String {
        let mut s = String::new();
        match self.levels.iter().find(|l| l.factor == 1.0) {
            Some(l) => {
                let _ = writeln!(s, "{}; levels are multiples of {}'s final error {:.4e}", self.metric.describe(), self.baseline, l.error);
            }
            None => {
                let _ = writeln!(s, "{}", self.metric.describe());
            }
        }
        let width = self.runs.iter().map(|r| r.label.len()).max().unwrap_or(0).max(5);
        let _ = write!(s, "{:<width$} {:>6} {:>9} {:>11}", "label", "iters", "time (s)", "final error");
        for l in &self.levels {
            let _ = write!(s, " {:>10}", format!("t({})", factor_name(l.factor)));
        }
        let _ = writeln!(s, " {:>8} {:>11}", "speed-up", "image error");
        let cell = |v: Option<f64>, f: &dyn Fn(f64) -> String| v.map(f).unwrap_or_else(|| "-".into());
        for r in &self.runs {
            let _ = write!(s, "{:<width$} {:>6} {:>9.2} {:>11}", r.label, r.iterations, r.time_s, cell(r.final_error, &|e| format!("{e:.4e}")));
            for t in &r.time_to_level {
                let _ = write!(s, " {:>10}", cell(*t, &|t| format!("{t:.3}")));
            }
            let _ = writeln!(s, " {:>8} {:>11}", cell(r.speedup, &|x| format!("{x:.2}x")), cell(r.image_error_over_reference, &|e| format!("{e:+.3e}")));
        }
        s
    }
}
