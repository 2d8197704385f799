//! What to draw: the camera, render settings, and the per-frame parameter block that the GPU and
//! the CPU reference both consume ([`RaycastParams`]).
//!
//! World space: the volume box is centred at the origin and scaled so that its longest physical
//! side (dims * spacing) is 1. Anisotropic spacing therefore renders with the right aspect. The
//! box's axes are the volume's index axes unless the volume has a model transform
//! ([`ModelTransform`]: a rotation about the box centre, e.g. an oblique NIfTI or DICOM volume in
//! RAS+ patient space); the camera, clip planes and host depth are always given in world space,
//! and the pass maps them into the volume frame (see [`model`] for the convention).
//! [`RaycastParams`] itself is in the volume frame.

mod clip;
pub mod model;

pub use clip::{ClipPlane, ClipPlaneError, ClipPlanes, MAX_CLIP_PLANES};
pub use model::{ModelTransform, ModelTransformError};

/// Render settings, a camera or a parameter block that cannot be used (the message names the
/// field and what was expected). The crate's [`Error`](crate::Error) takes it as
/// `InvalidInput`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid input: {0}")]
pub struct SceneError(pub String);

type Result<T, E = SceneError> = std::result::Result<T, E>;
use crate::optics::SamplingModel;
use crate::volume::Volume;
use glam::{Mat4, UVec3, Vec3, Vec4};

/// Smallest magnitude a ray direction component is given in the slab test (`RAY_DIR_EPSILON` in
/// GLSL): keeps axis-parallel rays finite.
pub const RAY_DIR_EPSILON: f32 = 1e-20;

/// Bisection steps of the iso-surface refinement (then one secant step): 2^-10 of a sample step
/// (passed to GLSL as a macro).
pub const ISO_BISECTIONS: u32 = 10;

/// How transitions between resolution levels are reconstructed.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Transition {
    /// C0 blend in the half-voxel band of hi-res bricks next to low-res bricks (needs the fixup).
    Smooth,
    /// Plain trilinear fetch everywhere, original duplicated borders: the baseline.
    Discontinuous,
}

/// Default opacity at which a ray stops (early ray termination).
pub const DEFAULT_EARLY_TERMINATION: f32 = 0.99;

/// How the camera projects.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Projection {
    /// Pinhole camera with a vertical field of view in degrees.
    Perspective {
        /// Vertical field of view, degrees, in (0, 180).
        fov_y_degrees: f32,
    },
    /// Parallel projection showing `height` world units vertically.
    Orthographic {
        /// Visible height in world units.
        height: f32,
    },
}

/// A look-at camera in world space.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (for orthographic: the centre of the image plane).
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Approximate up direction.
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
    /// Smallest ray parameter t rendered (distance from the eye along a unit ray).
    pub near: f32,
    /// Largest ray parameter t rendered.
    pub far: f32,
}

impl Camera {
    /// A perspective camera at `eye` looking at `target` with +y up.
    pub fn perspective(eye: Vec3, target: Vec3, fov_y_degrees: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y_degrees },
            near: 0.0,
            far: 1.0e6,
        }
    }

    /// An orthographic camera at `eye` looking at `target` with +y up, `height` world units tall.
    pub fn orthographic(eye: Vec3, target: Vec3, height: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Orthographic { height },
            near: 0.0,
            far: 1.0e6,
        }
    }

    /// The default view: perspective, 30 degrees, from the front-right-top at distance 2.2.
    pub fn default_view() -> Self {
        Self::perspective(Vec3::new(1.2, 0.9, 1.6), Vec3::ZERO, 35.0)
    }
}

/// What a ray computes.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub enum RenderMode {
    /// Direct volume rendering: front-to-back emission-absorption through the transfer function.
    #[default]
    Dvr,
    /// The first crossing of the iso-surface at sample value `value` (the units of
    /// [`RenderSettings::value_window`]: normalised for integer volumes), refined by bisection to
    /// a small fraction of a voxel and drawn opaque in `colour` (Blinn-Phong lit when
    /// [`RenderSettings::shading`] is set).
    Iso {
        /// Iso value.
        value: f32,
        /// Surface colour, components in [0, 1].
        colour: Vec3,
    },
    /// Maximum intensity projection: the transfer function at the largest TF position along the
    /// ray, with the opacity of one reference length.
    Mip,
    /// Bruckner and Groeller's maximum intensity difference accumulation with their single
    /// parameter `gamma` in [-1, 1]: -1 is DVR, 0 is MIDA, 1 is MIP, continuous in between
    /// (`beta = 1 - delta (1 + gamma)` below 0, an image-space blend of MIDA and MIP above).
    Mida {
        /// The DVR (-1) -> MIDA (0) -> MIP (1) parameter.
        gamma: f32,
    },
}

/// Blinn-Phong shading with a headlight (light and viewer along the ray), two-sided, with
/// normals from central differences of the reconstructed field (through the same warped
/// reconstruction as the samples, so shading is continuous across resolution changes). Lit
/// colour = `colour * (ambient + diffuse * |n.l|) + specular * |n.l|^shininess`; where the
/// gradient vanishes the sample counts as facing the light.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Shading {
    /// Ambient coefficient.
    pub ambient: f32,
    /// Diffuse coefficient.
    pub diffuse: f32,
    /// Specular coefficient (white highlights).
    pub specular: f32,
    /// Specular exponent, at least 1.
    pub shininess: f32,
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            ambient: 0.3,
            diffuse: 0.7,
            specular: 0.3,
            shininess: 24.0,
        }
    }
}

/// How the scalar field is reconstructed between voxel centres.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub enum Reconstruction {
    /// Hardware trilinear filtering (one fetch).
    #[default]
    Trilinear,
    /// Cubic B-spline from eight trilinear fetches (Sigg and Hadwiger): smoother, C2, slightly
    /// blurring (it approximates, not interpolates). Exact where the fetched field is trilinear
    /// on one grid: single-resolution volumes, and brick caches whose resident bricks are all
    /// hi-res. While a low-res brick is resident the renderer keeps trilinear reconstruction
    /// (and the frame's variant says so): across a level change the fetched field is the warped
    /// C0 blend, which is not linear between texel centres, and the 8-fetch B-spline of it would
    /// jump at every texel boundary.
    TricubicBSpline,
}

/// Which render mode a pipeline variant is compiled for (the parameters live in the per-frame
/// block).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub enum ModeKind {
    /// [`RenderMode::Dvr`].
    #[default]
    Dvr,
    /// [`RenderMode::Iso`].
    Iso,
    /// [`RenderMode::Mip`].
    Mip,
    /// [`RenderMode::Mida`].
    Mida,
}

/// The effects a scene calls for: what a ray-cast pipeline variant compiles in (and what the CPU
/// reference evaluates). Derived from [`RenderSettings::features`], which drops effects that do
/// not apply to the mode.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct RayFeatures {
    /// The render mode.
    pub mode: ModeKind,
    /// Blinn-Phong shading from field gradients (DVR, MIDA, iso-surfaces).
    pub shading: bool,
    /// Opacity modulated by the gradient magnitude (DVR, MIDA).
    pub gradient_opacity: bool,
    /// How samples turn into opacities.
    pub sampling_model: SamplingModel,
    /// Pre-integrated classification from a 2D table (DVR, MIDA).
    pub preintegrated: bool,
    /// Tricubic B-spline reconstruction ([`Reconstruction::TricubicBSpline`]).
    pub tricubic: bool,
    /// Low-res bricks sampled at twice the step ([`RenderSettings::coarse_low_res_steps`]).
    pub coarse_low_res: bool,
    /// Rays are cut to the kept side of clip planes ([`RenderSettings::clip_planes`]).
    pub clip_planes: bool,
}

/// Most samples one ray may take: step counts travel to the shaders as `f32`, exact up to
/// 2^24.
pub const MAX_RAY_STEPS: u32 = 1 << 24;

/// Settings for one render.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per voxel along a ray (step = smallest voxel side / this).
    pub samples_per_voxel: f32,
    /// A ray stops once its accumulated opacity reaches this.
    pub early_termination: f32,
    /// Normalised value mapped to TF position 0 and 1; `None` uses [0, 1] for integer volumes and
    /// the value range for float volumes (widened to `[min(v, 0), max(v, 1)]` when the volume is
    /// constant, so it is classified like an integer volume of the same value). A window that
    /// cannot be classified in f32 (width outside 2^-128..2^126, or float data below 2^-110 in
    /// magnitude) is an `InvalidInput` error, never a black frame.
    pub value_window: Option<(f32, f32)>,
    /// Lower bound on the samples a ray may take before it is stopped. Whatever this says, a
    /// frame allows every ray as many samples as the longest ray through the volume box needs
    /// (its diagonal over the step, see [`RaycastParams::for_dims`]), so no ray is ever cut
    /// short; a scene needing more than [`MAX_RAY_STEPS`] samples per ray is refused.
    pub max_steps: u32,
    /// What a ray computes.
    pub mode: RenderMode,
    /// Blinn-Phong shading (`None`: unlit; the shading code is then compiled out).
    pub shading: Option<Shading>,
    /// Gradient-magnitude opacity modulation: a sample's opacity of one reference length is
    /// scaled by `min(1, k |grad s|)`, s being the TF position and the gradient per world unit
    /// (the volume's longest side is 1). `None` compiles it out.
    pub gradient_opacity: Option<f32>,
    /// Opacity-based or extinction-based sampling (Kraus et al.).
    pub sampling_model: SamplingModel,
    /// Pre-integrated classification (DVR and MIDA): each step looks up the segment between the
    /// previous and the current sample in a 2D table built for the step length.
    pub preintegrated: bool,
    /// Central-difference distance for gradients, in voxels of the finest level.
    pub gradient_step: f32,
    /// Reconstruction filter.
    pub reconstruction: Reconstruction,
    /// LaMar et al.'s coarse sampling of low-res data (mixed resolution only): two consecutive
    /// samples in one low-res brick merge into one at their common boundary standing for both
    /// segments, with the opacity corrected for the doubled length. Fewer samples where the data
    /// has half the resolution; exact for homogeneous regions, an approximation elsewhere.
    pub coarse_low_res_steps: bool,
    /// World-space clip planes (up to [`MAX_CLIP_PLANES`]): each ray is cut to the part on the
    /// kept side (`normal . p + offset >= 0`) of every plane, once per ray; no per-sample cost.
    /// The same planes passed to `lod::cull_bricks` also drop clipped bricks.
    pub clip_planes: ClipPlanes,
}

impl RenderSettings {
    /// The value window the transfer function is applied through: [`Self::value_window`] when
    /// set, else `[0, 1]` for integer volumes (normalised values) and the volume's `value_range`
    /// for float volumes (a constant float volume classifies inside `[min(v, 0), max(v, 1)]`,
    /// as an integer volume of that value would, not at TF position 0).
    pub fn classification_window(&self, is_float: bool, value_range: (f32, f32)) -> (f32, f32) {
        match self.value_window {
            Some(window) => window,
            None if is_float && value_range.1 <= value_range.0 => {
                (value_range.0.min(0.0), value_range.1.max(1.0))
            }
            None if is_float => value_range,
            None => (0.0, 1.0),
        }
    }

    /// The effects this scene calls for (what the pipeline variant compiles in).
    pub fn features(&self) -> RayFeatures {
        let mode = match self.mode {
            RenderMode::Dvr => ModeKind::Dvr,
            RenderMode::Iso { .. } => ModeKind::Iso,
            RenderMode::Mip => ModeKind::Mip,
            RenderMode::Mida { .. } => ModeKind::Mida,
        };
        let classifies_samples = matches!(mode, ModeKind::Dvr | ModeKind::Mida);
        RayFeatures {
            mode,
            shading: self.shading.is_some() && mode != ModeKind::Mip,
            gradient_opacity: self.gradient_opacity.is_some() && classifies_samples,
            sampling_model: self.sampling_model,
            preintegrated: self.preintegrated && classifies_samples,
            tricubic: self.reconstruction == Reconstruction::TricubicBSpline,
            coarse_low_res: self.coarse_low_res_steps,
            clip_planes: !self.clip_planes.planes().is_empty(),
        }
    }

    /// Checks the mode and optics settings (ranges, finiteness).
    fn validate_optics(&self) -> Result<()> {
        let bad = |what: String| Err(SceneError(what));
        match self.mode {
            RenderMode::Iso { value, colour } => {
                if !value.is_finite() {
                    return bad(format!("iso value {value} must be finite"));
                }
                if !(colour.is_finite()
                    && colour.min_element() >= 0.0
                    && colour.max_element() <= 1.0)
                {
                    return bad(format!("iso colour {colour} must lie in [0, 1]"));
                }
            }
            RenderMode::Mida { gamma } if !(-1.0..=1.0).contains(&gamma) => {
                return bad(format!("MIDA gamma {gamma} must lie in [-1, 1]"));
            }
            _ => {}
        }
        if let Some(sh) = self.shading {
            let coefficients = [sh.ambient, sh.diffuse, sh.specular];
            if coefficients.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
                return bad(format!(
                    "shading coefficients {coefficients:?} must be finite and non-negative"
                ));
            }
            if !(sh.shininess >= 1.0 && sh.shininess.is_finite()) {
                return bad(format!("shininess {} must be at least 1", sh.shininess));
            }
        }
        if let Some(k) = self.gradient_opacity {
            if !(k >= 0.0 && k.is_finite()) {
                return bad(format!(
                    "gradient opacity scale {k} must be finite and >= 0"
                ));
            }
        }
        if !(self.gradient_step > 0.0 && self.gradient_step.is_finite()) {
            return bad(format!(
                "gradient step {} voxels must be positive",
                self.gradient_step
            ));
        }
        Ok(())
    }
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            samples_per_voxel: 1.0,
            early_termination: DEFAULT_EARLY_TERMINATION,
            value_window: None,
            max_steps: 16384,
            mode: RenderMode::Dvr,
            shading: None,
            gradient_opacity: None,
            sampling_model: SamplingModel::Opacity,
            preintegrated: false,
            gradient_step: 1.0,
            reconstruction: Reconstruction::Trilinear,
            coarse_low_res_steps: false,
            clip_planes: ClipPlanes::NONE,
        }
    }
}

/// The per-frame parameter block, std140-compatible: vec4 fields and one mat4 (368 bytes). Mirrors `RaycastParams`
/// in `glsl/include/params.glsl`; size and field offsets are checked in `gpu::shared_defs`.
/// Positions, directions and planes are in the volume frame (the world, rotated by the inverse
/// of the volume's [`ModelTransform`]; the world itself when there is none).
#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RaycastParams {
    /// xyz: eye or image-plane centre; w: 0 perspective, 1 orthographic.
    pub eye: Vec4,
    /// xyz: unit view direction; w: near.
    pub forward: Vec4,
    /// xyz: right scaled to half the image width at unit distance; w: far.
    pub right: Vec4,
    /// xyz: up scaled to half the image height at unit distance.
    pub up: Vec4,
    /// xyz: volume box minimum; w: step length.
    pub box_min: Vec4,
    /// xyz: volume box maximum; w: reference length d0 (one voxel).
    pub box_max: Vec4,
    /// x: window low; y: 1 / window range; z: early-termination alpha; w: max steps.
    pub tf_window: Vec4,
    /// x: width, y: height in pixels.
    pub viewport: Vec4,
    /// xyz: volume dimensions in voxels; w: brick size n (mixed resolution).
    pub volume_dims: Vec4,
    /// xyz: 1 / cache extent in texels (mixed resolution); w: unused.
    pub cache_extent_inv: Vec4,
    /// x: iso value; y: MIDA gamma; z: gradient opacity scale; w: gradient step (voxels).
    pub mode: Vec4,
    /// x: ambient, y: diffuse, z: specular, w: shininess (Blinn-Phong).
    pub shading: Vec4,
    /// rgb: iso-surface colour; w: number of clip planes.
    pub iso_colour: Vec4,
    /// Clip planes: xyz normal (towards the kept side), w offset; the first `iso_colour.w` count.
    pub clip_planes: [Vec4; MAX_CLIP_PLANES],
    /// Inverse of the host's `clip_from_world` times the model matrix (so clip space to the
    /// volume frame; used only when rays stop at a host depth buffer).
    pub world_from_clip: Mat4,
}

/// The world-space box of a volume: centred, longest physical side 1.
pub fn volume_box(dims: UVec3, spacing: Vec3) -> (Vec3, Vec3) {
    let extent = dims.as_vec3() * spacing;
    let size = extent / extent.max_element();
    (-0.5 * size, 0.5 * size)
}

impl RaycastParams {
    /// The same block set up for a brick cache of `cache_extent` texels and bricks of `brick_size`.
    pub fn with_cache(mut self, brick_size: u32, cache_extent: UVec3) -> Self {
        self.volume_dims.w = brick_size as f32;
        self.cache_extent_inv = (Vec3::ONE / cache_extent.as_vec3()).extend(0.0);
        self
    }

    /// Builds the parameter block for `volume` seen by `camera` at `width` x `height`.
    pub fn new(
        volume: &Volume,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        Self::for_dims(
            volume.dims(),
            volume.spacing(),
            volume.value_range(),
            volume.scalar_type() == crate::volume::ScalarType::F32,
            camera,
            settings,
            width,
            height,
        )
    }

    /// As [`RaycastParams::new`] from the volume's dims, spacing and value range.
    #[allow(clippy::too_many_arguments)] // reason: mirrors the fields it fills, all distinct.
    pub fn for_dims(
        dims: UVec3,
        spacing: Vec3,
        value_range: (f32, f32),
        is_float: bool,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(SceneError(format!(
                "viewport {width}x{height} has a zero side"
            )));
        }
        let forward = camera.target - camera.eye;
        if !(forward.is_finite() && forward.length() > 1e-12) {
            return Err(SceneError(
                "camera eye and target coincide (or are not finite)".into(),
            ));
        }
        let forward = forward.normalize();
        let right = forward.cross(camera.up);
        if right.length() < 1e-6 {
            return Err(SceneError(
                "camera up vector is parallel to the view direction".into(),
            ));
        }
        let right = right.normalize();
        let up = right.cross(forward);
        let aspect = width as f32 / height as f32;
        let (half_h, ortho) = match camera.projection {
            Projection::Perspective { fov_y_degrees } => {
                if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
                    return Err(SceneError(format!(
                        "perspective field of view {fov_y_degrees} must be in (0, 180) degrees"
                    )));
                }
                ((fov_y_degrees.to_radians() * 0.5).tan(), 0.0)
            }
            Projection::Orthographic { height } => {
                if !(height > 0.0 && height.is_finite()) {
                    return Err(SceneError(format!(
                        "orthographic height {height} must be positive"
                    )));
                }
                (0.5 * height, 1.0)
            }
        };
        settings.validate_optics()?;
        if settings.early_termination.is_nan() || settings.early_termination <= 0.0 {
            return Err(SceneError(format!(
                "early termination {} must be above 0 (the opacity at which a ray stops; 1 or \
                 more never stops early)",
                settings.early_termination
            )));
        }
        if !(settings.samples_per_voxel > 0.0 && settings.samples_per_voxel.is_finite()) {
            return Err(SceneError(format!(
                "samples per voxel {} must be positive",
                settings.samples_per_voxel
            )));
        }
        if !(camera.near >= 0.0 && camera.near < camera.far) {
            return Err(SceneError(format!(
                "near {} and far {} must satisfy 0 <= near < far",
                camera.near, camera.far
            )));
        }
        let (lo, hi) = settings.classification_window(is_float, value_range);
        // `1 / (hi - lo)` must be a normal f32: GPUs flush subnormal uniforms to zero (every
        // sample would classify at TF position 0) and an infinite one makes `(v - lo) * inv` NaN;
        // data below 2^-110 in magnitude is flushed by GPU texture filtering.
        let range = f64::from(hi) - f64::from(lo);
        let inv_range = if range > 0.0 {
            (1.0 / range) as f32
        } else {
            0.0
        };
        let magnitude = value_range.0.abs().max(value_range.1.abs());
        if !(lo.is_finite() && hi.is_finite())
            || (range > 0.0 && !(inv_range.is_normal() && (range as f32).is_finite()))
            || (is_float
                && settings.value_window.is_none()
                && magnitude < 2f32.powi(-110)
                && magnitude > 0.0)
        {
            return Err(SceneError(format!(
                "value window [{lo:e}, {hi:e}] (value range [{:e}, {:e}]) cannot be classified \
                 in f32: its width must be between 2^-128 and 2^126 and the data above 2^-110 in \
                 magnitude; pass RenderSettings::value_window or rescale the volume",
                value_range.0, value_range.1
            )));
        }
        let (iso_value, iso_colour, gamma) = match settings.mode {
            RenderMode::Iso { value, colour } => (value, colour, 0.0),
            RenderMode::Mida { gamma } => (0.0, Vec3::ZERO, gamma),
            _ => (0.0, Vec3::ZERO, 0.0),
        };
        let sh = settings.shading.unwrap_or(Shading {
            ambient: 1.0,
            diffuse: 0.0,
            specular: 0.0,
            shininess: 1.0,
        });
        let (box_min, box_max) = volume_box(dims, spacing);
        let voxel = ((box_max - box_min) / dims.as_vec3()).min_element();
        let step = voxel / settings.samples_per_voxel;
        // The longest ray inside the box is its diagonal: allow it every sample (plus the
        // partial first and last steps), so no ray is cut short.
        let needed = (f64::from((box_max - box_min).length()) / f64::from(step)).ceil() + 2.0;
        if !(step > 0.0 && step.is_finite() && needed <= f64::from(MAX_RAY_STEPS)) {
            return Err(SceneError(format!(
                "a ray through this volume needs {needed:.3e} samples (box diagonal {:.3} over \
                 step {step:.3e} = smallest voxel side {voxel:.3e} / {} samples per voxel); at \
                 most {MAX_RAY_STEPS} are supported: lower the samples per voxel or check the \
                 voxel spacing {spacing:?} (a side far thinner than the others)",
                (box_max - box_min).length(),
                settings.samples_per_voxel
            )));
        }
        let max_steps = (needed as u32).max(settings.max_steps.min(MAX_RAY_STEPS));
        Ok(Self {
            eye: camera.eye.extend(ortho),
            forward: forward.extend(camera.near),
            right: (right * half_h * aspect).extend(camera.far),
            up: (up * half_h).extend(0.0),
            box_min: box_min.extend(step),
            box_max: box_max.extend(voxel),
            tf_window: Vec4::new(lo, inv_range, settings.early_termination, max_steps as f32),
            viewport: Vec4::new(width as f32, height as f32, 0.0, 0.0),
            volume_dims: dims.as_vec3().extend(0.0),
            cache_extent_inv: Vec4::ZERO,
            mode: Vec4::new(
                iso_value,
                gamma,
                settings.gradient_opacity.unwrap_or(0.0),
                settings.gradient_step,
            ),
            shading: Vec4::new(sh.ambient, sh.diffuse, sh.specular, sh.shininess),
            iso_colour: iso_colour.extend(settings.clip_planes.planes().len() as f32),
            clip_planes: {
                let mut planes = [Vec4::ZERO; MAX_CLIP_PLANES];
                for (out, plane) in planes.iter_mut().zip(settings.clip_planes.planes()) {
                    *out = plane.normal.extend(plane.offset);
                }
                planes
            },
            world_from_clip: Mat4::IDENTITY,
        })
    }
}
