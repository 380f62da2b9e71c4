//! `vkinverse batch`: a list of optimisation jobs, run one after another on one Vulkan
//! context, split into shards for schedulers, with one results table.
//!
//! # Job file (TOML)
//! ```toml
//! # Shared settings, for every job (each optional; the scene's [optimise] value otherwise).
//! iterations = 100      # any run setting: time_budget, spp, fd_spp, primal_spp, lr, seed,
//!                       # loss, optimiser, checkpoint_every, fd_two_trace (crate::settings)
//!
//! # The product: one job per (scene, optimiser, seed, spp); scenes vary slowest, spp fastest.
//! scenes = ["cornell/scene.toml", "spiral/scene.toml"]   # relative to the job file
//! optimisers = ["meta", "adam", "adam@beta1=0.5"]        # optional, like seeds and spp
//! seeds = [0, 1]
//! spp = [1, 4]          # a list is an axis of the product; a number is a shared setting
//!
//! # Single jobs, numbered after the product, in file order; any shared setting may be set.
//! [[jobs]]
//! scene = "cornell/scene.toml"
//! optimiser = "meta@decay_f=0.99"
//! seed = 7
//! ```
//! A value comes from, most specific first: the job (its `[[jobs]]` entry or its point of
//! the product), the shared settings, the scene (layered as [`crate::settings`] says). Jobs are numbered from 1 in that order,
//! which depends only on the file, so every shard of a batch sees the same numbering.
//!
//! # Shards
//! `--shard I/N` (1 ≤ I ≤ N) runs the jobs I, I + N, I + 2N, …: shard numbers start at 1 like
//! job numbers, so a Slurm array `--array=1-N` passes `$SLURM_ARRAY_TASK_ID/N` as it is
//! (a 0-based index such as Kubernetes' `$JOB_COMPLETION_INDEX` needs `+1`).
//!
//! # Outputs
//! Each job writes the outputs of `optimise` into `OUTDIR/job-<k>-<label>/`. The table
//! `results.csv` / `results.json` has one row per job run; it is rewritten after every job,
//! so an interrupted batch leaves the rows it finished, and so are, per scene,
//! `error_vs_time-<scene>.png` (every finished job's curve) and `curves-<scene>.csv` (the
//! points behind it). `merge` joins the tables of shards.

use crate::device::Device;
use crate::error::{one_line, Error, Result};
use crate::image::write_bytes_atomic;
use crate::optim::spec::{file_safe, Spec};
use crate::report::{csv_bytes, write_curves, Curve};
use crate::run::{optimise_or_read, Log, Observer, RunOptions, Summary};
use crate::scene::{LoadOptions, Scene, SceneError};
use crate::settings::{deserialize_table, Settings, SettingsTable};
use serde::de::MapAccess;
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A number or a list of numbers (`spp`).
#[derive(Deserialize)]
#[serde(untagged)]
enum OneOrMany {
    One(u32),
    Many(Vec<u32>),
}

/// The job file: shared settings, the product's axes, single jobs.
#[derive(Default)]
struct JobFile {
    settings: Settings,
    scenes: Vec<PathBuf>,
    optimisers: Option<Vec<Spec>>,
    seeds: Option<Vec<u64>>,
    /// A list is an axis of the product (a number is a shared setting, in `settings`).
    spp_axis: Option<Vec<u32>>,
    jobs: Vec<JobEntry>,
}

impl SettingsTable for JobFile {
    const OWN_KEYS: &'static [&'static str] = &["scenes", "optimisers", "seeds", "spp", "jobs"];
    fn read_own<'de, A: MapAccess<'de>>(&mut self, key: &'static str, map: &mut A) -> std::result::Result<(), A::Error> {
        match key {
            "scenes" => self.scenes = map.next_value()?,
            "optimisers" => self.optimisers = Some(map.next_value()?),
            "seeds" => self.seeds = Some(map.next_value()?),
            "spp" => match map.next_value()? {
                OneOrMany::One(n) => self.settings.spp = Some(n),
                OneOrMany::Many(v) => self.spp_axis = Some(v),
            },
            _ => self.jobs = map.next_value()?,
        }
        Ok(())
    }
    fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }
}

impl<'de> Deserialize<'de> for JobFile {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        deserialize_table(d)
    }
}

/// A `[[jobs]]` entry: a scene and its own settings.
#[derive(Default)]
struct JobEntry {
    scene: Option<PathBuf>,
    settings: Settings,
}

impl SettingsTable for JobEntry {
    const OWN_KEYS: &'static [&'static str] = &["scene"];
    fn read_own<'de, A: MapAccess<'de>>(&mut self, _key: &'static str, map: &mut A) -> std::result::Result<(), A::Error> {
        self.scene = Some(map.next_value()?);
        Ok(())
    }
    fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }
    fn finish<E: serde::de::Error>(self) -> std::result::Result<Self, E> {
        match self.scene {
            Some(_) => Ok(self),
            None => Err(E::missing_field("scene")),
        }
    }
}

impl<'de> Deserialize<'de> for JobEntry {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        deserialize_table(d)
    }
}

/// One job of a batch.
#[derive(Clone, Debug)]
pub struct Job {
    /// Its number, from 1.
    pub index: usize,
    /// Scene name and the values the job sets, for its directory and table row.
    pub label: String,
    pub scene: PathBuf,
    /// Shared settings with the job's own on top.
    pub settings: Settings,
    /// Film size and path depth over the scene file's (the command line's `--film`,
    /// `--max-depth`).
    pub load: LoadOptions,
}

impl Job {
    /// The job with `over` (the command line's settings) on top of its own.
    pub fn overridden(self, over: &Settings) -> Job {
        Job { settings: self.settings.then(over), ..self }
    }

    /// The job with its scene loaded with `load` (the command line's film size and path
    /// depth) instead of the scene file's.
    pub fn loaded_with(self, load: LoadOptions) -> Job {
        Job { load, ..self }
    }

    /// The short name of the job's scene (its directory's for `…/NAME/scene.toml`), which
    /// begins its label.
    pub fn scene_name(&self) -> String {
        scene_name(&self.scene)
    }

    /// The job's output directory under OUTDIR.
    pub fn dir_name(&self) -> String {
        format!("job-{}-{}", self.index, self.label)
    }
}

/// A scene's short name: its file's stem, or its directory's name for `…/NAME/scene.toml`.
fn scene_name(path: &Path) -> String {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    match path.parent().and_then(Path::file_name) {
        Some(dir) if stem == "scene" => dir.to_string_lossy().into_owned(),
        _ => stem,
    }
}

/// The label names what the job sets itself: optimiser, seed, spp and learning rate.
fn make_job(index: usize, scene: PathBuf, shared: &Settings, own: &Settings) -> Job {
    let mut label = scene_name(&scene);
    if let Some(o) = &own.optimiser {
        label = format!("{label}-{}", o.label);
    }
    if let Some(s) = own.seed {
        label = format!("{label}-seed{s}");
    }
    if let Some(s) = own.spp {
        label = format!("{label}-spp{s}");
    }
    if let Some(lr) = own.lr {
        label = format!("{label}-lr{lr}");
    }
    Job { index, label: file_safe(&label), scene, settings: shared.then(own), load: LoadOptions::default() }
}

/// Reads and expands a job file; every setting and optimiser spec is checked here, before
/// any job runs (scenes are loaded by their jobs, so a broken one fails only its job).
pub fn load_jobs(path: &Path) -> Result<Vec<Job>> {
    let text = crate::files::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    let file: JobFile = toml::from_str(&text).map_err(|e| SceneError::toml(path.to_path_buf(), &text, e))?;
    let bad = |what: String| Error::Invalid(format!("{}: {what}", path.display()));
    let check = |at: &str, s: &Settings| s.validate().map_err(|e| bad(format!("{at}{} {}", e.key, e.message)));
    check("", &file.settings)?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let axes =
        [("optimisers", file.optimisers.as_ref().map(Vec::len)), ("seeds", file.seeds.as_ref().map(Vec::len)), ("spp", file.spp_axis.as_ref().map(Vec::len))];
    for (key, len) in axes {
        if len == Some(0) {
            return Err(bad(format!("{key} is an empty list")));
        }
        if len.is_some() && file.scenes.is_empty() {
            return Err(bad(format!("{key} is given without scenes = [...]")));
        }
    }
    let optimisers: Vec<Option<Spec>> = file.optimisers.as_ref().map_or(vec![None], |v| v.iter().cloned().map(Some).collect());
    let seeds: Vec<Option<u64>> = file.seeds.as_ref().map_or(vec![None], |v| v.iter().copied().map(Some).collect());
    let spps: Vec<Option<u32>> = file.spp_axis.as_ref().map_or(vec![None], |v| v.iter().copied().map(Some).collect());
    let mut jobs = Vec::new();
    for scene in &file.scenes {
        for optimiser in &optimisers {
            for &seed in &seeds {
                for &spp in &spps {
                    let own = Settings { optimiser: optimiser.clone(), seed, spp, ..Default::default() };
                    check("spp: ", &own)?;
                    jobs.push(make_job(jobs.len() + 1, dir.join(scene), &file.settings, &own));
                }
            }
        }
    }
    for (i, entry) in file.jobs.into_iter().enumerate() {
        check(&format!("jobs[{i}]: "), &entry.settings)?;
        let scene = dir.join(entry.scene.unwrap_or_default());
        jobs.push(make_job(jobs.len() + 1, scene, &file.settings, &entry.settings));
    }
    if jobs.is_empty() {
        return Err(bad("no jobs (give scenes = [...] or [[jobs]] entries)".into()));
    }
    Ok(jobs)
}

/// Shard I of N, both counted from 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// Whether job `index` (from 1) belongs to this shard.
    pub fn has(&self, job: usize) -> bool {
        (job - 1) % self.count == self.index - 1
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let form = || format!("'{s}' is not I/N (shard I of N, 1 <= I <= N, e.g. 1/4)");
        let (i, n) = s.split_once('/').ok_or_else(form)?;
        let index: usize = i.trim().parse().map_err(|_| form())?;
        let count: usize = n.trim().parse().map_err(|_| form())?;
        if count == 0 {
            return Err(format!("'{s}': N must be at least 1"));
        }
        if index == 0 || index > count {
            return Err(format!("'{s}': shards are numbered 1 to {count}"));
        }
        Ok(Shard { index, count })
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Ok,
    Failed,
    /// A Ctrl-C or SIGTERM stopped the job (a cancellation): its outputs are written
    /// for the iteration it reached, and `--resume` continues it.
    Interrupted,
}

impl Status {
    /// As the table and `results.csv` write it (and `results.json`, through serde).
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Failed => "failed",
            Status::Interrupted => "interrupted",
        }
    }
}

/// One row of the results table. Values that a job did not get far enough to know are
/// `None` (empty in the CSV).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JobResult {
    pub job: usize,
    pub label: String,
    pub scene: String,
    /// The spec that named it, or the scene's optimiser.
    pub optimiser: Option<String>,
    pub seed: Option<u64>,
    pub spp: Option<u32>,
    pub status: Status,
    /// The one-line error of a failed job, or where an interrupted one stopped; empty
    /// when ok.
    pub message: String,
    pub iterations: Option<u32>,
    /// Optimisation wall time (as `time_s` in log.csv).
    pub time_s: Option<f64>,
    pub final_loss: Option<f64>,
    /// Final parameter RMSE (None when the reference is unknown).
    pub final_error: Option<f64>,
    /// The optimised scene's image error (`summary.json`'s `final_image_error`).
    #[serde(default)]
    pub final_image_error: Option<f64>,
    /// The job's output directory, relative to the table's directory (in a merged table,
    /// the shard's directory as given to `--merge` joined with it); empty when a failed job
    /// wrote nothing.
    pub dir: String,
}

/// What `results.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Results {
    pub jobs_file: String,
    /// Jobs in the whole batch, not only in this table.
    pub total_jobs: usize,
    /// The shard this table is from; None for a whole batch or a merge.
    pub shard: Option<String>,
    #[serde(default)]
    pub merged_from: Vec<String>,
    pub results: Vec<JobResult>,
}

const CSV_HEADER: [&str; 14] =
    ["job", "label", "scene", "optimiser", "seed", "spp", "status", "message", "iterations", "time_s", "final_loss", "final_error", "final_image_error", "dir"];

impl Results {
    pub fn failed(&self) -> usize {
        self.results.iter().filter(|r| r.status == Status::Failed).count()
    }

    /// `results.csv`: its header (`CSV_HEADER`), one row per job, unknown values empty.
    pub fn csv(&self) -> Result<Vec<u8>> {
        fn opt<T: ToString>(v: Option<T>) -> String {
            v.map(|x| x.to_string()).unwrap_or_default()
        }
        let rows = self.results.iter().map(|r| {
            vec![
                r.job.to_string(),
                r.label.clone(),
                r.scene.clone(),
                opt(r.optimiser.as_deref()),
                opt(r.seed),
                opt(r.spp),
                r.status.as_str().to_string(),
                r.message.clone(),
                opt(r.iterations),
                opt(r.time_s),
                opt(r.final_loss),
                opt(r.final_error),
                opt(r.final_image_error),
                r.dir.clone(),
            ]
        });
        csv_bytes(&CSV_HEADER.map(String::from), rows).map_err(Error::Invalid)
    }

    /// The table printed at the end of a batch or merge.
    pub fn table(&self) -> String {
        let width = self.results.iter().map(|r| r.label.len()).max().unwrap_or(0).max(5);
        let mut s =
            format!("{:>4} {:<width$} {:<11} {:>6} {:>9} {:>11} {:>11}  message\n", "job", "label", "status", "iters", "time (s)", "final loss", "final error");
        let num = |v: Option<f64>| v.map(|x| format!("{x:.4e}")).unwrap_or_else(|| "-".into());
        for r in &self.results {
            let _ = writeln!(
                s,
                "{:>4} {:<width$} {:<11} {:>6} {:>9} {:>11} {:>11}  {}",
                r.job,
                r.label,
                r.status.as_str(),
                r.iterations.map(|i| i.to_string()).unwrap_or_else(|| "-".into()),
                r.time_s.map(|t| format!("{t:.2}")).unwrap_or_else(|| "-".into()),
                num(r.final_loss),
                num(r.final_error),
                r.message
            );
        }
        s
    }

    /// Writes `results.csv` and `results.json` into `dir`, each atomically.
    pub fn write(&self, dir: &Path) -> Result<()> {
        let json = serde_json::to_string_pretty(self).map_err(|e| Error::Invalid(e.to_string()))?;
        for (name, bytes) in [("results.csv", self.csv()?), ("results.json", json.into_bytes())] {
            let path = dir.join(name);
            write_bytes_atomic(&path, &bytes).map_err(|source| Error::Io { path, source })?;
        }
        Ok(())
    }
}

/// Runs one job into `dir`, filling `row` as it learns the job's settings and results;
/// returns its log.
fn run_job(device: &Device, job: &Job, options: &RunOptions, row: &mut JobResult, observer: &mut dyn Observer) -> Result<Log> {
    let scene = Scene::load_with(&job.scene, &job.load)?;
    let st = Settings::resolve(&scene.optimise.settings, &job.settings);
    row.optimiser = Some(job.settings.optimiser.as_ref().map_or_else(|| st.optimiser.label.clone(), |s| s.label.clone()));
    row.seed = Some(st.seed);
    row.spp = Some(st.spp);
    let run = optimise_or_read(device, &scene, &st, options, observer)?;
    row.record(&run.summary);
    Ok(run.log)
}

impl JobResult {
    /// Takes the run's iterations, time and final values from its summary.
    fn record(&mut self, summary: &Summary) {
        self.iterations = Some(summary.iterations);
        self.time_s = Some(summary.total_time_s);
        self.final_loss = Some(summary.final_loss).filter(|l| l.is_finite());
        self.final_error = summary.final_param_error;
        self.final_image_error = summary.final_image_error;
    }
}

/// The jobs of a batch: those of `jobs_file` (`total_jobs` of them) that this process runs
/// (a shard's, or all).
#[derive(Clone, Copy)]
pub struct Plan<'a> {
    pub jobs_file: &'a Path,
    pub total_jobs: usize,
    pub shard: Option<Shard>,
    pub jobs: &'a [Job],
}

/// Runs the plan's jobs one after another on `device` into the output directory of
/// `options` (required), each job's directory treated as its mode says. A job that fails is
/// recorded with its one-line error and the batch goes on; only failing to write the table
/// stops it, or a cancellation: the job it stops is recorded as interrupted, with its values
/// where it stopped, and no further job starts. The observer hears each job start
/// (`job N LABEL`) and end, and its iterations.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::batch::{load_jobs, run, Plan};
/// use vkinverse::{Config, Device, Mode, RunOptions};
/// let dir = std::env::temp_dir().join(format!("vkinverse-doc-batch-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// let cornell = std::fs::canonicalize("scenes/cornell/scene.toml").unwrap();
/// let text = format!("iterations = 2\ntarget_spp = 16\nscenes = [{:?}]\noptimisers = [\"meta\", \"adam\"]\n", cornell);
/// std::fs::write(dir.join("jobs.toml"), text).unwrap();
/// let jobs = load_jobs(&dir.join("jobs.toml"))?;
/// let plan = Plan { jobs_file: &dir.join("jobs.toml"), total_jobs: jobs.len(), shard: None, jobs: &jobs };
/// let out = dir.join("out");
/// let options = RunOptions { out_dir: Some(&out), mode: Mode::Overwrite, cancel: Default::default() };
/// let results = run(&Device::new(&Config::from_env().0)?, plan, &options, &mut ())?;
/// assert_eq!((results.results.len(), results.failed()), (2, 0));
/// # Ok(())
/// # }
/// ```
pub fn run(device: &Device, plan: Plan, options: &RunOptions, observer: &mut dyn Observer) -> Result<Results> {
    let Plan { jobs_file, total_jobs, shard, jobs } = plan;
    let out_dir = options.out_dir.ok_or_else(|| Error::Invalid("a batch needs an output directory".into()))?;
    let (mode, cancel) = (options.mode, &options.cancel);
    // Held for the whole batch: no other run writes into the directory meanwhile.
    let _lock = crate::rundir::RunDir::open_table(out_dir, mode, &device.config().debug_stops)?;
    let mut results =
        Results { jobs_file: jobs_file.display().to_string(), total_jobs, shard: shard.map(|s| s.to_string()), merged_from: Vec::new(), results: Vec::new() };
    let mut logs = BTreeMap::new();
    for job in jobs {
        // After a cancellation no further job starts; the table holds those that ran.
        if cancel.is_cancelled() {
            break;
        }
        let label = format!("job {} {}", job.index, job.label);
        observer.run_started(&label, job.settings.iterations);
        let mut row = JobResult {
            job: job.index,
            label: job.label.clone(),
            scene: job.scene.display().to_string(),
            optimiser: job.settings.optimiser.as_ref().map(|s| s.label.clone()),
            seed: job.settings.seed,
            spp: job.settings.spp,
            status: Status::Ok,
            message: String::new(),
            iterations: None,
            time_s: None,
            final_loss: None,
            final_error: None,
            final_image_error: None,
            dir: job.dir_name(),
        };
        let dir = out_dir.join(job.dir_name());
        let options = RunOptions { out_dir: Some(&dir), mode, cancel: cancel.clone() };
        match run_job(device, job, &options, &mut row, observer) {
            Ok(log) => {
                logs.insert(row.dir.clone(), log);
            }
            Err(Error::Interrupted(message)) => {
                // The run wrote its outputs for the iteration it reached: the row holds
                // its values there.
                row.status = Status::Interrupted;
                row.message = message;
                if let Some(summary) = Summary::read(&dir) {
                    row.record(&summary);
                }
                // Its curve up to there joins the scene's plot.
                if let Ok(log) = Log::read(&dir.join("log.csv")) {
                    logs.insert(row.dir.clone(), log);
                }
            }
            Err(e) => {
                row.status = Status::Failed;
                row.message = one_line(&e);
                if !dir.exists() {
                    // Failed before writing anything (e.g. a broken scene): no directory to name.
                    row.dir.clear();
                }
            }
        }
        match row.status {
            Status::Ok => observer.run_ended(&label, "ok"),
            status => observer.run_ended(&label, &format!("{}: {}", status.as_str(), row.message)),
        }
        results.results.push(row);
        results.write(out_dir)?;
        write_plots(out_dir, &results, &logs)?;
    }
    Ok(results)
}

/// Writes, for each scene of the table, `error_vs_time-<scene>.png` with the curve of every
/// finished job of that scene, and of every interrupted one up to where it stopped (its
/// label followed by ` (interrupted)`), and `curves-<scene>.csv` with the points behind it:
/// the parameter error when every such job has one, else the image loss. `logs` holds each
/// job's log by its row's `dir` (an interrupted job's where it could be read).
fn write_plots(out_dir: &Path, results: &Results, logs: &BTreeMap<String, Log>) -> Result<()> {
    let mut by_scene: BTreeMap<String, Vec<(String, Vec<(f64, f64)>, Vec<(f64, f64)>)>> = Default::default();
    for r in &results.results {
        let label = match r.status {
            Status::Ok => r.label.clone(),
            Status::Interrupted if logs.contains_key(&r.dir) => format!("{} (interrupted)", r.label),
            _ => continue,
        };
        let (err, loss) = logs.get(&r.dir).map(Log::curves).unwrap_or_default();
        by_scene.entry(scene_name(Path::new(&r.scene))).or_default().push((label, err, loss));
    }
    for (scene, runs) in by_scene {
        let param_error = runs.iter().all(|r| !r.1.is_empty());
        let label = if param_error { "parameter RMSE" } else { "image loss" };
        let curves: Vec<Curve> = runs.into_iter().map(|(name, err, loss)| Curve { name, points: if param_error { err } else { loss } }).collect();
        let name = file_safe(&scene);
        write_curves(
            &out_dir.join(format!("curves-{name}.csv")),
            &out_dir.join(format!("error_vs_time-{name}.png")),
            &format!("{scene}: {label} vs time"),
            label,
            &curves,
        )
        .map_err(Error::Invalid)?;
    }
    Ok(())
}

/// Joins the tables in `dirs` (shards of one batch) into one sorted by job number and
/// writes it to `out_dir` with the per-scene plots of the whole batch. Returns it and the numbers of the batch's jobs that no table has.
pub fn merge(dirs: &[PathBuf], out_dir: &Path) -> Result<(Results, Vec<usize>)> {
    let mut merged: Option<Results> = None;
    // Where each job's row came from, to name both tables of a duplicate.
    let mut origin: std::collections::BTreeMap<usize, &Path> = Default::default();
    for dir in dirs {
        let path = dir.join("results.json");
        let text = std::fs::read_to_string(&path).map_err(|source| Error::Io { path: path.clone(), source })?;
        let table: Results = serde_json::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        let m = merged.get_or_insert_with(|| Results { shard: None, merged_from: Vec::new(), results: Vec::new(), ..table.clone() });
        if table.total_jobs != m.total_jobs {
            let first = dirs[0].display();
            return Err(Error::Invalid(format!(
                "{}: a batch of {} jobs, but {first} is from one of {} (not shards of one job file?)",
                path.display(),
                table.total_jobs,
                m.total_jobs
            )));
        }
        for mut row in table.results {
            if let Some(other) = origin.insert(row.job, dir) {
                return Err(Error::Invalid(format!("job {} is in both {} and {}", row.job, other.display(), dir.display())));
            }
            if !row.dir.is_empty() {
                row.dir = dir.join(&row.dir).display().to_string();
            }
            m.results.push(row);
        }
        m.merged_from.push(dir.display().to_string());
    }
    let mut merged = merged.ok_or_else(|| Error::Invalid("nothing to merge: give the shards' output directories".into()))?;
    merged.results.sort_by_key(|r| r.job);
    let missing = (1..=merged.total_jobs).filter(|k| !origin.contains_key(k)).collect();
    // The merged table replaces one merged before; a single run's directory is refused.
    let _lock = crate::rundir::RunDir::open_table(out_dir, crate::rundir::Mode::Resume, &Default::default())?;
    merged.write(out_dir)?;
    // The shards ran in other processes: their logs are read back, from the job
    // directories as the shards were given.
    let mut logs = BTreeMap::new();
    for r in &merged.results {
        let log = Log::read(&Path::new(&r.dir).join("log.csv"));
        match (r.status, log) {
            (Status::Ok, log) => {
                logs.insert(r.dir.clone(), log?);
            }
            (Status::Interrupted, Ok(log)) => {
                logs.insert(r.dir.clone(), log);
            }
            _ => {}
        }
    }
    write_plots(out_dir, &merged, &logs)?;
    Ok((merged, missing))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jobs_from(text: &str) -> Result<Vec<Job>> {
        static COUNTER: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("vkinverse-batch-unit-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|source| Error::Io { path: dir.clone(), source })?;
        let path = dir.join("jobs.toml");
        std::fs::write(&path, text).map_err(|source| Error::Io { path: path.clone(), source })?;
        load_jobs(&path)
    }

    #[test]
    fn product_then_single_jobs_in_order() {
        let jobs = jobs_from(
            "iterations = 5\nspp = [1, 2]\nscenes = ['a/scene.toml', 'b.toml']\noptimisers = ['meta', 'adam@beta1=0.5']\n\
             [[jobs]]\nscene = 'c/scene.toml'\nseed = 3\niterations = 9\n\n[[jobs]]\nscene = 'c/scene.toml'\nlr = 0.002\n",
        )
        .unwrap();
        let labels: Vec<String> = jobs.iter().map(Job::dir_name).collect();
        assert_eq!(
            labels,
            [
                "job-1-a-meta-spp1",
                "job-2-a-meta-spp2",
                "job-3-a-adam@beta1=0.5-spp1",
                "job-4-a-adam@beta1=0.5-spp2",
                "job-5-b-meta-spp1",
                "job-6-b-meta-spp2",
                "job-7-b-adam@beta1=0.5-spp1",
                "job-8-b-adam@beta1=0.5-spp2",
                "job-9-c-seed3",
                "job-10-c-lr0.002",
            ]
        );
        assert_eq!(jobs[1].settings.iterations, Some(5));
        assert_eq!(jobs[1].settings.spp, Some(2));
        assert_eq!(jobs[8].settings.iterations, Some(9));
        assert_eq!(jobs[8].settings.spp, None, "a list of spp is an axis of the product only");
        assert_eq!(jobs[8].settings.seed, Some(3));
        assert_eq!(jobs[2].settings.optimiser.as_ref().map(|s| s.label.as_str()), Some("adam@beta1=0.5"));
    }

    #[test]
    fn bad_job_files_name_the_problem() {
        let err = |text: &str| jobs_from(text).unwrap_err().to_string();
        assert!(err("scenes = ['a.toml']\noptimisers = ['sgd']").contains(":2:14: unknown optimiser 'sgd'"));
        assert!(err("scenes = ['a.toml']\nlr = -1").contains("lr -1 is not positive"));
        assert!(err("seeds = [1]").contains("seeds is given without scenes"));
        assert!(err("scenes = ['a.toml']\nseeds = []").contains("seeds is an empty list"));
        assert!(err("scenes = ['a.toml']\nspp = [0]").contains("spp must be at least 1"));
        assert!(err("").contains("no jobs"));
        assert!(err("scenes = ['a.toml']\nitterations = 3").contains(":2:1: unknown field `itterations`"), "{}", err("scenes = ['a.toml']\nitterations = 3"));
        assert!(err("[[jobs]]\nscene = 'a.toml'\noptimiser = 'adam@beta3=1'").contains(":3:13: optimiser spec 'adam@beta3=1': unknown key 'beta3'"));
    }

    #[test]
    fn shards_partition_the_jobs() {
        let s: Shard = "2/3".parse().unwrap();
        assert_eq!((1..=8).filter(|&k| s.has(k)).collect::<Vec<_>>(), [2, 5, 8]);
        for bad in ["0/2", "3/2", "x", "1/0", "1/", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        let all: Vec<usize> = (1..=4).flat_map(|i| (1..=10).filter(move |&k| Shard { index: i, count: 4 }.has(k))).collect();
        let mut sorted = all.clone();
        sorted.sort();
        assert_eq!(sorted, (1..=10).collect::<Vec<_>>());
    }
}
