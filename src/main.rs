//! `mixvol` command-line interface.

use clap::{Args, Parser, Subcommand, ValueEnum};
use glam::{UVec3, Vec3};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{Renderer, TargetFormat};
use mixvol::scene::{Camera, Projection, RenderSettings};
use mixvol::volume::{load_raw, RawDescriptor, ScalarType, SyntheticField, Volume};
use mixvol::{reference, Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;

/// Mixed-resolution volume ray-caster (Vulkan).
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a volume to a PNG and print the frame timing.
    Render(RenderArgs),
}

#[derive(ValueEnum, Copy, Clone, Debug)]
enum ProjectionArg {
    Perspective,
    Orthographic,
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// Volume to render: a synthetic field (`ml` = Marschner-Lobb, `sphere`, `wall`) or a path to a
    /// headerless raw file (then --dims and --scalar describe it).
    #[arg(long, default_value = "ml")]
    volume: String,
    /// Dimensions x,y,z: of the synthetic field, or of the raw file.
    #[arg(long, default_value = "128,128,128", value_parser = parse_uvec3)]
    dims: UVec3,
    /// Scalar type: u8, u16 or f32 (synthetic fields are generated in it; raw files hold it).
    #[arg(long, default_value = "u8", value_parser = parse_scalar)]
    scalar: ScalarType,
    /// Voxel spacing x,y,z of a raw file (anisotropic spacing renders with the right aspect).
    #[arg(long, default_value = "1,1,1", value_parser = parse_vec3)]
    spacing: Vec3,
    /// Bytes to skip at the start of a raw file.
    #[arg(long, default_value_t = 0)]
    header_bytes: u64,
    /// The raw file's multi-byte values are big-endian.
    #[arg(long)]
    big_endian: bool,
    /// Transfer-function preset: grey, fire, bands, constant.
    #[arg(long, default_value = "fire", value_parser = parse_tf)]
    tf: TfPreset,
    /// Camera projection.
    #[arg(long, value_enum, default_value_t = ProjectionArg::Perspective)]
    projection: ProjectionArg,
    /// Eye position x,y,z in world units (the volume box is centred at the origin, longest side 1).
    #[arg(long, default_value = "1.0,1.3,1.4", value_parser = parse_vec3)]
    eye: Vec3,
    /// Point looked at, x,y,z.
    #[arg(long, default_value = "0,0,0", value_parser = parse_vec3)]
    target: Vec3,
    /// Vertical field of view in degrees (perspective).
    #[arg(long, default_value_t = 35.0)]
    fov: f32,
    /// Visible height in world units (orthographic).
    #[arg(long, default_value_t = 1.6)]
    ortho_height: f32,
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    height: u32,
    /// Samples per voxel along each ray.
    #[arg(long, default_value_t = 2.0)]
    samples_per_voxel: f32,
    /// Opacity at which a ray stops early.
    #[arg(long, default_value_t = mixvol::scene::DEFAULT_EARLY_TERMINATION)]
    early_termination: f32,
    /// Background colour r,g,b in [0,1] the image is composited over.
    #[arg(long, default_value = "0.08,0.08,0.1", value_parser = parse_vec3)]
    background: Vec3,
    /// Output PNG path (folders are created).
    #[arg(long, short, default_value = "out/render.png")]
    output: PathBuf,
    /// Frames to render for timing (min / median / max are printed); the image is the last one.
    #[arg(long, default_value_t = 5)]
    frames: u32,
    /// Enable the Khronos validation layers (with synchronization validation).
    #[arg(long)]
    validation: bool,
    /// Use the first Vulkan device whose name contains this (default: prefer a discrete GPU).
    #[arg(long)]
    device: Option<String>,
    /// Also render with the CPU reference and print the largest per-pixel difference.
    #[arg(long)]
    compare: bool,
}

fn parse_floats<const N: usize>(s: &str) -> std::result::Result<[f32; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!("expected {N} comma-separated numbers, got '{s}'"));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.parse().map_err(|_| format!("'{p}' is not a number"))?;
    }
    Ok(out)
}

fn parse_vec3(s: &str) -> std::result::Result<Vec3, String> {
    parse_floats::<3>(s).map(Vec3::from_array)
}

fn parse_uvec3(s: &str) -> std::result::Result<UVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected x,y,z (three integers), got '{s}'"));
    }
    let mut out = [0u32; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p
            .parse()
            .map_err(|_| format!("'{p}' is not a non-negative integer"))?;
    }
    Ok(UVec3::from_array(out))
}

fn parse_scalar(s: &str) -> std::result::Result<ScalarType, String> {
    ScalarType::parse(s).ok_or_else(|| format!("unknown scalar type '{s}' (u8, u16, f32)"))
}

fn parse_tf(s: &str) -> std::result::Result<TfPreset, String> {
    TfPreset::parse(s).ok_or_else(|| format!("unknown preset '{s}' ({})", TfPreset::NAMES))
}

fn load_volume(args: &RenderArgs) -> Result<Volume> {
    match SyntheticField::parse(&args.volume) {
        Some(field) => Ok(field.generate(args.dims, args.scalar)?),
        None => Ok(load_raw(
            std::path::Path::new(&args.volume),
            &RawDescriptor {
                dims: args.dims,
                scalar: args.scalar,
                spacing: args.spacing,
                header_bytes: args.header_bytes,
                big_endian: args.big_endian,
            },
        )?),
    }
}

fn stats(ms: &mut [f64]) -> (f64, f64, f64) {
    ms.sort_by(|a, b| a.total_cmp(b));
    (ms[0], ms[ms.len() / 2], ms[ms.len() - 1])
}

fn render(args: &RenderArgs) -> Result<()> {
    if args.frames == 0 {
        return Err(Error::InvalidInput("--frames must be at least 1".into()));
    }
    let volume = load_volume(args)?;
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: args.device.clone(),
    })?;
    let info = ctx.info();
    println!(
        "device: {} ({:?}){}",
        info.name,
        info.device_type,
        if info.validation {
            ", validation on"
        } else {
            ""
        }
    );
    let d = volume.dims();
    println!(
        "volume: {} {}x{}x{} {:?}",
        args.volume,
        d.x,
        d.y,
        d.z,
        volume.scalar_type()
    );
    let tf = TransferFunction::preset(args.tf);
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_volume(&volume)?;
    renderer.set_transfer_function(&tf)?;
    let projection = match args.projection {
        ProjectionArg::Perspective => Projection::Perspective {
            fov_y_degrees: args.fov,
        },
        ProjectionArg::Orthographic => Projection::Orthographic {
            height: args.ortho_height,
        },
    };
    let camera = Camera {
        projection,
        ..Camera::perspective(args.eye, args.target, args.fov)
    };
    let settings = RenderSettings {
        samples_per_voxel: args.samples_per_voxel,
        early_termination: args.early_termination,
        ..RenderSettings::default()
    };
    // Warm-up: llvmpipe compiles shaders at the first draw.
    let mut frame = renderer.render(&camera, &settings, args.width, args.height)?;
    let mut gpu = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..args.frames {
        frame = renderer.render(&camera, &settings, args.width, args.height)?;
        gpu.extend(frame.timing.gpu_raycast_ms);
        cpu.push(frame.timing.cpu_frame_ms);
    }
    if let Some(parent) = args.output.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::ImageWrite {
            path: args.output.clone(),
            message: e.to_string(),
        })?;
    }
    frame.save_png(&args.output, args.background)?;
    println!(
        "wrote {} ({}x{})",
        args.output.display(),
        args.width,
        args.height
    );
    let (lo, med, hi) = stats(&mut cpu);
    println!(
        "frame timing over {} frames (after 1 warm-up): cpu min {lo:.2} / median {med:.2} / max {hi:.2} ms",
        args.frames
    );
    if !gpu.is_empty() {
        let (lo, med, hi) = stats(&mut gpu);
        println!("  gpu ray-cast pass: min {lo:.2} / median {med:.2} / max {hi:.2} ms");
    }
    if info.device_type == ash::vk::PhysicalDeviceType::CPU {
        println!(
            "  note: {} is a CPU implementation; these times are not GPU times",
            info.name
        );
    }
    if args.compare {
        let params = renderer.params(&camera, &settings, args.width, args.height)?;
        let reference = reference::render(&volume, &tf, &params);
        let max_diff = reference
            .iter()
            .zip(&frame.pixels)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        println!(
            "cpu reference: max per-channel difference {:.4} ({:.1}/255)",
            max_diff,
            max_diff * 255.0
        );
    }
    drop(renderer);
    let log = ctx.message_log();
    drop(ctx);
    let problems = log.warnings_and_errors();
    if args.validation {
        println!("validation: {} warnings/errors", problems.len());
        for m in &problems {
            eprintln!("  {:?} {}: {}", m.severity, m.id_name, m.text);
        }
        if !problems.is_empty() {
            return Err(Error::InvalidInput(format!(
                "validation reported {} problem(s)",
                problems.len()
            )));
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Render(args) => render(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
