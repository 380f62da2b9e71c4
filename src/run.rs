//! `vkinverse optimise`: the optimisation loop and its outputs.
//!
//! The engine (`crate::engine`) records one iteration once — the proportional gradient estimate (primal →
//! loss → adjoint), for the meta-estimator the finite-difference sample (the gradient at
//! θ_i minus the gradient at θ_{i−1} with the same random numbers, both states evaluated
//! along one trace), then the fused optimiser passes — and this loop resubmits it. Between
//! submissions the host writes the iteration counter and reads back only what the log
//! needs (the loss, and θ for the parameter error).
//!
//! Outputs in OUTDIR (names and formats as in the design document): `log.csv`,
//! `summary.json`, `params/`, `final.exr`, `error_vs_time.png`, `checkpoint/`, the
//! per-sensor pictures `target.exr`, `start.exr` and `preview.png` (target | start |
//! final | difference; `crate::preview`, which also names them for several sensors), the
//! optimiser's diagnostics of every iteration and parameter group (`optimiser.csv`, reduced
//! on the GPU, and their plot `optimiser.png`; `optim::csv`), and the
//! recovered scene in `final/` (`crate::scene::write`). The
//! directory's rules (lock, refusal of a used directory, crash-safe checkpoints, what
//! `--resume` checks) are those of the `rundir` module. The log rows are also returned in
//! memory ([`Run::log`]).

use crate::cancel::Cancel;
use crate::device::Device;
use crate::engine::{CarryState, Engine};
use crate::error::{Error, Result};
use crate::gpu::Buffer;
use crate::image::{self, Image};
use crate::optim::csv::DiagLog;
use crate::rundir::{checkpoint_name, Mode, RunDir, RunIdentity};
use crate::scene::write::file_name;
use crate::scene::Scene;
use crate::settings::{gpu_seed, RunSettings};
use crate::tensor::{ParamValue, Shape};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::rc::Rc;
use std::time::Instant;

pub use crate::observer::{LogRow, Observer};

/// The rows of `log.csv` and the parameter names of its columns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Log {
    pub params: Vec<String>,
    pub rows: Vec<LogRow>,
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

impl Log {
    fn header(&self) -> Vec<String> {
        let fixed = ["iteration", "time_s", "gpu_time_s", "loss", "param_error"].map(String::from);
        fixed.into_iter().chain(self.params.iter().map(|p| format!("param_error.{p}"))).collect()
    }

    /// The CSV text: header `iteration,time_s,gpu_time_s,loss,param_error` and one
    /// `param_error.<name>` column per parameter; unknown values empty.
    pub fn to_csv(&self) -> Result<Vec<u8>> {
        let mut w = csv::Writer::from_writer(Vec::new());
        let bad = |e: csv::Error| Error::Invalid(format!("log.csv: {e}"));
        w.write_record(self.header()).map_err(bad)?;
        for r in &self.rows {
            let mut record = vec![r.iteration.to_string(), format!("{:.6}", r.time_s), format!("{:.6}", r.gpu_time_s)];
            record.push(r.loss.map(|l| format!("{l:e}")).unwrap_or_default());
            record.push(opt(r.param_error));
            record.extend(r.param_errors.iter().map(|e| opt(*e)));
            w.write_record(&record).map_err(bad)?;
        }
        w.into_inner().map_err(|e| Error::Invalid(format!("log.csv: {e}")))
    }

    /// Reads `path` as written by [`Self::to_csv`].
    pub fn read(path: &Path) -> Result<Log> {
        let bad = |what: String| Error::Invalid(format!("{}: {what}", path.display()));
        let mut reader = csv::Reader::from_path(path).map_err(|e| bad(e.to_string()))?;
        let header = reader.headers().map_err(|e| bad(e.to_string()))?.clone();
        let params: Vec<String> = header.iter().skip(5).map(|h| h.strip_prefix("param_error.").unwrap_or(h).to_string()).collect();
        let mut rows = Vec::new();
        for record in reader.records() {
            let record = record.map_err(|e| bad(e.to_string()))?;
            let field = |i: usize| -> Result<Option<f64>> {
                match record.get(i).unwrap_or_default() {
                    "" => Ok(None),
                    text => text.parse().map(Some).map_err(|_| bad(format!("'{text}' is not a number"))),
                }
            };
            rows.push(LogRow {
                iteration: field(0)?.unwrap_or_default() as u32,
                time_s: field(1)?.unwrap_or_default(),
                gpu_time_s: field(2)?.unwrap_or_default(),
                loss: field(3)?,
                param_error: field(4)?,
                param_errors: (5..5 + params.len()).map(field).collect::<Result<_>>()?,
            });
        }
        Ok(Log { params, rows })
    }

    /// (time, parameter error) and (time, loss) curves.
    pub fn curves(&self) -> (Vec<(f64, f64)>, Vec<(f64, f64)>) {
        let err = self.rows.iter().filter_map(|r| r.param_error.map(|e| (r.time_s, e))).collect();
        let loss = self.rows.iter().filter_map(|r| r.loss.map(|l| (r.time_s, l))).collect();
        (err, loss)
    }
}

/// What `summary.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    pub scene: String,
    /// The film the run rendered, [width, height] (the scene's, or `--film`'s); absent in
    /// the summaries of older runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub film: Option<[u32; 2]>,
    /// The longest path in segments it traced (the scene's, or `--max-depth`'s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_depth: Option<u32>,
    pub optimiser: String,
    pub settings: RunSettings,
    pub iterations: u32,
    pub total_time_s: f64,
    pub total_gpu_time_s: f64,
    pub final_loss: f64,
    pub final_param_error: Option<f64>,
    pub initial_param_error: Option<f64>,
    /// The image error of the optimised scene (the engine's `image_error`): the mean squared
    /// difference between its expected image and the target, per pixel and channel,
    /// estimated from two independent renders of `image_error_spp` samples without their
    /// noise. Unlike the parameter error it needs no reference and measures what the loss
    /// can see: where the target does not determine a parameter, the loss's optimum and
    /// the reference differ, and the parameter error stops measuring the fit.
    #[serde(default)]
    pub final_image_error: Option<f64>,
    /// The same of the reference scene, with the same random numbers (None when the
    /// reference is unknown): the floor that the target's own noise leaves.
    #[serde(default)]
    pub reference_image_error: Option<f64>,
    /// Samples per pixel of each of the two renders (final.exr is their mean).
    #[serde(default)]
    pub image_error_spp: u32,
    /// Median GPU milliseconds per iteration of each pass, by kernel name (a pass recorded
    /// once per sensor summed over sensors), over the iterations of this process.
    pub pass_ms: BTreeMap<String, f64>,
    pub nonfinite_gradients: u32,
    /// Meta only: per optimised parameter, the mean over its elements of the
    /// meta-estimator's effective number of averaged gradient samples at the last step,
    /// n_eff = 1/(1 − α). Near 1 the estimator is using little history (its
    /// finite-difference samples are too noisy to carry the past forward).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meta_n_eff: Option<BTreeMap<String, f64>>,
    pub device: String,
    /// The earlier run's `params.json` the parameters started from (`--init-from`); absent
    /// where they started from the scene's `init`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub started_from: Option<String>,
    /// A Ctrl-C or SIGTERM stopped the run before its iterations or time budget ran out
    /// (a [`crate::Cancel`], or the observer); a resume continues it.
    #[serde(default)]
    pub interrupted: bool,
}

/// A finished run: its summary, its log rows and the parameters' final values.
#[derive(Clone, Debug)]
pub struct Run {
    pub summary: Summary,
    pub log: Log,
    /// Every optimised parameter's final value, in the scene's order.
    pub params: Vec<(String, ParamValue)>,
}

/// What [`optimise`] did.
#[derive(Clone, Debug)]
pub enum Outcome {
    Finished(Box<Run>),
    /// `--resume` of a finished run, outputs and all: nothing was changed. The run as its
    /// `summary.json`, `log.csv` and `params/` hold it.
    AlreadyDone(Box<Run>),
}

impl Outcome {
    /// The run, finished now or before.
    pub fn into_run(self) -> Run {
        match self {
            Outcome::Finished(run) | Outcome::AlreadyDone(run) => *run,
        }
    }
}

impl Summary {
    /// The `summary.json` in `dir`; None where there is none or it does not read.
    pub fn read(dir: &Path) -> Option<Summary> {
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).ok()?).ok()
    }
}

impl Run {
    /// The run in `dir` whose outputs are written for `iteration`: its `summary.json`
    /// (which [`finish`] writes last) says that iteration, and its `log.csv` reads. None
    /// otherwise (a run killed while it wrote its outputs).
    fn read_finished(dir: &Path, iteration: u32) -> Option<Run> {
        let summary = Summary::read(dir).filter(|s| s.iterations == iteration)?;
        let log = Log::read(&dir.join("log.csv")).ok()?;
        let params = read_params(dir, &log.params).ok()?;
        Some(Run { summary, log, params })
    }
}

/// [`optimise`] for the runs of `compare` and `batch`: with [`Mode::Resume`] a directory
/// without a committed checkpoint (a run that never got to one, or none at all) starts
/// afresh and a finished run is read back ([`Outcome::AlreadyDone`]) instead of refused;
/// a run that was cancelled is [`Error::Interrupted`].
pub fn optimise_or_read(device: &Device, scene: &Scene, settings: &RunSettings, options: &RunOptions, observer: &mut dyn Observer) -> Result<Run> {
    let dir = options.out_dir.ok_or_else(|| Error::Invalid("a run of a comparison or batch needs its directory".into()))?;
    let mode = match options.mode {
        Mode::Resume if !crate::rundir::has_checkpoint(dir) => Mode::Overwrite,
        mode => mode,
    };
    let options = RunOptions { mode, ..options.clone() };
    let run = optimise(device, scene, settings, &options, observer)?.into_run();
    if run.summary.interrupted {
        return Err(Error::Interrupted(format!("stopped at iteration {} (its outputs are in {})", run.summary.iterations, dir.display())));
    }
    Ok(run)
}

/// `state.json` of a checkpoint.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct CheckpointState {
    iteration: u32,
    time_s: f64,
    gpu_time_s: f64,
    identity: RunIdentity,
    settings: RunSettings,
    /// The coarse-to-fine stage whose grids the checkpoint holds (`upsample`): an
    /// upsampling after iteration u may come before or after u's checkpoint.
    #[serde(default)]
    stage: usize,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |source| Error::Io { path: path.to_path_buf(), source }
}

fn json_bytes(value: &impl Serialize) -> Result<Vec<u8>> {
    serde_json::to_vec_pretty(value).map_err(|e| Error::Invalid(e.to_string()))
}

/// θ, the optimiser's state and meta's carried image: what a checkpoint saves, each with
/// the floats it saves. θ's buffer and the previous θ (shaped like it) save θ's part, not
/// the scene's material data after it, which the scene rebuilds.
fn state_buffers(engine: &Engine) -> Result<Vec<(&Buffer, usize)>> {
    let carry = engine.carry.iter().flat_map(|c| c.state());
    let gs = engine.scene();
    let optimiser = engine.optimiser()?;
    let theta_shaped = |b: &Buffer| b.same(&gs.theta) || optimiser.theta_prev.as_ref().is_some_and(|p| b.same(p));
    let buffers = std::iter::once(&gs.theta).chain(optimiser.state()).chain(carry);
    Ok(buffers.map(|b| (b, if theta_shaped(b) { gs.const_base as usize } else { (b.len() / 4) as usize })).collect())
}

fn save_checkpoint(run_dir: &RunDir, engine: &Engine, state: &CheckpointState, log: &Log, diag: &DiagLog, carry: &CarryLog) -> Result<()> {
    run_dir.commit(&checkpoint_name(state.iteration), |dir| {
        for (b, saved) in state_buffers(engine)? {
            let data: Vec<f32> = b.read_prefix(saved)?;
            crate::npy::write(&dir.join(format!("{}.npy", file_name(b.name()))), &crate::npy::Array { shape: vec![data.len()], data })?;
        }
        let log_path = dir.join("log.csv");
        image::write_bytes_atomic(&log_path, &log.to_csv()?).map_err(io_err(&log_path))?;
        let diag_path = dir.join(DIAG_CSV);
        image::write_bytes_atomic(&diag_path, diag.to_csv().as_bytes()).map_err(io_err(&diag_path))?;
        if engine.carry.is_some() {
            let carry_path = dir.join(CARRY_CSV);
            image::write_bytes_atomic(&carry_path, carry.to_csv().as_bytes()).map_err(io_err(&carry_path))?;
        }
        let path = dir.join("state.json");
        image::write_bytes_atomic(&path, &json_bytes(state)?).map_err(io_err(&path))
    })
}

/// The optimiser diagnostics' file name, in the run directory and its checkpoints.
pub const DIAG_CSV: &str = "optimiser.csv";

/// The carried primal image's log's file name (meta `carry`), in the run directory and its
/// checkpoints.
pub const CARRY_CSV: &str = "carry.csv";

/// The plot of the carried primal image's log, in the run directory.
pub const CARRY_PNG: &str = "carry.png";

/// The carried primal image's log (`carry.csv`): per iteration and sensor, the fresh render's
/// weight and the variances it was chosen from (glsl/carry_weight.comp).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CarryLog {
    pub rows: Vec<(u32, usize, CarryState)>,
}

impl CarryLog {
    /// The header line (without its newline).
    fn header() -> String {
        format!("iteration,sensor,{}", CarryState::COLUMNS.join(","))
    }

    pub fn to_csv(&self) -> String {
        let mut out = Self::header() + "\n";
        for (iteration, sensor, c) in &self.rows {
            let values: Vec<String> = c.values().iter().map(|v| v.to_string()).collect();
            out.push_str(&format!("{iteration},{sensor},{}\n", values.join(",")));
        }
        out
    }

    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        let mut lines = text.lines();
        let header = Self::header();
        // A log from before the adjoint render's weight lacks its column (read as 0).
        let earlier = header.rsplit_once(',').map(|(h, _)| h.to_string()).unwrap_or_default();
        let columns = match lines.next() {
            Some(h) if h == header => CarryState::COLUMNS.len(),
            Some(h) if h == earlier => CarryState::COLUMNS.len() - 1,
            _ => return Err(format!("the header is not '{header}'")),
        };
        let mut rows = Vec::new();
        for (n, line) in lines.enumerate() {
            let bad = || format!("line {}: '{line}' is not {} numbers", n + 2, 2 + columns);
            let f: Vec<&str> = line.split(',').collect();
            if f.len() != 2 + columns {
                return Err(bad());
            }
            let v: Vec<f32> = f[2..].iter().map(|x| x.parse::<f32>()).collect::<std::result::Result<_, _>>().map_err(|_| bad())?;
            rows.push((f[0].parse().map_err(|_| bad())?, f[1].parse().map_err(|_| bad())?, CarryState::from_floats(&v)));
        }
        Ok(CarryLog { rows })
    }

    /// Plots the log (`carry.png`): the weights of the fresh render and of the adjoint pass's
    /// render, and the variances they were chosen from, per sensor against the iteration, on log axes.
    pub fn plot(&self, path: &Path, title: &str) -> std::result::Result<(), String> {
        use crate::report::{plot_panels, Curve, Panel};
        let sensors = self.rows.iter().map(|r| r.1 + 1).max().unwrap_or(0);
        let series = |sensor: usize, value: fn(&CarryState) -> f32| -> Vec<(f64, f64)> {
            self.rows.iter().filter(|r| r.1 == sensor).map(|(i, _, c)| (*i as f64, value(c) as f64)).collect()
        };
        let label = |sensor: usize, what: &str| if sensors > 1 { format!("sensor {sensor} {what}") } else { what.to_string() };
        let mut weights = Vec::new();
        let mut variances = Vec::new();
        for s in 0..sensors {
            weights.push(Curve { name: label(s, "fresh render"), points: series(s, |c| c.weight) });
            if self.rows.iter().any(|r| r.1 == s && r.2.weight_adjoint > 0.0) {
                weights.push(Curve { name: label(s, "adjoint render"), points: series(s, |c| c.weight_adjoint) });
            }
            variances.push(Curve { name: label(s, "carried image"), points: series(s, |c| c.var_carried) });
            variances.push(Curve { name: label(s, "fresh render"), points: series(s, |c| c.var_fresh) });
            variances.push(Curve { name: label(s, "difference (bound)"), points: series(s, |c| c.var_diff) });
        }
        let panels = [
            Panel { y_label: "weight in the carried image".into(), curves: &weights },
            Panel { y_label: "variance per pixel and channel".into(), curves: &variances },
        ];
        plot_panels(path, title, "iteration", &panels, (800, 750))
    }
}

/// Reads a run's `optimiser.csv`.
pub fn read_diagnostics(path: &Path) -> Result<DiagLog> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    DiagLog::parse(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}

/// The committed checkpoint's state, log and diagnostics, checked against this run: the
/// same scene and parameters, and the optimiser whose state it holds.
fn read_checkpoint(run_dir: &RunDir, identity: &RunIdentity, settings: &RunSettings) -> Result<(std::path::PathBuf, CheckpointState, Log, DiagLog, CarryLog)> {
    let dir = run_dir.committed()?.ok_or_else(|| Error::Invalid(format!("{}: no committed checkpoint", run_dir.path.display())))?;
    let path = dir.join("state.json");
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let state: CheckpointState = serde_json::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    if let Some(why) = state.identity.mismatch(identity) {
        return Err(Error::Invalid(format!("{}: cannot resume: {why}", run_dir.path.display())));
    }
    let (then, now) = (state.settings.optimiser.optimiser.name(), settings.optimiser.optimiser.name());
    if then != now {
        return Err(Error::Invalid(format!("{}: cannot resume: the checkpoint holds optimiser {then}'s state, the run uses {now}", dir.display())));
    }
    let log = Log::read(&dir.join("log.csv"))?;
    // A checkpoint written before the diagnostics were logged has none to continue.
    let diag_path = dir.join(DIAG_CSV);
    let diag = if diag_path.exists() { read_diagnostics(&diag_path)? } else { DiagLog::default() };
    // Likewise a checkpoint from before the carried image's log (or of a run without one).
    let carry_path = dir.join(CARRY_CSV);
    let carry = match carry_path.exists() {
        true => {
            let text = std::fs::read_to_string(&carry_path).map_err(io_err(&carry_path))?;
            CarryLog::parse(&text).map_err(|e| Error::Invalid(format!("{}: {e}", carry_path.display())))?
        }
        false => CarryLog::default(),
    };
    Ok((dir, state, log, diag, carry))
}

fn load_state(dir: &Path, engine: &Engine) -> Result<()> {
    for (b, saved) in state_buffers(engine)? {
        let path = dir.join(format!("{}.npy", file_name(b.name())));
        // Checkpoints from before the carried image (or of a run without it) have none: its
        // count stays 0, and the first carry takes the fresh image alone. Checkpoints from
        // before the carried image's variance weights have no weight state: its tracked
        // variance starts at 0 and follows the renders from the next carry on. Files of
        // state the optimiser no longer keeps are not read.
        let optional = b.name() == "carry count" || b.name().starts_with("carried image") || b.name().starts_with("carry state");
        if optional && !path.exists() {
            continue;
        }
        let mut a = crate::npy::read(&path)?;
        // Checkpoints from before the adjoint render was taken in hold the carry state
        // without its weight: 0, as if the last iteration had not mixed one in.
        if b.name().starts_with("carry state") && a.data.len() + 1 == saved {
            a.data.push(0.0);
        }
        if a.data.len() != saved {
            return Err(Error::Invalid(format!("{}: {} values, expected {saved}", path.display(), a.data.len())));
        }
        b.write(&a.data)?;
    }
    Ok(())
}

/// Writes `params/`: every parameter as `NAME.npy` (float32, its array shape: `[channels]`
/// for a constant, `[height, width, channels]` for a texture, `[depth, height, width,
/// channels]` for a grid), `params.json` with every constant's value and every texture's
/// EXR (`{ "texture": "NAME.exr" }`, which `--init-from` reads).
fn write_params(dir: &Path, values: &[(String, ParamValue)]) -> Result<()> {
    let pdir = dir.join("params");
    std::fs::create_dir_all(&pdir).map_err(io_err(&pdir))?;
    let mut json = serde_json::Map::new();
    for (name, v) in values {
        let array = crate::npy::Array { shape: v.shape.array(), data: v.data.clone() };
        crate::npy::write(&pdir.join(format!("{}.npy", file_name(name))), &array)?;
        match v.shape.texture_size() {
            _ if v.shape.is_constant() => {
                json.insert(name.clone(), if v.data.len() == 1 { serde_json::json!(v.data[0]) } else { serde_json::json!(v.data) });
            }
            Some([width, height]) => {
                let c = v.shape.channels() as usize;
                let data = v.data.chunks(c).map(|t| if c == 1 { [t[0]; 3] } else { [t[0], t[1], t[2]] }).collect();
                let path = pdir.join(format!("{}.exr", file_name(name)));
                image::write_exr(&path, &Image { width, height, data })?;
                json.insert(name.clone(), serde_json::json!({ "texture": path.file_name().map(|f| f.to_string_lossy().into_owned()) }));
            }
            // Other shapes are in their .npy alone.
            None => {}
        }
    }
    let path = pdir.join("params.json");
    image::write_bytes_atomic(&path, &json_bytes(&serde_json::Value::Object(json))?).map_err(io_err(&path))
}

/// Reads `params/NAME.npy` of every parameter `names` lists, as [`write_params`] wrote them.
fn read_params(dir: &Path, names: &[String]) -> Result<Vec<(String, ParamValue)>> {
    names
        .iter()
        .map(|name| {
            let path = dir.join("params").join(format!("{}.npy", file_name(name)));
            let a = crate::npy::read(&path)?;
            let value = Shape::from_array(&a.shape).and_then(|shape| ParamValue::new(shape, a.data));
            let value = value.ok_or_else(|| Error::Invalid(format!("{}: shape {:?} is no parameter's", path.display(), a.shape)))?;
            Ok((name.clone(), value))
        })
        .collect()
}

fn write_plot(out_dir: &Path, log: &Log, scene: &str, optimiser: &str) -> Result<()> {
    let (err, loss) = log.curves();
    let (points, label) = if err.is_empty() { (loss, "image loss") } else { (err, "parameter RMSE") };
    let curves = [crate::report::Curve { name: optimiser.to_string(), points }];
    let path = out_dir.join("error_vs_time.png");
    crate::report::plot_error_vs_time(&path, &format!("{scene}: {label} vs time"), label, &curves)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}

/// The identity of a run of `scene` (what `--resume` must find unchanged).
pub fn identity(scene: &Scene, engine_layout: &crate::render::ParamLayout) -> RunIdentity {
    RunIdentity { scene_hash: format!("{:016x}", scene.content_hash()), params: engine_layout.slots.iter().map(|s| (s.name.clone(), s.len)).collect() }
}

/// Where a run keeps its files, how it treats a run found there, and the token that stops
/// it.
#[derive(Clone, Debug)]
pub struct RunOptions<'a> {
    /// The run directory; `None`: the run keeps everything in memory (no checkpoints, no
    /// files) and cannot be resumed.
    pub out_dir: Option<&'a Path>,
    /// How a run found in `out_dir` is treated.
    pub mode: Mode,
    /// Stops the run after its current iteration, with its outputs written (a resume
    /// continues it).
    pub cancel: Cancel,
}

impl<'a> RunOptions<'a> {
    /// A new run into `out_dir` (refused if it holds one), not cancelled.
    pub fn new(out_dir: Option<&'a Path>) -> Self {
        RunOptions { out_dir, mode: Mode::New, cancel: Cancel::new() }
    }
}

/// The loop's state: where it is and what it has logged.
struct Loop<'a> {
    /// The engine of the run's current coarse-to-fine stage (replaced at each upsampling).
    engine: Rc<Engine>,
    /// That stage: how many upsamplings came before.
    stage: usize,
    run_dir: Option<&'a RunDir>,
    identity: RunIdentity,
    has_reference: bool,
    log: Log,
    diag: DiagLog,
    carry: CarryLog,
    iteration: u32,
    time_offset: f64,
    gpu_total: f64,
    pass_samples: BTreeMap<String, Vec<f64>>,
    last_loss: f64,
    /// A cancellation or the observer ended the loop before the settings did.
    interrupted: bool,
    /// The iteration of the committed checkpoint, where this process knows one.
    committed: Option<u32>,
}

impl Loop<'_> {
    /// The log row of θ.
    fn row(&self, time_s: f64, loss: Option<f64>, theta: &[f32]) -> Result<LogRow> {
        let (e, per) = self.engine.scene().layout.errors(theta);
        let known = |v: f64| self.has_reference.then_some(v);
        Ok(LogRow {
            iteration: self.iteration,
            time_s,
            gpu_time_s: self.gpu_total,
            loss,
            param_error: known(e),
            param_errors: per.into_iter().map(known).collect(),
        })
    }

    /// Writes the logs so far into the run directory: `log.csv`, `optimiser.csv` and (meta's
    /// carried image) `carry.csv`.
    fn write_logs(&self, dir: &Path) -> Result<()> {
        let path = dir.join("log.csv");
        image::write_bytes_atomic(&path, &self.log.to_csv()?).map_err(io_err(&path))?;
        if self.engine.carry.is_some() {
            let path = dir.join(CARRY_CSV);
            image::write_bytes_atomic(&path, self.carry.to_csv().as_bytes()).map_err(io_err(&path))?;
        }
        let path = dir.join(DIAG_CSV);
        image::write_bytes_atomic(&path, self.diag.to_csv().as_bytes()).map_err(io_err(&path))
    }

    /// Commits a checkpoint of where the run stands and updates the logs (nothing without a
    /// run directory).
    fn checkpoint(&mut self, time_s: f64) -> Result<()> {
        let Some(run_dir) = self.run_dir else { return Ok(()) };
        let state = CheckpointState {
            iteration: self.iteration,
            time_s,
            gpu_time_s: self.gpu_total,
            identity: self.identity.clone(),
            settings: self.engine.settings.clone(),
            stage: self.stage,
        };
        save_checkpoint(run_dir, &self.engine, &state, &self.log, &self.diag, &self.carry)?;
        self.committed = Some(self.iteration);
        self.write_logs(&run_dir.path)
    }

    /// Iterates until the settings say stop, `cancel` is set, the observer breaks or the
    /// iteration count reaches `stop`; returns the total optimisation time.
    fn iterate(&mut self, observer: &mut dyn Observer, cancel: &Cancel, stop: Option<u32>) -> Result<f64> {
        let engine = Rc::clone(&self.engine);
        let settings = &engine.settings;
        let mut iteration = engine.iteration()?;
        let start = Instant::now();
        // Wall time spent on logging and checkpoints, which `time_s` leaves out.
        let mut untimed = 0.0;
        let offset = self.time_offset;
        let timed = |untimed: f64| offset + start.elapsed().as_secs_f64() - untimed;
        // How many iterations in a row had a zero gradient in every parameter.
        let mut zero_gradients = 0u32;
        while !settings.done(self.iteration, timed(untimed)) && stop.is_none_or(|s| self.iteration < s) {
            if cancel.is_cancelled() {
                self.interrupted = true;
                observer.notice(&format!("interrupted: stopping at iteration {} and writing the outputs", self.iteration));
                break;
            }
            let step = engine.step(&mut iteration, self.iteration)?;
            let time_s = timed(untimed);
            check_progress(&step, self.iteration + 1, &mut zero_gradients)?;
            for (name, ms) in &step.pass_ms {
                self.pass_samples.entry(name.clone()).or_default().push(*ms);
            }
            self.gpu_total += step.gpu_ms() * 1e-3;
            self.iteration += 1;
            self.last_loss = step.loss;
            let row = self.row(time_s, Some(step.loss), &step.theta)?;
            let flow = observer.iteration(&row, &step.diagnostics);
            let names = engine.scene().layout.slots.iter().map(|s| s.name.clone());
            self.diag.push(self.iteration, names.zip(step.diagnostics));
            self.carry.rows.extend(step.carry.iter().enumerate().map(|(s, c)| (self.iteration, s, *c)));
            self.log.rows.push(row);
            if self.iteration.is_multiple_of(settings.checkpoint_every) {
                self.checkpoint(time_s)?;
            }
            untimed += timed(untimed) - time_s;
            if flow.is_break() && !settings.done(self.iteration, timed(untimed)) {
                self.interrupted = true;
                break;
            }
        }
        Ok(timed(untimed))
    }
}

/// Iterations in a row with a zero gradient in every parameter after which a run stops.
pub const ZERO_GRADIENT_ITERATIONS: u32 = 20;

/// Stops a run going nowhere with an error naming the likely cause: a loss that is not
/// finite (the image overflows single precision), or a gradient that has been zero in every
/// parameter for [`ZERO_GRADIENT_ITERATIONS`] iterations (nothing the parameters change
/// reaches the image). `zero` counts the latter across iterations.
fn check_progress(step: &crate::engine::Step, iteration: u32, zero: &mut u32) -> Result<()> {
    if !step.loss.is_finite() {
        return Err(Error::Invalid(format!(
            "the loss is {} at iteration {iteration}: the rendered image is not finite in single precision (an emitter, light or environment too bright?)",
            step.loss
        )));
    }
    let all_zero = !step.diagnostics.is_empty() && step.diagnostics.iter().all(|d| d.rms_f == 0.0);
    *zero = if all_zero { *zero + 1 } else { 0 };
    if *zero >= ZERO_GRADIENT_ITERATIONS {
        return Err(Error::Invalid(format!(
            "the gradient has been zero in every parameter for {ZERO_GRADIENT_ITERATIONS} iterations (to iteration {iteration}): the parameters do not change the image (no light reaches what they change, or it is too faint?)"
        )));
    }
    Ok(())
}

/// Optimises `scene`'s parameters with `settings`, from their `init` values towards the
/// scene's targets (its sensors' target images, or renders of its own values). With a run
/// directory the run writes the outputs of the run-directory contract there (log, summary,
/// parameters, the recovered scene, plots, checkpoints), treating a run found there as
/// `options.mode` says. `observer` hears every iteration and may stop the run.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::{Config, Device, RunOptions, Scene, Settings};
/// let device = Device::new(&Config::from_env().0)?;
/// let scene = Scene::load("scenes/cornell/scene.toml")?;
/// let settings = Settings { iterations: Some(3), target_spp: Some(16), ..Settings::default() };
/// let run = vkinverse::optimise(&device, &scene, &settings.resolve_for(&scene), &RunOptions::new(None), &mut ())?.into_run();
/// assert_eq!(run.log.rows.len(), 4, "the start and three iterations");
/// assert_eq!(run.params[0].0, "materials.red.base_color");
/// # Ok(())
/// # }
/// ```
pub fn optimise(device: &Device, scene: &Scene, settings: &RunSettings, options: &RunOptions, observer: &mut dyn Observer) -> Result<Outcome> {
    let outcome = run_optimisation(device, scene, settings, options, observer)?;
    device.validated(outcome)
}

fn run_optimisation(device: &Device, scene: &Scene, settings: &RunSettings, options: &RunOptions, observer: &mut dyn Observer) -> Result<Outcome> {
    if scene.optimise.params.is_empty() {
        return Err(Error::Invalid(format!("{}: no [[optimise.params]] to optimise", scene.path.display())));
    }
    let mode = options.mode;
    if let Some(dir) = options.out_dir {
        check_targets_outside(scene, dir)?;
    }
    let run_dir = match options.out_dir {
        Some(dir) => Some(RunDir::open(dir, mode, &device.config().debug_stops)?),
        None if mode == Mode::Resume => return Err(Error::Invalid("a resume needs the run directory to resume".into())),
        None => None,
    };
    let identity = identity(scene, &crate::render::ParamLayout::new(scene));
    let upsample = &settings.upsample.0;
    crate::coarse::check(scene, upsample.len())?;
    let resume = match (&run_dir, mode) {
        (Some(dir), Mode::Resume) => Some(read_checkpoint(dir, &identity, settings)?),
        _ => None,
    };
    if let (Some((_, state, ..)), Some(dir)) = (&resume, &run_dir) {
        // A run whose iterations are done but whose outputs are not all written (killed
        // while it wrote them) goes on to write them.
        if settings.done(state.iteration, state.time_s) {
            if let Some(run) = Run::read_finished(&dir.path, state.iteration) {
                return Ok(Outcome::AlreadyDone(Box::new(run)));
            }
        }
        observer.resumed(state.iteration, &state.settings.changes(settings));
    }
    // A run resumed past an upsampling starts at its checkpoint's stage.
    let stage = resume.as_ref().map_or(0, |(_, state, ..)| state.stage);
    let engine = Engine::new(device, &*crate::coarse::stage_scene(scene, stage, None)?, settings, observer, &options.cancel)?;
    engine.warm_up()?;
    let has_reference = scene.sensors.iter().all(|s| s.target_image.is_none());
    let params = engine.scene().layout.slots.iter().map(|s| s.name.clone()).collect();
    let mut run = Loop {
        engine: Rc::new(engine),
        stage,
        run_dir: run_dir.as_ref(),
        identity,
        has_reference,
        log: Log { params, rows: Vec::new() },
        diag: DiagLog::default(),
        carry: CarryLog::default(),
        iteration: 0,
        time_offset: 0.0,
        gpu_total: 0.0,
        pass_samples: BTreeMap::new(),
        last_loss: f64::NAN,
        interrupted: false,
        committed: None,
    };
    match resume {
        Some((dir, state, log, diag, carry)) => {
            load_state(&dir, &run.engine)?;
            (run.iteration, run.time_offset, run.gpu_total, run.log, run.diag, run.carry) = (state.iteration, state.time_s, state.gpu_time_s, log, diag, carry);
            run.committed = Some(state.iteration);
            run.last_loss = run.log.rows.last().and_then(|r| r.loss).unwrap_or(f64::NAN);
        }
        None => {
            let row = run.row(0.0, None, &run.engine.theta()?)?;
            run.log.rows.push(row);
        }
    }
    loop {
        let stop = upsample.get(run.stage).copied();
        let total_time_s = run.iterate(observer, &options.cancel, stop)?;
        if run.interrupted || stop != Some(run.iteration) || settings.done(run.iteration, total_time_s) {
            let engine = Rc::clone(&run.engine);
            return finish(device, scene, &engine, run, total_time_s);
        }
        // Upsampling: the next stage's engine, warmed up before θ and the optimiser's state
        // are carried into it; its set-up counts in the run's time.
        let start = Instant::now();
        run.stage += 1;
        let next = Engine::new(device, &*crate::coarse::stage_scene(scene, run.stage, Some(&run.engine.targets))?, settings, &mut (), &options.cancel)?;
        next.warm_up()?;
        carry_state(&run.engine, &next)?;
        let sizes: Vec<String> = next
            .scene()
            .layout
            .slots
            .iter()
            .filter(|s| s.shape.ndim() == 3)
            .map(|s| format!("{} {:?}", s.name, crate::scene::media::grid_dims(s.shape)))
            .collect();
        observer.notice(&format!("iteration {}: grids upsampled to {}", run.iteration, sizes.join(", ")));
        run.engine = Rc::new(next);
        run.time_offset = total_time_s + start.elapsed().as_secs_f64();
    }
}

/// Carries θ and the optimiser's state (and meta's carried image) from `from` into `to`,
/// an engine of the same scene at the next coarse-to-fine stage: θ-shaped arrays laid out
/// anew with their grids resampled, the rest (per-group diagnostics, images) as they are.
fn carry_state(from: &Engine, to: &Engine) -> Result<()> {
    let (a, b) = (&from.scene().layout, &to.scene().layout);
    let per_element = |engine: &Engine, buffer: &Buffer| {
        let gs = engine.scene();
        buffer.same(&gs.theta) || engine.optimiser.as_ref().is_some_and(|o| o.per_element(buffer))
    };
    for ((old, old_len), (new, new_len)) in state_buffers(from)?.into_iter().zip(state_buffers(to)?) {
        let values: Vec<f32> = old.read_prefix(old_len)?;
        let values = match per_element(from, old) {
            true => crate::coarse::relayout(&values, a, b, new_len),
            false => values,
        };
        if values.len() != new_len || old.name() != new.name() {
            return Err(Error::Invalid(format!("upsample: {} holds {} values, {} expected", old.name(), values.len(), new_len)));
        }
        new.write(&values)?;
    }
    Ok(())
}

/// Refuses a run directory `dir` in which the run would write a picture over one of the
/// scene's target images (a scene whose `target_image` is `OUTDIR/target.exr`).
fn check_targets_outside(scene: &Scene, dir: &Path) -> Result<()> {
    let Ok(dir) = dir.canonicalize() else { return Ok(()) };
    for sensor in &scene.sensors {
        let Some(path) = sensor.target_image.as_ref().and_then(|t| t.path.canonicalize().ok()) else { continue };
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if path.parent() == Some(dir.as_path()) && crate::preview::is_sensor_file(&name) {
            return Err(Error::Invalid(format!(
                "{}: the run would write its {name} over the scene's target image; give the run another directory",
                dir.display()
            )));
        }
    }
    Ok(())
}

/// Commits the last checkpoint, unless it is committed already (a checkpoint is never
/// written over the committed one: src/rundir.rs), and writes the outputs: all of them,
/// the logs included, so that a run resumed after its last checkpoint was committed (killed
/// before its outputs were written) rebuilds every one from the checkpoint.
fn finish(device: &Device, scene: &Scene, engine: &Engine, mut run: Loop, total_time_s: f64) -> Result<Outcome> {
    if run.committed != Some(run.iteration) {
        run.checkpoint(total_time_s)?;
    }
    if let Some(dir) = run.run_dir {
        dir.debug_point("run.checkpointed");
        run.write_logs(&dir.path)?;
    }
    let settings = &engine.settings;
    let theta = engine.theta()?;
    let layout = &engine.scene().layout;
    let eval_spp = settings.primal_spp.max(64);
    let seeds = [gpu_seed(settings.seed) ^ 0x5EED, gpu_seed(settings.seed) ^ 0x5EED_B0B0];
    let (final_image_error, images) = engine.image_error(None, eval_spp, seeds)?;
    // The same renders of the reference (common random numbers: the same seeds), whose
    // error is what the target's own noise leaves.
    let reference_image_error = match run.has_reference {
        true => Some(engine.image_error(Some(&layout.reference()), eval_spp, seeds)?.0),
        false => None,
    };
    if let Some(dir) = run.run_dir {
        let out_dir = &dir.path;
        write_params(out_dir, &layout.values(&theta))?;
        crate::scene::write::write_final(out_dir, scene, &layout.recovered(&theta))?;
        // The start: the same renders with the initial parameters.
        let starts = engine.image_error(Some(&layout.initial()), eval_spp, seeds)?.1;
        crate::preview::write_run_pictures(out_dir, &engine.targets, &starts, &images)?;
        write_plot(out_dir, &run.log, &scene.path.display().to_string(), settings.optimiser.optimiser.name())?;
        let path = out_dir.join("optimiser.png");
        let title = format!("{}: {} diagnostics", scene.path.display(), settings.optimiser.label);
        crate::optim::csv::plot(&path, &title, &[("", &run.diag)]).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        if engine.carry.is_some() {
            let path = out_dir.join(CARRY_PNG);
            let title = format!("{}: {} carried primal image", scene.path.display(), settings.optimiser.label);
            run.carry.plot(&path, &title).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        }
    }
    let opt = engine.optimiser()?;
    let pass_ms = run.pass_samples.into_iter().map(|(k, mut v)| (k, crate::bench::median(&mut v))).collect();
    let meta_n_eff = opt.meta_n_eff()?.map(|n_eff| {
        let mean = |s: &crate::render::ParamSlot| n_eff[s.offset..s.offset + s.len].iter().map(|&x| x as f64).sum::<f64>() / s.len.max(1) as f64;
        layout.slots.iter().map(|s| (s.name.clone(), mean(s))).collect()
    });
    // Row 0 is the start, restored with the log on a resume: the error where this run
    // began, whether from the scene's `init` or an earlier run's parameters.
    let initial_error = run.log.rows.first().and_then(|r| r.param_error);
    let summary = Summary {
        scene: scene.path.display().to_string(),
        film: Some([scene.film.width, scene.film.height]),
        max_depth: Some(scene.integrator.max_depth),
        optimiser: settings.optimiser.optimiser.name().into(),
        settings: settings.clone(),
        iterations: run.iteration,
        total_time_s,
        total_gpu_time_s: run.gpu_total,
        final_loss: run.last_loss,
        final_param_error: run.log.rows.last().and_then(|r| r.param_error),
        initial_param_error: initial_error,
        final_image_error: Some(final_image_error).filter(|e| e.is_finite()),
        reference_image_error: reference_image_error.filter(|e| e.is_finite()),
        image_error_spp: eval_spp,
        pass_ms,
        nonfinite_gradients: opt.nonfinite_count()?,
        meta_n_eff,
        device: device.info().name.clone(),
        started_from: scene.optimise.started_from.as_ref().map(|p| p.display().to_string()),
        interrupted: run.interrupted,
    };
    if let Some(dir) = run.run_dir {
        let path = dir.path.join("summary.json");
        image::write_bytes_atomic(&path, &json_bytes(&summary)?).map_err(io_err(&path))?;
    }
    let params = layout.values(&theta);
    Ok(Outcome::Finished(Box::new(Run { summary, log: run.log, params })))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parameters of every shape go through `params/` alike: a constant, a texture and a 3-D
    /// grid are written as `NAME.npy` in their array shapes and read back value for value;
    /// the constant and the texture are also in `params.json` (the texture as its EXR).
    #[test]
    fn params_of_every_shape_round_trip_through_npy() {
        let dir = std::env::temp_dir().join(format!("vkinverse-params-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let ramp = |n: usize| (0..n).map(|i| i as f32 * 0.25).collect::<Vec<f32>>();
        let values = vec![
            ("materials.wall.base_color".to_string(), ParamValue { shape: Shape::constant(3), data: ramp(3) }),
            ("materials.wall.roughness".to_string(), ParamValue { shape: Shape::texture(4, 2, 1), data: ramp(8) }),
            ("media.smoke.density".to_string(), ParamValue { shape: Shape::grid(4, 3, 2, 1), data: ramp(24) }),
        ];
        write_params(&dir, &values).unwrap();
        let names: Vec<String> = values.iter().map(|(n, _)| n.clone()).collect();
        assert_eq!(read_params(&dir, &names).unwrap(), values);
        assert_eq!(crate::npy::read(&dir.join("params/media.smoke.density.npy")).unwrap().shape, vec![2, 3, 4, 1]);
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("params/params.json")).unwrap()).unwrap();
        assert_eq!(json["materials.wall.base_color"], serde_json::json!([0.0, 0.25, 0.5]));
        assert_eq!(json["materials.wall.roughness"]["texture"], "materials.wall.roughness.exr");
        assert!(json.get("media.smoke.density").is_none(), "a grid is in its .npy alone");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn carry_log_round_trips_and_names_bad_lines() {
        let state = |w: f32| CarryState { weight: w, var_carried: 1.5e-4, var_fresh: 0.0419, var_diff: 1.3e-13, weight_adjoint: 0.25 };
        let log = CarryLog { rows: vec![(1, 0, state(1.0)), (2, 0, state(0.53)), (2, 1, state(0.0033))] };
        let text = log.to_csv();
        assert_eq!(CarryLog::parse(&text).unwrap(), log);
        assert!(CarryLog::parse("iteration,sensor,weight\n").unwrap_err().contains("header"));
        let bad = format!("{}1,0,0.5,x,1,1,1\n", text.lines().next().unwrap().to_string() + "\n");
        assert!(CarryLog::parse(&bad).unwrap_err().contains("line 2"), "{:?}", CarryLog::parse(&bad));
        let short = format!("{}1,0,0.5\n", text.lines().next().unwrap().to_string() + "\n");
        assert!(CarryLog::parse(&short).is_err());
        // A log from before the adjoint render's weight column reads with that weight 0.
        let earlier = "iteration,sensor,weight,var_carried,var_fresh,var_diff\n3,0,0.5,0.001,0.1,1e-9\n";
        let rows = CarryLog::parse(earlier).unwrap().rows;
        assert_eq!(rows, vec![(3, 0, CarryState { weight: 0.5, var_carried: 0.001, var_fresh: 0.1, var_diff: 1e-9, weight_adjoint: 0.0 })]);
        assert!(CarryLog::parse("iteration,sensor,weight,var_carried,var_fresh,var_diff\n3,0,0.5,0.001,0.1,1e-9,0.2\n").is_err());
    }
}
