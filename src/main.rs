//! `mixvol` command-line interface.

use clap::{Args, Parser, Subcommand, ValueEnum};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::lod::{ClipPlane, ClipPlanes};
use mixvol::optics::{SamplingModel, TfPreset, TransferFunction};
use mixvol::reference::{ReferenceCache, Transition};
use mixvol::renderer::MixedConfig;
use mixvol::renderer::{Renderer, TargetFormat};
use mixvol::scene::{Camera, Projection, Reconstruction, RenderMode, RenderSettings, Shading};
use mixvol::volume::formats::{load_zarr_level, FileFormat};
use mixvol::volume::{load_raw, RawDescriptor, ScalarType, SyntheticField, Volume};
use mixvol::{reference, Error, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

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
    /// Render a close-up of a hi-res / low-res brick junction, discontinuous (left) and smooth
    /// (right), side by side into one PNG.
    Junction(JunctionArgs),
    /// Render a scene for N frames and report min / median / max GPU time per pass (upload,
    /// fixup, ray-cast) and CPU frame time, as a table and as JSON.
    Bench(BenchArgs),
    /// The accuracy-versus-time report of the default scene (Markdown, CSV and a PNG chart).
    Report(ReportArgs),
    /// Kraus & Bürger's sampling experiments on the CPU: opacity- vs extinction-based deviation
    /// from the exact integral (docs/report/kraus.md, .csv and a PNG chart).
    Kraus(KrausArgs),
}

#[derive(Args, Debug)]
struct KrausArgs {
    /// Folder for kraus.md, .csv and .png.
    #[arg(long, default_value = "docs/report")]
    output_dir: PathBuf,
}

#[derive(Args, Debug)]
struct ReportArgs {
    /// Folder for accuracy-vs-time.md, .csv and .png.
    #[arg(long, default_value = "docs/report")]
    output_dir: PathBuf,
    /// Image width and height.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Timed frames per setting (median reported).
    #[arg(long, default_value_t = 5)]
    frames: u32,
    /// Edge of the cubic Marschner-Lobb volume.
    #[arg(long, default_value_t = 128)]
    volume_size: u32,
    /// Brick size of the mixed-resolution rows.
    #[arg(long, default_value_t = 16)]
    brick_size: u32,
    /// Enable the validation layers.
    #[arg(long)]
    validation: bool,
}

#[derive(Args, Debug)]
struct BenchArgs {
    #[command(flatten)]
    render: RenderArgs,
    /// Change the brick levels every frame (alternating two patterns) so uploads and the fixup
    /// are timed too (needs --levels).
    #[arg(long)]
    churn: bool,
    /// Also write the results as JSON to this path ('-' for standard output).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(ValueEnum, Copy, Clone, Debug, PartialEq)]
enum LevelsArg {
    /// Every brick at full resolution.
    AllHi,
    /// Every brick low-res.
    AllLo,
    /// Hi-res and low-res bricks alternate in a 3D checkerboard.
    Checker,
    /// Bricks with x below the middle are low-res.
    Half,
}

#[derive(ValueEnum, Copy, Clone, Debug, PartialEq)]
enum TransitionArg {
    /// C0 transitions (border fixup + band blend).
    Smooth,
    /// Plain trilinear in every brick: the baseline.
    Discontinuous,
}

#[derive(Args, Debug)]
struct MixedArgs {
    /// Render through the mixed-resolution brick cache with this level pattern (omit for the
    /// plain single-texture ray-caster).
    #[arg(long, value_enum)]
    levels: Option<LevelsArg>,
    /// Brick edge in voxels (power of two).
    #[arg(long, default_value_t = 32)]
    brick_size: u32,
    /// Transition reconstruction between resolution levels.
    #[arg(long, value_enum, default_value_t = TransitionArg::Smooth)]
    transition: TransitionArg,
    /// Cache image budget in MiB.
    #[arg(long, default_value_t = 256)]
    cache_mb: u64,
}

#[derive(Args, Debug)]
struct JunctionArgs {
    /// Output PNG path (folders are created).
    #[arg(long, short, default_value = "out/junction.png")]
    output: PathBuf,
    /// Width of each half in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Enable the Khronos validation layers.
    #[arg(long)]
    validation: bool,
}

#[derive(ValueEnum, Copy, Clone, Debug)]
enum ProjectionArg {
    Perspective,
    Orthographic,
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// Volume to render: a synthetic field (`ml` = Marschner-Lobb, `sphere`, `wall`), a file with
    /// a header (.nii, .nii.gz, .nrrd, .nhdr, .den, a JSON sidecar or .raw with one), or a
    /// headerless raw file (then --dims, --scalar, --spacing describe it).
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
    /// Resolution level of an OME-Zarr image (index into its multiscales datasets, 0 = finest).
    #[arg(long)]
    zarr_level: Option<usize>,
    /// Transfer-function preset: grey, fire, bands, constant, ct, mri.
    #[arg(long, default_value = "fire", value_parser = parse_tf)]
    tf: TfPreset,
    /// Scan preset: `ct` or `mri` picks that transfer function and an automatic window from the
    /// histogram (overrides --tf).
    #[arg(long, value_parser = parse_tf)]
    preset: Option<TfPreset>,
    /// Value window `lo,hi` in normalised units mapped onto the transfer function, or `auto`
    /// (histogram percentiles). Default: [0, 1] for integer data, the value range for floats.
    #[arg(long)]
    window: Option<String>,
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
    #[command(flatten)]
    mixed: MixedArgs,
    #[command(flatten)]
    optics: OpticsArgs,
}

/// Render mode and optical model (each compiles into the pipeline variant only when asked for).
#[derive(Args, Debug)]
struct OpticsArgs {
    /// Render mode.
    #[arg(long, value_enum, default_value_t = ModeArg::Dvr)]
    mode: ModeArg,
    /// Iso value (mode iso), in the units of --window (normalised for integer data).
    #[arg(long, default_value_t = 0.5)]
    iso: f32,
    /// Iso-surface colour r,g,b.
    #[arg(long, default_value = "0.9,0.75,0.55", value_parser = parse_vec3)]
    iso_colour: Vec3,
    /// MIDA gamma in [-1, 1]: -1 DVR, 0 MIDA, 1 MIP (mode mida).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    gamma: f32,
    /// Blinn-Phong shading from field gradients.
    #[arg(long)]
    shading: bool,
    /// Gradient-magnitude opacity modulation with this scale.
    #[arg(long)]
    gradient_opacity: Option<f32>,
    /// Extinction-based sampling (default: opacity-based).
    #[arg(long)]
    extinction: bool,
    /// Pre-integrated classification (DVR, MIDA).
    #[arg(long)]
    preintegrated: bool,
    /// Tricubic B-spline reconstruction (single resolution, or every resident brick hi-res).
    #[arg(long)]
    tricubic: bool,
    /// LaMar's coarse sampling: low-res bricks at twice the step (mixed resolution).
    #[arg(long)]
    coarse_low_res: bool,
    /// A world-space clip plane `nx,ny,nz,d` keeping `n . p + d >= 0` (repeat for up to 6).
    #[arg(long, value_parser = parse_floats::<4>, allow_hyphen_values = true)]
    clip: Vec<[f32; 4]>,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum ModeArg {
    Dvr,
    Iso,
    Mip,
    Mida,
}

impl OpticsArgs {
    /// Fills the mode and optics fields of `settings`.
    fn apply(&self, settings: RenderSettings) -> Result<RenderSettings> {
        let planes: Vec<ClipPlane> = self
            .clip
            .iter()
            .map(|c| ClipPlane::new(Vec3::new(c[0], c[1], c[2]), c[3]))
            .collect();
        let clip_planes =
            ClipPlanes::new(&planes).map_err(|e| Error::InvalidInput(format!("--clip: {e}")))?;
        Ok(RenderSettings {
            clip_planes,
            mode: match self.mode {
                ModeArg::Dvr => RenderMode::Dvr,
                ModeArg::Iso => RenderMode::Iso {
                    value: self.iso,
                    colour: self.iso_colour,
                },
                ModeArg::Mip => RenderMode::Mip,
                ModeArg::Mida => RenderMode::Mida { gamma: self.gamma },
            },
            shading: self.shading.then(Shading::default),
            gradient_opacity: self.gradient_opacity,
            sampling_model: if self.extinction {
                SamplingModel::Extinction
            } else {
                SamplingModel::Opacity
            },
            preintegrated: self.preintegrated,
            reconstruction: if self.tricubic {
                Reconstruction::TricubicBSpline
            } else {
                Reconstruction::Trilinear
            },
            coarse_low_res_steps: self.coarse_low_res,
            ..settings
        })
    }
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

/// Whether `path` is a format with its own header (NIfTI, NRRD, sidecar JSON, VolPack .den, or a
/// .raw file with a sidecar next to it).
fn has_header(path: &std::path::Path) -> bool {
    let name = path.to_string_lossy().to_ascii_lowercase();
    let name = name.trim_end_matches('/');
    let headed = [
        ".nii", ".nii.gz", ".nrrd", ".nhdr", ".json", ".den", ".zarr",
    ];
    if headed.iter().any(|e| name.ends_with(e)) {
        return true;
    }
    name.ends_with(".raw")
        && (path.with_extension("raw.json").exists() || path.with_extension("json").exists())
}

fn load_volume(args: &RenderArgs) -> Result<Volume> {
    let path = std::path::Path::new(&args.volume);
    if let Some(level) = args.zarr_level {
        let is_zarr = FileFormat::from_path(path) == Some(FileFormat::Zarr)
            || ["zarr.json", ".zattrs", ".zarray"]
                .iter()
                .any(|m| path.join(m).is_file());
        if !is_zarr {
            return Err(Error::InvalidInput(format!(
                "--zarr-level applies to OME-Zarr images (a .zarr folder), not '{}'",
                args.volume
            )));
        }
        return Ok(load_zarr_level(path, level)?.volume);
    }
    if SyntheticField::parse(&args.volume).is_none() && has_header(path) {
        return Ok(mixvol::volume::load_volume(path)?);
    }
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

/// The value window from --window / --preset.
fn window_of(args: &RenderArgs, volume: &Volume) -> Result<Option<(f32, f32)>> {
    match args.window.as_deref() {
        Some("auto") => Ok(Some(volume.auto_window())),
        Some(text) => {
            let [lo, hi] = parse_floats::<2>(text).map_err(|e| {
                Error::InvalidInput(format!("--window: {e} (expected lo,hi or auto)"))
            })?;
            if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
                return Err(Error::InvalidInput(format!(
                    "--window: hi {hi} must exceed lo {lo}"
                )));
            }
            Ok(Some((lo, hi)))
        }
        None if args.preset.is_some() => Ok(Some(volume.auto_window())),
        None => Ok(None),
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
    let tf = TransferFunction::preset(args.preset.unwrap_or(args.tf));
    let value_window = window_of(args, &volume)?;
    if let Some((lo, hi)) = value_window {
        println!("window: [{lo:.4}, {hi:.4}] (normalised values)");
    }
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&tf)?;
    let volume = Arc::new(volume);
    let mut reference_cache = None;
    match args.mixed.levels {
        None => renderer.set_volume(&volume)?,
        Some(pattern) => {
            let config = MixedConfig {
                brick_size: args.mixed.brick_size,
                cache_budget_bytes: args.mixed.cache_mb << 20,
                transition: transition_of(args.mixed.transition),
                ..MixedConfig::default()
            };
            renderer.set_mixed_volume(volume.clone(), config)?;
            let grid = BrickGrid::new(volume.dims(), args.mixed.brick_size)
                .map_err(|e| Error::InvalidInput(e.to_string()))?;
            let levels = level_pattern(&grid, pattern);
            let report = renderer.set_levels(&levels)?;
            println!(
                "brick cache: {} hi + {} lo bricks of {}^3, {} uploaded ({:.1} MB), {} fixed up; pack {:.1} ms, upload+fixup {:.1} ms",
                report.hi_bricks,
                report.lo_bricks,
                args.mixed.brick_size,
                report.uploaded_bricks,
                report.uploaded_bytes as f64 / 1e6,
                report.fixup_bricks,
                report.pack_ms,
                report.update_ms
            );
            if args.compare {
                let cache = renderer.brick_cache().expect("mixed volume set");
                reference_cache = Some(ReferenceCache::build(
                    &volume,
                    config.filter,
                    cache,
                    volume.scalar_type(),
                    config.transition,
                )?);
            }
        }
    }
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
    let settings = args.optics.apply(RenderSettings {
        samples_per_voxel: args.samples_per_voxel,
        early_termination: args.early_termination,
        value_window,
        ..RenderSettings::default()
    })?;
    // Warm-up: llvmpipe compiles shaders at the first draw.
    let mut frame = renderer.render(&camera, &settings, args.width, args.height)?;
    let mut gpu = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..args.frames {
        frame = renderer.render(&camera, &settings, args.width, args.height)?;
        gpu.extend(frame.timing.gpu_raycast_ms);
        cpu.push(frame.timing.cpu_frame_ms);
    }
    create_parent(&args.output)?;
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
    println!("pipeline variant: {:?}", frame.variant);
    if args.compare {
        let params = renderer.params(&camera, &settings, args.width, args.height)?;
        let reference = match &reference_cache {
            Some(cache) => reference::render_mixed_scene(
                &cache.view(),
                transition_of(args.mixed.transition),
                &tf,
                &settings,
                &params,
            )?,
            None => reference::render_scene(&volume, &tf, &settings, &params)?,
        };
        let diffs: Vec<f32> = reference
            .iter()
            .zip(&frame.pixels)
            .flat_map(|(a, b)| (*a - *b).abs().to_array())
            .collect();
        let max_diff = diffs.iter().copied().fold(0.0f32, f32::max);
        let mean_diff = diffs.iter().map(|d| f64::from(*d)).sum::<f64>() / diffs.len() as f64;
        let large = diffs.iter().filter(|d| **d > 1.0 / 255.0).count() as f64 / diffs.len() as f64;
        println!(
            "cpu reference: max per-channel difference {:.4} ({:.1}/255), mean {:.2e}, {:.3} % of channels above 1/255",
            max_diff,
            max_diff * 255.0,
            mean_diff,
            100.0 * large
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

fn transition_of(t: TransitionArg) -> Transition {
    match t {
        TransitionArg::Smooth => Transition::Smooth,
        TransitionArg::Discontinuous => Transition::Discontinuous,
    }
}

fn level_pattern(grid: &BrickGrid, pattern: LevelsArg) -> Vec<Level> {
    let half = grid.bricks_per_axis().x / 2;
    (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i);
            let hi = match pattern {
                LevelsArg::AllHi => true,
                LevelsArg::AllLo => false,
                LevelsArg::Checker => (b.x + b.y + b.z).is_multiple_of(2),
                LevelsArg::Half => b.x >= half,
            };
            if hi {
                Level::Hi
            } else {
                Level::Lo
            }
        })
        .collect()
}

fn create_parent(path: &std::path::Path) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::ImageWrite {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    Ok(())
}

/// A close-up of a plane junction (bricks with x < 32 low-res) in a 64^3 Marschner-Lobb volume,
/// discontinuous on the left, smooth on the right.
fn junction(args: &JunctionArgs) -> Result<()> {
    if args.size == 0 {
        return Err(Error::InvalidInput("--size must be positive".into()));
    }
    // f32: 8-bit textures are filtered in 8-bit fixed point on lavapipe, which terraces a zoom.
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(64), ScalarType::F32)?);
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: None,
    })?;
    // Contour stripes: a jump in the field breaks the stripes at the junction.
    let stripes: Vec<(f32, glam::Vec4)> = (0..=40)
        .map(|i| {
            let s = i as f32 / 40.0;
            let c = if i % 2 == 0 {
                glam::Vec4::new(0.95, 0.85, 0.3, 1.0)
            } else {
                glam::Vec4::new(0.1, 0.25, 0.6, 1.0)
            };
            (s, c)
        })
        .collect();
    let tf = TransferFunction::from_control_points(&stripes)?;
    let grid = BrickGrid::new(volume.dims(), 16).map_err(|e| Error::InvalidInput(e.to_string()))?;
    let levels = level_pattern(&grid, LevelsArg::Half);
    // Looking down -z at the junction plane x = 0 (world), 8 voxels wide, through a slab two
    // voxels thick (near/far clip) so the image shows the field itself, like a slice.
    let camera = Camera {
        near: 2.0 - 1.0 / 64.0,
        far: 2.0 + 1.0 / 64.0,
        ..Camera::orthographic(
            Vec3::new(0.0, 0.1, 2.0),
            Vec3::new(0.0, 0.1, 0.0),
            8.0 / 64.0,
        )
    };
    let settings = RenderSettings {
        samples_per_voxel: 4.0,
        ..RenderSettings::default()
    };
    let mut halves = Vec::new();
    for transition in [Transition::Discontinuous, Transition::Smooth] {
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        renderer.set_transfer_function(&tf)?;
        renderer.set_mixed_volume(
            volume.clone(),
            MixedConfig {
                brick_size: 16,
                transition,
                ..MixedConfig::default()
            },
        )?;
        renderer.set_levels(&levels)?;
        let frame = renderer.render(&camera, &settings, args.size, args.size)?;
        halves.push(frame.to_rgba8(Vec3::splat(0.08)));
    }
    let gap = 4;
    let mut out = image::RgbaImage::from_pixel(
        2 * args.size + gap,
        args.size,
        image::Rgba([255, 255, 255, 255]),
    );
    image::imageops::overlay(&mut out, &halves[0], 0, 0);
    image::imageops::overlay(&mut out, &halves[1], i64::from(args.size + gap), 0);
    create_parent(&args.output)?;
    mixvol::renderer::save_png(&out, &args.output)?;
    println!(
        "wrote {}: low-res bricks left of the centre line, hi-res right; discontinuous (left image) vs smooth (right image)",
        args.output.display()
    );
    let log = ctx.message_log();
    drop(ctx);
    if args.validation && !log.warnings_and_errors().is_empty() {
        return Err(Error::InvalidInput("validation reported problems".into()));
    }
    Ok(())
}

/// min / median / max of a series.
fn summary(values: &[f64]) -> Option<(f64, f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    Some((v[0], v[v.len() / 2], v[v.len() - 1]))
}

fn bench(args: &BenchArgs) -> Result<()> {
    let r = &args.render;
    if r.frames == 0 {
        return Err(Error::InvalidInput("--frames must be at least 1".into()));
    }
    if args.churn && r.mixed.levels.is_none() {
        return Err(Error::InvalidInput("--churn needs --levels".into()));
    }
    let volume = Arc::new(load_volume(r)?);
    let ctx = GpuContext::new(&ContextDesc {
        validation: r.validation,
        device_name: r.device.clone(),
    })?;
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&TransferFunction::preset(r.tf))?;
    let mut patterns = Vec::new();
    match r.mixed.levels {
        None => renderer.set_volume(&volume)?,
        Some(pattern) => {
            let config = MixedConfig {
                brick_size: r.mixed.brick_size,
                cache_budget_bytes: r.mixed.cache_mb << 20,
                transition: transition_of(r.mixed.transition),
                ..MixedConfig::default()
            };
            renderer.set_mixed_volume(volume.clone(), config)?;
            let grid = BrickGrid::new(volume.dims(), r.mixed.brick_size)
                .map_err(|e| Error::InvalidInput(e.to_string()))?;
            patterns.push(level_pattern(&grid, pattern));
            // The churn partner: the same pattern with hi and lo swapped.
            patterns.push(
                patterns[0]
                    .iter()
                    .map(|l| {
                        if *l == Level::Hi {
                            Level::Lo
                        } else {
                            Level::Hi
                        }
                    })
                    .collect(),
            );
            renderer.set_levels(&patterns[0])?;
        }
    }
    let camera = Camera {
        projection: match r.projection {
            ProjectionArg::Perspective => Projection::Perspective {
                fov_y_degrees: r.fov,
            },
            ProjectionArg::Orthographic => Projection::Orthographic {
                height: r.ortho_height,
            },
        },
        ..Camera::perspective(r.eye, r.target, r.fov)
    };
    let settings = r.optics.apply(RenderSettings {
        samples_per_voxel: r.samples_per_voxel,
        early_termination: r.early_termination,
        ..RenderSettings::default()
    })?;
    renderer.render(&camera, &settings, r.width, r.height)?; // warm-up
    let (mut upload, mut fixup, mut raycast, mut cpu) = (vec![], vec![], vec![], vec![]);
    let mut variant = None;
    for i in 0..r.frames {
        if args.churn {
            renderer.stage_levels(&patterns[(i as usize + 1) % 2])?;
        }
        let frame = renderer.render(&camera, &settings, r.width, r.height)?;
        upload.extend(frame.timing.gpu_upload_ms);
        fixup.extend(frame.timing.gpu_fixup_ms);
        raycast.extend(frame.timing.gpu_raycast_ms);
        cpu.push(frame.timing.cpu_frame_ms);
        variant = Some(frame.variant);
    }
    let info = ctx.info();
    let rows = [
        ("upload (gpu)", &upload),
        ("fixup (gpu)", &fixup),
        ("ray-cast (gpu)", &raycast),
        ("frame (cpu)", &cpu),
    ];
    println!(
        "# {} frames, {}x{}, volume {} {:?}, device {} ({:?})",
        r.frames,
        r.width,
        r.height,
        r.volume,
        volume.dims().to_array(),
        info.name,
        info.device_type
    );
    println!("# variant {:?}", variant.expect("frames >= 1"));
    println!("| pass | samples | min ms | median ms | max ms |");
    println!("|---|---|---|---|---|");
    let mut json_passes = Vec::new();
    for (name, values) in rows {
        match summary(values) {
            Some((lo, med, hi)) => {
                println!(
                    "| {name} | {} | {lo:.3} | {med:.3} | {hi:.3} |",
                    values.len()
                );
                json_passes.push(format!(
                    "{{\"pass\":\"{name}\",\"samples\":{},\"min_ms\":{lo},\"median_ms\":{med},\"max_ms\":{hi}}}",
                    values.len()
                ));
            }
            None => println!("| {name} | 0 | - | - | - |"),
        }
    }
    if info.device_type == ash::vk::PhysicalDeviceType::CPU {
        println!(
            "note: {} is a CPU implementation; compare ratios, not absolute times",
            info.name
        );
    }
    if let Some(path) = &args.json {
        let json = format!(
            "{{\"device\":\"{}\",\"device_type\":\"{:?}\",\"width\":{},\"height\":{},\"frames\":{},\"volume\":\"{}\",\"passes\":[{}]}}\n",
            info.name.replace('"', "'"),
            info.device_type,
            r.width,
            r.height,
            r.frames,
            r.volume.replace('"', "'"),
            json_passes.join(",")
        );
        if path.as_os_str() == "-" {
            print!("{json}");
        } else {
            create_parent(path)?;
            std::fs::write(path, json).map_err(|e| Error::ImageWrite {
                path: path.clone(),
                message: e.to_string(),
            })?;
        }
    }
    Ok(())
}

fn report(args: &ReportArgs) -> Result<()> {
    let volume = Arc::new(
        SyntheticField::MarschnerLobb.generate(UVec3::splat(args.volume_size), ScalarType::U8)?,
    );
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: None,
    })?;
    let tf = TransferFunction::preset(TfPreset::Fire);
    let options = mixvol::report::ReportOptions {
        size: args.size,
        frames: args.frames,
        brick_size: args.brick_size,
        camera: Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0),
    };
    let report = mixvol::report::accuracy_report(&ctx, volume, &tf, &options)?;
    std::fs::create_dir_all(&args.output_dir).map_err(|e| Error::ImageWrite {
        path: args.output_dir.clone(),
        message: e.to_string(),
    })?;
    let when = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    let command = format!(
        "cargo run --release -- report --size {} --frames {} --volume-size {} --brick-size {}",
        args.size, args.frames, args.volume_size, args.brick_size
    );
    let write = |name: &str, text: String| -> Result<()> {
        let path = args.output_dir.join(name);
        std::fs::write(&path, text).map_err(|e| Error::ImageWrite {
            path,
            message: e.to_string(),
        })
    };
    let md = report.to_markdown(&when, &command);
    write("accuracy-vs-time.md", md.clone())?;
    write("accuracy-vs-time.csv", report.to_csv())?;
    let chart_path = args.output_dir.join("accuracy-vs-time.png");
    report
        .chart()
        .save(&chart_path)
        .map_err(|e| Error::ImageWrite {
            path: chart_path.clone(),
            message: e.to_string(),
        })?;
    print!("{md}");
    println!(
        "wrote {}/accuracy-vs-time.{{md,csv,png}}",
        args.output_dir.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Render(args) => render(args),
        Command::Junction(args) => junction(args),
        Command::Bench(args) => bench(args),
        Command::Report(args) => report(args),
        Command::Kraus(args) => mixvol::kraus::write_report(&args.output_dir, &Default::default())
            .map(|r| {
                print!("{}", r.to_markdown());
                println!("wrote {}/kraus.{{md,csv,png}}", args.output_dir.display());
            }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
