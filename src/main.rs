//! The vkinverse command line: parse, call the library, print.

mod cli;

use clap::{Args, Parser, Subcommand};
use cli::interrupt;
use cli::progress::{warn, Terminal};
use cli::settings_args::SettingsArgs;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use vkinverse::{Config, Device, Mode, Outcome, RunOptions, Settings};

type Result<T = ()> = std::result::Result<T, Box<dyn std::error::Error>>;

#[derive(Parser)]
#[command(name = "vkinverse", version, about = "Inverse path tracing on any Vulkan device")]
struct Cli {
    /// Vulkan device: index or part of its name (see `vkinverse info`).
    #[arg(long, global = true)]
    device: Option<String>,
    /// Print only errors and results.
    #[arg(long, global = true)]
    quiet: bool,
    /// Turn on the Vulkan validation layer (with synchronization validation).
    #[arg(long, global = true)]
    validation: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List Vulkan devices, the chosen one, its limits and the features vkinverse uses.
    Info {
        #[arg(long)]
        json: bool,
    },
    /// Render one sensor of a scene to EXR (linear), NPY (linear float32 [height, width, 3]) or PNG (tone-mapped sRGB).
    Render(RenderArgs),
    /// Recover the scene's optimised parameters from its target images.
    #[command(after_help = format!("{OPTIMISE_HELP}\n\nOptimiser specs (--optimiser): NAME[@KEY=VALUE]..., keys:\n{}", vkinverse::Spec::keys_help()))]
    Optimise(OptimiseArgs),
    /// Run several optimisers on one scene at equal cost and seed; plot and tabulate their
    /// error against run time.
    #[command(after_help = format!("Optimiser specs: NAME[@KEY=VALUE]..., with NAME adam, meta or meta-seed (the seed's configuration) and these keys (docs/optimisers.md):\n{}{COMPARE_HELP}", vkinverse::Spec::keys_help()))]
    Compare(CompareArgs),
    /// Run a list of optimisation jobs (or one shard of it) on one device, with one results
    /// table; or merge the tables of shards.
    #[command(after_help = BATCH_HELP)]
    Batch(BatchArgs),
    /// Check the adjoint gradient against finite differences of the loss. Exits non-zero
    /// unless the verdict is "pass" (a failed or an inconclusive check).
    Gradcheck(GradcheckArgs),
    /// Run the GPU optimiser passes on gradient streams from .npy files.
    Replay(ReplayArgs),
    /// Measure GPU passes with timestamps: a scene's iteration pass by pass, without a scene
    /// the buffer kernels' bandwidth, or with --media a synthetic medium's passes; each
    /// times the optimiser passes on a synthetic θ.
    Bench(BenchArgs),
}

#[derive(Args)]
struct RenderArgs {
    scene: PathBuf,
    #[arg(long, default_value_t = 64)]
    spp: u32,
    /// Render for at most about this many seconds (from the scene's upload; the
    /// submission under way when they run out is finished): the image holds the samples
    /// rendered by then, at most --spp, and the message says how many.
    #[arg(long, value_name = "SEC", allow_negative_numbers = true)]
    time_budget: Option<f64>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, default_value_t = 0)]
    sensor: u32,
    #[command(flatten)]
    scene_flags: SceneFlags,
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
}

#[derive(Args)]
struct OptimiseArgs {
    scene: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
    #[command(flatten)]
    scene_flags: SceneFlags,
    #[command(flatten)]
    start: StartFlags,
    /// Continue the run in OUTDIR from its committed checkpoint (same scene and parameters).
    #[arg(long, conflicts_with_all = ["overwrite", "init_from"])]
    resume: bool,
    /// Replace the run in OUTDIR.
    #[arg(long)]
    overwrite: bool,
    /// Output directory.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
}

#[derive(Args)]
struct CompareArgs {
    scene: PathBuf,
    /// Comma-separated optimiser specs NAME[@KEY=VALUE]..., e.g.
    /// `meta,adam,adam@beta1=0.5@beta2=0.99`; the first is the baseline.
    #[arg(long, allow_hyphen_values = true)]
    optimisers: String,
    #[command(flatten)]
    settings: SettingsArgs,
    #[command(flatten)]
    scene_flags: SceneFlags,
    #[command(flatten)]
    start: StartFlags,
    #[command(flatten)]
    out: TableOutput,
}

#[derive(Args)]
struct BatchArgs {
    /// Job file (TOML, format below).
    jobs: Option<PathBuf>,
    /// Run shard I of N: jobs I, I+N, I+2N, ... (jobs and shards count from 1).
    #[arg(long, value_name = "I/N", allow_hyphen_values = true)]
    shard: Option<String>,
    /// Run only the jobs of this scene (its short name, as in the jobs' labels: `ajar` for
    /// `ajar/scene.toml`); may be repeated. The jobs keep their numbers.
    #[arg(long = "scene", value_name = "NAME")]
    scenes: Vec<String>,
    /// Join the results tables in these output directories (of shards) into one.
    #[arg(long, value_name = "OUTDIR", num_args = 1.., conflicts_with_all = ["jobs", "shard", "scenes"])]
    merge: Vec<PathBuf>,
    /// Run settings given here replace every job's (e.g. `--seed 1` runs the job file at
    /// another seed).
    #[command(flatten)]
    settings: SettingsArgs,
    /// Film size and path depth for every job's scene (e.g. `--film 256x256` runs the job
    /// file at another resolution).
    #[command(flatten)]
    scene_flags: SceneFlags,
    #[command(flatten)]
    out: TableOutput,
}

/// The output of the commands that run many optimisations and print one table.
#[derive(Args)]
struct TableOutput {
    /// Replace runs found in OUTDIR's run directories.
    #[arg(long)]
    overwrite: bool,
    /// Continue the runs found in OUTDIR's run directories from their checkpoints (an
    /// interrupted batch or comparison): a finished run is taken as it is, a directory
    /// without a checkpoint is run anew.
    #[arg(long, conflicts_with = "overwrite")]
    resume: bool,
    /// Print the table as JSON (compare.json, results.json).
    #[arg(long)]
    json: bool,
    /// Output directory (of the comparison, the batch, a shard or the merged table).
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
}

#[derive(Args)]
struct GradcheckArgs {
    scene: PathBuf,
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Samples per pixel of the primal images whose loss the adjoint pass differentiates
    /// (by default --spp)
    #[arg(long, value_name = "N")]
    primal_spp: Option<u32>,
    /// Rounds (independent estimates of each side); by default sized from a pilot so that
    /// a 10 % bias of a typical gradient would be detected, up to --max-rounds.
    #[arg(long)]
    rounds: Option<u32>,
    #[arg(long, default_value_t = 200)]
    max_rounds: u32,
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    scene_flags: SceneFlags,
    #[command(flatten)]
    start: StartFlags,
}

#[derive(Args)]
struct ReplayArgs {
    /// An optimiser spec: meta, meta-seed or adam, with optional @KEY=VALUE hyperparameters.
    #[arg(long)]
    optimiser: String,
    #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
    lr: f64,
    /// Parameter bounds, e.g. `--range 0,1` (unbounded by default).
    #[arg(long, allow_hyphen_values = true)]
    range: Option<String>,
    /// Start values (shape [n]); zeros by default.
    #[arg(long)]
    init: Option<PathBuf>,
    /// Proportional gradients, float32 [iterations, n].
    grads: PathBuf,
    /// Finite-difference samples, float32 [iterations, n] (meta only).
    fd_grads: Option<PathBuf>,
    /// The sums of half of the pixels of GRADS and of FD_GRADS, `GH.npy,FH.npy`, each
    /// [iterations, n] (meta with var=centred).
    #[arg(long, value_name = "GH.npy,FH.npy")]
    halves: Option<String>,
    /// Write each step's optimiser diagnostics to this CSV file.
    #[arg(long, value_name = "CSV")]
    diagnostics: Option<PathBuf>,
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
}

#[derive(Args)]
struct BenchArgs {
    /// Scene to benchmark (the buffer kernels are measured when absent).
    scene: Option<PathBuf>,
    /// Repetitions of each kernel or iteration (the median is reported).
    #[arg(long, default_value_t = 9)]
    iterations: u32,
    /// Elements (f32) per buffer for the buffer kernels, and parameters of the synthetic
    /// θ of the optimiser passes [default: 16777216 without a scene, 1048576 with one]
    #[arg(long)]
    elements: Option<u64>,
    /// With a scene: compare the BVH layouts (binary, wide, cw8) instead, rotating them
    /// over `--iterations` rounds.
    #[arg(long)]
    bvh_layouts: bool,
    /// With a scene (or --media): repeat its iteration untimed for this many seconds before timing it,
    /// so that a GPU whose clocks idle low has raised them [default: 0 on a CPU device
    /// (lavapipe), 2 on others]
    #[arg(long, value_name = "SECONDS")]
    warm_up: Option<f64>,
    /// Without a scene: time the passes of a synthetic medium instead (a box of emitting and
    /// absorbing medium with smooth random density and emission grids, both optimised, seen
    /// by one camera; no meshes), for every grid side of --media-grids on every film side
    /// of --media-films, and the optimiser passes on a θ of 4·N³ parameters for the largest
    /// grid N (or --elements).
    #[arg(long, conflicts_with_all = ["scene", "bvh_layouts"])]
    media: bool,
    /// With --media: the grids' sides, comma-separated.
    #[arg(long, value_name = "N,...", value_delimiter = ',', default_value = "64,128", requires = "media")]
    media_grids: Vec<u32>,
    /// With --media: the (square) films' sides, comma-separated.
    #[arg(long, value_name = "N,...", value_delimiter = ',', default_value = "64,256", requires = "media")]
    media_films: Vec<u32>,
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    scene_flags: SceneFlags,
}

/// Where the optimised parameters start.
#[derive(Args)]
struct StartFlags {
    /// Start every optimised parameter from an earlier run's recovered values: its
    /// OUTDIR (or OUTDIR/params), whose params.json must name each of this scene's
    /// parameters; textures are resampled to this scene's size. Replaces the scene's `init`.
    #[arg(long, value_name = "OUTDIR")]
    init_from: Option<PathBuf>,
}

impl StartFlags {
    fn apply(&self, scene: &mut vkinverse::scene::Scene) -> std::result::Result<(), vkinverse::scene::SceneError> {
        match &self.init_from {
            Some(dir) => scene.start_from_run(dir),
            None => Ok(()),
        }
    }
}

/// Settings that change what a scene renders, over the scene file's (any format).
#[derive(Args)]
struct SceneFlags {
    /// Film size, e.g. `--film 640x480` (a bare glTF scene has 512 on the camera's longer
    /// side).
    #[arg(long, value_name = "WxH")]
    film: Option<String>,
    /// Longest path in segments (1: emitters only, 2: direct light); a bare glTF scene has 8.
    #[arg(long, value_name = "N")]
    max_depth: Option<u32>,
}

impl SceneFlags {
    fn options(&self) -> std::result::Result<vkinverse::scene::LoadOptions, String> {
        use vkinverse::scene::{Film, MAX_DEPTH, MAX_IMAGE_SIDE};
        let film = match &self.film {
            None => None,
            Some(f) => {
                let bad = || format!("--film {f}: expected WIDTHxHEIGHT, each in 1..={MAX_IMAGE_SIDE}");
                let (w, h) = f.split_once(['x', 'X']).ok_or_else(bad)?;
                let side = |v: &str| v.trim().parse::<u32>().ok().filter(|v| (1..=MAX_IMAGE_SIDE).contains(v)).ok_or_else(bad);
                Some(Film { width: side(w)?, height: side(h)? })
            }
        };
        if let Some(d) = self.max_depth.filter(|d| !(1..=MAX_DEPTH).contains(d)) {
            return Err(format!("--max-depth {d}: must be in 1..={MAX_DEPTH}"));
        }
        Ok(vkinverse::scene::LoadOptions { film, max_depth: self.max_depth })
    }
}

/// Loads a scene file of any format with the command line's scene flags, printing what the
/// import approximated or left out (one line each) unless --quiet.
fn load_scene(cli: &Cli, path: &std::path::Path, flags: &SceneFlags) -> std::result::Result<vkinverse::Scene, Box<dyn std::error::Error>> {
    let scene = vkinverse::Scene::load_with(path, &flags.options()?)?;
    for w in scene.warnings.iter().chain(&scene.render_warnings()) {
        warn(cli.quiet, w);
    }
    Ok(scene)
}

const OPTIMISE_HELP: &str = "\
Settings given here replace the scene's [optimise] values; --lr replaces its per-parameter
rates too. A --time-budget without --iterations runs for the budget alone.

OUTDIR holds one run at a time: a second run into it is refused at once, and a directory
that holds a run is refused unless --resume (continue it: the scene and its parameters
must be those of the checkpoint; changed settings are listed) or --overwrite (replace
it). A checkpoint is committed every --checkpoint-every iterations and at the end; a
kill at any instant leaves the last committed one resumable. Ctrl-C (or SIGTERM) stops the
run after its current iteration and writes its outputs (exit status 130, or 143); the
same command with --resume continues it. A second Ctrl-C stops at once.

preview.png shows, left to right, the target, the start (the initial parameters), the
result (final.exr) and |final - target| divided by the target's mean value, each as
`render -o IMAGE.png` writes an image; target.exr and start.exr hold the first two. A
scene of several sensors gets preview-K.png, target-K.exr, start-K.exr, final-K.exr.";

const COMPARE_HELP: &str = "\
Unset keys keep their defaults. `@` separates keys so that specs hold no comma.

Every run gets the same settings and seed: the same --time-budget (wall time, set-up
excluded) when given, else the same --iterations (the scene's by default). Each run's
directory follows optimise's rules (--overwrite replaces earlier runs; --resume continues
them, reads back the finished ones and starts the missing ones; Ctrl-C stops the run in
progress and writes no table). Outputs in OUTDIR:
  <label>/            each run's optimise outputs (log.csv, summary.json, ...)
  error_vs_time.png   all runs, log-scale error against wall time
  curves.csv          label,time_s,error: the points of the plot
  finals.png          the target, then each run's final image in --optimisers order, side
                      by side (finals-K.png for sensor K of several)
  compare.csv, .json  per run: final error; time_to_2x, time_to_1x, time_to_0.5x: the wall
                      time at which its error first reached 2, 1 and 0.5 times the first
                      run's final error; speedup: the first run's time to its final error
                      over this run's (empty when never reached);
                      image_error_over_reference: the result's image error less the
                      reference's at the same random numbers (summary.json)
The error is the parameter RMSE when the reference is known, else the image loss.";

const BATCH_HELP: &str = "\
Job file (TOML); paths are relative to it:
  iterations = 100                 # shared settings (optional): any run setting, as in a
  lr = 0.05                        #   scene's [optimise] (iterations, time_budget, spp, ...)
  scenes = [\"cornell/scene.toml\"]  # product: one job per scene x optimiser x seed x spp
  optimisers = [\"meta\", \"adam\"]    # optional axes; the scene's value when absent
  seeds = [0, 1]
  spp = [1, 4]                     # a list is an axis; a number is a shared setting
  [[jobs]]                         # single jobs after the product, in file order
  scene = \"spiral/scene.toml\"    # with optimiser, seed, spp and any shared setting
  optimiser = \"adam@beta1=0.5\"
Run settings given as flags (--seed 1, --iterations 50, ...) replace every job's.
--scene NAME (repeatable) runs only the jobs of that scene, e.g. --scene ajar.
Jobs are numbered from 1 (scenes vary slowest, spp fastest, then [[jobs]]). --shard I/N
runs jobs I, I+N, I+2N, ... (1 <= I <= N; with a 0-based scheduler index, pass index+1).
Each job writes OUTDIR/job-<k>-<label>/; OUTDIR/results.csv and results.json hold one row
per job (job, label, scene, optimiser, seed, spp, status ok|failed|interrupted, message, iterations,
time_s, final_loss, final_error, final_image_error, dir); per scene, error_vs_time-<scene>.png plots every
finished job's error against time (an interrupted one's up to where it stopped, labelled
\"(interrupted)\") and curves-<scene>.csv (label,time_s,error) holds its points.
--film WxH and --max-depth N load every job's scene at that size and depth.
A failed job does not stop the batch; the exit status is non-zero if any failed.
Ctrl-C (or SIGTERM) stops the job it interrupts after its current iteration (recorded as
interrupted, with its values there, its outputs written) and starts no further one (exit
status 130, or 143); --resume then continues each job's run from its checkpoint, reads
back the finished ones and starts the rest. --merge OUTDIR... -o OUTDIR joins shards'
tables, sorted by job, refusing a job found twice and warning about jobs found nowhere.";

/// Writes to stdout. A reader that closed the pipe early (`vkinverse info | head -1`) has
/// what it wanted, so that is not an error; `println!` would panic there instead.
fn out(text: std::fmt::Arguments) -> std::io::Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_fmt(text) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => r,
    }
}

macro_rules! outln {
    ($($arg:tt)*) => { out(format_args!("{}\n", format_args!($($arg)*))) };
}

/// Prints `value` as pretty JSON, or `table` as text.
fn print_result(json: bool, value: &impl serde::Serialize, table: impl FnOnce() -> String) -> Result {
    if json {
        outln!("{}", serde_json::to_string_pretty(value)?)?;
    } else {
        out(format_args!("{}", table()))?;
    }
    Ok(())
}

/// Checks a layer of settings given as flags, naming the flag.
fn check_flags(settings: &Settings) -> Result {
    settings.validate().map_err(|e| format!("{} {}", e.flag(), e.message))?;
    Ok(())
}

/// The configuration of the device: the environment's (`vkinverse::config::ENVIRONMENT`),
/// with `--device` and `--validation` over it. Values of the environment that cannot be
/// used are warned about.
fn config(cli: &Cli) -> Config {
    let (mut config, warnings) = Config::from_env();
    for w in warnings {
        warn(cli.quiet, &w);
    }
    if let Some(d) = &cli.device {
        config.device = Some(d.clone());
    }
    config.validation |= cli.validation;
    config
}

fn device(cli: &Cli) -> vkinverse::Result<Device> {
    Device::new(&config(cli))
}

/// How to continue work that a signal stopped (`cli::interrupt`), given whether its
/// command replaced an earlier run.
fn resume_hint(overwrite: bool) -> &'static str {
    if overwrite {
        "the same command with --resume instead of --overwrite"
    } else {
        "the same command with --resume"
    }
}

fn mode(resume: bool, overwrite: bool) -> Mode {
    match (resume, overwrite) {
        (true, _) => Mode::Resume,
        (_, true) => Mode::Overwrite,
        _ => Mode::New,
    }
}

/// Run options into `output` with the signal handler's cancellation token.
fn run_options(output: &std::path::Path, mode: Mode) -> Result<RunOptions<'_>> {
    interrupt::install()?;
    Ok(RunOptions { out_dir: Some(output), mode, cancel: interrupt::token() })
}

fn run_render(cli: &Cli, a: &RenderArgs) -> Result {
    let ext = a.output.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("exr" | "png" | "npy")) {
        return Err(format!("{}: output must end in .exr, .npy or .png", a.output.display()).into());
    }
    if a.spp == 0 {
        return Err("--spp must be at least 1".into());
    }
    if let Some(t) = a.time_budget.filter(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(format!("--time-budget {t} is not positive and finite").into());
    }
    let scene = load_scene(cli, &a.scene, &a.scene_flags)?;
    if a.sensor as usize >= scene.sensors.len() {
        return Err(format!("--sensor {}: the scene has {} sensor(s)", a.sensor, scene.sensors.len()).into());
    }
    // The directory first: a render is not thrown away for want of it.
    if let Some(dir) = a.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let device = device(cli)?;
    interrupt::install()?;
    let start = std::time::Instant::now();
    let mut progress = cli::progress::ProgressReport::new(cli.quiet, "render", a.spp as u64, "samples");
    let budget = a.time_budget.map(std::time::Duration::from_secs_f64);
    let out_of_time = || budget.is_some_and(|b| start.elapsed() >= b);
    let stop = || interrupt::requested() || out_of_time();
    let renderer = vkinverse::Renderer::new(&device, &scene)?;
    let options = vkinverse::RenderOptions { sensor: a.sensor, spp: a.spp, seed: a.seed };
    let (image, spp) = renderer.render_until(&options, |done, _| progress.set(done as u64, ""), stop)?;
    progress.finish();
    if ext.as_deref() == Some("png") {
        vkinverse::image::write_png(&a.output, &image)?;
    } else if ext.as_deref() == Some("npy") {
        let data = image.data.as_flattened().to_vec();
        vkinverse::npy::write(&a.output, &vkinverse::npy::Array { shape: vec![image.height as usize, image.width as usize, 3], data })?;
    } else {
        vkinverse::image::write_exr(&a.output, &image)?;
    }
    if !cli.quiet {
        let secs = start.elapsed().as_secs_f64();
        let why = if spp < a.spp && out_of_time() { " (the time budget's)" } else { "" };
        eprintln!("rendered {}x{} at {spp} spp{why} in {secs:.2} s -> {}", image.width, image.height, a.output.display());
    }
    if spp < a.spp && interrupt::requested() {
        // A Ctrl-C: the image holds the samples rendered until then.
        let msg = format!("stopped at {spp} of {} samples per pixel; {} holds their mean", a.spp, a.output.display());
        return Err(vkinverse::Error::Interrupted(msg).into());
    }
    Ok(())
}

fn run_optimise(cli: &Cli, a: &OptimiseArgs) -> Result {
    // Flags first: a typo on the command line is reported before the scene is read.
    check_flags(&a.settings.0)?;
    let mut scene = load_scene(cli, &a.scene, &a.scene_flags)?;
    a.start.apply(&mut scene)?;
    let st = a.settings.0.resolve_for(&scene);
    let device = device(cli)?;
    let mut progress = Terminal::new(cli.quiet, "optimise", st.iterations);
    let options = run_options(&a.output, mode(a.resume, a.overwrite))?;
    let outcome = vkinverse::optimise(&device, &scene, &st, &options, &mut progress);
    progress.finish();
    let run = match outcome? {
        Outcome::Finished(run) => run,
        Outcome::AlreadyDone(run) => {
            let iteration = run.summary.iterations;
            outln!("{}: the run finished at iteration {iteration}; nothing to do, nothing changed (give more --iterations or a longer --time-budget to continue it)", a.output.display())?;
            return Ok(());
        }
    };
    if !cli.quiet {
        let s = &run.summary;
        let err = |e: Option<f64>| e.map(|v| format!("{v:.4e}")).unwrap_or_else(|| "n/a".into());
        outln!(
            "{}: {} iterations of {} in {:.2} s (GPU {:.2} s); loss {:.4e}; parameter RMSE {} -> {}",
            s.scene,
            s.iterations,
            s.optimiser,
            s.total_time_s,
            s.total_gpu_time_s,
            s.final_loss,
            err(s.initial_param_error),
            err(s.final_param_error)
        )?;
        let floor = match (s.final_image_error, s.reference_image_error) {
            (Some(e), Some(r)) => format!(" (the reference's {r:.4e}, with the same random numbers: {:+.3e} over it)", e - r),
            _ => String::new(),
        };
        outln!("image error of the result: {}{floor}, from two renders of {} spp against the target", err(s.final_image_error), s.image_error_spp)?;
        let carry = if a.output.join(vkinverse::run::CARRY_CSV).exists() { " carry.csv carry.png" } else { "" };
        let pictures = match scene.sensors.len() {
            1 => "target.exr start.exr preview.png".to_string(),
            n => format!("target-K.exr start-K.exr final-K.exr preview-K.png (K = 0..{})", n - 1),
        };
        outln!(
            "outputs in {}: log.csv summary.json params/ final.exr final/ {pictures} error_vs_time.png optimiser.csv optimiser.png{carry} checkpoint/",
            a.output.display()
        )?;
    }
    if run.summary.interrupted {
        let target = match (st.iterations, st.time_budget) {
            (Some(n), _) => format!(" of {n}"),
            (None, Some(t)) => format!(" ({t} s budget)"),
            (None, None) => String::new(),
        };
        let msg = format!("stopped at iteration {}{target}; {} continues the run in {}", run.summary.iterations, resume_hint(a.overwrite), a.output.display());
        return Err(vkinverse::Error::Interrupted(msg).into());
    }
    Ok(())
}

fn run_compare(cli: &Cli, a: &CompareArgs) -> Result {
    // Flags first: a typo on the command line is reported before the scene is read.
    let specs = vkinverse::Spec::parse_list(&a.optimisers).map_err(|e| format!("--optimisers: {e}"))?;
    if a.settings.0.optimiser.is_some() {
        return Err("compare takes --optimisers (a list), not --optimiser".into());
    }
    check_flags(&a.settings.0)?;
    let mut scene = load_scene(cli, &a.scene, &a.scene_flags)?;
    a.start.apply(&mut scene)?;
    let device = device(cli)?;
    let options = run_options(&a.out.output, mode(a.out.resume, a.out.overwrite))?;
    let mut progress = Terminal::new(cli.quiet, "", None);
    let comparison = vkinverse::compare::compare(&device, &scene, &a.settings.0, &specs, &options, &mut progress).map_err(|e| match e {
        vkinverse::Error::Interrupted(m) => vkinverse::Error::Interrupted(format!("{m}; {} continues it", resume_hint(a.out.overwrite))),
        e => e,
    })?;
    progress.finish();
    print_result(a.out.json, &comparison, || comparison.table())?;
    if !a.out.json && !cli.quiet {
        let finals = match scene.sensors.len() {
            1 => "finals.png".to_string(),
            n => format!("finals-K.png (K = 0..{})", n - 1),
        };
        outln!(
            "outputs in {}: error_vs_time.png optimiser.png {finals} curves.csv compare.csv compare.json and one directory per optimiser",
            a.out.output.display()
        )?;
    }
    Ok(())
}

fn run_batch(cli: &Cli, a: &BatchArgs) -> Result {
    use vkinverse::batch;
    check_flags(&a.settings.0)?;
    if !a.merge.is_empty() {
        if a.settings.0 != Settings::default() || a.scene_flags.film.is_some() || a.scene_flags.max_depth.is_some() || a.out.resume || a.out.overwrite {
            return Err("run settings, --film, --max-depth, --resume and --overwrite apply to a job file's runs, not to --merge".into());
        }
        let (merged, missing) = batch::merge(&a.merge, &a.out.output)?;
        if !missing.is_empty() {
            let list: Vec<String> = missing.iter().map(usize::to_string).collect();
            warn(cli.quiet, &format!("job(s) {} of {} are in none of the tables", list.join(", "), merged.total_jobs));
        }
        return print_result(a.out.json, &merged, || merged.table());
    }
    let shard: Option<batch::Shard> = a.shard.as_deref().map(|s| s.parse().map_err(|e| format!("--shard {e}"))).transpose()?;
    let Some(jobs_file) = &a.jobs else {
        return Err("give a job file, or --merge with the shards' output directories".into());
    };
    let load = a.scene_flags.options()?;
    let all: Vec<batch::Job> = batch::load_jobs(jobs_file)?.into_iter().map(|job| job.overridden(&a.settings.0).loaded_with(load)).collect();
    let names: Vec<String> = all.iter().map(batch::Job::scene_name).collect();
    if let Some(unknown) = a.scenes.iter().find(|n| !names.contains(n)) {
        let mut known: Vec<&str> = Vec::new();
        for n in &names {
            if !known.contains(&n.as_str()) {
                known.push(n);
            }
        }
        return Err(format!("--scene {unknown}: no job of {} has that scene (its scenes: {})", jobs_file.display(), known.join(", ")).into());
    }
    let mine: Vec<batch::Job> = all
        .iter()
        .zip(&names)
        .filter(|(j, name)| shard.iter().all(|s| s.has(j.index)) && (a.scenes.is_empty() || a.scenes.contains(name)))
        .map(|(j, _)| j.clone())
        .collect();
    // One device for every job: its set-up is paid once per batch.
    let device = device(cli)?;
    let options = run_options(&a.out.output, mode(a.out.resume, a.out.overwrite))?;
    let plan = batch::Plan { jobs_file, total_jobs: all.len(), shard, jobs: &mine };
    let mut progress = Terminal::new(cli.quiet, "", None);
    let results = batch::run(&device, plan, &options, &mut progress)?;
    progress.finish();
    print_result(a.out.json, &results, || results.table())?;
    if interrupt::requested() {
        let msg = format!(
            "{} of {} jobs ran (see {}); {} continues the batch",
            results.results.len(),
            mine.len(),
            a.out.output.join("results.csv").display(),
            resume_hint(a.out.overwrite)
        );
        return Err(vkinverse::Error::Interrupted(msg).into());
    }
    let failed = results.failed();
    if failed > 0 {
        return Err(format!("{failed} of {} jobs failed (see {})", results.results.len(), a.out.output.join("results.csv").display()).into());
    }
    Ok(())
}

fn run_gradcheck(cli: &Cli, a: &GradcheckArgs) -> Result {
    use vkinverse::gradcheck::{Verdict, Z_FAIL};
    if a.spp == 0 {
        return Err("--spp must be at least 1".into());
    }
    if a.primal_spp == Some(0) {
        return Err("--primal-spp must be at least 1".into());
    }
    if a.max_rounds == 0 {
        return Err("--max-rounds must be at least 1".into());
    }
    let mut scene = load_scene(cli, &a.scene, &a.scene_flags)?;
    if scene.optimise.params.is_empty() {
        return Err(format!("{}: no [[optimise.params]] to check", scene.path.display()).into());
    }
    a.start.apply(&mut scene)?;
    let device = device(cli)?;
    let opts = vkinverse::gradcheck::Options {
        spp: a.spp,
        primal_spp: a.primal_spp.unwrap_or(a.spp),
        rounds: a.rounds.map(|r| r.max(2)),
        max_rounds: a.max_rounds,
        ..Default::default()
    };
    let report = vkinverse::gradcheck::gradcheck(&device, &scene, &opts)?;
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&report)?)?;
    } else {
        out(format_args!("{}", report.table()))?;
    }
    match report.verdict {
        Verdict::Pass => Ok(()),
        Verdict::Fail => {
            let failed = report.rows.iter().filter(|r| r.verdict == Verdict::Fail).count();
            let p = report.combined.map_or("n/a".to_string(), |h| format!("{:.2e}", h.p_value));
            Err(format!("gradcheck failed: {failed} of {} elements beyond {Z_FAIL} standard errors, combined p = {p}", report.rows.len()).into())
        }
        Verdict::Inconclusive => Err(format!(
            "gradcheck inconclusive: too noisy to see a 10 % bias in {} rounds; about {} rounds at {} spp would",
            report.rounds, report.rounds_needed, a.spp
        )
        .into()),
    }
}

fn run_replay(cli: &Cli, a: &ReplayArgs) -> Result {
    use vkinverse::replay;
    let spec: vkinverse::Spec = a.optimiser.parse().map_err(|e| format!("--optimiser {}: {e}", a.optimiser))?;
    let range = match &a.range {
        Some(r) => r.parse().map_err(|e| format!("--range {r}: {e}"))?,
        None => replay::Range::UNBOUNDED,
    };
    if !(a.lr.is_finite() && a.lr > 0.0) {
        return Err(format!("--lr {}: must be positive and finite", a.lr).into());
    }
    let halves = match &a.halves {
        Some(list) => {
            let (gh, fh) = list.split_once(',').ok_or_else(|| format!("--halves {list}: expected GH.npy,FH.npy"))?;
            Some((PathBuf::from(gh), PathBuf::from(fh)))
        }
        None => None,
    };
    let files = replay::Files {
        grads: &a.grads,
        fd_grads: a.fd_grads.as_deref(),
        init: a.init.as_deref(),
        halves: halves.as_ref().map(|(g, f)| (g.as_path(), f.as_path())),
    };
    let device = device(cli)?;
    let result = replay::replay(&device, &spec, &files, range, a.lr)?;
    vkinverse::npy::write_rows(&a.output, &result.trajectory)?;
    if let Some(path) = &a.diagnostics {
        result.write_diagnostics(path)?;
    }
    if !cli.quiet {
        eprintln!("replayed {} iterations of {} parameters -> {}", result.iterations, result.parameters, a.output.display());
    }
    if result.nonfinite > 0 {
        warn(cli.quiet, &format!("{} non-finite gradient elements were skipped (theta left unchanged there)", result.nonfinite));
    }
    Ok(())
}

/// `bench`'s default `--elements` without a scene: buffers far larger than the caches.
const BUFFER_BENCH_ELEMENTS: u64 = 16 << 20;
/// With a scene, whose own optimiser passes the iteration table times: a synthetic θ of
/// 16M parameters took about 13 s a round on lavapipe, nine tenths of the default scene
/// bench's time; 1M still fills every workgroup of a GPU many times over.
const SCENE_BENCH_ELEMENTS: u64 = 1 << 20;

/// `bench SCENE`'s default `--warm-up` on a GPU: NVIDIA's H100 and H200 idled at a few
/// hundred MHz, and benches that started cold ran up to 6x slower (experiments/gpu-runs.md).
const GPU_WARM_UP_SECONDS: f64 = 2.0;

fn run_bench(cli: &Cli, a: &BenchArgs) -> Result {
    if a.media {
        let device = device(cli)?;
        let options = vkinverse::bench::MediaOptions {
            grids: a.media_grids.clone(),
            films: a.media_films.clone(),
            iterations: a.iterations,
            optimiser_elements: a.elements,
            warm_up: Duration::from_secs_f64(bench_warm_up(a.warm_up, &device)?),
        };
        let result = vkinverse::bench::media_bench(&device, &options)?;
        return print_result(a.json, &result, || result.table());
    }
    let Some(path) = &a.scene else {
        let elements = a.elements.unwrap_or(BUFFER_BENCH_ELEMENTS);
        // Buffers are copied as vec4s, so fewer than 4 elements leave nothing to measure.
        if elements < 4 {
            return Err(format!("--elements {elements}: must be at least 4").into());
        }
        let result = vkinverse::bench::buffer_bench(&device(cli)?, elements, a.iterations)?;
        return print_result(a.json, &result, || result.table());
    };
    let scene = load_scene(cli, path, &a.scene_flags)?;
    let device = device(cli)?;
    if a.bvh_layouts {
        let result = vkinverse::bench::layout_bench(&device, &scene, a.iterations)?;
        return print_result(a.json, &result, || result.table());
    }
    let warm_up = bench_warm_up(a.warm_up, &device)?;
    let result = vkinverse::bench::scene_bench(&device, &scene, a.iterations, a.elements.unwrap_or(SCENE_BENCH_ELEMENTS), Duration::from_secs_f64(warm_up))?;
    print_result(a.json, &result, || result.table())
}

/// `--warm-up`, checked, or its default for `device`.
fn bench_warm_up(given: Option<f64>, device: &vkinverse::Device) -> std::result::Result<f64, String> {
    match given {
        Some(s) if !(0.0..=3600.0).contains(&s) => Err(format!("--warm-up {s}: must be between 0 and 3600 seconds")),
        Some(s) => Ok(s),
        // A CPU device runs at its clock from the first round; a GPU's idles low.
        None if device.info().device_type == "CPU" => Ok(0.0),
        None => Ok(GPU_WARM_UP_SECONDS),
    }
}

fn run(cli: &Cli) -> Result {
    match &cli.command {
        Command::Info { json } => {
            let device = device(cli)?;
            let text = if *json { format!("{}\n", device.info_json()) } else { device.info_text() };
            out(format_args!("{text}"))?;
            Ok(())
        }
        Command::Render(a) => run_render(cli, a),
        Command::Optimise(a) => run_optimise(cli, a),
        Command::Compare(a) => run_compare(cli, a),
        Command::Batch(a) => run_batch(cli, a),
        Command::Gradcheck(a) => run_gradcheck(cli, a),
        Command::Replay(a) => run_replay(cli, a),
        Command::Bench(a) => run_bench(cli, a),
    }
}

/// A usage error as one line: clap's first line, with the arguments it lists below it (a
/// missing required argument's name) joined on.
fn usage_error(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let mut lines = text.lines().map(str::trim).take_while(|l| !l.is_empty() && !l.starts_with("Usage:"));
    let first = lines.next().unwrap_or_default();
    let first = first.strip_prefix("error: ").unwrap_or(first);
    let listed: Vec<&str> = lines.collect();
    if listed.is_empty() {
        first.to_string()
    } else {
        format!("{first} {}", listed.join(", "))
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // Help and version, and the help shown for a bare `vkinverse`, as clap prints them.
        Err(e) if !e.use_stderr() || e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => e.exit(),
        // Usage errors get the same one-line form as every other error; clap's usual exit
        // status for them (2) is kept.
        Err(e) => {
            eprintln!("vkinverse: error: {} (see --help)", usage_error(&e));
            return ExitCode::from(2);
        }
    };
    // A panic is a bug of vkinverse's (or of a crate it uses) on this input: one line that
    // names the command, not a backtrace (RUST_BACKTRACE=1 shows one too).
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message =
            info.payload().downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| info.payload().downcast_ref::<String>().cloned()).unwrap_or_default();
        let at = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        let command: Vec<String> = std::env::args().skip(1).collect();
        eprintln!(
            "vkinverse: internal error: {}{at} (while running `vkinverse {}`); please report it with its input",
            message.replace('\n', "; "),
            command.join(" ")
        );
        if std::env::var_os("RUST_BACKTRACE").is_some() {
            default_hook(info);
        }
    }));
    let outcome = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(&cli))) {
        Ok(outcome) => outcome,
        // The hook said what happened; 70 is sysexits' EX_SOFTWARE.
        Err(_) => return ExitCode::from(70),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        // A Ctrl-C or SIGTERM (vkinverse::interrupt): the shell's status for the signal,
        // as a second signal's.
        Err(e) if matches!(e.downcast_ref(), Some(vkinverse::Error::Interrupted(_))) => {
            eprintln!("vkinverse: {e}");
            ExitCode::from(interrupt::exit_status())
        }
        Err(e) => {
            eprintln!("vkinverse: error: {}", vkinverse::error::one_line(e.as_ref()));
            ExitCode::FAILURE
        }
    }
}
