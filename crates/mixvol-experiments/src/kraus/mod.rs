//! The experiments of Kraus & Bürger, "Interpolating and Downsampling RGBA Volume Data"
//! (`../shared/papers/kraus-*`), on the CPU: opacity-based against extinction-based sampling of
//! pre-classified RGBA grids.
//!
//! A grid vertex holds an emitted colour `C` and an extinction coefficient `tau` (per grid
//! spacing; vertices are one unit apart, and everything outside the grid is empty). A ray is
//! sampled every `d` units, at positions `t = phase + k d`, and the samples are composited front
//! to back ([`composite`]) from the ray's origin (the camera side). The two models differ in what
//! is (bi)linearly interpolated at a sample:
//! - opacity-based (paper §3.2): the opacity `alpha0 = 1 - exp(-tau d0)` of a reference distance
//!   `d0` and the opacity-weighted colour `C alpha0`; then the opacity correction
//!   `alpha = 1 - (1 - alpha0)^(d / d0)` ([`correct_opacity`], Eq. 16) and the colour scaled by
//!   `alpha / alpha0` (Eq. 17);
//! - extinction-based (§3.3): the extinction `tau` and the extinction-weighted colour `C tau`;
//!   then `alpha = 1 - exp(-tau d)` ([`extinction_opacity`], Eq. 22) and the colour scaled by
//!   `alpha / tau` (Eq. 23).
//!
//! The ground truth ([`exact`]) is the emission-absorption integral (Eq. 1) of the continuous
//! model the extinction-based sampling discretises: extinction and extinction-weighted colour
//! interpolated bilinearly between the vertices, integrated with fine steps in f64 (step `h` and
//! `h / 2`, their difference reported as the error estimate). For the paper's set-ups the integral
//! also has a closed form (see [`Setup::exact`]), which the tests compare with.
//!
//! The set-ups ([`Setup`]):
//! - [`figure1`]: the paper's Figure 1, a 5 x 2 grid whose middle column has `C = 1`,
//!   `tau = tau_max` and all other vertices `C = 0`, `tau = 0`; a ray along the rows, half-way
//!   between them, towards the camera on the left. The samples sit at the projected distance
//!   `r` (0 <= r < d) from the filled column. The paper plots the ray's integrated opacity over
//!   `r` and `d = d0` for `tau_max = 1, 2, 4, 8` (its Figure 4); the exact value is
//!   `1 - exp(-tau_max)` for every `r` and `d`, so every deviation is a sampling error.
//! - [`wall`]: the one-voxel-thick opaque wall of the paper's Figures 5 and 6 along the ray
//!   perpendicular to it (the worst case: an oblique ray sees a thicker wall sampled more
//!   densely), as a 1D grid of 5 vertices with the middle one filled.
//!
//! [`run`] (in `sweep.rs`) sweeps both (Figure 1 over `d = 0.1 .. 2.5`, the wall on a 0.01 grid of `d` to find
//! where each model first deviates visibly), [`KrausReport`] writes the Markdown, CSV and chart
//! of `mixvol kraus` (`docs/report/kraus.*`).

//!
//! Files: this one holds the model (grids, rays, the two sampling models, the exact integral,
//! the set-ups and the deviation statistics); `sweep.rs` the experiment sweep ([`run`]);
//! `output.rs` the Markdown, CSV and chart of the report and [`write_report`].

mod output;
mod sweep;

pub use output::{write_report, COMMAND};
pub use sweep::{run, ExactCheck, KrausOptions, KrausReport, Row, WallOnset};

use glam::{DVec2, Vec3, Vec4};
use mixvol::optics::{composite, correct_opacity, extinction_opacity};
use mixvol::{Error, Result};

/// The largest number of samples one ray may take in [`integrate`] (guards against `d` tiny
/// relative to the ray length).
pub const MAX_SAMPLES: f64 = 1e7;

/// Fine steps per unit length of the coarser of the two integrations in [`exact`].
pub const EXACT_STEPS_PER_UNIT: f64 = 4096.0;

/// One pre-classified grid vertex.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Vertex {
    /// Emitted colour `C` (not weighted), each component in [0, 1].
    pub colour: Vec3,
    /// Extinction coefficient per grid spacing, finite and >= 0.
    pub tau: f32,
}

impl Vertex {
    /// The empty vertex: no extinction, no colour (also everything outside a grid).
    pub const EMPTY: Vertex = Vertex {
        colour: Vec3::ZERO,
        tau: 0.0,
    };

    /// A vertex of colour `colour` and extinction `tau`, checked.
    pub fn new(colour: Vec3, tau: f32) -> Result<Self> {
        if !(colour.is_finite() && colour.min_element() >= 0.0 && colour.max_element() <= 1.0) {
            return Err(Error::InvalidInput(format!(
                "vertex colour {colour:?} is outside [0, 1]"
            )));
        }
        if !(tau.is_finite() && tau >= 0.0) {
            return Err(Error::InvalidInput(format!(
                "vertex extinction {tau} must be finite and >= 0"
            )));
        }
        Ok(Self { colour, tau })
    }
}

/// A 2D grid of pre-classified vertices at integer positions `(i, j)`, `0 <= i < nx`,
/// `0 <= j < ny`, in empty space (a grid with `ny = 1` is a 1D grid along x at `y = 0`).
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaGrid {
    nx: usize,
    ny: usize,
    vertices: Vec<Vertex>,
}

impl RgbaGrid {
    /// A grid of `nx * ny` vertices, row by row (x fastest). Each vertex is checked as in
    /// [`Vertex::new`].
    pub fn new(nx: usize, ny: usize, vertices: Vec<Vertex>) -> Result<Self> {
        let expected = nx.checked_mul(ny).filter(|&n| n > 0).ok_or_else(|| {
            Error::InvalidInput(format!("grid dimensions {nx} x {ny} are empty or overflow"))
        })?;
        if vertices.len() != expected {
            return Err(Error::InvalidInput(format!(
                "grid {nx} x {ny} needs {expected} vertices, got {}",
                vertices.len()
            )));
        }
        for (i, v) in vertices.iter().enumerate() {
            Vertex::new(v.colour, v.tau)
                .map_err(|e| Error::InvalidInput(format!("vertex {i}: {e}")))?;
        }
        Ok(Self { nx, ny, vertices })
    }

    /// The grid's dimensions `(nx, ny)`.
    pub fn dims(&self) -> (usize, usize) {
        (self.nx, self.ny)
    }

    /// The vertex at `(i, j)`, [`Vertex::EMPTY`] outside the grid.
    pub fn vertex(&self, i: i64, j: i64) -> Vertex {
        if i < 0 || j < 0 || i as u64 >= self.nx as u64 || j as u64 >= self.ny as u64 {
            return Vertex::EMPTY;
        }
        self.vertices[j as usize * self.nx + i as usize]
    }

    /// The four vertices around `p` with their bilinear weights (which sum to 1).
    fn corners(&self, p: DVec2) -> [(f64, Vertex); 4] {
        let (fx, fy) = (p.x.floor(), p.y.floor());
        let (u, v) = (p.x - fx, p.y - fy);
        let (i, j) = (fx as i64, fy as i64);
        [
            ((1.0 - u) * (1.0 - v), self.vertex(i, j)),
            (u * (1.0 - v), self.vertex(i.saturating_add(1), j)),
            ((1.0 - u) * v, self.vertex(i, j.saturating_add(1))),
            (u * v, self.vertex(i.saturating_add(1), j.saturating_add(1))),
        ]
    }

    /// The continuous model at `p`, in f64: bilinear extinction and bilinear extinction-weighted
    /// colour (the emitted colour `g = C tau` of the paper's Eq. 1).
    pub fn extinction_at(&self, p: DVec2) -> (f64, [f64; 3]) {
        let mut tau = 0.0;
        let mut g = [0.0; 3];
        for (w, v) in self.corners(p) {
            let t = w * v.tau as f64;
            tau += t;
            for (gc, c) in g.iter_mut().zip(v.colour.to_array()) {
                *gc += t * c as f64;
            }
        }
        (tau, g)
    }
}

/// A straight ray through a grid: samples and the exact integral run from `origin` (the camera
/// side, composited first) over `length` units along the unit `direction`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GridRay {
    origin: DVec2,
    direction: DVec2,
    length: f64,
}

impl GridRay {
    /// A ray from `origin` along `direction` (normalised here; must be non-zero) for `length`
    /// units (finite, > 0).
    pub fn new(origin: DVec2, direction: DVec2, length: f64) -> Result<Self> {
        if !origin.is_finite() {
            return Err(Error::InvalidInput(format!(
                "ray origin {origin:?} is not finite"
            )));
        }
        let direction = direction.try_normalize().ok_or_else(|| {
            Error::InvalidInput(format!("ray direction {direction:?} is unusable"))
        })?;
        if !(length.is_finite() && length > 0.0) {
            return Err(Error::InvalidInput(format!(
                "ray length {length} must be finite and > 0"
            )));
        }
        Ok(Self {
            origin,
            direction,
            length,
        })
    }

    /// The point at distance `t` from the origin.
    pub fn at(&self, t: f64) -> DVec2 {
        self.origin + t * self.direction
    }

    /// The ray's length.
    pub fn length(&self) -> f64 {
        self.length
    }
}

/// Which distance the opacities of [`Model::OpacityBased`] are given for.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum ReferenceDistance {
    /// `d0 = d`: no opacity correction (the paper's choice for Figure 4 and Figures 5-6).
    Sampling,
    /// A fixed `d0` (finite, > 0), corrected for each sampling distance.
    Fixed(f32),
}

/// A sampling model for pre-classified RGBA data.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Model {
    /// Interpolate opacity-weighted colour and the opacity of `d0`, then opacity correction.
    OpacityBased(ReferenceDistance),
    /// Interpolate extinction-weighted colour and extinction.
    ExtinctionBased,
}

impl Model {
    /// Opacity-based sampling with `d0 = d` (the paper's set-up).
    pub const OPACITY: Model = Model::OpacityBased(ReferenceDistance::Sampling);
    /// Extinction-based sampling.
    pub const EXTINCTION: Model = Model::ExtinctionBased;

    /// A short name for tables: `opacity`, `opacity(d0=1)`, `extinction`.
    pub fn label(&self) -> String {
        match self {
            Model::OpacityBased(ReferenceDistance::Sampling) => "opacity".into(),
            Model::OpacityBased(ReferenceDistance::Fixed(d0)) => format!("opacity(d0={d0})"),
            Model::ExtinctionBased => "extinction".into(),
        }
    }

    fn check(&self) -> Result<()> {
        match self {
            Model::OpacityBased(ReferenceDistance::Fixed(d0)) if !(d0.is_finite() && *d0 > 0.0) => {
                Err(Error::InvalidInput(format!(
                    "reference distance d0 = {d0} must be finite and > 0"
                )))
            }
            _ => Ok(()),
        }
    }

    /// The non-weighted colour and the opacity of one sample at `p` for sampling distance `d`.
    fn sample(&self, grid: &RgbaGrid, p: DVec2, d: f32) -> (Vec3, f32) {
        let corners = grid.corners(p);
        match *self {
            Model::ExtinctionBased => {
                let (mut tau, mut weighted) = (0.0f32, Vec3::ZERO);
                for (w, v) in corners {
                    let t = w as f32 * v.tau;
                    tau += t;
                    weighted += t * v.colour;
                }
                let colour = if tau > 0.0 {
                    weighted / tau
                } else {
                    Vec3::ZERO
                };
                (colour, extinction_opacity(tau, d))
            }
            Model::OpacityBased(reference) => {
                let d0 = match reference {
                    ReferenceDistance::Sampling => d,
                    ReferenceDistance::Fixed(d0) => d0,
                };
                let (mut alpha0, mut weighted) = (0.0f32, Vec3::ZERO);
                for (w, v) in corners {
                    let a = w as f32 * extinction_opacity(v.tau, d0);
                    alpha0 += a;
                    weighted += a * v.colour;
                }
                if alpha0 <= 0.0 {
                    return (Vec3::ZERO, 0.0);
                }
                // Eq. 17 scales the weighted colour by alpha / alpha0; `composite` takes the
                // non-weighted colour and multiplies by alpha itself.
                (weighted / alpha0, correct_opacity(alpha0.min(1.0), d / d0))
            }
        }
    }
}

fn check_distance(d: f32) -> Result<()> {
    if d.is_finite() && d > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "sampling distance {d} must be finite and > 0"
        )))
    }
}

/// Samples `ray` every `d` units at `t = phase + k d` (every integer `k` with `0 <= t <= length`)
/// with `model` and composites front to back. Returns the accumulator: premultiplied colour and
/// opacity.
pub fn integrate(grid: &RgbaGrid, ray: &GridRay, model: Model, d: f32, phase: f64) -> Result<Vec4> {
    check_distance(d)?;
    model.check()?;
    if !phase.is_finite() {
        return Err(Error::InvalidInput(format!(
            "sample phase {phase} is not finite"
        )));
    }
    let step = d as f64;
    if ray.length / step > MAX_SAMPLES {
        return Err(Error::InvalidInput(format!(
            "{} samples of d = {d} along a ray of length {} exceed {MAX_SAMPLES}",
            ray.length / step,
            ray.length
        )));
    }
    let first = (-phase / step).ceil();
    if !first.is_finite() || first.abs() > 1e15 {
        return Err(Error::InvalidInput(format!(
            "sample phase {phase} is too far from the ray for d = {d}"
        )));
    }
    let mut acc = Vec4::ZERO;
    let mut k = first;
    loop {
        let t = phase + k * step;
        if t > ray.length {
            break;
        }
        if t >= 0.0 {
            let (colour, alpha) = model.sample(grid, ray.at(t), d);
            acc = composite(acc, colour, alpha);
        }
        k += 1.0;
    }
    Ok(acc)
}

/// The exact integral of a ray through the continuous model ([`RgbaGrid::extinction_at`]).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Exact {
    /// Premultiplied colour (r, g, b) and opacity, background black.
    pub rgba: [f64; 4],
    /// `|result(h) - result(h / 2)|`, largest component: an upper estimate of the remaining
    /// error (the scheme is second order, so the error of the returned `h / 2` result is about a
    /// third of it).
    pub error_estimate: f64,
    /// Steps of the returned (finer) integration.
    pub steps: usize,
}

fn integrate_fine(grid: &RgbaGrid, ray: &GridRay, steps: usize) -> [f64; 4] {
    let h = ray.length / steps as f64;
    let (mut transmittance, mut colour) = (1.0f64, [0.0f64; 3]);
    for i in 0..steps {
        let (tau, g) = grid.extinction_at(ray.at((i as f64 + 0.5) * h));
        // Eq. 2: a segment of constant tau and colour g / tau, integrated exactly.
        let segment = -(-tau * h).exp_m1();
        for (c, gc) in colour.iter_mut().zip(g) {
            *c += if tau > 0.0 {
                transmittance * gc / tau * segment
            } else {
                transmittance * gc * h
            };
        }
        transmittance *= 1.0 - segment;
    }
    [colour[0], colour[1], colour[2], 1.0 - transmittance]
}

/// The ground truth of a ray: the emission-absorption integral of the continuous model,
/// integrated with [`EXACT_STEPS_PER_UNIT`] midpoint segments per unit and with twice as many; the
/// finer result is returned, their difference is the error estimate.
pub fn exact(grid: &RgbaGrid, ray: &GridRay) -> Result<Exact> {
    let coarse = (ray.length * EXACT_STEPS_PER_UNIT).ceil();
    if coarse > 5e7 {
        return Err(Error::InvalidInput(format!(
            "ray of length {} is too long for the exact integral",
            ray.length
        )));
    }
    let coarse = coarse.max(1.0) as usize;
    let a = integrate_fine(grid, ray, coarse);
    let b = integrate_fine(grid, ray, 2 * coarse);
    let error_estimate = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    Ok(Exact {
        rgba: b,
        error_estimate,
        steps: 2 * coarse,
    })
}

/// One of the paper's set-ups: a grid, a ray through it, and where the samples' phase is
/// measured from.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    /// The pre-classified grid.
    pub grid: RgbaGrid,
    /// The ray, origin on the camera side.
    pub ray: GridRay,
    /// Distance along the ray of the filled vertex (column) the phase `r` is measured from.
    pub vertex_t: f64,
    /// The closed-form exact result (premultiplied colour and opacity, black background):
    /// the ray crosses a hat of extinction `tau_max` whose integral is `tau_max`, and its colour
    /// is 1 wherever the extinction is non-zero, so colour and opacity both equal
    /// `1 - exp(-tau_max)`.
    pub exact: [f64; 4],
}

fn filled(tau: f32) -> Result<Vertex> {
    Vertex::new(Vec3::ONE, tau)
}

fn closed_form(tau: f32) -> [f64; 4] {
    let a = -(-(tau as f64)).exp_m1();
    [a, a, a, a]
}

/// The paper's Figure 1: a 5 x 2 grid, the middle column (x = 2) filled with `C = 1`,
/// `tau = tau_max`, the rest empty; the ray runs along y = 0.5 from x = 0 (the camera on the left)
/// to x = 4. `tau_max` must be finite and >= 0.
pub fn figure1(tau_max: f32) -> Result<Setup> {
    let f = filled(tau_max)?;
    let e = Vertex::EMPTY;
    let row = [e, e, f, e, e];
    let vertices = row.iter().chain(row.iter()).copied().collect();
    Ok(Setup {
        grid: RgbaGrid::new(5, 2, vertices)?,
        ray: GridRay::new(DVec2::new(0.0, 0.5), DVec2::X, 4.0)?,
        vertex_t: 2.0,
        exact: closed_form(tau_max),
    })
}

/// The one-voxel-thick wall of the paper's Figures 5 and 6 along the ray perpendicular to it: a
/// 1D grid of 5 vertices, the middle one filled with `C = 1`, `tau` (finite, >= 0); the ray runs
/// along the grid from x = 0 to x = 4.
pub fn wall(tau: f32) -> Result<Setup> {
    let f = filled(tau)?;
    let e = Vertex::EMPTY;
    Ok(Setup {
        grid: RgbaGrid::new(5, 1, vec![e, e, f, e, e])?,
        ray: GridRay::new(DVec2::ZERO, DVec2::X, 4.0)?,
        vertex_t: 2.0,
        exact: closed_form(tau),
    })
}

/// Deviations of one model at one sampling distance from the exact result, over sample phases
/// `r = d j / phases`, `j = 0 .. phases` (so `r` covers [0, d), every offset the samples can have
/// relative to the filled vertex).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DeviationStats {
    /// Largest deviation over the phases: the largest absolute difference of any of colour
    /// (r, g, b) and opacity from the exact result.
    pub max: f64,
    /// Mean of the per-phase deviations.
    pub mean: f64,
    /// Smallest ray opacity over the phases.
    pub min_alpha: f32,
    /// Largest ray opacity over the phases.
    pub max_alpha: f32,
    /// Phases whose result had a NaN or infinite component (then left out of the other fields).
    pub non_finite: usize,
}

/// Sweeps the phase `r` over [0, d) for `setup` and returns the deviation statistics of `model` at
/// sampling distance `d` against `exact`. `phases` must be >= 1.
pub fn deviation(
    setup: &Setup,
    model: Model,
    d: f32,
    exact: [f64; 4],
    phases: usize,
) -> Result<DeviationStats> {
    check_distance(d)?;
    if phases == 0 {
        return Err(Error::InvalidInput(
            "at least one sample phase is needed".into(),
        ));
    }
    let mut stats = DeviationStats {
        max: 0.0,
        mean: 0.0,
        min_alpha: f32::INFINITY,
        max_alpha: f32::NEG_INFINITY,
        non_finite: 0,
    };
    let mut sum = 0.0;
    for j in 0..phases {
        let r = d as f64 * j as f64 / phases as f64;
        let got = integrate(&setup.grid, &setup.ray, model, d, setup.vertex_t + r)?;
        if !got.is_finite() {
            stats.non_finite += 1;
            continue;
        }
        let dev = got
            .to_array()
            .iter()
            .zip(exact)
            .map(|(&g, e)| (g as f64 - e).abs())
            .fold(0.0, f64::max);
        stats.max = stats.max.max(dev);
        sum += dev;
        stats.min_alpha = stats.min_alpha.min(got.w);
        stats.max_alpha = stats.max_alpha.max(got.w);
    }
    let finite = phases - stats.non_finite;
    if finite > 0 {
        stats.mean = sum / finite as f64;
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_weights_reproduce_vertices_and_vanish_outside() {
        let s = figure1(3.0).unwrap();
        assert_eq!(s.grid.extinction_at(DVec2::new(2.0, 0.0)).0, 3.0);
        assert_eq!(s.grid.extinction_at(DVec2::new(2.0, 0.5)).0, 3.0);
        assert!((s.grid.extinction_at(DVec2::new(2.25, 0.3)).0 - 2.25).abs() < 1e-12);
        assert_eq!(s.grid.extinction_at(DVec2::new(1.0, 0.5)).0, 0.0);
        // Outside the grid everything is empty, also at absurd coordinates.
        assert_eq!(s.grid.extinction_at(DVec2::new(-1e30, 7e300)).0, 0.0);
        assert_eq!(s.grid.extinction_at(DVec2::new(2.0, 1.5)).0, 1.5);
    }

    #[test]
    fn figure1_is_independent_of_the_ray_height() {
        // Both rows are equal, so the ray's height between them does not matter.
        let mut s = figure1(4.0).unwrap();
        let base = integrate(&s.grid, &s.ray, Model::OPACITY, 0.7, 2.3).unwrap();
        for y in [0.0, 0.1, 0.9, 1.0] {
            s.ray = GridRay::new(DVec2::new(0.0, y), DVec2::X, 4.0).unwrap();
            let got = integrate(&s.grid, &s.ray, Model::OPACITY, 0.7, 2.3).unwrap();
            assert!(
                (got - base).abs().max_element() < 1e-6,
                "y={y}: {got} vs {base}"
            );
        }
    }

    #[test]
    fn models_agree_with_hand_computation() {
        // d = 1 and r = 0: one sample on the filled column, weight 1.
        let s = figure1(2.0).unwrap();
        let expected = 1.0 - (-2.0f32).exp();
        for model in [Model::OPACITY, Model::EXTINCTION] {
            let got = integrate(&s.grid, &s.ray, model, 1.0, 2.0).unwrap();
            assert!((got.w - expected).abs() < 1e-6, "{model:?}: {got}");
        }
        // d = 1, r = 0.5: two samples of weight 1/2. Opacity-based: 1 - (1 - a/2)^2 with
        // a = 1 - e^-2; extinction-based: 1 - e^-(2 * 0.5) twice = 1 - e^-2 (exact).
        let a = 1.0 - (-2.0f32).exp();
        let op = integrate(&s.grid, &s.ray, Model::OPACITY, 1.0, 2.5).unwrap();
        assert!(
            (op.w - (1.0 - (1.0 - a / 2.0).powi(2))).abs() < 1e-6,
            "{op}"
        );
        let ex = integrate(&s.grid, &s.ray, Model::EXTINCTION, 1.0, 2.5).unwrap();
        assert!((ex.w - expected).abs() < 1e-6, "{ex}");
        // Fixed d0 = 2 at d = 1: alpha0 = 1 - e^-4, corrected to 1 - e^-2 at a vertex.
        let fixed = Model::OpacityBased(ReferenceDistance::Fixed(2.0));
        let got = integrate(&s.grid, &s.ray, fixed, 1.0, 2.0).unwrap();
        assert!((got.w - expected).abs() < 1e-6, "{got}");
    }

    #[test]
    fn bad_input_is_an_error() {
        assert!(Vertex::new(Vec3::ONE, -1.0).is_err());
        assert!(Vertex::new(Vec3::ONE, f32::INFINITY).is_err());
        assert!(Vertex::new(Vec3::splat(1.5), 1.0).is_err());
        assert!(Vertex::new(Vec3::new(f32::NAN, 0.0, 0.0), 1.0).is_err());
        assert!(RgbaGrid::new(0, 3, vec![]).is_err());
        assert!(RgbaGrid::new(usize::MAX, 3, vec![]).is_err());
        assert!(RgbaGrid::new(2, 2, vec![Vertex::EMPTY; 3]).is_err());
        let bad = Vertex {
            colour: Vec3::ONE,
            tau: f32::NAN,
        };
        assert!(RgbaGrid::new(1, 1, vec![bad]).is_err());
        assert!(figure1(f32::NAN).is_err());
        assert!(wall(-2.0).is_err());
        assert!(GridRay::new(DVec2::ZERO, DVec2::ZERO, 1.0).is_err());
        assert!(GridRay::new(DVec2::ZERO, DVec2::X, 0.0).is_err());
        assert!(GridRay::new(DVec2::ZERO, DVec2::new(f64::NAN, 1.0), 1.0).is_err());
        assert!(GridRay::new(DVec2::new(f64::INFINITY, 0.0), DVec2::X, 1.0).is_err());
        let s = figure1(1.0).unwrap();
        for d in [0.0, -1.0, f32::NAN, f32::INFINITY, 1e-9] {
            assert!(
                integrate(&s.grid, &s.ray, Model::EXTINCTION, d, 0.0).is_err(),
                "d={d}"
            );
        }
        assert!(integrate(&s.grid, &s.ray, Model::EXTINCTION, 0.5, f64::NAN).is_err());
        assert!(integrate(&s.grid, &s.ray, Model::EXTINCTION, 0.5, 1e300).is_err());
        for d0 in [0.0, -1.0, f32::NAN] {
            let m = Model::OpacityBased(ReferenceDistance::Fixed(d0));
            assert!(integrate(&s.grid, &s.ray, m, 0.5, 0.0).is_err(), "d0={d0}");
        }
        assert!(deviation(&s, Model::OPACITY, 0.5, s.exact, 0).is_err());
        let long = GridRay::new(DVec2::ZERO, DVec2::X, 1e12).unwrap();
        assert!(exact(&s.grid, &long).is_err());
        let options = KrausOptions {
            distances: vec![0.5, f32::NAN],
            ..KrausOptions::default()
        };
        assert!(run(&options).is_err());
    }

    #[test]
    fn exact_integral_matches_the_closed_form() {
        for tau in [0.0f32, 1.0, 8.0] {
            let s = figure1(tau).unwrap();
            let e = exact(&s.grid, &s.ray).unwrap();
            for (got, want) in e.rgba.iter().zip(s.exact) {
                assert!((got - want).abs() < 1e-7, "tau={tau}: {got} vs {want}");
            }
            assert!(e.error_estimate < 1e-6, "tau={tau}: {}", e.error_estimate);
        }
    }

    #[test]
    fn labels() {
        assert_eq!(Model::OPACITY.label(), "opacity");
        assert_eq!(Model::EXTINCTION.label(), "extinction");
        assert_eq!(
            Model::OpacityBased(ReferenceDistance::Fixed(1.0)).label(),
            "opacity(d0=1)"
        );
    }
}
