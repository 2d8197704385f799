//! Transfer functions, opacity correction and compositing. `glsl/include/optics.glsl` mirrors the
//! functions here one by one.

pub mod preintegration;

/// A transfer function or a pre-integration table that cannot be built from what was given
/// (the message says which value and what was expected). The crate's [`Error`](crate::Error)
/// takes it as `InvalidInput`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid input: {0}")]
pub struct OpticsError(pub String);

type Result<T, E = OpticsError> = std::result::Result<T, E>;
use glam::{Vec3, Vec4};

/// Entries in a transfer-function table (and in the GPU 1D texture). Passed to GLSL as `TF_SIZE`.
pub const TF_SIZE: usize = 256;

/// A 1D RGBA transfer function: [`TF_SIZE`] entries spanning TF positions 0..=1, linearly
/// interpolated between entry centres. RGB is emitted colour (not premultiplied); A is the
/// opacity of one reference length d0 (one voxel).
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFunction {
    entries: Vec<Vec4>,
}

/// Named transfer functions for the CLI and tests.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum TfPreset {
    /// Grey ramp: colour and opacity grow linearly with the value (opacity up to 0.25).
    Grey,
    /// A warm, nearly opaque shell around the value 0.5 (the classic Marschner-Lobb iso-value).
    Fire,
    /// Colour bands (blue, green, red) with moderate opacity: makes structure visible.
    Bands,
    /// Constant white at opacity 0.1 everywhere, values included: for analytic tests.
    ConstantWhite,
    /// CT: soft tissue faint and warm, bone bright and opaque (use with a window over the data).
    Ct,
    /// MRI: background transparent, tissue in warm greys rising with intensity.
    Mri,
}

impl TfPreset {
    /// Parses a preset name (`grey`, `fire`, `bands`, `constant`).
    pub fn parse(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "grey" | "gray" => Some(TfPreset::Grey),
            "fire" => Some(TfPreset::Fire),
            "bands" => Some(TfPreset::Bands),
            "constant" | "constant-white" => Some(TfPreset::ConstantWhite),
            "ct" => Some(TfPreset::Ct),
            "mri" => Some(TfPreset::Mri),
            _ => None,
        }
    }

    /// All preset names, for help texts.
    pub const NAMES: &'static str = "grey, fire, bands, constant, ct, mri";
}

impl TransferFunction {
    /// Builds a table from exactly [`TF_SIZE`] entries; components must lie in [0, 1].
    pub fn from_entries(entries: Vec<Vec4>) -> Result<Self> {
        if entries.len() != TF_SIZE {
            return Err(OpticsError(format!(
                "transfer function needs {TF_SIZE} entries, got {}",
                entries.len()
            )));
        }
        if let Some(i) = entries
            .iter()
            .position(|e| !(e.is_finite() && e.min_element() >= 0.0 && e.max_element() <= 1.0))
        {
            return Err(OpticsError(format!(
                "transfer function entry {i} = {:?} is outside [0, 1]",
                entries[i]
            )));
        }
        Ok(Self { entries })
    }

    /// Piecewise-linear table through control points `(position, rgba)`, positions ascending in
    /// [0, 1]; constant beyond the first and last point.
    pub fn from_control_points(points: &[(f32, Vec4)]) -> Result<Self> {
        if points.is_empty() {
            return Err(OpticsError(
                "transfer function without control points".into(),
            ));
        }
        if points
            .windows(2)
            .any(|w| w[0].0.partial_cmp(&w[1].0).is_none_or(|o| o.is_gt()))
        {
            return Err(OpticsError(
                "transfer function control points must be in ascending order".into(),
            ));
        }
        let entries = (0..TF_SIZE)
            .map(|i| {
                let s = i as f32 / (TF_SIZE - 1) as f32;
                let upper = points.iter().position(|p| p.0 >= s);
                match upper {
                    None => points[points.len() - 1].1,
                    Some(0) => points[0].1,
                    Some(j) => {
                        let (a, b) = (points[j - 1], points[j]);
                        let w = if b.0 > a.0 {
                            (s - a.0) / (b.0 - a.0)
                        } else {
                            1.0
                        };
                        a.1.lerp(b.1, w)
                    }
                }
            })
            .collect();
        Self::from_entries(entries)
    }

    /// A named preset.
    pub fn preset(preset: TfPreset) -> Self {
        let points: &[(f32, Vec4)] = match preset {
            TfPreset::Grey => &[(0.0, Vec4::ZERO), (1.0, Vec4::new(1.0, 1.0, 1.0, 0.25))],
            TfPreset::Fire => &[
                (0.0, Vec4::ZERO),
                (0.40, Vec4::new(0.5, 0.05, 0.0, 0.0)),
                (0.46, Vec4::new(0.9, 0.3, 0.05, 0.08)),
                (0.50, Vec4::new(1.0, 0.85, 0.4, 0.6)),
                (0.54, Vec4::new(0.9, 0.3, 0.05, 0.08)),
                (0.60, Vec4::new(0.5, 0.05, 0.0, 0.0)),
                (1.0, Vec4::ZERO),
            ],
            TfPreset::Bands => &[
                (0.0, Vec4::ZERO),
                (0.2, Vec4::new(0.1, 0.2, 0.9, 0.0)),
                (0.3, Vec4::new(0.1, 0.3, 1.0, 0.1)),
                (0.5, Vec4::new(0.1, 0.9, 0.3, 0.05)),
                (0.7, Vec4::new(0.9, 0.9, 0.1, 0.2)),
                (1.0, Vec4::new(1.0, 0.1, 0.1, 0.5)),
            ],
            TfPreset::ConstantWhite => &[(0.0, Vec4::new(1.0, 1.0, 1.0, 0.1))],
            TfPreset::Ct => &[
                (0.0, Vec4::ZERO),
                (0.25, Vec4::new(0.5, 0.15, 0.1, 0.0)),
                (0.4, Vec4::new(0.85, 0.45, 0.35, 0.03)),
                (0.6, Vec4::new(0.95, 0.85, 0.7, 0.15)),
                (0.8, Vec4::new(1.0, 0.97, 0.9, 0.5)),
                (1.0, Vec4::new(1.0, 1.0, 1.0, 0.8)),
            ],
            TfPreset::Mri => &[
                (0.0, Vec4::ZERO),
                (0.12, Vec4::ZERO),
                (0.35, Vec4::new(0.6, 0.5, 0.45, 0.04)),
                (0.7, Vec4::new(0.95, 0.9, 0.85, 0.25)),
                (1.0, Vec4::new(1.0, 1.0, 1.0, 0.5)),
            ],
        };
        Self::from_control_points(points).expect("presets are valid")
    }

    /// The table entries.
    pub fn entries(&self) -> &[Vec4] {
        &self.entries
    }

    /// Linear lookup at TF position `s` (clamped to [0, 1]) between entry centres, as the GPU's
    /// linearly filtered 1D texture does.
    pub fn lookup(&self, s: f32) -> Vec4 {
        let x = s.clamp(0.0, 1.0) * (TF_SIZE - 1) as f32;
        let i0 = (x.floor() as usize).min(TF_SIZE - 1);
        let i1 = (i0 + 1).min(TF_SIZE - 1);
        let f = x - i0 as f32;
        self.entries[i0].lerp(self.entries[i1], f)
    }
}

/// Maps a normalised sample value through the window `(lo, 1 / (hi - lo))` onto the transfer
/// function (unweighted colour and opacity; the ray-caster classifies through a
/// [`ClassificationTable`] instead).
pub fn classify(tf: &TransferFunction, window_lo: f32, window_inv_range: f32, value: f32) -> Vec4 {
    tf.lookup(tf_position(window_lo, window_inv_range, value))
}

/// The transfer-function position of a sample value: `(value - lo) / (hi - lo)` clamped to
/// [0, 1]. Mirrors `tf_position` in optics.glsl.
pub fn tf_position(window_lo: f32, window_inv_range: f32, value: f32) -> f32 {
    ((value - window_lo) * window_inv_range).clamp(0.0, 1.0)
}

/// How a sample's opacity follows from the classified data (Kraus et al., "Interpolating and
/// downsampling RGBA volume data"): what is interpolated, and how a segment length enters.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub enum SamplingModel {
    /// Interpolate opacity-weighted colour and the opacity of one reference length d0, then
    /// correct the opacity for the segment length: `1 - (1 - alpha)^(d / d0)`.
    #[default]
    Opacity,
    /// Interpolate extinction (per d0) and extinction-weighted colour; a segment of length d has
    /// opacity `1 - exp(-tau d / d0)`. A transfer-function opacity `a` converts to
    /// `tau = -ln(1 - a)`, capped at [`MAX_EXTINCTION`].
    Extinction,
}

/// Largest extinction per reference length a classification table holds (opacity 1 entries map
/// here): `exp(-64)` is 1.6e-28, opaque for every practical purpose.
pub const MAX_EXTINCTION: f32 = 64.0;

/// A transfer function in the form the ray-caster interpolates: per entry `(weighted colour,
/// coefficient)`, the coefficient being the opacity of one reference length
/// ([`SamplingModel::Opacity`]) or the extinction per reference length
/// ([`SamplingModel::Extinction`]) and the colour premultiplied by it. The GPU's 1D texture
/// holds exactly these entries.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassificationTable {
    model: SamplingModel,
    entries: Vec<Vec4>,
}

impl ClassificationTable {
    /// Converts `tf` for `model`.
    pub fn new(tf: &TransferFunction, model: SamplingModel) -> Self {
        let entries = tf
            .entries()
            .iter()
            .map(|e| {
                let coefficient = match model {
                    SamplingModel::Opacity => e.w,
                    SamplingModel::Extinction => opacity_to_extinction(e.w),
                };
                (e.truncate() * coefficient).extend(coefficient)
            })
            .collect();
        Self { model, entries }
    }

    /// The sampling model the entries are for.
    pub fn model(&self) -> SamplingModel {
        self.model
    }

    /// The weighted entries, [`TF_SIZE`] of them.
    pub fn entries(&self) -> &[Vec4] {
        &self.entries
    }

    /// Linear lookup at TF position `s` (clamped) between entry centres, as the GPU's linearly
    /// filtered 1D texture does. Mirrors `lookup_tf` in optics.glsl.
    pub fn lookup(&self, s: f32) -> Vec4 {
        let x = s.clamp(0.0, 1.0) * (TF_SIZE - 1) as f32;
        let i0 = (x.floor() as usize).min(TF_SIZE - 1);
        let i1 = (i0 + 1).min(TF_SIZE - 1);
        let f = x - i0 as f32;
        self.entries[i0].lerp(self.entries[i1], f)
    }

    /// Opacity of a segment `ratio` reference lengths long with coefficient `coefficient` (an
    /// interpolated entry's w). Mirrors `sample_opacity` in optics.glsl.
    pub fn sample_opacity(&self, coefficient: f32, ratio: f32) -> f32 {
        match self.model {
            SamplingModel::Opacity => correct_opacity(coefficient, ratio),
            SamplingModel::Extinction => extinction_opacity(coefficient, ratio),
        }
    }

    /// Opacity of one reference length (the opacity a transfer function shows). Mirrors
    /// `reference_opacity` in optics.glsl.
    pub fn reference_opacity(&self, coefficient: f32) -> f32 {
        match self.model {
            SamplingModel::Opacity => coefficient.min(1.0),
            SamplingModel::Extinction => extinction_opacity(coefficient, 1.0),
        }
    }

    /// Extinction per reference length of an interpolated coefficient (for pre-integration).
    pub fn extinction(&self, coefficient: f32) -> f32 {
        match self.model {
            SamplingModel::Opacity => opacity_to_extinction(coefficient),
            SamplingModel::Extinction => coefficient,
        }
    }
}

/// Extinction per reference length of opacity `alpha` over that length: `-ln(1 - alpha)`,
/// capped at [`MAX_EXTINCTION`].
pub fn opacity_to_extinction(alpha: f32) -> f32 {
    if alpha <= 0.0 {
        0.0
    } else if alpha >= 1.0 {
        MAX_EXTINCTION
    } else {
        (-(-f64::from(alpha)).ln_1p()).min(f64::from(MAX_EXTINCTION)) as f32
    }
}

/// The emitted colour of an interpolated weighted entry: weighted colour / coefficient (black
/// where the coefficient is 0). Mirrors `sample_colour` in optics.glsl.
pub fn sample_colour(weighted: Vec4) -> Vec3 {
    if weighted.w > 0.0 {
        weighted.truncate() / weighted.w
    } else {
        Vec3::ZERO
    }
}

/// Opacity of a segment `ratio` reference lengths long from the opacity `alpha` of one reference
/// length: `1 - (1 - alpha)^ratio = -expm1(ratio * log1p(-alpha))`, exact at alpha = 0 and 1.
/// Small arguments use third-order series (the same as the GLSL), so tiny opacities keep their
/// relative accuracy. Mirrors `correct_opacity`.
pub fn correct_opacity(alpha: f32, ratio: f32) -> f32 {
    if alpha >= 1.0 {
        return 1.0;
    }
    if alpha <= 0.0 {
        return 0.0;
    }
    let l = if alpha < 1e-3 {
        -alpha * (1.0 + alpha * (0.5 + alpha / 3.0))
    } else {
        (1.0 - alpha).ln()
    };
    one_minus_exp(ratio * l)
}

/// `1 - exp(y)` for `y <= 0`, with a third-order series near 0 so tiny results keep their
/// relative accuracy. Mirrors `one_minus_exp` in optics.glsl.
pub fn one_minus_exp(y: f32) -> f32 {
    if y > -1e-3 {
        -y * (1.0 + y * (0.5 + y / 6.0))
    } else {
        1.0 - y.exp()
    }
}

/// Opacity of a segment `length` long in a medium of extinction coefficient `tau` (per the same
/// length unit): `1 - exp(-tau * length)`, the extinction-based sampling model of Kraus et al.
/// Never negative, 1 once `exp` underflows, 0 for `tau <= 0`. Mirrors `extinction_opacity`.
pub fn extinction_opacity(tau: f32, length: f32) -> f32 {
    let depth = tau * length;
    if depth > 0.0 {
        one_minus_exp(-depth)
    } else {
        0.0
    }
}

/// Front-to-back compositing of emission `rgb` with opacity `alpha` behind the premultiplied
/// accumulator `acc`. Mirrors `composite`.
pub fn composite(acc: Vec4, rgb: Vec3, alpha: f32) -> Vec4 {
    let weight = (1.0 - acc.w) * alpha;
    (acc.truncate() + weight * rgb).extend(acc.w + weight)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opacity_correction_composes_over_segments() {
        // Two half segments must give the opacity of one whole segment.
        for &a in &[0.01f32, 0.3, 0.9, 0.999] {
            let half = correct_opacity(a, 0.5);
            let two_halves = 1.0 - (1.0 - half) * (1.0 - half);
            assert!((two_halves - a).abs() < 1e-5, "a={a}: {two_halves}");
        }
        assert_eq!(correct_opacity(1.0, 0.001), 1.0);
        // Tiny opacities keep their relative accuracy (1 - exp(y) would lose it).
        for &(a, r) in &[(1e-6f32, 1.0f32), (1e-7, 3.0), (2e-4, 0.01), (0.3, 1e-5)] {
            let exact = -((r as f64) * (-(a as f64)).ln_1p()).exp_m1();
            let got = correct_opacity(a, r) as f64;
            assert!(
                ((got - exact) / exact).abs() < 1e-5,
                "a={a} r={r}: {got} vs {exact}"
            );
        }
        assert_eq!(correct_opacity(0.0, 1000.0), 0.0);
        assert!((correct_opacity(0.5, 1.0) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn compositing_is_front_to_back_under() {
        let acc = composite(Vec4::ZERO, Vec3::new(1.0, 0.0, 0.0), 0.5);
        let acc = composite(acc, Vec3::new(0.0, 1.0, 0.0), 0.5);
        assert!((acc - Vec4::new(0.5, 0.25, 0.0, 0.75)).abs().max_element() < 1e-6);
    }

    #[test]
    fn lookup_interpolates_between_entry_centres() {
        let tf = TransferFunction::preset(TfPreset::Grey);
        // Entries are a linear ramp, so lookup is linear in s.
        for &s in &[0.0f32, 0.1, 0.5, 0.77, 1.0] {
            let v = tf.lookup(s);
            assert!((v.w - 0.25 * s).abs() < 1e-5, "s={s}: {v:?}");
        }
        assert_eq!(tf.lookup(-3.0), tf.lookup(0.0));
        assert_eq!(tf.lookup(7.0), tf.lookup(1.0));
    }

    #[test]
    fn bad_tables_are_rejected() {
        assert!(TransferFunction::from_entries(vec![Vec4::ZERO; 3]).is_err());
        let mut e = vec![Vec4::ZERO; TF_SIZE];
        e[7] = Vec4::splat(1.5);
        assert!(TransferFunction::from_entries(e).is_err());
        assert!(
            TransferFunction::from_control_points(&[(0.5, Vec4::ZERO), (0.1, Vec4::ZERO)]).is_err()
        );
    }
}
