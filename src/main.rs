//! The vkinverse command line: parse, call the library, print.

use clap::{Parser, Subcommand};
use std::process::ExitCode;
use vkinverse::gpu::{Context, ContextOptions};

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
    /// Render one sensor of a scene to EXR (linear) or PNG (tone-mapped sRGB).
    Render {
        scene: std::path::PathBuf,
        #[arg(long, default_value_t = 64)]
        spp: u32,
        #[arg(long, default_value_t = 0)]
        seed: u32,
        #[arg(long, default_value_t = 0)]
        sensor: u32,
        #[arg(short = 'o', long = "output")]
        output: std::path::PathBuf,
    },
    /// Recover the scene's optimised parameters from its target images.
    Optimise {
        scene: std::path::PathBuf,
        /// meta or adam (default: the scene's `[optimise] optimiser`)
        #[arg(long)]
        optimiser: Option<String>,
        #[command(flatten)]
        run: RunFlags,
        /// Write a checkpoint every N iterations.
        #[arg(long)]
        checkpoint_every: Option<u32>,
        /// Continue the run in OUTDIR from its checkpoint.
        #[arg(long)]
        resume: bool,
        /// Meta: trace each parameter state separately for the finite-difference sample
        /// instead of the fused single trace (for comparison).
        #[arg(long)]
        fd_two_trace: bool,
        #[arg(short = 'o', long = "output")]
        output: std::path::PathBuf,
    },
    /// Run several optimisers on one scene at equal cost and seed; plot and tabulate their
    /// error against run time.
    #[command(after_help = COMPARE_HELP)]
    Compare {
        scene: std::path::PathBuf,
        /// Comma-separated optimiser specs NAME[@KEY=VALUE]..., e.g.
        /// `meta,adam,adam@beta1=0.5@beta2=0.99`; the first is the baseline.
        #[arg(long, allow_hyphen_values = true)]
        optimisers: String,
        #[command(flatten)]
        run: RunFlags,
        /// Print compare.json instead of the table.
        #[arg(long)]
        json: bool,
        /// Output directory.
        #[arg(short = 'o', long = "output")]
        output: std::path::PathBuf,
    },
    /// Run a list of optimisation jobs (or one shard of it) on one device, with one results
    /// table; or merge the tables of shards.
    #[command(after_help = BATCH_HELP)]
    Batch {
        /// Job file (TOML, format below).
        jobs: Option<std::path::PathBuf>,
        /// Run shard I of N: jobs I, I+N, I+2N, ... (jobs and shards count from 1).
        #[arg(long, value_name = "I/N", allow_hyphen_values = true)]
        shard: Option<String>,
        /// Join the results tables in these output directories (of shards) into one.
        #[arg(long, value_name = "OUTDIR", num_args = 1.., conflicts_with_all = ["jobs", "shard"])]
        merge: Vec<std::path::PathBuf>,
        /// Print results.json instead of the table.
        #[arg(long)]
        json: bool,
        /// Output directory (of the batch, the shard or the merged table).
        #[arg(short = 'o', long = "output")]
        output: std::path::PathBuf,
    },
    /// Check the adjoint gradient against finite differences of the loss. Exits non-zero
    /// unless the verdict is "pass" (a failed or an inconclusive check).
    Gradcheck {
        scene: std::path::PathBuf,
        #[arg(long, default_value_t = 16)]
        spp: u32,
        /// Rounds (independent estimates of each side); by default sized from a pilot so
        /// that a 10 % bias of a typical gradient would be detected, up to --max-rounds.
        #[arg(long)]
        rounds: Option<u32>,
        #[arg(long, default_value_t = 200)]
        max_rounds: u32,
        #[arg(long)]
        json: bool,
    },
    /// Run the GPU optimiser passes on gradient streams from .npy files.
    Replay {
        /// meta or adam
        #[arg(long)]
        optimiser: String,
        #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
        lr: f64,
        /// Parameter bounds, e.g. `--range 0,1` (unbounded by default).
        #[arg(long, allow_hyphen_values = true)]
        range: Option<String>,
        /// Start values (shape [n]); zeros by default.
        #[arg(long)]
        init: Option<std::path::PathBuf>,
        /// Proportional gradients, float32 [iterations, n].
        grads: std::path::PathBuf,
        /// Finite-difference samples, float32 [iterations, n] (meta only).
        fd_grads: Option<std::path::PathBuf>,
        #[arg(short = 'o', long = "output")]
        output: std::path::PathBuf,
    },
    /// Measure GPU passes with timestamps: a scene's iteration pass by pass, or without a
    /// scene the buffer kernels' bandwidth; both time the optimiser passes on a synthetic θ.
    Bench {
        /// Scene to benchmark (the buffer kernels are measured when absent).
        scene: Option<std::path::PathBuf>,
        /// Repetitions of each kernel or iteration (the median is reported).
        #[arg(long, default_value_t = 9)]
        iterations: u32,
        /// Elements (f32) per buffer for the buffer kernels, and parameters of the synthetic
        /// θ of the optimiser passes.
        #[arg(long, default_value_t = 16 << 20)]
        elements: u64,
        /// With a scene: compare the BVH layouts (binary, wide) instead, alternating them
        /// over `--iterations` rounds.
        #[arg(long)]
        bvh_layouts: bool,
        #[arg(long)]
        json: bool,
    },
}

const COMPARE_HELP: &str = "\
Optimiser specs: NAME[@KEY=VALUE]... with NAME adam (keys beta1, beta2, eps) or meta (keys
decay_f, decay_d, eps); unset keys keep their defaults. `@` separates keys so that specs
hold no comma.

Every run gets the same settings and seed: the same --time-budget (wall time, set-up
excluded) when given, else the same --iterations (the scene's by default). Outputs in OUTDIR:
  <label>/            each run's optimise outputs (log.csv, summary.json, ...)
  error_vs_time.png   all runs, log-scale error against wall time
  curves.csv          label,time_s,error: the points of the plot
  compare.csv, .json  per run: final error; time_to_2x, time_to_1x, time_to_0.5x: the wall
                      time at which its error first reached 2, 1 and 0.5 times the first
                      run's final error; speedup: the first run's time to its final error
                      over this run's (empty when never reached)
The error is the parameter RMSE when the reference is known, else the image loss.";

const BATCH_HELP: &str = "\
Job file (TOML); paths are relative to it:
  iterations = 100                 # shared settings (optional): iterations, time_budget,
  lr = 0.05                        #   spp, fd_spp, primal_spp, lr, seed, checkpoint_every
  scenes = [\"cornell/scene.toml\"]  # product: one job per scene x optimiser x seed x spp
  optimisers = [\"meta\", \"adam\"]    # optional axes; the scene's value when absent
  seeds = [0, 1]
  spp = [1, 4]                     # a list is an axis; a number is a shared setting
  [[jobs]]                         # single jobs after the product, in file order
  scene = \"spiral/scene.toml\"    # with optimiser, seed, spp and any shared setting
  optimiser = \"adam@beta1=0.5\"
Jobs are numbered from 1 (scenes vary slowest, spp fastest, then [[jobs]]). --shard I/N
runs jobs I, I+N, I+2N, ... (1 <= I <= N; with a 0-based scheduler index, pass index+1).
Each job writes OUTDIR/job-<k>-<label>/; OUTDIR/results.csv and results.json hold one row
per job (job, label, scene, optimiser, seed, spp, status ok|failed, message, iterations,
time_s, final_loss, final_error, dir); per scene, error_vs_time-<scene>.png plots every
finished job's error against time and curves-<scene>.csv (label,time_s,error) holds its
points. A failed job does not stop the batch; the exit status
is non-zero if any failed. --merge OUTDIR... -o OUTDIR joins shards' tables, sorted by job,
refusing a job found twice and warning about jobs found nowhere.";

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

/// `Err` naming `flag` unless `value` is finite and positive.
fn positive(flag: &str, value: f64) -> Result<(), String> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(format!("{flag} {value}: must be positive and finite"))
    }
}

/// `Err` naming `flag` when a sample count is 0.
fn at_least_one(flag: &str, value: Option<u32>) -> Result<(), String> {
    match value {
        Some(0) => Err(format!("{flag} must be at least 1")),
        _ => Ok(()),
    }
}

/// Run settings shared by `optimise` and `compare`; each replaces the scene's
/// `[optimise]` value (see `vkinverse::overrides`).
#[derive(clap::Args, Debug)]
struct RunFlags {
    /// Iterations (with --time-budget: at most this many).
    #[arg(long)]
    iterations: Option<u32>,
    /// Stop after this many seconds of optimisation (instead of, or on top of, --iterations).
    #[arg(long, allow_negative_numbers = true)]
    time_budget: Option<f64>,
    #[arg(long)]
    spp: Option<u32>,
    #[arg(long)]
    fd_spp: Option<u32>,
    #[arg(long)]
    primal_spp: Option<u32>,
    /// Learning rate of every parameter (replaces the scene's per-parameter rates).
    #[arg(long, allow_negative_numbers = true)]
    lr: Option<f32>,
    #[arg(long)]
    seed: Option<u32>,
}

impl RunFlags {
    /// The flags as overrides, after checking their ranges (named as flags).
    fn overrides(&self, checkpoint_every: Option<u32>) -> Result<vkinverse::overrides::Overrides, String> {
        if let Some(x) = self.lr {
            positive("--lr", x as f64)?;
        }
        if let Some(t) = self.time_budget {
            positive("--time-budget", t)?;
        }
        at_least_one("--spp", self.spp)?;
        at_least_one("--fd-spp", self.fd_spp)?;
        at_least_one("--primal-spp", self.primal_spp)?;
        Ok(vkinverse::overrides::Overrides {
            iterations: self.iterations,
            time_budget: self.time_budget,
            spp: self.spp,
            fd_spp: self.fd_spp,
            primal_spp: self.primal_spp,
            lr: self.lr,
            seed: self.seed,
            checkpoint_every,
        })
    }
}

fn context(cli: &Cli) -> Result<std::sync::Arc<Context>, vkinverse::gpu::GpuError> {
    Context::new(&ContextOptions { device: cli.device.clone(), validation: cli.validation, timeout: None })
}

/// A progress bar on stderr, hidden with --quiet or when stderr is not a terminal.
fn progress_bar(quiet: bool, len: u64, unit: &str) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    let style = indicatif::ProgressStyle::with_template(&format!("{{bar:40}} {{pos}}/{{len}} {unit} ({{elapsed}}, eta {{eta}}) {{msg}}"))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar
}

fn run_optimise(
    cli: &Cli,
    scene: &vkinverse::scene::Scene,
    st: &vkinverse::optimise::Settings,
    output: &std::path::Path,
    resume: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    let ctx = context(cli)?;
    let total = if st.iterations > 0 { st.iterations as u64 } else { 0 };
    let bar = progress_bar(cli.quiet, total, "iterations");
    let target_bar = progress_bar(cli.quiet, 0, "target samples");
    let summary = vkinverse::optimise::optimise(
        &ctx,
        scene,
        st,
        output,
        resume,
        |p| {
            bar.set_position(p.iteration as u64);
            let err = p.param_error.map(|e| format!(" param RMSE {e:.3e}")).unwrap_or_default();
            bar.set_message(format!("loss {:.3e}{err}", p.loss));
        },
        |_, done, total| {
            target_bar.set_length(total as u64);
            target_bar.set_position(done as u64);
        },
    )?;
    target_bar.finish_and_clear();
    bar.finish_and_clear();
    if !cli.quiet {
        let err = |e: Option<f64>| e.map(|v| format!("{v:.4e}")).unwrap_or_else(|| "n/a".into());
        outln!(
            "{}: {} iterations of {} in {:.2} s (GPU {:.2} s); loss {:.4e}; parameter RMSE {} -> {}",
            summary.scene,
            summary.iterations,
            summary.optimiser,
            summary.total_time_s,
            summary.total_gpu_time_s,
            summary.final_loss,
            err(summary.initial_param_error),
            err(summary.final_param_error)
        )?;
        outln!("outputs in {}: log.csv summary.json params/ final.exr error_vs_time.png checkpoint/", output.display())?;
    }
    Ok(())
}

fn run(cli: &Cli) -> Result<(), Box<dyn std::error::Error>> {
    match &cli.command {
        Command::Info { json } => {
            let ctx = context(cli)?;
            if *json {
                outln!("{}", vkinverse::report::info_json(&ctx))?;
            } else {
                out(format_args!("{}", vkinverse::report::info_text(&ctx)))?;
            }
        }
        Command::Render { scene, spp, seed, sensor, output } => {
            let ext = output.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            if !matches!(ext.as_deref(), Some("exr" | "png")) {
                return Err(format!("{}: output must end in .exr or .png", output.display()).into());
            }
            if *spp == 0 {
                return Err("--spp must be at least 1".into());
            }
            let scene = vkinverse::scene::Scene::load(scene)?;
            if *sensor as usize >= scene.sensors.len() {
                return Err(format!("--sensor {sensor}: the scene has {} sensor(s)", scene.sensors.len()).into());
            }
            let ctx = context(cli)?;
            let start = std::time::Instant::now();
            let renderer = vkinverse::render::Renderer::new(vkinverse::render::GpuScene::new(&ctx, &scene)?)?;
            // The scene as written: optimised parameters at their reference values.
            renderer.scene.set_theta(renderer.scene.layout.reference())?;
            let bar = progress_bar(cli.quiet, *spp as u64, "samples");
            let image = renderer.render(*sensor, *spp, *seed, |done, _| bar.set_position(done as u64))?;
            bar.finish_and_clear();
            if ext.as_deref() == Some("png") {
                vkinverse::image::write_png(output, &image)?;
            } else {
                vkinverse::image::write_exr(output, &image)?;
            }
            if !cli.quiet {
                eprintln!(
                    "rendered {}x{} at {spp} spp in {:.2} s -> {}",
                    image.width,
                    image.height,
                    start.elapsed().as_secs_f64(),
                    output.display()
                );
            }
        }
        Command::Optimise { scene, optimiser, run, checkpoint_every, resume, fd_two_trace, output } => {
            // Flags first: a typo on the command line is reported before the scene is read.
            let optimiser: Option<vkinverse::optim::Optimiser> =
                optimiser.as_deref().map(|o| o.parse().map_err(|e| format!("--optimiser {o}: {e}"))).transpose()?;
            let overrides = run.overrides(*checkpoint_every)?;
            let scene = vkinverse::scene::Scene::load(scene)?;
            let (scene, mut st) = overrides.apply(&scene, optimiser);
            st.fd_two_trace = *fd_two_trace;
            run_optimise(cli, &scene, &st, output, *resume)?;
        }
        Command::Compare { scene, optimisers, run, json, output } => {
            // Flags first: a typo on the command line is reported before the scene is read.
            let specs = vkinverse::optim::spec::parse_list(optimisers).map_err(|e| format!("--optimisers: {e}"))?;
            if run.iterations == Some(0) {
                return Err("--iterations must be at least 1".into());
            }
            let overrides = run.overrides(None)?;
            let scene = vkinverse::scene::Scene::load(scene)?;
            let ctx = context(cli)?;
            let bar = std::cell::RefCell::new(indicatif::ProgressBar::hidden());
            let comparison = vkinverse::compare::compare(
                &ctx,
                &scene,
                &overrides,
                &specs,
                output,
                |spec, st| {
                    bar.borrow().finish_and_clear();
                    let b = progress_bar(cli.quiet, st.iterations as u64, "iterations");
                    b.set_message(spec.label.clone());
                    *bar.borrow_mut() = b;
                },
                |spec, p| {
                    let b = bar.borrow();
                    b.set_position(p.iteration as u64);
                    let err = p.param_error.map(|e| format!(" param RMSE {e:.3e}")).unwrap_or_default();
                    b.set_message(format!("{}: loss {:.3e}{err}", spec.label, p.loss));
                },
            )?;
            bar.borrow().finish_and_clear();
            if *json {
                outln!("{}", serde_json::to_string_pretty(&comparison)?)?;
            } else {
                out(format_args!("{}", comparison.table()))?;
                if !cli.quiet {
                    outln!("outputs in {}: error_vs_time.png curves.csv compare.csv compare.json and one directory per optimiser", output.display())?;
                }
            }
        }
        Command::Batch { jobs, shard, merge, json, output } => {
            use vkinverse::batch;
            let print = |results: &batch::Results| -> std::io::Result<()> {
                if *json {
                    outln!("{}", serde_json::to_string_pretty(results).unwrap_or_default())
                } else {
                    out(format_args!("{}", results.table()))
                }
            };
            if !merge.is_empty() {
                let (merged, missing) = batch::merge(merge, output)?;
                if !missing.is_empty() {
                    let list: Vec<String> = missing.iter().map(usize::to_string).collect();
                    eprintln!("warning: job(s) {} of {} are in none of the tables", list.join(", "), merged.total_jobs);
                }
                print(&merged)?;
                return Ok(());
            }
            let shard: Option<batch::Shard> = shard.as_deref().map(|s| s.parse().map_err(|e| format!("--shard {e}"))).transpose()?;
            let Some(jobs_file) = jobs else {
                return Err("give a job file, or --merge with the shards' output directories".into());
            };
            let all = batch::load_jobs(jobs_file)?;
            let mine: Vec<batch::Job> = all.iter().filter(|j| shard.iter().all(|s| s.has(j.index))).cloned().collect();
            // One context for every job: device set-up is paid once per batch.
            let ctx = context(cli)?;
            let bar = std::cell::RefCell::new(indicatif::ProgressBar::hidden());
            let results = batch::run(
                &ctx,
                jobs_file,
                all.len(),
                shard,
                &mine,
                output,
                |job| {
                    let total = job.overrides.iterations.unwrap_or(0) as u64;
                    *bar.borrow_mut() = progress_bar(cli.quiet, total, "iterations");
                    bar.borrow().set_message(format!("job {} {}", job.index, job.label));
                },
                |job, p| {
                    let b = bar.borrow();
                    b.set_position(p.iteration as u64);
                    b.set_message(format!("job {} {}: loss {:.3e}", job.index, job.label, p.loss));
                },
                |row| {
                    bar.borrow().finish_and_clear();
                    if !cli.quiet {
                        match row.status {
                            batch::Status::Ok => eprintln!("job {} {}: ok", row.job, row.label),
                            batch::Status::Failed => eprintln!("job {} {}: failed: {}", row.job, row.label, row.message),
                        }
                    }
                },
            )?;
            print(&results)?;
            let failed = results.failed();
            if failed > 0 {
                return Err(format!("{failed} of {} jobs failed (see {})", results.results.len(), output.join("results.csv").display()).into());
            }
        }
        Command::Gradcheck { scene, spp, rounds, max_rounds, json } => {
            at_least_one("--spp", Some(*spp))?;
            at_least_one("--max-rounds", Some(*max_rounds))?;
            let scene = vkinverse::scene::Scene::load(scene)?;
            if scene.optimise.params.is_empty() {
                return Err(format!("{}: no [[optimise.params]] to check", scene.path.display()).into());
            }
            let ctx = context(cli)?;
            let opts = vkinverse::gradcheck::Options {
                spp: *spp,
                primal_spp: *spp,
                rounds: rounds.map(|r| r.max(2)),
                max_rounds: *max_rounds,
                ..Default::default()
            };
            let report = vkinverse::gradcheck::gradcheck(&ctx, &scene, &opts)?;
            if *json {
                outln!("{}", serde_json::to_string_pretty(&report)?)?;
            } else {
                out(format_args!("{}", report.table()))?;
            }
            use vkinverse::gradcheck::Verdict;
            match report.verdict {
                Verdict::Pass => {}
                Verdict::Fail => {
                    let failed = report.rows.iter().filter(|r| r.verdict == Verdict::Fail).count();
                    return Err(format!("gradcheck failed: {failed} of {} elements beyond {} standard errors, combined p = {}", report.rows.len(), vkinverse::gradcheck::Z_FAIL, report.combined.map_or("n/a".to_string(), |h| format!("{:.2e}", h.p_value))).into());
                }
                Verdict::Inconclusive => {
                    return Err(format!("gradcheck inconclusive: too noisy to detect a 10 % bias in {} rounds; about {} rounds at {spp} spp would", report.rounds, report.rounds_needed).into());
                }
            }
        }
        Command::Replay { optimiser, lr, range, init, grads, fd_grads, output } => {
            use vkinverse::{npy, optim};
            let opt: optim::Optimiser = optimiser.parse().map_err(|e| format!("--optimiser {optimiser}: {e}"))?;
            let range = match range {
                Some(r) => r.parse().map_err(|e| format!("--range {r}: {e}"))?,
                None => optim::Range::UNBOUNDED,
            };
            positive("--lr", *lr)?;
            let g = npy::read(grads)?;
            if g.shape.len() != 2 {
                return Err(format!("{}: expected shape [iterations, n], got {:?}", grads.display(), g.shape).into());
            }
            let n = g.shape[1];
            let fd = match (fd_grads, opt.needs_fd()) {
                (Some(p), _) => {
                    let a = npy::read(p)?;
                    if a.shape != g.shape {
                        return Err(format!("{}: shape {:?} differs from the gradients' {:?}", p.display(), a.shape, g.shape).into());
                    }
                    Some(a.rows())
                }
                (None, true) => return Err("--optimiser meta needs FD_GRADS.npy (finite-difference samples) after GRADS.npy".into()),
                (None, false) => None,
            };
            let init = match init {
                Some(p) => {
                    let a = npy::read(p)?;
                    if a.data.len() != n {
                        return Err(format!("{}: {} values, the gradients have {n} per row", p.display(), a.data.len()).into());
                    }
                    a.data
                }
                None => vec![0.0; n],
            };
            let ctx = context(cli)?;
            let (trajectory, skipped) = optim::gpu::replay_gpu(&ctx, &opt, &g.rows(), fd.as_deref(), &init, range, *lr)?;
            npy::write_rows(output, &trajectory)?;
            if !cli.quiet {
                eprintln!("replayed {} iterations of {n} parameters -> {}", g.shape[0], output.display());
            }
            if skipped > 0 {
                eprintln!("warning: {skipped} non-finite gradient elements were skipped (theta left unchanged there)");
            }
        }
        Command::Bench { scene, iterations, elements, bvh_layouts, json } => {
            if let Some(path) = scene {
                let scene = vkinverse::scene::Scene::load(path)?;
                let ctx = context(cli)?;
                if *bvh_layouts {
                    let result = vkinverse::bench::layout_bench(&ctx, &scene, *iterations)?;
                    if *json {
                        println!("{}", serde_json::to_string_pretty(&result)?);
                    } else {
                        print!("{}", result.table());
                    }
                    return Ok(());
                }
                let result = vkinverse::bench::scene_bench(&ctx, &scene, *iterations, *elements)?;
                if *json {
                    println!("{}", serde_json::to_string_pretty(&result)?);
                } else {
                    print!("{}", result.table());
                }
                return Ok(());
            }
            // Buffers are copied as vec4s, so fewer than 4 elements leave nothing to measure.
            if *elements < 4 {
                return Err(format!("--elements {elements}: must be at least 4").into());
            }
            let ctx = context(cli)?;
            let result = vkinverse::bench::buffer_bench(&ctx, *elements, *iterations)?;
            if *json {
                outln!("{}", serde_json::to_string_pretty(&result)?)?;
            } else {
                out(format_args!("{}", result.table()))?;
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // Help and version, and the help shown for a bare `vkinverse`, as clap prints them.
        Err(e) if !e.use_stderr() || e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => e.exit(),
        // Usage errors get the same one-line form as every other error; clap's usual exit
        // status for them (2) is kept.
        Err(e) => {
            let text = e.render().to_string();
            let first = text.lines().next().unwrap_or_default();
            eprintln!("vkinverse: error: {} (see --help)", first.strip_prefix("error: ").unwrap_or(first));
            return ExitCode::from(2);
        }
    };
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vkinverse: error: {}", vkinverse::error::one_line(e.as_ref()));
            ExitCode::FAILURE
        }
    }
}
