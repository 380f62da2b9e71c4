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
    /// Measure GPU passes with timestamps. Without a scene: the buffer kernels' bandwidth.
    Bench {
        /// Scene to benchmark (the buffer kernels are measured when absent).
        scene: Option<std::path::PathBuf>,
        /// Repetitions of each kernel (the median is reported).
        #[arg(long, default_value_t = 9)]
        iterations: u32,
        /// Elements (f32) per buffer for the buffer kernels.
        #[arg(long, default_value_t = 16 << 20)]
        elements: u64,
        #[arg(long)]
        json: bool,
    },
}

fn context(cli: &Cli) -> Result<std::sync::Arc<Context>, vkinverse::gpu::GpuError> {
    Context::new(&ContextOptions { device: cli.device.clone(), validation: cli.validation, timeout: None })
}

fn run(cli: &Cli) -> Result<(), Box<dyn std::error::Error>> {
    match &cli.command {
        Command::Info { json } => {
            let ctx = context(cli)?;
            if *json {
                println!("{}", vkinverse::report::info_json(&ctx));
            } else {
                print!("{}", vkinverse::report::info_text(&ctx));
            }
        }
        Command::Bench { scene, iterations, elements, json } => {
            if scene.is_some() {
                return Err("scene benchmarks need the path tracer, which this build does not have yet".into());
            }
            let ctx = context(cli)?;
            let result = vkinverse::bench::buffer_bench(&ctx, *elements, *iterations)?;
            if *json {
                println!("{}", serde_json::to_string_pretty(&result)?);
            } else {
                print!("{}", result.table());
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vkinverse: error: {e}");
            ExitCode::FAILURE
        }
    }
}
