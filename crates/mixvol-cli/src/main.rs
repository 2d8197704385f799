//! `mixvol`, the command-line tool: renders volumes, benchmarks the passes, shows a brick
//! junction, and writes the experiment reports. Each subcommand is a module; the flags are in
//! `args`.

mod args;
mod bench;
mod camera_path;
mod compare;
mod convert;
mod convert_levels;
mod files;
mod frame_log;
mod input;
mod junction;
mod level_scene;
mod levels;
mod logging;
mod parse;
mod path_bench;
mod render;
mod reports;
mod soak;
mod stats;
mod stream;

use args::{BenchArgs, ConvertArgs, JunctionArgs, KrausArgs, RenderArgs, ReportArgs};
use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Mixed-resolution volume ray-caster (Vulkan).
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    /// Log the library's progress (info level) to stderr; RUST_LOG sets other levels.
    #[arg(long, global = true)]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a volume to a PNG and print the frame timing.
    Render(RenderArgs),
    /// Render a close-up of a hi-res / low-res brick junction, discontinuous (left) and smooth
    /// (right), side by side into one PNG.
    Junction(JunctionArgs),
    /// Render a scene for N frames and report min / median / max GPU time per pass (upload,
    /// fixup, ray-cast) and CPU frame time, as a table and as JSON; with --orbit / --dolly /
    /// --path, --gpu-budget-mb or a brick store: camera-driven residency along the path, smooth
    /// and discontinuous side by side (frame times, upload+fixup, planner time, frames to
    /// converge); with --soak N: N frames of camera motion under validation, watching for
    /// validation messages, leaks and memory growth.
    Bench(BenchArgs),
    /// The accuracy-versus-time report of the default scene (Markdown, CSV and a PNG chart).
    Report(ReportArgs),
    /// Kraus & Bürger's sampling experiments on the CPU: opacity- vs extinction-based deviation
    /// from the exact integral (docs/report/kraus.md, .csv and a PNG chart).
    Kraus(KrausArgs),
    /// Convert a volume (any supported file, an OME-Zarr level, raw data) into a brick store,
    /// reading it in slabs under a RAM budget, with a progress bar and a summary.
    Convert(ConvertArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    logging::install(cli.verbose);
    let result = match &cli.command {
        Command::Render(args) => render::render(args),
        Command::Junction(args) => junction::junction(args),
        Command::Bench(args) => bench::bench(args),
        Command::Report(args) => reports::accuracy(args),
        Command::Kraus(args) => reports::kraus(args),
        Command::Convert(args) => convert::convert(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
