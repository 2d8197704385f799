//! Structural similarity (SSIM, Wang et al. 2004) of the frame against the reference, from the
//! `image-compare` crate.
//!
//! Why that crate: it is MIT-licensed, works on `image` buffers of the `image` version this
//! workspace already uses (so no second image stack), and pulls in only `rayon`, `itertools` and
//! `thiserror`; its SSIM is the textbook formula over 8 x 8 windows, averaged. `dssim-core`
//! measures a multi-scale perceptual variant in its own colour space (not the SSIM papers quote)
//! and is AGPL-licensed; hand-rolling SSIM would not be a kept implementation.
//!
//! The frames are composited over black (premultiplied RGB is that composite) and quantised to
//! 8 bits per channel; the score is the mean of the three channels' mean SSIM, 1 for identical
//! frames.

use super::{Frame, MetricError};
use image_compare::Algorithm;

/// The frame as an 8-bit RGB image over black.
fn to_rgb8(frame: &Frame<'_>) -> image::RgbImage {
    image::RgbImage::from_fn(frame.width, frame.height, |x, y| {
        let p = frame.at(x, y);
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        image::Rgb([q(p.x), q(p.y), q(p.z)])
    })
}

/// Mean SSIM of `image` against `reference` (1 = identical structure).
pub fn ssim(image: &Frame<'_>, reference: &Frame<'_>) -> Result<f64, MetricError> {
    image.check_same_size(reference)?;
    image_compare::rgb_similarity_structure(
        &Algorithm::MSSIMSimple,
        &to_rgb8(image),
        &to_rgb8(reference),
    )
    .map(|s| s.score)
    .map_err(|e| MetricError::Ssim(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

    #[test]
    fn identical_frames_score_one_and_noise_scores_less() {
        let a: Vec<Vec4> = (0..256)
            .map(|i| Vec4::splat(((i * 37) % 17) as f32 / 16.0))
            .collect();
        let fa = Frame::new(16, 16, &a).unwrap();
        assert!((ssim(&fa, &fa).unwrap() - 1.0).abs() < 1e-6);
        let b: Vec<Vec4> = (0..256)
            .map(|i| Vec4::splat(((i * 11) % 13) as f32 / 12.0))
            .collect();
        let s = ssim(&Frame::new(16, 16, &b).unwrap(), &fa).unwrap();
        assert!(s < 0.9, "{s}");
    }
}
