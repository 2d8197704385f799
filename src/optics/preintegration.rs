//! Pre-integrated classification (Engel, Kraus and Ertl 2001, "High-quality pre-integrated
//! volume rendering using hardware-accelerated pixel shading"): a [`TF_SIZE`] x [`TF_SIZE`] table
//! holding, for every pair of transfer-function positions (front, back), the premultiplied
//! colour and the opacity of one ray segment along which the position runs linearly from front
//! to back. A ray-caster composites one table lookup per segment (the positions at its two ends)
//! instead of one classified sample, which resolves thin features of the transfer function at
//! any step size.
//!
//! # The model
//!
//! A segment is `L = ratio` reference lengths d0 long; its TF position runs linearly from `sf`
//! to `sb`. Along it the extinction per d0 is `tau(s) = table.extinction(table.lookup(s).w)` and
//! the emitted colour `c(s) = sample_colour(table.lookup(s))` (continuous emission-absorption,
//! the classification table's interpolation between entry centres taken as exact), with one
//! exception: for [`SamplingModel::Opacity`] the extinction `-ln(1 - alpha)` is not capped at
//! [`MAX_EXTINCTION`](super::MAX_EXTINCTION), so opacity 1 is opaque over any length, as in the
//! per-sample model ([`correct_opacity`](super::correct_opacity)):
//!
//! ```text
//! A = 1 - exp(-D(L)),   C = int_0^L tau(t) c(t) exp(-D(t)) dt,   D(t) = int_0^t tau.
//! ```
//!
//! # The method
//!
//! Entry positions are `s_i = i / (TF_SIZE - 1)`, so an entry's segment crosses whole *pieces*
//! (intervals between neighbouring entry positions) of the table, `|j - i|` of them, each over
//! the same length `L / |j - i|`. Within a piece the coefficient `w` and the weighted colour
//! `q` (colour times coefficient) are linear in the position, so:
//!
//! - the optical depth of any part of a piece has a closed form: `w` averaged
//!   ([`SamplingModel::Extinction`]), or the mean of `-ln(1 - alpha)` over a linear `alpha`,
//!   `1 - ln(1 - alpha_lo) - ln1p(x) / x` with `x = (alpha_hi - alpha_lo) / (1 - alpha_hi)`
//!   evaluated without cancellation ([`SamplingModel::Opacity`]);
//! - the colour integral is split into sub-steps of optical depth at most `0.5 (1 + D / 4)`,
//!   `D` the depth in front of the sub-step within the piece (its errors are weighted by
//!   `exp(-D)`), and, for the opacity model, of `1 - alpha` changing by at most a factor 2 down to
//!   1e-5 of the piece's change, which grades the sub-steps towards the logarithmic singularity
//!   of an opaque entry. On a sub-step the colour at its middle, `c_m`, is integrated exactly,
//!   `c_m (1 - exp(-dD))`, and the remainder `int (q - c_m w) phi(w) exp(-D)` (`phi = tau / w`,
//!   smooth, 1 for the extinction model) by 4-point Gauss-Legendre. The split makes constant
//!   colour exact whatever the extinction does, and leaves a small, smooth integrand to the
//!   quadrature. Pieces of constant coefficient have a closed form; integration stops once the
//!   depth inside a piece passes 30 (`exp(-30) = 1e-13`). Against sub-steps 25 times finer the
//!   entries agree to 2e-7 (f32 rounding).
//!
//! All entries on one diagonal `j - i = d` cross the same pieces at the same length, so the
//! pieces are integrated once per diagonal and direction (`2 * 255 * 255` piece integrals in
//! all, not one per entry and piece) and composited front to back ("over", associative) into
//! every window of `|d|` consecutive pieces with the two-stack sliding-window scheme: O(1)
//! compositions per entry, no subtraction anywhere. Depths add up exactly and the opacity is
//! `-expm1(-D)`, so tiny opacities keep their relative accuracy. Accumulation is in `f64`;
//! diagonals are spread over the available cores.

use super::OpticsError;
use super::{ClassificationTable, SamplingModel, TF_SIZE};

type Result<T, E = OpticsError> = std::result::Result<T, E>;
use glam::{DVec3, Vec4};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Pieces of the table: intervals between neighbouring entry positions.
const PIECES: usize = TF_SIZE - 1;

/// Depth inside a piece past which the rest of it cannot add colour (`exp(-30) = 1e-13`).
const CUTOFF_DEPTH: f64 = 30.0;

/// Sub-steps one piece may take at most (a guard for absurd ratios; never reached in practice).
const MAX_SUB_STEPS: usize = 1 << 16;

/// Gauss-Legendre nodes and weights on [0, 1], 4 points.
const GAUSS4: [(f64, f64); 4] = [
    (0.069_431_844_202_973_71, 0.173_927_422_568_726_93),
    (0.330_009_478_207_571_87, 0.326_072_577_431_273_07),
    (0.669_990_521_792_428_1, 0.326_072_577_431_273_07),
    (0.930_568_155_797_026_3, 0.173_927_422_568_726_93),
];

/// How finely pieces are sub-divided.
#[derive(Clone, Copy, Debug)]
struct Accuracy {
    /// Largest optical depth of one sub-step at the front of a piece.
    max_depth: f64,
    /// Growth of that limit with the depth `D` in front of the sub-step: `max_depth * (1 +
    /// growth * D)` (errors there are weighted by `exp(-D)`).
    growth: f64,
    /// Largest ratio of `1 - alpha` between a sub-step's ends (opacity model).
    max_ratio: f64,
    /// Fraction of a piece's opacity change below which `1 - alpha` is no longer graded
    /// towards 0 (the colour is constant to this fraction across the last sliver).
    sliver: f64,
    /// Quadrature for the colour remainder on a sub-step.
    gauss: &'static [(f64, f64)],
}

const DEFAULT_ACCURACY: Accuracy = Accuracy {
    max_depth: 0.5,
    growth: 0.25,
    max_ratio: 2.0,
    sliver: 1e-5,
    gauss: &GAUSS4,
};

/// A pre-integrated classification table: for TF positions `(front, back)` on the entry grid,
/// the premultiplied colour (RGB) and opacity (A) of a ray segment [`ratio`](Self::ratio)
/// reference lengths long along which the position runs linearly from front to back (see the
/// module documentation for the model). Built from a [`ClassificationTable`]; rebuild it when the
/// transfer function, the sampling model or the step changes.
#[derive(Clone, Debug, PartialEq)]
pub struct PreintegrationTable {
    ratio: f32,
    model: SamplingModel,
    entries: Vec<Vec4>,
}

impl PreintegrationTable {
    /// Table for segments `ratio` reference lengths long (`ratio = step / d0`, finite and
    /// positive; an error otherwise).
    pub fn build(table: &ClassificationTable, ratio: f32) -> Result<Self> {
        Self::build_with(table, ratio, &DEFAULT_ACCURACY)
    }

    fn build_with(table: &ClassificationTable, ratio: f32, accuracy: &Accuracy) -> Result<Self> {
        if !(ratio.is_finite() && ratio > 0.0) {
            return Err(OpticsError(format!(
                "pre-integration needs a finite, positive step ratio, got {ratio}"
            )));
        }
        let model = table.model();
        let length = f64::from(ratio);
        let w: Vec<f64> = table.entries().iter().map(|e| f64::from(e.w)).collect();
        let q: Vec<DVec3> = table
            .entries()
            .iter()
            .map(|e| e.truncate().as_dvec3())
            .collect();
        let colour = |i: usize| {
            if w[i] > 0.0 {
                q[i] / w[i]
            } else {
                DVec3::ZERO
            }
        };
        // Upper bound on any colour along any segment (colours are weighted means of entries).
        let max_colour = (0..TF_SIZE).fold(DVec3::ZERO, |m, i| m.max(colour(i)));

        let mut entries = vec![Vec4::ZERO; TF_SIZE * TF_SIZE];
        // Diagonal: constant classification along the segment.
        for i in 0..TF_SIZE {
            let depth = length * tau(model, w[i]);
            let segment = Segment::new(colour(i) * -(-depth).exp_m1(), depth);
            entries[i * TF_SIZE + i] = segment.entry(max_colour);
        }

        // Off-diagonals, one |back - front| per work item, heaviest (shortest) first.
        let next = AtomicUsize::new(1);
        let threads = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .clamp(1, 16);
        let diagonals: Vec<Diagonal> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..threads)
                .map(|_| {
                    scope.spawn(|| {
                        let mut done = Vec::new();
                        loop {
                            let d = next.fetch_add(1, Ordering::Relaxed);
                            if d > PIECES {
                                break done;
                            }
                            done.push(diagonal(model, &w, &q, length / d as f64, d, accuracy));
                        }
                    })
                })
                .collect();
            workers
                .into_iter()
                .flat_map(|h| h.join().expect("pre-integration worker panicked"))
                .collect()
        });
        for diag in diagonals {
            let d = diag.distance;
            for (front, segment) in diag.increasing.iter().enumerate() {
                entries[(front + d) * TF_SIZE + front] = segment.entry(max_colour);
            }
            for (k, segment) in diag.decreasing.iter().enumerate() {
                let front = PIECES - k;
                entries[(front - d) * TF_SIZE + front] = segment.entry(max_colour);
            }
        }
        Ok(Self {
            ratio,
            model,
            entries,
        })
    }

    /// Row-major entries (premultiplied RGB, opacity), `TF_SIZE * TF_SIZE` of them, index
    /// `back_index * TF_SIZE + front_index` (x = front, y = back): the layout of the RGBA32F 2D
    /// texture the GPU samples.
    pub fn entries(&self) -> &[Vec4] {
        &self.entries
    }

    /// The segment length the table is for, in reference lengths d0.
    pub fn ratio(&self) -> f32 {
        self.ratio
    }

    /// The sampling model of the classification table the table was built from.
    pub fn model(&self) -> SamplingModel {
        self.model
    }

    /// Bilinear lookup between entry centres at TF positions `(front, back)`, each clamped to
    /// [0, 1], as a linearly filtered 2D texture sampled at `(s * (TF_SIZE - 1) + 0.5) / TF_SIZE`
    /// does: [`ClassificationTable::lookup`] in 2D, weights computed the same way.
    pub fn lookup(&self, front: f32, back: f32) -> Vec4 {
        let (x0, x1, fx) = texel(front);
        let (y0, y1, fy) = texel(back);
        let row =
            |y: usize| self.entries[y * TF_SIZE + x0].lerp(self.entries[y * TF_SIZE + x1], fx);
        row(y0).lerp(row(y1), fy)
    }
}

/// Neighbouring entry indices and the weight of the second at TF position `s`, exactly as
/// [`ClassificationTable::lookup`] computes them.
fn texel(s: f32) -> (usize, usize, f32) {
    let x = s.clamp(0.0, 1.0) * (TF_SIZE - 1) as f32;
    let i0 = (x.floor() as usize).min(TF_SIZE - 1);
    let i1 = (i0 + 1).min(TF_SIZE - 1);
    (i0, i1, x - i0 as f32)
}

/// Extinction per d0 of coefficient `w`. The extinction model's coefficient is the extinction
/// (capped at [`MAX_EXTINCTION`](super::MAX_EXTINCTION) by the classification table). The opacity
/// model's is `-ln(1 - alpha)` *uncapped*, infinite at `alpha = 1`, so that a segment through
/// an opaque entry is opaque at any length, as [`correct_opacity`](super::correct_opacity) (the
/// per-sample opacity model) has it; [`ClassificationTable::extinction`]'s cap of 64 would make a
/// 0.01 d0 segment of opacity 1 only 47 % opaque.
fn tau(model: SamplingModel, w: f64) -> f64 {
    match model {
        SamplingModel::Extinction => w,
        SamplingModel::Opacity => {
            if w <= 0.0 {
                0.0
            } else if w >= 1.0 {
                f64::INFINITY
            } else {
                -(-w).ln_1p()
            }
        }
    }
}

/// `tau(w) / w` (its limit 1 at `w = 0`) given `t = tau(w)`: emission per unit weighted colour.
/// Only evaluated at quadrature nodes strictly inside a sub-step, where `alpha < 1` (bar
/// rounding, which the finite value of `-ln(f64::EPSILON / 2)` covers).
fn emission_factor(model: SamplingModel, w: f64, t: f64) -> f64 {
    match model {
        SamplingModel::Extinction => 1.0,
        SamplingModel::Opacity => {
            if w <= 0.0 {
                1.0
            } else if w >= 1.0 {
                -(f64::EPSILON / 2.0).ln()
            } else {
                t / w
            }
        }
    }
}

/// Mean extinction over a part of a piece whose coefficient runs linearly from `w0` to `w1`
/// (infinite only where the opacity model's alpha is 1 at both ends).
fn mean_tau(model: SamplingModel, w0: f64, w1: f64) -> f64 {
    mean_tau_with(model, w0, tau(model, w0), w1, tau(model, w1))
}

/// [`mean_tau`] with `tau0 = tau(w0)` and `tau1 = tau(w1)` at hand.
fn mean_tau_with(model: SamplingModel, w0: f64, tau0: f64, w1: f64, tau1: f64) -> f64 {
    match model {
        SamplingModel::Extinction => 0.5 * (w0 + w1),
        SamplingModel::Opacity => {
            let (lo, tau_lo, hi) = if w0 <= w1 {
                (w0, tau0, w1)
            } else {
                (w1, tau1, w0)
            };
            if hi >= 1.0 {
                if lo >= 1.0 {
                    return f64::INFINITY;
                }
                // int_0^v -ln(x) dx / v = 1 - ln v with v = 1 - lo (the singularity integrates).
                return 1.0 + tau_lo;
            }
            // (H(hi) - H(lo)) / (hi - lo), H(a) = (1 - a) ln(1 - a) + a, rearranged as
            // -ln(1 - lo) + g(x), g(x) = 1 - ln(1 + x) / x, x = (hi - lo) / (1 - hi): no
            // cancellation, relative accuracy for tiny opacities.
            let x = (hi - lo) / (1.0 - hi);
            let g = if x < 1e-3 {
                x * (0.5 - x * (1.0 / 3.0 - x * (0.25 - x * 0.2)))
            } else {
                1.0 - x.ln_1p() / x
            };
            tau_lo + g
        }
    }
}

/// Premultiplied colour and optical depth of a run of ray, with its transmittance.
#[derive(Clone, Copy, Debug)]
struct Segment {
    colour: DVec3,
    depth: f64,
    transmittance: f64,
}

impl Segment {
    fn new(colour: DVec3, depth: f64) -> Self {
        Self {
            colour,
            depth,
            transmittance: (-depth).exp(),
        }
    }

    /// Front-to-back "over": `self` in front of `back`.
    fn over(&self, back: &Segment) -> Segment {
        Segment {
            colour: self.colour + back.colour * self.transmittance,
            depth: self.depth + back.depth,
            transmittance: self.transmittance * back.transmittance,
        }
    }

    fn opacity(&self) -> f64 {
        -(-self.depth).exp_m1()
    }

    /// The table entry: opacity in [0, 1], colour in [0, opacity * max_colour].
    fn entry(&self, max_colour: DVec3) -> Vec4 {
        let opacity = self.opacity();
        let colour = self.colour.max(DVec3::ZERO).min(max_colour * opacity);
        colour.as_vec3().extend(opacity as f32)
    }
}

/// The entries of one diagonal `|back - front| = distance`.
struct Diagonal {
    distance: usize,
    /// Windows in increasing position, by front index (back = front + distance).
    increasing: Vec<Segment>,
    /// Windows in decreasing position, by `PIECES - front` (back = front - distance).
    decreasing: Vec<Segment>,
}

/// Integrates every piece over `length` reference lengths in both directions and composites the
/// windows of `distance` consecutive pieces.
fn diagonal(
    model: SamplingModel,
    w: &[f64],
    q: &[DVec3],
    length: f64,
    distance: usize,
    accuracy: &Accuracy,
) -> Diagonal {
    let mut up = Vec::with_capacity(PIECES);
    let mut down = Vec::with_capacity(PIECES);
    for p in 0..PIECES {
        let depth = length * mean_tau(model, w[p], w[p + 1]);
        let forward = Piece {
            model,
            wa: w[p],
            wb: w[p + 1],
            qa: q[p],
            qb: q[p + 1],
            length,
        };
        let backward = Piece {
            model,
            wa: w[p + 1],
            wb: w[p],
            qa: q[p + 1],
            qb: q[p],
            length,
        };
        up.push(Segment::new(forward.colour(accuracy), depth));
        down.push(Segment::new(backward.colour(accuracy), depth));
    }
    // Decreasing position: the front piece of front index i is piece i - 1.
    down.reverse();
    Diagonal {
        distance,
        increasing: windows(&up, distance),
        decreasing: windows(&down, distance),
    }
}

/// Every window of `len` consecutive segments composited front to back: blocks of `len`, each
/// window the suffix of one block over the prefix of the next (two-stack scheme).
fn windows(seq: &[Segment], len: usize) -> Vec<Segment> {
    let n = seq.len();
    let mut suffix = seq.to_vec();
    let mut prefix = seq.to_vec();
    for start in (0..n).step_by(len) {
        let end = (start + len).min(n);
        for k in (start..end - 1).rev() {
            suffix[k] = seq[k].over(&suffix[k + 1]);
        }
        for k in start + 1..end {
            prefix[k] = prefix[k - 1].over(&seq[k]);
        }
    }
    (0..=n - len)
        .map(|s| {
            if s % len == 0 {
                suffix[s]
            } else {
                suffix[s].over(&prefix[s + len - 1])
            }
        })
        .collect()
}

/// One piece of the table traversed from coefficient `wa` (weighted colour `qa`) to `wb` (`qb`)
/// over `length` reference lengths; positions along it are fractions `lam` in [0, 1].
struct Piece {
    model: SamplingModel,
    wa: f64,
    wb: f64,
    qa: DVec3,
    qb: DVec3,
    length: f64,
}

impl Piece {
    fn w(&self, lam: f64) -> f64 {
        if lam >= 1.0 {
            self.wb
        } else {
            self.wa + (self.wb - self.wa) * lam
        }
    }

    fn q(&self, lam: f64) -> DVec3 {
        self.qa + (self.qb - self.qa) * lam
    }

    /// Optical depth from `lam` (coefficient `w0`, extinction `tau0`) over `span`.
    fn depth(&self, lam: f64, w0: f64, tau0: f64, span: f64) -> f64 {
        let w1 = self.w(lam + span);
        self.length * span * mean_tau_with(self.model, w0, tau0, w1, tau(self.model, w1))
    }

    /// Largest span at most `span` from `lam` (coefficient `w0`, extinction `tau0`) whose depth
    /// stays within `max_depth`, and reaches a fair part of it where it is shorter than `span`.
    /// `graded`: the step keeps `1 - alpha` within the ratio `max_ratio`.
    fn depth_limited(
        &self,
        lam: f64,
        (w0, tau0): (f64, f64),
        span: f64,
        max_depth: f64,
        (graded, max_ratio): (bool, f64),
    ) -> f64 {
        if self.depth(lam, w0, tau0, span) <= max_depth {
            return span;
        }
        let dw = self.wb - self.wa;
        // Solve length * (tau0 x + slope x^2 / 2) = max_depth, slope bounding d tau / d lam.
        let slope = match self.model {
            SamplingModel::Extinction => dw,
            // d tau / d lam = dw / (1 - w) grows by at most max_ratio over a graded step.
            SamplingModel::Opacity if dw > 0.0 && graded => max_ratio * dw / (1.0 - w0),
            SamplingModel::Opacity if dw > 0.0 => {
                let f = |x: f64| self.depth(lam, w0, tau0, x);
                return solve_increasing(f, span, max_depth);
            }
            // Decreasing extinction: tau0 bounds it.
            SamplingModel::Opacity => 0.0,
        };
        let a = 0.5 * self.length * slope;
        let b = self.length * tau0;
        let x = if a > 0.0 {
            2.0 * max_depth / (b + (b * b + 4.0 * a * max_depth).sqrt())
        } else {
            max_depth / b
        };
        if x > 0.0 && x.is_finite() {
            x.min(span)
        } else {
            // Opaque at the start (tau0 infinite): only the depth itself can tell.
            solve_increasing(|x| self.depth(lam, w0, tau0, x), span, max_depth)
        }
    }

    /// `int_0^length tau c exp(-D)`: the premultiplied colour of the piece.
    fn colour(&self, accuracy: &Accuracy) -> DVec3 {
        let model = self.model;
        if model == SamplingModel::Opacity && self.wa >= 1.0 && self.wb >= 1.0 {
            // Opaque throughout (infinite depth): all of the colour is emitted at the front.
            return self.qa / self.wa;
        }
        let dw = self.wb - self.wa;
        if dw == 0.0 {
            // Constant extinction, colour linear along the piece: closed form.
            let depth = self.length * tau(model, self.wa);
            if depth <= 0.0 {
                return DVec3::ZERO;
            }
            let (ca, cb) = (self.qa / self.wa, self.qb / self.wb);
            // (1 - exp(-D) (1 + D)) / D: the weight of the colour's change.
            let shape = if depth < 1e-3 {
                depth * (0.5 - depth * (1.0 / 3.0 - depth * (0.125 - depth / 30.0)))
            } else {
                (1.0 - (-depth).exp() * (1.0 + depth)) / depth
            };
            return ca * -(-depth).exp_m1() + (cb - ca) * shape;
        }
        let sliver = accuracy.sliver * dw.abs();
        let (mut colour, mut depth, mut lam) = (DVec3::ZERO, 0.0f64, 0.0f64);
        let (mut w0, mut tau0) = (self.wa, tau(model, self.wa));
        for _ in 0..MAX_SUB_STEPS {
            if lam >= 1.0 || depth >= CUTOFF_DEPTH {
                break;
            }
            let rest = 1.0 - lam;
            let mut span = rest;
            let mut graded = true;
            if model == SamplingModel::Opacity {
                // Grade 1 - alpha geometrically towards 0 (the log singularity of -ln(1 - alpha)).
                let v0 = 1.0 - w0;
                let vb = 1.0 - self.wb;
                if dw > 0.0 {
                    let target = v0 / accuracy.max_ratio;
                    if target > vb.max(sliver) {
                        span = span.min((v0 - target) / dw);
                    } else {
                        graded = target <= vb;
                    }
                } else {
                    let target = v0.max(sliver) * accuracy.max_ratio;
                    if target < vb {
                        span = span.min((target - v0) / -dw);
                    }
                }
            }
            let max_depth = accuracy.max_depth * (1.0 + accuracy.growth * depth);
            span = self.depth_limited(
                lam,
                (w0, tau0),
                span,
                max_depth,
                (graded, accuracy.max_ratio),
            );
            let (lam1, w1) = if span >= rest {
                (1.0, self.wb)
            } else {
                (lam + span, self.w(lam + span))
            };
            if lam1 <= lam {
                break; // below f64 resolution: nothing left to resolve
            }
            let tau1 = tau(model, w1);
            let span = lam1 - lam;
            let len = self.length * span;
            let step_depth = len * mean_tau_with(model, w0, tau0, w1, tau1);
            // Colour at the middle integrated exactly, the (small, smooth) rest by quadrature.
            let mid = lam + 0.5 * span;
            let w_mid = self.w(mid);
            let reference = if w_mid > 0.0 {
                self.q(mid) / w_mid
            } else {
                DVec3::ZERO
            };
            let mut step = reference * -(-step_depth).exp_m1();
            for &(x, g) in accuracy.gauss {
                let l = lam + x * span;
                let w = self.w(l);
                let t = tau(model, w);
                let d = len * x * mean_tau_with(model, w0, tau0, w, t);
                let rest_emission = (self.q(l) - reference * w) * emission_factor(model, w, t);
                step += rest_emission * (g * len * (-d).exp());
            }
            colour += step * (-depth).exp();
            depth += step_depth;
            lam = lam1;
            (w0, tau0) = (w1, tau1);
        }
        colour
    }
}

/// For `f` increasing with `f(0) = 0` and `f(hi) > target`: an `x` in (0, hi) with `f(x)` in
/// [target / 2, target] (power-law secant, bisection as fallback).
fn solve_increasing(f: impl Fn(f64) -> f64, hi: f64, target: f64) -> f64 {
    let (mut lo, mut f_lo, mut hi, mut f_hi) = (0.0, 0.0, hi, f(hi));
    for _ in 0..200 {
        let aim = 0.75 * target;
        let guess = if lo > 0.0 && f_lo > 0.0 {
            let p = (f_hi / f_lo).ln() / (hi / lo).ln();
            lo * (aim / f_lo).powf(1.0 / p)
        } else {
            hi * aim / f_hi
        };
        let x = if guess > lo && guess < hi && guess.is_finite() {
            guess
        } else {
            0.5 * (lo + hi)
        };
        let fx = f(x);
        if fx > target {
            (hi, f_hi) = (x, fx);
        } else if fx >= 0.5 * target {
            return x;
        } else {
            (lo, f_lo) = (x, fx);
        }
    }
    if lo > 0.0 {
        lo
    } else {
        hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::{sample_colour, TfPreset, TransferFunction};
    use glam::Vec3;

    const MODELS: [SamplingModel; 2] = [SamplingModel::Opacity, SamplingModel::Extinction];

    fn pos(i: usize) -> f32 {
        i as f32 / PIECES as f32
    }

    fn entry(t: &PreintegrationTable, front: usize, back: usize) -> Vec4 {
        t.entries()[back * TF_SIZE + front]
    }

    fn points(points: &[(f32, Vec4)], model: SamplingModel) -> ClassificationTable {
        ClassificationTable::new(
            &TransferFunction::from_control_points(points).unwrap(),
            model,
        )
    }

    /// A transfer function with an opaque plateau (alpha = 1 over [0.3, 0.6]).
    fn opaque_tf() -> TransferFunction {
        TransferFunction::from_control_points(&[
            (0.0, Vec4::new(0.0, 0.0, 1.0, 0.0)),
            (0.2, Vec4::new(0.2, 0.4, 1.0, 0.05)),
            (0.3, Vec4::new(1.0, 1.0, 1.0, 1.0)),
            (0.6, Vec4::new(1.0, 0.1, 0.0, 1.0)),
            (0.7, Vec4::new(0.5, 0.9, 0.1, 0.3)),
            (1.0, Vec4::new(0.1, 0.1, 0.1, 0.02)),
        ])
        .unwrap()
    }

    /// Deterministic pseudo-random numbers (no dev-dependencies).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn index(&mut self) -> usize {
            ((self.next() * TF_SIZE as f64) as usize).min(TF_SIZE - 1)
        }
    }

    fn random_tf(seed: u64) -> TransferFunction {
        let mut rng = Lcg(seed);
        let entries = (0..TF_SIZE)
            .map(|_| {
                let a = rng.next() as f32;
                // Mostly light, some dense entries, a few opaque ones.
                let alpha = match (rng.next() * 10.0) as u32 {
                    0 => 1.0,
                    1..=2 => a,
                    _ => 0.05 * a,
                };
                Vec4::new(
                    rng.next() as f32,
                    rng.next() as f32,
                    rng.next() as f32,
                    alpha,
                )
            })
            .collect();
        TransferFunction::from_entries(entries).unwrap()
    }

    /// Independent reference: `steps` steps of front-to-back compositing with per-step opacity
    /// correction, sampling the classification table at each step's middle. An opaque plateau
    /// (opacity-model coefficient 1 over a stretch: a hard surface in the per-sample model) ends
    /// the ray with the colour where it begins, found by bisection, after the partial step in
    /// front of it, so that the error stays O(1 / steps^2) there too.
    fn brute_force(t: &ClassificationTable, sf: f32, sb: f32, ratio: f32, steps: usize) -> Vec4 {
        let at = |x: f64| t.lookup((f64::from(sf) + f64::from(sb - sf) * x) as f32);
        let opaque = |x: f64| t.model() == SamplingModel::Opacity && at(x).w >= 1.0 - 1e-6;
        let n = steps as f64;
        let quarter_piece = 0.25 / PIECES as f64 / f64::from((sb - sf).abs()).max(1e-30);
        let (mut colour, mut alpha) = (DVec3::ZERO, 0.0f64);
        let mut composite = |c: Vec3, a: f64| {
            let weight = (1.0 - alpha) * a;
            colour += c.as_dvec3() * weight;
            alpha += weight;
        };
        for k in 0..steps {
            let (x0, x1) = (k as f64 / n, (k + 1) as f64 / n);
            // A plateau (not an isolated opaque entry): opaque at the step's end and a quarter of
            // a TF piece on.
            if opaque(x1) && opaque(x1 + quarter_piece) {
                let (mut lo, mut hi) = (x0, x1);
                if opaque(x0) {
                    hi = x0;
                } else {
                    for _ in 0..40 {
                        let mid = 0.5 * (lo + hi);
                        if opaque(mid) {
                            hi = mid;
                        } else {
                            lo = mid;
                        }
                    }
                }
                if hi > x0 {
                    let v = at(0.5 * (x0 + hi));
                    let a = t.sample_opacity(v.w, ratio * (hi - x0) as f32);
                    composite(sample_colour(v), f64::from(a));
                }
                composite(sample_colour(at(hi)), 1.0);
                break;
            }
            let v = at((k as f64 + 0.5) / n);
            // Off plateaus, opacity 1 is an isolated entry that a sample hits only by f32
            // rounding of its position: a point of no extent, not a surface.
            let w = if t.model() == SamplingModel::Opacity {
                v.w.min(1.0 - f32::EPSILON / 2.0)
            } else {
                v.w
            };
            composite(
                sample_colour(v),
                f64::from(t.sample_opacity(w, ratio / steps as f32)),
            );
        }
        colour.as_vec3().extend(alpha as f32)
    }

    /// No NaN, opacity in [0, 1], colour in [0, opacity * largest colour of the spanned entries].
    fn check_bounds(t: &ClassificationTable, pre: &PreintegrationTable) {
        let colours: Vec<Vec3> = t.entries().iter().map(|&e| sample_colour(e)).collect();
        for back in 0..TF_SIZE {
            let mut max_colour = Vec3::ZERO;
            for front in (0..=back).rev() {
                max_colour = max_colour.max(colours[front]);
                for (f, b) in [(front, back), (back, front)] {
                    let e = entry(pre, f, b);
                    assert!(e.is_finite(), "({f}, {b}): {e:?}");
                    assert!((0.0..=1.0).contains(&e.w), "({f}, {b}): {e:?}");
                    assert!(e.truncate().min_element() >= 0.0, "({f}, {b}): {e:?}");
                    let bound = max_colour * e.w * (1.0 + 1e-6) + Vec3::splat(1e-7);
                    assert!(
                        e.truncate().cmple(bound).all(),
                        "({f}, {b}): {e:?} above {bound:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn equal_positions_match_the_per_sample_model() {
        let (mut worst, mut worst_rel) = (0.0f32, 0.0f64);
        for model in MODELS {
            for tf in [
                TransferFunction::preset(TfPreset::Fire),
                TransferFunction::preset(TfPreset::Ct),
                opaque_tf(),
                random_tf(7),
            ] {
                let t = ClassificationTable::new(&tf, model);
                for ratio in [0.01f32, 0.25, 1.0, 3.7] {
                    let pre = PreintegrationTable::build(&t, ratio).unwrap();
                    for i in 0..TF_SIZE {
                        let w = t.entries()[i].w;
                        let a = t.sample_opacity(w, ratio);
                        let c = sample_colour(t.entries()[i]) * a;
                        let e = entry(&pre, i, i);
                        // Against the per-sample model (f32) ...
                        let err = (e - c.extend(a)).abs().max_element();
                        worst = worst.max(err);
                        assert!(err <= 1e-5, "{model:?} {ratio} {i}: {e:?} vs {c:?} {a}");
                        // ... and its opacity in f64, relatively (tiny opacities included).
                        let (w, r) = (f64::from(w), f64::from(ratio));
                        let exact = match model {
                            SamplingModel::Opacity if w >= 1.0 => 1.0,
                            SamplingModel::Opacity => -(r * (-w).ln_1p()).exp_m1(),
                            SamplingModel::Extinction => -(-r * w).exp_m1(),
                        };
                        let rel = if exact > 0.0 {
                            (f64::from(e.w) - exact).abs() / exact
                        } else {
                            f64::from(e.w)
                        };
                        worst_rel = worst_rel.max(rel);
                        assert!(rel <= 1e-6, "{model:?} {ratio} {i}: {e:?} vs {exact}");
                    }
                }
            }
        }
        eprintln!("equal positions: worst error {worst:e}, opacity relative {worst_rel:e}");
    }

    #[test]
    fn constant_extinction_gives_the_closed_form() {
        // Constant opacity, colour linear in s: c(t) = cf + (cb - cf) t / L, tau constant, so
        // C = cf A + (cb - cf) (1 - exp(-tau L) (1 + tau L)) / (tau L), A = 1 - exp(-tau L).
        let (c0, c1) = (Vec3::new(1.0, 0.2, 0.0), Vec3::new(0.0, 0.6, 1.0));
        let mut worst = 0.0f64;
        for model in MODELS {
            for alpha in [1e-4f32, 0.1, 0.7] {
                let t = points(&[(0.0, c0.extend(alpha)), (1.0, c1.extend(alpha))], model);
                let tau = f64::from(t.extinction(t.entries()[0].w));
                for ratio in [0.05f32, 1.0, 20.0] {
                    let pre = PreintegrationTable::build(&t, ratio).unwrap();
                    let depth = tau * f64::from(ratio);
                    let a = -(-depth).exp_m1();
                    let shape = if depth < 1e-4 {
                        depth / 2.0 - depth * depth / 3.0
                    } else {
                        (1.0 - (-depth).exp() * (1.0 + depth)) / depth
                    };
                    for (f, b) in [(0, 255), (255, 0), (3, 4), (200, 17), (90, 90), (0, 1)] {
                        let cf = c0.lerp(c1, pos(f)).as_dvec3();
                        let cb = c0.lerp(c1, pos(b)).as_dvec3();
                        let c = cf * a + (cb - cf) * shape;
                        let e = entry(&pre, f, b);
                        let err = (e.truncate().as_dvec3() - c)
                            .abs()
                            .max_element()
                            .max((f64::from(e.w) - a).abs() / a.max(1e-3));
                        worst = worst.max(err);
                        assert!(
                            err < 2e-6,
                            "{model:?} {alpha} {ratio} ({f},{b}): {e:?} vs {c:?} {a}"
                        );
                    }
                }
            }
        }
        eprintln!("constant extinction: worst error {worst:e}");
    }

    #[test]
    fn linear_extinction_gives_the_closed_form() {
        let colour = Vec3::new(0.8, 0.5, 0.2);
        let mut worst = 0.0f64;
        // Extinction model: tau linear in s, A = 1 - exp(-L (tau_f + tau_b) / 2).
        // (Extinctions stay below 3 so that the f32 opacities of the transfer function, from
        // which the table converts them back, keep them linear to ~1e-6.)
        for (tau0, tau1) in [(0.0f64, 3.0f64), (0.02, 0.001), (2.5, 1.0)] {
            let entries = (0..TF_SIZE)
                .map(|i| {
                    let s = i as f64 / PIECES as f64;
                    let tau = tau0 + (tau1 - tau0) * s;
                    colour.extend(-(-tau).exp_m1() as f32)
                })
                .collect();
            let tf = TransferFunction::from_entries(entries).unwrap();
            let t = ClassificationTable::new(&tf, SamplingModel::Extinction);
            for ratio in [0.1f32, 1.0, 7.0] {
                let pre = PreintegrationTable::build(&t, ratio).unwrap();
                for (f, b) in [(0, 255), (255, 0), (10, 11), (128, 30), (7, 250)] {
                    let tf_ = f64::from(t.entries()[f].w);
                    let tb = f64::from(t.entries()[b].w);
                    let a = -(-f64::from(ratio) * (tf_ + tb) / 2.0).exp_m1();
                    let e = entry(&pre, f, b);
                    let err = ((f64::from(e.w) - a).abs() / a.max(1e-3)).max(
                        (e.truncate().as_dvec3() - colour.as_dvec3() * a)
                            .abs()
                            .max_element(),
                    );
                    worst = worst.max(err);
                    assert!(err < 2e-6, "{tau0}..{tau1} {ratio} ({f},{b}): {e:?} vs {a}");
                }
            }
        }
        // Opacity model: alpha linear in s, tau = -ln(1 - alpha); the mean of tau over
        // [a0, a1] is (H(a1) - H(a0)) / (a1 - a0), H(a) = (1 - a) ln(1 - a) + a.
        let h = |a: f64| (1.0 - a) * (1.0 - a).ln() + a;
        for (a0, a1) in [(0.0f32, 0.9f32), (0.5, 0.05), (0.2, 0.6)] {
            let t = points(
                &[(0.0, colour.extend(a0)), (1.0, colour.extend(a1))],
                SamplingModel::Opacity,
            );
            for ratio in [0.3f32, 1.0, 5.0] {
                let pre = PreintegrationTable::build(&t, ratio).unwrap();
                for (f, b) in [(0, 255), (255, 0), (40, 200), (180, 20)] {
                    let af = f64::from(t.entries()[f].w);
                    let ab = f64::from(t.entries()[b].w);
                    let mean = (h(ab) - h(af)) / (ab - af);
                    let a = -(-f64::from(ratio) * mean).exp_m1();
                    let e = entry(&pre, f, b);
                    let err = (f64::from(e.w) - a).abs().max(
                        (e.truncate().as_dvec3() - colour.as_dvec3() * a)
                            .abs()
                            .max_element(),
                    );
                    worst = worst.max(err);
                    assert!(err < 2e-6, "{a0}..{a1} {ratio} ({f},{b}): {e:?} vs {a}");
                }
            }
        }
        eprintln!("linear extinction: worst error {worst:e}");
    }

    #[test]
    fn random_entries_match_brute_force_integration() {
        let mut rng = Lcg(12345);
        let mut worst = 0.0f32;
        for model in MODELS {
            for tf in [
                TransferFunction::preset(TfPreset::Fire),
                TransferFunction::preset(TfPreset::Bands),
                opaque_tf(),
                random_tf(99),
            ] {
                let t = ClassificationTable::new(&tf, model);
                for ratio in [0.3f32, 1.0, 4.0] {
                    let pre = PreintegrationTable::build(&t, ratio).unwrap();
                    for _ in 0..6 {
                        let (f, b) = (rng.index(), rng.index());
                        let reference = brute_force(&t, pos(f), pos(b), ratio, 100_000);
                        let e = entry(&pre, f, b);
                        let err = (e - reference).abs().max_element();
                        worst = worst.max(err);
                        assert!(
                            err < 1e-4,
                            "{model:?} {ratio} ({f},{b}): {e:?} vs {reference:?}"
                        );
                    }
                }
            }
        }
        eprintln!("brute force: worst error {worst:e}");
    }

    #[test]
    fn halves_composite_to_the_whole() {
        let over = |a: Vec4, b: Vec4| {
            (a.truncate() + b.truncate() * (1.0 - a.w)).extend(a.w + b.w * (1.0 - a.w))
        };
        let mut worst_exact = 0.0f32;
        let mut worst_linear = 0.0f32;
        for model in MODELS {
            // Split at an entry position: exact for any transfer function.
            for tf in [TransferFunction::preset(TfPreset::Fire), opaque_tf()] {
                let t = ClassificationTable::new(&tf, model);
                for ratio in [0.5f32, 2.0] {
                    let whole = PreintegrationTable::build(&t, ratio).unwrap();
                    let half = PreintegrationTable::build(&t, ratio / 2.0).unwrap();
                    for (f, b) in [(0, 254), (254, 0), (100, 140), (150, 90), (3, 5)] {
                        let m = (f + b) / 2;
                        let split = over(entry(&half, f, m), entry(&half, m, b));
                        let err = (split - entry(&whole, f, b)).abs().max_element();
                        worst_exact = worst_exact.max(err);
                        assert!(
                            err < 1e-5,
                            "{model:?} {ratio} ({f},{b}): {split:?} vs {:?}",
                            entry(&whole, f, b)
                        );
                    }
                }
            }
            // Split between entry positions (bilinear lookup) where the TF is linear.
            let t = points(
                &[
                    (0.0, Vec4::new(1.0, 0.3, 0.0, 0.02)),
                    (1.0, Vec4::new(0.1, 0.8, 1.0, 0.6)),
                ],
                model,
            );
            for ratio in [0.5f32, 2.0] {
                let whole = PreintegrationTable::build(&t, ratio).unwrap();
                let half = PreintegrationTable::build(&t, ratio / 2.0).unwrap();
                for (f, b) in [(0, 255), (255, 0), (100, 141), (151, 90), (3, 6)] {
                    let m = 0.5 * (pos(f) + pos(b));
                    let split = over(half.lookup(pos(f), m), half.lookup(m, pos(b)));
                    let err = (split - entry(&whole, f, b)).abs().max_element();
                    worst_linear = worst_linear.max(err);
                    assert!(
                        err < 1e-4,
                        "{model:?} {ratio} ({f},{b}): {split:?} vs {:?}",
                        entry(&whole, f, b)
                    );
                }
            }
        }
        eprintln!("halves: worst error {worst_exact:e} (at entries), {worst_linear:e} (bilinear)");
    }

    #[test]
    fn extremes_stay_finite_and_bounded() {
        for model in MODELS {
            for tf in [
                opaque_tf(),
                random_tf(3),
                TransferFunction::preset(TfPreset::ConstantWhite),
            ] {
                let t = ClassificationTable::new(&tf, model);
                for ratio in [1e-3f32, 1.0, 1e3] {
                    let pre = PreintegrationTable::build(&t, ratio).unwrap();
                    check_bounds(&t, &pre);
                }
            }
            let t = ClassificationTable::new(&opaque_tf(), model);
            // Inside the opaque plateau: opaque, and at 1e3 d0 the colour is the front colour.
            let pre = PreintegrationTable::build(&t, 1e3).unwrap();
            for (f, b) in [(80, 150), (150, 80), (100, 0), (120, 255)] {
                let e = entry(&pre, f, b);
                assert_eq!(e.w, 1.0);
                let c = sample_colour(t.entries()[f]);
                assert!(
                    (e.truncate() - c).abs().max_element() < 1e-4,
                    "({f},{b}): {e:?} vs {c:?}"
                );
            }
            for ratio in [1.0f32, 1e-3] {
                let pre = PreintegrationTable::build(&t, ratio).unwrap();
                // Entirely inside the plateau: as per sample (the opacity model: opaque at any
                // length, with the front colour; the extinction model: extinction 64 per d0).
                let e = entry(&pre, 90, 140);
                let a = t.sample_opacity(t.entries()[90].w, ratio);
                assert!(
                    (e.w - a).abs() <= 1e-6 * a,
                    "{model:?} {ratio}: {e:?} vs {a}"
                );
                if model == SamplingModel::Opacity {
                    assert_eq!(e.w, 1.0);
                    let c = sample_colour(t.entries()[90]);
                    assert!(
                        (e.truncate() - c).abs().max_element() < 1e-6,
                        "{e:?} vs {c:?}"
                    );
                }
                // Into and out of the plateau, against brute force.
                for (f, b) in [
                    (40, 90),
                    (90, 40),
                    (160, 200),
                    (200, 160),
                    (0, 255),
                    (255, 0),
                ] {
                    let reference = brute_force(&t, pos(f), pos(b), ratio, 100_000);
                    let e = entry(&pre, f, b);
                    assert!(
                        (e - reference).abs().max_element() < 1e-4,
                        "{model:?} {ratio} ({f},{b}): {e:?} vs {reference:?}"
                    );
                }
            }
            // Tiny opacities keep their relative accuracy.
            let faint = points(&[(0.0, Vec4::new(1.0, 1.0, 1.0, 1e-6))], model);
            let pre = PreintegrationTable::build(&faint, 1e-3).unwrap();
            let e = entry(&pre, 0, 255);
            let a = -(-1e-3 * -(-1e-6f64).ln_1p()).exp_m1();
            assert!(((f64::from(e.w) - a) / a).abs() < 1e-6, "{e:?} vs {a}");
        }
        // Absurdly long segments: still finite, opaque where anything is there, and quick.
        for model in MODELS {
            let t = ClassificationTable::new(&random_tf(21), model);
            let pre = PreintegrationTable::build(&t, f32::MAX).unwrap();
            check_bounds(&t, &pre);
        }
        let t = ClassificationTable::new(&opaque_tf(), SamplingModel::Opacity);
        for bad in [0.0f32, -1.0, f32::NAN, f32::INFINITY] {
            assert!(PreintegrationTable::build(&t, bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn lookup_is_bilinear_between_entry_centres() {
        let t = ClassificationTable::new(&random_tf(5), SamplingModel::Opacity);
        let pre = PreintegrationTable::build(&t, 1.0).unwrap();
        assert_eq!(pre.ratio(), 1.0);
        assert_eq!(pre.model(), SamplingModel::Opacity);
        assert_eq!(pre.entries().len(), TF_SIZE * TF_SIZE);
        for f in 0..TF_SIZE {
            for b in (0..TF_SIZE).step_by(7) {
                assert_eq!(pre.lookup(pos(f), pos(b)), entry(&pre, f, b), "({f},{b})");
            }
        }
        let mut rng = Lcg(77);
        for _ in 0..1000 {
            let (x, y) = (rng.next() as f32, rng.next() as f32);
            let (fx, fy) = (x * PIECES as f32, y * PIECES as f32);
            let (i, j) = ((fx as usize).min(PIECES - 1), (fy as usize).min(PIECES - 1));
            let (u, v) = (fx - i as f32, fy - j as f32);
            let expected = entry(&pre, i, j) * (1.0 - u) * (1.0 - v)
                + entry(&pre, i + 1, j) * u * (1.0 - v)
                + entry(&pre, i, j + 1) * (1.0 - u) * v
                + entry(&pre, i + 1, j + 1) * u * v;
            let got = pre.lookup(x, y);
            assert!(
                (got - expected).abs().max_element() < 1e-6,
                "({x},{y}): {got:?} vs {expected:?}"
            );
        }
        assert_eq!(pre.lookup(-1.0, 2.0), entry(&pre, 0, PIECES));
        assert_eq!(pre.lookup(5.0, -0.5), entry(&pre, PIECES, 0));
    }

    #[test]
    fn default_sub_steps_have_converged() {
        const FINE: Accuracy = Accuracy {
            max_depth: 0.02,
            growth: 0.0,
            max_ratio: 1.05,
            sliver: 1e-9,
            gauss: &GAUSS4,
        };
        let mut worst = 0.0f32;
        for model in MODELS {
            for tf in [
                TransferFunction::preset(TfPreset::Fire),
                opaque_tf(),
                random_tf(11),
            ] {
                let t = ClassificationTable::new(&tf, model);
                for ratio in [0.1f32, 1.0, 10.0, 100.0] {
                    let coarse = PreintegrationTable::build(&t, ratio).unwrap();
                    let fine = PreintegrationTable::build_with(&t, ratio, &FINE).unwrap();
                    let err = coarse
                        .entries()
                        .iter()
                        .zip(fine.entries())
                        .map(|(a, b)| (*a - *b).abs().max_element())
                        .fold(0.0f32, f32::max);
                    worst = worst.max(err);
                    assert!(err < 1e-6, "{model:?} ratio {ratio}: {err:e}");
                }
            }
        }
        eprintln!("default vs fine sub-steps: worst difference {worst:e}");
    }
}
