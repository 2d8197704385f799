//! The command line: subcommands, their flags, and the parsers of flag values.

use crate::parse::{parse_colour, parse_floats, parse_scalar, parse_tf, parse_uvec3, parse_vec3};
use clap::{Args, ValueEnum};
use glam::{UVec3, Vec3};
use mixvol::optics::{SamplingModel, TfPreset};
use mixvol::renderer::MixedConfig;
use mixvol::scene::Transition;
use mixvol::scene::{
    Camera, ClipPlane, ClipPlanes, Projection, Reconstruction, RenderMode, RenderSettings, Shading,
};
use mixvol::volume::ScalarType;
use mixvol::{Error, Result};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct KrausArgs {
    /// Folder for kraus.md, .csv and .png.
    #[arg(long, default_value = "docs/report")]
    pub output_dir: PathBuf,
}

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Folder for accuracy-vs-time.{md,csv,json,png,svg} and seams-vs-time.{png,svg}.
    #[arg(long, default_value = "docs/report")]
    pub output_dir: PathBuf,
    /// Image width and height.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Timed frames per setting (median reported).
    #[arg(long, default_value_t = 5)]
    pub frames: u32,
    /// Edge of the cubic Marschner-Lobb volume.
    #[arg(long, default_value_t = 128)]
    pub volume_size: u32,
    /// Brick size of the mixed-resolution rows.
    #[arg(long, default_value_t = 16)]
    pub brick_size: u32,
    /// Enable the validation layers.
    #[arg(long)]
    pub validation: bool,
    /// The quick report of the test suite (48x48 image, 32^3 volume, bricks of 8, 1 frame).
    #[arg(long)]
    pub quick: bool,
    /// Views of the orbit over the scenes (Marschner-Lobb, MNI152 T1, VolPack head) written as
    /// scenes.{md,csv,json} and scene-NAME.{png,svg}; 0 skips it (the quick report never runs it).
    #[arg(long, default_value_t = 4)]
    pub views: u32,
    /// Image width and height of the orbit's views.
    #[arg(long, default_value_t = 96)]
    pub orbit_size: u32,
    /// Folder of the real volumes (scripts/fetch-datasets.sh fetches them there).
    #[arg(long, default_value = "target/datasets")]
    pub data_dir: PathBuf,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    pub render: RenderArgs,
    /// Change the brick levels every frame (alternating two patterns) so uploads and the fixup
    /// are timed too (needs --levels).
    #[arg(long)]
    pub churn: bool,
    /// Also write the results as JSON to this path ('-' for standard output).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Soak: render N frames along a moving camera (orbit, dolly, elevation bob) with
    /// camera-driven residency and the validation layers on; report validation messages, live
    /// GPU allocations at shutdown, RSS and GPU bytes over time and the residency changes, and
    /// fail on any message, leak or growth past the bounds (needs --gpu-budget-mb or a brick
    /// store; use a small image, e.g. --width 32 --height 32).
    #[arg(long, value_name = "N")]
    pub soak: Option<u32>,
    /// The soak's curve as CSV (the summary and the samples as JSON beside it, .json).
    #[arg(long, default_value = "out/soak.csv", requires = "soak")]
    pub soak_log: PathBuf,
    /// Most RSS growth after the soak's warm-up, in MiB, before the soak fails.
    #[arg(long, default_value_t = 4.0, requires = "soak")]
    pub soak_rss_growth_mb: f64,
}

#[derive(ValueEnum, Copy, Clone, Debug, PartialEq)]
pub enum LevelsArg {
    /// Every brick at full resolution.
    AllHi,
    /// Every brick low-res.
    AllLo,
    /// Hi-res and low-res bricks alternate in a 3D checkerboard.
    Checker,
    /// Bricks with x below the middle are low-res.
    Half,
    /// Levels 0, 1, 2, ... by distance from the first corner brick, one level coarser at each
    /// doubling of the distance (0, 1, 2, 2, 3, 3, 3, 3, ...), drawn through the three-level
    /// cache (block levels past 2 with bricks of at least 8 voxels; `render` only).
    Staircase,
    /// Levels 0, 1, 2, ... chosen from the camera for every view (drawn voxels at most a pixel
    /// on screen where --gpu-budget-mb allows), drawn through the three-level
    /// cache (`render` only).
    Camera,
}

#[derive(ValueEnum, Copy, Clone, Debug, PartialEq)]
pub enum TransitionArg {
    /// C0 transitions (border fixup + band blend).
    Smooth,
    /// Plain trilinear in every brick: the baseline.
    Discontinuous,
}

#[derive(Args, Debug)]
pub struct MixedArgs {
    /// Render through the mixed-resolution brick cache with this level pattern (omit for the
    /// plain single-texture ray-caster).
    #[arg(long, value_enum)]
    pub levels: Option<LevelsArg>,
    /// Brick edge in voxels (power of two).
    #[arg(long, default_value_t = 32)]
    pub brick_size: u32,
    /// Transition reconstruction between resolution levels.
    #[arg(long, value_enum, default_value_t = TransitionArg::Smooth)]
    pub transition: TransitionArg,
    /// With --levels camera (and level stores): the largest on-screen size, in pixels, of a
    /// drawn voxel; larger values draw coarser levels and take fewer slots.
    #[arg(long, default_value_t = 1.0)]
    pub voxel_px: f32,
    /// The most levels an in-memory volume is drawn at, from the camera (--gpu-budget-mb,
    /// --levels camera) or at the staircase (default: as many as its brick grid takes; 2: the
    /// full-resolution level and the one below it only).
    #[arg(long)]
    pub level_count: Option<u32>,
}

/// Camera-driven residency: the budgets the planner draws a volume (or a brick store) under.
#[derive(Args, Debug)]
pub struct ResidencyArgs {
    /// MiB of GPU memory for the brick cache image plus the per-frame upload staging,
    /// fractions allowed, at every level count (default: 256). Given for an in-memory volume
    /// without --levels, it draws the volume through the brick cache with camera-driven
    /// residency; brick stores, level stores, streamed images and --levels use it as their
    /// cache budget.
    #[arg(long)]
    pub gpu_budget_mb: Option<f64>,
    /// MiB of brick level changes uploaded per frame at most, taken from --gpu-budget-mb
    /// (default: an eighth of it).
    #[arg(long)]
    pub upload_mb: Option<f64>,
    /// Levels chosen from the camera: weigh each brick's on-screen voxel size by the width of
    /// its value range (a fraction of the volume's), so bricks of narrow range are drawn
    /// coarser and bricks of one value only as fine as their neighbours force.
    #[arg(long)]
    pub weigh_by_value: bool,
    /// MiB of RAM for the stored bricks a level store or a streamed image reads in the
    /// background (a streamed image gives half of it to decoded chunks).
    #[arg(long, default_value_t = 512.0)]
    pub ram_budget_mb: f64,
    /// Exit 1 and write no image when a brick the view wants failed to load (a corrupt stored
    /// brick, a failed fetch) and is drawn at a coarser level instead (without it: a warning
    /// on stderr; a view that draws nothing because of failed loads is always an error).
    #[arg(long)]
    pub strict: bool,
}

/// The camera path: one view (the default), a turntable, a dolly or keyframes.
#[derive(Args, Debug)]
pub struct PathArgs {
    /// Render a turntable of N frames around the target (about --up), starting at --eye.
    #[arg(long, conflicts_with_all = ["dolly", "path"])]
    pub orbit: Option<u32>,
    /// Elevation of the orbit in degrees above the plane through the target normal to --up
    /// (default: the eye's own).
    #[arg(long, requires = "orbit", allow_hyphen_values = true)]
    pub elevation: Option<f32>,
    /// Render N frames moving the eye straight towards the target, to --dolly-to of the
    /// starting distance.
    #[arg(long, conflicts_with = "path")]
    pub dolly: Option<u32>,
    /// End of the dolly as a fraction of the starting distance.
    #[arg(long, default_value_t = 0.35)]
    pub dolly_to: f32,
    /// Render the keyframed path in this JSON file (eye, target, up, fov per keyframe; see
    /// the docs of `mixvol render --help`).
    #[arg(long)]
    pub path: Option<PathBuf>,
    /// Folder for a path's frames (frame_0000.png, ...) and its per-frame log (frames.csv,
    /// frames.json).
    #[arg(long, default_value = "out/frames")]
    pub frames_dir: PathBuf,
    /// For a single view: also write the per-frame log as this CSV (and .json beside it).
    #[arg(long)]
    pub frame_log: Option<PathBuf>,
}

impl PathArgs {
    /// Whether a path (more than the single view) was asked for.
    pub fn is_path(&self) -> bool {
        self.orbit.is_some() || self.dolly.is_some() || self.path.is_some()
    }
}

/// The GPU budget without `--gpu-budget-mb`, in MiB.
pub const DEFAULT_GPU_BUDGET_MB: f64 = 256.0;

impl ResidencyArgs {
    /// `(cache budget, upload budget per frame)` in bytes of `--gpu-budget-mb` (default
    /// [`DEFAULT_GPU_BUDGET_MB`]) and `--upload-mb`: the one GPU budget of every brick-cache
    /// scene.
    pub fn gpu_budgets(&self) -> Result<(u64, u64)> {
        self.budgets(self.gpu_budget_mb.unwrap_or(DEFAULT_GPU_BUDGET_MB))
    }

    /// [`ResidencyArgs::gpu_budgets`] of a level scene whose smallest residency step uploads
    /// `least_upload` bytes: without `--upload-mb`, the upload share is at least that (an
    /// eighth of the budget may be less for a small one), the cache gets the rest; with it,
    /// the flag's value (the renderer refuses one below the step).
    pub fn level_budgets(&self, least_upload: u64) -> Result<(u64, u64)> {
        let (cache, upload) = self.gpu_budgets()?;
        if self.upload_mb.is_some() || upload >= least_upload {
            return Ok((cache, upload));
        }
        let gpu = cache + upload;
        if least_upload >= gpu {
            return Err(Error::InvalidInput(format!(
                "--gpu-budget-mb {:.3} leaves no room for a cache beside the smallest residency \
                 step of {least_upload} bytes (27 full-resolution bricks and their borders): \
                 raise --gpu-budget-mb",
                gpu as f64 / f64::from(1 << 20)
            )));
        }
        Ok((gpu - least_upload, least_upload))
    }

    /// `(cache budget, upload budget per frame)` in bytes for a GPU budget of `gpu_mb` MiB.
    fn budgets(&self, gpu_mb: f64) -> Result<(u64, u64)> {
        let mib = |flag: &str, v: f64| {
            if v.is_finite() && v > 0.0 && v <= 1.0e9 {
                Ok((v * (1u64 << 20) as f64) as u64)
            } else {
                Err(Error::InvalidInput(format!(
                    "{flag} {v}: expected a positive number of MiB (at most 1e9)"
                )))
            }
        };
        let gpu = mib("--gpu-budget-mb", gpu_mb)?;
        let upload = match self.upload_mb {
            Some(mb) => mib("--upload-mb", mb)?,
            None => gpu / 8,
        };
        if upload >= gpu {
            return Err(Error::InvalidInput(format!(
                "--upload-mb {:.3} must stay below --gpu-budget-mb {gpu_mb} (the cache gets the rest)",
                upload as f64 / (1u64 << 20) as f64
            )));
        }
        Ok((gpu - upload, upload.max(1)))
    }

    /// The streamer's RAM budget in bytes.
    pub fn ram_bytes(&self) -> Result<u64> {
        let v = self.ram_budget_mb;
        if v.is_finite() && v > 0.0 && v <= 1.0e9 {
            Ok((v * (1u64 << 20) as f64) as u64)
        } else {
            Err(Error::InvalidInput(format!(
                "--ram-budget-mb {v}: expected a positive number of MiB (at most 1e9)"
            )))
        }
    }
}

#[derive(Args, Debug)]
pub struct JunctionArgs {
    /// Output PNG path (folders are created).
    #[arg(long, short, default_value = "out/junction.png")]
    pub output: PathBuf,
    /// Width of each half in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Enable the Khronos validation layers.
    #[arg(long)]
    pub validation: bool,
}

#[derive(ValueEnum, Copy, Clone, Debug)]
pub enum ProjectionArg {
    Perspective,
    Orthographic,
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Volume to render: a synthetic field (`ml` = Marschner-Lobb, `sphere`, `wall`), a file with
    /// a header (.nii, .nii.gz, .nrrd, .nhdr, .den, a JSON sidecar or .raw with one), a TIFF
    /// stack (.tif, .tiff, .btf; OME-TIFF; a folder of .tif slices), a DICOM series (a folder
    /// of DICOM files, a DICOMDIR or one .dcm file; see --series), an OME-Zarr folder or
    /// remote image (s3://BUCKET/PATH.zarr with the AWS_* environment
    /// variables, http(s)://HOST/PATH.zarr; MIXVOL_REMOTE_TIMEOUT_MS / _RETRIES bound each
    /// fetch), a brick store (streamed from disk under --ram-budget-mb), a level store (a
    /// file, or s3://.../STORE.mvl, http(s)://.../STORE.mvl read with range requests), or a
    /// headerless raw file (then --dims, --scalar, --spacing describe it).
    #[arg(long, default_value = "ml", value_parser = parse_source)]
    pub volume: String,
    /// Dimensions x,y,z: of the synthetic field, or of the raw file.
    #[arg(long, default_value = "128,128,128", value_parser = parse_uvec3)]
    pub dims: UVec3,
    /// Scalar type: u8, u16 or f32 (synthetic fields are generated in it; raw files hold it).
    #[arg(long, default_value = "u8", value_parser = parse_scalar)]
    pub scalar: ScalarType,
    /// Voxel spacing x,y,z of a raw file (anisotropic spacing renders with the right aspect).
    #[arg(long, default_value = "1,1,1", value_parser = parse_vec3)]
    pub spacing: Vec3,
    /// Bytes to skip at the start of a raw file.
    #[arg(long, default_value_t = 0)]
    pub header_bytes: u64,
    /// The raw file's multi-byte values are big-endian.
    #[arg(long)]
    pub big_endian: bool,
    /// Resolution level of an OME-Zarr image (index into its multiscales datasets, 0 = finest):
    /// the level loaded, or with --stream the finest level drawn.
    #[arg(long)]
    pub zarr_level: Option<usize>,
    /// Stream the OME-Zarr image (a folder, s3:// or http(s)://) chunk by chunk instead of
    /// loading it: drawn at every level through the level cache at levels chosen from the
    /// camera (or --levels staircase), each level read from the image's own pyramid; only the
    /// chunks of the bricks the planner asks for are fetched (half of --ram-budget-mb caches
    /// decoded chunks, half stored bricks; MIXVOL_REMOTE_CONCURRENCY requests in flight,
    /// default 8). Needs --window for float images.
    #[arg(long)]
    pub stream: bool,
    /// Image, channel and time point of an OME-TIFF or ImageJ hyperstack (default 0 each).
    #[command(flatten)]
    pub tiff: TiffSelectArgs,
    /// DICOM series to load when the folder or DICOMDIR holds several: its SeriesInstanceUID or
    /// its SeriesNumber (without it, such a folder is an error listing the series).
    #[arg(long)]
    pub series: Option<String>,
    /// Render a NIfTI file or DICOM series axis-aligned in its nearest RAS orientation, without
    /// the residual oblique rotation of its sform / qform / ImageOrientationPatient. By default
    /// `mixvol render` (and the soak and path bench) applies that rotation as the volume's model
    /// transform: the volume renders in RAS+ patient space (+x right, +y anterior, +z superior),
    /// rotated about its centre; --eye, --target, --up and --clip are in that space.
    #[arg(long)]
    pub axis_aligned: bool,
    /// Transfer-function preset: grey, fire, bands, constant, ct, mri.
    #[arg(long, default_value = "fire", value_parser = parse_tf)]
    pub tf: TfPreset,
    /// Scan preset: `ct` or `mri` picks that transfer function and an automatic window from the
    /// histogram (overrides --tf).
    #[arg(long, value_parser = parse_tf)]
    pub preset: Option<TfPreset>,
    /// Value window `lo,hi` in normalised units mapped onto the transfer function, or `auto`
    /// (histogram percentiles). Default: [0, 1] for integer data, the value range for floats.
    #[arg(long)]
    pub window: Option<String>,
    /// Camera projection.
    #[arg(long, value_enum, default_value_t = ProjectionArg::Perspective)]
    pub projection: ProjectionArg,
    /// Eye position x,y,z in world units (the volume box is centred at the origin, longest side 1).
    #[arg(long, default_value = "1.0,1.3,1.4", value_parser = parse_vec3)]
    pub eye: Vec3,
    /// Point looked at, x,y,z.
    #[arg(long, default_value = "0,0,0", value_parser = parse_vec3)]
    pub target: Vec3,
    /// Camera up vector x,y,z (the image's vertical; need not be orthogonal to the view).
    #[arg(long, default_value = "0,1,0", value_parser = parse_vec3)]
    pub up: Vec3,
    /// Vertical field of view in degrees (perspective).
    #[arg(long, default_value_t = 35.0)]
    pub fov: f32,
    /// Visible height in world units (orthographic).
    #[arg(long, default_value_t = 1.6)]
    pub ortho_height: f32,
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Samples per voxel along each ray.
    #[arg(long, default_value_t = 2.0)]
    pub samples_per_voxel: f32,
    /// Opacity at which a ray stops early.
    #[arg(long, default_value_t = mixvol::scene::DEFAULT_EARLY_TERMINATION)]
    pub early_termination: f32,
    /// Background colour r,g,b in [0,1] the image is composited over.
    #[arg(long, default_value = "0.08,0.08,0.1", value_parser = parse_colour)]
    pub background: Vec3,
    /// Output PNG path (folders are created).
    #[arg(long, short, default_value = "out/render.png")]
    pub output: PathBuf,
    /// Frames to render for timing (min / median / max are printed; 1 to 100,000); the image is
    /// the last one.
    #[arg(long, default_value_t = 5)]
    pub frames: u32,
    /// Enable the Khronos validation layers (with synchronization validation).
    #[arg(long)]
    pub validation: bool,
    /// Use the first Vulkan device whose name contains this (default: prefer a discrete GPU).
    #[arg(long)]
    pub device: Option<String>,
    /// Also render with the CPU reference and print the largest per-pixel difference.
    #[arg(long)]
    pub compare: bool,
    #[command(flatten)]
    pub mixed: MixedArgs,
    #[command(flatten)]
    pub residency: ResidencyArgs,
    #[command(flatten)]
    pub camera_path: PathArgs,
    #[command(flatten)]
    pub optics: OpticsArgs,
}

/// Render mode and optical model (each compiles into the pipeline variant only when asked for).
#[derive(Args, Debug)]
pub struct OpticsArgs {
    /// Render mode.
    #[arg(long, value_enum, default_value_t = ModeArg::Dvr)]
    pub mode: ModeArg,
    /// Iso value (mode iso), in the units of --window (normalised for integer data).
    #[arg(long, default_value_t = 0.5)]
    pub iso: f32,
    /// Iso-surface colour r,g,b.
    #[arg(long, default_value = "0.9,0.75,0.55", value_parser = parse_vec3)]
    pub iso_colour: Vec3,
    /// MIDA gamma in [-1, 1]: -1 DVR, 0 MIDA, 1 MIP (mode mida).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub gamma: f32,
    /// Blinn-Phong shading from field gradients.
    #[arg(long)]
    pub shading: bool,
    /// Gradient-magnitude opacity modulation with this scale.
    #[arg(long)]
    pub gradient_opacity: Option<f32>,
    /// Extinction-based sampling (default: opacity-based).
    #[arg(long)]
    pub extinction: bool,
    /// Pre-integrated classification (DVR, MIDA).
    #[arg(long)]
    pub preintegrated: bool,
    /// Tricubic B-spline reconstruction (single resolution, or every resident brick hi-res).
    #[arg(long)]
    pub tricubic: bool,
    /// LaMar's coarse sampling: low-res bricks at twice the step (mixed resolution).
    #[arg(long)]
    pub coarse_low_res: bool,
    /// A world-space clip plane `nx,ny,nz,d` keeping `n . p + d >= 0` (repeat for up to 6).
    #[arg(long, value_parser = parse_floats::<4>, allow_hyphen_values = true)]
    pub clip: Vec<[f32; 4]>,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum ModeArg {
    Dvr,
    Iso,
    Mip,
    Mida,
}

impl OpticsArgs {
    /// Fills the mode and optics fields of `settings`.
    pub fn apply(&self, settings: RenderSettings) -> Result<RenderSettings> {
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

impl RenderArgs {
    /// The camera the flags describe (`--projection`, `--eye`, `--target`, `--fov`,
    /// `--ortho-height`).
    pub fn camera(&self) -> Camera {
        let projection = match self.projection {
            ProjectionArg::Perspective => Projection::Perspective {
                fov_y_degrees: self.fov,
            },
            ProjectionArg::Orthographic => Projection::Orthographic {
                height: self.ortho_height,
            },
        };
        Camera {
            projection,
            up: self.up,
            ..Camera::perspective(self.eye, self.target, self.fov)
        }
    }
}

impl TransitionArg {
    /// The reconstruction across level changes this flag value names.
    pub fn transition(self) -> Transition {
        match self {
            TransitionArg::Smooth => Transition::Smooth,
            TransitionArg::Discontinuous => Transition::Discontinuous,
        }
    }
}

impl MixedArgs {
    /// The brick-cache configuration of `--brick-size`, the cache's share of `--gpu-budget-mb`
    /// ([`ResidencyArgs::gpu_budgets`]) and `--transition`.
    pub fn config(&self, residency: &ResidencyArgs) -> Result<MixedConfig> {
        // One stated range for every brick-cache scene (review D21: two messages disagreed).
        let (min, max) = (
            mixvol::cache::MIN_BRICK_SIZE,
            mixvol::bricks::MAX_BRICK_SIZE,
        );
        let n = self.brick_size;
        if !(n.is_power_of_two() && (min..=max).contains(&n)) {
            return Err(Error::InvalidInput(format!(
                "--brick-size {n}: expected a power of two between {min} and {max} (the brick \
                 cache's bricks)"
            )));
        }
        Ok(MixedConfig {
            brick_size: self.brick_size,
            cache_budget_bytes: residency.gpu_budgets()?.0,
            transition: self.transition.transition(),
            ..MixedConfig::default()
        })
    }
}

/// Which planes of an OME-TIFF or ImageJ hyperstack make the volume: its z planes at one
/// image, channel and time point.
#[derive(Args, Debug, Clone, Copy, Default)]
pub struct TiffSelectArgs {
    /// OME-TIFF image (series) to read, 0 = the first.
    #[arg(long)]
    pub tiff_image: Option<usize>,
    /// Channel of an OME-TIFF (0..SizeC) or ImageJ hyperstack (0..channels) to read; default 0.
    #[arg(long)]
    pub tiff_channel: Option<u64>,
    /// Time point of an OME-TIFF (0..SizeT) or ImageJ hyperstack (0..frames) to read; default 0.
    #[arg(long)]
    pub tiff_time: Option<u64>,
}

impl TiffSelectArgs {
    /// The selection, when any flag was given.
    pub fn options(&self) -> Option<mixvol::volume::formats::TiffOptions> {
        if self.tiff_image.is_none() && self.tiff_channel.is_none() && self.tiff_time.is_none() {
            return None;
        }
        Some(mixvol::volume::formats::TiffOptions {
            image: self.tiff_image.unwrap_or(0),
            channel: self.tiff_channel.unwrap_or(0),
            time: self.tiff_time.unwrap_or(0),
        })
    }
}

/// `mixvol convert`: a volume into a level store (every level as the level cache stores it),
/// read in slabs under a RAM budget.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// The volume to convert: a file with a header (.nii, .nii.gz, .nrrd, .nhdr, .den, a JSON
    /// sidecar or .raw with one), a TIFF stack (.tif, .tiff, .btf; OME-TIFF; a folder of .tif
    /// slices; streamed page by page), a DICOM series (a folder, a DICOMDIR or a .dcm file;
    /// loaded whole, within --ram-budget-mb; see --series), an OME-Zarr folder or remote image (s3://BUCKET/PATH.zarr
    /// with the AWS_* environment variables, http(s)://HOST/PATH.zarr; MIXVOL_REMOTE_TIMEOUT_MS
    /// / _RETRIES bound each fetch), a headerless raw file (described by
    /// --dims, --scalar, --spacing, --header-bytes, --big-endian), or a synthetic field (ml,
    /// sphere, wall; generated whole at --dims, --scalar). A two-level brick store written by
    /// an earlier mixvol is upgraded: its voxels are read back from its level-0 bricks.
    #[arg(value_parser = parse_source)]
    pub input: String,
    /// The level store file to write (refused if it exists, unless --force), drawn by
    /// `mixvol render --volume STORE` at levels chosen from the camera.
    pub store: PathBuf,
    /// Brick edge in voxels (a power of two).
    #[arg(long, default_value_t = 32)]
    pub brick_size: u32,
    /// Filter building level 1 from level 0 (recorded in the store): mean2, lamar, box4,
    /// bspline4; every coarser level is the vertex pyramid's tent or mean.
    #[arg(long, default_value = "mean2", value_parser = parse_filter)]
    pub filter: mixvol::bricks::DownsampleFilter,
    /// Dimensions x,y,z of a headerless raw file or a synthetic field (default 128,128,128).
    #[arg(long, value_parser = parse_uvec3)]
    pub dims: Option<UVec3>,
    /// Scalar type of a headerless raw file or a synthetic field: u8 (default), u16 or f32.
    #[arg(long, value_parser = parse_scalar)]
    pub scalar: Option<ScalarType>,
    /// Voxel spacing x,y,z of a headerless raw file.
    #[arg(long, default_value = "1,1,1", value_parser = parse_vec3)]
    pub spacing: Vec3,
    /// Bytes to skip at the start of a headerless raw file.
    #[arg(long, default_value_t = 0)]
    pub header_bytes: u64,
    /// The headerless raw file's multi-byte values are big-endian.
    #[arg(long)]
    pub big_endian: bool,
    /// RAM budget in MiB for the write (slabs of level 0, the coarser levels' planes, read
    /// buffers), checked before any work.
    #[arg(long, default_value_t = 512)]
    pub ram_budget_mb: u64,
    /// Level of an OME-Zarr image to convert (index into its multiscales datasets; 0 = finest).
    #[arg(long)]
    pub level: Option<usize>,
    /// Image, channel and time point of an OME-TIFF or ImageJ hyperstack (default 0 each).
    #[command(flatten)]
    pub tiff: TiffSelectArgs,
    /// DICOM series to convert when the folder or DICOMDIR holds several: its
    /// SeriesInstanceUID or its SeriesNumber.
    #[arg(long)]
    pub series: Option<String>,
    /// Accepted for scripts written before level stores became the only format: every store
    /// holds all levels.
    #[arg(long, hide = true)]
    pub all_levels: bool,
    /// Levels of the store (default: 0-2 and block levels until one block covers the longest
    /// axis; more than 3 need bricks of at least 8).
    #[arg(long)]
    pub level_count: Option<u32>,
    /// Replace an existing STORE (atomically, once the new store is complete).
    #[arg(long)]
    pub force: bool,
    /// Also write the summary (sizes, MB/s, peak RSS) as JSON to this path.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
}

/// A volume, store or URL to read: any text but an empty one (review D28: "" was looked up as
/// a file and reported as "cannot read volume file : No such file").
fn parse_source(s: &str) -> std::result::Result<String, String> {
    if s.trim().is_empty() {
        return Err(
            "empty: expected a file, folder, URL or synthetic field (ml, sphere, wall)".into(),
        );
    }
    Ok(s.to_string())
}

fn parse_filter(s: &str) -> std::result::Result<mixvol::bricks::DownsampleFilter, String> {
    mixvol::bricks::DownsampleFilter::parse(s)
        .ok_or_else(|| format!("unknown filter '{s}' (mean2, lamar, box4, bspline4)"))
}
