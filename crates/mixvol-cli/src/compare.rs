//! `--compare`: the rendered frame against the CPU reference, per channel.

use glam::Vec4;

/// How far a frame is from the reference, over every channel of every pixel.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Difference {
    /// The largest absolute per-channel difference.
    pub max: f32,
    /// The mean absolute per-channel difference.
    pub mean: f64,
    /// The fraction of channels that differ by more than 1/255.
    pub above_one_step: f64,
}

impl Difference {
    /// Compares `frame` with `reference` (same pixel count; extra pixels of either are ignored).
    pub fn between(reference: &[Vec4], frame: &[Vec4]) -> Self {
        let diffs: Vec<f32> = reference
            .iter()
            .zip(frame)
            .flat_map(|(a, b)| (*a - *b).abs().to_array())
            .collect();
        let n = diffs.len().max(1) as f64;
        Self {
            max: diffs.iter().copied().fold(0.0f32, f32::max),
            mean: diffs.iter().map(|d| f64::from(*d)).sum::<f64>() / n,
            above_one_step: diffs.iter().filter(|d| **d > 1.0 / 255.0).count() as f64 / n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Difference;
    use glam::Vec4;

    #[test]
    fn difference_counts_channels_above_one_step() {
        let reference = [Vec4::ZERO, Vec4::ONE];
        let frame = [Vec4::new(0.5, 0.0, 0.0, 0.0), Vec4::ONE];
        let d = Difference::between(&reference, &frame);
        assert_eq!(d.max, 0.5);
        assert!((d.mean - 0.5 / 8.0).abs() < 1e-12);
        assert!((d.above_one_step - 1.0 / 8.0).abs() < 1e-12);
    }
}
